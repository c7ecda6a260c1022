//! Result sets from someone else: a page of magcal's is meant to be shared, so nothing in a set
//! may make it run script, fetch anything or read outside the set, and a manifest that is not a
//! regular file is named, not read (docs/conventions.md has no part of this: it is the page's,
//! `report/mod.rs` "A page from someone else's set").

use std::fs;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use magcal_runner::digest::sha256_hex;
use tempfile::TempDir;

use crate::browser::{chromium, open};
use crate::common::{magcal, magcal_process, run_into, smoke};
use crate::report::report;

/// What a hostile string holds: the HTML parser's script-data escapes, a script, an event
/// handler, plotly's own markup fetching a URL, and the line separators JavaScript ends lines at.
const HOSTILE: &str = "<!-- <script>document.title='pwned'</script> <img src=x onerror=\"document.title='pwned'\"> <span style=\"background:url(http://127.0.0.1:9/x)\">uT</span> \u{2028}\u{2029} --> &amp;";

/// A log `x,y,z` of 600 readings of 50 uT in directions all round, read with a bias.
fn sphere_log(dir: &Path) -> PathBuf {
    let mut text = String::from("x,y,z\n");
    for i in 0..600 {
        let t = f64::from(i);
        let z = 1.0 - 2.0 * (t + 0.5) / 600.0;
        let r = (1.0 - z * z).sqrt();
        let a = t * 2.399_963;
        // A deterministic scatter of 0.1 uT.
        let e = |k: f64| 0.1 * ((t * k).sin());
        let b = [
            50.0 * r * a.cos() + 3.0 + e(1.3),
            50.0 * r * a.sin() - 2.0 + e(2.9),
            50.0 * z + 1.0 + e(4.7),
        ];
        text.push_str(&format!("{},{},{}\n", b[0], b[1], b[2]));
    }
    let path = dir.join("log.csv");
    fs::write(&path, text).unwrap();
    path
}

