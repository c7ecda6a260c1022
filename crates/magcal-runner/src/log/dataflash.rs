//! ArduPilot DataFlash logs (`.bin`): the magnetometer's readings with the calibration in force
//! undone, and the attitude, battery current and throttle logged beside them.
//!
//! # The format
//! A stream of messages, each a header `A3 95 <type>` and a payload of a fixed length. `FMT`
//! messages (type 128) define the other types: name, total length, a format string (one character
//! per field: `b B h H i I q Q f d` integers and floats, `c C e E` hundredths, `L` 1e-7 degrees,
//! `M` mode, `n N Z` strings of 4, 16, 64 bytes, `a` 32 `int16`) and the field labels. No
//! checksum: a header that is not `A3 95` followed by a defined type is skipped byte by byte to
//! the next one that is (as pymavlink's `DFReader` does), and the bytes skipped are counted in the
//! notes.
//!
//! # Messages used
//! - `MAG` (instance field `I`; `MAG2`, `MAG3` in older logs): `MagX, MagY, MagZ` (mGauss, body
//!   frame, after the calibration in force), `OfsX..Z` (the offsets in force), `MOX..Z` (`MOfsX..Z`
//!   in older logs: the motor compensation added); time `TimeUS` (`TimeMS` in old logs).
//! - `PARM` (`Name`, `Value`): `COMPASS_OFS*`, `COMPASS_DIA*`, `COMPASS_ODI*`, `COMPASS_SCALE*`
//!   (no suffix for instance 0, `2`, `3` for instances 1 and 2), in force from where they are
//!   logged on; the first value of each is taken for readings logged before it.
//! - `ATT` (`Roll, Pitch, Yaw`, degrees) as a quaternion ([`super::binary::quaternion_of_euler`]);
//!   `BAT` (`Curr`, amperes, instance 0); `CTUN` (`ThO`, 0 to 1).
//!
//! # The calibration undone
//! ArduPilot's `AP_Compass_Backend::correct_field` turns the body-frame raw field `r` into
//! `m = D (s (r + OFS)) + MOT` (offsets added, then the scale factor `s`, then the symmetric
//! `D = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]]`, then the motor
//! compensation, which is what `MO*` logs). `D` is taken as the identity when all of `DIA` are 0
//! (as ArduPilot does), and `s` only when `COMPASS_SCALE` lies in ArduPilot's sanity range
//! (`Compass::have_scale_factor`, [`SCALE_RANGE`]); else `s = 1`. So this reader returns
//! `r = D^-1 (m - MO) / s - OFS` with the values in force at each reading. Firmware before the
//! motor term moved after `D` added `MOT` before it; where such a log (labels `MOfsX..`) has
//! non-zero motor offsets and `D` is not the identity the notes say so.
//!
//! The logged fields are `int16` casts (`Write_Compass_instance`: `(int16_t)mag_field.x`), which
//! truncate towards zero: a logged `k` came from `[k, k + 1)` for `k > 0`, `(k - 1, k]` for
//! `k < 0`, `(-1, 1)` for 0. The reader takes the middle of that interval (`k +- 0.5`, 0), which
//! removes the truncation's bias of half a unit; the error left is below 0.5 mGauss per
//! component of `m`. The offsets in force are taken from the `PARM` value (full precision) where
//! it truncates to the logged `Ofs`, else from `Ofs` (offsets learnt in flight, or parameters not
//! logged), and the notes count such readings.
//!
//! # Why this parser and not a crate
//! `ardupilot-binlog` 0.2.0 (the DataFlash crate on crates.io) was read and measured: it
//! allocates a vector of decoded values for every message (1.0 s for a 100 MB synthetic log,
//! parsing alone), skips bad bytes silently and stops silently after 256 in a row, gives no byte
//! offsets, and an `FMT` with a length below 3 makes it panic (`capacity overflow`: `msg_len - 3`
//! on a `u8` cast to `usize` after a wrap). This parser decodes only the fields it uses, at offsets
//! fixed when the `FMT` is read, and reads the same 100 MB log with hashing in the time the
//! benchmark (`benches/flightlogs.rs`) reports; its reading of the public fixture is compared
//! with pymavlink's (`scripts/crosscheck-flightlogs.py`, `tests/flightlogs.json`).

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use anyhow::{Result, bail};
use magcal_core::Vec3;
use magcal_core::small::Mat3;

