//! The raw file, as TOML gives it. Every table denies unknown keys; fixed-length arrays take
//! exactly their length.

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
    pub heading_budget_deg: Option<f64>,
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
    Explicit { name: String, attitudes: Vec<Attitude> },
    Grid { name: String, levels: Levels },
    Random { name: String, m: usize },
    Pso(Pso),
    Plan(Plan),
    Optimum(Optimum),
}

/// `kind = "pso"`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pso {
    pub name: String,
    pub m: usize,
    pub particles: Option<usize>,
    pub iterations: Option<usize>,
    pub w_max: Option<f64>,
    pub w_min: Option<f64>,
    pub c1: Option<f64>,
    pub c2: Option<f64>,
    pub vmax_fraction: Option<f64>,
    pub threshold: Option<f64>,
    pub criterion: Option<Criterion>,
}

/// `kind = "plan"`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Plan {
    pub name: String,
    pub readings: usize,
    // Read as any TOML value and checked in `design`: a design table is buffered for its
    // `kind` tag, and serde's errors from inside it name neither the key nor the value.
    pub max_attitudes: Option<toml::Value>,
    pub min_readings_per_attitude: Option<toml::Value>,
}

/// `kind = "optimum"`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Optimum {
    pub name: String,
    pub m: usize,
    pub starts: Option<usize>,
    pub max_iterations: Option<usize>,
    pub gradient_tolerance: Option<f64>,
    pub criterion: Option<Criterion>,
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
