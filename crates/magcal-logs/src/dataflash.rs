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
//!   logged on; the first value of each is taken for readings logged before it. For `export`
//!   ([`super::parameters`]): which of the `COMPASS_*` parameters it writes the log has (a log
//!   writes every parameter as `PARM` when it starts), and the last `COMPASS_OFFS_MAX`.
//! - `ATT` (`Roll, Pitch, Yaw`, degrees) as a quaternion ([`super::binary::quaternion_of_euler`]);
//!   `BAT` (`Curr`, amperes, instance 0); `CTUN` (`ThO`, 0 to 1).
//! - `GPS` (instance 0: field `I`, or the message `GPS` where older logs name a second receiver
//!   `GPS2`): `Status` (the fix type), `Lat`, `Lng` (1e-7 degrees), `Alt` (metres above mean sea
//!   level), `GWk`, `GMS` (GPS week and milliseconds of the week: the UTC date), and `Yaw`
//!   (degrees; a moving-baseline receiver's heading, 0 where it has none) in logs that have it.
//! - `XKY0` (core 0): `YC`, the yaw of EKF3's Gaussian sum filter of GPS velocities (degrees), an
//!   estimate that does not use the compass.
//!
//! # The calibration undone
//! With the values in force at each reading ([`super::ardupilot`]): `OFS` from `PARM` where it
//! truncates to the logged `Ofs`, else the logged `Ofs`; `D` and `s` from `PARM`; `MO` as logged.
//! Firmware before the motor term moved after `D` (logs whose `MAG` labels it `MOfsX..Z`) added
//! it before `D`; where such a log has non-zero motor offsets and `D` is not the identity the
//! notes say so.
//!
//! # Why this parser and not a crate
//! `ardupilot-binlog` 0.2.0, the DataFlash crate on crates.io, was read and measured on the same
//! logs: it decodes every field of every message into a fresh vector (1.0 s for the 100 MB log of
//! `benches/flightlogs.rs`, parsing alone, against 0.16 to 0.27 s for this reader with the file
//! hashed, on 2 cores under a load of 5), skips bad bytes silently and stops silently after 256 in
//! a row, gives no byte offsets, and an `FMT` with a length below 3 makes it panic (`msg_len - 3`
//! wraps: `capacity overflow`). pymavlink's `DFReader` is the reference: this reader's reading of
//! the public fixture is compared with it (`scripts/crosscheck-flightlogs.py`, whose numbers
//! `tests/flightlogs.json` holds). This reader decodes only the fields it uses, at offsets fixed
//! when their `FMT` is read.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use anyhow::{Result, bail};

use super::ardupilot::{IDENTITY, Logged, Readings, followed, middle, undo};
use super::binary::{At, Budget, Chunks, Dropped, Skipped, in_order, quaternion_of_euler, read_file, take_instance};
use super::flight::{Fix, FlightLog, Format, InForce, Sample, Selection, Series, utc_of_gps_week};
use super::parameters::LogParameters;
use crate::site::Units;

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
    read_file(
        path,
        |chunks, shown, log: &mut Parsed| parse(chunks, shown, selection, &mut budget, log),
        |log, shown, sha256, bytes| assemble(log, shown, selection, sha256, bytes),
    )
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
    /// the interval the logged value came from ([`middle`]).
    fn get_truncated(self, p: &[u8]) -> f64 {
        let v = self.get(p);
        if Self::integer(self.kind) { middle(v) } else { v }
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
    Gsf {
        time: Time,
        core: Option<Field>,
        yaw: Field,
    },
    Gps {
        time: Time,
        instance: Option<Field>,
        yaw: Option<Field>,
        status: Field,
        week: Option<Field>,
        ms: Option<Field>,
        lat_lon_alt: [Field; 3],
    },
}

/// A message type as its `FMT` defines it.
#[derive(Debug, Clone)]
struct Layout {
    name: String,
    len: usize,
    role: Role,
}

/// The readings of one instance, as logged.
#[derive(Default)]
struct Instance {
    readings: Readings,
    /// The message and fields, for [`FlightLog::messages`].
    source: String,
}

