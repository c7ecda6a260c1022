//! `magcal export`: the parameters it writes, read back and applied with each autopilot's or
//! tool's own formula (as its source states it, written once below), give what `magcal apply
//! --matrix symmetric` gives, on the public logs of `../shared/data/` (skipped, saying so, where
//! that folder is absent) and on a log `magcal simulate` writes; the check values of
//! docs/conventions.md; the range warnings; bad input.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use crate::common::{assert_refused, data, edited, magcal};
use magcal_runner::log::export::{self as fmt, ArduPilot, Calibration, Px4};
use tempfile::TempDir;

type Vec3 = [f64; 3];
type Mat3 = [[f64; 3]; 3];

fn mat_vec(m: &Mat3, v: Vec3) -> Vec3 {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

fn length(v: Vec3) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// A symmetric matrix from its diagonal and its (01, 02, 12) entries, as both autopilots build
/// theirs.
fn symmetric(diag: Vec3, off: Vec3) -> Mat3 {
    [
        [diag[0], off[0], off[1]],
        [off[0], diag[1], off[2]],
        [off[1], off[2], diag[2]],
    ]
}

// ---- The formulas, each as its source states it. ----

/// ArduPilot `libraries/AP_Compass/AP_Compass_Backend.cpp`, `AP_Compass_Backend::correct_field`:
/// `mag += offsets; if (have_scale_factor(i)) mag *= scale_factor; mag = mat * mag;` then
/// `mag += motor_compensation * (throttle or current)`. `Compass::have_scale_factor` is false
/// outside `[COMPASS_MIN_SCALE_FACTOR, COMPASS_MAX_SCALE_FACTOR]` = `[1/1.5, 1.5]`
/// (`CompassCalibrator.h`), and a firmware without `COMPASS_SCALE` (ArduPilot 3.x) has no such
/// step.
fn ardupilot_correct(p: &BTreeMap<String, f64>, suffix: &str, r: Vec3, u: f64) -> Vec3 {
    let get = |name: String| p[&name];
    let axes = ["X", "Y", "Z"];
    let ofs = axes.map(|a| get(format!("COMPASS_OFS{suffix}_{a}")));
    let dia = axes.map(|a| get(format!("COMPASS_DIA{suffix}_{a}")));
    let odi = axes.map(|a| get(format!("COMPASS_ODI{suffix}_{a}")));
    let mut mag = [0, 1, 2].map(|i| r[i] + ofs[i]);
    if let Some(&scale) = p.get(&format!("COMPASS_SCALE{suffix}"))
        && (1.0 / 1.5..=1.5).contains(&scale)
    {
        mag = mag.map(|v| v * scale);
    }
    let mut mag = mat_vec(&symmetric(dia, odi), mag);
    if p.get("COMPASS_MOTCT").is_some_and(|&ct| ct != 0.0) {
        let mot = axes.map(|a| get(format!("COMPASS_MOT{suffix}_{a}")));
        mag = [0, 1, 2].map(|i| mag[i] + mot[i] * u);
    }
    mag
}

/// PX4 `src/lib/sensor_calibration/Magnetometer.hpp`, `calibration::Magnetometer::Correct`:
/// `_rotation * (_scale * ((data + _power * _power_compensation) - _offset))`, with `_scale`
/// symmetric from `SCALE` and `ODIAG` (`set_scale`, `set_offdiagonal`), the rotation the identity
/// (CAL_MAGn_ROT none, no board rotation), and `_power` the throttle or the current in kA
/// (`VehicleMagnetometer::Run`: `bat_stat.current_a * 0.001f`).
fn px4_correct(p: &BTreeMap<String, f64>, n: u8, r: Vec3, amperes: f64) -> Vec3 {
    let get = |name: String| p[&name];
    let axes = ["X", "Y", "Z"];
    let off = axes.map(|a| get(format!("CAL_MAG{n}_{a}OFF")));
    let scale = axes.map(|a| get(format!("CAL_MAG{n}_{a}SCALE")));
    let odiag = axes.map(|a| get(format!("CAL_MAG{n}_{a}ODIAG")));
    // CAL_MAG_COMP_TYP 2: the current of battery 0, in kA.
    let (power, comp) = if p.get("CAL_MAG_COMP_TYP").map_or(0, |&t| t as i32) == 2 {
        (amperes * 0.001, axes.map(|a| get(format!("CAL_MAG{n}_{a}COMP"))))
    } else {
        (0.0, [0.0; 3])
    };
    mat_vec(
        &symmetric(scale, odiag),
        [0, 1, 2].map(|i| (r[i] + power * comp[i]) - off[i]),
    )
}

/// MotionCal `visualize.c`, `apply_calibration` (and Adafruit_Sensor_Calibration::calibrate):
/// `x = raw - V[0]; out.x = x * invW[0][0] + y * invW[0][1] + z * invW[0][2]`, ...
fn motioncal_correct(hard: Vec3, soft: &Mat3, r: Vec3) -> Vec3 {
    mat_vec(soft, [0, 1, 2].map(|i| r[i] - hard[i]))
}

// ---- Reading the text back. ----

/// `NAME,VALUE` lines (comments skipped), as Mission Planner's `ParamFile.loadParamFile` reads
/// them: split on comma, space and tab, two items.
fn read_param(text: &str) -> BTreeMap<String, f64> {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let items: Vec<&str> = l.split([',', ' ', '\t']).filter(|s| !s.is_empty()).collect();
            assert_eq!(items.len(), 2, "{l}");
            (items[0].to_string(), items[1].parse().unwrap())
        })
        .collect()
}

/// `param set NAME VALUE` lines.
fn read_px4(text: &str) -> BTreeMap<String, f64> {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let items: Vec<&str> = l.split_whitespace().collect();
            assert_eq!(&items[..2], ["param", "set"], "{l}");
            (items[2].to_string(), items[3].parse().unwrap())
        })
        .collect()
}

fn numbers(text: &str) -> Vec<f64> {
    text.split(|c: char| c.is_whitespace() || c == ',' || c == '{' || c == '}' || c == ';')
        .filter_map(|w| w.trim_end_matches('f').parse().ok())
        .collect()
}

/// MotionCal's lines: hard iron, field, soft iron (xx yy zz xy xz yz).
fn read_motioncal(text: &str) -> (Vec3, f64, Mat3) {
    let line = |name: &str| {
        let l = text.lines().find(|l| l.starts_with(name)).unwrap();
        numbers(&l[name.len()..])
    };
    let h = line("mag_hardiron ");
    let s = line("mag_softiron ");
    (
        [h[0], h[1], h[2]],
        line("mag_field ")[0],
        symmetric([s[0], s[1], s[2]], [s[3], s[4], s[5]]),
    )
}

/// Magneto's B and Ainv, from the lines after their titles.
fn read_magneto(text: &str) -> (Vec3, Mat3) {
    let lines: Vec<&str> = text.lines().collect();
    let at = |title: &str| lines.iter().position(|l| l.starts_with(title)).unwrap() + 1;
    let b = numbers(lines[at("Combined bias vector B:")]);
    let a = at("Correction matrix Ainv");
    let row = |i: usize| {
        let v = numbers(lines[a + i]);
        [v[0], v[1], v[2]]
    };
    ([b[0], b[1], b[2]], [row(0), row(1), row(2)])
}

