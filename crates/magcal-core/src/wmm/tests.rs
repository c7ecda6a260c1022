// Index loops over the three components read best here.
#![allow(clippy::needless_range_loop)]

use super::*;

type Row = (Model, f64, f64, f64, f64, [f64; 3]);

/// NOAA's official test values published with each release (WMM2010testvalues.pdf,
/// WMM2015testvalues.pdf, WMM2020testvalues.pdf): model, decimal year, height (m), latitude,
/// longitude (degrees), and X, Y, Z (nT) as printed, to 0.1 nT.
const OFFICIAL: &[Row] = &[
    (Model::Wmm2010, 2010.0, 0.0, 80.0, 0.0, [6649.5, -714.6, 54346.2]),
    (Model::Wmm2010, 2010.0, 0.0, 0.0, 120.0, [39428.8, 664.9, -11683.8]),
    (Model::Wmm2010, 2010.0, 0.0, -80.0, 240.0, [5657.7, 15727.3, -53407.5]),
    (Model::Wmm2010, 2010.0, 100000.0, 80.0, 0.0, [6332.2, -729.1, 52194.9]),
    (Model::Wmm2010, 2010.0, 100000.0, 0.0, 120.0, [37452.0, 611.9, -11180.8]),
    (
        Model::Wmm2010,
        2010.0,
        100000.0,
        -80.0,
        240.0,
        [5484.3, 14762.8, -50834.8],
    ),
    (Model::Wmm2010, 2012.5, 0.0, 80.0, 0.0, [6658.0, -606.7, 54420.4]),
    (Model::Wmm2010, 2012.5, 0.0, 0.0, 120.0, [39423.9, 608.1, -11540.5]),
    (Model::Wmm2010, 2012.5, 0.0, -80.0, 240.0, [5713.6, 15731.8, -53184.3]),
    (Model::Wmm2010, 2012.5, 100000.0, 80.0, 0.0, [6340.9, -625.1, 52261.9]),
    (Model::Wmm2010, 2012.5, 100000.0, 0.0, 120.0, [37448.1, 559.7, -11044.2]),
    (
        Model::Wmm2010,
        2012.5,
        100000.0,
        -80.0,
        240.0,
        [5535.5, 14765.4, -50625.9],
    ),
    (Model::Wmm2015, 2015.0, 0.0, 80.0, 0.0, [6627.1, -445.9, 54432.3]),
    (Model::Wmm2015, 2015.0, 0.0, 0.0, 120.0, [39518.2, 392.9, -11252.4]),
    (Model::Wmm2015, 2015.0, 0.0, -80.0, 240.0, [5797.3, 15761.1, -52919.1]),
    (Model::Wmm2015, 2015.0, 100000.0, 80.0, 0.0, [6314.3, -471.6, 52269.8]),
    (Model::Wmm2015, 2015.0, 100000.0, 0.0, 120.0, [37535.6, 364.4, -10773.4]),
    (
        Model::Wmm2015,
        2015.0,
        100000.0,
        -80.0,
        240.0,
        [5613.1, 14791.5, -50378.6],
    ),
    (Model::Wmm2015, 2017.5, 0.0, 80.0, 0.0, [6599.4, -317.1, 54459.2]),
    (Model::Wmm2015, 2017.5, 0.0, 0.0, 120.0, [39571.4, 222.5, -11030.1]),
    (Model::Wmm2015, 2017.5, 0.0, -80.0, 240.0, [5873.8, 15781.4, -52687.9]),
    (Model::Wmm2015, 2017.5, 100000.0, 80.0, 0.0, [6290.5, -348.5, 52292.7]),
    (Model::Wmm2015, 2017.5, 100000.0, 0.0, 120.0, [37585.5, 209.5, -10564.2]),
    (
        Model::Wmm2015,
        2017.5,
        100000.0,
        -80.0,
        240.0,
        [5683.5, 14808.8, -50163.0],
    ),
    (Model::Wmm2020, 2020.0, 0.0, 80.0, 0.0, [6570.4, -146.3, 54606.0]),
    (Model::Wmm2020, 2020.0, 0.0, 0.0, 120.0, [39624.3, 109.9, -10932.5]),
    (Model::Wmm2020, 2020.0, 0.0, -80.0, 240.0, [5940.6, 15772.1, -52480.8]),
    (Model::Wmm2020, 2020.0, 100000.0, 80.0, 0.0, [6261.8, -185.5, 52429.1]),
    (Model::Wmm2020, 2020.0, 100000.0, 0.0, 120.0, [37636.7, 104.9, -10474.8]),
    (
        Model::Wmm2020,
        2020.0,
        100000.0,
        -80.0,
        240.0,
        [5744.9, 14799.5, -49969.4],
    ),
    (Model::Wmm2020, 2022.5, 0.0, 80.0, 0.0, [6529.9, 1.1, 54713.4]),
    (Model::Wmm2020, 2022.5, 0.0, 0.0, 120.0, [39684.7, -42.2, -10809.5]),
    (Model::Wmm2020, 2022.5, 0.0, -80.0, 240.0, [6016.5, 15776.7, -52251.6]),
    (Model::Wmm2020, 2022.5, 100000.0, 80.0, 0.0, [6224.0, -44.5, 52527.0]),
    (Model::Wmm2020, 2022.5, 100000.0, 0.0, 120.0, [37694.0, -35.3, -10362.0]),
    (
        Model::Wmm2020,
        2022.5,
        100000.0,
        -80.0,
        240.0,
        [5815.0, 14803.0, -49755.3],
    ),
];

