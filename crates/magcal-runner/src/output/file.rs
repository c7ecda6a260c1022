//! Single-file outputs and standard output: the one writer of every file a command writes that is
//! not part of a result set ([`super::staging`] writes those).
//!
//! [`Output::File`] streams into a temporary file beside its path (`.<name>.magcal-tmp.<pid>.<n>`,
//! created exclusively, so that two processes or two outputs never share one), syncs it and renames
//! it over the path: a reader sees the old file or the whole new one. It replaces only a regular
//! file or a missing path: never a directory, a device, a FIFO or a symbolic link (write to standard
//! output with `--out -` and redirect it for those), and never a file that is one of the command's
//! inputs, compared by device and inode so that `./x.csv`, `x.csv` and a hard link of it are the
//! same file, and never a file inside a magcal result set. An error removes the temporary and leaves the path as it was; a temporary left by a
//! killed process is removed by the next write beside it.
//!
//! [`Output::Stdout`] writes to standard output and reports every failure (a full device, a closed
//! descriptor) as an error instead of a panic or a silent loss, but one: a reader that closed the
//! pipe (`magcal apply CAL LOG | head`) wants no more, so writing stops there without an error and
//! the command ends as it would have, with its own exit code. (Rust ignores `SIGPIPE`, so the write
//! fails with `EPIPE` where a C tool would be killed by the signal.)

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use anyhow::{Context, Result, bail};

use super::manifest::SetKind;
use super::staging::{left_by_the_dead, step};

const TEMPORARY: &str = "magcal-tmp";

/// Where a command's single output goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Output {
    /// Standard output (no `--out`, or `--out -`).
    Stdout,
    /// A file, replaced whole.
    File(PathBuf),
}

impl Output {
    /// The output an `--out` flag names: `-` or nothing is standard output.
    pub fn from_flag(flag: Option<&Path>) -> Self {
        match flag {
            Some(path) if path != Path::new("-") => Self::File(path.to_path_buf()),
            _ => Self::Stdout,
        }
    }

    /// Checks, before any work, that the output may be written: standard output is open, or the
    /// path may be replaced (see the module documentation). `inputs` are the files the command
    /// reads.
    ///
    /// # Errors
    /// A closed standard output, or a path that is a directory, device, FIFO, socket, symbolic
    /// link or one of `inputs`, or whose directory does not exist.
    pub fn check(&self, inputs: &[&Path]) -> Result<()> {
        match self {
            Self::Stdout => check_stdout(),
            Self::File(path) => check_file(path, inputs),
        }
    }

    /// Lets `write` fill the output (buffered), then syncs and renames a file into place, or
    /// flushes standard output. The checks of [`Self::check`] are made again before the rename.
    ///
    /// # Errors
    /// As [`Self::check`], a write that fails (a full disk, a file-size limit, a closed pipe), or
    /// what `write` returns; a file output then leaves its path as it was.
    pub fn write(&self, inputs: &[&Path], write: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
        match self {
            Self::Stdout => to_stdout(write),
            Self::File(path) => replace_with(path, inputs, write),
        }
    }
}

/// Set when standard output was closed when the process started (the runtime then opened it on
/// `/dev/null`, where everything written would be lost without an error).
static STDOUT_CLOSED: AtomicBool = AtomicBool::new(false);

/// Records that standard output was closed at start; called by the binary before the runtime
/// starts.
pub fn note_stdout_closed_at_start() {
    STDOUT_CLOSED.store(true, Ordering::SeqCst);
}

/// Checks that what is written to standard output can arrive: it was open at start.
///
/// # Errors
/// A standard output that was closed (`magcal ... >&-`).
pub fn check_stdout() -> Result<()> {
    if STDOUT_CLOSED.load(Ordering::SeqCst) {
        bail!("standard output is closed: redirect it (to /dev/null to discard what the command prints)");
    }
    Ok(())
}

/// Lets `write` fill standard output through a buffer and flushes it. A reader that closed the
/// pipe ends the writing without an error (see the module documentation). Within
/// [`super::capture::capturing`], the bytes are kept instead.
///
/// # Errors
/// A closed standard output, a write that fails (`> /dev/full`), or what `write` returns.
pub fn to_stdout(write: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    if super::capture::active() {
        let mut bytes = Vec::new();
        write(&mut bytes)?;
        super::capture::keep(&bytes, false);
        return Ok(());
    }
    check_stdout()?;
    let stdout = std::io::stdout();
    let mut w = Tracking::new(BufWriter::new(stdout.lock()));
    let written = write(&mut w);
    let written = w
        .blame(written, "standard output")
        .and_then(|()| w.flush().context("standard output: cannot write"));
    match written {
        // The error may reach here wrapped in a type that hides its cause (a CSV writer's): the
        // writer itself saw what failed.
        Err(_) if w.failure == Some(std::io::ErrorKind::BrokenPipe) => Ok(()),
        other => other,
    }
}

