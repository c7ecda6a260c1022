//! Attitudes, the direction cosine matrix of \[P1\] eq. (2) and attitude boxes, \[P1\] eq. (3)-(4).

use crate::error::ParameterError;
use crate::small::Mat3;

/// A vehicle attitude: roll `r`, yaw `y`, pitch `p` in **radians** (the order of \[P1\] eq. (2) and
/// of Table II, `[roll yaw pitch]`).
///
/// Build it from degrees with [`Attitude::from_degrees`]; files and tables use degrees.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Attitude {
    /// Roll `r`, radians: rotation about the body x (nose) axis.
    pub roll: f64,
    /// Yaw `y`, radians: rotation about the up axis; 0 puts the nose on north.
    pub yaw: f64,
    /// Pitch `p`, radians: rotation about the body z (right) axis.
    pub pitch: f64,
}

impl Attitude {
    /// An attitude from roll, yaw and pitch in degrees (the column order of \[P1\] Table II).
    pub fn from_degrees(roll_deg: f64, yaw_deg: f64, pitch_deg: f64) -> Self {
        Self {
            roll: roll_deg.to_radians(),
            yaw: yaw_deg.to_radians(),
            pitch: pitch_deg.to_radians(),
        }
    }

    /// `(roll, yaw, pitch)` in degrees.
    pub fn to_degrees(&self) -> [f64; 3] {
        [self.roll.to_degrees(), self.yaw.to_degrees(), self.pitch.to_degrees()]
    }

    /// `true` when all three angles are finite.
    pub fn is_finite(&self) -> bool {
        self.roll.is_finite() && self.yaw.is_finite() && self.pitch.is_finite()
    }

    /// The direction cosine matrix `C_n^b = Rx(r) Rz(p) Ry(y)` of \[P1\] eq. (2), which takes a vector
    /// in the n-frame (North, Up, East) to the b-frame (nose, up, right): `B^b = C_n^b B^n`
    /// (\[P1\] eq. (1)).
    pub fn dcm(&self) -> Mat3 {
        let (sr, cr) = self.roll.sin_cos();
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        // Rz(p) Ry(y), then Rx(r) on the left; multiplied out to keep it exact and allocation-free.
        let rz_ry = [[cp * cy, sp, -cp * sy], [-sp * cy, cp, sp * sy], [sy, 0.0, cy]];
        [
            rz_ry[0],
            [
                cr * rz_ry[1][0] + sr * rz_ry[2][0],
                cr * rz_ry[1][1] + sr * rz_ry[2][1],
                cr * rz_ry[1][2] + sr * rz_ry[2][2],
            ],
            [
                -sr * rz_ry[1][0] + cr * rz_ry[2][0],
                -sr * rz_ry[1][1] + cr * rz_ry[2][1],
                -sr * rz_ry[1][2] + cr * rz_ry[2][2],
            ],
        ]
    }

    /// The true heading of the nose: degrees clockwise from **true** north in `[0, 360)`, when
    /// yaw 0 puts the nose `yaw_offset_deg` counter-clockwise from north: positive yaw turns the
    /// nose west (\[P1\] eq. (2) with the n-frame North-Up-East, docs/conventions.md "Sense of the
    /// angles"), so the heading is `-(yaw + yaw_offset)` wrapped. Not what a compass reads: see
    /// [`Self::magnetic_heading_deg`].
    pub fn true_heading_deg(&self, yaw_offset_deg: f64) -> f64 {
        wrap_360(-(self.yaw.to_degrees() + yaw_offset_deg))
    }

    /// The magnetic heading of the nose, what a compass reads: degrees clockwise from
    /// **magnetic** north in `[0, 360)`, the true heading ([`Self::true_heading_deg`]) minus the
    /// declination `declination_deg` (degrees east of true north, as
    /// [`crate::ReferenceField::declination_deg`] gives it), wrapped.
    pub fn magnetic_heading_deg(&self, yaw_offset_deg: f64, declination_deg: f64) -> f64 {
        wrap_360(-(self.yaw.to_degrees() + yaw_offset_deg) - declination_deg)
    }

    /// The Hamilton unit quaternion `(w, x, y, z)`, `w >= 0`, of `C_b^n`: the rotation that takes
    /// body vectors (nose, up, right) into North-Up-East, with the yaw offset included.
    pub fn body_to_nav_quaternion(&self, yaw_offset_deg: f64) -> [f64; 4] {
        let flown = Self {
            yaw: self.yaw + yaw_offset_deg.to_radians(),
            ..*self
        };
        quaternion_of_transpose(&flown.dcm())
    }
}

