//! `magcal live SOURCE`: calibrate while the vehicle turns, and say where to turn next.
//!
//! A reader thread ([`source`]) takes the stream as it arrives (MAVLink over UDP, TCP or a serial
//! device; MotionCal's `Raw:` lines or CSV rows) into a bounded ring ([`buffer`]). The command's
//! own thread fits: at most once per `--every` seconds, on a snapshot of the ring written as the
//! log it is (a telemetry log, a CSV log) and read by the same reader, calibration and verdict as
//! `calibrate` ([`crate::commands::calibrate::calibrate`]), then the attitude to visit next as
//! `next` gives it for those readings ([`crate::commands::next::suggestion`]). So what `live`
//! says of its readings is what `calibrate` and `next` say of the same readings saved to a file
//! (`--record`). The reader never waits on a fit: a fit that takes longer than the stream means
//! fewer fits, each on the newest readings.
//!
//! At every usable fit the calibration set of `--out` is replaced whole (as `calibrate --out`
//! writes it) and the export for the source's autopilot is shown; Ctrl-C ends the command after
//! the fit under way, with what it has written whole.

pub mod ask;
pub mod buffer;
pub mod guide;
pub mod page;
pub mod send;
pub mod source;

use std::io::{IsTerminal, Write};

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;

use self::source::{Counts, Shared, Source};
use super::Failure;
use super::calibrate::{CalibrateArgs, Calibrated, Fit, ResidualArg};
use super::next::NextArgs;
use crate::deadline::Deadline;
use crate::log::calibration::CalibrationJson;
use crate::log::export::Target as ExportTarget;
use crate::log::read::HELD_BYTES_PER_READING;
use crate::log::source::{FormatArg, LogArgs};
use crate::log::vehicle::BoxFlags;
use crate::output::staging::{ResultSet, Target};
use crate::output::stderr::to_stderr;
use crate::scenario::site::{Date, Site, Units, parse_model};

/// `magcal live`.
#[derive(Debug, Args)]
pub struct LiveArgs {
    /// Where the readings come from: `udpin:ADDR:PORT` (MAVLink datagrams sent to this address,
    /// as a vehicle's telemetry or MAVProxy's `--out` forwards them), `tcp:HOST:PORT` (MAVLink
    /// from a TCP server: SITL's `tcp:127.0.0.1:5760`), `serial:PATH:BAUD` (MAVLink on a serial
    /// device), `lines:PATH[:BAUD]` (text lines from a device or a file: MotionCal's `Raw:` lines
    /// from the Adafruit calibration sketch, or CSV rows), or `-` (lines on standard input).
    #[arg(value_parser = parse_source, allow_hyphen_values = true)]
    pub source: Source,
    /// The calibration set to write (as `calibrate --out`): replaced whole at every usable fit;
    /// where no fit was usable, the last fit's at the end. DIR must be missing, empty or an
    /// earlier calibration set.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Also write what the stream brought, as it arrives: a telemetry log (MAVLink sources: every
    /// valid frame with its time of arrival) or a CSV log (lines: the readings' rows), for
    /// `calibrate` and `next` afterwards. The file must not exist.
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// The stream held in memory, MiB: the newest records within it (older ones are dropped and
    /// counted; a vehicle's parameters are kept). A fit reads a snapshot of them, and needs about
    /// as much again for its readings.
    #[arg(long = "memory", value_name = "MIB", default_value_t = 64, value_parser = clap::value_parser!(u64).range(1..=4096))]
    pub memory_mib: u64,
    /// Seconds between the starts of two fits, at least.
    #[arg(long, value_name = "SECONDS", default_value_t = 1.0, value_parser = crate::limits::finite)]
    pub every: f64,
    /// Seconds a fit may take, at most (default: 5 s and 20 us for each reading it holds, three
    /// times what a full fit of 200,000 readings takes on two cores): a stage with no time left
    /// is skipped and one cut short thrown away, each said in the fit's reasons, so that the plan
    /// and the page keep up with the stream. Ctrl-C ends a fit under way.
    #[arg(long, value_name = "SECONDS", value_parser = crate::limits::finite)]
    pub fit_within: Option<f64>,
    /// Serve a page that follows the fits on http://127.0.0.1:PORT/ (0: a free port, printed):
    /// the verdict, the attitude to visit next, the field directions and attitudes covered, the
    /// export. Bound to this machine only.
    #[arg(long, value_name = "PORT")]
    pub page: Option<u16>,
    /// End at the first usable fit.
    #[arg(long)]
    pub until_usable: bool,
    /// Send the first usable calibration to the vehicle (MAVLink sources) and end: `PARAM_SET`
    /// of each parameter `export --to ardupilot` writes, over the link it streams on, each read
    /// back from the autopilot's `PARAM_VALUE` and compared (exit 3 unless every one holds).
    #[arg(long)]
    pub send: bool,
    /// With `--send`: the vehicle, `SYSTEM[:COMPONENT]`, where several autopilots speak on the
    /// link (default: the first autopilot whose `HEARTBEAT` comes with compass frames; with a
    /// second such, nothing is sent until this chooses).
    #[arg(long, value_name = "SYSTEM[:COMPONENT]", value_parser = parse_vehicle)]
    pub vehicle: Option<(u8, Option<u8>)>,
    /// With `--send`: send what `export` warns of (offsets beyond the vehicle's
    /// `COMPASS_OFFS_MAX`, parts of the calibration its parameters cannot hold).
    #[arg(long, requires = "send")]
    pub force: bool,
    /// End when nothing arrived for this many seconds, counted from the start while nothing has
    /// (default: a network or serial source runs until Ctrl-C; a file or standard input ends at
    /// its end).
    #[arg(long, value_name = "SECONDS", value_parser = crate::limits::finite)]
    pub idle: Option<f64>,
    /// A scenario file: the attitude box the next attitude is chosen in, its site and search,
    /// and the coverage's D-efficiency (as for `calibrate` and `next`); or the box as flags.
    #[arg(long, conflicts_with_all = ["roll", "pitch", "yaw"])]
    pub scenario: Option<PathBuf>,
    #[command(flatten)]
    pub attitude: BoxFlags,
    /// The site, `LAT,LON[,ALT_M]` (with `--date`): the field's magnitude and direction from the
    /// World Magnetic Model.
    #[arg(long, requires = "date", allow_hyphen_values = true, value_name = "LAT,LON[,ALT_M]")]
    pub site: Option<Site>,
    /// The date, `YYYY-MM-DD` or a decimal year.
    #[arg(long, value_name = "DATE")]
    pub date: Option<Date>,
    /// The World Magnetic Model (default: the newest whose window holds the date).
    #[arg(long, requires = "site", value_parser = parse_model, value_name = "MODEL")]
    pub wmm: Option<magcal_core::wmm::Model>,
    /// The readings' units (MAVLink: mG, fixed; `Raw:` lines: uT; CSV rows: say them).
    #[arg(long, value_enum)]
    pub units: Option<Units>,
    /// The field magnitude in the readings' units (default: the WMM's at `--site`, else the
    /// fitted mean radius).
    #[arg(long, conflicts_with = "units", value_parser = crate::limits::finite)]
    pub magnitude: Option<f64>,
    /// The model, as for `calibrate`.
    #[arg(long, value_enum, default_value = "full")]
    pub fit: Fit,
    /// The readings' noise per component, in their units (default: estimated from the residuals).
    #[arg(long, value_name = "SIGMA", value_parser = crate::limits::finite)]
    pub noise: Option<f64>,
    /// Noisy trials of each fit's verdict, as for `calibrate`.
    #[arg(long, default_value_t = magcal_core::log_fit::CHECK_TRIALS as u64, value_parser = clap::value_parser!(u64).range(20..=100_000))]
    pub trials: u64,
    /// The seed of the trials' random streams.
    #[arg(long, default_value_t = magcal_core::log_fit::CHECK_SEED)]
    pub seed: u64,
    /// The heading error the calibration may leave, degrees (as `calibrate`'s): the finish line.
    /// Nothing is exported, sent or called usable before a fit meets it.
    #[arg(long, value_name = "DEG", default_value_t = magcal_core::budget::DEFAULT_BUDGET_DEG, allow_hyphen_values = true, value_parser = crate::limits::heading_budget)]
    pub heading_budget: f64,
    /// Attitudes to suggest at each fit (the first is the one to visit next).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=100))]
    pub count: u64,
    /// Print one JSON object when it ends (what arrived and was dropped, the fits, the last
    /// fit's verdict and next attitude, the set written) instead of the text.
    #[arg(long)]
    pub json: bool,
    /// How to read the readings, as for `calibrate` (`--format` is the source's).
    #[command(flatten)]
    pub input: LogArgs,
}

