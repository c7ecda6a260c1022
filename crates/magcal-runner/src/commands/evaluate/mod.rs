//! `magcal evaluate CAL.json LOG` and `magcal evaluate --raw LOG`: how good a calibration is as a
//! compass against the independent attitudes a log carries (docs/conventions.md "Heading
//! against a reference attitude").
//!
//! The log is read as `apply` reads it ([`super::apply::read_held`]: the calibration's columns,
//! its motor interference removed), the readings with an attitude are calibrated with `P`
//! (`b = P (raw - bias)`, \[P1\] eq. (6)), and `Q` and `F` are fitted by
//! [`magcal_core::reference::align`] twice: for the calibrated readings and for the raw ones
//! (so that the gain shows). The errors are also gathered by the body's heading (30-degree
//! sectors) and by its tilt (bands). With `--raw` the raw readings alone are evaluated.

mod report;

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use magcal_core::Vec3;
use magcal_core::aviation::{NavFrame, from_ned, roll_pitch_heading_deg, tilt_deg, z_up_of_ned};
use magcal_core::reference::{AlignSettings, Alignment, align, align_fixed};
use magcal_core::small::{Mat3, mat_mul};

use super::Failure;
use crate::log::calibration::{CalibrationJson, RadiusMedian, columns_for, read_calibration};
use crate::log::flight::Format;
use crate::log::source::{self, Log, LogArgs};
use crate::output::file::{Output, replace, replace_with, to_stdout};
use crate::output::stderr::to_stderr;

pub use report::{CellJson, ErrorRow, EvaluationJson, FiguresJson, RowsJson};

/// Memory a held reading costs `evaluate`, bytes: the log's reading, line, time and attitude
/// (120 B), the raw and calibrated readings and z-up attitudes of the readings used (120 B), two
/// fits' errors with their sorted copies (64 B) and the cells' (64 B); doubled for the growth of
/// the vectors that hold them.
pub const EVALUATE_BYTES_PER_READING: u64 = 768;

/// Width of the heading sectors, degrees.
pub const SECTOR_DEG: f64 = 30.0;

/// Bounds of the tilt bands, degrees: 0-15, 15-30, 30-60, 60-90, 90-180.
pub const TILT_BANDS_DEG: [f64; 6] = [0.0, 15.0, 30.0, 60.0, 90.0, 180.0];

/// `magcal evaluate`.
#[derive(Debug, Args)]
pub struct EvaluateArgs {
    /// A calibration.json written by `magcal calibrate`; with `--raw`, the log (`magcal evaluate
    /// --raw LOG`; `-`: standard input).
    #[arg(value_name = "CAL.json", value_parser = crate::log::path_parser())]
    pub calibration: PathBuf,
    /// The log to judge the calibration on (`-`: standard input).
    #[arg(value_name = "LOG", value_parser = crate::log::path_parser())]
    pub log: Option<PathBuf>,
    /// Evaluate the log's raw readings, uncalibrated, without a calibration file.
    #[arg(long)]
    pub raw: bool,
    /// How to read the log, as for `calibrate` (default columns: those the calibration was made
    /// from); it must carry attitudes (`--quaternion` or `--euler`, or a flight log's own).
    #[command(flatten)]
    pub input: LogArgs,
    /// Print one JSON object with every figure instead of the text report.
    #[arg(long)]
    pub json: bool,
    /// Write one row per reading used (its line, time, attitude, tilt and errors) to this CSV
    /// file, replaced whole (never an input).
    #[arg(long, value_name = "FILE.csv")]
    pub errors: Option<PathBuf>,
    /// Also write one self-contained HTML page of the evaluation to this file (replaced whole;
    /// never an input nor the `--errors` file): heading error against time, heading and tilt,
    /// its histogram, the errors per heading sector and tilt band, and the figures in tables.
    #[arg(long, value_name = "FILE.html")]
    pub report: Option<PathBuf>,
}

/// Runs `evaluate`.
///
/// # Errors
/// A bad calibration file or log, a log without attitudes, too few readings with one or
/// attitudes that do not determine the heading errors, a reading whose calibrated value is not
/// finite, an `--errors` path that may not be replaced (exit 2).
pub fn run(args: &EvaluateArgs) -> Result<(), Failure> {
    Ok(evaluate(args)?)
}

