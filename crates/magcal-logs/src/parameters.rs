//! What a flight log says of its firmware's parameters, for `magcal export`: which of the
//! parameters export writes the firmware has, and ArduPilot's `COMPASS_OFFS_MAX`. `calibrate`
//! records it in `calibration.json` as `log_parameters` ([`LogParameters`]).
//!
//! A name missing from a log says the firmware lacks the parameter only where the log lists every
//! parameter of its firmware: an ArduPilot DataFlash log writes all of them as `PARM` when it
//! starts (`AP_Logger`), a ULog all of them in its header; a telemetry log holds them all only
//! where the ground station fetched the whole list (`PARAM_VALUE` of every `param_index` below
//! `param_count`). Elsewhere `names` is `null` and export writes every parameter.

use std::collections::BTreeSet;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::limits::excerpt;

/// The autopilot whose parameters a log lists.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Autopilot {
    #[serde(rename = "ArduPilot")]
    ArduPilot,
    #[serde(rename = "PX4")]
    Px4,
}

impl Autopilot {
    /// The name in `calibration.json` and in the outputs.
    pub fn name(self) -> &'static str {
        match self {
            Self::ArduPilot => "ArduPilot",
            Self::Px4 => "PX4",
        }
    }
}

/// The largest `COMPASS_OFFS_MAX` ArduPilot can hold (an `AP_Int16`), mGauss.
pub const OFFS_MAX_LIMIT: f64 = 32767.0;
/// The longest parameter name of either autopilot (MAVLink's `param_id` holds 16 characters).
pub const NAME_MAX: usize = 16;

/// `log_parameters` of `calibration.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "Value")]
pub struct LogParameters {
    /// The autopilot whose parameters the log lists.
    pub autopilot: Autopilot,
    /// The messages the parameters come from: `PARM`, `PARAM_VALUE` or `ULog parameters`.
    pub source: String,
    /// The parameters `export` writes for [`Self::autopilot`] (every instance) that the log
    /// lists, where the log lists every parameter of its firmware; `None` where it does not (a
    /// name missing from it then says nothing).
    pub names: Option<BTreeSet<String>>,
    /// `COMPASS_OFFS_MAX` as the log last gives it, mGauss (ArduPilot); `None` where the log does
    /// not give it.
    pub compass_offs_max: Option<f64>,
}

impl LogParameters {
    /// An ArduPilot log's parameters: `listed` the names among those export writes, when the log
    /// lists every parameter of its firmware; `offs_max` the last `COMPASS_OFFS_MAX`. The list
    /// is kept only where it holds `COMPASS_OFS_X`, which every ArduPilot firmware with a compass
    /// has (a list without it is not an ArduPilot compass's), and `offs_max` only where ArduPilot
    /// could hold it (1 to 32767). `None` when neither is kept.
    pub fn ardupilot<'a>(
        source: &str,
        listed: Option<impl Iterator<Item = &'a String>>,
        offs_max: Option<f64>,
    ) -> Option<Self> {
        let names = listed
            .map(|n| n.cloned().collect::<BTreeSet<String>>())
            .filter(|n| n.contains("COMPASS_OFS_X"));
        let compass_offs_max = offs_max.filter(|v| offs_max_valid(*v));
        (names.is_some() || compass_offs_max.is_some()).then(|| Self {
            autopilot: Autopilot::ArduPilot,
            source: source.to_string(),
            names,
            compass_offs_max,
        })
    }

    /// A PX4 log's parameters: the names of `all` (every parameter of the log) that export
    /// writes ([`px4_written`]), kept where they hold `CAL_MAG0_XOFF`, which every PX4 firmware
    /// has.
    pub fn px4<'a>(all: impl Iterator<Item = &'a String>) -> Option<Self> {
        let names: BTreeSet<String> = all.filter(|n| px4_written(n)).cloned().collect();
        names.contains("CAL_MAG0_XOFF").then(|| Self {
            autopilot: Autopilot::Px4,
            source: "ULog parameters".to_string(),
            names: Some(names),
            compass_offs_max: None,
        })
    }

    /// The names the firmware has, where the list is of `autopilot`'s parameters and whole.
    pub fn names_of(&self, autopilot: Autopilot) -> Option<&BTreeSet<String>> {
        self.names.as_ref().filter(|_| self.autopilot == autopilot)
    }
}

