//! `manifest.json`: what is needed to rebuild a result set, written beside it and read back by
//! `check` (seed, trials) and `plot` (field, box, the files of the set); and `run.json`: how that
//! run went (command, threads, toolchain, git revision, wall time per stage).
//!
//! # What stays the same and what varies
//!
//! The manifest of a run holds only what a run of the same scenario with the same seed and trial
//! count reproduces byte for byte, on any number of threads: the scenario and its SHA-256, seed,
//! sizes, field, box, crate versions, the files of the set and their SHA-256. So a committed
//! result set stays as it is when it is made again. What differs from one run to the next (the
//! command line, the threads, the build's git revision and toolchain, the timings) goes to
//! [`RunRecord`], `run.json`, a file of the same set (written to the staging directory and swapped
//! in with the rest, so it is never left from an earlier run). `run.json` names the manifest it
//! was written with (`manifest_sha256`); the manifest does not list it, and `check` never reads
//! it. The repository ignores `results/*/run.json`.
//!
//! # The manifest's own hash
//!
//! A manifest records the SHA-256 of every other file of its set, and of itself in its last field,
//! `manifest_sha256`: the SHA-256 of the file's bytes with that field's value empty (`""`), that
//! is, of the file as written with the 64 hexadecimal digits taken out. Every reader ([`Manifest::read`],
//! [`SetKind::of`]) checks it first, so that an edited manifest (a changed seed, a changed file
//! hash) is reported as damage, never read as a result. A manifest without the field (written by
//! an older magcal) is read, and [`Seal::Absent`] says that it could not be checked.
//! `scripts/seal-manifests.py` adds the field to such a manifest without changing its other bytes.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result, bail};
use magcal_logs::digest::{sha256_hex, sha256_hex_of_parts};
use serde::{Deserialize, Serialize};

/// Largest manifest read, bytes.
pub const MAX_MANIFEST_BYTES: u64 = 16 << 20;

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
    /// `replay`: a scenario's designs replayed on a log ([`ReplayManifest`]).
    Replay,
}

impl SetKind {
    /// The name in manifests and messages.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Run => "run",
            Self::Calibration => "calibration",
            Self::Replay => "replay",
        }
    }

    /// The kind of the result set in `dir`: its `manifest.json`'s `kind`, or [`SetKind::Run`] for
    /// a manifest without one that names a scenario and its SHA-256; `None` when `dir` holds no
    /// magcal manifest (none, an unreadable one, or one that is not magcal's).
    ///
    /// # Errors
    /// A magcal manifest whose own hash does not match its bytes (see [`verify`]).
    pub fn of(dir: &Path) -> Result<Option<Self>> {
        #[derive(Deserialize)]
        struct Probe {
            kind: Option<SetKind>,
            name: Option<String>,
            scenario_sha256: Option<String>,
        }
        let path = dir.join("manifest.json");
        // A manifest that is there but not a regular file (a link out of the set, a FIFO that
        // would block the read) is named, not read.
        if std::fs::symlink_metadata(&path).is_ok() {
            magcal_logs::limits::set_member(dir, "manifest.json")?;
        }
        let Ok(bytes) = magcal_logs::limits::read_bounded(&path, MAX_MANIFEST_BYTES) else {
            return Ok(None);
        };
        let Ok(probe) = serde_json::from_slice::<Probe>(&bytes) else {
            return Ok(None);
        };
        let kind = match probe.kind {
            Some(kind) => kind,
            None if probe.name.is_some() && probe.scenario_sha256.is_some() => Self::Run,
            None => return Ok(None),
        };
        verify(&path, &bytes)?;
        Ok(Some(kind))
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
    /// SHA-256 of this manifest (see [the module documentation](self)); absent in manifests of
    /// older sets. Always the last field.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub manifest_sha256: Option<String>,
}

impl CalibrationManifest {
    /// Pretty JSON with a final newline, sealed with its own hash (`manifest_sha256`).
    ///
    /// # Errors
    /// Only a failure of serde_json.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        pretty_sealed(self.clone(), |m, seal| m.manifest_sha256 = seal)
    }
}

/// The `manifest.json` of a replay set (`replay SCENARIO LOG`): what it was made from, with which
/// settings, and the SHA-256 of every file beside it. The same scenario, log, settings and seed
/// give the same files on any number of threads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayManifest {
    /// Always [`SetKind::Replay`].
    pub kind: SetKind,
    /// The command line.
    pub command: Vec<String>,
    /// The scenario's name, path as given and SHA-256.
    pub scenario: String,
    pub scenario_path: String,
    pub scenario_sha256: String,
    /// The log, as given on the command line, its SHA-256 and size as read.
    pub log: String,
    pub log_sha256: String,
    pub log_bytes: u64,
    /// The seed and the trials per design.
    pub seed: u64,
    pub trials: usize,
    /// The settings that shape the result, by name (hold, angle, models, truth, noise, ...).
    pub settings: BTreeMap<String, String>,
    /// The magcal version and the build.
    pub version: String,
    pub git_revision: String,
    pub rustc: String,
    pub target: String,
    /// The files of the set beside this one, and the SHA-256 of each as written.
    pub files: Vec<String>,
    pub file_sha256: BTreeMap<String, String>,
    /// SHA-256 of this manifest (see [the module documentation](self)). Always the last field.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub manifest_sha256: Option<String>,
}

