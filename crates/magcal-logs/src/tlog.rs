//! MAVLink telemetry logs (`.tlog`, written by ground stations: Mission Planner, QGroundControl,
//! MAVProxy): the magnetometer's readings with the calibration in force undone, and the attitude,
//! battery current and throttle sent beside them.
//!
//! # The format
//! Records of an 8-byte big-endian time stamp (microseconds since 1970, the ground station's
//! clock when it received the frame) followed by one MAVLink frame, v1 (`FE`) or v2 (`FD`, signed
//! or not). A frame whose checksum fails (with its message's CRC extra) is counted and skipped; a
//! record that does not start with a frame is skipped byte by byte to the next one that does and
//! whose checksum holds; a cut last record is noted. A file with no valid frame in its first
//! [`PROBE`] bytes is not a telemetry log.
//!
//! # Messages used (ArduPilot, the vehicle's system and component)
//! - `RAW_IMU` (instance 0), `SCALED_IMU2` (1), `SCALED_IMU3` (2): `xmag, ymag, zmag` (mGauss,
//!   body frame, after the calibration in force; `int16` truncations, see
//!   [`super::ardupilot`]).
//! - `SENSOR_OFFSETS.mag_ofs_x..z`: compass 0's offsets in force, from where they are sent on.
//! - `PARAM_VALUE`: `COMPASS_OFS*`, `COMPASS_DIA*`, `COMPASS_ODI*`, `COMPASS_SCALE*`,
//!   `COMPASS_MOT*`, `COMPASS_MOTCT` (a ground station downloads them all when it connects; later
//!   ones are changes). The offsets of instances 1 and 2 come from `COMPASS_OFS2_*`,
//!   `COMPASS_OFS3_*` only. For `export` ([`super::parameters`]): the last `COMPASS_OFFS_MAX`,
//!   and, where the log received every `param_index` below `param_count`, which of the
//!   `COMPASS_*` parameters export writes the firmware has.
//! - `ATTITUDE` (roll, pitch, yaw, radians) as a quaternion
//!   ([`super::binary::quaternion_of_euler`]); `SYS_STATUS.current_battery` (cA; else
//!   `BATTERY_STATUS` of battery 0); `VFR_HUD.throttle` (percent, as 0 to 1).
//! - `GPS_RAW_INT`: `fix_type`, `lat`, `lon` (1e-7 degrees), `alt` (mm above mean sea level),
//!   `time_usec` (the fix's UTC where after 2000, as ArduPilot sends it), `yaw` (centidegrees, 0
//!   for none: a moving-baseline receiver's heading).
//!
//! # Times
//! On the vehicle's clock (seconds since boot): `RAW_IMU.time_usec`, `SCALED_IMU*.time_boot_ms`
//! and `ATTITUDE.time_boot_ms` as sent, so that readings and attitudes match as the vehicle
//! measured them, not as the radio delivered them. Messages without a time of their own
//! (`SYS_STATUS`, `BATTERY_STATUS`, `VFR_HUD`, `GPS_RAW_INT`, whose `time_usec` is UTC) take their reception time moved onto the vehicle's
//! clock by the difference of the last message with both.
//!
//! # The calibration undone
//! As for DataFlash ([`super::ardupilot`]): `OFS` from `COMPASS_OFS*` where it truncates to the
//! offsets in force (`SENSOR_OFFSETS`, instance 0), else those; `D`, `s` from the parameters. A
//! telemetry log does not carry the motor compensation added (`MO`): where `COMPASS_MOTCT` is 1
//! (throttle) or 2 (current) and `COMPASS_MOT*` is not zero, `MO = COMPASS_MOT * x` with `x` the
//! last throttle or current received, an approximation the notes state; per-motor compensation
//! (3) cannot be undone and the notes say so. What a log lacks is assumed at ArduPilot's defaults
//! and named in the notes.
//!
//! # Why the `mavlink` crate, and this framing
//! The `mavlink` crate (0.21, dialect `ardupilotmega`) holds every message's CRC extra and decodes
//! payloads (v2's truncated zeros included) with bounds checks and no panics on short payloads;
//! its readers scan a byte stream for frames and know nothing of the time stamps between them, so
//! this module frames the records itself and hands each frame's payload to the crate.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use anyhow::{Result, bail};
use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::{MavlinkVersion, Message, calculate_crc};

