//! The rows of the CSV files of a replay set (`magcal replay`), one type per file, shared by the
//! writer (`commands/replay/write.rs`) and every reader (the report page, the tests).

use serde::{Deserialize, Serialize};

use super::{Real, Status};

/// `realisation.csv`: each distinct attitude of each design, its field direction in the sensor
/// frame, and the windows of the log that may realise it (count; nearest, median and farthest
/// angle, degrees; empty without any).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RealisationRow {
    pub design: String,
    /// The rotation the design was turned by (`--orient`), degrees.
    pub turned_deg: Real,
    pub point: usize,
    pub roll_deg: Real,
    pub yaw_deg: Real,
    pub pitch_deg: Real,
    pub readings: usize,
    pub ux: Real,
    pub uy: Real,
    pub uz: Real,
    pub candidates: usize,
    pub nearest_deg: Option<Real>,
    pub median_deg: Option<Real>,
    pub farthest_deg: Option<Real>,
}

/// `trials.csv`: one row per trial and model.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ReplayTrialRow {
    pub design: String,
    pub trial: usize,
    pub model: String,
    pub status: Status,
    pub heading_rms_deg: Option<Real>,
    pub heading_p95_deg: Option<Real>,
    pub heading_max_deg: Option<Real>,
    pub direction_rms_deg: Option<Real>,
    /// With the calibration's own alignment held (the vector model); empty for the others.
    pub heading_rms_held_deg: Option<Real>,
    pub direction_rms_held_deg: Option<Real>,
    pub eta_psi: Option<Real>,
    pub eta_s: Option<Real>,
    pub eta_o: Option<Real>,
    pub rms_residual_nt: Option<Real>,
    /// The largest angle between a design attitude's direction and the window drawn for it.
    pub drawn_max_deg: Real,
}

/// `summary.csv`: per design, model and metric, the outcome counts and the statistics over the
/// `ok` trials (`trials = 0` for a design the log cannot realise).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ReplaySummaryRow {
    pub design: String,
    pub m: usize,
    pub model: String,
    pub trials: usize,
    pub ok: usize,
    pub not_converged: usize,
    pub not_identifiable: usize,
    pub failed: usize,
    pub metric: String,
    pub mean: Option<Real>,
    pub std: Option<Real>,
    pub median: Option<Real>,
    pub p05: Option<Real>,
    pub p95: Option<Real>,
    pub se_mean: Option<Real>,
    pub rms: Option<Real>,
}

/// `whole_log.csv`: each model's calibration of the whole log, scored as the trials are.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct WholeLogRow {
    pub model: String,
    pub readings: usize,
    pub status: Status,
    pub heading_rms_deg: Option<Real>,
    pub heading_p95_deg: Option<Real>,
    pub heading_max_deg: Option<Real>,
    pub direction_rms_deg: Option<Real>,
    /// With the calibration's own alignment held (the vector model); empty for the others.
    pub heading_rms_held_deg: Option<Real>,
    pub direction_rms_held_deg: Option<Real>,
    pub eta_psi: Option<Real>,
    pub eta_s: Option<Real>,
    pub eta_o: Option<Real>,
    pub rms_residual_nt: Option<Real>,
}
