//! `magcal evaluate --report`: the page of heading errors, from BROAD trial 02 (motion capture),
//! looked at in a real browser ([`crate::browser`]): no console error, no request leaving the
//! file, every figure drawn, its tables equal to `evaluate --json` (the CONVENTIONS.md check
//! values among them) and its histogram to the `--errors` rows; a page onto an input or the
//! `--errors` file refused with nothing written; the same inputs give the same page.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Duration;

use magcal_runner::commands::evaluate::{CellJson, ErrorRow, EvaluationJson};
use tempfile::TempDir;

use crate::browser::{Opened, chromium, open, pixel_statistics};
use crate::common::{BROAD_ARGS, assert_refused, broad_02_moving, magcal};
use crate::report::{assert_light_page, assert_shows, table};

/// `magcal evaluate ARGS`: exit code, stdout, stderr.
fn evaluate(args: &[&std::ffi::OsStr]) -> (i32, String, String) {
    let o = magcal().arg("evaluate").args(args).output().unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// The flags that read BROAD's moving rows (`broad_02_moving`), as `&OsStr`.
fn broad_args() -> Vec<&'static std::ffi::OsStr> {
    BROAD_ARGS[..6].iter().map(|a| a.as_ref()).collect()
}

/// Opens `page` and checks what every page of `evaluate` must: no error, nothing fetched, each
/// 2D figure drawn (at least 2 % of its pixels off the background).
fn open_checked(browser: &crate::browser::Browser, page_path: &Path) -> Opened {
    let page = open(browser, page_path, Duration::from_secs(60));
    assert!(page.errors.is_empty(), "{:?}", page.errors);
    assert!(
        page.remote_requests(&page_path.canonicalize().unwrap()).is_empty(),
        "{:?}",
        page.requests
    );
    for view in [
        "error-time",
        "error-heading",
        "error-tilt",
        "histogram",
        "by-heading-bars",
        "by-tilt-bars",
    ] {
        let (share, colours) = pixel_statistics(&page.screenshot(&format!("#{view}-box")));
        assert!(
            share > 0.02 && colours > 5,
            "{view}: {share:.3} drawn, {colours} colours"
        );
    }
    page
}

/// The table `id` holds `cells` (and the raw readings' heading rms in its last column where
/// `raw` is given), each number exactly.
fn assert_cells(page: &Opened, id: &str, cells: &[CellJson], raw: Option<&[CellJson]>) {
    let rows = table(page, id);
    assert_eq!(rows.len(), cells.len(), "{id}");
    for (i, (row, c)) in rows.iter().zip(cells).enumerate() {
        assert_eq!(row[0].0, format!("{}-{}", c.from_deg, c.to_deg));
        assert_shows(&row[1], c.readings as f64);
        let shows = |cell: &(String, Option<f64>), v: Option<f64>| match v {
            Some(v) => assert_shows(cell, v),
            None => assert_eq!(cell, &("-".to_string(), None)),
        };
        shows(&row[2], c.heading_rms_deg);
        shows(&row[3], c.heading_max_deg);
        shows(&row[4], c.direction_rms_deg);
        if let Some(raw) = raw {
            shows(&row[5], raw[i].heading_rms_deg);
        }
    }
}

/// The heading errors of the `--errors` file at `path`, and of its raw readings.
fn errors(path: &Path) -> (Vec<f64>, Vec<f64>) {
    let mut reader = csv::Reader::from_path(path).unwrap();
    let rows: Vec<ErrorRow> = reader.deserialize().map(Result::unwrap).collect();
    (
        rows.iter().map(|r| r.heading_error_deg.0).collect(),
        rows.iter().map(|r| r.raw_heading_error_deg.0).collect(),
    )
}

/// The page's histogram equals the one counted here from `errors` in the page's own bins.
fn assert_histogram(page: &Opened, key: &str, errors: &[f64]) {
    let h = page.eval("JSON.parse(document.getElementById('magcal-data').textContent).histogram");
    let width = h["width"].as_f64().unwrap();
    let counts: Vec<u64> = h[key].as_array().unwrap().iter().map(|c| c.as_u64().unwrap()).collect();
    let k = counts.len() as i64 / 2;
    let mut want = vec![0u64; counts.len()];
    for e in errors {
        let i = (e / width).floor() as i64 + k;
        assert!((0..2 * k).contains(&i), "{e} outside the bins of {width}");
        want[i as usize] += 1;
    }
    assert_eq!(counts, want, "{key}");
}

