//! What a run will cost before it starts: the memory it needs, item by item, and the time the PSO
//! work takes, each checked against a limit so that a run too large for the machine is refused
//! with the estimate, its largest item and the limit, before any work.

use anyhow::{Result, bail};
use magcal_core::monte_carlo::TrialOutcome;

use crate::limits::{available_memory, bytes};
use crate::scenario::{DesignSource, Scenario};

/// The memory a run of `scenario` needs, item by item: (what, bytes).
pub fn estimate(scenario: &Scenario, with_trials: bool, threads: usize) -> Vec<(String, u64)> {
    let mut items = Vec::new();
    let f = 8u64; // bytes per f64
    // Thread stacks (virtual memory, counted by an address-space limit).
    items.push((format!("{threads} worker threads"), threads as u64 * (8 << 20)));
    for d in &scenario.designs {
        let m = d.source.m() as u64;
        let dim = 3 * m;
        let need = match &d.source {
            DesignSource::Pso { swarm, .. } => {
                swarm.particles as u64 * (3 * dim * f + 512) + swarm.iterations as u64 * f
            }
            DesignSource::Optimum { settings, .. } => {
                settings.starts as u64 * dim * f * 3 + threads as u64 * (2 * settings.memory as u64 + 8) * dim * f
            }
            _ => 0,
        };
        // The design's readings, H and its SVD for the conditioning.
        items.push((format!("design {:?}", d.name), need + m * 600));
    }
    // The certificate's grid: attitude, regression row, weight and variance per candidate, up to
    // twice the budget, and the start indices of the search.
    items.push((
        format!(
            "certificate grid of about {} candidates",
            scenario.certificate.candidates
        ),
        2 * scenario.certificate.candidates as u64 * 220,
    ));
    if let Some(runs) = &scenario.pso_runs {
        let dim = 3 * runs.m as u64;
        let concurrent = runs.runs.min(threads) as u64;
        let swarm = runs.swarm.particles as u64 * (3 * dim * f + 512) + runs.swarm.iterations as u64 * f;
        items.push((
            format!("{} PSO runs, {concurrent} at a time", runs.runs),
            concurrent * swarm,
        ));
    }
    if with_trials {
        let rows = (scenario.designs.len() * scenario.sigmas_nt.len() * scenario.attitude_sigmas_deg.len()) as u64
            * scenario.trials as u64;
        // Every outcome is kept until the statistics and files are written; the statistics sort a
        // copy of each metric of one cell.
        let per_row = std::mem::size_of::<TrialOutcome>() as u64 + 32;
        let largest_m = scenario.designs.iter().map(|d| d.source.m()).max().unwrap_or(0) as u64;
        items.push((
            format!("{rows} trial outcomes x {per_row} B"),
            rows * per_row + 3 * scenario.trials as u64 * f + threads as u64 * largest_m * 1200,
        ));
    }
    items
}

/// Seconds of one PSO fitness evaluation and particle update for 9 attitudes on one thread: one
/// paper PSO run (300 particles x 3000 iterations, 903,000 evaluations) takes 0.34 s on one
/// thread (docs/research/benchmarks.md); the cost grows with the attitudes per design.
pub const PSO_SECONDS_PER_EVALUATION: f64 = 0.38e-6;
/// Estimated work above which a run is refused unless the user passes `--allow-long`, seconds
/// (one day).
pub const MAX_ESTIMATED_SECONDS: f64 = 86_400.0;
/// Estimated work above which the estimate is printed before the run starts, seconds.
pub const NOTE_ESTIMATED_SECONDS: f64 = 60.0;

