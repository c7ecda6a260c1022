//! The checks of single values of a scenario: a finite number, one within a range, a count, a
//! whole number given as any TOML value, a name; and a core parameter error against its key. Each
//! error names the key and the value as written.

use anyhow::{Result, bail};
use magcal_core::ParameterError;

use crate::limits::{self, show};

/// `value`, when finite.
pub(super) fn finite(key: &str, value: f64) -> Result<f64> {
    if !value.is_finite() {
        bail!("{key} = {}: must be a finite number", show(value));
    }
    Ok(value)
}

/// `value`, when finite and in `[min, max]` (`unit` follows the range in the error).
pub(super) fn within(key: &str, value: f64, min: f64, max: f64, unit: &str) -> Result<f64> {
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

/// `value`, when in `[min, max]`.
pub(super) fn count(key: &str, value: usize, min: usize, max: usize) -> Result<usize> {
    if value < min {
        bail!("{key} = {value}: must be at least {min}");
    }
    if value > max {
        bail!("{key} = {value}: must be at most {max}");
    }
    Ok(value)
}

/// A core parameter error against the key that carried it: `key = value: requirement`.
pub(super) fn keyed(prefix: &str, e: &ParameterError, value: &str) -> anyhow::Error {
    anyhow::anyhow!("{prefix}{} = {value}: {}", e.name(), e.requirement())
}

/// A whole number given as any TOML value; `what` says what was expected.
pub(super) fn whole(key: &str, value: &toml::Value, what: &str) -> Result<i64> {
    match value {
        toml::Value::Integer(i) => Ok(*i),
        toml::Value::Float(x) => bail!("{key} = {}: must be {what}", show(*x)),
        toml::Value::String(text) => bail!("{key} = {:?}: must be {what}", limits::excerpt(text, 40)),
        other => bail!("{key}: a {}, must be {what}", other.type_str()),
    }
}

/// A name that can name files and CSV rows: letters, digits, `_`, `-`, `.`, not starting with
/// `.`, at most [`limits::MAX_NAME`] characters.
pub(super) fn check_name(key: &str, name: &str) -> Result<()> {
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
