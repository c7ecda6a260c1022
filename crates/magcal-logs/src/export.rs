//! What autopilots and calibration tools take, from a calibration `b = M (r - c)`: the
//! parameters and their text, written to any [`Write`] so that they are tested on bytes.
//!
//! `M` is the symmetric square root of `G = P^T P` (`soft_iron_inverse` of `calibration.json`,
//! Magneto's and MotionCal's `A^-1`) and `c` the bias; `|b|` is the field in the unit the export
//! writes. \[P1\]'s upper-triangular `P` carries the same `G`, so `|P (r - c)| = |M (r - c)|`: the
//! two calibrated vectors differ by a fixed rotation `M P^-1`, a choice of frame. Every export
//! keeps `c` and `M`; the autopilots take nothing else (their matrices are symmetric).
//!
//! The formulas, each read from the autopilot's source (docs/conventions.md "Autopilot
//! parameters"):
//! - ArduPilot, `AP_Compass_Backend::correct_field`: `m = D s (r + OFS) + MOT u` (mGauss, body
//!   frame), `D = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]]`,
//!   `s = COMPASS_SCALE`, `u` the throttle (0 to 1) or the battery current (A).
//! - PX4, `calibration::Magnetometer::Correct`: `m = R S ((r + power COMP) - OFF)` (Gauss, sensor
//!   frame), `S` symmetric from `*SCALE` and `*ODIAG`, `power` the throttle (0 to 1) or the
//!   current in kA (`VehicleMagnetometer::Run`).
//! - MotionCal (`apply_calibration`) and Adafruit_Sensor_Calibration (`calibrate`):
//!   `b = softiron (r - hardiron)`, uT.
//! - Magneto: `Hcalc = Ainv (H - B)`, in the log's units.

use std::io::{self, Write};

use magcal_core::Vec3;
use magcal_core::small::{Mat3, mat_vec, norm};

use crate::site::Units;

/// What `magcal export --to` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Target {
    /// ArduPilot `.param` lines, `NAME,VALUE` (Mission Planner and MAVProxy load them).
    #[cfg_attr(feature = "clap", value(name = "ardupilot"))]
    ArduPilot,
    /// PX4 `param set NAME VALUE` lines (the MAVLink console or an nsh script).
    #[cfg_attr(feature = "clap", value(name = "px4"))]
    Px4,
    /// MotionCal's and Adafruit_Sensor_Calibration's hard iron, field and soft iron (uT).
    #[cfg_attr(feature = "clap", value(name = "motioncal"))]
    MotionCal,
    /// Magneto's combined bias `B` and correction matrix `Ainv`, in the log's units.
    #[cfg_attr(feature = "clap", value(name = "magneto"))]
    Magneto,
    /// A C header with the bias, the matrix and the field, in the log's units.
    #[cfg_attr(feature = "clap", value(name = "c"))]
    C,
}

impl Target {
    /// The name shown in the output.
    pub fn name(self) -> &'static str {
        match self {
            Self::ArduPilot => "ArduPilot",
            Self::Px4 => "PX4",
            Self::MotionCal => "MotionCal",
            Self::Magneto => "Magneto",
            Self::C => "C header",
        }
    }

    /// The unit the target takes; `None`: the calibration's own.
    pub fn unit(self) -> Option<Units> {
        match self {
            Self::ArduPilot => Some(Units::MilliGauss),
            Self::Px4 => Some(Units::Gauss),
            Self::MotionCal => Some(Units::MicroTesla),
            Self::Magneto | Self::C => None,
        }
    }

    /// The highest magnetometer instance the target has parameters for (`None`: it has no
    /// instances). ArduPilot: `COMPASS_OFS_*`, `COMPASS_OFS2_*`, `COMPASS_OFS3_*`; PX4:
    /// `CAL_MAG0_*` to `CAL_MAG3_*` (`calibration::Magnetometer::MAX_SENSOR_COUNT` = 4).
    pub fn max_instance(self) -> Option<u8> {
        match self {
            Self::ArduPilot => Some(2),
            Self::Px4 => Some(3),
            Self::MotionCal | Self::Magneto | Self::C => None,
        }
    }
}

/// The name of a unit as the outputs write it.
pub fn unit_name(unit: Units) -> &'static str {
    match unit {
        Units::NanoTesla => "nT",
        Units::MicroTesla => "uT",
        Units::MilliGauss => "mGauss",
        Units::Gauss => "Gauss",
    }
}

/// What the motor interference is proportional to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotorInput {
    /// Battery current, amperes.
    Current,
    /// Throttle, 0 to 1.
    Throttle,
}

impl MotorInput {
    /// `calibration.json`'s `motor.input`.
    pub fn parse(text: &str) -> Option<Self> {
        match text {
            "current" => Some(Self::Current),
            "throttle" => Some(Self::Throttle),
            _ => None,
        }
    }
}

/// Motor interference: the raw reading carries `d u` on top of the sensor's own reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Motor {
    pub input: MotorInput,
    /// `d`, the raw reading's change per unit of the input, in the calibration's unit.
    pub per_unit: Vec3,
}

