//! The ArduPilot DataFlash reader (`log::dataflash`): the public fixture against pymavlink's
//! reading of it (`tests/flightlogs.json`, written by `scripts/crosscheck-flightlogs.py`), logs
//! written here from a known sensor under a known old calibration, damaged logs, and the memory
//! budget.

use std::path::{Path, PathBuf};

use magcal_core::rng::stream_rng;
use magcal_runner::log::binary::Budget;
use magcal_runner::log::dataflash::{read, read_with};
use magcal_runner::log::flight::{FlightLog, InForce, Selection};
use rand::RngExt;
use tempfile::TempDir;

use crate::common::data;

const FIXTURE: &str = "ardupilot/pymavlink_test.BIN";

fn pick(k: Option<u8>) -> Selection {
    Selection { instance: k }
}

fn expected() -> serde_json::Value {
    let text = include_str!("../flightlogs.json");
    serde_json::from_str::<serde_json::Value>(text).unwrap()["ardupilot"].clone()
}

/// Roll, pitch, yaw (degrees, yaw in [0, 360)) of a body-to-NED quaternion, through its matrix.
pub fn euler_deg(q: [f64; 4]) -> [f64; 3] {
    let [w, x, y, z] = q;
    let c20 = 2.0 * (x * z - w * y);
    let c21 = 2.0 * (y * z + w * x);
    let c22 = 1.0 - 2.0 * (x * x + y * y);
    let c10 = 2.0 * (x * y + w * z);
    let c00 = 1.0 - 2.0 * (y * y + z * z);
    [
        c21.atan2(c22).to_degrees(),
        (-c20).asin().to_degrees(),
        c10.atan2(c00).to_degrees().rem_euclid(360.0),
    ]
}

/// A time equal to the one in the expectations: serde_json's default parsing of a decimal may be
/// one unit in the last place off the double Python printed.
pub fn same_time(t: f64, want: &serde_json::Value) -> bool {
    let w = want.as_f64().unwrap();
    (t - w).abs() <= 2.0 * f64::EPSILON * w.abs()
}

#[test]
fn the_fixture_reads_as_pymavlink_reads_it() {
    let Some(path) = data(FIXTURE) else { return };
    let want = expected();
    for k in 0..3u8 {
        let log = read(&path, &pick(Some(k))).unwrap();
        assert_eq!(log.instances, [0, 1, 2]);
        assert_eq!(log.instance, k);
        let inst = &want["instances"][k.to_string()];
        let samples = inst["samples"].as_array().unwrap();
        assert_eq!(log.samples.len(), samples.len(), "instance {k}");
        assert_eq!(
            samples.len() as u64,
            want["counts"][inst["message"].as_str().unwrap()].as_u64().unwrap()
        );
        for (s, w) in log.samples.iter().zip(samples) {
            assert!(same_time(s.time_s, &w["time_s"]), "{} vs {w}", s.time_s);
            for c in 0..3 {
                let r = w["raw"][c].as_f64().unwrap();
                // The same formula in another order of operations: rounding of |m| ~ 1e3 mGauss
                // through D (condition ~1.2) and a dozen operations.
                assert!(
                    (s.raw[c] - r).abs() < 64.0 * f64::EPSILON * 1e3,
                    "instance {k}: {:?} vs {r}",
                    s.raw
                );
            }
        }
        let InForce::Undone(words) = &log.calibration else {
            panic!("{:?}", log.calibration)
        };
        let f = &inst["in_force"];
        let sfx = if k == 0 { String::new() } else { (k + 1).to_string() };
        let shown = words
            .split(&format!("COMPASS_DIA{sfx} = ("))
            .nth(1)
            .unwrap()
            .split(')')
            .next()
            .unwrap();
        for (c, v) in shown.split(", ").enumerate() {
            let want = f["dia"][c].as_f64().unwrap();
            assert!(
                (v.parse::<f64>().unwrap() - want).abs() <= 2.0 * f64::EPSILON * want.abs(),
                "{words}"
            );
        }
        assert!(words.contains("changed 0 times"), "{words}");
        assert!(
            log.messages[0].starts_with(inst["message"].as_str().unwrap()),
            "{:?}",
            log.messages
        );
        assert!(log.messages.iter().any(|m| m.starts_with("ATT: Roll, Pitch, Yaw")));
    }
    let log = read(&path, &pick(None)).unwrap();
    assert_eq!(log.instance, 0);
    let att = log.attitude.as_ref().unwrap();
    let want_att = want["attitude"].as_array().unwrap();
    assert_eq!(att.times.len(), want_att.len());
    for ((t, q), w) in att.times.iter().zip(&att.values).zip(want_att) {
        assert!(same_time(*t, &w["time_s"]), "{t} vs {w}");
        let e = euler_deg(*q);
        for (c, name) in ["roll", "pitch", "yaw"].iter().enumerate() {
            let d = (e[c] - w[name].as_f64().unwrap() + 180.0).rem_euclid(360.0) - 180.0;
            assert!(d.abs() < 1e-9, "{name}: {e:?} vs {w}");
        }
    }
    let cur = log.current.as_ref().unwrap();
    let want_cur: Vec<f64> = want["current"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["current"].as_f64().unwrap())
        .collect();
    assert_eq!(cur.values, want_cur);
    // The fixture is the first 64 KiB of a longer log: its last message is cut.
    assert!(log.notes.iter().any(|n| n.contains("is cut short")), "{:?}", log.notes);
    assert!(!log.notes.iter().any(|n| n.contains("Skipped")), "{:?}", log.notes);
    assert_eq!(log.bytes, 65536);
}

