//! `magcal check`: runs a scenario again with the seed and trial count its baseline's manifest
//! records, and compares the result with the baseline (`results/<name>/` unless `--baseline`).
//!
//! The baseline is also checked against itself: its `manifest.json` must have the SHA-256 it
//! records of itself (an edited seed or file hash is damage, exit 2, before any run); every file
//! it lists must still have the SHA-256 recorded when it was written, so an edit of any of them
//! shows; and its `trials.csv` must give its `summary.csv` (to 1e-9). `run.json` (the earlier run's command,
//! threads, toolchain and timings) is neither listed nor read.
//!
//! The new run is compared with it (see [`compare`]): Monte Carlo means within 4 combined standard
//! errors, medians within 4 x 1.2533 of them, standard deviations within 4 of their own standard
//! errors; trial status counts within 4 sqrt(count); a design's `ln det M_F` within 1e-6 relative
//! and its certified bound within 1e-6; the attitudes (1.5e-9 degree) and `cond_2(H)`,
//! `cond_2(M_F)` (1e-3, 2e-3 relative) only of designs that are not optimised; the PSO runs by
//! the mean of their final `ln det M_F` within 4 combined standard errors. Identical values
//! match, non-finite ones included; a statistic that is undefined (one successful trial has no
//! standard error) is compared to 1e-9 relative; a non-finite standard error in the baseline is an
//! error of the baseline (exit 2).

use clap::Args;

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use magcal_core::{CalibrationStatus, Summary};

use super::{Common, Failure};
use crate::digest::sha256_hex;
use crate::output::manifest::{Manifest, Seal};
use crate::output::stderr::to_stderr;
use crate::output::{
    self, AdviceRow, DesignMetricsRow, DesignPointRow, PsoRunRow, Real, SummaryRow, TrialRow, read_csv,
};
use crate::pipeline::RunOutput;
use crate::{limits, scenario};

/// `magcal check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    #[command(flatten)]
    pub common: Common,
    /// The committed results to compare with (default: results/SCENARIO_NAME/).
    #[arg(long)]
    pub baseline: Option<PathBuf>,
}

/// Runs the command.
///
/// # Errors
/// A bad scenario, a missing or malformed baseline; a regression is [`Failure::Regression`].
pub fn run(args: &CheckArgs) -> Result<(), Failure> {
    let common = &args.common;
    let loaded = scenario::load(&common.scenario)?;
    let dir = args
        .baseline
        .clone()
        .unwrap_or_else(|| PathBuf::from("results").join(&loaded.name));
    if !dir.is_dir() {
        return Err(anyhow::anyhow!("{}: baseline directory not found", dir.display()).into());
    }
    let (manifest, seal) = Manifest::read(&dir)?;
    if seal == Seal::Absent {
        to_stderr!(
            "magcal: note: {} records no manifest_sha256 (made by an older magcal): edits of the manifest itself cannot be detected",
            dir.join("manifest.json").display()
        );
    }
    if manifest.name != loaded.name {
        return Err(anyhow::anyhow!(
            "{}: the baseline of scenario {:?}, not of {:?} ({}); give its own with --baseline",
            dir.display(),
            manifest.name.chars().take(64).collect::<String>(),
            loaded.name,
            common.scenario.display()
        )
        .into());
    }
    for name in manifest.files.iter().chain(manifest.file_sha256.keys()) {
        limits::set_member(&dir, name)?;
    }
    if manifest.scenario_sha256 != loaded.hash {
        to_stderr!(
            "magcal: note: {} has changed since {} was made (SHA-256 differs)",
            common.scenario.display(),
            dir.display()
        );
    }
    let with_trials = manifest.lists("summary.csv");
    let setup = super::setup_with(
        common,
        loaded,
        Some(common.seed.unwrap_or(manifest.seed)),
        Some(manifest.trials),
        with_trials,
    )?;
    // The designs, their verdicts and, when none works, the advice, as `run` and `design` make them.
    let (out, advice) = super::run::planned(&setup, !with_trials)?;
    let now_advice = match &advice {
        Some(a) => output::advice_rows(&out, a, &setup.scenario.bounds).collect(),
        None => Vec::new(),
    };
    let moved = compare(&out, &now_advice, &dir, &manifest)?;
    if !moved.is_empty() {
        return Err(Failure::Regression(report(&moved)));
    }
    if !common.quiet {
        crate::output::file::to_stdout(|w| {
            Ok(writeln!(
                w,
                "magcal check: {} matches {} within tolerance (seed {}, {} trials)",
                common.scenario.display(),
                dir.display(),
                setup.scenario.seed,
                setup.scenario.trials
            )?)
        })?;
    }
    Ok(())
}

