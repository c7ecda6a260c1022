//! The vehicle a log is judged against: its site's field, its attitude box, from a scenario file
//! or from flags.

use std::path::Path;

use anyhow::{Context, Result, bail};
use clap::Args;
use magcal_core::Vec3;
use magcal_core::budget::{IDENTITY, PAPER_TO_FRD};
use magcal_core::small::{Mat3, dot, mat_mul, mat_vec, norm, scale, sub, upper_triangular_inverse};
use magcal_core::stop::{Stop, Stopped};

use super::calibration::CalibrationJson;
pub use super::gps::Place;
use crate::scenario::site::{wmm_label, wmm_pick, wmm_place};

/// `--roll`, `--pitch`, `--yaw MIN,MAX`: an attitude range in degrees, under the rules the
/// scenario's `[attitude_box]` follows ([`crate::scenario::check_range`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range(pub [f64; 2]);

impl std::str::FromStr for Range {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let v: Vec<f64> = text
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| "give MIN,MAX in degrees".to_string())?;
        let [a, b] = v[..] else {
            return Err("give MIN,MAX in degrees (two numbers)".into());
        };
        crate::scenario::check_range([a, b]).map_err(str::to_string)?;
        Ok(Self([a, b]))
    }
}

/// A vehicle's attitude box as flags (with `--site` and `--date` for the field's direction).
#[derive(Debug, Clone, Args)]
pub struct BoxFlags {
    /// Roll range, degrees: `MIN,MAX` (with `--site`).
    #[arg(long, requires = "site", allow_hyphen_values = true, value_name = "MIN,MAX")]
    pub roll: Option<Range>,
    /// Pitch range, degrees: `MIN,MAX` (with `--site`).
    #[arg(long, requires = "site", allow_hyphen_values = true, value_name = "MIN,MAX")]
    pub pitch: Option<Range>,
    /// Yaw range, degrees: `MIN,MAX` (with `--site`; default any yaw).
    #[arg(long, requires = "site", allow_hyphen_values = true, value_name = "MIN,MAX")]
    pub yaw: Option<Range>,
}

impl BoxFlags {
    /// Whether any of the flags is given.
    pub fn any(&self) -> bool {
        self.roll.is_some() || self.pitch.is_some() || self.yaw.is_some()
    }
}

/// What `next` and the coverage need of a vehicle: its site's field (nT), its attitude box, the
/// certificate's search and a seed; from a scenario file or from flags.
pub struct Vehicle {
    pub field: magcal_core::ReferenceField,
    /// Where the field comes from, in words (the scenario's `[field]`, or the WMM at the site).
    pub field_source: String,
    pub bounds: magcal_core::AttitudeBox,
    pub certificate: magcal_core::design::approximate::Approximate,
    pub seed: u64,
    pub label: String,
}

impl Vehicle {
    /// The certificate of the vehicle's box under `problem`'s sensor, from the stream `run` uses
    /// for the same seed; `None` when no design in the box identifies the linear model.
    pub fn certificate(
        &self,
        problem: &magcal_core::design::DesignProblem,
    ) -> Option<magcal_core::design::approximate::Certificate> {
        self.certificate_until(problem, &Stop::NEVER).ok().flatten()
    }

    /// [`Self::certificate`], given up when `stop` is requested ([`Stopped`]).
    ///
    /// # Errors
    /// [`Stopped`] when `stop` was requested before the search finished.
    pub fn certificate_until(
        &self,
        problem: &magcal_core::design::DesignProblem,
        stop: &Stop,
    ) -> Result<Option<magcal_core::design::approximate::Certificate>, Stopped> {
        let mut rng = crate::pipeline::certificate_rng(self.seed);
        let design = self.certificate.compute_until(problem, &mut rng, stop)?;
        Ok(design.ok().map(|a| a.certificate))
    }

    pub fn from_scenario(path: &Path) -> Result<Self> {
        let s = crate::scenario::load(path)?;
        Ok(Self {
            field: s.field,
            field_source: format!("{}, from {}", s.field_source, path.display()),
            bounds: s.bounds,
            certificate: s.certificate,
            seed: s.seed,
            label: path.display().to_string(),
        })
    }

