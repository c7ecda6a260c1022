//! Scenario files: the raw TOML schema (`raw`), and its validation into a [`Scenario`] whose every
//! value is usable and every size bounded ([`crate::limits`]). Errors name the file, the key and the
//! value as written.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use magcal_core::calibration::step2::Residual;
use magcal_core::design::approximate::Approximate;
use magcal_core::design::optimum::Optimum;
use magcal_core::design::plan::PlanLimits;
use magcal_core::design::pso::Swarm;
use magcal_core::{Attitude, AttitudeBox, ErrorModel, ParameterError, ReferenceField, TwoStep, wmm};
use serde::{Deserialize, Serialize};

use crate::limits::{self, show};

/// The schema version this build reads.
pub const SCHEMA: u32 = 1;

/// Default trials of each design's verdict: the share of `ok` trials then has a standard error of
/// at most 3.5 percentage points, 1.5 at the 95 % threshold.
pub const DEFAULT_CHECK_TRIALS: usize = 200;
/// Fewest trials of a verdict: with fewer, one trial is more than 5 % of them.
pub const MIN_CHECK_TRIALS: usize = 20;

/// Default `max_attitudes` of a plan: 12. A crew holds a dozen attitudes, each for `N / 12`
/// readings; the approximate D-optimum of the \[P1\] AUV box has 12 support points, so its plans
/// lose nothing, and on boxes with wider supports the dozen best costs little (a box of every
/// attitude, 37 support points: see the README's "Certified designs"). `"all"` lifts the limit.
pub const DEFAULT_MAX_ATTITUDES: usize = 12;

/// Default noisy trials per design and noise level (\[P1\] IV.C: one thousand).
pub const DEFAULT_TRIALS: usize = 1000;

/// The raw file, as TOML gives it. Every table denies unknown keys; fixed-length arrays take
/// exactly their length.
mod raw {
    use serde::Deserialize;
    use serde::de::{self, Deserializer, SeqAccess, Visitor};

    /// Exactly `N` numbers (serde's arrays ignore extra elements).
    fn exact<'de, D: Deserializer<'de>, const N: usize>(d: D) -> Result<[f64; N], D::Error> {
        let v = Vec::<f64>::deserialize(d)?;
        let n = v.len();
        v.try_into()
            .map_err(|_| de::Error::invalid_length(n, &format!("exactly {N} numbers").as_str()))
    }

    /// A number (one noise level) or a list of numbers (a sweep).
    fn one_or_many<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Vec<f64>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number or a list of numbers")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Self::Value, E> {
                Ok(vec![v])
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Self::Value, E> {
                Ok(vec![v as f64])
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Self::Value, E> {
                Ok(vec![v as f64])
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut v = Vec::new();
                while let Some(x) = seq.next_element::<f64>()? {
                    if v.len() >= super::limits::MAX_SIGMAS {
                        return Err(de::Error::invalid_length(
                            v.len() + 1,
                            &format!("at most {} noise levels", super::limits::MAX_SIGMAS).as_str(),
                        ));
                    }
                    v.push(x);
                }
                Ok(v)
            }
        }
        d.deserialize_any(V)
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Scenario {
        pub schema: u32,
        pub name: String,
        #[serde(default)]
        pub description: String,
        pub seed: u64,
        #[serde(default = "default_trials")]
        pub trials: usize,
        #[serde(deserialize_with = "one_or_many")]
        pub sigma_nt: Vec<f64>,
        #[serde(default = "no_attitude_error", deserialize_with = "one_or_many")]
        pub attitude_sigma_deg: Vec<f64>,
        pub field: Field,
        pub sensor: Sensor,
        pub attitude_box: AttitudeBox,
        #[serde(default)]
        pub calibration: Calibration,
        #[serde(default)]
        pub verdict: Verdict,
        pub design: Vec<Design>,
        pub pso_runs: Option<PsoRuns>,
        #[serde(default)]
        pub certificate: Certificate,
    }

