//! Logs of real readings as the log commands take them: the readers, the calibration file and the
//! exports are the `magcal-logs` crate's (re-exported here under their module names); the vehicle
//! a log is judged against, from a scenario or from flags, is the command line's ([`vehicle`]).

pub use magcal_logs::{
    ardupilot, binary, calibration, dataflash, export, flight, flown, gps, parameters, read, source, tlog, ulog,
};

pub mod vehicle;
