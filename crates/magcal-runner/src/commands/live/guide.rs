//! The plan a person follows while `live` fits: a short ordered list of targets, the first to
//! turn to now, kept until it is flown or clearly superseded.
//!
//! What a reading adds to the calibration depends only on the field it reads in the sensor
//! frame (its regression row, \[P1\] eq. (9)); so a target is the field direction the sensor is to
//! read (with the attitude that gives it where the vehicle has an attitude box), and it is
//! *flown* once enough readings arrived whose calibrated direction lies within [`FLOWN_DEG`] of
//! it. Fresh targets come at every fit (`next`'s D-optimal increment inside the box, or, for a
//! device held in the hand, the same increment over the whole sphere, [`sphere_targets`]); the
//! plan follows them only when its own first target is flown, or when that target's variance
//! `d(h) = h^T M^-1 h` under the readings so far (\[P1\] eq. (12): `det(M + h h^T) = det M (1 + d)`)
//! has fallen below [`SUPERSEDE`] of the best fresh target's while the person is not on the way to
//! it: then flying it gains clearly less than flying the new one. A target being flown, neared
//! (a reading within twice the flown cone) or closed on (the newest reading a flown cone nearer
//! than when it was shown) is kept until it has its readings, and a target shown for less than
//! [`REACT_S`] is not judged. Between two fits the best fresh target moves about on a flat
//! variance surface; the plan does not.

// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

use magcal_core::Vec3;
use magcal_core::linear_model::{InformationMatrix, regression_row};
use magcal_core::small::{Mat9, dot, mat_vec, norm, scale, spd_inverse};
use serde::Serialize;
use std::time::Instant;

use crate::log::calibration::CalibrationJson;

/// What the guide needs of a fit: raw = `k b + bias`, and the field's magnitude (raw units).
#[derive(Debug, Clone, Copy)]
pub struct Sensor {
    pub k: magcal_core::small::Mat3,
    pub bias: Vec3,
    pub magnitude: f64,
}

impl Sensor {
    pub fn of(cal: &CalibrationJson) -> Self {
        Self {
            k: cal.k,
            bias: cal.bias,
            magnitude: cal.magnitude,
        }
    }
}

/// Targets in a plan.
pub const PLAN_LEN: usize = 3;

/// A reading whose calibrated field direction is within this angle of a target's counts as
/// flown there, degrees. A MotionCal region spans about 20 degrees; a person holding a pose
/// wobbles by a few.
pub const FLOWN_DEG: f64 = 15.0;

/// The plan is replaced when its first target's variance falls below this share of the best
/// fresh target's: a reading there would add `ln(1 + SUPERSEDE d)` to `ln det M` against
/// `ln(1 + d)` at the best. At a half, the plan of a hand turning at 90 deg/s through a sphere
/// was superseded more often than it was flown (3 against 2); a quarter keeps a target the hand
/// is on its way to unless another is clearly better ([`REACT_S`] and the closing rule keep the
/// one it is turning to).
pub const SUPERSEDE: f64 = 0.25;

/// Seconds a fresh plan is shown before it may be superseded: a person's time to read it and
/// start to turn (the page is polled every half second, a fit comes every `--every`).
pub const REACT_S: f64 = 2.0;

/// Readings asked at a target on the sphere (a device in the hand: a pose held for about a
/// second at common rates).
pub const SPHERE_READINGS: usize = 10;

/// Directions searched on the sphere.
pub const SPHERE_POINTS: usize = 2000;

/// One target of the plan.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Target {
    /// The attitude (degrees, NED) where the vehicle has a box; `null` for a device in the hand.
    pub roll_deg: Option<f64>,
    pub pitch_deg: Option<f64>,
    pub true_heading_deg: Option<f64>,
    pub magnetic_heading_deg: Option<f64>,
    /// The direction of the field the sensor is to read there: a unit vector in the sensor
    /// frame (the frame of the calibrated readings).
    pub field_direction: Vec3,
    /// Readings asked there, and those flown there since the target was set.
    pub readings: usize,
    pub flown: usize,
    /// The target in words: the attitude, or how to hold the sensor.
    pub words: String,
    /// Readings near the direction when the target was set, and within twice as far when it was
    /// shown (became the first).
    #[serde(skip)]
    near_at_set: usize,
    #[serde(skip)]
    approach_at_set: usize,
    /// When the target was set, and how far (degrees) the newest reading then was from it.
    #[serde(skip)]
    set_at: Option<Instant>,
    #[serde(skip)]
    start_deg: f64,
}

