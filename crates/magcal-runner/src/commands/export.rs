//! `magcal export CAL.json --to ardupilot|px4|motioncal|magneto|c`: what the autopilot or the
//! tool takes, from a calibration file. The formulas and formats are in [`crate::log::export`].

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Args;

use super::Failure;
use crate::log::calibration::{CalibrationJson, read_calibration};
use crate::log::export::{
    self as fmt, ARDUPILOT_OFFS_MAX_DEFAULT, ArduPilot, Calibration, Motor, MotorInput, Px4, RangeWarning, Target,
    unit_name,
};
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
    #[arg(long, default_value_t = ARDUPILOT_OFFS_MAX_DEFAULT, value_parser = clap::value_parser!(u16).range(1..))]
    pub offs_max: u16,
    /// Refuse (exit 2, nothing written) a value outside what the autopilot accepts, a frame
    /// the autopilot does not take, or a calibration not marked usable; without it they are
    /// warnings on stderr.
    #[arg(long)]
    pub strict: bool,
    /// Write to this file, replaced whole (default, or `-`: standard output). Only a regular
    /// file or a missing path is replaced, and never the calibration.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// Runs `export`: the calibration is checked ([`CalibrationJson::check`]), converted to the
/// target's unit, written whole, and the values outside what the autopilot accepts named on
/// stderr.
///
/// # Errors
/// A bad calibration file, units unknown where the target needs them, a compass the target has
/// no parameters for, `--strict` with a warning (exit 2); a calibration not marked usable
/// (written, exit 3).
pub fn run(args: &ExportArgs) -> Result<(), Failure> {
    let cal = export_inner(args)?;
    if !cal.usable {
        return Err(Failure::Unusable(not_usable(args, &cal)));
    }
    Ok(())
}

fn not_usable(args: &ExportArgs, cal: &CalibrationJson) -> String {
    let reasons = if cal.reasons.is_empty() {
        "it does not say it is usable".to_string()
    } else {
        cal.reasons.join("; ")
    };
    format!(
        "{}: the parameters were written, but the calibration is not marked usable: {reasons}",
        args.calibration.display()
    )
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

/// Reads, converts and writes; the calibration, for its `usable`.
fn export_inner(args: &ExportArgs) -> Result<CalibrationJson> {
    let out = Output::from_flag(args.out.as_deref());
    let inputs = [args.calibration.as_path()];
    out.check(&inputs)?;
    let shown = args.calibration.display().to_string();
    let cal = read_calibration(&args.calibration)?;
    let converted = convert(args, &cal, &shown)?;
    let made = render(args, &cal, &shown, &converted)?;
    if args.strict {
        refuse_strict(args, &cal, &shown, &made.problems)?;
    }
    out.write(&inputs, |w| Ok(w.write_all(&made.text)?))?;
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
    Ok(cal)
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
            cal.magnitude
        );
    }
    Ok(Converted {
        calibration,
        unit_label,
        instance,
    })
}

/// The export made whole before anything is written, and what to say on stderr.
struct Made {
    text: Vec<u8>,
    /// What the export keeps ([`keeps`]).
    keep: String,
    notes: Vec<String>,
    /// The range warnings, then the frame warnings.
    problems: Vec<String>,
}

/// The target's text with its header, its notes, and its warnings.
fn render(args: &ExportArgs, cal: &CalibrationJson, shown: &str, converted: &Converted) -> Result<Made> {
    let (frame_warnings, mut notes) = frame_check(args.to, cal);
    let keep = keeps(args.to, fmt::rotation_deg(&cal.soft_iron_inverse, &cal.k));
    let header = vec![
        format!(
            "magcal {} export --to {} of {} (log {}, fit {})",
            env!("CARGO_PKG_VERSION"),
            args.to.name(),
            crate::limits::excerpt(shown, 120),
            crate::limits::excerpt(&cal.log, 120),
            crate::limits::excerpt(&cal.fit, 20)
        ),
        keep.clone(),
    ];
    let mut text = Vec::new();
    let warnings = write_target(&mut text, args, converted, header, &mut notes)?;
    if converted.calibration.motor.is_some() && args.to.max_instance().is_none() {
        notes.push(format!(
            "{} has no motor compensation: the motor interference of {shown} is not exported",
            args.to.name()
        ));
    }
    let mut problems: Vec<String> = warnings.iter().map(ToString::to_string).collect();
    problems.extend(frame_warnings);
    Ok(Made {
        text,
        keep,
        notes,
        problems,
    })
}

/// Writes the target's form to `text` under `header` and the line that states the target's
/// formula; the range warnings (ArduPilot's only), and a note where the target needs one.
fn write_target(
    text: &mut Vec<u8>,
    args: &ExportArgs,
    converted: &Converted,
    mut header: Vec<String>,
    notes: &mut Vec<String>,
) -> Result<Vec<RangeWarning>> {
    let Converted {
        calibration,
        unit_label,
        instance,
    } = converted;
    let instance = *instance;
    let mut warnings: Vec<RangeWarning> = Vec::new();
    match args.to {
        Target::ArduPilot => {
            let p = ArduPilot::new(calibration, instance);
            warnings = p.warnings(calibration.magnitude, f64::from(args.offs_max));
            header.push(
                "ArduPilot applies m = D * s * (r + OFS) + MOT * u (AP_Compass_Backend::correct_field), mGauss, D from DIA and ODI, s = COMPASS_SCALE, u throttle (0 to 1) or current (A)"
                    .to_string(),
            );
            fmt::write_ardupilot(text, &header, &p)?;
        }
        Target::Px4 => {
            let p = Px4::new(calibration, instance);
            header.push(
                "PX4 applies m = R * S * ((r + power * COMP) - OFF) (calibration::Magnetometer::Correct), Gauss, S from SCALE and ODIAG, power throttle (0 to 1) or current (kA)"
                    .to_string(),
            );
            notes.push(format!(
                "CAL_MAG{instance}_ID and CAL_MAG{instance}_ROT must be those of the device on the vehicle: PX4 gives slot {instance} to the magnetometer whose device id is CAL_MAG{instance}_ID, and this calibration does not know it"
            ));
            fmt::write_px4(text, &header, &p)?;
        }
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
            header.insert(
                0,
                format!("b = magcal_soft_iron * (raw - magcal_hard_iron), in {unit_label}; |b| = magcal_field"),
            );
            fmt::write_c(text, &header, calibration)?;
        }
    }
    Ok(warnings)
}

/// `--strict`: refuses the first of `problems` (counting the others), or a calibration not
/// marked usable.
fn refuse_strict(args: &ExportArgs, cal: &CalibrationJson, shown: &str, problems: &[String]) -> Result<()> {
    if let Some(first) = problems.first() {
        bail!(
            "{shown}: --strict: {first}{}",
            match problems.len() {
                1 => String::new(),
                n => format!(" (and {} more)", n - 1),
            }
        );
    }
    if !cal.usable {
        bail!(
            "--strict: {}",
            not_usable(args, cal).replace("the parameters were written, but ", "")
        );
    }
    Ok(())
}