/// The C header's `magcal_hard_iron` and `magcal_soft_iron`.
fn read_c(text: &str) -> (Vec3, Mat3) {
    let after = |name: &str| &text[text.find(name).unwrap() + name.len()..];
    let h = numbers(after("magcal_hard_iron[3] ="));
    let s = numbers(after("magcal_soft_iron[3][3] ="));
    (
        [h[0], h[1], h[2]],
        [[s[0], s[1], s[2]], [s[3], s[4], s[5]], [s[6], s[7], s[8]]],
    )
}

// ---- Running magcal. ----

/// Exit code, stdout, stderr.
fn run(args: &[&std::ffi::OsStr]) -> (i32, String, String) {
    let out = magcal().args(args).output().unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    )
}

fn os(args: &[&str]) -> Vec<std::ffi::OsString> {
    args.iter().map(Into::into).collect()
}

/// `magcal calibrate LOG ARGS --out DIR`: its calibration.json (exit 0).
fn calibrate(log: &Path, args: &[&str], dir: &Path) -> PathBuf {
    let mut all = vec![std::ffi::OsString::from("calibrate"), log.into()];
    all.extend(os(args));
    all.extend(["--out".into(), dir.into()]);
    let refs: Vec<&std::ffi::OsStr> = all.iter().map(|s| s.as_os_str()).collect();
    let (code, _, stderr) = run(&refs);
    assert_eq!(code, 0, "{stderr}");
    dir.join("calibration.json")
}

/// `magcal export CAL --to TARGET ARGS`: exit code, stdout, stderr.
fn export(cal: &Path, to: &str, args: &[&str]) -> (i32, String, String) {
    let mut all = vec![std::ffi::OsString::from("export"), cal.into(), "--to".into(), to.into()];
    all.extend(os(args));
    let refs: Vec<&std::ffi::OsStr> = all.iter().map(|s| s.as_os_str()).collect();
    run(&refs)
}

/// `magcal apply CAL LOG --matrix M`: each reading's calibrated (x, y, z) and norm.
fn apply(cal: &Path, log: &Path, matrix: &str) -> Vec<(Vec3, f64)> {
    let (code, stdout, stderr) = run(&[
        "apply".as_ref(),
        cal.as_os_str(),
        log.as_os_str(),
        "--matrix".as_ref(),
        matrix.as_ref(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    stdout
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|c| c.parse().unwrap()).collect();
            ([v[1], v[2], v[3]], v[4])
        })
        .collect()
}

/// The raw readings of `log` in the columns named `columns` (a plain comma-separated log).
fn readings(log: &Path, columns: &[String; 3]) -> Vec<Vec3> {
    let text = fs::read_to_string(log).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let at = columns
        .clone()
        .map(|c| header.iter().position(|h| h.eq_ignore_ascii_case(&c)).unwrap());
    lines
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|c| c.parse().unwrap()).collect();
            at.map(|i| v[i])
        })
        .collect()
}

/// The largest of `|got_i - want_i| / |want|` over the readings and components.
fn worst(got: &[Vec3], want: &[Vec3]) -> f64 {
    assert_eq!(got.len(), want.len());
    got.iter()
        .zip(want)
        .flat_map(|(g, w)| (0..3).map(move |i| (g[i] - w[i]).abs() / length(*w)))
        .fold(0.0, f64::max)
}

/// A log, its calibration and what `apply` gives for it.
struct Case {
    name: &'static str,
    log: PathBuf,
    cal: PathBuf,
    /// `--units` for export, where the calibration does not record them.
    units: Vec<&'static str>,
    /// nT per unit of the log.
    nt: f64,
}

/// The logs of the round trip: ck-explorer (Gauss, units recorded), hamagure set 1 (Gauss, units
/// not recorded: `--units G`; `--reject 4`), and the 300-reading plan of scenarios/plan300.toml simulated (nT).
fn cases(dir: &Path) -> Vec<Case> {
    let wmm = ["--site", "28.2,112.97", "--date", "2013.0"];
    let mut out = Vec::new();
    if let Some(log) = data("ck-explorer/acc_mag_log.csv") {
        let cal = calibrate(&log, &[&wmm[..], &["--units", "G"]].concat(), &dir.join("ck"));
        out.push(Case {
            name: "ck-explorer",
            log,
            cal,
            units: vec![],
            nt: 1e5,
        });
    }
    if let Some(log) = data("hamagure/data-set_1.csv") {
        // Its last 43 readings pass through another field: dropped (docs/conventions.md "One field").
        let cal = calibrate(&log, &["--reject", "4"], &dir.join("h1"));
        out.push(Case {
            name: "hamagure set 1",
            log,
            cal,
            units: vec!["--units", "G"],
            nt: 1e5,
        });
    }
    out.push(simulated(dir));
    out
}

