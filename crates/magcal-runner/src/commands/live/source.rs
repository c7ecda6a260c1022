//! Where `live` reads: a MAVLink stream (UDP, TCP, a serial device) or a stream of text lines
//! (MotionCal's `Raw:` lines from the Adafruit calibration sketch, or CSV rows) from a device, a
//! file or standard input. A reader thread per source turns what arrives into records (a
//! telemetry log's records, or CSV rows) in the shared [`Ring`], and into the `--record` file.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs, UdpSocket};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant, SystemTime};

#[cfg(not(unix))]
use anyhow::bail;
use anyhow::{Context, Result};

use super::buffer::Ring;
use crate::log::tlog::{Framer, record};
use crate::scenario::site::Units;

/// `PARAM_VALUE`'s message id: a vehicle's parameters are sent once, when a ground station asks,
/// and must outlive the ring.
const PARAM_VALUE: u32 = 22;
/// `HEARTBEAT`'s message id: the autopilot's says which system to send parameters to.
const HEARTBEAT: u32 = 0;
/// The compass messages a vehicle streams: `RAW_IMU`, `SCALED_IMU2`, `SCALED_IMU3`.
const IMU: [u32; 3] = [27, 116, 129];
/// The longest text line taken, bytes; a longer one is counted as malformed.
const MAX_LINE: usize = 4096;
/// How often a waiting reader looks whether the command is ending.
const POLL: Duration = Duration::from_millis(200);

/// A source as the command line names it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Source {
    /// MAVLink datagrams received on this address (`udpin:ADDR:PORT`).
    Udp(String),
    /// MAVLink from a TCP server (`tcp:HOST:PORT`: SITL's 5760, a telemetry bridge).
    Tcp(String),
    /// MAVLink on a serial device at a baud rate (`serial:PATH:BAUD`).
    Serial(PathBuf, u32),
    /// Text lines from a device (at a baud rate), a file, or standard input (`-`)
    /// (`lines:PATH[:BAUD]`).
    Lines(PathBuf, Option<u32>),
}

impl std::str::FromStr for Source {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let baud = |b: &str| {
            b.parse::<u32>()
                .ok()
                .filter(|b| (50..=4_000_000).contains(b))
                .ok_or_else(|| format!("{s}: the baud rate {b:?} is not a number from 50 to 4000000"))
        };
        let path_baud = |rest: &str| match rest.rsplit_once(':') {
            Some((p, b)) if !p.is_empty() && b.bytes().all(|c| c.is_ascii_digit()) && !b.is_empty() => {
                baud(b).map(|b| (PathBuf::from(p), Some(b)))
            }
            _ => Ok((PathBuf::from(rest), None)),
        };
        if s == "-" {
            return Ok(Self::Lines(PathBuf::from("-"), None));
        }
        let (kind, rest) = s.split_once(':').ok_or_else(|| {
            format!("{s}: give udpin:ADDR:PORT, tcp:HOST:PORT, serial:PATH:BAUD, lines:PATH[:BAUD] or - (lines on standard input)")
        })?;
        if rest.is_empty() {
            return Err(format!("{s}: nothing after {kind}:"));
        }
        match kind {
            "udpin" | "udp" => Ok(Self::Udp(rest.to_string())),
            "tcp" | "tcpout" => Ok(Self::Tcp(rest.to_string())),
            "serial" => match path_baud(rest)? {
                (p, Some(b)) => Ok(Self::Serial(p, b)),
                (_, None) => Err(format!("{s}: give the baud rate, serial:PATH:BAUD")),
            },
            "lines" => path_baud(rest).map(|(p, b)| Self::Lines(p, b)),
            _ => Err(format!(
                "{s}: unknown source kind {kind:?}: udpin, tcp, serial or lines (or - for lines on standard input)"
            )),
        }
    }
}

impl Source {
    /// Whether the source carries MAVLink (a telemetry log) rather than lines (a CSV log).
    pub fn is_mavlink(&self) -> bool {
        !matches!(self, Self::Lines(..))
    }
}

