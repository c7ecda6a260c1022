//! `calibrate --fit vector`: the whole `K` and the bias against the log's reference attitudes
//! (docs/conventions.md "Vector calibration"), recorded as \[P1\]'s `P` and bias plus the
//! alignment `A` (`K^-1 = A P`).

use std::io::Write;

use anyhow::{Context, Result, bail};
use magcal_core::aviation::z_up_of_ned;
use magcal_core::log_fit::{
    ELLIPSOID_LIMIT_PERCENT, EllipsoidTest, FoldFit, HeldOut, LogFit, Noise, Order, StdSource, assemble_held_out,
    cut_folds, widen_std,
};
use magcal_core::reference::percentile;
use magcal_core::small::{Mat3, Vec3, mat_vec, norm};
use magcal_core::vector::{
    Manoeuvre, ReferenceField, VectorError, VectorFit, VectorModel, fit_track, fit_vector_in, headings_never_flown,
    lack_of_fit, next_manoeuvres,
};
use magcal_logs::text::significant;

use super::CalibrateArgs;
use crate::log::calibration::{AlignmentJson, CalibrationJson, HeadingFiguresJson, MotorJson};
use crate::log::flight::{Fix, Series};
use crate::log::gps;
use crate::log::source::Log;
use crate::log::vehicle::Place;
use crate::scenario::site::{Units, wmm_field, wmm_label, wmm_pick};

/// Refuses a reduced model or `--motor` without a given field, and a reduced model on readings in a
/// sensor frame turned from the body's.
fn check_model(args: &CalibrateArgs, log: &Log, place: Option<&Place>, model: VectorModel) -> Result<()> {
    let shown = args.log.display();
    let reduced = model != VectorModel::Full;
    if !(reduced || args.motor.is_some()) {
        return Ok(());
    }
    if place.is_none() {
        bail!(
            "{shown}: --fit {}{} needs the field given: --site and --date, a flight log with GPS fixes, or a CSV's --position with --utc or --date",
            args.fit.name(),
            if args.motor.is_some() { " with --motor" } else { "" }
        );
    }
    if reduced
        && let Some(r) = log.origin.to_body
        && (0..3).any(|i| (0..3).any(|j| (r[i][j] - f64::from(u8::from(i == j))).abs() > 1e-12))
    {
        bail!(
            "{shown}: --fit {} takes the readings as the field along the body's axes, and this log's readings are in a sensor frame turned from the body's: use --fit vector (the full matrix, which holds the turn)",
            args.fit.name()
        );
    }
    Ok(())
}

/// The readings that have an attitude, with their attitudes (body to z up), times and motor
/// inputs.
struct With {
    readings: Vec<Vec3>,
    attitudes: Vec<Mat3>,
    times: Vec<f64>,
    inputs: Option<Vec<f64>>,
}

/// The readings of `log` that have an attitude, and what goes with them.
///
/// # Errors
/// A log without attitudes; `--motor` and a reading without its input.
fn with_attitude(args: &CalibrateArgs, log: &Log) -> Result<With> {
    let inputs_all = args.motor.map(|m| super::motor::inputs(log, m)).transpose()?;
    let Some(logged) = &log.attitudes else {
        bail!(
            "{}: --fit vector needs a reference attitude per reading: name the log's attitude columns with --quaternion or --euler (and --attitude-frame)",
            args.log.display()
        );
    };
    // Sized once: the copies cost 104 bytes per reading, within the held reading's budget.
    let with = logged.iter().filter(|c| c.is_some()).count();
    let mut w = With {
        readings: Vec::with_capacity(with),
        attitudes: Vec::with_capacity(with),
        times: Vec::with_capacity(if log.times.is_some() { with } else { 0 }),
        inputs: inputs_all.as_ref().map(|_| Vec::with_capacity(with)),
    };
    for (i, (r, c)) in log.readings.iter().zip(logged).enumerate() {
        if let Some(c) = c {
            w.readings.push(*r);
            w.attitudes.push(z_up_of_ned(c));
            if let Some(t) = &log.times {
                w.times.push(t[i]);
            }
            if let (Some(u), Some(all)) = (w.inputs.as_mut(), &inputs_all) {
                u.push(all[i]);
            }
        }
    }
    Ok(w)
}

