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

    /// The names of [`Self::ALL`], comma-separated: `WMM2010, WMM2015, ...`.
    pub fn known_names() -> String {
        Self::ALL.map(|m| m.name()).join(", ")
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

/// A model name that none of [`Model::ALL`] has; says which names are known.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("unknown model; known: {}", Model::known_names())]
pub struct UnknownModel;

impl std::str::FromStr for Model {
    type Err = UnknownModel;

    /// [`Model::from_name`], with the known names on failure.
    fn from_str(name: &str) -> Result<Self, UnknownModel> {
        Self::from_name(name).ok_or(UnknownModel)
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
        return Err(ParameterError::OutsideValidityWindow { model, year: site.year });
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

/// The declination and inclination of `model` at `site`, degrees: `D` east of true north
/// ([`crate::field::declination_deg`]; `None` where the horizontal field vanishes) and `I` below
/// the horizontal ([`crate::field::inclination_deg`]), as the WMM report defines them from X, Y, Z.
///
/// # Errors
/// As [`field_ned`].
pub fn declination_inclination_deg(model: Model, site: &Site) -> Result<(Option<f64>, f64), ParameterError> {
    let ned = field_ned(model, site)?;
    Ok((crate::field::declination_deg(ned), crate::field::inclination_deg(ned)))
}

/// Earliest year [`decimal_year`] takes: the shipped models start in 2010, and a bound this wide
/// only catches a mistyped year (`20130`) before it reaches the model's window check.
pub const MIN_YEAR: i64 = 1900;
/// Latest year [`decimal_year`] takes (see [`MIN_YEAR`]; the shipped models end in 2030).
pub const MAX_YEAR: i64 = 2100;

/// A date that [`decimal_year`] cannot take.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DateError {
    /// Neither `YYYY-MM-DD` nor a decimal year (the text, cut to 40 characters).
    #[error("{0:?}: give YYYY-MM-DD or a decimal year")]
    Format(String),
    /// A day that the month does not have (`2013-02-30`, `2013-02-29`).
    #[error("{year}-{month:02}-{day:02} is not a date")]
    NotADate {
        /// Year.
        year: i64,
        /// Month, 1-12 if it is one.
        month: i64,
        /// Day.
        day: i64,
    },
    /// A year outside [[`MIN_YEAR`], [`MAX_YEAR`]].
    #[error("year {} is outside [{MIN_YEAR}, {MAX_YEAR}]", crate::error::show(*.0))]
    OutOfRange(f64),
}

/// Whether `year` (Gregorian) has a 29 February.
pub fn is_leap_year(year: i64) -> bool {
    (year % 4 == 0 && year % 100 != 0) || year % 400 == 0
}

/// The decimal year of `text`: a decimal year as written (`2013.5`), or `YYYY-MM-DD`, taken at
/// the middle of that day: `year + (day_of_year - 0.5) / days_in_year`, as the WMM's date is.
///
/// # Errors
/// Text that is neither, a day the month does not have, a year outside
/// [[`MIN_YEAR`], [`MAX_YEAR`]] (a decimal year must be finite and within them too).
pub fn decimal_year(text: &str) -> Result<f64, DateError> {
    let text = text.trim();
    let format = || DateError::Format(text.chars().take(40).collect());
    if let Ok(y) = text.parse::<f64>() {
        // The last day of MAX_YEAR ends at MAX_YEAR + 1.
        return if (MIN_YEAR as f64..MAX_YEAR as f64 + 1.0).contains(&y) {
            Ok(y)
        } else {
            Err(DateError::OutOfRange(y))
        };
    }
    let parts: Vec<&str> = text.split('-').collect();
    let [y, m, d] = parts[..] else {
        return Err(format());
    };
    let digits =
        |s: &str, n: std::ops::RangeInclusive<usize>| n.contains(&s.len()) && s.bytes().all(|b| b.is_ascii_digit());
    if !(digits(y, 4..=4) && digits(m, 1..=2) && digits(d, 1..=2)) {
        return Err(format());
    }
    let (year, month, day): (i64, i64, i64) = (
        y.parse().map_err(|_| format())?,
        m.parse().map_err(|_| format())?,
        d.parse().map_err(|_| format())?,
    );
    if !(MIN_YEAR..=MAX_YEAR).contains(&year) {
        return Err(DateError::OutOfRange(year as f64));
    }
    let leap = is_leap_year(year);
    let month_days = [31, if leap { 29 } else { 28 }, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31];
    if !(1..=12).contains(&month) || day < 1 || day > month_days[(month - 1) as usize] {
        return Err(DateError::NotADate { year, month, day });
    }
    let day_of_year: i64 = month_days[..(month - 1) as usize].iter().sum::<i64>() + day;
    let days = if leap { 366.0 } else { 365.0 };
    Ok(year as f64 + (day_of_year as f64 - 0.5) / days)
}

#[cfg(test)]
mod tests;
