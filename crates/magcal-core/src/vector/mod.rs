//! Vector calibration against reference attitudes (docs/conventions.md "Vector calibration"):
//! with an attitude per reading the field's direction in the body frame is known, so the whole
//! `K` (3x3) and the bias `O` are estimable, the misalignment between the sensor and the body
//! included, which a scalar calibration (\[P1\] IV.C) cannot see.
//!
//! # Model
//! Reading `t` is `m_t = K C_t^T F + O + n_t`: `C_t` the attitude, body to a reference frame
//! whose z axis points up ([`crate::aviation::z_up_of_ned`] of a logged NED attitude), `F` the
//! field in that frame and `n_t ~ N(0, sigma^2 I3)`. \[P1\] eq. (5) is the case of an upper
//! triangular `K` and a known body field `C_t^T F`.
//!
//! `F` is either **given** ([`ReferenceField::Given`], the World Magnetic Model where the
//! reference frame is geographic) or **fitted** ([`ReferenceField::Fitted`], a motion-capture
//! room whose north is unknown). A fitted `F` shares its scale with `K` (`K F = (K / s) (s F)`)
//! and its sign (`K F = (-K) (-F)`): `|F|` is fixed to the magnitude given, and the sign to the
//! one that makes `det K > 0`.
//!
//! # Decomposition
//! `K^-1 = A P`, a QR decomposition: `P` upper triangular with a positive diagonal (\[P1\]
//! eq. (6), so `psi`, `S` follow from `P^-1` as in [`ErrorModel::from_k`]) and `A` a rotation,
//! the **alignment**: the body-frame field of a reading is `A P (m - O)`. `A` is the rotation
//! between \[P1\]'s frame of the sensor (its z axis, then its y-z plane) and the body frame.
//! A sensor mounted along the body's axes in another orientation (its axes forward, left, up
//! in a body frame forward, right, down) turns `A` by a whole step `S`, one of the 24
//! rotations that map the axes onto each other; the **misalignment** is what remains,
//! `M = A S^T` with `S` the step nearest `A` ([`VectorFit::misalignment_deg`]).
//!
//! # Estimation
//! Given `F`, `K` and `O` enter linearly: 12 unknowns, solved by least squares. Fitted, `F`
//! adds two (its direction): Gauss-Newton on the 14, with `F` moved in the plane tangent to its
//! sphere and put back on it after each step, halving a step that does not lower the sum of
//! squares. The start comes from the linear model `m_t = sum_kj W_kj (C_t)_kj + O` (30
//! unknowns, `W_i = F K_i^T` for the sensor axis `i`), whose 9 x 3 matrix `(K_ij F_k)` is
//! rank one: its leading singular pair gives `K` and `F`.
//!
//! All is computed in units of the field magnitude (`m / |F|`), where the unknowns are of
//! order one; the normal equations are solved in correlation form (unit diagonal) by faer's
//! eigendecomposition, whose smallest eigenvalue says whether the information is singular.
//!
//! # Statistics
//! Noise per component from the residuals, `sigma^2 = RSS / (3 m - p)` (`p` = 12 or 14);
//! covariance `sigma^2 (J^T J)^-1` of the Gauss-Newton Jacobian `J` at the fit; the standard
//! errors of `psi`, `S` and the alignment's rotation vector by the delta method (central
//! differences of the decomposition). The fit is **identifiable** when the noise is estimable
//! (`3 m > p`) and every standard error is within its physical scale ([`PhysicalScales`]: 10
//! degrees for `psi`, the misalignment and the direction of a fitted `F`; half the scale
//! factor; the field magnitude for `O`). Attitudes that leave the information singular (all the
//! same, or turning about one axis only) are refused with the combination they leave open.
#![allow(non_snake_case)]
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

mod track;

pub use track::{Manoeuvre, SECTOR_DEG, VectorModel, fit_track, headings_never_flown, lack_of_fit, next_manoeuvres};

use crate::identifiability::PhysicalScales;
use crate::reference::det;
use crate::sensor::ErrorModel;
use crate::small::{Mat3, Vec3, dot, mat_mul, mat_t_vec, mat_vec, norm, sub, transpose, upper_triangular_inverse};

/// The field in the reference frame.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum ReferenceField {
    /// Known (the readings' units, reference frame z up): the WMM's field where the reference
    /// frame is geographic.
    Given(Vec3),
    /// Unknown, fitted with `|F|` fixed to `magnitude` (the readings' units): the field
    /// magnitude a scalar calibration would use.
    Fitted {
        /// `|F|`, the readings' units.
        magnitude: f64,
    },
}

/// Why a vector calibration cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum VectorError {
    /// The readings and attitudes differ in number.
    #[error("{readings} readings and {attitudes} attitudes: one attitude per reading is needed")]
    LengthMismatch {
        /// Readings given.
        readings: usize,
        /// Attitudes given.
        attitudes: usize,
    },
    /// Too few readings for the unknowns and a noise estimate.
    #[error("{got} readings with an attitude, at least {needed} are needed ({unknowns} unknowns, 3 components each)")]
    TooFewReadings {
        /// Readings given.
        got: usize,
        /// Readings needed.
        needed: usize,
        /// Unknowns of the fit.
        unknowns: usize,
    },
    /// A reading is NaN or infinite.
    #[error("reading {index}: not finite ({value:?})")]
    NonFiniteReading {
        /// Index of the reading (0-based).
        index: usize,
        /// The reading.
        value: Vec3,
    },
    /// An attitude is not a rotation.
    #[error("reading {index}: the attitude is not a rotation (|C^T C - I| = {deviation:.3e}, det {determinant:.6})")]
    NotARotation {
        /// Index of the reading (0-based).
        index: usize,
        /// Largest entry of `|C^T C - I|`.
        deviation: f64,
        /// `det C`.
        determinant: f64,
    },
    /// The given field or magnitude is zero or not finite.
    #[error("the reference field {value:?} must be finite and non-zero")]
    InvalidField {
        /// The field given (a fitted field's magnitude as its first component).
        value: Vec3,
    },
    /// The attitudes leave the information singular.
    #[error("the attitudes do not determine the calibration (singular information): {weakest}")]
    NotDetermined {
        /// The combination of unknowns they leave open, in words.
        weakest: String,
    },
    /// The fitted `K` has a negative determinant: the readings' axes form a left-handed frame.
    #[error(
        "det K = {determinant:.4} < 0: the readings' axes form a left-handed frame against the body's (a swapped or negated column?)"
    )]
    LeftHanded {
        /// `det K`.
        determinant: f64,
    },
    /// Gauss-Newton did not settle.
    #[error("the fit did not settle within {iterations} iterations")]
    NotConverged {
        /// Iterations made.
        iterations: usize,
    },
}

/// Standard errors of a [`VectorFit`] (the readings' units for `bias` and `field`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VectorStdError {
    /// Of each entry of `K`.
    pub k: Mat3,
    /// Of `O`.
    pub bias: Vec3,
    /// Of `F` (zero where `F` is given).
    pub field: Vec3,
    /// Of the direction of `F`, degrees (zero where `F` is given).
    pub field_direction_deg: f64,
    /// Of `psi`, degrees.
    pub psi_deg: Vec3,
    /// Of `S`.
    pub scale: Vec3,
    /// Of the components of the misalignment's rotation vector (axis times angle, body frame;
    /// [`VectorFit::misalignment_deg`]), degrees.
    pub rotation_vector_deg: Vec3,
    /// Of the misalignment angle, degrees (the delta method: meaningful where the angle is
    /// several times it).
    pub misalignment_deg: f64,
}

