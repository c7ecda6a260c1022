//! Position and time from flight logs (`log::gps`): the fixtures' GPS fixes against pymavlink's
//! and pyulog's reading of them (`tests/flightlogs.json`, key `gps`, written by
//! `scripts/crosscheck-flightlogs.py --only gps`), the site and date `calibrate` takes from them,
//! and an ordinary flight written as a DataFlash log (level legs and turns, 20 km from 60 N) whose
//! compass `calibrate --fit vector-diagonal --motor current` recovers against the field along
//! its track.

use std::path::Path;

use magcal_core::aviation::dcm_of_euler;
use magcal_core::flight::{FlightPlan, FlightSample, fly};
use magcal_core::rng::{MagcalRng, stream_rng};
use magcal_core::wmm;
use magcal_runner::log::flight::{FlightLog, Selection};
use rand_distr::{Distribution, StandardNormal};
use tempfile::TempDir;

use crate::common::{calibrate_json, data, magcal};
use crate::dataflash::{V, Writer};

fn expected() -> serde_json::Value {
    let text = include_str!("../flightlogs.json");
    serde_json::from_str::<serde_json::Value>(text).unwrap()["gps"].clone()
}

/// The fixes of `log` at the indices the expectations list match them: time, fix type,
/// position and UTC.
fn check(log: &FlightLog, want: &serde_json::Value, name: &str) {
    let gps = log.gps.as_ref().unwrap_or_else(|| panic!("{name}: no GPS read"));
    assert_eq!(gps.times.len() as u64, want["count"].as_u64().unwrap(), "{name}");
    for (i, w) in want["at"]
        .as_array()
        .unwrap()
        .iter()
        .zip(want["fixes"].as_array().unwrap())
    {
        let i = i.as_u64().unwrap() as usize;
        let (t, f) = (gps.times[i], gps.values[i]);
        let w: Vec<Option<f64>> = w.as_array().unwrap().iter().map(serde_json::Value::as_f64).collect();
        assert!(
            (t - w[0].unwrap()).abs() <= 1e-9 * t.abs(),
            "{name} {i}: time {t} {w:?}"
        );
        assert_eq!(f64::from(f.fix_type), w[1].unwrap(), "{name} {i}");
        // Degrees from 1e-7 integers or doubles, metres from millimetres or centimetres: the
        // same doubles to a few ulps.
        for (got, want) in [(f.lat_deg, w[2]), (f.lon_deg, w[3]), (f.alt_m, w[4])] {
            assert!(
                (got - want.unwrap()).abs() <= 1e-12 * want.unwrap().abs().max(1.0),
                "{name} {i}: {got} {want:?}"
            );
        }
        match (f.utc_s, w[5]) {
            (Some(a), Some(b)) => assert!((a - b).abs() < 1e-6, "{name} {i}: utc {a} {b}"),
            (a, b) => assert_eq!(a, b, "{name} {i}"),
        }
    }
}

#[test]
fn fixtures_read_their_fixes_as_pymavlink_and_pyulog_read_them() {
    let want = expected();
    let pick = Selection { instance: None };
    if let Some(path) = data("ardupilot/pymavlink_test.BIN") {
        let log = magcal_runner::log::dataflash::read(&path, &pick).unwrap();
        check(&log, &want["ardupilot/pymavlink_test.BIN"], "pymavlink_test.BIN");
    }
    for name in ["esc_status_log.ulg", "quadrotor_local.ulg", "sample_log_small.ulg"] {
        let Some(path) = data(&format!("px4/{name}")) else {
            continue;
        };
        let log = magcal_runner::log::ulog::read(&path, &pick).unwrap();
        let w = &want[format!("px4/{name}").as_str()];
        check(&log, w, name);
        assert!(
            log.messages.iter().any(|m| m.starts_with(w["topic"].as_str().unwrap())),
            "{:?}",
            log.messages
        );
    }
}

#[test]
fn calibrate_takes_site_and_date_from_the_fixed_part_or_says_why_not() {
    // esc_status: a 3D fix from its first message (Zurich, 13 May 2019); quadrotor_local: 926
    // messages, none with a fix (a simulator without GPS): no site, and the output says so.
    if let Some(path) = data("px4/esc_status_log.ulg") {
        let (_, c, _) = calibrate_json(&path, &["--trials", "20"]);
        let p = c.place_source.unwrap();
        assert!(
            p.starts_with("the log's GPS (vehicle_gps_position): site 47.3565765, 8.5189121, 428.9 m")
                && p.contains("date 2019-05-13 (2019.363)"),
            "{p}"
        );
        assert!(
            c.magnitude_source
                .starts_with("WMM2015v2 at 47.3565765, 8.5189121, 428.924 m, 2019.363"),
            "{}",
            c.magnitude_source
        );
    }
    if let Some(path) = data("px4/quadrotor_local.ulg") {
        let (_, c, _) = calibrate_json(&path, &["--trials", "20"]);
        let p = c.place_source.unwrap();
        assert!(p.starts_with("none: the log's GPS (vehicle_gps_position) has no fix of type 3 (3D) or better with a position among its 926 messages (best type 0); give --site and --date"), "{p}");
        // No site: the scalar fit's own radius.
        assert!(
            c.magnitude_source.starts_with("radius of the best-fitting sphere"),
            "{}",
            c.magnitude_source
        );
    }
}

/// The compass of the synthetic flights: `raw = K b + O + d u` in the body frame, mGauss, `u` the
/// battery current in amperes.
const K_DIAG: [f64; 3] = [1.04, 0.97, 1.02];
const O: [f64; 3] = [2.5, -1.2, 4.0];
const D: [f64; 3] = [0.06, -0.04, 0.15];
/// Noise per component, mGauss (100 nT).
const SIGMA: f64 = 1.0;

