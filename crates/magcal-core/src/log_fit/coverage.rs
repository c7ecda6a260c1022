//! Coverage heuristics of calibrated field directions: MotionCal's surface gaps and MicroStrain's
//! spatial coverage.

use rayon::prelude::*;

use crate::chunked::CHUNK;
use crate::small::{Vec3, norm};

/// MotionCal's surface-gap error of calibrated field directions, in percent of the sphere: the
/// sphere cut into 100 regions of equal area (two polar caps above 78.52 degrees of latitude, two
/// bands of 15 regions to 42.84 degrees, two of 34 about the equator: the boundaries where
/// `sin(latitude)` is 0.98 and 0.68), and each region adds 1 with no direction in it, 0.2 with one,
/// 0.01 with two (PJRC MotionCal, `quality.c`). 0 is full coverage, 100 none. Latitude is taken
/// from the third component.
pub fn motioncal_gaps(fields: &[Vec3]) -> f64 {
    gaps_of(&motioncal_region_counts(fields))
}

/// [`motioncal_gaps`] of the region counts.
fn gaps_of(counts: &[usize; 100]) -> f64 {
    counts
        .iter()
        .map(|&c| match c {
            0 => 1.0,
            1 => 0.2,
            2 => 0.01,
            _ => 0.0,
        })
        .sum()
}

/// MicroStrain's spatial coverage, in percent: the sphere of directions cut into 18 bands of 10
/// degrees of latitude and 32 sectors of 11.25 degrees of longitude (latitude `asin` of the third
/// component, longitude `atan2` of the second and first), and the share of those 576 bins that
/// hold at least one direction (MicroStrain by HBK, `microstrain_mag_cal`,
/// `calculateSpatialCoverage`, MIT). The bins have equal angles, not equal areas: a polar bin is
/// 11 times smaller than an equatorial one, so even uniform directions need many readings to
/// fill them. MicroStrain calls more than 70 % good. Their tool bins the raw readings less their
/// mean; magcal bins the calibrated field directions, as it does for [`motioncal_gaps`].
pub fn microstrain_coverage_percent(fields: &[Vec3]) -> f64 {
    tally(fields, |b| b).microstrain_percent()
}

/// [`motioncal_gaps`] and [`microstrain_coverage_percent`] of `map` applied to every one of
/// `readings` (a calibration), in one pass on every core, without holding the mapped directions:
/// the same numbers as the two of the mapped readings.
pub fn coverages(readings: &[Vec3], map: impl Fn(Vec3) -> Vec3 + Sync) -> (f64, f64) {
    let t = tally(readings, map);
    (gaps_of(&t.regions), t.microstrain_percent())
}

const LATITUDE_BINS: usize = 18;
const LONGITUDE_BINS: usize = 32;
const MICROSTRAIN_BINS: usize = LATITUDE_BINS * LONGITUDE_BINS;

/// The directions per MotionCal region and the MicroStrain bins that hold one.
struct Tally {
    regions: [usize; 100],
    occupied: [bool; MICROSTRAIN_BINS],
}

impl Tally {
    fn microstrain_percent(&self) -> f64 {
        100.0 * self.occupied.iter().filter(|&&o| o).count() as f64 / MICROSTRAIN_BINS as f64
    }
}

/// The [`Tally`] of `map` applied to each of `readings`: each chunk of [`CHUNK`] on its own, then
/// counts added and bins joined (in any order: the same result).
fn tally(readings: &[Vec3], map: impl Fn(Vec3) -> Vec3 + Sync) -> Tally {
    let empty = || Tally {
        regions: [0; 100],
        occupied: [false; MICROSTRAIN_BINS],
    };
    readings
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut t = empty();
            for &r in chunk {
                if let Some((region, bin)) = bins(map(r)) {
                    t.regions[region] += 1;
                    t.occupied[bin] = true;
                }
            }
            t
        })
        .reduce(empty, |a, b| Tally {
            regions: std::array::from_fn(|i| a.regions[i] + b.regions[i]),
            occupied: std::array::from_fn(|i| a.occupied[i] || b.occupied[i]),
        })
}