/// A vector calibration (see the module documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct VectorFit {
    /// `K`: `m = K C^T F + O`.
    pub k: Mat3,
    /// `O`, the readings' units.
    pub bias: Vec3,
    /// `F` in the reference frame, the readings' units (given or fitted).
    pub field: Vec3,
    /// Whether `F` was fitted.
    pub field_fitted: bool,
    /// \[P1\]'s upper-triangular `P` of the same sensor (`psi`, `S` as \[P1\] eq. (5)-(7)).
    pub p: Mat3,
    /// The rotation `A` with body `= A P (m - O)`, i.e. `K^-1 = A P`.
    pub alignment: Mat3,
    /// The noise per component from the residuals, the readings' units; `None` without residual
    /// degrees of freedom.
    pub noise: Option<f64>,
    /// Residual degrees of freedom, `3 m - p`.
    pub dof: usize,
    /// The 95 % interval of the noise (chi-square of `dof` degrees of freedom).
    pub noise_interval95: Option<(f64, f64)>,
    /// For readings in time order, the batch length of the standard errors' long-run
    /// covariance ([`fit_vector_in`]).
    pub serial: Option<crate::log_fit::Serial>,
    /// Student's `t` of `dof` degrees of freedom at 0.975: the multiple of a standard error
    /// that makes a 95 % confidence interval.
    pub quantile95: Option<f64>,
    /// Standard errors; `None` where the noise is unknown.
    pub std_error: Option<VectorStdError>,
    /// Whether the readings and attitudes determine the fit (see the module documentation).
    pub identifiable: bool,
    /// In words: what is determined, or what is not.
    pub verdict: String,
    /// RMS of the residual components `m_t - K C_t^T F - O`, the readings' units.
    pub rms_residual: f64,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// The model of `K` fitted ([`VectorModel::Full`] but for [`fit_track`]).
    pub model: VectorModel,
    /// The motor interference `d` per unit of input (`m = K C^T F + O + d u`), the readings'
    /// units, where it was fitted ([`fit_track`] with inputs), with its standard errors.
    pub motor: Option<Vec3>,
    /// The standard errors of [`Self::motor`].
    pub std_motor: Option<Vec3>,
}

impl VectorFit {
    /// The body-frame field of a raw reading: `A P (raw - O)`.
    pub fn apply(&self, raw: Vec3) -> Vec3 {
        mat_vec(&self.alignment, mat_vec(&self.p, sub(raw, self.bias)))
    }

    /// \[P1\]'s `(psi, S, O)` of `P` (`K_[P1] = P^-1`).
    pub fn error_model(&self) -> ErrorModel {
        let k = upper_triangular_inverse(&self.p).unwrap_or([[f64::NAN; 3]; 3]);
        ErrorModel::from_k(&k, self.bias)
    }

    /// The angle of the alignment `A`, degrees in [0, 180].
    pub fn alignment_angle_deg(&self) -> f64 {
        norm(rotation_vector(&self.alignment)).to_degrees()
    }

    /// The axis of the alignment `A`, a unit vector in the body frame (`(0, 0, 1)` for none).
    pub fn alignment_axis(&self) -> Vec3 {
        unit_or_z(rotation_vector(&self.alignment))
    }

    /// The whole step `S` nearest the alignment: of the 24 rotations that map the coordinate
    /// axes onto each other (a sensor mounted along the body's axes, in any orientation: what an
    /// autopilot's board orientation parameter holds), the one closest to `A`.
    pub fn whole_step(&self) -> Mat3 {
        nearest_whole_step(&self.alignment)
    }

    /// The misalignment: the angle of `M = A S^T` ([`Self::whole_step`]), the turn of the
    /// sensor beyond the whole step, degrees in [0, 180]. For a sensor mounted along the body's
    /// axes as \[P1\]'s frame lies (`S = I`), the angle of `A`.
    pub fn misalignment_deg(&self) -> f64 {
        norm(misalignment_vector(&self.alignment, &self.whole_step())).to_degrees()
    }

    /// The axis of the misalignment `M`, a unit vector in the body frame (`(0, 0, 1)` for
    /// none).
    pub fn misalignment_axis(&self) -> Vec3 {
        unit_or_z(misalignment_vector(&self.alignment, &self.whole_step()))
    }
}

/// `v / |v|`, or `(0, 0, 1)` for a zero `v`.
fn unit_or_z(v: Vec3) -> Vec3 {
    let n = norm(v);
    if n > 0.0 { v.map(|x| x / n) } else { [0.0, 0.0, 1.0] }
}

/// Of the 24 rotations that map the coordinate axes onto each other, the nearest to `a`
/// (largest `trace(S^T A)`).
fn nearest_whole_step(a: &Mat3) -> Mat3 {
    let trace = |s: &Mat3| {
        (0..3)
            .map(|i| (0..3).map(|k| s[k][i] * a[k][i]).sum::<f64>())
            .sum::<f64>()
    };
    crate::reference::axis_rotations()
        .max_by(|x, y| trace(x).total_cmp(&trace(y)))
        .unwrap_or([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
}

/// The rotation vector (radians, body frame) of `A S^T`.
fn misalignment_vector(a: &Mat3, step: &Mat3) -> Vec3 {
    rotation_vector(&mat_mul(a, &transpose(step)))
}

/// The largest entry of `|C^T C - I|` an attitude may have (as [`crate::reference`]).
pub const ROTATION_TOLERANCE: f64 = crate::reference::ROTATION_TOLERANCE;

/// Below this eigenvalue of the information in correlation form (unit diagonal, largest
/// eigenvalue at most the number of unknowns), the information is singular to working
/// precision: rounding leaves about `1e-16` times the sum of squares in a direction the
/// attitudes do not move at all, and a direction they move by a thousandth of the field leaves
/// `1e-6`.
const SINGULAR: f64 = 1e-11;

/// Gauss-Newton iterations at most.
const MAX_ITERATIONS: usize = 200;

/// Calibrates `readings` (any units) against `attitudes` (body to a z-up reference frame, one
/// per reading) with the field `field` (see the module documentation).
///
/// # Errors
/// Slices of different lengths, too few readings (`3 m` must exceed the unknowns), a reading
/// that is not finite, an attitude that is not a rotation, a given field that is zero or not
/// finite, attitudes that leave the information singular, a `K` with a negative determinant (a
/// given field), a fit that does not settle.
pub fn fit_vector(readings: &[Vec3], attitudes: &[Mat3], field: ReferenceField) -> Result<VectorFit, VectorError> {
    fit_vector_in(readings, attitudes, field, crate::log_fit::Order::Unknown)
}

/// [`fit_vector`] of readings in the order `order` says: in time order, the standard errors
/// allow for the residuals' correlation as a log fit's do ([`crate::log_fit::serial`]): the
/// covariance is the sandwich of the scores' long-run covariance (batch length by Andrews' rule
/// on the residuals' component along the calibrated field), its diagonal at least the white
/// one's (a diagonal added where it falls short, which keeps it a covariance), and the 95 %
/// intervals take the batches' degrees of freedom.
///
/// # Errors
/// As [`fit_vector`].
pub fn fit_vector_in(
    readings: &[Vec3],
    attitudes: &[Mat3],
    field: ReferenceField,
    order: crate::log_fit::Order,
) -> Result<VectorFit, VectorError> {
    let (scale, given) = validate(readings, attitudes, field)?;
    let data = Data {
        readings,
        attitudes,
        scale,
        fields: None,
    };
    let (fit, iterations) = match given {
        Some(f) => linear(&data, f)?,
        None => gauss_newton(&data, start(&data))?,
    };
    Ok(assess(&data, fit, given.is_none(), scale, iterations, order))
}

/// The fit with the field given (`f`, units of the scale; per reading where `data` has them):
/// linear in `K` and `O`, one step from zero solves it and a second removes the rounding of the
/// first.
fn linear(data: &Data, f: Vec3) -> Result<(Unit, usize), VectorError> {
    let mut unit = Unit {
        k: [[0.0; 3]; 3],
        o: [0.0; 3],
        f,
    };
    let mut iterations = 0;
    for _ in 0..2 {
        let n = NormalEquations::of(data, &unit, false);
        let step = n.solve()?;
        unit.step(&step, 1.0, false);
        iterations += 1;
    }
    let d = det(&unit.k);
    if d.is_nan() || d <= 0.0 {
        return Err(VectorError::LeftHanded { determinant: d });
    }
    Ok((unit, iterations))
}

/// Checks the inputs; the magnitude the readings are divided by and a given field's direction.
fn validate(readings: &[Vec3], attitudes: &[Mat3], field: ReferenceField) -> Result<(f64, Option<Vec3>), VectorError> {
    if readings.len() != attitudes.len() {
        return Err(VectorError::LengthMismatch {
            readings: readings.len(),
            attitudes: attitudes.len(),
        });
    }
    let (scale, given, unknowns) = match field {
        ReferenceField::Given(f) => {
            let n = norm(f);
            if !(n.is_finite() && n > 0.0) {
                return Err(VectorError::InvalidField { value: f });
            }
            (n, Some(f.map(|v| v / n)), 12)
        }
        ReferenceField::Fitted { magnitude } => {
            if !(magnitude.is_finite() && magnitude > 0.0) {
                return Err(VectorError::InvalidField {
                    value: [magnitude, 0.0, 0.0],
                });
            }
            (magnitude, None, 14)
        }
    };
    // 3 m > unknowns: at least one residual degree of freedom.
    let needed = unknowns / 3 + 1;
    if readings.len() < needed {
        return Err(VectorError::TooFewReadings {
            got: readings.len(),
            needed,
            unknowns,
        });
    }
    for (index, (r, c)) in readings.iter().zip(attitudes).enumerate() {
        if !r.iter().all(|v| (v / scale).is_finite()) {
            return Err(VectorError::NonFiniteReading { index, value: *r });
        }
        let ctc = mat_mul(&transpose(c), c);
        let deviation = (0..3)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| (ctc[i][j] - f64::from(u8::from(i == j))).abs())
            .fold(0.0_f64, |a, d| if d.is_nan() { f64::NAN } else { a.max(d) });
        let determinant = det(c);
        if !(deviation <= ROTATION_TOLERANCE && determinant > 0.0) {
            return Err(VectorError::NotARotation {
                index,
                deviation,
                determinant,
            });
        }
    }
    Ok((scale, given))
}

/// The readings in units of the field magnitude (`m / |F|`, made as they are used: nothing per
/// reading is copied) and their attitudes.
struct Data<'a> {
    readings: &'a [Vec3],
    attitudes: &'a [Mat3],
    scale: f64,
    /// The field of each reading in units of `scale`, where it is given per reading (the model
    /// along a track); else every reading has the one field of the fit.
    fields: Option<Vec<Vec3>>,
}