/// A calibration `b = M (r - c - d u)` in one unit: what every export is made from.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// `c`.
    pub bias: Vec3,
    /// `M`, symmetric (dimensionless: the same in every unit).
    pub matrix: Mat3,
    /// `|b|`, the field the calibration scales to.
    pub magnitude: f64,
    pub motor: Option<Motor>,
}

impl Calibration {
    /// The same calibration with its field quantities multiplied by `factor` (another unit);
    /// the matrix is dimensionless.
    pub fn scaled(&self, factor: f64) -> Self {
        Self {
            bias: self.bias.map(|v| v * factor),
            matrix: self.matrix,
            magnitude: self.magnitude * factor,
            motor: self.motor.map(|m| Motor {
                input: m.input,
                per_unit: m.per_unit.map(|v| v * factor),
            }),
        }
    }
}

/// A value outside what the autopilot accepts, with where that is said.
#[derive(Debug, Clone, PartialEq)]
pub struct RangeWarning {
    /// The parameter (or quantity) named as the autopilot names it.
    pub parameter: String,
    pub value: f64,
    /// The accepted range in words.
    pub accepted: String,
    /// Where the autopilot says so, and what happens outside.
    pub why: String,
}

impl std::fmt::Display for RangeWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} = {} is outside {} ({})",
            self.parameter,
            crate::limits::show(self.value),
            self.accepted,
            self.why
        )
    }
}

/// `COMPASS_MIN_SCALE_FACTOR` and `COMPASS_MAX_SCALE_FACTOR` (ArduPilot `CompassCalibrator.h`):
/// `Compass::have_scale_factor` applies `COMPASS_SCALE` only within them.
pub const ARDUPILOT_SCALE_RANGE: [f64; 2] = [1.0 / 1.5, 1.5];
/// The documented `@Range` of `COMPASS_SCALE` (`AP_Compass.cpp`).
pub const ARDUPILOT_SCALE_DOCUMENTED: f64 = 1.3;
/// `CompassCalibrator::fit_acceptable`: `0.2 < DIA < 5`.
pub const ARDUPILOT_DIA_RANGE: [f64; 2] = [0.2, 5.0];
/// `CompassCalibrator::fit_acceptable`: `|ODI| < 1`.
pub const ARDUPILOT_ODI_MAX: f64 = 1.0;
/// `CompassCalibrator::fit_acceptable`: the field radius between `FIELD_RADIUS_MIN` and
/// `FIELD_RADIUS_MAX`, mGauss.
pub const ARDUPILOT_FIELD_RANGE: [f64; 2] = [150.0, 950.0];
/// `AP_COMPASS_OFFSETS_MAX_DEFAULT` (`AP_Compass.cpp`), the default of `COMPASS_OFFS_MAX`, mGauss.
pub const ARDUPILOT_OFFS_MAX_DEFAULT: u16 = 1800;
/// The documented `@Range` of `COMPASS_MOT*_X/Y/Z` (`AP_Compass.cpp`).
pub const ARDUPILOT_MOT_MAX: f64 = 1000.0;

/// A parameter group export would write that the log's firmware does not have, and what
/// becomes of what it would carry.
#[derive(Debug, Clone, PartialEq)]
pub struct LeftOut {
    /// The parameters as the autopilot names them: `COMPASS_SCALE2`, `COMPASS_ODI2_*`.
    pub parameters: String,
    /// What becomes of what they would carry, in words.
    pub carried: String,
    /// Part of the calibration is not carried (else other parameters carry it all).
    pub lost: bool,
}

/// The axes of a parameter group, as both autopilots name them.
const AXES: [&str; 3] = ["X", "Y", "Z"];

/// ArduPilot's parameters for one compass (mGauss); a group that is `None` is not written.
#[derive(Debug, Clone, PartialEq)]
pub struct ArduPilot {
    /// 0, 1 or 2.
    pub instance: u8,
    /// `COMPASS_OFS*_X/Y/Z = -c`.
    pub ofs: Option<Vec3>,
    /// `COMPASS_SCALE* = s = trace(M) / 3`; `None` where the firmware has no such parameter, and
    /// then `D = M` carries it.
    pub scale: Option<f64>,
    /// `COMPASS_DIA*_X/Y/Z = diag(M) / s` (`diag(M)` without `COMPASS_SCALE*`).
    pub dia: Option<Vec3>,
    /// `COMPASS_ODI*_X/Y/Z = (M01, M02, M12) / s` (without `s` likewise).
    pub odi: Option<Vec3>,
    /// `COMPASS_MOT*_X/Y/Z = -M d` and `COMPASS_MOTCT` (1 throttle, 2 current).
    pub mot: Option<(Vec3, u8)>,
}

impl ArduPilot {
    /// The parameters of `cal` (in mGauss) for compass `instance`, every group written.
    pub fn new(cal: &Calibration, instance: u8) -> Self {
        let m = &cal.matrix;
        let s = (m[0][0] + m[1][1] + m[2][2]) / 3.0;
        // m = D s (r + OFS) + MOT u must equal M (r - c - d u): OFS = -c, s D = M, MOT = -M d.
        Self {
            instance,
            ofs: Some(cal.bias.map(|v| -v)),
            scale: Some(s),
            dia: Some([m[0][0] / s, m[1][1] / s, m[2][2] / s]),
            odi: Some([m[0][1] / s, m[0][2] / s, m[1][2] / s]),
            mot: cal.motor.map(|motor| {
                let mot = mat_vec(m, motor.per_unit).map(|v| -v);
                let ct = match motor.input {
                    MotorInput::Throttle => 1,
                    MotorInput::Current => 2,
                };
                (mot, ct)
            }),
        }
    }

