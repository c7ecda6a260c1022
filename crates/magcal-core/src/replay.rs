//! \[P1\]'s Monte Carlo (IV.C) on a real log: a design's attitudes realised by the log's own
//! readings instead of simulated ones.
//!
//! A scalar calibration sees an attitude only through the direction of the field in the sensor
//! frame (\[P1\] eq. (1): `B^b = C_n^b B^n`; the information of eq. (12) depends on nothing
//! else). So a design attitude `x` is realised, on a log whose readings carry a reference
//! attitude, by the readings whose body-frame field direction lies nearest to the design's
//! `C(x) B^n / |B^n|`, the design's body axes (nose, up, right) taken as the log's body axes
//! (forward, up, right: [`body_of_paper`]). The log's direction of reading `t` is
//! `C_t^T F / |F|`, with `C_t` its reference attitude (body forward-right-down into a z-up
//! reference frame) and `F` the field that aligns a calibration of the whole log with the
//! attitudes ([`crate::reference::align`]). The sensor's own axes may differ from the body's by a
//! constant rotation; the information of a design (`det M_F`) does not change under one, so a
//! design keeps its criterion value however the sensor is mounted.
//!
//! A vehicle holds an attitude for a moment, and the samples of that moment average down the
//! noise: a **held reading** is the mean of `hold` consecutive readings (a window), and its
//! direction the normalised mean of their directions. A window is used only where its readings
//! are consecutive in time (no gap in the reference attitudes inside it: [`windows`]). The
//! **candidates** of a design attitude are the windows whose direction lies within a given
//! angle of the design's ([`realise`]); a trial draws one at random for each design attitude,
//! so trials differ as real repetitions of the manoeuvre would.
//!
//! # Orientation
//! A log seldom covers every direction, and a design's directions may fall where it has none.
//! Since `det M_F` does not change when every direction of a design is turned by one rotation
//! (the quadratic and linear terms of `h` transform by matrices of determinant 1), the design
//! may be turned as a whole to where the log has readings: [`orient`] finds the rotation that
//! brings the design's farthest direction nearest to the log's coverage ([`CoverageMap`]). The
//! turned design has the same information; it is the design as a sensor mounted otherwise
//! would see it.

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::small::{Mat3, Vec3, add, dot, mat_mul, mat_vec, norm, scale};

/// A body-frame vector of \[P1\]'s axes (nose, up, right) in the forward-right-down axes of a
/// log's attitudes (docs/conventions.md "Logged attitudes"): `(x, z, -y)`.
pub fn body_of_paper(b: Vec3) -> Vec3 {
    [b[0], b[2], -b[1]]
}

/// The windows of `hold` consecutive readings, one per reading: the first reading of the window
/// centred on reading `c` (`c - (hold - 1) / 2`), or `None` where the window runs past either end
/// of the log or, with `times`, spans a gap: longer than `1.5 (hold - 1)` median intervals.
/// With `hold = 1` every reading is its own window.
///
/// # Panics
/// If `hold` is 0, or `times` is given with a length other than `n` (caller bugs).
pub fn windows(n: usize, times: Option<&[f64]>, hold: usize) -> Vec<Option<usize>> {
    assert!(hold >= 1, "windows: hold must be at least 1");
    if let Some(t) = times {
        assert_eq!(t.len(), n, "windows: one time per reading");
    }
    let longest = times.and_then(|t| median_interval(t).map(|dt| 1.5 * (hold - 1) as f64 * dt));
    let before = (hold - 1) / 2;
    (0..n)
        .map(|c| {
            let start = c.checked_sub(before)?;
            let last = start + hold - 1;
            if last >= n {
                return None;
            }
            match (times, longest) {
                (Some(t), Some(longest)) if t[last] - t[start] > longest => None,
                _ => Some(start),
            }
        })
        .collect()
}

/// The median of the positive intervals between successive times; `None` without any.
fn median_interval(times: &[f64]) -> Option<f64> {
    let mut dt: Vec<f64> = times
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    if dt.is_empty() {
        return None;
    }
    dt.sort_by(f64::total_cmp);
    Some(dt[dt.len() / 2])
}

