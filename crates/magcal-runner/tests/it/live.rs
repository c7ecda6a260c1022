//! `magcal live`: a test vehicle streams MAVLink over loopback UDP from a known sensor while it
//! turns through a scenario's attitudes, and a MotionCal sketch writes `Raw:` lines into a
//! pseudo-terminal. What `live` fits must be what `calibrate` and `next` say of the same
//! readings saved by `--record`.

use std::io::{BufRead, BufReader, Write};
use std::net::UdpSocket;
use std::path::Path;
use std::process::{Child, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use mavlink::dialects::ardupilotmega::{
    ATTITUDE_DATA, HEARTBEAT_DATA, MavAutopilot, MavMessage, MavParamType, MavType, PARAM_VALUE_DATA, RAW_IMU_DATA,
};
use mavlink::{MavHeader, MavlinkVersion, write_versioned_msg};
use serde_json::Value;
use tempfile::TempDir;

use crate::common::{magcal, magcal_process};

/// The offsets in force on the test vehicle, mGauss: the raw readings are sent with them added.
pub(crate) const OFS: [f32; 3] = [-30.0, 12.5, 44.0];

/// The glider's sensor bias (scenarios/glider.toml: 2500, -1800, 4200 nT in [P1]'s nose, up,
/// right) in the forward, right, down axes the vehicle sends, mGauss.
const GLIDER_BIAS_FRD: [f64; 3] = [25.0, 42.0, 18.0];

/// One MAVLink 2 frame from the vehicle (system 1, component 1).
pub(crate) fn frame(msg: &MavMessage) -> Vec<u8> {
    let mut bytes = Vec::new();
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    write_versioned_msg(&mut bytes, MavlinkVersion::V2, header, msg).unwrap();
    bytes
}

/// The rows of a simulated log: roll, pitch, true heading (degrees) and the reading (nT) in the
/// paper's body frame (nose, up, right).
pub(crate) fn simulated(dir: &Path, scenario: &str, design: &str, seed: u64) -> Vec<[f64; 6]> {
    round_and_round(&in_plan_order(dir, scenario, design, seed))
}

/// The rows of a simulated log as `simulate` writes them: attitude by attitude, in the plan's
/// order.
fn in_plan_order(dir: &Path, scenario: &str, design: &str, seed: u64) -> Vec<[f64; 6]> {
    let csv = dir.join("sim.csv");
    magcal()
        .args([
            "simulate",
            scenario,
            "--design",
            design,
            "--seed",
            &seed.to_string(),
            "--out",
        ])
        .arg(&csv)
        .assert()
        .success();
    let mut reader = csv::Reader::from_path(&csv).unwrap();
    let names: Vec<String> = reader.headers().unwrap().iter().map(str::to_string).collect();
    let at = |n: &str| names.iter().position(|h| h == n).unwrap();
    let cols = ["roll_deg", "pitch_deg", "true_heading_deg", "mx", "my", "mz"].map(at);
    reader
        .records()
        .map(|r| {
            let r = r.unwrap();
            cols.map(|c| r[c].parse::<f64>().unwrap())
        })
        .collect()
}

/// The rows of a plan flown attitude by attitude, reordered as a vehicle turned round and round
/// through its attitudes flies them: the first reading of each attitude, then the second of
/// each, and so on. Every stretch of the stream then visits every attitude, as a person turning a
/// vehicle does, and the fits without a fifth of it have the plan's attitudes still.
fn round_and_round(rows: &[[f64; 6]]) -> Vec<[f64; 6]> {
    let mut groups: Vec<Vec<[f64; 6]>> = Vec::new();
    for r in rows {
        match groups.last_mut() {
            Some(g) if g[0][..3] == r[..3] => g.push(*r),
            _ => groups.push(vec![*r]),
        }
    }
    let longest = groups.iter().map(Vec::len).max().unwrap_or(0);
    (0..longest)
        .flat_map(|i| groups.iter().filter_map(move |g| g.get(i).copied()))
        .collect()
}

/// The vehicle's frames: its heartbeat and the compass parameters in force, then its [`turns`].
fn vehicle_frames(rows: &[[f64; 6]]) -> Vec<Vec<u8>> {
    let mut out = vec![frame(&MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_SURFACE_BOAT,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        ..HEARTBEAT_DATA::default()
    }))];
    // The calibration in force, whole (live exports nothing while any of it is unknown): the
    // offsets, no soft iron.
    for (c, a) in ["X", "Y", "Z"].iter().enumerate() {
        for (name, value) in [("OFS", OFS[c]), ("DIA", 1.0), ("ODI", 0.0)] {
            out.push(frame(&MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
                param_value: value,
                param_count: 0,
                param_index: 0,
                param_id: format!("COMPASS_{name}_{a}").as_str().into(),
                param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
            })));
        }
    }
    out.extend(turns(rows, 1000));
    out
}

/// Per row an `ATTITUDE` and a `RAW_IMU` with the reading turned into forward, right, down
/// (mGauss, offsets added), 20 ms apart from `first_ms` after boot.
pub(crate) fn turns(rows: &[[f64; 6]], first_ms: u32) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    for (i, r) in rows.iter().enumerate() {
        let t_ms = first_ms + 20 * i as u32;
        out.push(frame(&MavMessage::ATTITUDE(ATTITUDE_DATA {
            time_boot_ms: t_ms,
            roll: r[0].to_radians() as f32,
            pitch: r[1].to_radians() as f32,
            yaw: r[2].to_radians() as f32,
            ..ATTITUDE_DATA::default()
        })));
        let frd = [r[3], r[5], -r[4]];
        let mag = |a: usize| (frd[a] / 100.0 + f64::from(OFS[a])).round() as i16;
        out.push(frame(&MavMessage::RAW_IMU(RAW_IMU_DATA {
            time_usec: u64::from(t_ms) * 1000,
            xmag: mag(0),
            ymag: mag(1),
            zmag: mag(2),
            ..RAW_IMU_DATA::default()
        })));
    }
    out
}

