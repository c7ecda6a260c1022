//! Plans a crew can fly: exact designs of `N` readings at **at most `K` distinct attitudes**, each
//! flown for **at least `R` readings**.
//!
//! The approximate D-optimal design of a box ([`super::approximate`]) can have thirty or more
//! support points (a box of every attitude has 37); rounded to 300 readings it asks a crew to hold
//! 37 attitudes, several for one or two readings. A plan with limits is an exact design with
//! replication: attitudes `x_1..x_L` (`L <= K`) and counts `n_i >= R` with `sum n_i = N`, whose
//! information is `M_F = sum n_i h(x_i) h(x_i)^T` (\[P1\] eq. (12)); it maximises `ln det M_F`
//! (\[P1\] eq. (14)) over the attitudes **and** the counts, not a truncation of the approximate
//! design.
//!
//! A reading repeated at one attitude repeats the same regression row `h` (\[P1\] eq. (9)): the
//! noise-free information of `L` attitudes has rank at most `L`, so a plan needs at least
//! `9` attitudes (the unknowns of \[P1\] eq. (9)), and hence `K >= 9` and `9 R <= N`.
//!
//! # Algorithm
//! When the efficient rounding of the approximate design ([`efficient_rounding`]) already meets
//! the limits, that rounding is the plan. Otherwise, with `L = min(K, floor(N / R), support size)`,
//! from several starts (the `L` support points of largest weight, then random subsets of `L`
//! support points drawn with probability by weight):
//! 1. weights on the `L` points by REX and the points moved over the continuous box with the
//!    weights held (projected L-BFGS), alternately: the approximate D-optimum on `L` points;
//! 2. counts by efficient rounding; a point below `R` readings is either raised to `R` (the
//!    readings taken one at a time where the determinant loses least) or dropped (and the rest
//!    rounded again); both are polished and the better kept;
//! 3. polish, until `ln det M_F` gains less than `1e-9`: moves of one reading from one attitude to
//!    another (never below `R`) while the determinant grows,
//!    `det(M + h_k h_k^T - h_l h_l^T) / det M = (1 + d_k)(1 - d_l) + d_kl^2` with
//!    `d_kl = h_k^T M^-1 h_l`; the attitudes moved over the box with the counts held; attitudes
//!    that meet (within 0.057 degrees) merged into one, their counts added.
//!
//! The plan of largest `ln det M_F` is kept (ties: the earlier start). Its certified D-efficiency
//! is `exp((ln det M_F - 9 ln N - ln_det_bound) / 9)` against the box's certificate
//! ([`super::approximate::Certificate::efficiency_bound`]): what the limits cost against every
//! design of `N` readings in the box, found by any method.
#![allow(non_snake_case)]

use rand::{Rng, RngExt, SeedableRng};
use rayon::prelude::*;

use super::DesignProblem;
use super::approximate::{
    ApproximateDesign, MERGE_RAD, P, Row, apply, certificate_search, dot9, efficient_rounding, information_inverse,
    ln_det_nt, merge, refine, rex, row,
};
use super::optimum::Optimum;
use crate::attitude::Attitude;
use crate::error::ParameterError;
use crate::rng::MagcalRng;

/// The limits a crew puts on a plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlanLimits {
    /// At most this many distinct attitudes (at least 9); `None`: no limit (as many as the
    /// rounding of the approximate design gives).
    pub max_attitudes: Option<usize>,
    /// At least this many readings at every attitude (at least 1; `9 R` at most the readings).
    pub min_readings: usize,
}

impl Default for PlanLimits {
    /// No limit: `max_attitudes = None`, `min_readings = 1`.
    fn default() -> Self {
        Self {
            max_attitudes: None,
            min_readings: 1,
        }
    }
}

