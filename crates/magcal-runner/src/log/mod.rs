//! Logs of real readings and what the log commands share: reading a CSV log ([`read`]), the
//! calibration file ([`calibration`]) and the vehicle's box ([`vehicle`]). The site, date and units
//! of a log are typed in [`crate::scenario::site`], which scenarios share.

pub mod ardupilot;
pub mod binary;
pub mod calibration;
pub mod dataflash;
pub mod flight;
pub mod read;
pub mod tlog;
pub mod vehicle;