use super::binary::{At, Budget, Chunks, Dropped, in_order, quaternion_of_euler};
use super::flight::{FlightLog, Format, InForce, Sample, Selection, Series};
use crate::limits::show;
use crate::scenario::site::Units;

/// The range of `COMPASS_SCALE` that ArduPilot applies (`COMPASS_MIN_SCALE_FACTOR` to
/// `COMPASS_MAX_SCALE_FACTOR`, 1/1.5 to 1.5); outside it (0 is "not set") it scales by 1.
pub const SCALE_RANGE: (f64, f64) = (1.0 / 1.5, 1.5);

const MAGIC: [u8; 2] = [0xA3, 0x95];
const FMT_TYPE: u8 = 0x80;
const FMT_LEN: usize = 89;
/// Bytes of a message header.
const HEADER: usize = 3;

/// Reads the DataFlash log at `path`: the readings of the asked magnetometer instance (the lowest
/// where none is asked) with the calibration in force undone, and the series beside them.
///
/// # Errors
/// A file that is not a DataFlash log, an `FMT` of a message used that cannot be decoded, no
/// readings of the instance, a calibration in force that cannot be undone, or more than fits in
/// memory; each names the file and the byte offset, message or option.
pub fn read(path: &Path, selection: &Selection) -> Result<FlightLog> {
    read_with(path, selection, Budget::new())
}

/// [`read`] within `budget`.
///
/// # Errors
/// As [`read`].
pub fn read_with(path: &Path, selection: &Selection, mut budget: Budget) -> Result<FlightLog> {
    let shown = path.display().to_string();
    let mut chunks = Chunks::open(path)?;
    let mut log = Parsed::default();
    parse(&mut chunks, &shown, selection, &mut budget, &mut log)?;
    let (sha256, bytes) = chunks.finish()?;
    assemble(log, &shown, selection, sha256, bytes)
}

/// A field of a message: its offset in the payload and its format character.
#[derive(Debug, Clone, Copy)]
struct Field {
    at: usize,
    kind: u8,
}

impl Field {
    /// The field's value, scaled as pymavlink scales it (`c C e E` hundredths, `L` 1e-7).
    fn get(self, p: &[u8]) -> f64 {
        let b = &p[self.at..];
        let le2 = || [b[0], b[1]];
        let le4 = || [b[0], b[1], b[2], b[3]];
        let le8 = || [b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]];
        match self.kind {
            b'b' => f64::from(b[0] as i8),
            b'B' | b'M' => f64::from(b[0]),
            b'h' => f64::from(i16::from_le_bytes(le2())),
            b'H' => f64::from(u16::from_le_bytes(le2())),
            b'c' => f64::from(i16::from_le_bytes(le2())) / 100.0,
            b'C' => f64::from(u16::from_le_bytes(le2())) / 100.0,
            b'i' => f64::from(i32::from_le_bytes(le4())),
            b'I' => f64::from(u32::from_le_bytes(le4())),
            b'e' => f64::from(i32::from_le_bytes(le4())) / 100.0,
            b'E' => f64::from(u32::from_le_bytes(le4())) / 100.0,
            b'L' => f64::from(i32::from_le_bytes(le4())) * 1e-7,
            b'f' => f64::from(f32::from_le_bytes(le4())),
            b'd' => f64::from_le_bytes(le8()),
            b'q' => i64::from_le_bytes(le8()) as f64,
            b'Q' => u64::from_le_bytes(le8()) as f64,
            _ => f64::NAN,
        }
    }

    /// A field ArduPilot fills by a C cast to an integer (truncation towards zero): the middle of
    /// the interval the logged value came from (see the module docs).
    fn get_truncated(self, p: &[u8]) -> f64 {
        let v = self.get(p);
        if Self::integer(self.kind) && v != 0.0 {
            v + 0.5 * v.signum()
        } else {
            v
        }
    }

    fn integer(kind: u8) -> bool {
        matches!(kind, b'b' | b'B' | b'h' | b'H' | b'i' | b'I' | b'q' | b'Q')
    }

    /// The text of a string field (`n N Z`), up to its first NUL.
    fn text(self, p: &[u8]) -> String {
        let b = &p[self.at..self.at + size(self.kind).unwrap_or(0)];
        let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
        String::from_utf8_lossy(&b[..end]).into_owned()
    }
}

