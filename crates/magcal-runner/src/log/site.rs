//! The site and date of a log: its units, and the World Magnetic Model's field there.

use anyhow::{Context, Result, bail};
use clap::ValueEnum;

/// `--units`: the log's units, for a magnitude from the WMM (nT).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Units {
    /// Nanotesla.
    #[value(name = "nT")]
    NanoTesla,
    /// Microtesla.
    #[value(name = "uT")]
    MicroTesla,
    /// Milligauss (100 nT).
    #[value(name = "mG")]
    MilliGauss,
    /// Gauss (100,000 nT).
    #[value(name = "G")]
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

/// The WMM magnitude at `--site` on `--date` in `--units`, and its source in words.
pub fn wmm_magnitude(site: &str, date: &str, units: Units, model: Option<&str>) -> Result<(f64, String)> {
    let (v, source) = wmm_field(site, date, model)?;
    let nt = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    Ok((nt / units.nt(), source))
}

/// The WMM field (North, East, Down, nT) at `site` (`LAT,LON[,ALT_M]`) on `date`, by `model` or
/// the newest whose window holds the date, and its source in words.
pub fn wmm_field(site: &str, date: &str, model: Option<&str>) -> Result<([f64; 3], String)> {
    use magcal_core::wmm;
    let numbers: Vec<f64> = site
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--site {site:?}: give LAT,LON or LAT,LON,ALT_M in numbers"))?;
    let (lat, lon, alt) = match numbers[..] {
        [lat, lon] => (lat, lon, 0.0),
        [lat, lon, alt] => (lat, lon, alt),
        _ => bail!("--site {site:?}: give LAT,LON or LAT,LON,ALT_M"),
    };
    let year = decimal_year(date)?;
    let site = wmm::Site {
        lat_deg: lat,
        lon_deg: lon,
        alt_m: alt,
        year,
    };
    let candidates: Vec<wmm::Model> = match model {
        Some(name) => vec![wmm::Model::from_name(name).with_context(|| {
            let known: Vec<&str> = wmm::Model::ALL.iter().map(|m| m.name()).collect();
            format!("--wmm {name:?}: unknown model; known: {}", known.join(", "))
        })?],
        None => wmm::Model::ALL.iter().rev().copied().collect(),
    };
    let mut last = None;
    for m in candidates {
        match wmm::field_ned(m, &site) {
            Ok(v) => {
                let nt = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                return Ok((
                    v,
                    format!("{} at {lat}, {lon}, {alt} m, {year:.3}: {nt:.1} nT", m.name()),
                ));
            }
            Err(e) => last = Some(e),
        }
    }
    bail!(
        "--site {lat},{lon},{alt} --date {date}: no model holds it ({})",
        last.map_or(String::new(), |e| e.to_string())
    )
}

/// `YYYY-MM-DD` (the middle of that day) or a decimal year.
pub fn decimal_year(date: &str) -> Result<f64> {
    if let Ok(y) = date.trim().parse::<f64>() {
        return Ok(y);
    }
    let parts: Vec<i64> = date
        .split('-')
        .map(|v| v.parse::<i64>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("--date {date:?}: give YYYY-MM-DD or a decimal year"))?;
    let [y, m, d] = parts[..] else {
        bail!("--date {date:?}: give YYYY-MM-DD or a decimal year");
    };
    let leap = (y % 4 == 0 && y % 100 != 0) || y % 400 == 0;
    let month_days = [31, if leap { 29 } else { 28 }, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31];
    if !(1..=12).contains(&m) || d < 1 || d > month_days[(m - 1) as usize] {
        bail!("--date {date:?}: not a date");
    }
    let day_of_year: i64 = month_days[..(m - 1) as usize].iter().sum::<i64>() + d;
    let days = if leap { 366.0 } else { 365.0 };
    Ok(y as f64 + (day_of_year as f64 - 0.5) / days)
}
