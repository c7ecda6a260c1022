//! `magcal replay SCENARIO LOG`: \[P1\]'s Monte Carlo (IV.C) on a real log with reference
//! attitudes instead of simulated readings.
//!
//! The scenario's designs are built as `run` builds them. Each design attitude is realised by
//! the log's windows of `--hold` consecutive readings whose body-frame field direction lies
//! within `--within-deg` of the design's ([`magcal_core::replay`]); a trial draws one window per
//! attitude, calibrates every model from the same held readings, and scores each calibration on
//! the log's other readings against the reference attitudes (heading and direction errors,
//! docs/conventions.md "Heading against a reference attitude") and, where the truth is known
//! (`--truth`), against it (\[P1\] eq. (21)-(23)). The whole log's own calibration by each model
//! is scored the same way, for comparison. The result set is replaced whole, like `run`'s.

mod models;
mod prepare;
mod trials;
mod write;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use magcal_core::reference::Rotations;
use magcal_core::replay::{
    CoverageMap, Realised, WindowIndex, body_of_paper, orient, realise, window_directions, windows,
};
use magcal_core::rng::{stream_id, stream_rng};
use magcal_core::small::{Mat3, mat_vec, norm, scale};
use rayon::prelude::*;

pub use models::Model;
pub use prepare::Truth;

use super::{Common, Failure};
use crate::log::read::HELD_BYTES_PER_READING;
use crate::log::source::{self, Log, LogArgs};
use crate::output::file::to_stdout;
use crate::output::staging::{ResultSet, Target};
use crate::pipeline::{self, BuiltDesign, RunOptions};
use crate::scenario::site::Units;
use crate::scenario::{DesignKind, Scenario};

/// `magcal replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    #[command(flatten)]
    pub common: Common,
    /// A log whose readings carry a reference attitude (motion capture, a turntable, a better
    /// navigation system), read as `calibrate` reads logs (`-`: standard input).
    #[arg(value_parser = crate::log::path_parser())]
    pub log: PathBuf,
    #[command(flatten)]
    pub input: LogArgs,
    /// The log's units (a flight log's format fixes them): the readings are turned into nT, the
    /// unit of the scenario's sensor.
    #[arg(long, value_enum)]
    pub units: Option<Units>,
    /// Output directory (default: results/replay-SCENARIO-LOGSTEM/). Replaced whole, and only if
    /// it is missing, empty or an earlier magcal replay set.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Trials per design (default: the scenario's), 1 to 1,000,000.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1_000_000))]
    pub trials: Option<u64>,
    /// Consecutive readings averaged to stand for one held attitude (default: those of 0.25 s
    /// where the log has times, else 1).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=100_000))]
    pub hold: Option<u64>,
    /// The largest angle, degrees, between a design attitude's field direction in the sensor
    /// frame and that of a window of the log that may realise it.
    #[arg(long, default_value_t = 5.0, value_name = "DEG", allow_hyphen_values = true, value_parser = crate::limits::finite)]
    pub within_deg: f64,
    /// At most this many candidate windows per design attitude, the nearest.
    #[arg(long, default_value_t = 5000, value_parser = clap::value_parser!(u64).range(1..=10_000_000))]
    pub candidates: u64,
    /// The models to calibrate with, comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_values = ["full", "diagonal", "offset", "symmetric", "vector"])]
    pub models: Vec<Model>,
    /// What is known of the sensor (see the values).
    #[arg(long, value_enum, default_value = "none")]
    pub truth: Truth,
    /// The noise of one reading per component, in the log's units (default: from the whole
    /// log's full fit).
    #[arg(long, value_name = "SIGMA", allow_hyphen_values = true, value_parser = crate::limits::finite)]
    pub noise: Option<f64>,
    /// Turn each design as a whole to where the log has readings (`fit`: the rotation that brings
    /// its farthest direction nearest to the log's; a design's information does not change under
    /// it), or realise it as it is (`none`).
    #[arg(long, value_enum, default_value = "fit")]
    pub orient: Orient,
    /// A `random` design of the scenario: drawn afresh in each trial (`redraw`: random attitudes
    /// of the design's count, each drawn again until the log realises it) or the scenario's one
    /// draw (`fixed`).
    #[arg(long, value_enum, default_value = "redraw")]
    pub random: RandomArg,
    /// Score each calibration on at most this many of the log's readings, evenly spaced (those
    /// the trial drew are left out).
    #[arg(long, default_value_t = 4000, value_parser = clap::value_parser!(u64).range(100..=10_000_000))]
    pub score_readings: u64,
}

