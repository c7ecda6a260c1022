//! How long a report page takes to open in the headless Chromium of the browser tests, from the
//! navigation to the first screen drawn (the target: 2 s) and to every figure drawn: a calibration of a public CSV log,
//! the calibration of 12,000 readings of BROAD trial 02 with attitudes against the AUV box, and
//! the pages of the shipped result sets. Without Chromium (`/usr/bin/chromium` or
//! `MAGCAL_CHROMIUM`) it says so and measures nothing.
//!
//! `cargo bench -p magcal-runner --bench pages`

#[path = "../tests/it/browser.rs"]
#[allow(dead_code)]
mod browser;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};

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
    pages
}

fn open_pages(c: &mut Criterion) {
    let Some(chrome) = browser::chromium() else { return };
    let tmp = std::env::temp_dir().join(format!("magcal-bench-pages-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let pages = pages(&tmp);
    // A page draws its figures as they come near the screen: "first_screen" is the time a reader
    // waits before the page shows, "every_figure" the time to scroll through all of it.
    for (group_name, all) in [("first_screen", false), ("every_figure", true)] {
        let mut group = c.benchmark_group(group_name);
        group.sample_size(10);
        for (id, page) in &pages {
            if !all {
                let bytes = std::fs::metadata(page).map_or(0, |m| m.len());
                eprintln!("{id}: {:.1} MB", bytes as f64 / 1e6);
            }
            group.bench_function(id.as_str(), |b| {
                b.iter_custom(|iters| {
                    (0..iters)
                        .map(|_| {
                            let opened = browser::open(&chrome, page, Duration::from_secs(120));
                            assert!(opened.errors.is_empty(), "{:?}", opened.errors);
                            let _ = opened.tab.close(true);
                            Duration::from_secs_f64(if all { opened.seconds } else { opened.first_screen })
                        })
                        .sum()
                });
            });
        }
        group.finish();
    }
    let _ = std::fs::remove_dir_all(&tmp);
}

criterion_group!(benches, open_pages);
criterion_main!(benches);
