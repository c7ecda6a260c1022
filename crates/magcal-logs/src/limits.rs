//! Reading what a user hands over without trusting it: numbers of flags checked finite, text
//! shown back escaped and cut short, files and streams read within a bound of bytes and of idle
//! time, and the memory this process may use.

use std::io::Read;
use std::path::Path;

use anyhow::{Context, Result, bail};

/// Largest `calibration.json` read, bytes (one is about 4 KiB).
pub const MAX_CALIBRATION_BYTES: u64 = 1 << 20;

pub use magcal_core::error::show;

/// A flag's number: any that parses as `f64` and is finite (`nan`, `inf` and numbers beyond
/// 1.8e308 are refused here, by name, rather than as a range they are "outside").
///
/// # Errors
/// Text that is not a number, or a number that is not finite.
pub fn finite(text: &str) -> std::result::Result<f64, String> {
    if text.trim().is_empty() {
        return Err("an empty value is not a number".into());
    }
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{} is not a number", excerpt(text, 40)))?;
    if v.is_nan() {
        return Err("NaN is not a number".into());
    }
    if v.is_infinite() && text.to_ascii_lowercase().contains("inf") {
        return Err(format!("{} is not finite", excerpt(text, 40)));
    }
    if v.is_infinite() {
        return Err(format!("{} is beyond the largest number (1.8e308)", excerpt(text, 40)));
    }
    Ok(v)
}

/// `--heading-budget`: a heading error in degrees above 0 and below 180.
///
/// # Errors
/// Text that is not a finite number, or one outside that range.
pub fn heading_budget(text: &str) -> std::result::Result<f64, String> {
    let v = finite(text)?;
    if (magcal_core::budget::MIN_BUDGET_DEG..180.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "{} degrees: a heading budget is at least {} and below 180",
            show(v),
            magcal_core::budget::MIN_BUDGET_DEG
        ))
    }
}

/// `text` with what a terminal would act on escaped: control characters (an escape sequence in a
/// cell never reaches the terminal as one), line and paragraph separators, and the marks that
/// reorder text (which could make a message read other than it is).
pub fn printable(text: &str) -> String {
    let acts = |c: char| {
        c.is_control()
            || matches!(c, '\u{2028}' | '\u{2029}' | '\u{200e}' | '\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}')
    };
    if !text.chars().any(acts) {
        return text.to_string();
    }
    text.chars()
        .map(|c| {
            if acts(c) {
                c.escape_unicode().to_string()
            } else {
                c.to_string()
            }
        })
        .collect()
}

/// `text`, cut to `max` characters (with "...") for an error message.
pub fn excerpt(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        Some((i, _)) => format!("{}...", &text[..i]),
        None => text.to_string(),
    }
}

/// Bytes, for people.
pub fn bytes(n: u64) -> String {
    const GIB: f64 = (1u64 << 30) as f64;
    const MIB: f64 = (1u64 << 20) as f64;
    let x = n as f64;
    if x >= GIB {
        format!("{:.1} GiB", x / GIB)
    } else {
        format!("{:.1} MiB", x / MIB)
    }
}

/// The most read from a log that is not a regular file (a pipe, a FIFO, a device), bytes: 1 GiB.
/// A stream has no size to check first and may never end (a FIFO that keeps sending zeros after
/// a header, endless format definitions); a flight log larger than this is saved to a file.
pub const MAX_STREAM_BYTES: u64 = 1 << 30;

/// The error of a [`Bounded`] reader past its bound: its words name the file and the bound.
#[derive(Debug)]
pub struct StreamBound(pub String);

