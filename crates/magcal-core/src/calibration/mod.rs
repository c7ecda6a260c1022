//! The two-step calibration of \[P1\] IV.C (after Gebre-Egziabher et al. 2006): a linear
//! least-squares ellipsoid fit ([`step1`]), refined by nonlinear least squares ([`step2`]).
//!
//! ```
//! use magcal_core::{TwoStep, paper};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let field = paper::changsha_field();
//! let truth = paper::true_error_model();
//! let readings = truth.measure_all(&field.body_fields(&paper::uniformity_design()));
//! let fit = TwoStep::default().calibrate(&readings, field.magnitude())?;
//! assert!((fit.estimate().model.scale()[0] - 1.3).abs() < 1e-9);
//! # Ok(())
//! # }
//! ```
#![allow(non_snake_case)]

mod errors;
pub mod step1;
pub mod step2;

pub use errors::{CalibrationError, CalibrationStatus};
pub use step2::Termination;

use crate::linear_model::UNKNOWNS;
use crate::sensor::ErrorModel;
use crate::small::{Mat3, Vec3, mat_vec, norm, sub, upper_triangular_inverse};
use crate::stop::Stop;

/// The estimate of one step: `P` and `O`, the error model they imply, and the fit's residual.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Estimate {
    /// `P = K^-1`, upper triangular with positive diagonal, dimensionless (\[P1\] eq. (6)).
    pub p: Mat3,
    /// `O`, nT (\[P1\] eq. (5)).
    pub bias_nt: Vec3,
    /// `(psi, S, O)` from `K = P^-1` (docs/conventions.md inverse map).
    pub model: ErrorModel,
    /// RMS of `|P (b_i - O)| - R` over the readings, nT.
    pub rms_residual_nt: f64,
}

impl Estimate {
    /// An estimate from `P` and `O`; the residual is evaluated on `readings`.
    fn new(p: Mat3, bias_nt: Vec3, readings: &[Vec3], field_magnitude_nt: f64) -> Self {
        Self::checked(p, bias_nt, readings, field_magnitude_nt).expect("P from a Cholesky factor is invertible")
    }

    /// As [`Self::new`], but a singular or non-finite `P` is an error rather than a bug.
    fn checked(p: Mat3, bias_nt: Vec3, readings: &[Vec3], field_magnitude_nt: f64) -> Result<Self, CalibrationError> {
        let k = upper_triangular_inverse(&p).ok_or(CalibrationError::NotPositiveDefinite {
            reason: "estimated P is singular",
        })?;
        if !(p[0][0] > 0.0 && p[1][1] > 0.0 && p[2][2] > 0.0 && bias_nt.iter().all(|v| v.is_finite())) {
            return Err(CalibrationError::NotPositiveDefinite {
                reason: "estimated P or O is not finite",
            });
        }
        let sum_sq: f64 = readings
            .iter()
            .map(|&b| (norm(mat_vec(&p, sub(b, bias_nt))) - field_magnitude_nt).powi(2))
            .sum();
        Ok(Self {
            p,
            bias_nt,
            model: ErrorModel::from_k(&k, bias_nt),
            rms_residual_nt: (sum_sq / readings.len() as f64).sqrt(),
        })
    }
}

/// Settings of the two-step calibration. The defaults suit readings in nT of any magnitude: the
/// tolerances apply to the problem scaled by the field magnitude `R`.
#[derive(Debug, Clone, PartialEq)]
pub struct TwoStep {
    /// Iteration limit of step 2. Default 500: a healthy fit converges in 10 to 40 iterations; a
    /// fit that runs along a flat direction is stopped by the local check (see
    /// [`step2::Termination::FlatDirection`]) after 230 iterations on average on the ship of
    /// `scenarios/ship.toml` (m = 20, 30 nT), which 100 did not reach.
    pub max_iterations: usize,
    /// Step 2 stops when every component of `J^T r` (scaled problem) is at most this. Default 1e-13.
    pub gradient_tolerance: f64,
    /// Step 2 stops when `|h| <= tol (|x| + tol)`. Default 1e-12.
    pub step_tolerance: f64,
    /// Step 2 stops when an accepted step reduces the cost by at most `tol` times the cost.
    /// Default 1e-12.
    pub cost_tolerance: f64,
    /// The readings' noise per component, nT, when known (a Monte Carlo knows it): the local
    /// identifiability check of step 2 uses it. `None` (the default): estimated from the residuals
    /// when there are more than 9 readings, and no check with exactly 9.
    pub noise_nt: Option<f64>,
    /// The residual step 2 minimises. Default [`step2::Residual::Paper`], \[P1\]'s.
    pub residual: step2::Residual,
    /// Asked before every iteration of step 2, which ends with [`step2::Termination::Stopped`]
    /// when it is requested. Default [`Stop::NEVER`].
    pub stop: Stop,
}

impl Default for TwoStep {
    fn default() -> Self {
        Self {
            max_iterations: 500,
            gradient_tolerance: 1e-13,
            step_tolerance: 1e-12,
            cost_tolerance: 1e-12,
            noise_nt: None,
            residual: step2::Residual::Paper,
            stop: Stop::NEVER,
        }
    }
}