impl Target {
    /// A target at an attitude of the vehicle's box (`next`'s row).
    pub fn attitude(a: &magcal_report::pages::next::AttitudeJson) -> Self {
        let words = format!(
            "roll {:.0}, pitch {:.0}, {}",
            whole(a.roll_deg),
            whole(a.pitch_deg),
            match a.magnetic_heading_deg {
                Some(m) => format!("magnetic heading {:.0} deg", whole(m)),
                None => format!("true heading {:.0} deg", whole(a.true_heading_deg)),
            }
        );
        Self {
            roll_deg: Some(a.roll_deg),
            pitch_deg: Some(a.pitch_deg),
            true_heading_deg: Some(a.true_heading_deg),
            magnetic_heading_deg: a.magnetic_heading_deg,
            field_direction: unit(a.field_direction),
            readings: a.readings.max(1),
            flown: 0,
            words,
            near_at_set: 0,
            approach_at_set: 0,
            set_at: None,
            start_deg: 180.0,
        }
    }

    /// A target for a device in the hand: the sensor held so that it reads the field along `u`.
    pub fn direction(u: Vec3, readings: usize) -> Self {
        let u = unit(u);
        Self {
            roll_deg: None,
            pitch_deg: None,
            true_heading_deg: None,
            magnetic_heading_deg: None,
            field_direction: u,
            readings: readings.max(1),
            flown: 0,
            words: hold_words(u),
            near_at_set: 0,
            approach_at_set: 0,
            set_at: None,
            start_deg: 180.0,
        }
    }
}

/// How to hold the sensor so that it reads the field along `u`: the sensor axis nearest `u`,
/// tilted towards the next, pointed along the field (magnetic north, dipping with it).
fn hold_words(u: Vec3) -> String {
    const AXES: [&str; 3] = ["x", "y", "z"];
    let sign = |v: f64| if v < 0.0 { "-" } else { "+" };
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| u[b].abs().total_cmp(&u[a].abs()));
    let (a, b) = (order[0], order[1]);
    let tilt = u[a].abs().clamp(-1.0, 1.0).acos().to_degrees();
    let axis = format!("{}{}", sign(u[a]), AXES[a]);
    if tilt < 5.0 {
        format!("the sensor's {axis} axis along the field (magnetic north, dipping with it)")
    } else {
        format!(
            "the sensor's {axis} axis tilted {:.0} deg towards {}{}, along the field (magnetic north, dipping with it)",
            whole(tilt),
            sign(u[b]),
            AXES[b]
        )
    }
}

/// `x` rounded to a whole number, without the sign of a negative zero.
fn whole(x: f64) -> f64 {
    x.round() + 0.0
}

fn unit(u: Vec3) -> Vec3 {
    let n = norm(u);
    if n > 0.0 { scale(1.0 / n, u) } else { [1.0, 0.0, 0.0] }
}

/// The variance function of the readings so far: `d(s) = h(s)^T M^-1 h(s)` with `M` their
/// information (\[P1\] eq. (12)) and `h(s)` the regression row of a raw reading `s`, both scaled
/// by the field's magnitude (as [`InformationMatrix`] scales them).
pub struct Variance {
    minv: Mat9,
    magnitude: f64,
}

impl Variance {
    /// Of raw readings `raw` with field magnitude `magnitude` (their units); `None` while their
    /// information is singular (fewer readings than unknowns, or all in a plane).
    pub fn new(raw: &[Vec3], magnitude: f64) -> Option<Self> {
        if !(magnitude.is_finite() && magnitude > 0.0) {
            return None;
        }
        let info = InformationMatrix::from_readings(raw, magnitude);
        spd_inverse(info.matrix()).map(|minv| Self { minv, magnitude })
    }

