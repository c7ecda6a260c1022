//! `calibration.json`: what `calibrate` writes and `apply` and `next` read.

use std::path::Path;

use anyhow::{Result, bail};
use magcal_core::small::Mat3;
use serde::{Deserialize, Serialize};

use super::flight::Format;
use super::parameters::LogParameters;
use super::source::{LogArgs, format_of};
use crate::limits::excerpt;

/// Standard errors of the fitted parameters; `null` where the information is singular.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StdError {
    pub psi_deg: Option<[f64; 3]>,
    pub scale: Option<[f64; 3]>,
    pub bias: Option<[f64; 3]>,
}

/// `calibration.json` and the `--json` output.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CalibrationJson {
    pub log: String,
    // What the calibration was made from. A file written before these fields existed lacks them
    // (`null`): its numbers are still checked, the log's identity is not.
    /// [`FORMAT`]: a file of another format is refused rather than misread.
    #[serde(default)]
    pub format: Option<String>,
    /// The magcal version that wrote the file.
    #[serde(default)]
    pub magcal_version: Option<String>,
    /// The SHA-256 of the log's bytes, lowercase hex: `next` warns when given another log.
    #[serde(default)]
    pub log_sha256: Option<String>,
    /// The log's data rows: readings fitted, skipped and rejected.
    #[serde(default)]
    pub log_rows: Option<usize>,
    /// The log's units where `calibrate` was told them (`--units`), else `null`.
    #[serde(default)]
    pub units: Option<String>,
    /// The log's format ([`crate::flight::Format::name`]); `null` in a file written before
    /// flight logs were read (a CSV log).
    #[serde(default)]
    pub log_format: Option<String>,
    /// The magnetometer instance read from a flight log (`--compass`), numbered as the log
    /// numbers it.
    #[serde(default)]
    pub instance: Option<u8>,
    /// The readings' frame in words where the log says it (`body (forward, right, down)`,
    /// `sensor`).
    #[serde(default)]
    pub frame: Option<String>,
    /// The messages or columns the readings and what was logged beside them came from.
    #[serde(default)]
    pub log_messages: Vec<String>,
    /// The calibration the logged field carried and what was done about it (flight logs): `raw`,
    /// `undone: ...` or `calibrated: ...` (a fit then calibrates the calibrated sensor).
    #[serde(default)]
    pub in_force: Option<String>,
    /// What the reader and the cut (window, rate) say about the log, one sentence each.
    #[serde(default)]
    pub log_notes: Vec<String>,
    /// What a flight log says of its firmware's parameters, for `export`: which of those export
    /// writes it has, and `COMPASS_OFFS_MAX`; `null` for a CSV log, a log that says nothing of
    /// them, and a file written before this field existed.
    #[serde(default)]
    pub log_parameters: Option<LogParameters>,
    /// The time span of the readings fitted, seconds on the log's clock, where it has times.
    #[serde(default)]
    pub time_span_s: Option<[f64; 2]>,
    /// With attitudes in the log: the heading the calibration gives against them.
    #[serde(default)]
    pub heading_vs_log: Option<HeadingCheckJson>,
    /// With times in the log: whether the field the calibration maps the readings to stays one
    /// field over time (docs/conventions.md "One field"); `null` without times.
    #[serde(default)]
    pub field_change: Option<FieldChangeJson>,
    /// Brief passes through another field (a magnet or iron passed close by): runs of readings
    /// whose calibrated magnitude departs from the field's, and what they do to the calibration
    /// (docs/conventions.md "One field"); `null` where the fit is not identifiable.
    #[serde(default)]
    pub passes: Option<PassesJson>,
    /// The motor interference fitted with the calibration (`calibrate --motor`), else `null`.
    #[serde(default)]
    pub motor: Option<MotorJson>,
    /// A vector calibration's alignment (`calibrate --fit vector`), else `null`: the body-frame
    /// field of a reading is `alignment.rotation P (raw - bias)`.
    #[serde(default)]
    pub alignment: Option<AlignmentJson>,
    pub columns: [String; 3],
    pub samples: usize,
    pub skipped: usize,
    /// Readings dropped by `--reject` (0 without it).
    pub rejected: usize,
    pub fit: String,
    /// With `--fit auto`: why this model.
    pub fit_reason: Option<String>,
    pub magnitude: f64,
    /// `given`, `fitted mean radius (...)` or `radius of the best-fitting sphere (...)`.
    pub magnitude_source: String,
    /// Where the site and date of the World Magnetic Model's field come from: `--site` and
    /// `--date`, or the log's GPS fixes (which fix, which message), or why the log's GPS gives
    /// none; `null` where there is neither.
    #[serde(default)]
    pub place_source: Option<String>,
    /// Where a flight log's attitudes' heading comes from (`--heading-from`), in words; `null`
    /// for logs without attitudes or CSV logs.
    #[serde(default)]
    pub heading_source: Option<String>,
    /// A vector fit against a field given per reading: the heading's standard error the bias's
    /// largest standard error leaves, degrees (`atan(std O / horizontal field)`).
    #[serde(default)]
    pub heading_std_deg: Option<f64>,
    /// Where that heading is worse than a usable compass's: the manoeuvres of largest gain in
    /// information, in a pilot's words, with the bias's standard errors each would give.
    #[serde(default)]
    pub next_manoeuvres: Vec<String>,
    /// With them: the headings the flight never flew (30-degree sectors holding under 1 % of the
    /// readings), `[from, to)` in degrees clockwise from north (`to` past 360 through north).
    #[serde(default)]
    pub headings_never_flown: Vec<[f64; 2]>,
    pub bias: [f64; 3],
    pub psi_deg: [f64; 3],
    pub scale: [f64; 3],
    /// `K = P^-1`: raw = K b + bias.
    pub k: Mat3,
    /// `b = P (raw - bias)`, upper triangular (\[P1\] eq. (6)).
    pub p: Mat3,
    /// `b = A^-1 (raw - bias)` with `A^-1` the symmetric square root of `G = P^T P` (Magneto,
    /// MotionCal, ArduPilot).
    pub soft_iron_inverse: Mat3,
    pub residual_rms: f64,
    pub residual_max: f64,
    pub residual_rms_percent: f64,
    /// The noise per component the standard errors rest on, in the log's units: given
    /// (`--noise`) or estimated from the residuals; `null` when neither (an exact fit).
    pub noise: Option<f64>,
    pub std_error: StdError,
    pub identifiable: bool,
    pub verdict: String,
    /// For a reduced model (`diagonal`, `offset`): its lack-of-fit F test against the richer
    /// models fitted to the same readings (`null` for `full`).
    pub lack_of_fit: Option<LackOfFitJson>,
    pub status: String,
    pub iterations: usize,
    pub coverage: Coverage,
    /// A calibration to use: identifiable, its model not rejected by the log, the readings on an
    /// ellipsoid, and standard errors known.
    #[serde(default)]
    pub usable: bool,
    /// Why not `usable`, one reason each.
    #[serde(default)]
    pub reasons: Vec<String>,
    /// Where `noise` comes from and how sure it is.
    #[serde(default)]
    pub noise_estimate: Option<NoiseJson>,
    /// Half-widths of the 95 % confidence intervals (`null` where the standard errors are
    /// unknown).
    #[serde(default)]
    pub interval95: Option<IntervalJson>,
    /// Whether the readings lie on an ellipsoid.
    #[serde(default)]
    pub ellipsoid: Option<EllipsoidJson>,
    /// The residual the fit minimised: `readings` (each reading's distance from the ellipsoid,
    /// the default) or `paper` (\[P1\]'s `|P (raw - bias)| - R`); `null` in older files.
    #[serde(default)]
    pub residual: Option<String>,
    /// The noise `--noise` gave (the log's units), whether or not it explains the scatter.
    #[serde(default)]
    pub given_noise: Option<f64>,
    /// For readings in time order: the correlation of the residuals the standard errors allow
    /// for.
    #[serde(default)]
    pub correlation: Option<CorrelationJson>,
    /// The verdict by noisy trials at the log's own readings (docs/conventions.md "The verdict of
    /// a log"); `null` where none was run (the noise unknown).
    #[serde(default)]
    pub check: Option<CheckJson>,
    /// What each standard error is: `white noise`, `long-run covariance`, `trials`, `held out`,
    /// `fixed` (the largest of those that apply is the one reported).
    #[serde(default)]
    pub std_error_source: Option<StdSourceJson>,
    /// The fits made without each fold of the log (docs/conventions.md "Held out"); `null` where
    /// none were made (a fit that is not identifiable, a vector fit's scalar start).
    #[serde(default)]
    pub held_out: Option<HeldOutJson>,
    /// The heading the calibration leaves against the user's budget (docs/conventions.md "Heading
    /// budget"); `null` where it could not be judged (no standard errors).
    #[serde(default)]
    pub heading_budget: Option<HeadingBudgetJson>,
}