fn parse_source(s: &str) -> Result<Source, String> {
    s.parse()
}

fn parse_vehicle(s: &str) -> Result<(u8, Option<u8>), String> {
    let id = |p: &str| {
        p.parse::<u8>()
            .map_err(|_| format!("{s:?}: give SYSTEM[:COMPONENT], each 0 to 255"))
    };
    match s.split_once(':') {
        Some((sys, comp)) => Ok((id(sys)?, Some(id(comp)?))),
        None => Ok((id(s)?, None)),
    }
}

/// What one fit of the stream gave.
struct Fitted {
    /// Readings fitted.
    readings: usize,
    json: Option<CalibrationJson>,
    /// Why there is no calibration, or why it is not usable.
    why: String,
    next: Result<Option<magcal_report::pages::next::AttitudeJson>, String>,
    /// `next`'s attitudes for the plan (the first is `next`'s).
    fresh: Vec<magcal_report::pages::next::AttitudeJson>,
    seconds: f64,
    /// The log as read, for the calibration set.
    log: Option<crate::log::source::Log>,
    rows: usize,
    /// Whether `why` is an option that does not apply to the stream (exit 2 if it is the last).
    bad_option: bool,
}

/// Runs `live` until the source ends, `--idle` passes, Ctrl-C, or (with `--until-usable`) the
/// first usable fit.
///
/// # Errors
/// A bad option, a source that cannot be opened, an output that cannot be written (exit 2,
/// before anything is written); no usable fit when it ends ([`Failure::Unusable`], exit 3, after
/// the last fit's set is written).
pub fn run(args: &LiveArgs) -> Result<(), Failure> {
    check(args)?;
    let inputs: Vec<&Path> = args
        .record
        .iter()
        .map(PathBuf::as_path)
        .chain(args.scenario.as_deref())
        .collect();
    // Everything that can be refused is, before the one file live creates at its start.
    drop(ResultSet::begin(&args.out, Target::Calibration, &inputs)?);
    if let Some(p) = &args.record
        && std::fs::symlink_metadata(p).is_ok()
    {
        return Err(Failure::Input(anyhow::anyhow!(
            "--record {}: it exists (live writes a new file, never over one)",
            p.display()
        )));
    }
    let shared = Shared::new(usize::try_from(args.memory_mib << 20).unwrap_or(usize::MAX));
    let [roll_box, pitch_box] = box_of(args).map_or([None, None], |[r, p]| [Some(r), Some(p)]);
    let status = Arc::new(Mutex::new(page::Status {
        source: source::shown(&args.source),
        out: args.out.display().to_string(),
        roll_box,
        pitch_box,
        region_bounds: (0..100).map(magcal_core::log_fit::motioncal_region).collect(),
        ..page::Status::default()
    }));
    let page = args.page.map(|port| page::serve(port, &shared, &status)).transpose()?;
    let record = match &args.record {
        Some(p) => Some(
            std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(p)
                .with_context(|| format!("--record {}: cannot be created (it must not exist)", p.display()))?,
        ),
        None => None,
    };
    let started = match source::start(&args.source, &shared, record) {
        Ok(started) => started,
        Err(e) => {
            // The source could not be opened: the recording it would have had is not left behind.
            if let Some(p) = &args.record {
                let _ = std::fs::remove_file(p);
            }
            return Err(e.into());
        }
    };
    let reading = started.reading;
    shared.lock().wanted = args.vehicle;
    let link = started.link.map(|l| Arc::new(Mutex::new(l)));
    if let Some(l) = &link {
        let (required, optional) = ask::in_force_names(args.input.compass.unwrap_or(0));
        let names = required.into_iter().chain(optional).collect();
        ask::start(Arc::clone(l), Arc::clone(&shared), names);
    }
    to_stderr!(
        "live: reading {reading}; fits at most every {} s; Ctrl-C ends it",
        args.every
    );
    status.lock().unwrap_or_else(PoisonError::into_inner).source = reading;
    if let Some(addr) = page {
        to_stderr!("live: page at http://{addr}/");
    }
    let stop = Arc::clone(&shared);
    // A second handler cannot be set in one process (the library bindings run commands in theirs).
    let _ = ctrlc::set_handler(move || {
        stop.stop.store(true, Ordering::Relaxed);
        stop.changed.notify_all();
    });
    let snapshot = Snapshot::new(args.source.is_mavlink());
    let view = View {
        status,
        budget_deg: args.heading_budget,
    };
    let result = fit_loop(args, &shared, &snapshot, &inputs, &view, link.as_deref());
    shared.stop.store(true, Ordering::Relaxed);
    result
}

