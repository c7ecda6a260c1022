//! `magcal calibrate LOG` and `magcal apply CAL.json LOG`: fit a log, and calibrate readings with
//! the fit (CONVENTIONS.md "Real data" and its calibration forms).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use magcal_core::log_fit::{self, FitModel, LogFit};
use magcal_core::small::{Mat3, upper_triangular_inverse};
use serde::{Deserialize, Serialize};

use crate::cli::Failure;
use crate::log_file;

/// `--fit`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Fit {
    /// The paper's model: non-orthogonality, scale factors and bias (9 parameters).
    Full,
    /// Scale factors and bias (6).
    Diagonal,
    /// Bias and one common scale factor (4).
    Offset,
    /// The richest model this log identifies.
    Auto,
}

impl Fit {
    /// The fit of `readings` to `magnitude` under this choice, with the reason for `auto`.
    fn fit(
        self,
        readings: &[magcal_core::Vec3],
        magnitude: f64,
    ) -> Result<(LogFit, Option<String>), magcal_core::CalibrationError> {
        let model = match self {
            Fit::Auto => return log_fit::fit_auto(readings, magnitude).map(|(f, why)| (f, Some(why))),
            Fit::Full => FitModel::Full,
            Fit::Diagonal => FitModel::Diagonal,
            Fit::Offset => FitModel::Offset,
        };
        log_fit::fit_tested(readings, magnitude, model).map(|f| (f, None))
    }
}

/// `--units`: the log's units, for a magnitude from the WMM (nT).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Units {
    /// Nanotesla.
    #[value(name = "nT")]
    NanoTesla,
    /// Microtesla.
    #[value(name = "uT")]
    MicroTesla,
    /// Milligauss (100 nT).
    #[value(name = "mG")]
    MilliGauss,
    /// Gauss (100,000 nT).
    #[value(name = "G")]
    Gauss,
}

impl Units {
    /// nT per unit.
    fn nt(self) -> f64 {
        match self {
            Self::NanoTesla => 1.0,
            Self::MicroTesla => 1e3,
            Self::MilliGauss => 1e2,
            Self::Gauss => 1e5,
        }
    }
}

/// The WMM magnitude at `--site` on `--date` in `--units`, and its source in words.
fn wmm_magnitude(site: &str, date: &str, units: Units, model: Option<&str>) -> Result<(f64, String)> {
    let (v, source) = wmm_field(site, date, model)?;
    let nt = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    Ok((nt / units.nt(), source))
}

/// The WMM field (North, East, Down, nT) at `site` (`LAT,LON[,ALT_M]`) on `date`, by `model` or
/// the newest whose window holds the date, and its source in words.
fn wmm_field(site: &str, date: &str, model: Option<&str>) -> Result<([f64; 3], String)> {
    use magcal_core::wmm;
    let numbers: Vec<f64> = site
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--site {site:?}: give LAT,LON or LAT,LON,ALT_M in numbers"))?;
    let (lat, lon, alt) = match numbers[..] {
        [lat, lon] => (lat, lon, 0.0),
        [lat, lon, alt] => (lat, lon, alt),
        _ => bail!("--site {site:?}: give LAT,LON or LAT,LON,ALT_M"),
    };
    let year = decimal_year(date)?;
    let site = wmm::Site {
        lat_deg: lat,
        lon_deg: lon,
        alt_m: alt,
        year,
    };
    let candidates: Vec<wmm::Model> = match model {
        Some(name) => vec![wmm::Model::from_name(name).with_context(|| {
            let known: Vec<&str> = wmm::Model::ALL.iter().map(|m| m.name()).collect();
            format!("--wmm {name:?}: unknown model; known: {}", known.join(", "))
        })?],
        None => wmm::Model::ALL.iter().rev().copied().collect(),
    };
    let mut last = None;
    for m in candidates {
        match wmm::field_ned(m, &site) {
            Ok(v) => {
                let nt = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                return Ok((
                    v,
                    format!("{} at {lat}, {lon}, {alt} m, {year:.3}: {nt:.1} nT", m.name()),
                ));
            }
            Err(e) => last = Some(e),
        }
    }
    bail!(
        "--site {lat},{lon},{alt} --date {date}: no model holds it ({})",
        last.map_or(String::new(), |e| e.to_string())
    )
}

