//! `calibrate --motor current|throttle`: the calibration fitted jointly with the interference of
//! the motors (docs/conventions.md "Motor interference").

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use magcal_core::log_fit::motor::{MotorFit, MotorInput, fit_motor};
use magcal_core::log_fit::{self, FitSettings, LogFit};

use crate::log::calibration::{CalibrationJson, IntervalJson, MotorJson, StdError};
use crate::log::source::Log;

/// `--motor`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Motor {
    /// Battery current, amperes (ArduPilot `COMPASS_MOTCT` 2, PX4 `CAL_MAG_COMP_TYP` 2).
    Current,
    /// Throttle, 0 to 1 (ArduPilot `COMPASS_MOTCT` 1, PX4 `CAL_MAG_COMP_TYP` 1).
    Throttle,
}

/// The input of each reading.
///
/// # Errors
/// A log without the input, or a reading without one.
pub fn inputs(log: &Log, motor: Motor) -> Result<Vec<f64>> {
    let (series, kind, flag) = match motor {
        Motor::Current => (&log.currents, "battery current", "--current"),
        Motor::Throttle => (&log.throttles, "throttle", "--throttle"),
    };
    let Some(series) = series else {
        bail!(
            "--motor {}: the log has no {kind} (a CSV log names its column with {flag})",
            name(motor)
        );
    };
    let missing = series.iter().filter(|v| v.is_none()).count();
    if let Some(first) = series.iter().position(Option::is_none) {
        let at = format!("the first at {} {}", log.origin.position_name(), log.lines[first]);
        if log.origin.format == crate::log::flight::Format::Csv {
            bail!(
                "--motor {}: {missing} of {} readings have no {kind} ({at}: its cell is empty or not a number); fill it, or cut the log (--from, --to, --where)",
                name(motor),
                series.len()
            );
        }
        bail!(
            "--motor {}: {missing} of {} readings have no {kind} near them in time ({at}); cut the log to where it has one (--from, --to)",
            name(motor),
            series.len()
        );
    }
    let u: Vec<f64> = series.iter().flatten().copied().collect();
    if let Some(i) = u.iter().position(|v| !v.is_finite()) {
        bail!(
            "--motor {}: the {kind} of the reading at {} {} is {}, not a finite number",
            name(motor),
            log.origin.position_name(),
            log.lines[i],
            u[i]
        );
    }
    Ok(u)
}

/// The joint fit of `log` under the model of `fit`, at its magnitude, then `log`'s readings with
/// the fitted interference removed and their fit: the calibration at zero input. The joint fit
/// is returned for its interference and its standard errors, which carry the uncertainty of the
/// interference (the refit's do not).
///
/// # Errors
/// A log without the input, or with a reading without one; a joint fit that fails.
pub fn refit(log: &mut Log, fit: &LogFit, motor: Motor, settings: &FitSettings) -> Result<(LogFit, MotorFit)> {
    let u = inputs(log, motor)?;
    let kind = match motor {
        Motor::Current => MotorInput::Current,
        Motor::Throttle => MotorInput::Throttle,
    };
    let joint = fit_motor(&log.readings, &u, kind, fit.magnitude, fit.model, settings)
        .with_context(|| format!("--motor {}: no joint fit", name(motor)))?;
    for (r, u) in log.readings.iter_mut().zip(&u) {
        *r = std::array::from_fn(|i| r[i] - joint.per_unit[i] * u);
    }
    let refit = log_fit::fit_tested(&log.readings, fit.magnitude, fit.model, settings)
        .with_context(|| format!("--motor {}: the readings without the interference", name(motor)))?;
    Ok((refit, joint))
}

pub fn name(motor: Motor) -> &'static str {
    match motor {
        Motor::Current => "current",
        Motor::Throttle => "throttle",
    }
}

/// Records the joint fit in `json`: the interference, and the joint fit's standard errors of the
/// calibration in place of the refit's; a joint fit that is not identifiable makes the
/// calibration unusable.
pub fn record(json: &mut CalibrationJson, joint: &MotorFit) {
    json.motor = Some(MotorJson {
        input: joint.input.as_str().to_string(),
        per_unit: joint.per_unit,
        std_error: joint.std_per_unit,
        input_range: joint.input_range,
    });
    json.std_error = StdError {
        psi_deg: joint.std_psi_deg,
        scale: joint.std_scale,
        bias: joint.std_bias,
    };
    json.interval95 = match (
        json.interval95.take(),
        joint.std_psi_deg,
        joint.std_scale,
        joint.std_bias,
    ) {
        (Some(i), Some(psi), Some(scale), Some(bias)) => Some(IntervalJson {
            psi_deg: psi.map(|v| i.quantile * v),
            scale: scale.map(|v| i.quantile * v),
            bias: bias.map(|v| i.quantile * v),
            ..i
        }),
        _ => None,
    };
    if !joint.identifiable {
        // The verdict is the joint fit's: the refit at zero input alone would call it identifiable.
        json.identifiable = false;
        json.usable = false;
        json.verdict = format!("motor interference: {}", joint.verdict);
        json.reasons.push(json.verdict.clone());
    }
}
