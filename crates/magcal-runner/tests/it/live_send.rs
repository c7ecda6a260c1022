//! `live --send` against a test vehicle on loopback UDP that others talk over: only the vehicle's
//! own answers confirm, only it is written to, and nothing is sent that `export` warns of or
//! while the calibration in force on it is unknown. `live` asks the vehicle for what it needs.

use std::net::UdpSocket;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use mavlink::dialects::ardupilotmega::{
    HEARTBEAT_DATA, MavAutopilot, MavMessage, MavParamType, MavType, PARAM_VALUE_DATA, RAW_IMU_DATA,
};
use mavlink::{MavHeader, MavlinkVersion, write_versioned_msg};
use serde_json::Value;
use tempfile::TempDir;

use crate::live::{OFS, finish_live, fly, simulated, start_live, turns, udp_address};

/// One MAVLink 2 frame from `system`, `component`.
fn frame_as(system: u8, component: u8, msg: &MavMessage) -> Vec<u8> {
    let mut bytes = Vec::new();
    let header = MavHeader {
        system_id: u32::from(system),
        component_id: component,
        sequence: 0,
    };
    write_versioned_msg(&mut bytes, MavlinkVersion::V2, header, msg).unwrap();
    bytes
}

pub(crate) fn heartbeat(system: u8) -> Vec<u8> {
    frame_as(
        system,
        1,
        &MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            mavtype: MavType::MAV_TYPE_QUADROTOR,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            ..HEARTBEAT_DATA::default()
        }),
    )
}

fn param_value(system: u8, name: &str, value: f32) -> Vec<u8> {
    frame_as(
        system,
        1,
        &MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
            param_value: value,
            param_count: 0,
            param_index: 0,
            param_id: name.into(),
            param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
        }),
    )
}

/// The calibration in force on the test vehicle: its offsets, no soft iron, and
/// `COMPASS_OFFS_MAX`.
pub(crate) fn in_force(offs_max: f32) -> Vec<(String, f32)> {
    let mut p = Vec::new();
    for (c, a) in ["X", "Y", "Z"].iter().enumerate() {
        p.push((format!("COMPASS_OFS_{a}"), OFS[c]));
        p.push((format!("COMPASS_DIA_{a}"), 1.0));
        p.push((format!("COMPASS_ODI_{a}"), 0.0));
    }
    p.push(("COMPASS_OFFS_MAX".to_string(), offs_max));
    p
}

/// What one datagram held: the `PARAM_SET`s (name, value) and the `PARAM_REQUEST_READ`s
/// (name), and whether it held anything else.
#[derive(Default, Debug)]
pub(crate) struct Heard {
    pub(crate) sets: Vec<(String, f32)>,
    pub(crate) reads: Vec<String>,
    other: usize,
}

fn name_at(p: &[u8]) -> String {
    let end = p.iter().position(|&b| b == 0).unwrap_or(p.len());
    String::from_utf8_lossy(&p[..end]).into_owned()
}

fn parse(bytes: &[u8]) -> Heard {
    let mut framer = magcal_runner::log::tlog::Framer::default();
    let mut heard = Heard::default();
    framer.push(bytes, |frame, id| {
        let header = if frame[0] == 0xFD { 10 } else { 6 };
        let mut p = frame[header..header + usize::from(frame[1])].to_vec();
        p.resize(64, 0);
        match id {
            23 => heard
                .sets
                .push((name_at(&p[6..22]), f32::from_le_bytes([p[0], p[1], p[2], p[3]]))),
            20 => heard.reads.push(name_at(&p[4..20])),
            _ => heard.other += 1,
        }
    });
    heard
}

