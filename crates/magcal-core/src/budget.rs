//! The heading budget (docs/conventions.md "Heading budget"): the heading error a calibration
//! leaves, in degrees, over the attitudes a vehicle flies, and whether it is within what the user
//! needs.
//!
//! A compass with a known tilt (roll and pitch from the accelerometer) takes its heading from the
//! calibrated body field turned level: with `C_n^b = L Ry(y)`, `L = Rx(r) Rz(p)` (\[P1\] eq. (2)),
//! `v = L^T b = Ry(y) B^n` has the horizontal components `H (cos y, sin y)` in its x and z slots.
//! A calibration `b_hat = P_hat (s - O_hat)` of the readings `s = K b + O` (\[P1\] eq. (5)-(6))
//! turns `v` into `v_hat = L^T b_hat`, and the heading error at that attitude is the angle from
//! `(v_x, v_z)` to `(v_hat_x, v_hat_z)`, wrapped to (-180, 180] (at roll = pitch = 0 this is
//! [`crate::heading`]'s definition). The tilt is taken as known: the error is the calibration's
//! alone, not the accelerometer's nor the readings' noise (a filter averages those).
//!
//! The attitudes ([`BudgetGrid`]): every heading (72, 5 degrees apart) at each roll and pitch of
//! a 5 x 5 grid spanning the vehicle's box (ends included; level when no box is given), in a field
//! of the site's inclination. A calibration of many possible ones (the trials of a check, draws
//! from its standard errors) is scored by a 95/95 tolerance ([`tolerance`]): the 95th percentile
//! over the calibrations of each one's 95th percentile of `|e|` over the attitudes ([`quantile`]):
//! "under 95 % of the calibrations the evidence allows, 95 % of the headings the vehicle takes
//! are within this". Pooling the attitudes and calibrations into one percentile says less: it is
//! about a typical calibration's, and a third of the logs of a plan whose pooled figure met the
//! budget left more than it (`scripts/loop.py`, the vessel's `plan300`: 12 of 41 usable logs).
//! The budget is met where the tolerance is at most the budget ([`DEFAULT_BUDGET_DEG`]).

use crate::attitude::Attitude;
use crate::sensor::ErrorModel;
use crate::small::{Mat3, Vec3, dot, mat_mul, mat_t_vec, mat_vec, sub};

/// The heading error a calibration may leave unless the user says otherwise, degrees (95th
/// percentile over the vehicle's attitudes and the calibration's uncertainty). IMO MSC.116(73)
/// asks a ship's transmitting heading device for a static error below 1.0 degree and a dynamic
/// one below 1.5, everything included; 2 degrees is the calibration's share for a small vehicle
/// (a 100 m leg flown 3.5 m off its line), and ship-grade work asks for 1
/// (`--heading-budget 1`).
pub const DEFAULT_BUDGET_DEG: f64 = 2.0;

/// The smallest budget taken, degrees (36 arc seconds): below it the figure says more of the
/// grid's arithmetic than of any compass, and a ratio to it runs to hundreds of digits.
pub const MIN_BUDGET_DEG: f64 = 0.01;

/// Headings of the grid, 5 degrees apart.
pub const HEADINGS: usize = 72;

/// Rolls and pitches of the grid across a box, ends included.
pub const TILT_STEPS: usize = 5;

/// The quantile of `|e|` over the attitudes, and of that over the calibrations, a budget is
/// judged by.
pub const BUDGET_QUANTILE: f64 = 0.95;

/// The 95/95 tolerance of calibrations scored by `errors` (each appends its `|e|` over the
/// grid's attitudes to the buffer it is given, and returns nothing): the [`BUDGET_QUANTILE`]
/// over the calibrations of each one's [`BUDGET_QUANTILE`] over the attitudes; `NaN` for none.
pub fn tolerance<T>(calibrations: &[T], mut errors: impl FnMut(&T, &mut Vec<f64>)) -> f64 {
    let mut e = Vec::new();
    let mut each: Vec<f64> = calibrations
        .iter()
        .map(|c| {
            e.clear();
            errors(c, &mut e);
            quantile(&mut e, BUDGET_QUANTILE)
        })
        .collect();
    quantile(&mut each, BUDGET_QUANTILE)
}

