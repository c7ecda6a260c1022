//! Whether a log is one sensor in one field (docs/conventions.md "One field"): a change of the
//! field within the log (a magnet put on the board or taken off), brief passes through another
//! field that move the calibration (a magnet or iron close to the path), and a calibration whose
//! heading against the log's attitudes is worse than the raw readings' each make a calibration
//! unusable, and say so.

use std::io::Write;

use magcal_core::Vec3;
use magcal_core::log_fit::{
    self, FieldChange, FieldChangeSettings, FitModel, FitSettings, LogFit, PASS_EDGE_SIGMAS, PASS_SHARE, PASS_SHIFT,
    Passes, REJECT_MIN_K, best_sphere, field_segments,
};
use magcal_core::small::{norm, sub};
use magcal_logs::text::significant;
use rayon::prelude::*;

use crate::log::calibration::{
    CalibrationJson, FieldChangeJson, FieldCutJson, FieldSegmentJson, PassJson, PassesJson, VersusRawJson,
};
use crate::log::source::Log;

/// Searches `log` for a change of the field (where it has times) under `fit`, records it in
/// `json`, and makes the calibration unusable where the field changes or where its heading
/// against the log's attitudes is worse than the raw readings' (`json.heading_vs_log` must be
/// filled). `plain`: `fit` is the fit of `log`'s readings under `settings` (no vector fit or
/// motor interference replaced it).
pub fn judge(json: &mut CalibrationJson, log: &Log, fit: &LogFit, settings: &FitSettings, plain: bool) {
    // Brief passes are found first, and the search of changes that last runs without them: a
    // pass of a tenth of a second is a block of a second far off the field.
    let found = fit.identifiable.then(|| brief_passes(log, fit)).flatten();
    if let Some(times) = &log.times {
        json.field_change = Some(field_change(
            &log.readings,
            times,
            (fit, plain),
            settings,
            found.as_ref(),
        ));
    }
    if let Some(f) = json.field_change.as_ref().filter(|f| f.changed) {
        json.usable = false;
        // The fit of two fields does not settle for that reason: the change is the cause to name.
        json.reasons.retain(|r| !r.starts_with("not identifiable"));
        json.reasons.insert(0, change_reason(f));
    } else if let Some(found) = &found {
        // Under a change of the field the whole log's calibration departs everywhere: the change
        // is the cause to name, and passes are looked for within one field only.
        let p = passes(json, log, fit, settings, found);
        if p.unusable {
            json.usable = false;
            json.reasons.push(pass_reason(&p));
        }
        json.passes = Some(p);
    }
    let worse = json
        .heading_vs_log
        .as_ref()
        .and_then(|h| Some((h.calibrated?, h.uncalibrated?, h.versus_raw.clone()?)))
        .filter(|(_, _, v)| v.worse);
    if let Some((c, r, v)) = worse {
        json.usable = false;
        json.reasons.push(format!(
            "its heading against the log's attitudes is worse than the raw readings': rms {:.3} against {:.3} degrees, {} more, beyond {} standard errors of the difference ({} over {} blocks of {}); the raw readings are the better compass",
            c.heading_rms_deg,
            r.heading_rms_deg,
            significant(v.difference_deg, 3),
            v.sigmas,
            v.std_error_deg.map_or("unknown".to_string(), |s| significant(s, 2)),
            v.blocks,
            v.block
        ));
    }
}

/// How many passes the words name before "and N more".
const PASSES_NAMED: usize = 5;

/// The passes of the log's readings under `fit` through another field: with times, the brief
/// ones ([`Passes::brief`] at the change search's shortest part).
fn brief_passes(log: &Log, fit: &LogFit) -> Option<Passes> {
    let magnitudes: Vec<f64> = log.readings.par_iter().map(|s| norm(fit.apply(*s))).collect();
    let found = log_fit::passes_in_magnitudes(magnitudes)?;
    Some(match &log.times {
        Some(t) => found.brief(t, FieldChangeSettings::default().min_part_s),
        None => found,
    })
}