#[test]
fn the_fixture_lists_its_firmwares_parameters_without_compass_scale() {
    // pymavlink's test.BIN comes from a firmware without COMPASS_SCALE (ArduPilot 3.x) and a
    // COMPASS_OFFS_MAX of 850: its PARM names every other COMPASS_* that export writes, for
    // three compasses (OFS, DIA, ODI, MOT: 36, and MOTCT).
    let Some(path) = data(FIXTURE) else { return };
    let log = read(&path, &pick(Some(1))).unwrap();
    let p = log.parameters.unwrap();
    assert_eq!(p.autopilot, magcal_runner::log::parameters::Autopilot::ArduPilot);
    assert_eq!(p.source, "PARM");
    assert_eq!(p.compass_offs_max, Some(850.0));
    let names = p.names.unwrap();
    assert_eq!(names.len(), 37, "{names:?}");
    for n in [
        "COMPASS_OFS2_X",
        "COMPASS_DIA3_Z",
        "COMPASS_ODI_Y",
        "COMPASS_MOT2_Z",
        "COMPASS_MOTCT",
    ] {
        assert!(names.contains(n), "{n}");
    }
    assert!(!names.iter().any(|n| n.starts_with("COMPASS_SCALE")), "{names:?}");
}

#[test]
fn an_instance_the_fixture_lacks_is_refused_naming_those_it_has() {
    let Some(path) = data(FIXTURE) else { return };
    let e = read(&path, &pick(Some(5))).unwrap_err().to_string();
    assert!(
        e.ends_with("--compass 5: the log has no readings of magnetometer 5; it has 0, 1, 2"),
        "{e}"
    );
}

// ------------------------------------------------------------------------------------------------
// A DataFlash writer, from the format's definition (an `FMT` per type; little-endian fields).

/// A DataFlash log being written.
#[derive(Default)]
pub struct Writer {
    pub bytes: Vec<u8>,
    formats: Vec<(u8, Vec<u8>)>,
}

/// A field's value.
#[derive(Clone, Copy)]
pub enum V<'a> {
    N(f64),
    S(&'a str),
}

