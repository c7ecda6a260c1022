//! Exporters: each formats to an `impl Write`, so that it is tested without touching disk; and
//! [`write_atomic`], which puts bytes in place by writing a temporary file and renaming it.
//!
//! Numbers are written with Rust's shortest round-trip formatting: exact, and the same bytes for the
//! same value on every platform and thread count.

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};
use serde::Serialize;

use crate::pipeline::RunOutput;
use crate::scenario::Scenario;

/// The header of `summary.csv`.
pub const SUMMARY_HEADER: [&str; 11] = [
    "design", "sigma_nt", "trials", "failed", "metric", "mean", "std", "median", "p05", "p95", "se_mean",
];

/// The header of `design_metrics.csv`.
pub const DESIGN_METRICS_HEADER: [&str; 13] = [
    "design",
    "m",
    "ln_det_mf",
    "d_efficiency",
    "cond_h",
    "cond_mf",
    "det_inv_ratio_vs_uniform",
    "cond_h_ratio_vs_uniform",
    "cond_mf_ratio_vs_uniform",
    "kind",
    "a_criterion",
    "e_criterion",
    "best_in_run",
];

fn num(x: f64) -> String {
    format!("{x}")
}

fn opt(x: Option<f64>) -> String {
    x.map(num).unwrap_or_default()
}

/// `summary.csv`: one row per design, noise level and metric; statistics over the trials that
/// succeeded, `failed` beside them. Values in percent.
pub fn summary_csv(out: &RunOutput, w: impl Write) -> Result<()> {
    let mut csv = csv::Writer::from_writer(w);
    csv.write_record(SUMMARY_HEADER)?;
    for cell in &out.cells {
        let design = &out.designs[cell.design].name;
        for (metric, s) in cell.summaries() {
            csv.write_record([
                design.clone(),
                num(cell.sigma_nt),
                cell.trials.len().to_string(),
                s.failed.to_string(),
                metric.to_string(),
                num(s.mean),
                num(s.std),
                num(s.median),
                num(s.p05),
                num(s.p95),
                num(s.se_mean),
            ])?;
        }
    }
    csv.flush()?;
    Ok(())
}

/// `trials.csv`: one row per trial, with its status, errors and estimates (empty when it failed).
pub fn trials_csv(out: &RunOutput, w: impl Write) -> Result<()> {
    let mut csv = csv::Writer::from_writer(w);
    csv.write_record([
        "design",
        "sigma_nt",
        "trial",
        "status",
        "eta_psi",
        "eta_s",
        "eta_o",
        "psi1_deg",
        "psi2_deg",
        "psi3_deg",
        "s1",
        "s2",
        "s3",
        "o1_nt",
        "o2_nt",
        "o3_nt",
        "step2_iterations",
        "rms_residual_nt",
    ])?;
    for cell in &out.cells {
        let design = &out.designs[cell.design].name;
        for (t, trial) in cell.trials.iter().enumerate() {
            let mut row = vec![
                design.clone(),
                num(cell.sigma_nt),
                t.to_string(),
                trial.status.as_str().to_string(),
                opt(trial.eta.map(|e| e.psi)),
                opt(trial.eta.map(|e| e.scale)),
                opt(trial.eta.map(|e| e.bias)),
            ];
            match &trial.estimate {
                Some(m) => row.extend(m.psi_deg().into_iter().chain(m.scale()).chain(m.bias_nt()).map(num)),
                None => row.extend(std::iter::repeat_n(String::new(), 9)),
            }
            row.push(trial.iterations.map(|i| i.to_string()).unwrap_or_default());
            row.push(opt(trial.rms_residual_nt));
            csv.write_record(row)?;
        }
    }
    csv.flush()?;
    Ok(())
}

/// Degrees rounded to 1e-9 (a nano-degree, 2e-11 rad): angles given in degrees come back as written
/// rather than as the last bits of a round trip through radians.
fn degrees(x: f64) -> String {
    num((x * 1e9).round() / 1e9)
}

/// `designs.csv`: the attitudes of every design, degrees (to 1e-9 degree).
pub fn designs_csv(out: &RunOutput, w: impl Write) -> Result<()> {
    let mut csv = csv::Writer::from_writer(w);
    csv.write_record(["design", "point", "roll_deg", "yaw_deg", "pitch_deg"])?;
    for d in &out.designs {
        for (i, a) in d.attitudes.iter().enumerate() {
            let [r, y, p] = a.to_degrees();
            csv.write_record([d.name.clone(), (i + 1).to_string(), degrees(r), degrees(y), degrees(p)])?;
        }
    }
    csv.flush()?;
    Ok(())
}

