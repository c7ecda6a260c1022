//! The loop from plan to calibration: the design `magcal design` recommends, flown (simulated by
//! `magcal simulate`) and calibrated by `magcal calibrate`, gives usable logs as often as design's
//! check calibrated it; a design that `design` calls FAILS gives logs that are not usable.
//!
//! Each vehicle runs `design`, then simulates [`SEEDS`] logs of the recommended design and of the
//! vehicle's failing design (seeds 1 to [`SEEDS`], the first of the 50 that `scripts/loop.py`
//! runs for the README's table) and calibrates each with `--magnitude R`, R the field magnitude
//! simulate prints. The bounds are statistical (README "Does the loop hold?"):
//! - recommended: the usable share within [`Z`] standard errors of design's check share, the
//!   standard error that of the difference of two binomial shares (check trials, logs) at their
//!   pooled share, the null being that both are one share `p`. Where both shares are 0 or both 1
//!   the difference and its standard error are 0 and the bound holds. With 200 of 200 check
//!   trials ok and 10 logs every log must be usable (9 of 10 is 4.5 standard errors away; with the
//!   script's 50 logs, 48 must be).
//! - failing: not usable in at least the lower [`Z`]-standard-error limit of a binomial of the
//!   logs each refused with probability [`REFUSED_P`] ("most": 7 of 10, 39 of 50), and the usable
//!   share not above design's check share by more than [`Z`] pooled standard errors (a log's fit
//!   is one trial of its design, so it cannot be usable more often than the design's trials are
//!   `ok`).
//!
//! Each vehicle is one test, so that the harness runs them side by side.

use std::path::Path;

use magcal_runner::output::{DesignMetricsRow, read_csv};
use tempfile::TempDir;

use crate::common::{calibrate_json, magcal, scenarios};

/// Logs per design.
const SEEDS: u64 = 10;
/// Standard errors a share may lie from its null.
const Z: f64 = 3.0;
/// The least probability with which a log of a failing design is refused that "most" means.
const REFUSED_P: f64 = 0.9;

/// `x2 / n2 - x1 / n1` in standard errors of the difference of two binomial shares at their
/// pooled share; 0 where both shares are 0 or both 1.
fn pooled_z(x1: usize, n1: usize, x2: usize, n2: usize) -> f64 {
    let (x1, n1, x2, n2) = (x1 as f64, n1 as f64, x2 as f64, n2 as f64);
    let p = (x1 + x2) / (n1 + n2);
    let se = (p * (1.0 - p) * (1.0 / n1 + 1.0 / n2)).sqrt();
    let diff = x2 / n2 - x1 / n1;
    if se == 0.0 { 0.0 } else { diff / se }
}

/// The fewest not-usable logs of `n` that "most are refused" allows.
fn min_refused(n: usize) -> usize {
    let n = n as f64;
    (REFUSED_P * n - Z * (REFUSED_P * (1.0 - REFUSED_P) * n).sqrt()).ceil() as usize
}

/// One calibrated log: its seed, exit code, `usable`, the log's own check and the first reason.
struct Log {
    seed: u64,
    code: Option<i32>,
    usable: bool,
    check: String,
    reason: String,
}

impl std::fmt::Debug for Log {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "seed {}: exit {:?}, usable {}, check {}; {}",
            self.seed, self.code, self.usable, self.check, self.reason
        )
    }
}

/// The scenario NAME: `dir`'s `NAME.toml` where a test wrote one, else the shipped one.
fn scenario(name: &str, dir: &Path) -> std::path::PathBuf {
    let own = dir.join(format!("{name}.toml"));
    if own.exists() {
        own
    } else {
        scenarios().join(format!("{name}.toml"))
    }
}

