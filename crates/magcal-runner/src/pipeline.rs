//! scenario -> designs -> noisy trials (parallel, collected in trial order) -> statistics.
//!
//! Every random stream is `stream_rng(seed, id)` with a fixed id per purpose, so the numbers do not
//! depend on the thread count: designs `[DESIGN_STREAM, design]`, trials `[design, level, trial]`
//! (`level` the noise level's index plus `MAX_SIGMAS` times the execution error's), each design's
//! check `[CHECK_STREAM, design, trial]`, repeated PSO runs from a seed drawn on
//! `[PSO_RUNS_STREAM, 0]`.

use std::time::Instant;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use magcal_core::design::approximate::ApproximateDesign;
use magcal_core::design::plan::PlanSearch;
use magcal_core::design::pso::RunSummary;
use magcal_core::design::tour;
use magcal_core::design::{DesignProblem, d_efficiency, sources};
use magcal_core::heading::HeadingProbe;
use magcal_core::monte_carlo::{self, TrialOutcome};
use magcal_core::rng::{stream_id, stream_rng};
use magcal_core::{
    Attitude, CalibrationStatus, Conditioning, CramerRao, ParameterError, PhysicalScales, Summary, Verdict,
};

use crate::output::Metric;
use rand::RngExt;
use rayon::prelude::*;

use crate::limits;
use crate::scenario::{DesignKind, DesignSource, Scenario};

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

/// A calibration of readings (nT) to a field magnitude (nT), in place of the scenario's estimator.
pub type Calibrate = dyn Fn(&[magcal_core::Vec3], f64) -> magcal_core::CalibrationOutcome + Sync;

/// A design calibrated by the scenario's estimator in [`Check::trials`] noisy trials at the
/// scenario's largest noise level, on their own random streams: what "works" rests on. The
/// Cramer-Rao bound is a linear prediction; where a box barely turns an axis against the field the
/// estimates of some trials leave the region where it holds, and only trials show how many.
#[derive(Debug, Clone)]
pub struct Check {
    /// Noise per component, nT.
    pub sigma_nt: f64,
    /// Trials run.
    pub trials: usize,
    /// How they ended.
    pub outcomes: Outcomes,
    /// Median over the `ok` trials of the rms heading error over level headings, degrees.
    pub heading_median_deg: Option<f64>,
    /// Its 95th percentile, degrees.
    pub heading_p95_deg: Option<f64>,
}

impl Check {
    /// The share of trials a design must calibrate (`ok`) to work.
    pub const OK_SHARE: f64 = 0.95;

    /// Whether the design calibrates in at least [`Self::OK_SHARE`] of the trials.
    pub fn works(&self) -> bool {
        self.trials > 0 && self.outcomes.ok as f64 >= Self::OK_SHARE * self.trials as f64
    }

    /// Runs the check: [`Scenario::check_trials`] trials of `body` (the design's body fields) at
    /// `sigma_nt` with the scenario's estimator, on the streams `[CHECK_STREAM, design, t]`.
    ///
    /// # Errors
    /// Only an invalid noise level (scenarios are validated).
    pub fn run(scenario: &Scenario, design: usize, body: &[magcal_core::Vec3], sigma_nt: f64) -> Result<Self> {
        Self::run_on(scenario, &[CHECK_STREAM, design as u64], body, sigma_nt, None)
    }

