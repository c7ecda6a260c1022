//! Whether a log fit's confidence intervals hold on real logs: coverage of the 95 % and 99 %
//! intervals of the full model on windows of the BROAD trials (docs/conventions.md "Real data",
//! "Replaying designs on a real log", its "Truth" paragraph) under white-noise standard errors
//! and under the standard errors of the residuals' long-run covariance ([`log_fit::serial`])
//! with several batch rules.
//!
//! ```text
//! cargo run --release -p magcal-core --example broad_coverage -- ../shared/data/broad
//!     [--windows 5,10,20,40] [--starts 1] [--trials 200] [--rules white,shipped,andrews1,fixed0.5,frac5,...]
//! ```
//!
//! For each clean trial with rotations (02, 05): the readings in nT (uT x 1000) carry \[P1\]'s
//! sensor, `B' = K B + O` (`paper::true_error_model`); the truth is `K K0`, `K O0 + O` with
//! `(K0, O0)` the full calibration of the trial's readings with an attitude (as `replay --truth
//! impose` takes them) at their median magnitude, the magnitude every fit here is made to. The
//! movement rows (movement = 1, breaks left out, in time order) are cut into consecutive windows
//! of W seconds, and each window is fitted (full model, default check by trials) under each rule:
//!
//! - `white`: `Order::Unknown`, what a fit reported before ("before");
//! - `shipped`: `Order::Time`, what a fit in time order reports ("after"; a batch of `m / 10`);
//! - `andrewsC`: batch `C` times Andrews' AR(1) length from the residuals' lag-one
//!   autocorrelation, at most `m / 10` (`andrews1` was the rule of `Order::Time` before);
//! - `fixedS`: a batch of `S` seconds (`Order::Batch`), where it leaves at least 4 batches;
//! - `fracK`: a batch of `m / K` readings.
//!
//! Of each time-order fit four standard errors are scored: as reported (the larger of the
//! long-run and the white ones, the check's trials' rms error as a floor), the long-run ones
//! alone (`LogFit::serial_std`), the larger of long-run and white without the floor, and the
//! trials' rms error alone (a circular block bootstrap of the log's residuals, `log_fit/check.rs`;
//! normal quantiles). Intervals are `quantile * std` with the fit's quantile (Student's t of its
//! degrees of freedom; for a standard error the held-out fits set, the t of their jackknife's,
//! as `LogFit::interval95` and so `calibrate` state it) and its 99.5 % counterpart for the 99 %
//! intervals.
//!
//! The windows of one trial are not independent, and the truth is an estimate that contains
//! them: the same tables against the movement rows' calibration (which holds each window more
//! strongly) and against the movement rows' without the window (which holds none of it) bracket
//! what that does. `BROAD_DETAIL=1` prints each window under the shipped rule, per parameter
//! `z` against the trial's truth / `z` against the movement rows' / the 95 % quantile its
//! interval takes.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use magcal_core::log_fit::{self, FitModel, FitSettings, LogFit, Order, serial};
use magcal_core::small::{add, mat_mul, mat_vec, norm, upper_triangular_inverse};
use magcal_core::{ErrorModel, Vec3, paper};
use statrs::distribution::{ContinuousCDF, Normal, StudentsT};

/// The clean trials with rotations, whose windows are scored.
const SCORED: [&str; 2] = [
    "02_undisturbed_slow_rotation_B",
    "05_undisturbed_slow_rotation_with_breaks_B",
];
/// Every trial, for the residuals' correlation and the ratio of long-run to white standard errors.
const ALL: [&str; 5] = [
    "02_undisturbed_slow_rotation_B",
    "05_undisturbed_slow_rotation_with_breaks_B",
    "10_undisturbed_slow_translation_A",
    "30_disturbed_stationary_magnet_C",
    "33_disturbed_attached_magnet_2cm",
];
const NAMES: [&str; 9] = ["psi1", "psi2", "psi3", "S1", "S2", "S3", "O1", "O2", "O3"];

/// One row of a BROAD CSV.
struct Row {
    t: f64,
    /// nT.
    b: Vec3,
    attitude: bool,
    movement: bool,
}

