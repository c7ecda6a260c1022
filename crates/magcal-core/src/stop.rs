//! A request to give up a long computation, made from outside it.
//!
//! The core keeps no clock. A caller that bounds a computation in time, or ends it on a signal,
//! hands it a [`Stop`] whose predicate says when to give up; the long loops ask it between their
//! steps: every Levenberg-Marquardt iteration of a fit ([`crate::calibration::step2`], through
//! [`crate::TwoStep::stop`] and [`crate::log_fit::FitSettings::stop`], so the fits of a check by
//! trials, of the held-out folds and of a profile ask it too), every round of a check by trials,
//! and in the approximate design every round, REX iteration, support point of an exchange and
//! start of the certificate's local search ([`crate::design::approximate`]).
//!
//! A computation that finds its stop requested returns as soon as it can, with nothing it has
//! not finished: the functions that take a `Stop` say what they return then
//! ([`crate::CalibrationError::Stopped`], [`Stopped`]). The default, [`Stop::NEVER`], is never
//! requested, and a computation given it takes the same steps and returns the same numbers as one
//! given none.

use std::sync::Arc;

/// When to give up: a predicate asked between the steps of a long computation.
///
/// The predicate must stay true once it has been (a deadline that has passed, a signal that has
/// come): the functions that take a `Stop` ask it once more before they return, and that answer
/// must cover every earlier one. It is asked often (every iteration of a fit, every support point
/// of an exchange of REX, about every millisecond in the worst case), so it should take well under
/// a microsecond: a clock read and an atomic load are about 20 ns.
#[derive(Clone, Default)]
pub struct Stop(Option<Arc<dyn Fn() -> bool + Send + Sync>>);

impl Stop {
    /// Never requested: the computation runs to its end.
    pub const NEVER: Self = Self(None);

    /// Requested when `requested` returns true, which must then stay true (see [`Stop`]).
    pub fn when(requested: impl Fn() -> bool + Send + Sync + 'static) -> Self {
        Self(Some(Arc::new(requested)))
    }

    /// Whether the computation should give up now.
    #[inline]
    pub fn requested(&self) -> bool {
        self.0.as_ref().is_some_and(|f| f())
    }

    /// `Err(Stopped)` when requested, else `value`: what a function that takes a `Stop` returns,
    /// so that a result made while it was requested (cut short somewhere inside) is never
    /// returned as if it were finished.
    pub fn unless_requested<T>(&self, value: T) -> Result<T, Stopped> {
        if self.requested() { Err(Stopped) } else { Ok(value) }
    }
}

impl std::fmt::Debug for Stop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "Stop::when(..)"
        } else {
            "Stop::NEVER"
        })
    }
}

/// Two stops are equal when both are [`Stop::NEVER`] or both ask the same predicate.
impl PartialEq for Stop {
    fn eq(&self, other: &Self) -> bool {
        match (&self.0, &other.0) {
            (None, None) => true,
            (Some(a), Some(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

/// A computation that was given up because its [`Stop`] was requested: it has no result.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("stopped before it finished")]
pub struct Stopped;

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};

    #[test]
    fn a_stop_is_requested_when_its_predicate_says() {
        assert!(!Stop::NEVER.requested());
        assert!(!Stop::default().requested());
        assert_eq!(Stop::NEVER.unless_requested(7), Ok(7));
        let flag = Arc::new(AtomicBool::new(false));
        let raised = Arc::clone(&flag);
        let stop = Stop::when(move || raised.load(Ordering::Relaxed));
        assert!(!stop.requested());
        assert_eq!(stop.unless_requested("done"), Ok("done"));
        flag.store(true, Ordering::Relaxed);
        assert!(stop.requested());
        assert_eq!(stop.clone().unless_requested(1), Err(Stopped));
        // A clone asks the same predicate; another stop does not equal it.
        assert_eq!(stop.clone(), stop);
        assert_ne!(stop, Stop::when(|| true));
        assert_ne!(stop, Stop::NEVER);
        assert_eq!(Stop::NEVER, Stop::default());
        assert_eq!(format!("{:?}", Stop::NEVER), "Stop::NEVER");
    }
}
