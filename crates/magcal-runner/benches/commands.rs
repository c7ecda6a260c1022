//! Whole `magcal` processes on a log, with their targets: `calibrate` on the ck-explorer log
//! (12,000 readings) with its default check of 200 trials (5 s: "a few seconds") and with the
//! fewest trials `--trials` takes, 20 (1 s), which shows what the check costs; `next` with
//! K = 10 (5 s: it fits and checks the log with the suggested readings). The public log is read
//! from `../shared/data/` when it is there; else a synthetic log of the same size.
//!
//! `cargo bench -p magcal-runner --bench commands`
use std::path::{Path, PathBuf};
use std::process::Command;

use criterion::{Criterion, criterion_group, criterion_main};
use magcal_core::design::sources;
use magcal_core::rng::stream_rng;
use magcal_core::{AttitudeBox, paper};

fn log(dir: &Path) -> PathBuf {
    let public = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/ck-explorer/acc_mag_log.csv");
    if public.is_file() {
        return public;
    }
    eprintln!(
        "{} is absent: a synthetic log of 12,000 readings instead",
        public.display()
    );
    let field = paper::changsha_field();
    let mut rng = stream_rng(3, 0);
    let design = sources::random(&AttitudeBox::full(), 12_000, &mut rng);
    let readings = paper::true_error_model()
        .noisy_readings(&field.body_fields(&design), 30.0, &mut rng)
        .unwrap();
    let text: String = std::iter::once("mx,my,mz\n".to_string())
        .chain(
            readings
                .iter()
                .map(|s| format!("{},{},{}\n", s[0] / 1e5, s[1] / 1e5, s[2] / 1e5)),
        )
        .collect();
    let path = dir.join("log.csv");
    std::fs::write(&path, text).unwrap();
    path
}

fn run(args: &[&std::ffi::OsStr]) {
    let out = Command::new(env!("CARGO_BIN_EXE_magcal")).args(args).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

fn commands(c: &mut Criterion) {
    let tmp = std::env::temp_dir().join(format!("magcal-bench-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let log = log(&tmp);
    let cal = tmp.join("cal");
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/drone.toml");
    let mut group = c.benchmark_group("process");
    group.sample_size(10);
    group.bench_function("calibrate_ck_explorer", |b| {
        b.iter(|| run(&["calibrate".as_ref(), log.as_os_str(), "--json".as_ref()]))
    });
    group.bench_function("calibrate_ck_explorer_trials_20", |b| {
        b.iter(|| {
            run(&[
                "calibrate".as_ref(),
                log.as_os_str(),
                "--json".as_ref(),
                "--trials".as_ref(),
                "20".as_ref(),
            ])
        })
    });
    run(&["calibrate".as_ref(), log.as_os_str(), "--out".as_ref(), cal.as_os_str()]);
    let json = cal.join("calibration.json");
    group.bench_function("next_k10_drone_box", |b| {
        b.iter(|| {
            run(&[
                "next".as_ref(),
                json.as_os_str(),
                log.as_os_str(),
                "--scenario".as_ref(),
                scenario.as_os_str(),
                "--count".as_ref(),
                "10".as_ref(),
            ])
        })
    });
    group.finish();
    let _ = std::fs::remove_dir_all(&tmp);
}

criterion_group!(benches, commands);
criterion_main!(benches);
