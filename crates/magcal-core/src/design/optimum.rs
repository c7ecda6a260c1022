//! An optimiser that reaches the D-optimum: multi-start projected L-BFGS on `ln det M_F` with its
//! analytic gradient with respect to the 3m angles.
//!
//! The gradient: `d ln det M_F / d theta = sum_i 2 w_i^T dh_i/d theta` with `w_i = M_F^-1 h_i`,
//! `dh/du` the 9x3 Jacobian of the regression row of \[P1\] eq. (9), `du/d theta = (K/R) dB^b/d theta`
//! ([`crate::ReferenceField::body_field_and_derivatives`]).
//!
//! Bounded angles are kept in the box by projection (the L-BFGS direction is restricted to the
//! variables not held at a bound, and the line search follows the projected path, as in
//! Kim, Sra, Dhillon 2010, "Tackling box-constrained optimization via a new projected quasi-Newton
//! approach"); an angle whose range is a whole turn (yaw, usually) is periodic: free, and wrapped
//! into its range at the end.
//!
//! Written here rather than taken from a crate: argmin's L-BFGS has no bounds and brings rand 0.9;
//! the L-BFGS-B crates bind the Fortran original. The problem is small (3m variables) and smooth.
#![allow(non_snake_case)]
// Index loops mirror the vector algebra they implement.
#![allow(clippy::needless_range_loop)]

use std::collections::VecDeque;

use rand::{Rng, RngExt, SeedableRng};
use rayon::prelude::*;

use super::{DesignCriterion, DesignProblem, from_vector, sources};
use crate::attitude::{Attitude, AttitudeBox};
use crate::error::ParameterError;
use crate::linear_model::UNKNOWNS;
use crate::rng::MagcalRng;
use crate::small::{cholesky_in_place, cholesky_solve};

/// `ln det M_F` (nT) of design `x` and its gradient with respect to `x` (per radian), written to
/// `grad`. Returns `-inf` (and leaves `grad` zero) for a singular design. Allocation-free.
///
/// # Panics
/// If `x` or `grad` is not of length `3m`.
#[track_caller]
pub fn ln_det_and_gradient(problem: &DesignProblem, x: &[f64], grad: &mut [f64]) -> f64 {
    assert_eq!(x.len(), problem.dimension(), "design vector length must be 3m");
    assert_eq!(grad.len(), x.len(), "gradient length must be 3m");
    grad.fill(0.0);
    let mut L = problem.information(x);
    if !cholesky_in_place(&mut L) {
        return f64::NEG_INFINITY;
    }
    let ln_det: f64 = (0..UNKNOWNS).map(|i| 2.0 * L[i][i].ln()).sum::<f64>() + problem.ln_det_shift();
    for (a, g) in x.chunks_exact(3).zip(grad.chunks_exact_mut(3)) {
        let jet = problem.row_jet(&Attitude {
            roll: a[0],
            yaw: a[1],
            pitch: a[2],
        });
        g.copy_from_slice(&jet.gradient(&cholesky_solve(&L, &jet.h)));
    }
    ln_det
}

/// The criteria of [`ln_criterion_and_gradient`]: those of [`DesignCriterion`] other than D, whose
/// logarithm has [`ln_det_and_gradient`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum InverseCriterion {
    /// [`DesignCriterion::A`]: `trace(M_F^-1)`.
    A,
    /// [`DesignCriterion::E`]: `1 / lambda_min(M_F)`.
    E,
}

impl InverseCriterion {
    /// `criterion` as [`ln_criterion_and_gradient`] takes it; `None` for D.
    pub fn of(criterion: DesignCriterion) -> Option<Self> {
        match criterion {
            DesignCriterion::D => None,
            DesignCriterion::A => Some(Self::A),
            DesignCriterion::E => Some(Self::E),
        }
    }
}

impl From<InverseCriterion> for DesignCriterion {
    fn from(c: InverseCriterion) -> Self {
        match c {
            InverseCriterion::A => Self::A,
            InverseCriterion::E => Self::E,
        }
    }
}

