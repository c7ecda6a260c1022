//! A field that is not one field: where, within a log, the field that a calibration maps the
//! readings to changes over time, as a magnet put on the board or taken off changes it
//! (docs/conventions.md "One field").
//!
//! A log fit assumes one sensor in one uniform field: under a calibration that holds, the
//! calibrated magnitude `m_t = |P (s_t - O)|` stays at the field magnitude but for noise and
//! what the model leaves out. A magnet fixed to the board adds a hard iron `d` while it is there:
//! under the calibration of the readings without it, `m_t = |b_t + P d|`, which moves the level
//! of `m_t` (by up to `|P d|` where the attitudes change little) and widens its spread (by about
//! `|P d| |cos|` where they turn). [`field_segments`] looks for both.
//!
//! # Method
//! - The series: blocks of `block_s` seconds (default 1; longer when the log has more than
//!   `max_blocks` of them), each holding the median of its readings' relative level
//!   `m_t / R - 1` and the median of their relative deviation `|m_t / R - 1|`, with `R` the
//!   median of all `m_t`. The medians make a block indifferent to a few spikes.
//! - The search (circular binary segmentation, Olshen et al. 2004): in each piece, every window of
//!   whole blocks against the rest of the piece (a window at an end of the piece is one change,
//!   one inside it is a change and a change back), scored by the difference of the block means
//!   inside and outside, `z = |mean_in - mean_out| / (sd sqrt(1/n_in + 1/n_out))`, for the level
//!   and for the deviation. A window is a change when, for the level or the deviation, the
//!   difference is at least `min_step` (default 5 % of the magnitude) **and** `z >= z` (default
//!   [`FIELD_CHANGE_Z`]); every piece it leaves lasts at least `min_part_s` (default 5 s). The
//!   window of largest `z` is cut first, and the search repeats in the pieces.
//! - `sd` is the long-run standard deviation of the block series, not its plain one: real
//!   residuals are correlated in time (the attitude moves slowly, and the field's departures
//!   from the model with it), so neighbouring blocks are not independent. It comes from batch
//!   means of `batch_blocks` blocks (default 10 s): `sd = sqrt(batch) 1.4826 median |a_k+1 -
//!   a_k| / sqrt(2)` over consecutive batch means `a_k`. Differences of neighbours and their
//!   median make it indifferent to the few batches that straddle a change.
//!
//! # Why both thresholds
//! Every real log holds changes that are significant and harmless: the rest phases of a BROAD
//! trial sit in another spot of the room than the motion between them, and its calibrated level
//! differs there by about 1 %; with 50,000 readings a z test alone calls that a change. The step
//! says how large a change must be to matter ([`FIELD_CHANGE_STEP`]), the z how sure it must be
//! ([`FIELD_CHANGE_Z`]). Measured (numbers in the docs of the two constants): the clean BROAD
//! trials' largest step is at most 1.8 %, the attached magnet's 24 %; the z of the clean trials
//! reaches 6.3 and the simulated logs' 9.3, the magnet's 12.3.
//!
//! # Parts
//! The longest piece is the reference: a piece whose median level lies within `min_step` of the
//! reference's and whose median deviation from the reference magnitude is below `min_step` is in
//! the reference field ([`Segment::in_field`]). Neighbouring pieces alike in that are one part
//! ([`FieldChange::parts`]): the pieces of a magnet's window, which the calibration of the rest
//! does not make constant, are one part "not in the field".

use crate::metrics::median;
use crate::small::Vec3;

/// The smallest change that counts, a fraction of the magnitude (of the level `m / R - 1` or the
/// deviation `|m / R - 1|`): 5 %. Measured, the largest difference of block means between a
/// window of 5 s or more and the rest, whatever its z, under the full fit of the whole log:
/// BROAD 02 1.78 %, 05 1.12 %, 30 (a magnet fixed in the room) 1.19 %; the magnet attached to
/// the board (trial 33) 23.9 % under the full fit of the part without it. A step of 5 % is the
/// hard iron of a magnet about a tenth of the field strong where the attitudes change little.
pub const FIELD_CHANGE_STEP: f64 = 0.05;

