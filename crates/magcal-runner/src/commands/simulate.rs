//! `magcal simulate SCENARIO --design NAME`: a log of a known sensor.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;

use super::Failure;
use crate::output::file::Output;
use crate::output::log_rows::SimulatedRow;
use crate::output::stderr::to_stderr;
use crate::output::{self, Real};

/// `magcal simulate`.
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// The scenario: its field, sensor (the truth to recover), box and designs.
    pub scenario: PathBuf,
    /// The design whose attitudes the log visits (each reading of a plan once).
    #[arg(long)]
    pub design: String,
    /// Noise per component, nT (default: the scenario's first `sigma_nt`).
    #[arg(long, value_parser = crate::limits::finite)]
    pub sigma_nt: Option<f64>,
    /// Seed of the noise (default: the scenario's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Write the log to this file, replaced whole (default, or `-`: standard output). Only a
    /// regular file or a missing path is replaced, and never the scenario.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Runs `simulate`: a log of noisy readings (nT) of the scenario's sensor at the attitudes of one
/// of its designs, `roll_deg,yaw_deg,pitch_deg,true_heading_deg,mx,my,mz`, to try `calibrate` on a known truth.
///
/// # Errors
/// A bad scenario, an unknown design, a bad noise level (exit 2).
pub fn run(args: &SimulateArgs) -> Result<(), Failure> {
    Ok(simulate_inner(args)?)
}

fn simulate_inner(args: &SimulateArgs) -> Result<()> {
    let target = Output::from_flag(args.out.as_deref());
    let inputs = [args.scenario.as_path()];
    target.check(&inputs)?;
    let scenario = crate::scenario::load(&args.scenario)?;
    let sigma = args.sigma_nt.unwrap_or(scenario.sigmas_nt[0]);
    if !(sigma.is_finite() && (0.0..=crate::limits::MAX_SIGMA_NT).contains(&sigma)) {
        bail!(
            "--sigma-nt {}: must lie in [0, {}] nT",
            crate::limits::show(sigma),
            crate::limits::show(crate::limits::MAX_SIGMA_NT)
        );
    }
    let Some(index) = scenario.designs.iter().position(|d| d.name == args.design) else {
        bail!(
            "{}: no design named {:?} (designs: {})",
            args.scenario.display(),
            args.design,
            scenario
                .designs
                .iter()
                .map(|d| d.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    };
    // Every design is built, so that each gets the random stream it gets in `magcal run`.
    let mut designs_only = scenario.clone();
    designs_only.pso_runs = None;
    let out = crate::pipeline::run(
        &designs_only,
        crate::pipeline::RunOptions {
            progress: &crate::pipeline::Quiet,
            designs_only: true,
        },
    )?;
    let attitudes = out.designs[index].expanded();
    let mut rng = crate::pipeline::simulated_log_rng(args.seed.unwrap_or(scenario.seed));
    let readings = scenario
        .truth
        .noisy_readings(&scenario.field.body_fields(&attitudes), sigma, &mut rng)?;
    let headings = crate::output::Headings::of(&scenario.field);
    let rows = attitudes.iter().zip(&readings).map(|(a, s)| {
        let [r, y, p] = a.to_degrees();
        SimulatedRow {
            roll_deg: Real(r),
            yaw_deg: Real(y),
            pitch_deg: Real(p),
            true_heading_deg: headings.true_heading(a),
            mx: Real(s[0]),
            my: Real(s[1]),
            mz: Real(s[2]),
        }
    });
    target.write(&inputs, |w| output::write_csv(rows, w))?;
    to_stderr!(
        "magcal: {} readings of design {:?} at {sigma} nT; the field magnitude is {} nT (calibrate with --magnitude {})",
        readings.len(),
        args.design,
        scenario.field.magnitude(),
        scenario.field.magnitude()
    );
    Ok(())
}