/// The passes `found` in words, and how far the calibration of the log without them lies from
/// `fit`, in `fit`'s standard errors.
fn passes(json: &CalibrationJson, log: &Log, fit: &LogFit, settings: &FitSettings, found: &Passes) -> PassesJson {
    let share_percent = 100.0 * PASS_SHARE;
    let mut out = PassesJson {
        magnitude: found.magnitude,
        noise: found.noise,
        threshold: found.threshold,
        share_percent,
        sigmas: found.sigmas,
        edge_sigmas: PASS_EDGE_SIGMAS,
        passes: found
            .passes
            .iter()
            .map(|p| PassJson {
                at: log.lines[p.first],
                position: log.origin.position_name().to_string(),
                from_s: log.times.as_ref().map(|t| t[p.first]),
                to_s: log.times.as_ref().map(|t| t[p.first + p.readings - 1]),
                readings: p.readings,
                peak_percent: 100.0 * p.peak,
            })
            .collect(),
        readings: found.readings(),
        shift_std_errors: None,
        shift_parameter: None,
        shift_limit: PASS_SHIFT,
        unusable: false,
        words: String::new(),
    };
    let rule = format!(
        "{} ({} % of the field, or {} noise standard deviations)",
        significant(found.threshold, 3),
        significant(share_percent, 2),
        significant(found.sigmas, 3)
    );
    if found.passes.is_empty() {
        out.words = format!(
            "no pass through another field: no reading's calibrated magnitude departs from the field's by {rule} or more"
        );
        return out;
    }
    let peak = out
        .passes
        .iter()
        .map(|p| p.peak_percent)
        .max_by(|a, b| a.abs().total_cmp(&b.abs()));
    let what = format!(
        "{} pass{} through another field ({} readings departing from the field's magnitude by {rule} or more, up to {} %; a magnet or iron close to the path, or glitches): {}",
        out.passes.len(),
        if out.passes.len() == 1 { "" } else { "es" },
        out.readings,
        peak.map_or("?".to_string(), |p| format!("{:+.0}", p)),
        pass_list(&out.passes)
    );
    let shift = shift_without(json, log, fit, settings, found);
    let remedy = format!(
        "drop them (--reject {}) or calibrate away from the iron",
        reject_k(found.threshold, found.noise)
    );
    match shift {
        Ok((s, name)) => {
            out.shift_std_errors = Some(s);
            out.shift_parameter = Some(name.clone());
            // A shift that is not a number is not within the limit.
            out.unusable = s.is_nan() || s > PASS_SHIFT;
            out.words = if out.unusable {
                format!(
                    "{what}; without them the calibration moves by {} standard errors ({name}), more than {}: {remedy}",
                    significant(s, 2),
                    significant(PASS_SHIFT, 2)
                )
            } else {
                format!(
                    "{what}; without them the calibration moves by {} standard errors at most ({name}), within {}: they leave it as it is",
                    significant(s, 2),
                    significant(PASS_SHIFT, 2)
                )
            };
        }
        Err(why) => {
            out.unusable = true;
            out.words = format!("{what}; what they do to the calibration is not known ({why}): {remedy}");
        }
    }
    out
}

/// What the passes do to the calibration: the same model refitted without them, as the largest
/// move of a parameter in its standard errors and the parameter's name.
fn shift_without(
    json: &CalibrationJson,
    log: &Log,
    fit: &LogFit,
    settings: &FitSettings,
    found: &Passes,
) -> Result<(f64, String), String> {
    if json.fit == "vector" || json.motor.is_some() {
        return Err(format!(
            "the {} fit is not refitted without them",
            if json.motor.is_some() { "motor" } else { "vector" }
        ));
    }
    let keep = found.keep(log.readings.len());
    let kept: Vec<Vec3> = log
        .readings
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(r, _)| *r)
        .collect();
    let refit_settings = FitSettings {
        trials: 0,
        held_out: false,
        ..settings.clone()
    };
    log_fit::fit_with(&kept, fit.magnitude, fit.model, &refit_settings)
        .map_err(|e| format!("the log without them does not fit: {e}"))
        .and_then(|r| largest_shift(fit, &r))
}

/// The reason passes give, short: the table's `PASSES` line and the JSON's words have the list.
fn pass_reason(p: &PassesJson) -> String {
    let moves = match (p.shift_std_errors, &p.shift_parameter) {
        (Some(s), Some(name)) => format!("move the calibration by {} standard errors ({name})", significant(s, 2)),
        _ => "do what is not known to the calibration".to_string(),
    };
    format!(
        "{} pass{} through another field ({} readings; a magnet or iron close to the path) {moves}: drop them (--reject {}) or calibrate away from the iron",
        p.passes.len(),
        if p.passes.len() == 1 { "" } else { "es" },
        p.readings,
        reject_k(p.threshold, p.noise)
    )
}

/// The `--reject` K that drops every departing reading: the departure threshold in noise
/// standard deviations, rounded down.
fn reject_k(threshold: f64, noise: f64) -> f64 {
    (threshold / noise).floor().max(REJECT_MIN_K)
}

