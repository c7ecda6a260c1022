//! The heading error of a calibration (CONVENTIONS.md "Heading error of a calibration"): what a
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
//! One `atan2` per yaw (`e_k = atan2(cross_k, dot_k)`) costs more than the rest of a Monte Carlo
//! trial of the \[P1\] design. Instead: one exact `atan2` at yaw 0, then the
//! increments `e_{k+1} - e_k = arg(w_{k+1} conj(w_k))`. For a calibration the heading error changes
//! little from one degree of yaw to the next, so each increment is a small angle `atan(x)`,
//! `x = Im / Re`, summed from its series to `x^13 / 13` (truncation below `0.05^15 / 15 < 3e-21`
//! for `|x| <= 0.05`, about 2.9 degrees); an increment that is not that small (or a `w` near zero)
//! is computed with `atan2` instead. The sums run as four interleaved chains of 90 yaws, each from
//! an exact anchor, so that their additions overlap; each value is wrapped to (-pi, pi]. Against
//! one `atan2` per yaw
//! the result agrees within 1e-12 rad (tested on calibrations from exact to absurd). The loop is
//! compiled a second time for AVX2 and chosen at run time, as the PSO kernel is (bit-identical,
//! tested). Medians of `heading_error/one_trial` on the 2-core machine, idle: one `atan2` per yaw
//! 4.6-4.9 us; increments 2.3-2.7 us; with the AVX2 clone 1.5-2.0 us; with four chains
//! 1.45-1.64 us.

use std::f64::consts::{PI, TAU};

use crate::attitude::Attitude;
use crate::field::ReferenceField;
use crate::sensor::ErrorModel;
use crate::small::{Mat3, Vec3, dot};

/// Yaws of the probe, one per degree.
pub const YAWS: usize = 360;

/// The heading error of one calibration: rms and maximum of `|e|` over the 360 yaws, degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
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
    /// `(b_x, b_z)` of the true body field per yaw.
    horizontal: Vec<[f64; 2]>,
    /// `s = K b + O` per yaw.
    readings: Vec<Vec3>,
}

impl HeadingProbe {
    /// The probe of `truth` in `field`.
    pub fn new(field: &ReferenceField, truth: &ErrorModel) -> Self {
        let body: Vec<Vec3> = (0..YAWS)
            .map(|k| field.body_field(&Attitude::from_degrees(0.0, k as f64, 0.0)))
            .collect();
        Self {
            horizontal: body.iter().map(|b| [b[0], b[2]]).collect(),
            readings: truth.measure_all(&body),
        }
    }

    /// The heading error of the calibration `b_hat = p (s - bias_nt)`.
    pub fn error(&self, p: &Mat3, bias_nt: Vec3) -> HeadingError {
        error_kernel(self, p, bias_nt)
    }

    #[inline(always)]
    fn error_body(&self, p: &Mat3, bias_nt: Vec3) -> HeadingError {
        let w = self.products(p, bias_nt);
        // Increments between consecutive yaws (the last one wraps to yaw 0 and is not used).
        let mut inc = [0.0; YAWS];
        let mut small = [true; YAWS];
        for k in 0..YAWS - 1 {
            let (a, b) = (w[k], w[k + 1]);
            // b conj(a)
            let re = b[0] * a[0] + b[1] * a[1];
            let im = b[1] * a[0] - b[0] * a[1];
            let x = im / re;
            let z = x * x;
            inc[k] = x
                * (1.0
                    + z * (-1.0 / 3.0
                        + z * (1.0 / 5.0 + z * (-1.0 / 7.0 + z * (1.0 / 9.0 + z * (-1.0 / 11.0 + z / 13.0))))));
            small[k] = re > 0.0 && x.abs() <= SMALL;
        }
        for k in (0..YAWS - 1).filter(|&k| !small[k]) {
            let (a, b) = (w[k], w[k + 1]);
            inc[k] = (b[1] * a[0] - b[0] * a[1]).atan2(b[0] * a[0] + b[1] * a[1]);
        }
        // Four chains of 90 yaws, each from an exact anchor, advanced together so that their
        // additions overlap; the sums are combined in a fixed order.
        const CHAINS: usize = 4;
        const LEN: usize = YAWS / CHAINS;
        let mut e: [f64; CHAINS] = std::array::from_fn(|c| w[c * LEN][1].atan2(w[c * LEN][0]));
        let mut sum_sq = e.map(|v| v * v);
        let mut max = e.map(f64::abs);
        for j in 0..LEN - 1 {
            for c in 0..CHAINS {
                let mut v = e[c] + inc[c * LEN + j];
                // Wrap to (-pi, pi].
                if v > PI {
                    v -= TAU;
                } else if v <= -PI {
                    v += TAU;
                }
                e[c] = v;
                sum_sq[c] += v * v;
                max[c] = max[c].max(v.abs());
            }
        }
        let sum_sq = (sum_sq[0] + sum_sq[1]) + (sum_sq[2] + sum_sq[3]);
        let max = max.iter().fold(0.0_f64, |m, v| m.max(*v));
        HeadingError {
            rms_deg: (sum_sq / YAWS as f64).sqrt().to_degrees(),
            max_deg: max.to_degrees(),
        }
    }

    /// `w_k = (dot_k, cross_k)` of the true and the calibrated horizontal field per yaw.
    #[inline(always)]
    fn products(&self, p: &Mat3, bias_nt: Vec3) -> [[f64; 2]; YAWS] {
        // Only the x and z rows of P matter: b_hat_x = P_0 . s - P_0 . O, the same for z.
        let (px, pz) = (p[0], p[2]);
        let (cx, cz) = (dot(px, bias_nt), dot(pz, bias_nt));
        let mut w = [[0.0; 2]; YAWS];
        for ((w, s), t) in w.iter_mut().zip(&self.readings).zip(&self.horizontal) {
            let ux = px[0] * s[0] + px[1] * s[1] + px[2] * s[2] - cx;
            let uz = pz[0] * s[0] + pz[1] * s[1] + pz[2] * s[2] - cz;
            *w = [t[0] * ux + t[1] * uz, t[0] * uz - t[1] * ux];
        }
        w
    }

    /// The same by one `atan2` per yaw: the definition, for tests and comparison.
    pub fn error_by_atan2(&self, p: &Mat3, bias_nt: Vec3) -> HeadingError {
        let w = self.products(p, bias_nt);
        let e: Vec<f64> = w.iter().map(|w| w[1].atan2(w[0])).collect();
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

/// Largest `|tan|` of an increment summed from its series (about 2.9 degrees).
const SMALL: f64 = 0.05;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::paper;

    #[test]
    fn conventions_check_values() {
        // CONVENTIONS.md "Heading error of a calibration", Changsha, [P1] truth (rms / max, deg).
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
    fn increments_agree_with_one_atan2_per_yaw() {
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
