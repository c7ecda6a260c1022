//! Calibration of a log of raw readings (docs/conventions.md "Real data"): a fit of one of three
//! models, its standard errors from the residual scatter (or a noise the user gives) and the
//! Fisher information of the log's own readings, whether the log determines it, and whether the
//! result is a calibration to use.
//!
//! - [`FitModel::Full`]: \[P1\]'s model, upper-triangular `K` (non-orthogonality `psi`, scale
//!   factors `S`) and bias `O`, 9 parameters, by the two-step calibration of \[P1\] IV.C.
//! - [`FitModel::Diagonal`]: `psi = 0`; `S` and `O`, 6 parameters.
//! - [`FitModel::Offset`]: `O` and one scale factor common to the three axes, 4 parameters.
//!
//! # Units
//! A fit does not depend on the log's units nor on the magnitude it is given. The readings are
//! first moved to their mean and divided by their rms distance from it (`u = (s - c) / L`), and
//! every model is fitted there to a unit field; `P = (R / L) P_u`, `O = c + L o_u`. The
//! least-squares problem `min sum (|P (s - O)| - R)^2` is the same problem for every `R` (its
//! minimiser scales with `R`), so the magnitude only scales `P` and the scale factors
//! ([`LogFit::at_magnitude`]). Readings of any size that a double holds (1e-14 or 1e20) are
//! fitted alike.
//!
//! # Statistics
//! A log has no attitudes: the body field of reading `i` under the fitted model is
//! `b_i = P (s_i - O)`, and the information is that of \[P1\]'s model at those fields
//! ([`crate::identifiability::information_per_unit_variance`]); a reduced model's is its block
//! (diagonal) or its image under `S = (s, s, s)` (offset). The noise per component is estimated
//! from the residuals `r_i = |b_i| - R`: `r_i ~ (b_i / |b_i|)^T P n_i`, so
//! `sigma^2 = sum r_i^2 / ((m - p) mean |P^T b_i / |b_i||^2)`, with `m - p` degrees of freedom;
//! its 95 % interval is that of a chi-square with `m - p` degrees of freedom. With `m = p` the fit
//! is exact and the log says nothing about its noise: the noise must be given
//! ([`FitSettings::noise`]), else the standard errors are unknown. Confidence intervals are
//! `estimate +- t std` with `t` the Student quantile of `m - p` degrees of freedom (the normal
//! one when the noise is given); `log_fit_honesty` in the core's tests measures their coverage.
//!
//! # Verdicts
//! The log is **identifiable** under a model when every parameter's standard error is known and
//! within the physical scales of [`PhysicalScales`](crate::identifiability::PhysicalScales) (10 degrees, half the scale factor, the
//! field magnitude) and the fit converged; otherwise the verdict names the weakest parameters,
//! by the sensor's axes x, y, z.
//!
//! A reduced model can be identifiable and still wrong: a sensor whose scale factors differ, fitted
//! with one common scale, leaves residuals far above the noise, and its estimates carry the bias
//! of the missing terms while its standard errors look small. [`fit_tested`] and [`fit_auto`]
//! therefore test every reduced fit against the richer models by the **lack-of-fit F test** of
//! nested least squares ([`LackOfFit`]).
//!
//! And a log can be fitted by an ellipsoid without lying on one (readings filling a volume): the
//! **ellipsoid test** ([`EllipsoidTest`]) refuses a residual rms above
//! [`ELLIPSOID_LIMIT_PERCENT`] of the magnitude and, when the noise is given, a residual scatter the
//! noise does not explain (chi-square test at [`LACK_OF_FIT_LEVEL`]).
//!
//! A fit is **usable** ([`LogFit::usable`]) when it is identifiable, the log does not reject its
//! model, it passes the ellipsoid test and its standard errors are known; [`LogFit::reasons`]
//! says why not.
#![allow(non_snake_case)]
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

mod check;
mod coverage;
mod field_change;
mod held_out;
mod lack_of_fit;
pub mod motor;
mod passes;
mod plausible;
mod reject;
pub mod serial;
mod statistics;
mod versus_raw;

pub use check::{CHECK_SEED, CHECK_TRIALS, TrialCheck, TrialNoise, USABLE_SHARE};
pub use coverage::{
    MotionCalRegion, coverages, microstrain_coverage_percent, motioncal_gaps, motioncal_region, motioncal_region_counts,
};
pub use field_change::{
    Candidate, FIELD_CHANGE_STEP, FIELD_CHANGE_Z, FieldChange, FieldChangeError, FieldChangeSettings, Segment,
    best_sphere, field_segments,
};
pub use held_out::{
    FoldFit, FoldKind, HELD_OUT_FOLDS, HELD_OUT_RATIO, HELD_OUT_RATIO_SHUFFLED, HeldOut, MIN_DETERMINED, Scale,
    assemble as assemble_held_out, cut as cut_folds, min_readings as min_held_out_readings, widen_std,
};
pub use lack_of_fit::{LACK_OF_FIT_LEVEL, LackOfFit, show_p};
pub use passes::{
    PASS_EDGE_SIGMAS, PASS_FALSE_ALARM, PASS_SHARE, PASS_SHIFT, Pass, Passes, pass_sigmas, passes, passes_in_magnitudes,
};
pub use plausible::{PLAUSIBLE_PSI_DEG, PLAUSIBLE_SCALE, PLAUSIBLE_SCALE_RATIO, implausible};
pub use reject::{REJECT_MAX_SHARE, REJECT_MIN_K, RejectError, Rejection, reject_outliers, truncated_variance_factor};
pub use serial::Serial;
pub use versus_raw::{HeadingVersusRaw, MIN_BLOCKS, WORSE_SIGMAS, heading_versus_raw, time_blocks};

pub use crate::calibration::step2::Residual;
use rayon::prelude::*;

use crate::calibration::{CalibrationError, CalibrationStatus, Termination, TwoStep, step2};
use crate::sensor::ErrorModel;
use crate::small::{Mat3, Vec3, cholesky_in_place, cholesky_solve, mat_t_vec, mat_vec, norm, sub};
use crate::stop::Stop;

/// The ellipsoid test's limit on the residual rms, percent of the magnitude. Readings on a
/// magnetometer's ellipsoid scatter by the sensor's noise (the public logs: 0.85 % to 2.64 %);
/// readings spread through a volume leave far more (uniform in a cube: 27 %). False alarms on the
/// public logs: none of the 63 windows of 300 consecutive readings that the full model fits
/// (largest residual 5.1 %; the core's test `log_fit_honesty`).
pub const ELLIPSOID_LIMIT_PERCENT: f64 = 10.0;

/// `x` with `digits` significant digits: fixed notation from 1e-4 to 1e7, scientific beyond
/// (`0.0001234`, `48277.79`, `1.234e-10`, `1.000e-300`); `0` for zero, `NaN`, `inf`. For the
/// core's own sentences (verdicts, reasons) alone: what prints numbers for a person uses
/// `magcal_logs::text::significant`, the same rule, so that the math crate exports no formatting.
pub(crate) fn significant(x: f64, digits: usize) -> String {
    let digits = digits.max(1);
    if !x.is_finite() {
        return format!("{x}");
    }
    if x == 0.0 {
        return "0".to_string();
    }
    let e = x.abs().log10().floor();
    if (-4.0..7.0).contains(&e) {
        let decimals = (digits as f64 - 1.0 - e).max(0.0) as usize;
        format!("{x:.decimals$}")
    } else {
        format!("{x:.*e}", digits - 1)
    }
}

/// Which parameters a log fit estimates (MATLAB `magcal`'s `fitkind`, with \[P1\]'s
/// non-orthogonality as the full model).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum FitModel {
    /// Non-orthogonality, scale factors and bias: 9 parameters.
    Full,
    /// Scale factors and bias: 6 parameters.
    Diagonal,
    /// Bias and one common scale factor: 4 parameters.
    Offset,
}

impl FitModel {
    /// `full`, `diagonal`, `offset`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::Full => "full",
            Self::Diagonal => "diagonal",
            Self::Offset => "offset",
        }
    }

    /// Parameters estimated.
    pub fn parameters(&self) -> usize {
        match self {
            Self::Full => 9,
            Self::Diagonal => 6,
            Self::Offset => 4,
        }
    }
}

/// Whether the readings are in time order, which makes their residuals' correlation measurable.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Order {
    /// Not known to be in time order (a CSV log without times): white-noise standard errors.
    #[default]
    Unknown,
    /// In time order (a flight log, a CSV log with `--time`): standard errors from the residuals'
    /// long-run covariance, batch length by [`Serial::of_residuals`].
    Time,
    /// In time order, with this batch length (readings): the trials of a log's check take the
    /// log's own.
    Batch(usize),
}

/// What a fit knows beyond the readings, and how it is judged.
#[derive(Debug, Clone, PartialEq)]
pub struct FitSettings {
    /// The readings' noise per component, in the log's units, when known (a data sheet, a
    /// stationary recording). Default `None`: estimated from the residuals. A given noise that
    /// does not explain the residuals' scatter (chi-square, [`LACK_OF_FIT_LEVEL`]) gives way to
    /// the scatter, and the ellipsoid test's words say so.
    pub noise: Option<f64>,
    /// The log kept only readings within this distance (the log's units) of the ellipsoid,
    /// [`Rejection::half_width`] of [`reject_outliers`]: the noise estimate and the standard
    /// errors are corrected for the truncation ([`truncated_variance_factor`]). Default `None`.
    pub truncation: Option<f64>,
    /// The residual every model minimises. Default [`Residual::Readings`], the one of designs
    /// (docs/conventions.md "Calibration"); [`Residual::Paper`] is \[P1\]'s.
    pub residual: Residual,
    /// Whether the readings are in time order. Default [`Order::Unknown`].
    pub order: Order,
    /// Noisy trials of the log's check ([`TrialCheck`]); 0: none, and a fit is usable on its
    /// statistics alone. Default [`CHECK_TRIALS`].
    pub trials: usize,
    /// The seed of the check's random streams. Default [`CHECK_SEED`].
    pub seed: u64,
    /// Whether the readings' residual's fits measure how far their cost bends away from the
    /// quadratic their standard errors assume ([`Profile`]), and widen the standard errors by
    /// it. Default `true`.
    pub profile: bool,
    /// Whether the fit is also made without each fold of the log and its standard errors set
    /// against the spread of those fits ([`HeldOut`]). Default `true`.
    pub held_out: bool,
    /// When to give up: asked before every iteration of every fit the fit makes (its own, its
    /// profile's, its trials', its held-out folds', its lack-of-fit test's) and before every
    /// round of its trials. A fit whose stop is requested before it returns is
    /// [`CalibrationError::Stopped`]. Default [`Stop::NEVER`].
    pub stop: Stop,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            noise: None,
            truncation: None,
            residual: Residual::Readings,
            order: Order::Unknown,
            trials: CHECK_TRIALS,
            seed: CHECK_SEED,
            profile: true,
            held_out: true,
            stop: Stop::NEVER,
        }
    }
}

/// The noise per component a fit's standard errors rest on.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Noise {
    /// Given by the user ([`FitSettings::noise`]), in the log's units.
    Given(f64),
    /// Estimated from the residuals, in the log's units, with `dof = m - p` degrees of freedom
    /// and its 95 % interval (chi-square).
    Estimated {
        /// The estimate.
        value: f64,
        /// Residual degrees of freedom.
        dof: usize,
        /// 95 % interval of the noise.
        interval95: (f64, f64),
    },
    /// Neither given nor estimable: the fit is exact (`m = p`).
    Unknown,
}

