//! The core's public results saved with serde: what a user writes is what they read back (the
//! workspace's serde_json reads a float's shortest text back to the same bits), and a fit's JSON
//! carries the fit's own numbers.

use magcal_core::log_fit::{self, FitModel};
use magcal_core::{Attitude, AttitudeBox, ErrorModel, Summary, design::replicated, paper, rng::stream_rng};

fn round_trip<T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug>(value: &T) {
    let text = serde_json::to_string(value).expect("serialises");
    let back: T = serde_json::from_str(&text).expect("reads back");
    assert_eq!(&back, value, "{text}");
}

#[test]
fn models_attitudes_boxes_and_summaries_read_back_bit_for_bit() {
    round_trip(&paper::true_error_model());
    round_trip(&ErrorModel::new([0.1, -0.7, 1e-9], [1.0 / 3.0, 0.97, 1.02], [-1.5e4, 0.25, 3.0]).unwrap());
    round_trip(&paper::auv_box());
    round_trip::<Vec<Attitude>>(&paper::conventions_optimum());
    let box_: AttitudeBox = paper::auv_box();
    round_trip(&box_);
    round_trip(&Summary::new(&[0.1, 0.2, 0.30000000000000004, 7.0], 1));
}

#[test]
fn a_fits_json_holds_its_estimates_and_standard_errors() {
    let field = paper::changsha_field();
    let truth = paper::true_error_model();
    let body = field.body_fields(&replicated(&paper::conventions_optimum(), &[20; 9]));
    let readings = truth
        .noisy_readings(&body, paper::SIGMA_NT, &mut stream_rng(7, 0))
        .unwrap();
    let fit = log_fit::fit(&readings, field.magnitude(), FitModel::Full).unwrap();
    let json: serde_json::Value = serde_json::to_value(&fit).unwrap();
    let numbers =
        |v: &serde_json::Value| -> Vec<f64> { v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect() };
    assert_eq!(numbers(&json["bias"]), fit.bias.to_vec());
    assert_eq!(numbers(&json["std_bias"]), fit.std_bias.unwrap().to_vec());
    assert_eq!(json["usable"], serde_json::Value::Bool(fit.usable));
    let model: ErrorModel = serde_json::from_value(json["errors"].clone()).unwrap();
    assert_eq!(model, fit.errors);
}