/// What each standard error of `calibration.json` rests on.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StdSourceJson {
    pub psi_deg: [String; 3],
    pub scale: [String; 3],
    pub bias: [String; 3],
}

/// The held-out fits of a log: the core's [`magcal_core::log_fit::HeldOut`] and its words.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct HeldOutJson {
    #[serde(flatten)]
    pub held_out: magcal_core::log_fit::HeldOut,
    /// Whether the fits without a fold give evidence at all (three folds or more determine the
    /// calibration).
    pub evidence: bool,
    pub words: String,
}

/// The heading budget's verdict: the core's [`magcal_core::budget::HeadingVerdict`], where its
/// field and axes come from, and its words.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct HeadingBudgetJson {
    #[serde(flatten)]
    pub verdict: magcal_core::budget::HeadingVerdict,
    /// The larger of the trials' and the standard errors' 95th percentiles, degrees.
    pub predicted_deg: f64,
    /// Where the inclination comes from, in words (the WMM at a site, the log's attitudes, or
    /// assumed).
    pub field: String,
    /// Which of the readings' axes is up at level, in words.
    pub axes: String,
    pub words: String,
    /// Where the budget is not met and the box is known: what `next` says to fly, and the
    /// heading the log with it is predicted to leave.
    #[serde(default)]
    pub next: Option<String>,
}

/// The residuals' correlation in time and what it does to the standard errors.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CorrelationJson {
    /// The batch length of the long-run covariance, readings.
    pub batch_readings: usize,
    /// The same in seconds (the median interval of the log's times), where known.
    pub batch_seconds: Option<f64>,
    /// The residuals' lag-one autocorrelation in time order.
    pub lag_one: Option<f64>,
    /// The standard errors white noise would give (`std_error` holds the larger of these and the
    /// long-run ones).
    pub white_std_error: StdError,
}

/// A log's check by trials.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CheckJson {
    /// Trials asked for (`--trials`).
    pub planned: usize,
    /// Trials run: fewer than planned once more had failed than a pass allows.
    pub trials: usize,
    pub ok: usize,
    pub not_converged: usize,
    pub not_identifiable: usize,
    pub failed: usize,
    /// At least 95 % of the trials `ok`.
    pub passed: bool,
    /// The noise the trials drew, in words.
    pub noise: String,
    /// The seed of the trials' streams.
    pub seed: u64,
    /// The trials drew every `every`-th reading of the log (a long log is judged on a part of
    /// it first, `log_fit::JUDGED_READINGS`); 1: all of them.
    #[serde(default = "one")]
    pub every: usize,
    /// The readings each trial drew (0 in a calibration written before this was recorded).
    #[serde(default)]
    pub readings: usize,
    /// The check in words.
    pub words: String,
}

/// `every` of a check that does not say: the whole log.
fn one() -> usize {
    1
}

