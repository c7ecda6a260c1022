//! A result set written whole or not at all.
//!
//! A command writes every file of its result set into a staging directory beside the target
//! (`.<target>.magcal-staging.<pid>`, on the same file system) and swaps it in at the end: on Linux
//! with one `renameat2(RENAME_EXCHANGE)`, which replaces the directory atomically; elsewhere (or on
//! a file system without it) by renaming the old set aside (`.<target>.magcal-old.<pid>`) and the
//! new one into place. So a kill at any moment leaves the target holding one complete set, old or
//! new, and nothing of an earlier set survives beside a new one. A staging or set-aside directory
//! left by a killed run is removed (or, if the target is missing, put back) by the next run on the
//! same target. An error before the swap removes the staging directory and leaves the target as it
//! was.
//!
//! A result set is of one kind (its manifest's `kind`; see [`SetKind`]): a set of one kind never
//! replaces a directory holding a set of another, and never a directory that holds one of the
//! command's inputs.
//!
//! For tests, `MAGCAL_TEST_ABORT_AFTER_STEP=k` aborts the process right after the k-th step of the
//! write phase (each file written, each rename), as a kill would.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, Result, bail};

use super::manifest::SetKind;

const STAGING: &str = "magcal-staging";
const OLD: &str = "magcal-old";

/// What may be replaced at the target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    /// A results directory of `run` or `design`: replaced only when it is missing, empty, or holds
    /// a magcal run set.
    Results,
    /// A calibration set of `calibrate --out`: replaced only when it is missing, empty, or holds a
    /// magcal calibration set.
    Calibration,
    /// A part of a results directory that the result set owns whole (its `plots/`).
    Owned,
}

impl Target {
    /// The kind of set a directory must hold to be replaced (none for an owned part).
    fn kind(self) -> Option<SetKind> {
        match self {
            Self::Results => Some(SetKind::Run),
            Self::Calibration => Some(SetKind::Calibration),
            Self::Owned => None,
        }
    }
}

/// A result set being written.
#[derive(Debug)]
pub struct ResultSet {
    target: PathBuf,
    staging: PathBuf,
    kind: Target,
    committed: bool,
}

impl ResultSet {
    /// Checks that `target` may be replaced, removes what killed runs left beside it, and creates
    /// an empty staging directory. `inputs` are the files the command reads: none may lie inside
    /// the target.
    ///
    /// # Errors
    /// A target that names no directory of its own (`.`, `..`, `/`), that exists and is not a
    /// magcal result set of the kind `kind` asks for, that holds one of `inputs`, or whose parent
    /// cannot be created or written.
    pub fn begin(target: &Path, kind: Target, inputs: &[&Path]) -> Result<Self> {
        let name = match target.components().next_back() {
            Some(std::path::Component::Normal(n)) => n.to_string_lossy().into_owned(),
            _ => bail!(
                "{}: name the output directory itself (not '.', '..' or a root)",
                target.display()
            ),
        };
        if name.len() > 200 {
            bail!("{}: the directory name is longer than 200 bytes", target.display());
        }
        check_inputs(target, inputs)?;
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        if let Some(want) = kind.kind() {
            check_replaceable(target, want)?;
            // A set inside another would go with it when that one is replaced.
            if let Some(outer) = SetKind::of(&parent)? {
                bail!(
                    "{}: {} holds a magcal {} set, which is replaced whole: give another --out",
                    target.display(),
                    parent.display(),
                    outer.as_str()
                );
            }
        }
        std::fs::create_dir_all(&parent).with_context(|| format!("{}: cannot create", parent.display()))?;
        recover(&parent, &name, target)?;
        let staging = parent.join(format!(".{name}.{STAGING}.{}", std::process::id()));
        if staging.exists() {
            remove_any(&staging)?;
        }
        std::fs::create_dir(&staging).with_context(|| format!("{}: cannot create", staging.display()))?;
        Ok(Self {
            target: target.to_path_buf(),
            staging,
            kind,
            committed: false,
        })
    }

    /// The staging directory (files written there become the result set at [`Self::commit`]).
    pub fn dir(&self) -> &Path {
        &self.staging
    }

