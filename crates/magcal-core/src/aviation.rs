//! Attitudes as autopilots, navigation systems and motion capture log them, and their relation
//! to \[P1\]'s.
//!
//! A logged attitude is a rotation `C` taking vectors of the vehicle's body frame into a local
//! navigation frame. Two conventions cover the logs `magcal` reads:
//! - [`NavFrame::Ned`]: body forward, right, down into north, east, down (ArduPilot, PX4,
//!   aviation). Euler angles `(roll, pitch, yaw)` with `C = Rz(yaw) Ry(pitch) Rx(roll)`; yaw is
//!   the heading, clockwise from north; pitch > 0 raises the nose; roll > 0 lowers the right side.
//! - [`NavFrame::Enu`]: body forward, left, up into east, north, up (ROS REP 103, many motion
//!   capture systems). The same formula for the Euler angles, in those frames: yaw
//!   counter-clockwise from east, pitch > 0 lowers the nose (a rotation about the left axis),
//!   roll > 0 lowers the right side, as in NED.
//!
//! Inside `magcal` an attitude is held as `C` in the NED convention ([`to_ned`], [`from_ned`]).
//! \[P1\]'s `(roll, yaw, pitch)` of eq. (2) (n-frame north, up, east; b-frame nose, up, right)
//! have the same senses of roll and pitch as the NED convention and the same order of rotation
//! (yaw, then pitch, then roll), with the compass heading `-(yaw + yaw_offset)`
//! (docs/conventions.md, "Sense of the angles").

use crate::small::{Mat3, mat_mul, transpose};

/// The navigation and body frames of a logged attitude (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NavFrame {
    /// Body forward, right, down into north, east, down.
    Ned,
    /// Body forward, left, up into east, north, up.
    Enu,
}

/// The largest departure of a logged quaternion's norm from 1 that is taken for rounding
/// (float32 storage, values printed to 7 digits): a quaternion further off is not a rotation,
/// most likely columns that are not a quaternion.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// `C` of a Hamilton quaternion `[w, x, y, z]` (vectors rotated, `v' = q v q*`), normalised;
/// `None` when its norm is not within [`QUATERNION_NORM_TOLERANCE`] of 1 or a component is not
/// finite.
pub fn dcm_of_quaternion(q: [f64; 4]) -> Option<Mat3> {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !n.is_finite() || (n - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return None;
    }
    let [w, x, y, z] = q.map(|v| v / n);
    Some([
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ])
}

/// `C = Rz(yaw) Ry(pitch) Rx(roll)`, radians: body into navigation frame.
pub fn dcm_of_euler(roll: f64, pitch: f64, yaw: f64) -> Mat3 {
    let (sr, cr) = roll.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let (sy, cy) = yaw.sin_cos();
    [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
}

/// `(roll, pitch, yaw)` in radians of `C` ([`dcm_of_euler`]'s inverse): roll and yaw in
/// `(-pi, pi]`, pitch in `[-pi/2, pi/2]`. At pitch `+-pi/2` roll is taken as 0.
pub fn euler_of_dcm(c: &Mat3) -> [f64; 3] {
    let pitch = (-c[2][0]).clamp(-1.0, 1.0).asin();
    if c[2][0].abs() > 1.0 - 1e-12 {
        // Gimbal lock: only yaw - roll (or yaw + roll) is defined.
        return [0.0, pitch, (-c[0][1]).atan2(c[1][1])];
    }
    [c[2][1].atan2(c[2][2]), pitch, c[1][0].atan2(c[0][0])]
}

/// Coordinates of ENU vectors in NED (and back: the matrix is its own inverse).
const ENU_TO_NED: Mat3 = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]];
/// Coordinates of forward-right-down body vectors in forward-left-up (its own inverse).
const FRD_TO_FLU: Mat3 = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]];

/// `C` of `frame` as `C` in the NED convention.
pub fn to_ned(c: &Mat3, frame: NavFrame) -> Mat3 {
    match frame {
        NavFrame::Ned => *c,
        NavFrame::Enu => mat_mul(&mat_mul(&ENU_TO_NED, c), &FRD_TO_FLU),
    }
}