    /// `d` at the raw reading `s`.
    pub fn at(&self, s: Vec3) -> f64 {
        let h = regression_row(s.map(|v| v / self.magnitude));
        let mut d = 0.0;
        for i in 0..9 {
            let mut w = 0.0;
            for j in 0..9 {
                w += self.minv[i][j] * h[j];
            }
            d += h[i] * w;
        }
        d
    }

    /// Adds `count` readings at the raw reading `s` (a rank-one update of `M^-1`, Sherman-Morrison).
    fn add(&mut self, s: Vec3, count: usize) {
        let h = regression_row(s.map(|v| v / self.magnitude));
        let mut w = [0.0; 9];
        for i in 0..9 {
            for j in 0..9 {
                w[i] += self.minv[i][j] * h[j];
            }
        }
        let d: f64 = (0..9).map(|i| h[i] * w[i]).sum();
        let c = count as f64;
        let k = c / (1.0 + c * d);
        for i in 0..9 {
            for j in 0..9 {
                self.minv[i][j] -= k * w[i] * w[j];
            }
        }
    }
}

/// The raw reading of the field along the calibrated direction `u`: `K (|B| u) + bias`.
pub fn raw_at(cal: &Sensor, u: Vec3) -> Vec3 {
    let b = scale(cal.magnitude, unit(u));
    let k = mat_vec(&cal.k, b);
    [k[0] + cal.bias[0], k[1] + cal.bias[1], k[2] + cal.bias[2]]
}

/// The D-optimal increment over the whole sphere of field directions: [`PLAN_LEN`] directions,
/// each where the variance of the readings so far and of the targets before it is largest
/// ([`SPHERE_READINGS`] readings each), searched on a Fibonacci lattice of [`SPHERE_POINTS`].
pub fn sphere_targets(cal: &Sensor, variance: &Variance) -> Vec<Target> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let points: Vec<Vec3> = (0..SPHERE_POINTS)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / SPHERE_POINTS as f64;
            let r = (1.0 - z * z).sqrt();
            let t = golden * i as f64;
            [r * t.cos(), r * t.sin(), z]
        })
        .collect();
    let raws: Vec<Vec3> = points.iter().map(|&u| raw_at(cal, u)).collect();
    let mut v = Variance {
        minv: variance.minv,
        magnitude: variance.magnitude,
    };
    let mut out = Vec::with_capacity(PLAN_LEN);
    for _ in 0..PLAN_LEN {
        let best = (0..points.len())
            .map(|i| (i, v.at(raws[i])))
            .fold((0, f64::NEG_INFINITY), |b, c| if c.1 > b.1 { c } else { b });
        out.push(Target::direction(points[best.0], SPHERE_READINGS));
        v.add(raws[best.0], SPHERE_READINGS);
    }
    out
}

/// What became of the plan at one fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Change {
    /// The same first target.
    Kept,
    /// The first target was flown: the next is now first (or a fresh plan, when none is left).
    Flown,
    /// The plan was replaced before its first target was flown: superseded.
    Superseded,
    /// A plan where there was none.
    Started,
    /// No plan: the fit gives no fresh targets and none is kept.
    None,
}

/// The plan and its history.
#[derive(Debug, Default)]
pub struct Guide {
    pub plan: Vec<Target>,
    /// Targets flown, plans superseded.
    pub flown: u64,
    pub superseded: u64,
}

