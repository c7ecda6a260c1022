//! Fuzzing the scenario parser and a shrunk pipeline with proptest (stable Rust; no nightly).
//!
//! - [`mutated_scenario_text_never_panics`]: the smoke scenario's text with random edits (a
//!   number replaced by an extreme one, a line dropped, duplicated or cut, bytes inserted) goes
//!   through parsing, validation and the memory estimate. Every outcome is `Ok` or an error
//!   naming the file; never a panic.
//! - [`extreme_valid_scenarios_run_check_and_draw`]: structurally valid scenarios at the edges of
//!   every accepted range (nominal and extreme sensors, tiny and full boxes, singular designs,
//!   noise from 0 to 1e8 nT) run through `magcal run` in-process (designs, trials, files, figures),
//!   and then `check` against themselves, which must pass. No CSV cell may read `NaN`.
//! - [`mutated_logs_calibrate_apply_and_next_or_say_why`]: logs of up to 60 rows, readings of an
//!   ellipsoid at any scale mixed with extreme numbers, empty and text cells, short and long
//!   rows, under every header and option (`--fit`, `--skip-bad`, `--reject`, `--magnitude`), go
//!   through `calibrate --out`; when it succeeds, its calibration through `apply` and `next`.
//!   Every outcome is `Ok` or an error naming the log or the option; never a panic.
//!
//! Cases per test: `MAGCAL_FUZZ_CASES` (default 24, what CI runs). A long run, as reported in the
//! README: `MAGCAL_FUZZ_CASES=20000 cargo test --release -p magcal-runner --test fuzz -- --nocapture`.
//! Inputs that once failed are kept in `proptest-regressions/fuzz.txt` (beside `tests/`) and are
//! replayed first.

use std::path::Path;

use magcal_runner::cli::{CheckArgs, Common, Failure, RunArgs};
use magcal_runner::commands;
use proptest::prelude::*;
use proptest::test_runner::{Config, FileFailurePersistence};

fn cases() -> u32 {
    std::env::var("MAGCAL_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(24)
}

fn config() -> Config {
    Config {
        cases: cases(),
        failure_persistence: Some(Box::new(FileFailurePersistence::Direct(
            "proptest-regressions/fuzz.txt",
        ))),
        max_shrink_iters: 200,
        ..Config::default()
    }
}

const EXTREMES: &[&str] = &[
    "0",
    "-0.0",
    "1e308",
    "-1e308",
    "5e-324",
    "nan",
    "inf",
    "-inf",
    "9223372036854775807",
    "18446744073709551615",
    "-1",
    "1e9",
    "1e-9",
    "360.0",
    "-360.0",
    "89.999",
    "\"x\"",
    "[]",
    "[1.0]",
    "{}",
    "1e7",
    "1e8",
    "1",
];

#[derive(Debug, Clone)]
enum Edit {
    Number(usize, usize),
    DropLine(usize),
    DuplicateLine(usize),
    Truncate(usize),
    Insert(usize, Vec<u8>),
}

fn apply(text: &str, edit: &Edit) -> Vec<u8> {
    if text.is_empty() {
        return Vec::new();
    }
    match edit {
        Edit::Number(which, value) => {
            // The which-th run of digits (with sign, point and exponent) replaced by an extreme.
            let bytes = text.as_bytes();
            let mut runs = Vec::new();
            let mut i = 0;
            while i < bytes.len() {
                if bytes[i].is_ascii_digit() {
                    let start = i;
                    while i < bytes.len()
                        && (bytes[i].is_ascii_alphanumeric() || matches!(bytes[i], b'.' | b'-' | b'+'))
                    {
                        i += 1;
                    }
                    runs.push((start, i));
                } else {
                    i += 1;
                }
            }
            let Some(&(a, b)) = runs.get(which % runs.len().max(1)) else {
                return bytes.to_vec();
            };
            let mut out = bytes[..a].to_vec();
            out.extend_from_slice(EXTREMES[value % EXTREMES.len()].as_bytes());
            out.extend_from_slice(&bytes[b..]);
            out
        }
        Edit::DropLine(n) | Edit::DuplicateLine(n) => {
            let lines: Vec<&str> = text.lines().collect();
            let k = n % lines.len();
            let mut out: Vec<&str> = Vec::new();
            for (i, l) in lines.iter().enumerate() {
                if i != k || matches!(edit, Edit::DuplicateLine(_)) {
                    out.push(l);
                }
                if i == k && matches!(edit, Edit::DuplicateLine(_)) {
                    out.push(l);
                }
            }
            out.join("\n").into_bytes()
        }
        Edit::Truncate(n) => text.as_bytes()[..n % text.len()].to_vec(),
        Edit::Insert(at, junk) => {
            let mut out = text.as_bytes().to_vec();
            let at = at % out.len();
            out.splice(at..at, junk.iter().copied());
            out
        }
    }
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        4 => (any::<usize>(), any::<usize>()).prop_map(|(a, b)| Edit::Number(a, b)),
        1 => any::<usize>().prop_map(Edit::DropLine),
        1 => any::<usize>().prop_map(Edit::DuplicateLine),
        1 => any::<usize>().prop_map(Edit::Truncate),
        1 => (any::<usize>(), proptest::collection::vec(any::<u8>(), 1..8)).prop_map(|(a, b)| Edit::Insert(a, b)),
    ]
}

