//! `magcal report RESULT --out FILE.html`: one self-contained HTML page of a result (see
//! [`crate::report`]), written whole or not at all, never onto the result's own files.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Result, bail};
use clap::Args;

use super::Failure;
use crate::output::file::{replace, to_stdout};

/// `magcal report`.
#[derive(Debug, Args)]
pub struct ReportArgs {
    /// A result set: a `calibrate --out`, `replay`, `design` or `run` directory (the pages of
    /// `next` and `evaluate` come from their own `--report FILE.html`).
    pub result: PathBuf,
    /// The HTML file to write (replaced whole; not inside a result set).
    #[arg(long, value_name = "FILE.html")]
    pub out: PathBuf,
}

/// Runs the command.
///
/// # Errors
/// A result that cannot be read, or an output that may not be written.
pub fn run(args: &ReportArgs) -> Result<(), Failure> {
    let started = Instant::now();
    if args.out.as_os_str() == "-" {
        return Err(Failure::Input(anyhow::anyhow!(
            "--out -: give a file (the page is several megabytes)"
        )));
    }
    check_not_inside(&args.out, &args.result)?;
    let page = crate::report::page_of(&args.result)?;
    let html = page.render()?;
    let inputs = [args.result.as_path()];
    replace(&args.out, &inputs, html.as_bytes())?;
    to_stdout(|w| {
        Ok(writeln!(
            w,
            "{}: the page of {} ({:.1} MB, {:.2} s); open it in a browser, offline",
            args.out.display(),
            args.result.display(),
            html.len() as f64 / 1e6,
            started.elapsed().as_secs_f64()
        )?)
    })?;
    Ok(())
}

/// Refuses a page inside the result it draws.
fn check_not_inside(out: &std::path::Path, result: &std::path::Path) -> Result<()> {
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    if let (Ok(a), Ok(b)) = (parent.canonicalize(), result.canonicalize())
        && a.starts_with(&b)
    {
        bail!(
            "{}: inside the result {} it draws; write the page elsewhere",
            out.display(),
            result.display()
        );
    }
    Ok(())
}