/// What arrived, and what became of it.
#[derive(Debug, Default, Clone)]
pub struct Counts {
    /// Bytes received.
    pub bytes: u64,
    /// MAVLink frames whose checksum held, frames whose checksum failed, frames of messages the
    /// dialect does not know, bytes outside any frame.
    pub frames: u64,
    pub bad_crc: u64,
    pub unknown: u64,
    pub between: u64,
    /// Lines taken as readings, lines that were not a reading, lines too long or with a
    /// `Raw:` that does not hold nine integers.
    pub lines: u64,
    pub other_lines: u64,
    pub malformed_lines: u64,
    /// When the last bytes arrived.
    pub last: Option<Instant>,
    /// UDP datagrams from another address than the vehicle's once it is known, and frames in the
    /// name of a system first heard from another address: counted, kept out of the fits and the
    /// recording, never answered.
    pub foreign: u64,
}

/// What was heard of one system and component on a MAVLink source.
#[derive(Debug, Clone, Default)]
pub struct Heard {
    /// Its order of first appearance.
    pub first: usize,
    /// Its `HEARTBEAT`'s autopilot type (`MAV_AUTOPILOT`) where it is an autopilot's.
    pub autopilot: Option<u8>,
    /// Compass frames (`RAW_IMU`, `SCALED_IMU2`, `SCALED_IMU3`).
    pub imu: u64,
    /// The address of its first datagram (UDP).
    pub addr: Option<SocketAddr>,
    /// Its parameters: each one's last value with its arrival.
    pub params: BTreeMap<String, (f32, Instant)>,
}

/// The state the reader and the fit share.
#[derive(Debug)]
pub struct State {
    pub ring: Ring,
    pub counts: Counts,
    /// Written before the records of a snapshot: a CSV header (empty for MAVLink).
    pub head: Vec<u8>,
    /// Set when the source ended: `Ok` at its end, `Err` with why it failed.
    pub ended: Option<Result<(), String>>,
    /// The readings' units where the lines fix them (MotionCal's `Raw:` lines: uT).
    pub units: Option<Units>,
    /// MAVLink: every system and component heard; the vehicle (`--vehicle`, else the first
    /// autopilot whose `HEARTBEAT` came with compass frames); the one `--vehicle` asks for.
    pub heard: BTreeMap<(u8, u8), Heard>,
    pub vehicle: Option<(u8, u8)>,
    pub wanted: Option<(u8, Option<u8>)>,
    /// What was asked of the autopilots ([`super::ask`]).
    pub asked: super::ask::Asked,
}

impl State {
    /// The vehicle's address (UDP): where its first datagram came from.
    pub fn peer(&self) -> Option<SocketAddr> {
        self.vehicle.and_then(|v| self.heard.get(&v)).and_then(|h| h.addr)
    }

    /// The vehicle's parameters (none while it is unknown).
    pub fn params(&self) -> Option<&BTreeMap<String, (f32, Instant)>> {
        self.vehicle.and_then(|v| self.heard.get(&v)).map(|h| &h.params)
    }

    /// Whether `id` is the one `--vehicle` asks for (any, without it).
    pub fn wanted(&self, id: (u8, u8)) -> bool {
        self.wanted
            .is_none_or(|(s, c)| s == id.0 && c.is_none_or(|c| c == id.1))
    }

    /// The autopilots heard that `--vehicle` allows, in order of first appearance.
    pub fn autopilots(&self) -> Vec<(u8, u8)> {
        let mut a: Vec<(&(u8, u8), &Heard)> = self
            .heard
            .iter()
            .filter(|(id, h)| h.autopilot.is_some() && self.wanted(**id))
            .collect();
        a.sort_by_key(|(_, h)| h.first);
        a.into_iter().map(|(id, _)| *id).collect()
    }

    /// Autopilots with compass frames other than the vehicle, where `--vehicle` did not choose
    /// it: a vehicle chosen by arrival alone cannot be sent parameters.
    pub fn contested(&self) -> Vec<(u8, u8)> {
        if self.wanted.is_some() {
            return Vec::new();
        }
        self.autopilots()
            .into_iter()
            .filter(|id| Some(*id) != self.vehicle && self.heard[id].imu > 0)
            .collect()
    }
}

/// The shared state and the signal of new records.
#[derive(Debug)]
pub struct Shared {
    state: Mutex<State>,
    pub changed: Condvar,
    /// Set by the command when it ends (Ctrl-C, usable with `--until-usable`).
    pub stop: AtomicBool,
}

