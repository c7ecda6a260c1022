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
pub(crate) const LN_DET_UNIT_POWER: f64 = 30.0;

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

/// Exponents `(a, b, c)` of the monomial `x^a y^b z^c` in each entry of `h`, \[P1\] eq. (9).
const H_EXPONENTS: [[u8; 3]; UNKNOWNS] = [
    [2, 0, 0],
    [1, 1, 0],
    [1, 0, 1],
    [0, 2, 0],
    [0, 1, 1],
    [0, 0, 2],
    [1, 0, 0],
    [0, 1, 0],
    [0, 0, 1],
];

/// Distinct moments `sum x^a y^b z^c` that make up `M_F`: every `(a, b, c)` of degree 4, 3 and 2.
pub(crate) const MOMENTS: usize = 15 + 10 + 6;

const MOMENT_EXPONENTS: [[u8; 3]; MOMENTS] = {
    let mut e = [[0u8; 3]; MOMENTS];
    let mut n = 0;
    let mut d = 4;
    while d >= 2 {
        let mut a = d;
        loop {
            let mut b = d - a;
            loop {
                e[n] = [a, b, d - a - b];
                n += 1;
                if b == 0 {
                    break;
                }
                b -= 1;
            }
            if a == 0 {
                break;
            }
            a -= 1;
        }
        d -= 1;
    }
    e
};

/// `MOMENT_OF[i][j]`: the index in [`MOMENT_EXPONENTS`] of the monomial `h_i h_j`.
const MOMENT_OF: [[usize; UNKNOWNS]; UNKNOWNS] = {
    let mut t = [[0; UNKNOWNS]; UNKNOWNS];
    let mut i = 0;
    while i < UNKNOWNS {
        let mut j = 0;
        while j < UNKNOWNS {
            let want = [
                H_EXPONENTS[i][0] + H_EXPONENTS[j][0],
                H_EXPONENTS[i][1] + H_EXPONENTS[j][1],
                H_EXPONENTS[i][2] + H_EXPONENTS[j][2],
            ];
            let mut k = 0;
            while !(MOMENT_EXPONENTS[k][0] == want[0]
                && MOMENT_EXPONENTS[k][1] == want[1]
                && MOMENT_EXPONENTS[k][2] == want[2])
            {
                k += 1;
            }
            t[i][j] = k;
            j += 1;
        }
        i += 1;
    }
    t
};

/// The 31 distinct moments `sum_i x_i^a y_i^b z_i^c` (degree 2 to 4) of a set of readings, from
/// which `M_F = H^T H` is assembled.
///
/// Every entry of `M_F` is such a moment (for example `(M_F)_14 = sum x^2 * y^2 = (M_F)_22`), so a
/// reading costs 31 products instead of the 45 of the lower triangle of `h h^T`, and they vectorise.
/// This is the inner loop of the design optimisers; it allocates nothing.
#[derive(Debug, Clone, PartialEq)]
pub struct Moments([f64; MOMENTS]);

/// The monomials `x^a y^b z^c` of one reading in the order of [`MOMENT_EXPONENTS`], each one
/// product of two lower-degree terms.
#[inline]
pub(crate) fn monomials(u: Vec3) -> [f64; MOMENTS] {
    let [x, y, z] = u;
    let [xx, xy, xz, yy, yz, zz] = [x * x, x * y, x * z, y * y, y * z, z * z];
    [
        // degree 4
        xx * xx,
        xx * xy,
        xx * xz,
        xx * yy,
        xx * yz,
        xx * zz,
        xy * yy,
        xy * yz,
        xy * zz,
        xz * zz,
        yy * yy,
        yy * yz,
        yy * zz,
        yz * zz,
        zz * zz,
        // degree 3
        xx * x,
        xx * y,
        xx * z,
        yy * x,
        xy * z,
        zz * x,
        yy * y,
        yy * z,
        zz * y,
        zz * z,
        // degree 2
        xx,
        xy,
        xz,
        yy,
        yz,
        zz,
    ]
}

impl Default for Moments {
    fn default() -> Self {
        Self([0.0; MOMENTS])
    }
}

impl Moments {
    /// Adds one reading.
    #[inline]
    pub fn add(&mut self, u: Vec3) {
        let terms = monomials(u);
        for (m, t) in self.0.iter_mut().zip(terms) {
            *m += t;
        }
    }

    /// Adds `count` readings of one value: one product per moment instead of `count` sums, so
    /// the rounding does not grow with the count (`count = 1` adds exactly as [`Self::add`]).
    #[inline]
    pub fn add_repeated(&mut self, u: Vec3, count: usize) {
        let n = count as f64;
        let terms = monomials(u);
        for (m, t) in self.0.iter_mut().zip(terms) {
            *m += n * t;
        }
    }

    /// The index of the moment that is entry `(i, j)` of `M_F`.
    #[inline]
    pub(crate) fn index_of(i: usize, j: usize) -> usize {
        MOMENT_OF[i][j]
    }

    /// `M_F`, both triangles.
    #[inline]
    pub fn information(&self) -> Mat9 {
        let mut M = [[0.0; UNKNOWNS]; UNKNOWNS];
        for (row, index) in M.iter_mut().zip(&MOMENT_OF) {
            for (m, &k) in row.iter_mut().zip(index) {
                *m = self.0[k];
            }
        }
        M
    }
}

/// The information matrix `M_F = H^T H` of \[P1\] eq. (12), accumulated in a fixed 9x9 array
/// from readings scaled by `scale` (see [`design_matrix`]), through their [`Moments`].
#[derive(Debug, Clone, PartialEq)]
pub struct InformationMatrix {
    M: Mat9,
    scale: f64,
}

impl InformationMatrix {
    /// `M_F` of `readings` divided by `scale`.
    pub fn from_readings(readings: &[Vec3], scale: f64) -> Self {
        let mut moments = Moments::default();
        for &b in readings {
            moments.add(b.map(|v| v / scale));
        }
        Self {
            M: moments.information(),
            scale,
        }
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

    /// `ln det M_F` with `H` in nT, the quantity of \[P1\] eq. (14)-(15) and of docs/conventions.md's
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
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
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
        // docs/conventions.md check values, to the 4 decimals printed there.
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
    fn monomials_follow_the_exponent_table() {
        let u = [1.3, -0.7, 2.1];
        for (k, (got, e)) in monomials(u).into_iter().zip(MOMENT_EXPONENTS).enumerate() {
            let want = u[0].powi(e[0].into()) * u[1].powi(e[1].into()) * u[2].powi(e[2].into());
            assert!(
                (got - want).abs() <= 4.0 * f64::EPSILON * want.abs(),
                "moment {k} {e:?}"
            );
        }
        // Each (a, b, c) of degree 2 to 4 exactly once.
        let mut seen = std::collections::HashSet::new();
        assert!(
            MOMENT_EXPONENTS
                .iter()
                .all(|e| (2..=4).contains(&(e[0] + e[1] + e[2])) && seen.insert(*e))
        );
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