/// The calibration (`None` with `--raw`) and the log named on the command line.
fn files(args: &EvaluateArgs) -> Result<(Option<&Path>, &Path)> {
    match (args.raw, &args.log) {
        (true, None) => Ok((None, &args.calibration)),
        (false, Some(log)) => Ok((Some(&args.calibration), log)),
        (true, Some(_)) => bail!(
            "--raw evaluates the log's readings uncalibrated: give the log alone, not {} (magcal evaluate --raw LOG)",
            args.calibration.display()
        ),
        (false, None) => bail!(
            "give the calibration and the log (magcal evaluate CAL.json LOG), or --raw to evaluate {}'s readings uncalibrated",
            args.calibration.display()
        ),
    }
}

fn evaluate(args: &EvaluateArgs) -> Result<()> {
    let (cal_path, log_path) = files(args)?;
    let inputs: Vec<&Path> = cal_path.into_iter().chain([log_path]).collect();
    let errors_out = match &args.errors {
        Some(p) if p == Path::new("-") => {
            bail!("--errors -: give a file (standard output carries the report)")
        }
        Some(p) => Some(Output::File(p.clone())),
        None => None,
    };
    let report_out = page_output(args.report.as_deref(), &inputs, args.errors.as_deref())?;
    if let Some(out) = &errors_out {
        out.check(&inputs).context("--errors")?;
    }
    let cal = cal_path.map(read_calibration).transpose()?;
    let cal_shown = cal_path.map(|p| p.display().to_string());
    let Evaluated { json, used, fits, .. } = evaluated(args, log_path, cal.as_ref().zip(cal_shown.as_deref()))?;
    if let Some(Output::File(path)) = &errors_out {
        let rows = report::error_rows(&used, fits.calibrated.as_ref().unwrap_or(&fits.raw), &fits.raw);
        replace_with(path, &inputs, |w| crate::output::write_csv(rows, w)).context("--errors")?;
    }
    if let Some(path) = &report_out {
        let html = page_html(&json, &used, &fits)?;
        let mut others = inputs.clone();
        others.extend(args.errors.as_deref());
        replace(path, &others, html.as_bytes()).context("--report")?;
    }
    to_stdout(|w| {
        if args.json {
            serde_json::to_writer_pretty(&mut *w, &json)?;
            writeln!(w)?;
        } else {
            report::print(w, &json)?;
        }
        Ok(())
    })?;
    Ok(())
}

/// What an evaluation finds, before it is written anywhere.
pub struct Evaluated {
    /// Every figure, as `--json` prints it.
    pub json: EvaluationJson,
    /// The readings with an attitude.
    pub used: Used,
    /// The alignments of the calibrated and the raw readings.
    pub fits: Fits,
    /// The log as read.
    pub log: Log,
}

/// Evaluates `cal` (the calibration, with its name for messages; `None`: the raw readings) on
/// the log at `log_path`, read as `args.input` says.
///
/// # Errors
/// As [`run`], but for the output files.
pub fn evaluated(args: &EvaluateArgs, log_path: &Path, cal: Option<(&CalibrationJson, &str)>) -> Result<Evaluated> {
    let log = read_log(args, log_path, cal)?;
    let cal_shown = cal.map(|(_, shown)| shown);
    let cal = cal.map(|(c, _)| c);
    let used = Used::of(&log, log_path)?;
    let log_shown = log_path.display().to_string();
    let calibrated = match cal {
        Some(c) => Some(calibrate(c, &used, &log_shown, cal_shown.unwrap_or_default())?),
        None => None,
    };
    // A calibration of other units or of another sensor gives figures that mean nothing: refused,
    // as `next` refuses it.
    if let (Some(c), Some(b)) = (cal, &calibrated) {
        let mut radius = RadiusMedian::new(c.magnitude);
        for v in b {
            radius.push(*v);
        }
        if let Some(why) = c.radius_mismatch(radius.ratio()) {
            bail!("{log_shown}: {why} (evaluated with {})", cal_shown.unwrap_or_default());
        }
    }
    // A vector calibration carries the alignment of its calibrated frame `P (raw - bias)` to the
    // body: its figures are also given with Q held there. Q is fitted in every case.
    let held = cal.and_then(|c| c.alignment.as_ref()).map(|a| &a.rotation);
    let fits = Fits::of(&used, calibrated.as_deref(), held).with_context(|| log_shown.clone())?;
    let json = report::evaluation_json(
        report::Source {
            log: &log,
            log_shown: &log_shown,
            cal,
            cal_shown,
        },
        &used,
        &fits,
    );
    warn(&log, cal.zip(cal_shown));
    Ok(Evaluated { json, used, fits, log })
}