fn read_trial(dir: &Path, name: &str) -> Result<Vec<Row>, String> {
    let path = dir.join(format!("{name}.csv"));
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().ok_or("empty file")?.split(',').map(str::trim).collect();
    let col = |n: &str| {
        header
            .iter()
            .position(|h| *h == n)
            .ok_or_else(|| format!("{}: no column {n}", path.display()))
    };
    let (t, mx, my, mz, qw, mv) = (
        col("t_s")?,
        col("mx")?,
        col("my")?,
        col("mz")?,
        col("qw")?,
        col("movement")?,
    );
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate().filter(|(_, l)| !l.trim().is_empty()) {
        let v: Vec<&str> = line.split(',').map(str::trim).collect();
        let num = |c: usize| {
            v.get(c).and_then(|s| s.parse::<f64>().ok()).ok_or_else(|| {
                format!(
                    "{} line {}: column {} is not a number",
                    path.display(),
                    i + 2,
                    header[c]
                )
            })
        };
        rows.push(Row {
            t: num(t)?,
            // uT to nT.
            b: [num(mx)? * 1e3, num(my)? * 1e3, num(mz)? * 1e3],
            attitude: v.get(qw).is_some_and(|s| !s.is_empty()),
            movement: num(mv)? == 1.0,
        });
    }
    Ok(rows)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The fit of a whole log: no check, no profile (replay's whole-log fit).
fn whole() -> FitSettings {
    FitSettings {
        trials: 0,
        profile: false,
        ..FitSettings::default()
    }
}

fn nine(psi: Vec3, s: Vec3, o: Vec3) -> [f64; 9] {
    [psi[0], psi[1], psi[2], s[0], s[1], s[2], o[0], o[1], o[2]]
}

/// `(psi, S, O)` of the imposed sensor on readings whose own calibration is `base`.
fn composed(base: &LogFit) -> Result<[f64; 9], String> {
    let imposed = paper::true_error_model();
    let k0 = upper_triangular_inverse(&base.p).ok_or("the trial's calibration is singular")?;
    let k = imposed.K();
    let t = ErrorModel::from_k(&mat_mul(&k, &k0), add(mat_vec(&k, base.bias), imposed.bias_nt()));
    Ok(nine(t.psi_deg(), t.scale(), t.bias_nt()))
}

fn impose(b: Vec3) -> Vec3 {
    let imposed = paper::true_error_model();
    add(mat_vec(&imposed.K(), b), imposed.bias_nt())
}

/// A batch rule.
#[derive(Clone, Copy, PartialEq)]
enum Rule {
    White,
    /// `Order::Time`: what a fit in time order reports.
    Shipped,
    /// Andrews' length times this factor, at most `m / 10`.
    Andrews(f64),
    /// This many seconds.
    Fixed(f64),
    /// `m` over this many batches.
    Fraction(usize),
}

impl Rule {
    fn parse(s: &str) -> Result<Self, String> {
        let num = |t: &str| t.parse::<f64>().map_err(|_| format!("rule {s}: not a number"));
        match s {
            "white" => Ok(Self::White),
            "shipped" => Ok(Self::Shipped),
            _ if s.starts_with("andrews") => Ok(Self::Andrews(num(&s[7..])?)),
            _ if s.starts_with("fixed") => Ok(Self::Fixed(num(&s[5..])?)),
            _ if s.starts_with("frac") => Ok(Self::Fraction(num(&s[4..])? as usize)),
            _ => Err(format!("unknown rule {s}")),
        }
    }

    fn name(&self) -> String {
        match self {
            Self::White => "white (before)".into(),
            Self::Shipped => "shipped (Order::Time)".into(),
            Self::Andrews(c) if *c == 1.0 => "Andrews (old)".into(),
            Self::Andrews(c) => format!("{c} x Andrews"),
            Self::Fixed(s) => format!("batch {s} s"),
            Self::Fraction(k) => format!("batch m / {k}"),
        }
    }
}

/// The standard errors scored of a fit.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Source {
    Reported,
    HacAlone,
    HacOrWhite,
    Bootstrap,
    WhiteAlone,
}

impl Source {
    fn name(&self) -> &'static str {
        match self {
            Self::Reported => "reported",
            Self::HacAlone => "HAC alone",
            Self::HacOrWhite => "max(HAC, white)",
            Self::Bootstrap => "trials' rms alone",
            Self::WhiteAlone => "white alone",
        }
    }
}

/// Nine values, one per parameter (`psi1..3`, `S1..3`, `O1..3`).
type Nine = [f64; 9];

/// One window's fit under one rule.
struct Record {
    usable: bool,
    estimate: [f64; 9],
    /// Standard errors by source, with the 95 % and 99 % quantiles that go with them (per
    /// parameter: a standard error the held-out fits set takes their jackknife's Student t, as
    /// `LogFit::interval95` does).
    std: Vec<(Source, Nine, Nine, Nine)>,
    batch: Option<usize>,
    lag_one: Option<f64>,
    inflation: f64,
    why: String,
}

fn t_quantile(q: f64, dof: usize) -> f64 {
    StudentsT::new(0.0, 1.0, dof as f64).map_or(f64::NAN, |d| d.inverse_cdf(q))
}

fn z_quantile(q: f64) -> f64 {
    Normal::standard().inverse_cdf(q)
}

/// Andrews' AR(1) Bartlett length for `m` values of lag-one autocorrelation `rho`, before any
/// rounding or cap (the rule of `Order::Time` before the batch became a tenth of the log).
fn andrews(rho: f64, m: usize) -> f64 {
    let alpha = 4.0 * rho * rho / ((1.0 - rho).powi(2) * (1.0 + rho).powi(2));
    1.1447 * (alpha * m as f64).cbrt()
}

