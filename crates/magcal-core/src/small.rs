//! Fixed-size kernels for the 3x3 sensor matrices and the 9x9 information matrix.
//!
//! faer works on heap-allocated matrices of any size; the per-trial and per-particle hot paths of
//! magcal only ever need 3x3 and 9x9 symmetric matrices, where an allocation and faer's dispatch cost
//! more than the arithmetic. These kernels are plain arrays, never allocate, and are tested against
//! faer (see the tests at the bottom of this file and `benches/calibration.rs` for the timings).
//! Everything of general size (the m x 9 regression matrix, its QR and SVD) goes through faer.
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

/// A 3-vector (nT for fields and biases, dimensionless for directions).
pub type Vec3 = [f64; 3];
/// A 3x3 matrix, row-major: `m[row][col]`.
pub type Mat3 = [[f64; 3]; 3];
/// A 9x9 matrix, row-major: the shape of the information matrix of \[P1\] eq. (12).
pub type Mat9 = [[f64; 9]; 9];

/// `a . b`.
#[inline]
pub fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Euclidean norm `|a|`.
#[inline]
pub fn norm(a: Vec3) -> f64 {
    dot(a, a).sqrt()
}

/// `a - b`.
#[inline]
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a + b`.
#[inline]
pub fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `s a`.
#[inline]
pub fn scale(s: f64, a: Vec3) -> Vec3 {
    [s * a[0], s * a[1], s * a[2]]
}

/// `M v`.
#[inline]
pub fn mat_vec(m: &Mat3, v: Vec3) -> Vec3 {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}

/// `M^T v`.
#[inline]
pub fn mat_t_vec(m: &Mat3, v: Vec3) -> Vec3 {
    [
        m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
        m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
        m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2],
    ]
}

/// `A B`.
#[inline]
pub fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for (i, row) in c.iter_mut().enumerate() {
        for (j, cij) in row.iter_mut().enumerate() {
            *cij = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    c
}

/// `A^T`.
#[inline]
pub fn transpose(a: &Mat3) -> Mat3 {
    [
        [a[0][0], a[1][0], a[2][0]],
        [a[0][1], a[1][1], a[2][1]],
        [a[0][2], a[1][2], a[2][2]],
    ]
}

/// Inverse of an upper-triangular 3x3 matrix, itself upper triangular.
///
/// Returns `None` when a diagonal entry is zero or the result is not finite.
pub fn upper_triangular_inverse(u: &Mat3) -> Option<Mat3> {
    let [[a, b, c], [_, d, e], [_, _, f]] = *u;
    // Back substitution, one diagonal entry at a time: products of diagonal entries such as
    // `a d f` underflow or overflow for entries near 1e-150 or 1e150 whose inverse is finite.
    let (ia, id, i_f) = (1.0 / a, 1.0 / d, 1.0 / f);
    let k12 = -e * id * i_f;
    let inv = [
        [ia, -b * id * ia, -(b * k12 + c * i_f) * ia],
        [0.0, id, k12],
        [0.0, 0.0, i_f],
    ];
    inv.iter().flatten().all(|x| x.is_finite()).then_some(inv)
}

/// Solves `A x = b` for a general 3x3 `A` by Cramer's rule (adequate at this size: the
/// determinant is checked against the scale of `A`).
///
/// Returns `None` when `A` is singular to working precision.
pub fn solve3(a: &Mat3, b: Vec3) -> Option<Vec3> {
    let cof = |r0: usize, r1: usize, c0: usize, c1: usize| a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0];
    let det = a[0][0] * cof(1, 2, 1, 2) - a[0][1] * cof(1, 2, 0, 2) + a[0][2] * cof(1, 2, 0, 1);
    let scale = a.iter().flatten().fold(0.0_f64, |m, x| m.max(x.abs()));
    if !det.is_finite() || det.abs() <= 64.0 * f64::EPSILON * scale * scale * scale {
        return None;
    }
    let replace = |col: usize| {
        let mut m = *a;
        for (row, bi) in m.iter_mut().zip(b) {
            row[col] = bi;
        }
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    Some([replace(0) / det, replace(1) / det, replace(2) / det])
}

/// Cholesky factor of a symmetric positive definite `N x N` matrix, in place: on success the lower
/// triangle (diagonal included) holds `L` with `A = L L^T`; the strict upper triangle is untouched.
///
/// Only the lower triangle of `a` is read. Returns `false`, leaving `a` partly overwritten, when a
/// pivot is not positive or not finite (the matrix is not positive definite to working precision).
#[inline]
pub fn cholesky_in_place<const N: usize>(a: &mut [[f64; N]; N]) -> bool {
    for j in 0..N {
        let d = a[j][j] - dot_slices(&a[j][..j], &a[j][..j]);
        if !(d > 0.0 && d.is_finite()) {
            return false;
        }
        let d = d.sqrt();
        a[j][j] = d;
        // Column j below the diagonal: L[i][j] = (A[i][j] - L[i][..j] . L[j][..j]) / L[j][j].
        let (upper, lower) = a.split_at_mut(j + 1);
        let row_j = &upper[j][..j];
        for row in lower.iter_mut() {
            row[j] = (row[j] - dot_slices(&row[..j], row_j)) / d;
        }
    }
    true
}

/// `sum a_k b_k` over two slices of equal length.
#[inline]
fn dot_slices(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// `ln det A` of a symmetric positive definite matrix, or `None` when it is not positive definite to
/// working precision. Only the lower triangle is read.
///
/// Cholesky factorisation ([`cholesky_in_place`]) and one logarithm of the product of the squared
/// pivots (the sum of logarithms only when that product would leave the normal range): this is the
/// fitness kernel of the design optimisers, where nine logarithms would cost as much as the
/// factorisation.
#[inline]
pub fn ln_det_spd<const N: usize>(a: &[[f64; N]; N]) -> Option<f64> {
    let mut l = *a;
    if !cholesky_in_place(&mut l) {
        return None;
    }
    let product: f64 = (0..N).map(|i| l[i][i] * l[i][i]).product();
    if product.is_normal() {
        Some(product.ln())
    } else {
        Some((0..N).map(|i| 2.0 * l[i][i].ln()).sum())
    }
}

/// Solves `L L^T x = b` given the factor `L` from [`cholesky_in_place`] (lower triangle of `l`).
#[inline]
pub fn cholesky_solve<const N: usize>(l: &[[f64; N]; N], b: &[f64; N]) -> [f64; N] {
    let mut y = *b;
    for i in 0..N {
        let mut s = y[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
    }
    for i in (0..N).rev() {
        let mut s = y[i];
        for k in (i + 1)..N {
            s -= l[k][i] * y[k];
        }
        y[i] = s / l[i][i];
    }
    y
}

/// `A^-1` from the factor `L` of `A = L L^T` ([`cholesky_in_place`]): its column `j` is
/// `cholesky_solve(l, e_j)` (and, `A^-1` being symmetric, so is its row `j`).
pub fn cholesky_inverse<const N: usize>(l: &[[f64; N]; N]) -> [[f64; N]; N] {
    std::array::from_fn(|j| {
        let mut e = [0.0; N];
        e[j] = 1.0;
        cholesky_solve(l, &e)
    })
}

/// `A^-1` of a symmetric positive definite `A` (lower triangle read), or `None` when it is not
/// positive definite to working precision.
pub fn spd_inverse<const N: usize>(a: &[[f64; N]; N]) -> Option<[[f64; N]; N]> {
    let mut l = *a;
    cholesky_in_place(&mut l).then(|| cholesky_inverse(&l))
}

/// Sweeps of [`symmetric_eigen`] at most.
const MAX_SWEEPS: usize = 20;

/// The eigenvalues (increasing) and eigenvectors (columns, in the same order) of a symmetric
/// `N x N` matrix (both triangles read as one), by cyclic Jacobi rotations until every
/// off-diagonal entry is below `f64::EPSILON` times the matrix's Frobenius norm; at most
/// 20 sweeps (Jacobi converges quadratically: 3 to 5 at `N = 3, 4`). `None` for
/// entries that are not finite.
///
/// Why not faer: the alignment of a calibration with reference attitudes ([`crate::reference`])
/// solves a 3x3 rotation problem hundreds of times per call, and faer's SVD and
/// eigendecomposition allocate on the heap and dispatch for every size: its 3x3 SVD costs 4.9 us
/// where [`wahba_rotation`] on this solver costs 1.9 us (`benches/calibration.rs`, `wahba`).
pub fn symmetric_eigen<const N: usize>(a: &[[f64; N]; N]) -> Option<([f64; N], [[f64; N]; N])> {
    if a.iter().flatten().any(|v| !v.is_finite()) {
        return None;
    }
    let mut a: [[f64; N]; N] = std::array::from_fn(|i| std::array::from_fn(|j| 0.5 * (a[i][j] + a[j][i])));
    let mut v: [[f64; N]; N] = std::array::from_fn(|i| std::array::from_fn(|j| f64::from(u8::from(i == j))));
    // The Frobenius norm, which the rotations keep.
    let size = a.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
    for _ in 0..MAX_SWEEPS {
        let off = (0..N)
            .flat_map(|p| (p + 1..N).map(move |q| (p, q)))
            .fold(0.0_f64, |m, (p, q)| m.max(a[p][q].abs()));
        if off <= f64::EPSILON * size {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                if a[p][q] == 0.0 {
                    continue;
                }
                // The rotation that zeroes a[p][q] (Golub and Van Loan, Algorithm 8.4.1).
                // `sqrt(1 + x^2)` rather than `hypot`, which costs most of a sweep; `theta^2`
                // overflows only past 1e154, where `t` is `1 / (2 theta)` to rounding.
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = if theta.abs() > 1e150 {
                    0.5 / theta
                } else {
                    theta.signum() / (theta.abs() + (1.0 + theta * theta).sqrt())
                };
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (1.0 + t * t).sqrt();
                let s = t * c;
                for k in 0..N {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..N {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for k in 0..N {
                    let (vkp, vkq) = (v[k][p], v[k][q]);
                    v[k][p] = c * vkp - s * vkq;
                    v[k][q] = s * vkp + c * vkq;
                }
            }
        }
    }
    let mut order: [usize; N] = std::array::from_fn(|i| i);
    order.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]));
    Some((order.map(|i| a[i][i]), std::array::from_fn(|r| order.map(|i| v[r][i]))))
}

/// The rotation `Q` maximising `trace(Q^T W)` (Wahba's problem; `W` the attitude profile
/// matrix), by Davenport's q-method: the unit quaternion of largest eigenvalue of the symmetric
/// 4x4 `N` with `q^T N q = trace(Q(q)^T W)`. `None` when `W` is zero or not finite.
pub fn wahba_rotation(w: &Mat3) -> Option<Mat3> {
    let scale = w.iter().flatten().fold(0.0_f64, |a, v| a.max(v.abs()));
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    let w: Mat3 = w.map(|row| row.map(|v| v / scale));
    // The quadratic form of trace(Q^T W) in q = (s, x, y, z), Q the rotation of q.
    let n = [
        [
            w[0][0] + w[1][1] + w[2][2],
            w[2][1] - w[1][2],
            w[0][2] - w[2][0],
            w[1][0] - w[0][1],
        ],
        [
            w[2][1] - w[1][2],
            w[0][0] - w[1][1] - w[2][2],
            w[0][1] + w[1][0],
            w[0][2] + w[2][0],
        ],
        [
            w[0][2] - w[2][0],
            w[0][1] + w[1][0],
            w[1][1] - w[0][0] - w[2][2],
            w[1][2] + w[2][1],
        ],
        [
            w[1][0] - w[0][1],
            w[0][2] + w[2][0],
            w[1][2] + w[2][1],
            w[2][2] - w[0][0] - w[1][1],
        ],
    ];
    let (_, vectors) = symmetric_eigen(&n)?;
    let q = [vectors[0][3], vectors[1][3], vectors[2][3], vectors[3][3]];
    let len = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    Some(rotation_of_quaternion(q.map(|v| v / len)))
}

/// The rotation of a unit quaternion `(s, x, y, z)` (turning vectors actively).
pub fn rotation_of_quaternion([s, x, y, z]: [f64; 4]) -> Mat3 {
    [
        [
            s * s + x * x - y * y - z * z,
            2.0 * (x * y - s * z),
            2.0 * (x * z + s * y),
        ],
        [
            2.0 * (x * y + s * z),
            s * s - x * x + y * y - z * z,
            2.0 * (y * z - s * x),
        ],
        [
            2.0 * (x * z - s * y),
            2.0 * (y * z + s * x),
            s * s - x * x - y * y + z * z,
        ],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::{Mat, Side};
    use rand::{RngExt, SeedableRng, rngs::ChaCha8Rng};

    fn random_spd<const N: usize>(rng: &mut ChaCha8Rng) -> [[f64; N]; N] {
        // B^T B + I for a random B: symmetric positive definite, moderately conditioned.
        let b: Vec<f64> = (0..N * N).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut a = [[0.0; N]; N];
        for i in 0..N {
            for j in 0..N {
                a[i][j] = (0..N).map(|k| b[k * N + i] * b[k * N + j]).sum::<f64>() + if i == j { 1.0 } else { 0.0 };
            }
        }
        a
    }

    #[test]
    fn cholesky9_matches_faer() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..200 {
            let a = random_spd::<9>(&mut rng);
            let fa = Mat::from_fn(9, 9, |i, j| a[i][j]);
            let llt = fa.llt(Side::Lower).expect("faer: SPD by construction");
            let fl = llt.L();
            let mut l = a;
            assert!(cholesky_in_place(&mut l));
            let scale = a.iter().flatten().fold(0.0_f64, |m, x| m.max(x.abs()));
            for i in 0..9 {
                for j in 0..=i {
                    assert!(
                        (l[i][j] - fl[(i, j)]).abs() <= 64.0 * f64::EPSILON * scale,
                        "L[{i}][{j}]"
                    );
                }
            }
            let faer_ln_det: f64 = (0..9).map(|i| 2.0 * fl[(i, i)].ln()).sum();
            let ln_det = ln_det_spd(&a).expect("SPD");
            assert!((ln_det - faer_ln_det).abs() <= 64.0 * f64::EPSILON * faer_ln_det.abs().max(1.0));
            // And against faer's determinant of the dense matrix.
            let det = fa.determinant();
            assert!((ln_det - det.ln()).abs() <= 1e3 * f64::EPSILON * ln_det.abs().max(1.0));
        }
    }

    #[test]
    fn cholesky_solve_satisfies_the_system() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        for _ in 0..100 {
            let a = random_spd::<9>(&mut rng);
            let b: [f64; 9] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let mut l = a;
            assert!(cholesky_in_place(&mut l));
            let x = cholesky_solve(&l, &b);
            let norm_a = a.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
            let norm_x = x.iter().map(|v| v * v).sum::<f64>().sqrt();
            for i in 0..9 {
                let r: f64 = (0..9).map(|j| a[i][j] * x[j]).sum::<f64>() - b[i];
                assert!(r.abs() <= 128.0 * 9.0 * f64::EPSILON * norm_a * norm_x, "row {i}: {r}");
            }
        }
    }

    #[test]
    fn not_positive_definite_is_reported() {
        let mut a = [[0.0; 3]; 3];
        a[0][0] = 1.0;
        a[1][1] = -1.0;
        a[2][2] = 1.0;
        assert!(ln_det_spd(&a).is_none());
        let nan = [[f64::NAN; 3]; 3];
        assert!(ln_det_spd(&nan).is_none());
    }

    #[test]
    fn small_inverses_are_inverses() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for _ in 0..200 {
            let mut u = [[0.0; 3]; 3];
            for i in 0..3 {
                u[i][i] = rng.random_range(0.5..2.0);
                for j in (i + 1)..3 {
                    u[i][j] = rng.random_range(-0.5..0.5);
                }
            }
            // At any scale whose inverse is finite: a d f underflows at 1e-150 and overflows
            // at 1e150.
            for scale in [1.0, 1e-150, 1e150] {
                let u = u.map(|row| row.map(|v| v * scale));
                let inv = upper_triangular_inverse(&u).expect("non-singular");
                let id = mat_mul(&u, &inv);
                for (i, row) in id.iter().enumerate() {
                    for (j, v) in row.iter().enumerate() {
                        let want = if i == j { 1.0 } else { 0.0 };
                        assert!((v - want).abs() <= 16.0 * f64::EPSILON * 8.0, "{scale}: {id:?}");
                    }
                }
            }
            let a: Mat3 = std::array::from_fn(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)));
            let b: Vec3 = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            if let Some(x) = solve3(&a, b) {
                let fa = Mat::from_fn(3, 3, |i, j| a[i][j]);
                let cond = {
                    let s = fa.singular_values().expect("svd");
                    s[0] / s[2]
                };
                let r = sub(mat_vec(&a, x), b);
                assert!(
                    norm(r) <= 64.0 * f64::EPSILON * cond * (norm(b) + 1.0),
                    "residual {r:?}"
                );
            }
        }
        assert!(upper_triangular_inverse(&[[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).is_none());
        assert!(solve3(&[[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]], [1.0, 1.0, 1.0]).is_none());
    }

    #[test]
    fn symmetric_eigen_matches_faer() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..200 {
            let a = random_spd::<4>(&mut rng);
            let a: [[f64; 4]; 4] =
                std::array::from_fn(|i| std::array::from_fn(|j| a[i][j] - 2.0 * f64::from(u8::from(i == j))));
            let (values, vectors) = symmetric_eigen(&a).unwrap();
            let fa = Mat::from_fn(4, 4, |i, j| a[i][j]);
            let evd = fa.self_adjoint_eigen(Side::Lower).unwrap();
            let mut fv: Vec<f64> = (0..4).map(|i| evd.S()[i]).collect();
            fv.sort_by(f64::total_cmp);
            let size = a.iter().flatten().fold(0.0_f64, |m, v| m.max(v.abs()));
            for k in 0..4 {
                assert!(
                    (values[k] - fv[k]).abs() <= 64.0 * f64::EPSILON * size,
                    "{values:?} {fv:?}"
                );
                // A v = lambda v, to rounding.
                for r in 0..4 {
                    let av: f64 = (0..4).map(|c| a[r][c] * vectors[c][k]).sum();
                    assert!((av - values[k] * vectors[r][k]).abs() <= 64.0 * f64::EPSILON * size);
                }
            }
        }
    }

    #[test]
    fn wahba_rotation_matches_the_svd_solution() {
        // Markley's SVD solution `U diag(1, 1, det(U V^T)) V^T` by faer, against the q-method, on
        // random matrices of either sign of determinant: the same rotation to 1e-12.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for trial in 0..500 {
            let w: Mat3 = std::array::from_fn(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)));
            let svd = Mat::from_fn(3, 3, |i, j| w[i][j]).svd().unwrap();
            let (u, v) = (svd.U(), svd.V());
            let uvt: Mat3 =
                std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| u[(i, k)] * v[(j, k)]).sum()));
            let d = if crate::reference::det(&uvt) < 0.0 { -1.0 } else { 1.0 };
            let weights = [1.0, 1.0, d];
            let want: Mat3 = std::array::from_fn(|i| {
                std::array::from_fn(|j| (0..3).map(|k| u[(i, k)] * weights[k] * v[(j, k)]).sum())
            });
            let got = wahba_rotation(&w).unwrap();
            let gap = (0..3)
                .flat_map(|i| (0..3).map(move |j| (i, j)))
                .fold(0.0_f64, |m, (i, j)| m.max((got[i][j] - want[i][j]).abs()));
            // The singular values' gaps set the conditioning: skip the near-degenerate draws.
            let s: Vec<f64> = (0..3).map(|k| svd.S()[k]).collect();
            let gap_s = (s[1] + d * s[2]).abs().min(s[0] + s[1]);
            if gap_s < 1e-3 {
                continue;
            }
            assert!(gap <= 1e-12, "trial {trial}: {gap:e}; singular values {s:?}");
        }
    }
}
