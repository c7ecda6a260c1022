//! Approximate D-optimal designs over the continuous attitude box and their certificate
//! (docs/conventions.md "Certified D-efficiency"; Kiefer-Wolfowitz equivalence theorem, Atwood's
//! bound).
//!
//! An approximate design `xi` is a set of attitudes with weights `w_i > 0`, `sum w_i = 1`; its
//! normalised information is `M(xi) = sum w_i h(x_i) h(x_i)^T` with `h` the regression row of the
//! noise-free reading (\[P1\] eq. (9)). Its variance function is `d(x) = h(x)^T M(xi)^-1 h(x)`.
//! For every design `ln det M* <= ln det M(xi) + p ln(d_max / p)`, `d_max = max over the box of
//! d(x)`, `p = 9`, with equality exactly at the optimum (where `d_max = p`). An exact design of
//! `m` readings has `M_F = m M(xi_m)`, so
//! `ln det M_F <= 9 ln m + ln det M(xi) + 9 ln(d_max / 9)` for **every** m-reading design in the
//! box: a bound computed once per box, against which any design's D-efficiency is certified.
//!
//! # Algorithm
//! 1. Candidates: a grid over the box (yaw periodic when it spans a turn), about
//!    [`Approximate::candidates`] attitudes.
//! 2. Weights on the candidates by the randomised exchange algorithm REX (Harman, Filova,
//!    Richtarik 2020, "A randomized exchange algorithm for computing optimal approximate designs
//!    of experiments", JASA 115): per iteration, the leading exchange between the candidate of
//!    largest variance and the support point of smallest, then optimal pairwise exchanges
//!    between the support and the `4p` candidates of largest variance, in random order. The
//!    optimal weight `alpha` moved from `l` to `k` maximises
//!    `det M(xi + alpha (e_k - e_l)) / det M(xi) = 1 + alpha (d_k - d_l) - alpha^2 (d_k d_l - d_kl^2)`,
//!    clipped to `[-w_k, w_l]`; `M^-1` follows by two Sherman-Morrison updates and is recomputed
//!    from scratch every iteration.
//! 3. The certificate: multi-start local maximisation of `d(x)` over the continuous box (projected
//!    L-BFGS, the same as [`super::optimum`]), from the support and from the candidates of largest
//!    variance that lie apart from each other.
//! 4. While `d_max > p (1 + tolerance)`, the maximisers found join the candidates and REX goes on
//!    from the current weights (the support points move off the grid to where the continuous box
//!    wants them). The last certificate is the one reported, whether or not it met the tolerance.
//!
//! The maximum found by multi-start local search is a lower estimate of the true `d_max`; the
//! bound is as good as that search (docs/conventions.md's check values are reproduced; see the tests).
#![allow(non_snake_case)]
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

use rand::Rng;
use rand::seq::SliceRandom;
use rayon::prelude::*;

use super::DesignProblem;
use super::optimum::{Optimum, bounds_of};
use crate::attitude::Attitude;
use crate::error::ParameterError;
use crate::linear_model::{UNKNOWNS, regression_row};
use crate::small::{Mat9, spd_inverse};
use crate::stop::{Stop, Stopped};

pub(super) const P: usize = UNKNOWNS;
pub(super) type Row = [f64; P];

/// Settings of the approximate design and its certificate.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Approximate {
    /// About how many grid candidates (the grid has the same angular step on every angle,
    /// at least 2 levels per bounded angle and 4 per periodic one). Default 20,000.
    pub candidates: usize,
    /// The certificate is met when `d_max <= p (1 + tolerance)`: the design is then at least
    /// `1 / (1 + tolerance)` D-efficient. Default 1e-4.
    pub tolerance: f64,
    /// Rounds of (REX on the candidates, certificate search, new candidates). Default 12.
    pub max_rounds: usize,
    /// REX iterations per round. Default 200.
    pub max_iterations: usize,
    /// Local maximisations of the variance function per certificate, besides those from the
    /// support points. Default 48.
    pub starts: usize,
}

impl Default for Approximate {
    fn default() -> Self {
        Self {
            candidates: 20_000,
            tolerance: 1e-4,
            max_rounds: 12,
            max_iterations: 200,
            starts: 48,
        }
    }
}

/// The certificate of an approximate design: the largest variance found over the box.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Certificate {
    /// `d_max`, the largest `h(x)^T M(xi)^-1 h(x)` found over the continuous box (`p = 9` at the
    /// optimum).
    pub d_max: f64,
    /// Where it was found.
    pub at: Attitude,
    /// Upper bound on `ln det M*` of the normalised information of any design in the box, with
    /// `H` in nT: `ln det M(xi) + 9 ln(d_max / 9)` (Atwood).
    pub ln_det_bound: f64,
}

impl Certificate {
    /// Upper bound on `ln det M_F` (nT) of any design of `m` readings in the box:
    /// `9 ln m + ln_det_bound`.
    pub fn ln_det_mf_bound(&self, m: usize) -> f64 {
        super::ln_det_of_count(m) + self.ln_det_bound
    }

    /// Certified lower bound of the D-efficiency of a design of `m` readings with `ln det M_F`
    /// (nT) `ln_det_mf`, against every design of `m` readings in the box:
    /// `exp((ln det M_F - bound) / 9)`. 0 for a singular design. Above 1 only if the certificate
    /// missed the true maximum of the variance function.
    pub fn efficiency_bound(&self, ln_det_mf: f64, m: usize) -> f64 {
        if ln_det_mf == f64::NEG_INFINITY {
            return 0.0;
        }
        ((ln_det_mf - self.ln_det_mf_bound(m)) / P as f64).exp()
    }

    /// `true` when `d_max <= 9 (1 + tolerance)`.
    pub fn is_met(&self, tolerance: f64) -> bool {
        self.d_max <= P as f64 * (1.0 + tolerance)
    }
}

