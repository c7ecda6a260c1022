//! `magcal next CAL.json LOG`: the attitudes to visit next.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use magcal_core::aviation::{NavFrame, dcm_of_euler, euler_of_dcm, from_ned, roll_pitch_heading_deg};
use magcal_core::small::Mat3;
use magcal_core::stop::Stop;
use magcal_core::{CramerRao, InformationMatrix, PhysicalScales, Vec3, log_fit};

use super::Failure;
use crate::deadline::Deadline;
use crate::log::calibration::{CalibrationJson, RadiusMedian, columns_for, read_calibration};
use crate::log::read::HELD_BYTES_PER_READING;
use crate::log::source::{self, Log, LogArgs};
use crate::log::vehicle::{BoxFlags, DesignAxes, Place, Vehicle, check_box, fitted_problem};
use crate::output::file::{Output, replace, to_stdout};
use crate::output::stderr::to_stderr;
use crate::report::next::{AttitudeJson, MAX_PASSES, NextJson, ParameterJson, RelativeJson};
use crate::scenario::site::{Date, Site, parse_model};

/// `magcal next`.
#[derive(Debug, Args)]
pub struct NextArgs {
    /// A calibration.json written by `magcal calibrate --out` (or its `--json` output).
    pub calibration: PathBuf,
    /// The log it was fitted to (`-`: standard input).
    #[arg(value_parser = crate::log::path_parser())]
    pub log: PathBuf,
    /// A scenario file giving the vehicle's attitude box (`[attitude_box]`), the site
    /// (`[field]`, for the field's direction) and the search (`[certificate]`); or the flags
    /// below.
    /// Not needed for a vector calibration of a flight (`calibrate --fit vector*` against the
    /// field along its GPS track): its manoeuvres come from the vector model's information.
    #[arg(long, conflicts_with_all = ["site", "date", "wmm", "roll", "pitch", "yaw"])]
    pub scenario: Option<PathBuf>,
    #[command(flatten)]
    pub attitude: BoxFlags,
    /// The site, `LAT,LON[,ALT_M]`, for the field's direction from the World Magnetic Model; needs
    /// `--date`, `--roll` and `--pitch`.
    #[arg(long, requires_all = ["date", "roll", "pitch"], allow_hyphen_values = true, value_name = "LAT,LON[,ALT_M]")]
    pub site: Option<Site>,
    /// The date, `YYYY-MM-DD` or a decimal year (with `--site`).
    #[arg(long, requires = "site", value_name = "DATE")]
    pub date: Option<Date>,
    /// The model (default: the newest whose window holds the date).
    #[arg(long, requires = "site", value_parser = parse_model, value_name = "MODEL")]
    pub wmm: Option<magcal_core::wmm::Model>,
    /// The heading error the calibration may leave, degrees (as `calibrate`'s): the passes over
    /// the attitudes to add go on until the log with them meets it.
    #[arg(long, value_name = "DEG", default_value_t = magcal_core::budget::DEFAULT_BUDGET_DEG, allow_hyphen_values = true, value_parser = crate::limits::heading_budget)]
    pub heading_budget: f64,
    /// Attitudes to suggest, 1 to 1000.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=1000))]
    pub count: u64,
    /// Print one JSON object with every figure instead of the text report.
    #[arg(long)]
    pub json: bool,
    /// Also write one self-contained HTML page to this file (replaced whole; never an input):
    /// the attitudes to add as a table a pilot follows and where each falls on the sphere of
    /// MotionCal's coverage regions, the standard errors and the coverage before and after.
    #[arg(long, value_name = "FILE.html")]
    pub report: Option<PathBuf>,
    /// How to read the log, as for `calibrate` (default columns: those the calibration was made
    /// from).
    #[command(flatten)]
    pub input: LogArgs,
}

/// Runs `next`: the attitudes that most increase the information of the log (D-optimal
/// augmentation under the fitted model), with the standard errors and the certified D-efficiency
/// per reading before and after.
///
/// The calibration is checked before use, the log read with its columns unless `--columns` says
/// otherwise; a log whose median calibrated radius is outside the fit's band is refused (its
/// efficiencies and standard errors would be of another sensor or units), and a log that is not
/// the one the calibration was fitted to (SHA-256) is warned about.
///
/// # Errors
/// A bad calibration, log or scenario, a log that does not fit the calibration, or a box with a
/// range too narrow to search (exit 2).
pub fn run(args: &NextArgs) -> Result<(), Failure> {
    Ok(next_inner(args)?)
}

/// An efficiency for the screen: `None` (no certificate) and values above 1 in words, since a
/// certified D-efficiency bounds designs inside the box and is at most 1 there.
fn show_efficiency(e: Option<f64>) -> String {
    match e {
        None => "none".to_string(),
        Some(e) if e > 1.0 => format!("none ({e:.4} times the best design's information per reading)"),
        Some(e) if e >= 1e-3 => format!("{e:.4}"),
        Some(e) => format!("{e:.3e}"),
    }
}

/// Whether the full model's calibration of `readings` (the log's units) is usable, as
/// `calibrate` says it: from the calibration when it is the full fit of these very readings,
/// else by the same fit and check ([`log_fit::fit`] of the full model at the calibration's
/// magnitude); with the source.
fn usable_before(cal: &CalibrationJson, same_readings: bool, readings: &[magcal_core::Vec3]) -> (bool, String) {
    // The verdict of the same fit: the full model by the readings' residual (a calibration of
    // [P1]'s residual, or of an older magcal, is fitted again).
    if same_readings && cal.fit == log_fit::FitModel::Full.as_str() && cal.residual.as_deref() == Some("readings") {
        return (cal.usable, "calibrate's verdict of this log".to_string());
    }
    match log_fit::fit(readings, cal.magnitude, log_fit::FitModel::Full) {
        Ok(f) => (
            f.usable,
            "the full fit of this log, as calibrate fits and checks it".to_string(),
        ),
        Err(e) => (false, format!("the full fit of this log fails: {e}")),
    }
}

