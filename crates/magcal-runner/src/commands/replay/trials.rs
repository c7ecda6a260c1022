//! The trials of a replay: for each design, draws of held readings that realise its attitudes,
//! every model calibrated from the same draw (paired), each calibration scored on the log's other
//! readings against the reference attitudes.

use magcal_core::reference::{
    AlignSettings, Alignment, ReferenceError, Rotations, align, align_checked, align_fixed, align_fixed_checked,
};
use magcal_core::replay::{CoverageMap, Realised, WindowIndex, body_of_paper, held, orient, realise};
use magcal_core::rng::{stream_id, stream_rng};
use magcal_core::small::{Mat3, mat_vec, norm, scale};
use magcal_core::{AttitudeBox, ReferenceField};
use magcal_core::{CalibrationStatus, RelativeErrors, TwoStep, Vec3};
use rand::RngExt;
use rayon::prelude::*;

use super::models::{Fitted, Model, calibrate};
use super::prepare::Prepared;

/// Stream-id prefix of a replay's draws: `[REPLAY_STREAM, design, trial]`.
const REPLAY_STREAM: u64 = 0xFFFA;

/// Heading and direction errors of a calibration against the reference, degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Figures {
    pub heading_rms: f64,
    pub heading_p95: f64,
    pub heading_max: f64,
    pub direction_rms: f64,
}

/// What one model made of one draw.
#[derive(Debug, Clone, PartialEq)]
pub struct Scored {
    pub status: CalibrationStatus,
    /// Against the reference attitudes; `None` without an estimate, or where the alignment
    /// failed.
    pub figures: Option<Figures>,
    /// Against the reference with the calibration's own alignment held (only `F` fitted), for a
    /// model that estimates the alignment.
    pub held: Option<Figures>,
    /// Against the truth, where known and there is an estimate.
    pub eta: Option<RelativeErrors>,
    /// RMS of `|calibrated| - R` over the readings calibrated, nT.
    pub rms_residual: Option<f64>,
}

impl Scored {
    /// A trial whose attitudes the log could not realise: failed, with no estimate.
    fn unrealised() -> Self {
        Self {
            status: CalibrationStatus::RankDeficient,
            figures: None,
            held: None,
            eta: None,
            rms_residual: None,
        }
    }
}

/// One trial: the largest angle between a design attitude's direction and the window drawn for
/// it, and each model's outcome in the order asked.
#[derive(Debug, Clone, PartialEq)]
pub struct Trial {
    pub drawn_max_deg: f64,
    pub scored: Vec<Scored>,
}

/// What realises a design's attitudes in a trial.
pub enum Points<'a> {
    /// The design's own attitudes, realised once.
    Fixed(Vec<Realised>),
    /// `m` attitudes drawn uniformly in the box afresh for each trial (a random design: one
    /// draw would say little about random attitudes), each drawn again until the log realises
    /// it, at most [`MAX_REDRAWS`] times.
    Random { m: usize, redraw: &'a Redraw<'a> },
}

/// Draws of attitudes an unrealisable random attitude is replaced by, at most.
pub const MAX_REDRAWS: usize = 1000;

/// What a random design drawn in a trial needs to be realised.
pub struct Redraw<'a> {
    pub bounds: &'a AttitudeBox,
    pub field: &'a ReferenceField,
    /// The log's coverage, to turn the draw to (`--orient fit`).
    pub map: Option<&'a CoverageMap>,
    /// The log's windows by direction.
    pub index: &'a WindowIndex,
    pub within_deg: f64,
    pub candidates: usize,
}

impl Redraw<'_> {
    /// `m` random attitudes realised on the log, or `None` where one could not be in
    /// [`MAX_REDRAWS`] draws.
    fn draw<R: rand::Rng + ?Sized>(&self, m: usize, rng: &mut R) -> Option<Vec<Realised>> {
        let target = |rng: &mut R| {
            let a = magcal_core::design::sources::random_attitude(self.bounds, rng);
            let b = self.field.body_fields(&[a])[0];
            body_of_paper(scale(1.0 / norm(b), b))
        };
        let targets: Vec<Vec3> = (0..m).map(|_| target(rng)).collect();
        let turn: Mat3 = match self.map {
            Some(map) => orient(&targets, map, 2000, rng).0,
            None => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        };
        let mut points = Vec::with_capacity(m);
        for t in targets {
            let mut t = t;
            let mut tries = 0;
            loop {
                let r = realise(mat_vec(&turn, t), self.index, self.within_deg, self.candidates);
                if !r.is_empty() {
                    points.push(r);
                    break;
                }
                tries += 1;
                if tries == MAX_REDRAWS {
                    return None;
                }
                t = target(rng);
            }
        }
        Some(points)
    }
}

/// What the trials share.
pub struct Plan<'a> {
    pub log: &'a Prepared,
    pub models: &'a [Model],
    pub hold: usize,
    /// The noise of a held reading per component that the verdicts rest on, nT.
    pub held_noise: f64,
    pub two_step: &'a TwoStep,
    /// The readings every calibration is scored on (indices into the log), before the trial's
    /// own windows are taken out.
    pub scoring: &'a [usize],
    /// The log's attitudes checked once to be rotations (`None` where one is not: then every
    /// alignment checks its own and refuses).
    pub rotations: Option<&'a Rotations>,
    pub seed: u64,
}

/// The attitudes of the readings a calibration is scored on.
pub enum ScoringAttitudes {
    /// Checked to be rotations.
    Checked(Rotations),
    /// Not checked (some attitude of the log is not a rotation).
    Unchecked(Vec<Mat3>),
}

