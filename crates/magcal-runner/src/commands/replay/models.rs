//! The calibrations a replay compares: \[P1\]'s full model and its reductions, and the forms the
//! field tools fit, each from the same held readings.

use magcal_core::calibration::step1;
use magcal_core::log_fit::{self, FitModel, FitSettings};
use magcal_core::small::{Mat3, mat_vec, sub};
use magcal_core::{CalibrationStatus, ErrorModel, TwoStep, Vec3};

/// `replay --models`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, clap::ValueEnum)]
pub enum Model {
    /// \[P1\]'s two-step calibration: non-orthogonality, scale factors, bias (9 parameters), with
    /// the scenario's `[calibration]` settings, as `run` calibrates.
    Full,
    /// Scale factors and bias (6), `log_fit`'s diagonal model.
    Diagonal,
    /// A sphere: bias and one scale (4), what ArduPilot's sphere step fits.
    Offset,
    /// The algebraic ellipsoid fit alone (\[P1\] eq. (11), one linear solve, no refinement):
    /// the form Magneto and MotionCal fit, whose symmetric `A^-1` carries the same `G`.
    Symmetric,
    /// The vector calibration against the reference attitudes ([`magcal_core::vector`]): full
    /// `K` and `O` with the field fitted in the reference frame (its magnitude fixed): what
    /// knowing each held reading's attitude adds.
    Vector,
}

impl Model {
    /// Every model, in the order of the outputs.
    pub const ALL: [Self; 5] = [Self::Full, Self::Diagonal, Self::Offset, Self::Symmetric, Self::Vector];

    /// The name in the outputs.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Full => "full",
            Self::Diagonal => "diagonal",
            Self::Offset => "offset",
            Self::Symmetric => "symmetric",
            Self::Vector => "vector",
        }
    }
}

/// A calibration made by one model: the map of raw readings to the calibrated field, and what
/// it estimates.
#[derive(Debug, Clone, PartialEq)]
pub struct Fitted {
    /// Its status: `ok`, `not_converged` or `not_identifiable`.
    pub status: CalibrationStatus,
    /// `P`: the calibrated field is `P (raw - bias)`.
    pub p: Mat3,
    /// The bias, nT.
    pub bias: Vec3,
    /// `(psi, S, O)` of the estimate (`psi = 0` where the model holds it).
    pub estimate: ErrorModel,
    /// RMS of `|P (raw - bias)| - R` over the readings it was fitted to, nT.
    pub rms_residual: f64,
    /// The rotation of `P (raw - bias)` into the body frame where the model estimates it (the
    /// vector calibration).
    pub alignment: Option<Mat3>,
}

impl Fitted {
    /// The calibrated field of a raw reading.
    pub fn apply(&self, raw: Vec3) -> Vec3 {
        mat_vec(&self.p, sub(raw, self.bias))
    }
}

/// Calibrates `readings` (nT, each with its attitude in `attitudes`, body into a z-up
/// reference frame) to the magnitude `magnitude` (nT) with `model`; `noise` is the
/// readings' noise per component (nT), which the verdicts of step 2 and of the log fits rest on.
/// A calibration that yields no estimate is its status (`failed`, or `not_identifiable` where
/// the readings do not determine one).
///
/// # Errors
/// The status of a calibration without an estimate.
pub fn calibrate(
    model: Model,
    readings: &[Vec3],
    attitudes: &[Mat3],
    magnitude: f64,
    noise: f64,
    two_step: &TwoStep,
) -> Result<Fitted, CalibrationStatus> {
    match model {
        Model::Full => {
            let settings = TwoStep {
                noise_nt: Some(noise),
                ..two_step.clone()
            };
            let c = settings.calibrate(readings, magnitude).map_err(|e| e.status())?;
            let e = c.estimate();
            Ok(Fitted {
                status: c.status(),
                p: e.p,
                bias: e.bias_nt,
                estimate: e.model,
                rms_residual: e.rms_residual_nt,
                alignment: None,
            })
        }
        Model::Diagonal | Model::Offset => {
            let fit_model = if model == Model::Diagonal {
                FitModel::Diagonal
            } else {
                FitModel::Offset
            };
            // The replay is the Monte Carlo: its fits run no check of their own.
            let settings = FitSettings {
                noise: Some(noise),
                residual: two_step.residual,
                trials: 0,
                held_out: false,
                profile: false,
                ..FitSettings::default()
            };
            let f = log_fit::fit_with(readings, magnitude, fit_model, &settings).map_err(|e| e.status())?;
            let status = if f.identifiable || f.status != CalibrationStatus::Ok {
                f.status
            } else {
                CalibrationStatus::NotIdentifiable
            };
            Ok(Fitted {
                status,
                p: f.p,
                bias: f.bias,
                estimate: f.errors,
                rms_residual: f.residual_rms,
                alignment: None,
            })
        }
        Model::Vector => {
            let f = magcal_core::vector::fit_vector(
                readings,
                attitudes,
                magcal_core::vector::ReferenceField::Fitted { magnitude },
            )
            .map_err(|e| match e {
                magcal_core::vector::VectorError::NotConverged { .. } => CalibrationStatus::NotConverged,
                magcal_core::vector::VectorError::NotDetermined { .. } => CalibrationStatus::NotIdentifiable,
                magcal_core::vector::VectorError::TooFewReadings { .. } => CalibrationStatus::TooFewReadings,
                _ => CalibrationStatus::RankDeficient,
            })?;
            // As `calibrate --fit vector` judges it: identifiable, and a believable sensor.
            let believable = crate::commands::calibrate::vector::implausible(&f.error_model()).is_none();
            Ok(Fitted {
                status: if f.identifiable && believable {
                    CalibrationStatus::Ok
                } else {
                    CalibrationStatus::NotIdentifiable
                },
                p: f.p,
                bias: f.bias,
                estimate: f.error_model(),
                rms_residual: f.rms_residual,
                alignment: Some(f.alignment),
            })
        }
        Model::Symmetric => {
            let e = step1::linear_fit(readings, magnitude).map_err(|e| e.status())?;
            Ok(Fitted {
                status: CalibrationStatus::Ok,
                p: e.p,
                bias: e.bias_nt,
                estimate: e.model,
                rms_residual: e.rms_residual_nt,
                alignment: None,
            })
        }
    }
}