/// `YYYY-MM-DD` (the middle of that day) or a decimal year.
fn decimal_year(date: &str) -> Result<f64> {
    if let Ok(y) = date.trim().parse::<f64>() {
        return Ok(y);
    }
    let parts: Vec<i64> = date
        .split('-')
        .map(|v| v.parse::<i64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--date {date:?}: give YYYY-MM-DD or a decimal year"))?;
    let [y, m, d] = parts[..] else {
        bail!("--date {date:?}: give YYYY-MM-DD or a decimal year");
    };
    let leap = (y % 4 == 0 && y % 100 != 0) || y % 400 == 0;
    let month_days = [31, if leap { 29 } else { 28 }, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31];
    if !(1..=12).contains(&m) || d < 1 || d > month_days[(m - 1) as usize] {
        bail!("--date {date:?}: not a date");
    }
    let day_of_year: i64 = month_days[..(m - 1) as usize].iter().sum::<i64>() + d;
    let days = if leap { 366.0 } else { 365.0 };
    Ok(y as f64 + (day_of_year as f64 - 0.5) / days)
}

/// `magcal calibrate`.
#[derive(Debug, Args)]
pub struct CalibrateArgs {
    /// The log: a CSV file, one reading per row.
    pub log: PathBuf,
    /// The three columns, by name or 1-based index: `mx,my,mz` or `4,5,6` (default: x, y, z with
    /// or without an m prefix, else the first three numeric columns).
    #[arg(long)]
    pub columns: Option<String>,
    /// The field magnitude in the log's units (default: the fitted mean radius, and scale factors
    /// relative to it).
    #[arg(long, conflicts_with = "units")]
    pub magnitude: Option<f64>,
    /// The magnitude from the World Magnetic Model at a site: `LAT,LON[,ALT_M]` (WGS 84 degrees,
    /// metres above the ellipsoid; default 0); needs `--date`, and `--units` unless `--magnitude`
    /// gives the magnitude (the site then serves the box flags' field direction only).
    #[arg(long, requires = "date")]
    pub site: Option<String>,
    /// The date of the log: `YYYY-MM-DD` or a decimal year.
    #[arg(long)]
    pub date: Option<String>,
    /// The log's units.
    #[arg(long, value_enum)]
    pub units: Option<Units>,
    /// The model (default: the newest whose five-year window holds the date): WMM2010, WMM2015,
    /// WMM2015v2, WMM2020, WMM2025.
    #[arg(long, requires = "site")]
    pub wmm: Option<String>,
    /// The model.
    #[arg(long, value_enum, default_value = "full")]
    pub fit: Fit,
    /// Drop rows with a non-finite or missing value, counting them (default: such a row is an
    /// error).
    #[arg(long)]
    pub skip_bad: bool,
    /// Drop readings whose `|calibrated| - R` lies more than K robust standard deviations
    /// (1.4826 median absolute deviations) from the median, refit, and repeat until the kept set
    /// does not change; `rejected` counts them. Off by default.
    #[arg(long, value_name = "K")]
    pub reject: Option<f64>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Also write DIR/calibration.json and DIR/residuals.csv.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// A scenario file whose attitude box and site give the coverage its D-efficiency: the log's
    /// information per reading against every design of as many readings in that box; or the box
    /// as flags (`--roll` and `--pitch`, with `--site` and `--date`).
    #[arg(long, conflicts_with_all = ["roll", "pitch", "yaw"])]
    pub scenario: Option<PathBuf>,
    #[command(flatten)]
    pub attitude: BoxFlags,
}

/// `magcal apply`.
#[derive(Debug, Args)]
pub struct ApplyArgs {
    /// A calibration.json written by `magcal calibrate --out` (or its `--json` output).
    pub calibration: PathBuf,
    /// The log to calibrate.
    pub log: PathBuf,
    /// As for `calibrate`.
    #[arg(long)]
    pub columns: Option<String>,
    /// As for `calibrate`: rows with a non-finite or missing value are dropped, and each is named
    /// on stderr.
    #[arg(long)]
    pub skip_bad: bool,
    /// Write the calibrated readings here (default: stdout).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

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

/// A vehicle's attitude box as flags (with `--site` and `--date` for the field's direction).
#[derive(Debug, Args)]
pub struct BoxFlags {
    /// Roll range, degrees: `MIN,MAX` (with `--site`).
    #[arg(long, requires = "site", allow_hyphen_values = true)]
    pub roll: Option<String>,
    /// Pitch range, degrees: `MIN,MAX` (with `--site`).
    #[arg(long, requires = "site", allow_hyphen_values = true)]
    pub pitch: Option<String>,
    /// Yaw range, degrees: `MIN,MAX` (with `--site`; default any yaw).
    #[arg(long, requires = "site", allow_hyphen_values = true)]
    pub yaw: Option<String>,
}

/// `magcal simulate`.
#[derive(Debug, Args)]
pub struct SimulateArgs {
    /// The scenario: its field, sensor (the truth to recover), box and designs.
    pub scenario: PathBuf,
    /// The design whose attitudes the log visits (each reading of a plan once).
    #[arg(long)]
    pub design: String,
    /// Noise per component, nT (default: the scenario's first `sigma_nt`).
    #[arg(long)]
    pub sigma_nt: Option<f64>,
    /// Seed of the noise (default: the scenario's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Write the log here (default: stdout).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Standard errors of the fitted parameters; `null` where the information is singular.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StdError {
    pub psi_deg: Option<[f64; 3]>,
    pub scale: Option<[f64; 3]>,
    pub bias: Option<[f64; 3]>,
}

/// `calibration.json` and the `--json` output.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CalibrationJson {
    pub log: String,
    pub columns: [String; 3],
    pub samples: usize,
    pub skipped: usize,
    /// Readings dropped by `--reject` (0 without it).
    pub rejected: usize,
    pub fit: String,
    /// With `--fit auto`: why this model.
    pub fit_reason: Option<String>,
    pub magnitude: f64,
    /// `given`, `fitted mean radius (...)` or `radius of the best-fitting sphere (...)`.
    pub magnitude_source: String,
    pub bias: [f64; 3],
    pub psi_deg: [f64; 3],
    pub scale: [f64; 3],
    /// `K = P^-1`: raw = K b + bias.
    pub k: Mat3,
    /// `b = P (raw - bias)`, upper triangular (\[P1\] eq. (6)).
    pub p: Mat3,
    /// `b = A^-1 (raw - bias)` with `A^-1` the symmetric square root of `G = P^T P` (Magneto,
    /// MotionCal, ArduPilot).
    pub soft_iron_inverse: Mat3,
    pub residual_rms: f64,
    pub residual_max: f64,
    pub residual_rms_percent: f64,
    /// The noise per component estimated from the residuals, in the log's units.
    pub noise: f64,
    pub std_error: StdError,
    pub identifiable: bool,
    pub verdict: String,
    /// For a reduced model (`diagonal`, `offset`): its lack-of-fit F test against the richer
    /// models fitted to the same readings (`null` for `full`).
    pub lack_of_fit: Option<LackOfFitJson>,
    pub status: String,
    pub iterations: usize,
    pub coverage: Coverage,
}

/// [`log_fit::LackOfFit`] in the JSON.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LackOfFitJson {
    /// The richer model of the most significant test.
    pub against: String,
    pub f: f64,
    /// `[p_f - p_r, m - p_f]`.
    pub dof: [usize; 2],
    pub p_value: f64,
    /// `p_value` (Bonferroni over the richer models tested) below 1e-3: the log shows terms the
    /// model leaves out.
    pub rejected: bool,
    /// The test in words.
    pub words: String,
}

