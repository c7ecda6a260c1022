//! scenario -> designs -> noisy trials (parallel, collected in trial order) -> statistics.
//!
//! Every random stream is `stream_rng(seed, id)` with a fixed id per purpose, so the numbers do not
//! depend on the thread count: designs `[DESIGN_STREAM, design]`, trials `[design, level, trial]`
//! (`level` the noise level's index plus `MAX_SIGMAS` times the execution error's), each design's
//! check `[CHECK_STREAM, design, trial]`, repeated PSO runs from a seed drawn on
//! `[PSO_RUNS_STREAM, 0]`.

pub mod advice;
pub mod budget;
pub mod build;
pub mod check;
pub mod trials;

use std::time::Instant;

use anyhow::Result;
use indicatif::ProgressBar;
use magcal_core::design::approximate::ApproximateDesign;
use magcal_core::design::d_efficiency;
use magcal_core::design::pso::RunSummary;
use magcal_core::rng::{stream_id, stream_rng};
use magcal_core::{Attitude, Conditioning, Verdict};

pub use check::{Calibrate, Check};
pub use trials::{Cell, Metric, MetricStats, Outcomes};

use crate::scenario::{DesignKind, Scenario};

/// Stream-id prefix of the design optimisers (design indices stay below it).
const DESIGN_STREAM: u64 = 0xFFFF;
/// Stream-id prefix of the repeated PSO runs.
const PSO_RUNS_STREAM: u64 = 0xFFFE;
/// Stream-id prefix of the approximate design that certifies the others.
const CERTIFICATE_STREAM: u64 = 0xFFFD;
/// Stream-id prefix of the short Monte Carlo behind each design's verdict ([`Check`]).
const CHECK_STREAM: u64 = 0xFFFB;
/// Longest stream-id prefix of a check ([`Check::run_on`]).
pub const CHECK_STREAM_DEPTH: usize = 3;
/// Stream-id prefix of the noise of `magcal simulate`.
const SIMULATED_LOG_STREAM: u64 = 0xFFFC;

/// The random stream of the approximate design and its certificate for `seed`: the same in
/// `run`, `calibrate --scenario` and `next`.
pub fn certificate_rng(seed: u64) -> magcal_core::rng::MagcalRng {
    stream_rng(seed, stream_id(&[CERTIFICATE_STREAM, 0]))
}

/// The random stream of the noise of a simulated log for `seed`.
pub fn simulated_log_rng(seed: u64) -> magcal_core::rng::MagcalRng {
    stream_rng(seed, stream_id(&[SIMULATED_LOG_STREAM, 0]))
}
/// The design that \[P1\] Table III compares against.
pub const REFERENCE_DESIGN: &str = "uniform";

/// A design with its attitudes and metrics.
#[derive(Debug, Clone)]
pub struct BuiltDesign {
    /// Name from the scenario.
    pub name: String,
    /// Source kind.
    pub kind: DesignKind,
    /// The criterion its optimiser minimised, if any.
    pub criterion: Option<magcal_core::design::DesignCriterion>,
    /// Its distinct attitudes, in the order built (the order of the scenario or the optimiser).
    pub attitudes: Vec<Attitude>,
    /// Readings planned at each attitude (1 but for a plan).
    pub readings: Vec<usize>,
    /// A visiting order of the attitudes that keeps the total rotation short (indices into
    /// `attitudes`; [`magcal_core::design::tour::flight_order`]).
    pub order: Vec<usize>,
    /// `ln det M_F`, nT (\[P1\] eq. (12), (14)).
    pub ln_det_mf: f64,
    /// `cond_2(H)` and `cond_2(M_F)`, `H` in nT.
    pub conditioning: Conditioning,
    /// `trace(M_F^-1)`, R-scaled readings.
    pub a_criterion: f64,
    /// `lambda_min(M_F)`, R-scaled readings.
    pub e_criterion: f64,
    /// The identifiability verdict of the Cramer-Rao bound at the scenario's largest noise level.
    pub verdict: Verdict,
    /// The short Monte Carlo at that noise level that says whether the design works.
    pub check: Check,
}

impl BuiltDesign {
    /// Readings in all, `m`.
    pub fn m(&self) -> usize {
        self.readings.iter().sum()
    }

    /// One attitude per reading, in the order built: what the trials simulate.
    pub fn expanded(&self) -> Vec<Attitude> {
        magcal_core::design::replicated(&self.attitudes, &self.readings)
    }

    /// `ln det (M_F / m)`: the information per reading, which designs of different sizes share.
    pub fn ln_det_per_reading(&self) -> f64 {
        magcal_core::design::ln_det_per_reading(self.ln_det_mf, self.m())
    }
}

/// Everything a run produces, before it is written anywhere.
#[derive(Debug, Clone)]
pub struct RunOutput {
    /// Designs in scenario order.
    pub designs: Vec<BuiltDesign>,
    /// Trials per design and noise level, design-major.
    pub cells: Vec<Cell>,
    /// Repeated PSO runs, if asked.
    pub pso_runs: Option<Vec<RunSummary>>,
    /// Attitudes per design of the repeated PSO runs (0 without them).
    pub pso_runs_m: usize,
    /// Wall time per stage, seconds.
    pub stages: Vec<(String, f64)>,
    /// The approximate D-optimal design of the box and its certificate; `None` when no design in
    /// the box identifies the linear model.
    pub approximate: Option<ApproximateDesign>,
}

