//! A log of any format as the log commands take it: the readings of one magnetometer, cut to a
//! time window and a rate, with the times, attitudes, currents and throttles logged beside them
//! matched to each reading.
//!
//! The format is told by the file's first bytes (DataFlash `A3 95`, ULog `ULog`, a MAVLink frame
//! after a telemetry log's 8-byte time stamp), else by its extension, else it is a CSV log
//! ([`super::read`]); `--format` overrides. Flags that apply to one kind of log only (`--columns`
//! for CSV, `--compass` for flight logs) are refused on the other, naming the log's format.
//!
//! # Matching by time
//! A series logged beside the readings at its own rate (an attitude at 10 Hz, the battery at
//! 1 Hz) is matched to each reading by the nearest sample in time, taken when it lies within
//! [`max_gap`] of the reading: twice the series' median interval, and at least
//! [`MIN_GAP_S`]. A reading without such a sample has none (`None`), and the output counts
//! them.

use std::path::Path;

use anyhow::{Context, Result, bail};
use magcal_core::Vec3;
use magcal_core::aviation::{NavFrame, dcm_of_euler, dcm_of_quaternion, to_ned};
use magcal_core::small::Mat3;

use super::flight::{Fix, FlightLog, Format, InForce, Selection, Series};
use super::parameters::LogParameters;
use super::read::{self, Extra, RowFilter};
use crate::limits::show;
use crate::site::Units;

/// The least gap accepted between a reading and the sample matched to it, seconds.
pub const MIN_GAP_S: f64 = 0.05;

/// `--format`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum FormatArg {
    /// From the file's first bytes, then its extension.
    #[default]
    Auto,
    Csv,
    /// ArduPilot DataFlash (`.bin`).
    Dataflash,
    /// MAVLink telemetry (`.tlog`).
    Tlog,
    /// PX4 ULog (`.ulg`).
    Ulog,
}

/// `--time-unit`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum TimeUnit {
    #[default]
    S,
    Ms,
    Us,
}

impl TimeUnit {
    fn seconds(self) -> f64 {
        match self {
            Self::S => 1.0,
            Self::Ms => 1e-3,
            Self::Us => 1e-6,
        }
    }
}

/// `--attitude-frame`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum FrameArg {
    /// Body forward, right, down into north, east, down (ArduPilot, PX4, aviation).
    #[default]
    Ned,
    /// Body forward, left, up into east, north, up (ROS, motion capture).
    Enu,
}

impl From<FrameArg> for NavFrame {
    fn from(f: FrameArg) -> Self {
        match f {
            FrameArg::Ned => NavFrame::Ned,
            FrameArg::Enu => NavFrame::Enu,
        }
    }
}

