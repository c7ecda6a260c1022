//! `calibrate --fit vector` (docs/conventions.md "Vector calibration"): a simulated log whose
//! sensor is misaligned with the body by 2 degrees, the alignment through `apply` and
//! `export`, refusals, and BROAD trial 02.

use std::path::{Path, PathBuf};

use magcal_core::aviation::{dcm_of_quaternion, z_up_of_ned};
use magcal_core::reference::{AlignSettings, align};
use magcal_core::small::{Mat3, Vec3, mat_mul, mat_t_vec, mat_vec, norm, sub, transpose};
use magcal_core::wmm::{Model, Site, field_ned};
use magcal_core::{ErrorModel, paper};
use magcal_runner::log::calibration::CalibrationJson;
use tempfile::TempDir;

use crate::common::{assert_refused, calibrate_json, magcal};

/// The rotation by `deg` about the unit vector `axis` (Rodrigues), written out here rather than
/// taken from the code under test.
fn about(axis: Vec3, deg: f64) -> Mat3 {
    let (s, c) = deg.to_radians().sin_cos();
    let skew = [
        [0.0, -axis[2], axis[1]],
        [axis[2], 0.0, -axis[0]],
        [-axis[1], axis[0], 0.0],
    ];
    std::array::from_fn(|i| {
        std::array::from_fn(|j| f64::from(u8::from(i == j)) * c + s * skew[i][j] + (1.0 - c) * axis[i] * axis[j])
    })
}

/// The misalignment of the simulated sensor: 2 degrees about the tilted axis (1, 2, 2) / 3.
const AXIS: Vec3 = [1.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0];
const ANGLE_DEG: f64 = 2.0;

/// The site and date of the simulated log, and its WMM2025 field in the z-up frame (east,
/// north, up), nT.
const SITE: &str = "63.43,10.40";
const DATE: &str = "2026.4";
fn field_enu() -> Vec3 {
    let ned = field_ned(
        Model::from_name("WMM2025").unwrap(),
        &Site {
            lat_deg: 63.43,
            lon_deg: 10.40,
            alt_m: 0.0,
            year: 2026.4,
        },
    )
    .unwrap();
    [ned[1], ned[0], -ned[2]]
}

/// A log of `count` readings in nT of [P1]'s sensor (IV.A: psi, S, O) turned by the
/// misalignment (`K = K_[P1] A^T`), at attitudes uniform over the sphere (NED quaternions
/// `qw,qx,qy,qz`, normalised Gaussian draws), noise [P1]'s 30 nT per component; the attitudes
/// (z up) beside it. `same` gives every reading the first attitude.
fn simulated_log(dir: &Path, count: usize, seed: u64, same: bool) -> (PathBuf, Vec<Mat3>) {
    let model = paper::true_error_model();
    let k = mat_mul(&model.K(), &transpose(&about(AXIS, ANGLE_DEG)));
    let mut rng = magcal_core::rng::stream_rng(seed, 0);
    // Unit normal draws from the core's noise: four per quaternion.
    let unit = ErrorModel::new([0.0; 3], [1.0; 3], [0.0; 3]).unwrap();
    let draws = unit.noisy_readings(&vec![[0.0; 3]; 2 * count], 1.0, &mut rng).unwrap();
    let f = field_enu();
    let mut text = String::from("mx,my,mz,qw,qx,qy,qz\n");
    let mut attitudes = Vec::new();
    let mut clean = Vec::new();
    for t in 0..count {
        let at = if same { 0 } else { t };
        let q = [
            draws[2 * at][0],
            draws[2 * at][1],
            draws[2 * at][2],
            draws[2 * at + 1][0],
        ];
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        let q = q.map(|v| v / n);
        // The reader takes the quaternion as printed: the attitude is that of the printed digits.
        let q: [f64; 4] = q.map(|v| format!("{v:.12}").parse().unwrap());
        let c = z_up_of_ned(&dcm_of_quaternion(q).unwrap());
        clean.push(magcal_core::small::add(mat_vec(&k, mat_t_vec(&c, f)), model.bias_nt()));
        attitudes.push(c);
        text.push_str(&format!(",{},{},{},{}\n", q[0], q[1], q[2], q[3]));
    }
    magcal_core::sensor::add_noise(&mut clean, paper::SIGMA_NT, &mut rng).unwrap();
    let mut lines = text.lines();
    let mut out = format!("{}\n", lines.next().unwrap());
    for (line, m) in lines.zip(&clean) {
        out.push_str(&format!("{:.6},{:.6},{:.6}{line}\n", m[0], m[1], m[2]));
    }
    let path = dir.join(format!("vector{seed}.csv"));
    std::fs::write(&path, out).unwrap();
    (path, attitudes)
}

const QUATERNION: [&str; 4] = ["--columns", "mx,my,mz", "--quaternion", "qw,qx,qy,qz"];