impl Shared {
    pub fn new(capacity: usize) -> Arc<Self> {
        Arc::new(Self {
            state: Mutex::new(State {
                ring: Ring::new(capacity),
                counts: Counts::default(),
                head: Vec::new(),
                ended: None,
                units: None,
                heard: BTreeMap::new(),
                vehicle: None,
                wanted: None,
                asked: super::ask::Asked::default(),
            }),
            changed: Condvar::new(),
            stop: AtomicBool::new(false),
        })
    }

    /// The state, locked (a reader that panicked leaves it as it was).
    pub fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn stopping(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    fn end(&self, how: Result<(), String>) {
        self.lock().ended.get_or_insert(how);
        self.changed.notify_all();
    }
}

/// The sending end of a MAVLink source.
pub enum Link {
    /// The UDP socket: parameters go to the address the vehicle's frames came from.
    Udp(UdpSocket),
    Tcp(TcpStream),
    /// A serial device opened for writing.
    Serial(std::fs::File),
}

impl Link {
    /// Writes `bytes` to the vehicle (over UDP, to `peer`).
    ///
    /// # Errors
    /// No peer yet (UDP), or the write fails.
    pub fn send(&mut self, bytes: &[u8], peer: Option<SocketAddr>) -> Result<()> {
        match self {
            Self::Udp(s) => {
                let peer = peer.context("no frame came from the vehicle's address yet")?;
                s.send_to(bytes, peer)?;
            }
            Self::Tcp(s) => s.write_all(bytes)?,
            Self::Serial(f) => f.write_all(bytes)?,
        }
        Ok(())
    }
}

/// The reader started, what it reads in words (a UDP source with the port it was bound to), and
/// the sending end of a MAVLink source.
pub struct Started {
    pub reader: std::thread::JoinHandle<()>,
    pub reading: String,
    pub link: Option<Link>,
}

/// Opens `source` (binding, connecting or opening it: its errors come back here) and starts its
/// reader, which writes every record it keeps to `record` as well.
///
/// # Errors
/// An address that does not resolve or cannot be bound or reached, a device or file that cannot
/// be opened or set to its baud rate.
pub fn start(source: &Source, shared: &Arc<Shared>, record: Option<File>) -> Result<Started> {
    let recorder = record.map(BufWriter::new);
    let shared2 = Arc::clone(shared);
    let mut shown = shown(source);
    let mut link = None;
    let input: Box<dyn Input> = match source {
        Source::Udp(addr) => {
            let addr = resolve(addr)?;
            let socket = UdpSocket::bind(addr).with_context(|| format!("{shown}: binding {addr}"))?;
            socket.set_read_timeout(Some(POLL))?;
            shown = format!("udpin:{}", socket.local_addr()?);
            link = Some(Link::Udp(socket.try_clone()?));
            Box::new(Udp { socket, peer: None })
        }
        Source::Tcp(addr) => {
            let addr = resolve(addr)?;
            let stream = TcpStream::connect_timeout(&addr, Duration::from_secs(10))
                .with_context(|| format!("{shown}: connecting to {addr}"))?;
            stream.set_read_timeout(Some(POLL))?;
            link = Some(Link::Tcp(stream.try_clone()?));
            Box::new(stream)
        }
        Source::Serial(path, baud) => {
            let device = open_device(path, Some(*baud), &shown, true)?;
            link = Some(Link::Serial(device.try_clone()?));
            Box::new(device)
        }
        Source::Lines(path, baud) if path.as_os_str() == "-" && baud.is_none() => Box::new(std::io::stdin()),
        Source::Lines(path, baud) => Box::new(open_device(path, *baud, &shown, false)?),
    };
    let mavlink = source.is_mavlink();
    let reading = shown.clone();
    let reader = std::thread::Builder::new()
        .name("magcal-live-reader".into())
        .spawn(move || {
            let how = if mavlink {
                read_mavlink(input, &shared2, recorder)
            } else {
                read_lines(input, &shared2, recorder)
            };
            shared2.end(how.map_err(|e| format!("{shown}: {e:#}")));
        })
        .context("starting the reader")?;
    Ok(Started { reader, reading, link })
}

/// The source as the messages name it.
pub fn shown(source: &Source) -> String {
    match source {
        Source::Udp(a) => format!("udpin:{a}"),
        Source::Tcp(a) => format!("tcp:{a}"),
        Source::Serial(p, b) => format!("serial:{}:{b}", p.display()),
        Source::Lines(p, _) if p.as_os_str() == "-" => "standard input".to_string(),
        Source::Lines(p, Some(b)) => format!("lines:{}:{b}", p.display()),
        Source::Lines(p, None) => format!("lines:{}", p.display()),
    }
}

fn resolve(addr: &str) -> Result<SocketAddr> {
    addr.to_socket_addrs()
        .with_context(|| format!("{addr}: not an address HOST:PORT"))?
        .next()
        .with_context(|| format!("{addr}: resolves to no address"))
}

/// A device or file (for writing too with `write`), set raw at `baud` where one is given.
fn open_device(path: &std::path::Path, baud: Option<u32>, shown: &str, write: bool) -> Result<File> {
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(write)
        .open(path)
        .with_context(|| format!("{shown}: opening {}", path.display()))?;
    if let Some(baud) = baud {
        set_baud(&file, baud).with_context(|| format!("{shown}: setting {} to {baud} baud", path.display()))?;
    }
    Ok(file)
}

#[cfg(unix)]
fn set_baud(file: &File, baud: u32) -> Result<()> {
    use rustix::termios::{OptionalActions, tcgetattr, tcsetattr};
    let mut t = tcgetattr(file).context("not a terminal device")?;
    t.make_raw();
    t.set_speed(baud)?;
    tcsetattr(file, OptionalActions::Now, &t)?;
    Ok(())
}

#[cfg(not(unix))]
fn set_baud(_file: &File, _baud: u32) -> Result<()> {
    bail!("a baud rate is set on Unix only: open the port at its rate with another tool and give lines:PATH")
}

/// Bytes from a source: `Ok(None)` when nothing arrived within [`POLL`], `Ok(Some(0))` at its
/// end.
trait Input: Send {
    fn next(&mut self, buf: &mut [u8]) -> std::io::Result<Option<usize>>;

