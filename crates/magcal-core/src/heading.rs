//! The heading error of a calibration (docs/conventions.md "Heading error of a calibration"): what a
//! navigator loses by flying with it.
//!
//! At roll = pitch = 0 and yaw 0, 1, ..., 359 degrees (with the field's yaw offset), the true body
//! field `b` (\[P1\] eq. (1)-(2)), the noise-free reading `s = K b + O` (\[P1\] eq. (5)) and the
//! calibrated field `b_hat = P_hat (s - O_hat)` (\[P1\] eq. (6)) give the heading error
//! `e = atan2(b_hat_z, b_hat_x) - atan2(b_z, b_x)`, wrapped to (-180, 180]. Reported: its rms and
//! maximum over the 360 yaws, degrees.
//!
//! The error is the angle from `(b_x, b_z)` to `(b_hat_x, b_hat_z)`, the argument of
//! `w_k = dot_k + i cross_k`.
//!
//! # Deviation from the obvious code
//! One `atan2` per yaw (`e_k = atan2(cross_k, dot_k)`) costs more than the rest of the added
//! metrics of a Monte Carlo trial. Instead, the structure of the problem: at a level attitude the
//! true horizontal field `T = b_x + i b_z` only turns with yaw (`|T| = h`, `b_y = v` fixed), and
//! the calibrated one `U = b_hat_x + i b_hat_z` is an affine image of `b`, so
//! `w = conj(T) U = A + B conj(T) + C conj(T)^2` with three complex numbers computed once per
//! calibration from `P_hat`, `O_hat` and the truth. Then `e_k = arg(A) + arg(w_k / A)`, and
//! `|w_k / A - 1| <= rho = |B / A| h + |C / A| h^2` bounds every `|tan arg(w_k / A)|` by
//! `rho / sqrt(1 - rho^2)` before any yaw is visited. That bound picks the shortest arctangent
//! series that is exact to below 1.2e-17 rad (see `atan_series`); above 0.15 (about 8.5
//! degrees from the anchor, a poor calibration) the definition is used. The per-yaw loop has no
//! dependence from one yaw to the next, no branch and no wrap (the bound keeps `arg(A) + d_k`
//! inside [-pi, pi]). Against one `atan2` per yaw the result agrees within 1e-12 rad (tested on
//! calibrations from exact to absurd, and on ones that mirror or flatten the plane). The loop is
//! compiled a second time for AVX2 and chosen at run time, as the PSO kernel is (bit-identical,
//! tested): about ten times faster than one `atan2` per yaw (`benches/calibration.rs`,
//! `heading_error/one_trial`; docs/research/benchmarks.md has the numbers). Of 2000 trials at
//! 30 nT of the Uniformity design 6 take the definition.

use std::f64::consts::PI;

use crate::attitude::Attitude;
use crate::field::ReferenceField;
use crate::sensor::ErrorModel;
use crate::small::{Mat3, Vec3, dot, sub};

/// Yaws of the probe, one per degree.
pub const YAWS: usize = 360;

/// The heading error of one calibration: rms and maximum of `|e|` over the 360 yaws, degrees.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct HeadingError {
    /// Root mean square over the yaws, degrees.
    pub rms_deg: f64,
    /// Largest absolute error, degrees.
    pub max_deg: f64,
}

/// The true horizontal field and the noise-free readings at the 360 level yaws of a field and a
/// sensor: built once per scenario, evaluated per calibration.
#[derive(Debug, Clone)]
pub struct HeadingProbe {
    /// `b_x` and `b_z` of the true body field per yaw.
    horizontal: Box<[[f64; YAWS]; 2]>,
    /// `s = K b + O` per yaw, by component.
    readings: Box<[[f64; YAWS]; 3]>,
    /// Real and imaginary parts of `conj(T_k)` and `conj(T_k)^2 / h^2`, `T_k = b_x + i b_z`.
    turns: Box<[[f64; YAWS]; 4]>,
    /// `h^2 = |T_k|^2`, the squared horizontal field (the same at every level yaw).
    horizontal_sq: f64,
    /// `b_y`, the vertical field (the same at every level yaw).
    vertical: f64,
    /// `K` and `O` of the truth.
    k: Mat3,
    bias_nt: Vec3,
}

