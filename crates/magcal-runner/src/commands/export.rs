//! `magcal export CAL.json --to ardupilot|px4|motioncal|magneto|c`: what the autopilot or the
//! tool takes, from a calibration file. The formulas and formats are in [`crate::log::export`].

use std::collections::BTreeSet;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;

use super::Failure;
use crate::log::calibration::{CalibrationJson, read_calibration};
use crate::log::export::{
    self as fmt, ARDUPILOT_OFFS_MAX_DEFAULT, ArduPilot, Calibration, LeftOut, Motor, MotorInput, Px4, Target, unit_name,
};
use crate::log::parameters::Autopilot;
use crate::output::file::Output;
use crate::output::stderr::to_stderr;
use crate::scenario::site::Units;

/// `magcal export`.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// A calibration.json written by `magcal calibrate --out` (or its `--json` output).
    pub calibration: PathBuf,
    /// What to write: ArduPilot `.param` lines (mGauss), PX4 `param set` lines (Gauss),
    /// MotionCal's hard iron, field and soft iron (uT), Magneto's B and Ainv, or a C header (the
    /// last two in the log's units).
    #[arg(long = "to", value_enum)]
    pub to: Target,
    /// The magnetometer the parameters are for (ArduPilot 0 to 2: `COMPASS_OFS_*`,
    /// `COMPASS_OFS2_*`, `COMPASS_OFS3_*`; PX4 0 to 3: `CAL_MAGn_*`). Default: the instance the
    /// calibration was read from, else 0.
    #[arg(long)]
    pub compass: Option<u8>,
    /// The units of the log the calibration was made from, where calibration.json does not
    /// record them (`units: null`): needed for ardupilot, px4 and motioncal.
    #[arg(long, value_enum)]
    pub units: Option<Units>,
    /// The vehicle's `COMPASS_OFFS_MAX`, mGauss, for the range check of the ArduPilot offsets.
    /// Default: the log's own, where calibration.json records it
    /// (`log_parameters.compass_offs_max`), else 1800 (ArduPilot's default).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..))]
    pub offs_max: Option<u16>,
    /// Refuse (exit 2, nothing written) a value outside what the autopilot accepts, a frame
    /// the autopilot does not take, or a part of the calibration that a parameter missing from
    /// the log's firmware leaves out; without it they are warnings on stderr.
    #[arg(long, conflicts_with = "force")]
    pub strict: bool,
    /// Write a calibration not marked usable, which is otherwise refused (exit 3, nothing
    /// written): its first line then says it is not a calibration to use, and why; exit 3.
    #[arg(long)]
    pub force: bool,
    /// Write to this file, replaced whole (default, or `-`: standard output). Only a regular
    /// file or a missing path is replaced, and never the calibration.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// How the first comment line of a forced export of a calibration not marked usable starts.
const NOT_USABLE: &str = "NOT A CALIBRATION TO USE";

/// Runs `export`: the calibration is checked ([`CalibrationJson::check`]), converted to the
/// target's unit and to the parameters the log's firmware has, made whole, and written unless
/// it is not marked usable (without `--force`) or `--strict` refuses a warning; the values
/// outside what the autopilot accepts are named on stderr.
///
/// # Errors
/// A bad calibration file, units unknown where the target needs them, a compass the target has
/// no parameters for, `--strict` with a warning (exit 2, nothing written); a calibration not
/// marked usable (exit 3: nothing written, or with `--force` written and marked so).
pub fn run(args: &ExportArgs) -> Result<(), Failure> {
    let out = Output::from_flag(args.out.as_deref());
    let inputs = [args.calibration.as_path()];
    out.check(&inputs)?;
    let shown = args.calibration.display().to_string();
    let cal = read_calibration(&args.calibration)?;
    let to = match &out {
        Output::File(path) => format!(" to {}", path.display()),
        Output::Stdout => " to standard output".to_string(),
    };
    let made = made(args, &cal, &shown, &to)?;
    out.write(&inputs, |w| Ok(w.write_all(&made.text)?))?;
    say(&cal, &shown, &made);
    if !cal.usable {
        return Err(Failure::Unusable(format!(
            "{shown}: written with --force{to}, its first line saying so: {}",
            not_usable(&cal)
        )));
    }
    Ok(())
}

/// Why `cal` is not marked usable, from its `reasons`.
fn not_usable(cal: &CalibrationJson) -> String {
    if cal.reasons.is_empty() {
        "the calibration is not marked usable, and gives no reasons".to_string()
    } else {
        format!("the calibration is not marked usable: {}", cal.reasons.join("; "))
    }
}

