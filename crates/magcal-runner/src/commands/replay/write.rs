//! The files of a replay set and the table printed.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use anyhow::Result;
use magcal_core::{CalibrationStatus, Summary};

use super::trials::{Scored, Trial};
use super::{Replay, ReplayArgs};
use crate::digest::sha256_hex;
use crate::log::source::Log;
use crate::output::manifest::{ReplayManifest, SetKind};
use crate::output::replay_rows::{RealisationRow, ReplaySummaryRow, ReplayTrialRow, WholeLogRow};
use crate::output::staging::ResultSet;
use crate::output::{self, Real, Status};
use crate::scenario::Scenario;
use crate::scenario::site::Units;

/// How a metric is read from an outcome.
type MetricOf = fn(&Scored) -> Option<f64>;

/// The metrics of `summary.csv`, in order, and how each is read from an outcome.
const METRICS: [(&str, MetricOf); 9] = [
    ("heading_rms_deg", |s| s.figures.map(|f| f.heading_rms)),
    ("heading_p95_deg", |s| s.figures.map(|f| f.heading_p95)),
    ("heading_max_deg", |s| s.figures.map(|f| f.heading_max)),
    ("direction_rms_deg", |s| s.figures.map(|f| f.direction_rms)),
    ("heading_rms_held_deg", |s| s.held.map(|f| f.heading_rms)),
    ("direction_rms_held_deg", |s| s.held.map(|f| f.direction_rms)),
    ("eta_psi", |s| s.eta.and_then(|e| e.psi)),
    ("eta_s", |s| s.eta.and_then(|e| e.scale)),
    ("eta_o", |s| s.eta.and_then(|e| e.bias)),
];

fn real(x: Option<f64>) -> Option<Real> {
    x.map(Real)
}

fn realisation_rows(r: &Replay) -> Vec<RealisationRow> {
    let mut rows = Vec::new();
    for ((d, points), turned) in r.designs.iter().zip(&r.realised).zip(&r.turned_deg) {
        for (i, (p, a)) in points.iter().zip(&d.attitudes).enumerate() {
            let angles = &p.angles_deg;
            let [roll, yaw, pitch] = a.to_degrees();
            rows.push(RealisationRow {
                design: d.name.clone(),
                turned_deg: Real(*turned),
                point: i,
                roll_deg: Real(roll),
                yaw_deg: Real(yaw),
                pitch_deg: Real(pitch),
                readings: d.readings[i],
                ux: Real(p.target[0]),
                uy: Real(p.target[1]),
                uz: Real(p.target[2]),
                candidates: p.starts.len(),
                nearest_deg: real(angles.first().copied()),
                median_deg: real(angles.get(angles.len() / 2).copied()),
                farthest_deg: real(angles.last().copied()),
            });
        }
    }
    rows
}

fn scored_fields(s: &Scored) -> [Option<Real>; 10] {
    let f = s.figures;
    let e = s.eta;
    [
        real(f.map(|f| f.heading_rms)),
        real(f.map(|f| f.heading_p95)),
        real(f.map(|f| f.heading_max)),
        real(f.map(|f| f.direction_rms)),
        real(s.held.map(|f| f.heading_rms)),
        real(s.held.map(|f| f.direction_rms)),
        real(e.and_then(|e| e.psi)),
        real(e.and_then(|e| e.scale)),
        real(e.and_then(|e| e.bias)),
        real(s.rms_residual),
    ]
}

fn trial_rows(r: &Replay) -> impl Iterator<Item = ReplayTrialRow> + '_ {
    r.designs.iter().zip(&r.trials).flat_map(move |(d, trials)| {
        trials.iter().enumerate().flat_map(move |(t, trial): (usize, &Trial)| {
            trial.scored.iter().zip(&r.models).map(move |(s, m)| {
                let [h, h95, hmax, dir, hh, dh, psi, sc, o, res] = scored_fields(s);
                ReplayTrialRow {
                    design: d.name.clone(),
                    trial: t,
                    model: m.as_str().into(),
                    status: Status(s.status),
                    heading_rms_deg: h,
                    heading_p95_deg: h95,
                    heading_max_deg: hmax,
                    direction_rms_deg: dir,
                    heading_rms_held_deg: hh,
                    direction_rms_held_deg: dh,
                    eta_psi: psi,
                    eta_s: sc,
                    eta_o: o,
                    rms_residual_nt: res,
                    drawn_max_deg: Real(trial.drawn_max_deg),
                }
            })
        })
    })
}