    /// The parameters of `cal` for a firmware that has the parameters `has` accepts, and the
    /// groups left out. Without `COMPASS_SCALE*`, `s` is 1 in `m = D s (r + OFS)`, so `D = M`
    /// carries the scale (`DIA = diag(M)`, `ODI = (M01, M02, M12)`); a group the firmware lacks
    /// otherwise is not written, and what it carries is lost.
    pub fn for_firmware(cal: &Calibration, instance: u8, has: &dyn Fn(&str) -> bool) -> (Self, Vec<LeftOut>) {
        let mut p = Self::new(cal, instance);
        let n = p.suffix();
        let group = |g: &str| AXES.iter().all(|a| has(&format!("COMPASS_{g}{n}_{a}")));
        let m = &cal.matrix;
        let s = p.scale.unwrap_or(1.0);
        let shown_s = crate::limits::show(s);
        let mut left = Vec::new();
        if !group("OFS") {
            p.ofs = None;
            left.push(LeftOut {
                parameters: format!("COMPASS_OFS{n}_*"),
                carried: "the offsets are not carried: ArduPilot keeps those it has".to_string(),
                lost: true,
            });
        }
        let (dia, odi) = (group("DIA"), group("ODI"));
        if !has(&format!("COMPASS_SCALE{n}")) {
            p.scale = None;
            let (carried, lost) = if dia {
                p.dia = Some([m[0][0], m[1][1], m[2][2]]);
                p.odi = Some([m[0][1], m[0][2], m[1][2]]);
                let odi_words = if odi {
                    format!(" and COMPASS_ODI{n}_*")
                } else {
                    String::new()
                };
                (
                    format!(
                        "its scale {shown_s} is carried by COMPASS_DIA{n}_*{odi_words} (D = M: ArduPilot then applies m = D (r + OFS))"
                    ),
                    false,
                )
            } else {
                (format!("the scale {shown_s} is not carried"), true)
            };
            left.push(LeftOut {
                parameters: format!("COMPASS_SCALE{n}"),
                carried,
                lost,
            });
        }
        if !dia {
            p.dia = None;
            p.odi = None;
            let applies = if p.scale.is_some() {
                "ArduPilot applies the scale alone"
            } else {
                "ArduPilot applies no matrix"
            };
            left.push(LeftOut {
                parameters: format!("COMPASS_DIA{n}_*"),
                carried: format!(
                    "the soft-iron matrix is not carried{}: {applies}",
                    if odi {
                        format!(" (nor COMPASS_ODI{n}_*, which ArduPilot applies only beside DIA)")
                    } else {
                        String::new()
                    }
                ),
                lost: true,
            });
        } else if !odi {
            let off = p.odi.take().unwrap_or_default();
            left.push(LeftOut {
                parameters: format!("COMPASS_ODI{n}_*"),
                carried: format!(
                    "the off-diagonal terms ({}, {}, {}) are not carried: ArduPilot applies the diagonal alone",
                    crate::limits::show(off[0]),
                    crate::limits::show(off[1]),
                    crate::limits::show(off[2])
                ),
                lost: true,
            });
        }
        let motct = has("COMPASS_MOTCT");
        if p.mot.is_some() && !(group("MOT") && motct) {
            p.mot = None;
            let mut missing: Vec<String> = Vec::new();
            if !group("MOT") {
                missing.push(format!("COMPASS_MOT{n}_*"));
            }
            if !motct {
                missing.push("COMPASS_MOTCT".to_string());
            }
            left.push(LeftOut {
                parameters: missing.join(" and "),
                carried: "the motor interference is not compensated".to_string(),
                lost: true,
            });
        }
        (p, left)
    }

    /// The number ArduPilot puts after `OFS`, `DIA`, ... for this instance: none, 2 or 3.
    fn suffix(&self) -> String {
        match self.instance {
            0 => String::new(),
            i => (i + 1).to_string(),
        }
    }

    /// The parameters in the order written, with their values.
    pub fn params(&self) -> Vec<(String, f64)> {
        let n = self.suffix();
        let mut out = Vec::with_capacity(16);
        for (group, v) in [("OFS", self.ofs), ("DIA", self.dia), ("ODI", self.odi)] {
            if let Some(v) = v {
                for (axis, x) in AXES.iter().zip(v) {
                    out.push((format!("COMPASS_{group}{n}_{axis}"), x));
                }
            }
        }
        if let Some(s) = self.scale {
            out.push((format!("COMPASS_SCALE{n}"), s));
        }
        if let Some((mot, ct)) = self.mot {
            for (axis, x) in AXES.iter().zip(mot) {
                out.push((format!("COMPASS_MOT{n}_{axis}"), x));
            }
            out.push(("COMPASS_MOTCT".to_string(), f64::from(ct)));
        }
        out
    }

