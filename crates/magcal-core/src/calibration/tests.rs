use super::step2::{PARAMETERS, Residual, pack, reading_residual_and_gradient, residual_and_gradient};
use super::*;
use crate::attitude::{Attitude, AttitudeBox};
use crate::design::sources;
use crate::metrics::RelativeErrors;
use crate::paper;
use crate::rng::stream_rng;
use crate::small::scale;
use proptest::prelude::*;
use rand::{Rng, RngExt};

fn random_truth<R: Rng>(rng: &mut R) -> ErrorModel {
    let psi = std::array::from_fn(|_| rng.random_range(-5.0..5.0));
    let s = std::array::from_fn(|_| rng.random_range(0.5..2.0));
    // |O| <= 20000 nT: a uniform direction, magnitude uniform in [0, 20000].
    let o = loop {
        let v: Vec3 = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
        let n = crate::small::norm(v);
        if n > 1e-3 && n <= 1.0 {
            break scale(rng.random_range(0.0..20_000.0) / n, v);
        }
    };
    ErrorModel::new(psi, s, o).unwrap()
}

fn max_relative_error(est: &ErrorModel, truth: &ErrorModel) -> f64 {
    let e = RelativeErrors::between(est, truth);
    // eta is in percent; relative = eta / 100. A zero truth makes its eta undefined (None): skipped.
    [e.psi, e.scale, e.bias].into_iter().flatten().fold(0.0, f64::max) / 100.0
}

#[test]
fn noise_free_recovery_of_the_paper_truth() {
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    for design in [paper::uniformity_design(), paper::table2_d_optimal()] {
        let readings = truth.measure_all(&field.body_fields(&design));
        let fit = TwoStep::default().calibrate(&readings, field.magnitude()).unwrap();
        for est in [&fit.step1, &fit.step2] {
            let err = max_relative_error(&est.model, &truth);
            assert!(err <= 1e-8, "relative error {err:e}");
        }
        assert_eq!(fit.status(), CalibrationStatus::Ok);
    }
}

#[test]
fn noise_free_recovery_of_random_truths_on_random_designs() {
    // >= 100 random truths (psi within +-5 deg, S in [0.5, 2], |O| <= 20000 nT), each on a random
    // design of 9 and one of 30 attitudes in the full attitude space. Every one must be recovered to
    // 1e-8 relative by both steps.
    let field = paper::changsha_field();
    let full = AttitudeBox::full();
    let mut rng = stream_rng(42, 0);
    let mut worst: f64 = 0.0;
    for _ in 0..200 {
        let truth = random_truth(&mut rng);
        for m in [9, 30] {
            let design = sources::random(&full, m, &mut rng);
            let readings = truth.measure_all(&field.body_fields(&design));
            let fit = TwoStep::default().calibrate(&readings, field.magnitude()).unwrap();
            for est in [&fit.step1, &fit.step2] {
                worst = worst.max(max_relative_error(&est.model, &truth));
            }
            assert!(fit.termination.converged());
        }
    }
    assert!(worst <= 1e-8, "worst relative error {worst:e}");
}

#[test]
fn step2_cannot_move_an_exact_nine_point_fit() {
    // With m = 9 the quadric through the readings is exact (docs/conventions.md): step 2 must agree with
    // step 1 to ~1e-9 even on noisy readings.
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    let body = field.body_fields(&paper::uniformity_design());
    let mut moved: f64 = 0.0;
    for trial in 0..200 {
        let mut rng = stream_rng(7, trial);
        let readings = truth.noisy_readings(&body, 30.0, &mut rng).unwrap();
        let Ok(fit) = TwoStep::default().calibrate(&readings, field.magnitude()) else {
            continue;
        };
        assert!(fit.step1.rms_residual_nt <= 1e-6, "{}", fit.step1.rms_residual_nt);
        for i in 0..3 {
            for j in i..3 {
                moved = moved.max((fit.step2.p[i][j] - fit.step1.p[i][j]).abs() / fit.step1.p[i][i].abs());
            }
            moved = moved.max((fit.step2.bias_nt[i] - fit.step1.bias_nt[i]).abs() / field.magnitude());
        }
    }
    assert!(moved <= 1e-9, "step 2 moved by {moved:e}");
}