impl Noise {
    /// The value, where known.
    pub fn value(&self) -> Option<f64> {
        match *self {
            Self::Given(v) | Self::Estimated { value: v, .. } => Some(v),
            Self::Unknown => None,
        }
    }

    /// `given`, `residuals`, `unknown`.
    pub fn source(&self) -> &'static str {
        match self {
            Self::Given(_) => "given",
            Self::Estimated { .. } => "residuals",
            Self::Unknown => "unknown",
        }
    }

    fn scaled(self, by: f64) -> Self {
        match self {
            Self::Given(v) => Self::Given(v * by),
            Self::Estimated { value, dof, interval95 } => Self::Estimated {
                value: value * by,
                dof,
                interval95: (interval95.0 * by, interval95.1 * by),
            },
            Self::Unknown => Self::Unknown,
        }
    }
}

/// Whether the readings lie on an ellipsoid (see the module documentation).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EllipsoidTest {
    /// The rms of the readings' distances from the fitted ellipsoid (each `(|b| - R) / |P^T
    /// w|`), percent of the radius of the sphere that best fits them.
    pub residual_percent: f64,
    /// With a given noise and residual degrees of freedom: `P(chi2 >= Q / sigma^2)` of the
    /// readings' squared distances `Q` from the ellipsoid.
    pub chi_square_p: Option<f64>,
    /// Both parts passed.
    pub passed: bool,
    /// In words.
    pub words: String,
}

/// What a standard error of a log fit is: the one a user reads is the largest of those that apply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StdSource {
    /// The parameter is held by the model (0).
    Fixed,
    /// The information at the residuals' scatter or the given noise, as white noise gives it.
    White,
    /// The residuals' long-run covariance (readings in time order; [`serial`]).
    LongRun,
    /// The rms error of the check's trials ([`TrialCheck`]).
    Trials,
    /// The spread of the fits made without each fold ([`HeldOut`]).
    HeldOut,
}

impl StdSource {
    /// In words: "white noise", "long-run", "trials", "held out", "fixed".
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::Fixed => "fixed",
            Self::White => "white noise",
            Self::LongRun => "long-run covariance",
            Self::Trials => "trials",
            Self::HeldOut => "held out",
        }
    }
}

/// A calibration of a log.
// Serialize only: it names its parts with `&'static str`, which a reader cannot borrow for ever.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LogFit {
    /// The model fitted.
    pub model: FitModel,
    /// The residual it minimised.
    pub residual: Residual,
    /// `P = K^-1`: calibrated field `b = P (raw - bias)`.
    pub p: Mat3,
    /// The bias, in the log's units.
    pub bias: Vec3,
    /// `(psi, S, O)` of the fit (`psi = 0` but for the full model). Its bias is in the log's
    /// units, as [`Self::bias`] is: [`ErrorModel`] says nT for \[P1\]'s simulated sensors, and
    /// its arithmetic is the same in any unit.
    pub errors: ErrorModel,
    /// The reference magnitude `R` the fit maps the readings to, in the log's units.
    pub magnitude: f64,
    /// RMS and largest `| |b_i| - R |`, in the magnitude's units.
    pub residual_rms: f64,
    /// See [`Self::residual_rms`].
    pub residual_max: f64,
    /// The noise per component the standard errors rest on.
    pub noise: Noise,
    /// The noise the settings gave (the log's units), whether or not it explains the scatter.
    pub given_noise: Option<f64>,
    /// Standard errors of `psi` (degrees; 0 where fixed), `S`, and `O` (the log's units); `None`
    /// where the information is singular or the noise unknown. For readings in time order, the
    /// larger of the white-noise ones and those of the residuals' long-run covariance
    /// ([`serial`]).
    pub std_psi_deg: Option<Vec3>,
    /// See [`Self::std_psi_deg`].
    pub std_scale: Option<Vec3>,
    /// See [`Self::std_psi_deg`].
    pub std_bias: Option<Vec3>,
    /// For readings in time order: the standard errors of `psi`, `S`, `O` that white noise would
    /// give, beside the ones above.
    pub white_std: Option<[Vec3; 3]>,
    /// For readings in time order: the standard errors of `psi`, `S`, `O` of the residuals'
    /// long-run covariance alone ([`serial`]; widened by the cost's bend and corrected for a
    /// truncation as the others are), before the larger of them and [`Self::white_std`] is
    /// taken and before the check's trials' errors set a floor ([`Self::check`]).
    pub serial_std: Option<[Vec3; 3]>,
    /// For readings in time order: the batch length of the long-run covariance.
    pub serial: Option<Serial>,
    /// The multiple of a standard error that makes a 95 % confidence interval: Student's `t` of
    /// the residual degrees of freedom, or the normal 1.96 with a given noise; `None` where the
    /// noise is unknown.
    pub quantile95: Option<f64>,
    /// Whether the log determines the fit (see the module documentation).
    pub identifiable: bool,
    /// In words: what is determined, or what is not.
    pub verdict: String,
    /// The fit's status (`not_identifiable` when step 2 ran along a flat direction).
    pub status: CalibrationStatus,
    /// Levenberg-Marquardt iterations.
    pub iterations: usize,
    /// The lack-of-fit test of a reduced model against the richer ones ([`fit_tested`],
    /// [`fit_auto`]); `None` for the full model, or from [`fit`] alone.
    pub lack_of_fit: Option<LackOfFit>,
    /// How far the readings' cost rises at 3 standard errors along the scale factors (the
    /// readings' residual only; see "Nonlinearity" in the module documentation).
    pub profile: Option<Profile>,
    /// Whether the readings lie on an ellipsoid.
    pub ellipsoid: EllipsoidTest,
    /// The noisy trials at the log's own readings ([`TrialCheck`]); `None` where not run.
    pub check: Option<TrialCheck>,
    /// The `ok` trials' errors against the sensor they were drawn from, `psi` (degrees), `S`,
    /// `O` (the log's units), scaled as [`TrialCheck::rms_error`] is: the calibrations the check
    /// allows, for the heading budget ([`crate::budget`]).
    #[serde(skip)]
    pub trial_errors: Vec<[Vec3; 3]>,
    /// The fit made without each fold of the log ([`HeldOut`]); `None` where not made (the
    /// settings, a fit that is not identifiable or not on an ellipsoid, a log too small).
    pub held_out: Option<HeldOut>,
    /// What each standard error of `psi`, `S`, `O` is ([`StdSource`]).
    pub std_source: [[StdSource; 3]; 3],
    /// The heading the calibration leaves against the user's budget ([`Self::judge_heading`]);
    /// `None` until judged.
    pub heading: Option<crate::budget::HeadingVerdict>,
    /// Identifiable, its model not rejected by the log, the ellipsoid test passed, the standard
    /// errors known, and its check by trials passed (where run): a calibration to use.
    pub usable: bool,
    /// Why not [`Self::usable`], one reason each (empty when usable).
    pub reasons: Vec<String>,
}

impl LogFit {
    /// The calibrated field of a raw reading: `P (raw - bias)`.
    pub fn apply(&self, raw: Vec3) -> Vec3 {
        mat_vec(&self.p, sub(raw, self.bias))
    }

    /// `A^-1`, the symmetric positive square root of `G = P^T P` (\[P1\] eq. (7)), by faer's
    /// eigendecomposition `V diag(sqrt lambda) V^T`: the calibration `b = A^-1 (raw - bias)` of
    /// Magneto, MotionCal and ArduPilot, equal in `|b|` to \[P1\]'s `P (raw - bias)` (docs/conventions.md
    /// "Real data"). NaN if the decomposition fails.
    pub fn soft_iron_inverse(&self) -> Mat3 {
        let g = crate::small::mat_mul(&crate::small::transpose(&self.p), &self.p);
        let m = faer::Mat::from_fn(3, 3, |i, j| g[i][j]);
        match m.self_adjoint_eigen(faer::Side::Lower) {
            Ok(evd) => std::array::from_fn(|i| {
                std::array::from_fn(|j| {
                    (0..3)
                        .map(|l| evd.U()[(i, l)] * evd.S()[l].max(0.0).sqrt() * evd.U()[(j, l)])
                        .sum()
                })
            }),
            Err(_) => [[f64::NAN; 3]; 3],
        }
    }

    /// The half-widths of the 95 % confidence intervals of `psi` (degrees), `S` and `O`:
    /// [`Self::quantile95`] standard errors, and Student's `t` of the held-out jackknife's degrees
    /// of freedom ([`HeldOut::quantile95`]) for those the held-out fits set; `None` where either
    /// is unknown.
    pub fn interval95(&self) -> Option<(Vec3, Vec3, Vec3)> {
        let q = self.quantile95?;
        // A standard error the held-out fits set takes the jackknife's Student t.
        let held = self.held_out.as_ref().and_then(HeldOut::quantile95).unwrap_or(q).max(q);
        let half = |g: usize, s: Option<Vec3>| -> Option<Vec3> {
            let v = s?;
            Some(std::array::from_fn(|i| {
                v[i] * if self.std_source[g][i] == StdSource::HeldOut {
                    held
                } else {
                    q
                }
            }))
        };
        Some((
            half(0, self.std_psi_deg)?,
            half(1, self.std_scale)?,
            half(2, self.std_bias)?,
        ))
    }

    /// The magnitude that makes the scale factors relative, with product 1: `R (S1 S2 S3)^(1/3)`
    /// (the fitted mean radius of the readings, in the log's units).
    pub fn mean_radius(&self) -> f64 {
        let s = self.errors.scale();
        self.magnitude * ((s[0].ln() + s[1].ln() + s[2].ln()) / 3.0).exp()
    }

    /// The same fit to the magnitude `magnitude` (the log's units): `P` and the residuals scale
    /// by `magnitude / R`, the scale factors and their standard errors by its inverse; the bias,
    /// the angles, the noise and every verdict are unchanged (see the module documentation).
    ///
    /// # Errors
    /// A magnitude that is not positive and finite, or scale factors out of floating-point range.
    pub fn at_magnitude(&self, magnitude: f64) -> Result<Self, CalibrationError> {
        if !(magnitude.is_finite() && magnitude > 0.0) {
            return Err(CalibrationError::InvalidFieldMagnitude { value: magnitude });
        }
        let f = magnitude / self.magnitude;
        let errors = ErrorModel::new(self.errors.psi_deg(), self.errors.scale().map(|s| s / f), self.bias)
            .map_err(|_| out_of_range())?;
        if !(self.p.iter().flatten().all(|v| (v * f).is_finite()) && errors.scale().iter().all(|s| *s > 0.0)) {
            return Err(out_of_range());
        }
        Ok(Self {
            p: self.p.map(|row| row.map(|v| v * f)),
            errors,
            magnitude,
            residual_rms: self.residual_rms * f,
            residual_max: self.residual_max * f,
            std_scale: self.std_scale.map(|s| s.map(|v| v / f)),
            white_std: self.white_std.map(|[p, s, o]| [p, s.map(|v| v / f), o]),
            serial_std: self.serial_std.map(|[p, s, o]| [p, s.map(|v| v / f), o]),
            check: self.check.map(|c| c.at_magnitude(f)),
            trial_errors: self
                .trial_errors
                .iter()
                .map(|[p, s, o]| [*p, s.map(|v| v / f), *o])
                .collect(),
            held_out: self.held_out.clone().map(|h| h.at_magnitude(f)),
            ..self.clone()
        })
    }

