//! Design optimiser timings (\[P1\] III-IV): fitness per call, the paper's PSO (Table I), the
//! multi-start optimum.
//!
//! `cargo bench -p magcal-core --bench design`. Thread count: rayon's default (all cores) unless
//! `RAYON_NUM_THREADS` is set.
use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use magcal_core::design::lanes::LANES;
use magcal_core::design::optimum::Optimum;
use magcal_core::design::pso::Swarm;
use magcal_core::design::{DesignCriterion, DesignProblem, to_vector};
use magcal_core::paper;
use magcal_core::rng::stream_rng;

fn problem() -> DesignProblem {
    DesignProblem::new(paper::changsha_field(), paper::true_error_model(), paper::auv_box(), 9).unwrap()
}

fn fitness(c: &mut Criterion) {
    let p = problem();
    let x = to_vector(&paper::table2_d_optimal());
    c.bench_function("fitness/d_m9", |b| {
        b.iter(|| p.fitness(DesignCriterion::D, black_box(&x)))
    });
    c.bench_function("fitness/a_m9", |b| {
        b.iter(|| p.fitness(DesignCriterion::A, black_box(&x)))
    });
    c.bench_function("fitness/e_m9", |b| {
        b.iter(|| p.fitness(DesignCriterion::E, black_box(&x)))
    });
    let y = to_vector(&paper::uniformity_design());
    let designs: [&[f64]; LANES] = std::array::from_fn(|l| if l % 2 == 0 { x.as_slice() } else { y.as_slice() });
    c.bench_function(&format!("fitness/d_m9_lanes_x{LANES}"), |b| {
        b.iter(|| p.ln_det_lanes(black_box(designs)))
    });
}

fn optimisers(c: &mut Criterion) {
    let p = problem();
    let mut group = c.benchmark_group("optimiser");
    group.sample_size(10);
    let mut seed = 0;
    group.bench_function("pso_table1_300x3000_m9", |b| {
        b.iter(|| {
            seed += 1;
            Swarm::default().optimise(&p, &mut stream_rng(seed, 0)).unwrap().fitness
        })
    });
    let mut seed = 0;
    group.bench_function("optimum_default_m9", |b| {
        b.iter(|| {
            seed += 1;
            let r = Optimum::default().optimise(&p, &mut stream_rng(seed, 0)).unwrap();
            assert!(r.ln_det >= 314.5485, "seed {seed}: {}", r.ln_det);
            r.ln_det
        })
    });
    group.finish();
}

/// Targets: the approximate design and its certificate for the AUV box (200 ms), the
/// optimum of 100 readings in the full attitude space (2 s).
fn certified(c: &mut Criterion) {
    use magcal_core::AttitudeBox;
    use magcal_core::design::approximate::Approximate;
    let p = problem();
    let mut group = c.benchmark_group("certified");
    group.sample_size(10);
    let mut seed = 0;
    group.bench_function("approximate_and_certificate_auv_box", |b| {
        b.iter(|| {
            seed += 1;
            let d = Approximate::default().compute(&p, &mut stream_rng(seed, 0)).unwrap();
            assert!(d.converged && d.certificate.ln_det_mf_bound(9) <= 314.947);
            d.certificate.ln_det_bound
        })
    });
    let full = DesignProblem::new(
        paper::changsha_field(),
        paper::true_error_model(),
        AttitudeBox::full(),
        100,
    )
    .unwrap();
    let mut seed = 0;
    group.bench_function("optimum_default_m100_full_space", |b| {
        b.iter(|| {
            seed += 1;
            Optimum::default()
                .optimise(&full, &mut stream_rng(seed, 0))
                .unwrap()
                .ln_det
        })
    });
    group.finish();
}

criterion_group!(benches, fitness, optimisers, certified);
criterion_main!(benches);