/// Options that do not depend on the stream.
fn check(args: &LiveArgs) -> Result<()> {
    if args.send && !args.source.is_mavlink() {
        bail!(
            "--send: {} carries lines, not MAVLink: there is no vehicle to send parameters to",
            source::shown(&args.source)
        );
    }
    if args.vehicle.is_some() && !args.source.is_mavlink() {
        bail!(
            "--vehicle: {} carries lines, not MAVLink: there is no vehicle to choose",
            source::shown(&args.source)
        );
    }
    if args.every <= 0.0 {
        bail!("--every {}: give a positive number of seconds", args.every);
    }
    if let Some(b) = args.fit_within
        && b <= 0.0
    {
        bail!("--fit-within {b}: give a positive number of seconds");
    }
    if let Some(i) = args.idle
        && i <= 0.0
    {
        bail!("--idle {i}: give a positive number of seconds");
    }
    let wanted = if args.source.is_mavlink() {
        FormatArg::Tlog
    } else {
        FormatArg::Csv
    };
    if args.input.format != FormatArg::Auto && args.input.format != wanted {
        bail!(
            "--format: {} carries {} (the format is the source's)",
            source::shown(&args.source),
            if args.source.is_mavlink() {
                "MAVLink"
            } else {
                "lines of CSV"
            }
        );
    }
    if args.site.is_some() != args.date.is_some() {
        bail!("--site and --date go together");
    }
    Ok(())
}

/// The file a fit reads: the ring's snapshot as a log, removed when the command ends.
struct Snapshot {
    path: PathBuf,
}

impl Snapshot {
    fn new(mavlink: bool) -> Self {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let name = format!(
            "magcal-live-{}-{nanos}.{}",
            std::process::id(),
            if mavlink { "tlog" } else { "csv" }
        );
        Self {
            path: std::env::temp_dir().join(name),
        }
    }
}

