//! The paper's particle swarm optimiser, \[P1\] section III.B, eq. (15)-(20) and Table I, exactly as
//! docs/conventions.md states it.
//!
//! Written here, not taken from a crate: argmin's PSO has neither the linear inertia schedule of
//! eq. (19) nor the per-dimension velocity clamp, and it is built on rand 0.9 (the project keeps one
//! rand major version).
//!
//! # Determinism
//! Each particle owns a ChaCha8 generator seeded, in particle order, from the RNG passed in, and draws
//! its `r1`, `r2` from it. Particles are then updated and evaluated in parallel (rayon), and the
//! swarm's best is reduced sequentially in particle order (ties keep the lower index). The result is
//! therefore identical on one thread or many.
//!
//! # Deviation from \[P1\]
//! The paper draws `r1` and `r2` without saying from which generator; per-particle streams are what
//! make the parallel evaluation reproducible. `r1` and `r2` are uniform on [0, 1) with 32-bit
//! resolution (the two halves of one 64-bit draw), which halves the cost of the generator.

use rand::{Rng, RngExt, SeedableRng};
use rayon::prelude::*;

use super::lanes::{LANES, Lanes};
use super::{DesignCriterion, DesignProblem, from_vector};
use crate::attitude::Attitude;
use crate::error::ParameterError;
use crate::rng::{MagcalRng, stream_rng};

/// Settings of the swarm. [`Default`] is \[P1\] Table I.
#[derive(Debug, Clone, PartialEq)]
pub struct Swarm {
    /// Particles `M`. Table I: 300.
    pub particles: usize,
    /// Iterations `iter_max`. Table I: 3000.
    pub iterations: usize,
    /// Inertia weight at the first iteration, eq. (19). Table I: 0.9.
    pub w_max: f64,
    /// Inertia weight at the last iteration, eq. (19). Table I: 0.4.
    pub w_min: f64,
    /// Cognitive ("study") factor `c1`, eq. (17). Table I: 1.8.
    pub c1: f64,
    /// Social factor `c2`, eq. (17). Table I: 1.8.
    pub c2: f64,
    /// `V_max` of each dimension as a fraction of its range. \[P1\] IV.A: 0.15.
    pub vmax_fraction: f64,
    /// Stop as soon as the swarm's best fitness is below this (\[P1\] III.B step 5). Default: none.
    pub threshold: Option<f64>,
    /// The criterion minimised. Default: D, \[P1\] eq. (15).
    pub criterion: DesignCriterion,
}

impl Default for Swarm {
    fn default() -> Self {
        Self {
            particles: 300,
            iterations: 3000,
            w_max: 0.9,
            w_min: 0.4,
            c1: 1.8,
            c2: 1.8,
            vmax_fraction: 0.15,
            threshold: None,
            criterion: DesignCriterion::D,
        }
    }
}

/// What one swarm run found.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct PsoResult {
    /// The swarm's best design (Gbest), \[P1\] eq. (20).
    pub design: Vec<Attitude>,
    /// Its fitness (for D: `-ln det M_F`, nT).
    pub fitness: f64,
    /// The best fitness after initialisation (index 0) and after every iteration.
    pub history: Vec<f64>,
    /// Fitness evaluations made.
    pub evaluations: usize,
    /// Iterations run (fewer than the setting when the threshold stopped the run).
    pub iterations: usize,
}

/// The final result of one of several independent runs: the data of \[P1\] Fig. 4.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct RunSummary {
    /// Run index.
    pub run: usize,
    /// Final best fitness.
    pub fitness: f64,
    /// Fitness evaluations made.
    pub evaluations: usize,
}

struct Particle {
    x: Vec<f64>,
    v: Vec<f64>,
    best_x: Vec<f64>,
    best_fitness: f64,
    rng: MagcalRng,
}

