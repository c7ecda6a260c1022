//! Sensors that exist (docs/conventions.md "Plausible sensors"): a calibration whose sensor no
//! magnetometer is cannot be usable, whatever its trials say, since the trials are drawn from it.
//!
//! - The axes' scale factors within [`PLAUSIBLE_SCALE_RATIO`] of each other: a magnetometer's
//!   axes have the same sensitivity to a few percent (the AK8963's factory adjustment spans 0.5
//!   to 1.5 of nominal, a ratio of 3 at its extremes), a vehicle's soft iron changes them by tens
//!   of percent; on the public logs the largest over the smallest is 1.02 to 1.14, \[P1\]'s sensor
//!   1.86. An ellipsoid flattened towards a disc (a log turning about one axis, a narrow log)
//!   leaves one axis's scale far from the others' (113 to 1 for a circle about the vertical).
//! - The non-orthogonality within [`PLAUSIBLE_PSI_DEG`]: a sensor's axes are within a degree or
//!   two of orthogonal, soft iron adds a few (public logs: at most 3.8 degrees; \[P1\]'s sensor
//!   1.5).
//! - Where the field's magnitude is known (a site, or given), every scale factor within
//!   [`PLAUSIBLE_SCALE`] of the field's: ArduPilot's onboard calibration takes radii of 150 to 950
//!   mGauss for fields of 250 to 850; a factor of two either way is a wrong magnitude or units.

use crate::sensor::ErrorModel;

/// Largest non-orthogonality of a plausible sensor, degrees.
pub const PLAUSIBLE_PSI_DEG: f64 = 10.0;

/// Largest ratio of a plausible sensor's axis scale factors.
pub const PLAUSIBLE_SCALE_RATIO: f64 = 3.0;

/// Scale factors of a plausible sensor against a known field.
pub const PLAUSIBLE_SCALE: [f64; 2] = [0.5, 2.0];

/// Why `e` is not a plausible magnetometer, if it is not; `absolute`: its scale factors are
/// against a known field's magnitude (else relative to the fit's own radius).
pub fn implausible(e: &ErrorModel, absolute: bool) -> Option<String> {
    let (psi, s) = (e.psi_deg(), e.scale());
    let mut why = Vec::new();
    // Not within the limit, NaN included.
    let within = |v: f64, limit: f64| v.partial_cmp(&limit).is_some_and(|o| o.is_le());
    if let Some(p) = psi.iter().find(|p| !within(p.abs(), PLAUSIBLE_PSI_DEG)) {
        why.push(format!(
            "a non-orthogonality of {p:.2} deg (at most {PLAUSIBLE_PSI_DEG})"
        ));
    }
    let (lo, hi) = (
        s.iter().copied().fold(f64::INFINITY, f64::min),
        s.iter().copied().fold(0.0, f64::max),
    );
    let ratio = hi / lo;
    if !within(ratio, PLAUSIBLE_SCALE_RATIO) {
        why.push(format!(
            "axes whose scale factors differ {} to 1 (at most {PLAUSIBLE_SCALE_RATIO}; an ellipsoid flattened towards a disc or a needle: the readings do not determine the model)",
            super::significant(ratio, 3)
        ));
    }
    if absolute
        && let Some(x) = s
            .iter()
            .find(|x| !(PLAUSIBLE_SCALE[0]..=PLAUSIBLE_SCALE[1]).contains(*x))
    {
        why.push(format!(
            "a scale factor of {} against the field's magnitude ({} to {}: a wrong magnitude or units)",
            super::significant(*x, 4),
            PLAUSIBLE_SCALE[0],
            PLAUSIBLE_SCALE[1]
        ));
    }
    (!why.is_empty()).then(|| {
        format!(
            "not a plausible sensor: psi ({:.2}, {:.2}, {:.2}) deg, scale factors ({:.4}, {:.4}, {:.4}): {}",
            psi[0],
            psi[1],
            psi[2],
            s[0],
            s[1],
            s[2],
            why.join("; ")
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_papers_sensor_is_plausible_and_a_disc_is_not() {
        let paper = crate::paper::true_error_model();
        assert_eq!(implausible(&paper, false), None);
        assert_eq!(implausible(&paper, true), None);
        let disc = ErrorModel::new([0.0; 3], [4.83, 4.83, 0.043], [0.0; 3]).unwrap();
        let why = implausible(&disc, false).unwrap();
        assert!(why.contains("differ 112 to 1"), "{why}");
        let skew = ErrorModel::new([0.0, 34.1, 0.0], [1.0; 3], [0.0; 3]).unwrap();
        assert!(
            implausible(&skew, false)
                .unwrap()
                .contains("non-orthogonality of 34.10 deg")
        );
        let small = ErrorModel::new([0.0; 3], [0.4, 0.45, 0.42], [0.0; 3]).unwrap();
        assert_eq!(implausible(&small, false), None);
        assert!(implausible(&small, true).unwrap().contains("a scale factor of 0.4000"));
    }
}