    #[derive(Debug, Default, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Verdict {
        pub trials: Option<usize>,
    }

    #[derive(Debug, Default, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Certificate {
        pub candidates: Option<usize>,
        pub tolerance: Option<f64>,
        pub max_rounds: Option<usize>,
    }

    fn no_attitude_error() -> Vec<f64> {
        vec![0.0]
    }

    fn default_trials() -> usize {
        super::DEFAULT_TRIALS
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    /// Either the NED components, or a World Magnetic Model site and date.
    pub struct Field {
        pub north_nt: Option<f64>,
        pub east_nt: Option<f64>,
        pub down_nt: Option<f64>,
        pub model: Option<String>,
        pub lat_deg: Option<f64>,
        pub lon_deg: Option<f64>,
        pub alt_m: Option<f64>,
        pub year: Option<f64>,
        #[serde(default)]
        pub yaw_offset_deg: f64,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Sensor {
        #[serde(deserialize_with = "exact")]
        pub psi_deg: [f64; 3],
        #[serde(deserialize_with = "exact")]
        pub scale: [f64; 3],
        #[serde(deserialize_with = "exact")]
        pub bias_nt: [f64; 3],
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct AttitudeBox {
        #[serde(deserialize_with = "exact")]
        pub roll_deg: [f64; 2],
        #[serde(deserialize_with = "exact")]
        pub yaw_deg: [f64; 2],
        #[serde(deserialize_with = "exact")]
        pub pitch_deg: [f64; 2],
    }

    #[derive(Debug, Default, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Calibration {
        pub max_iterations: Option<usize>,
        pub residual: Option<String>,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Attitude {
        pub roll_deg: f64,
        pub yaw_deg: f64,
        pub pitch_deg: f64,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Levels {
        pub roll: usize,
        pub yaw: usize,
        pub pitch: usize,
    }

    #[derive(Debug, Deserialize)]
    #[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
    pub enum Design {
        Explicit {
            name: String,
            attitudes: Vec<Attitude>,
        },
        Grid {
            name: String,
            levels: Levels,
        },
        Random {
            name: String,
            m: usize,
        },
        Pso {
            name: String,
            m: usize,
            particles: Option<usize>,
            iterations: Option<usize>,
            w_max: Option<f64>,
            w_min: Option<f64>,
            c1: Option<f64>,
            c2: Option<f64>,
            vmax_fraction: Option<f64>,
            threshold: Option<f64>,
            criterion: Option<Criterion>,
        },
        Plan {
            name: String,
            readings: usize,
            // Read as any TOML value and checked in `design`: a design table is buffered for its
            // `kind` tag, and serde's errors from inside it name neither the key nor the value.
            max_attitudes: Option<toml::Value>,
            min_readings_per_attitude: Option<toml::Value>,
        },
        Optimum {
            name: String,
            m: usize,
            starts: Option<usize>,
            max_iterations: Option<usize>,
            gradient_tolerance: Option<f64>,
            criterion: Option<Criterion>,
        },
    }

    /// `criterion = "d" | "a" | "e"`.
    #[derive(Debug, Clone, Copy, Deserialize)]
    #[serde(rename_all = "lowercase")]
    pub enum Criterion {
        D,
        A,
        E,
    }

    impl From<Criterion> for magcal_core::design::DesignCriterion {
        fn from(c: Criterion) -> Self {
            match c {
                Criterion::D => Self::D,
                Criterion::A => Self::A,
                Criterion::E => Self::E,
            }
        }
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct PsoRuns {
        pub runs: usize,
        pub design: String,
    }
}

/// The kind of a design source, as `design_metrics.csv` names it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DesignKind {
    /// Attitudes listed in the scenario.
    #[default]
    Explicit,
    /// A uniform grid.
    Grid,
    /// Uniform random attitudes.
    Random,
    /// The paper's PSO.
    Pso,
    /// The multi-start optimum optimiser.
    Optimum,
    /// The approximate D-optimal design rounded to a number of readings.
    Plan,
}

impl DesignKind {
    /// Whether an optimiser chose the attitudes. Many designs share the optimal `ln det M_F` with
    /// different attitudes and conditioning, so `check` compares only `ln det` for these.
    pub fn is_optimised(self) -> bool {
        matches!(self, Self::Pso | Self::Optimum | Self::Plan)
    }

    /// The name used in files.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Explicit => "explicit",
            Self::Grid => "grid",
            Self::Random => "random",
            Self::Pso => "pso",
            Self::Optimum => "optimum",
            Self::Plan => "plan",
        }
    }
}

/// How a design's attitudes are obtained.
#[derive(Debug, Clone)]
pub enum DesignSource {
    /// Attitudes listed in the file (checked against the box).
    Explicit(Vec<Attitude>),
    /// Uniform grid, levels per axis (roll, yaw, pitch).
    Grid([usize; 3]),
    /// `m` attitudes uniform in the box.
    Random {
        /// Attitudes.
        m: usize,
    },
    /// The paper's PSO.
    Pso {
        /// Attitudes.
        m: usize,
        /// Settings (defaults: \[P1\] Table I).
        swarm: Swarm,
    },
    /// Multi-start local optimisation to the D-optimum.
    Optimum {
        /// Attitudes.
        m: usize,
        /// Settings.
        settings: Optimum,
    },
    /// The run's approximate D-optimal design ([`Scenario::certificate`]) rounded to `readings`
    /// readings by efficient rounding: several readings per attitude; within `limits`, the exact
    /// design of at most `K` attitudes with at least `R` readings each
    /// ([`magcal_core::design::plan`]).
    Plan {
        /// Readings in all.
        readings: usize,
        /// At most `max_attitudes` attitudes (default [`DEFAULT_MAX_ATTITUDES`]), at least
        /// `min_readings_per_attitude` readings each (default 1).
        limits: PlanLimits,
    },
}

impl DesignSource {
    /// Its kind.
    pub fn kind(&self) -> DesignKind {
        match self {
            Self::Explicit(_) => DesignKind::Explicit,
            Self::Grid(_) => DesignKind::Grid,
            Self::Random { .. } => DesignKind::Random,
            Self::Pso { .. } => DesignKind::Pso,
            Self::Optimum { .. } => DesignKind::Optimum,
            Self::Plan { .. } => DesignKind::Plan,
        }
    }

    /// The criterion an optimiser minimises (`None` for designs that are not optimised; a plan
    /// is D-optimal).
    pub fn criterion(&self) -> Option<magcal_core::design::DesignCriterion> {
        use magcal_core::design::DesignCriterion;
        match self {
            Self::Pso { swarm, .. } => Some(swarm.criterion),
            Self::Optimum { settings, .. } => Some(settings.criterion),
            Self::Plan { .. } => Some(DesignCriterion::D),
            _ => None,
        }
    }

    /// The number of readings it gives (of attitudes, but for a plan).
    pub fn m(&self) -> usize {
        match self {
            Self::Explicit(list) => list.len(),
            Self::Grid(l) => l.iter().product(),
            Self::Random { m } | Self::Pso { m, .. } | Self::Optimum { m, .. } => *m,
            Self::Plan { readings, .. } => *readings,
        }
    }
}

/// A named design of the scenario.
#[derive(Debug, Clone)]
pub struct DesignSpec {
    /// Name, unique in the scenario; letters, digits, `_`, `-`, `.`.
    pub name: String,
    /// Where its attitudes come from.
    pub source: DesignSource,
}

/// Repeated PSO runs (\[P1\] Fig. 4).
#[derive(Debug, Clone)]
pub struct PsoRunsSpec {
    /// Number of runs.
    pub runs: usize,
    /// The swarm settings, from the named PSO design.
    pub swarm: Swarm,
    /// Attitudes per design of that PSO design.
    pub m: usize,
    /// The design they were taken from.
    pub design: String,
}

/// A validated scenario.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// The file it was read from.
    pub path: PathBuf,
    /// SHA-256 of the file's bytes, hex.
    pub hash: String,
    /// Scenario name (default output directory `results/<name>/`).
    pub name: String,
    /// Free text.
    pub description: String,
    /// Seed of every random stream.
    pub seed: u64,
    /// Noisy trials per design and noise level.
    pub trials: usize,
    /// Noise levels, nT per component.
    pub sigmas_nt: Vec<f64>,
    /// Execution errors, degrees: every commanded angle of every reading is off by an
    /// independent `N(0, sigma^2)` draw in each trial (0: flown as commanded).
    pub attitude_sigmas_deg: Vec<f64>,
    /// Reference field.
    pub field: ReferenceField,
    /// Where the field comes from, in words: the WMM at a site and date
    /// (`WMM2025 at 33.92 S, 18.42 E, 0 m, 2026.42`), or the components given in `[field]`.
    pub field_source: String,
    /// True sensor errors.
    pub truth: ErrorModel,
    /// The vehicle's attitude box.
    pub bounds: AttitudeBox,
    /// Two-step calibration settings.
    pub calibration: TwoStep,
    /// Trials of the short Monte Carlo behind each design's verdict
    /// ([`crate::pipeline::Check`]).
    pub check_trials: usize,
    /// Designs, in file order.
    pub designs: Vec<DesignSpec>,
    /// Repeated PSO runs, if asked.
    pub pso_runs: Option<PsoRunsSpec>,
    /// Settings of the approximate design that certifies every design's D-efficiency.
    pub certificate: Approximate,
}

