//! The attitudes a log visited, in the vehicle's terms: roll (right side down), pitch (nose up)
//! and heading (clockwise from north), against the vehicle's box.

use magcal_core::aviation::roll_pitch_heading_deg;
use magcal_core::small::Mat3;
use magcal_core::{Attitude, AttitudeBox};
use serde::{Deserialize, Serialize};

/// Heading sectors of the coverage table.
pub const SECTORS: usize = 12;
/// Width of a heading sector, degrees.
pub const SECTOR_DEG: f64 = 360.0 / SECTORS as f64;

/// What the log's attitudes visited.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Flown {
    /// Readings with an attitude.
    pub with_attitude: usize,
    /// Roll, degrees: minimum, 5th percentile, median, 95th percentile, maximum.
    pub roll_deg: [f64; 5],
    /// Pitch, degrees, as `roll_deg`.
    pub pitch_deg: [f64; 5],
    /// Readings per heading sector of [`SECTOR_DEG`] degrees, the first from 0 (north).
    pub heading_sectors: Vec<usize>,
    /// Readings whose attitude lies inside the vehicle's box, where one is given.
    pub in_box: Option<usize>,
    /// The vehicle's box in the same terms, where one is given.
    #[serde(default)]
    pub box_deg: Option<BoxDeg>,
}

/// A vehicle's box in the terms of [`Flown`], degrees: roll and pitch `[min, max]`, and the
/// headings from `heading_deg[0]` clockwise to `heading_deg[1]` (`[0, 360]` for every heading;
/// the second may exceed 360 where the range crosses north).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BoxDeg {
    pub roll_deg: [f64; 2],
    pub pitch_deg: [f64; 2],
    pub heading_deg: [f64; 2],
}

impl BoxDeg {
    /// Whether `[roll, pitch, heading]` degrees lies inside (within [`EDGE_DEG`]): the same test as
    /// the box's own in yaw terms ([`Bounds::contains`]).
    pub fn contains(&self, [roll, pitch, heading]: [f64; 3]) -> bool {
        let within = |v: f64, [min, max]: [f64; 2]| v >= min - EDGE_DEG && v <= max + EDGE_DEG;
        let [h0, h1] = self.heading_deg;
        let h = h0 + (heading - h0).rem_euclid(360.0);
        let heading_in = h1 - h0 >= 360.0 - EDGE_DEG || h <= h1 + EDGE_DEG || (h0 + 360.0 - h) <= EDGE_DEG;
        within(roll, self.roll_deg) && within(pitch, self.pitch_deg) && heading_in
    }
}

/// The vehicle's box as the coverage reads it: \[P1\]'s box, and the yaw offset that turns a
/// heading into its yaw.
#[derive(Debug, Clone, Copy)]
pub struct Bounds<'a> {
    pub bounds: &'a AttitudeBox,
    pub yaw_offset_deg: f64,
}

/// How far outside the box an attitude may lie and still count as inside, degrees: the precision
/// to which `magcal` writes angles, so that a design's attitude on the box's edge, written and
/// read back, is inside.
pub const EDGE_DEG: f64 = 1e-6;

impl Bounds<'_> {
    /// Whether a vehicle at `(roll, pitch, heading)` degrees is inside the box (within
    /// [`EDGE_DEG`]).
    pub fn contains(&self, [roll, pitch, heading]: [f64; 3]) -> bool {
        // docs/conventions.md "Sense of the angles": heading = -(yaw + yaw offset).
        let yaw = -heading - self.yaw_offset_deg;
        let a = Attitude {
            roll: roll.to_radians(),
            yaw: yaw.to_radians(),
            pitch: pitch.to_radians(),
        };
        let b = self.bounds;
        let off = [
            (a.roll - b.roll.confine(a.roll)).abs(),
            (a.pitch - b.pitch.confine(a.pitch)).abs(),
            yaw_off(a.yaw, b.yaw.min(), b.yaw.max()),
        ];
        off.iter().all(|o| *o <= EDGE_DEG.to_radians())
    }
}

impl Bounds<'_> {
    /// The box in degrees, its yaws turned into headings (docs/conventions.md "Sense of the
    /// angles": heading = -(yaw + yaw offset)).
    pub fn degrees(&self) -> BoxDeg {
        let b = self.bounds;
        let range = |min: f64, max: f64| [min.to_degrees(), max.to_degrees()];
        let (ymin, ymax) = (b.yaw.min().to_degrees(), b.yaw.max().to_degrees());
        let heading_deg = if ymax - ymin >= 360.0 - EDGE_DEG {
            [0.0, 360.0]
        } else {
            let start = (-ymax - self.yaw_offset_deg).rem_euclid(360.0);
            [start, start + (ymax - ymin)]
        };
        BoxDeg {
            roll_deg: range(b.roll.min(), b.roll.max()),
            pitch_deg: range(b.pitch.min(), b.pitch.max()),
            heading_deg,
        }
    }
}

/// How far the yaw `y` lies outside `[min, max]` around the circle, radians (0 inside).
fn yaw_off(y: f64, min: f64, max: f64) -> f64 {
    use std::f64::consts::TAU;
    let y = min + (y - min).rem_euclid(TAU);
    if y <= max { 0.0 } else { (y - max).min(min + TAU - y) }
}

/// The five-number summary of `v` (not empty): minimum, 5th percentile, median, 95th percentile
/// and maximum, the percentiles by linear interpolation between order statistics.
fn spread(v: &mut [f64]) -> [f64; 5] {
    v.sort_by(f64::total_cmp);
    let at = |q: f64| {
        let x = q * (v.len() - 1) as f64;
        let (i, f) = (x.floor() as usize, x.fract());
        if i + 1 < v.len() {
            v[i] + f * (v[i + 1] - v[i])
        } else {
            v[i]
        }
    };
    [v[0], at(0.05), at(0.5), at(0.95), v[v.len() - 1]]
}