/// An approximate design: support points, weights and its certificate.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct ApproximateDesign {
    /// Support attitudes (in the box), by decreasing weight.
    pub support: Vec<Attitude>,
    /// Their weights, summing to 1.
    pub weights: Vec<f64>,
    /// `ln det M(xi)` of the normalised information, `H` in nT.
    pub ln_det: f64,
    /// The certificate of the final design.
    pub certificate: Certificate,
    /// Whether the certificate met the tolerance.
    pub converged: bool,
    /// Rounds made.
    pub rounds: usize,
    /// Candidates at the end (grid and added maximisers).
    pub candidates: usize,
}

impl Approximate {
    /// Checks the settings.
    ///
    /// # Errors
    /// Fewer than 9 candidates, zero rounds, iterations or starts; a tolerance that is not
    /// positive and finite.
    pub fn validate(&self) -> Result<(), ParameterError> {
        if self.candidates < P {
            return Err(ParameterError::TooSmall {
                name: "candidates",
                min: P,
                value: self.candidates,
            });
        }
        for (name, value) in [
            ("max_rounds", self.max_rounds),
            ("max_iterations", self.max_iterations),
            ("starts", self.starts),
        ] {
            if value == 0 {
                return Err(ParameterError::TooSmall { name, min: 1, value });
            }
        }
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return Err(ParameterError::NotPositive {
                name: "tolerance",
                value: self.tolerance,
            });
        }
        Ok(())
    }

    /// The approximate D-optimal design of `problem`'s box, field and sensor (its `m` is not
    /// used), with its certificate. Random choices (REX's order) come from `rng`; the result does
    /// not depend on the threads.
    ///
    /// # Errors
    /// Invalid settings; [`ParameterError::Singular`] when no design on the candidate grid has a
    /// non-singular information (the box does not identify the linear model at all).
    pub fn compute<R: Rng + ?Sized>(
        &self,
        problem: &DesignProblem,
        rng: &mut R,
    ) -> Result<ApproximateDesign, ParameterError> {
        self.search(problem, rng, &Stop::NEVER)
    }

    /// [`Self::compute`], giving up when `stop` is requested: it is asked before every round,
    /// every REX iteration, every support point of an iteration's exchanges (a few hundred
    /// exchanges, well under a millisecond each) and every start of the certificate's local
    /// search. Where it is never requested, the same design as [`Self::compute`]'s, from the same
    /// draws of `rng`.
    ///
    /// # Errors
    /// [`Stopped`] when `stop` is requested before it returns (nothing of the search is kept);
    /// else as [`Self::compute`], inside.
    pub fn compute_until<R: Rng + ?Sized>(
        &self,
        problem: &DesignProblem,
        rng: &mut R,
        stop: &Stop,
    ) -> Result<Result<ApproximateDesign, ParameterError>, Stopped> {
        let design = self.search(problem, rng, stop);
        stop.unless_requested(design)
    }

    /// [`Self::compute`], asking `stop` as [`Self::compute_until`] says. Once `stop` is requested
    /// it returns early with whatever it has, for [`Self::compute_until`] to throw away.
    fn search<R: Rng + ?Sized>(
        &self,
        problem: &DesignProblem,
        rng: &mut R,
        stop: &Stop,
    ) -> Result<ApproximateDesign, ParameterError> {
        self.validate()?;
        let mut points = grid(problem, self.candidates);
        let mut rows: Vec<Row> = points.iter().map(|a| row(problem, a)).collect();
        // Start: equal weights on 5p random candidates (REX keeps a support of about that
        // size), or on every candidate when those do not identify the model (non-singular
        // whenever any design is).
        let mut weights = vec![0.0; points.len()];
        let start = rand::seq::index::sample(rng, points.len(), (5 * P).min(points.len()));
        for i in start.iter() {
            weights[i] = 1.0 / start.len() as f64;
        }
        if information_inverse(&rows, &weights).is_none() {
            weights.fill(1.0 / points.len() as f64);
            if information_inverse(&rows, &weights).is_none() {
                return Err(ParameterError::Singular { name: "attitude box" });
            }
        }
        let optimum = certificate_search();
        let mut rounds = 0;
        let (certificate, converged) = loop {
            rounds += 1;
            let variances = rex(
                &rows,
                &mut weights,
                self.tolerance * 0.1,
                self.max_iterations,
                rng,
                stop,
            )
            .ok_or(ParameterError::Singular { name: "attitude box" })?;
            refine(problem, &optimum, &mut points, &mut rows, &mut weights);
            let Some(minv) = information_inverse(&rows, &weights) else {
                return Err(ParameterError::Singular { name: "attitude box" });
            };
            let maxima = self.local_maxima(problem, &optimum, &minv, (&points, &weights, &variances), stop);
            let ln_det = ln_det_nt(problem, &rows, &weights);
            let (best_at, best_d) = maxima
                .iter()
                .copied()
                .chain(std::iter::once(grid_best(&points, &variances)))
                .fold((points[0], f64::NEG_INFINITY), |b, c| if c.1 > b.1 { c } else { b });
            let certificate = Certificate {
                d_max: best_d,
                at: best_at,
                ln_det_bound: ln_det + P as f64 * (best_d / P as f64).ln(),
            };
            if certificate.is_met(self.tolerance) {
                break (certificate, true);
            }
            if rounds >= self.max_rounds || stop.requested() {
                break (certificate, false);
            }
            // The maximisers that improve on the tolerance join the candidates.
            for (a, d) in maxima {
                if d > P as f64 * (1.0 + self.tolerance) && !points.iter().any(|q| same(q, &a)) {
                    points.push(a);
                    rows.push(row(problem, &a));
                    weights.push(0.0);
                }
            }
        };
        let mut support: Vec<(Attitude, f64)> = points
            .iter()
            .zip(&weights)
            .filter(|(_, w)| **w > 0.0)
            .map(|(a, w)| (*a, *w))
            .collect();
        support.sort_by(|a, b| b.1.total_cmp(&a.1));
        // Points that meet are one attitude: merged into the heavier (earlier) one.
        let merged = merge(support, MERGE_RAD);
        let (mut support, mut weights) = normalised(&merged);
        let mut rows: Vec<Row> = support.iter().map(|a| row(problem, a)).collect();
        // The certificate of exactly this design (the merge moved weight by at most MERGE_RAD).
        let mut certificate =
            if merged.len() == rows.len() && certificate_is_for(&certificate, problem, &rows, &weights) {
                certificate
            } else {
                self.certify_until(problem, &support, &weights, stop)?
            };
        let mut converged = converged && certificate.is_met(self.tolerance);
        // A design to fly: points within FLY_RAD of each other are one, and weights below
        // FLY_WEIGHT are dropped; the weights are optimised again on what is left and the points
        // refined. Kept only if it still meets the certificate (else the design above stays).
        if converged {
            let mut cleaned = merge(support.iter().copied().zip(weights.iter().copied()).collect(), FLY_RAD);
            cleaned.retain(|(_, w)| *w >= FLY_WEIGHT);
            let (mut fly, mut fly_weights) = normalised(&cleaned);
            let mut fly_rows: Vec<Row> = fly.iter().map(|a| row(problem, a)).collect();
            if fly.len() < support.len() && information_inverse(&fly_rows, &fly_weights).is_some() {
                for _ in 0..2 {
                    rex(
                        &fly_rows,
                        &mut fly_weights,
                        self.tolerance * 0.1,
                        self.max_iterations,
                        rng,
                        stop,
                    );
                    refine(problem, &optimum, &mut fly, &mut fly_rows, &mut fly_weights);
                }
                let kept: Vec<(Attitude, f64)> = merge(
                    fly.iter()
                        .copied()
                        .zip(fly_weights.iter().copied())
                        .filter(|(_, w)| *w > 0.0)
                        .collect(),
                    MERGE_RAD,
                );
                let (fly, fly_weights) = normalised(&kept);
                if let Ok(c) = self.certify_until(problem, &fly, &fly_weights, stop)
                    && c.is_met(self.tolerance)
                {
                    rows = fly.iter().map(|a| row(problem, a)).collect();
                    (support, weights, certificate) = (fly, fly_weights, c);
                }
            }
            converged = certificate.is_met(self.tolerance);
        }
        let ln_det = ln_det_nt(problem, &rows, &weights);
        // Rounding at the edges of the scales (a field of 1 nT against a bias of 1e7 nT) can
        // leave nothing usable: then there is no design to report.
        if !(ln_det.is_finite()
            && certificate.d_max.is_finite()
            && certificate.ln_det_bound.is_finite()
            && weights.iter().all(|w| w.is_finite() && *w > 0.0))
        {
            return Err(ParameterError::Singular { name: "attitude box" });
        }
        Ok(ApproximateDesign {
            ln_det,
            support,
            weights,
            certificate,
            converged,
            rounds,
            candidates: points.len(),
        })
    }

    /// The certificate of any approximate design (`support` with `weights`, which need not sum
    /// to 1; an exact design is one with equal weights): the largest variance found over the box
    /// by the same multi-start search as [`Self::compute`], from the support and from the
    /// candidates of a grid of [`Self::candidates`] attitudes.
    ///
    /// # Errors
    /// Invalid settings; [`ParameterError::Singular`] for a singular design.
    pub fn certify(
        &self,
        problem: &DesignProblem,
        support: &[Attitude],
        weights: &[f64],
    ) -> Result<Certificate, ParameterError> {
        self.certify_until(problem, support, weights, &Stop::NEVER)
    }

    /// [`Self::certify`] whose local searches ask `stop` at every start; once it is requested the
    /// certificate is cut short, for the caller to throw away.
    fn certify_until(
        &self,
        problem: &DesignProblem,
        support: &[Attitude],
        weights: &[f64],
        stop: &Stop,
    ) -> Result<Certificate, ParameterError> {
        self.validate()?;
        let total: f64 = weights.iter().sum();
        let weights: Vec<f64> = weights.iter().map(|w| w / total).collect();
        let support_rows: Vec<Row> = support.iter().map(|a| row(problem, a)).collect();
        let minv = information_inverse(&support_rows, &weights).ok_or(ParameterError::Singular { name: "design" })?;
        let mut points = grid(problem, self.candidates);
        let mut candidate_weights = vec![0.0; points.len()];
        points.extend_from_slice(support);
        candidate_weights.extend_from_slice(&weights);
        let rows: Vec<Row> = points.iter().map(|a| row(problem, a)).collect();
        let d = variances(&rows, &minv);
        let optimum = certificate_search();
        let maxima = self.local_maxima(problem, &optimum, &minv, (&points, &candidate_weights, &d), stop);
        let (at, d_max) = maxima
            .into_iter()
            .chain(std::iter::once(grid_best(&points, &d)))
            .fold((points[0], f64::NEG_INFINITY), |b, c| if c.1 > b.1 { c } else { b });
        let ln_det = ln_det_nt(problem, &support_rows, &weights);
        Ok(Certificate {
            d_max,
            at,
            ln_det_bound: ln_det + P as f64 * (d_max / P as f64).ln(),
        })
    }

    /// D-optimal augmentation: `count` attitudes of the box added one at a time to readings whose
    /// information (R-scaled, \[P1\] eq. (12)) is `information`, each where the variance function
    /// `d(x) = h(x)^T M^-1 h(x)` of the information so far is largest over the continuous box
    /// (the same multi-start search as the certificate), since `det(M + h h^T) = det M (1 + d)`.
    /// Returns each attitude with its `d` when chosen.
    ///
    /// # Errors
    /// Invalid settings; [`ParameterError::Singular`] when `information` is singular.
    pub fn augment(
        &self,
        problem: &DesignProblem,
        information: &Mat9,
        count: usize,
    ) -> Result<Vec<(Attitude, f64)>, ParameterError> {
        self.add(problem, information, count, &Stop::NEVER)
    }

    /// [`Self::augment`], giving up when `stop` is requested: it is asked before every attitude
    /// added and at every start of its local search. Where it is never requested, the same
    /// attitudes as [`Self::augment`]'s.
    ///
    /// # Errors
    /// [`Stopped`] when `stop` is requested before it returns; else as [`Self::augment`], inside.
    pub fn augment_until(
        &self,
        problem: &DesignProblem,
        information: &Mat9,
        count: usize,
        stop: &Stop,
    ) -> Result<Result<Vec<(Attitude, f64)>, ParameterError>, Stopped> {
        let chosen = self.add(problem, information, count, stop);
        stop.unless_requested(chosen)
    }

    /// [`Self::augment`], asking `stop` as [`Self::augment_until`] says; cut short once it is
    /// requested.
    fn add(
        &self,
        problem: &DesignProblem,
        information: &Mat9,
        count: usize,
        stop: &Stop,
    ) -> Result<Vec<(Attitude, f64)>, ParameterError> {
        self.validate()?;
        let points = grid(problem, self.candidates);
        let rows: Vec<Row> = points.iter().map(|a| row(problem, a)).collect();
        let optimum = certificate_search();
        let mut M = *information;
        let mut chosen = Vec::with_capacity(count);
        for _ in 0..count {
            if stop.requested() {
                break;
            }
            let minv = spd_inverse(&M).ok_or(ParameterError::Singular {
                name: "information of the log",
            })?;
            let d = variances(&rows, &minv);
            let maxima = self.local_maxima(problem, &optimum, &minv, (&points, &vec![0.0; points.len()], &d), stop);
            let (at, value) = maxima
                .into_iter()
                .chain(std::iter::once(grid_best(&points, &d)))
                .fold((points[0], f64::NEG_INFINITY), |b, c| if c.1 > b.1 { c } else { b });
            let h = row(problem, &at);
            for i in 0..P {
                for j in 0..P {
                    M[i][j] += h[i] * h[j];
                }
            }
            chosen.push((at, value));
        }
        Ok(chosen)
    }

    /// Local maxima of the variance function from the support points and from the candidates
    /// of largest variance (at least two grid steps apart), in start order; the `points` are
    /// given with their `weights` and `variances`. A start made once `stop` is requested is not
    /// searched: it gives its own attitude with a variance of minus infinity.
    fn local_maxima(
        &self,
        problem: &DesignProblem,
        optimum: &Optimum,
        minv: &Mat9,
        (points, weights, variances): (&[Attitude], &[f64], &[f64]),
        stop: &Stop,
    ) -> Vec<(Attitude, f64)> {
        let mut order: Vec<usize> = (0..points.len()).collect();
        order.sort_by(|&a, &b| variances[b].total_cmp(&variances[a]).then(a.cmp(&b)));
        let separation = 2.0 * grid_step(problem.bounds(), self.candidates);
        let mut starts: Vec<Attitude> = points
            .iter()
            .zip(weights)
            .filter(|(_, w)| **w > 0.0)
            .map(|(a, _)| *a)
            .collect();
        let mut chosen: Vec<Attitude> = Vec::new();
        for i in order {
            if chosen.len() >= self.starts {
                break;
            }
            let a = points[i];
            if chosen.iter().all(|c| distance(c, &a) >= separation) {
                chosen.push(a);
            }
        }
        starts.extend(chosen);
        let (lo, hi) = bounds_of(problem.bounds(), 3);
        starts
            .par_iter()
            .map(|a| {
                if stop.requested() {
                    return (*a, f64::NEG_INFINITY);
                }
                let (x, f, _) = optimum.minimise(&lo, &hi, vec![a.roll, a.yaw, a.pitch], |x, g| {
                    let (d, grad) = variance_and_gradient(
                        problem,
                        minv,
                        &Attitude {
                            roll: x[0],
                            yaw: x[1],
                            pitch: x[2],
                        },
                    );
                    for k in 0..3 {
                        g[k] = -grad[k];
                    }
                    -d
                });
                let at = problem.bounds().confine(&Attitude {
                    roll: x[0],
                    yaw: x[1],
                    pitch: x[2],
                });
                // The value where the point was confined (a periodic angle wraps exactly).
                let d = variance_and_gradient(problem, minv, &at).0;
                debug_assert!((d + f).abs() <= 1e-9 * d.abs().max(1.0));
                (at, d)
            })
            .collect()
    }
}