use super::ardupilot::{IDENTITY, Logged, Readings, followed, middle, undo};
use super::binary::{At, Budget, Chunks, Dropped, Skipped, in_order, quaternion_of_euler, read_file, take_instance};
use super::flight::{Fix, FlightLog, Format, InForce, Sample, Selection, Series};
use super::parameters::LogParameters;
use crate::site::Units;

/// Bytes of a record's time stamp.
const STAMP: usize = 8;
/// The longest frame: a signed MAVLink 2 frame of 255 payload bytes.
const MAX_FRAME: usize = 10 + 255 + 2 + 13;
/// A file with no valid frame in its first `PROBE` bytes is not a telemetry log.
pub const PROBE: u64 = 1 << 16;
/// `HEARTBEAT.autopilot` of a system that is not an autopilot (a ground station).
const AUTOPILOT_INVALID: u8 = 8;

/// Reads the telemetry log at `path`: the readings of the asked magnetometer instance (the lowest
/// where none is asked) with the calibration in force undone, and the series beside them.
///
/// # Errors
/// A file that is not a telemetry log, no readings of the instance, a calibration in force that
/// cannot be undone, or more than fits in memory; each names the file and the byte offset,
/// message or option.
pub fn read(path: &Path, selection: &Selection) -> Result<FlightLog> {
    read_with(path, selection, Budget::new())
}

/// [`read`] within `budget`.
///
/// # Errors
/// As [`read`].
pub fn read_with(path: &Path, selection: &Selection, mut budget: Budget) -> Result<FlightLog> {
    read_file(
        path,
        |chunks, shown, log: &mut Parsed| parse(chunks, shown, selection, &mut budget, log),
        |log, shown, sha256, bytes| assemble(log, shown, selection, sha256, bytes),
    )
}

/// A frame found at the start of a byte slice.
struct Frame {
    /// Bytes of the whole frame.
    len: usize,
    version: MavlinkVersion,
    id: u32,
    system: u8,
    component: u8,
    /// End of the payload (it starts after the header) in the frame.
    payload_end: usize,
    header: usize,
}

enum Look {
    Frame(Frame),
    /// A frame start whose frame needs this many bytes.
    Short,
    /// Not a frame start.
    Not,
}

fn look(w: &[u8]) -> Look {
    let (header, version) = match w.first() {
        Some(0xFE) => (6, MavlinkVersion::V1),
        Some(0xFD) => (10, MavlinkVersion::V2),
        _ => return Look::Not,
    };
    if w.len() < header {
        return Look::Short;
    }
    let n = usize::from(w[1]);
    let (id, system, component, signature) = match version {
        MavlinkVersion::V1 => (u32::from(w[5]), w[3], w[4], 0),
        MavlinkVersion::V2 => (
            u32::from(w[7]) | u32::from(w[8]) << 8 | u32::from(w[9]) << 16,
            w[5],
            w[6],
            if w[2] & 1 != 0 { 13 } else { 0 },
        ),
    };
    let len = header + n + 2 + signature;
    if w.len() < len {
        return Look::Short;
    }
    Look::Frame(Frame {
        len,
        version,
        id,
        system,
        component,
        payload_end: header + n,
        header,
    })
}

/// The CRC extras of the known message ids met (at most the dialect's few hundred).
#[derive(Default)]
struct Extras(HashMap<u32, u8>);

impl Extras {
    /// The CRC extra of message `id`, `None` where the dialect does not know it.
    fn get(&mut self, id: u32) -> Option<u8> {
        if let Some(&e) = self.0.get(&id) {
            return Some(e);
        }
        let e = MavMessage::default_message_from_id(id).map(|_| MavMessage::extra_crc(id))?;
        self.0.insert(id, e);
        Some(e)
    }