    /// As [`Self::run`] on the streams `[stream.., t]` (`stream` at most [`CHECK_STREAM_DEPTH`]
    /// long), calibrating each trial's readings with
    /// `calibrate` (readings, field magnitude) instead of the scenario's estimator when given.
    ///
    /// # Errors
    /// As [`Self::run`].
    pub fn run_on(
        scenario: &Scenario,
        stream: &[u64],
        body: &[magcal_core::Vec3],
        sigma_nt: f64,
        calibrate: Option<&Calibrate>,
    ) -> Result<Self> {
        let calibration = magcal_core::TwoStep {
            noise_nt: Some(sigma_nt),
            ..scenario.calibration.clone()
        };
        let probe = HeadingProbe::new(&scenario.field, &scenario.truth);
        let magnitude = scenario.field.magnitude();
        let trials: Vec<TrialOutcome> = (0..scenario.check_trials)
            .into_par_iter()
            .map(|t| {
                let mut ids = [0; CHECK_STREAM_DEPTH + 1];
                ids[..stream.len()].copy_from_slice(stream);
                ids[stream.len()] = t as u64;
                let mut rng = stream_rng(scenario.seed, stream_id(&ids[..=stream.len()]));
                match calibrate {
                    None => monte_carlo::trial(
                        &scenario.truth,
                        body,
                        magnitude,
                        sigma_nt,
                        &calibration,
                        &probe,
                        &mut rng,
                    ),
                    Some(f) => {
                        let readings = scenario.truth.noisy_readings(body, sigma_nt, &mut rng)?;
                        Ok(monte_carlo::scored(&scenario.truth, f(&readings, magnitude), &probe))
                    }
                }
            })
            .collect::<Result<_, _>>()?;
        let heading: Vec<f64> = trials
            .iter()
            .filter(|t| t.status == CalibrationStatus::Ok)
            .filter_map(|t| t.heading.map(|h| h.rms_deg))
            .collect();
        let summary = (!heading.is_empty()).then(|| Summary::new(&heading, 0));
        Ok(Self {
            sigma_nt,
            trials: trials.len(),
            outcomes: Outcomes::of(&trials),
            heading_median_deg: summary.map(|s| s.median),
            heading_p95_deg: summary.map(|s| s.p95),
        })
    }
}

impl BuiltDesign {
    /// Readings in all, `m`.
    pub fn m(&self) -> usize {
        self.readings.iter().sum()
    }

    /// One attitude per reading, in the order built: what the trials simulate.
    pub fn expanded(&self) -> Vec<Attitude> {
        self.attitudes
            .iter()
            .zip(&self.readings)
            .flat_map(|(a, &n)| std::iter::repeat_n(*a, n))
            .collect()
    }

    /// `ln det (M_F / m)`: the information per reading, which designs of different sizes share.
    pub fn ln_det_per_reading(&self) -> f64 {
        magcal_core::design::ln_det_per_reading(self.ln_det_mf, self.m())
    }
}

/// The trials of one design at one noise level.
#[derive(Debug, Clone)]
pub struct Cell {
    /// Index into [`RunOutput::designs`].
    pub design: usize,
    /// Noise level, nT.
    pub sigma_nt: f64,
    /// Execution error of the attitudes, degrees (0: flown as commanded).
    pub attitude_sigma_deg: f64,
    /// Trials in order.
    pub trials: Vec<TrialOutcome>,
    /// The Cramer-Rao bound of the design at this noise level, at the commanded attitudes.
    pub bound: CramerRao,
}

/// How the trials of a cell ended. Every trial is in exactly one class.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Outcomes {
    /// Converged: the trials the statistics are over.
    pub ok: usize,
    /// Step 2 hit its iteration limit: an estimate exists but is not a minimum; not in the
    /// statistics.
    pub not_converged: usize,
    /// The readings do not determine the estimate (step 2 ran along a flat direction, or its local
    /// standard deviations exceed the physical scales); not in the statistics.
    pub not_identifiable: usize,
    /// No estimate (no ellipsoid, rank deficient, non-finite input).
    pub failed: usize,
}

impl Outcomes {
    /// The counts of `trials`.
    pub fn of(trials: &[TrialOutcome]) -> Self {
        let count = |f: fn(&CalibrationStatus) -> bool| trials.iter().filter(|t| f(&t.status)).count();
        Self {
            ok: count(|s| *s == CalibrationStatus::Ok),
            not_converged: count(|s| *s == CalibrationStatus::NotConverged),
            not_identifiable: count(|s| *s == CalibrationStatus::NotIdentifiable),
            failed: count(|s| !s.has_estimate()),
        }
    }
}

