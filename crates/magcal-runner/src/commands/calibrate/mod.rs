//! `magcal calibrate LOG`: fit a log (docs/conventions.md "Real data" and its calibration forms).

mod budget;
mod glitch;
pub mod heading;
mod motor;
pub mod no_fit;
mod one_field;
mod print;
pub mod vector;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use magcal_core::log_fit::{self, AutoReason, FitModel, FitSettings, LogFit, Noise, Order};
use magcal_core::small::upper_triangular_inverse;
use magcal_core::stop::Stopped;
use magcal_logs::text::significant;

use super::Failure;
use crate::deadline::Deadline;
use crate::digest::{Hashing, sha256_hex};
use crate::log::calibration::{
    CalibrationJson, CheckJson, CorrelationJson, Coverage, EllipsoidJson, HeldOutJson, IntervalJson, LackOfFitJson,
    NoiseJson, StdError, StdSourceJson,
};
use crate::log::flight::InForce;
use crate::log::flown::{Bounds, flown};
use crate::log::gps;
use crate::log::read::HELD_BYTES_PER_READING;
use crate::log::source::{self, Log, LogArgs};
use crate::log::vehicle::{BoxFlags, Place, Vehicle, log_efficiency};
use crate::output::file::to_stdout;
use crate::output::log_rows::ResidualRow;
use crate::output::staging::{ResultSet, Target};
use crate::output::stderr::to_stderr;
use crate::output::{self, Derived, Real};
use crate::scenario::site::{Date, Site, Units, parse_model, wmm_magnitude};
use magcal_core::aviation::roll_pitch_heading_deg;
use print::print_table;

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
    /// Against the log's reference attitudes (`--quaternion` or `--euler`): the whole `K`, the
    /// misalignment with the body included, and the bias; the field from `--site` and `--date`
    /// or along the log's GPS track, else fitted (docs/conventions.md "Vector calibration").
    Vector,
    /// Against the log's attitudes and the field given (`--site` and `--date`, or along the
    /// log's GPS track): `K = diag(s)`, scale factors and offsets in the body frame (what an
    /// ordinary flight, level legs and turns, determines).
    VectorDiagonal,
    /// As `vector-diagonal` with `K = I`: offsets only, the readings taken as the field in the
    /// body frame.
    VectorOffsets,
}

impl Fit {
    /// The name `--fit` gives it.
    pub fn name(self) -> &'static str {
        match self {
            Fit::Full => "full",
            Fit::Diagonal => "diagonal",
            Fit::Offset => "offset",
            Fit::Auto => "auto",
            Fit::Vector => "vector",
            Fit::VectorDiagonal => "vector-diagonal",
            Fit::VectorOffsets => "vector-offsets",
        }
    }

    /// The model of `K` of a vector fit; `None` for a scalar one.
    pub fn vector_model(self) -> Option<magcal_core::vector::VectorModel> {
        use magcal_core::vector::VectorModel;
        match self {
            Fit::Vector => Some(VectorModel::Full),
            Fit::VectorDiagonal => Some(VectorModel::Diagonal),
            Fit::VectorOffsets => Some(VectorModel::Offsets),
            _ => None,
        }
    }

    /// The fit of `readings` to `magnitude` under this choice, with the reasons for `auto`.
    fn fit(
        self,
        readings: &[magcal_core::Vec3],
        magnitude: f64,
        settings: &FitSettings,
    ) -> Result<(LogFit, Vec<AutoReason>), magcal_core::CalibrationError> {
        let model = match self {
            Fit::Auto => return log_fit::fit_auto(readings, magnitude, settings),
            // The vector fit starts from the scalar full fit, whose magnitude it takes.
            Fit::Full | Fit::Vector | Fit::VectorDiagonal | Fit::VectorOffsets => FitModel::Full,
            Fit::Diagonal => FitModel::Diagonal,
            Fit::Offset => FitModel::Offset,
        };
        log_fit::fit_tested(readings, magnitude, model, settings).map(|f| (f, Vec::new()))
    }
}

/// `--residual`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ResidualArg {
    /// Each reading's distance from the fitted ellipsoid (the default, as designs).
    Readings,
    /// the paper's residual, `|P (raw - bias)| - R`.
    Paper,
}

impl ResidualArg {
    /// The core's residual.
    pub fn residual(self) -> log_fit::Residual {
        match self {
            Self::Readings => log_fit::Residual::Readings,
            Self::Paper => log_fit::Residual::Paper,
        }
    }
}