    /// Whether `f` (at the start of `w`) is a known message whose checksum holds.
    fn valid(&mut self, w: &[u8], f: &Frame) -> Option<bool> {
        let extra = self.get(f.id)?;
        let crc = u16::from_le_bytes([w[f.payload_end], w[f.payload_end + 1]]);
        Some(calculate_crc(&w[1..f.payload_end], extra) == crc)
    }
}

/// MAVLink frames cut from a byte stream as it arrives (a radio, UDP datagrams, a TCP socket),
/// for a telemetry log written live: each frame of a known message whose checksum holds, whole
/// and in order. What is not such a frame is counted, never passed on: a frame whose checksum
/// fails and a frame of a message the dialect does not know (the stream resumes at its next byte:
/// neither says where the next frame starts), bytes between frames. At most one frame's bytes
/// (280) wait for the rest of their frame.
#[derive(Default)]
pub struct Framer {
    pending: Vec<u8>,
    extras: Extras,
    /// Frames passed on.
    pub valid: u64,
    /// Frames whose checksum failed.
    pub bad_crc: u64,
    /// Frames of messages the dialect does not know.
    pub unknown: u64,
    /// Bytes outside any frame.
    pub between: u64,
}

impl Framer {
    /// Takes `bytes` and passes each whole valid frame completed by them to `frame`, with its
    /// message id.
    pub fn push(&mut self, bytes: &[u8], mut frame: impl FnMut(&[u8], u32)) {
        self.pending.extend_from_slice(bytes);
        let mut at = 0;
        while at < self.pending.len() {
            let w = &self.pending[at..];
            match look(w) {
                Look::Frame(f) => match self.extras.valid(w, &f) {
                    Some(true) => {
                        self.valid += 1;
                        frame(&w[..f.len], f.id);
                        at += f.len;
                    }
                    Some(false) => {
                        self.bad_crc += 1;
                        self.between += 1;
                        at += 1;
                    }
                    // Whose checksum cannot be checked: its bytes are searched for frames.
                    None => {
                        self.unknown += 1;
                        self.between += 1;
                        at += 1;
                    }
                },
                Look::Short => break,
                Look::Not => {
                    self.between += 1;
                    at += 1;
                }
            }
        }
        self.pending.drain(..at);
    }
}

/// One record of a telemetry log: the reception time (microseconds since 1970, big-endian) and
/// the frame.
pub fn record(received_us: u64, frame: &[u8]) -> Vec<u8> {
    let mut r = Vec::with_capacity(STAMP + frame.len());
    r.extend_from_slice(&received_us.to_be_bytes());
    r.extend_from_slice(frame);
    r
}

/// The readings of one instance and where they came from.
#[derive(Default)]
struct Instance {
    samples: Vec<Sample>,
    name: &'static str,
}

/// Everything read from the file.
#[derive(Default)]
struct Parsed {
    data: Data,
    dropped: Dropped,
    valid: u64,
    bad_crc: u64,
    unknown: u64,
    undecoded: BTreeMap<&'static str, u64>,
    other_systems: BTreeMap<u8, u64>,
    skipped: Skipped,
    truncated_at: Option<u64>,
}

/// The readings, parameters and series read.
#[derive(Default)]
struct Data {
    vehicle: Option<(u8, u8)>,
    instances: BTreeMap<u8, Instance>,
    seen: Vec<u8>,
    /// `SENSOR_OFFSETS`: (byte offset, offsets) each time they change.
    offsets: Vec<(u64, [f64; 3])>,
    /// `COMPASS_*` parameters: (byte offset, value) each time the value changes.
    params: HashMap<String, Vec<(u64, f64)>>,
    /// The last `COMPASS_OFFS_MAX`, mGauss, for `export`'s range check.
    offs_max: Option<f64>,
    /// Which parameters of the vehicle's list were received.
    indices: ParamIndices,
    attitude: Series<[f64; 4]>,
    sys_current: Series<f64>,
    battery_current: Series<f64>,
    throttle: Series<f64>,
    gps: Series<Fix>,
    gps_yaw: Series<f64>,
    /// Vehicle time minus reception time of the last message that has both.
    clock: Option<f64>,
    untimed: u64,
}

