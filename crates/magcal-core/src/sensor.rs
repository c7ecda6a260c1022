//! The magnetometer error model of \[P1\] eq. (5)-(7): non-orthogonality `psi`, scale factors `S`
//! and bias `O`, and the matrices `K`, `P = K^-1`, `G = P^T P` built from them.
#![allow(non_snake_case)]

use rand::Rng;
use rand_distr::{Distribution, Normal};

use crate::error::{ParameterError, finite};
use crate::small::{Mat3, Vec3, add, mat_mul, mat_vec, norm, transpose, upper_triangular_inverse};

/// The total sensor errors of \[P1\] eq. (5): `B^s = K B^b + O + n`, `K = diag(S) N`.
///
/// `N` is upper triangular with unit rows (docs/conventions.md):
/// `N = [[cos psi2 cos psi3, cos psi2 sin psi3, sin psi2], [0, cos psi1, sin psi1], [0, 0, 1]]`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorModel {
    psi: Vec3,
    scale: Vec3,
    bias_nt: Vec3,
}

impl ErrorModel {
    /// A model from non-orthogonality angles `psi_deg` (degrees, each in (-90, 90)), scale factors
    /// (dimensionless, each > 0) and bias (nT).
    ///
    /// # Errors
    /// A non-finite value, an angle outside (-90, 90) degrees, or a scale factor that is not positive.
    pub fn new(psi_deg: Vec3, scale: Vec3, bias_nt: Vec3) -> Result<Self, ParameterError> {
        for &p in &psi_deg {
            finite("psi_deg", p)?;
            if p.abs() >= 90.0 {
                return Err(ParameterError::OutOfRange {
                    name: "psi_deg",
                    allowed: "(-90, 90) degrees",
                    value: p,
                });
            }
        }
        for &s in &scale {
            finite("scale", s)?;
            if s <= 0.0 {
                return Err(ParameterError::NotPositive {
                    name: "scale",
                    value: s,
                });
            }
        }
        for &o in &bias_nt {
            finite("bias_nt", o)?;
        }
        let model = Self {
            psi: psi_deg.map(f64::to_radians),
            scale,
            bias_nt,
        };
        // Positive finite scale factors can still leave `K` without a finite inverse in floating
        // point (three of 1e-150: the product of the diagonal underflows); `P` must exist.
        if upper_triangular_inverse(&model.K()).is_none() {
            return Err(ParameterError::OutOfRange {
                name: "scale",
                allowed: "factors whose matrix K has a finite inverse",
                value: scale.iter().copied().fold(f64::INFINITY, f64::min),
            });
        }
        Ok(model)
    }

    /// The model whose `K` and `O` are given: the inverse map of docs/conventions.md,
    /// `S_i = |row_i(K)|`, `N = diag(S)^-1 K`, `psi2 = asin N13`, `psi3 = atan2(N12, N11)`,
    /// `psi1 = atan2(N23, N22)`.
    ///
    /// Only the upper triangle of `K` is read. `K` must have a positive diagonal (true for every
    /// estimate this crate produces); the result is not re-validated.
    pub fn from_k(K: &Mat3, bias_nt: Vec3) -> Self {
        let rows = [
            [K[0][0], K[0][1], K[0][2]],
            [0.0, K[1][1], K[1][2]],
            [0.0, 0.0, K[2][2]],
        ];
        let scale = rows.map(norm);
        let N = [0, 1, 2].map(|i| rows[i].map(|v| v / scale[i]));
        let psi2 = N[0][2].clamp(-1.0, 1.0).asin();
        let psi3 = N[0][1].atan2(N[0][0]);
        let psi1 = N[1][2].atan2(N[1][1]);
        Self {
            psi: [psi1, psi2, psi3],
            scale,
            bias_nt,
        }
    }

    /// Non-orthogonality angles `psi`, degrees.
    pub fn psi_deg(&self) -> Vec3 {
        self.psi.map(f64::to_degrees)
    }

    /// Scale factors `S`, dimensionless.
    pub fn scale(&self) -> Vec3 {
        self.scale
    }

    /// Bias `O`, nT.
    pub fn bias_nt(&self) -> Vec3 {
        self.bias_nt
    }

