//! PX4 ULog (`.ulg`): the magnetometer readings of one instance, the vehicle's attitude, battery
//! current and throttle, and the `CAL_MAGn_*` parameters in force.
//!
//! # What is read
//! - `sensor_mag`, one series per instance (ULog `multi_id`; `--compass N` is instance N): `x`,
//!   `y`, `z` in Gauss, `timestamp` in microseconds since boot, `device_id`. Where a log has no
//!   `sensor_mag` (PX4 1.9 logs `vehicle_magnetometer` only), `vehicle_magnetometer.magnetometer_ga`
//!   per instance, which PX4 publishes calibrated, in the body frame.
//! - The firmware version, from the info message `ver_sw_release` (`0xMMmmppTT`: major, minor,
//!   patch, type), decides what `sensor_mag` holds: from PX4 1.12 on the field as the chip reports
//!   it ([`InForce::Raw`]); before, the field after the driver applied `CAL_MAGn_XOFF..ZOFF` and
//!   `CAL_MAGn_XSCALE..ZSCALE` (`m = SCALE * (r - OFF)` per axis, PX4's `PX4Magnetometer::update`),
//!   which this reader undoes with the values in force at each reading ([`InForce::Undone`]). A
//!   log without a version cannot tell: its readings are returned as they are
//!   ([`InForce::Calibrated`]) and the words say why.
//! - `CAL_MAGn_*` is matched to the instance by `CAL_MAGn_ID == device_id` (PX4's own rule,
//!   `FindCurrentCalibrationIndex`), else by `n` = instance, and [`Px4Log`] says which. For
//!   `export` ([`super::parameters`]): which of the `CAL_MAGn_*` parameters it writes the
//!   firmware has (the header holds every parameter).
//! - `to_body`, the rotation PX4 applies after the calibration (`calibration::Magnetometer`:
//!   `m = R * S * ((r + power * COMP) - OFF)`): an external sensor (`CAL_MAGn_ROT >= 0`) is rotated
//!   by `CAL_MAGn_ROT`, an internal one (`CAL_MAGn_ROT = -1`) by the board's `SENS_BOARD_ROT`;
//!   both then by the level adjustment `SENS_BOARD_X_OFF`, `Y_OFF`, `Z_OFF` (degrees). The
//!   rotations are PX4's `enum Rotation` (`src/lib/conversion/rotation.h`, 0 to 47, roll, pitch,
//!   yaw in whole degrees) and `CAL_MAGn_ROT = 100` with `CAL_MAGn_ROLL`, `PITCH`, `YAW`
//!   (degrees) where the log has them; any other value leaves `to_body` unknown, with a note.
//! - `vehicle_attitude.q` (`w, x, y, z`, body FRD to NED: PX4's convention, as
//!   [`super::flight`] wants it), `battery_status.current_a` (amperes; instance 1 where
//!   `CAL_MAG_COMP_TYP = 3`, else 0), and throttle from `actuator_controls_0.control[3]` (PX4's
//!   `INDEX_THROTTLE`, what its throttle compensation uses) or, in logs without it,
//!   `vehicle_thrust_setpoint` as the norm of `xyz` (PX4's battery model's throttle).
//! - `vehicle_gps_position` (else `sensor_gps`), multi_id 0: `fix_type`, the position (`lat`,
//!   `lon` in 1e-7 degrees and `alt` in mm before PX4 1.14; `latitude_deg`, `longitude_deg`,
//!   `altitude_msl_m` after), `time_utc_usec` (0 before the receiver has a time) and `heading`
//!   (radians, NaN without one: a moving-baseline receiver's yaw).
//!
//! # Rate
//! PX4's default logging profile records `sensor_mag` at 1 Hz. A note says so when the log holds
//! fewer than [`MIN_READINGS`] readings (about five per parameter of the nine-parameter fit), or
//! when it logs them slower than [`MIN_RATE_HZ`]: at 5 Hz a vehicle turning at 30 degrees per
//! second moves 6 degrees between readings, so a full turn gives 60 of them; at 1 Hz it gives 12.
//! The note gives the vehicle's fastest turn (attitudes half a second apart) where the log has
//! attitudes, and the degrees between readings when it turns faster than [`TURNING_DEG_S`]. The note names the rate
//! measured and how to raise it (`SDLOG_PROFILE`'s sensor-comparison bit logs `sensor_mag` at
//! 10 Hz; a line `sensor_mag 20` in the SD card's `etc/logging/logger_topics.txt` logs it at
//! 50 Hz).
//!
//! # Why a reader of our own
//! The crates were read and tried on the three public fixtures and on crafted files:
//! - `px4-ulog` 0.6.1 (PX4's own) streams and is fast (3.86 MB in 4.4 ms), but panics on a
//!   parameter message whose key length runs past the message (`range start index 201 out of
//!   range`), on an empty parameter message and on a one-byte add-logged message, and aborts the
//!   process with a stack overflow on a 4 MB file of 200,000 nested formats (its recursive
//!   flattening); its errors name no byte offset.
//! - `yule_log` 0.4.0 streams but builds an owned tree per message (3.86 MB in 37 ms), prints to
//!   standard output from the library (`Heartbeat ...` on `quadrotor_local.ulg`), has no guard on
//!   nested or self-referring formats, and reads a message cut by the end of the file as zeros.
//! - `ulog-rs` 0.0.4 holds every message in memory and pulls a command-line parser into the
//!   library.
//!
//! This reader decodes only the topics above (3.86 MB in 16 ms, its SHA-256 included), computes
//! their field offsets once per
//! subscription (nesting bounded by [`MAX_NESTING`]), and checks every length against its
//! message: every error names the byte offset, never a panic. Its output is checked against
//! pyulog 1.3's reading of the same files (`scripts/crosscheck-flightlogs.py`).
//!
//! # Bounds
//! The file is streamed (one message of at most 64 KiB in memory); what is kept (readings,
//! series, parameter changes, formats) is charged against half of the memory the process may use
//! ([`limits::available_memory`]) as it grows, and a log that would pass it is refused naming the
//! byte offset reached.
//!
//! # Strictness
//! A message cut by the end of the file, an unknown message type that is not a letter, a data
//! message of a subscription never added or shorter than its format, a timestamp that goes back
//! in a series, or a non-finite reading is an error naming the byte offset. Unknown message types
//! that are letters (the ULog specification reserves them for additions) are skipped and counted
//! in a note.

use std::collections::{BTreeMap, HashMap};
use std::io::{BufReader, Read};
use std::path::Path;

use anyhow::{Context, Result, bail};
use magcal_core::small::Mat3;

use super::flight::{Fix, FlightLog, Format, InForce, Sample, Selection, Series};
use super::parameters::LogParameters;
use crate::digest::Hashing;
use crate::limits;
use crate::site::Units;

/// The first seven bytes of a ULog file.
const MAGIC: [u8; 7] = *b"ULog\x01\x12\x35";
/// Deepest nesting of formats followed: PX4 nests two levels; a cycle stops here.
pub const MAX_NESTING: usize = 16;
/// Fewest readings worth a calibration: about five per parameter of the nine-parameter fit.
pub const MIN_READINGS: usize = 50;
/// Slowest logging rate of `sensor_mag` that samples a turning vehicle well, Hz.
pub const MIN_RATE_HZ: f64 = 5.0;
/// Turn rate above which a vehicle is turning, degrees per second.
pub const TURNING_DEG_S: f64 = 10.0;
/// Rotations of PX4's `enum Rotation` (roll, pitch, yaw in degrees), in enum order.
const ROTATIONS: [[f64; 3]; 48] = [
    [0.0, 0.0, 0.0],
    [0.0, 0.0, 45.0],
    [0.0, 0.0, 90.0],
    [0.0, 0.0, 135.0],
    [0.0, 0.0, 180.0],
    [0.0, 0.0, 225.0],
    [0.0, 0.0, 270.0],
    [0.0, 0.0, 315.0],
    [180.0, 0.0, 0.0],
    [180.0, 0.0, 45.0],
    [180.0, 0.0, 90.0],
    [180.0, 0.0, 135.0],
    [0.0, 180.0, 0.0],
    [180.0, 0.0, 225.0],
    [180.0, 0.0, 270.0],
    [180.0, 0.0, 315.0],
    [90.0, 0.0, 0.0],
    [90.0, 0.0, 45.0],
    [90.0, 0.0, 90.0],
    [90.0, 0.0, 135.0],
    [270.0, 0.0, 0.0],
    [270.0, 0.0, 45.0],
    [270.0, 0.0, 90.0],
    [270.0, 0.0, 135.0],
    [0.0, 90.0, 0.0],
    [0.0, 270.0, 0.0],
    [0.0, 180.0, 90.0],
    [0.0, 180.0, 270.0],
    [90.0, 90.0, 0.0],
    [180.0, 90.0, 0.0],
    [270.0, 90.0, 0.0],
    [90.0, 180.0, 0.0],
    [270.0, 180.0, 0.0],
    [90.0, 270.0, 0.0],
    [180.0, 270.0, 0.0],
    [270.0, 270.0, 0.0],
    [90.0, 180.0, 90.0],
    [90.0, 0.0, 270.0],
    [90.0, 68.0, 293.0],
    [0.0, 315.0, 0.0],
    [90.0, 315.0, 0.0],
    [270.0, 0.0, 180.0],
    [270.0, 0.0, 270.0],
    [0.0, 90.0, 180.0],
    [0.0, 9.0, 180.0],
    [0.0, 45.0, 0.0],
    [270.0, 0.0, 225.0],
    [270.0, 0.0, 315.0],
];
/// PX4's custom rotation: `CAL_MAGn_ROLL`, `PITCH`, `YAW`.
const ROTATION_CUSTOM: i64 = 100;
/// Memory a kept reading costs while read and once handed over, doubled for vector growth, bytes.
const HELD_PER_READING: u64 = 2 * (32 + std::mem::size_of::<Sample>() as u64);
/// Memory a kept attitude costs (time and quaternion, kept and handed over, doubled), bytes.
const HELD_PER_ATTITUDE: u64 = 2 * (24 + 40);
/// Memory a kept scalar of a series costs (kept and handed over, doubled), bytes.
const HELD_PER_SCALAR: u64 = 2 * (16 + 16);
/// Bytes held per GPS fix: as logged, then as a series.
const HELD_PER_FIX: u64 = 2 * (16 + std::mem::size_of::<Fix>() as u64);
/// Memory a kept parameter change or format costs beyond its bytes, bytes: measured, a million
/// one-field formats (21 MB of log) held 457 MB, two entries each.
const HELD_PER_ENTRY: u64 = 256;
/// The most formats a log may define: PX4's logs define a few hundred; a stream of endless
/// definitions is refused long before it fills the memory budget.
const MAX_FORMATS: usize = 65_536;

