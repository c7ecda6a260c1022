//! Vector calibration of an ordinary flight (docs/conventions.md "Vector calibration along a
//! track"): the field given at each reading (the World Magnetic Model along the GPS track), `K`
//! as full as the flight determines, and the motor's interference.
//!
//! # Model
//! `m_t = K C_t^T F_t + O + d u_t + n_t`, readings in the body frame (or the frame `K` is
//! wanted in), `F_t` the field at reading `t` in the reference frame (z up), `u_t` the motor's
//! input (battery current or throttle) where one is fitted. `K` is
//! - [`VectorModel::Offsets`]: the identity: the readings are already the field in the body
//!   frame but for the offsets (3 unknowns, 6 with `d`);
//! - [`VectorModel::Diagonal`]: `diag(s)`, a scale factor per axis (6, 9 with `d`);
//! - [`VectorModel::Full`]: any matrix: scale, soft iron, non-orthogonality and the sensor's
//!   turn against the body (12, 15 with `d`).
//!
//! A level flight turns the body about its vertical axis only: the body-frame field's vertical
//! component hardly changes, so the full model's third column and `O_z` are nearly confounded,
//! and tilts of 10 degrees determine them poorly. The reduced models, fewer unknowns from the
//! same readings, are what an ordinary flight determines; the standard errors say which.
//!
//! # Estimation and statistics
//! Linear least squares in units of the mean field magnitude (one Gauss-Newton step from zero,
//! a second for the rounding of the first), solved in correlation form as [`super::fit_vector`]
//! is. Standard errors as its: the white ones from the residual scatter with `3 m - p` degrees of
//! freedom, and in time order the sandwich of the scores' long-run covariance by overlapping
//! batch means of a tenth of the log, its diagonal at least the white one's. Identifiable as
//! [`super::fit_vector`] judges it, and `d` when its standard error times the input's range is
//! within the field magnitude.

use super::{Data, NormalEquations, Unit, VectorError, VectorFit, assess_parts, sandwich, std_errors, validate};
use crate::small::{Mat3, Vec3, dot, mat_t_vec, mat_vec, norm};

/// How much of `K` a vector fit estimates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VectorModel {
    /// `K = I`: offsets only.
    Offsets,
    /// `K = diag(s)`: offsets and a scale factor per axis.
    Diagonal,
    /// `K` any matrix.
    Full,
}

impl VectorModel {
    /// Unknowns of `K`.
    fn k_unknowns(self) -> usize {
        match self {
            Self::Offsets => 0,
            Self::Diagonal => 3,
            Self::Full => 9,
        }
    }
}

const NAMES_FULL: [&str; 15] = [
    "K11", "K12", "K13", "K21", "K22", "K23", "K31", "K32", "K33", "Ox", "Oy", "Oz", "dx", "dy", "dz",
];
const NAMES_DIAGONAL: [&str; 9] = ["s1", "s2", "s3", "Ox", "Oy", "Oz", "dx", "dy", "dz"];
const NAMES_OFFSETS: [&str; 6] = ["Ox", "Oy", "Oz", "dx", "dy", "dz"];

/// The unknowns of a model, `K` then `O` then `d`.
struct Layout {
    model: VectorModel,
    motor: bool,
}

impl Layout {
    fn p(&self) -> usize {
        self.model.k_unknowns() + 3 + if self.motor { 3 } else { 0 }
    }

    fn names(&self) -> &'static [&'static str] {
        let all: &'static [&'static str] = match self.model {
            VectorModel::Offsets => &NAMES_OFFSETS,
            VectorModel::Diagonal => &NAMES_DIAGONAL,
            VectorModel::Full => &NAMES_FULL,
        };
        &all[..self.p()]
    }

    /// The three rows of the Jacobian of reading `t`'s residual (body field `b`, input `u`),
    /// with a sign that does not matter to the normal equations: `d m_i / d theta`.
    fn rows(&self, b: Vec3, u: f64) -> [[f64; 15]; 3] {
        let nk = self.model.k_unknowns();
        let mut rows = [[0.0; 15]; 3];
        for (i, row) in rows.iter_mut().enumerate() {
            match self.model {
                VectorModel::Offsets => {}
                VectorModel::Diagonal => row[i] = b[i],
                VectorModel::Full => row[3 * i..3 * i + 3].copy_from_slice(&b),
            }
            row[nk + i] = 1.0;
            if self.motor {
                row[nk + 3 + i] = u;
            }
        }
        rows
    }

    /// `K` of the unknowns `theta`.
    fn k(&self, theta: &[f64]) -> Mat3 {
        match self.model {
            VectorModel::Offsets => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            VectorModel::Diagonal => [[theta[0], 0.0, 0.0], [0.0, theta[1], 0.0], [0.0, 0.0, theta[2]]],
            VectorModel::Full => std::array::from_fn(|i| std::array::from_fn(|j| theta[3 * i + j])),
        }
    }

    fn o(&self, theta: &[f64]) -> Vec3 {
        let nk = self.model.k_unknowns();
        [theta[nk], theta[nk + 1], theta[nk + 2]]
    }

    fn d(&self, theta: &[f64]) -> Vec3 {
        let nk = self.model.k_unknowns();
        if self.motor {
            [theta[nk + 3], theta[nk + 4], theta[nk + 5]]
        } else {
            [0.0; 3]
        }
    }

    /// The index in the 12 unknowns of the full model without `d` (`K` row-major, then `O`) of
    /// unknown `a`, or `None` for `d`.
    fn full_index(&self, a: usize) -> Option<usize> {
        let nk = self.model.k_unknowns();
        if a < nk {
            Some(match self.model {
                VectorModel::Diagonal => 4 * a,
                _ => a,
            })
        } else if a < nk + 3 {
            Some(9 + a - nk)
        } else {
            None
        }
    }
}

