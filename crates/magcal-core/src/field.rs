//! The reference geomagnetic field of \[P1\] eq. (1) and its projection into the body frame.

use crate::attitude::Attitude;
use crate::error::{ParameterError, finite};
use crate::small::{Vec3, norm};
use rand_distr::Distribution;

/// The declination of a field given by its North, East, Down components (any unit): the direction
/// of its horizontal component, `D = atan2(east, north)`, in degrees east of true north, in
/// (-180, 180] (the definition of the NOAA WMM report). `None` when the horizontal component is
/// zero: a vertical field has no direction a compass could point along.
pub fn declination_deg(ned: Vec3) -> Option<f64> {
    let [north, east, _] = ned;
    let horizontal = north.hypot(east);
    (horizontal > 0.0 && horizontal.is_finite()).then(|| east.atan2(north).to_degrees())
}

/// The inclination (dip) of a field given by its North, East, Down components: the angle of the
/// field below the horizontal, `I = atan2(down, sqrt(north^2 + east^2))`, degrees in [-90, 90],
/// positive down (the definition of the NOAA WMM report).
pub fn inclination_deg(ned: Vec3) -> f64 {
    let [north, east, down] = ned;
    down.atan2(north.hypot(east)).to_degrees()
}

/// The homogeneous reference field at the calibration site (\[P1\] II.A).
///
/// Given as the World Magnetic Model reports it, North-East-Down components in nT, and stored as
/// `B^n = (X, -Z, Y)` in the paper's North-Up-East n-frame (docs/conventions.md).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ReferenceField {
    ned_nt: Vec3,
    b_n: Vec3,
    yaw_offset: f64,
}

impl ReferenceField {
    /// The field from its WMM components: `x` north, `y` east, `z` down, all in nT.
    ///
    /// # Errors
    /// A component that is not finite, or a zero field.
    pub fn from_ned(x_nt: f64, y_nt: f64, z_nt: f64) -> Result<Self, ParameterError> {
        let x = finite("north_nt", x_nt)?;
        let y = finite("east_nt", y_nt)?;
        let z = finite("down_nt", z_nt)?;
        let b_n = [x, -z, y];
        if norm(b_n) == 0.0 || !norm(b_n).is_finite() {
            return Err(ParameterError::NotPositive {
                name: "magnitude",
                value: norm(b_n),
            });
        }
        Ok(Self {
            ned_nt: [x, y, z],
            b_n,
            yaw_offset: 0.0,
        })
    }

    /// The same field with `yaw_offset_deg` (degrees) added to every yaw before \[P1\] eq. (2).
    /// Default 0: yaw 0 puts the nose on north (docs/conventions.md explains when 90 matters).
    ///
    /// # Errors
    /// A non-finite offset.
    pub fn with_yaw_offset_deg(mut self, yaw_offset_deg: f64) -> Result<Self, ParameterError> {
        self.yaw_offset = finite("yaw_offset_deg", yaw_offset_deg)?.to_radians();
        Ok(self)
    }

    /// `(X north, Y east, Z down)` in nT, as given.
    pub fn ned_nt(&self) -> Vec3 {
        self.ned_nt
    }

    /// The declination of the field, degrees east of true north ([`declination_deg`] of
    /// [`Self::ned_nt`]); `None` for a vertical field. A magnetic heading is the true heading
    /// minus it ([`Attitude::magnetic_heading_deg`]).
    pub fn declination_deg(&self) -> Option<f64> {
        declination_deg(self.ned_nt)
    }

    /// The inclination of the field, degrees below the horizontal ([`inclination_deg`] of
    /// [`Self::ned_nt`]).
    pub fn inclination_deg(&self) -> f64 {
        inclination_deg(self.ned_nt)
    }

    /// `B^n` in (North, Up, East), nT.
    pub fn b_n(&self) -> Vec3 {
        self.b_n
    }

    /// `R = |B^n|`, nT (\[P1\] eq. (7)).
    pub fn magnitude(&self) -> f64 {
        norm(self.b_n)
    }

    /// The yaw offset, degrees.
    pub fn yaw_offset_deg(&self) -> f64 {
        self.yaw_offset.to_degrees()
    }

    /// The field in the body frame at `attitude`: `B^b = C_n^b B^n`, \[P1\] eq. (1)-(2), with the yaw
    /// offset added to the attitude's yaw. nT.
    ///
    /// Applied as three plane rotations, `Rx(r) (Rz(p) (Ry(y) B^n))`, rather than by forming the
    /// matrix: this is the inner loop of the design optimisers.
    #[inline]
    pub fn body_field(&self, attitude: &Attitude) -> Vec3 {
        let [n, u, e] = self.b_n;
        let (sr, cr) = attitude.roll.sin_cos();
        let (sy, cy) = (attitude.yaw + self.yaw_offset).sin_cos();
        let (sp, cp) = attitude.pitch.sin_cos();
        let v1 = [cy * n - sy * e, u, sy * n + cy * e];
        let v2 = [cp * v1[0] + sp * v1[1], -sp * v1[0] + cp * v1[1], v1[2]];
        [v2[0], cr * v2[1] + sr * v2[2], -sr * v2[1] + cr * v2[2]]
    }

