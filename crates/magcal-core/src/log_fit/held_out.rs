//! Held-out evidence of a log fit (docs/conventions.md "Held out"): the log is cut into
//! [`HELD_OUT_FOLDS`] folds, each fitted without one, and the spread of those fits is set against
//! what the standard errors predict for it. The fit cannot vouch for itself here: every
//! leave-out fit stands on readings the fold it left out did not give it.
//!
//! - **Folds.** A log in time order ([`Order::Time`], [`Order::Batch`]) is cut into consecutive
//!   blocks, so that a fold carries the residuals' correlation, the drift and the field that
//!   changes with place as they came; a log without times into folds of readings drawn at random
//!   (stream `[0xFFF7]` of the check's seed): its readings are exchangeable as far as the fit
//!   knows, and blocks of rows would leave out whole attitudes of a designed plan.
//! - **What is predicted.** Leave fold `k` out: the estimate moves by `d_k = theta_-k - theta`,
//!   whose variance under the model is `std_-k^2 - std^2` (the fit without the fold is the less
//!   informed of two nested fits). Where a fold holds attitudes no other fold has (a plan flown
//!   attitude by attitude) both are large, and nothing is amiss.
//! - **The ratio.** Per parameter, `r_i = sum_k d_ki^2 / sum_k (std_-k,i^2 - std_i^2)`, and its
//!   median over the parameters. Under the model it is near 1; above [`HELD_OUT_RATIO`] the
//!   held-out fits move more than the standard errors allow, and the standard errors are widened
//!   by what was seen: each at least the block jackknife's, `sqrt((K - 1) / K sum_k (theta_-k -
//!   mean)^2)`, taken with Student's `t` of `K - 1` degrees of freedom, and at least `sqrt(r_i)`
//!   times its own.
//! - **The magnitude held out.** Each fold's readings under the fit without them: the rms of
//!   `|P_-k (s - O_-k)| - R` against that of the whole fit's residuals.
//! - A fold without which the fit does not determine the calibration gives no spread; with
//!   fewer than [`MIN_DETERMINED`] folds that do, the log holds no held-out evidence, and is not
//!   usable for that reason.

use rand::seq::SliceRandom;

use super::{FitModel, FitSettings, LogFit, Order, fit_unit, significant};
use crate::rng::{stream_id, stream_rng};
use crate::small::{Vec3, norm};

/// Folds of a log's held-out fits.
pub const HELD_OUT_FOLDS: usize = 5;

/// The median over the parameters of `(jackknife std / std)^2` above which the standard errors of
/// a log in time order are widened: any excess. Their long-run covariance rests on a dozen
/// batches and cannot see a drift slower than a tenth of the log, so the larger of it and the
/// held-out spread is the one to use, as the larger of it and white noise's already is.
pub const HELD_OUT_RATIO: f64 = 1.0;

/// The same for a log without times: its readings are exchangeable as far as the fit knows, and
/// its standard errors are widened only where the held-out spread exceeds them clearly (on logs
/// of one sensor in white noise the median ratio is 0.8 to 0.9 and exceeds 2 in 0 to 3 % of
/// logs of 300 readings or more; examples/held_out_gate.rs).
pub const HELD_OUT_RATIO_SHUFFLED: f64 = 2.0;

/// Folds that must determine the calibration without the readings they hold out.
pub const MIN_DETERMINED: usize = 3;

/// How the folds were cut.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FoldKind {
    /// Consecutive blocks of a log in time order.
    Blocks,
    /// Readings drawn at random, for a log without times.
    Shuffled,
}

impl FoldKind {
    /// In words.
    pub fn words(&self) -> &'static str {
        match self {
            Self::Blocks => "consecutive blocks of the log",
            Self::Shuffled => "readings drawn at random (the log has no times)",
        }
    }
}

/// The fits without each of `folds` folds.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Scale {
    /// Folds cut.
    pub folds: usize,
    /// Folds whose leave-out fit determined the calibration.
    pub determined: usize,
    /// The readings (first and last index) of each fold without which the fit did not determine
    /// the calibration.
    pub not_determined: Vec<[usize; 2]>,
    /// Per parameter `psi`, `S`, `O`: `(jackknife std / std)^2` (`None` for a parameter the model
    /// fixes); `None` with fewer than [`MIN_DETERMINED`] folds determined.
    pub ratios: Option<[[Option<f64>; 3]; 3]>,
    /// Their median over the model's parameters.
    pub ratio: Option<f64>,
    /// The block jackknife's standard errors of `psi` (degrees), `S`, `O` (the log's units),
    /// `sqrt((K - 1) / K sum_k (theta_-k - mean)^2)` over the `K` folds determined.
    pub jackknife_std: Option<[Vec3; 3]>,
    /// Student's `t` at 97.5 % of the jackknife's `K - 1` degrees of freedom.
    pub jackknife_quantile95: Option<f64>,
    /// Sum of squares of `|b| - R` of the readings held out under the fits without them, and
    /// their count.
    #[serde(skip)]
    held: (f64, usize),
}

