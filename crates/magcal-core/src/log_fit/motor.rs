//! Motor interference: a log fit ([`super`]) whose bias moves with the battery current or the
//! throttle (docs/conventions.md "Motor interference").
//!
//! Reading `t` is `s_t = K b_t + O + d u_t + n_t` with `|b_t| = R` (\[P1\] eq. (5) with the bias
//! `O + d u_t`), `u_t` the input at the reading (amperes, or a throttle from 0 to 1) and `d` the
//! interference per unit input, in the log's units, in the readings' frame. The fit minimises
//! `sum_t (|P (s_t - O - d u_t)| - R)^2` over `P` (under the model: full, diagonal or offset) and
//! `O`, jointly with the three components of `d`, by the Levenberg-Marquardt loop of step 2,
//! started from the fit without interference.
//!
//! # Statistics
//! As [`super`]'s: the residual of reading `t` has the gradient of the fit without interference
//! in `(psi, S, O)` ([`crate::identifiability::residual_jacobian`] at the calibrated fields
//! `b_t = P (s_t - O - d u_t)`), and `u_t` times its bias gradient in `d`; the noise comes from
//! the residual scatter with `m - p - 3` degrees of freedom (or is given), and the standard errors
//! are the sandwich of the unweighted fit. `O` is the bias at zero input.
//!
//! # Identifiability
//! A constant input moves the bias by a constant `d u`: `d` and `O` are confounded. An input
//! that does not vary at all is refused ([`MotorError::ConstantInput`]); one that varies too
//! little leaves the information singular to working precision, which the fit reports as not
//! identifiable, with the smallest eigenvalue of the information in correlation form
//! ([`MotorFit::information_min_eigenvalue`], 0 for a singular information, 1 for independent
//! parameters).
#![allow(non_snake_case)]
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

use super::serial::Serial;
use super::statistics::std_errors;
use super::{
    FitModel, FitSettings, Frame, Noise, Order, Residual, chi_square_interval, fit_unit, normal_quantile, prepare,
    significant, student_quantile, truncated_variance_factor, unit_settings, untruncated,
};
use crate::calibration::{CalibrationError, CalibrationStatus, TwoStep, step2};
use crate::identifiability::{AxisNames, PhysicalScales, residual_jacobian};
use crate::sensor::ErrorModel;
use crate::small::{Mat3, Vec3, mat_t_vec, mat_vec, norm, sub, upper_triangular_inverse};

/// What drives the interference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum MotorInput {
    /// Battery current, amperes.
    Current,
    /// Throttle, 0 to 1.
    Throttle,
}

impl MotorInput {
    /// `current`, `throttle`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::Current => "current",
            Self::Throttle => "throttle",
        }
    }
}

/// Why a log has no motor fit.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MotorError {
    /// The readings have no fit (as [`super::fit`]).
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// An input value is NaN or infinite.
    #[error("reading {index}: the motor input is not finite ({value})")]
    NonFiniteInput {
        /// Index of the reading (0-based).
        index: usize,
        /// The value.
        value: f64,
    },
    /// Every input value is the same: the interference is confounded with the bias.
    #[error(
        "the motor input is {} at every reading: its interference cannot be told from the bias",
        crate::error::show(*.value)
    )]
    ConstantInput {
        /// The value.
        value: f64,
    },
}

