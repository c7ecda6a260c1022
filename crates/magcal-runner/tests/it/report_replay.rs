//! `magcal report` of a replay set: the page of every shipped `results/replay-*` set opened in
//! one real browser ([`crate::browser`]): no console error, no request leaving the file, every
//! figure drawn (pixel statistics of its screenshot), every trial of trials.csv drawn, and the
//! tables equal to summary.csv, whole_log.csv and the counts of trials.csv; and a set whose CSV
//! was edited since replay wrote it has no page.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::time::Duration;

use tempfile::TempDir;

use crate::browser::{Opened, chromium, open};
use crate::common::magcal;
use crate::report::{assert_drawn_3d, assert_traces_in_bundle, report, table};

/// The shipped replay sets.
fn shipped() -> Vec<PathBuf> {
    let results = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../results");
    let mut sets: Vec<PathBuf> = fs::read_dir(&results)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("replay-"))
        })
        .collect();
    sets.sort();
    sets
}

/// The rows of a CSV file as maps from column to cell.
fn rows(path: &Path) -> Vec<BTreeMap<String, String>> {
    let mut r = csv::Reader::from_path(path).unwrap();
    let headers = r.headers().unwrap().clone();
    r.records()
        .map(|rec| {
            let rec = rec.unwrap();
            headers
                .iter()
                .zip(rec.iter())
                .map(|(h, v)| (h.to_string(), v.to_string()))
                .collect()
        })
        .collect()
}

/// A cell shows the CSV's `value`: text equal for a name; for a number its `data-value` is the
/// CSV's number (to within f64 formatting, relative 1e-12); an empty CSV cell is a dash.
fn assert_cell(cell: &(String, Option<f64>), value: &str, what: &str) {
    if value.is_empty() {
        assert_eq!((cell.0.as_str(), cell.1), ("-", None), "{what}");
        return;
    }
    match value.parse::<f64>() {
        Ok(v) => {
            let shown = cell
                .1
                .unwrap_or_else(|| panic!("{what}: {cell:?} has no value, the CSV {value}"));
            assert!(
                (shown - v).abs() <= 1e-12 * v.abs(),
                "{what}: {shown} on the page, {v} in the CSV"
            );
        }
        Err(_) => assert_eq!(cell.0, value, "{what}"),
    }
}

/// A table of the page equals the CSV's rows, column by column in `columns` order.
fn assert_table_is_csv(page: &Opened, id: &str, csv: &[BTreeMap<String, String>], columns: &[&str]) {
    let shown = table(page, id);
    assert_eq!(shown.len(), csv.len(), "table {id}: rows");
    for (i, (row, want)) in shown.iter().zip(csv).enumerate() {
        assert_eq!(row.len(), columns.len(), "table {id} row {i}");
        for (cell, column) in row.iter().zip(columns) {
            assert_cell(cell, &want[*column], &format!("table {id} row {i} {column}"));
        }
    }
}

const SUMMARY_COLUMNS: [&str; 16] = [
    "design",
    "m",
    "model",
    "trials",
    "ok",
    "not_converged",
    "not_identifiable",
    "failed",
    "metric",
    "mean",
    "std",
    "median",
    "p05",
    "p95",
    "se_mean",
    "rms",
];

const WHOLE_LOG_COLUMNS: [&str; 13] = [
    "model",
    "readings",
    "status",
    "heading_rms_deg",
    "heading_p95_deg",
    "heading_max_deg",
    "direction_rms_deg",
    "heading_rms_held_deg",
    "direction_rms_held_deg",
    "eta_psi",
    "eta_s",
    "eta_o",
    "rms_residual_nt",
];

/// The statuses, in the order of the outcome table's columns.
const STATUSES: [&str; 7] = [
    "ok",
    "not_converged",
    "not_identifiable",
    "too_few_readings",
    "non_finite_input",
    "rank_deficient",
    "not_positive_definite",
];