/// The WMM field (east, north, up) at the site and date of `place`, in the log's units (or scaled
/// to `--magnitude`), and where it comes from in words.
fn site_field(args: &CalibrateArgs, place: &Place, units: Option<Units>) -> Result<(Vec3, String)> {
    let (ned, label) = wmm_field(&place.site, place.date, place.model)?;
    let enu = [ned[1], ned[0], -ned[2]];
    let (f, unit) = match (units, args.magnitude) {
        (_, Some(r)) => (enu.map(|v| v * r / norm(enu)), format!("scaled to --magnitude {r}")),
        (Some(u), None) => (enu.map(|v| v / u.nt()), "in the log's units".to_string()),
        (None, None) => bail!(
            "--fit {} with --site: give --units (the log's) or --magnitude",
            args.fit.name()
        ),
    };
    Ok((
        f,
        format!("given: {label} (east, north, up; {unit}); the attitudes' frame must be geographic"),
    ))
}

/// The WMM field (east, north, up) at each of `times` along the used fixes of `gps`, on the date
/// and by the model of `place`, in the log's units (or scaled so that their mean has the length
/// `--magnitude`), and where it comes from in words.
fn track_fields(
    args: &CalibrateArgs,
    place: &Place,
    gps: &Series<Fix>,
    message: &str,
    times: &[f64],
    units: Option<Units>,
) -> Result<(Vec<Vec3>, String)> {
    let (first, model, at) = wmm_pick(&place.site, place.date, place.model)?;
    let label = wmm_label(first, model, &at);
    let t = gps::track(gps, times, place.date.year, model).with_context(|| args.log.display().to_string())?;
    let n = t.enu_nt.len().max(1) as f64;
    let mean: Vec3 = std::array::from_fn(|k| t.enu_nt.iter().map(|v| v[k]).sum::<f64>() / n);
    let (factor, unit) = match (units, args.magnitude) {
        (_, Some(r)) => (r / norm(mean), format!("scaled to --magnitude {r} on average")),
        (Some(u), None) => (1.0 / u.nt(), "in the log's units".to_string()),
        (None, None) => bail!("--fit vector along a GPS track: give --units (the log's) or --magnitude"),
    };
    let fields = t.enu_nt.iter().map(|v| v.map(|x| x * factor)).collect();
    let words = format!(
        "given along the track: {} at each of {} fixes of type 3 (3D) or better ({message}; {:.1} km of track), linear in time between them, {:.1} to {:.1} nT, turning by up to {:.3} deg (east, north, up; {unit}); the first: {label}",
        model.name(),
        t.fixes,
        t.length_m / 1000.0,
        t.magnitude_nt.0,
        t.magnitude_nt.1,
        t.turn_deg
    );
    Ok((fields, words))
}

/// A vector calibration of a log and what it was fitted to.
pub struct Vector {
    pub fit: VectorFit,
    /// The readings with an attitude, and their attitudes (body to z up).
    readings: Vec<Vec3>,
    attitudes: Vec<Mat3>,
    field_source: String,
    /// Whether `--magnitude` gave the field magnitude (else the scalar fit's, or the WMM's).
    magnitude_given: bool,
    /// `--fit`'s name.
    fit_name: &'static str,
    /// The motor's input (`current` or `throttle`) and its range, where fitted.
    motor: Option<(&'static str, [f64; 2])>,
    /// A fit against a field given per reading ([`fit_track`]): how well it points the compass,
    /// and the manoeuvres that would improve it.
    track: Option<TrackVerdict>,
    /// The fit made again without each fold of the readings (docs/conventions.md "Held out");
    /// `None` for a log too small to hold a fold out.
    held_out: Option<HeldOut>,
}

pub use crate::log::flown::{MAX_HEADING_STD_DEG, never_flown_words};

/// How well a track fit points the compass, and what to fly next.
pub struct TrackVerdict {
    /// The bias's largest standard error, the log's units.
    bias_std_max: f64,
    /// The horizontal field (the mean over the readings), the log's units.
    horizontal: f64,
    /// `atan(bias_std_max / horizontal)`, degrees.
    heading_std_deg: f64,
    /// What to fly next, where the heading is not good enough.
    advice: Advice,
    /// A reduced model against the full matrix: `(F, degrees of freedom, p-value)`.
    lack_of_fit: Option<(f64, (usize, usize), f64)>,
}

/// The verdict of a track fit: a reduced model against the full matrix, and, where its heading
/// is not good enough, the manoeuvres that would improve it.
fn track_verdict(
    fit: &VectorFit,
    readings: &[Vec3],
    attitudes: &[Mat3],
    fields: &[Vec3],
    inputs: Option<&[f64]>,
    model: VectorModel,
    order: magcal_core::log_fit::Order,
) -> Option<TrackVerdict> {
    let std = fit.std_error.as_ref()?;
    let bias_std_max = std.bias.iter().copied().fold(0.0, f64::max);
    let horizontal = fit.field[0].hypot(fit.field[1]);
    let heading_std_deg = (bias_std_max / horizontal).atan().to_degrees();
    let advice = if heading_std_deg > MAX_HEADING_STD_DEG {
        Advice::of(readings, attitudes, fields, inputs, model, fit.noise?, fit.k)
    } else {
        Advice::default()
    };
    let lack_of_fit = (model != VectorModel::Full)
        .then(|| fit_track(readings, attitudes, fields, inputs, VectorModel::Full, order).ok())
        .flatten()
        .and_then(|full| lack_of_fit(fit, &full));
    Some(TrackVerdict {
        bias_std_max,
        horizontal,
        heading_std_deg,
        advice,
        lack_of_fit,
    })
}

/// The share of the readings below which a heading sector counts as never flown.
const NEVER_FLOWN_SHARE: f64 = 0.01;

/// What a flight that does not point the compass well enough should fly next: the manoeuvres of
/// largest gain in the information of the vector model ([`next_manoeuvres`]) and the headings it
/// never flew.
#[derive(Default)]
pub struct Advice {
    next: Vec<Manoeuvre>,
    never_flown: Vec<[f64; 2]>,
}

impl Advice {
    /// The advice for a track fit of `readings` under `model` at the noise `noise` about the
    /// sensor `k` (see [`next_manoeuvres`]).
    fn of(
        readings: &[Vec3],
        attitudes: &[Mat3],
        fields: &[Vec3],
        inputs: Option<&[f64]>,
        model: VectorModel,
        noise: f64,
        k: Mat3,
    ) -> Self {
        Self {
            next: next_manoeuvres(readings, attitudes, fields, inputs, model, noise, k, 3).unwrap_or_default(),
            never_flown: headings_never_flown(attitudes, NEVER_FLOWN_SHARE),
        }
    }