/// Bytes of a field of format character `c`.
fn size(c: u8) -> Option<usize> {
    Some(match c {
        b'b' | b'B' | b'M' => 1,
        b'h' | b'H' | b'c' | b'C' => 2,
        b'i' | b'I' | b'e' | b'E' | b'f' | b'L' | b'n' => 4,
        b'q' | b'Q' | b'd' => 8,
        b'N' => 16,
        b'Z' | b'a' => 64,
        _ => return None,
    })
}

/// A time field: its field and seconds per unit.
#[derive(Debug, Clone, Copy)]
struct Time {
    field: Field,
    seconds: f64,
}

impl Time {
    fn get(self, p: &[u8]) -> f64 {
        self.field.get(p) * self.seconds
    }
}

/// What this reader takes from a message type, with the fields' places fixed when its `FMT` is
/// read.
#[derive(Debug, Clone)]
enum Role {
    Other,
    Mag {
        time: Time,
        instance: Result<Field, u8>,
        mag: [Field; 3],
        ofs: Option<[Field; 3]>,
        mo: Option<[Field; 3]>,
        old_labels: bool,
    },
    Parm {
        name: Field,
        value: Field,
    },
    Att {
        time: Time,
        rpy: [Field; 3],
    },
    Bat {
        time: Time,
        instance: Option<Field>,
        current: Field,
    },
    Ctun {
        time: Time,
        throttle: Field,
    },
}

/// A message type as its `FMT` defines it.
#[derive(Debug, Clone)]
struct Layout {
    name: String,
    len: usize,
    role: Role,
}

/// One reading as logged, before the calibration is undone.
#[derive(Debug, Clone, Copy)]
struct Logged {
    /// `OfsX..Z` (middle of the truncation interval), NaN where the message has none.
    ofs: [f64; 3],
    /// The same `Ofs` as logged (for the comparison with `PARM`).
    ofs_logged: [f64; 3],
    /// `MOX..Z`, 0 where the message has none.
    mo: Vec3,
}

/// The readings of one instance, as logged.
#[derive(Default)]
struct Instance {
    /// `raw` holds `m` until the calibration is undone.
    samples: Vec<Sample>,
    logged: Vec<Logged>,
    /// The message and fields, for [`FlightLog::messages`].
    source: String,
    ofs_integer: bool,
    has_ofs: bool,
    has_mo: bool,
    old_labels: bool,
}

/// Everything read from the file.
#[derive(Default)]
struct Parsed {
    data: Data,
    dropped: Dropped,
    skipped_bytes: u64,
    skipped_places: u64,
    first_skip: Option<u64>,
    truncated_at: Option<u64>,
}

/// The readings, parameters and series read.
#[derive(Default)]
struct Data {
    instances: BTreeMap<u8, Instance>,
    /// Instances seen but not kept (another was asked for).
    seen: Vec<u8>,
    /// `COMPASS_*` parameters: (byte offset, value) each time the value changes.
    params: HashMap<String, Vec<(u64, f64)>>,
    attitude: Series<[f64; 4]>,
    current: Series<f64>,
    throttle: Series<f64>,
    att_source: Option<String>,
    bat_source: Option<String>,
    ctun_source: Option<String>,
}