#[test]
fn step2_never_increases_the_residual_with_thirty_readings() {
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    let auv = paper::auv_box();
    let mut improved = 0;
    for trial in 0..300 {
        let mut rng = stream_rng(9, trial);
        let design = sources::random(&auv, 30, &mut rng);
        let readings = truth
            .noisy_readings(&field.body_fields(&design), 30.0, &mut rng)
            .unwrap();
        let Ok(fit) = TwoStep::default().calibrate(&readings, field.magnitude()) else {
            continue;
        };
        let (r1, r2) = (fit.step1.rms_residual_nt, fit.step2.rms_residual_nt);
        assert!(r2 <= r1 * (1.0 + 1e-12), "trial {trial}: step 2 {r2} > step 1 {r1}");
        assert!(fit.termination.converged(), "trial {trial}: {:?}", fit.termination);
        if r2 < r1 * (1.0 - 1e-6) {
            improved += 1;
        }
    }
    // Step 1 minimises the algebraic distance, not |P(b - O)| - R, so step 2 must actually improve
    // the geometric residual in most noisy trials, else it is not doing its job.
    assert!(improved >= 250, "step 2 improved only {improved} of 300 trials");
}

#[test]
fn step2_reports_not_converged_at_its_iteration_limit() {
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    let mut rng = stream_rng(10, 0);
    let design = sources::random(&paper::auv_box(), 30, &mut rng);
    let readings = truth
        .noisy_readings(&field.body_fields(&design), 30.0, &mut rng)
        .unwrap();
    let settings = TwoStep {
        max_iterations: 0,
        ..TwoStep::default()
    };
    let fit = settings.calibrate(&readings, field.magnitude()).unwrap();
    assert_eq!(fit.termination, Termination::MaxIterations);
    assert_eq!(fit.status(), CalibrationStatus::NotConverged);
    assert_eq!(fit.step2.p, fit.step1.p);
    let fit = TwoStep::default().calibrate(&readings, field.magnitude()).unwrap();
    assert!(fit.iterations >= 1 && fit.iterations < 100, "{}", fit.iterations);
}

/// The first parameter whose analytic derivative of `residual` at `x` differs from central
/// differences by more than `tol (1 + |analytic|)`, described; `None` when all agree.
fn gradient_mismatch(
    residual: fn(&[f64; PARAMETERS], Vec3) -> (f64, [f64; PARAMETERS]),
    x: &[f64; PARAMETERS],
    u: Vec3,
    tol: f64,
) -> Option<String> {
    let (_, g) = residual(x, u);
    (0..PARAMETERS).find_map(|k| {
        let h = 1e-6 * x[k].abs().max(1.0);
        let (mut xp, mut xm) = (*x, *x);
        xp[k] += h;
        xm[k] -= h;
        let fd = (residual(&xp, u).0 - residual(&xm, u).0) / (2.0 * h);
        ((fd - g[k]).abs() > tol * (1.0 + g[k].abs())).then(|| format!("parameter {k}: analytic {} vs fd {fd}", g[k]))
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, .. ProptestConfig::default() })]

    /// The analytic gradient of the step-2 residual against central differences.
    #[test]
    fn step2_jacobian_matches_central_differences(
        p_diag in prop::array::uniform3(0.3f64..3.0),
        p_off in prop::array::uniform3(-0.5f64..0.5),
        o in prop::array::uniform3(-0.5f64..0.5),
        u in prop::array::uniform3(-2.0f64..2.0),
    ) {
        let P = [[p_diag[0], p_off[0], p_off[1]], [0.0, p_diag[1], p_off[2]], [0.0, 0.0, p_diag[2]]];
        let x = pack(&P, o);
        let (r0, _) = residual_and_gradient(&x, u);
        prop_assume!(r0 + 1.0 > 1e-2); // |P(u - o)| away from 0, where the residual is smooth
        // Central differences: truncation O(h^2) of the third derivative, rounding O(eps |r| / h).
        let mismatch = gradient_mismatch(residual_and_gradient, &x, u, 1e-7);
        prop_assert!(mismatch.is_none(), "{:?}", mismatch);
    }

    /// The analytic gradient of the residual in the readings' units against central differences.
    #[test]
    fn readings_residual_jacobian_matches_central_differences(
        p_diag in prop::array::uniform3(0.3f64..3.0),
        p_off in prop::array::uniform3(-0.5f64..0.5),
        o in prop::array::uniform3(-0.5f64..0.5),
        u in prop::array::uniform3(-2.0f64..2.0),
    ) {
        let P = [[p_diag[0], p_off[0], p_off[1]], [0.0, p_diag[1], p_off[2]], [0.0, 0.0, p_diag[2]]];
        let x = pack(&P, o);
        let (r0, _) = residual_and_gradient(&x, u);
        prop_assume!(r0 + 1.0 > 1e-2);
        // As above, with |e| up to about 100 here (|P^T w| is at least the smallest singular
        // value of P). At m = 0, (P, c) with c = -P o is the point (P, o).
        let y = pack(&P, scale(-1.0, crate::small::mat_vec(&P, o)));
        let mismatch = gradient_mismatch(reading_residual_and_gradient, &y, u, 1e-6);
        prop_assert!(mismatch.is_none(), "{:?}", mismatch);
    }
}

