//! End-to-end tests: the real `magcal` binary on temporary directories.

use std::fs;
use std::path::{Path, PathBuf};

use magcal_core::Attitude;
use magcal_core::CalibrationStatus;
use magcal_core::design::tour::rotation_angle;
use magcal_runner::output::{DesignPointRow, SummaryRow, TrialRow, read_csv};
use magcal_runner::pipeline::Metric;
use tempfile::TempDir;

use crate::common::{magcal, scenarios, smoke};

/// Runs the smoke scenario into `dir` with `threads`.
fn run_smoke(dir: &Path, threads: usize) {
    magcal()
        .args(["run", "--quiet", "--threads", &threads.to_string(), "--out"])
        .arg(dir)
        .arg(smoke())
        .assert()
        .success();
}

fn csv_rows(path: &Path) -> Vec<Vec<String>> {
    let mut reader = csv::Reader::from_path(path).unwrap();
    reader
        .records()
        .map(|r| r.unwrap().iter().map(str::to_string).collect())
        .collect()
}

#[test]
fn run_writes_every_file_with_the_expected_rows() {
    let tmp = TempDir::new().unwrap();
    run_smoke(tmp.path(), 2);
    for f in [
        "summary.csv",
        "trials.csv",
        "crb.csv",
        "designs.csv",
        "design_metrics.csv",
        "pso_runs.csv",
        "manifest.json",
    ] {
        assert!(tmp.path().join(f).is_file(), "{f} missing");
    }
    // 4 designs x 2 noise levels x 8 metrics, read with the runner's own typed rows.
    let summary: Vec<SummaryRow> = read_csv(&tmp.path().join("summary.csv")).unwrap();
    assert_eq!(summary.len(), 64);
    // 4 designs x 2 noise levels x 200 trials, each with a status; every outcome counted once.
    let trials: Vec<TrialRow> = read_csv(&tmp.path().join("trials.csv")).unwrap();
    assert_eq!(trials.len(), 1600);
    for row in summary.iter().filter(|r| r.metric == Metric::EtaPsi) {
        let cell: Vec<&TrialRow> = trials
            .iter()
            .filter(|t| t.design == row.design && t.sigma_nt == row.sigma_nt)
            .collect();
        let count = |s: CalibrationStatus| cell.iter().filter(|t| t.status.0 == s).count();
        assert_eq!(
            row.ok + row.not_converged + row.not_identifiable + row.failed,
            row.trials
        );
        assert_eq!(row.ok, count(CalibrationStatus::Ok));
        assert_eq!(row.not_converged, count(CalibrationStatus::NotConverged));
        assert_eq!(row.not_identifiable, count(CalibrationStatus::NotIdentifiable));
        assert_eq!(row.failed, cell.iter().filter(|t| t.eta_psi.is_none()).count());
        // The Cramer-Rao prediction sits beside every relative error.
        assert!(row.crb_rms.is_some_and(|v| v.0 > 0.0));
    }
    let crb = fs::read_to_string(tmp.path().join("crb.csv")).unwrap();
    assert_eq!(crb.lines().count(), 1 + 4 * 2 * 9);
    // Explicit designs as given, [P1] Table II, listed in visiting order: every point once, the
    // turns those between consecutive rows, and no longer in all than the order given.
    let designs: Vec<DesignPointRow> = read_csv(&tmp.path().join("designs.csv")).unwrap();
    assert_eq!(designs.len(), 36);
    for name in ["uniform", "table2_dopt", "pso", "optimum"] {
        let rows: Vec<&DesignPointRow> = designs.iter().filter(|r| r.design == name).collect();
        let mut points: Vec<usize> = rows.iter().map(|r| r.point).collect();
        points.sort_unstable();
        assert_eq!(points, (1..=9).collect::<Vec<_>>());
        assert!(
            rows.iter()
                .enumerate()
                .all(|(v, r)| r.visit == v + 1 && r.readings == 1)
        );
        let attitude = |r: &DesignPointRow| Attitude::from_degrees(r.roll_deg.0, r.yaw_deg.0, r.pitch_deg.0);
        assert!(rows[0].turn_deg.is_none());
        for w in rows.windows(2) {
            let turn = rotation_angle(&attitude(w[0]), &attitude(w[1])).to_degrees();
            assert!((w[1].turn_deg.unwrap().0 - turn).abs() < 1e-8);
        }
        let flown: f64 = rows.iter().filter_map(|r| r.turn_deg.map(|t| t.0)).sum();
        let mut by_point = rows.clone();
        by_point.sort_by_key(|r| r.point);
        let given: f64 = by_point
            .windows(2)
            .map(|w| rotation_angle(&attitude(w[0]), &attitude(w[1])).to_degrees())
            .sum();
        assert!(flown <= given + 1e-9, "{name}: {flown} > {given}");
    }
    let first = designs.iter().find(|r| r.design == "uniform" && r.point == 1).unwrap();
    assert_eq!(
        [first.roll_deg.0, first.yaw_deg.0, first.pitch_deg.0],
        [-5.0, -60.0, -20.0]
    );
    // docs/conventions.md check values through the whole pipeline.
    let metrics = csv_rows(&tmp.path().join("design_metrics.csv"));
    let ln_det = |name: &str| {
        metrics.iter().find(|r| r[0] == name).unwrap()[2]
            .parse::<f64>()
            .unwrap()
    };
    assert!((ln_det("uniform") - 303.4800).abs() < 5e-5);
    assert!((ln_det("table2_dopt") - 298.9240).abs() < 5e-5);
    assert!(ln_det("optimum") >= 314.5485);
    // The certificate through the pipeline: docs/conventions.md, the best known 9-point design is
    // 95.67 % to 95.79 % D-efficient against every 9-point design in the box.
    let typed: Vec<magcal_runner::output::DesignMetricsRow> = read_csv(&tmp.path().join("design_metrics.csv")).unwrap();
    let optimum = typed.iter().find(|r| r.design == "optimum").unwrap();
    let bound = optimum.d_efficiency_bound.unwrap().0;
    assert!((0.9567..=0.9579).contains(&bound), "{bound}");
    assert!(
        typed
            .iter()
            .all(|r| r.d_efficiency_bound.unwrap().0 <= r.d_efficiency.unwrap().0 + 1e-12)
    );
    assert_eq!(csv_rows(&tmp.path().join("pso_runs.csv")).len(), 4);
    let manifest: serde_json::Value =
        serde_json::from_slice(&fs::read(tmp.path().join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["seed"], 7);
    assert_eq!(manifest["scenario_sha256"].as_str().unwrap().len(), 64);
    // What varies between runs is in run.json, not in the manifest.
    for varies in ["threads", "command", "git_revision", "rustc", "target", "stages"] {
        assert!(manifest.get(varies).is_none(), "manifest.json records {varies}");
    }
    let record: serde_json::Value = serde_json::from_slice(&fs::read(tmp.path().join("run.json")).unwrap()).unwrap();
    assert_eq!(record["threads"], 2);
    assert_eq!(record["manifest_sha256"], manifest["manifest_sha256"]);
    assert_eq!(record["stages"].as_array().unwrap().last().unwrap()[0], "total");
}

#[test]
fn same_seed_gives_byte_identical_csv_on_one_and_several_threads() {
    let dirs: Vec<TempDir> = (0..3).map(|_| TempDir::new().unwrap()).collect();
    for (threads, dir) in [1, 2, 3].into_iter().zip(&dirs) {
        run_smoke(dir.path(), threads);
    }
    for f in [
        "summary.csv",
        "trials.csv",
        "designs.csv",
        "design_metrics.csv",
        "pso_runs.csv",
        "approximate.csv",
        "certificate.csv",
        "manifest.json",
    ] {
        let one = fs::read(dirs[0].path().join(f)).unwrap();
        for d in &dirs[1..] {
            assert_eq!(one, fs::read(d.path().join(f)).unwrap(), "{f} differs");
        }
    }
    for (threads, dir) in [1, 2, 3].into_iter().zip(&dirs) {
        let record: serde_json::Value =
            serde_json::from_slice(&fs::read(dir.path().join("run.json")).unwrap()).unwrap();
        assert_eq!(record["threads"], threads);
    }
}

#[test]
fn execution_error_adds_cells_and_leaves_the_commanded_ones_unchanged() {
    // The smoke scenario with attitude_sigma_deg = [0, 2]: the 0 cells are the trials of the plain
    // run, bit for bit (same streams); the 2-degree cells are new trials of the same designs.
    let plain = TempDir::new().unwrap();
    run_smoke(plain.path(), 2);
    let text = fs::read_to_string(smoke()).unwrap().replacen(
        "sigma_nt = [10.0, 30.0]",
        "sigma_nt = [10.0, 30.0]\nattitude_sigma_deg = [0.0, 2.0]",
        1,
    );
    let dir = TempDir::new().unwrap();
    let scenario = dir.path().join("smoke-flown.toml");
    fs::write(&scenario, text).unwrap();
    let out = dir.path().join("out");
    magcal()
        .args(["run", "--quiet", "--out"])
        .arg(&out)
        .arg(&scenario)
        .assert()
        .success();
    let base: Vec<TrialRow> = read_csv(&plain.path().join("trials.csv")).unwrap();
    let both: Vec<TrialRow> = read_csv(&out.join("trials.csv")).unwrap();
    assert_eq!(both.len(), 2 * base.len());
    let commanded: Vec<&TrialRow> = both.iter().filter(|t| t.attitude_sigma_deg.0 == 0.0).collect();
    assert_eq!(commanded.len(), base.len());
    for (a, b) in base.iter().zip(commanded) {
        assert_eq!(a, b);
    }
    let flown: Vec<&TrialRow> = both.iter().filter(|t| t.attitude_sigma_deg.0 == 2.0).collect();
    assert_eq!(flown.len(), base.len());
    let differ = base.iter().zip(&flown).filter(|(a, b)| a.eta_psi != b.eta_psi).count();
    assert!(differ > base.len() * 9 / 10, "{differ} of {}", base.len());
    let summary: Vec<SummaryRow> = read_csv(&out.join("summary.csv")).unwrap();
    assert_eq!(
        summary.iter().filter(|r| r.attitude_sigma_deg.0 == 2.0).count(),
        summary.len() / 2
    );
    // One Cramer-Rao bound per design and noise level.
    let crb = fs::read_to_string(out.join("crb.csv")).unwrap();
    assert_eq!(crb.lines().count(), 1 + 4 * 2 * 9);
}

#[test]
fn seed_override_changes_the_trials() {
    let (a, b) = (TempDir::new().unwrap(), TempDir::new().unwrap());
    run_smoke(a.path(), 2);
    magcal()
        .args(["run", "--quiet", "--seed", "8", "--out"])
        .arg(b.path())
        .arg(smoke())
        .assert()
        .success();
    assert_ne!(
        fs::read(a.path().join("trials.csv")).unwrap(),
        fs::read(b.path().join("trials.csv")).unwrap()
    );
}

#[test]
fn check_passes_on_its_own_results_and_fails_when_they_move() {
    let tmp = TempDir::new().unwrap();
    run_smoke(tmp.path(), 2);
    magcal()
        .args(["check", "--quiet", "--baseline"])
        .arg(tmp.path())
        .arg(smoke())
        .assert()
        .code(0);

    // Move one deterministic number (ln det of the pso design) by 1e-2: far beyond 1e-6 relative.
    let path = tmp.path().join("design_metrics.csv");
    let text = fs::read_to_string(&path).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let i = lines.iter().position(|l| l.starts_with("pso,")).unwrap();
    let mut cols: Vec<String> = lines[i].split(',').map(str::to_string).collect();
    cols[2] = (cols[2].parse::<f64>().unwrap() + 1e-2).to_string();
    lines[i] = cols.join(",");
    fs::write(&path, lines.join("\n") + "\n").unwrap();
    let out = magcal()
        .args(["check", "--quiet", "--baseline"])
        .arg(tmp.path())
        .arg(smoke())
        .assert()
        .code(1);
    let stderr = String::from_utf8(out.get_output().stderr.clone()).unwrap();
    assert!(
        stderr.contains("design_metrics.csv pso") && stderr.contains("ln_det_mf"),
        "{stderr}"
    );
}

#[test]
fn design_command_writes_designs_only() {
    let tmp = TempDir::new().unwrap();
    magcal()
        .args(["design", "--quiet", "--out"])
        .arg(tmp.path())
        .arg(smoke())
        .assert()
        .success();
    assert!(tmp.path().join("designs.csv").is_file() && tmp.path().join("design_metrics.csv").is_file());
    assert!(!tmp.path().join("summary.csv").exists() && !tmp.path().join("trials.csv").exists());
}

/// The `[field]` components of the smoke scenario, replaced to move it.
const SMOKE_FIELD: &str = "north_nt = 35272.34\neast_nt = -2085.74\ndown_nt = 32897.67\nyaw_offset_deg = 0.0";

/// Runs `magcal design` on `scenario` into `dir`; its stdout.
fn design_stdout(scenario: &Path, dir: &Path) -> String {
    let out = magcal()
        .args(["design", "--plans", "--out"])
        .arg(dir)
        .arg(scenario)
        .assert()
        .success();
    String::from_utf8(out.get_output().stdout.clone()).unwrap()
}

/// `a - b` as an angle, degrees, in [0, 180].
fn angle_apart(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    d.min(360.0 - d)
}

#[test]
fn design_gives_magnetic_headings_at_cape_town() {
    use magcal_core::wmm;
    let tmp = TempDir::new().unwrap();
    // Cape Town, WMM2025: a declination of about -26 degrees, so true and magnetic headings are
    // far apart; a yaw offset of 30 so that the true heading is not minus the yaw.
    let scenario = edited_from(
        &smoke(),
        tmp.path(),
        SMOKE_FIELD,
        "model = \"WMM2025\"\nlat_deg = -33.92\nlon_deg = 18.42\nalt_m = 0.0\nyear = 2026.0\nyaw_offset_deg = 30.0",
    );
    let site = wmm::Site {
        lat_deg: -33.92,
        lon_deg: 18.42,
        alt_m: 0.0,
        year: 2026.0,
    };
    // The declination from the model's own X (north) and Y (east): the angle of the horizontal
    // field east of north.
    let [x, y, _] = wmm::field_ned(wmm::Model::Wmm2025, &site).unwrap();
    let declination = y.atan2(x).to_degrees();
    assert!((-28.0..-24.0).contains(&declination), "{declination}");

    let out = tmp.path().join("set");
    let stdout = design_stdout(&scenario, &out);
    let line = format!(
        "declination {declination:+.2} deg (WMM2025 at 33.92 S, 18.42 E, 0 m, 2026.00); magnetic heading = true heading - declination"
    );
    assert!(stdout.lines().any(|l| l == line.as_str()), "{stdout}");
    assert!(stdout.contains("true_hdg   mag_hdg"), "{stdout}");

    let rows: Vec<DesignPointRow> = read_csv(&out.join("designs.csv")).unwrap();
    assert_eq!(rows.len(), 4 * 9);
    for r in &rows {
        // True heading from the yaw ([P1] eq. (2): positive yaw turns the nose west), magnetic
        // heading from it; each written to 1e-9 degree.
        let true_heading = -(r.yaw_deg.0 + 30.0);
        assert!(angle_apart(r.true_heading_deg.0, true_heading) <= 2e-9, "{r:?}");
        let magnetic = r.magnetic_heading_deg.expect("a magnetic heading").0;
        assert!(
            angle_apart(magnetic, r.true_heading_deg.0 - declination) <= 2e-9,
            "{r:?}"
        );
        assert!((0.0..360.0).contains(&magnetic) && (0.0..360.0).contains(&r.true_heading_deg.0));
    }
    // The screen shows the same numbers as the file, to 0.01 degree: the first attitude of the
    // first plan.
    let first = &rows[0];
    let shown = stdout
        .lines()
        .find(|l| l.trim_start().starts_with("1 "))
        .unwrap()
        .split_whitespace()
        .map(|v| v.parse::<f64>().unwrap_or(f64::NAN))
        .collect::<Vec<_>>();
    assert!(
        (shown[3] - first.true_heading_deg.0).abs() <= 0.005 + 1e-9,
        "{shown:?} {first:?}"
    );
    assert!(
        (shown[4] - first.magnetic_heading_deg.unwrap().0).abs() <= 0.005 + 1e-9,
        "{shown:?} {first:?}"
    );
}

#[test]
fn design_says_where_the_declination_comes_from_or_why_there_is_none() {
    let tmp = TempDir::new().unwrap();
    // The paper's field as NED components: the declination is that of the components,
    // atan2(-2085.74, 35272.34) = -3.38 degrees.
    let stdout = design_stdout(&smoke(), &tmp.path().join("ned"));
    let declination = (-2085.74f64).atan2(35272.34).to_degrees();
    let line = format!("declination {declination:+.2} deg (field.north_nt, east_nt, down_nt)");
    assert!(stdout.lines().any(|l| l.starts_with(&line)), "{stdout}");
    // A vertical field has no declination: no magnetic heading is written or shown.
    let vertical = edited_from(
        &smoke(),
        tmp.path(),
        SMOKE_FIELD,
        "north_nt = 0.0\neast_nt = 0.0\ndown_nt = 50000.0\nyaw_offset_deg = 0.0",
    );
    let out = tmp.path().join("vertical");
    let stdout = design_stdout(&vertical, &out);
    assert!(
        stdout.lines().any(|l| l.starts_with("declination undefined")),
        "{stdout}"
    );
    let rows: Vec<DesignPointRow> = read_csv(&out.join("designs.csv")).unwrap();
    assert!(!rows.is_empty() && rows.iter().all(|r| r.magnetic_heading_deg.is_none()));
    let raw = csv_rows(&out.join("designs.csv"));
    assert!(raw.iter().all(|r| r[7].is_empty()), "{:?}", raw[0]);
}

#[test]
fn help_and_usage() {
    for sub in ["run", "design", "check"] {
        magcal().args([sub, "--help"]).assert().code(0);
    }
    magcal().arg("frobnicate").assert().code(2);
    magcal().args(["run"]).assert().code(2);
    // A usage error in clap's layout: the message with the flag as given, the usage line, the
    // pointer to --help.
    let out = magcal().args(["calibrate", "x.csv", "--bogus"]).output().unwrap();
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert_eq!(out.status.code(), Some(2));
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(
        lines[0], "magcal: error: unexpected argument '--bogus' found",
        "{stderr}"
    );
    assert!(
        lines.iter().any(|l| l.starts_with("Usage: magcal calibrate ")),
        "{stderr}"
    );
    assert_eq!(lines.last(), Some(&"For more information, try '--help'."), "{stderr}");
    // The top-level help groups the commands by task within 100 columns.
    let help = String::from_utf8(magcal().arg("--help").output().unwrap().stdout).unwrap();
    let headings: Vec<&str> = help
        .lines()
        .filter(|l| !l.starts_with(' ') && l.ends_with(':'))
        .collect();
    assert_eq!(
        headings,
        [
            "Plan a vehicle's calibration:",
            "Calibrate a log:",
            "Judge a calibration:",
            "Look at a result:",
            "Reproduce and check [P1]:",
            "Shell:",
            "Options:"
        ],
        "{help}"
    );
    assert!(help.lines().all(|l| l.chars().count() <= 100), "{help}");
}

#[test]
fn completions_for_every_shell_and_a_man_page_with_every_command() {
    for shell in ["bash", "zsh", "fish", "elvish", "powershell"] {
        let out = magcal().args(["completions", shell]).output().unwrap();
        assert_eq!(out.status.code(), Some(0), "{shell}");
        let script = String::from_utf8(out.stdout).unwrap();
        for word in ["calibrate", "--fit", "completions"] {
            assert!(script.contains(word), "{shell}: {word}");
        }
        // Bash's, zsh's and fish's completions offer a flag's values too.
        assert!(
            !["bash", "zsh", "fish"].contains(&shell) || script.contains("vector-diagonal"),
            "{shell}"
        );
    }
    let out = magcal().arg("man").output().unwrap();
    assert_eq!(out.status.code(), Some(0));
    let page = String::from_utf8(out.stdout).unwrap();
    assert!(
        page.starts_with(".ie") && page.contains(".TH magcal 1"),
        "{}",
        &page[..200]
    );
    for command in ["design", "calibrate", "export", "evaluate", "next", "report", "replay"] {
        let heading = format!(".SH \"MAGCAL {}\"", command.to_uppercase());
        assert_eq!(page.matches(&heading).count(), 1, "{heading}");
    }
    assert!(page.contains("vector\\-diagonal"), "the --fit values are in the page");
}

#[test]
fn design_prints_its_recommendation_first_then_the_table_and_the_recommended_plan() {
    let tmp = TempDir::new().unwrap();
    // The vessel's: a plan of 1000 readings (the smoke scenario's 9-reading designs work but
    // hold no fifth out, and none is recommended; the vessel's 300 readings fail the budget).
    let out = magcal()
        .args(["design", "--out"])
        .arg(tmp.path().join("set"))
        .arg(crate::common::scenarios().join("usv.toml"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0));
    let stdout = String::from_utf8(out.stdout).unwrap();
    let first = stdout.lines().next().unwrap();
    assert!(
        first.starts_with("fly plan1000: 1000 readings at 11 attitudes"),
        "{stdout}"
    );
    let plans: Vec<&str> = stdout.lines().filter(|l| l.starts_with("flight plan ")).collect();
    assert_eq!(plans.len(), 1, "{stdout}");
    assert!(
        plans[0].starts_with("flight plan plan1000 (11 attitudes, 1000 readings"),
        "{stdout}"
    );
    let table = stdout.lines().position(|l| l.starts_with("design ")).unwrap();
    let plan = stdout.lines().position(|l| l.starts_with("flight plan ")).unwrap();
    assert!(table < plan, "{stdout}");
    assert!(
        stdout.contains("(--plans prints every design's flight plan"),
        "{stdout}"
    );
}

#[test]
fn a_log_on_standard_input_calibrates_as_the_file_does() {
    let tmp = TempDir::new().unwrap();
    let log = tmp.path().join("log.csv");
    magcal()
        .args(["simulate", "--design", "optimum", "--seed", "3", "--out"])
        .arg(&log)
        .arg(smoke())
        .assert()
        .success();
    let from_file = magcal().args(["calibrate", "--json"]).arg(&log).output().unwrap();
    let piped = magcal()
        .args(["calibrate", "-", "--json"])
        .write_stdin(fs::read(&log).unwrap())
        .output()
        .unwrap();
    let redirected = std::process::Command::new(env!("CARGO_BIN_EXE_magcal"))
        .args(["calibrate", "-", "--json"])
        .stdin(fs::File::open(&log).unwrap())
        .output()
        .unwrap();
    let json = |o: &std::process::Output| -> serde_json::Value {
        let mut v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        v.as_object_mut().unwrap().remove("log");
        v
    };
    assert_eq!(from_file.status.code(), piped.status.code());
    assert_eq!(json(&from_file), json(&piped));
    assert_eq!(json(&from_file), json(&redirected));
    assert_eq!(json(&piped)["bias"], json(&from_file)["bias"]);
    let shown: serde_json::Value = serde_json::from_slice(&piped.stdout).unwrap();
    assert_eq!(shown["log"], "/dev/stdin");
}

/// A copy of `source` with `from` replaced by `to` (which must occur).
fn edited_from(source: &Path, dir: &Path, from: &str, to: &str) -> PathBuf {
    static COUNT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let text = fs::read_to_string(source).unwrap();
    assert!(text.contains(from), "{from:?} not in {}", source.display());
    let n = COUNT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let path = dir.join(format!("edited{n}.toml"));
    fs::write(&path, text.replacen(from, to, 1)).unwrap();
    path
}

#[test]
fn wmm_site_gives_the_conventions_field() {
    let tmp = TempDir::new().unwrap();
    // wu2014 with a small swarm and one PSO run: only the field matters here.
    let quick = edited_from(&scenarios().join("wu2014.toml"), tmp.path(), "runs = 100", "runs = 1");
    let quick = edited_from(
        &quick,
        tmp.path(),
        "kind = \"pso\"\nm = 9",
        "kind = \"pso\"\nm = 9\nparticles = 20\niterations = 20",
    );
    let out = tmp.path().join("out");
    magcal()
        .args(["design", "--quiet", "--out"])
        .arg(&out)
        .arg(&quick)
        .assert()
        .success();
    let manifest: serde_json::Value = serde_json::from_slice(&fs::read(out.join("manifest.json")).unwrap()).unwrap();
    let ned: Vec<f64> = manifest["field_ned_nt"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    // docs/conventions.md check value, to the 0.01 nT printed there.
    for (got, want) in ned.iter().zip([35272.34, -2085.74, 32897.67]) {
        assert!((got - want).abs() <= 0.005, "{ned:?}");
    }
}

#[test]
fn run_draws_every_figure_as_valid_non_blank_png_and_svg() {
    let tmp = TempDir::new().unwrap();
    run_smoke(tmp.path(), 2);
    let plots = tmp.path().join("plots");
    let mut stems: Vec<String> = vec!["eta_psi", "eta_s", "eta_o", "pso_runs"]
        .into_iter()
        .map(String::from)
        .collect();
    stems.extend(
        ["uniform", "table2_dopt", "pso", "optimum"]
            .iter()
            .map(|d| format!("design_{d}")),
    );
    // Two noise levels: the sweep is drawn too.
    stems.extend(["eta_psi", "eta_s", "eta_o"].iter().map(|m| format!("noise_sweep_{m}")));
    for stem in &stems {
        let png = image::open(plots.join(format!("{stem}.png")))
            .unwrap_or_else(|e| panic!("{stem}.png: {e}"))
            .to_rgb8();
        assert_eq!(png.dimensions(), (960, 600), "{stem}");
        // Not blank: a white background with a substantial share of drawn (non-white) pixels.
        let drawn = png.pixels().filter(|p| p.0 != [255, 255, 255]).count();
        let share = drawn as f64 / (960.0 * 600.0);
        assert!(share > 0.01 && share < 0.9, "{stem}.png: {share} of pixels drawn");
        let svg = fs::read_to_string(plots.join(format!("{stem}.svg"))).unwrap();
        assert!(
            svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>") && svg.contains("<text"),
            "{stem}.svg"
        );
    }
}

#[test]
fn plot_redraws_from_csv_and_names_a_bad_file() {
    let tmp = TempDir::new().unwrap();
    run_smoke(tmp.path(), 2);
    fs::remove_dir_all(tmp.path().join("plots")).unwrap();
    magcal().arg("plot").arg(tmp.path()).assert().success();
    assert!(tmp.path().join("plots/eta_psi.png").is_file());

    // A malformed number in summary.csv: exit 2, the file and the value named, no panic.
    let summary = tmp.path().join("summary.csv");
    let text = fs::read_to_string(&summary).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let mut cols: Vec<String> = lines[1].split(',').map(str::to_string).collect();
    cols[5] = "twelve".into();
    lines[1] = cols.join(",");
    fs::write(&summary, lines.join("\n")).unwrap();
    let out = magcal().arg("plot").arg(tmp.path()).assert().code(2);
    let stderr = String::from_utf8(out.get_output().stderr.clone()).unwrap();
    assert!(
        stderr.contains("summary.csv") && stderr.contains("\"twelve\"") && !stderr.contains("panicked"),
        "{stderr}"
    );

    // A missing file.
    fs::remove_file(tmp.path().join("designs.csv")).unwrap();
    let out = magcal().arg("plot").arg(tmp.path()).assert().code(2);
    let stderr = String::from_utf8(out.get_output().stderr.clone()).unwrap();
    assert!(
        stderr.contains("designs.csv") && stderr.contains("cannot read"),
        "{stderr}"
    );
}

#[test]
fn the_verdict_on_the_three_vehicles() {
    use magcal_runner::output::DesignMetricsRow;
    let tmp = TempDir::new().unwrap();
    let verdicts = |scenario: &str| -> Vec<DesignMetricsRow> {
        let out = tmp.path().join(scenario);
        magcal()
            .args(["design", "--quiet", "--out"])
            .arg(&out)
            .arg(scenarios().join(format!("{scenario}.toml")))
            .assert()
            .success();
        read_csv(&out.join("design_metrics.csv")).unwrap()
    };
    // Level within a degree: no design identifies the up axis's scale and bias.
    let ground = verdicts("ground-vehicle");
    assert_eq!(ground.len(), 3);
    for d in &ground {
        assert!(!d.identifiable, "{}: {}", d.design, d.weakest);
    }
    let optimum = ground.iter().find(|d| d.design == "optimum12").unwrap();
    assert!(
        optimum
            .weakest
            .starts_with("scale and bias of sensor axis 2 (up) are confounded"),
        "{}",
        optimum.weakest
    );
    // Every attitude, a nominal sensor: identifiable.
    assert!(verdicts("drone").iter().all(|d| d.identifiable));
    // The ship: its optimised designs are identifiable, a random one is not; the best design of
    // the run is identifiable.
    let ship = verdicts("ship");
    for (name, identifiable) in [("optimum9", true), ("optimum20", true), ("random20", false)] {
        let d = ship.iter().find(|d| d.design == name).unwrap();
        assert_eq!(d.identifiable, identifiable, "{name}: {}", d.weakest);
    }
    assert!(ship.iter().filter(|d| d.best_in_run).all(|d| d.identifiable));
}

#[test]
fn plans_keep_to_their_limits_and_their_certified_efficiency() {
    use magcal_runner::output::{CertificateRow, DesignMetricsRow};
    let tmp = TempDir::new().unwrap();
    // The drone (every attitude): an approximate design of 37 support points. Plans of 300
    // readings at the default limit (12 attitudes), without a limit, and at 9 attitudes by
    // asking 33 readings at each.
    let mut text = fs::read_to_string(scenarios().join("drone.toml")).unwrap();
    text.push_str(
        "\n[[design]]\nname = \"plan12\"\nkind = \"plan\"\nreadings = 300\n\
         \n[[design]]\nname = \"plan_all\"\nkind = \"plan\"\nreadings = 300\nmax_attitudes = \"all\"\n\
         \n[[design]]\nname = \"plan_r33\"\nkind = \"plan\"\nreadings = 300\nmin_readings_per_attitude = 33\n",
    );
    let scenario = tmp.path().join("drone-plans.toml");
    fs::write(&scenario, text).unwrap();
    let out = tmp.path().join("out");
    magcal()
        .args(["design", "--quiet", "--out"])
        .arg(&out)
        .arg(&scenario)
        .assert()
        .success();
    let points: Vec<DesignPointRow> = read_csv(&out.join("designs.csv")).unwrap();
    let metrics: Vec<DesignMetricsRow> = read_csv(&out.join("design_metrics.csv")).unwrap();
    let certificate: Vec<CertificateRow> = read_csv(&out.join("certificate.csv")).unwrap();
    let support = certificate[0].support_points;
    assert!(support > 12, "{support}");
    let bound_per_reading = certificate[0].ln_det_bound_per_reading.0;
    let plan = |name: &str| -> (Vec<usize>, f64) {
        let readings = points.iter().filter(|p| p.design == name).map(|p| p.readings).collect();
        let m = metrics.iter().find(|d| d.design == name).unwrap();
        assert_eq!(m.m, 300);
        // design_metrics.csv's certified efficiency is Atwood's bound of certificate.csv:
        // exp((ln det M_F - 9 ln m - bound per reading) / 9), to the rounding of exp and ln.
        let bound = m.d_efficiency_bound.as_ref().unwrap().0;
        let want = ((m.ln_det_mf.0 - 9.0 * 300f64.ln() - bound_per_reading) / 9.0).exp();
        assert!((bound - want).abs() <= 64.0 * f64::EPSILON, "{name}: {bound} {want}");
        assert!(bound <= 1.0, "{name}: {bound}");
        (readings, bound)
    };
    let (twelve, twelve_bound) = plan("plan12");
    let (all, all_bound) = plan("plan_all");
    let (nine, nine_bound) = plan("plan_r33");
    for readings in [&twelve, &all, &nine] {
        assert_eq!(readings.iter().sum::<usize>(), 300);
    }
    assert_eq!(twelve.len(), 12);
    assert_eq!(all.len(), support);
    assert_eq!(nine.len(), 9);
    assert!(nine.iter().all(|&n| n >= 33), "{nine:?}");
    // Measured on this box: the dozen attitudes are certified 0.99999993 efficient, above the
    // rounding of all 37 support points (0.99909); 9 attitudes cost 2.3 % (0.97692). The plans
    // converge to about 1e-9 in efficiency (see magcal-core's design::plan tests); 1e-6 allows
    // another optimum that close.
    assert!(twelve_bound >= 0.9999999 - 1e-6, "{twelve_bound}");
    assert!(twelve_bound >= all_bound, "{twelve_bound} {all_bound}");
    assert!(
        nine_bound >= 0.976918 - 1e-6 && nine_bound < twelve_bound,
        "{nine_bound}"
    );
}