/// The fit of `readings` (one window, `rate` readings per second) under `rule` at `magnitude`,
/// with the check's `trials`; `None` where there is no fit or the rule gives no batch.
fn fit_window(readings: &[Vec3], magnitude: f64, rule: Rule, rate: f64, trials: usize) -> Option<Record> {
    let m = readings.len();
    let most = (m / serial::MIN_BATCHES).max(1);
    let order = match rule {
        Rule::White => Order::Unknown,
        Rule::Shipped => Order::Time,
        Rule::Andrews(c) => {
            // Andrews' length before its cap, from the residuals of the window's fit.
            let probe = log_fit::fit_with(
                readings,
                magnitude,
                FitModel::Full,
                &FitSettings {
                    order: Order::Time,
                    ..whole()
                },
            )
            .ok()?;
            let l = c * andrews(probe.serial?.lag_one?, m);
            Order::Batch((l.ceil() as usize).clamp(1, most))
        }
        Rule::Fixed(s) => {
            // At least four batches: fewer leave the long-run covariance a guess.
            let l = (s * rate).round() as usize;
            if l > m / 4 {
                return None;
            }
            Order::Batch(l.max(1))
        }
        Rule::Fraction(k) => Order::Batch((m / k).max(1)),
    };
    let settings = FitSettings {
        order,
        trials,
        ..FitSettings::default()
    };
    let f = log_fit::fit_with(readings, magnitude, FitModel::Full, &settings).ok()?;
    let estimate = nine(f.errors.psi_deg(), f.errors.scale(), f.bias);
    let dof = f.serial.map_or(m - 9, |s| s.dof(m));
    let (q95, q99) = (t_quantile(0.975, dof), t_quantile(0.995, dof));
    let mut std = Vec::new();
    if let (Some(p), Some(s), Some(o)) = (f.std_psi_deg, f.std_scale, f.std_bias) {
        // The quantiles the fit's own intervals take (`LogFit::interval95`): the jackknife's
        // Student t for a standard error the held-out fits set, the fit's elsewhere.
        // The cut of fewest degrees of freedom (`HeldOut::quantile95`, the largest t).
        let held = f.held_out.as_ref().and_then(|h| {
            let dof = h
                .scales
                .iter()
                .filter(|s| s.jackknife_quantile95.is_some())
                .map(|s| s.determined - 1)
                .min()?;
            Some((t_quantile(0.975, dof).max(q95), t_quantile(0.995, dof).max(q99)))
        });
        let q = |level: usize| -> [f64; 9] {
            std::array::from_fn(|i| {
                let set = f.std_source[i / 3][i % 3] == log_fit::StdSource::HeldOut;
                match (set, held, level) {
                    (true, Some((h95, _)), 0) => h95,
                    (true, Some((_, h99)), _) => h99,
                    (_, _, 0) => q95,
                    _ => q99,
                }
            })
        };
        std.push((Source::Reported, nine(p, s, o), q(0), q(1)));
    }
    if let (Some([hp, hs, ho]), Some([wp, ws, wo])) = (f.serial_std, f.white_std) {
        let (h, w) = (nine(hp, hs, ho), nine(wp, ws, wo));
        std.push((Source::HacAlone, h, [q95; 9], [q99; 9]));
        std.push((
            Source::HacOrWhite,
            std::array::from_fn(|i| h[i].max(w[i])),
            [q95; 9],
            [q99; 9],
        ));
        std.push((
            Source::WhiteAlone,
            w,
            [t_quantile(0.975, m - 9); 9],
            [t_quantile(0.995, m - 9); 9],
        ));
    }
    if let Some([p, s, o]) = f.check.and_then(|c| c.rms_error) {
        std.push((
            Source::Bootstrap,
            nine(p, s, o),
            [z_quantile(0.975); 9],
            [z_quantile(0.995); 9],
        ));
    }
    Some(Record {
        usable: f.usable,
        estimate,
        std,
        batch: f.serial.map(|s| s.batch),
        lag_one: f.serial.and_then(|s| s.lag_one),
        inflation: f.profile.map_or(1.0, |p| p.inflation()),
        why: f
            .reasons
            .first()
            .map_or(String::new(), |r| r.chars().take(120).collect()),
    })
}

/// The truths a window is scored against: the trial's (rows with an attitude, as replay takes
/// them), the movement rows', the movement rows' without the window, and that last with its own
/// uncertainty: the fit of the other movement rows is an estimate too, made as `calibrate` makes
/// one (in time order, with its check and held-out fits), so the window's interval is set
/// against the difference of two independent estimates, `|a - b| <= q sqrt(se_a^2 + se_b^2)`.
const TRUTHS: [&str; 4] = [
    "the trial's (rows with an attitude)",
    "the movement rows'",
    "the movement rows' without the window",
    "the movement rows' without the window, its standard errors added",
];

/// A scale factor this far from the truth, relative, is another solution, not an error an
/// interval describes.
const WRONG_SCALE: f64 = 0.25;

