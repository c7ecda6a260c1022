//! What `live` asks of the vehicle over a MAVLink link: the messages it needs and the parameters
//! of the calibration in force.
//!
//! An autopilot streams nothing a ground station did not ask for (ArduPilot's stream rates
//! `SRn_*` / `MAVn_*` default to 0 on copter), and says its parameters only when asked. So a
//! thread asks every autopilot `--vehicle` allows, every [`EVERY`]: for its compass, attitude,
//! position and time (`MAV_CMD_SET_MESSAGE_INTERVAL`, and `REQUEST_DATA_STREAM` for firmware
//! older than the command) until its compass frames arrive, and for each parameter of the
//! calibration in force not yet heard (`PARAM_REQUEST_READ`) until it answers. What it asked is
//! counted for the report.

use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use mavlink::dialects::ardupilotmega::{COMMAND_LONG_DATA, MavCmd, MavMessage, PARAM_REQUEST_READ_DATA};
use mavlink::{MavHeader, MavlinkVersion, write_versioned_msg};

use super::source::{Link, Shared};

/// How often the thread asks again what is still missing.
pub const EVERY: Duration = Duration::from_secs(2);

/// The messages asked for, with their interval in microseconds: `RAW_IMU` (the compass, 20 Hz),
/// `ATTITUDE` (20 Hz), `GPS_RAW_INT` and `GLOBAL_POSITION_INT` (2 Hz), `SYSTEM_TIME` (1 Hz).
const MESSAGES: [(u32, f32); 5] = [(27, 5e4), (30, 5e4), (24, 5e5), (33, 5e5), (2, 1e6)];

/// The same messages as data streams, for firmware older than `SET_MESSAGE_INTERVAL` (MAVLink
/// marks `REQUEST_DATA_STREAM` superseded; ArduPilot still honours it): raw sensors and extra 1
/// (attitude) at 20 Hz, extended status and position at 2 Hz.
#[allow(deprecated)]
fn data_streams(bytes: &mut Vec<u8>, system: u8, component: u8) {
    use mavlink::dialects::ardupilotmega::{MavDataStream, REQUEST_DATA_STREAM_DATA};
    for (stream, rate) in [
        (MavDataStream::MAV_DATA_STREAM_RAW_SENSORS, 20),
        (MavDataStream::MAV_DATA_STREAM_EXTRA1, 20),
        (MavDataStream::MAV_DATA_STREAM_EXTENDED_STATUS, 2),
        (MavDataStream::MAV_DATA_STREAM_POSITION, 2),
    ] {
        put(
            bytes,
            &MavMessage::REQUEST_DATA_STREAM(REQUEST_DATA_STREAM_DATA {
                req_message_rate: rate,
                target_system: system,
                target_component: component,
                req_stream_id: stream,
                start_stop: 1,
            }),
        );
    }
}

/// An autopilot to ask: its system and component, its address (UDP), whether its compass frames
/// have yet to arrive, and the parameters not heard from it.
type Target = ((u8, u8), Option<std::net::SocketAddr>, bool, Vec<String>);

/// The ground station `live` speaks as: system 255, component 190 (`MAV_COMP_ID_MISSIONPLANNER`).
pub const HEADER: MavHeader = MavHeader {
    system_id: 255,
    component_id: 190,
    sequence: 0,
};

/// The parameters of ArduPilot's calibration in force for compass `instance` (0: the first):
/// `COMPASS_OFS`, `COMPASS_DIA`, `COMPASS_ODI` (required before anything is exported), then
/// `COMPASS_SCALE`, the motor compensation and `COMPASS_OFFS_MAX` (ArduPilot's defaults where
/// the firmware has none).
pub fn in_force_names(instance: u8) -> (Vec<String>, Vec<String>) {
    let names = crate::log::ardupilot::param_names(instance);
    let sfx = if instance == 0 {
        String::new()
    } else {
        (instance + 1).to_string()
    };
    let required = names[..9].to_vec();
    let mut optional = vec![
        names[9].clone(),
        "COMPASS_MOTCT".to_string(),
        "COMPASS_OFFS_MAX".to_string(),
    ];
    optional.extend(["X", "Y", "Z"].map(|a| format!("COMPASS_MOT{sfx}_{a}")));
    (required, optional)
}

