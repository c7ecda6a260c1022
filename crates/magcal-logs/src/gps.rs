//! Where and when a flight log was flown, from its GPS fixes: the site and date of the World
//! Magnetic Model's field, and that field along the track (docs/conventions.md "The field along
//! a track").
//!
//! A fix is used when it is at least a 3D fix ([`MIN_FIX_TYPE`]) with a position on the globe
//! ([`Fix::usable`]). The site is the first used fix; the date is the UTC day of the first used
//! fix that carries a time. The field along the track is the model's at every used fix (each
//! fix's own position and height), linear in time between consecutive fixes and held at the
//! first and last fix before and after them: at 10 m between fixes and the main field's gradient
//! of at most about 0.03 nT/m, the field between two fixes is within 0.3 nT of the line between
//! theirs, and the fixes of a vehicle flying at 20 m/s at 5 Hz are 4 m apart.

use anyhow::{Result, bail};
use magcal_core::Vec3;
use magcal_core::wmm;

use super::flight::{Fix, MIN_FIX_TYPE, Series};
use crate::site::{Date, Site};

/// The site, date and model the field comes from.
#[derive(Debug, Clone, Copy)]
pub struct Place {
    /// `--site`.
    pub site: Site,
    /// `--date`.
    pub date: Date,
    /// `--wmm` (default: the newest model whose window holds the date).
    pub model: Option<magcal_core::wmm::Model>,
}

/// The place a log's fixes give, and what was taken from where.
#[derive(Debug, Clone)]
pub struct FromFixes {
    pub place: Place,
    /// In words: the fix used for the site, the one for the date, the quality required.
    pub words: String,
}

/// What a log's fixes say of its place.
#[derive(Debug, Clone)]
pub enum PlaceOfLog {
    /// The log has no GPS messages.
    NoGps,
    /// It has GPS messages but no site or date can be taken from them: why, in words.
    Lacking(String),
    Found(FromFixes),
}

/// The civil date (year, month, day) of `days` since 1970-01-01 (proleptic Gregorian; H. Hinnant's
/// `civil_from_days`).
fn civil_from_days(days: i64) -> (i64, i64, i64) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

/// The UTC day of `utc_s` (seconds since 1970) as `YYYY-MM-DD`.
pub fn utc_day(utc_s: f64) -> String {
    let (y, m, d) = civil_from_days((utc_s / 86_400.0).floor() as i64);
    format!("{y:04}-{m:02}-{d:02}")
}

/// The site and date of `gps` (see the module documentation); `date` typed, where given, dates
/// the log instead of its fixes' UTC (positions without a time: a CSV's `--position` alone).
pub fn place_of(gps: Option<&Series<Fix>>, date: Option<Date>, model: Option<wmm::Model>, source: &str) -> PlaceOfLog {
    let Some(gps) = gps else {
        return PlaceOfLog::NoGps;
    };
    let used = || gps.times.iter().zip(&gps.values).filter(|(_, f)| f.usable());
    let Some((t_site, site_fix)) = used().next() else {
        let best = gps.values.iter().map(|f| f.fix_type).max().unwrap_or(0);
        return PlaceOfLog::Lacking(format!(
            "the log's GPS ({source}) has no fix of type {MIN_FIX_TYPE} (3D) or better with a position among its {} messages (best type {best})",
            gps.times.len()
        ));
    };
    let (year, dated) = match date {
        Some(d) => (d.year, format!("date {:.3} from --date", d.year)),
        None => {
            let Some((t_date, utc)) = used().find_map(|(t, f)| f.utc_s.map(|u| (t, u))) else {
                return PlaceOfLog::Lacking(format!(
                    "the log's GPS ({source}) gives no UTC time with its fixes, so no date"
                ));
            };
            let day = utc_day(utc);
            match wmm::decimal_year(&day) {
                Ok(y) => (
                    y,
                    format!("date {day} ({y:.3}) from the UTC of the fix at {t_date:.3} s"),
                ),
                Err(e) => return PlaceOfLog::Lacking(format!("the log's GPS gives the date {day}: {e}")),
            }
        }
    };
    // As logged: 1e-7 degrees and millimetres (not the binary fractions their products leave).
    let round = |x: f64, per_unit: f64| (x * per_unit).round() / per_unit;
    let site = Site {
        lat_deg: round(site_fix.lat_deg, 1e7),
        lon_deg: round(site_fix.lon_deg, 1e7),
        alt_m: round(site_fix.alt_m, 1e3),
    };
    let skipped = gps.times.iter().take_while(|t| *t < t_site).count();
    let words = format!(
        "the log's GPS ({source}): site {:.7}, {:.7}, {:.1} m (mean sea level) from its first fix of type {MIN_FIX_TYPE} (3D) or better, at {t_site:.3} s{}; {dated}",
        site.lat_deg,
        site.lon_deg,
        site.alt_m,
        if skipped > 0 {
            format!(" ({skipped} earlier messages without one)")
        } else {
            String::new()
        }
    );
    PlaceOfLog::Found(FromFixes {
        place: Place {
            site,
            date: Date { year },
            model,
        },
        words,
    })
}