impl ReplayManifest {
    /// Pretty JSON with a final newline, sealed with its own hash (`manifest_sha256`).
    ///
    /// # Errors
    /// Only a failure of serde_json.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        pretty_sealed(self.clone(), |m, seal| m.manifest_sha256 = seal)
    }
}

/// What `manifest.json` of a run records: what a run of the same scenario, seed and trial count
/// reproduces (see [the module documentation](self)). Manifests of older runs, which also hold
/// the fields of [`RunRecord`], are read as well: fields this struct does not know are ignored.
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
    /// Crate versions.
    pub crates: Vec<(String, String)>,
    /// The files of the result set beside this one (figures and `run.json` excepted).
    pub files: Vec<String>,
    /// SHA-256 of each of those files as written (absent in manifests of older runs).
    #[serde(default)]
    pub file_sha256: BTreeMap<String, String>,
    /// SHA-256 of this manifest (see [the module documentation](self)); absent in manifests of
    /// older runs. Always the last field.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub manifest_sha256: Option<String>,
}

impl Manifest {
    /// Pretty JSON (no final newline, as the committed baselines), sealed with its own hash
    /// (`manifest_sha256`); the bytes and that hash.
    ///
    /// # Errors
    /// Only a failure of serde_json.
    pub fn to_bytes(&self) -> Result<(Vec<u8>, String)> {
        sealed(
            self.clone(),
            |m, seal| m.manifest_sha256 = seal,
            |m| Ok(serde_json::to_vec_pretty(m)?),
        )
    }

    /// Reads `dir/manifest.json` and checks its own hash; the manifest and whether the hash was
    /// there to check.
    ///
    /// # Errors
    /// A missing or malformed file, or one whose own hash does not match its bytes, named.
    pub fn read(dir: &Path) -> Result<(Self, Seal)> {
        let path = magcal_logs::limits::set_member(dir, "manifest.json")?;
        let bytes = magcal_logs::limits::read_bounded(&path, MAX_MANIFEST_BYTES)?;
        let manifest: Self =
            serde_json::from_slice(&bytes).with_context(|| format!("{}: not a magcal manifest", path.display()))?;
        let seal = verify(&path, &bytes)?;
        Ok((manifest, seal))
    }

    /// Whether the set lists `file`.
    pub fn lists(&self, file: &str) -> bool {
        self.files.iter().any(|f| f == file)
    }
}

/// What `run.json` records: how one run went, which a run of the same scenario and seed need
/// not repeat (see [the module documentation](self)). Nothing in magcal reads it back.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunRecord {
    /// The own hash of the `manifest.json` this run wrote beside it.
    pub manifest_sha256: String,
    /// The command line.
    pub command: Vec<String>,
    /// Rayon threads.
    pub threads: usize,
    /// Git revision the binary was built from (`-dirty` with uncommitted changes).
    pub git_revision: String,
    /// `rustc --version` of the build.
    pub rustc: String,
    /// Target triple.
    pub target: String,
    /// Wall time per stage, seconds (the last, `total`, from the start to the manifest).
    pub stages: Vec<(String, f64)>,
}

impl RunRecord {
    /// Pretty JSON with a final newline.
    ///
    /// # Errors
    /// Only a failure of serde_json.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let mut bytes = serde_json::to_vec_pretty(self)?;
        bytes.push(b'\n');
        Ok(bytes)
    }
}

/// Whether a manifest's own hash was there to check.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Seal {
    /// `manifest_sha256` is present and matches the file's bytes.
    Verified,
    /// No `manifest_sha256` (a manifest of an older magcal): edits of it cannot be detected.
    Absent,
}

/// The name of the manifest's own hash.
const SELF_HASH: &str = "manifest_sha256";

/// Pretty JSON of `manifest` with a final newline, sealed with its own hash through `set` (see
/// [`sealed`]).
fn pretty_sealed<M>(manifest: M, set: impl Fn(&mut M, Option<String>)) -> Result<Vec<u8>>
where
    M: Serialize,
{
    sealed(manifest, set, |m| {
        let mut bytes = serde_json::to_vec_pretty(m)?;
        bytes.push(b'\n');
        Ok(bytes)
    })
    .map(|(bytes, _)| bytes)
}

