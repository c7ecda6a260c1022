//! Two-step calibration timings (\[P1\] IV.C) and the fixed-size kernels against faer.
//!
//! `cargo bench -p magcal-core --bench calibration`
use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use faer::{Mat, Side};
use magcal_core::attitude::Attitude;
use magcal_core::design::sources;
use magcal_core::metrics::RelativeErrors;
use magcal_core::rng::stream_rng;
use magcal_core::{InformationMatrix, TwoStep, paper, small};

fn noisy_readings(m: usize) -> (Vec<magcal_core::Vec3>, f64) {
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    let mut rng = stream_rng(1, 0);
    let design: Vec<Attitude> = if m == 9 {
        paper::uniformity_design()
    } else {
        sources::random(&paper::auv_box(), m, &mut rng)
    };
    let readings = truth
        .noisy_readings(&field.body_fields(&design), 30.0, &mut rng)
        .unwrap();
    (readings, field.magnitude())
}

fn two_step(c: &mut Criterion) {
    let settings = TwoStep::default();
    for m in [9, 100] {
        let (readings, r) = noisy_readings(m);
        c.bench_function(&format!("two_step/{m}_readings"), |b| {
            b.iter(|| settings.calibrate(black_box(&readings), black_box(r)))
        });
    }
}

fn kernels(c: &mut Criterion) {
    let (readings, r) = noisy_readings(9);
    let info = InformationMatrix::from_readings(&readings, r);
    let m = *info.matrix();
    c.bench_function("ln_det_9x9/fixed_cholesky", |b| {
        b.iter(|| small::ln_det_spd(black_box(&m)))
    });
    let fm: Mat<f64> = info.to_faer();
    c.bench_function("ln_det_9x9/faer_llt", |b| {
        b.iter(|| {
            let llt = black_box(&fm).llt(Side::Lower).unwrap();
            let l = llt.L();
            (0..9).map(|i| 2.0 * l[(i, i)].ln()).sum::<f64>()
        })
    });
}

/// 1000 noisy trials of one design (\[P1\] IV.C), in parallel with one stream per trial, collected in
/// order: what `magcal run` does per design and noise level.
fn monte_carlo(c: &mut Criterion) {
    use magcal_core::monte_carlo::trial;
    use rayon::prelude::*;
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    let body = field.body_fields(&paper::uniformity_design());
    // As the runner calibrates: the cell's noise known to step 2's local check.
    let settings = TwoStep {
        noise_nt: Some(30.0),
        ..TwoStep::default()
    };
    let probe = magcal_core::heading::HeadingProbe::new(&field, &truth);
    let mut group = c.benchmark_group("monte_carlo");
    group.sample_size(20);
    group.bench_function("1000_trials_one_design", |b| {
        b.iter(|| {
            (0..1000u64)
                .into_par_iter()
                .map(|t| {
                    trial(
                        &truth,
                        &body,
                        field.magnitude(),
                        30.0,
                        &settings,
                        &probe,
                        &mut stream_rng(1, t),
                    )
                    .unwrap()
                })
                .collect::<Vec<_>>()
        })
    });
    // The same trials without the absolute and heading errors: the ratio of the two is the cost
    // of those metrics (target: at most 1.25).
    group.bench_function("1000_trials_one_design_relative_errors_only", |b| {
        b.iter(|| {
            (0..1000u64)
                .into_par_iter()
                .map(|t| {
                    let readings = truth.noisy_readings(&body, 30.0, &mut stream_rng(1, t)).unwrap();
                    settings.calibrate(&readings, field.magnitude()).map(|fit| {
                        let e = fit.estimate();
                        (fit.status(), RelativeErrors::between(&e.model, &truth), e.model)
                    })
                })
                .collect::<Vec<_>>()
        })
    });
    group.finish();
}

/// The Cramer-Rao bound and identifiability verdict of one design (target: 50 us for m = 9), and
/// the heading error of one calibration over 360 yaws (part of every Monte Carlo trial).
fn metrics(c: &mut Criterion) {
    use magcal_core::heading::HeadingProbe;
    use magcal_core::{CramerRao, PhysicalScales};
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    let body = field.body_fields(&paper::uniformity_design());
    let scales = PhysicalScales::default();
    c.bench_function("crb_and_verdict/9_readings", |b| {
        b.iter(|| CramerRao::new(black_box(&truth), black_box(&body), 30.0, &scales))
    });
    let probe = HeadingProbe::new(&field, &truth);
    let (readings, r) = noisy_readings(9);
    let fit = TwoStep::default().calibrate(&readings, r).unwrap();
    let (p, o) = (fit.estimate().p, fit.estimate().bias_nt);
    c.bench_function("heading_error/one_trial", |b| {
        b.iter(|| probe.error(black_box(&p), black_box(o)))
    });
    c.bench_function("heading_error/one_trial_one_atan2_per_yaw", |b| {
        b.iter(|| probe.error_by_atan2(black_box(&p), black_box(o)))
    });
}