/// Readings per support point for an exact design of `n` readings from approximate weights, by
/// efficient rounding (Pukelsheim and Rieder 1992, "Efficient rounding of approximate designs",
/// Biometrika 79): `n_i = ceil((n - l/2) w_i)` for the `l` support points, then one reading at a
/// time added where `n_j / w_j` is smallest, or taken where `(n_j - 1) / w_j` is largest, until
/// they sum to `n`. Ties go to the earlier point. A point may get no reading when `n` is below
/// the support size.
///
/// # Panics
/// If a weight is not positive and finite (a caller bug; an [`ApproximateDesign`]'s are).
#[track_caller]
pub fn efficient_rounding(weights: &[f64], n: usize) -> Vec<usize> {
    assert!(
        weights.iter().all(|w| w.is_finite() && *w > 0.0),
        "weights must be positive"
    );
    let l = weights.len();
    let scaled = n as f64 - l as f64 / 2.0;
    let mut counts: Vec<usize> = weights.iter().map(|w| (scaled * w).ceil().max(0.0) as usize).collect();
    let mut total: usize = counts.iter().sum();
    let pick = |counts: &[usize], better: &dyn Fn(f64, f64) -> bool, key: &dyn Fn(usize, f64) -> f64| {
        (0..l).fold(None::<(usize, f64)>, |best, i| {
            let v = key(counts[i], weights[i]);
            match best {
                Some((_, b)) if !better(v, b) => best,
                _ => Some((i, v)),
            }
        })
    };
    while total < n {
        let (j, _) = pick(&counts, &|v, b| v < b, &|c, w| c as f64 / w).expect("some support");
        counts[j] += 1;
        total += 1;
    }
    while total > n {
        let (k, _) = pick(&counts, &|v, b| v > b, &|c, w| {
            if c == 0 {
                f64::NEG_INFINITY
            } else {
                (c as f64 - 1.0) / w
            }
        })
        .expect("some support");
        counts[k] -= 1;
        total -= 1;
    }
    counts
}