fn parse(chunks: &mut Chunks, shown: &str, selection: &Selection, budget: &mut Budget, log: &mut Parsed) -> Result<()> {
    let mut extras = Extras::default();
    loop {
        let avail = chunks.fill(STAMP + MAX_FRAME)?;
        if avail == 0 {
            break;
        }
        let offset = chunks.offset();
        if log.valid == 0 && offset > PROBE {
            break;
        }
        let w = chunks.window();
        let record = if avail > STAMP { look(&w[STAMP..]) } else { Look::Short };
        let frame = match record {
            Look::Frame(f) => f,
            Look::Short => {
                log.truncated_at = Some(offset);
                chunks.advance(avail);
                continue;
            }
            Look::Not => {
                let skip = resync(w, &mut extras);
                log.skipped.skip(offset, skip);
                chunks.advance(skip);
                continue;
            }
        };
        let f = &w[STAMP..STAMP + frame.len];
        match extras.valid(f, &frame) {
            None => log.unknown += 1,
            Some(false) => log.bad_crc += 1,
            Some(true) => {
                log.valid += 1;
                let received = u64::from_be_bytes(w[..STAMP].try_into().unwrap_or_default()) as f64 * 1e-6;
                let mut at = At {
                    shown,
                    offset,
                    budget,
                    dropped: &mut log.dropped,
                };
                let message = Received {
                    frame: &frame,
                    payload: &f[frame.header..frame.payload_end],
                    received,
                };
                take(
                    &message,
                    selection,
                    &mut at,
                    &mut log.data,
                    &mut log.undecoded,
                    &mut log.other_systems,
                )?;
            }
        }
        chunks.advance(STAMP + frame.len);
    }
    if log.valid == 0 {
        bail!(
            "{shown}: not a MAVLink telemetry log: no valid MAVLink frame after an 8-byte time stamp in its first {PROBE} bytes"
        );
    }
    Ok(())
}

/// Bytes to skip from the start of `w` (not a record) to the next record whose frame is known and
/// whose checksum holds, or to one that `w` holds too little of to check.
fn resync(w: &[u8], extras: &mut Extras) -> usize {
    for i in 1..w.len().saturating_sub(STAMP) {
        match look(&w[i + STAMP..]) {
            Look::Frame(f) if extras.valid(&w[i + STAMP..], &f) == Some(true) => return i,
            Look::Short => return i,
            _ => {}
        }
    }
    w.len().saturating_sub(STAMP).max(1)
}

/// Which `param_index` of the vehicle's `param_count` the log received: the log holds every
/// parameter of the firmware when it received each index (a ground station downloads the whole
/// list when it connects; a log that starts later holds only the changes).
#[derive(Default)]
struct ParamIndices {
    /// The last `param_count`.
    count: u16,
    /// One per index below `count` (at most 65,535 bytes).
    seen: Vec<bool>,
    /// Indices below `count` not received.
    missing: usize,
}

impl ParamIndices {
    /// Notes index `index` of a list of `count`; a new count starts the list again.
    fn mark(&mut self, count: u16, index: u16) {
        if count != self.count {
            self.count = count;
            self.seen = vec![false; usize::from(count)];
            self.missing = usize::from(count);
        }
        if let Some(seen) = self.seen.get_mut(usize::from(index))
            && !*seen
        {
            *seen = true;
            self.missing -= 1;
        }
    }

    /// Every index of a list that is not empty received.
    fn whole(&self) -> bool {
        self.count > 0 && self.missing == 0
    }
}

/// A valid frame with its reception time.
struct Received<'a> {
    frame: &'a Frame,
    payload: &'a [u8],
    received: f64,
}

/// 2000-01-01 00:00 UTC, seconds since 1970: a GPS time before it is a time since boot.
const UTC_2000_S: f64 = 946_684_800.0;

