//! One noisy Monte Carlo trial of \[P1\] IV.C: readings of a design with noise, two-step calibration,
//! relative errors. A trial whose calibration fails is an outcome with its status, not an error.

use rand::Rng;

use crate::calibration::{CalibrationOutcome, CalibrationStatus, TwoStep};
use crate::error::ParameterError;
use crate::heading::{HeadingError, HeadingProbe};
use crate::metrics::{AbsoluteErrors, RelativeErrors};
use crate::sensor::ErrorModel;
use crate::small::Vec3;

/// What one trial produced.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialOutcome {
    /// Calibration status.
    pub status: CalibrationStatus,
    /// Step-2 iterations, when there is an estimate.
    pub iterations: Option<usize>,
    /// RMS of `|P(b - O)| - R`, nT, when there is an estimate.
    pub rms_residual_nt: Option<f64>,
    /// The estimated sensor errors, when there are any.
    pub estimate: Option<ErrorModel>,
    /// Their relative errors against the truth, percent (\[P1\] eq. (21)-(23)).
    pub eta: Option<RelativeErrors>,
    /// Their absolute errors against the truth.
    pub abs: Option<AbsoluteErrors>,
    /// The heading error the estimate leaves (docs/conventions.md "Heading error of a calibration").
    pub heading: Option<HeadingError>,
}

/// Draws noisy readings of `body_fields` (nT) from `truth` with noise `sigma_nt` per component,
/// calibrates them with `calibration` against a field of magnitude `field_magnitude_nt`, and scores
/// the estimate against `truth`: relative and absolute errors, and the heading error over the
/// level yaws of `probe` (built from the same field and truth).
///
/// # Errors
/// Only an invalid `sigma_nt` (negative or not finite); a calibration that fails is an outcome.
pub fn trial<R: Rng + ?Sized>(
    truth: &ErrorModel,
    body_fields: &[Vec3],
    field_magnitude_nt: f64,
    sigma_nt: f64,
    calibration: &TwoStep,
    probe: &HeadingProbe,
    rng: &mut R,
) -> Result<TrialOutcome, ParameterError> {
    let readings = truth.noisy_readings(body_fields, sigma_nt, rng)?;
    Ok(scored(
        truth,
        calibration.calibrate(&readings, field_magnitude_nt),
        probe,
    ))
}

/// A calibration's outcome scored against `truth`: relative and absolute errors and the heading
/// error over the level yaws of `probe`; a calibration that failed is an outcome with its status.
pub fn scored(truth: &ErrorModel, outcome: CalibrationOutcome, probe: &HeadingProbe) -> TrialOutcome {
    match outcome {
        Ok(fit) => {
            let e = fit.estimate();
            TrialOutcome {
                status: fit.status(),
                iterations: Some(fit.iterations),
                rms_residual_nt: Some(e.rms_residual_nt),
                eta: Some(RelativeErrors::between(&e.model, truth)),
                abs: Some(AbsoluteErrors::between(&e.model, truth)),
                heading: Some(probe.error(&e.p, e.bias_nt)),
                estimate: Some(e.model),
            }
        }
        Err(e) => TrialOutcome {
            status: e.status(),
            iterations: None,
            rms_residual_nt: None,
            estimate: None,
            eta: None,
            abs: None,
            heading: None,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::Summary;
    use crate::paper;
    use crate::rng::stream_rng;

    fn eta_psi(sigma: f64, trials: u64, seed: u64) -> Summary {
        let field = paper::changsha_field().with_yaw_offset_deg(90.0).unwrap();
        let truth = paper::true_error_model();
        let body = field.body_fields(&paper::uniformity_design());
        let probe = HeadingProbe::new(&field, &truth);
        let values: Vec<f64> = (0..trials)
            .map(|t| {
                let o = trial(
                    &truth,
                    &body,
                    field.magnitude(),
                    sigma,
                    &TwoStep::default(),
                    &probe,
                    &mut stream_rng(seed, t),
                )
                .unwrap();
                o.eta.expect("small noise: every calibration succeeds").psi.unwrap()
            })
            .collect();
        Summary::new(&values, 0)
    }

    #[test]
    fn errors_vanish_without_noise() {
        let s = eta_psi(0.0, 20, 1);
        assert!(s.p95 < 1e-6, "{}", s.p95);
    }

    #[test]
    fn small_noise_errors_grow_linearly_with_sigma() {
        // For small noise the estimate is a linear function of the noise, so eta scales with sigma:
        // mean eta at 3 nT equals 3 x mean eta at 1 nT, within 4 standard errors of the difference.
        let a = eta_psi(1.0, 2000, 2);
        let b = eta_psi(3.0, 2000, 3);
        let se = (9.0 * a.se_mean * a.se_mean + b.se_mean * b.se_mean).sqrt();
        assert!(
            (b.mean - 3.0 * a.mean).abs() <= 4.0 * se,
            "{} vs 3 x {} (se {se})",
            b.mean,
            a.mean
        );
        assert!(a.mean > 0.1, "the noise must show: {}", a.mean);
    }

    #[test]
    fn invalid_sigma_is_an_error() {
        let field = paper::changsha_field();
        let body = field.body_fields(&paper::uniformity_design());
        let r = trial(
            &paper::true_error_model(),
            &body,
            field.magnitude(),
            -1.0,
            &TwoStep::default(),
            &HeadingProbe::new(&field, &paper::true_error_model()),
            &mut stream_rng(0, 0),
        );
        assert!(r.is_err());
    }
}
