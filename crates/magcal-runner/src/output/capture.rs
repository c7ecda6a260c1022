//! What the commands print, kept instead of printed for a caller in the same process
//! ([`capturing`]): the tests' in-process runs and the Python bindings, whose own standard output
//! is not the command's. [`super::file::to_stdout`] and [`super::stderr`] consult it.

/// What the commands printed on standard output and standard error while [`capturing`] ran.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Captured {
    /// The reports, as `magcal` would have printed them.
    pub stdout: Vec<u8>,
    /// The warnings and notes, one line each.
    pub stderr: Vec<u8>,
}

thread_local! {
    /// Where this thread's printing goes while [`capturing`] runs (`None`: the process's own
    /// standard output and error).
    static CAPTURE: std::cell::RefCell<Option<Captured>> = const { std::cell::RefCell::new(None) };
}

/// Restores the capture that was in place when dropped, a panic included.
struct Restore(Option<Option<Captured>>);

impl Drop for Restore {
    fn drop(&mut self) {
        if let Some(previous) = self.0.take() {
            CAPTURE.set(previous);
        }
    }
}

/// Runs `f` with what the commands it calls print on this thread (their reports and warnings)
/// kept instead of printed: for callers in the same process, whose own standard output is not
/// the command's (the tests' in-process runs, the Python bindings). The commands print only
/// from the thread that runs them, never from their workers.
pub fn capturing<T>(f: impl FnOnce() -> T) -> (T, Captured) {
    let restore = Restore(Some(CAPTURE.replace(Some(Captured::default()))));
    let value = f();
    let captured = CAPTURE.take().unwrap_or_default();
    drop(restore);
    (value, captured)
}

/// Appends `bytes` to the capture of [`capturing`] (`err`: standard error's) and says whether one
/// is running.
pub(crate) fn keep(bytes: &[u8], err: bool) -> bool {
    CAPTURE.with_borrow_mut(|c| match c {
        Some(c) => {
            if err { &mut c.stderr } else { &mut c.stdout }.extend_from_slice(bytes);
            true
        }
        None => false,
    })
}

/// Whether [`capturing`] runs on this thread.
pub(crate) fn active() -> bool {
    CAPTURE.with_borrow(Option::is_some)
}
