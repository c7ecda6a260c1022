//! How often the held-out fits call a log's standard errors too small
//! (docs/conventions.md "Held out"): the median ratio of the held-out spread to the predicted
//! one ([`log_fit::HeldOut::ratio`]) on logs where the model is right, and where widening is
//! what [`log_fit::HELD_OUT_RATIO`] is for.
//!
//! ```text
//! cargo run --release -p magcal-core --example held_out_gate [-- LOGS]
//! ```
//!
//! Logs of \[P1\]'s sensor in the Changsha field, 30 nT of white noise:
//! - random attitudes (every attitude, and roll and pitch +-30 degrees), no times: folds of
//!   readings drawn at random;
//! - the same in time order (`Order::Time`): consecutive blocks;
//! - a plan flown attitude by attitude in time order (11 attitudes of the AUV box, the readings
//!   of each consecutive): blocks that hold out whole attitudes.
//!
//! Printed: per kind and size, the quantiles of the median ratio, and the share above the gate.

use magcal_core::design::sources;
use magcal_core::log_fit::{self, FitModel, FitSettings, Order};
use magcal_core::rng::stream_rng;
use magcal_core::{Attitude, AttitudeBox, Vec3, budget, paper};

fn readings(design: &[Attitude], seed: u64) -> Vec<Vec3> {
    let truth = paper::true_error_model();
    let mut rng = stream_rng(seed, 1);
    truth
        .noisy_readings(&paper::changsha_field().body_fields(design), paper::SIGMA_NT, &mut rng)
        .unwrap()
}

fn main() {
    let logs: u64 = std::env::args().nth(1).map_or(200, |s| s.parse().unwrap());
    let field = paper::changsha_field().magnitude();
    let every = AttitudeBox::full();
    let thirty = AttitudeBox::from_degrees([-30.0, 30.0], [-180.0, 180.0], [-30.0, 30.0]).unwrap();
    println!(
        "| log | order | m | logs with evidence | median ratio p50 | p90 | p95 | p99 | share above {} |",
        log_fit::HELD_OUT_RATIO
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for (name, bounds, plan) in [
        ("random, every attitude", &every, false),
        ("random, roll and pitch +-30", &thirty, false),
        ("plan of 11 attitudes, AUV box", &paper::auv_box(), true),
    ] {
        for order in [Order::Unknown, Order::Time] {
            if plan && order == Order::Unknown {
                continue;
            }
            for m in [30usize, 100, 300, 1000] {
                let mut ratios = Vec::new();
                for seed in 0..logs {
                    let design: Vec<Attitude> = if plan {
                        let mut rng = stream_rng(seed, 2);
                        let at = sources::random(bounds, 11, &mut rng);
                        (0..m).map(|i| at[i * 11 / m]).collect()
                    } else {
                        let mut rng = stream_rng(seed, 2);
                        sources::random(bounds, m, &mut rng)
                    };
                    let settings = FitSettings {
                        order,
                        trials: 0,
                        ..FitSettings::default()
                    };
                    let Ok(f) = log_fit::fit_with(&readings(&design, seed), field, FitModel::Full, &settings) else {
                        continue;
                    };
                    if let Some(r) = f.held_out.and_then(|h| h.ratio()) {
                        ratios.push(r);
                    }
                }
                let n = ratios.len();
                let above = ratios.iter().filter(|r| **r > log_fit::HELD_OUT_RATIO).count();
                let q = |p: f64| budget::quantile(&mut ratios.clone(), p);
                println!(
                    "| {name} | {} | {m} | {n} of {logs} | {:.2} | {:.2} | {:.2} | {:.2} | {:.3} |",
                    if order == Order::Time { "time" } else { "none" },
                    q(0.5),
                    q(0.9),
                    q(0.95),
                    q(0.99),
                    above as f64 / n.max(1) as f64
                );
            }
        }
    }
}