    /// The values written outside what ArduPilot accepts, for a field of `magnitude` mGauss and
    /// the vehicle's `COMPASS_OFFS_MAX` (mGauss). The values are finite (the calibration is
    /// checked).
    pub fn warnings(&self, magnitude: f64, offs_max: f64) -> Vec<RangeWarning> {
        let n = self.suffix();
        let mut out = Vec::new();
        if let Some(ofs) = self.ofs {
            offset_warnings(&n, ofs, offs_max, &mut out);
        }
        let [lo, hi] = ARDUPILOT_DIA_RANGE;
        for (axis, &v) in AXES.iter().zip(self.dia.iter().flatten()) {
            if v <= lo || v >= hi {
                out.push(RangeWarning {
                    parameter: format!("COMPASS_DIA{n}_{axis}"),
                    value: v,
                    accepted: format!("{lo} to {hi} (exclusive)"),
                    why: "CompassCalibrator::fit_acceptable".to_string(),
                });
            }
        }
        for (axis, &v) in AXES.iter().zip(self.odi.iter().flatten()) {
            if v.abs() >= ARDUPILOT_ODI_MAX {
                out.push(RangeWarning {
                    parameter: format!("COMPASS_ODI{n}_{axis}"),
                    value: v,
                    accepted: format!("-{ARDUPILOT_ODI_MAX} to {ARDUPILOT_ODI_MAX} (exclusive)"),
                    why: "CompassCalibrator::fit_acceptable".to_string(),
                });
            }
        }
        if let Some(scale) = self.scale {
            out.extend(scale_warning(&n, scale));
        }
        let [lo, hi] = ARDUPILOT_FIELD_RANGE;
        if magnitude <= lo || magnitude >= hi {
            out.push(RangeWarning {
                parameter: "the field magnitude".to_string(),
                value: magnitude,
                accepted: format!("{lo} to {hi} mGauss"),
                why:
                    "FIELD_RADIUS_MIN/MAX of CompassCalibrator::fit_acceptable, the Earth's field: are the units right?"
                        .to_string(),
            });
        }
        if let Some((mot, _)) = self.mot {
            for (axis, &v) in AXES.iter().zip(&mot) {
                if v.abs() > ARDUPILOT_MOT_MAX {
                    out.push(RangeWarning {
                        parameter: format!("COMPASS_MOT{n}_{axis}"),
                        value: v,
                        accepted: format!("-{ARDUPILOT_MOT_MAX} to {ARDUPILOT_MOT_MAX}"),
                        why: "the parameter's documented @Range in AP_Compass.cpp".to_string(),
                    });
                }
            }
        }
        out
    }
}

/// The offsets `ofs` of instance suffix `n` against `COMPASS_OFFS_MAX`: per axis (the
/// calibrator) and in length (the pre-arm check).
fn offset_warnings(n: &str, ofs: Vec3, offs_max: f64, out: &mut Vec<RangeWarning>) {
    for (axis, &v) in AXES.iter().zip(&ofs) {
        if v.abs() >= offs_max {
            out.push(RangeWarning {
                parameter: format!("COMPASS_OFS{n}_{axis}"),
                value: v,
                accepted: format!("-{offs_max} to {offs_max} mGauss"),
                why: "COMPASS_OFFS_MAX; ArduPilot's calibrator refuses such a fit, CompassCalibrator::fit_acceptable"
                    .to_string(),
            });
        }
    }
    let length = norm(ofs);
    if length > offs_max {
        out.push(RangeWarning {
            parameter: format!("|COMPASS_OFS{n}|"),
            value: length,
            accepted: format!("0 to {offs_max} mGauss"),
            why: "COMPASS_OFFS_MAX; the pre-arm check fails with \"Compass offsets too high\"".to_string(),
        });
    }
}

/// `COMPASS_SCALE` of instance suffix `n` outside what ArduPilot applies, or above its
/// documented range.
fn scale_warning(n: &str, scale: f64) -> Option<RangeWarning> {
    let [lo, hi] = ARDUPILOT_SCALE_RANGE;
    if !(lo..=hi).contains(&scale) {
        let s = crate::limits::show(scale);
        Some(RangeWarning {
            parameter: format!("COMPASS_SCALE{n}"),
            value: scale,
            accepted: format!("{lo:.4} to {hi} (COMPASS_MIN/MAX_SCALE_FACTOR)"),
            why: format!(
                "Compass::have_scale_factor: ArduPilot ignores it and applies D alone, a field {s} times too small; COMPASS_SCALE{n} 0 with DIA and ODI times {s} carries it in D"
            ),
        })
    } else if scale > ARDUPILOT_SCALE_DOCUMENTED {
        Some(RangeWarning {
            parameter: format!("COMPASS_SCALE{n}"),
            value: scale,
            accepted: format!("0 to {ARDUPILOT_SCALE_DOCUMENTED}"),
            why: "the parameter's documented @Range in AP_Compass.cpp; Compass::have_scale_factor applies it up to 1.5"
                .to_string(),
        })
    } else {
        None
    }
}