/// How to read a log: the flags every log command shares.
#[derive(Debug, Clone, Default)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct LogArgs {
    /// The log's format (default: told by its first bytes, then its extension).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "auto"))]
    pub format: FormatArg,
    /// CSV: the three columns, by name or 1-based index: `mx,my,mz` or `4,5,6` (default: x, y, z
    /// with or without an m prefix, else the first three numeric columns).
    #[cfg_attr(feature = "clap", arg(long))]
    pub columns: Option<String>,
    /// CSV: drop rows with a non-finite or missing value, counting them (default: such a row is
    /// an error).
    #[cfg_attr(feature = "clap", arg(long))]
    pub skip_bad: bool,
    /// CSV: read only the rows whose COLUMN (a name or 1-based index) holds VALUE, compared as
    /// numbers when VALUE is one (`movement=1`), else as text; repeat for rows that meet every
    /// one. The rows left out are counted and said.
    #[cfg_attr(feature = "clap", arg(long = "where", value_name = "COLUMN=VALUE", value_parser = RowFilter::parse))]
    pub filter: Vec<RowFilter>,
    /// Flight logs: the magnetometer instance, numbered as the log numbers it (ArduPilot `MAG.I`
    /// and `COMPASS_OFS_*` = 0, `COMPASS_OFS2_*` = 1; PX4 `sensor_mag` instance and `CAL_MAGn`);
    /// default the lowest the log has.
    #[cfg_attr(feature = "clap", arg(long, value_name = "N"))]
    pub compass: Option<u8>,
    /// Only readings at or after this time, seconds on the log's clock (flight logs: time since
    /// boot; CSV: the `--time` column).
    #[cfg_attr(feature = "clap", arg(long, value_name = "SECONDS", allow_hyphen_values = true, value_parser = crate::limits::finite))]
    pub from: Option<f64>,
    /// Only readings at or before this time, seconds on the log's clock.
    #[cfg_attr(feature = "clap", arg(long, value_name = "SECONDS", allow_hyphen_values = true, value_parser = crate::limits::finite))]
    pub to: Option<f64>,
    /// At most this many readings per second, thinned evenly in time (a reading is kept when it
    /// lies at least 1/HZ after the last one kept).
    #[cfg_attr(feature = "clap", arg(long, value_name = "HZ", value_parser = crate::limits::finite))]
    pub rate: Option<f64>,
    /// CSV: the column of each reading's time, in order (a time earlier than the row before it is
    /// refused: windows, holds, `--from`/`--to` and `--rate` read the log in time order).
    #[cfg_attr(feature = "clap", arg(long, value_name = "COLUMN"))]
    pub time: Option<String>,
    /// CSV: the unit of the `--time` column.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "s", requires = "time"))]
    pub time_unit: TimeUnit,
    /// CSV: the columns of the attitude as Euler angles in degrees, `ROLL,PITCH,YAW`, in the
    /// convention of `--attitude-frame` (yaw, then pitch, then roll).
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "ROLL,PITCH,YAW", conflicts_with = "quaternion")
    )]
    pub euler: Option<String>,
    /// CSV: the columns of the attitude as a unit quaternion `W,X,Y,Z` (Hamilton) rotating body
    /// vectors into the navigation frame of `--attitude-frame`.
    #[cfg_attr(feature = "clap", arg(long, value_name = "W,X,Y,Z"))]
    pub quaternion: Option<String>,
    /// CSV: the frames of the attitude columns: `ned` (body forward, right, down into north,
    /// east, down: roll right-side-down, pitch nose-up, yaw clockwise from north) or `enu` (body
    /// forward, left, up into east, north, up: yaw counter-clockwise from east).
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "ned"))]
    pub attitude_frame: FrameArg,
    /// CSV: the column of the battery current, amperes (for `calibrate --motor current`).
    #[cfg_attr(feature = "clap", arg(long, value_name = "COLUMN"))]
    pub current: Option<String>,
    /// CSV: the column of the throttle, 0 to 1 (for `calibrate --motor throttle`).
    #[cfg_attr(feature = "clap", arg(long, value_name = "COLUMN"))]
    pub throttle: Option<String>,
    /// CSV: the columns of the vehicle's position, `LAT,LON,ALT` (degrees north and east, metres
    /// above mean sea level): the site of the World Magnetic Model's field, and the field along
    /// the track for a vector fit (a row with all three is a 3D fix).
    #[cfg_attr(feature = "clap", arg(long, value_name = "LAT,LON,ALT"))]
    pub position: Option<String>,
    /// CSV: the column of the positions' UTC time, seconds since 1970 (the date; else `--date`).
    #[cfg_attr(feature = "clap", arg(long, value_name = "COLUMN", requires = "position"))]
    pub utc: Option<String>,
    /// Flight logs: where the attitudes' heading comes from. `auto`: a moving-baseline GPS
    /// receiver's yaw where the log has one, else the autopilot's; `autopilot`: the autopilot's
    /// estimate (whose yaw used the compass being calibrated); `gps`: the receiver's yaw;
    /// `gsf`: ArduPilot's yaw from GPS velocities (`XKY0`; its spread is degrees). Roll and pitch
    /// are the autopilot's in every case.
    #[cfg_attr(feature = "clap", arg(long, value_enum, default_value = "auto"))]
    pub heading_from: HeadingFrom,
    /// Whether the command fits the motors (`calibrate --motor`): `--current` and `--throttle`
    /// mean nothing without it. Set by the command, not a flag.
    #[cfg_attr(feature = "clap", arg(skip))]
    pub motor: bool,
}

/// `--heading-from`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum HeadingFrom {
    /// A moving-baseline GPS yaw where the log has one, else the autopilot's.
    #[default]
    Auto,
    /// The autopilot's attitude estimate.
    Autopilot,
    /// A moving-baseline GPS receiver's yaw (DataFlash `GPS.Yaw`, MAVLink `GPS_RAW_INT.yaw`, ULog
    /// `heading`).
    Gps,
    /// ArduPilot's yaw from the Gaussian sum filter of GPS velocities (`XKY0.YC`).
    Gsf,
}

/// Where a log's readings came from, and what the reader and the cut did to them.
#[derive(Debug, Clone)]
pub struct Origin {
    pub format: Format,
    /// The messages or columns used, one phrase each.
    pub messages: Vec<String>,
    /// The readings' unit where the format fixes it.
    pub unit: Option<Units>,
    /// The readings' frame in words where the format says it.
    pub frame: Option<String>,
    /// The instance read, and the instances the log holds (flight logs).
    pub instance: Option<u8>,
    pub instances: Vec<u8>,
    /// The calibration the logged field carries (flight logs).
    pub calibration: Option<InForce>,
    /// The convention in which the log gives its attitudes, for what is said back about them.
    pub attitude_frame: NavFrame,
    /// Rotation of the readings' frame into the attitude's body frame, where known.
    pub to_body: Option<Mat3>,
    /// The time span of the log's readings before the cut, seconds.
    pub span: Option<[f64; 2]>,
    /// What the user should know, one sentence each: the reader's notes and the cut's.
    pub notes: Vec<String>,
    /// What a flight log says of its firmware's parameters (`log_parameters` of calibration.json).
    pub parameters: Option<LogParameters>,
    /// Where a flight log's attitudes' heading comes from, in words (`--heading-from`).
    pub heading_source: Option<String>,
    /// The independent heading reference that replaced the autopilot's yaw, by name (GPS yaw,
    /// GSF yaw); `None` where the heading is the autopilot's own.
    pub independent_heading: Option<String>,
}

impl Origin {
    fn csv(messages: Vec<String>, attitude_frame: NavFrame) -> Self {
        Self {
            format: Format::Csv,
            messages,
            unit: None,
            frame: None,
            instance: None,
            instances: Vec::new(),
            calibration: None,
            attitude_frame,
            to_body: None,
            span: None,
            notes: Vec::new(),
            parameters: None,
            heading_source: None,
            independent_heading: None,
        }
    }