/// The z a change needs (see [`field_segments`]): 8. Measured, the largest z over 200 simulated
/// logs of one field each (170 s at 285.7 Hz, AR(1) noise of 1 % with correlation times of 0.1,
/// 1 and 3 s): 7.25, 7.73 and 9.33, 99th percentiles 6.51, 7.49 and 8.46 (the test
/// `null_z_distribution`); BROAD's clean trials under their full fits 6.27 (02), 4.49 (05), 4.51
/// (30); the attached magnet 12.3. With the step, no log of one field in 200 changes at 1 % or
/// 3 % noise, one in 200 at 5 % noise correlated over 3 s (`one_field_false_alarms`).
pub const FIELD_CHANGE_Z: f64 = 8.0;

/// Settings of [`field_segments`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldChangeSettings {
    /// Block length, seconds (default 1); longer where the log would have more than
    /// `max_blocks`.
    pub block_s: f64,
    /// At most this many blocks (default 3000): the search costs the square of their number.
    pub max_blocks: usize,
    /// Blocks per batch of the long-run standard deviation (default 10).
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
            max_blocks: 3000,
            batch_blocks: 10,
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
    #[error("{name} = {value}: {why}")]
    InvalidSetting {
        /// The setting.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What it must be.
        why: &'static str,
    },
    /// A time or magnitude that is not finite, or a time before the one before it.
    #[error("reading {index}: {why}")]
    BadReading {
        /// 0-based index of the reading.
        index: usize,
        /// What is wrong.
        why: &'static str,
    },
    /// Too few blocks for the long-run standard deviation and two pieces.
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
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// Time of its first reading, seconds.
    pub from_s: f64,
    /// Time of its last reading, seconds.
    pub to_s: f64,
    /// Index of its first reading.
    pub first: usize,
    /// Its readings.
    pub readings: usize,
    /// The median magnitude of its readings, the log's units.
    pub magnitude: f64,
    /// The median of `|m / R_ref - 1|` over its readings, with `R_ref` the reference piece's
    /// median magnitude.
    pub deviation: f64,
    /// In the field of the reference piece (the longest): level and deviation within
    /// `min_step`.
    pub in_field: bool,
}

/// A window tested: the strongest of a search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    /// Start, seconds.
    pub from_s: f64,
    /// End, seconds.
    pub to_s: f64,
    /// Its z (the larger of level and deviation).
    pub z: f64,
    /// Its difference of block means, fraction of the magnitude (the larger of level and
    /// deviation, in absolute value).
    pub step: f64,
}

/// What [`field_segments`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldChange {
    /// The pieces in time order; one piece: no change found.
    pub segments: Vec<Segment>,
    /// The median of all magnitudes, the log's units (the `R` of the search).
    pub magnitude: f64,
    /// Blocks searched and their length, seconds.
    pub blocks: usize,
    /// Block length, seconds.
    pub block_s: f64,
    /// Long-run standard deviations of the block series (level, deviation), fractions of the
    /// magnitude.
    pub long_run_sd: [f64; 2],
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

/// One block: its readings and the medians of the two series.
#[derive(Debug, Clone, Copy)]
struct Block {
    first: usize,
    end: usize,
    from_s: f64,
    to_s: f64,
    /// Median of `m / R - 1` and of `|m / R - 1|`.
    x: [f64; 2],
}

