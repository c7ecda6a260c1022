//! `live`'s bound on each fit ([`calibrate_within`], [`suggestion_within`]): the fit that held
//! `live` up for 149 s no longer computes what stalled it, and that stage ends within its bound,
//! or at once on a signal; a stage cut short is said; with a bound it does not reach, every byte
//! is what it is without one.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use clap::Parser;
use magcal_core::stop::Stopped;
use magcal_runner::commands::calibrate::{CalibrateArgs, Calibrated, calibrate, calibrate_within};
use magcal_runner::commands::next::{NextArgs, suggestion, suggestion_within};
use magcal_runner::deadline::Deadline;
use magcal_runner::log::calibration::CalibrationJson;
use magcal_runner::log::read::HELD_BYTES_PER_READING;
use magcal_runner::log::source;
use magcal_runner::log::vehicle::{Vehicle, log_efficiency};
use tempfile::TempDir;

/// 43 readings (uT) of a tumble that covers little: 120 degrees of yaw with roll and pitch within
/// 10 degrees, in a field of 51 uT, of a sensor with a bias of (12, -7, 20) uT, scale factors
/// within 5 % and cross terms within 0.03, at 0.3 uT of noise. Its full fit does not settle
/// (not_converged after 500 iterations, at psi (-86, -78, -5) degrees), and the certificate of
/// the box of every roll and pitch under that sensor does not converge: 12 rounds of REX on a
/// support of 250 to 420 points, 73 to 92 s of a `calibrate` that takes 0.03 s without the box
/// (measured on this two-core machine, before that certificate was left out for a fit that does
/// not determine its sensor). `live` was held up 149 s on such a fit.
const STALLED: &str = "17.9482,-4.5570,71.8088 17.4205,-4.5960,71.7771 17.5241,-4.0169,71.7860 18.1407,-2.8178,71.3934 \
18.4553,-2.5107,71.1448 19.0443,-2.0498,72.2350 19.4397,-2.0168,71.8070 19.9907,-1.7229,71.2471 \
20.5935,-1.9216,71.4867 21.1958,-3.0082,71.3320 21.8283,-3.1468,71.1783 22.7847,-4.2791,71.0755 \
23.3023,-5.7014,70.7719 23.5735,-6.0864,70.7066 24.5041,-7.9700,70.4456 24.3788,-9.4820,70.1468 \
25.5331,-11.8849,69.8143 26.0952,-12.8542,69.1678 25.6348,-15.1156,69.3300 26.3057,-16.8183,68.3183 \
26.5543,-18.3304,67.9538 25.9592,-20.5613,67.7697 25.7638,-21.9082,66.7127 26.0177,-23.3501,66.5223 \
26.1547,-24.3707,66.4909 25.1805,-25.6641,65.8685 23.7602,-26.3418,65.5789 23.4975,-26.7733,65.2668 \
22.2578,-27.3228,65.1811 21.8398,-27.4078,66.0278 20.9047,-27.2286,66.0774 19.0913,-26.4620,66.0612 \
18.4193,-26.5485,66.6079 16.7222,-24.7926,67.6913 15.1257,-24.3899,67.7501 13.6878,-23.2372,68.9237 \
11.6217,-21.7750,69.0308 10.0991,-19.9565,69.8318 8.7479,-18.2362,70.5586 6.4072,-16.8273,69.9962 \
5.0521,-14.8262,70.6585 3.2366,-13.8263,70.7931 1.6720,-12.6823,71.0683";

/// The bound given to the stalled fit, and the most it may take. Once the bound passes, the work
/// left is the step under way: a support point of REX's exchanges (about 0.5 ms on 400 points
/// against 450 candidates), a start of the certificate's local search (milliseconds), then the
/// certificate's grid of 20,000 candidates (tens of milliseconds). Measured at a load average of
/// 8 on two cores: the stalled test 2.53 s in all (2 s, 0.5 s to the signal, and its fits), the
/// certificate cut short at 1 s 1.01 s with its fit; each bound overrun by tens of milliseconds.
/// The margin of 3 s is for cores other processes hold.
const BOUND: Duration = Duration::from_secs(2);
const MOST: Duration = Duration::from_secs(5);

#[derive(Parser)]
struct Calibrate {
    #[command(flatten)]
    args: CalibrateArgs,
}

#[derive(Parser)]
struct Next {
    #[command(flatten)]
    args: NextArgs,
}

/// `CalibrateArgs` of `calibrate LOG ARGS`.
fn calibrate_args(log: &Path, args: &[&str]) -> CalibrateArgs {
    let mut argv = vec!["calibrate".to_string(), log.display().to_string()];
    argv.extend(args.iter().map(|a| a.to_string()));
    Calibrate::parse_from(argv).args
}