impl Drop for Snapshot {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// What `live --json` prints when it ends.
#[derive(Debug, serde::Serialize)]
struct LiveJson {
    source: String,
    /// Bytes received; MAVLink frames whose checksum held, failed, or whose message is unknown;
    /// lines taken as readings, malformed, or other.
    bytes: u64,
    frames: u64,
    bad_crc: u64,
    unknown_frames: u64,
    lines: u64,
    malformed_lines: u64,
    other_lines: u64,
    /// Records dropped (oldest first) to stay within `--memory`.
    dropped_records: u64,
    fits: u64,
    /// The last fit: its readings, whether usable, why not, and the attitude to visit next.
    readings: usize,
    usable: bool,
    reasons: String,
    next: Option<magcal_report::pages::next::AttitudeJson>,
    next_error: Option<String>,
    /// The plan when it ended (empty when done), targets flown, plans superseded, and the first
    /// fit that met the budget.
    plan: Vec<guide::Target>,
    targets_flown: u64,
    plans_superseded: u64,
    done_fit: Option<u64>,
    /// The fit whose calibration set `out` holds, and whether it was usable.
    written_fit: Option<u64>,
    written_usable: bool,
    out: String,
    /// With `--send`: the parameters sent and what the vehicle read back.
    sent: Option<send::SentJson>,
    /// MAVLink: the vehicle (system, component), UDP datagrams from elsewhere (counted, never
    /// answered), and the requests for messages and parameters sent to it.
    vehicle: Option<(u8, u8)>,
    foreign_datagrams: u64,
    asked: ask::Asked,
}

/// What the fit loop knows between fits.
#[derive(Default)]
struct Progress {
    counts: Counts,
    dropped: u64,
    fits: u64,
    /// The fit whose set `--out` holds, and whether it was usable.
    written: Option<(u64, bool)>,
    /// What `--send` sent and read back, or why it could not.
    sent: Option<Result<send::SentJson, String>>,
    last: Option<Fitted>,
    /// The plan a person follows, and the first fit that met the budget.
    guide: guide::Guide,
    done_fit: Option<u64>,
    /// The export of the set `--out` holds when it is usable: printed when live ends.
    export: Option<Export>,
    /// MAVLink: the vehicle, and what was asked of it.
    vehicle: Option<(u8, u8)>,
    asked: ask::Asked,
}

/// A usable fit's export, as printed.
struct Export {
    samples: usize,
    text: String,
}

/// What the page shows: the status of the last fit.
struct View {
    status: Arc<Mutex<page::Status>>,
    /// `--heading-budget`, degrees.
    budget_deg: f64,
}

/// The roll and pitch ranges of the box of `--scenario` or the flags, degrees.
fn box_of(args: &LiveArgs) -> Option<[[f64; 2]; 2]> {
    let place = args.site.zip(args.date).map(|(site, date)| crate::log::gps::Place {
        site,
        date,
        model: args.wmm,
    });
    let vehicle = crate::log::vehicle::Vehicle::from_options(args.scenario.as_deref(), &args.attitude, place.as_ref())
        .ok()
        .flatten()?;
    let deg = |r: &magcal_core::AngleRange| [r.min().to_degrees(), r.max().to_degrees()];
    Some([deg(&vehicle.bounds.roll), deg(&vehicle.bounds.pitch)])
}

/// Puts the fit `f` into the page's status.
fn publish(view: &View, progress: &Progress, f: &Fitted, export: Option<String>) {
    let mut s = view.status.lock().unwrap_or_else(PoisonError::into_inner);
    s.fit = progress.fits;
    s.readings = f.readings;
    s.fit_seconds = f.seconds;
    s.reasons.clone_from(&f.why);
    s.next = f.next.clone().ok().flatten();
    s.next_error = f.next.clone().err();
    s.written_fit = progress.written.map(|w| w.0);
    s.written_usable = progress.written.is_some_and(|w| w.1);
    if export.is_some() {
        s.export = export;
    }
    let json = f.json.as_ref();
    s.usable = json.is_some_and(|j| j.usable);
    s.plan.clone_from(&progress.guide.plan);
    s.targets_flown = progress.guide.flown;
    s.plans_superseded = progress.guide.superseded;
    s.done = s.usable;
    s.done_fit = progress.done_fit;
    let budget = json.and_then(|j| j.heading_budget.as_ref());
    s.progress = guide::progress(budget.map(|b| b.predicted_deg), view.budget_deg, s.usable);
    s.heading_budget_deg = budget.map(|b| b.verdict.budget_deg);
    s.heading_predicted_deg = budget.map(|b| b.predicted_deg);
    s.model = json.map(|j| j.fit.clone());
    s.units = json.and_then(|j| j.units.clone());
    s.magnitude = json.map(|j| j.magnitude);
    s.bias = json.map(|j| j.bias);
    s.scale = json.map(|j| j.scale);
    s.psi_deg = json.map(|j| j.psi_deg);
    s.bias_se = json.and_then(|j| j.std_error.bias);
    s.scale_se = json.and_then(|j| j.std_error.scale);
    s.psi_se_deg = json.and_then(|j| j.std_error.psi_deg);
    s.gap_percent = json.map(|j| j.coverage.motioncal_gap_percent);
    let (Some(j), Some(log)) = (json, f.log.as_ref()) else {
        s.directions.clear();
        s.regions.clear();
        s.attitudes.clear();
        return;
    };
    let body: Vec<magcal_core::Vec3> = log.readings.iter().map(|r| j.apply_body(*r)).collect();
    s.regions = magcal_core::log_fit::motioncal_region_counts(&body).to_vec();
    s.directions = page::thinned(body.len(), page::MAX_POINTS)
        .map(|i| {
            let b = body[i];
            let n = magcal_core::small::norm(b);
            [
                b[1].atan2(b[0]).to_degrees().rem_euclid(360.0),
                (b[2] / n).clamp(-1.0, 1.0).asin().to_degrees(),
            ]
        })
        .collect();
    let flown: Vec<&magcal_core::small::Mat3> = log.attitudes.iter().flatten().flatten().collect();
    s.attitudes = page::thinned(flown.len(), page::MAX_POINTS)
        .map(|i| magcal_core::aviation::roll_pitch_heading_deg(flown[i]))
        .collect();
}

fn fit_loop(
    args: &LiveArgs,
    shared: &Arc<Shared>,
    snapshot: &Snapshot,
    inputs: &[&Path],
    view: &View,
    link: Option<&Mutex<source::Link>>,
) -> Result<(), Failure> {
    let mut progress = Progress::default();
    let mut seen = 0u64;
    let mut last_start: Option<Instant> = None;
    // `--idle` counts from the last bytes, or from the start while none have arrived.
    let started = Instant::now();
    let quiet_for = |last: Option<Instant>| last.unwrap_or(started).elapsed().as_secs_f64();
    let tty = std::io::stderr().is_terminal();
    loop {
        let (bytes, counts, dropped, held, ended, units) = {
            let mut state = shared.lock();
            loop {
                let due = last_start.is_none_or(|t| t.elapsed().as_secs_f64() >= args.every);
                let idle = args.idle.is_some_and(|i| quiet_for(state.counts.last) >= i);
                let stopping = shared.stop.load(Ordering::Relaxed);
                if (state.ring.generation != seen && due) || state.ended.is_some() || idle || stopping {
                    break;
                }
                state = shared
                    .changed
                    .wait_timeout(state, Duration::from_millis(100))
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .0;
            }
            let idle = args.idle.is_some_and(|i| quiet_for(state.counts.last) >= i);
            let ending = state
                .ended
                .clone()
                .or_else(|| (idle || shared.stop.load(Ordering::Relaxed)).then_some(Ok(())));
            let fresh = state.ring.generation != seen;
            seen = state.ring.generation;
            let bytes = fresh.then(|| state.ring.snapshot(&state.head));
            (
                bytes,
                state.counts.clone(),
                state.ring.dropped,
                state.ring.bytes(),
                ending,
                state.units,
            )
        };
        if let Some(Err(why)) = &ended {
            return Err(source_failed(args, &progress, why));
        }
        // A signal ends the fit under way and starts none: what it would give is not a result.
        let signalled = || shared.stop.load(Ordering::Relaxed);
        if let Some(bytes) = bytes.filter(|_| !signalled()) {
            last_start = Some(Instant::now());
            std::fs::write(&snapshot.path, &bytes).context("the live snapshot")?;
            let flag = Arc::clone(shared);
            let fitted = fit(args, &snapshot.path, units, in_force_unknown(args, shared), move || {
                flag.stop.load(Ordering::Relaxed)
            });
            if signalled() {
                break;
            }
            progress.fits += 1;
            progress.counts = counts.clone();
            progress.dropped = dropped;
            steer(args, &mut progress, &fitted);
            status(args, &progress, &fitted, &counts, dropped, held, tty);
            let export = keep(args, &mut progress, &fitted, inputs, (link, shared))?;
            publish(view, &progress, &fitted, export);
            let done = (args.until_usable || args.send) && progress.written.is_some_and(|w| w.1);
            progress.last = Some(fitted);
            if done {
                break;
            }
        }
        if ended.is_some() {
            break;
        }
    }
    if tty {
        to_stderr!("");
    }
    count_the_rest(shared, &mut progress);
    let end = ended_words(args, shared, &progress);
    view.status.lock().unwrap_or_else(PoisonError::into_inner).stream_end = Some(end);
    finish(args, progress, inputs)
}

/// A usable fit's set written, its export kept (and sent, with `--send`); the export's text, or
/// `None` for a fit that is not usable.
fn keep(
    args: &LiveArgs,
    progress: &mut Progress,
    fitted: &Fitted,
    inputs: &[&Path],
    (link, shared): (Option<&Mutex<source::Link>>, &Shared),
) -> Result<Option<String>, Failure> {
    let Some(json) = fitted.json.as_ref().filter(|j| j.usable) else {
        return Ok(None);
    };
    write_set(args, fitted, inputs)?;
    let (text, problems) = export_text(args, json);
    progress.export = Some(Export {
        samples: json.samples,
        text: text.clone(),
    });
    progress.written = Some((progress.fits, true));
    if args.send {
        let sent = send_export(args, (&text, &problems), link, shared);
        match &sent {
            Ok(j) => to_stderr!("live: {}", j.words()),
            Err(e) => to_stderr!("live: nothing sent: {e}"),
        }
        progress.sent = Some(sent);
    }
    Ok(Some(text))
}

/// Why live ended, in words, for the page.
fn ended_words(args: &LiveArgs, shared: &Shared, progress: &Progress) -> String {
    let state = shared.lock();
    match (&state.ended, state.counts.last) {
        (Some(Ok(())), _) => "the source ended".to_string(),
        (Some(Err(why)), _) => format!("the source failed: {why}"),
        _ if (args.until_usable || args.send) && progress.written.is_some_and(|w| w.1) => {
            "live ended at the first fit that met the budget".to_string()
        }
        (None, last) => match args.idle {
            Some(i) if last.is_none_or(|t| t.elapsed().as_secs_f64() >= i) => {
                format!("nothing arrived for {} s (--idle)", crate::limits::show(i))
            }
            _ => "stopped (Ctrl-C)".to_string(),
        },
    }
}

/// The source failed: why, and the usable set written before it, which stays, named.
fn source_failed(args: &LiveArgs, progress: &Progress, why: &str) -> Failure {
    Failure::Input(match progress.written {
        Some((k, true)) => anyhow::anyhow!(
            "{why}; the calibration of fit {k} in {} is usable and stays",
            args.out.display()
        ),
        _ => anyhow::anyhow!("{why}"),
    })
}

/// What arrived after the last fit, or with no fit at all, counted too.
fn count_the_rest(shared: &Shared, progress: &mut Progress) {
    let state = shared.lock();
    progress.counts = state.counts.clone();
    progress.dropped = state.ring.dropped;
    progress.vehicle = state.vehicle;
    progress.asked = state.asked.clone();
}

/// The fit of the snapshot at `path`: `calibrate`'s calibration and verdict, and `next`'s first
/// attitude where a box is given.
/// The bound on a fit without `--fit-within`: seconds, and seconds for each reading it holds.
const FIT_SECONDS: f64 = 5.0;
const FIT_SECONDS_PER_READING: f64 = 2e-5;

/// The fit of the snapshot at `path` and `next`'s attitudes for it, within `--fit-within` of its
/// start (or [`FIT_SECONDS`] and [`FIT_SECONDS_PER_READING`]), or until `ended` says the command
/// is ending.
fn fit(
    args: &LiveArgs,
    path: &Path,
    units: Option<Units>,
    unknown: Option<String>,
    ended: impl Fn() -> bool + Send + Sync + 'static,
) -> Fitted {
    let started = Instant::now();
    let (cal_args, input) = calibrate_args(args, path, units);
    let mut fitted = Fitted {
        readings: 0,
        json: None,
        why: String::new(),
        next: Ok(None),
        fresh: Vec::new(),
        seconds: 0.0,
        log: None,
        rows: 0,
        bad_option: false,
    };
    let mut log = match crate::log::source::open(path, &input, HELD_BYTES_PER_READING) {
        Ok(log) => log,
        Err(e) => {
            fitted.why = format!("waiting for readings: {}", first_words(&format!("{e:#}"), path));
            fitted.seconds = started.elapsed().as_secs_f64();
            return fitted;
        }
    };
    fitted.readings = log.readings.len();
    fitted.rows = log.readings.len() + log.skipped.len();
    let bound = args
        .fit_within
        .unwrap_or(FIT_SECONDS + FIT_SECONDS_PER_READING * fitted.readings as f64);
    // A bound beyond what a Duration holds is no bound.
    let deadline = match Duration::try_from_secs_f64(bound) {
        Ok(b) => Deadline::since(started, b),
        Err(_) => Deadline::none(),
    }
    .or_when(ended);
    match super::calibrate::calibrate_within(&cal_args, &mut log, &deadline) {
        Ok(Calibrated::Fit { mut json, .. }) => {
            if let Some(why) = unknown {
                json.usable = false;
                json.reasons.insert(0, why);
            }
            fitted.why = json.reasons.join("; ");
            match next_attitudes(args, path, &input, &json, &deadline) {
                Ok(all) => {
                    fitted.next = Ok(all.first().cloned());
                    fitted.fresh = all;
                }
                Err(e) => fitted.next = Err(e),
            }
            fitted.json = Some(*json);
        }
        Ok(Calibrated::NoFit(j)) => fitted.why = j.reasons.join("; "),
        Err(e) => {
            fitted.bad_option = matches!(e, Failure::Input(_));
            fitted.why = first_words(&words(&e), path);
        }
    }
    fitted.log = Some(log);
    fitted.seconds = started.elapsed().as_secs_f64();
    fitted
}

/// The ArduPilot parameters of `export` sent over `link`, read back and compared; nothing sent
/// where `export` warns (unless `--force`).
fn send_export(
    args: &LiveArgs,
    (export, problems): (&str, &[String]),
    link: Option<&Mutex<source::Link>>,
    shared: &Shared,
) -> Result<send::SentJson, String> {
    if !problems.is_empty() && !args.force {
        return Err(format!(
            "export warns: {}; --force sends it all the same",
            problems.join("; ")
        ));
    }
    let link = link.ok_or("the source has no sending end")?;
    let parameters = send::parameters(export).map_err(|e| format!("{e:#}"))?;
    let mut link = link.lock().unwrap_or_else(PoisonError::into_inner);
    send::send(&mut link, shared, &parameters).map_err(|e| format!("{e:#}"))
}

/// Why the calibration in force on the vehicle is unknown (a MAVLink source whose vehicle has
/// not said every parameter of it): nothing fitted can then be exported or sent, since a fit of
/// readings corrected by an unknown calibration says nothing of the parameters to set.
fn in_force_unknown(args: &LiveArgs, shared: &Shared) -> Option<String> {
    if !args.source.is_mavlink() {
        return None;
    }
    let (required, _) = ask::in_force_names(args.input.compass.unwrap_or(0));
    let state = shared.lock();
    let Some(params) = state.params() else {
        return Some("the vehicle is not known yet (no autopilot's HEARTBEAT with compass frames): its calibration in force is unknown, so nothing is exported or sent".to_string());
    };
    let missing: Vec<&String> = required.iter().filter(|n| !params.contains_key(*n)).collect();
    (!missing.is_empty()).then(|| {
        format!(
            "the calibration in force on the vehicle is unknown ({} not received; live asks for them by PARAM_REQUEST_READ every {} s): nothing is exported or sent",
            missing.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", "),
            ask::EVERY.as_secs()
        )
    })
}