/// Reads and validates a scenario file.
///
/// # Errors
/// A missing, unreadable or oversized file, a TOML syntax error (with line and column), an unknown
/// key, a wrong type, or an invalid value; each message names the file, the key and the value.
pub fn load(path: &Path) -> Result<Scenario> {
    let bytes = limits::read_bounded(path, limits::MAX_SCENARIO_BYTES)?;
    parse(&bytes, path)
}

/// Validates the bytes of a scenario file read from `path` (named in errors).
///
/// # Errors
/// As [`load`].
pub fn parse(bytes: &[u8], path: &Path) -> Result<Scenario> {
    let text = std::str::from_utf8(bytes).with_context(|| format!("{}: not UTF-8 text", path.display()))?;
    let raw: raw::Scenario = toml::from_str(text).map_err(|e| toml_error(path, text, &e))?;
    let hash = crate::output::manifest::sha256_hex(bytes);
    validate(raw, path, hash).with_context(|| format!("{}: invalid scenario", path.display()))
}

/// One line: `file:line:column: message (in: <the source line>)`.
fn toml_error(path: &Path, text: &str, e: &toml::de::Error) -> anyhow::Error {
    let message = e.message().trim().replace('\n', " ");
    match e.span() {
        Some(span) => {
            let start = floor_char_boundary(text, span.start);
            let before = &text[..start];
            let line = before.matches('\n').count() + 1;
            let column = before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1;
            let source: String = text
                .lines()
                .nth(line - 1)
                .unwrap_or("")
                .trim()
                .chars()
                .take(120)
                .collect();
            anyhow::anyhow!("{}:{line}:{column}: {message} (in: {source})", path.display())
        }
        None => anyhow::anyhow!("{}: {message}", path.display()),
    }
}

