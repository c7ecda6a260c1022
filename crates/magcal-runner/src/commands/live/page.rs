//! `live --page`: a page that follows the fits, served on 127.0.0.1 only.
//!
//! Three resources: the page (`/`), its script and style (`/live.js`, `/live.css`, so that the
//! Content-Security-Policy allows scripts and styles from the page's own origin and nothing
//! else), and `/status.json`, the last fit's status with the counts of the stream as they are at
//! the request. A request whose `Host` is not the server's own address (a page elsewhere that
//! rebinds a name to 127.0.0.1) is refused, as is every method but `GET` and `HEAD`.
//!
//! # The server
//! No client holds up another: each connection has its own thread, at most [`MAX_CONNECTIONS`]
//! at once (one more is answered 503 and closed by the accepting thread, so that memory and
//! threads stay bounded), and each is bounded in what it may send and how long it may take:
//! - the request head (request line, headers, blank line) within [`MAX_HEAD`] bytes, each of its
//!   lines within [`MAX_LINE`] and at most [`MAX_HEADERS`] headers: beyond, 414 (the request
//!   line) or 431 (the headers), and the connection is closed, so that a client's memory is at
//!   most one head's buffer whatever it sends;
//! - the whole head within [`READ_TIMEOUT`] of the connection (a client that sends a byte at a
//!   time is dropped then, with a 408), the whole response within [`WRITE_TIMEOUT`];
//! - one request a connection: the response says `Connection: close` and the server closes, so
//!   that a client that pipelines requests and never reads its responses holds one thread for at
//!   most the timeouts above, never the server.
//!
//! Every response has its `Content-Length` (never chunked) and the headers `Content-Type`,
//! `Content-Security-Policy` (`POLICY`, its own origin only), `Cache-Control: no-store` and
//! `X-Content-Type-Options: nosniff`; a response to `HEAD` has no body.
//!
//! # Why not a server crate
//! The request head is parsed by `httparse`; the connections, bounds and timeouts are here.
//! `tiny_http` 0.12, which served the page before, answers on one thread and bounds neither the
//! request nor its headers: a client that pipelined 3,000 requests and never read its responses
//! blocked every other client until it closed (the answering thread blocked in a write without a
//! timeout), and one header line of 1.4 GB took the process from 117 MB to 1.5 GB. The servers
//! that bound both (hyper and those over it) bring an asynchronous runtime (tokio), which the
//! build keeps out for the sake of its compile time. What is left to this module is small: a
//! thread per connection under a count, a deadline on each read and write, one request a
//! connection.

use std::borrow::Cow;
use std::io::{ErrorKind, Read, Write};
use std::net::{Ipv4Addr, Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use serde::Serialize;

use super::source::{Counts, Shared};

const PAGE: &str = include_str!("../../../assets/live/live.html");
const SCRIPT: &str = include_str!("../../../assets/live/live.js");
const STYLE: &str = include_str!("../../../assets/live/live.css");

/// What the page's sources may be: its own origin, nothing else.
const POLICY: &str = "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; img-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

/// The most calibrated directions and attitudes a status carries (thinned evenly beyond).
pub const MAX_POINTS: usize = 1500;

/// The status of the last fit, as the page draws it.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Status {
    /// The fit's number (0: none yet).
    pub fit: u64,
    pub source: String,
    pub readings: usize,
    pub fit_seconds: f64,
    pub usable: bool,
    pub reasons: String,
    /// The heading budget and the heading the fit is predicted to leave (95th percentile over
    /// the box at every heading), degrees: the finish line.
    pub heading_budget_deg: Option<f64>,
    pub heading_predicted_deg: Option<f64>,
    pub model: Option<String>,
    pub units: Option<String>,
    pub magnitude: Option<f64>,
    pub bias: Option<[f64; 3]>,
    pub bias_se: Option<[f64; 3]>,
    pub scale: Option<[f64; 3]>,
    pub scale_se: Option<[f64; 3]>,
    pub psi_deg: Option<[f64; 3]>,
    pub psi_se_deg: Option<[f64; 3]>,
    /// MotionCal's gap error of the calibrated directions, percent, and the readings in each of
    /// its 100 regions.
    pub gap_percent: Option<f64>,
    pub regions: Vec<usize>,
    /// The bounds of MotionCal's 100 equal-area regions, numbered as `regions` counts them.
    pub region_bounds: Vec<magcal_core::log_fit::MotionCalRegion>,
    /// Calibrated field directions in the sensor frame: longitude from the x axis towards the y
    /// axis in [0, 360) and latitude towards z, degrees.
    pub directions: Vec<[f64; 2]>,
    /// Attitudes flown: roll, pitch, heading, degrees (NED).
    pub attitudes: Vec<[f64; 3]>,
    /// The attitude box, degrees: roll and pitch ranges.
    pub roll_box: Option<[f64; 2]>,
    pub pitch_box: Option<[f64; 2]>,
    pub next: Option<magcal_report::pages::next::AttitudeJson>,
    pub next_error: Option<String>,
    /// The plan a person follows ([`super::guide`]): the target to turn to now, then the rest,
    /// kept until flown or clearly superseded.
    pub plan: Vec<super::guide::Target>,
    /// Targets flown, and plans replaced before their first target was flown.
    pub targets_flown: u64,
    pub plans_superseded: u64,
    /// The budget is met by the last fit: the calibration is done.
    pub done: bool,
    /// The first fit that met the budget.
    pub done_fit: Option<u64>,
    /// The plan's progress in words: "predicted heading error 2.4 deg -> budget 1.0 deg".
    pub progress: String,
    /// How the stream ended ("the source ended", "nothing arrived for 5 s"); `None` while it runs.
    pub stream_end: Option<String>,
    /// The fit whose calibration set `out` holds, and whether it was usable.
    pub written_fit: Option<u64>,
    pub written_usable: bool,
    pub out: String,
    pub export: Option<String>,
}

