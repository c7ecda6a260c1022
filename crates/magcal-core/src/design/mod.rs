//! Design of the calibration manoeuvre, \[P1\] sections III-IV: criteria of a set of m attitudes
//! ([`DesignProblem`], [`DesignCriterion`]), simple design sources ([`sources`]), the paper's
//! particle swarm ([`pso`]) and a local optimiser that reaches the D-optimum ([`optimum`]).
//!
//! A design is a list of attitudes. Optimisers work on the flat vector of \[P1\] eq. (16),
//! `X = [r_1, y_1, p_1, ..., r_m, y_m, p_m]` in radians.
#![allow(non_snake_case)]
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

pub mod approximate;
pub mod lanes;
pub mod optimum;
pub mod plan;
pub mod pso;
pub mod sources;
pub mod tour;

use crate::attitude::{Attitude, AttitudeBox};
use crate::error::ParameterError;
use crate::field::ReferenceField;
use crate::linear_model::{InformationMatrix, LN_DET_UNIT_POWER, Moments, UNKNOWNS};
use crate::sensor::ErrorModel;
use crate::small::{Mat3, Mat9, Vec3, cholesky_in_place, ln_det_spd, mat_vec};

/// An optimality criterion of the linear model's information matrix, \[P1\] III.A. Every criterion is
/// a value to **minimise**.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub enum DesignCriterion {
    /// D-optimality, \[P1\] eq. (14)-(15): `g = -ln det M_F`, `H` in nT (natural log).
    D,
    /// A-optimality: `trace(M_F^-1)` of readings scaled by `R` (unit-free).
    A,
    /// E-optimality: `-lambda_min(M_F)` of readings scaled by `R` (unit-free).
    E,
}

impl DesignCriterion {
    /// `d`, `a` or `e`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::D => "d",
            Self::A => "a",
            Self::E => "e",
        }
    }
}

/// The design problem: choose `m` attitudes inside `bounds` that minimise a criterion of the
/// noise-free readings of the nominal sensor model.
#[derive(Debug, Clone)]
pub struct DesignProblem {
    field: ReferenceField,
    model: ErrorModel,
    bounds: AttitudeBox,
    m: usize,
    // Precomputed for the inner loop: readings divided by R, u = (K/R) C(att) B^n + O/R.
    k_scaled: Mat3,
    o_scaled: Vec3,
    ln_r: f64,
}

impl DesignProblem {
    /// A problem of `m` attitudes (at least 9, the unknowns of \[P1\] eq. (9)) in `bounds`, with
    /// readings of `model` in `field`.
    ///
    /// # Errors
    /// [`ParameterError::TooSmall`] when `m < 9`.
    pub fn new(
        field: ReferenceField,
        model: ErrorModel,
        bounds: AttitudeBox,
        m: usize,
    ) -> Result<Self, ParameterError> {
        if m < UNKNOWNS {
            return Err(ParameterError::TooSmall {
                name: "m",
                min: UNKNOWNS,
                value: m,
            });
        }
        let r = field.magnitude();
        Ok(Self {
            field,
            model,
            bounds,
            m,
            k_scaled: model.K().map(|row| row.map(|v| v / r)),
            o_scaled: model.bias_nt().map(|v| v / r),
            ln_r: r.ln(),
        })
    }

    /// The reference field.
    pub fn field(&self) -> &ReferenceField {
        &self.field
    }

    /// The nominal sensor model whose readings define `M_F`.
    pub fn model(&self) -> &ErrorModel {
        &self.model
    }

    /// The attitude box.
    pub fn bounds(&self) -> &AttitudeBox {
        &self.bounds
    }

    /// Attitudes per design, `m`.
    pub fn m(&self) -> usize {
        self.m
    }

    /// Dimension of the search space, `3m` (\[P1\] eq. (16)).
    pub fn dimension(&self) -> usize {
        3 * self.m
    }

    /// What turns `ln det` of the R-scaled information into `ln det M_F` in nT: `30 ln R` (see
    /// [`InformationMatrix::ln_det_nt`]).
    pub(crate) fn ln_det_shift(&self) -> f64 {
        LN_DET_UNIT_POWER * self.ln_r
    }

