//! The verdict of a log as the verdict of a design (docs/conventions.md "The verdict of a log"):
//! noisy trials at the log's own readings, calibrated by the same fit.
//!
//! A design **works** when at least 95 % of noisy trials of its readings calibrate (`ok`).
//! A log is judged the same way: the log's field directions under its fitted calibration
//! (`b_i = P (s_i - O) / |P (s_i - O)|`), read by the fitted sensor (`K b_i + O`, on the fitted
//! ellipsoid), with the log's noise added, are fitted by the same model and settings; a trial is
//! `ok` when that fit settles and its standard errors are within the physical scales. The log's
//! calibration is usable only where at least [`USABLE_SHARE`] of [`CHECK_TRIALS`] trials are.
//!
//! The noise is the log's: white Gaussian at the given noise where it explains the scatter, else
//! at the scatter of the residuals; for readings in time order, the log's own residuals (each
//! reading's distance from the ellipsoid) resampled in circular blocks of the batch length of its
//! standard errors ([`super::serial`]), along the ellipsoid's normal at each reading: the trials
//! then carry the residuals' correlation in time, which white noise would not. To first order only
//! the normal component of the noise moves a fit.

use rand::RngExt;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use super::{FitModel, FitSettings, LogFit, Noise, Order, fit_unit, significant};
use crate::calibration::CalibrationStatus;
use crate::rng::{stream_id, stream_rng};
use crate::small::{Vec3, add, mat_t_vec, mat_vec, norm, scale, upper_triangular_inverse};

/// Trials of a log's check: as many as a design's (`[verdict] trials`), so that the share has a
/// standard error of 1.5 points at 95 %.
pub const CHECK_TRIALS: usize = 200;

/// The seed of the check's streams, trial `t` on stream `[0xFFF8, t]`.
pub const CHECK_SEED: u64 = 2014;

/// The share of `ok` trials that makes a calibration usable, as a design's verdict asks.
pub const USABLE_SHARE: f64 = 0.95;

/// The noise the trials of a check draw.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum TrialNoise {
    /// White Gaussian noise of `sigma` per component (the log's units).
    White {
        /// The noise per component.
        sigma: f64,
        /// Whether it is the given noise (else the residuals' scatter).
        given: bool,
    },
    /// The log's residuals resampled in circular blocks of `batch` consecutive readings.
    Resampled {
        /// Readings per block.
        batch: usize,
        /// The rms of the residuals resampled (the log's units).
        rms: f64,
    },
}

impl TrialNoise {
    /// In words: "white, 30.00 per component (given)", "the log's residuals (rms 0.1234) resampled
    /// in blocks of 563 readings".
    pub fn words(&self) -> String {
        match *self {
            Self::White { sigma, given } => format!(
                "white, {} per component ({})",
                significant(sigma, 4),
                if given { "given" } else { "the residuals' scatter" }
            ),
            Self::Resampled { batch, rms } => format!(
                "the log's residuals (rms {}) resampled in blocks of {batch} consecutive readings",
                significant(rms, 4)
            ),
        }
    }

    fn scaled(self, by: f64) -> Self {
        match self {
            Self::White { sigma, given } => Self::White {
                sigma: sigma * by,
                given,
            },
            Self::Resampled { batch, rms } => Self::Resampled { batch, rms: rms * by },
        }
    }
}

/// The outcome of a log's check by trials (see the module documentation). Every trial is in
/// exactly one of `ok`, `not_converged`, `not_identifiable`, `failed`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct TrialCheck {
    /// Trials asked for.
    pub planned: usize,
    /// Trials run: all that were asked for, or fewer once more had failed than a passing check
    /// allows.
    pub trials: usize,
    /// Trials whose fit settled with every standard error within the physical scales.
    pub ok: usize,
    /// Trials whose fit did not settle.
    pub not_converged: usize,
    /// Trials whose fit settled but did not determine the calibration.
    pub not_identifiable: usize,
    /// Trials without a fit.
    pub failed: usize,
    /// The noise the trials drew.
    pub noise: TrialNoise,
    /// Over the `ok` trials, the rms of each estimate's error against the sensor they were drawn
    /// from: `psi` (degrees), `S`, `O` (the log's units); `None` with fewer than 2 `ok` trials.
    /// For trials of every `every`-th reading, scaled to the whole log by the ratio of the log's
    /// standard errors to those of the readings drawn.
    pub rms_error: Option<[Vec3; 3]>,
    /// The trials drew every `every`-th reading of the log (1: all of it).
    pub every: usize,
    /// The readings each trial drew.
    pub readings: usize,
    /// The readings of the log.
    pub of: usize,
}

impl TrialCheck {
    /// At least [`USABLE_SHARE`] of the trials `ok`.
    pub fn passed(&self) -> bool {
        self.planned > 0 && self.ok >= needed(self.planned)
    }

