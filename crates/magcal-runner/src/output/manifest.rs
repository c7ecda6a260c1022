//! The manifests the command line writes (their types and checks are `magcal-report`'s, which
//! reads them): each made here from what only the writer knows, the scenario, the run and the
//! build of the binary (`build.rs`).

use std::collections::BTreeMap;

pub use magcal_report::manifest::*;

use crate::pipeline::RunOutput;
use crate::scenario::Scenario;

/// The manifest of a run of `scenario` that wrote the files of `file_sha256`.
pub fn run(scenario: &Scenario, file_sha256: BTreeMap<String, String>) -> Manifest {
    let version = env!("CARGO_PKG_VERSION").to_string();
    Manifest {
        scenario: scenario.path.display().to_string(),
        name: scenario.name.clone(),
        description: scenario.description.clone(),
        scenario_sha256: scenario.hash.clone(),
        seed: scenario.seed,
        trials: scenario.trials,
        sigma_nt: scenario.sigmas_nt.clone(),
        field_ned_nt: scenario.field.ned_nt(),
        yaw_offset_deg: scenario.field.yaw_offset_deg(),
        attitude_box_deg: Some(
            scenario
                .bounds
                .ranges()
                .map(|r| [r.min().to_degrees(), r.max().to_degrees()]),
        ),
        // Both crates share the workspace version.
        crates: vec![
            ("magcal-core".into(), version.clone()),
            ("magcal-runner".into(), version),
        ],
        files: file_sha256.keys().cloned().collect(),
        file_sha256,
        manifest_sha256: None,
    }
}

/// The record of this process's run on `threads` threads, which wrote the manifest whose own
/// hash is `manifest_sha256`, with the stage times of `out`.
pub fn record(manifest_sha256: String, threads: usize, out: &RunOutput) -> RunRecord {
    RunRecord {
        manifest_sha256,
        command: std::env::args().collect(),
        threads,
        git_revision: env!("MAGCAL_GIT_REVISION").into(),
        rustc: env!("MAGCAL_RUSTC_VERSION").into(),
        target: env!("MAGCAL_TARGET").into(),
        stages: out.stages.clone(),
    }
}

/// The manifest of a calibration of the log at `log` (its bytes hashed as read) into the
/// files of `file_sha256`.
pub fn calibration(
    log: &std::path::Path,
    log_sha256: String,
    log_bytes: u64,
    log_rows: usize,
    file_sha256: BTreeMap<String, String>,
) -> CalibrationManifest {
    CalibrationManifest {
        kind: SetKind::Calibration,
        command: std::env::args().collect(),
        log: log.display().to_string(),
        log_sha256,
        log_bytes,
        log_rows,
        version: env!("CARGO_PKG_VERSION").into(),
        git_revision: env!("MAGCAL_GIT_REVISION").into(),
        rustc: env!("MAGCAL_RUSTC_VERSION").into(),
        target: env!("MAGCAL_TARGET").into(),
        files: file_sha256.keys().cloned().collect(),
        file_sha256,
        manifest_sha256: None,
    }
}