    /// The body-frame field direction at angles `(roll, yaw, pitch)` (radians), with the field's yaw
    /// offset: the scaled reading before `K` and `O`.
    #[inline]
    pub(crate) fn body_field(&self, roll: f64, yaw: f64, pitch: f64) -> Vec3 {
        self.field.body_field(&Attitude { roll, yaw, pitch })
    }

    /// The reading of one attitude divided by `R`: `u = (K B^b + O) / R`.
    #[inline]
    pub(crate) fn scaled_reading(&self, roll: f64, yaw: f64, pitch: f64) -> Vec3 {
        let b = self.body_field(roll, yaw, pitch);
        let kb = mat_vec(&self.k_scaled, b);
        [
            kb[0] + self.o_scaled[0],
            kb[1] + self.o_scaled[1],
            kb[2] + self.o_scaled[2],
        ]
    }

    /// The [`RowJet`] of attitude `a`.
    pub(crate) fn row_jet(&self, a: &Attitude) -> RowJet<'_> {
        let (b, db) = self.field.body_field_and_derivatives(a);
        let kb = mat_vec(&self.k_scaled, b);
        let u = [
            kb[0] + self.o_scaled[0],
            kb[1] + self.o_scaled[1],
            kb[2] + self.o_scaled[2],
        ];
        RowJet {
            ks: &self.k_scaled,
            u,
            h: crate::linear_model::regression_row(u),
            db,
        }
    }

    /// `K / R`.
    pub(crate) fn k_scaled(&self) -> &Mat3 {
        &self.k_scaled
    }

    /// `O / R`.
    pub(crate) fn o_scaled(&self) -> Vec3 {
        self.o_scaled
    }

    /// `M_F` of the R-scaled readings of `x` (\[P1\] eq. (16) layout), both triangles, through
    /// [`Moments`]. Allocation-free.
    #[inline]
    pub fn information(&self, x: &[f64]) -> Mat9 {
        let mut moments = Moments::default();
        for a in x.chunks_exact(3) {
            moments.add(self.scaled_reading(a[0], a[1], a[2]));
        }
        moments.information()
    }

    /// `ln det M_F` in nT of the design `x`; `-inf` for a singular design. Allocation-free.
    #[inline]
    pub fn ln_det(&self, x: &[f64]) -> f64 {
        self.ln_det_of(&self.information(x))
    }

    /// `ln det M_F` in nT from the R-scaled `M_F`.
    #[inline]
    fn ln_det_of(&self, M: &Mat9) -> f64 {
        match ln_det_spd(M) {
            Some(v) => v + self.ln_det_shift(),
            None => f64::NEG_INFINITY,
        }
    }

    /// The value of `criterion` for design `x` (radians, \[P1\] eq. (16) layout): the fitness the
    /// optimisers minimise. `+inf` for a singular design.
    ///
    /// Allocation-free for every criterion (tested in `tests/no_allocation.rs`).
    ///
    /// # Panics
    /// If `x.len() != 3m` (a caller bug).
    #[track_caller]
    pub fn fitness(&self, criterion: DesignCriterion, x: &[f64]) -> f64 {
        assert_eq!(x.len(), self.dimension(), "design vector length must be 3m");
        self.criterion_of(criterion, &self.information(x))
    }

    /// The value of `criterion` for the R-scaled information matrix `M`.
    fn criterion_of(&self, criterion: DesignCriterion, M: &Mat9) -> f64 {
        match criterion {
            DesignCriterion::D => -self.ln_det_of(M),
            DesignCriterion::A => {
                let mut L = *M;
                if !cholesky_in_place(&mut L) {
                    return f64::INFINITY;
                }
                trace_of_inverse(&L)
            }
            DesignCriterion::E => match smallest_eigenvalue(M) {
                Some(lambda) if lambda > 0.0 => -lambda,
                _ => f64::INFINITY,
            },
        }
    }

    /// All criteria of a design given as attitudes.
    ///
    /// # Panics
    /// If the design does not have `m` attitudes.
    #[track_caller]
    pub fn evaluate(&self, design: &[Attitude]) -> DesignMetrics {
        let x = to_vector(design);
        assert_eq!(x.len(), self.dimension(), "design must have m attitudes");
        let M = self.information(&x);
        DesignMetrics {
            ln_det_mf: self.ln_det_of(&M),
            a: self.criterion_of(DesignCriterion::A, &M),
            e: -self.criterion_of(DesignCriterion::E, &M),
        }
    }

    /// All criteria of a design with replication: `counts[i]` readings at `attitudes[i]` (their
    /// sum, not this problem's `m`, is the readings). The same as [`Self::evaluate`] of the expanded design, with the rounding of `k`
    /// attitudes rather than of `m` readings (which a plan of 100,000 readings in a box that
    /// hardly identifies the model, `cond(M_F)` near 1e10, needs: measured, 3e-3 in `ln det`).
    /// A design of one reading per attitude gives exactly what [`Self::evaluate`] gives.
    ///
    /// # Panics
    /// If the lengths differ.
    #[track_caller]
    pub fn evaluate_replicated(&self, attitudes: &[Attitude], counts: &[usize]) -> DesignMetrics {
        assert_eq!(attitudes.len(), counts.len(), "one count per attitude");
        let mut moments = Moments::default();
        for (a, &n) in attitudes.iter().zip(counts) {
            moments.add_repeated(self.scaled_reading(a.roll, a.yaw, a.pitch), n);
        }
        let M = moments.information();
        DesignMetrics {
            ln_det_mf: self.ln_det_of(&M),
            a: self.criterion_of(DesignCriterion::A, &M),
            e: -self.criterion_of(DesignCriterion::E, &M),
        }
    }

    /// `M_F` of a design, for reporting (scaled by `R`, see [`InformationMatrix`]).
    pub fn information_matrix(&self, design: &[Attitude]) -> InformationMatrix {
        let readings = self.model.measure_all(&self.field.body_fields(design));
        InformationMatrix::from_readings(&readings, self.field.magnitude())
    }
}