/// A calibration fitted jointly with the motor interference.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct MotorFit {
    /// The model of `P`.
    pub model: FitModel,
    /// What drives the interference.
    pub input: MotorInput,
    /// `P = K^-1`: calibrated field `b = P (raw - bias - per_unit u)`.
    pub p: Mat3,
    /// `O`, the bias at zero input, the log's units.
    pub bias: Vec3,
    /// `(psi, S, O)` of the fit (`psi = 0` but for the full model).
    pub errors: ErrorModel,
    /// `d`: the reading's change per unit input, the log's units, the readings' frame.
    pub per_unit: Vec3,
    /// The magnitude `R` the fit maps the readings to, the log's units.
    pub magnitude: f64,
    /// Smallest and largest input of the readings fitted.
    pub input_range: [f64; 2],
    /// RMS of `|b_t| - R`, the log's units.
    pub residual_rms: f64,
    /// The noise per component the standard errors rest on, the log's units.
    pub noise: Noise,
    /// Standard errors of `per_unit`; `None` where the information is singular or the noise
    /// unknown.
    pub std_per_unit: Option<Vec3>,
    /// Standard errors of `psi` (degrees; 0 where fixed), as [`super::LogFit::std_psi_deg`].
    pub std_psi_deg: Option<Vec3>,
    /// Standard errors of `S`.
    pub std_scale: Option<Vec3>,
    /// Standard errors of `O`, the log's units.
    pub std_bias: Option<Vec3>,
    /// The multiple of a standard error that makes a 95 % interval, as
    /// [`super::LogFit::quantile95`].
    pub quantile95: Option<f64>,
    /// The smallest eigenvalue of the information of all the parameters in correlation form
    /// (`D A D`, `D = diag(A)^-1/2`): 0 where a combination is not determined at all.
    pub information_min_eigenvalue: f64,
    /// Every standard error known and within its physical scale ([`PhysicalScales`]; for `d`,
    /// its effect over the input's range within the bias scale), and the fit converged.
    pub identifiable: bool,
    /// In words.
    pub verdict: String,
    /// The fit's status.
    pub status: CalibrationStatus,
    /// Levenberg-Marquardt iterations.
    pub iterations: usize,
}

/// The upper-triangular entries of `P` a full fit estimates, row by row.
const ENTRIES: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];

/// Fits `readings` (any units) to `magnitude` (the same units) under `model`, with the bias
/// moving by `d input_t`; `input` holds one value per reading (amperes or throttle).
///
/// # Errors
/// As [`super::fit`] (with `model`'s parameters and 3 more as the fewest readings), a non-finite
/// or constant input.
///
/// # Panics
/// If `input` and `readings` differ in length, or as [`super::fit_with`] (caller bugs).
#[track_caller]
pub fn fit_motor(
    readings: &[Vec3],
    input: &[f64],
    kind: MotorInput,
    magnitude: f64,
    model: FitModel,
    settings: &FitSettings,
) -> Result<MotorFit, MotorError> {
    assert_eq!(readings.len(), input.len(), "one motor input per reading");
    let needed = model.parameters() + 3;
    if readings.len() < needed {
        return Err(CalibrationError::TooFewReadings {
            got: readings.len(),
            needed,
        }
        .into());
    }
    if let Some((index, &value)) = input.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(MotorError::NonFiniteInput { index, value });
    }
    let (lo, hi) = input
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    // Exactly one value: a spread the information check below could only call singular.
    if (hi - lo) <= 0.0 {
        return Err(MotorError::ConstantInput { value: lo });
    }
    let (frame, u) = prepare(readings, magnitude, model, settings)?;
    // The input in units of its largest size, so that w_t lies in [-1, 1].
    let a = lo.abs().max(hi.abs());
    let w: Vec<f64> = input.iter().map(|v| v / a).collect();
    let unit = unit_settings(&frame, settings);
    let f = match model {
        FitModel::Full => joint::<12>(&u, &w, model, &unit)?,
        FitModel::Diagonal => joint::<9>(&u, &w, model, &unit)?,
        FitModel::Offset => joint::<7>(&u, &w, model, &unit)?,
    };
    Ok(out_of_frame(f, &frame, a, magnitude, kind, [lo, hi]))
}

/// The joint fit in a [`Frame`] (unit field, input `w` scaled to [-1, 1]); `delta` is `d` in those
/// units.
struct Joint {
    model: FitModel,
    p: Mat3,
    bias: Vec3,
    delta: Vec3,
    residual_rms: f64,
    noise: Noise,
    /// Standard errors of `(psi, S, O, delta)`; `None` where unknown.
    std: Option<[Vec3; 4]>,
    quantile95: Option<f64>,
    information_min_eigenvalue: f64,
    status: CalibrationStatus,
    iterations: usize,
}

