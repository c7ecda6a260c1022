//! The motor-interference fit (`log_fit::motor`) on synthetic logs of known interference: its
//! estimate of `d` and whether its standard errors are honest, what it says of a log without
//! interference, and what it refuses.
//!
//! Synthetic logs: \[P1\]'s sensor (`paper::true_error_model`) in the Changsha field, 30 nT of
//! noise per component, attitudes drawn uniformly in roll, yaw and pitch over every attitude, a
//! battery current drawn uniformly from 0 to 30 A at each reading, and the interference `d` of
//! 2 mGauss/A (200 nT/A) on x and smaller on y and z. ChaCha streams seeded per log: the numbers
//! are fixed.

use magcal_core::design::sources;
use magcal_core::log_fit::motor::{MotorError, MotorFit, MotorInput, fit_motor};
use magcal_core::log_fit::{FitModel, FitSettings};
use magcal_core::rng::stream_rng;
use magcal_core::{AttitudeBox, ErrorModel, Vec3, paper};
use rand::RngExt;

const SIGMA_NT: f64 = 30.0;
const D_NT_PER_A: Vec3 = [200.0, -150.0, 80.0];

/// `n` readings (nT) of `truth` with the interference `d` at currents from 0 to 30 A, and the
/// currents, log `seed`.
fn log(truth: &ErrorModel, d: Vec3, n: usize, seed: u64) -> (Vec<Vec3>, Vec<f64>) {
    let mut rng = stream_rng(seed, 0);
    let design = sources::random(&AttitudeBox::full(), n, &mut rng);
    let clean = truth
        .noisy_readings(&paper::changsha_field().body_fields(&design), SIGMA_NT, &mut rng)
        .unwrap();
    let current: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..30.0)).collect();
    let readings = clean
        .iter()
        .zip(&current)
        .map(|(s, &u)| std::array::from_fn(|i| s[i] + d[i] * u))
        .collect();
    (readings, current)
}

fn magnitude() -> f64 {
    paper::changsha_field().magnitude()
}

/// `model`'s joint fit of a log whose input is the battery current, the noise from the residuals.
fn fit(readings: &[Vec3], current: &[f64], model: FitModel) -> Result<MotorFit, MotorError> {
    fit_motor(
        readings,
        current,
        MotorInput::Current,
        magnitude(),
        model,
        &FitSettings::default(),
    )
}