/// Motor interference: the raw reading carries `d * u` on top of the sensor's `K b + O`, with
/// `u` the battery current or the throttle at the reading.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MotorJson {
    /// `current` (amperes) or `throttle` (0 to 1).
    pub input: String,
    /// `d`: the raw reading's change per unit of `input`, in the log's units, in the readings'
    /// frame.
    pub per_unit: [f64; 3],
    /// Standard errors of `per_unit`, `null` where unknown.
    pub std_error: Option<[f64; 3]>,
    /// The range of `input` over the readings fitted.
    pub input_range: [f64; 2],
}

/// A vector calibration against reference attitudes (docs/conventions.md "Vector
/// calibration"): `raw = K C^T F + bias`, `K^-1 = rotation P`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AlignmentJson {
    /// `A`: the rotation of \[P1\]'s sensor frame (the frame of `P`) into the body frame
    /// (forward, right, down); the body-frame field is `A P (raw - bias)`.
    pub rotation: Mat3,
    /// The angle of `rotation`, degrees.
    pub angle_deg: f64,
    /// Its axis, a unit vector in the body frame.
    pub axis: [f64; 3],
    /// `S`: the rotation mapping the axes onto each other nearest `rotation` (the sensor
    /// mounted along the body's axes in some orientation).
    pub whole_step: Mat3,
    /// The angle of `M = rotation S^T`, degrees: the misalignment beyond the whole step, which
    /// a scalar calibration cannot see.
    pub misalignment_deg: f64,
    /// Its axis, a unit vector in the body frame.
    pub misalignment_axis: [f64; 3],
    /// Standard error of `misalignment_deg` (delta method), `null` where unknown.
    pub std_misalignment_deg: Option<f64>,
    /// Standard errors of the misalignment's rotation vector (axis times angle), degrees.
    pub std_misalignment_vector_deg: Option<[f64; 3]>,
    /// The whole `K`: `raw = K C^T F + bias`.
    pub k_full: Mat3,
    /// Standard errors of `k_full`.
    pub std_k_full: Option<Mat3>,
    /// `F`, the field in the reference frame (z up: east, north, up where the attitudes are
    /// geographic), the log's units.
    pub field: [f64; 3],
    /// Standard errors of `field` (zero where given).
    pub std_field: Option<[f64; 3]>,
    /// Where `field` comes from: the WMM, or fitted with its magnitude fixed.
    pub field_source: String,
    /// Readings with an attitude, fitted.
    pub readings: usize,
    /// RMS of the residual components `raw - K C^T F - bias`, the log's units.
    pub residual_rms: f64,
    /// Residual degrees of freedom, `3 readings - unknowns`.
    pub dof: usize,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// Heading and direction errors of `A P (raw - bias)` against the attitudes with the
    /// alignment held (`Q` = identity) and `F` as fitted or given; `null` where undefined.
    pub heading_held: Option<HeadingFiguresJson>,
}

/// The heading a calibration gives against the attitudes a log carries (docs/conventions.md
/// "Heading against a reference attitude"): against the autopilot's own estimate, which was made
/// with the calibration in force when it flew, a figure of consistency, not of truth.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct HeadingCheckJson {
    /// Readings with an attitude.
    pub readings: usize,
    /// What the attitudes are, in words.
    pub against: String,
    /// The calibrated readings `P (raw - bias)`.
    pub calibrated: Option<HeadingFiguresJson>,
    /// The raw readings taken as calibrated, for comparison.
    pub uncalibrated: Option<HeadingFiguresJson>,
    /// Why there are no figures, where there are none.
    pub error: Option<String>,
    /// The calibrated heading rms against the raw one, with the standard error of the difference.
    #[serde(default)]
    pub versus_raw: Option<VersusRawJson>,
}

/// The calibrated heading against the raw one over the same readings (docs/conventions.md "One
/// field").
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct VersusRawJson {
    /// Calibrated minus raw heading rms, degrees.
    pub difference_deg: f64,
    /// Its standard error (delete-one-block jackknife), degrees; `null` with too few blocks.
    pub std_error_deg: Option<f64>,
    /// Blocks of time (or of readings, in a log without times).
    pub blocks: usize,
    /// What a block is, in words.
    pub block: String,
    /// The difference beyond which the calibration is worse: `sigmas` standard errors, degrees.
    pub limit_deg: Option<f64>,
    /// Standard errors of the limit.
    pub sigmas: f64,
    /// The calibration's heading is worse than the raw readings' beyond chance.
    pub worse: bool,
}

/// Whether the field stays one field over the log's time.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FieldChangeJson {
    /// Whether the log was searched: it has times, enough of them, and a calibration that settles
    /// to measure the field with; `words` says why not.
    pub tested: bool,
    /// The field changes within the log.
    pub changed: bool,
    /// The calibration whose magnitudes were searched, in words.
    pub measured_with: String,
    /// The pieces between changes, in time order (one: no change).
    pub segments: Vec<FieldSegmentJson>,
    /// The smallest change that counts, percent of the magnitude.
    pub step_percent: f64,
    /// The z a change needs.
    pub z: f64,
    /// The shortest piece, seconds.
    pub min_part_s: f64,
    /// The blocks' length, seconds: a change lies within a block of a cut.
    pub block_s: f64,
    /// The changes found, in the order cut: each window, its z and its difference from the rest.
    #[serde(default)]
    pub changes: Vec<FieldCutJson>,
    /// Of the windows not cut: the largest z.
    pub largest_z: Option<f64>,
    /// Of the windows not cut with z at least `z`: the largest change, percent of the magnitude.
    pub largest_step_percent: Option<f64>,
    /// What was found, in words.
    pub words: String,
}