/// Hits of one rule and source over windows.
#[derive(Default, Clone)]
struct Tally {
    /// Windows with an interval: all, usable, usable and not a wrong solution.
    n_all: usize,
    n_usable: usize,
    n_right: usize,
    /// `[truth][95 %, 99 %][parameter]` hits: all windows, usable ones, usable right ones.
    all: [[[usize; 9]; 2]; 4],
    usable: [[[usize; 9]; 2]; 4],
    right: [[[usize; 9]; 2]; 4],
    /// Usable windows: `|z|` against the trial's truth, every parameter.
    z: Vec<f64>,
    /// Usable windows: the log of the standard error against the white fit's, every parameter.
    log_width: Vec<f64>,
}

/// One window's scores.
struct Scores<'a> {
    usable: bool,
    right: bool,
    estimate: &'a [f64; 9],
    truths: [&'a [f64; 9]; 4],
    /// The standard errors of the fourth truth.
    truth_std: &'a [f64; 9],
    white: Option<&'a [f64; 9]>,
}

impl Tally {
    fn add(&mut self, w: &Scores, std: &[f64; 9], q: [[f64; 9]; 2]) {
        let hits = |truth: &[f64; 9], truth_std: Option<&[f64; 9]>| -> [[usize; 9]; 2] {
            std::array::from_fn(|l| {
                std::array::from_fn(|i| {
                    let se = truth_std.map_or(std[i], |t| std[i].hypot(t[i]));
                    usize::from((w.estimate[i] - truth[i]).abs() <= q[l][i] * se)
                })
            })
        };
        let add = |to: &mut [[[usize; 9]; 2]; 4]| {
            for (t, truth) in w.truths.iter().enumerate() {
                let h = hits(truth, (t == 3).then_some(w.truth_std));
                for l in 0..2 {
                    for i in 0..9 {
                        to[t][l][i] += h[l][i];
                    }
                }
            }
        };
        self.n_all += 1;
        add(&mut self.all);
        if !w.usable {
            return;
        }
        self.n_usable += 1;
        add(&mut self.usable);
        if w.right {
            self.n_right += 1;
            add(&mut self.right);
        }
        for i in 0..9 {
            self.z.push((w.estimate[i] - w.truths[0][i]).abs() / std[i]);
            self.log_width.extend(w.white.map(|x| (std[i] / x[i]).ln()));
        }
    }
}

/// A scored trial: its truths, its rows, its movement rows.
struct Scored {
    name: &'static str,
    magnitude: f64,
    /// The trial's truth (rows with an attitude), and from all rows and from the movement rows.
    variants: [[f64; 9]; 3],
    rows: Vec<Row>,
    rate: f64,
    /// Indices into `rows` of the movement rows, in time order.
    movement: Vec<usize>,
}

fn scored(dir: &Path, name: &'static str) -> Result<Scored, String> {
    let rows = read_trial(dir, name)?;
    let clean: Vec<Vec3> = rows.iter().filter(|r| r.attitude).map(|r| r.b).collect();
    let magnitude = median(clean.iter().map(|b| norm(*b)).collect());
    let fit = |readings: &[Vec3]| {
        log_fit::fit_with(readings, magnitude, FitModel::Full, &whole()).map_err(|e| format!("{name}: {e}"))
    };
    let all: Vec<Vec3> = rows.iter().map(|r| r.b).collect();
    let movement: Vec<usize> = (0..rows.len()).filter(|&i| rows[i].movement).collect();
    let moving: Vec<Vec3> = movement.iter().map(|&i| rows[i].b).collect();
    let variants = [
        composed(&fit(&clean)?)?,
        composed(&fit(&all)?)?,
        composed(&fit(&moving)?)?,
    ];
    let dt = median(rows.windows(2).map(|w| w[1].t - w[0].t).collect());
    Ok(Scored {
        name,
        magnitude,
        variants,
        rate: 1.0 / dt,
        rows,
        movement,
    })
}

impl Scored {
    /// The windows of `seconds`, one starting every `1 / starts` of a window: index ranges into
    /// `movement`.
    fn windows(&self, seconds: f64, starts: usize) -> Vec<std::ops::Range<usize>> {
        let n = (seconds * self.rate).round() as usize;
        let step = (n / starts).max(1);
        (0..)
            .map(|k| k * step..k * step + n)
            .take_while(|w| w.end <= self.movement.len())
            .collect()
    }

    /// The rows (indices into `rows`) of the movement rows outside the window `w` (movement
    /// indices), in time order.
    fn outside<'a>(&'a self, w: &'a std::ops::Range<usize>) -> impl Iterator<Item = usize> + 'a {
        self.movement
            .iter()
            .enumerate()
            .filter(|(k, _)| !w.contains(k))
            .map(|(_, &i)| i)
    }

