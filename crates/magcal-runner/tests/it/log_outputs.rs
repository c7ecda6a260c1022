//! The outputs of the log commands: `calibrate --out` is a result set replaced whole, single files
//! replace only regular files and never an input, every failed write is exit 2 with one line, and
//! a calibration not to use is exit 3 after its outputs are written.

use std::fs;
use std::os::unix::fs::FileTypeExt;
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Output, Stdio};

use crate::common::{
    leftovers, magcal, magcal_process, magcal_with_file_size, restore, smoke, snapshot, without_manifest,
};
use magcal_core::design::sources;
use magcal_core::rng::stream_rng;
use magcal_core::{AttitudeBox, paper};
use magcal_runner::digest::sha256_hex;
use magcal_runner::log::calibration::CalibrationJson;
use magcal_runner::output::log_rows::{AppliedRow, ResidualRow, SimulatedRow};
use magcal_runner::output::manifest::{CalibrationManifest, SetKind};
use magcal_runner::output::parse_csv;
use tempfile::TempDir;

/// Writes a log of `n` readings (Gauss, `t,mx,my,mz`) of the [P1] sensor at random attitudes of
/// `bounds` in the Changsha field, 30 nT of noise, from random stream `seed`.
fn log_in(bounds: &AttitudeBox, path: &Path, seed: u64, n: usize) -> PathBuf {
    let mut rng = stream_rng(seed, 0);
    let design = sources::random(bounds, n, &mut rng);
    let readings = paper::true_error_model()
        .noisy_readings(&paper::changsha_field().body_fields(&design), 30.0, &mut rng)
        .unwrap();
    let mut text = String::from("t,mx,my,mz\n");
    for (i, s) in readings.iter().enumerate() {
        text.push_str(&format!("{i},{},{},{}\n", s[0] / 1e5, s[1] / 1e5, s[2] / 1e5));
    }
    fs::write(path, text).unwrap();
    path.to_path_buf()
}

/// A log over every attitude: the full model is determined.
fn log(path: &Path, seed: u64, n: usize) -> PathBuf {
    log_in(&AttitudeBox::full(), path, seed, n)
}

fn sha_of(path: &Path) -> String {
    sha256_hex(&fs::read(path).unwrap())
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Exit 2 with one line on stderr that contains every one of `words`, and no panic.
fn refused(out: &Output, words: &[&str]) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.starts_with("magcal: error: ") && !err.contains("panicked"), "{err}");
    for w in words {
        assert!(err.contains(w), "{w:?} not in {err}");
    }
}

