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
        let common = || Common { scenario: scenario.clone(), seed: None, threads: Some(2), quiet: true };
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
        }
    }
}