/// `magcal calibrate`.
#[derive(Debug, Args)]
pub struct CalibrateArgs {
    /// The log: a CSV file (one reading per row), an ArduPilot DataFlash log (`.bin`), a MAVLink
    /// telemetry log (`.tlog`) or a PX4 ULog (`.ulg`); `-` reads standard input (a flight log from a pipe needs `--format`).
    #[arg(value_parser = crate::log::path_parser())]
    pub log: PathBuf,
    #[command(flatten)]
    pub input: LogArgs,
    /// The field magnitude in the log's units (default: the fitted mean radius, and scale factors
    /// relative to it).
    #[arg(long, conflicts_with = "units", value_parser = crate::limits::finite)]
    pub magnitude: Option<f64>,
    /// The magnitude from the World Magnetic Model at a site: `LAT,LON[,ALT_M]` (WGS 84 degrees,
    /// metres above the ellipsoid; default 0); needs `--date`, and `--units` unless `--magnitude`
    /// gives the magnitude (the site then serves the box flags' field direction only).
    #[arg(long, requires = "date", allow_hyphen_values = true, value_name = "LAT,LON[,ALT_M]")]
    pub site: Option<Site>,
    /// The date of the log: `YYYY-MM-DD` or a decimal year (with `--site`, or with a log's
    /// positions that carry no time: a CSV's `--position` without `--utc`).
    #[arg(long, value_name = "DATE")]
    pub date: Option<Date>,
    /// The log's units: recorded in the calibration (for `export`), and with `--site` they give
    /// the WMM magnitude. A flight log's format fixes them (mG for ArduPilot, G for PX4).
    #[arg(long, value_enum)]
    pub units: Option<Units>,
    /// The model (default: the newest whose five-year window holds the date): WMM2010, WMM2015,
    /// WMM2015v2, WMM2020, WMM2025.
    #[arg(long, requires = "site", value_parser = parse_model, value_name = "MODEL")]
    pub wmm: Option<magcal_core::wmm::Model>,
    /// The model.
    #[arg(long, value_enum, default_value = "full")]
    pub fit: Fit,
    /// Drop readings whose `|calibrated| - R` lies more than K robust standard deviations
    /// (1.4826 median absolute deviations) from the median, refit, and repeat until the kept set
    /// does not change; `rejected` counts them. K is at least 2, and at most a tenth of the log
    /// may go; the noise and standard errors are corrected for the truncation. Off by default.
    #[arg(long, value_name = "K", value_parser = crate::limits::finite)]
    pub reject: Option<f64>,
    /// The readings' noise per component, in the log's units (a data sheet, a stationary
    /// recording): the standard errors rest on it, and the readings' scatter is tested against
    /// it. Default: estimated from the residuals (unknown when the fit is exact).
    #[arg(long, value_name = "SIGMA", value_parser = crate::limits::finite)]
    pub noise: Option<f64>,
    /// The residual every model minimises: `readings` (each reading's distance from the fitted
    /// ellipsoid, as designs are judged) or `paper` (the paper's `|P (raw - bias)| - R`, which runs
    /// off where a vehicle barely tilts in a steep field).
    #[arg(long, value_enum, default_value = "readings")]
    pub residual: ResidualArg,
    /// Noisy trials of the verdict: the log's field directions under the fit, read by the fitted
    /// sensor with the log's noise, calibrated by the same fit; usable needs 95 % of them `ok`.
    #[arg(long, default_value_t = log_fit::CHECK_TRIALS as u64, value_parser = clap::value_parser!(u64).range(20..=100_000))]
    pub trials: u64,
    /// The seed of the trials' random streams.
    #[arg(long, default_value_t = log_fit::CHECK_SEED)]
    pub seed: u64,
    /// The heading error the calibration may leave, degrees: usable needs the 95th percentile
    /// over the vehicle's attitudes (its box with --scenario or --roll and --pitch, else level,
    /// at every heading) within it under 95 % of the calibrations the check's trials and the
    /// standard errors its held-out fits allow. The default 2 is a small vehicle's share; IMO
    /// MSC.116(73) asks a ship's whole heading device for 1.0 degree static: use 1 there.
    #[arg(long, value_name = "DEG", default_value_t = magcal_core::budget::DEFAULT_BUDGET_DEG, allow_hyphen_values = true, value_parser = crate::limits::heading_budget)]
    pub heading_budget: f64,
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
    /// Fit the motors' interference with the calibration: the raw reading moving by `d` per
    /// ampere of battery current or per unit of throttle (the log's current or throttle, matched
    /// to each reading); the calibration is then the sensor's at zero input, and `motor` in the
    /// JSON gives `d` with its standard errors (for `export`'s `COMPASS_MOT*` or `CAL_MAGn_*COMP`).
    #[arg(long, value_enum)]
    pub motor: Option<motor::Motor>,
}

/// What `calibrate` makes of a log: a calibration (usable or not), or the report that no model
/// fits it.
#[derive(Debug)]
pub enum Calibrated {
    /// A calibration, and why `--fit auto` chose its model.
    Fit {
        json: Box<CalibrationJson>,
        why: Vec<AutoReason>,
    },
    /// No model fits the log (exit 3 on the command line).
    NoFit(Box<no_fit::NoCalibrationJson>),
}

impl Calibrated {
    /// Whether the log gives a calibration to use.
    pub fn usable(&self) -> bool {
        match self {
            Self::Fit { json, .. } => json.usable,
            Self::NoFit(_) => false,
        }
    }