/// The passes of a log through another field, and whether they move its calibration.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PassesJson {
    /// The median calibrated magnitude, the log's units.
    pub magnitude: f64,
    /// The robust standard deviation of the calibrated magnitude, the log's units.
    pub noise: f64,
    /// The departure a reading needs: the larger of `share_percent` of the magnitude and
    /// `sigmas` times `noise`, the log's units.
    pub threshold: f64,
    pub share_percent: f64,
    pub sigmas: f64,
    /// Noise standard deviations at which a pass's edge ends.
    pub edge_sigmas: f64,
    /// The passes found, in log order.
    pub passes: Vec<PassJson>,
    /// Readings within them.
    pub readings: usize,
    /// The largest difference between the calibration of the log without its passes and the
    /// calibration of the whole log, in the standard errors of the latter; `null` without passes
    /// or where it could not be measured.
    pub shift_std_errors: Option<f64>,
    /// The parameter that moves most, in words.
    pub shift_parameter: Option<String>,
    /// The largest shift that leaves the calibration usable, standard errors.
    pub shift_limit: f64,
    /// The passes make the calibration unusable.
    pub unusable: bool,
    /// What was found, in words.
    pub words: String,
}

impl PassesJson {
    /// What a usable calibration's verdict adds where the log passes through another field: the
    /// field where it was taken is not one field everywhere, so a heading taken near the passes is
    /// off whatever the calibration. `None` without passes.
    pub fn flag(&self) -> Option<String> {
        let n = self.passes.len();
        (n > 0).then(|| {
            format!(
                "FLAGGED: the log passes through another field {n} time{} ({} readings; a magnet or iron near the path, named under passes): the calibration without them is the same within its standard errors; a heading taken where they were is off",
                if n == 1 { "" } else { "s" },
                self.readings
            )
        })
    }
}

/// One pass through another field.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PassJson {
    /// The position of its first reading in the log (`position` names it: a CSV line, a flight
    /// log's byte offset).
    pub at: usize,
    pub position: String,
    /// Its span on the log's clock, seconds, where the log has times.
    pub from_s: Option<f64>,
    pub to_s: Option<f64>,
    pub readings: usize,
    /// Its largest departure, percent of the magnitude, signed.
    pub peak_percent: f64,
}

/// A window cut as a change of the field: against the rest of its piece.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FieldCutJson {
    pub from_s: f64,
    pub to_s: f64,
    pub z: f64,
    /// The rms change of the magnitude over the piece's readings between the window's fit and
    /// the rest's, percent of the magnitude.
    pub step_percent: f64,
}

/// A piece of the log between changes of the field.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FieldSegmentJson {
    /// Time of its first reading, seconds on the log's clock.
    pub from_s: f64,
    /// Time of its last reading.
    pub to_s: f64,
    pub readings: usize,
    /// Median calibrated magnitude under the calibration measured with (the log's units, at
    /// that calibration's scale).
    pub magnitude: f64,
    /// `magnitude / R - 1`, percent, with `R` the longest piece's median.
    pub level_percent: f64,
    /// The rms change of its readings' magnitude under the longest piece's field (level and hard
    /// iron) instead of its own, percent of the magnitude: how far it is from that field.
    pub change_percent: f64,
    /// In the field of the longest piece: `change_percent` below `step_percent`.
    pub in_field: bool,
}

/// Heading and direction errors, degrees.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct HeadingFiguresJson {
    pub heading_rms_deg: f64,
    pub heading_p95_deg: f64,
    pub heading_max_deg: f64,
    pub direction_rms_deg: f64,
}

/// Where the noise comes from.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NoiseJson {
    /// `given`, `residuals` or `unknown`.
    pub source: String,
    /// Residual degrees of freedom of an estimate.
    pub dof: Option<usize>,
    /// 95 % interval of an estimate (chi-square).
    pub interval95: Option<[f64; 2]>,
    /// `--reject K`: the estimate is corrected for the truncation at K.
    pub truncation_k: Option<f64>,
}

/// Half-widths of 95 % confidence intervals: `quantile` standard errors.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct IntervalJson {
    /// Student's t of the residual degrees of freedom, or 1.96 with a given noise.
    pub quantile: f64,
    pub psi_deg: [f64; 3],
    pub scale: [f64; 3],
    pub bias: [f64; 3],
}

/// The ellipsoid test.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EllipsoidJson {
    pub passed: bool,
    pub residual_rms_percent: f64,
    /// The limit on `residual_rms_percent`.
    pub limit_percent: f64,
    /// With `--noise`: the chi-square p-value of the readings' scatter about the ellipsoid.
    pub chi_square_p: Option<f64>,
    pub words: String,
}

/// [`magcal_core::log_fit::LackOfFit`] in the JSON.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LackOfFitJson {
    /// The richer model of the most significant test.
    pub against: String,
    pub f: f64,
    /// `[p_f - p_r, m - p_f]`.
    pub dof: [usize; 2],
    pub p_value: f64,
    /// `p_value` (Bonferroni over the richer models tested) below 1e-3: the log shows terms the
    /// model leaves out.
    pub rejected: bool,
    /// The test in words.
    pub words: String,
}

/// How well the log covers what the sensor can see.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Coverage {
    /// MotionCal's surface-gap error of the calibrated field directions, percent (0: every one of
    /// 100 equal-area regions holds at least three readings; 100: none).
    pub motioncal_gap_percent: f64,
    /// MicroStrain's spatial coverage of the calibrated field directions, percent: the share of
    /// 18 x 32 bins of 10 degrees of latitude by 11.25 of longitude holding at least one
    /// (MicroStrain calls more than 70 % good).
    pub microstrain_coverage_percent: f64,
    /// With `--scenario`: the certified D-efficiency per reading of the log's information against
    /// every design of as many readings in the scenario's box, under the fitted sensor.
    pub d_efficiency_per_reading: Option<f64>,
    /// Why `d_efficiency_per_reading` is `null` where a box was given and the certificate was not
    /// computed: a fit that does not determine the sensor the certificate would be made under
    /// (`not computed: ...`), or a bound in time (`live`'s: `skipped: the coverage certificate did
    /// not finish within 2 s`); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub d_efficiency_why_not: Option<String>,
    /// The scenario that gave the box.
    pub box_from: Option<String>,
    /// With attitudes in the log: the roll, pitch and heading it visited, against the box.
    #[serde(default)]
    pub flown: Option<super::flown::Flown>,
}