    /// Where the last bytes came from (a UDP source).
    fn peer(&self) -> Option<SocketAddr> {
        None
    }
}

/// A UDP source and the address of its last datagram.
struct Udp {
    socket: UdpSocket,
    peer: Option<SocketAddr>,
}

fn timed_out(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
    )
}

impl Input for Udp {
    fn next(&mut self, buf: &mut [u8]) -> std::io::Result<Option<usize>> {
        match self.socket.recv_from(buf) {
            // An empty datagram is not the end of a UDP source, which has none.
            Ok((n, from)) => {
                self.peer = Some(from);
                Ok((n > 0).then_some(n))
            }
            Err(e) if timed_out(&e) => Ok(None),
            Err(e) => Err(e),
        }
    }

    fn peer(&self) -> Option<SocketAddr> {
        self.peer
    }
}

impl Input for TcpStream {
    fn next(&mut self, buf: &mut [u8]) -> std::io::Result<Option<usize>> {
        match self.read(buf) {
            Ok(n) => Ok(Some(n)),
            Err(e) if timed_out(&e) => Ok(None),
            Err(e) => Err(e),
        }
    }
}

impl Input for File {
    fn next(&mut self, buf: &mut [u8]) -> std::io::Result<Option<usize>> {
        match self.read(buf) {
            Ok(n) => Ok(Some(n)),
            Err(e) if e.kind() == ErrorKind::Interrupted => Ok(None),
            // A pseudo-terminal whose other end closed reads EIO: its end.
            Err(e) if e.raw_os_error() == Some(5) => Ok(Some(0)),
            Err(e) => Err(e),
        }
    }
}

impl Input for std::io::Stdin {
    fn next(&mut self, buf: &mut [u8]) -> std::io::Result<Option<usize>> {
        match self.read(buf) {
            Ok(n) => Ok(Some(n)),
            Err(e) if e.kind() == ErrorKind::Interrupted => Ok(None),
            Err(e) => Err(e),
        }
    }
}

/// Microseconds since 1970 now, a telemetry log's reception stamp.
fn now_us() -> u64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX))
}