/// One attitude's R-scaled reading `u = (K B^b + O) / R`, its regression row `h` (\[P1\] eq. (9))
/// and what turns a vector `w` into `2 w^T dh / d(roll, yaw, pitch)`: the gradient of every
/// criterion the optimisers and the certificate use (`w = M^-1 h` for `ln det M` and the variance
/// function, `M^-2 h` for `trace(M^-1)`, `(v^T h) v` for an eigenvalue).
pub(crate) struct RowJet<'a> {
    ks: &'a Mat3,
    u: Vec3,
    /// The regression row.
    pub h: [f64; UNKNOWNS],
    /// `dB^b / d(roll, yaw, pitch)`.
    db: [Vec3; 3],
}

impl RowJet<'_> {
    /// `2 w^T dh/d theta` for theta = roll, yaw, pitch: `q = (dh/du)^T w`, then
    /// `2 (K/R)^T q . dB/d theta` (`du/d theta = (K/R) dB/d theta`).
    #[inline]
    pub(crate) fn gradient(&self, w: &[f64; UNKNOWNS]) -> [f64; 3] {
        let [ux, uy, uz] = self.u;
        // From h = (x^2, xy, xz, y^2, yz, z^2, x, y, z).
        let q = [
            2.0 * ux * w[0] + uy * w[1] + uz * w[2] + w[6],
            ux * w[1] + 2.0 * uy * w[3] + uz * w[4] + w[7],
            ux * w[2] + uy * w[4] + 2.0 * uz * w[5] + w[8],
        ];
        let kq = crate::small::mat_t_vec(self.ks, q);
        let db = &self.db;
        std::array::from_fn(|k| 2.0 * (kq[0] * db[k][0] + kq[1] * db[k][1] + kq[2] * db[k][2]))
    }
}

/// Bytes of stack scratch for faer's 9x9 eigenvalue solver: what `self_adjoint_evd_scratch` asks
/// (about 2 KiB in faer 0.24), with room to spare; a test checks that it fits.
const EVD_SCRATCH_BYTES: usize = 8192;