/// The address a `udpin:` source was bound to, from `live`'s first line.
pub(crate) fn udp_address(first: &str) -> String {
    first
        .strip_prefix("live: reading udpin:")
        .and_then(|s| s.split(';').next())
        .unwrap_or_else(|| panic!("{first}"))
        .to_string()
}

/// The vehicle's frames sent to `addr`, five to a datagram as a radio bridge sends them.
pub(crate) fn fly(vehicle: &UdpSocket, frames: &[Vec<u8>], addr: &str) {
    for chunk in frames.chunks(5) {
        vehicle.send_to(&chunk.concat(), addr).unwrap();
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// `magcal live` started with `args`, its standard error read by a thread: the first line (what
/// it reads) comes back at once, the rest when it ends.
pub(crate) fn start_live(args: &[&str]) -> (Child, String, mpsc::Receiver<Vec<String>>) {
    let (child, mut first, all) = start_live_lines(args, 1);
    (child, first.remove(0), all)
}

/// As [`start_live`], with its first `n` lines.
pub(crate) fn start_live_lines(args: &[&str], n: usize) -> (Child, Vec<String>, mpsc::Receiver<Vec<String>>) {
    let mut child = magcal_process()
        .arg("live")
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let (first_tx, first_rx) = mpsc::channel();
    let (all_tx, all_rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut lines = Vec::new();
        for line in BufReader::new(stderr).lines() {
            let line = line.unwrap();
            if lines.len() < n {
                let _ = first_tx.send(line.clone());
            }
            lines.push(line);
        }
        let _ = all_tx.send(lines);
    });
    let first = (0..n)
        .map(|_| {
            first_rx
                .recv_timeout(Duration::from_secs(30))
                .expect("live said too little")
        })
        .collect();
    (child, first, all_rx)
}

/// The JSON `live --json` printed, its standard error, and its exit code.
pub(crate) fn finish_live(mut child: Child, stderr: &mpsc::Receiver<Vec<String>>) -> (Value, Vec<String>, i32) {
    let mut out = String::new();
    std::io::Read::read_to_string(&mut child.stdout.take().unwrap(), &mut out).unwrap();
    let status = child.wait().unwrap();
    let lines = stderr.recv_timeout(Duration::from_secs(30)).unwrap();
    let json = serde_json::from_str(&out).unwrap_or_else(|e| panic!("{e}: {out:?} {lines:#?}"));
    (json, lines, status.code().unwrap())
}

pub(crate) fn json_of(path: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// The numbers of a calibration that must agree to the last bit between two fits of the same
/// readings.
const SAME: [&str; 7] = [
    "bias",
    "psi_deg",
    "scale",
    "magnitude",
    "samples",
    "usable",
    "log_sha256",
];

#[test]
fn a_vehicle_streaming_mavlink_over_udp_is_calibrated_as_its_recorded_tlog_is() {
    let tmp = TempDir::new().unwrap();
    let scenario = "../../scenarios/glider.toml";
    let rows = simulated(tmp.path(), scenario, "plan300", 7);
    let frames = vehicle_frames(&rows);
    let (out, record) = (tmp.path().join("out"), tmp.path().join("stream.tlog"));
    let (child, first, stderr) = start_live(&[
        "udpin:127.0.0.1:0",
        "--out",
        out.to_str().unwrap(),
        "--record",
        record.to_str().unwrap(),
        "--scenario",
        scenario,
        "--idle",
        "2",
        "--every",
        "0.2",
        "--json",
    ]);
    let addr = udp_address(&first);
    let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
    // Some frames a datagram, as a radio bridge sends them, with a damaged one among them.
    for (k, chunk) in frames.chunks(5).enumerate() {
        let mut datagram: Vec<u8> = chunk.concat();
        if k == 3 {
            let mut bad = frames[frames.len() - 1].clone();
            bad[12] ^= 0x55;
            datagram.extend(bad);
        }
        vehicle.send_to(&datagram, &addr).unwrap();
        std::thread::sleep(Duration::from_millis(2));
    }
    let (live, lines, code) = finish_live(child, &stderr);
    assert_eq!(code, 0, "{lines:#?}");
    assert_eq!(live["frames"], frames.len() as u64, "{live}");
    assert!(live["bad_crc"].as_u64().unwrap() >= 1, "{live}");
    assert_eq!(live["dropped_records"], 0);
    assert_eq!(live["readings"], rows.len() as u64);
    assert_eq!(live["usable"], true, "{live}");
    assert!(live["fits"].as_u64().unwrap() >= 1);
    // The set live wrote is calibrate's of the recorded telemetry log, to the last bit.
    let written = json_of(&out.join("calibration.json"));
    let again = tmp.path().join("again");
    magcal()
        .args(["calibrate", record.to_str().unwrap(), "--scenario", scenario, "--out"])
        .arg(&again)
        .assert()
        .success();
    let calibrated = json_of(&again.join("calibration.json"));
    for key in SAME {
        assert_eq!(written[key], calibrated[key], "{key}");
    }
    // The sensor is the vehicle's: the offsets in force undone, the bias is the simulated
    // sensor's within four standard errors.
    for a in 0..3 {
        let (b, se) = (
            written["bias"][a].as_f64().unwrap(),
            written["std_error"]["bias"][a].as_f64().unwrap(),
        );
        assert!((b - GLIDER_BIAS_FRD[a]).abs() < 4.0 * se, "bias {a}: {b} +- {se}");
    }
    // The attitude it asks for next is next's for the same readings.
    let next = magcal()
        .args(["next"])
        .arg(out.join("calibration.json"))
        .arg(&record)
        .args(["--scenario", scenario, "--count", "1", "--json"])
        .output()
        .unwrap();
    assert!(next.status.success(), "{}", String::from_utf8_lossy(&next.stderr));
    let next: Value = serde_json::from_slice(&next.stdout).unwrap();
    assert_eq!(live["next"], next["attitudes"][0], "{live}");
}

#[test]
fn motioncal_raw_lines_through_a_pseudo_terminal_calibrate_as_their_recorded_csv() {
    let tmp = TempDir::new().unwrap();
    let rows = simulated(tmp.path(), "../../scenarios/glider.toml", "plan300", 3);
    let (mut master, slave) = pty();
    let (out, record) = (tmp.path().join("out"), tmp.path().join("stream.csv"));
    let source = format!("lines:{slave}:115200");
    let (child, first, stderr) = start_live(&[
        &source,
        "--out",
        out.to_str().unwrap(),
        "--record",
        record.to_str().unwrap(),
        "--json",
    ]);
    assert!(first.starts_with(&format!("live: reading {source}")), "{first}");
    // The sketch's lines: accelerometer and gyroscope, then the magnetometer in 0.1 uT; a line
    // of another kind and a cut one among them.
    let mut text = String::from("Cal1:0,0,0\n");
    for r in &rows {
        let m = [r[3], r[4], r[5]].map(|v| (v / 100.0).round() as i64);
        text += &format!("Raw:0,0,8192,0,0,0,{},{},{}\n", m[0], m[1], m[2]);
    }
    text += "Raw:1,2,3\n";
    master.write_all(text.as_bytes()).unwrap();
    master.flush().unwrap();
    std::thread::sleep(Duration::from_millis(500));
    drop(master);
    let (live, lines, code) = finish_live(child, &stderr);
    assert_eq!(code, 0, "{lines:#?} {live}");
    assert_eq!(live["lines"], rows.len() as u64);
    assert_eq!(live["malformed_lines"], 1);
    assert_eq!(live["other_lines"], 1);
    assert_eq!(live["usable"], true, "{live}");
    let written = json_of(&out.join("calibration.json"));
    assert_eq!(written["units"], "uT");
    let again = tmp.path().join("again");
    magcal()
        .args(["calibrate", record.to_str().unwrap(), "--units", "uT", "--out"])
        .arg(&again)
        .assert()
        .success();
    let calibrated = json_of(&again.join("calibration.json"));
    for key in SAME {
        assert_eq!(written[key], calibrated[key], "{key}");
    }
}

/// A pseudo-terminal: its master end, and its slave's path.
fn pty() -> (std::fs::File, String) {
    use std::os::fd::FromRawFd;
    let (mut master, mut slave) = (0, 0);
    // SAFETY: openpty writes two descriptors; null name, termios and window size are allowed.
    let rc = unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            std::ptr::null(),
        )
    };
    assert_eq!(rc, 0, "openpty: {}", std::io::Error::last_os_error());
    // Neither end may pass to the processes the tests start, or the master never hangs up.
    for fd in [master, slave] {
        // SAFETY: fcntl on a descriptor just opened.
        assert_eq!(unsafe { libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC) }, 0);
    }
    let path = std::fs::read_link(format!("/proc/self/fd/{slave}")).unwrap();
    // SAFETY: both descriptors were just opened and are owned here; the slave stays open until
    // live has opened it, so that the master does not read EIO first.
    let master = unsafe { std::fs::File::from_raw_fd(master) };
    std::mem::forget(unsafe { std::fs::File::from_raw_fd(slave) });
    (master, path.display().to_string())
}