impl ScoringAttitudes {
    /// [`align`] of `calibrated` with these attitudes.
    fn align(&self, calibrated: &[Vec3]) -> Result<Alignment, ReferenceError> {
        let settings = AlignSettings::default();
        match self {
            Self::Checked(a) => align_checked(calibrated, a, &settings),
            Self::Unchecked(a) => align(calibrated, a, &settings),
        }
    }

    /// [`align_fixed`] of `calibrated` with these attitudes, the rotation held at `q`.
    fn align_fixed(&self, calibrated: &[Vec3], q: &Mat3) -> Result<Alignment, ReferenceError> {
        match self {
            Self::Checked(a) => align_fixed_checked(calibrated, a, q),
            Self::Unchecked(a) => align_fixed(calibrated, a, q),
        }
    }
}

impl Plan<'_> {
    /// `trials` draws of design `d`, whose attitudes `points` realise, in trial order.
    pub fn run(&self, d: usize, points: &Points, trials: usize, bar: &indicatif::ProgressBar) -> Vec<Trial> {
        (0..trials)
            .into_par_iter()
            .map(|t| {
                let trial = self.trial(d, t, points);
                bar.inc(1);
                trial
            })
            .collect()
    }

    fn trial(&self, d: usize, t: usize, points: &Points) -> Trial {
        let mut rng = stream_rng(self.seed, stream_id(&[REPLAY_STREAM, d as u64, t as u64]));
        let drawn;
        let points: &[Realised] = match points {
            Points::Fixed(p) => p,
            Points::Random { m, redraw } => match redraw.draw(*m, &mut rng) {
                Some(p) => {
                    drawn = p;
                    &drawn
                }
                None => {
                    return Trial {
                        drawn_max_deg: f64::NAN,
                        scored: self.models.iter().map(|_| Scored::unrealised()).collect(),
                    };
                }
            },
        };
        let mut starts = Vec::with_capacity(points.len());
        let mut drawn_max_deg = 0.0f64;
        for p in points {
            let k = rng.random_range(0..p.starts.len());
            starts.push(p.starts[k]);
            drawn_max_deg = drawn_max_deg.max(p.angles_deg[k]);
        }
        let readings: Vec<Vec3> = starts.iter().map(|&s| held(&self.log.readings, s, self.hold)).collect();
        // A held reading's attitude: that of its window's middle reading.
        let attitudes: Vec<Mat3> = starts
            .iter()
            .map(|&s| self.log.attitudes[s + (self.hold - 1) / 2])
            .collect();
        let scoring: Vec<usize> = self
            .scoring
            .iter()
            .copied()
            .filter(|&i| !starts.iter().any(|&s| (s..s + self.hold).contains(&i)))
            .collect();
        let scoring_attitudes = self.scoring_attitudes(&scoring);
        let scored = self
            .models
            .iter()
            .map(|&m| {
                self.scored(
                    calibrate(
                        m,
                        &readings,
                        &attitudes,
                        self.log.magnitude,
                        self.held_noise,
                        self.two_step,
                    ),
                    &scoring,
                    &scoring_attitudes,
                )
            })
            .collect();
        Trial { drawn_max_deg, scored }
    }

    /// The attitudes of the readings `scoring`, checked where the log's are.
    fn scoring_attitudes(&self, scoring: &[usize]) -> ScoringAttitudes {
        match self.rotations {
            Some(r) => ScoringAttitudes::Checked(r.select(scoring)),
            None => ScoringAttitudes::Unchecked(scoring.iter().map(|&i| self.log.attitudes[i]).collect()),
        }
    }

    /// A calibration scored on the readings `scoring`, whose attitudes are `attitudes`.
    pub fn scored(
        &self,
        fitted: Result<Fitted, CalibrationStatus>,
        scoring: &[usize],
        attitudes: &ScoringAttitudes,
    ) -> Scored {
        let fitted = match fitted {
            Ok(f) => f,
            Err(status) => {
                return Scored {
                    status,
                    figures: None,
                    held: None,
                    eta: None,
                    rms_residual: None,
                };
            }
        };
        let calibrated: Vec<Vec3> = scoring.iter().map(|&i| fitted.apply(self.log.readings[i])).collect();
        let figures_of = |a: Alignment| Figures {
            heading_rms: a.summary.heading_rms_deg,
            heading_p95: a.summary.heading_p95_deg,
            heading_max: a.summary.heading_max_deg,
            direction_rms: a.summary.direction_rms_deg,
        };
        let figures = attitudes.align(&calibrated).ok().map(figures_of);
        let held = fitted
            .alignment
            .and_then(|q| attitudes.align_fixed(&calibrated, &q).ok())
            .map(figures_of);
        Scored {
            status: fitted.status,
            figures,
            held,
            eta: self
                .log
                .truth
                .as_ref()
                .map(|t| RelativeErrors::between(&fitted.estimate, t)),
            rms_residual: Some(fitted.rms_residual),
        }
    }

    /// Every model calibrated from the whole log (each reading on its own), scored on the
    /// scoring readings: what a replayed design is measured against.
    pub fn whole_log(&self) -> Vec<Scored> {
        let attitudes = self.scoring_attitudes(self.scoring);
        self.models
            .iter()
            .map(|&m| {
                self.scored(
                    calibrate(
                        m,
                        &self.log.readings,
                        &self.log.attitudes,
                        self.log.magnitude,
                        self.log.noise,
                        self.two_step,
                    ),
                    self.scoring,
                    &attitudes,
                )
            })
            .collect()
    }
}
