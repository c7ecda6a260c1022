//! What `calibrate` prints: the table of a calibration (its origin, estimates, residuals and
//! noise, verdicts, heading check and the attitudes flown).

use std::io::Write;

use magcal_core::log_fit::AutoReason;
use magcal_logs::text::significant;

use super::{one_field, vector};
use crate::log::calibration::{CalibrationJson, HeadingCheckJson, PassesJson};
use crate::log::flown::{Flown, SECTOR_DEG};

/// Three numbers of 7 significant digits in columns of 15.
fn row(x: [f64; 3]) -> String {
    x.map(|v| format!("{:>15}", significant(v, 7))).join("")
}

/// The table of `j`, with `auto`'s reasons `why` one model per line.
pub(super) fn print_table(w: &mut dyn Write, j: &CalibrationJson, why: &[AutoReason]) -> std::io::Result<()> {
    writeln!(
        w,
        "{}: {} readings (columns {}), {} skipped, {} rejected",
        j.log,
        j.samples,
        j.columns.join(", "),
        j.skipped,
        j.rejected
    )?;
    print_origin(w, j)?;
    writeln!(w, "fit {}", j.fit)?;
    for reason in why {
        writeln!(w, "  {reason}")?;
    }
    writeln!(w, "magnitude {} ({})", significant(j.magnitude, 7), j.magnitude_source)?;
    print_estimates(w, j)?;
    if let Some(a) = j.alignment.as_ref().filter(|_| j.usable) {
        vector::print(w, a)?;
    }
    print_residuals_and_noise(w, j)?;
    print_verdicts(w, j)
}

/// Where a flight log's readings came from (the format, messages, instance, frame, units and the
/// calibration in force), the time span, and the log's notes.
fn print_origin(w: &mut dyn Write, j: &CalibrationJson) -> std::io::Result<()> {
    if let Some(format) = j.log_format.as_deref().filter(|f| *f != "CSV") {
        let instance = j.instance.map_or_else(String::new, |i| format!(", compass {i}"));
        writeln!(w, "format {format}{instance}: {}", j.log_messages.join("; "))?;
        let frame = j.frame.as_deref().unwrap_or("unknown");
        let units = j.units.as_deref().unwrap_or("unknown");
        writeln!(w, "  units {units}, frame {frame}")?;
    } else if j.log_messages.len() > 1 {
        writeln!(w, "  {}", j.log_messages[1..].join("; "))?;
    }
    if let Some(f) = &j.in_force {
        writeln!(w, "  logged field: {f}")?;
    }
    if let Some([a, b]) = j.time_span_s {
        writeln!(w, "  readings from {a:.3} to {b:.3} s")?;
    }
    if let Some(p) = &j.place_source {
        writeln!(w, "  site and date: {p}")?;
    }
    if let Some(h) = &j.heading_source {
        writeln!(w, "  attitudes: {h}")?;
    }
    for note in &j.log_notes {
        writeln!(w, "  note: {note}")?;
    }
    Ok(())
}