fn smoke_text() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/smoke.toml")).unwrap()
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn mutated_scenario_text_never_panics(edits in proptest::collection::vec(edit(), 1..4)) {
        let mut text = smoke_text();
        let mut bytes = text.clone().into_bytes();
        for e in &edits {
            bytes = apply(&text, e);
            text = String::from_utf8_lossy(&bytes).into_owned();
        }
        match magcal_runner::scenario::parse(&bytes, Path::new("fuzz.toml")) {
            Ok(s) => {
                // A scenario that validates has bounded sizes: its estimate is a finite sum.
                let total: u64 = magcal_runner::limits::estimate(&s, true, 2).iter().map(|(_, b)| b).sum();
                prop_assert!(total < u64::MAX / 2);
            }
            Err(e) => {
                let message = format!("{e:#}");
                prop_assert!(message.contains("fuzz.toml"), "{message}");
            }
        }
    }
}

/// Numbers at the edges of what validation accepts.
fn edge(values: &'static [f64]) -> impl Strategy<Value = f64> + Clone {
    prop_oneof![
        3 => proptest::sample::select(values),
        1 => values.iter().copied().fold(f64::INFINITY, f64::min)..values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    ]
}

#[derive(Debug, Clone)]
struct Extreme {
    sigmas: Vec<f64>,
    ned: [f64; 3],
    yaw_offset: f64,
    psi: [f64; 3],
    scale: [f64; 3],
    bias: [f64; 3],
    boxes: [[f64; 2]; 3],
    designs: Vec<String>,
    trials: usize,
    runs: Option<usize>,
    seed: u64,
    attitude_sigmas: Vec<f64>,
    candidates: usize,
}

fn range() -> impl Strategy<Value = [f64; 2]> {
    prop_oneof![
        Just([-180.0, 180.0]),
        Just([-5.0, 5.0]),
        Just([0.0, 1e-6]),
        Just([-360.0, 0.0]),
        Just([-1.0, 1.0]),
        (-360.0..359.0f64, 1e-6..1.0f64).prop_map(|(a, w)| [a, (a + w * 360.0).min(360.0)]),
    ]
}

fn design(i: usize) -> impl Strategy<Value = String> {
    prop_oneof![
        (9usize..14).prop_map(move |m| format!("[[design]]\nname = \"r{i}\"\nkind = \"random\"\nm = {m}\n")),
        (1usize..4, 1usize..5, 3usize..5).prop_map(move |(r, y, p)| format!(
            "[[design]]\nname = \"g{i}\"\nkind = \"grid\"\nlevels = {{ roll = {r}, yaw = {}, pitch = {p} }}\n",
            y.max(9 / (r * p) + 1)
        )),
        (9usize..12, 1usize..6, 1usize..6, criterion()).prop_map(move |(m, particles, iterations, c)| format!(
            "[[design]]\nname = \"p{i}\"\nkind = \"pso\"\nm = {m}\nparticles = {particles}\niterations = {iterations}\ncriterion = \"{c}\"\n"
        )),
        (9usize..12, 1usize..3, 1usize..30, criterion()).prop_map(move |(m, starts, it, c)| format!(
            "[[design]]\nname = \"o{i}\"\nkind = \"optimum\"\nm = {m}\nstarts = {starts}\nmax_iterations = {it}\ncriterion = \"{c}\"\n"
        )),
        (9usize..60).prop_map(move |n| format!("[[design]]\nname = \"n{i}\"\nkind = \"plan\"\nreadings = {n}\n")),
    ]
}