/// A status with the stream's counts at the request.
#[derive(Serialize)]
struct Now<'a> {
    #[serde(flatten)]
    status: &'a Status,
    bytes: u64,
    frames: u64,
    bad_frames: u64,
    lines: u64,
    malformed_lines: u64,
    other_lines: u64,
    dropped_records: u64,
    held_bytes: usize,
    /// Seconds since the last bytes arrived.
    quiet_s: Option<f64>,
    ended: bool,
}

/// The longest line of a request head (the request line, or a header line), bytes before its
/// CR LF (or its bare LF).
pub const MAX_LINE: usize = 8 * 1024;
/// The most headers of a request.
pub const MAX_HEADERS: usize = 64;
/// The longest request head, bytes: request line, headers and the blank line that ends them.
pub const MAX_HEAD: usize = 32 * 1024;
/// The most connections open at once, each with its thread; one more is answered 503.
pub const MAX_CONNECTIONS: usize = 32;
/// How long a client has, from its connection, to send the whole request head.
pub const READ_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a client has to take the whole response.
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(5);
/// After the response, how long and how much the server reads and discards of what the client
/// still sends: its close is then a FIN that the client reads after the response, not a reset
/// that may discard the response before the client read it.
const LINGER: Duration = Duration::from_millis(500);
const LINGER_BYTES: usize = 64 * 1024;
/// How often the accepting thread looks at `shared.stop` while no client connects.
const POLL: Duration = Duration::from_millis(25);
/// The stack of a connection's thread, bytes: a request head is on the heap, the status is
/// serialised on the heap.
const STACK: usize = 256 * 1024;

/// Starts the server on 127.0.0.1:`port` (0: a free port). Returns its address.
///
/// The server's thread accepts connections until `shared.stop` is set; each connection's own
/// thread ends within [`READ_TIMEOUT`] + [`WRITE_TIMEOUT`] + 0.5 s of its start.
///
/// # Errors
/// The port cannot be bound.
pub fn serve(port: u16, shared: &Arc<Shared>, status: &Arc<Mutex<Status>>) -> Result<SocketAddr> {
    let listener = TcpListener::bind((Ipv4Addr::LOCALHOST, port))
        .with_context(|| format!("--page {port}: cannot listen on 127.0.0.1:{port}"))?;
    let addr = listener.local_addr().context("--page: the server has no address")?;
    // Not blocking, so that the accepting thread sees `stop` while no one connects.
    listener
        .set_nonblocking(true)
        .context("--page: cannot make the server's socket non-blocking")?;
    let (shared, status) = (Arc::clone(shared), Arc::clone(status));
    std::thread::Builder::new()
        .name("magcal-live-page".into())
        .spawn(move || accept(&listener, addr.port(), &shared, &status))
        .context("starting the page's server")?;
    Ok(addr)
}

/// Accepts connections until `shared.stop`: each on its own thread while fewer than
/// [`MAX_CONNECTIONS`] are open, else answered 503 at once.
fn accept(listener: &TcpListener, port: u16, shared: &Arc<Shared>, status: &Arc<Mutex<Status>>) {
    let open = Arc::new(AtomicUsize::new(0));
    while !shared.stop.load(Ordering::Relaxed) {
        let stream = match listener.accept() {
            Ok((stream, _)) => stream,
            // Nothing to accept, or a failure of one connection or of the moment (a client that
            // reset before it was accepted, no file descriptor left): look again shortly.
            Err(_) => {
                std::thread::sleep(POLL);
                continue;
            }
        };
        let Some(slot) = Slot::take(&open) else {
            turn_away(stream);
            continue;
        };
        let (shared, status) = (Arc::clone(shared), Arc::clone(status));
        // A thread that cannot start drops its closure, and with it the stream and the slot.
        let _ = std::thread::Builder::new()
            .name("magcal-live-page-client".into())
            .stack_size(STACK)
            .spawn(move || {
                connection(stream, port, &shared, &status);
                drop(slot);
            });
    }
}

/// One of the [`MAX_CONNECTIONS`] places, given back when dropped.
struct Slot(Arc<AtomicUsize>);