    /// The directory the set will replace.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Writes `bytes` to `relative` in the staging directory.
    ///
    /// # Errors
    /// A file that cannot be created or written (a full disk, say).
    pub fn put(&mut self, relative: &str, bytes: &[u8]) -> Result<()> {
        self.put_with(relative, |w| Ok(w.write_all(bytes)?))
    }

    /// Creates `relative` in the staging directory and lets `write` fill it (buffered, synced).
    ///
    /// # Errors
    /// As [`Self::put`], or what `write` returns.
    pub fn put_with(&mut self, relative: &str, write: impl FnOnce(&mut BufWriter<File>) -> Result<()>) -> Result<()> {
        let path = self.staging.join(relative);
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
        }
        let shown = self.target.join(relative);
        let file = File::create(&path).with_context(|| format!("{}: cannot create", path.display()))?;
        let mut w = BufWriter::new(file);
        write(&mut w).with_context(|| format!("{}: cannot write", shown.display()))?;
        let file = w
            .into_inner()
            .map_err(|e| anyhow::anyhow!("{}: cannot write: {}", shown.display(), e.error()))?;
        file.sync_all()
            .with_context(|| format!("{}: cannot write", shown.display()))?;
        step();
        Ok(())
    }

    /// Swaps the staging directory in for the target.
    ///
    /// # Errors
    /// A rename that fails; the target then still holds its earlier set.
    pub fn commit(mut self) -> Result<()> {
        if let Ok(dir) = File::open(&self.staging) {
            let _ = dir.sync_all();
        }
        // Another process may have written the target since `begin`: it must still be one this
        // set may replace.
        let recheck = |target: &Path| match self.kind.kind() {
            Some(want) => check_replaceable(target, want),
            None => Ok(()),
        };
        recheck(&self.target)?;
        if std::fs::symlink_metadata(&self.target).is_err() {
            match std::fs::rename(&self.staging, &self.target) {
                Ok(()) => {
                    step();
                    self.committed = true;
                    return Ok(());
                }
                // A set that another process put there meanwhile is exchanged like any other.
                Err(_) if std::fs::symlink_metadata(&self.target).is_ok() => recheck(&self.target)?,
                Err(e) => {
                    return Err(e).with_context(|| {
                        format!("{}: cannot rename to {}", self.staging.display(), self.target.display())
                    });
                }
            }
        }
        if exchange(&self.staging, &self.target)? {
            step();
            // The old set is now at the staging path.
            remove_any(&self.staging)?;
            step();
        } else {
            let parent = self.staging.parent().unwrap_or(Path::new("."));
            let name = self.target.file_name().unwrap_or_default().to_string_lossy();
            let old = parent.join(format!(".{name}.{OLD}.{}", std::process::id()));
            rename(&self.target, &old)?;
            step();
            if let Err(e) = rename(&self.staging, &self.target) {
                let _ = rename(&old, &self.target);
                return Err(e);
            }
            step();
            remove_any(&old)?;
            step();
        }
        self.committed = true;
        Ok(())
    }
}

impl Drop for ResultSet {
    fn drop(&mut self) {
        if !self.committed {
            let _ = remove_any(&self.staging);
        }
    }
}

/// Refuses to replace a directory that holds anything but a magcal result set of kind `want`.
fn check_replaceable(target: &Path, want: SetKind) -> Result<()> {
    let Ok(meta) = std::fs::symlink_metadata(target) else {
        return Ok(());
    };
    if !meta.is_dir() {
        bail!("{}: exists and is not a directory", target.display());
    }
    let mut entries = std::fs::read_dir(target).with_context(|| format!("{}: cannot read", target.display()))?;
    if entries.next().is_none() {
        return Ok(());
    }
    match SetKind::of(target)? {
        None => bail!(
            "{}: exists and is not a magcal results directory (no magcal manifest.json); \
             give another --out, or remove it",
            target.display()
        ),
        Some(kind) if kind != want => bail!(
            "{}: holds a magcal {} set, not a {} set; give another --out, or remove it",
            target.display(),
            kind.as_str(),
            want.as_str()
        ),
        Some(_) => Ok(()),
    }
}