/// What stderr says of an export written: what it keeps, the alignment it drops, the notes and
/// the warnings.
fn say(cal: &CalibrationJson, shown: &str, made: &Made) {
    to_stderr!("magcal: note: {}", made.keep);
    if let Some(a) = &cal.alignment {
        to_stderr!(
            "magcal: warning: {shown}: the vector calibration's alignment ({:.3} deg, misalignment {:.3} deg beyond the nearest whole step) is not kept: the autopilots' board orientation parameters take only whole steps; the bias and soft-iron matrix are written",
            a.angle_deg,
            a.misalignment_deg
        );
    }
    for note in &made.notes {
        to_stderr!("magcal: note: {note}");
    }
    for problem in &made.problems {
        to_stderr!("magcal: warning: {problem}");
    }
}

/// The units of the log `cal` was made from: `units` of the file, or `--units`.
fn log_units(args: &ExportArgs, cal: &CalibrationJson, shown: &str) -> Result<Option<Units>> {
    use clap::ValueEnum;
    let recorded = match &cal.units {
        None => None,
        Some(text) => Some(Units::from_str(text, false).map_err(|_| {
            anyhow::anyhow!(
                "{shown}: units {:?}: not one of nT, uT, mG, G",
                crate::limits::excerpt(text, 20)
            )
        })?),
    };
    match (recorded, args.units) {
        (Some(a), Some(b)) if a != b => bail!(
            "{shown}: units {:?}, and --units {}: the calibration records its log's units; drop --units",
            cal.units.as_deref().unwrap_or_default(),
            b.to_possible_value()
                .map_or_else(String::new, |v| v.get_name().to_string())
        ),
        (a, b) => Ok(a.or(b)),
    }
}

/// The instance the parameters are for, checked against the target's.
fn instance(args: &ExportArgs, cal: &CalibrationJson, shown: &str) -> Result<u8> {
    let Some(max) = args.to.max_instance() else {
        if let Some(n) = args.compass {
            bail!(
                "--compass {n}: {} has no magnetometer instances (only ardupilot and px4 do)",
                args.to.name()
            );
        }
        return Ok(0);
    };
    let (n, from) = match (args.compass, cal.instance) {
        (Some(n), _) => (n, "--compass".to_string()),
        (None, Some(n)) => (n, format!("{shown}'s instance")),
        (None, None) => (0, "the default".to_string()),
    };
    if n > max {
        bail!(
            "--compass {n} (from {from}): {} has parameters for magnetometers 0 to {max}",
            args.to.name()
        );
    }
    Ok(n)
}

/// The motor interference of `cal`, checked.
fn motor(cal: &CalibrationJson, shown: &str) -> Result<Option<Motor>> {
    let Some(m) = &cal.motor else { return Ok(None) };
    let Some(input) = MotorInput::parse(&m.input) else {
        bail!(
            "{shown}: motor.input {:?}: not current or throttle",
            crate::limits::excerpt(&m.input, 20)
        );
    };
    if !m.per_unit.iter().all(|v| v.is_finite()) {
        bail!("{shown}: motor.per_unit {:?}: not finite", m.per_unit);
    }
    Ok(Some(Motor {
        input,
        per_unit: m.per_unit,
    }))
}

/// What the export keeps, in one sentence.
fn keeps(to: Target, rotation_deg: f64) -> String {
    format!(
        "{} keeps the bias and the symmetric A^-1 of b = A^-1 (raw - bias): the |b| of [P1]'s triangular P (the same G = P^T P), on axes turned {rotation_deg:.3} degrees from P's (a choice of frame, not a loss); not the standard errors or the verdict",
        to.name()
    )
}

/// Frame warnings and notes: the frame the target takes against the calibration's.
fn frame_check(to: Target, cal: &CalibrationJson) -> (Vec<String>, Vec<String>) {
    let (takes, wrong) = match to {
        Target::ArduPilot => (
            "ArduPilot applies its offsets and matrix in the body frame (forward, right, down), after COMPASS_ORIENT or AHRS_ORIENTATION",
            "sensor",
        ),
        Target::Px4 => (
            "PX4 applies CAL_MAGn_* in the sensor frame, before CAL_MAGn_ROT and the board rotation",
            "body",
        ),
        Target::MotionCal | Target::Magneto | Target::C => return (Vec::new(), Vec::new()),
    };
    let from = cal
        .log_format
        .as_deref()
        .map_or(String::new(), |f| format!(" (a {f} log)"));
    match cal.frame.as_deref() {
        Some(frame) if frame.starts_with(wrong) => (
            vec![format!(
                "the calibration is in the frame {:?}{from}: {takes}; rotate it, or calibrate from a log in that frame",
                crate::limits::excerpt(frame, 40)
            )],
            Vec::new(),
        ),
        Some(_) => (Vec::new(), Vec::new()),
        None => (
            Vec::new(),
            vec![format!(
                "the calibration is in the frame of its log's columns: {takes}; they must be those axes"
            )],
        ),
    }
}