/// Each reading's residual `m / |F| - K b - o - d u` (units of the mean field) under `theta`.
fn residuals<'a>(
    data: &'a Data,
    layout: &'a Layout,
    theta: &'a [f64],
    inputs: Option<&'a [f64]>,
) -> impl Iterator<Item = (Vec3, Vec3, f64)> + 'a {
    let (k, o, d) = (layout.k(theta), layout.o(theta), layout.d(theta));
    data.iter_with([0.0; 3]).enumerate().map(move |(t, (m, c, f))| {
        let b = mat_t_vec(c, f);
        let u = inputs.map_or(0.0, |x| x[t]);
        let model = mat_vec(&k, b);
        let r: Vec3 = std::array::from_fn(|i| m[i] - model[i] - o[i] - d[i] * u);
        (r, b, u)
    })
}

/// The normal equations of `theta`'s residuals.
fn normal_equations(data: &Data, layout: &Layout, theta: &[f64], inputs: Option<&[f64]>) -> NormalEquations {
    let p = layout.p();
    let mut jtj = vec![vec![0.0; p]; p];
    let mut jtr = vec![0.0; p];
    for (r, b, u) in residuals(data, layout, theta, inputs) {
        let rows = layout.rows(b, u);
        for (i, row) in rows.iter().enumerate() {
            for a in 0..p {
                jtr[a] += row[a] * r[i];
                for c in 0..=a {
                    jtj[a][c] += row[a] * row[c];
                }
            }
        }
    }
    for a in 0..p {
        for c in 0..a {
            jtj[c][a] = jtj[a][c];
        }
    }
    NormalEquations {
        jtj,
        jtr,
        names: layout.names(),
    }
}

/// Calibrates `readings` against `attitudes` (body to a z-up reference frame) and the field
/// `fields[t]` of each reading (reference frame, the readings' units) under `model`, with the
/// motor's interference where `inputs` gives its input per reading (see the module
/// documentation).
///
/// # Errors
/// As [`super::fit_vector`]; `fields` or `inputs` of another length than `readings`, a field that
/// is zero or not finite, an input that is not finite, a constant input (confounded with `O`).
pub fn fit_track(
    readings: &[Vec3],
    attitudes: &[Mat3],
    fields: &[Vec3],
    inputs: Option<&[f64]>,
    model: VectorModel,
    order: crate::log_fit::Order,
) -> Result<VectorFit, VectorError> {
    let layout = Layout {
        model,
        motor: inputs.is_some(),
    };
    if fields.len() != readings.len() || inputs.is_some_and(|u| u.len() != readings.len()) {
        return Err(VectorError::LengthMismatch {
            readings: readings.len(),
            attitudes: fields.len(),
        });
    }
    if let Some(bad) = fields.iter().find(|f| !(norm(**f).is_finite() && norm(**f) > 0.0)) {
        return Err(VectorError::InvalidField { value: *bad });
    }
    if let Some(u) = inputs {
        let (lo, hi) = u
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
            return Err(VectorError::NotDetermined {
                weakest: format!(
                    "the motor's input is constant or not finite (from {lo} to {hi}): its interference is confounded with the offsets"
                ),
            });
        }
    }
    let n = fields.len().max(1) as f64;
    let mean: Vec3 = std::array::from_fn(|i| fields.iter().map(|f| f[i]).sum::<f64>() / n);
    let (scale, _) = validate(readings, attitudes, super::ReferenceField::Given(mean))?;
    let needed = layout.p() / 3 + 1;
    if readings.len() < needed {
        return Err(VectorError::TooFewReadings {
            got: readings.len(),
            needed,
            unknowns: layout.p(),
        });
    }
    let data = Data {
        readings,
        attitudes,
        scale,
        fields: Some(fields.iter().map(|f| f.map(|v| v / scale)).collect()),
    };
    // Linear: one step from zero solves it, a second removes the rounding of the first.
    let mut theta = vec![0.0; layout.p()];
    for _ in 0..2 {
        let step = normal_equations(&data, &layout, &theta, inputs).solve()?;
        for (x, s) in theta.iter_mut().zip(&step) {
            *x += s;
        }
    }
    let k = layout.k(&theta);
    let det = crate::reference::det(&k);
    if det.is_nan() || det <= 0.0 {
        // An information too weak to trust leaves any `K`, a left-handed one too: it is what the
        // attitudes do not determine that is said, not a frame the readings do not have. Too
        // weak: an unknown of `K` with a standard error of half its unit value or more, or of
        // the offsets with one of the field or more (the physical scales of the verdict).
        let ne = normal_equations(&data, &layout, &theta, inputs);
        let inv = ne.inverse()?;
        let rss: f64 = residuals(&data, &layout, &theta, inputs)
            .map(|(r, _, _)| dot(r, r))
            .sum();
        let dof = (3 * readings.len()).saturating_sub(layout.p()).max(1);
        let noise2 = rss / dof as f64;
        let nk = layout.model.k_unknowns();
        let weak = (0..nk + 3).find(|&a| {
            let std = (inv[a][a] * noise2).max(0.0).sqrt();
            std >= if a < nk { 0.5 } else { norm(mean) / scale }
        });
        if let Some(a) = weak {
            return Err(VectorError::NotDetermined {
                weakest: format!(
                    "{} has a standard error beyond its physical scale (and the estimate a left-handed K, det {det:.4})",
                    layout.names()[a]
                ),
            });
        }
        return Err(VectorError::LeftHanded { determinant: det });
    }
    Ok(assess_track(&data, &layout, &theta, inputs, scale, order, mean))
}

