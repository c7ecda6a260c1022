//! `magcal design`: the designs and their metrics and figures, without trials.

use crate::cli::{DesignArgs, Failure};

/// Runs the command.
///
/// # Errors
/// As [`super::run::produce`].
pub fn run(args: &DesignArgs) -> Result<(), Failure> {
    super::run::produce(&args.common, args.out.as_deref(), None, true)
}