/// The map `x -> (P entries, o, delta)` of `model`, 12 x N: `P` is linear in `x`.
fn embedding<const N: usize>(model: FitModel) -> [[f64; N]; 12] {
    let mut t = [[0.0; N]; 12];
    let p_entries = N - 6;
    for (k, &(i, j)) in ENTRIES.iter().enumerate() {
        match model {
            FitModel::Full => t[k][k] = 1.0,
            FitModel::Diagonal if i == j => t[k][[0, 3, 5].iter().position(|&e| e == k).unwrap_or(0)] = 1.0,
            FitModel::Offset if i == j => t[k][0] = 1.0,
            _ => {}
        }
    }
    for r in 0..6 {
        t[6 + r][p_entries + r] = 1.0;
    }
    t
}

/// `(P, o, delta)` of the 12 embedded values.
fn split(x12: &[f64; 12]) -> (Mat3, Vec3, Vec3) {
    let mut p = [[0.0; 3]; 3];
    for (k, &(i, j)) in ENTRIES.iter().enumerate() {
        p[i][j] = x12[k];
    }
    (p, [x12[6], x12[7], x12[8]], [x12[9], x12[10], x12[11]])
}

/// `t x`.
fn embed<const N: usize>(t: &[[f64; N]; 12], x: &[f64; N]) -> [f64; 12] {
    std::array::from_fn(|r| (0..N).map(|c| t[r][c] * x[c]).sum())
}

/// Residual `|P (u - o - delta w)| - 1` and its gradient in the 12 embedded values:
/// `d/dP_jk = v_j e_k / |v|`, `d/do = -P^T v / |v|`, `d/d delta = -w P^T v / |v|`, with
/// `e = u - o - delta w`, `v = P e`; with [`Residual::Readings`], that residual divided by
/// `|P^T v / |v||` (step 2's, at the bias `o + delta w`), and its gradient.
fn residual(kind: Residual, x12: &[f64; 12], u: Vec3, w: f64) -> (f64, [f64; 12]) {
    let (p, o, delta) = split(x12);
    if kind == Residual::Readings {
        let o_w = [0, 1, 2].map(|i| o[i] + delta[i] * w);
        let (e, g9) = step2::reading_residual_at(&step2::pack(&p, o_w), u);
        return (e, std::array::from_fn(|i| if i < 9 { g9[i] } else { w * g9[i - 3] }));
    }
    let e = [0, 1, 2].map(|i| u[i] - o[i] - delta[i] * w);
    let v = mat_vec(&p, e);
    let n = norm(v);
    let dir = v.map(|c| c / n);
    let go = mat_t_vec(&p, dir);
    let mut g = [0.0; 12];
    for (k, &(i, j)) in ENTRIES.iter().enumerate() {
        g[k] = dir[i] * e[j];
    }
    for i in 0..3 {
        g[6 + i] = -go[i];
        g[9 + i] = -w * go[i];
    }
    (n - 1.0, g)
}