/// The smallest eigenvalue of the symmetric `M` (lower triangle read), by faer's self-adjoint
/// eigenvalue solver (eigenvalues only, ascending) with its scratch space on the stack rather than
/// in the `MemBuffer` faer's convenience method allocates. `None` if the solver does not converge.
fn smallest_eigenvalue(M: &Mat9) -> Option<f64> {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::linalg::evd::{ComputeEigenvectors, self_adjoint_evd, self_adjoint_evd_scratch};

    let params = Default::default();
    let req = self_adjoint_evd_scratch::<f64>(UNKNOWNS, ComputeEigenvectors::No, faer::Par::Seq, params);
    let mut scratch = [std::mem::MaybeUninit::<u8>::uninit(); EVD_SCRATCH_BYTES];
    // Only if a future faer asked for more: correct, but allocating.
    let mut heap;
    let stack = if MemStack::new(&mut scratch).can_hold(req) {
        MemStack::new(&mut scratch)
    } else {
        heap = MemBuffer::new(req);
        MemStack::new(&mut heap)
    };
    let mut eigenvalues = [0.0; UNKNOWNS];
    self_adjoint_evd(
        faer::MatRef::from_row_major_slice(M.as_flattened(), UNKNOWNS, UNKNOWNS),
        faer::ColMut::from_slice_mut(&mut eigenvalues).as_diagonal_mut(),
        None,
        faer::Par::Seq,
        stack,
        params,
    )
    .ok()?;
    Some(eigenvalues[0])
}

/// `trace(M^-1)` from the Cholesky factor `L` (lower triangle): the squared Frobenius norm of `L^-1`.
fn trace_of_inverse(L: &Mat9) -> f64 {
    let mut total = 0.0;
    // Column j of L^-1 by forward substitution of e_j; entries above j are zero.
    for j in 0..UNKNOWNS {
        let mut y = [0.0; UNKNOWNS];
        y[j] = 1.0 / L[j][j];
        total += y[j] * y[j];
        for i in (j + 1)..UNKNOWNS {
            let mut s = 0.0;
            for k in j..i {
                s -= L[i][k] * y[k];
            }
            y[i] = s / L[i][i];
            total += y[i] * y[i];
        }
    }
    total
}

/// Criteria of one design.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct DesignMetrics {
    /// `ln det M_F`, `H` in nT (\[P1\] eq. (12), (14)).
    pub ln_det_mf: f64,
    /// `trace(M_F^-1)`, R-scaled readings.
    pub a: f64,
    /// `lambda_min(M_F)`, R-scaled readings.
    pub e: f64,
}

/// `ln det (m I) = 9 ln m`: the part of `ln det M_F` that the count `m` of readings gives,
/// `ln det M_F = ln det (M_F / m) + 9 ln m`.
pub fn ln_det_of_count(m: usize) -> f64 {
    UNKNOWNS as f64 * (m as f64).ln()
}

/// One attitude per reading of a design that holds `attitudes[i]` for `counts[i]` readings, in
/// that order: the readings [`DesignProblem::evaluate_replicated`] counts, one by one.
///
/// # Panics
/// If the lengths differ.
#[track_caller]
pub fn replicated(attitudes: &[Attitude], counts: &[usize]) -> Vec<Attitude> {
    assert_eq!(attitudes.len(), counts.len(), "one count per attitude");
    attitudes
        .iter()
        .zip(counts)
        .flat_map(|(a, &n)| std::iter::repeat_n(*a, n))
        .collect()
}

/// `ln det (M_F / m) = ln det M_F - 9 ln m` of a design of `m` readings: its information per
/// reading, which designs of different sizes share (nT, as `ln_det_mf`).
pub fn ln_det_per_reading(ln_det_mf: f64, m: usize) -> f64 {
    ln_det_mf - ln_det_of_count(m)
}

/// D-efficiency of a design against a reference: `(det M_F / det M_F*)^(1/9)`, from the natural
/// logs of the determinants.
pub fn d_efficiency(ln_det_mf: f64, reference_ln_det_mf: f64) -> f64 {
    ((ln_det_mf - reference_ln_det_mf) / UNKNOWNS as f64).exp()
}

/// The flat vector of \[P1\] eq. (16) from attitudes.
pub fn to_vector(design: &[Attitude]) -> Vec<f64> {
    design.iter().flat_map(|a| [a.roll, a.yaw, a.pitch]).collect()
}

