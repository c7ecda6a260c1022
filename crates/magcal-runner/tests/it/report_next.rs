//! `magcal next --report`: the page of the attitudes to add, from a public log, looked at in a
//! real browser ([`crate::browser`]): no console error, no request leaving the file, the coverage
//! sphere drawn with the attitudes on it, and the pilot's table equal to `next --json`; a page
//! onto an input refused with nothing written; the same inputs give the same page.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Duration;

use magcal_runner::report::next::NextJson;
use tempfile::TempDir;

use crate::browser::{chromium, open};
use crate::common::{assert_refused, data, magcal, scenarios};
use crate::report::{assert_drawn_3d, assert_light_page, assert_shows, table};

/// The first 1200 readings of hamagure set 2 (a narrow arc of its restricted tilt) copied into
/// `dir` (so that a page refused onto it could never harm the public file) and calibrated (not
/// usable: exit 3, the set written all the same) into `dir/cal`: the calibration and the copy.
fn hamagure_2(dir: &Path) -> Option<(PathBuf, PathBuf)> {
    let public = data("hamagure/data-set_2.csv")?;
    let log = dir.join("data-set_2.csv");
    let text: String = fs::read_to_string(&public)
        .unwrap()
        .lines()
        .take(1201)
        .map(|l| format!("{l}\n"))
        .collect();
    fs::write(&log, text).unwrap();
    let o = magcal()
        .arg("calibrate")
        .arg(&log)
        .arg("--out")
        .arg(dir.join("cal"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "{}", String::from_utf8_lossy(&o.stderr));
    Some((dir.join("cal/calibration.json"), log))
}

/// `magcal next CAL LOG --scenario drone.toml ARGS`: exit code, stdout, stderr.
fn next(cal: &Path, log: &Path, args: &[&std::ffi::OsStr]) -> (i32, String, String) {
    let o = magcal()
        .arg("next")
        .arg(cal)
        .arg(log)
        .arg("--scenario")
        .arg(scenarios().join("drone.toml"))
        .args(args)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// MotionCal's gap percentage of per-region counts: 1, 0.2 and 0.01 for 0, 1 and 2 readings.
fn gaps(counts: &serde_json::Value) -> f64 {
    counts
        .as_array()
        .unwrap()
        .iter()
        .map(|c| match c.as_u64().unwrap() {
            0 => 1.0,
            1 => 0.2,
            2 => 0.01,
            _ => 0.0,
        })
        .sum()
}

#[test]
fn a_next_page_draws_the_attitudes_on_the_coverage_sphere_and_shows_the_json_numbers() {
    let Some(browser) = chromium() else { return };
    let tmp = TempDir::new().unwrap();
    let Some((cal, log)) = hamagure_2(tmp.path()) else {
        return;
    };
    let page_path = tmp.path().join("next.html");
    let (code, stdout, stderr) = next(
        &cal,
        &log,
        &["--json".as_ref(), "--report".as_ref(), page_path.as_os_str()],
    );
    assert_eq!(code, 0, "{stderr}");
    let json: NextJson = serde_json::from_str(&stdout).unwrap();
    assert_eq!(json.attitudes.len(), 10);
    assert_light_page(&page_path);
    let page = open(&browser, &page_path, Duration::from_secs(60));
    assert!(page.errors.is_empty(), "{:?}", page.errors);
    assert!(
        page.remote_requests(&page_path.canonicalize().unwrap()).is_empty(),
        "{:?}",
        page.requests
    );
    assert_drawn_3d(&page, "coverage-box");

    // The pilot's table is the JSON's, number for number.
    let rows = table(&page, "attitudes");
    assert_eq!(rows.len(), json.attitudes.len());
    for (row, a) in rows.iter().zip(&json.attitudes) {
        assert_shows(&row[0], a.k as f64);
        assert_shows(&row[1], a.roll_deg);
        assert_shows(&row[2], a.pitch_deg);
        assert_shows(&row[3], a.true_heading_deg);
        assert_shows(&row[4], a.magnetic_heading_deg.unwrap());
        assert_shows(&row[5], a.readings as f64);
        assert_shows(&row[6], a.variance);
        // Compass heading = true heading - declination, within the 1e-9 degree they are kept to.
        let d = json.declination_deg.unwrap();
        let m = (a.true_heading_deg - d).rem_euclid(360.0);
        assert!((m - a.magnetic_heading_deg.unwrap()).abs() < 2e-9, "{m} {a:?}");
    }
    let std = table(&page, "parameters");
    assert_eq!(std.len(), 9);
    for (row, p) in std.iter().zip(&json.parameters) {
        assert_eq!(row[0].0, p.name);
        assert_shows(&row[1], p.std_before.unwrap());
        assert_shows(&row[2], p.std_after.unwrap());
    }
    let summary = table(&page, "summary");
    assert_shows(&summary[0][1], json.d_efficiency_before.unwrap());
    assert_shows(&summary[0][2], json.d_efficiency_after.unwrap());
    assert_shows(&summary[1][1], json.motioncal_gap_percent_before);
    assert_shows(&summary[1][2], json.motioncal_gap_percent_after);
    assert_shows(&summary[2][1], json.microstrain_coverage_percent_before);
    assert_shows(&summary[2][2], json.microstrain_coverage_percent_after);
    assert!(json.usable_after && !json.usable_before, "{json:?}");
    // Two passes of ten: one pass leaves fewer than 4 of its 5 simulated logs usable.
    assert_eq!((json.passes_to_usable, json.readings_added), (Some(2), 20));
    let verdict = page.eval("document.querySelector('#verdict').innerText");
    assert!(verdict.as_str().unwrap().starts_with("USABLE AFTER"), "{verdict}");

    // The regions coloured are the ones the JSON's gap figures count, before and after.
    let data = page.eval("JSON.parse(document.getElementById('magcal-data').textContent)");
    assert!((gaps(&data["region_counts"]) - json.motioncal_gap_percent_before).abs() < 1e-9);
    assert!((gaps(&data["region_counts_after"]) - json.motioncal_gap_percent_after).abs() < 1e-9);
    // The attitudes are drawn where their field directions are, just outside the unit sphere
    // (at 1.06, to the 5 significant digits a figure is drawn with).
    let drawn = page.eval(
        "(() => { const d = document.getElementById('coverage').data; const t = d[d.length - 1]; return [t.x, t.y, t.z]; })()",
    );
    for (k, a) in json.attitudes.iter().enumerate() {
        let norm = a.field_direction.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((norm - 1.0).abs() < 1e-12, "{a:?}");
        for i in 0..3 {
            let (got, want) = (drawn[i][k].as_f64().unwrap(), 1.06 * a.field_direction[i]);
            // Half a unit of the fifth significant digit.
            let half = 0.5 * 10f64.powi(want.abs().log10().floor() as i32 - 4) * (1.0 + 1e-9);
            assert!((got - want).abs() <= half, "{got} {want} {a:?}");
        }
    }
    eprintln!("next page: drawn in {:.2} s", page.seconds);
}

#[test]
fn a_next_page_onto_an_input_is_refused_and_the_same_inputs_give_the_same_page() {
    let tmp = TempDir::new().unwrap();
    let Some((cal, log)) = hamagure_2(tmp.path()) else {
        return;
    };
    let scenario = tmp.path().join("drone.toml");
    fs::copy(scenarios().join("drone.toml"), &scenario).unwrap();
    let before: Vec<Vec<u8>> = [&cal, &log, &scenario].iter().map(|p| fs::read(p).unwrap()).collect();
    for (out, needle) in [
        (cal.clone(), "is the input"),
        (log.clone(), "is the input"),
        (scenario.clone(), "is the input"),
        (PathBuf::from("-"), "--report -: give a file"),
        (tmp.path().join("missing/next.html"), "no directory"),
        (tmp.path().join("cal/next.html"), "magcal calibration set"),
    ] {
        let o = magcal()
            .arg("next")
            .arg(&cal)
            .arg(&log)
            .arg("--scenario")
            .arg(&scenario)
            .arg("--report")
            .arg(&out)
            .output()
            .unwrap();
        let got = (
            o.status.code().unwrap_or(-1),
            String::from_utf8_lossy(&o.stdout).into_owned(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        );
        assert_refused(&got, &["--report", needle]);
    }
    let after: Vec<Vec<u8>> = [&cal, &log, &scenario].iter().map(|p| fs::read(p).unwrap()).collect();
    assert!(before == after, "an input was changed");
    assert!(!tmp.path().join("cal/next.html").exists());
    // The same inputs give the same page, byte for byte, and the text report beside it.
    let (a, b) = (tmp.path().join("a.html"), tmp.path().join("b.html"));
    let (code_a, text_a, _) = next(&cal, &log, &["--report".as_ref(), a.as_os_str()]);
    let (code_b, text_b, _) = next(&cal, &log, &["--report".as_ref(), b.as_os_str()]);
    assert_eq!((code_a, code_b), (0, 0));
    assert_eq!(text_a, text_b);
    assert!(text_a.contains("usable (full model): before false"), "{text_a}");
    assert!(text_a.contains("after true"), "{text_a}");
    assert!(
        fs::read(&a).unwrap() == fs::read(&b).unwrap(),
        "two pages of the same inputs differ"
    );
}

/// Text as the page's template escapes it.
fn escaped(text: &str) -> String {
    text.replace('&', "&#38;")
        .replace('<', "&#60;")
        .replace('>', "&#62;")
        .replace('"', "&#34;")
        .replace('\'', "&#39;")
}

#[test]
fn a_next_page_of_a_log_with_attitudes_says_each_attitude_relative_to_what_was_flown() {
    let tmp = TempDir::new().unwrap();
    let Some(log) = crate::common::broad_02_moving(tmp.path()) else {
        return;
    };
    let cal = tmp.path().join("cal");
    let o = magcal()
        .arg("calibrate")
        .arg(&log)
        .args(crate::common::BROAD_ARGS)
        // The subject is the page, not the check by trials: the fewest trials.
        .args(["--trials", "20"])
        .arg("--out")
        .arg(&cal)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let page_path = tmp.path().join("next.html");
    // `next` reads the log as calibrate did; the units come from calibration.json.
    let (code, stdout, stderr) = next(
        &cal.join("calibration.json"),
        &log,
        &[
            "--columns",
            "mx,my,mz",
            "--quaternion",
            "qw,qx,qy,qz",
            "--attitude-frame",
            "enu",
            "--json",
            "--report",
        ]
        .map(std::ffi::OsStr::new)
        .into_iter()
        .chain([page_path.as_os_str()])
        .collect::<Vec<_>>(),
    );
    assert_eq!(code, 0, "{stderr}");
    let json: NextJson = serde_json::from_str(&stdout).unwrap();
    let relative = json.relative_to_log.expect("the log has attitudes");
    assert_eq!(relative.flown, 32_280);
    // One sentence per tilt, the attitudes of one tilt at their headings together.
    assert!(!relative.tilts.is_empty() && relative.tilts.len() <= json.attitudes.len());
    let html = fs::read_to_string(&page_path).unwrap();
    assert!(html.contains(&format!("<p>Relative to the log&#39;s {} attitudes", relative.flown)));
    for tilt in &relative.tilts {
        assert!(html.contains(&format!("<p>{}</p>", escaped(tilt))), "{tilt}");
    }
    let enu = relative.as_logged.expect("an ENU log's own attitudes");
    assert!(html.contains(&escaped(&enu)), "{enu}");
}
