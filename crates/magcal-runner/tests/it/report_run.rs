//! `magcal report` of `design` and `run` sets: the shipped sets' pages looked at in a real browser
//! ([`crate::browser`]): no console error, no request leaving the file, the flight plan drawn in
//! 3D, the tables equal to the set's CSV files, the certified efficiency equal to what
//! `certificate.csv` certifies, the noise sweep drawn from `summary.csv`, and the set's SVG
//! figures inlined byte for byte.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Duration;

use tempfile::TempDir;

use crate::browser::{Opened, chromium, open, pixel_statistics};
use crate::common::{magcal, smoke};
use crate::report::{assert_drawn_3d, assert_light_page, assert_traces_in_bundle, table};

/// A shipped result set.
fn shipped(set: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../results").join(set)
}

/// `magcal report RESULT --out OUT`, which must succeed.
fn report(result: &Path, out: &Path) {
    let o = magcal()
        .arg("report")
        .arg(result)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// The rows of a CSV file as text cells, header first.
fn csv(path: &Path) -> Vec<Vec<String>> {
    fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

/// The column `name` of CSV rows (header first), as written.
fn column<'a>(rows: &'a [Vec<String>], name: &str) -> Vec<&'a str> {
    let k = rows[0]
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("{name}"));
    rows[1..].iter().map(|r| r[k].as_str()).collect()
}

/// A cell shows the CSV text `written`: an empty CSV cell is a dash with no value; otherwise its
/// `data-value` is the file's number exactly and its text that number to within half a unit of
/// its last digit.
fn assert_cell(cell: &(String, Option<f64>), written: &str) {
    if written.is_empty() {
        assert_eq!(cell, &("-".to_string(), None));
        return;
    }
    let value: f64 = written.parse().unwrap();
    assert_eq!(cell.1, Some(value), "{cell:?} against {written}");
    let shown: f64 = cell.0.parse().unwrap_or_else(|_| panic!("{cell:?}"));
    let decimals = cell.0.split('.').nth(1).map_or(0, |d| d.len() as i32);
    let unit = if cell.0.contains('e') {
        value.abs() * 1e-3
    } else {
        10f64.powi(-decimals)
    };
    // A heading that rounds up to 360 reads 0, as a compass does.
    let off = (shown - value).abs();
    let off = off.min((off - 360.0).abs());
    assert!(off <= 0.5 * unit * (1.0 + 1e-9), "{cell:?} against {value}");
}

/// The design tables of `set` on `page` against its designs.csv, design_metrics.csv and
/// certificate.csv.
fn assert_plans(page: &Opened, set: &Path) {
    let designs = csv(&set.join("designs.csv"));
    let metrics = csv(&set.join("design_metrics.csv"));
    let names = column(&metrics, "design");
    let buttons = page.eval("document.getElementById('plan').layout.updatemenus[0].buttons.map(b => b.label)");
    assert_eq!(buttons, serde_json::json!(names), "one dropdown entry per design");
    // Choosing a design in the dropdown shows its attitudes and no other design's.
    for (i, name) in names.iter().enumerate() {
        let shown = page.eval(&format!(
            "(() => {{ const d = document.getElementById('plan'); Plotly.restyle(d, d.layout.updatemenus[0].buttons[{i}].args[0]); return d.data.filter(t => t.visible !== false && t.mode === 'markers').map(t => [t.name, t.x.length]); }})()"
        ));
        let attitudes = designs[1..].iter().filter(|r| r[0] == *name).count();
        assert_eq!(shown, serde_json::json!([[format!("{name} attitudes"), attitudes]]));
    }
    for (i, name) in names.iter().enumerate() {
        let rows: Vec<Vec<String>> = designs[1..].iter().filter(|r| r[0] == *name).cloned().collect();
        let shown = table(page, &format!("attitudes-{}", i + 1));
        assert_eq!(shown.len(), rows.len(), "{name}");
        let mut with_header = vec![designs[0].clone()];
        with_header.extend(rows);
        let columns = [
            "visit",
            "roll_deg",
            "pitch_deg",
            "yaw_deg",
            "true_heading_deg",
            "magnetic_heading_deg",
            "readings",
            "turn_deg",
        ];
        for (c, col) in columns.iter().enumerate() {
            for (r, written) in column(&with_header, col).iter().enumerate() {
                assert_cell(&shown[r][c], written);
            }
        }
    }
    let shown = table(page, "designs");
    let certificate = csv(&set.join("certificate.csv"));
    let per_reading: f64 = column(&certificate, "ln_det_bound_per_reading")[0].parse().unwrap();
    for (r, (bound, (ln_det, m))) in column(&metrics, "d_efficiency_bound")
        .iter()
        .zip(column(&metrics, "ln_det_mf").iter().zip(column(&metrics, "m")))
        .enumerate()
    {
        assert_eq!(shown[r][0].0, names[r]);
        assert_cell(&shown[r][3], m);
        assert_cell(&shown[r][4], ln_det);
        assert_cell(&shown[r][6], bound);
        // What the certificate certifies (docs/conventions.md): exp((ln det M_F - 9 ln m -
        // bound per reading) / 9), each term near 300, so to a few ulps of 300 over 9.
        let (ln_det, m): (f64, f64) = (ln_det.parse().unwrap(), m.parse().unwrap());
        let certified = ((ln_det - 9.0 * m.ln() - per_reading) / 9.0).exp();
        let value = shown[r][6].1.unwrap();
        assert!(
            (value - certified).abs() <= 64.0 * f64::EPSILON * 300.0,
            "{value} against {certified}"
        );
        assert!(value <= 1.0 + 1e-12, "a certified efficiency above 1: {value}");
    }
    let cert = table(page, "certificate");
    for (r, col) in [
        "ln_det_per_reading",
        "d_max",
        "d_max_roll_deg",
        "d_max_yaw_deg",
        "d_max_pitch_deg",
        "ln_det_bound_per_reading",
        "tolerance",
    ]
    .iter()
    .enumerate()
    {
        assert_cell(&cert[r][1], column(&certificate, col)[0]);
    }
}

