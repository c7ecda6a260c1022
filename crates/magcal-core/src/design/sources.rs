//! Designs that need no optimisation: an explicit list, a uniform grid, uniform random draws.

use rand::{Rng, RngExt};

use crate::attitude::{AngleRange, Attitude, AttitudeBox};
use crate::error::ParameterError;

/// Checks that every attitude of an explicit design (for example \[P1\] Table II) is finite and lies in
/// `bounds`; returns the index and attitude of the first that does not.
///
/// # Errors
/// [`ParameterError::NonFinite`] or [`ParameterError::OutOfRange`] naming the angle (`"roll"`,
/// `"yaw"`, `"pitch"`) and its value in degrees.
pub fn check_explicit(design: &[Attitude], bounds: &AttitudeBox) -> Result<(), (usize, ParameterError)> {
    for (i, a) in design.iter().enumerate() {
        for (name, value, range) in [
            ("roll", a.roll, bounds.roll),
            ("yaw", a.yaw, bounds.yaw),
            ("pitch", a.pitch, bounds.pitch),
        ] {
            if !value.is_finite() {
                return Err((i, ParameterError::NonFinite { name, value }));
            }
            // Half a micro-degree of slack for values printed in degrees and converted.
            if value < range.min() - 1e-8 || value > range.max() + 1e-8 {
                return Err((
                    i,
                    ParameterError::OutOfRange {
                        name,
                        allowed: "the attitude box",
                        value: value.to_degrees(),
                    },
                ));
            }
        }
    }
    Ok(())
}

/// Levels of one angle on a uniform grid: `n` points from `min` to `max` inclusive, or, for a
/// full-turn range, `n` points spaced a turn apart over `[min, max)` so that none repeats.
fn levels(range: &AngleRange, n: usize) -> Vec<f64> {
    if n == 1 {
        return vec![0.5 * (range.min() + range.max())];
    }
    let steps = if range.is_full_turn() { n } else { n - 1 };
    (0..n)
        .map(|i| range.min() + range.width() * i as f64 / steps as f64)
        .collect()
}

/// The uniform grid with `[roll, yaw, pitch]` levels per axis: every combination, roll slowest and
/// pitch fastest. A full-turn yaw range takes its levels over `[min, max)`.
///
/// # Errors
/// A level count of zero ([`ParameterError::TooSmall`] naming `"roll"`, `"yaw"` or `"pitch"`); a
/// product of the counts that overflows `usize` ([`ParameterError::TooLarge`] naming `"levels"`).
pub fn grid(bounds: &AttitudeBox, levels_per_axis: [usize; 3]) -> Result<Vec<Attitude>, ParameterError> {
    for (name, n) in ["roll", "yaw", "pitch"].into_iter().zip(levels_per_axis) {
        if n == 0 {
            return Err(ParameterError::TooSmall { name, min: 1, value: n });
        }
    }
    let size = levels_per_axis
        .iter()
        .try_fold(1usize, |acc, &n| acc.checked_mul(n))
        .ok_or(ParameterError::TooLarge {
            name: "levels",
            max: usize::MAX,
            value: usize::MAX,
        })?;
    let [r, y, p] = [
        levels(&bounds.roll, levels_per_axis[0]),
        levels(&bounds.yaw, levels_per_axis[1]),
        levels(&bounds.pitch, levels_per_axis[2]),
    ];
    let mut out = Vec::with_capacity(size);
    for &roll in &r {
        for &yaw in &y {
            out.extend(p.iter().map(|&pitch| Attitude { roll, yaw, pitch }));
        }
    }
    Ok(out)
}

/// `m` attitudes drawn uniformly in the box, each angle independently, in the order roll, yaw,
/// pitch per attitude.
pub fn random<R: Rng + ?Sized>(bounds: &AttitudeBox, m: usize, rng: &mut R) -> Vec<Attitude> {
    (0..m).map(|_| random_attitude(bounds, rng)).collect()
}

/// One attitude drawn uniformly in the box.
pub fn random_attitude<R: Rng + ?Sized>(bounds: &AttitudeBox, rng: &mut R) -> Attitude {
    Attitude {
        roll: rng.random_range(bounds.roll.min()..=bounds.roll.max()),
        yaw: rng.random_range(bounds.yaw.min()..=bounds.yaw.max()),
        pitch: rng.random_range(bounds.pitch.min()..=bounds.pitch.max()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::paper;
    use crate::rng::stream_rng;

    #[test]
    fn grid_has_every_level_once() {
        let g = grid(&paper::auv_box(), [3, 4, 2]).unwrap();
        assert_eq!(g.len(), 24);
        let degs: Vec<[f64; 3]> = g.iter().map(Attitude::to_degrees).collect();
        // Roll slowest: -5, 0, 5; yaw over [-180, 180) in quarter turns; pitch fastest: -20, 20.
        let want_first = [[-5.0, -180.0, -20.0], [-5.0, -180.0, 20.0], [-5.0, -90.0, -20.0]];
        for (got, want) in degs.iter().zip(want_first) {
            for k in 0..3 {
                assert!((got[k] - want[k]).abs() < 1e-12, "{got:?} {want:?}");
            }
        }
        let last = degs[23];
        assert!((last[0] - 5.0).abs() < 1e-12 && (last[1] - 90.0).abs() < 1e-12 && (last[2] - 20.0).abs() < 1e-12);
        assert!(grid(&paper::auv_box(), [3, 0, 2]).is_err());
        assert!(g.iter().all(|a| paper::auv_box().contains(a)));
    }

    #[test]
    fn random_designs_stay_in_the_box_and_cover_it() {
        let b = paper::auv_box();
        let d = random(&b, 2000, &mut stream_rng(1, 1));
        assert!(d.iter().all(|a| b.contains(a)));
        // Uniform on [-20, 20] degrees: mean 0 within 4 standard errors (sd 40 / sqrt(12)).
        let mean = d.iter().map(|a| a.pitch.to_degrees()).sum::<f64>() / 2000.0;
        assert!(mean.abs() <= 4.0 * 40.0 / 12f64.sqrt() / 2000f64.sqrt(), "{mean}");
    }

    #[test]
    fn explicit_designs_are_checked_against_the_box() {
        let b = paper::auv_box();
        assert!(check_explicit(&paper::uniformity_design(), &b).is_ok());
        assert!(check_explicit(&paper::table2_d_optimal(), &b).is_ok());
        let mut d = paper::uniformity_design();
        d[4] = Attitude::from_degrees(0.0, 0.0, 25.0);
        let (i, e) = check_explicit(&d, &b).unwrap_err();
        assert_eq!(i, 4);
        assert!(matches!(e, ParameterError::OutOfRange { name: "pitch", .. }), "{e:?}");
        d[4] = Attitude::from_degrees(f64::NAN, 0.0, 0.0);
        assert!(matches!(
            check_explicit(&d, &b),
            Err((4, ParameterError::NonFinite { name: "roll", .. }))
        ));
    }
}
