//! `magcal live` against ArduPilot's own firmware: the SITL copter of `../shared/sitl` (built for
//! this machine; see its README). A stock copter streams nothing a ground station did not ask
//! for: live must ask, and hear the calibration in force. Skipped, and said, where the firmware
//! is absent.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use tempfile::TempDir;

use crate::live::{finish_live, start_live};

/// The SITL firmware, where this machine has it.
fn arducopter() -> Option<PathBuf> {
    let p = PathBuf::from("../../../shared/sitl/arducopter");
    p.exists().then(|| p.canonicalize().unwrap())
}

/// A SITL copter in `dir` as instance `instance` (MAVLink on TCP 5760 + 10 instance), killed when
/// dropped.
struct Sitl(Child);

impl Sitl {
    fn start(binary: &PathBuf, dir: &std::path::Path, instance: u16) -> (Self, u16) {
        Self::start_model(binary, dir, instance, "+")
    }

    /// As [`Sitl::start`] with another of SITL's vehicle models (`calibration`: a frame turned
    /// to the attitude servos 5 to 8 ask, as ArduPilot's own compass-calibration tests turn it).
    fn start_model(binary: &PathBuf, dir: &std::path::Path, instance: u16, model: &str) -> (Self, u16) {
        let defaults = binary.with_file_name("copter.parm");
        let child = Command::new(binary)
            .current_dir(dir)
            .args(["--model", model, "--speedup", "1", "--defaults"])
            .arg(&defaults)
            .args([
                &format!("-I{instance}"),
                "--home",
                "52.17,4.41,0,0",
                "--wipe",
                "--serial0",
                "tcp:0",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let port = 5760 + 10 * instance;
        let started = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "SITL did not listen on {port}"
            );
            std::thread::sleep(Duration::from_millis(200));
        }
        (Self(child), port)
    }
}