/// Whether `cal` is not usable for the heading budget alone.
fn budget_only(cal: &CalibrationJson) -> bool {
    !cal.reasons.is_empty() && cal.reasons.iter().all(|r| r.starts_with("heading budget not met"))
}

/// The sensor the plan assumes (see [`NextJson::planned_under`]): `cal` where it is usable, or
/// fails the heading budget alone (its estimate is determined, plausible and checked: only not
/// accurate enough, which is what the plan is for); else `cal` with the sensor of the sphere that
/// best fits `readings` (the offset model: no non-orthogonality, one scale, its centre as the
/// bias), and the words saying so.
fn planning_sensor(cal: &CalibrationJson, readings: &[Vec3]) -> (CalibrationJson, String) {
    if cal.usable {
        return (cal.clone(), "the calibration's sensor".to_string());
    }
    if budget_only(cal) {
        return (
            cal.clone(),
            "the calibration's sensor (not usable for the heading budget alone: its estimate is determined and checked)".to_string(),
        );
    }
    let sphere = log_fit::FitSettings {
        trials: 0,
        held_out: false,
        profile: false,
        ..log_fit::FitSettings::default()
    };
    match log_fit::fit_with(readings, cal.magnitude, log_fit::FitModel::Offset, &sphere) {
        Ok(f) if f.status == magcal_core::CalibrationStatus::Ok => {
            let mut planned = cal.clone();
            planned.psi_deg = f.errors.psi_deg();
            planned.scale = f.errors.scale();
            planned.bias = f.bias;
            planned.p = f.p;
            planned.k = magcal_core::small::upper_triangular_inverse(&f.p).unwrap_or(cal.k);
            (
                planned,
                "the sphere that best fits the log (the calibration is not usable, and its estimate is no sensor to plan with)"
                    .to_string(),
            )
        }
        _ => (
            cal.clone(),
            "the calibration's sensor, though not usable (no sphere fits the log)".to_string(),
        ),
    }
}

fn next_inner(args: &NextArgs) -> Result<()> {
    if args.scenario.is_none() && args.site.is_none() {
        return flight(args);
    }
    let page = page_output(args)?;
    let cal = read_calibration(&args.calibration)?;
    let (json, counts) = suggest(args, &cal, &Deadline::none())?;
    // The report is formatted in memory (a few kilobytes) and written at the end, so that a
    // failed write is one error.
    let mut w = Vec::new();
    if args.json {
        serde_json::to_writer_pretty(&mut w, &json)?;
        writeln!(w)?;
    } else {
        write_text(&mut w, &json)?;
    }
    if let Some(path) = page {
        let html = crate::report::next::page(&json, &counts[0], &counts[1])?.render()?;
        replace(path, &inputs(args), html.as_bytes()).context("--report")?;
    }
    to_stdout(|out| Ok(out.write_all(&w)?))
}

/// What a flight should fly next, for a vector calibration against the field along its track:
/// the headings it never flew and the manoeuvres of largest gain in the information of the
/// vector model, as `calibrate` computed them for this very log (its SHA-256 must match).
#[derive(Debug, serde::Serialize)]
struct FlightNextJson {
    log: String,
    calibration: String,
    fit: String,
    usable: bool,
    heading_std_deg: Option<f64>,
    headings_never_flown: Vec<[f64; 2]>,
    next_manoeuvres: Vec<String>,
}

/// `next` without a box: the flight's own manoeuvres, from a vector calibration of it.
///
/// # Errors
/// Not a vector calibration against a given field (give `--scenario` or `--site`), the log not
/// the one it was fitted to, `--report` (the flight's manoeuvres are three, not a design in a
/// box: `--count` does not apply).
fn flight(args: &NextArgs) -> Result<()> {
    let json = flight_json(args, &read_calibration(&args.calibration)?)?;
    let mut w = Vec::new();
    if args.json {
        serde_json::to_writer_pretty(&mut w, &json)?;
        writeln!(w)?;
    } else {
        write_flight(&mut w, &json)?;
    }
    to_stdout(|out| Ok(out.write_all(&w)?))
}

/// What `next --json` prints for the calibration `cal` (named by `args.calibration`) of the log
/// `args.log`: the attitudes to add in the box of `--scenario` or the flags, or without a box a
/// vector calibration's own manoeuvres; one JSON object and a line end.
///
/// # Errors
/// As [`run`].
pub fn json(args: &NextArgs, cal: &CalibrationJson) -> Result<String> {
    let mut w = Vec::new();
    if args.scenario.is_none() && args.site.is_none() {
        serde_json::to_writer_pretty(&mut w, &flight_json(args, cal)?)?;
    } else {
        serde_json::to_writer_pretty(&mut w, &suggest(args, cal, &Deadline::none())?.0)?;
    }
    writeln!(w)?;
    Ok(String::from_utf8(w)?)
}

/// The manoeuvres of [`flight`].
fn flight_json(args: &NextArgs, cal: &CalibrationJson) -> Result<FlightNextJson> {
    let shown = args.calibration.display().to_string();
    let log_shown = args.log.display().to_string();
    if cal.heading_std_deg.is_none() && cal.headings_never_flown.is_empty() && cal.next_manoeuvres.is_empty() {
        bail!(
            "{shown}: give --scenario (the vehicle's attitude box, site and search) or --site, --date, --roll and --pitch: a box is needed unless the calibration is a vector one of a flight against the field along its track (calibrate --fit vector, vector-diagonal or vector-offsets on a log with GPS fixes), which is not ({} fit)",
            cal.fit
        );
    }
    if args.report.is_some() {
        bail!("--report: a flight's manoeuvres have no page; the text or --json says them");
    }
    // Bounded as every log read is: a pipe or a device ends at the stream bounds, not never.
    let file = crate::limits::Bounded::open_log(&args.log, &log_shown)?;
    let mut hashing = crate::digest::Hashing::new(std::io::BufReader::new(file));
    // The reader's errors name the file.
    std::io::copy(&mut hashing, &mut std::io::sink())?;
    let sha = hashing.hex();
    if cal.log_sha256.as_deref() != Some(sha.as_str()) {
        bail!(
            "{log_shown}: not the log {shown} was fitted to (SHA-256 {} here): a flight's manoeuvres are its own; calibrate this log with --fit vector to have them",
            &sha[..12]
        );
    }
    Ok(FlightNextJson {
        log: log_shown,
        calibration: shown,
        fit: cal.fit.clone(),
        usable: cal.usable,
        heading_std_deg: cal.heading_std_deg,
        headings_never_flown: cal.headings_never_flown.clone(),
        next_manoeuvres: cal.next_manoeuvres.clone(),
    })
}

