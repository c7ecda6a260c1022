//! A field that is not one field: where, within a log, the field that a calibration maps the
//! readings to changes over time, as a magnet put on the board or taken off changes it
//! (docs/conventions.md "One field").
//!
//! A log fit assumes one sensor in one uniform field: under a calibration that holds, the
//! calibrated field `b_t = P (s_t - O)` has the field's magnitude but for noise and what the
//! model leaves out. A magnet fixed to the board adds a hard iron `d` while it is there: under a
//! calibration of the readings without it, `|b_t + d| / R - 1 ~ u_t . d / R` with `u_t = b_t /
//! |b_t|`, a change of the magnitude that follows the attitude (a step of the level where the
//! attitudes change little, a wider spread where they turn). A calibration fitted to the whole
//! log takes part of the magnet into its bias and its scale factors, so the readings with the
//! magnet and those without both stray with the attitude; what tells them apart is that each
//! keeps its own calibration error.
//!
//! # Method
//! - **The model of a window.** The relative magnitude `rho_t = |b_t| / R - 1` (`R` the median
//!   of `|b_t|`) is regressed on `h_t = (1, u, u_x^2 - u_z^2, u_y^2 - u_z^2, u_x u_y, u_x u_z,
//!   u_y u_z)` at `u = u_t`: to first order the magnitude's change under a small error of the
//!   calibration, a level, a hard iron (3) and the traceless part of a soft iron (5), nine
//!   unknowns `theta`. A ridge `RIDGE n |theta_(2..9)|^2` gives a window of one attitude (a rest)
//!   its level alone. Readings go in blocks of `block_s` seconds (default 1; longer where the log
//!   would have more than `max_blocks`), each holding `sum h h^T`, `sum h rho`, `sum rho^2` and
//!   its count: any window of whole blocks is fitted from prefix sums.
//! - **The search** (circular binary segmentation, Olshen et al. 2004): in each piece, every
//!   window of whole blocks against the rest of the piece (a window at an end of the piece is one
//!   change, one inside it a change and a change back). The window's fit `theta_in` and the
//!   rest's `theta_out` differ by `delta`; the **step** is the rms over the piece's readings of
//!   the change of magnitude that `delta` makes, `sqrt(delta^T (sum h h^T) delta / n)`, a fraction
//!   of `R`; the **z** is `sqrt((RSS_piece - RSS_in - RSS_out) / s^2)`, the drop of the residual
//!   sum of squares that the cut buys against the long-run variance `s^2` of a reading (for white
//!   noise the root of a chi-square of 9 degrees of freedom). A window is a change when its step
//!   is at least `min_step` (default [`FIELD_CHANGE_STEP`]) **and** its z at least `z` (default
//!   [`FIELD_CHANGE_Z`]), every piece it leaves lasting at least `min_part_s` (default 5 s). The
//!   window of largest z is cut first, and the search repeats in the pieces.
//! - **The long-run variance.** Real residuals are correlated in time (the attitude moves slowly,
//!   and the field's departures from the model with it), so the scatter of single readings
//!   understates what a window's fit can wander by. Each batch of `batch_blocks` blocks (default
//!   30 s) is fitted alone; its blocks' residual sums, scaled by the root of their counts, give
//!   the Bartlett (Newey-West) estimate over 5 lags of blocks, corrected for the nine unknowns.
//!   `s^2` is the median over the batches, so that a batch that straddles a change does not
//!   inflate it, nor a calibration wrong for the whole log (each batch has its own fit). The
//!   batch's own fit takes some of the slow noise with it: the thresholds are set on
//!   simulations (see [`FIELD_CHANGE_Z`]) rather than on the chi-square.
//!
//! # Why both thresholds
//! Every real log holds changes that are significant and harmless: the rest phases of a BROAD
//! trial sit in another spot of the room than the motion between them, and the calibrated field
//! differs there by about 1 %; with 50,000 readings a test alone calls that a change. The step
//! says how large a change must be to matter ([`FIELD_CHANGE_STEP`]), the z how sure it must be
//! ([`FIELD_CHANGE_Z`]); the numbers measured are in their docs. A step alone would not do
//! either: a window's fit of nine unknowns over a few seconds of correlated noise wanders by
//! several percent (up to 5.9 % in simulated logs of 1 % noise).
//!
//! # Parts
//! The longest piece is the reference. A piece whose readings, under the reference's fit instead
//! of their own, change by less than `min_step` (rms) is in the reference field
//! ([`Segment::in_field`]); neighbouring pieces alike in that are one part
//! ([`FieldChange::parts`]).
// Index loops mirror the matrix algebra they implement.
#![allow(clippy::needless_range_loop)]

use crate::metrics::median;
use crate::small::{Vec3, cholesky_in_place, cholesky_solve, norm};

