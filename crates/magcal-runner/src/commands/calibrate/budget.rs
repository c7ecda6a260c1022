//! The heading budget of a calibration (docs/conventions.md "Heading budget"): over which
//! attitudes, in which field and with which axis up the heading it leaves is judged, and the
//! verdict recorded.

use magcal_core::budget::{BudgetGrid, HeadingVerdict, IDENTITY, PAPER_TO_FRD, Tilts};
use magcal_core::log_fit::LogFit;
use magcal_core::reference::Alignment;
use magcal_core::small::{Mat3, mat_mul, transpose};

use super::CalibrateArgs;
use crate::log::calibration::{CalibrationJson, HeadingBudgetJson};
use crate::log::flight::Format;
use crate::log::source::Log;
use crate::log::vehicle::{Place, Vehicle};
use crate::scenario::site::wmm_pick;

/// The inclination taken where nothing gives the site's field, degrees: a mid-latitude field
/// (Western Europe and the northern United States lie between 60 and 70). The heading error of
/// a bias grows as `1 / cos I`, so a steeper site asks more than this says; the words name it
/// as assumed.
pub const ASSUMED_INCLINATION_DEG: f64 = 60.0;

/// What a heading is judged over, with where its parts come from.
pub struct Judged {
    pub grid: BudgetGrid,
    /// Where the inclination comes from, in words.
    pub field: String,
    /// Which of the readings' axes is up at level, in words.
    pub axes: String,
}

/// The grid of a log's heading budget: the vehicle's box (level without one) at every heading,
/// in the field of the log's site (the scenario's, the attitudes' fitted field, or assumed), with
/// the body axes the log gives (its attitudes' through the calibration's alignment with them, an
/// autopilot's forward-right-down, or \[P1\]'s nose-up-right for readings without a frame).
pub fn grid(log: &Log, vehicle: Option<&Vehicle>, place: Option<&Place>, alignment: Option<&Alignment>) -> Judged {
    let (inclination, field) = inclination(vehicle, place, alignment);
    let tilts = vehicle.map_or(Tilts::LEVEL, |v| {
        let [roll, _, pitch] = v.bounds.ranges();
        Tilts {
            roll_deg: [roll.min().to_degrees(), roll.max().to_degrees()],
            pitch_deg: [pitch.min().to_degrees(), pitch.max().to_degrees()],
        }
    });
    let (frame, axes): (Mat3, String) = match (alignment, log.origin.format) {
        (Some(a), _) => (
            // Q turns calibrated vectors into the body frame (forward, right, down).
            mat_mul(&transpose(&a.rotation), &PAPER_TO_FRD),
            "the body axes of the log's attitudes (the calibration aligned with them)".to_string(),
        ),
        (None, Format::Csv) => (
            IDENTITY,
            "the readings' y axis up and x forward ([P1]'s body axes, as next and --scenario take them)".to_string(),
        ),
        (None, _) => (
            PAPER_TO_FRD,
            "the autopilot's body axes (x forward, y right, z down)".to_string(),
        ),
    };
    Judged {
        grid: BudgetGrid::new(inclination, tilts, &frame),
        field,
        axes,
    }
}

/// The field's inclination (degrees) and where it comes from.
fn inclination(vehicle: Option<&Vehicle>, place: Option<&Place>, alignment: Option<&Alignment>) -> (f64, String) {
    let usable = |i: f64| i.is_finite() && i.abs() < 89.0;
    if let Some(p) = place
        && let Ok((ned, model, _)) = wmm_pick(&p.site, p.date, p.model)
    {
        let i = magcal_core::field::inclination_deg(ned);
        if usable(i) {
            return (i, format!("the World Magnetic Model's ({model:?}) at the log's site"));
        }
    }
    if let Some(v) = vehicle {
        let i = v.field.inclination_deg();
        if usable(i) {
            return (i, format!("the field of {}", v.label));
        }
    }
    if let Some(a) = alignment {
        let f = a.field;
        let i = (-f[2]).atan2(f[0].hypot(f[1])).to_degrees();
        if usable(i) {
            return (
                i,
                "the field the log's attitudes give (its calibration aligned with them)".to_string(),
            );
        }
    }
    (
        ASSUMED_INCLINATION_DEG,
        format!(
            "assumed ({ASSUMED_INCLINATION_DEG} deg, a mid-latitude field; give --site and --date for the site's own)"
        ),
    )
}

