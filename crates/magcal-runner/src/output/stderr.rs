//! Messages on standard error that never panic.
//!
//! `eprintln!` panics when standard error cannot be written (`2>/dev/full`, a closed descriptor),
//! which would turn a warning into a crash and a refusal into exit code 101. `to_stderr!` writes
//! the line in one call and drops a failure: there is nowhere left to report it, and the exit code
//! still says what happened.

use std::io::Write;

/// Writes `line` and a newline to standard error in one write (kept instead within
/// [`super::capture::capturing`]); a failure is ignored.
pub fn line(line: &str) {
    let mut bytes = Vec::with_capacity(line.len() + 1);
    bytes.extend_from_slice(line.as_bytes());
    bytes.push(b'\n');
    if !super::capture::keep(&bytes, true) {
        let _ = std::io::stderr().lock().write_all(&bytes);
    }
}

/// `eprintln!` that ignores a standard error that cannot be written (see [the module](self)).
macro_rules! to_stderr {
    ($($arg:tt)*) => {
        $crate::output::stderr::line(&format!($($arg)*))
    };
}

pub(crate) use to_stderr;
