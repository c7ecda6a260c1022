use magcal_core::design::sources;
use magcal_core::log_fit::{self, FitModel, FitSettings};
use magcal_core::rng::stream_rng;
use magcal_core::calibration::{TwoStep, step2::Residual};
use magcal_core::{paper, AttitudeBox};
use magcal_core::small::{mat_vec, sub, norm, mat_t_vec};

fn cost(p: &[[f64;3];3], o: [f64;3], readings: &[[f64;3]], r: f64) -> f64 {
    readings.iter().map(|&s| { let b = mat_vec(p, sub(s, o)); let n = norm(b); let w = b.map(|v| v/n); let g = mat_t_vec(p, w); ((n - r)/norm(g)).powi(2) }).sum()
}

fn main() {
    let truth = paper::true_error_model();
    let field = paper::changsha_field();
    let r = field.magnitude();
    let tilt: f64 = std::env::args().nth(1).unwrap().parse().unwrap();
    let bounds = AttitudeBox::from_degrees([-tilt, tilt], [-180.0, 180.0], [-tilt, tilt]).unwrap();
    for seed in [0u64, 13, 20, 1, 2] {
        let mut rng = stream_rng(1000 + seed, 0);
        let design = sources::random(&bounds, 400, &mut rng);
        let readings = truth.noisy_readings(&field.body_fields(&design), 30.0, &mut rng).unwrap();
        let f = log_fit::fit_with(&readings, r, FitModel::Full, &FitSettings { trials: 0, ..Default::default() }).unwrap();
        let c0 = cost(&f.p, f.bias, &readings, r) / 900.0;
        let ts = TwoStep { residual: Residual::Readings, ..TwoStep::default() };
        let tp = truth.P();
        print!("seed {seed}: Sy {:.3} cost {c0:.1};", f.errors.scale()[1]);
        for p22 in [tp[1][1] * 0.8, tp[1][1], tp[1][1]*1.25, tp[1][1]*1.6, tp[1][1]*2.0, f.p[1][1]] {
            let mut p = f.p; p[1][1] = p22;
            let mut free = [true; 6]; free[3] = false;
            match ts.calibrate_holding(&readings, r, p, free) {
                Ok(c) => { let e = c.estimate(); print!(" P22 {:.3} (Sy {:.3}) dcost {:.2};", p22, e.model.scale()[1], cost(&e.p, e.bias_nt, &readings, r)/900.0 - c0); }
                Err(e) => print!(" {e};"),
            }
        }
        println!();
    }
}