/// An independent implementation, pygeomag 1.1.0 (PyPI), for the releases whose official tables
/// are not at hand here (WMM2025, WMM2015v2), printed to 1e-4 nT.
const PYGEOMAG: &[Row] = &[
    (
        Model::Wmm2025,
        2025.0,
        0.0,
        80.0,
        0.0,
        [6521.5994, 145.8870, 54791.5077],
    ),
    (
        Model::Wmm2025,
        2025.0,
        0.0,
        0.0,
        120.0,
        [39677.7550, -109.6063, -10580.1698],
    ),
    (
        Model::Wmm2025,
        2025.0,
        0.0,
        -80.0,
        240.0,
        [6117.5482, 15751.9058, -52022.5194],
    ),
    (
        Model::Wmm2025,
        2027.5,
        100000.0,
        45.0,
        -70.0,
        [18064.8138, -4644.7538, 45994.8782],
    ),
    (
        Model::Wmm2025,
        2029.9,
        5000.0,
        -33.9,
        151.2,
        [23894.7277, 5471.8791, -51235.1553],
    ),
    (
        Model::Wmm2025,
        2026.3,
        0.0,
        28.2,
        112.97,
        [35079.7994, -2537.2678, 34087.9265],
    ),
    (
        Model::Wmm2025,
        2025.5,
        -500.0,
        60.0,
        10.0,
        [15068.9446, 1193.8299, 49267.0437],
    ),
    (
        Model::Wmm2015v2,
        2015.0,
        0.0,
        80.0,
        0.0,
        [6636.5802, -451.8843, 54408.8785],
    ),
    (
        Model::Wmm2015v2,
        2017.5,
        100000.0,
        0.0,
        120.0,
        [37584.3835, 235.7209, -10600.5388],
    ),
    (
        Model::Wmm2015v2,
        2019.9,
        0.0,
        -80.0,
        240.0,
        [5930.1221, 15768.9641, -52493.9572],
    ),
];

fn site(row: &Row) -> Site {
    Site {
        year: row.1,
        alt_m: row.2,
        lat_deg: row.3,
        lon_deg: row.4,
    }
}

#[test]
fn official_test_values_to_the_printed_precision() {
    for row in OFFICIAL {
        let got = field_ned(row.0, &site(row)).unwrap();
        for i in 0..3 {
            // Printed to 0.1 nT: a correct value rounds to it.
            assert!(
                (got[i] - row.5[i]).abs() <= 0.05 + 1e-9,
                "{row:?}: component {i} = {}",
                got[i]
            );
        }
    }
}

#[test]
fn agrees_with_an_independent_implementation() {
    for row in PYGEOMAG {
        let got = field_ned(row.0, &site(row)).unwrap();
        for i in 0..3 {
            assert!((got[i] - row.5[i]).abs() <= 1e-3, "{row:?}: component {i} = {}", got[i]);
        }
    }
}

#[test]
fn conventions_check_value_for_changsha() {
    // docs/conventions.md: WMM2010 at 28.2 N, 112.97 E, 0 m, 2013.0: X = 35272.34, Y = -2085.74,
    // Z = 32897.67 nT.
    let s = Site {
        lat_deg: 28.2,
        lon_deg: 112.97,
        alt_m: 0.0,
        year: 2013.0,
    };
    let got = field_ned(Model::Wmm2010, &s).unwrap();
    for (g, want) in got.iter().zip([35272.34, -2085.74, 32897.67]) {
        assert!((g - want).abs() <= 0.005, "{got:?}");
    }
    let field = reference_field(Model::Wmm2010, &s).unwrap();
    assert!((field.magnitude() - 48277.79).abs() < 0.01);
}