/// The estimates and their standard errors, or why there are none to use.
fn print_estimates(w: &mut dyn Write, j: &CalibrationJson) -> std::io::Result<()> {
    if j.usable {
        writeln!(w, "{:<22}{}", "bias", row(j.bias))?;
        writeln!(w, "{:<22}{}", "psi_deg", row(j.psi_deg))?;
        writeln!(w, "{:<22}{}", "scale", row(j.scale))?;
        let std = |x: Option<[f64; 3]>| x.map_or(format!("{:>15}", "unknown"), row);
        writeln!(w, "{:<22}{}", "std error bias", std(j.std_error.bias))?;
        writeln!(w, "{:<22}{}", "std error psi_deg", std(j.std_error.psi_deg))?;
        writeln!(w, "{:<22}{}", "std error scale", std(j.std_error.scale))?;
        if let Some(s) = &j.std_error_source {
            writeln!(
                w,
                "  standard errors from: bias {}; psi {}; scale {}",
                s.bias.join(", "),
                s.psi_deg.join(", "),
                s.scale.join(", ")
            )?;
        }
        if let Some(c) = &j.correlation {
            let e = &c.white_std_error;
            writeln!(w, "{:<22}{}", "white-noise std bias", std(e.bias))?;
            writeln!(w, "{:<22}{}", "white-noise std psi", std(e.psi_deg))?;
            writeln!(w, "{:<22}{}", "white-noise std scale", std(e.scale))?;
            writeln!(
                w,
                "  the residuals are correlated in time (lag-one {}): standard errors from their long-run covariance over batches of {} readings{}, where larger than white noise's",
                c.lag_one.map_or("given".to_string(), |r| significant(r, 4)),
                c.batch_readings,
                c.batch_seconds
                    .map_or(String::new(), |t| format!(" ({} s)", significant(t, 3)))
            )?;
            writeln!(
                w,
                "  read them as a lower bound on a real log: a drift slower than a tenth of the log does not show in its residuals (on windows of 5 to 40 s of BROAD's motion-capture trials, 95 % intervals held an imposed sensor in 82 to 58 % of cases; docs/workflows/calibrate.md, \"What the fit says\")"
            )?;
        }
        if let Some(i) = &j.interval95 {
            writeln!(
                w,
                "95 % intervals: estimate +- {} standard errors ({})",
                significant(i.quantile, 4),
                match (&j.correlation, j.noise_estimate.as_ref().and_then(|n| n.dof)) {
                    (Some(_), _) => "Student t, the batches' degrees of freedom".to_string(),
                    (None, Some(dof)) => format!("Student t, {dof} degrees of freedom"),
                    (None, None) => "normal, the noise given".to_string(),
                }
            )?;
        }
        for (name, m) in [
            ("P (b = P (raw - bias))", j.p),
            ("A^-1 (symmetric)", j.soft_iron_inverse),
        ] {
            for (r, x) in m.iter().enumerate() {
                writeln!(w, "{:<22}{}", if r == 0 { name } else { "" }, row(*x))?;
            }
        }
    } else {
        writeln!(
            w,
            "NO CALIBRATION TO USE: the estimates are not printed (--json has them, with \"usable\": false)"
        )?;
    }
    Ok(())
}

/// The residuals' size and the noise per component, with where it comes from.
fn print_residuals_and_noise(w: &mut dyn Write, j: &CalibrationJson) -> std::io::Result<()> {
    writeln!(
        w,
        "residual | |b| - R |: rms {} ({} % of R), max {}",
        significant(j.residual_rms, 4),
        significant(j.residual_rms_percent, 4),
        significant(j.residual_max, 4)
    )?;
    let n = j.noise_estimate.as_ref();
    writeln!(
        w,
        "noise per component: {}",
        match (j.noise, n) {
            (Some(v), Some(n)) if n.source == "given" => format!("{} (given)", significant(v, 4)),
            (Some(v), Some(n)) => format!(
                "{} (from the residuals, {} degrees of freedom; 95 % interval {} to {}{})",
                significant(v, 4),
                n.dof.unwrap_or(0),
                n.interval95.map_or("?".into(), |i| significant(i[0], 3)),
                n.interval95.map_or("?".into(), |i| significant(i[1], 3)),
                n.truncation_k.map_or(String::new(), |k| format!(
                    "; corrected for the rejection at {k} robust standard deviations, whose kept readings scatter less"
                ))
            ),
            (Some(v), None) => significant(v, 4),
            (None, _) => "unknown: the fit is exact, so the log does not give it (give --noise)".to_string(),
        }
    )?;
    Ok(())
}

