//! Brief departures from one field: runs of readings whose calibrated magnitude leaves the
//! field's by far more than noise and by a share that matters, as a sensor carried past a magnet
//! or a piece of iron gives (docs/conventions.md "One field").
//!
//! A change of the field that lasts ([`super::field_segments`]) is searched in blocks of a
//! second and parts of five; a pass by a magnet fixed in the room lasts a tenth of a second and
//! is gone. BROAD trial 30 (a magnet fixed in the room, 50,059 readings at 285.7 Hz) holds seven
//! such passes of 8 to 27 readings, at 45.6, 46.0, 84.4, 84.8, 126.0, 126.4 and 126.8 s, where the
//! magnitude drops by 13 to 60 % of the field (26.3 uT of 43.5) and comes back; its clean trials
//! 02 and 05 have none (their largest departure is 4.3 and 4.5 noise standard deviations, 7.6 %
//! of the field).
//!
//! # Method
//! `rho_t = |b_t| - R`, `b_t` the calibrated field and `R` the median of `|b_t|`; `sigma` the
//! robust standard deviation of `rho` (1.4826 times its median absolute deviation, which the
//! passes do not move). A reading **departs** when `|rho_t|` is at least the larger of
//! [`PASS_SHARE`] `R` (a departure that matters) and `z_n sigma` (one that noise does not make:
//! `z_n` the two-sided normal quantile at [`PASS_FALSE_ALARM`]` / n`, so that a log of `n`
//! readings of Gaussian noise has a departing reading with probability about 1 %). A **pass** is
//! a run of departing readings, widened on both sides while `|rho_t| > `[`PASS_EDGE_SIGMAS`]
//! `sigma` (the way in and out of the disturbance): departing runs joined by such readings are
//! one pass.
//!
//! What a pass does to the calibration is measured, not assumed: the caller refits the log
//! without the passes' readings and compares the estimates in their own standard errors
//! ([`PASS_SHIFT`]).

use rayon::prelude::*;
use statrs::distribution::{ContinuousCDF, Normal};

use crate::metrics::{median, median_of};
use crate::small::{Vec3, norm};

/// The smallest departure that counts: 10 % of the field's magnitude (a disturbance of a tenth of
/// the field turns the calibrated direction by up to 5.7 degrees). BROAD's clean trials reach 7.6
/// % at most (noise of 1.7 %), trial 30's passes 13 to 60 %.
pub const PASS_SHARE: f64 = 0.10;

/// The chance that a log of Gaussian noise alone holds a departing reading, the family-wise
/// level of the noise threshold `z_n sigma`: 1 %.
pub const PASS_FALSE_ALARM: f64 = 0.01;

/// The noise standard deviations at which a pass's edge ends: 3.
pub const PASS_EDGE_SIGMAS: f64 = 3.0;

/// Standard errors by which the calibration of the log without its passes may differ from the
/// calibration of the whole log, in every parameter, for the passes to leave it usable: 1. BROAD
/// 30 without its passes: psi2 moves by 4.7 white-noise standard errors, by 0.85 of those that
/// count the residuals' correlation in time (with `--time`).
pub const PASS_SHIFT: f64 = 1.0;

/// One run of readings that depart from the field.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pass {
    /// Index of its first reading.
    pub first: usize,
    /// Its readings.
    pub readings: usize,
    /// The departure `rho_t / R` of largest magnitude within it, signed.
    pub peak: f64,
}

/// The passes of a log and the thresholds they were found with.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Passes {
    /// `R`, the median calibrated magnitude.
    pub magnitude: f64,
    /// `sigma`, the robust standard deviation of `rho`.
    pub noise: f64,
    /// `z_n`, the noise standard deviations a departure needs.
    pub sigmas: f64,
    /// The departure a reading needs, the readings' units: `max(PASS_SHARE R, z_n sigma)`.
    pub threshold: f64,
    /// The runs found, in log order.
    pub passes: Vec<Pass>,
}

impl Passes {
    /// Readings within passes.
    pub fn readings(&self) -> usize {
        self.passes.iter().map(|p| p.readings).sum()
    }