/// The compass's raw reading (mGauss, body frame) at flight sample `s` with attitude `c` (body to
/// NED) and battery current `current`: the WMM2025 field there on the flight's date, through
/// `diag(K_DIAG)`, `O` and `D`, with [`SIGMA`] of noise per component drawn from `rng`.
fn reading(s: &FlightSample, c: &[[f64; 3]; 3], current: f64, rng: &mut MagcalRng) -> [f64; 3] {
    let site = wmm::Site {
        lat_deg: s.lat_deg,
        lon_deg: s.lon_deg,
        alt_m: s.alt_m,
        year: 2026.414,
    };
    let ned = wmm::field_ned(wmm::Model::Wmm2025, &site).unwrap().map(|v| v / 100.0);
    let b: [f64; 3] = std::array::from_fn(|a| (0..3).map(|r| c[r][a] * ned[r]).sum());
    std::array::from_fn(|a| {
        K_DIAG[a] * b[a]
            + O[a]
            + D[a] * current
            + SIGMA * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, rng)
    })
}

/// UTC of the flight's start: 2026-06-01 10:00.
const START_UTC_S: f64 = 1_780_308_000.0;

/// The default ordinary flight of `seed` as an ArduPilot DataFlash log: `MAG` (mGauss as int16,
/// no calibration in force), `ATT` and `BAT` at 10 Hz, `GPS` at 5 Hz with its week and
/// milliseconds, every `COMPASS_*` parameter at its default.
fn flight_log(dir: &Path, seed: u64) -> std::path::PathBuf {
    flight_log_with(dir, seed, 0.0, false)
}

/// [`flight_log`] with the autopilot's yaw (`ATT.Yaw`) off by `yaw_bias_deg` (a wrong heading
/// estimate) and, where `gps_yaw`, the newer `GPS` message (instance field `I`) with a
/// moving-baseline receiver's true `Yaw`.
fn flight_log_with(dir: &Path, seed: u64, yaw_bias_deg: f64, gps_yaw: bool) -> std::path::PathBuf {
    flight_log_of(dir, seed, &FlightPlan::default(), yaw_bias_deg, gps_yaw)
}

/// [`flight_log_with`] of the flight `plan`.
fn flight_log_of(dir: &Path, seed: u64, plan: &FlightPlan, yaw_bias_deg: f64, gps_yaw: bool) -> std::path::PathBuf {
    let f = fly(plan, seed);
    let mut rng = stream_rng(seed, 0xDF);
    let mut w = Writer::new();
    w.fmt(0x81, "PARM", "QNf", "TimeUS,Name,Value");
    w.fmt(
        0x82,
        "MAG",
        "QBhhhhhhhhhBI",
        "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S",
    );
    w.fmt(
        0x83,
        "ATT",
        "QccccCCCC",
        "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw",
    );
    w.fmt(0x84, "BAT", "QBfff", "TimeUS,Inst,Volt,Curr,CurrTot");
    if gps_yaw {
        w.fmt(
            0x85,
            "GPS",
            "QBBIHBcLLeffffB",
            "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U",
        );
    } else {
        w.fmt(
            0x85,
            "GPS",
            "QBIHBcLLefffB",
            "TimeUS,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,U",
        );
    }
    for (name, v) in [
        ("COMPASS_OFS_X", 0.0),
        ("COMPASS_OFS_Y", 0.0),
        ("COMPASS_OFS_Z", 0.0),
        ("COMPASS_DIA_X", 1.0),
        ("COMPASS_DIA_Y", 1.0),
        ("COMPASS_DIA_Z", 1.0),
        ("COMPASS_ODI_X", 0.0),
        ("COMPASS_ODI_Y", 0.0),
        ("COMPASS_ODI_Z", 0.0),
        ("COMPASS_SCALE", 1.0),
        // What pymavlink's magfit_WMM.py reads (scripts/peers-flight.py runs it on these logs).
        ("COMPASS_MOTCT", 0.0),
        ("AHRS_EKF_TYPE", 3.0),
        ("AHRS_TRIM_X", 0.0),
        ("AHRS_TRIM_Y", 0.0),
        ("AHRS_TRIM_Z", 0.0),
    ] {
        w.msg(0x81, &[V::N(1000.0), V::S(name), V::N(v)]);
    }
    let gps_epoch = 315_964_800.0;
    for (i, s) in f.iter().enumerate() {
        let t_us = 1e6 * (s.time_s + 60.0);
        // Attitudes at whole hundredths of a degree, as ATT stores them.
        let [roll, pitch, yaw] = [s.roll_deg, s.pitch_deg, s.heading_deg].map(|x| (x * 100.0).round() / 100.0);
        let c = dcm_of_euler(roll.to_radians(), pitch.to_radians(), yaw.to_radians());
        let raw = reading(s, &c, s.current_a, &mut rng);
        w.msg(
            0x83,
            &[
                V::N(t_us - 100.0),
                V::N(0.0),
                V::N(roll),
                V::N(0.0),
                V::N(pitch),
                V::N(0.0),
                V::N((yaw + yaw_bias_deg).rem_euclid(360.0)),
                V::N(0.0),
                V::N(0.0),
            ],
        );
        w.msg(
            0x84,
            &[V::N(t_us - 50.0), V::N(0.0), V::N(15.0), V::N(s.current_a), V::N(0.0)],
        );
        if i % 2 == 0 {
            let utc = START_UTC_S + s.time_s;
            let gps_s = utc + 18.0 - gps_epoch;
            let week = (gps_s / 604_800.0).floor();
            let ms = ((gps_s - week * 604_800.0) * 1000.0).round();
            let mut v = vec![V::N(t_us - 70.0)];
            if gps_yaw {
                v.push(V::N(0.0));
            }
            v.extend([
                V::N(3.0),
                V::N(ms),
                V::N(week),
                V::N(12.0),
                V::N(0.8),
                V::N(s.lat_deg),
                V::N(s.lon_deg),
                V::N(s.alt_m),
                V::N(plan.speed_m_s),
                V::N(s.heading_deg),
                V::N(0.0),
            ]);
            if gps_yaw {
                v.push(V::N(yaw));
            }
            v.push(V::N(1.0));
            w.msg(0x85, &v);
        }
        // ArduPilot's int16 casts truncate towards zero.
        let mut vals = vec![V::N(t_us), V::N(0.0)];
        vals.extend(raw.map(|x| V::N(x.trunc())));
        vals.extend([0.0; 6].map(V::N));
        vals.extend([V::N(1.0), V::N(t_us)]);
        w.msg(0x82, &vals);
    }
    w.save(dir, &format!("flight{seed}.bin"))
}

