use magcal_core::design::sources;
use magcal_core::log_fit::{self, FitModel, FitSettings};
use magcal_core::rng::stream_rng;
use magcal_core::{AttitudeBox, paper};

fn main() {
    let truth = paper::true_error_model();
    let field = paper::changsha_field();
    let r = field.magnitude();
    let m: usize = std::env::args().nth(1).unwrap().parse().unwrap();
    let given: bool = std::env::args().nth(2).unwrap() == "given";
    let trials: usize = std::env::args().nth(3).unwrap().parse().unwrap();
    let want = [truth.psi_deg(), truth.scale(), truth.bias_nt()].concat();
    let mut hits = [0usize; 9];
    let mut usable = 0;
    for seed in 0..400u64 {
        let mut rng = stream_rng(10_000 * m as u64 + seed, 0);
        let design = sources::random(&AttitudeBox::full(), m, &mut rng);
        let readings = truth
            .noisy_readings(&field.body_fields(&design), 30.0, &mut rng)
            .unwrap();
        let s = FitSettings {
            trials,
            noise: given.then_some(30.0),
            ..FitSettings::default()
        };
        if let Ok(f) = log_fit::fit_with(&readings, r, FitModel::Full, &s) {
            if let (true, Some((hp, hs, hb))) = (f.usable, f.interval95()) {
                usable += 1;
                let e = [f.errors.psi_deg(), f.errors.scale(), f.bias].concat();
                let h = [hp, hs, hb].concat();
                for i in 0..9 {
                    hits[i] += ((e[i] - want[i]).abs() <= h[i]) as usize;
                }
            }
        }
    }
    println!(
        "m {m} given {given} trials {trials}: usable {usable}, coverage {:?}",
        hits.map(|h| (1000.0 * h as f64 / usable as f64).round() / 1000.0)
    );
}
