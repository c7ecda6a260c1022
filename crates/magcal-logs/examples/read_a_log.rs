//! A log of any format read as `magcal calibrate` reads it, and fitted with the core.
//!
//! ```text
//! cargo run --release -p magcal-logs --example read_a_log -- LOG [COLUMNS]
//! cargo run --release -p magcal-logs --example read_a_log -- ../shared/data/px4/esc_status_log.ulg
//! cargo run --release -p magcal-logs --example read_a_log -- ../shared/data/ck-explorer/acc_mag_log.csv mx,my,mz
//! ```
//!
//! Prints what was read (format, units, columns, readings, time span, attitudes, notes) and the
//! full model's bias fitted to the readings' median magnitude: the fit is unit-free, so the
//! bias is in the log's units. A log of fewer than 9 readings is an error, and one that does not
//! determine the fit prints `usable: false`.

use magcal_core::log_fit::{self, FitModel};
use magcal_logs::source::{self, LogArgs};

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let path: std::path::PathBuf = args
        .next()
        .ok_or_else(|| anyhow::anyhow!("usage: read_a_log LOG [COLUMNS]"))?
        .into();
    let options = LogArgs {
        columns: args.next(),
        ..LogArgs::default()
    };
    let log = source::open(&path, &options, 0)?;

    println!(
        "{}: {:?}, {} readings of {}",
        path.display(),
        log.origin.format,
        log.readings.len(),
        log.columns.join(", ")
    );
    println!(
        "units: {}",
        log.origin
            .unit
            .map_or("not fixed by the format".to_string(), |u| format!("{u:?}"))
    );
    if let Some(t) = &log.times {
        println!("time: {:.3} to {:.3} s", t[0], t[t.len() - 1]);
    }
    if let Some(a) = &log.attitudes {
        println!("attitudes: {} of the readings have one", a.iter().flatten().count());
    }
    for note in &log.origin.notes {
        println!("note: {note}");
    }

    let mut norms: Vec<f64> = log
        .readings
        .iter()
        .map(|r| r.iter().map(|v| v * v).sum::<f64>().sqrt())
        .collect();
    norms.sort_by(f64::total_cmp);
    let magnitude = norms[norms.len() / 2];
    let fit = log_fit::fit(&log.readings, magnitude, FitModel::Full)?;
    println!(
        "bias at magnitude {magnitude:.6}: {:?} (std error {:?}); usable: {}",
        fit.bias, fit.std_bias, fit.usable
    );
    Ok(())
}
