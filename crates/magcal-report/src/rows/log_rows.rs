//! The rows of the CSV files the log commands write, one type per file, shared by the writer and
//! every reader (the tests), as the rows of a run's result set are in [`super`].

use serde::{Deserialize, Serialize};

use super::{Derived, Real};

/// `residuals.csv` of `calibrate --out`: one row per reading fitted, with its 1-based line in the
/// log, the raw reading, the calibrated field `b = P (raw - bias)`, its norm and `norm - R`, in
/// the log's units; with the log's attitude, where it has one, as roll, pitch and compass heading
/// in degrees (empty cells where it has none). The raw reading as read, the rest to
/// [`Derived::DIGITS`] significant digits.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ResidualRow {
    pub line: usize,
    pub raw_x: Real,
    pub raw_y: Real,
    pub raw_z: Real,
    pub x: Derived,
    pub y: Derived,
    pub z: Derived,
    pub norm: Derived,
    pub residual: Derived,
    pub roll_deg: Option<Derived>,
    pub pitch_deg: Option<Derived>,
    pub heading_deg: Option<Derived>,
}

/// The output of `apply`: one row per reading of the log, its 1-based line, the calibrated field
/// and its norm, in the log's units.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AppliedRow {
    pub line: usize,
    pub x: Real,
    pub y: Real,
    pub z: Real,
    pub norm: Real,
}

/// The log `simulate` writes: one row per reading, the attitude (degrees) and the noisy reading
/// (nT).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SimulatedRow {
    pub roll_deg: Real,
    pub yaw_deg: Real,
    pub pitch_deg: Real,
    /// The true heading of the nose, clockwise from north: with `roll_deg` and `pitch_deg`, the
    /// attitude as autopilots log it (`calibrate --euler roll_deg,pitch_deg,true_heading_deg`).
    pub true_heading_deg: Real,
    pub mx: Real,
    pub my: Real,
    pub mz: Real,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rows::{header, parse_csv, write_csv};

    #[test]
    fn headers_are_the_documented_columns() {
        assert_eq!(
            header::<ResidualRow>().unwrap().iter().collect::<Vec<_>>(),
            [
                "line",
                "raw_x",
                "raw_y",
                "raw_z",
                "x",
                "y",
                "z",
                "norm",
                "residual",
                "roll_deg",
                "pitch_deg",
                "heading_deg"
            ]
        );
        assert_eq!(
            header::<AppliedRow>().unwrap().iter().collect::<Vec<_>>(),
            ["line", "x", "y", "z", "norm"]
        );
        assert_eq!(
            header::<SimulatedRow>().unwrap().iter().collect::<Vec<_>>(),
            ["roll_deg", "yaw_deg", "pitch_deg", "true_heading_deg", "mx", "my", "mz"]
        );
    }

    #[test]
    fn rows_round_trip_exactly() {
        let rows = vec![
            AppliedRow {
                line: 7,
                x: Real(0.1 + 0.2),
                y: Real(-1e-300),
                z: Real(48_000.123_456_789),
                norm: Real(f64::MAX),
            },
            AppliedRow::default(),
        ];
        let mut bytes = Vec::new();
        write_csv(rows.clone(), &mut bytes).unwrap();
        assert!(
            String::from_utf8(bytes.clone())
                .unwrap()
                .starts_with("line,x,y,z,norm\n7,0.30000000000000004,")
        );
        assert_eq!(parse_csv::<AppliedRow>(&bytes, "test").unwrap(), rows);
    }
}
