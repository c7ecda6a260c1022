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
    /// A replay set of `replay`: replaced only when it is missing, empty, or holds a magcal
    /// replay set.
    Replay,
    /// A part of a results directory that the result set owns whole (its `plots/`).
    Owned,
}

impl Target {
    /// The kind of set a directory must hold to be replaced (none for an owned part).
    fn kind(self) -> Option<SetKind> {
        match self {
            Self::Results => Some(SetKind::Run),
            Self::Calibration => Some(SetKind::Calibration),
            Self::Replay => Some(SetKind::Replay),
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
        if kind == Target::Owned && std::fs::symlink_metadata(target).is_ok_and(|m| m.is_dir()) {
            // A set's `plots/` is replaced whole: only when it holds nothing but magcal's figures.
            let foreign = foreign_figures(target)?
                .into_iter()
                .map(|f| f.trim_start_matches("plots/").to_string())
                .collect();
            refuse_foreign(target, foreign, "magcal did not draw", "the figures are replaced whole")?;
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
    if meta.file_type().is_symlink() {
        bail!(
            "{}: is a symbolic link; magcal replaces only a real directory (a result set is swapped in whole): give the directory it points to",
            target.display()
        );
    }
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
        Some(kind) => check_own(target, kind),
    }
}

/// The files a set of `kind` may hold at its top, beside `plots/`: those its command writes. A
/// name outside them is the user's, whatever the manifest lists (a manifest can be edited and
/// resealed by anyone).
fn own_files(kind: SetKind) -> &'static [&'static str] {
    match kind {
        SetKind::Run => &[
            "manifest.json",
            "run.json",
            "designs.csv",
            "design_metrics.csv",
            "approximate.csv",
            "certificate.csv",
            "advice.csv",
            "summary.csv",
            "crb.csv",
            "pso_runs.csv",
            "trials.csv",
        ],
        SetKind::Calibration => &[
            "manifest.json",
            "calibration.json",
            "residuals.csv",
            "no_calibration.json",
        ],
        SetKind::Replay => &[
            "manifest.json",
            "realisation.csv",
            "summary.csv",
            "whole_log.csv",
            "trials.csv",
        ],
    }
}

/// Whether `name` is a figure magcal draws into a set's `plots/` (`plots.rs`): a metric's
/// (run and replay sets), a replay's heading and direction, a noise sweep's, the PSO runs', or a
/// design's, as `.svg` or `.png`.
pub fn is_figure(name: &str) -> bool {
    let Some(stem) = name.strip_suffix(".svg").or_else(|| name.strip_suffix(".png")) else {
        return false;
    };
    let metric = |m: &str| crate::pipeline::Metric::ALL.iter().any(|x| x.as_str() == m);
    metric(stem)
        || ["pso_runs", "heading_rms", "direction_rms"].contains(&stem)
        || stem.strip_prefix("noise_sweep_").is_some_and(metric)
        || stem.strip_prefix("design_").is_some_and(|d| !d.is_empty())
}

/// The entries of `dir`: names and kinds.
fn entries(dir: &Path) -> Result<Vec<(String, std::fs::FileType)>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("{}: cannot read", dir.display()))? {
        let entry = entry.with_context(|| format!("{}: cannot read", dir.display()))?;
        let kind = entry
            .file_type()
            .with_context(|| format!("{}: cannot read", entry.path().display()))?;
        out.push((entry.file_name().to_string_lossy().into_owned(), kind));
    }
    Ok(out)
}

/// The entries of a set's `plots/` that are not figures magcal draws, as `plots/NAME`.
fn foreign_figures(plots: &Path) -> Result<Vec<String>> {
    Ok(entries(plots)?
        .into_iter()
        .filter(|(name, kind)| !(kind.is_file() && is_figure(name)))
        .map(|(name, _)| format!("plots/{name}"))
        .collect())
}