/// `design_metrics.csv`: information and conditioning of every design; D-efficiency against the
/// best design of the run; the \[P1\] Table III ratios against the design named `uniform` (empty when
/// there is none): `det(M_F)^-1 / det(M_F(uniform))^-1`, `cond_2(H)` and `cond_2(M_F)` ratios.
pub fn design_metrics_csv(out: &RunOutput, w: impl Write) -> Result<()> {
    let mut csv = csv::Writer::from_writer(w);
    csv.write_record(DESIGN_METRICS_HEADER)?;
    let best = out.best_ln_det();
    let reference = out.reference();
    for (i, d) in out.designs.iter().enumerate() {
        let ratios = reference.map(|u| {
            (
                (u.ln_det_mf - d.ln_det_mf).exp(),
                d.conditioning.cond_h / u.conditioning.cond_h,
                d.conditioning.cond_mf / u.conditioning.cond_mf,
            )
        });
        csv.write_record([
            d.name.clone(),
            d.attitudes.len().to_string(),
            num(d.ln_det_mf),
            num(out.d_efficiency(i)),
            num(d.conditioning.cond_h),
            num(d.conditioning.cond_mf),
            opt(ratios.map(|r| r.0)),
            opt(ratios.map(|r| r.1)),
            opt(ratios.map(|r| r.2)),
            d.kind.to_string(),
            num(d.a_criterion),
            num(d.e_criterion),
            (d.ln_det_mf.to_bits() == best.to_bits()).to_string(),
        ])?;
    }
    csv.flush()?;
    Ok(())
}

/// `pso_runs.csv`: the final `ln det M_F` of each repeated PSO run (\[P1\] Fig. 4).
pub fn pso_runs_csv(out: &RunOutput, w: impl Write) -> Result<()> {
    let mut csv = csv::Writer::from_writer(w);
    csv.write_record(["run", "final_ln_det", "evaluations"])?;
    for r in out.pso_runs.iter().flatten() {
        csv.write_record([r.run.to_string(), num(-r.fitness), r.evaluations.to_string()])?;
    }
    csv.flush()?;
    Ok(())
}

/// What `manifest.json` records: enough to rebuild the result.
#[derive(Debug, Serialize)]
pub struct Manifest {
    /// The scenario file, as given on the command line.
    pub scenario: String,
    /// Scenario name.
    pub name: String,
    /// Scenario description.
    pub description: String,
    /// SHA-256 of the scenario file.
    pub scenario_sha256: String,
    /// The seed used.
    pub seed: u64,
    /// Trials per design and noise level.
    pub trials: usize,
    /// Noise levels, nT.
    pub sigma_nt: Vec<f64>,
    /// The reference field used, WMM NED components and yaw offset.
    pub field_ned_nt: [f64; 3],
    /// Yaw offset, degrees.
    pub yaw_offset_deg: f64,
    /// The attitude box, roll, yaw, pitch `[min, max]` in degrees.
    pub attitude_box_deg: [[f64; 2]; 3],
    /// Rayon threads.
    pub threads: usize,
    /// The command line.
    pub command: Vec<String>,
    /// Git revision the binary was built from (`-dirty` with uncommitted changes).
    pub git_revision: &'static str,
    /// `rustc --version` of the build.
    pub rustc: &'static str,
    /// Target triple.
    pub target: &'static str,
    /// Crate versions.
    pub crates: [(&'static str, &'static str); 2],
    /// Wall time per stage, seconds.
    pub stages: Vec<(String, f64)>,
    /// Files written beside this one.
    pub files: Vec<String>,
}

impl Manifest {
    /// The manifest of a run.
    pub fn new(scenario: &Scenario, out: &RunOutput, threads: usize, files: Vec<String>) -> Self {
        Self {
            scenario: scenario.path.display().to_string(),
            name: scenario.name.clone(),
            description: scenario.description.clone(),
            scenario_sha256: scenario.hash.clone(),
            seed: scenario.seed,
            trials: scenario.trials,
            sigma_nt: scenario.sigmas_nt.clone(),
            field_ned_nt: scenario.field.ned_nt(),
            yaw_offset_deg: scenario.field.yaw_offset_deg(),
            attitude_box_deg: scenario
                .bounds
                .ranges()
                .map(|r| [r.min().to_degrees(), r.max().to_degrees()]),
            threads,
            command: std::env::args().collect(),
            git_revision: env!("MAGCAL_GIT_REVISION"),
            rustc: env!("MAGCAL_RUSTC_VERSION"),
            target: env!("MAGCAL_TARGET"),
            crates: [
                ("magcal-core", magcal_core_version()),
                ("magcal-runner", env!("CARGO_PKG_VERSION")),
            ],
            stages: out.stages.clone(),
            files,
        }
    }

    /// Pretty JSON.
    pub fn write(&self, w: impl Write) -> Result<()> {
        serde_json::to_writer_pretty(w, self)?;
        Ok(())
    }
}

/// Both crates share the workspace version.
fn magcal_core_version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}

/// Writes `bytes` to `path` through a temporary file in the same directory and a rename, so that
/// `path` holds either its old content or the whole new one, never a part.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .context("output path has no file name")?
        .to_string_lossy();
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    let result = (|| -> Result<()> {
        let mut f = std::fs::File::create(&tmp).with_context(|| format!("{}: cannot create", tmp.display()))?;
        f.write_all(bytes)
            .with_context(|| format!("{}: cannot write", tmp.display()))?;
        f.sync_all()
            .with_context(|| format!("{}: cannot sync", tmp.display()))?;
        std::fs::rename(&tmp, path).with_context(|| format!("{}: cannot rename into place", path.display()))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Formats with `f` into memory.
pub fn to_bytes(f: impl FnOnce(&mut Vec<u8>) -> Result<()>) -> Result<Vec<u8>> {
    let mut buf = Vec::new();
    f(&mut buf)?;
    Ok(buf)
}