#[test]
fn invalid_sites_and_dates_are_errors() {
    let ok = Site {
        lat_deg: 10.0,
        lon_deg: 20.0,
        alt_m: 0.0,
        year: 2021.0,
    };
    assert!(field_ned(Model::Wmm2020, &ok).is_ok());
    for (model, s, name) in [
        (Model::Wmm2020, Site { year: 2019.99, ..ok }, "year"),
        (Model::Wmm2020, Site { year: 2025.01, ..ok }, "year"),
        (Model::Wmm2010, ok, "year"),
        (Model::Wmm2020, Site { lat_deg: 90.5, ..ok }, "lat_deg"),
        (
            Model::Wmm2020,
            Site {
                alt_m: -6378137.0,
                ..ok
            },
            "alt_m",
        ),
        (Model::Wmm2020, Site { alt_m: 850_001.0, ..ok }, "alt_m"),
        (
            Model::Wmm2020,
            Site {
                lat_deg: f64::NAN,
                ..ok
            },
            "lat_deg",
        ),
        (
            Model::Wmm2020,
            Site {
                alt_m: f64::INFINITY,
                ..ok
            },
            "alt_m",
        ),
    ] {
        let e = field_ned(model, &s).unwrap_err();
        let named = match e {
            ParameterError::OutOfRange { name, .. } | ParameterError::NonFinite { name, .. } => name,
            other => panic!("{other:?}"),
        };
        assert_eq!(named, name);
    }
    assert_eq!(Model::from_name("WMM2015v2"), Some(Model::Wmm2015v2));
    assert_eq!(Model::from_name("IGRF13"), None);
}

#[test]
fn poles_are_finite_and_continuous() {
    for lat in [90.0, -90.0] {
        let s = Site {
            lat_deg: lat,
            lon_deg: 0.0,
            alt_m: 0.0,
            year: 2020.0,
        };
        let at = field_ned(Model::Wmm2020, &s).unwrap();
        let near = field_ned(
            Model::Wmm2020,
            &Site {
                lat_deg: lat * (1.0 - 1e-7),
                ..s
            },
        )
        .unwrap();
        for i in 0..3 {
            assert!(at[i].is_finite() && (at[i] - near[i]).abs() < 0.1, "{at:?} {near:?}");
        }
    }
}

#[test]
fn decimal_years_take_the_middle_of_the_day_and_know_leap_years() {
    // 1 January is the first day: its middle is half a day into the year.
    assert_eq!(decimal_year("2013-01-01"), Ok(2013.0 + 0.5 / 365.0));
    // 2012 is a leap year: 1 March is day 61 of 366; in 2013 day 60 of 365.
    assert_eq!(decimal_year("2012-03-01"), Ok(2012.0 + 60.5 / 366.0));
    assert_eq!(decimal_year("2013-03-01"), Ok(2013.0 + 59.5 / 365.0));
    // 31 December ends the year: its middle is half a day before the next.
    assert_eq!(decimal_year("2000-12-31"), Ok(2000.0 + 365.5 / 366.0));
    assert_eq!(decimal_year(" 2013.25 "), Ok(2013.25));
    // Century years: 2000 is leap, 1900 and 2100 are not.
    assert!(is_leap_year(2000) && is_leap_year(2024) && !is_leap_year(1900) && !is_leap_year(2100));
    assert_eq!(decimal_year("2000-02-29"), Ok(2000.0 + 59.5 / 366.0));
    for (text, year, month, day) in [
        ("2100-02-29", 2100, 2, 29),
        ("2013-02-29", 2013, 2, 29),
        ("2013-13-01", 2013, 13, 1),
        ("2013-04-31", 2013, 4, 31),
        ("2013-01-00", 2013, 1, 0),
    ] {
        assert_eq!(
            decimal_year(text),
            Err(DateError::NotADate { year, month, day }),
            "{text}"
        );
    }
}

#[test]
fn decimal_years_are_bounded_and_malformed_dates_named() {
    assert_eq!(decimal_year("1900-01-01"), Ok(1900.0 + 0.5 / 365.0));
    assert_eq!(decimal_year("2100-12-31"), Ok(2100.0 + 364.5 / 365.0));
    assert_eq!(decimal_year("1899-12-31"), Err(DateError::OutOfRange(1899.0)));
    assert_eq!(decimal_year("20130"), Err(DateError::OutOfRange(20130.0)));
    assert_eq!(decimal_year("2101"), Err(DateError::OutOfRange(2101.0)));
    assert_eq!(decimal_year("1899.999"), Err(DateError::OutOfRange(1899.999)));
    assert!(matches!(decimal_year("NaN"), Err(DateError::OutOfRange(y)) if y.is_nan()));
    assert!(matches!(decimal_year("inf"), Err(DateError::OutOfRange(_))));
    for text in [
        "2013/01/01",
        "13-01-01",
        "2013-1",
        "2013-01-01-01",
        "yesterday",
        "2013-+1-01",
        "",
    ] {
        assert!(matches!(decimal_year(text), Err(DateError::Format(_))), "{text}");
    }
    // The text in the error is cut.
    let long = "x".repeat(1000);
    assert_eq!(
        decimal_year(&long).unwrap_err().to_string().len(),
        42 + ": give YYYY-MM-DD or a decimal year".len()
    );
}
