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
use rayon::prelude::*;

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

/// A log's windows with a direction ([`windows`], [`window_directions`]), sorted by the
/// direction's `z`, so that [`realise`] looks only at the band of `z` its cone can reach.
#[derive(Debug, Clone)]
pub struct WindowIndex {
    /// Per window, in increasing `z` (ties in the order of `windows`): `z`, direction, start.
    z: Vec<f64>,
    direction: Vec<Vec3>,
    start: Vec<usize>,
    /// Every direction is a unit vector to rounding (1e-12): the band of `z` holds every window
    /// of a cone. Otherwise [`realise`] looks at every window.
    unit: bool,
}

impl WindowIndex {
    /// The windows `windows` (a window's first reading, [`windows`]) whose direction
    /// `window_directions[start]` is given.
    pub fn new(windows: &[Option<usize>], window_directions: &[Option<Vec3>]) -> Self {
        let mut entries: Vec<(Vec3, usize)> = windows
            .iter()
            .flatten()
            .filter_map(|&s| Some((window_directions.get(s).copied().flatten()?, s)))
            .collect();
        entries.sort_by(|a, b| a.0[2].total_cmp(&b.0[2]));
        let unit = entries.iter().all(|(d, _)| (dot(*d, *d) - 1.0).abs() <= 1e-12);
        Self {
            z: entries.iter().map(|e| e.0[2]).collect(),
            direction: entries.iter().map(|e| e.0).collect(),
            start: entries.iter().map(|e| e.1).collect(),
            unit,
        }
    }

    /// The range of positions whose `z` a direction within `within_deg` of `target` can have:
    /// its polar angle is within that of `target`'s, widened by 1e-6 rad for rounding. Every
    /// position where the cone is too narrow for that margin or `target` is not a unit vector.
    fn band(&self, target: Vec3, within_deg: f64) -> std::ops::Range<usize> {
        let alpha = within_deg.to_radians();
        let length = dot(target, target);
        if !(self.unit && (length - 1.0).abs() <= 1e-12 && (1e-4..std::f64::consts::PI).contains(&alpha)) {
            return 0..self.z.len();
        }
        let polar = target[2].clamp(-1.0, 1.0).acos();
        let widened = alpha + 1e-6;
        let lo = (polar + widened).min(std::f64::consts::PI).cos() - 1e-12;
        let hi = (polar - widened).max(0.0).cos() + 1e-12;
        self.z.partition_point(|&z| z < lo)..self.z.partition_point(|&z| z <= hi)
    }
}

/// The candidate windows of the design direction `target` (a unit vector): the windows of
/// `index` whose mean direction lies within `within_deg` of it, nearest first, at most
/// `at_most` of them.
pub fn realise(target: Vec3, index: &WindowIndex, within_deg: f64, at_most: usize) -> Realised {
    let cos_within = within_deg.to_radians().cos();
    let mut found: Vec<(f64, usize)> = index
        .band(target, within_deg)
        .filter_map(|k| {
            let c = dot(index.direction[k], target).clamp(-1.0, 1.0);
            (c >= cos_within).then_some((c, index.start[k]))
        })
        .collect();
    // Nearest first; ties by position, so the order depends neither on the sort's algorithm
    // nor on the index's.
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
            .into_par_iter()
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
    band * 2 * BANDS + sector_of(u[1], u[0])
}

/// The sector of the azimuth `atan2(y, x)` (counter-clockwise from `+x`, in `[0, 2 pi)`): of
/// `2 BANDS` equal sectors, the one [`sector_by_atan2`] gives, always.
///
/// # Deviation from the obvious code
/// [`sector_by_atan2`] costs a correctly rounded `atan2` (26 ns here), and `orient` looks up a
/// cell millions of times per replay (`misfit_below`: a quarter of `replay`'s CPU on BROAD trial 02).
/// The sector needs only the azimuth's integer part: a polynomial `atan` (error below 3e-7 rad,
/// 1.1e-5 of a sector) gives it wherever the azimuth lies farther than [`SECTOR_MARGIN`] of a
/// sector from a boundary, and [`sector_by_atan2`] decides the rest (about one lookup in 5,000).
/// No crate offers an `f64` `atan` of bounded error cheaper than `std`'s (`libm::atan2`: 30 ns).
fn sector_of(y: f64, x: f64) -> usize {
    const SECTORS: f64 = (2 * BANDS) as f64;
    let (ax, ay) = (x.abs(), y.abs());
    let (small, large) = if ay <= ax { (ay, ax) } else { (ax, ay) };
    if !(large > 0.0 && large.is_finite()) {
        return sector_by_atan2(y, x);
    }
    let mut azimuth = atan_on_unit(small / large);
    if ay > ax {
        azimuth = std::f64::consts::FRAC_PI_2 - azimuth;
    }
    if x < 0.0 {
        azimuth = std::f64::consts::PI - azimuth;
    }
    if y < 0.0 {
        azimuth = std::f64::consts::TAU - azimuth;
    }
    let s = azimuth / std::f64::consts::TAU * SECTORS;
    let within = s - s.floor();
    // A NaN azimuth is in no range: `atan2` decides it too.
    if !(SECTOR_MARGIN..=1.0 - SECTOR_MARGIN).contains(&within) {
        return sector_by_atan2(y, x);
    }
    (s as usize).min(2 * BANDS - 1)
}