/// One quantity that moved beyond its tolerance.
#[derive(Debug, Clone, PartialEq)]
pub struct Moved {
    /// Which file and row.
    pub key: String,
    /// Which column.
    pub quantity: String,
    /// Baseline value (`None`: absent or empty).
    pub baseline: Option<f64>,
    /// Value now.
    pub now: Option<f64>,
    /// Allowed absolute difference.
    pub tolerance: f64,
}

#[derive(Default)]
struct Findings(Vec<Moved>);

impl Findings {
    /// Records a move unless the values are identical (non-finite ones too), both absent, or
    /// finite and within `tolerance`.
    fn value(&mut self, key: &str, quantity: &str, baseline: Option<f64>, now: Option<f64>, tolerance: f64) {
        let same = match (baseline, now) {
            (None, None) => true,
            (Some(b), Some(n)) => {
                b.to_bits() == n.to_bits() || (b.is_finite() && n.is_finite() && (b - n).abs() <= tolerance)
            }
            _ => false,
        };
        if !same {
            self.0.push(Moved {
                key: key.to_string(),
                quantity: quantity.to_string(),
                baseline,
                now,
                tolerance,
            });
        }
    }

    fn missing(&mut self, key: &str, what: &str) {
        self.0.push(Moved {
            key: key.to_string(),
            quantity: what.to_string(),
            baseline: None,
            now: None,
            tolerance: 0.0,
        });
    }
}

fn real(x: Option<Real>) -> Option<f64> {
    x.map(|r| r.0)
}

/// A standard error from the baseline: `Ok(None)` when undefined (empty), an error when present
/// and not a finite non-negative number.
fn standard_error(x: Option<Real>, file: &str, key: &str) -> Result<Option<f64>> {
    match x {
        None => Ok(None),
        Some(Real(v)) if v.is_finite() && v >= 0.0 => Ok(Some(v)),
        Some(Real(v)) => bail!("{file}: {key}: se_mean = {v} is not a standard error; the baseline is damaged"),
    }
}

/// Key of a cell: design and noise level.
fn cell_key(design: &str, sigma: f64, attitude_sigma: f64) -> String {
    if attitude_sigma == 0.0 {
        format!("{design} / {sigma}")
    } else {
        format!("{design} / {sigma} / attitude {attitude_sigma} deg")
    }
}