/// Reads MAVLink until the source ends or the command stops: each valid frame a telemetry
/// log's record, `PARAM_VALUE` pinned by its name.
fn read_mavlink(mut input: Box<dyn Input>, shared: &Shared, mut recorder: Option<BufWriter<File>>) -> Result<()> {
    let mut framer = Framer::default();
    let mut buf = vec![0u8; 1 << 16];
    while !shared.stopping() {
        let Some(n) = input.next(&mut buf)? else { continue };
        if n == 0 {
            return Ok(());
        }
        let stamp = now_us();
        let from = input.peer();
        {
            // A datagram from elsewhere than the vehicle, once it is known, is counted and no more.
            let mut state = shared.lock();
            if from.is_some() && state.peer().is_some() && from != state.peer() {
                state.counts.foreign += 1;
                state.counts.bytes += n as u64;
                continue;
            }
        }
        let mut frames = Vec::new();
        framer.push(&buf[..n], |frame, id| {
            let ids = sender(frame);
            // Parameters are pinned by their system, component and name.
            let pin = (id == PARAM_VALUE).then(|| [&[ids.0, ids.1][..], &param_name(frame)].concat());
            frames.push((ids, heard_of(frame, id), record(stamp, frame), pin));
        });
        let mut state = shared.lock();
        let now = Instant::now();
        let mut records = Vec::with_capacity(frames.len());
        for (ids, what, r, pin) in frames {
            if hear(&mut state, ids, what, from, now) {
                records.push((r, pin));
            } else {
                state.counts.foreign += 1;
            }
        }
        // The recording is written after the state is released: a reader that waits on the disk
        // under the lock would hold up the fits, and a fit the reader (datagrams dropped).
        let recorded: Vec<Vec<u8>> = if recorder.is_some() {
            records.iter().map(|(r, _)| r.clone()).collect()
        } else {
            Vec::new()
        };
        if state.vehicle.is_none() {
            state.vehicle = state.autopilots().into_iter().find(|id| state.heard[id].imu > 0);
        }
        let c = &mut state.counts;
        c.bytes += n as u64;
        c.last = Some(now);
        (c.frames, c.bad_crc, c.unknown, c.between) = (framer.valid, framer.bad_crc, framer.unknown, framer.between);
        for (r, pin) in records {
            state.ring.push(r, pin);
        }
        drop(state);
        shared.changed.notify_all();
        if let Some(w) = recorder.as_mut() {
            for r in &recorded {
                w.write_all(r).context("--record")?;
            }
            w.flush().context("--record")?;
        }
    }
    Ok(())
}

/// The payload of a frame, with the zeros a MAVLink 2 frame may have cut from its end put back
/// up to `len` bytes.
fn payload(frame: &[u8], len: usize) -> Vec<u8> {
    let header = if frame.first() == Some(&0xFD) { 10 } else { 6 };
    let n = usize::from(frame.get(1).copied().unwrap_or(0));
    let mut p = frame.get(header..header + n).unwrap_or_default().to_vec();
    p.resize(p.len().max(len), 0);
    p
}

/// The value of a `PARAM_VALUE` frame.
fn param_value(frame: &[u8]) -> f32 {
    let p = payload(frame, 4);
    f32::from_le_bytes([p[0], p[1], p[2], p[3]])
}

/// The system and component that sent a frame.
fn sender(frame: &[u8]) -> (u8, u8) {
    if frame.first() == Some(&0xFD) {
        (frame[5], frame[6])
    } else {
        (frame[3], frame[4])
    }
}

/// What one frame says of its sender.
enum Said {
    /// A `HEARTBEAT` of an autopilot (`MAV_AUTOPILOT`), or of a ground station (`None`:
    /// `MAV_AUTOPILOT_INVALID`).
    Heartbeat(Option<u8>),
    Imu,
    Param(String, f32),
    Other,
}

fn heard_of(frame: &[u8], id: u32) -> Said {
    const INVALID: u8 = 8;
    match id {
        HEARTBEAT => {
            let autopilot = payload(frame, 9)[5];
            Said::Heartbeat((autopilot != INVALID).then_some(autopilot))
        }
        PARAM_VALUE => Said::Param(
            String::from_utf8_lossy(&param_name(frame)).into_owned(),
            param_value(frame),
        ),
        _ if IMU.contains(&id) => Said::Imu,
        _ => Said::Other,
    }
}