impl HeadingProbe {
    /// The probe of `truth` in `field`.
    pub fn new(field: &ReferenceField, truth: &ErrorModel) -> Self {
        let body: Vec<Vec3> = (0..YAWS)
            .map(|k| field.body_field(&Attitude::from_degrees(0.0, k as f64, 0.0)))
            .collect();
        let readings = truth.measure_all(&body);
        let horizontal_sq = body[0][0] * body[0][0] + body[0][2] * body[0][2];
        let turns = std::array::from_fn(|j| {
            std::array::from_fn(|k| {
                let [tx, tz] = [body[k][0], -body[k][2]];
                match j {
                    0 => tx,
                    1 => tz,
                    2 => (tx * tx - tz * tz) / horizontal_sq,
                    _ => 2.0 * tx * tz / horizontal_sq,
                }
            })
        });
        Self {
            horizontal: Box::new([0, 2].map(|i| std::array::from_fn(|k| body[k][i]))),
            readings: Box::new(std::array::from_fn(|i| std::array::from_fn(|k| readings[k][i]))),
            turns: Box::new(turns),
            horizontal_sq,
            vertical: body[0][1],
            k: truth.K(),
            bias_nt: truth.bias_nt(),
        }
    }

    /// The heading error of the calibration `b_hat = p (s - bias_nt)`.
    pub fn error(&self, p: &Mat3, bias_nt: Vec3) -> HeadingError {
        error_kernel(self, p, bias_nt)
    }

    #[inline(always)]
    fn error_body(&self, p: &Mat3, bias_nt: Vec3) -> HeadingError {
        // U = b_hat_x + i b_hat_z = mu . b + kappa, mu = (P_x + i P_z) K, kappa = (P_x + i P_z)
        // (O - O_hat); with b = (Re T, v, Im T): w = conj(T) U = A + B conj(T) + C conj(T)^2.
        let (px, pz) = (p[0], p[2]);
        let mu: [[f64; 2]; 3] = std::array::from_fn(|j| {
            let column = [self.k[0][j], self.k[1][j], self.k[2][j]];
            [dot(px, column), dot(pz, column)]
        });
        let offset = sub(self.bias_nt, bias_nt);
        let kappa = [dot(px, offset), dot(pz, offset)];
        let h2 = self.horizontal_sq;
        let a = [0.5 * h2 * (mu[0][0] + mu[2][1]), 0.5 * h2 * (mu[0][1] - mu[2][0])];
        let b = [mu[1][0] * self.vertical + kappa[0], mu[1][1] * self.vertical + kappa[1]];
        let c = [0.5 * h2 * (mu[0][0] - mu[2][1]), 0.5 * h2 * (mu[0][1] + mu[2][0])];
        // w_k / A = 1 + beta conj(T_k) + gamma conj(T_k)^2 / h^2, within rho = |beta| h + |gamma|
        // of 1, so |arg(w_k / A)| <= asin(rho) and |tan| <= rho / sqrt(1 - rho^2).
        let a2 = a[0] * a[0] + a[1] * a[1];
        let over_a = |z: [f64; 2]| [(z[0] * a[0] + z[1] * a[1]) / a2, (z[1] * a[0] - z[0] * a[1]) / a2];
        let (beta, gamma) = (over_a(b), over_a(c));
        let rho = (beta[0] * beta[0] + beta[1] * beta[1]).sqrt() * h2.sqrt()
            + (gamma[0] * gamma[0] + gamma[1] * gamma[1]).sqrt();
        let tan_bound = rho / (1.0 - rho * rho).sqrt();
        let anchor = a[1].atan2(a[0]);
        if !(a2.is_normal() && tan_bound <= SMALL && anchor.abs() + tan_bound <= PI) {
            // A poor calibration: the definition, one atan2 per yaw.
            return self.error_by_atan2(p, bias_nt);
        }
        if tan_bound <= 0.005 {
            self.error_from_anchor::<2>(anchor, beta, gamma)
        } else if tan_bound <= 0.02 {
            self.error_from_anchor::<4>(anchor, beta, gamma)
        } else if tan_bound <= 0.05 {
            self.error_from_anchor::<6>(anchor, beta, gamma)
        } else {
            self.error_from_anchor::<9>(anchor, beta, gamma)
        }
    }

    /// `e_k = arg(A) + atan(x_k)`, `x_k = Im / Re` of `1 + beta conj(T_k) + gamma conj(T_k)^2 / h^2`,
    /// the arctangent from its series to `x^(2 TERMS + 1)`.
    #[inline(always)]
    fn error_from_anchor<const TERMS: usize>(&self, anchor: f64, beta: [f64; 2], gamma: [f64; 2]) -> HeadingError {
        let [t1r, t1i, t2r, t2i] = &*self.turns;
        let mut e = [0.0; YAWS];
        for k in 0..YAWS {
            let re = 1.0 + (beta[0] * t1r[k] - beta[1] * t1i[k]) + (gamma[0] * t2r[k] - gamma[1] * t2i[k]);
            let im = (beta[0] * t1i[k] + beta[1] * t1r[k]) + (gamma[0] * t2i[k] + gamma[1] * t2r[k]);
            e[k] = anchor + atan_series::<TERMS>(im / re);
        }
        let mut sum_sq = [0.0; LANES];
        let mut max = [0.0_f64; LANES];
        for chunk in e.chunks_exact(LANES) {
            for l in 0..LANES {
                sum_sq[l] += chunk[l] * chunk[l];
                max[l] = max[l].max(chunk[l].abs());
            }
        }
        let sum_sq = (sum_sq[0] + sum_sq[1]) + (sum_sq[2] + sum_sq[3]);
        let max = max.iter().fold(0.0_f64, |m, v| m.max(*v));
        HeadingError {
            rms_deg: (sum_sq / YAWS as f64).sqrt().to_degrees(),
            max_deg: max.to_degrees(),
        }
    }