/// A PX4 log as read, with what the reader found out about its calibration.
#[derive(Debug, Clone)]
pub struct Px4Log {
    /// What every reader hands over.
    pub log: FlightLog,
    /// The `n` of the `CAL_MAGn_*` parameters matched to the instance read, if any.
    pub calibration_index: Option<u8>,
    /// How `n` was matched, in words.
    pub matched_by: String,
    /// The parameters of the calibration in force at the start of the log: `CAL_MAGn_*` of the
    /// matched `n`, `CAL_MAG_COMP_TYP`, `SENS_BOARD_ROT` and `SENS_BOARD_*_OFF` where logged.
    pub parameters: BTreeMap<String, f64>,
    /// The firmware version `0xMMmmppTT`, where the log has it.
    pub ver_sw_release: Option<u32>,
    /// Readings per second of the instance read: (readings - 1) / time spanned.
    pub rate_hz: f64,
}

/// Reads the readings of `selection`'s instance and what was logged beside them.
///
/// # Errors
/// An unreadable file, a directory, a file that is not a ULog, a corrupt or truncated message
/// (byte offset named), a log without magnetometer readings, an instance the log does not have,
/// or a log larger than memory allows.
pub fn read(path: &Path, selection: &Selection) -> Result<FlightLog> {
    read_px4(path, selection).map(|p| p.log)
}

/// As [`read`], with what the reader found out about the calibration.
///
/// # Errors
/// As [`read`].
pub fn read_px4(path: &Path, selection: &Selection) -> Result<Px4Log> {
    let shown = path.display().to_string();
    let file = crate::limits::Bounded::open_log(path, &shown)?;
    read_from(BufReader::with_capacity(1 << 16, file), &shown, selection)
}

/// As [`read_px4`], from any reader; `shown` names it in errors.
///
/// # Errors
/// As [`read`].
pub fn read_from<R: Read>(reader: R, shown: &str, selection: &Selection) -> Result<Px4Log> {
    let mut hashing = Hashing::new(reader);
    let raw = parse(&mut hashing, shown, Budget::new())?;
    let sha256 = hashing.hex();
    let bytes = Hashing::bytes(&hashing);
    assemble(raw, shown, selection, sha256, bytes)
}

/// A parameter's value as logged.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Param {
    Float(f32),
    Int(i32),
}

impl Param {
    fn value(self) -> f64 {
        match self {
            Self::Float(v) => f64::from(v),
            Self::Int(v) => f64::from(v),
        }
    }
}

/// One field of a format: `base[count] name` (count 1 and not an array for a scalar).
#[derive(Debug, Clone)]
struct FieldDef {
    base: String,
    count: u64,
    name: String,
}

/// Where a decoded field lies in a data message's payload (after the message id).
#[derive(Debug, Clone, Copy)]
struct At {
    offset: usize,
    count: u64,
}

/// The topics this reader decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Topic {
    SensorMag,
    VehicleMagnetometer,
    Attitude,
    Battery,
    Controls,
    Thrust,
    /// `vehicle_gps_position`: the receiver PX4 selected (or blended).
    Gps,
    /// `sensor_gps`: a receiver's own topic, read where the log has no `vehicle_gps_position`.
    SensorGps,
}

impl Topic {
    fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "sensor_mag" => Self::SensorMag,
            "vehicle_magnetometer" => Self::VehicleMagnetometer,
            "vehicle_attitude" => Self::Attitude,
            "battery_status" => Self::Battery,
            "actuator_controls_0" => Self::Controls,
            "vehicle_thrust_setpoint" => Self::Thrust,
            "vehicle_gps_position" => Self::Gps,
            "sensor_gps" => Self::SensorGps,
            _ => return None,
        })
    }

    fn name(self) -> &'static str {
        match self {
            Self::SensorMag => "sensor_mag",
            Self::VehicleMagnetometer => "vehicle_magnetometer",
            Self::Attitude => "vehicle_attitude",
            Self::Battery => "battery_status",
            Self::Controls => "actuator_controls_0",
            Self::Thrust => "vehicle_thrust_setpoint",
            Self::Gps => "vehicle_gps_position",
            Self::SensorGps => "sensor_gps",
        }
    }

    /// The float field read, how many of its elements, and which element first.
    fn value_field(self) -> (&'static str, u64, u64) {
        match self {
            Self::SensorMag => ("x", 3, 0),
            Self::VehicleMagnetometer => ("magnetometer_ga", 3, 0),
            Self::Attitude => ("q", 4, 0),
            Self::Battery => ("current_a", 1, 0),
            Self::Controls => ("control", 1, 3),
            Self::Thrust => ("xyz", 3, 0),
            // Decoded by their own layout ([`GpsLayout`]).
            Self::Gps | Self::SensorGps => ("", 0, 0),
        }
    }
}

/// How to decode a subscription's data messages.
#[derive(Debug, Clone)]
struct Decoder {
    topic: Topic,
    multi_id: u8,
    timestamp: usize,
    /// Offsets of the float values read (up to four).
    values: [usize; 4],
    n: usize,
    device_id: Option<usize>,
    /// Where a GPS topic's fields lie.
    gps: Option<GpsLayout>,
    /// Shortest payload that holds every field read.
    need: usize,
}

/// A number of a GPS topic: a 32-bit integer in units of `scale`, or a `double`.
#[derive(Debug, Clone, Copy)]
enum Number {
    Int32 { at: usize, scale: f64 },
    Double { at: usize },
}

impl Number {
    fn get(self, data: &[u8]) -> f64 {
        match self {
            Self::Int32 { at, scale } => {
                f64::from(i32::from_le_bytes(data[at..at + 4].try_into().expect("4 bytes"))) * scale
            }
            Self::Double { at } => f64::from_le_bytes(data[at..at + 8].try_into().expect("8 bytes")),
        }
    }

    fn end(self) -> usize {
        match self {
            Self::Int32 { at, .. } => at + 4,
            Self::Double { at } => at + 8,
        }
    }
}

/// The fields of `vehicle_gps_position` or `sensor_gps`: `lat`, `lon` (1e-7 degrees), `alt`
/// (mm) before PX4 1.14, `latitude_deg`, `longitude_deg`, `altitude_msl_m` (doubles) after;
/// `fix_type` (uint8), `time_utc_usec` (uint64, 0 before a time).
#[derive(Debug, Clone, Copy)]
struct GpsLayout {
    lat: Number,
    lon: Number,
    alt: Number,
    fix_type: usize,
    utc: Option<usize>,
    /// `heading` (float, radians, NaN without one): a moving-baseline receiver's yaw.
    heading: Option<usize>,
}

/// The layout of a GPS topic in `formats`.
fn gps_layout(
    name: &str,
    formats: &HashMap<String, Vec<FieldDef>>,
    sizes: &mut HashMap<String, u64>,
) -> std::result::Result<GpsLayout, String> {
    let mut number = |old: &str, scale: f64, new: &str| -> std::result::Result<Number, String> {
        if let Some(a) = locate(name, old, "int32_t", formats, sizes)? {
            return Ok(Number::Int32 { at: a.offset, scale });
        }
        locate(name, new, "double", formats, sizes)?
            .map(|a| Number::Double { at: a.offset })
            .ok_or_else(|| format!("{name} has neither {old} nor {new}"))
    };
    let lat = number("lat", 1e-7, "latitude_deg")?;
    let lon = number("lon", 1e-7, "longitude_deg")?;
    let alt = number("alt", 1e-3, "altitude_msl_m")?;
    let fix_type = locate(name, "fix_type", "uint8_t", formats, sizes)?
        .ok_or_else(|| format!("{name} has no fix_type"))?
        .offset;
    let utc = locate(name, "time_utc_usec", "uint64_t", formats, sizes)?.map(|a| a.offset);
    let heading = locate(name, "heading", "float", formats, sizes)?.map(|a| a.offset);
    Ok(GpsLayout {
        lat,
        lon,
        alt,
        fix_type,
        utc,
        heading,
    })
}

impl GpsLayout {
    fn need(&self) -> usize {
        [
            self.lat.end(),
            self.lon.end(),
            self.alt.end(),
            self.fix_type + 1,
            self.utc.map_or(0, |u| u + 8),
            self.heading.map_or(0, |h| h + 4),
        ]
        .into_iter()
        .max()
        .unwrap_or(0)
    }

    /// The fix a message holds; UTC where the receiver has given a time (0 before).
    fn fix(&self, data: &[u8]) -> Fix {
        let utc_us = self
            .utc
            .map_or(0, |u| u64::from_le_bytes(data[u..u + 8].try_into().expect("8 bytes")));
        Fix {
            lat_deg: self.lat.get(data),
            lon_deg: self.lon.get(data),
            alt_m: self.alt.get(data),
            fix_type: data[self.fix_type],
            utc_s: (utc_us > 0).then_some(utc_us as f64 * 1e-6),
        }
    }
}

/// A kept magnetometer reading as logged.
#[derive(Debug, Clone, Copy)]
struct RawReading {
    t_us: u64,
    v: [f32; 3],
    device_id: Option<u32>,
    offset: u64,
}

