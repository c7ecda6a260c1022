//! The lack-of-fit F test of a reduced log fit against the richer models of the same readings.
#![allow(non_snake_case)]
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

use super::{FitModel, LogFit, levenberg_marquardt};
use crate::calibration::TwoStep;
use crate::small::{Mat3, Vec3, mat_t_vec, mat_vec, norm, sub};
use crate::stop::Stop;

/// The lack-of-fit F test of a reduced fit against a richer one of the same readings: with
/// residual sums of squares `Q_r`, `Q_f` in the readings' units (each residual divided by
/// `|P^T u|`: the distance of the reading from the fitted ellipsoid, to first order) and
/// parameters `p_r < p_f` of `m` readings,
/// `F = ((Q_r - Q_f) / (p_f - p_r)) / (Q_f / (m - p_f))`, F-distributed with
/// `(p_f - p_r, m - p_f)` degrees of freedom when the reduced model is true and the noise is
/// Gaussian (to first order in the noise: the models are nonlinear).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct LackOfFit {
    /// The richer model of the most significant test.
    pub against: FitModel,
    /// The statistic (0 when the richer fit's residual sum is not smaller).
    pub f: f64,
    /// Degrees of freedom `(p_f - p_r, m - p_f)`.
    pub dof: (usize, usize),
    /// `P(F' >= F)` under the reduced model, times the number of richer models tested
    /// (Bonferroni), at most 1.
    pub p_value: f64,
    /// Whether the log rejects the reduced model: `p_value` below [`LACK_OF_FIT_LEVEL`].
    pub rejected: bool,
}

/// The residual sum of squares of a calibration `(P, O)` in the readings' own units:
/// `sum_i r_i^2 / |P^T u_i|^2` with `r_i = |P (s_i - O)| - R` and `u_i` the unit calibrated
/// direction, each term the squared distance (to first order) from the reading to the fitted
/// ellipsoid. Unlike `sum r_i^2`, it does not shrink with `P`: a fit running away to large scale
/// factors compresses the calibrated residuals, not the readings' distances, and sensors with
/// unequal scale factors weigh their readings evenly.
pub(super) fn raw_sum_of_squares(p: &Mat3, bias: Vec3, readings: &[Vec3], magnitude: f64) -> f64 {
    readings
        .iter()
        .map(|&s| {
            let b = mat_vec(p, sub(s, bias));
            let n = norm(b);
            // A reading at the bias has no direction; any one gives its distance's order.
            let u = if n > 0.0 { b.map(|v| v / n) } else { [1.0, 0.0, 0.0] };
            let g = mat_t_vec(p, u);
            (n - magnitude).powi(2) / g.iter().map(|v| v * v).sum::<f64>()
        })
        .sum()
}

/// `model` fitted from `(p, bias)` (a sensor of that model or a smaller one) by minimising the
/// readings' distances to the ellipsoid ([`raw_sum_of_squares`]) instead of the calibrated
/// residuals: Levenberg-Marquardt with the weights `1 / |P^T u_i|` frozen in each step's gradient
/// (the objective itself is exact, and only steps that lower it are taken; at most 200). Returns
/// the sum reached, never above the start's.
fn distance_refine(
    model: FitModel,
    p: &Mat3,
    bias: Vec3,
    readings: &[Vec3],
    magnitude: f64,
    stop: &Stop,
) -> Option<f64> {
    // The parameters theta = (P11, P12, P13, P22, P23, P33, o1, o2, o3) of the full model are
    // linear in each model's own: theta = T x.
    let full: [[f64; 9]; 9] = std::array::from_fn(|i| std::array::from_fn(|j| f64::from(u8::from(i == j))));
    let diagonal: [[f64; 6]; 9] = std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            f64::from(u8::from(
                matches!((i, j), (0, 0) | (3, 1) | (5, 2)) || (i >= 6 && j == i - 3),
            ))
        })
    });
    let offset: [[f64; 4]; 9] = std::array::from_fn(|i| {
        std::array::from_fn(|j| f64::from(u8::from(matches!((i, j), (0 | 3 | 5, 0)) || (i >= 6 && j == i - 5))))
    });
    let theta = crate::calibration::step2::pack(p, bias.map(|v| v / magnitude));
    let q = match model {
        FitModel::Full => distance_lm(&full, theta, readings, magnitude, stop),
        FitModel::Diagonal => distance_lm(&diagonal, theta, readings, magnitude, stop),
        FitModel::Offset => distance_lm(&offset, theta, readings, magnitude, stop),
    }?;
    Some(q.min(raw_sum_of_squares(p, bias, readings, magnitude)))
}

