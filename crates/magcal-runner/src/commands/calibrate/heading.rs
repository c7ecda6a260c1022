//! The heading a calibration gives against the attitudes its log carries.

use magcal_core::Vec3;
use magcal_core::aviation::z_up_of_ned;
use magcal_core::log_fit::{LogFit, WORSE_SIGMAS, heading_versus_raw, time_blocks};
use magcal_core::reference::{AlignSettings, Alignment, align};
use magcal_logs::text::significant;

use crate::log::calibration::{HeadingCheckJson, HeadingFiguresJson, VersusRawJson};
use crate::log::flight::Format;
use crate::log::source::{Log, Origin};

/// What a log's attitudes are as a reference for the heading, in words.
pub fn against(origin: &Origin) -> String {
    if let Some(name) = &origin.independent_heading {
        return format!(
            "roll and pitch the autopilot's, heading from {name}, independent of the compass: a truth for the heading within that reference's own error"
        );
    }
    match origin.format {
        Format::Csv => {
            "the log's attitude columns: a truth only where they come from an independent reference (motion capture, a turntable), else a figure of consistency"
                .to_string()
        }
        _ => {
            "the autopilot's own attitude estimate, made with the calibration in force when it flew: a figure of consistency, not a truth"
                .to_string()
        }
    }
}

/// Seconds per block of the comparison with the raw readings: longer than the heading errors
/// stay correlated on BROAD (the attitude's slow turns), short enough for 15 or more blocks in
/// a trial of three minutes. A log shorter than ten of them takes ten blocks, of 2 s at least.
pub const BLOCK_S: f64 = 10.0;

/// Blocks a log shorter than `BLOCKS_AT_LEAST * BLOCK_S` is cut into (the jackknife's standard
/// error needs several; PX4's `esc_status_log.ulg` spans 39 s).
const BLOCKS_AT_LEAST: f64 = 10.0;

/// The shortest block, seconds.
const SHORTEST_BLOCK_S: f64 = 2.0;

/// Blocks of equal count for a log without times.
const BLOCKS_WITHOUT_TIMES: usize = 20;

/// The heading and direction errors of the calibrated and of the raw readings against the log's
/// attitudes (`Q` and `F` fitted for each), and the calibrated heading against the raw one;
/// `None` for a log without attitudes.
pub fn check(log: &Log, fit: &LogFit) -> Option<HeadingCheckJson> {
    check_aligned(log, fit).0
}

/// [`check`], and the calibrated readings' alignment with the attitudes where it was made.
pub fn check_aligned(log: &Log, fit: &LogFit) -> (Option<HeadingCheckJson>, Option<Alignment>) {
    let Some(attitudes) = log.attitudes.as_ref() else {
        return (None, None);
    };
    let (index, (raw, c)): (Vec<usize>, (Vec<Vec3>, Vec<_>)) = log
        .readings
        .iter()
        .zip(attitudes)
        .enumerate()
        .filter_map(|(i, (r, a))| Some((i, (*r, z_up_of_ned(a.as_ref()?)))))
        .unzip();
    let against = against(&log.origin);
    let aligned = |readings: &[Vec3]| align(readings, &c, &AlignSettings::default());
    let calibrated: Vec<Vec3> = raw.iter().map(|r| fit.apply(*r)).collect();
    let (after, before) = (aligned(&calibrated), aligned(&raw));
    let error = after.as_ref().err().or(before.as_ref().err()).map(ToString::to_string);
    let versus_raw = match (&after, &before) {
        (Ok(a), Ok(b)) => versus_raw(log, &index, a, b),
        _ => None,
    };
    let json = HeadingCheckJson {
        readings: raw.len(),
        against: against.to_string(),
        calibrated: after.as_ref().ok().map(figures),
        uncalibrated: before.as_ref().ok().map(figures),
        error,
        versus_raw,
    };
    (Some(json), after.ok())
}

fn figures(a: &Alignment) -> HeadingFiguresJson {
    HeadingFiguresJson {
        heading_rms_deg: a.summary.heading_rms_deg,
        heading_p95_deg: a.summary.heading_p95_deg,
        heading_max_deg: a.summary.heading_max_deg,
        direction_rms_deg: a.summary.direction_rms_deg,
    }
}

/// The calibrated heading errors against the raw ones of the readings `index` of `log`, in
/// blocks of [`BLOCK_S`] seconds (of equal count without times).
fn versus_raw(log: &Log, index: &[usize], calibrated: &Alignment, raw: &Alignment) -> Option<VersusRawJson> {
    let (blocks, block) = match &log.times {
        Some(t) => {
            let times: Vec<f64> = index.iter().map(|i| t[*i]).collect();
            let span = times.last().zip(times.first()).map_or(0.0, |(b, a)| b - a);
            let block_s = (span / BLOCKS_AT_LEAST).clamp(SHORTEST_BLOCK_S, BLOCK_S);
            (
                time_blocks(&times, block_s),
                format!("{} s of the log's time", significant(block_s, 3)),
            )
        }
        None => {
            let per = index.len().div_ceil(BLOCKS_WITHOUT_TIMES).max(1);
            (
                (0..index.len()).map(|i| i / per).collect(),
                format!("{per} readings in log order (the log has no times)"),
            )
        }
    };
    let v = heading_versus_raw(&blocks, &calibrated.heading_deg, &raw.heading_deg)?;
    Some(VersusRawJson {
        difference_deg: v.difference_deg,
        std_error_deg: v.std_error_deg,
        blocks: v.blocks,
        block,
        limit_deg: v.limit_deg,
        sigmas: WORSE_SIGMAS,
        worse: v.worse,
    })
}
