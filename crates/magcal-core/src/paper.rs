//! The numbers of \[P1\] section IV as values: site field, true sensor errors, the AUV attitude box,
//! the two designs of Table II, and the PSO settings of Table I live with the optimiser.
//!
//! Readings of the paper that it leaves open are fixed by docs/conventions.md and noted at each item.

use crate::attitude::{Attitude, AttitudeBox};
use crate::field::ReferenceField;
use crate::sensor::ErrorModel;

/// Noise standard deviation of the \[P1\] Monte Carlo runs, nT per component (section IV.C).
pub const SIGMA_NT: f64 = 30.0;

/// Number of Monte Carlo runs per design in \[P1\] section IV.C.
pub const TRIALS: usize = 1000;

/// The best `ln det M_F` known for the \[P1\] AUV box with m = 9 (docs/conventions.md).
pub const BEST_KNOWN_LN_DET: f64 = 314.54855;

/// The reference field at Changsha: WMM2010 at 28.2 N, 112.97 E, sea level, epoch 2013.0,
/// X = 35272.34, Y = -2085.74, Z = 32897.67 nT (docs/conventions.md; \[P1\] IV.A names the site only).
pub fn changsha_field() -> ReferenceField {
    ReferenceField::from_ned(35272.34, -2085.74, 32897.67).expect("constant field is valid")
}

/// The true sensor errors of \[P1\] IV.A: psi = (1.5, 0.8, 1.4) deg, S = (1.3, 0.7, 1.2),
/// O = (3000, -6000, 5000) nT.
pub fn true_error_model() -> ErrorModel {
    ErrorModel::new([1.5, 0.8, 1.4], [1.3, 0.7, 1.2], [3000.0, -6000.0, 5000.0]).expect("constant model is valid")
}

/// The AUV's attitude box of \[P1\] IV.A: roll [-5, 5], yaw [-180, 180], pitch [-20, 20] degrees.
pub fn auv_box() -> AttitudeBox {
    AttitudeBox::from_degrees([-5.0, 5.0], [-180.0, 180.0], [-20.0, 20.0]).expect("constant box is valid")
}

/// \[P1\] Table II, Uniformity design, `[roll yaw pitch]` in degrees.
pub const UNIFORMITY_DESIGN_DEG: [[f64; 3]; 9] = [
    [-5.0, -60.0, -20.0],
    [-5.0, 60.0, -20.0],
    [-5.0, 180.0, -20.0],
    [0.0, -90.0, 0.0],
    [0.0, 0.0, 0.0],
    [0.0, 90.0, 0.0],
    [0.0, 180.0, 0.0],
    [5.0, -60.0, 20.0],
    [5.0, 60.0, 20.0],
];

/// \[P1\] Table II, D-optimal design as printed, `[roll yaw pitch]` in degrees. docs/conventions.md: it
/// scores below the Uniformity design, so it cannot be what produced the paper's figures.
pub const TABLE2_D_OPTIMAL_DEG: [[f64; 3]; 9] = [
    [-5.0, -37.0, -20.0],
    [-5.0, -145.0, -20.0],
    [-5.0, -10.0, -6.0],
    [0.0, 24.5, 20.0],
    [-3.2, -96.0, 7.0],
    [-1.3, 178.0, -20.0],
    [-1.4, 180.0, -20.0],
    [2.1, -35.0, 20.0],
    [-5.0, -137.5, 20.0],
];

/// Attitudes from `[roll yaw pitch]` rows in degrees.
pub fn attitudes_from_degrees(rows: &[[f64; 3]]) -> Vec<Attitude> {
    rows.iter().map(|&[r, y, p]| Attitude::from_degrees(r, y, p)).collect()
}

/// The D-optimal design of the AUV box (m = 9, yaw offset 0) that docs/conventions.md "Identifiability
/// and the Cramer-Rao floor" uses for its check values (angles to 3 decimals).
pub fn conventions_optimum() -> Vec<Attitude> {
    attitudes_from_degrees(&[
        [-5.0, -39.440, -20.0],
        [-5.0, -124.369, 20.0],
        [-5.0, 30.364, 20.0],
        [-4.243, 174.298, -10.117],
        [3.778, -0.309, -3.253],
        [5.0, 37.236, -20.0],
        [5.0, 93.384, 7.939],
        [5.0, -58.296, 20.0],
        [5.0, 157.595, 20.0],
    ])
}

/// \[P1\] Table II, Uniformity design.
pub fn uniformity_design() -> Vec<Attitude> {
    attitudes_from_degrees(&UNIFORMITY_DESIGN_DEG)
}

/// \[P1\] Table II, D-optimal design as printed.
pub fn table2_d_optimal() -> Vec<Attitude> {
    attitudes_from_degrees(&TABLE2_D_OPTIMAL_DEG)
}
