//! `magcal plot DIR`: redraws the figures of a result set from its files into `DIR/plots/`, which
//! is replaced whole.

use std::path::PathBuf;

use clap::Args;

use anyhow::Result;

use super::Failure;
use crate::output::file::to_stdout;
use crate::output::manifest::Manifest;
use crate::output::staging::{ResultSet, Target};
use crate::plots;

/// `magcal plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// A results directory written by `magcal run` or `magcal design`.
    pub dir: PathBuf,
}

/// Runs the command.
///
/// # Errors
/// A directory that is not a result set, or a missing or malformed file of it.
pub fn run(args: &PlotArgs) -> Result<(), Failure> {
    let (manifest, _) = Manifest::read(&args.dir)?;
    let target = args.dir.join("plots");
    let mut set = ResultSet::begin(&target, Target::Owned, &[])?;
    let drawn = plots::draw(&args.dir, &manifest, &mut set, "")?;
    set.commit()?;
    to_stdout(|w| {
        Ok(writeln!(
            w,
            "{} figures (SVG and PNG) drawn in {}",
            drawn.len(),
            target.display()
        )?)
    })?;
    Ok(())
}