    /// Judges the heading the calibration leaves over `grid` against `budget_deg` (degrees), its
    /// calibrations drawn by its trials and its standard errors ([`crate::budget::judge`]; draws
    /// on streams of `seed` where it has no trials), and redoes the verdict: a budget not met
    /// makes the fit unusable. A fit without standard errors is left as it is (unusable already).
    pub fn judge_heading(&mut self, grid: &crate::budget::BudgetGrid, budget_deg: f64, seed: u64) {
        self.heading = crate::budget::judge(self, grid, budget_deg, seed);
        self.assess();
    }

    /// What each standard error rests on before the check and the held-out fits widen it: fixed,
    /// white noise, or the long-run covariance where it is the larger.
    fn sources_of_model(&self) -> [[StdSource; 3]; 3] {
        std::array::from_fn(|g| {
            std::array::from_fn(|i| {
                if g == 0 && self.model != FitModel::Full {
                    return StdSource::Fixed;
                }
                match (self.serial_std, self.white_std) {
                    (Some(s), Some(w)) if s[g][i] > w[g][i] => StdSource::LongRun,
                    _ => StdSource::White,
                }
            })
        })
    }

    /// Sets [`Self::usable`] and [`Self::reasons`] from the verdicts.
    fn assess(&mut self) {
        let mut reasons = Vec::new();
        if self.noise == Noise::Unknown {
            reasons.push(format!(
                "standard errors unknown: {} readings leave no residual degrees of freedom for the {} parameters of the {} model, so the noise cannot come from the log (give it)",
                self.model.parameters(),
                self.model.parameters(),
                self.model.as_str()
            ));
        } else if !self.identifiable {
            reasons.push(format!("not identifiable: {}", self.verdict));
        }
        // The trials are drawn from the fitted sensor: one that does not exist would confirm
        // itself. The magnitude here is relative; a known one is checked where it is known.
        if let Some(why) = implausible(&self.errors, false) {
            reasons.push(why);
        }
        if let Some(t) = self.lack_of_fit.as_ref().filter(|t| t.rejected) {
            reasons.push(format!("model rejected: {}", t.words()));
        }
        if !self.ellipsoid.passed {
            reasons.push(format!("not an ellipsoid: {}", self.ellipsoid.words));
        }
        if let Some(c) = self.check.as_ref().filter(|c| !c.passed()) {
            reasons.push(format!("fails its check by trials: {}", c.words()));
        }
        if let Some(h) = self.held_out.as_ref().filter(|h| !h.evidence()) {
            reasons.push(format!("no held-out evidence: {}", h.words()));
        }
        if let Some(why) = self.heading.as_ref().and_then(|h| h.reason()) {
            reasons.push(why);
        }
        self.usable = reasons.is_empty();
        self.reasons = reasons;
    }
}

fn out_of_range() -> CalibrationError {
    CalibrationError::NotPositiveDefinite {
        reason: "estimated scale factors are out of floating-point range (is the magnitude in the log's units?)",
    }
}

/// The readings moved to their mean and divided by their rms distance from it (see the module
/// documentation): `u = (s - centre) / length`.
struct Frame {
    centre: Vec3,
    length: f64,
}

impl Frame {
    /// The frame of `readings` (finite, at least one) and the readings in it. Sums are taken in
    /// units of the largest component, so that readings near the floating-point limits neither
    /// overflow nor underflow.
    fn of(readings: &[Vec3]) -> Result<(Self, Vec<Vec3>), CalibrationError> {
        let too_alike = CalibrationError::RankDeficient { rank: 0, needed: 4 };
        let a = readings.iter().flatten().fold(0.0_f64, |m, v| m.max(v.abs()));
        if !(a > 0.0 && a.is_finite()) {
            return Err(too_alike);
        }
        let m = readings.len() as f64;
        let mean: Vec3 = [0, 1, 2].map(|i| readings.iter().map(|s| s[i] / a).sum::<f64>() / m);
        let spread = (readings
            .iter()
            .map(|s| [0, 1, 2].map(|i| s[i] / a - mean[i]).iter().map(|v| v * v).sum::<f64>())
            .sum::<f64>()
            / m)
            .sqrt();
        let frame = Self {
            centre: mean.map(|v| v * a),
            length: spread * a,
        };
        if !(spread > 0.0 && frame.length > 0.0 && frame.length.is_finite()) {
            return Err(too_alike);
        }
        let u = readings
            .par_iter()
            .map(|s| [0, 1, 2].map(|i| (s[i] / a - mean[i]) / spread))
            .collect();
        Ok((frame, u))
    }
}

impl LogFit {
    /// A fit in a [`Frame`] (magnitude 1) in the log's units at magnitude `magnitude`.
    fn out_of_frame(self, frame: &Frame, magnitude: f64) -> Result<Self, CalibrationError> {
        let L = frame.length;
        let bias = [0, 1, 2].map(|i| frame.centre[i] + L * self.bias[i]);
        let unit = Self {
            bias,
            errors: ErrorModel::new(self.errors.psi_deg(), self.errors.scale().map(|s| s * L), bias)
                .map_err(|_| out_of_range())?,
            p: self.p.map(|row| row.map(|v| v / L)),
            noise: self.noise.scaled(L),
            given_noise: self.given_noise.map(|v| v * L),
            check: self.check.map(|c| c.scaled(L)),
            trial_errors: self
                .trial_errors
                .iter()
                .map(|[p, s, o]| [*p, s.map(|v| v * L), o.map(|v| v * L)])
                .collect(),
            held_out: self.held_out.clone().map(|h| h.scaled(L)),
            white_std: self.white_std.map(|[p, s, o]| [p, s.map(|v| v * L), o.map(|v| v * L)]),
            serial_std: self.serial_std.map(|[p, s, o]| [p, s.map(|v| v * L), o.map(|v| v * L)]),
            std_scale: self.std_scale.map(|s| s.map(|v| v * L)),
            std_bias: self.std_bias.map(|s| s.map(|v| v * L)),
            ..self
        };
        if !unit.p.iter().flatten().all(|v| v.is_finite()) {
            return Err(out_of_range());
        }
        unit.at_magnitude(magnitude)
    }
}

/// Calibrates `readings` (any units) to the magnitude `magnitude` (the same units) under
/// `model`, with the noise estimated from the residuals.
///
/// # Errors
/// Too few or non-finite readings, a magnitude that is not positive and finite, readings that no
/// ellipsoid (full model) or sphere (reduced models) fits.
pub fn fit(readings: &[Vec3], magnitude: f64, model: FitModel) -> Result<LogFit, CalibrationError> {
    fit_with(readings, magnitude, model, &FitSettings::default())
}

/// [`fit`] with `settings`.
///
/// # Errors
/// As [`fit`].
///
/// # Panics
/// If a given noise or truncation is not positive and finite (a caller bug: the runner checks
/// its options).
#[track_caller]
pub fn fit_with(
    readings: &[Vec3],
    magnitude: f64,
    model: FitModel,
    settings: &FitSettings,
) -> Result<LogFit, CalibrationError> {
    let (frame, u) = prepare(readings, magnitude, model, settings)?;
    let unit = unit_settings(&frame, settings);
    let fitted = fit_unit(&u, model, &unit).and_then(|f| checked(f, &u, &unit).out_of_frame(&frame, magnitude));
    unless_stopped(settings, fitted)
}

/// `fitted`, or [`CalibrationError::Stopped`] where the settings' stop is requested: a fit whose
/// parts were cut short is never returned as a fit. The stop stays requested once it has been,
/// so this one look covers every part.
fn unless_stopped<T>(settings: &FitSettings, fitted: Result<T, CalibrationError>) -> Result<T, CalibrationError> {
    settings
        .stop
        .unless_requested(fitted)
        .unwrap_or(Err(CalibrationError::Stopped))
}

/// `f` (a fit of `u` under `settings`, in its frame) with its check by trials and its held-out
/// fits where the settings ask for them ([`TrialCheck`], [`HeldOut`]), its standard errors widened
/// by what they show, and the verdict redone.
fn checked(mut f: LogFit, u: &[Vec3], settings: &FitSettings) -> LogFit {
    // The fit's own statistics are a first screen: a fit that does not settle, is not
    // identifiable or leaves the ellipsoid is not usable whatever trials would say, and is not
    // simulated (a runaway estimate is no sensor to draw readings from).
    if !(f.identifiable
        && f.ellipsoid.passed
        && implausible(&f.errors, false).is_none()
        && (settings.trials > 0 || settings.held_out))
    {
        return f;
    }
    if settings.trials > 0
        && let Some((check, errors)) = judged_check(&f, u, settings)
    {
        f.check = Some(check);
        f.trial_errors = errors;
        // The trials' own errors are what the estimate's error is at this log's noise, curvature
        // and correlation included: a standard error is never below their rms.
        if let Some(rms) = check.rms_error {
            f.raise(rms, StdSource::Trials);
        }
    }
    if settings.held_out {
        f.held_out = Some(held_out::run(u, &f, settings).unwrap_or_else(HeldOut::too_few));
        if let Some(h) = f.held_out.clone() {
            let raised = held_out::widen(&mut f, &h);
            for g in 0..3 {
                for i in 0..3 {
                    if raised[g][i] {
                        f.std_source[g][i] = StdSource::HeldOut;
                    }
                }
            }
        }
    }
    if let Some(words) = beyond_scales(&f) {
        f.identifiable = false;
        f.verdict = format!("not determined: the trials' and held-out fits' errors at this log's noise exceed {words}");
    }
    f.assess();
    f
}

impl LogFit {
    /// Each standard error at least `floor` (`psi`, `S`, `O`), named `source` where raised.
    fn raise(&mut self, floor: [Vec3; 3], source: StdSource) {
        let full = self.model == FitModel::Full;
        let stds = [&mut self.std_psi_deg, &mut self.std_scale, &mut self.std_bias];
        for (g, std) in stds.into_iter().enumerate() {
            if g == 0 && !full {
                continue;
            }
            if let Some(v) = std.as_mut() {
                for i in 0..3 {
                    if floor[g][i] > v[i] {
                        v[i] = floor[g][i];
                        self.std_source[g][i] = source;
                    }
                }
            }
        }
    }
}

/// The readings of the first part a long log is judged on by its check and its [`Profile`]:
/// every `k`-th reading, `k` the least that leaves at most this many.
pub const JUDGED_READINGS: usize = 8192;

/// The strides at which a log of `m` readings is judged, the sparsest first: every `k`-th reading
/// for the `k` that leaves at most [`JUDGED_READINGS`], then twice as many readings each time,
/// and last the whole log (`k = 1`).
fn strides(m: usize) -> Vec<usize> {
    let mut out = Vec::new();
    let mut n = JUDGED_READINGS;
    while n < m {
        out.push(m.div_ceil(n));
        n *= 2;
    }
    out.push(1);
    out.dedup();
    out
}

/// Every `k`-th reading of `u`, from the first.
fn every(u: &[Vec3], k: usize) -> Vec<Vec3> {
    u.iter().step_by(k).copied().collect()
}