/// Refuses a set of `kind` that holds what it did not write (a file the user put there), naming
/// it: the set is replaced whole, which would delete it. A set's own files are those of
/// [`own_files`] and, in `plots/`, the figures of [`is_figure`].
fn check_own(target: &Path, kind: SetKind) -> Result<()> {
    let mut foreign = Vec::new();
    for (name, entry) in entries(target)? {
        if name == "plots" && entry.is_dir() {
            foreign.extend(foreign_figures(&target.join("plots"))?);
        } else if !(entry.is_file() && own_files(kind).contains(&name.as_str())) {
            foreign.push(name);
        }
    }
    refuse_foreign(target, foreign, "the set did not write", "the set is replaced whole")
}

/// Refuses `target` when `foreign` names anything, naming at most five of them.
fn refuse_foreign(target: &Path, mut foreign: Vec<String>, what: &str, why: &str) -> Result<()> {
    if foreign.is_empty() {
        return Ok(());
    }
    foreign.sort();
    let shown: Vec<String> = foreign.iter().take(5).map(|f| format!("{f:?}")).collect();
    let more = if foreign.len() > 5 {
        format!(" and {} more", foreign.len() - 5)
    } else {
        String::new()
    };
    bail!(
        "{}: holds {} {what} ({}{more}); {why}, which would delete them: move them out, or give another --out",
        target.display(),
        if foreign.len() == 1 { "a file" } else { "files" },
        shown.join(", ")
    )
}