fn floor_char_boundary(text: &str, i: usize) -> usize {
    let mut i = i.min(text.len());
    while !text.is_char_boundary(i) {
        i -= 1;
    }
    i
}

fn finite(key: &str, value: f64) -> Result<f64> {
    if !value.is_finite() {
        bail!("{key} = {}: must be a finite number", show(value));
    }
    Ok(value)
}

fn within(key: &str, value: f64, min: f64, max: f64, unit: &str) -> Result<f64> {
    finite(key, value)?;
    if !(min..=max).contains(&value) {
        bail!(
            "{key} = {}: must lie in [{}, {}]{unit}",
            show(value),
            show(min),
            show(max)
        );
    }
    Ok(value)
}

fn count(key: &str, value: usize, min: usize, max: usize) -> Result<usize> {
    if value < min {
        bail!("{key} = {value}: must be at least {min}");
    }
    if value > max {
        bail!("{key} = {value}: must be at most {max}");
    }
    Ok(value)
}

/// A core parameter error against the key that carried it: `key = value: requirement`.
fn keyed(prefix: &str, e: &ParameterError, value: &str) -> anyhow::Error {
    anyhow::anyhow!("{prefix}{} = {value}: {}", e.name(), e.requirement())
}

fn validate(raw: raw::Scenario, path: &Path, hash: String) -> Result<Scenario> {
    if raw.schema != SCHEMA {
        bail!("schema = {}: this magcal reads schema {SCHEMA}", raw.schema);
    }
    check_name("name", &raw.name)?;
    count("trials", raw.trials, 1, limits::MAX_TRIALS)?;
    if raw.sigma_nt.is_empty() {
        bail!("sigma_nt = []: give at least one noise level");
    }
    for (i, &s) in raw.sigma_nt.iter().enumerate() {
        let key = format!("sigma_nt[{i}]");
        finite(&key, s)?;
        if s < 0.0 {
            bail!("{key} = {}: a noise level cannot be negative", show(s));
        }
        if s != 0.0 && !(limits::MIN_SIGMA_NT..=limits::MAX_SIGMA_NT).contains(&s) {
            bail!(
                "{key} = {}: must be 0 or lie in [{}, {}] nT",
                show(s),
                show(limits::MIN_SIGMA_NT),
                show(limits::MAX_SIGMA_NT)
            );
        }
        if raw.sigma_nt[..i].contains(&s) {
            bail!("{key} = {}: listed twice", show(s));
        }
    }
    // -0 and 0 are one level, written as 0.
    let sigmas_nt: Vec<f64> = raw.sigma_nt.iter().map(|&s| if s == 0.0 { 0.0 } else { s }).collect();
    if raw.attitude_sigma_deg.is_empty() {
        bail!("attitude_sigma_deg = []: give at least one level (0 for none)");
    }
    count(
        "attitude_sigma_deg (count)",
        raw.attitude_sigma_deg.len(),
        1,
        limits::MAX_ATTITUDE_SIGMAS,
    )?;
    for (i, &a) in raw.attitude_sigma_deg.iter().enumerate() {
        let key = format!("attitude_sigma_deg[{i}]");
        within(&key, a, 0.0, limits::MAX_ATTITUDE_SIGMA_DEG, " degrees")?;
        if raw.attitude_sigma_deg[..i].contains(&a) {
            bail!("{key} = {}: listed twice", show(a));
        }
    }
    let attitude_sigmas_deg: Vec<f64> = raw
        .attitude_sigma_deg
        .iter()
        .map(|&a| if a == 0.0 { 0.0 } else { a })
        .collect();

    let (field, field_source) = reference_field(&raw.field)?;

    let s = &raw.sensor;
    for (key, values, min, max) in [
        ("sensor.psi_deg", s.psi_deg, -limits::MAX_PSI_DEG, limits::MAX_PSI_DEG),
        ("sensor.scale", s.scale, limits::MIN_SCALE, limits::MAX_SCALE),
        ("sensor.bias_nt", s.bias_nt, -limits::MAX_BIAS_NT, limits::MAX_BIAS_NT),
    ] {
        for (i, v) in values.into_iter().enumerate() {
            within(&format!("{key}[{i}]"), v, min, max, "")?;
        }
    }
    let truth = ErrorModel::new(s.psi_deg, s.scale, s.bias_nt).map_err(|e| keyed("sensor.", &e, "the values given"))?;

    let b = &raw.attitude_box;
    for (key, range) in [
        ("attitude_box.roll_deg", b.roll_deg),
        ("attitude_box.yaw_deg", b.yaw_deg),
        ("attitude_box.pitch_deg", b.pitch_deg),
    ] {
        if let Err(rule) = check_range(range) {
            bail!("{key} = [{}, {}]: {rule}", show(range[0]), show(range[1]));
        }
    }
    let bounds = AttitudeBox::from_degrees(b.roll_deg, b.yaw_deg, b.pitch_deg)
        .map_err(|e| keyed("attitude_box.", &e, "the range given"))?;

    let mut calibration = TwoStep::default();
    if let Some(n) = raw.calibration.max_iterations {
        calibration.max_iterations = count("calibration.max_iterations", n, 1, limits::MAX_STEP2_ITERATIONS)?;
    }
    let check_trials = match raw.verdict.trials {
        Some(n) => count("verdict.trials", n, MIN_CHECK_TRIALS, limits::MAX_TRIALS)?,
        None => DEFAULT_CHECK_TRIALS,
    };
    calibration.residual = match raw.calibration.residual.as_deref() {
        None | Some("readings") => Residual::Readings,
        Some("paper") => Residual::Paper,
        Some(other) => bail!(
            "calibration.residual = {:?}: expected \"readings\" (the default: distances in the readings' units) \
             or \"paper\" ([P1]'s residual after the correction)",
            limits::excerpt(other, 40)
        ),
    };

    if raw.design.is_empty() {
        bail!("no [[design]]: give at least one design");
    }
    count("[[design]] (count)", raw.design.len(), 1, limits::MAX_DESIGNS)?;
    let mut designs: Vec<DesignSpec> = Vec::with_capacity(raw.design.len());
    for (i, d) in raw.design.into_iter().enumerate() {
        let spec = design(i, d, &raw.attitude_box)?;
        if designs.iter().any(|other| other.name == spec.name) {
            bail!("design[{i}].name = {:?}: another design has this name", spec.name);
        }
        designs.push(spec);
    }

    let pso_runs = match raw.pso_runs {
        None => None,
        Some(r) => {
            count("pso_runs.runs", r.runs, 1, limits::MAX_PSO_RUNS)?;
            let Some(spec) = designs.iter().find(|d| d.name == r.design) else {
                bail!("pso_runs.design = {:?}: no design has this name", r.design);
            };
            let DesignSource::Pso { m, swarm } = &spec.source else {
                bail!(
                    "pso_runs.design = {:?}: that design is {}, not pso",
                    r.design,
                    spec.source.kind().as_str()
                );
            };
            Some(PsoRunsSpec {
                runs: r.runs,
                swarm: swarm.clone(),
                m: *m,
                design: r.design,
            })
        }
    };

    let d = Approximate::default();
    let c = &raw.certificate;
    let certificate = Approximate {
        candidates: count(
            "certificate.candidates",
            c.candidates.unwrap_or(d.candidates),
            limits::MIN_CERTIFICATE_CANDIDATES,
            limits::MAX_CERTIFICATE_CANDIDATES,
        )?,
        tolerance: within(
            "certificate.tolerance",
            c.tolerance.unwrap_or(d.tolerance),
            1e-9,
            0.1,
            "",
        )?,
        max_rounds: count("certificate.max_rounds", c.max_rounds.unwrap_or(d.max_rounds), 1, 1000)?,
        ..d
    };

    Ok(Scenario {
        path: path.to_path_buf(),
        hash,
        name: raw.name,
        description: raw.description,
        seed: raw.seed,
        trials: raw.trials,
        check_trials,
        sigmas_nt,
        attitude_sigmas_deg,
        field,
        field_source,
        truth,
        bounds,
        calibration,
        designs,
        pso_runs,
        certificate,
    })
}