impl Writer {
    pub fn new() -> Self {
        let mut w = Self::default();
        w.fmt(0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns");
        w
    }

    pub fn fmt(&mut self, t: u8, name: &str, format: &str, labels: &str) {
        let len = 3 + format.bytes().map(size).sum::<usize>();
        self.fmt_raw(t, len as u8, name, format, labels);
    }

    /// An `FMT` with a length of the caller's choosing (right or not).
    pub fn fmt_raw(&mut self, t: u8, len: u8, name: &str, format: &str, labels: &str) {
        let mut p = vec![t, len];
        p.extend(padded(name, 4));
        p.extend(padded(format, 16));
        p.extend(padded(labels, 64));
        self.bytes.extend([0xA3, 0x95, 0x80]);
        self.bytes.extend(p);
        self.formats.retain(|(x, _)| *x != t);
        self.formats.push((t, format.as_bytes().to_vec()));
    }

    pub fn msg(&mut self, t: u8, values: &[V]) {
        let format = self.formats.iter().find(|(x, _)| *x == t).unwrap().1.clone();
        assert_eq!(format.len(), values.len());
        self.bytes.extend([0xA3, 0x95, t]);
        for (&c, v) in format.iter().zip(values) {
            match (c, *v) {
                (b'b', V::N(x)) => self.bytes.push(x as i8 as u8),
                (b'B' | b'M', V::N(x)) => self.bytes.push(x as u8),
                (b'h', V::N(x)) => self.bytes.extend((x as i16).to_le_bytes()),
                (b'H', V::N(x)) => self.bytes.extend((x as u16).to_le_bytes()),
                (b'c', V::N(x)) => self.bytes.extend(((x * 100.0).round() as i16).to_le_bytes()),
                (b'e', V::N(x)) => self.bytes.extend(((x * 100.0).round() as i32).to_le_bytes()),
                (b'L', V::N(x)) => self.bytes.extend(((x * 1e7).round() as i32).to_le_bytes()),
                (b'C', V::N(x)) => self.bytes.extend(((x * 100.0).round() as u16).to_le_bytes()),
                (b'i', V::N(x)) => self.bytes.extend((x as i32).to_le_bytes()),
                (b'I', V::N(x)) => self.bytes.extend((x as u32).to_le_bytes()),
                (b'f', V::N(x)) => self.bytes.extend((x as f32).to_le_bytes()),
                (b'd', V::N(x)) => self.bytes.extend(x.to_le_bytes()),
                (b'Q', V::N(x)) => self.bytes.extend((x as u64).to_le_bytes()),
                (b'q', V::N(x)) => self.bytes.extend((x as i64).to_le_bytes()),
                (b'n', V::S(s)) => self.bytes.extend(padded(s, 4)),
                (b'N', V::S(s)) => self.bytes.extend(padded(s, 16)),
                (b'Z', V::S(s)) => self.bytes.extend(padded(s, 64)),
                (c, _) => panic!("format {} with that value", c as char),
            }
        }
    }

    pub fn save(&self, dir: &Path, name: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, &self.bytes).unwrap();
        p
    }
}

fn size(c: u8) -> usize {
    match c {
        b'b' | b'B' | b'M' => 1,
        b'h' | b'H' | b'c' | b'C' => 2,
        b'i' | b'I' | b'f' | b'n' | b'e' | b'E' | b'L' => 4,
        b'q' | b'Q' | b'd' => 8,
        b'N' => 16,
        b'Z' | b'a' => 64,
        _ => panic!("format {}", c as char),
    }
}

fn padded(s: &str, n: usize) -> Vec<u8> {
    let mut v = s.as_bytes().to_vec();
    v.resize(n, 0);
    v
}

// ------------------------------------------------------------------------------------------------
// A known sensor under a known old calibration.

pub type M3 = [[f64; 3]; 3];

pub fn mv(m: &M3, v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| (0..3).map(|j| m[i][j] * v[j]).sum())
}

fn inf_norm(m: &M3) -> f64 {
    m.iter()
        .map(|r| r.iter().map(|x| x.abs()).sum::<f64>())
        .fold(0.0, f64::max)
}

