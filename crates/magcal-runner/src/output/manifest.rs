//! `manifest.json`: what is needed to rebuild a result set, written beside it and read back by
//! `check` (seed, trials) and `plot` (field, box, the files of the set).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::pipeline::RunOutput;
use crate::scenario::Scenario;

/// The kind of a result set, as its manifest records it (`"kind"`): a set of one kind never
/// replaces a directory that holds a set of another.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SetKind {
    /// `run` or `design`: designs, trials, statistics, figures. Its manifest ([`Manifest`]) has
    /// no `kind` field.
    Run,
    /// `calibrate --out`: a calibration of a log ([`CalibrationManifest`]).
    Calibration,
}

impl SetKind {
    /// The name in manifests and messages.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Run => "run",
            Self::Calibration => "calibration",
        }
    }

    /// The kind of the result set in `dir`: its `manifest.json`'s `kind`, or [`SetKind::Run`] for
    /// a manifest without one that names a scenario and its SHA-256; `None` when `dir` holds no
    /// magcal manifest.
    pub fn of(dir: &std::path::Path) -> Option<Self> {
        #[derive(Deserialize)]
        struct Probe {
            kind: Option<SetKind>,
            name: Option<String>,
            scenario_sha256: Option<String>,
        }
        let bytes = std::fs::read(dir.join("manifest.json")).ok()?;
        let probe: Probe = serde_json::from_slice(&bytes).ok()?;
        match probe.kind {
            Some(kind) => Some(kind),
            None if probe.name.is_some() && probe.scenario_sha256.is_some() => Some(Self::Run),
            None => None,
        }
    }
}

/// The `manifest.json` of a calibration set (`calibrate --out DIR`): what it was made from and
/// by, and the SHA-256 of every file beside it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationManifest {
    /// Always [`SetKind::Calibration`].
    pub kind: SetKind,
    /// The command line.
    pub command: Vec<String>,
    /// The log, as given on the command line.
    pub log: String,
    /// SHA-256 of the log's bytes as they were read.
    pub log_sha256: String,
    /// The log's size in bytes as it was read.
    pub log_bytes: u64,
    /// The log's data rows read: readings fitted, rejected (`--reject`) and skipped
    /// (`--skip-bad`); blank and comment lines are not counted.
    pub log_rows: usize,
    /// The magcal version.
    pub version: String,
    /// Git revision the binary was built from (`-dirty` with uncommitted changes).
    pub git_revision: String,
    /// `rustc --version` of the build.
    pub rustc: String,
    /// Target triple.
    pub target: String,
    /// The files of the set beside this one.
    pub files: Vec<String>,
    /// SHA-256 of each of those files as written.
    pub file_sha256: BTreeMap<String, String>,
}

impl CalibrationManifest {
    /// The manifest of a calibration of the log at `log` (its bytes hashed as read) into the
    /// files of `file_sha256`.
    pub fn new(
        log: &std::path::Path,
        log_sha256: String,
        log_bytes: u64,
        log_rows: usize,
        file_sha256: BTreeMap<String, String>,
    ) -> Self {
        Self {
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
        }
    }

    /// Pretty JSON with a final newline.
    ///
    /// # Errors
    /// Only a failure of serde_json.
    pub fn to_bytes(&self) -> anyhow::Result<Vec<u8>> {
        let mut bytes = serde_json::to_vec_pretty(self)?;
        bytes.push(b'\n');
        Ok(bytes)
    }
}

/// What `manifest.json` records.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    /// The reference field used: WMM north, east, down, nT.
    pub field_ned_nt: [f64; 3],
    /// Yaw offset, degrees.
    pub yaw_offset_deg: f64,
    /// The attitude box, roll, yaw, pitch `[min, max]` in degrees.
    #[serde(default)]
    pub attitude_box_deg: Option<[[f64; 2]; 3]>,
    /// Rayon threads.
    pub threads: usize,
    /// The command line.
    pub command: Vec<String>,
    /// Git revision the binary was built from (`-dirty` with uncommitted changes).
    pub git_revision: String,
    /// `rustc --version` of the build.
    pub rustc: String,
    /// Target triple.
    pub target: String,
    /// Crate versions.
    pub crates: Vec<(String, String)>,
    /// Wall time per stage, seconds.
    pub stages: Vec<(String, f64)>,
    /// The files of the result set beside this one (figures excepted).
    pub files: Vec<String>,
    /// SHA-256 of each of those files as written (absent in manifests of older runs).
    #[serde(default)]
    pub file_sha256: BTreeMap<String, String>,
}

/// SHA-256 of `bytes`, lower-case hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// A writer or reader that hashes and counts the bytes that pass through it.
pub struct Hashing<W> {
    inner: W,
    hash: Sha256,
    bytes: u64,
}

impl<W> Hashing<W> {
    /// Wraps `inner`.
    pub fn new(inner: W) -> Self {
        Self {
            inner,
            hash: Sha256::new(),
            bytes: 0,
        }
    }

    /// How many bytes passed.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// The SHA-256 of everything written, lower-case hex.
    pub fn hex(&self) -> String {
        self.hash
            .clone()
            .finalize()
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    }
}

impl<W: std::io::Write> std::io::Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash.update(&buf[..n]);
        self.bytes += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl<R: std::io::Read> std::io::Read for Hashing<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.hash.update(&buf[..n]);
        self.bytes += n as u64;
        Ok(n)
    }
}

impl Manifest {
    /// The manifest of a run.
    pub fn new(scenario: &Scenario, out: &RunOutput, threads: usize, file_sha256: BTreeMap<String, String>) -> Self {
        let version = env!("CARGO_PKG_VERSION").to_string();
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
            attitude_box_deg: Some(
                scenario
                    .bounds
                    .ranges()
                    .map(|r| [r.min().to_degrees(), r.max().to_degrees()]),
            ),
            threads,
            command: std::env::args().collect(),
            git_revision: env!("MAGCAL_GIT_REVISION").into(),
            rustc: env!("MAGCAL_RUSTC_VERSION").into(),
            target: env!("MAGCAL_TARGET").into(),
            // Both crates share the workspace version.
            crates: vec![
                ("magcal-core".into(), version.clone()),
                ("magcal-runner".into(), version),
            ],
            stages: out.stages.clone(),
            files: file_sha256.keys().cloned().collect(),
            file_sha256,
        }
    }

    /// Pretty JSON.
    ///
    /// # Errors
    /// Only a failure of serde_json.
    pub fn to_bytes(&self) -> anyhow::Result<Vec<u8>> {
        Ok(serde_json::to_vec_pretty(self)?)
    }

    /// Reads `dir/manifest.json`.
    ///
    /// # Errors
    /// A missing or malformed file, named.
    pub fn read(dir: &std::path::Path) -> anyhow::Result<Self> {
        use anyhow::Context;
        let path = dir.join("manifest.json");
        let bytes = crate::limits::read_bounded(&path, crate::limits::MAX_MANIFEST_BYTES)?;
        serde_json::from_slice(&bytes).with_context(|| format!("{}: not a magcal manifest", path.display()))
    }

    /// Whether the set lists `file`.
    pub fn lists(&self, file: &str) -> bool {
        self.files.iter().any(|f| f == file)
    }
}
