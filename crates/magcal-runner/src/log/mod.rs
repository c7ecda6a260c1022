//! Logs of real readings as the log commands take them: the readers, the calibration file and the
//! exports are the `magcal-logs` crate's (re-exported here under their module names); the vehicle
//! a log is judged against, from a scenario or from flags, is the command line's ([`vehicle`]).

pub use magcal_logs::{
    ardupilot, binary, calibration, dataflash, export, flight, flown, gps, parameters, read, source, tlog, ulog,
};

pub mod vehicle;

/// The parser of a log's path on the command line: `-` is standard input, read through
/// `/dev/stdin` (a pipe as a stream, bounded as every stream is; a redirected file as that file,
/// its format told by its first bytes). Where there is no `/dev/stdin`, `-` is refused.
pub fn path_parser() -> impl clap::builder::TypedValueParser<Value = std::path::PathBuf> {
    use clap::builder::TypedValueParser;
    clap::builder::PathBufValueParser::new().try_map(|path| {
        if path.as_os_str() != "-" {
            Ok(path)
        } else if cfg!(unix) {
            Ok(std::path::PathBuf::from("/dev/stdin"))
        } else {
            Err("standard input (-) is read through /dev/stdin, which this platform lacks: give the log's path")
        }
    })
}