/// The text report of [`flight`].
fn write_flight(w: &mut dyn Write, j: &FlightNextJson) -> std::io::Result<()> {
    writeln!(
        w,
        "{}: the flight's own next manoeuvres, from the information of its {} fit against the field along its track ({})",
        j.log, j.fit, j.calibration
    )?;
    if let Some(h) = j.heading_std_deg {
        writeln!(
            w,
            "heading: the bias's largest standard error leaves {} degrees (at most {} for a usable compass)",
            magcal_logs::text::significant(h, 3),
            crate::log::flown::MAX_HEADING_STD_DEG
        )?;
    }
    if !j.headings_never_flown.is_empty() {
        writeln!(
            w,
            "never flown: headings {} (30-degree sectors with under 1 % of the readings)",
            crate::log::flown::never_flown_words(&j.headings_never_flown)
        )?;
    }
    for m in &j.next_manoeuvres {
        writeln!(w, "fly {m}")?;
    }
    if j.next_manoeuvres.is_empty() {
        writeln!(
            w,
            "{}",
            if j.usable {
                "nothing to fly: the flight points the compass well enough"
            } else {
                "no manoeuvre of the ones tried (full turns at 10, 20, 30 degrees of bank, straight legs every 30 degrees) is needed for the heading; the calibration is not usable for other reasons: see calibrate's"
            }
        )?;
    }
    Ok(())
}

/// The files `next` reads: the calibration, the log and the scenario.
fn inputs(args: &NextArgs) -> Vec<&Path> {
    [args.calibration.as_path(), args.log.as_path()]
        .into_iter()
        .chain(args.scenario.as_deref())
        .collect()
}

/// The path of `--report`, checked before any work: a file (not `-`) that may be replaced and is
/// none of the inputs.
fn page_output(args: &NextArgs) -> Result<Option<&Path>> {
    let Some(path) = args.report.as_deref() else {
        return Ok(None);
    };
    if path == Path::new("-") {
        bail!("--report -: give a file (standard output carries the report)");
    }
    Output::File(path.to_path_buf())
        .check(&inputs(args))
        .context("--report")?;
    Ok(Some(path))
}

/// What the augmentation gives, before it is put into words.
struct Augmented {
    /// The readings of the log.
    m: usize,
    /// The attitudes chosen, with the variance at each when chosen.
    chosen: Vec<(magcal_core::Attitude, f64)>,
    /// The passes over the chosen attitudes that make the log usable (`None`: not within
    /// [`MAX_PASSES`]).
    passes: Option<usize>,
    /// The body fields (nT): the log's calibrated readings, then the added readings' (the
    /// chosen attitudes, `passes` times, or [`MAX_PASSES`] times).
    body: Vec<Vec3>,
    /// The noise of the readings, nT.
    sigma: f64,
    /// The certified D-efficiency per reading before and after, and why they are `None` where the
    /// deadline left the certificate unfinished.
    efficiency: [Option<f64>; 2],
    efficiency_why_not: Option<String>,
    /// The full fit of the log with the added readings simulated (the first of its logs).
    after_fit: Result<log_fit::LogFit, magcal_core::CalibrationError>,
    /// The logs flown at the passes settled on (or the last tried).
    flown: SimulatedLogs,
}

/// What `next --json` says of the calibration `cal` and the log `args.log` in the box of
/// `--scenario` or the flags: the attitudes to add, the first the one to visit next.
///
/// # Errors
/// As [`run`].
pub fn suggestion(args: &NextArgs, cal: &CalibrationJson) -> Result<NextJson> {
    suggestion_within(args, cal, &Deadline::none())
}

/// [`suggestion`] within `deadline`: what `live` asks of each fit, so that it never holds the
/// stream up for longer than the deadline, and a signal ends it.
///
/// The choice of attitudes (every attitude added, every start of its local search) and the logs
/// simulated with them (every iteration of their fits, every round of their trials) ask the
/// deadline; where it cuts either short or leaves it no time, there is no suggestion, and the
/// error says so ([`Deadline::skipped`]: `skipped: next's simulated logs did not finish within
/// 2 s`). The coverage certificate comes last: where the deadline cuts it short, the suggestion
/// stands with `d_efficiency_before` and `d_efficiency_after` `null` and why in
/// `d_efficiency_why_not`. Reading the log again and the simulation of its readings are single
/// passes, run to their end. With [`Deadline::none`] it is [`suggestion`], number for number.
///
/// # Errors
/// As [`suggestion`]; the deadline, where it ended the work before the attitudes were settled.
pub fn suggestion_within(args: &NextArgs, cal: &CalibrationJson, deadline: &Deadline) -> Result<NextJson> {
    Ok(suggest(args, cal, deadline)?.0)
}

