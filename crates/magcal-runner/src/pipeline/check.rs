//! The verdict of a design: does it calibrate, at the scenario's noise, in a short Monte Carlo of
//! its own? The Cramer-Rao bound predicts; these trials show (docs/conventions.md "The verdict of a
//! design").

use anyhow::Result;
use magcal_core::heading::HeadingProbe;
use magcal_core::log_fit::FitModel;
use magcal_core::monte_carlo::{self, TrialOutcome};
use magcal_core::rng::{stream_id, stream_rng};
use magcal_core::{CalibrationStatus, Summary};
use rayon::prelude::*;

use super::trials::Outcomes;
use super::{CHECK_STREAM, CHECK_STREAM_DEPTH};
use crate::scenario::Scenario;

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
    /// The heading budget, degrees ([`Scenario::heading_budget_deg`]).
    pub budget_deg: f64,
    /// The 95/95 tolerance of the heading error over the box at every heading of the `ok`
    /// trials' calibrations, against the truth (the 95th percentile over the trials of each
    /// one's over the attitudes; docs/conventions.md "Heading budget"), degrees; `None` without
    /// an `ok` trial.
    pub budget_p95_deg: Option<f64>,
    /// Of [`Self::LOGS`] logs of the design flown at the check's noise (simulated), how many
    /// `calibrate` judges usable; `None` where they are not flown: the trials
    /// miss the budget, or meet it by more than [`Self::LOGS_BELOW`] of it, or calibrate by an
    /// estimator of the caller's (a reduced model of design's advice, which `calibrate` fits
    /// otherwise), or the design has too few readings for a log of it to hold a fifth out (no
    /// such log is ever usable; design says to fly its attitudes as a plan).
    pub logs_usable: Option<usize>,
}

impl Check {
    /// The share of trials a design must calibrate (`ok`) to work.
    pub const OK_SHARE: f64 = 0.95;

    /// Whether the design calibrates in at least [`Self::OK_SHARE`] of the trials and its
    /// calibrations keep the heading within the budget ([`Self::meets_budget`]).
    pub fn works(&self) -> bool {
        self.calibrates() && self.meets_budget()
    }

    /// Whether the design calibrates in at least [`Self::OK_SHARE`] of the trials.
    pub fn calibrates(&self) -> bool {
        self.trials > 0 && self.outcomes.ok as f64 >= Self::OK_SHARE * self.trials as f64
    }

    /// Whether the heading error its trials' calibrations leave over the box (the 95/95
    /// tolerance) is within the budget, and 95 % of its logs will be judged so by `calibrate`
    /// ([`Self::logs_meet_budget`]).
    pub fn meets_budget(&self) -> bool {
        self.truth_meets_budget() && self.logs_meet_budget()
    }

    /// Whether the heading error its trials' calibrations leave over the box, against the
    /// truth (the 95/95 tolerance), is within the budget.
    pub fn truth_meets_budget(&self) -> bool {
        self.budget_p95_deg.is_some_and(|p| p <= self.budget_deg)
    }

    /// Whether its logs are judged usable by `calibrate` ([`Self::logs_usable`] at least
    /// [`Self::LOGS_USABLE`] of [`Self::LOGS`]), where they are flown. A log states the heading
    /// its own estimate leaves, and that scatters about the truth's along a valley of scale and
    /// bias (a rover's +-3 degree box, 1000 readings at 30 nT: 0.97 to 1.79 degrees over 20 logs
    /// where the trials' figure is 1.28; at 500 readings, 1.52 in truth, 9 of 20 logs usable), so
    /// a plan whose truth is near the budget gives logs that `calibrate` refuses.
    pub fn logs_meet_budget(&self) -> bool {
        self.logs_usable.is_none_or(|k| k >= Self::LOGS_USABLE)
    }

    /// Logs flown per design whose trials meet the budget by less than [`Self::LOGS_BELOW`].
    pub const LOGS: usize = 20;

    /// Of them, the usable ones a design needs: 90 %. A plan of which 95 % of the logs are
    /// usable passes with probability 0.92, one of 80 % with 0.21 (binomial).
    pub const LOGS_USABLE: usize = 18;

    /// The share of the budget below which the logs are not flown: the figure a log states of
    /// itself is at most 1.8 times its design's over the 200 logs of recommended designs of
    /// `scripts/loop.py` (results/loop/logs.csv), so a design at half the budget gives logs
    /// within it.
    pub const LOGS_BELOW: f64 = 0.5;

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
                let mut rng = trial_rng(scenario.seed, stream, t);
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
        let budget_p95_deg = budget_p95(scenario, &trials);
        let budget = scenario.heading_budget_deg;
        let logs_usable = budget_p95_deg
            .filter(|p| *p <= budget && *p > Self::LOGS_BELOW * budget)
            .filter(|_| {
                calibrate.is_none() && body.len() >= magcal_core::log_fit::min_held_out_readings(FitModel::Full)
            })
            .map(|_| logs_usable(scenario, stream, body, sigma_nt))
            .transpose()?;
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
            budget_deg: scenario.heading_budget_deg,
            budget_p95_deg,
            logs_usable,
        })
    }
}