/// Body (FRD) to NED of roll, pitch, yaw (radians): Rz(yaw) Ry(pitch) Rx(roll).
pub fn c_bn(r: f64, p: f64, y: f64) -> M3 {
    let (sr, cr) = r.sin_cos();
    let (sp, cp) = p.sin_cos();
    let (sy, cy) = y.sin_cos();
    [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
}

/// An old calibration as ArduPilot holds it (float32 parameters).
struct OldCal {
    ofs: [f32; 3],
    dia: [f32; 3],
    odi: [f32; 3],
    scale: f32,
}

impl OldCal {
    fn d(&self) -> M3 {
        let (a, o) = (self.dia.map(f64::from), self.odi.map(f64::from));
        [[a[0], o[0], o[1]], [o[0], a[1], o[2]], [o[1], o[2], a[2]]]
    }

    fn s(&self) -> f64 {
        if self.scale > 0.0 { f64::from(self.scale) } else { 1.0 }
    }

    /// ArduPilot's correct_field: m = D (s (r + OFS)) + MOT.
    fn apply(&self, r: [f64; 3], mot: [f64; 3]) -> [f64; 3] {
        let v = std::array::from_fn(|c| self.s() * (r[c] + f64::from(self.ofs[c])));
        let m = mv(&self.d(), v);
        std::array::from_fn(|c| m[c] + mot[c])
    }

    fn parms(&self, w: &mut Writer, t_us: f64) {
        for (c, a) in ["X", "Y", "Z"].iter().enumerate() {
            for (p, v) in [("OFS", self.ofs), ("DIA", self.dia), ("ODI", self.odi)] {
                let name = format!("COMPASS_{p}_{a}");
                w.msg(0x81, &[V::N(t_us), V::S(&name), V::N(f64::from(v[c]))]);
            }
        }
        w.msg(0x81, &[V::N(t_us), V::S("COMPASS_SCALE"), V::N(f64::from(self.scale))]);
    }
}

/// What a synthetic log was written from.
struct Truth {
    raw: Vec<[f64; 3]>,
    q: Vec<[f64; 3]>,
    /// Largest `||D^-1||_inf / s` of the calibrations in force.
    gain: f64,
    max_m: f64,
}

/// A log of `n` readings in ArduPilot's layout, with `MagX..` of format `mag_kind` (`h` as
/// ArduPilot writes them, or `f`), the calibration changed half-way.
fn synthetic(n: usize, mag_kind: char, seed: u64) -> (Writer, Truth) {
    synthetic_in(n, mag_kind, seed, [180.0, -20.0, 420.0])
}

/// The true sensor of [`synthetic`]: `raw = K b + O`, mGauss.
const TRUE_K: M3 = [[1.08, 0.03, -0.02], [0.0, 0.95, 0.04], [0.0, 0.0, 1.02]];
const TRUE_O: [f64; 3] = [35.0, -60.0, 120.0];

/// [`synthetic`] in the field `field_ned` (mGauss).
fn synthetic_in(n: usize, mag_kind: char, seed: u64, field_ned: [f64; 3]) -> (Writer, Truth) {
    let (k, o) = (TRUE_K, TRUE_O);
    let cals = [
        OldCal {
            ofs: [-40.25, 61.5, -118.75],
            dia: [1.02, 0.97, 1.05],
            odi: [0.01, -0.02, 0.015],
            scale: 0.0,
        },
        OldCal {
            ofs: [-33.125, 58.0, -122.5],
            dia: [0.99, 1.03, 0.98],
            odi: [-0.012, 0.004, 0.02],
            scale: 1.04,
        },
    ];
    let mot = [2.5, -1.25, 4.0];
    let mut w = Writer::new();
    let m = mag_kind;
    w.fmt(0x81, "PARM", "QNf", "TimeUS,Name,Value");
    w.fmt(
        0x82,
        "MAG",
        &format!("QB{}BI", m.to_string().repeat(9)),
        "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S",
    );
    w.fmt(
        0x83,
        "ATT",
        "QccccCCCC",
        "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw",
    );
    w.fmt(0x84, "BAT", "QBfff", "TimeUS,Inst,Volt,Curr,CurrTot");
    w.fmt(0x85, "CTUN", "Qfff", "TimeUS,ThI,ThO,ThH");
    cals[0].parms(&mut w, 1000.0);
    let mut rng = stream_rng(seed, 0);
    let mut truth = Truth {
        raw: Vec::new(),
        q: Vec::new(),
        gain: 0.0,
        max_m: 0.0,
    };
    for (i, cal) in cals.iter().enumerate() {
        let d_inv = inverse(&cal.d());
        truth.gain = truth.gain.max(inf_norm(&d_inv) / cal.s());
        if i == 1 {
            cal.parms(&mut w, 2000.0 + (n / 2) as f64 * 10_000.0);
        }
        for j in 0..n / 2 {
            let t = 10_000.0 * (i * n / 2 + j + 1) as f64 + 5000.0;
            // Attitudes at whole hundredths of a degree, as ATT stores them.
            let roll: f64 = (rng.random_range(-6000..6000) as f64) / 100.0;
            let pitch: f64 = (rng.random_range(-4000..4000) as f64) / 100.0;
            let yaw: f64 = (rng.random_range(0..36000) as f64) / 100.0;
            let c = c_bn(roll.to_radians(), pitch.to_radians(), yaw.to_radians());
            let b = std::array::from_fn(|a| (0..3).map(|r| c[r][a] * field_ned[r]).sum::<f64>());
            let kb = mv(&k, b);
            let raw: [f64; 3] = std::array::from_fn(|a| kb[a] + o[a]);
            let current: f64 = rng.random_range(0.0..30.0);
            let mo: [f64; 3] = mot.map(|x| x * current);
            let mlog = cal.apply(raw, mo);
            truth.max_m = mlog.iter().chain(&mo).fold(truth.max_m, |a, x| a.max(x.abs()));
            truth.raw.push(raw);
            truth.q.push([roll, pitch, yaw]);
            w.msg(
                0x83,
                &[
                    V::N(t - 100.0),
                    V::N(0.0),
                    V::N(roll),
                    V::N(0.0),
                    V::N(pitch),
                    V::N(0.0),
                    V::N(yaw),
                    V::N(0.0),
                    V::N(0.0),
                ],
            );
            w.msg(0x84, &[V::N(t - 50.0), V::N(0.0), V::N(12.0), V::N(current), V::N(0.0)]);
            w.msg(0x84, &[V::N(t - 40.0), V::N(1.0), V::N(12.0), V::N(99.0), V::N(0.0)]);
            w.msg(0x85, &[V::N(t - 30.0), V::N(0.0), V::N(current / 30.0), V::N(0.0)]);
            let mut vals = vec![V::N(t), V::N(0.0)];
            // ArduPilot's int16 casts truncate (as Rust's `as` does); a float field holds the float.
            vals.extend(mlog.map(V::N));
            vals.extend(cal.ofs.map(|x| V::N(f64::from(x))));
            vals.extend(mo.map(V::N));
            vals.extend([V::N(1.0), V::N(t)]);
            w.msg(0x82, &vals);
        }
    }
    (w, truth)
}

pub fn inverse(a: &M3) -> M3 {
    let c = |i: usize, j: usize| {
        let (r0, r1, c0, c1) = ((i + 1) % 3, (i + 2) % 3, (j + 1) % 3, (j + 2) % 3);
        a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0]
    };
    let det: f64 = (0..3).map(|j| a[0][j] * c(0, j)).sum();
    std::array::from_fn(|i| std::array::from_fn(|j| c(j, i) / det))
}