/// The time the PSO work of `scenario` takes on `threads`, item by item: (what, seconds). The
/// other designs and the trials take far less for the sizes allowed.
pub fn estimate_time(scenario: &Scenario, threads: usize) -> Vec<(String, f64)> {
    let evaluation = |m: usize| PSO_SECONDS_PER_EVALUATION * (m.max(1) as f64 / 9.0);
    let threads = threads.max(1) as f64;
    let mut items = Vec::new();
    for d in &scenario.designs {
        if let DesignSource::Pso { m, swarm } = &d.source {
            let evaluations = swarm.particles as f64 * (swarm.iterations as f64 + 1.0);
            items.push((
                format!(
                    "design {:?} ({} particles x {} iterations)",
                    d.name, swarm.particles, swarm.iterations
                ),
                evaluations * evaluation(*m) / threads,
            ));
        }
    }
    if let Some(runs) = &scenario.pso_runs {
        let evaluations = runs.runs as f64 * runs.swarm.particles as f64 * (runs.swarm.iterations as f64 + 1.0);
        items.push((
            format!(
                "{} PSO runs of {} particles x {} iterations",
                runs.runs, runs.swarm.particles, runs.swarm.iterations
            ),
            evaluations * evaluation(runs.m) / threads,
        ));
    }
    items
}

/// Time for people: seconds, minutes, hours or days.
pub fn duration(seconds: f64) -> String {
    match seconds {
        s if s < 120.0 => format!("{s:.0} s"),
        s if s < 7_200.0 => format!("{:.0} min", s / 60.0),
        s if s < 172_800.0 => format!("{:.1} h", s / 3_600.0),
        s => format!("{:.1} days", s / 86_400.0),
    }
}

/// Refuses a run whose PSO work is estimated above [`MAX_ESTIMATED_SECONDS`] unless `allow_long`;
/// returns the estimate in words when it is above [`NOTE_ESTIMATED_SECONDS`], for the caller to
/// print before the run starts.
///
/// # Errors
/// The estimate, its largest item and the limit.
pub fn check_time(scenario: &Scenario, threads: usize, allow_long: bool) -> Result<Option<String>> {
    let items = estimate_time(scenario, threads);
    let total: f64 = items.iter().map(|(_, s)| s).sum();
    let Some((item, largest)) = items.iter().max_by(|a, b| a.1.total_cmp(&b.1)) else {
        return Ok(None);
    };
    let words = format!(
        "the run's PSO work is estimated at {} on {threads} threads, most of it for {item} ({})",
        duration(total),
        duration(*largest)
    );
    if total > MAX_ESTIMATED_SECONDS && !allow_long {
        bail!(
            "{words}; runs above {} are refused unless --allow-long is given",
            duration(MAX_ESTIMATED_SECONDS)
        );
    }
    Ok((total > NOTE_ESTIMATED_SECONDS).then_some(words))
}

/// Refuses a run whose estimated memory exceeds half of what the process may use.
///
/// # Errors
/// The estimate, its largest item and the limit.
pub fn check_memory(scenario: &Scenario, with_trials: bool, threads: usize) -> Result<()> {
    let items = estimate(scenario, with_trials, threads);
    let total: u64 = items.iter().map(|(_, b)| b).sum();
    let Some((available, what)) = available_memory() else {
        crate::output::stderr::to_stderr!(
            "magcal: note: the run needs about {} of memory, which is not checked: this system tells no memory available",
            bytes(total)
        );
        return Ok(());
    };
    let limit = available / 2;
    if total > limit {
        let (item, b) = items.iter().max_by_key(|(_, b)| *b).expect("at least the threads");
        bail!(
            "the run needs about {} of memory, most of it for {item} ({}); the limit is {}, half of {} {what}",
            bytes(total),
            bytes(*b),
            bytes(limit),
            bytes(available)
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_are_shown_in_their_unit() {
        assert_eq!(duration(0.2), "0 s");
        assert_eq!(duration(90.0), "90 s");
        assert_eq!(duration(600.0), "10 min");
        assert_eq!(duration(36_000.0), "10.0 h");
        assert_eq!(duration(1.9e5), "2.2 days");
    }
}