/// Refuses a target that is, or holds, one of `inputs` (compared by device and inode, so that a
/// relative and an absolute path of the same file are caught).
fn check_inputs(target: &Path, inputs: &[&Path]) -> Result<()> {
    if std::fs::symlink_metadata(target).is_err() {
        return Ok(());
    }
    for input in inputs {
        // An input that cannot be found is the command's to report.
        let Ok(real) = std::fs::canonicalize(input) else {
            continue;
        };
        for ancestor in real.ancestors() {
            if same_file(ancestor, target) {
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
        let path = entry.path();
        if !(what == STAGING || what == OLD) || !left_by_the_dead(pid, &path) {
            continue;
        }
        // Only what magcal could have written there: a directory of the user's under such a
        // name is left as it is.
        if !looks_ours(&path) {
            crate::output::stderr::to_stderr!(
                "magcal: note: {} is named as magcal's temporary directories are but holds what magcal does not write: left as it is",
                path.display()
            );
            continue;
        }
        if what == OLD && std::fs::symlink_metadata(target).is_err() {
            rename(&path, target)?;
        } else {
            remove_any(&path)?;
        }
    }
    Ok(())
}

/// Whether `dir` is a directory (not a link) holding only what a killed run of magcal leaves:
/// the files of a set of some kind ([`own_files`]), figures ([`is_figure`]), and a `plots/` of
/// figures.
fn looks_ours(dir: &Path) -> bool {
    let is_dir = std::fs::symlink_metadata(dir).is_ok_and(|m| m.is_dir());
    let Ok(list) = entries(dir)
        .map_err(|_| ())
        .and_then(|l| if is_dir { Ok(l) } else { Err(()) })
    else {
        return false;
    };
    let any_own = |name: &str| {
        [SetKind::Run, SetKind::Calibration, SetKind::Replay]
            .iter()
            .any(|k| own_files(*k).contains(&name))
            || is_figure(name)
    };
    list.iter().all(|(name, kind)| {
        if name == "plots" && kind.is_dir() {
            foreign_figures(&dir.join("plots")).is_ok_and(|f| f.is_empty())
        } else {
            kind.is_file() && any_own(name)
        }
    })
}

/// Whether process `pid` runs: on Unix, whether signal 0 reaches it (`EPERM` is another user's
/// process, running); `None` where that cannot be told (not Unix), and then what it left must be
/// kept: it may be in use.
fn alive(pid: u32) -> Option<bool> {
    #[cfg(unix)]
    {
        use rustix::process::{Pid, test_kill_process};
        let Some(pid) = i32::try_from(pid).ok().and_then(Pid::from_raw) else {
            return Some(false);
        };
        Some(test_kill_process(pid) != Err(rustix::io::Errno::SRCH))
    }
    #[cfg(not(unix))]
    {
        let _ = pid;
        None
    }
}

/// Whether what process `pid` left at `path` may be removed: the process does not run. Where that
/// cannot be told, the path is kept and a note says so.
pub(super) fn left_by_the_dead(pid: u32, path: &Path) -> bool {
    if pid == std::process::id() {
        return false;
    }
    match alive(pid) {
        Some(running) => !running,
        None => {
            crate::output::stderr::to_stderr!(
                "magcal: note: {} was left by process {pid}, and whether it still runs cannot be told on this platform: kept; remove it when no magcal runs",
                path.display()
            );
            false
        }
    }
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

/// Whether `a` and `b` name the same file (symbolic links followed): on Unix the same device and
/// inode, from `stat`; elsewhere the same volume and file index, by the `same-file` crate. The
/// crate is not used on Unix because it opens both paths, and opening a FIFO blocks until a writer
/// comes and then takes the writer's first bytes from the command that reads it (a test of an
/// endless FIFO saw its log end at line 1).
pub fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (std::fs::metadata(a), std::fs::metadata(b)) {
            (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        ::same_file::is_same_file(a, b).unwrap_or(false)
    }
}

/// Figures go into the set with the rest of its files.
impl magcal_report::figures::Figures for ResultSet {
    fn put(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        ResultSet::put(self, name, bytes)
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    /// A process id above the largest Linux gives (2^22): never running.
    const DEAD: u32 = 4_194_305;

    #[cfg(unix)]
    #[test]
    fn a_process_runs_until_it_has_ended_and_been_reaped() {
        assert_eq!(alive(std::process::id()), Some(true));
        // PID 1 is another user's process here or in a container, and runs: signal 0 says EPERM
        // or succeeds, both "running".
        assert_eq!(alive(1), Some(true));
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let pid = child.id();
        child.wait().unwrap();
        assert_eq!(alive(pid), Some(false));
        assert_eq!(alive(DEAD), Some(false));
        assert_eq!(alive(u32::MAX), Some(false), "not a process id at all");
    }

    /// The manifest of a run set as [`SetKind::of`] recognises it (a name and a scenario hash).
    const RUN_MANIFEST: &str =
        r#"{"name":"s","scenario_sha256":"0","files":["summary.csv","trials.csv","designs.csv","crb.csv"]}"#;

    /// Every file below `dir`, relative path -> text.
    fn files(dir: &Path) -> BTreeMap<String, String> {
        fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, String>) {
            for e in std::fs::read_dir(dir).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    walk(root, &p, out);
                } else {
                    let rel = p.strip_prefix(root).unwrap().to_string_lossy().replace('\\', "/");
                    out.insert(rel, std::fs::read_to_string(&p).unwrap());
                }
            }
        }
        let mut out = BTreeMap::new();
        walk(dir, dir, &mut out);
        out
    }

    /// The names in `dir`, sorted.
    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    fn make(dir: &Path, files: &[(&str, &str)]) {
        for (rel, text) in files {
            let p = dir.join(rel);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(p, text).unwrap();
        }
    }

    fn map(files: &[(&str, &str)]) -> BTreeMap<String, String> {
        files.iter().map(|(a, b)| (a.to_string(), b.to_string())).collect()
    }

    fn message(e: &anyhow::Error) -> String {
        format!("{e:#}")
    }

    #[test]
    fn a_set_is_staged_beside_the_target_and_swapped_in_whole() {
        let tmp = tempfile::TempDir::new().unwrap();
        let target = tmp.path().join("out");
        let mut set = ResultSet::begin(&target, Target::Results, &[]).unwrap();
        assert_eq!(
            set.dir(),
            tmp.path().join(format!(".out.magcal-staging.{}", std::process::id()))
        );
        assert_eq!(set.target(), target);
        set.put("manifest.json", RUN_MANIFEST.as_bytes()).unwrap();
        set.put("summary.csv", b"1\n").unwrap();
        set.put_with("plots/eta_psi.svg", |w| Ok(w.write_all(b"<svg/>")?))
            .unwrap();
        // Nothing at the target until the commit.
        assert!(!target.exists());
        set.commit().unwrap();
        let first = [
            ("manifest.json", RUN_MANIFEST),
            ("summary.csv", "1\n"),
            ("plots/eta_psi.svg", "<svg/>"),
        ];
        assert_eq!(files(&target), map(&first));
        assert_eq!(names(tmp.path()), ["out"]);

        // A second set replaces the first whole: none of its files survive.
        let mut set = ResultSet::begin(&target, Target::Results, &[]).unwrap();
        set.put("manifest.json", RUN_MANIFEST.as_bytes()).unwrap();
        set.put("trials.csv", b"2\n").unwrap();
        // The old set stays whole while the new one is staged.
        assert_eq!(files(&target), map(&first));
        set.commit().unwrap();
        assert_eq!(
            files(&target),
            map(&[("manifest.json", RUN_MANIFEST), ("trials.csv", "2\n")])
        );
        assert_eq!(names(tmp.path()), ["out"]);
    }

    #[test]
    fn a_failed_write_or_an_abandoned_set_leaves_the_old_set_and_no_staging() {
        let tmp = tempfile::TempDir::new().unwrap();
        let target = tmp.path().join("out");
        let old = [("manifest.json", RUN_MANIFEST), ("summary.csv", "old\n")];
        make(&target, &old);

        let mut set = ResultSet::begin(&target, Target::Results, &[]).unwrap();
        set.put("summary.csv", b"new\n").unwrap();
        let e = set
            .put_with("trials.csv", |w| {
                w.write_all(b"partial")?;
                Err(std::io::Error::new(std::io::ErrorKind::StorageFull, "disk full").into())
            })
            .unwrap_err();
        assert_eq!(
            message(&e),
            format!("{}: cannot write: disk full", target.join("trials.csv").display())
        );
        drop(set);
        assert_eq!(files(&target), map(&old));
        assert_eq!(names(tmp.path()), ["out"]);

        // A file where a directory of the set must go.
        let mut set = ResultSet::begin(&target, Target::Results, &[]).unwrap();
        set.put("plots", b"").unwrap();
        let e = set.put("plots/eta_psi.svg", b"<svg/>").unwrap_err();
        assert!(message(&e).contains("plots: cannot create"), "{e:#}");
        drop(set);
        assert_eq!(files(&target), map(&old));
        assert_eq!(names(tmp.path()), ["out"]);
    }

    #[test]
    fn only_a_missing_or_empty_directory_or_a_set_of_the_same_kind_is_replaced() {
        let tmp = tempfile::TempDir::new().unwrap();
        let at = |name: &str| tmp.path().join(name);
        // An empty directory is replaced.
        std::fs::create_dir(at("empty")).unwrap();
        let mut set = ResultSet::begin(&at("empty"), Target::Calibration, &[]).unwrap();
        set.put("x", b"x").unwrap();
        set.commit().unwrap();
        assert_eq!(files(&at("empty")), map(&[("x", "x")]));

        make(&at("foreign"), &[("notes.txt", "mine")]);
        std::fs::write(at("file"), "a file").unwrap();
        std::os::unix::fs::symlink(at("run"), at("link")).unwrap();
        make(&at("run"), &[("manifest.json", RUN_MANIFEST)]);
        make(&at("cal"), &[("manifest.json", r#"{"kind":"calibration"}"#)]);
        let before: Vec<_> = ["foreign", "run", "cal"].iter().map(|n| files(&at(n))).collect();
        for (name, kind, why) in [
            (
                "foreign",
                Target::Results,
                "exists and is not a magcal results directory (no magcal manifest.json); give another --out, or remove it",
            ),
            (
                "foreign",
                Target::Calibration,
                "exists and is not a magcal results directory (no magcal manifest.json); give another --out, or remove it",
            ),
            ("file", Target::Results, "exists and is not a directory"),
            (
                "link",
                Target::Results,
                "is a symbolic link; magcal replaces only a real directory (a result set is swapped in whole): give the directory it points to",
            ),
            (
                "run",
                Target::Calibration,
                "holds a magcal run set, not a calibration set; give another --out, or remove it",
            ),
            (
                "cal",
                Target::Results,
                "holds a magcal calibration set, not a run set; give another --out, or remove it",
            ),
        ] {
            let e = ResultSet::begin(&at(name), kind, &[]).unwrap_err();
            assert_eq!(message(&e), format!("{}: {why}", at(name).display()));
        }
        let after: Vec<_> = ["foreign", "run", "cal"].iter().map(|n| files(&at(n))).collect();
        assert_eq!(before, after);
        assert_eq!(std::fs::read_to_string(at("file")).unwrap(), "a file");
        assert_eq!(names(tmp.path()), ["cal", "empty", "file", "foreign", "link", "run"]);

        // A set inside another, a directory holding an input, and no directory name of its own.
        let e = ResultSet::begin(&at("run").join("inner"), Target::Results, &[]).unwrap_err();
        assert_eq!(
            message(&e),
            format!(
                "{}: {} holds a magcal run set, which is replaced whole: give another --out",
                at("run").join("inner").display(),
                at("run").display()
            )
        );
        let input = at("foreign").join("notes.txt");
        let e = ResultSet::begin(&at("foreign"), Target::Owned, &[&input]).unwrap_err();
        assert_eq!(
            message(&e),
            format!(
                "{}: holds the input {}; replacing the directory would destroy it: give another --out",
                at("foreign").display(),
                input.display()
            )
        );
        for bad in [".", "..", "/"] {
            let e = ResultSet::begin(Path::new(bad), Target::Results, &[]).unwrap_err();
            assert_eq!(
                message(&e),
                format!("{bad}: name the output directory itself (not '.', '..' or a root)")
            );
        }
        let long = at(&"n".repeat(201));
        let e = ResultSet::begin(&long, Target::Results, &[]).unwrap_err();
        assert!(
            message(&e).ends_with(": the directory name is longer than 200 bytes"),
            "{e:#}"
        );
        assert_eq!(
            before,
            ["foreign", "run", "cal"]
                .iter()
                .map(|n| files(&at(n)))
                .collect::<Vec<_>>()
        );
    }

    #[test]
    fn an_owned_part_is_replaced_only_when_it_holds_only_magcals_figures() {
        let tmp = tempfile::TempDir::new().unwrap();
        let plots = tmp.path().join("plots");
        make(&plots, &[("eta_psi.svg", "old"), ("design_a.png", "old")]);
        let mut set = ResultSet::begin(&plots, Target::Owned, &[]).unwrap();
        set.put("eta_s.svg", b"new").unwrap();
        set.commit().unwrap();
        assert_eq!(files(&plots), map(&[("eta_s.svg", "new")]));
        assert_eq!(names(tmp.path()), ["plots"]);
        // A file of the user's, a figure's name on a directory, a PNG magcal never draws.
        for (name, shown) in [
            ("notes.txt", "\"notes.txt\""),
            ("pso_runs.svg/x.svg", "\"pso_runs.svg\""),
            ("mine.png", "\"mine.png\""),
        ] {
            make(&plots, &[(name, "mine")]);
            let e = ResultSet::begin(&plots, Target::Owned, &[]).unwrap_err();
            assert_eq!(
                message(&e),
                format!(
                    "{}: holds a file magcal did not draw ({shown}); the figures are replaced whole, which would delete them: move them out, or give another --out",
                    plots.display()
                )
            );
            remove_any(&plots.join(name.split('/').next().unwrap())).unwrap();
        }
        assert_eq!(files(&plots), map(&[("eta_s.svg", "new")]));
    }

    #[test]
    fn a_set_holds_only_the_names_its_command_writes_whatever_its_manifest_lists() {
        let tmp = tempfile::TempDir::new().unwrap();
        let target = tmp.path().join("out");
        let listed = r#"{"name":"s","scenario_sha256":"0","files":["mine.csv"]}"#;
        make(&target, &[("manifest.json", listed), ("mine.csv", "mine")]);
        let e = ResultSet::begin(&target, Target::Results, &[]).unwrap_err();
        assert!(
            message(&e).contains("holds a file the set did not write (\"mine.csv\")"),
            "{e:#}"
        );
        assert_eq!(files(&target).len(), 2);
    }

    #[test]
    fn the_commit_checks_the_target_again() {
        let tmp = tempfile::TempDir::new().unwrap();
        let target = tmp.path().join("out");
        // A foreign directory made at the target after `begin` is never replaced.
        let mut set = ResultSet::begin(&target, Target::Results, &[]).unwrap();
        set.put("manifest.json", RUN_MANIFEST.as_bytes()).unwrap();
        make(&target, &[("notes.txt", "mine")]);
        let e = set.commit().unwrap_err();
        assert!(
            message(&e).contains("exists and is not a magcal results directory"),
            "{e:#}"
        );
        assert_eq!(files(&target), map(&[("notes.txt", "mine")]));
        assert_eq!(names(tmp.path()), ["out"]);

        // A set of the same kind made there meanwhile is exchanged like any other.
        let other = tmp.path().join("other");
        let mut set = ResultSet::begin(&other, Target::Results, &[]).unwrap();
        set.put("manifest.json", RUN_MANIFEST.as_bytes()).unwrap();
        set.put("designs.csv", b"new").unwrap();
        make(&other, &[("manifest.json", RUN_MANIFEST), ("crb.csv", "raced")]);
        set.commit().unwrap();
        assert_eq!(
            files(&other),
            map(&[("manifest.json", RUN_MANIFEST), ("designs.csv", "new")])
        );
        assert_eq!(names(tmp.path()), ["other", "out"]);
    }

    #[test]
    fn what_killed_runs_left_is_removed_or_put_back_and_live_runs_are_left_alone() {
        let tmp = tempfile::TempDir::new().unwrap();
        let at = |name: &str| tmp.path().join(name);
        let old = [("manifest.json", RUN_MANIFEST), ("summary.csv", "old")];
        // A run killed between setting the old set aside and renaming the new one in: the target
        // is missing, and the set aside is put back.
        make(&at(&format!(".out.magcal-old.{DEAD}")), &old);
        make(&at(&format!(".out.magcal-staging.{DEAD}")), &[("summary.csv", "")]);
        // A running process's staging (pid 1 runs on every Linux), another target's, and a
        // name that only looks like one.
        make(&at(".out.magcal-staging.1"), &[("summary.csv", "")]);
        make(&at(&format!(".other.magcal-staging.{DEAD}")), &[("trials.csv", "")]);
        make(&at(".out.magcal-staging.x"), &[("trials.csv", "")]);
        let set = ResultSet::begin(&at("out"), Target::Results, &[]).unwrap();
        assert_eq!(files(&at("out")), map(&old));
        drop(set);
        assert_eq!(files(&at("out")), map(&old));
        let mut left = vec![
            ".other.magcal-staging.4194305".to_string(),
            ".out.magcal-staging.x".into(),
            "out".into(),
        ];
        if cfg!(target_os = "linux") {
            left.insert(1, ".out.magcal-staging.1".into());
        }
        assert_eq!(names(tmp.path()), left);

        // With the target present, a set aside by a dead run is removed.
        make(&at(&format!(".out.magcal-old.{DEAD}")), &[("crb.csv", "")]);
        // A directory of the user's under such a name is left as it is.
        make(
            &at(&format!(".out.magcal-staging.{}", DEAD + 1)),
            &[("important.txt", "mine")],
        );
        let mut set = ResultSet::begin(&at("out"), Target::Results, &[]).unwrap();
        assert!(!at(&format!(".out.magcal-old.{DEAD}")).exists());
        set.put("manifest.json", RUN_MANIFEST.as_bytes()).unwrap();
        set.commit().unwrap();
        assert_eq!(files(&at("out")), map(&[("manifest.json", RUN_MANIFEST)]));
        left.push(format!(".out.magcal-staging.{}", DEAD + 1));
        left.sort();
        assert_eq!(names(tmp.path()), left);
        assert_eq!(
            files(&at(&format!(".out.magcal-staging.{}", DEAD + 1))),
            map(&[("important.txt", "mine")])
        );
    }
}
