//! The noisy trials of every design at every noise level and execution error, in parallel and
//! collected in trial order, and the statistics of their metrics.

use std::borrow::Cow;

use anyhow::Result;
use magcal_core::heading::HeadingProbe;
use magcal_core::monte_carlo::{self, TrialOutcome};
use magcal_core::rng::{stream_id, stream_rng};
use magcal_core::{CalibrationStatus, CramerRao, PhysicalScales, Summary, Vec3};
use rayon::prelude::*;

pub use magcal_report::rows::Metric;

use super::{BuiltDesign, Progress};
use crate::limits;
use crate::scenario::Scenario;

/// The trials of one design at one noise level.
#[derive(Debug, Clone)]
pub struct Cell {
    /// Index into [`super::RunOutput::designs`].
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

/// Runs `scenario.trials` noisy trials of every design at every noise level and execution error,
/// on the streams `[design, level, trial]`, design-major.
///
/// # Errors
/// Only an invalid noise level or execution error (scenarios are validated).
pub fn run_cells(scenario: &Scenario, designs: &[BuiltDesign], progress: &dyn Progress) -> Result<Vec<Cell>> {
    let total =
        (designs.len() * scenario.sigmas_nt.len() * scenario.attitude_sigmas_deg.len() * scenario.trials) as u64;
    let bar = progress.stage("trials", Some(total));
    let probe = HeadingProbe::new(&scenario.field, &scenario.truth);
    let mut cells = Vec::new();
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
                        let flown: Cow<[Vec3]> = if attitude_sigma == 0.0 {
                            Cow::Borrowed(&body)
                        } else {
                            let radians = attitude_sigma.to_radians();
                            Cow::Owned(scenario.field.executed_body_fields(&commanded, radians, &mut rng)?)
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
    Ok(cells)
}
