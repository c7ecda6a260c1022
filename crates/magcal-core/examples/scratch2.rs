use magcal_core::log_fit::{self, FitModel, FitSettings, Residual};

fn main() {
    let path = std::env::args().nth(1).unwrap();
    let cols: Vec<usize> = std::env::args()
        .nth(2)
        .unwrap()
        .split(',')
        .map(|c| c.parse().unwrap())
        .collect();
    let text = std::fs::read_to_string(&path).unwrap();
    let readings: Vec<[f64; 3]> = text
        .lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.trim().parse().unwrap()).collect();
            [v[cols[0]], v[cols[1]], v[cols[2]]]
        })
        .collect();
    for (i, w) in readings.chunks_exact(300).enumerate() {
        for residual in [Residual::Readings, Residual::Paper] {
            let s = FitSettings {
                trials: 200,
                residual,
                ..FitSettings::default()
            };
            match log_fit::fit_with(w, 1.0, FitModel::Full, &s) {
                Ok(f) => {
                    if !f.ellipsoid.passed || residual == Residual::Readings {
                        println!(
                            "{i} {residual:?}: ell {:.2}% it {} status {:?} S {:?} psi {:?} usable {} prof {:?}",
                            f.ellipsoid.residual_percent,
                            f.iterations,
                            f.status,
                            f.errors.scale().map(|v| (v * 1000.0).round() / 1000.0),
                            f.errors.psi_deg().map(|v| (v * 10.0).round() / 10.0),
                            f.usable,
                            f.profile.map(|p| p.rise)
                        )
                    }
                }
                Err(e) => println!("{i} {residual:?}: {e}"),
            }
        }
    }
}
