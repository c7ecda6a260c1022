//! The table `run` and `design` print on stdout, written to any `io::Write` so that a failed
//! write is an error.

use std::io::Write;
use std::path::Path;

use magcal_core::log_fit::significant;

use crate::pipeline::advice::Advice;
use crate::pipeline::{Check, RunOutput};

/// A statistic for the screen: `-` where undefined.
fn cell(x: f64) -> String {
    if x.is_nan() { "-".into() } else { format!("{x:.3}") }
}

/// Rows of a flight plan shown on the screen per design; the rest are in `designs.csv`.
const FLIGHT_PLAN_ROWS: usize = 40;

/// The line above a table of headings: the declination used and where it comes from, or why
/// there is no magnetic heading.
pub fn declination_line(declination_deg: Option<f64>, source: &str) -> String {
    match declination_deg {
        Some(d) => format!("declination {d:+.2} deg ({source}); magnetic heading = true heading - declination"),
        None => format!(
            "declination undefined: the field ({source}) has no horizontal component, so a compass has no heading; true headings only"
        ),
    }
}

/// Each design as a pilot flies it: the attitudes in visiting order with roll, pitch, the true
/// and the magnetic heading of the nose, the readings to log there and the turn from the previous
/// attitude; under one line naming the declination and its source.
pub fn flight_plans(
    w: &mut dyn Write,
    out: &RunOutput,
    headings: crate::output::Headings,
    field_source: &str,
) -> std::io::Result<()> {
    let rows: Vec<_> = crate::output::design_rows(out, headings).collect();
    writeln!(w, "{}", declination_line(headings.declination_deg, field_source))?;
    for d in &out.designs {
        let plan: Vec<_> = rows.iter().filter(|r| r.design == d.name).collect();
        let total: f64 = plan.iter().filter_map(|r| r.turn_deg.map(|t| t.0)).sum();
        writeln!(
            w,
            "flight plan {} ({} attitudes, {} readings, {:.0} deg of turning in all):",
            d.name,
            plan.len(),
            d.m(),
            total
        )?;
        writeln!(
            w,
            "  {:>5} {:>9} {:>9} {:>9} {:>9} {:>8} {:>9}",
            "visit", "roll_deg", "pitch_deg", "true_hdg", "mag_hdg", "readings", "turn_deg"
        )?;
        for r in plan.iter().take(FLIGHT_PLAN_ROWS) {
            writeln!(
                w,
                "  {:>5} {:>9.2} {:>9.2} {:>9.2} {:>9} {:>8} {:>9}",
                r.visit,
                r.roll_deg.0,
                r.pitch_deg.0,
                r.true_heading_deg.0,
                r.magnetic_heading_deg
                    .map_or("-".to_string(), |h| format!("{:.2}", h.0)),
                r.readings,
                r.turn_deg.map_or("-".to_string(), |t| format!("{:.1}", t.0))
            )?;
        }
        if plan.len() > FLIGHT_PLAN_ROWS {
            writeln!(w, "  ... {} more in designs.csv", plan.len() - FLIGHT_PLAN_ROWS)?;
        }
        writeln!(w)?;
    }
    Ok(())
}

/// The trials of a check that did not calibrate, in words.
fn outcome_words(o: &crate::pipeline::Outcomes) -> String {
    format!(
        "{} not converged, {} not identifiable, {} failed",
        o.not_converged, o.not_identifiable, o.failed
    )
}

/// What to fly: the design that works (calibrates in at least 95 % of its check's trials) with
/// the smallest median heading error, the fewer readings on a tie; or, when none works, that none
/// does and why.
pub fn recommendation(w: &mut dyn Write, out: &RunOutput, advice: Option<&Advice>) -> std::io::Result<()> {
    match out.recommended() {
        Some(i) => {
            let d = &out.designs[i];
            let c = &d.check;
            writeln!(
                w,
                "fly {}: {} readings at {} attitudes (its flight plan is in designs.csv). At {} nT it \
                 calibrated in {} of {} trials; heading error (rms over level headings) median {} deg, \
                 95th percentile {} deg{}.",
                d.name,
                d.m(),
                d.attitudes.len(),
                c.sigma_nt,
                c.outcomes.ok,
                c.trials,
                c.heading_median_deg.map_or("-".into(), |v| format!("{v:.3}")),
                c.heading_p95_deg.map_or("-".into(), |v| format!("{v:.3}")),
                out.d_efficiency_bound(i)
                    .map_or(String::new(), |e| format!("; certified D-efficiency >= {e:.4}"))
            )
        }
        None => {
            writeln!(
                w,
                "no design here calibrates the full model in {:.0} % of trials at this noise.",
                100.0 * Check::OK_SHARE
            )?;
            let Some(a) = advice else { return Ok(()) };
            let base = &out.designs[a.base];
            writeln!(
                w,
                "What works instead, by the same check, from {} ({} readings):",
                base.name,
                base.m()
            )?;
            let heading = |c: &Check| {
                format!(
                    "{} of {} trials ok at {} nT, heading error median {} deg, 95th percentile {} deg",
                    c.outcomes.ok,
                    c.trials,
                    significant(c.sigma_nt, 3),
                    c.heading_median_deg.map_or("-".into(), |v| format!("{v:.3}")),
                    c.heading_p95_deg.map_or("-".into(), |v| format!("{v:.3}")),
                )
            };
            for (model, c) in &a.reduced {
                let works = if c.works() { "works" } else { "does not work" };
                writeln!(w, "  - {}: {works}: {}", model.words(), heading(c))?;
            }
            match &a.quieter {
                Some(c) => writeln!(
                    w,
                    "  - the full model with a quieter sensor: works at {} nT ({}x less noise): {}",
                    significant(c.sigma_nt, 3),
                    significant(base.check.sigma_nt / c.sigma_nt, 3),
                    heading(c)
                )?,
                None => writeln!(
                    w,
                    "  - the full model with a quieter sensor: not even at 1/1024 of the noise"
                )?,
            }
            match &a.wider {
                Some(v) => writeln!(
                    w,
                    "  - the full model in a wider box: tilting {} deg further (roll {} to {}, pitch {} to {} deg), \
                     {} D-optimal attitudes x {} readings: {}",
                    v.extra_deg,
                    v.roll_deg[0],
                    v.roll_deg[1],
                    v.pitch_deg[0],
                    v.pitch_deg[1],
                    v.attitudes.len(),
                    v.readings_per_attitude,
                    heading(&v.check)
                )?,
                None => writeln!(
                    w,
                    "  - the full model in a wider box: not even with 90 degrees more tilt"
                )?,
            }
            writeln!(
                w,
                "  (advice.csv has each; to fly the wider box, set its ranges in the scenario and run design again)"
            )
        }
    }
}

