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
    check_not_an_input(&args.out, &args.result)?;
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

/// Refuses a page onto a file the set was made from (its log or scenario), told by the SHA-256
/// the set's manifest recorded for it, wherever the file now is and whatever its name.
fn check_not_an_input(out: &std::path::Path, result: &std::path::Path) -> Result<()> {
    let Ok(meta) = std::fs::metadata(out) else {
        return Ok(());
    };
    if !meta.is_file() {
        return Ok(());
    }
    let path = result.join("manifest.json");
    let Ok(bytes) = crate::limits::read_bounded(&path, crate::limits::MAX_MANIFEST_BYTES) else {
        return Ok(());
    };
    let Ok(manifest) = serde_json::from_slice::<serde_json::Value>(&bytes) else {
        return Ok(());
    };
    let inputs: Vec<(&str, &str)> = [("log", "log_sha256"), ("scenario", "scenario_sha256")]
        .into_iter()
        .filter_map(|(what, key)| Some((what, manifest.get(key)?.as_str()?)))
        .collect();
    if inputs.is_empty() {
        return Ok(());
    }
    let mut hashing = crate::digest::Hashing::new(std::io::sink());
    let Ok(mut file) = std::fs::File::open(out) else {
        return Ok(());
    };
    if std::io::copy(&mut file, &mut hashing).is_err() {
        return Ok(());
    }
    let hash = hashing.hex();
    if let Some((what, _)) = inputs.iter().find(|(_, h)| *h == hash) {
        // A replay's manifest names its scenario file `scenario_path` (`scenario` is its name).
        let keys: &[&str] = if *what == "log" {
            &["log"]
        } else {
            &["scenario_path", "scenario"]
        };
        let named = keys.iter().find_map(|k| manifest.get(*k)?.as_str()).unwrap_or("?");
        bail!(
            "{}: is the {what} {named} the set {} was made from (the SHA-256 its manifest records); writing it would destroy it: give another path",
            out.display(),
            result.display()
        );
    }
    Ok(())
}
