//! The heading budget of a calibration (docs/conventions.md "Heading budget"): over which
//! attitudes, in which field and with which axis up the heading it leaves is judged, and the
//! verdict recorded.

use magcal_core::budget::{BudgetGrid, HeadingVerdict, IDENTITY, PAPER_TO_FRD, Tilts};
use magcal_core::log_fit::LogFit;
use magcal_core::reference::Alignment;
use magcal_core::small::{Mat3, mat_mul, transpose};

use super::CalibrateArgs;
use crate::deadline::Deadline;
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
    /// The grid for each way up the readings may be: one where the log or scenario fixes the
    /// body axes, each of the readings' axes up where nothing does (judged by the worst).
    pub grids: Vec<(&'static str, BudgetGrid)>,
    /// Where the inclination comes from, in words.
    pub field: String,
    /// Which of the readings' axes is up at level, in words.
    pub axes: String,
}

/// \[P1\]'s body axes (nose, up, right) in readings whose x is forward and z up (y left).
const Z_UP: Mat3 = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]];

/// \[P1\]'s body axes in readings whose y is forward and x up (z left).
const X_UP: Mat3 = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]];

/// The grid of a log's heading budget: the vehicle's box (level without one) at every heading,
/// in the field of the log's site (the scenario's, the attitudes' fitted field, or assumed), with
/// the body axes the log gives (its attitudes' through the calibration's alignment with them, an
/// autopilot's forward-right-down, \[P1\]'s nose-up-right for a CSV log given a box (`boxed`: a
/// scenario, or `--roll` and `--pitch`, whose angles are of those axes), and each of the readings'
/// axes up in turn for a CSV log that says none).
pub fn grid(
    log: &Log,
    vehicle: Option<&Vehicle>,
    boxed: bool,
    place: Option<&Place>,
    alignment: Option<&Alignment>,
) -> Judged {
    let (inclination, field) = inclination(vehicle, place, alignment);
    let tilts = vehicle.map_or(Tilts::LEVEL, |v| {
        let [roll, _, pitch] = v.bounds.ranges();
        Tilts::of_box([roll.min(), roll.max()], [pitch.min(), pitch.max()])
    });
    let (frames, axes): (Vec<(&'static str, Mat3)>, &str) = match (alignment, log.origin.format) {
        // Q turns calibrated vectors into the body frame (forward, right, down).
        (Some(a), _) => (
            vec![("", mat_mul(&transpose(&a.rotation), &PAPER_TO_FRD))],
            "the body axes of the log's attitudes (the calibration aligned with them)",
        ),
        (None, Format::Csv) if boxed => (
            vec![("", IDENTITY)],
            "the readings' y axis up and x forward ([P1]'s body axes, in which the box is given)",
        ),
        (None, Format::Csv) => (
            vec![("x", X_UP), ("y", IDENTITY), ("z", Z_UP)],
            "each of the readings' axes up in turn (their frame is not known), judged by the worst",
        ),
        (None, _) => (
            vec![("", PAPER_TO_FRD)],
            "the autopilot's body axes (x forward, y right, z down)",
        ),
    };
    Judged {
        grids: frames
            .into_iter()
            .map(|(up, frame)| (up, BudgetGrid::new(inclination, tilts, &frame)))
            .collect(),
        field,
        axes: axes.to_string(),
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
            return (
                i,
                format!("the World Magnetic Model's field ({}) at the log's site", model.name()),
            );
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
            "an assumed {ASSUMED_INCLINATION_DEG} deg (a mid-latitude field; give --site and --date for the site's own)"
        ),
    )
}