/// `degrees` wrapped to `[0, 360)`: `rem_euclid` alone gives 360 for a tiny negative angle.
fn wrap_360(degrees: f64) -> f64 {
    let wrapped = degrees.rem_euclid(360.0);
    if wrapped >= 360.0 { 0.0 } else { wrapped }
}

/// The unit quaternion `(w, x, y, z)` (Hamilton, `w >= 0`) of `C_b^n = (C_n^b)^T`, from the
/// direction cosine matrix `C_n^b` of \[P1\] eq. (2), by Shepperd's method (the largest of the
/// four squared components first, for accuracy).
fn quaternion_of_transpose(c_nb: &Mat3) -> [f64; 4] {
    // m = C_b^n.
    let m = |i: usize, j: usize| c_nb[j][i];
    let trace = m(0, 0) + m(1, 1) + m(2, 2);
    let candidates = [trace, m(0, 0), m(1, 1), m(2, 2)];
    let k = (0..4)
        .max_by(|&a, &b| candidates[a].total_cmp(&candidates[b]))
        .unwrap_or(0);
    let q = match k {
        0 => {
            let w = (1.0 + trace).sqrt() / 2.0;
            [
                w,
                (m(2, 1) - m(1, 2)) / (4.0 * w),
                (m(0, 2) - m(2, 0)) / (4.0 * w),
                (m(1, 0) - m(0, 1)) / (4.0 * w),
            ]
        }
        1 => {
            let x = (1.0 + m(0, 0) - m(1, 1) - m(2, 2)).sqrt() / 2.0;
            [
                (m(2, 1) - m(1, 2)) / (4.0 * x),
                x,
                (m(0, 1) + m(1, 0)) / (4.0 * x),
                (m(0, 2) + m(2, 0)) / (4.0 * x),
            ]
        }
        2 => {
            let y = (1.0 - m(0, 0) + m(1, 1) - m(2, 2)).sqrt() / 2.0;
            [
                (m(0, 2) - m(2, 0)) / (4.0 * y),
                (m(0, 1) + m(1, 0)) / (4.0 * y),
                y,
                (m(1, 2) + m(2, 1)) / (4.0 * y),
            ]
        }
        _ => {
            let z = (1.0 - m(0, 0) - m(1, 1) + m(2, 2)).sqrt() / 2.0;
            [
                (m(1, 0) - m(0, 1)) / (4.0 * z),
                (m(0, 2) + m(2, 0)) / (4.0 * z),
                (m(1, 2) + m(2, 1)) / (4.0 * z),
                z,
            ]
        }
    };
    let sign = if q[0] < 0.0 { -1.0 } else { 1.0 };
    q.map(|v| v * sign)
}

/// A closed interval of one Euler angle, radians, with `min < max`, both finite.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AngleRange {
    min: f64,
    max: f64,
}

impl AngleRange {
    /// A range from degrees. `name` names the angle in the error (for example `"pitch"`).
    ///
    /// # Errors
    /// [`ParameterError::NonFinite`] for a NaN or infinite bound, [`ParameterError::EmptyRange`]
    /// when `min_deg >= max_deg`.
    pub fn from_degrees(name: &'static str, min_deg: f64, max_deg: f64) -> Result<Self, ParameterError> {
        for value in [min_deg, max_deg] {
            if !value.is_finite() {
                return Err(ParameterError::NonFinite { name, value });
            }
        }
        if min_deg >= max_deg {
            return Err(ParameterError::EmptyRange {
                name,
                min: min_deg,
                max: max_deg,
            });
        }
        Ok(Self {
            min: min_deg.to_radians(),
            max: max_deg.to_radians(),
        })
    }

    /// Lower bound, radians.
    pub fn min(&self) -> f64 {
        self.min
    }

    /// Upper bound, radians.
    pub fn max(&self) -> f64 {
        self.max
    }

    /// `max - min`, radians.
    pub fn width(&self) -> f64 {
        self.max - self.min
    }

    /// `true` when the range covers a whole turn (360 degrees or more), so that the angle is
    /// periodic inside it rather than bounded.
    pub fn is_full_turn(&self) -> bool {
        self.width() >= std::f64::consts::TAU * (1.0 - 1e-12)
    }

    /// `true` when `angle` (radians) lies in the closed range.
    pub fn contains(&self, angle: f64) -> bool {
        self.min <= angle && angle <= self.max
    }

    /// `angle` clamped into the range, or for a full-turn range wrapped into it.
    pub fn confine(&self, angle: f64) -> f64 {
        if self.is_full_turn() {
            self.min + (angle - self.min).rem_euclid(std::f64::consts::TAU)
        } else {
            angle.clamp(self.min, self.max)
        }
    }
}