/// Whether `certificate` was made for the design of `rows` and `weights` (same `ln det`).
fn certificate_is_for(certificate: &Certificate, problem: &DesignProblem, rows: &[Row], weights: &[f64]) -> bool {
    let ln_det = ln_det_nt(problem, rows, weights);
    let own = ln_det + P as f64 * (certificate.d_max / P as f64).ln();
    own.to_bits() == certificate.ln_det_bound.to_bits()
}

/// The local optimiser of the certificate and of the refinement.
pub(super) fn certificate_search() -> Optimum {
    Optimum {
        max_iterations: 200,
        gradient_tolerance: 1e-10,
        ..Optimum::default()
    }
}

/// Supports larger than this are not refined (each step of the refinement costs the support's
/// size squared).
const MAX_REFINED: usize = 20 * P;

/// Support points closer than this (radians, 0.057 degrees: one attitude to any vehicle) are
/// merged into the heavier one. A point of small weight has a small gradient and stops short of
/// the heavier point it is converging to (0.007 degrees apart on the AUV box, measured).
pub(super) const MERGE_RAD: f64 = 1e-3;

/// Support points closer than this (radians, 0.25 degrees) are one attitude in the design to
/// fly (see [`Approximate::compute`]).
const FLY_RAD: f64 = 4.363e-3;

