//! The table `run` and `design` print on stdout, written to any `io::Write` so that a failed
//! write is an error.

use std::io::Write;
use std::path::Path;

use magcal_logs::text::significant;
pub use magcal_report::rows::cells::declination_line;

use crate::pipeline::advice::Advice;
use crate::pipeline::{Check, RunOutput};

/// A statistic for the screen: `-` where undefined.
fn cell(x: f64) -> String {
    if x.is_nan() { "-".into() } else { format!("{x:.3}") }
}

/// Rows of a flight plan shown on the screen per design; the rest are in `designs.csv`.
const FLIGHT_PLAN_ROWS: usize = 40;

/// Each design (or only design `only`) as a pilot flies it: the attitudes in visiting order with
/// roll, pitch, the true and the magnetic heading of the nose, the readings to log there and the
/// turn from the previous attitude; under one line naming the declination and its source.
pub fn flight_plans(
    w: &mut dyn Write,
    out: &RunOutput,
    headings: crate::output::Headings,
    field_source: &str,
    only: Option<usize>,
) -> std::io::Result<()> {
    let rows: Vec<_> = crate::output::design_rows(out, headings).collect();
    writeln!(w, "{}", declination_line(headings.declination_deg, field_source))?;
    for (_, d) in out
        .designs
        .iter()
        .enumerate()
        .filter(|(i, _)| only.is_none_or(|o| o == *i))
    {
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
                "  {:>5} {:>9.2} {:>9.2} {:>9} {:>9} {:>8} {:>9}",
                r.visit,
                r.roll_deg.0,
                r.pitch_deg.0,
                crate::output::compass_text(r.true_heading_deg.0, 2),
                r.magnetic_heading_deg
                    .map_or("-".to_string(), |h| crate::output::compass_text(h.0, 2)),
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

/// Where designs work but none gives a log of the readings held-out fits need: which, and to fly
/// them as a plan.
fn too_few_readings(w: &mut dyn Write, out: &RunOutput) -> std::io::Result<()> {
    let fewest = magcal_core::log_fit::min_held_out_readings(magcal_core::log_fit::FitModel::Full);
    let small: Vec<&str> = out
        .designs
        .iter()
        .filter(|d| d.check.works())
        .map(|d| d.name.as_str())
        .collect();
    let (names, verb) = match small.split_last() {
        Some((last, [])) => (last.to_string(), "works"),
        Some((last, rest)) => (format!("{} and {last}", rest.join(", ")), "work"),
        None => (String::new(), "works"),
    };
    writeln!(
        w,
        "no design here gives a log calibrate can call usable: {names} {verb}, but a log of fewer than {fewest} readings holds no fifth out to vouch for its calibration; fly its attitudes as a plan (kind = \"plan\", readings = 100 or more)."
    )
}

/// What to fly: the design that works (calibrates in at least 95 % of its check's trials and keeps
/// the heading within the budget) and gives a log held-out fits can vouch for, with the smallest
/// heading error, the fewer readings on a tie; or, when none does, that none does and why.
pub fn recommendation(w: &mut dyn Write, out: &RunOutput, advice: Option<&Advice>) -> std::io::Result<()> {
    match out.recommended() {
        Some(i) => {
            let d = &out.designs[i];
            let c = &d.check;
            writeln!(
                w,
                "fly {}: {} readings at {} attitudes (its flight plan is in designs.csv). At {} nT it \
                 calibrated in {} of {} trials; heading error 95th percentile {} deg over the box at every \
                 heading, within the budget of {} deg{}{}.",
                d.name,
                d.m(),
                d.attitudes.len(),
                c.sigma_nt,
                c.outcomes.ok,
                c.trials,
                c.budget_p95_deg.map_or("-".into(), |v| format!("{v:.3}")),
                crate::limits::show(c.budget_deg),
                logs_words(c),
                out.d_efficiency_bound(i)
                    .map_or(String::new(), |e| format!("; certified D-efficiency >= {e:.4}"))
            )
        }
        None if out.designs.iter().any(|d| d.check.works()) => too_few_readings(w, out),
        None => no_design_works(w, out, advice),
    }
}

/// "; 19 of 20 logs of it flown usable by calibrate" where design flew logs of the design.
fn logs_words(c: &Check) -> String {
    c.logs_usable.map_or(String::new(), |k| {
        format!("; {k} of {} logs of it flown usable by calibrate", Check::LOGS)
    })
}

/// Where no design works: that, and the advice (what works instead, by the same check).
fn no_design_works(w: &mut dyn Write, out: &RunOutput, advice: Option<&Advice>) -> std::io::Result<()> {
    let budget = out.designs.first().map_or(0.0, |d| d.check.budget_deg);
    // A design whose trials meet the budget but whose logs do not: said, lest "no design" read
    // as no design coming near it.
    let near = out
        .designs
        .iter()
        .find(|d| d.check.calibrates() && d.check.truth_meets_budget())
        .and_then(|d| d.check.logs_usable.map(|k| (d, k)))
        .map_or(String::new(), |(d, k)| {
            format!(
                " ({} meets it in its trials, but {k} of {} logs of it flown are usable by calibrate, not the {} needed)",
                d.name,
                Check::LOGS,
                Check::LOGS_USABLE
            )
        });
    writeln!(
        w,
        "no design here calibrates the full model in {:.0} % of trials at this noise with the heading within the budget of {} deg{near}.",
        100.0 * Check::OK_SHARE,
        crate::limits::show(budget)
    )?;
    let Some(a) = advice else { return Ok(()) };
    let base = &out.designs[a.base];
    let flown = match a.passes {
        1 => String::new(),
        n => format!(
            ", flown {n} times over: {} readings, enough for a log to hold a fifth out",
            n * base.m()
        ),
    };
    writeln!(
        w,
        "What works instead, by the same check, from {} ({} readings{flown}):",
        base.name,
        base.m()
    )?;
    let heading = |c: &Check| {
        format!(
            "{} of {} trials ok at {} nT, heading error 95th percentile {} deg over the box (budget {} deg){}",
            c.outcomes.ok,
            c.trials,
            significant(c.sigma_nt, 3),
            c.budget_p95_deg.map_or("-".into(), |v| format!("{v:.3}")),
            crate::limits::show(c.budget_deg),
            logs_words(c),
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
             {} D-optimal attitudes x {} reading{}: {}",
            v.extra_deg,
            v.roll_deg[0],
            v.roll_deg[1],
            v.pitch_deg[0],
            v.pitch_deg[1],
            v.attitudes.len(),
            v.readings_per_attitude,
            if v.readings_per_attitude == 1 { "" } else { "s" },
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
        let heading = c.budget_p95_deg.map_or(String::new(), |p| {
            let logs = c.logs_usable.map_or(String::new(), |k| {
                format!(", {k} of {} of its logs usable by calibrate", Check::LOGS)
            });
            format!(
                ", heading {} deg at the 95th percentile{logs} (budget {})",
                significant(p, 3),
                crate::limits::show(c.budget_deg)
            )
        });
        let verdict = match (c.works(), c.calibrates(), d.verdict.identifiable) {
            (true, _, _) => format!("works: {share}{heading}"),
            (false, true, _) => format!("FAILS THE HEADING BUDGET: {share}{heading}"),
            (false, false, true) => format!("FAILS: only {share} ({})", outcome_words(&c.outcomes)),
            (false, false, false) => format!("NOT IDENTIFIABLE: {}; {share}", d.verdict.weakest),
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
        cells(w, out)?;
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

/// The trials of every cell: outcome counts, the medians of the relative errors beside their
/// Cramer-Rao rms, the heading median, and a warning under a cell where fewer than 95 % are `ok`.
fn cells(w: &mut dyn Write, out: &RunOutput) -> std::io::Result<()> {
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
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::sync::OnceLock;

    use magcal_core::CalibrationStatus;

    use super::*;
    use crate::output::Headings;
    use crate::pipeline::advice::{Reduced, Widening};
    use crate::pipeline::{Outcomes, RunOptions};

    /// Two explicit designs of the smoke scenario ([P1] Table II) at one noise level, 40 trials.
    const SCENARIO: &str = r#"
schema = 1
name = "print"
seed = 7
trials = 40
sigma_nt = [30.0]

[field]
north_nt = 35272.34
east_nt = -2085.74
down_nt = 32897.67

[sensor]
psi_deg = [1.5, 0.8, 1.4]
scale = [1.3, 0.7, 1.2]
bias_nt = [3000.0, -6000.0, 5000.0]

[attitude_box]
roll_deg = [-5.0, 5.0]
yaw_deg = [-180.0, 180.0]
pitch_deg = [-20.0, 20.0]

# The Uniformity design leaves about 5 degrees of heading over this box (95 % of its trials, 95th
# percentile over the attitudes): it works at a budget of 8.
[verdict]
heading_budget_deg = 8.0

[[design]]
name = "uniform"
kind = "explicit"
attitudes = [
  { roll_deg = -5.0, yaw_deg = -60.0, pitch_deg = -20.0 },
  { roll_deg = -5.0, yaw_deg = 60.0, pitch_deg = -20.0 },
  { roll_deg = -5.0, yaw_deg = 180.0, pitch_deg = -20.0 },
  { roll_deg = 0.0, yaw_deg = -90.0, pitch_deg = 0.0 },
  { roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = 0.0 },
  { roll_deg = 0.0, yaw_deg = 90.0, pitch_deg = 0.0 },
  { roll_deg = 0.0, yaw_deg = 180.0, pitch_deg = 0.0 },
  { roll_deg = 5.0, yaw_deg = -60.0, pitch_deg = 20.0 },
  { roll_deg = 5.0, yaw_deg = 60.0, pitch_deg = 20.0 },
]

[[design]]
name = "table2_dopt"
kind = "explicit"
attitudes = [
  { roll_deg = -5.0, yaw_deg = -37.0, pitch_deg = -20.0 },
  { roll_deg = -5.0, yaw_deg = -145.0, pitch_deg = -20.0 },
  { roll_deg = -5.0, yaw_deg = -10.0, pitch_deg = -6.0 },
  { roll_deg = 0.0, yaw_deg = 24.5, pitch_deg = 20.0 },
  { roll_deg = -3.2, yaw_deg = -96.0, pitch_deg = 7.0 },
  { roll_deg = -1.3, yaw_deg = 178.0, pitch_deg = -20.0 },
  { roll_deg = -1.4, yaw_deg = 180.0, pitch_deg = -20.0 },
  { roll_deg = 2.1, yaw_deg = -35.0, pitch_deg = 20.0 },
  { roll_deg = -5.0, yaw_deg = -137.5, pitch_deg = 20.0 },
]
"#;

    /// The run of [`SCENARIO`] (computed once for every test here), its headings and field source.
    fn run() -> (RunOutput, Headings, String) {
        static RUN: OnceLock<(RunOutput, Headings, String)> = OnceLock::new();
        RUN.get_or_init(|| {
            let scenario = crate::scenario::parse(SCENARIO.as_bytes(), Path::new("print.toml")).unwrap();
            let options = RunOptions {
                progress: &crate::pipeline::Quiet,
                designs_only: false,
            };
            let out = crate::pipeline::run(&scenario, options).unwrap();
            (out, Headings::of(&scenario.field), scenario.field_source.clone())
        })
        .clone()
    }

    fn text(write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> String {
        let mut bytes = Vec::new();
        write(&mut bytes).unwrap();
        String::from_utf8(bytes).unwrap()
    }

    /// Asserts that `printed` is `value` rounded to `decimals` places: within half a unit of the
    /// last place, plus the rounding of the subtraction.
    #[track_caller]
    fn rounded(printed: &str, value: f64, decimals: i32) {
        let p: f64 = printed
            .parse()
            .unwrap_or_else(|_| panic!("{printed:?} is not a number"));
        let half = 0.5 * 10f64.powi(-decimals);
        assert!(
            (p - value).abs() <= half + 4.0 * f64::EPSILON * value.abs(),
            "{printed} is not {value} to {decimals} places"
        );
    }

    /// The byte offsets at which the right-aligned columns of the design table end.
    const DESIGN_COLUMN_ENDS: [usize; 4] = [19, 30, 40, 50];

    #[test]
    fn the_design_table_has_a_header_and_one_row_per_design_with_its_numbers() {
        let (out, _, _) = run();
        let printed = text(|w| summary(w, &out, Path::new("results/print")));
        let lines: Vec<&str> = printed.lines().collect();
        let a = out.approximate.as_ref().expect("the box identifies the linear model");
        let certificate = lines[0]
            .strip_prefix("certificate: no design of m readings in this box has ln det M_F above 9 ln m + ")
            .unwrap_or_else(|| panic!("{}", lines[0]));
        let (bound, rest) = certificate.split_once(' ').unwrap();
        rounded(bound, a.certificate.ln_det_bound, 4);
        assert!(
            rest.starts_with(&format!("(approximate design of {} points, d_max = ", a.support.len())),
            "{rest}"
        );
        let header = "design            m ln det M_F     D-eff certified  verdict";
        assert_eq!(lines[1], header);
        for end in DESIGN_COLUMN_ENDS {
            assert_ne!(header.as_bytes()[end - 1], b' ', "{header}: {end}");
        }
        assert_eq!(out.designs.len(), 2);
        for (i, d) in out.designs.iter().enumerate() {
            let row = lines[2 + i];
            // Right-aligned under the header.
            for end in DESIGN_COLUMN_ENDS {
                assert!(
                    row.as_bytes()[end - 1] != b' ' && row.as_bytes()[end] == b' ',
                    "{row}: {end}"
                );
            }
            assert_eq!(row[..14].trim_end(), d.name);
            let cells: Vec<&str> = row[14..].split_whitespace().collect();
            assert_eq!(cells[0], "9");
            rounded(cells[1], d.ln_det_mf, 4);
            rounded(cells[2], out.d_efficiency(i), 4);
            assert_eq!(cells[3], ">=");
            rounded(cells[4], out.d_efficiency_bound(i).unwrap(), 4);
            let c = &d.check;
            let share = format!("{} of {} trials ok at 30 nT", c.outcomes.ok, c.trials);
            // The Uniformity design calibrates every trial of its check; the design of [P1]
            // Table II as printed leaves the bias of axis 3 confounded in this box, and most of
            // its trials say so.
            match d.name.as_str() {
                "uniform" => {
                    assert!(c.works() && d.verdict.identifiable);
                    assert_eq!(c.outcomes.ok, c.trials);
                    let heading = format!(
                        ", heading {} deg at the 95th percentile (budget 8)",
                        significant(c.budget_p95_deg.unwrap(), 3)
                    );
                    assert!(c.budget_p95_deg.unwrap() > 3.0 && c.budget_p95_deg.unwrap() < 8.0);
                    assert_eq!(row[52..], format!("works: {share}{heading}"));
                }
                _ => {
                    assert!(!c.works() && !d.verdict.identifiable);
                    assert!(d.verdict.weakest.contains("bias of axis 3"), "{}", d.verdict.weakest);
                    assert_eq!(row[52..], format!("NOT IDENTIFIABLE: {}; {share}", d.verdict.weakest));
                }
            }
        }
        // The trials' table: one row per design and noise level.
        assert_eq!(lines[4], "");
        assert_eq!(
            lines[5],
            "design          sigma_nt     ok n.conv n.ident failed eta_psi med/crb %   eta_S med/crb %   \
             eta_O med/crb %  heading med"
        );
        assert_eq!(out.cells.len(), 2);
        let mut at = 6;
        for c in &out.cells {
            let row = lines[at];
            let cells: Vec<&str> = row.split_whitespace().collect();
            assert_eq!(cells[0], out.designs[c.design].name);
            let o = c.outcomes();
            let counts = [o.ok, o.not_converged, o.not_identifiable, o.failed].map(|n| n.to_string());
            assert_eq!(cells[1], "30");
            assert_eq!(cells[2..6], counts, "{row}");
            assert_eq!(o.ok + o.not_converged + o.not_identifiable + o.failed, 40);
            let s = c.summaries();
            for (j, pair) in cells[6..9].iter().enumerate() {
                let (median, crb) = pair.split_once('/').unwrap();
                rounded(median, s[j].summary.median, 3);
                rounded(crb, s[j].metric.predicted_rms(&c.bound).unwrap(), 3);
            }
            rounded(cells[9], s[6].summary.median, 3);
            assert_eq!(cells[10], "deg");
            assert_eq!(cells.len(), 11);
            at += 1;
            // A warning under a cell where fewer than 95 % of the trials are ok.
            if 100 * o.ok < 95 * 40 {
                assert_eq!(
                    lines[at],
                    format!(
                        "  warning: only {} of 40 trials ok ({} not converged, {} not identifiable, {} failed); \
                         statistics are over the ok ones",
                        o.ok, o.not_converged, o.not_identifiable, o.failed
                    )
                );
                at += 1;
            }
        }
        // The Table II design's cell has the warning.
        assert_eq!(at, 9);
        assert!(
            lines[at].is_empty() && lines[at + 1].starts_with("times: "),
            "{printed}"
        );
        assert_eq!(lines[at + 2], "written to results/print");
        assert_eq!(lines.len(), at + 3);
    }

    #[test]
    fn failing_designs_undefined_statistics_and_a_missing_certificate_read_as_such() {
        let (mut out, _, _) = run();
        // The Cramer-Rao rms beside each median: a prediction, which the trials do not change.
        let crb: Vec<String> = out.cells[0]
            .summaries()
            .iter()
            .take(3)
            .map(|s| format!("-/{:.3}", s.metric.predicted_rms(&out.cells[0].bound).unwrap()))
            .collect();
        out.approximate = None;
        // The Uniformity design calibrates 90 % of its check's trials; the Table II design is
        // called identifiable (and still fails its check).
        let c = &mut out.designs[0].check;
        c.outcomes = Outcomes {
            ok: c.trials - 20,
            not_converged: 5,
            not_identifiable: 0,
            failed: 15,
        };
        let trials = c.trials;
        out.designs[1].verdict.identifiable = true;
        let table2 = out.designs[1].check.outcomes;
        // Every trial of the Uniformity design's cell failed.
        for t in &mut out.cells[0].trials {
            t.status = CalibrationStatus::RankDeficient;
        }
        let printed = text(|w| summary(w, &out, Path::new("r")));
        let lines: Vec<&str> = printed.lines().collect();
        assert_eq!(
            lines[0],
            "certificate: none (no design in this box identifies the linear model)"
        );
        let verdict = |row: &str| {
            assert_eq!(row[41..50].trim_start(), "-", "{row}");
            row[52..].to_string()
        };
        assert_eq!(
            verdict(lines[2]),
            format!(
                "FAILS: only {} of {trials} trials ok at 30 nT (5 not converged, 0 not identifiable, 15 failed)",
                trials - 20
            )
        );
        assert_eq!(
            verdict(lines[3]),
            format!(
                "FAILS: only {} of {trials} trials ok at 30 nT ({} not converged, {} not identifiable, {} failed)",
                table2.ok, table2.not_converged, table2.not_identifiable, table2.failed
            )
        );
        let failed: Vec<&str> = lines[6].split_whitespace().collect();
        assert_eq!(failed[..6], ["uniform", "30", "0", "0", "0", "40"]);
        assert_eq!(failed[6..9], crb);
        assert_eq!(failed[9..], ["-", "deg"]);
        assert_eq!(
            lines[7],
            "  warning: only 0 of 40 trials ok (0 not converged, 0 not identifiable, 40 failed); statistics are over the ok ones"
        );
        assert!(lines[8].starts_with("table2_dopt "), "{}", lines[8]);
        assert!(lines[9].starts_with("  warning: only "), "{}", lines[9]);
    }

    #[test]
    fn the_recommendation_names_the_design_to_fly_or_what_works_instead() {
        let (mut out, _, _) = run();
        // The Uniformity design is the one that works (see the design table's test), but nine
        // readings hold no fifth out: nothing to fly, and the line says why.
        assert_eq!(out.recommended(), None);
        assert_eq!(
            text(|w| recommendation(w, &out, None)),
            "no design here gives a log calibrate can call usable: uniform works, but a log of fewer than 23 readings holds no fifth out to vouch for its calibration; fly its attitudes as a plan (kind = \"plan\", readings = 100 or more).\n"
        );
        // Flown three times at each attitude (27 readings), it is the one to fly.
        out.designs[0].readings = vec![3; 9];
        let i = out.recommended().expect("a design works");
        assert_eq!(i, 0);
        let d = &out.designs[i];
        let printed = text(|w| recommendation(w, &out, None));
        let line = printed.strip_suffix(".\n").unwrap();
        let head = format!(
            "fly {}: 27 readings at 9 attitudes (its flight plan is in designs.csv). At 30 nT it calibrated in {} of {} \
             trials; heading error 95th percentile ",
            d.name, d.check.trials, d.check.trials
        );
        let rest = line.strip_prefix(&head).unwrap_or_else(|| panic!("{line}"));
        let (p95, rest) = rest
            .split_once(" deg over the box at every heading, within the budget of 8 deg; certified D-efficiency >= ")
            .unwrap_or_else(|| panic!("{line}"));
        rounded(p95, d.check.budget_p95_deg.unwrap(), 3);
        rounded(rest, out.d_efficiency_bound(i).unwrap(), 4);

        // None works: one line, and with advice a line per alternative.
        let works = out.designs[0].check.clone();
        for d in &mut out.designs {
            d.check.outcomes.ok = 0;
        }
        assert_eq!(out.recommended(), None);
        let none = "no design here calibrates the full model in 95 % of trials at this noise with the heading within the budget of 8 deg.";
        assert_eq!(text(|w| recommendation(w, &out, None)), format!("{none}\n"));
        let failing = out.designs[0].check.clone();
        let quieter = Check {
            sigma_nt: 7.5,
            ..works.clone()
        };
        let wider = Widening {
            extra_deg: 10.0,
            roll_deg: [-15.0, 15.0],
            pitch_deg: [-30.0, 30.0],
            attitudes: out.designs[0].attitudes.clone(),
            readings_per_attitude: 2,
            check: works.clone(),
        };
        let mut advice = Advice {
            base: 0,
            passes: 1,
            reduced: vec![
                (Reduced::Diagonal, works.clone()),
                (Reduced::OffsetsOnly, failing.clone()),
            ],
            quieter: Some(quieter),
            wider: Some(wider),
        };
        let printed = text(|w| recommendation(w, &out, Some(&advice)));
        let lines: Vec<&str> = printed.lines().collect();
        let heading = |c: &Check| {
            format!(
                "{} of {} trials ok at {} nT, heading error 95th percentile {:.3} deg over the box (budget 8 deg){}",
                c.outcomes.ok,
                c.trials,
                significant(c.sigma_nt, 3),
                c.budget_p95_deg.unwrap(),
                logs_words(c)
            )
        };
        assert_eq!(lines[0], none);
        assert_eq!(
            lines[1],
            "What works instead, by the same check, from uniform (27 readings):"
        );
        assert_eq!(
            lines[2],
            format!(
                "  - non-orthogonality held at 0 (diagonal model): works: {}",
                heading(&works)
            )
        );
        assert!(lines[2].contains(" of 200 trials ok at 30.0 nT, "), "{}", lines[2]);
        assert_eq!(
            lines[3],
            format!(
                "  - offsets only, scales held at the scenario's values: does not work: {}",
                heading(&failing)
            )
        );
        assert_eq!(
            lines[4],
            format!(
                "  - the full model with a quieter sensor: works at 7.50 nT (4.00x less noise): {}",
                heading(&Check {
                    sigma_nt: 7.5,
                    ..works.clone()
                })
            )
        );
        assert_eq!(
            lines[5],
            format!(
                "  - the full model in a wider box: tilting 10 deg further (roll -15 to 15, pitch -30 to 30 deg), \
                 9 D-optimal attitudes x 2 readings: {}",
                heading(&works)
            )
        );
        assert_eq!(
            lines[6],
            "  (advice.csv has each; to fly the wider box, set its ranges in the scenario and run design again)"
        );
        assert_eq!(lines.len(), 7);
        // A base design too short for a log to hold a fifth out is checked flown more than once.
        advice.passes = 2;
        let printed = text(|w| recommendation(w, &out, Some(&advice)));
        assert_eq!(
            printed.lines().nth(1),
            Some(
                "What works instead, by the same check, from uniform (27 readings, flown 2 times over: 54 readings, enough for a log to hold a fifth out):"
            )
        );
        advice.quieter = None;
        advice.wider = None;
        advice.reduced.clear();
        let printed = text(|w| recommendation(w, &out, Some(&advice)));
        let lines: Vec<&str> = printed.lines().collect();
        assert_eq!(
            lines[2..],
            [
                "  - the full model with a quieter sensor: not even at 1/1024 of the noise",
                "  - the full model in a wider box: not even with 90 degrees more tilt",
                "  (advice.csv has each; to fly the wider box, set its ranges in the scenario and run design again)",
            ]
        );
    }

    #[test]
    fn flight_plans_list_every_attitude_in_visiting_order_and_cut_long_plans() {
        let (mut out, headings, source) = run();
        let printed = text(|w| flight_plans(w, &out, headings, &source, None));
        let lines: Vec<&str> = printed.lines().collect();
        assert_eq!(lines[0], declination_line(headings.declination_deg, &source));
        let declination = headings.declination_deg.unwrap();
        assert!(lines[0].starts_with(&format!("declination {declination:+.2} deg (")));
        let rows: Vec<_> = crate::output::design_rows(&out, headings).collect();
        let mut at = 1;
        for d in &out.designs {
            let plan: Vec<_> = rows.iter().filter(|r| r.design == d.name).collect();
            let turning: f64 = plan.iter().filter_map(|r| r.turn_deg).map(|t| t.0).sum();
            let title = lines[at]
                .strip_prefix(&format!("flight plan {} (9 attitudes, 9 readings, ", d.name))
                .unwrap_or_else(|| panic!("{}", lines[at]));
            rounded(title.strip_suffix(" deg of turning in all):").unwrap(), turning, 0);
            assert_eq!(
                lines[at + 1],
                "  visit  roll_deg pitch_deg  true_hdg   mag_hdg readings  turn_deg"
            );
            for (v, r) in plan.iter().enumerate() {
                let cells: Vec<&str> = lines[at + 2 + v].split_whitespace().collect();
                assert_eq!(cells[0], (v + 1).to_string());
                rounded(cells[1], r.roll_deg.0, 2);
                rounded(cells[2], r.pitch_deg.0, 2);
                rounded(cells[3], r.true_heading_deg.0, 2);
                rounded(cells[4], r.magnetic_heading_deg.unwrap().0, 2);
                assert_eq!(cells[5], "1");
                match r.turn_deg {
                    None => assert_eq!((v, cells[6]), (0, "-")),
                    Some(t) => rounded(cells[6], t.0, 1),
                }
            }
            assert_eq!(lines[at + 11], "");
            at += 12;
        }
        assert_eq!(lines.len(), at);

        // A plan of 45 attitudes shows 40, and no field direction leaves no magnetic heading.
        let d = &mut out.designs[0];
        d.attitudes = (0..45).map(|k| d.attitudes[k % 9]).collect();
        d.readings = vec![1; 45];
        d.order = (0..45).collect();
        let level = Headings {
            declination_deg: None,
            ..headings
        };
        let printed = text(|w| flight_plans(w, &out, level, "a vertical field", None));
        let lines: Vec<&str> = printed.lines().collect();
        assert_eq!(
            lines[0],
            "declination undefined: the field (a vertical field) has no horizontal component, so a compass has no heading; true headings only"
        );
        assert!(lines[1].starts_with("flight plan uniform (45 attitudes, 45 readings, "));
        for v in 0..40 {
            let cells: Vec<&str> = lines[3 + v].split_whitespace().collect();
            assert_eq!((cells[0], cells[4]), ((v + 1).to_string().as_str(), "-"));
        }
        assert_eq!(lines[43], "  ... 5 more in designs.csv");
        assert_eq!(lines[44], "");
        assert!(lines[45].starts_with("flight plan table2_dopt (9 attitudes"));
    }

    #[test]
    fn a_failed_write_is_an_error_of_every_table() {
        let (out, headings, source) = run();
        let full = |write: &dyn Fn(&mut dyn Write) -> std::io::Result<()>| {
            let mut room = [0u8; 64];
            let e = write(&mut &mut room[..]).unwrap_err();
            assert_eq!(e.kind(), std::io::ErrorKind::WriteZero);
        };
        full(&|w| summary(w, &out, Path::new("r")));
        full(&|w| recommendation(w, &out, None));
        full(&|w| flight_plans(w, &out, headings, &source, None));
    }
}