    /// The reasons it is not usable (none when it is).
    pub fn reasons(&self) -> &[String] {
        match self {
            Self::Fit { json, .. } => &json.reasons,
            Self::NoFit(json) => &json.reasons,
        }
    }
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
    let input = LogArgs {
        motor: args.motor.is_some(),
        ..args.input.clone()
    };
    let mut log = source::open(&args.log, &input, HELD_BYTES_PER_READING)?;
    let rows = log.readings.len() + log.skipped.len();
    let (json, why) = match calibrate(args, &mut log)? {
        Calibrated::Fit { json, why } => (json, why),
        Calibrated::NoFit(json) => return no_fit::report(args, set, &log, rows, &json),
    };
    if let Some(set) = set {
        write_out(set, &args.log, rows, &json, &log)?;
    }
    to_stdout(|w| {
        if args.json {
            serde_json::to_writer_pretty(&mut *w, &json).context("JSON")?;
            writeln!(w)?;
        } else {
            print_table(w, &json, &why)?;
        }
        Ok(())
    })?;
    if json.usable {
        Ok(())
    } else {
        Err(Failure::Unusable(format!(
            "{}: {}",
            args.log.display(),
            json.reasons.join("; ")
        )))
    }
}

/// The calibration of `log` (read from `args.log` as `args.input` and `args.motor` say) as
/// `calibrate` makes it, without writing or printing: what the command line and the library
/// bindings share. The readings `--reject` drops leave `log`.
///
/// # Errors
/// A bad option, or one that does not apply to the log (exit 2 on the command line).
pub fn calibrate(args: &CalibrateArgs, log: &mut Log) -> Result<Calibrated, Failure> {
    calibrate_within(args, log, &Deadline::none())
}

/// [`calibrate`] within `deadline`: what `live` fits each snapshot of the stream with, so that a
/// fit never holds the stream up for longer than the deadline, and a signal ends it.
///
/// Every stage asks the deadline: the fit (its iterations, its check by trials, its held-out
/// folds, `--reject`'s and the motors' refits), the heading budget, the one-field checks, the
/// coverage certificate of the box and what to fly next. A stage it leaves no time for is
/// skipped, and one it cuts short is thrown away, each said in words
/// ([`Deadline::skipped`]: `skipped: the coverage certificate did not finish within 2 s`):
/// - the fit: [`Calibrated::NoFit`], that the reason;
/// - the heading budget or the one-field checks (part of the verdict): the calibration, not
///   usable, that among its reasons;
/// - the coverage certificate: `coverage.d_efficiency_per_reading` `null`, that in
///   `coverage.d_efficiency_why_not` (the verdict does not rest on it);
/// - what to fly next: that in the heading budget's `next`.
///
/// The work left when the deadline passes is one step of a loop: an iteration of a fit (up to
/// about 0.2 s on a million readings), a round of trials, a support point of the certificate's
/// exchanges (under a millisecond). Stages that are one pass over the readings (reading the
/// glitches, the heading against the log's attitudes) and a vector fit (`--fit vector*`) run to
/// their end, and the deadline is looked at after them. With [`Deadline::none`] it is
/// [`calibrate`], step for step and number for number.
///
/// # Errors
/// As [`calibrate`].
pub fn calibrate_within(args: &CalibrateArgs, log: &mut Log, deadline: &Deadline) -> Result<Calibrated, Failure> {
    positive_options(args)?;
    let shown = args.log.display().to_string();
    if let Some(m) = args.motor {
        motor::inputs(log, m).with_context(|| shown.clone())?;
    }
    let mut settings = fit_settings(args, log, deadline);
    let glitches = glitch::find(&log.readings);
    // Without --reject the glitches stay in the log, named first among the reasons.
    let glitch_reason = (args.reject.is_none() && !glitches.is_empty())
        .then(|| format!("{}; --reject K drops them", glitches.words(log)));
    let rejected = rejected(args, log, &mut settings, &glitches);
    // Fits the deadline stopped are not the log's, whatever they gave.
    if deadline.expired() {
        return Ok(skipped_fit(args, log, deadline));
    }
    let rejected = rejected.with_context(|| shown.clone())?;
    let (place, place_source) = place_of(args, log)?;
    let units = units_of(args, log)?;
    let (fit, why, source) = match fit_at_magnitude(args, log, &settings, magnitude_of(args, units, place.as_ref())?)? {
        _ if deadline.expired() => return Ok(skipped_fit(args, log, deadline)),
        Ok(fitted) => fitted,
        Err(why) => {
            let why = glitch_reason.map_or(why.clone(), |g| format!("{why}; {g}"));
            return Ok(Calibrated::NoFit(Box::new(no_fit::json(args, log, rejected, why))));
        }
    };
    let along = place_source.as_ref().is_some_and(|s| s.from_log);
    let (mut fit, vector, advice) = vector::instead(args, log, fit, units, place.as_ref(), along)?;
    // A vector fit fits the interference with the calibration itself.
    let joint = match args.motor.filter(|_| vector.is_none()) {
        Some(m) => {
            let (refit, joint) = motor::refit(log, &fit, m, &settings).with_context(|| shown.clone())?;
            fit = refit;
            Some(joint)
        }
        None => None,
    };
    if deadline.expired() {
        return Ok(skipped_fit(args, log, deadline));
    }
    // A magnitude from the field's model in the log's units makes the scale factors absolute;
    // one given by --magnitude may be in other units on purpose (counts in, microtesla out).
    let absolute = args.magnitude.is_none() && source != FITTED_RADIUS && vector.is_none();
    let mut json = to_json(&args.log, log, &fit, &why, source, args.seed);
    vector.iter().for_each(|v| v.record(&mut json));
    advice.iter().for_each(|a| a.record(&mut json));
    if let Some(joint) = &joint {
        motor::record(&mut json, joint);
    }
    // A magnitude that is the field's (a site, or given) makes the scale factors absolute.
    if absolute
        && json.usable
        && let Some(why) = log_fit::implausible(&fit.errors, true)
    {
        json.usable = false;
        json.reasons.push(why);
    }
    let (heading_vs_log, alignment) = heading::check_aligned(log, &fit);
    json.heading_vs_log = heading_vs_log;
    let vehicle = Vehicle::from_options(args.scenario.as_deref(), &args.attitude, place.as_ref())?;
    let judged = budget::grid(
        log,
        vehicle.as_ref(),
        args.scenario.is_some() || args.attitude.any(),
        place.as_ref(),
        alignment.as_ref(),
    );
    // `fit` is the plain fit of the log's readings unless a vector fit or the motor's replaced it.
    let plain = vector.is_none() && joint.is_none();
    verdict_within(&mut json, log, (&fit, judged, &settings, plain), args, deadline);
    json.rejected = rejected;
    if let Some(g) = glitch_reason {
        json.usable = false;
        json.reasons.insert(0, g);
    }
    if let Some(n) = json.noise_estimate.as_mut() {
        n.truncation_k = args.reject.filter(|_| settings.truncation.is_some());
    }
    record_provenance(&mut json, units, log);
    json.place_source = place_source.map(|s| s.words);
    // A usable calibration is one `apply` and `next` accept: a fit whose numbers leave the range
    // of f64 on the way (readings at 1e150 fitted to a magnitude of 1, P^T P overflowing) is not.
    if let Err(why) = json.check()
        && json.usable
    {
        json.usable = false;
        json.reasons
            .push(format!("the calibration fails the checks of apply and next: {why}"));
    }
    coverage_in_box(&mut json, args, log, vehicle.as_ref(), deadline)?;
    budget::what_to_fly(args, &mut json, deadline);
    Ok(Calibrated::Fit {
        json: Box::new(json),
        why,
    })
}

