//! The table `run` and `design` print on stdout.

use std::path::Path;

use crate::pipeline::RunOutput;

/// A statistic for the screen: `-` where undefined.
fn cell(x: f64) -> String {
    if x.is_nan() { "-".into() } else { format!("{x:.3}") }
}

/// Designs with `ln det M_F` and D-efficiency; per cell the failed count and mean / median of each
/// metric; the PSO runs' range; stage times; where it was written.
pub fn summary(out: &RunOutput, dir: &Path) {
    println!("{:<14} {:>10} {:>9}", "design", "ln det M_F", "D-eff");
    for (i, d) in out.designs.iter().enumerate() {
        println!("{:<14} {:>10.4} {:>9.4}", d.name, d.ln_det_mf, out.d_efficiency(i));
    }
    if !out.cells.is_empty() {
        println!();
        println!(
            "{:<14} {:>8} {:>7} {:>18} {:>18} {:>18}",
            "design", "sigma_nt", "failed", "eta_psi mean/med %", "eta_S mean/med %", "eta_O mean/med %"
        );
        for c in &out.cells {
            let s = c
                .summaries()
                .map(|(_, s)| format!("{:>9}/{:<8}", cell(s.mean), cell(s.median)));
            println!(
                "{:<14} {:>8} {:>7} {} {} {}",
                out.designs[c.design].name,
                c.sigma_nt,
                c.failed(),
                s[0],
                s[1],
                s[2]
            );
        }
    }
    if let Some(runs) = &out.pso_runs {
        let v: Vec<f64> = runs.iter().map(|r| -r.fitness).collect();
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        println!("\n{} PSO runs: final ln det M_F from {lo:.4} to {hi:.4}", v.len());
    }
    let times: Vec<String> = out.stages.iter().map(|(n, t)| format!("{n} {t:.3} s")).collect();
    println!("\ntimes: {}", times.join(", "));
    println!("written to {}", dir.display());
}