impl Swarm {
    /// Checks the settings.
    ///
    /// # Errors
    /// Zero particles or iterations; non-finite or negative weights and factors; `w_min > w_max`;
    /// `vmax_fraction` not in (0, 1]; a NaN threshold.
    pub fn validate(&self) -> Result<(), ParameterError> {
        if self.particles == 0 {
            return Err(ParameterError::TooSmall {
                name: "particles",
                min: 1,
                value: 0,
            });
        }
        if self.iterations == 0 {
            return Err(ParameterError::TooSmall {
                name: "iterations",
                min: 1,
                value: 0,
            });
        }
        for (name, value) in [
            ("w_max", self.w_max),
            ("w_min", self.w_min),
            ("c1", self.c1),
            ("c2", self.c2),
        ] {
            crate::error::finite(name, value)?;
            if value < 0.0 {
                return Err(ParameterError::Negative { name, value });
            }
        }
        if self.w_min > self.w_max {
            return Err(ParameterError::EmptyRange {
                name: "w_min",
                min: self.w_min,
                max: self.w_max,
            });
        }
        if !(self.vmax_fraction > 0.0 && self.vmax_fraction <= 1.0) {
            return Err(ParameterError::OutOfRange {
                name: "vmax_fraction",
                allowed: "(0, 1]",
                value: self.vmax_fraction,
            });
        }
        if let Some(t) = self.threshold
            && t.is_nan()
        {
            return Err(ParameterError::NonFinite {
                name: "threshold",
                value: t,
            });
        }
        Ok(())
    }

    /// Runs the swarm on `problem`, drawing the particles' generators from `rng`.
    ///
    /// Procedure of \[P1\] III.B: initialise positions uniformly in the box and velocities uniformly in
    /// `[-V_max, V_max]`; then per iteration update velocities (eq. (17), inertia of eq. (19)),
    /// clamp them to `V_max`, move (eq. (18)), clamp positions to the box, evaluate, and update Pbest
    /// and Gbest.
    ///
    /// # Errors
    /// Invalid settings ([`Self::validate`]).
    pub fn optimise<R: Rng + ?Sized>(&self, problem: &DesignProblem, rng: &mut R) -> Result<PsoResult, ParameterError> {
        self.optimise_observed(problem, rng, &|_, _| {})
    }

    /// [`Self::optimise`], calling `observe(iteration, best_fitness)` after every iteration (for a
    /// progress display; it must be cheap).
    ///
    /// # Errors
    /// Invalid settings ([`Self::validate`]).
    pub fn optimise_observed<R: Rng + ?Sized>(
        &self,
        problem: &DesignProblem,
        rng: &mut R,
        observe: &(dyn Fn(usize, f64) + Sync),
    ) -> Result<PsoResult, ParameterError> {
        self.validate()?;
        let seeds: Vec<u64> = (0..self.particles).map(|_| rng.random()).collect();
        // Run the iterations on a worker of the current rayon pool: a parallel loop started from a
        // thread outside the pool must wake a worker and then be woken itself, every iteration
        // (3000 times); from inside the pool the loop forks and joins on its own thread.
        Ok(rayon::scope(|_| self.run(problem, seeds, observe, true)))
    }

    /// The iterations of [`Self::optimise`], particle `i` seeded by `seeds[i]`; the particles of
    /// an iteration in parallel, or in order on the calling thread (the same result).
    fn run(
        &self,
        problem: &DesignProblem,
        seeds: Vec<u64>,
        observe: &(dyn Fn(usize, f64) + Sync),
        parallel: bool,
    ) -> PsoResult {
        let dim = problem.dimension();
        let ranges = problem.bounds().ranges();
        let lo: Vec<f64> = (0..dim).map(|j| ranges[j % 3].min()).collect();
        let hi: Vec<f64> = (0..dim).map(|j| ranges[j % 3].max()).collect();
        let vmax: Vec<f64> = (0..dim).map(|j| self.vmax_fraction * ranges[j % 3].width()).collect();
        let criterion = self.criterion;

        let mut swarm: Vec<Particle> = seeds
            .into_iter()
            .map(|seed| {
                let mut rng = MagcalRng::seed_from_u64(seed);
                let x: Vec<f64> = (0..dim).map(|j| rng.random_range(lo[j]..=hi[j])).collect();
                let v: Vec<f64> = (0..dim).map(|j| rng.random_range(-vmax[j]..=vmax[j])).collect();
                Particle {
                    best_x: x.clone(),
                    x,
                    v,
                    best_fitness: f64::INFINITY,
                    rng,
                }
            })
            .collect();
        swarm
            .par_chunks_mut(LANES)
            .for_each(|chunk| evaluate(problem, criterion, chunk));
        let mut evaluations = self.particles;

        let (mut g_index, mut g_fitness) = best_of(&swarm);
        let mut g_x = swarm[g_index].best_x.clone();
        let mut history = Vec::with_capacity(self.iterations + 1);
        history.push(g_fitness);
        let mut iterations = 0;

        for k in 0..self.iterations {
            if self.threshold.is_some_and(|t| g_fitness < t) {
                break;
            }
            // [P1] eq. (19): inertia decreasing linearly from w_max to w_min.
            let w = self.w_max - (self.w_max - self.w_min) / self.iterations as f64 * k as f64;
            let g = &g_x;
            let (c1, c2) = (self.c1, self.c2);
            // One chunk per task (rayon's default split): more chunks per task are slower on two
            // threads (`benches/design.rs`).
            let step = |chunk: &mut [Particle]| {
                move_chunk(chunk, w, (c1, c2), g, (&lo, &hi, &vmax));
                evaluate(problem, criterion, chunk);
            };
            if parallel {
                swarm.par_chunks_mut(LANES).for_each(step);
            } else {
                swarm.chunks_mut(LANES).for_each(step);
            }
            evaluations += self.particles;
            iterations += 1;
            let (i, f) = best_of(&swarm);
            if f < g_fitness {
                g_index = i;
                g_fitness = f;
                g_x.copy_from_slice(&swarm[g_index].best_x);
            }
            history.push(g_fitness);
            observe(iterations, g_fitness);
        }

        PsoResult {
            design: from_vector(&g_x),
            fitness: g_fitness,
            history,
            evaluations,
            iterations,
        }
    }