#[test]
fn sources_and_options_that_cannot_work_are_refused_before_anything_is_written() {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    let exists = tmp.path().join("exists.tlog");
    std::fs::write(&exists, b"x").unwrap();
    for (args, says) in [
        (vec!["ftp:host:21"], "unknown source kind"),
        (vec!["serial:/dev/null"], "give the baud rate"),
        (vec!["udpin:256.0.0.1:14550"], "not an address"),
        (vec!["lines:/no/such/device"], "opening /no/such/device"),
        (vec!["lines:/dev/null:9600"], "not a terminal device"),
        (
            vec!["udpin:127.0.0.1:0", "--record", exists.to_str().unwrap()],
            "it exists",
        ),
        (vec!["udpin:127.0.0.1:0", "--every", "0"], "--every 0"),
        (vec!["udpin:127.0.0.1:0", "--format", "csv"], "--format"),
    ] {
        let o = magcal()
            .arg("live")
            .args(&args)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?}");
    }
    assert_eq!(std::fs::read(&exists).unwrap(), b"x");
    // A source that cannot be opened leaves no recording behind.
    let record = tmp.path().join("new.tlog");
    let o = magcal()
        .args(["live", "udpin:256.0.0.1:14550", "--record"])
        .arg(&record)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(!record.exists() && !out.exists());
}

/// MotionCal's `Raw:` lines of `rows` (nT in [P1]'s axes; the sketch's units are 0.1 uT).
pub(crate) fn raw_lines(rows: &[[f64; 6]]) -> String {
    rows.iter()
        .map(|r| {
            format!(
                "Raw:0,0,0,0,0,0,{},{},{}\n",
                (r[3] / 100.0).round(),
                (r[4] / 100.0).round(),
                (r[5] / 100.0).round()
            )
        })
        .collect()
}

