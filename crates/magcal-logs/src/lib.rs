//! Magnetometer logs for magcal: the readings of one magnetometer out of a CSV file, an ArduPilot
//! DataFlash log (`.bin`), a MAVLink telemetry log (`.tlog`) or a PX4 ULog (`.ulg`), with the
//! times, attitudes, currents, throttles and GPS fixes logged beside them; the calibration file
//! magcal writes (`calibration.json`); and its exports to autopilots and tools (ArduPilot and PX4
//! parameters, MotionCal, Magneto, a C header).
//!
//! The math (the fit, its statistics and verdict, the designs) is `magcal-core`'s; this crate
//! reads and writes files and knows no command line (the `clap` feature derives the option types
//! as the `magcal` command's flags).
//!
//! - [`source::open`]: a log of any format, told by its first bytes, cut to a window and a rate
//!   ([`source::LogArgs`], whose `Default` is the command line's defaults), as a [`source::Log`].
//! - [`read`]: the CSV reader (separators and decimal commas sniffed, columns by name or index,
//!   rows filtered, every read bounded); [`dataflash`], [`tlog`] and [`ulog`]: the flight logs,
//!   handed over as a [`flight::FlightLog`] with what they say of their firmware's parameters
//!   ([`parameters`]) and of where and when they were flown ([`gps`]).
//! - [`calibration`]: `calibration.json`, written and read back (sealed by its digest).
//! - [`export`]: a calibration as an autopilot's parameters or a tool's input.
//! - [`site`]: sites, dates and units; [`limits`]: reading untrusted input within bounds;
//!   [`text`]: numbers written for a person (messages, sentences, tables).
//!
//! Every error names the file and, where it has one, the line, byte offset or message.
//!
//! # Example
//! A log of a sensor turned through every direction of a 48 uT field with an offset, read and
//! calibrated:
//! ```
//! use magcal_core::log_fit::{self, FitModel};
//! use magcal_logs::source::{self, LogArgs};
//!
//! fn main() -> anyhow::Result<()> {
//!     let dir = std::env::temp_dir().join(format!("magcal-logs-example-{}", std::process::id()));
//!     std::fs::create_dir_all(&dir)?;
//!     let path = dir.join("turned.csv");
//!     let mut text = String::from("time,mx,my,mz\n");
//!     for i in 0..400 {
//!         // A spiral over the sphere: every direction once.
//!         let z = 1.0 - (2 * i + 1) as f64 / 400.0;
//!         let a = i as f64 * 2.399_963;
//!         let r = (1.0 - z * z).sqrt();
//!         let [x, y] = [r * a.cos(), r * a.sin()];
//!         text += &format!("{},{},{},{}\n", 0.1 * i as f64, 48.0 * x + 3.0, 48.0 * y - 1.5, 48.0 * z + 0.5);
//!     }
//!     std::fs::write(&path, text)?;
//!
//!     let log = source::open(&path, &LogArgs::default(), 0)?;
//!     assert_eq!(log.readings.len(), 400);
//!     assert_eq!(log.columns, ["mx", "my", "mz"].map(String::from));
//!
//!     let fit = log_fit::fit(&log.readings, 48.0, FitModel::Full)?;
//!     for (estimated, offset) in fit.bias.iter().zip([3.0, -1.5, 0.5]) {
//!         assert!((estimated - offset).abs() < 1e-9, "{estimated} against {offset}");
//!     }
//!     std::fs::remove_dir_all(&dir)?;
//!     Ok(())
//! }
//! ```

pub mod ardupilot;
pub mod binary;
pub mod calibration;
pub mod dataflash;
pub mod digest;
pub mod export;
pub mod flight;
pub mod flown;
pub mod gps;
pub mod limits;
pub mod parameters;
pub mod read;
pub mod site;
pub mod source;
pub mod text;
pub mod tlog;
pub mod ulog;