/// Judges `fit`'s heading over `judged` against `budget_deg` (by the worst of its grids),
/// records it in `json` and, where the budget is not met, makes the calibration unusable with
/// the reason.
pub fn record(json: &mut CalibrationJson, fit: &LogFit, judged: Judged, budget_deg: f64, seed: u64) {
    let verdicts: Vec<(&str, HeadingVerdict)> = judged
        .grids
        .iter()
        .filter_map(|(up, g)| Some((*up, magcal_core::budget::judge(fit, g, budget_deg, seed)?)))
        .collect();
    let Some(worst) = verdicts
        .iter()
        .max_by(|a, b| a.1.predicted_deg().total_cmp(&b.1.predicted_deg()))
    else {
        return;
    };
    let mut axes = judged.axes;
    if verdicts.len() > 1 {
        let each: Vec<String> = verdicts
            .iter()
            .map(|(up, v)| format!("{up} up {} deg", v.against_budget(v.predicted_deg())))
            .collect();
        axes.push_str(&format!(" ({}; a box takes [P1]'s y up)", each.join(", ")));
        axes = axes.replacen(
            "judged by the worst",
            &format!("judged by the worst, {} up", worst.0),
            1,
        );
    }
    let v = worst.1.clone();
    if let Some(why) = v.reason() {
        json.usable = false;
        json.reasons.push(why);
    }
    json.heading_budget = Some(to_json(v, judged.field, axes));
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
/// a vector fit, a log from standard input) or finds nothing. Within `deadline`: where it leaves
/// `next` no time or cuts it short, that is said instead.
pub fn what_to_fly(args: &CalibrateArgs, json: &mut CalibrationJson, deadline: &Deadline) {
    let unmet = json.heading_budget.as_ref().is_some_and(|b| !b.verdict.met);
    let boxed = args.scenario.is_some() || args.attitude.any();
    if !unmet || !boxed || args.fit.vector_model().is_some() || args.log.as_os_str() == "-" {
        return;
    }
    // Met by the trials and missed only with the standard errors the held-out fits widened: the
    // log's parts disagree beyond its noise (a field or a sensor that drifts along it). `next`
    // predicts from the log simulated in white noise, which has no drift: more attitudes would be
    // predicted to mend what they cannot.
    if let Some(v) = json.heading_budget.as_ref().map(|b| &b.verdict)
        && v.held_out_widened
        && v.by_trials_deg.is_some_and(|t| t <= v.budget_deg)
    {
        let words = "by its trials the log meets the budget; its parts disagree beyond its noise (the fits without each fifth spread further than the standard errors say: the field or the sensor drifts along the log), which more attitudes do not mend: fly again in one place, or calibrate the part of the log that is one field (--from, --to)".to_string();
        add_to_reason(json, words);
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
    if deadline.expired() {
        return add_to_reason(json, deadline.skipped("what to fly next (`magcal next`)"));
    }
    // Quietly: what next would warn of a log it reads again is calibrate's to say.
    let suggested =
        crate::output::capture::capturing(|| crate::commands::next::suggestion_within(&next, json, deadline)).0;
    if deadline.expired() {
        return add_to_reason(json, deadline.skipped("what to fly next (`magcal next`)"));
    }
    let Ok(n) = suggested else {
        return;
    };
    let Some(first) = n.attitudes.first() else { return };
    let heading = match (n.heading_after_deg, n.usable_after) {
        (Some(h), true) => format!("leave {} deg, within the budget", magcal_logs::text::significant(h, 2)),
        (Some(h), false) => format!(
            "still leave {} deg: in this box more of the attitudes next chooses do not reach the budget; `magcal design` on the vehicle's scenario says what does (a longer plan from the start, a wider box, a quieter sensor, or a reduced model)",
            magcal_logs::text::significant(h, 2)
        ),
        (None, _) => "not determine the calibration".to_string(),
    };
    let words = format!(
        "fly {} `magcal next` gives in the box ({}roll {:.0}, pitch {:.0}, {} heading {:.0} deg), {} readings more: the log with them is predicted to {heading}",
        match n.attitudes.len() {
            1 => "the attitude".to_string(),
            k => format!("the {k} attitudes"),
        },
        if n.attitudes.len() == 1 { "" } else { "the first: " },
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
    add_to_reason(json, words);
}

/// `words` as the budget's `next` and at the end of its reason.
fn add_to_reason(json: &mut CalibrationJson, words: String) {
    if let Some(r) = json
        .reasons
        .iter_mut()
        .find(|r| r.starts_with("heading budget not met"))
    {
        r.push_str(&format!("; {words}"));
    }
    if let Some(b) = json.heading_budget.as_mut() {
        b.next = Some(words);
    }
}