/// Adds what a frame of `ids` said, from the address `from`, to the state; `false` (nothing
/// added) when that system and component were first heard from another address: a frame in
/// their name from elsewhere.
fn hear(state: &mut State, ids: (u8, u8), what: Said, from: Option<SocketAddr>, now: Instant) -> bool {
    let n = state.heard.len();
    let h = state.heard.entry(ids).or_insert_with(|| Heard {
        first: n,
        addr: from,
        ..Heard::default()
    });
    if h.addr != from {
        return false;
    }
    match what {
        Said::Heartbeat(a) => h.autopilot = h.autopilot.or(a),
        Said::Imu => h.imu += 1,
        Said::Param(name, value) => {
            h.params.insert(name, (value, now));
        }
        Said::Other => {}
    }
    true
}

/// The name of the parameter of a `PARAM_VALUE` frame (its key among the pinned records).
fn param_name(frame: &[u8]) -> Vec<u8> {
    let header = if frame.first() == Some(&0xFD) { 10 } else { 6 };
    // param_value (4 bytes), param_count, param_index (2 each), then the 16-byte name; a v2
    // frame may end its payload early (trailing zeros dropped).
    let start = (header + 8).min(frame.len());
    let end = (header + 24).min(frame.len().saturating_sub(2)).max(start);
    let name = &frame[start..end];
    let cut = name.iter().position(|&b| b == 0).unwrap_or(name.len());
    name[..cut].to_vec()
}

/// How the lines of a source are read: decided by its first line that is not empty.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LineKind {
    /// MotionCal's `Raw:ax,ay,az,gx,gy,gz,mx,my,mz` (integers; the magnetometer in 0.1 uT),
    /// written as CSV rows `mx,my,mz` in uT.
    Raw,
    /// CSV rows as they come; a first row with a cell that is not a number is the header.
    Csv,
}

/// Reads lines until the source ends or the command stops.
fn read_lines(mut input: Box<dyn Input>, shared: &Shared, mut recorder: Option<BufWriter<File>>) -> Result<()> {
    let mut buf = vec![0u8; 1 << 14];
    let mut line: Vec<u8> = Vec::new();
    let mut too_long = false;
    let mut kind = None;
    let mut pending = None;
    while !shared.stopping() {
        let Some(n) = input.next(&mut buf)? else { continue };
        if n == 0 {
            break;
        }
        let mut taken: Vec<(Vec<u8>, Option<Vec<u8>>)> = Vec::new();
        let mut counts = (0u64, 0u64, 0u64);
        let mut head = None;
        for &b in &buf[..n] {
            if b != b'\n' {
                if line.len() < MAX_LINE {
                    line.push(b);
                } else {
                    too_long = true;
                }
                continue;
            }
            if too_long {
                counts.2 += 1;
            } else {
                take_line(&line, (&mut kind, &mut pending), &mut taken, &mut counts, &mut head);
            }
            line.clear();
            too_long = false;
        }
        deliver(shared, recorder.as_mut(), kind, (head, taken, counts), n)?;
    }
    // A stream of one line: it decides alone.
    if let Some(first) = pending.take() {
        let (mut taken, mut counts, mut head) = (Vec::new(), (0, 0, 0), None);
        take_decided(
            &String::from_utf8_lossy(&first),
            None,
            &mut kind,
            &mut taken,
            &mut counts,
            &mut head,
        );
        deliver(shared, recorder.as_mut(), kind, (head, taken, counts), 0)?;
    }
    // A last line without its end is counted, not taken: it may be cut.
    if !line.is_empty() || too_long {
        shared.lock().counts.malformed_lines += 1;
    }
    Ok(())
}

/// What lines of `bytes` bytes gave (the header, the readings, the counts of readings, other
/// and malformed lines): recorded, then into the ring and the counts.
type Lines = (Option<Vec<u8>>, Vec<(Vec<u8>, Option<Vec<u8>>)>, (u64, u64, u64));

fn deliver(
    shared: &Shared,
    recorder: Option<&mut BufWriter<File>>,
    kind: Option<LineKind>,
    (head, taken, counts): Lines,
    bytes: usize,
) -> Result<()> {
    if let Some(w) = recorder {
        if let Some(h) = &head {
            w.write_all(h).context("--record")?;
        }
        for (r, _) in &taken {
            w.write_all(r).context("--record")?;
        }
        w.flush().context("--record")?;
    }
    let mut state = shared.lock();
    if let Some(h) = head {
        state.head = h;
        if kind == Some(LineKind::Raw) {
            state.units = Some(Units::MicroTesla);
        }
    }
    let c = &mut state.counts;
    c.bytes += bytes as u64;
    if bytes > 0 {
        c.last = Some(Instant::now());
    }
    c.lines += counts.0;
    c.other_lines += counts.1;
    c.malformed_lines += counts.2;
    for (r, pin) in taken {
        state.ring.push(r, pin);
    }
    drop(state);
    shared.changed.notify_all();
    Ok(())
}