/// The attitudes to add and every figure of them, with the readings per MotionCal region of the
/// log's calibrated field directions before and after; within `deadline`
/// ([`suggestion_within`]).
fn suggest(args: &NextArgs, cal: &CalibrationJson, deadline: &Deadline) -> Result<(NextJson, [[usize; 100]; 2])> {
    let shown = args.calibration.display().to_string();
    let place = args.site.zip(args.date).map(|(site, date)| Place {
        site,
        date,
        model: args.wmm,
    });
    let vehicle = Vehicle::from_options(args.scenario.as_deref(), &args.attitude, place.as_ref())?
        .context("next needs --scenario, or the box as flags with --site and --date")?;
    check_box(&vehicle)?;
    let log = read_log(args, cal)?;
    let (planned, planned_under) = planning_sensor(cal, &log.readings);
    // Planned in the design problem's axes, said in the readings' (see DesignAxes).
    let axes = DesignAxes::of(&planned, &log.frame);
    let designed = axes.calibration(&planned);
    let (problem, factor) = fitted_problem(&designed, &vehicle).with_context(|| shown.clone())?;
    let turned = log.readings.into_iter().map(|s| axes.turn(s)).collect();
    let mut a = augment(
        args,
        &designed,
        (&vehicle, &problem),
        factor,
        (turned, log.in_time),
        deadline,
    )?;
    for b in &mut a.body {
        *b = magcal_core::small::mat_vec(&log.frame, *b);
    }
    // Standard errors of the sensor's parameters in the readings' axes, at the log's noise.
    let sensor = magcal_core::ErrorModel::new(planned.psi_deg, planned.scale, planned.bias.map(|b| b * factor))
        .context("the fitted sensor is outside what the model takes")?;
    let scales = PhysicalScales::default();
    let crb = [
        CramerRao::new(&sensor, &a.body[..a.m], a.sigma, &scales),
        CramerRao::new(&sensor, &a.body, a.sigma, &scales),
    ];
    let (body_log, body_all) = (&a.body[..a.m], &a.body[..]);
    let counts = [
        log_fit::motioncal_region_counts(body_log),
        log_fit::motioncal_region_counts(body_all),
    ];
    let (usable_before, usable_before_source) = log.before;
    let json = NextJson {
        log: args.log.display().to_string(),
        calibration: shown,
        readings: a.m,
        count: args.count as usize,
        attitude_box: vehicle.label.clone(),
        declination_deg: vehicle.field.declination_deg(),
        field_source: vehicle.field_source.clone(),
        attitudes: attitude_rows(&a.chosen, (&vehicle.field, &log.frame), a.passes.unwrap_or(MAX_PASSES)),
        relative_to_log: log
            .flown
            .as_ref()
            .map(|f| relative(&a.chosen, vehicle.field.yaw_offset_deg(), f)),
        parameters: parameters(&crb, factor),
        d_efficiency_before: a.efficiency[0],
        d_efficiency_after: a.efficiency[1],
        d_efficiency_why_not: a.efficiency_why_not,
        motioncal_gap_percent_before: log_fit::motioncal_gaps(body_log),
        motioncal_gap_percent_after: log_fit::motioncal_gaps(body_all),
        microstrain_coverage_percent_before: log_fit::microstrain_coverage_percent(body_log),
        microstrain_coverage_percent_after: log_fit::microstrain_coverage_percent(body_all),
        planned_under,
        usable_before,
        usable_before_source,
        passes_to_usable: a.passes,
        readings_added: a.body.len() - a.m,
        usable_after: a.passes.is_some(),
        heading_after_deg: a.flown.heading_median_deg,
        heading_budget_deg: Some(args.heading_budget),
        simulated_logs: a.flown.logs,
        simulated_logs_usable: a.flown.usable,
        usable_after_why_not: match (&a.after_fit, a.passes) {
            (_, Some(_)) => None,
            (Ok(f), None) if !f.usable => Some(few_attitudes(f.reasons.join("; "), a.chosen.len())),
            (Ok(_), None) => Some(format!(
                "{} of {} logs simulated with the readings added drawn afresh are usable ({NEXT_LOGS_USABLE} needed)",
                a.flown.usable, a.flown.logs
            )),
            (Err(e), None) => Some(few_attitudes(e.to_string(), a.chosen.len())),
        },
    };
    Ok((json, counts))
}

/// Why the log with the new attitudes is not usable, and, where there are fewer of them than the
/// full model has parameters, that the held-out fits which leave the log's own readings out cannot
/// determine it from them alone.
fn few_attitudes(why: String, attitudes: usize) -> String {
    let parameters = log_fit::FitModel::Full.parameters();
    if attitudes >= parameters {
        return why;
    }
    format!(
        "{why}; {attitudes} new attitudes are fewer than the full model's {parameters} parameters: a held-out fit without the log's own readings cannot determine it (ask for --count {parameters} or more)"
    )
}

