//! The relative errors of \[P1\] eq. (21)-(23) and summary statistics over Monte Carlo trials.

use crate::sensor::ErrorModel;
use crate::small::{Vec3, norm, sub};

/// `100 |v_hat - v| / |v|`, percent: \[P1\] eq. (21)-(23). `None` where the truth is zero (a
/// nominal sensor: psi = 0 or O = 0), for which a relative error is undefined.
pub fn relative_error_percent(estimate: Vec3, truth: Vec3) -> Option<f64> {
    let scale = norm(truth);
    (scale > 0.0).then(|| 100.0 * norm(sub(estimate, truth)) / scale)
}

/// The three criteria of \[P1\] IV.B, percent; each `None` where its truth is zero.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct RelativeErrors {
    /// `eta_psi`, \[P1\] eq. (21), from psi in degrees.
    pub psi: Option<f64>,
    /// `eta_S`, \[P1\] eq. (22).
    pub scale: Option<f64>,
    /// `eta_O`, \[P1\] eq. (23).
    pub bias: Option<f64>,
}

impl RelativeErrors {
    /// The errors of `estimate` against `truth`.
    pub fn between(estimate: &ErrorModel, truth: &ErrorModel) -> Self {
        Self {
            psi: relative_error_percent(estimate.psi_deg(), truth.psi_deg()),
            scale: relative_error_percent(estimate.scale(), truth.scale()),
            bias: relative_error_percent(estimate.bias_nt(), truth.bias_nt()),
        }
    }
}

/// The absolute errors beside the relative ones: `|psi_hat - psi|` (degrees), `|S_hat - S|`,
/// `|O_hat - O|` (nT). Defined for every truth, a nominal one included.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct AbsoluteErrors {
    /// `|psi_hat - psi|`, degrees.
    pub psi_deg: f64,
    /// `|S_hat - S|`.
    pub scale: f64,
    /// `|O_hat - O|`, nT.
    pub bias_nt: f64,
}

impl AbsoluteErrors {
    /// The errors of `estimate` against `truth`.
    pub fn between(estimate: &ErrorModel, truth: &ErrorModel) -> Self {
        Self {
            psi_deg: norm(sub(estimate.psi_deg(), truth.psi_deg())),
            scale: norm(sub(estimate.scale(), truth.scale())),
            bias_nt: norm(sub(estimate.bias_nt(), truth.bias_nt())),
        }
    }
}

/// Summary statistics of one metric over the trials that succeeded, with the failed count beside
/// them (docs/conventions.md "Metrics").
///
/// Percentiles interpolate linearly between order statistics (Hyndman-Fan type 7, the default of
/// numpy and R). With no values every statistic is NaN; with one value `std` and `se_mean` are NaN.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Summary {
    /// Values summarised (successful trials).
    pub n: usize,
    /// Trials that failed and contribute no value.
    pub failed: usize,
    /// Arithmetic mean.
    pub mean: f64,
    /// Sample standard deviation (divisor `n - 1`).
    pub std: f64,
    /// Median (50th percentile).
    pub median: f64,
    /// 5th percentile.
    pub p05: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Standard error of the mean, `std / sqrt(n)`.
    pub se_mean: f64,
}

impl Summary {
    /// Summarises `values` (from successful trials) and records `failed` beside them.
    ///
    /// The mean is a plain sequential sum in the order given, so that the same values in the same
    /// order give the same bits whatever produced them.
    ///
    /// # Panics
    /// If a value is not finite: metrics of successful trials are finite, so this is a caller bug.
    #[track_caller]
    pub fn new(values: &[f64], failed: usize) -> Self {
        assert!(
            values.iter().all(|v| v.is_finite()),
            "Summary::new: values must be finite"
        );
        let n = values.len();
        let nf = n as f64;
        let mean = if n == 0 {
            f64::NAN
        } else {
            values.iter().sum::<f64>() / nf
        };
        let std = if n < 2 {
            f64::NAN
        } else {
            (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (nf - 1.0)).sqrt()
        };
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        Self {
            n,
            failed,
            mean,
            std,
            median: percentile(&sorted, 0.5),
            p05: percentile(&sorted, 0.05),
            p95: percentile(&sorted, 0.95),
            se_mean: std / nf.sqrt(),
        }
    }
}

/// The median of `values` (type 7, as [`Summary::median`]); NaN when empty.
pub fn median(values: &[f64]) -> f64 {
    median_of(&mut values.to_vec())
}