/// The calibration in the target's unit, and the instance its parameters are for.
struct Converted {
    calibration: Calibration,
    /// The unit's name, or "the log's units" where neither the file nor `--units` names it.
    unit_label: String,
    instance: u8,
}

/// Checks the calibration's units, instance and motor interference against the target, and
/// converts it to the target's unit (where the target has one), its field quantities finite.
fn convert(args: &ExportArgs, cal: &CalibrationJson, shown: &str) -> Result<Converted> {
    let units = log_units(args, cal, shown)?;
    let instance = instance(args, cal, shown)?;
    let in_log = Calibration {
        bias: cal.bias,
        matrix: cal.soft_iron_inverse,
        magnitude: cal.magnitude,
        motor: motor(cal, shown)?,
    };
    let (calibration, unit_label) = match (args.to.unit(), units) {
        (Some(to), Some(from)) => (in_log.scaled(from.nt() / to.nt()), unit_name(to).to_string()),
        (Some(to), None) => bail!(
            "{shown}: field units is null (made without --units), and {} takes {}: give --units nT|uT|mG|G, the units of the log it was made from",
            args.to.name(),
            unit_name(to)
        ),
        (None, Some(from)) => (in_log, unit_name(from).to_string()),
        (None, None) => (in_log, "the log's units".to_string()),
    };
    if !calibration
        .bias
        .iter()
        .chain([&calibration.magnitude])
        .all(|v| v.is_finite())
    {
        bail!(
            "{shown}: bias {:?} and magnitude {} overflow in {unit_label}",
            cal.bias,
            crate::limits::show(cal.magnitude)
        );
    }
    Ok(Converted {
        calibration,
        unit_label,
        instance,
    })
}

/// The export made whole before anything is written, and what to say on stderr.
#[derive(Debug, Clone)]
pub struct Made {
    pub text: Vec<u8>,
    /// What the export keeps (`keeps`), in words.
    pub keep: String,
    pub notes: Vec<String>,
    /// The range warnings, the parts of the calibration left out for the log's firmware, then
    /// the frame warnings.
    pub problems: Vec<String>,
}

/// The export of `cal` (shown as `shown`) as `args` ask, made whole and not written: what the
/// command line and the library bindings share. `to` says where it would have gone, for the
/// refusal (` to standard output`, or empty). `args.calibration` and `args.out` are not read.
///
/// # Errors
/// As [`run`]: a calibration that fails its checks, units unknown where the target needs them,
/// a compass the target has no parameters for, `--strict` with a warning (exit 2); a calibration
/// not marked usable without `--force` (exit 3).
pub fn made(args: &ExportArgs, cal: &CalibrationJson, shown: &str, to: &str) -> Result<Made, Failure> {
    let converted = convert(args, cal, shown)?;
    let made = render(args, cal, shown, &converted)?;
    if !cal.usable && !args.force {
        return Err(Failure::Unusable(format!(
            "{shown}: nothing written{to}: {}; --force writes it all the same, its first line saying so",
            not_usable(cal)
        )));
    }
    if args.strict {
        refuse_strict(shown, &made.problems)?;
    }
    Ok(made)
}

/// The target's text with its header, its notes, and its warnings. A calibration not marked
/// usable (written only with `--force`) says so in its first line.
fn render(args: &ExportArgs, cal: &CalibrationJson, shown: &str, converted: &Converted) -> Result<Made> {
    let (frame_warnings, mut notes) = frame_check(args.to, cal);
    let keep = keeps(args.to, fmt::rotation_deg(&cal.soft_iron_inverse, &cal.k));
    let mut header = Vec::new();
    if !cal.usable {
        header.push(format!("{NOT_USABLE} (written with --force): {}", not_usable(cal)));
    }
    header.push(format!(
        "magcal {} export --to {} of {} (log {}, fit {})",
        env!("CARGO_PKG_VERSION"),
        args.to.name(),
        crate::limits::excerpt(shown, 120),
        crate::limits::excerpt(&cal.log, 120),
        crate::limits::excerpt(&cal.fit, 20)
    ));
    header.push(keep.clone());
    let mut text = Vec::new();
    let mut problems = write_target(&mut text, args, cal, converted, header, &mut notes)
        .with_context(|| format!("{}: --to {}", crate::limits::excerpt(shown, 120), args.to.name()))?;
    if converted.calibration.motor.is_some() && args.to.max_instance().is_none() {
        notes.push(format!(
            "{} has no motor compensation: the motor interference of {shown} is not exported",
            args.to.name()
        ));
    }
    problems.extend(frame_warnings);
    Ok(Made {
        text,
        keep,
        notes,
        problems,
    })
}

