//! Errors for invalid parameters (the caller's input), as opposed to failures of a fit, which live in
//! [`crate::calibration::CalibrationError`].

/// A parameter outside its domain. Each variant names the parameter and carries the offending value,
/// so that a front end can report it against the key of its input file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ParameterError {
    /// A value that must be finite is NaN or infinite.
    #[error("{name} must be finite, got {value}")]
    NonFinite {
        /// Parameter name.
        name: &'static str,
        /// The value given.
        value: f64,
    },
    /// A range whose minimum is not below its maximum.
    #[error("{name}: minimum {min} must be below maximum {max}")]
    EmptyRange {
        /// Parameter name.
        name: &'static str,
        /// Lower bound given.
        min: f64,
        /// Upper bound given.
        max: f64,
    },
    /// A value that must be strictly positive is not.
    #[error("{name} must be positive, got {value}")]
    NotPositive {
        /// Parameter name.
        name: &'static str,
        /// The value given.
        value: f64,
    },
    /// A value that must not be negative is.
    #[error("{name} must not be negative, got {value}")]
    Negative {
        /// Parameter name.
        name: &'static str,
        /// The value given.
        value: f64,
    },
    /// A count below its minimum.
    #[error("{name} must be at least {min}, got {value}")]
    TooSmall {
        /// Parameter name.
        name: &'static str,
        /// Smallest allowed value.
        min: usize,
        /// The value given.
        value: usize,
    },
    /// A value outside an open or closed interval.
    #[error("{name} must lie in {allowed}, got {value}")]
    OutOfRange {
        /// Parameter name.
        name: &'static str,
        /// The allowed interval, as text (for example `"(-90, 90) degrees"`).
        allowed: &'static str,
        /// The value given.
        value: f64,
    },
}

/// `Ok(value)` when finite, else [`ParameterError::NonFinite`].
pub(crate) fn finite(name: &'static str, value: f64) -> Result<f64, ParameterError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(ParameterError::NonFinite { name, value })
    }
}
