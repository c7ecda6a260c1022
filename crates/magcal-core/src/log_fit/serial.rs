//! Standard errors of a log fit whose residuals are correlated in time (docs/conventions.md
//! "Correlated residuals").
//!
//! A real log's residuals are not white noise: the attitude's timing, a field that changes from
//! place to place, the motion inside a sample all drift slowly, so neighbouring readings err
//! alike. Least squares stays unbiased, but its covariance is no longer `sigma^2 A^-1`: it is the
//! sandwich `A^-1 B A^-1` with `B` the long-run covariance of the scores `s_t = w_t r_t J_t`
//! (`w_t` the residual's weight, `r_t` the residual, `J_t` its gradient in the parameters).
//!
//! `B` is estimated by **overlapping batch means** (Meketon and Schmeiser 1984): the outer
//! products of the sums of `L` consecutive scores, averaged over every start and divided by `L`,
//! `B = m / (m - L + 1) sum_t S_t S_t^T / L`, `S_t = s_t + ... + s_{t+L-1}`. It equals the Bartlett
//! kernel estimator of Newey and West (1987) with bandwidth `L` up to terms of order `L / m`,
//! costs `O(m N^2)` for any `L` (prefix sums), and is never negative. With `L = 1` it is White's
//! heteroscedasticity-consistent sandwich.
//!
//! The batch length follows Andrews' (1991) plug-in rule for the Bartlett kernel from an AR(1)
//! fitted to the residuals in time order: `L = 1.1447 (alpha m)^(1/3)`,
//! `alpha = 4 rho^2 / ((1 - rho)^2 (1 + rho)^2)`, `rho` their lag-one autocorrelation, at least 1
//! and at most `m / 10` (ten batches: fewer say nothing of a covariance of nine parameters).
//!
//! # Deviation from \[P1\]
//! \[P1\] IV.C takes the noise white and Gaussian (eq. (5)), as its Monte Carlo draws it. On the
//! BROAD motion-capture trials the residuals' lag-one autocorrelation is above 0.99 at 285.7 Hz;
//! white standard errors there were too small by an order of magnitude (README "Standard errors
//! that hold on real logs").

/// The most batches' worth of a log the batch length may take: at least ten batches.
pub const MIN_BATCHES: usize = 10;

/// How a fit's standard errors treat the order of its readings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Serial {
    /// The batch length `L` of the overlapping batch means, readings.
    pub batch: usize,
    /// The lag-one autocorrelation of the residuals in time order that chose it (`None` where
    /// the length was given).
    pub lag_one: Option<f64>,
}

impl Serial {
    /// The batch length of Andrews' AR(1) rule for the residuals `r` in time order (see the module
    /// documentation): 1 for fewer than 3 residuals or a zero spread.
    pub fn of_residuals(r: &[f64]) -> Self {
        let rho = lag_one(r);
        Self {
            batch: batch_length(rho, r.len()),
            lag_one: Some(rho),
        }
    }

    /// The effective degrees of freedom of the long-run covariance of `m` readings: `1.5 (m / L -
    /// 1)`, those of overlapping batch means (Meketon and Schmeiser 1984: two thirds of the
    /// variance of non-overlapping ones, whose `m / L` batches leave `m / L - 1`), at least 1.
    pub fn dof(&self, m: usize) -> usize {
        let batches = m as f64 / self.batch.max(1) as f64;
        ((1.5 * (batches - 1.0)).floor() as usize).max(1)
    }
}

/// The lag-one autocorrelation of `r` about its mean (0 for fewer than 3 values or no spread),
/// within [-0.999, 0.999].
pub fn lag_one(r: &[f64]) -> f64 {
    if r.len() < 3 {
        return 0.0;
    }
    let mean = r.iter().sum::<f64>() / r.len() as f64;
    let var: f64 = r.iter().map(|v| (v - mean).powi(2)).sum();
    if !(var > 0.0 && var.is_finite()) {
        return 0.0;
    }
    let cov: f64 = r.windows(2).map(|w| (w[0] - mean) * (w[1] - mean)).sum();
    (cov / var).clamp(-0.999, 0.999)
}

/// Andrews' (1991) Bartlett bandwidth for an AR(1) of lag-one autocorrelation `rho` and `m`
/// values, rounded up, within 1 and `m / MIN_BATCHES`.
pub fn batch_length(rho: f64, m: usize) -> usize {
    let alpha = 4.0 * rho * rho / ((1.0 - rho).powi(2) * (1.0 + rho).powi(2));
    let l = 1.1447 * (alpha * m as f64).cbrt();
    let most = (m / MIN_BATCHES).max(1);
    if l.is_finite() {
        (l.ceil() as usize).clamp(1, most)
    } else {
        most
    }
}

