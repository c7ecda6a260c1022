//! `magcal live` against ArduPilot's own firmware: the SITL copter of `../shared/sitl` (built for
//! this machine; see its README). A stock copter streams nothing a ground station did not ask
//! for: live must ask, and hear the calibration in force. Skipped, and said, where the firmware
//! is absent.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use tempfile::TempDir;

use crate::live::{finish_live, start_live};

/// The SITL firmware, where this machine has it.
fn arducopter() -> Option<PathBuf> {
    let p = PathBuf::from("../../../shared/sitl/arducopter");
    p.exists().then(|| p.canonicalize().unwrap())
}

/// A SITL copter in `dir` as instance `instance` (MAVLink on TCP 5760 + 10 instance), killed when
/// dropped.
struct Sitl(Child);

impl Sitl {
    fn start(binary: &PathBuf, dir: &std::path::Path, instance: u16) -> (Self, u16) {
        let defaults = binary.with_file_name("copter.parm");
        let child = Command::new(binary)
            .current_dir(dir)
            .args(["--model", "+", "--speedup", "1", "--defaults"])
            .arg(&defaults)
            .args([
                &format!("-I{instance}"),
                "--home",
                "52.17,4.41,0,0",
                "--wipe",
                "--serial0",
                "tcp:0",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let port = 5760 + 10 * instance;
        let started = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "SITL did not listen on {port}"
            );
            std::thread::sleep(Duration::from_millis(200));
        }
        (Self(child), port)
    }
}

impl Drop for Sitl {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn live_on_a_stock_sitl_copter_gets_its_readings_and_calibration_in_force_by_asking() {
    let Some(binary) = arducopter() else {
        eprintln!("skipped: ../shared/sitl/arducopter is absent");
        return;
    };
    let tmp = TempDir::new().unwrap();
    let (sitl, port) = Sitl::start(&binary, tmp.path(), 7);
    let out = tmp.path().join("out");
    let source = format!("tcp:127.0.0.1:{port}");
    let record = tmp.path().join("sitl.tlog");
    let (child, _, stderr) = start_live(&[
        &source,
        "--out",
        out.to_str().unwrap(),
        "--record",
        record.to_str().unwrap(),
        "--json",
        "--every",
        "2",
    ]);
    std::thread::sleep(Duration::from_secs(15));
    // Ctrl-C ends it, with what it has.
    unsafe {
        libc::kill(child.id() as i32, libc::SIGINT);
    }
    let (live, lines, code) = finish_live(child, &stderr);
    drop(sitl);
    // The copter on the ground, still: its readings are all one field, so no fit is usable.
    assert_eq!(code, 3, "{lines:#?}");
    assert_eq!(
        (&live["vehicle"][0], &live["vehicle"][1]),
        (&1.into(), &1.into()),
        "{live}"
    );
    // Asked once for its messages (their rates are 0 until a ground station asks), it streams
    // its compass at the 20 Hz asked: about 10 s of readings in the 15 s after it was asked.
    assert!(live["asked"]["streams"].as_u64().unwrap() >= 1, "{}", live["asked"]);
    let readings = live["readings"].as_u64().unwrap();
    assert!(readings >= 100, "{readings} readings: {live}");
    // Its calibration in force was asked for by name, and the firmware answered each: the
    // recording holds their PARAM_VALUE from system 1.
    assert!(live["asked"]["parameters"].as_u64().unwrap() >= 9, "{}", live["asked"]);
    let mut framer = magcal_runner::log::tlog::Framer::default();
    let mut heard = Vec::new();
    framer.push(&std::fs::read(&record).unwrap(), |frame, id| {
        let (header, system) = if frame[0] == 0xFD {
            (10, frame[5])
        } else {
            (6, frame[3])
        };
        if id == 22 && system == 1 {
            let mut p = frame[header..header + usize::from(frame[1])].to_vec();
            p.resize(25, 0);
            let end = p[8..24].iter().position(|&b| b == 0).unwrap_or(16);
            heard.push(String::from_utf8_lossy(&p[8..8 + end]).into_owned());
        }
    });
    for axis in ["X", "Y", "Z"] {
        for name in ["OFS", "DIA", "ODI"] {
            let p = format!("COMPASS_{name}_{axis}");
            assert!(heard.contains(&p), "{p} not heard: {heard:?}");
        }
    }
    assert!(live["sent"].is_null());
}