/// One line: a reading (`taken`), the CSV header (`head`), or counted as another line or a
/// malformed one (`counts`: readings, other, malformed). The kind of the stream is decided by
/// its first two lines: a first line without a tag is held (`pending`), since a device opened
/// in the middle of a line gives the cut end of one; a `Raw:` line after it makes the stream
/// MotionCal's and the held line a malformed one, anything else makes it CSV.
fn take_line(
    line: &[u8],
    (kind, pending): (&mut Option<LineKind>, &mut Option<Vec<u8>>),
    taken: &mut Vec<(Vec<u8>, Option<Vec<u8>>)>,
    counts: &mut (u64, u64, u64),
    head: &mut Option<Vec<u8>>,
) {
    let text = String::from_utf8_lossy(line);
    let text = text.trim();
    if text.is_empty() {
        return;
    }
    // A line of the sketch's other kinds (`Uni:`, `Cal1:`) decides nothing.
    let tag = text.split_once(':').map(|(t, _)| t).filter(|t| {
        t.chars().next().is_some_and(|c| c.is_ascii_alphabetic()) && t.chars().all(|c| c.is_ascii_alphanumeric())
    });
    if kind.is_none() && tag.is_some_and(|t| t != "Raw") {
        counts.1 += 1;
        return;
    }
    if kind.is_none() {
        match pending.take() {
            None if tag.is_none() => {
                *pending = Some(text.as_bytes().to_vec());
                return;
            }
            Some(_) if tag == Some("Raw") => counts.2 += 1,
            Some(first) => take_decided(&String::from_utf8_lossy(&first), None, kind, taken, counts, head),
            None => {}
        }
    }
    take_decided(text, tag, kind, taken, counts, head);
}

/// [`take_line`] of a line whose tag is known, deciding the stream's kind where it is not yet.
fn take_decided(
    text: &str,
    tag: Option<&str>,
    kind: &mut Option<LineKind>,
    taken: &mut Vec<(Vec<u8>, Option<Vec<u8>>)>,
    counts: &mut (u64, u64, u64),
    head: &mut Option<Vec<u8>>,
) {
    let first = kind.is_none();
    let k = *kind.get_or_insert_with(|| {
        if tag == Some("Raw") {
            *head = Some(b"mx,my,mz\n".to_vec());
            LineKind::Raw
        } else {
            LineKind::Csv
        }
    });
    match k {
        LineKind::Raw => match text.strip_prefix("Raw:") {
            Some(rest) => match raw_uT(rest) {
                Some(m) => {
                    taken.push((format!("{},{},{}\n", m[0], m[1], m[2]).into_bytes(), None));
                    counts.0 += 1;
                }
                None => counts.2 += 1,
            },
            None => counts.1 += 1,
        },
        LineKind::Csv if tag.is_some() => counts.1 += 1,
        LineKind::Csv => {
            let mut row = text.as_bytes().to_vec();
            row.push(b'\n');
            if first && text.split(',').any(|c| c.trim().parse::<f64>().is_err()) {
                *head = Some(row);
            } else {
                taken.push((row, None));
                counts.0 += 1;
            }
        }
    }
}