    /// `runs` independent runs, run `r` seeded by stream `r` of `seed`, in parallel across runs; the
    /// final fitness of each, in run order: the data of \[P1\] Fig. 4.
    ///
    /// # Errors
    /// Invalid settings.
    pub fn repeated_runs(
        &self,
        problem: &DesignProblem,
        runs: usize,
        seed: u64,
    ) -> Result<Vec<RunSummary>, ParameterError> {
        self.repeated_runs_observed(problem, runs, seed, &|_| {})
    }

    /// [`Self::repeated_runs`], calling `finished(run)` as each run ends (in any order).
    ///
    /// # Errors
    /// Invalid settings.
    pub fn repeated_runs_observed(
        &self,
        problem: &DesignProblem,
        runs: usize,
        seed: u64,
        finished: &(dyn Fn(usize) + Sync),
    ) -> Result<Vec<RunSummary>, ParameterError> {
        self.validate()?;
        // One run per thread, its particles in order: the threads never wait for each other, where
        // a run's parallel iterations would meet 3000 times.
        (0..runs)
            .into_par_iter()
            .map(|run| {
                let mut rng = stream_rng(seed, run as u64);
                let seeds: Vec<u64> = (0..self.particles).map(|_| rng.random()).collect();
                let result = self.run(problem, seeds, &|_, _| {}, false);
                finished(run);
                Ok(RunSummary {
                    run,
                    fitness: result.fitness,
                    evaluations: result.evaluations,
                })
            })
            .collect()
    }
}

/// Evaluates the particles of a chunk (at most [`LANES`]) at their positions and updates their Pbest
/// (\[P1\] III.B step 3). D is evaluated [`LANES`] particles at a time
/// ([`DesignProblem::ln_det_lanes`]); a short chunk repeats its first particle in the spare lanes.
fn evaluate(problem: &DesignProblem, criterion: DesignCriterion, chunk: &mut [Particle]) {
    let fitness: Lanes = match criterion {
        DesignCriterion::D => {
            let xs = std::array::from_fn(|l| chunk[if l < chunk.len() { l } else { 0 }].x.as_slice());
            problem.ln_det_lanes(xs).map(|v| -v)
        }
        _ => std::array::from_fn(|l| chunk.get(l).map_or(f64::INFINITY, |p| problem.fitness(criterion, &p.x))),
    };
    for (p, f) in chunk.iter_mut().zip(fitness) {
        if f < p.best_fitness {
            p.best_fitness = f;
            p.best_x.copy_from_slice(&p.x);
        }
    }
}

/// Scale of a 32-bit half of a draw onto [0, 1).
const TWO_TO_MINUS_32: f64 = 1.0 / 4_294_967_296.0;

/// Dimensions whose uniforms are drawn at once before the arithmetic of [`move_particle`].
const BLOCK: usize = 32;

