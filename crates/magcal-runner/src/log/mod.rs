//! Logs of real readings and what the log commands share: a log of any format with what it
//! carries beside the field ([`source`]), the CSV reader ([`read`]), what a flight log's reader
//! hands over ([`flight`]) with what it says of its firmware's parameters ([`parameters`]) and of
//! where and when it was flown ([`gps`]), the
//! calibration file ([`calibration`]) and the vehicle's box ([`vehicle`]). The site, date and units
//! of a log are typed in [`crate::scenario::site`], which scenarios share.

pub mod ardupilot;
pub mod binary;
pub mod calibration;
pub mod dataflash;
pub mod export;
pub mod flight;
pub mod flown;
pub mod gps;
pub mod parameters;
pub mod read;
pub mod source;
pub mod tlog;
pub mod ulog;
pub mod vehicle;
