//! The site and date of a log: its units, and the World Magnetic Model's field there.

use anyhow::{Result, bail};

use crate::limits::show;

/// `--units`: the log's units, for a magnitude from the WMM (nT).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Units {
    /// Nanotesla.
    #[cfg_attr(feature = "clap", value(name = "nT"))]
    NanoTesla,
    /// Microtesla.
    #[cfg_attr(feature = "clap", value(name = "uT"))]
    MicroTesla,
    /// Milligauss (100 nT).
    #[cfg_attr(feature = "clap", value(name = "mG"))]
    MilliGauss,
    /// Gauss (100,000 nT).
    #[cfg_attr(feature = "clap", value(name = "G"))]
    Gauss,
}

impl Units {
    /// nT per unit.
    pub fn nt(self) -> f64 {
        match self {
            Self::NanoTesla => 1.0,
            Self::MicroTesla => 1e3,
            Self::MilliGauss => 1e2,
            Self::Gauss => 1e5,
        }
    }
}

/// `--site LAT,LON[,ALT_M]`: WGS 84 geodetic latitude and longitude (degrees) and height above
/// the ellipsoid (metres, default 0), checked where the command line is read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Site {
    /// Latitude, degrees, in [-90, 90].
    pub lat_deg: f64,
    /// Longitude, degrees east, in [-360, 360].
    pub lon_deg: f64,
    /// Height above the ellipsoid, metres, within the WMM's range.
    pub alt_m: f64,
}

impl std::str::FromStr for Site {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        use magcal_core::wmm::{MAX_ALT_M, MIN_ALT_M};
        let numbers: Vec<f64> = text
            .split(',')
            .map(|v| v.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| "give LAT,LON or LAT,LON,ALT_M in numbers (degrees, metres)".to_string())?;
        let (lat, lon, alt) = match numbers[..] {
            [lat, lon] => (lat, lon, 0.0),
            [lat, lon, alt] => (lat, lon, alt),
            _ => return Err("give LAT,LON or LAT,LON,ALT_M (degrees, metres)".into()),
        };
        for (name, v) in [("latitude", lat), ("longitude", lon), ("height", alt)] {
            if !v.is_finite() {
                return Err(format!("{name} {} is not a finite number", show(v)));
            }
        }
        if !(-90.0..=90.0).contains(&lat) {
            return Err(format!("latitude {} is outside [-90, 90] degrees", show(lat)));
        }
        if !(-360.0..=360.0).contains(&lon) {
            return Err(format!("longitude {} is outside [-360, 360] degrees", show(lon)));
        }
        if !(MIN_ALT_M..=MAX_ALT_M).contains(&alt) {
            return Err(format!(
                "height {} m is outside the WMM's [{}, {}] m",
                show(alt),
                show(MIN_ALT_M),
                show(MAX_ALT_M)
            ));
        }
        Ok(Self {
            lat_deg: lat,
            lon_deg: lon,
            alt_m: alt,
        })
    }
}

/// `--date YYYY-MM-DD` (the middle of that day) or a decimal year
/// ([`magcal_core::wmm::decimal_year`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Date {
    /// Decimal year.
    pub year: f64,
}

impl std::str::FromStr for Date {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        magcal_core::wmm::decimal_year(text)
            .map(|year| Self { year })
            .map_err(|e| e.to_string())
    }
}

/// `--wmm NAME`: a model of [`magcal_core::wmm::Model::ALL`].
///
/// # Errors
/// An unknown name, with the known ones.
pub fn parse_model(name: &str) -> Result<magcal_core::wmm::Model, String> {
    name.parse().map_err(|e: magcal_core::wmm::UnknownModel| e.to_string())
}

/// Where a WMM field comes from, for a person: `WMM2025 at 33.92 S, 18.42 E, 0 m, 2026.42`
/// (latitude and longitude to 0.01 degree with their hemisphere, the longitude taken into
/// (-180, 180]; height in metres; decimal year to 0.01).
pub fn wmm_place(model: magcal_core::wmm::Model, at: &magcal_core::wmm::Site) -> String {
    let lon = -(-at.lon_deg + 180.0).rem_euclid(360.0) + 180.0;
    format!(
        "{} at {:.2} {}, {:.2} {}, {} m, {:.2}",
        model.name(),
        at.lat_deg.abs(),
        if at.lat_deg < 0.0 { 'S' } else { 'N' },
        lon.abs(),
        if lon < 0.0 { 'W' } else { 'E' },
        show(at.alt_m),
        at.year
    )
}

/// The WMM magnitude at `site` on `date` in `units`, and its source in words.
///
/// # Errors
/// As [`wmm_field`].
pub fn wmm_magnitude(
    site: &Site,
    date: Date,
    units: Units,
    model: Option<magcal_core::wmm::Model>,
) -> Result<(f64, String)> {
    let (v, source) = wmm_field(site, date, model)?;
    let nt = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    Ok((nt / units.nt(), source))
}