impl Guide {
    /// The plan after a fit, at `now`, whose calibrated field directions (sensor frame, oldest
    /// first) are `directions`, whose readings' variance function is `variance`, and whose fresh
    /// targets are `fresh` (empty where there are none: the plan is kept as it is).
    pub fn update(
        &mut self,
        cal: &Sensor,
        directions: &[Vec3],
        variance: Option<&Variance>,
        fresh: Vec<Target>,
        now: Instant,
    ) -> Change {
        let units: Vec<Vec3> = directions.iter().map(|&d| unit(d)).collect();
        let within = |u: Vec3, deg: f64| {
            let c = deg.to_radians().cos();
            units.iter().filter(|&&d| dot(d, u) >= c).count()
        };
        let near = |u: Vec3| within(u, FLOWN_DEG);
        let approach = |u: Vec3| within(u, 2.0 * FLOWN_DEG);
        for t in &mut self.plan {
            // The ring may have dropped readings near it since: flown counts never go back.
            t.flown = t.flown.max(near(t.field_direction).saturating_sub(t.near_at_set));
        }
        let newest = units.last().copied();
        let from_newest = |u: Vec3| newest.map_or(180.0, |d| dot(d, u).clamp(-1.0, 1.0).acos().to_degrees());
        // A target is shown from `now` when it becomes the plan's first: the person turns to it
        // from where the newest reading is.
        let show = |t: &mut Target| {
            t.approach_at_set = approach(t.field_direction);
            t.set_at = Some(now);
            t.start_deg = from_newest(t.field_direction);
        };
        let mut change = Change::Kept;
        while self.plan.first().is_some_and(|t| t.flown >= t.readings) {
            self.plan.remove(0);
            self.flown += 1;
            change = Change::Flown;
            if let Some(t) = self.plan.first_mut() {
                show(t);
            }
        }
        let d = |t: &Target| variance.map(|v| v.at(raw_at(cal, t.field_direction)));
        // A target is being flown, and kept until it has its readings (its variance falls as
        // they come, as it should), once the hand has come within twice the flown cone of it, or
        // is closing on it: its newest reading a flown cone nearer than when it was shown. And a
        // target shown for less than a person's reaction time is not judged.
        let reached = |t: &Target| {
            t.flown > 0
                || approach(t.field_direction) > t.approach_at_set
                || from_newest(t.field_direction) <= t.start_deg - FLOWN_DEG
                || t.set_at
                    .is_some_and(|at| now.duration_since(at).as_secs_f64() < REACT_S)
        };
        let superseded = match (self.plan.first().filter(|t| !reached(t)), fresh.first()) {
            (Some(head), Some(best)) => match (d(head), d(best)) {
                (Some(a), Some(b)) => a < SUPERSEDE * b,
                _ => false,
            },
            _ => false,
        };
        if self.plan.is_empty() || superseded {
            if fresh.is_empty() {
                return if self.plan.is_empty() { Change::None } else { change };
            }
            if superseded {
                self.superseded += 1;
                change = Change::Superseded;
            } else if change == Change::Kept {
                change = Change::Started;
            }
            self.plan = fresh
                .into_iter()
                .map(|mut t| {
                    t.near_at_set = near(t.field_direction);
                    t.flown = 0;
                    t
                })
                .collect();
            if let Some(t) = self.plan.first_mut() {
                show(t);
            }
        }
        change
    }

    /// The plan in one line: "now: ... (3 of 10 readings) then: ...; ...".
    pub fn words(&self) -> Option<String> {
        let (now, then) = self.plan.split_first()?;
        let mut s = format!("now: {} ({} of {} readings)", now.words, now.flown, now.readings);
        if !then.is_empty() {
            s += " then: ";
            s += &then.iter().map(|t| t.words.as_str()).collect::<Vec<_>>().join("; ");
        }
        Some(s)
    }
}

