//! The `magcal` binary: see the `magcal_runner` crate.

fn main() -> std::process::ExitCode {
    magcal_runner::cli::main()
}

/// Notes whether standard output is open. This runs before the Rust runtime starts, because the
/// runtime reopens a closed standard output on `/dev/null`, after which a lost output could not be
/// told from a written one.
#[cfg(unix)]
#[ctor::ctor(unsafe)]
fn note_standard_output() {
    // SAFETY: F_GETFD reads the flags of a descriptor number; it touches no memory.
    if unsafe { libc::fcntl(libc::STDOUT_FILENO, libc::F_GETFD) } == -1 {
        magcal_runner::output::file::note_stdout_closed_at_start();
    }
}
