//! The World Magnetic Model: the reference field of \[P1\] eq. (1) at any site and date.
//!
//! \[P1\] IV.A takes its reference field from the WMM at the calibration site. The coefficient files
//! of each release (public domain, NOAA NCEI and the British Geological Survey) ship in `data/wmm/`
//! and are compiled in, so no file is read at run time. They are evaluated by the `magnetics` crate
//! (f64; WGS 84 geodetic to geocentric coordinates, Schmidt semi-normalised spherical harmonics to
//! degree 12, secular variation, rotation to geodetic North, East, Down: the steps of the NOAA WMM
//! report); this module adds the model list, the validity window and the checks of its input.

use crate::error::ParameterError;
use crate::field::ReferenceField;

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

    /// The model, read from its shipped coefficient file.
    fn load(&self) -> magnetics::main_field::Model {
        magnetics::main_field::read_cof(self.cof()).expect("shipped COF files are valid")
    }
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

/// Lowest height the WMM is valid at, metres above the ellipsoid (1 km below).
pub const MIN_ALT_M: f64 = -1_000.0;
/// Highest height the WMM is valid at, metres above the ellipsoid (850 km).
pub const MAX_ALT_M: f64 = 850_000.0;

/// The field of `model` at `site`: North, East, Down components in nT (X, Y, Z as the WMM reports
/// them).
///
/// # Errors
/// A non-finite input, a latitude outside [-90, 90], a height outside [[`MIN_ALT_M`], [`MAX_ALT_M`]], or a date outside the model's five-year
/// validity window.
pub fn field_ned(model: Model, site: &Site) -> Result<[f64; 3], ParameterError> {
    for (name, v) in [
        ("lat_deg", site.lat_deg),
        ("lon_deg", site.lon_deg),
        ("alt_m", site.alt_m),
        ("year", site.year),
    ] {
        crate::error::finite(name, v)?;
    }
    if site.lat_deg.abs() > 90.0 {
        return Err(ParameterError::OutOfRange {
            name: "lat_deg",
            allowed: "[-90, 90] degrees",
            value: site.lat_deg,
        });
    }
    if !(MIN_ALT_M..=MAX_ALT_M).contains(&site.alt_m) {
        return Err(ParameterError::OutOfRange {
            name: "alt_m",
            allowed: "[-1000, 850000] m, the WMM's validity range",
            value: site.alt_m,
        });
    }
    let m = model.load();
    let t = site.year - m.epoch;
    if !(0.0..=VALIDITY_YEARS).contains(&t) {
        return Err(ParameterError::OutOfRange {
            name: "year",
            allowed: "the model's validity window (epoch to epoch + 5 years)",
            value: site.year,
        });
    }
    // At a pole the east component is a limit (it divides by the cosine of the latitude): evaluate
    // a nano-degree away, which changes the field by less than 1e-6 nT.
    let lat = site.lat_deg.clamp(-90.0 + 1e-9, 90.0 - 1e-9).to_radians();
    let e = m.elements(site.year, lat, site.lon_deg.to_radians(), site.alt_m);
    Ok([e.x, e.y, e.z])
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