/// The path of `--report`, checked before any work: a file (not `-`) that may be replaced and is
/// none of `inputs` nor the `--errors` file.
fn page_output(report: Option<&Path>, inputs: &[&Path], errors: Option<&Path>) -> Result<Option<PathBuf>> {
    let Some(path) = report else {
        return Ok(None);
    };
    if path == Path::new("-") {
        bail!("--report -: give a file (standard output carries the report)");
    }
    if let Some(errors) = errors
        && crate::output::file::one_output(path, errors)
    {
        bail!(
            "--report {}: the same file as --errors {}: give the page another path",
            path.display(),
            errors.display()
        );
    }
    Output::File(path.to_path_buf()).check(inputs).context("--report")?;
    Ok(Some(path.to_path_buf()))
}

/// The page of `--report`: the evaluation `json`, every reading's heading error counted and
/// at most [`crate::report::evaluate::MAX_DRAWN`] of them drawn.
fn page_html(json: &EvaluationJson, used: &Used, fits: &Fits) -> Result<String> {
    let judged = fits.calibrated.as_ref().unwrap_or(&fits.raw);
    let shown = crate::report::thin(used.raw.len(), crate::report::evaluate::MAX_DRAWN);
    let drawn: Vec<ErrorRow> = shown
        .into_iter()
        .map(|t| report::error_row(used, judged, &fits.raw, t))
        .collect();
    let readings = crate::report::evaluate::Readings {
        drawn: &drawn,
        heading_error_deg: &judged.heading_deg,
        raw_heading_error_deg: fits.calibrated.as_ref().map(|_| &fits.raw.heading_deg[..]),
    };
    crate::report::evaluate::page(json, &readings)?.render()
}

/// The log at `path`, read as `apply` reads it for a calibration `cal` (named `.1`), or as given
/// for `--raw`; refused without attitudes, naming the flags that give them.
fn read_log(args: &EvaluateArgs, path: &Path, cal: Option<(&CalibrationJson, &str)>) -> Result<Log> {
    let log = match cal {
        Some((cal, shown)) => {
            let mut input = args.input.clone();
            input.columns = columns_for(cal, shown, path, &input)?;
            super::apply::read_held(cal, shown, path, &input, EVALUATE_BYTES_PER_READING)?
        }
        None => source::open(path, &args.input, EVALUATE_BYTES_PER_READING)?,
    };
    if log.attitudes.is_none() {
        match log.origin.format {
            Format::Csv => bail!(
                "{}: no attitudes to evaluate against: name the log's attitude columns with --quaternion W,X,Y,Z or --euler ROLL,PITCH,YAW (and --attitude-frame enu for body-to-ENU attitudes)",
                path.display()
            ),
            f => bail!(
                "{}: {} without attitude messages: nothing to evaluate against",
                path.display(),
                f.with_article()
            ),
        }
    }
    Ok(log)
}

/// The readings of a log that have an attitude, with what the figures need of each.
pub struct Used {
    /// Each reading's line (or byte offset) and time.
    pub lines: Vec<usize>,
    pub times: Option<Vec<f64>>,
    /// The raw readings.
    pub raw: Vec<Vec3>,
    /// The attitudes as [`align`] takes them: body (in the log's convention: forward-right-down
    /// for `ned`, forward-left-up for `enu`) into a z-up reference frame.
    pub attitudes: Vec<Mat3>,
    /// Roll, pitch and heading (NED convention, degrees; heading clockwise from the reference
    /// frame's north) and tilt (degrees) of each.
    pub roll_pitch_heading: Vec<[f64; 3]>,
    pub tilt: Vec<f64>,
    /// Readings of the log without an attitude.
    pub without: usize,
    /// The log's attitude convention.
    pub frame: NavFrame,
}