/// The box of roll and pitch over every angle at Trondheim, as `live --roll --pitch` gives it.
const BOX: [&str; 6] = [
    "--site",
    "63.43,10.40,50",
    "--date",
    "2026.5",
    "--roll=-180,180",
    "--pitch=-90,90",
];

/// `calibrate_within` of the log at `path` under `args`, and how long it took.
fn timed(args: &CalibrateArgs, path: &Path, deadline: &Deadline) -> (Calibrated, Duration) {
    let mut log = source::open(path, &args.input, HELD_BYTES_PER_READING).unwrap();
    let started = Instant::now();
    let calibrated = calibrate_within(args, &mut log, deadline).unwrap();
    (calibrated, started.elapsed())
}

/// The stalled log, written to `dir`.
fn stalled_log(dir: &Path) -> PathBuf {
    let path = dir.join("stalled.csv");
    let rows: Vec<String> = STALLED.split(' ').map(str::to_string).collect();
    std::fs::write(&path, format!("x,y,z\n{}\n", rows.join("\n"))).unwrap();
    path
}

fn fitted(c: Calibrated) -> CalibrationJson {
    match c {
        Calibrated::Fit { json, .. } => *json,
        Calibrated::NoFit(j) => panic!("no fit: {:?}", j.reasons),
    }
}

#[test]
fn the_stalled_fit_ends_within_its_bound_and_says_what_it_skipped() {
    let tmp = TempDir::new().unwrap();
    let path = stalled_log(tmp.path());
    let args = calibrate_args(&path, &[&["--units", "uT"][..], &BOX[..]].concat());
    // The fit does not determine its sensor, so the box's certificate under it is not computed:
    // `calibrate` is as quick with the box as without it (0.03 s), and says why the figure is
    // missing.
    let (calibrated, took) = timed(&args, &path, &Deadline::none());
    assert!(took < MOST, "{took:?}");
    let json = fitted(calibrated);
    assert_eq!(
        (json.samples, json.status.as_str(), json.identifiable, json.usable),
        (43, "not_converged", false, false)
    );
    assert_eq!(json.coverage.d_efficiency_per_reading, None);
    assert!(
        json.coverage
            .d_efficiency_why_not
            .as_deref()
            .unwrap()
            .starts_with("not computed: "),
        "{:?}",
        json.coverage.d_efficiency_why_not
    );
    assert!(
        json.coverage
            .box_from
            .as_deref()
            .unwrap()
            .contains("roll [-180.0, 180.0]")
    );
    // The stage that stalled, the certificate under that sensor, within its bound: given up, not
    // reported.
    let place = magcal_runner::log::vehicle::Place {
        site: args.site.unwrap(),
        date: args.date.unwrap(),
        model: None,
    };
    let vehicle = Vehicle::from_options(None, &args.attitude, Some(&place))
        .unwrap()
        .unwrap();
    let log = source::open(&path, &args.input, HELD_BYTES_PER_READING).unwrap();
    let certificate = |deadline: &Deadline| {
        let started = Instant::now();
        let efficiency = log_efficiency(
            &json,
            &vehicle,
            (&log.readings, &magcal_core::budget::IDENTITY),
            &deadline.stop(),
        )
        .unwrap();
        (efficiency, started.elapsed())
    };
    let (efficiency, took) = certificate(&Deadline::after(BOUND));
    assert!(took >= BOUND && took < MOST, "{took:?}");
    assert_eq!(efficiency, Err(Stopped));
    // A signal (a flag its handler sets) ends it under way: here 0.5 s in, far inside an hour's
    // bound.
    let signal = Arc::new(AtomicBool::new(false));
    let raised = Arc::clone(&signal);
    let deadline = Deadline::after(Duration::from_secs(3600)).or_when(move || raised.load(Ordering::Relaxed));
    let setter = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(500));
        signal.store(true, Ordering::Relaxed);
    });
    let (efficiency, took) = certificate(&deadline);
    setter.join().unwrap();
    assert!(
        took >= Duration::from_millis(500) && took < Duration::from_millis(500) + MOST - BOUND,
        "{took:?}"
    );
    assert_eq!(efficiency, Err(Stopped));
    assert_eq!(
        deadline.skipped("the coverage certificate"),
        "skipped: the coverage certificate was ended before it finished (the command is ending)"
    );
    // With no time left, the fit itself is skipped, and no model is said to fail the log.
    match timed(&args, &path, &Deadline::after(Duration::ZERO)).0 {
        Calibrated::NoFit(j) => assert_eq!(j.reasons, ["skipped: the fit did not finish within 0 s"]),
        Calibrated::Fit { json, .. } => panic!("a fit with no time: {:?}", json.reasons),
    }
}

