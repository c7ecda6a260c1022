//! `magcal`: scenario files -> designs -> noisy Monte Carlo trials -> CSV statistics, and regression
//! checks against committed results. The mathematics lives in `magcal-core`; this binary is glue.
//!
//! Exit codes: 0 success, 1 regression found by `check`, 2 bad input or usage.

mod check;
mod export;
mod pipeline;
mod plots;
mod scenario;

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};

use crate::export::{Manifest, to_bytes, write_atomic};
use crate::pipeline::{RunOptions, RunOutput};

/// Calibration of strapdown three-axis magnetometers and D-optimal calibration manoeuvres, after
/// Wu, Hu, Wu, Liu, "D-Optimal Design Applied to Calibration of Strapdown Three-axis Magnetometer".
#[derive(Debug, Parser)]
#[command(name = "magcal", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Build the designs, run the noisy trials, write statistics, designs and a manifest.
    Run(RunArgs),
    /// Build the designs and write only their attitudes and metrics.
    Design(DesignArgs),
    /// Run again and compare with committed results; exit 1 when something moved.
    Check(CheckArgs),
    /// Redraw the figures of a results directory from its CSV files (into DIR/plots/).
    Plot(PlotArgs),
}

#[derive(Debug, Args)]
struct PlotArgs {
    /// A results directory written by `magcal run` or `magcal design`.
    dir: PathBuf,
}

#[derive(Debug, Args)]
struct Common {
    /// The scenario file (TOML; see README "Scenario files").
    scenario: PathBuf,
    /// Override the scenario's seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long)]
    threads: Option<usize>,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
}

#[derive(Debug, Args)]
struct RunArgs {
    #[command(flatten)]
    common: Common,
    /// Output directory (default: results/SCENARIO_NAME/).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Override the scenario's trials per design and noise level.
    #[arg(long)]
    trials: Option<usize>,
}

#[derive(Debug, Args)]
struct DesignArgs {
    #[command(flatten)]
    common: Common,
    /// Output directory (default: results/SCENARIO_NAME/).
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(Debug, Args)]
struct CheckArgs {
    #[command(flatten)]
    common: Common,
    /// The committed results to compare with (default: results/SCENARIO_NAME/).
    #[arg(long)]
    baseline: Option<PathBuf>,
}

/// A failure with its exit code.
enum Failure {
    /// Bad input or usage: exit 2.
    Input(anyhow::Error),
    /// `check` found a regression: exit 1.
    Regression(String),
}

impl From<anyhow::Error> for Failure {
    fn from(e: anyhow::Error) -> Self {
        Self::Input(e)
    }
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let _ = e.print();
            return match e.kind() {
                clap::error::ErrorKind::DisplayHelp | clap::error::ErrorKind::DisplayVersion => ExitCode::SUCCESS,
                _ => ExitCode::from(2),
            };
        }
    };
    match dispatch(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure::Input(e)) => {
            eprintln!("magcal: error: {e:#}");
            ExitCode::from(2)
        }
        Err(Failure::Regression(table)) => {
            eprintln!("magcal: regression: these results moved beyond their tolerance:\n{table}");
            ExitCode::from(1)
        }
    }
}

