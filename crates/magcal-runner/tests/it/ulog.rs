//! The PX4 ULog reader (`log::ulog`), in-process:
//! - the three public fixtures of `../shared/data/px4/` (skipped, saying so, where that folder is
//!   absent) against pyulog's reading of the same files, committed in `tests/flightlogs.json` by
//!   `scripts/crosscheck-flightlogs.py`;
//! - synthetic logs written here (header, flag bits, formats, info, parameters, add-logged, data,
//!   dropouts) from a known sensor and known attitudes: the reader returns exactly what was
//!   written, and undoes a pre-1.12 calibration with the values in force at each reading;
//! - corrupt logs: every truncation of a synthetic log, truncations of the fixtures, random byte
//!   flips and insertions, and crafted absurd messages. Always `Ok` or an error naming the byte
//!   offset; never a panic, a hang or unbounded memory.

use std::path::{Path, PathBuf};

use magcal_runner::log::flight::{InForce, Selection};
use magcal_runner::log::ulog::{self, Px4Log};
use proptest::prelude::*;
use proptest::test_runner::{Config, FileFailurePersistence};

/// The PX4 fixtures, where `../shared/data/` is present.
fn fixtures() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/px4");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("skipped: {} is absent", dir.display());
        None
    }
}

fn expectations() -> serde_json::Value {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/flightlogs.json")).unwrap();
    let all: serde_json::Value = serde_json::from_str(&text).unwrap();
    all["px4"].clone()
}

fn read_bytes(bytes: &[u8], instance: Option<u8>) -> anyhow::Result<Px4Log> {
    ulog::read_from(bytes, "test.ulg", &Selection { instance })
}

/// Within `k` ulps of f64 of the larger magnitude (serde_json's default parser, without its
/// `float_roundtrip` feature, may read a number one ulp off what Python wrote).
fn close(a: f64, b: f64, k: f64) -> bool {
    (a - b).abs() <= k * f64::EPSILON * a.abs().max(b.abs()).max(f64::MIN_POSITIVE)
}

fn vec_of(v: &serde_json::Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
}

#[test]
fn fixtures_read_as_pyulog_reads_them() {
    let Some(dir) = fixtures() else { return };
    let want = expectations();
    let files = want["files"].as_object().unwrap();
    assert_eq!(files.len(), 3);
    for (name, w) in files {
        let path = dir.join(name);
        let instances = w["instances"].as_object().unwrap();
        for (inst, wi) in instances {
            let inst: u8 = inst.parse().unwrap();
            let p = ulog::read_px4(&path, &Selection { instance: Some(inst) }).unwrap();
            let log = &p.log;
            let ctx = format!("{name} instance {inst}");
            let keys: Vec<u8> = instances.keys().map(|k| k.parse().unwrap()).collect();
            assert_eq!(log.instances, keys, "{ctx}");
            assert_eq!(log.instance, inst, "{ctx}");
            assert_eq!(log.unit, magcal_runner::scenario::site::Units::Gauss, "{ctx}");
            assert!(
                log.messages[0].starts_with(w["topic"].as_str().unwrap()),
                "{ctx}: {:?}",
                log.messages
            );
            assert!(wi["monotonic"].as_bool().unwrap(), "{ctx}: pyulog sees time go back");
            // Counts, times, rate.
            assert_eq!(log.samples.len() as u64, wi["count"].as_u64().unwrap(), "{ctx}");
            let (first, last) = (log.samples[0].time_s, log.samples.last().unwrap().time_s);
            assert!(close(first, wi["first_t_s"].as_f64().unwrap(), 2.0), "{ctx}: {first}");
            assert!(close(last, wi["last_t_s"].as_f64().unwrap(), 2.0), "{ctx}: {last}");
            assert!(
                close(p.rate_hz, wi["rate_hz"].as_f64().unwrap(), 16.0),
                "{ctx}: {}",
                p.rate_hz
            );
            // What the readings carry, and the readings.
            let in_force = w["in_force"].as_str().unwrap();
            match (&log.calibration, in_force) {
                (InForce::Raw, "raw") | (InForce::Undone(_), "undone") | (InForce::Calibrated(_), "calibrated") => {}
                (got, want) => panic!("{ctx}: {got:?}, pyulog's version says {want}"),
            }
            for (sample, key) in [
                (&log.samples[0], "raw_first"),
                (log.samples.last().unwrap(), "raw_last"),
            ] {
                let want = vec_of(&wi[key]);
                for k in 0..3 {
                    assert!(
                        close(sample.raw[k], want[k], 4.0),
                        "{ctx} {key}: {:?} against {want:?}",
                        sample.raw
                    );
                }
            }
            // The calibration slot and its parameters.
            let n = wi["calibration_index"].as_u64().map(|n| n as u8);
            assert_eq!(p.calibration_index, n, "{ctx}");
            let how = wi["matched_by"].as_str().unwrap();
            assert!(
                p.matched_by.contains(match how {
                    "device_id" => "= device_id",
                    "instance" => "instance number",
                    _ => "no CAL_MAGn",
                }),
                "{ctx}: {}",
                p.matched_by
            );
            if let Some(dev) = wi["device_id"].as_u64() {
                assert!(
                    log.messages[0].contains(&format!("device_id {dev}")),
                    "{ctx}: {:?}",
                    log.messages
                );
            }
            let want_parameters = wi["parameters"].as_object().unwrap();
            assert!(!want_parameters.is_empty(), "{ctx}");
            for (k, v) in want_parameters {
                let got = p.parameters.get(k).copied().unwrap_or(f64::NAN);
                assert!(close(got, v.as_f64().unwrap(), 2.0), "{ctx}: {k} = {got}, pyulog {v}");
            }
            assert_eq!(p.ver_sw_release.map(u64::from), w["ver_sw_release"].as_u64(), "{ctx}");
            // The series beside the readings.
            let att = log.attitude.as_ref().unwrap();
            let wa = &w["attitude"];
            assert_eq!(att.times.len() as u64, wa["count"].as_u64().unwrap(), "{ctx}");
            assert!(close(att.times[0], wa["first_t_s"].as_f64().unwrap(), 2.0), "{ctx}");
            for (got, key) in [(att.values[0], "first"), (*att.values.last().unwrap(), "last")] {
                let want = vec_of(&wa[key]);
                assert!(
                    (0..4).all(|k| close(got[k], want[k], 2.0)),
                    "{ctx}: {got:?} against {want:?}"
                );
            }
            for (series, key) in [(&log.current, "current"), (&log.throttle, "throttle")] {
                let s = series.as_ref().unwrap();
                let ws = &w[key];
                assert_eq!(s.times.len() as u64, ws["count"].as_u64().unwrap(), "{ctx} {key}");
                let pairs = [
                    (*s.times.last().unwrap(), ws["last_t_s"].as_f64().unwrap()),
                    (s.values[0], vec_of(&ws["first"])[0]),
                    (*s.values.last().unwrap(), vec_of(&ws["last"])[0]),
                ];
                for (got, want) in pairs {
                    assert!(close(got, want, 2.0), "{ctx} {key}: {got} against {want}");
                }
            }
            assert_eq!(log.throttle.is_some(), !w["throttle"].is_null());
            let throttle_topic = w["throttle"]["topic"].as_str().unwrap();
            assert!(
                log.messages.iter().any(|m| m.starts_with(throttle_topic)),
                "{ctx}: {:?}",
                log.messages
            );
            // Every fixture logs the magnetometer too slowly to calibrate, and says so.
            let rate = format!("{:.2} Hz", wi["rate_hz"].as_f64().unwrap());
            assert!(
                log.notes
                    .iter()
                    .any(|n| n.contains(&rate) && n.contains("SDLOG_PROFILE")),
                "{ctx}: {:?}",
                log.notes
            );
        }
    }
}