impl Slot {
    fn take(open: &Arc<AtomicUsize>) -> Option<Self> {
        open.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
            (n < MAX_CONNECTIONS).then_some(n + 1)
        })
        .ok()
        .map(|_| Self(Arc::clone(open)))
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Answers 503 to a connection beyond the bound, without ever waiting on it: one write to the
/// new connection's empty send buffer, then what the client already sent is read and discarded,
/// so that the close is a FIN after the answer rather than a reset.
fn turn_away(mut stream: TcpStream) {
    if stream.set_nonblocking(true).is_err() {
        return;
    }
    let _ = stream.write(&Reply::refusal(503).bytes(false));
    let _ = stream.shutdown(Shutdown::Write);
    let mut sink = [0u8; 4096];
    for _ in 0..4 {
        if !matches!(stream.read(&mut sink), Ok(n) if n > 0) {
            break;
        }
    }
}

/// Serves one connection: one request head read within the bounds, one response, the close.
fn connection(mut stream: TcpStream, port: u16, shared: &Shared, status: &Mutex<Status>) {
    // Accepted sockets inherit the listener's non-blocking mode on some systems.
    if stream.set_nonblocking(false).is_err() {
        return;
    }
    let _ = stream.set_nodelay(true);
    let mut buf = vec![0u8; MAX_HEAD];
    let (reply, head_only) = match read_head(&mut stream, &mut buf, Instant::now() + READ_TIMEOUT) {
        Ok(head) => (answer(&head, port, shared, status), head.method == "HEAD"),
        Err(Refused::Answer(code)) => (Reply::refusal(code), false),
        Err(Refused::Drop) => return,
    };
    drop(buf);
    if send(&mut stream, &reply.bytes(head_only), Instant::now() + WRITE_TIMEOUT).is_ok() {
        linger(&mut stream);
    }
}

/// What a request head says that the server needs.
struct Head<'a> {
    method: &'a str,
    /// The request target as sent: the path, with its query if any.
    path: &'a str,
    /// The value of the `Host` header when there is exactly one.
    host: Option<&'a [u8]>,
}

/// Why a request is not answered: with a status code and the close, or with the close alone (the
/// client closed, failed, or sent nothing within the time).
enum Refused {
    Answer(u16),
    Drop,
}

/// Reads a request head into `buf` (of [`MAX_HEAD`] bytes) by `deadline`.
fn read_head<'b>(stream: &mut TcpStream, buf: &'b mut [u8], deadline: Instant) -> Result<Head<'b>, Refused> {
    let mut scan = Scan::default();
    let mut len = 0;
    let end = loop {
        let Some(left) = left(deadline) else {
            return Err(if len == 0 { Refused::Drop } else { Refused::Answer(408) });
        };
        stream.set_read_timeout(Some(left)).map_err(|_| Refused::Drop)?;
        match stream.read(&mut buf[len..]) {
            Ok(0) => return Err(Refused::Drop),
            Ok(n) => len += n,
            Err(e) if e.kind() == ErrorKind::Interrupted => continue,
            // The deadline passed: the next turn says so.
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => continue,
            Err(_) => return Err(Refused::Drop),
        }
        if let Some(end) = scan.more(&buf[..len]).map_err(Refused::Answer)? {
            break end;
        }
        if len == buf.len() {
            return Err(Refused::Answer(431));
        }
    };
    parse(&buf[..end])
}

/// Parses a whole request head (its blank line included).
fn parse(head: &[u8]) -> Result<Head<'_>, Refused> {
    let mut headers = [httparse::EMPTY_HEADER; MAX_HEADERS];
    let mut request = httparse::Request::new(&mut headers);
    match request.parse(head) {
        Ok(httparse::Status::Complete(_)) => {}
        // `Scan` found the blank line where httparse did not: not a head httparse can read.
        Ok(httparse::Status::Partial) => return Err(Refused::Answer(400)),
        Err(httparse::Error::TooManyHeaders) => return Err(Refused::Answer(431)),
        Err(_) => return Err(Refused::Answer(400)),
    }
    let (Some(method), Some(path)) = (request.method, request.path) else {
        return Err(Refused::Answer(400));
    };
    let mut hosts = request.headers.iter().filter(|h| h.name.eq_ignore_ascii_case("Host"));
    let host = match (hosts.next(), hosts.next()) {
        (Some(h), None) => Some(h.value),
        _ => None,
    };
    Ok(Head { method, path, host })
}

/// Finds the end of a request head as its bytes arrive, each line bounded to [`MAX_LINE`].
#[derive(Default)]
struct Scan {
    /// Bytes already looked at.
    seen: usize,
    /// Where the line under way starts.
    line: usize,
    /// Lines of the head so far that were not empty (empty lines before the request line are
    /// skipped, as httparse does).
    lines: usize,
}