fn criterion() -> impl Strategy<Value = &'static str> {
    proptest::sample::select(&["d", "a", "e"][..])
}

fn extreme() -> impl Strategy<Value = Extreme> {
    let sigma = edge(&[0.0, 1e-6, 1.0, 30.0, 1e4, 1e8]);
    let component = edge(&[-1e7, -50000.0, 0.0, 1.0, 20000.0, 1e7]);
    (
        proptest::collection::vec(sigma, 1..3),
        [component.clone(), component.clone(), component],
        edge(&[-360.0, 0.0, 90.0, 360.0]),
        proptest::array::uniform3(edge(&[-45.0, 0.0, 1.5, 45.0])),
        proptest::array::uniform3(edge(&[1e-3, 1.0, 1e3])),
        proptest::array::uniform3(edge(&[-1e7, 0.0, 3000.0, 1e7])),
        [range(), range(), range()],
        (1usize..4).prop_flat_map(|n| (0..n).map(design).collect::<Vec<_>>()),
        1usize..6,
        proptest::option::of(1usize..3),
        any::<u64>(),
        (
            proptest::collection::vec(edge(&[0.0, 1e-9, 0.5, 30.0]), 1..3),
            100usize..1500,
        ),
    )
        .prop_map(
            |(
                sigmas,
                ned,
                yaw_offset,
                psi,
                scale,
                bias,
                boxes,
                designs,
                trials,
                runs,
                seed,
                (attitude_sigmas, candidates),
            )| Extreme {
                sigmas,
                ned,
                yaw_offset,
                psi,
                scale,
                bias,
                boxes,
                designs,
                trials,
                runs,
                seed,
                attitude_sigmas,
                candidates,
            },
        )
}

fn list(v: &[f64]) -> String {
    format!(
        "[{}]",
        v.iter().map(|x| format!("{x:?}")).collect::<Vec<_>>().join(", ")
    )
}

