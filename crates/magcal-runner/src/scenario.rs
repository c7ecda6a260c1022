//! Scenario files: the raw TOML schema (`raw`), and its validation into a [`Scenario`] whose every
//! value is usable. Errors name the file, the key and the value.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use magcal_core::design::optimum::Optimum;
use magcal_core::design::pso::Swarm;
use magcal_core::design::sources;
use magcal_core::{Attitude, AttitudeBox, ErrorModel, ReferenceField, TwoStep, wmm};
use sha2::{Digest, Sha256};

/// The schema version this build reads.
pub const SCHEMA: u32 = 1;

/// Default noisy trials per design and noise level (\[P1\] IV.C: one thousand).
pub const DEFAULT_TRIALS: usize = 1000;

/// The raw file, as TOML gives it. Every table denies unknown keys.
mod raw {
    use serde::Deserialize;

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
        pub sigma_nt: Vec<f64>,
        pub field: Field,
        pub sensor: Sensor,
        pub attitude_box: AttitudeBox,
        #[serde(default)]
        pub calibration: Calibration,
        pub design: Vec<Design>,
        pub pso_runs: Option<PsoRuns>,
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
        pub psi_deg: [f64; 3],
        pub scale: [f64; 3],
        pub bias_nt: [f64; 3],
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct AttitudeBox {
        pub roll_deg: [f64; 2],
        pub yaw_deg: [f64; 2],
        pub pitch_deg: [f64; 2],
    }

    #[derive(Debug, Default, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Calibration {
        pub max_iterations: Option<usize>,
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
        },
        Optimum {
            name: String,
            m: usize,
            starts: Option<usize>,
            max_iterations: Option<usize>,
            gradient_tolerance: Option<f64>,
        },
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct PsoRuns {
        pub runs: usize,
        pub design: String,
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
}

impl DesignSource {
    /// `explicit`, `grid`, `random`, `pso` or `optimum`.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Explicit(_) => "explicit",
            Self::Grid(_) => "grid",
            Self::Random { .. } => "random",
            Self::Pso { .. } => "pso",
            Self::Optimum { .. } => "optimum",
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
    /// Reference field.
    pub field: ReferenceField,
    /// True sensor errors.
    pub truth: ErrorModel,
    /// The vehicle's attitude box.
    pub bounds: AttitudeBox,
    /// Two-step calibration settings.
    pub calibration: TwoStep,
    /// Designs, in file order.
    pub designs: Vec<DesignSpec>,
    /// Repeated PSO runs, if asked.
    pub pso_runs: Option<PsoRunsSpec>,
}

/// Reads and validates a scenario file.
///
/// # Errors
/// A missing or unreadable file, a TOML syntax error (with line and column), an unknown key, a
/// wrong type, or an invalid value; each message names the file, the key and the value.
pub fn load(path: &Path) -> Result<Scenario> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read scenario file", path.display()))?;
    let text = String::from_utf8(bytes.clone()).with_context(|| format!("{}: not UTF-8 text", path.display()))?;
    let raw: raw::Scenario = toml::from_str(&text).map_err(|e| toml_error(path, &text, &e))?;
    let hash = Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect();
    validate(raw, path, hash).with_context(|| format!("{}: invalid scenario", path.display()))
}

/// One line: `file:line:column: message (in: <the source line>)`.
fn toml_error(path: &Path, text: &str, e: &toml::de::Error) -> anyhow::Error {
    let message = e.message().trim().replace('\n', " ");
    match e.span() {
        Some(span) => {
            let before = &text[..span.start.min(text.len())];
            let line = before.matches('\n').count() + 1;
            let column = before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1;
            let source = text.lines().nth(line - 1).unwrap_or("").trim();
            anyhow::anyhow!("{}:{line}:{column}: {message} (in: {source})", path.display())
        }
        None => anyhow::anyhow!("{}: {message}", path.display()),
    }
}

fn finite(key: &str, value: f64) -> Result<f64> {
    if !value.is_finite() {
        bail!("{key} = {value}: must be a finite number");
    }
    Ok(value)
}

fn at_least(key: &str, value: usize, min: usize) -> Result<usize> {
    if value < min {
        bail!("{key} = {value}: must be at least {min}");
    }
    Ok(value)
}