/// The check by trials of `f`, the fit of `u`. A long log is judged on every `k`-th reading
/// ([`strides`]), the sparsest first: fewer readings of the same attitudes at the same noise
/// determine less, so where they pass, the log passes. The first part that passes gives the
/// check, its errors scaled to the whole log by the ratio of the log's standard errors to the
/// part's own fit's; where none passes, the whole log's trials do. A part whose own fit is not
/// identifiable, or not the whole log's sensor ([`same_sensor`]), is not judged.
fn judged_check(f: &LogFit, u: &[Vec3], settings: &FitSettings) -> Option<(TrialCheck, Vec<[Vec3; 3]>)> {
    for k in strides(u.len()) {
        if k == 1 {
            return check::run(u, f, settings);
        }
        let part = every(u, k);
        let Ok(g) = fit_unit(&part, f.model, settings) else {
            continue;
        };
        if !(g.identifiable && g.ellipsoid.passed) {
            continue;
        }
        if !same_sensor(&g, &f.p, f.bias) {
            continue;
        }
        let Some((c, errors)) = check::run(&part, &g, settings).filter(|c| c.0.passed()) else {
            continue;
        };
        // Per parameter, the ratio of the log's standard errors to the part's.
        let ratio = |whole: Option<Vec3>, part: Option<Vec3>| -> Option<Vec3> {
            let (whole, part) = (whole?, part?);
            Some(std::array::from_fn(|i| whole[i] / part[i]).map(|v: f64| if v.is_finite() { v } else { 0.0 }))
        };
        let Some(by) = (|| {
            let p = if f.model == FitModel::Full {
                ratio(f.std_psi_deg, g.std_psi_deg)?
            } else {
                [1.0; 3]
            };
            Some([p, ratio(f.std_scale, g.std_scale)?, ratio(f.std_bias, g.std_bias)?])
        })() else {
            return Some((
                TrialCheck {
                    rms_error: None,
                    every: k,
                    of: u.len(),
                    ..c
                },
                Vec::new(),
            ));
        };
        let scale =
            |e: &[Vec3; 3]| -> [Vec3; 3] { std::array::from_fn(|g| std::array::from_fn(|i| e[g][i] * by[g][i])) };
        return Some((
            TrialCheck {
                rms_error: c.rms_error.map(|e| scale(&e)),
                every: k,
                of: u.len(),
                ..c
            },
            errors.iter().map(scale).collect(),
        ));
    }
    None
}

/// Checks the inputs and moves the readings into their frame.
#[track_caller]
fn prepare(
    readings: &[Vec3],
    magnitude: f64,
    model: FitModel,
    settings: &FitSettings,
) -> Result<(Frame, Vec<Vec3>), CalibrationError> {
    for (name, v) in [("noise", settings.noise), ("truncation", settings.truncation)] {
        assert!(
            v.is_none_or(|v| v.is_finite() && v > 0.0),
            "FitSettings::{name} must be positive and finite"
        );
    }
    crate::calibration::validate_readings(readings, magnitude, model.parameters())?;
    Frame::of(readings)
}

/// `settings` in the frame's units.
fn unit_settings(frame: &Frame, settings: &FitSettings) -> FitSettings {
    FitSettings {
        noise: settings.noise.map(|s| s / frame.length),
        truncation: settings.truncation.map(|t| t / frame.length),
        ..settings.clone()
    }
}

/// [`fit`] of readings in a [`Frame`], to a unit field, without the check by trials.
fn fit_unit(u: &[Vec3], model: FitModel, settings: &FitSettings) -> Result<LogFit, CalibrationError> {
    let two_step = TwoStep {
        noise_nt: settings.noise,
        residual: settings.residual,
        stop: settings.stop.clone(),
        ..TwoStep::default()
    };
    let (p, bias, iterations, termination) = match (model, settings.residual) {
        (FitModel::Full, _) => {
            let c = two_step.calibrate(u, 1.0)?;
            let e = c.estimate();
            (e.p, e.bias_nt, c.iterations, c.termination)
        }
        (_, Residual::Paper) => reduced(u, 1.0, model, &two_step)?,
        (_, Residual::Readings) => reduced_readings(u, model, &two_step)?,
    };
    // Step 2's local check at the estimate is a first screen only: the statistics below judge
    // the fit, and a log's verdict is its check by trials (`check`).
    let status = match termination {
        Termination::Stopped => return Err(CalibrationError::Stopped),
        Termination::FlatDirection => CalibrationStatus::NotIdentifiable,
        t if t.converged() => CalibrationStatus::Ok,
        _ => CalibrationStatus::NotConverged,
    };
    let k = crate::small::upper_triangular_inverse(&p).ok_or(CalibrationError::NotPositiveDefinite {
        reason: "estimated P is singular",
    })?;
    let mut errors = ErrorModel::from_k(&k, bias);
    if model != FitModel::Full {
        // Exactly zero where the model fixes them.
        errors = ErrorModel::new([0.0; 3], errors.scale(), bias).map_err(|_| out_of_range())?;
    } else if crate::small::upper_triangular_inverse(&errors.K()).is_none() {
        return Err(out_of_range());
    }
    let fields: Vec<Vec3> = u.par_iter().map(|&s| mat_vec(&p, sub(s, bias))).collect();
    let m = u.len();
    let residual = |b: &Vec3| norm(*b) - 1.0;
    let sum_sq: f64 = fields.iter().map(|b| residual(b).powi(2)).sum();
    let mut distances: Vec<f64> = fields.par_iter().map(|b| gain(&p, b)).collect();
    let mean_gain = distances.iter().sum::<f64>() / m as f64;
    // Each reading's distance from the ellipsoid to first order, `r / |P^T w|`, in place of its
    // gain.
    distances
        .par_iter_mut()
        .zip(&fields)
        .for_each(|(d, b)| *d = residual(b) / d.sqrt());
    let distance_sq: f64 = distances.iter().map(|d| d * d).sum();
    let dof = m - model.parameters();
    // Readings kept within K robust standard deviations scatter less than the sensor's noise by
    // the truncated normal's variance factor c; the kept fit's estimates scatter as sigma^2 / c
    // times the inverse information of the kept readings (the skipped M-estimator: E psi^2 /
    // (E psi')^2 with psi(x) = x 1{|x| <= K}, both terms c times the untruncated ones per kept
    // reading, but the expectation of psi' is c times that of psi^2 in units of sigma^2).
    let kept_scatter = (dof > 0)
        .then(|| match settings.residual {
            Residual::Paper => (sum_sq / (dof as f64 * mean_gain)).sqrt(),
            Residual::Readings => (distance_sq / dof as f64).sqrt(),
        })
        .filter(|v| v.is_finite());
    let estimated = match (kept_scatter, settings.truncation) {
        (Some(v), t) => {
            let value = t.map_or(v, |t| untruncated(v, t));
            Noise::Estimated {
                value,
                dof,
                interval95: chi_square_interval(value, dof),
            }
        }
        (None, _) => Noise::Unknown,
    };
    let factor = |sigma: f64| match settings.truncation {
        Some(t) if sigma > 0.0 => truncated_variance_factor(t / sigma),
        _ => 1.0,
    };
    // A given noise that does not explain the scatter (chi-square test at LACK_OF_FIT_LEVEL) is
    // not what the estimates scatter by: they rest on the scatter instead, and the words say so.
    let chi = settings
        .noise
        .filter(|_| dof > 0)
        .map(|s| chi_square_of(distance_sq / factor(s), s, dof));
    let noise = match (settings.noise, chi) {
        (Some(_), Some((p_value, _))) if p_value < LACK_OF_FIT_LEVEL && estimated != Noise::Unknown => estimated,
        (Some(s), _) => Noise::Given(s),
        (None, _) => estimated,
    };
    let c = noise.value().map_or(1.0, factor);
    let serial = match settings.order {
        Order::Unknown => None,
        _ if noise == Noise::Unknown => None,
        Order::Time => Some(Serial::of_residuals(&distances)),
        Order::Batch(batch) => Some(Serial { batch, lag_one: None }),
    };
    let quantile95 = match (noise, serial) {
        (Noise::Unknown, _) => None,
        (_, Some(s)) => Some(student_quantile(0.975, s.dof(m))),
        (Noise::Given(_), None) => Some(normal_quantile(0.975)),
        (Noise::Estimated { dof, .. }, None) => Some(student_quantile(0.975, dof)),
    };
    let converged = status == CalibrationStatus::Ok;
    let straight = match (converged, noise.value()) {
        // Readings on their ellipsoid to rounding (noise-free, synthetic) leave a cost that is
        // rounding too: nothing bends, and the rise would be rounding over rounding.
        (true, Some(sigma)) if settings.residual == Residual::Readings && settings.profile && sigma > 1e-9 => {
            judged_profile(u, model, settings, &two_step, (p, bias, sigma))
        }
        _ => None,
    };
    let basis = statistics::Basis {
        residual: settings.residual,
        noise: noise.value().map(|s| s / c.sqrt()),
        truncation_factor: c,
        serial,
        inflation: straight.map_or(1.0, |s| s.inflation()),
    };
    // The readings' distances from the ellipsoid against the radius of the sphere that best fits
    // them: the size of the cloud, which no fit can shrink (a fit that runs off into a flat or
    // long ellipsoid keeps its distances small while `|b| - R` grows). Two passes, side by side.
    let (judged, radius) = rayon::join(
        || statistics::judge(&errors, &fields, model, basis),
        || sphere(u).map_or(1.0, |s| s.1),
    );
    let bent = straight.filter(|s| s.rise < PROFILE_RISE_MIN);
    let ellipsoid = ellipsoid_test((distance_sq / m as f64).sqrt() / radius, chi.zip(settings.noise));
    let mut f = LogFit {
        model,
        residual: settings.residual,
        p,
        bias,
        errors,
        magnitude: 1.0,
        residual_rms: (sum_sq / m as f64).sqrt(),
        residual_max: fields.iter().fold(0.0_f64, |a, b| a.max(residual(b).abs())),
        noise,
        given_noise: settings.noise,
        std_psi_deg: judged.std_psi_deg,
        std_scale: judged.std_scale,
        std_bias: judged.std_bias,
        white_std: judged.white,
        serial_std: judged.serial,
        serial,
        quantile95,
        identifiable: judged.identifiable && converged && bent.is_none(),
        verdict: if let Some(b) = bent {
            b.words()
        } else if converged {
            judged.words
        } else {
            not_settled(&judged.words, &errors, status, iterations)
        },
        status,
        iterations,
        lack_of_fit: None,
        profile: straight,
        ellipsoid,
        check: None,
        trial_errors: Vec::new(),
        held_out: None,
        // Set from the standard errors below.
        std_source: [[StdSource::White; 3]; 3],
        heading: None,
        usable: false,
        reasons: Vec::new(),
    };
    f.std_source = f.sources_of_model();
    f.assess();
    Ok(f)
}

/// The least rise of a log's cost at 3 standard errors of an entry of `P` (the scale factors,
/// and for the full model the non-orthogonalities too), the other unknowns re-fitted
/// (`calibration::step2::profile_rise`).
// Serialize only: it names its parts with `&'static str`, which a reader cannot borrow for ever.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Profile {
    /// The rise, in units of the residuals' variance (a chi-square's): 9 for a straight problem.
    pub rise: f64,
    /// Along what: `scale of sensor axis x`, `non-orthogonality of axes x-y`, ...
    pub along: &'static str,
    /// The side: -1 toward a smaller entry of `P`, +1 toward a larger.
    pub side: f64,
    /// The readings it was measured on: a long log's, every `k`-th ([`JUDGED_READINGS`]).
    pub readings: usize,
}

/// Below this rise at 3 standard errors ([`Profile`]) the standard errors understate the
/// log's uncertainty by more than 1.5 (`3 / sqrt(4)`): the log does not determine that scale.
pub const PROFILE_RISE_MIN: f64 = 4.0;

impl Profile {
    /// The factor the standard errors are widened by: `3 / sqrt(rise)` where the rise is below
    /// the 9 of a straight problem (the half-width at which a parabola through the rise reaches
    /// the chi-square's 9), else 1.
    pub fn inflation(&self) -> f64 {
        if self.rise < 9.0 && self.rise > 0.0 {
            3.0 / self.rise.sqrt()
        } else {
            1.0
        }
    }