/// The outcome table counts what trials.csv holds and says what summary.csv says.
fn assert_outcomes(page: &Opened, set: &Path) {
    let trials = rows(&set.join("trials.csv"));
    let summary = rows(&set.join("summary.csv"));
    let mut counted: BTreeMap<(String, String, String), usize> = BTreeMap::new();
    for t in &trials {
        *counted
            .entry((t["design"].clone(), t["model"].clone(), t["status"].clone()))
            .or_default() += 1;
        if t["status"] == "ok" && !t["heading_rms_deg"].is_empty() {
            *counted
                .entry((t["design"].clone(), t["model"].clone(), "drawn".into()))
                .or_default() += 1;
        }
    }
    let outcomes = table(page, "outcomes");
    let heading: Vec<&BTreeMap<String, String>> = summary.iter().filter(|s| s["metric"] == "heading_rms_deg").collect();
    assert_eq!(outcomes.len(), heading.len(), "one row per design and model");
    for (row, s) in outcomes.iter().zip(heading) {
        let what = format!("{} {}", s["design"], s["model"]);
        assert_eq!(row[0].0, s["design"], "{what}");
        assert_eq!(row[2].0, s["model"], "{what}");
        for (k, column) in [
            (1, "m"),
            (3, "trials"),
            (4, "ok"),
            (5, "not_converged"),
            (6, "not_identifiable"),
        ] {
            assert_cell(&row[k], &s[column], &format!("{what} {column}"));
        }
        let count = |status: &str| {
            counted
                .get(&(s["design"].clone(), s["model"].clone(), status.to_string()))
                .copied()
                .unwrap_or(0)
        };
        for (k, status) in STATUSES.iter().enumerate() {
            assert_eq!(row[4 + k].1, Some(count(status) as f64), "{what} {status}");
        }
        let failed: usize = STATUSES[3..].iter().map(|s| count(s)).sum();
        assert_eq!(failed.to_string(), s["failed"], "{what}: failed");
        assert_eq!(row[11].1, Some(count("drawn") as f64), "{what}: drawn");
        if s["trials"] == "0" {
            assert!(row[12].0.starts_with("not realised"), "{what}: {:?}", row[12]);
        }
    }
}

/// Every ok trial with a heading is a point of the heading figure (and the whole log's one per
/// model), and each box's median is summary.csv's to within the 5 significant digits drawn.
fn assert_heading_figure(page: &Opened, set: &Path) {
    let summary = rows(&set.join("summary.csv"));
    let boxes = page.eval(
        "(() => { const gd = document.getElementById('dist-heading-rms-deg'); const cats = gd._fullLayout.xaxis._categories; return gd.calcdata.map((cd, i) => [gd.data[i].name, gd.data[i].y.length, cd.map(b => [cats[b.pos], b.med, b.pts.length])]); })()",
    );
    let mut points = 0;
    for trace in boxes.as_array().unwrap() {
        let model = trace[0].as_str().unwrap();
        points += trace[1].as_u64().unwrap();
        for b in trace[2].as_array().unwrap() {
            let design = b[0].as_str().unwrap();
            let (median, n) = (b[1].as_f64().unwrap(), b[2].as_u64().unwrap());
            if design == "whole log" {
                assert_eq!(n, 1, "{model}: one whole-log value");
                continue;
            }
            let s = summary
                .iter()
                .find(|s| s["design"] == design && s["model"] == model && s["metric"] == "heading_rms_deg")
                .unwrap_or_else(|| panic!("{design} {model}: not in summary.csv"));
            let want: f64 = s["median"].parse().unwrap();
            assert!(
                (median - want).abs() <= 5e-5 * want.abs(),
                "{design} {model}: median drawn {median}, summary.csv {want}"
            );
        }
    }
    let trials = rows(&set.join("trials.csv"));
    let drawn = trials
        .iter()
        .filter(|t| t["status"] == "ok" && !t["heading_rms_deg"].is_empty())
        .count();
    let whole = rows(&set.join("whole_log.csv"))
        .iter()
        .filter(|w| !w["heading_rms_deg"].is_empty())
        .count();
    assert_eq!(points as usize, drawn + whole, "every ok trial drawn");
}

/// The pixels in colour (not white, grey or black: the grid lines are grey, the boxes and
/// points are the models' colours).
fn coloured_pixels(image: &image::RgbaImage) -> usize {
    image
        .pixels()
        .filter(|p| {
            let (hi, lo) = (p[0].max(p[1]).max(p[2]), p[0].min(p[1]).min(p[2]));
            i32::from(hi) - i32::from(lo) > 40
        })
        .count()
}