/// Refuses a target that is, or holds, one of `inputs` (compared by device and inode, so that a
/// relative and an absolute path of the same file are caught).
fn check_inputs(target: &Path, inputs: &[&Path]) -> Result<()> {
    let Ok(dir) = std::fs::symlink_metadata(target) else {
        return Ok(());
    };
    for input in inputs {
        // An input that cannot be found is the command's to report.
        let Ok(real) = std::fs::canonicalize(input) else {
            continue;
        };
        for ancestor in real.ancestors() {
            if std::fs::metadata(ancestor).is_ok_and(|m| same_inode(&m, &dir)) {
                bail!(
                    "{}: holds the input {}; replacing the directory would destroy it: give another --out",
                    target.display(),
                    input.display()
                );
            }
        }
    }
    Ok(())
}

/// Removes staging directories of runs that are no longer running, and puts back a set-aside set
/// whose replacement never arrived.
fn recover(parent: &Path, name: &str, target: &Path) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(parent) else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let file = entry.file_name().to_string_lossy().into_owned();
        let Some(rest) = file.strip_prefix(&format!(".{name}.")) else {
            continue;
        };
        let Some((what, pid)) = rest.rsplit_once('.') else {
            continue;
        };
        let Ok(pid) = pid.parse::<u32>() else { continue };
        if !(what == STAGING || what == OLD) || pid == std::process::id() || alive(pid) {
            continue;
        }
        let path = entry.path();
        if what == OLD && std::fs::symlink_metadata(target).is_err() {
            rename(&path, target)?;
        } else {
            remove_any(&path)?;
        }
    }
    Ok(())
}

/// Whether process `pid` runs (Linux: it has a `/proc` entry; elsewhere assumed not).
pub(super) fn alive(pid: u32) -> bool {
    cfg!(target_os = "linux") && Path::new("/proc").join(pid.to_string()).exists()
}

fn rename(from: &Path, to: &Path) -> Result<()> {
    std::fs::rename(from, to).with_context(|| format!("{}: cannot rename to {}", from.display(), to.display()))
}

fn remove_any(path: &Path) -> Result<()> {
    let meta = std::fs::symlink_metadata(path).with_context(|| format!("{}: cannot read", path.display()))?;
    if meta.is_dir() {
        std::fs::remove_dir_all(path)
    } else {
        std::fs::remove_file(path)
    }
    .with_context(|| format!("{}: cannot remove", path.display()))
}

/// Exchanges two paths atomically; `Ok(false)` where the system cannot.
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> Result<bool> {
    use rustix::fs::{CWD, RenameFlags, renameat_with};
    match renameat_with(CWD, a, CWD, b, RenameFlags::EXCHANGE) {
        Ok(()) => Ok(true),
        Err(e) if e == rustix::io::Errno::INVAL || e == rustix::io::Errno::NOSYS => Ok(false),
        Err(e) => {
            Err(std::io::Error::from(e)).with_context(|| format!("{}: cannot swap in the new results", b.display()))
        }
    }
}

#[cfg(not(target_os = "linux"))]
fn exchange(_: &Path, _: &Path) -> Result<bool> {
    Ok(false)
}

/// One step of the write phase; the test hook aborts after the k-th.
pub(super) fn step() {
    static STEPS: AtomicUsize = AtomicUsize::new(0);
    static LIMIT: std::sync::OnceLock<Option<usize>> = std::sync::OnceLock::new();
    let limit = LIMIT.get_or_init(|| {
        std::env::var("MAGCAL_TEST_ABORT_AFTER_STEP")
            .ok()
            .and_then(|v| v.parse().ok())
    });
    let n = STEPS.fetch_add(1, Ordering::SeqCst) + 1;
    if *limit == Some(n) {
        std::process::abort();
    }
}

/// Whether two files' metadata name the same file (device and inode).
#[cfg(unix)]
pub(super) fn same_inode(a: &std::fs::Metadata, b: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    a.dev() == b.dev() && a.ino() == b.ino()
}

#[cfg(not(unix))]
pub(super) fn same_inode(_: &std::fs::Metadata, _: &std::fs::Metadata) -> bool {
    false
}
