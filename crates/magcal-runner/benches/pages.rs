//! How long a report page takes to open in the headless Chromium of the browser tests, on the
//! page's own clock from the navigation: to its text painted, to its first screen shown whole
//! (text and the figures on it; the target: 2 s), to its first figure drawn wherever it is, and to
//! every figure drawn, scrolled through.
//! Pages: a calibration of a public CSV log, the calibration of 12,000 readings of BROAD trial 02
//! with attitudes against the AUV box, and three shipped result sets (a run, a design, a
//! replay). Without Chromium (`/usr/bin/chromium` or `MAGCAL_CHROMIUM`) it says so and measures
//! nothing.
//!
//! `cargo bench -p magcal-runner --bench pages [ID...]` prints the medians and ranges of 10 opens
//! of each page (criterion would open each page again for every quantity). With
//! `MAGCAL_BENCH_PAGES=DIR` it opens the `*.html` pages in `DIR` instead, by name: pages of two
//! builds side by side, measured in one run under the same load.

#[path = "../tests/it/browser.rs"]
#[allow(dead_code)]
mod browser;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn run(args: &[&OsStr]) {
    let out = Command::new(env!("CARGO_BIN_EXE_magcal")).args(args).output().unwrap();
    assert!(
        matches!(out.status.code(), Some(0 | 3)),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The first `rows` data rows of BROAD trial 02 that move and have an attitude.
fn broad_02_cut(dir: &Path, rows: usize) -> Option<PathBuf> {
    let path = root().join("../shared/data/broad/02_undisturbed_slow_rotation_B.csv");
    let text = std::fs::read_to_string(&path).ok()?;
    let mut lines = text.lines();
    let header = lines.next()?;
    let names: Vec<&str> = header.split(',').collect();
    let (moving, qw) = (
        names.iter().position(|n| *n == "movement")?,
        names.iter().position(|n| *n == "qw")?,
    );
    let kept: Vec<&str> = lines
        .filter(|l| {
            let f: Vec<&str> = l.split(',').collect();
            f.get(moving) == Some(&"1") && f.get(qw).is_some_and(|q| !q.is_empty())
        })
        .take(rows)
        .collect();
    let out = dir.join("broad02.csv");
    std::fs::write(&out, format!("{header}\n{}\n", kept.join("\n"))).ok()?;
    Some(out)
}

/// The pages to open: (benchmark id, page), built into `dir`.
fn pages(dir: &Path) -> Vec<(String, PathBuf)> {
    let mut pages = Vec::new();
    let mut report = |id: &str, result: &Path| {
        let page = dir.join(format!("{id}.html"));
        run(&[
            "report".as_ref(),
            result.as_os_str(),
            "--out".as_ref(),
            page.as_os_str(),
        ]);
        pages.push((id.to_string(), page));
    };
    let hamagure = root().join("../shared/data/hamagure/data-set_1.csv");
    if hamagure.is_file() {
        let set = dir.join("cal-hamagure");
        run(&[
            "calibrate".as_ref(),
            hamagure.as_os_str(),
            "--out".as_ref(),
            set.as_os_str(),
        ]);
        report("calibration_hamagure", &set);
    }
    if let Some(log) = broad_02_cut(dir, 12_000) {
        let set = dir.join("cal-broad02");
        let scenario = root().join("scenarios/wu2014.toml");
        let words = [
            "calibrate",
            log.to_str().unwrap(),
            "--columns",
            "mx,my,mz",
            "--quaternion",
            "qw,qx,qy,qz",
            "--attitude-frame",
            "enu",
            "--units",
            "uT",
            "--scenario",
            scenario.to_str().unwrap(),
            "--out",
            set.to_str().unwrap(),
        ];
        let args: Vec<&OsStr> = words.iter().map(OsStr::new).collect();
        run(&args);
        report("calibration_broad02_12000", &set);
    }
    // The shipped sets: the paper's run (its SVG figures inlined), a design set's flight plans and
    // a replay of BROAD trial 02.
    for (id, set) in [
        ("run_wu2014", "wu2014"),
        ("design_ship", "ship"),
        ("replay_auv_02", "replay-auv-02"),
    ] {
        report(id, &root().join("results").join(set));
    }
    pages
}

/// The `*.html` pages in `dir`, by name, each with its stem as its id.
fn given(dir: &Path) -> Vec<(String, PathBuf)> {
    let mut pages: Vec<(String, PathBuf)> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == "html"))
        .map(|path| (path.file_stem().unwrap().to_string_lossy().into_owned(), path))
        .collect();
    pages.sort();
    pages
}

/// Opens of each page; every open gives all three times, so one pass measures them together.
const OPENS: usize = 10;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn main() {
    // `cargo bench` passes `--bench`; a filter word selects pages by id.
    let filter: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    let Some(chrome) = browser::chromium() else { return };
    let tmp = std::env::temp_dir().join(format!("magcal-bench-pages-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    println!(
        "{:<26} {:>4} | medians of {OPENS} opens, seconds from the navigation (min-max)",
        "page", "MB"
    );
    println!(
        "{:<26} {:>4} | {:<17} {:<17} {:<17} {:<17}",
        "", "", "text painted", "first screen", "first figure", "every figure"
    );
    let pages = match std::env::var_os("MAGCAL_BENCH_PAGES") {
        Some(dir) => given(Path::new(&dir)),
        None => pages(&tmp),
    };
    for (id, page) in pages {
        if !filter.is_empty() && !filter.iter().any(|f| id.contains(f.as_str())) {
            continue;
        }
        let mb = std::fs::metadata(&page).map_or(0, |m| m.len()) as f64 / 1e6;
        let mut times = [Vec::new(), Vec::new(), Vec::new(), Vec::new()];
        for _ in 0..OPENS {
            let opened = browser::open(&chrome, &page, Duration::from_secs(120));
            assert!(opened.errors.is_empty(), "{id}: {:?}", opened.errors);
            let _ = opened.tab.close();
            for (t, v) in times.iter_mut().zip([
                opened.painted,
                opened.first_screen,
                opened.first_figure.unwrap_or(f64::NAN),
                opened.seconds,
            ]) {
                t.push(v);
            }
        }
        let cell = |v: &Vec<f64>| {
            let (lo, hi) = (
                v.iter().copied().fold(f64::INFINITY, f64::min),
                v.iter().copied().fold(0.0, f64::max),
            );
            format!("{:.2} ({:.2}-{:.2})", median(v.clone()), lo, hi)
        };
        println!(
            "{id:<26} {mb:>4.1} | {:<17} {:<17} {:<17} {:<17}",
            cell(&times[0]),
            cell(&times[1]),
            cell(&times[2]),
            cell(&times[3])
        );
    }
    let _ = std::fs::remove_dir_all(&tmp);
}