/// \[P1\] eq. (17)-(18) for one particle: the velocity from inertia `w`, the cognitive and social
/// factors `(c1, c2)` and the swarm's best `g`, clamped to `V_max`; then the move, clamped to the
/// box.
///
/// `r1`, `r2` of eq. (17) are two independent uniforms on [0, 1) with 32-bit resolution, the two
/// halves of one 64-bit draw (half the generator's work of two `f64` draws; a resolution of 2^-32 is
/// far below anything eq. (17) can resolve). The draws of a block of dimensions are taken at once
/// (`fill_bytes` yields the words `next_u64` would, in the same order: the stream of the particle is
/// one draw per dimension), so that the arithmetic over the block has no call in it and runs in
/// vector registers. The clamps are written as comparisons: `f64::clamp` checks its bounds on every
/// call, a branch that kept the loop scalar; for bounds in order they give the same values.
#[inline(always)]
fn move_particle(
    p: &mut Particle,
    w: f64,
    (c1, c2): (f64, f64),
    g: &[f64],
    (lo, hi, vmax): (&[f64], &[f64], &[f64]),
    bytes: &mut [u8; 8 * BLOCK],
) {
    let Particle { x, v, best_x, rng, .. } = p;
    let mut from = 0;
    while from < x.len() {
        let to = (from + BLOCK).min(x.len());
        let n = to - from;
        rng.fill_bytes(&mut bytes[..8 * n]);
        let draws = bytes[..8 * n].chunks_exact(8);
        let state = x[from..to]
            .iter_mut()
            .zip(&mut v[from..to])
            .zip(&best_x[from..to])
            .zip(&g[from..to]);
        let bounds = lo[from..to].iter().zip(&hi[from..to]).zip(&vmax[from..to]);
        for (((((x, v), &pbest), &gbest), ((&lo, &hi), &vmax)), draw) in state.zip(bounds).zip(draws) {
            let bits = u64::from_le_bytes(draw.try_into().expect("8 bytes"));
            let r1 = word_to_f64(bits >> 32) * TWO_TO_MINUS_32;
            let r2 = word_to_f64(bits) * TWO_TO_MINUS_32;
            // [P1] eq. (17): inertia + cognitive (Pbest) + social (Gbest) terms.
            let v_new = w * *v + c1 * r1 * (pbest - *x) + c2 * r2 * (gbest - *x);
            *v = clamp(v_new, -vmax, vmax);
            // [P1] eq. (18), then back into the search space.
            *x = clamp(*x + *v, lo, hi);
        }
        from = to;
    }
}

/// [`move_particle`] for each particle of a chunk, compiled for AVX2 and for baseline x86-64, the
/// one the CPU can run chosen at run time (as the fitness kernel, `design/lanes.rs`). Both give
/// the same bits: the arithmetic is `+ - *` and comparisons, each correctly rounded at any width,
/// and no multiply is fused with an add.
#[multiversion::multiversion(targets("x86_64+avx2+avx"))]
fn move_chunk(chunk: &mut [Particle], w: f64, c: (f64, f64), g: &[f64], bounds: (&[f64], &[f64], &[f64])) {
    let mut bytes = [0u8; 8 * BLOCK];
    for p in chunk.iter_mut() {
        move_particle(p, w, c, g, bounds, &mut bytes);
    }
}

/// A 32-bit word as `f64` (exact), by its bits: `2^52 + u` has `u` in its low mantissa bits. The same
/// value as `u as f64`, in integer and float operations that vectorise (the cast is a scalar
/// conversion on x86-64 without AVX-512).
#[inline(always)]
fn word_to_f64(u: u64) -> f64 {
    const TWO_TO_52: f64 = 4_503_599_627_370_496.0;
    f64::from_bits(TWO_TO_52.to_bits() | (u & 0xffff_ffff)) - TWO_TO_52
}

/// `f64::clamp` for `lo <= hi`, without its check of the bounds.
#[inline(always)]
fn clamp(value: f64, lo: f64, hi: f64) -> f64 {
    let value = if value < lo { lo } else { value };
    if value > hi { hi } else { value }
}