/// The 300-reading plan of scenarios/plan300.toml simulated (nT) and calibrated with the WMM
/// magnitude at its site.
fn simulated(dir: &Path) -> Case {
    let wmm = ["--site", "28.2,112.97", "--date", "2013.0"];
    let scenario = crate::common::scenarios().join("plan300.toml");
    let log = dir.join("plan300.csv");
    let (code, _, stderr) = run(&[
        "simulate".as_ref(),
        scenario.as_os_str(),
        "--design".as_ref(),
        "plan300".as_ref(),
        "--out".as_ref(),
        log.as_os_str(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let cal = calibrate(&log, &[&wmm[..], &["--units", "nT"]].concat(), &dir.join("sim"));
    Case {
        name: "plan300 simulated",
        log,
        cal,
        units: vec![],
        nt: 1.0,
    }
}

/// Round-trip tolerance asked of the exports, relative to |b|: the autopilots store floats
/// (6e-8 relative), well inside it.
const ROUND_TRIP: f64 = 1e-6;
/// What the round trip in f64 actually leaves: the exported decimals read back as the same
/// f64, so only the rounding of a 3 x 3 product and a difference remains, a few eps times the
/// condition of M (about 3 here).
const EXACT: f64 = 256.0 * f64::EPSILON;

#[test]
fn every_export_applied_by_its_own_formula_gives_what_apply_gives() {
    let tmp = TempDir::new().unwrap();
    for case in cases(tmp.path()) {
        let cal = magcal_runner::log::calibration::read_calibration(&case.cal).unwrap();
        let raw = readings(&case.log, &cal.columns);
        let symmetric_apply = apply(&case.cal, &case.log, "symmetric");
        let triangular_apply = apply(&case.cal, &case.log, "triangular");
        assert_eq!(symmetric_apply.len(), raw.len());
        // The two factorisations give the same |b|.
        for ((_, a), (_, b)) in symmetric_apply.iter().zip(&triangular_apply) {
            assert!((a - b).abs() <= ROUND_TRIP * b, "{}: {a} {b}", case.name);
        }
        let want_in = |nt_per_unit: f64| -> Vec<Vec3> {
            symmetric_apply
                .iter()
                .map(|(b, _)| b.map(|v| v * case.nt / nt_per_unit))
                .collect()
        };
        let raw_in =
            |nt_per_unit: f64| -> Vec<Vec3> { raw.iter().map(|r| r.map(|v| v * case.nt / nt_per_unit)).collect() };
        let units: Vec<&str> = case.units.clone();
        let text = |to: &str| {
            let (code, stdout, stderr) = export(&case.cal, to, &units);
            assert_eq!(code, 0, "{}: {to}: {stderr}", case.name);
            stdout
        };

        // ArduPilot, mGauss (100 nT).
        let p = read_param(&text("ardupilot"));
        let got: Vec<Vec3> = raw_in(100.0)
            .iter()
            .map(|&r| ardupilot_correct(&p, "", r, 0.0))
            .collect();
        let s = p["COMPASS_SCALE"];
        if (1.0 / 1.5..=1.5).contains(&s) {
            let w = worst(&got, &want_in(100.0));
            eprintln!("{}: ArduPilot within {w:.1e} of |b|", case.name);
            assert!(
                w <= EXACT && EXACT < ROUND_TRIP,
                "{}: ArduPilot off by {w:e}",
                case.name
            );
        } else {
            // ArduPilot ignores such a scale (and export says so): what it computes is |b| / s.
            for (g, (_, n)) in got.iter().zip(&triangular_apply) {
                let ratio = length(*g) / (n * case.nt / 100.0);
                assert!((ratio * s - 1.0).abs() <= ROUND_TRIP, "{}: {ratio} {s}", case.name);
            }
        }
        // PX4, Gauss.
        let p = read_px4(&text("px4"));
        let got: Vec<Vec3> = raw_in(1e5).iter().map(|&r| px4_correct(&p, 0, r, 0.0)).collect();
        let w = worst(&got, &want_in(1e5));
        eprintln!("{}: PX4 within {w:.1e} of |b|", case.name);
        assert!(w <= EXACT && EXACT < ROUND_TRIP, "{}: PX4 off by {w:e}", case.name);
        // MotionCal, uT; its field is the calibration's magnitude.
        let (hard, field, soft) = read_motioncal(&text("motioncal"));
        let got: Vec<Vec3> = raw_in(1e3).iter().map(|&r| motioncal_correct(hard, &soft, r)).collect();
        let w = worst(&got, &want_in(1e3));
        assert!(
            w <= EXACT && EXACT < ROUND_TRIP,
            "{}: MotionCal off by {w:e}",
            case.name
        );
        assert!((field - cal.magnitude * case.nt / 1e3).abs() <= ROUND_TRIP * field);
        // Magneto and C, in the log's units: Hcalc = Ainv (H - B).
        for (to, (b, a)) in [("magneto", read_magneto(&text("magneto"))), ("c", read_c(&text("c")))] {
            let got: Vec<Vec3> = raw_in(case.nt)
                .iter()
                .map(|&r| mat_vec(&a, [0, 1, 2].map(|i| r[i] - b[i])))
                .collect();
            let w = worst(&got, &want_in(case.nt));
            eprintln!("{}: {to} within {w:.1e} of |b|", case.name);
            assert!(w <= EXACT && EXACT < ROUND_TRIP, "{}: {to} off by {w:e}", case.name);
        }
        eprintln!("{}: {} readings round-trip within {ROUND_TRIP:e}", case.name, raw.len());
    }
}

/// `text` with the sign of parameter `name`'s value flipped.
fn flipped(text: &str, name: &str) -> String {
    text.lines()
        .map(|l| {
            let sep = if l.starts_with("param set") { ' ' } else { ',' };
            match l.rsplit_once(sep) {
                Some((head, v)) if head.ends_with(name) => {
                    let v: f64 = v.parse().unwrap();
                    format!("{head}{sep}{}\n", -v)
                }
                _ => format!("{l}\n"),
            }
        })
        .collect()
}

#[test]
fn the_offsets_carry_opposite_signs_and_a_flipped_sign_is_caught() {
    let tmp = TempDir::new().unwrap();
    let case = simulated(tmp.path());
    let raw = readings(&case.log, &["mx", "my", "mz"].map(String::from));
    let want: Vec<Vec3> = apply(&case.cal, &case.log, "symmetric")
        .iter()
        .map(|(b, _)| *b)
        .collect();
    let ap = export(&case.cal, "ardupilot", &[]).1;
    let px4 = export(&case.cal, "px4", &[]).1;
    let (a, p) = (read_param(&ap), read_px4(&px4));
    // ArduPilot adds its offsets (mGauss), PX4 subtracts its own (Gauss): -OFS = 1000 OFF.
    for (x, y) in [("OFS_X", "XOFF"), ("OFS_Y", "YOFF"), ("OFS_Z", "ZOFF")] {
        let (o, f) = (a[&format!("COMPASS_{x}")], p[&format!("CAL_MAG0_{y}")]);
        assert!(o != 0.0 && (o + 1000.0 * f).abs() <= 1e-12 * o.abs(), "{x}: {o} {f}");
    }
    // Each formula with the export as written matches; with one offset's sign flipped it is off
    // by twice that offset (30 mGauss of a 483 mGauss field here), far beyond the round trip.
    let nt = |v: &Vec3, per: f64| v.map(|x| x * case.nt / per);
    let in_mg: Vec<Vec3> = want.iter().map(|w| nt(w, 100.0)).collect();
    let in_g: Vec<Vec3> = want.iter().map(|w| nt(w, 1e5)).collect();
    for (text, good) in [(ap.clone(), true), (flipped(&ap, "COMPASS_OFS_X"), false)] {
        let p = read_param(&text);
        let got: Vec<Vec3> = raw
            .iter()
            .map(|r| ardupilot_correct(&p, "", nt(r, 100.0), 0.0))
            .collect();
        let w = worst(&got, &in_mg);
        assert_eq!(w <= ROUND_TRIP, good, "ArduPilot {w:e}");
        if !good {
            assert!(w > 0.01, "{w}");
        }
    }
    for (text, good) in [(px4.clone(), true), (flipped(&px4, "CAL_MAG0_XOFF"), false)] {
        let p = read_px4(&text);
        let got: Vec<Vec3> = raw.iter().map(|r| px4_correct(&p, 0, nt(r, 1e5), 0.0)).collect();
        let w = worst(&got, &in_g);
        assert_eq!(w <= ROUND_TRIP, good, "PX4 {w:e}");
        if !good {
            assert!(w > 0.01, "{w}");
        }
    }
}

#[test]
fn motor_interference_is_cancelled_by_each_autopilots_compensation() {
    // The simulated log with a current u (0 to 19 A) at each reading adding d u to the raw
    // reading; calibration.json given that d: ArduPilot's MOT and PX4's COMP, applied with the
    // current by their formulas, give back the calibration of the reading without it.
    let tmp = TempDir::new().unwrap();
    let case = simulated(tmp.path());
    let d = [40.0, -25.0, 60.0]; // nT per ampere
    let mut json: serde_json::Value = serde_json::from_slice(&fs::read(&case.cal).unwrap()).unwrap();
    json["motor"] =
        serde_json::json!({"input": "current", "per_unit": d, "std_error": null, "input_range": [0.0, 19.0]});
    let cal = tmp.path().join("motor.json");
    fs::write(&cal, serde_json::to_vec(&json).unwrap()).unwrap();
    let raw = readings(&case.log, &["mx", "my", "mz"].map(String::from));
    let want: Vec<Vec3> = apply(&case.cal, &case.log, "symmetric")
        .iter()
        .map(|(b, _)| *b)
        .collect();
    let amps: Vec<f64> = (0..raw.len()).map(|i| (i % 20) as f64).collect();
    let with_motor: Vec<Vec3> = raw
        .iter()
        .zip(&amps)
        .map(|(r, u)| [0, 1, 2].map(|i| r[i] + d[i] * u))
        .collect();
    // Each autopilot: its text, the parameter naming the input (2: current), its formula, and
    // its unit in nT.
    type Formula = fn(&BTreeMap<String, f64>, Vec3, f64) -> Vec3;
    type Reader = fn(&str) -> BTreeMap<String, f64>;
    let autopilots: [(&str, Reader, &str, Formula, f64); 2] = [
        (
            "ardupilot",
            read_param,
            "COMPASS_MOTCT",
            |p, r, u| ardupilot_correct(p, "", r, u),
            100.0,
        ),
        (
            "px4",
            read_px4,
            "CAL_MAG_COMP_TYP",
            |p, r, u| px4_correct(p, 0, r, u),
            1e5,
        ),
    ];
    let mut px4 = BTreeMap::new();
    for (to, read, input, correct, per) in autopilots {
        let (code, text, stderr) = export(&cal, to, &[]);
        assert_eq!(code, 0, "{stderr}");
        let p = read(&text);
        assert_eq!(p[input], 2.0, "{to}");
        let got: Vec<Vec3> = with_motor
            .iter()
            .zip(&amps)
            .map(|(r, &u)| correct(&p, r.map(|v| v / per), u))
            .collect();
        let w = worst(&got, &want.iter().map(|b| b.map(|v| v / per)).collect::<Vec<_>>());
        assert!(w <= EXACT, "{to} with its motor compensation: {w:e}");
        px4 = p;
    }
    let p = px4;
    // The formula without the compensation is off by M d u: the test can fail.
    let got: Vec<Vec3> = with_motor
        .iter()
        .map(|r| px4_correct(&p, 0, r.map(|v| v / 1e5), 0.0))
        .collect();
    assert!(worst(&got, &want.iter().map(|b| b.map(|v| v / 1e5)).collect::<Vec<_>>()) > 0.01);
    // A tool without motor compensation says it drops it.
    let (code, _, stderr) = export(&cal, "motioncal", &[]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.contains("motor interference"), "{stderr}");
}

#[test]
fn the_conventions_check_values_are_reproduced() {
    // docs/conventions.md "Autopilot parameters": c = (120, -45, 300) mGauss and M.
    let cal = Calibration {
        bias: [120.0, -45.0, 300.0],
        matrix: [[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 1.01]],
        magnitude: 500.0,
        motor: None,
    };
    let mut bytes = Vec::new();
    fmt::write_ardupilot(&mut bytes, &[], &ArduPilot::new(&cal, 0)).unwrap();
    let p = read_param(&String::from_utf8(bytes).unwrap());
    let shown = |name: &str, digits: usize| format!("{:.*}", digits, p[name]);
    for (name, want) in [
        ("COMPASS_OFS_X", "-120"),
        ("COMPASS_OFS_Y", "45"),
        ("COMPASS_OFS_Z", "-300"),
    ] {
        assert_eq!(shown(name, 0), want);
    }
    assert_eq!(shown("COMPASS_SCALE", 2), "1.01");
    for (name, want) in [
        ("COMPASS_DIA_X", "1.039604"),
        ("COMPASS_DIA_Y", "0.960396"),
        ("COMPASS_DIA_Z", "1.000000"),
        ("COMPASS_ODI_X", "0.019802"),
        ("COMPASS_ODI_Y", "-0.009901"),
        ("COMPASS_ODI_Z", "0.029703"),
    ] {
        assert_eq!(shown(name, 6), want, "{name}");
    }
    // PX4 in Gauss: the same calibration, 1 mGauss = 0.001 Gauss.
    let mut bytes = Vec::new();
    fmt::write_px4(&mut bytes, &[], &Px4::new(&cal.scaled(1e-3), 0)).unwrap();
    let p = read_px4(&String::from_utf8(bytes).unwrap());
    for (name, want) in [
        ("CAL_MAG0_XOFF", "0.120"),
        ("CAL_MAG0_YOFF", "-0.045"),
        ("CAL_MAG0_ZOFF", "0.300"),
        ("CAL_MAG0_XSCALE", "1.050"),
        ("CAL_MAG0_YSCALE", "0.970"),
        ("CAL_MAG0_ZSCALE", "1.010"),
        ("CAL_MAG0_XODIAG", "0.020"),
        ("CAL_MAG0_YODIAG", "-0.010"),
        ("CAL_MAG0_ZODIAG", "0.030"),
    ] {
        assert_eq!(format!("{:.3}", p[name]), want, "{name}");
    }
}

#[test]
fn values_outside_what_ardupilot_takes_are_named_and_strict_refuses_them() {
    let tmp = TempDir::new().unwrap();
    let case = simulated(tmp.path());
    // The simulated sensor is inside every range: no warning.
    let (code, _, stderr) = export(&case.cal, "ardupilot", &[]);
    assert_eq!(code, 0, "{stderr}");
    assert!(!stderr.contains("warning"), "{stderr}");
    // A bias of 2000 mGauss on x: above COMPASS_OFFS_MAX (default 1800, or as given), per axis
    // and in length.
    let big = edited(&case.cal, "big.json", |j| {
        j["bias"][0] = serde_json::json!(200_000.0);
    });
    let (code, stdout, stderr) = export(&big, "ardupilot", &[]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("COMPASS_OFS_X,-2000\n"), "{stdout}");
    assert!(
        stderr.contains("magcal: warning: COMPASS_OFS_X = -2000 is outside -1800 to 1800 mGauss"),
        "{stderr}"
    );
    assert!(stderr.contains("|COMPASS_OFS| = "), "{stderr}");
    let (_, _, stderr) = export(&big, "ardupilot", &["--offs-max", "2500"]);
    assert!(!stderr.contains("warning"), "{stderr}");
    let refused = export(&big, "ardupilot", &["--strict"]);
    assert_refused(&refused, &["--strict: COMPASS_OFS_X = -2000", "(and 1 more)"]);
    // The same log in nT declared as Gauss: a field of 4.8e7 mGauss, which ArduPilot's
    // calibrator never sees (150 to 950).
    let wrong = edited(&case.cal, "wrong-units.json", |j| {
        j["units"] = serde_json::json!("G");
    });
    let (_, _, stderr) = export(&wrong, "ardupilot", &[]);
    assert!(stderr.contains("warning: the field magnitude = "), "{stderr}");
    assert!(stderr.contains("are the units right?"), "{stderr}");
    // ck-explorer's sensor reads the field 1.57 times too small: COMPASS_SCALE beyond 1.5, which
    // ArduPilot ignores (the round trip test shows what it then computes).
    if let Some(log) = data("ck-explorer/acc_mag_log.csv") {
        let cal = calibrate(
            &log,
            &["--site", "28.2,112.97", "--date", "2013.0", "--units", "G"],
            &tmp.path().join("ck"),
        );
        let (code, _, stderr) = export(&cal, "ardupilot", &[]);
        assert_eq!(code, 0, "{stderr}");
        assert!(stderr.contains("warning: COMPASS_SCALE = 1.56"), "{stderr}");
        assert!(stderr.contains("Compass::have_scale_factor"), "{stderr}");
    }
}

#[test]
fn frames_and_notes_are_said() {
    let tmp = TempDir::new().unwrap();
    let case = simulated(tmp.path());
    let (_, _, stderr) = export(&case.cal, "ardupilot", &[]);
    assert!(
        stderr.contains("note: ArduPilot keeps the bias and the symmetric A^-1"),
        "{stderr}"
    );
    assert!(stderr.contains("frame of its log's columns"), "{stderr}");
    // A PX4 log's sensor frame exported to ArduPilot, and an ArduPilot log's body frame to PX4.
    let px4 = edited(&case.cal, "px4.json", |j| {
        j["frame"] = serde_json::json!("sensor");
        j["log_format"] = serde_json::json!("PX4 ULog");
    });
    let (code, _, stderr) = export(&px4, "ardupilot", &[]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains("warning: the calibration is in the frame \"sensor\" (a PX4 ULog log)"),
        "{stderr}"
    );
    let (_, _, stderr) = export(&px4, "px4", &[]);
    assert!(!stderr.contains("warning"), "{stderr}");
    assert!(stderr.contains("CAL_MAG0_ID and CAL_MAG0_ROT"), "{stderr}");
    let ap = edited(&case.cal, "ap.json", |j| {
        j["frame"] = serde_json::json!("body (forward, right, down)");
    });
    let (_, _, stderr) = export(&ap, "px4", &[]);
    assert!(
        stderr.contains("warning: the calibration is in the frame \"body"),
        "{stderr}"
    );
    assert_refused(
        &export(&ap, "px4", &["--strict"]),
        &["--strict: the calibration is in the frame"],
    );
}

#[test]
fn bad_input_is_refused_before_anything_is_written() {
    let tmp = TempDir::new().unwrap();
    let case = simulated(tmp.path());
    let missing = tmp.path().join("nope.json");
    assert_refused(&export(&missing, "px4", &[]), &["nope.json: cannot read"]);
    let garbled = tmp.path().join("garbled.json");
    fs::write(&garbled, b"{\"log\": 3,").unwrap();
    assert_refused(
        &export(&garbled, "px4", &[]),
        &["garbled.json: not a magcal calibration"],
    );
    // A calibration made with --magnitude does not know its units: the autopilots need
    // --units; Magneto and C write the log's own units.
    let r = serde_json::from_slice::<serde_json::Value>(&fs::read(&case.cal).unwrap()).unwrap()["magnitude"]
        .as_f64()
        .unwrap();
    let unitless = calibrate(
        &case.log,
        &["--magnitude", &r.to_string()],
        &tmp.path().join("unitless"),
    );
    for to in ["ardupilot", "px4", "motioncal"] {
        assert_refused(&export(&unitless, to, &[]), &["field units is null", "give --units"]);
    }
    assert_eq!(export(&unitless, "ardupilot", &["--units", "nT"]).0, 0);
    let (code, stdout, stderr) = export(&unitless, "magneto", &[]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.contains("in the log's units"), "{stdout}");
    // Units given twice and differently.
    assert_refused(
        &export(&case.cal, "px4", &["--units", "G"]),
        &["units \"nT\", and --units G"],
    );
    // Instances the autopilot has no parameters for; an instance where there are none.
    assert_refused(
        &export(&case.cal, "ardupilot", &["--compass", "3"]),
        &["--compass 3", "0 to 2"],
    );
    assert_refused(
        &export(&case.cal, "px4", &["--compass", "4"]),
        &["--compass 4", "0 to 3"],
    );
    let from_file = edited(&case.cal, "instance.json", |j| {
        j["instance"] = serde_json::json!(3);
    });
    assert_refused(
        &export(&from_file, "ardupilot", &[]),
        &["instance.json's instance", "0 to 2"],
    );
    let (code, stdout, _) = export(&from_file, "px4", &[]);
    assert_eq!(code, 0);
    assert!(stdout.contains("param set CAL_MAG3_XOFF "), "{stdout}");
    let (code, stdout, _) = export(&case.cal, "ardupilot", &["--compass", "1"]);
    assert_eq!(code, 0);
    assert!(
        stdout.contains("\nCOMPASS_OFS2_X,") && stdout.contains("\nCOMPASS_SCALE2,"),
        "{stdout}"
    );
    assert_refused(
        &export(&case.cal, "c", &["--compass", "1"]),
        &["--compass 1", "no magnetometer instances"],
    );
    // A motor term that is not one.
    let bad_motor = edited(&case.cal, "motor.json", |j| {
        j["motor"] = serde_json::json!({"input": "rpm", "per_unit": [1.0, 2.0, 3.0], "std_error": null, "input_range": [0.0, 1.0]});
    });
    assert_refused(&export(&bad_motor, "px4", &[]), &["motor.input \"rpm\""]);
    // --out the calibration itself: refused, the file unchanged.
    let before = fs::read(&case.cal).unwrap();
    assert_refused(
        &export(&case.cal, "c", &["--out", case.cal.to_str().unwrap()]),
        &["calibration.json"],
    );
    assert_eq!(fs::read(&case.cal).unwrap(), before);
}

// ---- A calibration not marked usable. ----

/// Every target, with the line that opens its comments (the C header's is a block comment).
const TARGETS: [(&str, &str); 5] = [
    ("ardupilot", "# "),
    ("px4", "# "),
    ("motioncal", "# "),
    ("magneto", "# "),
    ("c", " * "),
];

/// The lines of an export that are not comments.
fn values(text: &str) -> Vec<&str> {
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with(" *") && !l.starts_with("/*"))
        .collect()
}

#[test]
fn a_calibration_not_usable_is_written_by_no_target_unless_forced() {
    let tmp = TempDir::new().unwrap();
    let case = simulated(tmp.path());
    let reasons = ["the log rejects the model", "the readings are not on an ellipsoid"];
    let unusable = edited(&case.cal, "unusable.json", |j| {
        j["usable"] = serde_json::json!(false);
        j["reasons"] = serde_json::json!(reasons);
    });
    let shown = unusable.display().to_string();
    for (to, comment) in TARGETS {
        // Refused: exit 3, one line naming the calibration, the output and the reasons; no file
        // made, an existing one left as it was, nothing on standard output.
        let out = tmp.path().join(format!("{to}.out"));
        let out_s = out.to_str().unwrap();
        let (code, stdout, stderr) = export(&unusable, to, &["--out", out_s]);
        assert_eq!(code, 3, "{to}: {stderr}");
        assert!(stdout.is_empty(), "{stdout}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        let want = format!(
            "magcal: not a calibration to use: {shown}: nothing written to {out_s}: the calibration is not marked usable: {}; --force writes it all the same, its first line saying so\n",
            reasons.join("; ")
        );
        assert_eq!(stderr, want);
        assert!(!out.exists(), "{to}");
        let before = b"COMPASS_OFS_X,1\n# a file the user had\n".to_vec();
        fs::write(&out, &before).unwrap();
        assert_eq!(export(&unusable, to, &["--out", out_s]).0, 3);
        assert_eq!(fs::read(&out).unwrap(), before, "{to}");
        let (code, stdout, stderr) = export(&unusable, to, &[]);
        assert_eq!((code, stdout.as_str()), (3, ""), "{to}: {stderr}");
        assert!(stderr.contains("nothing written to standard output"), "{stderr}");
        // Forced: written, its first comment line says it is not to use and why; exit 3. The
        // values are those of the same calibration marked usable.
        let (code, _, stderr) = export(&unusable, to, &["--force", "--out", out_s]);
        assert_eq!(code, 3, "{to}: {stderr}");
        assert!(
            stderr.ends_with(&format!(
                "magcal: not a calibration to use: {shown}: written with --force to {out_s}, its first line saying so: the calibration is not marked usable: {}\n",
                reasons.join("; ")
            )),
            "{stderr}"
        );
        let text = fs::read_to_string(&out).unwrap();
        let first = text.lines().find(|l| *l != "/*").unwrap();
        assert_eq!(
            first,
            format!(
                "{comment}NOT A CALIBRATION TO USE (written with --force): the calibration is not marked usable: {}",
                reasons.join("; ")
            ),
            "{to}"
        );
        if to == "c" {
            assert!(text.starts_with("/*\n"), "{text}");
        }
        let (code, usable_text, _) = export(&case.cal, to, &[]);
        assert_eq!(code, 0);
        assert!(!usable_text.contains("NOT A CALIBRATION"), "{usable_text}");
        assert_eq!(values(&text), values(&usable_text), "{to}");
        assert!(values(&text).len() >= 3, "{text}");
        // --force and --strict contradict each other: refused before anything is written.
        fs::remove_file(&out).unwrap();
        let (code, _, stderr) = export(&unusable, to, &["--force", "--strict", "--out", out_s]);
        assert_eq!(code, 2, "{stderr}");
        assert!(stderr.contains("'--force' cannot be used with '--strict'"), "{stderr}");
        assert!(!out.exists());
    }
    // --force on a usable calibration changes nothing; --strict on one not usable refuses it as
    // not usable (exit 3), nothing written.
    let (code, forced, _) = export(&case.cal, "ardupilot", &["--force"]);
    assert_eq!((code, forced), (0, export(&case.cal, "ardupilot", &[]).1));
    let (code, stdout, stderr) = export(&unusable, "px4", &["--strict"]);
    assert_eq!((code, stdout.as_str()), (3, ""), "{stderr}");
    // Without reasons, it says so.
    let bare = edited(&case.cal, "bare.json", |j| {
        j["usable"] = serde_json::json!(false);
        j["reasons"] = serde_json::json!([]);
    });
    let (code, _, stderr) = export(&bare, "c", &[]);
    assert_eq!(code, 3);
    assert!(stderr.contains("not marked usable, and gives no reasons"), "{stderr}");
}

// ---- The log's own parameters. ----

/// The true sensor of [`log_without_scale`]'s compass 1: `raw = K b + O` (mGauss), its gains
/// about 0.8 (so `COMPASS_SCALE` would be about 1.25) and its bias beyond a `COMPASS_OFFS_MAX` of
/// 850 on x.
const K1: Mat3 = [[0.80, 0.02, -0.01], [0.0, 0.76, 0.03], [0.0, 0.0, 0.84]];
const O1: Vec3 = [905.0, -310.0, 240.0];
/// The field at the log's site, north, east, down, mGauss (|F| = 457.38).
const FIELD_NED: Vec3 = [180.0, -20.0, 420.0];

/// A DataFlash log of compass 1 (`MAG` with `I` = 1) as a firmware without `COMPASS_SCALE*`
/// writes it (ArduPilot 3.x, as `pymavlink_test.BIN` was): `PARM` with every `COMPASS_OFS*`,
/// `DIA*`, `ODI*`, `MOT*`, `COMPASS_MOTCT` and `COMPASS_OFFS_MAX` 850, then `n` readings of
/// [`K1`], [`O1`] at random attitudes under an old calibration (`m = D (r + OFS)`, int16 fields as
/// ArduPilot casts them). The log and the true raw readings.
fn log_without_scale(dir: &Path, n: usize) -> (PathBuf, Vec<Vec3>) {
    use crate::dataflash::{V, Writer, c_bn, mv};
    use rand::RngExt;
    let mut w = Writer::new();
    w.fmt(0x81, "PARM", "QNf", "TimeUS,Name,Value");
    w.fmt(
        0x82,
        "MAG",
        "QBhhhhhhhhh",
        "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ",
    );
    let old_ofs = [-40.0f32, 25.0, 10.0];
    let (old_dia, old_odi) = ([1.02f32, 0.97, 1.01], [0.01f32, -0.02, 0.015]);
    let mut parm = |name: &str, v: f32| w.msg(0x81, &[V::N(1000.0), V::S(name), V::N(f64::from(v))]);
    for (sfx, ofs, dia, odi) in [
        ("", [0.0; 3], [1.0; 3], [0.0; 3]),
        ("2", old_ofs, old_dia, old_odi),
        ("3", [0.0; 3], [1.0; 3], [0.0; 3]),
    ] {
        for (c, a) in ["X", "Y", "Z"].iter().enumerate() {
            parm(&format!("COMPASS_OFS{sfx}_{a}"), ofs[c]);
            parm(&format!("COMPASS_DIA{sfx}_{a}"), dia[c]);
            parm(&format!("COMPASS_ODI{sfx}_{a}"), odi[c]);
            parm(&format!("COMPASS_MOT{sfx}_{a}"), 0.0);
        }
    }
    parm("COMPASS_MOTCT", 0.0);
    parm("COMPASS_OFFS_MAX", 850.0);
    parm("COMPASS_USE2", 1.0);
    let d = {
        let (a, o) = (old_dia.map(f64::from), old_odi.map(f64::from));
        [[a[0], o[0], o[1]], [o[0], a[1], o[2]], [o[1], o[2], a[2]]]
    };
    let mut rng = magcal_core::rng::stream_rng(32, 0);
    let mut raw = Vec::with_capacity(n);
    for i in 0..n {
        let roll = rng.random_range(-180.0f64..180.0).to_radians();
        let pitch = rng.random_range(-90.0f64..90.0).to_radians();
        let yaw = rng.random_range(0.0f64..360.0).to_radians();
        let c = c_bn(roll, pitch, yaw);
        let b: Vec3 = std::array::from_fn(|a| (0..3).map(|r| c[r][a] * FIELD_NED[r]).sum::<f64>());
        let kb = mv(&K1, b);
        let r: Vec3 = std::array::from_fn(|a| kb[a] + O1[a]);
        let m = mv(&d, std::array::from_fn(|a| r[a] + f64::from(old_ofs[a])));
        let mut vals = vec![V::N(2000.0 + 20_000.0 * i as f64), V::N(1.0)];
        vals.extend(m.map(V::N));
        vals.extend(old_ofs.map(|x| V::N(f64::from(x))));
        vals.extend([V::N(0.0); 3]);
        w.msg(0x82, &vals);
        raw.push(r);
    }
    (w.save(dir, "no-scale.bin"), raw)
}

/// The largest `||m| - |P (raw - bias)||` over `raw`, with `m` ArduPilot's field
/// ([`ardupilot_correct`]) from the parameters `p` of compass suffix `sfx` stored as ArduPilot
/// stores them (float32), and a bound on it: float32 rounding (2^-24 relative) of `D`
/// and `OFS`, through `m = D (r + OFS)` (and `s` where written), to 4 units.
fn ardupilot_against_p(
    p: &BTreeMap<String, f64>,
    sfx: &str,
    cal: &magcal_runner::log::calibration::CalibrationJson,
    raw: &[Vec3],
) -> (f64, f64) {
    let stored: BTreeMap<String, f64> = p.iter().map(|(k, v)| (k.clone(), f64::from(*v as f32))).collect();
    let u = f64::from(f32::EPSILON) / 2.0;
    let (mut worst, mut bound) = (0.0f64, 0.0f64);
    for r in raw {
        let m = ardupilot_correct(&stored, sfx, *r, 0.0);
        let b = cal.apply(*r);
        worst = worst.max((length(m) - length(b)).abs());
        // |dm| <= |D| |d(r + OFS)| + |dD| |r + OFS| with |dD| <= u |D|_F (and as much of s).
        let ofs = ["X", "Y", "Z"].map(|a| p[&format!("COMPASS_OFS{sfx}_{a}")]);
        let d_f = ["DIA", "ODI"]
            .iter()
            .flat_map(|g| ["X", "Y", "Z"].map(|a| p[&format!("COMPASS_{g}{sfx}_{a}")]))
            .map(|v| v * v)
            .sum::<f64>()
            .sqrt()
            * 2f64.sqrt();
        let s = p.get(&format!("COMPASS_SCALE{sfx}")).copied().unwrap_or(1.0);
        let shifted = length([0, 1, 2].map(|i| r[i] + ofs[i]));
        bound = bound.max(4.0 * u * d_f * s * (length(ofs) + 2.0 * shifted));
    }
    (worst, bound)
}

#[test]
fn a_dataflash_logs_own_offs_max_and_parameters_decide_what_is_written() {
    let tmp = TempDir::new().unwrap();
    let (log, raw) = log_without_scale(tmp.path(), 600);
    let r = length(FIELD_NED);
    let cal_path = calibrate(
        &log,
        &["--compass", "1", "--magnitude", &r.to_string()],
        &tmp.path().join("cal"),
    );
    let cal = magcal_runner::log::calibration::read_calibration(&cal_path).unwrap();
    // What calibrate records of the log's parameters: the 37 COMPASS_* the firmware has of
    // those export writes (no SCALE), and COMPASS_OFFS_MAX.
    let json: serde_json::Value = serde_json::from_slice(&fs::read(&cal_path).unwrap()).unwrap();
    let lp = &json["log_parameters"];
    assert_eq!(lp["autopilot"], "ArduPilot");
    assert_eq!(lp["source"], "PARM");
    assert_eq!(lp["compass_offs_max"], 850.0);
    let names: Vec<&str> = lp["names"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n.as_str().unwrap())
        .collect();
    assert_eq!(names.len(), 37, "{names:?}");
    assert!(names.contains(&"COMPASS_DIA2_X") && names.contains(&"COMPASS_MOTCT"));
    assert!(!names.iter().any(|n| n.contains("SCALE")), "{names:?}");
    assert_eq!(cal.instance, Some(1));
    // The fit: the true bias to within the int16 logging's noise.
    for (b, o) in cal.bias.iter().zip(O1) {
        assert!((b - o).abs() < 1.0, "{:?}", cal.bias);
    }

    let (code, text, stderr) = export(&cal_path, "ardupilot", &[]);
    assert_eq!(code, 0, "{stderr}");
    let p = read_param(&text);
    // No COMPASS_SCALE2: its scale, about 1.25, is carried by D = M.
    assert!(!text.lines().any(|l| l.starts_with("COMPASS_SCALE")), "{text}");
    let m = &cal.soft_iron_inverse;
    let s = (m[0][0] + m[1][1] + m[2][2]) / 3.0;
    assert!((1.2..1.3).contains(&s), "{s}");
    eprintln!(
        "COMPASS_SCALE2 = {s} folded into DIA2 = {:?}",
        [m[0][0], m[1][1], m[2][2]]
    );
    let said = format!(
        "COMPASS_SCALE2: not written, the log's firmware has none (its PARM list every parameter it has); its scale {s} is carried by COMPASS_DIA2_* and COMPASS_ODI2_* (D = M: ArduPilot then applies m = D (r + OFS))"
    );
    assert!(text.contains(&format!("# {said}\n")), "{text}");
    assert!(stderr.contains(&format!("magcal: note: {said}\n")), "{stderr}");
    for (name, v) in [
        ("COMPASS_DIA2_X", m[0][0]),
        ("COMPASS_DIA2_Y", m[1][1]),
        ("COMPASS_DIA2_Z", m[2][2]),
        ("COMPASS_ODI2_X", m[0][1]),
        ("COMPASS_ODI2_Y", m[0][2]),
        ("COMPASS_ODI2_Z", m[1][2]),
    ] {
        assert_eq!(p[name], v, "{name}");
    }
    assert!(
        (1.2..1.35).contains(&p["COMPASS_DIA2_Y"]),
        "{}: inside ArduPilot's 0.2 to 5",
        p["COMPASS_DIA2_Y"]
    );
    // ArduPilot's formula with the parameters as written (decimals that read back as the same
    // f64) gives |P (raw - bias)| of the calibration to the rounding of the arithmetic; as
    // ArduPilot stores them (float32), to float32 rounding; on the true raw readings.
    let exact = raw
        .iter()
        .map(|r| {
            let b = cal.apply(*r);
            (length(ardupilot_correct(&p, "2", *r, 0.0)) - length(b)).abs() / length(b)
        })
        .fold(0.0, f64::max);
    assert!(exact <= EXACT, "{exact:e}");
    let (worst, bound) = ardupilot_against_p(&p, "2", &cal, &raw);
    eprintln!("ArduPilot without COMPASS_SCALE2: ||m| - |P (r - c)|| <= {worst:.2e} mGauss (bound {bound:.2e})");
    assert!(worst <= bound && bound < 1e-2, "{worst} {bound}");
    // The formula with COMPASS_SCALE2 written as a firmware with it would take it (s D = M):
    // the same field; dropping the scale without folding it into D would be 1/s off.
    let unfolded: BTreeMap<String, f64> = p
        .iter()
        .map(|(k, v)| {
            (
                k.clone(),
                if k.starts_with("COMPASS_DIA2") || k.starts_with("COMPASS_ODI2") {
                    v / s
                } else {
                    *v
                },
            )
        })
        .collect();
    let b = cal.apply(raw[0]);
    let m0 = ardupilot_correct(&unfolded, "2", raw[0], 0.0);
    assert!((length(m0) * s / length(b) - 1.0).abs() < 1e-12);

    // The range check uses the log's COMPASS_OFFS_MAX, 850: OFS2_X = -c_x, about -905.
    let ofs_x = p["COMPASS_OFS2_X"];
    assert!((-906.0..-904.0).contains(&ofs_x), "{ofs_x}");
    assert!(
        stderr.contains(
            "magcal: note: the offsets are checked against COMPASS_OFFS_MAX = 850 mGauss: the log's (PARM)\n"
        ),
        "{stderr}"
    );
    assert!(
        text.contains("# the offsets are checked against COMPASS_OFFS_MAX = 850 mGauss: the log's (PARM)\n"),
        "{text}"
    );
    assert!(
        stderr.contains(&format!(
            "magcal: warning: COMPASS_OFS2_X = {ofs_x} is outside -850 to 850 mGauss"
        )),
        "{stderr}"
    );
    assert!(stderr.contains("magcal: warning: |COMPASS_OFS2| = "), "{stderr}");
    assert!(!stderr.contains("COMPASS_OFS2_Y ="), "{stderr}");
    assert_refused(
        &export(&cal_path, "ardupilot", &["--strict"]),
        &["--strict: COMPASS_OFS2_X = ", "(and 1 more)"],
    );
    // --offs-max overrides it, and says over what.
    let (code, text2, stderr) = export(&cal_path, "ardupilot", &["--offs-max", "1000"]);
    assert_eq!(code, 0);
    assert!(!stderr.contains("warning"), "{stderr}");
    assert!(
        stderr.contains("COMPASS_OFFS_MAX = 1000 mGauss: --offs-max, over the log's 850 (PARM)"),
        "{stderr}"
    );
    assert_eq!(values(&text2), values(&text));
    // PX4's parameters are not the log's firmware's: all written.
    let (code, px4, stderr) = export(&cal_path, "px4", &[]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(read_px4(&px4).len(), 9);
    assert!(
        !stderr.contains("not written") && !stderr.contains("COMPASS_OFFS_MAX"),
        "{stderr}"
    );

    // The same calibration as a file written before log_parameters: every parameter, the
    // default limit of 1800 (no warning for |OFS2| = 986), and the same field by the formula.
    let old = edited(&cal_path, "old.json", |j| {
        j.as_object_mut().unwrap().remove("log_parameters");
    });
    let (code, text, stderr) = export(&old, "ardupilot", &[]);
    assert_eq!(code, 0, "{stderr}");
    let p_old = read_param(&text);
    assert_eq!(p_old["COMPASS_SCALE2"], s);
    assert!(!stderr.contains("warning"), "{stderr}");
    assert!(
        stderr.contains("COMPASS_OFFS_MAX = 1800 mGauss: ArduPilot's default (calibration.json records no COMPASS_OFFS_MAX of its log)"),
        "{stderr}"
    );
    let (worst, bound) = ardupilot_against_p(&p_old, "2", &cal, &raw);
    assert!(worst <= bound, "{worst} {bound}");
}

#[test]
fn a_malformed_log_parameters_is_refused_naming_the_file_the_field_and_the_value() {
    let tmp = TempDir::new().unwrap();
    let case = simulated(tmp.path());
    let out = tmp.path().join("kept.param");
    fs::write(&out, b"kept\n").unwrap();
    for (name, value, said) in [
        (
            "offs.json",
            serde_json::json!({"autopilot": "ArduPilot", "source": "PARM", "names": null, "compass_offs_max": "850"}),
            "log_parameters.compass_offs_max \"850\": not null or a number of mGauss from 1 to 32767",
        ),
        (
            "negative.json",
            serde_json::json!({"autopilot": "ArduPilot", "source": "PARM", "names": null, "compass_offs_max": -3}),
            "log_parameters.compass_offs_max -3: not null",
        ),
        (
            "names.json",
            serde_json::json!({"autopilot": "ArduPilot", "source": "PARM", "names": ["COMPASS_OFS_X", 7]}),
            "log_parameters.names: 7: not a parameter name",
        ),
        (
            "autopilot.json",
            serde_json::json!({"autopilot": "Betaflight", "source": "PARM"}),
            "log_parameters.autopilot \"Betaflight\": not \"ArduPilot\" or \"PX4\"",
        ),
    ] {
        let bad = edited(&case.cal, name, |j| j["log_parameters"] = value);
        for to in ["ardupilot", "c"] {
            assert_refused(
                &export(&bad, to, &["--out", out.to_str().unwrap()]),
                &[&format!("{}: not a magcal calibration: {said}", bad.display())],
            );
        }
        assert_eq!(fs::read(&out).unwrap(), b"kept\n");
    }
    // null, as a CSV log's calibration has it: written as before.
    let null = edited(&case.cal, "null.json", |j| {
        j["log_parameters"] = serde_json::Value::Null
    });
    assert_eq!(export(&null, "ardupilot", &[]).0, 0);
}

#[test]
fn a_px4_19_log_without_odiag_gets_no_odiag_and_says_what_is_lost() {
    // PX4 1.9 (esc_status_log.ulg) had no CAL_MAGn_*ODIAG: its calibration (not usable: the log
    // is too short) forced to PX4 writes offsets and scales, and says the off-diagonal terms
    // are lost.
    let Some(log) = data("px4/esc_status_log.ulg") else {
        return;
    };
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path().join("cal");
    let (code, _, stderr) = run(&["calibrate".as_ref(), log.as_os_str(), "--out".as_ref(), dir.as_os_str()]);
    assert_eq!(code, 3, "{stderr}");
    let cal = dir.join("calibration.json");
    let json: serde_json::Value = serde_json::from_slice(&fs::read(&cal).unwrap()).unwrap();
    assert_eq!(json["log_parameters"]["autopilot"], "PX4");
    assert_eq!(json["log_parameters"]["names"].as_array().unwrap().len(), 24);
    assert_eq!(export(&cal, "px4", &[]).0, 3);
    let (code, text, stderr) = export(&cal, "px4", &["--force"]);
    assert_eq!(code, 3, "{stderr}");
    let p = read_px4(&text);
    assert_eq!(
        p.keys().map(String::as_str).collect::<Vec<_>>(),
        [
            "CAL_MAG0_XOFF",
            "CAL_MAG0_XSCALE",
            "CAL_MAG0_YOFF",
            "CAL_MAG0_YSCALE",
            "CAL_MAG0_ZOFF",
            "CAL_MAG0_ZSCALE"
        ]
    );
    let said = "CAL_MAG0_*ODIAG: not written, the log's firmware has none (its ULog parameters list every parameter it has); the off-diagonal terms are not carried: PX4 applies the diagonal alone";
    assert!(text.contains(&format!("\n# {said}\n")), "{text}");
    assert!(stderr.contains(&format!("magcal: warning: {said}\n")), "{stderr}");
    assert!(
        text.starts_with(
            "# NOT A CALIBRATION TO USE (written with --force): the calibration is not marked usable: not identifiable"
        ),
        "{text}"
    );
}