/// The joint fit of `N` unknowns (`model`'s and 3 for `delta`) in a frame.
fn joint<const N: usize>(u: &[Vec3], w: &[f64], model: FitModel, settings: &FitSettings) -> Result<Joint, MotorError> {
    let start = fit_unit(u, model, settings)?;
    let t = embedding::<N>(model);
    let mut x0 = [0.0; N];
    // P's entries as model's unknowns: its first N - 6 (the embedding takes them in order).
    let p_unknowns: Vec<f64> = match model {
        FitModel::Full => ENTRIES.iter().map(|&(i, j)| start.p[i][j]).collect(),
        FitModel::Diagonal => (0..3).map(|i| start.p[i][i]).collect(),
        FitModel::Offset => vec![(start.p[0][0] * start.p[1][1] * start.p[2][2]).cbrt()],
    };
    x0[..N - 6].copy_from_slice(&p_unknowns);
    x0[N - 6..N - 3].copy_from_slice(&start.bias);
    let project = |g12: &[f64; 12]| -> [f64; N] { std::array::from_fn(|c| (0..12).map(|r| t[r][c] * g12[r]).sum()) };
    let cost = |x: &[f64; N]| {
        let x12 = embed(&t, x);
        0.5 * u
            .iter()
            .zip(w)
            .map(|(&ui, &wi)| residual(settings.residual, &x12, ui, wi).0.powi(2))
            .sum::<f64>()
    };
    let normal = |x: &[f64; N]| {
        let x12 = embed(&t, x);
        let mut jtj = [[0.0; N]; N];
        let mut g = [0.0; N];
        for (&ui, &wi) in u.iter().zip(w) {
            let (r, g12) = residual(settings.residual, &x12, ui, wi);
            let gn = project(&g12);
            for i in 0..N {
                g[i] += gn[i] * r;
                for j in 0..=i {
                    jtj[i][j] += gn[i] * gn[j];
                }
            }
        }
        (jtj, g)
    };
    let fit = step2::levenberg_marquardt(&TwoStep::default(), x0, cost, normal, |_, _, _| None, false);
    let (mut p, bias, delta) = split(&embed(&t, &fit.x));
    // |P e| is unchanged when a row of P changes sign: keep the positive diagonal.
    for row in p.iter_mut() {
        let sign = row.iter().find(|v| **v != 0.0).copied().unwrap_or(1.0).signum();
        *row = row.map(|v| v * sign);
    }
    let k = upper_triangular_inverse(&p).ok_or(CalibrationError::NotPositiveDefinite {
        reason: "estimated P is singular",
    })?;
    let mut errors = ErrorModel::from_k(&k, bias);
    if model != FitModel::Full {
        errors = ErrorModel::new([0.0; 3], errors.scale(), bias).map_err(|_| super::out_of_range())?;
    }
    let fields: Vec<Vec3> = u
        .iter()
        .zip(w)
        .map(|(&ui, &wi)| mat_vec(&p, [0, 1, 2].map(|i| ui[i] - bias[i] - delta[i] * wi)))
        .collect();
    let m = u.len();
    let sum_sq: f64 = fields.iter().map(|b| (norm(*b) - 1.0).powi(2)).sum();
    let rows = || {
        residual_jacobian(&errors, &fields)
            .zip(w)
            .zip(&fields)
            .map(|(((j9, g2), &wi), b)| {
                let j12: [f64; 12] = std::array::from_fn(|i| if i < 9 { j9[i] } else { wi * j9[i - 3] });
                (j12, g2, norm(*b) - 1.0)
            })
    };
    let distance_sq: f64 = rows().map(|(_, g2, r)| r * r / g2).sum();
    let gain = rows().map(|(_, g2, _)| g2).sum::<f64>() / m as f64;
    let dof = m - N;
    let kept = (dof > 0)
        .then(|| match settings.residual {
            Residual::Paper => (sum_sq / (dof as f64 * gain)).sqrt(),
            Residual::Readings => (distance_sq / dof as f64).sqrt(),
        })
        .filter(|v| v.is_finite());
    let noise = match (settings.noise, kept, settings.truncation) {
        (Some(s), _, _) => Noise::Given(s),
        (None, Some(v), t) => {
            let value = t.map_or(v, |t| untruncated(v, t));
            Noise::Estimated {
                value,
                dof,
                interval95: chi_square_interval(value, dof),
            }
        }
        (None, None, _) => Noise::Unknown,
    };
    let c = match (settings.truncation, noise.value()) {
        (Some(t), Some(s)) if s > 0.0 => truncated_variance_factor(t / s),
        _ => 1.0,
    };
    let serial = match settings.order {
        _ if noise == Noise::Unknown => None,
        Order::Unknown => None,
        Order::Time => Some(Serial::of_residuals(
            &rows().map(|(_, g2, r)| r / g2.sqrt()).collect::<Vec<_>>(),
        )),
        Order::Batch(batch) => Some(Serial { batch, lag_one: None }),
    };
    let quantile95 = match (noise, serial) {
        (Noise::Unknown, _) => None,
        (_, Some(s)) => Some(student_quantile(0.975, s.dof(m))),
        (Noise::Given(_), None) => Some(normal_quantile(0.975)),
        (Noise::Estimated { dof, .. }, None) => Some(student_quantile(0.975, dof)),
    };
    // theta = (psi, S, O, delta) from the model's (psi?, S or s, O, delta).
    let theta = theta_map::<N>(model);
    let per_noise = std_errors(rows(), &theta, settings.residual, serial.map(|s| s.batch));
    let std = per_noise.zip(noise.value()).map(|((white, hac), s)| {
        let s = s / c.sqrt();
        // In time order the larger of the white and the long-run standard errors.
        let at = |i: usize| (white[i] * s).max(hac.as_ref().map_or(0.0, |h| h[i] / c.sqrt()));
        let k = N.saturating_sub(9);
        let scale: Vec3 = match model {
            FitModel::Offset => [at(0); 3],
            _ => [at(k), at(k + 1), at(k + 2)],
        };
        let psi = if model == FitModel::Full {
            [at(0), at(1), at(2)]
        } else {
            [0.0; 3]
        };
        let o = N - 6;
        [
            psi,
            scale,
            [at(o), at(o + 1), at(o + 2)],
            [at(o + 3), at(o + 4), at(o + 5)],
        ]
    });
    Ok(Joint {
        model,
        p,
        bias,
        delta,
        residual_rms: (sum_sq / m as f64).sqrt(),
        noise,
        std,
        quantile95,
        information_min_eigenvalue: min_eigenvalue(rows().map(|(j, _, _)| j), &theta),
        status: if fit.termination.converged() {
            CalibrationStatus::Ok
        } else {
            CalibrationStatus::NotConverged
        },
        iterations: fit.iterations,
    })
}

