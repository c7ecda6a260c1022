//! A result set read from its files alone: its manifest checked, its statistics printed, and its
//! page written.
//!
//! ```text
//! cargo run --release -p magcal-report --example show_a_set -- [SET_DIR] [PAGE.html]
//! cargo run --release -p magcal-report --example show_a_set -- results/wu2014 /tmp/wu2014.html
//! ```
//!
//! `SET_DIR` is a directory `magcal run`, `design`, `calibrate --out` or `replay` wrote (default:
//! the committed `results/smoke`); the page is written to `PAGE.html` (default: `report.html` in
//! the temporary directory) and is the one `magcal report SET_DIR` writes.

use std::path::PathBuf;

use magcal_report::manifest::{Manifest, SetKind};
use magcal_report::rows::{self, Metric, SummaryRow};

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let dir = PathBuf::from(args.next().unwrap_or_else(|| "results/smoke".into()));
    let out = args
        .next()
        .map_or_else(|| std::env::temp_dir().join("report.html"), PathBuf::from);

    let kind = SetKind::of(&dir)?;
    println!(
        "{}: {}",
        dir.display(),
        kind.map_or("not a magcal result set", SetKind::as_str)
    );
    if kind == Some(SetKind::Run) {
        let (manifest, seal) = Manifest::read(&dir)?;
        println!(
            "scenario {} (seed {}), manifest {seal:?}, {} files",
            manifest.name,
            manifest.seed,
            manifest.files.len()
        );
        if manifest.lists("summary.csv") {
            for row in rows::read_csv::<SummaryRow>(&dir.join("summary.csv"))? {
                if row.metric == Metric::EtaPsi {
                    let mean = row.mean.map_or("-".to_string(), |m| format!("{:.3}", m.0));
                    println!(
                        "  {:<14} sigma {} nT: eta_psi mean {mean} % over {} ok trials",
                        row.design, row.sigma_nt.0, row.ok
                    );
                }
            }
        }
    }
    let html = magcal_report::pages::page_of(&dir)?.render()?;
    std::fs::write(&out, &html)?;
    println!("wrote {} ({} bytes)", out.display(), html.len());
    Ok(())
}