/// The D-optimal augmentation of the log's `readings` (its units) under the planning sensor (the
/// vehicle's `problem`), the passes over it that make the log usable, and what they give; within
/// `deadline` ([`suggestion_within`]).
fn augment(
    args: &NextArgs,
    cal: &CalibrationJson,
    (vehicle, problem): (&Vehicle, &magcal_core::design::DesignProblem),
    factor: f64,
    (log_readings, in_time): (Vec<Vec3>, bool),
    deadline: &Deadline,
) -> Result<Augmented> {
    let stop = deadline.stop();
    let shown = args.calibration.display().to_string();
    let m = log_readings.len();
    let field = vehicle.field;
    let model = *problem.model();
    let r = field.magnitude();
    // The log's units to the vehicle field's (nT): only the field's direction comes from the site.
    let mut readings = log_readings;
    for s in readings.iter_mut() {
        *s = s.map(|v| v * factor);
    }
    let before = InformationMatrix::from_readings(&readings, r);
    // Flown `passes` times, each chosen attitude weighs `passes` readings against the log's: the
    // augmentation for that many passes is of the log's information divided by them (else a
    // table chosen to complement a short log, repeated until it dwarfs the log, need not
    // calibrate on its own).
    let choose = |passes: usize| -> Result<Vec<(magcal_core::Attitude, f64)>> {
        let info = before.matrix().map(|row| row.map(|v| v / passes as f64));
        vehicle
            .certificate
            .augment_until(problem, &info, args.count as usize, &stop)
            .map_err(|_| anyhow::anyhow!("{}", deadline.skipped("next's choice of attitudes")))?
            .with_context(|| format!("{}: the log's information is singular", args.log.display()))
    };
    let noise = cal
        .noise
        .ok_or_else(|| anyhow::anyhow!("{shown}: the calibration's noise is unknown (calibrate with --noise)"))?;
    let mut base = planning_readings(cal, &readings, &model, (noise, factor, r), vehicle.seed)?;
    let budget = (
        crate::pipeline::check::grid_of_box(&field, &vehicle.bounds),
        args.heading_budget,
    );
    let body_fields = |chosen: &[(magcal_core::Attitude, f64)]| -> Vec<Vec3> {
        let attitudes: Vec<magcal_core::Attitude> = chosen.iter().map(|c| c.0).collect();
        field.body_fields(&attitudes)
    };
    let order = if in_time {
        log_fit::Order::Time
    } else {
        log_fit::Order::Unknown
    };
    let tried = passes_to_usable(
        &mut base,
        &model,
        |p| choose(p).map(|c| (body_fields(&c), c)),
        (noise * factor, order, &stop),
        r,
        vehicle.seed,
        &budget,
    );
    let (passes, after_fit, chosen, added, flown) =
        unless_expired(tried, deadline)?.with_context(|| format!("{shown}: noise {noise}"))?;
    drop(base);
    // The information of noise-free readings ([P1] eq. (12)).
    readings.extend(model.measure_all(&added));
    let after = InformationMatrix::from_readings(&readings, r);
    // The body fields: the log's calibrated (P (s - O), in nT), then the added attitudes'.
    readings.truncate(m);
    let bias_nt = cal.bias.map(|b| b * factor);
    for s in readings.iter_mut() {
        *s = magcal_core::small::mat_vec(&cal.p, magcal_core::small::sub(*s, bias_nt));
    }
    let n_added = added.len();
    readings.extend(added);
    let (efficiency, efficiency_why_not) =
        efficiencies((vehicle, problem), [(&before, m), (&after, m + n_added)], deadline);
    Ok(Augmented {
        m,
        efficiency,
        efficiency_why_not,
        chosen,
        passes,
        body: readings,
        sigma: noise * factor,
        after_fit,
        flown,
    })
}

/// What the passes gave, unless `deadline` passed while they ran: a choice of attitudes it cut
/// short (the passes' error then) or logs whose fits it stopped are no verdict of them, and the
/// error says which was skipped.
fn unless_expired(tried: Result<Tried>, deadline: &Deadline) -> Result<Result<Tried>> {
    if !deadline.expired() {
        return Ok(tried);
    }
    let stage = if tried.is_err() {
        "next's choice of attitudes"
    } else {
        "next's simulated logs"
    };
    bail!("{}", deadline.skipped(stage))
}

/// The certified D-efficiency per reading of each information with its number of readings, in
/// the vehicle's box under `problem`'s sensor (`None` where no design in the box determines the
/// model); both `None`, and why, where `deadline` cuts the certificate short.
fn efficiencies(
    (vehicle, problem): (&Vehicle, &magcal_core::design::DesignProblem),
    informations: [(&InformationMatrix, usize); 2],
    deadline: &Deadline,
) -> ([Option<f64>; 2], Option<String>) {
    match vehicle.certificate_until(problem, &deadline.stop()) {
        Ok(c) => (
            informations.map(|(info, m)| c.as_ref().map(|c| c.efficiency_bound(info.ln_det_nt(), m))),
            None,
        ),
        Err(_) => ([None; 2], Some(deadline.skipped("next's coverage certificate"))),
    }
}

/// The log's readings (nT) as the planning sensor reads them. Added readings of the planning
/// sensor join the log's own where that sensor is the calibration's (usable, or failing only the
/// heading budget); planned under the sphere, the log's readings are read again by the sphere's
/// sensor at their field directions under it, so that one sensor reads them all.
fn planning_readings(
    cal: &CalibrationJson,
    readings: &[Vec3],
    model: &magcal_core::ErrorModel,
    (noise, factor, r): (f64, f64, f64),
    seed: u64,
) -> Result<Vec<Vec3>> {
    if cal.usable || budget_only(cal) {
        return Ok(readings.to_vec());
    }
    let directions: Vec<Vec3> = readings
        .iter()
        .map(|s| {
            let b = magcal_core::small::mat_vec(&cal.p, magcal_core::small::sub(*s, cal.bias.map(|v| v * factor)));
            magcal_core::small::scale(r / magcal_core::small::norm(b), b)
        })
        .collect();
    Ok(model.noisy_readings(
        &directions,
        noise * factor,
        &mut crate::pipeline::simulated_log_rng(seed ^ 1),
    )?)
}

/// A fit of the log with readings added, or why there is none.
type FitResult = Result<log_fit::LogFit, magcal_core::CalibrationError>;

/// The attitudes chosen for a number of passes: their body fields (nT) and the attitudes with
/// the variance at each when chosen.
type Chosen = (Vec<Vec3>, Vec<(magcal_core::Attitude, f64)>);

/// What the passes tried gave: the passes that make the log usable (`None` where none tried
/// does), the fit, the attitudes and the body fields added at the last tried, and its simulated
/// logs.
type Tried = (
    Option<usize>,
    FitResult,
    Vec<(magcal_core::Attitude, f64)>,
    Vec<Vec3>,
    SimulatedLogs,
);

/// Logs flown (simulated) at the passes `next` settles on, each with the readings added drawn
/// afresh: one log's figure carries its own noise (a log 5 % above the budget was told that 20
/// readings reach it, 1.9 degrees predicted, and flown gave 2.05), so the passes must make most
/// of them usable.
pub const NEXT_LOGS: usize = 5;