    /// The passes that are brief on the clock `times` (one per reading): those of a cluster,
    /// passes less than `part_s` apart, that spans less than `part_s`. A longer cluster is a
    /// field that lasts (a magnet on the board, whose departure `u_t . d` turns through zero as
    /// the board turns and breaks into runs), for the search of changes to name
    /// ([`super::field_segments`], whose shortest part is `part_s`).
    ///
    /// # Panics
    /// If `times` is shorter than the log the passes were found in (a caller bug).
    #[track_caller]
    pub fn brief(&self, times: &[f64], part_s: f64) -> Passes {
        let last = |p: &Pass| times[p.first + p.readings - 1];
        let mut kept = Vec::new();
        let mut cluster: Vec<Pass> = Vec::new();
        let mut flush = |cluster: &mut Vec<Pass>| {
            if let (Some(a), Some(b)) = (cluster.first(), cluster.last())
                && last(b) - times[a.first] < part_s
            {
                kept.extend_from_slice(cluster);
            }
            cluster.clear();
        };
        for p in &self.passes {
            if cluster.last().is_some_and(|q| times[p.first] - last(q) >= part_s) {
                flush(&mut cluster);
            }
            cluster.push(*p);
        }
        flush(&mut cluster);
        Passes {
            passes: kept,
            ..self.clone()
        }
    }

    /// Per reading of a log of `n`, whether it lies outside every pass.
    pub fn keep(&self, n: usize) -> Vec<bool> {
        let mut keep = vec![true; n];
        for p in &self.passes {
            keep[p.first..p.first + p.readings].iter_mut().for_each(|k| *k = false);
        }
        keep
    }
}

/// `z_n`: the two-sided normal quantile at level `PASS_FALSE_ALARM / n`.
pub fn pass_sigmas(n: usize) -> f64 {
    let normal = Normal::new(0.0, 1.0).expect("the standard normal");
    normal.inverse_cdf(1.0 - PASS_FALSE_ALARM / (2.0 * n.max(1) as f64))
}

/// The passes of the calibrated fields `calibrated`, in log order (see the module
/// documentation). `None` for fewer than two readings or a magnitude that is not positive.
pub fn passes(calibrated: &[Vec3]) -> Option<Passes> {
    passes_in_magnitudes(calibrated.par_iter().map(|b| norm(*b)).collect())
}