/// The grid of a scenario's heading budget: its box's roll and pitch at every heading, in its
/// field, in \[P1\]'s body axes.
pub fn budget_grid(scenario: &Scenario) -> magcal_core::budget::BudgetGrid {
    grid_of_box(&scenario.field, &scenario.bounds)
}

/// The grid of a heading budget over `bounds`' roll and pitch at every heading, in `field`, in
/// \[P1\]'s body axes.
pub fn grid_of_box(
    field: &magcal_core::ReferenceField,
    bounds: &magcal_core::AttitudeBox,
) -> magcal_core::budget::BudgetGrid {
    let [roll, _, pitch] = bounds.ranges();
    let tilts = magcal_core::budget::Tilts::of_box([roll.min(), roll.max()], [pitch.min(), pitch.max()]);
    // A field without a horizontal part has no heading: the grid is judged at 89 degrees.
    let inclination = field.inclination_deg().clamp(-89.0, 89.0);
    magcal_core::budget::BudgetGrid::new(inclination, tilts, &magcal_core::budget::IDENTITY)
}

/// The 95/95 tolerance (`magcal_core::budget::tolerance`) of the heading error the `ok` trials'
/// calibrations leave over the scenario's budget grid, against its true sensor: the 95th
/// percentile over the trials of each one's 95th percentile over the attitudes, what 95 % of the
/// logs flown so leave; `None` without an `ok` trial.
fn budget_p95(scenario: &Scenario, trials: &[TrialOutcome]) -> Option<f64> {
    let grid = budget_grid(scenario);
    let truth = (&scenario.truth.K(), scenario.truth.bias_nt());
    let ok: Vec<_> = trials
        .iter()
        .filter(|t| t.status == CalibrationStatus::Ok)
        .filter_map(|t| t.estimate.as_ref())
        .collect();
    (!ok.is_empty()).then(|| {
        magcal_core::budget::tolerance(&ok, |m, e| {
            grid.errors_into(truth, scenario.field.magnitude(), (&m.P(), m.bias_nt()), e);
        })
    })
}

/// How many of [`Check::LOGS`] logs of `body` at `sigma_nt` (on the streams `[stream.., t]`, `t`
/// from the scenario's check trials on: beside the trials', not theirs) `calibrate` judges
/// usable: the full fit of each log in the order flown, with its check by trials and held-out
/// fits, its heading judged over the scenario's box against its budget, as `calibrate LOG
/// --magnitude R --scenario S` judges a log `simulate` wrote.
///
/// # Errors
/// Only an invalid noise level (scenarios are validated).
fn logs_usable(scenario: &Scenario, stream: &[u64], body: &[magcal_core::Vec3], sigma_nt: f64) -> Result<usize> {
    let grid = budget_grid(scenario);
    let magnitude = scenario.field.magnitude();
    let usable: Vec<bool> = (0..Check::LOGS)
        .into_par_iter()
        .map(|k| {
            let mut rng = trial_rng(scenario.seed, stream, scenario.check_trials + k);
            let readings = scenario.truth.noisy_readings(body, sigma_nt, &mut rng)?;
            let fit = judged_as_calibrate(
                &readings,
                magnitude,
                magcal_core::log_fit::Order::Unknown,
                (&grid, scenario.heading_budget_deg),
                &magcal_core::stop::Stop::NEVER,
            );
            Ok(fit.is_ok_and(|f| f.usable))
        })
        .collect::<Result<_>>()?;
    Ok(usable.iter().filter(|u| **u).count())
}

/// The random stream of trial `t` of a check on the streams `[stream.., t]` (`stream` at most
/// [`CHECK_STREAM_DEPTH`] long).
fn trial_rng(seed: u64, stream: &[u64], t: usize) -> magcal_core::rng::MagcalRng {
    let mut ids = [0; CHECK_STREAM_DEPTH + 1];
    ids[..stream.len()].copy_from_slice(stream);
    ids[stream.len()] = t as u64;
    stream_rng(seed, stream_id(&ids[..=stream.len()]))
}

/// The full fit of a log's `readings` (in `order`) to the field's `magnitude`, judged as
/// `calibrate` judges a log: its check by trials, its held-out fits and its heading over `grid`
/// against `budget_deg` (`usable` says all of it); its fits ask `stop`.
///
/// # Errors
/// Where the readings determine no fit; [`magcal_core::CalibrationError::Stopped`] where `stop`
/// was requested.
pub fn judged_as_calibrate(
    readings: &[magcal_core::Vec3],
    magnitude: f64,
    order: magcal_core::log_fit::Order,
    (grid, budget_deg): (&magcal_core::budget::BudgetGrid, f64),
    stop: &magcal_core::stop::Stop,
) -> Result<magcal_core::log_fit::LogFit, magcal_core::CalibrationError> {
    let settings = magcal_core::log_fit::FitSettings {
        order,
        stop: stop.clone(),
        ..magcal_core::log_fit::FitSettings::default()
    };
    magcal_core::log_fit::fit_with(readings, magnitude, FitModel::Full, &settings).map(|mut f| {
        f.judge_heading(grid, budget_deg, magcal_core::log_fit::CHECK_SEED);
        f
    })
}