/// The summary table against summary.csv, every cell.
fn assert_summary(page: &Opened, set: &Path) {
    let summary = csv(&set.join("summary.csv"));
    let shown = table(page, "summary");
    assert_eq!(shown.len(), summary.len() - 1);
    // The table's columns are the file's, metric moved after the noise levels.
    let order = [0, 1, 2, 8, 3, 4, 5, 6, 7, 9, 10, 11, 12, 13, 14, 15, 16];
    for (row, written) in shown.iter().zip(&summary[1..]) {
        for (c, &k) in order.iter().enumerate() {
            if c == 0 || c == 3 {
                assert_eq!(row[c].0, written[k]);
            } else {
                assert_cell(&row[c], &written[k]);
            }
        }
    }
}

/// Every SVG of the set's plots/ is in the page byte for byte (the page draws its figures from
/// the set's sealed files as `magcal plot` drew these), as a `data:` image, and drawn.
fn assert_figures(page: &Opened, html: &str, set: &Path) {
    use base64::Engine;
    let mut count = 0;
    for entry in fs::read_dir(set.join("plots")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "svg") {
            let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
            let svg = fs::read(&path).unwrap();
            let shown = format!(
                "<div class=\"figure\" id=\"figure-{stem}\"><img alt=\"{}\" src=\"data:image/svg+xml;base64,{}\"></div>",
                "",
                base64::engine::general_purpose::STANDARD.encode(&svg)
            );
            let (head, tail) = shown.split_once("alt=\"\"").unwrap();
            assert!(
                html.contains(head) && html.contains(tail),
                "{} is not the page's figure",
                path.display()
            );
            count += 1;
        }
    }
    assert_eq!(html.matches("<div class=\"figure\"").count() as u64, count);
    let drawn = page.eval(
        "Array.from(document.querySelectorAll('.figure > img')).filter(i => i.complete && i.naturalWidth > 100 && i.getBoundingClientRect().width > 100).length",
    );
    assert_eq!(drawn.as_u64(), Some(count), "every figure decoded and laid out");
    assert_eq!(
        page.eval("document.querySelectorAll('.figure svg').length").as_u64(),
        Some(0),
        "no SVG markup in the page"
    );
}