    /// `w_k = (dot_k, cross_k)` of the true and the calibrated horizontal field per yaw, as the
    /// arrays of dot and cross.
    #[inline(always)]
    fn products(&self, p: &Mat3, bias_nt: Vec3) -> [[f64; YAWS]; 2] {
        // Only the x and z rows of P matter: b_hat_x = P_0 . s - P_0 . O, the same for z.
        let (px, pz) = (p[0], p[2]);
        let (cx, cz) = (dot(px, bias_nt), dot(pz, bias_nt));
        let [s0, s1, s2] = &*self.readings;
        let [tx, tz] = &*self.horizontal;
        let mut w = [[0.0; YAWS]; 2];
        let [re, im] = &mut w;
        for k in 0..YAWS {
            let ux = px[0] * s0[k] + px[1] * s1[k] + px[2] * s2[k] - cx;
            let uz = pz[0] * s0[k] + pz[1] * s1[k] + pz[2] * s2[k] - cz;
            re[k] = tx[k] * ux + tz[k] * uz;
            im[k] = tx[k] * uz - tz[k] * ux;
        }
        w
    }

    /// The same by one `atan2` per yaw: the definition, for tests and comparison.
    pub fn error_by_atan2(&self, p: &Mat3, bias_nt: Vec3) -> HeadingError {
        let [re, im] = self.products(p, bias_nt);
        let e: Vec<f64> = re.iter().zip(&im).map(|(re, im)| im.atan2(*re)).collect();
        HeadingError {
            rms_deg: (e.iter().map(|v| v * v).sum::<f64>() / YAWS as f64).sqrt().to_degrees(),
            max_deg: e.iter().fold(0.0_f64, |m, v| m.max(v.abs())).to_degrees(),
        }
    }
}

/// [`HeadingProbe::error`], compiled for baseline x86-64 and for AVX2, chosen at run time (as the
/// PSO kernel in `design/lanes.rs`; bit-identical: no fused multiply-add is ever formed).
#[multiversion::multiversion(targets("x86_64+avx2+avx"))]
fn error_kernel(probe: &HeadingProbe, p: &Mat3, bias_nt: Vec3) -> HeadingError {
    probe.error_body(p, bias_nt)
}

/// Largest bound on `|tan|` of an angle from the anchor summed from its series (about 8.5
/// degrees).
const SMALL: f64 = 0.15;

/// `atan(x)` from its series to `x^(2 TERMS + 1)`: within `|x|^(2 TERMS + 3) / (2 TERMS + 3)`.
/// Used with 2 terms for `|x| <= 0.005` (below 1.2e-17 rad), 4 for `|x| <= 0.02` (below 2e-20),
/// 6 for `|x| <= 0.05` (below 3e-21) and 9 for `|x| <= SMALL` (below 2.5e-19).
#[inline(always)]
fn atan_series<const TERMS: usize>(x: f64) -> f64 {
    const C: [f64; 9] = [
        -1.0 / 3.0,
        1.0 / 5.0,
        -1.0 / 7.0,
        1.0 / 9.0,
        -1.0 / 11.0,
        1.0 / 13.0,
        -1.0 / 15.0,
        1.0 / 17.0,
        -1.0 / 19.0,
    ];
    let z = x * x;
    let mut p = C[TERMS - 1];
    for c in C[..TERMS - 1].iter().rev() {
        p = c + z * p;
    }
    x * (1.0 + z * p)
}