impl PlanLimits {
    /// Checks the limits against a plan of `readings` readings.
    ///
    /// # Errors
    /// [`ParameterError::TooSmall`] for fewer than 9 readings, `max_attitudes < 9` or
    /// `min_readings = 0`; [`ParameterError::TooLarge`] for `min_readings > readings / 9` (nine
    /// attitudes, the fewest that identify the model, could not each get `R` readings).
    pub fn validate(&self, readings: usize) -> Result<(), ParameterError> {
        if readings < P {
            return Err(ParameterError::TooSmall {
                name: "readings",
                min: P,
                value: readings,
            });
        }
        if let Some(k) = self.max_attitudes
            && k < P
        {
            return Err(ParameterError::TooSmall {
                name: "max_attitudes",
                min: P,
                value: k,
            });
        }
        if self.min_readings == 0 {
            return Err(ParameterError::TooSmall {
                name: "min_readings_per_attitude",
                min: 1,
                value: 0,
            });
        }
        if self.min_readings > readings / P {
            return Err(ParameterError::TooLarge {
                name: "min_readings_per_attitude",
                max: readings / P,
                value: self.min_readings,
            });
        }
        Ok(())
    }

    /// Whether `counts` (one per attitude) meet the limits.
    pub fn admit(&self, counts: &[usize]) -> bool {
        self.max_attitudes.is_none_or(|k| counts.len() <= k) && counts.iter().all(|&n| n >= self.min_readings)
    }
}

/// Settings of the search for a plan with limits.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanSearch {
    /// Starts (the first from the heaviest support points, the others random subsets). Default 16.
    pub starts: usize,
    /// Alternations of REX and point refinement on a start's points before rounding. Default 4.
    pub rounds: usize,
    /// Alternations of reading moves and point refinement after rounding, at most. Default 20.
    pub polish_rounds: usize,
}

impl Default for PlanSearch {
    fn default() -> Self {
        Self {
            starts: 16,
            rounds: 4,
            polish_rounds: 20,
        }
    }
}

/// An exact design with replication: attitudes and readings at each.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Distinct attitudes, by decreasing readings.
    pub attitudes: Vec<Attitude>,
    /// Readings at each, summing to the plan's readings.
    pub readings: Vec<usize>,
    /// `ln det M_F` (nT) of all readings.
    pub ln_det_mf: f64,
    /// Certified lower bound of its D-efficiency against every design of as many readings in the
    /// box ([`super::approximate::Certificate::efficiency_bound`]).
    pub efficiency_bound: f64,
    /// `ln det M_F` (nT) of the efficient rounding of the approximate design without limits,
    /// against which the limits' cost is `exp((ln_det_mf - unlimited_ln_det_mf) / 9)`.
    pub unlimited_ln_det_mf: f64,
}

impl Plan {
    /// Readings in all.
    pub fn m(&self) -> usize {
        self.readings.iter().sum()
    }

    /// The D-efficiency of this plan relative to the rounding without limits (1 when the limits
    /// did not bind).
    pub fn relative_to_unlimited(&self) -> f64 {
        super::d_efficiency(self.ln_det_mf, self.unlimited_ln_det_mf)
    }
}

impl PlanSearch {
    /// Checks the settings.
    ///
    /// # Errors
    /// Zero starts or rounds.
    pub fn validate(&self) -> Result<(), ParameterError> {
        for (name, value) in [
            ("starts", self.starts),
            ("rounds", self.rounds),
            ("polish_rounds", self.polish_rounds),
        ] {
            if value == 0 {
                return Err(ParameterError::TooSmall { name, min: 1, value });
            }
        }
        Ok(())
    }