    /// What a reading's position is in words: a CSV line, or a flight log's byte offset.
    pub fn position_name(&self) -> &'static str {
        match self.format {
            Format::Csv => "line",
            _ => "byte offset",
        }
    }
}

/// The readings of a log, what was skipped, and what was logged beside them.
#[derive(Debug, Clone)]
pub struct Log {
    /// The readings, in log order: the field before any calibration, in the log's units.
    pub readings: Vec<Vec3>,
    /// Each reading's position: its 1-based line in a CSV file, its message's byte offset in a
    /// flight log ([`Origin::position_name`]).
    pub lines: Vec<usize>,
    /// Lines skipped for a non-finite or missing value (CSV with `--skip-bad`), with the reason.
    pub skipped: Vec<(usize, String)>,
    /// Data rows left out by `--where` (CSV).
    pub filtered: usize,
    /// The names of the three columns read (`column 4` without a header; `x, y, z` for a flight
    /// log, whose messages [`Origin::messages`] names).
    pub columns: [String; 3],
    /// SHA-256 of the file's bytes as read (lower-case hex).
    pub sha256: String,
    /// The file's size in bytes as read.
    pub bytes: u64,
    pub origin: Origin,
    /// Each reading's time, seconds on the log's clock, where the log has times.
    pub times: Option<Vec<f64>>,
    /// Each reading's attitude (`C` body into navigation, NED convention), where the log has
    /// attitudes; `None` for a reading without one within the gap.
    pub attitudes: Option<Vec<Option<Mat3>>>,
    /// Each reading's battery current (A), where the log has it.
    pub currents: Option<Vec<Option<f64>>>,
    /// Each reading's throttle (0 to 1), where the log has it.
    pub throttles: Option<Vec<Option<f64>>>,
    /// The GPS receiver's fixes on the log's clock, where the log has them (every fix, not cut
    /// to the readings' window: the track's field is taken at the readings' times), and the
    /// message they come from.
    pub gps: Option<(Series<Fix>, String)>,
}

/// The entries of `items` where `keep` is true.
fn kept<T: Clone>(items: &[T], keep: &[bool]) -> Vec<T> {
    items
        .iter()
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|(x, _)| x.clone())
        .collect()
}

impl Log {
    /// A log of `readings` handed over in memory (a library caller's array), named `shown`: no
    /// times, attitudes or other series; each reading's position is its 1-based row, and its
    /// digest is that of the readings' little-endian bytes, `x, y, z` of each in turn.
    pub fn of_readings(readings: Vec<Vec3>, shown: &str) -> Self {
        let bytes: Vec<u8> = readings.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
        let origin = Origin::csv(vec![format!("{shown}: readings handed over in memory")], NavFrame::Ned);
        Self {
            lines: (1..=readings.len()).collect(),
            readings,
            skipped: Vec::new(),
            filtered: 0,
            columns: ["x", "y", "z"].map(String::from),
            sha256: crate::digest::sha256_hex(&bytes),
            bytes: bytes.len() as u64,
            origin,
            times: None,
            attitudes: None,
            currents: None,
            throttles: None,
            gps: None,
        }
    }

    /// Keeps the readings where `keep` is true, and what was logged beside them.
    pub fn keep(&mut self, keep: &[bool]) {
        self.readings = kept(&self.readings, keep);
        self.lines = kept(&self.lines, keep);
        if let Some(v) = &mut self.times {
            *v = kept(v, keep);
        }
        if let Some(v) = &mut self.attitudes {
            *v = kept(v, keep);
        }
        for v in [&mut self.currents, &mut self.throttles].into_iter().flatten() {
            *v = kept(v, keep);
        }
    }

    /// The readings that have an attitude.
    pub fn with_attitude(&self) -> usize {
        self.attitudes
            .as_ref()
            .map_or(0, |a| a.iter().filter(|c| c.is_some()).count())
    }
}

/// Reads the log at `path` as `args` say, holding `held_bytes_per_reading` per reading (see
/// [`read::stream`]).
///
/// # Errors
/// A bad log (the error names the file and the line, byte offset or message), a flag that does
/// not apply to the log's format, a window or rate that keeps no reading.
pub fn open(path: &Path, args: &LogArgs, held_bytes_per_reading: u64) -> Result<Log> {
    let format = format_of(path, args.format)?;
    let shown = path.display().to_string();
    check_flags(args, format).with_context(|| format!("{shown} is {} log", format.with_article()))?;
    let mut log = match format {
        Format::Csv => read_csv(path, args, held_bytes_per_reading)?,
        _ => {
            let selection = Selection { instance: args.compass };
            from_flight(reader(format)?(path, &selection)?, args.heading_from).with_context(|| shown.clone())?
        }
    };
    cut(&mut log, args).with_context(|| shown.clone())?;
    Ok(log)
}

/// A reader of a flight log format.
type Reader = fn(&Path, &Selection) -> Result<FlightLog>;

fn reader(format: Format) -> Result<Reader> {
    match format {
        Format::DataFlash => Ok(super::dataflash::read),
        Format::Tlog => Ok(super::tlog::read),
        Format::Ulog => Ok(super::ulog::read),
        Format::Csv => bail!("a CSV log has no flight log reader"),
    }
}

