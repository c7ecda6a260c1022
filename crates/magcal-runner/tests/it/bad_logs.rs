//! Bad logs, options and result sets, end to end: every case exits 2 with ONE stderr line that
//! names the file and the line, column or option, quotes at most a short excerpt, and leaves every
//! input and earlier output byte-identical. The binary runs under the memory limit of
//! [`crate::common::magcal`], so an unbounded read fails here instead of exhausting the machine.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use crate::common::{magcal, magcal_with_limits, run_into, scenarios};
use magcal_runner::digest::sha256_hex;
use tempfile::TempDir;

/// The public ck-explorer log, in `../shared/data/` beside the repository.
fn ck_log() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ck-explorer/acc_mag_log.csv")
        .display()
        .to_string()
}

/// Every entry below `dir`: a file's bytes, or a symbolic link's target (never followed).
fn state(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
            let meta = fs::symlink_metadata(&p).unwrap();
            if meta.file_type().is_symlink() {
                out.insert(rel, fs::read_link(&p).unwrap().into_os_string().into_encoded_bytes());
            } else if meta.is_dir() {
                walk(root, &p, out);
            } else if meta.is_file() {
                out.insert(rel, fs::read(&p).unwrap());
            } else {
                out.insert(rel, b"<special>".to_vec());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// Runs `args` (`{}` replaced by the temporary directory) in `dir`; asserts exit 2, one stderr
/// line of at most 400 characters holding every needle, and `dir` unchanged.
fn refused(dir: &Path, args: &[&str], needles: &[&str]) {
    refused_with(magcal(), dir, args, needles);
}

fn refused_with(mut cmd: assert_cmd::Command, dir: &Path, args: &[&str], needles: &[&str]) {
    let before = state(dir);
    let root = dir.to_str().unwrap();
    let args: Vec<String> = args.iter().map(|a| a.replace("{}", root)).collect();
    let out = cmd.current_dir(dir).args(&args).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    let what = format!("magcal {}: {stderr}", args.join(" "));
    assert_eq!(out.status.code(), Some(2), "{what}");
    assert!(
        stderr.starts_with("magcal: error: ") && stderr.ends_with('\n'),
        "{what}"
    );
    let lines = crate::common::error_lines(&stderr);
    assert_eq!(lines.len(), 1, "{what}");
    assert!(lines[0].len() <= 400, "{} characters: {what}", lines[0].len());
    for needle in needles {
        assert!(stderr.contains(needle), "{needle:?} missing: {what}");
    }
    assert!(state(dir) == before, "{what}: the directory changed");
}

/// A directory with `files` and an earlier calibration set `out/` (of the ck-explorer log).
fn with_files(files: &[(&str, &[u8])]) -> TempDir {
    let tmp = TempDir::new().unwrap();
    for (name, bytes) in files {
        fs::write(tmp.path().join(name), bytes).unwrap();
    }
    magcal()
        .current_dir(tmp.path())
        .args(["calibrate", &ck_log(), "--out", "out"])
        .assert()
        .success();
    tmp
}

/// The first `rows` data rows of the ck-explorer log (header `ax,ay,az,mx,my,mz`).
fn ck(rows: usize) -> String {
    let text = fs::read_to_string(ck_log()).unwrap();
    text.lines().take(rows + 1).map(|l| format!("{l}\n")).collect()
}

#[test]
fn bad_cells_are_named_by_the_line_an_editor_shows() {
    let good = ck(200);
    let mut lines: Vec<&str> = good.lines().collect();
    lines.insert(3, "");
    lines.insert(3, "");
    let blank = format!("{}\n", lines.join("\n"));
    // Line 6 of `blank` is the 3rd data row after two blank lines: make it NaN.
    let blank = blank.replacen(lines[5], "NaN,0,0,NaN,0.1,0.2", 1);
    let cr_only = good.replace('\n', "\r").replacen("\r", "\r\r", 2);
    let cr_only = {
        let mut l: Vec<String> = cr_only.split('\r').map(str::to_string).collect();
        l[4] = "0,0,0,0.1,0.2,inf".into();
        l.join("\r")
    };
    let crlf = good.replace('\n', "\r\n").replacen("\r\n", "\r\n\r\n", 1);
    let crlf = {
        let mut l: Vec<String> = crlf.split("\r\n").map(str::to_string).collect();
        l[9] = "0,0,0,0.1,,0.2".into();
        l.join("\r\n")
    };
    let tmp = with_files(&[
        ("blank.csv", blank.as_bytes()),
        ("cr.csv", cr_only.as_bytes()),
        ("crlf.csv", crlf.as_bytes()),
    ]);
    let d = tmp.path();
    refused(
        d,
        &["calibrate", "blank.csv", "--out", "out"],
        &["blank.csv: line 6: column 4 (mx) is NaN"],
    );
    refused(
        d,
        &["calibrate", "cr.csv", "--out", "out"],
        &["cr.csv: line 5: column 6 (mz) is inf"],
    );
    refused(
        d,
        &["calibrate", "crlf.csv"],
        &["crlf.csv: line 10: no value in column 5 (my)"],
    );
    refused(
        d,
        &["apply", "out/calibration.json", "blank.csv"],
        &["blank.csv: line 6: column 4 (mx) is NaN"],
    );
}

#[test]
fn unbounded_inputs_stop_with_one_short_line() {
    let long_line = format!("x,y,z\n1,2,3\n{}\n", "7".repeat(2 << 20));
    let open_quote = format!("x,y,z\n1,2,3\n4,5,\"6{}\n7,8,9\n", ",1".repeat(50_000));
    let long_cell = format!("x,y,z\n1,2,3\n4,5,{}\n", "z".repeat(100_000));
    let tmp = with_files(&[
        ("long.csv", long_line.as_bytes()),
        ("quote.csv", open_quote.as_bytes()),
        ("cell.csv", long_cell.as_bytes()),
        ("cal.json", b"{"),
    ]);
    let d = tmp.path();
    refused(
        d,
        &["calibrate", "/dev/zero", "--out", "out"],
        &["/dev/zero: line 1 is longer than 1.0 MiB"],
    );
    refused(
        d,
        &["calibrate", "long.csv"],
        &["long.csv: line 3 is longer than 1.0 MiB"],
    );
    refused(
        d,
        &["calibrate", "quote.csv"],
        &["quote.csv: line 3: a quote (\") is not closed"],
    );
    refused(
        d,
        &["calibrate", "cell.csv"],
        &["cell.csv: line 3, column 3 (z): \"zzzz", "is not a number"],
    );
    refused(d, &["apply", "/dev/zero", &ck_log()], &["/dev/zero: more than 1.0 MiB"]);
    refused(d, &["apply", "cal.json", "/dev/zero"], &["cal.json"]);
    refused(d, &["calibrate", "{}"], &["is a directory, not a log"]);
    refused(d, &["calibrate", "missing.csv"], &["missing.csv: cannot read the log"]);
    refused(d, &["run", "/dev/zero"], &["/dev/zero: more than 16.0 MiB"]);
}

#[test]
fn a_fifo_that_never_ends_is_stopped_by_the_memory_budget() {
    let tmp = with_files(&[]);
    let fifo = tmp.path().join("endless.csv");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let writer = {
        let fifo = fifo.clone();
        std::thread::spawn(move || {
            use std::io::Write;
            let mut f = fs::OpenOptions::new().write(true).open(&fifo).unwrap();
            let block = "0.1,0.2,0.3\n".repeat(10_000);
            let _ = f.write_all(b"x,y,z\n");
            // Until the reader gives up (EPIPE: the test harness ignores SIGPIPE).
            while f.write_all(block.as_bytes()).is_ok() {}
        })
    };
    // 1 GiB of address space: a budget of half of it at 256 B per reading, about 2.1 million rows.
    refused_with(
        magcal_with_limits(1 << 30, None),
        tmp.path(),
        &["calibrate", "endless.csv", "--out", "out"],
        &["endless.csv: line ", "the log holds more rows than fit in memory"],
    );
    writer.join().unwrap();
}

#[test]
fn separators_are_detected_and_give_the_same_readings() {
    let comma = ck(3000);
    let semicolon_decimal_comma = comma.replace(',', ";").replace('.', ",");
    let tab = comma.replace(',', "\t");
    let spaces = comma.replace(',', "   ");
    let bom = format!("\u{feff}{}", comma.replace('\n', "\r\n"));
    let tmp = with_files(&[
        ("comma.csv", comma.as_bytes()),
        ("semi.csv", semicolon_decimal_comma.as_bytes()),
        ("tab.tsv", tab.as_bytes()),
        ("spaces.txt", spaces.as_bytes()),
        ("bom.csv", bom.as_bytes()),
    ]);
    let json = |name: &str| -> serde_json::Value {
        let out = magcal()
            .current_dir(tmp.path())
            .args(["calibrate", name, "--json"])
            .output()
            .unwrap();
        assert!(out.status.success(), "{name}: {}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        // What the fit made of the readings (not what names the file).
        [
            "samples",
            "columns",
            "bias",
            "psi_deg",
            "scale",
            "p",
            "residual_rms",
            "noise",
        ]
        .map(|k| v[k].clone())
        .to_vec()
        .into()
    };
    let want = json("comma.csv");
    assert_eq!(want[0], 3000);
    assert_eq!(want[1], serde_json::json!(["mx", "my", "mz"]));
    // The same numbers parse to the same f64: the calibrations are identical, not merely close.
    for name in ["semi.csv", "tab.tsv", "spaces.txt", "bom.csv"] {
        assert_eq!(json(name), want, "{name}");
    }
}

#[test]
fn unclear_columns_are_refused_naming_the_reason() {
    let log = ck(100);
    let decimal_comma_in_commas = "x,y,z\n\"0,5\",1,2\n";
    let dup = "x,y,z,x,y,z\n1,2,3,4,5,6\n";
    let two = "a b\n1 2\n";
    let tmp = with_files(&[
        ("log.csv", log.as_bytes()),
        ("dc.csv", decimal_comma_in_commas.as_bytes()),
        ("dup.csv", dup.as_bytes()),
        ("two.txt", two.as_bytes()),
        ("empty.csv", b""),
        ("comments.csv", b"# nothing\n\n# here\n"),
        ("header.csv", b"x,y,z\n\n"),
        ("allbad.csv", b"x,y,z\nnan,1,2\n1,,2\n"),
    ]);
    let d = tmp.path();
    for (args, needles) in [
        (
            vec!["calibrate", "log.csv", "--columns", "1,1,1"],
            vec!["--columns \"1,1,1\": column 1 (ax) is chosen twice"],
        ),
        (
            vec!["calibrate", "log.csv", "--columns", "mx,MX,my"],
            vec!["column 4 (mx) is chosen twice"],
        ),
        (
            vec!["calibrate", "log.csv", "--columns", "a,b,c"],
            vec!["log.csv", "no column named \"a\""],
        ),
        (
            vec!["calibrate", "log.csv", "--columns", "1,2,9"],
            vec!["log.csv", "column 9 is not in the log (6 columns)"],
        ),
        (
            vec!["calibrate", "log.csv", "--columns", "1,2"],
            vec!["--columns \"1,2\": give three columns"],
        ),
        (
            vec!["calibrate", "dc.csv"],
            vec!["dc.csv: line 2, column 1 (x): \"0,5\"", "decimal comma"],
        ),
        (
            vec!["calibrate", "dup.csv"],
            vec!["dup.csv", "columns 1, 4 are all named \"x\""],
        ),
        (
            vec!["calibrate", "dup.csv", "--columns", "x,y,z"],
            vec!["columns 1 and 4 are both named \"x\""],
        ),
        (
            vec!["calibrate", "two.txt"],
            vec!["two.txt (read as space-separated)", "fewer than three numeric columns"],
        ),
        (vec!["calibrate", "empty.csv"], vec!["empty.csv: the log is empty"]),
        (
            vec!["calibrate", "comments.csv"],
            vec!["comments.csv: the log is empty"],
        ),
        (
            vec!["calibrate", "header.csv"],
            vec!["header.csv: the log has a header but no readings"],
        ),
        (
            vec!["calibrate", "allbad.csv"],
            vec!["allbad.csv: line 2: column 1 (x) is NaN"],
        ),
        (
            vec!["calibrate", "allbad.csv", "--skip-bad"],
            vec!["allbad.csv: no readings (2 rows skipped)"],
        ),
        (
            vec!["apply", "out/calibration.json", "log.csv", "--columns", "1,1,2"],
            vec!["log.csv", "--columns \"1,1,2\": column 1 (ax) is chosen twice"],
        ),
    ] {
        refused(d, &args, &needles);
    }
}

#[test]
fn site_date_units_and_box_flags_are_typed_at_the_edge() {
    let log = ck(12_000);
    let tmp = with_files(&[("log.csv", log.as_bytes())]);
    let d = tmp.path();
    let cal = |extra: &[&'static str]| [&["calibrate", "log.csv"][..], extra].concat();
    for (args, needles) in [
        (
            cal(&["--site", "north", "--date", "2013.0", "--units", "G"]),
            vec!["invalid value 'north' for '--site", "in numbers"],
        ),
        (
            cal(&["--site", "91,0", "--date", "2013.0", "--units", "G"]),
            vec!["'--site", "latitude 91 is outside [-90, 90]"],
        ),
        (
            cal(&["--site", "1,2,1e9", "--date", "2013.0", "--units", "G"]),
            vec!["'--site", "height 1000000000 m is outside"],
        ),
        (
            cal(&["--site", "1,2", "--date", "2013-02-30", "--units", "G"]),
            vec!["'--date", "2013-02-30 is not a date"],
        ),
        (
            cal(&["--site", "1,2", "--date", "2013-02-29", "--units", "G"]),
            vec!["'--date", "2013-02-29 is not a date"],
        ),
        (
            cal(&["--site", "1,2", "--date", "20130", "--units", "G"]),
            vec!["'--date", "year 20130 is outside [1900, 2100]"],
        ),
        (
            cal(&["--site", "1,2", "--date", "13/01/2013", "--units", "G"]),
            vec!["'--date", "give YYYY-MM-DD or a decimal year"],
        ),
        (
            cal(&["--site", "1,2", "--date", "2040-01-01", "--units", "G"]),
            vec!["no model holds it"],
        ),
        (
            cal(&["--site", "1,2", "--date", "2013.0", "--units", "G", "--wmm", "WMM1999"]),
            vec!["'--wmm", "unknown model; known: WMM2010"],
        ),
        (
            cal(&["--site", "1,2", "--date", "2013.0", "--units", "furlongs"]),
            vec!["'--units", "furlongs"],
        ),
        (cal(&["--date", "2013.0"]), vec!["--site"]),
        (cal(&["--wmm", "WMM2010"]), vec!["--site"]),
        (cal(&["--site", "1,2", "--units", "G"]), vec!["--date"]),
        (
            cal(&["--site", "1,2", "--date", "2013.0"]),
            vec!["--site: give --units"],
        ),
        (
            cal(&["--site", "-33.92,18.42", "--date", "2013.0", "--magnitude", "0.5"]),
            vec!["--site with --magnitude", "drop --site"],
        ),
        (
            cal(&[
                "--site",
                "1,2",
                "--date",
                "2013.0",
                "--units",
                "G",
                "--roll=5,-5",
                "--pitch=-5,5",
            ]),
            vec!["'--roll", "the minimum must be below the maximum"],
        ),
        (
            cal(&[
                "--site",
                "1,2",
                "--date",
                "2013.0",
                "--units",
                "G",
                "--roll=-400,0",
                "--pitch=-5,5",
            ]),
            vec!["'--roll", "[-360, 360]"],
        ),
        (
            cal(&[
                "--site",
                "1,2",
                "--date",
                "2013.0",
                "--units",
                "G",
                "--roll=-5,5",
                "--pitch=-200,200",
            ]),
            vec!["'--pitch", "spans more than 360 degrees"],
        ),
        (
            cal(&[
                "--site",
                "1,2",
                "--date",
                "2013.0",
                "--units",
                "G",
                "--roll=-5,5",
                "--pitch=nan,5",
            ]),
            vec!["'--pitch", "finite"],
        ),
        (
            cal(&["--site", "1,2", "--date", "2013.0", "--units", "G", "--yaw", "1,2,3"]),
            vec!["'--yaw", "two numbers"],
        ),
        (
            cal(&["--site", "1,2", "--date", "2013.0", "--units", "G", "--roll=-5,5"]),
            vec!["needs both --roll and --pitch"],
        ),
        (cal(&["--roll=-5,5", "--pitch=-5,5"]), vec!["--site"]),
        (cal(&["--magnitude=-1"]), vec!["--magnitude -1: must be positive"]),
        (cal(&["--reject", "0"]), vec!["--reject 0: K = 0: must be at least 2"]),
    ] {
        refused(d, &args, &needles);
    }
}

#[test]
fn a_southern_site_is_taken_with_or_without_an_equals_sign() {
    let log = ck(12_000);
    let tmp = with_files(&[("log.csv", log.as_bytes())]);
    let magnitude = |site: &[&str]| -> f64 {
        let out = magcal()
            .current_dir(tmp.path())
            .args(["calibrate", "log.csv", "--json", "--date", "2024-06-01", "--units", "G"])
            .args(site)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert!(
            v["magnitude_source"]
                .as_str()
                .unwrap()
                .starts_with("WMM2020 at -33.92, 18.42"),
            "{v}"
        );
        v["magnitude"].as_f64().unwrap()
    };
    let (a, b) = (
        magnitude(&["--site", "-33.92,18.42"]),
        magnitude(&["--site=-33.92,18.42"]),
    );
    // Cape Town's field is about 25,600 nT (0.256 G): weak, as the South Atlantic Anomaly is.
    assert!(a.to_bits() == b.to_bits() && (0.2..0.3).contains(&a), "{a} {b}");
}

#[test]
fn a_calibration_file_with_a_byte_order_mark_is_read() {
    let log = ck(12_000);
    let tmp = with_files(&[("log.csv", log.as_bytes())]);
    let d = tmp.path();
    magcal()
        .current_dir(d)
        .args(["calibrate", "log.csv", "--out", "cal"])
        .assert()
        .success();
    let plain = fs::read(d.join("cal/calibration.json")).unwrap();
    let mut bom = b"\xef\xbb\xbf".to_vec();
    bom.extend_from_slice(&plain);
    fs::write(d.join("bom.json"), bom).unwrap();
    let apply = |cal: &str| {
        magcal()
            .current_dir(d)
            .args(["apply", cal, "log.csv"])
            .output()
            .unwrap()
    };
    let (a, b) = (apply("cal/calibration.json"), apply("bom.json"));
    assert!(
        a.status.success() && b.status.success(),
        "{}",
        String::from_utf8_lossy(&b.stderr)
    );
    assert_eq!(a.stdout, b.stdout);
    assert_eq!(String::from_utf8(a.stdout).unwrap().lines().count(), 12_001);
}

/// What a case does to its copy of the set.
type Damage = Box<dyn Fn(&Path)>;

/// A result set of the smoke scenario, made once per test that needs one.
fn baseline() -> (TempDir, PathBuf) {
    let tmp = TempDir::new().unwrap();
    let set = tmp.path().join("set");
    run_into(&set, 7);
    (tmp, set)
}

/// Edits the manifest of `set` and seals it again with its own hash (as
/// `scripts/seal-manifests.py` does), so that what is tested is the reader's next check.
fn edit_manifest(set: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = set.join("manifest.json");
    let mut m: serde_json::Value = serde_json::from_slice(&fs::read(&path).unwrap()).unwrap();
    edit(&mut m);
    m.as_object_mut().unwrap().remove("manifest_sha256");
    fs::write(path, sealed(&serde_json::to_string_pretty(&m).unwrap())).unwrap();
}

/// A pretty-printed JSON object with `manifest_sha256` appended as its last member: the SHA-256
/// of the text with that value empty.
fn sealed(text: &str) -> String {
    let body = text.strip_suffix("\n}").unwrap();
    let with = |hash: &str| format!("{body},\n  \"manifest_sha256\": \"{hash}\"\n}}");
    with(&sha256_hex(with("").as_bytes()))
}

/// Copies the regular files of the set `from` into a new directory `to`.
fn copy_set(from: &Path, to: &Path) {
    fs::create_dir(to).unwrap();
    for e in fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_file() {
            fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

#[test]
fn an_edited_manifest_is_damage_before_any_comparison() {
    let (tmp, set) = baseline();
    let d = tmp.path();
    let smoke = scenarios().join("smoke.toml");
    let smoke = smoke.to_str().unwrap();
    let text = fs::read_to_string(set.join("manifest.json")).unwrap();
    // The set as written checks, and so does the same manifest sealed by the test's own rule.
    magcal()
        .args(["check", smoke, "--quiet", "--baseline"])
        .arg(&set)
        .assert()
        .code(0)
        .stderr("");
    let own = text.rsplit_once(",\n  \"manifest_sha256\"").unwrap().0.to_string() + "\n}";
    assert_eq!(sealed(&own), text);
    let summary_hash = serde_json::from_str::<serde_json::Value>(&text).unwrap()["file_sha256"]["summary.csv"]
        .as_str()
        .unwrap()
        .to_string();
    let mut flipped = summary_hash.clone();
    flipped.replace_range(..1, if summary_hash.starts_with('0') { "1" } else { "0" });
    let edits: [(&str, &str, String); 5] = [
        // The seed: read as a regression (exit 1) without the manifest's own hash.
        ("seed", "\"seed\": 7,", "\"seed\": 8,".into()),
        ("hash", &summary_hash, flipped),
        ("trials", "\"trials\": 20,", "\"trials\": 21,".into()),
        (
            "description",
            "\"description\": \"",
            "\"description\": \"edited: ".into(),
        ),
        ("indent", "\n  \"seed\"", "\n\t\"seed\"".into()),
    ];
    for (name, from, to) in &edits {
        assert_eq!(text.matches(from).count(), 1, "{name}");
        let copy = d.join(name);
        copy_set(&set, &copy);
        fs::write(copy.join("manifest.json"), text.replacen(from, to, 1)).unwrap();
        let damaged = format!("{name}/manifest.json: damaged: manifest.json was edited");
        refused(
            d,
            &["check", smoke, "--baseline", name],
            &[&damaged, "differs from the manifest_sha256"],
        );
    }
    // plot, and a run or design into the set, read the same manifest.
    refused(
        d,
        &["plot", "seed"],
        &["seed/manifest.json: damaged: manifest.json was edited"],
    );
    refused(
        d,
        &["run", smoke, "--quiet", "--trials", "5", "--out", "hash"],
        &["hash/manifest.json: damaged: manifest.json was edited"],
    );
    refused(
        d,
        &["design", smoke, "--quiet", "--out", "trials"],
        &["trials/manifest.json: damaged: manifest.json was edited"],
    );
    // The hash itself edited, moved from the end, or renamed.
    let digits = &text[text.len() - 67..text.len() - 3];
    assert!(
        text.ends_with(&format!("\"manifest_sha256\": \"{digits}\"\n}}")),
        "{text}"
    );
    let member = format!(",\n  \"manifest_sha256\": \"{digits}\"");
    let moved =
        text.replacen(&member, "", 1)
            .replacen("{\n", &format!("{{\n  \"manifest_sha256\": \"{digits}\",\n"), 1);
    let short = text.replacen(digits, &digits[1..], 1);
    let renamed = text.replacen("\"manifest_sha256\"", "\"manifest_sha265\"", 1);
    for (name, edited, why) in [
        ("moved", moved, "manifest_sha256 is not its last field"),
        ("short", short, "its manifest_sha256 is not a SHA-256"),
        (
            "renamed",
            renamed,
            "its last field \"manifest_sha265\" holds a SHA-256: manifest_sha256 renamed?",
        ),
    ] {
        let copy = d.join(name);
        copy_set(&set, &copy);
        fs::write(copy.join("manifest.json"), edited).unwrap();
        refused(
            d,
            &["check", smoke, "--baseline", name],
            &[&format!(
                "{name}/manifest.json: damaged: manifest.json was edited ({why}"
            )],
        );
    }
}

#[test]
fn an_edited_calibration_manifest_is_damage_to_every_command_that_reads_it() {
    let tmp = with_files(&[]);
    let d = tmp.path();
    let path = d.join("out/manifest.json");
    let text = fs::read_to_string(&path).unwrap();
    let edited = text.replacen("\"log_rows\": ", "\"log_rows\": 1", 1);
    assert_ne!(edited, text);
    fs::write(&path, edited).unwrap();
    let log = ck_log();
    let damaged = "out/manifest.json: damaged: manifest.json was edited";
    refused(d, &["calibrate", &log, "--out", "out"], &[damaged]);
    refused(
        d,
        &["apply", "out/calibration.json", &log, "--out", "out/applied.csv"],
        &[damaged],
    );
    refused(d, &["calibrate", &log, "--out", "out/inner"], &[damaged]);
}

#[test]
fn a_manifest_without_its_own_hash_is_read_with_a_note() {
    let (tmp, set) = baseline();
    let smoke = scenarios().join("smoke.toml");
    let path = set.join("manifest.json");
    let text = fs::read_to_string(&path).unwrap();
    let old = text.rsplit_once(",\n  \"manifest_sha256\"").unwrap().0.to_string() + "\n}";
    fs::write(&path, &old).unwrap();
    let out = magcal()
        .current_dir(tmp.path())
        .args(["check", "--quiet", "--baseline", "set"])
        .arg(&smoke)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert_eq!(
        stderr,
        "magcal: note: set/manifest.json records no manifest_sha256 (made by an older magcal): edits of the manifest itself cannot be detected\n"
    );
    // Sealed as the script seals the committed baselines, it is the manifest magcal writes.
    assert_eq!(sealed(&old), text);
}

#[test]
fn the_committed_smoke_baseline_is_sealed_and_checks() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let text = fs::read_to_string(root.join("results/smoke/manifest.json")).unwrap();
    let own = text.rsplit_once(",\n  \"manifest_sha256\"").unwrap().0.to_string() + "\n}";
    assert_eq!(sealed(&own), text);
    magcal()
        .current_dir(&root)
        .args(["check", "scenarios/smoke.toml", "--quiet"])
        .assert()
        .code(0)
        .stderr("");
}

#[test]
fn check_and_plot_read_only_the_regular_files_of_the_set() {
    let (tmp, set) = baseline();
    let smoke = scenarios().join("smoke.toml");
    let smoke = smoke.to_str().unwrap();
    let drone = scenarios().join("drone.toml");
    // Another scenario's baseline: named, before any run.
    refused(
        tmp.path(),
        &["check", drone.to_str().unwrap(), "--baseline", "set"],
        &["set: the baseline of scenario \"smoke\", not of \"drone\""],
    );
    let cases: Vec<(&str, Damage, Vec<&str>)> = vec![
        (
            "up",
            Box::new(|s: &Path| {
                edit_manifest(s, |m| {
                    m["files"].as_array_mut().unwrap().push("../../../etc/hostname".into())
                })
            }),
            vec!["manifest.json: names the file \"../../../etc/hostname\", which is not a plain file name"],
        ),
        (
            "abs",
            Box::new(|s: &Path| {
                edit_manifest(s, |m| {
                    m["file_sha256"]["/etc/hostname"] = "00".into();
                })
            }),
            vec!["manifest.json: names the file \"/etc/hostname\""],
        ),
        (
            "zero",
            Box::new(|s: &Path| {
                fs::remove_file(s.join("summary.csv")).unwrap();
                std::os::unix::fs::symlink("/dev/zero", s.join("summary.csv")).unwrap();
            }),
            vec!["summary.csv: is a symbolic link, not a regular file"],
        ),
        (
            "designs",
            Box::new(|s: &Path| {
                fs::remove_file(s.join("designs.csv")).unwrap();
                std::os::unix::fs::symlink("/dev/zero", s.join("designs.csv")).unwrap();
            }),
            vec!["designs.csv: is a symbolic link, not a regular file"],
        ),
        (
            "manifest",
            Box::new(|s: &Path| {
                fs::remove_file(s.join("manifest.json")).unwrap();
                std::os::unix::fs::symlink("/dev/zero", s.join("manifest.json")).unwrap();
            }),
            vec!["manifest.json: is a symbolic link, not a regular file"],
        ),
    ];
    for (name, damage, needles) in cases {
        let copy = tmp.path().join(name);
        copy_set(&set, &copy);
        damage(&copy);
        refused(tmp.path(), &["check", smoke, "--baseline", name], &needles);
        if name != "up" && name != "abs" {
            refused(tmp.path(), &["plot", name], &needles);
        }
    }
}

#[test]
fn a_pso_run_of_days_is_refused_with_its_estimate() {
    let tmp = TempDir::new().unwrap();
    let text = fs::read_to_string(scenarios().join("smoke.toml")).unwrap();
    assert!(text.contains("\nparticles = 40\n") && text.contains("\niterations = 150\n"));
    let big = text
        .replace("\nparticles = 40\n", "\nparticles = 100000\n")
        .replace("\niterations = 150\n", "\niterations = 10000000\n");
    fs::write(tmp.path().join("big.toml"), big).unwrap();
    // 4 runs + 1 design of 1e5 x (1e7 + 1) evaluations at 0.38 us each, on 2 threads: 11.0 days.
    refused(
        tmp.path(),
        &["design", "big.toml", "--threads", "2", "--out", "out"],
        &[
            "big.toml: the run's PSO work is estimated at 11.0 days on 2 threads",
            "--allow-long",
        ],
    );
}

#[test]
fn an_output_that_would_destroy_an_input_or_a_set_is_refused() {
    let log = ck(500);
    let tmp = with_files(&[("x.csv", log.as_bytes())]);
    let d = tmp.path();
    fs::hard_link(d.join("x.csv"), d.join("hard.csv")).unwrap();
    fs::copy(d.join("out/calibration.json"), d.join("cal.json")).unwrap();
    fs::copy(scenarios().join("smoke.toml"), d.join("s.toml")).unwrap();
    fs::create_dir(d.join("dir")).unwrap();
    fs::create_dir(d.join("dir/inside")).unwrap();
    std::os::unix::fs::symlink("x.csv", d.join("link.csv")).unwrap();
    std::os::unix::fs::symlink("dir", d.join("linkdir")).unwrap();
    run_into(&d.join("run"), 7);
    for (args, needles) in [
        // The log inside the set it would replace.
        (
            vec!["calibrate", "out/residuals.csv", "--out", "out"],
            vec!["out: holds the input out/residuals.csv"],
        ),
        // apply over its log by any path, a hard link, or over its calibration.
        (
            vec!["apply", "cal.json", "x.csv", "--out", "x.csv"],
            vec!["x.csv: is the input x.csv"],
        ),
        (
            vec!["apply", "cal.json", "x.csv", "--out", "./x.csv"],
            vec!["./x.csv: is the input x.csv"],
        ),
        (
            vec!["apply", "cal.json", "x.csv", "--out", "hard.csv"],
            vec!["hard.csv: is the input x.csv"],
        ),
        (
            vec!["apply", "cal.json", "x.csv", "--out", "cal.json"],
            vec!["cal.json: is the input cal.json"],
        ),
        (
            vec!["simulate", "s.toml", "--design", "plan300", "--out", "s.toml"],
            vec!["s.toml: is the input s.toml"],
        ),
        // A calibration set never replaces a run's set, a root, a directory or a link.
        (
            vec!["calibrate", "x.csv", "--out", "run"],
            vec!["run: holds a magcal run set, not a calibration set"],
        ),
        (
            vec!["calibrate", "x.csv", "--out", "run/cal"],
            vec!["run/cal: run holds a magcal run set, which is replaced whole"],
        ),
        (
            vec!["calibrate", "x.csv", "--out", "/"],
            vec!["/: name the output directory itself"],
        ),
        (
            vec!["calibrate", "x.csv", "--out", "dir"],
            vec!["dir: exists and is not a magcal results directory"],
        ),
        (
            vec!["calibrate", "x.csv", "--out", "linkdir"],
            vec!["linkdir: is a symbolic link; magcal replaces only a real directory"],
        ),
        // Single files: never a directory or a symbolic link.
        (
            vec!["apply", "cal.json", "x.csv", "--out", "dir"],
            vec!["dir: is a directory; give a file name"],
        ),
        (
            vec!["simulate", "s.toml", "--design", "uniform", "--out", "dir"],
            vec!["dir: is a directory; give a file name"],
        ),
        (
            vec!["apply", "cal.json", "x.csv", "--out", "link.csv"],
            vec!["link.csv: is a symbolic link"],
        ),
        (
            vec!["apply", "cal.json", "x.csv", "--out", "run/applied.csv"],
            vec!["run/applied.csv: run holds a magcal run set"],
        ),
    ] {
        refused(d, &args, &needles);
    }
}

#[test]
fn noise_reject_site_date_and_count_flags_outside_their_range_are_refused() {
    let log = ck(3000);
    let tmp = with_files(&[("log.csv", log.as_bytes())]);
    let d = tmp.path();
    let cal = |extra: &[&'static str]| [&["calibrate", "log.csv"][..], extra].concat();
    let wmm = |extra: &[&'static str]| [&["calibrate", "log.csv", "--units", "G"][..], extra].concat();
    let next = |extra: &[&'static str]| {
        let site = ["next", "out/calibration.json", "log.csv", "--site", "28.2,112.97"];
        [&site[..], &["--date", "2013.0"], extra].concat()
    };
    for (args, needles) in [
        (cal(&["--noise", "0"]), vec!["--noise 0: must be positive and finite"]),
        (
            cal(&["--noise", "nan"]),
            vec!["invalid value 'nan' for '--noise <SIGMA>': NaN is not a number"],
        ),
        (cal(&["--noise=-1"]), vec!["--noise -1: must be positive and finite"]),
        (
            cal(&["--noise", "inf"]),
            vec!["invalid value 'inf' for '--noise <SIGMA>': inf is not finite"],
        ),
        (
            cal(&["--reject", "1"]),
            vec!["log.csv: --reject 1: K = 1: must be at least 2"],
        ),
        (
            cal(&["--reject", "nan"]),
            vec!["invalid value 'nan' for '--reject <K>': NaN is not a number"],
        ),
        (
            cal(&["--reject", "1e400"]),
            vec!["invalid value '1e400' for '--reject <K>': 1e400 is beyond the largest number (1.8e308)"],
        ),
        (
            wmm(&["--site", "nan,0", "--date", "2013.0"]),
            vec!["'--site", "latitude NaN is not a finite number"],
        ),
        (
            wmm(&["--site", "0,0,1e9", "--date", "2013.0"]),
            vec!["'--site", "height 1000000000 m is outside"],
        ),
        (
            wmm(&["--site", "-91,0", "--date", "2013.0"]),
            vec!["'--site", "latitude -91 is outside [-90, 90]"],
        ),
        (
            wmm(&["--site", "0,0", "--date", "1800-01-01"]),
            vec!["'--date", "year 1800 is outside [1900, 2100]"],
        ),
        (
            wmm(&["--site", "0,0", "--date", "2026-02-30"]),
            vec!["'--date", "2026-02-30 is not a date"],
        ),
        (
            wmm(&["--site", "0,0", "--date", "2013.0", "--wmm", "WMM1990"]),
            vec!["'--wmm", "WMM1990", "unknown model"],
        ),
        (
            next(&["--roll=-5,5", "--pitch=-20,20", "--count", "0"]),
            vec!["'--count", "0 is not in 1..=1000"],
        ),
        (
            next(&["--roll=-5,5", "--pitch=-20,20", "--count", "1001"]),
            vec!["'--count", "1001 is not in 1..=1000"],
        ),
        (
            next(&["--roll=5,-5", "--pitch=-20,20"]),
            vec!["'--roll", "the minimum must be below the maximum"],
        ),
        // A box narrower than 0.01 degree is a fixed angle, not a range to search.
        (
            next(&["--roll=-0.001,0.004", "--pitch=-20,20", "--count", "2"]),
            vec!["the roll range is 5.000e-3 degree wide", "narrower than 0.01 degree"],
        ),
    ] {
        refused(d, &args, &needles);
    }
}

#[test]
fn logs_that_are_not_text_or_have_no_such_columns_are_refused() {
    let log = ck(300);
    let headerless: String = log.lines().skip(1).map(|l| format!("{l}\n")).collect();
    let renamed = log.replacen("ax,ay,az,mx,my,mz", "ax,ay,az,x,y,z", 1);
    let utf16 = |bom: bool| -> Vec<u8> {
        let units = log.encode_utf16();
        let mut bytes: Vec<u8> = if bom { vec![0xff, 0xfe] } else { Vec::new() };
        bytes.extend(units.flat_map(u16::to_le_bytes));
        bytes
    };
    // The start of an ELF file: NUL bytes on its first line.
    let binary = b"\x7fELF\x02\x01\x01\x00\x00\x00\x00\x00\x00\x00\x00\x00\x03\x00>\x00\n1,2,3\n";
    let escape = "a\x1b[2Jb,y,z\n1,2,3\n4,5,6\n";
    let tmp = with_files(&[
        ("log.csv", log.as_bytes()),
        ("nohead.csv", headerless.as_bytes()),
        ("xyz.csv", renamed.as_bytes()),
        ("u16.csv", &utf16(true)),
        ("u16le.csv", &utf16(false)),
        ("bin.csv", binary),
        ("esc.csv", escape.as_bytes()),
    ]);
    let d = tmp.path();
    for (args, needles) in [
        (
            vec!["calibrate", "log.csv", "--columns", "0,1,2"],
            vec!["log.csv", "--columns \"0,1,2\": column 0 is not in the log (6 columns)"],
        ),
        (
            vec!["calibrate", "log.csv", "--columns", "x,y"],
            vec!["log.csv", "--columns \"x,y\": give three columns"],
        ),
        (
            vec!["calibrate", "nohead.csv", "--columns", "a,b,c"],
            vec!["nohead.csv", "no column named \"a\" (columns: column 1, column 2"],
        ),
        (
            vec!["calibrate", "u16.csv"],
            vec!["u16.csv: line 1: the log is UTF-16 text", "save it as UTF-8"],
        ),
        (
            vec!["calibrate", "u16le.csv", "--out", "out"],
            vec!["u16le.csv: line 1: byte 2 is NUL: not a text log"],
        ),
        (
            vec!["calibrate", "bin.csv"],
            vec!["bin.csv: line 1: byte 8 is NUL: not a text log"],
        ),
        (
            vec!["apply", "out/calibration.json", "u16.csv", "--out", "applied.csv"],
            vec!["u16.csv: line 1: the log is UTF-16 text"],
        ),
        // A header's control characters are shown escaped, never sent to the terminal.
        (
            vec!["calibrate", "esc.csv", "--columns", "q,r,s"],
            vec!["esc.csv", "(columns: a\\u{1b}[2Jb, y, z)"],
        ),
        // A calibration of another log's columns.
        (
            vec!["apply", "out/calibration.json", "xyz.csv"],
            vec![
                "xyz.csv: no column \"mx\", which out/calibration.json was made from",
                "give --columns",
            ],
        ),
        (
            vec!["apply", "out/calibration.json", "nohead.csv"],
            vec!["nohead.csv: no header and 6 columns", "give --columns"],
        ),
    ] {
        refused(d, &args, &needles);
    }
}

#[test]
fn edited_calibration_files_are_refused_naming_the_field() {
    let log = ck(300);
    let tmp = with_files(&[("log.csv", log.as_bytes())]);
    let d = tmp.path();
    let json: serde_json::Value = serde_json::from_slice(&fs::read(d.join("out/calibration.json")).unwrap()).unwrap();
    let edited = |name: &str, edit: &dyn Fn(&mut serde_json::Value)| {
        let mut v = json.clone();
        edit(&mut v);
        fs::write(d.join(name), serde_json::to_string_pretty(&v).unwrap()).unwrap();
    };
    edited("p0.json", &|v| v["p"][0][0] = 0.0.into());
    edited("mag.json", &|v| v["magnitude"] = (-1.0).into());
    edited("fmt.json", &|v| v["format"] = "magcal-calibration/99".into());
    edited("cols.json", &|v| v["columns"] = serde_json::json!(["mx", "my"]));
    edited("bias.json", &|v| v["bias"][0] = 1e308.into());
    // JSON has no NaN: a calibration file holding one is not JSON, named by line and column.
    let text = serde_json::to_string_pretty(&json).unwrap();
    let p00 = json["p"][0][0].to_string();
    assert_eq!(text.matches(&p00).count(), 1, "{p00}");
    fs::write(d.join("nan.json"), text.replacen(&p00, "NaN", 1)).unwrap();
    let next = |cal: &'static str| {
        let args = ["next", cal, "log.csv", "--site", "28.2,112.97", "--date", "2013.0"];
        [&args[..], &["--roll=-5,5", "--pitch=-20,20", "--count", "2"]].concat()
    };
    for (args, needles) in [
        (
            vec!["apply", "p0.json", "log.csv"],
            vec!["p0.json: p [[0.0, ", "diagonal entry 1 is 0"],
        ),
        (
            vec!["apply", "mag.json", "log.csv"],
            vec!["mag.json: magnitude -1: must be finite and positive"],
        ),
        (
            vec!["apply", "fmt.json", "log.csv"],
            vec!["fmt.json: format \"magcal-calibration/99\"", "magcal-calibration-1"],
        ),
        (
            vec!["apply", "cols.json", "log.csv"],
            vec!["cols.json: not a magcal calibration: invalid length 2"],
        ),
        (
            vec!["apply", "nan.json", "log.csv"],
            vec!["nan.json: not a magcal calibration", "line ", "column "],
        ),
        (
            vec!["apply", "bias.json", "log.csv"],
            vec![
                "bias.json: bias (1e308, ",
                "times the field's raw size",
                "a usable calibration's is at most 1e6 times it",
            ],
        ),
        (next("nan.json"), vec!["nan.json: not a magcal calibration"]),
        (next("p0.json"), vec!["p0.json: p [[0.0, ", "diagonal entry 1 is 0"]),
    ] {
        refused(d, &args, &needles);
    }
}