/// `magcal calibrate LOG ARGS --trials 20 --out SET`, which must give a usable calibration.
fn calibrated_set(log: &Path, args: &[&str], set: &Path) {
    let o = magcal()
        .arg("calibrate")
        .arg(log)
        .args(args)
        .args(["--trials", "20", "--out"])
        .arg(set)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Edits the set's file `name` with `edit`, records its new SHA-256 in the manifest and seals the
/// manifest again, as anyone can.
fn edit_and_reseal(set: &Path, name: &str, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = set.join(name);
    let mut v: serde_json::Value = serde_json::from_slice(&fs::read(&path).unwrap()).unwrap();
    edit(&mut v);
    reseal(set, name, &serde_json::to_vec_pretty(&v).unwrap());
}

/// Writes `bytes` as the set's file `name`, records their SHA-256 in the manifest and seals the
/// manifest again.
fn reseal(set: &Path, name: &str, bytes: &[u8]) {
    fs::write(set.join(name), bytes).unwrap();
    let manifest = set.join("manifest.json");
    let mut m: serde_json::Value = serde_json::from_slice(&fs::read(&manifest).unwrap()).unwrap();
    m["file_sha256"][name] = serde_json::Value::String(sha256_hex(bytes));
    m.as_object_mut().unwrap().remove("manifest_sha256");
    let text = serde_json::to_string_pretty(&m).unwrap();
    let body = text.strip_suffix("\n}").unwrap();
    let with = |hash: &str| format!("{body},\n  \"manifest_sha256\": \"{hash}\"\n}}");
    fs::write(&manifest, with(&sha256_hex(with("").as_bytes()))).unwrap();
}

#[test]
fn markup_in_a_resealed_calibration_is_only_text_on_its_page() {
    let tmp = TempDir::new().unwrap();
    let log = sphere_log(tmp.path());
    let set = tmp.path().join("cal");
    calibrated_set(&log, &["--units", "uT"], &set);
    edit_and_reseal(&set, "calibration.json", |c| {
        c["units"] = HOSTILE.into();
        c["fit_reason"] = HOSTILE.into();
    });
    let page_path = tmp.path().join("page.html");
    report(&set, &page_path);
    let html = fs::read_to_string(&page_path).unwrap();
    // No string of the set's reaches the markup unescaped, nor a script element's text.
    for raw in [
        "<img src=x onerror",
        "<span style=\"background:url(http://127.0.0.1",
        "<script>document.title",
    ] {
        assert!(!html.contains(raw), "{raw} in the page's markup");
    }
    assert_eq!(html.matches("<!-- ").count(), 1, "only the page's own comment");
    let Some(browser) = chromium() else { return };
    let page = open(&browser, &page_path, Duration::from_secs(60));
    assert!(page.errors.is_empty(), "{:?}", page.errors);
    assert!(
        page.requests
            .iter()
            .all(|u| u.starts_with("file://") || u.starts_with("data:")),
        "{:?}",
        page.requests
    );
    assert_ne!(page.eval("document.title"), "pwned");
    // The data block is whole and holds the string as it is.
    assert_eq!(
        page.eval("JSON.parse(document.getElementById('magcal-data').textContent).calibration.units"),
        HOSTILE
    );
    assert_eq!(
        page.eval("document.querySelectorAll('span[style], img[onerror]').length"),
        0
    );
    // Every figure's JSON parses; where it shows the units, plotly shows them as text.
    let figures = page.eval(
        "Array.from(document.querySelectorAll('script.magcal-figure')).every(s => { JSON.parse(s.textContent); return true; })",
    );
    assert_eq!(figures, true);
    // The residual map's axis shows the units: the hostile string, character for character, as
    // text (plotly's markup taken as none).
    let shown = page.eval("Array.from(document.querySelectorAll('.plotly-graph-div')).map(d => d.innerText).join(' ')");
    let shown = shown.as_str().unwrap_or("");
    assert!(
        shown.contains("(<!-- <script>document.title='pwned'</script> <img src=x onerror=\"document.title='pwned'\"> <span style=\"background:url(http://127.0.0.1:9/x)\">uT</span>"),
        "{shown}"
    );
    assert!(shown.contains("--> &amp;)"), "{shown}");
}

/// Runs `magcal ARGS`, which must end within 20 s; its exit code and stderr.
fn ends(args: &[&std::ffi::OsStr]) -> (Option<i32>, String) {
    let mut child = magcal_process()
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut stderr = String::new();
            std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut stderr).unwrap();
            return (status.code(), stderr);
        }
        if start.elapsed() > Duration::from_secs(20) {
            child.kill().unwrap();
            panic!("magcal {args:?} still runs after 20 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[cfg(unix)]
#[test]
fn a_manifest_that_is_a_fifo_or_a_link_is_named_and_not_read() {
    let tmp = TempDir::new().unwrap();
    let log = sphere_log(tmp.path());
    let set = tmp.path().join("cal");
    calibrated_set(&log, &[], &set);
    let smoke = tmp.path().join("smoke");
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/smoke.toml");
    let o = magcal()
        .args(["design", "--quiet"])
        .arg(&scenario)
        .arg("--out")
        .arg(&smoke)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let secret = tmp.path().join("secret.json");
    fs::write(&secret, "{\"SECRET\": 1}").unwrap();
    let page = tmp.path().join("p.html");
    for dir in [&set, &smoke] {
        let manifest = dir.join("manifest.json");
        for kind in ["a symbolic link", "a special file"] {
            fs::remove_file(&manifest).unwrap();
            if kind == "a symbolic link" {
                std::os::unix::fs::symlink(&secret, &manifest).unwrap();
            } else {
                let c = std::ffi::CString::new(manifest.to_str().unwrap()).unwrap();
                assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
            }
            let report_args = ["report".as_ref(), dir.as_os_str(), "--out".as_ref(), page.as_os_str()];
            let check_args = [
                "check".as_ref(),
                "--baseline".as_ref(),
                dir.as_os_str(),
                scenario.as_os_str(),
            ];
            for args in [&report_args[..], &check_args[..]] {
                if args[0] == "check" && dir == &set {
                    continue;
                }
                let (code, stderr) = ends(args);
                assert_eq!(code, Some(2), "{args:?}: {stderr}");
                assert!(
                    stderr.contains(&format!("manifest.json: is {kind}, not a regular file"))
                        && !stderr.contains("SECRET"),
                    "{args:?}: {stderr}"
                );
                assert!(!page.exists());
            }
        }
    }
}

#[test]
fn a_set_that_holds_what_it_did_not_write_is_not_replaced() {
    let tmp = TempDir::new().unwrap();
    let log = sphere_log(tmp.path());
    let set = tmp.path().join("cal");
    let calibrate = || {
        magcal()
            .arg("calibrate")
            .arg(&log)
            .args(["--trials", "20", "--out"])
            .arg(&set)
            .output()
            .unwrap()
    };
    assert_eq!(calibrate().status.code(), Some(0));
    // A set of its own files only is replaced, as before.
    assert_eq!(calibrate().status.code(), Some(0));
    fs::write(set.join("notes.txt"), "the user's").unwrap();
    fs::create_dir(set.join("photos")).unwrap();
    let before = crate::common::snapshot(&set);
    let o = calibrate();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("holds files the set did not write (\"notes.txt\", \"photos\")") && stderr.lines().count() == 1,
        "{stderr}"
    );
    assert_eq!(crate::common::snapshot(&set), before, "nothing of the set changed");
    // A run set: a file beside its figures is the user's too.
    let smoke = tmp.path().join("smoke");
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/smoke.toml");
    let design = || {
        magcal()
            .args(["design", "--quiet"])
            .arg(&scenario)
            .arg("--out")
            .arg(&smoke)
            .output()
            .unwrap()
    };
    assert_eq!(design().status.code(), Some(0));
    assert_eq!(design().status.code(), Some(0));
    fs::write(smoke.join("plots").join("mine.pdf"), "x").unwrap();
    let o = design();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("holds a file the set did not write (\"plots/mine.pdf\")"),
        "{stderr}"
    );
    assert!(smoke.join("plots").join("mine.pdf").exists());
}