#[test]
fn fixtures_say_what_their_readings_carry() {
    let Some(dir) = fixtures() else { return };
    // Firmware 1.16: raw, sensor frame; CAL_MAG0_ROT = 0 (external) and the level adjustment
    // SENS_BOARD_X_OFF = -0.82, Y_OFF = 0.46 degrees give the rotation into the body frame.
    let p = ulog::read_px4(&dir.join("quadrotor_local.ulg"), &Selection::default()).unwrap();
    assert_eq!(p.log.calibration, InForce::Raw);
    assert_eq!(p.log.frame, "sensor");
    let r = p.log.to_body.unwrap();
    let want = ulog::euler_dcm(p.parameters["SENS_BOARD_X_OFF"], p.parameters["SENS_BOARD_Y_OFF"], 0.0);
    assert_eq!(r, want);
    assert!(
        p.log.messages.iter().any(|m| m.contains("v1.16.1 (release candidate)")),
        "{:?}",
        p.log.messages
    );
    // Instance 1 is internal (CAL_MAG1_ROT = -1): the board's rotation, SENS_BOARD_ROT = 0.
    let p1 = ulog::read_px4(&dir.join("quadrotor_local.ulg"), &Selection { instance: Some(1) }).unwrap();
    assert_eq!(p1.parameters["CAL_MAG1_ROT"], -1.0);
    assert_eq!(p1.log.to_body.unwrap(), want);
    // 1.11: the driver's calibration undone; instance 1 re-calibrated by CAL_MAG1 gives the logged
    // field back.
    let p = ulog::read_px4(&dir.join("sample_log_small.ulg"), &Selection { instance: Some(1) }).unwrap();
    let InForce::Undone(words) = &p.log.calibration else {
        panic!("{:?}", p.log.calibration)
    };
    assert!(
        words.contains("CAL_MAG1_XOFF") && words.contains("CAL_MAG1_ID = device_id 592905"),
        "{words}"
    );
    // 1.9: vehicle_magnetometer only, calibrated, body frame.
    let p = ulog::read_px4(&dir.join("esc_status_log.ulg"), &Selection::default()).unwrap();
    assert!(matches!(&p.log.calibration, InForce::Calibrated(w) if w.starts_with("vehicle_magnetometer")));
    assert_eq!(p.log.frame, "body (forward, right, down)");
    assert!(
        p.log.notes.iter().any(|n| n.contains("no sensor_mag")),
        "{:?}",
        p.log.notes
    );
    // An instance the log does not have.
    let e = ulog::read(&dir.join("quadrotor_local.ulg"), &Selection { instance: Some(3) }).unwrap_err();
    assert!(
        e.to_string()
            .contains("--compass 3: the log has sensor_mag instances 0, 1 only"),
        "{e}"
    );
}