/// `ln` of the A- or E-criterion of design `x` and its gradient, written to `grad`: with
/// `phi = trace(M^-1)` (A) or `phi = 1 / lambda_min(M)` (E) of the R-scaled information,
/// `d phi / d theta = -2 sum_i w_i^T dh_i/d theta` with `w_i = M^-2 h_i` (A) or
/// `w_i = (v^T h_i) v / lambda_min^2` (E, `v` the unit eigenvector of `lambda_min`, which is
/// differentiable where `lambda_min` is simple). The logarithm makes the value scale-free, so that
/// one gradient tolerance serves every box. `+inf` (gradient zero) for a singular design.
///
/// # Panics
/// If `x` or `grad` is not of length `3m`.
#[track_caller]
pub fn ln_criterion_and_gradient(
    problem: &DesignProblem,
    criterion: InverseCriterion,
    x: &[f64],
    grad: &mut [f64],
) -> f64 {
    assert_eq!(x.len(), problem.dimension(), "design vector length must be 3m");
    assert_eq!(grad.len(), x.len(), "gradient length must be 3m");
    grad.fill(0.0);
    let M = problem.information(x);
    let mut L = M;
    if !cholesky_in_place(&mut L) {
        return f64::INFINITY;
    }
    // phi and the matrix W with w_i = W h_i.
    let (phi, W): (f64, [[f64; UNKNOWNS]; UNKNOWNS]) = match criterion {
        InverseCriterion::A => {
            let inv = crate::small::cholesky_inverse(&L);
            let phi: f64 = (0..UNKNOWNS).map(|i| inv[i][i]).sum();
            let W = std::array::from_fn(|i| {
                std::array::from_fn(|j| (0..UNKNOWNS).map(|k| inv[i][k] * inv[k][j]).sum::<f64>())
            });
            (phi, W)
        }
        InverseCriterion::E => {
            let fm = faer::MatRef::from_row_major_slice(M.as_flattened(), UNKNOWNS, UNKNOWNS);
            let Ok(evd) = fm.self_adjoint_eigen(faer::Side::Lower) else {
                return f64::INFINITY;
            };
            let lambda = evd.S()[0];
            if lambda.is_nan() || lambda <= 0.0 {
                return f64::INFINITY;
            }
            let v: [f64; UNKNOWNS] = std::array::from_fn(|i| evd.U()[(i, 0)]);
            let W = std::array::from_fn(|i| std::array::from_fn(|j| v[i] * v[j] / (lambda * lambda)));
            (1.0 / lambda, W)
        }
    };
    for (a, g) in x.chunks_exact(3).zip(grad.chunks_exact_mut(3)) {
        let jet = problem.row_jet(&Attitude {
            roll: a[0],
            yaw: a[1],
            pitch: a[2],
        });
        let w: [f64; UNKNOWNS] = std::array::from_fn(|i| (0..UNKNOWNS).map(|j| W[i][j] * jet.h[j]).sum());
        let d = jet.gradient(&w);
        for k in 0..3 {
            // d ln phi = d phi / phi, and d phi = -2 w^T dh.
            g[k] = -d[k] / phi;
        }
    }
    phi.ln()
}

/// Settings of the multi-start optimiser.
#[derive(Debug, Clone, PartialEq)]
pub struct Optimum {
    /// Random starting designs, uniform in the box. Default 16.
    pub starts: usize,
    /// Iteration limit of each local run. Default 500.
    pub max_iterations: usize,
    /// A local run stops when the projected gradient of `ln det M_F` is at most this in every
    /// component (per radian). Default 1e-7.
    pub gradient_tolerance: f64,
    /// L-BFGS memory (pairs kept). Default 10.
    pub memory: usize,
    /// The criterion optimised. Default D.
    pub criterion: DesignCriterion,
}

impl Default for Optimum {
    fn default() -> Self {
        Self {
            starts: 16,
            max_iterations: 500,
            gradient_tolerance: 1e-7,
            memory: 10,
            criterion: DesignCriterion::D,
        }
    }
}

