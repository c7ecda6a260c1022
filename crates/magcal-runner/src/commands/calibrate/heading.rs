//! The heading a calibration gives against the attitudes its log carries.

use magcal_core::Vec3;
use magcal_core::aviation::z_up_of_ned;
use magcal_core::log_fit::LogFit;
use magcal_core::reference::{AlignSettings, align};

use crate::log::calibration::{HeadingCheckJson, HeadingFiguresJson};
use crate::log::flight::Format;
use crate::log::source::Log;

/// What a log's attitudes are as a reference for the heading, in words.
pub fn against(format: Format) -> &'static str {
    match format {
        Format::Csv => {
            "the log's attitude columns: a truth only where they come from an independent reference (motion capture, a turntable), else a figure of consistency"
        }
        _ => {
            "the autopilot's own attitude estimate, made with the calibration in force when it flew: a figure of consistency, not a truth"
        }
    }
}

/// The heading and direction errors of the calibrated and of the raw readings against the log's
/// attitudes (`Q` and `F` fitted for each); `None` for a log without attitudes.
pub fn check(log: &Log, fit: &LogFit) -> Option<HeadingCheckJson> {
    let attitudes = log.attitudes.as_ref()?;
    let (raw, c): (Vec<Vec3>, Vec<_>) = log
        .readings
        .iter()
        .zip(attitudes)
        .filter_map(|(r, a)| Some((*r, z_up_of_ned(a.as_ref()?))))
        .unzip();
    let against = against(log.origin.format);
    let figures = |readings: &[Vec3]| {
        align(readings, &c, &AlignSettings::default()).map(|a| HeadingFiguresJson {
            heading_rms_deg: a.summary.heading_rms_deg,
            heading_p95_deg: a.summary.heading_p95_deg,
            heading_max_deg: a.summary.heading_max_deg,
            direction_rms_deg: a.summary.direction_rms_deg,
        })
    };
    let calibrated: Vec<Vec3> = raw.iter().map(|r| fit.apply(*r)).collect();
    let (after, before) = (figures(&calibrated), figures(&raw));
    let error = after.as_ref().err().or(before.as_ref().err()).map(ToString::to_string);
    Some(HeadingCheckJson {
        readings: raw.len(),
        against: against.to_string(),
        calibrated: after.ok(),
        uncalibrated: before.ok(),
        error,
    })
}