/// The attitudes a vehicle can take, \[P1\] eq. (3): a box in (roll, yaw, pitch).
///
/// Every range is validated on construction (finite, `min < max`), so a box that exists is usable.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AttitudeBox {
    /// Roll range.
    pub roll: AngleRange,
    /// Yaw range; periodic when it spans a whole turn.
    pub yaw: AngleRange,
    /// Pitch range.
    pub pitch: AngleRange,
}

impl AttitudeBox {
    /// A box from `[min, max]` in degrees for roll, yaw and pitch.
    ///
    /// # Errors
    /// The first invalid range, named `"roll"`, `"yaw"` or `"pitch"`.
    pub fn from_degrees(roll: [f64; 2], yaw: [f64; 2], pitch: [f64; 2]) -> Result<Self, ParameterError> {
        Ok(Self {
            roll: AngleRange::from_degrees("roll", roll[0], roll[1])?,
            yaw: AngleRange::from_degrees("yaw", yaw[0], yaw[1])?,
            pitch: AngleRange::from_degrees("pitch", pitch[0], pitch[1])?,
        })
    }

    /// The whole attitude space: roll and yaw in [-180, 180], pitch in [-90, 90] degrees.
    pub fn full() -> Self {
        Self::from_degrees([-180.0, 180.0], [-180.0, 180.0], [-90.0, 90.0]).expect("constant box is valid")
    }

    /// The three ranges in the order of \[P1\] eq. (16): roll, yaw, pitch.
    pub fn ranges(&self) -> [AngleRange; 3] {
        [self.roll, self.yaw, self.pitch]
    }

    /// `true` when the attitude lies inside the box (each angle in its closed range).
    pub fn contains(&self, attitude: &Attitude) -> bool {
        self.roll.contains(attitude.roll) && self.yaw.contains(attitude.yaw) && self.pitch.contains(attitude.pitch)
    }