#[test]
fn a_stream_is_not_usable_before_it_meets_the_heading_budget_and_nothing_is_exported() {
    // 241 readings of the vessel's plan turned round and round (the vessel rolls 15 and pitches
    // 8 degrees at 75 degrees of inclination, 50 nT of noise): a fit its own trials confirm, as
    // live's first usable fit was once, but the heading it leaves at every heading over the box
    // is beyond 2 degrees. No export is printed, nothing is called usable.
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    let usv = simulated(tmp.path(), "../../scenarios/usv.toml", "plan300", 21);
    let o = magcal()
        .args(["live", "-", "--json", "--scenario", "../../scenarios/usv.toml", "--out"])
        .arg(&out)
        .write_stdin(raw_lines(&usv[..241]))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    let live: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (&live["usable"], &live["written_usable"]),
        (&false.into(), &false.into()),
        "{live}"
    );
    // (--json: the report of the end alone on standard output; without it, "usable at" and
    // the export would be there.)
    assert!(!err.contains("usable at") && !err.contains("its export"), "{err}");
    assert!(live.get("export").is_none_or(Value::is_null), "{live}");
    let reasons = live["reasons"].as_str().unwrap_or_default();
    assert!(reasons.starts_with("heading budget not met"), "{reasons}");
    // Every status line with a fit says where it stands against the budget.
    let fits: Vec<&str> = err.lines().filter(|l| l.contains("| fit ")).collect();
    assert!(!fits.is_empty(), "{err}");
    assert!(
        fits.iter().all(|l| !l.contains("USABLE"))
            && fits
                .iter()
                .any(|l| l.contains(" deg (95th percentile) against a budget of 2 deg")),
        "{fits:#?}"
    );
    // The glider's whole plan, turned round and round: usable, and only now the export.
    let all = simulated(tmp.path(), "../../scenarios/glider.toml", "plan300", 21);
    let out2 = tmp.path().join("out2");
    let o = magcal()
        .args(["live", "-", "--out"])
        .arg(&out2)
        .write_stdin(raw_lines(&all))
        .output()
        .unwrap();
    let (said, err) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(said.contains("usable at") && said.contains("its export"), "{said}");
    // The export names the log as the set does: the source, not the temporary snapshot a fit
    // read (gone when live ends).
    assert!(said.contains("(log standard input (live), fit "), "{said}");
    let cal = json_of(&out2.join("calibration.json"));
    assert_eq!(cal["log"], "standard input (live)");
    assert!(
        cal["heading_budget"]["met"] == true && cal["heading_budget"]["predicted_deg"].as_f64().unwrap() < 2.0,
        "{}",
        cal["heading_budget"]
    );
}

#[test]
fn a_stream_that_ends_without_a_usable_fit_writes_the_last_and_exits_3() {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    // Twenty readings at one attitude: nothing is determined.
    let text: String = (0..20)
        .map(|i| format!("Raw:0,0,0,0,0,0,{},{},{}\n", 200 + i % 2, -100, 400))
        .collect();
    let o = magcal()
        .args(["live", "-", "--json", "--out"])
        .arg(&out)
        .write_stdin(text)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "{}", String::from_utf8_lossy(&o.stderr));
    let live: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(live["usable"], false);
    assert_eq!(live["written_usable"], false);
    assert_eq!(live["readings"], 20);
    // No model fits twenty readings at one attitude: nothing to write.
    assert_eq!(live["written_fit"], Value::Null);
    assert!(!out.exists());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("no fit was usable") && err.contains("nothing written"),
        "{err}"
    );
    // Forty at attitudes that determine a fit the verdict refuses: its set is written, and says so.
    let rows = simulated(tmp.path(), "../../scenarios/usv.toml", "optimum12", 1);
    let text: String = rows
        .iter()
        .take(12)
        .map(|r| {
            format!(
                "Raw:0,0,0,0,0,0,{},{},{}\n",
                (r[3] / 100.0).round(),
                (r[4] / 100.0).round(),
                (r[5] / 100.0).round()
            )
        })
        .collect();
    let o = magcal()
        .args(["live", "-", "--json", "--out"])
        .arg(&out)
        .write_stdin(text)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    let live: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(live["written_usable"], false, "{live}");
    assert_eq!(json_of(&out.join("calibration.json"))["usable"], false);
    assert!(err.contains("its set is in"), "{err}");
}