impl Drop for Sitl {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn live_on_a_stock_sitl_copter_gets_its_readings_and_calibration_in_force_by_asking() {
    let Some(binary) = arducopter() else {
        eprintln!("skipped: ../shared/sitl/arducopter is absent");
        return;
    };
    let tmp = TempDir::new().unwrap();
    let (sitl, port) = Sitl::start(&binary, tmp.path(), 7);
    let out = tmp.path().join("out");
    let source = format!("tcp:127.0.0.1:{port}");
    let record = tmp.path().join("sitl.tlog");
    let (child, _, stderr) = start_live(&[
        &source,
        "--out",
        out.to_str().unwrap(),
        "--record",
        record.to_str().unwrap(),
        "--json",
        "--every",
        "2",
    ]);
    std::thread::sleep(Duration::from_secs(15));
    // Ctrl-C ends it, with what it has.
    unsafe {
        libc::kill(child.id() as i32, libc::SIGINT);
    }
    let (live, lines, code) = finish_live(child, &stderr);
    drop(sitl);
    // The copter on the ground, still: its readings are all one field, so no fit is usable.
    assert_eq!(code, 3, "{lines:#?}");
    assert_eq!(
        (&live["vehicle"][0], &live["vehicle"][1]),
        (&1.into(), &1.into()),
        "{live}"
    );
    // Asked once for its messages (their rates are 0 until a ground station asks), it streams
    // its compass at the 20 Hz asked: about 10 s of readings in the 15 s after it was asked.
    assert!(live["asked"]["streams"].as_u64().unwrap() >= 1, "{}", live["asked"]);
    let readings = live["readings"].as_u64().unwrap();
    assert!(readings >= 100, "{readings} readings: {live}");
    // Its calibration in force was asked for by name, and the firmware answered each: the
    // recording holds their PARAM_VALUE from system 1.
    assert!(live["asked"]["parameters"].as_u64().unwrap() >= 9, "{}", live["asked"]);
    let mut framer = magcal_runner::log::tlog::Framer::default();
    let mut heard = Vec::new();
    framer.push(&std::fs::read(&record).unwrap(), |frame, id| {
        let (header, system) = if frame[0] == 0xFD {
            (10, frame[5])
        } else {
            (6, frame[3])
        };
        if id == 22 && system == 1 {
            let mut p = frame[header..header + usize::from(frame[1])].to_vec();
            p.resize(25, 0);
            let end = p[8..24].iter().position(|&b| b == 0).unwrap_or(16);
            heard.push(String::from_utf8_lossy(&p[8..8 + end]).into_owned());
        }
    });
    for axis in ["X", "Y", "Z"] {
        for name in ["OFS", "DIA", "ODI"] {
            let p = format!("COMPASS_{name}_{axis}");
            assert!(heard.contains(&p), "{p} not heard: {heard:?}");
        }
    }
    assert!(live["sent"].is_null());
}

/// A ground station on SITL's second port: it sets parameters, turns the calibration frame, and
/// keeps the newest `PARAM_VALUE`s, `RAW_IMU` and `SIMSTATE` (the simulation's true attitude).
struct Station {
    stream: std::net::TcpStream,
    heard: std::sync::Arc<std::sync::Mutex<Heard>>,
}

#[derive(Default)]
struct Heard {
    params: std::collections::BTreeMap<String, f32>,
    /// `RAW_IMU`'s field (mGauss) and `SIMSTATE`'s roll, pitch, yaw (radians), newest.
    mag: Option<[f64; 3]>,
    truth: Option<[f64; 3]>,
}

impl Station {
    fn connect(port: u16) -> Self {
        let stream = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        let heard = std::sync::Arc::new(std::sync::Mutex::new(Heard::default()));
        let (mut reader, shared) = (stream.try_clone().unwrap(), std::sync::Arc::clone(&heard));
        std::thread::spawn(move || {
            let mut framer = magcal_runner::log::tlog::Framer::default();
            let mut buf = [0u8; 8192];
            while let Ok(n) = std::io::Read::read(&mut reader, &mut buf) {
                if n == 0 {
                    break;
                }
                framer.push(&buf[..n], |frame, id| {
                    let header = if frame[0] == 0xFD { 10 } else { 6 };
                    let mut p = frame[header..header + usize::from(frame[1])].to_vec();
                    p.resize(64, 0);
                    let f32_at = |i: usize| f32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]]);
                    let i16_at = |i: usize| f64::from(i16::from_le_bytes([p[i], p[i + 1]]));
                    let mut h = shared.lock().unwrap();
                    match id {
                        22 => {
                            let end = p[8..24].iter().position(|&b| b == 0).unwrap_or(16);
                            h.params
                                .insert(String::from_utf8_lossy(&p[8..8 + end]).into_owned(), f32_at(0));
                        }
                        27 => h.mag = Some([i16_at(20), i16_at(22), i16_at(24)]),
                        164 => h.truth = Some([0, 4, 8].map(|i| f64::from(f32_at(i)))),
                        _ => {}
                    }
                });
            }
        });
        let station = Self { stream, heard };
        // RAW_IMU and SIMSTATE at 10 Hz on this port.
        use mavlink::dialects::ardupilotmega::{COMMAND_LONG_DATA, MavCmd, MavMessage};
        for id in [27.0, 164.0] {
            station.send(&MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                param1: id,
                param2: 100_000.0,
                command: MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
                target_system: 1,
                target_component: 1,
                ..COMMAND_LONG_DATA::default()
            }));
        }
        station
    }

    fn send(&self, msg: &mavlink::dialects::ardupilotmega::MavMessage) {
        let header = mavlink::MavHeader {
            system_id: 250,
            component_id: 190,
            sequence: 0,
        };
        let mut bytes = Vec::new();
        mavlink::write_versioned_msg(&mut bytes, mavlink::MavlinkVersion::V2, header, msg).unwrap();
        std::io::Write::write_all(&mut &self.stream, &bytes).unwrap();
    }

    fn set(&self, name: &str, value: f32) {
        use mavlink::dialects::ardupilotmega::{MavMessage, MavParamType, PARAM_SET_DATA};
        self.send(&MavMessage::PARAM_SET(PARAM_SET_DATA {
            param_value: value,
            target_system: 1,
            target_component: 1,
            param_id: name.into(),
            param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
        }));
    }

    /// The value the firmware holds, asked and waited for (up to 5 s).
    fn get(&self, name: &str) -> Option<f32> {
        use mavlink::dialects::ardupilotmega::{MavMessage, PARAM_REQUEST_READ_DATA};
        self.heard.lock().unwrap().params.remove(name);
        self.send(&MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
            param_index: -1,
            target_system: 1,
            target_component: 1,
            param_id: name.into(),
        }));
        let asked = Instant::now();
        while asked.elapsed() < Duration::from_secs(5) {
            if let Some(v) = self.heard.lock().unwrap().params.get(name) {
                return Some(*v);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }

    /// The calibration frame turned to roll, pitch, yaw (degrees; MAVProxy's `sitl_calibration`
    /// convention: servo 5 at 1150 holds an attitude, servos 6 to 8 give it, 1500 + angle 500/pi
    /// microseconds).
    fn turn_to(&self, [roll, pitch, yaw]: [f64; 3]) {
        use mavlink::dialects::ardupilotmega::{COMMAND_LONG_DATA, MavCmd, MavMessage};
        let yaw = (yaw + 540.0).rem_euclid(360.0) - 180.0;
        let pwm = |deg: f64| (1500.0 + deg.to_radians() * 500.0 / std::f64::consts::PI).round() as f32;
        for (servo, value) in [(5.0, 1150.0), (6.0, pwm(roll)), (7.0, pwm(pitch)), (8.0, pwm(yaw))] {
            self.send(&MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                param1: servo,
                param2: value,
                command: MavCmd::MAV_CMD_DO_SET_SERVO,
                target_system: 1,
                target_component: 1,
                ..COMMAND_LONG_DATA::default()
            }));
        }
    }
}