/// What the multi-start optimiser found.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct OptimumResult {
    /// The best design over all starts, angles in the box (periodic ones wrapped into range).
    pub design: Vec<Attitude>,
    /// Its `ln det M_F`, nT.
    pub ln_det: f64,
    /// The final `ln det M_F` of every start, in start order.
    pub start_ln_dets: Vec<f64>,
    /// The best design's value of the criterion optimised, as
    /// [`DesignProblem::fitness`] gives it (to minimise).
    pub fitness: f64,
    /// Objective and gradient evaluations, all starts together.
    pub evaluations: usize,
}

impl Optimum {
    /// Checks the settings.
    ///
    /// # Errors
    /// Zero starts, iterations or memory; a tolerance that is not positive and finite.
    pub fn validate(&self) -> Result<(), ParameterError> {
        for (name, value) in [
            ("starts", self.starts),
            ("max_iterations", self.max_iterations),
            ("memory", self.memory),
        ] {
            if value == 0 {
                return Err(ParameterError::TooSmall { name, min: 1, value });
            }
        }
        let t = self.gradient_tolerance;
        if !(t.is_finite() && t > 0.0) {
            return Err(ParameterError::NotPositive {
                name: "gradient_tolerance",
                value: t,
            });
        }
        Ok(())
    }

    /// Runs `starts` local optimisations from random designs and keeps the best. Each start's
    /// generator is seeded, in start order, from `rng`; starts run in parallel and the best is
    /// chosen in start order (ties keep the earlier), so the result does not depend on the threads.
    ///
    /// # Errors
    /// Invalid settings.
    pub fn optimise<R: Rng + ?Sized>(
        &self,
        problem: &DesignProblem,
        rng: &mut R,
    ) -> Result<OptimumResult, ParameterError> {
        self.validate()?;
        let seeds: Vec<u64> = (0..self.starts).map(|_| rng.random()).collect();
        // Each start: (design, ln det M_F, fitness, evaluations).
        let runs: Vec<(Vec<f64>, f64, f64, usize)> = seeds
            .into_par_iter()
            .map(|seed| {
                let mut rng = MagcalRng::seed_from_u64(seed);
                let start = super::to_vector(&sources::random(problem.bounds(), problem.m(), &mut rng));
                match InverseCriterion::of(self.criterion) {
                    None => {
                        let (x, ln_det, evaluations) = self.local(problem, start);
                        (x, ln_det, -ln_det, evaluations)
                    }
                    Some(criterion) => {
                        let (lo, hi) = bounds_of(problem.bounds(), start.len());
                        let (x, _, evaluations) = self.minimise(&lo, &hi, start, |x, g| {
                            ln_criterion_and_gradient(problem, criterion, x, g)
                        });
                        (
                            x.clone(),
                            problem.ln_det(&x),
                            problem.fitness(criterion.into(), &x),
                            evaluations,
                        )
                    }
                }
            })
            .collect();
        let evaluations = runs.iter().map(|r| r.3).sum();
        let start_ln_dets: Vec<f64> = runs.iter().map(|r| r.1).collect();
        let best = runs
            .iter()
            .enumerate()
            .fold(0, |b, (i, r)| if r.2 < runs[b].2 { i } else { b });
        let design = from_vector(&runs[best].0)
            .into_iter()
            .map(|a| problem.bounds().confine(&a))
            .collect();
        Ok(OptimumResult {
            design,
            ln_det: runs[best].1,
            start_ln_dets,
            fitness: runs[best].2,
            evaluations,
        })
    }

    /// One projected L-BFGS run minimising `-ln det M_F` from `x`. Returns the final design,
    /// its `ln det M_F` and the evaluations made.
    pub fn local(&self, problem: &DesignProblem, x: Vec<f64>) -> (Vec<f64>, f64, usize) {
        let (lo, hi) = bounds_of(problem.bounds(), x.len());
        let (x, f, evaluations) = self.minimise(&lo, &hi, x, |x, g| {
            let v = ln_det_and_gradient(problem, x, g);
            g.iter_mut().for_each(|v| *v = -*v);
            -v
        });
        (x, -f, evaluations)
    }