/// Whether ArduPilot could hold `v` as `COMPASS_OFFS_MAX`.
fn offs_max_valid(v: f64) -> bool {
    v.is_finite() && (1.0..=OFFS_MAX_LIMIT).contains(&v)
}

/// Whether `name` is one of the PX4 parameters export writes: `CAL_MAGn_` and `X`, `Y` or `Z`
/// with `OFF`, `SCALE`, `ODIAG` or `COMP` (`n` one digit), and `CAL_MAG_COMP_TYP`.
pub fn px4_written(name: &str) -> bool {
    if name == "CAL_MAG_COMP_TYP" {
        return true;
    }
    let Some(rest) = name.strip_prefix("CAL_MAG") else {
        return false;
    };
    let mut chars = rest.chars();
    let (Some(n), Some('_'), Some('X' | 'Y' | 'Z')) = (chars.next(), chars.next(), chars.next()) else {
        return false;
    };
    n.is_ascii_digit() && matches!(chars.as_str(), "OFF" | "SCALE" | "ODIAG" | "COMP")
}

/// `value` as the message shows it.
fn shown(value: &Value) -> String {
    excerpt(&value.to_string(), 40)
}

impl TryFrom<Value> for LogParameters {
    type Error = String;

    /// Checks each field, naming it and its value: `autopilot` `ArduPilot` or `PX4`, `source` a
    /// string, `names` `null` or parameter names (1 to 16 of `A-Z`, `0-9`, `_`),
    /// `compass_offs_max` `null` or a number from 1 to 32767. Other keys are ignored, as in the
    /// rest of the file.
    fn try_from(v: Value) -> Result<Self, String> {
        let Value::Object(map) = &v else {
            return Err(format!("log_parameters {}: not an object", shown(&v)));
        };
        let field = |name: &str| map.get(name).unwrap_or(&Value::Null);
        let autopilot = match field("autopilot").as_str() {
            Some("ArduPilot") => Autopilot::ArduPilot,
            Some("PX4") => Autopilot::Px4,
            _ => {
                return Err(format!(
                    "log_parameters.autopilot {}: not \"ArduPilot\" or \"PX4\"",
                    shown(field("autopilot"))
                ));
            }
        };
        let Some(source) = field("source").as_str() else {
            return Err(format!(
                "log_parameters.source {}: not a string",
                shown(field("source"))
            ));
        };
        let names = match field("names") {
            Value::Null => None,
            Value::Array(items) => Some(
                items
                    .iter()
                    .map(|item| match item.as_str() {
                        Some(n) if parameter_name(n) => Ok(n.to_string()),
                        _ => Err(format!(
                            "log_parameters.names: {}: not a parameter name (1 to {NAME_MAX} of A-Z, 0-9, _)",
                            shown(item)
                        )),
                    })
                    .collect::<Result<BTreeSet<String>, String>>()?,
            ),
            other => {
                return Err(format!(
                    "log_parameters.names {}: not null or a list of names",
                    shown(other)
                ));
            }
        };
        let compass_offs_max = match field("compass_offs_max") {
            Value::Null => None,
            other => match other.as_f64() {
                Some(x) if offs_max_valid(x) => Some(x),
                _ => {
                    return Err(format!(
                        "log_parameters.compass_offs_max {}: not null or a number of mGauss from 1 to {OFFS_MAX_LIMIT} (ArduPilot's int16)",
                        shown(other)
                    ));
                }
            },
        };
        Ok(Self {
            autopilot,
            source: source.to_string(),
            names,
            compass_offs_max,
        })
    }
}