/// The page's `/status.json`, or `None` once the page is gone (live ended).
pub(crate) fn page_status(page: &str) -> Option<Vec<u8>> {
    use std::io::{Read, Write};
    let mut stream = std::net::TcpStream::connect(page).ok()?;
    write!(
        stream,
        "GET /status.json HTTP/1.1\r\nHost: {page}\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut reply = Vec::new();
    stream.read_to_end(&mut reply).ok()?;
    let end = reply.windows(4).position(|w| w == b"\r\n\r\n")?;
    reply.starts_with(b"HTTP/1.1 200").then(|| reply[end + 4..].to_vec())
}

/// One HTTP/1.1 request to the page's server: the status code and the body.
pub(crate) fn http(addr: &str, method: &str, path: &str, host: &str) -> (u16, Vec<u8>) {
    use std::io::Read;
    let mut stream = std::net::TcpStream::connect(addr).unwrap();
    write!(
        stream,
        "{method} {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut reply = Vec::new();
    stream.read_to_end(&mut reply).unwrap();
    let end = reply.windows(4).position(|w| w == b"\r\n\r\n").expect("a header");
    let code = String::from_utf8_lossy(&reply[9..12]).parse().unwrap();
    (code, reply[end + 4..].to_vec())
}

/// The page's status once `done` holds of it (at most 60 s).
fn status_when(addr: &str, done: impl Fn(&Value) -> bool) -> Value {
    let started = std::time::Instant::now();
    loop {
        let (code, body) = http(addr, "GET", "/status.json", addr);
        assert_eq!(code, 200);
        let status: Value = serde_json::from_slice(&body).unwrap();
        if done(&status) {
            return status;
        }
        assert!(started.elapsed() < Duration::from_secs(60), "{status}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The drawing of a canvas of the page, as PNG bytes.
fn canvas(tab: &crate::browser::Tab, id: &str) -> Vec<u8> {
    use base64::Engine;
    let url = tab
        .evaluate(&format!("document.getElementById('{id}').toDataURL('image/png')"))
        .unwrap();
    let data = url.as_str().unwrap().strip_prefix("data:image/png;base64,").unwrap();
    base64::engine::general_purpose::STANDARD.decode(data).unwrap()
}

/// A drag of the mouse across the element `id`, from its centre by (`dx`, `dy`) CSS pixels, as
/// DevTools sends a real one (the page sees pointer events).
fn drag(tab: &crate::browser::Tab, id: &str, dx: f64, dy: f64) {
    let at = tab
        .evaluate(&format!(
            "(() => {{ const e = document.getElementById('{id}'); e.scrollIntoView({{block: 'center'}}); const r = e.getBoundingClientRect(); return [r.left + r.width / 2, r.top + r.height / 2]; }})()"
        ))
        .unwrap();
    let (x, y) = (at[0].as_f64().unwrap(), at[1].as_f64().unwrap());
    let steps = [
        ("mousePressed", 0.0, 1),
        ("mouseMoved", 0.5, 1),
        ("mouseMoved", 1.0, 1),
        ("mouseReleased", 1.0, 0),
    ];
    for (kind, part, buttons) in steps {
        let event = serde_json::json!({
            "type": kind, "x": x + part * dx, "y": y + part * dy,
            "button": "left", "buttons": buttons, "clickCount": 1,
        });
        tab.call("Input.dispatchMouseEvent", event).unwrap();
    }
    // A frame or two, for the drawing.
    std::thread::sleep(Duration::from_millis(300));
}

/// The page's text of `id` once the page shows the fit `fit` (at most 30 s).
fn page_text_at(tab: &crate::browser::Tab, fit: u64, id: &str) -> String {
    let started = std::time::Instant::now();
    loop {
        let verdict = tab.evaluate("document.getElementById('verdict').textContent").unwrap();
        if verdict.as_str().is_some_and(|v| v.contains(&format!("fit {fit},"))) {
            return tab
                .evaluate(&format!("document.getElementById('{id}').textContent"))
                .unwrap()
                .as_str()
                .unwrap()
                .to_string();
        }
        assert!(started.elapsed() < Duration::from_secs(30), "{verdict}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn the_live_page_follows_the_stream_in_a_browser_and_asks_nothing_beyond_its_server() {
    let Some(browser) = crate::browser::chromium() else {
        return;
    };
    let tmp = TempDir::new().unwrap();
    let scenario = "../../scenarios/glider.toml";
    let rows = simulated(tmp.path(), scenario, "plan300", 11);
    let frames = vehicle_frames(&rows);
    let out = tmp.path().join("out");
    let (child, first, stderr) = start_live_lines(
        &[
            "udpin:127.0.0.1:0",
            "--out",
            out.to_str().unwrap(),
            "--scenario",
            scenario,
            "--page",
            "0",
            "--every",
            "0.2",
            // Counted from the start while nothing arrived: the page loads before the vehicle
            // sends, and a loaded machine may take seconds to start the browser's tab.
            "--idle",
            "15",
            "--json",
        ],
        2,
    );
    let udp = udp_address(&first[0]);
    let addr = first[1]
        .strip_prefix("live: page at http://")
        .and_then(|s| s.strip_suffix('/'))
        .unwrap_or_else(|| panic!("{first:?}"))
        .to_string();
    assert!(addr.starts_with("127.0.0.1:"), "{addr}");
    // Another host's name for the same address, and a method that is not GET, are refused.
    assert_eq!(http(&addr, "GET", "/status.json", "attacker.example:80").0, 403);
    assert_eq!(http(&addr, "POST", "/status.json", &addr).0, 405);
    assert_eq!(http(&addr, "GET", "/../calibration.json", &addr).0, 404);
    let tab = browser.new_tab().unwrap();
    for domain in ["Runtime", "Network", "Page", "Log"] {
        tab.call(&format!("{domain}.enable"), serde_json::json!({})).unwrap();
    }
    tab.call("Page.bringToFront", serde_json::json!({})).unwrap();
    let url = format!("http://{addr}/");
    tab.call("Page.navigate", serde_json::json!({ "url": url })).unwrap();
    tab.wait_for("Page.loadEventFired", Duration::from_secs(60)).unwrap();
    let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
    let send = |frames: &[Vec<u8>]| fly(&vehicle, frames, &udp);
    // The heartbeat, the nine parameters and the first third of the turns, then the rest.
    let third = 10 + 2 * (rows.len() / 3);
    send(&frames[..third]);
    let early = status_when(&addr, |s| s["readings"] == rows.len() / 3);
    let fit = early["fit"].as_u64().unwrap();
    let early_next = page_text_at(&tab, fit, "next");
    let early_shots = [canvas(&tab, "sphere"), canvas(&tab, "box"), canvas(&tab, "headings")];
    send(&frames[third..]);
    let late = status_when(&addr, |s| s["readings"] == rows.len());
    let late_fit = late["fit"].as_u64().unwrap();
    let late_next = page_text_at(&tab, late_fit, "next");
    let late_shots = [canvas(&tab, "sphere"), canvas(&tab, "box"), canvas(&tab, "headings")];
    // The coverage grew where the vehicle turned: every figure was drawn again, differently.
    for (k, (a, b)) in early_shots.iter().zip(&late_shots).enumerate() {
        assert_ne!(a, b, "figure {k} unchanged");
    }
    assert!(late["attitudes"].as_array().unwrap().len() > early["attitudes"].as_array().unwrap().len());
    // The page says the attitude of each status, as the status gives it: the plan's first target
    // in its words where the status has a plan, else the next attitude.
    for (text, status) in [(&early_next, &early), (&late_next, &late)] {
        if let Some(words) = status["plan"][0]["words"].as_str() {
            assert_eq!(text, words, "{status}");
            continue;
        }
        // Rounded as the page rounds: -0.3 is "0".
        let roll = status["next"]["roll_deg"].as_f64().unwrap().round() + 0.0;
        assert!(text.starts_with(&format!("roll {roll:.0}, pitch ")), "{text} {status}");
    }
    assert_ne!(early["next"], late["next"], "the next attitude did not change");
    let (live, lines, code) = finish_live(child, &stderr);
    assert_eq!(code, 0, "{lines:#?}");
    assert_eq!(live["usable"], true);
    // The sphere to turn, with the last status: drawn (the shaded ball is a third of its canvas),
    // held still once dragged, in the view it has when a status is shown again, and turned by a
    // drag.
    let globe = || canvas(&tab, "globe");
    let drawn = image::load_from_memory(&globe()).unwrap().to_rgba8();
    let (share, colours) = crate::browser::pixel_statistics(&drawn);
    assert!(
        share > 0.2 && colours > 20,
        "the sphere: {share} of its pixels drawn, {colours} colours"
    );
    drag(&tab, "globe", 40.0, 15.0);
    let held = globe();
    tab.evaluate("show(globe.status)").unwrap();
    std::thread::sleep(Duration::from_millis(300));
    assert!(
        globe() == held,
        "the sphere turned back (or on) when its status was shown again"
    );
    drag(&tab, "globe", 60.0, -30.0);
    assert!(globe() != held, "a drag did not turn the sphere");
    // Nothing but the page's own server was asked for anything, and nothing failed.
    let mut asked = Vec::new();
    for event in tab.events() {
        match event["method"].as_str() {
            Some("Network.requestWillBeSent") => {
                asked.push(event["params"]["request"]["url"].as_str().unwrap().to_string());
            }
            Some("Runtime.exceptionThrown") => panic!("{event}"),
            Some("Runtime.consoleAPICalled") if event["params"]["type"] == "error" => panic!("{event}"),
            _ => {}
        }
    }
    assert!(asked.iter().any(|u| u.ends_with("/status.json")), "{asked:?}");
    let own = format!("http://{addr}/");
    assert!(asked.iter().all(|u| u.starts_with(&own)), "{asked:?}");
    let _ = tab.close();
}

/// The test vehicle's autopilot: answers each `PARAM_SET` that reaches `socket` with the
/// `PARAM_VALUE` of the value it then holds (`hold` of the name and the value sent), until `stop`.
/// Returns the parameters it was sent.
fn autopilot(
    socket: UdpSocket,
    hold: fn(&str, f32) -> f32,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> std::thread::JoinHandle<Vec<(String, f32)>> {
    std::thread::spawn(move || {
        socket.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
        let mut framer = magcal_runner::log::tlog::Framer::default();
        let mut got = Vec::new();
        let mut buf = [0u8; 2048];
        while !stop.load(std::sync::atomic::Ordering::Relaxed) {
            let Ok((n, from)) = socket.recv_from(&mut buf) else {
                continue;
            };
            let mut sets = Vec::new();
            framer.push(&buf[..n], |frame, id| {
                if id == 23 {
                    let header = if frame[0] == 0xFD { 10 } else { 6 };
                    let mut p = frame[header..header + usize::from(frame[1])].to_vec();
                    p.resize(23, 0);
                    let value = f32::from_le_bytes([p[0], p[1], p[2], p[3]]);
                    let end = p[6..22].iter().position(|&b| b == 0).unwrap_or(16);
                    sets.push((String::from_utf8_lossy(&p[6..6 + end]).into_owned(), value));
                }
            });
            for (name, value) in sets {
                let reply = frame(&MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
                    param_value: hold(&name, value),
                    param_count: 0,
                    param_index: 0,
                    param_id: name.as_str().into(),
                    param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
                }));
                socket.send_to(&reply, from).unwrap();
                got.push((name, value));
            }
        }
        got
    })
}

/// `live --send` against the test vehicle whose autopilot holds `hold` of each value sent.
fn send_to_vehicle(hold: fn(&str, f32) -> f32) -> (Value, Vec<String>, i32, Vec<(String, f32)>, TempDir) {
    let tmp = TempDir::new().unwrap();
    let scenario = "../../scenarios/glider.toml";
    let frames = vehicle_frames(&simulated(tmp.path(), scenario, "plan300", 5));
    let out = tmp.path().join("out");
    let (child, first, stderr) = start_live(&["udpin:127.0.0.1:0", "--out", out.to_str().unwrap(), "--send", "--json"]);
    let addr = udp_address(&first);
    let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let pilot = autopilot(vehicle.try_clone().unwrap(), hold, std::sync::Arc::clone(&stop));
    fly(&vehicle, &frames, &addr);
    let (live, lines, code) = finish_live(child, &stderr);
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    (live, lines, code, pilot.join().unwrap(), tmp)
}

#[test]
fn a_usable_calibration_sent_to_the_vehicle_is_read_back_and_a_value_it_does_not_hold_is_named() {
    let (live, lines, code, got, tmp) = send_to_vehicle(|_, v| v);
    assert_eq!(code, 0, "{lines:#?}");
    assert_eq!(live["usable"], true);
    // The vehicle was sent every parameter of the ArduPilot export, with its value.
    let export = magcal()
        .args(["export"])
        .arg(tmp.path().join("out/calibration.json"))
        .args(["--to", "ardupilot"])
        .output()
        .unwrap();
    let text = String::from_utf8(export.stdout).unwrap();
    let exported: Vec<(String, f32)> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty())
        .map(|l| {
            let (n, v) = l.split_once(',').unwrap();
            (n.to_string(), v.parse::<f64>().unwrap() as f32)
        })
        .collect();
    assert!(exported.len() >= 10, "{text}");
    let mut sent = got.clone();
    sent.sort_by(|a, b| a.0.cmp(&b.0));
    sent.dedup_by(|a, b| a.0 == b.0);
    let mut wanted = exported.clone();
    wanted.sort_by(|a, b| a.0.cmp(&b.0));
    assert_eq!(sent, wanted);
    assert_eq!(
        live["sent"]["equal"].as_array().unwrap().len(),
        exported.len(),
        "{live}"
    );
    assert_eq!(live["sent"]["system"], 1);
    assert!(
        lines
            .iter()
            .any(|l| l.contains(&format!("{} read back equal", exported.len()))),
        "{lines:#?}"
    );
    // An autopilot that rounds the offsets to whole mGauss does not hold what was sent: named.
    let (live, lines, code, _, _) = send_to_vehicle(|n, v| if n == "COMPASS_OFS_X" { v.round() + 0.5 } else { v });
    assert_eq!(code, 3, "{lines:#?}");
    assert_eq!(live["sent"]["differ"][0][0], "COMPASS_OFS_X", "{live}");
    let last = lines.last().unwrap();
    assert!(
        last.contains("does not hold") && last.contains("COMPASS_OFS_X reads back"),
        "{last}"
    );
}

#[test]
fn a_flood_beyond_the_memory_bound_keeps_the_newest_readings_and_counts_what_it_dropped() {
    let tmp = TempDir::new().unwrap();
    let rows = simulated(tmp.path(), "../../scenarios/glider.toml", "plan300", 9);
    let frames = vehicle_frames(&rows);
    // The heartbeat and the nine parameters in force once, then the turns forty times over:
    // 24,000 records.
    let mut flood: Vec<Vec<u8>> = frames[..10].to_vec();
    for k in 0..40 {
        flood.extend(turns(&rows, 1000 + 20 * (k * rows.len()) as u32));
    }
    let (out, record) = (tmp.path().join("out"), tmp.path().join("flood.tlog"));
    let (child, first, stderr) = start_live(&[
        "udpin:127.0.0.1:0",
        "--out",
        out.to_str().unwrap(),
        "--record",
        record.to_str().unwrap(),
        "--memory",
        "1",
        "--idle",
        "2",
        "--json",
    ]);
    let addr = udp_address(&first);
    let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
    for chunk in flood.chunks(40) {
        vehicle.send_to(&chunk.concat(), &addr).unwrap();
        std::thread::sleep(Duration::from_micros(200));
    }
    let (live, lines, code) = finish_live(child, &stderr);
    // The verdict is calibrate's (this nominal sensor's calibration can be no better than its raw
    // readings, which thousands of readings show): 0 or 3, said either way.
    assert_eq!(code, if live["usable"] == true { 0 } else { 3 }, "{lines:#?}");
    let (frames_in, dropped) = (
        live["frames"].as_u64().unwrap(),
        live["dropped_records"].as_u64().unwrap(),
    );
    let readings = live["readings"].as_u64().unwrap();
    // What arrived is all recorded; what did not fit in 1 MiB was dropped oldest first and
    // counted, the parameters kept (the offsets are still undone: the fit is usable).
    assert!(frames_in > 20_000, "{live}");
    assert_eq!(
        std::fs::read(&record).unwrap().len() as u64,
        flood.iter().map(|f| 8 + f.len() as u64).sum::<u64>(),
        "every record arrived and was written"
    );
    assert!(dropped > 5_000, "{live}");
    // Held: the nine parameters pinned, and the newest records, two a reading (the oldest
    // reading held may have lost its attitude).
    assert!(readings.abs_diff((frames_in - dropped - 9) / 2) <= 1, "{live}");
    assert!(readings < 6_500, "{live}");
    // The parameters outlived the drop: the offsets in force are undone, the bias is the
    // simulated sensor's, not less the offsets (-30 and 12.5 mG on x and y). The flood repeats
    // the same 300 readings, their noise too: the standard errors of the copies held shrink by
    // the root of their number, what the readings hold does not.
    let written = json_of(&out.join("calibration.json"));
    assert_eq!(written["samples"], readings);
    let copies = (readings as f64 / rows.len() as f64).sqrt();
    for a in 0..2 {
        let (b, se) = (
            written["bias"][a].as_f64().unwrap(),
            written["std_error"]["bias"][a].as_f64().unwrap(),
        );
        assert!(
            (b - GLIDER_BIAS_FRD[a]).abs() < 4.0 * se * copies && se < 5.0,
            "bias {a}: {b} +- {se} ({copies:.1} x)"
        );
    }
    let held = lines.iter().rev().find(|l| l.contains(" of 1 MiB held")).unwrap();
    assert!(held.contains(&format!("{dropped} records dropped")), "{held}");
}

/// The calibration numbers of two sets that must agree to the bit.
fn assert_same_calibration(a: &Path, b: &Path) {
    let (a, b) = (
        json_of(&a.join("calibration.json")),
        json_of(&b.join("calibration.json")),
    );
    for key in SAME {
        assert_eq!(a[key], b[key], "{key}");
    }
}

#[test]
fn mavlink_from_a_tcp_server_and_through_a_serial_line_calibrate_as_their_recordings() {
    let tmp = TempDir::new().unwrap();
    let scenario = "../../scenarios/glider.toml";
    let frames = vehicle_frames(&simulated(tmp.path(), scenario, "plan300", 13));
    // A TCP server (as SITL's 5760) that streams the vehicle's frames, then ends its side: the
    // end. It reads what live asks of it (as an autopilot does) until live closes, so that its
    // close is orderly rather than a reset.
    let server = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = server.local_addr().unwrap().port();
    let bytes = frames.concat();
    let serving = std::thread::spawn(move || {
        let (mut client, _) = server.accept().unwrap();
        let mut reader = client.try_clone().unwrap();
        let draining = std::thread::spawn(move || {
            let mut asked = Vec::new();
            std::io::Read::read_to_end(&mut reader, &mut asked).unwrap();
            asked.len()
        });
        for chunk in bytes.chunks(700) {
            client.write_all(chunk).unwrap();
            std::thread::sleep(Duration::from_millis(1));
        }
        client.shutdown(std::net::Shutdown::Write).unwrap();
        draining.join().unwrap()
    });
    let (out, record) = (tmp.path().join("tcp"), tmp.path().join("tcp.tlog"));
    let source = format!("tcp:127.0.0.1:{port}");
    let (child, _, stderr) = start_live(&[
        &source,
        "--out",
        out.to_str().unwrap(),
        "--record",
        record.to_str().unwrap(),
        "--json",
    ]);
    let (live, lines, code) = finish_live(child, &stderr);
    serving.join().unwrap();
    assert_eq!(code, 0, "{lines:#?}");
    assert_eq!(live["frames"], frames.len() as u64);
    let again = tmp.path().join("tcp-again");
    magcal()
        .args(["calibrate", record.to_str().unwrap(), "--out"])
        .arg(&again)
        .assert()
        .success();
    assert_same_calibration(&out, &again);
    // The same frames through a serial line (a pseudo-terminal at 57600 baud), which then hangs up.
    let (mut master, slave) = pty();
    let (out, record) = (tmp.path().join("serial"), tmp.path().join("serial.tlog"));
    let source = format!("serial:{slave}:57600");
    let (child, first, stderr) = start_live(&[
        &source,
        "--out",
        out.to_str().unwrap(),
        "--record",
        record.to_str().unwrap(),
        "--json",
    ]);
    assert!(first.starts_with(&format!("live: reading {source}")), "{first}");
    for chunk in frames.concat().chunks(512) {
        master.write_all(chunk).unwrap();
    }
    master.flush().unwrap();
    std::thread::sleep(Duration::from_millis(500));
    drop(master);
    let (live, lines, code) = finish_live(child, &stderr);
    assert_eq!(code, 0, "{lines:#?}");
    assert_eq!(live["frames"], frames.len() as u64, "{live}");
    let again = tmp.path().join("serial-again");
    magcal()
        .args(["calibrate", record.to_str().unwrap(), "--out"])
        .arg(&again)
        .assert()
        .success();
    assert_same_calibration(&out, &again);
}

#[test]
fn ctrl_c_ends_live_with_its_set_and_its_recording_whole() {
    let tmp = TempDir::new().unwrap();
    let scenario = "../../scenarios/glider.toml";
    let frames = vehicle_frames(&simulated(tmp.path(), scenario, "plan300", 17));
    let (out, record) = (tmp.path().join("out"), tmp.path().join("stream.tlog"));
    let (child, first, stderr) = start_live(&[
        "udpin:127.0.0.1:0",
        "--out",
        out.to_str().unwrap(),
        "--record",
        record.to_str().unwrap(),
        "--every",
        "0.2",
        "--json",
    ]);
    let addr = udp_address(&first);
    let vehicle = UdpSocket::bind("127.0.0.1:0").unwrap();
    fly(&vehicle, &frames, &addr);
    // A network source has no end: the operator's Ctrl-C ends it, once the set is usable.
    let started = std::time::Instant::now();
    while !out.join("calibration.json").exists() {
        assert!(started.elapsed() < Duration::from_secs(60), "no set written");
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(500));
    // SAFETY: kill(2) with the pid of a child of this process.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) }, 0);
    let (live, lines, code) = finish_live(child, &stderr);
    assert_eq!(code, 0, "{lines:#?}");
    assert_eq!(live["usable"], true);
    // The recording holds every frame whole, and the set is the one calibrate makes of it.
    assert_eq!(
        std::fs::read(&record).unwrap().len(),
        frames.iter().map(|f| 8 + f.len()).sum::<usize>()
    );
    assert_eq!(live["readings"], 300, "{live}");
    let again = tmp.path().join("again");
    magcal()
        .args(["calibrate", record.to_str().unwrap(), "--out"])
        .arg(&again)
        .assert()
        .success();
    assert_same_calibration(&out, &again);
}

/// `child`'s exit code and standard output, killed (and the test failed) if it runs past
/// `bound`.
fn exit_within(mut child: Child, bound: Duration) -> (i32, String) {
    let started = std::time::Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut out = String::new();
            std::io::Read::read_to_string(&mut child.stdout.take().unwrap(), &mut out).unwrap();
            return (status.code().unwrap(), out);
        }
        if started.elapsed() > bound {
            let _ = child.kill();
            panic!("live still ran after {bound:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_stream_that_sends_nothing_ends_at_idle_and_what_arrived_without_a_fit_is_counted() {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    // Nobody sends to the port: --idle counts from the start, so live ends after about a second.
    let started = std::time::Instant::now();
    let child = magcal_process()
        .args(["live", "udpin:127.0.0.1:0", "--idle", "1", "--json", "--out"])
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let (code, stdout) = exit_within(child, Duration::from_secs(30));
    let seconds = started.elapsed().as_secs_f64();
    assert_eq!(code, 3, "{stdout}");
    assert!(seconds >= 1.0, "ended after {seconds} s, before --idle 1");
    let live: Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(
        (live["bytes"].as_u64(), live["fits"].as_u64()),
        (Some(0), Some(0)),
        "{live}"
    );
    assert_eq!(live["reasons"], "no readings arrived");
    assert!(!out.exists());

    // 500 lines of a kind that holds no reading (a sketch's `Info:` lines): no fit runs, and the
    // JSON still counts every line and byte.
    let junk = "Info: not a reading\n".repeat(500);
    let o = magcal()
        .args(["live", "-", "--json", "--out"])
        .arg(&out)
        .write_stdin(junk.clone())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "{}", String::from_utf8_lossy(&o.stderr));
    let live: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(live["fits"], 0, "{live}");
    assert_eq!(live["bytes"].as_u64(), Some(junk.len() as u64), "{live}");
    let counted = ["lines", "other_lines", "malformed_lines"].map(|k| live[k].as_u64().unwrap());
    assert_eq!(counted, [0, 500, 0], "{live}");
}