impl Cell {
    /// The root mean square over the `ok` trials of each estimated parameter's error, in the
    /// order and units of [`magcal_core::identifiability::PARAMETERS`]; `None` without `ok` trials.
    pub fn estimate_rms(&self, truth: &magcal_core::ErrorModel) -> Option<[f64; 9]> {
        let flat = |m: &magcal_core::ErrorModel| -> [f64; 9] {
            let (p, s, o) = (m.psi_deg(), m.scale(), m.bias_nt());
            [p[0], p[1], p[2], s[0], s[1], s[2], o[0], o[1], o[2]]
        };
        let t = flat(truth);
        let mut sum = [0.0; 9];
        let mut n = 0usize;
        for e in self
            .trials
            .iter()
            .filter(|t| t.status == CalibrationStatus::Ok)
            .filter_map(|t| t.estimate.as_ref())
        {
            let v = flat(e);
            for i in 0..9 {
                sum[i] += (v[i] - t[i]).powi(2);
            }
            n += 1;
        }
        (n > 0).then(|| sum.map(|s| (s / n as f64).sqrt()))
    }

    /// The outcome counts.
    pub fn outcomes(&self) -> Outcomes {
        Outcomes::of(&self.trials)
    }

    /// Statistics of every metric, in the order of [`Metric::ALL`], over the `ok` trials that
    /// produced the metric (a relative error of a zero truth has none: every statistic undefined).
    /// `failed` beside them counts every trial that is not `ok`.
    pub fn summaries(&self) -> Vec<MetricStats> {
        let ok: Vec<&TrialOutcome> = self
            .trials
            .iter()
            .filter(|t| t.status == CalibrationStatus::Ok)
            .collect();
        let not_counted = self.trials.len() - ok.len();
        Metric::ALL
            .iter()
            .map(|&metric| {
                let v: Vec<f64> = ok.iter().filter_map(|t| metric.of(t)).collect();
                let rms = (!v.is_empty()).then(|| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt());
                MetricStats {
                    metric,
                    summary: Summary::new(&v, not_counted),
                    rms,
                }
            })
            .collect()
    }
}

/// The statistics of one metric over a cell's `ok` trials.
#[derive(Debug, Clone, Copy)]
pub struct MetricStats {
    /// Which metric.
    pub metric: Metric,
    /// Mean, std, percentiles, standard error.
    pub summary: Summary,
    /// Root mean square of the values; `None` without any.
    pub rms: Option<f64>,
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