/// The mean of `values[start..start + hold]`.
///
/// # Panics
/// If the window runs past the end of `values` (a caller bug).
pub fn held(values: &[Vec3], start: usize, hold: usize) -> Vec3 {
    let sum = values[start..start + hold].iter().fold([0.0; 3], |acc, v| add(acc, *v));
    scale(1.0 / hold as f64, sum)
}

/// A design attitude's realisation on a log.
#[derive(Debug, Clone, PartialEq)]
pub struct Realised {
    /// The design's sensor-frame field direction (unit).
    pub target: Vec3,
    /// The first reading of each candidate window, nearest first.
    pub starts: Vec<usize>,
    /// The angle between each candidate's direction and the target, degrees, ascending.
    pub angles_deg: Vec<f64>,
}

impl Realised {
    /// Whether no window lies within the angle asked.
    pub fn is_empty(&self) -> bool {
        self.starts.is_empty()
    }
}

/// The mean directions of the windows of `hold` readings starting at each reading (normalised;
/// `None` where the window runs past the end or its mean is zero): prefix sums, one pass.
pub fn window_directions(directions: &[Vec3], hold: usize) -> Vec<Option<Vec3>> {
    let mut prefix = Vec::with_capacity(directions.len() + 1);
    prefix.push([0.0; 3]);
    for d in directions {
        let last = *prefix.last().expect("prefix starts with zero");
        prefix.push(add(last, *d));
    }
    (0..directions.len())
        .map(|s| {
            let end = s + hold;
            if end > directions.len() {
                return None;
            }
            let sum = [0, 1, 2].map(|k| prefix[end][k] - prefix[s][k]);
            let n = norm(sum);
            (n > 0.0 && n.is_finite()).then(|| scale(1.0 / n, sum))
        })
        .collect()
}

/// The candidate windows of the design direction `target` (a unit vector): those of `windows`
/// whose mean direction (`window_directions`, indexed by a window's first reading) lies within
/// `within_deg` of it, nearest first, at most `at_most` of them.
pub fn realise(
    target: Vec3,
    windows: &[Option<usize>],
    window_directions: &[Option<Vec3>],
    within_deg: f64,
    at_most: usize,
) -> Realised {
    let cos_within = within_deg.to_radians().cos();
    let mut found: Vec<(f64, usize)> = windows
        .iter()
        .flatten()
        .filter_map(|&s| {
            let d = window_directions.get(s).copied().flatten()?;
            let c = dot(d, target).clamp(-1.0, 1.0);
            (c >= cos_within).then_some((c, s))
        })
        .collect();
    // Nearest first; ties by position, so the order does not depend on the sort's algorithm.
    found.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    found.dedup_by_key(|f| f.1);
    found.truncate(at_most);
    Realised {
        target,
        starts: found.iter().map(|f| f.1).collect(),
        angles_deg: found.iter().map(|f| f.0.acos().to_degrees()).collect(),
    }
}

/// The angle from any direction to the nearest of a log's directions, tabulated on a grid of
/// the sphere: `BANDS` equal-area bands of `z` by `2 BANDS` sectors of azimuth.
#[derive(Debug, Clone)]
pub struct CoverageMap {
    /// Per cell, the angle from its centre to the nearest direction, degrees.
    distance_deg: Vec<f64>,
}

/// Bands of the coverage grid (cells of about 1.4 degrees).
const BANDS: usize = 128;

impl CoverageMap {
    /// The map of `directions` (unit vectors; at most a few thousand suffice: the cost is one
    /// dot product per cell and direction).
    pub fn new(directions: &[Vec3]) -> Self {
        let distance_deg = (0..BANDS * 2 * BANDS)
            .map(|cell| {
                let c = cell_centre(cell);
                let best = directions.iter().map(|d| dot(*d, c)).fold(-1.0f64, f64::max);
                best.clamp(-1.0, 1.0).acos().to_degrees()
            })
            .collect();
        Self { distance_deg }
    }

    /// The angle from `u` (a unit vector) to the log's nearest direction, degrees, to within
    /// the grid's half-cell (about 1 degree).
    pub fn distance_deg(&self, u: Vec3) -> f64 {
        self.distance_deg[cell_of(u)]
    }
}