/// What the pass over the file collected.
#[derive(Debug, Default)]
struct Raw {
    version: u8,
    info_u32: BTreeMap<String, u32>,
    info_text: BTreeMap<String, String>,
    initial: BTreeMap<String, Param>,
    /// Parameters set in the data section: (byte offset, name, value), in file order.
    changes: Vec<(u64, String, Param)>,
    sensor_mag: BTreeMap<u8, Vec<RawReading>>,
    vehicle_mag: BTreeMap<u8, Vec<RawReading>>,
    attitude: Vec<(u64, [f32; 4], u64)>,
    battery: BTreeMap<u8, Vec<(u64, f32, u64)>>,
    controls: Vec<(u64, f32, u64)>,
    thrust: Vec<(u64, f32, u64)>,
    vehicle_gps: Vec<(u64, Fix, u64)>,
    sensor_gps: Vec<(u64, Fix, u64)>,
    vehicle_gps_heading: Vec<(u64, f32, u64)>,
    sensor_gps_heading: Vec<(u64, f32, u64)>,
    dropouts: usize,
    dropout_ms: u64,
    unknown: BTreeMap<u8, usize>,
    skipped_before_appended: u64,
}

/// The running charge of what is kept against half of the memory the process may use.
struct Budget {
    used: u64,
    limit: Option<(u64, u64, &'static str)>,
}

impl Budget {
    fn new() -> Self {
        Self {
            used: 0,
            limit: limits::available_memory().map(|(a, what)| (a / 2, a, what)),
        }
    }

    fn charge(&mut self, bytes: u64, shown: &str, offset: u64) -> Result<()> {
        self.used = self.used.saturating_add(bytes);
        if let Some((limit, available, what)) = self.limit
            && self.used > limit
        {
            bail!(
                "{shown}: byte {offset}: the log holds more than fits in memory (the readings, series and parameters kept so far take {}; the limit is {}, half of {} {what})",
                limits::bytes(self.used),
                limits::bytes(limit),
                limits::bytes(available)
            );
        }
        Ok(())
    }
}

/// The file as a stream of bytes with its position.
struct Stream<'a, R> {
    inner: &'a mut R,
    pos: u64,
    shown: &'a str,
}

impl<R: Read> Stream<'_, R> {
    /// Reads into `buf` until it is full or the file ends; returns the bytes read.
    fn fill(&mut self, buf: &mut [u8]) -> Result<usize> {
        let mut got = 0;
        while got < buf.len() {
            match self.inner.read(&mut buf[got..]) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    return Err(e).with_context(|| {
                        format!("{}: cannot read the log at byte {}", self.shown, self.pos + got as u64)
                    });
                }
            }
        }
        self.pos += got as u64;
        Ok(got)
    }

    /// Skips `n` bytes; the file must hold them.
    fn skip(&mut self, n: u64, why: &str) -> Result<()> {
        let start = self.pos;
        let mut left = n;
        let mut buf = [0u8; 4096];
        while left > 0 {
            let want = left.min(buf.len() as u64) as usize;
            let got = self.fill(&mut buf[..want])?;
            if got == 0 {
                bail!(
                    "{}: byte {start}: {why} at byte {}, past the end of the file (byte {}): truncated or corrupt",
                    self.shown,
                    start + n,
                    self.pos
                );
            }
            left -= got as u64;
        }
        Ok(())
    }
}

/// Reads the whole file once, keeping what [`assemble`] needs: the header, then one message at a
/// time, each handed to [`Pass::take`].
fn parse<R: Read>(reader: &mut R, shown: &str, budget: Budget) -> Result<Raw> {
    let mut s = Stream {
        inner: reader,
        pos: 0,
        shown,
    };
    let mut pass = Pass::new(file_version(&mut s)?, budget);
    let mut first = true;
    let mut payload = vec![0u8; usize::from(u16::MAX)];
    loop {
        let at = s.pos;
        // The appended data starts here, or within the next message header's bytes.
        if pass.skip_to_appended(&mut s, at, at + 3)? {
            continue;
        }
        let mut head = [0u8; 3];
        let got = s.fill(&mut head)?;
        if got == 0 {
            break;
        }
        if got < 3 {
            bail!("{shown}: byte {at}: the file ends inside a message header ({got} of 3 bytes): truncated");
        }
        let size = usize::from(u16::from_le_bytes([head[0], head[1]]));
        let kind = head[2];
        let end = at + 3 + size as u64;
        // Appended data (a crash log's tail) starts at a fixed offset: a message of the main
        // section that runs past it was cut where the appended data was written.
        if pass.skip_to_appended(&mut s, at, end)? {
            continue;
        }
        let got = s.fill(&mut payload[..size])?;
        if got < size {
            bail!(
                "{shown}: byte {at}: message '{}' of {size} bytes ends at byte {end}, past the end of the file (byte {}): truncated",
                show_type(kind),
                s.pos
            );
        }
        let msg = Message {
            shown,
            at,
            kind,
            body: &payload[..size],
        };
        pass.take(&msg, first)?;
        first = false;
    }
    if let Some(&next) = pass.appended.first()
        && next > s.pos
    {
        bail!(
            "{shown}: the flag bits announce appended data at byte {next}, past the end of the file (byte {}): truncated",
            s.pos
        );
    }
    Ok(pass.raw)
}

/// Reads the 16-byte header: the ULog magic, then the file version, returned.
fn file_version<R: Read>(s: &mut Stream<'_, R>) -> Result<u8> {
    let mut header = [0u8; 16];
    let got = s.fill(&mut header)?;
    if got < 16 || header[..7] != MAGIC {
        bail!(
            "{}: not a PX4 ULog file (it does not start with the 16-byte ULog header \"ULog\" 01 12 35)",
            s.shown
        );
    }
    Ok(header[7])
}

/// One message as read: where it starts, its type and its payload (after the 3-byte header).
struct Message<'a> {
    shown: &'a str,
    at: u64,
    kind: u8,
    body: &'a [u8],
}

impl Message<'_> {
    /// The byte after the message.
    fn end(&self) -> u64 {
        self.at + 3 + self.body.len() as u64
    }

    /// The text of an error about this message: the file, its byte offset, type and size, `what`.
    fn error(&self, what: &str) -> String {
        format!(
            "{}: byte {}: message '{}' ({} bytes): {what}",
            self.shown,
            self.at,
            show_type(self.kind),
            self.body.len()
        )
    }
}

/// What the pass over the file holds while it reads: what it keeps, and the state of the log
/// (formats, subscriptions, whether the data section began, appended data still ahead).
struct Pass {
    raw: Raw,
    budget: Budget,
    formats: HashMap<String, Vec<FieldDef>>,
    /// Bytes of the formats sized so far.
    sizes: HashMap<String, u64>,
    /// The decoder of each message id added, `None` for a topic not read.
    subs: HashMap<u16, Option<Decoder>>,
    in_data: bool,
    /// Byte offsets where appended data starts, ascending, those not reached yet.
    appended: Vec<u64>,
}

impl Pass {
    fn new(version: u8, budget: Budget) -> Self {
        Self {
            raw: Raw {
                version,
                ..Raw::default()
            },
            budget,
            formats: HashMap::new(),
            sizes: HashMap::new(),
            subs: HashMap::new(),
            in_data: false,
            appended: Vec::new(),
        }
    }

    /// Skips from `at` to the next appended data when it starts before `upto`, counting the
    /// bytes skipped since `at`; whether it did.
    fn skip_to_appended<R: Read>(&mut self, s: &mut Stream<'_, R>, at: u64, upto: u64) -> Result<bool> {
        let Some(&next) = self.appended.first() else {
            return Ok(false);
        };
        if next >= upto {
            return Ok(false);
        }
        self.raw.skipped_before_appended += next.saturating_sub(at);
        s.skip(next.saturating_sub(s.pos), "the appended data starts")?;
        self.appended.remove(0);
        Ok(true)
    }

    /// Takes one message; `first` when it is the first after the header.
    fn take(&mut self, msg: &Message<'_>, first: bool) -> Result<()> {
        match msg.kind {
            b'B' => self.flag_bits(msg, first),
            b'F' => self.format(msg),
            b'I' | b'M' => self.info(msg),
            b'P' | b'Q' => self.parameter(msg),
            b'A' => self.add_logged(msg),
            b'R' => self.remove_logged(msg),
            b'D' => self.data(msg),
            b'O' => self.dropout(msg),
            b'L' | b'C' | b'S' => {
                self.in_data = true;
                Ok(())
            }
            other if other.is_ascii_alphabetic() => {
                *self.raw.unknown.entry(other).or_default() += 1;
                Ok(())
            }
            _ => bail!("{}", msg.error("not a ULog message type: corrupt")),
        }
    }

    /// `B`, the flag bits: incompatible flags this reader does not know are an error; the
    /// offsets of appended data are kept.
    fn flag_bits(&mut self, msg: &Message<'_>, first: bool) -> Result<()> {
        let body = msg.body;
        if !first {
            bail!("{}", msg.error("flag bits are allowed only as the first message"));
        }
        if body.len() < 40 {
            bail!("{}", msg.error("flag bits need 40 bytes"));
        }
        let incompat = &body[8..16];
        if incompat[0] & !1 != 0 || incompat[1..].iter().any(|&b| b != 0) {
            bail!(
                "{}",
                msg.error(&format!(
                    "incompatible flags {incompat:02x?} that this reader does not know: a newer ULog"
                ))
            );
        }
        if incompat[0] & 1 != 0 {
            for k in 0..3 {
                let o = u64::from_le_bytes(body[16 + 8 * k..24 + 8 * k].try_into().expect("8 bytes"));
                if o != 0 {
                    if o < msg.end() || self.appended.last().is_some_and(|&p| o <= p) {
                        bail!(
                            "{}",
                            msg.error(&format!(
                                "appended data offset {o} is not after the flag bits and ascending"
                            ))
                        );
                    }
                    self.appended.push(o);
                }
            }
        }
        Ok(())
    }