impl std::fmt::Display for StreamBound {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for StreamBound {}

/// The longest a file that is not a regular file may send nothing before its reader gives up:
/// 30 s. A FIFO with no writer, or a writer that stalls, would otherwise hold the command forever.
pub const MAX_STREAM_IDLE: std::time::Duration = std::time::Duration::from_secs(30);

/// [`MAX_STREAM_IDLE`], or for tests `MAGCAL_TEST_STREAM_IDLE_MS` milliseconds (so that a test of
/// a FIFO nobody writes to ends in a moment).
pub fn stream_idle() -> std::time::Duration {
    std::env::var("MAGCAL_TEST_STREAM_IDLE_MS")
        .ok()
        .and_then(|v| v.parse().ok())
        .map_or(MAX_STREAM_IDLE, std::time::Duration::from_millis)
}

/// A log file being read: a regular file as it is; anything else (a pipe, a FIFO, a device) as a
/// stream that fails, naming `shown`, once more than `max` bytes have come through it
/// ([`MAX_STREAM_BYTES`]) or when it sends nothing for `idle` ([`MAX_STREAM_IDLE`]).
pub struct Bounded {
    inner: std::fs::File,
    stream: bool,
    left: u64,
    max: u64,
    idle: std::time::Duration,
    shown: String,
}

impl Bounded {
    /// Opens `path` (`shown` in errors) and says whether it is a regular file. A stream is opened
    /// without waiting for a writer, so that a FIFO nobody writes to ends at the idle bound
    /// rather than in `open`.
    ///
    /// # Errors
    /// A file that cannot be opened, or a directory.
    pub fn open(path: &Path, shown: &str, max: u64, idle: std::time::Duration) -> Result<Self> {
        let meta = std::fs::metadata(path).with_context(|| format!("{shown}: cannot read the log"))?;
        if meta.is_dir() {
            bail!("{shown}: is a directory, not a log");
        }
        let stream = !meta.is_file();
        // A stream's idle bound waits with poll(2); without it a pipe nobody writes to would
        // hang the command, so off Unix only regular files are read.
        #[cfg(not(unix))]
        if stream {
            bail!(
                "{shown}: is a pipe or a device, which magcal reads only on Unix (its 30-s idle bound needs poll): save it to a file"
            );
        }
        let mut options = std::fs::OpenOptions::new();
        options.read(true);
        #[cfg(unix)]
        if stream {
            use std::os::unix::fs::OpenOptionsExt;
            options.custom_flags(libc::O_NONBLOCK);
        }
        let inner = options
            .open(path)
            .with_context(|| format!("{shown}: cannot read the log"))?;
        Ok(Self {
            inner,
            stream,
            left: if stream { max } else { u64::MAX },
            max,
            idle,
            shown: shown.to_string(),
        })
    }

    /// [`Self::open`] with the bounds of a log: [`MAX_STREAM_BYTES`] and [`stream_idle`].
    ///
    /// # Errors
    /// As [`Self::open`].
    pub fn open_log(path: &Path, shown: &str) -> Result<Self> {
        Self::open(path, shown, MAX_STREAM_BYTES, stream_idle())
    }

    /// Whether the file is a stream rather than a regular file.
    pub fn is_stream(&self) -> bool {
        self.stream
    }