/// Compares `out` and the rows of its advice (empty when a design works) with the baseline
/// directory; returns what moved (empty: no regression).
///
/// # Errors
/// A missing or malformed baseline file, or a baseline whose tolerance is not finite.
pub fn compare(out: &RunOutput, advice: &[AdviceRow], baseline: &Path, manifest: &Manifest) -> Result<Vec<Moved>> {
    let mut f = Findings::default();
    file_hashes(&mut f, baseline, manifest)?;
    if manifest.lists("summary.csv") {
        let shown = baseline.join("summary.csv").display().to_string();
        let base: Vec<SummaryRow> = read_csv(&limits::set_member(baseline, "summary.csv")?)?;
        let now: Vec<SummaryRow> = output::summary_rows(out).collect();
        compare_summaries(&mut f, &base, &now, &shown)?;
        if manifest.lists("trials.csv") {
            let trials: Vec<TrialRow> = read_csv(&limits::set_member(baseline, "trials.csv")?)?;
            // Files edited since they were written are named as such above, and what they
            // change is reported with them; a baseline whose hashes hold (its manifest resealed)
            // but whose statistics are not its trials' is damaged.
            let edited = f.0.iter().any(|m| m.key == "summary.csv" || m.key == "trials.csv");
            let mut damage = Findings::default();
            baseline_consistency(&mut damage, &base, &trials);
            if edited {
                f.0.append(&mut damage.0);
            }
            if let Some(first) = damage.0.first() {
                bail!(
                    "{shown}: damaged: its statistics are not those of its trials.csv ({} of them, the first {}: {} {}, {} from the trials); remove the set and make it again",
                    damage.0.len(),
                    first.key.trim_start_matches("baseline trials.csv vs summary.csv "),
                    first.quantity,
                    first.baseline.map_or("missing".to_string(), crate::limits::show),
                    first.now.map_or("none".to_string(), crate::limits::show)
                );
            }
            compare_statuses(&mut f, &trials, out);
        }
    }
    compare_designs(&mut f, out, baseline, manifest)?;
    compare_advice(&mut f, advice, baseline, manifest)?;
    compare_pso_runs(&mut f, out, baseline, manifest)?;
    Ok(f.0)
}

/// Tolerance of a count of `ok` trials out of `trials` with a fixed seed: 4 binomial standard
/// deviations, `sqrt(n p (1 - p))` taken as `sqrt(min(ok, trials - ok))`, at least 4 (a verdict
/// of 200 of 200 may move to 196, not to 28).
fn count_tolerance(ok: usize, trials: usize) -> f64 {
    4.0 * (ok.min(trials.saturating_sub(ok)).max(1) as f64).sqrt()
}

/// `advice.csv`: what works instead when no design does, one row per option, each with the
/// trials of its own verdict.
fn compare_advice(f: &mut Findings, now: &[AdviceRow], baseline: &Path, manifest: &Manifest) -> Result<()> {
    let base: Vec<AdviceRow> = if manifest.lists("advice.csv") {
        read_csv(&limits::set_member(baseline, "advice.csv")?)?
    } else {
        Vec::new()
    };
    compare_advice_rows(f, &base, now);
    Ok(())
}

/// [`compare_advice`] of rows read.
fn compare_advice_rows(f: &mut Findings, base: &[AdviceRow], now: &[AdviceRow]) {
    let by = |rows: &[AdviceRow]| -> BTreeMap<String, AdviceRow> {
        rows.iter()
            .map(|r| (format!("advice.csv {} {} {}", r.option, r.model, r.design), r.clone()))
            .collect()
    };
    let (base_by, now_by) = (by(base), by(now));
    keys_match(f, &base_by, &now_by);
    for (k, b) in &base_by {
        let Some(n) = now_by.get(k) else { continue };
        f.value(
            k,
            "check_trials",
            Some(b.check_trials as f64),
            Some(n.check_trials as f64),
            0.0,
        );
        f.value(
            k,
            "check_ok",
            Some(b.check_ok as f64),
            Some(n.check_ok as f64),
            count_tolerance(b.check_ok, b.check_trials),
        );
        f.value(k, "readings", Some(b.readings as f64), Some(n.readings as f64), 0.0);
    }
}

/// Every file as it was written: the SHA-256 its manifest recorded. Only plain names of regular
/// files inside the baseline are read.
fn file_hashes(f: &mut Findings, baseline: &Path, manifest: &Manifest) -> Result<()> {
    if manifest.file_sha256.is_empty() {
        to_stderr!(
            "magcal: note: {} records no file hashes (made by an older magcal): edits of its files cannot be detected",
            baseline.join("manifest.json").display()
        );
    }
    for (name, want) in &manifest.file_sha256 {
        let bytes = limits::read_bounded(&limits::set_member(baseline, name)?, limits::max_result_file_bytes())?;
        if &sha256_hex(&bytes) != want {
            f.missing(name, "edited since it was written (SHA-256 differs from manifest.json)");
        }
    }

    Ok(())
}