/// `C` in the NED convention as `C` of `frame` ([`to_ned`]'s inverse).
pub fn from_ned(c: &Mat3, frame: NavFrame) -> Mat3 {
    match frame {
        NavFrame::Ned => *c,
        NavFrame::Enu => mat_mul(&mat_mul(&transpose(&ENU_TO_NED), c), &transpose(&FRD_TO_FLU)),
    }
}

/// A NED-convention `C` with its navigation frame turned to east, north, up (the body frame kept):
/// the z-up attitude [`crate::reference::align`] takes. The half turn about the north-east
/// diagonal: its own inverse.
pub fn z_up_of_ned(c: &Mat3) -> Mat3 {
    mat_mul(&ENU_TO_NED, c)
}

/// `(roll, pitch, heading)` in degrees of a NED-convention `C`: heading clockwise from north in
/// `[0, 360)`.
pub fn roll_pitch_heading_deg(c_ned: &Mat3) -> [f64; 3] {
    let [r, p, y] = euler_of_dcm(c_ned);
    [r.to_degrees(), p.to_degrees(), y.to_degrees().rem_euclid(360.0)]
}

/// The tilt of a NED-convention `C` in degrees, `[0, 180]`: the angle between the body's down
/// axis and the navigation frame's (so between body up and up), `acos(cos roll cos pitch)`.
pub fn tilt_deg(c_ned: &Mat3) -> f64 {
    c_ned[2][0].hypot(c_ned[2][1]).atan2(c_ned[2][2]).to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::attitude::Attitude;
    use crate::small::mat_vec;

    fn close(a: &Mat3, b: &Mat3, tol: f64) -> bool {
        a.iter()
            .flatten()
            .zip(b.iter().flatten())
            .all(|(x, y)| (x - y).abs() <= tol)
    }

    #[test]
    fn euler_angles_round_trip_and_have_the_aviation_senses() {
        for (r, p, y) in [(0.1, -0.4, 2.0), (-3.0, 1.2, -0.5), (0.0, 0.0, 3.1), (1.0, -1.5, -3.0)] {
            let back = euler_of_dcm(&dcm_of_euler(r, p, y));
            for (a, b) in back.iter().zip([r, p, y]) {
                assert!((a - b).abs() < 1e-12, "{back:?} vs {:?}", [r, p, y]);
            }
        }
        // Pitch up: the nose (body x) gets a negative down component.
        let nose = mat_vec(&dcm_of_euler(0.0, 0.3, 0.0), [1.0, 0.0, 0.0]);
        assert!((nose[2] + 0.3f64.sin()).abs() < 1e-15);
        // Roll right: the right wing (body y) goes down.
        let wing = mat_vec(&dcm_of_euler(0.3, 0.0, 0.0), [0.0, 1.0, 0.0]);
        assert!((wing[2] - 0.3f64.sin()).abs() < 1e-15);
        // Heading 90: the nose points east.
        let nose = mat_vec(&dcm_of_euler(0.0, 0.0, 90f64.to_radians()), [1.0, 0.0, 0.0]);
        assert!((nose[1] - 1.0).abs() < 1e-15);
    }

    #[test]
    fn tilt_is_acos_of_cos_roll_cos_pitch_whatever_the_heading() {
        for (r, p, y) in [
            (0.1_f64, -0.4_f64, 2.0),
            (-3.0, 1.2, -0.5),
            (0.0, 0.0, 3.1),
            (1.0, -1.5, -3.0),
            (3.0, 0.2, 1.0),
        ] {
            let want = (r.cos() * p.cos()).acos().to_degrees();
            let got = tilt_deg(&dcm_of_euler(r, p, y));
            // acos loses digits near 0 and 180 degrees; atan2 does not: 1e-12 of a radian.
            assert!((got - want).abs() < 1e-9, "{got} against {want}");
        }
        // Upside down, and level.
        assert!((tilt_deg(&dcm_of_euler(std::f64::consts::PI, 0.0, 0.4)) - 180.0).abs() < 1e-12);
        assert!(tilt_deg(&dcm_of_euler(0.0, 0.0, 2.0)).abs() < 1e-12);
    }

    #[test]
    fn quaternions_give_the_same_rotation_as_their_euler_angles() {
        // q of a rotation about z by yaw: (cos(yaw/2), 0, 0, sin(yaw/2)); likewise x and y.
        let h = |a: f64| (0.5 * a).sin_cos();
        let (sy, cy) = h(0.7);
        let (sp, cp) = h(-0.2);
        let (sr, cr) = h(0.4);
        // q = qz(yaw) * qy(pitch) * qx(roll), Hamilton products written out.
        let q = [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ];
        let c = dcm_of_quaternion(q).unwrap();
        assert!(close(&c, &dcm_of_euler(0.4, -0.2, 0.7), 1e-15), "{c:?}");
        assert!(dcm_of_quaternion([0.0; 4]).is_none());
        assert!(dcm_of_quaternion([1.01, 0.0, 0.0, 0.0]).is_none());
        assert!(dcm_of_quaternion([f64::NAN, 0.0, 0.0, 0.0]).is_none());
        assert!(dcm_of_quaternion([1.0 + 5e-4, 0.0, 0.0, 0.0]).is_some());
    }

    #[test]
    fn enu_and_ned_describe_the_same_vehicle() {
        // Level, nose north: NED identity; in ENU/FLU the nose (x) is north = ENU y, yaw 90.
        let enu = from_ned(&dcm_of_euler(0.0, 0.0, 0.0), NavFrame::Enu);
        let [r, p, y] = euler_of_dcm(&enu);
        assert!(r.abs() < 1e-15 && p.abs() < 1e-15 && (y - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
        // Nose up 0.3 rad in NED is pitch -0.3 in ENU/FLU (pitch about the left axis); roll
        // right side down is the same roll in both.
        let enu = from_ned(&dcm_of_euler(0.2, 0.3, 0.0), NavFrame::Enu);
        let [r, p, _] = euler_of_dcm(&enu);
        assert!((p + 0.3).abs() < 1e-15 && (r - 0.2).abs() < 1e-15, "{r} {p}");
        for (r, p, y) in [(0.1, -0.4, 2.0), (-3.0, 1.2, -0.5)] {
            let c = dcm_of_euler(r, p, y);
            assert!(close(&to_ned(&from_ned(&c, NavFrame::Enu), NavFrame::Enu), &c, 1e-15));
            assert!(close(&to_ned(&c, NavFrame::Ned), &c, 0.0));
        }
    }

    #[test]
    fn p1_attitudes_are_the_ned_euler_angles_with_heading_minus_yaw() {
        // [P1] eq. (2): C_n^b maps (N, U, E) into (nose, up, right). The same vehicle in NED /
        // FRD: roll and pitch equal, heading = -yaw.
        for (r, y, p) in [(0.05, 0.6, -0.3), (-0.08, -2.5, 0.33), (0.0, 3.0, 0.1)] {
            let c_nb = Attitude {
                roll: r,
                yaw: y,
                pitch: p,
            }
            .dcm();
            // NUE -> NED: (n, u, e) -> (n, e, -u); nose-up-right -> FRD: (x, u, r) -> (x, r, -u).
            let m: Mat3 = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]];
            let c_ned = mat_mul(&mat_mul(&m, &transpose(&c_nb)), &transpose(&m));
            let [roll, pitch, heading] = roll_pitch_heading_deg(&c_ned);
            assert!((roll - r.to_degrees()).abs() < 1e-12, "{roll} {r}");
            assert!((pitch - p.to_degrees()).abs() < 1e-12, "{pitch} {p}");
            assert!(
                (heading - (-y.to_degrees()).rem_euclid(360.0)).abs() < 1e-12,
                "{heading} {y}"
            );
        }
    }
}