/// The reference field from `[field]`: NED numbers (nT), or `model, lat_deg, lon_deg, alt_m, year`
/// evaluated with the World Magnetic Model; then the yaw offset. With where it comes from, in
/// words.
fn reference_field(f: &raw::Field) -> Result<(ReferenceField, String)> {
    within("field.yaw_offset_deg", f.yaw_offset_deg, -360.0, 360.0, " degrees")?;
    let ned = [f.north_nt, f.east_nt, f.down_nt];
    let site = [f.lat_deg, f.lon_deg, f.alt_m, f.year];
    let (field, source) = match (&f.model, ned.iter().any(Option::is_some)) {
        (Some(_), true) => bail!("[field]: give either north_nt, east_nt, down_nt or a model and site, not both"),
        (None, _) => {
            let keys = ["field.north_nt", "field.east_nt", "field.down_nt"];
            let mut v = [0.0; 3];
            for ((key, value), slot) in keys.iter().zip(ned).zip(&mut v) {
                let Some(value) = value else {
                    bail!("{key} is missing (or give field.model with lat_deg, lon_deg, alt_m, year)");
                };
                *slot = within(key, value, -limits::MAX_FIELD_NT, limits::MAX_FIELD_NT, " nT")?;
            }
            if site.iter().any(Option::is_some) {
                bail!("[field]: lat_deg, lon_deg, alt_m and year need field.model");
            }
            let magnitude = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if magnitude < limits::MIN_FIELD_NT {
                bail!(
                    "[field] north_nt, east_nt, down_nt = [{}, {}, {}]: the field magnitude must be at least {} nT",
                    show(v[0]),
                    show(v[1]),
                    show(v[2]),
                    show(limits::MIN_FIELD_NT)
                );
            }
            let field =
                ReferenceField::from_ned(v[0], v[1], v[2]).map_err(|e| keyed("field.", &e, "the values given"))?;
            (field, "field.north_nt, east_nt, down_nt".to_string())
        }
        (Some(name), false) => {
            let model: wmm::Model = name
                .parse()
                .map_err(|e| anyhow::anyhow!("field.model = {name:?}: {e}"))?;
            let keys = ["lat_deg", "lon_deg", "alt_m", "year"];
            let mut v = [0.0; 4];
            for ((key, value), slot) in keys.iter().zip(site).zip(&mut v) {
                let Some(value) = value else {
                    bail!("field.{key} is missing (needed with field.model)")
                };
                *slot = finite(&format!("field.{key}"), value)?;
            }
            let site = wmm::Site {
                lat_deg: v[0],
                lon_deg: v[1],
                alt_m: v[2],
                year: v[3],
            };
            let field = wmm::reference_field(model, &site).map_err(|e| match e {
                ParameterError::OutsideValidityWindow { model, year } => anyhow::anyhow!(
                    "field.year = {}: outside the validity window of {} (its epoch to 5 years after)",
                    show(year),
                    model.name()
                ),
                // The core names its parameter; the key is the same under [field], and its value
                // is the one given.
                other => keyed("field.", &other, &other.value().map_or(String::new(), show)),
            })?;
            (field, crate::log::site::wmm_place(model, &site))
        }
    };
    let field = field
        .with_yaw_offset_deg(f.yaw_offset_deg)
        .map_err(|e| keyed("field.", &e, &show(f.yaw_offset_deg)))?;
    Ok((field, source))
}