/// PX4's parameters for one calibration slot (Gauss); a group that is `None` is not written.
#[derive(Debug, Clone, PartialEq)]
pub struct Px4 {
    /// The `n` of `CAL_MAGn_*`, 0 to 3.
    pub instance: u8,
    /// `CAL_MAGn_XOFF/YOFF/ZOFF = +c`.
    pub off: Option<Vec3>,
    /// `CAL_MAGn_XSCALE/YSCALE/ZSCALE = diag(M)`.
    pub scale: Option<Vec3>,
    /// `CAL_MAGn_XODIAG/YODIAG/ZODIAG = (M01, M02, M12)`.
    pub odiag: Option<Vec3>,
    /// `CAL_MAGn_XCOMP/YCOMP/ZCOMP = -d` per unit of PX4's power (throttle 0 to 1, or current in
    /// kA: `-1000 d` for `d` per ampere) and `CAL_MAG_COMP_TYP` (1 throttle, 2 current of battery
    /// 0).
    pub comp: Option<(Vec3, u8)>,
}

impl Px4 {
    /// The parameters of `cal` (in Gauss) for calibration slot `instance`, every group written.
    pub fn new(cal: &Calibration, instance: u8) -> Self {
        let m = &cal.matrix;
        // m = R S ((r + power COMP) - OFF) must equal R M (r - c - d u): OFF = c, S = M,
        // power COMP = -d u.
        Self {
            instance,
            off: Some(cal.bias),
            scale: Some([m[0][0], m[1][1], m[2][2]]),
            odiag: Some([m[0][1], m[0][2], m[1][2]]),
            comp: cal.motor.map(|motor| match motor.input {
                MotorInput::Throttle => (motor.per_unit.map(|v| -v), 1),
                MotorInput::Current => (motor.per_unit.map(|v| -1000.0 * v), 2),
            }),
        }
    }

    /// The parameters of `cal` for a firmware that has the parameters `has` accepts, and the
    /// groups left out (PX4 has no common scale to carry another group's part: what a missing
    /// group carries is lost).
    pub fn for_firmware(cal: &Calibration, instance: u8, has: &dyn Fn(&str) -> bool) -> (Self, Vec<LeftOut>) {
        let mut p = Self::new(cal, instance);
        let n = instance;
        let group = |g: &str| AXES.iter().all(|a| has(&format!("CAL_MAG{n}_{a}{g}")));
        let mut left = Vec::new();
        let mut leave = |parameters: String, carried: &str| {
            left.push(LeftOut {
                parameters,
                carried: carried.to_string(),
                lost: true,
            });
        };
        if !group("OFF") {
            p.off = None;
            leave(
                format!("CAL_MAG{n}_*OFF"),
                "the offsets are not carried: PX4 keeps those it has",
            );
        }
        if !group("SCALE") {
            p.scale = None;
            p.odiag = None;
            leave(
                format!("CAL_MAG{n}_*SCALE"),
                "the soft-iron matrix is not carried: PX4 keeps the scales it has",
            );
        } else if !group("ODIAG") {
            p.odiag = None;
            leave(
                format!("CAL_MAG{n}_*ODIAG"),
                "the off-diagonal terms are not carried: PX4 applies the diagonal alone",
            );
        }
        let typ = has("CAL_MAG_COMP_TYP");
        if p.comp.is_some() && !(group("COMP") && typ) {
            p.comp = None;
            let mut missing: Vec<String> = Vec::new();
            if !group("COMP") {
                missing.push(format!("CAL_MAG{n}_*COMP"));
            }
            if !typ {
                missing.push("CAL_MAG_COMP_TYP".to_string());
            }
            leave(missing.join(" and "), "the motor interference is not compensated");
        }
        (p, left)
    }

    /// The parameters in the order written, with their values.
    pub fn params(&self) -> Vec<(String, f64)> {
        let n = self.instance;
        let mut out = Vec::with_capacity(14);
        for (name, v) in [("OFF", self.off), ("SCALE", self.scale), ("ODIAG", self.odiag)] {
            if let Some(v) = v {
                for (axis, x) in AXES.iter().zip(v) {
                    out.push((format!("CAL_MAG{n}_{axis}{name}"), x));
                }
            }
        }
        if let Some((comp, typ)) = self.comp {
            for (axis, x) in AXES.iter().zip(comp) {
                out.push((format!("CAL_MAG{n}_{axis}COMP"), x));
            }
            out.push(("CAL_MAG_COMP_TYP".to_string(), f64::from(typ)));
        }
        out
    }
}

/// `text` fit for one line of a comment: control characters (a newline would start a line of
/// parameters) become `?`.
pub fn comment_safe(text: &str) -> String {
    text.chars().map(|c| if c.is_control() { '?' } else { c }).collect()
}

/// `notes` as `#` comment lines.
fn comments(w: &mut dyn Write, notes: &[String]) -> io::Result<()> {
    for note in notes {
        writeln!(w, "# {}", comment_safe(note))?;
    }
    Ok(())
}

/// Writes ArduPilot's `.param` lines: `#` comments, then `NAME,VALUE` (the form Mission Planner
/// writes; its `ParamFile.loadParamFile` and pymavlink's `MAVParmDict.load`, which MAVProxy's
/// `param load` uses, both split on commas and spaces and skip lines starting with `#`).
///
/// # Errors
/// A write that fails.
pub fn write_ardupilot(w: &mut dyn Write, notes: &[String], p: &ArduPilot) -> io::Result<()> {
    comments(w, notes)?;
    for (name, value) in p.params() {
        writeln!(w, "{name},{value}")?;
    }
    Ok(())
}