/// Everything read from the file.
#[derive(Default)]
struct Parsed {
    data: Data,
    dropped: Dropped,
    skipped: Skipped,
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
    /// The last `COMPASS_OFFS_MAX`, mGauss, for `export`'s range check.
    offs_max: Option<f64>,
    attitude: Series<[f64; 4]>,
    current: Series<f64>,
    throttle: Series<f64>,
    att_source: Option<String>,
    bat_source: Option<String>,
    ctun_source: Option<String>,
    gps: Series<Fix>,
    gps_source: Option<String>,
    gps_yaw: Series<f64>,
    gsf_yaw: Series<f64>,
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
            log.skipped.skip(offset, skip);
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
    matches!(name, "MAG" | "PARM" | "ATT" | "BAT" | "CTUN" | "GPS" | "XKY0")
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
        "GPS" => Role::Gps {
            time: time()?,
            instance: f.get("I").copied().map(numeric).transpose()?,
            yaw: f.get("Yaw").copied().map(numeric).transpose()?,
            status: numeric(get("Status")?)?,
            week: f.get("GWk").copied().map(numeric).transpose()?,
            ms: f.get("GMS").copied().map(numeric).transpose()?,
            lat_lon_alt: [numeric(get("Lat")?)?, numeric(get("Lng")?)?, numeric(get("Alt")?)?],
        },
        "XKY0" => Role::Gsf {
            time: time()?,
            core: f.get("C").copied().map(numeric).transpose()?,
            yaw: numeric(get("YC")?)?,
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
            if name == "COMPASS_OFFS_MAX" {
                data.offs_max = Some(value.get(p));
            }
            if followed(&name) {
                let v = value.get(p);
                let series = data.params.entry(name).or_default();
                if series.last().is_none_or(|&(_, last)| last.to_bits() != v.to_bits()) {
                    at.budget.push(series, (at.offset, v), at.shown, at.offset)?;
                }
            }
        }
        Role::Mag { .. } => take_mag(layout, p, selection, at, data)?,
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
        Role::Gsf { time, core, yaw } => {
            if core.is_some_and(|f| f.get(p) != 0.0) {
                return Ok(());
            }
            let y = yaw.get(p);
            at.push_series(
                &mut data.gsf_yaw,
                time.get(p),
                y.rem_euclid(360.0),
                y.is_finite(),
                "XKY0",
            )?;
        }
        Role::Gps { .. } => take_gps(&layout.role, p, at, data)?,
        Role::Ctun { time, throttle } => {
            data.ctun_source.get_or_insert_with(|| "CTUN: ThO (0 to 1)".into());
            let v = throttle.get(p);
            at.push_series(&mut data.throttle, time.get(p), v, v.is_finite(), "CTUN")?;
        }
    }
    Ok(())
}

/// Takes a `GPS` message of the first receiver: its fix, and a moving-baseline receiver's yaw
/// where the message has one.
fn take_gps(role: &Role, p: &[u8], at: &mut At, data: &mut Data) -> Result<()> {
    let Role::Gps {
        time,
        instance,
        yaw,
        status,
        week,
        ms,
        lat_lon_alt,
    } = role
    else {
        return Ok(());
    };
    // The first receiver: instance 0 (older logs name a second one GPS2).
    if instance.is_some_and(|f| f.get(p) != 0.0) {
        return Ok(());
    }
    data.gps_source.get_or_insert_with(|| {
        format!(
            "GPS{}: Status, Lat, Lng, Alt{}",
            if instance.is_some() { " (instance 0)" } else { "" },
            if week.is_some() && ms.is_some() {
                ", GWk, GMS (UTC)"
            } else {
                ""
            }
        )
    });
    let [lat_deg, lon_deg, alt_m] = lat_lon_alt.map(|f| f.get(p));
    let fix = Fix {
        lat_deg,
        lon_deg,
        alt_m,
        fix_type: status.get(p).clamp(0.0, 255.0) as u8,
        utc_s: week.zip(*ms).and_then(|(w, m)| utc_of_gps_week(w.get(p), m.get(p))),
    };
    let finite = lat_deg.is_finite() && lon_deg.is_finite() && alt_m.is_finite();
    at.push_series(&mut data.gps, time.get(p), fix, finite, "GPS")?;
    // A receiver without a yaw logs 0: a moving-baseline yaw of exactly 0 is taken as none.
    if let Some(y) = yaw.map(|f| f.get(p)).filter(|y| *y != 0.0 && y.is_finite())
        && fix.fix_type >= 3
    {
        at.push_series(&mut data.gps_yaw, time.get(p), y.rem_euclid(360.0), true, "GPS")?;
    }
    Ok(())
}

