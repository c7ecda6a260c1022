//! `live --page`: a page that follows the fits, served on 127.0.0.1 only.
//!
//! Three resources: the page (`/`), its script and style (`/live.js`, `/live.css`, so that the
//! Content-Security-Policy allows scripts and styles from the page's own origin and nothing
//! else), and `/status.json`, the last fit's status with the counts of the stream as they are at
//! the request. A request whose `Host` is not the server's own address (a page elsewhere that
//! rebinds a name to 127.0.0.1) is refused, as is every method but `GET` and `HEAD`.

use std::net::SocketAddr;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

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

/// Starts the server on 127.0.0.1:`port` (0: a free port). Returns its address.
///
/// # Errors
/// The port cannot be bound.
pub fn serve(port: u16, shared: &Arc<Shared>, status: &Arc<Mutex<Status>>) -> Result<SocketAddr> {
    let server = tiny_http::Server::http(("127.0.0.1", port))
        .map_err(|e| anyhow::anyhow!("--page {port}: cannot listen on 127.0.0.1:{port}: {e}"))?;
    let addr = server
        .server_addr()
        .to_ip()
        .context("--page: the server has no IP address")?;
    let (shared, status) = (Arc::clone(shared), Arc::clone(status));
    std::thread::Builder::new()
        .name("magcal-live-page".into())
        .spawn(move || {
            while !shared.stop.load(Ordering::Relaxed) {
                match server.recv_timeout(Duration::from_millis(200)) {
                    Ok(Some(request)) => {
                        let _ = answer(request, addr, &shared, &status);
                    }
                    Ok(None) => {}
                    Err(_) => break,
                }
            }
        })
        .context("starting the page's server")?;
    Ok(addr)
}

fn header(name: &str, value: &str) -> tiny_http::Header {
    tiny_http::Header::from_bytes(name.as_bytes(), value.as_bytes()).unwrap_or_else(|()| unreachable!("a valid header"))
}

fn answer(
    request: tiny_http::Request,
    addr: SocketAddr,
    shared: &Shared,
    status: &Mutex<Status>,
) -> std::io::Result<()> {
    use tiny_http::{Method, Response};
    let host_ok = request
        .headers()
        .iter()
        .find(|h| h.field.equiv("Host"))
        .is_some_and(|h| {
            let v = h.value.as_str();
            v == format!("127.0.0.1:{}", addr.port()) || v == format!("localhost:{}", addr.port())
        });
    if !host_ok {
        return request.respond(Response::from_string("not this host\n").with_status_code(403));
    }
    if !matches!(request.method(), Method::Get | Method::Head) {
        return request.respond(Response::from_string("GET only\n").with_status_code(405));
    }
    let (body, kind) = match request.url() {
        "/" | "/index.html" => (PAGE.as_bytes().to_vec(), "text/html; charset=utf-8"),
        "/live.js" => (SCRIPT.as_bytes().to_vec(), "text/javascript; charset=utf-8"),
        "/live.css" => (STYLE.as_bytes().to_vec(), "text/css; charset=utf-8"),
        "/status.json" => (now(shared, status), "application/json"),
        _ => return request.respond(Response::from_string("not found\n").with_status_code(404)),
    };
    // Whole, with its length: no chunked encoding, whatever its size (a status of 1500 points is
    // about 100 kB; tiny_http chunks above 32 kB by default).
    let response = Response::from_data(body)
        .with_chunked_threshold(usize::MAX)
        .with_header(header("Content-Type", kind))
        .with_header(header("Content-Security-Policy", POLICY))
        .with_header(header("Cache-Control", "no-store"))
        .with_header(header("X-Content-Type-Options", "nosniff"));
    request.respond(response)
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
