//! Reading a 100 MB ArduPilot DataFlash log (`log::dataflash::read`: the file read, hashed and
//! parsed, three compasses' readings kept and one undone), generated here: a log as ArduPilot
//! writes one, `IMU` at 400 Hz for two IMUs making most of its bytes, `MAG` x3, `ATT`, `BAT`,
//! `CTUN` at 100 Hz, parameters at the start.
//!
//! Then the whole process on it, `magcal calibrate big.bin --json` (read, fit, JSON), with its
//! peak resident memory (the children's `ru_maxrss`).
//!
//! `cargo bench -p magcal-runner --bench flightlogs`

use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use magcal_runner::log::dataflash;
use magcal_runner::log::flight::Selection;

/// Bytes of the generated log.
const TARGET: usize = 100_000_000;

fn fmt(out: &mut Vec<u8>, t: u8, name: &str, format: &str, labels: &str, len: u8) {
    let mut p = [0u8; 86];
    p[0] = t;
    p[1] = len;
    p[2..2 + name.len()].copy_from_slice(name.as_bytes());
    p[6..6 + format.len()].copy_from_slice(format.as_bytes());
    p[22..22 + labels.len()].copy_from_slice(labels.as_bytes());
    out.extend([0xA3, 0x95, 0x80]);
    out.extend(p);
}

fn generate(path: &Path) {
    let mut out = Vec::with_capacity(TARGET + 1024);
    fmt(&mut out, 0x80, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns", 89);
    fmt(&mut out, 0x81, "PARM", "QNf", "TimeUS,Name,Value", 31);
    fmt(
        &mut out,
        0x82,
        "MAG",
        "QBhhhhhhhhhBI",
        "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S",
        35,
    );
    fmt(
        &mut out,
        0x83,
        "ATT",
        "QccccCCCC",
        "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw",
        27,
    );
    fmt(
        &mut out,
        0x84,
        "IMU",
        "QBffffffIIfBBHH",
        "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz",
        54,
    );
    fmt(&mut out, 0x85, "BAT", "QBff", "TimeUS,Inst,Volt,Curr", 20);
    fmt(&mut out, 0x86, "CTUN", "Qfff", "TimeUS,ThI,ThO,ThH", 23);
    for (name, v) in [
        ("COMPASS_OFS_X", -40.0f32),
        ("COMPASS_DIA_X", 1.02),
        ("COMPASS_ODI_X", 0.01),
    ] {
        out.extend([0xA3, 0x95, 0x81]);
        out.extend(0u64.to_le_bytes());
        let mut n = [0u8; 16];
        n[..name.len()].copy_from_slice(name.as_bytes());
        out.extend(n);
        out.extend(v.to_le_bytes());
    }
    let mut t: u64 = 1_000_000;
    let mut i: u64 = 0;
    while out.len() < TARGET {
        t += 2500;
        for imu in 0..2u8 {
            out.extend([0xA3, 0x95, 0x84]);
            out.extend(t.to_le_bytes());
            out.push(imu);
            for v in [0.01f32, -0.02, 0.005, 0.1, -0.2, -9.8] {
                out.extend(v.to_le_bytes());
            }
            out.extend([0u8; 8]);
            out.extend(25.0f32.to_le_bytes());
            out.extend([1, 1, 0x90, 0x01, 0x90, 0x01]);
        }
        if i.is_multiple_of(4) {
            for k in 0..3u8 {
                out.extend([0xA3, 0x95, 0x82]);
                out.extend(t.to_le_bytes());
                out.push(k);
                // The field turning through every direction, on an ellipsoid: a log the full
                // model calibrates.
                let (a, b) = ((i as f64) * 1e-3, (i as f64) * 3.7e-4);
                for v in [
                    480.0 * b.cos() * a.cos() + 30.0,
                    450.0 * b.cos() * a.sin() - 20.0,
                    430.0 * b.sin() + 60.0,
                ] {
                    out.extend((v as i16).to_le_bytes());
                }
                for v in [-40i16, 61, -118, 0, 0, 0] {
                    out.extend(v.to_le_bytes());
                }
                out.push(1);
                out.extend((t as u32).to_le_bytes());
            }
            out.extend([0xA3, 0x95, 0x83]);
            out.extend(t.to_le_bytes());
            for v in [0i16, 512, 0, -300] {
                out.extend(v.to_le_bytes());
            }
            for v in [0u16, ((i / 4) % 36_000) as u16, 0, 0] {
                out.extend(v.to_le_bytes());
            }
            out.extend([0xA3, 0x95, 0x85]);
            out.extend(t.to_le_bytes());
            out.push(0);
            out.extend(12.4f32.to_le_bytes());
            out.extend(8.5f32.to_le_bytes());
            out.extend([0xA3, 0x95, 0x86]);
            out.extend(t.to_le_bytes());
            for v in [0.4f32, 0.42, 0.4] {
                out.extend(v.to_le_bytes());
            }
        }
        i += 1;
    }
    std::fs::write(path, out).unwrap();
}

fn flightlogs(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("magcal-bench-flightlogs-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("big.bin");
    generate(&path);
    let all = Selection { instance: None };
    let log = dataflash::read(&path, &all).unwrap();
    eprintln!(
        "{} bytes: {} readings of compass {} (of {:?}), {} attitudes",
        log.bytes,
        log.samples.len(),
        log.instance,
        log.instances,
        log.attitude.as_ref().map_or(0, |a| a.times.len())
    );
    let mut group = c.benchmark_group("dataflash");
    group.sample_size(10);
    group.bench_function("read_100MB", |b| b.iter(|| dataflash::read(&path, &all).unwrap()));
    let one = Selection { instance: Some(0) };
    group.bench_function("read_100MB_compass_0", |b| {
        b.iter(|| dataflash::read(&path, &one).unwrap())
    });
    group.bench_function("calibrate_100MB_process", |b| {
        b.iter(|| {
            let out = std::process::Command::new(env!("CARGO_BIN_EXE_magcal"))
                .arg("calibrate")
                .arg(&path)
                .arg("--json")
                .output()
                .unwrap();
            let code = out.status.code();
            assert!(
                code == Some(0) || code == Some(3),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
        })
    });
    group.finish();
    // SAFETY: getrusage writes the struct it is given.
    let rss_kib = unsafe {
        let mut u: libc::rusage = std::mem::zeroed();
        libc::getrusage(libc::RUSAGE_CHILDREN, &mut u);
        u.ru_maxrss
    };
    eprintln!(
        "calibrate on {} bytes: peak resident memory {} MiB",
        log.bytes,
        rss_kib / 1024
    );
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, flightlogs);
criterion_main!(benches);