#[test]
fn an_ordinary_dataflash_flight_calibrates_against_the_field_along_its_track() {
    // Level legs and full turns at 10 degrees of bank, 20 km from 60 N, 10,000 readings: the
    // field changes along the track by tens of nT. The diagonal model with the current's
    // interference: every estimate within 4 standard errors of the truth (the 50-seed study of
    // the same flights is the core's `ordinary_flights_give_the_sensor_...`).
    let dir = TempDir::new().unwrap();
    let log = flight_log(dir.path(), 7);
    let (code, c, stderr) = calibrate_json(&log, &["--fit", "vector-diagonal", "--motor", "current"]);
    assert_eq!(code, Some(0), "{stderr} {:?}", c.reasons);
    assert_eq!(c.fit, "vector-diagonal");
    let place = c.place_source.clone().unwrap();
    assert!(
        place.starts_with("the log's GPS (GPS): site 60.0000000, 10.0000000, 300.0 m")
            && place.contains("date 2026-06-01"),
        "{place}"
    );
    let a = c.alignment.clone().unwrap();
    assert!(
        a.field_source
            .starts_with("given along the track: WMM2025 at each of 5000 fixes"),
        "{}",
        a.field_source
    );
    let se = c.std_error.bias.unwrap();
    let ses = c.std_error.scale.unwrap();
    let m = c.motor.clone().unwrap();
    let sd = m.std_error.unwrap();
    for i in 0..3 {
        let z = [
            (c.bias[i] - O[i]) / se[i],
            (c.scale[i] - K_DIAG[i]) / ses[i],
            (m.per_unit[i] - D[i]) / sd[i],
        ];
        assert!(
            z.iter().all(|z| z.abs() < 4.0),
            "axis {i}: z {z:?}; bias {:?} scale {:?} motor {:?}",
            c.bias,
            c.scale,
            m.per_unit
        );
    }
    assert_eq!(m.input, "current");
    // The same log with one site for the whole flight (its start) is told so.
    let (_, one, _) = calibrate_json(
        &log,
        &[
            "--fit",
            "vector-diagonal",
            "--motor",
            "current",
            "--site",
            "60,10,300",
            "--date",
            "2026-06-01",
        ],
    );
    assert!(
        one.place_source
            .unwrap()
            .starts_with("--site and --date (the log's GPS fixes are not used")
    );
    // Measured: along the track (2.459, -1.214, 3.952) mGauss, standard errors (0.062, 0.045,
    // 0.39); at one site (2.606, -1.245, 5.266): its z offset 3.2 standard errors off.
    let off = |b: [f64; 3]| (0..3).map(|i| (b[i] - O[i]).powi(2)).sum::<f64>().sqrt();
    assert!(off(one.bias) > 5.0 * off(c.bias), "{:?} {:?}", one.bias, c.bias);
    // Offsets alone do not describe a compass with scale errors of 3 to 4 %: the log rejects them.
    let (code, offsets, _) = calibrate_json(&log, &["--fit", "vector-offsets", "--motor", "current"]);
    assert_eq!(code, Some(3));
    assert!(
        offsets.reasons[0].starts_with("the log rejects the vector-offsets model: lack-of-fit F = ")
            && offsets.reasons[0].ends_with("fit --fit vector-diagonal or --fit vector"),
        "{:?}",
        offsets.reasons
    );
}