/// A track fit's heading standard error, the headings its flight never flew and the manoeuvres
/// to fly next.
fn print_flight_advice(w: &mut dyn Write, j: &CalibrationJson) -> std::io::Result<()> {
    if let Some(h) = j.heading_std_deg {
        writeln!(
            w,
            "heading: the bias's largest standard error leaves {} degrees (at most {} for a usable compass)",
            significant(h, 3),
            vector::MAX_HEADING_STD_DEG
        )?;
    }
    if !j.headings_never_flown.is_empty() {
        writeln!(
            w,
            "  never flown: headings {} (30-degree sectors with under 1 % of the readings)",
            vector::never_flown_words(&j.headings_never_flown)
        )?;
    }
    for m in &j.next_manoeuvres {
        writeln!(w, "  next: fly {m}")?;
    }
    Ok(())
}
/// The held-out fits, the heading budget, and the verdict: USABLE with both heading figures, or
/// NOT USABLE with every reason.
fn print_usable(w: &mut dyn Write, j: &CalibrationJson) -> std::io::Result<()> {
    if let Some(h) = &j.held_out {
        writeln!(
            w,
            "{}: {}",
            if h.evidence { "held out" } else { "NO HELD-OUT EVIDENCE" },
            h.words
        )?;
    }
    if let Some(b) = &j.heading_budget {
        writeln!(
            w,
            "{}: {}; inclination from {}; level is {}",
            if b.verdict.met {
                "heading budget"
            } else {
                "HEADING BUDGET NOT MET"
            },
            b.words,
            b.field,
            b.axes
        )?;
    }
    print_flight_advice(w, j)?;
    if j.usable {
        let budget = j.heading_budget.as_ref().map_or(String::new(), |b| {
            let v = &b.verdict;
            format!(
                " for heading within {} deg: 95th percentile {}{} deg with {} standard errors",
                magcal_core::error::show(v.budget_deg),
                v.by_trials_deg.map_or(String::new(), |t| format!(
                    "{} deg by {} trials, ",
                    v.against_budget(t),
                    v.trials
                )),
                v.against_budget(v.with_std_deg),
                if v.held_out_widened { "the held-out" } else { "the" }
            )
        });
        writeln!(
            w,
            "USABLE{budget}: {}; identifiable, not rejected by the log, on an ellipsoid, standard errors known{}",
            j.check.as_ref().map_or("no check by trials".to_string(), |c| format!(
                "{} of {} trials ok at this log's noise",
                c.ok, c.trials
            )),
            j.passes
                .as_ref()
                .and_then(PassesJson::flag)
                .map_or(String::new(), |f| format!("; {f}"))
        )?;
    } else {
        writeln!(w, "NOT USABLE: {}", j.reasons.join("; "))?;
    }
    Ok(())
}

/// The verdicts (identifiable, lack of fit, ellipsoid, usable) and the coverage of the log.
fn print_verdicts(w: &mut dyn Write, j: &CalibrationJson) -> std::io::Result<()> {
    writeln!(
        w,
        "{}: {}",
        if j.identifiable {
            "IDENTIFIABLE"
        } else {
            "NOT IDENTIFIABLE"
        },
        j.verdict
    )?;
    if let Some(t) = &j.lack_of_fit {
        let head = if t.rejected {
            "MODEL REJECTED BY THE LOG"
        } else {
            "lack of fit"
        };
        writeln!(w, "{head}: {}", t.words)?;
    }
    if let Some(e) = &j.ellipsoid {
        writeln!(
            w,
            "{}: {}",
            if e.passed { "ellipsoid" } else { "NOT AN ELLIPSOID" },
            e.words
        )?;
    }
    if let Some(c) = &j.check {
        writeln!(w, "{}: {}", if c.passed { "check" } else { "CHECK FAILED" }, c.words)?;
    }
    print_usable(w, j)?;
    writeln!(
        w,
        "coverage: MotionCal gaps {:.1} %, MicroStrain spatial coverage {:.1} %{}",
        j.coverage.motioncal_gap_percent,
        j.coverage.microstrain_coverage_percent,
        match (&j.coverage.d_efficiency_per_reading, &j.coverage.box_from) {
            // The certificate bounds noise-free designs inside the box: more information per
            // reading than any of them comes from attitudes outside it, or from the noise of the
            // readings, which spreads them where the box is narrow (the weak direction's
            // information is small, and noise adds to it), and is no efficiency.
            (Some(e), Some(b)) if *e > 1.0 => format!(
                "; certified D-efficiency per reading: none in the box of {b} (the log holds {} times the information per reading of the best design in it: its attitudes lie outside the box, or its readings' noise spreads them beyond a narrow one)",
                significant(*e, 4)
            ),
            (Some(e), Some(b)) => format!(
                "; certified D-efficiency per reading {} in the box of {b}",
                significant(*e, 4)
            ),
            (None, Some(b)) => j.coverage.d_efficiency_why_not.as_ref().map_or(String::new(), |why| {
                format!("; certified D-efficiency per reading in the box of {b}: none ({why})")
            }),
            _ => String::new(),
        }
    )?;
    if let Some(f) = &j.coverage.flown {
        print_flown(w, f, j.samples, j.coverage.box_from.as_deref())?;
    }
    if let Some(h) = &j.heading_vs_log {
        print_heading(w, h)?;
    }
    one_field::print_field_change(w, j)?;
    one_field::print_passes(w, j)?;
    if let Some(m) = &j.motor {
        let se = m.std_error.map_or("unknown".to_string(), row);
        writeln!(
            w,
            "motor interference per unit {} (over {} to {}): d{}\n  std error d          {se}",
            m.input,
            significant(m.input_range[0], 4),
            significant(m.input_range[1], 4),
            row(m.per_unit)
        )?;
    }
    Ok(())
}