#[test]
fn a_certificate_cut_short_leaves_the_calibration_and_says_so() {
    // A certificate asked for a tolerance no search meets (1e-9: every one of 1,000 rounds runs
    // its 200 REX iterations, about 0.8 s a round, 13 minutes in all) of a fit that determines its
    // sensor: within 1 s the calibration stands, identifiable, with the figure left out and why.
    let tmp = TempDir::new().unwrap();
    let path = turned_log(tmp.path());
    let scenario = tmp.path().join("slow.toml");
    let drone = std::fs::read_to_string(crate::common::scenarios().join("drone.toml")).unwrap();
    std::fs::write(
        &scenario,
        format!("{drone}\n[certificate]\ntolerance = 1e-9\nmax_rounds = 1000\n"),
    )
    .unwrap();
    let args = calibrate_args(
        &path,
        &["--magnitude", "50000", "--scenario", scenario.to_str().unwrap()],
    );
    let bound = Duration::from_secs(1);
    let (calibrated, took) = timed(&args, &path, &Deadline::after(bound));
    assert!(took >= bound && took < bound + MOST - BOUND, "{took:?}");
    let json = fitted(calibrated);
    assert!(json.identifiable && json.check.is_some(), "{:?}", json.reasons);
    assert_eq!(json.coverage.d_efficiency_per_reading, None);
    assert_eq!(
        json.coverage.d_efficiency_why_not.as_deref(),
        Some("skipped: the coverage certificate did not finish within 1 s")
    );
    // No stage of the verdict was skipped.
    assert!(
        json.reasons.iter().all(|r| !r.starts_with("skipped")),
        "{:?}",
        json.reasons
    );
}

/// 200 readings (nT) of a vehicle turned through every roll, pitch and yaw of a grid, read by a
/// sensor with a bias of a few thousand nT at 30 nT of noise: a log the full model determines, in a
/// field of 50,000 nT.
fn turned_log(dir: &Path) -> PathBuf {
    let field = magcal_core::ReferenceField::from_ned(15_000.0, 1_000.0, 47_680.0).unwrap();
    let sensor = magcal_core::ErrorModel::new([1.0, -0.5, 0.8], [1.03, 0.97, 1.01], [2500.0, -1800.0, 4200.0]).unwrap();
    let attitudes: Vec<magcal_core::Attitude> = (0..200)
        .map(|i| {
            let (roll, pitch, yaw) = ((i % 5) as f64, ((i / 5) % 5) as f64, (i / 25) as f64);
            magcal_core::Attitude::from_degrees(-160.0 + 80.0 * roll, -170.0 + 45.0 * yaw, -80.0 + 40.0 * pitch)
        })
        .collect();
    let readings = sensor
        .noisy_readings(
            &field.body_fields(&attitudes),
            30.0,
            &mut magcal_core::rng::stream_rng(55, 0),
        )
        .unwrap();
    let rows: Vec<String> = readings
        .iter()
        .map(|r| format!("{:.3},{:.3},{:.3}", r[0], r[1], r[2]))
        .collect();
    let path = dir.join("turned.csv");
    std::fs::write(&path, format!("x,y,z\n{}\n", rows.join("\n"))).unwrap();
    path
}

#[test]
fn a_bound_not_reached_changes_no_byte() {
    // Every loop asks the deadline, and none draws or computes anything for it: a fit and its
    // next attitudes within an hour are byte for byte those without a bound.
    let tmp = TempDir::new().unwrap();
    let path = turned_log(tmp.path());
    let args = calibrate_args(&path, &[&["--magnitude", "50000"][..], &BOX[..]].concat());
    let mut log = source::open(&path, &args.input, HELD_BYTES_PER_READING).unwrap();
    let unbounded = fitted(calibrate(&args, &mut log).unwrap());
    let (bounded, _) = timed(&args, &path, &Deadline::after(Duration::from_secs(3600)));
    let bounded = fitted(bounded);
    assert!(unbounded.identifiable && unbounded.coverage.d_efficiency_per_reading.is_some());
    assert_eq!(
        serde_json::to_string(&bounded).unwrap(),
        serde_json::to_string(&unbounded).unwrap()
    );
    let next = Next::parse_from(
        [
            &["next", "calibration.json", path.to_str().unwrap(), "--count", "3"][..],
            &BOX[..],
        ]
        .concat(),
    )
    .args;
    let unbounded_next = suggestion(&next, &unbounded).unwrap();
    let bounded_next = suggestion_within(&next, &unbounded, &Deadline::after(Duration::from_secs(3600))).unwrap();
    assert_eq!(unbounded_next.attitudes.len(), 3);
    assert_eq!(
        serde_json::to_string(&bounded_next).unwrap(),
        serde_json::to_string(&unbounded_next).unwrap()
    );
    // With no time left there is no suggestion, and the error says which stage it skipped.
    let e = suggestion_within(&next, &unbounded, &Deadline::after(Duration::ZERO)).unwrap_err();
    assert_eq!(
        format!("{e:#}"),
        "skipped: next's choice of attitudes did not finish within 0 s"
    );
}

