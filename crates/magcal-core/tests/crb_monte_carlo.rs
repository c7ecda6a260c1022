//! The Monte Carlo against the Cramer-Rao bound (docs/conventions.md "Identifiability and the
//! Cramer-Rao floor"): with 9 readings the two-step estimate is the exact ellipsoid through them,
//! whose first-order covariance is exactly the bound. Tolerances are standard errors of the Monte
//! Carlo quantities at a fixed seed.

use faer::linalg::solvers::DenseSolveCore;
use magcal_core::attitude::Attitude;
use magcal_core::heading::HeadingProbe;
use magcal_core::monte_carlo::trial;
use magcal_core::rng::stream_rng;
use magcal_core::{CramerRao, PhysicalScales, TwoStep, paper};

/// The estimates `(psi_deg, S, O_nt)` minus the truth, of `n` trials.
fn errors(yaw_offset: f64, design: &[Attitude], sigma: f64, n: u64, seed: u64) -> (Vec<[f64; 9]>, CramerRao) {
    let field = paper::changsha_field().with_yaw_offset_deg(yaw_offset).unwrap();
    let truth = paper::true_error_model();
    let body = field.body_fields(design);
    let probe = HeadingProbe::new(&field, &truth);
    let t = [truth.psi_deg(), truth.scale(), truth.bias_nt()].concat();
    let errors = (0..n)
        .map(|i| {
            let o = trial(
                &truth,
                &body,
                field.magnitude(),
                sigma,
                &TwoStep::default(),
                &probe,
                &mut stream_rng(seed, i),
            )
            .unwrap();
            let m = o.estimate.expect("every trial calibrates at this noise");
            let e = [m.psi_deg(), m.scale(), m.bias_nt()].concat();
            std::array::from_fn(|k| e[k] - t[k])
        })
        .collect();
    (errors, CramerRao::new(&truth, &body, sigma, &PhysicalScales::default()))
}

#[test]
fn at_one_nanotesla_the_covariance_is_the_bound() {
    let n = 4000;
    for (offset, design) in [(90.0, paper::uniformity_design()), (0.0, paper::conventions_optimum())] {
        let (e, bound) = errors(offset, &design, 1.0, n, 7);
        let cov = bound.covariance.unwrap();
        // Each variance: a sample variance has relative standard error sqrt(2 / (n - 1)).
        let se = (2.0 / (n as f64 - 1.0)).sqrt();
        for k in 0..9 {
            let mean = e.iter().map(|v| v[k]).sum::<f64>() / n as f64;
            let var = e.iter().map(|v| (v[k] - mean).powi(2)).sum::<f64>() / (n as f64 - 1.0);
            assert!(
                (var / cov[k][k] - 1.0).abs() <= 4.0 * se,
                "offset {offset}, parameter {k}: {var} vs {}",
                cov[k][k]
            );
        }
        // The whole matrix: (e^T C^-1 e) is chi-square with 9 degrees of freedom (mean 9, var 18).
        let inverse = faer::Mat::from_fn(9, 9, |i, j| cov[i][j])
            .llt(faer::Side::Lower)
            .unwrap()
            .inverse();
        let q: f64 = e
            .iter()
            .map(|v| {
                (0..9)
                    .map(|i| (0..9).map(|j| v[i] * inverse[(i, j)] * v[j]).sum::<f64>())
                    .sum::<f64>()
            })
            .sum::<f64>()
            / n as f64;
        assert!(
            (q - 9.0).abs() <= 4.0 * (18.0 / n as f64).sqrt(),
            "offset {offset}: mean quadratic form {q}"
        );
    }
}

#[test]
fn at_thirty_nanotesla_the_rms_relative_errors_are_within_five_percent_of_the_bound() {
    let n = 4000;
    let truth = paper::true_error_model();
    let t = [truth.psi_deg(), truth.scale(), truth.bias_nt()];
    for (offset, design) in [(90.0, paper::uniformity_design()), (0.0, paper::conventions_optimum())] {
        let (e, bound) = errors(offset, &design, 30.0, n, 8);
        let predicted = bound.rms_eta().map(Option::unwrap);
        for g in 0..3 {
            let norm_t = t[g].iter().map(|v| v * v).sum::<f64>().sqrt();
            let ms = e
                .iter()
                .map(|v| (0..3).map(|i| v[3 * g + i].powi(2)).sum::<f64>())
                .sum::<f64>()
                / n as f64;
            let rms = 100.0 * ms.sqrt() / norm_t;
            assert!(
                (rms / predicted[g] - 1.0).abs() <= 0.05,
                "offset {offset}, group {g}: {rms} vs {}",
                predicted[g]
            );
        }
    }
}