/// Serialises `manifest` (through `set` and `to_bytes`) with its own hash: once with an empty
/// hash, whose bytes are hashed, then with that hash. Serialisation is deterministic, so the two
/// differ only in the 64 digits, which [`verify`] takes out again. The bytes and the hash.
fn sealed<M>(
    mut manifest: M,
    set: impl Fn(&mut M, Option<String>),
    to_bytes: impl Fn(&M) -> Result<Vec<u8>>,
) -> Result<(Vec<u8>, String)> {
    set(&mut manifest, Some(String::new()));
    let hash = sha256_hex(&to_bytes(&manifest)?);
    set(&mut manifest, Some(hash.clone()));
    Ok((to_bytes(&manifest)?, hash))
}

/// Checks the own hash of the manifest `bytes` read from `path`: its last member must be
/// `"manifest_sha256": "<64 hex digits>"`, and the SHA-256 of the bytes without those digits must
/// be them. A manifest with no such member, whose last member is not a SHA-256 either (that of
/// an older magcal ends with `file_sha256`, an object), is [`Seal::Absent`].
///
/// # Errors
/// Bytes that are not JSON; a hash that is not the last member, not 64 lower-case hex digits, or
/// not the bytes' hash; a last member that is a SHA-256 under another name (an edited name):
/// "damaged: manifest.json was edited".
pub fn verify(path: &Path, bytes: &[u8]) -> Result<Seal> {
    #[derive(Deserialize)]
    struct Probe {
        manifest_sha256: Option<serde_json::Value>,
    }
    let damaged = |why: &str| -> Result<Seal> {
        bail!(
            "{}: damaged: manifest.json was edited ({why}); remove the set and make it again",
            path.display()
        )
    };
    let probe: Probe =
        serde_json::from_slice(bytes).with_context(|| format!("{}: not a magcal manifest", path.display()))?;
    let last = last_string_member(bytes);
    let digits = match (&probe.manifest_sha256, &last) {
        (None, Some((key, value))) if is_sha256_hex(value) => {
            let key: String = key.chars().take(40).collect();
            return damaged(&format!(
                "its last field {key:?} holds a SHA-256: manifest_sha256 renamed?"
            ));
        }
        (None, _) => return Ok(Seal::Absent),
        (Some(recorded), _) => match recorded.as_str() {
            Some(h) if is_sha256_hex(h) => h,
            _ => return damaged("its manifest_sha256 is not a SHA-256"),
        },
    };
    let Some(at) = last
        .filter(|(key, value)| key == SELF_HASH && value == digits)
        .and_then(|_| last_member_value(bytes))
    else {
        return damaged("manifest_sha256 is not its last field, where magcal writes it");
    };
    let actual = sha256_hex_of_parts(&[&bytes[..at.start], &bytes[at.end..]]);
    if actual != digits {
        return damaged("its SHA-256 differs from the manifest_sha256 it records");
    }
    Ok(Seal::Verified)
}

