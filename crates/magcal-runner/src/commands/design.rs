//! `magcal design`: the designs and their metrics and figures, without trials.

use std::path::PathBuf;

use clap::Args;

use super::{Common, Failure};

/// `magcal design`.
#[derive(Debug, Args)]
pub struct DesignArgs {
    #[command(flatten)]
    pub common: Common,
    /// Output directory (default: results/SCENARIO_NAME/), replaced as for `run`.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Runs the command.
///
/// # Errors
/// As [`super::run::produce`].
pub fn run(args: &DesignArgs) -> Result<(), Failure> {
    super::run::produce(&args.common, args.out.as_deref(), None, true)
}