impl Data<'_> {
    fn iter(&self) -> impl Iterator<Item = (Vec3, &Mat3)> {
        self.readings
            .iter()
            .map(|r| r.map(|v| v / self.scale))
            .zip(self.attitudes)
    }

    /// Each reading, its attitude and its field: its own where given per reading, else `f`.
    fn iter_with(&self, f: Vec3) -> impl Iterator<Item = (Vec3, &Mat3, Vec3)> {
        self.iter()
            .enumerate()
            .map(move |(t, (m, c))| (m, c, self.fields.as_ref().map_or(f, |fs| fs[t])))
    }
}

/// The unknowns in units of the field magnitude: `K`, `o = O / |F|`, `f = F / |F|`.
#[derive(Debug, Clone, Copy)]
struct Unit {
    k: Mat3,
    o: Vec3,
    f: Vec3,
}

impl Unit {
    /// Moves by `t` times `step` (`K` row-major, `o`, and with `fitted` two tangent
    /// coordinates of `f`, then put back on the unit sphere).
    fn step(&mut self, step: &[f64], t: f64, fitted: bool) {
        for i in 0..3 {
            for j in 0..3 {
                self.k[i][j] += t * step[3 * i + j];
            }
            self.o[i] += t * step[9 + i];
        }
        if fitted {
            let [u, v] = tangent(self.f);
            let f: Vec3 = std::array::from_fn(|i| self.f[i] + t * (step[12] * u[i] + step[13] * v[i]));
            self.f = f.map(|x| x / norm(f));
        }
    }

    /// `sum_t |m_t / |F| - K C_t^T f - o|^2`.
    fn rss(&self, data: &Data) -> f64 {
        data.iter_with(self.f)
            .map(|(m, c, f)| {
                let r = sub(m, crate::small::add(mat_vec(&self.k, mat_t_vec(c, f)), self.o));
                dot(r, r)
            })
            .sum()
    }
}

/// Two unit vectors orthogonal to the unit vector `f` and to each other.
fn tangent(f: Vec3) -> [Vec3; 2] {
    // The coordinate axis least along f.
    let i = (0..3).min_by(|&a, &b| f[a].abs().total_cmp(&f[b].abs())).unwrap_or(0);
    let mut e = [0.0; 3];
    e[i] = 1.0;
    let u = cross(f, e);
    let u = u.map(|x| x / norm(u));
    [u, cross(f, u)]
}

fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The Gauss-Newton normal equations `J^T J d = J^T r` at `unit` (12 unknowns, 14 with a
/// fitted field), and the sum of squares there.
struct NormalEquations {
    jtj: Vec<Vec<f64>>,
    jtr: Vec<f64>,
    /// The unknowns' names, in order, for what the readings leave open.
    names: &'static [&'static str],
}

/// The names of the unknowns, in order.
const NAMES: [&str; 14] = [
    "K11",
    "K12",
    "K13",
    "K21",
    "K22",
    "K23",
    "K31",
    "K32",
    "K33",
    "Ox",
    "Oy",
    "Oz",
    "F (first turn)",
    "F (second turn)",
];

impl NormalEquations {
    fn of(data: &Data, unit: &Unit, fitted: bool) -> Self {
        let p = if fitted { 14 } else { 12 };
        let mut jtj = vec![vec![0.0; p]; p];
        let mut jtr = vec![0.0; p];
        let [u, v] = tangent(unit.f);
        let mut rows = [[0.0; 14]; 3];
        for (m, c, f) in data.iter_with(unit.f) {
            let b = mat_t_vec(c, f);
            let r = sub(m, crate::small::add(mat_vec(&unit.k, b), unit.o));
            let (ku, kv) = (mat_vec(&unit.k, mat_t_vec(c, u)), mat_vec(&unit.k, mat_t_vec(c, v)));
            for i in 0..3 {
                let row = &mut rows[i];
                *row = [0.0; 14];
                row[3 * i..3 * i + 3].copy_from_slice(&b);
                row[9 + i] = 1.0;
                row[12] = ku[i];
                row[13] = kv[i];
            }
            for row in &rows {
                for a in 0..p {
                    for b in 0..=a {
                        jtj[a][b] += row[a] * row[b];
                    }
                }
            }
            for i in 0..3 {
                for a in 0..p {
                    jtr[a] += rows[i][a] * r[i];
                }
            }
        }
        for a in 0..p {
            for b in 0..a {
                jtj[b][a] = jtj[a][b];
            }
        }
        Self {
            jtj,
            jtr,
            names: &NAMES,
        }
    }

    /// The eigendecomposition of the information in correlation form: `(d, values, vectors)`
    /// with `J^T J = D^(1/2) V diag(values) V^T D^(1/2)`, `D = diag(d)`; values increasing.
    fn correlation_eigen(&self) -> Result<CorrelationEigen, VectorError> {
        let p = self.jtr.len();
        let d: Vec<f64> = (0..p).map(|a| self.jtj[a][a]).collect();
        if let Some(a) = (0..p).find(|&a| !(d[a] > 0.0 && d[a].is_finite())) {
            return Err(VectorError::NotDetermined {
                weakest: format!("the readings do not move {} at all", self.names[a]),
            });
        }
        let s: Vec<f64> = d.iter().map(|v| v.sqrt()).collect();
        let m = faer::Mat::from_fn(p, p, |a, b| self.jtj[a][b] / (s[a] * s[b]));
        let evd = m
            .self_adjoint_eigen(faer::Side::Lower)
            .map_err(|_| VectorError::NotDetermined {
                weakest: "the eigendecomposition of the information failed".into(),
            })?;
        let mut order: Vec<usize> = (0..p).collect();
        order.sort_by(|&a, &b| evd.S()[a].total_cmp(&evd.S()[b]));
        let values = order.iter().map(|&i| evd.S()[i]).collect();
        let vectors = order
            .iter()
            .map(|&i| (0..p).map(|r| evd.U()[(r, i)]).collect())
            .collect();
        Ok((d, values, vectors))
    }