/// The summary rows of every design, model and metric.
pub fn summary_rows(r: &Replay) -> Vec<ReplaySummaryRow> {
    let mut rows = Vec::new();
    for (d, trials) in r.designs.iter().zip(&r.trials) {
        for (k, m) in r.models.iter().enumerate() {
            let outcomes: Vec<&Scored> = trials.iter().map(|t| &t.scored[k]).collect();
            let count = |s: CalibrationStatus| outcomes.iter().filter(|o| o.status == s).count();
            let ok: Vec<&&Scored> = outcomes.iter().filter(|o| o.status == CalibrationStatus::Ok).collect();
            for (name, of) in METRICS {
                let v: Vec<f64> = ok.iter().filter_map(|o| of(o)).collect();
                let s = Summary::new(&v, outcomes.len() - v.len());
                let defined = |x: f64| x.is_finite().then_some(Real(x));
                rows.push(ReplaySummaryRow {
                    design: d.name.clone(),
                    m: d.m(),
                    model: m.as_str().into(),
                    trials: outcomes.len(),
                    ok: ok.len(),
                    not_converged: count(CalibrationStatus::NotConverged),
                    not_identifiable: count(CalibrationStatus::NotIdentifiable),
                    failed: outcomes.iter().filter(|o| !o.status.has_estimate()).count(),
                    metric: name.into(),
                    mean: defined(s.mean),
                    std: defined(s.std),
                    median: defined(s.median),
                    p05: defined(s.p05),
                    p95: defined(s.p95),
                    se_mean: defined(s.se_mean),
                    rms: (!v.is_empty()).then(|| Real((v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt())),
                });
            }
        }
    }
    rows
}

fn whole_log_rows(r: &Replay) -> Vec<WholeLogRow> {
    r.whole_log
        .iter()
        .zip(&r.models)
        .map(|(s, m)| {
            let [h, h95, hmax, dir, hh, dh, psi, sc, o, res] = scored_fields(s);
            WholeLogRow {
                model: m.as_str().into(),
                readings: r.prepared.readings.len(),
                status: Status(s.status),
                heading_rms_deg: h,
                heading_p95_deg: h95,
                heading_max_deg: hmax,
                direction_rms_deg: dir,
                heading_rms_held_deg: hh,
                direction_rms_held_deg: dh,
                eta_psi: psi,
                eta_s: sc,
                eta_o: o,
                rms_residual_nt: res,
            }
        })
        .collect()
}

/// The settings that shape the result, by name.
fn settings(args: &ReplayArgs, r: &Replay, units: Units) -> BTreeMap<String, String> {
    let p = &r.prepared;
    let mut s = BTreeMap::new();
    let mut put = |k: &str, v: String| {
        s.insert(k.to_string(), v);
    };
    put("hold", r.hold.to_string());
    put("within_deg", args.within_deg.to_string());
    put("candidates", args.candidates.to_string());
    put(
        "models",
        r.models.iter().map(|m| m.as_str()).collect::<Vec<_>>().join(","),
    );
    put("truth", args.truth.as_str().into());
    put("orient", format!("{:?}", args.orient).to_lowercase());
    put("random", format!("{:?}", args.random).to_lowercase());
    put("units_nt", units.nt().to_string());
    put("noise_nt", p.noise.to_string());
    put("noise_source", p.noise_source.into());
    put("held_noise_nt", r.held_noise.to_string());
    put("white_held_noise_nt", r.white_held_noise.to_string());
    put(
        "measured_held_error_nt",
        r.measured_held_error.map_or_else(String::new, |e| e.to_string()),
    );
    put("magnitude_nt", p.magnitude.to_string());
    put("magnitude_source", p.magnitude_source.into());
    put("readings", p.readings.len().to_string());
    put("without_attitude", p.without_attitude.to_string());
    put("scoring_readings", r.scoring.to_string());
    s
}

/// Writes every file of the set (`manifest.json` last).
///
/// # Errors
/// A file that cannot be written.
pub fn write_set(
    args: &ReplayArgs,
    scenario: &Scenario,
    log: &Log,
    r: &Replay,
    set: &mut ResultSet,
    units: Units,
) -> Result<()> {
    let mut files = BTreeMap::new();
    let mut put = |name: &str, bytes: Vec<u8>| -> Result<()> {
        set.put(name, &bytes)?;
        files.insert(name.to_string(), sha256_hex(&bytes));
        Ok(())
    };
    put("realisation.csv", output::csv_bytes(realisation_rows(r))?)?;
    put("summary.csv", output::csv_bytes(summary_rows(r))?)?;
    put("whole_log.csv", output::csv_bytes(whole_log_rows(r))?)?;
    put("trials.csv", output::csv_bytes(trial_rows(r))?)?;
    let summary = summary_rows(r);
    let cells = |metric: &str| -> Vec<crate::plots::ReplayCell> {
        summary
            .iter()
            .filter(|s| s.metric == metric)
            .map(|s| crate::plots::ReplayCell {
                design: s.design.clone(),
                model: s.model.clone(),
                trials: s.trials,
                band: match (s.p05, s.median, s.p95) {
                    (Some(a), Some(m), Some(b)) => Some([a.0, m.0, b.0]),
                    _ => None,
                },
            })
            .collect()
    };
    let title = format!("{} on {}", scenario.name, file_name(&args.log));
    let metrics = [
        (
            "heading_rms",
            "heading rms against the reference, deg",
            cells("heading_rms_deg"),
        ),
        (
            "direction_rms",
            "direction rms against the reference, deg",
            cells("direction_rms_deg"),
        ),
        ("eta_psi", "eta_psi, %", cells("eta_psi")),
        ("eta_s", "eta_S, %", cells("eta_s")),
        ("eta_o", "eta_O, %", cells("eta_o")),
    ];
    crate::plots::draw_replay(set, "plots/", &title, &metrics)?;
    let manifest = ReplayManifest {
        kind: SetKind::Replay,
        command: std::env::args().collect(),
        scenario: scenario.name.clone(),
        scenario_path: scenario.path.display().to_string(),
        scenario_sha256: scenario.hash.clone(),
        log: args.log.display().to_string(),
        log_sha256: log.sha256.clone(),
        log_bytes: log.bytes,
        seed: scenario.seed,
        trials: r.trials_per_design,
        settings: settings(args, r, units),
        version: env!("CARGO_PKG_VERSION").into(),
        git_revision: env!("MAGCAL_GIT_REVISION").into(),
        rustc: env!("MAGCAL_RUSTC_VERSION").into(),
        target: env!("MAGCAL_TARGET").into(),
        files: files.keys().cloned().collect(),
        file_sha256: files,
        manifest_sha256: None,
    };
    set.put("manifest.json", &manifest.to_bytes()?)
}

/// The file name of `path` (the whole path where it has none).
fn file_name(path: &Path) -> String {
    path.file_name()
        .map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned())
}