    /// The first manoeuvre, in words, for a reason.
    fn first(&self) -> Option<String> {
        self.next
            .first()
            .map(|m| format!("fly {} ({} readings): see next manoeuvres", m.words, m.readings))
    }

    /// Records the advice in `json`.
    pub fn record(&self, json: &mut CalibrationJson) {
        json.next_manoeuvres = self
            .next
            .iter()
            .map(|m| {
                format!(
                    "{} ({} readings): bias standard errors {} (white noise; {})",
                    m.words,
                    m.readings,
                    m.bias_std
                        .map_or("unknown".to_string(), |b| b.map(|x| significant(x, 3)).join(", ")),
                    if m.identifiable {
                        "identifiable"
                    } else {
                        "still not identifiable"
                    }
                )
            })
            .collect();
        json.headings_never_flown.clone_from(&self.never_flown);
    }
}

/// With `--fit vector`, the vector fit of `log` ([`fit`]) and `scalar` replaced by it
/// ([`Vector::as_log_fit`]); else `scalar` as it is.
///
/// # Errors
/// As [`fit`].
pub fn instead(
    args: &CalibrateArgs,
    log: &Log,
    scalar: LogFit,
    units: Option<Units>,
    place: Option<&Place>,
    along: bool,
) -> Result<(LogFit, Option<Vector>, Option<Advice>)> {
    if args.fit.vector_model().is_none() {
        return Ok((scalar, None, None));
    }
    match fit(args, log, &scalar, units, place, along) {
        Ok(v) => Ok((v.as_log_fit(&scalar, log), Some(v), None)),
        // What the readings and attitudes do not determine is the log's, not bad input: the
        // scalar fit is reported, not usable, with the reason (exit 3).
        Err(e)
            if matches!(
                e.downcast_ref::<VectorError>(),
                Some(
                    VectorError::TooFewReadings { .. }
                        | VectorError::NotDetermined { .. }
                        | VectorError::NotConverged { .. }
                )
            ) =>
        {
            // Against a given field the information does not depend on the estimate: what to
            // fly next is known though nothing is fitted (about the nominal sensor, at the
            // scalar fit's noise).
            let advice = scalar.noise.value().and_then(|noise| {
                let p = prepare(args, log, units, place, along).ok()?;
                let (fields, _) = p.given?;
                let w = &p.with;
                let unit = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
                Some(Advice::of(
                    &w.readings,
                    &w.attitudes,
                    &fields,
                    w.inputs.as_deref(),
                    p.model,
                    noise,
                    unit,
                ))
            });
            let mut f = scalar;
            f.usable = false;
            f.identifiable = false;
            f.reasons.insert(
                0,
                format!(
                    "no vector calibration: {e:#}; the estimates shown are the scalar full fit's{}",
                    advice
                        .as_ref()
                        .and_then(Advice::first)
                        .map_or(String::new(), |m| format!("; {m}"))
                ),
            );
            Ok((f, None, advice))
        }
        Err(e) => Err(e),
    }
}

/// What a vector fit of a log fits: the model of `--fit`, the readings with an attitude, their
/// order, and the field given per reading (along the GPS track where `along`, else at the
/// place's site where the model needs a given field) with its words.
struct Prepared {
    model: VectorModel,
    with: With,
    order: magcal_core::log_fit::Order,
    given: Option<(Vec<Vec3>, String)>,
}

/// The [`Prepared`] fit of `log`.
///
/// # Errors
/// As [`fit`]'s checks of the log and flags.
fn prepare(
    args: &CalibrateArgs,
    log: &Log,
    units: Option<Units>,
    place: Option<&Place>,
    along: bool,
) -> Result<Prepared> {
    let model = args.fit.vector_model().unwrap_or(VectorModel::Full);
    let reduced = model != VectorModel::Full;
    check_model(args, log, place, model)?;
    let with = with_attitude(args, log)?;
    let order = if log.times.is_some() {
        magcal_core::log_fit::Order::Time
    } else {
        magcal_core::log_fit::Order::Unknown
    };
    let track = if along && log.times.is_some() {
        log.gps.as_ref()
    } else {
        None
    };
    let given = match (place, track) {
        (Some(p), Some((gps, message))) => Some(track_fields(args, p, gps, message, &with.times, units)?),
        (Some(p), None) if reduced || with.inputs.is_some() => {
            let (f, words) = site_field(args, p, units)?;
            Some((vec![f; with.readings.len()], words))
        }
        _ => None,
    };
    Ok(Prepared {
        model,
        with,
        order,
        given,
    })
}

/// The vector fit of `log` under the model of `--fit`, with the motor's interference where
/// `--motor` asks for it: against the WMM field along the log's GPS track where `along` (the
/// place came from the log's fixes), else at the site and date of `place` (in the log's units, or
/// scaled to `--magnitude`), else (the full model without `--motor` only) with `F` fitted at the
/// scalar fit's magnitude.
///
/// # Errors
/// A log without attitudes, a reduced model or `--motor` without a given field, a reduced model
/// on readings in a sensor frame the body's is turned from, a motor input missing, or a fit the
/// core refuses (too few readings with an attitude, attitudes that do not determine it, a
/// left-handed frame).
pub fn fit(
    args: &CalibrateArgs,
    log: &Log,
    scalar: &LogFit,
    units: Option<Units>,
    place: Option<&Place>,
    along: bool,
) -> Result<Vector> {
    let shown = args.log.display();
    let Prepared {
        model,
        with: With {
            readings,
            attitudes,
            inputs,
            ..
        },
        order,
        given,
    } = prepare(args, log, units, place, along)?;
    let motor = args.motor.zip(inputs.as_ref()).map(|(m, u)| {
        let lo = u.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = u.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (super::motor::name(m), [lo, hi])
    });
    let what = || {
        format!(
            "{shown}: --fit {} ({} of {} readings with an attitude)",
            args.fit.name(),
            readings.len(),
            log.readings.len()
        )
    };
    if let Some((fields, field_source)) = given {
        let fit = fit_track(&readings, &attitudes, &fields, inputs.as_deref(), model, order).with_context(what)?;
        let track = track_verdict(&fit, &readings, &attitudes, &fields, inputs.as_deref(), model, order);
        let track_data = (&readings[..], &attitudes[..], &fields[..], inputs.as_deref());
        let held_out = held_out_of_track(&fit, track_data, model, order, args.seed);
        return Ok(Vector {
            held_out,
            fit,
            readings,
            attitudes,
            field_source,
            magnitude_given: args.magnitude.is_some(),
            fit_name: args.fit.name(),
            motor,
            track,
        });
    }
    let (field, field_source) = match place {
        Some(p) => {
            let (f, words) = site_field(args, p, units)?;
            (ReferenceField::Given(f), words)
        }
        None => (
            ReferenceField::Fitted {
                magnitude: scalar.magnitude,
            },
            format!(
                "fitted; its magnitude fixed to {} (the scalar fit's magnitude, which K shares with F), its direction in the attitudes' frame",
                significant(scalar.magnitude, 7)
            ),
        ),
    };
    let fit = fit_vector_in(&readings, &attitudes, field, order).with_context(what)?;
    let held_out = held_out_of_field(&fit, &readings, &attitudes, field, order, args.seed);
    Ok(Vector {
        held_out,
        fit,
        readings,
        attitudes,
        field_source,
        magnitude_given: args.magnitude.is_some(),
        fit_name: args.fit.name(),
        motor: None,
        track: None,
    })
}

/// What a track fit is made of: the readings, their attitudes, the field at each, and the motor's
/// input where fitted.
type TrackData<'a> = (&'a [Vec3], &'a [Mat3], &'a [Vec3], Option<&'a [f64]>);

/// The held-out evidence of a fit against the field given per reading ([`fit_track`]).
fn held_out_of_track(
    fit: &VectorFit,
    (readings, attitudes, fields, inputs): TrackData<'_>,
    model: VectorModel,
    order: Order,
    seed: u64,
) -> Option<HeldOut> {
    held_out(
        fit,
        readings,
        |i| norm(fields[i]),
        order,
        seed,
        |keep| {
            let pick = |v: &[Vec3]| keep.iter().map(|&i| v[i]).collect::<Vec<_>>();
            let inputs: Option<Vec<f64>> = inputs.map(|u| keep.iter().map(|&i| u[i]).collect());
            let attitudes: Vec<Mat3> = keep.iter().map(|&i| attitudes[i]).collect();
            fit_track(
                &pick(readings),
                &attitudes,
                &pick(fields),
                inputs.as_deref(),
                model,
                order,
            )
            .ok()
        },
    )
}

/// The held-out evidence of a fit against one field, given or fitted ([`fit_vector_in`]).
fn held_out_of_field(
    fit: &VectorFit,
    readings: &[Vec3],
    attitudes: &[Mat3],
    field: ReferenceField,
    order: Order,
    seed: u64,
) -> Option<HeldOut> {
    let magnitude = norm(fit.field);
    held_out(
        fit,
        readings,
        |_| magnitude,
        order,
        seed,
        |keep| {
            let readings: Vec<Vec3> = keep.iter().map(|&i| readings[i]).collect();
            let attitudes: Vec<Mat3> = keep.iter().map(|&i| attitudes[i]).collect();
            fit_vector_in(&readings, &attitudes, field, order).ok()
        },
    )
}

/// The held-out evidence of the vector fit `fit` of `readings` (docs/conventions.md "Held out"):
/// `refit` fits the readings of the indices it is given; `magnitude(i)` is the field's at reading
/// `i`. `None` for a log too small to hold a fold out or a fit without standard errors.
fn held_out(
    fit: &VectorFit,
    readings: &[Vec3],
    magnitude: impl Fn(usize) -> f64 + Sync,
    order: Order,
    seed: u64,
    refit: impl Fn(&[usize]) -> Option<VectorFit> + Sync,
) -> Option<HeldOut> {
    use rayon::prelude::*;
    let m = readings.len();
    // K and the bias: twelve unknowns, and at least twice as many readings kept.
    if m - m.div_ceil(magcal_core::log_fit::HELD_OUT_FOLDS) < 24 {
        return None;
    }
    let nine = |p: Vec3, s: Vec3, o: Vec3| [p[0], p[1], p[2], s[0], s[1], s[2], o[0], o[1], o[2]];
    let std = fit.std_error.as_ref()?;
    let std = nine(std.psi_deg, std.scale, std.bias);
    let (kind, cuts) = cut_folds(m, order, seed);
    let fits: Vec<Vec<Option<FoldFit>>> = cuts
        .iter()
        .map(|folds| {
            folds
                .par_iter()
                .map(|fold| {
                    let mut keep = vec![true; m];
                    fold.iter().for_each(|&i| keep[i] = false);
                    let kept: Vec<usize> = (0..m).filter(|&i| keep[i]).collect();
                    let g = refit(&kept).filter(|g| g.identifiable && g.std_error.is_some())?;
                    let e = g.error_model();
                    let held = fold
                        .iter()
                        .map(|&i| (norm(g.apply(readings[i])) - magnitude(i)).powi(2))
                        .sum();
                    Some((nine(e.psi_deg(), e.scale(), e.bias_nt()), held))
                })
                .collect()
        })
        .collect();
    let whole_rms = ((0..m)
        .map(|i| (norm(fit.apply(readings[i])) - magnitude(i)).powi(2))
        .sum::<f64>()
        / m as f64)
        .sqrt();
    Some(assemble_held_out(
        kind,
        &cuts,
        &fits,
        &std,
        fit.model != VectorModel::Full,
        whole_rms,
    ))
}

impl Vector {
    /// `f`'s standard errors widened by the held-out fits where they spread further, each named
    /// by what it rests on.
    fn widen_by_held_out(&self, f: &mut LogFit) {
        let v = &self.fit;
        f.held_out = self.held_out.clone();
        let own = if v.serial.is_some() {
            StdSource::LongRun
        } else {
            StdSource::White
        };
        f.std_source = [[own; 3]; 3];
        let fixed = v.model != VectorModel::Full;
        if fixed {
            f.std_source[0] = [StdSource::Fixed; 3];
        }
        let Some(h) = &self.held_out else { return };
        let raised = widen_std([&mut f.std_psi_deg, &mut f.std_scale, &mut f.std_bias], fixed, h);
        for (g, row) in raised.iter().enumerate() {
            for (i, r) in row.iter().enumerate() {
                if *r {
                    f.std_source[g][i] = StdSource::HeldOut;
                }
            }
        }
    }

