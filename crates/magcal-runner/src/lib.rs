//! `magcal`: scenario files -> designs -> noisy Monte Carlo trials -> CSV statistics, figures and a
//! manifest, and regression checks against committed results. The mathematics lives in
//! `magcal-core`; this crate is glue, a library so that its tests and fuzz targets call it directly.
//!
//! Data flows one way: [`scenario`] (raw TOML -> validated, sizes bounded by [`limits`]) ->
//! [`pipeline`] (designs, parallel trials collected in trial order) -> [`output`] (typed rows, the
//! manifest, the result set swapped in whole) and [`plots`]. [`cli`] parses the command line and
//! matches the command once; each command is a module of [`commands`].
//!
//! Logs: [`log`] reads raw readings and the calibration file for the log commands
//! ([`commands::calibrate`], [`commands::apply`], [`commands::next`], [`commands::simulate`]).
//!
//! Exit codes: 0 success, 1 regression found by `check`, 2 bad input or usage or an output that
//! cannot be written, 3 `calibrate` ran and wrote its outputs but the result is not a calibration
//! to use (the log does not determine it, or rejects its model).

pub mod cli;
pub mod commands;
pub mod deadline;
pub mod help;
pub use magcal_logs::digest;
pub mod limits;
pub mod log;
pub mod output;
pub mod pipeline;
pub use magcal_report::figures as plots;
pub use magcal_report::pages as report;
pub mod scenario;
