//! `magcal run`: designs, trials, statistics, figures and a manifest, written as one result set.

use clap::Args;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};

use super::{Common, Failure};
use crate::digest::{Hashing, sha256_hex};
use crate::output::file::to_stdout;
use crate::output::manifest::Manifest;
use crate::output::staging::{ResultSet, Target};
use crate::output::{self, print};
use crate::pipeline::advice::{self, Advice};
use crate::pipeline::{self, RunOptions, RunOutput};
use crate::plots;
use crate::scenario::Scenario;

/// `magcal run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    #[command(flatten)]
    pub common: Common,
    /// Output directory (default: results/SCENARIO_NAME/). Replaced whole, and only if it is
    /// missing, empty or an earlier magcal result set.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override the scenario's trials per design and noise level (1 to 10,000,000).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=crate::limits::MAX_TRIALS as u64))]
    pub trials: Option<u64>,
}

/// Runs the command.
///
/// # Errors
/// As [`produce`].
pub fn run(args: &RunArgs) -> Result<(), Failure> {
    produce(&args.common, args.out.as_deref(), args.trials.map(|t| t as usize), None)
}

/// Which flight plans `design` prints (designs.csv has all of them).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Plans {
    /// The recommended design's, under the recommendation.
    Recommended,
    /// Every design's.
    All,
}

/// Builds the designs and, unless `plans` is given (`design`: only the designs, and which flight
/// plans to print), runs the trials; writes the result set to `out` (default `results/<name>/`)
/// and swaps it in whole. `design` prints its recommendation first, `run` its table first.
///
/// # Errors
/// A bad scenario, an output directory that may not be replaced (checked before any work), a run
/// too large for the machine, or a file that cannot be written; the earlier set is then untouched.
pub fn produce(
    common: &Common,
    out: Option<&Path>,
    trials: Option<usize>,
    plans: Option<Plans>,
) -> Result<(), Failure> {
    let started = Instant::now();
    let designs_only = plans.is_some();
    let setup = super::setup(common, common.seed, trials, !designs_only)?;
    let scenario = &setup.scenario;
    let dir = out.map_or_else(|| PathBuf::from("results").join(&scenario.name), Path::to_path_buf);
    let mut set = ResultSet::begin(&dir, Target::Results, &[&common.scenario])?;
    let (mut run, advice) = planned(&setup, designs_only)?;
    let manifest = write_set(
        scenario,
        &mut run,
        advice.as_ref(),
        &mut set,
        setup.threads,
        !designs_only,
        started,
    )?;
    let staged = set.dir().to_path_buf();
    let drawn = plots::draw(&staged, &manifest, &mut set, "plots/").context("drawing the figures")?;
    set.commit()?;
    if !common.quiet {
        to_stdout(|w| {
            let headings = output::Headings::of(&scenario.field);
            match plans {
                Some(plans) => {
                    print::recommendation(w, &run, advice.as_ref())?;
                    writeln!(w)?;
                    print::summary(w, &run, &dir)?;
                    // Every plan, or the recommended one's; none when nothing is recommended.
                    let shown = match plans {
                        Plans::All => Some(None),
                        Plans::Recommended => run.recommended().map(Some),
                    };
                    if let Some(only) = shown {
                        writeln!(w)?;
                        print::flight_plans(w, &run, headings, &scenario.field_source, only)?;
                    }
                    if plans == Plans::Recommended && run.designs.len() > 1 {
                        writeln!(
                            w,
                            "(--plans prints every design's flight plan; designs.csv has them all)"
                        )?;
                    }
                }
                None => {
                    print::summary(w, &run, &dir)?;
                    print::recommendation(w, &run, advice.as_ref())?;
                }
            }
            writeln!(
                w,
                "{} figures (SVG and PNG) in {}",
                drawn.len(),
                dir.join("plots").display()
            )?;
            Ok(())
        })?;
    }
    Ok(())
}