/// `summary.csv`: the statistics of each cell within 4 combined standard errors, the outcome
/// counts within 4 binomial standard deviations. `shown` names the baseline's file in errors.
///
/// # Errors
/// A baseline standard error that is not a finite non-negative number.
fn compare_summaries(f: &mut Findings, base: &[SummaryRow], now: &[SummaryRow], shown: &str) -> Result<()> {
    let key = |r: &SummaryRow| {
        format!(
            "summary.csv {} / {}",
            cell_key(&r.design, r.sigma_nt.0, r.attitude_sigma_deg.0),
            r.metric.as_str()
        )
    };
    let now_by: BTreeMap<String, &SummaryRow> = now.iter().map(|r| (key(r), r)).collect();
    let base_by: BTreeMap<String, &SummaryRow> = base.iter().map(|r| (key(r), r)).collect();
    keys_match(f, &base_by, &now_by);
    for (k, b) in &base_by {
        let Some(n) = now_by.get(k) else { continue };
        let se_b = standard_error(b.se_mean, shown, k)?;
        let se_n = standard_error(n.se_mean, "this run", k)?;
        // An undefined standard error (fewer than two values): no statistical tolerance.
        let se = se_b.zip(se_n).map(|(a, c)| (a * a + c * c).sqrt());
        let exact = |v: Option<Real>| 1e-9 * real(v).map_or(0.0, f64::abs);
        f.value(k, "trials", Some(b.trials as f64), Some(n.trials as f64), 0.0);
        // Binomial counts: 4 standard deviations.
        for (quantity, bc, nc) in [
            ("ok", b.ok, n.ok),
            ("not_converged", b.not_converged, n.not_converged),
            ("not_identifiable", b.not_identifiable, n.not_identifiable),
            ("failed", b.failed, n.failed),
        ] {
            f.value(
                k,
                quantity,
                Some(bc as f64),
                Some(nc as f64),
                4.0 * (bc.max(1) as f64).sqrt(),
            );
        }
        f.value(
            k,
            "mean",
            real(b.mean),
            real(n.mean),
            se.map_or(exact(b.mean), |se| 4.0 * se),
        );
        // The median's standard error is about sqrt(pi/2) times the mean's for a smooth density.
        let median_tol = se.map_or(exact(b.median), |se| 4.0 * 1.2533 * se);
        f.value(k, "median", real(b.median), real(n.median), median_tol);
        // Std of a sample std: about std / sqrt(2 (n - 1)).
        let succeeded = b.ok as f64;
        let std_tol = match (real(b.std), se) {
            (Some(s), Some(_)) if s.is_finite() => 4.0 * s / (2.0 * (succeeded - 1.0).max(1.0)).sqrt(),
            _ => exact(b.std),
        };
        f.value(k, "std", real(b.std), real(n.std), std_tol);
    }
    Ok(())
}

