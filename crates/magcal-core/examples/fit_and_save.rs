//! A calibration of a known sensor, fitted from noisy readings over the D-optimal design of
//! \[P1\]'s box and saved: the fit's estimates and standard errors as JSON (every public result
//! of the core is `serde::Serialize`), and the sensor model read back.
//!
//! ```text
//! cargo run --release -p magcal-core --example fit_and_save [-- OUT.json]
//! ```
//!
//! Prints the true and fitted bias with its standard error, and writes the fit (default
//! `fit.json` in the temporary directory).

use magcal_core::log_fit::{self, FitModel};
use magcal_core::{ErrorModel, design::replicated, paper, rng::stream_rng};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .map_or_else(|| std::env::temp_dir().join("fit.json"), Into::into);
    // The paper's site, sensor and box, \[P1\] section IV.A; the D-optimal design of its box
    // (docs/conventions.md) flown 20 times over.
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    let attitudes = replicated(&paper::conventions_optimum(), &[20; 9]);
    let body = field.body_fields(&attitudes);
    let readings = truth.noisy_readings(&body, paper::SIGMA_NT, &mut stream_rng(7, 0))?;

    let fit = log_fit::fit(&readings, field.magnitude(), FitModel::Full)?;
    println!("true bias, nT:   {:?}", truth.bias_nt());
    println!("fitted bias, nT: {:?}", fit.bias);
    println!("its std error:   {:?}", fit.std_bias);
    println!("usable: {} ({} readings)", fit.usable, readings.len());

    std::fs::write(&out, serde_json::to_string_pretty(&fit)?)?;
    // The sensor model alone reads back as it was written, bit for bit.
    let model: ErrorModel = serde_json::from_str(&serde_json::to_string(&fit.errors)?)?;
    assert_eq!(model, fit.errors);
    println!("wrote {}", out.display());
    Ok(())
}