fn check_against_truth(log: &FlightLog, truth: &Truth, tol: f64) {
    assert_eq!(log.samples.len(), truth.raw.len());
    let mut worst = 0.0f64;
    for (s, r) in log.samples.iter().zip(&truth.raw) {
        for (a, b) in s.raw.iter().zip(r) {
            worst = worst.max((a - b).abs());
        }
    }
    assert!(worst <= tol, "largest error {worst} mGauss, bound {tol}");
    let att = log.attitude.as_ref().unwrap();
    assert_eq!(att.values.len(), truth.q.len());
    for (q, want) in att.values.iter().zip(&truth.q) {
        let e = euler_deg(*q);
        for c in 0..3 {
            let d = (e[c] - want[c] + 180.0).rem_euclid(360.0) - 180.0;
            assert!(d.abs() < 1e-10, "{e:?} vs {want:?}");
        }
    }
}

#[test]
fn a_synthetic_log_gives_back_the_true_sensor_under_both_calibrations() {
    let dir = TempDir::new().unwrap();
    for kind in ['h', 'f'] {
        let (w, truth) = synthetic(400, kind, 7);
        let path = w.save(dir.path(), "syn.bin");
        let log = read(&path, &pick(None)).unwrap();
        // The error left in m - MO: for int16 fields the middle of a truncation interval, half a
        // unit each of m and MO, or a whole one where the logged value is 0 (its interval is
        // (-1, 1)); for float fields float32 rounding (2^-24 relative each). D^-1 and 1/s carry
        // it to r; the f64 arithmetic adds ~1e-12.
        let per_component = match kind {
            'h' => 2.0,
            _ => 2.0 * truth.max_m * f32::EPSILON as f64 / 2.0,
        };
        let tol = truth.gain * per_component + 1e-9;
        check_against_truth(&log, &truth, tol);
        let InForce::Undone(words) = &log.calibration else {
            panic!("{:?}", log.calibration)
        };
        assert!(words.contains("changed 1 times"), "{words}");
        assert!(
            words.contains("COMPASS_OFS = (-40.25, 61.5, -118.75) (parameters)"),
            "{words}"
        );
        assert!(
            log.notes.iter().any(|n| n.contains("changed 1 times")),
            "{:?}",
            log.notes
        );
        let cur = log.current.as_ref().unwrap();
        assert_eq!(cur.values.len(), 400, "BAT of instance 1 are not the battery read");
        let thr = log.throttle.as_ref().unwrap();
        assert!(
            thr.values
                .iter()
                .zip(&cur.values)
                .all(|(t, c)| (t - (*c as f32 as f64 / 30.0) as f32 as f64).abs() < 1e-6)
        );
        assert_eq!(log.instances, [0]);
    }
}