/// `designs.csv` and `design_metrics.csv`: sizes and `ln det M_F` of every design, condition numbers
/// and attitudes of those that are not optimised.
fn compare_designs(f: &mut Findings, out: &RunOutput, baseline: &Path, manifest: &Manifest) -> Result<()> {
    let file = |name: &str| limits::set_member(baseline, name);
    let base_metrics: Vec<DesignMetricsRow> = read_csv(&file("design_metrics.csv")?)?;
    let now_metrics: Vec<DesignMetricsRow> = output::design_metrics_rows(out).collect();
    let base_points = group_points(read_csv::<DesignPointRow>(&file("designs.csv")?)?);
    // Only the attitudes are compared: the headings follow from them.
    let headings = output::Headings {
        yaw_offset_deg: manifest.yaw_offset_deg,
        declination_deg: None,
    };
    let now_points = group_points(output::design_rows(out, headings).collect());
    let by = |rows: &[DesignMetricsRow]| -> BTreeMap<String, DesignMetricsRow> {
        rows.iter()
            .map(|r| (format!("design_metrics.csv {}", r.design), r.clone()))
            .collect()
    };
    let (base_by, now_by) = (by(&base_metrics), by(&now_metrics));
    keys_match(f, &base_by, &now_by);
    for (k, b) in &base_by {
        let Some(n) = now_by.get(k) else { continue };
        f.value(k, "m", Some(b.m as f64), Some(n.m as f64), 0.0);
        // The verdict's own trials.
        f.value(
            k,
            "check_ok",
            Some(b.check_ok as f64),
            Some(n.check_ok as f64),
            count_tolerance(b.check_ok, b.check_trials),
        );
        f.value(
            k,
            "ln_det_mf",
            Some(b.ln_det_mf.0),
            Some(n.ln_det_mf.0),
            1e-6 * b.ln_det_mf.0.abs(),
        );
        // The certified bound: deterministic for a seed, up to the rounding of the search.
        f.value(
            k,
            "d_efficiency_bound",
            real(b.d_efficiency_bound),
            real(n.d_efficiency_bound),
            1e-6,
        );
        // Condition numbers only for designs that are not optimised (many designs share the optimal
        // ln det with different conditioning), at 1e-3 relative: cond_2 of an ill-conditioned H
        // (1e9 for the printed Table II design) moved 2e-6 relative when the field moved 1e-8.
        if !b.kind.is_optimised() {
            let relative = |x: Option<Real>, r: f64| real(x).map_or(0.0, |v| r * v.abs());
            f.value(k, "cond_h", real(b.cond_h), real(n.cond_h), relative(b.cond_h, 1e-3));
            f.value(
                k,
                "cond_mf",
                real(b.cond_mf),
                real(n.cond_mf),
                relative(b.cond_mf, 2e-3),
            );
        }
        let design = &b.design;
        let key = format!("designs.csv {design}");
        let Some(points) = base_points.get(design) else {
            f.missing(&key, "design missing in the baseline's designs.csv");
            continue;
        };
        let readings: usize = points.iter().map(|p| p.1).sum();
        f.value(&key, "readings", Some(readings as f64), Some(b.m as f64), 0.0);
        // Attitudes of designs that are not optimised; an optimiser's attitudes are covered by
        // ln det above and by the file's hash.
        if !b.kind.is_optimised()
            && let Some(now) = now_points.get(design)
            && now.len() == points.len()
        {
            const ANGLES: [&str; 3] = ["roll_deg", "yaw_deg", "pitch_deg"];
            for (i, ((p, _), (q, _))) in points.iter().zip(now).enumerate() {
                for (j, angle) in ANGLES.iter().enumerate() {
                    f.value(&format!("{key} point {}", i + 1), angle, Some(p[j]), Some(q[j]), 1.5e-9);
                }
            }
        }
    }

    Ok(())
}

/// `pso_runs.csv`: the runs are chaotic, so their mean final `ln det M_F` is compared.
fn compare_pso_runs(f: &mut Findings, out: &RunOutput, baseline: &Path, manifest: &Manifest) -> Result<()> {
    match (manifest.lists("pso_runs.csv"), out.pso_runs.is_some()) {
        (true, true) => {
            let base: Vec<f64> = read_csv::<PsoRunRow>(&limits::set_member(baseline, "pso_runs.csv")?)?
                .iter()
                .map(|r| r.final_ln_det.0)
                .collect();
            let now: Vec<f64> = output::pso_run_rows(out).map(|r| r.final_ln_det.0).collect();
            f.value(
                "pso_runs.csv",
                "runs",
                Some(base.len() as f64),
                Some(now.len() as f64),
                0.0,
            );
            if base.iter().chain(&now).all(|v| v.is_finite()) {
                let (mb, seb) = mean_se(&base);
                let (mn, sen) = mean_se(&now);
                let tol = 4.0 * (seb * seb + sen * sen).sqrt() + 1e-9 * mb.abs();
                f.value("pso_runs.csv", "mean final_ln_det", Some(mb), Some(mn), tol);
            } else {
                // Non-finite finals: the same runs must end the same way.
                let sorted = |v: &[f64]| {
                    let mut v = v.to_vec();
                    v.sort_by(f64::total_cmp);
                    v
                };
                for (i, (b, n)) in sorted(&base).iter().zip(sorted(&now)).enumerate() {
                    f.value(
                        "pso_runs.csv",
                        &format!("final_ln_det, {}-th smallest", i + 1),
                        Some(*b),
                        Some(n),
                        0.0,
                    );
                }
            }
        }
        (false, true) => f.missing("pso_runs.csv", "not in the baseline"),
        (true, false) => f.missing("pso_runs.csv", "not made by this run"),
        (false, false) => {}
    }
    Ok(())
}

