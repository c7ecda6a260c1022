//! Outlier rejection of a log: readings whose residual lies more than K robust standard
//! deviations from the median are dropped and the log refitted, until the kept set is stable.
//!
//! What is kept is a normal sample truncated at K standard deviations: it scatters less than the
//! sensor's noise, by [`truncated_variance_factor`]. [`super::FitSettings::truncation`] corrects
//! the noise estimate and the standard errors of the fit of the kept readings for it.

use super::LogFit;
use crate::calibration::CalibrationError;
use crate::small::{Vec3, norm};

/// The smallest K accepted: below 2 robust standard deviations a clean normal log loses more
/// than 4.6 % of its readings, and the kept set follows the fit rather than the sensor.
pub const REJECT_MIN_K: f64 = 2.0;

/// The largest share of a log that rejection may drop: more than a tenth is not outliers but
/// the log itself (a moving magnet, a second sensor state), which no refit of the rest describes.
pub const REJECT_MAX_SHARE: f64 = 0.1;

/// Rounds of rejection before a kept set that keeps changing is an error.
const MAX_ROUNDS: usize = 100;

/// Why outlier rejection gave no kept set.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RejectError {
    /// K below [`REJECT_MIN_K`] or not finite.
    #[error(
        "K = {k}: must be at least {REJECT_MIN_K} robust standard deviations (below that a clean normal log loses more than 4.6 % of its readings)"
    )]
    TooSmall {
        /// The K given.
        k: f64,
    },
    /// More than [`REJECT_MAX_SHARE`] of the readings would be dropped.
    #[error(
        "K = {k} drops {dropped} of {readings} readings, more than {} %: that is not outliers but the log; give a larger K or clean the log",
        100.0 * REJECT_MAX_SHARE
    )]
    TooMany {
        /// The K given.
        k: f64,
        /// Readings it would drop.
        dropped: usize,
        /// Readings of the log.
        readings: usize,
    },
    /// The kept set did not settle in 100 rounds.
    #[error("K = {k}: the kept set still changes after {MAX_ROUNDS} rounds")]
    Unstable {
        /// The K given.
        k: f64,
    },
    /// A round's fit failed.
    #[error("no calibration of the {kept} readings kept: {why}")]
    Fit {
        /// Readings kept in that round.
        kept: usize,
        /// Why (a field, not an error source: the message already holds it once).
        why: CalibrationError,
    },
}

/// The outcome of [`reject_outliers`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Rejection {
    /// Per reading, whether it is kept.
    pub keep: Vec<bool>,
    /// Readings dropped.
    pub dropped: usize,
    /// Fits made (rounds until the kept set was stable).
    pub rounds: usize,
    /// The K used.
    pub k: f64,
    /// The truncation's half-width: K robust standard deviations of the last round, in the
    /// readings' units (the distance from the ellipsoid beyond which a reading was dropped); the
    /// fit of the kept readings takes it as [`super::FitSettings::truncation`].
    pub half_width: f64,
}

impl Rejection {
    /// The kept readings, in order.
    pub fn kept<T: Copy>(&self, items: &[T]) -> Vec<T> {
        items
            .iter()
            .zip(&self.keep)
            .filter(|(_, k)| **k)
            .map(|(x, _)| *x)
            .collect()
    }
}

/// `Var(X | |X| <= K) / Var(X)` for a normal `X` in units of its standard deviation:
/// `1 - 2 K phi(K) / (2 Phi(K) - 1)` (0.774 at K = 2, 0.973 at K = 3, 1 at infinity).
pub fn truncated_variance_factor(k: f64) -> f64 {
    use statrs::distribution::{Continuous, ContinuousCDF, Normal};
    let n = Normal::standard();
    let inside = 2.0 * n.cdf(k) - 1.0;
    if inside <= 0.0 {
        return 0.0;
    }
    (1.0 - 2.0 * k * n.pdf(k) / inside).max(0.0)
}

/// The signed distance of a raw reading from a fit's ellipsoid, to first order:
/// `(|b| - R) / |P^T u|` with `b = P (s - O)` and `u = b / |b|`. Its scatter is the sensor's
/// noise whatever the direction (the calibrated residual `|b| - R` scatters `|P^T u|` times
/// more, unequally for unequal scale factors, which would give a mixture of normals with heavier
/// tails than the truncation assumes).
fn distance(f: &LogFit, s: Vec3) -> f64 {
    let b = f.apply(s);
    let n = norm(b);
    let u = if n > 0.0 { b.map(|v| v / n) } else { [1.0, 0.0, 0.0] };
    (n - f.magnitude) / norm(crate::small::mat_t_vec(&f.p, u))
}

