//! Step 1: the linear least-squares ellipsoid fit of \[P1\] eq. (9)-(11), and the extraction of
//! `O`, `G`, `P` from `theta` (docs/conventions.md).
#![allow(non_snake_case)]

use faer::Mat;
use faer::linalg::solvers::SolveLstsq;
use rayon::prelude::*;

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
/// and reveals a rank-deficient `H`. The readings are divided by `R` first (docs/conventions.md): the
/// fitted quadric is the same, the arithmetic better scaled.
///
/// # Errors
/// Too few readings, non-finite input, rank-deficient `H`, or a quadric that is not an ellipsoid.
pub fn linear_fit(readings: &[Vec3], field_magnitude_nt: f64) -> Result<Estimate, CalibrationError> {
    validate(readings, field_magnitude_nt)?;
    if readings.len() > CHUNKED_ABOVE {
        return linear_fit_chunked(readings, field_magnitude_nt, CHUNK);
    }
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

/// Above this many readings, step 1 works in chunks ([`linear_fit_chunked`]).
pub const CHUNKED_ABOVE: usize = 1 << 16;
/// Rows per chunk.
const CHUNK: usize = 1 << 14;

/// [`linear_fit`] for long logs, in memory independent of their length: the Householder QR of
/// `[H | W]` (m x 10) is accumulated chunk by chunk, each chunk's rows stacked under the `R`
/// factor so far and factorised again (a tall-skinny QR), so that only `chunk + 10` rows are held
/// at a time instead of the m x 9 matrix `H` (72 bytes per reading, and as much again for its
/// factorisation). The final `R = [R_H, q; 0, rho]` gives `theta = R_H^-1 q`, the least-squares
/// solution of \[P1\] eq. (11), and the rank from the column-pivoted QR of `R_H` (whose singular
/// values are `H`'s). The same numbers as [`linear_fit`] to rounding (tested), not bit for bit.
///
/// # Errors
/// As [`linear_fit`].
pub fn linear_fit_chunked(
    readings: &[Vec3],
    field_magnitude_nt: f64,
    chunk: usize,
) -> Result<Estimate, CalibrationError> {
    validate(readings, field_magnitude_nt)?;
    let R = field_magnitude_nt;
    let n = UNKNOWNS + 1;
    // Each chunk's triangle in parallel, then the triangle of the chunks' triangles stacked in
    // chunk order (a two-level tall-skinny QR): the same bits on any number of threads.
    let triangles: Vec<Mat<f64>> = readings
        .par_chunks(chunk.max(n))
        .map(|rows| {
            let block = Mat::<f64>::from_fn(rows.len(), n, |k, j| {
                if j == UNKNOWNS {
                    1.0
                } else {
                    crate::linear_model::regression_row(rows[k].map(|v| v / R))[j]
                }
            });
            block.qr().thin_R().to_owned()
        })
        .collect();
    let mut stacked = Mat::<f64>::zeros(triangles.iter().map(|t| t.nrows()).sum(), n);
    let mut top = 0;
    for t in &triangles {
        for i in 0..t.nrows() {
            for j in 0..n {
                stacked[(top + i, j)] = t[(i, j)];
            }
        }
        top += t.nrows();
    }
    let r = if triangles.len() == 1 {
        stacked
    } else {
        stacked.qr().thin_R().to_owned()
    };
    let rh = Mat::<f64>::from_fn(UNKNOWNS, UNKNOWNS, |i, j| if i <= j { r[(i, j)] } else { 0.0 });
    let r_diag: Vec<f64> = {
        let p = rh.col_piv_qr();
        let d = p.thin_R();
        (0..UNKNOWNS).map(|i| d[(i, i)].abs()).collect()
    };
    let tol = readings.len().max(UNKNOWNS) as f64 * f64::EPSILON * r_diag[0];
    let rank = r_diag.iter().filter(|&&d| d > tol).count();
    if rank < UNKNOWNS {
        return Err(CalibrationError::RankDeficient { rank, needed: UNKNOWNS });
    }
    // Back substitution R_H theta = q.
    let mut t = [0.0; UNKNOWNS];
    for i in (0..UNKNOWNS).rev() {
        let s: f64 = (i + 1..UNKNOWNS).map(|j| rh[(i, j)] * t[j]).sum();
        t[i] = (r[(i, UNKNOWNS)] - s) / rh[(i, i)];
    }
    let (P, O_u) = ellipsoid_from_theta(&t)?;
    Ok(Estimate::new(P, scale(R, O_u), readings, R))
}

/// The sphere nearest the readings in the algebraic sense, `|u - c|^2 = rho^2` (readings `u` in
/// units of `R`, fitted as `|d|^2 = 2 d . c' + k` about their mean `m`, `c = m + c'`), as an
/// estimate `P = I / rho`, `O = R c`: a start for step 2 where the readings cover too little of the
/// ellipsoid for the nine-parameter quadric of [`linear_fit`] to be one (a vehicle that barely
/// tilts; no error model of \[P1\]'s size fails to start from it).
///
/// # Errors
/// Too few readings, non-finite input, or readings in a plane (`RankDeficient`).
pub fn sphere_fit(readings: &[Vec3], field_magnitude_nt: f64) -> Result<Estimate, CalibrationError> {
    validate(readings, field_magnitude_nt)?;
    let R = field_magnitude_nt;
    let n = readings.len() as f64;
    let m = scale(
        1.0 / n,
        readings
            .iter()
            .fold([0.0; 3], |acc, &b| crate::small::add(acc, scale(1.0 / R, b))),
    );
    let mut ata = [[0.0; 4]; 4];
    let mut atb = [0.0; 4];
    for &b in readings {
        let d = crate::small::sub(scale(1.0 / R, b), m);
        let row = [2.0 * d[0], 2.0 * d[1], 2.0 * d[2], 1.0];
        let rhs = dot(d, d);
        for i in 0..4 {
            atb[i] += row[i] * rhs;
            for j in 0..4 {
                ata[i][j] += row[i] * row[j];
            }
        }
    }
    if !cholesky_in_place(&mut ata) {
        return Err(CalibrationError::RankDeficient { rank: 3, needed: 4 });
    }
    let y = crate::small::cholesky_solve(&ata, &atb);
    let c = [y[0], y[1], y[2]];
    let rho = (y[3] + dot(c, c)).sqrt();
    if !(rho.is_finite() && rho > 0.0) {
        return Err(CalibrationError::NotPositiveDefinite {
            reason: "no sphere through the readings",
        });
    }
    let P = [[1.0 / rho, 0.0, 0.0], [0.0, 1.0 / rho, 0.0], [0.0, 0.0, 1.0 / rho]];
    Ok(Estimate::new(P, scale(R, crate::small::add(m, c)), readings, R))
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

#[cfg(test)]
mod chunked_tests {
    use super::*;
    use crate::design::sources;
    use crate::paper;
    use crate::rng::stream_rng;

    #[test]
    fn the_chunked_fit_agrees_with_the_whole_one() {
        let field = paper::changsha_field();
        let truth = paper::true_error_model();
        let mut rng = stream_rng(17, 0);
        for (m, chunk) in [(9, 4), (37, 10), (5000, 700), (5000, 5000)] {
            let design = sources::random(&crate::AttitudeBox::full(), m, &mut rng);
            let readings = truth
                .noisy_readings(&field.body_fields(&design), 30.0, &mut rng)
                .unwrap();
            let (a, b) = (
                linear_fit(&readings, field.magnitude()).unwrap(),
                linear_fit_chunked(&readings, field.magnitude(), chunk).unwrap(),
            );
            for i in 0..3 {
                for j in 0..3 {
                    assert!((a.p[i][j] - b.p[i][j]).abs() <= 1e-9 * a.p[i][i].abs(), "{m}: P{i}{j}");
                }
                assert!(
                    (a.bias_nt[i] - b.bias_nt[i]).abs() <= 1e-9 * field.magnitude(),
                    "{m}: O{i}"
                );
            }
        }
        // A rank-deficient log is refused by both.
        let flat: Vec<Vec3> = (0..100).map(|i| [(i as f64).cos(), (i as f64).sin(), 0.0]).collect();
        assert!(matches!(
            linear_fit_chunked(&flat, 1.0, 16),
            Err(CalibrationError::RankDeficient { .. })
        ));
    }
}