impl CalibrationJson {
    /// The calibrated field of a raw reading: `P (raw - bias)`.
    pub fn apply(&self, raw: magcal_core::Vec3) -> magcal_core::Vec3 {
        magcal_core::small::mat_vec(&self.p, magcal_core::small::sub(raw, self.bias))
    }

    /// The field of a raw reading in the body frame where the calibration carries an alignment
    /// (`rotation P (raw - bias)`), else [`Self::apply`].
    pub fn apply_body(&self, raw: magcal_core::Vec3) -> magcal_core::Vec3 {
        let b = self.apply(raw);
        self.alignment
            .as_ref()
            .map_or(b, |a| magcal_core::small::mat_vec(&a.rotation, b))
    }
}

/// The `format` this magcal writes and reads.
pub const FORMAT: &str = "magcal-calibration-1";

/// Largest Frobenius condition number `|P|_F |P^-1|_F` of a usable `p` (at least the 2-norm
/// condition number, at most 3 times it).
///
/// The calibrated field `P (raw - bias)` carries a reading's relative error amplified by up to
/// `cond(P)`: the ratio of the longest to the shortest axis of the ellipsoid the raw readings lie
/// on. A magnetometer's axes, with their soft iron, differ in gain by percent to tens of percent
/// (\[P1\]'s sensor: scale factors 0.7 to 1.3). On the public logs, `cond_F` is 3.01 and 3.02
/// for the full fits of ck-explorer and hamagure set 1 (3 is the least, a multiple of the
/// identity), and 17 and 21 for the full and diagonal fits of hamagure set 2 that run away. At
/// 1000 a reading good to 0.1 % gives a calibrated field good to nothing: such a `p` is a garbled
/// or nearly singular matrix, not a calibration.
pub const MAX_CONDITION: f64 = 1e3;

/// The largest bias component of a usable calibration, in the field's raw size (the magnitude
/// times the largest scale factor): 1e6.
pub const MAX_BIAS_RATIO: f64 = 1e6;

/// The Earth's main field at the surface lies between about 22,000 and 67,000 nT (WMM), so a log
/// of the calibrated sensor from any site has a median calibrated radius within a factor
/// 67 / 22 = 3.05 of the calibration's magnitude. Beyond this factor no site explains the log:
/// other units, another sensor or the wrong columns.
pub const SITE_RATIO: f64 = 3.2;

/// `value <= tol`, false for NaN: a check that cannot be computed fails.
fn within(value: f64, tol: f64) -> bool {
    value <= tol
}

fn frobenius(m: &Mat3) -> f64 {
    m.iter().flatten().map(|v| v * v).sum::<f64>().sqrt()
}

impl CalibrationJson {
    /// `p`'s Frobenius condition number `|P|_F |P^-1|_F` (infinite when singular).
    pub fn condition(&self) -> f64 {
        magcal_core::small::upper_triangular_inverse(&self.p)
            .map_or(f64::INFINITY, |k| frobenius(&self.p) * frobenius(&k))
    }

    /// The checks of a calibration before use; the error names the field and its value.
    ///
    /// `p` upper triangular with a positive diagonal (\[P1\] eq. (6): the Cholesky factor of
    /// `G = P^T P`), finite, invertible and, where `usable`, conditioned below [`MAX_CONDITION`]; `bias` finite;
    /// `magnitude` finite and positive; `noise` and `residual_rms` finite and not negative; and
    /// what is derived from `p` agrees with it: `k = P^-1`, `scale` and `psi_deg` (docs/conventions.md's
    /// inverse map of `K`), `soft_iron_inverse` (the symmetric square root of `P^T P`).
    ///
    /// # Errors
    /// The first check that fails, in words.
    pub fn check(&self) -> Result<(), String> {
        if let Some(f) = &self.format
            && f != FORMAT
        {
            return Err(format!("format {:?}: this magcal reads {FORMAT:?}", excerpt(f, 40)));
        }
        for (name, m) in [
            ("p", &self.p),
            ("k", &self.k),
            ("soft_iron_inverse", &self.soft_iron_inverse),
        ] {
            if let Some(v) = m.iter().flatten().find(|v| !v.is_finite()) {
                return Err(format!(
                    "{name}: an entry is {v}, not finite (numbers beyond the range of f64)"
                ));
            }
        }
        for (name, v) in [("bias", self.bias), ("scale", self.scale), ("psi_deg", self.psi_deg)] {
            if !v.iter().all(|x| x.is_finite()) {
                return Err(format!("{name} {v:?}: not finite"));
            }
        }
        if !(self.magnitude.is_finite() && self.magnitude > 0.0) {
            return Err(format!(
                "magnitude {}: must be finite and positive",
                crate::limits::show(self.magnitude)
            ));
        }
        // A usable calibration's bias is a hard-iron field, in the raw readings' units: a magnet
        // on the board is a few hundred times the field's raw size (its magnitude times the
        // scale factors), never a million; beyond that it is an edited or garbled file whose
        // calibrated readings would be meaningless numbers.
        let largest = self.bias.iter().fold(0.0_f64, |a, b| a.max(b.abs()));
        let raw_size = self.magnitude * self.scale.iter().fold(0.0_f64, |a, s| a.max(s.abs()));
        if self.usable && largest > MAX_BIAS_RATIO * raw_size {
            return Err(format!(
                "bias ({}): {} times the field's raw size {} (magnitude times the largest scale factor); a usable calibration's is at most {MAX_BIAS_RATIO:e} times it (a magnet beside the sensor gives a few hundred)",
                self.bias.map(crate::limits::show).join(", "),
                Some(largest / raw_size)
                    .filter(|r| r.is_finite())
                    .map_or("more than 1e308".to_string(), |r| crate::text::significant(r, 3)),
                crate::text::significant(raw_size, 7),
            ));
        }
        // The noise is `null` where the log cannot give it (an exact fit without --noise).
        for (name, v) in [("noise", self.noise), ("residual_rms", Some(self.residual_rms))] {
            if let Some(v) = v
                && !(v.is_finite() && v >= 0.0)
            {
                return Err(format!("{name} {v}: must be finite and not negative"));
            }
        }
        self.check_p()?;
        self.check_derived()?;
        self.check_alignment()
    }