/// The held-out evidence of a fit (see the module documentation).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct HeldOut {
    /// How the folds were cut.
    pub kind: FoldKind,
    /// The cuts ([`HELD_OUT_FOLDS`] folds); none for a
    /// log too small to hold a fold out.
    pub scales: Vec<Scale>,
    /// Whether the standard errors were widened: the median ratio of a cut that gives evidence
    /// above [`HELD_OUT_RATIO`].
    pub widened: bool,
    /// The rms of `|b| - R` of the readings held out under the fits without them (the finest cut
    /// that gives evidence), and of every reading under the whole fit (the log's units).
    pub magnitude_rms: Option<[f64; 2]>,
}

impl HeldOut {
    /// Whether the held-out fits give evidence at all: the finest cut has [`MIN_DETERMINED`]
    /// folds that determine the calibration.
    pub fn evidence(&self) -> bool {
        self.scales.first().is_some_and(|s| s.ratios.is_some())
    }

    /// The multiple of a standard error the held-out fits raised that makes its 95 % interval:
    /// Student's `t` of the jackknife's degrees of freedom (the largest over the cuts).
    pub fn quantile95(&self) -> Option<f64> {
        self.scales
            .iter()
            .filter_map(|s| s.jackknife_quantile95)
            .reduce(f64::max)
    }

    /// The largest median ratio of the cuts that give evidence.
    pub fn ratio(&self) -> Option<f64> {
        self.scales.iter().filter_map(|s| s.ratio).reduce(f64::max)
    }

    /// In words, for the verdict.
    pub fn words(&self) -> String {
        if self.scales.is_empty() {
            return "too few readings to hold a fold out (a fifth of the log held out must leave at least twice the model's parameters); fit a longer log".to_string();
        }
        let cuts: Vec<String> = self
            .scales
            .iter()
            .map(|s| format!("{} of {}", s.determined, s.folds))
            .collect();
        let mut w = format!(
            "{} folds ({}) determine the calibration without the readings they hold out",
            cuts.join(" and "),
            self.kind.words()
        );
        if let Some(r) = self.ratio() {
            w.push_str(&format!(
                "; the fits without a fold spread {} times as far as the standard errors say (median over the parameters){}",
                significant(r.sqrt(), 3),
                if self.widened {
                    ": the standard errors are widened to the spread"
                } else {
                    ""
                }
            ));
        }
        if let Some([held, whole]) = self.magnitude_rms {
            w.push_str(&format!(
                "; the readings held out lie {} from the field (rms), the fitted ones {}",
                significant(held, 4),
                significant(whole, 4)
            ));
        }
        w
    }

    /// The evidence of a log too small to hold a fold out: none.
    pub(super) fn too_few() -> Self {
        Self {
            kind: FoldKind::Shuffled,
            scales: Vec::new(),
            widened: false,
            magnitude_rms: None,
        }
    }

    /// Scaled into the log's units: the jackknife's standard errors of `S` and `O` by `by`; the
    /// magnitudes `|b| - R` are the field's, which the frame does not change.
    pub(super) fn scaled(mut self, by: f64) -> Self {
        for s in &mut self.scales {
            s.jackknife_std = s
                .jackknife_std
                .map(|[p, s, o]| [p, s.map(|v| v * by), o.map(|v| v * by)]);
        }
        self
    }

    /// At a field magnitude `f` times the old: the scale factors' standard errors by `1 / f`, the
    /// magnitudes `|b| - R` by `f`.
    pub(super) fn at_magnitude(mut self, f: f64) -> Self {
        for s in &mut self.scales {
            s.jackknife_std = s.jackknife_std.map(|[p, s, o]| [p, s.map(|v| v / f), o]);
            s.held.0 *= f * f;
        }
        self.magnitude_rms = self.magnitude_rms.map(|m| m.map(|v| v * f));
        self
    }
}

/// The nine parameters of a fit and their standard errors, `None` where unknown.
fn parameters(f: &LogFit) -> Option<([f64; 9], [f64; 9])> {
    let (p, s, o) = (f.std_psi_deg?, f.std_scale?, f.std_bias?);
    let e = [f.errors.psi_deg(), f.errors.scale(), f.bias];
    Some((
        std::array::from_fn(|i| e[i / 3][i % 3]),
        [p[0], p[1], p[2], s[0], s[1], s[2], o[0], o[1], o[2]],
    ))
}

