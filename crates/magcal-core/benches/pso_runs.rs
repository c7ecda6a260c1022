//! 100 independent runs of the paper's PSO (Table I): the data of \[P1\] Fig. 4.
//!
//! Too long for criterion's minimum of 10 samples, so this times 3 repetitions and prints each and
//! the median. `cargo bench -p magcal-core --bench pso_runs` (threads: rayon's default, or
//! `RAYON_NUM_THREADS`).
use std::time::Instant;

use magcal_core::design::DesignProblem;
use magcal_core::design::pso::Swarm;
use magcal_core::paper;

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` does not: then run one small repetition.
    let full = std::env::args().any(|a| a == "--bench");
    let problem = DesignProblem::new(paper::changsha_field(), paper::true_error_model(), paper::auv_box(), 9)
        .expect("paper problem is valid");
    let (runs, reps, swarm) = if full {
        (100, 3, Swarm::default())
    } else {
        (
            4,
            1,
            Swarm {
                iterations: 10,
                ..Swarm::default()
            },
        )
    };
    let mut times = Vec::new();
    for rep in 0..reps {
        let t = Instant::now();
        let results = swarm.repeated_runs(&problem, runs, rep as u64).expect("valid settings");
        let secs = t.elapsed().as_secs_f64();
        let lo = results.iter().map(|r| -r.fitness).fold(f64::INFINITY, f64::min);
        let hi = results.iter().map(|r| -r.fitness).fold(f64::NEG_INFINITY, f64::max);
        println!(
            "pso_runs/{runs}x{}: {secs:.2} s (final ln det M_F {lo:.4} .. {hi:.4})",
            swarm.iterations
        );
        times.push(secs);
    }
    times.sort_by(f64::total_cmp);
    println!(
        "pso_runs/{runs}: median {:.2} s over {reps} repetitions",
        times[times.len() / 2]
    );
}