/// What `attitudes` (NED convention) visited; `None` when no reading has one.
pub fn flown(attitudes: &[Option<Mat3>], bounds: Option<Bounds>) -> Option<Flown> {
    let angles: Vec<[f64; 3]> = attitudes.iter().flatten().map(roll_pitch_heading_deg).collect();
    if angles.is_empty() {
        return None;
    }
    let mut sectors = vec![0; SECTORS];
    for a in &angles {
        sectors[((a[2] / SECTOR_DEG) as usize).min(SECTORS - 1)] += 1;
    }
    let mut roll: Vec<f64> = angles.iter().map(|a| a[0]).collect();
    let mut pitch: Vec<f64> = angles.iter().map(|a| a[1]).collect();
    Some(Flown {
        with_attitude: angles.len(),
        roll_deg: spread(&mut roll),
        pitch_deg: spread(&mut pitch),
        heading_sectors: sectors,
        in_box: bounds.map(|b| angles.iter().filter(|a| b.contains(**a)).count()),
        box_deg: bounds.map(|b| b.degrees()),
    })
}

/// The largest heading standard error a usable calibration of an ordinary flight may leave,
/// degrees: the bias's largest standard error against the horizontal field. A compass's heading
/// is what a flight needs it for; an autopilot's own checks (ArduPilot's compass consistency)
/// work in degrees of that order.
pub const MAX_HEADING_STD_DEG: f64 = 1.0;

/// The headings never flown in words: `120 to 300, 330 to 90, 30 to 360`.
pub fn never_flown_words(runs: &[[f64; 2]]) -> String {
    runs.iter()
        .map(|[a, b]| format!("{a:.0} to {:.0}", if *b > 360.0 { b - 360.0 } else { *b }))
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use magcal_core::aviation::dcm_of_euler;

    #[test]
    fn the_spread_and_sectors_count_what_was_flown() {
        // Roll 0..=10, pitch -5..=5, headings 5, 41, ..., 365 (= 5).
        let attitudes: Vec<Option<Mat3>> = (0..=10)
            .map(|i| {
                let i = f64::from(i);
                Some(dcm_of_euler(
                    i.to_radians(),
                    (i - 5.0).to_radians(),
                    (36.0 * i + 5.0).to_radians(),
                ))
            })
            .chain([None])
            .collect();
        let bounds = AttitudeBox::from_degrees([-5.0, 5.0], [-180.0, 180.0], [-20.0, 20.0]).unwrap();
        let f = flown(
            &attitudes,
            Some(Bounds {
                bounds: &bounds,
                yaw_offset_deg: 0.0,
            }),
        )
        .unwrap();
        assert_eq!(f.with_attitude, 11);
        let want_roll = [0.0, 0.5, 5.0, 9.5, 10.0];
        for (a, b) in f.roll_deg.iter().zip(want_roll) {
            assert!((a - b).abs() < 1e-9, "{:?}", f.roll_deg);
        }
        assert!((f.pitch_deg[2]).abs() < 1e-9 && (f.pitch_deg[4] - 5.0).abs() < 1e-9);
        // Headings 5, 41, 77, ..., 329, 5: sectors of 30 degrees.
        assert_eq!(f.heading_sectors, [2, 1, 1, 1, 1, 0, 1, 1, 1, 1, 1, 0]);
        // Roll within 5 degrees: the first six.
        assert_eq!(f.in_box, Some(6));
        assert!(flown(&[None, None], None).is_none());
    }

    #[test]
    fn a_heading_range_is_the_boxs_yaw_range_turned_by_the_offset() {
        // Yaw [0, 90] with an offset of 90: headings -(yaw + 90) in [-180, -90] = [180, 270].
        let bounds = AttitudeBox::from_degrees([-5.0, 5.0], [0.0, 90.0], [-5.0, 5.0]).unwrap();
        let b = Bounds {
            bounds: &bounds,
            yaw_offset_deg: 90.0,
        };
        assert!(b.contains([0.0, 0.0, 200.0]));
        assert!(b.contains([0.0, 0.0, 269.0]));
        assert!(!b.contains([0.0, 0.0, 100.0]));
        assert!(!b.contains([0.0, 6.0, 200.0]));
        // On the edge, written to 1e-9 degree and read back: inside; 1e-5 degree out: outside.
        assert!(b.contains([5.000_000_001, -5.000_000_001, 270.000_000_001]));
        assert!(!b.contains([5.000_01, 0.0, 200.0]));
        // The same range in degrees: from 180 clockwise to 270; the roll and pitch as given.
        let d = b.degrees();
        assert_eq!((d.roll_deg, d.pitch_deg), ([-5.0, 5.0], [-5.0, 5.0]));
        assert!((d.heading_deg[0] - 180.0).abs() < 1e-12 && (d.heading_deg[1] - 270.0).abs() < 1e-12);
        // A range across north keeps its width; a whole turn is every heading.
        let across = AttitudeBox::from_degrees([-5.0, 5.0], [-20.0, 30.0], [-5.0, 5.0]).unwrap();
        let d = Bounds {
            bounds: &across,
            yaw_offset_deg: 0.0,
        }
        .degrees();
        assert!((d.heading_deg[0] - 330.0).abs() < 1e-12 && (d.heading_deg[1] - 380.0).abs() < 1e-12);
        let all = AttitudeBox::from_degrees([-5.0, 5.0], [-180.0, 180.0], [-5.0, 5.0]).unwrap();
        let d = Bounds {
            bounds: &all,
            yaw_offset_deg: 37.0,
        }
        .degrees();
        assert_eq!(d.heading_deg, [0.0, 360.0]);
    }
}
