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

mod parse;
#[cfg(test)]
use parse::parse_format;
use parse::{Budget, locate, parse};

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

mod assemble;
use assemble::assemble;

#[cfg(test)]
mod tests;