    /// The plan of `readings` readings within `limits`, from the approximate design `approximate`
    /// of `problem`'s box (its `m` is not used). Random choices (the starts' subsets, REX's order)
    /// come from seeds drawn from `rng` in start order; the starts run in parallel and the best is
    /// chosen in start order, so the result does not depend on the threads.
    ///
    /// # Errors
    /// Invalid settings or limits ([`PlanLimits::validate`]); [`ParameterError::Singular`] when
    /// no plan within the limits identifies the linear model (not for a valid approximate design).
    pub fn plan<R: Rng + ?Sized>(
        &self,
        problem: &DesignProblem,
        approximate: &ApproximateDesign,
        readings: usize,
        limits: PlanLimits,
        rng: &mut R,
    ) -> Result<Plan, ParameterError> {
        self.validate()?;
        limits.validate(readings)?;
        let singular = || ParameterError::Singular { name: "plan" };
        let counts = efficient_rounding(&approximate.weights, readings);
        let (unlimited, unlimited_counts): (Vec<Attitude>, Vec<usize>) = approximate
            .support
            .iter()
            .zip(counts)
            .filter(|(_, n)| *n > 0)
            .map(|(a, n)| (*a, n))
            .unzip();
        let unlimited_ln_det = ln_det_of(problem, &unlimited, &unlimited_counts);
        let finish = |attitudes: Vec<Attitude>, counts: Vec<usize>, ln_det_mf: f64| Plan {
            efficiency_bound: approximate.certificate.efficiency_bound(ln_det_mf, readings),
            attitudes,
            readings: counts,
            ln_det_mf,
            unlimited_ln_det_mf: unlimited_ln_det,
        };
        if limits.admit(&unlimited_counts) {
            return Ok(finish(unlimited, unlimited_counts, unlimited_ln_det));
        }
        let support = approximate.support.len();
        let size = limits
            .max_attitudes
            .unwrap_or(support)
            .min(readings / limits.min_readings)
            .min(support);
        if size < P {
            return Err(singular());
        }
        let seeds: Vec<u64> = (0..self.starts).map(|_| rng.random()).collect();
        let runs: Vec<Option<Candidate>> = seeds
            .into_par_iter()
            .enumerate()
            .map(|(start, seed)| {
                let mut rng = MagcalRng::seed_from_u64(seed);
                let chosen = if start == 0 {
                    (0..size).collect()
                } else {
                    weighted_subset(&approximate.weights, size, &mut rng)
                };
                self.one_start(problem, approximate, &chosen, readings, limits, &mut rng)
            })
            .collect();
        let best = runs
            .into_iter()
            .flatten()
            .fold(None::<Candidate>, |best, c| match best {
                Some(b) if b.ln_det >= c.ln_det => Some(b),
                _ => Some(c),
            })
            .ok_or_else(singular)?;
        let mut order: Vec<usize> = (0..best.points.len()).collect();
        order.sort_by(|&a, &b| best.counts[b].cmp(&best.counts[a]).then(a.cmp(&b)));
        let attitudes: Vec<Attitude> = order.iter().map(|&i| best.points[i]).collect();
        let counts: Vec<usize> = order.iter().map(|&i| best.counts[i]).collect();
        let ln_det = ln_det_of(problem, &attitudes, &counts);
        if !ln_det.is_finite() {
            return Err(singular());
        }
        Ok(finish(attitudes, counts, ln_det))
    }

    /// One start: the support points `chosen` of the approximate design, optimised as an
    /// approximate design on that many points, rounded, the limits enforced and polished.
    fn one_start<R: Rng + ?Sized>(
        &self,
        problem: &DesignProblem,
        approximate: &ApproximateDesign,
        chosen: &[usize],
        readings: usize,
        limits: PlanLimits,
        rng: &mut R,
    ) -> Option<Candidate> {
        let optimum = certificate_search();
        let mut points: Vec<Attitude> = chosen.iter().map(|&i| approximate.support[i]).collect();
        let mut rows: Vec<Row> = points.iter().map(|a| row(problem, a)).collect();
        let total: f64 = chosen.iter().map(|&i| approximate.weights[i]).sum();
        let mut weights: Vec<f64> = chosen.iter().map(|&i| approximate.weights[i] / total).collect();
        information_inverse(&rows, &weights)?;
        for _ in 0..self.rounds {
            rex(&rows, &mut weights, 1e-6, 200, rng)?;
            refine(problem, &optimum, &mut points, &mut rows, &mut weights);
        }
        let kept: Vec<(Attitude, f64)> = points
            .iter()
            .zip(&weights)
            .filter(|(_, w)| **w > 0.0)
            .map(|(a, w)| (*a, *w))
            .collect();
        let kept = merge(kept, MERGE_RAD);
        let points: Vec<Attitude> = kept.iter().map(|p| p.0).collect();
        let weights: Vec<f64> = kept.iter().map(|p| p.1).collect();
        let counts = efficient_rounding(&weights, readings);
        let mut variants = Vec::with_capacity(2);
        let positive = |points: &[Attitude], counts: &[usize]| -> (Vec<Attitude>, Vec<usize>) {
            points
                .iter()
                .zip(counts)
                .filter(|(_, n)| **n > 0)
                .map(|(a, n)| (*a, *n))
                .unzip()
        };
        // Equal counts (as equal as `readings` allows): the D-optimal weights of a design on
        // exactly 9 points, and a start that reading moves from the rounding do not reach when
        // the box has many optima (measured on a box of every attitude).
        let equal: Vec<usize> = (0..points.len())
            .map(|i| readings / points.len() + usize::from(i < readings % points.len()))
            .collect();
        if equal.iter().all(|&n| n >= limits.min_readings) {
            variants.push((points.clone(), equal));
        }
        let (p, c) = positive(&points, &counts);
        if c.iter().all(|&n| n >= limits.min_readings) {
            variants.push((p, c));
        } else {
            variants.push(raise(problem, &p, &c, readings, limits.min_readings)?);
            if let Some(dropped) = drop_smallest(&points, &weights, readings, limits.min_readings) {
                variants.push(dropped);
            }
        }
        // Both orders of the alternation: each reaches optima the other misses (measured: the
        // attitudes first from equal counts on a box of every attitude, the moves first on a
        // ground vehicle's box).
        variants
            .into_iter()
            .flat_map(|(p, c)| [(p.clone(), c.clone(), true), (p, c, false)])
            .filter_map(|(p, c, first)| self.polish(problem, &optimum, p, c, limits.min_readings, first))
            .fold(None, |best: Option<Candidate>, c| match best {
                Some(b) if b.ln_det >= c.ln_det => Some(b),
                _ => Some(c),
            })
    }