/// The magnetometer of a MotionCal `Raw:` line (after `Raw:`), in uT: nine integers, the last
/// three in 0.1 uT.
#[allow(non_snake_case)]
fn raw_uT(rest: &str) -> Option<[f64; 3]> {
    let cells: Vec<i64> = rest
        .split(',')
        .map(|c| c.trim().parse::<i64>())
        .collect::<Result<_, _>>()
        .ok()?;
    if cells.len() != 9 {
        return None;
    }
    Some([cells[6], cells[7], cells[8]].map(|v| v as f64 / 10.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sources_are_parsed_and_bad_ones_named() {
        assert_eq!(
            "udpin:127.0.0.1:14550".parse(),
            Ok(Source::Udp("127.0.0.1:14550".into()))
        );
        assert_eq!("tcp:localhost:5760".parse(), Ok(Source::Tcp("localhost:5760".into())));
        assert_eq!(
            "serial:/dev/ttyUSB0:57600".parse(),
            Ok(Source::Serial(PathBuf::from("/dev/ttyUSB0"), 57600))
        );
        assert_eq!(
            "lines:/dev/ttyACM0:115200".parse(),
            Ok(Source::Lines(PathBuf::from("/dev/ttyACM0"), Some(115_200)))
        );
        assert_eq!(
            "lines:log.csv".parse(),
            Ok(Source::Lines(PathBuf::from("log.csv"), None))
        );
        assert_eq!("-".parse(), Ok(Source::Lines(PathBuf::from("-"), None)));
        for bad in [
            "udpin:",
            "serial:/dev/ttyUSB0",
            "serial:/dev/x:12",
            "mavlink",
            "ftp:host:21",
        ] {
            let e = bad.parse::<Source>().unwrap_err();
            assert!(e.starts_with(bad), "{bad}: {e}");
        }
    }

    /// The lines `lines` as a line stream reads them: its kind, and the header, the readings
    /// taken and the counts (readings, other, malformed).
    fn read(lines: &[&str]) -> (Option<LineKind>, Lines) {
        let (mut kind, mut pending, mut taken, mut counts, mut head) = (None, None, Vec::new(), (0, 0, 0), None);
        for l in lines {
            take_line(
                l.as_bytes(),
                (&mut kind, &mut pending),
                &mut taken,
                &mut counts,
                &mut head,
            );
        }
        (kind, (head, taken, counts))
    }

    #[test]
    fn raw_lines_become_rows_in_microtesla_and_the_rest_is_counted() {
        let (kind, (head, taken, counts)) = read(&[
            "Uni:0,0",
            "Raw:1,2,3,4,5,6,123,-45,6",
            "Cal1:0,0",
            "Raw:1,2,3",
            "Raw:1,2,3,4,5,6,7,8,x",
            "",
        ]);
        assert_eq!(kind, Some(LineKind::Raw));
        assert_eq!(head.as_deref(), Some(&b"mx,my,mz\n"[..]));
        assert_eq!(taken, vec![(b"12.3,-4.5,0.6\n".to_vec(), None)]);
        assert_eq!(counts, (1, 2, 2));
    }

    #[test]
    fn a_csv_stream_keeps_its_header() {
        let (_, (head, taken, counts)) = read(&["t,mx,my,mz", "0.1,1,2,3", "Raw:1,2,3,4,5,6,7,8,9", "0.2,4,5,6"]);
        assert_eq!(head.as_deref(), Some(&b"t,mx,my,mz\n"[..]));
        assert_eq!(taken.len(), 2);
        assert_eq!(counts, (2, 1, 0));
        // A header-less CSV stream keeps its first row.
        let (kind, (head, taken, counts)) = read(&["0.1,1,2,3", "0.2,4,5,6"]);
        assert_eq!(
            (kind, head, taken.len(), counts),
            (Some(LineKind::Csv), None, 2, (2, 0, 0))
        );
    }

    #[test]
    fn a_motioncal_stream_opened_in_the_middle_of_a_line_is_still_motioncal() {
        // The cut end of a `Raw:` line, all numbers, then whole lines: the cut one is malformed.
        let (kind, (head, taken, counts)) = read(&[
            "5,6,123,-45,6",
            "Raw:1,2,3,4,5,6,123,-45,6",
            "Raw:1,2,3,4,5,6,124,-44,7",
        ]);
        assert_eq!(kind, Some(LineKind::Raw));
        assert_eq!(head.as_deref(), Some(&b"mx,my,mz\n"[..]));
        assert_eq!(taken.len(), 2);
        assert_eq!(counts, (2, 0, 1));
    }

    #[test]
    fn a_param_value_frame_is_pinned_by_its_name() {
        // A MAVLink 1 PARAM_VALUE: header, value, count, index, name "COMPASS_OFS_X", type, CRC.
        let mut frame = vec![0xFE, 25, 0, 1, 1, 22];
        frame.extend_from_slice(&[0; 8]);
        frame.extend_from_slice(b"COMPASS_OFS_X\0\0\0");
        frame.extend_from_slice(&[9, 0, 0]);
        assert_eq!(param_name(&frame), b"COMPASS_OFS_X");
    }
}