fn dispatch(cli: Cli) -> Result<(), Failure> {
    let common = match &cli.command {
        Command::Run(a) => &a.common,
        Command::Design(a) => &a.common,
        Command::Check(a) => &a.common,
        Command::Plot(a) => {
            let pngs = plots::plot_dir(&a.dir)?;
            println!("{} figures drawn in {}", pngs.len(), a.dir.join("plots").display());
            return Ok(());
        }
    };
    let mut scenario = scenario::load(&common.scenario)?;
    if let Some(seed) = common.seed {
        scenario.seed = seed;
    }
    if let Command::Run(RunArgs { trials: Some(t), .. }) = &cli.command {
        if *t == 0 {
            return Err(anyhow::anyhow!("--trials 0: give at least one trial").into());
        }
        scenario.trials = *t;
    }
    let threads = match common.threads {
        Some(0) => return Err(anyhow::anyhow!("--threads 0: give at least one thread").into()),
        Some(n) => n,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("cannot start worker threads")?;
    let progress = !common.quiet && std::io::stderr().is_terminal();
    let default_dir = || PathBuf::from("results").join(&scenario.name);

    match &cli.command {
        Command::Run(RunArgs { out: dir, .. }) | Command::Design(DesignArgs { out: dir, .. }) => {
            let started = Instant::now();
            let designs_only = matches!(cli.command, Command::Design(_));
            let options = RunOptions { progress, designs_only };
            let mut out = pool.install(|| pipeline::run(&scenario, options))?;
            let dir = dir.clone().unwrap_or_else(default_dir);
            write_results(&scenario, &mut out, &dir, threads, !designs_only, started)?;
            let pngs = plots::plot_dir(&dir).context("the results are written; drawing their figures failed")?;
            if !common.quiet {
                print_summary(&out, &dir);
                println!("{} figures in {}", pngs.len(), dir.join("plots").display());
            }
        }
        Command::Plot(_) => unreachable!("handled above"),
        Command::Check(args) => {
            let dir = args.baseline.clone().unwrap_or_else(default_dir);
            if !dir.is_dir() {
                return Err(anyhow::anyhow!("{}: baseline directory not found", dir.display()).into());
            }
            let options = RunOptions {
                progress,
                designs_only: false,
            };
            let out = pool.install(|| pipeline::run(&scenario, options))?;
            let moved = check::compare(&out, &dir)?;
            if !moved.is_empty() {
                return Err(Failure::Regression(check::report(&moved)));
            }
            if !common.quiet {
                println!(
                    "magcal check: {} matches {} within tolerance",
                    scenario.path.display(),
                    dir.display()
                );
            }
        }
    }
    Ok(())
}

/// Formats every file in memory first, then puts each in place atomically.
fn write_results(
    scenario: &scenario::Scenario,
    out: &mut RunOutput,
    dir: &Path,
    threads: usize,
    with_trials: bool,
    started: Instant,
) -> Result<()> {
    let mut files: Vec<(&str, Vec<u8>)> = vec![
        ("designs.csv", to_bytes(|w| export::designs_csv(out, w))?),
        ("design_metrics.csv", to_bytes(|w| export::design_metrics_csv(out, w))?),
    ];
    if with_trials {
        files.push(("summary.csv", to_bytes(|w| export::summary_csv(out, w))?));
        files.push(("trials.csv", to_bytes(|w| export::trials_csv(out, w))?));
    }
    if out.pso_runs.is_some() {
        files.push(("pso_runs.csv", to_bytes(|w| export::pso_runs_csv(out, w))?));
    }
    out.stages.push(("total".into(), started.elapsed().as_secs_f64()));
    let names: Vec<String> = files.iter().map(|(n, _)| n.to_string()).collect();
    let manifest = to_bytes(|w| Manifest::new(scenario, out, threads, names).write(w))?;
    files.push(("manifest.json", manifest));
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create output directory", dir.display()))?;
    for (name, bytes) in files {
        write_atomic(&dir.join(name), &bytes)?;
    }
    Ok(())
}

fn print_summary(out: &RunOutput, dir: &Path) {
    println!("{:<14} {:>10} {:>9}", "design", "ln det M_F", "D-eff");
    for (i, d) in out.designs.iter().enumerate() {
        println!("{:<14} {:>10.4} {:>9.4}", d.name, d.ln_det_mf, out.d_efficiency(i));
    }
    if !out.cells.is_empty() {
        println!();
        println!(
            "{:<14} {:>8} {:>7} {:>18} {:>18} {:>18}",
            "design", "sigma_nt", "failed", "eta_psi mean/med %", "eta_S mean/med %", "eta_O mean/med %"
        );
        for cell in &out.cells {
            let s = cell.summaries();
            println!(
                "{:<14} {:>8} {:>7} {:>9.3}/{:<8.3} {:>9.3}/{:<8.3} {:>9.3}/{:<8.3}",
                out.designs[cell.design].name,
                cell.sigma_nt,
                cell.failed(),
                s[0].1.mean,
                s[0].1.median,
                s[1].1.mean,
                s[1].1.median,
                s[2].1.mean,
                s[2].1.median
            );
        }
    }
    if let Some(runs) = &out.pso_runs {
        let v: Vec<f64> = runs.iter().map(|r| -r.fitness).collect();
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        println!("\n{} PSO runs: final ln det M_F from {lo:.4} to {hi:.4}", v.len());
    }
    let times: Vec<String> = out.stages.iter().map(|(n, t)| format!("{n} {t:.3} s")).collect();
    println!("\ntimes: {}", times.join(", "));
    println!("written to {}", dir.display());
}