    /// `alignment.rotation`, where present, a rotation: finite, orthonormal to rounding,
    /// determinant +1.
    fn check_alignment(&self) -> Result<(), String> {
        use magcal_core::small::{mat_mul, transpose};
        let Some(a) = &self.alignment else {
            return Ok(());
        };
        let r = &a.rotation;
        let rtr = mat_mul(&transpose(r), r);
        let off = frobenius(&std::array::from_fn(|i| {
            std::array::from_fn(|j| rtr[i][j] - if i == j { 1.0 } else { 0.0 })
        }));
        let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
        if !(within(off, 1e-9) && det > 0.0) {
            return Err(format!(
                "alignment.rotation {r:?}: not a rotation (|R^T R - I| = {off:.3e}, det {det:.6})"
            ));
        }
        Ok(())
    }

    /// `p` upper triangular with a positive diagonal, `P^T P` finite, invertible, and for a
    /// usable calibration conditioned below [`MAX_CONDITION`].
    fn check_p(&self) -> Result<(), String> {
        use magcal_core::small::{mat_mul, transpose};
        let show = |m: &Mat3| format!("{m:?}");
        let p = &self.p;
        for (i, j) in [(1, 0), (2, 0), (2, 1)] {
            if p[i][j] != 0.0 {
                return Err(format!(
                    "p {}: entry ({}, {}) is {}; P is upper triangular ([P1] eq. (6))",
                    show(p),
                    i + 1,
                    j + 1,
                    p[i][j]
                ));
            }
        }
        if let Some(i) = (0..3).find(|&i| p[i][i] <= 0.0) {
            return Err(format!(
                "p {}: diagonal entry {} is {}; P has a positive diagonal (the Cholesky factor of G = P^T P)",
                show(p),
                i + 1,
                p[i][i]
            ));
        }
        if !frobenius(&mat_mul(&transpose(p), p)).is_finite() {
            return Err(format!("p {}: too large (G = P^T P overflows)", show(p)));
        }
        // A usable calibration must be conditioned below the limit; one calibrate marked not
        // usable may be ill-conditioned (a fit that runs away) and is still calibrate's own
        // record of the log: `next` plans from it and `export --force` writes it, so only a
        // singular `p` is refused there.
        let cond = self.condition();
        let limit = if self.usable { MAX_CONDITION } else { f64::MAX };
        if cond.is_nan() {
            return Err(format!(
                "p {}: its condition number is not a number (singular, or beyond the range of f64)",
                show(p)
            ));
        }
        if cond > limit {
            return Err(format!(
                "p {}: condition number {cond:.3e} above {limit:e} (singular or garbled: it would amplify a reading's error by as much)",
                show(p)
            ));
        }
        Ok(())
    }

    /// What is derived from `p` agrees with it, to the rounding of its computation: `k = P^-1`,
    /// `scale`, `psi_deg`, `soft_iron_inverse`.
    fn check_derived(&self) -> Result<(), String> {
        use magcal_core::small::{mat_mul, transpose, upper_triangular_inverse};
        let show = |m: &Mat3| format!("{m:?}");
        let p = &self.p;
        let cond = self.condition();
        let inverse = upper_triangular_inverse(p).ok_or_else(|| format!("p {}: singular", show(p)))?;
        // Substitution is backward stable: |K P - I| <= c n eps |K| |P| with c n well below 64.
        let eps = f64::EPSILON;
        let kp = mat_mul(&self.k, p);
        let off = frobenius(&std::array::from_fn(|i| {
            std::array::from_fn(|j| kp[i][j] - if i == j { 1.0 } else { 0.0 })
        }));
        if !within(off, 64.0 * eps * frobenius(&self.k) * frobenius(p)) {
            return Err(format!(
                "k {}: not the inverse of p (|K P - I| = {off:.3e})",
                show(&self.k)
            ));
        }
        // psi and scale from K = P^-1; each is good to cond(P) eps relative.
        let derived = magcal_core::ErrorModel::from_k(&inverse, self.bias);
        let tol = 64.0 * eps * cond;
        let scale = derived.scale();
        if (0..3).any(|i| !within((self.scale[i] - scale[i]).abs(), tol * scale[i])) {
            return Err(format!(
                "scale {:?}: not the scale factors of p (from p: {scale:?})",
                self.scale
            ));
        }
        let psi = derived.psi_deg();
        if (0..3).any(|i| !within((self.psi_deg[i] - psi[i]).abs().to_radians(), tol)) {
            return Err(format!(
                "psi_deg {:?}: not the non-orthogonality of p (from p: {psi:?})",
                self.psi_deg
            ));
        }
        // A^-1 A^-1 = G = P^T P, to the accuracy of a symmetric eigendecomposition of G.
        let a = &self.soft_iron_inverse;
        let g = mat_mul(&transpose(p), p);
        let aa = mat_mul(a, a);
        let off = frobenius(&std::array::from_fn(|i| std::array::from_fn(|j| aa[i][j] - g[i][j])));
        let asymmetry = frobenius(&std::array::from_fn(|i| std::array::from_fn(|j| a[i][j] - a[j][i])));
        if !(within(off, 256.0 * eps * frobenius(&g)) && within(asymmetry, 256.0 * eps * frobenius(a))) {
            return Err(format!(
                "soft_iron_inverse {}: not the symmetric square root of P^T P",
                show(a)
            ));
        }
        Ok(())
    }