/// Target: calibrating a log of 12,000 readings (the size of the ck-explorer log) in at
/// most 20 ms: a synthetic log of the [P1] sensor over every attitude, 30 nT noise, in Gauss.
fn log_fit(c: &mut Criterion) {
    use magcal_core::log_fit::{FitModel, fit, fit_with};
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    let mut rng = stream_rng(9, 0);
    let design = sources::random(&magcal_core::AttitudeBox::full(), 12_000, &mut rng);
    let readings: Vec<magcal_core::Vec3> = truth
        .noisy_readings(&field.body_fields(&design), 30.0, &mut rng)
        .unwrap()
        .into_iter()
        .map(|s| s.map(|v| v / 1e5))
        .collect();
    let r = field.magnitude() / 1e5;
    let mut group = c.benchmark_group("log_fit");
    group.sample_size(20);
    for model in [FitModel::Full, FitModel::Diagonal, FitModel::Offset] {
        group.bench_function(format!("{}_12000_readings", model.as_str()), |b| {
            b.iter(|| fit(black_box(&readings), r, model).unwrap().residual_rms)
        });
    }
    // One trial of a long log's check: the full model on the part of JUDGED_READINGS it draws,
    // without a check or a profile of its own, and the two-step fit alone.
    let part = &readings[..magcal_core::log_fit::JUDGED_READINGS];
    let trial = magcal_core::log_fit::FitSettings {
        trials: 0,
        held_out: false,
        profile: false,
        ..Default::default()
    };
    group.bench_function("trial_8192_readings", |b| {
        b.iter(|| {
            fit_with(black_box(part), r, FitModel::Full, &trial)
                .unwrap()
                .residual_rms
        })
    });
    group.bench_function("two_step_8192_readings", |b| {
        b.iter(|| TwoStep::default().calibrate(black_box(part), r).unwrap().iterations)
    });
    group.finish();
}

/// The rotation of Wahba's problem on a 3x3 attitude profile matrix: faer's SVD (Markley's
/// solution) against the fixed-size q-method of [`small::wahba_rotation`]; and a whole
/// alignment of 50,000 readings with reference attitudes (`reference::align`, six starts).
fn wahba(c: &mut Criterion) {
    let w = [[0.3, -1.2, 0.4], [0.9, 0.1, -0.7], [-0.2, 0.5, 1.1]];
    c.bench_function("wahba/faer_svd", |b| {
        b.iter(|| {
            let svd = Mat::from_fn(3, 3, |i, j| black_box(&w)[i][j]).svd().unwrap();
            let (u, v) = (svd.U(), svd.V());
            let q: [[f64; 3]; 3] =
                std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| u[(i, k)] * v[(j, k)]).sum()));
            q
        })
    });
    c.bench_function("wahba/q_method", |b| b.iter(|| small::wahba_rotation(black_box(&w))));
    let mut rng = stream_rng(3, 0);
    let attitudes: Vec<[[f64; 3]; 3]> = sources::random(&paper::auv_box(), 50_000, &mut rng)
        .iter()
        .map(|a| small::transpose(&a.dcm()))
        .collect();
    let field = [3_000.0, 15_000.0, -48_000.0];
    // A scale factor 1 % off on x: the errors the alignment measures.
    let readings: Vec<magcal_core::Vec3> = attitudes
        .iter()
        .map(|c| {
            let b = small::mat_t_vec(c, field);
            [1.01 * b[0], b[1], b[2]]
        })
        .collect();
    let mut group = c.benchmark_group("align");
    group.sample_size(10);
    group.bench_function("50000_readings", |b| {
        b.iter(|| magcal_core::reference::align(black_box(&readings), &attitudes, &Default::default()))
    });
    group.finish();
}

criterion_group!(benches, two_step, kernels, wahba, monte_carlo, metrics, log_fit);
criterion_main!(benches);