/// Message ids of what this reader takes (besides `HEARTBEAT`, 0).
const USED: [u32; 11] = [1, 22, 24, 26, 27, 30, 74, 116, 129, 147, 150];

/// Takes what a valid frame carries.
fn take(
    m: &Received,
    selection: &Selection,
    at: &mut At,
    data: &mut Data,
    undecoded: &mut BTreeMap<&'static str, u64>,
    others: &mut BTreeMap<u8, u64>,
) -> Result<()> {
    let f = m.frame;
    if f.id == 0 && data.vehicle.is_none() && m.payload.get(5).copied().unwrap_or(0) != AUTOPILOT_INVALID {
        data.vehicle = Some((f.system, f.component));
    }
    if !USED.contains(&f.id) {
        return Ok(());
    }
    let vehicle = *data.vehicle.get_or_insert((f.system, f.component));
    if vehicle != (f.system, f.component) {
        *others.entry(f.system).or_default() += 1;
        return Ok(());
    }
    let msg = match MavMessage::parse(f.version, f.id, m.payload) {
        Ok(msg) => msg,
        Err(_) => {
            let name = MavMessage::default_message_from_id(f.id).map_or("?", |d| d.message_name());
            *undecoded.entry(name).or_default() += 1;
            return Ok(());
        }
    };
    let imu = match &msg {
        MavMessage::RAW_IMU(d) => Some((0, "RAW_IMU", d.time_usec as f64 * 1e-6, [d.xmag, d.ymag, d.zmag])),
        MavMessage::SCALED_IMU2(d) => Some((
            1,
            "SCALED_IMU2",
            f64::from(d.time_boot_ms) * 1e-3,
            [d.xmag, d.ymag, d.zmag],
        )),
        MavMessage::SCALED_IMU3(d) => Some((
            2,
            "SCALED_IMU3",
            f64::from(d.time_boot_ms) * 1e-3,
            [d.xmag, d.ymag, d.zmag],
        )),
        _ => None,
    };
    if let Some((k, name, t, xyz)) = imu {
        return mag(data, at, selection, k, name, t, m.received, xyz);
    }
    match msg {
        // Deprecated in the dialect since 2022; older ArduPilot firmware sends it, and it is the
        // only message with the offsets in force.
        #[allow(deprecated)]
        MavMessage::SENSOR_OFFSETS(d) => {
            let o = [d.mag_ofs_x, d.mag_ofs_y, d.mag_ofs_z].map(f64::from);
            if data.offsets.last().is_none_or(|&(_, last)| last != o) {
                at.budget.push(&mut data.offsets, (at.offset, o), at.shown, at.offset)?;
            }
        }
        MavMessage::PARAM_VALUE(d) => {
            let name = d.param_id.to_str().unwrap_or_default();
            data.indices.mark(d.param_count, d.param_index);
            if name == "COMPASS_OFFS_MAX" {
                data.offs_max = Some(f64::from(d.param_value));
            }
            if followed(name) {
                let v = f64::from(d.param_value);
                let series = data.params.entry(name.to_string()).or_default();
                if series.last().is_none_or(|&(_, last)| last.to_bits() != v.to_bits()) {
                    at.budget.push(series, (at.offset, v), at.shown, at.offset)?;
                }
            }
        }
        MavMessage::ATTITUDE(d) => {
            let t = f64::from(d.time_boot_ms) * 1e-3;
            data.clock = Some(t - m.received);
            let q = quaternion_of_euler(f64::from(d.roll), f64::from(d.pitch), f64::from(d.yaw));
            let finite = q.iter().all(|v| v.is_finite());
            at.push_series(&mut data.attitude, t, q, finite, "ATTITUDE")?;
        }
        MavMessage::SYS_STATUS(d) if d.current_battery >= 0 => {
            untimed(data, at, m.received, f64::from(d.current_battery) / 100.0, Untimed::Sys)?;
        }
        MavMessage::BATTERY_STATUS(d) if d.id == 0 && d.current_battery >= 0 => {
            untimed(
                data,
                at,
                m.received,
                f64::from(d.current_battery) / 100.0,
                Untimed::Battery,
            )?;
        }
        MavMessage::VFR_HUD(d) => {
            untimed(data, at, m.received, f64::from(d.throttle) / 100.0, Untimed::Throttle)?;
        }
        MavMessage::GPS_RAW_INT(d) => gps_raw_int(data, at, m, &d)?,
        _ => {}
    }
    Ok(())
}