/// [`median`] of values the caller no longer needs in their order: they are reordered, not
/// copied (a long log's values are hundreds of megabytes).
pub fn median_of(v: &mut [f64]) -> f64 {
    // The two middle order statistics by selection (linear time), then the type-7 percentile
    // at 0.5 of them, as of the sorted values.
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    let lo = (n - 1) / 2;
    let (_, &mut a, above) = v.select_nth_unstable_by(lo, f64::total_cmp);
    if n % 2 == 1 {
        return a;
    }
    let b = above
        .iter()
        .copied()
        .min_by(f64::total_cmp)
        .expect("n even and positive");
    let h = (n - 1) as f64 * 0.5;
    a + (h - lo as f64) * (b - a)
}

/// Type-7 percentile `q` in [0, 1] of sorted values; NaN when empty.
fn percentile(sorted: &[f64], q: f64) -> f64 {
    match sorted.len() {
        0 => f64::NAN,
        n => {
            let h = (n - 1) as f64 * q;
            let lo = h.floor() as usize;
            let hi = (lo + 1).min(n - 1);
            sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The median by selection is the sorted values' type-7 percentile at 0.5, bit for bit.
    #[test]
    fn the_median_by_selection_is_the_sorted_one() {
        for n in 0..60 {
            let values: Vec<f64> = (0..n).map(|i| ((i * 7919 % 61) as f64 * 0.37).sin() * 1e3).collect();
            let mut sorted = values.clone();
            sorted.sort_by(f64::total_cmp);
            let want = percentile(&sorted, 0.5);
            assert_eq!(median(&values).to_bits(), want.to_bits(), "{n}");
        }
        assert!(median(&[]).is_nan());
        assert_eq!(median(&[2.0, f64::NAN, 1.0]).to_bits(), 2.0_f64.to_bits());
    }

    #[test]
    fn relative_errors_follow_eq_21_23() {
        let truth = crate::paper::true_error_model();
        let est = ErrorModel::new(
            [1.5 * 1.1, 0.8 * 1.1, 1.4 * 1.1],
            [1.3, 0.7, 1.2],
            [3000.0, -6000.0, 5000.0],
        )
        .unwrap();
        let e = RelativeErrors::between(&est, &truth);
        assert!((e.psi.unwrap() - 10.0).abs() < 1e-12, "{:?}", e.psi);
        assert!(e.scale.unwrap().abs() < 1e-12 && e.bias.unwrap().abs() < 1e-12);
        let eta = relative_error_percent([3.0, 4.0, 0.0], [0.0, 0.0, 10.0]).unwrap();
        assert!((eta - 100.0 * 125f64.sqrt() / 10.0).abs() < 1e-12);
    }

    #[test]
    fn relative_error_of_a_zero_truth_is_undefined_not_nan() {
        let nominal = ErrorModel::new([0.0; 3], [1.0; 3], [0.0; 3]).unwrap();
        let est = ErrorModel::new([0.1, 0.0, 0.0], [1.01, 1.0, 1.0], [5.0, 0.0, 0.0]).unwrap();
        let e = RelativeErrors::between(&est, &nominal);
        assert_eq!((e.psi, e.bias), (None, None));
        let a = AbsoluteErrors::between(&est, &nominal);
        assert!((a.psi_deg - 0.1).abs() < 1e-12 && (a.scale - 0.01).abs() < 1e-12 && (a.bias_nt - 5.0).abs() < 1e-9);
        assert!((e.scale.unwrap() - 100.0 * 0.01 / 3f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn summary_matches_hand_computation() {
        let v = [4.0, 1.0, 3.0, 2.0, 10.0];
        let s = Summary::new(&v, 2);
        assert_eq!((s.n, s.failed), (5, 2));
        assert!((s.mean - 4.0).abs() < 1e-15);
        // Sample variance: (0 + 9 + 1 + 4 + 36) / 4 = 12.5.
        assert!((s.std - 12.5f64.sqrt()).abs() < 1e-15);
        assert!((s.median - 3.0).abs() < 1e-15);
        // Type 7: h = 4 * 0.05 = 0.2 -> 1 + 0.2 (2 - 1); h = 3.8 -> 4 + 0.8 (10 - 4).
        assert!((s.p05 - 1.2).abs() < 1e-15);
        assert!((s.p95 - 8.8).abs() < 1e-14);
        assert!((s.se_mean - 12.5f64.sqrt() / 5f64.sqrt()).abs() < 1e-15);
    }

    #[test]
    fn summary_of_few_values() {
        let s = Summary::new(&[], 3);
        assert!(s.mean.is_nan() && s.median.is_nan() && s.failed == 3);
        let s = Summary::new(&[2.5], 0);
        assert!((s.mean - 2.5).abs() < 1e-15 && (s.p95 - 2.5).abs() < 1e-15 && s.std.is_nan());
    }
}