impl Used {
    fn of(log: &Log, path: &Path) -> Result<Self> {
        let Some(attitudes) = &log.attitudes else {
            bail!("{}: no attitudes", path.display());
        };
        let frame = log.origin.attitude_frame;
        let mut used = Self {
            lines: Vec::new(),
            times: log.times.as_ref().map(|_| Vec::new()),
            raw: Vec::new(),
            attitudes: Vec::new(),
            roll_pitch_heading: Vec::new(),
            tilt: Vec::new(),
            without: 0,
            frame,
        };
        for (t, c) in attitudes.iter().enumerate() {
            let Some(c) = c else {
                used.without += 1;
                continue;
            };
            used.lines.push(log.lines[t]);
            if let (Some(out), Some(times)) = (&mut used.times, &log.times) {
                out.push(times[t]);
            }
            used.raw.push(log.readings[t]);
            used.attitudes.push(match frame {
                NavFrame::Ned => z_up_of_ned(c),
                NavFrame::Enu => from_ned(c, NavFrame::Enu),
            });
            used.roll_pitch_heading.push(roll_pitch_heading_deg(c));
            used.tilt.push(tilt_deg(c));
        }
        Ok(used)
    }

    /// Each reading's heading sector (`SECTOR_DEG` wide from 0).
    pub fn sectors(&self) -> Vec<Option<usize>> {
        let n = (360.0 / SECTOR_DEG) as usize;
        self.roll_pitch_heading
            .iter()
            .map(|a| Some(((a[2] / SECTOR_DEG).floor() as usize).min(n - 1)))
            .collect()
    }

    /// Each reading's tilt band ([`TILT_BANDS_DEG`]; a band holds its upper bound, the first its
    /// lower too).
    pub fn bands(&self) -> Vec<Option<usize>> {
        self.tilt
            .iter()
            .map(|&t| (1..TILT_BANDS_DEG.len()).position(|i| t <= TILT_BANDS_DEG[i]))
            .collect()
    }
}

/// The fits of one evaluation.
pub struct Fits {
    /// `Q` and `F` fitted to the calibrated readings; `None` with `--raw`.
    pub calibrated: Option<Alignment>,
    /// `Q` held at the calibration's alignment and `F` fitted, where it carries one.
    pub aligned: Option<Alignment>,
    /// `Q` and `F` fitted to the raw readings.
    pub raw: Alignment,
}

impl Fits {
    /// The fits of the raw readings of `used`, of their calibrated values `calibrated`, and of
    /// those with `Q` held at `alignment`: the rotation of the calibrated frame into the body
    /// frame forward, right, down (as a vector calibration records it), turned here into the
    /// body frame of the log's attitudes ([`in_log_body`]).
    ///
    /// # Errors
    /// Attitudes that do not judge a set of readings ([`align`], [`align_fixed`]).
    pub fn of(used: &Used, calibrated: Option<&[Vec3]>, alignment: Option<&Mat3>) -> Result<Self> {
        let fit = |readings: &[Vec3], what: &str| {
            align(readings, &used.attitudes, &AlignSettings::default())
                .with_context(|| format!("{what}: the attitudes do not judge them"))
        };
        let raw = fit(&used.raw, "the raw readings")?;
        let (calibrated, aligned) = match calibrated {
            Some(b) => {
                let aligned = match alignment {
                    Some(a) => Some(
                        align_fixed(b, &used.attitudes, &in_log_body(a, used.frame))
                            .context("the calibrated readings with the alignment held")?,
                    ),
                    None => None,
                };
                (Some(fit(b, "the calibrated readings")?), aligned)
            }
            None => (None, None),
        };
        Ok(Self {
            calibrated,
            aligned,
            raw,
        })
    }
}

