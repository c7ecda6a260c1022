//! `magcal report`: the pages built from real results and looked at in a real browser
//! ([`crate::browser`]): no console error, no request leaving the file, every 3D view drawn (pixel
//! statistics of its screenshot), and the numbers in the tables equal to the result's JSON.

use std::fs;
use std::path::Path;
use std::time::Duration;

use tempfile::TempDir;

use crate::browser::{Opened, chromium, open, pixel_statistics};
use crate::common::{BROAD_ARGS, broad_02_moving, data, magcal};

/// Largest page, bytes (the bound): plotly.js packed (0.66 MB) and the page's own.
pub const MAX_PAGE_BYTES: u64 = 2_000_000;

/// The trace types of the page at `path`'s figures (their JSON blocks), each of which the
/// plotly.js it embeds must register, and which tests assert it does: a figure of a type the bundle
/// lacks would draw nothing, without an error. Returns the page's HTML.
pub fn assert_traces_in_bundle(path: &Path) -> String {
    let html = fs::read_to_string(path).unwrap();
    let bundle = magcal_runner::report::PLOTLY_JS;
    // The page carries it packed (a unit test unpacks that to the bundle, byte for byte).
    assert!(
        html.contains(magcal_runner::report::plotly_packed()),
        "{}: the bundle is embedded",
        path.display()
    );
    // Each trace module of plotly.js declares itself so.
    let registered: Vec<&str> = bundle
        .split("moduleType:\"trace\",name:\"")
        .skip(1)
        .filter_map(|rest| rest.split('"').next())
        .collect();
    let mut used = std::collections::BTreeSet::new();
    for block in html
        .split("<script type=\"application/json\" class=\"magcal-figure\"")
        .skip(1)
    {
        let json = block.split_once('>').unwrap().1.split("</script>").next().unwrap();
        let figure: serde_json::Value = serde_json::from_str(json).unwrap();
        for trace in figure["data"].as_array().unwrap() {
            // plotly.js draws a trace without a type as a scatter.
            used.insert(trace["type"].as_str().unwrap_or("scatter").to_string());
        }
    }
    for kind in &used {
        assert!(
            registered.contains(&kind.as_str()),
            "{}: a {kind} trace, which the embedded plotly.js (registering {registered:?}) does not hold",
            path.display()
        );
    }
    html
}

/// [`assert_traces_in_bundle`], and the page at `path` at most [`MAX_PAGE_BYTES`].
pub fn assert_light_page(path: &Path) -> String {
    let html = assert_traces_in_bundle(path);
    assert!(
        (html.len() as u64) < MAX_PAGE_BYTES,
        "{}: {} bytes",
        path.display(),
        html.len()
    );
    html
}

