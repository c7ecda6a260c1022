//! ArduPilot's compass correction and its undoing, shared by the readers of its logs
//! ([`super::dataflash`], [`super::tlog`]).
//!
//! ArduPilot's `AP_Compass_Backend::correct_field` turns the body-frame raw field `r` into
//! `m = D (s (r + OFS)) + MOT`: offsets added, then the scale factor `s`, then the symmetric
//! `D = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]]`, then the motor
//! compensation. `D` is taken as the identity when all of `DIA` are 0 (as ArduPilot does), and
//! `s` only when `COMPASS_SCALE` lies in ArduPilot's sanity range (`Compass::have_scale_factor`,
//! [`SCALE_RANGE`]); else `s = 1`. [`undo`] returns `r = D^-1 (m - MO) / s - OFS` with the values
//! in force at each reading.
//!
//! ArduPilot logs and sends these values as `int16` casts (`(int16_t)mag_field.x`), which
//! truncate towards zero: a logged `k` came from `[k, k + 1)` for `k > 0`, `(k - 1, k]` for
//! `k < 0`, `(-1, 1)` for 0. The readers take the middle of that interval ([`middle`]), which
//! removes the truncation's bias of half a unit. The offsets in force are taken from the
//! parameter (full precision) where it truncates to the logged offsets, else from the logged
//! offsets (offsets learnt in flight, or parameters not logged), and the notes count such
//! readings.

use std::collections::HashMap;

use anyhow::{Result, bail};
use magcal_core::Vec3;
use magcal_core::small::Mat3;

use super::flight::Sample;
use crate::limits::show;

/// The range of `COMPASS_SCALE` that ArduPilot applies (`COMPASS_MIN_SCALE_FACTOR` to
/// `COMPASS_MAX_SCALE_FACTOR`, 1/1.5 to 1.5); outside it (0 is "not set") it scales by 1.
pub const SCALE_RANGE: (f64, f64) = (1.0 / 1.5, 1.5);

pub const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// The middle of the interval an integer logged by a C cast (truncation towards zero) came from.
pub fn middle(k: f64) -> f64 {
    if k != 0.0 { k + 0.5 * k.signum() } else { k }
}

/// One reading as logged, before the calibration is undone.
#[derive(Debug, Clone, Copy)]
pub struct Logged {
    /// The logged offsets in force (`MAG.OfsX..Z`, `SENSOR_OFFSETS`) at the middle of their
    /// truncation interval; NaN where the log has none.
    pub ofs: [f64; 3],
    /// The same offsets as logged (for the comparison with the parameters).
    pub ofs_logged: [f64; 3],
    /// The motor compensation added (`MAG.MOX..Z`, or rebuilt from the parameters), mGauss.
    pub mo: Vec3,
}

/// The readings of one instance as logged, and what the log says of their offsets and motor
/// compensation.
#[derive(Default)]
pub struct Readings {
    /// `raw` holds `m` until [`undo`] undoes the calibration.
    pub samples: Vec<Sample>,
    pub logged: Vec<Logged>,
    /// The logged offsets are integers (truncated), not floats.
    pub ofs_integer: bool,
    /// The readings come with logged offsets.
    pub has_ofs: bool,
    /// Where the logged offsets come from, for the notes (`MAG's OfsX..Z`, `SENSOR_OFFSETS`).
    pub ofs_source: &'static str,
    /// How `MO` was found, for the words (`MO as logged`).
    pub mo_source: String,
    /// The log may come from firmware that added the motor compensation before `D`.
    pub mo_before_d: bool,
}

/// Names of the parameters a reader of instance `k` needs.
pub fn param_names(k: u8) -> [String; 10] {
    let sfx = if k == 0 { String::new() } else { (k + 1).to_string() };
    let xyz = |p: &str, a: &str| format!("COMPASS_{p}{sfx}_{a}");
    [
        xyz("OFS", "X"),
        xyz("OFS", "Y"),
        xyz("OFS", "Z"),
        xyz("DIA", "X"),
        xyz("DIA", "Y"),
        xyz("DIA", "Z"),
        xyz("ODI", "X"),
        xyz("ODI", "Y"),
        xyz("ODI", "Z"),
        format!("COMPASS_SCALE{sfx}"),
    ]
}