/// The format of `path`: asked for, else told by its first bytes (a regular file), else by its
/// extension.
pub fn format_of(path: &Path, asked: FormatArg) -> Result<Format> {
    match asked {
        FormatArg::Csv => return Ok(Format::Csv),
        FormatArg::Dataflash => return Ok(Format::DataFlash),
        FormatArg::Tlog => return Ok(Format::Tlog),
        FormatArg::Ulog => return Ok(Format::Ulog),
        FormatArg::Auto => {}
    }
    // Only a regular file is sniffed: the bytes read from a pipe would be lost to the reader.
    let mut head = [0u8; 16];
    let regular = std::fs::metadata(path).is_ok_and(|m| m.is_file());
    // The reader names a missing or unreadable file.
    let n = match regular.then(|| std::fs::File::open(path)) {
        Some(Ok(mut f)) => read_head(&mut f, &mut head),
        _ => 0,
    };
    if let Some(f) = format_of_bytes(&head[..n]) {
        return Ok(f);
    }
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    Ok(match ext.as_str() {
        "bin" => Format::DataFlash,
        "tlog" => Format::Tlog,
        "ulg" => Format::Ulog,
        _ => Format::Csv,
    })
}

/// Fills `head` as far as the file goes; read errors count as the end (the reader names them).
fn read_head(f: &mut impl std::io::Read, head: &mut [u8]) -> usize {
    let mut n = 0;
    while n < head.len() {
        match f.read(&mut head[n..]) {
            Ok(0) | Err(_) => break,
            Ok(k) => n += k,
        }
    }
    n
}

/// The format the first bytes of a file show: DataFlash's message header `A3 95` followed by the
/// `FMT` message id 128, ULog's magic `ULog 01 12 35`, or a MAVLink frame start (`FE` for v1, `FD`
/// for v2) after a telemetry log's 8-byte time stamp whose first byte is 0 (microseconds since
/// 1970 are below 2^56).
pub fn format_of_bytes(head: &[u8]) -> Option<Format> {
    if head.starts_with(&[0xa3, 0x95, 0x80]) {
        Some(Format::DataFlash)
    } else if head.starts_with(b"ULog\x01\x12\x35") {
        Some(Format::Ulog)
    } else if head.len() > 8 && head[0] == 0 && matches!(head[8], 0xfe | 0xfd) {
        Some(Format::Tlog)
    } else {
        None
    }
}

/// Refuses flags that do not apply to `format`.
fn check_flags(args: &LogArgs, format: Format) -> Result<()> {
    let csv_only = [
        ("--columns", args.columns.is_some()),
        ("--skip-bad", args.skip_bad),
        ("--where", !args.filter.is_empty()),
        ("--time", args.time.is_some()),
        ("--euler", args.euler.is_some()),
        ("--quaternion", args.quaternion.is_some()),
        ("--attitude-frame", args.attitude_frame != FrameArg::Ned),
        ("--current", args.current.is_some()),
        ("--throttle", args.throttle.is_some()),
        ("--position", args.position.is_some()),
        ("--utc", args.utc.is_some()),
    ];
    if format == Format::Csv {
        if args.attitude_frame != FrameArg::Ned && args.euler.is_none() && args.quaternion.is_none() {
            bail!(
                "--attitude-frame gives the frame of the attitude columns, and none is named: give --euler or --quaternion, or leave it out"
            );
        }
        for (flag, given) in [
            ("--current", args.current.is_some()),
            ("--throttle", args.throttle.is_some()),
        ] {
            if given && !args.motor {
                bail!(
                    "{flag} names a column read only for motor interference (calibrate --motor {}, or a calibration it made): give --motor, or leave it out",
                    &flag[2..]
                );
            }
        }
        if args.compass.is_some() {
            bail!("--compass applies to flight logs; a CSV log holds one magnetometer (choose it with --columns)");
        }
        if args.position.is_some() && args.time.is_none() {
            bail!(
                "--position needs the CSV log's times (the field along the track is taken at them): name their column with --time"
            );
        }
        if args.heading_from != HeadingFrom::Auto {
            bail!(
                "--heading-from applies to flight logs; a CSV log's attitude columns are its attitudes (--euler, --quaternion)"
            );
        }
        if args.time.is_none() && (args.from.is_some() || args.to.is_some() || args.rate.is_some()) {
            bail!("--from, --to and --rate need the CSV log's times: name their column with --time");
        }
    } else if let Some((flag, _)) = csv_only.iter().find(|(_, given)| *given) {
        bail!("{flag} applies to CSV logs; a flight log names its own messages");
    }
    for (flag, v) in [("--from", args.from), ("--to", args.to)] {
        if let Some(v) = v
            && !v.is_finite()
        {
            bail!("{flag} {}: must be a finite time in seconds", show(v));
        }
    }
    if let (Some(a), Some(b)) = (args.from, args.to)
        && a >= b
    {
        bail!(
            "--from {} --to {}: the window is empty (--from must be before --to)",
            show(a),
            show(b)
        );
    }
    if let Some(r) = args.rate
        && !(r.is_finite() && r > 0.0)
    {
        bail!("--rate {}: must be a positive number of readings per second", show(r));
    }
    Ok(())
}