    /// `(J^T J)^-1`, or the singular combination in words.
    fn inverse(&self) -> Result<Vec<Vec<f64>>, VectorError> {
        let (d, values, vectors) = self.correlation_eigen()?;
        let p = d.len();
        let regular = values[0] > SINGULAR * values[p - 1];
        if !regular {
            return Err(VectorError::NotDetermined {
                weakest: weakest(&vectors[0], self.names),
            });
        }
        Ok((0..p)
            .map(|a| {
                (0..p)
                    .map(|b| {
                        let sum: f64 = (0..p).map(|k| vectors[k][a] * vectors[k][b] / values[k]).sum();
                        sum / (d[a] * d[b]).sqrt()
                    })
                    .collect()
            })
            .collect())
    }

    /// The Gauss-Newton step `(J^T J)^-1 J^T r`.
    fn solve(&self) -> Result<Vec<f64>, VectorError> {
        let inv = self.inverse()?;
        Ok(inv.iter().map(|row| dot_slices(row, &self.jtr)).collect())
    }
}

/// `value <= limit`, false for NaN: a standard error that cannot be computed is not within.
fn within(value: f64, limit: f64) -> bool {
    value <= limit
}

/// `(d, values, vectors)`: see [`NormalEquations::correlation_eigen`].
type CorrelationEigen = (Vec<f64>, Vec<f64>, Vec<Vec<f64>>);

fn dot_slices(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The unknowns that carry most of a (correlation-form) eigenvector, in words.
fn weakest(v: &[f64], names: &[&'static str]) -> String {
    let mut parts: Vec<(f64, &str)> = v.iter().zip(names).map(|(x, n)| (x.abs(), *n)).collect();
    parts.sort_by(|a, b| b.0.total_cmp(&a.0));
    let named: Vec<String> = parts
        .iter()
        .take_while(|(w, _)| *w >= 0.2)
        .take(6)
        .map(|(w, n)| format!("{n} ({w:.2})"))
        .collect();
    format!(
        "{} move together at no cost (all the same attitude, or turns about one axis only, leave such a combination open; weights in correlation form)",
        named.join(", ")
    )
}

/// The start of a fitted field's Gauss-Newton: the rank-one part of the 30-unknown linear model
/// (see the module documentation), its least squares by the pseudo-inverse (eigenvalues of the
/// correlation form above [`SINGULAR`] of the largest).
fn start(data: &Data) -> Unit {
    // Design row: the 9 entries of C (row-major: C_kj at 3 k + j) and 1.
    let mut ztz = [[0.0; 10]; 10];
    let mut zty = [[0.0; 3]; 10];
    for (m, c) in data.iter() {
        let z: [f64; 10] = std::array::from_fn(|a| if a < 9 { c[a / 3][a % 3] } else { 1.0 });
        for a in 0..10 {
            for b in 0..10 {
                ztz[a][b] += z[a] * z[b];
            }
            for i in 0..3 {
                zty[a][i] += z[a] * m[i];
            }
        }
    }
    let d: [f64; 10] = std::array::from_fn(|a| ztz[a][a].max(f64::MIN_POSITIVE).sqrt());
    let corr = faer::Mat::from_fn(10, 10, |a, b| ztz[a][b] / (d[a] * d[b]));
    // beta[a][i]: the coefficient of design entry a for sensor axis i.
    let mut beta = [[0.0; 3]; 10];
    if let Ok(evd) = corr.self_adjoint_eigen(faer::Side::Lower) {
        let largest = (0..10).map(|k| evd.S()[k]).fold(0.0_f64, f64::max);
        for k in (0..10).filter(|&k| evd.S()[k] > SINGULAR * largest) {
            let u: [f64; 10] = std::array::from_fn(|a| evd.U()[(a, k)]);
            for i in 0..3 {
                let c: f64 = (0..10).map(|a| u[a] * zty[a][i] / d[a]).sum::<f64>() / evd.S()[k];
                for a in 0..10 {
                    beta[a][i] += c * u[a] / d[a];
                }
            }
        }
    }
    // Z[(i, j)][k] = K_ij F_k = beta[3 k + j][i]; its leading right singular vector is F.
    let mut ztz3 = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            for k in 0..3 {
                for l in 0..3 {
                    ztz3[k][l] += beta[3 * k + j][i] * beta[3 * l + j][i];
                }
            }
        }
    }
    let f = leading_eigenvector(&ztz3);
    let mut k: Mat3 = std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|l| beta[3 * l + j][i] * f[l]).sum()));
    let mut f = f;
    if det(&k) < 0.0 {
        k = k.map(|r| r.map(|v| -v));
        f = f.map(|v| -v);
    }
    Unit {
        k,
        o: [beta[9][0], beta[9][1], beta[9][2]],
        f,
    }
}

/// The unit eigenvector of the largest eigenvalue of a symmetric 3x3 matrix (`(0, 0, 1)` when
/// the decomposition fails).
fn leading_eigenvector(a: &Mat3) -> Vec3 {
    let m = faer::Mat::from_fn(3, 3, |i, j| a[i][j]);
    match m.self_adjoint_eigen(faer::Side::Lower) {
        Ok(evd) => {
            let k = (0..3).max_by(|&i, &j| evd.S()[i].total_cmp(&evd.S()[j])).unwrap_or(2);
            let v: Vec3 = std::array::from_fn(|r| evd.U()[(r, k)]);
            if v.iter().all(|x| x.is_finite()) && norm(v) > 0.0 {
                v.map(|x| x / norm(v))
            } else {
                [0.0, 0.0, 1.0]
            }
        }
        Err(_) => [0.0, 0.0, 1.0],
    }
}

/// Gauss-Newton from `unit` with the field fitted; the fit and its iterations.
fn gauss_newton(data: &Data, mut unit: Unit) -> Result<(Unit, usize), VectorError> {
    let mut rss = unit.rss(data);
    for iteration in 1..=MAX_ITERATIONS {
        let n = NormalEquations::of(data, &unit, true);
        let step = n.solve()?;
        // The step in correlation units: each unknown times the square root of its information.
        let size = (0..14)
            .map(|a| (step[a] * n.jtj[a][a].sqrt()).powi(2))
            .sum::<f64>()
            .sqrt();
        let mut t = 1.0;
        let mut accepted = false;
        for _ in 0..40 {
            let mut next = unit;
            next.step(&step, t, true);
            let r = next.rss(data);
            if r <= rss {
                (unit, rss, accepted) = (next, r, true);
                break;
            }
            t /= 2.0;
        }
        // The step's size is the change it makes to the residuals. Below 1e-6 of their norm it
        // moves each unknown by at most 1e-6 sqrt(dof) of its standard error, and lowers the sum
        // of squares by its square, 1e-12 of the sum: the rounding of a sum over 1e4 to 1e5
        // readings, where further steps wander. Below 1e-13 per reading (noise-free readings) it
        // is rounding too; a step that lowers nothing leaves the fit at its rounding.
        if !accepted || size <= 1e-6 * rss.sqrt() || size <= 1e-13 * (data.readings.len() as f64).sqrt() {
            if det(&unit.k) < 0.0 {
                unit.k = unit.k.map(|r| r.map(|v| -v));
                unit.f = unit.f.map(|v| -v);
            }
            return Ok((unit, iteration));
        }
    }
    Err(VectorError::NotConverged {
        iterations: MAX_ITERATIONS,
    })
}