/// Whether `s` is a SHA-256 in lower-case hex.
fn is_sha256_hex(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// The key and value of the last member of the JSON object `bytes` when that is a string without
/// escapes under a key without escapes.
fn last_string_member(bytes: &[u8]) -> Option<(String, String)> {
    let (key, value) = last_member(bytes)?;
    let text = |r: std::ops::Range<usize>| String::from_utf8(bytes[r].to_vec()).ok();
    Some((text(key)?, text(value)?))
}

/// The byte range of the value of the last member (see [`last_member`]).
fn last_member_value(bytes: &[u8]) -> Option<std::ops::Range<usize>> {
    last_member(bytes).map(|(_, value)| value)
}

/// The byte ranges of the key and the value of `"key": "value"` when that is the last member of
/// the JSON object `bytes` (only white space between the value and the final `}`), neither with a
/// backslash or a quote inside.
fn last_member(bytes: &[u8]) -> Option<(std::ops::Range<usize>, std::ops::Range<usize>)> {
    let ws = |b: &u8| b" \t\r\n".contains(b);
    let skip_ws_back = |mut i: usize| {
        while i > 0 && ws(&bytes[i - 1]) {
            i -= 1;
        }
        i
    };
    // Index of the opening quote of the string that closes at `close`.
    let string_back = |close: usize| -> Option<usize> {
        let open = bytes[..close].iter().rposition(|&b| b == b'"')?;
        (!bytes[open + 1..close].contains(&b'\\')).then_some(open)
    };
    let brace = skip_ws_back(bytes.len()).checked_sub(1).filter(|&e| bytes[e] == b'}')?;
    let close = skip_ws_back(brace).checked_sub(1).filter(|&e| bytes[e] == b'"')?;
    let open = string_back(close)?;
    let colon = skip_ws_back(open).checked_sub(1).filter(|&c| bytes[c] == b':')?;
    let key_close = skip_ws_back(colon).checked_sub(1).filter(|&e| bytes[e] == b'"')?;
    let key_open = string_back(key_close)?;
    Some((key_open + 1..key_close, open + 1..close))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn manifest() -> CalibrationManifest {
        let file_sha256 = BTreeMap::from([("calibration.json".to_string(), "cd".repeat(32))]);
        CalibrationManifest {
            kind: SetKind::Calibration,
            command: vec!["magcal".into(), "calibrate".into(), "log.csv".into()],
            log: "log.csv".into(),
            log_sha256: "ab".repeat(32),
            log_bytes: 1234,
            log_rows: 56,
            version: "0.1.0".into(),
            git_revision: "unknown".into(),
            rustc: "rustc".into(),
            target: "x86_64-unknown-linux-gnu".into(),
            files: file_sha256.keys().cloned().collect(),
            file_sha256,
            manifest_sha256: None,
        }
    }

    #[test]
    fn a_written_manifest_verifies_and_reads_back_whole() {
        let bytes = manifest().to_bytes().unwrap();
        assert_eq!(verify(Path::new("m"), &bytes).unwrap(), Seal::Verified);
        let back: CalibrationManifest = serde_json::from_slice(&bytes).unwrap();
        let digits = back.manifest_sha256.clone().unwrap();
        assert!(is_sha256_hex(&digits), "{digits}");
        // The hash is that of the bytes with the digits taken out.
        let text = String::from_utf8(bytes.clone()).unwrap();
        assert!(
            text.ends_with(&format!("\"manifest_sha256\": \"{digits}\"\n}}\n")),
            "{text}"
        );
        assert_eq!(sha256_hex(text.replace(&digits, "").as_bytes()), digits);
        assert_eq!(
            back,
            CalibrationManifest {
                manifest_sha256: Some(digits),
                ..manifest()
            }
        );
    }

    #[test]
    fn every_edit_of_a_byte_but_white_space_is_damage() {
        let bytes = manifest().to_bytes().unwrap();
        let mut detected = 0;
        for i in 0..bytes.len() {
            if bytes[i].is_ascii_whitespace() {
                continue;
            }
            let mut edited = bytes.clone();
            // A byte of the same class, so that most edits still parse.
            edited[i] = match bytes[i] {
                b'0'..=b'8' | b'a'..=b'e' | b'A'..=b'Y' => bytes[i] + 1,
                other => other ^ 1,
            };
            match verify(Path::new("m"), &edited) {
                Ok(seal) => panic!("byte {i} edited, read as {seal:?}"),
                Err(e) => {
                    let e = format!("{e:#}");
                    if e.contains("damaged: manifest.json was edited") {
                        detected += 1;
                    } else {
                        assert!(e.contains("not a magcal manifest"), "{e}");
                    }
                }
            }
        }
        assert!(detected > bytes.len() / 2, "{detected} of {}", bytes.len());
    }

    #[test]
    fn white_space_edits_outside_values_are_damage_too_and_no_hash_is_absent() {
        let bytes = manifest().to_bytes().unwrap();
        let text = String::from_utf8(bytes).unwrap();
        let reindented = text.replacen("\n  \"kind\"", "\n   \"kind\"", 1);
        let e = verify(Path::new("d/manifest.json"), reindented.as_bytes()).unwrap_err();
        assert_eq!(
            format!("{e:#}"),
            "d/manifest.json: damaged: manifest.json was edited (its SHA-256 differs from the manifest_sha256 it records); remove the set and make it again"
        );
        let back: CalibrationManifest = serde_json::from_str(&text).unwrap();
        let digits = back.manifest_sha256.unwrap();
        let member = format!(",\n  \"manifest_sha256\": \"{digits}\"");
        assert!(text.contains(&member), "{text}");
        let moved =
            text.replacen(&member, "", 1)
                .replacen("{\n", &format!("{{\n  \"manifest_sha256\": \"{digits}\",\n"), 1);
        let e = verify(Path::new("m"), moved.as_bytes()).unwrap_err();
        assert!(format!("{e:#}").contains("not its last field"), "{e:#}");
        let renamed = text.replacen("\"manifest_sha256\"", "\"manifest_sha265\"", 1);
        let e = verify(Path::new("m"), renamed.as_bytes()).unwrap_err();
        assert!(format!("{e:#}").contains("manifest_sha256 renamed?"), "{e:#}");
        let unsealed = serde_json::to_vec_pretty(&manifest()).unwrap();
        assert_eq!(verify(Path::new("m"), &unsealed).unwrap(), Seal::Absent);
    }
}