    /// The attitude clamped into the box (yaw wrapped when the yaw range is a full turn).
    pub fn confine(&self, attitude: &Attitude) -> Attitude {
        Attitude {
            roll: self.roll.confine(attitude.roll),
            yaw: self.yaw.confine(attitude.yaw),
            pitch: self.pitch.confine(attitude.pitch),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::small::{mat_mul, transpose};

    fn rx(r: f64) -> Mat3 {
        let (s, c) = r.sin_cos();
        [[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]]
    }
    fn rz(p: f64) -> Mat3 {
        let (s, c) = p.sin_cos();
        [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]
    }
    fn ry(y: f64) -> Mat3 {
        let (s, c) = y.sin_cos();
        [[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]]
    }

    #[test]
    fn magnetic_heading_is_what_a_level_compass_reads() {
        // A level compass reads the field in the body's horizontal plane: with the nose x and the
        // right z, a field at bearing D seen from a nose at true heading h has body components
        // (cos(D - h), sin(D - h)), so the compass heading is -atan2(b_z, b_x). Checked against
        // the body field of [P1] eq. (1)-(2) at Cape-Town-like (D = -27) and polar (D = 150)
        // fields, every 7 degrees of yaw, with and without a yaw offset.
        use crate::ReferenceField;
        for (x, y, z) in [
            (9000.0, -4600.0, -22000.0),
            (-3000.0, 1732.05, 55000.0),
            (35272.34, -2085.74, 32897.67),
        ] {
            for offset in [0.0, 90.0, -33.0] {
                let f = ReferenceField::from_ned(x, y, z)
                    .unwrap()
                    .with_yaw_offset_deg(offset)
                    .unwrap();
                let d = f.declination_deg().unwrap();
                for k in -26..=26 {
                    let a = Attitude::from_degrees(0.0, 7.0 * k as f64, 0.0);
                    let b = f.body_field(&a);
                    let compass = (-b[2].atan2(b[0]).to_degrees()).rem_euclid(360.0);
                    let got = a.magnetic_heading_deg(offset, d);
                    let diff = (got - compass).rem_euclid(360.0);
                    assert!(
                        diff.min(360.0 - diff) < 1e-9,
                        "D {d} offset {offset} yaw {}: {got} vs {compass}",
                        7 * k
                    );
                    assert!((0.0..360.0).contains(&got));
                    // And the identity the outputs promise: magnetic = true - D (mod 360).
                    let t = a.true_heading_deg(offset);
                    let back = (t - d - got).rem_euclid(360.0);
                    assert!(back.min(360.0 - back) < 1e-9);
                }
            }
        }
        // A tiny negative angle wraps to 0, not to 360.
        assert!(Attitude::from_degrees(0.0, 1e-300, 0.0).true_heading_deg(0.0) < 360.0);
        assert!(Attitude::from_degrees(0.0, 0.0, 0.0).magnetic_heading_deg(0.0, 1e-300) < 360.0);
    }

    #[test]
    fn dcm_is_the_product_of_eq_2_and_orthonormal() {
        for (r, y, p) in [(0.1, -2.0, 0.3), (-3.0, 1.0, 1.5), (0.0, 0.0, 0.0), (2.5, 3.1, -1.2)] {
            let a = Attitude {
                roll: r,
                yaw: y,
                pitch: p,
            };
            let c = a.dcm();
            let want = mat_mul(&mat_mul(&rx(r), &rz(p)), &ry(y));
            let ctc = mat_mul(&transpose(&c), &c);
            for i in 0..3 {
                for j in 0..3 {
                    assert!((c[i][j] - want[i][j]).abs() <= 4.0 * f64::EPSILON);
                    let id = if i == j { 1.0 } else { 0.0 };
                    assert!((ctc[i][j] - id).abs() <= 8.0 * f64::EPSILON);
                }
            }
        }
    }

    #[test]
    fn frames_follow_conventions() {
        // Level, yaw 0: the nose points north, so the body field equals the NUE field.
        let c = Attitude::from_degrees(0.0, 0.0, 0.0).dcm();
        assert_eq!(c, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        // Pitch up 90 degrees: the nose points up, so the Up component of B^n appears on body x.
        let c = Attitude::from_degrees(0.0, 0.0, 90.0).dcm();
        let b = crate::small::mat_vec(&c, [0.0, 1.0, 0.0]);
        assert!((b[0] - 1.0).abs() < 1e-15 && b[1].abs() < 1e-15 && b[2].abs() < 1e-15);
    }

    #[test]
    fn the_quaternion_rotates_body_vectors_into_north_up_east() {
        use crate::small::{mat_t_vec, norm};
        let mut rng = crate::rng::stream_rng(5, 0);
        for _ in 0..10_000 {
            let a = crate::design::sources::random_attitude(&crate::AttitudeBox::full(), &mut rng);
            let c_nb = a.dcm();
            let [w, x, y, z] = a.body_to_nav_quaternion(0.0);
            assert!(w >= 0.0 && (norm([x, y, z]).hypot(w) - 1.0).abs() < 1e-14);
            // v' = q v q*, by the rotation matrix of q.
            let r = crate::aviation::dcm_of_quaternion([w, x, y, z]).unwrap();
            for v in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.3, -0.2, 0.9]] {
                let want = mat_t_vec(&c_nb, v);
                let got = [0, 1, 2].map(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2]);
                for i in 0..3 {
                    assert!((got[i] - want[i]).abs() < 1e-14, "{a:?}");
                }
            }
        }
        // Level, yaw -60 (heading 60): the nose points north-east-ish, 60 degrees east of north.
        let q = Attitude::from_degrees(0.0, -60.0, 0.0).body_to_nav_quaternion(0.0);
        assert!((Attitude::from_degrees(0.0, -60.0, 0.0).true_heading_deg(0.0) - 60.0).abs() < 1e-12);
        // yaw 0 with the nose put on west (offset 90): heading 270.
        assert!((Attitude::from_degrees(0.0, 0.0, 0.0).true_heading_deg(90.0) - 270.0).abs() < 1e-12);
        assert!((q[0] - 30f64.to_radians().cos()).abs() < 1e-15 && (q[2] + 30f64.to_radians().sin()).abs() < 1e-15);
    }

    #[test]
    fn boxes_validate_and_confine() {
        assert!(matches!(
            AttitudeBox::from_degrees([5.0, -5.0], [-180.0, 180.0], [-20.0, 20.0]),
            Err(ParameterError::EmptyRange { name: "roll", .. })
        ));
        assert!(matches!(
            AttitudeBox::from_degrees([-5.0, 5.0], [0.0, 0.0], [-20.0, 20.0]),
            Err(ParameterError::EmptyRange { name: "yaw", .. })
        ));
        assert!(matches!(
            AttitudeBox::from_degrees([-5.0, 5.0], [-180.0, 180.0], [f64::NAN, 20.0]),
            Err(ParameterError::NonFinite { name: "pitch", .. })
        ));
        let b = AttitudeBox::from_degrees([-5.0, 5.0], [-180.0, 180.0], [-20.0, 20.0]).unwrap();
        assert!(b.yaw.is_full_turn() && !b.roll.is_full_turn());
        let c = b.confine(&Attitude::from_degrees(9.0, 190.0, -25.0));
        let [r, y, p] = c.to_degrees();
        assert!((r - 5.0).abs() < 1e-12 && (y + 170.0).abs() < 1e-12 && (p + 20.0).abs() < 1e-12);
        assert!(b.contains(&c));
        assert!(!b.contains(&Attitude::from_degrees(6.0, 0.0, 0.0)));
    }
}