/// The test vehicle's autopilot on `socket`: it holds `params`, answers each `PARAM_REQUEST_READ`
/// of one it holds when `answers_reads`, and each `PARAM_SET` with the value then held (its
/// reply preceded, when `spoof`, by a `PARAM_VALUE` of another value from system 42 through the
/// same socket, as another component on the vehicle's link might send). Returns what reached it.
pub(crate) fn autopilot(
    socket: UdpSocket,
    params: Vec<(String, f32)>,
    answers_reads: bool,
    spoof: bool,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<Heard> {
    std::thread::spawn(move || {
        socket.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
        let mut params = params;
        let mut all = Heard::default();
        let mut buf = [0u8; 4096];
        while !stop.load(Ordering::Relaxed) {
            let Ok((n, from)) = socket.recv_from(&mut buf) else {
                continue;
            };
            let heard = parse(&buf[..n]);
            for name in &heard.reads {
                if let Some((_, v)) = params.iter().find(|(p, _)| p == name).filter(|_| answers_reads) {
                    socket.send_to(&param_value(1, name, *v), from).unwrap();
                }
            }
            for (name, value) in &heard.sets {
                if spoof {
                    socket.send_to(&param_value(42, name, value + 1.0), from).unwrap();
                }
                match params.iter_mut().find(|(p, _)| p == name) {
                    Some(p) => p.1 = *value,
                    None => params.push((name.clone(), *value)),
                }
                socket.send_to(&param_value(1, name, *value), from).unwrap();
            }
            all.sets.extend(heard.sets);
            all.reads.extend(heard.reads);
            all.other += heard.other;
        }
        all
    })
}

/// The glider's plan300 at `seed` as the test vehicle's frames: a heartbeat, then its turns.
fn glider(tmp: &TempDir, seed: u64) -> Vec<Vec<u8>> {
    let rows = simulated(tmp.path(), "../../scenarios/glider.toml", "plan300", seed);
    let mut frames = vec![heartbeat(1)];
    frames.extend(turns(&rows, 1000));
    frames
}

/// `live --send` on a fresh UDP port with `extra` arguments; `fly` gets the address and sends.
fn run(extra: &[&str], fly_it: impl FnOnce(&str)) -> (Value, Vec<String>, i32) {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    let mut args = vec!["udpin:127.0.0.1:0", "--out", out.to_str().unwrap(), "--send", "--json"];
    args.extend(extra);
    let (child, first, stderr) = start_live(&args);
    fly_it(&udp_address(&first));
    finish_live(child, &stderr)
}

#[test]
fn only_the_vehicle_is_asked_written_to_and_believed() {
    // The vehicle says nothing of its calibration until asked; a socket elsewhere sends junk and
    // a PARAM_VALUE in the vehicle's name; system 42 on the vehicle's own link answers every
    // PARAM_SET first, with another value.
    let tmp = TempDir::new().unwrap();
    let frames = glider(&tmp, 5);
    let stop = Arc::new(AtomicBool::new(false));
    let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
    let pilot = autopilot(
        vehicle.try_clone().unwrap(),
        in_force(1800.0),
        true,
        true,
        Arc::clone(&stop),
    );
    let junk = UdpSocket::bind("127.0.0.1:0").unwrap();
    junk.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
    let (live, lines, code) = run(&["--idle", "4"], |addr| {
        // The vehicle's heartbeat and first compass frames make it the vehicle; then the junk.
        fly(&vehicle, &frames[..51], addr);
        std::thread::sleep(Duration::from_millis(300));
        for _ in 0..20 {
            junk.send_to(b"\xfe\x09junk that is no frame", addr).unwrap();
            junk.send_to(&param_value(1, "COMPASS_OFS_X", 999.0), addr).unwrap();
        }
        fly(&vehicle, &frames[51..], addr);
    });
    stop.store(true, Ordering::Relaxed);
    let heard = pilot.join().unwrap();
    assert_eq!(code, 0, "{lines:#?}");
    // Asked: the calibration in force by name (the vehicle pushed none of it).
    for name in ["COMPASS_OFS_X", "COMPASS_DIA_Z", "COMPASS_ODI_Y", "COMPASS_OFFS_MAX"] {
        assert!(heard.reads.iter().any(|r| r == name), "{name}: {heard:?}");
    }
    assert!(live["asked"]["parameters"].as_u64().unwrap() >= 10, "{}", live["asked"]);
    // Every PARAM_SET reached the vehicle, and its own answers alone confirmed them: system 42's
    // differing values, sent first, did not count.
    let sent = live["sent"]["parameters"].as_array().unwrap().len();
    assert!(sent >= 10, "{live}");
    assert_eq!(
        live["sent"]["equal"].as_array().unwrap().len(),
        sent,
        "{}",
        live["sent"]
    );
    assert_eq!(heard.sets.len(), sent, "{heard:?}");
    assert_eq!((&live["vehicle"][0], &live["vehicle"][1]), (&1.into(), &1.into()));
    // The junk socket's 40 datagrams after the vehicle spoke: counted, never answered.
    assert_eq!(live["foreign_datagrams"], 40, "{live}");
    let mut buf = [0u8; 2048];
    assert!(junk.recv_from(&mut buf).is_err(), "the junk socket was answered");
}

#[test]
fn nothing_is_sent_while_the_calibration_in_force_is_unknown() {
    // The vehicle never says its calibration and answers no request: its readings carry an
    // unknown correction, so no fit is exportable.
    let tmp = TempDir::new().unwrap();
    let frames = glider(&tmp, 5);
    let stop = Arc::new(AtomicBool::new(false));
    let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
    let pilot = autopilot(
        vehicle.try_clone().unwrap(),
        in_force(1800.0),
        false,
        false,
        Arc::clone(&stop),
    );
    let (live, lines, code) = run(&["--idle", "4"], |addr| fly(&vehicle, &frames, addr));
    stop.store(true, Ordering::Relaxed);
    let heard = pilot.join().unwrap();
    assert_eq!(code, 3, "{lines:#?}");
    assert_eq!(live["usable"], false, "{live}");
    let reasons = live["reasons"].as_str().unwrap();
    assert!(
        reasons.starts_with("the calibration in force on the vehicle is unknown (COMPASS_OFS_X"),
        "{reasons}"
    );
    assert!(heard.sets.is_empty() && !heard.reads.is_empty(), "{heard:?}");
    assert!(live["sent"].is_null(), "{live}");
}

#[test]
fn two_autopilots_or_offsets_beyond_the_vehicles_limit_send_nothing() {
    // A second autopilot (system 2) streams compass frames too: which is the vehicle is not for
    // live to guess.
    let tmp = TempDir::new().unwrap();
    let mut frames = glider(&tmp, 5);
    let turns = frames.split_off(1);
    frames.extend(in_force(1800.0).iter().map(|(n, v)| param_value(1, n, *v)));
    frames.extend(turns);
    let stop = Arc::new(AtomicBool::new(false));
    let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
    let pilot = autopilot(
        vehicle.try_clone().unwrap(),
        in_force(1800.0),
        true,
        false,
        Arc::clone(&stop),
    );
    let (live, lines, code) = run(&["--idle", "4"], |addr| {
        let half = frames.len() / 2;
        fly(&vehicle, &frames[..half], addr);
        let imu = frame_as(
            2,
            1,
            &MavMessage::RAW_IMU(RAW_IMU_DATA {
                xmag: 100,
                ..RAW_IMU_DATA::default()
            }),
        );
        // The second autopilot on the vehicle's own link (MAVProxy forwarding two vehicles).
        vehicle.send_to(&[heartbeat(2), imu].concat(), addr).unwrap();
        fly(&vehicle, &frames[half..], addr);
    });
    stop.store(true, Ordering::Relaxed);
    let heard = pilot.join().unwrap();
    assert_eq!(code, 3, "{lines:#?}");
    assert_eq!(live["usable"], true, "{live}");
    assert!(heard.sets.is_empty(), "{heard:?}");
    let last = lines.last().unwrap();
    assert!(last.contains("choose the vehicle with --vehicle"), "{last}");

    // The vehicle's own COMPASS_OFFS_MAX below the offsets to send: export warns of the pre-arm
    // failure, so nothing is sent; --force sends it.
    for (force, expected) in [(false, 3), (true, 0)] {
        let stop = Arc::new(AtomicBool::new(false));
        let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
        let pilot = autopilot(
            vehicle.try_clone().unwrap(),
            in_force(40.0),
            true,
            false,
            Arc::clone(&stop),
        );
        let extra: &[&str] = if force {
            &["--idle", "4", "--force"]
        } else {
            &["--idle", "4"]
        };
        let frames = glider(&tmp, 5);
        let (live, lines, code) = run(extra, |addr| fly(&vehicle, &frames, addr));
        stop.store(true, Ordering::Relaxed);
        let heard = pilot.join().unwrap();
        assert_eq!(code, expected, "--force {force}: {lines:#?}");
        if force {
            assert_eq!(
                live["sent"]["equal"].as_array().unwrap().len(),
                heard.sets.len(),
                "{live}"
            );
        } else {
            assert!(heard.sets.is_empty(), "{heard:?}");
            let last = lines.last().unwrap();
            assert!(last.contains("COMPASS_OFFS_MAX") && last.contains("--force"), "{last}");
        }
    }
}