/// A vessel at Trondheim that rolls +-15 and pitches +-8 degrees (the field 75 degrees steep): the
/// paper's residual runs off along the valley of the up axis's scale and bias, the readings'
/// residual calibrates, with errors at the Cramer-Rao floor.
#[test]
fn the_readings_residual_calibrates_a_vessel_that_barely_tilts() {
    // WMM2025 at 63.43 N, 10.40 E, sea level, 2026.42 (NED, nT).
    let field = crate::ReferenceField::from_ned(13_517.64, 1_239.52, 50_486.16).unwrap();
    let truth = ErrorModel::new([0.0; 3], [1.0; 3], [0.0; 3]).unwrap();
    let mut design = Vec::new();
    for roll in [-15.0, 0.0, 15.0] {
        for pitch in [-8.0, 8.0] {
            for k in 0..8 {
                let a = Attitude::from_degrees(roll, -180.0 + 45.0 * f64::from(k), pitch);
                design.extend(std::iter::repeat_n(a, 6));
            }
        }
    }
    let body = field.body_fields(&design);
    let sigma = 50.0;
    let bound = crate::CramerRao::new(&truth, &body, sigma, &crate::PhysicalScales::default());
    let crb_s2 = bound.std.expect("regular information")[4];
    let trials = 200;
    let mut ok = [0usize; 2];
    let mut sq_s2 = 0.0;
    for (k, residual) in [Residual::Paper, Residual::Readings].into_iter().enumerate() {
        let settings = TwoStep {
            noise_nt: Some(sigma),
            residual,
            ..TwoStep::default()
        };
        for t in 0..trials {
            let mut rng = stream_rng(41, t);
            let readings = truth.noisy_readings(&body, sigma, &mut rng).unwrap();
            if let Ok(fit) = settings.calibrate(&readings, field.magnitude())
                && fit.status() == CalibrationStatus::Ok
            {
                ok[k] += 1;
                if residual == Residual::Readings {
                    sq_s2 += (fit.estimate().model.scale()[1] - 1.0).powi(2);
                }
            }
        }
    }
    let n = trials as usize;
    assert!(ok[0] <= n / 10, "paper's residual: {} of {n} ok", ok[0]);
    assert!(ok[1] >= n * 95 / 100, "readings' residual: {} of {n} ok", ok[1]);
    // The rms over n trials has a relative standard error of about 1 / sqrt(2 n) (5 % here):
    // within four of them of the floor.
    let ratio = (sq_s2 / ok[1] as f64).sqrt() / crb_s2;
    assert!(
        (ratio - 1.0).abs() <= 4.0 / (2.0 * ok[1] as f64).sqrt(),
        "rms / CRB of s2: {ratio}"
    );
}

#[test]
fn fewer_than_nine_readings_is_an_error() {
    let field = paper::changsha_field();
    let readings = paper::true_error_model().measure_all(&field.body_fields(&paper::uniformity_design()[..8]));
    let err = TwoStep::default().calibrate(&readings, field.magnitude()).unwrap_err();
    assert_eq!(err, CalibrationError::TooFewReadings { got: 8, needed: 9 });
    assert_eq!(err.status(), CalibrationStatus::TooFewReadings);
}