/// A ULog writer: the messages of the specification, little-endian.
#[derive(Default)]
pub struct Writer {
    pub buf: Vec<u8>,
}

impl Writer {
    pub fn new() -> Self {
        let mut w = Self::default();
        w.buf.extend_from_slice(b"ULog\x01\x12\x35\x01");
        w.buf.extend_from_slice(&1_000u64.to_le_bytes());
        w
    }

    pub fn msg(&mut self, kind: u8, body: &[u8]) -> usize {
        let at = self.buf.len();
        self.buf.extend_from_slice(&(body.len() as u16).to_le_bytes());
        self.buf.push(kind);
        self.buf.extend_from_slice(body);
        at
    }

    pub fn flag_bits(&mut self, incompat0: u8, appended: u64) {
        let mut b = vec![0u8; 40];
        b[8] = incompat0;
        b[16..24].copy_from_slice(&appended.to_le_bytes());
        self.msg(b'B', &b);
    }

    pub fn format(&mut self, text: &str) {
        self.msg(b'F', text.as_bytes());
    }

    pub fn info_u32(&mut self, key: &str, v: u32) {
        let key = format!("uint32_t {key}");
        let mut b = vec![key.len() as u8];
        b.extend_from_slice(key.as_bytes());
        b.extend_from_slice(&v.to_le_bytes());
        self.msg(b'I', &b);
    }

    pub fn param(&mut self, name: &str, v: f32) -> usize {
        self.param_bytes(&format!("float {name}"), v.to_le_bytes())
    }

    pub fn param_i32(&mut self, name: &str, v: i32) -> usize {
        self.param_bytes(&format!("int32_t {name}"), v.to_le_bytes())
    }

    pub fn param_bytes(&mut self, key: &str, v: [u8; 4]) -> usize {
        let mut b = vec![key.len() as u8];
        b.extend_from_slice(key.as_bytes());
        b.extend_from_slice(&v);
        self.msg(b'P', &b)
    }

    pub fn add_logged(&mut self, multi_id: u8, id: u16, topic: &str) {
        let mut b = vec![multi_id];
        b.extend_from_slice(&id.to_le_bytes());
        b.extend_from_slice(topic.as_bytes());
        self.msg(b'A', &b);
    }

    pub fn data(&mut self, id: u16, fields: &[&[u8]]) -> usize {
        let mut b = id.to_le_bytes().to_vec();
        for f in fields {
            b.extend_from_slice(f);
        }
        self.msg(b'D', &b)
    }
}

const SENSOR_MAG: &str = "sensor_mag:uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;float z;float temperature;uint32_t error_count;";
const ATTITUDE: &str = "vehicle_attitude:uint64_t timestamp;uint64_t timestamp_sample;float[4] q;float[4] delta_q_reset;uint8_t quat_reset_counter;uint8_t[7] _padding0;";
const ESC_REPORT: &str = "esc_report:uint64_t timestamp;int32_t esc_rpm;float esc_current;";
const ESC_STATUS: &str = "esc_status:uint64_t timestamp;uint8_t esc_count;uint8_t[7] _padding0;esc_report[2] esc;";
const BATTERY: &str = "battery_status:uint64_t timestamp;float voltage_v;float current_a;";
const THRUST: &str = "vehicle_thrust_setpoint:uint64_t timestamp;uint64_t timestamp_sample;float[3] xyz;";

const DEVICE: u32 = 396809;

/// The true sensor of the synthetic logs: `r = K b + O`, Gauss, sensor frame = body frame.
const K: [[f64; 3]; 3] = [[1.05, 0.02, -0.01], [0.0, 0.97, 0.03], [0.0, 0.0, 1.01]];
const O: [f64; 3] = [0.12, -0.045, 0.3];
/// The Earth's field, NED, Gauss.
const FIELD_NED: [f64; 3] = [0.21, -0.01, 0.43];

/// Roll, pitch, yaw (radians) of attitude `i` of `n`: yaw through two full turns, roll and
/// pitch swinging by 30 degrees.
fn angles(i: usize, n: usize) -> [f64; 3] {
    let s = i as f64 / n as f64;
    [
        0.5 * (10.0 * s).cos(),
        0.5 * (6.0 * s).sin(),
        4.0 * std::f64::consts::PI * s,
    ]
}