/// The pieces of a log of one field each: `times` (seconds, non-decreasing) and the calibrated
/// magnitudes `magnitudes` of the readings (any units, positive), searched as the module says.
///
/// # Errors
/// A setting out of range, a time or magnitude not finite, a time before the one before it, a
/// median magnitude not positive; a log too short for the search ([`FieldChangeError::TooShort`]).
///
/// # Panics
/// `times` and `magnitudes` of different lengths.
#[track_caller]
pub fn field_segments(
    times: &[f64],
    magnitudes: &[f64],
    settings: &FieldChangeSettings,
) -> Result<FieldChange, FieldChangeError> {
    assert_eq!(times.len(), magnitudes.len(), "one time per magnitude");
    check_settings(settings)?;
    for (i, (t, m)) in times.iter().zip(magnitudes).enumerate() {
        if !t.is_finite() || !m.is_finite() {
            return Err(FieldChangeError::BadReading {
                index: i,
                why: "time or magnitude not finite",
            });
        }
        if i > 0 && *t < times[i - 1] {
            return Err(FieldChangeError::BadReading {
                index: i,
                why: "time before the one before it",
            });
        }
    }
    let r = median(magnitudes);
    if r.is_nan() || r <= 0.0 {
        return Err(FieldChangeError::BadReading {
            index: 0,
            why: "the median magnitude is not positive",
        });
    }
    let span = times.last().map_or(0.0, |l| l - times[0]);
    let block_s = settings.block_s.max(span / settings.max_blocks as f64);
    let blocks = blocks(times, magnitudes, r, block_s);
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
    let sd = [0, 1].map(|k| long_run_sd(&blocks, k, settings.batch_blocks));
    let search = Search {
        blocks: &blocks,
        sums: [0, 1].map(|k| prefix_sums(&blocks, k)),
        sd,
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
            largest_step = stronger(largest_step, found.largest_step, |c| c.step.abs());
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
        segments: segments(&blocks, &cuts, magnitudes, settings.min_step),
        magnitude: r,
        blocks: blocks.len(),
        block_s,
        long_run_sd: sd,
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

fn stronger(a: Option<Candidate>, b: Option<Candidate>, key: impl Fn(&Candidate) -> f64) -> Option<Candidate> {
    match (a, b) {
        (Some(a), Some(b)) => Some(if key(&b) > key(&a) { b } else { a }),
        (a, b) => a.or(b),
    }
}

/// The readings in blocks of `block_s` seconds from the first (empty blocks left out).
fn blocks(times: &[f64], magnitudes: &[f64], r: f64, block_s: f64) -> Vec<Block> {
    let t0 = times[0];
    let index = |t: f64| ((t - t0) / block_s).floor();
    let mut out = Vec::new();
    let mut first = 0;
    while first < times.len() {
        let k = index(times[first]);
        let end = first + times[first..].iter().take_while(|t| index(**t) <= k).count();
        let level: Vec<f64> = magnitudes[first..end].iter().map(|m| m / r - 1.0).collect();
        let deviation: Vec<f64> = level.iter().map(|v| v.abs()).collect();
        out.push(Block {
            first,
            end,
            from_s: times[first],
            to_s: times[end - 1],
            x: [median(&level), median(&deviation)],
        });
        first = end;
    }
    out
}

/// The long-run standard deviation of series `k` per block, from the neighbours' differences of
/// batch means of `batch` blocks (see the module).
fn long_run_sd(blocks: &[Block], k: usize, batch: usize) -> f64 {
    let means: Vec<f64> = blocks
        .chunks_exact(batch)
        .map(|c| c.iter().map(|b| b.x[k]).sum::<f64>() / batch as f64)
        .collect();
    let mut steps: Vec<f64> = means.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    steps.sort_by(f64::total_cmp);
    // The rms of the smallest KEPT of the differences, scaled to a normal's standard deviation.
    let kept = ((steps.len() as f64 * KEPT).ceil() as usize).clamp(1, steps.len().max(1));
    let rms = (steps[..kept].iter().map(|d| d * d).sum::<f64>() / kept as f64).sqrt();
    (batch as f64).sqrt() * rms / TRIMMED_RMS / 2f64.sqrt()
}

/// The share of the differences of batch means kept for the long-run standard deviation: those
/// that straddle a change (two per change) are left out with the largest.
const KEPT: f64 = 0.8;

/// The rms of the smallest 80 % of `|x|` for a standard normal x: `sqrt((0.8 - 2 q phi(q)) / 0.8)`
/// with `q = 1.28155` its 90th percentile.
const TRIMMED_RMS: f64 = 0.661_6;

fn prefix_sums(blocks: &[Block], k: usize) -> Vec<f64> {
    let mut sums = Vec::with_capacity(blocks.len() + 1);
    sums.push(0.0);
    for b in blocks {
        sums.push(sums.last().copied().unwrap_or(0.0) + b.x[k]);
    }
    sums
}

/// The state of a search: the blocks, the prefix sums of both series, their long-run standard
/// deviations.
struct Search<'a> {
    blocks: &'a [Block],
    sums: [Vec<f64>; 2],
    sd: [f64; 2],
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
    /// Whether blocks `a..b` last at least the shortest piece (an empty range does).
    fn long_enough(&self, a: usize, b: usize) -> bool {
        a == b || self.blocks[b - 1].to_s - self.blocks[a].from_s >= self.settings.min_part_s
    }

    /// Difference of means inside `i..j` and outside it within `a..b`, and its z, of series `k`.
    fn score(&self, k: usize, (a, b): (usize, usize), (i, j): (usize, usize)) -> (f64, f64) {
        let s = &self.sums[k];
        let (n_in, n_out) = ((j - i) as f64, (b - a - (j - i)) as f64);
        let inside = s[j] - s[i];
        let outside = s[b] - s[a] - inside;
        let step = inside / n_in - outside / n_out;
        let z = step.abs() / (self.sd[k] * (1.0 / n_in + 1.0 / n_out).sqrt());
        // A series without scatter: any difference is sure, none is not.
        let z = if z.is_nan() { 0.0 } else { z };
        (step, z)
    }

    /// Every window of blocks `a..b` against the rest of the piece.
    fn piece(&self, a: usize, b: usize) -> PieceSearch {
        let mut out = PieceSearch {
            cut: None,
            largest_z: None,
            largest_step: None,
        };
        let (min_step, z_needed) = (self.settings.min_step, self.settings.z);
        for i in a..b {
            if !self.long_enough(a, i) {
                continue;
            }
            for j in i + 1..=b {
                if (i == a && j == b) || !self.long_enough(i, j) || !self.long_enough(j, b) {
                    continue;
                }
                let scores = [0, 1].map(|k| self.score(k, (a, b), (i, j)));
                let z = scores[0].1.max(scores[1].1);
                let step = if scores[0].0.abs() >= scores[1].0.abs() {
                    scores[0].0
                } else {
                    scores[1].0
                };
                let window = Candidate {
                    from_s: self.blocks[i].from_s,
                    to_s: self.blocks[j - 1].to_s,
                    z,
                    step,
                };
                // The z and step of the series that make the window a change, the larger z first.
                let cut = scores
                    .iter()
                    .filter(|(s, z)| s.abs() >= min_step && *z >= z_needed)
                    .max_by(|a, b| a.1.total_cmp(&b.1));
                match cut {
                    Some(&(step, z)) => {
                        if out.cut.is_none_or(|c| z > c.0.z) {
                            out.cut = Some((Candidate { z, step, ..window }, i, j));
                        }
                    }
                    None => {
                        out.largest_z = stronger(out.largest_z, Some(window), |c| c.z);
                        if z >= z_needed {
                            out.largest_step = stronger(out.largest_step, Some(window), |c| c.step.abs());
                        }
                    }
                }
            }
        }
        out
    }
}

/// The pieces between `cuts` (block indices), with their medians against the longest piece.
fn segments(blocks: &[Block], cuts: &[usize], magnitudes: &[f64], min_step: f64) -> Vec<Segment> {
    let mut out: Vec<Segment> = cuts
        .windows(2)
        .map(|w| {
            let (first, end) = (blocks[w[0]].first, blocks[w[1] - 1].end);
            Segment {
                from_s: blocks[w[0]].from_s,
                to_s: blocks[w[1] - 1].to_s,
                first,
                readings: end - first,
                magnitude: median(&magnitudes[first..end]),
                deviation: f64::NAN,
                in_field: true,
            }
        })
        .collect();
    let reference = out[longest(&out)].magnitude;
    for s in &mut out {
        let m = &magnitudes[s.first..s.first + s.readings];
        let deviation: Vec<f64> = m.iter().map(|v| (v / reference - 1.0).abs()).collect();
        s.deviation = median(&deviation);
        s.in_field = (s.magnitude / reference - 1.0).abs() < min_step && s.deviation < min_step;
    }
    out
}

/// The centre and radius of the sphere that best fits the readings (the linear fit of
/// [`super::sphere_radius`]): a start that no runaway can take, for the magnitudes of a log
/// whose fit does not settle. `None` when no sphere fits.
pub fn best_sphere(readings: &[Vec3]) -> Option<(Vec3, f64)> {
    super::sphere(readings).ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::{MagcalRng, stream_rng};
    use rand_distr::{Distribution, StandardNormal};

    /// BROAD's rate, Hz.
    const RATE: f64 = 285.714;

    /// Times of a log of `span_s` seconds at [`RATE`].
    fn times(span_s: f64) -> Vec<f64> {
        (0..(span_s * RATE) as usize).map(|i| i as f64 / RATE).collect()
    }

    /// Unit-variance AR(1) noise of correlation time `tau_s` at the times' spacing.
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

    /// Magnitudes `r (1 + sigma e_t)` of one field.
    fn one_field(t: &[f64], r: f64, sigma: f64, tau_s: f64, rng: &mut MagcalRng) -> Vec<f64> {
        ar1(t.len(), tau_s, rng).iter().map(|e| r * (1.0 + sigma * e)).collect()
    }

    /// Magnitudes of one field with a magnet on the board from `on_s` to `off_s`: `level` moves
    /// the magnitude (attitudes that change little), `spread` widens it (attitudes that turn:
    /// `|b + d| = R sqrt(1 + a^2 + 2 a cos theta)` with `a = spread` and the turn of period 7 s).
    fn with_magnet(t: &[f64], base: &[f64], (on_s, off_s): (f64, f64), level: f64, spread: f64) -> Vec<f64> {
        t.iter()
            .zip(base)
            .map(|(t, m)| {
                if (on_s..off_s).contains(t) {
                    let c = (std::f64::consts::TAU * t / 7.0).cos();
                    m * (1.0 + level) * (1.0 + spread * spread + 2.0 * spread * c).sqrt()
                } else {
                    *m
                }
            })
            .collect()
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
    fn a_step_of_the_level_is_found_within_a_block() {
        // 8 % for 50 s in 2 % AR(1) noise of 1 s: 20 logs, every window found within 1 s (the
        // block) of where the magnet went on and off.
        for k in 0..20 {
            let mut rng = stream_rng(0xF1E1E, k);
            let t = times(170.0);
            let m = with_magnet(&t, &one_field(&t, 44.0, 0.02, 1.0, &mut rng), (60.0, 110.0), 0.08, 0.0);
            let f = field_segments(&t, &m, &FieldChangeSettings::default()).unwrap();
            let (on, off) = found_window(&f).unwrap();
            assert!(
                (on - 60.0).abs() <= 2.5 && (off - 110.0).abs() <= 2.5,
                "log {k}: {on} to {off}"
            );
            assert!((f.segments[1].magnitude / f.segments[0].magnitude - 1.08).abs() < 0.01);
        }
    }

    #[test]
    fn a_wider_spread_is_found_where_the_level_hardly_moves() {
        // A magnet of 0.2 R turning with the board: the median magnitude moves by
        // sqrt(1 + 0.04) - 1 = 2 %, below the step, its spread by far more.
        for k in 0..20 {
            let mut rng = stream_rng(0xF1E1F, k);
            let t = times(170.0);
            let m = with_magnet(&t, &one_field(&t, 44.0, 0.02, 1.0, &mut rng), (60.0, 110.0), 0.0, 0.2);
            let f = field_segments(&t, &m, &FieldChangeSettings::default()).unwrap();
            let (on, off) = found_window(&f).unwrap();
            assert!(
                (on - 60.0).abs() <= 2.5 && (off - 110.0).abs() <= 2.5,
                "log {k}: {on} to {off}"
            );
        }
    }

    #[test]
    fn a_step_below_the_threshold_is_not_a_change() {
        // 3 % for 50 s: significant (z far above 8 with 1 % noise) but below the 5 % step.
        let mut rng = stream_rng(0xF1E20, 0);
        let t = times(170.0);
        let m = with_magnet(&t, &one_field(&t, 44.0, 0.01, 1.0, &mut rng), (60.0, 110.0), 0.03, 0.0);
        let f = field_segments(&t, &m, &FieldChangeSettings::default()).unwrap();
        assert!(!f.changed(), "{:?}", f.segments);
        assert!(
            f.largest_step.is_some_and(|c| (c.step.abs() - 0.03).abs() < 0.005),
            "{:?}",
            f.largest_step
        );
    }

    #[test]
    fn one_field_false_alarms() {
        // 200 logs of one field each (170 s at 285.7 Hz, BROAD's length and rate) with AR(1)
        // noise. Measured: no change in any log at 1 % and 3 % noise (correlation 1 s), one
        // in 200 at 5 % with correlation 3 s (`null_z_distribution`); asserted within twice that.
        for (sigma, tau, most) in [(0.01, 1.0, 0), (0.03, 1.0, 0), (0.05, 3.0, 2)] {
            let alarms = (0..200)
                .filter(|k| {
                    let mut rng = stream_rng(0xF1E1D, *k);
                    let t = times(170.0);
                    let m = one_field(&t, 44.0, sigma, tau, &mut rng);
                    field_segments(&t, &m, &FieldChangeSettings::default())
                        .unwrap()
                        .changed()
                })
                .count();
            assert!(
                alarms <= most,
                "noise {sigma}, correlation {tau} s: {alarms} of 200 logs"
            );
        }
    }

    #[test]
    fn a_log_too_short_is_not_searched() {
        let t: Vec<f64> = (0..200).map(|i| f64::from(i) * 0.1).collect();
        let m = vec![1.0; t.len()];
        let e = field_segments(&t, &m, &FieldChangeSettings::default()).unwrap_err();
        assert!(
            matches!(
                e,
                FieldChangeError::TooShort {
                    blocks: 20,
                    needed: 30,
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn times_out_of_order_are_refused() {
        let mut t = times(60.0);
        t.swap(10, 11);
        let m = vec![1.0; t.len()];
        let e = field_segments(&t, &m, &FieldChangeSettings::default()).unwrap_err();
        assert!(matches!(e, FieldChangeError::BadReading { index: 11, .. }), "{e}");
    }

    #[test]
    fn a_log_at_one_hertz_is_searched_in_blocks_of_its_readings() {
        // A flight log's 1 Hz: 300 readings, one per block; a 10 % step for 100 s is found.
        let t: Vec<f64> = (0..300).map(f64::from).collect();
        let mut rng = stream_rng(0xF1E21, 0);
        let base: Vec<f64> = (0..300)
            .map(|_| 0.5 * (1.0 + 0.01 * <StandardNormal as Distribution<f64>>::sample(&StandardNormal, &mut rng)))
            .collect();
        let m = with_magnet(&t, &base, (100.0, 200.0), 0.1, 0.0);
        let f = field_segments(&t, &m, &FieldChangeSettings::default()).unwrap();
        assert_eq!(found_window(&f).unwrap(), (100.0, 200.0));
        assert_eq!(f.blocks, 300);
    }

    #[test]
    #[ignore = "a measurement: cargo test --release -p magcal-core null_z -- --ignored --nocapture"]
    fn null_z_distribution() {
        for (sigma, tau) in [
            (0.01, 0.1),
            (0.01, 1.0),
            (0.01, 3.0),
            (0.03, 1.0),
            (0.05, 1.0),
            (0.05, 3.0),
            (0.1, 1.0),
        ] {
            let mut zs = Vec::new();
            let mut alarms = [0; 3];
            for k in 0..200 {
                let mut rng = stream_rng(0xF1E1D, k);
                let t = times(170.0);
                let m = one_field(&t, 44.0, sigma, tau, &mut rng);
                for (i, (a, z)) in alarms.iter_mut().zip([6.0, 7.0, 8.0]).enumerate() {
                    let settings = FieldChangeSettings {
                        z,
                        ..FieldChangeSettings::default()
                    };
                    let f = field_segments(&t, &m, &settings).unwrap();
                    *a += usize::from(f.changed());
                    if i == 0 {
                        zs.push(f.largest_z.map_or(0.0, |c| c.z));
                    }
                }
            }
            zs.sort_by(f64::total_cmp);
            println!(
                "sigma {sigma} tau {tau}: largest z median {:.2} p95 {:.2} p99 {:.2} max {:.2}; logs with a change at z 6, 7, 8: {alarms:?}/200",
                zs[100], zs[190], zs[198], zs[199]
            );
        }
    }
}