    /// The band of `median |P (raw - bias)| / magnitude` around 1 within which a log is one of the
    /// calibrated sensor in the calibration's field: 5 times the fit's residual rms relative to
    /// the magnitude (the median of the log it was fitted to lies within one), and at least 1 %
    /// (four bins of [`RadiusMedian`]).
    pub fn radius_band(&self) -> f64 {
        (5.0 * self.residual_rms / self.magnitude).max(0.01)
    }

    /// What a median calibrated radius of `ratio` times the magnitude says about a log: `None`
    /// within [`Self::radius_band`], else why it is not the calibration's log, in words.
    pub fn radius_mismatch(&self, ratio: f64) -> Option<String> {
        let band = self.radius_band();
        if (ratio - 1.0).abs() <= band {
            return None;
        }
        let made_from = format!(
            "the calibration was made from columns {}{}",
            self.columns.join(", "),
            self.units.as_ref().map_or(String::new(), |u| format!(" in {u}"))
        );
        let magnitude = crate::limits::show(self.magnitude);
        Some(if !ratio.is_finite() {
            format!(
                "its readings, calibrated, have no median radius (they are not finite numbers): other units or the wrong log or columns ({made_from})"
            )
        } else if (1.0 / SITE_RATIO..=SITE_RATIO).contains(&ratio) {
            format!(
                "its median radius under the calibration is {} times the magnitude {magnitude} (the fit's band: 1 +- {band:.4}): a field of another strength (another site, nearby iron), another sensor or other columns ({made_from})",
                crate::text::significant(ratio, 5),
            )
        } else {
            format!(
                "its median radius under the calibration is {} times the magnitude {magnitude}, which no site on Earth explains (fields of 22,000 to 67,000 nT): other units or the wrong log or columns ({made_from})",
                crate::text::significant(ratio, 5),
            )
        })
    }
}

/// A `calibration.json` that passes [`CalibrationJson::check`].
///
/// # Errors
/// A file that cannot be read, is larger than [`crate::limits::MAX_CALIBRATION_BYTES`], is not a calibration, or fails
/// a check; one line naming the file and the field.
pub fn read_calibration(path: &Path) -> Result<CalibrationJson> {
    let text = crate::limits::read_bounded(path, crate::limits::MAX_CALIBRATION_BYTES)?;
    parse_calibration(&text, &path.display().to_string())
}

/// A calibration file's bytes, read as [`read_calibration`] reads them; `shown` names the file in
/// messages.
///
/// # Errors
/// As [`read_calibration`].
pub fn parse_calibration(text: &[u8], shown: &str) -> Result<CalibrationJson> {
    // A byte-order mark, as editors on Windows write it, is not part of the JSON.
    let text = text.strip_prefix(b"\xef\xbb\xbf").unwrap_or(text);
    let cal: CalibrationJson = serde_json::from_slice(text).map_err(|e| match no_calibration(text) {
        Some(why) => anyhow::anyhow!(
            "{shown}: calibrate's report that its log has no calibration ({}: {}), not a calibration: there is nothing to use; the reason says what the log lacks",
            NO_CALIBRATION_FORMAT,
            excerpt(&why, 160)
        ),
        None => anyhow::anyhow!("{shown}: not a magcal calibration: {}", excerpt(&e.to_string(), 160)),
    })?;
    cal.check().map_err(|e| anyhow::anyhow!("{shown}: {e}"))?;
    Ok(cal)
}

/// The format of `calibrate`'s report that a log has no calibration (`no_calibration.json`).
pub const NO_CALIBRATION_FORMAT: &str = "magcal-no-calibration-1";

/// The first reason of `calibrate`'s report that a log has no calibration (`no_calibration.json`),
/// where `text` is one.
fn no_calibration(text: &[u8]) -> Option<String> {
    let v: serde_json::Value = serde_json::from_slice(text).ok()?;
    (v.get("format")?.as_str()? == NO_CALIBRATION_FORMAT)
        .then(|| v.get("reasons")?.get(0)?.as_str().map(str::to_string))
        .flatten()
}

/// The columns to read `log` with: `asked` (`--columns`) when given, else the columns `cal` was
/// made from, as 1-based indices of `log`'s header (a name, or the `column N` recorded for a
/// column without a name of its own: no header, an empty name, a name several columns carry).
/// `None` when the log's first row cannot be read (the reader then says why), and for a flight
/// log (which names its own messages).
///
/// # Errors
/// A log without the recorded columns: one line naming the log, the calibration and both sets
/// of columns.
pub fn columns_for(cal: &CalibrationJson, cal_shown: &str, log: &Path, input: &LogArgs) -> Result<Option<String>> {
    if let Some(asked) = &input.columns {
        return Ok(Some(asked.clone()));
    }
    if format_of(log, input.format)? != Format::Csv {
        return Ok(None);
    }
    // The first row as the log reader splits it (separator, quotes, empty names), so that the
    // names calibrate recorded are found in a log that is not comma-separated.
    let Some((header, names)) = crate::read::first_row(log) else {
        return Ok(None);
    };
    let recorded = cal.columns.join(", ");
    let shown = log.display();
    let mut picks = Vec::with_capacity(3);
    for name in &cal.columns {
        let found = if header {
            // A name the log gives several columns does not say which; a column recorded by its
            // number (its name was not unique in the log calibrate read) is found by it.
            let by_name: Vec<usize> = (0..names.len())
                .filter(|&i| names[i].eq_ignore_ascii_case(name))
                .collect();
            if let [a, b, ..] = by_name[..] {
                bail!(
                    "{shown}: columns {} and {} are both named {:?}, which {cal_shown} was made from; give --columns",
                    a + 1,
                    b + 1,
                    excerpt(name, 40)
                );
            }
            by_name.first().map(|i| i + 1).or_else(|| {
                name.strip_prefix("column ")
                    .and_then(|i| i.parse::<usize>().ok())
                    .filter(|i| (1..=names.len()).contains(i))
            })
        } else {
            name.strip_prefix("column ")
                .and_then(|i| i.parse::<usize>().ok())
                .filter(|i| (1..=names.len()).contains(i))
        };
        match found {
            Some(i) => picks.push(i.to_string()),
            None if header => bail!(
                "{shown}: no column {:?}, which {cal_shown} was made from (columns {}; the log's: {}); give --columns",
                excerpt(name, 40),
                excerpt(&recorded, 80),
                excerpt(&names.join(", "), 120)
            ),
            None => bail!(
                "{shown}: no header and {} columns, and {cal_shown} was made from columns {}; give --columns",
                names.len(),
                excerpt(&recorded, 80)
            ),
        }
    }
    Ok(Some(picks.join(",")))
}