/// The result of a successful two-step calibration.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Calibration {
    /// Step 1, the linear fit of \[P1\] eq. (11); with [`step2::Residual::Readings`], where that
    /// quadric is not an ellipsoid, the sphere of [`step1::sphere_fit`] instead.
    pub step1: Estimate,
    /// Step 2, refined from step 1; the estimate to use.
    pub step2: Estimate,
    /// Step 2 iterations (damped normal-equation solves).
    pub iterations: usize,
    /// Why step 2 stopped.
    pub termination: Termination,
    /// Whether the readings determine every parameter at the estimate: its local standard
    /// deviations within the physical scales (`None`: not known).
    pub identifiable: Option<bool>,
}

impl Calibration {
    /// The final estimate (step 2).
    pub fn estimate(&self) -> &Estimate {
        &self.step2
    }

    /// [`CalibrationStatus::NotIdentifiable`] when the readings do not determine the estimate
    /// (step 2 stopped on a flat direction, or its local check failed at the end); else `Ok`, or
    /// `NotConverged` when step 2 hit its iteration limit.
    pub fn status(&self) -> CalibrationStatus {
        if self.termination == Termination::FlatDirection || self.identifiable == Some(false) {
            CalibrationStatus::NotIdentifiable
        } else if self.termination.converged() {
            CalibrationStatus::Ok
        } else {
            CalibrationStatus::NotConverged
        }
    }
}

/// What a calibration attempt yields: estimates or the reason there are none.
pub type CalibrationOutcome = Result<Calibration, CalibrationError>;

impl TwoStep {
    /// Calibrates from `readings` (nT, at least 9) of a field of magnitude `field_magnitude_nt`
    /// (`R`, nT): step 1 ([`step1::linear_fit`]) then step 2 (Levenberg-Marquardt on
    /// `|P (b_i - O)| - R`).
    ///
    /// # Errors
    /// See [`CalibrationError`]; none of them panics, and step 2 reaching its iteration limit is not
    /// an error but [`CalibrationStatus::NotConverged`]. [`CalibrationError::Stopped`] when
    /// [`Self::stop`] is requested before it returns.
    pub fn calibrate(&self, readings: &[Vec3], field_magnitude_nt: f64) -> CalibrationOutcome {
        let step1 = match step1::linear_fit(readings, field_magnitude_nt) {
            Err(CalibrationError::NotPositiveDefinite { .. }) if self.residual == step2::Residual::Readings => {
                step1::sphere_fit(readings, field_magnitude_nt)?
            }
            fit => fit?,
        };
        let refined = step2::refine(self, &step1, readings, field_magnitude_nt)?;
        if self.stop.requested() {
            return Err(CalibrationError::Stopped);
        }
        Ok(Calibration {
            step1,
            step2: refined.estimate,
            iterations: refined.iterations,
            termination: refined.termination,
            identifiable: refined.identifiable,
        })
    }
}

impl TwoStep {
    /// Calibrates a reduced model: the entries of `P = K^-1` (upper triangular, row by row:
    /// `P11, P12, P13, P22, P23, P33`) that are not `free_p` are held at `nominal_p`'s, the others
    /// and the bias are fitted by step 2 with [`step2::Residual::Readings`] (whatever
    /// `self.residual`), started from `nominal_p` and the centre of [`step1::sphere_fit`]. Holding a
    /// diagonal entry and the off-diagonal ones of its row holds that axis's scale at the nominal
    /// one: what a vehicle that barely turns that axis against the field cannot estimate.
    ///
    /// # Errors
    /// As [`Self::calibrate`]; a `nominal_p` that is not upper triangular with a positive diagonal
    /// is [`CalibrationError::NotPositiveDefinite`].
    pub fn calibrate_holding(
        &self,
        readings: &[Vec3],
        field_magnitude_nt: f64,
        nominal_p: Mat3,
        free_p: [bool; 6],
    ) -> CalibrationOutcome {
        let sphere = step1::sphere_fit(readings, field_magnitude_nt)?;
        let start = Estimate::checked(nominal_p, sphere.bias_nt, readings, field_magnitude_nt)?;
        let settings = Self {
            residual: step2::Residual::Readings,
            ..self.clone()
        };
        let free = std::array::from_fn(|i| i >= 6 || free_p[i]);
        let refined = step2::refine_holding(&settings, &start, readings, field_magnitude_nt, free)?;
        if self.stop.requested() {
            return Err(CalibrationError::Stopped);
        }
        Ok(Calibration {
            step1: start,
            step2: refined.estimate,
            iterations: refined.iterations,
            termination: refined.termination,
            identifiable: refined.identifiable,
        })
    }
}

/// Checks the inputs common to both steps.
fn validate(readings: &[Vec3], field_magnitude_nt: f64) -> Result<(), CalibrationError> {
    validate_readings(readings, field_magnitude_nt, UNKNOWNS)
}

/// A positive finite magnitude and at least `needed` finite readings.
pub(crate) fn validate_readings(
    readings: &[Vec3],
    field_magnitude_nt: f64,
    needed: usize,
) -> Result<(), CalibrationError> {
    if !(field_magnitude_nt.is_finite() && field_magnitude_nt > 0.0) {
        return Err(CalibrationError::InvalidFieldMagnitude {
            value: field_magnitude_nt,
        });
    }
    if readings.len() < needed {
        return Err(CalibrationError::TooFewReadings {
            got: readings.len(),
            needed,
        });
    }
    for (index, r) in readings.iter().enumerate() {
        for (component, &value) in r.iter().enumerate() {
            if !value.is_finite() {
                return Err(CalibrationError::NonFiniteReading {
                    index,
                    component,
                    value,
                });
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