#[test]
fn the_truncation_of_int16_fields_is_taken_at_its_middle() {
    // Without the middle, truncation towards zero biases every component by half a unit; with
    // it the mean error over many readings is near zero.
    let dir = TempDir::new().unwrap();
    let (w, truth) = synthetic(4000, 'h', 11);
    let log = read(&w.save(dir.path(), "t.bin"), &pick(None)).unwrap();
    for c in 0..3 {
        let errors: Vec<f64> = log
            .samples
            .iter()
            .zip(&truth.raw)
            .map(|(s, r)| s.raw[c] - r[c])
            .collect();
        let n = errors.len() as f64;
        let mean = errors.iter().sum::<f64>() / n;
        let sd = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        // Four standard errors of the mean.
        assert!(mean.abs() < 4.0 * sd / n.sqrt(), "axis {c}: mean error {mean}, sd {sd}");
    }
}

// ------------------------------------------------------------------------------------------------
// Damaged logs.

const NOT_DATAFLASH: &str = "not an ArduPilot DataFlash log";

/// Every outcome of a damaged log: a log whose readings and series are finite and in order, or an
/// error naming the file and a byte offset or message.
pub fn check_outcome(path: &Path, r: anyhow::Result<FlightLog>, not_format: &str) {
    let shown = path.display().to_string();
    match r {
        Ok(log) => {
            assert!(!log.samples.is_empty());
            for w in log.samples.windows(2) {
                assert!(w[0].time_s <= w[1].time_s);
            }
            assert!(log.samples.iter().all(|s| s.raw.iter().all(|x| x.is_finite())));
            if let Some(a) = &log.attitude {
                for q in &a.values {
                    let n: f64 = q.iter().map(|x| x * x).sum();
                    assert!((n - 1.0).abs() < 1e-9);
                }
            }
            for s in [&log.current, &log.throttle].into_iter().flatten() {
                assert!(s.times.windows(2).all(|w| w[0] <= w[1]));
            }
        }
        Err(e) => {
            let e = format!("{e:#}");
            assert!(e.starts_with(&shown), "{e}");
            assert!(!e.contains('\n'), "{e}");
            assert!(
                e.contains("byte ") || e.contains("no magnetometer readings") || e.contains(not_format),
                "{e}"
            );
        }
    }
}

#[test]
fn the_fixture_cut_at_any_length_reads_or_says_where() {
    let Some(path) = data(FIXTURE) else { return };
    let bytes = std::fs::read(&path).unwrap();
    let dir = TempDir::new().unwrap();
    let cut = dir.path().join("cut.bin");
    // Every length through the FMTs and the first messages, then a stride, then every length of
    // the end.
    let lengths = (0..4096)
        .chain((4096..bytes.len() - 1024).step_by(61))
        .chain(bytes.len() - 1024..=bytes.len());
    for n in lengths {
        std::fs::write(&cut, &bytes[..n]).unwrap();
        check_outcome(&cut, read(&cut, &pick(None)), NOT_DATAFLASH);
    }
}

#[test]
fn random_damage_to_the_fixture_never_panics() {
    let Some(path) = data(FIXTURE) else { return };
    let bytes = std::fs::read(&path).unwrap();
    let dir = TempDir::new().unwrap();
    let bad = dir.path().join("bad.bin");
    let mut rng = stream_rng(21, 1);
    for case in 0..400 {
        std::fs::write(&bad, damage(&bytes, case, &mut rng)).unwrap();
        check_outcome(&bad, read(&bad, &pick(None)), NOT_DATAFLASH);
    }
}

/// `bytes` with 1 to 40 random bit flips (`case` 0 mod 3), byte insertions (1) or removals (2).
pub fn damage(bytes: &[u8], case: usize, rng: &mut impl rand::Rng) -> Vec<u8> {
    let mut b = bytes.to_vec();
    for _ in 0..rng.random_range(1..40) {
        let at = rng.random_range(0..b.len());
        match case % 3 {
            0 => b[at] ^= 1 << rng.random_range(0..8),
            1 => b.insert(at, rng.random()),
            _ => {
                b.remove(at);
            }
        }
    }
    b
}

