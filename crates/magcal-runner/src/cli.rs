//! The command line: raw flags (clap types that reject what can never be valid, such as
//! `--threads 0`) and the one `match` over the commands.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

use crate::commands::{self, Failure};
use crate::output::file::Output;
use crate::output::stderr::to_stderr;

/// The command line's raw flags: the command and its arguments.
#[derive(Debug, Parser)]
#[command(
    name = "magcal",
    version,
    about = "Plan the attitudes a vehicle should visit to calibrate its magnetometer, calibrate what it \
             logged (CSV, ArduPilot, MAVLink, PX4), judge the result, export it to the autopilot and look \
             at it.",
    long_about = "Plan the attitudes a vehicle should visit to calibrate its magnetometer, calibrate what it \
                  logged (CSV, ArduPilot, MAVLink, PX4), judge the result, export it to the autopilot and \
                  look at it.\n\nThe attitudes are D-optimal for the vehicle's box of roll, pitch and \
                  heading, after Wu, Hu, Wu, Liu, \"D-Optimal Design Applied to Calibration of Strapdown \
                  Three-axis Magnetometer\" ([P1]); every verdict is a Monte Carlo check at the sensor's \
                  noise. Start with `magcal design scenarios/usv.toml` (a plan for a boat) or `magcal \
                  calibrate LOG` (a log you have)."
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Reproduce a scenario: designs, noisy trials, statistics and figures.
    ///
    /// Builds the designs, runs the noisy trials, writes statistics, designs, figures and a
    /// manifest (the paper's Monte Carlo, [P1] IV).
    Run(commands::run::RunArgs),
    /// Plan a vehicle's calibration attitudes: the recommended flight plan first.
    ///
    /// Builds the designs of the scenario's attitude box, checks each by Monte Carlo at the
    /// sensor's noise, prints the recommendation (or what works instead), the table of designs and
    /// the recommended flight plan, and writes their attitudes, metrics and figures.
    Design(commands::design::DesignArgs),
    /// Compare a run with its committed baseline; exit 1 when something moved.
    ///
    /// Runs again with the baseline's seed and trials and compares every statistic within its
    /// tolerance.
    Check(commands::check::CheckArgs),
    /// Redraw a result set's figures from its CSV files (into DIR/plots/).
    Plot(commands::plot::PlotArgs),
    /// Calibrate a log: bias, non-orthogonality, scale factors and a verdict.
    ///
    /// Fits a log of raw readings: bias, non-orthogonality, scale factors, their standard errors,
    /// and whether the log determines them; exit 3 when it does not, or when the log rejects the
    /// model (the outputs are written all the same).
    Calibrate(commands::calibrate::CalibrateArgs),
    /// Calibrate every reading of a log with a calibration.json.
    Apply(commands::apply::ApplyArgs),
    /// Judge a calibration as a compass against the attitudes a log carries.
    ///
    /// How good a calibration is as a compass against the independent attitudes a log carries
    /// (or, with --raw, the log's raw readings): heading and direction errors, by heading and tilt.
    Evaluate(commands::evaluate::EvaluateArgs),
    /// The attitudes to visit next to most increase a log's information.
    ///
    /// The attitudes a vehicle should visit next to most increase the information of its log
    /// (D-optimal augmentation), with every parameter's standard error before and after.
    Next(commands::next::NextArgs),
    /// Calibrate while the vehicle turns, and say where to turn next.
    ///
    /// Reads a MAVLink stream (UDP, TCP, serial) or lines of readings (MotionCal's `Raw:`, CSV)
    /// as they arrive, fits them as `calibrate` does at most once a second, says the attitude to
    /// visit next as `next` does, and writes the calibration set at every usable fit.
    Live(commands::live::LiveArgs),
    /// Write a log of noisy readings of a scenario's sensor at one design's attitudes.
    Simulate(commands::simulate::SimulateArgs),
    /// The paper's Monte Carlo on a real log with reference attitudes.
    ///
    /// Each design's attitudes realised by the log's own readings, every model scored against
    /// the reference.
    Replay(commands::replay::ReplayArgs),
    /// Write a calibration as an autopilot's parameters (ArduPilot, PX4) or a tool's form.
    ///
    /// Writes a calibration.json as an autopilot's parameters (ArduPilot, PX4) or a tool's form
    /// (MotionCal, Magneto, a C header); a calibration not marked usable writes nothing and exits
    /// 3, unless `--force` writes it under a first line that says so (still exit 3).
    Export(commands::export::ExportArgs),
    /// One self-contained HTML page of a result, to turn and hover in a browser, offline.
    Report(commands::report::ReportArgs),
    /// Print a shell's completion script.
    ///
    /// For example `magcal completions bash > ~/.local/share/bash-completion/completions/magcal`.
    Completions(ShellArgs),
    /// Print the man page, every command in it.
    ///
    /// For example `magcal man > magcal.1 && man ./magcal.1`.
    Man,
}

/// `magcal completions`.
#[derive(Debug, clap::Args)]
struct ShellArgs {
    /// The shell.
    shell: clap_complete::Shell,
}

/// The command definition with its grouped help: what `--help`, the completions and the man page
/// are made from.
pub fn command() -> clap::Command {
    crate::help::grouped(Cli::command())
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
            Self::Plot(_)
            | Self::Calibrate(_)
            | Self::Live(_)
            | Self::Next(_)
            | Self::Evaluate(_)
            | Self::Report(_)
            | Self::Completions(_)
            | Self::Man => true,
            Self::Apply(a) => to_stdout(&a.out),
            Self::Simulate(a) => to_stdout(&a.out),
            Self::Export(a) => to_stdout(&a.out),
        }
    }
}

/// Longest error line about the command line, characters (it may quote a value as given).
const MAX_USAGE_ERROR: usize = 300;

/// A clap error in clap's own layout (the message, its tip, the usage line and the pointer to
/// `--help`), each line made printable and cut at 300 characters (`MAX_USAGE_ERROR`): a value
/// quoted as given can be anything.
pub fn shown(e: &clap::Error) -> String {
    let text = e.render().to_string();
    text.trim_end()
        .lines()
        .map(|l| {
            let l = crate::limits::printable(l);
            if l.chars().count() > MAX_USAGE_ERROR {
                format!("{}...", l.chars().take(MAX_USAGE_ERROR).collect::<String>())
            } else {
                l
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

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
    let parsed = command().try_get_matches().and_then(|m| Cli::from_arg_matches(&m));
    let cli = match parsed {
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
                    to_stderr!("magcal: {}", shown(&e));
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
        Command::Live(args) => commands::live::run(&args),
        Command::Simulate(args) => commands::simulate::run(&args),
        Command::Export(args) => commands::export::run(&args),
        Command::Report(args) => commands::report::run(&args),
        Command::Replay(args) => commands::replay::run(&args),
        Command::Completions(args) => {
            crate::output::file::to_stdout(|w| crate::help::completions(&mut command(), args.shell, w))
                .map_err(Failure::from)
        }
        Command::Man => crate::output::file::to_stdout(|w| crate::help::man(command(), w)).map_err(Failure::from),
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