/// How well the log covers what the sensor can see.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Coverage {
    /// MotionCal's surface-gap error of the calibrated field directions, percent (0: every one of
    /// 100 equal-area regions holds at least three readings; 100: none).
    pub motioncal_gap_percent: f64,
    /// MicroStrain's spatial coverage of the calibrated field directions, percent: the share of
    /// 18 x 32 bins of 10 degrees of latitude by 11.25 of longitude holding at least one
    /// (MicroStrain calls more than 70 % good).
    pub microstrain_coverage_percent: f64,
    /// With `--scenario`: the certified D-efficiency per reading of the log's information against
    /// every design of as many readings in the scenario's box, under the fitted sensor.
    pub d_efficiency_per_reading: Option<f64>,
    /// The scenario that gave the box.
    pub box_from: Option<String>,
}

/// What `next` and the coverage need of a vehicle: its site's field (nT), its attitude box, the
/// certificate's search and a seed; from a scenario file or from flags.
struct Vehicle {
    field: magcal_core::ReferenceField,
    bounds: magcal_core::AttitudeBox,
    certificate: magcal_core::design::approximate::Approximate,
    seed: u64,
    label: String,
}

impl Vehicle {
    /// The certificate of the vehicle's box under `problem`'s sensor, from the stream `run` uses
    /// for the same seed; `None` when no design in the box identifies the linear model.
    fn certificate(
        &self,
        problem: &magcal_core::design::DesignProblem,
    ) -> Option<magcal_core::design::approximate::Certificate> {
        self.certificate
            .compute(problem, &mut crate::pipeline::certificate_rng(self.seed))
            .ok()
            .map(|a| a.certificate)
    }