    /// Reading moves and point refinement with the counts held, alternately (the refinement
    /// first when `refine_first`), until `ln det M_F` gains less than `1e-9`; points that meet
    /// are merged. `None` for a singular start.
    fn polish(
        &self,
        problem: &DesignProblem,
        optimum: &Optimum,
        mut points: Vec<Attitude>,
        mut counts: Vec<usize>,
        min_readings: usize,
        refine_first: bool,
    ) -> Option<Candidate> {
        let readings: usize = counts.iter().sum();
        let mut ln_det = ln_det_of(problem, &points, &counts);
        if !ln_det.is_finite() {
            return None;
        }
        for _ in 0..self.polish_rounds {
            let mut rows: Vec<Row> = points.iter().map(|a| row(problem, a)).collect();
            if !refine_first {
                move_readings(&rows, &mut counts, min_readings);
            }
            let mut weights: Vec<f64> = counts.iter().map(|&n| n as f64 / readings as f64).collect();
            refine(problem, optimum, &mut points, &mut rows, &mut weights);
            // Refinement merged points that met into the earlier one, adding weights n / N.
            let moved: Vec<(Attitude, f64)> = points
                .iter()
                .zip(&weights)
                .filter(|(_, w)| **w > 0.0)
                .map(|(a, w)| (*a, (*w * readings as f64).round()))
                .collect();
            let merged = merge(moved, MERGE_RAD);
            points = merged.iter().map(|p| p.0).collect();
            counts = merged.iter().map(|p| p.1 as usize).collect();
            debug_assert_eq!(counts.iter().sum::<usize>(), readings);
            if refine_first {
                let rows: Vec<Row> = points.iter().map(|a| row(problem, a)).collect();
                move_readings(&rows, &mut counts, min_readings);
            }
            let next = ln_det_of(problem, &points, &counts);
            if !next.is_finite() {
                return None;
            }
            let gain = next - ln_det;
            ln_det = next;
            if gain < 1e-9 {
                break;
            }
        }
        Some(Candidate { points, counts, ln_det })
    }
}

/// A plan found from one start.
struct Candidate {
    points: Vec<Attitude>,
    counts: Vec<usize>,
    ln_det: f64,
}

/// `ln det M_F` (nT) of `counts` readings at `points`; `-inf` when singular.
fn ln_det_of(problem: &DesignProblem, points: &[Attitude], counts: &[usize]) -> f64 {
    let rows: Vec<Row> = points.iter().map(|a| row(problem, a)).collect();
    let weights: Vec<f64> = counts.iter().map(|&n| n as f64).collect();
    ln_det_nt(problem, &rows, &weights)
}

