//! What a reader of an autopilot's log hands over: the raw magnetometer readings of one instance
//! with their times, and the series a log carries beside them (attitude, battery current,
//! throttle). The readers ([`super::dataflash`], [`super::tlog`], [`super::ulog`]) fill a
//! [`FlightLog`]; the log layer ([`super::source`]) cuts it to a time window and a rate, matches
//! the series to the readings by time and hands the commands a [`super::source::Log`].
//!
//! # Frames
//! - A reading is the field *before* any calibration, in [`FlightLog::unit`], in the frame
//!   [`FlightLog::frame`] names: ArduPilot logs the field after its calibration in force, in the
//!   body frame, and its reader undoes that calibration at each sample; PX4 logs `sensor_mag` in
//!   the sensor frame (raw from firmware 1.12 on).
//! - An attitude is a unit quaternion `[w, x, y, z]` rotating vectors of the vehicle's body frame
//!   (forward, right, down) into the local navigation frame (north, east, down): the autopilots'
//!   own convention, as ArduPilot's `ATT` (roll, pitch, yaw in degrees, yaw clockwise from north)
//!   and PX4's `vehicle_attitude.q` give it.
//! - [`FlightLog::to_body`] rotates a reading's frame into that body frame, where known.

use magcal_core::Vec3;
use magcal_core::small::Mat3;

use super::parameters::LogParameters;
use crate::site::Units;

/// The formats `magcal` reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Text, one reading per row ([`super::read`]).
    Csv,
    /// ArduPilot DataFlash (`.bin`).
    DataFlash,
    /// MAVLink telemetry (`.tlog`).
    Tlog,
    /// PX4 ULog (`.ulg`).
    Ulog,
}

impl Format {
    /// The name shown in outputs and recorded in `calibration.json`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Csv => "CSV",
            Self::DataFlash => "ArduPilot DataFlash",
            Self::Tlog => "MAVLink telemetry",
            Self::Ulog => "PX4 ULog",
        }
    }

    /// The name with its indefinite article: `a CSV`, `an ArduPilot DataFlash`.
    pub fn with_article(self) -> String {
        let name = self.name();
        let article = if name.starts_with(['A', 'E', 'I', 'O', 'U']) {
            "an"
        } else {
            "a"
        };
        format!("{article} {name}")
    }
}

/// What the caller asks a reader for.
#[derive(Debug, Clone, Default)]
pub struct Selection {
    /// The magnetometer instance (`--compass N`), numbered as the log numbers it: ArduPilot's
    /// `MAG.I` (0 for `MAG`, 1 for `MAG2`, 2 for `MAG3` in older logs; parameters `COMPASS_OFS_*`,
    /// `COMPASS_OFS2_*`, `COMPASS_OFS3_*`), MAVLink's `RAW_IMU` (0), `SCALED_IMU2` (1),
    /// `SCALED_IMU3` (2), PX4's `sensor_mag` multi-instance (`CAL_MAG0_*`, ...). `None`: the
    /// lowest instance the log has.
    pub instance: Option<u8>,
}

/// One magnetometer reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Seconds on the log's clock (ArduPilot's and PX4's time since boot).
    pub time_s: f64,
    /// The field before any calibration, in [`FlightLog::unit`], in [`FlightLog::frame`].
    pub raw: Vec3,
    /// The byte offset of the message in the file, so that a reading can be found again.
    pub offset: u64,
}

/// A series logged beside the readings, at its own times.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Series<T> {
    /// Seconds on the log's clock, not decreasing.
    pub times: Vec<f64>,
    /// One value per time.
    pub values: Vec<T>,
}

/// A position fix of the vehicle's GPS receiver (the default: no fix).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Fix {
    /// Latitude, degrees north.
    pub lat_deg: f64,
    /// Longitude, degrees east.
    pub lon_deg: f64,
    /// Altitude above mean sea level, metres. The WMM takes the height above the ellipsoid,
    /// which differs by the geoid's undulation (at most about 100 m; the field's vertical
    /// gradient is about 0.025 nT/m, so at most 2.5 nT, below a compass's noise).
    pub alt_m: f64,
    /// The fix type as every autopilot numbers it (MAVLink `GPS_FIX_TYPE`): 0 or 1 no fix, 2 a
    /// 2D fix, 3 a 3D fix, 4 DGPS, 5 RTK float, 6 RTK fixed.
    pub fix_type: u8,
    /// UTC of the fix, seconds since 1970, where the receiver gave the time.
    pub utc_s: Option<f64>,
}

/// The fix type a position must have to be used: a 3D fix.
pub const MIN_FIX_TYPE: u8 = 3;