    /// Projected L-BFGS minimisation of `objective` (which returns `f(x)` and writes its gradient)
    /// from `x` inside `lo..hi` (infinite bounds for periodic angles), with these settings'
    /// iteration limit, gradient tolerance and memory. Returns the final point, `f` there and the
    /// evaluations made. A start where `f` is not finite is returned as it is.
    pub(crate) fn minimise(
        &self,
        lo: &[f64],
        hi: &[f64],
        mut x: Vec<f64>,
        mut objective: impl FnMut(&[f64], &mut [f64]) -> f64,
    ) -> (Vec<f64>, f64, usize) {
        let n = x.len();
        project(&mut x, lo, hi);
        let mut g = vec![0.0; n];
        let mut evaluations = 1;
        let mut f = objective(&x, &mut g);
        if !f.is_finite() {
            return (x, f, evaluations);
        }
        let mut memory: VecDeque<(Vec<f64>, Vec<f64>, f64)> = VecDeque::with_capacity(self.memory);
        let mut x_new = vec![0.0; n];
        let mut g_new = vec![0.0; n];
        for _ in 0..self.max_iterations {
            // Variables held at a bound by a gradient pointing out of the box are not moved.
            let free: Vec<bool> = (0..n)
                .map(|j| !((x[j] <= lo[j] && g[j] > 0.0) || (x[j] >= hi[j] && g[j] < 0.0)))
                .collect();
            let pg: Vec<f64> = (0..n).map(|j| if free[j] { g[j] } else { 0.0 }).collect();
            if pg.iter().all(|v| v.abs() <= self.gradient_tolerance) {
                break;
            }
            let mut d = two_loop(&pg, &memory);
            for j in 0..n {
                d[j] = if free[j] { -d[j] } else { 0.0 };
            }
            let slope: f64 = (0..n).map(|j| d[j] * pg[j]).sum();
            let initial_step = if memory.is_empty() || slope >= 0.0 {
                memory.clear();
                d.copy_from_slice(&pg);
                d.iter_mut().for_each(|v| *v = -*v);
                // A first step of 0.1 rad in the largest component.
                0.1 / pg.iter().fold(0.0_f64, |m, v| m.max(v.abs()))
            } else {
                1.0
            };
            // Backtracking (Armijo) along the projected path.
            let mut t = initial_step;
            let accepted = loop {
                for j in 0..n {
                    x_new[j] = x[j] + t * d[j];
                }
                project(&mut x_new, lo, hi);
                evaluations += 1;
                let f_try = objective(&x_new, &mut g_new);
                let decrease: f64 = (0..n).map(|j| g[j] * (x_new[j] - x[j])).sum();
                if f_try.is_finite() && f_try <= f + 1e-4 * decrease {
                    break Some(f_try);
                }
                t *= 0.5;
                if t < 1e-12 * initial_step {
                    break None;
                }
            };
            let Some(f_try) = accepted else { break };
            let s: Vec<f64> = (0..n).map(|j| x_new[j] - x[j]).collect();
            let y: Vec<f64> = (0..n).map(|j| g_new[j] - g[j]).collect();
            let sy: f64 = (0..n).map(|j| s[j] * y[j]).sum();
            let (ss, yy): (f64, f64) = (s.iter().map(|v| v * v).sum(), y.iter().map(|v| v * v).sum());
            if sy > 1e-10 * (ss * yy).sqrt() {
                if memory.len() == self.memory {
                    memory.pop_front();
                }
                memory.push_back((s, y, 1.0 / sy));
            }
            let progress = f - f_try;
            std::mem::swap(&mut x, &mut x_new);
            std::mem::swap(&mut g, &mut g_new);
            f = f_try;
            if progress <= 1e-15 * f.abs() {
                break;
            }
        }
        (x, f, evaluations)
    }
}