/// Designs with `ln det M_F`, D-efficiency per reading and the identifiability verdict; per cell
/// the outcome counts and the median of the main metrics beside their Cramer-Rao rms, with a
/// warning line under a cell where fewer than 95 % of the trials are `ok`.
pub fn summary(w: &mut dyn Write, out: &RunOutput, dir: &Path) -> std::io::Result<()> {
    match &out.approximate {
        Some(a) => writeln!(
            w,
            "certificate: no design of m readings in this box has ln det M_F above 9 ln m + {:.4} \
             (approximate design of {} points, d_max = {:.5}{})",
            a.certificate.ln_det_bound,
            a.support.len(),
            a.certificate.d_max,
            if a.converged { "" } else { ", tolerance NOT reached" }
        )?,
        None => writeln!(
            w,
            "certificate: none (no design in this box identifies the linear model)"
        )?,
    }
    writeln!(
        w,
        "{:<14} {:>4} {:>10} {:>9} {:>9}  verdict",
        "design", "m", "ln det M_F", "D-eff", "certified"
    )?;
    for (i, d) in out.designs.iter().enumerate() {
        let c = &d.check;
        let share = format!("{} of {} trials ok at {} nT", c.outcomes.ok, c.trials, c.sigma_nt);
        let verdict = match (c.works(), d.verdict.identifiable) {
            (true, _) => format!("works: {share}"),
            (false, true) => format!("FAILS: only {share} ({})", outcome_words(&c.outcomes)),
            (false, false) => format!("NOT IDENTIFIABLE: {}; {share}", d.verdict.weakest),
        };
        writeln!(
            w,
            "{:<14} {:>4} {:>10.4} {:>9.4} {:>9}  {verdict}",
            d.name,
            d.m(),
            d.ln_det_mf,
            out.d_efficiency(i),
            out.d_efficiency_bound(i)
                .map_or("-".to_string(), |e| format!(">= {e:.4}"))
        )?;
    }
    if !out.cells.is_empty() {
        writeln!(w)?;
        writeln!(
            w,
            "{:<14} {:>9} {:>6} {:>6} {:>6} {:>6} {:>17} {:>17} {:>17} {:>12}",
            "design",
            "sigma_nt",
            "ok",
            "n.conv",
            "n.ident",
            "failed",
            "eta_psi med/crb %",
            "eta_S med/crb %",
            "eta_O med/crb %",
            "heading med"
        )?;
        for c in &out.cells {
            let s = c.summaries();
            let o = c.outcomes();
            let pair = |k: usize| {
                let crb = s[k].metric.predicted_rms(&c.bound).unwrap_or(f64::NAN);
                format!("{:>8}/{:<8}", cell(s[k].summary.median), cell(crb))
            };
            let name = if c.attitude_sigma_deg > 0.0 {
                format!("{}~{}deg", out.designs[c.design].name, c.attitude_sigma_deg)
            } else {
                out.designs[c.design].name.clone()
            };
            writeln!(
                w,
                "{:<14} {:>9} {:>6} {:>6} {:>6} {:>6} {} {} {} {:>10} deg",
                name,
                c.sigma_nt,
                o.ok,
                o.not_converged,
                o.not_identifiable,
                o.failed,
                pair(0),
                pair(1),
                pair(2),
                cell(s[6].summary.median)
            )?;
            if 100 * o.ok < 95 * c.trials.len() {
                writeln!(
                    w,
                    "  warning: only {} of {} trials ok ({} not converged, {} not identifiable, {} failed); statistics are over the ok ones",
                    o.ok,
                    c.trials.len(),
                    o.not_converged,
                    o.not_identifiable,
                    o.failed
                )?;
            }
        }
    }
    if let Some(runs) = &out.pso_runs {
        let v: Vec<f64> = runs.iter().map(|r| -r.fitness).collect();
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        writeln!(w, "\n{} PSO runs: final ln det M_F from {lo:.4} to {hi:.4}", v.len())?;
    }
    let times: Vec<String> = out.stages.iter().map(|(n, t)| format!("{n} {t:.3} s")).collect();
    writeln!(w, "\ntimes: {}", times.join(", "))?;
    writeln!(w, "written to {}", dir.display())?;
    Ok(())
}