/// [`distance_refine`] in the parameters `x` of a model with `theta = T x`, from the `x` that
/// reproduces `theta0` (its components read at the first 1 of each column of `T`).
fn distance_lm<const N: usize>(
    T: &[[f64; N]; 9],
    theta0: [f64; 9],
    readings: &[Vec3],
    magnitude: f64,
    stop: &Stop,
) -> Option<f64> {
    let theta = |x: &[f64; N]| -> [f64; 9] { std::array::from_fn(|i| (0..N).map(|j| T[i][j] * x[j]).sum()) };
    let x0: [f64; N] = std::array::from_fn(|j| (0..9).find(|&i| T[i][j] != 0.0).map_or(0.0, |i| theta0[i]));
    let u: Vec<Vec3> = readings.iter().map(|s| s.map(|v| v / magnitude)).collect();
    let settings = TwoStep {
        max_iterations: 200,
        stop: stop.clone(),
        ..TwoStep::default()
    };
    let (x, _, _) = levenberg_marquardt(x0, &u, 1.0, &settings, |x, u| {
        // Step 2's residual |P d| - 1 and its gradient in theta; |P^T w| is the norm of the
        // gradient's bias part.
        let (r, dn) = crate::calibration::step2::residual_and_gradient(&theta(x), u);
        let G = norm([dn[6], dn[7], dn[8]]);
        (
            1.0 + r / G,
            std::array::from_fn(|j| (0..9).map(|i| T[i][j] * dn[i]).sum::<f64>() / G),
        )
    });
    let (p, o) = crate::calibration::step2::unpack(&theta(&x));
    let q = raw_sum_of_squares(&p, o.map(|v| v * magnitude), readings, magnitude);
    q.is_finite().then_some(q)
}

/// The level of the lack-of-fit test: a true reduced model is rejected once in a thousand logs.
pub const LACK_OF_FIT_LEVEL: f64 = 1e-3;

impl LackOfFit {
    /// The test of `reduced` against the richer models (`richer`: their fits of the same
    /// `readings` to the same magnitude, where they exist; a model that leaves no degrees of
    /// freedom is skipped).
    ///
    /// The statistic compares least sums of the readings' distances from the ellipsoid (each
    /// residual over `|P^T u|`), the quantity the F distribution is about; the fits minimise
    /// calibrated residuals (\[P1\]'s step 2), which differ where the scale factors differ. So the
    /// reduced model's sum is that of its fit refined to least distances, and a richer model's
    /// the least of: its own fit; the reduced fit refined to least distances within the richer
    /// model (the reduced sensor is a point of it, so this never ends above the reduced sum,
    /// however the richer model's own fit ran away); and, for the full model, step 2 started from
    /// the reduced fit. A reduced fit within 1e-9 of the magnitude everywhere (noise-free
    /// readings) is not rejected: its residual sum is rounding.
    pub fn test(reduced: &LogFit, richer: &[&LogFit], readings: &[Vec3]) -> Option<Self> {
        Self::test_until(reduced, richer, readings, &Stop::NEVER)
    }