    /// The body field and its partial derivatives with respect to roll, yaw and pitch (nT per
    /// radian), from \[P1\] eq. (2): with `v1 = Ry(y) B^n`, `v2 = Rz(p) v1`, `B^b = Rx(r) v2`,
    /// `dB/dr = Rx'(r) v2`, `dB/dp = Rx(r) Rz'(p) v1`, `dB/dy = Rx(r) Rz(p) Ry'(y) B^n`.
    pub fn body_field_and_derivatives(&self, attitude: &Attitude) -> (Vec3, [Vec3; 3]) {
        let [n, u, e] = self.b_n;
        let (sr, cr) = attitude.roll.sin_cos();
        let (sy, cy) = (attitude.yaw + self.yaw_offset).sin_cos();
        let (sp, cp) = attitude.pitch.sin_cos();
        let v1 = [cy * n - sy * e, u, sy * n + cy * e];
        let dv1 = [-sy * n - cy * e, 0.0, cy * n - sy * e];
        let rz = |v: Vec3| [cp * v[0] + sp * v[1], -sp * v[0] + cp * v[1], v[2]];
        let drz = |v: Vec3| [-sp * v[0] + cp * v[1], -cp * v[0] - sp * v[1], 0.0];
        let rx = |v: Vec3| [v[0], cr * v[1] + sr * v[2], -sr * v[1] + cr * v[2]];
        let drx = |v: Vec3| [0.0, -sr * v[1] + cr * v[2], -cr * v[1] - sr * v[2]];
        let v2 = rz(v1);
        (rx(v2), [drx(v2), rx(rz(dv1)), rx(drz(v1))])
    }

    /// The body fields of `attitudes` as a vehicle flies them: each of roll, yaw and pitch off
    /// its commanded value by an independent `N(0, sigma_rad^2)` draw (three draws per attitude,
    /// roll, yaw, pitch, in order). With `sigma_rad = 0` nothing is drawn and the fields are the
    /// commanded ones.
    ///
    /// # Errors
    /// [`ParameterError::Negative`] or [`ParameterError::NonFinite`] for a bad `sigma_rad`.
    pub fn executed_body_fields<R: rand::Rng + ?Sized>(
        &self,
        attitudes: &[Attitude],
        sigma_rad: f64,
        rng: &mut R,
    ) -> Result<Vec<Vec3>, ParameterError> {
        let sigma = finite("attitude_sigma", sigma_rad)?;
        if sigma < 0.0 {
            return Err(ParameterError::Negative {
                name: "attitude_sigma",
                value: sigma,
            });
        }
        if sigma == 0.0 {
            return Ok(self.body_fields(attitudes));
        }
        let normal = rand_distr::Normal::new(0.0, sigma).map_err(|_| ParameterError::NonFinite {
            name: "attitude_sigma",
            value: sigma,
        })?;
        Ok(attitudes
            .iter()
            .map(|a| {
                let flown = Attitude {
                    roll: a.roll + normal.sample(rng),
                    yaw: a.yaw + normal.sample(rng),
                    pitch: a.pitch + normal.sample(rng),
                };
                self.body_field(&flown)
            })
            .collect())
    }