/// `magcal report RESULT --out OUT`, which must succeed.
pub fn report(result: &Path, out: &Path) -> String {
    let o = magcal()
        .arg("report")
        .arg(result)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// `magcal calibrate LOG ARGS --out DIR`; exit 0 or 3 (a set is written either way).
fn calibrate(log: &Path, args: &[&str], dir: &Path) {
    let o = magcal()
        .arg("calibrate")
        .arg(log)
        .args(args)
        .arg("--out")
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        matches!(o.status.code(), Some(0 | 3)),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The 3D view in `box_id` is drawn: WebGL, no fallback message, and a screenshot that is not
/// blank (at least 3 % of its pixels off the background, and 40 colours).
pub fn assert_drawn_3d(page: &Opened, box_id: &str) {
    let canvases = page.eval(&format!("document.querySelectorAll('#{box_id} canvas').length"));
    assert!(canvases.as_u64().unwrap_or(0) > 0, "{box_id}: no canvas");
    let text = page.eval(&format!("document.querySelector('#{box_id}').innerText"));
    assert!(
        !text.as_str().unwrap_or("").contains("WebGL is not supported"),
        "{box_id}: {text}"
    );
    let shot = page.screenshot(&format!("#{box_id}"));
    let (share, colours) = pixel_statistics(&shot);
    if share <= 0.03 || colours <= 40 {
        let kept = std::env::temp_dir().join(format!("magcal-report-{box_id}.png"));
        let _ = shot.save(&kept);
        panic!(
            "{box_id}: {share:.3} of the pixels drawn, {colours} colours (the screenshot: {})",
            kept.display()
        );
    }
}

/// The cells of table `id`: per row, each cell's text and `data-value`.
pub fn table(page: &Opened, id: &str) -> Vec<Vec<(String, Option<f64>)>> {
    let rows = page.eval(&format!(
        "Array.from(document.querySelectorAll('#{id} tbody tr')).map(r => Array.from(r.cells).map(c => [c.innerText, c.dataset.value ?? null]))"
    ));
    rows.as_array()
        .unwrap_or_else(|| panic!("table {id}: {rows}"))
        .iter()
        .map(|r| {
            r.as_array()
                .unwrap()
                .iter()
                .map(|c| {
                    (
                        c[0].as_str().unwrap().to_string(),
                        c[1].as_str().map(|v| v.parse().unwrap()),
                    )
                })
                .collect()
        })
        .collect()
}

/// A cell shows `value`: its `data-value` is the JSON's number, bit for bit (the page writes the
/// shortest text that reads back as the number, and both sides parse it correctly rounded), and
/// its text is that number rounded (within half a unit of its last digit).
pub fn assert_shows(cell: &(String, Option<f64>), value: f64) {
    let kept = cell.1.unwrap_or_else(|| panic!("{cell:?} keeps no value"));
    assert_eq!(kept.to_bits(), value.to_bits(), "{cell:?} against {value}");
    let shown: f64 = cell.0.parse().unwrap_or_else(|_| panic!("{cell:?}"));
    let decimals = cell.0.split('.').nth(1).map_or(0, |d| d.len() as i32);
    assert!(
        (shown - value).abs() <= 0.5 * 10f64.powi(-decimals) * (1.0 + 1e-9),
        "{cell:?} against {value}"
    );
}

#[test]
fn a_calibration_page_draws_its_views_offline_and_shows_the_json_numbers() {
    let Some(browser) = chromium() else { return };
    let tmp = TempDir::new().unwrap();
    let Some(log) = data("hamagure/data-set_1.csv") else {
        return;
    };
    let set = tmp.path().join("cal");
    // Its last 43 readings pass through another field; --reject 4 drops them (docs/conventions.md
    // "One field").
    calibrate(&log, &["--reject", "4"], &set);
    let page_path = tmp.path().join("cal.html");
    report(&set, &page_path);
    assert_traces_in_bundle(&page_path);
    let page = open(&browser, &page_path, Duration::from_secs(60));
    assert!(page.errors.is_empty(), "{:?}", page.errors);
    assert!(
        page.remote_requests(&page_path.canonicalize().unwrap()).is_empty(),
        "{:?}",
        page.requests
    );
    for view in ["raw-box", "calibrated-box", "coverage-box"] {
        assert_drawn_3d(&page, view);
    }
    let (share, _) = pixel_statistics(&page.screenshot("#residual-map-box"));
    assert!(share > 0.03, "the residual map is blank: {share:.3}");

    let cal: serde_json::Value = serde_json::from_slice(&fs::read(set.join("calibration.json")).unwrap()).unwrap();
    let num = |v: &serde_json::Value| v.as_f64().unwrap();
    let rows = table(&page, "parameters");
    assert_eq!(rows.len(), 9);
    for i in 0..3 {
        assert_shows(&rows[i][1], num(&cal["bias"][i]));
        assert_shows(&rows[i][2], num(&cal["std_error"]["bias"][i]));
        assert_shows(&rows[3 + i][1], num(&cal["scale"][i]));
        assert_shows(&rows[3 + i][2], num(&cal["std_error"]["scale"][i]));
        assert_shows(&rows[6 + i][1], num(&cal["psi_deg"][i]));
        assert_shows(&rows[6 + i][3], num(&cal["interval95"]["psi_deg"][i]));
    }
    let fit = table(&page, "fit");
    assert_eq!(fit[0][1].1, Some(num(&cal["samples"])));
    let verdict = page.eval("document.querySelector('#verdict').innerText");
    assert!(verdict.as_str().unwrap().starts_with("USABLE"), "{verdict}");
    // The regions drawn are the ones the calibration's MotionCal figure counts: each region's 24
    // triangles take its colour, and the weights of 1, 0.2 and 0.01 that MotionCal gives regions
    // of 0, 1 and 2 readings add up, over the colours drawn, to the JSON's gap percentage.
    let colours = page.eval("document.querySelector('#coverage-box .plotly-graph-div').data[0].facecolor");
    let colours: Vec<&str> = colours
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_str().unwrap())
        .collect();
    assert_eq!(colours.len(), 100 * 24);
    let gaps: f64 = colours
        .chunks(24)
        .map(|region| {
            assert!(region.iter().all(|c| *c == region[0]), "one colour per region");
            let weight = [0.0, 1.0, 0.2, 0.01]
                .into_iter()
                .zip(["#2ca02c", "#d62728", "#ff7f0e", "#f2c94c"])
                .find(|(_, c)| *c == region[0])
                .unwrap_or_else(|| panic!("colour {}", region[0]));
            weight.0
        })
        .sum();
    assert!(
        (gaps - num(&cal["coverage"]["motioncal_gap_percent"])).abs() < 1e-9,
        "{gaps}"
    );
    // A log without attitudes draws none.
    assert_eq!(page.eval("document.querySelectorAll('#roll-pitch-box').length"), 0);
    eprintln!(
        "calibration page: first screen in {:.2} s, every figure in {:.2} s",
        page.first_screen, page.seconds
    );
}

#[test]
fn the_page_of_a_12000_reading_log_stays_under_2_mb_and_says_what_it_thinned() {
    let tmp = TempDir::new().unwrap();
    let Some(moving) = broad_02_moving(tmp.path()) else {
        return;
    };
    let text = fs::read_to_string(&moving).unwrap();
    let cut: String = text.lines().take(12_001).map(|l| format!("{l}\n")).collect();
    let log = tmp.path().join("cut.csv");
    fs::write(&log, cut).unwrap();
    let set = tmp.path().join("cal");
    let wu2014 = crate::common::scenarios().join("wu2014.toml");
    let args: Vec<&str> = BROAD_ARGS
        .iter()
        .copied()
        .chain(["--scenario", wu2014.to_str().unwrap()])
        // The subject is the page, not the check by trials: the fewest trials.
        .chain(["--trials", "20"])
        .collect();
    calibrate(&log, &args, &set);
    let page_path = tmp.path().join("cal.html");
    report(&set, &page_path);
    assert_traces_in_bundle(&page_path);
    let bytes = fs::metadata(&page_path).unwrap().len();
    assert!(bytes < MAX_PAGE_BYTES, "{bytes} bytes");
    let html = fs::read_to_string(&page_path).unwrap();
    assert!(
        html.contains(&format!(
            "{} of the 12000 readings drawn",
            magcal_runner::report::calibration::MAX_DRAWN
        )),
        "the thinning is said"
    );
    let Some(browser) = chromium() else { return };
    let page = open(&browser, &page_path, Duration::from_secs(60));
    assert!(page.errors.is_empty(), "{:?}", page.errors);
    assert_drawn_3d(&page, "raw-box");
    attitudes_against_the_box(&page, &set);
    // Every figure marks its drawing on the page's clock, and the clocks agree on the order.
    let first_figure = page.first_figure.expect("the figures are marked");
    assert!(page.painted <= page.first_screen && first_figure <= page.seconds);
    eprintln!(
        "12,000-reading calibration page: {bytes} bytes, text painted at {:.2} s, first screen at {:.2} s, first figure at {first_figure:.2} s, every figure at {:.2} s",
        page.painted, page.first_screen, page.seconds
    );
}

/// The attitude figures of the calibration set `set` (of a log with attitudes and a box): the
/// readings counted inside the box over the whole log are the JSON's, and the points drawn green
/// and grey are the thinned readings that the box holds and does not.
fn attitudes_against_the_box(page: &Opened, set: &Path) {
    use magcal_runner::log::calibration::read_calibration;
    use magcal_runner::output::log_rows::ResidualRow;
    let cal = read_calibration(&set.join("calibration.json")).unwrap();
    let flown = cal.coverage.flown.expect("the log has attitudes");
    let b = flown.box_deg.expect("the scenario gave a box");
    let rows: Vec<ResidualRow> = magcal_runner::output::read_csv(&set.join("residuals.csv")).unwrap();
    let angles = |r: &ResidualRow| Some([r.roll_deg?.0, r.pitch_deg?.0, r.heading_deg?.0]);
    let all: Vec<[f64; 3]> = rows.iter().filter_map(angles).collect();
    assert_eq!(all.len(), flown.with_attitude);
    assert_eq!(Some(all.iter().filter(|a| b.contains(**a)).count()), flown.in_box);
    let shown = magcal_runner::report::thin(rows.len(), magcal_runner::report::calibration::MAX_DRAWN);
    let drawn: Vec<[f64; 3]> = shown.iter().filter_map(|&i| angles(&rows[i])).collect();
    let inside = drawn.iter().filter(|a| b.contains(**a)).count();
    for view in ["roll-pitch-box", "heading-pitch-box"] {
        let lengths = page.eval(&format!(
            "Object.fromEntries(document.querySelector('#{view} .plotly-graph-div').data.map(t => [t.name, t.x.length]))"
        ));
        // A trace with no point is left out of the figure.
        let count = |name: &str| lengths[name].as_u64().unwrap_or(0);
        assert_eq!(count("inside the box"), inside as u64, "{view}: {lengths}");
        assert_eq!(
            count("outside the box"),
            (drawn.len() - inside) as u64,
            "{view}: {lengths}"
        );
        let (share, _) = pixel_statistics(&page.screenshot(&format!("#{view}")));
        assert!(share > 0.01, "{view} is blank: {share:.3}");
    }
    let flown_rows = table(page, "flown");
    assert_eq!(flown_rows.last().unwrap()[1].1, flown.in_box.map(|n| n as f64));
    for (k, v) in flown.roll_deg.iter().enumerate() {
        assert_shows(&flown_rows[0][1 + k], *v);
    }
}

#[test]
fn a_page_is_not_written_into_its_result_or_from_what_is_not_a_result() {
    let tmp = TempDir::new().unwrap();
    let Some(log) = data("hamagure/data-set_1.csv") else {
        return;
    };
    let set = tmp.path().join("cal");
    calibrate(&log, &[], &set);
    let before = crate::common::snapshot(&set);
    for (result, out, needle) in [
        (set.clone(), set.join("page.html"), "inside the result"),
        (set.clone(), set.join("calibration.json"), "calibration.json"),
        (
            tmp.path().join("missing"),
            tmp.path().join("p.html"),
            "no such directory",
        ),
        (log.clone(), tmp.path().join("p.html"), "not a magcal result set"),
        (set.clone(), "-".into(), "--out -: give a file"),
    ] {
        let o = magcal()
            .arg("report")
            .arg(&result)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(needle), "{needle:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
    }
    assert_eq!(crate::common::snapshot(&set), before, "the result is untouched");
    // The log the set was made from, under another name, is told by its SHA-256 and kept.
    let copy = tmp.path().join("log copy.csv");
    fs::copy(&log, &copy).unwrap();
    let o = magcal()
        .arg("report")
        .arg(&set)
        .arg("--out")
        .arg(&copy)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("is the log") && stderr.contains("writing it would destroy it"),
        "{stderr}"
    );
    assert!(
        fs::read(&copy).unwrap() == fs::read(&log).unwrap(),
        "the log is untouched"
    );
    // A file of the set edited after calibrate wrote it is named, and no page is written; also
    // one whose rows no longer parse (residuals.csv is hashed as it is read).
    for (k, (name, from, to)) in [
        ("calibration.json", "\"usable\"", "\"usable\" "),
        ("residuals.csv", "\n", "\n\n"),
        ("residuals.csv", "line,", "line;"),
    ]
    .into_iter()
    .enumerate()
    {
        let edited = tmp.path().join(format!("edited-{k}"));
        fs::create_dir(&edited).unwrap();
        for entry in fs::read_dir(&set).unwrap() {
            let entry = entry.unwrap().path();
            fs::copy(&entry, edited.join(entry.file_name().unwrap())).unwrap();
        }
        let path = edited.join(name);
        let text = fs::read_to_string(&path).unwrap().replacen(from, to, 1);
        fs::write(&path, text).unwrap();
        let page = tmp.path().join("edited.html");
        let o = magcal()
            .arg("report")
            .arg(&edited)
            .arg("--out")
            .arg(&page)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{stderr}");
        assert!(
            stderr.contains(name) && stderr.contains("edited since calibrate wrote it"),
            "{stderr}"
        );
        assert!(!page.exists(), "no page of an edited set");
    }
    // The same result gives the same page, byte for byte.
    let (a, b) = (tmp.path().join("a.html"), tmp.path().join("b.html"));
    report(&set, &a);
    report(&set, &b);
    assert!(
        fs::read(&a).unwrap() == fs::read(&b).unwrap(),
        "two pages of one result differ"
    );
}

#[test]
fn a_page_is_not_written_onto_the_scenario_a_set_was_made_from() {
    let tmp = TempDir::new().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    for (set, scenario) in [
        ("results/ship", "scenarios/ship.toml"),
        ("results/replay-auv-02", "scenarios/replay-auv.toml"),
    ] {
        let copy = tmp.path().join("a copy.toml");
        fs::copy(root.join(scenario), &copy).unwrap();
        let o = magcal()
            .arg("report")
            .arg(root.join(set))
            .arg("--out")
            .arg(&copy)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(&format!("is the scenario {scenario}")), "{stderr}");
        assert!(
            fs::read(&copy).unwrap() == fs::read(root.join(scenario)).unwrap(),
            "the scenario is untouched"
        );
    }
}