    /// The non-orthogonality matrix `N` (`C_N` of \[P1\] eq. (5)).
    pub fn N(&self) -> Mat3 {
        let [p1, p2, p3] = self.psi;
        [
            [p2.cos() * p3.cos(), p2.cos() * p3.sin(), p2.sin()],
            [0.0, p1.cos(), p1.sin()],
            [0.0, 0.0, 1.0],
        ]
    }

    /// `K = C_s C_N = diag(S) N`, \[P1\] eq. (5); upper triangular.
    pub fn K(&self) -> Mat3 {
        let N = self.N();
        [0, 1, 2].map(|i| N[i].map(|v| v * self.scale[i]))
    }

    /// `P = K^-1`, \[P1\] eq. (6); upper triangular.
    pub fn P(&self) -> Mat3 {
        upper_triangular_inverse(&self.K()).expect("validated model: K has a positive diagonal")
    }

    /// `G = P^T P`, \[P1\] eq. (7); symmetric positive definite.
    pub fn G(&self) -> Mat3 {
        let P = self.P();
        mat_mul(&transpose(&P), &P)
    }

    /// The noise-free reading of body field `b` (nT): `K b + O`, \[P1\] eq. (5) with `n = 0`.
    pub fn measure(&self, b: Vec3) -> Vec3 {
        add(mat_vec(&self.K(), b), self.bias_nt)
    }

    /// Noise-free readings of a sequence of body fields.
    pub fn measure_all(&self, body_fields: &[Vec3]) -> Vec<Vec3> {
        let K = self.K();
        body_fields.iter().map(|&b| add(mat_vec(&K, b), self.bias_nt)).collect()
    }

    /// Noisy readings, \[P1\] eq. (5): `K b + O + n` with `n ~ N(0, sigma^2 I3)`, one draw per component
    /// per reading, in the order reading 1 (x, y, z), reading 2 (x, y, z), ...
    ///
    /// `sigma_nt` is the standard deviation per component, nT.
    ///
    /// # Errors
    /// `sigma_nt` negative or not finite.
    pub fn noisy_readings<R: Rng + ?Sized>(
        &self,
        body_fields: &[Vec3],
        sigma_nt: f64,
        rng: &mut R,
    ) -> Result<Vec<Vec3>, ParameterError> {
        let mut readings = self.measure_all(body_fields);
        add_noise(&mut readings, sigma_nt, rng)?;
        Ok(readings)
    }
}