/// The compass's simulated errors (SITL's `inv(M) B - SIM_MAG1_OFS`, mGauss, M symmetric) and the
/// calibration in force before live sends another: offsets only, wrong.
const SIM: [(&str, f32); 9] = [
    ("SIM_MAG1_OFS_X", 120.0),
    ("SIM_MAG1_OFS_Y", -80.0),
    ("SIM_MAG1_OFS_Z", 60.0),
    ("SIM_MAG1_DIA_X", 1.04),
    ("SIM_MAG1_DIA_Y", 0.97),
    ("SIM_MAG1_DIA_Z", 1.02),
    ("SIM_MAG1_ODI_X", 0.02),
    ("SIM_MAG1_ODI_Y", -0.01),
    ("SIM_MAG1_ODI_Z", 0.03),
];
const IN_FORCE: [(&str, f32); 9] = [
    ("COMPASS_OFS_X", 10.0),
    ("COMPASS_OFS_Y", 10.0),
    ("COMPASS_OFS_Z", 10.0),
    ("COMPASS_DIA_X", 1.0),
    ("COMPASS_DIA_Y", 1.0),
    ("COMPASS_DIA_Z", 1.0),
    ("COMPASS_ODI_X", 0.0),
    ("COMPASS_ODI_Y", 0.0),
    ("COMPASS_ODI_Z", 0.0),
];
/// SITL's own field at its home, 52.17 N 4.41 E (ArduPilot's table, not the WMM: the README).
const SITL_DECLINATION: f64 = 2.004;
const SITL_FIELD: f64 = 493.38;