/// Writes PX4's `param set NAME VALUE` lines after `#` comments.
///
/// # Errors
/// A write that fails.
pub fn write_px4(w: &mut dyn Write, notes: &[String], p: &Px4) -> io::Result<()> {
    comments(w, notes)?;
    for (name, value) in p.params() {
        writeln!(w, "param set {name} {value}")?;
    }
    Ok(())
}

/// Writes MotionCal's calibration (uT) as `name values` lines after `#` comments:
/// `mag_hardiron X Y Z`, `mag_field B`, `mag_softiron XX YY ZZ XY XZ YZ`, the six entries in the
/// order MotionCal sends them (`send_calibration`) and Adafruit_Sensor_Calibration_EEPROM stores
/// them (`offsets[10..15]`).
///
/// # Errors
/// A write that fails.
pub fn write_motioncal(w: &mut dyn Write, notes: &[String], cal: &Calibration) -> io::Result<()> {
    comments(w, notes)?;
    let [x, y, z] = cal.bias;
    let m = &cal.matrix;
    writeln!(w, "mag_hardiron {x} {y} {z}")?;
    writeln!(w, "mag_field {}", cal.magnitude)?;
    writeln!(
        w,
        "mag_softiron {} {} {} {} {} {}",
        m[0][0], m[1][1], m[2][2], m[0][1], m[0][2], m[1][2]
    )
}

/// Writes Magneto's result as Magneto prints it (`Combined bias vector B`, `Correction matrix
/// Ainv, using Hm=...`, `Where Hcalc = Ainv*(H-B)`), at full precision, after `#` comments.
///
/// # Errors
/// A write that fails.
pub fn write_magneto(w: &mut dyn Write, notes: &[String], cal: &Calibration) -> io::Result<()> {
    comments(w, notes)?;
    let [x, y, z] = cal.bias;
    writeln!(w, "Combined bias vector B:")?;
    writeln!(w, "{x} {y} {z}")?;
    writeln!(w)?;
    writeln!(w, "Correction matrix Ainv, using Hm={}:", cal.magnitude)?;
    for row in &cal.matrix {
        writeln!(w, "{} {} {}", row[0], row[1], row[2])?;
    }
    writeln!(w)?;
    writeln!(w, "Where Hcalc = Ainv*(H-B)")
}

/// A C `float` literal of `v` that reads back as `v` to float precision (`{:?}` always has a
/// decimal point or an exponent).
fn c_float(v: f64) -> String {
    format!("{v:?}f")
}

/// Writes a C header: `magcal_hard_iron[3]`, `magcal_soft_iron[3][3]` and `magcal_field`, with
/// `notes` (the first says the formula and the units) in a block comment.
///
/// # Errors
/// A write that fails.
pub fn write_c(w: &mut dyn Write, notes: &[String], cal: &Calibration) -> io::Result<()> {
    writeln!(w, "/*")?;
    for note in notes {
        // "*/" inside would end the comment.
        writeln!(w, " * {}", comment_safe(note).replace("*/", "* /"))?;
    }
    writeln!(w, " */")?;
    writeln!(w, "#ifndef MAGCAL_CALIBRATION_H")?;
    writeln!(w, "#define MAGCAL_CALIBRATION_H")?;
    writeln!(w)?;
    let [x, y, z] = cal.bias.map(c_float);
    writeln!(w, "static const float magcal_hard_iron[3] = {{{x}, {y}, {z}}};")?;
    writeln!(w, "static const float magcal_soft_iron[3][3] = {{")?;
    for row in &cal.matrix {
        let [a, b, c] = row.map(c_float);
        writeln!(w, "    {{{a}, {b}, {c}}},")?;
    }
    writeln!(w, "}};")?;
    writeln!(w, "static const float magcal_field = {};", c_float(cal.magnitude))?;
    writeln!(w)?;
    writeln!(w, "#endif /* MAGCAL_CALIBRATION_H */")
}