/// The report that the fit of `log` is skipped: the deadline cut it short, or left no time for it.
fn skipped_fit(args: &CalibrateArgs, log: &Log, deadline: &Deadline) -> Calibrated {
    let stage = if args.fit.vector_model().is_some() {
        "the vector fit"
    } else {
        "the fit"
    };
    Calibrated::NoFit(Box::new(no_fit::json(args, log, 0, deadline.skipped(stage))))
}

/// The stages of the verdict after the fit, within `deadline`: the heading budget over `judged`
/// and the one-field checks of `fit` (`plain`: the fit of the log's readings under `settings`).
/// A stage the deadline leaves no time for is skipped, and the one-field checks it cuts short (their
/// fits ask it) are undone; either leaves the calibration not usable, saying so.
fn verdict_within(
    json: &mut CalibrationJson,
    log: &Log,
    (fit, judged, settings, plain): (&LogFit, budget::Judged, &FitSettings, bool),
    args: &CalibrateArgs,
    deadline: &Deadline,
) {
    let skip = |json: &mut CalibrationJson, stage: &str| {
        json.usable = false;
        json.reasons.push(deadline.skipped(stage));
    };
    if deadline.expired() {
        skip(json, "the heading budget");
    } else {
        budget::record(json, fit, judged, args.heading_budget, args.seed);
    }
    if deadline.expired() {
        return skip(json, "the one-field checks");
    }
    let before = json.clone();
    one_field::judge(json, log, fit, settings, plain);
    if deadline.expired() {
        *json = before;
        skip(json, "the one-field checks");
    }
}

/// Where the site and date of the field come from.
struct PlaceSource {
    /// From the log's GPS fixes (not typed): a vector fit takes the field along the track.
    from_log: bool,
    words: String,
}

