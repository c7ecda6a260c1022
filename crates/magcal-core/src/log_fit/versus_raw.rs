//! Whether a calibration's heading against a log's reference attitudes is worse than the raw
//! readings' beyond what chance gives (docs/conventions.md "One field").
//!
//! Both headings are fitted to the same attitudes ([`crate::reference::align`], `Q` and `F` each
//! their own), reading by reading: `e_c(t)` calibrated, `e_r(t)` raw. The figure is the
//! difference of their rms, `D = rms e_c - rms e_r`. Its errors are correlated in time (the
//! attitude moves slowly, and with it what a calibration gets wrong; the reference's own errors
//! drift), so its standard error comes from whole blocks of time: the delete-one-block jackknife
//! over blocks of `block_s` seconds (Kunsch 1989), `se^2 = (B - 1) / B sum_b (D_-b - mean D_-b)^2`.
//! `Q` and `F` are held at the fit of all readings (their own scatter over a log of thousands of
//! readings is far below the blocks').
//!
//! The calibration is **worse** when `D > k se` ([`WORSE_SIGMAS`], one-sided) with at least
//! [`MIN_BLOCKS`] blocks; with fewer the figure is given and no verdict.

/// Standard errors by which a calibrated heading rms must exceed the raw one to be worse: 3
/// (one-sided 0.13 % for a normal difference; 2 of 200 simulated logs of a calibration as good
/// as raw, the test `a_calibration_as_good_as_raw_is_rarely_called_worse`). Measured with 10-s
/// blocks, calibrated minus raw (its standard error) in degrees, every reading with an
/// attitude: BROAD 02 -0.019 (0.032), 05 -0.073 (0.022), 30 (a magnet fixed in the room)
/// -0.0015 (0.085); the movement rows alone: 02 -0.072 (0.047), 05 -0.12 (0.041), 30 +0.090
/// (0.095). Fits that run away: 10 +16.0 (0.62), 33 +36.9 (8.4).
pub const WORSE_SIGMAS: f64 = 3.0;

/// The fewest blocks for a verdict: 5 (the jackknife's standard error from fewer is too unsure).
pub const MIN_BLOCKS: usize = 5;

/// The comparison of a calibrated and a raw heading over the same readings.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct HeadingVersusRaw {
    /// RMS of the calibrated heading errors, degrees.
    pub calibrated_rms_deg: f64,
    /// RMS of the raw ones, degrees.
    pub raw_rms_deg: f64,
    /// `calibrated - raw`, degrees.
    pub difference_deg: f64,
    /// The jackknife standard error of the difference, degrees; `None` with fewer than
    /// [`MIN_BLOCKS`] blocks.
    pub std_error_deg: Option<f64>,
    /// Blocks of time.
    pub blocks: usize,
    /// `WORSE_SIGMAS` standard errors, degrees (`None` with the standard error).
    pub limit_deg: Option<f64>,
    /// The calibration is worse than the raw readings beyond chance.
    pub worse: bool,
}

/// The block of each reading: `floor((t - t_0) / block_s)`, for times in order.
pub fn time_blocks(times: &[f64], block_s: f64) -> Vec<usize> {
    let t0 = times.first().copied().unwrap_or(0.0);
    times
        .iter()
        .map(|t| ((t - t0) / block_s).floor().max(0.0) as usize)
        .collect()
}