/// Appends a `GPS_RAW_INT`: its fix, and a moving-baseline receiver's yaw where it sends one, at
/// its reception time moved onto the vehicle's clock (skipped, and counted, before the clock is
/// known).
fn gps_raw_int(
    data: &mut Data,
    at: &mut At,
    m: &Received,
    d: &mavlink::dialects::ardupilotmega::GPS_RAW_INT_DATA,
) -> Result<()> {
    // ArduPilot sends the fix's UTC (microseconds since 1970) as `time_usec`; a time
    // before 2000 is a time since boot, which gives no date.
    let utc = d.time_usec as f64 * 1e-6;
    let fix = Fix {
        lat_deg: f64::from(d.lat) * 1e-7,
        lon_deg: f64::from(d.lon) * 1e-7,
        alt_m: f64::from(d.alt) * 1e-3,
        fix_type: u8::try_from(d.fix_type as u32).unwrap_or(u8::MAX),
        utc_s: (utc >= UTC_2000_S).then_some(utc),
    };
    match data.clock {
        Some(clock) => {
            at.push_series(&mut data.gps, m.received + clock, fix, true, "GPS_RAW_INT")?;
            // The extension field `yaw` (centidegrees; 0 unknown, 36000 north) at bytes 50
            // and 51 of the payload (the dialect is built without extensions), zeros
            // where MAVLink 2 truncated them.
            let byte = |i: usize| m.payload.get(i).copied().unwrap_or(0);
            let yaw = u16::from_le_bytes([byte(50), byte(51)]);
            if yaw > 0 && fix.fix_type >= 3 {
                let y = (f64::from(yaw) / 100.0).rem_euclid(360.0);
                at.push_series(&mut data.gps_yaw, m.received + clock, y, true, "GPS_RAW_INT")?;
            }
        }
        None => data.untimed += 1,
    }
    Ok(())
}

/// The series of messages without a vehicle time.
#[derive(Clone, Copy)]
enum Untimed {
    Sys,
    Battery,
    Throttle,
}

/// Appends a value of a message without a vehicle time, at its reception time moved onto the
/// vehicle's clock (skipped, and counted, before the clock is known).
fn untimed(data: &mut Data, at: &mut At, received: f64, v: f64, which: Untimed) -> Result<()> {
    let Some(clock) = data.clock else {
        data.untimed += 1;
        return Ok(());
    };
    let (series, name) = match which {
        Untimed::Sys => (&mut data.sys_current, "SYS_STATUS"),
        Untimed::Battery => (&mut data.battery_current, "BATTERY_STATUS"),
        Untimed::Throttle => (&mut data.throttle, "VFR_HUD"),
    };
    at.push_series(series, received + clock, v, v.is_finite(), name)
}

/// Appends a reading of instance `k` (the logged `m`; the calibration is undone at the end).
#[allow(clippy::too_many_arguments)]
fn mag(
    data: &mut Data,
    at: &mut At,
    selection: &Selection,
    k: u8,
    name: &'static str,
    t: f64,
    received: f64,
    m: [i16; 3],
) -> Result<()> {
    data.clock = Some(t - received);
    if selection.instance.is_some_and(|want| want != k) {
        if !data.seen.contains(&k) {
            data.seen.push(k);
        }
        return Ok(());
    }
    let inst = data.instances.entry(k).or_insert_with(|| Instance {
        name,
        ..Instance::default()
    });
    if !in_order(inst.samples.last().map(|s| s.time_s), t) {
        *at.dropped.out_of_order.entry(name).or_default() += 1;
        return Ok(());
    }
    let sample = Sample {
        time_s: t,
        raw: m.map(|v| middle(f64::from(v))),
        offset: at.offset,
    };
    at.budget.push(&mut inst.samples, sample, at.shown, at.offset)
}