    fn from_scenario(path: &Path) -> Result<Self> {
        let s = crate::scenario::load(path)?;
        Ok(Self {
            field: s.field,
            bounds: s.bounds,
            certificate: s.certificate,
            seed: s.seed,
            label: path.display().to_string(),
        })
    }

    /// The vehicle of `--scenario`, else of the box flags with `[--site, --date, --wmm]`; `None`
    /// when neither is given.
    fn from_options(
        scenario: Option<&Path>,
        flags: &BoxFlags,
        [site, date, wmm]: [Option<&str>; 3],
    ) -> Result<Option<Self>> {
        match (scenario, &flags.roll, &flags.pitch, &flags.yaw) {
            (Some(path), ..) => Self::from_scenario(path).map(Some),
            (None, Some(_), Some(_), _) => {
                Self::from_flags(flags, site.unwrap_or(""), date.unwrap_or(""), wmm).map(Some)
            }
            (None, None, None, None) => Ok(None),
            _ => bail!("the box as flags needs both --roll and --pitch"),
        }
    }

    /// `--roll, --pitch [--yaw] --site --date [--wmm]`.
    fn from_flags(args: &BoxFlags, site: &str, date: &str, wmm: Option<&str>) -> Result<Self> {
        let range = |name: &str, value: Option<&String>, default: [f64; 2]| -> Result<[f64; 2]> {
            let Some(text) = value else { return Ok(default) };
            let v: Vec<f64> = text
                .split(',')
                .map(|x| x.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|_| anyhow::anyhow!("--{name} {text:?}: give MIN,MAX in degrees"))?;
            match v[..] {
                [a, b]
                    if a.is_finite()
                        && b.is_finite()
                        && a < b
                        && b - a <= 360.0
                        && a.abs() <= 360.0
                        && b.abs() <= 360.0 =>
                {
                    Ok([a, b])
                }
                _ => bail!(
                    "--{name} {text:?}: give MIN,MAX in degrees, MIN < MAX, at most 360 apart, each in [-360, 360]"
                ),
            }
        };
        let roll = range("roll", args.roll.as_ref(), [0.0, 0.0])?;
        let pitch = range("pitch", args.pitch.as_ref(), [0.0, 0.0])?;
        let yaw = range("yaw", args.yaw.as_ref(), [-180.0, 180.0])?;
        let bounds = magcal_core::AttitudeBox::from_degrees(roll, yaw, pitch).context("the attitude box")?;
        let (ned, source) = wmm_field(site, date, wmm)?;
        let field = magcal_core::ReferenceField::from_ned(ned[0], ned[1], ned[2]).context("the WMM field")?;
        Ok(Self {
            field,
            bounds,
            certificate: Default::default(),
            seed: 0,
            label: format!("roll {roll:?}, pitch {pitch:?}, yaw {yaw:?} deg, {source}"),
        })
    }
}

/// The fitted sensor as a design problem in the vehicle's field (nT) and box, and the factor from
/// the log's units to nT (only the field's direction comes from the site).
fn fitted_problem(cal: &CalibrationJson, scenario: &Vehicle) -> Result<(magcal_core::design::DesignProblem, f64)> {
    let field = scenario.field;
    let factor = field.magnitude() / cal.magnitude;
    if !(factor.is_finite() && factor > 0.0) {
        bail!("magnitude {} is not usable", cal.magnitude);
    }
    let model = magcal_core::ErrorModel::new(cal.psi_deg, cal.scale, cal.bias.map(|b| b * factor))
        .context("the fitted sensor is outside what the model takes")?;
    Ok((
        magcal_core::design::DesignProblem::new(field, model, scenario.bounds, 9)?,
        factor,
    ))
}

/// The certified D-efficiency per reading of `readings` (the log's units) in the scenario's box.
fn log_efficiency(cal: &CalibrationJson, scenario: &Vehicle, readings: &[magcal_core::Vec3]) -> Result<Option<f64>> {
    let (problem, factor) = fitted_problem(cal, scenario)?;
    let scaled: Vec<magcal_core::Vec3> = readings.iter().map(|s| s.map(|v| v * factor)).collect();
    let info = magcal_core::InformationMatrix::from_readings(&scaled, scenario.field.magnitude());
    Ok(scenario
        .certificate(&problem)
        .map(|c| c.efficiency_bound(info.ln_det_nt(), readings.len())))
}