    /// The verdict of a rise below [`PROFILE_RISE_MIN`].
    pub fn words(&self) -> String {
        let how = if self.rise < 0.0 {
            format!("falls by {}", significant(-self.rise, 3))
        } else {
            format!("rises by only {}", significant(self.rise, 3))
        };
        format!(
            "not determined: the readings' cost {how} at 3 standard errors along the {} (it would rise by 9 were the problem straight, and at least {PROFILE_RISE_MIN} is needed): the standard errors at the estimate understate what the log leaves open",
            self.along
        )
    }
}

/// The [`Profile`] of the fit `(p, bias)` of `u` at the noise `sigma`, a long log's judged as its
/// check is ([`judged_check`]): on every `k`-th reading, the sparsest first, each part's own fit
/// profiled. A part stands for the whole where its fit is the whole log's sensor
/// ([`same_sensor`]) and its cost rises by at least [`STRAIGHT_RISE`]: a part's cost bends more
/// than the whole's (its standard errors are wider), so the whole log's standard errors are then
/// widened by at most 0.6 %, where they need less. Else the whole log's own profile: the shortfall
/// of a part's rise, scaled by the square root of the readings as a cubic term of the cost would
/// be, missed the whole log's by up to a factor of 4 in [P1]'s AUV box (test
/// `a_long_logs_profile_from_a_part_is_the_whole_logs`).
fn judged_profile(
    u: &[Vec3],
    model: FitModel,
    settings: &FitSettings,
    two_step: &TwoStep,
    (p, bias, sigma): (Mat3, Vec3, f64),
) -> Option<Profile> {
    for k in strides(u.len()) {
        if k == 1 {
            return profile(u, model, two_step, p, bias, sigma * sigma);
        }
        let part = every(u, k);
        let part_settings = FitSettings {
            profile: false,
            ..settings.clone()
        };
        let Ok(g) = fit_unit(&part, model, &part_settings) else {
            continue;
        };
        let Some(s) = g
            .noise
            .value()
            .filter(|s| g.status == CalibrationStatus::Ok && *s > 1e-9)
        else {
            continue;
        };
        if !same_sensor(&g, &p, bias) {
            continue;
        }
        if let Some(found) = profile(&part, model, two_step, g.p, g.bias, s * s).filter(|f| f.rise >= STRAIGHT_RISE) {
            return Some(found);
        }
    }
    None
}

/// The rise at 3 standard errors from which a part of a long log stands for the whole in its
/// [`Profile`] ([`judged_profile`]): its inflation of the standard errors, `3 / sqrt(8.9)`, is
/// 1.0056.
const STRAIGHT_RISE: f64 = 8.9;

/// Whether the fit `g` of a part of a log is the sensor `(p, bias)` fitted to the whole: each of
/// its estimates within 4 of its standard errors of the whole's (a log that does not determine
/// its sensor lets each part run off its own way).
fn same_sensor(g: &LogFit, p: &Mat3, bias: Vec3) -> bool {
    let Some(k) = crate::small::upper_triangular_inverse(p) else {
        return false;
    };
    let whole = ErrorModel::from_k(&k, bias);
    let near =
        |a: Vec3, b: Vec3, std: Option<Vec3>| std.is_some_and(|s| (0..3).all(|i| (a[i] - b[i]).abs() <= 4.0 * s[i]));
    (g.model != FitModel::Full || near(g.errors.psi_deg(), whole.psi_deg(), g.std_psi_deg))
        && near(g.errors.scale(), whole.scale(), g.std_scale)
        && near(g.bias, bias, g.std_bias)
}

/// The [`Profile`] of the fit `(p, bias)` of `u` (unit frame) under `model`, `var` the variance
/// of one residual.
fn profile(u: &[Vec3], model: FitModel, two_step: &TwoStep, p: Mat3, bias: Vec3, var: f64) -> Option<Profile> {
    let k = crate::small::upper_triangular_inverse(&p)?;
    let estimate = crate::calibration::Estimate {
        p,
        bias_nt: bias,
        model: ErrorModel::from_k(&k, bias),
        rms_residual_nt: f64::NAN,
    };
    let (rise, which, side) = match model {
        FitModel::Full => {
            let t: [[f64; 9]; 9] = std::array::from_fn(|i| std::array::from_fn(|j| f64::from(u8::from(i == j))));
            step2::profile_rise(two_step, &estimate, u, 1.0, &t, &[0, 3, 5, 1, 2, 4], var)?
        }
        FitModel::Diagonal => step2::profile_rise(two_step, &estimate, u, 1.0, &DIAGONAL_Y, &[0, 1, 2], var)?,
        FitModel::Offset => step2::profile_rise(two_step, &estimate, u, 1.0, &OFFSET_Y, &[0], var)?,
    };
    const FULL: [&str; 6] = [
        "scale of sensor axis x",
        "scale of sensor axis y",
        "scale of sensor axis z",
        "non-orthogonality of axes x-y",
        "non-orthogonality of axes x-z",
        "non-orthogonality of axes y-z",
    ];
    Some(Profile {
        readings: u.len(),
        rise,
        along: if model == FitModel::Offset {
            "common scale"
        } else {
            FULL[which]
        },
        side,
    })
}

/// The centred unknowns `y = (P11, P12, P13, P22, P23, P33, c)` of the diagonal model from its
/// own `(P11, P22, P33, c)`.
const DIAGONAL_Y: [[f64; 6]; 9] = [
    [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [0.0; 6],
    [0.0; 6],
    [0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
    [0.0; 6],
    [0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
];

/// The same for the offset model's `(p, c)`: `P = p I`.
const OFFSET_Y: [[f64; 4]; 9] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0; 4],
    [0.0; 4],
    [1.0, 0.0, 0.0, 0.0],
    [0.0; 4],
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// The standard errors of `f` (in its frame: a unit field) beyond the physical scales (10
/// degrees, half the scale factor, the field), in words; `None` where within.
fn beyond_scales(f: &LogFit) -> Option<String> {
    let scales = crate::PhysicalScales::default();
    let (p, s, o) = (f.std_psi_deg?, f.std_scale?, f.std_bias?);
    let axes = ["x", "y", "z"];
    let mut over = Vec::new();
    for i in 0..3 {
        if p[i] > scales.psi_deg {
            over.push(format!("10 degrees for psi{}", i + 1));
        }
        if s[i] > scales.scale_fraction * f.errors.scale()[i] {
            over.push(format!("half the scale factor of axis {}", axes[i]));
        }
        if o[i] > scales.bias_fraction_of_field * f.magnitude {
            over.push(format!("the field for the bias of axis {}", axes[i]));
        }
    }
    (!over.is_empty()).then(|| over.join(", "))
}

/// `|P^T w|^2`, `w = b / |b|`: the squared gradient of `|P (s - O)|` with respect to the reading
/// at the calibrated field `b` (a reading at the bias has no direction; any one gives its order).
fn gain(p: &Mat3, b: &Vec3) -> f64 {
    let n = norm(*b);
    let w = if n > 0.0 { b.map(|v| v / n) } else { [1.0, 0.0, 0.0] };
    let g = mat_t_vec(p, w);
    g.iter().map(|v| v * v).sum::<f64>()
}

/// The verdict of a fit that does not settle: it runs along a direction the log does not
/// determine, which the bound at where it stopped names.
fn not_settled(words: &str, errors: &ErrorModel, status: CalibrationStatus, iterations: usize) -> String {
    let along = words
        .trim_start_matches("identifiable; ")
        .trim_start_matches("not determined: ")
        .trim_start_matches("weakest: ")
        .to_string();
    let s = errors.scale();
    let mean = ((s[0].ln() + s[1].ln() + s[2].ln()) / 3.0).exp();
    format!(
        "not determined: the fit does not settle ({} after {iterations} iterations, relative scale factors {}, {}, {}); it runs along: {along}",
        status.as_str(),
        significant(s[0] / mean, 4),
        significant(s[1] / mean, 4),
        significant(s[2] / mean, 4),
    )
}

/// The chi-square test of a scatter: the readings' squared distances from the ellipsoid `q`
/// against the noise `sigma` with `dof` degrees of freedom: `(P(chi2 >= q / sigma^2), sqrt(q /
/// dof))`.
fn chi_square_of(q: f64, sigma: f64, dof: usize) -> (f64, f64) {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    let stat = q / (sigma * sigma);
    let p = ChiSquared::new(dof as f64).map_or(f64::NAN, |d| d.sf(stat));
    (p, (q / dof as f64).sqrt())
}

/// The noise `sigma` of a normal whose sample truncated at `+-half_width` scatters as `kept`:
/// the fixed point of `sigma = kept / sqrt(c(half_width / sigma))` ([`truncated_variance_factor`]),
/// from `sigma = kept` (an increasing sequence; 100 steps at most, a relative change of 1e-12
/// ends it). Solving for the truncation in units of the noise, rather than taking it as the K of
/// the rejection, accounts for the robust spread that set it being an estimate itself.
fn untruncated(kept: f64, half_width: f64) -> f64 {
    let mut sigma = kept;
    for _ in 0..100 {
        let c = truncated_variance_factor(half_width / sigma);
        if c <= 0.0 {
            break;
        }
        let next = kept / c.sqrt();
        let done = (next - sigma).abs() <= 1e-12 * next;
        sigma = next;
        if done {
            break;
        }
    }
    sigma
}

/// The ellipsoid test of a fit whose readings lie at an rms distance `rms` from the fitted
/// ellipsoid (in units of the radius of the sphere that best fits them) and, with a
/// given noise, its chi-square test `((p, distance rms), sigma)`. Only the residual's size
/// decides: a scatter the given noise does not explain moves the standard errors onto the
/// scatter (`fit_unit`), and is said here, but is no rejection (a log of one sensor at exactly
/// the given noise is rejected by that test at its level, 1e-3, and a real log's errors beyond
/// white noise are not a second ellipsoid).
fn ellipsoid_test(rms: f64, chi: Option<((f64, f64), f64)>) -> EllipsoidTest {
    let residual_percent = 100.0 * rms;
    let within = residual_percent <= ELLIPSOID_LIMIT_PERCENT;
    let pct = significant(residual_percent, 4);
    let mut words = if within {
        format!("distance rms {pct} % of the readings' radius (limit {ELLIPSOID_LIMIT_PERCENT} %)")
    } else {
        format!(
            "the readings do not lie on an ellipsoid: their distance from it has an rms of {pct} % of their radius, above the limit of {ELLIPSOID_LIMIT_PERCENT} %"
        )
    };
    if let Some(((p, scatter), sigma)) = chi {
        let ratio = significant(scatter / sigma, 4);
        words.push_str(&if p >= LACK_OF_FIT_LEVEL {
            format!("; the given noise explains the scatter (distance rms {ratio} times the noise, chi-square p {})", lack_of_fit::show_p(p))
        } else {
            format!("; the readings scatter about the ellipsoid {ratio} times the given noise (chi-square p {}): the log's errors are larger than the given noise, and the standard errors rest on its scatter", lack_of_fit::show_p(p))
        });
    }
    EllipsoidTest {
        residual_percent,
        chi_square_p: chi.map(|c| c.0.0),
        passed: within,
        words,
    }
}

/// The 95 % interval of a noise `value` estimated with `dof` degrees of freedom:
/// `value sqrt(dof / chi2_q)` at `q` = 0.975 and 0.025.
pub(crate) fn chi_square_interval(value: f64, dof: usize) -> (f64, f64) {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    if value == 0.0 {
        // Noise-free readings: nothing scatters, whatever the quantiles.
        return (0.0, 0.0);
    }
    match ChiSquared::new(dof as f64) {
        Ok(d) => {
            let n = dof as f64;
            (
                value * (n / d.inverse_cdf(0.975)).sqrt(),
                value * (n / d.inverse_cdf(0.025)).sqrt(),
            )
        }
        Err(_) => (f64::NAN, f64::NAN),
    }
}

/// The standard normal quantile of `q`.
fn normal_quantile(q: f64) -> f64 {
    use statrs::distribution::{ContinuousCDF, Normal};
    Normal::standard().inverse_cdf(q)
}

/// Student's `t` quantile of `q` with `dof` degrees of freedom.
pub(crate) fn student_quantile(q: f64, dof: usize) -> f64 {
    use statrs::distribution::{ContinuousCDF, StudentsT};
    StudentsT::new(0.0, 1.0, dof as f64).map_or(f64::NAN, |d| d.inverse_cdf(q))
}

/// [`fit_with`], and for a reduced model its lack-of-fit test against the richer models (which
/// are fitted for it; one that fails is left out), added to the verdict when the log rejects it.
///
/// # Errors
/// As [`fit`] for `model`.
///
/// # Panics
/// As [`fit_with`].
#[track_caller]
pub fn fit_tested(
    readings: &[Vec3],
    magnitude: f64,
    model: FitModel,
    settings: &FitSettings,
) -> Result<LogFit, CalibrationError> {
    let (frame, u) = prepare(readings, magnitude, model, settings)?;
    let unit = unit_settings(&frame, settings);
    let tested = fit_unit(&u, model, &unit).and_then(|f| {
        let richer: Vec<LogFit> = [FitModel::Full, FitModel::Diagonal]
            .into_iter()
            .filter(|r| r.parameters() > model.parameters() && u.len() >= r.parameters())
            .filter_map(|r| fit_unit(&u, r, &unit).ok())
            .collect();
        let f = checked(f, &u, &unit);
        with_test(f, &richer.iter().collect::<Vec<_>>(), &u, &unit.stop).out_of_frame(&frame, magnitude)
    });
    unless_stopped(settings, tested)
}

/// `f` with its lack-of-fit test against `richer`, the verdict extended when the log rejects it;
/// the test's fits ask `stop`.
fn with_test(mut f: LogFit, richer: &[&LogFit], readings: &[Vec3], stop: &Stop) -> LogFit {
    // A fit the log does not determine is no hypothesis to test: its verdict says so already.
    if !f.identifiable {
        return f;
    }
    f.lack_of_fit = LackOfFit::test_until(&f, richer, readings, stop);
    if let Some(t) = f.lack_of_fit.as_ref().filter(|t| t.rejected) {
        f.verdict = format!("{}; but {}", f.verdict, t.words());
    }
    f.assess();
    f
}

/// One step of [`fit_auto`]'s choice of model; its `Display` is the step in words
/// (`full: not identifiable (...)`, `offset but rejected by the log (lack-of-fit p ... against
/// full)`).
// Serialize only: it names its parts with `&'static str`, which a reader cannot borrow for ever.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[non_exhaustive]
pub enum AutoReason {
    /// The log has fewer readings than `model` has parameters.
    TooFewReadings {
        /// The model not fitted.
        model: FitModel,
        /// The readings of the log.
        readings: usize,
    },
    /// `model`'s fit is identifiable: the choice.
    Identifiable(FitModel),
    /// `model`'s fit is not identifiable, for the reason of its verdict ([`LogFit::verdict`]).
    NotIdentifiable {
        /// The model fitted.
        model: FitModel,
        /// The fit's verdict.
        verdict: String,
    },
    /// `model`'s fit is identifiable but fails its check by trials ([`TrialCheck`]).
    FailsCheck {
        /// The model fitted.
        model: FitModel,
        /// The check in words.
        words: String,
    },
    /// The last model, returned although its fit is not identifiable (or fails its check)
    /// either.
    NoneIdentifiable(FitModel),
    /// `model` has no fit.
    Failed {
        /// The model tried.
        model: FitModel,
        /// Why it has no fit.
        error: CalibrationError,
    },
    /// The chosen reduced model's lack-of-fit test tests nothing: no richer fit comes closer to
    /// the readings (`F = 0`).
    Untested(FitModel),
    /// The chosen reduced model's lack-of-fit test ([`LogFit::lack_of_fit`]).
    Tested {
        /// The model chosen.
        model: FitModel,
        /// Its test against the richer models.
        test: LackOfFit,
    },
}

impl std::fmt::Display for AutoReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::TooFewReadings { model, readings } => write!(
                f,
                "{}: {readings} readings, at least {} are needed",
                model.as_str(),
                model.parameters()
            ),
            Self::Identifiable(model) => write!(f, "{}: identifiable", model.as_str()),
            Self::NotIdentifiable { model, verdict } => write!(f, "{}: not identifiable ({verdict})", model.as_str()),
            Self::FailsCheck { model, words } => {
                write!(
                    f,
                    "{}: identifiable, but fails its check by trials ({words})",
                    model.as_str()
                )
            }
            Self::NoneIdentifiable(model) => write!(f, "{}: not usable either", model.as_str()),
            Self::Failed { model, error } => write!(f, "{}: {error}", model.as_str()),
            Self::Untested(model) => write!(
                f,
                "{}: untested, no richer fit comes closer to the readings",
                model.as_str()
            ),
            Self::Tested { model, test } => write!(
                f,
                "{} {} by the log (lack-of-fit p {} against {})",
                model.as_str(),
                if test.rejected { "but rejected" } else { "not rejected" },
                lack_of_fit::show_p(test.p_value),
                test.against.as_str()
            ),
        }
    }
}