/// The statistics and verdict of a track fit.
fn assess_track(
    data: &Data,
    layout: &Layout,
    theta: &[f64],
    inputs: Option<&[f64]>,
    scale: f64,
    order: crate::log_fit::Order,
    mean: Vec3,
) -> VectorFit {
    let m = data.readings.len();
    let p = layout.p();
    let parts: Vec<(Vec3, Vec3, f64)> = residuals(data, layout, theta, inputs).collect();
    let rss: f64 = parts.iter().map(|(r, _, _)| dot(*r, *r)).sum();
    let dof = 3 * m - p;
    let noise_unit = (rss / dof as f64).sqrt();
    let k = layout.k(theta);
    let unit = Unit {
        k,
        o: layout.o(theta),
        f: mean.map(|v| v / scale),
    };
    let inverse = normal_equations(data, layout, theta, inputs).inverse().ok();
    let radial: Vec<f64> = parts
        .iter()
        .map(|(r, b, _)| {
            let w = mat_vec(&k, *b);
            dot(*r, w) / norm(w)
        })
        .collect();
    let serial = match order {
        crate::log_fit::Order::Unknown => None,
        crate::log_fit::Order::Time => Some(crate::log_fit::Serial::of_residuals(&radial)),
        crate::log_fit::Order::Batch(batch) => Some(crate::log_fit::Serial { batch, lag_one: None }),
    };
    let covariance = inverse.as_ref().map(|inv| {
        let white: Vec<Vec<f64>> = inv
            .iter()
            .map(|row| row.iter().map(|v| v * noise_unit * noise_unit).collect())
            .collect();
        match serial {
            Some(s) => {
                let scores: Vec<[f64; 15]> = parts
                    .iter()
                    .map(|(r, b, u)| {
                        let rows = layout.rows(*b, *u);
                        std::array::from_fn(|a| (0..3).map(|i| rows[i][a] * r[i]).sum())
                    })
                    .collect();
                let b = crate::log_fit::serial::long_run_covariance(&scores, s.batch);
                sandwich(inv, &b, &white, 3 * m)
            }
            None => white,
        }
    });
    // The 12 unknowns of the full model without `d` for the derived standard errors (zero for
    // what the model holds fixed), and `d`'s own.
    let (std_error, std_motor) = match covariance.as_ref().filter(|_| noise_unit.is_finite()) {
        Some(cov) => {
            let mut full = vec![vec![0.0; 12]; 12];
            for a in 0..p {
                for c in 0..p {
                    if let (Some(x), Some(y)) = (layout.full_index(a), layout.full_index(c)) {
                        full[x][y] = cov[a][c];
                    }
                }
            }
            let nk = layout.model.k_unknowns();
            let motor = layout
                .motor
                .then(|| std::array::from_fn(|i| cov[nk + 3 + i][nk + 3 + i].max(0.0).sqrt() * scale));
            (std_errors(&unit, &full, false, scale), motor)
        }
        None => (None, None),
    };
    let parts_fit = assess_parts(&unit, scale, noise_unit, dof, serial, m, rss, std_error, false);
    let mut fit = VectorFit {
        model: layout.model,
        motor: layout.motor.then(|| layout.d(theta).map(|v| v * scale)),
        std_motor,
        ..parts_fit
    };
    if let (Some(u), Some(sd)) = (inputs, fit.std_motor) {
        let range =
            u.iter().copied().fold(f64::NEG_INFINITY, f64::max) - u.iter().copied().fold(f64::INFINITY, f64::min);
        let weak: Vec<String> = (0..3)
            .filter(|&i| !super::within(sd[i] * range, scale))
            .map(|i| {
                format!(
                    "d{} (std {:.4e} times the input's range {range:.4} > the field {scale:.4e})",
                    ["x", "y", "z"][i],
                    sd[i]
                )
            })
            .collect();
        if !weak.is_empty() {
            fit.identifiable = false;
            fit.verdict = if fit.verdict.starts_with("not determined: ") {
                format!("{}, {}", fit.verdict, weak.join(", "))
            } else {
                format!("not determined: {}", weak.join(", "))
            };
        }
    }
    fit
}