/// A rotation into the body frame forward, right, down as a rotation into the body frame of
/// attitudes in the convention `frame` (forward, left, up for ENU: a half turn about forward).
pub fn in_log_body(rotation: &Mat3, frame: NavFrame) -> Mat3 {
    match frame {
        NavFrame::Ned => *rotation,
        NavFrame::Enu => mat_mul(&[[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], rotation),
    }
}

/// The calibrated readings `P (raw - bias)` of `used`; a value that is not finite is an error
/// naming its line.
fn calibrate(cal: &CalibrationJson, used: &Used, log_shown: &str, cal_shown: &str) -> Result<Vec<Vec3>> {
    used.raw
        .iter()
        .zip(&used.lines)
        .map(|(raw, line)| {
            let b = cal.apply(*raw);
            if !b.iter().all(|v| v.is_finite()) {
                bail!(
                    "{log_shown}: line {line}: the reading {raw:?} calibrated by {cal_shown} is {b:?}, not finite (is the calibration for this sensor and units?)"
                );
            }
            Ok(b)
        })
        .collect()
}

/// The warnings of `apply`: rows skipped, a calibration not marked
/// identifiable.
fn warn(log: &Log, cal: Option<(&CalibrationJson, &str)>) {
    for (line, reason) in &log.skipped {
        to_stderr!("magcal: skipped line {line}: {reason}");
    }
    let Some((cal, shown)) = cal else {
        return;
    };
    if !cal.identifiable {
        to_stderr!("magcal: warning: {shown} is marked not identifiable: {}", cal.verdict);
    }
}

#[cfg(test)]
mod tests {
    use magcal_core::aviation::dcm_of_quaternion;
    use magcal_core::small::{mat_t_vec, mat_vec};

    use super::*;

    /// The readings of [`Used`] with ENU attitudes `C` (body forward-left-up into east, north,
    /// up) drawn from `seed`, the field `F` and the calibrated fields `A^T v` of a calibration
    /// whose frame turns into the body frame forward, right, down by `A`: `v = H C^T F` with `H`
    /// the half turn about forward between the two body frames.
    fn used_and_calibrated(a: &Mat3, seed: u64) -> (Used, Vec<Vec3>) {
        use rand::RngExt;
        let f = [-0.25, 15.3, -41.9];
        let mut rng = magcal_core::rng::stream_rng(seed, 0);
        let (mut attitudes, mut calibrated) = (Vec::new(), Vec::new());
        for _ in 0..100 {
            let q: [f64; 4] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
            let c = dcm_of_quaternion(q.map(|v| v / n)).unwrap();
            let flu = mat_t_vec(&c, f);
            calibrated.push(mat_t_vec(a, [flu[0], -flu[1], -flu[2]]));
            attitudes.push(c);
        }
        let used = Used {
            lines: (1..=100).collect(),
            times: None,
            raw: calibrated.clone(),
            attitudes,
            roll_pitch_heading: vec![[0.0; 3]; 100],
            tilt: vec![0.0; 100],
            without: 0,
            frame: NavFrame::Enu,
        };
        (used, calibrated)
    }

    #[test]
    fn an_alignment_into_the_forward_right_down_body_is_held_in_the_logs_own_body_frame() {
        let a = magcal_core::aviation::dcm_of_euler(0.3, -0.2, 1.1);
        let (used, calibrated) = used_and_calibrated(&a, 31);
        let fits = Fits::of(&used, Some(&calibrated), Some(&a)).unwrap();
        let held = fits.aligned.unwrap();
        // Exact to rounding: 100 readings of 16 eps of the field each, as a heading of its
        // horizontal part.
        let f = [-0.25_f64, 15.3, -41.9];
        let bound = (1600.0 * f64::EPSILON * magcal_core::small::norm(f) / f[0].hypot(f[1])).to_degrees();
        assert!(held.summary.heading_max_deg <= bound, "{:?}", held.summary);
        for (got, want) in held.field.iter().zip(f) {
            assert!((got - want).abs() <= 1e-12, "{:?}", held.field);
        }
        // The fitted Q is the same rotation, in the log's body frame.
        let fitted = fits.calibrated.unwrap();
        let want = in_log_body(&a, NavFrame::Enu);
        for (r, w) in fitted.rotation.iter().zip(&want) {
            for (x, y) in r.iter().zip(w) {
                assert!((x - y).abs() <= 1e-12, "{:?} {want:?}", fitted.rotation);
            }
        }
        // Held without the half turn, every reading is off: the frames matter.
        let wrong = Fits::of(&used, Some(&calibrated), Some(&in_log_body(&a, NavFrame::Enu))).unwrap();
        assert!(wrong.aligned.unwrap().summary.direction_rms_deg > 10.0);
        // A NED log's body is forward, right, down: the rotation as it is.
        assert_eq!(in_log_body(&a, NavFrame::Ned), a);
        let v = [1.0, 2.0, 3.0];
        assert_eq!(mat_vec(&in_log_body(&a, NavFrame::Enu), v)[0], mat_vec(&a, v)[0]);
    }
}