/// The roll and pitch a vehicle flies, degrees (its box; `[0, 0]` each for level).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Tilts {
    /// Roll range, degrees.
    pub roll_deg: [f64; 2],
    /// Pitch range, degrees.
    pub pitch_deg: [f64; 2],
}

impl Tilts {
    /// Level only.
    pub const LEVEL: Self = Self {
        roll_deg: [0.0, 0.0],
        pitch_deg: [0.0, 0.0],
    };

    /// The tilts of a box's roll and pitch ranges, radians, in degrees to the nanodegree (a box
    /// given in degrees and kept in radians comes back as 14.999999999999998).
    pub fn of_box(roll: [f64; 2], pitch: [f64; 2]) -> Self {
        let d = |r: f64| (r.to_degrees() * 1e9).round() / 1e9;
        Self {
            roll_deg: roll.map(d),
            pitch_deg: pitch.map(d),
        }
    }

    /// Whether only level is flown.
    pub fn is_level(&self) -> bool {
        self.roll_deg.iter().chain(&self.pitch_deg).all(|v| *v == 0.0)
    }

    /// "level" or "roll -5 to 5, pitch -20 to 20 deg".
    pub fn words(&self) -> String {
        if self.is_level() {
            "level".to_string()
        } else {
            // Degrees to the hundredth: a box converted from radians and back keeps rounding.
            let d = |v: f64| format!("{}", (v * 100.0).round() / 100.0);
            format!(
                "roll {} to {}, pitch {} to {} deg",
                d(self.roll_deg[0]),
                d(self.roll_deg[1]),
                d(self.pitch_deg[0]),
                d(self.pitch_deg[1])
            )
        }
    }
}

/// The attitudes a budget is judged over, in a calibration's frame (see the module
/// documentation).
#[derive(Debug, Clone)]
pub struct BudgetGrid {
    /// The unit body field at each attitude, in the readings' frame.
    field: Vec<Vec3>,
    /// The level frame's x and z axes at each attitude, in the readings' frame.
    level_x: Vec<Vec3>,
    level_z: Vec<Vec3>,
    /// `(v_x, v_z)` of the true unit field turned level.
    level: Vec<[f64; 2]>,
    inclination_deg: f64,
    tilts: Tilts,
}

impl BudgetGrid {
    /// The grid of `tilts` at every heading in a field of `inclination_deg` (degrees below the
    /// horizontal, positive north of the magnetic equator), with `frame` turning \[P1\]'s body
    /// axes (nose, up, right) into the readings' axes (the identity for readings in those axes).
    ///
    /// # Panics
    /// An inclination whose field has no horizontal part (|inclination| >= 90 degrees, or not
    /// finite): no heading exists there (a caller bug; the field's source is checked before).
    pub fn new(inclination_deg: f64, tilts: Tilts, frame: &Mat3) -> Self {
        assert!(
            inclination_deg.is_finite() && inclination_deg.abs() < 90.0,
            "a heading needs a field with a horizontal part"
        );
        let i = inclination_deg.to_radians();
        // B^n in (N, U, E) with no declination: the heading is measured from magnetic north.
        let field_n: Vec3 = [i.cos(), -i.sin(), 0.0];
        let steps = |r: [f64; 2]| -> Vec<f64> {
            // A range of one value (level) is that value alone, to the bit.
            if r[0].to_bits() == r[1].to_bits() {
                vec![r[0]]
            } else {
                (0..TILT_STEPS)
                    .map(|k| r[0] + (r[1] - r[0]) * k as f64 / (TILT_STEPS - 1) as f64)
                    .collect()
            }
        };
        let mut grid = Self {
            field: Vec::new(),
            level_x: Vec::new(),
            level_z: Vec::new(),
            level: Vec::new(),
            inclination_deg,
            tilts,
        };
        for roll in steps(tilts.roll_deg) {
            for pitch in steps(tilts.pitch_deg) {
                // L = Rx(r) Rz(p): the tilt alone, [P1] eq. (2) at yaw 0.
                let l = Attitude::from_degrees(roll, 0.0, pitch).dcm();
                let column = |j: usize| mat_vec(frame, [l[0][j], l[1][j], l[2][j]]);
                let (x, z) = (column(0), column(2));
                for k in 0..HEADINGS {
                    let yaw = Attitude::from_degrees(roll, 360.0 * k as f64 / HEADINGS as f64 - 180.0, pitch);
                    let b = mat_vec(frame, mat_vec(&yaw.dcm(), field_n));
                    grid.level.push([dot(x, b), dot(z, b)]);
                    grid.field.push(b);
                    grid.level_x.push(x);
                    grid.level_z.push(z);
                }
            }
        }
        grid
    }

