//! The `magcal` binary: see the `magcal_runner` crate.

fn main() -> std::process::ExitCode {
    magcal_runner::cli::main()
}
