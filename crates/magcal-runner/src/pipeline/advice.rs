//! What works when no design of a scenario calibrates the full model: a reduced model on the same
//! readings, a quieter sensor, or a box the vehicle tilts further in. Each is computed by the same
//! short Monte Carlo as a design's verdict ([`Check`]), never guessed.

use anyhow::{Context, Result};
use magcal_core::design::DesignProblem;
use magcal_core::design::optimum::Optimum;
use magcal_core::rng::{stream_id, stream_rng};
use magcal_core::{Attitude, AttitudeBox};

use crate::pipeline::{BuiltDesign, Check};
use crate::scenario::Scenario;

/// Stream-id prefix of the advice's trials and designs.
const ADVICE_STREAM: u64 = 0xFFFA;

/// A model with fewer unknowns than \[P1\]'s nine, the rest held at the scenario's sensor (what
/// the user takes as nominal: a data sheet, or scale 1 and no non-orthogonality).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reduced {
    /// Non-orthogonality held at 0; scale factors and bias fitted (6 unknowns).
    Diagonal,
    /// The scale of one axis and its non-orthogonality to the other two held (its row and column
    /// of `P`; the axis the design turns least against the field, 0-based); 6 unknowns.
    AxisHeld(usize),
    /// Every scale and non-orthogonality held; the bias fitted (3 unknowns), as ArduPilot's
    /// offsets-only calibration of a large vehicle.
    OffsetsOnly,
}

impl Reduced {
    /// A stable name: `diagonal`, `axis1_held` (1-based), `offsets_only`.
    pub fn name(&self) -> String {
        match self {
            Self::Diagonal => "diagonal".into(),
            Self::AxisHeld(a) => format!("axis{}_held", a + 1),
            Self::OffsetsOnly => "offsets_only".into(),
        }
    }

    /// In words.
    pub fn words(&self) -> String {
        match self {
            Self::Diagonal => "non-orthogonality held at 0 (diagonal model)".into(),
            Self::AxisHeld(a) => format!(
                "the scale of axis {} and its non-orthogonality held at the scenario's values",
                magcal_core::identifiability::AxisNames::Body.names()[*a]
            ),
            Self::OffsetsOnly => "offsets only, scales held at the scenario's values".into(),
        }
    }

    /// The entries `P11, P12, P13, P22, P23, P33` it fits, and the nominal `P` it holds the
    /// others at.
    fn free_and_nominal(&self, truth: &magcal_core::ErrorModel) -> ([bool; 6], magcal_core::Mat3) {
        let s = truth.scale();
        let diagonal = [[1.0 / s[0], 0.0, 0.0], [0.0, 1.0 / s[1], 0.0], [0.0, 0.0, 1.0 / s[2]]];
        match self {
            Self::Diagonal => ([true, false, false, true, false, true], diagonal),
            // Row and column of each axis in (P11 P12 P13 P22 P23 P33).
            Self::AxisHeld(a) => {
                let rows: [&[usize]; 3] = [&[0, 1, 2], &[1, 3, 4], &[2, 4, 5]];
                let mut free = [true; 6];
                for &i in rows[*a] {
                    free[i] = false;
                }
                (free, truth.P())
            }
            Self::OffsetsOnly => ([false; 6], truth.P()),
        }
    }
}

/// Steps of the noise search: the scenario's noise divided by `sqrt(2)^k`, `k = 1..=NOISE_STEPS`
/// (down to 1/1024 of it).
const NOISE_STEPS: u32 = 20;

/// Extra tilt tried, degrees added to both ends of the roll and the pitch range.
const WIDENINGS_DEG: [f64; 8] = [5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0];

/// What works instead, for the design the advice starts from.
#[derive(Debug, Clone)]
pub struct Advice {
    /// Index of the design the advice starts from: the one most trials calibrated, then the most
    /// information per reading.
    pub base: usize,
    /// Passes over that design's attitudes the options are checked at: enough readings for a log
    /// of them to hold a fifth out (what `calibrate` needs for held-out evidence), 1 where the
    /// design has them already.
    pub passes: usize,
    /// Each reduced model on that design's readings, flown `passes` times.
    pub reduced: Vec<(Reduced, Check)>,
    /// The largest noise tried at which the full model works with that design, and its check.
    pub quieter: Option<Check>,
    /// The smallest widening tried of the box at which the full model works.
    pub wider: Option<Widening>,
}

/// A wider box and the design of it that works.
#[derive(Debug, Clone)]
pub struct Widening {
    /// Degrees added at both ends of the roll and the pitch range.
    pub extra_deg: f64,
    /// The widened ranges, degrees.
    pub roll_deg: [f64; 2],
    pub pitch_deg: [f64; 2],
    /// D-optimal attitudes in the wider box, as many as the base design has.
    pub attitudes: Vec<Attitude>,
    /// Readings at each of them (the base design's readings spread evenly).
    pub readings_per_attitude: usize,
    /// Its check.
    pub check: Check,
}