#[test]
fn a_gps_yaw_is_the_reference_where_the_autopilots_yaw_is_wrong() {
    // The autopilot's yaw 3 degrees off (a compass offset it flew with), a moving-baseline
    // receiver's yaw true. By default the GPS yaw is the heading: the sensor comes back within
    // 4 standard errors, and the output names it. Against the autopilot's yaw the offsets are
    // many standard errors off, and the output says that heading shares the compass's error.
    let dir = TempDir::new().unwrap();
    let log = flight_log_with(dir.path(), 11, 3.0, true);
    let (code, c, stderr) = calibrate_json(&log, &["--fit", "vector-diagonal", "--motor", "current"]);
    assert_eq!(code, Some(0), "{stderr} {:?}", c.reasons);
    let h = c.heading_source.clone().unwrap();
    assert!(h.starts_with("roll and pitch the autopilot's, heading from GPS.Yaw (moving baseline), independent of the compass (10000 of 10000 readings have one)"), "{h}");
    let se = c.std_error.bias.unwrap();
    let z = |b: [f64; 3]| -> f64 { (0..3).map(|i| ((b[i] - O[i]) / se[i]).abs()).fold(0.0, f64::max) };
    assert!(z(c.bias) < 4.0, "{:?} {se:?}", c.bias);
    let (_, biased, _) = calibrate_json(
        &log,
        &[
            "--fit",
            "vector-diagonal",
            "--motor",
            "current",
            "--heading-from",
            "autopilot",
        ],
    );
    let hb = biased.heading_source.unwrap();
    assert!(
        hb.starts_with("the autopilot's attitude estimate, whose heading used the compass being calibrated")
            && hb.contains("the log also has GPS.Yaw (moving baseline): --heading-from"),
        "{hb}"
    );
    // The largest |z| of the bias fitted against the biased heading, in the GPS-yaw fit's
    // standard errors.
    assert!(z(biased.bias) > 20.0, "{:?} {:?}", biased.bias, c.bias);
    println!(
        "GPS yaw: bias {:?} (|z| {:.2}); autopilot's yaw: {:?} (|z| {:.1})",
        c.bias,
        z(c.bias),
        biased.bias,
        z(biased.bias)
    );
    // `evaluate` scores against the same reference and says which: the field it fits in the
    // reference frame points to the model's declination against the GPS yaw, and is turned by
    // the autopilot's 3 degrees against its yaw (a constant heading error moves the field, not
    // the heading errors).
    let cal = dir.path().join("cal");
    let out = magcal()
        .args(["calibrate", "--fit", "vector-diagonal", "--motor", "current", "--out"])
        .arg(&cal)
        .arg(&log)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let evaluated = |from: &str| -> serde_json::Value {
        let out = magcal()
            .args(["evaluate", "--json", "--heading-from", from])
            .arg(cal.join("calibration.json"))
            .arg(&log)
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_slice(&out.stdout).unwrap()
    };
    let (gps, autopilot) = (evaluated("auto"), evaluated("autopilot"));
    let against = |j: &serde_json::Value| j["against"].as_str().unwrap().to_string();
    assert!(
        against(&gps).starts_with(
            "roll and pitch the autopilot's, heading from GPS.Yaw (moving baseline), independent of the compass"
        ),
        "{}",
        against(&gps)
    );
    assert!(
        against(&autopilot).starts_with("the autopilot's own attitude estimate"),
        "{}",
        against(&autopilot)
    );
    // The field's azimuth fitted against each reference: the GPS yaw gives the model's
    // declination, the autopilot's yaw that turned by its bias.
    let declination = |j: &serde_json::Value| {
        let f = &j["calibrated"]["field"];
        f[0].as_f64().unwrap().atan2(f[1].as_f64().unwrap()).to_degrees()
    };
    let site = wmm::Site {
        lat_deg: 60.0,
        lon_deg: 10.0,
        alt_m: 300.0,
        year: 2026.414,
    };
    let model = wmm::declination_inclination_deg(wmm::Model::Wmm2025, &site)
        .unwrap()
        .0
        .unwrap();
    println!(
        "declination: model {model:.3}, against GPS yaw {:.3}, against the autopilot's {:.3}",
        declination(&gps),
        declination(&autopilot)
    );
    // 0.05 degrees: the model's declination changes by less along the 20 km track (from its
    // start), and 10,000 readings of 0.16 degrees' direction error give its mean to 0.002.
    assert!((declination(&gps) - model).abs() < 0.05);
    assert!((declination(&autopilot) - model - 3.0).abs() < 0.05);
}

/// The default ordinary flight of `seed` as a PX4 ULog (firmware 1.14: raw `sensor_mag` in Gauss,
/// the sensor along the body's axes): `sensor_mag`, `vehicle_attitude` and `battery_status` at
/// 10 Hz, `vehicle_gps_position` at 5 Hz (the layout with doubles, its UTC); the compass of
/// [`flight_log`] in Gauss.
fn flight_ulog(dir: &Path, seed: u64) -> std::path::PathBuf {
    flight_ulog_of(dir, seed, &FlightPlan::default())
}