/// The site and date: `--site` and `--date` where given, else the log's GPS fixes where they
/// give both ([`gps::place_of`]); where the log has GPS messages that do not, why in words.
///
/// # Errors
/// `--date` without `--site` for a log without positions.
fn place_of(args: &CalibrateArgs, log: &Log) -> Result<(Option<Place>, Option<PlaceSource>)> {
    if let Some((site, date)) = args.site.zip(args.date) {
        let words = format!(
            "--site and --date{}",
            if log.gps.is_some() {
                " (the log's GPS fixes are not used: one site for the whole log)"
            } else {
                ""
            }
        );
        let place = Place {
            site,
            date,
            model: args.wmm,
        };
        return Ok((Some(place), Some(PlaceSource { from_log: false, words })));
    }
    let (gps, message) = match &log.gps {
        Some((g, m)) => (Some(g), m.as_str()),
        None => (None, ""),
    };
    // A date typed without a site dates the log's fixes (a CSV's positions without times).
    Ok(match gps::place_of(gps, args.date, args.wmm, message) {
        gps::PlaceOfLog::NoGps if args.date.is_some() => {
            bail!("--date without --site: the log has no positions to take the site from; give --site too")
        }
        gps::PlaceOfLog::NoGps => (None, None),
        gps::PlaceOfLog::Lacking(why) => (
            None,
            Some(PlaceSource {
                from_log: false,
                words: format!("none: {why}; give --site and --date for the World Magnetic Model's field"),
            }),
        ),
        gps::PlaceOfLog::Found(f) => (
            Some(f.place),
            Some(PlaceSource {
                from_log: true,
                words: f.words,
            }),
        ),
    })
}

/// With `--reject K`: drops the glitches, then the readings the robust fit rejects, and sets the
/// truncation the noise estimate corrects for; how many went.
fn rejected(
    args: &CalibrateArgs,
    log: &mut Log,
    settings: &mut FitSettings,
    glitches: &glitch::Glitches,
) -> Result<usize> {
    let Some(k) = args.reject else {
        return Ok(0);
    };
    let dropped = glitches.drop_from(log);
    let r = reject(log, k, args.fit, settings).with_context(|| format!("--reject {}", crate::limits::show(k)))?;
    // A zero spread (readings on the fit to rounding, as an exact fit of a few readings gives)
    // truncates nothing to correct for; the core takes only a positive width.
    settings.truncation = Some(r.half_width).filter(|h| h.is_finite() && *h > 0.0);
    Ok(dropped + r.dropped)
}

/// `--magnitude` and `--noise`, when given, are positive and finite.
fn positive_options(args: &CalibrateArgs) -> anyhow::Result<()> {
    for (name, value) in [("--magnitude", args.magnitude), ("--noise", args.noise)] {
        if let Some(v) = value
            && !(v.is_finite() && v > 0.0)
        {
            anyhow::bail!("{name} {}: must be positive and finite", crate::limits::show(v));
        }
    }
    Ok(())
}

/// What the fit knows beyond the readings and how it is judged, from the options and the log;
/// its fits ask `deadline`.
fn fit_settings(args: &CalibrateArgs, log: &Log, deadline: &Deadline) -> FitSettings {
    FitSettings {
        noise: args.noise,
        truncation: None,
        residual: args.residual.residual(),
        order: if log.times.is_some() {
            Order::Time
        } else {
            Order::Unknown
        },
        // A vector fit replaces the scalar fit it starts from, and has no check by trials of
        // its own: the scalar fit's would be run for nothing.
        trials: if args.fit.vector_model().is_some() {
            0
        } else {
            args.trials as usize
        },
        seed: args.seed,
        profile: true,
        // As the trials: the vector fit makes its own held-out fits.
        held_out: args.fit.vector_model().is_none(),
        stop: deadline.stop(),
    }
}

/// Why a fit that does not determine its sensor has no certified D-efficiency in the box.
const NOT_DETERMINED: &str = "not computed: the box's certificate is made under the fitted sensor, which the log does not determine (not identifiable)";

/// The coverage against the vehicle's box (`--scenario` or the box flags): the certified
/// D-efficiency per reading (within `deadline`, and of a fit that determines its sensor; else
/// `null` and why), and the share of the log's attitudes inside the box.
///
/// The certificate bounds every design in the box under the fitted sensor. A fit that does not
/// determine its sensor stopped somewhere along a direction the readings leave open (the stalled
/// fit of 43 readings: psi -86 deg, scale factors 4 to 1), so its bound is of no sensor the
/// vehicle carries, and such a sensor's certificate need not converge (12 rounds of REX, 73 to
/// 92 s, against 0.03 s for the fit): it is not computed.
fn coverage_in_box(
    json: &mut CalibrationJson,
    args: &CalibrateArgs,
    log: &Log,
    vehicle: Option<&Vehicle>,
    deadline: &Deadline,
) -> Result<()> {
    if let Some(vehicle) = vehicle {
        let stage = "the coverage certificate";
        json.coverage.d_efficiency_why_not = if !json.identifiable {
            Some(NOT_DETERMINED.to_string())
        } else if deadline.expired() {
            Some(deadline.skipped(stage))
        } else {
            let frame = crate::log::vehicle::readings_frame(log.origin.format);
            match log_efficiency(json, vehicle, (&log.readings, &frame), &deadline.stop())
                .with_context(|| format!("{}: coverage in {}", args.log.display(), vehicle.label))?
            {
                Ok(e) => {
                    json.coverage.d_efficiency_per_reading = e;
                    None
                }
                Err(Stopped) => Some(deadline.skipped(stage)),
            }
        };
        json.coverage.box_from = Some(vehicle.label.clone());
    }
    if let Some(attitudes) = &log.attitudes {
        let bounds = vehicle.map(|v| Bounds {
            bounds: &v.bounds,
            yaw_offset_deg: v.field.yaw_offset_deg(),
        });
        json.coverage.flown = flown(attitudes, bounds);
    }
    Ok(())
}