/// The smallest change that counts: 5 % of the magnitude, rms over the readings of the piece
/// searched. Measured, the largest step of any window of 5 s or more whatever its z, under the
/// full fit of the whole log: BROAD 02 2.1 %, 05 2.8 %, 30 (a magnet fixed in the room) 2.5 %;
/// of the windows with `z >= 15`, 1.6 % in 02 and none in the others. A magnet attached to the
/// board (BROAD 33): 46.7 %. A magnet `d` changes the field by `|d| / sqrt(3)` rms where the
/// board turns all round, by up to `|d|` where it keeps one attitude: 5 % is a magnet of a
/// twentieth to a tenth of the field.
pub const FIELD_CHANGE_STEP: f64 = 0.05;

/// The z a change needs (see [`field_segments`]): 15. Measured, the largest z over 200
/// simulated logs of one field each (170 s at 285.7 Hz, at rest for the first and last 30 s,
/// AR(1) noise of 1 %): 12.8, 14.4 and 19.3 with correlation times of 0.1, 1 and 3 s (99th
/// percentiles 11.5, 13.8 and 18.5; the test `null_z_distribution`); BROAD under the full fits
/// of the whole trials: 02 15.5, 05 5.1, 30 8.7; BROAD 33's magnet 87. With the step, 200 such
/// logs change in none at 1 % noise (correlation 3 s) and at 3 % (1 s), in 6 at 3 % (3 s) and 9
/// at 5 % (3 s); of 40 logs with a change from 60 to 110 s in 2 % noise correlated over 1 s, a
/// level 8 % higher is found in 38, a magnet of 0.2 R turning with the board in 40, one of
/// 0.1 R in 38 (`operating_points`).
pub const FIELD_CHANGE_Z: f64 = 15.0;

/// The ridge on the hard iron of a window, per reading (`RIDGE n |c|^2`): against the `n / 3`
/// that readings all round the sphere give each component, a shrink of 3 %.
const RIDGE: f64 = 0.01;

/// Unknowns of a window's fit: level and hard iron.
const P: usize = 9;

/// Settings of [`field_segments`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldChangeSettings {
    /// Block length, seconds (default 1); longer where the log would have more than
    /// `max_blocks`.
    pub block_s: f64,
    /// At most this many blocks (default 1000): the search costs the square of their number.
    pub max_blocks: usize,
    /// Blocks per batch of the long-run variance (default 30).
    pub batch_blocks: usize,
    /// The shortest piece, seconds (default 5).
    pub min_part_s: f64,
    /// The smallest change, fraction of the magnitude (default [`FIELD_CHANGE_STEP`]).
    pub min_step: f64,
    /// The z a change needs (default [`FIELD_CHANGE_Z`]).
    pub z: f64,
    /// At most this many pieces (default 16).
    pub max_pieces: usize,
}

impl Default for FieldChangeSettings {
    fn default() -> Self {
        FieldChangeSettings {
            block_s: 1.0,
            max_blocks: 1000,
            batch_blocks: 30,
            min_part_s: 5.0,
            min_step: FIELD_CHANGE_STEP,
            z: FIELD_CHANGE_Z,
            max_pieces: 16,
        }
    }
}

/// Why a log was not searched.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FieldChangeError {
    /// A setting out of its range.
    #[error("{name} = {}: {why}", crate::error::show(*.value))]
    InvalidSetting {
        /// The setting.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What it must be.
        why: &'static str,
    },
    /// A time or field that is not finite, a zero field, or a time before the one before it.
    #[error("reading {index}: {why}")]
    BadReading {
        /// 0-based index of the reading.
        index: usize,
        /// What is wrong.
        why: &'static str,
    },
    /// Too few blocks for the long-run variance and two pieces.
    #[error(
        "{span_s:.1} s in {blocks} blocks of {block_s} s: too short to tell a change of the field (needs {needed} blocks and two pieces of {min_part_s} s)"
    )]
    TooShort {
        /// The log's span, seconds.
        span_s: f64,
        /// Blocks it has.
        blocks: usize,
        /// Their length, seconds.
        block_s: f64,
        /// Blocks needed.
        needed: usize,
        /// The shortest piece, seconds.
        min_part_s: f64,
    },
}

/// One piece of a log between changes of the field.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct Segment {
    /// Time of its first reading, seconds.
    pub from_s: f64,
    /// Time of its last reading, seconds.
    pub to_s: f64,
    /// Index of its first reading.
    pub first: usize,
    /// Its readings.
    pub readings: usize,
    /// The median magnitude of its readings, the units of the fields given.
    pub magnitude: f64,
    /// The rms change of its readings' magnitude under the reference piece's fit instead of its
    /// own, a fraction of the magnitude (0 for the reference).
    pub change: f64,
    /// In the field of the reference piece (the longest): `change < min_step`.
    pub in_field: bool,
}

/// A window tested: the strongest of a search.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Candidate {
    /// Start, seconds.
    pub from_s: f64,
    /// End, seconds.
    pub to_s: f64,
    /// Its z.
    pub z: f64,
    /// Its step, a fraction of the magnitude.
    pub step: f64,
}