/// The richest model this log identifies: full, else diagonal, else offset (the offset fit is
/// returned, not identifiable, when none is), with the reasons, one per model tried, and the
/// chosen reduced model's lack-of-fit test against the richer fits ([`fit_tested`]).
///
/// # Errors
/// As [`fit`], for the offset model (the others failing only moves on to the next).
///
/// # Panics
/// As [`fit_with`].
#[track_caller]
pub fn fit_auto(
    readings: &[Vec3],
    magnitude: f64,
    settings: &FitSettings,
) -> Result<(LogFit, Vec<AutoReason>), CalibrationError> {
    unless_stopped(settings, auto(readings, magnitude, settings))
}

/// [`fit_auto`], cut short where the settings' stop is requested.
#[track_caller]
fn auto(
    readings: &[Vec3],
    magnitude: f64,
    settings: &FitSettings,
) -> Result<(LogFit, Vec<AutoReason>), CalibrationError> {
    let (frame, u) = prepare(readings, magnitude, FitModel::Offset, settings)?;
    let unit = unit_settings(&frame, settings);
    let mut reasons = Vec::new();
    let mut richer: Vec<LogFit> = Vec::new();
    for model in [FitModel::Full, FitModel::Diagonal] {
        if u.len() < model.parameters() {
            reasons.push(AutoReason::TooFewReadings {
                model,
                readings: u.len(),
            });
            continue;
        }
        match fit_unit(&u, model, &unit) {
            Ok(f) if f.identifiable => {
                let f = checked(f, &u, &unit);
                if let Some(c) = f.check.filter(|c| !c.passed()) {
                    reasons.push(AutoReason::FailsCheck {
                        model,
                        words: c.words(),
                    });
                    richer.push(f);
                    continue;
                }
                reasons.push(AutoReason::Identifiable(model));
                let f = with_test(f, &richer.iter().collect::<Vec<_>>(), &u, &unit.stop);
                push_test(&mut reasons, &f);
                return Ok((f.out_of_frame(&frame, magnitude)?, reasons));
            }
            Ok(f) => {
                reasons.push(AutoReason::NotIdentifiable {
                    model,
                    verdict: f.verdict.clone(),
                });
                richer.push(f);
            }
            Err(error) => reasons.push(AutoReason::Failed { model, error }),
        }
    }
    let f = fit_unit(&u, FitModel::Offset, &unit)?;
    let f = if f.identifiable { checked(f, &u, &unit) } else { f };
    reasons.push(if f.identifiable && f.check.is_none_or(|c| c.passed()) {
        AutoReason::Identifiable(FitModel::Offset)
    } else {
        AutoReason::NoneIdentifiable(FitModel::Offset)
    });
    let f = with_test(f, &richer.iter().collect::<Vec<_>>(), &u, &unit.stop);
    push_test(&mut reasons, &f);
    Ok((f.out_of_frame(&frame, magnitude)?, reasons))
}

/// Ends the reasons of [`fit_auto`] with the chosen model's lack-of-fit test, where it has one.
fn push_test(reasons: &mut Vec<AutoReason>, chosen: &LogFit) {
    if let Some(t) = &chosen.lack_of_fit {
        reasons.push(if t.f == 0.0 {
            AutoReason::Untested(chosen.model)
        } else {
            AutoReason::Tested {
                model: chosen.model,
                test: t.clone(),
            }
        });
    }
}

/// The reduced models by Levenberg-Marquardt from a sphere fit, in units scaled by the sphere's
/// radius: `x = (p_1, p_2, p_3, o)` (diagonal) or `(p, o)` (offset), residual `|P (u - o)| - R'`.
fn reduced(
    readings: &[Vec3],
    magnitude: f64,
    model: FitModel,
    settings: &TwoStep,
) -> Result<(Mat3, Vec3, usize, Termination), CalibrationError> {
    let (centre, radius) = sphere(readings)?;
    let u: Vec<Vec3> = readings.iter().map(|s| sub(*s, centre).map(|v| v / radius)).collect();
    let target = magnitude / radius;
    // In scaled units the sphere is (u - 0) with |u| = 1: start from P = target I, o = 0.
    let (x, iterations, converged) = match model {
        FitModel::Diagonal => {
            let (x, it, ok) =
                levenberg_marquardt([target, target, target, 0.0, 0.0, 0.0], &u, target, settings, |x, u| {
                    let d = [u[0] - x[3], u[1] - x[4], u[2] - x[5]];
                    let v = [x[0] * d[0], x[1] * d[1], x[2] * d[2]];
                    let n = norm(v);
                    let w = v.map(|c| c / n);
                    (
                        n,
                        [
                            w[0] * d[0],
                            w[1] * d[1],
                            w[2] * d[2],
                            -w[0] * x[0],
                            -w[1] * x[1],
                            -w[2] * x[2],
                        ],
                    )
                });
            (x.to_vec(), it, ok)
        }
        _ => {
            let (x, it, ok) = levenberg_marquardt([target, 0.0, 0.0, 0.0], &u, target, settings, |x, u| {
                let d = [u[0] - x[1], u[1] - x[2], u[2] - x[3]];
                let n = norm(d);
                let w = d.map(|c| c / n);
                (
                    x[0].abs() * n,
                    [
                        x[0].signum() * n,
                        -x[0].abs() * w[0],
                        -x[0].abs() * w[1],
                        -x[0].abs() * w[2],
                    ],
                )
            });
            (vec![x[0].abs(), x[0].abs(), x[0].abs(), x[1], x[2], x[3]], it, ok)
        }
    };
    // diag(x) (u - o) = diag(x) (s - bias) / radius has magnitude R / radius: P = diag(x).
    let p = [[x[0].abs(), 0.0, 0.0], [0.0, x[1].abs(), 0.0], [0.0, 0.0, x[2].abs()]];
    let bias = [0, 1, 2].map(|i| centre[i] + radius * x[3 + i]);
    Ok((p, bias, iterations, converged))
}

