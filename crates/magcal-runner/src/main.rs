//! `magcal`: the command line over `magcal-core`.
//!
//! The scenario runner (scenario files -> designs -> Monte Carlo trials -> CSV) is being built;
//! see README.md "Status". Until it lands this binary prints the \[P1\] check values that the core
//! reproduces, so that the command in the README does real work.

use std::process::ExitCode;

use magcal_core::{Conditioning, paper};

fn main() -> ExitCode {
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    println!(
        "magcal {}: the scenario runner is not built yet (README.md, Status).",
        env!("CARGO_PKG_VERSION")
    );
    println!("Reference field R = {:.2} nT", field.magnitude());
    for (name, design, offset) in [
        ("uniform (Table II)", paper::uniformity_design(), 0.0),
        ("table2_dopt (Table II, as printed)", paper::table2_d_optimal(), 0.0),
        ("uniform, yaw_offset_deg = 90", paper::uniformity_design(), 90.0),
    ] {
        let field = match field.with_yaw_offset_deg(offset) {
            Ok(f) => f,
            Err(e) => {
                eprintln!("error: {e}");
                return ExitCode::from(2);
            }
        };
        let readings = truth.measure_all(&field.body_fields(&design));
        let c = Conditioning::of_readings(&readings, field.magnitude());
        println!(
            "{name:<36} ln det M_F = {:.4}  cond_2(H) = {:.4e}",
            c.ln_det_mf, c.cond_h
        );
    }
    ExitCode::SUCCESS
}