/// What [`field_segments`] found.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct FieldChange {
    /// The pieces in time order; one piece: no change found.
    pub segments: Vec<Segment>,
    /// The median of all magnitudes, the units of the fields given (the `R` of the search).
    pub magnitude: f64,
    /// Blocks searched.
    pub blocks: usize,
    /// Block length, seconds.
    pub block_s: f64,
    /// The long-run standard deviation of a reading's relative magnitude (`s`).
    pub long_run_sd: f64,
    /// The windows cut, in the order cut.
    pub cuts: Vec<Candidate>,
    /// Of the windows not cut in the last round: the one of largest z whatever its step.
    pub largest_z: Option<Candidate>,
    /// And the one of largest step among those of z at least the threshold.
    pub largest_step: Option<Candidate>,
}

impl FieldChange {
    /// Whether the field changes within the log.
    pub fn changed(&self) -> bool {
        self.segments.len() > 1
    }

    /// Neighbouring segments alike in [`Segment::in_field`] merged: `(first segment, last
    /// segment)` index pairs, in time order.
    pub fn parts(&self) -> Vec<(usize, usize)> {
        let mut parts: Vec<(usize, usize)> = Vec::new();
        for (i, s) in self.segments.iter().enumerate() {
            match parts.last_mut() {
                Some(p) if self.segments[p.1].in_field == s.in_field => p.1 = i,
                _ => parts.push((i, i)),
            }
        }
        parts
    }

    /// The index of the longest segment (by time).
    pub fn longest(&self) -> usize {
        longest(&self.segments)
    }
}

fn longest(segments: &[Segment]) -> usize {
    segments
        .iter()
        .enumerate()
        .max_by(|a, b| (a.1.to_s - a.1.from_s).total_cmp(&(b.1.to_s - b.1.from_s)))
        .map_or(0, |(i, _)| i)
}

/// The sums of a window's regression: count, `sum h h^T`, `sum h rho`, `sum rho^2`.
#[derive(Debug, Clone, Copy, Default)]
struct Sums {
    n: f64,
    hh: [[f64; P]; P],
    hr: [f64; P],
    rr: f64,
}

impl Sums {
    fn add(&mut self, h: [f64; P], rho: f64) {
        self.n += 1.0;
        for i in 0..P {
            self.hr[i] += h[i] * rho;
            for j in 0..P {
                self.hh[i][j] += h[i] * h[j];
            }
        }
        self.rr += rho * rho;
    }

    /// `self - other`, `self + other` by `sign`.
    fn combine(&self, other: &Sums, sign: f64) -> Sums {
        let mut out = *self;
        out.n += sign * other.n;
        out.rr += sign * other.rr;
        for i in 0..P {
            out.hr[i] += sign * other.hr[i];
            for j in 0..P {
                out.hh[i][j] += sign * other.hh[i][j];
            }
        }
        out
    }

    /// The ridge fit `theta` and its residual sum of squares (at least 0).
    fn fit(&self) -> ([f64; P], f64) {
        let mut a = self.hh;
        for i in 1..P {
            a[i][i] += RIDGE * self.n;
        }
        if !cholesky_in_place(&mut a) {
            return ([0.0; P], self.rr.max(0.0));
        }
        let theta = cholesky_solve(&a, &self.hr);
        (theta, self.rss(&theta))
    }

    /// `sum (rho - h . theta)^2`.
    fn rss(&self, theta: &[f64; P]) -> f64 {
        let mut q = self.rr;
        for i in 0..P {
            q -= 2.0 * theta[i] * self.hr[i];
            for j in 0..P {
                q += theta[i] * self.hh[i][j] * theta[j];
            }
        }
        q.max(0.0)
    }

    /// The rms over these readings of `h . delta`.
    fn rms_of(&self, delta: &[f64; P]) -> f64 {
        let mut q = 0.0;
        for i in 0..P {
            for j in 0..P {
                q += delta[i] * self.hh[i][j] * delta[j];
            }
        }
        (q.max(0.0) / self.n).sqrt()
    }
}

/// One block: its readings and their sums.
#[derive(Debug, Clone, Copy)]
struct Block {
    first: usize,
    end: usize,
    from_s: f64,
    to_s: f64,
    sums: Sums,
}