/// The designs of `setup`'s scenario with their verdicts and, unless `designs_only`, their
/// trials; with the advice of what works instead when no design does.
///
/// # Errors
/// A scenario whose designs cannot be built (named by its path).
pub fn planned(setup: &super::Setup, designs_only: bool) -> Result<(RunOutput, Option<Advice>)> {
    let scenario = &setup.scenario;
    let options = RunOptions {
        progress: &crate::output::progress::Bars { show: setup.progress },
        designs_only,
    };
    setup
        .pool
        .install(|| -> Result<_> {
            let run = pipeline::run(scenario, options)?;
            // Only when no design works: what does instead. (Where one works but none is
            // recommended, its log is too small: the words say to fly it as a plan.)
            let advice = if run.designs.iter().any(|d| d.check.works()) {
                None
            } else {
                advice::advise(scenario, &run.designs)?
            };
            Ok((run, advice))
        })
        .with_context(|| format!("{}", scenario.path.display()))
}

/// The tables of the designs, as the result set holds them: `designs.csv`, `design_metrics.csv`,
/// `approximate.csv`, `certificate.csv` and, when no design works, `advice.csv`.
///
/// # Errors
/// Only a row that cannot be formatted.
pub fn design_tables(
    scenario: &Scenario,
    out: &RunOutput,
    advice: Option<&Advice>,
) -> Result<Vec<(&'static str, Vec<u8>)>> {
    let headings = output::Headings::of(&scenario.field);
    let mut tables = vec![
        ("designs.csv", output::csv_bytes(output::design_rows(out, headings))?),
        (
            "design_metrics.csv",
            output::csv_bytes(output::design_metrics_rows(out))?,
        ),
        (
            "approximate.csv",
            output::csv_bytes(output::approximate_rows(out, headings))?,
        ),
        (
            "certificate.csv",
            output::csv_bytes(output::certificate_rows(out, scenario.certificate.tolerance))?,
        ),
    ];
    if let Some(a) = advice {
        tables.push((
            "advice.csv",
            output::csv_bytes(output::advice_rows(out, a, &scenario.bounds))?,
        ));
    }
    Ok(tables)
}

/// Writes every file of the set but the figures (`run.json` last); returns the manifest.
fn write_set(
    scenario: &Scenario,
    out: &mut RunOutput,
    advice: Option<&Advice>,
    set: &mut ResultSet,
    threads: usize,
    with_trials: bool,
    started: Instant,
) -> Result<Manifest> {
    let mut files = BTreeMap::new();
    let mut put = |name: &str, bytes: Vec<u8>| -> Result<()> {
        set.put(name, &bytes)?;
        files.insert(name.to_string(), sha256_hex(&bytes));
        Ok(())
    };
    for (name, bytes) in design_tables(scenario, out, advice)? {
        put(name, bytes)?;
    }
    if with_trials {
        put("summary.csv", output::csv_bytes(output::summary_rows(out))?)?;
        put("crb.csv", output::csv_bytes(output::crb_rows(out, &scenario.truth))?)?;
    }
    if out.pso_runs.is_some() {
        put("pso_runs.csv", output::csv_bytes(output::pso_run_rows(out))?)?;
    }
    if with_trials {
        // The largest file: streamed, not formatted in memory, and hashed on the way.
        let mut hex = String::new();
        set.put_with("trials.csv", |w| {
            let mut w = Hashing::new(w);
            output::write_csv(output::trial_rows(out), &mut w)?;
            hex = w.hex();
            Ok(())
        })?;
        files.insert("trials.csv".into(), hex);
    }
    out.stages.push(("total".into(), started.elapsed().as_secs_f64()));
    let manifest = crate::output::manifest::run(scenario, files);
    let (bytes, seal) = manifest.to_bytes()?;
    set.put("manifest.json", &bytes)?;
    // What varies from run to run, apart from the manifest, so that the manifest reproduces.
    set.put(
        "run.json",
        &crate::output::manifest::record(seal, threads, out).to_bytes()?,
    )?;
    Ok(manifest)
}