/// The comparison of `calibrated` and `raw` heading errors (degrees) of the same readings, in
/// blocks `blocks` (one id per reading, non-decreasing, as [`time_blocks`] gives). `None` without
/// readings.
///
/// # Panics
/// Slices of different lengths.
#[track_caller]
pub fn heading_versus_raw(blocks: &[usize], calibrated: &[f64], raw: &[f64]) -> Option<HeadingVersusRaw> {
    assert!(
        blocks.len() == calibrated.len() && blocks.len() == raw.len(),
        "one block and two heading errors per reading"
    );
    if blocks.is_empty() {
        return None;
    }
    // Per block: readings and the sums of squares of both.
    let mut sums: Vec<(f64, f64, f64)> = Vec::new();
    let mut last = None;
    for ((b, c), r) in blocks.iter().zip(calibrated).zip(raw) {
        if last != Some(*b) {
            sums.push((0.0, 0.0, 0.0));
            last = Some(*b);
        }
        if let Some(s) = sums.last_mut() {
            *s = (s.0 + 1.0, s.1 + c * c, s.2 + r * r);
        }
    }
    let total = sums
        .iter()
        .fold((0.0, 0.0, 0.0), |a, s| (a.0 + s.0, a.1 + s.1, a.2 + s.2));
    let difference = |(n, c, r): (f64, f64, f64)| (c / n).sqrt() - (r / n).sqrt();
    let d = difference(total);
    let b = sums.len();
    let std_error = (b >= MIN_BLOCKS).then(|| {
        let left_out: Vec<f64> = sums
            .iter()
            .map(|s| difference((total.0 - s.0, total.1 - s.1, total.2 - s.2)))
            .collect();
        let mean = left_out.iter().sum::<f64>() / b as f64;
        ((b as f64 - 1.0) / b as f64 * left_out.iter().map(|x| (x - mean).powi(2)).sum::<f64>()).sqrt()
    });
    let limit = std_error.map(|s| WORSE_SIGMAS * s);
    Some(HeadingVersusRaw {
        calibrated_rms_deg: (total.1 / total.0).sqrt(),
        raw_rms_deg: (total.2 / total.0).sqrt(),
        difference_deg: d,
        std_error_deg: std_error,
        blocks: b,
        limit_deg: limit,
        worse: limit.is_some_and(|l| d > l),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::{MagcalRng, stream_rng};
    use rand_distr::{Distribution, StandardNormal};

    /// Unit-variance AR(1) noise of correlation time `tau_s` at `rate` Hz.
    fn ar1(n: usize, rate: f64, tau_s: f64, rng: &mut MagcalRng) -> Vec<f64> {
        let phi = (-1.0 / (rate * tau_s)).exp();
        let innovation = (1.0 - phi * phi).sqrt();
        let mut e: f64 = StandardNormal.sample(rng);
        (0..n)
            .map(|_| {
                let v = e;
                e = phi * e + innovation * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, rng);
                v
            })
            .collect()
    }

    #[test]
    fn constant_errors_give_their_difference_exactly() {
        // Every calibrated error 2 degrees, every raw one 1: rms 2 and 1, difference 1, and the
        // same in every block, so its standard error is 0.
        let times: Vec<f64> = (0..600).map(|i| f64::from(i) * 0.1).collect();
        let blocks = time_blocks(&times, 10.0);
        let v = heading_versus_raw(&blocks, &vec![2.0; 600], &vec![-1.0; 600]).unwrap();
        assert_eq!(v.blocks, 6);
        assert!((v.difference_deg - 1.0).abs() < 1e-12 && v.std_error_deg.is_some_and(|s| s < 1e-12));
        assert!(v.worse);
        let same = heading_versus_raw(&blocks, &vec![1.0; 600], &vec![-1.0; 600]).unwrap();
        assert!(same.difference_deg.abs() < 1e-12 && !same.worse);
    }

    #[test]
    fn too_few_blocks_give_no_verdict() {
        let times: Vec<f64> = (0..40).map(f64::from).collect();
        let blocks = time_blocks(&times, 10.0);
        let v = heading_versus_raw(&blocks, &vec![5.0; 40], &vec![1.0; 40]).unwrap();
        assert_eq!((v.blocks, v.std_error_deg, v.worse), (4, None, false));
        assert!(heading_versus_raw(&[], &[], &[]).is_none());
    }

    /// Heading errors of 170 s at 285.7 Hz: a part both share (the reference's own, 2.5 degrees,
    /// correlated over 3 s) and a part of each (`own` degrees each, correlated over 3 s), the
    /// calibrated one's scaled by `1 + worse`.
    fn headings(own: f64, worse: f64, rng: &mut MagcalRng) -> (Vec<usize>, Vec<f64>, Vec<f64>) {
        let rate = 285.714;
        let n = (170.0 * rate) as usize;
        let times: Vec<f64> = (0..n).map(|i| i as f64 / rate).collect();
        let shared = ar1(n, rate, 3.0, rng);
        let (a, b) = (ar1(n, rate, 3.0, rng), ar1(n, rate, 3.0, rng));
        let raw = (0..n).map(|i| 2.5 * shared[i] + own * a[i]).collect();
        let calibrated = (0..n).map(|i| 2.5 * shared[i] + own * (1.0 + worse) * b[i]).collect();
        (time_blocks(&times, 10.0), calibrated, raw)
    }

    #[test]
    fn a_calibration_as_good_as_raw_is_rarely_called_worse() {
        // 200 logs where the two headings differ by chance only (1 degree of each's own error):
        // measured 2 of 200 called worse; a normal difference would give 0.13 %, the jackknife's
        // standard error from 17 blocks is itself unsure (Student's t of 16 degrees of freedom:
        // 0.4 %), and errors correlated over 3 s leak across blocks of 10 s.
        let worse = (0..200)
            .filter(|k| {
                let (blocks, c, r) = headings(1.0, 0.0, &mut stream_rng(0x4EAD, *k));
                heading_versus_raw(&blocks, &c, &r).unwrap().worse
            })
            .count();
        assert!(worse <= 2, "{worse} of 200");
    }

    #[test]
    fn a_calibration_much_worse_than_raw_is_called_worse() {
        // Its own error 4 degrees where the raw readings' is 1: rms sqrt(2.5^2 + 16) = 4.72
        // against sqrt(2.5^2 + 1) = 2.69, 2.03 more. Errors correlated over 3 s leave 170 s
        // about 30 independent draws: measured differences 1.37 to 3.24 (standard errors near
        // 0.40), called worse in 19 logs of 20. Own error 2 (0.51 more): 0.02 to 1.09, standard
        // errors near 0.24, called worse in 7 of 20.
        for (own, expected, least) in [(4.0, 2.03, 18), (2.0, 0.51, 0)] {
            let called = (0..20)
                .filter(|k| {
                    let (blocks, c, r) = headings(1.0, own - 1.0, &mut stream_rng(0x4EAE, *k));
                    let v = heading_versus_raw(&blocks, &c, &r).unwrap();
                    assert!((v.difference_deg - expected).abs() < 1.5, "log {k}: {v:?}");
                    v.worse
                })
                .count();
            assert!(called >= least, "own error {own}: {called} of 20");
        }
    }
}
