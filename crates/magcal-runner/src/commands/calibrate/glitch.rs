//! Readings far from all the others: a glitch (a flipped bit, a row in other units) that no
//! calibration fits. Left in, it makes the fit fail for a reason that is not the log's ("readings
//! too alike", "does not settle"), and `--reject` cannot drop it, because its first fit already
//! fails; so glitches are found before any fit, named in the reasons, and dropped by `--reject`.

use magcal_core::Vec3;
use magcal_core::metrics::median_of;
use magcal_logs::text::significant;
use rayon::prelude::*;

use crate::log::source::Log;

/// How many times the readings' own size a reading must lie from their median to be a glitch:
/// 1000. A magnetometer's readings lie on an ellipsoid about the bias, within a few times its
/// size of one another whatever the bias, the scale factors or the coverage.
pub const GLITCH_FACTOR: f64 = 1e3;

/// At most one reading in this many may be a glitch: 20 (5 %).
pub const GLITCH_SHARE: usize = 20;

/// The glitches of a log.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Glitches {
    /// Indices of the glitch readings, ascending.
    pub indices: Vec<usize>,
    /// The readings' own size: the larger of their median distance from their componentwise
    /// median and their median norm.
    pub size: f64,
    /// The farthest glitch's distance from the median, in that size (infinite where it
    /// overflows).
    pub farthest: f64,
}

/// The readings of `readings` farther than [`GLITCH_FACTOR`] times their own size from their
/// componentwise median (or whose distance is not finite), when they are at most one in
/// [`GLITCH_SHARE`].
pub fn find(readings: &[Vec3]) -> Glitches {
    if readings.len() < 3 {
        return Glitches::default();
    }
    // Each median and each map is what the plain loop gives; the three components' medians, and
    // the distances' and the norms', are found side by side.
    let components: Vec<f64> = (0..3)
        .into_par_iter()
        .map(|c| median_of(&mut readings.iter().map(|r| r[c]).collect::<Vec<_>>()))
        .collect();
    let centre: Vec3 = [components[0], components[1], components[2]];
    let distance = |r: &Vec3| (0..3).map(|c| (r[c] - centre[c]).powi(2)).sum::<f64>().sqrt();
    let distances: Vec<f64> = readings.par_iter().map(distance).collect();
    let (distance_median, norm_median) = rayon::join(
        || median_of(&mut distances.iter().copied().filter(|d| d.is_finite()).collect::<Vec<_>>()),
        || {
            median_of(
                &mut readings
                    .iter()
                    .map(|r| r.iter().map(|x| x * x).sum::<f64>().sqrt())
                    .filter(|n| n.is_finite())
                    .collect::<Vec<_>>(),
            )
        },
    );
    let size = distance_median.max(norm_median);
    if !(size.is_finite() && size > 0.0) {
        return Glitches::default();
    }
    let indices: Vec<usize> = distances
        .iter()
        .enumerate()
        // NaN (a reading of infinities) is out too.
        .filter(|(_, d)| d.is_nan() || **d > GLITCH_FACTOR * size)
        .map(|(i, _)| i)
        .collect();
    // Glitches are few: when many readings lie that far out, the spread is the log's own
    // (readings in two units, or the far ones are the log), which the fit and its reasons judge.
    if indices.len() * GLITCH_SHARE > readings.len() {
        return Glitches::default();
    }
    let farthest = indices
        .iter()
        .map(|&i| {
            if distances[i].is_nan() {
                f64::INFINITY
            } else {
                distances[i] / size
            }
        })
        .fold(0.0_f64, f64::max);
    Glitches {
        indices,
        size,
        farthest,
    }
}

impl Glitches {
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }

    /// The glitches in words: how many, the first three by their place in `log` and value, and
    /// how far out the farthest lies.
    pub fn words(&self, log: &Log) -> String {
        let shown: Vec<String> = self
            .indices
            .iter()
            .take(3)
            .map(|&i| {
                let r = log.readings[i].map(crate::limits::show);
                format!(
                    "{} {} ({}, {}, {})",
                    log.origin.position_name(),
                    log.lines[i],
                    r[0],
                    r[1],
                    r[2]
                )
            })
            .collect();
        let more = if self.indices.len() > 3 {
            format!(" and {} more", self.indices.len() - 3)
        } else {
            String::new()
        };
        format!(
            "{} reading{} {} glitch{}, more than {} times the readings' own size ({}) from their median, up to {}: {}{more}",
            self.indices.len(),
            if self.indices.len() == 1 { "" } else { "s" },
            if self.indices.len() == 1 { "is a" } else { "are" },
            if self.indices.len() == 1 { "" } else { "es" },
            crate::limits::show(GLITCH_FACTOR),
            significant(self.size, 4),
            if self.farthest.is_finite() {
                format!("{} times it", significant(self.farthest, 2))
            } else {
                "beyond the range of numbers".to_string()
            },
            shown.join(", ")
        )
    }

    /// Drops the glitches from `log`, noting them; how many went.
    pub fn drop_from(&self, log: &mut Log) -> usize {
        if self.is_empty() {
            return 0;
        }
        let words = self.words(log);
        let mut keep = vec![true; log.readings.len()];
        for &i in &self.indices {
            keep[i] = false;
        }
        log.keep(&keep);
        log.origin
            .notes
            .push(format!("--reject dropped the glitches first: {words}."));
        self.indices.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Readings of 50 on a sphere about (3, -2, 1), `n` of them.
    fn sphere(n: usize) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let t = i as f64;
                let z = 1.0 - 2.0 * (t + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let a = t * 2.399_963;
                [50.0 * r * a.cos() + 3.0, 50.0 * r * a.sin() - 2.0, 50.0 * z + 1.0]
            })
            .collect()
    }

    #[test]
    fn a_reading_a_thousand_times_out_is_a_glitch_and_a_far_bias_or_a_cap_is_not() {
        let mut r = sphere(500);
        assert!(find(&r).is_empty());
        r[200] = [1e20, 1.0, 2.0];
        r[300] = [f64::MAX, f64::MAX, 0.0];
        let g = find(&r);
        assert_eq!(g.indices, [200, 300]);
        // Three far readings of five are the log, not glitches.
        let few = [
            [1.0, 1e308, 0.0],
            [1.0, 0.0, 1e308],
            [1e308, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
        ];
        assert!(find(&few).is_empty());
        // A bias 1e4 times the field, and a cap of a few degrees of the sphere: no glitch.
        let far: Vec<Vec3> = sphere(500).iter().map(|v| [v[0] + 5e5, v[1], v[2]]).collect();
        assert!(find(&far).is_empty());
        let cap: Vec<Vec3> = sphere(500).into_iter().filter(|v| v[2] > 49.0).collect();
        assert!(cap.len() > 3);
        let mut with_far_side = cap.clone();
        with_far_side.push([3.0, -2.0, -49.0]);
        assert!(find(&with_far_side).is_empty());
    }
}
