//! `magcal next CAL.json LOG`: the attitudes to visit next.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use magcal_core::log_fit;

use crate::cli::Failure;
use crate::log::calibration::read_calibration;
use crate::log::read as log_file;
use crate::log::vehicle::{BoxFlags, Vehicle, fitted_problem};

/// `magcal next`.
#[derive(Debug, Args)]
pub struct NextArgs {
    /// A calibration.json written by `magcal calibrate --out` (or its `--json` output).
    pub calibration: PathBuf,
    /// The log it was fitted to.
    pub log: PathBuf,
    /// A scenario file giving the vehicle's attitude box (`[attitude_box]`), the site
    /// (`[field]`, for the field's direction) and the search (`[certificate]`); or the flags
    /// below.
    #[arg(long, required_unless_present = "site", conflicts_with = "site")]
    pub scenario: Option<PathBuf>,
    #[command(flatten)]
    pub attitude: BoxFlags,
    /// The site, `LAT,LON[,ALT_M]`, for the field's direction from the World Magnetic Model; needs
    /// `--date`, `--roll` and `--pitch`.
    #[arg(long, requires_all = ["date", "roll", "pitch"], allow_hyphen_values = true)]
    pub site: Option<String>,
    /// The date, `YYYY-MM-DD` or a decimal year (with `--site`).
    #[arg(long)]
    pub date: Option<String>,
    /// The model (default: the newest whose window holds the date).
    #[arg(long, requires = "site")]
    pub wmm: Option<String>,
    /// Attitudes to suggest, 1 to 1000.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub count: u64,
    /// As for `calibrate`.
    #[arg(long)]
    pub columns: Option<String>,
    /// As for `calibrate`.
    #[arg(long)]
    pub skip_bad: bool,
}

/// per reading before and after.
///
/// # Errors
/// A bad calibration, log or scenario (exit 2).
/// Runs `next`: the attitudes that most increase the information of the log (D-optimal
/// augmentation under the fitted model), with the standard errors and the certified D-efficiency
/// per reading before and after.
///
/// # Errors
/// A bad calibration, log or scenario (exit 2).
pub fn run(args: &NextArgs) -> Result<(), Failure> {
    Ok(next_inner(args)?)
}

fn next_inner(args: &NextArgs) -> Result<()> {
    use magcal_core::{CramerRao, InformationMatrix, PhysicalScales};
    let shown = args.calibration.display().to_string();
    let cal = read_calibration(&args.calibration)?;
    let scenario = Vehicle::from_options(
        args.scenario.as_deref(),
        &args.attitude,
        [&args.site, &args.date, &args.wmm].map(|a| a.as_deref()),
    )?
    .context("next needs --scenario, or the box as flags with --site and --date")?;
    let log = log_file::read(&args.log, args.columns.as_deref(), args.skip_bad)?;
    if !cal.identifiable {
        eprintln!(
            "magcal: warning: {shown} is not identifiable ({}); the suggestions assume its fitted sensor",
            cal.verdict
        );
    }
    // The log's units to the scenario field's (nT): only the field's direction comes from the site.
    let field = scenario.field;
    let (problem, factor) = fitted_problem(&cal, &scenario).with_context(|| shown.clone())?;
    let model = *problem.model();
    let readings: Vec<magcal_core::Vec3> = log.readings.iter().map(|s| s.map(|v| v * factor)).collect();
    let r = field.magnitude();
    let before = InformationMatrix::from_readings(&readings, r);
    let chosen = scenario
        .certificate
        .augment(&problem, before.matrix(), args.count as usize)
        .with_context(|| format!("{}: the log's information is singular", args.log.display()))?;
    let attitudes: Vec<magcal_core::Attitude> = chosen.iter().map(|c| c.0).collect();
    let added = model.measure_all(&field.body_fields(&attitudes));
    let all: Vec<magcal_core::Vec3> = readings.iter().chain(&added).copied().collect();
    let after = InformationMatrix::from_readings(&all, r);
    let certificate = scenario.certificate(&problem);
    let efficiency = |info: &InformationMatrix, m: usize| {
        certificate
            .as_ref()
            .map_or(f64::NAN, |c| c.efficiency_bound(info.ln_det_nt(), m))
    };
    // Standard errors under the fitted model, noise from the residuals.
    let body_log: Vec<magcal_core::Vec3> = log.readings.iter().map(|s| cal.apply(*s).map(|v| v * factor)).collect();
    let body_all: Vec<magcal_core::Vec3> = body_log.iter().copied().chain(field.body_fields(&attitudes)).collect();
    let sigma = cal
        .noise
        .ok_or_else(|| anyhow::anyhow!("{shown}: the calibration's noise is unknown (calibrate with --noise)"))?
        * factor;
    let scales = PhysicalScales::default();
    let (crb_before, crb_after) = (
        CramerRao::new(&model, &body_log, sigma, &scales),
        CramerRao::new(&model, &body_all, sigma, &scales),
    );
    println!(
        "{} readings of {}; the next {} attitudes in the box of {} (D-optimal augmentation under the fitted model):",
        log.readings.len(),
        args.log.display(),
        args.count,
        scenario.label
    );
    // The same attitude chosen again is one row with its readings.
    let mut rows: Vec<(magcal_core::Attitude, usize, f64)> = Vec::new();
    for (a, d) in &chosen {
        match rows.last_mut() {
            Some(last) if magcal_core::design::tour::rotation_angle(&last.0, a) < 1e-6 => last.1 += 1,
            _ => rows.push((*a, 1, *d)),
        }
    }
    println!(
        "  {:>4} {:>9} {:>9} {:>11} {:>8} {:>12}",
        "k", "roll_deg", "pitch_deg", "heading_deg", "readings", "variance d"
    );
    for (k, (a, n, d)) in rows.iter().enumerate() {
        let [roll, yaw, pitch] = a.to_degrees();
        println!(
            "  {:>4} {:>9.2} {:>9.2} {:>11.2} {:>8} {:>12.4}",
            k + 1,
            roll,
            pitch,
            (-(yaw + field.yaw_offset_deg())).rem_euclid(360.0),
            n,
            d
        );
    }
    let names = magcal_core::identifiability::PARAMETERS;
    println!(
        "\n  {:<10} {:>14} {:>14}  (bias in the log's units)",
        "parameter", "std before", "std after"
    );
    for i in 0..9 {
        let unit = if i >= 6 { 1.0 / factor } else { 1.0 };
        let show = |c: &CramerRao| c.std.map_or("singular".to_string(), |s| format!("{:.4e}", s[i] * unit));
        let name = names[i].trim_end_matches("_nt");
        println!("  {name:<10} {:>14} {:>14}", show(&crb_before), show(&crb_after));
    }
    let m = log.readings.len();
    let show = |e: f64| {
        if e >= 1e-3 {
            format!("{e:.4}")
        } else {
            format!("{e:.3e}")
        }
    };
    println!(
        "\ncertified D-efficiency per reading in this box: before {}, after {} (against every design of as many readings)",
        show(efficiency(&before, m)),
        show(efficiency(&after, m + attitudes.len()))
    );
    println!(
        "coverage: MotionCal gaps before {:.1} %, after {:.1} %; MicroStrain spatial coverage before {:.1} %, after {:.1} %",
        log_fit::motioncal_gaps(&body_log),
        log_fit::motioncal_gaps(&body_all),
        log_fit::microstrain_coverage_percent(&body_log),
        log_fit::microstrain_coverage_percent(&body_all)
    );
    println!(
        "identifiable: before {}, after {}",
        crb_before.verdict.identifiable, crb_after.verdict.identifiable
    );
    Ok(())
}