/// Attitude `i` of `n` as the quaternion `[w, x, y, z]` (body FRD to NED) of its angles.
fn attitude(i: usize, n: usize) -> [f32; 4] {
    let [roll, pitch, yaw] = angles(i, n);
    let (cy, sy) = ((yaw / 2.0).cos(), (yaw / 2.0).sin());
    let (cp, sp) = ((pitch / 2.0).cos(), (pitch / 2.0).sin());
    let (cr, sr) = ((roll / 2.0).cos(), (roll / 2.0).sin());
    [
        (cr * cp * cy + sr * sp * sy) as f32,
        (sr * cp * cy - cr * sp * sy) as f32,
        (cr * sp * cy + sr * cp * sy) as f32,
        (cr * cp * sy - sr * sp * cy) as f32,
    ]
}

/// The field in the body frame at attitude `i` of `n`: `C^T F` with `C = Rz(yaw) Ry(pitch)
/// Rx(roll)`, the rotation of the same angles as the quaternion.
fn body_field(i: usize, n: usize) -> [f64; 3] {
    let c = ulog::euler_dcm(
        angles(i, n)[0].to_degrees(),
        angles(i, n)[1].to_degrees(),
        angles(i, n)[2].to_degrees(),
    );
    std::array::from_fn(|i| (0..3).map(|k| c[k][i] * FIELD_NED[k]).sum())
}

/// The true sensor's reading at attitude `i` of `n`.
fn true_reading(i: usize, n: usize) -> [f64; 3] {
    let b = body_field(i, n);
    std::array::from_fn(|i| (0..3).map(|k| K[i][k] * b[k]).sum::<f64>() + O[i])
}

/// What a synthetic log was written with.
struct Written {
    bytes: Vec<u8>,
    times_us: Vec<u64>,
    readings: Vec<[f32; 3]>,
    attitudes: Vec<[f32; 4]>,
    offsets: Vec<usize>,
}

/// A log of `n` readings at 50 Hz of the true sensor (firmware `version`, PX4 1.12 and later
/// log raw readings), attitudes at 100 Hz, battery and thrust at 10 Hz, a nested topic logged
/// beside them, and `CAL_MAG0_*` with `rot`. `logged` turns the true reading into what is logged.
fn synthetic(n: usize, version: u32, rot: i32, logged: impl Fn(usize, [f64; 3]) -> [f32; 3]) -> Written {
    let mut w = Writer::new();
    w.flag_bits(0, 0);
    for f in [SENSOR_MAG, ATTITUDE, ESC_REPORT, ESC_STATUS, BATTERY, THRUST] {
        w.format(f);
    }
    w.info_u32("ver_sw_release", version);
    w.param_i32("CAL_MAG0_ID", DEVICE as i32);
    w.param_i32("CAL_MAG0_ROT", rot);
    for (k, v) in [
        ("XOFF", 0.25f32),
        ("YOFF", -0.5),
        ("ZOFF", 0.125),
        ("XSCALE", 1.25),
        ("YSCALE", 0.75),
        ("ZSCALE", 1.5),
    ] {
        w.param(&format!("CAL_MAG0_{k}"), v);
    }
    w.param_i32("SENS_BOARD_ROT", 4);
    w.param_i32("CAL_MAG_COMP_TYP", 2);
    w.add_logged(0, 0, "sensor_mag");
    w.add_logged(0, 1, "vehicle_attitude");
    w.add_logged(0, 2, "esc_status");
    w.add_logged(0, 3, "battery_status");
    w.add_logged(0, 4, "vehicle_thrust_setpoint");
    let mut out = Written {
        bytes: Vec::new(),
        times_us: Vec::new(),
        readings: Vec::new(),
        attitudes: Vec::new(),
        offsets: Vec::new(),
    };
    for i in 0..2 * n {
        let t = 5_000_000 + 10_000 * i as u64;
        let q = attitude(i, 2 * n);
        let mut delta = Vec::new();
        for x in q.iter().chain(&[0.0f32; 4]) {
            delta.extend_from_slice(&x.to_le_bytes());
        }
        w.data(1, &[&t.to_le_bytes(), &t.to_le_bytes(), &delta, &[3]]);
        out.attitudes.push(q);
        if i % 2 == 0 {
            let r = logged(i / 2, true_reading(i, 2 * n));
            let mut xyz = Vec::new();
            for x in r {
                xyz.extend_from_slice(&x.to_le_bytes());
            }
            let at = w.data(
                0,
                &[
                    &t.to_le_bytes(),
                    &(t - 300).to_le_bytes(),
                    &DEVICE.to_le_bytes(),
                    &xyz,
                    &25f32.to_le_bytes(),
                    &0u32.to_le_bytes(),
                ],
            );
            out.times_us.push(t);
            out.readings.push(r);
            out.offsets.push(at);
        }
        if i % 10 == 0 {
            let report = [
                t.to_le_bytes().as_slice(),
                &1234i32.to_le_bytes(),
                &2.5f32.to_le_bytes(),
            ]
            .concat();
            w.data(2, &[&t.to_le_bytes(), &[2], &[0; 7], &report, &report]);
            w.data(
                3,
                &[
                    &t.to_le_bytes(),
                    &16.0f32.to_le_bytes(),
                    &(i as f32 * 0.5).to_le_bytes(),
                ],
            );
            let thrust = [0.1f32, -0.2, -(i as f32) / (2 * n) as f32];
            w.data(
                4,
                &[
                    &t.to_le_bytes(),
                    &t.to_le_bytes(),
                    &thrust.map(f32::to_le_bytes).concat(),
                ],
            );
        }
        if i == n {
            w.msg(b'O', &150u16.to_le_bytes());
        }
    }
    out.bytes = w.buf;
    out
}