#[test]
fn all_readings_at_one_attitude_is_rank_deficient() {
    let field = paper::changsha_field();
    let design = vec![Attitude::from_degrees(1.0, 20.0, 3.0); 12];
    let readings = paper::true_error_model().measure_all(&field.body_fields(&design));
    let err = TwoStep::default().calibrate(&readings, field.magnitude()).unwrap_err();
    assert_eq!(err, CalibrationError::RankDeficient { rank: 1, needed: 9 });
    assert_eq!(err.status().as_str(), "rank_deficient");
}

#[test]
fn readings_on_a_hyperboloid_are_not_an_ellipsoid() {
    // Points on x^2 + y^2 - z^2 = R^2 (a hyperboloid of one sheet), offset by a bias.
    let r = 48_000.0;
    let readings: Vec<Vec3> = (0..20)
        .map(|i| {
            let t = -1.0 + 0.1 * i as f64;
            let phi = 0.7 * i as f64;
            [
                r * t.cosh() * phi.cos() + 1000.0,
                r * t.cosh() * phi.sin() - 500.0,
                r * t.sinh() + 200.0,
            ]
        })
        .collect();
    let err = TwoStep::default().calibrate(&readings, r).unwrap_err();
    assert!(matches!(err, CalibrationError::NotPositiveDefinite { .. }), "{err:?}");
    assert_eq!(err.status(), CalibrationStatus::NotPositiveDefinite);
}

#[test]
fn non_finite_input_is_an_error() {
    let field = paper::changsha_field();
    let clean = paper::true_error_model().measure_all(&field.body_fields(&paper::uniformity_design()));
    for (index, component, value) in [(3, 1, f64::NAN), (8, 2, f64::INFINITY), (0, 0, f64::NEG_INFINITY)] {
        let mut readings = clean.clone();
        readings[index][component] = value;
        let err = TwoStep::default().calibrate(&readings, field.magnitude()).unwrap_err();
        assert!(
            matches!(err, CalibrationError::NonFiniteReading { index: i, component: c, .. } if i == index && c == component),
            "{err:?}"
        );
        assert_eq!(err.status(), CalibrationStatus::NonFiniteInput);
    }
    for bad_r in [0.0, -1.0, f64::NAN] {
        let err = TwoStep::default().calibrate(&clean, bad_r).unwrap_err();
        assert!(matches!(err, CalibrationError::InvalidFieldMagnitude { .. }));
    }
}

#[test]
fn readings_that_do_not_determine_the_fit_are_not_identifiable() {
    use crate::calibration::CalibrationStatus;
    use crate::rng::stream_rng;
    // Level, twelve headings: the up axis never turns against the field.
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    let level: Vec<Attitude> = (0..12)
        .map(|i| Attitude::from_degrees(0.0, 30.0 * i as f64, 0.0))
        .collect();
    let settings = TwoStep {
        noise_nt: Some(30.0),
        ..TwoStep::default()
    };
    let mut statuses = Vec::new();
    for t in 0..200 {
        let readings = truth
            .noisy_readings(&field.body_fields(&level), 30.0, &mut stream_rng(31, t))
            .unwrap();
        let status = match settings.calibrate(&readings, field.magnitude()) {
            Ok(fit) => fit.status(),
            Err(e) => e.status(),
        };
        statuses.push(status);
    }
    // Never `ok`: either no ellipsoid, or one that the readings do not determine.
    assert!(statuses.iter().all(|s| *s != CalibrationStatus::Ok), "{statuses:?}");
    assert!(statuses.contains(&CalibrationStatus::NotIdentifiable));

    // A well-spread design at the same noise: every trial ok and locally identifiable.
    let spread = crate::design::sources::random(&crate::attitude::AttitudeBox::full(), 20, &mut stream_rng(32, 0));
    for t in 0..200 {
        let readings = truth
            .noisy_readings(&field.body_fields(&spread), 30.0, &mut stream_rng(33, t))
            .unwrap();
        let fit = settings.calibrate(&readings, field.magnitude()).unwrap();
        assert_eq!(
            (fit.status(), fit.identifiable),
            (CalibrationStatus::Ok, Some(true)),
            "trial {t}"
        );
    }
}