/// `atan(t)` for `t` in `[0, 1]` to within 2.7e-7 rad: `t P(t^2)`, `P` of degree 6 fitted by
/// least squares on 20,000 Chebyshev nodes (its largest error on a grid of 400,001 points: test
/// `sectors_are_those_of_atan2`).
#[inline]
fn atan_on_unit(t: f64) -> f64 {
    const P: [f64; 7] = [
        0.999_996_634_700_673_1,
        -0.333_183_028_994_467_06,
        0.198_132_135_090_681_42,
        -0.132_475_227_716_275_3,
        0.079_811_204_956_175_23,
        -0.033_725_938_104_144_385,
        0.006_842_624_897_568_442,
    ];
    let t2 = t * t;
    t * P.iter().rev().fold(0.0, |acc, &c| acc * t2 + c)
}

/// How near a sector's boundary (a share of a sector) [`sector_of`] leaves the decision to
/// `atan2`: nine times the polynomial's error.
const SECTOR_MARGIN: f64 = 1e-4;

/// The sector of the azimuth `atan2(y, x)`, by `atan2`: the definition of the coverage grid.
fn sector_by_atan2(y: f64, x: f64) -> usize {
    let azimuth = y.atan2(x).rem_euclid(std::f64::consts::TAU);
    ((azimuth / std::f64::consts::TAU * (2 * BANDS) as f64) as usize).min(2 * BANDS - 1)
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
/// `None` as soon as a direction lies farther than `bound`'s farthest: the misfit is then not
/// below `bound` (the sum only grows), and most of `orient`'s tries end after a few lookups.
fn misfit_below(r: &Mat3, targets: &[Vec3], map: &CoverageMap, bound: (f64, f64)) -> Option<(f64, f64)> {
    let mut misfit = (0.0f64, 0.0);
    for t in targets {
        let d = map.distance_deg(mat_vec(r, *t));
        if d > bound.0 {
            return None;
        }
        misfit = (misfit.0.max(d), misfit.1 + d);
    }
    (misfit < bound).then_some(misfit)
}

/// The rotation that turns `targets` (a design's unit directions) nearest to the log's coverage
/// `map` (its farthest direction first, then their sum), and that farthest distance in degrees:
/// the identity and `starts` uniform random rotations, the best refined by random turns that
/// shrink from 10 degrees. Deterministic for the state of `rng`.
pub fn orient<R: Rng + ?Sized>(targets: &[Vec3], map: &CoverageMap, starts: usize, rng: &mut R) -> (Mat3, f64) {
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut best = (
        identity,
        misfit_below(&identity, targets, map, (f64::INFINITY, f64::INFINITY)).unwrap_or((f64::INFINITY, f64::INFINITY)),
    );
    let mut normal = || -> f64 { StandardNormal.sample(rng) };
    for _ in 0..starts {
        let r = rotation_of([normal(), normal(), normal(), normal()]);
        if let Some(m) = misfit_below(&r, targets, map, best.1) {
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
            if let Some(m) = misfit_below(&r, targets, map, best.1) {
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
    fn sectors_are_those_of_atan2() {
        use rand::RngExt;
        let mut rng = crate::rng::stream_rng(7, 0);
        let mut checked = 0;
        let mut check = |y: f64, x: f64| {
            assert_eq!(sector_of(y, x), sector_by_atan2(y, x), "y {y:e}, x {x:e}");
            checked += 1;
        };
        // Random directions, their scales spanning the range a lookup meets.
        for _ in 0..1_000_000 {
            let a = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
            let r = 10f64.powf(rng.random_range(-3.0..1.0));
            check(r * a.sin(), r * a.cos());
        }
        // Every boundary, one ulp either side, and the axes with both zeros' signs.
        for k in 0..2 * BANDS {
            let a = k as f64 * std::f64::consts::TAU / (2 * BANDS) as f64;
            for a in [
                a,
                f64::from_bits(a.to_bits() + 1),
                f64::from_bits(a.to_bits().saturating_sub(1)),
            ] {
                check(a.sin(), a.cos());
            }
        }
        for (y, x) in [
            (0.0, 1.0),
            (-0.0, 1.0),
            (0.0, -1.0),
            (-0.0, -1.0),
            (1.0, 0.0),
            (-1.0, -0.0),
            (0.0, 0.0),
        ] {
            check(y, x);
        }
        check(f64::NAN, 1.0);
        check(1e-300, -1.0);
        check(-1e-300, 1.0);
        assert_eq!(checked, 1_000_000 + 3 * 2 * BANDS + 10);
        // The polynomial's largest error, on a fine grid of [0, 1]: within the margin's ninth.
        let worst = (0..=400_000)
            .map(|i| {
                let t = f64::from(i) / 400_000.0;
                (atan_on_unit(t) - t.atan()).abs()
            })
            .fold(0.0f64, f64::max);
        let margin_rad = SECTOR_MARGIN * std::f64::consts::TAU / (2 * BANDS) as f64;
        assert!(worst < 2.7e-7 && worst < margin_rad / 9.0, "{worst:e}");
        assert!(worst > 2.6e-7, "{worst:e}");
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
        let index = WindowIndex::new(&windows(dirs.len(), None, 1), &window_directions(&dirs, 1));
        let target = [4.2f64.to_radians().cos(), 4.2f64.to_radians().sin(), 0.0];
        let r = realise(target, &index, 2.0, 100);
        assert_eq!(r.starts, vec![4, 5, 3, 6]);
        for (a, want) in r.angles_deg.iter().zip([0.2, 0.8, 1.2, 1.8]) {
            assert!((a - want).abs() < 1e-9, "{:?}", r.angles_deg);
        }
        assert_eq!(realise(target, &index, 2.0, 2).starts, vec![4, 5]);
        assert!(realise([0.0, 0.0, 1.0], &index, 5.0, 100).is_empty());
        // Windows of 3: the mean direction of readings 3, 4, 5 is at 4 degrees.
        let index3 = WindowIndex::new(&windows(dirs.len(), None, 3), &window_directions(&dirs, 3));
        let r3 = realise(target, &index3, 0.5, 100);
        assert_eq!(r3.starts, vec![3]);
        assert!((r3.angles_deg[0] - 0.2).abs() < 1e-9);
    }

    #[test]
    fn the_index_finds_what_a_scan_of_every_window_finds() {
        use rand::RngExt;
        let mut rng = crate::rng::stream_rng(11, 0);
        let mut unit = || {
            let v: Vec3 = [0; 3].map(|_| StandardNormal.sample(&mut rng));
            scale(1.0 / norm(v), v)
        };
        // Directions crowded about the poles and the equator, as slow rotations leave them.
        let mut dirs: Vec<Vec3> = Vec::with_capacity(20_000);
        for i in 0..20_000 {
            let d = match i % 4 {
                0 => [0.0, 0.0, 1.0],
                1 => [1.0, 0.0, 0.0],
                _ => unit(),
            };
            let v = add(d, scale(0.05, unit()));
            dirs.push(scale(1.0 / norm(v), v));
        }
        let w = windows(dirs.len(), None, 3);
        let wd = window_directions(&dirs, 3);
        let index = WindowIndex::new(&w, &wd);
        assert!(index.unit && index.z.len() == dirs.len() - 2);
        let mut scan_rng = crate::rng::stream_rng(12, 0);
        let mut found = 0;
        for k in 0..400 {
            let target = if k % 10 == 0 {
                [0.0, 0.0, if k % 20 == 0 { 1.0 } else { -1.0 }]
            } else {
                unit()
            };
            let within = [1e-3, 0.5, 3.0, 10.0, 45.0, 89.9][k % 6];
            let at_most = scan_rng.random_range(1..200);
            let cos_within = f64::to_radians(within).cos();
            let mut all: Vec<(f64, usize)> = w
                .iter()
                .flatten()
                .filter_map(|&s| {
                    let c = dot(wd[s]?, target).clamp(-1.0, 1.0);
                    (c >= cos_within).then_some((c, s))
                })
                .collect();
            all.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            all.truncate(at_most);
            let r = realise(target, &index, within, at_most);
            assert_eq!(
                r.starts,
                all.iter().map(|a| a.1).collect::<Vec<_>>(),
                "target {target:?}, {within} deg"
            );
            found += r.starts.len();
        }
        assert!(found > 10_000, "{found}");
    }
}
