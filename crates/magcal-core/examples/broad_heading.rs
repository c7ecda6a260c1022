//! Whether the heading budget's verdict is what happens on a real log: windows of the BROAD
//! trials (and the whole trials) with \[P1\]'s sensor imposed, where the true calibration is known
//! (docs/conventions.md "Heading budget", its evidence).
//!
//! ```text
//! cargo run --release -p magcal-core --example broad_heading -- [DIR] [--windows 10,20,40] [--starts 4] [--budget 2]
//! ```
//!
//! The truth of a window is that of `replay --truth impose` (`K K0`, `K O0 + O`, `(K0, O0)` the
//! trial's own full calibration of its rows with an attitude). Each window of the movement rows
//! is fitted as `calibrate` fits a log in time order (full model, the default check and held-out
//! fits) and judged over level headings in the trial's field (inclination 69.7 degrees, from the
//! capture's alignment; the axes those of the readings). Printed per window length: the windows,
//! how many are usable, the coverage of the 95 % intervals per parameter (usable windows), the
//! true heading error (95th percentile over the headings of the estimate against the truth) of
//! the usable windows and how many are within the budget, and of the windows not usable how many
//! are beyond it.

use std::path::{Path, PathBuf};

use magcal_core::budget::{self, BudgetGrid, IDENTITY, Tilts};
use magcal_core::log_fit::{self, FitModel, FitSettings, Order};
use magcal_core::small::{add, mat_mul, mat_vec, norm, upper_triangular_inverse};
use magcal_core::{ErrorModel, Vec3, paper};

/// The inclination of the capture room's field (the trials' alignment with the capture).
const INCLINATION_DEG: f64 = 69.7;

struct Trial {
    name: &'static str,
    magnitude: f64,
    truth: ErrorModel,
    /// The truth from the movement rows' own calibration.
    movement_truth: ErrorModel,
    /// The raw movement rows (nT), for the truth without a window.
    raw_moving: Vec<Vec3>,
    /// The movement rows with the sensor imposed, nT, in time order.
    moving: Vec<Vec3>,
}

fn read(dir: &Path, name: &'static str) -> Trial {
    let text = std::fs::read_to_string(dir.join(format!("{name}.csv"))).expect("the BROAD trials");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
    let (mx, qw, mv) = (col("mx"), col("qw"), col("movement"));
    let rows: Vec<(Vec3, bool, bool)> = lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            let b = [0, 1, 2].map(|i| v[mx + i].parse::<f64>().unwrap() * 1e3);
            (b, !v[qw].is_empty(), v[mv] == "1")
        })
        .collect();
    let imposed = paper::true_error_model();
    let (k, o) = (imposed.K(), imposed.bias_nt());
    let clean: Vec<Vec3> = rows.iter().filter(|r| r.1).map(|r| r.0).collect();
    let mut norms: Vec<f64> = clean.iter().map(|b| norm(*b)).collect();
    norms.sort_by(f64::total_cmp);
    let magnitude = norms[norms.len() / 2];
    let whole = FitSettings {
        trials: 0,
        profile: false,
        held_out: false,
        ..FitSettings::default()
    };
    let base = log_fit::fit_with(&clean, magnitude, FitModel::Full, &whole).unwrap();
    let k0 = upper_triangular_inverse(&base.p).unwrap();
    let truth = ErrorModel::from_k(&mat_mul(&k, &k0), add(mat_vec(&k, base.bias), o));
    let moving = rows.iter().filter(|r| r.2).map(|r| add(mat_vec(&k, r.0), o)).collect();
    let raw_moving: Vec<Vec3> = rows.iter().filter(|r| r.2).map(|r| r.0).collect();
    let movement_truth = composed(&raw_moving, magnitude);
    Trial {
        name,
        magnitude,
        truth,
        movement_truth,
        raw_moving,
        moving,
    }
}

/// The imposed sensor on the full calibration of `raw` (nT) at `magnitude`.
fn composed(raw: &[Vec3], magnitude: f64) -> ErrorModel {
    let imposed = paper::true_error_model();
    let whole = FitSettings {
        trials: 0,
        profile: false,
        held_out: false,
        ..FitSettings::default()
    };
    let base = log_fit::fit_with(raw, magnitude, FitModel::Full, &whole).unwrap();
    let k0 = upper_triangular_inverse(&base.p).unwrap();
    let k = imposed.K();
    ErrorModel::from_k(&mat_mul(&k, &k0), add(mat_vec(&k, base.bias), imposed.bias_nt()))
}

/// One window's outcome.
struct Outcome {
    usable: bool,
    hits: [bool; 9],
    predicted: Option<f64>,
    true_p95: f64,
    /// Against the movement rows' truth, and against theirs without the window.
    movement_p95: f64,
    leave_out_p95: f64,
    why: String,
}