/// The passes in words, the first [`PASSES_NAMED`] of them.
fn pass_list(passes: &[PassJson]) -> String {
    let mut named: Vec<String> = passes
        .iter()
        .take(PASSES_NAMED)
        .map(|p| {
            let place = match (p.from_s, p.to_s) {
                (Some(a), Some(b)) => format!("{} s", span(a, b)),
                _ => format!("{} {}", p.position, p.at),
            };
            format!("{place} ({} readings, {:+.0} %)", p.readings, p.peak_percent)
        })
        .collect();
    if passes.len() > PASSES_NAMED {
        named.push(format!("and {} more", passes.len() - PASSES_NAMED));
    }
    named.join(", ")
}

/// The largest `|refit - fit|` over the estimated parameters in `fit`'s standard errors, and its
/// parameter's name; an error where `fit` has no standard errors.
fn largest_shift(fit: &LogFit, refit: &LogFit) -> Result<(f64, String), String> {
    let (Some(sp), Some(ss), Some(sb)) = (fit.std_psi_deg, fit.std_scale, fit.std_bias) else {
        return Err("the calibration has no standard errors".to_string());
    };
    let axes = ["x", "y", "z"];
    let groups = [
        (
            fit.errors.psi_deg(),
            refit.errors.psi_deg(),
            sp,
            "non-orthogonality psi",
        ),
        (fit.errors.scale(), refit.errors.scale(), ss, "scale of sensor axis "),
        (fit.bias, refit.bias, sb, "bias of sensor axis "),
    ];
    let mut best: Option<(f64, String)> = None;
    for (a, b, se, name) in groups {
        for i in 0..3 {
            // A parameter the model holds fixed has a standard error of 0 and does not move.
            if se[i].is_nan() || se[i] <= 0.0 {
                continue;
            }
            let z = (b[i] - a[i]).abs() / se[i];
            let label = if name.ends_with("psi") {
                format!("{name}{}", i + 1)
            } else {
                format!("{name}{}", axes[i])
            };
            if best.as_ref().is_none_or(|(m, _)| z.is_nan() || z > *m) {
                best = Some((z, label));
            }
        }
    }
    best.ok_or_else(|| "no parameter has a standard error".to_string())
}

/// The search of the log's magnitudes: under `fit` where it is identifiable; else under the
/// best-fitting sphere, to find the pieces, then under the fit (the model of `fit`, else a
/// sphere) of its longest piece, which must settle to measure the field with.
fn field_change(
    readings: &[Vec3],
    times: &[f64],
    (fit, plain): (&LogFit, bool),
    settings: &FitSettings,
    passes: Option<&Passes>,
) -> FieldChangeJson {
    let search = FieldChangeSettings::default();
    let under = |f: &LogFit| readings.iter().map(|s| f.apply(*s)).collect::<Vec<Vec3>>();
    if fit.identifiable {
        let Some(p) = passes.filter(|p| !p.passes.is_empty()) else {
            return to_json(
                field_segments(times, &under(fit), &search),
                "the calibration of the whole log".to_string(),
            );
        };
        let keep = p.keep(readings.len());
        let (t, b): (Vec<f64>, Vec<Vec3>) = times
            .iter()
            .zip(under(fit))
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(x, _)| x)
            .unzip();
        return to_json(
            field_segments(&t, &b, &search),
            format!(
                "the calibration of the whole log, without the {} readings of its passes through another field",
                p.readings()
            ),
        );
    }
    let Some((centre, _)) = best_sphere(readings) else {
        return untested("no calibration of the whole log settles and no sphere fits its readings".to_string());
    };
    let at_sphere: Vec<Vec3> = readings.iter().map(|s| sub(*s, centre)).collect();
    let pieces = match field_segments(times, &at_sphere, &search) {
        Ok(p) => p,
        Err(e) => return untested(e.to_string()),
    };
    let piece = &pieces.segments[pieces.longest()];
    let part = &readings[piece.first..piece.first + piece.readings];
    // The piece's fit only measures the field: it needs to settle, not the log's check.
    let settings = FitSettings {
        truncation: None,
        trials: 0,
        held_out: false,
        ..settings.clone()
    };
    // Fitted to a unit field and taken to its mean radius, as the fit of a whole log: the
    // magnitudes come out in the log's units.
    // Where the piece is the whole log and `fit` its plain fit under these settings, not made
    // unidentifiable by trials, fitting its model again would only repeat that fit (on a log
    // whose profile takes seconds, half of calibrate's time).
    let repeat = plain
        && fit.check.is_none()
        && settings.truncation.is_none()
        && piece.first == 0
        && piece.readings == readings.len();
    let settled = [fit.model, FitModel::Offset]
        .into_iter()
        .filter(|&m| !(repeat && m == fit.model))
        .filter_map(|m| log_fit::fit_with(part, 1.0, m, &settings).ok())
        .filter(|f| f.identifiable)
        .find_map(|f| f.at_magnitude(f.mean_radius()).ok());
    let span = format!("{:.3} to {:.3} s", piece.from_s, piece.to_s);
    let whole = if pieces.changed() {
        "its longest piece"
    } else {
        "the whole log"
    };
    match settled {
        Some(f) => to_json(
            field_segments(times, &under(&f), &search),
            format!(
                "the {} fit of {span} ({whole} under the best-fitting sphere), as the fit of the whole log does not settle",
                f.model.as_str()
            ),
        ),
        None => untested(format!(
            "cannot tell: the fit of the whole log does not settle, and neither the {} model nor a sphere settles on {whole} under the best-fitting sphere ({span}), so no calibration measures the field",
            fit.model.as_str()
        )),
    }
}