impl CalibrationJson {
    /// The calibrated field of a raw reading: `P (raw - bias)`.
    fn apply(&self, raw: magcal_core::Vec3) -> magcal_core::Vec3 {
        magcal_core::small::mat_vec(&self.p, magcal_core::small::sub(raw, self.bias))
    }
}

/// Runs `calibrate`.
///
/// # Errors
/// A bad log or option (exit 2), or a log that no model fits.
pub fn run(args: &CalibrateArgs) -> Result<(), Failure> {
    let mut log = log_file::read(&args.log, args.columns.as_deref(), args.skip_bad)?;
    let rejected = match args.reject {
        Some(k) if k.is_finite() && k > 0.0 => reject(&mut log, k, args.fit)?,
        Some(k) => return Err(anyhow::anyhow!("--reject {k}: must be positive and finite").into()),
        None => 0,
    };
    if let Some(r) = args.magnitude
        && !(r.is_finite() && r > 0.0)
    {
        return Err(anyhow::anyhow!("--magnitude {r}: must be positive and finite").into());
    }
    let shown = args.log.display().to_string();
    let fit_with = |magnitude: f64| -> Result<(LogFit, Option<String>)> {
        args.fit
            .fit(&log.readings, magnitude)
            .with_context(|| format!("{shown}: no calibration ({} readings)", log.readings.len()))
    };
    let wmm = match (&args.site, &args.date, args.units) {
        (Some(site), Some(date), Some(units)) => Some(wmm_magnitude(site, date, units, args.wmm.as_deref())?),
        (Some(_), _, None) if args.magnitude.is_none() => {
            return Err(
                anyhow::anyhow!("--site: give --units (the log's) for the WMM magnitude, or --magnitude").into(),
            );
        }
        _ => None,
    };
    let given = args.magnitude.map(|r| (r, "given".to_string())).or(wmm);
    let (fit, why, source) = match given {
        Some((r, source)) => {
            // A magnitude in other units than the log's (0.49 for a log in nT) still fits, with
            // scale factors 1e5 away from 1: say so before they are read as a calibration.
            if let Some(radius) = log_fit::sphere_radius(&log.readings)
                && !(1e-2..=1e2).contains(&(radius / r))
            {
                eprintln!(
                    "magcal: warning: {shown}: the readings lie about {radius:.6e} from their centre, {:.1e} times the magnitude {r} ({source}); are they in the same units?",
                    radius / r
                );
            }
            let (f, why) = fit_with(r)?;
            (f, why, source)
        }
        None => {
            // The fitted mean radius: the geometric mean of the scale factors of a fit to a unit
            // field, so that the scale factors are relative with product 1; when that fit is not
            // determined, the radius of the best-fitting sphere.
            let (unit, _) = fit_with(1.0)?;
            let (radius, source) = if unit.identifiable {
                let s = unit.errors.scale();
                (
                    (s[0] * s[1] * s[2]).cbrt(),
                    "fitted mean radius (scale factors are relative to it, product 1)",
                )
            } else {
                (
                    log_fit::sphere_radius(&log.readings)
                        .with_context(|| format!("{shown}: no sphere fits the readings"))?,
                    "radius of the best-fitting sphere (scale factors are relative to it)",
                )
            };
            let (f, why) = fit_with(radius)?;
            (f, why, source.to_string())
        }
    };
    let mut json = to_json(&args.log, &log, &fit, why, source);
    json.rejected = rejected;
    let vehicle = Vehicle::from_options(
        args.scenario.as_deref(),
        &args.attitude,
        [&args.site, &args.date, &args.wmm].map(|a| a.as_deref()),
    )?;
    if let Some(vehicle) = &vehicle {
        json.coverage.d_efficiency_per_reading = log_efficiency(&json, vehicle, &log.readings)
            .with_context(|| format!("{}: coverage in {}", args.log.display(), vehicle.label))?;
        json.coverage.box_from = Some(vehicle.label.clone());
    }
    if let Some(dir) = &args.out {
        write_out(dir, &json, &log, &fit)?;
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&json).context("JSON")?);
    } else {
        print_table(&json);
    }
    Ok(())
}

