//! magcal's result sets, read and shown: the typed rows of their CSV files and their manifests
//! ([`rows`], [`manifest`]), the self-contained HTML pages of `magcal report`, `calibrate
//! --report`, `evaluate --report`, `next --report` and `replay` ([`pages`]), and the SVG and PNG
//! figures of a result set ([`figures`]).
//!
//! A set is read from its files alone: nothing here runs a scenario, fits a log or knows the
//! command line (`magcal-runner` writes the sets; `magcal-core` holds the math). Every file is
//! read within the bounds of [`magcal_logs::limits`], and a manifest's own hash is checked before
//! a page trusts it.
//!
//! # Example
//! A `summary.csv` read back with its exact numbers, and a figure's row type named by its header:
//! ```
//! use magcal_report::rows::{self, Metric, SummaryRow};
//!
//! fn main() -> anyhow::Result<()> {
//!     let header = rows::header::<SummaryRow>()?;
//!     assert_eq!(&header[0], "design");
//!     let row = SummaryRow {
//!         design: "optimum".into(),
//!         metric: Metric::EtaPsi,
//!         mean: Some(rows::Real(9.4)),
//!         ..SummaryRow::default()
//!     };
//!     let bytes = rows::csv_bytes([row.clone()])?;
//!     let back: Vec<SummaryRow> = rows::parse_csv(&bytes, "summary.csv")?;
//!     assert_eq!(back, [row]);
//!     Ok(())
//! }
//! ```

pub mod figures;
pub mod manifest;
pub mod pages;
pub mod rows;