#[test]
fn the_standard_errors_of_the_interference_are_honest_over_200_logs() {
    // z = (d_hat - d) / se per axis over 200 logs of 300 readings: mean 0 within 4 standard
    // errors (4 / sqrt(200) = 0.28) and rms 1 within 4 standard errors of an rms of 200 unit
    // normals (sqrt(2 / 200) / 2 = 0.05, so 0.2).
    let truth = paper::true_error_model();
    let mut z = [Vec::new(), Vec::new(), Vec::new()];
    for seed in 0..200 {
        let (readings, current) = log(&truth, D_NT_PER_A, 300, 5000 + seed);
        let f = fit(&readings, &current, FitModel::Full).unwrap();
        assert!(f.identifiable, "log {seed}: {}", f.verdict);
        let se = f.std_per_unit.unwrap();
        for i in 0..3 {
            z[i].push((f.per_unit[i] - D_NT_PER_A[i]) / se[i]);
        }
    }
    for (i, zi) in z.iter().enumerate() {
        let n = zi.len() as f64;
        let mean = zi.iter().sum::<f64>() / n;
        let rms = (zi.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
        assert!(mean.abs() <= 4.0 / n.sqrt(), "axis {i}: mean z {mean}");
        assert!(
            (rms - 1.0).abs() <= 4.0 * (2.0 / n).sqrt() / 2.0,
            "axis {i}: rms z {rms}"
        );
    }
}

#[test]
fn every_model_recovers_the_interference_and_the_sensor_it_can_describe() {
    for (model, truth) in [
        (FitModel::Full, paper::true_error_model()),
        (
            FitModel::Diagonal,
            ErrorModel::new([0.0; 3], [1.3, 0.7, 1.2], [3000.0, -6000.0, 5000.0]).unwrap(),
        ),
        (
            FitModel::Offset,
            ErrorModel::new([0.0; 3], [1.1; 3], [3000.0, -6000.0, 5000.0]).unwrap(),
        ),
    ] {
        let (readings, current) = log(&truth, D_NT_PER_A, 2000, 7);
        let f = fit(&readings, &current, model).unwrap();
        assert!(f.identifiable, "{model:?}: {}", f.verdict);
        let (sd, ss, sb) = (f.std_per_unit.unwrap(), f.std_scale.unwrap(), f.std_bias.unwrap());
        for i in 0..3 {
            // Within 5 standard errors of the truth, each parameter.
            assert!((f.per_unit[i] - D_NT_PER_A[i]).abs() <= 5.0 * sd[i], "{model:?} d{i}");
            assert!(
                (f.errors.scale()[i] - truth.scale()[i]).abs() <= 5.0 * ss[i],
                "{model:?} S{i}"
            );
            assert!((f.bias[i] - truth.bias_nt()[i]).abs() <= 5.0 * sb[i], "{model:?} O{i}");
        }
        // The noise from the residuals: 30 nT within 10 % (2000 readings: its own standard error
        // is about 30 / sqrt(2 * 2000) nT, 1.6 %).
        let noise = f.noise.value().unwrap();
        assert!((noise / SIGMA_NT - 1.0).abs() < 0.1, "{model:?}: {noise}");
        assert_eq!(f.input_range[0], current.iter().copied().fold(f64::INFINITY, f64::min));
    }
}

#[test]
fn a_log_without_interference_gives_none_within_its_standard_errors() {
    let (readings, current) = log(&paper::true_error_model(), [0.0; 3], 1000, 11);
    let f = fit(&readings, &current, FitModel::Full).unwrap();
    assert!(f.identifiable, "{}", f.verdict);
    let se = f.std_per_unit.unwrap();
    for i in 0..3 {
        assert!(
            f.per_unit[i].abs() <= 4.0 * se[i],
            "d{i} = {} +- {}",
            f.per_unit[i],
            se[i]
        );
        // 30 nT of noise over 1000 readings of currents spread by 30 / sqrt 12 A: about
        // 30 |P| / (sqrt(1000) 8.66) = 0.11 to 0.16 nT/A, more with the correlation of d and O
        // (measured 0.17 to 0.22): a thousandth of a motor's 2 mGauss/A.
        assert!(se[i] < 0.5, "{se:?}");
    }
}

#[test]
fn an_input_that_does_not_vary_is_refused_and_one_that_barely_varies_is_not_identifiable() {
    let (readings, _) = log(&paper::true_error_model(), D_NT_PER_A, 300, 13);
    let constant = vec![12.5; readings.len()];
    assert_eq!(
        fit(&readings, &constant, FitModel::Full),
        Err(MotorError::ConstantInput { value: 12.5 })
    );
    // A current that moves by 1e-12 A: d u is the bias plus 1e-12 d, which 30 nT of noise never
    // shows. The information of (O, d) in correlation form is singular to working precision.
    let barely: Vec<f64> = (0..readings.len()).map(|k| 12.5 + 1e-12 * (k % 7) as f64).collect();
    let f = fit(&readings, &barely, FitModel::Full).unwrap();
    assert!(!f.identifiable && f.std_per_unit.is_none(), "{}", f.verdict);
    assert!(f.verdict.contains("varies too little"), "{}", f.verdict);
    assert!(f.information_min_eigenvalue < 1e-12, "{}", f.information_min_eigenvalue);
    // A current that varies: the same eigenvalue is of order 1.
    let (readings, current) = log(&paper::true_error_model(), D_NT_PER_A, 300, 13);
    let f = fit(&readings, &current, FitModel::Full).unwrap();
    assert!(f.information_min_eigenvalue > 1e-3, "{}", f.information_min_eigenvalue);
    let mut bad = current.clone();
    bad[4] = f64::NAN;
    assert!(matches!(
        fit(&readings, &bad, FitModel::Full),
        Err(MotorError::NonFiniteInput { index: 4, .. })
    ));
}