/// The lack-of-fit test of a reduced track fit against the full one of the same readings:
/// `F = ((Q_r - Q_f) / (p_f - p_r)) / (Q_f / (3 m - p_f))` on `(p_f - p_r, 3 m - p_f)` degrees of
/// freedom, `Q` the residual sums of squares; `(F, degrees of freedom, p-value)`. The log rejects
/// the reduced model when the p-value is below [`crate::log_fit::LACK_OF_FIT_LEVEL`] (a compass
/// whose scale factors or soft iron the reduced model holds at one would be calibrated wrong).
/// Residuals correlated in time make it reject more often than its level: a rejection on a real
/// log says the richer model fits better, not by how much it matters.
pub fn lack_of_fit(reduced: &VectorFit, full: &VectorFit) -> Option<(f64, (usize, usize), f64)> {
    use statrs::distribution::{ContinuousCDF, FisherSnedecor};
    let m3 = reduced.dof + unknowns(reduced);
    let (p_r, p_f) = (unknowns(reduced), unknowns(full));
    if p_f <= p_r || m3 <= p_f {
        return None;
    }
    let q = |f: &VectorFit| f.rms_residual * f.rms_residual * m3 as f64;
    let (q_r, q_f) = (q(reduced), q(full));
    let dof = (p_f - p_r, m3 - p_f);
    let f = ((q_r - q_f).max(0.0) / dof.0 as f64) / (q_f / dof.1 as f64);
    let p = FisherSnedecor::new(dof.0 as f64, dof.1 as f64).ok()?.sf(f);
    Some((f, dof, p))
}

/// The unknowns of a track fit.
fn unknowns(fit: &VectorFit) -> usize {
    let layout = Layout {
        model: fit.model,
        motor: fit.motor.is_some(),
    };
    layout.p()
}

/// A manoeuvre a pilot can fly, and what it would make of the calibration of a flight
/// ([`next_manoeuvres`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Manoeuvre {
    /// In a pilot's words: `a full turn at 20 degrees of bank`, `a straight leg heading 120`.
    pub words: String,
    /// Readings it adds (at the log's rate: a turn of 120 readings, a leg of 60).
    pub readings: usize,
    /// Whether the log with it determines the calibration.
    pub identifiable: bool,
    /// The verdict of the log with it, in words.
    pub verdict: String,
    /// The gain in `ln det` of the information (\[P1\]'s D-criterion, eq. (12)); infinite where
    /// the log's own information is singular and the manoeuvre makes it regular, `NaN` where it
    /// stays singular.
    pub ln_det_gain: f64,
    /// `ln det` of the information with it (`-inf` where singular): what ranks manoeuvres of
    /// equal gain, as those that make a singular information regular are.
    pub ln_det_with: f64,
    /// The bias's standard errors with it (white noise at the noise given, the readings' units);
    /// `None` where its information is singular.
    pub bias_std: Option<Vec3>,
}

/// Bank angles of the turns offered, degrees.
const TURN_BANKS_DEG: [f64; 3] = [10.0, 20.0, 30.0];
/// Readings of a turn (one every 3 degrees of heading) and of a straight leg.
const TURN_READINGS: usize = 120;
const LEG_READINGS: usize = 60;

/// `ln det` of a symmetric positive definite matrix by its Cholesky factor; `-inf` where it is
/// not positive definite.
fn ln_det(a: &[Vec<f64>]) -> f64 {
    let p = a.len();
    let m = faer::Mat::from_fn(p, p, |i, j| a[i][j]);
    match m.llt(faer::Side::Lower) {
        Ok(l) => (0..p).map(|i| 2.0 * l.L()[(i, i)].ln()).sum(),
        Err(_) => f64::NEG_INFINITY,
    }
}