/// The pieces of a log of one field each: `times` (seconds, non-decreasing) and the calibrated
/// fields `fields` of the readings (any units), searched as the module says.
///
/// # Errors
/// A setting out of range, a time or field not finite, a zero field, a time before the one before
/// it; a log too short for the search ([`FieldChangeError::TooShort`]).
///
/// # Panics
/// `times` and `fields` of different lengths.
#[track_caller]
pub fn field_segments(
    times: &[f64],
    fields: &[Vec3],
    settings: &FieldChangeSettings,
) -> Result<FieldChange, FieldChangeError> {
    assert_eq!(times.len(), fields.len(), "one time per field");
    check_settings(settings)?;
    let magnitudes: Vec<f64> = fields.iter().map(|b| norm(*b)).collect();
    check_readings(times, &magnitudes)?;
    let r = median(&magnitudes);
    let span = times.last().map_or(0.0, |l| l - times[0]);
    let block_s = settings.block_s.max(span / settings.max_blocks as f64);
    let blocks = blocks(times, fields, &magnitudes, r, block_s);
    let needed = 3 * settings.batch_blocks;
    if blocks.len() < needed || span < 2.0 * settings.min_part_s {
        return Err(FieldChangeError::TooShort {
            span_s: span,
            blocks: blocks.len(),
            block_s,
            needed,
            min_part_s: settings.min_part_s,
        });
    }
    let mut prefix = vec![Sums::default()];
    for b in &blocks {
        prefix.push(prefix[prefix.len() - 1].combine(&b.sums, 1.0));
    }
    let search = Search {
        blocks: &blocks,
        prefix,
        variance: long_run_variance(&blocks, settings.batch_blocks),
        settings,
    };
    let mut cuts = vec![0, blocks.len()];
    let mut cut = Vec::new();
    let (largest_z, largest_step) = loop {
        let mut best: Option<(Candidate, usize, usize)> = None;
        let mut largest_z: Option<Candidate> = None;
        let mut largest_step: Option<Candidate> = None;
        for w in cuts.windows(2) {
            let found = search.piece(w[0], w[1]);
            if let Some((c, i, j)) = found.cut
                && best.is_none_or(|b| c.z > b.0.z)
            {
                best = Some((c, i, j));
            }
            largest_z = stronger(largest_z, found.largest_z, |c| c.z);
            largest_step = stronger(largest_step, found.largest_step, |c| c.step);
        }
        match best {
            Some((c, i, j)) if cuts.len() - 1 < settings.max_pieces => {
                cut.push(c);
                cuts.extend([i, j]);
                cuts.sort_unstable();
                cuts.dedup();
            }
            _ => break (largest_z, largest_step),
        }
    };
    Ok(FieldChange {
        segments: search.segments(&cuts, &magnitudes),
        magnitude: r,
        blocks: blocks.len(),
        block_s,
        long_run_sd: search.variance.sqrt(),
        cuts: cut,
        largest_z,
        largest_step,
    })
}

fn check_settings(s: &FieldChangeSettings) -> Result<(), FieldChangeError> {
    let positive = [
        ("block_s", s.block_s),
        ("min_part_s", s.min_part_s),
        ("min_step", s.min_step),
        ("z", s.z),
    ];
    for (name, value) in positive {
        if !(value.is_finite() && value > 0.0) {
            return Err(FieldChangeError::InvalidSetting {
                name,
                value,
                why: "must be positive and finite",
            });
        }
    }
    let counts = [
        ("max_blocks", s.max_blocks, 2),
        ("batch_blocks", s.batch_blocks, 1),
        ("max_pieces", s.max_pieces, 1),
    ];
    for (name, value, least) in counts {
        if value < least {
            return Err(FieldChangeError::InvalidSetting {
                name,
                value: value as f64,
                why: "too small",
            });
        }
    }
    Ok(())
}

fn check_readings(times: &[f64], magnitudes: &[f64]) -> Result<(), FieldChangeError> {
    for (i, (t, m)) in times.iter().zip(magnitudes).enumerate() {
        let why = if !t.is_finite() || !m.is_finite() {
            "time or field not finite"
        } else if *m <= 0.0 {
            "a zero field"
        } else if i > 0 && *t < times[i - 1] {
            "time before the one before it"
        } else {
            continue;
        };
        return Err(FieldChangeError::BadReading { index: i, why });
    }
    if times.is_empty() {
        return Err(FieldChangeError::BadReading {
            index: 0,
            why: "no readings",
        });
    }
    Ok(())
}

fn stronger(a: Option<Candidate>, b: Option<Candidate>, key: impl Fn(&Candidate) -> f64) -> Option<Candidate> {
    match (a, b) {
        (Some(a), Some(b)) => Some(if key(&b) > key(&a) { b } else { a }),
        (a, b) => a.or(b),
    }
}

/// The readings in blocks of `block_s` seconds from the first (empty blocks left out).
fn blocks(times: &[f64], fields: &[Vec3], magnitudes: &[f64], r: f64, block_s: f64) -> Vec<Block> {
    let t0 = times[0];
    let index = |t: f64| ((t - t0) / block_s).floor();
    let mut out = Vec::new();
    let mut first = 0;
    while first < times.len() {
        let k = index(times[first]);
        let end = first + times[first..].iter().take_while(|t| index(**t) <= k).count();
        let mut sums = Sums::default();
        for (b, m) in fields[first..end].iter().zip(&magnitudes[first..end]) {
            let u = [b[0] / m, b[1] / m, b[2] / m];
            sums.add(
                [
                    1.0,
                    u[0],
                    u[1],
                    u[2],
                    u[0] * u[0] - u[2] * u[2],
                    u[1] * u[1] - u[2] * u[2],
                    u[0] * u[1],
                    u[0] * u[2],
                    u[1] * u[2],
                ],
                m / r - 1.0,
            );
        }
        out.push(Block {
            first,
            end,
            from_s: times[first],
            to_s: times[end - 1],
            sums,
        });
        first = end;
    }
    out
}