/// A failure in words.
fn words(f: &Failure) -> String {
    match f {
        Failure::Input(e) => format!("{e:#}"),
        Failure::Regression(s) | Failure::Unusable(s) => s.clone(),
    }
}

/// A message about the snapshot, with its temporary path replaced by "the stream".
fn first_words(message: &str, path: &Path) -> String {
    message.replace(&path.display().to_string(), "the stream")
}

/// `calibrate`'s arguments for the snapshot at `path`, and how to read it; `units`: those the
/// stream's lines fix (MotionCal's `Raw:` lines are in uT), unless `--units` or `--magnitude`
/// says.
fn calibrate_args(args: &LiveArgs, path: &Path, units: Option<Units>) -> (CalibrateArgs, LogArgs) {
    let mut input = args.input.clone();
    input.format = if args.source.is_mavlink() {
        FormatArg::Tlog
    } else {
        FormatArg::Csv
    };
    let units = args.units.or(units.filter(|_| args.magnitude.is_none()));
    let cal = CalibrateArgs {
        log: path.to_path_buf(),
        input: input.clone(),
        magnitude: args.magnitude,
        site: args.site,
        date: args.date,
        units,
        wmm: args.wmm,
        fit: args.fit,
        reject: None,
        noise: args.noise,
        residual: ResidualArg::Readings,
        trials: args.trials,
        seed: args.seed,
        json: false,
        out: None,
        scenario: args.scenario.clone(),
        attitude: args.attitude.clone(),
        motor: None,
        heading_budget: args.heading_budget,
    };
    (cal, input)
}