fn judge(t: &Trial, range: std::ops::Range<usize>, grid: &BudgetGrid, budget_deg: f64) -> Option<Outcome> {
    let readings = &t.moving[range.clone()];
    let settings = FitSettings {
        order: Order::Time,
        ..FitSettings::default()
    };
    let mut f = log_fit::fit_with(readings, t.magnitude, FitModel::Full, &settings).ok()?;
    f.judge_heading(grid, budget_deg, log_fit::CHECK_SEED);
    let (hp, hs, hb) = f.interval95()?;
    let est = [f.errors.psi_deg(), f.errors.scale(), f.bias];
    let truth = [t.truth.psi_deg(), t.truth.scale(), t.truth.bias_nt()];
    let half = [hp, hs, hb];
    let hits = std::array::from_fn(|i| (est[i / 3][i % 3] - truth[i / 3][i % 3]).abs() <= half[i / 3][i % 3]);
    // The estimate against the truth: readings of the true sensor, calibrated by the estimate.
    let p95 = |truth: &ErrorModel| {
        let mut e = Vec::new();
        grid.errors_into((&truth.K(), truth.bias_nt()), t.magnitude, (&f.p, f.bias), &mut e);
        budget::quantile(&mut e, budget::BUDGET_QUANTILE)
    };
    let rest: Vec<Vec3> = t
        .raw_moving
        .iter()
        .enumerate()
        .filter(|(i, _)| !range.contains(i))
        .map(|(_, b)| *b)
        .collect();
    let leave_out_p95 = if rest.len() > 1000 {
        p95(&composed(&rest, t.magnitude))
    } else {
        f64::NAN
    };
    let mut e = Vec::new();
    grid.errors_into((&t.truth.K(), t.truth.bias_nt()), t.magnitude, (&f.p, f.bias), &mut e);
    Some(Outcome {
        movement_p95: p95(&t.movement_truth),
        leave_out_p95,
        usable: f.usable,
        hits,
        predicted: f.heading.as_ref().map(|h| h.predicted_deg()),
        true_p95: budget::quantile(&mut e, budget::BUDGET_QUANTILE),
        why: f
            .reasons
            .first()
            .map_or(String::new(), |r| r.chars().take(70).collect()),
    })
}

fn main() {
    let mut dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/broad");
    let mut windows = vec![10.0, 20.0, 40.0];
    let mut starts = 4usize;
    let mut budget_deg = budget::DEFAULT_BUDGET_DEG;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--windows" => windows = args.next().unwrap().split(',').map(|s| s.parse().unwrap()).collect(),
            "--starts" => starts = args.next().unwrap().parse().unwrap(),
            "--budget" => budget_deg = args.next().unwrap().parse().unwrap(),
            _ => dir = PathBuf::from(a),
        }
    }
    let trials: Vec<Trial> = [
        "02_undisturbed_slow_rotation_B",
        "05_undisturbed_slow_rotation_with_breaks_B",
    ]
    .into_iter()
    .map(|n| read(&dir, n))
    .collect();
    let grid = BudgetGrid::new(INCLINATION_DEG, Tilts::LEVEL, &IDENTITY);
    println!(
        "| window | windows | usable | coverage per parameter (usable) | true p95 of usable: median, max | usable within budget | predicted >= true (usable) | not usable beyond budget |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let detail = std::env::var_os("BROAD_DETAIL").is_some();
    let mut whole_rows = Vec::new();
    for t in &trials {
        if let Some(o) = judge(t, 0..t.moving.len(), &grid, budget_deg) {
            whole_rows.push(format!(
                "| {} whole ({} readings) | usable {} | predicted {:.2} | true {:.2} | {} |",
                &t.name[..2],
                t.moving.len(),
                o.usable,
                o.predicted.unwrap_or(f64::NAN),
                o.true_p95,
                o.why
            ));
        }
    }
    for &w in &windows {
        let n = (w * 285.714_f64).round() as usize;
        let step = (n / starts).max(1);
        let mut outcomes = Vec::new();
        for t in &trials {
            let mut start = 0;
            while start + n <= t.moving.len() {
                if let Some(o) = judge(t, start..start + n, &grid, budget_deg) {
                    if detail {
                        println!(
                            "{} {start} usable {} predicted {:?} true {:.2} movement {:.2} leave-out {:.2} {}",
                            &t.name[..2],
                            o.usable,
                            o.predicted,
                            o.true_p95,
                            o.movement_p95,
                            o.leave_out_p95,
                            o.why
                        );
                    }
                    outcomes.push(o);
                }
                start += step;
            }
        }
        let usable: Vec<&Outcome> = outcomes.iter().filter(|o| o.usable).collect();
        let nu = usable.len().max(1) as f64;
        let coverage: Vec<String> = (0..9)
            .map(|i| format!("{:.2}", usable.iter().filter(|o| o.hits[i]).count() as f64 / nu))
            .collect();
        let mut truths: Vec<f64> = usable.iter().map(|o| o.true_p95).collect();
        truths.sort_by(f64::total_cmp);
        let within = usable.iter().filter(|o| o.true_p95 <= budget_deg).count();
        let within_movement = usable.iter().filter(|o| o.movement_p95 <= budget_deg).count();
        let within_leave_out = usable.iter().filter(|o| o.leave_out_p95 <= budget_deg).count();
        let honest = usable
            .iter()
            .filter(|o| o.predicted.is_some_and(|p| p >= o.true_p95))
            .count();
        let not: Vec<&Outcome> = outcomes.iter().filter(|o| !o.usable).collect();
        let beyond = not.iter().filter(|o| o.true_p95 > budget_deg).count();
        println!(
            "| {w} s | {} | {} | {} | {:.2}, {:.2} | {within} of {} (movement truth {within_movement}, leave-out {within_leave_out}) | {honest} of {} | {beyond} of {} |",
            outcomes.len(),
            usable.len(),
            coverage.join(" "),
            truths.get(truths.len() / 2).copied().unwrap_or(f64::NAN),
            truths.last().copied().unwrap_or(f64::NAN),
            usable.len(),
            usable.len(),
            not.len()
        );
    }
    println!();
    for r in whole_rows {
        println!("{r}");
    }
}