impl RunOutput {
    /// The certified lower bound of design `i`'s D-efficiency against every design of as many
    /// readings in the box (docs/conventions.md "Certified D-efficiency"); `None` without a
    /// certificate.
    pub fn d_efficiency_bound(&self, i: usize) -> Option<f64> {
        let d = &self.designs[i];
        self.approximate
            .as_ref()
            .map(|a| a.certificate.efficiency_bound(d.ln_det_mf, d.m()))
    }

    /// The D-efficiency reference: the largest information per reading among the identifiable
    /// designs (among all when none is): an optimiser's design that is not identifiable is not
    /// called optimal.
    pub fn best_ln_det_per_reading(&self) -> f64 {
        let best = |identifiable_only: bool| {
            self.designs
                .iter()
                .filter(|d| d.verdict.identifiable || !identifiable_only)
                .map(BuiltDesign::ln_det_per_reading)
                .fold(f64::NEG_INFINITY, f64::max)
        };
        let identifiable = best(true);
        if identifiable > f64::NEG_INFINITY {
            identifiable
        } else {
            best(false)
        }
    }

    /// Whether design `i` is the best of the run: identifiable, with the most information per
    /// reading. Never a design that is not identifiable (with none identifiable, none is best).
    pub fn is_best(&self, i: usize) -> bool {
        let d = &self.designs[i];
        d.verdict.identifiable && d.ln_det_per_reading().to_bits() == self.best_ln_det_per_reading().to_bits()
    }

    /// The design to fly: among those that work ([`Check::works`]: they calibrate and keep the
    /// heading within the budget) and whose log can hold a fifth out
    /// ([`magcal_core::log_fit::min_held_out_readings`], else `calibrate` can never call it
    /// usable), the smallest 95th percentile of the heading error over the box, then the fewest
    /// readings, then scenario order. `None` when none does.
    pub fn recommended(&self) -> Option<usize> {
        let fewest = magcal_core::log_fit::min_held_out_readings(magcal_core::log_fit::FitModel::Full);
        (0..self.designs.len())
            .filter(|&i| self.designs[i].check.works() && self.designs[i].m() >= fewest)
            .min_by(|&a, &b| {
                let key = |i: usize| {
                    let d = &self.designs[i];
                    (d.check.budget_p95_deg.unwrap_or(f64::INFINITY), d.m())
                };
                let (ha, ma) = key(a);
                let (hb, mb) = key(b);
                ha.total_cmp(&hb).then(ma.cmp(&mb)).then(a.cmp(&b))
            })
    }

    /// The Table III reference design, if the scenario has one named `uniform`.
    pub fn reference(&self) -> Option<&BuiltDesign> {
        self.designs.iter().find(|d| d.name == REFERENCE_DESIGN)
    }

    /// D-efficiency of design `i` per reading, `(det(M_F/m) / det(M_F*/m*))^(1/9)`, against the
    /// best design of the run.
    pub fn d_efficiency(&self, i: usize) -> f64 {
        d_efficiency(self.designs[i].ln_det_per_reading(), self.best_ln_det_per_reading())
    }
}

/// Where the pipeline reports its progress; the caller decides how it is shown (bars on a
/// terminal, nothing in a pipe or a test).
pub trait Progress: Sync {
    /// A handle for the stage `message`, which counts to `len` steps or, with `None`, has no count.
    fn stage(&self, message: &str, len: Option<u64>) -> ProgressBar;
}

/// Progress shown nowhere.
#[derive(Debug, Clone, Copy, Default)]
pub struct Quiet;

impl Progress for Quiet {
    fn stage(&self, _: &str, _: Option<u64>) -> ProgressBar {
        ProgressBar::hidden()
    }
}

/// Options of a run that are not in the scenario.
#[derive(Clone, Copy)]
pub struct RunOptions<'a> {
    /// Where progress goes.
    pub progress: &'a dyn Progress,
    /// Skip the noisy trials (`magcal design`).
    pub designs_only: bool,
}

/// Builds the designs of the scenario and, unless `designs_only`, runs its trials; the wall time
/// of each stage goes into [`RunOutput::stages`].
///
/// # Errors
/// A design that cannot be built (for example a singular one).
pub fn run(scenario: &Scenario, options: RunOptions) -> Result<RunOutput> {
    let mut stages = Vec::new();
    let mut timed = |name: String, t: Instant| stages.push((name, t.elapsed().as_secs_f64()));
    let t = Instant::now();
    let approximate = build::approximate(scenario, options.progress)?;
    timed("certificate".to_string(), t);
    let mut designs = Vec::with_capacity(scenario.designs.len());
    for (i, spec) in scenario.designs.iter().enumerate() {
        let t = Instant::now();
        designs.push(build::design(scenario, i, approximate.as_ref(), options.progress)?);
        timed(format!("design:{}", spec.name), t);
    }
    let t = Instant::now();
    let pso_runs = build::pso_runs(scenario, options.progress)?;
    if pso_runs.is_some() {
        timed("pso_runs".to_string(), t);
    }
    let mut cells = Vec::new();
    if !options.designs_only {
        let t = Instant::now();
        cells = trials::run_cells(scenario, &designs, options.progress)?;
        timed("trials".to_string(), t);
    }
    Ok(RunOutput {
        designs,
        cells,
        pso_runs,
        pso_runs_m: scenario.pso_runs.as_ref().map_or(0, |r| r.m),
        stages,
        approximate,
    })
}