/// `--reject K` ([`log_fit::reject_outliers`]): the fits of its rounds are made to a unit field
/// (the residuals are relative) with `settings`; `log` keeps the readings kept.
fn reject(log: &mut Log, k: f64, model: Fit, settings: &FitSettings) -> Result<log_fit::Rejection> {
    let r = log_fit::reject_outliers(&log.readings, k, |kept| model.fit(kept, 1.0, settings).map(|(f, _)| f))?;
    log.keep(&r.keep);
    Ok(r)
}

/// What the calibration was made from: the format, magcal's version, the log's SHA-256, data
/// rows (readings, skipped, rejected), format, messages, instance, frame and units, what its
/// reader and cut say about it, and what it says of its firmware's parameters.
fn record_provenance(json: &mut CalibrationJson, units: Option<Units>, log: &Log) {
    json.format = Some(crate::log::calibration::FORMAT.to_string());
    json.magcal_version = Some(env!("CARGO_PKG_VERSION").to_string());
    // The reader hashed the bytes it parsed: the file is not read a second time.
    json.log_sha256 = Some(log.sha256.clone());
    json.log_rows = Some(json.samples + json.skipped + json.rejected);
    json.units = units.map(units_name);
    let o = &log.origin;
    json.log_format = Some(o.format.name().to_string());
    json.instance = o.instance;
    json.frame.clone_from(&o.frame);
    json.log_messages.clone_from(&o.messages);
    json.in_force = o.calibration.as_ref().map(|c| match c {
        InForce::Raw => "raw".to_string(),
        InForce::Undone(w) => format!("undone: {w}"),
        InForce::Calibrated(w) => format!("calibrated: {w}"),
    });
    json.log_notes.clone_from(&o.notes);
    json.log_parameters.clone_from(&o.parameters);
    json.heading_source.clone_from(&o.heading_source);
    json.time_span_s = log
        .times
        .as_ref()
        .and_then(|t| Some([t.first()?, t.last()?]))
        .map(|[a, b]| [*a, *b]);
}

fn to_json(path: &Path, log: &Log, fit: &LogFit, why: &[AutoReason], source: String, seed: u64) -> CalibrationJson {
    let (motioncal_gap_percent, microstrain_coverage_percent) = log_fit::coverages(&log.readings, |s| fit.apply(s));
    let k = upper_triangular_inverse(&fit.p).unwrap_or([[f64::NAN; 3]; 3]);
    CalibrationJson {
        log: path.display().to_string(),
        format: None,
        magcal_version: None,
        log_sha256: None,
        log_rows: None,
        units: None,
        log_format: None,
        instance: None,
        frame: None,
        log_messages: Vec::new(),
        in_force: None,
        log_notes: Vec::new(),
        log_parameters: None,
        time_span_s: None,
        heading_vs_log: None,
        field_change: None,
        passes: None,
        motor: None,
        alignment: None,
        columns: log.columns.clone(),
        samples: log.readings.len(),
        skipped: log.skipped.len(),
        rejected: 0,
        fit: fit.model.as_str().to_string(),
        fit_reason: (!why.is_empty()).then(|| why.iter().map(ToString::to_string).collect::<Vec<_>>().join("; ")),
        magnitude: fit.magnitude,
        magnitude_source: source,
        place_source: None,
        heading_source: None,
        heading_std_deg: None,
        next_manoeuvres: Vec::new(),
        headings_never_flown: Vec::new(),
        bias: fit.bias,
        psi_deg: fit.errors.psi_deg(),
        scale: fit.errors.scale(),
        k,
        p: fit.p,
        soft_iron_inverse: fit.soft_iron_inverse(),
        residual_rms: fit.residual_rms,
        residual_max: fit.residual_max,
        residual_rms_percent: 100.0 * fit.residual_rms / fit.magnitude,
        noise: fit.noise.value(),
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
            motioncal_gap_percent,
            microstrain_coverage_percent,
            d_efficiency_per_reading: None,
            d_efficiency_why_not: None,
            box_from: None,
            flown: None,
        },
        usable: fit.usable,
        reasons: fit.reasons.clone(),
        noise_estimate: Some(noise_json(&fit.noise)),
        interval95: fit
            .interval95()
            .zip(fit.quantile95)
            .map(|((psi, scale, bias), q)| IntervalJson {
                quantile: q,
                psi_deg: psi,
                scale,
                bias,
            }),
        ellipsoid: Some(EllipsoidJson {
            passed: fit.ellipsoid.passed,
            residual_rms_percent: fit.ellipsoid.residual_percent,
            limit_percent: log_fit::ELLIPSOID_LIMIT_PERCENT,
            chi_square_p: fit.ellipsoid.chi_square_p,
            words: fit.ellipsoid.words.clone(),
        }),
        residual: Some(fit.residual.as_str().to_string()),
        given_noise: fit.given_noise,
        correlation: correlation_json(fit, log),
        check: fit.check.map(|c| check_json(&c, seed)),
        std_error_source: Some(std_source_json(fit)),
        held_out: fit.held_out.as_ref().map(held_out_json),
        heading_budget: None,
    }
}