#[test]
fn absurd_fmt_lengths_and_formats_are_errors_naming_the_byte() {
    let dir = TempDir::new().unwrap();
    for (len, format) in [
        (0u8, "QBhhh"),
        (2, "QBhhh"),
        (3, "QBhhh"),
        (255, "QBhhh"),
        (20, "QB!hh"),
        (20, ""),
    ] {
        let mut w = Writer::new();
        let at = w.bytes.len();
        w.fmt_raw(0x82, len, "MAG", format, "TimeUS,I,MagX,MagY,MagZ");
        w.bytes.extend([0xA3, 0x95, 0x82]);
        w.bytes.extend([0u8; 40]);
        let p = w.save(dir.path(), "fmt.bin");
        let e = read(&p, &pick(None)).unwrap_err().to_string();
        assert!(
            e.contains(&format!("byte {at}: the FMT of MAG (type 130) cannot be decoded")),
            "{len} {format}: {e}"
        );
    }
    // An FMT of a type the reader does not use may be damaged: its messages are skipped as bytes
    // that are not messages.
    let (mut w, _) = synthetic(10, 'h', 3);
    let mut head = Writer::new();
    head.fmt_raw(0x90, 1, "XYZ", "Q", "TimeUS");
    head.bytes.extend([0xA3, 0x95, 0x90, 1, 2, 3]);
    head.bytes.extend(w.bytes.split_off(89));
    let p = head.save(dir.path(), "other.bin");
    let log = read(&p, &pick(None)).unwrap();
    assert_eq!(log.samples.len(), 10);
    assert!(
        log.notes
            .iter()
            .any(|n| n.starts_with("Skipped 6 bytes that are not messages, in 1 places from byte 178")),
        "{:?}",
        log.notes
    );
}

#[test]
fn files_that_are_not_dataflash_are_refused() {
    let dir = TempDir::new().unwrap();
    for (bytes, shows) in [
        (&b""[..], "nothing (the file is empty)"),
        (b"mx,my,mz\n1,2,3\n", "6D 78 2C"),
        (&[0xA3, 0x95][..], "A3 95"),
    ] {
        let p = dir.path().join("x.bin");
        std::fs::write(&p, bytes).unwrap();
        let e = read(&p, &pick(None)).unwrap_err().to_string();
        assert!(
            e.ends_with(&format!(
                "not an ArduPilot DataFlash log: it begins with {shows}, not the FMT header A3 95 80"
            )),
            "{e}"
        );
    }
    let e = read(dir.path(), &pick(None)).unwrap_err().to_string();
    assert!(e.ends_with("is a directory, not a log"), "{e}");
    let mut w = Writer::new();
    w.fmt(0x81, "PARM", "QNf", "TimeUS,Name,Value");
    let p = w.save(dir.path(), "nomag.bin");
    let e = read(&p, &pick(None)).unwrap_err().to_string();
    assert!(
        e.ends_with("no magnetometer readings (no MAG, MAG2 or MAG3 messages)"),
        "{e}"
    );
}

#[test]
fn a_singular_old_calibration_is_an_error_naming_it() {
    let dir = TempDir::new().unwrap();
    let mut w = Writer::new();
    w.fmt(0x81, "PARM", "QNf", "TimeUS,Name,Value");
    w.fmt(0x82, "MAG", "QBhhh", "TimeUS,I,MagX,MagY,MagZ");
    for (n, v) in [
        ("COMPASS_DIA_X", 1.0),
        ("COMPASS_DIA_Y", 1.0),
        ("COMPASS_DIA_Z", 1.0),
        ("COMPASS_ODI_X", 1.0),
    ] {
        w.msg(0x81, &[V::N(1.0), V::S(n), V::N(v)]);
    }
    let at = w.bytes.len();
    w.msg(0x82, &[V::N(2.0), V::N(0.0), V::N(100.0), V::N(0.0), V::N(0.0)]);
    let e = read(&w.save(dir.path(), "s.bin"), &pick(None)).unwrap_err().to_string();
    assert!(
        e.contains(&format!(
            "byte {at}: COMPASS_DIA_* = (1, 1, 1) and COMPASS_ODI_* = (1, 0, 0) in force give a singular matrix"
        )),
        "{e}"
    );
}