/// `magcal ARGS`: exit code and stderr.
fn run(args: &[&std::ffi::OsStr]) -> (Option<i32>, String) {
    let o = magcal().args(args).output().unwrap();
    (o.status.code(), String::from_utf8_lossy(&o.stderr).into_owned())
}

#[test]
fn flags_that_cannot_be_meant_are_refused_naming_them() {
    let tmp = TempDir::new().unwrap();
    let log = sphere_log(tmp.path());
    // The same readings with columns beside them: a, b, c (angles) and t (a time).
    let text = fs::read_to_string(&log).unwrap();
    let mut rows = text.lines();
    let mut wide = format!("{},a,b,c,t\n", rows.next().unwrap());
    for (i, r) in rows.enumerate() {
        wide.push_str(&format!("{r},0,0,{},{}\n", i % 360, i));
    }
    let wide_log = tmp.path().join("wide.csv");
    fs::write(&wide_log, wide).unwrap();
    for (extra, needle) in [
        (
            &["--euler", "a,a,c"][..],
            "--euler names column 4 (\"a\") twice: each column is one quantity",
        ),
        (
            &["--euler", "a,b,c", "--time", "c"][..],
            "--time and --euler both name column 6 (\"c\")",
        ),
        (
            &["--attitude-frame", "enu"][..],
            "--attitude-frame gives the frame of the attitude columns, and none is named",
        ),
        (
            &["--current", "a"][..],
            "--current names a column read only for motor interference (calibrate --motor current, or a calibration it made): give --motor, or leave it out",
        ),
        (
            &["--throttle", "a"][..],
            "--throttle names a column read only for motor interference (calibrate --motor throttle",
        ),
    ] {
        let mut args: Vec<&std::ffi::OsStr> = vec!["calibrate".as_ref(), wide_log.as_os_str()];
        args.extend(extra.iter().map(std::ffi::OsStr::new));
        args.extend(["--trials", "20"].map(std::ffi::OsStr::new));
        let (code, stderr) = run(&args);
        assert_eq!(code, Some(2), "{extra:?}: {stderr}");
        assert!(
            stderr.contains("wide.csv") && stderr.contains(needle) && stderr.lines().count() == 1,
            "{extra:?}: {stderr}"
        );
    }
    // --current with --motor current reads it.
    let (code, stderr) = run(&[
        "calibrate".as_ref(),
        wide_log.as_os_str(),
        "--current".as_ref(),
        "c".as_ref(),
        "--motor".as_ref(),
        "current".as_ref(),
        "--trials".as_ref(),
        "20".as_ref(),
    ]);
    assert!(matches!(code, Some(0 | 3)), "{stderr}");
}

