//! The design verdict as a promise: "works" is what the trials of a run then show, the design
//! recommended is one that works, and where none works the advice is computed by the same check.

use std::path::{Path, PathBuf};

use crate::common::magcal;
use magcal_runner::output::{AdviceRow, DesignMetricsRow, SummaryRow, read_csv};
use tempfile::TempDir;

fn scenario(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../scenarios/{name}.toml"))
}

fn run(args: &[&str], scenario: &Path, out: &Path) -> String {
    let output = magcal()
        .args(args)
        .arg("--out")
        .arg(out)
        .arg(scenario)
        .output()
        .unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    String::from_utf8(output.stdout).unwrap()
}

/// The ok share of `n` trials has a standard error of at most `0.5 / sqrt(n)`.
fn share_se(n: usize) -> f64 {
    0.5 / (n as f64).sqrt()
}

#[test]
fn the_vessel_at_trondheim_gets_a_plan_that_works_in_the_trials_of_a_run() {
    let dir = TempDir::new().unwrap();
    let out = dir.path().join("usv");
    let stdout = run(&["run"], &scenario("usv"), &out);
    let metrics: Vec<DesignMetricsRow> = read_csv(&out.join("design_metrics.csv")).unwrap();
    let summary: Vec<SummaryRow> = read_csv(&out.join("summary.csv")).unwrap();
    let recommended: Vec<_> = metrics.iter().filter(|m| m.recommended).collect();
    assert_eq!(recommended.len(), 1, "one design to fly");
    let fly = recommended[0];
    assert!(fly.works && fly.check_ok as f64 >= 0.95 * fly.check_trials as f64);
    assert!(
        stdout.contains(&format!("fly {}:", fly.design)),
        "the screen names the design to fly:\n{stdout}"
    );
    // Every design's verdict against its run's own trials (independent streams): a design that
    // works has an ok share within three standard errors of at least 95 %, one that fails below it.
    for m in &metrics {
        let row = summary.iter().find(|r| r.design == m.design).unwrap();
        let share = row.ok as f64 / row.trials as f64;
        let se = share_se(row.trials) + share_se(m.check_trials);
        if m.works {
            assert!(
                share >= 0.95 - 3.0 * se,
                "{}: works, yet {share} of the run ok",
                m.design
            );
        } else {
            assert!(
                share < 0.95 + 3.0 * se,
                "{}: fails, yet {share} of the run ok",
                m.design
            );
        }
    }
    // The recommended plan calibrates the heading best of those that work.
    let best = metrics
        .iter()
        .filter(|m| m.works)
        .map(|m| m.check_heading_median_deg.unwrap().0)
        .fold(f64::INFINITY, f64::min);
    assert_eq!(fly.check_heading_median_deg.unwrap().0, best);
    assert!(!out.join("advice.csv").exists(), "no advice when a design works");
}

#[test]
fn with_the_papers_residual_the_same_plan_fails_and_the_advice_is_checked() {
    let dir = TempDir::new().unwrap();
    let out = dir.path().join("usv-paper");
    let stdout = run(&["design"], &scenario("usv-paper"), &out);
    let metrics: Vec<DesignMetricsRow> = read_csv(&out.join("design_metrics.csv")).unwrap();
    let plan = metrics.iter().find(|m| m.design == "plan300").unwrap();
    // The Cramer-Rao bound alone called it identifiable; its trials do not calibrate.
    assert!(plan.identifiable && !plan.works, "{plan:?}");
    assert!(metrics.iter().all(|m| !m.recommended));
    assert!(stdout.contains("no design here calibrates the full model"), "{stdout}");
    let advice: Vec<AdviceRow> = read_csv(&out.join("advice.csv")).unwrap();
    let models: Vec<&str> = advice
        .iter()
        .filter(|a| a.option == "reduced")
        .map(|a| a.model.as_str())
        .collect();
    assert_eq!(models, ["diagonal", "axis2_held", "offsets_only"]);
    // An option works where 95 % of its trials calibrate and their heading is within the budget
    // (the diagonal model calibrates 199 of 200 and leaves the heading beyond 2 degrees), and
    // its logs flown are usable where they were flown.
    for a in &advice {
        let budget = a
            .check_budget_p95_deg
            .zip(a.heading_budget_deg)
            .is_some_and(|(p, b)| p.0 <= b.0);
        // Where its logs were flown, 18 of 20 must be usable.
        let logs = a.check_logs_usable.is_none_or(|k| k >= 18);
        assert_eq!(
            a.works,
            a.check_ok as f64 >= 0.95 * a.check_trials as f64 && budget && logs,
            "{a:?}"
        );
    }
    // The quieter sensor found works, at less noise than the scenario's.
    let quieter = advice.iter().find(|a| a.option == "quieter").unwrap();
    assert!(quieter.works && quieter.sigma_nt.0 < 50.0, "{quieter:?}");
    // A wider box that works contains the vessel's box.
    if let Some(w) = advice.iter().find(|a| a.option == "wider") {
        assert!(w.works && w.roll_min_deg.0 < -15.0 && w.pitch_max_deg.0 > 8.0, "{w:?}");
    }
}