/// The heading budget's progress in words.
pub fn progress(predicted_deg: Option<f64>, budget_deg: f64, usable: bool) -> String {
    let budget = crate::limits::show(budget_deg);
    match predicted_deg {
        Some(p) if usable => format!("DONE: predicted heading error {p:.2} deg within the budget of {budget} deg"),
        Some(p) => format!("predicted heading error {p:.2} deg -> budget {budget} deg"),
        None => format!("heading error not predicted yet -> budget {budget} deg"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use magcal_core::small::sub;
    use std::time::Duration;

    /// A calibration of an ideal sensor (P = K = I, no bias) in a field of 500.
    fn ideal() -> Sensor {
        Sensor {
            k: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            bias: [0.0; 3],
            magnitude: 500.0,
        }
    }

    /// Readings along directions spread over a cap around +z (a device turned about one axis).
    fn cap(n: usize) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let t = i as f64 * 0.7;
                let z = 0.6 + 0.4 * ((i % 7) as f64 / 6.0);
                let r = (1.0 - z * z).sqrt();
                [500.0 * r * t.cos(), 500.0 * r * t.sin(), 500.0 * z]
            })
            .collect()
    }

    #[test]
    fn the_variance_update_is_the_inverse_of_the_information_with_the_readings_added() {
        let raw = cap(60);
        let mut v = Variance::new(&raw, 500.0).expect("the cap's information is regular");
        let s = [0.0, 0.0, -500.0];
        v.add(s, 4);
        let mut more = raw.clone();
        more.extend(std::iter::repeat_n(s, 4));
        let w = Variance::new(&more, 500.0).unwrap();
        for u in [[1.0, 0.0, 0.0], [0.3, -0.5, -0.8], [0.0, 0.0, -1.0]] {
            let x = scale(500.0, unit(u));
            let (a, b) = (v.at(x), w.at(x));
            // Sherman-Morrison against a fresh Cholesky inverse: rounding of a 9x9 system whose
            // condition number is far below 1e8.
            assert!((a - b).abs() <= 1e-8 * b.abs().max(1.0), "{a} against {b}");
        }
    }

    #[test]
    fn a_cap_of_readings_is_told_to_turn_to_the_other_side_of_the_sphere() {
        let cal = ideal();
        let raw = cap(80);
        let v = Variance::new(&raw, 500.0).unwrap();
        let t = sphere_targets(&cal, &v);
        assert_eq!(t.len(), PLAN_LEN);
        // The cap lies within 53 degrees of +z: the largest variance is far from it.
        assert!(t[0].field_direction[2] < 0.0, "{:?}", t[0]);
        assert!(t[0].words.contains("along the field"), "{}", t[0].words);
    }

    #[test]
    fn a_plan_is_kept_until_its_first_target_is_flown_then_the_next_comes() {
        let cal = ideal();
        let raw = cap(80);
        let v = Variance::new(&raw, 500.0).unwrap();
        let fresh = sphere_targets(&cal, &v);
        let mut g = Guide::default();
        let t0 = Instant::now();
        assert_eq!(g.update(&cal, &raw, Some(&v), fresh.clone(), t0), Change::Started);
        let first = g.plan[0].clone();
        // A fresh plan that differs a little (its first target 20 degrees away) does not move it.
        let mut moved = fresh.clone();
        moved[0] = Target::direction([0.34, 0.0, -0.94], SPHERE_READINGS);
        assert_eq!(g.update(&cal, &raw, Some(&v), moved, later(t0, 5.0)), Change::Kept);
        assert_eq!(g.plan[0], first);
        // Readings at the target: it is flown after as many as it asked.
        let mut flown = raw.clone();
        let at = scale(500.0, first.field_direction);
        flown.extend(std::iter::repeat_n(at, SPHERE_READINGS - 1));
        let v2 = Variance::new(&flown, 500.0).unwrap();
        let fresh2 = sphere_targets(&cal, &v2);
        assert_eq!(
            g.update(&cal, &flown, Some(&v2), fresh2.clone(), later(t0, 6.0)),
            Change::Kept
        );
        assert_eq!(g.plan[0].flown, SPHERE_READINGS - 1);
        flown.push(at);
        let v3 = Variance::new(&flown, 500.0).unwrap();
        assert_eq!(
            g.update(&cal, &flown, Some(&v3), sphere_targets(&cal, &v3), later(t0, 7.0)),
            Change::Flown
        );
        assert_eq!(g.flown, 1);
        assert_ne!(g.plan[0].field_direction, first.field_direction);
    }

    /// `t0` and `s` seconds.
    fn later(t0: Instant, s: f64) -> Instant {
        t0 + Duration::from_secs_f64(s)
    }

    /// `first` and readings landing, 40 each, on a ring 35 degrees round it (beyond twice its
    /// cone: not flown there, nor within its approach), which take most of its variance away,
    /// then `tail` readings back on the cap the hand started from.
    fn filled_round(raw: &[Vec3], first: Vec3, tail: usize) -> Vec<Vec3> {
        let e1 = unit(if first[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        });
        let e1 = unit(sub(e1, scale(dot(e1, first), first)));
        let e2 = [
            first[1] * e1[2] - first[2] * e1[1],
            first[2] * e1[0] - first[0] * e1[2],
            first[0] * e1[1] - first[1] * e1[0],
        ];
        let (s35, c35) = (35f64.to_radians().sin(), 35f64.to_radians().cos());
        let mut more = raw.to_vec();
        for k in 0..8 {
            let a = f64::from(k) * std::f64::consts::FRAC_PI_4;
            let on = unit([0, 1, 2].map(|i| c35 * first[i] + s35 * (a.cos() * e1[i] + a.sin() * e2[i])));
            more.extend(std::iter::repeat_n(scale(500.0, on), 40));
        }
        more.extend(raw.iter().rev().take(tail).copied());
        more
    }

    /// An ideal sensor, 80 readings on a cap, and the guide's plan for them set at the time
    /// returned.
    fn planned_on_a_cap() -> (Sensor, Vec<Vec3>, Guide, Instant) {
        let cal = ideal();
        let raw = cap(80);
        let v = Variance::new(&raw, 500.0).unwrap();
        let mut g = Guide::default();
        let t0 = Instant::now();
        g.update(&cal, &raw, Some(&v), sphere_targets(&cal, &v), t0);
        (cal, raw, g, t0)
    }

    #[test]
    fn a_plan_whose_target_was_filled_otherwise_is_superseded_once_shown_long_enough() {
        let (cal, raw, mut g, t0) = planned_on_a_cap();
        let first = g.plan[0].field_direction;
        // The hand went round the target and back where it began.
        let more = filled_round(&raw, first, 5);
        let v2 = Variance::new(&more, 500.0).unwrap();
        let d_old = v2.at(raw_at(&cal, first));
        let fresh = sphere_targets(&cal, &v2);
        let d_new = v2.at(raw_at(&cal, fresh[0].field_direction));
        assert!(d_old < SUPERSEDE * d_new, "{d_old} against {d_new}");
        // Within a person's reaction time the plan stands; after it, it is superseded.
        assert_eq!(
            g.update(&cal, &more, Some(&v2), fresh.clone(), later(t0, 0.9 * REACT_S)),
            Change::Kept
        );
        assert_eq!(g.plan[0].field_direction, first);
        assert_eq!(
            g.update(&cal, &more, Some(&v2), fresh, later(t0, REACT_S)),
            Change::Superseded
        );
        assert_eq!((g.superseded, g.flown), (1, 0));
    }

    #[test]
    fn a_target_the_hand_is_closing_on_is_not_superseded() {
        let (cal, raw, mut g, t0) = planned_on_a_cap();
        let first = g.plan[0].field_direction;
        // The same readings, but the newest is 35 degrees from the target: far nearer than the
        // cap it was shown from, so the hand is on its way.
        let more = filled_round(&raw, first, 0);
        let v2 = Variance::new(&more, 500.0).unwrap();
        let fresh = sphere_targets(&cal, &v2);
        assert!(v2.at(raw_at(&cal, first)) < SUPERSEDE * v2.at(raw_at(&cal, fresh[0].field_direction)));
        assert_eq!(g.update(&cal, &more, Some(&v2), fresh, later(t0, 10.0)), Change::Kept);
        assert_eq!((g.superseded, g.plan[0].field_direction), (0, first));
    }

    #[test]
    fn the_progress_says_the_budget() {
        assert_eq!(
            progress(Some(2.4), 1.0, false),
            "predicted heading error 2.40 deg -> budget 1 deg"
        );
        assert!(progress(Some(0.8), 1.0, true).starts_with("DONE"));
        assert!(progress(None, 1.0, false).contains("not predicted yet"));
    }
}
