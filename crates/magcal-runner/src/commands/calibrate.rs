//! `magcal calibrate LOG`: fit a log (CONVENTIONS.md "Real data" and its calibration forms).

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use magcal_core::log_fit::{self, FitModel, LogFit};
use magcal_core::small::upper_triangular_inverse;

use crate::cli::Failure;
use crate::log::calibration::{CalibrationJson, Coverage, LackOfFitJson, StdError};
use crate::log::read as log_file;
use crate::log::site::{Date, Site, Units, parse_model, wmm_magnitude};
use crate::log::vehicle::{BoxFlags, Place, Vehicle, log_efficiency};
use crate::output::file::to_stdout;
use crate::output::log_rows::ResidualRow;
use crate::output::manifest::{CalibrationManifest, Hashing, sha256_hex};
use crate::output::staging::{ResultSet, Target};
use crate::output::{self, Real};

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
    #[arg(long, requires = "date", allow_hyphen_values = true, value_name = "LAT,LON[,ALT_M]")]
    pub site: Option<Site>,
    /// The date of the log: `YYYY-MM-DD` or a decimal year (with `--site`).
    #[arg(long, requires = "site", value_name = "DATE")]
    pub date: Option<Date>,
    /// The log's units (with `--site`).
    #[arg(long, value_enum, requires = "site")]
    pub units: Option<Units>,
    /// The model (default: the newest whose five-year window holds the date): WMM2010, WMM2015,
    /// WMM2015v2, WMM2020, WMM2025.
    #[arg(long, requires = "site", value_parser = parse_model, value_name = "MODEL")]
    pub wmm: Option<magcal_core::wmm::Model>,
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
    /// Also write the calibration set DIR: calibration.json, residuals.csv and manifest.json,
    /// replaced whole (DIR must be missing, empty or an earlier calibration set, and hold none of
    /// the inputs).
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