/// The attitudes `next` gives for the snapshot at `path` and its calibration (at least a plan's
/// worth, [`guide::PLAN_LEN`]); none without a box.
fn next_attitudes(
    args: &LiveArgs,
    path: &Path,
    input: &LogArgs,
    cal: &CalibrationJson,
    deadline: &Deadline,
) -> Result<Vec<magcal_report::pages::next::AttitudeJson>, String> {
    if !boxed(args) {
        return Ok(Vec::new());
    }
    let next = NextArgs {
        calibration: PathBuf::from("the live fit"),
        log: path.to_path_buf(),
        scenario: args.scenario.clone(),
        attitude: args.attitude.clone(),
        site: args.site,
        date: args.date,
        wmm: args.wmm,
        count: args.count.max(guide::PLAN_LEN as u64),
        json: true,
        report: None,
        input: input.clone(),
        heading_budget: args.heading_budget,
    };
    super::next::suggestion_within(&next, cal, deadline)
        .map(|j| j.attitudes)
        .map_err(|e| first_words(&format!("{e:#}"), path))
}

/// Whether the vehicle has an attitude box (`--scenario` or the flags): its plan is of attitudes
/// in it; without one, of field directions over the whole sphere (a device in the hand).
fn boxed(args: &LiveArgs) -> bool {
    args.scenario.is_some() || args.attitude.any()
}