    /// `F`, a format: kept by name, each name once.
    fn format(&mut self, msg: &Message<'_>) -> Result<()> {
        let text = std::str::from_utf8(msg.body)
            .map_err(|_| anyhow::anyhow!("{}", msg.error("a format that is not UTF-8")))?;
        let (fname, fields) = parse_format(text).map_err(|e| anyhow::anyhow!("{}", msg.error(&e)))?;
        if self.formats.len() >= MAX_FORMATS {
            bail!(
                "{}",
                msg.error(&format!(
                    "more than {MAX_FORMATS} formats (a PX4 log defines a few hundred): not a log to read"
                ))
            );
        }
        let held = msg.body.len() as u64 + HELD_PER_ENTRY * (1 + fields.len() as u64);
        self.budget.charge(held, msg.shown, msg.at)?;
        if self.formats.insert(fname.clone(), fields).is_some() {
            bail!("{}", msg.error(&format!("format {} defined twice", excerpt(&fname))));
        }
        Ok(())
    }

    /// `I` or `M`, an information message (`M` with its multi-message flag): the `uint32_t`
    /// values, and the texts `ver_sw`, `ver_hw`, `sys_name`, `ver_sw_branch`, are kept.
    fn info(&mut self, msg: &Message<'_>) -> Result<()> {
        let (body, size) = (msg.body, msg.body.len());
        let skip = usize::from(msg.kind == b'M');
        if size < 1 + skip {
            bail!("{}", msg.error("too short"));
        }
        let key_len = usize::from(body[skip]);
        if 1 + skip + key_len > size {
            bail!(
                "{}",
                msg.error(&format!("a key of {key_len} bytes runs past the message"))
            );
        }
        let key = std::str::from_utf8(&body[1 + skip..1 + skip + key_len])
            .map_err(|_| anyhow::anyhow!("{}", msg.error("a key that is not UTF-8")))?;
        let value = &body[1 + skip + key_len..];
        if msg.kind == b'I'
            && let Some((ty, k)) = key.split_once(' ')
        {
            if ty == "uint32_t" && value.len() == 4 {
                self.budget.charge(HELD_PER_ENTRY + k.len() as u64, msg.shown, msg.at)?;
                self.raw
                    .info_u32
                    .insert(k.to_string(), u32::from_le_bytes(value.try_into().expect("4 bytes")));
            } else if ty.starts_with("char[") && matches!(k, "ver_sw" | "ver_hw" | "sys_name" | "ver_sw_branch") {
                let text = String::from_utf8_lossy(value).trim_end_matches('\0').to_string();
                self.raw.info_text.insert(k.to_string(), text);
            }
        }
        Ok(())
    }

    /// `P`, a parameter, or `Q`, a parameter default (checked, not kept): a `float` or
    /// `int32_t`, kept as in force at the start where it comes before the data section, else
    /// as a change at its byte offset.
    fn parameter(&mut self, msg: &Message<'_>) -> Result<()> {
        let (body, size) = (msg.body, msg.body.len());
        let skip = usize::from(msg.kind == b'Q');
        if size < 1 + skip {
            bail!("{}", msg.error("too short"));
        }
        let key_len = usize::from(body[skip]);
        if 1 + skip + key_len + 4 != size {
            bail!(
                "{}",
                msg.error(&format!(
                    "a key of {key_len} bytes and a 4-byte value do not make {size} bytes"
                ))
            );
        }
        let key = std::str::from_utf8(&body[1 + skip..1 + skip + key_len])
            .map_err(|_| anyhow::anyhow!("{}", msg.error("a parameter name that is not UTF-8")))?;
        let bytes: [u8; 4] = body[size - 4..].try_into().expect("4 bytes");
        let (ty, pname) = key
            .split_once(' ')
            .ok_or_else(|| anyhow::anyhow!("{}", msg.error(&format!("parameter {} has no type", excerpt(key)))))?;
        let value = match ty {
            "float" => Param::Float(f32::from_le_bytes(bytes)),
            "int32_t" => Param::Int(i32::from_le_bytes(bytes)),
            _ => bail!(
                "{}",
                msg.error(&format!(
                    "parameter {} of type {}, which ULog does not have (float and int32_t): a damaged log",
                    excerpt(pname),
                    excerpt(ty)
                ))
            ),
        };
        if msg.kind == b'P' {
            self.budget.charge(HELD_PER_ENTRY + key_len as u64, msg.shown, msg.at)?;
            if self.in_data {
                self.raw.changes.push((msg.at, pname.to_string(), value));
            } else {
                self.raw.initial.insert(pname.to_string(), value);
            }
        }
        Ok(())
    }

    /// `A`, a subscription added: its message id, with the decoder of a topic this reader reads.
    fn add_logged(&mut self, msg: &Message<'_>) -> Result<()> {
        let body = msg.body;
        self.in_data = true;
        if body.len() < 4 {
            bail!("{}", msg.error("too short for an add-logged message"));
        }
        let multi_id = body[0];
        let id = u16::from_le_bytes([body[1], body[2]]);
        let topic = std::str::from_utf8(&body[3..])
            .map_err(|_| anyhow::anyhow!("{}", msg.error("a topic name that is not UTF-8")))?;
        if !self.formats.contains_key(topic) {
            bail!("{}", msg.error(&format!("topic {} has no format", excerpt(topic))));
        }
        let decoder = match Topic::from_name(topic) {
            Some(t) => Some(
                decoder(t, multi_id, &self.formats, &mut self.sizes)
                    .map_err(|e| anyhow::anyhow!("{}", msg.error(&e)))?,
            ),
            None => None,
        };
        self.budget.charge(HELD_PER_ENTRY, msg.shown, msg.at)?;
        if self.subs.insert(id, decoder).is_some() {
            bail!("{}", msg.error(&format!("message id {id} added twice")));
        }
        Ok(())
    }

    /// `R`, a subscription removed.
    fn remove_logged(&mut self, msg: &Message<'_>) -> Result<()> {
        self.in_data = true;
        if msg.body.len() < 2 {
            bail!("{}", msg.error("too short"));
        }
        self.subs.remove(&u16::from_le_bytes([msg.body[0], msg.body[1]]));
        Ok(())
    }

    /// `D`, data of a subscription: decoded and kept where its topic is read.
    fn data(&mut self, msg: &Message<'_>) -> Result<()> {
        let body = msg.body;
        if body.len() < 2 {
            bail!("{}", msg.error("too short for a data message"));
        }
        let id = u16::from_le_bytes([body[0], body[1]]);
        let Some(sub) = self.subs.get(&id) else {
            bail!(
                "{}",
                msg.error(&format!(
                    "data of message id {id}, which no add-logged message announced"
                ))
            );
        };
        if let Some(d) = sub {
            let data = &body[2..];
            if data.len() < d.need {
                bail!(
                    "{}",
                    msg.error(&format!(
                        "{} (multi_id {}) needs {} bytes of data, the message has {}",
                        d.topic.name(),
                        d.multi_id,
                        d.need,
                        data.len()
                    ))
                );
            }
            keep(&mut self.raw, d, data, msg.at, &mut self.budget, msg.shown)?;
        }
        Ok(())
    }

    /// `O`, a dropout: counted, with its milliseconds.
    fn dropout(&mut self, msg: &Message<'_>) -> Result<()> {
        self.in_data = true;
        if msg.body.len() < 2 {
            bail!("{}", msg.error("too short"));
        }
        self.raw.dropouts += 1;
        self.raw.dropout_ms += u64::from(u16::from_le_bytes([msg.body[0], msg.body[1]]));
        Ok(())
    }
}

/// A message type for an error: its letter, or its code.
fn show_type(t: u8) -> String {
    if t.is_ascii_graphic() {
        char::from(t).to_string()
    } else {
        format!("0x{t:02x}")
    }
}

/// At most [`super::read::EXCERPT_CHARS`] characters of `text`, for an error.
fn excerpt(text: &str) -> String {
    format!("{:?}", limits::excerpt(text, super::read::EXCERPT_CHARS))
}

/// `name:type field;type field;...`
fn parse_format(text: &str) -> std::result::Result<(String, Vec<FieldDef>), String> {
    let (name, rest) = text
        .split_once(':')
        .ok_or_else(|| format!("format {} has no ':'", excerpt(text)))?;
    if name.is_empty() {
        return Err(format!("format {} has no name", excerpt(text)));
    }
    let mut fields = Vec::new();
    for part in rest.split(';').filter(|p| !p.is_empty()) {
        let (ty, fname) = part
            .split_once(' ')
            .ok_or_else(|| format!("field {} of format {} is not 'type name'", excerpt(part), excerpt(name)))?;
        let (base, count) = match ty.split_once('[') {
            Some((base, n)) => {
                let n = n
                    .strip_suffix(']')
                    .and_then(|n| n.parse::<u64>().ok())
                    .filter(|&n| n <= u64::from(u16::MAX))
                    .ok_or_else(|| {
                        format!(
                            "field {} of format {}: not an array size up to 65535",
                            excerpt(part),
                            excerpt(name)
                        )
                    })?;
                (base, n)
            }
            None => (ty, 1),
        };
        if base.is_empty() || fname.is_empty() {
            return Err(format!(
                "field {} of format {} is not 'type name'",
                excerpt(part),
                excerpt(name)
            ));
        }
        fields.push(FieldDef {
            base: base.to_string(),
            count,
            name: fname.to_string(),
        });
    }
    Ok((name.to_string(), fields))
}