/// Runs `calibrate`: fits the log, writes the calibration set of `--out` (swapped in whole), then
/// prints the table or the JSON.
///
/// # Errors
/// A bad log or option, a log that no model fits, or an output that cannot be written (exit 2; a
/// failure before the swap replaces nothing, and a failed print leaves the new set in place); a
/// calibration that is not identifiable or whose model the log rejects ([`Failure::Unusable`],
/// exit 3, after its outputs are written).
pub fn run(args: &CalibrateArgs) -> Result<(), Failure> {
    let inputs: Vec<&Path> = [Some(args.log.as_path()), args.scenario.as_deref()]
        .into_iter()
        .flatten()
        .collect();
    // The target is checked, and what killed runs left beside it removed, before any work.
    let set = match &args.out {
        Some(dir) => Some(ResultSet::begin(dir, Target::Calibration, &inputs)?),
        None => None,
    };
    let mut log = log_file::read(&args.log, args.columns.as_deref(), args.skip_bad)?;
    let rows = log.readings.len() + log.skipped.len();
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
    let place = args.site.zip(args.date).map(|(site, date)| Place {
        site,
        date,
        model: args.wmm,
    });
    let wmm = match (&place, args.units) {
        (Some(p), Some(units)) => Some(wmm_magnitude(&p.site, p.date, units, p.model)?),
        (Some(_), None) if args.magnitude.is_none() => {
            return Err(
                anyhow::anyhow!("--site: give --units (the log's) for the WMM magnitude, or --magnitude").into(),
            );
        }
        (Some(_), None) if !args.attitude.any() => {
            return Err(anyhow::anyhow!(
                "--site with --magnitude: the site would give only the box flags' field direction; add --roll and --pitch, or drop --site"
            )
            .into());
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
    record_provenance(&mut json, args)?;
    let vehicle = Vehicle::from_options(args.scenario.as_deref(), &args.attitude, place.as_ref())?;
    if let Some(vehicle) = &vehicle {
        json.coverage.d_efficiency_per_reading = log_efficiency(&json, vehicle, &log.readings)
            .with_context(|| format!("{}: coverage in {}", args.log.display(), vehicle.label))?;
        json.coverage.box_from = Some(vehicle.label.clone());
    }
    if let Some(set) = set {
        write_out(set, &args.log, rows, &json, &log, &fit)?;
    }
    to_stdout(|w| {
        if args.json {
            serde_json::to_writer_pretty(&mut *w, &json).context("JSON")?;
            writeln!(w)?;
        } else {
            print_table(w, &json)?;
        }
        Ok(())
    })?;
    unusable(&args.log, &json).map_or(Ok(()), |why| Err(Failure::Unusable(why)))
}

/// Why a calibration should not be used, if it should not: the log does not determine it, or
/// rejects its model.
fn unusable(log: &Path, json: &CalibrationJson) -> Option<String> {
    let mut why = Vec::new();
    if !json.identifiable {
        why.push(format!("not identifiable: {}", json.verdict));
    }
    if let Some(t) = json.lack_of_fit.as_ref().filter(|t| t.rejected) {
        why.push(format!("the log rejects the {} model: {}", json.fit, t.words));
    }
    (!why.is_empty()).then(|| format!("{}: {}", log.display(), why.join("; ")))
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

/// What the calibration was made from: the format, magcal's version, the log's SHA-256 and data
/// rows (readings, skipped, rejected), and its units where given.
fn record_provenance(json: &mut CalibrationJson, args: &CalibrateArgs) -> Result<()> {
    json.format = Some(crate::log::calibration::FORMAT.to_string());
    json.magcal_version = Some(env!("CARGO_PKG_VERSION").to_string());
    json.log_sha256 = Some(crate::log::calibration::sha256_file(&args.log)?);
    json.log_rows = Some(json.samples + json.skipped + json.rejected);
    json.units = args
        .units
        .and_then(|u| u.to_possible_value())
        .map(|v| v.get_name().to_string());
    Ok(())
}

fn to_json(path: &Path, log: &log_file::Log, fit: &LogFit, why: Option<String>, source: String) -> CalibrationJson {
    let fields: Vec<magcal_core::Vec3> = log.readings.iter().map(|s| fit.apply(*s)).collect();
    let k = upper_triangular_inverse(&fit.p).unwrap_or([[f64::NAN; 3]; 3]);
    CalibrationJson {
        log: path.display().to_string(),
        format: None,
        magcal_version: None,
        log_sha256: None,
        log_rows: None,
        units: None,
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

fn print_table(w: &mut dyn Write, j: &CalibrationJson) -> std::io::Result<()> {
    let v = |x: [f64; 3]| format!("{:>12.6} {:>12.6} {:>12.6}", x[0], x[1], x[2]);
    writeln!(
        w,
        "{}: {} readings (columns {}), {} skipped, {} rejected",
        j.log,
        j.samples,
        j.columns.join(", "),
        j.skipped,
        j.rejected
    )?;
    writeln!(w, "fit {}", j.fit)?;
    // `auto`'s reasons, one model per line (they are joined by "; " outside parentheses).
    for reason in j.fit_reason.as_deref().map(top_level_parts).unwrap_or_default() {
        writeln!(w, "  {reason}")?;
    }
    writeln!(w, "magnitude {:.6} ({})", j.magnitude, j.magnitude_source)?;
    writeln!(w, "{:<22} {}", "bias", v(j.bias))?;
    writeln!(w, "{:<22} {}", "psi_deg", v(j.psi_deg))?;
    writeln!(w, "{:<22} {}", "scale", v(j.scale))?;
    let std = |x: Option<[f64; 3]>| x.map_or("singular".to_string(), v);
    writeln!(w, "{:<22} {}", "std error bias", std(j.std_error.bias))?;
    writeln!(w, "{:<22} {}", "std error psi_deg", std(j.std_error.psi_deg))?;
    writeln!(w, "{:<22} {}", "std error scale", std(j.std_error.scale))?;
    for (name, m) in [
        ("P (b = P (raw - bias))", j.p),
        ("A^-1 (symmetric)", j.soft_iron_inverse),
    ] {
        for (r, row) in m.iter().enumerate() {
            writeln!(w, "{:<22} {}", if r == 0 { name } else { "" }, v(*row))?;
        }
    }
    writeln!(
        w,
        "residual | |b| - R |: rms {:.6} ({:.3} % of R), max {:.6}; noise per component {:.6}",
        j.residual_rms, j.residual_rms_percent, j.residual_max, j.noise
    )?;
    writeln!(
        w,
        "{}: {}",
        if j.identifiable {
            "IDENTIFIABLE"
        } else {
            "NOT IDENTIFIABLE"
        },
        j.verdict
    )?;
    if let Some(t) = &j.lack_of_fit {
        let head = if t.rejected {
            "MODEL REJECTED BY THE LOG"
        } else {
            "lack of fit"
        };
        writeln!(w, "{head}: {}", t.words)?;
    }
    writeln!(
        w,
        "coverage: MotionCal gaps {:.1} %, MicroStrain spatial coverage {:.1} %{}",
        j.coverage.motioncal_gap_percent,
        j.coverage.microstrain_coverage_percent,
        match (&j.coverage.d_efficiency_per_reading, &j.coverage.box_from) {
            (Some(e), Some(b)) if *e >= 1e-3 =>
                format!("; certified D-efficiency per reading {e:.4} in the box of {b}"),
            (Some(e), Some(b)) => format!("; certified D-efficiency per reading {e:.3e} in the box of {b}"),
            _ => String::new(),
        }
    )?;
    Ok(())
}

/// Writes the calibration set: `calibration.json`, `residuals.csv` (one [`ResidualRow`] per
/// reading fitted) and `manifest.json` with the log's and every file's SHA-256, into the staging
/// directory of `set`, and swaps it in. `rows`: the data rows read from the log.
fn write_out(
    mut set: ResultSet,
    path: &Path,
    rows: usize,
    json: &CalibrationJson,
    log: &log_file::Log,
    fit: &LogFit,
) -> Result<()> {
    let mut files = BTreeMap::new();
    let mut text = serde_json::to_vec_pretty(json).context("JSON")?;
    text.push(b'\n');
    set.put("calibration.json", &text)?;
    files.insert("calibration.json".to_string(), sha256_hex(&text));
    let mut hex = String::new();
    set.put_with("residuals.csv", |w| {
        let mut w = Hashing::new(w);
        let residuals = log.readings.iter().zip(&log.lines).map(|(raw, &line)| {
            let b = fit.apply(*raw);
            let norm = magcal_core::small::norm(b);
            ResidualRow {
                line,
                raw_x: Real(raw[0]),
                raw_y: Real(raw[1]),
                raw_z: Real(raw[2]),
                x: Real(b[0]),
                y: Real(b[1]),
                z: Real(b[2]),
                norm: Real(norm),
                residual: Real(norm - fit.magnitude),
            }
        });
        output::write_csv(residuals, &mut w)?;
        hex = w.hex();
        Ok(())
    })?;
    files.insert("residuals.csv".to_string(), hex);
    let manifest = CalibrationManifest::new(path, log.sha256.clone(), log.bytes, rows, files);
    set.put("manifest.json", &manifest.to_bytes()?)?;
    set.commit()
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