impl Scan {
    /// Looks at the bytes of `buf` beyond those seen: the end of the head (just past the blank
    /// line) once it arrived, `None` while it did not.
    ///
    /// # Errors
    /// A line longer than [`MAX_LINE`]: 414 for the request line, 431 for a header.
    fn more(&mut self, buf: &[u8]) -> Result<Option<usize>, u16> {
        let too_long = |lines| if lines == 0 { 414 } else { 431 };
        while let Some(at) = buf[self.seen..].iter().position(|&b| b == b'\n') {
            let end = self.seen + at + 1;
            let line = &buf[self.line..end - 1];
            let line = line.strip_suffix(b"\r").unwrap_or(line);
            if line.len() > MAX_LINE {
                return Err(too_long(self.lines));
            }
            (self.seen, self.line) = (end, end);
            if !line.is_empty() {
                self.lines += 1;
            } else if self.lines > 0 {
                return Ok(Some(end));
            }
        }
        self.seen = buf.len();
        // Room for the CR of a line of MAX_LINE bytes.
        if buf.len() - self.line > MAX_LINE + 1 {
            return Err(too_long(self.lines));
        }
        Ok(None)
    }
}

/// The time left before `deadline`, if any.
fn left(deadline: Instant) -> Option<Duration> {
    deadline.checked_duration_since(Instant::now()).filter(|d| !d.is_zero())
}