    /// Why a track fit is not usable beyond what a vector fit's verdict says: a reduced model the
    /// log rejects against the full matrix, a bias that leaves more than
    /// [`MAX_HEADING_STD_DEG`] of heading.
    fn track_reasons(&self) -> Vec<String> {
        let mut reasons = Vec::new();
        if let Some((fv, dof, p)) = self.track.as_ref().and_then(|t| t.lack_of_fit)
            && p < magcal_core::log_fit::LACK_OF_FIT_LEVEL
        {
            reasons.push(format!(
                "the log rejects the {} model: lack-of-fit F = {} on ({}, {}) degrees of freedom against the full matrix, p {} (below {}): fit {}",
                self.fit_name,
                significant(fv, 4),
                dof.0,
                dof.1,
                magcal_core::log_fit::show_p(p),
                magcal_core::log_fit::LACK_OF_FIT_LEVEL,
                if self.fit_name == "vector-offsets" {
                    "--fit vector-diagonal or --fit vector"
                } else {
                    "--fit vector"
                }
            ));
        }
        if let Some(t) = &self.track
            && t.heading_std_deg > MAX_HEADING_STD_DEG
        {
            reasons.push(format!(
                "the bias is determined to {} only (its largest standard error), {} of the horizontal field: a heading error of about {} degrees (at most {MAX_HEADING_STD_DEG} for a usable compass){}",
                significant(t.bias_std_max, 3),
                significant(t.bias_std_max / t.horizontal, 3),
                significant(t.heading_std_deg, 3),
                t.advice.first().map_or(String::new(), |m| format!("; {m}"))
            ));
        }
        reasons
    }
    /// `scalar` with \[P1\]'s `P`, bias, `psi`, `S`, their standard errors, the noise and the
    /// verdict of the vector fit; the residuals `|P (raw - bias)| - R` over every reading.
    pub fn as_log_fit(&self, scalar: &LogFit, log: &Log) -> LogFit {
        let v = &self.fit;
        let radii: Vec<f64> = log
            .readings
            .iter()
            .map(|r| norm(mat_vec(&v.p, magcal_core::small::sub(*r, v.bias))) - scalar.magnitude)
            .collect();
        let noise = match (v.noise, v.noise_interval95) {
            (Some(value), Some(interval95)) => Noise::Estimated {
                value,
                dof: v.dof,
                interval95,
            },
            _ => Noise::Unknown,
        };
        let std = v.std_error.as_ref();
        let mut f = LogFit {
            p: v.p,
            bias: v.bias,
            errors: v.error_model(),
            residual_rms: (radii.iter().map(|x| x * x).sum::<f64>() / radii.len() as f64).sqrt(),
            residual_max: radii.iter().fold(0.0_f64, |a, x| a.max(x.abs())),
            noise,
            std_psi_deg: std.map(|s| s.psi_deg),
            std_scale: std.map(|s| s.scale),
            std_bias: std.map(|s| s.bias),
            quantile95: v.quantile95,
            identifiable: v.identifiable,
            verdict: v.verdict.clone(),
            iterations: v.iterations,
            lack_of_fit: None,
            // The vector fit's own statistics: the scalar fit's check, profile and white
            // standard errors are not its.
            serial: v.serial,
            white_std: None,
            profile: None,
            check: None,
            ..scalar.clone()
        };
        f.reasons.clear();
        self.widen_by_held_out(&mut f);
        if !v.identifiable {
            f.reasons.push(format!("not identifiable: {}", v.verdict));
        }
        match &self.held_out {
            Some(h) if !h.evidence() => f.reasons.push(format!("no held-out evidence: {}", h.words())),
            None => f.reasons.push(
                "no held-out evidence: too few readings with an attitude to hold a fold out (each fit without one needs twice the twelve unknowns)"
                    .to_string(),
            ),
            Some(_) => {}
        }
        f.reasons.extend(self.track_reasons());
        // The magnitude that K shares with a fitted F comes from the scalar fit: only a scalar
        // fit that determines it may give it.
        if v.field_fitted && !self.magnitude_given && !scalar.identifiable {
            f.reasons.push(format!(
                "the field magnitude is not determined: the scalar fit it comes from is not identifiable ({}); give --magnitude, or --site and --date",
                scalar.verdict
            ));
        }
        // The readings must lie near the vector calibration's own sphere, as a scalar fit's must
        // lie near its ellipsoid.
        let percent = 100.0 * f.residual_rms / scalar.magnitude;
        let within = percent <= ELLIPSOID_LIMIT_PERCENT;
        f.ellipsoid = EllipsoidTest {
            residual_percent: percent,
            chi_square_p: None,
            passed: within,
            words: format!(
                "the vector calibration's residual rms {} % of the magnitude (limit {ELLIPSOID_LIMIT_PERCENT} %)",
                significant(percent, 4)
            ),
        };
        if !within {
            f.reasons.push(format!("not an ellipsoid: {}", f.ellipsoid.words));
        }
        if let Some(why) = implausible(&v.error_model()) {
            f.reasons.push(why);
        }
        f.usable = f.reasons.is_empty();
        f
    }

