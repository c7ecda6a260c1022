use magcal_core::design::sources;
use magcal_core::log_fit::{self, FitModel, FitSettings};
use magcal_core::rng::stream_rng;
use magcal_core::{AttitudeBox, CramerRao, PhysicalScales, paper};

fn main() {
    let truth = paper::true_error_model();
    let field = paper::changsha_field();
    let r = field.magnitude();
    let tilt: f64 = std::env::args().nth(1).unwrap().parse().unwrap();
    let n: usize = std::env::args().nth(2).unwrap().parse().unwrap();
    let bounds = AttitudeBox::from_degrees([-tilt, tilt], [-180.0, 180.0], [-tilt, tilt]).unwrap();
    let mut rng = stream_rng(21, 0);
    let design = sources::random(&bounds, n, &mut rng);
    let crb = CramerRao::new(&truth, &field.body_fields(&design), 30.0, &PhysicalScales::default());
    println!(
        "CRB at truth: std S {:?} O {:?} ident {}",
        crb.std.map(|s| [s[3], s[4], s[5]]),
        crb.std.map(|s| [s[6], s[7], s[8]]),
        crb.verdict.identifiable
    );
    let settings = FitSettings {
        trials: 40,
        ..FitSettings::default()
    };
    let mut rows = vec![];
    for seed in 0..60u64 {
        let mut rng = stream_rng(1000 + seed, 0);
        let design = sources::random(&bounds, n, &mut rng);
        let readings = truth
            .noisy_readings(&field.body_fields(&design), 30.0, &mut rng)
            .unwrap();
        if let Ok(f) = log_fit::fit_with(&readings, r, FitModel::Full, &settings) {
            let z = (f.errors.scale()[1] - 0.7) / f.std_scale.map_or(f64::NAN, |s| s[1]);
            rows.push((f.usable, f.errors.scale()[1], z));
            println!(
                "{seed}: usable {} Sy {:.4} se {:.4} z {:.2} check {:?} rise {:?}",
                f.usable,
                f.errors.scale()[1],
                f.std_scale.map_or(f64::NAN, |s| s[1]),
                z,
                f.check.map(|c| (c.ok, c.trials)),
                f.profile.map(|p| (p.rise, p.along, p.side))
            );
        }
    }
    let u: Vec<_> = rows.iter().filter(|r| r.0).collect();
    let inside = u.iter().filter(|r| r.2.abs() <= 2.576).count();
    println!("usable {} of {}, inside 99% {}", u.len(), rows.len(), inside);
}
