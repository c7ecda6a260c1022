//! Any truth, zeros included (a nominal sensor: psi 0, S 1, O 0), gives outputs without a panic
//! and without NaN: a relative error of a zero truth is `None`, everything else a finite number.

use magcal_core::design::sources;
use magcal_core::heading::HeadingProbe;
use magcal_core::monte_carlo::trial;
use magcal_core::rng::stream_rng;
use magcal_core::{AttitudeBox, CramerRao, ErrorModel, PhysicalScales, TwoStep, paper};
use proptest::prelude::*;

/// A component that is exactly zero a third of the time.
fn maybe_zero(range: std::ops::Range<f64>) -> impl Strategy<Value = f64> {
    prop_oneof![Just(0.0), range.clone(), range]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    #[test]
    fn no_panic_and_no_nan_for_any_truth(
        psi in proptest::array::uniform3(maybe_zero(-5.0..5.0)),
        scale in proptest::array::uniform3(prop_oneof![Just(1.0), 0.5..2.0]),
        bias in proptest::array::uniform3(maybe_zero(-20_000.0..20_000.0)),
        m in 9usize..16,
        sigma in prop_oneof![Just(0.0), 0.1..300.0],
        seed in any::<u64>(),
    ) {
        let truth = ErrorModel::new(psi, scale, bias).unwrap();
        let field = paper::changsha_field();
        let design = sources::random(&AttitudeBox::full(), m, &mut stream_rng(seed, 0));
        let body = field.body_fields(&design);
        let probe = HeadingProbe::new(&field, &truth);
        let settings = TwoStep { noise_nt: Some(sigma), ..TwoStep::default() };
        let o = trial(&truth, &body, field.magnitude(), sigma, &settings, &probe, &mut stream_rng(seed, 1)).unwrap();
        if let Some(eta) = o.eta {
            for (value, truth_norm) in [(eta.psi, psi), (eta.scale, scale), (eta.bias, bias)] {
                let zero = truth_norm.iter().all(|v| *v == 0.0);
                prop_assert_eq!(value.is_none(), zero);
                prop_assert!(value.is_none_or(f64::is_finite));
            }
            let abs = o.abs.unwrap();
            prop_assert!(abs.psi_deg.is_finite() && abs.scale.is_finite() && abs.bias_nt.is_finite());
            let h = o.heading.unwrap();
            prop_assert!(h.rms_deg.is_finite() && h.max_deg.is_finite() && h.rms_deg <= h.max_deg + 1e-12);
        }
        let bound = CramerRao::new(&truth, &body, sigma, &PhysicalScales::default());
        for v in bound.rms_eta().into_iter().chain(bound.rms_abs()).flatten() {
            prop_assert!(v.is_finite() && v >= 0.0);
        }
        if let Some(std) = bound.std {
            prop_assert!(std.iter().all(|v| v.is_finite() && *v >= 0.0));
        }
        prop_assert!(!bound.verdict.weakest.is_empty() && !bound.verdict.weakest.contains("NaN"));
    }
}