    /// Attitudes in the grid.
    pub fn len(&self) -> usize {
        self.field.len()
    }

    /// Whether the grid is empty (never: at least the 72 level headings).
    pub fn is_empty(&self) -> bool {
        self.field.is_empty()
    }

    /// The field's inclination, degrees.
    pub fn inclination_deg(&self) -> f64 {
        self.inclination_deg
    }

    /// The tilts flown.
    pub fn tilts(&self) -> Tilts {
        self.tilts
    }

    /// Appends to `out` the `|e|` (degrees) at every attitude of the calibration `b = p (s -
    /// bias)` of the readings `s = k b + o` that a sensor `(k, o)` makes in a field of magnitude
    /// `magnitude` (all in the readings' units).
    pub fn errors_into(&self, sensor: (&Mat3, Vec3), magnitude: f64, calibration: (&Mat3, Vec3), out: &mut Vec<f64>) {
        let (k, o) = sensor;
        let (p, bias) = calibration;
        // b_hat = P K b + P (O - O_hat), with b = R u.
        let m = mat_mul(p, k).map(|row| row.map(|v| v * magnitude));
        let c = mat_vec(p, sub(o, bias));
        out.extend((0..self.field.len()).map(|j| {
            let b = mat_vec(&m, self.field[j]);
            let b = [b[0] + c[0], b[1] + c[1], b[2] + c[2]];
            let (vx, vz) = (dot(self.level_x[j], b), dot(self.level_z[j], b));
            let [tx, tz] = self.level[j];
            (tx * vz - tz * vx).atan2(tx * vx + tz * vz).abs().to_degrees()
        }));
    }
}

/// The `q` quantile of `values` by linear interpolation between order statistics at `(n - 1) q`
/// (numpy's default, as "Heading against a reference attitude" takes it); `NaN` for none. The
/// values are reordered.
pub fn quantile(values: &mut [f64], q: f64) -> f64 {
    let n = values.len();
    if n == 0 {
        return f64::NAN;
    }
    let at = (n - 1) as f64 * q.clamp(0.0, 1.0);
    let lo = at.floor() as usize;
    let (_, below, above) = values.select_nth_unstable_by(lo, f64::total_cmp);
    let below = *below;
    if lo + 1 >= n {
        return below;
    }
    let next = above.iter().copied().fold(f64::INFINITY, f64::min);
    below + (at - lo as f64) * (next - below)
}

/// The rotation of \[P1\]'s body axes (nose, up, right) into forward, right, down: a log whose
/// readings are in the body frame of its attitudes (an autopilot's).
pub const PAPER_TO_FRD: Mat3 = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]];

/// The identity: readings in \[P1\]'s body axes.
pub const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// `frame^T v`: a vector of the readings' axes in \[P1\]'s body axes.
pub fn to_paper(frame: &Mat3, v: Vec3) -> Vec3 {
    mat_t_vec(frame, v)
}

/// Draws from a fit's standard errors where it has no trials.
pub const DRAWS: usize = 200;