/// Checks that `dir` holds one complete calibration set: its manifest lists exactly the other
/// files, each with the SHA-256 it has, and `calibration.json` names the manifest's log.
fn complete_set(dir: &Path) -> CalibrationManifest {
    let manifest: CalibrationManifest = serde_json::from_slice(&fs::read(dir.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest.kind, SetKind::Calibration);
    let mut on_disk: Vec<String> = snapshot(dir).into_keys().collect();
    on_disk.retain(|f| f != "manifest.json");
    assert_eq!(on_disk, manifest.files);
    assert_eq!(manifest.file_sha256.keys().cloned().collect::<Vec<_>>(), manifest.files);
    for (file, want) in &manifest.file_sha256 {
        assert_eq!(&sha_of(&dir.join(file)), want, "{file}");
    }
    let json: CalibrationJson = serde_json::from_slice(&fs::read(dir.join("calibration.json")).unwrap()).unwrap();
    assert_eq!(json.log, manifest.log);
    manifest
}

fn calibrate(log: &Path, out: &Path) -> Output {
    magcal()
        .arg("calibrate")
        .arg(log)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn the_calibration_set_records_its_log_and_every_file() {
    let tmp = TempDir::new().unwrap();
    let a = log(&tmp.path().join("a.csv"), 1, 1500);
    let out = tmp.path().join("cal");
    let run = calibrate(&a, &out);
    assert!(run.status.success(), "{}", stderr(&run));
    let manifest = complete_set(&out);
    assert_eq!(manifest.log_sha256, sha_of(&a));
    assert_eq!(manifest.log_bytes, fs::metadata(&a).unwrap().len());
    assert_eq!(manifest.log_rows, 1500);
    assert_eq!(manifest.files, ["calibration.json", "residuals.csv"]);
    assert_eq!(
        manifest.command[1..],
        [
            "calibrate".to_string(),
            a.display().to_string(),
            "--out".into(),
            out.display().to_string()
        ]
    );
    // residuals.csv: one typed row per reading, in line order, with residual = norm - R.
    let json: CalibrationJson = serde_json::from_slice(&fs::read(out.join("calibration.json")).unwrap()).unwrap();
    let rows: Vec<ResidualRow> = parse_csv(&fs::read(out.join("residuals.csv")).unwrap(), "residuals.csv").unwrap();
    assert_eq!(rows.len(), json.samples);
    assert!(rows.iter().enumerate().all(|(i, r)| r.line == i + 2));
    // Each derived number is written to 7 significant digits: within half a unit of its 7th
    // digit, 5e-7 of itself, of the number it stands for.
    let digit = 5e-7;
    for r in &rows {
        let residual = r.norm.0 - json.magnitude;
        assert!(
            (r.residual.0 - residual).abs() <= digit * (r.norm.0 + r.residual.0.abs()) * (1.0 + 1e-9),
            "{residual} vs {}",
            r.residual.0
        );
        let norm = (r.x.0 * r.x.0 + r.y.0 * r.y.0 + r.z.0 * r.z.0).sqrt();
        // Each component within 5e-7 of itself moves the norm by at most 5e-7 of it.
        assert!(
            (norm - r.norm.0).abs() <= 2.0 * digit * norm * (1.0 + 1e-9),
            "{norm} vs {}",
            r.norm.0
        );
    }
    // The set is replaced by a calibration of another log, whole.
    let b = log(&tmp.path().join("b.csv"), 2, 700);
    assert!(calibrate(&b, &out).status.success());
    let manifest = complete_set(&out);
    assert_eq!((manifest.log_sha256, manifest.log_rows), (sha_of(&b), 700));
    assert!(leftovers(&out).is_empty(), "{:?}", leftovers(&out));
}

#[test]
fn a_kill_at_any_step_of_calibrate_leaves_one_complete_set() {
    let tmp = TempDir::new().unwrap();
    let a = log(&tmp.path().join("a.csv"), 1, 1500);
    let b = log(&tmp.path().join("b.csv"), 2, 1500);
    let out = tmp.path().join("cal");
    assert!(calibrate(&a, &out).status.success());
    let old = snapshot(&out);
    let reference = tmp.path().join("reference");
    assert!(calibrate(&b, &reference).status.success());
    let new = without_manifest(snapshot(&reference));
    // calibration.json, residuals.csv, manifest.json, then the exchange and the removal of the
    // old set.
    let steps = 5;
    let (mut old_seen, mut new_seen) = (0, 0);
    for k in 1..=steps {
        restore(&out, &old);
        let run = magcal()
            .env("MAGCAL_TEST_ABORT_AFTER_STEP", k.to_string())
            .arg("calibrate")
            .arg(&b)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert_eq!(
            run.status.signal(),
            Some(libc::SIGABRT),
            "step {k}: the hook did not abort"
        );
        let now = snapshot(&out);
        if now == old {
            old_seen += 1;
        } else {
            assert_eq!(complete_set(&out).log_sha256, sha_of(&b), "step {k}: neither set");
            assert_eq!(without_manifest(now), new, "step {k}: a mixed set");
            new_seen += 1;
        }
    }
    assert_eq!((old_seen, new_seen), (3, 2), "kills before and after the swap");
    // Killed between the swap and the removal, the old set is left beside the target; the next
    // calibrate removes it.
    restore(&out, &old);
    let run = magcal()
        .env("MAGCAL_TEST_ABORT_AFTER_STEP", "4")
        .arg("calibrate")
        .arg(&b)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!run.status.success());
    assert_eq!(leftovers(&out).len(), 1, "{:?}", leftovers(&out));
    assert!(calibrate(&a, &out).status.success());
    assert!(leftovers(&out).is_empty(), "{:?}", leftovers(&out));
    assert_eq!(snapshot(&out), old);
}

#[test]
fn two_calibrates_into_one_directory_leave_one_complete_set_of_one_of_them() {
    let tmp = TempDir::new().unwrap();
    let logs = [
        log(&tmp.path().join("a.csv"), 1, 3000),
        log(&tmp.path().join("b.csv"), 2, 2000),
    ];
    let shas = logs.each_ref().map(|l| sha_of(l));
    let out = tmp.path().join("cal");
    for round in 0..16 {
        // Every other round starts without the directory: both then race to create it.
        if round % 2 == 0 && out.exists() {
            fs::remove_dir_all(&out).unwrap();
        }
        let children: Vec<_> = logs
            .iter()
            .map(|l| {
                magcal_process()
                    .arg("calibrate")
                    .arg(l)
                    .arg("--out")
                    .arg(&out)
                    .stdout(Stdio::null())
                    .stderr(Stdio::piped())
                    .spawn()
                    .unwrap()
            })
            .collect();
        let outputs: Vec<Output> = children.into_iter().map(|c| c.wait_with_output().unwrap()).collect();
        for o in &outputs {
            assert!(o.status.success(), "round {round}: {}", stderr(o));
        }
        let survivor = complete_set(&out);
        let which = shas.iter().position(|s| *s == survivor.log_sha256);
        let which = which.unwrap_or_else(|| panic!("round {round}: the set names neither log"));
        assert_eq!(survivor.log_rows, [3000, 2000][which]);
        assert!(leftovers(&out).is_empty(), "round {round}: {:?}", leftovers(&out));
    }
}

#[test]
fn outputs_never_replace_an_input_or_a_set_of_another_kind() {
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path();
    let x = log(&dir.join("x.csv"), 1, 800);
    assert!(calibrate(&x, &dir.join("d")).status.success());
    let d = snapshot(&dir.join("d"));
    let x_bytes = fs::read(&x).unwrap();
    let in_dir = |args: &[&str]| magcal().current_dir(dir).args(args).output().unwrap();
    // The log inside the calibration set it would replace, by any path.
    for log in ["d/residuals.csv", "./d/residuals.csv", "d/../d/calibration.json"] {
        refused(&in_dir(&["calibrate", log, "--out", "d"]), &["d: holds the input", log]);
    }
    // apply over its log (any spelling, a hard link) or over its calibration.
    fs::hard_link(&x, dir.join("h.csv")).unwrap();
    for (input, out) in [
        ("x.csv", "x.csv"),
        ("./x.csv", "x.csv"),
        ("x.csv", "./x.csv"),
        ("x.csv", "h.csv"),
    ] {
        refused(
            &in_dir(&["apply", "d/calibration.json", input, "--out", out]),
            &[&format!("{out}: is the input {input}")],
        );
    }
    refused(
        &in_dir(&["apply", "d/calibration.json", "x.csv", "--out", "d/calibration.json"]),
        &["d/calibration.json: is the input d/calibration.json"],
    );
    // simulate over its scenario.
    fs::copy(smoke(), dir.join("s.toml")).unwrap();
    let scenario = fs::read(dir.join("s.toml")).unwrap();
    refused(
        &in_dir(&["simulate", "s.toml", "--design", "uniform", "--out", "s.toml"]),
        &["s.toml: is the input s.toml"],
    );
    assert_eq!(fs::read(dir.join("s.toml")).unwrap(), scenario);
    // A run's set is not a calibration set, nor the reverse; `/`, `.` and `..` are no set.
    assert!(
        in_dir(&["run", "--quiet", "--trials", "5", "--out", "r", "s.toml"])
            .status
            .success()
    );
    let r = snapshot(&dir.join("r"));
    refused(
        &in_dir(&["calibrate", "x.csv", "--out", "r"]),
        &["r: holds a magcal run set, not a calibration set"],
    );
    refused(
        &in_dir(&["run", "--quiet", "--trials", "5", "--out", "d", "s.toml"]),
        &["d: holds a magcal calibration set, not a run set"],
    );
    refused(
        &in_dir(&["design", "--quiet", "--out", "d", "s.toml"]),
        &["d: holds a magcal calibration set"],
    );
    // Nothing is written into a set, which the next command into it would replace whole.
    refused(
        &in_dir(&["apply", "d/calibration.json", "x.csv", "--out", "d/applied.csv"]),
        &["d/applied.csv: d holds a magcal calibration set"],
    );
    refused(
        &in_dir(&["apply", "d/calibration.json", "x.csv", "--out", "d/residuals.csv"]),
        &["d/residuals.csv: d holds a magcal calibration set"],
    );
    refused(
        &in_dir(&["calibrate", "x.csv", "--out", "r/cal"]),
        &["r/cal: r holds a magcal run set"],
    );
    refused(
        &in_dir(&["run", "--quiet", "--trials", "5", "--out", "d/run", "s.toml"]),
        &["d/run: d holds a magcal calibration set"],
    );
    // A run never replaces the directory of its scenario.
    fs::create_dir(dir.join("inside")).unwrap();
    fs::copy(smoke(), dir.join("inside/s.toml")).unwrap();
    refused(
        &in_dir(&["run", "--quiet", "--trials", "5", "--out", "inside", "inside/s.toml"]),
        &["inside: holds the input inside/s.toml"],
    );
    for root in ["/", ".", ".."] {
        refused(
            &in_dir(&["calibrate", "x.csv", "--out", root]),
            &["name the output directory itself"],
        );
    }
    assert_eq!(snapshot(&dir.join("d")), d);
    assert_eq!(snapshot(&dir.join("r")), r);
    assert_eq!(fs::read(&x).unwrap(), x_bytes);
    assert_eq!(fs::read(dir.join("h.csv")).unwrap(), x_bytes);
}

#[test]
fn single_file_outputs_replace_only_regular_files() {
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path();
    let x = log(&dir.join("x.csv"), 1, 400);
    assert!(calibrate(&x, &dir.join("d")).status.success());
    let cal = dir.join("d/calibration.json");
    let fifo = dir.join("fifo");
    let path = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid C string; mkfifo touches nothing else.
    assert_eq!(unsafe { libc::mkfifo(path.as_ptr(), 0o644) }, 0);
    // A character device like /dev/null (1, 3), where the process may make one (as root).
    let device = dir.join("null");
    let path = std::ffi::CString::new(device.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: as above.
    let made = unsafe { libc::mknod(path.as_ptr(), libc::S_IFCHR | 0o666, libc::makedev(1, 3)) } == 0;
    if !made {
        eprintln!("not root: the character-device case is tested with a FIFO only");
    }
    fs::write(dir.join("target.csv"), "kept\n").unwrap();
    std::os::unix::fs::symlink("target.csv", dir.join("link.csv")).unwrap();
    fs::create_dir(dir.join("sub")).unwrap();
    fs::write(dir.join("sub/keep"), "kept\n").unwrap();
    let mut cases = vec![
        ("fifo", "is not a regular file"),
        ("link.csv", "is a symbolic link"),
        ("sub", "is a directory"),
        ("sub/", "is a directory"),
    ];
    if made {
        cases.push(("null", "is not a regular file"));
    }
    let before = fs::read_dir(dir).unwrap().count();
    for (target, why) in &cases {
        let apply = magcal()
            .current_dir(dir)
            .arg("apply")
            .arg(&cal)
            .arg(&x)
            .args(["--out", target])
            .output()
            .unwrap();
        refused(&apply, &[target, why]);
        let simulate = magcal()
            .current_dir(dir)
            .arg("simulate")
            .arg(smoke())
            .args(["--design", "uniform", "--out", target])
            .output()
            .unwrap();
        refused(&simulate, &[target, why]);
    }
    // Nothing was replaced, and nothing was left beside them.
    assert!(fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
    if made {
        assert!(fs::symlink_metadata(&device).unwrap().file_type().is_char_device());
    }
    assert!(
        fs::symlink_metadata(dir.join("link.csv"))
            .unwrap()
            .file_type()
            .is_symlink()
    );
    assert_eq!(fs::read_to_string(dir.join("target.csv")).unwrap(), "kept\n");
    assert_eq!(snapshot(&dir.join("sub")).len(), 1);
    assert_eq!(fs::read_dir(dir).unwrap().count(), before);
    // A missing directory is named.
    let apply = magcal()
        .arg("apply")
        .arg(&cal)
        .arg(&x)
        .arg("--out")
        .arg(dir.join("no/x.csv"))
        .output()
        .unwrap();
    refused(&apply, &["no directory"]);
}

#[test]
fn a_dash_is_standard_output_and_every_row_is_typed() {
    let tmp = TempDir::new().unwrap();
    let x = log(&tmp.path().join("x.csv"), 1, 400);
    assert!(calibrate(&x, &tmp.path().join("d")).status.success());
    let cal = tmp.path().join("d/calibration.json");
    let file = tmp.path().join("applied.csv");
    let apply = |out: Option<&Path>| {
        let mut cmd = magcal();
        cmd.arg("apply").arg(&cal).arg(&x);
        if let Some(out) = out {
            cmd.arg("--out").arg(out);
        }
        let o = cmd.output().unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
        o.stdout
    };
    let dash = apply(Some(Path::new("-")));
    assert_eq!(apply(None), dash);
    assert!(apply(Some(&file)).is_empty());
    assert_eq!(fs::read(&file).unwrap(), dash);
    let rows: Vec<AppliedRow> = parse_csv(&dash, "apply").unwrap();
    assert_eq!(rows.len(), 400);
    // apply's field is calibrate's (the same calibration of the same readings).
    let residuals: Vec<ResidualRow> =
        parse_csv(&fs::read(tmp.path().join("d/residuals.csv")).unwrap(), "residuals").unwrap();
    for (a, r) in rows.iter().zip(&residuals) {
        assert_eq!(a.line, r.line);
        // residuals.csv holds 7 significant digits: within 5e-7 of each value.
        for (u, v) in [(a.x.0, r.x.0), (a.y.0, r.y.0), (a.z.0, r.z.0), (a.norm.0, r.norm.0)] {
            assert!(
                (u - v).abs() <= 5e-7 * u.abs() * (1.0 + 1e-9) + 64.0 * f64::EPSILON * r.norm.0,
                "{u} vs {v}",
            );
        }
    }
    let simulate = magcal()
        .arg("simulate")
        .arg(smoke())
        .args(["--design", "uniform", "--out", "-"])
        .output()
        .unwrap();
    assert!(simulate.status.success(), "{}", stderr(&simulate));
    let rows: Vec<SimulatedRow> = parse_csv(&simulate.stdout, "simulate").unwrap();
    assert_eq!(rows.len(), 9);
}

/// `magcal` with standard output on /dev/full.
fn to_full(args: &[&str], dir: &Path) -> Output {
    let full = fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
    magcal_process()
        .current_dir(dir)
        .args(args)
        .stdout(full)
        .output()
        .unwrap()
}

/// `magcal` with standard output closed.
fn stdout_closed(args: &[&str], dir: &Path) -> Output {
    let mut cmd = magcal_process();
    cmd.current_dir(dir).args(args);
    // SAFETY: close is async-signal-safe.
    unsafe {
        cmd.pre_exec(|| {
            libc::close(libc::STDOUT_FILENO);
            Ok(())
        });
    }
    cmd.stderr(Stdio::piped()).output().unwrap()
}

#[test]
fn a_failed_or_impossible_write_to_standard_output_is_exit_2_with_one_line() {
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path();
    log(&dir.join("x.csv"), 1, 400);
    fs::copy(smoke(), dir.join("s.toml")).unwrap();
    assert!(calibrate(&dir.join("x.csv"), &dir.join("d")).status.success());
    let d = snapshot(&dir.join("d"));
    let commands: [&[&str]; 7] = [
        &["calibrate", "x.csv", "--json"],
        &["calibrate", "x.csv"],
        &["apply", "d/calibration.json", "x.csv"],
        &["simulate", "s.toml", "--design", "uniform"],
        &[
            "next",
            "d/calibration.json",
            "x.csv",
            "--roll=-5,5",
            "--pitch=-20,20",
            "--site",
            "28.2,112.97",
            "--date",
            "2013.0",
            "--count",
            "2",
        ],
        &["design", "--out", "des", "s.toml"],
        &["run", "--trials", "5", "--out", "r", "s.toml"],
    ];
    for args in commands {
        refused(
            &to_full(args, dir),
            &["standard output: cannot write: No space left on device"],
        );
        refused(&stdout_closed(args, dir), &["standard output is closed"]);
    }
    // A closed standard output is found before any work: nothing was replaced or made.
    refused(
        &stdout_closed(&["calibrate", "x.csv", "--out", "d"], dir),
        &["standard output is closed"],
    );
    assert_eq!(snapshot(&dir.join("d")), d);
    refused(
        &stdout_closed(&["run", "--trials", "5", "--out", "r2", "s.toml"], dir),
        &["standard output is closed"],
    );
    assert!(!dir.join("r2").exists());
    // A command that writes nothing to standard output runs without it.
    let apply = stdout_closed(&["apply", "d/calibration.json", "x.csv", "--out", "y.csv"], dir);
    assert!(apply.status.success(), "{}", stderr(&apply));
    assert_eq!(
        parse_csv::<AppliedRow>(&fs::read(dir.join("y.csv")).unwrap(), "y")
            .unwrap()
            .len(),
        400
    );
    let quiet = stdout_closed(&["run", "--quiet", "--trials", "5", "--out", "r3", "s.toml"], dir);
    assert!(quiet.status.success(), "{}", stderr(&quiet));
}

#[test]
fn a_file_size_limit_leaves_the_old_output_and_no_temporary() {
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path();
    let a = log(&dir.join("a.csv"), 1, 300);
    let b = log(&dir.join("b.csv"), 2, 3000);
    let out = dir.join("d");
    assert!(calibrate(&a, &out).status.success());
    let old = snapshot(&out);
    // 64 KiB per file: b's residuals.csv (about 0.5 MB) cannot be written.
    let limit = 64 << 10;
    let run = magcal_with_file_size(limit)
        .arg("calibrate")
        .arg(&b)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    refused(&run, &["d/residuals.csv: cannot write", "File too large"]);
    assert_eq!(snapshot(&out), old);
    assert!(leftovers(&out).is_empty(), "{:?}", leftovers(&out));
    let applied = dir.join("applied.csv");
    fs::write(&applied, "old\n").unwrap();
    let before: Vec<_> = fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    let run = magcal_with_file_size(limit)
        .arg("apply")
        .arg(out.join("calibration.json"))
        .arg(&b)
        .arg("--out")
        .arg(&applied)
        .output()
        .unwrap();
    refused(&run, &["applied.csv: cannot write", "File too large"]);
    assert_eq!(fs::read_to_string(&applied).unwrap(), "old\n");
    let after: Vec<_> = fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(after, before);
}

#[test]
fn a_kill_while_writing_a_single_file_leaves_the_old_or_the_new_file() {
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path();
    let x = log(&dir.join("x.csv"), 1, 400);
    assert!(calibrate(&x, &dir.join("d")).status.success());
    let applied = dir.join("applied.csv");
    let apply = |abort: Option<usize>| {
        let mut cmd = magcal();
        if let Some(k) = abort {
            cmd.env("MAGCAL_TEST_ABORT_AFTER_STEP", k.to_string());
        }
        cmd.arg("apply")
            .arg(dir.join("d/calibration.json"))
            .arg(&x)
            .arg("--out")
            .arg(&applied)
            .output()
            .unwrap()
    };
    assert!(apply(None).status.success());
    let new = fs::read(&applied).unwrap();
    let temporaries = || {
        fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|f| f.starts_with(".applied.csv.magcal-tmp."))
            .count()
    };
    // Killed after the temporary is written: the old file, and the temporary beside it.
    fs::write(&applied, "old\n").unwrap();
    assert_eq!(apply(Some(1)).status.signal(), Some(libc::SIGABRT));
    assert_eq!(fs::read_to_string(&applied).unwrap(), "old\n");
    assert_eq!(temporaries(), 1);
    // Killed after the rename: the new file. The next write removed the dead one's temporary.
    assert_eq!(apply(Some(2)).status.signal(), Some(libc::SIGABRT));
    assert_eq!(fs::read(&applied).unwrap(), new);
    assert_eq!(temporaries(), 0);
}

#[test]
fn outputs_of_the_same_stem_do_not_share_a_temporary() {
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path();
    let x = log(&dir.join("x.csv"), 1, 20_000);
    assert!(calibrate(&x, &dir.join("d")).status.success());
    for round in 0..6 {
        let apply = magcal_process()
            .arg("apply")
            .arg(dir.join("d/calibration.json"))
            .arg(&x)
            .arg("--out")
            .arg(dir.join("coll.csv"))
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let simulate = magcal_process()
            .arg("simulate")
            .arg(smoke())
            .args(["--design", "uniform", "--out"])
            .arg(dir.join("coll.txt"))
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        for child in [apply, simulate] {
            let o = child.wait_with_output().unwrap();
            assert!(o.status.success(), "round {round}: {}", stderr(&o));
        }
        let applied: Vec<AppliedRow> = parse_csv(&fs::read(dir.join("coll.csv")).unwrap(), "coll.csv").unwrap();
        let simulated: Vec<SimulatedRow> = parse_csv(&fs::read(dir.join("coll.txt")).unwrap(), "coll.txt").unwrap();
        assert_eq!((applied.len(), simulated.len()), (20_000, 9), "round {round}");
    }
}

#[test]
fn a_calibration_not_to_use_is_written_and_exits_3() {
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path();
    // Yaw only, +-3 degrees of tilt: the diagonal model's up axis is not determined.
    let cap = AttitudeBox::from_degrees([-3.0, 3.0], [-180.0, 180.0], [-3.0, 3.0]).unwrap();
    let flat = log_in(&cap, &dir.join("flat.csv"), 3, 400);
    // Every direction, but scale factors 1.3, 0.7, 1.2: the log rejects one common scale.
    let full = log(&dir.join("full.csv"), 4, 2000);
    for (log, fit, why) in [
        (&flat, "diagonal", "not identifiable"),
        (&full, "offset", "the log rejects this model"),
    ] {
        let out = dir.join(format!("cal-{fit}"));
        let run = magcal()
            .arg("calibrate")
            .arg(log)
            .args(["--fit", fit, "--json", "--out"])
            .arg(&out)
            .output()
            .unwrap();
        let err = stderr(&run);
        assert_eq!(run.status.code(), Some(3), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.starts_with("magcal: not a calibration to use: "), "{err}");
        assert!(err.contains(&log.display().to_string()) && err.contains(why), "{err}");
        // The outputs were written all the same, and say why.
        let printed: CalibrationJson = serde_json::from_slice(&run.stdout).unwrap();
        let written = complete_set(&out);
        assert_eq!(written.log_sha256, sha_of(log));
        let json: CalibrationJson = serde_json::from_slice(&fs::read(out.join("calibration.json")).unwrap()).unwrap();
        assert_eq!(
            serde_json::to_value(&printed).unwrap(),
            serde_json::to_value(&json).unwrap()
        );
        let rejected = json.lack_of_fit.as_ref().is_some_and(|t| t.rejected);
        assert!(!json.identifiable || rejected, "{}", json.verdict);
    }
    // The same logs under a model they determine and do not reject: exit 0.
    let run = magcal()
        .arg("calibrate")
        .arg(&full)
        .args(["--fit", "full"])
        .output()
        .unwrap();
    assert_eq!(run.status.code(), Some(0), "{}", stderr(&run));
}

/// `magcal` in `dir` with standard error on /dev/full (every write to it fails with ENOSPC) or,
/// for comparison, piped.
fn with_stderr(args: &[&str], dir: &Path, full: bool) -> Output {
    let mut cmd = magcal_process();
    cmd.current_dir(dir).args(args);
    if full {
        cmd.stderr(fs::OpenOptions::new().write(true).open("/dev/full").unwrap());
    }
    cmd.output().unwrap()
}

#[test]
fn a_full_standard_error_loses_the_message_not_the_exit_code() {
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path();
    log(&dir.join("x.csv"), 1, 400);
    // Yaw only, +-3 degrees of tilt: the diagonal model's up axis is not determined (exit 3).
    let cap = AttitudeBox::from_degrees([-3.0, 3.0], [-180.0, 180.0], [-3.0, 3.0]).unwrap();
    log_in(&cap, &dir.join("flat.csv"), 3, 400);
    let flat = magcal()
        .current_dir(dir)
        .args(["calibrate", "flat.csv", "--fit", "diagonal", "--json"])
        .output()
        .unwrap();
    assert_eq!(flat.status.code(), Some(3), "{}", stderr(&flat));
    fs::write(dir.join("flat.json"), &flat.stdout).unwrap();
    assert!(calibrate(&dir.join("x.csv"), &dir.join("d")).status.success());
    // Each command with the code it exits with and a line it writes to standard error.
    let cases: [(&[&str], i32, &str); 6] = [
        // The log is in gauss: a magnitude in nT fits, with a warning about the units.
        (
            &["calibrate", "x.csv", "--magnitude", "50000"],
            0,
            "magcal: warning: x.csv: the readings lie about",
        ),
        (
            &["apply", "flat.json", "x.csv"],
            0,
            "magcal: warning: flat.json is marked not identifiable",
        ),
        (
            &["calibrate", "flat.csv", "--fit", "diagonal"],
            3,
            "magcal: not a calibration to use: ",
        ),
        (&["calibrate", "missing.csv"], 2, "magcal: error: missing.csv"),
        (
            &["calibrate", "x.csv", "--bogus"],
            2,
            "magcal: error: unexpected argument",
        ),
        (
            &["apply", "d/calibration.json", "x.csv", "--out", "x.csv"],
            2,
            "magcal: error: x.csv: is the input x.csv",
        ),
    ];
    for (args, code, line) in cases {
        let piped = with_stderr(args, dir, false);
        assert_eq!(piped.status.code(), Some(code), "{args:?}: {}", stderr(&piped));
        assert!(stderr(&piped).contains(line), "{args:?}: {}", stderr(&piped));
        // A panic would exit 101; the same code and the same standard output instead.
        let full = with_stderr(args, dir, true);
        assert_eq!(
            full.status.code(),
            Some(code),
            "{args:?} with standard error on /dev/full"
        );
        assert_eq!(full.stdout, piped.stdout, "{args:?}");
    }
}

/// `magcal` with standard output on a pipe whose reader has gone (`magcal ... | head` after head
/// ended).
fn reader_gone(args: &[&str], dir: &Path) -> Output {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    magcal_process()
        .current_dir(dir)
        .args(args)
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap()
}

#[test]
fn a_reader_that_left_ends_the_output_quietly_and_the_exit_code_is_the_commands() {
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path();
    log(&dir.join("x.csv"), 1, 400);
    assert!(calibrate(&dir.join("x.csv"), &dir.join("d")).status.success());
    let apply = reader_gone(&["apply", "d/calibration.json", "x.csv"], dir);
    assert_eq!((apply.status.code(), stderr(&apply)), (Some(0), String::new()));
    // A log that does not determine the calibration: its outputs are written and the exit code
    // says so, whether or not anyone reads the table.
    let cap = AttitudeBox::from_degrees([-0.1, 0.1], [-0.1, 0.1], [-0.1, 0.1]).unwrap();
    log_in(&cap, &dir.join("cap.csv"), 2, 400);
    let cap = reader_gone(&["calibrate", "cap.csv", "--out", "c"], dir);
    assert_eq!(cap.status.code(), Some(3), "{}", stderr(&cap));
    assert!(stderr(&cap).contains("not a calibration to use"), "{}", stderr(&cap));
    assert!(dir.join("c/calibration.json").is_file());
}