/// Rounds of rejection: fit the kept readings with `fit`, keep every reading whose distance
/// from the fitted ellipsoid (in the readings' units) lies within `k` robust standard deviations (1.4826 median absolute
/// deviations, [`crate::metrics::median`]) of the median residual, until the kept set is stable
/// (or cycles: then the readings kept in every set of the cycle).
///
/// # Errors
/// [`RejectError`]: `k` below [`REJECT_MIN_K`], a round that would drop more than
/// [`REJECT_MAX_SHARE`], a kept set that does not settle, or a fit that fails.
pub fn reject_outliers(
    readings: &[Vec3],
    k: f64,
    mut fit: impl FnMut(&[Vec3]) -> Result<LogFit, CalibrationError>,
) -> Result<Rejection, RejectError> {
    use crate::metrics::median;
    if !(k.is_finite() && k >= REJECT_MIN_K) {
        return Err(RejectError::TooSmall { k });
    }
    // Distances within rounding of the readings' spread (an exact fit, noise-free readings) are
    // no scatter to reject by: nothing is nearer than rounding.
    let n = readings.len().max(1) as f64;
    let mean = [0, 1, 2].map(|i| readings.iter().map(|s| s[i]).sum::<f64>() / n);
    let cloud = (readings
        .iter()
        .map(|s| norm(crate::small::sub(*s, mean)).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    let rounding = 1e-9 * cloud;
    let mut keep = vec![true; readings.len()];
    let mut history: Vec<Vec<bool>> = Vec::new();
    for round in 1..=MAX_ROUNDS {
        let kept: Vec<Vec3> = readings
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(s, _)| *s)
            .collect();
        let f = fit(&kept).map_err(|why| RejectError::Fit { kept: kept.len(), why })?;
        let r: Vec<f64> = readings.iter().map(|s| distance(&f, *s)).collect();
        let centre = median(&r);
        let spread = 1.4826 * median(&r.iter().map(|x| (x - centre).abs()).collect::<Vec<_>>());
        if k * spread <= rounding && r.iter().all(|x| (x - centre).abs() <= rounding) {
            return Ok(Rejection {
                keep: vec![true; readings.len()],
                dropped: 0,
                rounds: round,
                k,
                half_width: 0.0,
            });
        }
        let next: Vec<bool> = r.iter().map(|x| (x - centre).abs() <= k * spread).collect();
        let dropped = next.iter().filter(|k| !**k).count();
        if dropped as f64 > REJECT_MAX_SHARE * readings.len() as f64 {
            return Err(RejectError::TooMany {
                k,
                dropped,
                readings: readings.len(),
            });
        }
        if next == keep {
            return Ok(Rejection {
                keep,
                dropped,
                rounds: round,
                k,
                half_width: k * spread,
            });
        }
        // Readings at the edge can flip back and forth between two fits: a kept set seen before
        // closes a cycle, and the readings kept in every set of it are kept.
        if let Some(start) = history.iter().position(|h| *h == next) {
            let keep: Vec<bool> = (0..readings.len())
                .map(|i| history[start..].iter().all(|h| h[i]) && next[i])
                .collect();
            let dropped = keep.iter().filter(|k| !**k).count();
            if dropped as f64 > REJECT_MAX_SHARE * readings.len() as f64 {
                return Err(RejectError::TooMany {
                    k,
                    dropped,
                    readings: readings.len(),
                });
            }
            return Ok(Rejection {
                keep,
                dropped,
                rounds: round,
                k,
                half_width: k * spread,
            });
        }
        history.push(std::mem::replace(&mut keep, next));
    }
    Err(RejectError::Unstable { k })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_truncated_variance_factor_matches_its_integral() {
        // Var(X | |X| <= K) by the midpoint rule on 200,000 cells of [-K, K]: the rule's error is
        // of order (h^2 / 24) max |f''| K, below 1e-9 here.
        for k in [0.5, 2.0, 3.0, 5.0] {
            let n = 200_000;
            let h = 2.0 * k / n as f64;
            let (mut mass, mut second) = (0.0, 0.0);
            for i in 0..n {
                let x = -k + (i as f64 + 0.5) * h;
                let w = (-0.5 * x * x).exp();
                mass += w;
                second += w * x * x;
            }
            let got = truncated_variance_factor(k);
            assert!((got - second / mass).abs() < 1e-9, "{k}: {got} vs {}", second / mass);
        }
        assert!((truncated_variance_factor(40.0) - 1.0).abs() <= f64::EPSILON);
    }
}