/// `(P, A)` of `K^-1 = A P` (QR by Gram-Schmidt, twice for orthogonality), or `None` when `K`
/// is singular.
fn decompose(k: &Mat3) -> Option<(Mat3, Mat3)> {
    let cols: [Vec3; 3] = std::array::from_fn(|j| {
        let mut e = [0.0; 3];
        e[j] = 1.0;
        crate::small::solve3(k, e)
    })
    .map(|c| c.unwrap_or([f64::NAN; 3]));
    // cols[j] is column j of K^-1.
    let mut q: [Vec3; 3] = [[0.0; 3]; 3];
    let mut p = [[0.0; 3]; 3];
    for j in 0..3 {
        let mut v = cols[j];
        for _ in 0..2 {
            for i in 0..j {
                let c = dot(q[i], v);
                p[i][j] += c;
                v = sub(v, q[i].map(|x| x * c));
            }
        }
        let n = norm(v);
        if !(n > 0.0 && n.is_finite()) {
            return None;
        }
        p[j][j] = n;
        q[j] = v.map(|x| x / n);
    }
    // A has the q's as columns.
    let a: Mat3 = std::array::from_fn(|r| std::array::from_fn(|c| q[c][r]));
    (det(&a) > 0.0).then_some((p, a))
}

/// The rotation vector (axis times angle, radians) of a rotation `r`.
fn rotation_vector(r: &Mat3) -> Vec3 {
    let v = [r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]];
    let s = norm(v) / 2.0;
    let c = ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0).clamp(-1.0, 1.0);
    let angle = s.atan2(c);
    if s > 1e-6 {
        return v.map(|x| x * angle / (2.0 * s));
    }
    if c > 0.0 {
        // Near the identity: the antisymmetric part is the vector to third order.
        return v.map(|x| x / 2.0);
    }
    // Near a half turn: the axis from the symmetric part r + I = 2 a a^T.
    let i = (0..3).max_by(|&a, &b| r[a][a].total_cmp(&r[b][b])).unwrap_or(0);
    let col: Vec3 = std::array::from_fn(|j| r[j][i] + f64::from(u8::from(i == j)));
    let n = norm(col);
    col.map(|x| x / n * angle)
}

/// `(psi_deg, S, misalignment vector in degrees)` of `K` beyond the whole step `step`: what
/// the delta method differentiates.
fn derived(k: &Mat3, step: &Mat3) -> Option<[f64; 9]> {
    let (p, a) = decompose(k)?;
    let e = ErrorModel::from_k(&upper_triangular_inverse(&p)?, [0.0; 3]);
    let (psi, s, w) = (e.psi_deg(), e.scale(), misalignment_vector(&a, step));
    Some([
        psi[0],
        psi[1],
        psi[2],
        s[0],
        s[1],
        s[2],
        w[0].to_degrees(),
        w[1].to_degrees(),
        w[2].to_degrees(),
    ])
}

/// The fit's statistics and verdict.
fn assess(
    data: &Data,
    unit: Unit,
    fitted: bool,
    scale: f64,
    iterations: usize,
    order: crate::log_fit::Order,
) -> VectorFit {
    let m = data.readings.len();
    let p_count = if fitted { 14 } else { 12 };
    let rss = unit.rss(data);
    let dof = 3 * m - p_count;
    let noise_unit = (rss / dof as f64).sqrt();
    let inverse = NormalEquations::of(data, &unit, fitted).inverse().ok();
    let serial = match order {
        crate::log_fit::Order::Unknown => None,
        crate::log_fit::Order::Time => Some(crate::log_fit::Serial::of_residuals(&radial_residuals(data, &unit))),
        crate::log_fit::Order::Batch(batch) => Some(crate::log_fit::Serial { batch, lag_one: None }),
    };
    let covariance = inverse.as_ref().map(|inv| {
        let white: Vec<Vec<f64>> = inv
            .iter()
            .map(|row| row.iter().map(|v| v * noise_unit * noise_unit).collect())
            .collect();
        match serial {
            Some(s) => long_run(data, &unit, inv, &white, s.batch),
            None => white,
        }
    });
    let std_error = covariance
        .as_ref()
        .filter(|_| noise_unit.is_finite())
        .and_then(|cov| std_errors(&unit, cov, fitted, scale));
    let fit = assess_parts(&unit, scale, noise_unit, dof, serial, m, rss, std_error, fitted);
    VectorFit { iterations, ..fit }
}

/// A fit of the given field from its unknowns `unit`, the noise and degrees of freedom, the
/// residuals' correlation, the readings, the residual sum of squares (units of `scale`) and the
/// standard errors, whether `F` was fitted: the decomposition of `K`, the verdict ([`judge`]),
/// two iterations and no motor (the callers set what differs).
#[allow(clippy::too_many_arguments)]
fn assess_parts(
    unit: &Unit,
    scale: f64,
    noise_unit: f64,
    dof: usize,
    serial: Option<crate::log_fit::Serial>,
    m: usize,
    rss: f64,
    std_error: Option<VectorStdError>,
    fitted: bool,
) -> VectorFit {
    let (p, alignment) = decompose(&unit.k).unwrap_or(([[f64::NAN; 3]; 3], [[f64::NAN; 3]; 3]));
    let model = ErrorModel::from_k(&upper_triangular_inverse(&p).unwrap_or([[f64::NAN; 3]; 3]), [0.0; 3]);
    let (identifiable, verdict) = judge(std_error.as_ref(), &model, scale, fitted, m);
    VectorFit {
        k: unit.k,
        bias: unit.o.map(|v| v * scale),
        field: unit.f.map(|v| v * scale),
        field_fitted: fitted,
        p,
        alignment,
        noise: noise_unit.is_finite().then_some(noise_unit * scale),
        dof,
        noise_interval95: noise_unit
            .is_finite()
            .then(|| crate::log_fit::chi_square_interval(noise_unit * scale, dof)),
        quantile95: Some(crate::log_fit::student_quantile(
            0.975,
            serial.map_or(dof, |s| s.dof(m)),
        ))
        .filter(|q| q.is_finite()),
        serial,
        std_error,
        identifiable,
        verdict,
        rms_residual: (rss / (3 * m) as f64).sqrt() * scale,
        iterations: 2,
        model: VectorModel::Full,
        motor: None,
        std_motor: None,
    }
}

/// Each reading's residual along the calibrated field, `r . w`, `w = K C^T f / |K C^T f|`: the
/// series whose lag-one autocorrelation chooses the batch length.
fn radial_residuals(data: &Data, unit: &Unit) -> Vec<f64> {
    data.iter_with(unit.f)
        .map(|(m, c, f)| {
            let model = mat_vec(&unit.k, mat_t_vec(c, f));
            let r = sub(m, crate::small::add(model, unit.o));
            dot(r, model) / norm(model)
        })
        .collect()
}

/// The covariance of the unknowns from the long-run covariance of the scores `J_t^T r_t` (summed
/// over a reading's three components) by overlapping batch means of `batch` readings, times
/// `n / (n - p)` (`n = 3 m` residuals, `p` unknowns), with the white covariance's diagonal where
/// that is larger (see [`fit_vector_in`]).
fn long_run(data: &Data, unit: &Unit, inv: &[Vec<f64>], white: &[Vec<f64>], batch: usize) -> Vec<Vec<f64>> {
    let [u, v] = tangent(unit.f);
    let scores: Vec<[f64; 14]> = data
        .iter_with(unit.f)
        .map(|(m, c, f)| {
            let b = mat_t_vec(c, f);
            let r = sub(m, crate::small::add(mat_vec(&unit.k, b), unit.o));
            let (ku, kv) = (mat_vec(&unit.k, mat_t_vec(c, u)), mat_vec(&unit.k, mat_t_vec(c, v)));
            let mut s = [0.0; 14];
            for i in 0..3 {
                for j in 0..3 {
                    s[3 * i + j] += b[j] * r[i];
                }
                s[9 + i] += r[i];
                s[12] += ku[i] * r[i];
                s[13] += kv[i] * r[i];
            }
            s
        })
        .collect();
    let b = crate::log_fit::serial::long_run_covariance(&scores, batch);
    sandwich(inv, &b, white, 3 * scores.len())
}