fn three(v: [f64; 9]) -> [Vec3; 3] {
    std::array::from_fn(|g| std::array::from_fn(|i| v[3 * g + i]))
}

/// `k` folds of the readings in the order `order`: each a sorted list of indices.
fn folds(order: &[usize], k: usize) -> Vec<Vec<usize>> {
    let m = order.len();
    (0..k)
        .map(|f| {
            let mut v = order[f * m / k..(f + 1) * m / k].to_vec();
            v.sort_unstable();
            v
        })
        .collect()
}

/// The cuts of `m` readings for held-out fits (see the module documentation): for a log in time
/// order consecutive blocks, fifths of it; without times a fifth of the readings each,
/// drawn on stream `[0xFFF7]` of `seed`. Each cut is a list of folds, each fold the sorted
/// indices of the readings it holds out.
pub fn cut(m: usize, order: Order, seed: u64) -> (FoldKind, Vec<Vec<Vec<usize>>>) {
    match order {
        Order::Time | Order::Batch(_) => {
            let order: Vec<usize> = (0..m).collect();
            (FoldKind::Blocks, vec![folds(&order, HELD_OUT_FOLDS)])
        }
        Order::Unknown => {
            let mut order: Vec<usize> = (0..m).collect();
            order.shuffle(&mut stream_rng(seed, stream_id(&[0xFFF7])));
            (FoldKind::Shuffled, vec![folds(&order, HELD_OUT_FOLDS)])
        }
    }
}

/// What a fit without one fold gave: its nine parameters `psi` (degrees), `S`, `O`, and the sum
/// of squares of `|b| - R` of the readings it held out (the field's units).
pub type FoldFit = ([f64; 9], f64);

/// The held-out evidence of a fit whose standard errors are `std` (nine, `psi`, `S`, `O`; `psi`
/// fixed by the model where `fixed_psi`), from the fits without each fold of `cuts` (`fits[c][k]`
/// for fold `k` of cut `c`, `None` where the fit without it did not determine the calibration),
/// and the rms of `|b| - R` of every reading under the whole fit.
pub fn assemble(
    kind: FoldKind,
    cuts: &[Vec<Vec<usize>>],
    fits: &[Vec<Option<FoldFit>>],
    std: &[f64; 9],
    fixed_psi: bool,
    whole_rms: f64,
) -> HeldOut {
    let scales: Vec<Scale> = cuts
        .iter()
        .zip(fits)
        .map(|(folds, fits)| scale(folds, fits, std, fixed_psi))
        .collect();
    let magnitude_rms = scales
        .iter()
        .find(|s| s.ratios.is_some())
        .map(|s| [(s.held.0 / s.held.1 as f64).sqrt(), whole_rms]);
    let gate = match kind {
        FoldKind::Blocks => HELD_OUT_RATIO,
        FoldKind::Shuffled => HELD_OUT_RATIO_SHUFFLED,
    };
    let widened = scales.iter().filter_map(|s| s.ratio).any(|r| r > gate);
    HeldOut {
        kind,
        scales,
        widened,
        magnitude_rms,
    }
}

/// The fewest readings a log needs for held-out evidence under `model`: with a fifth held out,
/// twice the model's parameters kept (23 for the full model).
pub fn min_readings(model: FitModel) -> usize {
    (1..)
        .find(|&m: &usize| m - m.div_ceil(HELD_OUT_FOLDS) >= 2 * model.parameters())
        .unwrap_or(usize::MAX)
}

/// The held-out evidence of `f`, the fit of `u` (in the fit's frame) under `settings`; `None`
/// where the log is too small to hold a fold out (each kept set needs twice the parameters).
pub(super) fn run(u: &[Vec3], f: &LogFit, settings: &FitSettings) -> Option<HeldOut> {
    use rayon::prelude::*;
    let m = u.len();
    if m < min_readings(f.model) {
        return None;
    }
    // The standard errors as they stand (the check's floor included) are what the held-out
    // spread is set against.
    let (_, std) = parameters(f)?;
    let quick = FitSettings {
        trials: 0,
        profile: false,
        held_out: false,
        ..settings.clone()
    };
    let (kind, cuts) = cut(m, settings.order, settings.seed);
    let fits: Vec<Vec<Option<FoldFit>>> = cuts
        .iter()
        .map(|folds| {
            folds
                .par_iter()
                .map(|fold| {
                    let mut keep = vec![true; m];
                    fold.iter().for_each(|&i| keep[i] = false);
                    let kept: Vec<Vec3> = (0..m).filter(|&i| keep[i]).map(|i| u[i]).collect();
                    let g = fit_unit(&kept, f.model, &quick).ok()?;
                    if !g.identifiable || g.status != crate::calibration::CalibrationStatus::Ok {
                        return None;
                    }
                    let (e, _) = parameters(&g)?;
                    // The held-out readings' distances from the field under the fit without them.
                    let held: f64 = fold.iter().map(|&i| (norm(g.apply(u[i])) - g.magnitude).powi(2)).sum();
                    Some((e, held))
                })
                .collect()
        })
        .collect();
    let whole_rms = (u.iter().map(|&s| (norm(f.apply(s)) - f.magnitude).powi(2)).sum::<f64>() / m as f64).sqrt();
    Some(assemble(kind, &cuts, &fits, &std, f.model != FitModel::Full, whole_rms))
}