/// `(estimate - truth) / std error` of everything the calibration states about the sensor:
/// psi, S, O, every entry of K, the misalignment angle; at most 4.5 (the largest of some 20
/// normal deviates exceeds 4.5 with probability 1e-4).
fn assert_within_standard_errors(c: &CalibrationJson) {
    let model = paper::true_error_model();
    let k = mat_mul(&model.K(), &transpose(&about(AXIS, ANGLE_DEG)));
    let a = c.alignment.as_ref().unwrap();
    let (psi, scale, bias) = (
        c.std_error.psi_deg.unwrap(),
        c.std_error.scale.unwrap(),
        c.std_error.bias.unwrap(),
    );
    let mut z = Vec::new();
    for i in 0..3 {
        z.push(("psi", (c.psi_deg[i] - model.psi_deg()[i]) / psi[i]));
        z.push(("S", (c.scale[i] - model.scale()[i]) / scale[i]));
        z.push(("O", (c.bias[i] - model.bias_nt()[i]) / bias[i]));
        for ((est, truth), se) in a.k_full[i].iter().zip(k[i]).zip(a.std_k_full.unwrap()[i]) {
            z.push(("K", (est - truth) / se));
        }
    }
    z.push((
        "misalignment",
        (a.misalignment_deg - ANGLE_DEG) / a.std_misalignment_deg.unwrap(),
    ));
    for (name, v) in &z {
        assert!(v.abs() <= 4.5, "{name}: {v} standard errors off; {z:?}");
    }
    // Determined: the misalignment's standard error is a small part of it.
    assert!(a.std_misalignment_deg.unwrap() < 0.25 * ANGLE_DEG, "{a:?}");
    let axis = a.misalignment_axis;
    let cos = axis.iter().zip(AXIS).map(|(x, y)| x * y).sum::<f64>();
    assert!(cos > 0.95, "{axis:?}");
    // The sensor is mounted as [P1]'s frame lies: no whole step.
    assert_eq!(a.whole_step, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
}

#[test]
fn a_simulated_misalignment_is_recovered_within_its_standard_errors_with_the_field_given_or_fitted() {
    let tmp = TempDir::new().unwrap();
    let (log, _) = simulated_log(tmp.path(), 300, 22, false);
    let given = [
        &QUATERNION[..],
        &["--fit", "vector", "--site", SITE, "--date", DATE, "--units", "nT"],
    ]
    .concat();
    let (code, c, stderr) = calibrate_json(&log, &given);
    assert_eq!(code, Some(0), "{stderr}");
    assert!(c.identifiable && c.usable, "{} {:?}", c.verdict, c.reasons);
    assert_eq!(c.fit, "vector");
    assert_within_standard_errors(&c);
    let a = c.alignment.as_ref().unwrap();
    assert!(a.field_source.starts_with("given: WMM2025"), "{}", a.field_source);
    assert_eq!(a.std_field, Some([0.0; 3]));
    // The noise from the residuals: within 4 standard errors (sigma / sqrt(2 dof)) of 30 nT.
    let noise = c.noise.unwrap();
    assert_eq!(a.dof, 3 * 300 - 12);
    assert!(
        (noise - 30.0).abs() <= 4.0 * 30.0 / (2.0 * a.dof as f64).sqrt(),
        "{noise}"
    );

    // F fitted, its magnitude the WMM's.
    let magnitude = norm(field_enu()).to_string();
    let fitted = [&QUATERNION[..], &["--fit", "vector", "--magnitude", &magnitude]].concat();
    let (code, c, stderr) = calibrate_json(&log, &fitted);
    assert_eq!(code, Some(0), "{stderr}");
    assert_within_standard_errors(&c);
    let a = c.alignment.as_ref().unwrap();
    assert!(a.field_source.starts_with("fitted"), "{}", a.field_source);
    assert_eq!(a.dof, 3 * 300 - 14);
    let (f, sf) = (a.field, a.std_field.unwrap());
    for i in 0..3 {
        let z = (f[i] - field_enu()[i]) / sf[i];
        assert!(z.abs() <= 4.5, "F {i}: {f:?} +- {sf:?}");
    }
    assert!((norm(f) / norm(field_enu()) - 1.0).abs() <= 1e-12, "{f:?}");
}

#[test]
fn apply_gives_the_body_frame_field_and_export_says_the_alignment_is_not_kept() {
    let tmp = TempDir::new().unwrap();
    let (log, attitudes) = simulated_log(tmp.path(), 200, 23, false);
    let out = tmp.path().join("cal");
    let o = magcal()
        .arg("calibrate")
        .arg(&log)
        .args(QUATERNION)
        .args([
            "--fit", "vector", "--site", SITE, "--date", DATE, "--units", "nT", "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cal = out.join("calibration.json");
    let o = magcal().arg("apply").arg(&cal).arg(&log).output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(
        stderr.contains("carries an alignment") && stderr.contains("body-frame field"),
        "{stderr}"
    );
    // Each applied reading against the body field C^T F it was made from: the differences are
    // the noise through P (about 30 nT / S, S from 0.7 to 1.3), nothing of the 2 degrees
    // (1700 nT of a 53,000 nT field) is left.
    let text = String::from_utf8(o.stdout).unwrap();
    let mut sum = 0.0;
    let mut n = 0;
    for (line, c) in text.lines().skip(1).zip(&attitudes) {
        let v: Vec<f64> = line.split(',').map(|x| x.parse().unwrap()).collect();
        let d = sub([v[1], v[2], v[3]], mat_t_vec(c, field_enu()));
        sum += d.iter().map(|x| x * x).sum::<f64>();
        n += 3;
    }
    assert_eq!(n, 600);
    let rms = (sum / f64::from(n)).sqrt();
    assert!((30.0 / 1.3 * 0.8..=30.0 / 0.7).contains(&rms), "{rms}");
    // --matrix symmetric leaves the alignment out, and says so.
    let o = magcal()
        .arg("apply")
        .arg(&cal)
        .arg(&log)
        .args(["--matrix", "symmetric"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("leaves it out"));
    // export: the rest is written, the alignment named as not kept.
    let o = magcal()
        .arg("export")
        .arg(&cal)
        .args(["--to", "magneto"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(!o.stdout.is_empty());
    assert!(
        stderr.contains("alignment") && stderr.contains("is not kept"),
        "{stderr}"
    );
    // A calibration whose alignment is no rotation is refused by apply, naming the field.
    let bad = crate::common::edited(&cal, "bad.json", |j| {
        j["alignment"]["rotation"][0][0] = serde_json::json!(2.0);
    });
    let o = magcal().arg("apply").arg(&bad).arg(&log).output().unwrap();
    let r = (
        o.status.code().unwrap(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    );
    assert_refused(&r, &["alignment.rotation", "not a rotation"]);
}

/// `magcal calibrate LOG ARGS`: exit code, stdout, stderr.
fn calibrate(log: &Path, args: &[&str]) -> (i32, String, String) {
    let o = magcal().arg("calibrate").arg(log).args(args).output().unwrap();
    (
        o.status.code().unwrap(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn vector_fits_without_attitudes_or_with_degenerate_ones_are_refused_naming_why() {
    let tmp = TempDir::new().unwrap();
    let (log, _) = simulated_log(tmp.path(), 50, 24, false);
    assert_refused(
        &calibrate(&log, &["--columns", "mx,my,mz", "--fit", "vector"]),
        &["--fit vector needs a reference attitude", "--quaternion or --euler"],
    );
    let with = [&QUATERNION[..], &["--fit", "vector"]].concat();
    assert_refused(
        &calibrate(&log, &[&with[..], &["--motor", "current"]].concat()),
        &["--motor"],
    );
    // A log of one attitude is fine input that determines no vector calibration: exit 3, the
    // scalar fit's report with the reason, never exit 2.
    let (same, _) = simulated_log(tmp.path(), 50, 25, true);
    let (code, stdout, stderr) = calibrate(&same, &with);
    assert_eq!(code, 3, "{stderr}");
    assert!(stdout.contains("NO CALIBRATION TO USE"), "{stdout}");
    for n in ["--fit vector", "singular information", "at no cost"] {
        assert!(stderr.contains(n), "{n:?} not in {stderr}");
    }
    // The scalar full fit that gives the start and the magnitude needs 9 readings, more than
    // the vector fit's 5: a log of 4 gets the report that there is no calibration.
    let (few, _) = simulated_log(tmp.path(), 4, 26, false);
    let (code, _, stderr) = calibrate(&few, &[&with[..], &["--magnitude", "50000"]].concat());
    assert_eq!(code, 3, "{stderr}");
    assert!(stderr.contains("4 readings, at least 9 are needed"), "{stderr}");
}

#[test]
fn broad_trial_02_gives_its_misalignment_and_a_heading_no_worse_than_the_scalar_fit() {
    // The capture room's z is up and its north unknown: F is fitted. Rows with movement and an
    // attitude, as tests/it/attitudes.rs takes them.
    let tmp = TempDir::new().unwrap();
    let Some(log) = crate::common::broad_02_moving(tmp.path()) else {
        return;
    };
    let args = crate::common::BROAD_ARGS;
    let (code, full, stderr) = calibrate_json(&log, &[&args[..], &["--fit", "full"]].concat());
    assert_eq!(code, Some(0), "{stderr}");
    let (code, vector, stderr) = calibrate_json(&log, &[&args[..], &["--fit", "vector"]].concat());
    assert_eq!(code, Some(0), "{stderr}");
    assert!(vector.identifiable, "{}", vector.verdict);
    let a = vector.alignment.as_ref().unwrap();
    assert_eq!(a.readings, 32_280);
    // The IMU's axes are the capture body's forward, left, up: a half turn about forward from
    // magcal's forward, right, down.
    assert_eq!(a.whole_step, [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]);
    // |F| is the scalar fit's magnitude, to rounding.
    assert!((norm(a.field) / full.magnitude - 1.0).abs() <= 1e-12);
    // The heading with the vector calibration, through align (Q fitted) and with the alignment
    // held, against the scalar full fit's through align.
    let scalar = full.heading_vs_log.as_ref().unwrap().calibrated.unwrap();
    let aligned = vector.heading_vs_log.as_ref().unwrap().calibrated.unwrap();
    let held = a.heading_held.unwrap();
    eprintln!(
        "BROAD 02: K {:?}\n  misalignment {:.4} +- {:.4} deg about {:?}, residual rms {:.4} uT per component, F {:?}\n  heading rms: scalar full {:.4}, vector through align {:.4}, vector held {:.4} (p95 {:.4} / {:.4} / {:.4})",
        a.k_full,
        a.misalignment_deg,
        a.std_misalignment_deg.unwrap(),
        a.misalignment_axis,
        a.residual_rms,
        a.field,
        scalar.heading_rms_deg,
        aligned.heading_rms_deg,
        held.heading_rms_deg,
        scalar.heading_p95_deg,
        aligned.heading_p95_deg,
        held.heading_p95_deg
    );
    // The vector fit minimises the residuals of the field itself, which the heading errors are
    // angles of: held or re-aligned, it is no worse than the scalar fit's best alignment.
    assert!(held.heading_rms_deg <= scalar.heading_rms_deg, "{held:?} vs {scalar:?}");
    assert!(aligned.heading_rms_deg <= scalar.heading_rms_deg);
    // Held, the alignment is the vector fit's own: align's Q on its body-frame readings is
    // within a few standard errors of the identity, so the two figures agree closely.
    assert!(
        (held.heading_rms_deg - aligned.heading_rms_deg).abs() <= 0.01,
        "{held:?} {aligned:?}"
    );
    // The misalignment is determined, and stands out from its standard error.
    let se = a.std_misalignment_deg.unwrap();
    assert!(a.misalignment_deg > 10.0 * se, "{} +- {se}", a.misalignment_deg);
    // Independent of the calibrate command: align's rotation on the vector calibration's
    // body-frame readings (its own attitude reading of the CSV) is within 0.1 degree of none.
    let rows: Vec<Vec<f64>> = std::fs::read_to_string(&log)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    let cal = magcal_core::small::mat_mul(&a.rotation, &vector.p);
    let (mut body, mut c) = (Vec::new(), Vec::new());
    for r in &rows {
        body.push(mat_vec(&cal, sub([r[1], r[2], r[3]], vector.bias)));
        // ENU quaternion of a forward-left-up body: turned into z up with magcal's
        // forward-right-down body by a half turn about forward.
        let q = dcm_of_quaternion([r[10], r[11], r[12], r[13]]).unwrap();
        c.push(mat_mul(&q, &[[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]));
    }
    let q = align(&body, &c, &AlignSettings::default()).unwrap().rotation;
    let angle = ((q[0][0] + q[1][1] + q[2][2] - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    assert!(angle <= 0.1, "{angle}");
}

#[test]
fn a_vector_fit_whose_magnitude_or_sensor_is_not_believable_is_not_usable() {
    // BROAD 10 (translation, narrow attitudes): the scalar fit the field's magnitude comes from
    // is not determined (its cost barely rises along a scale factor), and the vector fit runs
    // off to a sensor no magnetometer is (psi 34 degrees, scale factors 6 to 8): the log's (exit
    // 3), not bad input. BROAD 33
    // (a magnet on the board): the readings lie 20 % off the vector calibration's sphere.
    // Neither may be called usable (exit 3, reasons named).
    for (trial, words) in [
        ("broad/10_undisturbed_slow_translation_A.csv", "not a believable sensor"),
        ("broad/33_disturbed_attached_magnet_2cm.csv", "not an ellipsoid"),
    ] {
        let Some(path) = crate::common::data(trial) else {
            return;
        };
        let out = crate::common::magcal()
            .arg("calibrate")
            .arg(&path)
            .args(crate::common::BROAD_ARGS)
            .args(["--where", "movement=1", "--fit", "vector", "--json"])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(3), "{trial}: {stderr}");
        let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(j["usable"], serde_json::Value::Bool(false), "{trial}");
        let reasons = j["reasons"].to_string();
        assert!(reasons.contains(words), "{trial}: {reasons}");
    }
}