#[test]
fn export_refuses_a_value_no_target_can_hold() {
    let tmp = TempDir::new().unwrap();
    let log = sphere_log(tmp.path());
    let set = tmp.path().join("cal");
    calibrated_set(&log, &["--units", "uT"], &set);
    let cal: serde_json::Value = serde_json::from_slice(&fs::read(set.join("calibration.json")).unwrap()).unwrap();
    for (field, value, needle) in [
        ("bias", 1e300, "the bias along x would be 1"),
        // Converted to mGauss it overflows before it is a parameter: refused all the same.
        ("bias", f64::MAX, ""),
    ] {
        // Not marked usable (a usable calibration's bias is at most 1e6 magnitudes, refused
        // before export looks at it), and written with --force, which still refuses these.
        let mut c = cal.clone();
        c[field][0] = value.into();
        c["usable"] = false.into();
        c["reasons"] = serde_json::json!(["edited"]);
        let edited = tmp.path().join("edited.json");
        fs::write(&edited, serde_json::to_vec(&c).unwrap()).unwrap();
        for to in ["ardupilot", "px4", "motioncal", "magneto", "c"] {
            let out = tmp.path().join(format!("out-{to}"));
            let (code, stderr) = run(&[
                "export".as_ref(),
                edited.as_os_str(),
                "--to".as_ref(),
                to.as_ref(),
                "--out".as_ref(),
                out.as_os_str(),
                "--force".as_ref(),
            ]);
            assert_eq!(code, Some(2), "{to}: {stderr}");
            assert!(
                stderr.contains("edited.json")
                    && stderr.contains(needle)
                    && (needle.is_empty() || stderr.contains("nothing written")),
                "{to}: {stderr}"
            );
            assert!(!out.exists(), "{to}: written");
        }
    }
}

#[test]
fn a_planar_log_is_never_usable() {
    use rand::RngExt;
    // Readings on a flat circle of radius 30 (a vehicle that only turns), 1 % noise in the plane
    // and 0.1 % across it: the third axis is not determined, under the full model or auto.
    let tmp = TempDir::new().unwrap();
    for seed in 0..5 {
        let mut rng = magcal_core::rng::stream_rng(0x33, seed);
        let mut text = String::from("x,y,z\n");
        for i in 0..400 {
            let a = std::f64::consts::TAU * f64::from(i) / 400.0;
            let mut n = || rng.random_range(-0.5..0.5);
            let (x, y, z) = (
                30.0 * a.cos() + 5.0 + 0.6 * n(),
                30.0 * a.sin() - 3.0 + 0.6 * n(),
                2.0 + 0.06 * n(),
            );
            text.push_str(&format!("{x},{y},{z}\n"));
        }
        let log = tmp.path().join(format!("flat{seed}.csv"));
        fs::write(&log, text).unwrap();
        for fit in ["full", "auto"] {
            let (code, stderr) = run(&[
                "calibrate".as_ref(),
                log.as_os_str(),
                "--fit".as_ref(),
                fit.as_ref(),
                "--trials".as_ref(),
                "20".as_ref(),
            ]);
            // Not identifiable, or a fit to a sensor no magnetometer is (an ellipsoid flattened to
            // a disc): both say the readings do not determine the model.
            assert_eq!(code, Some(3), "seed {seed} {fit}: {stderr}");
            assert!(
                stderr.contains("not identifiable") || stderr.contains("not a plausible sensor"),
                "seed {seed} {fit}: {stderr}"
            );
        }
    }
}

/// The `i`-th chunk a stream sends after its head.
type Chunk = Box<dyn Fn(u64) -> Vec<u8> + Send>;

/// A FIFO at `path` fed from a thread: `head`, then `next(i)` for i = 0, 1, ... until the reader
/// goes away.
#[cfg(unix)]
fn endless_fifo(
    path: &Path,
    head: Vec<u8>,
    next: impl Fn(u64) -> Vec<u8> + Send + 'static,
) -> std::thread::JoinHandle<()> {
    let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let path = path.to_path_buf();
    std::thread::spawn(move || {
        use std::io::Write;
        let Ok(mut f) = fs::OpenOptions::new().write(true).open(&path) else {
            return;
        };
        if f.write_all(&head).is_err() {
            return;
        }
        for i in 0.. {
            if f.write_all(&next(i)).is_err() {
                return;
            }
        }
    })
}