/// Rounds of `--reject`: fit the kept readings (to a unit field: the residuals are relative),
/// keep every reading within `k` robust standard deviations of the median residual, until the kept
/// set is stable (at most 100 rounds). Returns how many were dropped; `log` keeps the rest.
fn reject(log: &mut log_file::Log, k: f64, model: Fit) -> Result<usize> {
    let all = std::mem::take(&mut log.readings);
    let lines = std::mem::take(&mut log.lines);
    let mut keep = vec![true; all.len()];
    for _ in 0..100 {
        let kept: Vec<magcal_core::Vec3> = all.iter().zip(&keep).filter(|(_, k)| **k).map(|(s, _)| *s).collect();
        let (fit, _) = model
            .fit(&kept, 1.0)
            .with_context(|| format!("--reject {k}: no calibration of the {} readings kept", kept.len()))?;
        let r: Vec<f64> = all
            .iter()
            .map(|s| magcal_core::small::norm(fit.apply(*s)) - 1.0)
            .collect();
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let centre = median(&mut r.clone());
        let spread = 1.4826 * median(&mut r.iter().map(|x| (x - centre).abs()).collect());
        let next: Vec<bool> = r.iter().map(|x| (x - centre).abs() <= k * spread).collect();
        if next == keep {
            break;
        }
        keep = next;
    }
    for ((s, line), k) in all.into_iter().zip(lines).zip(&keep) {
        if *k {
            log.readings.push(s);
            log.lines.push(line);
        }
    }
    Ok(keep.iter().filter(|k| !**k).count())
}

fn to_json(path: &Path, log: &log_file::Log, fit: &LogFit, why: Option<String>, source: String) -> CalibrationJson {
    let fields: Vec<magcal_core::Vec3> = log.readings.iter().map(|s| fit.apply(*s)).collect();
    let k = upper_triangular_inverse(&fit.p).unwrap_or([[f64::NAN; 3]; 3]);
    CalibrationJson {
        log: path.display().to_string(),
        columns: log.columns.clone(),
        samples: log.readings.len(),
        skipped: log.skipped.len(),
        rejected: 0,
        fit: fit.model.as_str().to_string(),
        fit_reason: why,
        magnitude: fit.magnitude,
        magnitude_source: source,
        bias: fit.bias,
        psi_deg: fit.errors.psi_deg(),
        scale: fit.errors.scale(),
        k,
        p: fit.p,
        soft_iron_inverse: fit.soft_iron_inverse(),
        residual_rms: fit.residual_rms,
        residual_max: fit.residual_max,
        residual_rms_percent: 100.0 * fit.residual_rms / fit.magnitude,
        noise: fit.noise,
        std_error: StdError {
            psi_deg: fit.std_psi_deg,
            scale: fit.std_scale,
            bias: fit.std_bias,
        },
        identifiable: fit.identifiable,
        verdict: fit.verdict.clone(),
        lack_of_fit: fit.lack_of_fit.as_ref().map(|t| LackOfFitJson {
            against: t.against.as_str().to_string(),
            f: t.f,
            dof: [t.dof.0, t.dof.1],
            p_value: t.p_value,
            rejected: t.rejected,
            words: t.words(),
        }),
        status: fit.status.as_str().to_string(),
        iterations: fit.iterations,
        coverage: Coverage {
            motioncal_gap_percent: log_fit::motioncal_gaps(&fields),
            microstrain_coverage_percent: log_fit::microstrain_coverage_percent(&fields),
            d_efficiency_per_reading: None,
            box_from: None,
        },
    }
}

/// `text` split at every "; " outside parentheses.
fn top_level_parts(text: &str) -> Vec<&str> {
    let mut parts = Vec::new();
    let (mut depth, mut start) = (0_i32, 0);
    for (i, c) in text.char_indices() {
        match c {
            '(' => depth += 1,
            ')' => depth -= 1,
            ';' if depth == 0 && text[i..].starts_with("; ") => {
                parts.push(&text[start..i]);
                start = i + 2;
            }
            _ => {}
        }
    }
    parts.push(&text[start..]);
    parts
}