/// The model's field along the track.
#[derive(Debug, Clone)]
pub struct Track {
    /// The field (east, north, up; nT) at each time asked for.
    pub enu_nt: Vec<Vec3>,
    /// The fixes used.
    pub fixes: usize,
    /// The smallest and largest magnitude over them, nT.
    pub magnitude_nt: (f64, f64),
    /// The largest angle between the field at a fix and at the first one, degrees.
    pub turn_deg: f64,
    /// The length of the track, metres (great-circle legs between consecutive fixes).
    pub length_m: f64,
}

/// Metres between two fixes on a sphere of the Earth's mean radius (haversine).
fn distance_m(a: &Fix, b: &Fix) -> f64 {
    const R: f64 = 6_371_008.8;
    let (p1, p2) = (a.lat_deg.to_radians(), b.lat_deg.to_radians());
    let dp = p2 - p1;
    let dl = (b.lon_deg - a.lon_deg).to_radians();
    let h = (dp / 2.0).sin().powi(2) + p1.cos() * p2.cos() * (dl / 2.0).sin().powi(2);
    2.0 * R * h.sqrt().min(1.0).asin()
}

/// The field of `model` (or the newest holding the date) at each of `times` on the log's clock,
/// along the used fixes of `gps` on the date `year` (see the module documentation).
///
/// # Errors
/// No used fix, or a fix the model does not hold (a height beyond its range).
pub fn track(gps: &Series<Fix>, times: &[f64], year: f64, model: wmm::Model) -> Result<Track> {
    let used: Vec<(f64, &Fix)> = gps
        .times
        .iter()
        .zip(&gps.values)
        .filter(|(_, f)| f.usable())
        .map(|(t, f)| (*t, f))
        .collect();
    if used.is_empty() {
        bail!("the log's GPS has no fix of type {MIN_FIX_TYPE} (3D) or better");
    }
    let mut at_fix: Vec<Vec3> = Vec::with_capacity(used.len());
    for (t, f) in &used {
        let site = wmm::Site {
            lat_deg: f.lat_deg,
            lon_deg: f.lon_deg,
            alt_m: f.alt_m,
            year,
        };
        let ned = wmm::field_ned(model, &site)
            .map_err(|e| anyhow::anyhow!("the fix at {t:.3} s ({}, {}, {} m): {e}", f.lat_deg, f.lon_deg, f.alt_m))?;
        at_fix.push([ned[1], ned[0], -ned[2]]);
    }
    let fix_times: Vec<f64> = used.iter().map(|(t, _)| *t).collect();
    let enu_nt = times
        .iter()
        .map(|&t| {
            let i = fix_times.partition_point(|&s| s <= t);
            if i == 0 {
                at_fix[0]
            } else if i == fix_times.len() {
                at_fix[i - 1]
            } else {
                let (t0, t1) = (fix_times[i - 1], fix_times[i]);
                let w = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
                std::array::from_fn(|k| at_fix[i - 1][k] + w * (at_fix[i][k] - at_fix[i - 1][k]))
            }
        })
        .collect();
    let norm = |v: &Vec3| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    let magnitudes: Vec<f64> = at_fix.iter().map(norm).collect();
    let first = at_fix[0];
    let turn_deg = at_fix
        .iter()
        .map(|v| {
            let c = (v[0] * first[0] + v[1] * first[1] + v[2] * first[2]) / (norm(v) * norm(&first));
            c.clamp(-1.0, 1.0).acos().to_degrees()
        })
        .fold(0.0, f64::max);
    let length_m = used.windows(2).map(|w| distance_m(w[0].1, w[1].1)).sum();
    Ok(Track {
        enu_nt,
        fixes: used.len(),
        magnitude_nt: (
            magnitudes.iter().copied().fold(f64::INFINITY, f64::min),
            magnitudes.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        ),
        turn_deg,
        length_m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fix(lat: f64, lon: f64, fix_type: u8, utc_s: Option<f64>) -> Fix {
        Fix {
            lat_deg: lat,
            lon_deg: lon,
            alt_m: 100.0,
            fix_type,
            utc_s,
        }
    }

    #[test]
    fn days_since_1970_are_civil_dates() {
        assert_eq!(utc_day(0.0), "1970-01-01");
        // GPS week 1973, 6,448 s into it (the ArduPilot fixture's first fix), less 18 leap seconds.
        assert_eq!(
            utc_day(315_964_800.0 + 1973.0 * 604_800.0 + 6448.0 - 18.0),
            "2017-10-29"
        );
        assert_eq!(utc_day(1_557_756_559.6), "2019-05-13");
        assert_eq!(utc_day(951_782_400.0), "2000-02-29");
        assert_eq!(utc_day(-86_400.0), "1969-12-31");
    }

    #[test]
    fn the_site_is_the_first_3d_fix_and_the_date_the_first_with_a_time() {
        let gps = Series {
            times: vec![1.0, 2.0, 3.0, 4.0],
            values: vec![
                fix(0.0, 0.0, 0, None),
                fix(60.1, 10.2, 2, Some(1.7e9)),
                fix(60.2, 10.3, 3, None),
                fix(60.3, 10.4, 3, Some(1_700_000_000.0)),
            ],
        };
        let PlaceOfLog::Found(p) = place_of(Some(&gps), None, None, "GPS") else {
            panic!("a place")
        };
        assert_eq!((p.place.site.lat_deg, p.place.site.lon_deg), (60.2, 10.3));
        // 2023-11-14, day 318 of 365, at its middle.
        assert!((p.place.date.year - (2023.0 + 317.5 / 365.0)).abs() < 1e-12);
        assert!(
            p.words.contains("at 3.000 s (2 earlier messages without one)"),
            "{}",
            p.words
        );
        assert!(p.words.contains("date 2023-11-14"), "{}", p.words);
        let none = Series {
            times: vec![1.0],
            values: vec![fix(60.0, 10.0, 2, Some(1.7e9))],
        };
        let PlaceOfLog::Lacking(why) = place_of(Some(&none), None, None, "GPS") else {
            panic!("lacking")
        };
        assert!(
            why.contains("no fix of type 3 (3D) or better") && why.contains("best type 2"),
            "{why}"
        );
        let timeless = Series {
            times: vec![1.0],
            values: vec![fix(60.0, 10.0, 3, None)],
        };
        assert!(matches!(place_of(Some(&timeless), None, None, "GPS"), PlaceOfLog::Lacking(w) if w.contains("no UTC")));
        // A date typed dates fixes without a time.
        let PlaceOfLog::Found(typed) = place_of(Some(&timeless), Some(Date { year: 2026.5 }), None, "GPS") else {
            panic!("a place")
        };
        assert!(
            typed.place.date.year == 2026.5 && typed.words.ends_with("date 2026.500 from --date"),
            "{}",
            typed.words
        );
        assert!(matches!(place_of(None, None, None, "GPS"), PlaceOfLog::NoGps));
    }

    #[test]
    fn the_field_along_a_track_is_the_models_at_each_fix_and_linear_between() {
        // 20 km north from 60 N: the field changes by tens of nT.
        let n = 21;
        let gps = Series {
            times: (0..n).map(|i| f64::from(i) * 10.0).collect(),
            values: (0..n)
                .map(|i| fix(60.0 + f64::from(i) * 0.009, 10.0, 3, Some(1.7e9)))
                .collect(),
        };
        let times = [-5.0, 0.0, 55.0, 200.0, 300.0];
        let tr = track(&gps, &times, 2025.5, wmm::Model::Wmm2025).unwrap();
        let at = |lat: f64| {
            let v = wmm::field_ned(
                wmm::Model::Wmm2025,
                &wmm::Site {
                    lat_deg: lat,
                    lon_deg: 10.0,
                    alt_m: 100.0,
                    year: 2025.5,
                },
            )
            .unwrap();
            [v[1], v[0], -v[2]]
        };
        let (first, last) = (at(60.0), at(60.0 + 20.0 * 0.009));
        // Before the first fix and after the last, held; at a fix, its own.
        for (k, want) in [(0, first), (1, first), (3, last), (4, last)] {
            for c in 0..3 {
                assert!(
                    (tr.enu_nt[k][c] - want[c]).abs() < 1e-9,
                    "{k} {:?} {want:?}",
                    tr.enu_nt[k]
                );
            }
        }
        // Halfway between the fixes at 50 and 60 s: their mean, within 0.1 nT of the model there.
        let mid = at(60.0 + 5.5 * 0.009);
        for c in 0..3 {
            assert!((tr.enu_nt[2][c] - mid[c]).abs() < 0.1, "{:?} {mid:?}", tr.enu_nt[2]);
        }
        let change =
            ((first[0] - last[0]).powi(2) + (first[1] - last[1]).powi(2) + (first[2] - last[2]).powi(2)).sqrt();
        assert!(change > 50.0, "{change}");
        assert_eq!(tr.fixes, 21);
        assert!((tr.length_m - 20_015.0).abs() < 20.0, "{}", tr.length_m);
    }
}