/// Whether `name` is one of the `COMPASS_` parameters the readers follow: `OFS`, `DIA`, `ODI`,
/// `MOT` (`_X`, `_Y`, `_Z`, with instance suffix none, `2`, `3`), `SCALE` (likewise) and `MOTCT`.
/// A fixed set, so that a log of made-up names holds no more than these.
pub fn followed(name: &str) -> bool {
    let Some(rest) = name.strip_prefix("COMPASS_") else {
        return false;
    };
    if rest == "MOTCT" {
        return true;
    }
    if let Some(r) = rest.strip_prefix("SCALE") {
        return matches!(r, "" | "2" | "3");
    }
    ["OFS", "DIA", "ODI", "MOT"].iter().any(|p| {
        rest.strip_prefix(p).is_some_and(|r| {
            let r = r.strip_prefix(['2', '3']).unwrap_or(r);
            matches!(r, "_X" | "_Y" | "_Z")
        })
    })
}

/// The calibration undone, in words: for [`super::flight::InForce::Undone`] and for the messages
/// used.
pub struct Undone {
    pub words: String,
    pub params: String,
}

/// The parameters in force at one reading (`None`: not in the log), in the order of
/// [`param_names`].
type InForceAt = [Option<f64>; 10];

/// `D^-1` and `s` of the parameters in force.
struct Inverse {
    d_inv: Mat3,
    s: f64,
}

/// Undoes, in place, the calibration in force at each reading of instance `k` (see the module
/// docs).
pub fn undo(
    inst: &mut Readings,
    k: u8,
    params: &HashMap<String, Vec<(u64, f64)>>,
    shown: &str,
    notes: &mut Vec<String>,
) -> Result<Undone> {
    let names = param_names(k);
    let sfx = if k == 0 { String::new() } else { (k + 1).to_string() };
    let series: [Option<&Vec<(u64, f64)>>; 10] = std::array::from_fn(|i| params.get(&names[i]));
    let mut cursor = [0usize; 10];
    let mut last: Option<InForceAt> = None;
    let mut inverse = Inverse {
        d_inv: IDENTITY,
        s: 1.0,
    };
    let (mut changes, mut from_mag, mut ofs_changes) = (0u64, 0u64, 0u64);
    let mut first: Option<(InForceAt, [f64; 3])> = None;
    let mut prev_logged: Option<[f64; 3]> = None;
    for (sample, logged) in inst.samples.iter_mut().zip(&inst.logged) {
        let v: InForceAt = std::array::from_fn(|i| {
            series[i].map(|s| {
                while cursor[i] + 1 < s.len() && s[cursor[i] + 1].0 < sample.offset {
                    cursor[i] += 1;
                }
                s[cursor[i]].1
            })
        });
        if last.as_ref().is_none_or(|l| !same(l, &v)) {
            changes += u64::from(last.is_some());
            inverse = invert(&v).ok_or_else(|| {
                anyhow::anyhow!(
                    "{shown}: byte {}: COMPASS_DIA{sfx}_* = {} and COMPASS_ODI{sfx}_* = {} in force give a singular matrix: the readings cannot be undone",
                    sample.offset,
                    triple(&v[3..6], 1.0),
                    triple(&v[6..9], 0.0)
                )
            })?;
            last = Some(v);
        }
        let mut ofs = [0.0; 3];
        let mut took_logged = false;
        for c in 0..3 {
            let lo = logged.ofs_logged[c];
            ofs[c] = match v[c] {
                Some(pv) if lo.is_nan() || ofs_matches(pv, lo, inst.ofs_integer) => pv,
                _ if lo.is_nan() => 0.0,
                _ => {
                    took_logged = true;
                    logged.ofs[c]
                }
            };
        }
        from_mag += u64::from(took_logged);
        if inst.has_ofs {
            ofs_changes += u64::from(prev_logged.is_some_and(|p| p != logged.ofs_logged));
            prev_logged = Some(logged.ofs_logged);
        }
        first.get_or_insert((v, ofs));
        let corrected = std::array::from_fn(|c| sample.raw[c] - logged.mo[c]);
        let r = magcal_core::small::mat_vec(&inverse.d_inv, corrected);
        sample.raw = std::array::from_fn(|c| r[c] / inverse.s - ofs[c]);
        if !sample.raw.iter().all(|x| x.is_finite()) {
            bail!(
                "{shown}: byte {}: the reading with the calibration in force undone is not finite",
                sample.offset
            );
        }
    }
    let (v0, ofs0) = first.unwrap_or(([None; 10], [0.0; 3]));
    undo_notes(&v0, &sfx, inst, (changes, from_mag, ofs_changes), notes);
    let scale = match v0[9] {
        Some(s) if applied(s) => format!("COMPASS_SCALE{sfx} = {} (s)", show(s)),
        Some(0.0) => format!("COMPASS_SCALE{sfx} = 0 (not set: s = 1)"),
        Some(s) => format!("COMPASS_SCALE{sfx} = {} (not applied: s = 1)", show(s)),
        None => "no COMPASS_SCALE (s = 1)".into(),
    };
    let ofs_source = if v0[..3].iter().all(Option::is_some) {
        "parameters"
    } else {
        "logged"
    };
    let words = format!(
        "r = D^-1 (m - MO) / s - OFS (ArduPilot's correct_field undone), with at the first reading COMPASS_OFS{sfx} = {} ({ofs_source}), COMPASS_DIA{sfx} = {}, COMPASS_ODI{sfx} = {}, {scale}, {}; the parameters changed {changes} times and the logged offsets {ofs_changes} times during the readings",
        triple(&ofs0.map(Some), 0.0),
        triple(&v0[3..6], 1.0),
        triple(&v0[6..9], 0.0),
        inst.mo_source,
    );
    let params = format!("COMPASS_OFS{sfx}_*, COMPASS_DIA{sfx}_*, COMPASS_ODI{sfx}_*, COMPASS_SCALE{sfx}");
    Ok(Undone { words, params })
}

