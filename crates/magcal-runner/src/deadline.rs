//! A bound in time on one piece of work, and an end asked from outside it (a signal): what
//! `live` fits the stream within ([`crate::commands::calibrate::calibrate_within`],
//! [`crate::commands::next::suggestion_within`]).
//!
//! The core keeps no clock: it asks a [`Stop`] between the steps of its long loops (every
//! iteration of a fit, every round of a check by trials, every support point of the certificate's
//! exchanges), and a deadline is the `Stop` that says yes once the time is up or the work is
//! ended. The stages of the work look at [`Deadline::expired`] between them: a stage with no time
//! left is skipped, and one the deadline cut short is thrown away; either is said in words
//! ([`Deadline::skipped`]) where its result would have been.

use std::sync::Arc;
use std::time::{Duration, Instant};

use magcal_core::stop::Stop;

/// When a piece of work must give up: at a time, when something outside it says so, both, or
/// never ([`Deadline::none`]).
#[derive(Clone, Default)]
pub struct Deadline {
    /// The bound and the time it ends at; `None`: no bound in time.
    limit: Option<(Duration, Instant)>,
    /// Ends the work when it returns true (a signal's flag).
    ended: Option<Arc<dyn Fn() -> bool + Send + Sync>>,
}

impl Deadline {
    /// No bound: the work runs to its end, taking the same steps and giving the same results as
    /// without a deadline (what `calibrate` and `next` do).
    pub fn none() -> Self {
        Self::default()
    }

    /// `limit` from now.
    pub fn after(limit: Duration) -> Self {
        Self {
            limit: Some((limit, Instant::now() + limit)),
            ended: None,
        }
    }

    /// `limit` from `start` (a time already passed: the work began before the deadline was made).
    pub fn since(start: Instant, limit: Duration) -> Self {
        Self {
            limit: Some((limit, start + limit)),
            ended: None,
        }
    }

    /// Also ended as soon as `ended` returns true, which must then stay true (a flag a signal's
    /// handler sets and nothing clears). It is asked as often as the time (about every
    /// millisecond of the longest loops), so it should be as cheap as an atomic load.
    pub fn or_when(self, ended: impl Fn() -> bool + Send + Sync + 'static) -> Self {
        Self {
            ended: Some(Arc::new(ended)),
            ..self
        }
    }

    /// Whether the work was ended from outside.
    fn ended(&self) -> bool {
        self.ended.as_ref().is_some_and(|f| f())
    }

    /// Whether the time is up or the work was ended: the stages still to come are skipped, and
    /// what the stage under way made is thrown away.
    pub fn expired(&self) -> bool {
        self.ended() || self.limit.is_some_and(|(_, until)| Instant::now() >= until)
    }

    /// The deadline as the core asks it between the steps of its loops: requested once
    /// [`Self::expired`].
    pub fn stop(&self) -> Stop {
        if self.limit.is_none() && self.ended.is_none() {
            return Stop::NEVER;
        }
        let this = self.clone();
        Stop::when(move || this.expired())
    }

    /// Why `stage` has no result, in words: `skipped: the coverage certificate did not finish
    /// within 2 s`, or, when the work was ended from outside, `skipped: the coverage certificate
    /// was ended before it finished (the command is ending)`.
    pub fn skipped(&self, stage: &str) -> String {
        match self.limit {
            _ if self.ended() => format!("skipped: {stage} was ended before it finished (the command is ending)"),
            Some((limit, _)) => format!(
                "skipped: {stage} did not finish within {} s",
                crate::limits::show(limit.as_secs_f64())
            ),
            None => format!("skipped: {stage} did not finish"),
        }
    }
}

impl std::fmt::Debug for Deadline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Deadline")
            .field("limit", &self.limit.map(|(l, _)| l))
            .field("ended_from_outside", &self.ended.is_some())
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};

    #[test]
    fn a_deadline_expires_at_its_time_or_when_ended() {
        let none = Deadline::none();
        assert!(!none.expired() && !none.stop().requested());
        assert_eq!(none.stop(), Stop::NEVER);
        assert_eq!(none.skipped("the fit"), "skipped: the fit did not finish");
        // A bound already passed: expired, and the core's stop says so.
        let passed = Deadline::after(Duration::ZERO);
        assert!(passed.expired() && passed.stop().requested());
        assert_eq!(
            passed.skipped("the coverage certificate"),
            "skipped: the coverage certificate did not finish within 0 s"
        );
        let begun = Deadline::since(Instant::now() - Duration::from_secs(2), Duration::from_secs(1));
        assert!(begun.expired());
        assert_eq!(begun.skipped("the fit"), "skipped: the fit did not finish within 1 s");
        let later = Deadline::after(Duration::from_millis(2500));
        assert!(!later.expired() && !later.stop().requested());
        assert_eq!(later.skipped("the fit"), "skipped: the fit did not finish within 2.5 s");
        // Ended from outside (a signal's flag), whatever the time left.
        let flag = Arc::new(AtomicBool::new(false));
        let raised = Arc::clone(&flag);
        let ended = Deadline::after(Duration::from_secs(3600)).or_when(move || raised.load(Ordering::Relaxed));
        let stop = ended.stop();
        assert!(!ended.expired() && !stop.requested());
        flag.store(true, Ordering::Relaxed);
        assert!(ended.expired() && stop.requested());
        assert_eq!(
            ended.skipped("the fit"),
            "skipped: the fit was ended before it finished (the command is ending)"
        );
    }
}
