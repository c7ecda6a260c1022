//! The validation of a raw scenario, one function per table: every value usable, every size
//! bounded ([`crate::limits`]), every error naming the key and the value as written.

use std::path::Path;

use anyhow::{Result, bail};
use magcal_core::calibration::step2::Residual;
use magcal_core::design::approximate::Approximate;
use magcal_core::{AttitudeBox, ErrorModel, ParameterError, ReferenceField, TwoStep, wmm};

use super::raw;
use super::values::{check_name, count, finite, keyed, within};
use super::{
    DEFAULT_CHECK_TRIALS, DesignSource, DesignSpec, MIN_CHECK_TRIALS, PsoRunsSpec, SCHEMA, Scenario, check_range,
};
use crate::limits::{self, show};

/// A raw scenario read from `path` (with the SHA-256 `hash` of its bytes), validated.
pub(super) fn validate(raw: raw::Scenario, path: &Path, hash: String) -> Result<Scenario> {
    if raw.schema != SCHEMA {
        bail!("schema = {}: this magcal reads schema {SCHEMA}", raw.schema);
    }
    check_name("name", &raw.name)?;
    count("trials", raw.trials, 1, limits::MAX_TRIALS)?;
    let (sigmas_nt, attitude_sigmas_deg) = noise(&raw.sigma_nt, &raw.attitude_sigma_deg)?;
    let (field, field_source) = reference_field(&raw.field)?;
    let truth = sensor(&raw.sensor)?;
    let bounds = attitude_box(&raw.attitude_box)?;
    let (calibration, check_trials) = calibration(&raw.calibration, &raw.verdict)?;
    let heading_budget_deg = heading_budget(raw.verdict.heading_budget_deg)?;
    let designs = designs(raw.design, &raw.attitude_box)?;
    let pso_runs = pso_runs(raw.pso_runs, &designs)?;
    let certificate = certificate(&raw.certificate)?;
    Ok(Scenario {
        path: path.to_path_buf(),
        hash,
        name: raw.name,
        description: raw.description,
        seed: raw.seed,
        trials: raw.trials,
        check_trials,
        heading_budget_deg,
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
/// `sigma_nt` and `attitude_sigma_deg`: the noise levels (nT) and the execution errors (degrees),
/// each listed once, `-0` written as `0`.
fn noise(sigma_nt: &[f64], attitude_sigma_deg: &[f64]) -> Result<(Vec<f64>, Vec<f64>)> {
    if sigma_nt.is_empty() {
        bail!("sigma_nt = []: give at least one noise level");
    }
    for (i, &s) in sigma_nt.iter().enumerate() {
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
        if sigma_nt[..i].contains(&s) {
            bail!("{key} = {}: listed twice", show(s));
        }
    }
    // -0 and 0 are one level, written as 0.
    let sigmas_nt: Vec<f64> = sigma_nt.iter().map(|&s| if s == 0.0 { 0.0 } else { s }).collect();
    if attitude_sigma_deg.is_empty() {
        bail!("attitude_sigma_deg = []: give at least one level (0 for none)");
    }
    count(
        "attitude_sigma_deg (count)",
        attitude_sigma_deg.len(),
        1,
        limits::MAX_ATTITUDE_SIGMAS,
    )?;
    for (i, &a) in attitude_sigma_deg.iter().enumerate() {
        let key = format!("attitude_sigma_deg[{i}]");
        within(&key, a, 0.0, limits::MAX_ATTITUDE_SIGMA_DEG, " degrees")?;
        if attitude_sigma_deg[..i].contains(&a) {
            bail!("{key} = {}: listed twice", show(a));
        }
    }
    let attitude_sigmas_deg: Vec<f64> = attitude_sigma_deg
        .iter()
        .map(|&a| if a == 0.0 { 0.0 } else { a })
        .collect();
    Ok((sigmas_nt, attitude_sigmas_deg))
}

/// `[sensor]`: the true non-orthogonality, scale factors and bias of the simulated sensor.
fn sensor(s: &raw::Sensor) -> Result<ErrorModel> {
    for (key, values, min, max) in [
        ("sensor.psi_deg", s.psi_deg, -limits::MAX_PSI_DEG, limits::MAX_PSI_DEG),
        ("sensor.scale", s.scale, limits::MIN_SCALE, limits::MAX_SCALE),
        ("sensor.bias_nt", s.bias_nt, -limits::MAX_BIAS_NT, limits::MAX_BIAS_NT),
    ] {
        for (i, v) in values.into_iter().enumerate() {
            within(&format!("{key}[{i}]"), v, min, max, "")?;
        }
    }
    ErrorModel::new(s.psi_deg, s.scale, s.bias_nt).map_err(|e| keyed("sensor.", &e, "the values given"))
}

/// `[attitude_box]`: the ranges of roll, yaw and pitch the vehicle can take (degrees).
fn attitude_box(b: &raw::AttitudeBox) -> Result<AttitudeBox> {
    for (key, range) in [
        ("attitude_box.roll_deg", b.roll_deg),
        ("attitude_box.yaw_deg", b.yaw_deg),
        ("attitude_box.pitch_deg", b.pitch_deg),
    ] {
        if let Err(rule) = check_range(range) {
            bail!("{key} = [{}, {}]: {rule}", show(range[0]), show(range[1]));
        }
    }
    AttitudeBox::from_degrees(b.roll_deg, b.yaw_deg, b.pitch_deg)
        .map_err(|e| keyed("attitude_box.", &e, "the range given"))
}

/// `[calibration]` and `[verdict]`: the estimator of the trials, and the trials of each design's
/// verdict.
fn calibration(c: &raw::Calibration, verdict: &raw::Verdict) -> Result<(TwoStep, usize)> {
    let mut calibration = TwoStep::default();
    if let Some(n) = c.max_iterations {
        calibration.max_iterations = count("calibration.max_iterations", n, 1, limits::MAX_STEP2_ITERATIONS)?;
    }
    let check_trials = match verdict.trials {
        Some(n) => count("verdict.trials", n, MIN_CHECK_TRIALS, limits::MAX_TRIALS)?,
        None => DEFAULT_CHECK_TRIALS,
    };
    calibration.residual = match c.residual.as_deref() {
        None | Some("readings") => Residual::Readings,
        Some("paper") => Residual::Paper,
        Some(other) => bail!(
            "calibration.residual = {:?}: expected \"readings\" (the default: distances in the readings' units) \
             or \"paper\" ([P1]'s residual after the correction)",
            limits::excerpt(other, 40)
        ),
    };
    Ok((calibration, check_trials))
}

/// `[verdict] heading_budget_deg`: above 0 and below 180 degrees.
pub fn heading_budget(value: Option<f64>) -> Result<f64> {
    match value {
        None => Ok(magcal_core::budget::DEFAULT_BUDGET_DEG),
        Some(v) if (magcal_core::budget::MIN_BUDGET_DEG..180.0).contains(&v) => Ok(v),
        Some(v) => bail!(
            "verdict.heading_budget_deg = {}: a heading error of at least {} and below 180 degrees",
            limits::show(v),
            magcal_core::budget::MIN_BUDGET_DEG
        ),
    }
}

/// `[[design]]`: at least one, each with its own name.
fn designs(raw: Vec<raw::Design>, raw_box: &raw::AttitudeBox) -> Result<Vec<DesignSpec>> {
    if raw.is_empty() {
        bail!("no [[design]]: give at least one design");
    }
    count("[[design]] (count)", raw.len(), 1, limits::MAX_DESIGNS)?;
    let mut designs: Vec<DesignSpec> = Vec::with_capacity(raw.len());
    for (i, d) in raw.into_iter().enumerate() {
        let spec = super::design::design(i, d, raw_box)?;
        if designs.iter().any(|other| other.name == spec.name) {
            bail!("design[{i}].name = {:?}: another design has this name", spec.name);
        }
        designs.push(spec);
    }
    Ok(designs)
}

/// `[pso_runs]`: repeated runs of one of the PSO designs (\[P1\] Fig. 4).
fn pso_runs(raw: Option<raw::PsoRuns>, designs: &[DesignSpec]) -> Result<Option<PsoRunsSpec>> {
    Ok(match raw {
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
    })
}

/// `[certificate]`: the settings of the approximate design that certifies the others.
fn certificate(c: &raw::Certificate) -> Result<Approximate> {
    let d = Approximate::default();
    Ok(Approximate {
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
            (field, crate::scenario::site::wmm_place(model, &site))
        }
    };
    let field = field
        .with_yaw_offset_deg(f.yaw_offset_deg)
        .map_err(|e| keyed("field.", &e, &show(f.yaw_offset_deg)))?;
    Ok((field, source))
}
