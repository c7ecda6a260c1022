//! The heading error of a calibration (CONVENTIONS.md "Heading error of a calibration"): what a
//! navigator loses by flying with it.
//!
//! At roll = pitch = 0 and yaw 0, 1, ..., 359 degrees (with the field's yaw offset), the true body
//! field `b` (\[P1\] eq. (1)-(2)), the noise-free reading `s = K b + O` (\[P1\] eq. (5)) and the
//! calibrated field `b_hat = P_hat (s - O_hat)` (\[P1\] eq. (6)) give the heading error
//! `e = atan2(b_hat_z, b_hat_x) - atan2(b_z, b_x)`, wrapped to (-180, 180]. Reported: its rms and
//! maximum over the 360 yaws, degrees.
//!
//! The error is computed as the angle from `(b_x, b_z)` to `(b_hat_x, b_hat_z)`,
//! `atan2(cross, dot)`: the wrapped difference of the two headings in one call.

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
        // Only the x and z rows of P matter: b_hat_x = P_0 . s - P_0 . O, the same for z.
        let (px, pz) = (p[0], p[2]);
        let (cx, cz) = (dot(px, bias_nt), dot(pz, bias_nt));
        let mut e = [0.0; YAWS];
        for ((e, s), t) in e.iter_mut().zip(&self.readings).zip(&self.horizontal) {
            let ux = px[0] * s[0] + px[1] * s[1] + px[2] * s[2] - cx;
            let uz = pz[0] * s[0] + pz[1] * s[1] + pz[2] * s[2] - cz;
            *e = (t[0] * uz - t[1] * ux).atan2(t[0] * ux + t[1] * uz);
        }
        let sum_sq: f64 = e.iter().map(|v| v * v).sum();
        let max = e.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        HeadingError {
            rms_deg: (sum_sq / YAWS as f64).sqrt().to_degrees(),
            max_deg: max.to_degrees(),
        }
    }
}

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
    fn the_yaw_offset_only_reorders_the_yaws() {
        let truth = paper::true_error_model();
        let a = HeadingProbe::new(&paper::changsha_field(), &truth);
        let b = HeadingProbe::new(&paper::changsha_field().with_yaw_offset_deg(90.0).unwrap(), &truth);
        let (ea, eb) = (a.error(&truth.P(), [0.0; 3]), b.error(&truth.P(), [0.0; 3]));
        assert!((ea.rms_deg - eb.rms_deg).abs() < 1e-12 && (ea.max_deg - eb.max_deg).abs() < 1e-12);
    }
}