fn untested(words: String) -> FieldChangeJson {
    let s = FieldChangeSettings::default();
    FieldChangeJson {
        tested: false,
        changed: false,
        measured_with: String::new(),
        segments: Vec::new(),
        step_percent: 100.0 * s.min_step,
        z: s.z,
        min_part_s: s.min_part_s,
        block_s: s.block_s,
        changes: Vec::new(),
        largest_z: None,
        largest_step_percent: None,
        words: format!("not searched: {words}"),
    }
}

fn to_json(found: Result<FieldChange, log_fit::FieldChangeError>, measured_with: String) -> FieldChangeJson {
    let f = match found {
        Ok(f) => f,
        Err(e) => return untested(e.to_string()),
    };
    let s = FieldChangeSettings::default();
    let reference = f.segments[f.longest()].magnitude;
    let segments: Vec<FieldSegmentJson> = f
        .segments
        .iter()
        .map(|g| FieldSegmentJson {
            from_s: g.from_s,
            to_s: g.to_s,
            readings: g.readings,
            magnitude: g.magnitude,
            level_percent: 100.0 * (g.magnitude / reference - 1.0),
            change_percent: 100.0 * g.change,
            in_field: g.in_field,
        })
        .collect();
    let largest_z = f.largest_z.map(|c| c.z);
    let largest_step_percent = f.largest_step.map(|c| 100.0 * c.step.abs());
    let words = if f.changed() {
        format!("the field changes within the log: {}", parts_words(&segments))
    } else {
        format!(
            "one field: no window of {} s or more whose field (level and hard iron) differs from the rest's by {} % of the magnitude or more with z >= {} (largest z {}; largest difference among windows of z >= {}: {})",
            s.min_part_s,
            100.0 * s.min_step,
            s.z,
            largest_z.map_or("none".to_string(), |z| significant(z, 3)),
            s.z,
            largest_step_percent.map_or("none".to_string(), |p| format!("{} %", significant(p, 2)))
        )
    };
    FieldChangeJson {
        tested: true,
        changed: f.changed(),
        measured_with,
        segments,
        step_percent: 100.0 * s.min_step,
        z: s.z,
        min_part_s: s.min_part_s,
        block_s: f.block_s,
        changes: f
            .cuts
            .iter()
            .map(|c| FieldCutJson {
                from_s: c.from_s,
                to_s: c.to_s,
                z: c.z,
                step_percent: 100.0 * c.step,
            })
            .collect(),
        largest_z,
        largest_step_percent,
        words,
    }
}

/// The parts of the log in words: those in the longest piece's field, and those in another.
fn parts_words(segments: &[FieldSegmentJson]) -> String {
    let groups = group_indices(segments);
    let describe = |in_field: bool| -> Vec<String> {
        groups
            .iter()
            .filter(|(a, _)| segments[*a].in_field == in_field)
            .map(|&(a, b)| {
                let g = &segments[a..=b];
                let readings: usize = g.iter().map(|s| s.readings).sum();
                let off = g.iter().map(|s| s.change_percent).fold(0.0, f64::max);
                let span = span(g[0].from_s, g[g.len() - 1].to_s);
                if in_field {
                    format!("{span} s ({readings} readings)")
                } else {
                    format!(
                        "{span} s ({readings} readings, its magnitude {} % off under the other's field, rms)",
                        significant(off, 2)
                    )
                }
            })
            .collect()
    };
    format!(
        "one field in {}, another in {}",
        describe(true).join(", "),
        describe(false).join(", ")
    )
}