/// `replay --orient`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Orient {
    /// The rotation that brings the design nearest to the log's coverage.
    Fit,
    /// The design as it is.
    None,
}

/// `replay --random`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RandomArg {
    /// Random attitudes drawn afresh in each trial.
    Redraw,
    /// The scenario's one draw.
    Fixed,
}

/// Stream-id prefix of the orientation search of design `d`: `[ORIENT_STREAM, d]`.
const ORIENT_STREAM: u64 = 0xFFF9;

/// Random starts of the orientation search.
const ORIENT_STARTS: usize = 20_000;

/// Everything a replay produces, before it is written.
pub struct Replay {
    pub designs: Vec<BuiltDesign>,
    /// Per design, its distinct attitudes' realisations.
    pub realised: Vec<Vec<Realised>>,
    /// Per design, the rotation it was turned by (`--orient`), degrees.
    pub turned_deg: Vec<f64>,
    /// Per design, its trials (none where an attitude has no candidate).
    pub trials: Vec<Vec<trials::Trial>>,
    /// Each model's calibration of the whole log.
    pub whole_log: Vec<trials::Scored>,
    pub models: Vec<Model>,
    pub hold: usize,
    /// The noise of a held reading the verdicts rest on, nT: the measured error of a held
    /// reading (the rms of `|P (h - O)| - R` over the windows under the whole log's calibration) or,
    /// where larger, white noise averaged over the hold.
    pub held_noise: f64,
    /// White noise averaged over the hold, nT.
    pub white_held_noise: f64,
    /// The measured error of a held reading, nT.
    pub measured_held_error: Option<f64>,
    pub scoring: usize,
    pub prepared: prepare::Prepared,
    pub trials_per_design: usize,
}

/// Runs the command.
///
/// # Errors
/// A bad scenario or log, flags out of range, an output directory that may not be replaced (all
/// before any work), or a file that cannot be written; the earlier set is then untouched.
pub fn run(args: &ReplayArgs) -> Result<(), Failure> {
    let started = Instant::now();
    check_flags(args)?;
    let setup = super::setup(&args.common, args.common.seed, args.trials.map(|t| t as usize), false)?;
    let scenario = &setup.scenario;
    let dir = args.out.clone().unwrap_or_else(|| default_dir(scenario, &args.log));
    let mut set = ResultSet::begin(&dir, Target::Replay, &[&args.common.scenario, &args.log])?;
    let shown = args.log.display().to_string();
    let log = source::open(&args.log, &args.input, HELD_BYTES_PER_READING)?;
    let units = units_of(args, &log).with_context(|| shown.clone())?;
    let prepared = prepare::prepare(
        &log,
        units.nt(),
        args.truth,
        scenario,
        args.noise.map(|n| n * units.nt()),
    )
    .with_context(|| shown.clone())?;
    let bars = crate::output::progress::Bars { show: setup.progress };
    let replay = setup
        .pool
        .install(|| replay(args, scenario, prepared, &bars))
        .with_context(|| format!("{} on {shown}", scenario.path.display()))?;
    write::write_set(args, scenario, &log, &replay, &mut set, units)?;
    set.commit()?;
    if !args.common.quiet {
        to_stdout(|w| write::print(w, &replay, &dir, started.elapsed().as_secs_f64()))?;
    }
    Ok(())
}