/// The long-run variance of a reading's relative magnitude: each batch of `batch` blocks fitted
/// alone; its blocks' residual sums `r_k`, scaled `e_k = r_k / sqrt(n_k)`, give the Bartlett
/// (Newey-West) estimate `g_0 + 2 sum_{l <= LAGS} (1 - l / (LAGS + 1)) g_l` of their
/// autocovariances `g_l`, times `batch / (batch - P)` for the unknowns fitted. The median over
/// the batches is the variance: a batch that straddles a change is one of many.
fn long_run_variance(blocks: &[Block], batch: usize) -> f64 {
    let per_batch: Vec<f64> = blocks
        .chunks_exact(batch)
        .map(|c| {
            let total = c.iter().fold(Sums::default(), |s, b| s.combine(&b.sums, 1.0));
            let (theta, _) = total.fit();
            // A block's residual sum: sum rho - (sum h) . theta, the first row of its sums.
            let e: Vec<f64> = c
                .iter()
                .map(|b| (b.sums.hr[0] - (0..P).map(|i| b.sums.hh[0][i] * theta[i]).sum::<f64>()) / b.sums.n.sqrt())
                .collect();
            let g = |l: usize| e.iter().zip(&e[l..]).map(|(a, b)| a * b).sum::<f64>() / batch as f64;
            let lags = LAGS.min(batch - 1);
            let bartlett = g(0)
                + 2.0
                    * (1..=lags)
                        .map(|l| (1.0 - l as f64 / (lags + 1) as f64) * g(l))
                        .sum::<f64>();
            bartlett * batch as f64 / batch.saturating_sub(P).max(1) as f64
        })
        .collect();
    median(&per_batch)
}

/// Lags of blocks in the Bartlett estimate of the long-run variance.
const LAGS: usize = 5;

/// The state of a search: the blocks, the prefix sums of their sums, the long-run variance.
struct Search<'a> {
    blocks: &'a [Block],
    prefix: Vec<Sums>,
    variance: f64,
    settings: &'a FieldChangeSettings,
}

/// What the search of one piece found: the window to cut (with its first and end block) and the
/// strongest windows not cut.
struct PieceSearch {
    cut: Option<(Candidate, usize, usize)>,
    largest_z: Option<Candidate>,
    largest_step: Option<Candidate>,
}

impl Search<'_> {
    /// The sums of blocks `a..b`.
    fn sums(&self, a: usize, b: usize) -> Sums {
        self.prefix[b].combine(&self.prefix[a], -1.0)
    }

    /// Whether blocks `a..b` last at least the shortest piece (an empty range does).
    fn long_enough(&self, a: usize, b: usize) -> bool {
        a == b || self.blocks[b - 1].to_s - self.blocks[a].from_s >= self.settings.min_part_s
    }

    /// The step and z of window `i..j` against the rest of piece `a..b`, whose sums and fit's
    /// residual sum of squares are given.
    fn score(&self, piece: &Sums, piece_rss: f64, (i, j): (usize, usize)) -> (f64, f64) {
        let inside = self.sums(i, j);
        let outside = piece.combine(&inside, -1.0);
        let (theta_in, rss_in) = inside.fit();
        let (theta_out, rss_out) = outside.fit();
        let delta: [f64; P] = std::array::from_fn(|k| theta_in[k] - theta_out[k]);
        let drop = (piece_rss - rss_in - rss_out).max(0.0);
        let z = (drop / self.variance).sqrt();
        // A series without scatter: any difference is sure, none is not.
        (piece.rms_of(&delta), if z.is_nan() { 0.0 } else { z })
    }

    /// Every window of blocks `a..b` against the rest of the piece.
    fn piece(&self, a: usize, b: usize) -> PieceSearch {
        let mut out = PieceSearch {
            cut: None,
            largest_z: None,
            largest_step: None,
        };
        let piece = self.sums(a, b);
        let (_, piece_rss) = piece.fit();
        let (min_step, z_needed) = (self.settings.min_step, self.settings.z);
        for i in a..b {
            if !self.long_enough(a, i) {
                continue;
            }
            for j in i + 1..=b {
                if (i == a && j == b) || !self.long_enough(i, j) || !self.long_enough(j, b) {
                    continue;
                }
                let (step, z) = self.score(&piece, piece_rss, (i, j));
                let window = Candidate {
                    from_s: self.blocks[i].from_s,
                    to_s: self.blocks[j - 1].to_s,
                    z,
                    step,
                };
                if step >= min_step && z >= z_needed {
                    if out.cut.is_none_or(|c| z > c.0.z) {
                        out.cut = Some((window, i, j));
                    }
                } else {
                    out.largest_z = stronger(out.largest_z, Some(window), |c| c.z);
                    if z >= z_needed {
                        out.largest_step = stronger(out.largest_step, Some(window), |c| c.step);
                    }
                }
            }
        }
        out
    }

    /// The pieces between `cuts` (block indices), each against the longest.
    fn segments(&self, cuts: &[usize], magnitudes: &[f64]) -> Vec<Segment> {
        let mut out: Vec<Segment> = cuts
            .windows(2)
            .map(|w| {
                let (first, end) = (self.blocks[w[0]].first, self.blocks[w[1] - 1].end);
                Segment {
                    from_s: self.blocks[w[0]].from_s,
                    to_s: self.blocks[w[1] - 1].to_s,
                    first,
                    readings: end - first,
                    magnitude: median(&magnitudes[first..end]),
                    change: 0.0,
                    in_field: true,
                }
            })
            .collect();
        let reference = longest(&out);
        let theta = |k: usize| self.sums(cuts[k], cuts[k + 1]).fit().0;
        let theta_ref = theta(reference);
        for (k, s) in out.iter_mut().enumerate() {
            let own = theta(k);
            let delta: [f64; P] = std::array::from_fn(|i| theta_ref[i] - own[i]);
            s.change = self.sums(cuts[k], cuts[k + 1]).rms_of(&delta);
            s.in_field = s.change < self.settings.min_step;
        }
        out
    }
}