/// The page of a shipped set, opened: no console error, no request, the plan drawn.
fn opened(browser: &crate::browser::Browser, set: &Path, out: &Path) -> (Opened, String) {
    report(set, out);
    assert_traces_in_bundle(out);
    let page = open(browser, out, Duration::from_secs(90));
    assert!(page.errors.is_empty(), "{}: {:?}", set.display(), page.errors);
    assert!(
        page.remote_requests(&out.canonicalize().unwrap()).is_empty(),
        "{:?}",
        page.requests
    );
    assert_drawn_3d(&page, "plan-box");
    // The glyphs' noses are drawn (red strokes), not only the sphere behind them.
    let shot = page.screenshot("#plan-box");
    let red = shot.pixels().filter(|p| p[0] > 170 && p[1] < 90 && p[2] < 90).count();
    assert!(red > 300, "{}: {red} red pixels of nose strokes", set.display());
    (page, fs::read_to_string(out).unwrap())
}

#[test]
fn report_run_pages_draw_the_flight_plans_and_show_the_sets_files() {
    let Some(browser) = chromium() else { return };
    let tmp = TempDir::new().unwrap();
    for name in ["wu2014", "ship"] {
        let set = shipped(name);
        let path = tmp.path().join(format!("{name}.html"));
        let (page, html) = opened(&browser, &set, &path);
        // The run's page is under the bound; the ship's design set has 0.1 MB more of figures.
        if name == "wu2014" {
            assert_light_page(&path);
        }
        assert_plans(&page, &set);
        assert_summary(&page, &set);
        assert_figures(&page, &html, &set);
        assert!(!html.contains("id=\"sweep\""), "{name}: one noise level, no sweep");
        let metrics = csv(&set.join("design_metrics.csv"));
        let designs = column(&metrics, "design");
        let pick = |flag: &str| -> Vec<String> {
            designs
                .iter()
                .zip(column(&metrics, flag))
                .filter(|(_, v)| *v == "true")
                .map(|(d, _)| d.to_string())
                .collect()
        };
        let (recommended, works) = (pick("recommended"), pick("works"));
        if name == "wu2014" {
            // [P1]'s optimum keeps the heading within the budget, but 9 readings are too few.
            assert!(
                recommended.is_empty() && works.contains(&"optimum".to_string()),
                "{works:?}"
            );
        }
        let verdict = page.eval("document.querySelector('#verdict').innerText");
        // The verdict follows the file: the recommended design; or, with none, the designs that
        // work but are too short for a log to vouch for itself; or that none works.
        let expected = match (recommended.first(), works.is_empty()) {
            (Some(r), _) => format!("RECOMMENDED: design {r} ("),
            (None, false) => format!("NONE RECOMMENDED AS IT STANDS: {} work", works.join(", ")),
            (None, true) => "NO DESIGN WORKS: ".to_string(),
        };
        assert!(verdict.as_str().unwrap().starts_with(&expected), "{verdict}");
        eprintln!("{name} page: {} bytes, drawn in {:.2} s", html.len(), page.seconds);
    }
}

