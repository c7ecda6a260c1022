//! Step 1: the linear least-squares ellipsoid fit of \[P1\] eq. (9)-(11), and the extraction of
//! `O`, `G`, `P` from `theta` (CONVENTIONS.md).
#![allow(non_snake_case)]

use faer::Mat;
use faer::linalg::solvers::SolveLstsq;

use super::errors::CalibrationError;
use super::{Estimate, validate};
use crate::linear_model::{UNKNOWNS, design_matrix};
use crate::small::{Mat3, Vec3, cholesky_in_place, dot, mat_vec, scale, solve3};

/// Step 1 of the two-step calibration: `theta = argmin |W - H theta|`, \[P1\] eq. (10)-(11), then
/// the quadric `u^T A u + a^T u = 1` in readings `u = b / R`, centre `O = -A^-1 a / 2`,
/// `G = A / (1 + O^T A O)` and `P` its upper Cholesky factor (`G = P^T P`, positive diagonal).
///
/// `field_magnitude_nt` is `R` of \[P1\] eq. (7).
///
/// # Deviation from \[P1\]
/// \[P1\] eq. (11) writes the normal equations `(H^T H)^-1 H^T W`; this solves the same least-squares
/// problem by column-pivoted Householder QR (faer), which does not square the condition number
/// and reveals a rank-deficient `H`. The readings are divided by `R` first (CONVENTIONS.md): the
/// fitted quadric is the same, the arithmetic better scaled.
///
/// # Errors
/// Too few readings, non-finite input, rank-deficient `H`, or a quadric that is not an ellipsoid.
pub fn linear_fit(readings: &[Vec3], field_magnitude_nt: f64) -> Result<Estimate, CalibrationError> {
    validate(readings, field_magnitude_nt)?;
    let R = field_magnitude_nt;
    let H = design_matrix(readings, R);
    let qr = H.col_piv_qr();

    // Numerical rank from the pivoted R's diagonal, at the usual threshold max(m, n) eps |r_11|.
    let r_diag: Vec<f64> = {
        let r = qr.thin_R();
        (0..UNKNOWNS).map(|i| r[(i, i)].abs()).collect()
    };
    let tol = readings.len().max(UNKNOWNS) as f64 * f64::EPSILON * r_diag[0];
    let rank = r_diag.iter().filter(|&&d| d > tol).count();
    if rank < UNKNOWNS {
        return Err(CalibrationError::RankDeficient { rank, needed: UNKNOWNS });
    }

    // W = (1, ..., 1)^T, [P1] eq. (10); theta = argmin |W - H theta|, eq. (11).
    let W = Mat::<f64>::from_fn(readings.len(), 1, |_, _| 1.0);
    let theta = qr.solve_lstsq(&W);
    let t: [f64; UNKNOWNS] = std::array::from_fn(|i| theta[(i, 0)]);

    let (P, O_u) = ellipsoid_from_theta(&t)?;
    Ok(Estimate::new(P, scale(R, O_u), readings, R))
}

/// From `theta` of \[P1\] eq. (9) (readings in units of `R`) to `P` (upper triangular, positive
/// diagonal) and the centre `O / R`.
///
/// `theta` holds the quadric `t1 x^2 + t2 xy + t3 xz + t4 y^2 + t5 yz + t6 z^2 + t7 x + t8 y + t9 z = 1`.
pub(crate) fn ellipsoid_from_theta(t: &[f64; UNKNOWNS]) -> Result<(Mat3, Vec3), CalibrationError> {
    let A: Mat3 = [
        [t[0], t[1] / 2.0, t[2] / 2.0],
        [t[1] / 2.0, t[3], t[4] / 2.0],
        [t[2] / 2.0, t[4] / 2.0, t[5]],
    ];
    let a = [t[6], t[7], t[8]];
    // Centre: grad(u^T A u + a^T u) = 0  =>  O = -A^-1 a / 2.
    let O = solve3(&A, scale(-0.5, a)).ok_or(CalibrationError::NotPositiveDefinite {
        reason: "quadratic part singular, no centre",
    })?;
    // (u - O)^T A (u - O) = 1 + O^T A O.
    let level = 1.0 + dot(O, mat_vec(&A, O));
    let G: Mat3 = A.map(|row| row.map(|v| v / level));
    let mut L = G;
    if !level.is_finite() || !cholesky_in_place(&mut L) {
        return Err(CalibrationError::NotPositiveDefinite {
            reason: "Cholesky factorisation of G failed",
        });
    }
    // G = L L^T = P^T P with P = L^T upper triangular.
    let P = [
        [L[0][0], L[1][0], L[2][0]],
        [0.0, L[1][1], L[2][1]],
        [0.0, 0.0, L[2][2]],
    ];
    Ok((P, O))
}