/// The 2D figure `id` is drawn: one SVG point per value it holds (every trial on the screen), and
/// its plot area (without axes and legend) not blank: at least 50 pixels in the models' colours
/// where an empty plot area has none.
fn assert_drawn_2d(page: &Opened, id: &str, name: &str) {
    let counts = page.eval(&format!(
        "(() => {{ const gd = document.getElementById('{id}'); return [gd.data.reduce((n, t) => n + t.y.length, 0), gd.querySelectorAll('.point').length]; }})()"
    ));
    let (values, points) = (counts[0].as_u64().unwrap(), counts[1].as_u64().unwrap());
    assert!(values > 0, "{name} {id}: no values");
    assert_eq!(points, values, "{name} {id}: points drawn");
    let shot = page.screenshot(&format!("#{id} .nsewdrag"));
    let coloured = coloured_pixels(&shot);
    if coloured < 50 {
        let kept = std::env::temp_dir().join(format!("magcal-{name}-{id}.png"));
        let _ = shot.save(&kept);
        panic!("{name} {id}: {coloured} pixels in colour ({})", kept.display());
    }
}

#[test]
fn the_page_of_every_shipped_replay_set_draws_offline_and_shows_its_csv_numbers() {
    let Some(browser) = chromium() else { return };
    let tmp = TempDir::new().unwrap();
    let sets = shipped();
    assert!(sets.len() >= 6, "{sets:?}");
    for set in &sets {
        let name = set.file_name().unwrap().to_string_lossy().into_owned();
        let page_path = tmp.path().join(format!("{name}.html"));
        report(set, &page_path);
        assert_traces_in_bundle(&page_path);
        let bytes = fs::metadata(&page_path).unwrap().len();
        let page = open(&browser, &page_path, Duration::from_secs(60));
        assert!(page.errors.is_empty(), "{name}: {:?}", page.errors);
        assert!(
            page.remote_requests(&page_path.canonicalize().unwrap()).is_empty(),
            "{name}: {:?}",
            page.requests
        );
        assert_drawn_3d(&page, "realisation-box");
        for figure in ["dist-heading-rms-deg", "dist-eta-psi", "dist-eta-s", "dist-eta-o"] {
            assert_drawn_2d(&page, figure, &name);
        }
        assert_table_is_csv(&page, "summary", &rows(&set.join("summary.csv")), &SUMMARY_COLUMNS);
        assert_table_is_csv(
            &page,
            "whole-log",
            &rows(&set.join("whole_log.csv")),
            &WHOLE_LOG_COLUMNS,
        );
        assert_outcomes(&page, set);
        assert_heading_figure(&page, set);
        let points = page.eval("JSON.parse(document.getElementById('magcal-data').textContent).realisation_points");
        assert_eq!(points.as_u64(), Some(rows(&set.join("realisation.csv")).len() as u64));
        eprintln!("{name}: {bytes} bytes, drawn in {:.2} s", page.seconds);
        page.tab.close().unwrap();
    }
}

#[test]
fn a_replay_set_whose_csv_was_edited_has_no_page() {
    let tmp = TempDir::new().unwrap();
    let shipped = shipped();
    let from = shipped
        .iter()
        .find(|p| p.ends_with("replay-handheld-10"))
        .expect("results/replay-handheld-10");
    let set = tmp.path().join("set");
    fs::create_dir(&set).unwrap();
    for name in [
        "manifest.json",
        "summary.csv",
        "trials.csv",
        "realisation.csv",
        "whole_log.csv",
    ] {
        fs::copy(from.join(name), set.join(name)).unwrap();
    }
    let page_path = tmp.path().join("page.html");
    report(&set, &page_path);
    fs::remove_file(&page_path).unwrap();
    for (file, from, to) in [
        ("summary.csv", ",200,", ",199,"),
        ("trials.csv", ",not_converged,", ",ok,"),
        ("manifest.json", "\"seed\": 22", "\"seed\": 23"),
    ] {
        let path = set.join(file);
        let original = fs::read_to_string(&path).unwrap();
        assert!(original.contains(from), "{file}: {from}");
        fs::write(&path, original.replacen(from, to, 1)).unwrap();
        let o = magcal()
            .arg("report")
            .arg(&set)
            .arg("--out")
            .arg(&page_path)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{file}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert!(stderr.contains(file), "{file}: {stderr}");
        assert!(!page_path.exists(), "{file}: a page was written");
        fs::write(&path, original).unwrap();
    }
}