/// Per-variable bounds; `-inf..inf` for a periodic (full-turn) angle.
pub(crate) fn bounds_of(b: &AttitudeBox, n: usize) -> (Vec<f64>, Vec<f64>) {
    let ranges = b.ranges();
    (0..n)
        .map(|j| {
            let r = ranges[j % 3];
            if r.is_full_turn() {
                (f64::NEG_INFINITY, f64::INFINITY)
            } else {
                (r.min(), r.max())
            }
        })
        .unzip()
}

fn project(x: &mut [f64], lo: &[f64], hi: &[f64]) {
    for j in 0..x.len() {
        x[j] = x[j].clamp(lo[j], hi[j]);
    }
}

/// The L-BFGS two-loop recursion: `H g` for the inverse-Hessian approximation of the stored pairs.
fn two_loop(g: &[f64], memory: &VecDeque<(Vec<f64>, Vec<f64>, f64)>) -> Vec<f64> {
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let mut q = g.to_vec();
    let mut alpha = vec![0.0; memory.len()];
    for (k, (s, y, rho)) in memory.iter().enumerate().rev() {
        alpha[k] = rho * dot(s, &q);
        q.iter_mut().zip(y).for_each(|(qi, yi)| *qi -= alpha[k] * yi);
    }
    if let Some((s, y, _)) = memory.back() {
        let gamma = dot(s, y) / dot(y, y);
        q.iter_mut().for_each(|v| *v *= gamma);
    }
    for (k, (s, y, rho)) in memory.iter().enumerate() {
        let beta = rho * dot(y, &q);
        q.iter_mut().zip(s).for_each(|(qi, si)| *qi += (alpha[k] - beta) * si);
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::tests::paper_problem;
    use crate::paper;
    use crate::rng::stream_rng;
    use proptest::prelude::*;

    #[test]
    fn a_and_e_gradients_match_central_differences() {
        let problem = DesignProblem::new(
            paper::changsha_field(),
            paper::true_error_model(),
            AttitudeBox::full(),
            12,
        )
        .unwrap();
        let mut rng = stream_rng(41, 0);
        for criterion in [InverseCriterion::A, InverseCriterion::E] {
            for _ in 0..20 {
                let x = crate::design::to_vector(&sources::random(problem.bounds(), 12, &mut rng));
                let mut g = vec![0.0; 36];
                let f = ln_criterion_and_gradient(&problem, criterion, &x, &mut g);
                // The value is ln of the criterion as fitness() gives it.
                let fitness = problem.fitness(criterion.into(), &x);
                let want = if criterion == InverseCriterion::A {
                    fitness.ln()
                } else {
                    (-1.0 / fitness).ln()
                };
                assert!((f - want).abs() < 1e-10 * want.abs().max(1.0), "{f} {want}");
                let mut scratch = vec![0.0; 36];
                for k in 0..36 {
                    let h = 1e-6;
                    let mut at = |d: f64| {
                        let mut y = x.clone();
                        y[k] += d;
                        ln_criterion_and_gradient(&problem, criterion, &y, &mut scratch)
                    };
                    let numeric = (at(h) - at(-h)) / (2.0 * h);
                    assert!(
                        (numeric - g[k]).abs() <= 1e-5 * (1.0 + g[k].abs()),
                        "{criterion:?} {k}: {numeric} vs {}",
                        g[k]
                    );
                }
            }
        }
    }

    #[test]
    fn a_and_e_optima_beat_the_d_optimum_on_their_own_criterion() {
        let problem = paper_problem();
        let d = Optimum::default().optimise(&problem, &mut stream_rng(3, 0)).unwrap();
        for criterion in [DesignCriterion::A, DesignCriterion::E] {
            let o = Optimum {
                criterion,
                ..Optimum::default()
            }
            .optimise(&problem, &mut stream_rng(3, 0))
            .unwrap();
            let own = problem.fitness(criterion, &crate::design::to_vector(&o.design));
            assert!((own - o.fitness).abs() <= 1e-9 * own.abs());
            assert!(
                own < problem.fitness(criterion, &crate::design::to_vector(&d.design)),
                "{criterion:?}"
            );
            // and the D-optimum is better on D.
            assert!(o.ln_det < d.ln_det);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, .. ProptestConfig::default() })]

        /// The analytic gradient of ln det M_F against central differences, on random designs of the
        /// full attitude space with a random yaw offset.
        #[test]
        fn gradient_matches_central_differences(
            angles in prop::collection::vec(-3.0f64..3.0, 30),
            offset in -180.0f64..180.0,
        ) {
            let field = paper::changsha_field().with_yaw_offset_deg(offset).unwrap();
            let problem = DesignProblem::new(field, paper::true_error_model(), AttitudeBox::full(), 10).unwrap();
            let mut g = vec![0.0; 30];
            let f0 = ln_det_and_gradient(&problem, &angles, &mut g);
            prop_assume!(f0.is_finite());
            // Central differences of ln det are only as good as ln det's rounding, about
            // cond(M_F) eps / h: keep to designs where that is far below the tolerance.
            let m_f = problem.information_matrix(&crate::design::from_vector(&angles));
            let cond = crate::linear_model::cond_2(m_f.to_faer().as_ref());
            prop_assume!(cond < 1e7);
            let mut scratch = vec![0.0; 30];
            for k in 0..30 {
                let mut at = |d: f64| {
                    let mut x = angles.clone();
                    x[k] += d;
                    ln_det_and_gradient(&problem, &x, &mut scratch)
                };
                // Fourth-order central differences at h and h/2: their difference estimates the
                // error of the finer one (random designs near a singular one have large higher
                // derivatives, where no fixed h serves; measured: the differences converge to the
                // analytic value as h shrinks).
                let mut fourth = |h: f64| (8.0 * (at(h) - at(-h)) - (at(2.0 * h) - at(-2.0 * h))) / (12.0 * h);
                let (coarse, fine) = (fourth(1e-4), fourth(5e-5));
                // Truncation: estimated by the two steps. Rounding: ln det carries up to
                // 9 cond(M_F) eps, which the stencil (weights summing to 1.5 in absolute value)
                // divides by h.
                let rounding = 1.5 * 2.0 * 9.0 * cond * f64::EPSILON / 5e-5;
                let tol = 1e-7 * (1.0 + g[k].abs()) + 4.0 * (fine - coarse).abs() + rounding;
                prop_assert!((fine - g[k]).abs() <= tol, "k {}: analytic {} fd {} tol {:e}", k, g[k], fine, tol);
                prop_assume!(tol <= 1e-3 * (1.0 + g[k].abs()));
            }
            prop_assert!((f0 - problem.ln_det(&angles)).abs() <= 1e-12 * f0.abs());
        }
    }

    #[test]
    fn reaches_the_best_known_optimum_for_twenty_seeds() {
        let problem = paper_problem();
        let settings = Optimum::default();
        for seed in 0..20 {
            let r = settings.optimise(&problem, &mut stream_rng(seed, 0)).unwrap();
            assert!(r.ln_det >= 314.5485, "seed {seed}: {}", r.ln_det);
            assert!(r.design.iter().all(|a| problem.bounds().contains(a)));
            let check = problem.ln_det(&crate::design::to_vector(&r.design));
            assert!((check - r.ln_det).abs() <= 1e-9 * check, "{check} {}", r.ln_det);
        }
    }

    #[test]
    fn deterministic_on_one_and_several_threads() {
        let problem = paper_problem();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| Optimum::default().optimise(&problem, &mut stream_rng(3, 1)).unwrap())
        };
        assert_eq!(run(1), run(4));
    }

    #[test]
    fn invalid_settings_are_errors() {
        let problem = paper_problem();
        let mut rng = stream_rng(0, 0);
        for bad in [
            Optimum {
                starts: 0,
                ..Optimum::default()
            },
            Optimum {
                gradient_tolerance: -1.0,
                ..Optimum::default()
            },
            Optimum {
                memory: 0,
                ..Optimum::default()
            },
        ] {
            assert!(bad.optimise(&problem, &mut rng).is_err());
        }
    }
}