/// Judges `fit`'s heading over `judged` against `budget_deg`, records it in `json` and, where the
/// budget is not met, makes the calibration unusable with the reason.
pub fn record(json: &mut CalibrationJson, fit: &LogFit, judged: Judged, budget_deg: f64, seed: u64) {
    let Some(v) = magcal_core::budget::judge(fit, &judged.grid, budget_deg, seed) else {
        return;
    };
    if let Some(why) = v.reason() {
        json.usable = false;
        json.reasons.push(why);
    }
    json.heading_budget = Some(to_json(v, judged.field, judged.axes));
}

fn to_json(v: HeadingVerdict, field: String, axes: String) -> HeadingBudgetJson {
    HeadingBudgetJson {
        predicted_deg: v.predicted_deg(),
        words: v.words(),
        verdict: v,
        field,
        axes,
        next: None,
    }
}

/// Where the budget is not met and the vehicle's box is known: the attitudes `next` would add
/// (its D-optimal augmentation of the log in the box) and the heading the log with them is
/// predicted to leave, in words, added to the reason; `None` where `next` does not apply (no box,
/// a vector fit, a log from standard input) or finds nothing.
pub fn what_to_fly(args: &CalibrateArgs, json: &mut CalibrationJson) {
    let unmet = json.heading_budget.as_ref().is_some_and(|b| !b.verdict.met);
    let boxed = args.scenario.is_some() || args.attitude.any();
    if !unmet || !boxed || args.fit.vector_model().is_some() || args.log.as_os_str() == "-" {
        return;
    }
    let next = crate::commands::next::NextArgs {
        calibration: std::path::PathBuf::from("this calibration"),
        log: args.log.clone(),
        scenario: args.scenario.clone(),
        attitude: args.attitude.clone(),
        site: args.site.filter(|_| args.scenario.is_none()),
        date: args.date.filter(|_| args.scenario.is_none()),
        wmm: args.wmm.filter(|_| args.scenario.is_none()),
        count: 10,
        json: true,
        report: None,
        input: args.input.clone(),
        heading_budget: args.heading_budget,
    };
    // Quietly: what next would warn of a log it reads again is calibrate's to say.
    let Ok(n) = crate::output::capture::capturing(|| crate::commands::next::suggestion(&next, json)).0 else {
        return;
    };
    let Some(first) = n.attitudes.first() else { return };
    let heading = match (n.heading_after_deg, n.usable_after) {
        (Some(h), true) => format!("leave {} deg, within the budget", magcal_logs::text::significant(h, 2)),
        (Some(h), false) => format!("still leave {} deg", magcal_logs::text::significant(h, 2)),
        (None, _) => "not determine the calibration".to_string(),
    };
    let words = format!(
        "fly the {} attitudes `magcal next` gives in the box (the first: roll {:.0}, pitch {:.0}, {} heading {:.0} deg), {} readings more: the log with them is predicted to {heading}",
        n.attitudes.len(),
        first.roll_deg,
        first.pitch_deg,
        if first.magnetic_heading_deg.is_some() {
            "magnetic"
        } else {
            "true"
        },
        first.magnetic_heading_deg.unwrap_or(first.true_heading_deg),
        n.readings_added
    );
    if let Some(b) = json.heading_budget.as_mut() {
        b.next = Some(words.clone());
    }
    if let Some(r) = json
        .reasons
        .iter_mut()
        .find(|r| r.starts_with("heading budget not met"))
    {
        r.push_str(&format!("; {words}"));
    }
}