/// The table printed: per design and model, the outcomes and the median (5th-95th percentile)
/// of the heading rms, and of the eta where the truth is known; then the whole log's.
///
/// # Errors
/// A failed write.
pub fn print(w: &mut dyn Write, r: &Replay, dir: &Path, seconds: f64) -> Result<()> {
    let p = &r.prepared;
    writeln!(
        w,
        "{} readings with an attitude ({} without, left out); field {:.1} nT ({}); noise {:.1} nT per reading ({})",
        p.readings.len(),
        p.without_attitude,
        p.magnitude,
        p.magnitude_source,
        p.noise,
        p.noise_source,
    )?;
    writeln!(
        w,
        "a held attitude is the mean of {} readings: white noise would leave {:.1} nT, the whole log's calibration measures {} on them; the verdicts rest on {:.1} nT",
        r.hold,
        r.white_held_noise,
        r.measured_held_error.map_or("nothing".into(), |e| format!("{e:.1} nT")),
        r.held_noise,
    )?;
    let summary = summary_rows(r);
    let find = |d: &str, m: &str, metric: &str| {
        summary
            .iter()
            .find(|s| s.design == d && s.model == m && s.metric == metric)
    };
    let cell = |s: Option<&ReplaySummaryRow>| match s {
        Some(ReplaySummaryRow {
            median: Some(m),
            p05: Some(a),
            p95: Some(b),
            ..
        }) => format!("{:.3} ({:.3}-{:.3})", m.0, a.0, b.0),
        _ => "-".into(),
    };
    writeln!(
        w,
        "{:<14} {:>4} {:<10} {:>9}  {:<26} {:<26} eta psi / S / O % (median)",
        "design", "m", "model", "ok/trials", "heading rms deg", "direction rms deg"
    )?;
    for ((d, points), trials) in r.designs.iter().zip(&r.realised).zip(&r.trials) {
        if let (Some(i), true) = (points.iter().position(|p| p.is_empty()), trials.is_empty()) {
            writeln!(
                w,
                "{:<14} {:>4} not realised: attitude {i} has no window of the log within the angle asked",
                d.name,
                d.m()
            )?;
            continue;
        }
        for m in &r.models {
            let h = find(&d.name, m.as_str(), "heading_rms_deg");
            let eta = ["eta_psi", "eta_s", "eta_o"]
                .map(|e| {
                    find(&d.name, m.as_str(), e)
                        .and_then(|s| s.median)
                        .map_or("-".into(), |v| format!("{:.3}", v.0))
                })
                .join(" / ");
            writeln!(
                w,
                "{:<14} {:>4} {:<10} {:>9}  {:<26} {:<26} {}",
                d.name,
                d.m(),
                m.as_str(),
                h.map_or("-".into(), |h| format!("{}/{}", h.ok, h.trials)),
                cell(h),
                cell(find(&d.name, m.as_str(), "direction_rms_deg")),
                eta
            )?;
        }
    }
    for (s, m) in r.whole_log.iter().zip(&r.models) {
        let f = s.figures.map_or("-".into(), |f| format!("{:.3}", f.heading_rms));
        let d = s.figures.map_or("-".into(), |f| format!("{:.3}", f.direction_rms));
        writeln!(
            w,
            "whole log      {:>4} {:<10} {:>9}  {f:<26} {d:<26}",
            p.readings.len(),
            m.as_str(),
            s.status.as_str()
        )?;
    }
    writeln!(w, "written to {} in {seconds:.1} s", dir.display())?;
    Ok(())
}
