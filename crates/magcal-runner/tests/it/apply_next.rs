//! `apply` and `next` take only a calibration that fits the log: the calibration file records what
//! it was made from and is checked before use, the log is read with the calibration's columns, and
//! its radius under the calibration is compared with the magnitude. On the public logs of
//! `../shared/data/` (skipped, saying so, where that folder is absent) and on edits of them.

use std::fs;
use std::path::{Path, PathBuf};

use crate::common::{assert_refused, data, edited, magcal};
use magcal_runner::log::calibration::{CalibrationJson, FORMAT, MAX_CONDITION, read_calibration};
use sha2::{Digest, Sha256};
use tempfile::TempDir;

const CK: &str = "ck-explorer/acc_mag_log.csv";
const H1: &str = "hamagure/data-set_1.csv";
const H2: &str = "hamagure/data-set_2.csv";

fn scenario(name: &str) -> PathBuf {
    crate::common::scenarios().join(format!("{name}.toml"))
}

/// `calibrate LOG ARGS --out DIR`: the calibration file it wrote (exit 0, or 3 for a calibration
/// not to use, which is written all the same).
fn calibrate(log: &Path, args: &[&str], dir: &Path) -> PathBuf {
    let out = magcal()
        .arg("calibrate")
        .arg(log)
        .args(args)
        .arg("--out")
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        matches!(out.status.code(), Some(0 | 3)),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir.join("calibration.json")
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&fs::read(path).unwrap()).unwrap()
}

/// Runs `magcal ARGS`: exit code, stdout, stderr.
fn run(args: &[&std::ffi::OsStr]) -> (i32, String, String) {
    let out = magcal().args(args).output().unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    )
}

/// The median of `|P (raw - bias)|` over `readings`, computed here from the JSON's `p` and `bias`.
fn median_radius(cal: &CalibrationJson, readings: &[[f64; 3]]) -> f64 {
    let mut r: Vec<f64> = readings
        .iter()
        .map(|s| {
            let d = [0, 1, 2].map(|i| s[i] - cal.bias[i]);
            let b = [0, 1, 2].map(|i| (0..3).map(|j| cal.p[i][j] * d[j]).sum::<f64>());
            (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt()
        })
        .collect();
    r.sort_by(f64::total_cmp);
    r[(r.len() - 1) / 2]
}

/// Columns 4-6 (`mx,my,mz`) of the ck-explorer log, times `factor`.
fn ck_readings(log: &Path, factor: f64) -> Vec<[f64; 3]> {
    fs::read_to_string(log)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|c| c.parse().unwrap()).collect();
            [v[3] * factor, v[4] * factor, v[5] * factor]
        })
        .collect()
}

/// The numbers in `text`, in order.
fn numbers(text: &str) -> Vec<f64> {
    text.split(|c: char| c.is_whitespace() || c == ',' || c == '(' || c == ')' || c == ';')
        .filter_map(|w| w.parse().ok())
        .collect()
}

#[test]
fn a_calibration_records_what_it_was_made_from_and_every_public_fit_passes_the_checks() {
    let Some(ck) = data(CK) else { return };
    let tmp = TempDir::new().unwrap();
    let wmm = ["--site", "28.2,112.97", "--date", "2013.0", "--units", "G"];
    let path = calibrate(&ck, &wmm, &tmp.path().join("ck"));
    let j = json(&path);
    assert_eq!(j["format"], FORMAT);
    assert_eq!(j["magcal_version"], env!("CARGO_PKG_VERSION"));
    let sha: String = Sha256::digest(fs::read(&ck).unwrap())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    assert_eq!(j["log_sha256"], sha.as_str());
    assert_eq!(j["log_rows"], 12_000);
    assert_eq!(j["units"], "G");
    assert_eq!(j["columns"], serde_json::json!(["mx", "my", "mz"]));
    // Without --units the units are unknown, and say so.
    let path = calibrate(&ck, &[], &tmp.path().join("ck-relative"));
    assert!(json(&path)["units"].is_null());
    // Every fit of the public logs that calibrate writes passes the checks, the runaway full fit
    // of the constrained log (hamagure set 2) too: its condition number is the largest.
    let mut conditions = Vec::new();
    for (log, fit) in [
        (CK, "full"),
        (H1, "full"),
        (H2, "full"),
        (H2, "diagonal"),
        (H2, "offset"),
        (H2, "auto"),
    ] {
        let Some(path) = data(log) else { return };
        let dir = tmp.path().join(format!("{}-{fit}", log.replace('/', "-")));
        let cal = read_calibration(&calibrate(&path, &["--fit", fit], &dir)).unwrap();
        conditions.push(cal.condition());
    }
    eprintln!("condition numbers |P|_F |P^-1|_F: {conditions:?}");
    // cond_F >= 3 for any 3 x 3 matrix (equal for a multiple of the identity, to rounding).
    let least = 3.0 * (1.0 - 8.0 * f64::EPSILON);
    assert!(
        conditions.iter().all(|&c| (least..MAX_CONDITION).contains(&c)),
        "{conditions:?}"
    );
}

