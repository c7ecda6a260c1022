//! The World Magnetic Model: the reference field of \[P1\] eq. (1) at any site and date.
//!
//! \[P1\] IV.A takes its reference field from the WMM at the calibration site. This module evaluates
//! the model's degree-12 spherical-harmonic expansion from its coefficient files (public domain,
//! NOAA NCEI and the British Geological Survey; shipped in `data/wmm/` and compiled in, so no file is
//! read at run time): WGS 84 geodetic to geocentric coordinates, Schmidt semi-normalised associated
//! Legendre functions, secular variation from the model epoch, and the rotation of the geocentric
//! components back to the geodetic North, East, Down frame (NOAA technical report "The US/UK World
//! Magnetic Model for 2020-2025", section 1.2, equations 7-19).
//!
//! Written here rather than taken from a crate: `world_magnetic_model` is f32 and carries WMM2020
//! and later only; `magnetics` had no release that builds with the project's dependency set.
// Index loops mirror the recurrences of the spherical-harmonic synthesis.
#![allow(clippy::needless_range_loop)]

use crate::error::ParameterError;
use crate::field::ReferenceField;

/// Maximum degree of the WMM expansion.
const N: usize = 12;
/// Geomagnetic reference radius, km.
const A_REF: f64 = 6371.2;
/// WGS 84 semi-major axis, km.
const WGS84_A: f64 = 6378.137;
/// WGS 84 flattening.
const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// Years a model is valid after its epoch.
const VALIDITY_YEARS: f64 = 5.0;

/// A WMM release.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Model {
    /// WMM2010, valid 2010.0-2015.0.
    Wmm2010,
    /// WMM2015 (the original release), valid 2015.0-2020.0.
    Wmm2015,
    /// WMM2015v2 (the out-of-cycle update of 2018), valid 2015.0-2020.0.
    Wmm2015v2,
    /// WMM2020, valid 2020.0-2025.0.
    Wmm2020,
    /// WMM2025, valid 2025.0-2030.0.
    Wmm2025,
}

impl Model {
    /// Every model, oldest first.
    pub const ALL: [Model; 5] = [
        Self::Wmm2010,
        Self::Wmm2015,
        Self::Wmm2015v2,
        Self::Wmm2020,
        Self::Wmm2025,
    ];

    /// The name used in scenario files: `WMM2010`, `WMM2015`, `WMM2015v2`, `WMM2020`, `WMM2025`.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Wmm2010 => "WMM2010",
            Self::Wmm2015 => "WMM2015",
            Self::Wmm2015v2 => "WMM2015v2",
            Self::Wmm2020 => "WMM2020",
            Self::Wmm2025 => "WMM2025",
        }
    }

    /// The model named `name` (as [`Self::name`] spells it), if there is one.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    fn cof(&self) -> &'static str {
        match self {
            Self::Wmm2010 => include_str!("../../data/wmm/WMM_2010.COF"),
            Self::Wmm2015 => include_str!("../../data/wmm/WMM_2015.COF"),
            Self::Wmm2015v2 => include_str!("../../data/wmm/WMM_2015v2.COF"),
            Self::Wmm2020 => include_str!("../../data/wmm/WMM_2020.COF"),
            Self::Wmm2025 => include_str!("../../data/wmm/WMM_2025.COF"),
        }
    }

    /// The model's epoch (decimal year) and its Gauss coefficients `g, h` (nT) and their secular
    /// variation `g_dot, h_dot` (nT / year), indexed `[n][m]`.
    fn coefficients(&self) -> Coefficients {
        let mut lines = self.cof().lines();
        let header = lines.next().expect("shipped COF file has a header");
        let epoch: f64 = header
            .split_whitespace()
            .next()
            .and_then(|t| t.parse().ok())
            .expect("shipped COF header starts with the epoch");
        let mut c = Coefficients {
            epoch,
            g: [[0.0; N + 1]; N + 1],
            h: [[0.0; N + 1]; N + 1],
            g_dot: [[0.0; N + 1]; N + 1],
            h_dot: [[0.0; N + 1]; N + 1],
        };
        for line in lines {
            let f: Vec<&str> = line.split_whitespace().collect();
            if f.len() < 6 {
                break; // the 9999... terminator
            }
            let n: usize = f[0].parse().expect("shipped COF degree");
            let m: usize = f[1].parse().expect("shipped COF order");
            let v: Vec<f64> = f[2..6].iter().map(|t| t.parse().expect("shipped COF number")).collect();
            c.g[n][m] = v[0];
            c.h[n][m] = v[1];
            c.g_dot[n][m] = v[2];
            c.h_dot[n][m] = v[3];
        }
        c
    }
}

struct Coefficients {
    epoch: f64,
    g: [[f64; N + 1]; N + 1],
    h: [[f64; N + 1]; N + 1],
    g_dot: [[f64; N + 1]; N + 1],
    h_dot: [[f64; N + 1]; N + 1],
}

/// A site and date: WGS 84 geodetic latitude and longitude (degrees), height above the ellipsoid
/// (metres) and decimal year.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Site {
    /// Geodetic latitude, degrees, in [-90, 90].
    pub lat_deg: f64,
    /// Longitude, degrees, east positive.
    pub lon_deg: f64,
    /// Height above the WGS 84 ellipsoid, metres.
    pub alt_m: f64,
    /// Decimal year, within the model's validity window.
    pub year: f64,
}