/// The design the advice starts from.
fn base(designs: &[BuiltDesign]) -> Option<usize> {
    (0..designs.len()).max_by(|&a, &b| {
        let (da, db) = (&designs[a], &designs[b]);
        da.check
            .outcomes
            .ok
            .cmp(&db.check.outcomes.ok)
            .then(da.ln_det_per_reading().total_cmp(&db.ln_det_per_reading()))
            .then(b.cmp(&a))
    })
}

/// Computes the advice from the scenario's designs.
///
/// # Errors
/// A design problem or a trial that cannot be built (scenarios are validated, so a bug).
pub fn advise(scenario: &Scenario, designs: &[BuiltDesign]) -> Result<Option<Advice>> {
    let Some(base) = base(designs) else {
        return Ok(None);
    };
    let d = &designs[base];
    let fewest = magcal_core::log_fit::min_held_out_readings(magcal_core::log_fit::FitModel::Full);
    let passes = fewest.div_ceil(d.m()).max(1);
    let flown: Vec<Attitude> = (0..passes).flat_map(|_| d.expanded()).collect();
    let body = scenario.field.body_fields(&flown);
    let sigma = d.check.sigma_nt;
    // The scale the design determines worst: the largest scale component of the weakest direction.
    let weak_axis = (0..3)
        .max_by(|&a, &b| {
            d.verdict.direction[3 + a]
                .abs()
                .total_cmp(&d.verdict.direction[3 + b].abs())
        })
        .unwrap_or(1);
    let calibration = scenario.calibration.clone();
    let reduced = [Reduced::Diagonal, Reduced::AxisHeld(weak_axis), Reduced::OffsetsOnly]
        .iter()
        .enumerate()
        .map(|(k, &model)| {
            let (free, nominal) = model.free_and_nominal(&scenario.truth);
            let settings = magcal_core::TwoStep {
                noise_nt: Some(sigma),
                ..calibration.clone()
            };
            let fit = move |readings: &[magcal_core::Vec3], magnitude: f64| {
                settings.calibrate_holding(readings, magnitude, nominal, free)
            };
            Check::run_on(scenario, &[ADVICE_STREAM, 0, k as u64], &body, sigma, Some(&fit)).map(|c| (model, c))
        })
        .collect::<Result<Vec<_>>>()?;
    let mut quieter = None;
    for k in 1..=NOISE_STEPS {
        let level = sigma / 2f64.sqrt().powi(k as i32);
        let check = Check::run_on(scenario, &[ADVICE_STREAM, 1, u64::from(k)], &body, level, None)?;
        if check.works() {
            quieter = Some(check);
            break;
        }
    }

    let [roll, yaw, pitch] = scenario.bounds.ranges();
    let degrees = |r: &magcal_core::AngleRange| [r.min().to_degrees(), r.max().to_degrees()];
    let per = (d.m() * passes).div_ceil(d.attitudes.len().max(9));
    let k = d.attitudes.len().max(9);
    let mut wider = None;
    for (j, &extra) in WIDENINGS_DEG.iter().enumerate() {
        let [r0, r1] = degrees(&roll);
        let [p0, p1] = degrees(&pitch);
        let roll_deg = [(r0 - extra).max(-180.0), (r1 + extra).min(180.0)];
        let pitch_deg = [(p0 - extra).max(-90.0), (p1 + extra).min(90.0)];
        let bounds = AttitudeBox::from_degrees(roll_deg, degrees(&yaw), pitch_deg)?;
        let problem = DesignProblem::new(scenario.field, scenario.truth, bounds, k)?;
        let mut rng = stream_rng(scenario.seed, stream_id(&[ADVICE_STREAM, 2, j as u64]));
        let attitudes = Optimum::default()
            .optimise(&problem, &mut rng)
            .with_context(|| format!("the optimum of the box widened by {extra} deg"))?
            .design;
        let every: Vec<Attitude> = attitudes.iter().flat_map(|a| std::iter::repeat_n(*a, per)).collect();
        let body = scenario.field.body_fields(&every);
        let check = Check::run_on(scenario, &[ADVICE_STREAM, 3, j as u64], &body, sigma, None)?;
        if check.works() {
            wider = Some(Widening {
                extra_deg: extra,
                roll_deg,
                pitch_deg,
                attitudes,
                readings_per_attitude: per,
                check,
            });
            break;
        }
    }
    Ok(Some(Advice {
        base,
        passes,
        reduced,
        quieter,
        wider,
    }))
}