/// What a fit says of the heading a vehicle will steer by (see the module documentation).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct HeadingVerdict {
    /// The budget, degrees.
    pub budget_deg: f64,
    /// The tilts flown.
    pub tilts: Tilts,
    /// The field's inclination, degrees.
    pub inclination_deg: f64,
    /// Attitudes judged.
    pub attitudes: usize,
    /// The 95/95 tolerance ([`tolerance`]) of `|e|` over the attitudes and the calibrations of
    /// the check's `ok` trials, degrees; `None` without trials.
    pub by_trials_deg: Option<f64>,
    /// Trials it rests on.
    pub trials: usize,
    /// The same over calibrations drawn with the standard errors the fit reports, which the
    /// held-out fits widened where they spread further (the trials' errors rescaled to them, or
    /// without trials independent normal draws); degrees.
    pub with_std_deg: f64,
    /// Calibrations drawn for it.
    pub draws: usize,
    /// Whether those draws are the trials' errors rescaled (else normal draws).
    pub rescaled_trials: bool,
    /// Whether the fit's standard errors were widened by its held-out fits.
    pub held_out_widened: bool,
    /// Whether its held-out fits gave evidence at all (enough folds determine the calibration).
    #[serde(default)]
    pub held_out_evidence: bool,
    /// Both figures within the budget.
    pub met: bool,
}

impl HeadingVerdict {
    /// The larger of the two figures: what the calibration is predicted to leave.
    pub fn predicted_deg(&self) -> f64 {
        self.by_trials_deg
            .map_or(self.with_std_deg, |t| t.max(self.with_std_deg))
    }

    /// Why a calibration whose budget is not met is not usable; `None` where it is met.
    pub fn reason(&self) -> Option<String> {
        (!self.met).then(|| {
            format!(
                "heading budget not met: {} ({} times the budget)",
                self.words(),
                times(self.predicted_deg() / self.budget_deg)
            )
        })
    }

    /// "heading within 2 deg (95th percentile over roll -5 to 5, pitch -20 to 20 deg, every
    /// heading, inclination 43.0 deg): 0.42 deg by 200 trials, 0.47 with the held-out standard
    /// errors".
    pub fn words(&self) -> String {
        let trials = self.by_trials_deg.map_or(String::new(), |t| {
            format!("{} deg by {} trials, ", self.against_budget(t), self.trials)
        });
        format!(
            "heading within {} deg (95th percentile over {}, every heading, inclination {:.1} deg): {trials}{} deg with {}",
            crate::error::show(self.budget_deg),
            self.tilts.words(),
            self.inclination_deg,
            self.against_budget(self.with_std_deg),
            match (self.held_out_widened, self.held_out_evidence) {
                (true, _) => "the standard errors the held-out fits widened",
                (false, true) => "the standard errors (the held-out fits spread no further)",
                (false, false) => "the standard errors",
            }
        )
    }

    /// `x` degrees to a few digits, with as many more as it takes to show on which side of the
    /// budget it lies (1.004 against a budget of 1 is not "1.0").
    pub fn against_budget(&self, x: f64) -> String {
        let shown = significant_deg(x);
        let within = x <= self.budget_deg;
        if !x.is_finite() || shown.parse::<f64>().is_ok_and(|s| (s <= self.budget_deg) == within) {
            return shown;
        }
        (3..=9)
            .map(|d| format!("{x:.d$}"))
            .find(|s| s.parse::<f64>().is_ok_and(|s| (s <= self.budget_deg) == within))
            .unwrap_or_else(|| format!("{x}"))
    }
}

/// A ratio above 1, with the digits it takes not to read as 1 ("1.03", not "1.0").
fn times(ratio: f64) -> String {
    if ratio > 1.0 && ratio < 1.1 {
        format!("{ratio:.2}")
    } else {
        significant_deg(ratio)
    }
}

fn significant_deg(x: f64) -> String {
    if x >= 10.0 {
        format!("{x:.0}")
    } else if x >= 1.0 {
        format!("{x:.1}")
    } else {
        format!("{x:.2}")
    }
}

/// The 95/95 tolerance ([`tolerance`]) over `grid` of the calibrations `centre + d` for each of
/// `draws` (psi degrees, scale, bias nT, as `centre`), against `sensor` (`K`, bias nT) read in a
/// field of `magnitude` nT: what a fit at `centre` whose errors are `draws` says it leaves. A
/// draw that is no sensor (a scale factor at or below zero) turns every heading by 180 degrees.
pub fn tolerance_around(
    grid: &BudgetGrid,
    magnitude: f64,
    sensor: (&Mat3, Vec3),
    centre: [Vec3; 3],
    draws: &[[Vec3; 3]],
) -> f64 {
    tolerance(draws, |d, e| {
        let at = |g: usize| -> Vec3 { std::array::from_fn(|i| centre[g][i] + d[g][i]) };
        match ErrorModel::new(at(0), at(1), at(2)).ok().and_then(|m| {
            let p = crate::small::upper_triangular_inverse(&m.K())?;
            Some((p, at(2)))
        }) {
            Some((p, bias)) => grid.errors_into(sensor, magnitude, (&p, bias), e),
            None => e.extend(std::iter::repeat_n(180.0, grid.len())),
        }
    })
}