/// The plan after fit `f`: kept, flown or superseded ([`guide`]); none while the budget is met
/// (done), resumed if a later fit does not meet it.
fn steer(args: &LiveArgs, progress: &mut Progress, f: &Fitted) {
    let (Some(json), Some(log)) = (&f.json, &f.log) else {
        return;
    };
    if json.usable {
        progress.done_fit.get_or_insert(progress.fits);
        progress.guide.plan.clear();
        return;
    }
    let sensor = guide::Sensor::of(json);
    let variance = guide::Variance::new(&log.readings, json.magnitude);
    let directions: Vec<magcal_core::Vec3> = log.readings.iter().map(|&r| json.apply(r)).collect();
    let fresh = if boxed(args) {
        f.fresh.iter().map(guide::Target::attitude).collect()
    } else {
        variance
            .as_ref()
            .map(|v| guide::sphere_targets(&sensor, v))
            .unwrap_or_default()
    };
    progress.guide.update(
        &sensor,
        &directions,
        variance.as_ref(),
        fresh,
        std::time::Instant::now(),
    );
}

/// One line on stderr: what arrived, what was kept and dropped, the fit and the next attitude;
/// on a terminal it replaces the line before.
fn status(args: &LiveArgs, progress: &Progress, f: &Fitted, c: &Counts, dropped: u64, held: usize, tty: bool) {
    let mut line = format!("live: {} readings", f.readings);
    if args.source.is_mavlink() {
        line += &format!(" ({} frames, {} bad", c.frames, c.bad_crc + c.unknown);
    } else {
        line += &format!(
            " ({} lines, {} malformed, {} other",
            c.lines, c.malformed_lines, c.other_lines
        );
    }
    line += &format!(
        ", {dropped} records dropped, {:.1} of {} MiB held)",
        held as f64 / f64::from(1u32 << 20),
        args.memory_mib
    );
    line += &format!(" | fit {} in {:.2} s: ", progress.fits, f.seconds);
    // The finish line: the heading the fit is predicted to leave against the budget.
    if let Some(b) = f.json.as_ref().and_then(|j| j.heading_budget.as_ref()) {
        line += &format!(
            "heading {} deg (95th percentile) against a budget of {} deg, ",
            b.verdict.against_budget(b.predicted_deg),
            crate::limits::show(b.verdict.budget_deg)
        );
    }
    match &f.json {
        Some(j) if j.usable => {
            line += "USABLE";
            if let Some(se) = j.std_error.bias {
                line += &format!(", bias se {:.3} {:.3} {:.3}", se[0], se[1], se[2]);
            }
        }
        _ => line += &format!("not usable: {}", crate::limits::excerpt(&f.why, 160)),
    }
    if f.json.as_ref().is_some_and(|j| j.usable) {
        line += &format!(
            " | DONE since fit {}: the budget is met{}",
            progress.done_fit.unwrap_or(progress.fits),
            if args.until_usable || args.send {
                ""
            } else {
                "; Ctrl-C ends live with this calibration"
            }
        );
    } else if let Some(plan) = progress.guide.words() {
        line += &format!(" | {plan}");
    }
    if let Err(e) = &f.next {
        line += &format!(" | next: {}", crate::limits::excerpt(e, 120));
    }
    let line = crate::limits::printable(&line);
    if tty {
        let _ = write!(std::io::stderr(), "\r\x1b[2K{line}");
    } else {
        to_stderr!("{line}");
    }
}

/// Writes the calibration set of `fitted` into `--out`, replaced whole.
fn write_set(args: &LiveArgs, fitted: &Fitted, inputs: &[&Path]) -> Result<()> {
    let (Some(json), Some(log)) = (&fitted.json, &fitted.log) else {
        return Ok(());
    };
    let set = ResultSet::begin(&args.out, Target::Calibration, inputs)?;
    let shown = log_shown(args);
    let mut json = json.clone();
    json.log = shown.display().to_string();
    super::calibrate::write_out(set, &shown, fitted.rows, &json, log)
}