/// The MotionCal region and the MicroStrain bin of the direction of `b`; `None` for a zero or
/// non-finite vector.
fn bins(b: Vec3) -> Option<(usize, usize)> {
    let n = norm(b);
    if !(n > 0.0 && n.is_finite()) {
        return None;
    }
    let longitude = b[1].atan2(b[0]);
    let sin_latitude = b[2] / n;
    let turn = (longitude / std::f64::consts::TAU).rem_euclid(1.0);
    let band = |regions: usize| ((turn * regions as f64) as usize).min(regions - 1);
    let region = if sin_latitude > 0.98 {
        0
    } else if sin_latitude < -0.98 {
        99
    } else if sin_latitude > 0.68 {
        1 + band(15)
    } else if sin_latitude < -0.68 {
        84 + band(15)
    } else if sin_latitude >= 0.0 {
        16 + band(34)
    } else {
        50 + band(34)
    };
    let latitude = sin_latitude.clamp(-1.0, 1.0).asin();
    let bin = |angle: f64, half_range: f64, bins: usize| {
        (((angle + half_range) / (2.0 * half_range) * bins as f64) as usize).min(bins - 1)
    };
    let i = bin(latitude, std::f64::consts::FRAC_PI_2, LATITUDE_BINS);
    let j = bin(longitude, std::f64::consts::PI, LONGITUDE_BINS);
    Some((region, i * LONGITUDE_BINS + j))
}

/// One of the 100 regions of [`motioncal_gaps`]: the bounds of `sin(latitude)` (third component)
/// and of the longitude as a fraction of a turn from the first axis towards the second.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MotionCalRegion {
    /// Lower and upper `sin(latitude)`.
    pub sin_latitude: [f64; 2],
    /// First and last longitude, fractions of a turn in `[0, 1]`.
    pub turn: [f64; 2],
}

/// The bounds of region `index` (0 to 99, numbered as [`motioncal_region_counts`] counts them).
///
/// # Panics
/// If `index` is 100 or more (a caller bug).
pub fn motioncal_region(index: usize) -> MotionCalRegion {
    assert!(index < 100, "motioncal_region: index {index} of 100 regions");
    // (first index, regions in the band, sin(latitude) from, to), north to south.
    const BANDS: [(usize, usize, f64, f64); 6] = [
        (0, 1, 0.98, 1.0),
        (1, 15, 0.68, 0.98),
        (16, 34, 0.0, 0.68),
        (50, 34, -0.68, 0.0),
        (84, 15, -0.98, -0.68),
        (99, 1, -1.0, -0.98),
    ];
    let &(first, regions, lo, hi) = BANDS.iter().rev().find(|b| b.0 <= index).expect("band 0 starts at 0");
    let k = (index - first) as f64;
    MotionCalRegion {
        sin_latitude: [lo, hi],
        turn: [k / regions as f64, (k + 1.0) / regions as f64],
    }
}