/// `size` distinct indices drawn with probability by weight, without replacement (Efraimidis and
/// Spirakis 2006, "Weighted random sampling with a reservoir": the largest keys `ln(u) / w`).
fn weighted_subset<R: Rng + ?Sized>(weights: &[f64], size: usize, rng: &mut R) -> Vec<usize> {
    let mut keys: Vec<(f64, usize)> = weights
        .iter()
        .enumerate()
        .map(|(i, &w)| {
            // u in (0, 1]: ln u is finite.
            let u = 1.0 - rng.random::<f64>();
            (u.ln() / w, i)
        })
        .collect();
    keys.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut chosen: Vec<usize> = keys[..size].iter().map(|k| k.1).collect();
    chosen.sort_unstable();
    chosen
}

/// Counts below `min` raised to `min`, then the excess readings taken one at a time from the
/// attitude (above `min`) whose reading adds least, `h_l^T M^-1 h_l` smallest
/// (`det(M - h h^T) = det M (1 - h^T M^-1 h)`). `None` when the design is singular.
fn raise(
    problem: &DesignProblem,
    points: &[Attitude],
    counts: &[usize],
    readings: usize,
    min: usize,
) -> Option<(Vec<Attitude>, Vec<usize>)> {
    let rows: Vec<Row> = points.iter().map(|a| row(problem, a)).collect();
    let mut counts: Vec<usize> = counts.iter().map(|&n| n.max(min)).collect();
    let mut total: usize = counts.iter().sum();
    while total > readings {
        let minv = information_inverse(&rows, &counts.iter().map(|&n| n as f64).collect::<Vec<_>>())?;
        let l = (0..rows.len()).filter(|&i| counts[i] > min).min_by(|&a, &b| {
            let d = |i: usize| dot9(&rows[i], &apply(&minv, &rows[i]));
            d(a).total_cmp(&d(b)).then(a.cmp(&b))
        })?;
        counts[l] -= 1;
        total -= 1;
    }
    Some((points.to_vec(), counts))
}

/// The points of smallest weight dropped one at a time, and the rest rounded again, until every
/// count reaches `min`. `None` when fewer than 9 points would be left.
fn drop_smallest(
    points: &[Attitude],
    weights: &[f64],
    readings: usize,
    min: usize,
) -> Option<(Vec<Attitude>, Vec<usize>)> {
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by(|&a, &b| weights[b].total_cmp(&weights[a]).then(a.cmp(&b)));
    loop {
        if order.len() < P {
            return None;
        }
        let w: Vec<f64> = order.iter().map(|&i| weights[i]).collect();
        let counts = efficient_rounding(&w, readings);
        if counts.iter().all(|&n| n >= min) {
            return Some((order.iter().map(|&i| points[i]).collect(), counts));
        }
        order.pop();
    }
}

/// Moves of one reading from attitude `l` (kept at `min` or more) to `k` while one raises
/// `det M`, the best move first: `det(M + h_k h_k^T - h_l h_l^T) / det M = (1 + d_k)(1 - d_l) +
/// d_kl^2`. Each move raises the determinant, so the moves end.
fn move_readings(rows: &[Row], counts: &mut [usize], min: usize) {
    let n = rows.len();
    // Each accepted move gains at least a relative 1e-12 of det M; a bound that no real plan
    // reaches keeps a pathological one finite.
    for _ in 0..(16 * counts.iter().sum::<usize>()).max(64) {
        let weights: Vec<f64> = counts.iter().map(|&c| c as f64).collect();
        let Some(minv) = information_inverse(rows, &weights) else {
            return;
        };
        let a: Vec<Row> = rows.iter().map(|h| apply(&minv, h)).collect();
        let d: Vec<f64> = (0..n).map(|i| dot9(&rows[i], &a[i])).collect();
        let mut best = (1.0 + 1e-12, None);
        for l in (0..n).filter(|&l| counts[l] > min) {
            for k in (0..n).filter(|&k| k != l) {
                let dkl = dot9(&rows[k], &a[l]);
                let ratio = (1.0 + d[k]) * (1.0 - d[l]) + dkl * dkl;
                if ratio > best.0 {
                    best = (ratio, Some((k, l)));
                }
            }
        }
        let Some((k, l)) = best.1 else { return };
        counts[k] += 1;
        counts[l] -= 1;
    }
}