/// Index and fitness of the particle with the lowest Pbest fitness; ties keep the lower index.
fn best_of(swarm: &[Particle]) -> (usize, f64) {
    swarm.iter().enumerate().fold((0, f64::INFINITY), |(bi, bf), (i, p)| {
        if p.best_fitness < bf {
            (i, p.best_fitness)
        } else {
            (bi, bf)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::tests::paper_problem;
    use crate::design::to_vector;
    use crate::paper;

    fn small_swarm() -> Swarm {
        Swarm {
            particles: 60,
            iterations: 300,
            ..Swarm::default()
        }
    }

    #[test]
    fn same_seed_same_design_on_one_and_several_threads() {
        let problem = paper_problem();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| small_swarm().optimise(&problem, &mut stream_rng(5, 0)).unwrap())
        };
        let one = run(1);
        let three = run(3);
        assert_eq!(to_vector(&one.design), to_vector(&three.design));
        assert_eq!(one.history, three.history);
        let other = small_swarm().optimise(&problem, &mut stream_rng(6, 0)).unwrap();
        assert_ne!(to_vector(&one.design), to_vector(&other.design));
    }

    #[test]
    fn pso_improves_on_the_uniformity_design_by_a_wide_margin() {
        let problem = paper_problem();
        let result = small_swarm().optimise(&problem, &mut stream_rng(1, 0)).unwrap();
        let ln_det = -result.fitness;
        // Uniformity design: 303.48 (docs/conventions.md). A factor e^9 in det M_F is a D-efficiency of e.
        assert!(ln_det > 303.48 + 9.0, "ln det {ln_det}");
        assert!((problem.ln_det(&to_vector(&result.design)) - ln_det).abs() <= 1e-9 * ln_det);
        assert!(result.design.iter().all(|a| problem.bounds().contains(a)));
        assert_eq!(result.history.len(), 301);
        assert!(result.history.windows(2).all(|w| w[1] <= w[0]));
        assert_eq!(result.evaluations, 60 * 301);
        // The observer sees every iteration, in order, with the history's values.
        let seen = std::sync::Mutex::new(Vec::new());
        let again = small_swarm()
            .optimise_observed(&problem, &mut stream_rng(1, 0), &|k, f| {
                seen.lock().unwrap().push((k, f))
            })
            .unwrap();
        let seen = seen.into_inner().unwrap();
        assert_eq!(seen.len(), 300);
        assert!(
            seen.iter()
                .enumerate()
                .all(|(i, &(k, f))| k == i + 1 && f.to_bits() == again.history[k].to_bits())
        );
    }

    #[test]
    fn block_draws_are_the_streams_words_and_exact() {
        // `move_particle` takes its draws by `fill_bytes`: the same 64-bit words, in order, as one
        // `next_u64` per dimension, across the generator's block boundaries.
        let mut by_word = stream_rng(7, 3);
        let mut by_block = stream_rng(7, 3);
        let mut bytes = [0u8; 8 * BLOCK];
        for n in [27, 1, BLOCK, 5, 31, 27, 27, 2] {
            by_block.fill_bytes(&mut bytes[..8 * n]);
            for draw in bytes[..8 * n].chunks_exact(8) {
                assert_eq!(u64::from_le_bytes(draw.try_into().unwrap()), by_word.next_u64());
            }
        }
        // The bit trick is the cast, for every 32-bit half.
        for u in [0u64, 1, 2, 0x7fff_ffff, 0x8000_0000, 0xffff_fffe, 0xffff_ffff, u64::MAX]
            .into_iter()
            .chain((0..10_000).map(|_| by_word.next_u64()))
        {
            assert_eq!(word_to_f64(u).to_bits(), ((u & 0xffff_ffff) as f64).to_bits(), "{u:#x}");
        }
    }

    #[test]
    fn threshold_stops_early() {
        let problem = paper_problem();
        let swarm = Swarm {
            threshold: Some(-300.0),
            ..small_swarm()
        };
        let r = swarm.optimise(&problem, &mut stream_rng(2, 0)).unwrap();
        assert!(
            r.iterations < 300 && r.fitness < -300.0,
            "{} {}",
            r.iterations,
            r.fitness
        );
        assert_eq!(r.evaluations, 60 * (r.iterations + 1));
    }

    #[test]
    fn invalid_settings_are_errors() {
        let problem = paper_problem();
        for bad in [
            Swarm {
                particles: 0,
                ..Swarm::default()
            },
            Swarm {
                iterations: 0,
                ..Swarm::default()
            },
            Swarm {
                c1: f64::NAN,
                ..Swarm::default()
            },
            Swarm {
                w_min: 1.0,
                w_max: 0.5,
                ..Swarm::default()
            },
            Swarm {
                vmax_fraction: 0.0,
                ..Swarm::default()
            },
        ] {
            assert!(bad.optimise(&problem, &mut stream_rng(0, 0)).is_err(), "{bad:?}");
        }
        let _ = paper::BEST_KNOWN_LN_DET;
    }

    #[test]
    fn repeated_runs_are_independent_and_ordered() {
        let problem = paper_problem();
        let swarm = Swarm {
            particles: 20,
            iterations: 50,
            ..Swarm::default()
        };
        let runs = swarm.repeated_runs(&problem, 4, 9).unwrap();
        assert_eq!(runs.iter().map(|r| r.run).collect::<Vec<_>>(), [0, 1, 2, 3]);
        let again = swarm.optimise(&problem, &mut stream_rng(9, 2)).unwrap();
        assert_eq!(runs[2].fitness.to_bits(), again.fitness.to_bits());
        assert_ne!(runs[0].fitness.to_bits(), runs[1].fitness.to_bits());
    }
}
