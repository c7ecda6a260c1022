//! The designs of a scenario: the approximate design that certifies them, each design from its
//! source (a list, a grid, random, the PSO, the optimum, a plan) with its metrics and verdict, and
//! the repeated PSO runs of \[P1\] Fig. 4.

use anyhow::{Context, Result};
use magcal_core::design::approximate::ApproximateDesign;
use magcal_core::design::plan::PlanSearch;
use magcal_core::design::pso::RunSummary;
use magcal_core::design::{DesignProblem, replicated, sources, tour};
use magcal_core::rng::{MagcalRng, stream_id, stream_rng};
use magcal_core::{Attitude, Conditioning, CramerRao, ParameterError, PhysicalScales};
use rand::RngExt;

use super::check::Check;
use super::{BuiltDesign, DESIGN_STREAM, PSO_RUNS_STREAM, Progress, certificate_rng};
use crate::scenario::{DesignSource, DesignSpec, Scenario};

/// The approximate D-optimal design of the scenario's box and its certificate; `None` when no
/// design in the box identifies the linear model.
///
/// # Errors
/// A certificate that cannot be computed for another reason than a singular box.
pub fn approximate(scenario: &Scenario, progress: &dyn Progress) -> Result<Option<ApproximateDesign>> {
    let bar = progress.stage("approximate design and certificate", None);
    let problem = DesignProblem::new(scenario.field, scenario.truth, scenario.bounds, 9)?;
    let mut rng = certificate_rng(scenario.seed);
    let approximate = match scenario.certificate.compute(&problem, &mut rng) {
        Ok(a) => Some(a),
        Err(ParameterError::Singular { .. }) => None,
        Err(e) => return Err(e).context("certificate"),
    };
    bar.finish_and_clear();
    Ok(approximate)
}

/// Builds design `i` of the scenario (`spec`), on its stream `[DESIGN_STREAM, i]`, with its
/// metrics, the Cramer-Rao verdict and the Monte Carlo check at the largest noise level.
///
/// # Errors
/// A design that cannot be built (a singular one, a plan without an approximate design).
pub fn design(
    scenario: &Scenario,
    i: usize,
    approximate: Option<&ApproximateDesign>,
    progress: &dyn Progress,
) -> Result<BuiltDesign> {
    let spec = &scenario.designs[i];
    // The PSO draws its own bar of iterations; two bars at once would overwrite each other.
    let bar = match spec.source {
        DesignSource::Pso { .. } => indicatif::ProgressBar::hidden(),
        _ => progress.stage(&format!("design {} ({})", spec.name, spec.source.kind().as_str()), None),
    };
    let mut rng = stream_rng(scenario.seed, stream_id(&[DESIGN_STREAM, i as u64]));
    let (attitudes, readings) = attitudes(scenario, spec, approximate, &mut rng, progress)?;
    let every = replicated(&attitudes, &readings);
    let metrics = problem(scenario, spec, every.len())?.evaluate_replicated(&attitudes, &readings);
    let body = scenario.field.body_fields(&every);
    let noise_free = scenario.truth.measure_all(&body);
    let loudest = scenario.sigmas_nt.iter().copied().fold(0.0, f64::max);
    let verdict = CramerRao::new(&scenario.truth, &body, loudest, &PhysicalScales::default()).verdict;
    let check = Check::run(scenario, i, &body, loudest)?;
    bar.finish_and_clear();
    Ok(BuiltDesign {
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
    })
}

/// The design problem of `m` readings in the scenario's box.
fn problem(scenario: &Scenario, spec: &DesignSpec, m: usize) -> Result<DesignProblem> {
    DesignProblem::new(scenario.field, scenario.truth, scenario.bounds, m)
        .with_context(|| format!("design {:?}", spec.name))
}

/// The distinct attitudes of a design and the readings planned at each (1 but for a plan).
fn attitudes(
    scenario: &Scenario,
    spec: &DesignSpec,
    approximate: Option<&ApproximateDesign>,
    rng: &mut MagcalRng,
    progress: &dyn Progress,
) -> Result<(Vec<Attitude>, Vec<usize>)> {
    let single = |list: Vec<Attitude>| {
        let n = list.len();
        (list, vec![1; n])
    };
    Ok(match &spec.source {
        DesignSource::Explicit(list) => single(list.clone()),
        DesignSource::Grid(levels) => single(sources::grid(&scenario.bounds, *levels)?),
        DesignSource::Random { m } => single(sources::random(&scenario.bounds, *m, rng)),
        DesignSource::Pso { m, swarm } => {
            let bar = progress.stage(
                &format!("design {} PSO iterations", spec.name),
                Some(swarm.iterations as u64),
            );
            let observe = |_: usize, _: f64| bar.inc(1);
            let design = swarm
                .optimise_observed(&problem(scenario, spec, *m)?, rng, &observe)?
                .design;
            bar.finish_and_clear();
            single(design)
        }
        DesignSource::Optimum { m, settings } => single(settings.optimise(&problem(scenario, spec, *m)?, rng)?.design),
        DesignSource::Plan { readings, limits } => {
            let Some(a) = approximate else {
                anyhow::bail!(
                    "design {:?} (plan): no design in this attitude box identifies the linear model, so there is no \
                     approximate design to round",
                    spec.name
                );
            };
            let plan = PlanSearch::default()
                .plan(&problem(scenario, spec, *readings)?, a, *readings, *limits, rng)
                .with_context(|| format!("design {:?} (plan)", spec.name))?;
            (plan.attitudes, plan.readings)
        }
    })
}

/// The repeated PSO runs the scenario asks for (\[P1\] Fig. 4), from a seed drawn on
/// `[PSO_RUNS_STREAM, 0]`; `None` when it asks for none.
///
/// # Errors
/// A design problem that cannot be built.
pub fn pso_runs(scenario: &Scenario, progress: &dyn Progress) -> Result<Option<Vec<RunSummary>>> {
    let Some(spec) = &scenario.pso_runs else {
        return Ok(None);
    };
    let bar = progress.stage(
        &format!("repeated PSO runs of design {}", spec.design),
        Some(spec.runs as u64),
    );
    let problem = DesignProblem::new(scenario.field, scenario.truth, scenario.bounds, spec.m)?;
    let seed: u64 = stream_rng(scenario.seed, stream_id(&[PSO_RUNS_STREAM, 0])).random();
    let runs = spec
        .swarm
        .repeated_runs_observed(&problem, spec.runs, seed, &|_| bar.inc(1))?;
    bar.finish_and_clear();
    Ok(Some(runs))
}
