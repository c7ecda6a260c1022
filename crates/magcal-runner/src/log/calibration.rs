//! `calibration.json`: what `calibrate` writes and `apply` and `next` read.

use std::path::Path;

use anyhow::{Context, Result, bail};
use magcal_core::small::Mat3;
use serde::{Deserialize, Serialize};

/// Standard errors of the fitted parameters; `null` where the information is singular.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StdError {
    pub psi_deg: Option<[f64; 3]>,
    pub scale: Option<[f64; 3]>,
    pub bias: Option<[f64; 3]>,
}

/// `calibration.json` and the `--json` output.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CalibrationJson {
    pub log: String,
    pub columns: [String; 3],
    pub samples: usize,
    pub skipped: usize,
    /// Readings dropped by `--reject` (0 without it).
    pub rejected: usize,
    pub fit: String,
    /// With `--fit auto`: why this model.
    pub fit_reason: Option<String>,
    pub magnitude: f64,
    /// `given`, `fitted mean radius (...)` or `radius of the best-fitting sphere (...)`.
    pub magnitude_source: String,
    pub bias: [f64; 3],
    pub psi_deg: [f64; 3],
    pub scale: [f64; 3],
    /// `K = P^-1`: raw = K b + bias.
    pub k: Mat3,
    /// `b = P (raw - bias)`, upper triangular (\[P1\] eq. (6)).
    pub p: Mat3,
    /// `b = A^-1 (raw - bias)` with `A^-1` the symmetric square root of `G = P^T P` (Magneto,
    /// MotionCal, ArduPilot).
    pub soft_iron_inverse: Mat3,
    pub residual_rms: f64,
    pub residual_max: f64,
    pub residual_rms_percent: f64,
    /// The noise per component the standard errors rest on, in the log's units: given
    /// (`--noise`) or estimated from the residuals; `null` when neither (an exact fit).
    pub noise: Option<f64>,
    pub std_error: StdError,
    pub identifiable: bool,
    pub verdict: String,
    /// For a reduced model (`diagonal`, `offset`): its lack-of-fit F test against the richer
    /// models fitted to the same readings (`null` for `full`).
    pub lack_of_fit: Option<LackOfFitJson>,
    pub status: String,
    pub iterations: usize,
    pub coverage: Coverage,
    /// A calibration to use: identifiable, its model not rejected by the log, the readings on an
    /// ellipsoid, and standard errors known.
    #[serde(default)]
    pub usable: bool,
    /// Why not `usable`, one reason each.
    #[serde(default)]
    pub reasons: Vec<String>,
    /// Where `noise` comes from and how sure it is.
    #[serde(default)]
    pub noise_estimate: Option<NoiseJson>,
    /// Half-widths of the 95 % confidence intervals (`null` where the standard errors are
    /// unknown).
    #[serde(default)]
    pub interval95: Option<IntervalJson>,
    /// Whether the readings lie on an ellipsoid.
    #[serde(default)]
    pub ellipsoid: Option<EllipsoidJson>,
}

/// Where the noise comes from.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NoiseJson {
    /// `given`, `residuals` or `unknown`.
    pub source: String,
    /// Residual degrees of freedom of an estimate.
    pub dof: Option<usize>,
    /// 95 % interval of an estimate (chi-square).
    pub interval95: Option<[f64; 2]>,
    /// `--reject K`: the estimate is corrected for the truncation at K.
    pub truncation_k: Option<f64>,
}

/// Half-widths of 95 % confidence intervals: `quantile` standard errors.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct IntervalJson {
    /// Student's t of the residual degrees of freedom, or 1.96 with a given noise.
    pub quantile: f64,
    pub psi_deg: [f64; 3],
    pub scale: [f64; 3],
    pub bias: [f64; 3],
}

/// The ellipsoid test.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EllipsoidJson {
    pub passed: bool,
    pub residual_rms_percent: f64,
    /// The limit on `residual_rms_percent`.
    pub limit_percent: f64,
    /// With `--noise`: the chi-square p-value of the readings' scatter about the ellipsoid.
    pub chi_square_p: Option<f64>,
    pub words: String,
}

/// [`magcal_core::log_fit::LackOfFit`] in the JSON.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LackOfFitJson {
    /// The richer model of the most significant test.
    pub against: String,
    pub f: f64,
    /// `[p_f - p_r, m - p_f]`.
    pub dof: [usize; 2],
    pub p_value: f64,
    /// `p_value` (Bonferroni over the richer models tested) below 1e-3: the log shows terms the
    /// model leaves out.
    pub rejected: bool,
    /// The test in words.
    pub words: String,
}

/// How well the log covers what the sensor can see.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Coverage {
    /// MotionCal's surface-gap error of the calibrated field directions, percent (0: every one of
    /// 100 equal-area regions holds at least three readings; 100: none).
    pub motioncal_gap_percent: f64,
    /// MicroStrain's spatial coverage of the calibrated field directions, percent: the share of
    /// 18 x 32 bins of 10 degrees of latitude by 11.25 of longitude holding at least one
    /// (MicroStrain calls more than 70 % good).
    pub microstrain_coverage_percent: f64,
    /// With `--scenario`: the certified D-efficiency per reading of the log's information against
    /// every design of as many readings in the scenario's box, under the fitted sensor.
    pub d_efficiency_per_reading: Option<f64>,
    /// The scenario that gave the box.
    pub box_from: Option<String>,
}

impl CalibrationJson {
    /// The calibrated field of a raw reading: `P (raw - bias)`.
    pub fn apply(&self, raw: magcal_core::Vec3) -> magcal_core::Vec3 {
        magcal_core::small::mat_vec(&self.p, magcal_core::small::sub(raw, self.bias))
    }
}

/// A `calibration.json` whose `p`, `bias` and `magnitude` are usable.
pub fn read_calibration(path: &Path) -> Result<CalibrationJson> {
    let shown = path.display().to_string();
    let text = std::fs::read(path).with_context(|| format!("{shown}: cannot read"))?;
    let cal: CalibrationJson =
        serde_json::from_slice(&text).with_context(|| format!("{shown}: not a magcal calibration"))?;
    if !(cal.p.iter().flatten().all(|v| v.is_finite())
        && cal.bias.iter().all(|v| v.is_finite())
        && cal.magnitude.is_finite()
        && cal.magnitude > 0.0)
    {
        bail!("{shown}: p, bias or magnitude is not finite and positive");
    }
    Ok(cal)
}