    /// Waits until the stream has bytes or has ended, at most `idle`.
    #[cfg(unix)]
    fn wait(&self) -> std::io::Result<()> {
        use rustix::event::{PollFd, PollFlags, Timespec, poll};
        let timeout = Timespec {
            tv_sec: i64::try_from(self.idle.as_secs()).unwrap_or(i64::MAX),
            tv_nsec: i64::from(self.idle.subsec_nanos()),
        };
        loop {
            let mut fds = [PollFd::new(&self.inner, PollFlags::IN)];
            match poll(&mut fds, Some(&timeout)) {
                Ok(0) => {
                    return Err(std::io::Error::other(StreamBound(format!(
                        "{}: nothing came from the stream (a pipe or a device, not a regular file) for {} s; save it to a file",
                        self.shown,
                        self.idle.as_secs_f64()
                    ))));
                }
                Ok(_) => return Ok(()),
                Err(rustix::io::Errno::INTR) => {}
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// Off Unix no stream is opened ([`Self::open`] refuses them), so there is nothing to wait for.
    #[cfg(not(unix))]
    fn wait(&self) -> std::io::Result<()> {
        let _ = self.idle;
        Ok(())
    }

    /// One read of the file; a stream is waited for first, and a read that would block (the
    /// stream was opened without blocking) waits again.
    fn read_once(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if !self.stream {
            return self.inner.read(buf);
        }
        loop {
            self.wait()?;
            match self.inner.read(buf) {
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                r => return r,
            }
        }
    }
}

impl Read for Bounded {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.left == 0 {
            // One byte more than the bound says whether the stream goes on.
            let mut probe = [0u8; 1];
            return match self.read_once(&mut probe)? {
                0 => Ok(0),
                _ => Err(std::io::Error::other(StreamBound(format!(
                    "{}: more than {} from a stream (a pipe or a device, not a regular file), which is all magcal reads of one; save the log to a file",
                    self.shown,
                    bytes(self.max)
                )))),
            };
        }
        let n = buf.len().min(usize::try_from(self.left).unwrap_or(usize::MAX));
        let k = self.read_once(&mut buf[..n])?;
        self.left -= k as u64;
        Ok(k)
    }
}

/// The whole of `path`, at most `max` bytes, whatever it is (a regular file, a FIFO, a device):
/// a directory, or more than `max` bytes, is refused naming the file and the limit.
///
/// # Errors
/// An unreadable file, a directory, or a file larger than `max`.
pub fn read_bounded(path: &Path, max: u64) -> Result<Vec<u8>> {
    let shown = path.display().to_string();
    let meta = std::fs::metadata(path).with_context(|| format!("{shown}: cannot read"))?;
    if meta.is_dir() {
        bail!("{shown}: is a directory");
    }
    if meta.len() > max {
        bail!("{shown}: {} bytes; at most {} are read", meta.len(), bytes(max));
    }
    // A FIFO is opened without waiting for a writer and read for as long as it sends.
    let file = Bounded::open(path, &shown, u64::MAX, stream_idle())?;
    let mut out = Vec::with_capacity(meta.len() as usize);
    match file.take(max + 1).read_to_end(&mut out) {
        Ok(_) => {}
        Err(e) if e.get_ref().is_some_and(|r| r.is::<StreamBound>()) => bail!("{e}"),
        Err(e) => return Err(e).with_context(|| format!("{shown}: cannot read")),
    }
    if out.len() as u64 > max {
        bail!(
            "{shown}: more than {} bytes (not a regular file?); at most that is read",
            bytes(max)
        );
    }
    Ok(out)
}

/// The file `name` of the result set in `dir`, as its manifest names it: a plain name (no
/// separator, not `.` or `..`, so never a path outside the set) of a regular file (not a symlink,
/// a FIFO or a device: magcal writes none of those into a set).
///
/// # Errors
/// A name that is not plain, or a file that is missing or not regular.
pub fn set_member(dir: &Path, name: &str) -> Result<std::path::PathBuf> {
    let plain =
        !name.is_empty() && name != "." && name != ".." && !name.contains(['/', '\\', '\0']) && name.len() <= 255;
    let shown: String = name.chars().take(60).collect();
    if !plain {
        bail!(
            "{}: names the file {shown:?}, which is not a plain file name of the set; the baseline is damaged or not magcal's",
            dir.join("manifest.json").display()
        );
    }
    let path = dir.join(name);
    let meta = std::fs::symlink_metadata(&path).with_context(|| format!("{}: cannot read", path.display()))?;
    if !meta.is_file() {
        let kind = if meta.file_type().is_symlink() {
            "a symbolic link"
        } else if meta.is_dir() {
            "a directory"
        } else {
            "a special file"
        };
        bail!(
            "{}: is {kind}, not a regular file; magcal writes only regular files into a result set",
            path.display()
        );
    }
    Ok(path)
}

/// Largest file of a result set read whole (`trials.csv` the largest), bytes: a quarter of what
/// the process may use, so that its text and its parsed rows fit in half.
pub fn max_result_file_bytes() -> u64 {
    available_memory().map_or(u64::MAX, |(a, _)| a / 4)
}

/// What this process may use: the smallest of the memory the system reports available and the
/// address-space and data limits (`setrlimit`) of the process; `None` where none is known.
pub fn available_memory() -> Option<(u64, &'static str)> {
    let mut best: Option<(u64, &'static str)> = None;
    let mut take = |v: u64, what: &'static str| {
        if best.is_none_or(|(b, _)| v < b) {
            best = Some((v, what));
        }
    };
    if let Ok(text) = std::fs::read_to_string("/proc/meminfo")
        && let Some(kib) = text
            .lines()
            .find_map(|l| l.strip_prefix("MemAvailable:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
    {
        take(kib * 1024, "memory available (MemAvailable)");
    }
    #[cfg(not(target_os = "linux"))]
    {
        use sysinfo::{MemoryRefreshKind, RefreshKind, System};
        let system =
            System::new_with_specifics(RefreshKind::nothing().with_memory(MemoryRefreshKind::nothing().with_ram()));
        let available = system.available_memory();
        if available > 0 {
            take(available, "memory available (the system's count)");
        }
    }
    #[cfg(unix)]
    {
        use rustix::process::{Resource, getrlimit};
        for (resource, what) in [
            (Resource::As, "the address-space limit (RLIMIT_AS)"),
            (Resource::Data, "the data limit (RLIMIT_DATA)"),
        ] {
            if let Some(v) = getrlimit(resource).current {
                take(v, what);
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_members_are_plain_regular_files() {
        let dir = tempfile::TempDir::new().unwrap();
        std::fs::write(dir.path().join("a.csv"), "x").unwrap();
        assert!(set_member(dir.path(), "a.csv").is_ok());
        for bad in ["../a.csv", "/etc/hostname", "..", ".", "", "b/../a.csv", "a\\b"] {
            let e = set_member(dir.path(), bad).unwrap_err().to_string();
            assert!(e.contains("not a plain file name"), "{bad}: {e}");
        }
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink("/dev/zero", dir.path().join("z.csv")).unwrap();
            let e = set_member(dir.path(), "z.csv").unwrap_err().to_string();
            assert!(e.contains("is a symbolic link, not a regular file"), "{e}");
        }
        std::fs::create_dir(dir.path().join("d")).unwrap();
        assert!(
            set_member(dir.path(), "d")
                .unwrap_err()
                .to_string()
                .contains("is a directory")
        );
    }

    /// A FIFO at `dir/name`.
    #[cfg(unix)]
    fn fifo(dir: &Path, name: &str) -> std::path::PathBuf {
        let p = dir.join(name);
        let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        p
    }

    #[cfg(unix)]
    #[test]
    fn a_stream_ends_at_its_bounds_in_bytes_and_in_time_without_progress() {
        let dir = tempfile::TempDir::new().unwrap();
        let idle = std::time::Duration::from_millis(300);
        // No writer at all: the open does not wait for one, the read waits `idle`.
        let lonely = fifo(dir.path(), "lonely");
        let mut f = Bounded::open(&lonely, "lonely", 1 << 20, idle).unwrap();
        assert!(f.is_stream());
        let started = std::time::Instant::now();
        let e = f.read_to_end(&mut Vec::new()).unwrap_err().to_string();
        assert!(
            e == "lonely: nothing came from the stream (a pipe or a device, not a regular file) for 0.3 s; save it to a file",
            "{e}"
        );
        assert!(started.elapsed() >= idle, "{:?}", started.elapsed());
        // A writer that sends five bytes and stalls: the bytes are read, then the wait ends it.
        let stalled = fifo(dir.path(), "stalled");
        let writer = {
            let p = stalled.clone();
            std::thread::spawn(move || {
                use std::io::Write;
                let mut w = std::fs::OpenOptions::new().write(true).open(p).unwrap();
                w.write_all(b"hello").unwrap();
                std::thread::sleep(std::time::Duration::from_millis(1500));
            })
        };
        let mut f = Bounded::open(&stalled, "stalled", 1 << 20, idle).unwrap();
        let mut got = Vec::new();
        let e = f.read_to_end(&mut got).unwrap_err().to_string();
        assert!(e.contains("nothing came from the stream"), "{e}");
        assert_eq!(got, b"hello");
        writer.join().unwrap();
        // A writer that closes: the end of the stream, read as the end of the log.
        let closed = fifo(dir.path(), "closed");
        let writer = {
            let p = closed.clone();
            std::thread::spawn(move || std::fs::write(p, b"abc").unwrap())
        };
        let mut f = Bounded::open(&closed, "closed", 1 << 20, std::time::Duration::from_secs(10)).unwrap();
        let mut got = Vec::new();
        f.read_to_end(&mut got).unwrap();
        writer.join().unwrap();
        assert_eq!(got, b"abc");
        // A device that never ends: the byte bound.
        let mut f = Bounded::open(Path::new("/dev/zero"), "zero", 1 << 16, idle).unwrap();
        let e = f.read_to_end(&mut Vec::new()).unwrap_err().to_string();
        assert!(e.starts_with("zero: more than 0.1 MiB from a stream"), "{e}");
        // A regular file is no stream.
        let p = dir.path().join("f");
        std::fs::write(&p, [1u8; 10]).unwrap();
        assert!(!Bounded::open(&p, "f", 4, idle).unwrap().is_stream());
    }

    #[test]
    fn what_a_terminal_acts_on_is_escaped_and_numbers_are_checked() {
        assert_eq!(printable("a\u{1b}[2Jb\u{7}"), "a\\u{1b}[2Jb\\u{7}");
        assert_eq!(printable("x\u{2028}y\u{202e}z"), "x\\u{2028}y\\u{202e}z");
        assert_eq!(printable("plain é 😀"), "plain é 😀");
        assert_eq!(finite("2.5"), Ok(2.5));
        assert_eq!(finite("nan"), Err("NaN is not a number".into()));
        assert_eq!(finite("-inf"), Err("-inf is not finite".into()));
        assert_eq!(
            finite("1e400"),
            Err("1e400 is beyond the largest number (1.8e308)".into())
        );
        assert_eq!(finite("x"), Err("x is not a number".into()));
    }

    #[test]
    fn bounded_reads_stop_at_the_bound() {
        let dir = tempfile::TempDir::new().unwrap();
        let p = dir.path().join("f");
        std::fs::write(&p, [7u8; 100]).unwrap();
        assert_eq!(read_bounded(&p, 100).unwrap().len(), 100);
        assert!(
            read_bounded(&p, 99)
                .unwrap_err()
                .to_string()
                .contains("100 bytes; at most")
        );
        #[cfg(unix)]
        {
            let e = read_bounded(Path::new("/dev/zero"), 1 << 20).unwrap_err().to_string();
            assert!(e.contains("more than 1.0 MiB"), "{e}");
        }
        assert!(
            read_bounded(dir.path(), 10)
                .unwrap_err()
                .to_string()
                .contains("is a directory")
        );
    }

    #[test]
    fn numbers_are_shown_as_written() {
        assert_eq!(show(-60.0), "-60");
        assert_eq!(show(0.25), "0.25");
        assert_eq!(show(1e308), "1e308");
        assert_eq!(show(5e-324), "5e-324");
        assert_eq!(show(0.0), "0");
        assert_eq!(show(f64::INFINITY), "inf");
        assert_eq!(show(48277.79), "48277.79");
    }
}