/// `n / (n - p) A^-1 B A^-1` (`A^-1 = inv`, `p` its order, `B` the scores' long-run covariance
/// padded to `N`, `n` the residuals) with its diagonal at least the white covariance's (a
/// diagonal added where it falls short, which keeps it a covariance).
fn sandwich<const N: usize>(inv: &[Vec<f64>], b: &[[f64; N]; N], white: &[Vec<f64>], n: usize) -> Vec<Vec<f64>> {
    let p = inv.len();
    let n = n as f64;
    let factor = if n > p as f64 { n / (n - p as f64) } else { f64::NAN };
    let mut cov: Vec<Vec<f64>> = (0..p)
        .map(|a| {
            (0..p)
                .map(|d| {
                    factor
                        * (0..p)
                            .map(|k| (0..p).map(|l| inv[a][k] * b[k][l] * inv[l][d]).sum::<f64>())
                            .sum::<f64>()
                })
                .collect()
        })
        .collect();
    for a in 0..p {
        cov[a][a] += (white[a][a] - cov[a][a]).max(0.0);
    }
    cov
}

/// The standard errors from the covariance `cov` of the unknowns in units of the field.
fn std_errors(unit: &Unit, cov: &[Vec<f64>], fitted: bool, scale: f64) -> Option<VectorStdError> {
    let sd = |a: usize| cov[a][a].max(0.0).sqrt();
    let k = std::array::from_fn(|i| std::array::from_fn(|j| sd(3 * i + j)));
    let bias = std::array::from_fn(|i| sd(9 + i) * scale);
    let (field, field_direction_deg) = if fitted {
        // F = u a + v b in the tangent plane: cov(F) = T cov_ab T^T, T = [u v].
        let [u, v] = tangent(unit.f);
        let c = [[cov[12][12], cov[12][13]], [cov[13][12], cov[13][13]]];
        let f: Vec3 = std::array::from_fn(|i| {
            let t = [u[i], v[i]];
            (0..2)
                .map(|a| (0..2).map(|b| t[a] * c[a][b] * t[b]).sum::<f64>())
                .sum::<f64>()
                .max(0.0)
                .sqrt()
                * scale
        });
        // The direction's angular standard error: the rms of the two tangent ones (|f| = 1).
        (f, ((c[0][0] + c[1][1]) / 2.0).max(0.0).sqrt().to_degrees())
    } else {
        ([0.0; 3], 0.0)
    };
    // The delta method on the K block: central differences of `derived`.
    let base = unit.k;
    let step = nearest_whole_step(&decompose(&base)?.1);
    let h = 1e-6 * base.iter().flatten().fold(0.0_f64, |a, v| a.max(v.abs()));
    let mut jac = [[0.0; 9]; 9];
    for a in 0..9 {
        let (mut plus, mut minus) = (base, base);
        plus[a / 3][a % 3] += h;
        minus[a / 3][a % 3] -= h;
        let (gp, gm) = (derived(&plus, &step)?, derived(&minus, &step)?);
        for r in 0..9 {
            jac[r][a] = (gp[r] - gm[r]) / (2.0 * h);
        }
    }
    let var = |r: usize| {
        (0..9)
            .map(|a| (0..9).map(|b| jac[r][a] * cov[a][b] * jac[r][b]).sum::<f64>())
            .sum::<f64>()
            .max(0.0)
    };
    let g: [f64; 9] = std::array::from_fn(|r| var(r).sqrt());
    // The angle |w|: gradient w / |w| through the rotation vector's covariance.
    let w = derived(&base, &step)?;
    let wv = [w[6], w[7], w[8]];
    let angle = norm(wv);
    let misalignment_deg = if angle > 0.0 {
        let dir = wv.map(|x| x / angle);
        (0..9)
            .map(|a| {
                (0..9)
                    .map(|b| {
                        let ga: f64 = (0..3).map(|i| dir[i] * jac[6 + i][a]).sum();
                        let gb: f64 = (0..3).map(|i| dir[i] * jac[6 + i][b]).sum();
                        ga * cov[a][b] * gb
                    })
                    .sum::<f64>()
            })
            .sum::<f64>()
            .max(0.0)
            .sqrt()
    } else {
        (g[6] * g[6] + g[7] * g[7] + g[8] * g[8]).sqrt()
    };
    Some(VectorStdError {
        k,
        bias,
        field,
        field_direction_deg,
        psi_deg: [g[0], g[1], g[2]],
        scale: [g[3], g[4], g[5]],
        rotation_vector_deg: [g[6], g[7], g[8]],
        misalignment_deg,
    })
}

