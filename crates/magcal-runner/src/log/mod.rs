//! Logs of real readings and what the log commands share: reading a CSV log ([`read`]), the
//! site and units ([`site`]), the calibration file ([`calibration`]) and the vehicle's box
//! ([`vehicle`]).

pub mod calibration;
pub mod read;
pub mod site;
pub mod vehicle;