fn keys_match<V, W>(f: &mut Findings, base: &BTreeMap<String, V>, now: &BTreeMap<String, W>) {
    for k in base.keys().filter(|k| !now.contains_key(*k)) {
        f.missing(k, "row missing in this run");
    }
    for k in now.keys().filter(|k| !base.contains_key(*k)) {
        f.missing(k, "row not in the baseline");
    }
}

/// The mean of finite `v` and its standard error ([`Summary`]), 0 where undefined (a
/// single value: no statistical tolerance).
fn mean_se(v: &[f64]) -> (f64, f64) {
    let s = Summary::new(v, 0);
    (s.mean, if s.se_mean.is_finite() { s.se_mean } else { 0.0 })
}

/// Attitudes per design (degrees) in the order built (`point`), with their readings.
fn group_points(rows: Vec<DesignPointRow>) -> BTreeMap<String, Vec<([f64; 3], usize)>> {
    let mut by: BTreeMap<String, Vec<(usize, [f64; 3], usize)>> = BTreeMap::new();
    for r in rows {
        by.entry(r.design)
            .or_default()
            .push((r.point, [r.roll_deg.0, r.yaw_deg.0, r.pitch_deg.0], r.readings));
    }
    by.into_iter()
        .map(|(k, mut v)| {
            v.sort_by_key(|p| p.0);
            (k, v.into_iter().map(|p| (p.1, p.2)).collect())
        })
        .collect()
}

/// Status counts per cell, baseline `trials.csv` against this run, within 4 sqrt(count).
fn compare_statuses(f: &mut Findings, trials: &[TrialRow], out: &RunOutput) {
    let mut base: BTreeMap<(String, CalibrationStatus), usize> = BTreeMap::new();
    for t in trials {
        *base
            .entry((cell_key(&t.design, t.sigma_nt.0, t.attitude_sigma_deg.0), t.status.0))
            .or_default() += 1;
    }
    let mut now: BTreeMap<(String, CalibrationStatus), usize> = BTreeMap::new();
    for c in &out.cells {
        for t in &c.trials {
            *now.entry((
                cell_key(&out.designs[c.design].name, c.sigma_nt, c.attitude_sigma_deg),
                t.status,
            ))
            .or_default() += 1;
        }
    }
    let keys: std::collections::BTreeSet<_> = base.keys().chain(now.keys()).cloned().collect();
    for key in keys {
        let b = base.get(&key).copied().unwrap_or(0);
        let n = now.get(&key).copied().unwrap_or(0);
        f.value(
            &format!("trials.csv {}", key.0),
            &format!("status {}", key.1.as_str()),
            Some(b as f64),
            Some(n as f64),
            4.0 * (b.max(1) as f64).sqrt(),
        );
    }
}