/// The manoeuvres that would determine the track fit of a flight (attitudes body to z up, the
/// field of each reading, the motor's input where fitted) under `model`, at the noise `noise`
/// (the readings' units) and about the sensor `k` (the fit's `K`: the delta method of the
/// derived standard errors needs one): of full turns at 10, 20 and 30 degrees of bank and
/// straight legs every 30 degrees of heading, each added alone to the log's information (which
/// does not depend on the estimate: the model is linear), the `best` of largest gain in `ln det`
/// of the information (the D-optimal increment), with the verdict and the bias's standard errors
/// they would give. The log's own bias standard errors are those of the first with no gain:
/// compute them from [`fit_track`].
///
/// # Errors
/// As [`fit_track`]'s checks of its inputs.
#[allow(clippy::too_many_arguments)]
pub fn next_manoeuvres(
    readings: &[Vec3],
    attitudes: &[Mat3],
    fields: &[Vec3],
    inputs: Option<&[f64]>,
    model: VectorModel,
    noise: f64,
    k: Mat3,
    best: usize,
) -> Result<Vec<Manoeuvre>, VectorError> {
    let layout = Layout {
        model,
        motor: inputs.is_some(),
    };
    let n = fields.len().max(1) as f64;
    let mean: Vec3 = std::array::from_fn(|i| fields.iter().map(|f| f[i]).sum::<f64>() / n);
    let (scale, _) = validate(readings, attitudes, super::ReferenceField::Given(mean))?;
    let unit_fields: Vec<Vec3> = fields.iter().map(|f| f.map(|v| v / scale)).collect();
    let f_unit = mean.map(|v| v / scale);
    let u_typical = inputs.map_or(0.0, |u| {
        let mut v = u.to_vec();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    });
    let p = layout.p();
    let info_of = |cs: &mut dyn Iterator<Item = (Mat3, Vec3, f64)>| {
        let mut jtj = vec![vec![0.0; p]; p];
        for (c, f, u) in cs {
            let rows = layout.rows(mat_t_vec(&c, f), u);
            for row in &rows {
                for a in 0..p {
                    for b in 0..p {
                        jtj[a][b] += row[a] * row[b];
                    }
                }
            }
        }
        jtj
    };
    let base = info_of(
        &mut attitudes
            .iter()
            .zip(&unit_fields)
            .enumerate()
            .map(|(t, (c, f))| (*c, *f, inputs.map_or(0.0, |u| u[t]))),
    );
    // Singular as the fit finds it (its inverse's test of the pivots), not by `ln det`, which
    // rounding leaves finite.
    let base_regular = NormalEquations {
        jtj: base.clone(),
        jtr: vec![0.0; p],
        names: layout.names(),
    }
    .inverse()
    .is_ok();
    let base_ln_det = ln_det(&base);
    let sigma = noise / scale;
    let unit = Unit {
        k,
        o: [0.0; 3],
        f: f_unit,
    };
    let up = |c: Mat3| crate::aviation::z_up_of_ned(&c);
    let mut candidates: Vec<(String, Vec<Mat3>)> = TURN_BANKS_DEG
        .iter()
        .map(|&bank| {
            let turn = (0..TURN_READINGS)
                .map(|i| {
                    up(crate::aviation::dcm_of_euler(
                        bank.to_radians(),
                        0.0,
                        (3.0 * i as f64).to_radians(),
                    ))
                })
                .collect();
            (format!("a full turn at {bank:.0} degrees of bank"), turn)
        })
        .collect();
    candidates.extend((0..12).map(|h| {
        let heading = 30.0 * f64::from(h);
        let leg = (0..LEG_READINGS)
            .map(|_| up(crate::aviation::dcm_of_euler(0.0, 0.0, heading.to_radians())))
            .collect();
        (format!("a straight leg heading {heading:.0}"), leg)
    }));
    let mut out: Vec<Manoeuvre> = candidates
        .into_iter()
        .map(|(words, cs)| {
            let added = info_of(&mut cs.iter().map(|c| (*c, f_unit, u_typical)));
            let total: Vec<Vec<f64>> = (0..p)
                .map(|a| (0..p).map(|b| base[a][b] + added[a][b]).collect())
                .collect();
            let ln_det_with = ln_det(&total);
            let ne = NormalEquations {
                jtj: total,
                jtr: vec![0.0; p],
                names: layout.names(),
            };
            let mut bias_std = None;
            let inverse = ne.inverse();
            let ln_det_gain = match (base_regular, inverse.is_ok()) {
                (true, _) => ln_det_with - base_ln_det,
                (false, true) => f64::INFINITY,
                (false, false) => f64::NAN,
            };
            let (identifiable, verdict) = match inverse {
                Ok(inv) => {
                    let mut full = vec![vec![0.0; 12]; 12];
                    for a in 0..p {
                        for b in 0..p {
                            if let (Some(x), Some(y)) = (layout.full_index(a), layout.full_index(b)) {
                                full[x][y] = inv[a][b] * sigma * sigma;
                            }
                        }
                    }
                    let std = std_errors(&unit, &full, false, scale);
                    bias_std = Some(std::array::from_fn(|i| full[9 + i][9 + i].max(0.0).sqrt() * scale));
                    let model_k = crate::sensor::ErrorModel::from_k(
                        &crate::small::upper_triangular_inverse(
                            &super::decompose(&k).map_or([[f64::NAN; 3]; 3], |d| d.0),
                        )
                        .unwrap_or([[f64::NAN; 3]; 3]),
                        [0.0; 3],
                    );
                    super::judge(std.as_ref(), &model_k, scale, false, readings.len() + cs.len())
                }
                Err(e) => (false, e.to_string()),
            };
            Manoeuvre {
                words,
                readings: cs.len(),
                identifiable,
                verdict,
                ln_det_gain,
                ln_det_with,
                bias_std,
            }
        })
        .collect();
    // Largest gain first; among equal gains (infinite, from a singular log), largest information.
    // A gain of NaN (still singular) sorts last.
    let key = |m: &Manoeuvre| {
        if m.ln_det_gain.is_nan() {
            f64::NEG_INFINITY
        } else {
            m.ln_det_gain
        }
    };
    out.sort_by(|a, b| key(b).total_cmp(&key(a)).then(b.ln_det_with.total_cmp(&a.ln_det_with)));
    out.truncate(best);
    Ok(out)
}

/// Width of the heading sectors of [`headings_never_flown`], degrees.
pub const SECTOR_DEG: f64 = 30.0;

