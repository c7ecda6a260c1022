//! Why a calibration could not produce an estimate, and the status recorded for every trial.

/// A calibration that produced no estimate. Each is an outcome to record, never a reason to abort a
/// batch: the Monte Carlo runner counts them as failed trials.
// Serialize only: it names its parts with `&'static str`, which a reader cannot borrow for ever.
#[derive(Debug, Clone, PartialEq, thiserror::Error, serde::Serialize)]
#[non_exhaustive]
pub enum CalibrationError {
    /// Fewer readings than the 9 unknowns of \[P1\] eq. (9).
    #[error("{got} readings, at least {needed} are needed")]
    TooFewReadings {
        /// Readings given.
        got: usize,
        /// Readings needed.
        needed: usize,
    },
    /// A reading component is NaN or infinite.
    #[error("reading {index} component {component} is not finite ({value})")]
    NonFiniteReading {
        /// Index of the reading (0-based).
        index: usize,
        /// Component 0, 1, 2 for x, y, z.
        component: usize,
        /// The value.
        value: f64,
    },
    /// The reference field magnitude is not a positive finite number.
    #[error("field magnitude must be positive and finite, got {value} nT")]
    InvalidFieldMagnitude {
        /// The value, nT.
        value: f64,
    },
    /// `H` of \[P1\] eq. (10) has numerical rank below 9: the readings do not determine a quadric.
    #[error("the regression matrix H has rank {rank}, {needed} are needed (readings too alike)")]
    RankDeficient {
        /// Numerical rank found.
        rank: usize,
        /// Rank needed.
        needed: usize,
    },
    /// The fitted quadric is not an ellipsoid: `G` of \[P1\] eq. (7) is not positive definite.
    #[error("the fitted quadric is not an ellipsoid: G is not positive definite ({reason})")]
    NotPositiveDefinite {
        /// What failed.
        reason: &'static str,
    },
    /// The fit's [`crate::stop::Stop`] was requested before it finished (a deadline passed, a
    /// signal came): there is no estimate, whatever the readings determine.
    #[error("stopped before it finished")]
    Stopped,
}

/// The status of a calibration, as written in a trial's row.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub enum CalibrationStatus {
    /// Both steps succeeded and step 2 converged.
    Ok,
    /// Both steps produced estimates, but step 2 reached its iteration limit.
    NotConverged,
    /// Both steps produced estimates, but the readings do not determine them: step 2 ran along a
    /// flat direction, or its local standard deviations exceed the physical scales.
    NotIdentifiable,
    /// [`CalibrationError::TooFewReadings`].
    TooFewReadings,
    /// [`CalibrationError::NonFiniteReading`] or [`CalibrationError::InvalidFieldMagnitude`].
    NonFiniteInput,
    /// [`CalibrationError::RankDeficient`].
    RankDeficient,
    /// [`CalibrationError::NotPositiveDefinite`].
    NotPositiveDefinite,
}

impl CalibrationStatus {
    /// A stable snake_case name for files: `ok`, `not_converged`, `not_identifiable`,
    /// `too_few_readings`, `non_finite_input`, `rank_deficient`, `not_positive_definite`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::Ok => "ok",
            Self::NotConverged => "not_converged",
            Self::NotIdentifiable => "not_identifiable",
            Self::TooFewReadings => "too_few_readings",
            Self::NonFiniteInput => "non_finite_input",
            Self::RankDeficient => "rank_deficient",
            Self::NotPositiveDefinite => "not_positive_definite",
        }
    }

    /// Every status, in the order of [`Self::as_str`]'s match.
    pub const ALL: [Self; 7] = [
        Self::Ok,
        Self::NotConverged,
        Self::NotIdentifiable,
        Self::TooFewReadings,
        Self::NonFiniteInput,
        Self::RankDeficient,
        Self::NotPositiveDefinite,
    ];

    /// The status named `name` (as [`Self::as_str`] writes it).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.as_str() == name)
    }

    /// `true` when the calibration produced estimates (`Ok`, `NotConverged` or `NotIdentifiable`).
    pub fn has_estimate(&self) -> bool {
        matches!(self, Self::Ok | Self::NotConverged | Self::NotIdentifiable)
    }
}

impl std::fmt::Display for CalibrationStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl CalibrationError {
    /// The status this error is recorded as.
    pub fn status(&self) -> CalibrationStatus {
        match self {
            Self::TooFewReadings { .. } => CalibrationStatus::TooFewReadings,
            Self::NonFiniteReading { .. } | Self::InvalidFieldMagnitude { .. } => CalibrationStatus::NonFiniteInput,
            Self::RankDeficient { .. } => CalibrationStatus::RankDeficient,
            Self::NotPositiveDefinite { .. } => CalibrationStatus::NotPositiveDefinite,
            // A fit given up before it converged; no status of its own, so that the tables that
            // count every status keep their columns.
            Self::Stopped => CalibrationStatus::NotConverged,
        }
    }
}