/// Bytes of one element of type `base`.
fn type_size(
    base: &str,
    formats: &HashMap<String, Vec<FieldDef>>,
    sizes: &mut HashMap<String, u64>,
    depth: usize,
) -> std::result::Result<u64, String> {
    let primitive = match base {
        "int8_t" | "uint8_t" | "bool" | "char" => 1,
        "int16_t" | "uint16_t" => 2,
        "int32_t" | "uint32_t" | "float" => 4,
        "int64_t" | "uint64_t" | "double" => 8,
        _ => 0,
    };
    if primitive > 0 {
        return Ok(primitive);
    }
    if let Some(&n) = sizes.get(base) {
        return Ok(n);
    }
    if depth >= MAX_NESTING {
        return Err(format!(
            "formats nested deeper than {MAX_NESTING} levels at {} (a format that contains itself?)",
            excerpt(base)
        ));
    }
    let fields = formats
        .get(base)
        .ok_or_else(|| format!("type {} is neither a ULog type nor a format of the log", excerpt(base)))?;
    let mut total: u64 = 0;
    for f in fields {
        let one = type_size(&f.base, formats, sizes, depth + 1)?;
        total = total.saturating_add(one.saturating_mul(f.count));
    }
    sizes.insert(base.to_string(), total);
    Ok(total)
}

/// Finds the top-level field `name` of `topic`: its offset and element count, checking its type.
fn locate(
    topic: &str,
    name: &str,
    want: &str,
    formats: &HashMap<String, Vec<FieldDef>>,
    sizes: &mut HashMap<String, u64>,
) -> std::result::Result<Option<At>, String> {
    let fields = formats
        .get(topic)
        .ok_or_else(|| format!("topic {topic} has no format"))?;
    let mut offset: u64 = 0;
    for f in fields {
        if f.name == name {
            if f.base != want {
                return Err(format!("{topic}.{name} is {}, not {want}", excerpt(&f.base)));
            }
            let offset = usize::try_from(offset)
                .ok()
                .filter(|&o| o <= usize::from(u16::MAX))
                .ok_or_else(|| format!("{topic}.{name} lies past the largest message"))?;
            return Ok(Some(At { offset, count: f.count }));
        }
        offset = offset.saturating_add(type_size(&f.base, formats, sizes, 1)?.saturating_mul(f.count));
    }
    Ok(None)
}

/// The decoder of a subscription to `topic`.
fn decoder(
    topic: Topic,
    multi_id: u8,
    formats: &HashMap<String, Vec<FieldDef>>,
    sizes: &mut HashMap<String, u64>,
) -> std::result::Result<Decoder, String> {
    let name = topic.name();
    let timestamp = locate(name, "timestamp", "uint64_t", formats, sizes)?
        .ok_or_else(|| format!("{name} has no timestamp"))?
        .offset;
    if matches!(topic, Topic::Gps | Topic::SensorGps) {
        let gps = gps_layout(name, formats, sizes)?;
        return Ok(Decoder {
            topic,
            multi_id,
            timestamp,
            values: [0; 4],
            n: 0,
            device_id: None,
            need: gps.need().max(timestamp + 8),
            gps: Some(gps),
        });
    }
    let (field, n, first) = topic.value_field();
    let mut values = [0usize; 4];
    if topic == Topic::SensorMag {
        for (k, axis) in ["x", "y", "z"].into_iter().enumerate() {
            values[k] = locate(name, axis, "float", formats, sizes)?
                .ok_or_else(|| format!("{name} has no field {axis}"))?
                .offset;
        }
    } else {
        let at = locate(name, field, "float", formats, sizes)?.ok_or_else(|| format!("{name} has no field {field}"))?;
        if at.count < first + n {
            return Err(format!(
                "{name}.{field} has {} elements, {} are read",
                at.count,
                first + n
            ));
        }
        for (k, v) in values.iter_mut().enumerate().take(n as usize) {
            *v = at.offset + 4 * (first as usize + k);
        }
    }
    let device_id = if matches!(topic, Topic::SensorMag | Topic::VehicleMagnetometer) {
        locate(name, "device_id", "uint32_t", formats, sizes)?.map(|a| a.offset)
    } else {
        None
    };
    let n = n as usize;
    let need = [timestamp + 8, device_id.map_or(0, |o| o + 4)]
        .into_iter()
        .chain(values[..n].iter().map(|o| o + 4))
        .max()
        .unwrap_or(0);
    Ok(Decoder {
        topic,
        multi_id,
        timestamp,
        values,
        n,
        device_id,
        gps: None,
        need,
    })
}

fn f32_at(data: &[u8], o: usize) -> f32 {
    f32::from_le_bytes(data[o..o + 4].try_into().expect("4 bytes"))
}

/// Decodes one data message of a kept topic (its length already checked against `d.need`).
fn keep(raw: &mut Raw, d: &Decoder, data: &[u8], at: u64, budget: &mut Budget, shown: &str) -> Result<()> {
    let t_us = u64::from_le_bytes(data[d.timestamp..d.timestamp + 8].try_into().expect("8 bytes"));
    let mut v = [0f32; 4];
    for (x, &o) in v.iter_mut().zip(&d.values[..d.n]) {
        *x = f32_at(data, o);
    }
    match d.topic {
        Topic::SensorMag | Topic::VehicleMagnetometer => {
            budget.charge(HELD_PER_READING, shown, at)?;
            let device_id = d
                .device_id
                .map(|o| u32::from_le_bytes(data[o..o + 4].try_into().expect("4 bytes")));
            let map = if d.topic == Topic::SensorMag {
                &mut raw.sensor_mag
            } else {
                &mut raw.vehicle_mag
            };
            map.entry(d.multi_id).or_default().push(RawReading {
                t_us,
                v: [v[0], v[1], v[2]],
                device_id,
                offset: at,
            });
        }
        Topic::Attitude => {
            // One attitude: the estimator's output, instance 0.
            if d.multi_id == 0 {
                budget.charge(HELD_PER_ATTITUDE, shown, at)?;
                raw.attitude.push((t_us, v, at));
            }
        }
        Topic::Battery => {
            budget.charge(HELD_PER_SCALAR, shown, at)?;
            raw.battery.entry(d.multi_id).or_default().push((t_us, v[0], at));
        }
        Topic::Controls => {
            if d.multi_id == 0 {
                budget.charge(HELD_PER_SCALAR, shown, at)?;
                raw.controls.push((t_us, v[0], at));
            }
        }
        Topic::Gps | Topic::SensorGps => {
            if let (0, Some(g)) = (d.multi_id, &d.gps) {
                budget.charge(HELD_PER_FIX, shown, at)?;
                let (list, headings) = if d.topic == Topic::Gps {
                    (&mut raw.vehicle_gps, &mut raw.vehicle_gps_heading)
                } else {
                    (&mut raw.sensor_gps, &mut raw.sensor_gps_heading)
                };
                let fix = g.fix(data);
                list.push((t_us, fix, at));
                if let Some(h) = g.heading.map(|o| f32_at(data, o)).filter(|h| h.is_finite())
                    && fix.fix_type >= 3
                {
                    headings.push((t_us, h, at));
                }
            }
        }
        Topic::Thrust => {
            if d.multi_id == 0 {
                budget.charge(HELD_PER_SCALAR, shown, at)?;
                let norm = (f64::from(v[0]).powi(2) + f64::from(v[1]).powi(2) + f64::from(v[2]).powi(2)).sqrt();
                raw.thrust.push((t_us, norm as f32, at));
            }
        }
    }
    Ok(())
}

/// A firmware version `0xMMmmppTT` in words: `v1.16.1 (release candidate)`.
pub fn version_words(v: u32) -> String {
    let [major, minor, patch, kind] = v.to_be_bytes();
    let kind = match kind {
        0..=63 => "development",
        64..=127 => "alpha",
        128..=191 => "beta",
        192..=254 => "release candidate",
        255 => "release",
    };
    format!("v{major}.{minor}.{patch} ({kind})")
}

/// PX4's `matrix::Dcmf(Eulerf(roll, pitch, yaw))`, angles in degrees: `Rz(yaw) Ry(pitch) Rx(roll)`.
pub fn euler_dcm(roll_deg: f64, pitch_deg: f64, yaw_deg: f64) -> Mat3 {
    let (sr, cr) = roll_deg.to_radians().sin_cos();
    let (sp, cp) = pitch_deg.to_radians().sin_cos();
    let (sy, cy) = yaw_deg.to_radians().sin_cos();
    [
        [cp * cy, -cr * sy + sr * sp * cy, sr * sy + cr * sp * cy],
        [cp * sy, cr * cy + sr * sp * sy, -sr * cy + cr * sp * sy],
        [-sp, sr * cp, cr * cp],
    ]
}

/// The matrix of PX4's `enum Rotation` value `rot`, where it is one.
pub fn rotation_matrix(rot: i64) -> Option<Mat3> {
    let [r, p, y] = *ROTATIONS.get(usize::try_from(rot).ok()?)?;
    Some(euler_dcm(r, p, y))
}

fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for (i, row) in c.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