/// Weights below this are dropped from the design to fly: a point that would get one reading
/// in a thousand.
const FLY_WEIGHT: f64 = 1e-3;

/// Points with their weights by decreasing weight, each merged into an earlier (heavier) one
/// within `radius`.
pub(super) fn merge(mut points: Vec<(Attitude, f64)>, radius: f64) -> Vec<(Attitude, f64)> {
    points.sort_by(|a, b| b.1.total_cmp(&a.1));
    let mut merged: Vec<(Attitude, f64)> = Vec::with_capacity(points.len());
    for (a, w) in points {
        match merged.iter_mut().find(|(b, _)| distance(b, &a) <= radius) {
            Some(m) => m.1 += w,
            None => merged.push((a, w)),
        }
    }
    merged
}

/// Attitudes and weights summing to 1.
fn normalised(points: &[(Attitude, f64)]) -> (Vec<Attitude>, Vec<f64>) {
    let total: f64 = points.iter().map(|p| p.1).sum();
    (
        points.iter().map(|p| p.0).collect(),
        points.iter().map(|p| p.1 / total).collect(),
    )
}

/// Weights below this (of a total of 1) are dropped before the support is refined.
const NEGLIGIBLE_WEIGHT: f64 = 1e-6;

/// Refines the support in place: drops negligible weights, moves the support points to a local
/// maximum of `ln det M(xi)` over the continuous box with the weights held (projected L-BFGS),
/// and merges points that meet (within [`MERGE_RAD`]), adding their weights.
pub(super) fn refine(
    problem: &DesignProblem,
    optimum: &Optimum,
    points: &mut [Attitude],
    rows: &mut [Row],
    weights: &mut [f64],
) {
    for w in weights.iter_mut() {
        if *w < NEGLIGIBLE_WEIGHT {
            *w = 0.0;
        }
    }
    let total: f64 = weights.iter().sum();
    weights.iter_mut().for_each(|w| *w /= total);
    let support: Vec<usize> = (0..points.len()).filter(|&i| weights[i] > 0.0).collect();
    if support.len() > MAX_REFINED {
        return;
    }
    let held: Vec<f64> = support.iter().map(|&i| weights[i]).collect();
    let x0: Vec<f64> = support
        .iter()
        .flat_map(|&i| [points[i].roll, points[i].yaw, points[i].pitch])
        .collect();
    let (lo, hi) = bounds_of(problem.bounds(), x0.len());
    let (x, f, _) = optimum.minimise(&lo, &hi, x0, |x, g| {
        let v = weighted_ln_det_and_gradient(problem, x, &held, g);
        g.iter_mut().for_each(|v| *v = -*v);
        -v
    });
    if !f.is_finite() {
        return;
    }
    for (j, &i) in support.iter().enumerate() {
        points[i] = problem.bounds().confine(&Attitude {
            roll: x[3 * j],
            yaw: x[3 * j + 1],
            pitch: x[3 * j + 2],
        });
        rows[i] = row(problem, &points[i]);
    }
    for (j, &i) in support.iter().enumerate() {
        if let Some(&k) = support[..j]
            .iter()
            .find(|&&k| weights[k] > 0.0 && distance(&points[k], &points[i]) <= 1e-7)
        {
            weights[k] += weights[i];
            weights[i] = 0.0;
        }
    }
}

/// `ln det M(xi)` (R-scaled) of the weighted design `x` (\[P1\] eq. (16) layout) and its gradient
/// with respect to `x`, written to `grad`; `-inf` (gradient zero) when singular.
fn weighted_ln_det_and_gradient(problem: &DesignProblem, x: &[f64], weights: &[f64], grad: &mut [f64]) -> f64 {
    grad.fill(0.0);
    let rows: Vec<Row> = x
        .chunks_exact(3)
        .map(|a| {
            row(
                problem,
                &Attitude {
                    roll: a[0],
                    yaw: a[1],
                    pitch: a[2],
                },
            )
        })
        .collect();
    let M = information(&rows, weights);
    let Some(ln_det) = crate::small::ln_det_spd(&M) else {
        return f64::NEG_INFINITY;
    };
    let Some(minv) = information_inverse(&rows, weights) else {
        return f64::NEG_INFINITY;
    };
    for ((a, g), &w) in x.chunks_exact(3).zip(grad.chunks_exact_mut(3)).zip(weights) {
        // d ln det / d theta = w_i d(h^T M^-1 h)/d theta at fixed M.
        let (_, dd) = variance_and_gradient(
            problem,
            &minv,
            &Attitude {
                roll: a[0],
                yaw: a[1],
                pitch: a[2],
            },
        );
        for k in 0..3 {
            g[k] = w * dd[k];
        }
    }
    ln_det
}

