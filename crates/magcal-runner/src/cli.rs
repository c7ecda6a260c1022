//! The command line: raw flags (clap types that reject what can never be valid, such as
//! `--threads 0`) and the one `match` over the commands.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use crate::commands::{self, Failure};
use crate::output::file::Output;
use crate::output::stderr::to_stderr;

/// Calibration of strapdown three-axis magnetometers and D-optimal calibration manoeuvres, after
/// Wu, Hu, Wu, Liu, "D-Optimal Design Applied to Calibration of Strapdown Three-axis Magnetometer".
#[derive(Debug, Parser)]
#[command(name = "magcal", version, about)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Build the designs, run the noisy trials, write statistics, designs, figures and a manifest.
    Run(commands::run::RunArgs),
    /// Build the designs and write only their attitudes, metrics and figures.
    Design(commands::design::DesignArgs),
    /// Run again with the baseline's seed and trials and compare; exit 1 when something moved.
    Check(commands::check::CheckArgs),
    /// Redraw the figures of a results directory from its CSV files (into DIR/plots/).
    Plot(commands::plot::PlotArgs),
    /// Fit a log of raw readings: bias, non-orthogonality, scale factors, their standard errors,
    /// and whether the log determines them; exit 3 when it does not, or when the log rejects the
    /// model (the outputs are written all the same).
    Calibrate(commands::calibrate::CalibrateArgs),
    /// Calibrate every reading of a log with a calibration.json.
    Apply(commands::apply::ApplyArgs),
    /// How good a calibration is as a compass against the independent attitudes a log carries
    /// (or, with --raw, the log's raw readings): heading and direction errors, by heading and tilt.
    Evaluate(commands::evaluate::EvaluateArgs),
    /// The attitudes a vehicle should visit next to most increase the information of its log.
    Next(commands::next::NextArgs),
    /// Write a log of noisy readings of a scenario's sensor at one design's attitudes.
    Simulate(commands::simulate::SimulateArgs),
    /// The paper's Monte Carlo on a real log with reference attitudes: each design's attitudes
    /// realised by the log's own readings, every model scored against the reference.
    Replay(commands::replay::ReplayArgs),
    /// Write a calibration.json as an autopilot's parameters (ArduPilot, PX4) or a tool's form
    /// (MotionCal, Magneto, a C header); a calibration not marked usable writes nothing and exits
    /// 3, unless `--force` writes it under a first line that says so (still exit 3).
    Export(commands::export::ExportArgs),
    /// One self-contained HTML page of a result, to turn and hover in a browser, offline.
    Report(commands::report::ReportArgs),
}

impl Command {
    /// Whether the command writes to standard output.
    fn writes_stdout(&self) -> bool {
        let to_stdout = |out: &Option<PathBuf>| Output::from_flag(out.as_deref()) == Output::Stdout;
        match self {
            Self::Run(a) => !a.common.quiet,
            Self::Replay(a) => !a.common.quiet,
            Self::Design(a) => !a.common.quiet,
            Self::Check(a) => !a.common.quiet,
            Self::Plot(_) | Self::Calibrate(_) | Self::Next(_) | Self::Evaluate(_) | Self::Report(_) => true,
            Self::Apply(a) => to_stdout(&a.out),
            Self::Simulate(a) => to_stdout(&a.out),
            Self::Export(a) => to_stdout(&a.out),
        }
    }
}

/// Longest error line about the command line, characters (it may quote a value as given).
const MAX_USAGE_ERROR: usize = 300;

/// A clap error as one line: its message and tips, without the usage and help pointers, at most
/// 300 characters (`MAX_USAGE_ERROR`).
pub fn one_line(e: &clap::Error) -> String {
    let text = e.render().to_string();
    let line = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("Usage:") && !l.starts_with("For more information"))
        .map(|l| l.strip_prefix("error: ").unwrap_or(l))
        .collect::<Vec<_>>()
        .join(" ");
    if line.chars().count() > MAX_USAGE_ERROR {
        format!("{}...", line.chars().take(MAX_USAGE_ERROR).collect::<String>())
    } else {
        line
    }
}

/// Parses the command line, runs the command, prints an error as one line; the exit code.
pub fn main() -> ExitCode {
    // A write past the file-size limit (`ulimit -f`) fails with EFBIG, an error like a full
    // disk, instead of killing the process by SIGXFSZ with its temporary files left behind.
    #[cfg(unix)]
    // SAFETY: called first, before any thread starts; SIG_IGN is a valid disposition.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            use clap::error::ErrorKind;
            return match e.kind() {
                ErrorKind::DisplayHelp | ErrorKind::DisplayVersion => {
                    let _ = e.print();
                    ExitCode::SUCCESS
                }
                ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => {
                    let _ = e.print();
                    ExitCode::from(2)
                }
                _ => {
                    to_stderr!("magcal: error: {}", one_line(&e));
                    ExitCode::from(2)
                }
            };
        }
    };
    if cli.command.writes_stdout()
        && let Err(e) = crate::output::file::check_stdout()
    {
        to_stderr!("magcal: error: {e:#}");
        return ExitCode::from(2);
    }
    let result = match cli.command {
        Command::Run(args) => commands::run::run(&args),
        Command::Design(args) => commands::design::run(&args),
        Command::Check(args) => commands::check::run(&args),
        Command::Plot(args) => commands::plot::run(&args),
        Command::Calibrate(args) => commands::calibrate::run(&args),
        Command::Apply(args) => commands::apply::run(&args),
        Command::Evaluate(args) => commands::evaluate::run(&args),
        Command::Next(args) => commands::next::run(&args),
        Command::Simulate(args) => commands::simulate::run(&args),
        Command::Export(args) => commands::export::run(&args),
        Command::Report(args) => commands::report::run(&args),
        Command::Replay(args) => commands::replay::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure::Input(e)) => {
            // What an input held may be in the message: never as bytes a terminal acts on.
            to_stderr!(
                "magcal: error: {}",
                crate::limits::printable(&format!("{e:#}").replace('\n', " "))
            );
            ExitCode::from(2)
        }
        Err(Failure::Regression(table)) => {
            to_stderr!("magcal: regression: these results moved beyond their tolerance:\n{table}");
            ExitCode::from(1)
        }
        Err(Failure::Unusable(why)) => {
            to_stderr!(
                "magcal: not a calibration to use: {}",
                crate::limits::printable(&why.replace('\n', " "))
            );
            ExitCode::from(3)
        }
    }
}