/// Whether the standard errors are within their physical scales, and the verdict in words.
fn judge(std: Option<&VectorStdError>, model: &ErrorModel, scale: f64, fitted: bool, m: usize) -> (bool, String) {
    let Some(s) = std else {
        return (
            false,
            format!(
                "not determined: the standard errors are unknown ({m} readings leave no residual degrees of freedom, or the decomposition of K failed)"
            ),
        );
    };
    let scales = PhysicalScales::default();
    let axes = ["x", "y", "z"];
    let mut weak = Vec::new();
    for i in 0..3 {
        if !within(s.psi_deg[i], scales.psi_deg) {
            weak.push(format!(
                "psi{} (std {:.3} deg > {} deg)",
                i + 1,
                s.psi_deg[i],
                scales.psi_deg
            ));
        }
        if !within(s.scale[i], scales.scale_fraction * model.scale()[i]) {
            weak.push(format!(
                "S{} (std {:.4} > half of {:.4})",
                i + 1,
                s.scale[i],
                model.scale()[i]
            ));
        }
        if !within(s.bias[i], scales.bias_fraction_of_field * scale) {
            weak.push(format!(
                "O{} (std {:.4e} > the field {:.4e})",
                axes[i], s.bias[i], scale
            ));
        }
        if !within(s.rotation_vector_deg[i], scales.psi_deg) {
            weak.push(format!(
                "the alignment about body {} (std {:.3} deg > {} deg)",
                axes[i], s.rotation_vector_deg[i], scales.psi_deg
            ));
        }
    }
    if fitted && !within(s.field_direction_deg, scales.psi_deg) {
        weak.push(format!(
            "the direction of F (std {:.3} deg > {} deg)",
            s.field_direction_deg, scales.psi_deg
        ));
    }
    if weak.is_empty() {
        (
            true,
            format!(
                "identifiable: every standard error within its physical scale (psi, misalignment{} {} degrees; S half its value; O the field); misalignment std {:.3} deg",
                if fitted { " and the direction of F" } else { "" },
                scales.psi_deg,
                s.misalignment_deg
            ),
        )
    } else {
        (false, format!("not determined: {}", weak.join(", ")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::paper;
    use crate::rng::{MagcalRng, stream_rng};
    use rand_distr::{Distribution, StandardNormal};
    use statrs::distribution::{ChiSquared, ContinuousCDF};

    /// \[P1\]'s Changsha field (IV.A) in the z-up frame east, north, up, nT.
    const FIELD_ENU: Vec3 = [-2085.74, 35272.34, -32897.67];

    /// The rotation by `deg` about the unit vector `axis` (Rodrigues).
    fn about(axis: Vec3, deg: f64) -> Mat3 {
        let (s, c) = deg.to_radians().sin_cos();
        std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                let skew = [
                    [0.0, -axis[2], axis[1]],
                    [axis[2], 0.0, -axis[0]],
                    [-axis[1], axis[0], 0.0],
                ];
                f64::from(u8::from(i == j)) * c + s * skew[i][j] + (1.0 - c) * axis[i] * axis[j]
            })
        })
    }

    /// The test sensor: \[P1\]'s psi, S, O (IV.A) turned by 2 degrees about the tilted axis
    /// (1, 2, 2) / 3: `K = K_[P1] A^T`; with `A` and `K`.
    fn truth() -> (ErrorModel, Mat3, Mat3) {
        let model = paper::true_error_model();
        let a = about([1.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0], 2.0);
        (model, a, mat_mul(&model.K(), &transpose(&a)))
    }

    /// `count` attitudes uniform on SO(3) (normalised Gaussian quaternions).
    fn attitudes(count: usize, rng: &mut MagcalRng) -> Vec<Mat3> {
        (0..count)
            .map(|_| {
                let q: [f64; 4] = std::array::from_fn(|_| StandardNormal.sample(rng));
                let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
                crate::aviation::dcm_of_quaternion(q.map(|v| v / n)).unwrap()
            })
            .collect()
    }

    /// Readings of `k`, `bias` at `attitudes` with noise `sigma` per component.
    fn readings(k: &Mat3, bias: Vec3, attitudes: &[Mat3], sigma: f64, rng: &mut MagcalRng) -> Vec<Vec3> {
        attitudes
            .iter()
            .map(|c| {
                let m = crate::small::add(mat_vec(k, mat_t_vec(c, FIELD_ENU)), bias);
                m.map(|v| v + sigma * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, rng))
            })
            .collect()
    }

    fn max_abs_diff(a: &Mat3, b: &Mat3) -> f64 {
        (0..3)
            .flat_map(|i| (0..3).map(move |j| (a[i][j] - b[i][j]).abs()))
            .fold(0.0, f64::max)
    }

    #[test]
    fn noise_free_readings_give_the_sensor_back_to_rounding() {
        let (model, a, k) = truth();
        let mut rng = stream_rng(22, 0);
        let c = attitudes(40, &mut rng);
        let m = readings(&k, model.bias_nt(), &c, 0.0, &mut rng);
        let magnitude = norm(FIELD_ENU);
        for field in [ReferenceField::Given(FIELD_ENU), ReferenceField::Fitted { magnitude }] {
            let fit = fit_vector(&m, &c, field).unwrap();
            // Entries of order 1 from a well-conditioned least squares of 120 equations: the
            // rounding of the readings (eps |F|) amplified by the condition of K (about 2).
            let tol = 1e3 * f64::EPSILON;
            assert!(max_abs_diff(&fit.k, &k) <= tol, "{:?}", fit.k);
            assert!(max_abs_diff(&fit.alignment, &a) <= tol, "{:?}", fit.alignment);
            assert!(max_abs_diff(&fit.p, &model.P()) <= tol, "{:?}", fit.p);
            for i in 0..3 {
                assert!((fit.bias[i] - model.bias_nt()[i]).abs() <= tol * magnitude);
                assert!((fit.field[i] - FIELD_ENU[i]).abs() <= tol * magnitude);
                assert!((fit.error_model().psi_deg()[i] - model.psi_deg()[i]).abs() <= tol * 100.0);
                assert!((fit.error_model().scale()[i] - model.scale()[i]).abs() <= tol);
            }
            assert!(
                (fit.misalignment_deg() - 2.0).abs() <= 1e-9,
                "{}",
                fit.misalignment_deg()
            );
            let axis = fit.misalignment_axis();
            assert!(
                (dot(axis, [1.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0]) - 1.0).abs() <= 1e-9,
                "{axis:?}"
            );
            // The body-frame field of every reading is C^T F.
            for (r, c) in m.iter().zip(&c) {
                let d = sub(fit.apply(*r), mat_t_vec(c, FIELD_ENU));
                assert!(norm(d) <= tol * magnitude, "{d:?}");
            }
            assert!(fit.rms_residual <= tol * magnitude);
        }
    }

    #[test]
    fn a_field_given_per_reading_is_fitted_as_given_and_one_field_is_not_enough() {
        // A field that grows by 2 % and turns by about a degree over the log (a track of some
        // hundred kilometres): noise-free readings give the sensor back to rounding against
        // the fields per reading; against their mean the fit is left with residuals of the
        // fields' spread.
        let (model, _, k) = truth();
        let mut rng = stream_rng(23, 0);
        let c = attitudes(60, &mut rng);
        let n = c.len();
        let fields: Vec<Vec3> = (0..n)
            .map(|t| {
                let s = t as f64 / (n - 1) as f64;
                [
                    FIELD_ENU[0] + 300.0 * s,
                    FIELD_ENU[1] * (1.0 + 0.02 * s),
                    FIELD_ENU[2] * (1.0 + 0.01 * s),
                ]
            })
            .collect();
        let m: Vec<Vec3> = c
            .iter()
            .zip(&fields)
            .map(|(c, f)| crate::small::add(mat_vec(&k, mat_t_vec(c, *f)), model.bias_nt()))
            .collect();
        let magnitude = norm(FIELD_ENU);
        let fit = fit_track(&m, &c, &fields, None, VectorModel::Full, crate::log_fit::Order::Unknown).unwrap();
        let tol = 1e3 * f64::EPSILON;
        assert!(max_abs_diff(&fit.k, &k) <= tol, "{:?}", fit.k);
        assert!(fit.rms_residual <= tol * magnitude, "{}", fit.rms_residual);
        for i in 0..3 {
            assert!((fit.bias[i] - model.bias_nt()[i]).abs() <= tol * magnitude);
        }
        let mean = fit.field;
        let one = fit_vector(&m, &c, ReferenceField::Given(mean)).unwrap();
        // The fields depart from their mean by up to 1 % of the magnitude (500 nT): one field
        // leaves residuals of that order.
        assert!(one.rms_residual > 50.0, "{}", one.rms_residual);
        // Lengths and fields are checked.
        assert!(matches!(
            fit_track(
                &m,
                &c,
                &fields[1..],
                None,
                VectorModel::Full,
                crate::log_fit::Order::Unknown
            ),
            Err(VectorError::LengthMismatch { .. })
        ));
        let mut zero = fields.clone();
        zero[3] = [0.0; 3];
        assert!(matches!(
            fit_track(&m, &c, &zero, None, VectorModel::Full, crate::log_fit::Order::Unknown),
            Err(VectorError::InvalidField { .. })
        ));
    }

    #[test]
    #[allow(clippy::float_cmp)] // a signed permutation matrix: exact
    fn a_sensor_mounted_in_another_whole_step_keeps_its_misalignment() {
        // The sensor's axes forward, left, up in a body frame forward, right, down: A turned by
        // a half turn about forward, the misalignment beyond it still 2 degrees.
        let (model, a, _) = truth();
        let half = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]];
        let mounted = mat_mul(&a, &half);
        let k = mat_mul(&model.K(), &transpose(&mounted));
        let mut rng = stream_rng(22, 4);
        let c = attitudes(40, &mut rng);
        let m = readings(&k, model.bias_nt(), &c, 0.0, &mut rng);
        let fit = fit_vector(&m, &c, ReferenceField::Given(FIELD_ENU)).unwrap();
        assert_eq!(fit.whole_step(), half);
        assert!(
            (fit.misalignment_deg() - 2.0).abs() <= 1e-9,
            "{}",
            fit.misalignment_deg()
        );
        assert!((fit.alignment_angle_deg() - 180.0).abs() <= 2.0 + 1e-9);
        // M = A S^T = the 2-degree turn about (1, 2, 2) / 3 in the body frame.
        let axis = fit.misalignment_axis();
        assert!(
            (dot(axis, [1.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0]) - 1.0).abs() <= 1e-9,
            "{axis:?}"
        );
    }

    #[test]
    fn the_decomposition_is_a_rotation_times_an_upper_triangular_matrix() {
        let mut rng = stream_rng(22, 1);
        for _ in 0..1000 {
            let k: Mat3 = std::array::from_fn(|i| {
                std::array::from_fn(|j| {
                    f64::from(u8::from(i == j))
                        + 0.3 * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng)
                })
            });
            let Some((p, a)) = decompose(&k) else {
                assert!(det(&k) <= 0.0, "{k:?}");
                continue;
            };
            let ap = mat_mul(&a, &p);
            let kap = mat_mul(&k, &ap);
            let cond = {
                let inv: Mat3 = std::array::from_fn(|i| std::array::from_fn(|j| ap[i][j]));
                let f = |m: &Mat3| m.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
                f(&k) * f(&inv)
            };
            assert!(
                max_abs_diff(&kap, &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]) <= 64.0 * f64::EPSILON * cond
            );
            let ata = mat_mul(&transpose(&a), &a);
            assert!(max_abs_diff(&ata, &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]) <= 64.0 * f64::EPSILON);
            assert!(det(&a) > 0.0);
            assert!(p[1][0] == 0.0 && p[2][0] == 0.0 && p[2][1] == 0.0 && (0..3).all(|i| p[i][i] > 0.0));
            // The rotation vector turns back into A.
            let w = rotation_vector(&a);
            let back = about(w.map(|x| x / norm(w)), norm(w).to_degrees());
            assert!(norm(w) == 0.0 || max_abs_diff(&back, &a) <= 1e-9, "{a:?}");
        }
    }

    /// `(rms z, count)` of `z`.
    fn rms(z: &[f64]) -> f64 {
        (z.iter().map(|v| v * v).sum::<f64>() / z.len() as f64).sqrt()
    }

    /// Over 200 seeded logs of 150 readings at [P1]'s noise: the rms over the logs of
    /// `(estimate - truth) / std error` of every K entry, O, F (fitted), psi, S and the
    /// misalignment angle lies within the 99.9 % band of `sqrt(chi2_200 / 200)`.
    fn honesty(fitted: bool) {
        let (model, a, k) = truth();
        let angle = norm(rotation_vector(&a)).to_degrees();
        let logs = 200;
        let mut z: Vec<Vec<f64>> = vec![Vec::new(); 22];
        let mut noise = Vec::new();
        for log in 0..logs {
            let mut rng = stream_rng(2022, 10 + u64::from(fitted) * 1000 + log);
            let c = attitudes(150, &mut rng);
            let m = readings(&k, model.bias_nt(), &c, paper::SIGMA_NT, &mut rng);
            let field = if fitted {
                ReferenceField::Fitted {
                    magnitude: norm(FIELD_ENU),
                }
            } else {
                ReferenceField::Given(FIELD_ENU)
            };
            let fit = fit_vector(&m, &c, field).unwrap();
            assert!(fit.identifiable, "{}", fit.verdict);
            let s = fit.std_error.unwrap();
            let e = fit.error_model();
            let mut push = |i: usize, est: f64, truth: f64, se: f64| z[i].push((est - truth) / se);
            for i in 0..3 {
                for j in 0..3 {
                    push(3 * i + j, fit.k[i][j], k[i][j], s.k[i][j]);
                }
                push(9 + i, fit.bias[i], model.bias_nt()[i], s.bias[i]);
                push(12 + i, e.psi_deg()[i], model.psi_deg()[i], s.psi_deg[i]);
                push(15 + i, e.scale()[i], model.scale()[i], s.scale[i]);
                if fitted {
                    push(18 + i, fit.field[i], FIELD_ENU[i], s.field[i]);
                }
            }
            push(21, fit.misalignment_deg(), angle, s.misalignment_deg);
            noise.push(fit.noise.unwrap());
        }
        let chi = ChiSquared::new(logs as f64).unwrap();
        let band = (
            (chi.inverse_cdf(0.0005) / logs as f64).sqrt(),
            (chi.inverse_cdf(0.9995) / logs as f64).sqrt(),
        );
        for (i, zi) in z.iter().enumerate().filter(|(_, zi)| !zi.is_empty()) {
            let r = rms(zi);
            assert!(
                band.0 <= r && r <= band.1,
                "unknown {i} (fitted {fitted}): rms z {r}, band {band:?}"
            );
        }
        // The noise estimate: its mean within 4 standard errors of the truth.
        let mean = noise.iter().sum::<f64>() / logs as f64;
        let sd = (noise.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (logs - 1) as f64).sqrt();
        assert!(
            (mean - paper::SIGMA_NT).abs() <= 4.0 * sd / (logs as f64).sqrt(),
            "{mean} +- {sd}"
        );
    }

    #[test]
    fn standard_errors_match_the_scatter_with_the_field_given() {
        honesty(false);
    }

    #[test]
    fn standard_errors_match_the_scatter_with_the_field_fitted() {
        honesty(true);
    }

    #[test]
    fn attitudes_that_do_not_determine_the_sensor_are_refused_naming_what_is_open() {
        let (model, _, k) = truth();
        let mut rng = stream_rng(22, 2);
        let magnitude = norm(FIELD_ENU);
        let one = attitudes(1, &mut rng)[0];
        let same = vec![one; 30];
        let yaw: Vec<Mat3> = (0..30).map(|i| about([0.0, 0.0, 1.0], 12.0 * f64::from(i))).collect();
        let tilted: Vec<Mat3> = (0..30).map(|i| about([0.6, 0.0, 0.8], 12.0 * f64::from(i))).collect();
        for (name, c) in [("same", &same), ("yaw", &yaw), ("tilted axis", &tilted)] {
            let m = readings(&k, model.bias_nt(), c, paper::SIGMA_NT, &mut rng);
            for field in [ReferenceField::Given(FIELD_ENU), ReferenceField::Fitted { magnitude }] {
                match fit_vector(&m, c, field) {
                    Err(VectorError::NotDetermined { weakest }) => {
                        assert!(
                            weakest.contains("at no cost") || weakest.contains("at all"),
                            "{name}: {weakest}"
                        );
                    }
                    Ok(fit) => assert!(!fit.identifiable, "{name} {field:?}: {}", fit.verdict),
                    Err(e) => panic!("{name} {field:?}: {e}"),
                }
            }
        }
        // Turns about two axes only, 90 degrees each: enough with the field given.
        let two: Vec<Mat3> = (0..60)
            .map(|i| {
                let axis = if i % 2 == 0 { [1.0, 0.0, 0.0] } else { [0.0, 0.0, 1.0] };
                about(axis, 6.0 * f64::from(i))
            })
            .collect();
        let m = readings(&k, model.bias_nt(), &two, paper::SIGMA_NT, &mut rng);
        assert!(
            fit_vector(&m, &two, ReferenceField::Given(FIELD_ENU))
                .unwrap()
                .identifiable
        );
    }

    #[test]
    fn bad_inputs_are_errors_naming_them() {
        let (model, _, k) = truth();
        let mut rng = stream_rng(22, 3);
        let c = attitudes(10, &mut rng);
        let m = readings(&k, model.bias_nt(), &c, paper::SIGMA_NT, &mut rng);
        let given = ReferenceField::Given(FIELD_ENU);
        let e = fit_vector(&m[..9], &c, given).unwrap_err();
        assert!(
            matches!(
                e,
                VectorError::LengthMismatch {
                    readings: 9,
                    attitudes: 10
                }
            ),
            "{e}"
        );
        let e = fit_vector(&m[..4], &c[..4], given).unwrap_err();
        assert!(e.to_string().contains("4 readings with an attitude, at least 5"), "{e}");
        let mut bad = m.clone();
        bad[3][1] = f64::NAN;
        assert!(matches!(
            fit_vector(&bad, &c, given),
            Err(VectorError::NonFiniteReading { index: 3, .. })
        ));
        let mut reflected = c.clone();
        reflected[2][0] = reflected[2][0].map(|v| -v);
        assert!(matches!(
            fit_vector(&m, &reflected, given),
            Err(VectorError::NotARotation { index: 2, .. })
        ));
        for f in [
            ReferenceField::Given([0.0; 3]),
            ReferenceField::Fitted { magnitude: f64::NAN },
        ] {
            assert!(
                matches!(fit_vector(&m, &c, f), Err(VectorError::InvalidField { .. })),
                "{f:?}"
            );
        }
        // A negated reading axis against a known field: a left-handed frame.
        let flipped: Vec<Vec3> = m.iter().map(|r| [r[0], r[1], -r[2]]).collect();
        let e = fit_vector(&flipped, &c, given).unwrap_err();
        assert!(matches!(e, VectorError::LeftHanded { .. }), "{e}");
        // Readings at the floating-point limit of the field's scale: no panic.
        let huge: Vec<Vec3> = m.iter().map(|r| r.map(|v| v * 1e300)).collect();
        let _ = fit_vector(&huge, &c, ReferenceField::Fitted { magnitude: 1e-300 });
    }
}