/// What each standard error of `fit` rests on, as `calibration.json` gives it.
fn std_source_json(fit: &LogFit) -> StdSourceJson {
    let names = |g: usize| fit.std_source[g].map(|s| s.as_str().to_string());
    StdSourceJson {
        psi_deg: names(0),
        scale: names(1),
        bias: names(2),
    }
}

/// The held-out fits as `calibration.json` gives them.
fn held_out_json(h: &log_fit::HeldOut) -> HeldOutJson {
    HeldOutJson {
        evidence: h.evidence(),
        words: h.words(),
        held_out: h.clone(),
    }
}

/// Where the noise comes from and how sure it is, as `calibration.json` gives it.
fn noise_json(noise: &Noise) -> NoiseJson {
    NoiseJson {
        source: noise.source().to_string(),
        dof: match *noise {
            Noise::Estimated { dof, .. } => Some(dof),
            _ => None,
        },
        interval95: match *noise {
            Noise::Estimated { interval95, .. } if interval95.0.is_finite() && interval95.1.is_finite() => {
                Some([interval95.0, interval95.1])
            }
            _ => None,
        },
        truncation_k: None,
    }
}

/// The residuals' correlation in time as `calibration.json` gives it.
fn correlation_json(fit: &LogFit, log: &Log) -> Option<CorrelationJson> {
    fit.serial.map(|s| CorrelationJson {
        batch_readings: s.batch,
        batch_seconds: log
            .times
            .as_deref()
            .and_then(median_interval)
            .map(|dt| dt * s.batch as f64),
        lag_one: s.lag_one,
        white_std_error: StdError {
            psi_deg: fit.white_std.map(|w| w[0]),
            scale: fit.white_std.map(|w| w[1]),
            bias: fit.white_std.map(|w| w[2]),
        },
    })
}

/// A check by trials as `calibration.json` gives it.
fn check_json(c: &log_fit::TrialCheck, seed: u64) -> CheckJson {
    CheckJson {
        planned: c.planned,
        trials: c.trials,
        ok: c.ok,
        not_converged: c.not_converged,
        not_identifiable: c.not_identifiable,
        failed: c.failed,
        passed: c.passed(),
        noise: c.noise.words(),
        seed,
        every: c.every,
        readings: c.readings,
        words: c.words(),
    }
}

/// The median interval between consecutive times, `None` for fewer than two.
fn median_interval(times: &[f64]) -> Option<f64> {
    let mut d: Vec<f64> = times
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|v| v.is_finite())
        .collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    Some(d[d.len() / 2])
}

/// Writes the calibration set: `calibration.json`, `residuals.csv` (one [`ResidualRow`] per
/// reading fitted) and `manifest.json` with the log's and every file's SHA-256, into the staging
/// directory of `set`, and swaps it in. `rows`: the data rows read from the log.
pub(crate) fn write_out(mut set: ResultSet, path: &Path, rows: usize, json: &CalibrationJson, log: &Log) -> Result<()> {
    let mut files = BTreeMap::new();
    let mut text = serde_json::to_vec_pretty(json).context("JSON")?;
    text.push(b'\n');
    set.put("calibration.json", &text)?;
    files.insert("calibration.json".to_string(), sha256_hex(&text));
    let mut hex = String::new();
    set.put_with("residuals.csv", |w| {
        let mut w = Hashing::new(w);
        let attitudes = log.attitudes.as_deref();
        let residual = |i: usize| {
            let (raw, line) = (log.readings[i], log.lines[i]);
            let b = json.apply_body(raw);
            let norm = magcal_core::small::norm(b);
            let angles = attitudes.and_then(|a| a[i].as_ref()).map(roll_pitch_heading_deg);
            let angle = |k: usize| angles.map(|a| Derived(a[k]));
            ResidualRow {
                line,
                raw_x: Real(raw[0]),
                raw_y: Real(raw[1]),
                raw_z: Real(raw[2]),
                x: Derived(b[0]),
                y: Derived(b[1]),
                z: Derived(b[2]),
                norm: Derived(norm),
                residual: Derived(norm - json.magnitude),
                roll_deg: angle(0),
                pitch_deg: angle(1),
                heading_deg: angle(2),
            }
        };
        output::write_csv_indexed(log.readings.len(), residual, &mut w)?;
        hex = w.hex();
        Ok(())
    })?;
    files.insert("residuals.csv".to_string(), hex);
    let manifest = crate::output::manifest::calibration(path, log.sha256.clone(), log.bytes, rows, files);
    set.put("manifest.json", &manifest.to_bytes()?)?;
    set.commit()
}