/// The reduced models by step 2 on the readings' residual ([`step2::refine_linear`]) from a
/// sphere fit: `P` diagonal (diagonal) or `p I` (offset), and the bias.
fn reduced_readings(
    u: &[Vec3],
    model: FitModel,
    settings: &TwoStep,
) -> Result<(Mat3, Vec3, usize, Termination), CalibrationError> {
    let (centre, radius) = sphere(u)?;
    let p0 = [
        [1.0 / radius, 0.0, 0.0],
        [0.0, 1.0 / radius, 0.0],
        [0.0, 0.0, 1.0 / radius],
    ];
    let start = crate::calibration::Estimate {
        p: p0,
        bias_nt: centre,
        model: ErrorModel::from_k(&[[radius, 0.0, 0.0], [0.0, radius, 0.0], [0.0, 0.0, radius]], centre),
        rms_residual_nt: f64::NAN,
    };
    // The centred unknowns y = (P11, P12, P13, P22, P23, P33, c) from the model's own.
    let refined = match model {
        FitModel::Diagonal => step2::refine_linear(settings, &start, u, 1.0, &DIAGONAL_Y)?,
        _ => step2::refine_linear(settings, &start, u, 1.0, &OFFSET_Y)?,
    };
    let e = refined.estimate;
    Ok((e.p, e.bias_nt, refined.iterations, refined.termination))
}

/// The radius of the sphere that best fits the readings (the linear fit `|s|^2 = 2 c . s + k`),
/// `None` when none does.
pub fn sphere_radius(readings: &[Vec3]) -> Option<f64> {
    sphere(readings).ok().map(|s| s.1)
}

/// The sphere `|s - c|^2 = r^2` through the readings in the least-squares sense of the linear
/// model `|s|^2 = 2 c . s + k`, `k = r^2 - |c|^2` (about the readings' mean, for conditioning).
fn sphere(readings: &[Vec3]) -> Result<(Vec3, f64), CalibrationError> {
    let m = readings.len() as f64;
    let mean = [0, 1, 2].map(|i| readings.iter().map(|s| s[i]).sum::<f64>() / m);
    let spread = readings.iter().map(|s| norm(sub(*s, mean))).sum::<f64>() / m;
    if !(spread > 0.0 && spread.is_finite()) {
        return Err(CalibrationError::RankDeficient { rank: 0, needed: 4 });
    }
    let mut A = [[0.0; 4]; 4];
    let mut y = [0.0; 4];
    for s in readings {
        let d = sub(*s, mean).map(|v| v / spread);
        let row = [2.0 * d[0], 2.0 * d[1], 2.0 * d[2], 1.0];
        let rhs = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        for i in 0..4 {
            y[i] += row[i] * rhs;
            for j in 0..4 {
                A[i][j] += row[i] * row[j];
            }
        }
    }
    let scale = (0..4).map(|i| A[i][i]).fold(0.0_f64, f64::max);
    let mut L = A;
    if !cholesky_in_place(&mut L) || (0..4).any(|i| L[i][i] * L[i][i] <= 1e-12 * scale) {
        return Err(CalibrationError::RankDeficient { rank: 3, needed: 4 });
    }
    let t = cholesky_solve(&L, &y);
    let c = [t[0], t[1], t[2]];
    let r2 = t[3] + c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
    if r2.is_nan() || r2 <= 0.0 {
        return Err(CalibrationError::NotPositiveDefinite {
            reason: "no sphere fits the readings",
        });
    }
    Ok(([0, 1, 2].map(|i| mean[i] + spread * c[i]), spread * r2.sqrt()))
}