/// The heading against the log's attitudes, calibrated and raw.
fn print_heading(w: &mut dyn Write, h: &HeadingCheckJson) -> std::io::Result<()> {
    writeln!(w, "heading against {} ({} readings)", h.against, h.readings)?;
    for (name, f) in [("calibrated", &h.calibrated), ("raw readings", &h.uncalibrated)] {
        if let Some(f) = f {
            writeln!(
                w,
                "  {name:<13} heading rms {:.3}, p95 {:.3}, max {:.3} deg; direction rms {:.3} deg",
                f.heading_rms_deg, f.heading_p95_deg, f.heading_max_deg, f.direction_rms_deg
            )?;
        }
    }
    if let Some(v) = &h.versus_raw {
        one_field::print_versus_raw(w, v)?;
    }
    if let Some(e) = &h.error {
        writeln!(w, "  no figures: {e}")?;
    }
    Ok(())
}

/// The roll, pitch and heading the log visited, and the share inside the box.
pub(super) fn print_flown(w: &mut dyn Write, f: &Flown, samples: usize, box_from: Option<&str>) -> std::io::Result<()> {
    writeln!(
        w,
        "attitudes: {} of {samples} readings have one (degrees; roll right side down, pitch nose up, heading clockwise from north)",
        f.with_attitude
    )?;
    writeln!(
        w,
        "  {:<8}{:>9}{:>9}{:>9}{:>9}{:>9}",
        "", "min", "p5", "median", "p95", "max"
    )?;
    for (name, v) in [("roll", f.roll_deg), ("pitch", f.pitch_deg)] {
        writeln!(
            w,
            "  {name:<8}{:>9.1}{:>9.1}{:>9.1}{:>9.1}{:>9.1}",
            v[0], v[1], v[2], v[3], v[4]
        )?;
    }
    let sectors: Vec<String> = f
        .heading_sectors
        .iter()
        .enumerate()
        .map(|(i, n)| format!("{:.0}: {n}", i as f64 * SECTOR_DEG))
        .collect();
    writeln!(
        w,
        "  readings per {SECTOR_DEG:.0}-degree heading sector from: {}",
        sectors.join(", ")
    )?;
    let empty: Vec<String> = f
        .heading_sectors
        .iter()
        .enumerate()
        .filter(|(_, n)| **n == 0)
        .map(|(i, _)| format!("{:.0}-{:.0}", i as f64 * SECTOR_DEG, (i + 1) as f64 * SECTOR_DEG))
        .collect();
    if !empty.is_empty() {
        writeln!(w, "  no reading at headings {}", empty.join(", "))?;
    }
    if let (Some(n), Some(b)) = (f.in_box, box_from) {
        writeln!(
            w,
            "  inside the box of {b}: {n} readings ({:.1} %)",
            100.0 * n as f64 / f.with_attitude as f64
        )?;
    }
    Ok(())
}