fn print_table(j: &CalibrationJson) {
    let v = |x: [f64; 3]| format!("{:>12.6} {:>12.6} {:>12.6}", x[0], x[1], x[2]);
    println!(
        "{}: {} readings (columns {}), {} skipped, {} rejected",
        j.log,
        j.samples,
        j.columns.join(", "),
        j.skipped,
        j.rejected
    );
    println!("fit {}", j.fit);
    // `auto`'s reasons, one model per line (they are joined by "; " outside parentheses).
    for reason in j.fit_reason.as_deref().map(top_level_parts).unwrap_or_default() {
        println!("  {reason}");
    }
    println!("magnitude {:.6} ({})", j.magnitude, j.magnitude_source);
    println!("{:<22} {}", "bias", v(j.bias));
    println!("{:<22} {}", "psi_deg", v(j.psi_deg));
    println!("{:<22} {}", "scale", v(j.scale));
    let std = |x: Option<[f64; 3]>| x.map_or("singular".to_string(), v);
    println!("{:<22} {}", "std error bias", std(j.std_error.bias));
    println!("{:<22} {}", "std error psi_deg", std(j.std_error.psi_deg));
    println!("{:<22} {}", "std error scale", std(j.std_error.scale));
    for (name, m) in [
        ("P (b = P (raw - bias))", j.p),
        ("A^-1 (symmetric)", j.soft_iron_inverse),
    ] {
        for (r, row) in m.iter().enumerate() {
            println!("{:<22} {}", if r == 0 { name } else { "" }, v(*row));
        }
    }
    println!(
        "residual | |b| - R |: rms {:.6} ({:.3} % of R), max {:.6}; noise per component {:.6}",
        j.residual_rms, j.residual_rms_percent, j.residual_max, j.noise
    );
    println!(
        "{}: {}",
        if j.identifiable {
            "IDENTIFIABLE"
        } else {
            "NOT IDENTIFIABLE"
        },
        j.verdict
    );
    if let Some(t) = &j.lack_of_fit {
        let head = if t.rejected {
            "MODEL REJECTED BY THE LOG"
        } else {
            "lack of fit"
        };
        println!("{head}: {}", t.words);
    }
    println!(
        "coverage: MotionCal gaps {:.1} %, MicroStrain spatial coverage {:.1} %{}",
        j.coverage.motioncal_gap_percent,
        j.coverage.microstrain_coverage_percent,
        match (&j.coverage.d_efficiency_per_reading, &j.coverage.box_from) {
            (Some(e), Some(b)) if *e >= 1e-3 =>
                format!("; certified D-efficiency per reading {e:.4} in the box of {b}"),
            (Some(e), Some(b)) => format!("; certified D-efficiency per reading {e:.3e} in the box of {b}"),
            _ => String::new(),
        }
    );
}

/// Writes `calibration.json` and `residuals.csv` into `dir` (created), each through a temporary
/// file renamed into place.
fn write_out(dir: &Path, json: &CalibrationJson, log: &log_file::Log, fit: &LogFit) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    let mut text = serde_json::to_vec_pretty(json).context("JSON")?;
    text.push(b'\n');
    replace(&dir.join("calibration.json"), &text)?;
    replace_with(&dir.join("residuals.csv"), |csv| {
        writeln!(csv, "line,raw_x,raw_y,raw_z,x,y,z,norm,residual")?;
        for (raw, line) in log.readings.iter().zip(&log.lines) {
            let b = fit.apply(*raw);
            let n = magcal_core::small::norm(b);
            writeln!(
                csv,
                "{line},{},{},{},{},{},{},{n},{}",
                raw[0],
                raw[1],
                raw[2],
                b[0],
                b[1],
                b[2],
                n - fit.magnitude
            )?;
        }
        Ok(())
    })
}

fn replace(path: &Path, bytes: &[u8]) -> Result<()> {
    replace_with(path, |w| Ok(w.write_all(bytes)?))
}