/// The centre and radius of the sphere that best fits the readings (the linear fit of
/// [`super::sphere_radius`]): a start that no runaway can take, for the calibrated field of a
/// log whose fit does not settle. `None` when no sphere fits.
pub fn best_sphere(readings: &[Vec3]) -> Option<(Vec3, f64)> {
    super::sphere(readings).ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::{MagcalRng, stream_rng};
    use rand::RngExt;
    use rand_distr::{Distribution, StandardNormal};

    /// BROAD's rate, Hz.
    const RATE: f64 = 285.714;

    /// Times of a log of `span_s` seconds at [`RATE`].
    fn times(span_s: f64) -> Vec<f64> {
        (0..(span_s * RATE) as usize).map(|i| i as f64 / RATE).collect()
    }

    /// Unit-variance AR(1) noise of correlation time `tau_s` at [`RATE`].
    fn ar1(n: usize, tau_s: f64, rng: &mut MagcalRng) -> Vec<f64> {
        let phi = (-1.0 / (RATE * tau_s)).exp();
        let innovation = (1.0 - phi * phi).sqrt();
        let mut e: f64 = StandardNormal.sample(rng);
        (0..n)
            .map(|_| {
                let v = e;
                let w: f64 = StandardNormal.sample(rng);
                e = phi * e + innovation * w;
                v
            })
            .collect()
    }

    /// The field's direction in the calibrated frame as a BROAD trial turns it: at rest for the
    /// first and last 30 s, between them through most directions (periods 37 and 11 s, phases
    /// drawn).
    fn directions(t: &[f64], rng: &mut MagcalRng) -> Vec<Vec3> {
        let (p1, p2) = (rng.random_range(0.0..1.0), rng.random_range(0.0..1.0));
        let end = t.last().copied().unwrap_or(0.0);
        t.iter()
            .map(|t| {
                let moving = t.clamp(30.0, end - 30.0);
                let phi = std::f64::consts::PI * (0.5 + 0.45 * (std::f64::consts::TAU * (moving / 37.0 + p1)).sin());
                let lambda = std::f64::consts::TAU * (moving / 11.0 + p2);
                [phi.sin() * lambda.cos(), phi.sin() * lambda.sin(), phi.cos()]
            })
            .collect()
    }

    /// Calibrated fields of one field of magnitude `r` with relative AR(1) noise `sigma` of
    /// correlation time `tau_s`, and from `on_s` to `off_s` a magnet: the level times `1 + level`
    /// and a hard iron `d` (the calibrated frame, the units of `r`).
    #[allow(clippy::too_many_arguments)]
    fn log(
        t: &[f64],
        r: f64,
        (sigma, tau_s): (f64, f64),
        (on_s, off_s): (f64, f64),
        level: f64,
        d: Vec3,
        rng: &mut MagcalRng,
    ) -> Vec<Vec3> {
        let u = directions(t, rng);
        let e = ar1(t.len(), tau_s, rng);
        t.iter()
            .zip(u)
            .zip(e)
            .map(|((t, u), e)| {
                let m = r * (1.0 + sigma * e);
                if (on_s..off_s).contains(t) {
                    std::array::from_fn(|i| m * (1.0 + level) * u[i] + d[i])
                } else {
                    u.map(|c| m * c)
                }
            })
            .collect()
    }

    /// A log of one field.
    fn one_field(t: &[f64], noise: (f64, f64), rng: &mut MagcalRng) -> Vec<Vec3> {
        log(t, 44.0, noise, (0.0, 0.0), 0.0, [0.0; 3], rng)
    }

    /// The boundaries of the part found out of the field, or a message.
    fn found_window(f: &FieldChange) -> Result<(f64, f64), String> {
        let s = &f.segments;
        match f.parts().as_slice() {
            [a, b, c] if s[a.0].in_field && !s[b.0].in_field && s[c.0].in_field => Ok((s[b.0].from_s, s[c.0].from_s)),
            p => Err(format!("{} parts: {s:?}", p.len())),
        }
    }

    #[test]
    fn a_step_of_the_level_is_found_at_its_block() {
        // 10 % for 50 s in 2 % noise correlated over 1 s, the board turning: found in 20 logs of
        // 20, both ends at the block (the first reading of 60 s and of 110 s).
        for k in 0..20 {
            let mut rng = stream_rng(0xF1E1E, k);
            let t = times(170.0);
            let b = log(&t, 44.0, (0.02, 1.0), (60.0, 110.0), 0.1, [0.0; 3], &mut rng);
            let f = field_segments(&t, &b, &FieldChangeSettings::default()).unwrap();
            let (on, off) = found_window(&f).unwrap();
            assert!(
                (on - 60.0).abs() <= 0.01 && (off - 110.0).abs() <= 0.01,
                "log {k}: {on} to {off}"
            );
            let middle = &f.segments[f.parts()[1].0];
            assert!(
                (middle.magnitude / f.segments[0].magnitude - 1.1).abs() < 0.01,
                "{middle:?}"
            );
        }
    }

    #[test]
    fn a_magnet_turning_with_the_board_is_found_within_three_seconds() {
        // A hard iron of 0.2 R: the median magnitude moves by about 2 %, below the step; the
        // field by 0.2 R / sqrt(3) rms. Found in 20 logs of 20: both ends at the block in 17,
        // within 1 s in 19, 3 s late in one (the field's direction nearly square to the magnet
        // then, so that the magnet hardly shows).
        for k in 0..20 {
            let mut rng = stream_rng(0xF1E1F, k);
            let t = times(170.0);
            let b = log(&t, 44.0, (0.02, 1.0), (60.0, 110.0), 0.0, [0.0, 0.0, 8.8], &mut rng);
            let f = field_segments(&t, &b, &FieldChangeSettings::default()).unwrap();
            let (on, off) = found_window(&f).unwrap();
            assert!(
                (on - 60.0).abs() <= 3.01 && (off - 110.0).abs() <= 3.01,
                "log {k}: {on} to {off}"
            );
        }
    }

    #[test]
    fn a_step_below_the_threshold_is_not_a_change() {
        // 3 % for 50 s in 1 % noise: sure (z above the threshold) but below the 5 % step.
        let mut rng = stream_rng(0xF1E20, 0);
        let t = times(170.0);
        let b = log(&t, 44.0, (0.01, 1.0), (60.0, 110.0), 0.03, [0.0; 3], &mut rng);
        let f = field_segments(&t, &b, &FieldChangeSettings::default()).unwrap();
        assert!(!f.changed(), "{:?}", f.segments);
        let largest = f.largest_step.unwrap();
        assert!(
            (largest.step - 0.03).abs() < 0.01 && largest.z > FIELD_CHANGE_Z,
            "{largest:?}"
        );
    }

    #[test]
    fn one_field_false_alarms() {
        // 200 logs of one field each (170 s at 285.7 Hz, BROAD's length and rate; at rest for
        // the first and last 30 s) with AR(1) noise: no change in any at 1 % noise correlated
        // over 3 s, nor at 3 % correlated over 1 s (`operating_points` measures more).
        for noise in [(0.01, 3.0), (0.03, 1.0)] {
            use rayon::prelude::*;
            let alarms = (0..200u64)
                .into_par_iter()
                .filter(|k| {
                    let mut rng = stream_rng(0xF1E22, *k);
                    let t = times(170.0);
                    let b = one_field(&t, noise, &mut rng);
                    field_segments(&t, &b, &FieldChangeSettings::default())
                        .unwrap()
                        .changed()
                })
                .count();
            assert_eq!(alarms, 0, "noise {noise:?}");
        }
    }

    #[test]
    fn a_log_too_short_is_not_searched() {
        let t: Vec<f64> = (0..200).map(|i| f64::from(i) * 0.1).collect();
        let b = vec![[1.0, 0.0, 0.0]; t.len()];
        let e = field_segments(&t, &b, &FieldChangeSettings::default()).unwrap_err();
        assert!(
            matches!(
                e,
                FieldChangeError::TooShort {
                    blocks: 20,
                    needed: 90,
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn bad_readings_are_refused() {
        let mut t = times(60.0);
        let mut b = vec![[1.0, 0.0, 0.0]; t.len()];
        t.swap(10, 11);
        let e = field_segments(&t, &b, &FieldChangeSettings::default()).unwrap_err();
        assert!(matches!(e, FieldChangeError::BadReading { index: 11, .. }), "{e}");
        t.swap(10, 11);
        b[5] = [0.0; 3];
        let e = field_segments(&t, &b, &FieldChangeSettings::default()).unwrap_err();
        assert!(matches!(e, FieldChangeError::BadReading { index: 5, .. }), "{e}");
    }

    #[test]
    fn a_log_at_one_hertz_is_searched_in_blocks_of_its_readings() {
        // A flight log's 1 Hz: 300 readings, one per block; a level 10 % higher for 100 s in
        // white noise of 1 % is found where it is.
        let t: Vec<f64> = (0..300).map(f64::from).collect();
        let mut rng = stream_rng(0xF1E21, 0);
        let u = directions(&t, &mut rng);
        let b: Vec<Vec3> = t
            .iter()
            .zip(u)
            .map(|(t, u)| {
                let e: f64 = StandardNormal.sample(&mut rng);
                let m = 0.5 * (1.0 + 0.01 * e) * if (100.0..200.0).contains(t) { 1.1 } else { 1.0 };
                u.map(|c| m * c)
            })
            .collect();
        let f = field_segments(&t, &b, &FieldChangeSettings::default()).unwrap();
        assert_eq!(found_window(&f).unwrap(), (100.0, 200.0));
        assert_eq!(f.blocks, 300);
    }

    #[test]
    #[ignore = "a measurement: cargo test --release -p magcal-core operating -- --ignored --nocapture"]
    fn operating_points() {
        for (min_part_s, z) in [(5.0, 12.0), (5.0, 15.0), (5.0, 18.0)] {
            let settings = FieldChangeSettings {
                min_part_s,
                z,
                ..FieldChangeSettings::default()
            };
            let mut line = format!("part {min_part_s} z {z}:");
            for (name, noise, level, d) in [
                ("null 1%/3s", (0.01, 3.0), 0.0, [0.0; 3]),
                ("null 3%/1s", (0.03, 1.0), 0.0, [0.0; 3]),
                ("null 3%/3s", (0.03, 3.0), 0.0, [0.0; 3]),
                ("null 5%/3s", (0.05, 3.0), 0.0, [0.0; 3]),
                ("level 8%", (0.02, 1.0), 0.08, [0.0; 3]),
                ("iron 0.2R", (0.02, 1.0), 0.0, [0.0, 0.0, 8.8]),
                ("iron 0.1R", (0.02, 1.0), 0.0, [0.0, 0.0, 4.4]),
                ("iron 0.1R xy", (0.02, 1.0), 0.0, [3.1, 3.1, 0.0]),
            ] {
                let (mut found, mut within) = (0, 0);
                let logs = if name.starts_with("null") { 200 } else { 40 };
                for k in 0..logs {
                    let mut rng = stream_rng(0xF1E22, k);
                    let t = times(170.0);
                    let b = log(&t, 44.0, noise, (60.0, 110.0), level, d, &mut rng);
                    let f = field_segments(&t, &b, &settings).unwrap();
                    found += usize::from(f.changed());
                    if let Ok((on, off)) = found_window(&f) {
                        within += usize::from((on - 60.0).abs() <= 2.5 && (off - 110.0).abs() <= 2.5);
                    }
                }
                line += &format!(" {name} {found}/{within} of {logs};");
            }
            println!("{line}");
        }
    }

    #[test]
    #[ignore = "a measurement: cargo test --release -p magcal-core null_z -- --ignored --nocapture"]
    fn null_z_distribution() {
        for noise in [(0.01, 0.1), (0.01, 1.0), (0.01, 3.0), (0.03, 1.0), (0.05, 3.0)] {
            let mut zs = Vec::new();
            let mut steps = Vec::new();
            let mut alarms = 0;
            for k in 0..200 {
                let mut rng = stream_rng(0xF1E1D, k);
                let t = times(170.0);
                let b = one_field(&t, noise, &mut rng);
                let settings = FieldChangeSettings {
                    z: 1e-9,
                    min_step: 10.0,
                    ..FieldChangeSettings::default()
                };
                let f = field_segments(&t, &b, &settings).unwrap();
                zs.push(f.largest_z.map_or(0.0, |c| c.z));
                steps.push(f.largest_step.map_or(0.0, |c| c.step));
                alarms += usize::from(
                    field_segments(&t, &b, &FieldChangeSettings::default())
                        .unwrap()
                        .changed(),
                );
            }
            zs.sort_by(f64::total_cmp);
            steps.sort_by(f64::total_cmp);
            println!(
                "noise {noise:?}: largest z median {:.2} p95 {:.2} p99 {:.2} max {:.2}; largest step median {:.4} max {:.4}; logs with a change {alarms}/200",
                zs[100], zs[190], zs[198], zs[199], steps[100], steps[199]
            );
        }
    }
}