/// [`flight_ulog`] of the flight `plan`.
fn flight_ulog_of(dir: &Path, seed: u64, plan: &FlightPlan) -> std::path::PathBuf {
    use crate::ulog::Writer;
    let f = fly(plan, seed);
    let mut rng = stream_rng(seed, 0xDF);
    let mut w = Writer::new();
    w.flag_bits(0, 0);
    for fmt in [
        "sensor_mag:uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;float z;float temperature;uint32_t error_count;",
        "vehicle_attitude:uint64_t timestamp;uint64_t timestamp_sample;float[4] q;float[4] delta_q_reset;uint8_t quat_reset_counter;uint8_t[7] _padding0;",
        "battery_status:uint64_t timestamp;float voltage_v;float current_a;",
        "vehicle_gps_position:uint64_t timestamp;uint64_t timestamp_sample;double latitude_deg;double longitude_deg;double altitude_msl_m;uint64_t time_utc_usec;float heading;uint8_t fix_type;uint8_t[3] _padding0;",
    ] {
        w.format(fmt);
    }
    let device: u32 = 396_809;
    w.info_u32("ver_sw_release", 0x010E_00FF);
    w.param_i32("CAL_MAG0_ID", device as i32);
    w.param_i32("CAL_MAG0_ROT", 0);
    w.param_i32("SENS_BOARD_ROT", 0);
    w.param_i32("CAL_MAG_COMP_TYP", 2);
    for (i, topic) in [
        "sensor_mag",
        "vehicle_attitude",
        "battery_status",
        "vehicle_gps_position",
    ]
    .iter()
    .enumerate()
    {
        w.add_logged(0, i as u16, topic);
    }
    for (i, s) in f.iter().enumerate() {
        let t = 60_000_000 + (s.time_s * 1e6).round() as u64;
        let c = dcm_of_euler(
            s.roll_deg.to_radians(),
            s.pitch_deg.to_radians(),
            s.heading_deg.to_radians(),
        );
        let q = quaternion_of(&c).map(|x| x as f32);
        // Gauss: a thousandth of the mGauss reading.
        let raw = reading(s, &c, s.current_a, &mut rng).map(|x| (x / 1000.0) as f32);
        let mut att = Vec::new();
        for x in q.iter().chain(&[0.0f32; 4]) {
            att.extend_from_slice(&x.to_le_bytes());
        }
        w.data(
            1,
            &[&(t - 200).to_le_bytes(), &(t - 200).to_le_bytes(), &att, &[0], &[0; 7]],
        );
        w.data(
            2,
            &[
                &(t - 100).to_le_bytes(),
                &15.0f32.to_le_bytes(),
                &(s.current_a as f32).to_le_bytes(),
            ],
        );
        if i % 2 == 0 {
            let utc = ((START_UTC_S + s.time_s) * 1e6).round() as u64;
            w.data(
                3,
                &[
                    &(t - 300).to_le_bytes(),
                    &(t - 300).to_le_bytes(),
                    &s.lat_deg.to_le_bytes(),
                    &s.lon_deg.to_le_bytes(),
                    &s.alt_m.to_le_bytes(),
                    &utc.to_le_bytes(),
                    &f32::NAN.to_le_bytes(),
                    &[3],
                    &[0; 3],
                ],
            );
        }
        w.data(
            0,
            &[
                &t.to_le_bytes(),
                &t.to_le_bytes(),
                &device.to_le_bytes(),
                &raw.map(f32::to_le_bytes).concat(),
                &25f32.to_le_bytes(),
                &0u32.to_le_bytes(),
            ],
        );
    }
    let path = dir.join(format!("flight{seed}.ulg"));
    std::fs::write(&path, &w.buf).unwrap();
    path
}

/// The unit quaternion `[w, x, y, z]` of a rotation matrix (Shepperd's method, largest pivot).
fn quaternion_of(c: &[[f64; 3]; 3]) -> [f64; 4] {
    let t = c[0][0] + c[1][1] + c[2][2];
    let q = if t > 0.0 {
        let s = (t + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (c[2][1] - c[1][2]) / s,
            (c[0][2] - c[2][0]) / s,
            (c[1][0] - c[0][1]) / s,
        ]
    } else if c[0][0] > c[1][1] && c[0][0] > c[2][2] {
        let s = (1.0 + c[0][0] - c[1][1] - c[2][2]).sqrt() * 2.0;
        [
            (c[2][1] - c[1][2]) / s,
            0.25 * s,
            (c[0][1] + c[1][0]) / s,
            (c[0][2] + c[2][0]) / s,
        ]
    } else if c[1][1] > c[2][2] {
        let s = (1.0 + c[1][1] - c[0][0] - c[2][2]).sqrt() * 2.0;
        [
            (c[0][2] - c[2][0]) / s,
            (c[0][1] + c[1][0]) / s,
            0.25 * s,
            (c[1][2] + c[2][1]) / s,
        ]
    } else {
        let s = (1.0 + c[2][2] - c[0][0] - c[1][1]).sqrt() * 2.0;
        [
            (c[1][0] - c[0][1]) / s,
            (c[0][2] + c[2][0]) / s,
            (c[1][2] + c[2][1]) / s,
            0.25 * s,
        ]
    };
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    q.map(|x| x / n)
}

#[test]
fn an_ordinary_px4_flight_calibrates_against_the_field_along_its_track() {
    // The flight of the DataFlash test as PX4 logs it (Gauss, raw sensor_mag, float32): the same
    // compass comes back within 4 standard errors, from the ULog's own GPS.
    let dir = TempDir::new().unwrap();
    let log = flight_ulog(dir.path(), 7);
    let (code, c, stderr) = calibrate_json(&log, &["--fit", "vector-diagonal", "--motor", "current"]);
    assert_eq!(code, Some(0), "{stderr} {:?}", c.reasons);
    let place = c.place_source.clone().unwrap();
    assert!(
        place.starts_with("the log's GPS (vehicle_gps_position): site 60.0000000, 10.0000000, 300.0 m")
            && place.contains("date 2026-06-01"),
        "{place}"
    );
    let se = c.std_error.bias.unwrap();
    let ses = c.std_error.scale.unwrap();
    let m = c.motor.clone().unwrap();
    let sd = m.std_error.unwrap();
    for i in 0..3 {
        let z = [
            (c.bias[i] - O[i] / 1000.0) / se[i],
            (c.scale[i] - K_DIAG[i]) / ses[i],
            (m.per_unit[i] - D[i] / 1000.0) / sd[i],
        ];
        assert!(
            z.iter().all(|z| z.abs() < 4.0),
            "axis {i}: z {z:?}; bias {:?} scale {:?} motor {:?}",
            c.bias,
            c.scale,
            m.per_unit
        );
    }
}

/// The default ordinary flight of `seed` as a MAVLink telemetry log of ArduPilot (protocol 2):
/// `RAW_IMU` (mGauss as int16, no calibration in force), `ATTITUDE` and `SYS_STATUS` at 10 Hz,
/// `GPS_RAW_INT` at 5 Hz with the fix's UTC; the compass of [`flight_log`].
fn flight_tlog(dir: &Path, seed: u64) -> std::path::PathBuf {
    flight_tlog_of(dir, seed, &FlightPlan::default())
}

