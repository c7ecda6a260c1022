//! One module per command. The scenario commands: [`run`] and [`design`] (which share
//! [`run::produce`]), [`check`] and [`plot`]. The log commands: [`calibrate`] fits a log,
//! [`apply`] calibrates a log's readings with a calibration file, [`next`] picks the attitudes
//! that add most to a log, [`evaluate`] judges a calibration against a log's reference
//! attitudes, [`simulate`] writes a log of a known sensor; what they share (reading
//! a log, the site and units, the calibration file, the vehicle's box) is in [`crate::log`].
//! Every command that reads a scenario starts from [`setup`].

pub mod apply;
pub mod calibrate;
pub mod check;
pub mod design;
pub mod evaluate;
pub mod export;
pub mod live;
pub mod next;
pub mod plot;
pub mod replay;
pub mod report;
pub mod run;
pub mod simulate;

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

use crate::limits;
use crate::output::stderr::to_stderr;
use crate::scenario::{self, Scenario};

/// Flags every scenario command takes.
#[derive(Debug, Args)]
pub struct Common {
    /// The scenario file (TOML; every key commented in scenarios/template.toml, docs/reference/scenarios.md).
    pub scenario: PathBuf,
    /// Override the scenario's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Worker threads, 1 to 256 (default: all cores). Results do not depend on it.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=limits::MAX_THREADS as u64))]
    pub threads: Option<u64>,
    /// No progress bars and no summary table.
    #[arg(long)]
    pub quiet: bool,
    /// Run even when the PSO work is estimated above one day (the estimate is printed first).
    #[arg(long)]
    pub allow_long: bool,
    /// The heading error a design's calibration may leave, degrees (default: the scenario's
    /// `[verdict] heading_budget_deg`, else 2): a design works where 95 % of its check's trials
    /// leave the heading within it at the 95th percentile over the box at every heading and,
    /// where that is above half the budget, 18 of 20 logs of it flown are usable as calibrate
    /// judges them.
    #[arg(long, value_name = "DEG", allow_hyphen_values = true, value_parser = crate::limits::heading_budget)]
    pub heading_budget: Option<f64>,
}

/// A failure with its exit code.
#[derive(Debug)]
pub enum Failure {
    /// Bad input or usage, or an output that cannot be written: exit 2.
    Input(anyhow::Error),
    /// `check` found a regression: exit 1 (the table of what moved).
    Regression(String),
    /// The result is not a calibration to use: the log does not determine it, or rejects its
    /// model. Exit 3, with the reason. `calibrate` writes its outputs all the same; `export`
    /// writes nothing unless forced (`--force`), and then says so in what it writes.
    Unusable(String),
}

impl From<anyhow::Error> for Failure {
    fn from(e: anyhow::Error) -> Self {
        Self::Input(e)
    }
}

/// A validated scenario with its overrides applied, and the workers to run it.
pub struct Setup {
    /// The scenario.
    pub scenario: Scenario,
    /// Worker threads.
    pub threads: usize,
    /// The pool they form.
    pub pool: rayon::ThreadPool,
    /// Draw progress bars.
    pub progress: bool,
}

/// Loads the scenario, applies `seed` and `trials`, checks the memory the run needs (with trials
/// or without), and starts the workers.
///
/// # Errors
/// A bad scenario, a run too large for the machine, or threads that cannot start.
pub fn setup(common: &Common, seed: Option<u64>, trials: Option<usize>, with_trials: bool) -> Result<Setup> {
    setup_with(common, scenario::load(&common.scenario)?, seed, trials, with_trials)
}

/// [`setup`] for a scenario already loaded.
///
/// # Errors
/// As [`setup`].
pub fn setup_with(
    common: &Common,
    mut scenario: Scenario,
    seed: Option<u64>,
    trials: Option<usize>,
    with_trials: bool,
) -> Result<Setup> {
    if let Some(seed) = seed {
        scenario.seed = seed;
    }
    if let Some(t) = trials {
        scenario.trials = t;
    }
    if let Some(b) = common.heading_budget {
        scenario.heading_budget_deg = crate::scenario::validate::heading_budget(Some(b))
            .map_err(|e| anyhow::anyhow!("--heading-budget: {e:#}"))?;
    }
    let threads = match common.threads {
        Some(n) => n as usize,
        None => std::thread::available_parallelism().map_or(1, |n| n.get().min(limits::MAX_THREADS)),
    };
    crate::pipeline::budget::check_memory(&scenario, with_trials, threads).with_context(|| {
        format!(
            "{}: trials = {}, threads {threads}",
            common.scenario.display(),
            scenario.trials
        )
    })?;
    let context = || format!("{}", common.scenario.display());
    if let Some(words) =
        crate::pipeline::budget::check_time(&scenario, threads, common.allow_long).with_context(context)?
    {
        to_stderr!("magcal: note: {}: {words}", common.scenario.display());
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("cannot start worker threads")?;
    Ok(Setup {
        scenario,
        threads,
        pool,
        progress: !common.quiet && std::io::stderr().is_terminal(),
    })
}