/// The value in force at byte `offset` of a series of changes (the first where none is before).
fn in_force<T: Copy>(series: &[(u64, T)], offset: u64) -> Option<T> {
    let i = series.partition_point(|&(o, _)| o < offset);
    series.get(i.saturating_sub(1)).map(|&(_, v)| v)
}

/// The value of `series` at time `t`: the last at or before it.
fn at_time(series: &Series<f64>, t: f64) -> Option<f64> {
    let i = series.times.partition_point(|&x| x <= t);
    i.checked_sub(1).map(|i| series.values[i])
}

/// The flight log from what was read: the instance chosen, its calibration undone, the notes.
fn assemble(parsed: Parsed, shown: &str, selection: &Selection, sha256: String, bytes: u64) -> Result<FlightLog> {
    let Parsed {
        mut data,
        dropped,
        bad_crc,
        unknown,
        undecoded,
        other_systems,
        skipped,
        truncated_at,
        ..
    } = parsed;
    let instances_kept = std::mem::take(&mut data.instances);
    let (instances, k, inst) = take_instance(
        instances_kept,
        &data.seen,
        selection,
        shown,
        "RAW_IMU, SCALED_IMU2 or SCALED_IMU3",
    )?;
    let from_sys = !data.sys_current.times.is_empty();
    let current = std::mem::take(if from_sys {
        &mut data.sys_current
    } else {
        &mut data.battery_current
    });
    let mut notes = Vec::new();
    let (mut readings, mo_note) = readings_of(inst.samples, k, &data, &current);
    notes.extend(mo_note);
    let undone = undo(&mut readings, k, &data.params, shown, &mut notes)?;
    notes.extend(frame_notes(bad_crc, unknown, &undecoded, &other_systems));
    notes.extend(skipped.note("records"));
    if let Some(at) = truncated_at {
        notes.push(format!(
            "The last record, at byte {at}, is cut short (the log was not closed); it is ignored."
        ));
    }
    if data.untimed > 0 {
        notes.push(format!(
            "{} SYS_STATUS, BATTERY_STATUS, VFR_HUD or GPS_RAW_INT messages came before any message with the vehicle's time and were skipped.",
            data.untimed
        ));
    }
    notes.extend(dropped.notes());
    let mut messages = vec![format!("{}: xmag, ymag, zmag (mGauss)", inst.name)];
    if k == 0 && !data.offsets.is_empty() {
        messages.push("SENSOR_OFFSETS: mag_ofs_x, mag_ofs_y, mag_ofs_z".into());
    }
    messages.push(format!("PARAM_VALUE: {}", undone.params));
    let present = |s: &Series<f64>| !s.times.is_empty();
    if !data.attitude.times.is_empty() {
        messages.push("ATTITUDE: roll, pitch, yaw (radians)".into());
    }
    if present(&current) {
        messages.push(if from_sys {
            "SYS_STATUS: current_battery (cA)".into()
        } else {
            "BATTERY_STATUS (id 0): current_battery (cA)".into()
        });
    }
    if present(&data.throttle) {
        messages.push("VFR_HUD: throttle (%)".into());
    }
    if !data.gps.times.is_empty() {
        messages.push("GPS_RAW_INT: fix_type, lat, lon, alt, time_usec (UTC)".into());
    }
    let listed = data.indices.whole().then(|| data.params.keys());
    let parameters = LogParameters::ardupilot("PARAM_VALUE", listed, data.offs_max);
    Ok(FlightLog {
        format: Format::Tlog,
        messages,
        unit: Units::MilliGauss,
        frame: "body (forward, right, down)".into(),
        instances,
        instance: k,
        samples: readings.samples,
        attitude: (!data.attitude.times.is_empty()).then_some(data.attitude),
        current: present(&current).then_some(current),
        throttle: present(&data.throttle).then_some(data.throttle),
        gps: (!data.gps.times.is_empty()).then_some(data.gps),
        gps_yaw: (!data.gps_yaw.times.is_empty()).then(|| (data.gps_yaw, "GPS_RAW_INT.yaw".to_string())),
        gsf_yaw: None,
        to_body: Some(IDENTITY),
        calibration: InForce::Undone(undone.words),
        notes,
        parameters,
        sha256,
        bytes,
    })
}