    /// The design to fly: among those that work ([`Check::works`]), the smallest median heading
    /// error of its check, then the fewest readings, then scenario order. `None` when none works.
    pub fn recommended(&self) -> Option<usize> {
        (0..self.designs.len())
            .filter(|&i| self.designs[i].check.works())
            .min_by(|&a, &b| {
                let key = |i: usize| {
                    let d = &self.designs[i];
                    (d.check.heading_median_deg.unwrap_or(f64::INFINITY), d.m())
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

/// Options of a run that are not in the scenario.
#[derive(Debug, Clone, Copy)]
pub struct RunOptions {
    /// Draw progress bars.
    pub progress: bool,
    /// Skip the noisy trials (`magcal design`).
    pub designs_only: bool,
}

fn spinner(show: bool, message: String) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new_spinner().with_message(message);
    bar.set_style(ProgressStyle::with_template("{spinner} {msg} [{elapsed}]").expect("valid template"));
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

/// A bar counting to `len`, or a hidden one.
fn counter(show: bool, len: u64, message: String) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len).with_message(message);
    bar.set_style(
        ProgressStyle::with_template("{msg} {bar:40} {pos}/{len} [{elapsed} < {eta}]").expect("valid template"),
    );
    bar
}

/// Builds the designs of the scenario and, unless `designs_only`, runs its trials.
///
/// # Errors
/// A design that cannot be built (for example a singular one).
pub fn run(scenario: &Scenario, options: RunOptions) -> Result<RunOutput> {
    let mut stages = Vec::new();
    let t = Instant::now();
    let bar = spinner(options.progress, "approximate design and certificate".to_string());
    let approximate = {
        let problem = DesignProblem::new(scenario.field, scenario.truth, scenario.bounds, 9)?;
        let mut rng = certificate_rng(scenario.seed);
        match scenario.certificate.compute(&problem, &mut rng) {
            Ok(a) => Some(a),
            Err(ParameterError::Singular { .. }) => None,
            Err(e) => return Err(e).context("certificate"),
        }
    };
    bar.finish_and_clear();
    stages.push(("certificate".to_string(), t.elapsed().as_secs_f64()));
    let mut designs = Vec::with_capacity(scenario.designs.len());
    for (i, spec) in scenario.designs.iter().enumerate() {
        let t = Instant::now();
        // The PSO draws its own bar of iterations; two bars at once would overwrite each other.
        let is_pso = matches!(spec.source, DesignSource::Pso { .. });
        let bar = spinner(
            options.progress && !is_pso,
            format!("design {} ({})", spec.name, spec.source.kind().as_str()),
        );
        let mut rng = stream_rng(scenario.seed, stream_id(&[DESIGN_STREAM, i as u64]));
        let problem = |m: usize| {
            DesignProblem::new(scenario.field, scenario.truth, scenario.bounds, m)
                .with_context(|| format!("design {:?}", spec.name))
        };
        let single = |list: Vec<Attitude>| {
            let n = list.len();
            (list, vec![1; n])
        };
        let (attitudes, readings) = match &spec.source {
            DesignSource::Explicit(list) => single(list.clone()),
            DesignSource::Grid(levels) => single(sources::grid(&scenario.bounds, *levels)?),
            DesignSource::Random { m } => single(sources::random(&scenario.bounds, *m, &mut rng)),
            DesignSource::Pso { m, swarm } => {
                let bar = counter(
                    options.progress,
                    swarm.iterations as u64,
                    format!("design {} PSO iterations", spec.name),
                );
                let observe = |_: usize, _: f64| bar.inc(1);
                let design = swarm.optimise_observed(&problem(*m)?, &mut rng, &observe)?.design;
                bar.finish_and_clear();
                single(design)
            }
            DesignSource::Optimum { m, settings } => single(settings.optimise(&problem(*m)?, &mut rng)?.design),
            DesignSource::Plan { readings, limits } => {
                let Some(a) = &approximate else {
                    anyhow::bail!(
                        "design {:?} (plan): no design in this attitude box identifies the linear model, so there is \
                         no approximate design to round",
                        spec.name
                    );
                };
                let plan = PlanSearch::default()
                    .plan(&problem(*readings)?, a, *readings, *limits, &mut rng)
                    .with_context(|| format!("design {:?} (plan)", spec.name))?;
                (plan.attitudes, plan.readings)
            }
        };
        let every: Vec<Attitude> = attitudes
            .iter()
            .zip(&readings)
            .flat_map(|(a, &n)| std::iter::repeat_n(*a, n))
            .collect();
        let metrics = problem(every.len())?.evaluate_replicated(&attitudes, &readings);
        let body = scenario.field.body_fields(&every);
        let noise_free = scenario.truth.measure_all(&body);
        let loudest = scenario.sigmas_nt.iter().copied().fold(0.0, f64::max);
        let verdict = CramerRao::new(&scenario.truth, &body, loudest, &PhysicalScales::default()).verdict;
        let check = Check::run(scenario, i, &body, loudest)?;
        designs.push(BuiltDesign {
            name: spec.name.clone(),
            kind: spec.source.kind(),
            criterion: spec.source.criterion(),
            conditioning: Conditioning::of_readings(&noise_free, scenario.field.magnitude()),
            ln_det_mf: metrics.ln_det_mf,
            a_criterion: metrics.a,
            e_criterion: metrics.e,
            verdict,
            check,
            order: tour::flight_order(&attitudes),
            attitudes,
            readings,
        });
        bar.finish_and_clear();
        stages.push((format!("design:{}", spec.name), t.elapsed().as_secs_f64()));
    }

    let pso_runs = match &scenario.pso_runs {
        Some(spec) => {
            let t = Instant::now();
            let bar = counter(
                options.progress,
                spec.runs as u64,
                format!("repeated PSO runs of design {}", spec.design),
            );
            let problem = DesignProblem::new(scenario.field, scenario.truth, scenario.bounds, spec.m)?;
            let seed: u64 = stream_rng(scenario.seed, stream_id(&[PSO_RUNS_STREAM, 0])).random();
            let runs = spec
                .swarm
                .repeated_runs_observed(&problem, spec.runs, seed, &|_| bar.inc(1))?;
            bar.finish_and_clear();
            stages.push(("pso_runs".to_string(), t.elapsed().as_secs_f64()));
            Some(runs)
        }
        None => None,
    };

    let mut cells = Vec::new();
    if !options.designs_only {
        let t = Instant::now();
        let total =
            (designs.len() * scenario.sigmas_nt.len() * scenario.attitude_sigmas_deg.len() * scenario.trials) as u64;
        let bar = if options.progress {
            let bar = ProgressBar::new(total);
            bar.set_style(
                ProgressStyle::with_template("trials {bar:40} {pos}/{len} [{elapsed} < {eta}]")
                    .expect("valid template"),
            );
            bar
        } else {
            ProgressBar::hidden()
        };
        let probe = HeadingProbe::new(&scenario.field, &scenario.truth);
        for (d, built) in designs.iter().enumerate() {
            let commanded = built.expanded();
            let body = scenario.field.body_fields(&commanded);
            for (s, &sigma) in scenario.sigmas_nt.iter().enumerate() {
                // Step 2's local identifiability check knows the noise of the cell.
                let calibration = magcal_core::TwoStep {
                    noise_nt: Some(sigma),
                    ..scenario.calibration.clone()
                };
                let bound = CramerRao::new(&scenario.truth, &body, sigma, &PhysicalScales::default());
                for (a, &attitude_sigma) in scenario.attitude_sigmas_deg.iter().enumerate() {
                    // Without execution error the stream is [d, s, t]: those cells draw the same trials
                    // whatever execution errors the scenario also lists.
                    let level = (s + a * limits::MAX_SIGMAS) as u64;
                    let trials: Vec<TrialOutcome> = (0..scenario.trials)
                        .into_par_iter()
                        .map(|t| {
                            let mut rng = stream_rng(scenario.seed, stream_id(&[d as u64, level, t as u64]));
                            // The attitudes as flown (drawn first), then the readings' noise.
                            let flown: std::borrow::Cow<[magcal_core::Vec3]> = if attitude_sigma == 0.0 {
                                std::borrow::Cow::Borrowed(&body)
                            } else {
                                let radians = attitude_sigma.to_radians();
                                std::borrow::Cow::Owned(
                                    scenario.field.executed_body_fields(&commanded, radians, &mut rng)?,
                                )
                            };
                            let trial = monte_carlo::trial(
                                &scenario.truth,
                                &flown,
                                scenario.field.magnitude(),
                                sigma,
                                &calibration,
                                &probe,
                                &mut rng,
                            );
                            bar.inc(1);
                            trial
                        })
                        .collect::<Result<_, _>>()?;
                    cells.push(Cell {
                        design: d,
                        sigma_nt: sigma,
                        attitude_sigma_deg: attitude_sigma,
                        trials,
                        bound: bound.clone(),
                    });
                }
            }
        }
        bar.finish_and_clear();
        stages.push(("trials".to_string(), t.elapsed().as_secs_f64()));
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