/// Whether two sets of parameters in force are the same, bit for bit.
fn same(a: &InForceAt, b: &InForceAt) -> bool {
    a.iter().zip(b).all(|(x, y)| x.map(f64::to_bits) == y.map(f64::to_bits))
}

/// Whether ArduPilot applies a `COMPASS_SCALE` of `s`.
fn applied(s: f64) -> bool {
    (SCALE_RANGE.0..=SCALE_RANGE.1).contains(&s)
}

/// Whether the `COMPASS_OFS` parameter `pv` is what the log's `Ofs` field shows as `lo`: its
/// truncation for an integer field, its `float` for a float field.
fn ofs_matches(pv: f64, lo: f64, integer: bool) -> bool {
    if integer {
        pv.trunc() == lo
    } else {
        (pv as f32) == (lo as f32)
    }
}

/// `D^-1` and `s` of the parameters `v` (missing ones at ArduPilot's defaults); `None` when `D` is
/// singular.
fn invert(v: &InForceAt) -> Option<Inverse> {
    let mut dia = [0, 1, 2].map(|c| v[3 + c].unwrap_or(1.0));
    if dia == [0.0; 3] {
        // correct_field: diagonals of zero are taken as 1.
        dia = [1.0; 3];
    }
    let odi = [0, 1, 2].map(|c| v[6 + c].unwrap_or(0.0));
    let d = [
        [dia[0], odi[0], odi[1]],
        [odi[0], dia[1], odi[2]],
        [odi[1], odi[2], dia[2]],
    ];
    let s = v[9].filter(|&s| applied(s)).unwrap_or(1.0);
    Some(Inverse {
        d_inv: inverse3(&d)?,
        s,
    })
}

/// The inverse of `a` by its adjugate; `None` when `a` is singular to working precision.
fn inverse3(a: &Mat3) -> Option<Mat3> {
    let cof = |i: usize, j: usize| {
        let (r0, r1) = ((i + 1) % 3, (i + 2) % 3);
        let (c0, c1) = ((j + 1) % 3, (j + 2) % 3);
        a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0]
    };
    let det: f64 = (0..3).map(|j| a[0][j] * cof(0, j)).sum();
    let scale = a.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
    if !det.is_finite() || det.abs() <= 64.0 * f64::EPSILON * scale.powi(3) {
        return None;
    }
    Some(std::array::from_fn(|i| std::array::from_fn(|j| cof(j, i) / det)))
}

