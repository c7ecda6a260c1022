//! A log made ready for replay: its readings with a reference attitude, in nT, with a known
//! sensor imposed where asked, the whole log's calibration and alignment, and each reading's
//! field direction in the sensor frame.

use anyhow::{Result, bail};
use magcal_core::aviation::z_up_of_ned;
use magcal_core::log_fit::{self, FitModel, FitSettings};
use magcal_core::reference::{AlignSettings, Alignment, align};
use magcal_core::small::{Mat3, mat_mul, mat_t_vec, mat_vec, norm, scale, upper_triangular_inverse};
use magcal_core::{ErrorModel, Vec3};

use crate::log::source::Log;
use crate::scenario::Scenario;

/// `replay --truth`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Truth {
    /// Nothing is known about the sensor: heading and direction errors only.
    #[default]
    None,
    /// Impose the scenario's `[sensor]` on the log's readings, `B' = K B + O` (O in nT, the
    /// readings turned into nT by `--units`): the real noise and attitudes are kept and the
    /// truth becomes the imposed sensor composed with the whole log's own calibration.
    Impose,
    /// The log's readings are of the scenario's sensor in the scenario's field (a log that
    /// `magcal simulate` wrote): the truth is the scenario's `[sensor]`, the magnitude its field's.
    Scenario,
}

impl Truth {
    /// The name in the outputs.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Impose => "impose",
            Self::Scenario => "scenario",
        }
    }
}

/// The log as the trials use it.
pub struct Prepared {
    /// The readings with an attitude, in log order, nT, after any imposed sensor.
    pub readings: Vec<Vec3>,
    /// Each one's attitude, body into a z-up reference frame.
    pub attitudes: Vec<Mat3>,
    /// Each one's time, seconds, where the log has times.
    pub times: Option<Vec<f64>>,
    /// Each one's field direction in the body frame, forward-right-down (unit): `C_t^T F / |F|`.
    pub directions: Vec<Vec3>,
    /// Readings of the log without an attitude, left out.
    pub without_attitude: usize,
    /// The field magnitude the calibrations map to, nT.
    pub magnitude: f64,
    /// Where it comes from, in words.
    pub magnitude_source: &'static str,
    /// The truth the estimates are scored against, where known.
    pub truth: Option<ErrorModel>,
    /// The noise of one reading per component, nT (after any imposed sensor), and its source.
    pub noise: f64,
    pub noise_source: &'static str,
    /// The whole log's full calibration of the readings (after any imposed sensor): what a held
    /// reading's own error is measured against ([`held_error`]).
    pub whole: magcal_core::log_fit::LogFit,
    /// The whole log's alignment of its own full calibration (before any imposed sensor).
    pub alignment: Alignment,
}