fn validate(raw: raw::Scenario, path: &Path, hash: String) -> Result<Scenario> {
    if raw.schema != SCHEMA {
        bail!("schema = {}: this magcal reads schema {SCHEMA}", raw.schema);
    }
    check_name("name", &raw.name)?;
    at_least("trials", raw.trials, 1)?;
    if raw.sigma_nt.is_empty() {
        bail!("sigma_nt = []: give at least one noise level");
    }
    for (i, &s) in raw.sigma_nt.iter().enumerate() {
        finite(&format!("sigma_nt[{i}]"), s)?;
        if s < 0.0 {
            bail!("sigma_nt[{i}] = {s}: a noise level cannot be negative");
        }
    }
    for (i, s) in raw.sigma_nt.iter().enumerate() {
        if raw.sigma_nt[..i].iter().any(|t| t.to_bits() == s.to_bits()) {
            bail!("sigma_nt[{i}] = {s}: listed twice");
        }
    }

    let field = reference_field(&raw.field)?;

    let s = &raw.sensor;
    for (key, values) in [
        ("sensor.psi_deg", s.psi_deg),
        ("sensor.scale", s.scale),
        ("sensor.bias_nt", s.bias_nt),
    ] {
        for (i, v) in values.into_iter().enumerate() {
            finite(&format!("{key}[{i}]"), v)?;
        }
    }
    let truth = ErrorModel::new(s.psi_deg, s.scale, s.bias_nt).map_err(|e| anyhow::anyhow!("sensor: {e}"))?;

    let b = &raw.attitude_box;
    for (key, range) in [
        ("attitude_box.roll_deg", b.roll_deg),
        ("attitude_box.yaw_deg", b.yaw_deg),
        ("attitude_box.pitch_deg", b.pitch_deg),
    ] {
        finite(&format!("{key}[0]"), range[0])?;
        finite(&format!("{key}[1]"), range[1])?;
        if range[0] >= range[1] {
            bail!(
                "{key} = [{}, {}]: the minimum must be below the maximum",
                range[0],
                range[1]
            );
        }
        if range[1] - range[0] > 360.0 {
            bail!("{key} = [{}, {}]: spans more than 360 degrees", range[0], range[1]);
        }
    }
    let bounds = AttitudeBox::from_degrees(b.roll_deg, b.yaw_deg, b.pitch_deg).context("attitude_box")?;

    let mut calibration = TwoStep::default();
    if let Some(n) = raw.calibration.max_iterations {
        calibration.max_iterations = at_least("calibration.max_iterations", n, 1)?;
    }

    if raw.design.is_empty() {
        bail!("no [[design]]: give at least one design");
    }
    let mut designs: Vec<DesignSpec> = Vec::with_capacity(raw.design.len());
    for (i, d) in raw.design.into_iter().enumerate() {
        let spec = design(i, d, &bounds)?;
        if designs.iter().any(|other| other.name == spec.name) {
            bail!("design[{i}].name = {:?}: another design has this name", spec.name);
        }
        designs.push(spec);
    }

    let pso_runs = match raw.pso_runs {
        None => None,
        Some(r) => {
            at_least("pso_runs.runs", r.runs, 1)?;
            let Some(spec) = designs.iter().find(|d| d.name == r.design) else {
                bail!("pso_runs.design = {:?}: no design has this name", r.design);
            };
            let DesignSource::Pso { m, swarm } = &spec.source else {
                bail!(
                    "pso_runs.design = {:?}: that design is {}, not pso",
                    r.design,
                    spec.source.kind()
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

    Ok(Scenario {
        path: path.to_path_buf(),
        hash,
        name: raw.name,
        description: raw.description,
        seed: raw.seed,
        trials: raw.trials,
        sigmas_nt: raw.sigma_nt,
        field,
        truth,
        bounds,
        calibration,
        designs,
        pso_runs,
    })
}

/// The reference field from `[field]`: NED numbers (nT), or `model, lat_deg, lon_deg, alt_m, year`
/// evaluated with the World Magnetic Model; then the yaw offset.
fn reference_field(f: &raw::Field) -> Result<ReferenceField> {
    finite("field.yaw_offset_deg", f.yaw_offset_deg)?;
    let ned = [f.north_nt, f.east_nt, f.down_nt];
    let site = [f.lat_deg, f.lon_deg, f.alt_m, f.year];
    let field = match (&f.model, ned.iter().any(Option::is_some)) {
        (Some(_), true) => bail!("[field]: give either north_nt, east_nt, down_nt or a model and site, not both"),
        (None, _) => {
            let keys = ["field.north_nt", "field.east_nt", "field.down_nt"];
            let mut v = [0.0; 3];
            for ((key, value), slot) in keys.iter().zip(ned).zip(&mut v) {
                let Some(value) = value else {
                    bail!("{key} is missing (or give field.model with lat_deg, lon_deg, alt_m, year)");
                };
                *slot = finite(key, value)?;
            }
            if site.iter().any(Option::is_some) {
                bail!("[field]: lat_deg, lon_deg, alt_m and year need field.model");
            }
            ReferenceField::from_ned(v[0], v[1], v[2]).context("field")?
        }
        (Some(name), false) => {
            let Some(model) = wmm::Model::from_name(name) else {
                let known: Vec<&str> = wmm::Model::ALL.iter().map(|m| m.name()).collect();
                bail!("field.model = {name:?}: unknown model; known: {}", known.join(", "));
            };
            let keys = ["field.lat_deg", "field.lon_deg", "field.alt_m", "field.year"];
            let mut v = [0.0; 4];
            for ((key, value), slot) in keys.iter().zip(site).zip(&mut v) {
                let Some(value) = value else {
                    bail!("{key} is missing (needed with field.model)")
                };
                *slot = finite(key, value)?;
            }
            let site = wmm::Site {
                lat_deg: v[0],
                lon_deg: v[1],
                alt_m: v[2],
                year: v[3],
            };
            wmm::reference_field(model, &site).map_err(|e| match e {
                magcal_core::ParameterError::OutOfRange {
                    name: "field.year",
                    value,
                    ..
                } => {
                    anyhow::anyhow!(
                        "field.year = {value}: outside the validity window of {name} (its epoch to 5 years after)"
                    )
                }
                other => anyhow::anyhow!("{other}"),
            })?
        }
    };
    field.with_yaw_offset_deg(f.yaw_offset_deg).context("field")
}

fn check_name(key: &str, name: &str) -> Result<()> {
    let ok = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
    if !ok {
        bail!("{key} = {name:?}: use letters, digits, '_', '-' or '.' (it names files and CSV rows)");
    }
    Ok(())
}

fn design(i: usize, d: raw::Design, bounds: &AttitudeBox) -> Result<DesignSpec> {
    let key = |field: &str| format!("design[{i}].{field}");
    let (name, source) = match d {
        raw::Design::Explicit { name, attitudes } => {
            at_least(&key("attitudes (count)"), attitudes.len(), 9)?;
            let mut list = Vec::with_capacity(attitudes.len());
            for (j, a) in attitudes.iter().enumerate() {
                for (field, v) in [
                    ("roll_deg", a.roll_deg),
                    ("yaw_deg", a.yaw_deg),
                    ("pitch_deg", a.pitch_deg),
                ] {
                    finite(&key(&format!("attitudes[{j}].{field}")), v)?;
                }
                list.push(Attitude::from_degrees(a.roll_deg, a.yaw_deg, a.pitch_deg));
            }
            if let Err((j, e)) = sources::check_explicit(&list, bounds) {
                bail!("{}: {e}", key(&format!("attitudes[{j}]")));
            }
            (name, DesignSource::Explicit(list))
        }
        raw::Design::Grid { name, levels } => {
            let l = [levels.roll, levels.yaw, levels.pitch];
            for (field, n) in ["levels.roll", "levels.yaw", "levels.pitch"].iter().zip(l) {
                at_least(&key(field), n, 1)?;
            }
            at_least(&key("levels (roll * yaw * pitch)"), l.iter().product(), 9)?;
            (name, DesignSource::Grid(l))
        }
        raw::Design::Random { name, m } => (
            name,
            DesignSource::Random {
                m: at_least(&key("m"), m, 9)?,
            },
        ),
        raw::Design::Pso {
            name,
            m,
            particles,
            iterations,
            w_max,
            w_min,
            c1,
            c2,
            vmax_fraction,
            threshold,
        } => {
            let d = Swarm::default();
            let swarm = Swarm {
                particles: particles.unwrap_or(d.particles),
                iterations: iterations.unwrap_or(d.iterations),
                w_max: w_max.unwrap_or(d.w_max),
                w_min: w_min.unwrap_or(d.w_min),
                c1: c1.unwrap_or(d.c1),
                c2: c2.unwrap_or(d.c2),
                vmax_fraction: vmax_fraction.unwrap_or(d.vmax_fraction),
                threshold,
                criterion: d.criterion,
            };
            swarm.validate().map_err(|e| anyhow::anyhow!("{}: {e}", key("")))?;
            (
                name,
                DesignSource::Pso {
                    m: at_least(&key("m"), m, 9)?,
                    swarm,
                },
            )
        }
        raw::Design::Optimum {
            name,
            m,
            starts,
            max_iterations,
            gradient_tolerance,
        } => {
            let d = Optimum::default();
            let settings = Optimum {
                starts: starts.unwrap_or(d.starts),
                max_iterations: max_iterations.unwrap_or(d.max_iterations),
                gradient_tolerance: gradient_tolerance.unwrap_or(d.gradient_tolerance),
                memory: d.memory,
            };
            settings.validate().map_err(|e| anyhow::anyhow!("{}: {e}", key("")))?;
            (
                name,
                DesignSource::Optimum {
                    m: at_least(&key("m"), m, 9)?,
                    settings,
                },
            )
        }
    };
    check_name(&key("name"), &name)?;
    Ok(DesignSpec { name, source })
}