/// [`flight_tlog`] of the flight `plan`.
fn flight_tlog_of(dir: &Path, seed: u64, plan: &FlightPlan) -> std::path::PathBuf {
    use mavlink::MavlinkVersion::V2;
    use mavlink::dialects::ardupilotmega::{
        ATTITUDE_DATA, GPS_RAW_INT_DATA, GpsFixType, HEARTBEAT_DATA, MavAutopilot, MavMessage, MavType, RAW_IMU_DATA,
        SYS_STATUS_DATA,
    };

    use crate::tlog::Tlog;
    let f = fly(plan, seed);
    let mut rng = stream_rng(seed, 0xDF);
    let mut w = Tlog::default();
    let hb = HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_FIXED_WING,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        ..HEARTBEAT_DATA::default()
    };
    w.push(100, 1, V2, &MavMessage::HEARTBEAT(hb));
    for a in ["X", "Y", "Z"] {
        w.param(200, &format!("COMPASS_OFS_{a}"), 0.0);
        w.param(200, &format!("COMPASS_DIA_{a}"), 1.0);
        w.param(200, &format!("COMPASS_ODI_{a}"), 0.0);
    }
    w.param(200, "COMPASS_SCALE", 1.0);
    for (i, s) in f.iter().enumerate() {
        let t_us = 60_000_000 + (s.time_s * 1e6).round() as u64;
        let att = ATTITUDE_DATA {
            time_boot_ms: (t_us / 1000) as u32 - 20,
            roll: s.roll_deg.to_radians() as f32,
            pitch: s.pitch_deg.to_radians() as f32,
            yaw: s.heading_deg.to_radians() as f32,
            ..ATTITUDE_DATA::default()
        };
        // The field at the attitude as sent (float32 radians).
        let c = dcm_of_euler(f64::from(att.roll), f64::from(att.pitch), f64::from(att.yaw));
        w.push(t_us - 20_000, 1, V2, &MavMessage::ATTITUDE(att));
        let current = (s.current_a * 100.0).round() / 100.0;
        let raw = reading(s, &c, current, &mut rng);
        let sys = SYS_STATUS_DATA {
            current_battery: (current * 100.0).round() as i16,
            ..SYS_STATUS_DATA::default()
        };
        w.push(t_us - 10_000, 1, V2, &MavMessage::SYS_STATUS(sys));
        if i % 2 == 0 {
            let gps = GPS_RAW_INT_DATA {
                time_usec: ((START_UTC_S + s.time_s) * 1e6).round() as u64,
                lat: (s.lat_deg * 1e7).round() as i32,
                lon: (s.lon_deg * 1e7).round() as i32,
                alt: (s.alt_m * 1e3).round() as i32,
                fix_type: GpsFixType::GPS_FIX_TYPE_3D_FIX,
                satellites_visible: 12,
                ..GPS_RAW_INT_DATA::default()
            };
            w.push(t_us - 5_000, 1, V2, &MavMessage::GPS_RAW_INT(gps));
        }
        let imu = RAW_IMU_DATA {
            time_usec: t_us,
            xmag: raw[0] as i16,
            ymag: raw[1] as i16,
            zmag: raw[2] as i16,
            ..RAW_IMU_DATA::default()
        };
        w.push(t_us, 1, V2, &MavMessage::RAW_IMU(imu));
    }
    let path = dir.join(format!("flight{seed}.tlog"));
    std::fs::write(&path, &w.bytes).unwrap();
    path
}

#[test]
fn an_ordinary_mavlink_flight_calibrates_against_the_field_along_its_track() {
    // The flight of the DataFlash test as a ground station records it: the same compass comes
    // back within 4 standard errors from the telemetry's own GPS_RAW_INT.
    let dir = TempDir::new().unwrap();
    let log = flight_tlog(dir.path(), 7);
    let (code, c, stderr) = calibrate_json(&log, &["--fit", "vector-diagonal", "--motor", "current"]);
    assert_eq!(code, Some(0), "{stderr} {:?}", c.reasons);
    let place = c.place_source.clone().unwrap();
    assert!(
        place.starts_with("the log's GPS (GPS_RAW_INT): site 60.0000000, 10.0000000, 300.0 m")
            && place.contains("date 2026-06-01"),
        "{place}"
    );
    let se = c.std_error.bias.unwrap();
    let ses = c.std_error.scale.unwrap();
    let m = c.motor.clone().unwrap();
    let sd = m.std_error.unwrap();
    for i in 0..3 {
        let z = [
            (c.bias[i] - O[i]) / se[i],
            (c.scale[i] - K_DIAG[i]) / ses[i],
            (m.per_unit[i] - D[i]) / sd[i],
        ];
        assert!(
            z.iter().all(|z| z.abs() < 4.0),
            "axis {i}: z {z:?}; bias {:?} scale {:?} motor {:?}",
            c.bias,
            c.scale,
            m.per_unit
        );
    }
}

#[test]
#[ignore = "a generator: writes the synthetic flights that scripts/peers-flight.py compares with pymavlink's magfit_WMM.py"]
fn write_flights_for_the_peers() {
    // MAGCAL_FLIGHTS_DIR: where; MAGCAL_FLIGHTS: how many (seeds 1 to N). Beside them, truth.json.
    let dir = std::path::PathBuf::from(std::env::var("MAGCAL_FLIGHTS_DIR").expect("MAGCAL_FLIGHTS_DIR"));
    let n: u64 = std::env::var("MAGCAL_FLIGHTS").map_or(5, |v| v.parse().unwrap());
    std::fs::create_dir_all(&dir).unwrap();
    for seed in 1..=n {
        flight_log(&dir, seed);
    }
    let truth = serde_json::json!({"scale": K_DIAG, "bias": O, "motor_per_amp": D, "noise": SIGMA, "units": "mGauss", "frame": "body (forward, right, down)"});
    std::fs::write(dir.join("truth.json"), truth.to_string()).unwrap();
}