/// `theta = T x`: the 12 parameters `(psi_deg, S, O, delta)` of the residual's gradient from the
/// model's `N` (psi for the full model only, one common scale for the offset model).
fn theta_map<const N: usize>(model: FitModel) -> [[f64; N]; 12] {
    let mut t = [[0.0; N]; 12];
    let k = N.saturating_sub(9);
    for i in 0..3 {
        if model == FitModel::Full {
            t[i][i] = 1.0;
        }
        t[3 + i][if model == FitModel::Offset { 0 } else { k + i }] = 1.0;
    }
    for i in 0..6 {
        t[6 + i][N - 6 + i] = 1.0;
    }
    t
}

/// The smallest eigenvalue of `A = T^T (sum J J^T) T` in correlation form, by faer; 0 where a
/// diagonal entry vanishes or the decomposition fails.
fn min_eigenvalue<const N: usize>(rows: impl Iterator<Item = [f64; 12]>, t: &[[f64; N]; 12]) -> f64 {
    let mut a = [[0.0; N]; N];
    for j in rows {
        let x: [f64; N] = std::array::from_fn(|c| (0..12).map(|r| j[r] * t[r][c]).sum());
        for i in 0..N {
            for k in 0..N {
                a[i][k] += x[i] * x[k];
            }
        }
    }
    let d: [f64; N] = std::array::from_fn(|i| 1.0 / a[i][i].sqrt());
    if d.iter().any(|v| !v.is_finite()) {
        return 0.0;
    }
    let m = faer::Mat::from_fn(N, N, |i, k| d[i] * a[i][k] * d[k]);
    m.self_adjoint_eigen(faer::Side::Lower)
        .map_or(0.0, |e| (0..N).map(|i| e.S()[i]).fold(f64::INFINITY, f64::min).max(0.0))
}