#[cfg(unix)]
#[test]
fn endless_streams_end_with_one_line_naming_what_was_seen() {
    let tmp = TempDir::new().unwrap();
    // A DataFlash FMT header, then zeros for ever (bounded in bytes); a tlog of zeros (no frame
    // where one must be); a ULog header, then new format definitions for ever (bounded in
    // formats: 65,536, where a million took 457 MB and a stream of them 18 GB in 2 minutes).
    let mut fmt = vec![0xA3, 0x95, 0x80, 128, 89];
    fmt.extend(b"FMT\0");
    let mut f = b"BBnNZ".to_vec();
    f.resize(16, 0);
    fmt.extend(f);
    let mut c = b"Type,Length,Name,Format,Columns".to_vec();
    c.resize(64, 0);
    fmt.extend(c);
    let mut ulog = b"ULog\x01\x12\x35\x01".to_vec();
    ulog.extend([0u8; 8]);
    let cases: Vec<(&str, Vec<u8>, Chunk, &str)> = vec![
        (
            "dataflash",
            fmt,
            Box::new(|_| vec![0u8; 1 << 20]),
            "more than 1.0 GiB from a stream",
        ),
        (
            // A tlog must show a frame in its first 64 KiB.
            "tlog",
            Vec::new(),
            Box::new(|_| vec![0u8; 1 << 20]),
            "no valid MAVLink frame",
        ),
        (
            "ulog",
            ulog,
            Box::new(|i| {
                let body = format!("t{i}:uint8_t x;").into_bytes();
                let mut m = (body.len() as u16).to_le_bytes().to_vec();
                m.push(b'F');
                m.extend(body);
                m
            }),
            "more than 65536 formats",
        ),
    ];
    for (format, head, next, needle) in cases {
        let fifo = tmp.path().join(format!("stream-{format}"));
        let writer = endless_fifo(&fifo, head, next);
        let (code, stderr) = ends(&[
            "calibrate".as_ref(),
            fifo.as_os_str(),
            "--format".as_ref(),
            format.as_ref(),
        ]);
        assert_eq!(code, Some(2), "{format}: {stderr}");
        assert!(
            stderr.contains(&format!("stream-{format}")) && stderr.contains(needle) && stderr.lines().count() == 1,
            "{format}: {stderr}"
        );
        writer.join().unwrap();
    }
}

#[test]
fn skip_bad_drops_a_row_whose_attitude_is_partly_missing() {
    let tmp = TempDir::new().unwrap();
    let log = sphere_log(tmp.path());
    let text = fs::read_to_string(&log).unwrap();
    let mut rows = text.lines();
    let mut with = format!("{},r,p,h\n", rows.next().unwrap());
    for (i, r) in rows.enumerate() {
        // Line 9 (the 8th reading) has no heading.
        let h = if i == 7 { String::new() } else { (i % 360).to_string() };
        with.push_str(&format!("{r},0,0,{h}\n"));
    }
    let log = tmp.path().join("euler.csv");
    fs::write(&log, with).unwrap();
    let base = [
        "calibrate".as_ref(),
        log.as_os_str(),
        "--euler".as_ref(),
        "r,p,h".as_ref(),
        "--trials".as_ref(),
        "20".as_ref(),
    ];
    let (code, stderr) = run(&base);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains("euler.csv: line 9: --euler has a value in 2 of its 3 columns"),
        "{stderr}"
    );
    let o = magcal().args(base).args(["--skip-bad", "--json"]).output().unwrap();
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (j["skipped"].as_u64(), j["samples"].as_u64()),
        (Some(1), Some(599)),
        "{j}"
    );
}

#[test]
fn check_refuses_a_resealed_baseline_whose_statistics_are_not_its_trials() {
    // The standard errors of summary.csv set check's tolerances: widened a thousandfold and the
    // manifest resealed, the baseline would pass any run. Its trials.csv says what they are.
    let tmp = TempDir::new().unwrap();
    let base = tmp.path().join("base");
    run_into(&base, 7);
    let text = fs::read_to_string(base.join("summary.csv")).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    let se = header.split(',').position(|h| h == "se_mean").unwrap();
    let mut widened = format!("{header}\n");
    for line in lines {
        let mut cells: Vec<String> = line.split(',').map(str::to_string).collect();
        if let Ok(v) = cells[se].parse::<f64>() {
            cells[se] = format!("{}", v * 1000.0);
        }
        widened.push_str(&cells.join(","));
        widened.push('\n');
    }
    reseal(&base, "summary.csv", widened.as_bytes());
    let out = magcal()
        .args(["check", "--quiet", "--baseline"])
        .arg(&base)
        .arg(smoke())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("summary.csv: damaged: its statistics are not those of its trials.csv (")
            && stderr.contains("se_mean"),
        "{stderr}"
    );
    assert!(!stderr.contains("edited since it was written"), "{stderr}");
}

/// `magcal ARGS`: exit code and stderr, from strings.
fn run_str(args: &[&str]) -> (Option<i32>, String) {
    let args: Vec<&std::ffi::OsStr> = args.iter().map(std::ffi::OsStr::new).collect();
    run(&args)
}

