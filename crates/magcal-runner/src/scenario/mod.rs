//! Scenario files: the raw TOML schema (`raw`), and its validation (`validate`, `design`) into a
//! [`Scenario`] whose every value is usable and every size bounded ([`crate::limits`]). Errors name
//! the file, the key and the value as written. [`site`] types the site, date and units that
//! scenarios and the log commands' flags share.

mod design;
mod raw;
pub use magcal_logs::site;
pub use magcal_report::rows::DesignKind;
pub(crate) mod validate;
mod values;

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use magcal_core::design::approximate::Approximate;
use magcal_core::design::optimum::Optimum;
use magcal_core::design::plan::PlanLimits;
use magcal_core::design::pso::Swarm;
use magcal_core::{Attitude, AttitudeBox, ErrorModel, ReferenceField, TwoStep};

use crate::limits;

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
/// attitude, 37 support points: see docs/research/certified.md). `"all"` lifts the limit.
pub const DEFAULT_MAX_ATTITUDES: usize = 12;

/// Default noisy trials per design and noise level (\[P1\] IV.C: one thousand).
pub const DEFAULT_TRIALS: usize = 1000;

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
    /// The heading error a design's calibration may leave, degrees (`[verdict]
    /// heading_budget_deg`, default [`magcal_core::budget::DEFAULT_BUDGET_DEG`]): a design works
    /// where the 95th percentile over its box at every heading is within it.
    pub heading_budget_deg: f64,
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
    let hash = crate::digest::sha256_hex(bytes);
    validate::validate(raw, path, hash).with_context(|| format!("{}: invalid scenario", path.display()))
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