/// Turns `raw` into the [`Px4Log`] of `selection`'s instance.
fn assemble(raw: Raw, shown: &str, selection: &Selection, sha256: String, bytes: u64) -> Result<Px4Log> {
    let chosen = choose_instance(&raw, shown, selection)?;
    let mut notes = Vec::new();
    let mut messages = Vec::new();
    let ver = raw.info_u32.get("ver_sw_release").copied().filter(|&v| v != 0);
    match ver {
        Some(v) => messages.push(format!("info: ver_sw_release 0x{v:08X} = {}", version_words(v))),
        None => notes.push("The log has no firmware version (info ver_sw_release).".to_string()),
    }
    let slot = match_slot(&raw, &chosen, &mut notes);
    let (calibration, frame, samples) = carried(&raw, &chosen, &slot, ver, shown, &mut notes)?;
    messages.insert(0, chosen.source());
    if let Some(p) = &slot.prefix {
        messages.push(format!("parameters: {p}* (matched by {})", slot.matched_by));
    }
    let to_body = if !chosen.from_sensor {
        Some([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    } else {
        body_rotation(
            slot.cal("ROT"),
            &slot.parameters,
            slot.prefix.as_deref(),
            &raw,
            &mut notes,
        )
    };
    let comp_type = slot.parameters.get("CAL_MAG_COMP_TYP").copied().unwrap_or(0.0);
    note_compensation(&slot, comp_type, &mut notes);
    let beside = beside(&raw, shown, comp_type, &mut messages)?;
    let rate_hz = rate_of(&samples);
    note_rate(&raw, &chosen, &samples, rate_hz, beside.attitude.as_ref(), &mut notes);
    note_file(&raw, &mut notes);
    // A ULog's header holds every parameter of its firmware.
    let parameters = LogParameters::px4(raw.initial.keys());
    let log = FlightLog {
        format: Format::Ulog,
        messages,
        unit: Units::Gauss,
        frame,
        instances: chosen.instances,
        instance: chosen.instance,
        samples,
        attitude: beside.attitude,
        current: beside.current,
        throttle: beside.throttle,
        gps: beside.gps,
        gps_yaw: beside.gps_yaw,
        gsf_yaw: None,
        to_body,
        calibration,
        notes,
        parameters,
        sha256,
        bytes,
    };
    Ok(Px4Log {
        log,
        calibration_index: slot.index,
        matched_by: slot.matched_by,
        parameters: slot.parameters,
        ver_sw_release: ver,
        rate_hz,
    })
}

/// The magnetometer series read: `sensor_mag`, else `vehicle_magnetometer`, and its instance.
struct Chosen<'a> {
    /// Whether the readings are `sensor_mag`'s.
    from_sensor: bool,
    topic: &'static str,
    /// The instances the log has of `topic`, ascending.
    instances: Vec<u8>,
    instance: u8,
    /// The instance's readings, at least one.
    readings: &'a [RawReading],
}

impl Chosen<'_> {
    /// The `device_id` of the first reading, where the topic carries one.
    fn device_id(&self) -> Option<u32> {
        self.readings[0].device_id
    }

    /// What was read, for the log's messages.
    fn source(&self) -> String {
        format!(
            "{} (multi_id {}{}): {}",
            self.topic,
            self.instance,
            self.device_id().map_or(String::new(), |id| format!(", device_id {id}")),
            if self.from_sensor {
                "x, y, z"
            } else {
                "magnetometer_ga[0..2]"
            }
        )
    }
}

/// The series of `selection`'s instance (default the lowest), or an error naming those there are.
fn choose_instance<'a>(raw: &'a Raw, shown: &str, selection: &Selection) -> Result<Chosen<'a>> {
    let from_sensor = !raw.sensor_mag.is_empty();
    let series = if from_sensor { &raw.sensor_mag } else { &raw.vehicle_mag };
    if series.is_empty() {
        bail!("{shown}: the log has no magnetometer readings (no sensor_mag or vehicle_magnetometer data)");
    }
    let topic = if from_sensor {
        "sensor_mag"
    } else {
        "vehicle_magnetometer"
    };
    let instances: Vec<u8> = series.keys().copied().collect();
    let instance = selection.instance.unwrap_or(instances[0]);
    let Some(readings) = series.get(&instance) else {
        let list: Vec<String> = instances.iter().map(u8::to_string).collect();
        bail!(
            "{shown}: --compass {instance}: the log has {topic} instance{} {} only",
            if list.len() == 1 { "" } else { "s" },
            list.join(", ")
        );
    };
    Ok(Chosen {
        from_sensor,
        topic,
        instances,
        instance,
        readings,
    })
}

/// The `CAL_MAGn_*` slot matched to the instance read, and the parameters kept.
struct Slot {
    /// The `n` matched, if any.
    index: Option<u8>,
    /// How `n` was matched, in words.
    matched_by: String,
    /// `CAL_MAGn_` of the `n` matched.
    prefix: Option<String>,
    /// See [`Px4Log::parameters`].
    parameters: BTreeMap<String, f64>,
}

impl Slot {
    /// `CAL_MAGn_{suffix}` of the slot matched, where logged.
    fn cal(&self, suffix: &str) -> Option<f64> {
        self.prefix
            .as_ref()
            .and_then(|p| self.parameters.get(&format!("{p}{suffix}")).copied())
    }
}

/// The calibration slot of the instance read, with notes on a change of sensor or of the slot's
/// parameters inside the log.
fn match_slot(raw: &Raw, chosen: &Chosen<'_>, notes: &mut Vec<String>) -> Slot {
    let (index, matched_by) = slot_index(raw, chosen);
    if let Some(id) = chosen.device_id()
        && let Some(other) = chosen.readings.iter().find(|r| r.device_id != Some(id))
    {
        notes.push(format!(
            "{} instance {} changes device_id from {id} to {} at byte {}: another sensor took its place.",
            chosen.topic,
            chosen.instance,
            other.device_id.unwrap_or(0),
            other.offset
        ));
    }
    let prefix = index.map(|n| format!("CAL_MAG{n}_"));
    let parameters = kept_parameters(raw, prefix.as_deref());
    if let Some(p) = &prefix {
        note_changes(raw, p, notes);
    }
    Slot {
        index,
        matched_by,
        prefix,
        parameters,
    }
}

/// The `n` of `CAL_MAGn_*`: by `CAL_MAGn_ID == device_id`, else the instance number where
/// `CAL_MAGn_XOFF` is logged; and how, in words.
fn slot_index(raw: &Raw, chosen: &Chosen<'_>) -> (Option<u8>, String) {
    let device_id = chosen.device_id();
    let param = |name: &str| raw.initial.get(name).copied();
    if let Some(id) = device_id {
        for n in 0..10u8 {
            if let Some(Param::Int(v)) = param(&format!("CAL_MAG{n}_ID"))
                && v as u32 == id
            {
                return (Some(n), format!("CAL_MAG{n}_ID = device_id {id}"));
            }
        }
    }
    let instance = chosen.instance;
    if param(&format!("CAL_MAG{instance}_XOFF")).is_some() {
        let words = match device_id {
            Some(id) => format!("instance number (no CAL_MAGn_ID equals device_id {id})"),
            None => format!("instance number ({} carries no device_id)", chosen.topic),
        };
        return (Some(instance), words);
    }
    (None, String::from("no CAL_MAGn_* parameters in the log"))
}

/// The parameters in force at the start that bear on the calibration: `CAL_MAGn_*` of `prefix`,
/// `CAL_MAG_COMP_TYP`, `SENS_BOARD_ROT`, `SENS_BOARD_*_OFF`.
fn kept_parameters(raw: &Raw, prefix: Option<&str>) -> BTreeMap<String, f64> {
    let mut parameters = BTreeMap::new();
    for (k, v) in &raw.initial {
        let wanted = prefix.is_some_and(|p| k.starts_with(p))
            || k == "CAL_MAG_COMP_TYP"
            || k == "SENS_BOARD_ROT"
            || (k.starts_with("SENS_BOARD_") && k.ends_with("_OFF"));
        if wanted {
            parameters.insert(k.clone(), v.value());
        }
    }
    parameters
}

/// A note where the parameters of `prefix` change inside the log.
fn note_changes(raw: &Raw, prefix: &str, notes: &mut Vec<String>) {
    let changed: Vec<&str> = raw
        .changes
        .iter()
        .filter(|(_, k, v)| k.starts_with(prefix) && raw.initial.get(k) != Some(v))
        .map(|(_, k, _)| k.as_str())
        .collect();
    if !changed.is_empty() {
        notes.push(format!(
            "{} change{} of {prefix}* inside the log (first {}); the values in force at each reading are used.",
            changed.len(),
            if changed.len() == 1 { "" } else { "s" },
            changed[0]
        ));
    }
}

/// What the readings carry, the frame they are in, and the readings.
type Carried = (InForce, String, Vec<Sample>);

/// What the readings carry, by topic and firmware version `ver` (see the module docs), and the
/// readings: raw, undone, or as logged.
fn carried(
    raw: &Raw,
    chosen: &Chosen<'_>,
    slot: &Slot,
    ver: Option<u32>,
    shown: &str,
    notes: &mut Vec<String>,
) -> Result<Carried> {
    let (readings, topic) = (chosen.readings, chosen.topic);
    if !chosen.from_sensor {
        let words = format!(
            "vehicle_magnetometer: PX4 publishes it after its calibration in force{} and rotated into the body frame; a fit calibrates the calibrated field",
            slot.index.map_or(String::new(), |n| format!(" (CAL_MAG{n}_*)"))
        );
        notes.push(
            "The log has no sensor_mag: read vehicle_magnetometer, which PX4 calibrates before it logs it.".to_string(),
        );
        return Ok((
            InForce::Calibrated(words),
            "body (forward, right, down)".to_string(),
            plain(readings, shown, topic)?,
        ));
    }
    match ver.map(|v| (v >> 16) >= 0x010C) {
        Some(true) => Ok((InForce::Raw, "sensor".to_string(), plain(readings, shown, topic)?)),
        None => {
            let words = "the log has no firmware version: sensor_mag is raw from PX4 1.12 on and calibrated before, which cannot be told here; read as logged".to_string();
            Ok((
                InForce::Calibrated(words),
                "sensor (as logged)".to_string(),
                plain(readings, shown, topic)?,
            ))
        }
        Some(false) => undo_driver(raw, chosen, slot, shown),
    }
}