    /// [`Self::test`] whose fits ask `stop` before every iteration; what it returns once `stop` is
    /// requested is cut short, for the caller to throw away.
    pub(super) fn test_until(reduced: &LogFit, richer: &[&LogFit], readings: &[Vec3], stop: &Stop) -> Option<Self> {
        use statrs::distribution::{ContinuousCDF, FisherSnedecor};
        let m = readings.len();
        let R = reduced.magnitude;
        let pr = reduced.model.parameters();
        // No richer model (the full one is the richest): nothing to test against, and the
        // reduced sum below (a refinement over every reading) would be thrown away.
        if ![FitModel::Full, FitModel::Diagonal]
            .into_iter()
            .any(|model| model.parameters() > pr && m > model.parameters())
        {
            return None;
        }
        let exact = reduced.residual_rms <= 1e-9 * R;
        // The full model from the reduced fit: the same sensor is a point of the full model.
        let start = crate::calibration::Estimate {
            p: reduced.p,
            bias_nt: reduced.bias,
            model: reduced.errors,
            rms_residual_nt: reduced.residual_rms,
        };
        let step2 = (reduced.model != FitModel::Full)
            .then(|| {
                let settings = TwoStep {
                    stop: stop.clone(),
                    ..TwoStep::default()
                };
                crate::calibration::step2::refine(&settings, &start, readings, R)
            })
            .and_then(Result::ok)
            .map(|r| raw_sum_of_squares(&r.estimate.p, r.estimate.bias_nt, readings, R));
        // Each model at the smallest distance sum found: the reduced one refined from its fit,
        // the richer ones at their own fits and refined from the reduced fit (a point of theirs;
        // a richer fit of its own that ran away is a poor start).
        let least = |model: FitModel, own: Option<&LogFit>| {
            [
                own.map(|f| raw_sum_of_squares(&f.p, f.bias, readings, R)),
                distance_refine(model, &reduced.p, reduced.bias, readings, R, stop),
                if model == FitModel::Full { step2 } else { None },
            ]
            .into_iter()
            .flatten()
            .reduce(f64::min)
        };
        let q_reduced = least(reduced.model, None)?;
        let candidates: Vec<(FitModel, f64)> = [FitModel::Full, FitModel::Diagonal]
            .into_iter()
            .filter(|model| model.parameters() > pr)
            .filter_map(|model| {
                let own = richer.iter().copied().find(|f| f.model == model);
                least(model, own).map(|q| (model, q))
            })
            .collect();
        let tests: Vec<Self> = candidates
            .into_iter()
            .filter(|(model, _)| model.parameters() > pr && m > model.parameters())
            .map(|(model, q)| {
                let pf = model.parameters();
                let dof = (pf - pr, m - pf);
                let drop = (q_reduced - q).max(0.0) / dof.0 as f64;
                let variance = q / dof.1 as f64;
                let stat = if exact || drop == 0.0 {
                    0.0
                } else if variance > 0.0 {
                    drop / variance
                } else {
                    f64::INFINITY
                };
                let p_value = FisherSnedecor::new(dof.0 as f64, dof.1 as f64)
                    .map(|d| if stat.is_finite() { d.sf(stat) } else { 0.0 })
                    .unwrap_or(f64::NAN);
                Self {
                    against: model,
                    f: stat,
                    dof,
                    p_value,
                    rejected: false,
                }
            })
            .collect();
        let n = tests.len() as f64;
        tests
            .into_iter()
            .min_by(|a, b| a.p_value.total_cmp(&b.p_value))
            .map(|t| {
                let p_value = (t.p_value * n).min(1.0);
                Self {
                    p_value,
                    rejected: p_value < LACK_OF_FIT_LEVEL,
                    ..t
                }
            })
    }

    /// In words, for a verdict: "the log rejects this model (lack-of-fit F = 73.7127 on (2, 14)
    /// degrees of freedom against the diagonal model, p = 7.38e-8): ...".
    pub fn words(&self) -> String {
        let test = format!(
            "lack-of-fit F = {:.4} on ({}, {}) degrees of freedom against the {} model, p {}",
            self.f,
            self.dof.0,
            self.dof.1,
            self.against.as_str(),
            show_p(self.p_value)
        );
        if self.rejected {
            format!(
                "the log rejects this model ({test}): the sensor has terms the model leaves out, and its estimates carry their bias (its standard errors do not)"
            )
        } else if self.f == 0.0 {
            format!(
                "the log cannot test this model: no richer fit comes closer to the readings ({test}; the richer models run along what the log does not determine)"
            )
        } else {
            format!("the log does not reject this model ({test})")
        }
    }
}

/// A p-value in words: `= 7.38e-8`, or `< 1e-300` where the tail probability underflows (an F of
/// hundreds on thousands of degrees of freedom: the exact value is far smaller still).
pub fn show_p(p: f64) -> String {
    if p > 0.0 {
        format!("= {p:.2e}")
    } else {
        "< 1e-300".to_string()
    }
}