/// What was asked, for the report.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Asked {
    /// Requests for messages (each a set of `SET_MESSAGE_INTERVAL` and `REQUEST_DATA_STREAM`).
    pub streams: u64,
    /// `PARAM_REQUEST_READ` sent.
    pub parameters: u64,
}

/// Starts the thread that asks, over `link`, until `shared.stop`.
pub fn start(link: Arc<Mutex<Link>>, shared: Arc<Shared>, names: Vec<String>) {
    let _ = std::thread::Builder::new()
        .name("magcal-live-ask".into())
        .spawn(move || {
            let mut last: Option<Instant> = None;
            while !shared.stop.load(Ordering::Relaxed) {
                if last.is_none_or(|t| t.elapsed() >= EVERY) {
                    last = Some(Instant::now());
                    ask_once(&link, &shared, &names);
                }
                std::thread::sleep(Duration::from_millis(100));
            }
        });
}

/// One round: every autopilot allowed without compass frames asked for its messages, and the
/// vehicle (or, before it is known, every autopilot allowed) for the parameters not heard.
fn ask_once(link: &Mutex<Link>, shared: &Shared, names: &[String]) {
    let targets = {
        let s = shared.lock();
        let targets: Vec<Target> = s
            .autopilots()
            .into_iter()
            .filter(|id| s.vehicle.is_none_or(|v| v == *id))
            .map(|id| {
                let h = &s.heard[&id];
                let missing = names.iter().filter(|n| !h.params.contains_key(*n)).cloned().collect();
                (id, h.addr, h.imu == 0, missing)
            })
            .collect();
        targets
    };
    let mut link = link.lock().unwrap_or_else(PoisonError::into_inner);
    let mut count = Asked::default();
    for ((system, component), addr, silent, missing) in targets {
        let mut bytes = Vec::new();
        if silent {
            count.streams += 1;
            for (id, interval) in MESSAGES {
                put(
                    &mut bytes,
                    &MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                        param1: id as f32,
                        param2: interval,
                        command: MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
                        target_system: system,
                        target_component: component,
                        ..COMMAND_LONG_DATA::default()
                    }),
                );
            }
            data_streams(&mut bytes, system, component);
        }
        for name in &missing {
            count.parameters += 1;
            put(
                &mut bytes,
                &MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
                    param_index: -1,
                    target_system: system,
                    target_component: component,
                    param_id: name.as_str().into(),
                }),
            );
        }
        if !bytes.is_empty() {
            // A link that cannot be written now is asked again at the next round.
            let _ = link.send(&bytes, addr);
        }
    }
    let a = &mut shared.lock().asked;
    a.streams += count.streams;
    a.parameters += count.parameters;
}

/// Appends the frame of `msg` from [`HEADER`].
fn put(bytes: &mut Vec<u8>, msg: &MavMessage) {
    // Writing into a vector cannot fail.
    let _ = write_versioned_msg(bytes, MavlinkVersion::V2, HEADER, msg);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_calibration_in_force_is_named_for_each_compass() {
        let (req, opt) = in_force_names(0);
        assert_eq!(req[0], "COMPASS_OFS_X");
        assert_eq!(req[8], "COMPASS_ODI_Z");
        assert!(opt.contains(&"COMPASS_OFFS_MAX".to_string()) && opt.contains(&"COMPASS_MOT_Z".to_string()));
        let (req, opt) = in_force_names(1);
        assert_eq!(req[0], "COMPASS_OFS2_X");
        assert!(opt.contains(&"COMPASS_MOT2_X".to_string()));
    }
}