/// An edit of a calibration's JSON.
type Edit = Box<dyn FnOnce(&mut serde_json::Value)>;

#[test]
fn apply_and_next_refuse_a_calibration_that_cannot_be_used() {
    let Some(ck) = data(CK) else { return };
    let tmp = TempDir::new().unwrap();
    let cal = calibrate(&ck, &[], &tmp.path().join("cal"));
    let out = tmp.path().join("calibrated.csv");
    let identity = serde_json::json!([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
    let cases: Vec<(&str, Edit, Vec<&str>)> = vec![
        (
            "singular.json",
            Box::new(|j| j["p"] = serde_json::json!([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])),
            vec!["singular.json: p ", "diagonal entry 1 is 0"],
        ),
        (
            "huge.json",
            Box::new(|j| j["p"] = serde_json::json!([[1e308, 0.0, 0.0], [0.0, 1e308, 0.0], [0.0, 0.0, 1e308]])),
            vec!["huge.json: p ", "too large (G = P^T P overflows)"],
        ),
        (
            "rank1.json",
            Box::new(|j| j["p"] = serde_json::json!([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0]])),
            vec!["rank1.json: p ", "entry (2, 1) is 1; P is upper triangular"],
        ),
        (
            "near-singular.json",
            Box::new(|j| j["p"] = serde_json::json!([[1.0, 1.0, 0.0], [0.0, 1e-6, 0.0], [0.0, 0.0, 1.0]])),
            vec!["near-singular.json: p ", "condition number 2.449e6 above 1e3"],
        ),
        (
            "scaled.json",
            Box::new(move |j| j["p"] = identity),
            vec!["scaled.json: k ", "not the inverse of p"],
        ),
        (
            "scale.json",
            Box::new(|j| j["scale"][2] = serde_json::json!(2.0)),
            vec!["scale.json: scale [", "not the scale factors of p"],
        ),
        (
            "psi.json",
            Box::new(|j| j["psi_deg"][0] = serde_json::json!(1.0)),
            vec!["psi.json: psi_deg [", "not the non-orthogonality of p"],
        ),
        (
            "soft.json",
            Box::new(|j| j["soft_iron_inverse"][0][1] = serde_json::json!(0.5)),
            vec![
                "soft.json: soft_iron_inverse ",
                "not the symmetric square root of P^T P",
            ],
        ),
        (
            "magnitude.json",
            Box::new(|j| j["magnitude"] = serde_json::json!(-0.3)),
            vec!["magnitude.json: magnitude -0.3: must be finite and positive"],
        ),
        (
            "noise.json",
            Box::new(|j| j["noise"] = serde_json::json!(-1.0)),
            vec!["noise.json: noise -1: must be finite and not negative"],
        ),
        (
            "format.json",
            Box::new(|j| j["format"] = serde_json::json!("magcal-calibration-9")),
            vec!["format.json: format \"magcal-calibration-9\": this magcal reads \"magcal-calibration-1\""],
        ),
        (
            "missing.json",
            Box::new(|j| {
                j.as_object_mut().unwrap().remove("k");
            }),
            vec!["missing.json: not a magcal calibration: missing field `k`"],
        ),
    ];
    for (name, edit, needles) in cases {
        let bad = edited(&cal, name, edit);
        let apply = run(&[
            "apply".as_ref(),
            bad.as_os_str(),
            ck.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        assert_refused(&apply, &needles);
        assert!(!out.exists(), "{name}: apply wrote {}", out.display());
        let next = run(&[
            "next".as_ref(),
            bad.as_os_str(),
            ck.as_os_str(),
            "--scenario".as_ref(),
            scenario("drone").as_os_str(),
        ]);
        assert_refused(&next, &needles);
    }
    // A file far larger than a calibration is refused before it is read whole.
    let big = tmp.path().join("big.json");
    fs::write(&big, vec![b' '; 2 << 20]).unwrap();
    assert_refused(
        &run(&["apply".as_ref(), big.as_os_str(), ck.as_os_str()]),
        &["big.json: 2097152 bytes; at most 1.0 MiB are read"],
    );
    // A calibration without the provenance fields (written before they existed) is still used.
    let old = edited(&cal, "old.json", |j| {
        for key in ["format", "magcal_version", "log_sha256", "log_rows", "units"] {
            j.as_object_mut().unwrap().remove(key);
        }
    });
    let (code, stdout, stderr) = run(&["apply".as_ref(), old.as_os_str(), ck.as_os_str()]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(stdout.lines().count(), 12_001);
}

#[test]
fn apply_refuses_a_reading_whose_calibrated_value_is_not_finite() {
    let Some(ck) = data(CK) else { return };
    let tmp = TempDir::new().unwrap();
    let cal = calibrate(&ck, &[], &tmp.path().join("cal"));
    let mut text = fs::read_to_string(&ck).unwrap();
    // Calibrated, each component stays below f64::MAX but the length does not.
    text.push_str("0,0,0,1.7e308,1.7e308,1.7e308\n");
    let log = tmp.path().join("huge.csv");
    fs::write(&log, text).unwrap();
    let out = tmp.path().join("calibrated.csv");
    assert_refused(
        &run(&[
            "apply".as_ref(),
            cal.as_os_str(),
            log.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]),
        &[
            "huge.csv: line 12002: the reading [1.7e308, 1.7e308, 1.7e308]",
            "not finite",
        ],
    );
    assert!(!out.exists());
}

#[test]
fn apply_and_next_read_the_columns_the_calibration_was_made_from() {
    // The ck-explorer log with its columns renamed so that no default finds the magnetometer:
    // calibrated from columns 4-6, applied without --columns.
    let Some(ck) = data(CK) else { return };
    let tmp = TempDir::new().unwrap();
    let text = fs::read_to_string(&ck).unwrap();
    let renamed = text.replacen("ax,ay,az,mx,my,mz", "a1,a2,a3,b1,b2,b3", 1);
    let log = tmp.path().join("abc.csv");
    fs::write(&log, &renamed).unwrap();
    let cal_path = calibrate(&log, &["--columns", "4,5,6"], &tmp.path().join("cal"));
    let cal = read_calibration(&cal_path).unwrap();
    assert_eq!(cal.columns, ["b1", "b2", "b3"]);
    let (code, stdout, stderr) = run(&["apply".as_ref(), cal_path.as_os_str(), log.as_os_str()]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.is_empty(), "{stderr}");
    // Row for row what calibrate wrote for the same readings (one formula, to rounding).
    let residuals = fs::read_to_string(tmp.path().join("cal/residuals.csv")).unwrap();
    let mut rows = 0;
    for (a, r) in stdout.lines().skip(1).zip(residuals.lines().skip(1)) {
        let (a, r) = (numbers(a), numbers(r));
        assert_eq!(a[0], r[0]);
        for i in 0..4 {
            // residuals.csv holds 7 significant digits: within 5e-7 of each value.
            assert!(
                (a[1 + i] - r[4 + i]).abs() <= 5e-7 * a[1 + i].abs() * (1.0 + 1e-9) + 8.0 * f64::EPSILON * r[7],
                "{a:?} {r:?}"
            );
        }
        rows += 1;
    }
    assert_eq!(rows, 12_000);
    // --columns overrides: the accelerometer (about 1 g) under the magnetometer's calibration is
    // 3.27 times the magnitude: warned, naming the log and the recorded columns.
    let (code, _, stderr) = run(&[
        "apply".as_ref(),
        cal_path.as_os_str(),
        log.as_os_str(),
        "--columns".as_ref(),
        "1,2,3".as_ref(),
    ]);
    assert_eq!(code, 0);
    assert!(
        stderr.starts_with("magcal: warning: ")
            && stderr.contains("abc.csv: its median radius under the calibration is 3.2")
            && stderr.contains("no site on Earth explains")
            && stderr.contains("made from columns b1, b2, b3"),
        "{stderr}"
    );
    // A log without those columns: said so, with both sets of names.
    let other = tmp.path().join("other.csv");
    fs::write(&other, text).unwrap();
    for command in ["apply", "next"] {
        let mut args: Vec<&std::ffi::OsStr> = vec![command.as_ref(), cal_path.as_os_str(), other.as_os_str()];
        let drone = scenario("drone");
        if command == "next" {
            args.extend(["--scenario".as_ref(), drone.as_os_str()]);
        }
        assert_refused(
            &run(&args),
            &[
                "other.csv: no column \"b1\", which",
                "was made from (columns b1, b2, b3; the log's: ax, ay, az, mx, my, mz); give --columns",
            ],
        );
    }
    // Without a header, a calibration from named columns cannot be matched.
    let headerless = tmp.path().join("headerless.csv");
    fs::write(&headerless, renamed.split_once('\n').unwrap().1).unwrap();
    assert_refused(
        &run(&["apply".as_ref(), cal_path.as_os_str(), headerless.as_os_str()]),
        &[
            "headerless.csv: no header and 6 columns",
            "made from columns b1, b2, b3; give --columns",
        ],
    );
    // A calibration of the headerless log records `column 4..6` and reads them back.
    let cal2 = calibrate(&headerless, &["--columns", "4,5,6"], &tmp.path().join("cal2"));
    assert_eq!(
        json(&cal2)["columns"],
        serde_json::json!(["column 4", "column 5", "column 6"])
    );
    let (code, stdout2, stderr) = run(&["apply".as_ref(), cal2.as_os_str(), headerless.as_os_str()]);
    assert_eq!(code, 0, "{stderr}");
    let norms: Vec<f64> = stdout2.lines().skip(1).map(|l| numbers(l)[4]).collect();
    let median = {
        let mut n = norms.clone();
        n.sort_by(f64::total_cmp);
        n[(n.len() - 1) / 2]
    };
    let magnitude = json(&cal2)["magnitude"].as_f64().unwrap();
    // The median radius of the fitted log lies within its residual rms of the magnitude.
    let rms = json(&cal2)["residual_rms"].as_f64().unwrap();
    assert!((median - magnitude).abs() <= rms, "{median} {magnitude} {rms}");
}

#[test]
fn apply_warns_and_next_refuses_a_log_in_other_units() {
    // The ck-explorer log in nT (Gauss x 1e5) under its calibration in Gauss.
    let Some(ck) = data(CK) else { return };
    let tmp = TempDir::new().unwrap();
    let wmm = ["--site", "28.2,112.97", "--date", "2013.0", "--units", "G"];
    let cal_path = calibrate(&ck, &wmm, &tmp.path().join("cal"));
    let cal = read_calibration(&cal_path).unwrap();
    let text = fs::read_to_string(&ck).unwrap();
    let mut nt = String::from("ax,ay,az,mx,my,mz\n");
    for l in text.lines().skip(1) {
        let v: Vec<f64> = l.split(',').map(|c| c.parse().unwrap()).collect();
        nt.push_str(&format!(
            "{},{},{},{},{},{}\n",
            v[0],
            v[1],
            v[2],
            v[3] * 1e5,
            v[4] * 1e5,
            v[5] * 1e5
        ));
    }
    let log = tmp.path().join("nt.csv");
    fs::write(&log, nt).unwrap();
    let (code, stdout, stderr) = run(&["apply".as_ref(), cal_path.as_os_str(), log.as_os_str()]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(stdout.lines().count(), 12_001);
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.starts_with("magcal: warning: ")
            && stderr.contains("nt.csv: its median radius under the calibration is ")
            && stderr.contains("which no site on Earth explains")
            && stderr.contains("made from columns mx, my, mz in G"),
        "{stderr}"
    );
    // The ratio printed is the median computed here, to the histogram's half bin (0.14 %).
    let printed = numbers(stderr.split("calibration is ").nth(1).unwrap())[0];
    let expected = median_radius(&cal, &ck_readings(&ck, 1e5)) / cal.magnitude;
    let half_bin = 2_f64.powf(0.5 / 256.0) - 1.0;
    assert!(
        (printed / expected - 1.0).abs() <= half_bin + 1e-4,
        "{printed} {expected}"
    );
    assert!(expected > 1e4, "{expected}");
    // next needs the calibration's own log: refused.
    let drone = scenario("drone");
    assert_refused(
        &run(&[
            "next".as_ref(),
            cal_path.as_os_str(),
            log.as_os_str(),
            "--scenario".as_ref(),
            drone.as_os_str(),
        ]),
        &["nt.csv: its median radius", "next needs the log the calibration"],
    );
    // The log it was fitted to: no warning from apply.
    let (code, _, stderr) = run(&["apply".as_ref(), cal_path.as_os_str(), ck.as_os_str()]);
    assert!(code == 0 && stderr.is_empty(), "{stderr}");
}

#[test]
fn next_warns_on_another_log_and_says_an_efficiency_above_one_is_none() {
    let Some(ck) = data(CK) else { return };
    let tmp = TempDir::new().unwrap();
    // In the AUV box (smoke), ck-explorer's readings hold more information per reading than any
    // design in the box: calibrate's coverage gives the same ratio as next.
    let smoke = scenario("smoke");
    let cal = calibrate(&ck, &["--scenario", smoke.to_str().unwrap()], &tmp.path().join("cal"));
    let ratio = json(&cal)["coverage"]["d_efficiency_per_reading"].as_f64().unwrap();
    assert!(ratio > 3.0, "{ratio}");
    let (code, stdout, stderr) = run(&[
        "next".as_ref(),
        cal.as_os_str(),
        ck.as_os_str(),
        "--scenario".as_ref(),
        smoke.as_os_str(),
        "--count".as_ref(),
        "2".as_ref(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.is_empty(), "{stderr}");
    let line = stdout
        .lines()
        .find(|l| l.starts_with("certified D-efficiency"))
        .unwrap();
    assert!(line.contains("before none ("), "{line}");
    let n = numbers(line);
    // before, after: both ratios above 1, before equal to calibrate's (same certificate stream).
    assert!((n[0] / ratio - 1.0).abs() <= 1e-4 && n[1] > 1.0, "{line} {ratio}");
    assert!(stdout.contains("above 1 is no efficiency"), "{stdout}");
    // In the drone's box (every attitude) the log is inside: an efficiency, below 1.
    let drone = scenario("drone");
    let (code, stdout, _) = run(&[
        "next".as_ref(),
        cal.as_os_str(),
        ck.as_os_str(),
        "--scenario".as_ref(),
        drone.as_os_str(),
        "--count".as_ref(),
        "2".as_ref(),
    ]);
    assert_eq!(code, 0);
    let line = stdout
        .lines()
        .find(|l| l.starts_with("certified D-efficiency"))
        .unwrap();
    let n = numbers(line);
    assert!(n[0] > 0.5 && n[0] <= 1.0 && n[1] >= n[0] && n[1] <= 1.0, "{line}");
    assert!(!stdout.contains("above 1"), "{stdout}");
    // Another log of the same sensor (the first 6000 readings): warned, named by SHA-256, and
    // "identifiable before" is then the full fit of the log given.
    let half: String = fs::read_to_string(&ck)
        .unwrap()
        .lines()
        .take(6001)
        .map(|l| format!("{l}\n"))
        .collect();
    let other = tmp.path().join("half.csv");
    fs::write(&other, half).unwrap();
    let (code, stdout, stderr) = run(&[
        "next".as_ref(),
        cal.as_os_str(),
        other.as_os_str(),
        "--scenario".as_ref(),
        drone.as_os_str(),
        "--count".as_ref(),
        "2".as_ref(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.starts_with("magcal: warning: ")
            && stderr.contains("half.csv is not the log")
            && stderr.contains("SHA-256"),
        "{stderr}"
    );
    assert!(
        stdout.contains(
            "usable (full model): before true (the full fit of this log, as calibrate fits and checks it); after true"
        ),
        "{stdout}"
    );
}

#[test]
fn next_says_usable_before_as_calibrate_said_it() {
    // The first 1200 readings of hamagure set 2 (restricted tilt, a narrow arc of it): calibrate
    // says the full model's calibration is not usable (its fit runs off), under --fit full and
    // under --fit auto (which falls back to a reduced model); next agrees for both, plans under
    // the sphere that best fits the log, and says passes over the ten attitudes make it usable.
    let Some(h2) = data(H2) else { return };
    let tmp = TempDir::new().unwrap();
    let arc = tmp.path().join("arc.csv");
    let text: String = fs::read_to_string(&h2)
        .unwrap()
        .lines()
        .take(1201)
        .map(|l| format!("{l}\n"))
        .collect();
    fs::write(&arc, text).unwrap();
    let drone = scenario("drone");
    for fit in ["full", "auto"] {
        let cal = calibrate(&arc, &["--fit", fit], &tmp.path().join(fit));
        let j = json(&cal);
        assert!(!j["usable"].as_bool().unwrap(), "{fit}");
        if fit == "auto" {
            assert_ne!(j["fit"], "full");
        }
        let (code, stdout, stderr) = run(&[
            "next".as_ref(),
            cal.as_os_str(),
            arc.as_os_str(),
            "--scenario".as_ref(),
            drone.as_os_str(),
        ]);
        assert_eq!(code, 0, "{stderr}");
        assert!(
            stdout.contains("planned under the sphere that best fits the log"),
            "{stdout}"
        );
        let line = stdout.lines().find(|l| l.starts_with("usable (full model):")).unwrap();
        // After: the full fit of the log (read again by the sphere's sensor) with ten readings
        // simulated at the suggested attitudes is usable, its check by trials and the heading
        // budget over the drone's box included.
        let source = if fit == "full" {
            "before false (calibrate's verdict of this log); after true, heading "
        } else {
            "before false (the full fit of this log, as calibrate fits and checks it); after true, heading "
        };
        assert!(line.contains(source), "{line}");
        // Usable in 4 or 5 of the 5 logs simulated with the readings drawn afresh, at some number
        // of passes over the ten attitudes.
        let logs = line
            .split("deg predicted at the 95th percentile over the box (budget 2), the median over 5 logs simulated, ")
            .nth(1)
            .unwrap_or_else(|| panic!("{line}"));
        let usable: usize = logs.split(' ').next().unwrap().parse().unwrap();
        assert!((4..=5).contains(&usable), "{line}");
        let readings: usize = logs
            .split(" of them usable (")
            .nth(1)
            .unwrap()
            .split(' ')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!(readings.is_multiple_of(10) && readings <= 320, "{line}");
    }
}

#[test]
fn next_refuses_a_box_too_narrow_to_search() {
    let Some(ck) = data(CK) else { return };
    let tmp = TempDir::new().unwrap();
    let cal = calibrate(&ck, &[], &tmp.path().join("cal"));
    let site = ["--site", "28.2,112.97", "--date", "2013.0", "--count", "2"];
    let mut args: Vec<&std::ffi::OsStr> = vec!["next".as_ref(), cal.as_os_str(), ck.as_os_str()];
    args.extend(site.iter().map(std::ffi::OsStr::new));
    let with = |extra: &[&'static str]| {
        let mut a = args.clone();
        a.extend(extra.iter().map(std::ffi::OsStr::new));
        run(&a)
    };
    assert_refused(
        &with(&["--roll=0,1e-9", "--pitch=0,1e-9"]),
        &[
            "the box of roll [0.0, 1e-9]",
            "the roll range is 1.000e-9 degree wide",
            "narrower than 0.01 degree",
        ],
    );
    assert_refused(
        &with(&["--roll=-5,5", "--pitch=-20,20", "--yaw=10,10.005"]),
        &["the yaw range is 5.000e-3 degree wide"],
    );
    // Just wide enough to search, too narrow for any design to determine the model: no bound,
    // said in words rather than NaN.
    let (code, stdout, stderr) = with(&["--roll=-0.01,0.01", "--pitch=-0.01,0.01"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains("certified D-efficiency per reading in this box: before none, after none")
            && stdout.contains("no design in this box determines the linear model")
            && !stdout.contains("NaN"),
        "{stdout}"
    );
}