/// A log of `n` readings (uT) of a sensor with a bias of (30, -20, 50) uT and scale factors and
/// cross terms of a few per cent, its field directions spread over the sphere in a scrambled
/// order (any prefix covers it), at 0.03 uT of noise.
fn sphere_log(dir: &Path, n: usize) -> PathBuf {
    const K: [[f64; 3]; 3] = [[1.08, 0.03, -0.02], [0.0, 0.95, 0.04], [0.0, 0.0, 1.03]];
    let mut rng = magcal_core::rng::stream_rng(56, 0);
    let noise = rand_distr::Normal::new(0.0, 0.03).unwrap();
    let mut text = String::with_capacity(n * 24);
    text.push_str("x,y,z\n");
    for j in 0..n {
        let i = (j * 7919) % n;
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let (r, t) = ((1.0 - z * z).sqrt(), i as f64 * 2.399_963);
        let b = [50.0 * r * t.cos(), 50.0 * r * t.sin(), 50.0 * z];
        let raw: Vec<f64> = (0..3)
            .map(|a| {
                (0..3).map(|c| K[a][c] * b[c]).sum::<f64>()
                    + [30.0, -20.0, 50.0][a]
                    + rand_distr::Distribution::sample(&noise, &mut rng)
            })
            .collect();
        text.push_str(&format!("{:.3},{:.3},{:.3}\n", raw[0], raw[1], raw[2]));
    }
    let path = dir.join("sphere.csv");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn live_says_a_fit_it_gave_no_time_and_writes_nothing_of_it() {
    let tmp = TempDir::new().unwrap();
    let path = sphere_log(tmp.path(), 300);
    let out = tmp.path().join("out");
    let output = crate::common::magcal()
        .args(["live", &format!("lines:{}", path.display()), "--units", "uT", "--json"])
        .args(["--fit-within", "0.000001", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(3), "{stderr}");
    let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(
        (json["usable"].as_bool(), json["readings"].as_u64()),
        (Some(false), Some(300))
    );
    assert_eq!(json["reasons"], "skipped: the fit did not finish within 1e-6 s");
    assert!(stderr.contains("nothing written to"), "{stderr}");
    assert!(!out.exists());
}

#[test]
fn a_signal_ends_live_during_a_fit_of_a_million_readings_with_the_last_whole_fits_set() {
    // A million readings: a fit of them takes 2.2 to 3 s on two idle cores (live's own timing).
    // The signal comes during the fit after the first; live ends at the fit's next step (an
    // iteration over the readings, about 0.2 s), measured at 0.03 s.
    let tmp = TempDir::new().unwrap();
    let path = sphere_log(tmp.path(), 1_000_000);
    let out = tmp.path().join("out");
    let (child, first, stderr) = crate::live::start_live_lines(
        &[
            &format!("lines:{}", path.display()),
            "--units",
            "uT",
            "--every",
            "0.2",
            "--memory",
            "128",
            "--json",
            "--out",
            out.to_str().unwrap(),
        ],
        2,
    );
    assert!(first[1].contains("| fit 1 in "), "{first:?}");
    std::thread::sleep(Duration::from_millis(400));
    let signalled = Instant::now();
    // SAFETY: kill(2) with the pid of a child of this process.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) }, 0);
    let (json, lines, code) = crate::live::finish_live(child, &stderr);
    let took = signalled.elapsed();
    assert!(took < Duration::from_secs(3), "{took:?} {lines:#?}");
    assert_eq!(code, 0, "{lines:#?}");
    // The fit under way is not a result: the last fit counted is the last printed, and its set
    // is the one written.
    let fits = json["fits"].as_u64().unwrap();
    let last = lines.iter().rev().find(|l| l.contains("| fit ")).unwrap();
    assert!(last.contains(&format!("| fit {fits} in ")), "{fits}: {last}");
    let set = crate::live::json_of(&out.join("calibration.json"));
    assert_eq!(set["samples"], json["readings"]);
    assert!(json["readings"].as_u64().unwrap() < 1_000_000, "{json}");
}