/// The long-run covariance `B` (see the module documentation) of the `scores` in time order,
/// by overlapping batch means of length `batch` (at most their number).
pub fn long_run_covariance<const N: usize>(scores: &[[f64; N]], batch: usize) -> [[f64; N]; N] {
    let m = scores.len();
    let mut b = [[0.0; N]; N];
    if m == 0 {
        return b;
    }
    let l = batch.clamp(1, m);
    // Prefix sums: S_t = prefix[t + L] - prefix[t].
    let mut prefix = vec![[0.0; N]; m + 1];
    for t in 0..m {
        for a in 0..N {
            prefix[t + 1][a] = prefix[t][a] + scores[t][a];
        }
    }
    for t in 0..=m - l {
        let s: [f64; N] = std::array::from_fn(|a| prefix[t + l][a] - prefix[t][a]);
        for a in 0..N {
            for c in 0..=a {
                b[a][c] += s[a] * s[c];
            }
        }
    }
    let f = m as f64 / ((m - l + 1) as f64 * l as f64);
    for a in 0..N {
        for c in 0..=a {
            b[a][c] *= f;
            b[c][a] = b[a][c];
        }
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::stream_rng;
    use rand_distr::{Distribution, StandardNormal};

    #[test]
    fn with_a_batch_of_one_it_is_the_sum_of_outer_products() {
        let s = [[1.0, 2.0], [-3.0, 0.5], [2.0, -2.5]];
        let b = long_run_covariance(&s, 1);
        let want = [[1.0 + 9.0 + 4.0, 2.0 - 1.5 - 5.0], [2.0 - 1.5 - 5.0, 4.0 + 0.25 + 6.25]];
        for a in 0..2 {
            for c in 0..2 {
                assert!((b[a][c] - want[a][c]).abs() <= 8.0 * f64::EPSILON * 14.0, "{b:?}");
            }
        }
    }

    #[test]
    fn the_long_run_variance_of_an_ar1_is_found_with_the_bartlett_bias() {
        // AR(1) x_t = rho x_{t-1} + e_t, unit innovations: the long-run variance of the sum's
        // increments is 1 / (1 - rho)^2 = 100 at rho = 0.9. Batch means of length L estimate it
        // with the Bartlett kernel's bias, the factor 1 - 2 rho / (L (1 - rho^2)) (0.932 at the
        // L = 139 of 20,000 readings). The mean over 200 series lies within 4 of its standard
        // errors of that.
        let rho: f64 = 0.9;
        let m = 20_000;
        let values: Vec<f64> = (0..200)
            .map(|k| {
                let mut rng = stream_rng(77, k);
                let mut x = 0.0;
                let series: Vec<f64> = (0..m)
                    .map(|_| {
                        let e: f64 = StandardNormal.sample(&mut rng);
                        x = rho * x + e;
                        x
                    })
                    .collect();
                let mean = series.iter().sum::<f64>() / m as f64;
                let scores: Vec<[f64; 1]> = series.iter().map(|v| [v - mean]).collect();
                long_run_covariance(&scores, 139)[0][0] / m as f64
            })
            .collect();
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let se = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
        let expected = 100.0 * (1.0 - 2.0 * rho / (139.0 * (1.0 - rho * rho)));
        assert!((mean - expected).abs() <= 4.0 * se, "{mean} vs {expected} (se {se})");
    }

    #[test]
    fn andrews_rule_grows_with_the_correlation_and_stays_within_its_limits() {
        assert_eq!(batch_length(0.0, 1000), 1);
        let l90 = batch_length(0.9, 12_000);
        let l99 = batch_length(0.99, 12_000);
        // alpha = 4 0.81 / (0.01 3.61) = 89.75; 1.1447 (89.75 12000)^(1/3) = 117.4.
        assert_eq!(l90, 118);
        assert!(l99 > l90 && l99 <= 1200, "{l99}");
        assert_eq!(batch_length(0.999, 12_000), 1200);
        assert_eq!(batch_length(0.999, 5), 1);
        assert!((lag_one(&[1.0, 2.0, 3.0, 4.0]) - 0.25).abs() < 1e-15);
    }
}