    /// The movement rows' truth without the window `w` (movement indices).
    fn leave_out(&self, w: &std::ops::Range<usize>) -> Result<[f64; 9], String> {
        let kept: Vec<Vec3> = self.outside(w).map(|i| self.rows[i].b).collect();
        let f = log_fit::fit_with(&kept, self.magnitude, FitModel::Full, &whole())
            .map_err(|e| format!("{}: {e}", self.name))?;
        composed(&f)
    }

    /// The movement rows without the window `w`, the imposed sensor on them, fitted as
    /// `calibrate` fits a log in time order (its check by `trials` trials, held-out fits): the
    /// estimate and its standard errors as reported.
    fn leave_out_calibrated(&self, w: &std::ops::Range<usize>, trials: usize) -> Result<([f64; 9], [f64; 9]), String> {
        // The rows before and after the window are two logs joined: their seam is one reading.
        let kept: Vec<Vec3> = self.outside(w).map(|i| impose(self.rows[i].b)).collect();
        let settings = FitSettings {
            order: Order::Time,
            trials,
            ..FitSettings::default()
        };
        let f = log_fit::fit_with(&kept, self.magnitude, FitModel::Full, &settings)
            .map_err(|e| format!("{}: {e}", self.name))?;
        let (Some(p), Some(s), Some(o)) = (f.std_psi_deg, f.std_scale, f.std_bias) else {
            return Err(format!(
                "{}: the fit without a window states no standard errors",
                self.name
            ));
        };
        Ok((nine(f.errors.psi_deg(), f.errors.scale(), f.bias), nine(p, s, o)))
    }
}

fn pct(h: usize, n: usize) -> String {
    if n == 0 {
        "  -  ".into()
    } else {
        format!("{:5.3}", h as f64 / n as f64)
    }
}

fn pooled(h: &[usize; 9], n: usize) -> String {
    pct(h.iter().sum(), 9 * n)
}

/// A table of coverage per parameter, `pick` giving the hits at 95 % and 99 % and the windows.
fn table(
    title: &str,
    keys: &[(String, Source)],
    tallies: &BTreeMap<(String, Source), Tally>,
    level: usize,
    pick: impl Fn(&Tally) -> (&[[usize; 9]; 2], usize),
) {
    println!("\n{title}\n");
    print!("| {:<20} | {:<17} | {:>3} |", "rule", "std", "n");
    for n in NAMES {
        print!(" {n:>5} |");
    }
    println!(" all 9 | all 9 at {} % |", if level == 0 { 99 } else { 95 });
    println!("|{}|", ["---"; 15].join("|"));
    for key in keys {
        let Some(t) = tallies.get(key) else { continue };
        let (h, n) = pick(t);
        print!("| {:<20} | {:<17} | {n:>3} |", key.0, key.1.name());
        for v in h[level] {
            print!(" {} |", pct(v, n));
        }
        println!(" {} | {} |", pooled(&h[level], n), pooled(&h[1 - level], n));
    }
}

/// The coverage of every rule and source, all nine parameters pooled: 95 % / 99 %, against each
/// truth, usable windows and the usable ones at the right solution; the `|z|` quantiles and the
/// width against the white fit's.
fn summary(title: &str, keys: &[(String, Source)], tallies: &BTreeMap<(String, Source), Tally>) {
    println!(
        "\n{title}: 95 % / 99 % coverage against each truth, usable windows and those at the right solution; |z| quantiles against the normal's and width against the white fit's, usable windows\n"
    );
    print!("| {:<20} | {:<17} | n usable | n right |", "rule", "std");
    for t in ["trial", "movement", "leave-out", "two-sample"] {
        print!(" {t} usable | {t} right |");
    }
    println!(" median abs z / 0.674 | 90 % abs z / 1.645 | width x white |");
    println!("|{}|", ["---"; 15].join("|"));
    for key in keys {
        let Some(t) = tallies.get(key) else { continue };
        print!(
            "| {:<20} | {:<17} | {:>3} | {:>3} |",
            key.0,
            key.1.name(),
            t.n_usable,
            t.n_right
        );
        for k in 0..4 {
            print!(
                " {} / {} | {} / {} |",
                pooled(&t.usable[k][0], t.n_usable),
                pooled(&t.usable[k][1], t.n_usable),
                pooled(&t.right[k][0], t.n_right),
                pooled(&t.right[k][1], t.n_right)
            );
        }
        let mut z = t.z.clone();
        z.sort_by(f64::total_cmp);
        let at = |q: f64| {
            z.get(((z.len() as f64 * q) as usize).min(z.len().saturating_sub(1)))
                .copied()
                .unwrap_or(f64::NAN)
        };
        let width = (t.log_width.iter().sum::<f64>() / t.log_width.len().max(1) as f64).exp();
        println!(" {:.2} | {:.2} | {width:.2} |", at(0.5) / 0.6745, at(0.9) / 1.6449);
    }
}