fn cell_of(u: Vec3) -> usize {
    let band = (((u[2].clamp(-1.0, 1.0) + 1.0) / 2.0 * BANDS as f64) as usize).min(BANDS - 1);
    let azimuth = u[1].atan2(u[0]).rem_euclid(std::f64::consts::TAU);
    let sector = ((azimuth / std::f64::consts::TAU * (2 * BANDS) as f64) as usize).min(2 * BANDS - 1);
    band * 2 * BANDS + sector
}

fn cell_centre(cell: usize) -> Vec3 {
    let (band, sector) = (cell / (2 * BANDS), cell % (2 * BANDS));
    let z = (band as f64 + 0.5) / BANDS as f64 * 2.0 - 1.0;
    let a = (sector as f64 + 0.5) / (2 * BANDS) as f64 * std::f64::consts::TAU;
    let r = (1.0 - z * z).sqrt();
    [r * a.cos(), r * a.sin(), z]
}

/// The rotation of the quaternion `q` normalised (`q` drawn from a normal distribution: a uniform
/// random rotation); the identity for a zero or non-finite `q`.
fn rotation_of(q: [f64; 4]) -> Mat3 {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    crate::aviation::dcm_of_quaternion(q.map(|v| v / n)).unwrap_or([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
}

/// How far a turned design lies from the log: its farthest direction's distance, then the sum.
fn misfit(r: &Mat3, targets: &[Vec3], map: &CoverageMap) -> (f64, f64) {
    targets.iter().fold((0.0f64, 0.0), |(worst, sum), t| {
        let d = map.distance_deg(mat_vec(r, *t));
        (worst.max(d), sum + d)
    })
}

/// The rotation that turns `targets` (a design's unit directions) nearest to the log's coverage
/// `map` (its farthest direction first, then their sum), and that farthest distance in degrees:
/// the identity and `starts` uniform random rotations, the best refined by random turns that
/// shrink from 10 degrees. Deterministic for the state of `rng`.
pub fn orient<R: Rng + ?Sized>(targets: &[Vec3], map: &CoverageMap, starts: usize, rng: &mut R) -> (Mat3, f64) {
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut best = (identity, misfit(&identity, targets, map));
    let mut normal = || -> f64 { StandardNormal.sample(rng) };
    for _ in 0..starts {
        let r = rotation_of([normal(), normal(), normal(), normal()]);
        let m = misfit(&r, targets, map);
        if m < best.1 {
            best = (r, m);
        }
    }
    let mut step = 10f64.to_radians();
    while step > 0.05f64.to_radians() {
        for _ in 0..200 {
            let axis = [normal(), normal(), normal()];
            let half = step * normal() / 2.0;
            let n = norm(axis);
            let q = [
                half.cos(),
                axis[0] / n * half.sin(),
                axis[1] / n * half.sin(),
                axis[2] / n * half.sin(),
            ];
            let r = mat_mul(&rotation_of(q), &best.0);
            let m = misfit(&r, targets, map);
            if m < best.1 {
                best = (r, m);
            }
        }
        step /= 2.0;
    }
    (best.0, best.1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_coverage_map_measures_angles_and_orient_turns_a_design_into_it() {
        use crate::rng::stream_rng;
        // A log covering the cap within 30 degrees of +z, densely.
        let mut cap = Vec::new();
        for i in 0..60 {
            for j in 0..60 {
                let t = (f64::from(i) / 59.0 * 30.0).to_radians();
                let a = f64::from(j) / 60.0 * std::f64::consts::TAU;
                cap.push([t.sin() * a.cos(), t.sin() * a.sin(), t.cos()]);
            }
        }
        let map = CoverageMap::new(&cap);
        // Within the cap: within a cell; outside: the angle to its rim, within a cell (1.5 deg).
        assert!(map.distance_deg([0.0, 0.0, 1.0]) < 1.5);
        let x = map.distance_deg([1.0, 0.0, 0.0]);
        assert!((x - 60.0).abs() < 1.5, "{x}");
        // Three directions 20 degrees apart around -z: all outside; turned, all inside.
        let design: Vec<Vec3> = (0..3)
            .map(|k| {
                let a = f64::from(k) * std::f64::consts::TAU / 3.0;
                let t = 20f64.to_radians();
                [t.sin() * a.cos(), t.sin() * a.sin(), -t.cos()]
            })
            .collect();
        let (r, worst) = orient(&design, &map, 2000, &mut stream_rng(1, 0));
        assert!(worst < 1.5, "{worst}");
        // A rotation: orthonormal with determinant +1 (to rounding).
        let rt_r = mat_mul(&crate::small::transpose(&r), &r);
        for (i, row) in rt_r.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((v - want).abs() < 1e-12);
            }
        }
        // The turned directions keep their angles to each other.
        let turned: Vec<Vec3> = design.iter().map(|d| mat_vec(&r, *d)).collect();
        assert!((dot(turned[0], turned[1]) - dot(design[0], design[1])).abs() < 1e-12);
    }

    #[test]
    #[allow(clippy::float_cmp)]
    fn the_paper_body_frame_maps_onto_forward_right_down() {
        // Level, nose north, at [P1]'s Changsha field (N, U, E) = (35272, -32898, -2086) nT:
        // body (nose, up, right) = (N, U, E); forward-right-down = (N, E, -U).
        // A permutation with a sign: exact.
        let b = body_of_paper([35272.0, -32898.0, -2086.0]);
        assert!(b == [35272.0, -2086.0, 32898.0], "{b:?}");
    }

    #[test]
    fn windows_are_centred_and_stop_at_the_ends_and_at_gaps() {
        assert_eq!(windows(4, None, 1), vec![Some(0), Some(1), Some(2), Some(3)]);
        assert_eq!(windows(5, None, 3), vec![None, Some(0), Some(1), Some(2), None]);
        // Even holds put the extra reading after the centre.
        assert_eq!(windows(4, None, 2), vec![Some(0), Some(1), Some(2), None]);
        // A gap of 3 intervals between readings 2 and 3: windows across it are refused
        // (longest span 1.5 x 2 intervals of 0.01 s).
        let t = [0.0, 0.01, 0.02, 0.05, 0.06, 0.07];
        assert_eq!(windows(6, Some(&t), 3), vec![None, Some(0), None, None, Some(3), None]);
    }

    #[test]
    #[allow(clippy::float_cmp)]
    fn a_held_reading_is_the_mean_of_its_window() {
        let v = [[1.0, 2.0, 3.0], [3.0, 2.0, 1.0], [5.0, 5.0, 5.0]];
        // Sums of small integers halved: exact.
        let (a, b) = (held(&v, 0, 2), held(&v, 1, 2));
        assert!(a == [2.0, 2.0, 2.0] && b == [4.0, 3.5, 3.0], "{a:?} {b:?}");
    }

    #[test]
    fn candidates_lie_within_the_angle_nearest_first() {
        // Directions at 0, 1, ..., 9 degrees from x in the x-y plane.
        let dirs: Vec<Vec3> = (0..10)
            .map(|i| {
                let a = f64::from(i).to_radians();
                [a.cos(), a.sin(), 0.0]
            })
            .collect();
        let w = windows(dirs.len(), None, 1);
        let wd = window_directions(&dirs, 1);
        let target = [4.2f64.to_radians().cos(), 4.2f64.to_radians().sin(), 0.0];
        let r = realise(target, &w, &wd, 2.0, 100);
        assert_eq!(r.starts, vec![4, 5, 3, 6]);
        for (a, want) in r.angles_deg.iter().zip([0.2, 0.8, 1.2, 1.8]) {
            assert!((a - want).abs() < 1e-9, "{:?}", r.angles_deg);
        }
        assert_eq!(realise(target, &w, &wd, 2.0, 2).starts, vec![4, 5]);
        assert!(realise([0.0, 0.0, 1.0], &w, &wd, 5.0, 100).is_empty());
        // Windows of 3: the mean direction of readings 3, 4, 5 is at 4 degrees.
        let w3 = windows(dirs.len(), None, 3);
        let wd3 = window_directions(&dirs, 3);
        let r3 = realise(target, &w3, &wd3, 0.5, 100);
        assert_eq!(r3.starts, vec![3]);
        assert!((r3.angles_deg[0] - 0.2).abs() < 1e-9);
    }
}