/// A writer that remembers how its first failed write or flush failed, so that an error of the
/// output (a full disk) is told from an error of what the rows are made from (a bad line of a
/// log, which names its own file).
struct Tracking<W> {
    inner: W,
    failure: Option<std::io::ErrorKind>,
}

impl<W: Write> Tracking<W> {
    fn new(inner: W) -> Self {
        Self { inner, failure: None }
    }

    /// `result`, with "`shown`: cannot write" in front of its error when a write failed.
    fn blame(&self, result: Result<()>, shown: &str) -> Result<()> {
        match result {
            Err(e) if self.failure.is_some() => Err(e.context(format!("{shown}: cannot write"))),
            other => other,
        }
    }

    /// Notes the kind of a failure of `result`.
    fn note<T>(&mut self, result: std::io::Result<T>) -> std::io::Result<T> {
        if let Err(e) = &result
            && e.kind() != std::io::ErrorKind::Interrupted
        {
            self.failure.get_or_insert(e.kind());
        }
        result
    }
}

impl<W: Write> Write for Tracking<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let written = self.inner.write(buf);
        self.note(written)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        let flushed = self.inner.flush();
        self.note(flushed)
    }
}

/// Writes `bytes` to `path` through [`replace_with`].
///
/// # Errors
/// As [`replace_with`].
pub fn replace(path: &Path, inputs: &[&Path], bytes: &[u8]) -> Result<()> {
    replace_with(path, inputs, |w| Ok(w.write_all(bytes)?))
}

/// Streams `write` into a fresh temporary file beside `path`, syncs it, and renames it over
/// `path`, which must be a regular file or missing and none of `inputs`.
///
/// # Errors
/// As [`Output::write`].
pub fn replace_with(path: &Path, inputs: &[&Path], write: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    check_file(path, inputs)?;
    let (parent, name) = split(path)?;
    remove_stale_temporaries(&parent, &name);
    let mut temporary =
        Temporary::create(&parent, &name).with_context(|| format!("{}: cannot write", path.display()))?;
    if let Ok(old) = std::fs::metadata(path) {
        // The new file keeps the permissions of the one it replaces.
        let _ = std::fs::set_permissions(&temporary.path, old.permissions());
    }
    temporary.fill(write, &path.display().to_string())?;
    step();
    // The path may have changed while the output was computed.
    check_file(path, inputs)?;
    std::fs::rename(&temporary.path, path).with_context(|| format!("{}: cannot write", path.display()))?;
    temporary.renamed = true;
    if let Ok(dir) = File::open(&parent) {
        let _ = dir.sync_all();
    }
    step();
    Ok(())
}

/// A temporary file beside an output, removed unless it was renamed into place.
struct Temporary {
    path: PathBuf,
    file: Option<File>,
    renamed: bool,
}

impl Temporary {
    fn create(parent: &Path, name: &str) -> std::io::Result<Self> {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        loop {
            let n = NEXT.fetch_add(1, Ordering::SeqCst);
            let path = parent.join(format!(".{name}.{TEMPORARY}.{}.{n}", std::process::id()));
            match OpenOptions::new().write(true).create_new(true).open(&path) {
                Ok(file) => {
                    return Ok(Self {
                        path,
                        file: Some(file),
                        renamed: false,
                    });
                }
                // Left by an earlier process of the same id: take the next number.
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
                Err(e) => return Err(e),
            }
        }
    }

    /// Lets `write` fill the file; an error of a write is "`shown`: cannot write", one of `write`'s
    /// own (a bad line of its input) is returned as it is.
    fn fill(&mut self, write: impl FnOnce(&mut dyn Write) -> Result<()>, shown: &str) -> Result<()> {
        let cannot = || format!("{shown}: cannot write");
        let file = self.file.take().with_context(cannot)?;
        let mut w = Tracking::new(BufWriter::new(file));
        let written = write(&mut w);
        w.blame(written, shown)?;
        let file = w.inner.into_inner().map_err(|e| e.into_error()).with_context(cannot)?;
        file.sync_all().with_context(cannot)?;
        Ok(())
    }
}