/// The names the log's firmware has of `to`'s parameters, where calibration.json records them
/// (`log_parameters`), with the messages they come from.
fn firmware(to: Target, cal: &CalibrationJson) -> Option<(&BTreeSet<String>, &str)> {
    let autopilot = match to {
        Target::ArduPilot => Autopilot::ArduPilot,
        Target::Px4 => Autopilot::Px4,
        Target::MotionCal | Target::Magneto | Target::C => return None,
    };
    let p = cal.log_parameters.as_ref()?;
    Some((p.names_of(autopilot)?, p.source.as_str()))
}

/// The groups left out for the log's firmware, in words for the file's comments and stderr:
/// those whose part of the calibration is lost go to `problems`, the others to `notes`.
fn left_out(
    left: &[LeftOut],
    source: &str,
    header: &mut Vec<String>,
    notes: &mut Vec<String>,
    problems: &mut Vec<String>,
) {
    for l in left {
        let words = format!(
            "{}: not written, the log's firmware has none (its {} list every parameter it has); {}",
            l.parameters,
            crate::limits::excerpt(source, 40),
            l.carried
        );
        header.push(words.clone());
        if l.lost {
            problems.push(words);
        } else {
            notes.push(words);
        }
    }
}

/// `COMPASS_OFFS_MAX` for the range check, mGauss, and where it comes from: `--offs-max`, else
/// the log's (calibration.json's `log_parameters`), else ArduPilot's default.
fn offs_max(args: &ExportArgs, cal: &CalibrationJson) -> (f64, String) {
    let logged = cal
        .log_parameters
        .as_ref()
        .and_then(|p| Some((p.compass_offs_max?, p.source.as_str())));
    match (args.offs_max, logged) {
        (Some(v), Some((l, source))) => (
            f64::from(v),
            format!(
                "--offs-max, over the log's {} ({})",
                crate::limits::show(l),
                crate::limits::excerpt(source, 40)
            ),
        ),
        (Some(v), None) => (f64::from(v), "--offs-max".to_string()),
        (None, Some((l, source))) => (l, format!("the log's ({})", crate::limits::excerpt(source, 40))),
        (None, None) => (
            f64::from(ARDUPILOT_OFFS_MAX_DEFAULT),
            "ArduPilot's default (calibration.json records no COMPASS_OFFS_MAX of its log); give the vehicle's with --offs-max"
                .to_string(),
        ),
    }
}

/// ArduPilot's text: the parameters its firmware has, the formula, the range check's limit; the
/// warnings.
fn write_ardupilot(
    text: &mut Vec<u8>,
    args: &ExportArgs,
    cal: &CalibrationJson,
    converted: &Converted,
    mut header: Vec<String>,
    notes: &mut Vec<String>,
) -> Result<Vec<String>> {
    let c = &converted.calibration;
    let mut problems = Vec::new();
    let p = match firmware(Target::ArduPilot, cal) {
        Some((names, source)) => {
            let (p, left) = ArduPilot::for_firmware(c, converted.instance, &|n: &str| names.contains(n));
            left_out(&left, source, &mut header, notes, &mut problems);
            p
        }
        None => ArduPilot::new(c, converted.instance),
    };
    representable(&p.params())?;
    let (limit, from) = offs_max(args, cal);
    let limit_words = format!(
        "the offsets are checked against COMPASS_OFFS_MAX = {} mGauss: {from}",
        crate::limits::show(limit)
    );
    header.push(limit_words.clone());
    notes.push(limit_words);
    let range: Vec<String> = p.warnings(c.magnitude, limit).iter().map(ToString::to_string).collect();
    problems.splice(0..0, range);
    header.push(
        "ArduPilot applies m = D * s * (r + OFS) + MOT * u (AP_Compass_Backend::correct_field), mGauss, D from DIA and ODI, s = COMPASS_SCALE (1 where the firmware has none), u throttle (0 to 1) or current (A)"
            .to_string(),
    );
    fmt::write_ardupilot(text, &header, &p)?;
    Ok(problems)
}