/// Independent accumulators, in a fixed order (the same bits on every target).
const LANES: usize = 4;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::paper;

    #[test]
    fn conventions_check_values() {
        // docs/conventions.md "Heading error of a calibration", Changsha, [P1] truth (rms / max, deg).
        let truth = paper::true_error_model();
        let probe = HeadingProbe::new(&paper::changsha_field(), &truth);
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let s = truth.scale();
        let inverse_scale = [[1.0 / s[0], 0.0, 0.0], [0.0, 1.0 / s[1], 0.0], [0.0, 0.0, 1.0 / s[2]]];
        for (p, o, rms, max) in [
            (identity, [0.0; 3], 5.278, 8.787),
            (identity, truth.bias_nt(), 1.935, 3.787),
            (inverse_scale, truth.bias_nt(), 1.044, 2.104),
        ] {
            let e = probe.error(&p, o);
            assert!(
                (e.rms_deg - rms).abs() <= 5e-4 && (e.max_deg - max).abs() <= 5e-4,
                "{e:?} vs {rms} / {max}"
            );
        }
        // The true calibration has no heading error.
        let exact = probe.error(&truth.P(), truth.bias_nt());
        assert!(exact.max_deg < 1e-12, "{exact:?}");
    }

    #[test]
    fn series_agrees_with_one_atan2_per_yaw() {
        use crate::rng::stream_rng;
        use rand::RngExt;
        let truth = paper::true_error_model();
        let field = paper::changsha_field();
        let probe = HeadingProbe::new(&field, &truth);
        let mut rng = stream_rng(21, 0);
        let mut worst: f64 = 0.0;
        for i in 0..5000 {
            // From near the truth to absurd: P and O perturbed by 1e-6 to 10 relative.
            let spread = 10f64.powf(rng.random_range(-6.0..1.0));
            let mut p = truth.P();
            for (i, row) in p.iter_mut().enumerate() {
                let diagonal = row[i];
                for v in &mut row[i..] {
                    *v += spread * rng.random_range(-1.0..1.0) * diagonal;
                }
            }
            let r = field.magnitude();
            let o = truth.bias_nt().map(|v| v + spread * r * rng.random_range(-1.0..1.0));
            let (a, b) = (probe.error(&p, o), probe.error_by_atan2(&p, o));
            let tol = 1e-12_f64.to_degrees();
            assert!(
                (a.rms_deg - b.rms_deg).abs() <= tol && (a.max_deg - b.max_deg).abs() <= tol,
                "{i}: {a:?} {b:?}"
            );
            worst = worst.max((a.rms_deg - b.rms_deg).abs());
        }
        assert!(worst < 1e-12_f64.to_degrees());
    }

    #[test]
    fn curves_around_zero_agree_with_one_atan2_per_yaw() {
        // A calibration that mirrors the horizontal plane (w turns twice per turn, its mean is
        // near zero), one that turns it around, and two that remove one of its axes: the fallback
        // path.
        let truth = paper::true_error_model();
        let probe = HeadingProbe::new(&paper::changsha_field(), &truth);
        let p = truth.P();
        for (zx, zz) in [(1.0, -1.0), (0.0, 1.0), (1.0, 0.0), (-1.0, -1.0)] {
            let q = [p[0].map(|v| v * zx), p[1], p[2].map(|v| v * zz)];
            let (a, b) = (
                probe.error(&q, truth.bias_nt()),
                probe.error_by_atan2(&q, truth.bias_nt()),
            );
            let tol = 1e-12_f64.to_degrees();
            assert!(
                (a.rms_deg - b.rms_deg).abs() <= tol && (a.max_deg - b.max_deg).abs() <= tol,
                "{zx} {zz}: {a:?} {b:?}"
            );
        }
    }

    #[test]
    fn every_target_gives_the_same_bits() {
        use crate::rng::stream_rng;
        use rand::RngExt;
        // The run-time clone (AVX2 where the CPU has it) against the body compiled here, for the
        // baseline target.
        let truth = paper::true_error_model();
        let probe = HeadingProbe::new(&paper::changsha_field(), &truth);
        let mut rng = stream_rng(23, 0);
        for _ in 0..1000 {
            let mut p = truth.P();
            for (i, row) in p.iter_mut().enumerate() {
                let diagonal = row[i];
                for v in &mut row[i..] {
                    *v += 0.05 * rng.random_range(-1.0..1.0) * diagonal;
                }
            }
            let o = truth.bias_nt().map(|v| v + rng.random_range(-2000.0..2000.0));
            let (a, b) = (probe.error(&p, o), probe.error_body(&p, o));
            assert_eq!(
                (a.rms_deg.to_bits(), a.max_deg.to_bits()),
                (b.rms_deg.to_bits(), b.max_deg.to_bits())
            );
        }
    }

    #[test]
    fn the_yaw_offset_only_reorders_the_yaws() {
        let truth = paper::true_error_model();
        let a = HeadingProbe::new(&paper::changsha_field(), &truth);
        let b = HeadingProbe::new(&paper::changsha_field().with_yaw_offset_deg(90.0).unwrap(), &truth);
        let (ea, eb) = (a.error(&truth.P(), [0.0; 3]), b.error(&truth.P(), [0.0; 3]));
        assert!((ea.rms_deg - eb.rms_deg).abs() < 1e-12 && (ea.max_deg - eb.max_deg).abs() < 1e-12);
    }
}