/// A comma-separated list of `n` columns for `flag`.
fn column_list<'a>(flag: &'a str, value: &'a str, n: usize) -> Result<Vec<Extra<'a>>> {
    let parts: Vec<&str> = value.split(',').map(str::trim).collect();
    if parts.len() != n || parts.iter().any(|p| p.is_empty()) {
        bail!(
            "{flag} {}: give {n} columns, names or 1-based indices, separated by commas",
            read::excerpt(value.as_bytes())
        );
    }
    Ok(parts.into_iter().map(|column| Extra { flag, column }).collect())
}

/// What a CSV log carries beside the field, as asked.
struct CsvExtras<'a> {
    extras: Vec<Extra<'a>>,
    time: Option<usize>,
    euler: Option<usize>,
    quaternion: Option<usize>,
    current: Option<usize>,
    throttle: Option<usize>,
    position: Option<usize>,
    utc: Option<usize>,
}

impl<'a> CsvExtras<'a> {
    /// Appends the row's position (values `v`, time `t`) to `fixes` where it has all three
    /// values and a time after the last fix's: a 3D fix on the row's time (the track's field is
    /// taken at the readings' times: a CSV with positions needs `--time`).
    fn push_fix(&self, fixes: &mut Series<Fix>, t: f64, v: &[Option<f64>]) {
        let Some(at) = self.position else {
            return;
        };
        if let (Some(lat), Some(lon), Some(alt)) = (v[at], v[at + 1], v[at + 2])
            && fixes.times.last().is_none_or(|last| *last < t)
        {
            fixes.times.push(t);
            fixes.values.push(Fix {
                lat_deg: lat,
                lon_deg: lon,
                alt_m: alt,
                fix_type: 3,
                utc_s: self.utc.and_then(|u| v[u]),
            });
        }
    }
    fn new(args: &'a LogArgs) -> Result<Self> {
        let mut extras = Vec::new();
        // Where each asked-for list starts among the extras.
        let mut add = |flag: &'a str, value: &'a Option<String>, n: usize| -> Result<Option<usize>> {
            let Some(value) = value else {
                return Ok(None);
            };
            let at = extras.len();
            extras.extend(column_list(flag, value, n)?);
            Ok(Some(at))
        };
        let time = add("--time", &args.time, 1)?;
        let euler = add("--euler", &args.euler, 3)?;
        let quaternion = add("--quaternion", &args.quaternion, 4)?;
        let current = add("--current", &args.current, 1)?;
        let throttle = add("--throttle", &args.throttle, 1)?;
        let position = add("--position", &args.position, 3)?;
        let utc = add("--utc", &args.utc, 1)?;
        Ok(Self {
            extras,
            time,
            euler,
            quaternion,
            current,
            throttle,
            position,
            utc,
        })
    }

    /// The attitude flag whose columns hold a value in some but not all of them in the row's
    /// values `v` (what `--skip-bad` drops, as it drops a missing value of the field).
    fn partly_missing(&self, v: &[Option<f64>]) -> Option<&'static str> {
        let partly = |at: usize, n: usize| {
            let present = v[at..at + n].iter().filter(|x| x.is_some()).count();
            present != 0 && present != n
        };
        match (self.euler, self.quaternion) {
            (Some(at), _) if partly(at, 3) => Some("--euler"),
            (_, Some(at)) if partly(at, 4) => Some("--quaternion"),
            _ => None,
        }
    }

    /// The attitude of a row's values (`C`, NED convention), `None` where every value of it is
    /// missing (empty or not finite: an attitude the capture lost); some missing and some not,
    /// or a quaternion that is not of unit norm, is an error naming the line.
    fn attitude(&self, v: &[Option<f64>], frame: NavFrame, shown: &str, line: usize) -> Result<Option<Mat3>> {
        if let Some(at) = self.euler {
            let Some([r, p, y]) = whole::<3>(&v[at..], "--euler", shown, line)? else {
                return Ok(None);
            };
            let c = dcm_of_euler(r.to_radians(), p.to_radians(), y.to_radians());
            return Ok(Some(to_ned(&c, frame)));
        }
        let Some(at) = self.quaternion else {
            return Ok(None);
        };
        let Some(q) = whole::<4>(&v[at..], "--quaternion", shown, line)? else {
            return Ok(None);
        };
        match dcm_of_quaternion(q) {
            Some(c) => Ok(Some(to_ned(&c, frame))),
            None => bail!(
                "{shown}: line {line}: --quaternion {q:?} has norm {:.6}, not 1: are these the quaternion's columns?",
                q.iter().map(|x| x * x).sum::<f64>().sqrt()
            ),
        }
    }
}

/// The first `N` values when all are present, `None` when none is; an error naming `flag` and
/// the line when some are and some are not.
fn whole<const N: usize>(v: &[Option<f64>], flag: &str, shown: &str, line: usize) -> Result<Option<[f64; N]>> {
    let present = v[..N].iter().filter(|x| x.is_some()).count();
    if present == 0 || present == N {
        return Ok(values(v));
    }
    bail!(
        "{shown}: line {line}: {flag} has a value in {present} of its {N} columns (the others empty or not finite): an attitude needs all of them, or none where it was lost"
    )
}

