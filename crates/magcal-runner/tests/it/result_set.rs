//! The result set is replaced whole or not at all, and `check` gives the right verdict.

use std::fs;
use std::path::Path;

use crate::common::{leftovers, magcal, magcal_with_limits, restore, run_into, smoke, snapshot, without_manifest};
use tempfile::TempDir;

#[test]
fn a_kill_at_any_step_of_the_write_phase_leaves_one_complete_set() {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    run_into(&out, 7);
    let old = snapshot(&out);
    let reference = tmp.path().join("reference");
    run_into(&reference, 8);
    let new = without_manifest(snapshot(&reference));
    // Each file of the set is a step (the manifest and run.json too), and so is each rename of
    // the swap (two on Linux).
    let steps = new.len() + 2 + 2;
    let (mut old_seen, mut new_seen) = (0, 0);
    for k in 1..=steps {
        restore(&out, &old);
        let status = magcal()
            .env("MAGCAL_TEST_ABORT_AFTER_STEP", k.to_string())
            .args(["run", "--quiet", "--trials", "20", "--seed", "8", "--out"])
            .arg(&out)
            .arg(smoke())
            .output()
            .unwrap()
            .status;
        assert!(!status.success(), "step {k}: the hook did not abort");
        let now = snapshot(&out);
        if now == old {
            old_seen += 1;
        } else {
            let manifest: serde_json::Value = serde_json::from_slice(&now["manifest.json"]).unwrap();
            assert_eq!(manifest["seed"], 8, "step {k}: neither set");
            assert_eq!(without_manifest(now), new, "step {k}: a mixed set");
            new_seen += 1;
        }
    }
    // Killed before the swap: the old set; after it: the new one.
    assert_eq!(old_seen, new.len() + 2, "kills before the swap");
    assert_eq!(new_seen, 2, "kills after the swap");
    // A kill between the swap and the removal leaves the old set beside the target; the next
    // run removes it.
    magcal()
        .env("MAGCAL_TEST_ABORT_AFTER_STEP", (steps - 1).to_string())
        .args(["run", "--quiet", "--trials", "20", "--seed", "8", "--out"])
        .arg(&out)
        .arg(smoke())
        .assert()
        .failure();
    assert_eq!(leftovers(&out).len(), 1, "{:?}", leftovers(&out));
    run_into(&out, 7);
    assert!(leftovers(&out).is_empty(), "{:?}", leftovers(&out));
    assert_eq!(without_manifest(snapshot(&out)), without_manifest(old));
}

#[test]
fn a_full_disk_leaves_the_earlier_set_and_exits_2() {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    run_into(&out, 7);
    let old = snapshot(&out);
    // Every file may have 16 KiB: trials.csv and the figures need more.
    let assert = magcal_with_limits(crate::common::MEMORY_LIMIT, Some(16 << 10))
        .args(["run", "--quiet", "--trials", "20", "--seed", "8", "--out"])
        .arg(&out)
        .arg(smoke())
        .assert()
        .code(2);
    let stderr = String::from_utf8(assert.get_output().stderr.clone()).unwrap();
    assert!(stderr.contains("cannot write") && stderr.contains("out/"), "{stderr}");
    assert_eq!(snapshot(&out), old);
    assert!(leftovers(&out).is_empty(), "{:?}", leftovers(&out));
}

#[test]
fn nothing_of_an_earlier_set_survives_beside_a_new_one() {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    run_into(&out, 7);
    // `design` into a run's directory: no trials, summary or eta figures remain.
    magcal()
        .args(["design", "--quiet", "--out"])
        .arg(&out)
        .arg(smoke())
        .assert()
        .success();
    let files: Vec<String> = snapshot(&out).into_keys().collect();
    assert!(files.contains(&"designs.csv".to_string()) && files.contains(&"pso_runs.csv".to_string()));
    for gone in [
        "trials.csv",
        "summary.csv",
        "plots/eta_psi.png",
        "plots/noise_sweep_eta_o.svg",
    ] {
        assert!(!files.contains(&gone.to_string()), "{gone} survived: {files:?}");
    }
    // A run without [pso_runs]: no pso_runs.csv or Fig. 4 remains, and `plot` does not redraw it.
    let text = fs::read_to_string(smoke()).unwrap();
    let cut = &text[..text.find("[pso_runs]").unwrap()];
    let no_runs = tmp.path().join("no-runs.toml");
    fs::write(&no_runs, cut).unwrap();
    magcal()
        .args(["run", "--quiet", "--trials", "20", "--out"])
        .arg(&out)
        .arg(&no_runs)
        .assert()
        .success();
    magcal().arg("plot").arg(&out).assert().success();
    let files: Vec<String> = snapshot(&out).into_keys().collect();
    assert!(!files.iter().any(|f| f.contains("pso_runs")), "{files:?}");
    assert!(files.contains(&"plots/eta_psi.png".to_string()));
    assert!(leftovers(&out).is_empty() && leftovers(&out.join("plots")).is_empty());
}

/// Runs `scenario` into `out`, then checks it against itself: exit 0.
fn check_against_itself(scenario: &Path, out: &Path, trials: &str) {
    magcal()
        .args(["run", "--quiet", "--trials", trials, "--out"])
        .arg(out)
        .arg(scenario)
        .assert()
        .success();
    let assert = magcal().args(["check", "--baseline"]).arg(out).arg(scenario).assert();
    let output = assert.get_output().clone();
    assert!(
        output.status.success(),
        "{}: {}",
        scenario.display(),
        String::from_utf8_lossy(&output.stderr)
    );
    let stdout = String::from_utf8(output.stdout).unwrap();
    assert!(stdout.contains(&format!("{trials} trials")), "{stdout}");
}