    /// The vehicle of `--scenario`, else of the box flags at `place`; `None` when neither is
    /// given.
    ///
    /// # Errors
    /// A bad scenario, one of `--roll` and `--pitch` without the other, box flags without a
    /// place, or a place no model holds.
    pub fn from_options(scenario: Option<&Path>, flags: &BoxFlags, place: Option<&Place>) -> Result<Option<Self>> {
        match (scenario, flags.roll, flags.pitch, place) {
            (Some(path), ..) => Self::from_scenario(path).map(Some),
            (None, Some(roll), Some(pitch), Some(place)) => Self::from_flags(roll, pitch, flags.yaw, place).map(Some),
            (None, Some(_), Some(_), None) => bail!("the box as flags needs --site and --date"),
            (None, None, None, _) if flags.yaw.is_none() => Ok(None),
            _ => bail!("the box as flags needs both --roll and --pitch"),
        }
    }

    /// `--roll, --pitch [--yaw] --site --date [--wmm]`.
    ///
    /// # Errors
    /// A box the core refuses, or a place no model holds.
    pub fn from_flags(roll: Range, pitch: Range, yaw: Option<Range>, place: &Place) -> Result<Self> {
        let (roll, pitch) = (roll.0, pitch.0);
        let yaw = yaw.map_or([-180.0, 180.0], |y| y.0);
        let bounds = magcal_core::AttitudeBox::from_degrees(roll, yaw, pitch).context("the attitude box")?;
        let (ned, model, at) = wmm_pick(&place.site, place.date, place.model)?;
        let source = wmm_label(ned, model, &at);
        let field = magcal_core::ReferenceField::from_ned(ned[0], ned[1], ned[2]).context("the WMM field")?;
        Ok(Self {
            field,
            field_source: wmm_place(model, &at),
            bounds,
            certificate: Default::default(),
            seed: 0,
            label: format!("roll {roll:?}, pitch {pitch:?}, yaw {yaw:?} deg, {source}"),
        })
    }
}

/// The narrowest range of roll, pitch or yaw a box may have, degrees: the attitude accuracy of a
/// navigation-grade reference. A narrower range is a fixed angle written as a range, which no
/// vehicle holds and no reference resolves; searched, it gives rounding (a box 1e-9 degree wide
/// gave a certificate of NaN).
pub const MIN_RANGE_DEG: f64 = 0.01;

/// Every range of the vehicle's box at least [`MIN_RANGE_DEG`] wide.
///
/// # Errors
/// The first range that is narrower, named with its width.
pub fn check_box(scenario: &Vehicle) -> Result<()> {
    for (name, range) in ["roll", "yaw", "pitch"].iter().zip(scenario.bounds.ranges()) {
        let width = range.width().to_degrees();
        if width < MIN_RANGE_DEG {
            bail!(
                "the box of {}: the {name} range is {width:.3e} degree wide; a range narrower than {MIN_RANGE_DEG} degree (a navigation-grade reference's accuracy) is a fixed angle and cannot be searched",
                scenario.label
            );
        }
    }
    Ok(())
}

/// The fitted sensor as a design problem in the vehicle's field (nT) and box, and the factor from
/// the log's units to nT (only the field's direction comes from the site).
///
/// # Errors
/// A range of the box narrower than [`MIN_RANGE_DEG`], or a sensor the model does not take.
pub fn fitted_problem(cal: &CalibrationJson, scenario: &Vehicle) -> Result<(magcal_core::design::DesignProblem, f64)> {
    check_box(scenario)?;
    let field = scenario.field;
    let factor = field.magnitude() / cal.magnitude;
    if !(factor.is_finite() && factor > 0.0) {
        bail!("magnitude {} is not usable", cal.magnitude);
    }
    let model = magcal_core::ErrorModel::new(cal.psi_deg, cal.scale, cal.bias.map(|b| b * factor))
        .context("the fitted sensor is outside what the model takes")?;
    Ok((
        magcal_core::design::DesignProblem::new(field, model, scenario.bounds, 9)?,
        factor,
    ))
}

/// The axes a log's readings are planned in against a box.
///
/// The design problem's attitudes give body fields in \[P1\]'s axes (nose, up, right); a sensor
/// whose readings are in other axes (an autopilot's forward, right, down: `frame` turns \[P1\]'s
/// axes into them) reads `s = K frame b + O` there, which is no sensor of the problem's form
/// (`K` upper triangular in \[P1\]'s axes). A fixed rotation of every reading leaves the
/// D-criterion as it is (the regression row of a turned reading, \[P1\] eq. (9), is a fixed linear
/// map of its row, of determinant 1), so the readings are turned by `R` with `R K frame = T`
/// upper triangular (a QR decomposition) and the sensor planned with is `(T, R O)`: its
/// calibrated readings are then the body fields in \[P1\]'s axes. Readings already in \[P1\]'s
/// axes (a CSV log planned against a box) are left as they are, bit for bit.
#[derive(Debug, Clone, Copy)]
pub struct DesignAxes {
    /// `R` and `T`; `None`: the identity and the calibration's own `K`.
    turn: Option<(Mat3, Mat3)>,
}