/// The headings a flight never flew: runs of [`SECTOR_DEG`]-wide sectors (from north,
/// clockwise) each holding no reading or fewer than `share` of them, as `[from, to)` in degrees
/// (`to` may pass 360 where a run wraps through north). `attitudes` body (forward, right, down)
/// to z up (east, north, up), as [`fit_track`] takes them.
pub fn headings_never_flown(attitudes: &[Mat3], share: f64) -> Vec<[f64; 2]> {
    let sectors = (360.0 / SECTOR_DEG).round() as usize;
    let mut count = vec![0usize; sectors];
    for c in attitudes {
        // The body's forward axis in east, north, up.
        let heading = c[0][0].atan2(c[1][0]).to_degrees().rem_euclid(360.0);
        count[((heading / SECTOR_DEG) as usize).min(sectors - 1)] += 1;
    }
    let empty: Vec<bool> = count
        .iter()
        .map(|&k| k == 0 || (k as f64) < share * attitudes.len() as f64)
        .collect();
    if empty.iter().all(|&e| e) {
        return vec![[0.0, 360.0]];
    }
    // Runs start after a flown sector, so a run through north is not cut in two.
    let first_flown = empty.iter().position(|&e| !e).unwrap_or(0);
    let mut runs = Vec::new();
    let mut start: Option<usize> = None;
    for step in 1..=sectors {
        let i = (first_flown + step) % sectors;
        let at = first_flown + step;
        match (empty[i], start) {
            (true, None) => start = Some(at),
            (false, Some(a)) => {
                runs.push([a, at]);
                start = None;
            }
            _ => {}
        }
    }
    runs.into_iter()
        .map(|[a, b]| {
            let from = (a % sectors) as f64 * SECTOR_DEG;
            [from, from + (b - a) as f64 * SECTOR_DEG]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use rand_distr::{Distribution, StandardNormal};

    use super::*;
    use crate::aviation::{dcm_of_euler, z_up_of_ned};
    use crate::flight::{FlightPlan, fly};
    use crate::rng::stream_rng;
    use crate::wmm;

    /// The noise of the simulated compass, nT per component.
    const SIGMA_NT: f64 = 100.0;

    /// A flight of `seed` read by a compass `K`, `O`, `d` (body frame, nT and nT/A): the
    /// readings, attitudes (body to ENU), the WMM field (ENU, nT) along the track and at its
    /// first fix only, and the currents.
    struct Flown {
        readings: Vec<Vec3>,
        attitudes: Vec<Mat3>,
        along: Vec<Vec3>,
        origin: Vec<Vec3>,
        currents: Vec<f64>,
    }

    fn flown(seed: u64, k: &Mat3, o: Vec3, d: Vec3) -> Flown {
        let plan = FlightPlan::default();
        let f = fly(&plan, seed);
        let mut rng = stream_rng(seed, 0xC0);
        let field = |s: &crate::flight::FlightSample| {
            let site = wmm::Site {
                lat_deg: s.lat_deg,
                lon_deg: s.lon_deg,
                alt_m: s.alt_m,
                year: 2026.5,
            };
            let ned = wmm::field_ned(wmm::Model::Wmm2025, &site).unwrap();
            [ned[1], ned[0], -ned[2]]
        };
        let first = field(&f[0]);
        let mut out = Flown {
            readings: Vec::new(),
            attitudes: Vec::new(),
            along: Vec::new(),
            origin: Vec::new(),
            currents: Vec::new(),
        };
        // The model at every tenth sample (1 s, 20 m apart), linear between: within 0.1 nT.
        let at_second: Vec<Vec3> = f.iter().step_by(10).map(field).collect();
        let along = |i: usize| {
            let (j, w) = (i / 10, (i % 10) as f64 / 10.0);
            let (a, b) = (at_second[j], at_second[(j + 1).min(at_second.len() - 1)]);
            let b = if (j + 1) * 10 < f.len() { b } else { a };
            std::array::from_fn::<f64, 3, _>(|k| a[k] + w * (b[k] - a[k]))
        };
        for (i, s) in f.iter().enumerate() {
            let c = z_up_of_ned(&dcm_of_euler(
                s.roll_deg.to_radians(),
                s.pitch_deg.to_radians(),
                s.heading_deg.to_radians(),
            ));
            let fe = along(i);
            let b = mat_vec(k, mat_t_vec(&c, fe));
            let m: Vec3 = std::array::from_fn(|i| {
                b[i] + o[i]
                    + d[i] * s.current_a
                    + SIGMA_NT * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng)
            });
            out.readings.push(m);
            out.attitudes.push(c);
            out.along.push(fe);
            out.origin.push(first);
            out.currents.push(s.current_a);
        }
        out
    }

    const K: Mat3 = [[1.04, 0.0, 0.0], [0.0, 0.97, 0.0], [0.0, 0.0, 1.02]];
    const O: Vec3 = [250.0, -120.0, 400.0];
    const D: Vec3 = [6.0, -4.0, 15.0];

    #[test]
    fn noise_free_flights_give_the_sensor_back_under_each_model() {
        for (model, k) in [
            (
                VectorModel::Offsets,
                [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            ),
            (VectorModel::Diagonal, K),
            (
                VectorModel::Full,
                [[1.04, 0.02, -0.01], [-0.015, 0.97, 0.03], [0.01, -0.02, 1.02]],
            ),
        ] {
            let f = flown(3, &k, O, D);
            let exact: Vec<Vec3> = f
                .readings
                .iter()
                .zip(&f.attitudes)
                .zip(&f.along)
                .zip(&f.currents)
                .map(|(((_, c), fe), u)| {
                    let b = mat_vec(&k, mat_t_vec(c, *fe));
                    std::array::from_fn(|i| b[i] + O[i] + D[i] * u)
                })
                .collect();
            let fit = fit_track(
                &exact,
                &f.attitudes,
                &f.along,
                Some(&f.currents),
                model,
                crate::log_fit::Order::Time,
            )
            .unwrap();
            // Rounding of readings of 50,000 nT, amplified by the condition of the level
            // flight's information (the vertical column is weakly determined).
            for i in 0..3 {
                assert!((fit.bias[i] - O[i]).abs() < 1e-6, "{model:?} {:?}", fit.bias);
                assert!((fit.motor.unwrap()[i] - D[i]).abs() < 1e-8, "{model:?} {:?}", fit.motor);
                for j in 0..3 {
                    assert!((fit.k[i][j] - k[i][j]).abs() < 1e-10, "{model:?} {:?}", fit.k);
                }
            }
            assert_eq!(fit.model, model);
        }
    }

    /// `(|z| max, share of 95 % intervals holding the truth, intervals)` of the bias, motor and
    /// (diagonal model) scale factors of fits of `seeds` flights under `model`, and the rms
    /// error of the bias over them with the field along the track and at its first fix.
    fn study(model: VectorModel, seeds: u64) -> (f64, f64, usize, f64, f64, usize) {
        let k = if model == VectorModel::Offsets {
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        } else {
            K
        };
        use rayon::prelude::*;
        // Per flight: (worst |z|, intervals holding the truth, intervals, squared bias errors
        // along the track and at one origin, rejected), flights in parallel, summed in order.
        let per_flight: Vec<(f64, usize, usize, f64, f64, usize)> = (0..seeds)
            .into_par_iter()
            .map(|seed| {
                let (mut worst, mut held, mut n) = (0.0_f64, 0, 0);
                let f = flown(seed, &k, O, D);
                let fit_with = |fields: &[Vec3], model| {
                    fit_track(
                        &f.readings,
                        &f.attitudes,
                        fields,
                        Some(&f.currents),
                        model,
                        crate::log_fit::Order::Time,
                    )
                    .unwrap()
                };
                let fit = fit_with(&f.along, model);
                assert!(fit.identifiable, "{model:?} {seed}: {}", fit.verdict);
                let (se, q) = (fit.std_error.unwrap(), fit.quantile95.unwrap());
                let (motor, std_motor) = (fit.motor.unwrap(), fit.std_motor.unwrap());
                let mut pairs: Vec<(f64, f64)> = (0..3)
                    .flat_map(|i| [(fit.bias[i] - O[i], se.bias[i]), (motor[i] - D[i], std_motor[i])])
                    .collect();
                if model == VectorModel::Diagonal {
                    pairs.extend((0..3).map(|i| (fit.k[i][i] - K[i][i], se.k[i][i])));
                }
                for (e, s) in pairs {
                    worst = worst.max((e / s).abs());
                    held += usize::from(e.abs() <= q * s);
                    n += 1;
                }
                let rejected = if model == VectorModel::Full {
                    0
                } else {
                    let full = fit_with(&f.along, VectorModel::Full);
                    usize::from(lack_of_fit(&fit, &full).unwrap().2 < crate::log_fit::LACK_OF_FIT_LEVEL)
                };
                let one = fit_with(&f.origin, model);
                (
                    worst,
                    held,
                    n,
                    (0..3).map(|i| (fit.bias[i] - O[i]).powi(2)).sum::<f64>(),
                    (0..3).map(|i| (one.bias[i] - O[i]).powi(2)).sum::<f64>(),
                    rejected,
                )
            })
            .collect();
        let (mut worst, mut held, mut n) = (0.0_f64, 0, 0);
        let (mut se_track, mut se_origin) = (0.0, 0.0);
        let mut rejected = 0;
        for (w, h, c, t, o, r) in per_flight {
            worst = worst.max(w);
            held += h;
            n += c;
            se_track += t;
            se_origin += o;
            rejected += r;
        }
        let rms = |x: f64| (x / (3 * seeds) as f64).sqrt();
        (
            worst,
            held as f64 / n as f64,
            n,
            rms(se_track),
            rms(se_origin),
            rejected,
        )
    }

    #[test]
    fn headings_never_flown_are_runs_of_empty_sectors_through_north() {
        let at = |h: f64| z_up_of_ned(&dcm_of_euler(0.0, 0.0, h.to_radians()));
        // Flown: 95 to 115 and 305 to 325 degrees; never: 120-300 and 330-90 (through north).
        let flown: Vec<Mat3> = (0..=20)
            .flat_map(|d| [at(95.0 + f64::from(d)), at(305.0 + f64::from(d))])
            .collect();
        assert_eq!(headings_never_flown(&flown, 0.01), vec![[120.0, 300.0], [330.0, 450.0]]);
        assert_eq!(headings_never_flown(&[], 0.01), vec![[0.0, 360.0]]);
        let every: Vec<Mat3> = (0..360).map(|d| at(f64::from(d))).collect();
        assert!(headings_never_flown(&every, 0.01).is_empty());
    }

    #[test]
    fn a_log_that_determines_nothing_is_told_the_manoeuvres_that_would() {
        // A straight, level leg without turbulence (a ship at anchor, a vehicle on a trailer):
        // the diagonal model's information is singular (scale and bias confounded on every
        // axis). Each full turn makes it regular; the straight legs do not.
        let c = z_up_of_ned(&dcm_of_euler(0.0, 0.0, 0.3));
        let f = [3_000.0, 15_000.0, -48_000.0];
        let readings: Vec<Vec3> = (0..500).map(|_| mat_t_vec(&c, f)).collect();
        let next = next_manoeuvres(
            &readings,
            &vec![c; 500],
            &vec![f; 500],
            None,
            VectorModel::Diagonal,
            SIGMA_NT,
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            15,
        )
        .unwrap();
        let words: Vec<&str> = next.iter().map(|m| m.words.as_str()).collect();
        assert_eq!(
            &words[..3],
            [
                "a full turn at 30 degrees of bank",
                "a full turn at 20 degrees of bank",
                "a full turn at 10 degrees of bank"
            ]
        );
        assert!(
            next[..3]
                .iter()
                .all(|m| m.identifiable && m.ln_det_gain == f64::INFINITY)
        );
        assert!(next[3..].iter().all(|m| !m.identifiable && m.ln_det_gain.is_nan()));
    }

    #[test]
    fn a_leg_alone_hardly_determines_the_full_model_and_a_turn_would() {
        // The flight's first 100 s: one straight leg, heading 340, turbulence only. Offsets are
        // determined to a few nT (the field and the attitude are known); the full matrix hardly:
        // the body's field barely turns, and the bias's standard errors are thousands of nT. The
        // manoeuvre of largest gain in information is named, from the information alone (the
        // model is linear: no estimate enters it).
        let f = flown(5, &K, O, D);
        let cut = 1000;
        let (m, c, fe, u) = (
            &f.readings[..cut],
            &f.attitudes[..cut],
            &f.along[..cut],
            &f.currents[..cut],
        );
        let offsets = fit_track(m, c, fe, None, VectorModel::Offsets, crate::log_fit::Order::Time).unwrap();
        assert!(offsets.identifiable, "{}", offsets.verdict);
        let full = fit_track(m, c, fe, Some(u), VectorModel::Full, crate::log_fit::Order::Time);
        let next = next_manoeuvres(m, c, fe, Some(u), VectorModel::Full, SIGMA_NT, K, 3).unwrap();
        // Measured: the leg's bias standard errors are 4,434 nT; a full turn at 30 degrees of
        // bank would bring them to 237 nT (20 degrees: 402; 10 degrees: 477).
        let before = full.as_ref().map_or(f64::INFINITY, |f| {
            f.std_error
                .map_or(f64::INFINITY, |s| s.bias.iter().copied().fold(0.0, f64::max))
        });
        let after = next[0].bias_std.unwrap().iter().copied().fold(0.0, f64::max);
        println!("{before} -> {next:#?}");
        assert_eq!(next[0].words, "a full turn at 30 degrees of bank");
        assert!(next[0].identifiable && after < before / 10.0, "{before} {after}");
        assert!(next.windows(2).all(|w| w[0].ln_det_gain >= w[1].ln_det_gain));
    }

    #[test]
    fn ordinary_flights_give_the_sensor_within_four_standard_errors_and_one_origin_does_not() {
        // 50 flights of 20 km from 60 N (10,000 readings, tilts of 10 degrees and turbulence) at
        // 100 nT of noise, a compass with offsets, scale factors and motor interference. Every
        // estimate within 4 of its standard errors; the 95 % intervals (the batches' Student t)
        // hold the truth in at least 0.91 of the cases (three binomial standard errors below
        // 0.95 over 300 intervals). Measured (printed): offsets worst |z| 2.92, coverage 0.983
        // of 300; diagonal 3.00, 0.982 of 450; full 2.86, 0.990 of 300 (the standard errors are
        // the larger of the long-run and the white ones, with 13 degrees of freedom: cautious);
        // the bias's rms error with the field at the first fix instead of along the track:
        // offsets 28.9 against 4.0 nT, diagonal 76.3 against 22.7, full 89.2 against 37.7.
        for (model, ratio) in [
            (VectorModel::Offsets, 3.0),
            (VectorModel::Diagonal, 2.0),
            (VectorModel::Full, 1.5),
        ] {
            let (worst, coverage, n, track, origin, rejected) = study(model, 50);
            println!(
                "{model:?}: worst |z| {worst:.2}, 95 % coverage {coverage:.3} of {n}; bias rms error {track:.1} nT along the track, {origin:.1} at one origin; rejected against the full matrix {rejected} of 50"
            );
            // The lack-of-fit test at its level 0.001 of a model that is the truth: 50 flights
            // reject it 0.05 times on average; 2 or more has a chance of about 1e-3.
            assert!(rejected <= 1, "{model:?} {rejected}");
            assert!(worst < 4.0, "{model:?} {worst}");
            assert!(coverage >= 0.91, "{model:?} {coverage}");
            assert!(origin > ratio * track, "{model:?} {origin} {track}");
        }
    }
}