/// Names of the parameters a reader of instance `k` needs.
fn param_names(k: u8) -> [String; 10] {
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

/// Whether `name` is one of the `COMPASS_` parameters this reader follows.
fn followed(name: &str) -> bool {
    let Some(rest) = name.strip_prefix("COMPASS_") else {
        return false;
    };
    ["OFS", "DIA", "ODI", "SCALE"].iter().any(|p| {
        rest.strip_prefix(p)
            .is_some_and(|s| s.is_empty() || s.starts_with(['_', '2', '3']))
    })
}

fn parse(chunks: &mut Chunks, shown: &str, selection: &Selection, budget: &mut Budget, log: &mut Parsed) -> Result<()> {
    let mut types: Vec<Option<Layout>> = vec![None; 256];
    types[usize::from(FMT_TYPE)] = Some(Layout {
        name: "FMT".into(),
        len: FMT_LEN,
        role: Role::Other,
    });
    let head = chunks.fill(HEADER)?;
    if head < HEADER || chunks.window()[..HEADER] != [MAGIC[0], MAGIC[1], FMT_TYPE] {
        let w = &chunks.window()[..head.min(HEADER)];
        bail!(
            "{shown}: not an ArduPilot DataFlash log: it begins with {}, not the FMT header A3 95 80",
            hex(w)
        );
    }
    loop {
        let avail = chunks.fill(256)?;
        if avail == 0 {
            break;
        }
        let offset = chunks.offset();
        let w = chunks.window();
        if avail < HEADER {
            log.truncated_at = Some(offset);
            chunks.advance(avail);
            continue;
        }
        let known = w[..2] == MAGIC && types[usize::from(w[2])].is_some();
        if !known {
            let skip = resync(w, &types);
            log.skipped_bytes += skip as u64;
            log.skipped_places += u64::from(log.first_skip.is_none() || w[..2] == MAGIC || skip > 1);
            log.first_skip.get_or_insert(offset);
            chunks.advance(skip);
            continue;
        }
        let t = w[2];
        let len = types[usize::from(t)].as_ref().map_or(HEADER, |l| l.len);
        if avail < len {
            log.truncated_at = Some(offset);
            chunks.advance(avail);
            continue;
        }
        let p = &w[HEADER..len];
        if t == FMT_TYPE {
            define(p, offset, shown, &mut types)?;
        } else if let Some(layout) = &types[usize::from(t)] {
            let mut at = At {
                shown,
                offset,
                budget,
                dropped: &mut log.dropped,
            };
            take(layout, p, selection, &mut at, &mut log.data)?;
        }
        chunks.advance(len);
    }
    Ok(())
}

/// Bytes to skip from the start of `w` (a bad header) to the next `A3 95` with a defined type, or
/// to the last byte of `w` (which may start a header the next chunk completes).
fn resync(w: &[u8], types: &[Option<Layout>]) -> usize {
    (1..w.len().saturating_sub(2))
        .find(|&i| w[i..i + 2] == MAGIC && types[usize::from(w[i + 2])].is_some())
        .unwrap_or(w.len().saturating_sub(2).max(1))
}

fn hex(b: &[u8]) -> String {
    if b.is_empty() {
        return "nothing (the file is empty)".into();
    }
    b.iter().map(|x| format!("{x:02X}")).collect::<Vec<_>>().join(" ")
}

/// The names of messages this reader uses.
fn used(name: &str) -> bool {
    matches!(name, "MAG" | "PARM" | "ATT" | "BAT" | "CTUN")
        || name.strip_prefix("MAG").is_some_and(|n| matches!(n, "2" | "3"))
}

/// Installs the layout an `FMT` payload defines.
fn define(p: &[u8], offset: u64, shown: &str, types: &mut [Option<Layout>]) -> Result<()> {
    let text = |b: &[u8]| {
        let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
        String::from_utf8_lossy(&b[..end]).into_owned()
    };
    let (t, len) = (p[0], usize::from(p[1]));
    let name = text(&p[2..6]);
    let format = text(&p[6..22]).into_bytes();
    let labels = text(&p[22..86]);
    if t == FMT_TYPE {
        // The FMT of FMT is fixed by the format; a log's own says the same or is damaged.
        return Ok(());
    }
    let sizes: Option<Vec<usize>> = format.iter().map(|&c| size(c)).collect();
    let payload: Option<usize> = sizes.as_ref().map(|s| s.iter().sum());
    let fits = len >= HEADER && payload == Some(len - HEADER);
    if !used(&name) {
        // A type this reader skips needs only its length (at least a header's).
        types[usize::from(t)] = (len >= HEADER).then_some(Layout {
            name,
            len,
            role: Role::Other,
        });
        return Ok(());
    }
    let excerpt = crate::limits::excerpt(&String::from_utf8_lossy(&format), 16);
    if !fits {
        bail!(
            "{shown}: byte {offset}: the FMT of {name} (type {t}) cannot be decoded: format {excerpt:?} takes {} bytes after the header, its length says {}",
            payload.map_or("an unknown number of".into(), |n| n.to_string()),
            len.saturating_sub(HEADER)
        );
    }
    let mut at = 0;
    let mut fields: HashMap<&str, Field> = HashMap::new();
    for (label, (&kind, n)) in labels.split(',').zip(format.iter().zip(sizes.unwrap_or_default())) {
        fields.entry(label.trim()).or_insert(Field { at, kind });
        at += n;
    }
    let role = role(&name, &fields).map_err(|missing| {
        anyhow::anyhow!("{shown}: byte {offset}: the FMT of {name} (type {t}) has no field {missing}")
    })?;
    types[usize::from(t)] = Some(Layout { name, len, role });
    Ok(())
}

/// The role of a used message from its fields; `Err(label)` names a field it lacks.
fn role(name: &str, f: &HashMap<&str, Field>) -> Result<Role, String> {
    let get = |l: &str| f.get(l).copied().ok_or_else(|| l.to_string());
    let xyz = |a: &str, b: &str, c: &str| -> Option<[Field; 3]> { Some([*f.get(a)?, *f.get(b)?, *f.get(c)?]) };
    let time = || -> Result<Time, String> {
        if let Some(&field) = f.get("TimeUS") {
            Ok(Time { field, seconds: 1e-6 })
        } else if let Some(&field) = f.get("TimeMS") {
            Ok(Time { field, seconds: 1e-3 })
        } else {
            Err("TimeUS (or TimeMS)".into())
        }
    };
    let numeric = |x: Field| -> Result<Field, String> {
        if matches!(x.kind, b'n' | b'N' | b'Z' | b'a') {
            Err(format!(
                "of a number (a string or array is where one is expected in {name})"
            ))
        } else {
            Ok(x)
        }
    };
    Ok(match name {
        "PARM" => Role::Parm {
            name: get("Name")?,
            value: numeric(get("Value")?)?,
        },
        "ATT" => Role::Att {
            time: time()?,
            rpy: [numeric(get("Roll")?)?, numeric(get("Pitch")?)?, numeric(get("Yaw")?)?],
        },
        "BAT" => Role::Bat {
            time: time()?,
            instance: ["Inst", "Instance", "I"].iter().find_map(|l| f.get(l).copied()),
            current: numeric(get("Curr")?)?,
        },
        "CTUN" => match f.get("ThO") {
            Some(&throttle) => Role::Ctun {
                time: time()?,
                throttle: numeric(throttle)?,
            },
            None => Role::Other,
        },
        _ => {
            let instance = match f.get("I") {
                Some(&i) => Ok(numeric(i)?),
                None => Err(name
                    .strip_prefix("MAG")
                    .and_then(|n| n.parse::<u8>().ok())
                    .map_or(0, |n| n - 1)),
            };
            let old = xyz("MOfsX", "MOfsY", "MOfsZ");
            Role::Mag {
                time: time()?,
                instance,
                mag: [numeric(get("MagX")?)?, numeric(get("MagY")?)?, numeric(get("MagZ")?)?],
                ofs: xyz("OfsX", "OfsY", "OfsZ"),
                mo: xyz("MOX", "MOY", "MOZ").or(old),
                old_labels: old.is_some(),
            }
        }
    })
}

/// Takes what a message of a used type carries.
fn take(layout: &Layout, p: &[u8], selection: &Selection, at: &mut At, data: &mut Data) -> Result<()> {
    match &layout.role {
        Role::Other => {}
        Role::Parm { name, value } => {
            let name = name.text(p);
            if followed(&name) {
                let v = value.get(p);
                let series = data.params.entry(name).or_default();
                if series.last().is_none_or(|&(_, last)| last.to_bits() != v.to_bits()) {
                    at.budget.push(series, (at.offset, v), at.shown, at.offset)?;
                }
            }
        }
        Role::Mag {
            time,
            instance,
            mag,
            ofs,
            mo,
            old_labels,
        } => {
            let k = match instance {
                Ok(f) => f.get(p),
                Err(k) => f64::from(*k),
            };
            if !(0.0..=255.0).contains(&k) || k.fract() != 0.0 {
                *at.dropped.not_finite.entry("MAG").or_default() += 1;
                return Ok(());
            }
            let k = k as u8;
            if selection.instance.is_some_and(|want| want != k) {
                if !data.seen.contains(&k) {
                    data.seen.push(k);
                }
                return Ok(());
            }
            let inst = data.instances.entry(k).or_insert_with(|| Instance {
                source: mag_source(
                    &layout.name,
                    instance.is_ok(),
                    k,
                    ofs.is_some(),
                    mo.is_some(),
                    *old_labels,
                ),
                ofs_integer: ofs.is_some_and(|o| Field::integer(o[0].kind)),
                has_ofs: ofs.is_some(),
                has_mo: mo.is_some(),
                old_labels: *old_labels,
                ..Instance::default()
            });
            let t = time.get(p);
            let m = mag.map(|f| f.get_truncated(p));
            let (o, o_logged) = match ofs {
                Some(f) => (f.map(|f| f.get_truncated(p)), f.map(|f| f.get(p))),
                None => ([f64::NAN; 3], [f64::NAN; 3]),
            };
            let mo = mo.map_or([0.0; 3], |f| f.map(|f| f.get_truncated(p)));
            let finite =
                m.iter().chain(&mo).all(|v| v.is_finite()) && (ofs.is_none() || o.iter().all(|v| v.is_finite()));
            if !finite || !t.is_finite() {
                *at.dropped.not_finite.entry("MAG").or_default() += 1;
            } else if !in_order(inst.samples.last().map(|s| s.time_s), t) {
                *at.dropped.out_of_order.entry("MAG").or_default() += 1;
            } else {
                let sample = Sample {
                    time_s: t,
                    raw: m,
                    offset: at.offset,
                };
                at.budget.push(&mut inst.samples, sample, at.shown, at.offset)?;
                let logged = Logged {
                    ofs: o,
                    ofs_logged: o_logged,
                    mo,
                };
                at.budget.push(&mut inst.logged, logged, at.shown, at.offset)?;
            }
        }
        Role::Att { time, rpy } => {
            data.att_source
                .get_or_insert_with(|| "ATT: Roll, Pitch, Yaw (degrees)".into());
            let [r, pi, y] = rpy.map(|f| f.get(p).to_radians());
            let q = quaternion_of_euler(r, pi, y);
            let finite = q.iter().all(|v| v.is_finite());
            at.push_series(&mut data.attitude, time.get(p), q, finite, "ATT")?;
        }
        Role::Bat {
            time,
            instance,
            current,
        } => {
            if instance.is_some_and(|f| f.get(p) != 0.0) {
                return Ok(());
            }
            data.bat_source.get_or_insert_with(|| {
                format!("BAT{}: Curr (A)", if instance.is_some() { " (instance 0)" } else { "" })
            });
            let c = current.get(p);
            at.push_series(&mut data.current, time.get(p), c, c.is_finite(), "BAT")?;
        }
        Role::Ctun { time, throttle } => {
            data.ctun_source.get_or_insert_with(|| "CTUN: ThO (0 to 1)".into());
            let v = throttle.get(p);
            at.push_series(&mut data.throttle, time.get(p), v, v.is_finite(), "CTUN")?;
        }
    }
    Ok(())
}

/// The message and fields of an instance's readings, in words.
fn mag_source(name: &str, has_i: bool, k: u8, ofs: bool, mo: bool, old: bool) -> String {
    let mut s = if has_i {
        format!("{name} (I = {k}): MagX, MagY, MagZ")
    } else {
        format!("{name}: MagX, MagY, MagZ")
    };
    if ofs {
        s.push_str(", OfsX, OfsY, OfsZ");
    }
    if mo {
        s.push_str(if old {
            ", MOfsX, MOfsY, MOfsZ"
        } else {
            ", MOX, MOY, MOZ"
        });
    }
    s.push_str(" (mGauss)");
    s
}

/// The flight log from what was read: the instance chosen, its calibration undone, the notes.
fn assemble(parsed: Parsed, shown: &str, selection: &Selection, sha256: String, bytes: u64) -> Result<FlightLog> {
    let Parsed {
        mut data,
        dropped,
        skipped_bytes,
        skipped_places,
        first_skip,
        truncated_at,
    } = parsed;
    let mut instances: Vec<u8> = data
        .instances
        .keys()
        .copied()
        .chain(data.seen.iter().copied())
        .collect();
    instances.sort_unstable();
    instances.dedup();
    let k = match selection.instance {
        Some(k) => k,
        None => match instances.first() {
            Some(&k) => k,
            None => bail!("{shown}: no magnetometer readings (no MAG, MAG2 or MAG3 messages)"),
        },
    };
    let Some(mut inst) = data.instances.remove(&k) else {
        bail!(
            "{shown}: --compass {k}: the log has no readings of magnetometer {k}; it has {}",
            if instances.is_empty() {
                "none".to_string()
            } else {
                list(&instances)
            }
        );
    };
    let mut notes = Vec::new();
    let undone = undo(&mut inst, k, &data.params, shown, &mut notes)?;
    if let Some(at) = first_skip {
        notes.push(format!(
            "Skipped {skipped_bytes} bytes that are not messages, in {skipped_places} places from byte {at} on (damaged or partly written)."
        ));
    }
    if let Some(at) = truncated_at {
        notes.push(format!(
            "The last message, at byte {at}, is cut short (the log was not closed); it is ignored."
        ));
    }
    notes.extend(dropped.notes());
    let mut messages = vec![inst.source.clone(), undone.params];
    messages.extend(
        [data.att_source, data.bat_source, data.ctun_source]
            .into_iter()
            .flatten(),
    );
    Ok(FlightLog {
        format: Format::DataFlash,
        messages,
        unit: Units::MilliGauss,
        frame: "body (forward, right, down)".into(),
        instances,
        instance: k,
        samples: inst.samples,
        attitude: (!data.attitude.times.is_empty()).then_some(data.attitude),
        current: (!data.current.times.is_empty()).then_some(data.current),
        throttle: (!data.throttle.times.is_empty()).then_some(data.throttle),
        to_body: Some(IDENTITY),
        calibration: InForce::Undone(undone.words),
        notes,
        sha256,
        bytes,
    })
}

const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

fn list(v: &[u8]) -> String {
    v.iter().map(u8::to_string).collect::<Vec<_>>().join(", ")
}

/// The calibration undone, in words: for [`InForce::Undone`] and for the messages used.
struct Undone {
    words: String,
    params: String,
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
fn undo(
    inst: &mut Instance,
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
        Some(s) => format!("COMPASS_SCALE{sfx} = {} (not applied: s = 1)", show(s)),
        None => "no COMPASS_SCALE (s = 1)".into(),
    };
    let ofs_source = if v0[..3].iter().all(Option::is_some) {
        "PARM"
    } else {
        "MAG"
    };
    let words = format!(
        "r = D^-1 (m - MO) / s - OFS (ArduPilot's correct_field undone), with at the first reading COMPASS_OFS{sfx} = {} ({ofs_source}), COMPASS_DIA{sfx} = {}, COMPASS_ODI{sfx} = {}, {scale}, MO as logged; the parameters changed {changes} times and the logged offsets {ofs_changes} times during the readings",
        triple(&ofs0.map(Some), 0.0),
        triple(&v0[3..6], 1.0),
        triple(&v0[6..9], 0.0),
    );
    let params = format!("PARM: COMPASS_OFS{sfx}_*, COMPASS_DIA{sfx}_*, COMPASS_ODI{sfx}_*, COMPASS_SCALE{sfx}");
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
fn undo_notes(v0: &InForceAt, sfx: &str, inst: &Instance, counts: (u64, u64, u64), notes: &mut Vec<String>) {
    let (changes, from_mag, ofs_changes) = counts;
    if v0[3..9].iter().all(Option::is_none) {
        notes.push(format!(
            "The log has no PARM COMPASS_DIA{sfx}_* or COMPASS_ODI{sfx}_*: DIA = 1 and ODI = 0 were assumed."
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
            format!("The log has no PARM COMPASS_OFS{sfx}_*: the offsets are MAG's OfsX..Z (whole mGauss, the middle of their truncation).")
        } else {
            format!("The log has neither PARM COMPASS_OFS{sfx}_* nor offsets in MAG: offsets of 0 were assumed.")
        });
    } else if from_mag > 0 {
        notes.push(format!(
            "{from_mag} readings logged offsets that differ from COMPASS_OFS{sfx}_* in force (offsets learnt in flight, or changes not logged): their offsets are MAG's OfsX..Z."
        ));
    }
    if changes > 0 {
        notes.push(format!(
            "The calibration parameters changed {changes} times during the readings; each reading was undone with the values in force at it."
        ));
    }
    if ofs_changes > 0 {
        notes.push(format!(
            "MAG's logged offsets changed {ofs_changes} times during the readings."
        ));
    }
    let d_identity =
        v0[3..6].iter().all(|x| x.is_none_or(|x| x == 1.0)) && v0[6..9].iter().all(|x| x.is_none_or(|x| x == 0.0));
    if inst.old_labels && inst.has_mo && inst.logged.iter().any(|l| l.mo != [0.0; 3]) && !d_identity {
        notes.push(
            "This log's MAG has MOfsX..Z (older firmware, which may have added the motor compensation before D): where it did, the readings are off by (D - I) MO.".into(),
        );
    }
}
