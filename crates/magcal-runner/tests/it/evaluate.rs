//! `magcal evaluate`: the check values of docs/conventions.md "Heading against a reference
//! attitude" through the command, closed forms on logs built here (a calibration right but for a
//! rotation; attitudes turned about the vertical by +-delta), the row filter `--where`, and bad
//! input.

use std::path::{Path, PathBuf};

use magcal_core::small::{Mat3, Vec3, mat_mul, mat_t_vec, mat_vec, norm, transpose};
use magcal_runner::commands::evaluate::{ErrorRow, EvaluationJson};
use rand::RngExt;
use tempfile::TempDir;

use crate::attitudes::{about, dcm, mul};
use crate::common::{assert_refused, data, magcal};

/// The field of the logs built here, uT, in the z-up reference frame (about BROAD's).
const FIELD: Vec3 = [-0.25, 15.3, -41.9];
/// The attitude flags of those logs: quaternions body (forward, left, up) into the z-up frame.
const ATTITUDE: [&str; 4] = ["--quaternion", "qw,qx,qy,qz", "--attitude-frame", "enu"];

/// `magcal evaluate ARGS`: exit code, stdout, stderr.
fn evaluate(args: &[&str]) -> (i32, String, String) {
    let out = magcal().arg("evaluate").args(args).output().unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `magcal evaluate ARGS --json`, which must succeed: the report and stderr.
fn evaluate_json(args: &[&str]) -> (EvaluationJson, String) {
    let (code, stdout, stderr) = evaluate(&[args, &["--json"]].concat());
    assert_eq!(code, 0, "{stderr}");
    (serde_json::from_str(&stdout).unwrap(), stderr)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `count` unit quaternions drawn from `seed` (any spread will do).
fn quaternions(count: usize, seed: u64) -> Vec<[f64; 4]> {
    let mut rng = magcal_core::rng::stream_rng(seed, 0);
    (0..count)
        .map(|_| {
            let q: [f64; 4] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            q.map(|v| v / n)
        })
        .collect()
}

/// Writes a log `t,mx,my,mz,qw,qx,qy,qz` of `rows` (reading, quaternion) at 100 Hz, every number
/// in its shortest exact form.
fn write_log(path: &Path, rows: &[(Vec3, [f64; 4])]) {
    let mut text = String::from("t,mx,my,mz,qw,qx,qy,qz\n");
    for (i, (m, q)) in rows.iter().enumerate() {
        text.push_str(&format!(
            "{},{},{},{},{},{},{},{}\n",
            i as f64 / 100.0,
            m[0],
            m[1],
            m[2],
            q[0],
            q[1],
            q[2],
            q[3]
        ));
    }
    std::fs::write(path, text).unwrap();
}

/// The largest entry of `|a - b|`.
fn distance(a: &Mat3, b: &Mat3) -> f64 {
    (0..3)
        .flat_map(|i| (0..3).map(move |j| (a[i][j] - b[i][j]).abs()))
        .fold(0.0, f64::max)
}

/// The rotation of unit quaternion `about(axis, deg)`.
fn rotation(axis: Vec3, deg: f64) -> Mat3 {
    let n = norm(axis);
    dcm(about(axis.map(|v| v / n), deg))
}

/// A heading error of `rounding` radians of the field's length, as degrees of its horizontal
/// part.
fn heading_bound(rounding: f64) -> f64 {
    (rounding * norm(FIELD) / FIELD[0].hypot(FIELD[1])).to_degrees()
}

#[test]
fn broad_02_raw_readings_through_evaluate_give_the_check_values() {
    // docs/conventions.md "Heading against a reference attitude": BROAD trial 02, the rows with
    // movement = 1 and an attitude, raw readings: rms 3.1267, p95 6.2666, max 17.3922,
    // direction rms 1.9601 degrees, F = (-0.2536, 15.3257, -41.9034) uT.
    let Some(log) = data("broad/02_undisturbed_slow_rotation_B.csv") else {
        return;
    };
    let tmp = TempDir::new().unwrap();
    let errors = tmp.path().join("errors.csv");
    let args = [
        &[
            "--raw",
            s(&log),
            "--columns",
            "mx,my,mz",
            "--time",
            "t_s",
            "--where",
            "movement=1",
        ][..],
        &ATTITUDE,
        &["--errors", s(&errors)],
    ]
    .concat();
    let (j, _) = evaluate_json(&args);
    assert!(j.calibration.is_none() && j.calibrated.is_none());
    // The data README: 53,240 rows, 32,280 of them with movement (all with an attitude).
    assert_eq!(
        (j.rows.used, j.rows.without_attitude, j.rows.left_out_by_where),
        (32_280, 0, 20_960)
    );
    let f = &j.uncalibrated;
    for (got, want) in [
        (f.heading_rms_deg, 3.1267),
        (f.heading_p95_deg, 6.2666),
        (f.heading_max_deg, 17.3922),
        (f.direction_rms_deg, 1.9601),
    ] {
        assert!((got - want).abs() <= 5e-5, "{got} against {want}");
    }
    for (got, want) in f.field.iter().zip([-0.2536, 15.3257, -41.9034]) {
        assert!((got - want).abs() <= 5e-5, "F = {:?}", f.field);
    }
    // The cells partition the readings: their counts add up, and so do their sums of squares.
    for cells in [&f.by_heading, &f.by_tilt] {
        assert_eq!(cells.iter().map(|c| c.readings).sum::<usize>(), 32_280);
        let sum_sq: f64 = cells
            .iter()
            .map(|c| c.readings as f64 * c.heading_rms_deg.unwrap_or(0.0).powi(2))
            .sum();
        let whole = 32_280.0 * f.heading_rms_deg.powi(2);
        assert!((sum_sq - whole).abs() <= 1e-9 * whole, "{sum_sq} {whole}");
        let max = cells.iter().filter_map(|c| c.heading_max_deg).fold(0.0, f64::max);
        assert_eq!(max.to_bits(), f.heading_max_deg.to_bits());
        for c in cells.iter() {
            assert_eq!(c.readings == 0, c.heading_rms_deg.is_none(), "{c:?}");
        }
    }
    assert_eq!(f.by_heading.len(), 12);
    assert_eq!(j.tilt_bands_deg, [0.0, 15.0, 30.0, 60.0, 90.0, 180.0]);
    // The per-reading file: one row per reading used, lines of movement rows, the same errors.
    let rows: Vec<ErrorRow> = magcal_runner::output::read_csv(&errors).unwrap();
    assert_eq!(rows.len(), 32_280);
    let rms = (rows.iter().map(|r| r.heading_error_deg.0.powi(2)).sum::<f64>() / 32_280.0).sqrt();
    assert!((rms - f.heading_rms_deg).abs() <= 1e-12, "{rms}");
    let max = rows.iter().map(|r| r.heading_error_deg.0.abs()).fold(0.0, f64::max);
    assert_eq!(max.to_bits(), f.heading_max_deg.to_bits());
    for r in &rows {
        assert_eq!(r.heading_error_deg, r.raw_heading_error_deg);
        assert!((0.0..=180.0).contains(&r.tilt_deg.0) && (0.0..360.0).contains(&r.heading_deg.0));
    }
    // The time column is t_s of the line: line 11451 is the first movement row (t = 40.0715 s).
    assert_eq!((rows[0].line, rows[0].time_s.unwrap().0), (11_451, 40.0715));
}

/// The sensor of the calibrated tests: [P1]'s truth with its bias in uT.
fn sensor() -> magcal_core::ErrorModel {
    let p1 = magcal_core::paper::true_error_model();
    magcal_core::ErrorModel::new(p1.psi_deg(), p1.scale(), p1.bias_nt().map(|o| o / 1000.0)).unwrap()
}

/// `magcal calibrate` of noise-free readings of [`sensor`] at 300 attitudes into `dir/cal`:
/// the calibration.json's path and contents.
fn calibration(dir: &Path) -> (PathBuf, magcal_runner::log::calibration::CalibrationJson) {
    let log = dir.join("fit.csv");
    let sensor = sensor();
    let rows: Vec<(Vec3, [f64; 4])> = quaternions(300, 11)
        .into_iter()
        .map(|q| (sensor.measure(mat_t_vec(&dcm(q), FIELD)), q))
        .collect();
    write_log(&log, &rows);
    let out = dir.join("cal");
    let magnitude = norm(FIELD).to_string();
    let o = magcal()
        .arg("calibrate")
        .arg(&log)
        .args(["--magnitude", &magnitude, "--out"])
        .arg(&out)
        .output()
        .unwrap();
    // Noise-free readings leave no noise to give standard errors: exit 3, the file written.
    assert!(
        matches!(o.status.code(), Some(0 | 3)),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let path = out.join("calibration.json");
    let cal = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    (path, cal)
}

#[test]
fn a_calibration_right_but_for_a_rotation_scores_zero_and_q_is_its_inverse() {
    // The readings of body field u_t = C_t^T F (body forward-left-up) are m_t = K (R u_t) + O
    // with K and O the calibration's own: P (m_t - O) = R u_t, the body field turned by R, which
    // a scalar calibration cannot see. The fit must find Q = R^T (calibrated frame into body)
    // and heading errors of rounding only: per reading about 16 eps (|P| |K| + |P| |O| / |u|) of
    // the field, and the sums of the fit over 200 readings at most 200 times that.
    let tmp = TempDir::new().unwrap();
    let (cal_path, cal) = calibration(tmp.path());
    let r = rotation([0.3, -0.8, 0.5], 25.0);
    let qs = quaternions(200, 12);
    let rows: Vec<(Vec3, [f64; 4])> = qs
        .iter()
        .map(|q| {
            let turned = mat_vec(&r, mat_t_vec(&dcm(*q), FIELD));
            let m = mat_vec(&cal.k, turned);
            ([m[0] + cal.bias[0], m[1] + cal.bias[1], m[2] + cal.bias[2]], *q)
        })
        .collect();
    let log = tmp.path().join("turned.csv");
    write_log(&log, &rows);
    let frob = |a: &Mat3| a.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
    let per_reading = 16.0 * f64::EPSILON * (frob(&cal.p) * frob(&cal.k) + frob(&cal.p) * norm(cal.bias) / norm(FIELD));
    let rounding = 200.0 * per_reading;
    let (j, stderr) = evaluate_json(&[&[s(&cal_path), s(&log)][..], &ATTITUDE].concat());
    assert!(!stderr.contains("warning"), "{stderr}");
    let c = j.calibrated.unwrap();
    assert!(c.heading_max_deg <= heading_bound(rounding), "{c:?}");
    assert!(c.direction_rms_deg <= heading_bound(rounding), "{c:?}");
    assert!(distance(&c.rotation, &transpose(&r)) <= rounding, "{:?}", c.rotation);
    assert!((c.rotation_angle_deg - 25.0).abs() <= rounding.to_degrees(), "{c:?}");
    for (got, want) in c.field.iter().zip(FIELD) {
        assert!((got - want).abs() <= rounding * norm(FIELD), "{:?}", c.field);
    }
    // The raw readings under [P1]'s sensor are far off: the gain shows.
    assert!(j.uncalibrated.heading_rms_deg > 10.0, "{:?}", j.uncalibrated);
    // --raw on readings that are R u_t themselves: the same closed form, without a calibration.
    let raw_log = tmp.path().join("raw.csv");
    let raw_rows: Vec<(Vec3, [f64; 4])> = qs
        .iter()
        .map(|q| (mat_vec(&r, mat_t_vec(&dcm(*q), FIELD)), *q))
        .collect();
    write_log(&raw_log, &raw_rows);
    let (j, _) = evaluate_json(&[&["--raw", s(&raw_log)][..], &ATTITUDE].concat());
    let u = j.uncalibrated;
    let rounding = 200.0 * 16.0 * f64::EPSILON;
    assert!(u.heading_max_deg <= heading_bound(rounding), "{u:?}");
    assert!(distance(&u.rotation, &transpose(&r)) <= rounding, "{:?}", u.rotation);
}

/// The log of the heading-perturbation test: for each base attitude `C` (and, when `balanced`,
/// its twin turned half a turn about the vertical), the readings `Q0^T C^T F` of a calibrated
/// frame turned by `Q0^T` from the body, logged with the attitudes `Rz(+delta) C` and
/// `Rz(-delta) C`.
fn perturbed(path: &Path, q0: &Mat3, delta: f64, balanced: bool) {
    let mut rows = Vec::new();
    for q in quaternions(100, 13) {
        let twins = if balanced {
            vec![q, mul(about([0.0, 0.0, 1.0], 180.0), q)]
        } else {
            vec![q]
        };
        for base in twins {
            let reading = mat_t_vec(q0, mat_t_vec(&dcm(base), FIELD));
            for sign in [1.0, -1.0] {
                rows.push((reading, mul(about([0.0, 0.0, 1.0], sign * delta), base)));
            }
        }
    }
    write_log(path, &rows);
}

#[test]
fn attitudes_turned_about_the_vertical_by_plus_and_minus_delta_give_errors_of_delta() {
    // Each reading is logged twice, with its attitude turned about the vertical by +delta and by
    // -delta: C'_t Q0 b_t = Rz(+-delta) F. With Q = Q0, F = D F where D shrinks the horizontal
    // by cos(delta), every heading error is +-delta and every direction error
    // acos(|D F| / |F|). Q stays at Q0 when Wahba's matrix W = sum_t C'_t^T F b_t^T = A Q0 has
    // A = sum_t C_t^T D^2 F F^T C_t symmetric positive definite: its antisymmetric part is
    // [sum_t C_t^T w]x with w = F x D^2 F horizontal, which vanishes when each base attitude
    // comes with its twin turned half a turn about the vertical (balanced); otherwise it does
    // not, and Q moves off Q0 (checked below).
    let tmp = TempDir::new().unwrap();
    let q0 = rotation([1.0, 2.0, -0.5], 40.0);
    let delta: f64 = 5.0;
    let log = tmp.path().join("balanced.csv");
    perturbed(&log, &q0, delta, true);
    let (j, _) = evaluate_json(&[&["--raw", s(&log)][..], &ATTITUDE].concat());
    let u = &j.uncalibrated;
    assert_eq!(u.by_heading.iter().map(|c| c.readings).sum::<usize>(), 400);
    let cd = delta.to_radians().cos();
    let shrunk = [cd * FIELD[0], cd * FIELD[1], FIELD[2]];
    let direction = (norm(shrunk) / norm(FIELD)).acos().to_degrees();
    // The fit stops at a turn of Q below 1e-14 rad; rounding over 400 readings adds 400 x 16
    // eps of the field.
    let rounding = 1e-14 + 400.0 * 16.0 * f64::EPSILON;
    assert!(distance(&u.rotation, &q0) <= rounding * 10.0, "{:?}", u.rotation);
    for (got, want) in u.field.iter().zip(shrunk) {
        assert!((got - want).abs() <= rounding * norm(FIELD), "{:?} {shrunk:?}", u.field);
    }
    let bound = heading_bound(rounding);
    assert!((u.heading_rms_deg - delta).abs() <= bound, "{u:?}");
    assert!((u.heading_max_deg - delta).abs() <= bound, "{u:?}");
    assert!((u.heading_p95_deg - delta).abs() <= bound, "{u:?}");
    assert!((u.direction_rms_deg - direction).abs() <= bound, "{u:?} {direction}");
    // The horizontal of F shrinks by cos(delta), so its dip grows.
    let dip = (-FIELD[2]).atan2(cd * FIELD[0].hypot(FIELD[1])).to_degrees();
    assert!((u.field_dip_deg - dip).abs() <= bound, "{} {dip}", u.field_dip_deg);
    // Each reading's error through --errors: +delta for the first of each pair, -delta for the
    // second.
    let errors = tmp.path().join("e.csv");
    let (code, _, stderr) = evaluate(&[&["--raw", s(&log)][..], &ATTITUDE, &["--errors", s(&errors)]].concat());
    assert_eq!(code, 0, "{stderr}");
    let rows: Vec<ErrorRow> = magcal_runner::output::read_csv(&errors).unwrap();
    for (i, row) in rows.iter().enumerate() {
        let want = if i % 2 == 0 { delta } else { -delta };
        assert!((row.heading_error_deg.0 - want).abs() <= bound, "row {i}: {row:?}");
    }
    // Without the twins the antisymmetric part is there: Q leaves Q0 and the errors leave
    // +-delta.
    let unbalanced = tmp.path().join("unbalanced.csv");
    perturbed(&unbalanced, &q0, delta, false);
    let (j, _) = evaluate_json(&[&["--raw", s(&unbalanced)][..], &ATTITUDE].concat());
    let moved = mat_mul(&transpose(&q0), &j.uncalibrated.rotation);
    let angle = magcal_core::reference::axis_angle(&moved).1.to_degrees();
    // Measured: 0.024 degrees, and a heading rms 2e-4 degrees off delta.
    assert!(angle > 1e-3, "{angle}");
    assert!(
        (j.uncalibrated.heading_rms_deg - delta).abs() > 1e-5,
        "{:?}",
        j.uncalibrated
    );
}

/// A small log with attitudes: 40 readings of the body field at quaternions drawn from `seed`,
/// raw readings `C^T F` (the calibration of [`calibration`] does not apply to them).
fn small_log(path: &Path, seed: u64) -> Vec<(Vec3, [f64; 4])> {
    let rows: Vec<(Vec3, [f64; 4])> = quaternions(40, seed)
        .into_iter()
        .map(|q| (mat_t_vec(&dcm(q), FIELD), q))
        .collect();
    write_log(path, &rows);
    rows
}

#[test]
fn bad_input_is_refused_in_one_line_naming_the_file_and_flag_and_nothing_is_replaced() {
    let tmp = TempDir::new().unwrap();
    let log = tmp.path().join("log.csv");
    small_log(&log, 21);
    let before = std::fs::read(&log).unwrap();
    let l = s(&log);
    // No attitude flags: the flags that give them are named.
    assert_refused(
        &evaluate(&["--raw", l]),
        &[l, "no attitudes to evaluate against", "--quaternion W,X,Y,Z", "--euler"],
    );
    // The files as the flags want them.
    assert_refused(
        &evaluate(&[&["--raw", l, l][..], &ATTITUDE].concat()),
        &["--raw", "give the log alone"],
    );
    assert_refused(
        &evaluate(&[&[l][..], &ATTITUDE].concat()),
        &["magcal evaluate CAL.json LOG", "--raw"],
    );
    // --errors onto an input, or onto standard output.
    assert_refused(
        &evaluate(&[&["--raw", l][..], &ATTITUDE, &["--errors", l]].concat()),
        &["--errors: ", "is the input", "give another path"],
    );
    assert_refused(
        &evaluate(&[&["--raw", l][..], &ATTITUDE, &["--errors", "-"]].concat()),
        &["--errors -: give a file"],
    );
    assert_eq!(std::fs::read(&log).unwrap(), before);
    // A --where column the log does not have, and --where on a flight log.
    assert_refused(
        &evaluate(&[&["--raw", l][..], &ATTITUDE, &["--where", "movement=1"]].concat()),
        &[
            l,
            "--where \"movement\": no column of that name (columns: t, mx, my, mz, qw, qx, qy, qz)",
        ],
    );
    let tlog = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/pymavlink.tlog");
    assert_refused(
        &evaluate(&["--raw", s(&tlog), "--where", "a=1"]),
        &["--where applies to CSV logs"],
    );
    // A calibration that is not one.
    let junk = tmp.path().join("junk.json");
    std::fs::write(&junk, "{\"p\": 1}").unwrap();
    assert_refused(
        &evaluate(&[&[s(&junk), l][..], &ATTITUDE].concat()),
        &[s(&junk), "not a magcal calibration"],
    );
}

#[test]
fn a_lost_attitude_is_counted_and_a_partly_lost_one_is_refused_naming_its_line() {
    let tmp = TempDir::new().unwrap();
    let log = tmp.path().join("log.csv");
    let rows = small_log(&log, 22);
    let text = std::fs::read_to_string(&log).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    // Line 6 (reading 4): the capture lost the attitude, written as NaN in every cell.
    let row = lines[5].clone();
    let cells: Vec<&str> = row.split(',').collect();
    lines[5] = format!("{},nan,NaN,nan,nan", cells[..4].join(","));
    let lost = tmp.path().join("lost.csv");
    std::fs::write(&lost, lines.join("\n") + "\n").unwrap();
    let (j, _) = evaluate_json(&[&["--raw", s(&lost)][..], &ATTITUDE].concat());
    assert_eq!((j.rows.readings, j.rows.used, j.rows.without_attitude), (40, 39, 1));
    // The same figures as the log without that reading.
    let mut kept = rows.clone();
    kept.remove(4);
    let without = tmp.path().join("without.csv");
    write_log(&without, &kept);
    let (k, _) = evaluate_json(&[&["--raw", s(&without)][..], &ATTITUDE].concat());
    assert_eq!(j.uncalibrated.field, k.uncalibrated.field);
    assert_eq!(j.uncalibrated.heading_max_deg, k.uncalibrated.heading_max_deg);
    // NaN in one cell of four: not a lost attitude but a broken one.
    lines[5] = format!("{},nan,{}", cells[..4].join(","), cells[5..].join(","));
    let broken = tmp.path().join("broken.csv");
    std::fs::write(&broken, lines.join("\n") + "\n").unwrap();
    let errors = tmp.path().join("e.csv");
    std::fs::write(&errors, "old").unwrap();
    assert_refused(
        &evaluate(&[&["--raw", s(&broken)][..], &ATTITUDE, &["--errors", s(&errors)]].concat()),
        &[s(&broken), "line 6: --quaternion has a value in 3 of its 4 columns"],
    );
    // Nothing written: the old file stands.
    assert_eq!(std::fs::read_to_string(&errors).unwrap(), "old");
}

#[test]
fn a_calibration_of_other_units_is_refused_naming_why() {
    // The calibration was fitted in uT; the log gives the same field in nT: its figures would
    // mean nothing, so evaluate refuses, as next does, and prints nothing.
    let tmp = TempDir::new().unwrap();
    let (cal, _) = calibration(tmp.path());
    let log = tmp.path().join("nt.csv");
    let sensor = sensor();
    let rows: Vec<(Vec3, [f64; 4])> = quaternions(60, 23)
        .into_iter()
        .map(|q| (sensor.measure(mat_t_vec(&dcm(q), FIELD)).map(|v| v * 1000.0), q))
        .collect();
    write_log(&log, &rows);
    let out = magcal()
        .arg("evaluate")
        .args([&[s(&cal), s(&log)][..], &ATTITUDE].concat())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("which no site on Earth explains") && stderr.contains("other units"),
        "{stderr}"
    );
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(out.stdout.is_empty());
}

#[test]
fn where_keeps_the_rows_that_meet_it_in_every_log_command_and_says_how_many_went() {
    let tmp = TempDir::new().unwrap();
    let (cal, _) = calibration(tmp.path());
    // [P1]'s sensor readings with a flag column: half the rows flagged 1.
    let sensor = sensor();
    let mut text = String::from("mx,my,mz,movement\n");
    let mut flagged = Vec::new();
    for (i, q) in quaternions(50, 24).into_iter().enumerate() {
        let m = sensor.measure(mat_t_vec(&dcm(q), FIELD));
        let flag = i % 2;
        text.push_str(&format!("{},{},{},{flag}\n", m[0], m[1], m[2]));
        if flag == 1 {
            flagged.push(i + 2);
        }
    }
    let log = tmp.path().join("flagged.csv");
    std::fs::write(&log, text).unwrap();
    // apply streams the log: only the flagged lines come out, and stderr says how many went.
    let out = magcal()
        .arg("apply")
        .arg(&cal)
        .arg(&log)
        .args(["--where", "movement=1"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("--where movement=1: 25 rows left out"), "{stderr}");
    let applied: Vec<magcal_runner::output::log_rows::AppliedRow> =
        magcal_runner::output::parse_csv(&out.stdout, "apply").unwrap();
    assert_eq!(applied.iter().map(|r| r.line).collect::<Vec<_>>(), flagged);
    // calibrate fits the flagged rows only and says so.
    let (_, json, _) = crate::common::calibrate_json(&log, &["--where", "movement=1"]);
    assert_eq!((json.samples, json.skipped), (25, 0));
    assert!(
        json.log_notes
            .iter()
            .any(|n| n == "--where movement=1: 25 rows left out"),
        "{:?}",
        json.log_notes
    );
}