/// The angle (degrees) of the rotation `M K` between the calibrated vectors of `M (r - c)` and
/// of \[P1\]'s `P (r - c)` (`K = P^-1`): `M (r - c) = (M K) P (r - c)`.
pub fn rotation_deg(matrix: &Mat3, k: &Mat3) -> f64 {
    let r = magcal_core::small::mat_mul(matrix, k);
    let cos = ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0).clamp(-1.0, 1.0);
    cos.acos().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// docs/conventions.md "Autopilot parameters": c = (120, -45, 300) mGauss and M.
    fn check_value() -> Calibration {
        Calibration {
            bias: [120.0, -45.0, 300.0],
            matrix: [[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 1.01]],
            magnitude: 500.0,
            motor: None,
        }
    }

    /// A symmetric matrix from its diagonal and its (01, 02, 12) entries, as both autopilots
    /// build theirs.
    fn symmetric(diag: Vec3, off: Vec3) -> Mat3 {
        [
            [diag[0], off[0], off[1]],
            [off[0], diag[1], off[2]],
            [off[1], off[2], diag[2]],
        ]
    }

    /// ArduPilot's `m = D s (r + OFS)` (`AP_Compass_Backend::correct_field`) with the groups
    /// `ap` writes, a missing one at what the firmware then applies: `s` 1, `D` the identity or
    /// diagonal, `OFS` 0 (its own, taken as 0 here).
    fn ardupilot_m(ap: &ArduPilot, r: Vec3) -> Vec3 {
        let ofs = ap.ofs.unwrap_or([0.0; 3]);
        let s = ap.scale.unwrap_or(1.0);
        let d = symmetric(ap.dia.unwrap_or([1.0; 3]), ap.odi.unwrap_or([0.0; 3]));
        mat_vec(&d, [0, 1, 2].map(|i| s * (r[i] + ofs[i])))
    }

    #[test]
    fn without_compass_scale_d_carries_it_and_gives_the_same_field() {
        // A firmware without COMPASS_SCALE2 (ArduPilot before it had one): D = M, the field the
        // same as with the scale, to rounding.
        let cal = check_value();
        let all = ArduPilot::new(&cal, 1);
        let (folded, left) = ArduPilot::for_firmware(&cal, 1, &|n: &str| !n.starts_with("COMPASS_SCALE"));
        assert_eq!(folded.scale, None);
        assert_eq!(folded.dia, Some([1.05, 0.97, 1.01]));
        assert_eq!(folded.odi, Some([0.02, -0.01, 0.03]));
        assert_eq!(left.len(), 1);
        assert_eq!(left[0].parameters, "COMPASS_SCALE2");
        assert!(!left[0].lost);
        assert!(
            left[0]
                .carried
                .starts_with("its scale 1.01 is carried by COMPASS_DIA2_* and COMPASS_ODI2_*")
        );
        let names: Vec<String> = folded.params().into_iter().map(|p| p.0).collect();
        assert_eq!(names.len(), 9);
        assert!(!names.iter().any(|n| n.contains("SCALE")), "{names:?}");
        let r = [400.0, -100.0, 250.0];
        let (a, b) = (ardupilot_m(&all, r), ardupilot_m(&folded, r));
        let want = mat_vec(&cal.matrix, [0, 1, 2].map(|i| r[i] - cal.bias[i]));
        for i in 0..3 {
            assert!(
                (a[i] - want[i]).abs() <= 16.0 * f64::EPSILON * norm(want),
                "{a:?} {want:?}"
            );
            assert!(
                (b[i] - want[i]).abs() <= 16.0 * f64::EPSILON * norm(want),
                "{b:?} {want:?}"
            );
        }
        // The folded D is checked as written: a scale of 3 gives DIA of 3, inside 0.2 to 5, where
        // COMPASS_SCALE 3 would be ignored.
        let mut big = check_value();
        big.matrix = big.matrix.map(|row| row.map(|v| 3.0 * v));
        assert_eq!(
            ArduPilot::new(&big, 0).warnings(500.0, 1800.0)[0].parameter,
            "COMPASS_SCALE"
        );
        let (p, _) = ArduPilot::for_firmware(&big, 0, &|n: &str| n != "COMPASS_SCALE");
        assert!(p.warnings(500.0, 1800.0).is_empty());
        big.matrix = big.matrix.map(|row| row.map(|v| 2.0 * v));
        let (p, _) = ArduPilot::for_firmware(&big, 0, &|n: &str| n != "COMPASS_SCALE");
        let w = p.warnings(500.0, 1800.0);
        assert_eq!(w[0].parameter, "COMPASS_DIA_X");
        assert!(
            w[0].to_string().starts_with("COMPASS_DIA_X = 6.3") && w[0].to_string().contains(" is outside 0.2 to 5"),
            "{}",
            w[0]
        );
    }

    #[test]
    fn a_group_the_firmware_lacks_is_left_out_and_said_lost() {
        let mut cal = check_value();
        cal.motor = Some(Motor {
            input: MotorInput::Current,
            per_unit: [1.0, 2.0, 3.0],
        });
        // Without ODI and MOTCT: DIA and SCALE written; the off-diagonals and the motor lost.
        let has = |n: &str| !n.starts_with("COMPASS_ODI") && n != "COMPASS_MOTCT";
        let (p, left) = ArduPilot::for_firmware(&cal, 0, &has);
        assert_eq!((p.odi, p.mot), (None, None));
        assert!(p.dia.is_some() && p.scale.is_some());
        let said: Vec<(&str, bool)> = left.iter().map(|l| (l.parameters.as_str(), l.lost)).collect();
        assert_eq!(said, [("COMPASS_ODI_*", true), ("COMPASS_MOTCT", true)]);
        assert!(left[0].carried.contains("(0.0198019801980198"), "{}", left[0].carried);
        // Nothing but the offsets: neither scale nor matrix carried.
        let (p, left) = ArduPilot::for_firmware(&cal, 2, &|n: &str| n.starts_with("COMPASS_OFS3"));
        assert_eq!(p.params().len(), 3);
        assert_eq!(left.len(), 3, "{left:?}");
        assert!(left.iter().all(|l| l.lost));
        // PX4 1.9 had no ODIAG or COMP.
        let has = |n: &str| n.ends_with("OFF") || n.ends_with("SCALE");
        let (p, left) = Px4::for_firmware(&cal, 1, &has);
        assert_eq!(p.params().len(), 6);
        let said: Vec<&str> = left.iter().map(|l| l.parameters.as_str()).collect();
        assert_eq!(said, ["CAL_MAG1_*ODIAG", "CAL_MAG1_*COMP and CAL_MAG_COMP_TYP"]);
        // A firmware with everything: the same as new.
        assert_eq!(
            Px4::for_firmware(&cal, 1, &|_: &str| true),
            (Px4::new(&cal, 1), Vec::new())
        );
        assert_eq!(
            ArduPilot::for_firmware(&cal, 1, &|_: &str| true),
            (ArduPilot::new(&cal, 1), Vec::new())
        );
    }

    #[test]
    fn instance_numbers_name_the_parameters_as_ardupilot_and_px4_do() {
        let cal = check_value();
        let names = |i| {
            ArduPilot::new(&cal, i)
                .params()
                .into_iter()
                .map(|p| p.0)
                .collect::<Vec<_>>()
        };
        assert_eq!(names(0)[0], "COMPASS_OFS_X");
        assert_eq!(names(0)[9], "COMPASS_SCALE");
        assert_eq!(names(1)[3], "COMPASS_DIA2_X");
        assert_eq!(names(2)[8], "COMPASS_ODI3_Z");
        assert_eq!(names(2)[9], "COMPASS_SCALE3");
        let px4 = Px4::new(&cal, 2).params();
        assert_eq!(px4[0].0, "CAL_MAG2_XOFF");
        assert_eq!(px4[5].0, "CAL_MAG2_ZSCALE");
        assert_eq!(px4[7].0, "CAL_MAG2_YODIAG");
    }

    #[test]
    fn the_motor_terms_cancel_the_interference_in_each_autopilot_formula() {
        // r = K b + c + d u with M K = I here (b = M (r - c - d u)): each autopilot's formula,
        // applied to r with the input u, gives back M (r - c - d u) to rounding.
        let mut cal = check_value();
        let d = [3.0, -2.0, 5.0];
        for input in [MotorInput::Throttle, MotorInput::Current] {
            cal.motor = Some(Motor { input, per_unit: d });
            let u = 0.7;
            let r = [400.0, -100.0, 250.0];
            let want = mat_vec(&cal.matrix, [0, 1, 2].map(|i| r[i] - cal.bias[i] - d[i] * u));
            let ap = ArduPilot::new(&cal, 0);
            let (mot, ct) = ap.mot.unwrap();
            assert_eq!(ct, if input == MotorInput::Throttle { 1 } else { 2 });
            let got = [0, 1, 2].map(|i| ardupilot_m(&ap, r)[i] + mot[i] * u);
            let px4 = Px4::new(&cal, 0);
            let (comp, typ) = px4.comp.unwrap();
            let power = if typ == 1 { u } else { u / 1000.0 };
            let (scale, odiag, off) = (px4.scale.unwrap(), px4.odiag.unwrap(), px4.off.unwrap());
            let got_px4 = mat_vec(
                &symmetric(scale, odiag),
                [0, 1, 2].map(|i| r[i] + power * comp[i] - off[i]),
            );
            let tol = 64.0 * f64::EPSILON * norm(want);
            for i in 0..3 {
                assert!((got[i] - want[i]).abs() <= tol, "{input:?} ArduPilot {got:?} {want:?}");
                assert!(
                    (got_px4[i] - want[i]).abs() <= tol,
                    "{input:?} PX4 {got_px4:?} {want:?}"
                );
            }
        }
    }

    #[test]
    fn ranges_are_checked_at_their_edges() {
        let ap = |scale: f64, ofs: f64| ArduPilot {
            instance: 1,
            ofs: Some([ofs, 0.0, 0.0]),
            scale: Some(scale),
            dia: Some([1.0; 3]),
            odi: Some([0.0; 3]),
            mot: None,
        };
        assert!(ap(1.0, 0.0).warnings(500.0, 1800.0).is_empty());
        // 1.5 is still applied; 1.5 is above the documented 1.3.
        let w = ap(1.5, 0.0).warnings(500.0, 1800.0);
        assert_eq!(w.len(), 1);
        assert!(w[0].to_string().contains("documented @Range"), "{}", w[0]);
        let w = ap(1.6, 0.0).warnings(500.0, 1800.0);
        assert!(
            w[0].to_string().starts_with("COMPASS_SCALE2 = 1.6 is outside"),
            "{}",
            w[0]
        );
        // An offset at COMPASS_OFFS_MAX fails the calibrator's strict test and not the length's.
        let w = ap(1.0, -1800.0).warnings(500.0, 1800.0);
        assert_eq!(w.len(), 1, "{w:?}");
        assert_eq!(w[0].parameter, "COMPASS_OFS2_X");
        assert_eq!(ap(1.0, 0.0).warnings(950.0, 1800.0)[0].parameter, "the field magnitude");
    }

    #[test]
    fn comments_stay_on_one_line() {
        assert_eq!(comment_safe("a\nCOMPASS_OFS_X,5\r"), "a?COMPASS_OFS_X,5?");
        let mut out = Vec::new();
        write_c(&mut out, &["x */ y".to_string()], &check_value()).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert_eq!(text.matches("*/").count(), 2, "{text}");
        assert!(text.contains("{120.0f, -45.0f, 300.0f}"), "{text}");
    }
}