/// Of [`NEXT_LOGS`], the usable ones the passes need.
pub const NEXT_LOGS_USABLE: usize = 4;

/// The simulated logs of the last passes tried: how many, how many usable, and the median of
/// their predicted heading figures (degrees; `None` where none has one).
#[derive(Debug, Clone, Copy)]
struct SimulatedLogs {
    logs: usize,
    usable: usize,
    heading_median_deg: Option<f64>,
}

/// The fewest passes (1, 2, 4, ... up to [`MAX_PASSES`]) over the attitudes `choose` gives for
/// that many passes whose readings, simulated from `model` with noise `sigma` (as `simulate`
/// draws it) and added after the log's `readings` (nT; in `order`: a log in time order keeps its
/// blocks, so a drift the log holds is still seen), make the full calibration of the log usable
/// (its check by trials and heading budget included: what `calibrate` would say of the log flown
/// so) in [`NEXT_LOGS_USABLE`] of [`NEXT_LOGS`] logs whose added readings are drawn afresh (the
/// first drawn; the others only where it is usable). Returns the passes (`None` where even the
/// most do not), the first log's fit, the attitudes and the body fields added at the last tried,
/// and its logs. `readings` holds the log and the last readings tried. The fits ask `stop`.
fn passes_to_usable(
    readings: &mut Vec<Vec3>,
    model: &magcal_core::ErrorModel,
    choose: impl Fn(usize) -> Result<Chosen>,
    (sigma, order, stop): (f64, log_fit::Order, &Stop),
    r: f64,
    seed: u64,
    budget: &(magcal_core::budget::BudgetGrid, f64),
) -> Result<Tried> {
    let m = readings.len();
    // The log with the readings `added` drawn on stream `k` (0: the seed's own), fitted and
    // judged as calibrate judges it: the heading over the vehicle's box against the budget.
    let mut fly = |added: &[Vec3], k: u64| -> Result<FitResult> {
        let mut rng = crate::pipeline::simulated_log_rng(seed ^ (k << 32));
        let simulated = model.noisy_readings(added, sigma, &mut rng)?;
        readings.truncate(m);
        readings.extend(simulated);
        Ok(crate::pipeline::check::judged_as_calibrate(
            readings,
            r,
            order,
            (&budget.0, budget.1),
            stop,
        ))
    };
    let figure = |f: &FitResult| {
        f.as_ref()
            .ok()
            .and_then(|f| f.heading.as_ref())
            .map(magcal_core::budget::HeadingVerdict::predicted_deg)
    };
    let mut passes = 1;
    loop {
        let (fields, chosen) = choose(passes)?;
        let added: Vec<Vec3> = (0..passes).flat_map(|_| fields.iter().copied()).collect();
        let fit = fly(&added, 0)?;
        let mut figures: Vec<f64> = figure(&fit).into_iter().collect();
        let mut usable = usize::from(fit.as_ref().is_ok_and(|f| f.usable));
        let mut logs = 1;
        if usable == 1 {
            for k in 1..NEXT_LOGS as u64 {
                let other = fly(&added, k)?;
                usable += usize::from(other.as_ref().is_ok_and(|f| f.usable));
                figures.extend(figure(&other));
                logs += 1;
            }
        }
        let flown = SimulatedLogs {
            logs,
            usable,
            heading_median_deg: (!figures.is_empty()).then(|| magcal_core::budget::quantile(&mut figures, 0.5)),
        };
        if usable >= NEXT_LOGS_USABLE {
            return Ok((Some(passes), fit, chosen, added, flown));
        }
        if passes >= MAX_PASSES {
            return Ok((None, fit, chosen, added, flown));
        }
        passes *= 2;
    }
}

/// The text report of `j`.
fn write_text(w: &mut Vec<u8>, j: &NextJson) -> Result<()> {
    writeln!(
        w,
        "{} readings of {}; the next {} attitudes in the box of {} (D-optimal augmentation of the log's information):",
        j.readings, j.log, j.count, j.attitude_box
    )?;
    write_attitudes(w, j)?;
    if let Some(r) = &j.relative_to_log {
        writeln!(
            w,
            "  relative to the log's {} attitudes (heading clockwise from north, degrees):",
            r.flown
        )?;
        for tilt in &r.tilts {
            writeln!(w, "    {tilt}")?;
        }
        if let Some(enu) = &r.as_logged {
            writeln!(
                w,
                "  as the log gives attitudes (ENU, body forward-left-up: roll, pitch, yaw counter-clockwise from east), in the table's order: {enu}"
            )?;
        }
    }
    write_information(w, j)?;
    writeln!(
        w,
        "coverage: MotionCal gaps before {:.1} %, after {:.1} %; MicroStrain spatial coverage before {:.1} %, after {:.1} %",
        j.motioncal_gap_percent_before,
        j.motioncal_gap_percent_after,
        j.microstrain_coverage_percent_before,
        j.microstrain_coverage_percent_after
    )?;
    writeln!(w, "planned under {}", j.planned_under)?;
    writeln!(
        w,
        "usable (full model): before {} ({}); after {}{} ({} readings at these attitudes, {}; the full fit of the log with them simulated at the log's noise, checked as calibrate checks a log{})",
        j.usable_before,
        j.usable_before_source,
        j.usable_after,
        j.heading_after_deg
            .zip(j.heading_budget_deg)
            .map_or(String::new(), |(h, b)| format!(
                ", heading {} deg predicted at the 95th percentile over the box (budget {}), the median over {} log{} simulated, {} of them usable",
                magcal_logs::text::significant(h, 3),
                crate::limits::show(b),
                j.simulated_logs,
                if j.simulated_logs == 1 { "" } else { "s" },
                j.simulated_logs_usable
            )),
        j.readings_added,
        match j.passes_to_usable {
            Some(1) => "the table as it stands".to_string(),
            Some(n) => format!("{n} passes of the table"),
            None => format!("{MAX_PASSES} passes of the table, the most tried"),
        },
        j.usable_after_why_not
            .as_ref()
            .map_or(String::new(), |why| format!(": {why}"))
    )?;
    Ok(())
}