#[test]
fn live_guides_the_firmware_to_done_and_the_calibration_it_sends_is_what_the_firmware_then_reads_by() {
    let Some(binary) = arducopter() else {
        eprintln!("skipped: ../shared/sitl/arducopter is absent");
        return;
    };
    let budget = 1.0;
    let tmp = TempDir::new().unwrap();
    let (sitl, port) = Sitl::start_model(&binary, tmp.path(), 8, "calibration");
    let station = Station::connect(port + 2);
    for (name, value) in SIM.iter().chain(&IN_FORCE) {
        station.set(name, *value);
    }
    for (name, value) in SIM.iter().chain(&IN_FORCE) {
        assert_eq!(station.get(name), Some(*value), "{name}");
    }
    let out = tmp.path().join("out");
    let (mut child, first, stderr) = crate::live::start_live_lines(
        &[
            &format!("tcp:127.0.0.1:{port}"),
            "--site",
            "52.17,4.41,0",
            "--date",
            "2026.9",
            "--roll=-40,40",
            "--pitch=-40,40",
            "--heading-budget",
            &budget.to_string(),
            "--page",
            "0",
            "--send",
            "--json",
            "--out",
            out.to_str().unwrap(),
        ],
        2,
    );
    let page = first[1]
        .trim_start_matches("live: page at http://")
        .trim_end_matches('/')
        .to_string();
    // Closed loop: one turn round level, then each target of the page's plan, at 30 deg/s.
    let started = Instant::now();
    let (mut at, mut target, mut last_look) = ([0.0f64; 3], None::<[f64; 3]>, Instant::now());
    let ended = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        assert!(started.elapsed() < Duration::from_secs(180), "not done in 180 s");
        let t = started.elapsed().as_secs_f64();
        if t < 10.0 {
            at = [0.0, 0.0, 36.0 * t];
        } else if let Some(goal) = target {
            for i in 0..3 {
                let mut d = goal[i] - at[i];
                if i == 2 {
                    d = (d + 540.0).rem_euclid(360.0) - 180.0;
                }
                at[i] += d.clamp(-1.5, 1.5);
            }
        }
        station.turn_to(at);
        std::thread::sleep(Duration::from_millis(50));
        if last_look.elapsed() > Duration::from_millis(500) {
            last_look = Instant::now();
            let Some(body) = crate::live::page_status(&page) else {
                continue;
            };
            let status: serde_json::Value = serde_json::from_slice(&body).unwrap();
            let head = &status["plan"][0];
            if let (Some(r), Some(p), Some(h)) = (
                head["roll_deg"].as_f64(),
                head["pitch_deg"].as_f64(),
                head["true_heading_deg"].as_f64(),
            ) {
                target = Some([r, p, h]);
            }
        }
    };
    let (live, lines, code) = finish_live(child, &stderr);
    assert_eq!((code, ended.code()), (0, Some(0)), "{lines:#?}");
    let sent = live["sent"]["parameters"].as_array().unwrap();
    assert!(
        sent.len() >= 9 && live["sent"]["equal"].as_array().unwrap().len() == sent.len(),
        "{}",
        live["sent"]
    );
    // The firmware holds what was sent.
    for p in sent {
        let (name, value) = (p[0].as_str().unwrap(), p[1].as_f64().unwrap() as f32);
        assert_eq!(station.get(name), Some(value), "{name}");
    }
    // And reads by it: held at tilts of the box and every 45 degrees of heading, its compass
    // (RAW_IMU: the field with the calibration in force applied), turned level by the
    // simulation's true roll and pitch, points along the true heading less SITL's declination.
    let mut errors = Vec::new();
    let mut magnitudes = Vec::new();
    for (roll, pitch) in [(0.0, 0.0), (30.0, 0.0), (0.0, -30.0), (-30.0, 30.0), (30.0, 30.0)] {
        for k in 0..8 {
            station.turn_to([roll, pitch, 45.0 * f64::from(k)]);
            std::thread::sleep(Duration::from_millis(1500));
            let (m, [r, p, y]) = {
                let h = station.heard.lock().unwrap();
                (h.mag.unwrap(), h.truth.unwrap())
            };
            // Level: Ry(pitch) Rx(roll) m.
            let (sr, cr) = r.sin_cos();
            let (sp, cp) = p.sin_cos();
            let a = [m[0], cr * m[1] - sr * m[2], sr * m[1] + cr * m[2]];
            let level = [cp * a[0] + sp * a[2], a[1]];
            let heading = (-level[1]).atan2(level[0]).to_degrees();
            let e = heading - (y.to_degrees() - SITL_DECLINATION);
            errors.push(((e + 540.0).rem_euclid(360.0) - 180.0).abs());
            magnitudes.push(m.iter().map(|v| v * v).sum::<f64>().sqrt());
        }
    }
    drop(sitl);
    let mut sorted = errors.clone();
    let p95 = magcal_core::budget::quantile(&mut sorted, 0.95);
    let worst_magnitude = magnitudes
        .iter()
        .map(|m| (m / SITL_FIELD - 1.0).abs())
        .fold(0.0, f64::max);
    let set = crate::live::json_of(&out.join("calibration.json"));
    let predicted = set["heading_budget"]["predicted_deg"].as_f64().unwrap();
    assert!(set["usable"] == true && predicted <= budget, "{predicted}");
    eprintln!(
        "sitl: {} readings, predicted {predicted:.2} deg; held by the firmware: heading p95 {p95:.2} deg, max {:.2}, magnitude within {:.2} %",
        live["readings"],
        errors.iter().copied().fold(0.0, f64::max),
        100.0 * worst_magnitude
    );
    assert!(p95 <= 1.5 * budget, "{errors:?}");
    assert!(worst_magnitude < 0.02, "{magnitudes:?}");
}