    /// In words: "197 of 200 trials at this log's noise calibrate (noise white, ...); 2 not
    /// identifiable, 1 failed".
    pub fn words(&self) -> String {
        let mut w = format!(
            "{} of {} trials at this log's noise calibrate (at least {} % are needed; noise {})",
            self.ok,
            self.trials,
            100.0 * USABLE_SHARE,
            self.noise.words()
        );
        if self.every > 1 {
            w.push_str(&format!(
                "; on 1 reading in {} ({} of {}, evenly through the log: fewer readings of the same attitudes and noise determine less, so the log passes where they do; their errors scaled to all {} by the standard errors)",
                self.every, self.readings, self.of, self.of
            ));
        }
        if self.trials < self.planned {
            w.push_str(&format!(
                "; stopped after {} of {} trials: {} had failed, more than the {} a pass allows",
                self.trials,
                self.planned,
                self.trials - self.ok,
                self.planned - needed(self.planned)
            ));
        }
        for (n, what) in [
            (self.not_converged, "do not settle"),
            (self.not_identifiable, "not identifiable"),
            (self.failed, "no fit"),
        ] {
            if n > 0 {
                w.push_str(&format!("; {n} {what}"));
            }
        }
        w
    }

    pub(super) fn scaled(self, by: f64) -> Self {
        Self {
            noise: self.noise.scaled(by),
            rms_error: self
                .rms_error
                .map(|[p, s, o]| [p, s.map(|v| v * by), o.map(|v| v * by)]),
            ..self
        }
    }

    /// The scale factors' errors for a fit to another magnitude, `f` times the old one.
    pub(super) fn at_magnitude(self, f: f64) -> Self {
        Self {
            rms_error: self.rms_error.map(|[p, s, o]| [p, s.map(|v| v / f), o]),
            ..self
        }
    }
}

/// The check of `fit`, the fit of the readings `u` under `settings` (both in the fit's frame);
/// `None` where the noise is unknown or the fit has no sensor to simulate (a singular `P`).
pub(super) fn run(u: &[Vec3], fit: &LogFit, settings: &FitSettings) -> Option<(TrialCheck, Vec<[Vec3; 3]>)> {
    let sigma = fit.noise.value().filter(|s| s.is_finite() && *s > 0.0)?;
    let k = upper_triangular_inverse(&fit.p)?;
    // Each reading's field direction under the fit, the reading of it on the fitted ellipsoid,
    // the ellipsoid's unit normal there, and the reading's distance from it.
    let mut clean = Vec::with_capacity(u.len());
    let mut normals = Vec::with_capacity(u.len());
    let mut distances = Vec::with_capacity(u.len());
    for &s in u {
        let b = mat_vec(&fit.p, crate::small::sub(s, fit.bias));
        let n = norm(b);
        if !(n > 0.0 && n.is_finite()) {
            return None;
        }
        let w = scale(1.0 / n, b);
        let g = mat_t_vec(&fit.p, w);
        let ng = norm(g);
        clean.push(add(mat_vec(&k, scale(fit.magnitude, w)), fit.bias));
        normals.push(scale(1.0 / ng, g));
        distances.push((n - fit.magnitude) / ng);
    }
    let given = matches!(fit.noise, Noise::Given(_));
    let noise = match fit.serial {
        Some(s) if !given => {
            let mean = distances.iter().sum::<f64>() / distances.len() as f64;
            distances.iter_mut().for_each(|d| *d -= mean);
            let rms = (distances.iter().map(|d| d * d).sum::<f64>() / distances.len() as f64).sqrt();
            TrialNoise::Resampled { batch: s.batch, rms }
        }
        _ => TrialNoise::White { sigma, given },
    };
    let trial_settings = FitSettings {
        noise: settings.noise.filter(|_| given),
        truncation: None,
        held_out: false,
        order: match fit.serial {
            Some(s) => Order::Batch(s.batch),
            None => Order::Unknown,
        },
        trials: 0,
        // The trials judge the precision at the log's noise by their standard errors; the
        // log's own fit measured how far its cost bends (six more fits, which would more than
        // double each trial's time).
        profile: false,
        ..settings.clone()
    };
    // In rounds of ROUND trials, in trial order: once more trials have failed than a passing
    // check allows, the rest cannot change the verdict and are not run (the words say how many
    // ran). Each trial draws on its own stream, so the counts do not depend on the threads.
    let allowed = settings.trials - needed(settings.trials);
    let mut outcomes: Vec<Outcome> = Vec::with_capacity(settings.trials);
    // A stop requested ends the check at the next round (each trial's fit also asks it): the
    // caller throws away what a stopped check counted.
    while outcomes.len() < settings.trials && !settings.stop.requested() {
        let from = outcomes.len();
        let to = (from + ROUND).min(settings.trials);
        outcomes.par_extend((from..to).into_par_iter().map(|t| {
            let mut rng = stream_rng(settings.seed, stream_id(&[0xFFF8, t as u64]));
            let readings = draw(&clean, &normals, &distances, noise, &mut rng);
            outcome(&readings, fit.model, &trial_settings)
        }));
        if outcomes.iter().filter(|o| !matches!(o, Outcome::Ok(_))).count() > allowed {
            break;
        }
    }
    let count = |o: Outcome| outcomes.iter().filter(|x| x.same(o)).count();
    let truth = [fit.errors.psi_deg(), fit.errors.scale(), fit.bias];
    let errors: Vec<[Vec3; 3]> = outcomes
        .iter()
        .filter_map(|o| match o {
            Outcome::Ok(e) => Some(std::array::from_fn(|g| std::array::from_fn(|i| e[g][i] - truth[g][i]))),
            _ => None,
        })
        .collect();
    let n = errors.len() as f64;
    let rms_error = (errors.len() >= 2).then(|| {
        std::array::from_fn(|g| {
            std::array::from_fn(|i| (errors.iter().map(|e| e[g][i] * e[g][i]).sum::<f64>() / n).sqrt())
        })
    });
    let check = TrialCheck {
        planned: settings.trials,
        trials: outcomes.len(),
        ok: count(Outcome::Ok([[0.0; 3]; 3])),
        not_converged: count(Outcome::NotConverged),
        not_identifiable: count(Outcome::NotIdentifiable),
        failed: count(Outcome::Failed),
        noise,
        rms_error,
        every: 1,
        readings: u.len(),
        of: u.len(),
    };
    Some((check, errors))
}