/// The spread of the fits without each of `folds` (`fits`), against `std`.
fn scale(folds: &[Vec<usize>], fits: &[Option<FoldFit>], std: &[f64; 9], fixed_psi: bool) -> Scale {
    let fixed = |i: usize| i < 3 && fixed_psi;
    let not_determined = folds
        .iter()
        .zip(fits)
        .filter(|(_, g)| g.is_none())
        .map(|(fold, _)| [fold[0], fold[fold.len() - 1]])
        .collect();
    let good: Vec<&FoldFit> = fits.iter().flatten().collect();
    let held = (
        good.iter().map(|g| g.1).sum(),
        folds
            .iter()
            .zip(fits)
            .filter(|(_, g)| g.is_some())
            .map(|(f, _)| f.len())
            .sum(),
    );
    let mut out = Scale {
        folds: folds.len(),
        determined: good.len(),
        not_determined,
        ratios: None,
        ratio: None,
        jackknife_std: None,
        jackknife_quantile95: None,
        held,
    };
    if good.len() < MIN_DETERMINED {
        return out;
    }
    let n = good.len() as f64;
    let mean: [f64; 9] = std::array::from_fn(|i| good.iter().map(|g| g.0[i]).sum::<f64>() / n);
    let jackknife: [f64; 9] = std::array::from_fn(|i| {
        if fixed(i) {
            0.0
        } else {
            ((n - 1.0) / n * good.iter().map(|g| (g.0[i] - mean[i]).powi(2)).sum::<f64>()).sqrt()
        }
    });
    let ratios: [f64; 9] = std::array::from_fn(|i| {
        if fixed(i) || std[i] == 0.0 {
            f64::NAN
        } else {
            (jackknife[i] / std[i]).powi(2)
        }
    });
    let mut finite: Vec<f64> = ratios.iter().copied().filter(|r| r.is_finite()).collect();
    let ratio = crate::budget::quantile(&mut finite, 0.5);
    out.ratios = Some(std::array::from_fn(|g| {
        std::array::from_fn(|i| Some(ratios[3 * g + i]).filter(|r| r.is_finite()))
    }));
    out.ratio = ratio.is_finite().then_some(ratio);
    out.jackknife_std = Some(three(jackknife));
    out.jackknife_quantile95 = Some(super::student_quantile(0.975, good.len() - 1));
    out
}

/// Widens the standard errors `std` (`psi`, `S`, `O`; `psi` left where `fixed_psi`) to the
/// jackknife's of every cut of `h` that gives evidence, and each to its own times the square
/// root of the cut's median ratio, where `h` says so (see the module documentation); returns
/// which were raised. Their intervals take [`HeldOut::quantile95`].
pub fn widen_std(std: [&mut Option<Vec3>; 3], fixed_psi: bool, h: &HeldOut) -> [[bool; 3]; 3] {
    let mut raised = [[false; 3]; 3];
    if !h.widened {
        return raised;
    }
    for (g, v) in std.into_iter().enumerate() {
        if g == 0 && fixed_psi {
            continue;
        }
        let Some(v) = v.as_mut() else {
            continue;
        };
        // Every cut is set against the standard errors as they stood before any was applied.
        let own = *v;
        for s in &h.scales {
            let (Some(jk), Some(ratio)) = (s.jackknife_std, s.ratio) else {
                continue;
            };
            // The cut's median ratio rests on every parameter's spread at once: a parameter
            // whose own spread came out small by chance is widened by it too.
            let pooled = ratio.max(1.0).sqrt();
            for i in 0..3 {
                let wider = jk[g][i].max(own[i] * pooled);
                if wider.is_finite() && wider > v[i] {
                    v[i] = wider;
                    raised[g][i] = true;
                }
            }
        }
    }
    raised
}

/// [`widen_std`] of a log fit.
pub(super) fn widen(f: &mut LogFit, h: &HeldOut) -> [[bool; 3]; 3] {
    let fixed = f.model != FitModel::Full;
    widen_std([&mut f.std_psi_deg, &mut f.std_scale, &mut f.std_bias], fixed, h)
}