impl Drop for Temporary {
    fn drop(&mut self) {
        if !self.renamed {
            self.file = None;
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// The directory of `path` (`.` for a bare name) and its file name.
fn split(path: &Path) -> Result<(PathBuf, String)> {
    let Some(name) = path.file_name() else {
        bail!(
            "{}: name a file (not a directory such as '.', '..' or '/')",
            path.display()
        );
    };
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    Ok((parent, name.to_string_lossy().into_owned()))
}

/// Refuses a path that is not a regular file or missing, that is one of `inputs`, or that lies in
/// a magcal result set (which the next command into it replaces whole, this file with it).
fn check_file(path: &Path, inputs: &[&Path]) -> Result<()> {
    let shown = path.display();
    let (parent, _) = split(path)?;
    let not_in_a_set = || match SetKind::of(&parent)? {
        Some(kind) => bail!(
            "{shown}: {} holds a magcal {} set, which is replaced whole: write the file elsewhere",
            parent.display(),
            kind.as_str()
        ),
        None => Ok(()),
    };
    match std::fs::symlink_metadata(path) {
        Ok(meta) => {
            let kind = meta.file_type();
            if kind.is_symlink() {
                bail!(
                    "{shown}: is a symbolic link; magcal replaces only regular files: give the file it points to (or, where the flag takes -, write to standard output and redirect it)"
                );
            }
            if kind.is_dir() {
                bail!("{shown}: is a directory; give a file name");
            }
            if !kind.is_file() {
                bail!(
                    "{shown}: is not a regular file (a device, FIFO or socket); magcal replaces only regular files: where the flag takes -, write to standard output and redirect it there"
                );
            }
            for input in inputs {
                if same_file(path, input) {
                    bail!(
                        "{shown}: is the input {} (the same file); writing it would destroy it: give another path",
                        input.display()
                    );
                }
            }
            not_in_a_set()
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => match std::fs::metadata(&parent) {
            Ok(meta) if meta.is_dir() => not_in_a_set(),
            Ok(_) => bail!("{shown}: {} is not a directory", parent.display()),
            Err(_) => bail!("{shown}: no directory {}", parent.display()),
        },
        Err(e) => Err(e).with_context(|| format!("{shown}: cannot read")),
    }
}

pub use super::staging::same_file;

/// Whether two outputs name one file: the same file, or the same name in the same directory
/// (where the file does not exist yet).
pub fn one_output(a: &Path, b: &Path) -> bool {
    let place = |p: &Path| -> Option<(PathBuf, std::ffi::OsString)> {
        let (parent, name) = split(p).ok()?;
        Some((parent.canonicalize().ok()?, name.into()))
    };
    same_file(a, b) || matches!((place(a), place(b)), (Some(x), Some(y)) if x == y)
}

/// Removes the temporaries of `name` that processes no longer running left in `parent`.
fn remove_stale_temporaries(parent: &Path, name: &str) {
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    let prefix = format!(".{name}.{TEMPORARY}.");
    for entry in entries.flatten() {
        let file = entry.file_name().to_string_lossy().into_owned();
        let Some((pid, n)) = file.strip_prefix(&prefix).and_then(|rest| rest.split_once('.')) else {
            continue;
        };
        let (Ok(pid), Ok(_)) = (pid.parse::<u32>(), n.parse::<usize>()) else {
            continue;
        };
        if left_by_the_dead(pid, &entry.path()) {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dash_or_nothing_is_standard_output() {
        assert_eq!(Output::from_flag(None), Output::Stdout);
        assert_eq!(Output::from_flag(Some(Path::new("-"))), Output::Stdout);
        assert_eq!(
            Output::from_flag(Some(Path::new("./-"))),
            Output::File(PathBuf::from("./-"))
        );
    }

    #[test]
    fn a_failed_write_leaves_the_old_file_and_no_temporary() {
        let dir = tempfile::TempDir::new().unwrap();
        let path = dir.path().join("out.csv");
        std::fs::write(&path, "old\n").unwrap();
        let e = replace_with(&path, &[], |w| {
            w.write_all(b"partial")?;
            bail!("the rows ran out")
        })
        .unwrap_err();
        // An error of what the rows are made from is not one of the output.
        assert_eq!(format!("{e:#}"), "the rows ran out");
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "old\n");
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["out.csv"]);
        replace(&path, &[], b"new\n").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "new\n");
    }

    #[test]
    fn the_temporaries_of_dead_processes_are_removed_and_live_ones_kept() {
        let dir = tempfile::TempDir::new().unwrap();
        // 4194305 is above the largest process id Linux gives (2^22), so that process never runs.
        let dead = dir.path().join(".x.csv.magcal-tmp.4194305.0");
        let live = dir.path().join(format!(".x.csv.magcal-tmp.{}.999", std::process::id()));
        let other = dir.path().join(".y.csv.magcal-tmp.4194305.0");
        for p in [&dead, &live, &other] {
            std::fs::write(p, "").unwrap();
        }
        replace(&dir.path().join("x.csv"), &[], b"x\n").unwrap();
        assert!(!dead.exists() && live.exists() && other.exists());
    }
}
