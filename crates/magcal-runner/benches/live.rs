//! `magcal live` under a stream: a vehicle sends MAVLink over loopback UDP at 10, 100 and 1000
//! readings a second (a known sensor turning at random through every attitude), and the status
//! the page polls (`/status.json`) is read every 5 ms. For each fit it gives: the latency from
//! the arrival of the newest reading it holds to the status that shows it (the page, which polls
//! twice a second, adds up to 0.5 s), the fit's own time, and the fits a second.
//!
//! `cargo bench -p magcal-runner --bench live` (about two minutes; `MAGCAL_LIVE_SECONDS` sets the
//! seconds of each stream, 20 by default).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpStream, UdpSocket};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use magcal_core::design::sources;
use magcal_core::rng::stream_rng;
use magcal_core::{AttitudeBox, paper};
use mavlink::dialects::ardupilotmega::{
    ATTITUDE_DATA, HEARTBEAT_DATA, MavAutopilot, MavMessage, MavType, RAW_IMU_DATA,
};
use mavlink::{MavHeader, MavlinkVersion, write_versioned_msg};

fn frame(msg: &MavMessage, out: &mut Vec<u8>) {
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    write_versioned_msg(out, MavlinkVersion::V2, header, msg).unwrap();
}

/// One datagram per reading: its attitude and its `RAW_IMU` (mGauss, forward, right, down).
fn readings(n: usize) -> Vec<Vec<u8>> {
    let field = paper::changsha_field();
    let mut rng = stream_rng(5, 0);
    let design = sources::random(&AttitudeBox::full(), n, &mut rng);
    let raw = paper::true_error_model()
        .noisy_readings(&field.body_fields(&design), 30.0, &mut rng)
        .unwrap();
    design
        .iter()
        .zip(&raw)
        .enumerate()
        .map(|(i, (a, r))| {
            let [roll, _, pitch] = a.to_degrees();
            let t_ms = 1000 + 10 * i as u32;
            let mut d = Vec::new();
            frame(
                &MavMessage::ATTITUDE(ATTITUDE_DATA {
                    time_boot_ms: t_ms,
                    roll: roll.to_radians() as f32,
                    pitch: pitch.to_radians() as f32,
                    yaw: a.true_heading_deg(0.0).to_radians() as f32,
                    ..ATTITUDE_DATA::default()
                }),
                &mut d,
            );
            let mg = [r[0], r[2], -r[1]].map(|v| (v / 100.0).round() as i16);
            frame(
                &MavMessage::RAW_IMU(RAW_IMU_DATA {
                    time_usec: u64::from(t_ms) * 1000,
                    xmag: mg[0],
                    ymag: mg[1],
                    zmag: mg[2],
                    ..RAW_IMU_DATA::default()
                }),
                &mut d,
            );
            d
        })
        .collect()
}

fn status(addr: &str) -> Option<serde_json::Value> {
    let mut s = TcpStream::connect(addr).ok()?;
    write!(
        s,
        "GET /status.json HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut reply = Vec::new();
    s.read_to_end(&mut reply).ok()?;
    let end = reply.windows(4).position(|w| w == b"\r\n\r\n")?;
    serde_json::from_slice(&reply[end + 4..]).ok()
}

fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(((v.len() as f64 - 1.0) * q).round() as usize)
        .copied()
        .unwrap_or(f64::NAN)
}

/// Streams at `rate` readings a second for `seconds` into `live --every every`; one row of the
/// table.
fn run(rate: f64, seconds: f64, every: f64) {
    let n = (rate * seconds) as usize;
    let data = readings(n);
    let dir = std::env::temp_dir().join(format!("magcal-live-bench-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut child = Command::new(env!("CARGO_BIN_EXE_magcal"))
        .args(["live", "udpin:127.0.0.1:0", "--page", "0", "--idle", "2", "--every"])
        .arg(every.to_string())
        .arg("--out")
        .arg(&dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    let udp = lines.next().unwrap().unwrap();
    let udp = udp
        .strip_prefix("live: reading udpin:")
        .unwrap()
        .split(';')
        .next()
        .unwrap()
        .to_string();
    let page = lines.next().unwrap().unwrap();
    let page = page
        .strip_prefix("live: page at http://")
        .unwrap()
        .trim_end_matches('/')
        .to_string();
    std::thread::spawn(move || {
        for line in lines.map_while(Result::ok) {
            if std::env::var_os("MAGCAL_LIVE_VERBOSE").is_some() {
                eprintln!("{line}");
            }
        }
    });
    let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
    let start = Instant::now();
    let watcher = {
        let page = page.clone();
        std::thread::spawn(move || {
            let mut seen = Vec::new();
            let mut last_fit = 0;
            loop {
                if let Some(s) = status(&page) {
                    let fit = s["fit"].as_u64().unwrap_or(0);
                    if fit != last_fit {
                        last_fit = fit;
                        let t = start.elapsed().as_secs_f64();
                        seen.push((
                            t,
                            s["readings"].as_u64().unwrap_or(0) as usize,
                            s["fit_seconds"].as_f64().unwrap_or(0.0),
                        ));
                    }
                } else if start.elapsed().as_secs_f64() > seconds {
                    // The command ended (`--idle`) after the stream: its server is gone.
                    break;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            seen
        })
    };
    let mut heartbeat = Vec::new();
    frame(
        &MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            mavtype: MavType::MAV_TYPE_QUADROTOR,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            ..HEARTBEAT_DATA::default()
        }),
        &mut heartbeat,
    );
    vehicle.send_to(&heartbeat, &udp).unwrap();
    let mut sent = Vec::with_capacity(n);
    for (k, d) in data.iter().enumerate() {
        let due = Duration::from_secs_f64(k as f64 / rate);
        if let Some(wait) = due.checked_sub(start.elapsed()) {
            std::thread::sleep(wait);
        }
        vehicle.send_to(d, &udp).unwrap();
        sent.push(start.elapsed().as_secs_f64());
    }
    let seen = watcher.join().unwrap();
    let _ = child.wait();
    let _ = std::fs::remove_dir_all(&dir);
    let streaming: Vec<_> = seen.iter().filter(|s| s.1 > 0).collect();
    let mut latency: Vec<f64> = streaming.iter().map(|(t, m, _)| t - sent[(*m).min(n) - 1]).collect();
    let mut fit: Vec<f64> = streaming.iter().map(|s| s.2).collect();
    let fits = streaming.len();
    println!(
        "{rate:>6} /s  every {every:>4} s  {n:>6} readings  {fits:>4} fits ({:.2} a second)  latency median {:.3} s, p95 {:.3} s  fit median {:.3} s, max {:.3} s",
        fits as f64 / seconds,
        quantile(&mut latency, 0.5),
        quantile(&mut latency, 0.95),
        quantile(&mut fit, 0.5),
        quantile(&mut fit, 1.0),
    );
}

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` passes nothing to run.
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let seconds: f64 = std::env::var("MAGCAL_LIVE_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20.0);
    for every in [1.0, 0.25] {
        for rate in [10.0, 100.0, 1000.0] {
            run(rate, seconds, every);
        }
    }
}