/// The heading `fit` leaves over `grid` against `budget_deg`, its calibrations drawn by its
/// check's trials and by its standard errors (draws on stream `[0xFFF6]` of `seed` where it has
/// no trials); `None` where the fit has no standard errors.
pub fn judge(fit: &crate::log_fit::LogFit, grid: &BudgetGrid, budget_deg: f64, seed: u64) -> Option<HeadingVerdict> {
    use rand_distr::{Distribution, StandardNormal};
    let std = [fit.std_psi_deg?, fit.std_scale?, fit.std_bias?];
    let centre = [fit.errors.psi_deg(), fit.errors.scale(), fit.bias];
    let k = crate::small::upper_triangular_inverse(&fit.p)?;
    let full = fit.model == crate::log_fit::FitModel::Full;
    let score = |draws: &[[Vec3; 3]]| tolerance_around(grid, fit.magnitude, (&k, fit.bias), centre, draws);
    let trials = &fit.trial_errors;
    let by_trials_deg = (trials.len() >= 2).then(|| score(trials));
    let rms: [Vec3; 3] = std::array::from_fn(|g| {
        std::array::from_fn(|i| {
            (trials.iter().map(|e| e[g][i] * e[g][i]).sum::<f64>() / trials.len().max(1) as f64).sqrt()
        })
    });
    // The trials' errors at the standard errors the fit reports: one factor for every parameter
    // (the rms over the parameters of each one's standard error over its trials' rms), so that
    // the trials' joint spread, whose correlations make the heading (a bias and a scale that
    // cancel), is kept; a factor per parameter breaks what a few trials estimate of them.
    let factors: Vec<f64> = (0..3)
        .flat_map(|g| (0..3).map(move |i| (g, i)))
        .filter(|&(g, _)| g > 0 || full)
        .filter(|&(g, i)| rms[g][i] > 0.0)
        .map(|(g, i)| std[g][i] / rms[g][i])
        .collect();
    let rescaled_trials = trials.len() >= 2 && !factors.is_empty();
    let draws: Vec<[Vec3; 3]> = if rescaled_trials {
        let c = (factors.iter().map(|f| f * f).sum::<f64>() / factors.len() as f64).sqrt();
        trials.iter().map(|e| e.map(|v| v.map(|x| c * x))).collect()
    } else {
        let mut rng = crate::rng::stream_rng(seed, crate::rng::stream_id(&[0xFFF6]));
        (0..DRAWS)
            .map(|_| {
                std::array::from_fn(|g| {
                    std::array::from_fn(|i| {
                        let z: f64 = StandardNormal.sample(&mut rng);
                        if g == 0 && !full { 0.0 } else { z * std[g][i] }
                    })
                })
            })
            .collect()
    };
    let with_std_deg = score(&draws);
    let mut v = HeadingVerdict {
        budget_deg,
        tilts: grid.tilts(),
        inclination_deg: grid.inclination_deg(),
        attitudes: grid.len(),
        by_trials_deg,
        trials: if by_trials_deg.is_some() { trials.len() } else { 0 },
        with_std_deg,
        draws: draws.len(),
        rescaled_trials,
        held_out_widened: fit.held_out.as_ref().is_some_and(|h| h.widened),
        held_out_evidence: fit.held_out.as_ref().is_some_and(|h| h.evidence()),
        met: false,
    };
    v.met = v.predicted_deg() <= budget_deg;
    Some(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::paper;

    #[test]
    fn level_headings_agree_with_the_heading_probe() {
        // At level, the grid's errors are the heading probe's (every 5 degrees instead of 1, at
        // yaws shifted by the declination): the same definition. The rms over equally spaced
        // headings of an error that is a trigonometric polynomial of low degree is the same for
        // 72 and 360 of them, whatever their phase; the arctangent adds harmonics far below.
        let field = paper::changsha_field();
        let truth = paper::true_error_model();
        let grid = BudgetGrid::new(field.inclination_deg(), Tilts::LEVEL, &IDENTITY);
        assert_eq!(grid.len(), HEADINGS);
        for p in [IDENTITY, truth.P()] {
            // Only the bias removed, and the bias and K removed but for a 1 % scale on x.
            let p = if p == IDENTITY {
                p
            } else {
                let mut q = p;
                q[0] = q[0].map(|v| v * 1.01);
                q
            };
            let mut e = Vec::new();
            grid.errors_into(
                (&truth.K(), truth.bias_nt()),
                field.magnitude(),
                (&p, truth.bias_nt()),
                &mut e,
            );
            let rms = (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt();
            let probe = crate::heading::HeadingProbe::new(&field, &truth).error_by_atan2(&p, truth.bias_nt());
            assert!((rms / probe.rms_deg - 1.0).abs() < 1e-4, "{rms} {}", probe.rms_deg);
        }
    }

    #[test]
    fn a_perfect_calibration_leaves_no_error_at_any_tilt() {
        let field = paper::changsha_field();
        let truth = paper::true_error_model();
        let tilts = Tilts {
            roll_deg: [-30.0, 30.0],
            pitch_deg: [-60.0, 60.0],
        };
        let grid = BudgetGrid::new(field.inclination_deg(), tilts, &PAPER_TO_FRD);
        assert_eq!(grid.len(), TILT_STEPS * TILT_STEPS * HEADINGS);
        let mut e = Vec::new();
        grid.errors_into(
            (&truth.K(), truth.bias_nt()),
            field.magnitude(),
            (&truth.P(), truth.bias_nt()),
            &mut e,
        );
        let max = e.iter().copied().fold(0.0, f64::max);
        assert!(max < 1e-10, "{max}");
    }

    #[test]
    fn a_bias_across_the_field_turns_the_level_heading_by_its_angle() {
        // A bias error d along the body's right axis, level: the calibrated horizontal field is
        // T + d z, so with the nose on magnetic north (yaw 0, grid index 36) the error is
        // atan(d / H), and at no heading more than asin(d / H).
        let inclination: f64 = 60.0;
        let grid = BudgetGrid::new(inclination, Tilts::LEVEL, &IDENTITY);
        let r = 50_000.0;
        let h = r * inclination.to_radians().cos();
        let d = 500.0;
        let mut e = Vec::new();
        grid.errors_into((&IDENTITY, [0.0; 3]), r, (&IDENTITY, [0.0, 0.0, -d]), &mut e);
        assert!(
            (e[HEADINGS / 2] - (d / h).atan().to_degrees()).abs() < 1e-12,
            "{}",
            e[HEADINGS / 2]
        );
        let max = e.iter().copied().fold(0.0, f64::max);
        assert!(max <= (d / h).asin().to_degrees() + 1e-12, "{max}");
        // A vertical bias error moves no level heading.
        e.clear();
        grid.errors_into((&IDENTITY, [0.0; 3]), r, (&IDENTITY, [0.0, d, 0.0]), &mut e);
        assert!(e.iter().all(|v| *v < 1e-12));
    }

    #[test]
    fn quantiles_interpolate_as_numpy() {
        // Within a few roundings of the values (numpy: 3.0, 4.8, 5.0, 1.0).
        let near = |a: f64, b: f64| (a - b).abs() <= 4.0 * f64::EPSILON * b.abs();
        let mut v = vec![4.0, 1.0, 3.0, 2.0, 5.0];
        assert!(near(quantile(&mut v, 0.5), 3.0));
        assert!(near(quantile(&mut v, 0.95), 4.8));
        assert!(near(quantile(&mut v, 1.0), 5.0));
        assert!(near(quantile(&mut v, 0.0), 1.0));
        assert!(quantile(&mut [], 0.5).is_nan());
        assert!(near(quantile(&mut [7.0], 0.95), 7.0));
    }
}