    /// [`Self::body_field`] for every attitude of a design, in order.
    pub fn body_fields(&self, attitudes: &[Attitude]) -> Vec<Vec3> {
        attitudes.iter().map(|a| self.body_field(a)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::paper;

    #[test]
    fn executed_fields_turn_the_commanded_ones_by_about_sigma() {
        use crate::rng::stream_rng;
        let f = paper::changsha_field();
        let design = paper::uniformity_design();
        let commanded = f.body_fields(&design);
        assert_eq!(
            f.executed_body_fields(&design, 0.0, &mut stream_rng(1, 0)).unwrap(),
            commanded
        );
        // The angle between commanded and flown field: its mean grows linearly with sigma
        // (small angles), and the magnitude is kept.
        let mean_angle = |sigma_deg: f64| {
            let mut rng = stream_rng(2, 0);
            let mut total = 0.0;
            let n = 20_000;
            for _ in 0..n / design.len() {
                let flown = f
                    .executed_body_fields(&design, sigma_deg.to_radians(), &mut rng)
                    .unwrap();
                for (a, b) in commanded.iter().zip(&flown) {
                    assert!((norm(*a) - norm(*b)).abs() < 1e-9 * norm(*a));
                    let c = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (norm(*a) * norm(*b));
                    total += c.clamp(-1.0, 1.0).acos();
                }
            }
            total / (n / design.len() * design.len()) as f64
        };
        let (one, two) = (mean_angle(0.5), mean_angle(1.0));
        assert!(
            one > 0.2f64.to_radians() && one < 1.0f64.to_radians(),
            "{}",
            one.to_degrees()
        );
        assert!((two / one - 2.0).abs() < 0.05, "{}", two / one);
        assert!(f.executed_body_fields(&design, -1.0, &mut stream_rng(1, 0)).is_err());
    }

    #[test]
    #[allow(clippy::float_cmp)] // B^n is a permutation of the given numbers: exact
    fn changsha_magnitude_matches_check_value() {
        // docs/conventions.md check value: R = 48277.79 nT.
        let f = paper::changsha_field();
        assert!((f.magnitude() - 48277.79).abs() < 0.005, "{}", f.magnitude());
        assert_eq!(f.b_n(), [35272.34, -32897.67, -2085.74]);
    }

    #[test]
    fn body_field_preserves_magnitude_and_applies_offset() {
        let f = paper::changsha_field();
        let g = f.with_yaw_offset_deg(90.0).unwrap();
        let a = Attitude::from_degrees(3.0, 10.0, -7.0);
        let b = Attitude::from_degrees(3.0, 100.0, -7.0);
        let (fa, gb) = (g.body_field(&a), f.body_field(&b));
        // The plane rotations agree with the matrix of [P1] eq. (2).
        let via_dcm = crate::small::mat_vec(&a.dcm(), f.b_n());
        let direct = f.body_field(&a);
        for i in 0..3 {
            assert!((via_dcm[i] - direct[i]).abs() <= 16.0 * f64::EPSILON * f.magnitude());
        }
        for i in 0..3 {
            assert!((fa[i] - gb[i]).abs() <= 1e-10);
        }
        assert!((norm(fa) - f.magnitude()).abs() <= 8.0 * f64::EPSILON * f.magnitude());
    }

    #[test]
    fn derivatives_match_central_differences() {
        let f = paper::changsha_field().with_yaw_offset_deg(33.0).unwrap();
        for a in [
            Attitude::from_degrees(3.0, -120.0, 15.0),
            Attitude::from_degrees(-170.0, 10.0, 80.0),
            Attitude::from_degrees(0.0, 0.0, 0.0),
        ] {
            let (b, d) = f.body_field_and_derivatives(&a);
            let b0 = f.body_field(&a);
            for i in 0..3 {
                assert!((b[i] - b0[i]).abs() <= 1e-10);
            }
            let h = 1e-6;
            for (k, step) in [[h, 0.0, 0.0], [0.0, h, 0.0], [0.0, 0.0, h]].into_iter().enumerate() {
                let shift = |s: f64| Attitude {
                    roll: a.roll + s * step[0],
                    yaw: a.yaw + s * step[1],
                    pitch: a.pitch + s * step[2],
                };
                let (p, m) = (f.body_field(&shift(1.0)), f.body_field(&shift(-1.0)));
                for i in 0..3 {
                    let fd = (p[i] - m[i]) / (2.0 * h);
                    // Truncation |B| h^2 / 6 plus rounding eps |B| / h, with |B| ~ 5e4 nT.
                    assert!((fd - d[k][i]).abs() <= 1e-3, "angle {k} comp {i}: {fd} vs {}", d[k][i]);
                }
            }
        }
    }

    #[test]
    fn declination_and_inclination_of_ned_components() {
        // Quadrants of the horizontal component: D is the angle from north toward east.
        let d = |x: f64, y: f64| {
            ReferenceField::from_ned(x, y, 1000.0)
                .unwrap()
                .declination_deg()
                .unwrap()
        };
        let tol = 64.0 * f64::EPSILON * 180.0;
        for (x, y, want) in [
            (1.0, 0.0, 0.0),
            (1.0, 1.0, 45.0),
            (0.0, 1.0, 90.0),
            (-1.0, 0.0, 180.0),
            (-1.0, -1.0, -135.0),
            (3.0f64.sqrt(), -1.0, -30.0),
        ] {
            assert!((d(x, y) - want).abs() <= tol, "({x}, {y}): {}", d(x, y));
        }
        // Changsha (docs/conventions.md): atan2(-2085.74, 35272.34) west of north, and
        // I = atan2(32897.67, |(X, Y)|) below the horizontal.
        let f = paper::changsha_field();
        let (x, y, z): (f64, f64, f64) = (35272.34, -2085.74, 32897.67);
        assert!((f.declination_deg().unwrap() - y.atan2(x).to_degrees()).abs() <= tol);
        assert!((f.inclination_deg() - z.atan2(x.hypot(y)).to_degrees()).abs() <= tol);
        assert!(f.declination_deg().unwrap() < -3.38 && f.declination_deg().unwrap() > -3.39);
        // A vertical field has no declination; its inclination is +-90.
        let vertical = ReferenceField::from_ned(0.0, 0.0, -50_000.0).unwrap();
        assert_eq!(vertical.declination_deg(), None);
        assert!((vertical.inclination_deg() + 90.0).abs() <= tol);
        // The yaw offset turns the body, not the field.
        let turned = f.with_yaw_offset_deg(90.0).unwrap();
        assert_eq!(turned.declination_deg(), f.declination_deg());
    }

    #[test]
    fn bad_fields_are_errors() {
        assert!(ReferenceField::from_ned(f64::NAN, 0.0, 1.0).is_err());
        assert!(ReferenceField::from_ned(0.0, 0.0, 0.0).is_err());
        assert!(paper::changsha_field().with_yaw_offset_deg(f64::INFINITY).is_err());
    }
}