impl DesignAxes {
    /// The axes of a log whose readings are in `frame` (see [`readings_frame`]) under the sensor
    /// of `cal`.
    pub fn of(cal: &CalibrationJson, frame: &Mat3) -> Self {
        if *frame == IDENTITY {
            return Self { turn: None };
        }
        // Gram-Schmidt on the columns of M = K frame: M = Q T, R = Q^T.
        let m = mat_mul(&cal.k, frame);
        let column = |j: usize| [m[0][j], m[1][j], m[2][j]];
        let mut q: Vec<Vec3> = Vec::with_capacity(3);
        for j in 0..3 {
            let mut v = column(j);
            for u in &q {
                let c = dot(*u, v);
                v = sub(v, scale(c, *u));
            }
            q.push(scale(1.0 / norm(v), v));
        }
        let r = [q[0], q[1], q[2]];
        let mut t = mat_mul(&r, &m);
        // Below the diagonal is rounding.
        (t[1][0], t[2][0], t[2][1]) = (0.0, 0.0, 0.0);
        Self { turn: Some((r, t)) }
    }

    /// A reading turned into these axes.
    pub fn turn(&self, s: Vec3) -> Vec3 {
        self.turn.map_or(s, |(r, _)| mat_vec(&r, s))
    }

    /// `cal` (the one these axes are [`Self::of`]) as the sensor of these axes: `K = T`,
    /// `P = T^-1`, the bias turned, and `psi` and the scale factors of `T`.
    pub fn calibration(&self, cal: &CalibrationJson) -> CalibrationJson {
        let Some((r, t)) = self.turn else {
            return cal.clone();
        };
        let sensor = magcal_core::ErrorModel::from_k(&t, mat_vec(&r, cal.bias));
        let mut out = cal.clone();
        out.k = t;
        out.p = upper_triangular_inverse(&t).unwrap_or(cal.p);
        out.bias = sensor.bias_nt();
        out.psi_deg = sensor.psi_deg();
        out.scale = sensor.scale();
        out
    }
}

/// The rotation of \[P1\]'s body axes into the axes of a log's readings: an autopilot's forward,
/// right, down for a flight log, \[P1\]'s own for a CSV log (whose box is given in them), as the
/// heading budget takes them (docs/conventions.md "Heading budget").
pub fn readings_frame(format: crate::log::flight::Format) -> Mat3 {
    match format {
        crate::log::flight::Format::Csv => IDENTITY,
        _ => PAPER_TO_FRD,
    }
}

/// The certified D-efficiency per reading of `readings` (the log's units, in `frame`: see
/// [`DesignAxes`]) in the scenario's box:
/// `None` when no design in the box determines the linear model. Above 1 when the readings hold
/// more information per reading than any design in the box: they come from outside it. Inside,
/// [`Stopped`] when `stop` was requested before the box's certificate was found.
///
/// # Errors
/// As [`fitted_problem`].
pub fn log_efficiency(
    cal: &CalibrationJson,
    scenario: &Vehicle,
    (readings, frame): (&[magcal_core::Vec3], &Mat3),
    stop: &Stop,
) -> Result<Result<Option<f64>, Stopped>> {
    let axes = DesignAxes::of(cal, frame);
    let (problem, factor) = fitted_problem(&axes.calibration(cal), scenario)?;
    let scaled: Vec<magcal_core::Vec3> = readings.iter().map(|&s| axes.turn(s).map(|v| v * factor)).collect();
    let info = magcal_core::InformationMatrix::from_readings(&scaled, scenario.field.magnitude());
    Ok(scenario
        .certificate_until(&problem, stop)
        .map(|c| c.map(|c| c.efficiency_bound(info.ln_det_nt(), readings.len()))))
}

#[cfg(test)]
mod tests {
    use super::Range;

    #[test]
    fn ranges_follow_the_scenario_rules() {
        assert_eq!("-5,5".parse::<Range>(), Ok(Range([-5.0, 5.0])));
        assert_eq!(" -180 , 180 ".parse::<Range>(), Ok(Range([-180.0, 180.0])));
        for (text, needle) in [
            ("5,-5", "the minimum must be below the maximum"),
            ("5,5", "the minimum must be below the maximum"),
            ("-400,0", "[-360, 360]"),
            ("-200,200", "more than 360"),
            ("nan,1", "finite"),
            ("1", "two numbers"),
            ("a,b", "give MIN,MAX"),
        ] {
            let e = text.parse::<Range>().unwrap_err();
            assert!(e.contains(needle), "{text}: {e}");
        }
    }
}
