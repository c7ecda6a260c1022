//! Errors for invalid parameters (the caller's input), as opposed to failures of a fit, which live in
//! [`crate::calibration::CalibrationError`].
//!
//! Each variant names the core parameter (`"particles"`, `"lat_deg"`, `"psi_deg"`): the name of the
//! field or argument of this crate, never a key of some input file. A front end that knows which
//! key it passed adds it, as globset's `Error { glob, kind }` does.

/// A parameter outside its domain. Each variant names the parameter and carries the offending value,
/// so that a front end can report it against the key of its input file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ParameterError {
    /// A value that must be finite is NaN or infinite.
    #[error("{name} must be finite, got {}", show(*.value))]
    NonFinite {
        /// Parameter name.
        name: &'static str,
        /// The value given.
        value: f64,
    },
    /// A range whose minimum is not below its maximum.
    #[error("{name}: minimum {} must be below maximum {}", show(*.min), show(*.max))]
    EmptyRange {
        /// Parameter name.
        name: &'static str,
        /// Lower bound given.
        min: f64,
        /// Upper bound given.
        max: f64,
    },
    /// A value that must be strictly positive is not.
    #[error("{name} must be positive, got {}", show(*.value))]
    NotPositive {
        /// Parameter name.
        name: &'static str,
        /// The value given.
        value: f64,
    },
    /// A value that must not be negative is.
    #[error("{name} must not be negative, got {}", show(*.value))]
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
    /// A count above what can be represented or computed.
    #[error("{name} must be at most {max}, got {value}")]
    TooLarge {
        /// Parameter name.
        name: &'static str,
        /// Largest allowed value.
        max: usize,
        /// The value given (saturated at `usize::MAX` when it overflowed).
        value: usize,
    },
    /// A value outside an open or closed interval.
    #[error("{name} must lie in {allowed}, got {}", show(*.value))]
    OutOfRange {
        /// Parameter name.
        name: &'static str,
        /// The allowed interval, as text (for example `"(-90, 90) degrees"`).
        allowed: &'static str,
        /// The value given.
        value: f64,
    },
    /// A date outside the five-year validity window of a World Magnetic Model release
    /// ([`crate::wmm::field_ned`]); the parameter is `year`.
    #[error("year must lie in the model's validity window (epoch to epoch + 5 years), got {}", show(*.year))]
    OutsideValidityWindow {
        /// The model asked for.
        model: crate::wmm::Model,
        /// The decimal year given.
        year: f64,
    },
    /// Inputs under which no design identifies the linear model (\[P1\] eq. (9)): every
    /// information matrix is singular (for example an attitude box too small to turn the field).
    #[error("{name}: no design in it identifies the 9 unknowns of the linear model")]
    Singular {
        /// Parameter name.
        name: &'static str,
    },
}

impl ParameterError {
    /// The core parameter the error is about.
    pub fn name(&self) -> &'static str {
        match self {
            Self::NonFinite { name, .. }
            | Self::EmptyRange { name, .. }
            | Self::NotPositive { name, .. }
            | Self::Negative { name, .. }
            | Self::TooSmall { name, .. }
            | Self::TooLarge { name, .. }
            | Self::OutOfRange { name, .. }
            | Self::Singular { name } => name,
            Self::OutsideValidityWindow { .. } => "year",
        }
    }

    /// The value given, where it is a real number (a count, a range and a singular input have
    /// none).
    pub fn value(&self) -> Option<f64> {
        match *self {
            Self::NonFinite { value, .. }
            | Self::NotPositive { value, .. }
            | Self::Negative { value, .. }
            | Self::OutOfRange { value, .. } => Some(value),
            Self::OutsideValidityWindow { year, .. } => Some(year),
            Self::EmptyRange { .. } | Self::TooSmall { .. } | Self::TooLarge { .. } | Self::Singular { .. } => None,
        }
    }

    /// What the parameter must satisfy, without its name or value: `"must be at least 1"`.
    pub fn requirement(&self) -> String {
        match self {
            Self::NonFinite { .. } => "must be a finite number".into(),
            Self::EmptyRange { .. } => "the minimum must be below the maximum".into(),
            Self::NotPositive { .. } => "must be positive".into(),
            Self::Negative { .. } => "must not be negative".into(),
            Self::TooSmall { min, .. } => format!("must be at least {min}"),
            Self::TooLarge { max, .. } => format!("must be at most {max}"),
            Self::OutOfRange { allowed, .. } => format!("must lie in {allowed}"),
            Self::Singular { .. } => "must let some design identify the linear model".into(),
            Self::OutsideValidityWindow { .. } => {
                "must lie in the model's validity window (epoch to epoch + 5 years)".into()
            }
        }
    }
}

/// `Ok(value)` when finite, else [`ParameterError::NonFinite`].
pub(crate) fn finite(name: &'static str, value: f64) -> Result<f64, ParameterError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(ParameterError::NonFinite { name, value })
    }
}

/// A number as a person wrote it, for messages that echo one: `-60`, `0.25`, `1e308`, `5e-324`
/// (never the 309 digits of `1e308` in plain notation).
pub fn show(x: f64) -> String {
    let a = x.abs();
    if x != 0.0 && a.is_finite() && !(1e-4..1e16).contains(&a) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}