/// Trials run at once between two looks at the count.
const ROUND: usize = 20;

/// The `ok` trials of `planned` that a passing check needs: [`USABLE_SHARE`] of them, rounded up.
fn needed(planned: usize) -> usize {
    (USABLE_SHARE * planned as f64 - 1e-9).ceil() as usize
}

/// How one trial ended; an `ok` one with its estimate (`psi`, `S`, `O`).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Outcome {
    Ok([Vec3; 3]),
    NotConverged,
    NotIdentifiable,
    Failed,
}

impl Outcome {
    /// The same kind of outcome, whatever the estimate.
    fn same(&self, other: Outcome) -> bool {
        std::mem::discriminant(self) == std::mem::discriminant(&other)
    }
}

/// The fit of one trial's readings, classified.
fn outcome(readings: &[Vec3], model: FitModel, settings: &FitSettings) -> Outcome {
    match fit_unit(readings, model, settings) {
        Err(_) => Outcome::Failed,
        Ok(f) if f.status == CalibrationStatus::NotConverged => Outcome::NotConverged,
        Ok(f) if f.status == CalibrationStatus::Ok && f.identifiable => {
            Outcome::Ok([f.errors.psi_deg(), f.errors.scale(), f.bias])
        }
        Ok(_) => Outcome::NotIdentifiable,
    }
}

/// One trial's readings: `clean` plus white noise, or plus the centred `distances` resampled in
/// circular blocks along `normals`.
fn draw(
    clean: &[Vec3],
    normals: &[Vec3],
    distances: &[f64],
    noise: TrialNoise,
    rng: &mut crate::rng::MagcalRng,
) -> Vec<Vec3> {
    match noise {
        TrialNoise::White { sigma, .. } => clean
            .iter()
            .map(|&c| {
                let n: Vec3 = std::array::from_fn(|_| StandardNormal.sample(rng));
                add(c, scale(sigma, n))
            })
            .collect(),
        TrialNoise::Resampled { batch, .. } => {
            let m = clean.len();
            let mut out = Vec::with_capacity(m);
            while out.len() < m {
                let start = rng.random_range(0..m);
                for j in 0..batch.min(m - out.len()) {
                    let i = out.len();
                    out.push(add(clean[i], scale(distances[(start + j) % m], normals[i])));
                }
            }
            out
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_words_count_every_trial() {
        let c = TrialCheck {
            planned: 200,
            trials: 200,
            ok: 197,
            not_converged: 0,
            not_identifiable: 2,
            failed: 1,
            noise: TrialNoise::White {
                sigma: 30.0,
                given: true,
            },
            rms_error: None,
            every: 1,
            readings: 12000,
            of: 12000,
        };
        assert!(c.passed());
        assert_eq!(
            c.words(),
            "197 of 200 trials at this log's noise calibrate (at least 95 % are needed; noise white, 30.00 per component (given)); 2 not identifiable; 1 no fit"
        );
        assert!(!TrialCheck { ok: 189, ..c }.passed());
        assert!(TrialCheck { ok: 190, ..c }.passed());
        assert_eq!(needed(200), 190);
        assert_eq!(needed(20), 19);
        assert_eq!(needed(21), 20);
        let stopped = TrialCheck {
            trials: 20,
            ok: 9,
            not_identifiable: 11,
            failed: 0,
            ..c
        };
        assert!(!stopped.passed());
        assert!(
            stopped.words().contains(
                "; stopped after 20 of 200 trials: 11 had failed, more than the 10 a pass allows; 11 not identifiable"
            ),
            "{}",
            stopped.words()
        );
    }
}