/// The regression row of the R-scaled reading of attitude `a`.
pub(super) fn row(problem: &DesignProblem, a: &Attitude) -> Row {
    regression_row(problem.scaled_reading(a.roll, a.yaw, a.pitch))
}

/// The variance `h(x)^T M^-1 h(x)` at `a` and its gradient with respect to (roll, yaw, pitch).
pub(crate) fn variance_and_gradient(problem: &DesignProblem, minv: &Mat9, a: &Attitude) -> (f64, [f64; 3]) {
    let jet = problem.row_jet(a);
    let w = apply(minv, &jet.h);
    (dot9(&jet.h, &w), jet.gradient(&w))
}

/// `ln det M(xi)` (normalised, `H` in nT) of `weights` on `rows` (R-scaled).
pub(super) fn ln_det_nt(problem: &DesignProblem, rows: &[Row], weights: &[f64]) -> f64 {
    let M = information(rows, weights);
    match crate::small::ln_det_spd(&M) {
        Some(v) => v + problem.ln_det_shift(),
        None => f64::NEG_INFINITY,
    }
}

/// `sum w_i h_i h_i^T` over the points of positive weight (both triangles).
fn information(rows: &[Row], weights: &[f64]) -> Mat9 {
    let mut M = [[0.0; P]; P];
    for (h, &w) in rows.iter().zip(weights) {
        if w > 0.0 {
            for i in 0..P {
                let wh = w * h[i];
                for j in 0..=i {
                    M[i][j] += wh * h[j];
                }
            }
        }
    }
    for i in 0..P {
        for j in i + 1..P {
            M[i][j] = M[j][i];
        }
    }
    M
}

/// `M^-1` of the design, or `None` when it is singular to working precision.
pub(super) fn information_inverse(rows: &[Row], weights: &[f64]) -> Option<Mat9> {
    spd_inverse(&information(rows, weights))
}

/// `minv h`.
#[inline]
pub(super) fn apply(minv: &Mat9, h: &Row) -> Row {
    std::array::from_fn(|i| (0..P).map(|j| minv[i][j] * h[j]).sum())
}

#[inline]
pub(super) fn dot9(a: &Row, b: &Row) -> f64 {
    (0..P).map(|i| a[i] * b[i]).sum()
}

/// REX on fixed candidates from `weights`, until the largest variance is within
/// `p (1 + tolerance)` or `max_iterations`, or `stop` is requested (asked before every iteration
/// and every support point of its exchanges: a support of 400 points against 450 candidates made
/// an iteration 40 ms, and a round 8 s, on an ill-conditioned sensor). Returns the variances of
/// the final weights, or `None` if the information became singular.
pub(super) fn rex<R: Rng + ?Sized>(
    rows: &[Row],
    weights: &mut [f64],
    tolerance: f64,
    max_iterations: usize,
    rng: &mut R,
    stop: &Stop,
) -> Option<Vec<f64>> {
    let n = rows.len();
    let greedy = (4 * P).min(n);
    for _ in 0..max_iterations {
        if stop.requested() {
            break;
        }
        let mut minv = information_inverse(rows, weights)?;
        let d = variances(rows, &minv);
        let (k_max, d_max) = argmax(&d);
        if d_max <= P as f64 * (1.0 + tolerance) {
            return Some(d);
        }
        // The leading exchange: the worst support point to the best candidate.
        let l_min = (0..n)
            .filter(|&i| weights[i] > 0.0)
            .min_by(|&a, &b| d[a].total_cmp(&d[b]))?;
        exchange(rows, weights, &mut minv, k_max, l_min);
        // The support and the greedy candidates, in random order.
        let mut support: Vec<usize> = (0..n).filter(|&i| weights[i] > 0.0).collect();
        let mut order: Vec<usize> = (0..n).collect();
        order.select_nth_unstable_by(greedy - 1, |&a, &b| d[b].total_cmp(&d[a]).then(a.cmp(&b)));
        let mut pool: Vec<usize> = order[..greedy].to_vec();
        pool.extend(support.iter().copied().filter(|i| !order[..greedy].contains(i)));
        pool.sort_unstable();
        support.shuffle(rng);
        pool.shuffle(rng);
        for &l in &support {
            if stop.requested() {
                break;
            }
            for &k in &pool {
                if weights[l] <= 0.0 {
                    break;
                }
                if k != l {
                    exchange(rows, weights, &mut minv, k, l);
                }
            }
        }
        let total: f64 = weights.iter().sum();
        weights.iter_mut().for_each(|w| *w /= total);
    }
    let minv = information_inverse(rows, weights)?;
    Some(variances(rows, &minv))
}

/// The variance of every candidate.
fn variances(rows: &[Row], minv: &Mat9) -> Vec<f64> {
    rows.par_iter()
        .with_min_len(1024)
        .map(|h| dot9(h, &apply(minv, h)))
        .collect()
}