/// The WMM field (North, East, Down, nT) at `site` on `date`, by `model` or the newest whose
/// window holds the date, and its source in words.
///
/// # Errors
/// As [`wmm_pick`].
pub fn wmm_field(site: &Site, date: Date, model: Option<magcal_core::wmm::Model>) -> Result<([f64; 3], String)> {
    let (v, m, at) = wmm_pick(site, date, model)?;
    Ok((v, wmm_label(v, m, &at)))
}

/// A WMM field `ned` (nT) of `model` at `at` in words, as the log commands name their source:
/// `WMM2025 at 63.43, 10.4, 0 m, 2026.420: 51234.5 nT`.
pub fn wmm_label(ned: [f64; 3], model: magcal_core::wmm::Model, at: &magcal_core::wmm::Site) -> String {
    let nt = (ned[0] * ned[0] + ned[1] * ned[1] + ned[2] * ned[2]).sqrt();
    format!(
        "{} at {}, {}, {} m, {:.3}: {nt:.1} nT",
        model.name(),
        at.lat_deg,
        at.lon_deg,
        at.alt_m,
        at.year
    )
}

/// The WMM field (North, East, Down, nT) at `site` on `date`, by `model` or the newest whose
/// window holds the date; with the model used and the site and date as the model took them.
///
/// # Errors
/// A date that no model (or not the model asked for) holds.
pub fn wmm_pick(
    site: &Site,
    date: Date,
    model: Option<magcal_core::wmm::Model>,
) -> Result<([f64; 3], magcal_core::wmm::Model, magcal_core::wmm::Site)> {
    use magcal_core::wmm;
    let (lat, lon, alt, year) = (site.lat_deg, site.lon_deg, site.alt_m, date.year);
    let at = wmm::Site {
        lat_deg: lat,
        lon_deg: lon,
        alt_m: alt,
        year,
    };
    let candidates: Vec<wmm::Model> = match model {
        Some(m) => vec![m],
        None => wmm::Model::ALL.iter().rev().copied().collect(),
    };
    let mut last = None;
    for m in candidates {
        match wmm::field_ned(m, &at) {
            Ok(v) => return Ok((v, m, at)),
            Err(e) => last = Some(e),
        }
    }
    bail!(
        "--site {lat},{lon},{alt} --date {year:.3}: no model holds it ({})",
        last.map_or(String::new(), |e| e.to_string())
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sites_are_checked_where_they_are_read() {
        let s: Site = "-33.92,18.42".parse().unwrap();
        assert_eq!((s.lat_deg, s.lon_deg, s.alt_m), (-33.92, 18.42, 0.0));
        let s: Site = " 28.2, 112.97 , 50".parse().unwrap();
        assert_eq!((s.lat_deg, s.lon_deg, s.alt_m), (28.2, 112.97, 50.0));
        for (text, needle) in [
            ("north", "in numbers"),
            ("1,2,3,4", "give LAT,LON"),
            ("91,0", "latitude 91 is outside"),
            ("NaN,0", "latitude NaN is not a finite number"),
            ("0,inf", "longitude inf is not a finite number"),
            ("0,400", "longitude 400 is outside"),
            ("0,0,1e7", "height 10000000 m is outside"),
        ] {
            let e = text.parse::<Site>().unwrap_err();
            assert!(e.contains(needle), "{text}: {e}");
        }
    }

    #[test]
    fn dates_and_models_are_typed() {
        assert_eq!("2013.0".parse::<Date>().unwrap().year, 2013.0);
        assert!("2013-02-30".parse::<Date>().unwrap_err().contains("not a date"));
        assert_eq!(parse_model("WMM2010"), Ok(magcal_core::wmm::Model::Wmm2010));
        assert!(parse_model("WMM1999").unwrap_err().contains("unknown model"));
    }

    #[test]
    fn places_name_their_hemispheres_and_a_longitude_in_the_half_open_circle() {
        use magcal_core::wmm::{Model, Site};
        let at = |lat_deg, lon_deg, alt_m, year| Site {
            lat_deg,
            lon_deg,
            alt_m,
            year,
        };
        for (site, want) in [
            (
                at(-33.92, 18.42, 0.0, 2026.0),
                "WMM2025 at 33.92 S, 18.42 E, 0 m, 2026.00",
            ),
            (
                at(63.43, 10.4, 50.0, 2026.5),
                "WMM2025 at 63.43 N, 10.40 E, 50 m, 2026.50",
            ),
            (
                at(-80.0, 240.0, 100000.0, 2027.5),
                "WMM2025 at 80.00 S, 120.00 W, 100000 m, 2027.50",
            ),
            (
                at(0.0, -180.0, 0.0, 2025.0),
                "WMM2025 at 0.00 N, 180.00 E, 0 m, 2025.00",
            ),
            (
                at(45.0, -70.0, -500.0, 2025.0),
                "WMM2025 at 45.00 N, 70.00 W, -500 m, 2025.00",
            ),
            (at(10.0, 360.0, 0.0, 2025.0), "WMM2025 at 10.00 N, 0.00 E, 0 m, 2025.00"),
        ] {
            assert_eq!(wmm_place(Model::Wmm2025, &site), want);
        }
    }
}