/// The baseline's `summary.csv` must be the statistics of its `trials.csv`.
fn baseline_consistency(f: &mut Findings, summary: &[SummaryRow], trials: &[TrialRow]) {
    let mut cells: BTreeMap<String, Vec<&TrialRow>> = BTreeMap::new();
    for t in trials {
        cells
            .entry(cell_key(&t.design, t.sigma_nt.0, t.attitude_sigma_deg.0))
            .or_default()
            .push(t);
    }
    for row in summary {
        let cell = cell_key(&row.design, row.sigma_nt.0, row.attitude_sigma_deg.0);
        let key = format!("baseline trials.csv vs summary.csv {cell} / {}", row.metric.as_str());
        let Some(rows) = cells.get(&cell) else {
            f.missing(&key, "no trials in the baseline's trials.csv");
            continue;
        };
        let ok: Vec<&&TrialRow> = rows.iter().filter(|t| t.status.0 == CalibrationStatus::Ok).collect();
        let count = |status: CalibrationStatus| rows.iter().filter(|t| t.status.0 == status).count();
        let not_converged = count(CalibrationStatus::NotConverged);
        let not_identifiable = count(CalibrationStatus::NotIdentifiable);
        let failed = rows.iter().filter(|t| !t.status.0.has_estimate()).count();
        f.value(&key, "trials", Some(row.trials as f64), Some(rows.len() as f64), 0.0);
        for (quantity, b, n) in [
            ("ok", row.ok, ok.len()),
            ("not_converged", row.not_converged, not_converged),
            ("not_identifiable", row.not_identifiable, not_identifiable),
            ("failed", row.failed, failed),
        ] {
            f.value(&key, quantity, Some(b as f64), Some(n as f64), 0.0);
        }
        let values: Vec<f64> = ok
            .iter()
            .filter_map(|t| t.value(row.metric))
            .filter(|v| v.is_finite())
            .collect();
        let s = Summary::new(&values, rows.len() - ok.len());
        let defined = |x: f64| (!x.is_nan()).then_some(x);
        let rms =
            (!values.is_empty()).then(|| (values.iter().map(|x| x * x).sum::<f64>() / values.len() as f64).sqrt());
        // The standard error too: it sets the tolerance of every comparison above, so a baseline
        // whose standard errors were widened would pass any run.
        for (quantity, b, n) in [
            ("mean", real(row.mean), defined(s.mean)),
            ("std", real(row.std), defined(s.std)),
            ("median", real(row.median), defined(s.median)),
            ("p05", real(row.p05), defined(s.p05)),
            ("p95", real(row.p95), defined(s.p95)),
            ("se_mean", real(row.se_mean), defined(s.se_mean)),
            ("rms", real(row.rms), rms),
        ] {
            f.value(&key, quantity, b, n, 1e-9 * b.map_or(0.0, f64::abs));
        }
    }
}