/// The log a live calibration is of, as its set and its export name it: the recording, or the
/// source (the snapshot each fit reads is a temporary file, gone when `live` ends).
fn log_shown(args: &LiveArgs) -> PathBuf {
    args.record
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("{} (live)", source::shown(&args.source))))
}

/// The set written, of usable fit `k`: said on stdout, with its export for the source's autopilot.
fn announce(args: &LiveArgs, k: u64, export: &Export) -> Result<()> {
    let to = if args.source.is_mavlink() {
        "ardupilot"
    } else {
        "motioncal"
    };
    let text = format!(
        "usable at {} readings (fit {k}, the last that met the budget): {} written; its export (magcal export {} --to {to}):\n{}",
        export.samples,
        args.out.join("calibration.json").display(),
        args.out.join("calibration.json").display(),
        export.text
    );
    crate::output::file::to_stdout(|w| Ok(w.write_all(text.as_bytes())?))?;
    Ok(())
}

/// The export of a usable fit for the source's autopilot (ArduPilot for MAVLink, MotionCal for
/// lines), or why there is none; and what `export` warns of.
fn export_text(args: &LiveArgs, json: &CalibrationJson) -> (String, Vec<String>) {
    let export = super::export::ExportArgs {
        calibration: args.out.join("calibration.json"),
        to: if args.source.is_mavlink() {
            ExportTarget::ArduPilot
        } else {
            ExportTarget::MotionCal
        },
        compass: None,
        units: None,
        offs_max: None,
        strict: false,
        force: false,
        out: None,
    };
    let mut json = json.clone();
    json.log = log_shown(args).display().to_string();
    match super::export::made(&export, &json, "the live fit", "") {
        Ok(made) => (String::from_utf8_lossy(&made.text).into_owned(), made.problems),
        Err(e) => {
            let why = words(&e);
            (format!("(no export: {why})\n"), vec![why])
        }
    }
}

/// The end: where no fit was usable, the last fit's set is written (as `calibrate` writes an
/// unusable one) and the command fails with why.
fn finish(args: &LiveArgs, mut progress: Progress, inputs: &[&Path]) -> Result<(), Failure> {
    if progress.written.is_none()
        && let Some(last) = &progress.last
        && last.json.is_some()
    {
        write_set(args, last, inputs)?;
        progress.written = Some((progress.fits, false));
    }
    // The export of the set written, the last fit that met the budget: printed once, at the end.
    if let (Some(e), Some((k, true)), false) = (&progress.export, progress.written, args.json) {
        announce(args, k, e)?;
    }
    if args.json {
        let c = &progress.counts;
        let last = progress.last.as_ref();
        let json = LiveJson {
            source: source::shown(&args.source),
            bytes: c.bytes,
            frames: c.frames,
            bad_crc: c.bad_crc,
            unknown_frames: c.unknown,
            lines: c.lines,
            malformed_lines: c.malformed_lines,
            other_lines: c.other_lines,
            dropped_records: progress.dropped,
            fits: progress.fits,
            readings: last.map_or(0, |l| l.readings),
            usable: last.is_some_and(|l| l.json.as_ref().is_some_and(|j| j.usable)),
            reasons: last.map_or_else(|| "no readings arrived".to_string(), |l| l.why.clone()),
            next: last.and_then(|l| l.next.clone().ok().flatten()),
            next_error: last.and_then(|l| l.next.clone().err()),
            plan: progress.guide.plan.clone(),
            targets_flown: progress.guide.flown,
            plans_superseded: progress.guide.superseded,
            done_fit: progress.done_fit,
            written_fit: progress.written.map(|w| w.0),
            written_usable: progress.written.is_some_and(|w| w.1),
            out: args.out.display().to_string(),
            sent: progress.sent.clone().and_then(Result::ok),
            vehicle: progress.vehicle,
            foreign_datagrams: c.foreign,
            asked: progress.asked.clone(),
        };
        crate::output::file::to_stdout(|w| {
            serde_json::to_writer_pretty(&mut *w, &json)?;
            writeln!(w)?;
            Ok(())
        })?;
    }
    match &progress.sent {
        Some(Err(why)) => {
            return Err(Failure::Unusable(format!(
                "the calibration in {} is usable, but nothing was sent: {why}",
                args.out.display()
            )));
        }
        Some(Ok(sent)) if !sent.confirmed() => {
            return Err(Failure::Unusable(format!(
                "the vehicle does not hold the calibration sent: {}",
                sent.words()
            )));
        }
        _ => {}
    }
    if let Some(last) = progress.last.as_ref().filter(|l| l.bad_option) {
        return Err(Failure::Input(anyhow::anyhow!("{}", last.why)));
    }
    match (progress.written, progress.last) {
        (Some((k, true)), last) => {
            let later = last.filter(|l| !l.json.as_ref().is_some_and(|j| j.usable));
            match later {
                None => Ok(()),
                Some(l) => Err(Failure::Unusable(format!(
                    "the last fit is not usable ({}); {} holds fit {k}'s, which was",
                    l.why,
                    args.out.display()
                ))),
            }
        }
        (written, Some(last)) => Err(Failure::Unusable(format!(
            "{}: no fit was usable; the last ({} readings): {}; {}",
            source::shown(&args.source),
            last.readings,
            last.why,
            if written.is_some() {
                format!("its set is in {}", args.out.display())
            } else {
                format!("nothing written to {}", args.out.display())
            }
        ))),
        (_, None) => Err(Failure::Unusable(format!(
            "{}: no readings arrived",
            source::shown(&args.source)
        ))),
    }
}