    /// Records the alignment in `json`, and the fit's name.
    pub fn record(&self, json: &mut CalibrationJson) {
        let v = &self.fit;
        let std = v.std_error.as_ref();
        json.fit = self.fit_name.to_string();
        if let Some(t) = &self.track {
            json.heading_std_deg = Some(t.heading_std_deg);
            t.advice.record(json);
        }
        if let (Some(d), Some(input)) = (v.motor, self.motor) {
            json.motor = Some(MotorJson {
                input: input.0.to_string(),
                per_unit: d,
                std_error: v.std_motor,
                input_range: input.1,
            });
        }
        // The scalar fit's magnitude, but the vector fit's own scale factors: their product is
        // not 1 in general, and the source must not say it is.
        let product: f64 = v.error_model().scale().iter().product();
        json.magnitude_source = format!(
            "{}; the vector fit's scale factors are relative to it, product {}",
            json.magnitude_source.replace(", product 1", ""),
            significant(product, 5)
        );
        json.alignment = Some(AlignmentJson {
            rotation: v.alignment,
            angle_deg: v.alignment_angle_deg(),
            axis: v.alignment_axis(),
            whole_step: v.whole_step(),
            misalignment_deg: v.misalignment_deg(),
            misalignment_axis: v.misalignment_axis(),
            std_misalignment_deg: std.map(|s| s.misalignment_deg),
            std_misalignment_vector_deg: std.map(|s| s.rotation_vector_deg),
            k_full: v.k,
            std_k_full: std.map(|s| s.k),
            field: v.field,
            std_field: std.map(|s| s.field),
            field_source: self.field_source.clone(),
            readings: self.readings.len(),
            residual_rms: v.rms_residual,
            dof: v.dof,
            iterations: v.iterations,
            heading_held: self.heading_held(),
        });
    }

