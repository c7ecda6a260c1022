//! `magcal design`: the designs and their metrics and figures, without trials.

use std::path::PathBuf;

use clap::Args;

use super::run::Plans;
use super::{Common, Failure};

/// `magcal design`.
#[derive(Debug, Args)]
pub struct DesignArgs {
    #[command(flatten)]
    pub common: Common,
    /// Output directory (default: results/SCENARIO_NAME/), replaced as for `run`.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print every design's flight plan (by default only the recommended design's; all of them
    /// are in designs.csv).
    #[arg(long)]
    pub plans: bool,
}

/// Runs the command.
///
/// # Errors
/// As [`super::run::produce`].
pub fn run(args: &DesignArgs) -> Result<(), Failure> {
    let plans = if args.plans { Plans::All } else { Plans::Recommended };
    super::run::produce(&args.common, args.out.as_deref(), None, Some(plans))
}