/// The log's readings (in its units), the rows skipped, and whether the log was identifiable
/// before (and on what that rests); the log must be the one the calibration was fitted to, by its
/// calibrated radius.
fn read_log(args: &NextArgs, cal: &CalibrationJson) -> Result<LogRead> {
    let shown = args.calibration.display().to_string();
    let log_shown = args.log.display().to_string();
    let mut input = args.input.clone();
    input.columns = columns_for(cal, &shown, &args.log, &input)?;
    // The flags that made a calibration with motor interference are taken as they were given.
    input.motor = cal.motor.is_some();
    let Log {
        readings: log_readings,
        skipped,
        columns: read_columns,
        sha256: sha,
        attitudes,
        origin,
        times,
        ..
    } = source::open(&args.log, &input, HELD_BYTES_PER_READING)?;
    for (line, reason) in &skipped {
        to_stderr!("magcal: skipped line {line}: {reason}");
    }
    let flown = attitudes.map(|a| Flown {
        attitudes: a.into_iter().flatten().collect(),
        frame: origin.attitude_frame,
    });
    // The readings alone are kept (24 bytes each), turned into nT and then into body fields in
    // place.
    let m = log_readings.len();
    let mut radius = RadiusMedian::new(cal.magnitude);
    for s in &log_readings {
        radius.push(cal.apply(*s));
    }
    if let Some(why) = cal.radius_mismatch(radius.ratio()) {
        bail!("{log_shown}: {why}; next needs the log the calibration {shown} was fitted to");
    }
    let same_file = match &cal.log_sha256 {
        // The reader hashed the bytes it parsed: the file is not read a second time.
        Some(recorded) => {
            if &sha != recorded {
                to_stderr!(
                    "magcal: warning: {log_shown} is not the log {shown} was fitted to ({}; SHA-256 {} there, {} here): the suggestions add to the log given",
                    cal.log,
                    crate::limits::excerpt(recorded, 12),
                    &sha[..12]
                );
            }
            &sha == recorded
        }
        None => false,
    };
    let same_readings = same_file && read_columns == cal.columns && m == cal.samples && skipped.len() == cal.skipped;
    let before = usable_before(cal, same_readings, &log_readings);
    Ok(LogRead {
        readings: log_readings,
        in_time: times.is_some(),
        frame: crate::log::vehicle::readings_frame(origin.format),
        flown,
        before,
    })
}

/// What [`read_log`] returns.
struct LogRead {
    /// The readings, in the log's units.
    readings: Vec<Vec3>,
    /// Whether they are in time order (the log has times): the log with readings added is then
    /// fitted as `calibrate` fits it, its held-out folds consecutive blocks that see a drift.
    in_time: bool,
    /// The rotation of [P1]'s body axes into the readings' axes.
    frame: Mat3,
    /// The attitudes the log flew, where it has them.
    flown: Option<Flown>,
    /// Whether the log's full calibration was usable before, and on what that rests.
    before: (bool, String),
}

/// The rows of the table of attitudes to add: the same attitude chosen again is one row, with its
/// readings and the first variance.
fn table_rows(chosen: &[(magcal_core::Attitude, f64)]) -> Vec<(magcal_core::Attitude, usize, f64)> {
    let mut rows: Vec<(magcal_core::Attitude, usize, f64)> = Vec::new();
    for (a, d) in chosen {
        match rows.last_mut() {
            Some(last) if magcal_core::design::tour::rotation_angle(&last.0, a) < 1e-6 => last.1 += 1,
            _ => rows.push((*a, 1, *d)),
        }
    }
    rows
}

/// The attitudes to add as a pilot reads them: roll, pitch, true and magnetic heading, readings
/// (its choices times the `passes` that make the log usable), the variance of the linear model's
/// prediction there, and the direction of the field the sensor reads there; the same attitude
/// chosen again is one row with its readings.
fn attitude_rows(
    chosen: &[(magcal_core::Attitude, f64)],
    (field, frame): (&magcal_core::ReferenceField, &Mat3),
    passes: usize,
) -> Vec<AttitudeJson> {
    // The headings a pilot reads: true, and magnetic from the declination of the vehicle's field.
    let headings = crate::output::Headings::of(field);
    let rows = table_rows(chosen);
    let attitudes: Vec<magcal_core::Attitude> = rows.iter().map(|r| r.0).collect();
    let fields = field.body_fields(&attitudes);
    rows.iter()
        .zip(fields)
        .enumerate()
        .map(|(k, ((a, n, d), f))| {
            let [roll, _, pitch] = a.to_degrees();
            let length = magcal_core::small::norm(f);
            AttitudeJson {
                k: k + 1,
                roll_deg: roll,
                pitch_deg: pitch,
                true_heading_deg: headings.true_heading(a).0,
                magnetic_heading_deg: headings.magnetic_heading(a).map(|h| h.0),
                readings: *n * passes,
                variance: *d,
                field_direction: magcal_core::small::mat_vec(frame, f.map(|c| c / length)),
            }
        })
        .collect()
}

/// The table of attitudes to add, under the line naming the declination.
fn write_attitudes(w: &mut Vec<u8>, j: &NextJson) -> Result<()> {
    writeln!(
        w,
        "  {}",
        crate::output::print::declination_line(j.declination_deg, &j.field_source)
    )?;
    writeln!(
        w,
        "  {:>4} {:>9} {:>9} {:>9} {:>9} {:>8} {:>12}",
        "k", "roll_deg", "pitch_deg", "true_hdg", "mag_hdg", "readings", "variance d"
    )?;
    for a in &j.attitudes {
        writeln!(
            w,
            "  {:>4} {:>9.2} {:>9.2} {:>9.2} {:>9} {:>8} {:>12.4}",
            a.k,
            a.roll_deg,
            a.pitch_deg,
            a.true_heading_deg,
            a.magnetic_heading_deg.map_or("-".to_string(), |h| format!("{h:.2}")),
            a.readings,
            a.variance
        )?;
    }
    Ok(())
}

