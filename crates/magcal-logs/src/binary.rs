//! What the readers of binary flight logs ([`super::dataflash`], [`super::tlog`]) share: the file
//! read in chunks and hashed as it goes ([`Chunks`]), and the memory their readings and series
//! may hold ([`Budget`]).

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use anyhow::{Context, Result, bail};
use sha2::{Digest, Sha256};

use super::flight::Series;
use crate::limits;

/// Bytes read from the file at a time.
const CHUNK: usize = 1 << 20;

/// A file read front to back in chunks: the bytes from the current position are in
/// [`Chunks::window`], at least as many as the last [`Chunks::fill`] asked for (fewer only at the
/// end of the file). Every byte read is hashed.
pub struct Chunks {
    file: limits::Bounded,
    shown: String,
    buf: Vec<u8>,
    /// Index in `buf` of the current position.
    pos: usize,
    /// Bytes of `buf` that hold file data.
    end: usize,
    /// File offset of `buf[0]`.
    base: u64,
    hash: Sha256,
    eof: bool,
}

impl Chunks {
    /// Opens `path` (a directory is refused).
    ///
    /// # Errors
    /// A file that cannot be opened, or a directory.
    pub fn open(path: &Path) -> Result<Self> {
        let shown = path.display().to_string();
        Ok(Self {
            file: crate::limits::Bounded::open_log(path, &shown)?,
            shown,
            buf: vec![0; CHUNK],
            pos: 0,
            end: 0,
            base: 0,
            hash: Sha256::new(),
            eof: false,
        })
    }

    /// The file's offset of the current position.
    pub fn offset(&self) -> u64 {
        self.base + self.pos as u64
    }

    /// The bytes from the current position that are in memory.
    pub fn window(&self) -> &[u8] {
        &self.buf[self.pos..self.end]
    }

    /// Reads until at least `n` bytes (at most 1 MiB) from the current position are in
    /// memory, or the file ends; returns how many are.
    ///
    /// # Errors
    /// A read error, naming the file and the offset.
    pub fn fill(&mut self, n: usize) -> Result<usize> {
        debug_assert!(n <= CHUNK);
        if self.end - self.pos >= n || self.eof {
            return Ok(self.end - self.pos);
        }
        self.buf.copy_within(self.pos..self.end, 0);
        self.base += self.pos as u64;
        self.end -= self.pos;
        self.pos = 0;
        while self.end < n && !self.eof {
            let k = match self.file.read(&mut self.buf[self.end..]) {
                Ok(k) => k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) if e.get_ref().is_some_and(|r| r.is::<limits::StreamBound>()) => {
                    // The stream's bound: its own words name the file.
                    bail!("{e}");
                }
                Err(e) => {
                    return Err(e).with_context(|| {
                        format!("{}: cannot read at byte {}", self.shown, self.base + self.end as u64)
                    });
                }
            };
            self.hash.update(&self.buf[self.end..self.end + k]);
            self.end += k;
            self.eof = k == 0;
        }
        Ok(self.end)
    }

    /// Moves the current position `n` bytes on (within [`Self::window`]).
    pub fn advance(&mut self, n: usize) {
        assert!(n <= self.end - self.pos, "advance past the bytes in memory");
        self.pos += n;
    }

    /// Reads what is left (so that the hash covers the whole file) and returns the file's
    /// SHA-256 (lower-case hex) and size.
    ///
    /// # Errors
    /// A read error.
    pub fn finish(mut self) -> Result<(String, u64)> {
        self.pos = self.end;
        while !self.eof {
            self.fill(1)?;
            self.pos = self.end;
        }
        let size = self.offset();
        let hex = self.hash.finalize().iter().map(|b| format!("{b:02x}")).collect();
        Ok((hex, size))
    }
}

/// The memory a log's readings and series may take: half of what the process may use
/// ([`limits::available_memory`]). Every vector a reader fills grows through [`Budget::push`],
/// which refuses the growth that would pass the limit, before it is made.
pub struct Budget {
    limit: Option<(u64, u64, &'static str)>,
    used: u64,
}

impl Budget {
    /// Half of what the process may use.
    pub fn new() -> Self {
        Self::with_limit(limits::available_memory().map(|(a, what)| (a / 2, a, what)))
    }