/// `sensor_mag` of PX4 before 1.12, which its driver calibrated: undone where the log has the
/// slot's offsets and scales, else as logged.
fn undo_driver(raw: &Raw, chosen: &Chosen<'_>, slot: &Slot, shown: &str) -> Result<Carried> {
    let readings = chosen.readings;
    match slot.prefix.as_ref().and_then(|p| old_calibration(p, raw)) {
        Some(cal0) => {
            let p = slot.prefix.as_deref().unwrap_or_default();
            let samples = undo(readings, raw, p, cal0, shown)?;
            let words = format!(
                "PX4 before 1.12 logs sensor_mag after its driver applied m = SCALE * (r - OFF) per axis; undone with {p}XOFF..ZOFF and {p}XSCALE..ZSCALE in force at each reading (n matched by {})",
                slot.matched_by
            );
            Ok((
                InForce::Undone(words),
                "sensor (after the driver's orientation)".to_string(),
                samples,
            ))
        }
        None => {
            let words = format!(
                "PX4 before 1.12 logs sensor_mag after its driver's calibration, and the log lacks {}XOFF..ZOFF or XSCALE..ZSCALE (finite, scales not zero) to undo it",
                slot.prefix.as_deref().unwrap_or("CAL_MAGn_")
            );
            Ok((
                InForce::Calibrated(words),
                "sensor (calibrated by the driver)".to_string(),
                plain(readings, shown, chosen.topic)?,
            ))
        }
    }
}

/// A note where the slot has a power compensation, which the raw field does not carry.
fn note_compensation(slot: &Slot, comp_type: f64, notes: &mut Vec<String>) {
    let comp = ["XCOMP", "YCOMP", "ZCOMP"].map(|k| slot.cal(k).unwrap_or(0.0));
    if comp.iter().any(|&c| c != 0.0) {
        notes.push(format!(
            "PX4 adds power * ({}, {}, {}) (CAL_MAG_COMP_TYP = {comp_type}) to the field before its calibration; the readings here are without it.",
            comp[0], comp[1], comp[2]
        ));
    }
}

/// The series logged beside the readings.
struct Beside {
    attitude: Option<Series<[f64; 4]>>,
    current: Option<Series<f64>>,
    throttle: Option<Series<f64>>,
    gps: Option<Series<Fix>>,
    gps_yaw: Option<(Series<f64>, String)>,
}

/// The attitude, the current of the battery `CAL_MAG_COMP_TYP` = `comp_type` names, and the
/// throttle, each named in `messages` where the log has it.
fn beside(raw: &Raw, shown: &str, comp_type: f64, messages: &mut Vec<String>) -> Result<Beside> {
    let attitude = series_of(&raw.attitude, shown, "vehicle_attitude", |q| {
        [f64::from(q[0]), f64::from(q[1]), f64::from(q[2]), f64::from(q[3])]
    })?;
    if attitude.is_some() {
        messages.push("vehicle_attitude (multi_id 0): q[0..3] (w, x, y, z; body FRD to NED)".to_string());
    }
    let battery_instance = if comp_type == 3.0 { 1 } else { 0 };
    let current = match raw.battery.get(&battery_instance) {
        Some(b) => {
            messages.push(format!("battery_status (multi_id {battery_instance}): current_a (A)"));
            series_of(b, shown, "battery_status", f64::from)?
        }
        None => None,
    };
    let throttle = if !raw.controls.is_empty() {
        messages.push("actuator_controls_0: control[3] (throttle)".to_string());
        series_of(&raw.controls, shown, "actuator_controls_0", f64::from)?
    } else if !raw.thrust.is_empty() {
        messages.push("vehicle_thrust_setpoint (multi_id 0): |xyz| (throttle)".to_string());
        series_of(&raw.thrust, shown, "vehicle_thrust_setpoint", f64::from)?
    } else {
        None
    };
    let (topic, fixes, headings) = if raw.vehicle_gps.is_empty() {
        ("sensor_gps", &raw.sensor_gps, &raw.sensor_gps_heading)
    } else {
        ("vehicle_gps_position", &raw.vehicle_gps, &raw.vehicle_gps_heading)
    };
    let gps_yaw = series_of(headings, shown, topic, |h| f64::from(h).to_degrees().rem_euclid(360.0))?
        .map(|s| (s, format!("{topic}.heading (moving baseline)")));
    let gps = series_of(fixes, shown, topic, |f| f)?;
    if gps.is_some() {
        messages.push(format!(
            "{topic} (multi_id 0): fix_type, latitude, longitude, altitude (mean sea level), time_utc_usec"
        ));
    }
    Ok(Beside {
        attitude,
        current,
        throttle,
        gps,
        gps_yaw,
    })
}

/// Readings per second: (readings - 1) / time spanned; 0 for one reading or no time spanned.
fn rate_of(samples: &[Sample]) -> f64 {
    let span = samples.last().map_or(0.0, |l| l.time_s) - samples[0].time_s;
    if samples.len() > 1 && span > 0.0 {
        (samples.len() - 1) as f64 / span
    } else {
        0.0
    }
}

/// Notes where the readings are too few or too slow to calibrate (see the module docs), and
/// where `vehicle_magnetometer` then holds more of them.
fn note_rate(
    raw: &Raw,
    chosen: &Chosen<'_>,
    samples: &[Sample],
    rate_hz: f64,
    attitude: Option<&Series<[f64; 4]>>,
    notes: &mut Vec<String>,
) {
    let topic = chosen.topic;
    let turn = attitude.map(peak_turn_rate);
    let how = "raise it with SDLOG_PROFILE (add 64, sensor comparison: sensor_mag at 10 Hz) or a line 'sensor_mag 20' in the SD card's etc/logging/logger_topics.txt (50 Hz)";
    if samples.len() < MIN_READINGS {
        notes.push(format!(
            "Only {} {topic} readings ({rate_hz:.2} Hz): fewer than {MIN_READINGS}, too few to calibrate; {how}.",
            samples.len()
        ));
    } else if rate_hz < MIN_RATE_HZ {
        let moving = match turn {
            Some(t) if t >= TURNING_DEG_S => format!(
                "while the vehicle turns at up to {t:.0} degrees per second ({:.0} degrees between readings)",
                t / rate_hz
            ),
            Some(t) => format!(
                "(the vehicle turns at most {t:.0} degrees per second in this log; a calibration flight turns faster)"
            ),
            None => "(the log has no attitude to tell how fast the vehicle turns)".to_string(),
        };
        notes.push(format!(
            "{topic} is logged at {rate_hz:.2} Hz {moving}: below {MIN_RATE_HZ} Hz, too slow to calibrate (PX4's default logging profile records it at 1 Hz); {how}."
        ));
    }
    if chosen.from_sensor
        && rate_hz < MIN_RATE_HZ
        && let Some(v) = raw
            .vehicle_mag
            .get(&chosen.instance)
            .or_else(|| raw.vehicle_mag.values().next())
        && v.len() > samples.len()
    {
        notes.push(format!(
            "vehicle_magnetometer holds {} readings (calibrated by PX4, body frame) against {} of sensor_mag.",
            v.len(),
            samples.len()
        ));
    }
}

/// Notes on what the pass over the file met: dropouts, messages of unknown types, bytes skipped
/// before appended data, a file version newer than this reader knows.
fn note_file(raw: &Raw, notes: &mut Vec<String>) {
    if raw.dropouts > 0 {
        notes.push(format!(
            "The logger dropped data {} times ({} ms in all).",
            raw.dropouts, raw.dropout_ms
        ));
    }
    for (t, n) in &raw.unknown {
        notes.push(format!(
            "Skipped {n} messages of a type this reader does not know ('{}').",
            char::from(*t)
        ));
    }
    if raw.skipped_before_appended > 0 {
        notes.push(format!(
            "Skipped {} bytes cut short before the appended data.",
            raw.skipped_before_appended
        ));
    }
    if raw.version > 1 {
        notes.push(format!(
            "ULog file version {} (this reader knows 0 and 1).",
            raw.version
        ));
    }
}

/// The readings as logged.
fn plain(readings: &[RawReading], shown: &str, topic: &str) -> Result<Vec<Sample>> {
    let mut out = Vec::with_capacity(readings.len());
    let mut last = 0u64;
    for r in readings {
        check_reading(r, last, shown, topic)?;
        last = r.t_us;
        out.push(Sample {
            time_s: r.t_us as f64 * 1e-6,
            raw: r.v.map(f64::from),
            offset: r.offset,
        });
    }
    Ok(out)
}

fn check_reading(r: &RawReading, last: u64, shown: &str, topic: &str) -> Result<()> {
    if r.v.iter().any(|x| !x.is_finite()) {
        bail!(
            "{shown}: byte {}: {topic} reading ({}, {}, {}) is not finite",
            r.offset,
            r.v[0],
            r.v[1],
            r.v[2]
        );
    }
    if r.t_us < last {
        bail!(
            "{shown}: byte {}: {topic} timestamp {} us is earlier than the one before ({last} us)",
            r.offset,
            r.t_us
        );
    }
    Ok(())
}

/// Offsets and scales of a calibration slot.
type OldCal = ([f64; 3], [f64; 3]);

/// `prefix`'s offsets and scales at the start of the log, where all six are logged and usable.
fn old_calibration(prefix: &str, raw: &Raw) -> Option<OldCal> {
    let get = |k: &str| raw.initial.get(&format!("{prefix}{k}")).map(|v| v.value());
    let off = [get("XOFF")?, get("YOFF")?, get("ZOFF")?];
    let scale = [get("XSCALE")?, get("YSCALE")?, get("ZSCALE")?];
    usable(&off, &scale).then_some((off, scale))
}

fn usable(off: &[f64; 3], scale: &[f64; 3]) -> bool {
    off.iter().chain(scale).all(|v| v.is_finite()) && scale.iter().all(|&s| s != 0.0)
}

