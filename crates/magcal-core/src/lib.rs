//! # magcal-core
//!
//! The mathematics of strapdown three-axis magnetometer calibration and of the D-optimal choice of
//! calibration attitudes, after \[P1\]. No files, no printing, no clocks, no global state: every
//! random draw takes an RNG passed in (see [`rng`]).
//!
//! ## The pipeline
//! attitudes ([`Attitude`], inside an [`AttitudeBox`]) -> body-frame field ([`ReferenceField`]) ->
//! sensor readings ([`ErrorModel`], with noise drawn from a passed-in RNG) -> linear model and
//! information matrix ([`linear_model`]) -> two-step calibration ([`TwoStep`]) -> relative errors
//! and statistics ([`metrics`]).
//!
//! ```
//! use magcal_core::{RelativeErrors, TwoStep, paper, rng::stream_rng};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let field = paper::changsha_field();
//! let truth = paper::true_error_model();
//! let body = field.body_fields(&paper::uniformity_design());
//! let mut rng = stream_rng(2014, 0);
//! let readings = truth.noisy_readings(&body, paper::SIGMA_NT, &mut rng)?;
//! let fit = TwoStep::default().calibrate(&readings, field.magnitude())?;
//! let eta = RelativeErrors::between(&fit.estimate().model, &truth);
//! assert!(eta.scale.is_some_and(|e| e < 10.0)); // percent; None only where the truth is zero
//! # Ok(())
//! # }
//! ```
//!
//! The results a user keeps (sensor models, attitudes and boxes, fits, designs, certificates,
//! statistics, alignments) are `serde::Serialize`, and all but those that name their parts with
//! `&'static str` ([`log_fit::LogFit`], its profile and auto reasons, [`CalibrationError`]) read
//! back with `serde::Deserialize`; those that will grow are `#[non_exhaustive]`. The example
//! `fit_and_save` fits a known sensor and saves the fit as JSON.
//!
//! ## Equation index
//! | \[P1\] | item |
//! |---|---|
//! | eq. (1) | [`ReferenceField::body_field`]; `B^n` from the WMM: [`wmm::field_ned`] |
//! | eq. (2) | [`Attitude::dcm`] |
//! | eq. (3)-(4) | [`AttitudeBox`] |
//! | eq. (5) | [`ErrorModel`], [`ErrorModel::K`], [`ErrorModel::noisy_readings`] |
//! | eq. (6) | [`ErrorModel::P`] |
//! | eq. (7) | [`ErrorModel::G`], [`calibration::step1::linear_fit`] |
//! | eq. (8)-(9) | [`linear_model::regression_row`] |
//! | eq. (10) | [`linear_model::design_matrix`] |
//! | eq. (11) | [`calibration::step1::linear_fit`] |
//! | eq. (12)-(14) | [`linear_model::InformationMatrix`], [`linear_model::Conditioning`] |
//! | eq. (21)-(23) | [`metrics::relative_error_percent`], [`RelativeErrors`] |
//! | section IV.A, Table II | [`paper`] |
//! | section IV.C, two-step method | [`TwoStep`], [`calibration::step2`] |
//! | section IV.C, Monte Carlo trials | [`monte_carlo::trial`] |
//! | eq. (5), (13): the Cramer-Rao floor and identifiability | [`identifiability::CramerRao`] |
//! | eq. (1)-(2), (5)-(6): heading error of a calibration | [`heading::HeadingProbe`] |
//! | eq. (6), IV.C: heading against a reference attitude | [`reference::align`] |
//! | eq. (5)-(6) with reference attitudes: vector calibration, `K^-1 = A P` | [`vector::fit_vector`] |
//!
//! ## References
//! - \[P1\] Z. Wu, X. Hu, M. Wu, P. Liu, "D-Optimal Design Applied to Calibration of Strapdown
//!   Three-axis Magnetometer". Readings of the paper that it leaves open follow the project's
//!   docs/conventions.md.
//! - D. Gebre-Egziabher, G. H. Elkaim, J. D. Powell, B. W. Parkinson, "Calibration of Strapdown
//!   Magnetometers in Magnetic Field Domain", ASCE J. Aerospace Eng. 19, 2006 (the two-step method).
//! - K. Madsen, H. B. Nielsen, O. Tingleff, "Methods for Non-Linear Least Squares Problems", 2004
//!   (the Levenberg-Marquardt damping of [`calibration::step2`]).
#![warn(missing_docs)]
#![deny(clippy::float_cmp)]

pub mod attitude;
pub mod aviation;
pub mod budget;
pub mod calibration;
pub mod chunked;
pub mod design;
pub mod error;
pub mod field;
pub mod flight;
pub mod heading;
pub mod identifiability;
pub mod linear_model;
pub mod log_fit;
pub mod metrics;
pub mod monte_carlo;
pub mod paper;
pub mod reference;
pub mod replay;
pub mod rng;
pub mod sensor;
pub mod small;
pub mod stop;
pub mod vector;
pub mod wmm;

pub use attitude::{AngleRange, Attitude, AttitudeBox};
pub use calibration::{
    Calibration, CalibrationError, CalibrationOutcome, CalibrationStatus, Estimate, Termination, TwoStep,
};
pub use error::ParameterError;
pub use field::ReferenceField;
pub use identifiability::{CramerRao, PhysicalScales, Verdict};
pub use linear_model::{Conditioning, InformationMatrix};
pub use metrics::{AbsoluteErrors, RelativeErrors, Summary};
pub use sensor::ErrorModel;
pub use small::{Mat3, Vec3};