    /// A budget of `limit` bytes (`None`: no limit), with the memory and its name it is half of.
    pub fn with_limit(limit: Option<(u64, u64, &'static str)>) -> Self {
        Self { limit, used: 0 }
    }

    /// Bytes held so far.
    pub fn used(&self) -> u64 {
        self.used
    }

    /// Pushes `x` onto `v`; when `v` is full, first checks that doubling it keeps within the
    /// budget.
    ///
    /// # Errors
    /// The growth would pass the limit: the error names the file, the byte offset reached and the
    /// limit.
    pub fn push<T>(&mut self, v: &mut Vec<T>, x: T, shown: &str, offset: u64) -> Result<()> {
        if v.len() == v.capacity() {
            let more = v.capacity().max(256);
            let bytes = (more * size_of::<T>()) as u64;
            if let Some((limit, available, what)) = self.limit
                && self.used + bytes > limit
            {
                bail!(
                    "{shown}: byte {offset}: the log holds more readings and series than fit in memory ({} held, {} more needed; the limit is {}, half of {} {what})",
                    limits::bytes(self.used),
                    limits::bytes(bytes),
                    limits::bytes(limit),
                    limits::bytes(available)
                );
            }
            v.reserve_exact(more);
            self.used += bytes;
        }
        v.push(x);
        Ok(())
    }
}

impl Default for Budget {
    fn default() -> Self {
        Self::new()
    }
}

/// Unit quaternion `[w, x, y, z]` (Hamilton, `w >= 0`) of the rotation `Rz(yaw) Ry(pitch)
/// Rx(roll)` (radians): body (forward, right, down) into north, east, down, the autopilots' Euler
/// angles (ArduPilot `ATT`, MAVLink `ATTITUDE`).
pub fn quaternion_of_euler(roll: f64, pitch: f64, yaw: f64) -> [f64; 4] {
    let (sr, cr) = (roll / 2.0).sin_cos();
    let (sp, cp) = (pitch / 2.0).sin_cos();
    let (sy, cy) = (yaw / 2.0).sin_cos();
    let q = [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ];
    if q[0] < 0.0 { q.map(|v| -v) } else { q }
}

/// Whether a series takes a value at time `t`: `t` is finite and not before the series' last time
/// (a time that goes back is a reboot or a damaged message).
pub fn in_order(last: Option<f64>, t: f64) -> bool {
    t.is_finite() && last.is_none_or(|last| t >= last)
}

/// Readings and values a reader dropped, by message: a time that went back, or a value that is
/// not a finite number.
#[derive(Debug, Default)]
pub struct Dropped {
    pub out_of_order: BTreeMap<&'static str, u64>,
    pub not_finite: BTreeMap<&'static str, u64>,
}

impl Dropped {
    /// One sentence per kind, for the notes.
    pub fn notes(&self) -> Vec<String> {
        let list = |m: &BTreeMap<&str, u64>| m.iter().map(|(k, n)| format!("{n} {k}")).collect::<Vec<_>>().join(", ");
        let mut out = Vec::new();
        if !self.out_of_order.is_empty() {
            out.push(format!(
                "Skipped messages whose time goes back (a reboot or damage): {}.",
                list(&self.out_of_order)
            ));
        }
        if !self.not_finite.is_empty() {
            out.push(format!(
                "Skipped messages with values that are not finite numbers: {}.",
                list(&self.not_finite)
            ));
        }
        out
    }
}

/// Opens `path`, parses it front to back into a `P` with `parse` (given the chunks and the path as
/// shown), reads what is left so that the hash covers the whole file, and hands the `P`, the
/// file's SHA-256 and its size to `assemble`.
///
/// # Errors
/// The file cannot be read, or `parse` or `assemble` fails.
pub fn read_file<P: Default>(
    path: &Path,
    parse: impl FnOnce(&mut Chunks, &str, &mut P) -> Result<()>,
    assemble: impl FnOnce(P, &str, String, u64) -> Result<super::flight::FlightLog>,
) -> Result<super::flight::FlightLog> {
    let shown = path.display().to_string();
    let mut chunks = Chunks::open(path)?;
    let mut parsed = P::default();
    parse(&mut chunks, &shown, &mut parsed)?;
    let (sha256, bytes) = chunks.finish()?;
    assemble(parsed, &shown, sha256, bytes)
}

/// Takes the readings of the asked instance (the lowest where none is asked) from `kept`, the
/// instances whose readings were kept; `seen` are instances met but not kept, `messages` names the
/// messages that carry readings. Returns the instances the log has, ascending, the instance
/// taken and its readings.
///
/// # Errors
/// No readings at all, or none of the asked instance.
pub fn take_instance<T>(
    mut kept: BTreeMap<u8, T>,
    seen: &[u8],
    selection: &super::flight::Selection,
    shown: &str,
    messages: &str,
) -> Result<(Vec<u8>, u8, T)> {
    let mut instances: Vec<u8> = kept.keys().copied().chain(seen.iter().copied()).collect();
    instances.sort_unstable();
    instances.dedup();
    let Some(k) = selection.instance.or(instances.first().copied()) else {
        bail!("{shown}: no magnetometer readings (no {messages} messages)");
    };
    let Some(readings) = kept.remove(&k) else {
        let has: Vec<String> = instances.iter().map(u8::to_string).collect();
        let has = if has.is_empty() {
            "none".to_string()
        } else {
            has.join(", ")
        };
        bail!("{shown}: --compass {k}: the log has no readings of magnetometer {k}; it has {has}");
    };
    Ok((instances, k, readings))
}

/// Bytes a reader skipped because they were not what the format puts there, in runs.
#[derive(Debug, Default)]
pub struct Skipped {
    bytes: u64,
    runs: u64,
    first: Option<u64>,
    end: u64,
}

impl Skipped {
    /// `n` bytes skipped from byte `offset`; a run goes on where the last one ended.
    pub fn skip(&mut self, offset: u64, n: usize) {
        if self.first.is_none() || offset != self.end {
            self.runs += 1;
        }
        self.first.get_or_insert(offset);
        self.bytes += n as u64;
        self.end = offset + n as u64;
    }