/// Adds white Gaussian noise `N(0, sigma_nt^2)` to every component, in reading order then x, y, z.
///
/// # Errors
/// `sigma_nt` negative or not finite.
pub fn add_noise<R: Rng + ?Sized>(readings: &mut [Vec3], sigma_nt: f64, rng: &mut R) -> Result<(), ParameterError> {
    finite("sigma_nt", sigma_nt)?;
    if sigma_nt < 0.0 {
        return Err(ParameterError::Negative {
            name: "sigma_nt",
            value: sigma_nt,
        });
    }
    let normal = Normal::new(0.0, sigma_nt).expect("sigma checked finite and non-negative");
    for r in readings.iter_mut() {
        for c in r.iter_mut() {
            *c += normal.sample(rng);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::paper;
    use rand::{RngExt, SeedableRng, rngs::ChaCha8Rng};

    #[test]
    fn scale_factors_whose_k_has_no_finite_inverse_are_refused() {
        // Each positive and finite, but 1 / 1e-310 overflows: P would not exist.
        let e = ErrorModel::new([0.0; 3], [1e-310; 3], [0.0; 3]).unwrap_err();
        assert!(e.to_string().contains("finite inverse"), "{e}");
        // Back substitution inverts K = 1e-150 I, whose determinant (1e-450) underflows (the
        // log fuzzer's readings near 1e150 fitted to a magnitude of 1e300).
        let m = ErrorModel::new([0.0; 3], [1e-150; 3], [0.0; 3]).unwrap();
        assert!(m.P().iter().flatten().all(|v| v.is_finite()));
        // The smallest and largest scale factors a scenario accepts stay valid.
        for s in [1e-3, 1e3] {
            let m = ErrorModel::new([89.0, -89.0, 45.0], [s; 3], [0.0; 3]).unwrap();
            assert!(m.P().iter().flatten().all(|v| v.is_finite()));
        }
    }

    #[test]
    #[allow(clippy::float_cmp)] // the bias is passed through untouched: exact
    fn parameters_round_trip_through_k() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..10_000 {
            let psi: Vec3 = std::array::from_fn(|_| rng.random_range(-30.0..30.0));
            let s: Vec3 = std::array::from_fn(|_| rng.random_range(0.2..5.0));
            let o: Vec3 = std::array::from_fn(|_| rng.random_range(-5e4..5e4));
            let m = ErrorModel::new(psi, s, o).unwrap();
            let back = ErrorModel::from_k(&m.K(), m.bias_nt());
            for i in 0..3 {
                assert!((back.psi_deg()[i] - psi[i]).abs() <= 1e-12 * 30.0, "psi {i}");
                assert!((back.scale()[i] - s[i]).abs() <= 1e-12 * s[i], "S {i}");
            }
            assert_eq!(back.bias_nt(), o);
        }
    }

    #[test]
    #[allow(clippy::float_cmp)] // structural zeros of triangular matrices: exact
    fn k_p_g_are_consistent() {
        let m = paper::true_error_model();
        let (K, P, G) = (m.K(), m.P(), m.G());
        let kp = mat_mul(&K, &P);
        let Kinv_t_Kinv = mat_mul(&transpose(&P), &P);
        for i in 0..3 {
            for j in 0..3 {
                let id = if i == j { 1.0 } else { 0.0 };
                assert!((kp[i][j] - id).abs() <= 8.0 * f64::EPSILON);
                assert!((G[i][j] - G[j][i]).abs() <= 4.0 * f64::EPSILON);
                assert!((G[i][j] - Kinv_t_Kinv[i][j]).abs() <= 4.0 * f64::EPSILON);
            }
            // Rows of N are unit vectors; K is upper triangular.
            assert!((norm(m.N()[i]) - 1.0).abs() <= 4.0 * f64::EPSILON);
            for j in 0..i {
                assert_eq!(K[i][j], 0.0);
                assert_eq!(P[i][j], 0.0);
            }
        }
    }

    #[test]
    fn readings_lie_on_the_ellipsoid_of_eq_7() {
        // |P (B^s - O)| = R for every noise-free reading, [P1] eq. (7).
        let f = paper::changsha_field();
        let m = paper::true_error_model();
        let readings = m.measure_all(&f.body_fields(&paper::uniformity_design()));
        for r in readings {
            let v = mat_vec(&m.P(), crate::small::sub(r, m.bias_nt()));
            assert!((norm(v) - f.magnitude()).abs() <= 1e-10 * f.magnitude());
        }
    }

    #[test]
    fn noise_has_the_requested_sigma() {
        // 30k draws at sigma = 30 nT: the sample std lies within 4 standard errors
        // (se of a sample std ~ sigma / sqrt(2n)).
        let m = paper::true_error_model();
        let body = vec![[0.0, 0.0, 0.0]; 10_000];
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let noisy = m.noisy_readings(&body, 30.0, &mut rng).unwrap();
        let clean = m.measure_all(&body);
        let d: Vec<f64> = noisy
            .iter()
            .zip(&clean)
            .flat_map(|(a, b)| (0..3).map(move |i| a[i] - b[i]))
            .collect();
        let n = d.len() as f64;
        let mean = d.iter().sum::<f64>() / n;
        let std = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        assert!(mean.abs() <= 4.0 * 30.0 / n.sqrt(), "mean {mean}");
        assert!((std - 30.0).abs() <= 4.0 * 30.0 / (2.0 * n).sqrt(), "std {std}");
        assert!(m.noisy_readings(&body, -1.0, &mut rng).is_err());
        assert!(m.noisy_readings(&body, f64::NAN, &mut rng).is_err());
    }

    #[test]
    fn invalid_models_are_errors() {
        assert!(ErrorModel::new([90.0, 0.0, 0.0], [1.0; 3], [0.0; 3]).is_err());
        assert!(ErrorModel::new([0.0; 3], [1.0, 0.0, 1.0], [0.0; 3]).is_err());
        assert!(ErrorModel::new([0.0; 3], [1.0; 3], [f64::NAN, 0.0, 0.0]).is_err());
    }
}