/// The attitudes a log flew (NED convention) and the convention in which the log gives them.
struct Flown {
    attitudes: Vec<Mat3>,
    frame: NavFrame,
}

/// The attitude `a` of \[P1\] as a NED-convention `C`: the same roll and pitch, the heading
/// `-(yaw + yaw offset)` (docs/conventions.md "Sense of the angles").
fn ned_of(a: &magcal_core::Attitude, yaw_offset_deg: f64) -> Mat3 {
    dcm_of_euler(a.roll, a.pitch, -(a.yaw + yaw_offset_deg.to_radians()))
}

/// The angle of the rotation between two attitudes, degrees.
fn angle_between(a: &Mat3, b: &Mat3) -> f64 {
    let trace: f64 = (0..3).map(|i| (0..3).map(|k| a[k][i] * b[k][i]).sum::<f64>()).sum();
    ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

/// A tilt in words: `level`, or the pitch and roll that are not within half a degree of 0.
fn tilt_words(roll: f64, pitch: f64) -> String {
    let mut parts = Vec::new();
    if pitch.abs() >= 0.5 {
        parts.push(format!(
            "nose {} {:.0}",
            if pitch > 0.0 { "up" } else { "down" },
            pitch.abs()
        ));
    }
    if roll.abs() >= 0.5 {
        parts.push(format!(
            "{} side down {:.0}",
            if roll > 0.0 { "right" } else { "left" },
            roll.abs()
        ));
    }
    if parts.is_empty() {
        "level".to_string()
    } else {
        parts.join(", ")
    }
}

/// The attitudes to add relative to what the log flew: each as a tilt at headings, how far the
/// nearest attitude the log flew lies, and (for a log in the ENU convention) the roll, pitch and
/// yaw the log itself would show.
fn relative(chosen: &[(magcal_core::Attitude, f64)], yaw_offset_deg: f64, flown: &Flown) -> RelativeJson {
    // Tilts rounded to a degree, each with its headings, in the order first chosen.
    let mut tilts: Vec<(String, Vec<String>, f64)> = Vec::new();
    let mut enu = Vec::new();
    for (a, _, _) in &table_rows(chosen) {
        let c = ned_of(a, yaw_offset_deg);
        let [roll, pitch, heading] = roll_pitch_heading_deg(&c);
        let tilt = tilt_words(roll, pitch);
        let nearest = flown
            .attitudes
            .iter()
            .map(|f| angle_between(f, &c))
            .fold(f64::INFINITY, f64::min);
        let heading = format!("{}", (heading.round() as i64).rem_euclid(360));
        match tilts.iter_mut().find(|t| t.0 == tilt) {
            Some(t) if t.1.contains(&heading) => {}
            Some(t) => {
                t.1.push(heading);
                t.2 = t.2.max(nearest);
            }
            None => tilts.push((tilt, vec![heading], nearest)),
        }
        if flown.frame == NavFrame::Enu {
            let [r, p, y] = euler_of_dcm(&from_ned(&c, NavFrame::Enu)).map(f64::to_degrees);
            enu.push(format!("({r:.1}, {p:.1}, {y:.1})"));
        }
    }
    RelativeJson {
        flown: flown.attitudes.len(),
        tilts: tilts
            .iter()
            .map(|(tilt, headings, nearest)| {
                format!(
                    "{tilt} at heading{} {}: the log came within {nearest:.0} degrees of {}",
                    if headings.len() > 1 { "s" } else { "" },
                    headings.join(", "),
                    if headings.len() > 1 { "each" } else { "it" }
                )
            })
            .collect(),
        as_logged: (!enu.is_empty()).then(|| enu.join(", ")),
    }
}

/// The standard error of each parameter before and after the added readings, the bias in the
/// log's units (`factor` turns those into nT).
fn parameters(crb: &[CramerRao; 2], factor: f64) -> Vec<ParameterJson> {
    let names = magcal_core::identifiability::PARAMETERS;
    (0..9)
        .map(|i| {
            let unit = if i >= 6 { 1.0 / factor } else { 1.0 };
            let std = |c: &CramerRao| c.std.map(|s| s[i] * unit);
            ParameterJson {
                name: names[i].trim_end_matches("_nt").to_string(),
                std_before: std(&crb[0]),
                std_after: std(&crb[1]),
            }
        })
        .collect()
}

/// The standard error of each parameter before and after the added readings, and the certified
/// D-efficiency of the log before and after.
fn write_information(w: &mut Vec<u8>, j: &NextJson) -> Result<()> {
    let (e_before, e_after) = (j.d_efficiency_before, j.d_efficiency_after);
    writeln!(
        w,
        "\n  {:<10} {:>14} {:>14}  (bias in the log's units)",
        "parameter", "std before", "std after"
    )?;
    for p in &j.parameters {
        let show = |s: Option<f64>| s.map_or("singular".to_string(), |s| format!("{s:.4e}"));
        writeln!(
            w,
            "  {:<10} {:>14} {:>14}",
            p.name,
            show(p.std_before),
            show(p.std_after)
        )?;
    }
    writeln!(
        w,
        "\ncertified D-efficiency per reading in this box: before {}, after {} (against every design of as many readings)",
        show_efficiency(e_before),
        show_efficiency(e_after)
    )?;
    if e_before.is_none() {
        writeln!(
            w,
            "  no design in this box determines the linear model ([P1] eq. (9)-(12)): there is no bound to compare with"
        )?;
    } else if e_before.into_iter().chain(e_after).any(|e| e > 1.0) {
        writeln!(
            w,
            "  above 1 is no efficiency: the certificate bounds designs inside the box, and these readings hold more information per reading than any of them, so they come from attitudes outside it"
        )?;
    }
    Ok(())
}