/// A readable table of what moved.
pub fn report(moved: &[Moved]) -> String {
    // Six decimals, or six significant digits where that would be long (1e308 has 309 digits).
    let show = |v: Option<f64>| {
        v.map_or("-".to_string(), |v| {
            if v.is_finite() && v != 0.0 && !(1e-3..1e9).contains(&v.abs()) {
                format!("{v:.6e}")
            } else {
                format!("{v:.6}")
            }
        })
    };
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<60} {:<36} {:>16} {:>16} {:>12}",
        "row", "quantity", "baseline", "now", "tolerance"
    );
    for m in moved {
        let _ = writeln!(
            s,
            "{:<60} {:<36} {:>16} {:>16} {:>12.3e}",
            m.key,
            m.quantity,
            show(m.baseline),
            show(m.now),
            m.tolerance
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::parse_csv;

    const HEADER: &str = "design,sigma_nt,attitude_sigma_deg,trials,ok,not_converged,not_identifiable,failed,metric,\
                          mean,std,median,p05,p95,se_mean,rms,crb_rms\n";

    /// One summary row of design `a` at 30 nT: `ok` of 1000 trials, `mean` with standard error
    /// `se`.
    fn rows(ok: usize, mean: f64, se: &str) -> Vec<SummaryRow> {
        let failed = 1000 - ok;
        let text = format!("{HEADER}a,30,0,1000,{ok},0,0,{failed},eta_psi,{mean},3.0,{mean},1,9,{se},5,5\n");
        parse_csv(text.as_bytes(), "summary.csv").unwrap()
    }

    /// A verdict's trials move by their binomial noise, not from failing to working: the ground
    /// vehicle's advice with the up axis's scale held went from 28 to 200 of 200.
    #[test]
    fn an_advice_whose_verdict_moved_is_a_regression() {
        let row = |ok: usize| AdviceRow {
            option: "reduced".into(),
            model: "axis2_held".into(),
            design: "optimum12".into(),
            readings: 12,
            check_trials: 200,
            check_ok: ok,
            ..AdviceRow::default()
        };
        let moved = |base: usize, now: usize| {
            let mut f = Findings::default();
            compare_advice_rows(&mut f, &[row(base)], &[row(now)]);
            f.0.into_iter().map(|m| m.quantity).collect::<Vec<_>>()
        };
        assert_eq!(moved(28, 200), ["check_ok"]);
        assert!(moved(200, 196).is_empty(), "4 of a verdict at 200 of 200 is noise");
        assert_eq!(moved(200, 195), ["check_ok"]);
        // sqrt(min(100, 100)) = 10: 40 either way.
        assert!(moved(100, 140).is_empty());
        assert_eq!(moved(100, 141), ["check_ok"]);
        // An option that appears or goes is named.
        let mut f = Findings::default();
        compare_advice_rows(&mut f, &[row(28)], &[]);
        assert_eq!(f.0[0].quantity, "row missing in this run");
    }

    fn moved(base: &[SummaryRow], now: &[SummaryRow]) -> Vec<(String, String)> {
        let mut f = Findings::default();
        compare_summaries(&mut f, base, now, "baseline/summary.csv").unwrap();
        f.0.into_iter().map(|m| (m.key, m.quantity)).collect()
    }

    #[test]
    fn identical_summaries_have_moved_nothing() {
        assert_eq!(moved(&rows(990, 4.0, "0.1"), &rows(990, 4.0, "0.1")), vec![]);
    }

    #[test]
    fn a_mean_moves_beyond_four_combined_standard_errors_only() {
        // Combined standard error sqrt(2) * 0.1 = 0.1414: the tolerance is 0.566.
        assert_eq!(moved(&rows(990, 4.0, "0.1"), &rows(990, 4.5, "0.1")), vec![]);
        let m = moved(&rows(990, 4.0, "0.1"), &rows(990, 4.6, "0.1"));
        let key = "summary.csv a / 30 / eta_psi".to_string();
        // The median moved as much, and its tolerance is 1.2533 times wider: 0.709.
        assert_eq!(m, vec![(key, "mean".to_string())]);
    }

    #[test]
    fn outcome_counts_move_beyond_four_binomial_deviations_only() {
        // 4 sqrt(10) = 12.6 failed trials.
        assert_eq!(moved(&rows(990, 4.0, "0.1"), &rows(978, 4.0, "0.1")), vec![]);
        let m = moved(&rows(990, 4.0, "0.1"), &rows(977, 4.0, "0.1"));
        let quantities: Vec<&str> = m.iter().map(|(_, q)| q.as_str()).collect();
        // `ok` has the wider tolerance, 4 sqrt(990) = 125.9.
        assert_eq!(quantities, ["failed"]);
    }

    #[test]
    fn a_row_on_one_side_only_is_named() {
        let mut other = rows(990, 4.0, "0.1");
        other[0].design = "b".to_string();
        let m = moved(&rows(990, 4.0, "0.1"), &other);
        assert_eq!(
            m,
            vec![
                (
                    "summary.csv a / 30 / eta_psi".to_string(),
                    "row missing in this run".to_string()
                ),
                (
                    "summary.csv b / 30 / eta_psi".to_string(),
                    "row not in the baseline".to_string()
                ),
            ]
        );
    }

    #[test]
    fn a_baseline_standard_error_that_is_not_one_is_damage() {
        let mut f = Findings::default();
        let e = compare_summaries(
            &mut f,
            &rows(990, 4.0, "-0.1"),
            &rows(990, 4.0, "0.1"),
            "base/summary.csv",
        )
        .unwrap_err()
        .to_string();
        assert_eq!(
            e,
            "base/summary.csv: summary.csv a / 30 / eta_psi: se_mean = -0.1 is not a standard error; the baseline is \
             damaged"
        );
    }
}
