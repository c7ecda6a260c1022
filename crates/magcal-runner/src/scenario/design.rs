//! The validation of one `[[design]]`, one function per source: a list of attitudes, a grid, random
//! attitudes, the PSO, the optimum, a plan of readings.

use anyhow::{Result, bail};
use magcal_core::design::optimum::Optimum;
use magcal_core::design::plan::PlanLimits;
use magcal_core::design::pso::Swarm;
use magcal_core::{Attitude, ParameterError};

use super::raw;
use super::values::{check_name, count, finite, keyed, whole, within};
use super::{DEFAULT_MAX_ATTITUDES, DesignSource, DesignSpec};
use crate::limits::{self, show};

/// `[[design]]` number `i`, its attitudes checked against the box `raw_box`.
pub(super) fn design(i: usize, d: raw::Design, raw_box: &raw::AttitudeBox) -> Result<DesignSpec> {
    let name = match &d {
        raw::Design::Explicit { name, .. } | raw::Design::Grid { name, .. } | raw::Design::Random { name, .. } => {
            name.clone()
        }
        raw::Design::Pso(p) => p.name.clone(),
        raw::Design::Optimum(o) => o.name.clone(),
        raw::Design::Plan(p) => p.name.clone(),
    };
    check_name(&format!("design[{i}].name"), &name)?;
    // `design[2] ("pso").particles`
    let prefix = format!("design[{i}] ({name:?}).");
    let source = match d {
        raw::Design::Explicit { attitudes, .. } => explicit(&prefix, &attitudes, raw_box)?,
        raw::Design::Grid { levels, .. } => grid(&prefix, &levels)?,
        raw::Design::Random { m, .. } => DesignSource::Random {
            m: readings(&prefix, m)?,
        },
        raw::Design::Pso(p) => pso(&prefix, &p)?,
        raw::Design::Optimum(o) => optimum(&prefix, &o)?,
        raw::Design::Plan(p) => plan(&prefix, &p)?,
    };
    Ok(DesignSpec { name, source })
}

/// `m`: readings of a design, at least the 9 unknowns of the linear model.
fn readings(prefix: &str, m: usize) -> Result<usize> {
    count(&format!("{prefix}m"), m, 9, limits::MAX_M)
}

/// Attitudes given one by one, each inside the box.
fn explicit(prefix: &str, attitudes: &[raw::Attitude], raw_box: &raw::AttitudeBox) -> Result<DesignSource> {
    let key = |field: &str| format!("{prefix}{field}");
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
    Ok(DesignSource::Explicit(list))
}

/// A full factorial grid of `levels` (roll x yaw x pitch), of 9 to `MAX_M` attitudes.
fn grid(prefix: &str, levels: &raw::Levels) -> Result<DesignSource> {
    let key = |field: &str| format!("{prefix}{field}");
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
    Ok(DesignSource::Grid(l))
}

/// The PSO of \[P1\] Section III, its settings defaulted and checked.
fn pso(prefix: &str, p: &raw::Pso) -> Result<DesignSource> {
    let key = |field: &str| format!("{prefix}{field}");
    let d = Swarm::default();
    let swarm = Swarm {
        particles: count(
            &key("particles"),
            p.particles.unwrap_or(d.particles),
            1,
            limits::MAX_PARTICLES,
        )?,
        iterations: count(
            &key("iterations"),
            p.iterations.unwrap_or(d.iterations),
            1,
            limits::MAX_PSO_ITERATIONS,
        )?,
        w_max: p.w_max.unwrap_or(d.w_max),
        w_min: p.w_min.unwrap_or(d.w_min),
        c1: p.c1.unwrap_or(d.c1),
        c2: p.c2.unwrap_or(d.c2),
        vmax_fraction: p.vmax_fraction.unwrap_or(d.vmax_fraction),
        threshold: p.threshold,
        criterion: p.criterion.map_or(d.criterion, Into::into),
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
            ParameterError::TooSmall { value, .. } | ParameterError::TooLarge { value, .. } => value.to_string(),
            other => other.to_string(),
        };
        keyed(prefix, &e, &value)
    })?;
    Ok(DesignSource::Pso {
        m: readings(prefix, p.m)?,
        swarm,
    })
}

/// The local optimiser of the design criterion from many starts, its settings defaulted and
/// checked.
fn optimum(prefix: &str, o: &raw::Optimum) -> Result<DesignSource> {
    let key = |field: &str| format!("{prefix}{field}");
    let d = Optimum::default();
    let settings = Optimum {
        starts: count(&key("starts"), o.starts.unwrap_or(d.starts), 1, limits::MAX_STARTS)?,
        max_iterations: count(
            &key("max_iterations"),
            o.max_iterations.unwrap_or(d.max_iterations),
            1,
            limits::MAX_OPTIMUM_ITERATIONS,
        )?,
        gradient_tolerance: o.gradient_tolerance.unwrap_or(d.gradient_tolerance),
        memory: d.memory,
        criterion: o.criterion.map_or(d.criterion, Into::into),
    };
    if !(settings.gradient_tolerance.is_finite() && settings.gradient_tolerance > 0.0) {
        bail!(
            "{} = {}: must be positive and finite",
            key("gradient_tolerance"),
            show(settings.gradient_tolerance)
        );
    }
    settings.validate().map_err(|e| keyed(prefix, &e, "the value given"))?;
    Ok(DesignSource::Optimum {
        m: readings(prefix, o.m)?,
        settings,
    })
}

/// A plan of `readings` readings over at most `max_attitudes` held attitudes, each held for at
/// least `min_readings_per_attitude` readings.
fn plan(prefix: &str, p: &raw::Plan) -> Result<DesignSource> {
    let key = |field: &str| format!("{prefix}{field}");
    let readings = count(&key("readings"), p.readings, 9, limits::MAX_M)?;
    let why_nine = "each attitude gives one equation, whatever its readings, and the linear model has 9 unknowns";
    let max_attitudes = match &p.max_attitudes {
        None => Some(DEFAULT_MAX_ATTITUDES),
        Some(toml::Value::String(word)) if word == "all" => None,
        Some(value) => {
            let k = whole(&key("max_attitudes"), value, "a whole number of attitudes or \"all\"")?;
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
    let min_readings = match &p.min_readings_per_attitude {
        None => 1,
        Some(value) => {
            let r = whole(&key("min_readings_per_attitude"), value, "a whole number of readings")?;
            if r < 1 {
                bail!("{} = {r}: must be at least 1", key("min_readings_per_attitude"));
            }
            if r > (readings / 9) as i64 {
                bail!(
                    "{} = {r}: must be at most {} (readings = {readings} over the 9 attitudes a plan needs at least: \
                     {why_nine})",
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
        .map_err(|e| keyed(prefix, &e, "the value given"))?;
    Ok(DesignSource::Plan { readings, limits })
}