    /// The note on what was skipped (`what`: "messages", "records"), if anything was.
    pub fn note(&self, what: &str) -> Option<String> {
        self.first.map(|at| {
            format!(
                "Skipped {} bytes that are not {what}, in {} places from byte {at} on (damaged or partly written).",
                self.bytes, self.runs
            )
        })
    }
}

/// Where a reader is: the file as shown, the byte offset of the message, and the budget.
pub struct At<'a> {
    pub shown: &'a str,
    pub offset: u64,
    pub budget: &'a mut Budget,
    pub dropped: &'a mut Dropped,
}

impl At<'_> {
    /// Appends `(t, v)` to `series` where `t` keeps it in order and `finite`, else counts it
    /// under `name`.
    ///
    /// # Errors
    /// The series would pass the memory budget.
    pub fn push_series<T>(
        &mut self,
        series: &mut Series<T>,
        t: f64,
        v: T,
        finite: bool,
        name: &'static str,
    ) -> Result<()> {
        if !finite {
            *self.dropped.not_finite.entry(name).or_default() += 1;
        } else if !in_order(series.times.last().copied(), t) {
            *self.dropped.out_of_order.entry(name).or_default() += 1;
        } else {
            self.budget.push(&mut series.times, t, self.shown, self.offset)?;
            self.budget.push(&mut series.values, v, self.shown, self.offset)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_hash_the_whole_file_and_give_every_byte_once() {
        let dir = tempfile::TempDir::new().unwrap();
        let p = dir.path().join("f");
        let data: Vec<u8> = (0..(3 * CHUNK + 17)).map(|i| (i * 7 % 251) as u8).collect();
        std::fs::write(&p, &data).unwrap();
        let mut c = Chunks::open(&p).unwrap();
        let mut seen = Vec::new();
        // Odd steps across chunk boundaries.
        loop {
            let n = c.fill(1000).unwrap();
            if n == 0 {
                break;
            }
            let k = n.min(997);
            seen.extend_from_slice(&c.window()[..k]);
            c.advance(k);
        }
        assert_eq!(seen, data);
        let (hex, size) = c.finish().unwrap();
        assert_eq!(size, data.len() as u64);
        assert_eq!(hex, crate::digest::sha256_hex(&data));
        // Finishing early still hashes everything.
        let c = Chunks::open(&p).unwrap();
        assert_eq!(c.finish().unwrap().0, crate::digest::sha256_hex(&data));
    }

    #[test]
    fn the_budget_refuses_growth_past_its_limit() {
        let mut b = Budget::with_limit(Some((4096, 8192, "test memory")));
        let mut v: Vec<u64> = Vec::new();
        // 256 u64 = 2048 bytes: the first growth fits, the second (another 2048) fits exactly,
        // the third does not.
        for i in 0..512 {
            b.push(&mut v, i, "f", i).unwrap();
        }
        assert_eq!(b.used(), 4096);
        let e = b.push(&mut v, 0, "f.bin", 99).unwrap_err().to_string();
        assert!(e.starts_with("f.bin: byte 99: the log holds more"), "{e}");
        assert_eq!(v.len(), 512);
    }

    #[test]
    fn euler_quaternions_compose_the_axis_rotations() {
        // q = qz(yaw) qy(pitch) qx(roll), each a half-angle axis quaternion.
        fn mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
            [
                a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
            ]
        }
        for &(r, p, y) in &[(0.1, -0.4, 2.9), (-2.0, 1.2, -0.3), (3.0, 0.0, 6.0)] {
            let qx = [(r / 2.0f64).cos(), (r / 2.0f64).sin(), 0.0, 0.0];
            let qy = [(p / 2.0f64).cos(), 0.0, (p / 2.0f64).sin(), 0.0];
            let qz = [(y / 2.0f64).cos(), 0.0, 0.0, (y / 2.0f64).sin()];
            let mut want = mul(qz, mul(qy, qx));
            if want[0] < 0.0 {
                want = want.map(|v| -v);
            }
            let got = quaternion_of_euler(r, p, y);
            for k in 0..4 {
                assert!((got[k] - want[k]).abs() < 4.0 * f64::EPSILON, "{got:?} {want:?}");
            }
        }
    }
}