/// Writes `bytes` whole by `deadline`.
fn send(stream: &mut TcpStream, mut bytes: &[u8], deadline: Instant) -> std::io::Result<()> {
    while !bytes.is_empty() {
        let left = left(deadline).ok_or(ErrorKind::TimedOut)?;
        stream.set_write_timeout(Some(left))?;
        match stream.write(bytes) {
            Ok(0) => return Err(ErrorKind::WriteZero.into()),
            Ok(n) => bytes = &bytes[n..],
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// Closes the sending side, then reads and discards what the client still sends, for at most
/// [`LINGER`] and [`LINGER_BYTES`], before the connection is closed.
fn linger(stream: &mut TcpStream) {
    let _ = stream.shutdown(Shutdown::Write);
    let deadline = Instant::now() + LINGER;
    let mut sink = [0u8; 4096];
    let mut read = 0;
    while read < LINGER_BYTES {
        let Some(left) = left(deadline) else { break };
        if stream.set_read_timeout(Some(left)).is_err() {
            break;
        }
        match stream.read(&mut sink) {
            Ok(0) => break,
            Ok(n) => read += n,
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(_) => break,
        }
    }
}

/// A response.
struct Reply {
    code: u16,
    kind: &'static str,
    body: Cow<'static, [u8]>,
}

impl Reply {
    /// A refusal: the code, and a line that says why.
    fn refusal(code: u16) -> Self {
        Self {
            code,
            kind: "text/plain; charset=utf-8",
            body: Cow::Borrowed(reason(code).1.as_bytes()),
        }
    }

    /// The response as sent: status line, headers and, unless `head_only`, the body.
    fn bytes(&self, head_only: bool) -> Vec<u8> {
        let Self { code, kind, ref body } = *self;
        let mut out = format!(
            "HTTP/1.1 {code} {reason}\r\nContent-Type: {kind}\r\nContent-Length: {len}\r\n\
             Content-Security-Policy: {POLICY}\r\nCache-Control: no-store\r\n\
             X-Content-Type-Options: nosniff\r\nConnection: close\r\n",
            reason = reason(code).0,
            len = body.len(),
        );
        match code {
            405 => out.push_str("Allow: GET, HEAD\r\n"),
            503 => out.push_str("Retry-After: 1\r\n"),
            _ => {}
        }
        out.push_str("\r\n");
        let mut out = out.into_bytes();
        if !head_only {
            out.extend_from_slice(body);
        }
        out
    }
}

/// The reason phrase of a status code, and the body of a refusal with that code.
fn reason(code: u16) -> (&'static str, &'static str) {
    match code {
        200 => ("OK", ""),
        400 => ("Bad Request", "not an HTTP/1.x request head\n"),
        403 => ("Forbidden", "not this host\n"),
        404 => ("Not Found", "not found\n"),
        405 => ("Method Not Allowed", "GET or HEAD only\n"),
        408 => ("Request Timeout", "the request head took too long\n"),
        414 => ("URI Too Long", "the request line is too long\n"),
        431 => (
            "Request Header Fields Too Large",
            "the headers are too long or too many\n",
        ),
        503 => ("Service Unavailable", "too many connections\n"),
        _ => ("Error", "error\n"),
    }
}

/// The response to a request head.
fn answer(head: &Head, port: u16, shared: &Shared, status: &Mutex<Status>) -> Reply {
    let host_ok = head
        .host
        .is_some_and(|h| h == format!("127.0.0.1:{port}").as_bytes() || h == format!("localhost:{port}").as_bytes());
    if !host_ok {
        return Reply::refusal(403);
    }
    if !matches!(head.method, "GET" | "HEAD") {
        return Reply::refusal(405);
    }
    let (body, kind) = match head.path {
        "/" | "/index.html" => (Cow::Borrowed(PAGE.as_bytes()), "text/html; charset=utf-8"),
        "/live.js" => (Cow::Borrowed(SCRIPT.as_bytes()), "text/javascript; charset=utf-8"),
        "/live.css" => (Cow::Borrowed(STYLE.as_bytes()), "text/css; charset=utf-8"),
        "/status.json" => (Cow::Owned(now(shared, status)), "application/json"),
        _ => return Reply::refusal(404),
    };
    Reply { code: 200, kind, body }
}

/// The status JSON at this moment.
fn now(shared: &Shared, status: &Mutex<Status>) -> Vec<u8> {
    let (counts, dropped, held, ended): (Counts, u64, usize, bool) = {
        let s = shared.lock();
        (s.counts.clone(), s.ring.dropped, s.ring.bytes(), s.ended.is_some())
    };
    let status = status.lock().unwrap_or_else(PoisonError::into_inner);
    let now = Now {
        status: &status,
        bytes: counts.bytes,
        frames: counts.frames,
        bad_frames: counts.bad_crc + counts.unknown,
        lines: counts.lines,
        malformed_lines: counts.malformed_lines,
        other_lines: counts.other_lines,
        dropped_records: dropped,
        held_bytes: held,
        quiet_s: counts.last.map(|t| t.elapsed().as_secs_f64()),
        ended,
    };
    serde_json::to_vec(&now).unwrap_or_default()
}

/// Every `len / max`-th index (all of them when `len <= max`).
pub fn thinned(len: usize, max: usize) -> impl Iterator<Item = usize> {
    let step = len.div_ceil(max.max(1)).max(1);
    (0..len).step_by(step)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::thread::JoinHandle;

    /// A server on a free port, told to stop when dropped.
    struct Server {
        addr: SocketAddr,
        shared: Arc<Shared>,
    }

    impl Server {
        fn start() -> Self {
            Self::with(Status::default())
        }

        fn with(status: Status) -> Self {
            let shared = Shared::new(1 << 20);
            let status = Arc::new(Mutex::new(status));
            let addr = serve(0, &shared, &status).unwrap();
            Self { addr, shared }
        }

        /// A new connection whose reads and writes give up after 10 s.
        fn connect(&self) -> TcpStream {
            let stream = TcpStream::connect(self.addr).unwrap();
            stream.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
            stream.set_write_timeout(Some(Duration::from_secs(10))).unwrap();
            stream
        }

        /// `request` sent whole on a new connection, and what came back.
        fn exchange(&self, request: &[u8]) -> Response {
            let mut stream = self.connect();
            stream.write_all(request).unwrap();
            Response::read(&mut stream)
        }

        fn request(&self, method: &str, path: &str, host: &str) -> Response {
            self.exchange(format!("{method} {path} HTTP/1.1\r\nHost: {host}\r\n\r\n").as_bytes())
        }

        fn get(&self, path: &str) -> Response {
            self.request("GET", path, &self.addr.to_string())
        }
    }

    impl Drop for Server {
        fn drop(&mut self) {
            self.shared.stop.store(true, Ordering::Relaxed);
        }
    }

    /// A response as a client read it up to the server's close.
    #[derive(Debug)]
    struct Response {
        /// None: the connection closed before a whole response head came.
        code: Option<u16>,
        /// Names in lower case.
        headers: Vec<(String, String)>,
        body: Vec<u8>,
    }

    impl Response {
        /// Reads to the close, or to a reset or the stream's timeout (what came before them counts).
        fn read(stream: &mut TcpStream) -> Self {
            let mut raw = Vec::new();
            let _ = stream.read_to_end(&mut raw);
            let Some(end) = raw.windows(4).position(|w| w == b"\r\n\r\n") else {
                return Self {
                    code: None,
                    headers: Vec::new(),
                    body: raw,
                };
            };
            let head = String::from_utf8_lossy(&raw[..end]).into_owned();
            let mut lines = head.split("\r\n");
            let code = lines
                .next()
                .and_then(|l| l.split(' ').nth(1))
                .and_then(|c| c.parse().ok());
            let headers = lines
                .filter_map(|l| l.split_once(':'))
                .map(|(n, v)| (n.to_ascii_lowercase(), v.trim().to_string()))
                .collect();
            Self {
                code,
                headers,
                body: raw[end + 4..].to_vec(),
            }
        }

        fn header(&self, name: &str) -> Option<&str> {
            self.headers.iter().find(|(n, _)| n == name).map(|(_, v)| v.as_str())
        }

        /// The headers every response carries, with the length of the body that `GET` sends.
        #[track_caller]
        fn assert_headers(&self, length: usize) {
            assert_eq!(
                self.header("content-length"),
                Some(length.to_string().as_str()),
                "{self:?}"
            );
            assert_eq!(self.header("content-security-policy"), Some(POLICY), "{self:?}");
            assert_eq!(self.header("cache-control"), Some("no-store"), "{self:?}");
            assert_eq!(self.header("x-content-type-options"), Some("nosniff"), "{self:?}");
            assert_eq!(self.header("transfer-encoding"), None, "{self:?}");
        }
    }

    #[test]
    fn answers_its_four_resources_to_its_own_host_with_get_and_head_only() {
        let server = Server::start();
        assert_eq!(server.addr.ip(), Ipv4Addr::LOCALHOST);
        let port = server.addr.port();
        for (path, kind, body) in [
            ("/", "text/html; charset=utf-8", Some(PAGE)),
            ("/index.html", "text/html; charset=utf-8", Some(PAGE)),
            ("/live.js", "text/javascript; charset=utf-8", Some(SCRIPT)),
            ("/live.css", "text/css; charset=utf-8", Some(STYLE)),
            ("/status.json", "application/json", None),
        ] {
            for host in [format!("127.0.0.1:{port}"), format!("localhost:{port}")] {
                let got = server.request("GET", path, &host);
                assert_eq!(got.code, Some(200), "{path} {got:?}");
                assert_eq!(got.header("content-type"), Some(kind), "{path}");
                got.assert_headers(got.body.len());
                if let Some(body) = body {
                    assert_eq!(got.body, body.as_bytes(), "{path}");
                }
                // HEAD: the same head, the length of the body it does not send.
                let head = server.request("HEAD", path, &host);
                assert_eq!(head.code, Some(200), "{path} {head:?}");
                head.assert_headers(got.body.len());
                assert!(head.body.is_empty(), "{path} {head:?}");
            }
        }
        let status: serde_json::Value = serde_json::from_slice(&server.get("/status.json").body).unwrap();
        assert_eq!(status["fit"], 0, "{status}");
        assert_eq!(status["ended"], false, "{status}");

        // Another host's name for the address, another port, no port, no Host, two Hosts.
        let own = format!("127.0.0.1:{port}");
        for request in [
            "GET / HTTP/1.1\r\nHost: attacker.example:80\r\n\r\n".to_string(),
            format!("GET / HTTP/1.1\r\nHost: attacker.example:{port}\r\n\r\n"),
            format!("GET / HTTP/1.1\r\nHost: 127.0.0.1:{}\r\n\r\n", port.wrapping_add(1)),
            "GET / HTTP/1.1\r\nHost: localhost\r\n\r\n".to_string(),
            "GET / HTTP/1.1\r\n\r\n".to_string(),
            "GET / HTTP/1.0\r\n\r\n".to_string(),
            format!("GET / HTTP/1.1\r\nHost: {own}\r\nHost: attacker.example\r\n\r\n"),
        ] {
            let got = server.exchange(request.as_bytes());
            assert_eq!(got.code, Some(403), "{request:?} {got:?}");
            got.assert_headers(got.body.len());
        }
        for method in ["POST", "PUT", "DELETE", "OPTIONS", "get"] {
            let got = server.request(method, "/status.json", &own);
            assert_eq!(got.code, Some(405), "{method} {got:?}");
            assert_eq!(got.header("allow"), Some("GET, HEAD"), "{method}");
            got.assert_headers(got.body.len());
        }
        for path in ["/../calibration.json", "/status.json?x=1", "/STATUS.JSON", "/live", "*"] {
            let got = server.get(path);
            assert_eq!(got.code, Some(404), "{path} {got:?}");
            got.assert_headers(got.body.len());
            let head = server.request("HEAD", path, &own);
            assert_eq!(head.code, Some(404), "{path} {head:?}");
            head.assert_headers(got.body.len());
            assert!(head.body.is_empty(), "{path} {head:?}");
        }
    }

    #[test]
    fn refuses_a_request_head_beyond_its_bounds_and_serves_one_within_them() {
        let server = Server::start();
        let host = format!("Host: {}\r\n", server.addr);
        // A header line of `len` bytes before its CR LF.
        let pad = |len: usize| format!("X-Pad: {}\r\n", "p".repeat(len - "X-Pad: ".len()));
        let head = |line: &str, headers: &[String]| format!("{line}\r\n{host}{}\r\n", headers.concat());
        let path_of = |len: usize| format!("/{}", "a".repeat(len - "GET / HTTP/1.1".len()));
        let cases = [
            (
                "request line of MAX_LINE",
                head(&format!("GET {} HTTP/1.1", path_of(MAX_LINE)), &[]),
                404,
            ),
            (
                "request line of MAX_LINE + 1",
                head(&format!("GET {} HTTP/1.1", path_of(MAX_LINE + 1)), &[]),
                414,
            ),
            ("header line of MAX_LINE", head("GET / HTTP/1.1", &[pad(MAX_LINE)]), 200),
            (
                "header line of MAX_LINE + 1",
                head("GET / HTTP/1.1", &[pad(MAX_LINE + 1)]),
                431,
            ),
            (
                "MAX_HEADERS headers",
                head("GET / HTTP/1.1", &vec![pad(10); MAX_HEADERS - 1]),
                200,
            ),
            (
                "MAX_HEADERS + 1 headers",
                head("GET / HTTP/1.1", &vec![pad(10); MAX_HEADERS]),
                431,
            ),
            // 16 + 23 + 4 × 8002 + 2 = 32,049 bytes, then 40,059.
            (
                "a head below MAX_HEAD",
                head("GET / HTTP/1.1", &vec![pad(8000); 4]),
                200,
            ),
            (
                "a head beyond MAX_HEAD",
                head("GET / HTTP/1.1", &vec![pad(8000); 5]),
                431,
            ),
            (
                "bare line feeds",
                head("GET / HTTP/1.1", &[]).replace("\r\n", "\n"),
                200,
            ),
            ("not HTTP", "\u{1}\u{2}\u{3}\r\n\r\n".to_string(), 400),
            (
                "a header without a colon",
                head("GET / HTTP/1.1", &["no colon\r\n".to_string()]),
                400,
            ),
            ("no version", head("GET /", &[]), 400),
        ];
        for (what, request, code) in cases {
            let got = server.exchange(request.as_bytes());
            assert_eq!(got.code, Some(code), "{what}: {got:?}");
            got.assert_headers(got.body.len());
        }
    }

    #[test]
    fn scan_finds_the_end_of_a_head_that_arrives_a_byte_at_a_time() {
        let head = b"\r\nGET / HTTP/1.1\r\nHost: h\r\n\r\nGET /next HTTP/1.1\r\n";
        let end = head.len() - "GET /next HTTP/1.1\r\n".len();
        let mut scan = Scan::default();
        for len in 1..end {
            assert_eq!(scan.more(&head[..len]), Ok(None), "{len}");
        }
        assert_eq!(scan.more(&head[..end]), Ok(Some(end)));
        let mut scan = Scan::default();
        assert_eq!(scan.more(&head[..]), Ok(Some(end)));
        // A request line or a header line longer than MAX_LINE, before its end arrived.
        let long = vec![b'a'; MAX_LINE + 2];
        assert_eq!(Scan::default().more(&long), Err(414));
        assert_eq!(
            Scan::default().more(&[b"GET / HTTP/1.1\r\n", &long[..]].concat()),
            Err(431)
        );
        assert_eq!(Scan::default().more(&long[..MAX_LINE + 1]), Ok(None), "room for the CR");
    }

    #[test]
    fn a_client_that_pipelines_and_never_reads_blocks_no_one() {
        // A status as large as a fit's (MAX_POINTS directions and attitudes, about 150 kB): the
        // answers to a few of the requests fill the greedy client's socket buffers, so that a
        // server that answered its requests in turn would block in a write.
        let points = (0..MAX_POINTS).map(|k| k as f64 * 0.123_456_789_012_3);
        let server = Server::with(Status {
            directions: points.clone().map(|x| [x, -x]).collect(),
            attitudes: points.map(|x| [x, -x, x / 3.0]).collect(),
            ..Status::default()
        });
        let request = format!("GET /status.json HTTP/1.1\r\nHost: {}\r\n\r\n", server.addr);
        let mut greedy = server.connect();
        // Its first request is in before the other client connects, the rest follow.
        greedy.write_all(request.as_bytes()).unwrap();
        let rest = request.repeat(9_999);
        let greedy = std::thread::spawn(move || {
            // Fails once the server closes.
            let _ = greedy.write_all(rest.as_bytes());
            greedy
        });
        // The other client is answered at once by a server that serves each connection on its
        // own; by one that answers in turn, never (the greedy client stays open and does not
        // read). 5 s tells the two apart with room for a loaded machine.
        let started = Instant::now();
        let got = server.get("/status.json");
        let waited = started.elapsed();
        assert_eq!(got.code, Some(200), "{got:?}");
        assert!(waited < Duration::from_secs(5), "{waited:?}");
        // The greedy client got one answer, then the close: nothing beyond the answer's length
        // came (and maybe less: the server's close with requests unread is a reset, which drops
        // the part of the answer the client's full buffers had not yet let through).
        let mut greedy = greedy.join().unwrap();
        let answered = Response::read(&mut greedy);
        assert_eq!(answered.code, Some(200), "{:?}", answered.code);
        let length: usize = answered.header("content-length").unwrap().parse().unwrap();
        assert!(length > 100_000, "{length}");
        assert!(answered.body.len() <= length, "{} > {length}", answered.body.len());
    }

    #[test]
    fn a_huge_header_line_is_refused_after_a_bounded_read_and_others_are_served() {
        let server = Server::start();
        let mut stream = server.connect();
        // The client's own send buffer small (loopback's grows to megabytes by itself), so that
        // what its writes hand over is what the server's side took in, within 32 kB.
        #[cfg(unix)]
        small_send_buffer(&stream);
        let mut reader = stream.try_clone().unwrap();
        let answer = std::thread::spawn(move || Response::read(&mut reader));
        stream
            .write_all(format!("GET / HTTP/1.1\r\nHost: {}\r\nX-Huge: ", server.addr).as_bytes())
            .unwrap();
        // Up to 16 MiB of one header line, until the server closes.
        let chunk = vec![b'h'; 64 * 1024];
        let mut sent = 0;
        let closed = loop {
            if sent >= 16 << 20 {
                break None;
            }
            match stream.write(&chunk) {
                Ok(n) => sent += n,
                Err(e) => break Some(e.kind()),
            }
        };
        let got = answer.join().unwrap();
        assert_eq!(got.code, Some(431), "{got:?}");
        got.assert_headers(got.body.len());
        // The server closed (a timeout of the write would mean it neither read nor closed), after
        // taking in MAX_HEAD, LINGER_BYTES and what its socket's receive buffer holds: far less
        // than 1 MiB.
        assert!(
            matches!(
                closed,
                Some(ErrorKind::BrokenPipe | ErrorKind::ConnectionReset | ErrorKind::ConnectionAborted)
            ),
            "{closed:?} after {sent} bytes"
        );
        #[cfg(unix)]
        assert!(sent < 1 << 20, "{sent} bytes taken in");
        assert_eq!(server.get("/status.json").code, Some(200));
    }

    /// Sets the send buffer of `stream` to 16 kB (Linux doubles it), which also stops its growth.
    #[cfg(unix)]
    fn small_send_buffer(stream: &TcpStream) {
        use std::os::fd::AsRawFd;
        let size: libc::c_int = 16 * 1024;
        // SAFETY: a valid socket, and a pointer to an int with its length.
        let done = unsafe {
            libc::setsockopt(
                stream.as_raw_fd(),
                libc::SOL_SOCKET,
                libc::SO_SNDBUF,
                std::ptr::from_ref(&size).cast(),
                libc::socklen_t::try_from(std::mem::size_of_val(&size)).unwrap(),
            )
        };
        assert_eq!(done, 0, "{}", std::io::Error::last_os_error());
    }

    /// Sends a byte every 500 ms until the server answers or closes (10 s at most): how long after
    /// `started` that came, and the code of the answer if any.
    fn drip(mut stream: TcpStream, started: Instant) -> (Duration, Option<u16>) {
        stream.set_read_timeout(Some(Duration::from_millis(500))).unwrap();
        loop {
            match stream.peek(&mut [0u8; 1]) {
                Ok(0) => return (started.elapsed(), None),
                Ok(_) => {
                    let at = started.elapsed();
                    stream.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
                    return (at, Response::read(&mut stream).code);
                }
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    if started.elapsed() > Duration::from_secs(10) || stream.write_all(b"s").is_err() {
                        return (started.elapsed(), None);
                    }
                }
                Err(_) => return (started.elapsed(), None),
            }
        }
    }

    #[test]
    fn slow_clients_block_no_one_and_are_dropped_after_the_read_timeout() {
        let server = Server::start();
        let slow: Vec<JoinHandle<(Duration, Option<u16>)>> = (0..4)
            .map(|_| {
                let started = Instant::now();
                let mut stream = server.connect();
                stream.write_all(b"GET / HTTP/1.1\r\nX-Slow: ").unwrap();
                std::thread::spawn(move || drip(stream, started))
            })
            .collect();
        // Four clients hold a head open: a server that took its clients in turn would answer the
        // fifth after 4 × READ_TIMEOUT = 8 s; one that serves each on its own, at once. 5 s tells
        // the two apart with room for a loaded machine.
        let started = Instant::now();
        let got = server.get("/status.json");
        let waited = started.elapsed();
        assert_eq!(got.code, Some(200), "{got:?}");
        assert!(waited < Duration::from_secs(5), "{waited:?}");
        for slow in slow {
            let (held, code) = slow.join().unwrap();
            // Never before READ_TIMEOUT (counted from the server's accept, after `started`), and
            // soon after it (3 s of room for a loaded machine).
            assert!(held >= READ_TIMEOUT, "{held:?}");
            assert!(held < READ_TIMEOUT + Duration::from_secs(3), "{held:?}");
            assert_eq!(code, Some(408));
        }
    }

    #[test]
    fn connections_beyond_the_bound_are_turned_away_until_some_close() {
        let server = Server::start();
        // MAX_CONNECTIONS clients that began a head: each holds its place until it closes or
        // READ_TIMEOUT passes.
        let held: Vec<TcpStream> = (0..MAX_CONNECTIONS)
            .map(|_| {
                let mut stream = server.connect();
                stream.write_all(b"GET / HTTP/1.1\r\n").unwrap();
                stream
            })
            .collect();
        // One more that only listens is answered 503 at once.
        let mut listening = server.connect();
        let got = Response::read(&mut listening);
        assert_eq!(got.code, Some(503), "{got:?}");
        assert_eq!(got.header("retry-after"), Some("1"));
        got.assert_headers(got.body.len());
        // One that sends a request is answered 503 too, or closed before it read the answer (when
        // its request came after the server's close), but never served.
        for _ in 0..3 {
            let got = server.get("/status.json");
            assert!(matches!(got.code, Some(503) | None), "{got:?}");
        }
        drop(held);
        // Served again once they closed: their threads see the close at once (and give their
        // places back after READ_TIMEOUT at the latest; 5 s leaves room for a loaded machine).
        let started = Instant::now();
        loop {
            let got = server.get("/status.json");
            if got.code == Some(200) {
                break;
            }
            assert!(started.elapsed() < Duration::from_secs(5), "{got:?}");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    #[test]
    fn the_server_closes_its_port_when_the_command_stops() {
        let server = Server::start();
        assert_eq!(server.get("/").code, Some(200));
        server.shared.stop.store(true, Ordering::Relaxed);
        let started = Instant::now();
        while TcpStream::connect(server.addr).is_ok() {
            assert!(started.elapsed() < Duration::from_secs(5), "still listening");
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}