/// The synthetic flights shipped in `data/synthetic/` for the README's flight-log recipe: the
/// default flight of seed 1 at 2 readings per second as DataFlash, MAVLink and ULog. Each is what
/// these writers write (`MAGCAL_WRITE_SHIPPED=1 cargo test --release --test it shipped_flights`
/// writes them), and each calibrates to its compass within 4 standard errors.
#[test]
fn the_shipped_flights_are_what_their_generator_writes_and_calibrate() {
    let plan = FlightPlan {
        rate_hz: 2.0,
        ..FlightPlan::default()
    };
    let dir = TempDir::new().unwrap();
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/synthetic");
    let made = [
        (flight_log_of(dir.path(), 1, &plan, 0.0, false), "flight.bin"),
        (flight_tlog_of(dir.path(), 1, &plan), "flight.tlog"),
        (flight_ulog_of(dir.path(), 1, &plan), "flight.ulg"),
    ];
    for (path, name) in &made {
        let bytes = std::fs::read(path).unwrap();
        let target = shipped.join(name);
        if std::env::var_os("MAGCAL_WRITE_SHIPPED").is_some() {
            std::fs::write(&target, &bytes).unwrap();
        }
        let kept = std::fs::read(&target).unwrap_or_default();
        assert!(
            kept == bytes,
            "{}: not what the generator writes ({} bytes against {}): MAGCAL_WRITE_SHIPPED=1 writes it",
            target.display(),
            kept.len(),
            bytes.len()
        );
        let (code, c, stderr) = calibrate_json(&target, &["--fit", "vector-diagonal", "--motor", "current"]);
        assert_eq!(code, Some(0), "{name}: {stderr} {:?}", c.reasons);
        let (se, ses) = (c.std_error.bias.unwrap(), c.std_error.scale.unwrap());
        // ULog's Gauss, the others' mGauss.
        let unit = if name.ends_with("ulg") { 1e-3 } else { 1.0 };
        for i in 0..3 {
            let z = [(c.bias[i] - O[i] * unit) / se[i], (c.scale[i] - K_DIAG[i]) / ses[i]];
            assert!(z.iter().all(|z| z.abs() < 4.0), "{name} axis {i}: z {z:?}");
        }
    }
}

#[test]
fn a_flight_too_straight_to_point_the_compass_is_told_what_to_fly() {
    // The first 100 s of the flight (one leg, heading 340): the diagonal model's bias is known
    // to 4.4 mGauss only, 1.7 degrees of heading: not usable (exit 3), and the manoeuvre of
    // largest gain in information is named with the standard errors it would give.
    let dir = TempDir::new().unwrap();
    let log = flight_log(dir.path(), 7);
    let (code, c, _) = calibrate_json(&log, &["--fit", "vector-diagonal", "--motor", "current", "--to", "160"]);
    assert_eq!(code, Some(3));
    let h = c.heading_std_deg.unwrap();
    assert!(h > 1.0 && h < 3.0, "{h}");
    assert!(
        c.reasons.iter().any(|r| r.contains("a heading error of about")
            && r.contains("fly a full turn at 30 degrees of bank (120 readings)")),
        "{:?}",
        c.reasons
    );
    assert_eq!(c.next_manoeuvres.len(), 3);
    assert!(
        c.next_manoeuvres[0].starts_with("a full turn at 30 degrees of bank (120 readings): bias standard errors"),
        "{:?}",
        c.next_manoeuvres
    );
    // The whole flight points it: no manoeuvre to suggest.
    let (code, whole, _) = calibrate_json(&log, &["--fit", "vector-diagonal", "--motor", "current"]);
    assert_eq!(code, Some(0));
    assert!(whole.heading_std_deg.unwrap() < 0.3 && whole.next_manoeuvres.is_empty());
}