    /// The heading and direction errors of `A P (raw - bias)` against the attitudes, with the
    /// alignment held and `F` the fit's; `None` where `F` has no horizontal part.
    fn heading_held(&self) -> Option<HeadingFiguresJson> {
        let f = self.fit.field;
        if f[0].hypot(f[1]) <= 1e-9 * norm(f) {
            return None;
        }
        let (mut heading, mut direction) = (Vec::new(), Vec::new());
        for (r, c) in self.readings.iter().zip(&self.attitudes) {
            let v = mat_vec(c, self.fit.apply(*r));
            let cross = f[0] * v[1] - f[1] * v[0];
            heading.push(cross.atan2(f[0] * v[0] + f[1] * v[1]).to_degrees());
            let dot = magcal_core::small::dot(f, v);
            let c3 = [
                f[1] * v[2] - f[2] * v[1],
                f[2] * v[0] - f[0] * v[2],
                f[0] * v[1] - f[1] * v[0],
            ];
            direction.push(norm(c3).atan2(dot).to_degrees());
        }
        let rms = |x: &[f64]| (x.iter().map(|e| e * e).sum::<f64>() / x.len() as f64).sqrt();
        let abs: Vec<f64> = heading.iter().map(|e| e.abs()).collect();
        Some(HeadingFiguresJson {
            heading_rms_deg: rms(&heading),
            heading_p95_deg: percentile(&abs, 95.0),
            heading_max_deg: abs.iter().fold(0.0, |a: f64, e| a.max(*e)),
            direction_rms_deg: rms(&direction),
        })
    }
}

/// A whole step in words: the body axes the sensor's x, y and z (\[P1\]'s frame) lie along.
fn step_words(s: &Mat3) -> String {
    let names = ["forward", "right", "down"];
    let along = |j: usize| {
        (0..3).find(|&i| s[i][j].abs() > 0.5).map_or("?".to_string(), |i| {
            format!("{}{}", if s[i][j] < 0.0 { "-" } else { "" }, names[i])
        })
    };
    format!("(sensor x, y, z along body {}, {}, {})", along(0), along(1), along(2))
}

/// The alignment's lines of the table.
pub fn print(w: &mut dyn Write, a: &AlignmentJson) -> std::io::Result<()> {
    let se = |x: Option<f64>| x.map_or("unknown".to_string(), |v| significant(v, 3));
    let axis = |v: [f64; 3]| v.map(|x| significant(x, 4)).join(", ");
    writeln!(
        w,
        "alignment A (body = A P (raw - bias), body forward, right, down): {} deg about ({})",
        significant(a.angle_deg, 4),
        axis(a.axis)
    )?;
    writeln!(
        w,
        "  misalignment beyond the nearest whole step {}: {} deg (std error {}) about ({})",
        step_words(&a.whole_step),
        significant(a.misalignment_deg, 4),
        se(a.std_misalignment_deg),
        axis(a.misalignment_axis)
    )?;
    writeln!(
        w,
        "  F ({}, {}, {}), {}",
        significant(a.field[0], 6),
        significant(a.field[1], 6),
        significant(a.field[2], 6),
        a.field_source
    )?;
    writeln!(
        w,
        "  {} readings with an attitude; residual rms per component {} ({} degrees of freedom)",
        a.readings,
        significant(a.residual_rms, 4),
        a.dof
    )?;
    if let Some(h) = &a.heading_held {
        writeln!(
            w,
            "  heading with the alignment held: rms {:.3}, p95 {:.3}, max {:.3} deg; direction rms {:.3} deg",
            h.heading_rms_deg, h.heading_p95_deg, h.heading_max_deg, h.direction_rms_deg
        )?;
    }
    Ok(())
}

/// Largest non-orthogonality and scale factors outside which a sensor is not believed: a
/// magnetometer's axes are within a few degrees of orthogonal, and its scale factors within a
/// factor of two of the field's (a wrong magnitude shows here first).
const PLAUSIBLE_PSI_DEG: f64 = 10.0;
const PLAUSIBLE_SCALE: [f64; 2] = [0.5, 2.0];

/// Why the sensor a vector fit gives is not a believable magnetometer, if it is not.
pub fn implausible(e: &magcal_core::ErrorModel) -> Option<String> {
    let (psi, scale) = (e.psi_deg(), e.scale());
    let bad_psi = psi.iter().any(|p| p.abs() > PLAUSIBLE_PSI_DEG);
    let bad_scale = scale
        .iter()
        .any(|s| !(PLAUSIBLE_SCALE[0]..=PLAUSIBLE_SCALE[1]).contains(s));
    (bad_psi || bad_scale).then(|| {
        format!(
            "not a believable sensor: psi ({:.2}, {:.2}, {:.2}) deg, scale factors ({:.4}, {:.4}, {:.4}) (at most {PLAUSIBLE_PSI_DEG} deg and {} to {}): a wrong field magnitude or attitudes that are not the readings'",
            psi[0], psi[1], psi[2], scale[0], scale[1], scale[2], PLAUSIBLE_SCALE[0], PLAUSIBLE_SCALE[1]
        )
    })
}

#[cfg(test)]
mod tests {
    use super::never_flown_words;

    #[test]
    fn headings_never_flown_read_as_a_pilot_reads_them() {
        assert_eq!(
            never_flown_words(&[[120.0, 300.0], [330.0, 450.0], [30.0, 360.0]]),
            "120 to 300, 330 to 90, 30 to 360"
        );
        assert_eq!(never_flown_words(&[[0.0, 360.0]]), "0 to 360");
    }
}