/// `magcal design scenarios/NAME.toml`: its design metrics.
fn design(name: &str, dir: &Path) -> Vec<DesignMetricsRow> {
    let out = dir.join(format!("design-{name}"));
    let o = magcal()
        .arg("design")
        .arg(scenario(name, dir))
        .args(["--quiet", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    read_csv(&out.join("design_metrics.csv")).unwrap()
}

/// A log of design `design` of scenario `name` with noise seed `seed`, calibrated.
fn flown(name: &str, design: &str, seed: u64, dir: &Path) -> Log {
    let log = dir.join(format!("{name}-{design}-{seed}.csv"));
    let o = magcal()
        .arg("simulate")
        .arg(scenario(name, dir))
        .args(["--design", design, "--seed", &seed.to_string(), "--out"])
        .arg(&log)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let magnitude = stderr
        .split("--magnitude ")
        .nth(1)
        .map(|v| v.trim_end_matches(|c: char| c == ')' || c.is_whitespace()))
        .unwrap_or_else(|| panic!("no magnitude in {stderr}"))
        .to_string();
    // Judged over the scenario's box and in its field, as design judged the plan.
    let scenario = scenario(name, dir);
    let (code, c, stderr) = calibrate_json(
        &log,
        &["--magnitude", &magnitude, "--scenario", scenario.to_str().unwrap()],
    );
    // Exit 0 is a calibration to use, 3 one that is not; anything else is no answer.
    assert_eq!(
        code,
        Some(if c.usable { 0 } else { 3 }),
        "{name} {design} seed {seed}: {stderr}"
    );
    Log {
        seed,
        code,
        usable: c.usable,
        check: c
            .check
            .map_or("none".to_string(), |k| format!("{} of {}", k.ok, k.trials)),
        reason: c.reasons.first().cloned().unwrap_or_default(),
    }
}

/// Runs the loop for vehicle `name`: its recommended design must give usable logs as often as
/// design's check share says, and `failing` (a design that `design` calls FAILS), where given,
/// logs that are mostly not usable.
fn the_loop_holds(name: &str, failing: Option<&str>) {
    let dir = TempDir::new().unwrap();
    let metrics = design(name, dir.path());
    let recommended: Vec<&DesignMetricsRow> = metrics.iter().filter(|m| m.recommended).collect();
    assert_eq!(recommended.len(), 1, "{name}: one design to fly");
    let mut judged = vec![(recommended[0], true)];
    if let Some(f) = failing {
        let m = metrics.iter().find(|m| m.design == f).unwrap();
        assert!(
            !m.works,
            "{name} {f}: design says it works ({} of {})",
            m.check_ok, m.check_trials
        );
        judged.push((m, false));
    }
    for (m, works) in judged {
        let logs: Vec<Log> = (1..=SEEDS).map(|s| flown(name, &m.design, s, dir.path())).collect();
        let n = logs.len();
        let usable = logs.iter().filter(|l| l.usable).count();
        // Against the logs design flew where it flew them, else its check trials.
        let (said_ok, said_of) = m
            .check_logs_usable
            .zip(m.check_logs)
            .unwrap_or((m.check_ok, m.check_trials));
        let z = pooled_z(said_ok, said_of, usable, n);
        let said = format!(
            "{name} {}: design's check {said_ok} of {said_of}, {usable} of {n} logs usable (z = {z:+.2})\n{logs:#?}",
            m.design
        );
        if works {
            assert!(z.abs() <= Z, "{said}");
        } else {
            assert!(n - usable >= min_refused(n) && z <= Z, "{said}");
        }
    }
}

#[test]
fn the_bounds_are_those_the_readme_states() {
    // 200 of 200 check trials: every one of 10 logs, 48 of 50.
    assert!(pooled_z(200, 200, 10, 10).abs() <= Z && pooled_z(200, 200, 9, 10).abs() > Z);
    assert!(pooled_z(200, 200, 48, 50).abs() <= Z && pooled_z(200, 200, 47, 50).abs() > Z);
    assert_eq!(min_refused(10), 7);
    assert_eq!(min_refused(50), 39);
    // A design no trial calibrates: 2 usable logs of 50 are within the bound, 3 are not.
    assert!(pooled_z(0, 200, 2, 50) <= Z && pooled_z(0, 200, 3, 50) > Z);
}

#[test]
fn the_vessels_plan_calibrates_when_flown_and_its_random_design_does_not() {
    the_loop_holds("usv", Some("random12"));
}

#[test]
fn the_ships_designs_fail_the_heading_budget_and_are_refused_when_flown() {
    // The ship barely tilts (roll +-10, pitch +-5 degrees at 57 N): its grid calibrates in 200
    // of 200 check trials, but leaves 4.5 degrees of heading at the 95th percentile over its box,
    // beyond the budget of 2; no design works, and the logs of the grid are refused.
    refused_when_flown("ship", "grid36");
}

#[test]
fn the_drones_optimum_calibrates_when_flown() {
    // Every attitude: every design of the drone works, none to fly that fails.
    the_loop_holds("drone", None);
}

#[test]
fn the_auvs_plan_calibrates_when_flown() {
    // [P1]'s AUV; plan300.toml fits with the default residual (the readings'), as calibrate does.
    the_loop_holds("plan300", None);
}

#[test]
fn the_gliders_plan_calibrates_when_flown_and_its_surface_circles_do_not() {
    the_loop_holds("glider", Some("surface12"));
}

/// A rover on rough ground: roll and pitch within +-3 degrees, the ground vehicle's sensor and
/// field, two plans of the same attitudes.
const ROVER: &str = r#"schema = 1
name = "rover"
seed = 2026
sigma_nt = 30.0

[field]
model = "WMM2025"
lat_deg = 48.14
lon_deg = 11.58
alt_m = 520.0
year = 2026.5

[sensor]
psi_deg = [1.5, 0.8, 1.4]
scale = [1.3, 0.7, 1.2]
bias_nt = [3000.0, -6000.0, 5000.0]

[attitude_box]
roll_deg = [-3.0, 3.0]
yaw_deg = [-180.0, 180.0]
pitch_deg = [-3.0, 3.0]

[[design]]
name = "plan500"
kind = "plan"
readings = 500

[[design]]
name = "plan1000"
kind = "plan"
readings = 1000
"#;

#[test]
fn a_plan_whose_logs_calibrate_would_refuse_is_not_recommended() {
    // 500 readings in the rover's box leave 1.5 degrees at the 95/95 figure in truth, within the
    // budget of 2; but a log judges its heading by its own estimate, which runs along the up
    // axis's valley of scale and bias, and calibrate refuses many of them. Design flies 20 logs
    // and says so; the logs flown here agree with its count (pooled binomial shares), and the
    // plan of 1000 readings is recommended.
    let dir = TempDir::new().unwrap();
    std::fs::write(dir.path().join("rover.toml"), ROVER).unwrap();
    let metrics = design("rover", dir.path());
    let row = |d: &str| metrics.iter().find(|m| m.design == d).unwrap();
    let short = row("plan500");
    let budget = short.heading_budget_deg.unwrap().0;
    assert!(short.check_budget_p95_deg.unwrap().0 <= budget, "{short:?}");
    assert_eq!(short.check_logs, Some(20), "{short:?}");
    let said = short.check_logs_usable.unwrap();
    assert!(said < 18 && !short.works && !short.recommended, "{short:?}");
    let logs: Vec<Log> = (1..=SEEDS).map(|s| flown("rover", "plan500", s, dir.path())).collect();
    let usable = logs.iter().filter(|l| l.usable).count();
    let z = pooled_z(said, 20, usable, logs.len());
    assert!(
        z.abs() <= Z,
        "design {said} of 20, flown {usable} of {} (z = {z:+.2}): {logs:#?}",
        logs.len()
    );
    assert!(usable < logs.len(), "every log of plan500 usable: {logs:#?}");
    assert!(row("plan1000").recommended && row("plan1000").check_logs_usable >= Some(18));
}

#[test]
fn the_ground_vehicles_optimum_is_refused_when_flown() {
    // No design of the level box works; its optimum calibrates in 18 of 200 check trials.
    refused_when_flown("ground-vehicle", "optimum12");
}

/// No design of vehicle `name` works, and the logs of `design` flown are refused (most of them,
/// and not more often usable than its check trials are ok).
fn refused_when_flown(name: &str, design_name: &str) {
    let dir = TempDir::new().unwrap();
    let metrics = design(name, dir.path());
    assert!(metrics.iter().all(|m| !m.recommended && !m.works));
    let m = metrics.iter().find(|m| m.design == design_name).unwrap();
    let logs: Vec<Log> = (1..=SEEDS).map(|s| flown(name, design_name, s, dir.path())).collect();
    let usable = logs.iter().filter(|l| l.usable).count();
    let z = pooled_z(m.check_ok, m.check_trials, usable, logs.len());
    assert!(
        logs.len() - usable >= min_refused(logs.len()) && z <= Z,
        "{} of {} check trials, {usable} usable (z = {z:+.2}): {logs:#?}",
        m.check_ok,
        m.check_trials
    );
}