/// Bins of [`RadiusMedian`] per octave.
const PER_OCTAVE: f64 = 256.0;
/// Octaves of [`RadiusMedian`] on each side of the magnitude.
const OCTAVES: f64 = 40.0;

/// The median of `|b| / magnitude` over the calibrated readings `b` of a log, in constant memory
/// (so that a log can be streamed): a histogram of `log2(|b| / magnitude)` in bins of 1/256
/// octave (0.27 %) from 2^-40 to 2^40, whose end bins hold everything beyond; a non-finite
/// radius counts above all.
#[derive(Debug, Clone)]
pub struct RadiusMedian {
    magnitude: f64,
    bins: Vec<u64>,
    nonfinite: u64,
    count: u64,
}

impl RadiusMedian {
    /// An empty histogram for `magnitude` (finite and positive).
    pub fn new(magnitude: f64) -> Self {
        Self {
            magnitude,
            bins: vec![0; (2.0 * OCTAVES * PER_OCTAVE) as usize],
            nonfinite: 0,
            count: 0,
        }
    }

    /// Adds one calibrated reading.
    pub fn push(&mut self, b: magcal_core::Vec3) {
        self.count += 1;
        let ratio = magcal_core::small::norm(b) / self.magnitude;
        if !ratio.is_finite() {
            self.nonfinite += 1;
            return;
        }
        let at = ((ratio.log2() + OCTAVES) * PER_OCTAVE).floor();
        let last = self.bins.len() - 1;
        // The saturating cast takes -inf (a zero radius) to 0.
        self.bins[(at.max(0.0) as usize).min(last)] += 1;
    }

    /// Readings added.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The (lower) median of `|b| / magnitude`, to half a bin (0.14 %); infinite when it is a
    /// non-finite radius, NaN without readings.
    pub fn ratio(&self) -> f64 {
        if self.count == 0 {
            return f64::NAN;
        }
        let rank = (self.count - 1) / 2;
        let mut seen = 0;
        for (i, &n) in self.bins.iter().enumerate() {
            seen += n;
            if seen > rank {
                return ((i as f64 + 0.5) / PER_OCTAVE - OCTAVES).exp2();
            }
        }
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::{PassJson, PassesJson, RadiusMedian};
    use crate::limits::excerpt;

    #[test]
    fn passes_flag_a_usable_verdict_and_count_their_readings() {
        let pass = |readings| PassJson {
            at: 10,
            position: "line".into(),
            from_s: None,
            to_s: None,
            readings,
            peak_percent: -20.0,
        };
        let mut p = PassesJson {
            magnitude: 44.0,
            noise: 0.8,
            threshold: 4.4,
            share_percent: 10.0,
            sigmas: 5.0,
            edge_sigmas: 1.0,
            passes: Vec::new(),
            readings: 0,
            shift_std_errors: None,
            shift_parameter: None,
            shift_limit: 1.0,
            unusable: false,
            words: String::new(),
        };
        assert_eq!(p.flag(), None);
        p.passes = vec![pass(18)];
        p.readings = 18;
        assert!(
            p.flag()
                .unwrap()
                .starts_with("FLAGGED: the log passes through another field 1 time (18 readings;")
        );
        p.passes.push(pass(26));
        p.readings = 44;
        assert!(p.flag().unwrap().contains("another field 2 times (44 readings;"));
    }

    #[test]
    fn the_histogram_median_is_the_median_to_half_a_bin() {
        // Radii 1, 2, ..., 1001 times a magnitude of 0.3: the median is 501; one bin is 2^(1/256).
        let half_bin = 2_f64.powf(0.5 / 256.0) - 1.0;
        let mut h = RadiusMedian::new(0.3);
        for i in 1..=1001 {
            h.push([0.0, 0.3 * f64::from(i), 0.0]);
        }
        assert_eq!(h.count(), 1001);
        let r = h.ratio();
        assert!((r / 501.0 - 1.0).abs() <= half_bin, "{r}");
        // Ratios beyond 2^40 land in the end bin; non-finite ones count above all.
        let mut h = RadiusMedian::new(1.0);
        h.push([1e300, 0.0, 0.0]);
        h.push([f64::INFINITY, 0.0, 0.0]);
        h.push([f64::NAN, 0.0, 0.0]);
        assert!(h.ratio().is_infinite());
        let mut h = RadiusMedian::new(1.0);
        for _ in 0..3 {
            h.push([0.0; 3]);
        }
        h.push([1.0, 0.0, 0.0]);
        assert!(h.ratio() <= 2_f64.powi(-39), "{}", h.ratio());
        assert!(RadiusMedian::new(1.0).ratio().is_nan());
    }

    #[test]
    fn excerpts_cut_long_text() {
        assert_eq!(excerpt("abcdef", 3), "abc...");
        assert_eq!(excerpt("abc", 3), "abc");
        assert_eq!(excerpt("ééé", 2), "éé...");
    }
}