/// Builds the designs, realises them on the log, runs the trials and the whole log's fits.
fn replay(
    args: &ReplayArgs,
    scenario: &Scenario,
    prepared: prepare::Prepared,
    bars: &crate::output::progress::Bars,
) -> Result<Replay> {
    let built = pipeline::run(
        scenario,
        RunOptions {
            progress: bars,
            designs_only: true,
        },
    )?;
    let hold = args
        .hold
        .map_or_else(|| default_hold(prepared.times.as_deref()), |h| h as usize);
    let n = prepared.readings.len();
    if hold * 10 > n {
        bail!("--hold {hold}: the log has {n} readings with an attitude, fewer than ten holds");
    }
    let starts = windows(n, prepared.times.as_deref(), hold);
    let directions = window_directions(&prepared.directions, hold);
    let map = coverage(args, &starts, &directions);
    let index = WindowIndex::new(&starts, &directions);
    let (realised, turned_deg) = realise_designs(args, scenario, &built.designs, map.as_ref(), &index);
    let valid: Vec<usize> = starts.iter().flatten().copied().collect();
    let measured = prepare::held_error(&prepared, &valid, hold);
    let white = prepared.noise / (hold as f64).sqrt();
    let held_noise = measured.map_or(white, |m| m.max(white));
    let step = n.div_ceil(args.score_readings as usize).max(1);
    let scoring: Vec<usize> = (0..n).step_by(step).collect();
    let rotations = Rotations::new(prepared.attitudes.clone()).ok();
    let plan = trials::Plan {
        log: &prepared,
        models: &args.models,
        hold,
        held_noise,
        two_step: &scenario.calibration,
        scoring: &scoring,
        rotations: rotations.as_ref(),
        seed: scenario.seed,
    };
    let redraw = trials::Redraw {
        bounds: &scenario.bounds,
        field: &scenario.field,
        map: map.as_ref(),
        index: &index,
        within_deg: args.within_deg,
        candidates: args.candidates as usize,
    };
    let trials = run_trials(args, scenario, &built.designs, &realised, &plan, &redraw, bars);
    let whole_log = plan.whole_log();
    Ok(Replay {
        designs: built.designs,
        realised,
        turned_deg,
        trials,
        whole_log,
        models: args.models.clone(),
        hold,
        held_noise,
        white_held_noise: white,
        measured_held_error: measured,
        scoring: scoring.len(),
        prepared,
        trials_per_design: scenario.trials,
    })
}

/// Every design's trials, in design order: a random design drawn afresh in each trial (with
/// `--random redraw`), a design with an attitude the log cannot realise none.
fn run_trials(
    args: &ReplayArgs,
    scenario: &Scenario,
    designs: &[BuiltDesign],
    realised: &[Vec<Realised>],
    plan: &trials::Plan,
    redraw: &trials::Redraw,
    bars: &crate::output::progress::Bars,
) -> Vec<Vec<trials::Trial>> {
    let random = |design: &BuiltDesign| design.kind == DesignKind::Random && args.random == RandomArg::Redraw;
    let total: usize = designs
        .iter()
        .zip(realised)
        .filter(|(d, r)| random(d) || r.iter().all(|p| !p.is_empty()))
        .count()
        * scenario.trials;
    let bar = bars_stage(bars, total);
    let trials = designs
        .iter()
        .zip(realised)
        .enumerate()
        .map(|(d, (design, points))| {
            let points = if random(design) {
                trials::Points::Random { m: design.m(), redraw }
            } else if points.iter().any(Realised::is_empty) {
                return Vec::new();
            } else {
                trials::Points::Fixed(
                    points
                        .iter()
                        .zip(&design.readings)
                        .flat_map(|(p, &k)| std::iter::repeat_n(p.clone(), k))
                        .collect(),
                )
            };
            plan.run(d, &points, scenario.trials, &bar)
        })
        .collect();
    bar.finish_and_clear();
    trials
}