/// The magnitude the fit is made to: `--magnitude`, or the WMM's at `--site` and `--date` in the
/// log's `--units`; `None` when neither is given (the fit takes its own mean radius).
/// The log's units: `--units`, or those its format fixes; the two must agree.
fn units_of(args: &CalibrateArgs, log: &Log) -> Result<Option<Units>> {
    match (args.units, log.origin.unit) {
        (Some(given), Some(logged)) if given != logged => bail!(
            "--units {}: {} is {} log, whose readings are in {}",
            units_name(given),
            args.log.display(),
            log.origin.format.with_article(),
            units_name(logged)
        ),
        (given, logged) => Ok(given.or(logged)),
    }
}

/// The name `--units` gives `u`.
fn units_name(u: Units) -> String {
    u.to_possible_value()
        .map_or_else(String::new, |v| v.get_name().to_string())
}

fn magnitude_of(args: &CalibrateArgs, units: Option<Units>, place: Option<&Place>) -> Result<Option<(f64, String)>> {
    let wmm = match (place, units) {
        (Some(p), Some(units)) => Some(wmm_magnitude(&p.site, p.date, units, p.model)?),
        (Some(_), None) if args.magnitude.is_none() => {
            bail!("--site: give --units (the log's) for the WMM magnitude, or --magnitude");
        }
        // A vector fit takes the site's field direction, scaled to --magnitude.
        (Some(_), None) if !args.attitude.any() && args.fit.vector_model().is_none() => {
            bail!(
                "--site with --magnitude: the site would give only the box flags' field direction; add --roll and --pitch, or drop --site"
            );
        }
        _ => None,
    };
    Ok(args.magnitude.map(|r| (r, "given".to_string())).or(wmm))
}

/// Where the magnitude comes from when the fit takes its own mean radius.
const FITTED_RADIUS: &str = "fitted mean radius (scale factors are relative to it, product 1)";

/// A log's fit, the reasons of `--fit auto`, and where the magnitude comes from.
type Fitted = (LogFit, Vec<AutoReason>, String);

/// The fit of `log` with the model of `--fit` at the magnitude `given` (with where it comes from),
/// or at the fit's own mean radius; the reasons of `--fit auto`, and where the magnitude comes
/// from, in words.
fn fit_at_magnitude(
    args: &CalibrateArgs,
    log: &Log,
    settings: &FitSettings,
    given: Option<(f64, String)>,
) -> Result<Result<Fitted, String>> {
    let shown = args.log.display().to_string();
    // No fit is a property of the readings (too few, too alike), not bad input: the caller
    // reports it with exit 3.
    let fit_with = |magnitude: f64| {
        args.fit
            .fit(&log.readings, magnitude, settings)
            .map_err(|e| format!("the {} model: {e}", args.fit.name()))
    };
    Ok(match given {
        Some((r, source)) => {
            // A magnitude in other units than the log's (0.49 for a log in nT) still fits, with
            // scale factors 1e5 away from 1: say so before they are read as a calibration.
            if let Some(radius) = log_fit::sphere_radius(&log.readings)
                && !(1e-2..=1e2).contains(&(radius / r))
            {
                to_stderr!(
                    "magcal: warning: {shown}: the readings lie about {} from their centre, {:.1e} times the magnitude {} ({source}); are they in the same units?",
                    significant(radius, 4),
                    radius / r,
                    significant(r, 7)
                );
            }
            fit_with(r).map(|(f, why)| (f, why, source))
        }
        None => {
            // The fitted mean radius: the magnitude that makes the scale factors relative with
            // product 1; when the fit is not determined, the radius of the best-fitting sphere.
            // A fit does not depend on its magnitude but through that scale, so one fit serves.
            let (unit, why) = match fit_with(1.0) {
                Ok(f) => f,
                Err(e) => return Ok(Err(e)),
            };
            let (radius, source) = if unit.identifiable {
                (Some(unit.mean_radius()), FITTED_RADIUS)
            } else {
                (
                    log_fit::sphere_radius(&log.readings),
                    "radius of the best-fitting sphere (scale factors are relative to it)",
                )
            };
            match radius.map(|r| (r, unit.at_magnitude(r))) {
                Some((_, Ok(f))) => Ok((f, why, source.to_string())),
                Some((r, Err(e))) => Err(format!("no calibration at the magnitude {}: {e}", significant(r, 7))),
                None => Err("no sphere fits the readings".to_string()),
            }
        }
    })
}