/// PX4's text: the parameters its firmware has and the formula; the parts left out.
fn write_px4(
    text: &mut Vec<u8>,
    cal: &CalibrationJson,
    converted: &Converted,
    mut header: Vec<String>,
    notes: &mut Vec<String>,
) -> Result<Vec<String>> {
    let (c, instance) = (&converted.calibration, converted.instance);
    let mut problems = Vec::new();
    let p = match firmware(Target::Px4, cal) {
        Some((names, source)) => {
            let (p, left) = Px4::for_firmware(c, instance, &|n: &str| names.contains(n));
            left_out(&left, source, &mut header, notes, &mut problems);
            p
        }
        None => Px4::new(c, instance),
    };
    representable(&p.params())?;
    header.push(
        "PX4 applies m = R * S * ((r + power * COMP) - OFF) (calibration::Magnetometer::Correct), Gauss, S from SCALE and ODIAG, power throttle (0 to 1) or current (kA)"
            .to_string(),
    );
    notes.push(format!(
        "CAL_MAG{instance}_ID and CAL_MAG{instance}_ROT must be those of the device on the vehicle: PX4 gives slot {instance} to the magnetometer whose device id is CAL_MAG{instance}_ID, and this calibration does not know it"
    ));
    fmt::write_px4(text, &header, &p)?;
    Ok(problems)
}

/// Writes the target's form to `text` under `header` and the line that states the target's
/// formula; the warnings (range and parameters left out: the autopilots'), and a note where the
/// target needs one.
fn write_target(
    text: &mut Vec<u8>,
    args: &ExportArgs,
    cal: &CalibrationJson,
    converted: &Converted,
    mut header: Vec<String>,
    notes: &mut Vec<String>,
) -> Result<Vec<String>> {
    let Converted {
        calibration,
        unit_label,
        ..
    } = converted;
    let mut values: Vec<(String, f64)> = Vec::new();
    for (i, axis) in ["x", "y", "z"].iter().enumerate() {
        values.push((format!("the bias along {axis}"), calibration.bias[i]));
        for (j, other) in ["x", "y", "z"].iter().enumerate() {
            values.push((
                format!("the soft-iron matrix's entry {axis}{other}"),
                calibration.matrix[i][j],
            ));
        }
    }
    values.push(("the field's magnitude".to_string(), calibration.magnitude));
    if let Some(m) = &calibration.motor {
        values.extend((0..3).map(|i| (format!("the motor term {}", ["x", "y", "z"][i]), m.per_unit[i])));
    }
    representable(&values)?;
    match args.to {
        Target::ArduPilot => return write_ardupilot(text, args, cal, converted, header, notes),
        Target::Px4 => return write_px4(text, cal, converted, header, notes),
        Target::MotionCal => {
            header.push(
                "MotionCal and Adafruit_Sensor_Calibration apply b = softiron * (raw - hardiron), uT; mag_softiron is xx yy zz xy xz yz"
                    .to_string(),
            );
            fmt::write_motioncal(text, &header, calibration)?;
        }
        Target::Magneto => {
            header.push(format!(
                "Magneto's form, in {unit_label}: Hcalc = Ainv*(H-B), |Hcalc| = Hm"
            ));
            fmt::write_magneto(text, &header, calibration)?;
        }
        Target::C => {
            // The formula leads the header, after the line of a calibration not to use.
            let at = header.iter().take_while(|l| l.starts_with(NOT_USABLE)).count();
            header.insert(
                at,
                format!("b = magcal_soft_iron * (raw - magcal_hard_iron), in {unit_label}; |b| = magcal_field"),
            );
            fmt::write_c(text, &header, calibration)?;
        }
    }
    Ok(Vec::new())
}

/// Refuses a value no target can hold: one that is not finite or lies beyond a 32-bit float
/// (ArduPilot's and PX4's parameters, MotionCal's and the C form's numbers are `float`).
fn representable(values: &[(String, f64)]) -> Result<()> {
    for (name, v) in values {
        if !(v.is_finite() && v.abs() <= f64::from(f32::MAX)) {
            bail!(
                "{name} would be {}: not a number the target holds (a 32-bit float: finite, at most 3.4e38 in size); nothing written",
                crate::limits::show(*v)
            );
        }
    }
    Ok(())
}

/// `--strict`: refuses the first of `problems`, counting the others.
fn refuse_strict(shown: &str, problems: &[String]) -> Result<()> {
    if let Some(first) = problems.first() {
        bail!(
            "{shown}: --strict: {first}{}",
            match problems.len() {
                1 => String::new(),
                n => format!(" (and {} more)", n - 1),
            }
        );
    }
    Ok(())
}