#[test]
fn broad_02_raw_gives_a_page_with_the_check_values_and_every_figure_drawn() {
    let Some(browser) = chromium() else { return };
    let tmp = TempDir::new().unwrap();
    let Some(log) = broad_02_moving(tmp.path()) else {
        return;
    };
    let (page_path, csv) = (tmp.path().join("raw.html"), tmp.path().join("errors.csv"));
    let mut args = vec!["--raw".as_ref(), log.as_os_str()];
    args.extend(broad_args());
    args.extend(["--json".as_ref(), "--errors".as_ref(), csv.as_os_str()]);
    args.extend(["--report".as_ref(), page_path.as_os_str()]);
    let (code, stdout, stderr) = evaluate(&args);
    assert_eq!(code, 0, "{stderr}");
    let json: EvaluationJson = serde_json::from_str(&stdout).unwrap();
    assert_light_page(&page_path);
    let page = open_checked(&browser, &page_path);

    // CONVENTIONS.md check values: BROAD 02's raw readings against the capture.
    let figures = table(&page, "figures");
    assert_eq!(figures.len(), 1);
    assert_eq!(figures[0][0].0, "uncalibrated");
    let u = &json.uncalibrated;
    for (i, (want, value)) in [
        ("3.1267", u.heading_rms_deg),
        ("6.2666", u.heading_p95_deg),
        ("17.3922", u.heading_max_deg),
        ("1.9601", u.direction_rms_deg),
    ]
    .into_iter()
    .enumerate()
    {
        assert_eq!(figures[0][1 + i].0, want);
        assert_shows(&figures[0][1 + i], value);
    }
    let rows = table(&page, "rows");
    assert_shows(&rows[1][1], 32_280.0);
    assert_cells(&page, "by-heading", &u.by_heading, None);
    assert_cells(&page, "by-tilt", &u.by_tilt, None);
    let (judged, _) = errors(&csv);
    assert_eq!(judged.len(), 32_280);
    assert_histogram(&page, "counts", &judged);
    // A scatter draws 4000 of the 32,280 readings, and the page says so.
    let drawn = page.eval("document.getElementById('error-time').data[0].x.length");
    assert_eq!(drawn.as_u64(), Some(4000));
    let text = page.eval("document.body.innerText");
    assert!(
        text.as_str().unwrap().contains("4000 of the 32280 readings drawn"),
        "the thinning is said"
    );
    eprintln!("evaluate --raw page: drawn in {:.2} s", page.seconds);
}

#[test]
fn a_calibrated_evaluation_page_shows_the_calibrated_and_raw_figures_of_the_json() {
    let Some(browser) = chromium() else { return };
    let tmp = TempDir::new().unwrap();
    let Some(log) = broad_02_moving(tmp.path()) else {
        return;
    };
    let o = magcal()
        .arg("calibrate")
        .arg(&log)
        .args(BROAD_ARGS)
        // The subject is the page, not the check by trials: the fewest trials.
        .args(["--trials", "20"])
        .arg("--out")
        .arg(tmp.path().join("cal"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let cal = tmp.path().join("cal/calibration.json");
    let (page_path, csv) = (tmp.path().join("cal.html"), tmp.path().join("errors.csv"));
    let mut args = vec![cal.as_os_str(), log.as_os_str()];
    args.extend(broad_args());
    args.extend(["--json".as_ref(), "--errors".as_ref(), csv.as_os_str()]);
    args.extend(["--report".as_ref(), page_path.as_os_str()]);
    let (code, stdout, stderr) = evaluate(&args);
    assert_eq!(code, 0, "{stderr}");
    let json: EvaluationJson = serde_json::from_str(&stdout).unwrap();
    let page = open_checked(&browser, &page_path);
    let figures = table(&page, "figures");
    let c = json.calibrated.as_ref().unwrap();
    let u = &json.uncalibrated;
    assert_eq!(figures.len(), 2);
    for (row, (name, f)) in figures.iter().zip([("calibrated", c), ("uncalibrated", u)]) {
        assert_eq!(row[0].0, name);
        assert_shows(&row[1], f.heading_rms_deg);
        assert_shows(&row[2], f.heading_p95_deg);
        assert_shows(&row[3], f.heading_max_deg);
        assert_shows(&row[4], f.direction_rms_deg);
        assert_shows(&row[5], f.rotation_angle_deg);
        assert_shows(&row[6], f.field_magnitude);
        assert_shows(&row[7], f.field_dip_deg);
    }
    // The calibration brings the heading rms down: the figures of the README.
    assert_eq!(figures[0][1].0, "3.0531");
    assert_cells(&page, "by-heading", &c.by_heading, Some(&u.by_heading));
    assert_cells(&page, "by-tilt", &c.by_tilt, Some(&u.by_tilt));
    let (judged, raw) = errors(&csv);
    assert_histogram(&page, "counts", &judged);
    assert_histogram(&page, "raw", &raw);
    eprintln!("evaluate page: drawn in {:.2} s", page.seconds);
}

#[test]
fn an_evaluation_page_onto_an_input_or_the_errors_file_is_refused_and_is_reproducible() {
    let tmp = TempDir::new().unwrap();
    let Some(log) = broad_02_moving(tmp.path()) else {
        return;
    };
    let before = fs::read(&log).unwrap();
    let csv = tmp.path().join("errors.csv");
    for (out, needle) in [
        (log.clone(), "is the input"),
        (csv.clone(), "the same file as --errors"),
        (PathBuf::from("-"), "--report -: give a file"),
        (tmp.path().join("missing/e.html"), "no directory"),
    ] {
        let mut args = vec!["--raw".as_ref(), log.as_os_str()];
        args.extend(broad_args());
        args.extend([
            "--errors".as_ref(),
            csv.as_os_str(),
            "--report".as_ref(),
            out.as_os_str(),
        ]);
        assert_refused(&evaluate(&args), &["--report", needle]);
        assert!(!csv.exists(), "--errors written although --report was refused");
    }
    assert!(fs::read(&log).unwrap() == before, "the log was changed");
    // The same inputs give the same page, byte for byte.
    let pages = ["a.html", "b.html"].map(|name| {
        let page = tmp.path().join(name);
        let mut args = vec!["--raw".as_ref(), log.as_os_str()];
        args.extend(broad_args());
        args.extend(["--report".as_ref(), page.as_os_str()]);
        let (code, _, stderr) = evaluate(&args);
        assert_eq!(code, 0, "{stderr}");
        fs::read(&page).unwrap()
    });
    assert!(pages[0] == pages[1], "two pages of the same inputs differ");
}