impl Extreme {
    fn toml(&self) -> String {
        let mut sigmas = self.sigmas.clone();
        sigmas.dedup();
        let mut attitude = self.attitude_sigmas.clone();
        attitude.dedup();
        let mut text = format!(
            "schema = 1\nname = \"fuzz\"\nseed = {}\ntrials = {}\nsigma_nt = {}\nattitude_sigma_deg = {}\n\n[certificate]\ncandidates = {}\n\n[field]\nnorth_nt = {:?}\neast_nt = {:?}\ndown_nt = {:?}\nyaw_offset_deg = {:?}\n\n[sensor]\npsi_deg = {}\nscale = {}\nbias_nt = {}\n\n[attitude_box]\nroll_deg = {}\nyaw_deg = {}\npitch_deg = {}\n\n",
            self.seed,
            self.trials,
            list(&sigmas),
            list(&attitude),
            self.candidates,
            self.ned[0],
            self.ned[1].max(if self.ned.iter().all(|x| x.abs() < 1.0) {
                1.0
            } else {
                self.ned[1]
            }),
            self.ned[2],
            self.yaw_offset,
            list(&self.psi),
            list(&self.scale),
            list(&self.bias),
            list(&self.boxes[0]),
            list(&self.boxes[1]),
            list(&self.boxes[2]),
        );
        for d in &self.designs {
            text.push_str(d);
            text.push('\n');
        }
        if let Some(runs) = self.runs
            && let Some(pso) = self.designs.iter().find(|d| d.contains("kind = \"pso\""))
        {
            let name = pso.split('"').nth(1).unwrap();
            text.push_str(&format!("[pso_runs]\nruns = {runs}\ndesign = \"{name}\"\n"));
        }
        text
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn extreme_valid_scenarios_run_check_and_draw(x in extreme()) {
        let tmp = tempfile::TempDir::new().unwrap();
        let scenario = tmp.path().join("fuzz.toml");
        std::fs::write(&scenario, x.toml()).unwrap();
        let out = tmp.path().join("out");
        let common = || Common { scenario: scenario.clone(), seed: None, threads: Some(2), quiet: true, allow_long: false };
        let run = RunArgs { common: common(), out: Some(out.clone()), trials: None };
        match commands::run::run(&run) {
            Ok(()) => {}
            // The generator keeps to accepted ranges; a refusal must still be a clear message.
            Err(Failure::Input(e)) => {
                let message = format!("{e:#}");
                prop_assert!(message.contains("fuzz.toml"), "{message}\n{}", x.toml());
                return Ok(());
            }
            Err(Failure::Regression(r)) => prop_assert!(false, "run reported a regression: {r}"),
            Err(Failure::Unusable(r)) => prop_assert!(false, "run reported an unusable calibration: {r}"),
        }
        for f in ["summary.csv", "trials.csv", "design_metrics.csv", "designs.csv", "approximate.csv", "certificate.csv"] {
            let text = std::fs::read_to_string(out.join(f)).unwrap();
            prop_assert!(!text.contains("NaN"), "{f} holds NaN\n{}", x.toml());
        }
        prop_assert!(out.join("plots/eta_psi.png").is_file());
        let check = CheckArgs { common: common(), baseline: Some(out.clone()) };
        match commands::check::run(&check) {
            Ok(()) => {}
            Err(Failure::Regression(r)) => prop_assert!(false, "check against itself moved:\n{r}\n{}", x.toml()),
            Err(Failure::Input(e)) => prop_assert!(false, "check: {e:#}\n{}", x.toml()),
            Err(Failure::Unusable(r)) => prop_assert!(false, "check reported an unusable calibration: {r}"),
        }
    }
}

/// A log: a header, rows of an ellipsoid's readings at `scale`, some of them spoiled.
#[derive(Debug, Clone)]
struct FuzzLog {
    header: &'static str,
    rows: Vec<Row>,
    scale: f64,
    fit: &'static str,
    skip_bad: bool,
    reject: Option<f64>,
    magnitude: Option<f64>,
}

#[derive(Debug, Clone)]
enum Row {
    Reading(usize),
    Spoiled(usize, usize, &'static str),
    Short(usize),
    Long(usize),
    Repeat,
}

impl FuzzLog {
    fn text(&self) -> String {
        // Readings of an ellipsoid (scale factors 1.3, 0.7, 1.2, an offset) on a spiral.
        let reading = |i: usize| -> [f64; 3] {
            let z = -1.0 + (2 * (i % 40) + 1) as f64 / 40.0;
            let a = i as f64 * 2.4;
            let r = (1.0 - z * z).sqrt();
            [
                self.scale * (1.3 * r * a.cos() + 0.2),
                self.scale * (0.7 * r * a.sin() - 0.1),
                self.scale * (1.2 * z + 0.3),
            ]
        };
        let cells = |v: [f64; 3]| v.map(|x| format!("{x:e}"));
        let mut text = String::from(self.header);
        let mut last = String::from("1,2,3");
        for row in &self.rows {
            let line = match row {
                Row::Reading(i) => cells(reading(*i)).join(","),
                Row::Spoiled(i, c, value) => {
                    let mut v = cells(reading(*i));
                    v[*c % 3] = (*value).to_string();
                    v.join(",")
                }
                Row::Short(i) => cells(reading(*i))[..2].join(","),
                Row::Long(i) => format!("{},7", cells(reading(*i)).join(",")),
                Row::Repeat => last.clone(),
            };
            text.push_str(&line);
            text.push('\n');
            last = line;
        }
        text
    }
}

fn fuzz_log() -> impl Strategy<Value = FuzzLog> {
    let row = prop_oneof![
        40 => (0usize..1000).prop_map(Row::Reading),
        2 => (0usize..1000, 0usize..3, prop::sample::select(&["nan", "inf", "-inf", "1e308", "0", "", "x", "5e-324", "1e400"][..]))
            .prop_map(|(i, c, v)| Row::Spoiled(i, c, v)),
        1 => (0usize..1000).prop_map(Row::Short),
        1 => (0usize..1000).prop_map(Row::Long),
        1 => Just(Row::Repeat),
    ];
    (
        prop::sample::select(&["x,y,z\n", "mx,my,mz\n", "a,b,c,d\n", "", "t,x,y,z\n"][..]),
        proptest::collection::vec(row, 0..60),
        prop::sample::select(&[1.0, 1e-6, 1e6, 48_000.0, 1e150][..]),
        prop::sample::select(&["full", "diagonal", "offset", "auto"][..]),
        prop::bool::weighted(0.75),
        // Mostly accepted options, so that most logs reach a fit; the refusals still come up.
        prop_oneof![
            8 => Just(None),
            2 => Just(Some(3.0)),
            1 => prop::sample::select(&[Some(0.0), Some(-1.0), Some(f64::NAN)][..]),
        ],
        prop_oneof![
            8 => Just(None),
            2 => prop::sample::select(&[Some(1.0), Some(48_000.0), Some(1e300)][..]),
            1 => prop::sample::select(&[Some(0.0), Some(-1.0), Some(f64::NAN)][..]),
        ],
    )
        .prop_map(|(header, rows, scale, fit, skip_bad, reject, magnitude)| FuzzLog {
            header,
            rows,
            scale,
            fit,
            skip_bad,
            reject,
            magnitude,
        })
}

/// An error of a command on `log`: it names the log or an option.
fn names_the_input(e: Failure, log: &Path) -> Result<(), String> {
    match e {
        Failure::Input(e) => {
            let message = format!("{e:#}");
            if message.contains(&log.display().to_string()) || message.contains("--") {
                Ok(())
            } else {
                Err(format!("an error naming neither the log nor an option: {message}"))
            }
        }
        Failure::Regression(r) => Err(format!("a regression from a log command: {r}")),
        Failure::Unusable(r) => Err(format!(
            "an unusable calibration from a command that does not calibrate: {r}"
        )),
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn mutated_logs_calibrate_apply_and_next_or_say_why(x in fuzz_log()) {
        use clap::Parser;
        use magcal_runner::commands::{apply::{self, ApplyArgs}, calibrate::{self, CalibrateArgs}, next::{self, NextArgs}};
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
        let tmp = tempfile::TempDir::new().unwrap();
        let log = tmp.path().join("fuzz.csv");
        std::fs::write(&log, x.text()).unwrap();
        let out = tmp.path().join("cal");
        let mut argv: Vec<String> = vec!["calibrate".into(), log.display().to_string(), "--fit".into(), x.fit.into(), "--json".into(), "--out".into(), out.display().to_string()];
        if x.skip_bad {
            argv.push("--skip-bad".into());
        }
        if let Some(k) = x.reject {
            argv.push(format!("--reject={k}"));
        }
        if let Some(r) = x.magnitude {
            argv.push(format!("--magnitude={r}"));
        }
        let args = Calibrate::try_parse_from(&argv).unwrap().args;
        match calibrate::run(&args) {
            // A calibration that should not be used is still written, and named.
            Ok(()) => {}
            Err(Failure::Unusable(why)) => prop_assert!(why.contains(&log.display().to_string()), "{why}"),
            Err(e) => {
                let why = names_the_input(e, &log);
                prop_assert!(why.is_ok(), "{}: {why:?}\n{}", argv.join(" "), x.text());
                return Ok(());
            }
        }
        let json = out.join("calibration.json");
        prop_assert!(json.is_file());
        let apply = ApplyArgs { calibration: json.clone(), log: log.clone(), columns: None, skip_bad: x.skip_bad, out: Some(tmp.path().join("calibrated.csv")) };
        if let Err(e) = apply::run(&apply) {
            let why = names_the_input(e, &log);
            prop_assert!(why.is_ok(), "apply: {why:?}\n{}", x.text());
        }
        let mut argv: Vec<String> = vec!["next".into(), json.display().to_string(), log.display().to_string(), "--roll=-5,5".into(), "--pitch=-20,20".into(), "--site".into(), "28.2,112.97".into(), "--date".into(), "2013.0".into(), "--count".into(), "2".into()];
        if x.skip_bad {
            argv.push("--skip-bad".into());
        }
        let next = Next::try_parse_from(&argv).unwrap().args;
        if let Err(e) = next::run(&next) {
            let why = names_the_input(e, &log);
            prop_assert!(why.is_ok(), "next: {why:?}\n{}", x.text());
        }
    }
}