/// The field of `model` at `site`: North, East, Down components in nT (X, Y, Z as the WMM reports
/// them).
///
/// # Errors
/// A non-finite input, a latitude outside [-90, 90], or a date outside the model's five-year
/// validity window.
pub fn field_ned(model: Model, site: &Site) -> Result<[f64; 3], ParameterError> {
    for (name, v) in [
        ("field.lat_deg", site.lat_deg),
        ("field.lon_deg", site.lon_deg),
        ("field.alt_m", site.alt_m),
        ("field.year", site.year),
    ] {
        crate::error::finite(name, v)?;
    }
    if site.lat_deg.abs() > 90.0 {
        return Err(ParameterError::OutOfRange {
            name: "field.lat_deg",
            allowed: "[-90, 90] degrees",
            value: site.lat_deg,
        });
    }
    let c = model.coefficients();
    let t = site.year - c.epoch;
    if !(0.0..=VALIDITY_YEARS).contains(&t) {
        return Err(ParameterError::OutOfRange {
            name: "field.year",
            allowed: "the model's validity window (epoch to epoch + 5 years)",
            value: site.year,
        });
    }

    // Geodetic to geocentric spherical coordinates (WGS 84).
    // At a pole the east component is a limit; evaluate a nano-degree away (changes < 1e-6 nT).
    let lat = site.lat_deg.clamp(-90.0 + 1e-9, 90.0 - 1e-9).to_radians();
    let lon = site.lon_deg.to_radians();
    let h_km = site.alt_m / 1000.0;
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let (sin_lat, cos_lat) = lat.sin_cos();
    let rc = WGS84_A / (1.0 - e2 * sin_lat * sin_lat).sqrt();
    let p = (rc + h_km) * cos_lat;
    let z = (rc * (1.0 - e2) + h_km) * sin_lat;
    let r = (p * p + z * z).sqrt();
    let lat_c = (z / r).asin();

    // Schmidt semi-normalised associated Legendre functions P[n][m] of sin(lat_c) and their
    // derivatives with respect to lat_c, by the standard recurrences.
    let (sin_c, cos_c) = lat_c.sin_cos();
    let mut pnm = [[0.0; N + 1]; N + 1];
    let mut dpnm = [[0.0; N + 1]; N + 1];
    pnm[0][0] = 1.0;
    for n in 1..=N {
        for m in 0..=n {
            let nf = n as f64;
            if n == m {
                let k = if n == 1 {
                    1.0
                } else {
                    ((2.0 * nf - 1.0) / (2.0 * nf)).sqrt()
                };
                pnm[n][n] = k * cos_c * pnm[n - 1][n - 1];
                dpnm[n][n] = k * (cos_c * dpnm[n - 1][n - 1] - sin_c * pnm[n - 1][n - 1]);
            } else {
                let mf = m as f64;
                let a = (2.0 * nf - 1.0) / (nf * nf - mf * mf).sqrt();
                let b = (((nf - 1.0) * (nf - 1.0) - mf * mf) / (nf * nf - mf * mf)).sqrt();
                let p2 = if n >= 2 { pnm[n - 2][m] } else { 0.0 };
                let dp2 = if n >= 2 { dpnm[n - 2][m] } else { 0.0 };
                pnm[n][m] = a * sin_c * pnm[n - 1][m] - b * p2;
                dpnm[n][m] = a * (sin_c * dpnm[n - 1][m] + cos_c * pnm[n - 1][m]) - b * dp2;
            }
        }
    }

    // Synthesis (NOAA report eq. 10-12): geocentric North X', East Y', Down Z'.
    let (mut xc, mut yc, mut zc) = (0.0, 0.0, 0.0);
    let ratio = A_REF / r;
    let mut rn = ratio * ratio; // (a/r)^(n+2) for n = 0
    for n in 1..=N {
        rn *= ratio;
        for m in 0..=n {
            let g = c.g[n][m] + t * c.g_dot[n][m];
            let h = c.h[n][m] + t * c.h_dot[n][m];
            let (sm, cm) = (m as f64 * lon).sin_cos();
            let gc = g * cm + h * sm;
            xc -= rn * gc * dpnm[n][m];
            yc += rn * m as f64 * (g * sm - h * cm) * pnm[n][m] / cos_c;
            zc -= (n as f64 + 1.0) * rn * gc * pnm[n][m];
        }
    }
    // Rotate from geocentric to geodetic (NOAA report eq. 17).
    let d = lat_c - lat;
    let (sd, cd) = d.sin_cos();
    Ok([xc * cd - zc * sd, yc, xc * sd + zc * cd])
}

/// The reference field of `model` at `site`, as [`ReferenceField::from_ned`] takes it.
///
/// # Errors
/// As [`field_ned`].
pub fn reference_field(model: Model, site: &Site) -> Result<ReferenceField, ParameterError> {
    let [x, y, z] = field_ned(model, site)?;
    ReferenceField::from_ned(x, y, z)
}

#[cfg(test)]
mod tests;