/// The joint fit in the log's units at `magnitude`, with the input scaled back by `a`, and its
/// verdict.
fn out_of_frame(j: Joint, frame: &Frame, a: f64, magnitude: f64, input: MotorInput, range: [f64; 2]) -> MotorFit {
    let L = frame.length;
    let r = magnitude;
    let bias = [0, 1, 2].map(|i| frame.centre[i] + L * j.bias[i]);
    let per_unit = j.delta.map(|v| v * L / a);
    let p = j.p.map(|row| row.map(|v| v * r / L));
    let k = upper_triangular_inverse(&p).unwrap_or([[f64::NAN; 3]; 3]);
    let errors = ErrorModel::from_k(&k, bias);
    let errors = if j.model == FitModel::Full {
        errors
    } else {
        ErrorModel::new([0.0; 3], errors.scale(), bias).unwrap_or(errors)
    };
    let std = j
        .std
        .map(|[psi, s, o, d]| [psi, s.map(|v| v * L / r), o.map(|v| v * L), d.map(|v| v * L / a)]);
    let scales = PhysicalScales::default();
    let converged = j.status == CalibrationStatus::Ok;
    let span = range[1] - range[0];
    let axes = AxisNames::Sensor.names();
    let mut weak = Vec::new();
    let verdict_of = |weak: &mut Vec<String>| {
        let Some([psi, s, o, d]) = std else {
            return;
        };
        for i in 0..3 {
            if psi[i] > scales.psi_deg {
                weak.push(format!(
                    "non-orthogonality {} (std {} degrees)",
                    i + 1,
                    significant(psi[i], 3)
                ));
            }
            if s[i] > scales.scale_fraction * errors.scale()[i] {
                weak.push(format!("scale of axis {}", axes[i]));
            }
            if o[i] > scales.bias_fraction_of_field * r {
                weak.push(format!("bias of axis {}", axes[i]));
            }
            if d[i] * span > scales.bias_fraction_of_field * r {
                weak.push(format!(
                    "interference of axis {} (std over the input's range {} times the field)",
                    axes[i],
                    significant(d[i] * span / r, 3)
                ));
            }
        }
    };
    verdict_of(&mut weak);
    weak.dedup();
    let eig = significant(j.information_min_eigenvalue, 3);
    let (identifiable, verdict) = match (std, j.noise) {
        (_, Noise::Unknown) => (
            false,
            "unknown: the fit is exact, so the log does not give the noise its standard errors rest on".to_string(),
        ),
        (None, _) => (
            false,
            format!(
                "not determined: the {} varies too little over the log ({} to {}) to tell its interference from the bias (smallest eigenvalue of the information in correlation form {eig})",
                input.as_str(),
                significant(range[0], 4),
                significant(range[1], 4)
            ),
        ),
        _ if !converged => (
            false,
            format!(
                "not determined: the fit does not settle after {} iterations",
                j.iterations
            ),
        ),
        _ if weak.is_empty() => (
            true,
            format!("identifiable (smallest eigenvalue of the information in correlation form {eig})"),
        ),
        _ => (false, format!("not determined: {}", weak.join(", "))),
    };
    MotorFit {
        model: j.model,
        input,
        p,
        bias,
        errors,
        per_unit,
        magnitude,
        input_range: range,
        residual_rms: j.residual_rms * r,
        noise: j.noise.scaled(L),
        std_per_unit: std.map(|s| s[3]),
        std_psi_deg: std.map(|s| s[0]),
        std_scale: std.map(|s| s[1]),
        std_bias: std.map(|s| s[2]),
        quantile95: j.quantile95,
        information_min_eigenvalue: j.information_min_eigenvalue,
        identifiable,
        verdict,
        status: j.status,
        iterations: j.iterations,
    }
}

impl MotorFit {
    /// `P (raw - bias - per_unit input)`.
    pub fn apply(&self, raw: Vec3, input: f64) -> Vec3 {
        mat_vec(
            &self.p,
            sub(raw, [0, 1, 2].map(|i| self.bias[i] + self.per_unit[i] * input)),
        )
    }
}