/// The rules of an attitude range `[min, max]` in degrees, for the scenario's `[attitude_box]` and
/// the `--roll`, `--pitch`, `--yaw` flags alike: finite, each end in [-360, 360], the minimum below
/// the maximum, at most 360 apart. The rule broken, in words.
///
/// # Errors
/// The first rule `range` breaks.
pub fn check_range(range: [f64; 2]) -> Result<(), &'static str> {
    if !range.iter().all(|v| v.is_finite()) {
        return Err("must be finite numbers");
    }
    if range.iter().any(|v| v.abs() > 360.0) {
        return Err("each end must lie in [-360, 360] degrees");
    }
    if range[0] >= range[1] {
        return Err("the minimum must be below the maximum");
    }
    if range[1] - range[0] > 360.0 {
        return Err("spans more than 360 degrees");
    }
    Ok(())
}

/// A whole number given as any TOML value; `what` says what was expected.
fn whole(key: &str, value: &toml::Value, what: &str) -> Result<i64> {
    match value {
        toml::Value::Integer(i) => Ok(*i),
        toml::Value::Float(x) => bail!("{key} = {}: must be {what}", show(*x)),
        toml::Value::String(text) => bail!("{key} = {:?}: must be {what}", limits::excerpt(text, 40)),
        other => bail!("{key}: a {}, must be {what}", other.type_str()),
    }
}

fn check_name(key: &str, name: &str) -> Result<()> {
    let shown: String = name.chars().take(80).collect();
    let shown = if shown.len() < name.len() {
        format!("{shown:?}... ({} characters)", name.chars().count())
    } else {
        format!("{name:?}")
    };
    let ok = !name.is_empty()
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
    if !ok {
        bail!(
            "{key} = {shown}: use letters, digits, '_', '-' or '.', not starting with '.' (it names files and CSV rows)"
        );
    }
    if name.len() > limits::MAX_NAME {
        bail!("{key} = {shown}: at most {} characters", limits::MAX_NAME);
    }
    Ok(())
}