impl Fix {
    /// A fix of at least [`MIN_FIX_TYPE`] with a position on the globe (receivers log zeros or
    /// NaN before their first fix).
    pub fn usable(&self) -> bool {
        self.fix_type >= MIN_FIX_TYPE
            && self.lat_deg.is_finite()
            && self.lon_deg.is_finite()
            && self.alt_m.is_finite()
            && self.lat_deg.abs() <= 90.0
            && self.lon_deg.abs() <= 360.0
            && !(self.lat_deg == 0.0 && self.lon_deg == 0.0)
    }
}

/// GPS week 0 began at 1980-01-06 00:00 UTC: 315,964,800 s after 1970.
pub const GPS_EPOCH_UNIX_S: f64 = 315_964_800.0;

/// UTC seconds since 1970 of a GPS week and milliseconds of the week (ArduPilot's `GWk`, `GMS`);
/// `None` for week 0 (no time yet). GPS time runs ahead of UTC by the leap seconds since 1980
/// (18 from 2017 on): they are subtracted, as the date is what is wanted and a second does not
/// move it.
pub fn utc_of_gps_week(week: f64, ms: f64) -> Option<f64> {
    (week.is_finite() && ms.is_finite() && week > 0.0).then_some(GPS_EPOCH_UNIX_S + week * 604_800.0 + ms * 1e-3 - 18.0)
}

/// The calibration the logged field carries, and what the reader did about it.
#[derive(Debug, Clone, PartialEq)]
pub enum InForce {
    /// The log holds raw readings (PX4 `sensor_mag` from firmware 1.12 on).
    Raw,
    /// The log holds calibrated readings and the reader undid the calibration in force at each
    /// sample; the words say with what (parameters, and how often they changed).
    Undone(String),
    /// The log holds readings after a calibration the reader cannot undo; the words say which
    /// (PX4 `sensor_mag` before firmware 1.12). A fit calibrates the calibrated sensor.
    Calibrated(String),
}

/// A flight log's readings of one magnetometer and what was logged beside them.
#[derive(Debug, Clone)]
pub struct FlightLog {
    pub format: Format,
    /// The messages and fields used, for the output: e.g. `MAG (I = 0): MagX, MagY, MagZ`,
    /// `PARM: COMPASS_OFS_*, COMPASS_DIA_*, COMPASS_ODI_*, COMPASS_SCALE`, `ATT: Roll, Pitch, Yaw`.
    pub messages: Vec<String>,
    /// The readings' unit: mGauss for ArduPilot and MAVLink, Gauss for PX4.
    pub unit: Units,
    /// The readings' frame in words: `body (forward, right, down)` or `sensor`.
    pub frame: String,
    /// The magnetometer instances the log holds, ascending.
    pub instances: Vec<u8>,
    /// The instance read.
    pub instance: u8,
    /// The readings, in log order.
    pub samples: Vec<Sample>,
    /// The vehicle's attitude where the log has it (see the module docs for its sense).
    pub attitude: Option<Series<[f64; 4]>>,
    /// Battery current, amperes, where the log has it.
    pub current: Option<Series<f64>>,
    /// Throttle, 0 to 1, where the log has it.
    pub throttle: Option<Series<f64>>,
    /// The GPS receiver's fixes (the first receiver), where the log has them; every fix as
    /// logged, those without a position included ([`Fix::usable`] tells them apart).
    pub gps: Option<Series<Fix>>,
    /// A heading that does not come from the compass, degrees clockwise from north, where the log
    /// has one: a moving-baseline GPS receiver's yaw (DataFlash `GPS.Yaw`, MAVLink
    /// `GPS_RAW_INT.yaw`, ULog `heading`), with the message it comes from.
    pub gps_yaw: Option<(Series<f64>, String)>,
    /// ArduPilot's yaw from the Gaussian sum filter of GPS velocities (`XKY0.YC`, core 0): an
    /// estimate without the compass, degrees, where the log has it.
    pub gsf_yaw: Option<(Series<f64>, String)>,
    /// Rotation of [`Self::frame`] into the body frame of [`Self::attitude`], where known.
    pub to_body: Option<Mat3>,
    pub calibration: InForce,
    /// What the user should know about the log, one sentence each: a rate too low to calibrate,
    /// parameters that changed, messages that were skipped and why.
    pub notes: Vec<String>,
    /// What the log says of its firmware's parameters, for `export`, where it says anything.
    pub parameters: Option<LogParameters>,
    /// SHA-256 of the file's bytes (lower-case hex).
    pub sha256: String,
    /// The file's size in bytes.
    pub bytes: u64,
}