/// `r = m / SCALE + OFF` per axis with the values in force at each reading.
fn undo(readings: &[RawReading], raw: &Raw, prefix: &str, mut cal: OldCal, shown: &str) -> Result<Vec<Sample>> {
    let keys = ["XOFF", "YOFF", "ZOFF", "XSCALE", "YSCALE", "ZSCALE"].map(|k| format!("{prefix}{k}"));
    let mut changes = raw.changes.iter().filter(|(_, k, _)| keys.contains(k)).peekable();
    let mut out = Vec::with_capacity(readings.len());
    let mut last = 0u64;
    for r in readings {
        check_reading(r, last, shown, "sensor_mag")?;
        last = r.t_us;
        while let Some((at, k, v)) = changes.next_if(|(at, _, _)| *at < r.offset) {
            let i = keys.iter().position(|x| x == k).expect("filtered on keys");
            let mut next = cal;
            if i < 3 {
                next.0[i] = v.value();
            } else {
                next.1[i - 3] = v.value();
            }
            if !usable(&next.0, &next.1) {
                bail!(
                    "{shown}: byte {at}: {k} = {} cannot be undone (not finite, or a zero scale)",
                    v.value()
                );
            }
            cal = next;
        }
        let (off, scale) = cal;
        out.push(Sample {
            time_s: r.t_us as f64 * 1e-6,
            raw: std::array::from_fn(|k| f64::from(r.v[k]) / scale[k] + off[k]),
            offset: r.offset,
        });
    }
    Ok(out)
}

/// The rotation PX4 applies to the sensor's calibrated field (see the module docs).
fn body_rotation(
    rot: Option<f64>,
    parameters: &BTreeMap<String, f64>,
    prefix: Option<&str>,
    raw: &Raw,
    notes: &mut Vec<String>,
) -> Option<Mat3> {
    let Some(rot) = rot else {
        notes.push(
            "The log has no CAL_MAGn_ROT for this sensor: its rotation into the body frame is unknown.".to_string(),
        );
        return None;
    };
    let p = prefix.unwrap_or_default();
    let level = euler_dcm(
        parameters.get("SENS_BOARD_X_OFF").copied().unwrap_or(0.0),
        parameters.get("SENS_BOARD_Y_OFF").copied().unwrap_or(0.0),
        parameters.get("SENS_BOARD_Z_OFF").copied().unwrap_or(0.0),
    );
    let rot = rot as i64;
    let sensor = if rot == -1 {
        let board = parameters.get("SENS_BOARD_ROT").copied().unwrap_or(0.0) as i64;
        let m = rotation_matrix(board);
        if m.is_none() {
            notes.push(format!(
                "SENS_BOARD_ROT = {board} is not a rotation this reader knows (PX4's enum Rotation, 0 to 47): the rotation into the body frame is unknown."
            ));
        }
        m
    } else if rot == ROTATION_CUSTOM {
        let angle = |k: &str| raw.initial.get(&format!("{p}{k}")).map(|v| v.value());
        match (angle("ROLL"), angle("PITCH"), angle("YAW")) {
            (Some(r), Some(pi), Some(y)) => Some(euler_dcm(r, pi, y)),
            _ => {
                notes.push(format!(
                    "{p}ROT = 100 (custom) without {p}ROLL, PITCH, YAW in the log: the rotation into the body frame is unknown."
                ));
                None
            }
        }
    } else {
        let m = rotation_matrix(rot);
        if m.is_none() {
            notes.push(format!(
                "{p}ROT = {rot} is not a rotation this reader knows (PX4's enum Rotation, 0 to 47, or 100): the rotation into the body frame is unknown."
            ));
        }
        m
    };
    sensor.map(|m| mat_mul(&level, &m))
}

/// A kept series as [`Series`], its times checked not to decrease; non-finite values dropped.
fn series_of<V: Copy, T>(
    points: &[(u64, V, u64)],
    shown: &str,
    topic: &str,
    f: impl Fn(V) -> T,
) -> Result<Option<Series<T>>>
where
    T: Finite,
{
    let mut out = Series {
        times: Vec::with_capacity(points.len()),
        values: Vec::with_capacity(points.len()),
    };
    let mut last = 0u64;
    for &(t, v, at) in points {
        if t < last {
            bail!("{shown}: byte {at}: {topic} timestamp {t} us is earlier than the one before ({last} us)");
        }
        last = t;
        let value = f(v);
        if value.finite() {
            out.times.push(t as f64 * 1e-6);
            out.values.push(value);
        }
    }
    Ok((!out.times.is_empty()).then_some(out))
}

/// Values whose every component is finite.
trait Finite {
    fn finite(&self) -> bool;
}

impl Finite for Fix {
    /// A fix without a position (NaN before the first one in some firmware) is still a fix:
    /// [`Fix::usable`] tells it apart.
    fn finite(&self) -> bool {
        true
    }
}

impl Finite for f64 {
    fn finite(&self) -> bool {
        self.is_finite()
    }
}

impl Finite for [f64; 4] {
    fn finite(&self) -> bool {
        self.iter().all(|x| x.is_finite())
    }
}

/// The fastest turn of the vehicle, degrees per second: the angle between attitudes at least
/// half a second apart over their time apart, at its largest.
fn peak_turn_rate(att: &Series<[f64; 4]>) -> f64 {
    let mut best: f64 = 0.0;
    let mut j = 0;
    for i in 0..att.times.len() {
        while j < att.times.len() && att.times[j] - att.times[i] < 0.5 {
            j += 1;
        }
        if j == att.times.len() {
            break;
        }
        let (a, b) = (att.values[i], att.values[j]);
        let dot = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]).abs();
        let na = a.iter().map(|x| x * x).sum::<f64>().sqrt();
        let nb = b.iter().map(|x| x * x).sum::<f64>().sqrt();
        if na > 0.0 && nb > 0.0 {
            let angle = 2.0 * (dot / (na * nb)).min(1.0).acos();
            best = best.max(angle.to_degrees() / (att.times[j] - att.times[i]));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotations_are_proper_and_match_px4s_names() {
        for (k, _) in ROTATIONS.iter().enumerate() {
            let m = rotation_matrix(k as i64).unwrap();
            let mtm = mat_mul(&m, &[0, 1, 2].map(|i| [0, 1, 2].map(|j| m[j][i])));
            for (i, row) in mtm.iter().enumerate() {
                for (j, x) in row.iter().enumerate() {
                    let want = if i == j { 1.0 } else { 0.0 };
                    assert!((x - want).abs() < 8.0 * f64::EPSILON, "rotation {k}: M M^T = {mtm:?}");
                }
            }
        }
        // ROTATION_YAW_90: the sensor's x axis points along the body's y (right).
        let m = rotation_matrix(2).unwrap();
        let x = [m[0][0], m[1][0], m[2][0]];
        assert!(
            (x[0]).abs() < 1e-15 && (x[1] - 1.0).abs() < 1e-15 && x[2].abs() < 1e-15,
            "{x:?}"
        );
        // ROTATION_ROLL_180: y and z flip.
        let m = rotation_matrix(8).unwrap();
        assert!((m[1][1] + 1.0).abs() < 1e-15 && (m[2][2] + 1.0).abs() < 1e-15);
        assert!(rotation_matrix(48).is_none() && rotation_matrix(-1).is_none());
    }

    #[test]
    fn what_is_kept_is_charged_against_the_memory_budget() {
        fn msg(out: &mut Vec<u8>, kind: u8, body: &[u8]) {
            out.extend_from_slice(&(body.len() as u16).to_le_bytes());
            out.push(kind);
            out.extend_from_slice(body);
        }
        let mut log = b"ULog\x01\x12\x35\x01".to_vec();
        log.extend_from_slice(&0u64.to_le_bytes());
        msg(
            &mut log,
            b'F',
            b"sensor_mag:uint64_t timestamp;float x;float y;float z;",
        );
        msg(&mut log, b'A', b"\x00\x00\x00sensor_mag");
        for t in 0..1000u64 {
            let mut d = vec![0, 0];
            d.extend_from_slice(&t.to_le_bytes());
            d.extend_from_slice(&[0; 12]);
            msg(&mut log, b'D', &d);
        }
        let budget = |limit| Budget {
            used: 0,
            limit: Some((limit, 2 * limit, "a test's limit")),
        };
        let raw = parse(&mut log.as_slice(), "t.ulg", budget(1 << 30)).unwrap();
        assert_eq!(raw.sensor_mag[&0].len(), 1000);
        // 100 readings fit in 100 * HELD_PER_READING bytes and a little; the 101st does not.
        let limit = 100 * HELD_PER_READING + HELD_PER_ENTRY * 6 + 64;
        let e = parse(&mut log.as_slice(), "t.ulg", budget(limit))
            .unwrap_err()
            .to_string();
        let at = 16 + 3 + 54 + 3 + 13 + 100 * 25;
        assert!(
            e.starts_with(&format!("t.ulg: byte {at}: the log holds more than fits in memory")),
            "{e}"
        );
    }

    #[test]
    fn versions_read_as_px4_writes_them() {
        assert_eq!(version_words(0x011001C0), "v1.16.1 (release candidate)");
        assert_eq!(version_words(0x010B0200), "v1.11.2 (development)");
        assert_eq!(version_words(0x010C03FF), "v1.12.3 (release)");
    }

    #[test]
    fn formats_parse_and_nest() {
        let (name, fields) = parse_format("a:uint64_t timestamp;b[2] bs;float[3] v;uint8_t[4] _padding0;").unwrap();
        assert_eq!(name, "a");
        assert_eq!(fields.len(), 4);
        let mut formats = HashMap::new();
        formats.insert(name, fields);
        formats.insert("b".to_string(), parse_format("b:uint16_t u;double d;").unwrap().1);
        let mut sizes = HashMap::new();
        let at = locate("a", "v", "float", &formats, &mut sizes).unwrap().unwrap();
        assert_eq!((at.offset, at.count), (8 + 2 * 10, 3));
        assert!(locate("a", "v", "double", &formats, &mut sizes).is_err());
        // A format that contains itself stops at the nesting bound.
        formats.insert("c".to_string(), parse_format("c:c self;float x;").unwrap().1);
        let e = locate("c", "x", "float", &formats, &mut sizes).unwrap_err();
        assert!(e.contains("nested deeper than 16"), "{e}");
        for bad in ["nocolon", ":float x;", "a:float;", "a:float[x] y;", "a:float[70000] y;"] {
            assert!(parse_format(bad).is_err(), "{bad}");
        }
    }
}
