//! `magcal replay`: the paper's Monte Carlo on a log with reference attitudes. Where the log is
//! a simulation of the scenario's own sensor, replay must give what `run` gives; it must give the
//! same files on 1 and 2 threads; and it must refuse what it cannot replay before replacing
//! anything.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use tempfile::TempDir;

use crate::common::magcal;

/// [P1] Table II's Uniformity design (yaw_offset_deg = 90, as the paper's figures read it).
const UNIFORM: [[f64; 3]; 9] = magcal_core::paper::UNIFORMITY_DESIGN_DEG;

/// Readings of the repeated design per attitude.
const REPEATS: usize = 200;

/// A scenario at [P1]'s site and sensor with the Uniformity design and, as `repeated`, the same
/// nine attitudes `REPEATS` times each (the log to replay on).
fn scenario(dir: &Path, trials: usize) -> PathBuf {
    let list = |times: usize| -> String {
        (0..times)
            .flat_map(|_| UNIFORM.iter())
            .map(|[r, y, p]| format!("  {{ roll_deg = {r}, yaw_deg = {y}, pitch_deg = {p} }},\n"))
            .collect()
    };
    let text = format!(
        r#"schema = 1
name = "replay-agree"
seed = 7
trials = {trials}
sigma_nt = [30.0]

[field]
model = "WMM2010"
lat_deg = 28.2
lon_deg = 112.97
alt_m = 0.0
year = 2013.0
yaw_offset_deg = 90.0

[sensor]
psi_deg = [1.5, 0.8, 1.4]
scale = [1.3, 0.7, 1.2]
bias_nt = [3000.0, -6000.0, 5000.0]

[attitude_box]
roll_deg = [-5.0, 5.0]
yaw_deg = [-180.0, 180.0]
pitch_deg = [-20.0, 20.0]

[[design]]
name = "uniform"
kind = "explicit"
attitudes = [
{}]

[[design]]
name = "repeated"
kind = "explicit"
attitudes = [
{}]

[calibration]
residual = "paper"
"#,
        list(1),
        list(REPEATS)
    );
    let path = dir.join("agree.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// The rows of a CSV file as maps from column to cell.
fn rows(path: &Path) -> Vec<HashMap<String, String>> {
    let mut r = csv::Reader::from_path(path).unwrap();
    let headers = r.headers().unwrap().clone();
    r.records()
        .map(|rec| {
            let rec = rec.unwrap();
            headers
                .iter()
                .map(String::from)
                .zip(rec.iter().map(String::from))
                .collect()
        })
        .collect()
}

/// The (mean, standard error, ok) of `metric` for `design` in a summary.csv (of `run` or
/// `replay`, whose `model` must then be `full`).
fn mean_se(summary: &Path, design: &str, metric: &str) -> (f64, f64, usize) {
    let row = rows(summary)
        .into_iter()
        .find(|r| r["design"] == design && r["metric"] == metric && r.get("model").is_none_or(|m| m == "full"))
        .unwrap_or_else(|| panic!("{design} {metric} in {}", summary.display()));
    let f = |k: &str| row[k].parse::<f64>().unwrap();
    (f("mean"), f("se_mean"), row["ok"].parse().unwrap())
}

/// A simulated log of the repeated design and the arguments that replay it with the truth known.
fn simulated(dir: &Path, trials: usize) -> (PathBuf, PathBuf) {
    let scenario = scenario(dir, trials);
    let log = dir.join("log.csv");
    let o = magcal()
        .arg("simulate")
        .arg(&scenario)
        .args(["--design", "repeated", "--seed", "11", "--out"])
        .arg(&log)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    (scenario, log)
}

fn replay_args(scenario: &Path, log: &Path, out: &Path) -> Vec<String> {
    replay_with(scenario, log, out, "full")
}

fn replay_with(scenario: &Path, log: &Path, out: &Path, models: &str) -> Vec<String> {
    let mut a: Vec<String> = vec![
        "replay".into(),
        scenario.display().to_string(),
        log.display().to_string(),
    ];
    for s in [
        "--euler",
        "roll_deg,pitch_deg,true_heading_deg",
        "--units",
        "nT",
        "--truth",
        "scenario",
        "--noise",
        "30",
        "--orient",
        "none",
        "--within-deg",
        "0.1",
        "--models",
        models,
        "--quiet",
        "--out",
    ] {
        a.push(s.into());
    }
    a.push(out.display().to_string());
    a
}

#[test]
fn replay_on_a_simulated_log_gives_the_statistics_of_run() {
    // The log holds each attitude of the Uniformity design 200 times with independent noise at
    // 30 nT: a replay trial draws one of them per attitude, as `run` draws fresh noise. The mean
    // relative errors must agree within 4 combined standard errors (trials share a reading with
    // probability 1/200 per attitude: nearly independent).
    let tmp = TempDir::new().unwrap();
    let trials = 400;
    let (scenario, log) = simulated(tmp.path(), trials);
    let run = tmp.path().join("run");
    let o = magcal()
        .args(["run"])
        .arg(&scenario)
        .args(["--quiet", "--out"])
        .arg(&run)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let replayed = tmp.path().join("replay");
    let o = magcal().args(replay_args(&scenario, &log, &replayed)).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Every attitude realised by exactly its 200 readings (the fitted field's direction is
    // 0.01 degree off the true one: that much separates them from the design).
    for r in rows(&replayed.join("realisation.csv"))
        .iter()
        .filter(|r| r["design"] == "uniform")
    {
        assert_eq!(r["candidates"], REPEATS.to_string(), "{r:?}");
        assert!(r["farthest_deg"].parse::<f64>().unwrap() < 0.1, "{r:?}");
    }
    for metric in ["eta_psi", "eta_s", "eta_o"] {
        let (a, sa, oka) = mean_se(&run.join("summary.csv"), "uniform", metric);
        let (b, sb, okb) = mean_se(&replayed.join("summary.csv"), "uniform", metric);
        assert_eq!((oka, okb), (trials, trials), "{metric}");
        let z = (a - b) / (sa * sa + sb * sb).sqrt();
        assert!(z.abs() < 4.0, "{metric}: run {a} +- {sa}, replay {b} +- {sb}, z = {z}");
    }
}

#[test]
fn replay_is_the_same_on_one_and_two_threads() {
    let tmp = TempDir::new().unwrap();
    let (scenario, log) = simulated(tmp.path(), 60);
    let mut sets = Vec::new();
    for threads in ["1", "2"] {
        let out = tmp.path().join(format!("t{threads}"));
        let mut args = replay_with(&scenario, &log, &out, "full,diagonal,offset,symmetric");
        args.extend(["--threads".into(), threads.into()]);
        let o = magcal().args(&args).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        sets.push(out);
    }
    for file in ["summary.csv", "trials.csv", "realisation.csv", "whole_log.csv"] {
        let a = std::fs::read(sets[0].join(file)).unwrap();
        let b = std::fs::read(sets[1].join(file)).unwrap();
        assert!(a == b, "{file} differs between 1 and 2 threads");
    }
    // Four models, 60 trials, two designs: every outcome counted.
    let trials = rows(&sets[0].join("trials.csv"));
    assert_eq!(trials.len(), 4 * 60 * 2);
    for r in rows(&sets[0].join("summary.csv")) {
        let n = |k: &str| r[k].parse::<usize>().unwrap();
        assert_eq!(n("trials"), 60);
        assert_eq!(
            n("ok") + n("not_converged") + n("not_identifiable") + n("failed"),
            60,
            "{r:?}"
        );
    }
}

#[test]
fn replay_refuses_what_it_cannot_replay_before_replacing_anything() {
    let tmp = TempDir::new().unwrap();
    let (scenario, log) = simulated(tmp.path(), 20);
    let out = tmp.path().join("out");
    let o = magcal().args(replay_args(&scenario, &log, &out)).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let before = crate::common::snapshot(&out);
    let cases: Vec<(Vec<&str>, &str)> = vec![
        // No attitude columns.
        (vec!["--units", "nT", "--columns", "mx,my,mz"], "no attitudes"),
        // No units.
        (vec!["--euler", "roll_deg,pitch_deg,true_heading_deg"], "--units"),
        (
            vec![
                "--euler",
                "roll_deg,pitch_deg,true_heading_deg",
                "--units",
                "nT",
                "--within-deg",
                "0",
            ],
            "--within-deg 0",
        ),
        (
            vec![
                "--euler",
                "roll_deg,pitch_deg,true_heading_deg",
                "--units",
                "nT",
                "--noise",
                "-1",
            ],
            "--noise -1",
        ),
        (
            vec![
                "--euler",
                "roll_deg,pitch_deg,true_heading_deg",
                "--units",
                "nT",
                "--models",
                "full,full",
            ],
            "twice",
        ),
    ];
    for (args, words) in cases {
        let o = magcal()
            .arg("replay")
            .arg(&scenario)
            .arg(&log)
            .args(&args)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(words), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert_eq!(crate::common::snapshot(&out), before, "{args:?} changed the set");
    }
    // The log itself as the output directory's member: refused.
    let o = magcal()
        .args(replay_args(&scenario, &log, tmp.path()))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(log.is_file());
}

#[test]
fn truth_scenario_is_refused_for_a_log_that_is_not_of_the_scenarios_sensor() {
    // BROAD 02 is a maker-calibrated IMU, not [P1]'s sensor: eta against that truth would be a
    // comparison with a sensor the readings never had.
    let Some(path) = crate::common::data("broad/02_undisturbed_slow_rotation_B.csv") else {
        return;
    };
    let tmp = TempDir::new().unwrap();
    let o = magcal()
        .arg("replay")
        .arg(crate::common::scenarios().join("replay-handheld.toml"))
        .arg(&path)
        .args(crate::common::BROAD_ARGS)
        .args(["--where", "movement=1", "--truth", "scenario", "--trials", "2", "--out"])
        .arg(tmp.path().join("out"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("is not the scenario's sensor"), "{stderr}");
    assert!(!tmp.path().join("out").exists());
}