/// The first `N` values, when all are present.
fn values<const N: usize>(v: &[Option<f64>]) -> Option<[f64; N]> {
    let mut out = [0.0; N];
    for (o, x) in out.iter_mut().zip(v) {
        *o = (*x)?;
    }
    Some(out)
}

fn read_csv(path: &Path, args: &LogArgs, held: u64) -> Result<Log> {
    let shown = path.display().to_string();
    let x = CsvExtras::new(args)?;
    let frame = NavFrame::from(args.attitude_frame);
    let (mut readings, mut lines) = (Vec::new(), Vec::new());
    let mut times = x.time.map(|_| Vec::new());
    let mut attitudes = (x.euler.is_some() || x.quaternion.is_some()).then(Vec::new);
    let mut currents = x.current.map(|_| Vec::new());
    let mut throttles = x.throttle.map(|_| Vec::new());
    let mut fixes: Option<Series<Fix>> = x.position.map(|_| Series::default());
    let mut missing_time = None;
    let mut previous: Option<(usize, f64)> = None;
    // Rows dropped here by --skip-bad: an attitude with some of its values missing.
    let mut dropped: Vec<(usize, String)> = Vec::new();
    let s = read::stream_with(
        path,
        args.columns.as_deref(),
        &x.extras,
        &args.filter,
        args.skip_bad,
        held,
        |line, r, v| {
            if args.skip_bad
                && let Some(flag) = x.partly_missing(v)
            {
                dropped.push((line, format!("{flag} has a value missing (--skip-bad)")));
                return Ok(());
            }
            if let (Some(t), Some(at)) = (&mut times, x.time) {
                match v[at] {
                    Some(s) => {
                        let now = s * args.time_unit.seconds();
                        if let Some((before, then)) = previous.filter(|&(_, then)| now < then) {
                            bail!(
                                "{shown}: line {line}: time {now} s is earlier than line {before}'s {then} s: the --time column must not go backwards (holds, --from/--to and --rate read the log in time order; sort or split the log)"
                            );
                        }
                        previous = Some((line, now));
                        t.push(now);
                    }
                    None => {
                        missing_time.get_or_insert(line);
                        t.push(f64::NAN);
                    }
                }
            }
            if let Some(a) = &mut attitudes {
                a.push(x.attitude(v, frame, &shown, line)?);
            }
            for (series, at) in [(&mut currents, x.current), (&mut throttles, x.throttle)] {
                if let (Some(s), Some(at)) = (series, at) {
                    s.push(v[at]);
                }
            }
            if let (Some(g), Some(t)) = (&mut fixes, times.as_ref().and_then(|t| t.last())) {
                x.push_fix(g, *t, v);
            }
            readings.push(r);
            lines.push(line);
            Ok(())
        },
    )?;
    if let Some(line) = missing_time {
        bail!("{shown}: line {line}: no time in the --time column");
    }
    let messages = csv_messages(args, &s.columns);
    let mut origin = Origin::csv(messages, frame);
    origin.span = times.as_deref().and_then(span);
    if let Some(note) = filter_note(&args.filter, s.filtered) {
        origin.notes.push(note);
    }
    let mut skipped = s.skipped;
    if !dropped.is_empty() {
        skipped.extend(dropped);
        skipped.sort_by_key(|(line, _)| *line);
    }
    Ok(Log {
        readings,
        lines,
        skipped,
        filtered: s.filtered,
        columns: s.columns,
        sha256: s.sha256,
        bytes: s.bytes,
        origin,
        times,
        attitudes,
        currents,
        throttles,
        gps: fixes
            .filter(|g| !g.times.is_empty())
            .map(|g| (g, format!("columns {}", args.position.as_deref().unwrap_or("")))),
    })
}

/// What a CSV log's reading used, one phrase each: the columns, then each flag's.
fn csv_messages(args: &LogArgs, columns: &[String]) -> Vec<String> {
    let mut messages = vec![format!("columns {}", columns.join(", "))];
    for (what, list) in [
        ("time", &args.time),
        ("attitude (Euler, degrees)", &args.euler),
        ("attitude (quaternion)", &args.quaternion),
        ("current", &args.current),
        ("throttle", &args.throttle),
        ("position", &args.position),
        ("UTC", &args.utc),
    ] {
        if let Some(c) = list {
            messages.push(format!("{what}: {c}"));
        }
    }
    messages
}

/// What `--where` left out, in words: `None` without a filter.
pub fn filter_note(filters: &[RowFilter], filtered: usize) -> Option<String> {
    if filters.is_empty() {
        return None;
    }
    let shown: Vec<String> = filters.iter().map(|f| format!("--where {}", f.shown())).collect();
    Some(format!("{}: {filtered} rows left out", shown.join(" ")))
}

/// The first and last of `times`.
fn span(times: &[f64]) -> Option<[f64; 2]> {
    Some([*times.first()?, *times.last()?])
}

/// The largest gap between a reading and the sample of `times` matched to it: twice the median
/// interval of `times`, at least [`MIN_GAP_S`].
pub fn max_gap(times: &[f64]) -> f64 {
    let mut d: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).filter(|d| *d > 0.0).collect();
    if d.is_empty() {
        return MIN_GAP_S;
    }
    let mid = d.len() / 2;
    let (_, median, _) = d.select_nth_unstable_by(mid, f64::total_cmp);
    (2.0 * *median).max(MIN_GAP_S)
}