/// Prepares `log` (readings in units of `nt_per_unit` nT) for replay under `truth`, with the
/// noise `noise_nt` where given.
///
/// # Errors
/// A log without attitudes or with too few, a whole log that no full calibration fits, an
/// alignment that fails, or a noise that cannot be estimated.
pub fn prepare(
    log: &Log,
    nt_per_unit: f64,
    truth: Truth,
    scenario: &Scenario,
    noise_nt: Option<f64>,
) -> Result<Prepared> {
    let Some(attitudes) = log.attitudes.as_ref() else {
        bail!(
            "the log has no attitudes: give its attitude columns (--quaternion W,X,Y,Z or --euler ROLL,PITCH,YAW, with --attitude-frame)"
        );
    };
    let (clean, c, times) = with_attitude(log, attitudes, nt_per_unit);
    if clean.len() < 100 {
        bail!(
            "{} readings with an attitude: replay needs at least 100 (the designs' attitudes are drawn among them)",
            clean.len()
        );
    }
    let (magnitude, magnitude_source) = match truth {
        Truth::Scenario => (scenario.field.magnitude(), "the scenario's field"),
        _ => (median_norm(&clean), "the median magnitude of the log's readings"),
    };
    let whole_log = whole_log_settings(scenario);
    let base = log_fit::fit_with(&clean, magnitude, FitModel::Full, &whole_log)
        .map_err(|e| anyhow::anyhow!("the whole log does not calibrate (full model): {e}"))?;
    let calibrated: Vec<Vec3> = clean.iter().map(|r| base.apply(*r)).collect();
    let alignment = align(&calibrated, &c, &AlignSettings::default()).map_err(|e| {
        let fit = if base.identifiable {
            String::new()
        } else {
            format!(
                " (the full fit of its {} readings is not identifiable: {})",
                clean.len(),
                base.verdict
            )
        };
        anyhow::anyhow!("the whole log's calibration does not align with its attitudes: {e}{fit}")
    })?;
    let f = scale(1.0 / norm(alignment.field), alignment.field);
    let directions = c
        .iter()
        .map(|ct| {
            let d = mat_t_vec(ct, f);
            scale(1.0 / norm(d), d)
        })
        .collect();
    if truth == Truth::Scenario {
        let eta = magcal_core::RelativeErrors::between(&base.errors, &scenario.truth);
        let off = |e: Option<f64>, limit: f64| e.is_none_or(|e| e > limit);
        if off(eta.scale, 5.0) || off(eta.bias, 20.0) {
            bail!(
                "--truth scenario: the whole log's calibration (scale factors {:.4?}, bias {:.1?} nT) is not the scenario's sensor (eta S {:.1} %, eta O {:.1} %): --truth scenario is for logs of that sensor (magcal simulate); --truth impose puts it on a real log",
                base.errors.scale(),
                base.errors.bias_nt(),
                eta.scale.unwrap_or(f64::NAN),
                eta.bias.unwrap_or(f64::NAN)
            );
        }
    }
    let (readings, truth_model) = match truth {
        Truth::None => (clean, None),
        Truth::Scenario => (clean, Some(scenario.truth)),
        Truth::Impose => {
            let k = scenario.truth.K();
            let o = scenario.truth.bias_nt();
            let imposed = clean
                .iter()
                .map(|b| magcal_core::small::add(mat_vec(&k, *b), o))
                .collect();
            let k0 = upper_triangular_inverse(&base.p)
                .ok_or_else(|| anyhow::anyhow!("the whole log's calibration is singular"))?;
            let composed = ErrorModel::from_k(&mat_mul(&k, &k0), magcal_core::small::add(mat_vec(&k, base.bias), o));
            (imposed, Some(composed))
        }
    };
    let whole = log_fit::fit_with(&readings, magnitude, FitModel::Full, &whole_log)
        .map_err(|e| anyhow::anyhow!("the whole log does not calibrate (full model): {e}"))?;
    let (noise, noise_source) = match (noise_nt, whole.noise.value()) {
        (Some(n), _) => (n, "--noise"),
        (None, Some(n)) if n.is_finite() && n > 0.0 => (n, "the whole log's full fit (residual scatter)"),
        _ => bail!("the noise of the readings cannot be estimated from the whole log's fit: give --noise"),
    };
    Ok(Prepared {
        readings,
        attitudes: c,
        times,
        directions,
        without_attitude: log.readings.len() - log.with_attitude(),
        magnitude,
        magnitude_source,
        truth: truth_model,
        noise,
        noise_source,
        whole,
        alignment,
    })
}

/// The readings of `log` that have an attitude (in nT), their attitudes (z up) and their times.
fn with_attitude(log: &Log, attitudes: &[Option<Mat3>], nt_per_unit: f64) -> (Vec<Vec3>, Vec<Mat3>, Option<Vec<f64>>) {
    let mut clean = Vec::new();
    let mut c = Vec::new();
    let mut times = log.times.as_ref().map(|_| Vec::new());
    for (i, (r, a)) in log.readings.iter().zip(attitudes).enumerate() {
        let Some(a) = a else { continue };
        clean.push(scale(nt_per_unit, *r));
        c.push(z_up_of_ned(a));
        if let (Some(t), Some(all)) = (times.as_mut(), log.times.as_ref()) {
            t.push(all[i]);
        }
    }
    (clean, c, times)
}

/// The error a held reading carries, measured: the rms of `|P (h - O)| - R` over the held
/// readings of `starts` (windows of `hold`), with the whole log's full calibration. White noise
/// would give the noise over `sqrt(hold)`; what the field's changes from place to place, the
/// motion within a window and the attitude's timing add does not average down. `None` without
/// a window.
pub fn held_error(p: &Prepared, starts: &[usize], hold: usize) -> Option<f64> {
    if starts.is_empty() {
        return None;
    }
    let every = starts.len().div_ceil(20_000).max(1);
    let (sum, n) = starts.iter().step_by(every).fold((0.0, 0usize), |(sum, n), &s| {
        let h = magcal_core::replay::held(&p.readings, s, hold);
        (sum + (norm(p.whole.apply(h)) - p.magnitude).powi(2), n + 1)
    });
    Some((sum / n as f64).sqrt())
}

/// The median of `|r|`.
fn median_norm(readings: &[Vec3]) -> f64 {
    let mut n: Vec<f64> = readings.iter().map(|r| norm(*r)).collect();
    n.sort_by(f64::total_cmp);
    n[n.len() / 2]
}

/// The angle of a rotation, degrees.
pub fn rotation_angle_deg(q: &Mat3) -> f64 {
    let t = (q[0][0] + q[1][1] + q[2][2] - 1.0) / 2.0;
    t.clamp(-1.0, 1.0).acos().to_degrees()
}

/// The settings of the whole log's fits, which give the truth and the noise: the scenario's
/// residual, as the trials' fits use, so that the whole log is measured by the estimator the
/// designs are; no check by trials and no profile (the replay's trials judge the designs).
fn whole_log_settings(scenario: &Scenario) -> FitSettings {
    FitSettings {
        residual: scenario.calibration.residual,
        trials: 0,
        held_out: false,
        profile: false,
        ..FitSettings::default()
    }
}
