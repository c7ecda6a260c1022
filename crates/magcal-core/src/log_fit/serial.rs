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
//! The batch is a tenth of the log, `L = m / 10` ([`MIN_BATCHES`] batches): a bandwidth in
//! proportion to the log ("fixed-b", Kiefer and Vogelsang 2005), whose estimate keeps the
//! batches' few degrees of freedom ([`Serial::dof`], `1.5 (10 - 1) = 13`) and is judged with
//! Student's `t` of them, in exchange for reaching as far in time as the log allows.
//!
//! # Why not a plug-in bandwidth
//! Andrews' (1991) AR(1) plug-in rule, `L = 1.1447 (alpha m)^(1/3)` with `alpha = 4 rho^2 / ((1 -
//! rho)^2 (1 + rho)^2)` from the residuals' lag-one autocorrelation `rho`, was the rule before.
//! On the BROAD motion-capture trials (285.7 Hz) it is wrong by construction: the residuals'
//! correlation has a fast part (lag-one 0.82 on trials 02 and 05, 0.33 at 3 readings, 0.17 at 10)
//! and a slow one (0.14 at 0.35 s, 0.10 at 1 s, 0.06 at 3.5 s on trial 02) that the lag-one
//! does not see. Andrews gave 0.1 to 0.4 s (33 readings on 5 s windows, 109 on the 113 s of
//! trial 02's movement), where the long-run standard errors of the whole trials keep growing up
//! to batches of about 3.5 s: against white noise's, 2.7 at 33 readings, 3.8 at 100, 5.0 at 300,
//! 5.8 at 1000 and 6.1 at 3000 (trial 02; 05, 10 and 30 alike). Over windows of the trials 02
//! and 05 with \[P1\]'s sensor imposed (`examples/broad_coverage.rs`: the windows of 5, 10, 20
//! and 40 s, the full model, the default check), the share of 95 % intervals of usable fits
//! that held the trial's calibration, all nine parameters pooled, was
//!
//! | window | white | Andrews | `m / 20` | `m / 10` | `m / 5` |
//! |---|---|---|---|---|---|
//! | 5 s (42 windows) | 0.42 | 0.62 | 0.73 | 0.82 | 0.81 |
//! | 10 s (21) | 0.36 | 0.61 | 0.64 | 0.68 | 0.74 |
//! | 20 s (10) | 0.21 | 0.52 | 0.67 | 0.70 | 0.77 |
//! | 40 s (4) | 0.19 | 0.44 | 0.56 | 0.58 | 0.69 |
//!
//! with intervals 2.1 to 3.2 times white noise's under Andrews and 2.5 to 5.0 times under `m /
//! 10`. A tenth of the log is the longest batch that keeps ten batches; it is ahead of Andrews'
//! at every window length. `m / 5` covers a little more on the longer windows, with wider
//! intervals again (`t_6` 2.45 against `t_13` 2.16) and a covariance of nine parameters from five
//! batches (its trials' blocks a fifth of the log). None reaches 0.95 on windows this short: the
//! windows' errors do not shrink with their length (the median error is 3.5 white standard errors
//! at 5 s, 12.6 at 40 s), a drift slower than a window shows in its own residuals. Where the
//! correlation reaches further than a tenth of the log, the standard errors are still too small.
//!
//! # Deviation from \[P1\]
//! \[P1\] IV.C takes the noise white and Gaussian (eq. (5)), as its Monte Carlo draws it. On the
//! BROAD trials white standard errors were too small by a factor of 3.5 to 12.6 (the median
//! error of the windows above), their 95 % intervals holding the truth in a fifth to two fifths
//! of the fits.

/// The batches a log is cut into for its long-run covariance: the batch length is `m /
/// MIN_BATCHES` readings.
pub const MIN_BATCHES: usize = 10;

/// How a fit's standard errors treat the order of its readings.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Serial {
    /// The batch length `L` of the overlapping batch means, readings.
    pub batch: usize,
    /// The lag-one autocorrelation of the residuals in time order, measured where the batch
    /// length was not given (`None` where it was); reported, the length does not depend on it.
    pub lag_one: Option<f64>,
}

impl Serial {
    /// The batch length of the residuals `r` in time order, [`batch_length`] of their number,
    /// and their lag-one autocorrelation.
    pub fn of_residuals(r: &[f64]) -> Self {
        Self {
            batch: batch_length(r.len()),
            lag_one: Some(lag_one(r)),
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

/// The batch length of `m` readings in time order: `m / MIN_BATCHES`, at least 1 (see the
/// module documentation).
pub fn batch_length(m: usize) -> usize {
    (m / MIN_BATCHES).max(1)
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
    fn the_batch_is_a_tenth_of_the_log_whatever_its_correlation() {
        // The rule of the module documentation: m / 10, at least 1, the lag-one measured beside
        // it. Series of 12,000 values: white, AR(1) at 0.9, and a steady drift.
        assert_eq!(batch_length(12_000), 1200);
        assert_eq!(batch_length(32_280), 3228);
        assert_eq!(batch_length(1429), 142);
        assert_eq!(batch_length(19), 1);
        assert_eq!(batch_length(5), 1);
        assert_eq!(batch_length(0), 1);
        let mut rng = stream_rng(78, 0);
        let white: Vec<f64> = (0..12_000).map(|_| StandardNormal.sample(&mut rng)).collect();
        let mut x = 0.0;
        let ar: Vec<f64> = white
            .iter()
            .map(|e| {
                x = 0.9 * x + e;
                x
            })
            .collect();
        let drift: Vec<f64> = (0..12_000).map(|t| t as f64).collect();
        for (r, rho) in [(&white, 0.0), (&ar, 0.9), (&drift, 1.0)] {
            let s = Serial::of_residuals(r);
            assert_eq!(s.batch, 1200);
            assert_eq!(s.dof(r.len()), 13);
            let measured = s.lag_one.unwrap();
            assert!((measured - rho).abs() < 0.03, "{measured} vs {rho}");
        }
        assert!((lag_one(&[1.0, 2.0, 3.0, 4.0]) - 0.25).abs() < 1e-15);
        assert_eq!(Serial::of_residuals(&[1.0, -1.0]).batch, 1);
    }
}