#[test]
fn a_leg_that_determines_nothing_is_told_the_turns_and_headings_it_lacks() {
    // The first 100 s of a flight without turbulence: one attitude, level, heading 340. The
    // diagonal model's scale and bias are confounded on every axis: no vector calibration (exit
    // 3), and yet the information of the vector model says what would give one: the full turns,
    // steepest first, and the headings never flown.
    let dir = TempDir::new().unwrap();
    let plan = FlightPlan {
        turbulence_deg: 0.0,
        ..FlightPlan::default()
    };
    let log = flight_log_of(dir.path(), 7, &plan, 0.0, false);
    let (code, c, stderr) = calibrate_json(&log, &["--fit", "vector-diagonal", "--to", "160"]);
    assert_eq!(code, Some(3), "{stderr}");
    assert!(
        c.reasons[0].starts_with("no vector calibration: ")
            && c.reasons[0].ends_with("fly a full turn at 30 degrees of bank (120 readings): see next manoeuvres"),
        "{:?}",
        c.reasons
    );
    let next: Vec<&str> = c
        .next_manoeuvres
        .iter()
        .map(|m| m.split(" (").next().unwrap())
        .collect();
    assert_eq!(
        next,
        [
            "a full turn at 30 degrees of bank",
            "a full turn at 20 degrees of bank",
            "a full turn at 10 degrees of bank"
        ]
    );
    assert!(
        c.next_manoeuvres.iter().all(|m| m.ends_with("; identifiable)")),
        "{:?}",
        c.next_manoeuvres
    );
    // Heading 340 (legs 20 degrees either side of north, the first to the west): every sector
    // but 330-360 never flown.
    assert_eq!(c.headings_never_flown, vec![[0.0, 330.0]]);
    let text = crate::common::magcal()
        .args(["calibrate", "--fit", "vector-diagonal", "--to", "160"])
        .arg(&log)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.contains("  never flown: headings 0 to 330 (30-degree sectors with under 1 % of the readings)"),
        "{text}"
    );
    // `next` of that calibration, without a box: the flight's own manoeuvres, of this log only.
    let out = dir.path().join("cal");
    let run = crate::common::magcal()
        .args(["calibrate", "--fit", "vector-diagonal", "--to", "160", "--out"])
        .arg(&out)
        .arg(&log)
        .output()
        .unwrap();
    assert_eq!(run.status.code(), Some(3));
    let next = crate::common::magcal()
        .arg("next")
        .arg(out.join("calibration.json"))
        .arg(&log)
        .output()
        .unwrap();
    assert_eq!(next.status.code(), Some(0), "{}", String::from_utf8_lossy(&next.stderr));
    let next = String::from_utf8_lossy(&next.stdout);
    let lines: Vec<&str> = next.lines().collect();
    assert!(
        lines[1] == "never flown: headings 0 to 330 (30-degree sectors with under 1 % of the readings)"
            && lines[2].starts_with("fly a full turn at 30 degrees of bank (120 readings): bias standard errors "),
        "{next}"
    );
    let other_dir = dir.path().join("other");
    std::fs::create_dir(&other_dir).unwrap();
    let other = flight_log_of(&other_dir, 8, &plan, 0.0, false);
    let refused = crate::common::magcal()
        .arg("next")
        .arg(out.join("calibration.json"))
        .arg(&other)
        .output()
        .unwrap();
    assert_eq!(refused.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("not the log"));
    // A FIFO nobody writes to ends at the stream's idle bound, as every log read does.
    #[cfg(unix)]
    {
        let fifo = dir.path().join("fifo");
        assert!(
            std::process::Command::new("mkfifo")
                .arg(&fifo)
                .status()
                .unwrap()
                .success()
        );
        let stalled = crate::common::magcal()
            .env("MAGCAL_TEST_STREAM_IDLE_MS", "200")
            .arg("next")
            .arg(out.join("calibration.json"))
            .arg(&fifo)
            .output()
            .unwrap();
        assert_eq!(stalled.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&stalled.stderr).contains("nothing came from the stream"));
    }
}

#[test]
fn a_csv_log_with_positions_calibrates_along_its_track() {
    // The flight as a CSV with an Euler attitude (NED, degrees), the position columns and no
    // time of day: the date is typed, the site and the field along the track are the rows'.
    let plan = FlightPlan::default();
    let f = fly(&plan, 9);
    let mut rng = stream_rng(9, 0xC5);
    let mut text = String::from("t,mx,my,mz,roll,pitch,yaw,lat,lon,alt,current\n");
    for s in &f {
        let c = dcm_of_euler(
            s.roll_deg.to_radians(),
            s.pitch_deg.to_radians(),
            s.heading_deg.to_radians(),
        );
        let raw = reading(s, &c, s.current_a, &mut rng);
        text.push_str(&format!(
            "{:.2},{:.4},{:.4},{:.4},{:.6},{:.6},{:.6},{:.8},{:.8},{:.2},{:.4}\n",
            s.time_s,
            raw[0],
            raw[1],
            raw[2],
            s.roll_deg,
            s.pitch_deg,
            s.heading_deg,
            s.lat_deg,
            s.lon_deg,
            s.alt_m,
            s.current_a
        ));
    }
    let dir = TempDir::new().unwrap();
    let log = dir.path().join("flight.csv");
    std::fs::write(&log, text).unwrap();
    let args = [
        "--columns",
        "mx,my,mz",
        "--time",
        "t",
        "--euler",
        "roll,pitch,yaw",
        "--position",
        "lat,lon,alt",
        "--current",
        "current",
        "--units",
        "mG",
        "--fit",
        "vector-diagonal",
        "--motor",
        "current",
    ];
    let (code, c, stderr) = calibrate_json(&log, &[&args[..], &["--date", "2026-06-01"]].concat());
    assert_eq!(code, Some(0), "{stderr} {:?}", c.reasons);
    let place = c.place_source.clone().unwrap();
    assert!(
        place.starts_with("the log's GPS (columns lat,lon,alt): site 60.0000000, 10.0000000, 300.0 m")
            && place.contains("date 2026.415 from --date"),
        "{place}"
    );
    let se = c.std_error.bias.unwrap();
    for i in 0..3 {
        assert!(((c.bias[i] - O[i]) / se[i]).abs() < 4.0, "{:?} {se:?}", c.bias);
    }
    // Without a date the rows give none, and the fit that needs the field says what to give.
    let out = crate::common::magcal()
        .arg("calibrate")
        .arg(&log)
        .args(args)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains(
        "needs the field given: --site and --date, a flight log with GPS fixes, or a CSV's --position with --utc or --date"
    ));
    // A scalar fit runs, and says why it has no site.
    let (_, undated, _) = calibrate_json(&log, &args[..8]);
    assert!(
        undated
            .place_source
            .unwrap()
            .contains("gives no UTC time with its fixes, so no date")
    );
    // A date and no positions is refused by name.
    let out = crate::common::magcal()
        .args([
            "calibrate",
            log.to_str().unwrap(),
            "--columns",
            "mx,my,mz",
            "--date",
            "2026-06-01",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--date without --site"));
}
