//! The linear ellipsoid model of \[P1\] eq. (8)-(13): regression rows `h`, the matrix `H`, the
//! information matrix `M_F = H^T H` and its determinant and condition numbers.
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]
#![allow(non_snake_case)]

use faer::{Mat, MatRef};

use crate::small::{Mat9, Vec3, ln_det_spd};

/// Number of unknowns of the linear model, `theta` in \[P1\] eq. (9).
pub const UNKNOWNS: usize = 9;

/// Exponent of the unit in `det M_F`: six quadratic columns (nT^2 each, nT^4 in `M_F`'s diagonal)
/// and three linear ones (nT, nT^2), so `det M_F` carries nT^(2 (6*2 + 3*1)) = nT^30.
const LN_DET_UNIT_POWER: f64 = 30.0;

/// The regression row of one reading `b`, \[P1\] eq. (9):
/// `h = (bx^2, bx by, bx bz, by^2, by bz, bz^2, bx, by, bz)`.
#[inline]
pub fn regression_row(b: Vec3) -> [f64; UNKNOWNS] {
    let [x, y, z] = b;
    [x * x, x * y, x * z, y * y, y * z, z * z, x, y, z]
}

/// `H = (h_1, ..., h_m)^T`, \[P1\] eq. (10), for the readings divided by `scale` (nT; pass 1.0 for `H`
/// in nT as the paper writes it, or the field magnitude `R` for a unit-free, well-scaled `H`).
pub fn design_matrix(readings: &[Vec3], scale: f64) -> Mat<f64> {
    let mut H = Mat::zeros(readings.len(), UNKNOWNS);
    for (i, &b) in readings.iter().enumerate() {
        let h = regression_row(b.map(|v| v / scale));
        for (j, v) in h.into_iter().enumerate() {
            H[(i, j)] = v;
        }
    }
    H
}

/// The 2-norm condition number `s_max / s_min` of a matrix, from faer's singular values;
/// infinite when it is rank deficient (or the SVD does not converge).
pub fn cond_2(A: MatRef<'_, f64>) -> f64 {
    match A.singular_values() {
        Ok(s) if !s.is_empty() => {
            let (max, min) = (s[0], s[s.len() - 1]);
            if min > 0.0 { max / min } else { f64::INFINITY }
        }
        _ => f64::INFINITY,
    }
}

/// The information matrix `M_F = H^T H` of \[P1\] eq. (12), accumulated in a fixed 9x9 array
/// from readings scaled by `scale` (see [`design_matrix`]).
///
/// Accumulating `sum_i h_i h_i^T` avoids building `H`: the design optimisers evaluate it in their
/// inner loop and allocate nothing.
#[derive(Debug, Clone, PartialEq)]
pub struct InformationMatrix {
    M: Mat9,
    scale: f64,
}

impl InformationMatrix {
    /// `M_F` of `readings` divided by `scale`.
    pub fn from_readings(readings: &[Vec3], scale: f64) -> Self {
        let mut M = [[0.0; UNKNOWNS]; UNKNOWNS];
        for &b in readings {
            let h = regression_row(b.map(|v| v / scale));
            for i in 0..UNKNOWNS {
                for j in 0..=i {
                    M[i][j] += h[i] * h[j];
                }
            }
        }
        for i in 0..UNKNOWNS {
            for j in (i + 1)..UNKNOWNS {
                M[i][j] = M[j][i];
            }
        }
        Self { M, scale }
    }

    /// The matrix, of the scaled readings.
    pub fn matrix(&self) -> &Mat9 {
        &self.M
    }

    /// The scale the readings were divided by (nT).
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// `ln det M_F` of the scaled readings; `-inf` when `M_F` is singular to working precision.
    pub fn ln_det_scaled(&self) -> f64 {
        ln_det_spd(&self.M).unwrap_or(f64::NEG_INFINITY)
    }

    /// `ln det M_F` with `H` in nT, the quantity of \[P1\] eq. (14)-(15) and of CONVENTIONS.md's
    /// check values: `ln det M_F(scaled) + 30 ln(scale)`.
    ///
    /// # Deviation from \[P1\]
    /// The paper forms `M_F` in nT, whose entries span nT^2 to nT^4 (1e9 to 1e19 at 48000 nT);
    /// computing its determinant directly loses digits. Scaling the readings by `s` multiplies
    /// column j of `H` by `s^-deg_j`, which changes `ln det M_F` by exactly `2 ln(s) sum deg_j`
    /// = `30 ln s`; the scaled matrix is well conditioned, so this is the accurate route.
    pub fn ln_det_nt(&self) -> f64 {
        self.ln_det_scaled() + LN_DET_UNIT_POWER * self.scale.ln()
    }