/// `from-to` with the start rounded down and the end up to the millisecond, so that `--from` and
/// `--to` given these numbers keep every reading of the span.
fn span(from_s: f64, to_s: f64) -> String {
    let [a, b] = bounds(from_s, to_s);
    format!("{a:.3}-{b:.3}")
}

fn bounds(from_s: f64, to_s: f64) -> [f64; 2] {
    // A nanosecond of slack: 44.98 - 1 is 43.980000000000004 in binary, not 43.981.
    [(from_s * 1e3 + 1e-6).floor() / 1e3, (to_s * 1e3 - 1e-6).ceil() / 1e3]
}

/// The reason a change of the field gives: the parts, and the longest to calibrate alone, less
/// the block at each end where it meets another part (a change lies within a block of a cut).
fn change_reason(f: &FieldChangeJson) -> String {
    let s = &f.segments;
    let groups = group_indices(s);
    let longest = groups
        .iter()
        .max_by(|x, y| (s[x.1].to_s - s[x.0].from_s).total_cmp(&(s[y.1].to_s - s[y.0].from_s)));
    let suggestion = longest.map_or(String::new(), |&(a, b)| {
        let from = s[a].from_s + if a > 0 { f.block_s } else { 0.0 };
        let to = s[b].to_s - if b + 1 < s.len() { f.block_s } else { 0.0 };
        let [from, to] = bounds(from, to);
        format!("; calibrate one part alone, e.g. the longest: --from {from:.3} --to {to:.3}")
    });
    format!(
        "the field changes within the log (a magnet put on the board or taken off, or the log spans places of different fields), so no one calibration holds for all of it: {}{suggestion}",
        parts_words(s)
    )
}

/// [`FieldChange::parts`] of segments read back from JSON.
fn group_indices(segments: &[FieldSegmentJson]) -> Vec<(usize, usize)> {
    let mut groups: Vec<(usize, usize)> = Vec::new();
    for (i, s) in segments.iter().enumerate() {
        match groups.last_mut() {
            Some(g) if segments[g.1].in_field == s.in_field => g.1 = i,
            _ => groups.push((i, i)),
        }
    }
    groups
}

/// The search's verdict for the table.
pub fn print_field_change(w: &mut dyn Write, j: &CalibrationJson) -> std::io::Result<()> {
    let Some(f) = &j.field_change else {
        return Ok(());
    };
    if !f.tested {
        return writeln!(w, "field over time {}", f.words);
    }
    if !f.changed {
        return writeln!(w, "{} (measured with {})", f.words, f.measured_with);
    }
    writeln!(w, "FIELD CHANGES WITHIN THE LOG (measured with {}):", f.measured_with)?;
    for s in &f.segments {
        writeln!(
            w,
            "  {:<20}{:>8} readings, level {:>+6.1} %, {:>5.1} % off under the longest piece's field (rms){}",
            format!("{} s", span(s.from_s, s.to_s)),
            s.readings,
            s.level_percent,
            s.change_percent,
            if s.in_field { "" } else { ": ANOTHER FIELD" }
        )?;
    }
    for c in &f.changes {
        writeln!(
            w,
            "  change: {} s against the rest of its piece, z {}, {} % of the magnitude (needs z >= {} and {} %)",
            span(c.from_s, c.to_s),
            significant(c.z, 3),
            significant(c.step_percent, 3),
            f.z,
            f.step_percent
        )?;
    }
    Ok(())
}

/// The passes through another field, for the table.
pub fn print_passes(w: &mut dyn Write, j: &CalibrationJson) -> std::io::Result<()> {
    match &j.passes {
        Some(p) if p.passes.is_empty() => writeln!(w, "{}", p.words),
        Some(p) => writeln!(w, "{}{}", if p.unusable { "PASSES: " } else { "passes: " }, p.words),
        None => Ok(()),
    }
}

/// The calibrated heading against the raw one, for the table.
pub fn print_versus_raw(w: &mut dyn Write, v: &VersusRawJson) -> std::io::Result<()> {
    writeln!(
        w,
        "  calibrated minus raw heading rms {} deg, std error {} over {} blocks of {}: {}",
        significant(v.difference_deg, 3),
        v.std_error_deg.map_or("unknown".to_string(), |s| significant(s, 2)),
        v.blocks,
        v.block,
        match (v.worse, v.limit_deg) {
            (true, Some(l)) => format!("WORSE THAN THE RAW READINGS (beyond {} deg)", significant(l, 2)),
            (false, Some(l)) => format!("not worse beyond chance (limit {} deg)", significant(l, 2)),
            (_, None) => "too few blocks to tell".to_string(),
        }
    )
}