fn run() -> Result<(), String> {
    let started = Instant::now();
    // The repository's root is two folders above this package's.
    let mut dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/broad");
    let mut windows = vec![5.0, 10.0, 20.0, 40.0];
    let mut trials = log_fit::CHECK_TRIALS;
    // Windows start every window (1) or every 1 / starts of one: overlapping windows measure the
    // same coverage with more of them (not independent).
    let mut starts = 1usize;
    let mut rules: Vec<Rule> = [
        "white", "shipped", "andrews1", "andrews2", "andrews4", "fixed0.5", "fixed1", "fixed2", "fixed5", "frac5",
        "frac20",
    ]
    .iter()
    .map(|r| Rule::parse(r))
    .collect::<Result<_, _>>()?;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = |what: &str| args.next().ok_or(format!("{what} needs a value"));
        match a.as_str() {
            "--windows" => {
                windows = value("--windows")?
                    .split(',')
                    .map(|s| s.parse().map_err(|_| format!("--windows: {s}")))
                    .collect::<Result<_, _>>()?
            }
            "--starts" => starts = value("--starts")?.parse().map_err(|_| "--starts: not a number")?,
            "--trials" => trials = value("--trials")?.parse().map_err(|_| "--trials: not a number")?,
            "--rules" => {
                rules = value("--rules")?
                    .split(',')
                    .map(Rule::parse)
                    .collect::<Result<_, _>>()?
            }
            _ if a.starts_with("--") => return Err(format!("unknown option {a}")),
            _ => dir = PathBuf::from(a),
        }
    }
    // The widths are against the white fit's, which comes first.
    rules.retain(|r| *r != Rule::White);
    rules.insert(0, Rule::White);

    println!(
        "# Coverage of log-fit intervals on the BROAD trials ({})\n",
        dir.display()
    );
    println!("## The residuals' correlation on whole trials (full model, time order, real readings)\n");
    println!("Lag-one autocorrelation of the residuals, the batch of Andrews' AR(1) rule (at most m / 10) and of the");
    println!("shipped rule, and under each the long-run standard errors against the white ones, per parameter.\n");
    println!(
        "| trial | rows | rho1 | L Andrews | HAC / white under Andrews: psi1 psi2 psi3 S1 S2 S3 O1 O2 O3 | L shipped | HAC / white shipped |"
    );
    println!("|---|---|---|---|---|---|---|");
    for name in ALL {
        let rows = read_trial(&dir, name)?;
        for (what, readings) in [
            ("all rows", rows.iter().map(|r| r.b).collect::<Vec<_>>()),
            ("movement", rows.iter().filter(|r| r.movement).map(|r| r.b).collect()),
        ] {
            let m = readings.len();
            let magnitude = median(readings.iter().map(|b| norm(*b)).collect());
            let fit =
                |order| log_fit::fit_with(&readings, magnitude, FitModel::Full, &FitSettings { order, ..whole() });
            let ratio = |f: &LogFit| match (f.serial_std, f.white_std) {
                (Some([hp, hs, ho]), Some([wp, ws, wo])) => {
                    let (h, w) = (nine(hp, hs, ho), nine(wp, ws, wo));
                    (0..9)
                        .map(|i| format!("{:.1}", h[i] / w[i]))
                        .collect::<Vec<_>>()
                        .join(" ")
                }
                _ => format!("none: {}", f.verdict.chars().take(90).collect::<String>()),
            };
            let shipped = match fit(Order::Time) {
                Ok(f) => f,
                Err(e) => {
                    println!("| {} {what} | {m} | no fit: {e} | | | | |", &name[..2]);
                    continue;
                }
            };
            let s = shipped.serial.ok_or("no serial")?;
            let rho = s.lag_one.unwrap_or(f64::NAN);
            let l = (andrews(rho, m).ceil() as usize).clamp(1, (m / serial::MIN_BATCHES).max(1));
            let old = fit(Order::Batch(l)).map_err(|e| format!("{name}: {e}"))?;
            println!(
                "| {} {what} | {m} | {rho:.4} | {l} ({:.2} s) | {} | {} ({:.1} s) | {} |",
                &name[..2],
                l as f64 / 285.714,
                ratio(&old),
                s.batch,
                s.batch as f64 / 285.714,
                ratio(&shipped)
            );
        }
    }

    println!("\n## How far the correlation reaches (movement rows, full model, real readings)\n");
    println!("Autocorrelation of the residuals `|P (b - O)| - R` at lags of readings (seconds at 285.7 Hz), and the");
    println!(
        "long-run standard errors with a batch of L readings against the white ones (geometric mean over the nine"
    );
    println!("parameters).\n");
    const LAGS: [usize; 8] = [1, 3, 10, 30, 100, 300, 1000, 3000];
    const BATCHES: [usize; 8] = [1, 10, 33, 100, 300, 1000, 2000, 3000];
    print!("| trial |");
    for l in LAGS {
        print!(" acf {l} ({:.2} s) |", l as f64 / 285.714);
    }
    println!();
    println!("|---|{}", "---|".repeat(LAGS.len()));
    let mut ratios = Vec::new();
    for name in ALL {
        let rows = read_trial(&dir, name)?;
        let readings: Vec<Vec3> = rows.iter().filter(|r| r.movement).map(|r| r.b).collect();
        let magnitude = median(readings.iter().map(|b| norm(*b)).collect());
        let Ok(f) = log_fit::fit_with(&readings, magnitude, FitModel::Full, &whole()) else {
            continue;
        };
        let r: Vec<f64> = readings.iter().map(|b| norm(f.apply(*b)) - f.magnitude).collect();
        let mean = r.iter().sum::<f64>() / r.len() as f64;
        let var: f64 = r.iter().map(|v| (v - mean).powi(2)).sum();
        print!("| {} |", &name[..2]);
        for l in LAGS {
            let c: f64 = r.windows(l + 1).map(|w| (w[0] - mean) * (w[l] - mean)).sum();
            print!(" {:.3} |", c / var);
        }
        println!();
        let mut line = Vec::new();
        for l in BATCHES {
            let settings = FitSettings {
                order: Order::Batch(l),
                ..whole()
            };
            let ratio = log_fit::fit_with(&readings, magnitude, FitModel::Full, &settings)
                .ok()
                .and_then(|f| {
                    let ([hp, hs, ho], [wp, ws, wo]) = (f.serial_std?, f.white_std?);
                    let (h, w) = (nine(hp, hs, ho), nine(wp, ws, wo));
                    Some(((0..9).map(|i| (h[i] / w[i]).ln()).sum::<f64>() / 9.0).exp())
                });
            line.push(ratio.map_or("-".into(), |v| format!("{v:.2}")));
        }
        ratios.push(format!("| {} | {} |", &name[..2], line.join(" | ")));
    }
    print!("\n| trial |");
    for l in BATCHES {
        print!(" L {l} ({:.2} s) |", l as f64 / 285.714);
    }
    println!("\n|---|{}", "---|".repeat(BATCHES.len()));
    for l in &ratios {
        println!("{l}");
    }

    let trials_data: Vec<Scored> = SCORED.iter().map(|n| scored(&dir, n)).collect::<Result<_, _>>()?;
    println!("\n## Truths: the imposed [P1] sensor on each trial's own full calibration\n");
    println!("| trial | magnitude nT | rate Hz | calibration of | psi1 psi2 psi3 (deg) | S1 S2 S3 | O1 O2 O3 (nT) |");
    println!("|---|---|---|---|---|---|---|");
    for s in &trials_data {
        for (what, t) in ["rows with an attitude (the truth)", "all rows", "movement rows"]
            .iter()
            .zip(&s.variants)
        {
            println!(
                "| {} | {:.1} | {:.3} | {what} | {:.4} {:.4} {:.4} | {:.6} {:.6} {:.6} | {:.1} {:.1} {:.1} |",
                &s.name[..2],
                s.magnitude,
                s.rate,
                t[0],
                t[1],
                t[2],
                t[3],
                t[4],
                t[5],
                t[6],
                t[7],
                t[8]
            );
        }
    }
    let detail = std::env::var_os("BROAD_DETAIL").is_some();

    for &w in &windows {
        let t0 = Instant::now();
        let mut tallies: BTreeMap<(String, Source), Tally> = BTreeMap::new();
        let mut shared: BTreeMap<(String, Source), Tally> = BTreeMap::new();
        let mut keys: Vec<(String, Source)> = Vec::new();
        let mut count = Vec::new();
        let mut batches: BTreeMap<String, Vec<f64>> = BTreeMap::new();
        let (mut rhos, mut inflated, mut wrong, mut m) = (Vec::new(), 0usize, 0usize, 0usize);
        for s in &trials_data {
            let ranges = s.windows(w, starts);
            count.push(format!("{} from {}", ranges.len(), &s.name[..2]));
            for range in ranges {
                let readings: Vec<Vec3> = s.movement[range.clone()].iter().map(|&i| impose(s.rows[i].b)).collect();
                m = readings.len();
                let loo = s.leave_out(&range)?;
                let (two, two_std) = s.leave_out_calibrated(&range, trials)?;
                let truths = [&s.variants[0], &s.variants[2], &loo, &two];
                let mut white: Option<[f64; 9]> = None;
                let mut records = Vec::new();
                for &rule in &rules {
                    let Some(r) = fit_window(&readings, s.magnitude, rule, s.rate, trials) else {
                        continue;
                    };
                    if rule == Rule::White {
                        white = r.std.iter().find(|x| x.0 == Source::Reported).map(|x| x.1);
                    }
                    let right = (3..6).all(|i| (r.estimate[i] / s.variants[0][i] - 1.0).abs() <= WRONG_SCALE);
                    if rule == Rule::Shipped {
                        rhos.extend(r.lag_one);
                        inflated += usize::from(r.inflation > 1.0);
                        wrong += usize::from(r.usable && !right);
                        if detail {
                            let rep = r.std.iter().find(|x| x.0 == Source::Reported);
                            let z: Vec<String> = (0..9)
                                .map(|i| {
                                    rep.map_or("-".into(), |x| {
                                        format!(
                                            "{:.1}/{:.1}/{:.2}",
                                            (r.estimate[i] - s.variants[0][i]) / x.1[i],
                                            (r.estimate[i] - s.variants[2][i]) / x.1[i],
                                            x.2[i]
                                        )
                                    })
                                })
                                .collect();
                            println!(
                                "{} {range:?} usable {} L {:?} rho {:.3} inflation {:.2} z [{}] {}",
                                &s.name[..2],
                                r.usable,
                                r.batch,
                                r.lag_one.unwrap_or(f64::NAN),
                                r.inflation,
                                z.join(" "),
                                r.why
                            );
                        }
                    }
                    if let Some(b) = r.batch {
                        batches.entry(rule.name()).or_default().push(b as f64);
                    }
                    records.push((rule, right, r));
                }
                // The windows every rule calls usable: the same windows for every rule.
                let common = records.iter().all(|(_, _, r)| r.usable);
                for (rule, right, r) in &records {
                    for (source, std, q95, q99) in &r.std {
                        // The white fit is scored as it reports; its white std is the same.
                        if *rule == Rule::White && *source != Source::Reported
                            || *rule != Rule::Shipped && *source == Source::WhiteAlone
                        {
                            continue;
                        }
                        let key = (rule.name(), *source);
                        if !keys.contains(&key) {
                            keys.push(key.clone());
                        }
                        for (map, usable) in [(&mut tallies, r.usable), (&mut shared, common)] {
                            let scores = Scores {
                                usable,
                                right: *right,
                                estimate: &r.estimate,
                                truths,
                                truth_std: &two_std,
                                white: white.as_ref(),
                            };
                            map.entry(key.clone()).or_default().add(&scores, std, [*q95, *q99]);
                        }
                    }
                }
            }
        }
        keys.sort_by_key(|k| (rules.iter().position(|r| r.name() == k.0).unwrap_or(usize::MAX), k.1));
        println!(
            "\n## Windows of {w} s ({m} readings): {} ({:.0} s)\n",
            count.join(", "),
            t0.elapsed().as_secs_f64()
        );
        let mut rs = rhos.clone();
        rs.sort_by(f64::total_cmp);
        if !rs.is_empty() {
            println!(
                "- lag-one autocorrelation of the windows' residuals: min {:.3}, median {:.3}, max {:.3}",
                rs[0],
                rs[rs.len() / 2],
                rs[rs.len() - 1]
            );
        }
        println!("- windows whose cost profile widened the standard errors (shipped rule): {inflated}");
        println!(
            "- usable windows at another solution (a scale factor {:.0} % or more off the truth; shipped rule): {wrong}",
            100.0 * WRONG_SCALE
        );
        for (name, b) in &batches {
            println!(
                "- batch under {name}: median {:.0} readings ({:.2} s; m / 10 = {})",
                median(b.clone()),
                median(b.clone()) / trials_data[0].rate,
                m / 10
            );
        }
        table(
            &format!("95 % intervals holding {}, usable windows", TRUTHS[0]),
            &keys,
            &tallies,
            0,
            |t| (&t.usable[0], t.n_usable),
        );
        table(
            &format!("99 % intervals holding {}, usable windows", TRUTHS[0]),
            &keys,
            &tallies,
            1,
            |t| (&t.usable[0], t.n_usable),
        );
        table(
            &format!("95 % intervals holding {}, every window with an interval", TRUTHS[0]),
            &keys,
            &tallies,
            0,
            |t| (&t.all[0], t.n_all),
        );
        table(
            &format!("99 % intervals holding {}, every window with an interval", TRUTHS[0]),
            &keys,
            &tallies,
            1,
            |t| (&t.all[0], t.n_all),
        );
        table(
            &format!("95 % intervals holding {}, usable windows", TRUTHS[1]),
            &keys,
            &tallies,
            0,
            |t| (&t.usable[1], t.n_usable),
        );
        table(
            &format!("95 % intervals holding {}, usable windows", TRUTHS[2]),
            &keys,
            &tallies,
            0,
            |t| (&t.usable[2], t.n_usable),
        );
        table(
            &format!("95 % intervals holding {}, usable windows", TRUTHS[3]),
            &keys,
            &tallies,
            0,
            |t| (&t.usable[3], t.n_usable),
        );
        summary(
            "Summary, all nine parameters pooled, each rule's usable windows",
            &keys,
            &tallies,
        );
        summary(
            "Summary, all nine parameters pooled, the windows usable under every rule",
            &keys,
            &shared,
        );
    }
    println!(
        "\nrun time {:.0} s (check trials {trials})",
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("broad_coverage: {e}");
            ExitCode::FAILURE
        }
    }
}