/// The heading (degrees) of `series` at each of `times`: linear in time between the samples
/// around it (the shorter way round the circle) where both lie within [`max_gap`] of it, else the
/// nearest within it, else none. A receiver's yaw at 5 Hz is 0.2 s apart: a vehicle turning at 5
/// degrees per second turns 1 degree between its samples, which the nearest one would leave as
/// an error of up to half a degree.
fn interpolate_headings(times: &[f64], series: &Series<f64>) -> Vec<Option<f64>> {
    let gap = max_gap(&series.times);
    let (t, v) = (&series.times, &series.values);
    let nearest = match_series(times, series);
    times
        .iter()
        .zip(nearest)
        .map(|(&at, near)| {
            let i = t.partition_point(|&s| s <= at);
            if i == 0 || i == t.len() {
                return near;
            }
            let (t0, t1) = (t[i - 1], t[i]);
            if at - t0 > gap || t1 - at > gap || t1 <= t0 {
                return near;
            }
            let turn = (v[i] - v[i - 1] + 180.0).rem_euclid(360.0) - 180.0;
            Some((v[i - 1] + turn * (at - t0) / (t1 - t0)).rem_euclid(360.0))
        })
        .collect()
}

/// The sample of `series` nearest in time to each of `times`, within [`max_gap`].
pub fn match_series<T: Copy>(times: &[f64], series: &Series<T>) -> Vec<Option<T>> {
    let gap = max_gap(&series.times);
    let t = &series.times;
    times
        .iter()
        .map(|&at| {
            let i = t.partition_point(|&s| s < at);
            let near = [i.checked_sub(1), (i < t.len()).then_some(i)]
                .into_iter()
                .flatten()
                .min_by(|&a, &b| (t[a] - at).abs().total_cmp(&(t[b] - at).abs()))?;
            ((t[near] - at).abs() <= gap).then(|| series.values[near])
        })
        .collect()
}

/// The heading reference `--heading-from` asks for among what `f` holds: its series (degrees)
/// and words; `None` for the autopilot's own.
///
/// # Errors
/// `gps` or `gsf` asked for and the log has none.
fn heading_reference(f: &FlightLog, from: HeadingFrom) -> Result<Option<&(Series<f64>, String)>> {
    Ok(match from {
        HeadingFrom::Autopilot => None,
        HeadingFrom::Auto => f.gps_yaw.as_ref(),
        HeadingFrom::Gps => Some(f.gps_yaw.as_ref().ok_or_else(|| {
            anyhow::anyhow!(
                "--heading-from gps: the log has no GPS yaw (a moving-baseline receiver's: DataFlash GPS.Yaw, MAVLink GPS_RAW_INT.yaw, ULog heading)"
            )
        })?),
        HeadingFrom::Gsf => Some(f.gsf_yaw.as_ref().ok_or_else(|| {
            anyhow::anyhow!("--heading-from gsf: the log has no GSF yaw (ArduPilot's XKY0, logged by EKF3)")
        })?),
    })
}

/// Each reading's attitude: the autopilot's, its heading replaced by `reference` (degrees) where
/// given (a reading without a reference heading near it in time has none); and where the
/// heading came from, in words.
fn attitudes_of(
    f: &FlightLog,
    times: &[f64],
    reference: Option<&(Series<f64>, String)>,
) -> (Option<Vec<Option<Mat3>>>, Option<String>) {
    let Some(a) = f.attitude.as_ref() else {
        return (None, None);
    };
    let own: Vec<Option<Mat3>> = match_series(times, a)
        .into_iter()
        .map(|q| q.and_then(dcm_of_quaternion))
        .collect();
    let Some((yaw, name)) = reference else {
        let others: Vec<&str> = [f.gps_yaw.as_ref(), f.gsf_yaw.as_ref()]
            .into_iter()
            .flatten()
            .map(|(_, n)| n.as_str())
            .collect();
        let words = format!(
            "the autopilot's attitude estimate, whose heading used the compass being calibrated: a vector calibration's offsets and that heading share an error{}",
            if others.is_empty() {
                " (the log has no independent heading)".to_string()
            } else {
                format!(" (the log also has {}: --heading-from)", others.join(", "))
            }
        );
        return (Some(own), Some(words));
    };
    let matched = interpolate_headings(times, yaw);
    let rebuilt: Vec<Option<Mat3>> = own
        .iter()
        .zip(&matched)
        .map(|(c, y)| {
            let (c, y) = ((*c)?, (*y)?);
            let [roll, pitch, _] = magcal_core::aviation::euler_of_dcm(&c);
            Some(magcal_core::aviation::dcm_of_euler(roll, pitch, y.to_radians()))
        })
        .collect();
    let with = rebuilt.iter().filter(|c| c.is_some()).count();
    let words = format!(
        "roll and pitch the autopilot's, heading from {name}, independent of the compass ({with} of {} readings have one)",
        times.len()
    );
    (Some(rebuilt), Some(words))
}