/// The optimal exchange of weight from `l` to `k` (negative: from `k` to `l`), and the update of
/// `minv`. Nothing happens when it would not increase `det M`.
fn exchange(rows: &[Row], weights: &mut [f64], minv: &mut Mat9, k: usize, l: usize) {
    let (hk, hl) = (&rows[k], &rows[l]);
    let (ak, al) = (apply(minv, hk), apply(minv, hl));
    let (dk, dl, dkl) = (dot9(hk, &ak), dot9(hl, &al), dot9(hk, &al));
    let curvature = dk * dl - dkl * dkl;
    let alpha = if curvature > 0.0 {
        (dk - dl) / (2.0 * curvature)
    } else if dk > dl {
        f64::INFINITY
    } else {
        f64::NEG_INFINITY
    };
    let alpha = alpha.clamp(-weights[k], weights[l]);
    let gain = alpha * (dk - dl) - alpha * alpha * curvature;
    if gain.is_nan() || gain <= 1e-14 {
        return;
    }
    weights[k] += alpha;
    weights[l] -= alpha;
    if weights[l] < 1e-15 {
        weights[l] = 0.0;
    }
    if weights[k] < 1e-15 {
        weights[k] = 0.0;
    }
    // M + alpha h_k h_k^T: minv - alpha ak ak^T / (1 + alpha dk); then - alpha h_l h_l^T.
    let c = alpha / (1.0 + alpha * dk);
    for i in 0..P {
        for j in 0..P {
            minv[i][j] -= c * ak[i] * ak[j];
        }
    }
    let bl = apply(minv, hl);
    let c = alpha / (1.0 - alpha * dot9(hl, &bl));
    for i in 0..P {
        for j in 0..P {
            minv[i][j] += c * bl[i] * bl[j];
        }
    }
}

fn argmax(d: &[f64]) -> (usize, f64) {
    d.iter()
        .enumerate()
        .fold((0, f64::NEG_INFINITY), |b, (i, &v)| if v > b.1 { (i, v) } else { b })
}

fn grid_best(points: &[Attitude], d: &[f64]) -> (Attitude, f64) {
    let (i, v) = argmax(d);
    (points[i], v)
}

/// The grid of about `budget` candidates: its common angular step (radians) and the levels of
/// roll, yaw and pitch. Bounded angles get at least 2 levels, periodic ones 4; the step grows
/// until the grid has at most twice `budget` points, so that no box (however thin in one angle
/// and wide in another) makes a grid larger than that.
fn grid_levels(bounds: &crate::attitude::AttitudeBox, budget: usize) -> (f64, [usize; 3]) {
    let ranges = bounds.ranges();
    let volume: f64 = ranges.iter().map(|r| r.width().min(std::f64::consts::TAU)).product();
    let mut step = (volume / budget as f64).cbrt();
    loop {
        let levels = ranges.map(|r| {
            if r.is_full_turn() {
                ((std::f64::consts::TAU / step).round().min(1e9) as usize).max(4)
            } else {
                ((r.width() / step).round().min(1e9) as usize + 1).max(2)
            }
        });
        if levels.iter().map(|&n| n as f64).product::<f64>() <= 2.0 * budget as f64 {
            return (step, levels);
        }
        step *= 1.1;
    }
}

/// The common angular step of the grid (radians).
fn grid_step(bounds: &crate::attitude::AttitudeBox, budget: usize) -> f64 {
    grid_levels(bounds, budget).0
}

/// About `budget` attitudes on a grid of equal steps over the box ([`grid_levels`]): bounded
/// angles from `min` to `max` inclusive, periodic ones at `min + k turn / n`.
fn grid(problem: &DesignProblem, budget: usize) -> Vec<Attitude> {
    let (_, n) = grid_levels(problem.bounds(), budget);
    let levels: Vec<Vec<f64>> = problem
        .bounds()
        .ranges()
        .iter()
        .zip(n)
        .map(|(r, n)| {
            if r.is_full_turn() {
                (0..n)
                    .map(|i| r.min() + std::f64::consts::TAU * i as f64 / n as f64)
                    .collect()
            } else {
                (0..n)
                    .map(|i| r.min() + r.width() * i as f64 / (n - 1) as f64)
                    .collect()
            }
        })
        .collect();
    let mut points = Vec::with_capacity(levels[0].len() * levels[1].len() * levels[2].len());
    for &roll in &levels[0] {
        for &yaw in &levels[1] {
            for &pitch in &levels[2] {
                points.push(Attitude { roll, yaw, pitch });
            }
        }
    }
    points
}

/// The largest difference of the three angles (yaw and roll periodic).
pub(super) fn distance(a: &Attitude, b: &Attitude) -> f64 {
    let wrap = |d: f64| {
        let d = d.rem_euclid(std::f64::consts::TAU);
        d.min(std::f64::consts::TAU - d)
    };
    wrap(a.roll - b.roll)
        .max(wrap(a.yaw - b.yaw))
        .max((a.pitch - b.pitch).abs())
}