/// A parameter name as both autopilots spell theirs.
fn parameter_name(n: &str) -> bool {
    (1..=NAME_MAX).contains(&n.len())
        && n.bytes()
            .all(|b| b.is_ascii_uppercase() || b.is_ascii_digit() || b == b'_')
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<LogParameters, String> {
        serde_json::from_str::<LogParameters>(text).map_err(|e| e.to_string())
    }

    #[test]
    fn the_json_round_trips_and_each_bad_field_is_named_with_its_value() {
        let p = LogParameters::ardupilot(
            "PARM",
            Some(["COMPASS_OFS_X", "COMPASS_DIA_X"].map(String::from).iter()),
            Some(850.0),
        )
        .unwrap();
        let text = serde_json::to_string(&p).unwrap();
        assert_eq!(
            text,
            r#"{"autopilot":"ArduPilot","source":"PARM","names":["COMPASS_DIA_X","COMPASS_OFS_X"],"compass_offs_max":850.0}"#
        );
        assert_eq!(parse(&text).unwrap(), p);
        for (text, said) in [
            (r#"[1]"#, "log_parameters [1]: not an object"),
            (
                r#"{"autopilot":"iNav","source":"x"}"#,
                "log_parameters.autopilot \"iNav\"",
            ),
            (r#"{"autopilot":"PX4"}"#, "log_parameters.source null: not a string"),
            (
                r#"{"autopilot":"PX4","source":"x","names":"CAL"}"#,
                "log_parameters.names \"CAL\": not null or a list",
            ),
            (
                r#"{"autopilot":"PX4","source":"x","names":["cal_mag0_xoff"]}"#,
                "log_parameters.names: \"cal_mag0_xoff\": not a parameter name",
            ),
            (
                r#"{"autopilot":"ArduPilot","source":"x","compass_offs_max":"850"}"#,
                "log_parameters.compass_offs_max \"850\": not null or a number",
            ),
            (
                r#"{"autopilot":"ArduPilot","source":"x","compass_offs_max":0}"#,
                "log_parameters.compass_offs_max 0: not null",
            ),
            (
                r#"{"autopilot":"ArduPilot","source":"x","compass_offs_max":40000}"#,
                "log_parameters.compass_offs_max 40000:",
            ),
        ] {
            let e = parse(text).unwrap_err();
            assert!(e.starts_with(said), "{text}: {e}");
        }
        // Absent fields are null; unknown ones are ignored.
        let p = parse(r#"{"autopilot":"PX4","source":"ULog parameters","later":1}"#).unwrap();
        assert_eq!((p.names, p.compass_offs_max), (None, None));
    }

    #[test]
    fn a_list_is_kept_only_where_it_is_the_autopilots() {
        let names = ["COMPASS_DIA_X", "COMPASS_SCALE"].map(String::from);
        // No COMPASS_OFS_X: not an ArduPilot compass's list; the offset limit is still kept.
        let p = LogParameters::ardupilot("PARAM_VALUE", Some(names.iter()), Some(850.0)).unwrap();
        assert_eq!((p.names, p.compass_offs_max), (None, Some(850.0)));
        assert!(LogParameters::ardupilot("PARM", Some(names.iter()), Some(0.0)).is_none());
        assert!(LogParameters::ardupilot("PARM", None::<std::slice::Iter<String>>, None).is_none());
        let all = [
            "CAL_MAG0_XOFF",
            "CAL_MAG0_XSCALE",
            "CAL_MAG1_ZCOMP",
            "CAL_MAG_COMP_TYP",
            "SENS_BOARD_ROT",
        ]
        .map(String::from);
        let p = LogParameters::px4(all.iter()).unwrap();
        assert_eq!(p.names.as_ref().unwrap().len(), 4);
        assert!(p.names_of(Autopilot::ArduPilot).is_none());
        assert!(p.names_of(Autopilot::Px4).unwrap().contains("CAL_MAG1_ZCOMP"));
        for (name, written) in [
            ("CAL_MAG3_YODIAG", true),
            ("CAL_MAG0_ID", false),
            ("CAL_MAG0_XOFFS", false),
            ("CAL_MAGX_XOFF", false),
            ("CAL_MAG_COMP_TYP", true),
        ] {
            assert_eq!(px4_written(name), written, "{name}");
        }
    }
}