fn from_flight(f: FlightLog, heading_from: HeadingFrom) -> Result<Log> {
    let times: Vec<f64> = f.samples.iter().map(|s| s.time_s).collect();
    let reference = heading_reference(&f, heading_from)?;
    let (attitudes, heading_source) = attitudes_of(&f, &times, reference);
    let independent_heading = reference.map(|(_, name)| name.clone());
    let currents = f.current.as_ref().map(|c| match_series(&times, c));
    let throttles = f.throttle.as_ref().map(|c| match_series(&times, c));
    let gps_message = match f.format {
        Format::DataFlash => "GPS",
        Format::Tlog => "GPS_RAW_INT",
        _ if f.messages.iter().any(|m| m.starts_with("vehicle_gps_position")) => "vehicle_gps_position",
        _ => "sensor_gps",
    };
    let gps = f.gps.map(|g| (g, gps_message.to_string()));
    let origin = Origin {
        format: f.format,
        messages: f.messages,
        unit: Some(f.unit),
        frame: Some(f.frame),
        instance: Some(f.instance),
        instances: f.instances,
        calibration: Some(f.calibration),
        attitude_frame: NavFrame::Ned,
        to_body: f.to_body,
        span: span(&times),
        notes: f.notes,
        parameters: f.parameters,
        heading_source,
        independent_heading,
    };
    Ok(Log {
        readings: f.samples.iter().map(|s| s.raw).collect(),
        lines: f.samples.iter().map(|s| s.offset as usize).collect(),
        skipped: Vec::new(),
        filtered: 0,
        columns: ["x", "y", "z"].map(String::from),
        sha256: f.sha256,
        bytes: f.bytes,
        origin,
        times: Some(times),
        attitudes,
        currents,
        throttles,
        gps,
    })
}

/// Cuts `log` to the window `--from`..`--to` and thins it to `--rate`, noting what went.
fn cut(log: &mut Log, args: &LogArgs) -> Result<()> {
    let Some(times) = log.times.clone().filter(|t| !t.is_empty()) else {
        // No readings at all: nothing to cut, and what follows says why there are none.
        return Ok(());
    };
    let before = times.len();
    let (from, to) = (args.from.unwrap_or(f64::NEG_INFINITY), args.to.unwrap_or(f64::INFINITY));
    let mut keep: Vec<bool> = times.iter().map(|t| (from..=to).contains(t)).collect();
    let in_window = keep.iter().filter(|k| **k).count();
    if in_window == 0 {
        let [a, b] = log.origin.span.unwrap_or([f64::NAN; 2]);
        bail!(
            "no reading between --from {} and --to {} s: the log's readings span {a:.3} to {b:.3} s",
            show(from),
            show(to)
        );
    }
    if args.from.is_some() || args.to.is_some() {
        let bounds: Vec<String> = [("from", args.from), ("to", args.to)]
            .iter()
            .filter_map(|(w, v)| v.map(|v| format!("{w} {} s", show(v))))
            .collect();
        log.origin
            .notes
            .push(format!("window {}: {in_window} of {before} readings", bounds.join(" ")));
    }
    if let Some(rate) = args.rate {
        if let Some(w) = times.windows(2).position(|w| w[1] < w[0]) {
            bail!(
                "--rate {}: the log's times go back at reading {} ({} s after {} s); thinning needs times in order",
                show(rate),
                w + 2,
                show(times[w + 1]),
                show(times[w])
            );
        }
        let step = 1.0 / rate;
        let mut last = f64::NEG_INFINITY;
        for (k, &t) in keep.iter_mut().zip(&times) {
            // A relative allowance, so that readings logged exactly at 1/rate are all kept.
            if *k && t >= last + step * (1.0 - 1e-9) {
                last = t;
            } else {
                *k = false;
            }
        }
        let thinned = keep.iter().filter(|k| **k).count();
        log.origin.notes.push(format!(
            "rate at most {rate} Hz: {thinned} of {in_window} readings kept"
        ));
    }
    if keep.iter().any(|k| !k) {
        log.keep(&keep);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn series_are_matched_to_the_nearest_sample_within_twice_their_interval() {
        let series = Series {
            times: vec![0.0, 0.1, 0.2, 0.3, 1.0],
            values: vec![0, 1, 2, 3, 4],
        };
        // Median interval 0.1: the gap is 0.2.
        assert!((max_gap(&series.times) - 0.2).abs() < 1e-12);
        let got = match_series(&[-0.3, -0.1, 0.04, 0.06, 0.29, 0.55, 0.85, 1.19, 1.21], &series);
        assert_eq!(
            got,
            [None, Some(0), Some(0), Some(1), Some(3), None, Some(4), Some(4), None]
        );
        assert_eq!(max_gap(&[1.0]), MIN_GAP_S);
    }

    #[test]
    fn formats_are_told_by_their_first_bytes() {
        assert_eq!(format_of_bytes(&[0xa3, 0x95, 0x80, 0x59]), Some(Format::DataFlash));
        assert_eq!(format_of_bytes(b"ULog\x01\x12\x35\x01"), Some(Format::Ulog));
        let mut tlog = [0u8; 12];
        tlog[1..8].copy_from_slice(&[5, 0x8c, 1, 2, 3, 4, 5]);
        tlog[8] = 0xfd;
        assert_eq!(format_of_bytes(&tlog), Some(Format::Tlog));
        assert_eq!(format_of_bytes(b"x,y,z\n1,2,3\n"), None);
        assert_eq!(format_of_bytes(b""), None);
    }
}