#[test]
fn report_run_the_noise_sweep_is_drawn_from_summary_csv() {
    let Some(browser) = chromium() else { return };
    let tmp = TempDir::new().unwrap();
    let set = shipped("noise-sweep");
    let (page, html) = opened(&browser, &set, &tmp.path().join("sweep.html"));
    assert_plans(&page, &set);
    assert_summary(&page, &set);
    assert_figures(&page, &html, &set);
    let (share, _) = pixel_statistics(&page.screenshot("#sweep-box"));
    assert!(share > 0.03, "the sweep is blank: {share:.3}");
    // The first metric's median traces: x the file's noise levels, y its medians as drawn (5
    // significant digits).
    let summary = csv(&set.join("summary.csv"));
    let traces = page.eval("document.getElementById('sweep').data.filter(t => t.visible !== false && t.name.endsWith(': median')).map(t => [t.name, t.x, t.y])");
    let traces = traces.as_array().unwrap();
    let designs = column(&csv(&set.join("design_metrics.csv")), "design").len();
    assert_eq!(traces.len(), designs);
    for t in traces {
        let design = t[0].as_str().unwrap().trim_end_matches(": median");
        let rows: Vec<&Vec<String>> = summary[1..]
            .iter()
            .filter(|r| r[0] == design && r[8] == "eta_psi" && !r[11].is_empty())
            .collect();
        assert_eq!(t[1].as_array().unwrap().len(), rows.len(), "{design}");
        for (k, r) in rows.iter().enumerate() {
            assert_eq!(t[1][k].as_f64(), Some(r[1].parse::<f64>().unwrap()));
            let median: f64 = r[11].parse().unwrap();
            assert!(
                (t[2][k].as_f64().unwrap() - median).abs() <= 5e-5 * median,
                "{design}: {t}"
            );
        }
    }
    // The cells without a value are counted, not dropped silently.
    let missing = page.eval("JSON.parse(document.getElementById('magcal-data').textContent).sweep[0]");
    let empty = summary[1..]
        .iter()
        .filter(|r| r[8] == "eta_psi" && r[11].is_empty())
        .count();
    assert!(empty > 0, "the sweep's noisiest cells have no ok trial");
    assert_eq!(missing["metric"], "eta_psi");
    assert_eq!(missing["missing"].as_u64(), Some(empty as u64));
    let axes = page.eval(
        "[document.getElementById('sweep').layout.xaxis.type, document.getElementById('sweep').layout.yaxis.type]",
    );
    assert_eq!(
        axes,
        serde_json::json!(["log", "log"]),
        "sigma from 1 to 300 nT and eta over decades"
    );
    // The dropdown's last metric, as a person picks it: its traces only, its own y axis.
    let picked = page.eval(
        "(() => { const d = document.getElementById('sweep'); const b = d.layout.updatemenus[0].buttons; const last = b[b.length - 1]; Plotly.update(d, last.args[0], last.args[1]); return [last.label, d.layout.yaxis.title.text, d.data.filter(t => t.visible !== false && t.name.endsWith(': median')).length]; })()",
    );
    assert_eq!(picked[0], "heading_max_deg");
    assert_eq!(picked[1], "largest heading error over level yaws (deg)");
    assert_eq!(picked[2].as_u64(), Some(designs as u64));
    eprintln!("noise-sweep page: {} bytes, drawn in {:.2} s", html.len(), page.seconds);
}

#[test]
fn report_run_of_a_design_set_and_of_changed_or_unsafe_sets() {
    let tmp = TempDir::new().unwrap();
    let set = tmp.path().join("smoke");
    let o = magcal()
        .args(["design", "--quiet"])
        .arg(smoke())
        .arg("--out")
        .arg(&set)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let page = tmp.path().join("design.html");
    report(&set, &page);
    let html = assert_traces_in_bundle(&page);
    assert!(html.contains("each design checked by its own noisy trials"));
    assert!(html.contains("id=\"plan\"") && html.contains("id=\"attitudes-1\""));
    assert!(!html.contains("id=\"summary\""), "no trials, no summary");
    // A set whose files changed, or whose figure could run script, gives no page.
    let designs = set.join("designs.csv");
    let original = fs::read(&designs).unwrap();
    let mut changed = original.clone();
    let at = changed.iter().rposition(|&b| b == b'1').unwrap();
    changed[at] = b'2';
    fs::write(&designs, &changed).unwrap();
    let out = tmp.path().join("bad.html");
    let o = magcal()
        .arg("report")
        .arg(&set)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("designs.csv: edited since magcal run wrote it") && stderr.lines().count() == 1,
        "{stderr}"
    );
    assert!(!out.exists(), "no page written");
    // plots/ is not sealed and never read: a drawing that runs script, a link to a file outside
    // the set and a FIFO there change nothing of the page, which draws its own figures.
    fs::write(&designs, &original).unwrap();
    let plots = set.join("plots");
    let svg = fs::read_dir(&plots)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "svg"))
        .unwrap();
    let drawing = fs::read_to_string(&svg).unwrap();
    fs::write(&svg, drawing.replace("<svg", "<svg onload=\"document.title='pwned'\"")).unwrap();
    let secret = tmp.path().join("secret.txt");
    fs::write(&secret, "SECRET-OUTSIDE-THE-SET").unwrap();
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(&secret, plots.join("zz_link.svg")).unwrap();
        let fifo = std::ffi::CString::new(plots.join("zz_fifo.svg").to_str().unwrap()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(fifo.as_ptr(), 0o600) }, 0);
    }
    let again = tmp.path().join("again.html");
    report(&set, &again);
    let html = fs::read_to_string(&again).unwrap();
    assert!(!html.contains("pwned") && !html.contains("SECRET-OUTSIDE-THE-SET"));
    assert_eq!(
        html.replace("again.html", "design.html"),
        fs::read_to_string(&page).unwrap().replace("again.html", "design.html")
    );
}