#[test]
fn check_passes_on_identical_output_with_undefined_and_non_finite_values() {
    let tmp = TempDir::new().unwrap();
    let text = fs::read_to_string(smoke()).unwrap();
    let variants = [
        // Huge noise: most trials fail, some cells keep one success or none.
        text.replace("sigma_nt = [10.0, 30.0]", "sigma_nt = [1e6]"),
        // A singular explicit design: ln det M_F = -inf.
        text.replace(
            "{ roll_deg = -5.0, yaw_deg = -60.0, pitch_deg = -20.0 },\n  { roll_deg = -5.0, yaw_deg = 60.0, pitch_deg = -20.0 },",
            "{ roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = 0.0 },\n  { roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = 0.0 },",
        )
        .replacen("{ roll_deg = -5.0, yaw_deg = 180.0, pitch_deg = -20.0 }", "{ roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = 0.0 }", 1),
        // A nominal sensor: eta_psi and eta_O are undefined.
        text.replace("psi_deg = [1.5, 0.8, 1.4]", "psi_deg = [0.0, 0.0, 0.0]")
            .replace("bias_nt = [3000.0, -6000.0, 5000.0]", "bias_nt = [0.0, 0.0, 0.0]"),
    ];
    for (i, v) in variants.iter().enumerate() {
        let scenario = tmp.path().join(format!("v{i}.toml"));
        fs::write(&scenario, v).unwrap();
        check_against_itself(&scenario, &tmp.path().join(format!("out{i}")), "30");
    }
    // Results made with --trials are checked with their own trial count.
    check_against_itself(&smoke(), &tmp.path().join("few"), "25");
}

/// Replaces `column` of the first data row of `file` whose first cell is `first` with `value`.
fn edit_cell(file: &Path, first: &str, column: &str, value: &str) {
    let text = fs::read_to_string(file).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let c = lines[0].split(',').position(|h| h == column).unwrap();
    let i = lines.iter().position(|l| l.split(',').next() == Some(first)).unwrap();
    let mut cols: Vec<String> = lines[i].split(',').map(str::to_string).collect();
    cols[c] = value.to_string();
    lines[i] = cols.join(",");
    fs::write(file, lines.join("\n") + "\n").unwrap();
}

#[test]
fn check_detects_edits_of_every_file_and_rejects_a_damaged_baseline() {
    let tmp = TempDir::new().unwrap();
    let base = tmp.path().join("base");
    run_into(&base, 7);
    let pristine = snapshot(&base);
    let check = || {
        magcal()
            .args(["check", "--quiet", "--baseline"])
            .arg(&base)
            .arg(smoke())
            .assert()
    };
    check().code(0);
    for (file, first, column, value, needle) in [
        (
            "designs.csv",
            "uniform",
            "pitch_deg",
            "-19.9",
            "designs.csv uniform point ",
        ),
        // The approximate design is covered by its hash.
        ("approximate.csv", "1", "weight", "0.5", "approximate.csv"),
        // An optimiser's attitudes are not compared (see check.rs): the file's hash shows the edit.
        ("designs.csv", "optimum", "yaw_deg", "12.5", "designs.csv "),
        (
            "trials.csv",
            "pso",
            "eta_psi",
            "99",
            "baseline trials.csv vs summary.csv",
        ),
        (
            "trials.csv",
            "uniform",
            "status",
            "rank_deficient",
            "baseline trials.csv vs summary.csv uniform",
        ),
        (
            "design_metrics.csv",
            "pso",
            "ln_det_mf",
            "300",
            "design_metrics.csv pso",
        ),
        ("summary.csv", "optimum", "mean", "1000", "summary.csv optimum"),
    ] {
        restore(&base, &pristine);
        edit_cell(&base.join(file), first, column, value);
        let out = check().code(1);
        let stderr = String::from_utf8(out.get_output().stderr.clone()).unwrap();
        assert!(stderr.contains(needle), "{file} {column}: {stderr}");
        assert!(
            stderr.contains(&format!("{file:<60} edited since it was written")),
            "{file}: {stderr}"
        );
    }
    // A non-finite standard error is damage, not a licence to pass.
    restore(&base, &pristine);
    edit_cell(&base.join("summary.csv"), "optimum", "se_mean", "inf");
    let out = check().code(2);
    let stderr = String::from_utf8(out.get_output().stderr.clone()).unwrap();
    assert!(
        stderr.contains("se_mean = inf") && stderr.contains("summary.csv"),
        "{stderr}"
    );
}

#[test]
fn plot_draws_non_finite_values_as_absent_and_replaces_a_plots_file() {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    run_into(&out, 7);
    // inf in a statistic, -inf as a PSO run's final value: drawn as absent, never a hang.
    edit_cell(&out.join("summary.csv"), "uniform", "mean", "inf");
    edit_cell(&out.join("pso_runs.csv"), "0", "final_ln_det", "-inf");
    fs::remove_dir_all(out.join("plots")).unwrap();
    fs::write(out.join("plots"), "not a directory").unwrap();
    let assert = magcal()
        .arg("plot")
        .arg(&out)
        .timeout(std::time::Duration::from_secs(60))
        .assert()
        .success();
    let stdout = String::from_utf8(assert.get_output().stdout.clone()).unwrap();
    // 4 designs, 8 metrics at 30 nT, their 8 noise sweeps, Fig. 4.
    assert!(stdout.starts_with("21 figures"), "{stdout}");
    let svg = fs::read_to_string(out.join("plots/pso_runs.svg")).unwrap();
    assert!(
        svg.contains("1 not finite, not drawn"),
        "the caption counts the absent run"
    );
    assert!(leftovers(&out.join("plots")).is_empty());
}