/// `(x, y, z)` of parameters, `default` for missing ones.
fn triple(v: &[Option<f64>], default: f64) -> String {
    let s: Vec<String> = v.iter().map(|x| show(x.unwrap_or(default))).collect();
    format!("({})", s.join(", "))
}

/// The notes on the calibration undone: parameters missing or not applied, offsets taken from
/// the readings, changes.
fn undo_notes(v0: &InForceAt, sfx: &str, inst: &Readings, counts: (u64, u64, u64), notes: &mut Vec<String>) {
    let (changes, from_mag, ofs_changes) = counts;
    if v0[3..9].iter().all(Option::is_none) {
        notes.push(format!(
            "The log has no COMPASS_DIA{sfx}_* or COMPASS_ODI{sfx}_* parameters: DIA = 1 and ODI = 0 were assumed."
        ));
    }
    if let Some(s) = v0[9].filter(|&s| s != 0.0 && !applied(s)) {
        notes.push(format!(
            "COMPASS_SCALE{sfx} = {} lies outside {}..{}, where ArduPilot does not apply it: s = 1.",
            show(s),
            show(SCALE_RANGE.0),
            show(SCALE_RANGE.1)
        ));
    }
    if v0[..3].iter().any(Option::is_none) {
        notes.push(if inst.has_ofs {
            format!(
                "The log has no COMPASS_OFS{sfx}_* parameters: the offsets are {} (whole mGauss, the middle of their truncation).",
                inst.ofs_source
            )
        } else {
            format!("The log has neither COMPASS_OFS{sfx}_* parameters nor logged offsets: offsets of 0 were assumed.")
        });
    } else if from_mag > 0 {
        notes.push(format!(
            "{from_mag} readings logged offsets that differ from COMPASS_OFS{sfx}_* in force (offsets learnt in flight, or changes not logged): their offsets are {}.",
            inst.ofs_source
        ));
    }
    if changes > 0 {
        notes.push(format!(
            "The calibration parameters changed {changes} times during the readings; each reading was undone with the values in force at it."
        ));
    }
    if ofs_changes > 0 {
        notes.push(format!(
            "The logged offsets ({}) changed {ofs_changes} times during the readings.",
            inst.ofs_source
        ));
    }
    let d_identity =
        v0[3..6].iter().all(|x| x.is_none_or(|x| x == 1.0)) && v0[6..9].iter().all(|x| x.is_none_or(|x| x == 0.0));
    if inst.mo_before_d && inst.logged.iter().any(|l| l.mo != [0.0; 3]) && !d_identity {
        notes.push(
            "This log comes from older firmware (MAG has MOfsX..Z), which may have added the motor compensation before D: where it did, the readings are off by (D - I) MO.".into(),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_followed_parameters_are_a_fixed_set() {
        for name in [
            "COMPASS_OFS_X",
            "COMPASS_OFS2_Y",
            "COMPASS_DIA3_Z",
            "COMPASS_ODI_Z",
            "COMPASS_SCALE",
            "COMPASS_SCALE3",
            "COMPASS_MOT2_X",
            "COMPASS_MOTCT",
        ] {
            assert!(followed(name), "{name}");
        }
        for name in [
            "COMPASS_OFS_XX",
            "COMPASS_OFS4_X",
            "COMPASS_OFS",
            "COMPASS_SCALE4",
            "COMPASS_DEC",
            "OFS_X",
        ] {
            assert!(!followed(name), "{name}");
        }
    }

    #[test]
    fn a_truncated_integer_is_read_at_the_middle_of_its_interval() {
        assert_eq!(middle(3.0), 3.5);
        assert_eq!(middle(-3.0), -3.5);
        assert_eq!(middle(0.0), 0.0);
    }

    #[test]
    fn the_inverse_of_d_is_its_inverse_and_singular_d_is_refused() {
        let a = [[1.02, 0.01, -0.02], [0.01, 0.97, 0.015], [-0.02, 0.015, 1.05]];
        let inv = inverse3(&a).unwrap();
        let product = magcal_core::small::mat_mul(&a, &inv);
        for (i, row) in product.iter().enumerate() {
            for (j, p) in row.iter().enumerate() {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((p - want).abs() < 16.0 * f64::EPSILON, "{p}");
            }
        }
        assert!(inverse3(&[[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).is_none());
    }
}