/// Directions per region of the 100 equal-area regions of [`motioncal_gaps`] (region 0 the north
/// cap, 1-15 the northern band, 16-49 and 50-83 the equatorial bands, 84-98 the southern band, 99
/// the south cap; see [`motioncal_region`]).
pub fn motioncal_region_counts(fields: &[Vec3]) -> [usize; 100] {
    tally(fields, |b| b).regions
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::stream_rng;

    #[test]
    fn every_region_holds_its_own_centre_and_the_regions_have_equal_area() {
        for index in 0..100 {
            let r = motioncal_region(index);
            let s = (r.sin_latitude[0] + r.sin_latitude[1]) / 2.0;
            let lon = std::f64::consts::TAU * (r.turn[0] + r.turn[1]) / 2.0;
            let c = (1.0 - s * s).sqrt();
            let counts = motioncal_region_counts(&[[c * lon.cos(), c * lon.sin(), s]]);
            assert_eq!(counts[index], 1, "region {index}: {r:?}");
            // Area on the unit sphere: 2 pi (delta sin latitude) (delta turn) = 4 pi / 100.
            let area = std::f64::consts::TAU * (r.sin_latitude[1] - r.sin_latitude[0]) * (r.turn[1] - r.turn[0]);
            let equal = 4.0 * std::f64::consts::PI / 100.0;
            // 0.02 / 1 = 0.30 / 15 = 0.68 / 34: equal to rounding.
            assert!(
                (area / equal - 1.0).abs() < 1e-12,
                "region {index}: area {area} against {equal}"
            );
        }
    }

    #[test]
    fn motioncal_gaps_count_empty_regions_of_equal_area() {
        assert!((motioncal_gaps(&[]) - 100.0).abs() < 1e-12);
        // One direction per region (centres of the bands): 20 % of the sphere's error left.
        let mut one = Vec::new();
        for (lat_sin, regions) in [(0.99, 1), (0.83, 15), (0.34, 34), (-0.34, 34), (-0.83, 15), (-0.99, 1)] {
            let lat: f64 = f64::asin(lat_sin);
            for k in 0..regions {
                let lon = std::f64::consts::TAU * (k as f64 + 0.5) / regions as f64;
                one.push([lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin()]);
            }
        }
        assert_eq!(one.len(), 100);
        assert!((motioncal_gaps(&one) - 20.0).abs() < 1e-9, "{}", motioncal_gaps(&one));
        let three: Vec<Vec3> = one.iter().flat_map(|d| [*d; 3]).collect();
        assert!(motioncal_gaps(&three).abs() < 1e-12);
        // Equal area: 20,000 uniform directions leave no region empty.
        let mut rng = stream_rng(8, 0);
        let uniform: Vec<Vec3> = (0..20_000)
            .map(|_| {
                use rand::RngExt;
                let z: f64 = rng.random_range(-1.0..1.0);
                let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                [(1.0 - z * z).sqrt() * a.cos(), (1.0 - z * z).sqrt() * a.sin(), z]
            })
            .collect();
        assert!(motioncal_gaps(&uniform).abs() < 1e-12);
    }

    #[test]
    fn microstrain_coverage_counts_equal_angle_bins() {
        assert!(microstrain_coverage_percent(&[]).abs() < 1e-12);
        // The centre of every one of the 18 x 32 bins: all 576 occupied; half of them: 50 %.
        let centres: Vec<Vec3> = (0..18)
            .flat_map(|i| {
                (0..32).map(move |j| {
                    let lat = (-90.0 + 10.0 * (i as f64 + 0.5)).to_radians();
                    let lon = (-180.0 + 11.25 * (j as f64 + 0.5)).to_radians();
                    // Any length: only the direction counts.
                    [
                        7.0 * lat.cos() * lon.cos(),
                        7.0 * lat.cos() * lon.sin(),
                        7.0 * lat.sin(),
                    ]
                })
            })
            .collect();
        assert!((microstrain_coverage_percent(&centres) - 100.0).abs() < 1e-12);
        assert!((microstrain_coverage_percent(&centres[..288]) - 50.0).abs() < 1e-12);
        // The poles and the seam at 180 degrees of longitude fall in the last bins, not beyond.
        let edges = [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [-1.0, -0.0, 0.0]];
        assert!((microstrain_coverage_percent(&edges) - 400.0 / 576.0).abs() < 1e-12);
        // Zero, NaN and infinite vectors have no direction and are not counted.
        let bad = [[0.0; 3], [f64::NAN, 0.0, 1.0], [f64::INFINITY, 0.0, 0.0]];
        assert!(microstrain_coverage_percent(&bad).abs() < 1e-12);
        // Equal angles, not equal areas: a yaw-only log at level attitude (directions on one
        // cone of latitude) fills one band of 32, 1/18 of the bins.
        let ring: Vec<Vec3> = (0..360)
            .map(|k| {
                let a = (k as f64).to_radians();
                [0.6 * a.cos(), 0.6 * a.sin(), 0.8]
            })
            .collect();
        assert!((microstrain_coverage_percent(&ring) - 100.0 / 18.0).abs() < 1e-12);
    }

    /// The one-pass coverages of mapped readings are the two measures of the mapped directions,
    /// on more readings than a chunk, bits and all.
    #[test]
    fn coverages_of_a_map_are_those_of_the_mapped_directions() {
        use rand::RngExt;
        let mut rng = stream_rng(35, 1);
        let raw: Vec<Vec3> = (0..3 * CHUNK + 11)
            .map(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)))
            .collect();
        let map = |r: Vec3| [2.0 * r[0] - 0.3, r[1] + 0.5 * r[2], 0.7 * r[2] - 0.2];
        let mapped: Vec<Vec3> = raw.iter().map(|&r| map(r)).collect();
        let (gaps, percent) = coverages(&raw, map);
        assert_eq!(gaps.to_bits(), motioncal_gaps(&mapped).to_bits());
        assert_eq!(percent.to_bits(), microstrain_coverage_percent(&mapped).to_bits());
        assert!(percent > 50.0 && percent < 100.0, "{percent}");
    }
}