/// The readings of instance `k` with the offsets and motor compensation in force at each, and a
/// note on how the motor compensation was found.
fn readings_of(samples: Vec<Sample>, k: u8, data: &Data, current: &Series<f64>) -> (Readings, Option<String>) {
    let sfx = if k == 0 { String::new() } else { (k + 1).to_string() };
    let param = |name: &str, offset: u64| data.params.get(name).and_then(|s| in_force(s, offset));
    let has_ofs = k == 0 && !data.offsets.is_empty();
    let mut kinds = [false; 4];
    let logged = samples
        .iter()
        .map(|s| {
            let ofs_logged = if has_ofs {
                in_force(&data.offsets, s.offset).unwrap_or([f64::NAN; 3])
            } else {
                [f64::NAN; 3]
            };
            let motct = param("COMPASS_MOTCT", s.offset).unwrap_or(0.0);
            let mot = ["X", "Y", "Z"].map(|a| param(&format!("COMPASS_MOT{sfx}_{a}"), s.offset).unwrap_or(0.0));
            let x = match motct as i64 {
                1 => at_time(&data.throttle, s.time_s),
                2 => at_time(current, s.time_s),
                _ => None,
            };
            let mo = if mot == [0.0; 3] {
                [0.0; 3]
            } else {
                mot.map(|c| c * x.unwrap_or(0.0))
            };
            if mot != [0.0; 3] {
                kinds[(motct as usize).min(3)] = true;
            }
            Logged {
                ofs: ofs_logged.map(middle),
                ofs_logged,
                mo,
            }
        })
        .collect();
    let note = if kinds[3] {
        Some(
            "COMPASS_MOTCT = 3 (per-motor compensation) cannot be undone from telemetry: MO = 0 was assumed."
                .to_string(),
        )
    } else if kinds[1] || kinds[2] {
        Some(format!(
            "MO was rebuilt as COMPASS_MOT{sfx}_* times the last {} received before each reading: an approximation at telemetry rates.",
            if kinds[1] { "throttle (VFR_HUD)" } else { "current" }
        ))
    } else {
        None
    };
    let readings = Readings {
        samples,
        logged,
        ofs_integer: true,
        has_ofs,
        ofs_source: "SENSOR_OFFSETS",
        mo_source: if kinds[1] || kinds[2] {
            format!("MO = COMPASS_MOT{sfx} x (throttle or current)")
        } else {
            "MO = 0 (no motor compensation in force)".into()
        },
        mo_before_d: false,
    };
    (readings, note)
}

/// Notes on frames skipped: checksums, unknown ids, payloads the crate could not decode, other
/// systems.
fn frame_notes(bad_crc: u64, unknown: u64, undecoded: &BTreeMap<&str, u64>, others: &BTreeMap<u8, u64>) -> Vec<String> {
    let mut notes = Vec::new();
    if bad_crc > 0 {
        notes.push(format!(
            "Skipped {bad_crc} frames whose checksum fails (damaged in transmission)."
        ));
    }
    if unknown > 0 {
        notes.push(format!(
            "Skipped {unknown} frames of message ids the ArduPilot dialect does not know."
        ));
    }
    if !undecoded.is_empty() {
        let list: Vec<String> = undecoded.iter().map(|(n, c)| format!("{c} {n}")).collect();
        notes.push(format!(
            "Skipped messages whose payload could not be decoded (a value outside its enumeration): {}.",
            list.join(", ")
        ));
    }
    if !others.is_empty() {
        let list: Vec<String> = others.iter().map(|(s, c)| format!("{c} from system {s}")).collect();
        notes.push(format!(
            "Ignored messages of other systems or components: {}.",
            list.join(", ")
        ));
    }
    notes
}