/// [`passes`] of the calibrated readings' magnitudes `|b_i|`, in log order: for a caller that
/// need not hold the calibrated readings themselves.
pub fn passes_in_magnitudes(magnitudes: Vec<f64>) -> Option<Passes> {
    if magnitudes.len() < 2 {
        return None;
    }
    let r = median(&magnitudes);
    if !(r.is_finite() && r > 0.0) {
        return None;
    }
    let rho: Vec<f64> = magnitudes.into_par_iter().map(|m| m - r).collect();
    let sigma = 1.4826 * median_of(&mut rho.par_iter().map(|x| x.abs()).collect::<Vec<f64>>());
    let sigmas = pass_sigmas(rho.len());
    let threshold = (PASS_SHARE * r).max(sigmas * sigma);
    let edge = PASS_EDGE_SIGMAS * sigma;
    let mut found: Vec<Pass> = Vec::new();
    let mut t = 0;
    while t < rho.len() {
        if rho[t].abs() < threshold {
            t += 1;
            continue;
        }
        let mut first = t;
        while first > 0 && rho[first - 1].abs() > edge {
            first -= 1;
        }
        let mut end = t + 1;
        while end < rho.len() && rho[end].abs() > edge {
            end += 1;
        }
        let peak = rho[first..end]
            .iter()
            .copied()
            .max_by(|a, b| a.abs().total_cmp(&b.abs()))
            .expect("a pass holds a reading")
            / r;
        // The run before ended at a reading within the edge, so this one starts after it.
        found.push(Pass {
            first,
            readings: end - first,
            peak,
        });
        t = end;
    }
    Some(Passes {
        magnitude: r,
        noise: sigma,
        sigmas,
        threshold,
        passes: found,
    })
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng, rngs::ChaCha8Rng};
    use rand_distr::{Distribution, StandardNormal};

    use super::*;

    /// Readings on a sphere of radius 50 in random directions with Gaussian noise `sigma` per
    /// component.
    fn sphere(n: usize, sigma: f64, seed: u64) -> Vec<Vec3> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let d: Vec3 = std::array::from_fn(|_| StandardNormal.sample(&mut rng));
                let l = norm(d);
                std::array::from_fn(|i| {
                    50.0 * d[i] / l
                        + sigma * {
                            let z: f64 = StandardNormal.sample(&mut rng);
                            z
                        }
                })
            })
            .collect()
    }

    #[test]
    fn the_noise_threshold_is_the_bonferroni_quantile() {
        // 1 - 0.01 / (2 * 50,000) = 1 - 1e-7: z = 5.199 (tables).
        assert!((pass_sigmas(50_000) - 5.199).abs() < 1e-3, "{}", pass_sigmas(50_000));
        assert!((pass_sigmas(1) - 2.5758).abs() < 1e-4);
    }

    #[test]
    fn gaussian_logs_rarely_hold_a_pass() {
        // 200 logs of 5,000 readings at noise 5 % of the field (above PASS_SHARE / z_n, so the
        // noise threshold binds): a pass in about 1 % of them, at most 6 (binomial 200, 0.01:
        // P(X >= 7) < 0.5 %).
        let with: usize = (0..200)
            .filter(|s| !passes(&sphere(5_000, 2.5, *s)).expect("passes").passes.is_empty())
            .count();
        assert!(with <= 6, "{with} of 200 logs hold a pass");
    }

    #[test]
    fn a_pass_is_found_with_its_edges_and_peak() {
        let mut b = sphere(5_000, 0.5, 7);
        // A disturbance of 20 readings rising to -30 % and back, at 1000.
        let bump = |k: usize| -0.30 * (std::f64::consts::PI * (k as f64 + 0.5) / 20.0).sin();
        for k in 0..20 {
            let m = norm(b[1000 + k]);
            let f = 1.0 + bump(k) * 50.0 / m;
            b[1000 + k] = b[1000 + k].map(|v| v * f);
        }
        let p = passes(&b).expect("passes");
        assert_eq!(p.passes.len(), 1, "{p:?}");
        let pass = p.passes[0];
        // The edges lie where the bump falls under 3 sigma (1.5 of 50, 3 %) give or take the
        // noise: within 2 readings of 1000 and 1020.
        assert!(
            pass.first.abs_diff(1000) <= 2 && (pass.first + pass.readings).abs_diff(1020) <= 2,
            "{pass:?}"
        );
        assert!((pass.peak + 0.30).abs() < 0.03, "{pass:?}");
        assert_eq!(p.readings(), pass.readings);
        assert_eq!(p.keep(5_000).iter().filter(|k| !**k).count(), pass.readings);
    }

    #[test]
    fn departures_joined_above_the_edge_are_one_pass() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut b: Vec<Vec3> = (0..2_000)
            .map(|_| [50.0 + rng.random_range(-0.01..0.01), 0.0, 0.0])
            .collect();
        // Two departures of -20 % joined by readings at -5 % (above 3 sigma, below the share).
        for (k, v) in [(500, 40.0), (501, 47.5), (502, 47.5), (503, 40.0)] {
            b[k] = [v, 0.0, 0.0];
        }
        let p = passes(&b).expect("passes");
        assert_eq!(p.passes.len(), 1, "{p:?}");
        assert_eq!((p.passes[0].first, p.passes[0].readings), (500, 4));
        assert!((p.passes[0].peak + 0.2).abs() < 1e-3);
    }

    #[test]
    fn clusters_that_last_are_not_brief() {
        let p = Passes {
            magnitude: 1.0,
            noise: 0.01,
            sigmas: 5.0,
            threshold: 0.1,
            passes: [(10, 5), (40, 5), (200, 5), (230, 5), (260, 5), (290, 5), (600, 5)]
                .map(|(first, readings)| Pass {
                    first,
                    readings,
                    peak: 0.2,
                })
                .to_vec(),
        };
        // 10 readings a second: the first two within 3.4 s (brief), the next four spanning 9.4 s
        // with gaps of 2.6 s (a field that lasts), the last alone.
        let times: Vec<f64> = (0..1000).map(|i| f64::from(i) / 10.0).collect();
        let firsts: Vec<usize> = p.brief(&times, 5.0).passes.iter().map(|q| q.first).collect();
        assert_eq!(firsts, [10, 40, 600]);
    }

    #[test]
    fn too_few_readings_or_no_field_give_none() {
        assert!(passes(&[[1.0, 0.0, 0.0]]).is_none());
        assert!(passes(&[[0.0; 3]; 10]).is_none());
    }
}