/// Levenberg-Marquardt ([`crate::calibration::step2::levenberg_marquardt`], the loop of step 2) on
/// `sum ((rho(x, u_i) - target) / target)^2 / 2` with `rho` and its gradient from `model`.
/// Returns the parameters, the iterations that took or refused a step (one that stops on a
/// negligible step is not counted, as step 2 counts it) and why it stopped.
fn levenberg_marquardt<const N: usize>(
    x: [f64; N],
    u: &[Vec3],
    target: f64,
    settings: &TwoStep,
    model: impl Fn(&[f64; N], Vec3) -> (f64, [f64; N]) + Sync,
) -> ([f64; N], usize, Termination) {
    let cost = |x: &[f64; N]| {
        0.5 * crate::chunked::sum(u, |&ui| {
            let r = (model(x, ui).0 - target) / target;
            r * r
        })
    };
    let normal = |x: &[f64; N]| {
        crate::chunked::normal_equations(u, |&ui| {
            let (rho, grad) = model(x, ui);
            ((rho - target) / target, grad.map(|g| g / target))
        })
    };
    let fit = crate::calibration::step2::levenberg_marquardt(settings, x, cost, normal, |_, _, _| None, false);
    let iterations = match fit.termination {
        Termination::StepSize => fit.iterations - 1,
        _ => fit.iterations,
    };
    (fit.x, iterations, fit.termination)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::sources;
    use crate::paper;
    use crate::rng::stream_rng;

    /// Noisy readings of `truth` at `n` random attitudes of `bounds`, in Gauss (nT / 1e5).
    fn log(truth: &ErrorModel, bounds: &crate::AttitudeBox, n: usize, sigma_nt: f64, seed: u64) -> Vec<Vec3> {
        let mut rng = stream_rng(seed, 0);
        let field = paper::changsha_field();
        let design = sources::random(bounds, n, &mut rng);
        truth
            .noisy_readings(&field.body_fields(&design), sigma_nt, &mut rng)
            .unwrap()
            .into_iter()
            .map(|s| s.map(|v| v / 1e5))
            .collect()
    }

    /// A stop that is never requested leaves every number of a fit as it is; one requested at
    /// any question (before the first iteration, inside the fit, its profile, its trials or its
    /// held-out folds, or at the last look before it returns) makes it no fit. The questions are
    /// counted on the full fit of 300 readings over every attitude, its check and folds included.
    #[test]
    fn a_fit_stopped_at_any_step_is_no_fit() {
        use std::sync::Arc;
        use std::sync::atomic::{AtomicUsize, Ordering};
        let readings = log(&paper::true_error_model(), &crate::AttitudeBox::full(), 300, 30.0, 21);
        let field = paper::changsha_field().magnitude() / 1e5;
        let json = |f: &LogFit| serde_json::to_string(f).unwrap();
        let plain = fit_tested(&readings, field, FitModel::Full, &FitSettings::default()).unwrap();
        assert!(
            plain.usable && plain.check.is_some() && plain.held_out.is_some(),
            "{:?}",
            plain.reasons
        );
        // Requested after `k` questions: it stays requested from then on, as a stop must.
        let after = |k: usize| {
            let asked = Arc::new(AtomicUsize::new(0));
            let counter = Arc::clone(&asked);
            let settings = FitSettings {
                stop: Stop::when(move || counter.fetch_add(1, Ordering::Relaxed) >= k),
                ..FitSettings::default()
            };
            let fitted = fit_tested(&readings, field, FitModel::Full, &settings);
            (fitted, asked.load(Ordering::Relaxed))
        };
        let (never, questions) = after(usize::MAX);
        assert_eq!(json(&never.unwrap()), json(&plain));
        // Every iteration of the fit, of its profile's six refits and of each of 200 trials and
        // five folds asks once.
        assert!(questions > 1000, "{questions}");
        for k in [0, 1, questions / 3, 2 * questions / 3, questions - 1] {
            assert_eq!(
                after(k).0.unwrap_err(),
                CalibrationError::Stopped,
                "requested after {k} of {questions}"
            );
        }
        assert_eq!(json(&after(questions).0.unwrap()), json(&plain));
        // The automatic choice of model says the same.
        let stopped = FitSettings {
            stop: Stop::when(|| true),
            ..FitSettings::default()
        };
        assert_eq!(
            fit_auto(&readings, field, &stopped).unwrap_err(),
            CalibrationError::Stopped
        );
        assert_eq!(CalibrationError::Stopped.status(), CalibrationStatus::NotConverged);
    }

    /// A long log's profile is a part's where the part's is straight, and the whole log's own
    /// where the cost bends: logs of 40,000 readings over every attitude at 30 nT (a part
    /// stands for the whole, within 0.05 of its rise), and in [P1]'s AUV box, a cap of the sphere,
    /// at 300 to 3000 nT (the whole bends by 0.3 to 2.8 at 3 standard errors; its parts by more).
    #[test]
    fn a_long_logs_profile_from_a_part_is_the_whole_logs() {
        let field = paper::changsha_field().magnitude() / 1e5;
        let truth = paper::true_error_model();
        for (bounds, sigma, seed, straight) in [
            (crate::AttitudeBox::full(), 30.0, 10, true),
            (paper::auv_box(), 300.0, 11, false),
            (paper::auv_box(), 1000.0, 12, false),
            (paper::auv_box(), 3000.0, 13, false),
        ] {
            let readings = log(&truth, &bounds, 40_000, sigma, seed);
            let settings = FitSettings::default();
            let (frame, u) = prepare(&readings, field, FitModel::Full, &settings).unwrap();
            let unit = FitSettings {
                trials: 0,
                held_out: false,
                ..unit_settings(&frame, &settings)
            };
            let f = fit_unit(&u, FitModel::Full, &unit).unwrap();
            let judged = f.profile.unwrap();
            let two_step = TwoStep {
                noise_nt: unit.noise,
                residual: unit.residual,
                ..TwoStep::default()
            };
            let var = f.noise.value().unwrap().powi(2);
            let whole = profile(&u, FitModel::Full, &two_step, f.p, f.bias, var).unwrap();
            if straight {
                assert!(judged.readings < u.len() && judged.rise >= STRAIGHT_RISE, "{judged:?}");
                assert!((judged.rise - whole.rise).abs() < 0.05, "{judged:?} {whole:?}");
            } else {
                assert!(whole.rise < STRAIGHT_RISE, "{sigma}: {whole:?}");
                assert_eq!(judged, whole, "{sigma}");
            }
        }
    }

    /// A long log judged on every `k`-th reading gives the errors the whole log's own trials
    /// give: each rms error scaled from the part within 0.3 of the whole's (200 trials each, a
    /// relative standard error of 5 % apiece: 4 standard errors of their ratio) for white noise,
    /// and each standard error widened by them for noise correlated in time (AR(1), 0.9 from one
    /// reading to the next).
    #[test]
    fn a_long_log_judged_on_a_part_gives_the_whole_logs_errors() {
        use rand_distr::{Distribution, StandardNormal};
        let field = paper::changsha_field().magnitude() / 1e5;
        let truth = paper::true_error_model();
        let n = 30_000;
        let white = log(&truth, &crate::AttitudeBox::full(), n, 30.0, 5);
        let mut rng = stream_rng(6, 0);
        let mut state = [0.0; 3];
        let phi: f64 = 0.9;
        let correlated: Vec<Vec3> = log(&truth, &crate::AttitudeBox::full(), n, 0.0, 5)
            .into_iter()
            .map(|c| {
                for s in state.iter_mut() {
                    let e: f64 = StandardNormal.sample(&mut rng);
                    *s = phi * *s + (1.0 - phi * phi).sqrt() * 30.0 / 1e5 * e;
                }
                crate::small::add(c, state)
            })
            .collect();
        for (readings, order) in [(white, Order::Unknown), (correlated, Order::Time)] {
            let settings = FitSettings {
                order,
                ..FitSettings::default()
            };
            let (frame, u) = prepare(&readings, field, FitModel::Full, &settings).unwrap();
            let unit = unit_settings(&frame, &settings);
            let f = fit_unit(&u, FitModel::Full, &unit).unwrap();
            let part = judged_check(&f, &u, &unit).unwrap().0;
            let whole = check::run(&u, &f, &unit).unwrap().0;
            assert!(
                part.every > 1 && part.readings <= JUDGED_READINGS && part.of == n,
                "{part:?}"
            );
            assert!(part.passed() && whole.passed(), "{} / {}", part.words(), whole.words());
            let (a, b) = (part.rms_error.unwrap(), whole.rms_error.unwrap());
            let std = [f.std_psi_deg.unwrap(), f.std_scale.unwrap(), f.std_bias.unwrap()];
            for g in 0..3 {
                for i in 0..3 {
                    // White noise: the trials themselves agree. Noise correlated in time: the
                    // trials resample the residuals' normal component, which the attitudes'
                    // turns leave nearly white (lag-one correlation -0.003 here), so neither
                    // set of trials carries the correlation the bias sees (its standard error
                    // from the batch means is 2.6 times the white one); what a user reads, the
                    // standard error never below the trials' rms, agrees.
                    let ratio = match order {
                        Order::Unknown => a[g][i] / b[g][i],
                        _ => std[g][i].max(a[g][i]) / std[g][i].max(b[g][i]),
                    };
                    assert!((ratio - 1.0).abs() < 0.3, "{order:?} group {g} axis {i}: {ratio}");
                }
            }
        }
    }

    #[test]
    fn every_model_recovers_a_sensor_it_can_describe() {
        let field = paper::changsha_field().magnitude() / 1e5;
        let full = crate::AttitudeBox::full();
        for (model, truth) in [
            (FitModel::Full, paper::true_error_model()),
            (
                FitModel::Diagonal,
                ErrorModel::new([0.0; 3], [1.3, 0.7, 1.2], [3000.0, -6000.0, 5000.0]).unwrap(),
            ),
            (
                FitModel::Offset,
                ErrorModel::new([0.0; 3], [1.1; 3], [3000.0, -6000.0, 5000.0]).unwrap(),
            ),
        ] {
            let readings = log(&truth, &full, 2000, 30.0, 3);
            let f = fit(&readings, field, model).unwrap();
            assert!(f.identifiable, "{model:?}: {}", f.verdict);
            // Within 5 standard errors of the truth, each parameter.
            let (ss, sb) = (f.std_scale.unwrap(), f.std_bias.unwrap());
            for i in 0..3 {
                assert!(
                    (f.errors.scale()[i] - truth.scale()[i]).abs() <= 5.0 * ss[i],
                    "{model:?} S{i}"
                );
                assert!(
                    (f.bias[i] - truth.bias_nt()[i] / 1e5).abs() <= 5.0 * sb[i],
                    "{model:?} O{i}"
                );
            }
            // The noise estimate: 30 nT = 3e-4 G, within 10 %.
            let noise = f.noise.value().unwrap();
            assert!((noise / 3e-4 - 1.0).abs() < 0.1, "{model:?}: {noise}");
        }
    }

    /// 400 logs of 300 readings at 30 nT of `truth`, in `bounds`, fitted with `model` and tested:
    /// the p-values of the identifiable fits.
    fn lack_of_fit_p_values(truth: &ErrorModel, bounds: &crate::AttitudeBox, model: FitModel) -> Vec<f64> {
        use rayon::prelude::*;
        let field = paper::changsha_field().magnitude() / 1e5;
        // The p-value does not depend on the check by trials, which is left out.
        let settings = FitSettings {
            trials: 0,
            held_out: false,
            ..FitSettings::default()
        };
        (0..400)
            .into_par_iter()
            .filter_map(|seed| {
                let f = fit_tested(&log(truth, bounds, 300, 30.0, 1000 + seed), field, model, &settings).unwrap();
                f.lack_of_fit.map(|t| t.p_value)
            })
            .collect()
    }

    #[test]
    fn the_lack_of_fit_test_holds_its_level_when_the_reduced_model_is_true() {
        // A sensor with psi = 0 and unequal scale factors, fitted diagonal: p is uniform, so the
        // share below 0.05 and 0.5 lies within 3 binomial standard errors of 0.05 and 0.5
        // (sqrt(0.05 0.95 / 400) = 0.011, sqrt(0.25 / 400) = 0.025). Measured: 0.050, 0.493.
        // Both models are taken at their least distance sums: the sum of the diagonal fit itself
        // (least calibrated residuals) left 0.57 below 0.5, its drop inflated by the difference
        // of the two objectives; in calibrated units the runaway fits of the AUV's box gave 0.16
        // below 0.05.
        let diagonal = ErrorModel::new([0.0; 3], [1.3, 0.7, 1.2], [3000.0, -6000.0, 5000.0]).unwrap();
        let p = lack_of_fit_p_values(&diagonal, &crate::AttitudeBox::full(), FitModel::Diagonal);
        assert_eq!(p.len(), 400, "every fit identifiable");
        let share = |a: f64| p.iter().filter(|&&x| x < a).count() as f64 / p.len() as f64;
        assert!((share(0.05) - 0.05).abs() <= 3.0 * 0.0109, "{}", share(0.05));
        assert!((share(0.5) - 0.5).abs() <= 3.0 * 0.025, "{}", share(0.5));
        // A common scale in the AUV's box (two tests, Bonferroni: at most the level). Measured:
        // 0.040 below 0.05.
        let offset = ErrorModel::new([0.0; 3], [1.1; 3], [3000.0, -6000.0, 5000.0]).unwrap();
        let p = lack_of_fit_p_values(&offset, &paper::auv_box(), FitModel::Offset);
        assert_eq!(p.len(), 400, "every fit identifiable");
        let share = p.iter().filter(|&&x| x < 0.05).count() as f64 / p.len() as f64;
        assert!(share <= 0.05 + 3.0 * 0.0109, "{share}");
    }

    #[test]
    fn the_lack_of_fit_test_rejects_a_model_that_leaves_out_what_the_sensor_has() {
        let field = paper::changsha_field().magnitude() / 1e5;
        // [P1]'s sensor (psi up to 1.5 degrees) fitted diagonal over every attitude: rejected by
        // the full model, and said so in the verdict.
        let readings = log(&paper::true_error_model(), &crate::AttitudeBox::full(), 300, 30.0, 5);
        let f = fit_tested(&readings, field, FitModel::Diagonal, &FitSettings::default()).unwrap();
        let t = f.lack_of_fit.clone().unwrap();
        assert!(f.identifiable && t.rejected && t.against == FitModel::Full, "{t:?}");
        assert_eq!(t.dof, (3, 291));
        assert!(f.verdict.contains("the log rejects this model"), "{}", f.verdict);
        // ... and auto, which takes the full model here, tests nothing.
        let (auto, why) = fit_auto(&readings, field, &FitSettings::default()).unwrap();
        assert!(auto.model == FitModel::Full && auto.lack_of_fit.is_none(), "{why:?}");
        assert_eq!(why, [AutoReason::Identifiable(FitModel::Full)]);
        // Unequal scale factors fitted with one common scale in the AUV's box: rejected.
        let diagonal = ErrorModel::new([0.0; 3], [1.3, 0.7, 1.2], [3000.0, -6000.0, 5000.0]).unwrap();
        let readings = log(&diagonal, &paper::auv_box(), 300, 30.0, 6);
        let f = fit_tested(&readings, field, FitModel::Offset, &FitSettings::default()).unwrap();
        assert!(
            f.identifiable && f.lack_of_fit.as_ref().unwrap().rejected,
            "{:?}",
            f.lack_of_fit
        );
        // Noise-free readings of a true model: the residual is rounding, never a rejection.
        let exact = log(&diagonal, &crate::AttitudeBox::full(), 50, 0.0, 7);
        let f = fit_tested(&exact, field, FitModel::Diagonal, &FitSettings::default()).unwrap();
        let t = f.lack_of_fit.unwrap();
        assert!(
            !t.rejected && t.f == 0.0 && (1.0 - t.p_value).abs() <= f64::EPSILON,
            "{t:?}"
        );
    }

    #[test]
    fn the_reasons_of_auto_read_as_the_json_and_the_table_print_them() {
        let test = |p_value, rejected| LackOfFit {
            against: FitModel::Full,
            f: 12.5,
            dof: (5, 291),
            p_value,
            rejected,
        };
        let cases = [
            (
                AutoReason::TooFewReadings {
                    model: FitModel::Full,
                    readings: 7,
                },
                "full: 7 readings, at least 9 are needed",
            ),
            (AutoReason::Identifiable(FitModel::Diagonal), "diagonal: identifiable"),
            (
                AutoReason::NotIdentifiable {
                    model: FitModel::Full,
                    verdict: "not determined: x (correlation 0.9)".into(),
                },
                "full: not identifiable (not determined: x (correlation 0.9))",
            ),
            (
                AutoReason::NoneIdentifiable(FitModel::Offset),
                "offset: not usable either",
            ),
            (
                AutoReason::Failed {
                    model: FitModel::Diagonal,
                    error: CalibrationError::RankDeficient { rank: 3, needed: 4 },
                },
                "diagonal: the regression matrix H has rank 3, 4 are needed (readings too alike)",
            ),
            (
                AutoReason::Untested(FitModel::Offset),
                "offset: untested, no richer fit comes closer to the readings",
            ),
            (
                AutoReason::Tested {
                    model: FitModel::Offset,
                    test: test(9.28e-261, true),
                },
                "offset but rejected by the log (lack-of-fit p = 9.28e-261 against full)",
            ),
            (
                AutoReason::Tested {
                    model: FitModel::Diagonal,
                    test: test(0.0, true),
                },
                "diagonal but rejected by the log (lack-of-fit p < 1e-300 against full)",
            ),
            (
                AutoReason::Tested {
                    model: FitModel::Diagonal,
                    test: test(0.25, false),
                },
                "diagonal not rejected by the log (lack-of-fit p = 2.50e-1 against full)",
            ),
        ];
        for (reason, words) in cases {
            assert_eq!(reason.to_string(), words);
        }
    }

    #[test]
    fn a_small_cap_calibrates_by_the_readings_residual_and_runs_off_by_the_papers() {
        // Yaw only and +-3 degrees of tilt: the up axis barely turns. The readings' residual
        // determines the full model from 3000 readings at 30 nT (its check by trials agrees, and
        // the estimate lies within 3 standard errors of the truth); [P1]'s residual runs off
        // along the up axis's scale and bias.
        let truth = paper::true_error_model();
        let cap = crate::AttitudeBox::from_degrees([-3.0, 3.0], [-180.0, 180.0], [-3.0, 3.0]).unwrap();
        let readings = log(&truth, &cap, 3000, 30.0, 4);
        let field = paper::changsha_field().magnitude() / 1e5;
        let f = fit(&readings, field, FitModel::Full).unwrap();
        assert!(f.usable, "{:?}", f.reasons);
        let c = f.check.unwrap();
        assert_eq!((c.trials, c.ok), (200, 200));
        let (se_s, se_o) = (f.std_scale.unwrap(), f.std_bias.unwrap());
        for i in 0..3 {
            assert!((f.errors.scale()[i] - truth.scale()[i]).abs() <= 3.0 * se_s[i], "S{i}");
            assert!((f.bias[i] - truth.bias_nt()[i] / 1e5).abs() <= 3.0 * se_o[i], "O{i}");
        }
        let (auto, why) = fit_auto(&readings, field, &FitSettings::default()).unwrap();
        assert_eq!(
            (auto.model, why),
            (FitModel::Full, vec![AutoReason::Identifiable(FitModel::Full)])
        );
        let paper = FitSettings {
            residual: Residual::Paper,
            ..FitSettings::default()
        };
        // No estimate at all (step 1 finds no ellipsoid) is as good an answer as a verdict.
        if let Ok(f) = fit_with(&readings, field, FitModel::Full, &paper) {
            assert!(!f.usable, "{}", f.verdict);
        }
    }
}