    /// `M_F` as a faer matrix.
    pub fn to_faer(&self) -> Mat<f64> {
        Mat::from_fn(UNKNOWNS, UNKNOWNS, |i, j| self.M[i][j])
    }
}

/// Conditioning of a set of readings under the linear model, in the units of \[P1\] (`H` in nT).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Conditioning {
    /// `ln det M_F`, `H` in nT (\[P1\] eq. (12), (14)).
    pub ln_det_mf: f64,
    /// `cond_2(H)`, `H` in nT.
    pub cond_h: f64,
    /// `cond_2(M_F) = cond_2(H)^2` (exact for `M_F = H^T H`; computing it from `M_F` itself would
    /// square the rounding error as well).
    pub cond_mf: f64,
}

impl Conditioning {
    /// Conditioning of `readings` (nT); `field_magnitude_nt` only scales the determinant's
    /// computation (any positive value gives the same numbers up to rounding).
    pub fn of_readings(readings: &[Vec3], field_magnitude_nt: f64) -> Self {
        let cond_h = cond_2(design_matrix(readings, 1.0).as_ref());
        Self {
            ln_det_mf: InformationMatrix::from_readings(readings, field_magnitude_nt).ln_det_nt(),
            cond_h,
            cond_mf: cond_h * cond_h,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::paper;

    fn paper_readings(design: &[crate::Attitude], yaw_offset_deg: f64) -> (Vec<Vec3>, f64) {
        let f = paper::changsha_field().with_yaw_offset_deg(yaw_offset_deg).unwrap();
        let m = paper::true_error_model();
        (m.measure_all(&f.body_fields(design)), f.magnitude())
    }

    #[test]
    fn ln_det_matches_conventions_check_values() {
        // CONVENTIONS.md check values, to the 4 decimals printed there.
        for (design, offset, want) in [
            (paper::uniformity_design(), 0.0, 303.4800),
            (paper::table2_d_optimal(), 0.0, 298.9240),
            (paper::uniformity_design(), 90.0, 309.1878),
        ] {
            let (r, mag) = paper_readings(&design, offset);
            let got = InformationMatrix::from_readings(&r, mag).ln_det_nt();
            assert!((got - want).abs() < 5e-5, "got {got}, want {want}");
        }
    }

    #[test]
    fn ln_det_is_independent_of_the_scaling() {
        let (r, mag) = paper_readings(&paper::uniformity_design(), 0.0);
        let a = InformationMatrix::from_readings(&r, mag).ln_det_nt();
        let b = InformationMatrix::from_readings(&r, 1000.0).ln_det_nt();
        let c = InformationMatrix::from_readings(&r, 1.0).ln_det_nt();
        assert!((a - b).abs() <= 1e-9 * a.abs(), "{a} {b}");
        // In raw nT the Cholesky loses digits but must still agree to ~1e-6 relative.
        assert!((a - c).abs() <= 1e-6 * a.abs(), "{a} {c}");
    }

    #[test]
    fn information_matrix_equals_h_transpose_h() {
        let (r, mag) = paper_readings(&paper::table2_d_optimal(), 0.0);
        let H = design_matrix(&r, mag);
        let want = H.transpose() * &H;
        let got = InformationMatrix::from_readings(&r, mag);
        let norm = want.norm_max();
        for i in 0..UNKNOWNS {
            for j in 0..UNKNOWNS {
                assert!((got.matrix()[i][j] - want[(i, j)]).abs() <= 16.0 * 9.0 * f64::EPSILON * norm);
            }
        }
    }

    #[test]
    fn condition_numbers() {
        let (r, mag) = paper_readings(&paper::uniformity_design(), 0.0);
        let c = Conditioning::of_readings(&r, mag);
        // Cross-check cond(M_F) = cond(H)^2 on the well-scaled matrices, where both are accurate.
        let Hs = design_matrix(&r, mag);
        let ch = cond_2(Hs.as_ref());
        let cm = cond_2((Hs.transpose() * &Hs).as_ref());
        assert!((cm / (ch * ch) - 1.0).abs() < 1e-6, "{cm} {ch}");
        assert!(c.cond_h.is_finite() && c.cond_h > 1.0);
        assert!((c.cond_mf - c.cond_h * c.cond_h).abs() <= 4.0 * f64::EPSILON * c.cond_mf);
        // One repeated reading: rank 1, infinitely ill-conditioned, ln det = -inf.
        let same = vec![r[0]; 9];
        assert!(InformationMatrix::from_readings(&same, mag).ln_det_nt().is_infinite());
        assert!(cond_2(design_matrix(&same, mag).as_ref()) > 1e12);
    }
}