fn raw_log(n: usize) -> Written {
    synthetic(n, 0x010C00FF, 0, |_, r| r.map(|x| x as f32))
}

#[test]
fn a_synthetic_raw_log_reads_back_exactly() {
    let w = raw_log(1000);
    let p = read_bytes(&w.bytes, None).unwrap();
    let log = &p.log;
    assert_eq!(log.calibration, InForce::Raw);
    assert_eq!(log.instances, vec![0]);
    assert_eq!(log.samples.len(), 1000);
    for (i, s) in log.samples.iter().enumerate() {
        assert_eq!(s.raw, w.readings[i].map(f64::from), "reading {i}");
        assert_eq!(s.time_s, w.times_us[i] as f64 * 1e-6);
        assert_eq!(s.offset, w.offsets[i] as u64);
    }
    let att = log.attitude.as_ref().unwrap();
    assert_eq!(att.values.len(), 2000);
    for (i, q) in att.values.iter().enumerate() {
        assert_eq!(*q, w.attitudes[i].map(f64::from), "attitude {i}");
    }
    // 50 Hz: (n - 1) readings over 19.98 s.
    assert!((p.rate_hz - 50.0).abs() <= 64.0 * f64::EPSILON * 50.0, "{}", p.rate_hz);
    assert!(
        !log.notes.iter().any(|n| n.contains("SDLOG_PROFILE")),
        "{:?}",
        log.notes
    );
    assert!(
        log.notes.iter().any(|n| n.contains("dropped data 1 times (150 ms")),
        "{:?}",
        log.notes
    );
    // Current: battery_status instance 0 (CAL_MAG_COMP_TYP = 2); throttle: the thrust's norm.
    let current = log.current.as_ref().unwrap();
    assert_eq!(current.values.len(), 200);
    assert_eq!(current.values[3], 15.0);
    let throttle = log.throttle.as_ref().unwrap();
    let want = (0.1f32 as f64).powi(2) + (0.2f32 as f64).powi(2) + ((30.0f32 / 2000.0f32) as f64).powi(2);
    assert_eq!(throttle.values[3], want.sqrt() as f32 as f64);
    // The calibration slot by device id, and CAL_MAG0_ROT = 0 (external, no level offsets).
    assert_eq!(p.calibration_index, Some(0));
    assert_eq!(p.matched_by, format!("CAL_MAG0_ID = device_id {DEVICE}"));
    let to_body = log.to_body.unwrap();
    assert_eq!(to_body, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
    // The true calibration brings every reading to the field the attitude predicts, to float32
    // rounding of the reading and the quaternion (|r| < 1 G, K near I: 1e-6 G is 16 float32 ulps).
    for (j, s) in log.samples.iter().enumerate() {
        let b = solve_upper(K, std::array::from_fn(|i| s.raw[i] - O[i]));
        let predicted = body_field(2 * j, att.values.len());
        for i in 0..3 {
            assert!((b[i] - predicted[i]).abs() < 1e-6, "{b:?} against {predicted:?}");
        }
    }
    // The same log read through a file, hashed.
    let dir = tempfile::TempDir::new().unwrap();
    let path = dir.path().join("raw.ulg");
    std::fs::write(&path, &w.bytes).unwrap();
    let f = ulog::read(&path, &Selection::default()).unwrap();
    assert_eq!(f.samples, log.samples);
    assert_eq!(f.bytes, w.bytes.len() as u64);
    assert_eq!(f.sha256, magcal_runner::digest::sha256_hex(&w.bytes));
}

/// `b` with `K b = y`, `K` upper triangular (back substitution).
fn solve_upper(k: [[f64; 3]; 3], y: [f64; 3]) -> [f64; 3] {
    let b2 = y[2] / k[2][2];
    let b1 = (y[1] - k[1][2] * b2) / k[1][1];
    let b0 = (y[0] - k[0][1] * b1 - k[0][2] * b2) / k[0][0];
    [b0, b1, b2]
}

#[test]
fn rotations_follow_cal_mag_rot_and_the_board() {
    // External, ROTATION_YAW_90.
    let w = synthetic(60, 0x010C00FF, 2, |_, r| r.map(|x| x as f32));
    let r = read_bytes(&w.bytes, None).unwrap().log.to_body.unwrap();
    assert_eq!(r, ulog::rotation_matrix(2).unwrap());
    // Internal (-1): the board's SENS_BOARD_ROT = 4, ROTATION_YAW_180.
    let w = synthetic(60, 0x010C00FF, -1, |_, r| r.map(|x| x as f32));
    let r = read_bytes(&w.bytes, None).unwrap().log.to_body.unwrap();
    assert_eq!(r, ulog::rotation_matrix(4).unwrap());
    assert!((r[0][0] + 1.0).abs() < 1e-15 && (r[1][1] + 1.0).abs() < 1e-15 && (r[2][2] - 1.0).abs() < 1e-15);
    // A value that is no rotation: unknown, and said.
    let w = synthetic(60, 0x010C00FF, 77, |_, r| r.map(|x| x as f32));
    let p = read_bytes(&w.bytes, None).unwrap();
    assert!(p.log.to_body.is_none());
    assert!(
        p.log
            .notes
            .iter()
            .any(|n| n.contains("CAL_MAG0_ROT = 77 is not a rotation")),
        "{:?}",
        p.log.notes
    );
}

#[test]
fn a_pre_1_12_calibration_is_undone_with_the_values_in_force() {
    // PX4 1.11's driver logs m = SCALE * (r - OFF) with CAL_MAG0_* (written in `synthetic`).
    let off = [0.25f32, -0.5, 0.125];
    let scale = [1.25f32, 0.75, 1.5];
    let apply =
        |r: [f64; 3], off: [f32; 3]| std::array::from_fn(|k| (f64::from(scale[k]) * (r[k] - f64::from(off[k]))) as f32);
    let mut w = synthetic(200, 0x010B0200, 0, |_, r| apply(r, off));
    let p = read_bytes(&w.bytes, None).unwrap();
    let InForce::Undone(words) = &p.log.calibration else {
        panic!("{:?}", p.log.calibration)
    };
    assert!(words.contains("CAL_MAG0_XOFF..ZOFF"), "{words}");
    let check = |p: &Px4Log, w: &Written, changed_from: usize| {
        for (i, s) in p.log.samples.iter().enumerate() {
            let truth = true_reading(2 * i, w.attitudes.len());
            let off = if i >= changed_from { [0.5f32, -0.5, 0.125] } else { off };
            let m = apply(truth, off);
            for k in 0..3 {
                // The logged float32 carries the rounding: half an ulp of m, over the scale.
                let tol = (f64::from(m[k]).abs() * f64::from(f32::EPSILON) / f64::from(scale[k])) + 4.0 * f64::EPSILON;
                assert!(
                    (s.raw[k] - truth[k]).abs() <= tol,
                    "reading {i} axis {k}: {} against {}",
                    s.raw[k],
                    truth[k]
                );
            }
        }
    };
    check(&p, &w, usize::MAX);
    // XOFF changes to 0.5 in the data section before reading 120: readings from there on were
    // calibrated with it, and are undone with it.
    let at = w.offsets[120];
    let mut tail = w.bytes.split_off(at);
    let mut change = Writer::default();
    change.param("CAL_MAG0_XOFF", 0.5);
    w.bytes.extend_from_slice(&change.buf);
    // Rewrite the readings after the change as the driver would have logged them.
    let shift = change.buf.len();
    for i in 120..200 {
        let o = w.offsets[i] - at;
        let m = apply(true_reading(2 * i, w.attitudes.len()), [0.5, -0.5, 0.125]);
        let x0 = o + 3 + 2 + 8 + 8 + 4;
        for k in 0..3 {
            tail[x0 + 4 * k..x0 + 4 * k + 4].copy_from_slice(&m[k].to_le_bytes());
        }
        w.offsets[i] += shift;
    }
    w.bytes.extend_from_slice(&tail);
    let p = read_bytes(&w.bytes, None).unwrap();
    check(&p, &w, 120);
    assert!(
        p.log
            .notes
            .iter()
            .any(|n| n.contains("1 change of CAL_MAG0_* inside the log (first CAL_MAG0_XOFF)")),
        "{:?}",
        p.log.notes
    );
    // Without a version: read as logged, and said.
    let w = synthetic(60, 0, 0, |_, r| apply(r, off));
    let p = read_bytes(&w.bytes, None).unwrap();
    assert!(matches!(&p.log.calibration, InForce::Calibrated(t) if t.contains("no firmware version")));
    assert_eq!(p.log.samples[0].raw, w.readings[0].map(f64::from));
}

#[test]
fn a_slow_log_of_a_turning_vehicle_says_so() {
    // 60 readings at 50 Hz while turning: enough. Thinned to one reading in 25 (2 Hz): too slow.
    let w = raw_log(60);
    let p = read_bytes(&w.bytes, None).unwrap();
    assert!(
        !p.log.notes.iter().any(|n| n.contains("SDLOG_PROFILE")),
        "{:?}",
        p.log.notes
    );
    let w = synthetic(1500, 0x010C00FF, 0, |_, r| r.map(|x| x as f32));
    let mut bytes = w.bytes[..w.offsets[0]].to_vec();
    let mut pos = w.offsets[0];
    for (i, &o) in w.offsets.iter().enumerate().skip(1) {
        if i % 25 != 0 {
            bytes.extend_from_slice(&w.bytes[pos..o]);
            pos = o + (3 + 2 + 40);
        }
    }
    bytes.extend_from_slice(&w.bytes[pos..]);
    let p = read_bytes(&bytes, None).unwrap();
    assert_eq!(p.log.samples.len(), 60);
    let note = p.log.notes.iter().find(|n| n.contains("SDLOG_PROFILE")).unwrap();
    assert!(
        note.contains("logged at 2.00 Hz while the vehicle turns at up to"),
        "{note}"
    );
}

#[test]
fn every_truncation_is_an_error_naming_the_byte_or_a_shorter_log() {
    let w = raw_log(40);
    let full = read_bytes(&w.bytes, None).unwrap();
    for len in 0..w.bytes.len() {
        match read_bytes(&w.bytes[..len], None) {
            Ok(p) => assert!(p.log.samples.len() <= full.log.samples.len()),
            Err(e) => {
                let e = format!("{e:#}");
                assert!(
                    e.contains("byte") || e.contains("not a PX4 ULog") || e.contains("no magnetometer readings"),
                    "cut at {len}: {e}"
                );
                assert!(e.lines().count() == 1 && e.len() < 300, "cut at {len}: {e}");
            }
        }
    }
}

#[test]
fn truncated_fixtures_are_errors_naming_the_byte() {
    let Some(dir) = fixtures() else { return };
    for name in ["quadrotor_local.ulg", "sample_log_small.ulg", "esc_status_log.ulg"] {
        let bytes = std::fs::read(dir.join(name)).unwrap();
        let stride = bytes.len() / 97;
        for len in (17..bytes.len()).step_by(stride) {
            if let Err(e) = read_bytes(&bytes[..len], None) {
                let e = e.to_string();
                assert!(
                    e.contains("byte") || e.contains("no magnetometer readings"),
                    "{name} cut at {len}: {e}"
                );
            }
        }
    }
}

/// Crafted messages after a valid start (header, flag bits, the sensor_mag format).
fn crafted(tail: impl FnOnce(&mut Writer)) -> anyhow::Result<Px4Log> {
    let mut w = Writer::new();
    w.flag_bits(0, 0);
    w.format(SENSOR_MAG);
    tail(&mut w);
    read_bytes(&w.buf, None)
}

fn reading(w: &mut Writer, t: u64, v: [f32; 3]) -> usize {
    w.data(
        0,
        &[
            &t.to_le_bytes(),
            &t.to_le_bytes(),
            &DEVICE.to_le_bytes(),
            &v.map(f32::to_le_bytes).concat(),
            &[0; 8],
        ],
    )
}

#[test]
fn absurd_messages_are_errors_naming_the_byte() {
    type Tail = Box<dyn FnOnce(&mut Writer)>;
    let cases: Vec<(&str, Tail)> = vec![
        (
            "past the end of the file (byte 205): truncated",
            Box::new(|w: &mut Writer| w.buf.extend_from_slice(&[0xff, 0xff, b'D', 1, 2])),
        ),
        (
            "a key of 200 bytes runs past",
            Box::new(|w: &mut Writer| {
                w.msg(b'I', &[200, b'a']);
            }),
        ),
        (
            "do not make 2 bytes",
            Box::new(|w: &mut Writer| {
                w.msg(b'P', &[200, b'a']);
            }),
        ),
        (
            "too short",
            Box::new(|w: &mut Writer| {
                w.msg(b'P', &[]);
            }),
        ),
        (
            "too short for an add-logged message",
            Box::new(|w: &mut Writer| {
                w.msg(b'A', &[0]);
            }),
        ),
        (
            "topic \"nothing\" has no format",
            Box::new(|w: &mut Writer| w.add_logged(0, 0, "nothing")),
        ),
        (
            "no add-logged message announced",
            Box::new(|w: &mut Writer| {
                w.add_logged(0, 0, "sensor_mag");
                w.data(9, &[&[0; 40]]);
            }),
        ),
        (
            "needs 32 bytes of data, the message has 10",
            Box::new(|w: &mut Writer| {
                w.add_logged(0, 0, "sensor_mag");
                w.data(0, &[&[0; 10]]);
            }),
        ),
        (
            "message id 0 added twice",
            Box::new(|w: &mut Writer| {
                w.add_logged(0, 0, "sensor_mag");
                w.add_logged(1, 0, "sensor_mag");
            }),
        ),
        (
            "format \"sensor_mag\" defined twice",
            Box::new(|w: &mut Writer| w.format(SENSOR_MAG)),
        ),
        (
            "not a ULog message type",
            Box::new(|w: &mut Writer| {
                w.msg(0x07, &[1, 2, 3]);
            }),
        ),
        (
            "flag bits are allowed only as the first message",
            Box::new(|w: &mut Writer| w.flag_bits(0, 0)),
        ),
        (
            "is not finite",
            Box::new(|w: &mut Writer| {
                w.add_logged(0, 0, "sensor_mag");
                reading(w, 10, [f32::NAN, 0.0, 0.0]);
            }),
        ),
        (
            "earlier than the one before",
            Box::new(|w: &mut Writer| {
                w.add_logged(0, 0, "sensor_mag");
                reading(w, 10, [0.1, 0.0, 0.0]);
                reading(w, 9, [0.1, 0.0, 0.0]);
            }),
        ),
        (
            "vehicle_attitude.q is \"double\", not float",
            Box::new(|w: &mut Writer| {
                w.format("vehicle_attitude:uint64_t timestamp;double[4] q;");
                w.add_logged(0, 1, "vehicle_attitude");
            }),
        ),
    ];
    for (want, tail) in cases {
        let e = crafted(tail).map(|_| ()).unwrap_err();
        let e = format!("{e:#}");
        assert!(e.contains(want) && e.contains("byte"), "want {want:?}: {e}");
    }
    // Flag bits this reader does not know, and appended data past the end.
    let mut w = Writer::new();
    w.flag_bits(2, 0);
    let e = read_bytes(&w.buf, None).unwrap_err().to_string();
    assert!(e.contains("byte 16") && e.contains("incompatible flags"), "{e}");
    let mut w = Writer::new();
    w.flag_bits(1, 1 << 40);
    w.format(SENSOR_MAG);
    let e = read_bytes(&w.buf, None).unwrap_err().to_string();
    assert!(
        e.contains("appended data at byte 1099511627776, past the end of the file"),
        "{e}"
    );
    // Not a ULog at all.
    let e = read_bytes(b"PK\x03\x04 a zip", None).unwrap_err().to_string();
    assert!(e.contains("not a PX4 ULog file"), "{e}");
}

#[test]
fn nested_and_self_referring_formats_are_bounded() {
    // A chain of 60,000 formats (a log may define 65,536), each holding the next: the offsets of
    // a topic behind it are followed to MAX_NESTING levels only (no stack overflow, no quadratic
    // walk).
    let e = crafted(|w| {
        for i in 0..60_000 {
            w.format(&format!("f{i}:f{} a;", i + 1));
        }
        w.format("vehicle_attitude:uint64_t timestamp;f0 chain;float[4] q;");
        w.add_logged(0, 1, "vehicle_attitude");
    })
    .unwrap_err();
    assert!(format!("{e:#}").contains("nested deeper than 16"), "{e:#}");
    // A format containing itself; and 12 levels of 50 fields each (50^12 bytes), which a walk
    // without memory of the sizes found would take 50^12 steps for.
    let e = crafted(|w| {
        w.format("loop:loop again;");
        w.format("vehicle_attitude:uint64_t timestamp;loop l;float[4] q;");
        w.add_logged(0, 1, "vehicle_attitude");
    })
    .unwrap_err();
    assert!(format!("{e:#}").contains("nested deeper than 16"), "{e:#}");
    let e = crafted(|w| {
        for i in 0..12 {
            let fields: String = (0..50).map(|k| format!("w{} a{k};", i + 1)).collect();
            w.format(&format!("w{i}:{fields}"));
        }
        w.format("w12:uint8_t z;");
        w.format("vehicle_attitude:uint64_t timestamp;w0 wide;float[4] q;");
        w.add_logged(0, 1, "vehicle_attitude");
    })
    .unwrap_err();
    assert!(
        format!("{e:#}").contains("vehicle_attitude.q lies past the largest message"),
        "{e:#}"
    );
}

proptest! {
    #![proptest_config(Config {
        cases: std::env::var("MAGCAL_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(64),
        failure_persistence: Some(Box::new(FileFailurePersistence::Direct("proptest-regressions/ulog.txt"))),
        ..Config::default()
    })]

    /// Random byte flips and insertions in a synthetic log: `Ok`, or one line naming the byte.
    #[test]
    fn flipped_bytes_are_read_or_refused_naming_the_byte(
        flips in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        insert in proptest::option::of((any::<prop::sample::Index>(), proptest::collection::vec(any::<u8>(), 1..6))),
    ) {
        let mut bytes = raw_log(30).bytes;
        for (i, b) in flips {
            let i = i.index(bytes.len());
            bytes[i] = b;
        }
        if let Some((i, b)) = insert {
            let i = i.index(bytes.len());
            bytes.splice(i..i, b);
        }
        if let Err(e) = read_bytes(&bytes, None) {
            let e = format!("{e:#}");
            prop_assert!(
                e.contains("byte") || e.contains("not a PX4 ULog") || e.contains("no magnetometer readings") || e.contains("--compass"),
                "{}", e
            );
            prop_assert!(e.lines().count() == 1 && e.len() < 400, "{}", e);
        }
    }
}