/// Asserts a refusal in one short line that holds `needle`.
fn one_short_line(code: Option<i32>, stderr: &str, want_code: i32, needle: &str) {
    assert_eq!(code, Some(want_code), "{stderr}");
    let last = stderr.lines().last().unwrap_or_default();
    assert!(last.contains(needle), "{stderr}");
    assert!(
        last.chars().count() <= 300,
        "{} characters: {last}",
        last.chars().count()
    );
    assert!(!last.contains("NaN") || needle.contains("NaN"), "{last}");
}

#[test]
fn messages_name_the_cause_in_a_line_a_person_can_read() {
    let tmp = TempDir::new().unwrap();
    let dir = tmp.path();
    let log = sphere_log(dir);
    // The sphere with a time, a current (NaN at line 12) and an attitude turning about two axes.
    let text = fs::read_to_string(&log).unwrap();
    let mut rows = text.lines();
    let mut wide = format!("{},t,amps,qw,qx,qy,qz\n", rows.next().unwrap());
    let mut zero = String::from("x,y,z,qw,qx,qy,qz\n");
    let mut huge = zero.clone();
    for (i, r) in rows.enumerate() {
        let amps = if i == 10 {
            "NaN".to_string()
        } else {
            format!("{}", (i % 7) as f64)
        };
        let (a, b) = (0.01 * i as f64, 0.023 * i as f64);
        let q = [
            a.cos() * b.cos(),
            a.sin() * b.cos(),
            a.cos() * b.sin(),
            a.sin() * b.sin(),
        ];
        let q = format!("{},{},{},{}", q[0], q[1], q[2], q[3]);
        wide.push_str(&format!("{r},{},{amps},{q}\n", i as f64 * 0.1));
        zero.push_str(&format!("0,0,0,{q}\n"));
        huge.push_str(&format!("1e300,-2e300,3e299,{q}\n"));
    }
    let wide_log = dir.join("wide.csv");
    fs::write(&wide_log, wide).unwrap();
    let w = wide_log.to_str().unwrap();
    // A window far outside the log: the number as written, not its 309 digits.
    let (code, stderr) = run_str(&["calibrate", w, "--time", "t", "--from", "1e308"]);
    one_short_line(
        code,
        &stderr,
        2,
        "no reading between --from 1e308 and --to inf s: the log's readings span 0.000 to 59.900 s",
    );
    let (code, stderr) = run_str(&["calibrate", w, "--time", "t", "--from", "5", "--to=-1e300"]);
    one_short_line(code, &stderr, 2, "--from 5 --to -1e300: the window is empty");
    let (code, stderr) = run_str(&["calibrate", w, "--magnitude=-1e308"]);
    one_short_line(code, &stderr, 2, "--magnitude -1e308: must be positive and finite");
    // A current that is not a number names its line (the CSV reader reads NaN as no value).
    let (code, stderr) = run_str(&[
        "calibrate",
        w,
        "--current",
        "amps",
        "--motor",
        "current",
        "--trials",
        "20",
    ]);
    one_short_line(
        code,
        &stderr,
        2,
        "--motor current: 1 of 600 readings have no battery current (the first at line 12: its cell is empty or not a number)",
    );
    // Readings that are all zero, or whose squares overflow, against attitudes that turn: the
    // readings are the cause, not the attitudes.
    for (name, text, needle) in [
        (
            "zero.csv",
            &zero,
            "all 600 calibrated fields are zero: there is no field to align with the attitudes",
        ),
        (
            "huge.csv",
            &huge,
            "is too large to align (the sum of squares overflows)",
        ),
    ] {
        let p = dir.join(name);
        fs::write(&p, text).unwrap();
        let (code, stderr) = run_str(&["evaluate", "--raw", p.to_str().unwrap(), "--quaternion", "qw,qx,qy,qz"]);
        assert!(!stderr.contains("one axis"), "{stderr}");
        one_short_line(code, &stderr, 2, needle);
    }
    // A flight log whose readings the reader skipped says so in the reason, not only a count.
    for (kind, needle) in [
        (
            "nan",
            "0 readings, at least 9 are needed (skipped messages with values that are not finite numbers: 300 MAG)",
        ),
        (
            "back",
            "2 readings, at least 9 are needed (skipped messages whose time goes back (a reboot or damage): 298 MAG)",
        ),
    ] {
        let mut w = crate::dataflash::Writer::new();
        w.fmt(0x82, "MAG", "QBfff", "TimeUS,I,MagX,MagY,MagZ");
        for i in 0..300u32 {
            let t = if kind == "back" && i % 2 == 1 {
                1e6 + f64::from(300 - i) * 1e5
            } else {
                1e6 + f64::from(i) * 1e5
            };
            let v = if kind == "nan" {
                f64::NAN
            } else {
                400.0 * (f64::from(i) * 0.7).sin()
            };
            use crate::dataflash::V;
            w.msg(0x82, &[V::N(t), V::N(0.0), V::N(v), V::N(-v), V::N(v * 0.5)]);
        }
        let p = w.save(dir, &format!("{kind}.bin"));
        let (code, stderr) = run_str(&["calibrate", p.to_str().unwrap()]);
        one_short_line(code, &stderr, 3, needle);
    }
}