/// Two attitudes within 1e-9 rad of each other.
fn same(a: &Attitude, b: &Attitude) -> bool {
    distance(a, b) <= 1e-9
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::tests::paper_problem;
    use crate::paper;
    use crate::rng::stream_rng;

    #[test]
    fn auv_box_reproduces_the_conventions_check_values() {
        // docs/conventions.md "Certified D-efficiency": 9 ln 9 + ln det M* lies between 314.936 and
        // 314.947; the best known 9-point design (314.54855) is 95.67 % to 95.79 % efficient.
        let problem = paper_problem();
        let design = Approximate::default()
            .compute(&problem, &mut stream_rng(12, 0))
            .unwrap();
        let c = design.certificate;
        let reached = 9.0 * 9f64.ln() + design.ln_det;
        let bound = c.ln_det_mf_bound(9);
        assert!(design.converged, "{c:?}");
        assert!(reached >= 314.936 && reached <= bound, "{reached} {bound}");
        assert!(bound <= 314.947, "{bound}");
        let eff = c.efficiency_bound(314.54855, 9);
        assert!((0.9567..=0.9579).contains(&eff), "{eff}");
        assert!((design.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        // Kiefer-Wolfowitz: the variance function equals p at every support point of the optimum.
        let minv = information_inverse(
            &design.support.iter().map(|a| row(&problem, a)).collect::<Vec<_>>(),
            &design.weights,
        )
        .unwrap();
        for a in &design.support {
            let d = variance_and_gradient(&problem, &minv, a).0;
            assert!(
                (d - 9.0).abs() <= 9.0 * Approximate::default().tolerance,
                "{d} at {a:?}"
            );
        }
        // Every exact design lies below the bound: the best known one and random ones.
        assert!(314.54855 < bound);
        let mut rng = stream_rng(13, 0);
        for _ in 0..200 {
            let d = crate::design::sources::random(problem.bounds(), 9, &mut rng);
            assert!(problem.evaluate(&d).ln_det_mf < bound);
        }
    }

    #[test]
    fn the_certificate_fails_for_designs_that_are_not_optimal() {
        // The Uniformity design of [P1] Table II with equal weights, and the best known exact
        // design: each one's own certificate is far from p = 9, so it does not certify itself.
        let problem = paper_problem();
        let settings = Approximate::default();
        for (design, below) in [(paper::uniformity_design(), 0.6), (paper::conventions_optimum(), 0.97)] {
            let c = settings.certify(&problem, &design, &[1.0; 9]).unwrap();
            assert!(!c.is_met(settings.tolerance), "{c:?}");
            // Its own efficiency against the bound it implies: 9 / d_max at best.
            let own = c.efficiency_bound(problem.evaluate(&design).ln_det_mf, 9);
            assert!(own < below && own <= 9.0 / c.d_max * (1.0 + 1e-9), "{own} {c:?}");
        }
        // The optimum certifies itself.
        let optimum = settings.compute(&problem, &mut stream_rng(12, 0)).unwrap();
        let c = settings.certify(&problem, &optimum.support, &optimum.weights).unwrap();
        assert!(c.is_met(settings.tolerance), "{c:?}");
    }

    /// The design and the augmentation given a stop never requested are those without one, from
    /// the same draws; requested at any question, or from the start, they are [`Stopped`].
    #[test]
    fn a_stopped_design_is_no_design() {
        use std::sync::Arc;
        use std::sync::atomic::{AtomicUsize, Ordering};
        let problem = paper_problem();
        let settings = Approximate {
            candidates: 2000,
            ..Approximate::default()
        };
        let plain = settings.compute(&problem, &mut stream_rng(12, 0)).unwrap();
        let after = |k: usize| {
            let asked = Arc::new(AtomicUsize::new(0));
            let counter = Arc::clone(&asked);
            let stop = Stop::when(move || counter.fetch_add(1, Ordering::Relaxed) >= k);
            let design = settings.compute_until(&problem, &mut stream_rng(12, 0), &stop);
            (design, asked.load(Ordering::Relaxed))
        };
        let (never, questions) = after(usize::MAX);
        assert_eq!(never, Ok(Ok(plain.clone())));
        assert!(questions > 100, "{questions}");
        for k in [0, questions / 2, questions - 1] {
            assert_eq!(after(k).0, Err(Stopped), "requested after {k} of {questions}");
        }
        assert_eq!(after(questions).0, Ok(Ok(plain)));
        let information = crate::InformationMatrix::from_readings(
            &problem
                .model()
                .measure_all(&problem.field().body_fields(&paper::uniformity_design())),
            problem.field().magnitude(),
        );
        let chosen = settings.augment(&problem, information.matrix(), 3).unwrap();
        assert_eq!(chosen.len(), 3);
        let never = Stop::when(|| false);
        assert_eq!(
            settings.augment_until(&problem, information.matrix(), 3, &never),
            Ok(Ok(chosen))
        );
        let always = Stop::when(|| true);
        assert_eq!(
            settings.augment_until(&problem, information.matrix(), 3, &always),
            Err(Stopped)
        );
    }

    #[test]
    fn efficient_rounding_matches_pukelsheim_and_rieder() {
        // Sums to n; within one reading of n w_i when n is large against the support.
        let w = [0.5, 0.3, 0.2];
        for n in [1, 2, 3, 5, 10, 11, 100, 301] {
            let c = efficient_rounding(&w, n);
            assert_eq!(c.iter().sum::<usize>(), n, "{n}: {c:?}");
            if n >= 10 {
                for (ci, wi) in c.iter().zip(w) {
                    assert!((*ci as f64 - n as f64 * wi).abs() <= 1.5, "{n}: {c:?}");
                }
            }
        }
        // Equal weights: equal counts; a hand-checked case: (n - l/2) w = (10 - 1.5) w = 4.25,
        // 2.55, 1.7 -> ceil 5, 3, 2 = 10.
        assert_eq!(efficient_rounding(&[0.25; 4], 8), vec![2; 4]);
        assert_eq!(efficient_rounding(&w, 10), vec![5, 3, 2]);
    }

    #[test]
    fn thin_boxes_keep_the_grid_within_its_budget() {
        for (roll, yaw, pitch) in [
            ([0.0, 1e-9], [-180.0, 180.0], [0.0, 1e-9]),
            ([-180.0, 180.0], [-180.0, 180.0], [-90.0, 90.0]),
            ([-1.0, 1.0], [-180.0, 180.0], [-1.0, 1.0]),
            ([0.0, 1e-9], [0.0, 1e-9], [-90.0, 90.0]),
        ] {
            let b = crate::AttitudeBox::from_degrees(roll, yaw, pitch).unwrap();
            let (_, n) = grid_levels(&b, 20_000);
            let total = n[0] * n[1] * n[2];
            assert!((16..=40_000).contains(&total), "{n:?}");
        }
    }

    #[test]
    fn a_box_that_cannot_turn_the_field_is_refused() {
        // Roll and pitch within 1e-9 degrees and yaw within 1e-9 degrees: one attitude.
        let tiny = crate::AttitudeBox::from_degrees([0.0, 1e-9], [0.0, 1e-9], [0.0, 1e-9]).unwrap();
        let problem = DesignProblem::new(paper::changsha_field(), paper::true_error_model(), tiny, 9).unwrap();
        let r = Approximate::default().compute(&problem, &mut stream_rng(1, 0));
        assert_eq!(r.unwrap_err(), ParameterError::Singular { name: "attitude box" });
    }
}