/// The log's coverage of directions for `--orient fit` (at most 4000 windows' directions).
fn coverage(
    args: &ReplayArgs,
    starts: &[Option<usize>],
    directions: &[Option<magcal_core::Vec3>],
) -> Option<CoverageMap> {
    (args.orient == Orient::Fit).then(|| {
        let valid: Vec<_> = starts.iter().flatten().filter_map(|&s| directions[s]).collect();
        let every = valid.len().div_ceil(4000).max(1);
        CoverageMap::new(&valid.into_iter().step_by(every).collect::<Vec<_>>())
    })
}

/// Each design's attitudes realised on the log (turned to its coverage where `map` is given),
/// and the angle each design was turned by.
fn realise_designs(
    args: &ReplayArgs,
    scenario: &Scenario,
    designs: &[BuiltDesign],
    map: Option<&CoverageMap>,
    index: &WindowIndex,
) -> (Vec<Vec<Realised>>, Vec<f64>) {
    let (realised, turned_deg): (Vec<Vec<Realised>>, Vec<f64>) = designs
        .par_iter()
        .enumerate()
        .map(|(d, design)| {
            let targets: Vec<_> = scenario
                .field
                .body_fields(&design.attitudes)
                .iter()
                .map(|b| body_of_paper(scale(1.0 / norm(*b), *b)))
                .collect();
            let turn = map.map_or(IDENTITY, |map| {
                let mut rng = stream_rng(scenario.seed, stream_id(&[ORIENT_STREAM, d as u64]));
                orient(&targets, map, ORIENT_STARTS, &mut rng).0
            });
            let points = targets
                .iter()
                .map(|t| realise(mat_vec(&turn, *t), index, args.within_deg, args.candidates as usize))
                .collect();
            (points, prepare::rotation_angle_deg(&turn))
        })
        .unzip();
    (realised, turned_deg)
}

fn bars_stage(bars: &crate::output::progress::Bars, total: usize) -> indicatif::ProgressBar {
    use crate::pipeline::Progress;
    bars.stage("replay", Some(total as u64))
}

const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// The readings of 0.25 s where the log has times (at least 1), else 1.
fn default_hold(times: Option<&[f64]>) -> usize {
    let Some(t) = times else { return 1 };
    let span = t.last().copied().unwrap_or(0.0) - t.first().copied().unwrap_or(0.0);
    if span.is_nan() || span <= 0.0 || t.len() < 2 {
        return 1;
    }
    let rate = (t.len() - 1) as f64 / span;
    ((0.25 * rate).round() as usize).max(1)
}

/// Flags whose range clap cannot check.
fn check_flags(args: &ReplayArgs) -> Result<()> {
    if !(args.within_deg.is_finite() && args.within_deg > 0.0 && args.within_deg <= 90.0) {
        bail!(
            "--within-deg {}: must be above 0 and at most 90 degrees",
            crate::limits::show(args.within_deg)
        );
    }
    if let Some(n) = args.noise
        && !(n.is_finite() && n > 0.0)
    {
        bail!(
            "--noise {}: must be finite and positive (the log's units)",
            crate::limits::show(n)
        );
    }
    if args.models.is_empty() {
        bail!("--models: name at least one model");
    }
    let mut seen = args.models.clone();
    seen.sort();
    seen.dedup();
    if seen.len() != args.models.len() {
        bail!("--models: a model is named twice");
    }
    Ok(())
}

/// The log's units: `--units`, or those its format fixes; the two must agree.
fn units_of(args: &ReplayArgs, log: &Log) -> Result<Units> {
    match (args.units, log.origin.unit) {
        (Some(given), Some(logged)) if given != logged => {
            bail!("--units: the log's format fixes its units, and they are not the ones given")
        }
        (Some(u), _) | (None, Some(u)) => Ok(u),
        (None, None) => bail!("give --units (the log's: nT, uT, mG or G): the scenario's sensor and noise are in nT"),
    }
}

/// `results/replay-<scenario>-<log stem>`.
fn default_dir(scenario: &Scenario, log: &Path) -> PathBuf {
    let stem = log
        .file_stem()
        .map_or_else(|| "log".to_string(), |s| s.to_string_lossy().into_owned());
    PathBuf::from("results").join(format!("replay-{}-{stem}", scenario.name))
}