#[cfg(unix)]
#[test]
fn a_fifo_nobody_writes_to_ends_in_every_place_a_file_is_read() {
    // The idle bound, 30 s in use, at 300 ms here: every reader of a file that is not regular
    // opens it without waiting for a writer and gives up when nothing comes.
    let tmp = TempDir::new().unwrap();
    let log = sphere_log(tmp.path());
    let set = tmp.path().join("cal");
    calibrated_set(&log, &[], &set);
    let cal = set.join("calibration.json");
    let fifo = tmp.path().join("fifo");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let smoke = crate::common::smoke();
    let baseline = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../results/smoke");
    let f = fifo.as_os_str();
    let cases: Vec<Vec<&std::ffi::OsStr>> = vec![
        vec!["calibrate".as_ref(), f],
        vec!["calibrate".as_ref(), f, "--format".as_ref(), "dataflash".as_ref()],
        vec!["calibrate".as_ref(), f, "--format".as_ref(), "ulog".as_ref()],
        vec!["apply".as_ref(), f, log.as_os_str()],
        vec!["apply".as_ref(), cal.as_os_str(), f],
        vec!["export".as_ref(), f, "--to".as_ref(), "px4".as_ref()],
        vec!["evaluate".as_ref(), "--raw".as_ref(), f],
        vec!["run".as_ref(), f, "--quiet".as_ref()],
        vec!["check".as_ref(), f, "--baseline".as_ref(), baseline.as_os_str()],
        vec![
            "next".as_ref(),
            cal.as_os_str(),
            log.as_os_str(),
            "--scenario".as_ref(),
            f,
        ],
        vec!["check".as_ref(), smoke.as_os_str(), "--baseline".as_ref(), f],
    ];
    for args in cases {
        let started = Instant::now();
        let mut child = magcal_process()
            .args(&args)
            .env("MAGCAL_TEST_STREAM_IDLE_MS", "300")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        while child.try_wait().unwrap().is_none() {
            if started.elapsed() > Duration::from_secs(20) {
                child.kill().unwrap();
                panic!("magcal {args:?} still runs after 20 s");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.contains("fifo"), "{args:?}: {stderr}");
    }
}

/// Strings a page must show as text: pieces of markup, script-data escapes, entities, quotes and
/// characters outside ASCII, joined by single spaces (the DOM's text keeps single spaces).
fn page_string() -> impl proptest::strategy::Strategy<Value = String> {
    use proptest::prelude::*;
    let piece = prop_oneof![
        proptest::sample::select(
            &[
                "<!--",
                "-->",
                "<script>",
                "</script",
                "</script>",
                "<img src=x onerror=document.title='pwned'>",
                "<span style=\"background:url(http://127.0.0.1:9/x)\">",
                "&amp;",
                "&lt;",
                "&",
                "<",
                ">",
                "\"",
                "'",
                "`",
                "${x}",
                "{{x}}",
                "</style>",
                "<b>",
                "\\",
                "é",
                "😀",
                "uT",
                "\u{2028}",
                "\u{202e}",
            ][..]
        )
        .prop_map(str::to_string),
        "[a-zA-Z0-9<>&\"'=/!:;-]{1,12}",
    ];
    proptest::collection::vec(piece, 1..8).prop_map(|p| p.join(" "))
}

/// The calibration set the page fuzz edits (one calibrate for every case), under cargo's
/// temporary directory for tests (a static is never dropped, so it is not left in /tmp).
fn page_fuzz_set() -> &'static Path {
    static SET: std::sync::OnceLock<(TempDir, PathBuf)> = std::sync::OnceLock::new();
    &SET.get_or_init(|| {
        let tmp = TempDir::new_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
        let log = sphere_log(tmp.path());
        let set = tmp.path().join("cal");
        calibrated_set(&log, &["--units", "uT"], &set);
        (tmp, set)
    })
    .1
}