#[test]
fn a_log_larger_than_the_budget_is_refused_before_it_is_read_whole() {
    let dir = TempDir::new().unwrap();
    let (w, _) = synthetic(20_000, 'h', 5);
    let p = w.save(dir.path(), "big.bin");
    let budget = Budget::with_limit(Some((256 << 10, 512 << 10, "test memory")));
    let e = read_with(&p, &pick(None), budget).unwrap_err().to_string();
    assert!(
        e.contains(": byte ") && e.contains("the log holds more readings and series than fit in memory"),
        "{e}"
    );
    assert!(e.ends_with("the limit is 0.2 MiB, half of 0.5 MiB test memory)"), "{e}");
    let at: u64 = e
        .split(": byte ")
        .nth(1)
        .unwrap()
        .split(':')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(
        at < w.bytes.len() as u64 / 2,
        "refused at byte {at} of {}",
        w.bytes.len()
    );
}

#[test]
fn a_log_under_an_old_calibration_calibrated_and_exported_gives_the_wmm_field_by_ardupilots_formula() {
    use magcal_core::wmm::{Model, Site, field_ned};
    // The WMM field at Zurich in mid-2026, in mGauss; MAG written under two old calibrations.
    let site = Site {
        lat_deg: 47.4,
        lon_deg: 8.5,
        alt_m: 400.0,
        year: 2026.5,
    };
    let field = field_ned(Model::Wmm2025, &site).unwrap().map(|v| v / 100.0);
    let r = field.iter().map(|v| v * v).sum::<f64>().sqrt();
    let (w, truth) = synthetic_in(2000, 'h', 17, field);
    let tmp = TempDir::new().unwrap();
    let log = w.save(tmp.path(), "old.bin");
    let out = crate::common::magcal()
        .arg("calibrate")
        .arg(&log)
        .args(["--site", "47.4,8.5,400", "--date", "2026.5", "--out"])
        .arg(tmp.path().join("cal"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let cal: magcal_runner::log::calibration::CalibrationJson =
        serde_json::from_slice(&std::fs::read(tmp.path().join("cal/calibration.json")).unwrap()).unwrap();
    assert_eq!(cal.units.as_deref(), Some("mG"));
    assert!((cal.magnitude - r).abs() < 1e-9 * r, "{} vs {r}", cal.magnitude);
    // The true sensor, not the old calibrations: [P1]'s parameters within 4 standard errors.
    let t = magcal_core::ErrorModel::from_k(&TRUE_K, TRUE_O);
    let se = &cal.std_error;
    for (i, o) in TRUE_O.iter().enumerate() {
        assert!((cal.bias[i] - o).abs() <= 4.0 * se.bias.unwrap()[i], "{:?}", cal.bias);
        assert!(
            (cal.scale[i] - t.scale()[i]).abs() <= 4.0 * se.scale.unwrap()[i],
            "{:?}",
            cal.scale
        );
        assert!(
            (cal.psi_deg[i] - t.psi_deg()[i]).abs() <= 4.0 * se.psi_deg.unwrap()[i],
            "{:?}",
            cal.psi_deg
        );
    }
    // The parameters ArduPilot takes, applied by its formula (AP_Compass_Backend::correct_field:
    // m = D s (r + OFS)) to the true raw readings: |m| is the WMM magnitude to within the noise
    // (the int16 logging's, about 0.3 mGauss a component).
    let out = crate::common::magcal()
        .arg("export")
        .arg(tmp.path().join("cal/calibration.json"))
        .args(["--to", "ardupilot"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let param = |name: &str| -> f64 {
        text.lines()
            .find_map(|l| l.strip_prefix(&format!("{name},")))
            .unwrap_or_else(|| panic!("{name}: {text}"))
            .trim()
            .parse()
            .unwrap()
    };
    let ofs = ["X", "Y", "Z"].map(|a| param(&format!("COMPASS_OFS_{a}")));
    let dia = ["X", "Y", "Z"].map(|a| param(&format!("COMPASS_DIA_{a}")));
    let odi = ["X", "Y", "Z"].map(|a| param(&format!("COMPASS_ODI_{a}")));
    let s = param("COMPASS_SCALE");
    let d: M3 = [
        [dia[0], odi[0], odi[1]],
        [odi[0], dia[1], odi[2]],
        [odi[1], odi[2], dia[2]],
    ];
    let noise = cal.noise.unwrap();
    let mut sum = 0.0;
    for raw in &truth.raw {
        let m = mv(&d, std::array::from_fn(|c| s * (raw[c] + ofs[c])));
        let e = m.iter().map(|v| v * v).sum::<f64>().sqrt() - r;
        sum += e * e;
    }
    let rms = (sum / truth.raw.len() as f64).sqrt();
    assert!(noise < 1.0, "{noise}");
    assert!(rms < noise, "|m| - R rms {rms} mGauss, noise {noise}");
}