/// Attitudes from the flat vector of \[P1\] eq. (16), eq. (20).
///
/// # Panics
/// If the length is not a multiple of 3.
#[track_caller]
pub fn from_vector(x: &[f64]) -> Vec<Attitude> {
    assert!(
        x.len().is_multiple_of(3),
        "design vector length must be a multiple of 3"
    );
    x.chunks_exact(3)
        .map(|a| Attitude {
            roll: a[0],
            yaw: a[1],
            pitch: a[2],
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::paper;
    use faer::Side;
    use faer::linalg::solvers::DenseSolveCore;

    pub(crate) fn paper_problem() -> DesignProblem {
        DesignProblem::new(paper::changsha_field(), paper::true_error_model(), paper::auv_box(), 9).unwrap()
    }

    #[test]
    fn fitness_matches_the_linear_model_and_check_values() {
        let p = paper_problem();
        for (design, want) in [
            (paper::uniformity_design(), 303.4800),
            (paper::table2_d_optimal(), 298.9240),
        ] {
            let x = to_vector(&design);
            assert!((p.ln_det(&x) - want).abs() < 5e-5);
            let info = p.information_matrix(&design);
            let direct = info.ln_det_nt();
            // Two summation orders of the same readings: |d ln det| <= trace(M^-1 dM) <= 9 cond(M) eps.
            let cond = crate::linear_model::cond_2(info.to_faer().as_ref());
            let tol = 4.0 * 9.0 * cond * f64::EPSILON;
            assert!(
                (p.ln_det(&x) - direct).abs() <= tol,
                "{} vs {direct}, tol {tol:e}",
                p.ln_det(&x)
            );
            assert!((p.fitness(DesignCriterion::D, &x) + p.ln_det(&x)).abs() <= f64::EPSILON * 400.0);
        }
    }

    #[test]
    fn a_and_e_criteria_agree_with_faer() {
        let p = paper_problem();
        for design in [paper::uniformity_design(), paper::table2_d_optimal()] {
            let m = p.information_matrix(&design).to_faer();
            let inv = m.as_ref().llt(Side::Lower).unwrap().inverse();
            let trace: f64 = (0..9).map(|i| inv[(i, i)]).sum();
            let ev = m.self_adjoint_eigenvalues(Side::Lower).unwrap();
            let metrics = p.evaluate(&design);
            assert!((metrics.a - trace).abs() <= 1e-8 * trace, "{} {}", metrics.a, trace);
            // lambda_min from the eigen solver is accurate to eps * lambda_max.
            assert!(
                (metrics.e - ev[0]).abs() <= 1e3 * f64::EPSILON * ev[8],
                "{} {}",
                metrics.e,
                ev[0]
            );
            // A and E are positive and ordered as their definitions demand: trace(M^-1) >= 1/lambda_min.
            assert!(metrics.a >= 1.0 / metrics.e * (1.0 - 1e-12));
        }
    }

    #[test]
    fn the_eigenvalue_scratch_fits_on_the_stack() {
        use faer::linalg::evd::{ComputeEigenvectors, self_adjoint_evd_scratch};
        let req =
            self_adjoint_evd_scratch::<f64>(UNKNOWNS, ComputeEigenvectors::No, faer::Par::Seq, Default::default());
        // What a buffer of EVD_SCRATCH_BYTES can hold whatever its start address.
        assert!(
            req.unaligned_bytes_required() <= EVD_SCRATCH_BYTES,
            "{} bytes",
            req.unaligned_bytes_required()
        );
    }

    #[test]
    fn d_efficiency_against_itself_is_one() {
        let p = paper_problem();
        let l = p.ln_det(&to_vector(&paper::uniformity_design()));
        assert!((d_efficiency(l, l) - 1.0).abs() <= f64::EPSILON);
        // det ratio e^9 -> efficiency e.
        assert!((d_efficiency(l + 9.0, l) - std::f64::consts::E).abs() <= 4.0 * f64::EPSILON);
    }

    #[test]
    fn singular_designs_have_infinite_fitness() {
        let p = paper_problem();
        let same = to_vector(&[Attitude::from_degrees(1.0, 2.0, 3.0); 9]);
        for c in [DesignCriterion::D, DesignCriterion::A] {
            assert!(p.fitness(c, &same) > 1e12, "{c:?}: {}", p.fitness(c, &same));
        }
        // E: lambda_min is zero to working precision (or the matrix is not positive definite).
        assert!(p.fitness(DesignCriterion::E, &same) >= -1e-12);
        assert!(DesignProblem::new(paper::changsha_field(), paper::true_error_model(), paper::auv_box(), 8).is_err());
    }

    #[test]
    fn vector_round_trip() {
        let d = paper::table2_d_optimal();
        assert_eq!(from_vector(&to_vector(&d)), d);
    }
}