/// Streams `write` into a temporary file beside `path`, then renames it into place: a reader sees
/// the old file or the whole new one, and nothing is held in memory.
fn replace_with(path: &Path, write: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    let tmp = path.with_extension("magcal-tmp");
    let result = (|| -> Result<()> {
        let file = std::fs::File::create(&tmp)?;
        let mut w = std::io::BufWriter::new(file);
        write(&mut w)?;
        w.flush()?;
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(e).with_context(|| format!("{}: cannot write", path.display()));
    }
    std::fs::rename(&tmp, path).with_context(|| format!("{}: cannot write", path.display()))
}

/// Runs `apply`.
///
/// # Errors
/// A bad calibration file or log (exit 2).
pub fn apply(args: &ApplyArgs) -> Result<(), Failure> {
    Ok(apply_inner(args)?)
}

/// A `calibration.json` whose `p`, `bias` and `magnitude` are usable.
fn read_calibration(path: &Path) -> Result<CalibrationJson> {
    let shown = path.display().to_string();
    let text = std::fs::read(path).with_context(|| format!("{shown}: cannot read"))?;
    let cal: CalibrationJson =
        serde_json::from_slice(&text).with_context(|| format!("{shown}: not a magcal calibration"))?;
    if !(cal.p.iter().flatten().all(|v| v.is_finite())
        && cal.bias.iter().all(|v| v.is_finite())
        && cal.magnitude.is_finite()
        && cal.magnitude > 0.0)
    {
        bail!("{shown}: p, bias or magnitude is not finite and positive");
    }
    Ok(cal)
}

fn apply_inner(args: &ApplyArgs) -> Result<()> {
    let shown = args.calibration.display().to_string();
    let cal = read_calibration(&args.calibration)?;
    if !cal.identifiable {
        eprintln!("magcal: warning: {shown} is marked not identifiable: {}", cal.verdict);
    }
    let log = log_file::read(&args.log, args.columns.as_deref(), args.skip_bad)?;
    for (line, reason) in &log.skipped {
        eprintln!("magcal: skipped line {line}: {reason}");
    }
    let rows = |out: &mut dyn Write| -> Result<()> {
        writeln!(out, "line,x,y,z,norm")?;
        for (raw, line) in log.readings.iter().zip(&log.lines) {
            let b = cal.apply(*raw);
            writeln!(out, "{line},{},{},{},{}", b[0], b[1], b[2], magcal_core::small::norm(b))?;
        }
        Ok(())
    };
    match &args.out {
        Some(path) => replace_with(path, rows),
        None => {
            let mut w = std::io::BufWriter::new(std::io::stdout().lock());
            rows(&mut w)?;
            w.flush().context("stdout")
        }
    }
}

/// Runs `next`: the attitudes that most increase the information of the log (D-optimal
/// augmentation under the fitted model), with the standard errors and the certified D-efficiency
/// per reading before and after.
///
/// # Errors
/// A bad calibration, log or scenario (exit 2).
pub fn next(args: &NextArgs) -> Result<(), Failure> {
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
    let sigma = cal.noise * factor;
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

/// Runs `simulate`: a log of noisy readings (nT) of the scenario's sensor at the attitudes of one
/// of its designs, `roll_deg,yaw_deg,pitch_deg,mx,my,mz`, to try `calibrate` on a known truth.
///
/// # Errors
/// A bad scenario, an unknown design, a bad noise level (exit 2).
pub fn simulate(args: &SimulateArgs) -> Result<(), Failure> {
    Ok(simulate_inner(args)?)
}

fn simulate_inner(args: &SimulateArgs) -> Result<()> {
    let scenario = crate::scenario::load(&args.scenario)?;
    let sigma = args.sigma_nt.unwrap_or(scenario.sigmas_nt[0]);
    if !(sigma.is_finite() && (0.0..=crate::limits::MAX_SIGMA_NT).contains(&sigma)) {
        bail!(
            "--sigma-nt {sigma}: must lie in [0, {}] nT",
            crate::limits::MAX_SIGMA_NT
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
            progress: false,
            designs_only: true,
        },
    )?;
    let attitudes = out.designs[index].expanded();
    let mut rng = crate::pipeline::simulated_log_rng(args.seed.unwrap_or(scenario.seed));
    let readings = scenario
        .truth
        .noisy_readings(&scenario.field.body_fields(&attitudes), sigma, &mut rng)?;
    let rows = |out: &mut dyn Write| -> Result<()> {
        writeln!(out, "roll_deg,yaw_deg,pitch_deg,mx,my,mz")?;
        for (a, s) in attitudes.iter().zip(&readings) {
            let [r, y, p] = a.to_degrees();
            writeln!(out, "{r},{y},{p},{},{},{}", s[0], s[1], s[2])?;
        }
        Ok(())
    };
    match &args.out {
        Some(path) => replace_with(path, rows)?,
        None => {
            let mut w = std::io::BufWriter::new(std::io::stdout().lock());
            rows(&mut w)?;
            w.flush().context("stdout")?;
        }
    }
    eprintln!(
        "magcal: {} readings of design {:?} at {sigma} nT; the field magnitude is {} nT (calibrate with --magnitude {})",
        readings.len(),
        args.design,
        scenario.field.magnitude(),
        scenario.field.magnitude()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::top_level_parts;

    #[test]
    fn reasons_split_outside_parentheses_only() {
        assert_eq!(
            top_level_parts("full: not identifiable (a; b (c; d)); diagonal: x; offset: identifiable"),
            [
                "full: not identifiable (a; b (c; d))",
                "diagonal: x",
                "offset: identifiable"
            ]
        );
        assert_eq!(top_level_parts("full: identifiable"), ["full: identifiable"]);
    }
}