/// Copies the regular files of `from` into a new directory `to`.
fn copy_dir(from: &Path, to: &Path) {
    fs::create_dir(to).unwrap();
    for e in fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

proptest::proptest! {
    #![proptest_config(proptest::test_runner::Config {
        cases: std::env::var("MAGCAL_FUZZ_PAGE_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(4),
        failure_persistence: None,
        ..proptest::test_runner::Config::default()
    })]

    /// Random strings in the fields a calibration page shows (its units, in tables and figure
    /// titles; its log's name, in the title; the fit's reason and the columns, in its data):
    /// the page runs no script, fetches nothing, and holds each string as text.
    #[test]
    fn fuzzed_fields_of_a_page_are_its_text(units in page_string(), log in page_string(), reason in page_string()) {
        let tmp = TempDir::new().unwrap();
        let set = tmp.path().join("cal");
        copy_dir(page_fuzz_set(), &set);
        let log_name = log.replace(['/', '\\'], "|");
        edit_and_reseal(&set, "calibration.json", |c| {
            c["units"] = units.clone().into();
            c["fit_reason"] = reason.clone().into();
            c["log"] = log_name.clone().into();
        });
        let page_path = tmp.path().join("page.html");
        report(&set, &page_path);
        let Some(browser) = chromium() else { return Ok(()) };
        let page = open(&browser, &page_path, Duration::from_secs(60));
        proptest::prop_assert!(page.errors.is_empty(), "{:?}", page.errors);
        proptest::prop_assert!(page.remote_requests(&page_path.canonicalize().unwrap()).is_empty(), "{:?}", page.requests);
        let title = page.eval("document.title");
        proptest::prop_assert_ne!(title.as_str(), Some("pwned"));
        let data = page.eval("JSON.parse(document.getElementById('magcal-data').textContent).calibration");
        proptest::prop_assert_eq!(data["units"].as_str(), Some(units.as_str()));
        proptest::prop_assert_eq!(data["fit_reason"].as_str(), Some(reason.as_str()));
        // The text nodes outside script and style elements, as they are (not as rendered).
        let text = page.eval(
            "Array.from(document.body.querySelectorAll('*')).filter(e => !['SCRIPT', 'STYLE'].includes(e.tagName)).map(e => Array.from(e.childNodes).filter(n => n.nodeType === 3).map(n => n.nodeValue).join('')).join('\\n')",
        );
        let text = text.as_str().unwrap_or_default();
        proptest::prop_assert!(text.contains(&units), "units {:?} not in the page's text", units);
        proptest::prop_assert!(text.contains(&log_name), "log {:?} not in the page's text", log_name);
        proptest::prop_assert_eq!(page.eval("document.querySelectorAll('[onerror], [onload], span[style]').length"), 0);
    }
}

#[test]
fn a_glitch_reading_is_named_and_reject_drops_it() {
    // The sphere with one row a flipped exponent: no calibration fits it (the fit runs off or
    // its matrix loses rank), which is the glitch's doing, not the log's.
    let tmp = TempDir::new().unwrap();
    let log = sphere_log(tmp.path());
    let text = fs::read_to_string(&log).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines[200] = "1e20,1,2";
    let glitched = tmp.path().join("glitch.csv");
    fs::write(&glitched, lines.join("\n") + "\n").unwrap();
    let g = glitched.to_str().unwrap();
    let (code, stderr) = run_str(&["calibrate", g, "--trials", "20"]);
    assert_eq!(code, Some(3), "{stderr}");
    assert!(
        stderr.contains("1 reading is a glitch, more than 1000 times the readings' own size")
            && stderr.contains("line 201 (1e20, 1, 2); --reject K drops them"),
        "{stderr}"
    );
    // --reject drops it first, counts it, and the rest calibrates.
    let out = magcal()
        .args(["calibrate", g, "--reject", "5", "--trials", "20", "--json"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(j["rejected"].as_u64() >= Some(1), "{}", j["rejected"]);
    assert_eq!(j["samples"].as_u64().unwrap() + j["rejected"].as_u64().unwrap(), 600);
    let notes = j["log_notes"].to_string();
    assert!(
        notes.contains("--reject dropped the glitches first: 1 reading is a glitch"),
        "{notes}"
    );
}