/// Takes a magnetometer reading (`MAG`, `MAG2`, `MAG3`) of the instance asked for, with the
/// offsets and motor term logged beside it.
fn take_mag(layout: &Layout, p: &[u8], selection: &Selection, at: &mut At, data: &mut Data) -> Result<()> {
    let Role::Mag {
        time,
        instance,
        mag,
        ofs,
        mo,
        old_labels,
    } = &layout.role
    else {
        return Ok(());
    };
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
    let inst = &mut data
        .instances
        .entry(k)
        .or_insert_with(|| Instance {
            source: mag_source(
                &layout.name,
                instance.is_ok(),
                k,
                ofs.is_some(),
                mo.is_some(),
                *old_labels,
            ),
            readings: Readings {
                ofs_integer: ofs.is_some_and(|o| Field::integer(o[0].kind)),
                has_ofs: ofs.is_some(),
                ofs_source: "MAG's OfsX..Z",
                mo_source: if mo.is_some() {
                    "MO as logged".into()
                } else {
                    "MO = 0 (not logged)".into()
                },
                mo_before_d: *old_labels,
                ..Readings::default()
            },
        })
        .readings;
    let t = time.get(p);
    let m = mag.map(|f| f.get_truncated(p));
    let (o, o_logged) = match ofs {
        Some(f) => (f.map(|f| f.get_truncated(p)), f.map(|f| f.get(p))),
        None => ([f64::NAN; 3], [f64::NAN; 3]),
    };
    let mo = mo.map_or([0.0; 3], |f| f.map(|f| f.get_truncated(p)));
    let finite = m.iter().chain(&mo).all(|v| v.is_finite()) && (ofs.is_none() || o.iter().all(|v| v.is_finite()));
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
        skipped,
        truncated_at,
    } = parsed;
    let instances_kept = std::mem::take(&mut data.instances);
    let (instances, k, mut inst) = take_instance(instances_kept, &data.seen, selection, shown, "MAG, MAG2 or MAG3")?;
    let mut notes = Vec::new();
    let undone = undo(&mut inst.readings, k, &data.params, shown, &mut notes)?;
    notes.extend(skipped.note("messages"));
    if let Some(at) = truncated_at {
        notes.push(format!(
            "The last message, at byte {at}, is cut short (the log was not closed); it is ignored."
        ));
    }
    notes.extend(dropped.notes());
    let mut messages = vec![inst.source.clone(), format!("PARM: {}", undone.params)];
    messages.extend(
        [data.att_source, data.bat_source, data.ctun_source, data.gps_source]
            .into_iter()
            .flatten(),
    );
    // A log writes every parameter as PARM when it starts: the names it lacks, its firmware lacks.
    let parameters = LogParameters::ardupilot("PARM", Some(data.params.keys()), data.offs_max);
    Ok(FlightLog {
        format: Format::DataFlash,
        messages,
        unit: Units::MilliGauss,
        frame: "body (forward, right, down)".into(),
        instances,
        instance: k,
        samples: inst.readings.samples,
        attitude: (!data.attitude.times.is_empty()).then_some(data.attitude),
        current: (!data.current.times.is_empty()).then_some(data.current),
        throttle: (!data.throttle.times.is_empty()).then_some(data.throttle),
        gps: (!data.gps.times.is_empty()).then_some(data.gps),
        gps_yaw: (!data.gps_yaw.times.is_empty()).then(|| (data.gps_yaw, "GPS.Yaw (moving baseline)".to_string())),
        gsf_yaw: (!data.gsf_yaw.times.is_empty()).then(|| (data.gsf_yaw, "XKY0.YC (core 0)".to_string())),
        to_body: Some(IDENTITY),
        calibration: InForce::Undone(undone.words),
        notes,
        parameters,
        sha256,
        bytes,
    })
}