fn design(i: usize, d: raw::Design, raw_box: &raw::AttitudeBox) -> Result<DesignSpec> {
    let name = match &d {
        raw::Design::Explicit { name, .. }
        | raw::Design::Grid { name, .. }
        | raw::Design::Random { name, .. }
        | raw::Design::Pso { name, .. }
        | raw::Design::Optimum { name, .. }
        | raw::Design::Plan { name, .. } => name.clone(),
    };
    check_name(&format!("design[{i}].name"), &name)?;
    // `design[2] ("pso").particles`
    let prefix = format!("design[{i}] ({name:?}).");
    let key = |field: &str| format!("{prefix}{field}");
    let m_of = |m: usize| count(&key("m"), m, 9, limits::MAX_M);
    let source = match d {
        raw::Design::Explicit { attitudes, .. } => {
            count(&key("attitudes (count)"), attitudes.len(), 9, limits::MAX_M)?;
            let mut list = Vec::with_capacity(attitudes.len());
            for (j, a) in attitudes.iter().enumerate() {
                for (field, v, range) in [
                    ("roll_deg", a.roll_deg, raw_box.roll_deg),
                    ("yaw_deg", a.yaw_deg, raw_box.yaw_deg),
                    ("pitch_deg", a.pitch_deg, raw_box.pitch_deg),
                ] {
                    let k = key(&format!("attitudes[{j}].{field}"));
                    finite(&k, v)?;
                    // Half a micro-degree of slack, as the core's check in radians.
                    if v < range[0] - limits::BOX_SLACK_DEG || v > range[1] + limits::BOX_SLACK_DEG {
                        bail!(
                            "{k} = {}: outside the attitude box [{}, {}]",
                            show(v),
                            show(range[0]),
                            show(range[1])
                        );
                    }
                }
                list.push(Attitude::from_degrees(a.roll_deg, a.yaw_deg, a.pitch_deg));
            }
            DesignSource::Explicit(list)
        }
        raw::Design::Grid { levels, .. } => {
            let l = [levels.roll, levels.yaw, levels.pitch];
            for (field, n) in ["levels.roll", "levels.yaw", "levels.pitch"].iter().zip(l) {
                count(&key(field), n, 1, limits::MAX_M)?;
            }
            let product = l.iter().try_fold(1usize, |a, &n| a.checked_mul(n));
            match product {
                Some(p) if (9..=limits::MAX_M).contains(&p) => {}
                _ => bail!(
                    "{} = {} x {} x {}{}: must be at least 9 and at most {}",
                    key("levels (roll x yaw x pitch)"),
                    l[0],
                    l[1],
                    l[2],
                    product.map_or(String::new(), |p| format!(" = {p}")),
                    limits::MAX_M
                ),
            }
            DesignSource::Grid(l)
        }
        raw::Design::Random { m, .. } => DesignSource::Random { m: m_of(m)? },
        raw::Design::Pso {
            m,
            particles,
            iterations,
            w_max,
            w_min,
            c1,
            c2,
            vmax_fraction,
            threshold,
            criterion,
            ..
        } => {
            let d = Swarm::default();
            let swarm = Swarm {
                particles: count(
                    &key("particles"),
                    particles.unwrap_or(d.particles),
                    1,
                    limits::MAX_PARTICLES,
                )?,
                iterations: count(
                    &key("iterations"),
                    iterations.unwrap_or(d.iterations),
                    1,
                    limits::MAX_PSO_ITERATIONS,
                )?,
                w_max: w_max.unwrap_or(d.w_max),
                w_min: w_min.unwrap_or(d.w_min),
                c1: c1.unwrap_or(d.c1),
                c2: c2.unwrap_or(d.c2),
                vmax_fraction: vmax_fraction.unwrap_or(d.vmax_fraction),
                threshold,
                criterion: criterion.map_or(d.criterion, Into::into),
            };
            for (field, v) in [
                ("w_max", swarm.w_max),
                ("w_min", swarm.w_min),
                ("c1", swarm.c1),
                ("c2", swarm.c2),
            ] {
                within(&key(field), v, 0.0, 10.0, "")?;
            }
            swarm.validate().map_err(|e| {
                let value = match &e {
                    ParameterError::EmptyRange { min, max, .. } => format!("{} (w_max = {})", show(*min), show(*max)),
                    ParameterError::NonFinite { value, .. }
                    | ParameterError::NotPositive { value, .. }
                    | ParameterError::Negative { value, .. }
                    | ParameterError::OutOfRange { value, .. } => show(*value),
                    ParameterError::TooSmall { value, .. } | ParameterError::TooLarge { value, .. } => {
                        value.to_string()
                    }
                    other => other.to_string(),
                };
                keyed(&prefix, &e, &value)
            })?;
            DesignSource::Pso { m: m_of(m)?, swarm }
        }
        raw::Design::Optimum {
            m,
            starts,
            max_iterations,
            gradient_tolerance,
            criterion,
            ..
        } => {
            let d = Optimum::default();
            let settings = Optimum {
                starts: count(&key("starts"), starts.unwrap_or(d.starts), 1, limits::MAX_STARTS)?,
                max_iterations: count(
                    &key("max_iterations"),
                    max_iterations.unwrap_or(d.max_iterations),
                    1,
                    limits::MAX_OPTIMUM_ITERATIONS,
                )?,
                gradient_tolerance: gradient_tolerance.unwrap_or(d.gradient_tolerance),
                memory: d.memory,
                criterion: criterion.map_or(d.criterion, Into::into),
            };
            if !(settings.gradient_tolerance.is_finite() && settings.gradient_tolerance > 0.0) {
                bail!(
                    "{} = {}: must be positive and finite",
                    key("gradient_tolerance"),
                    show(settings.gradient_tolerance)
                );
            }
            settings.validate().map_err(|e| keyed(&prefix, &e, "the value given"))?;
            DesignSource::Optimum { m: m_of(m)?, settings }
        }
        raw::Design::Plan {
            readings,
            max_attitudes,
            min_readings_per_attitude,
            ..
        } => {
            let readings = count(&key("readings"), readings, 9, limits::MAX_M)?;
            let why_nine =
                "each attitude gives one equation, whatever its readings, and the linear model has 9 unknowns";
            let max_attitudes = match max_attitudes {
                None => Some(DEFAULT_MAX_ATTITUDES),
                Some(toml::Value::String(word)) if word == "all" => None,
                Some(value) => {
                    let k = whole(&key("max_attitudes"), &value, "a whole number of attitudes or \"all\"")?;
                    if k < 9 {
                        bail!(
                            "{} = {k}: must be at least 9 ({why_nine}), or \"all\"",
                            key("max_attitudes")
                        );
                    }
                    // Beyond MAX_M it cannot bind (a plan has at most `readings` attitudes).
                    Some(usize::try_from(k).unwrap_or(usize::MAX).min(limits::MAX_M + 1))
                }
            };
            let min_readings = match min_readings_per_attitude {
                None => 1,
                Some(value) => {
                    let r = whole(&key("min_readings_per_attitude"), &value, "a whole number of readings")?;
                    if r < 1 {
                        bail!("{} = {r}: must be at least 1", key("min_readings_per_attitude"));
                    }
                    if r > (readings / 9) as i64 {
                        bail!(
                            "{} = {r}: must be at most {} (readings = {readings} over the 9 attitudes a plan needs \
                             at least: {why_nine})",
                            key("min_readings_per_attitude"),
                            readings / 9
                        );
                    }
                    r as usize
                }
            };
            let limits = PlanLimits {
                max_attitudes,
                min_readings,
            };
            limits
                .validate(readings)
                .map_err(|e| keyed(&prefix, &e, "the value given"))?;
            DesignSource::Plan { readings, limits }
        }
    };
    Ok(DesignSpec { name, source })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn smoke() -> String {
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/smoke.toml")).unwrap()
    }

    fn error_of(text: &str) -> String {
        format!("{:#}", parse(text.as_bytes(), Path::new("s.toml")).unwrap_err())
    }

    #[test]
    fn a_single_noise_level_may_be_a_number() {
        let text = smoke().replace("sigma_nt = [10.0, 30.0]", "sigma_nt = 30.0");
        let s = parse(text.as_bytes(), Path::new("s.toml")).unwrap();
        assert_eq!(s.sigmas_nt, [30.0]);
        let text = smoke().replace("sigma_nt = [10.0, 30.0]", "sigma_nt = 30");
        assert_eq!(parse(text.as_bytes(), Path::new("s.toml")).unwrap().sigmas_nt, [30.0]);
    }

    #[test]
    fn fixed_length_arrays_take_exactly_their_length() {
        let e = error_of(&smoke().replace("psi_deg = [1.5, 0.8, 1.4]", "psi_deg = [1.5, 0.8, 1.4, 2.0]"));
        assert!(
            e.contains("s.toml:") && e.contains("invalid length 4") && e.contains("exactly 3"),
            "{e}"
        );
        let e = error_of(&smoke().replace("roll_deg = [-5.0, 5.0]", "roll_deg = [-5.0, 5.0, 99.0]"));
        assert!(e.contains("invalid length 3") && e.contains("exactly 2"), "{e}");
    }

    #[test]
    fn messages_show_the_value_as_written() {
        let e = error_of(&smoke().replace(
            "{ roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = 0.0 }",
            "{ roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = -60 }",
        ));
        assert!(
            e.contains("attitudes[4].pitch_deg = -60: outside the attitude box [-20, 20]"),
            "{e}"
        );
        let e = error_of(&smoke().replace("north_nt = 35272.34", "north_nt = 1e308"));
        assert!(e.contains("field.north_nt = 1e308: must lie in"), "{e}");
        let e = error_of(&smoke().replace("particles = 40", "particles = 0"));
        assert!(
            e.contains("design[2] (\"pso\").particles = 0: must be at least 1"),
            "{e}"
        );
    }
}
