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
//!   rows; separated by commas, semicolons, tabs or spaces, with decimal commas; under headers
//!   with prefixes, a time column, empty and repeated names, or none; with `--columns` by name,
//!   index, repeated or out of range; `--fit`, `--skip-bad`, `--reject`, `--magnitude`, `--noise`
//!   (absurd values too) and `--site --date --units` with the log in those units or others. They
//!   go through `calibrate --out`; its calibration.json, edited or not (an entry of `p`, `k`,
//!   `bias`, `magnitude`, `noise` set to null, negative, huge or a string; `columns` renamed or
//!   pointing at missing columns; `format`; a field removed or added; cut short; a byte-order
//!   mark), through `apply` and `next`. Every outcome is one of: exit 0, whose calibration is
//!   usable with finite estimates and standard errors, and whose applied readings are finite;
//!   exit 3, whose JSON says `usable: false` with reasons; or an input error, one short line
//!   naming the log, the calibration or an option, with no output written. Never a panic. An
//!   unedited usable calibration applies to its own log.
//!
//! Plain regression tests below the fuzzers keep what the fuzzer found, readably.
//!
//! Cases per test: `MAGCAL_FUZZ_CASES` (default 24, what CI runs). A long run, as reported in the
//! README: `MAGCAL_FUZZ_CASES=30000 cargo test --release -p magcal-runner --test it -- fuzz::mutated_logs`
//! (the commands print to standard output: redirect it).
//! Inputs that once failed are kept in `proptest-regressions/fuzz.txt` (beside `tests/`) and are
//! replayed first.

use std::path::Path;

use magcal_runner::commands;
use magcal_runner::commands::check::CheckArgs;
use magcal_runner::commands::run::RunArgs;
use magcal_runner::commands::{Common, Failure};
use magcal_runner::log::source::LogArgs;
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
                let total: u64 = magcal_runner::pipeline::budget::estimate(&s, true, 2).iter().map(|(_, b)| b).sum();
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
            100usize..500,
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
    /// `[verdict] trials`: 20 (the least accepted) to 40, drawn from the scenario's seed so that the
    /// strategy, and the cases `proptest-regressions/fuzz.txt` replays, stay what they were. Each
    /// design's verdict calibrates this many trials at the largest noise; at the default 200 the
    /// verdicts of scenarios whose fits run to the iteration limit were 90 % of this test's time
    /// (perf of its slowest case), and the count is no edge of any range.
    fn verdict_trials(&self) -> u64 {
        20 + self.seed % 21
    }

    fn toml(&self) -> String {
        let mut sigmas = self.sigmas.clone();
        sigmas.dedup();
        let mut attitude = self.attitude_sigmas.clone();
        attitude.dedup();
        let mut text = format!(
            "schema = 1\nname = \"fuzz\"\nseed = {}\ntrials = {}\nsigma_nt = {}\nattitude_sigma_deg = {}\n\n[certificate]\ncandidates = {}\n\n[verdict]\ntrials = {}\n\n[field]\nnorth_nt = {:?}\neast_nt = {:?}\ndown_nt = {:?}\nyaw_offset_deg = {:?}\n\n[sensor]\npsi_deg = {}\nscale = {}\nbias_nt = {}\n\n[attitude_box]\nroll_deg = {}\nyaw_deg = {}\npitch_deg = {}\n\n",
            self.seed,
            self.trials,
            list(&sigmas),
            list(&attitude),
            self.candidates,
            self.verdict_trials(),
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
        let common = || Common { scenario: scenario.clone(), seed: None, threads: Some(2), quiet: true, allow_long: false, heading_budget: None };
        let run = RunArgs { common: common(), out: Some(out.clone()), trials: None };
        match quietly(|| commands::run::run(&run)) {
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
        match quietly(|| commands::check::run(&check)) {
            Ok(()) => {}
            Err(Failure::Regression(r)) => prop_assert!(false, "check against itself moved:\n{r}\n{}", x.toml()),
            Err(Failure::Input(e)) => prop_assert!(false, "check: {e:#}\n{}", x.toml()),
            Err(Failure::Unusable(r)) => prop_assert!(false, "check reported an unusable calibration: {r}"),
        }
    }
}

/// A log: a header, rows of an ellipsoid's readings at `scale`, some of them spoiled, in one of
/// the separators the reader sniffs; the options of `calibrate`; and an edit of the calibration
/// file it writes before `apply` and `next` read it.
#[derive(Debug, Clone)]
struct FuzzLog {
    /// The header's names (`None`: no header) and how many cells each row has before the reading.
    header: (Option<&'static [&'static str]>, usize),
    separator: Sep,
    decimal_comma: bool,
    rows: Vec<Row>,
    scale: f64,
    columns: Option<String>,
    fit: &'static str,
    skip_bad: bool,
    reject: Option<f64>,
    magnitude: Option<f64>,
    noise: Option<Noise>,
    place: Option<Place>,
    edit: Option<CalEdit>,
}

#[derive(Debug, Clone, Copy)]
enum Sep {
    Comma,
    Semicolon,
    Tab,
    Spaces,
}

#[derive(Debug, Clone)]
enum Row {
    Reading(usize),
    Spoiled(usize, usize, &'static str),
    Short(usize),
    Long(usize),
    Repeat,
}

/// `--noise`: relative to the log's scale, or a literal.
#[derive(Debug, Clone)]
enum Noise {
    Relative(f64),
    Literal(&'static str),
}

/// `--site --date --units`, the log scaled to match the units or not.
#[derive(Debug, Clone)]
struct Place {
    site: &'static str,
    date: &'static str,
    units: Option<&'static str>,
    matched: bool,
}

/// An edit of calibration.json.
#[derive(Debug, Clone)]
enum CalEdit {
    /// A JSON pointer set to a value (JSON text).
    Set(&'static str, &'static str),
    /// A number at a pointer multiplied.
    Scale(&'static str, f64),
    Remove(&'static str),
    Truncate(usize),
    Bom,
    ExtraField,
}

/// Roughly the WMM's total field at 28.2 N 112.97 E in 2013, nT: a log in the units given reads
/// this divided by the units' nT.
const FIELD_NT: f64 = 48_000.0;

fn units_nt(u: &str) -> f64 {
    match u {
        "nT" => 1.0,
        "uT" => 1e3,
        "mG" => 1e2,
        "G" => 1e5,
        _ => 1.0,
    }
}

impl Place {
    /// The site and date of [P1] in nT, the log at another scale than the field's.
    fn nt_not_matched() -> Self {
        Place {
            site: "28.2,112.97",
            date: "2013.0",
            units: Some("nT"),
            matched: false,
        }
    }
}

impl FuzzLog {
    /// The scale of the readings: the field in the units given (`matched`), or in others.
    fn scale(&self) -> f64 {
        match &self.place {
            Some(Place {
                units: Some(u),
                matched: true,
                ..
            }) => FIELD_NT / units_nt(u),
            Some(Place {
                units: Some(u),
                matched: false,
                ..
            }) => FIELD_NT / units_nt(u) * if *u == "nT" { 1e-3 } else { 1e3 },
            _ => self.scale,
        }
    }

    fn text(&self) -> String {
        let scale = self.scale();
        // Readings of an ellipsoid (scale factors 1.3, 0.7, 1.2, an offset) on a spiral.
        let reading = |i: usize| -> [f64; 3] {
            let z = -1.0 + (2 * (i % 40) + 1) as f64 / 40.0;
            let a = i as f64 * 2.4;
            let r = (1.0 - z * z).sqrt();
            [
                scale * (1.3 * r * a.cos() + 0.2),
                scale * (0.7 * r * a.sin() - 0.1),
                scale * (1.2 * z + 0.3),
            ]
        };
        let number = |x: f64| {
            let t = format!("{x:e}");
            match (self.decimal_comma, self.separator) {
                (false, _) => t,
                // A decimal comma in a comma-separated log must be quoted to be one cell (and is
                // then refused).
                (true, Sep::Comma) => format!("\"{}\"", t.replace('.', ",")),
                (true, _) => t.replace('.', ","),
            }
        };
        let sep = match self.separator {
            Sep::Comma => ",",
            Sep::Semicolon => ";",
            Sep::Tab => "\t",
            Sep::Spaces => "  ",
        };
        let (names, lead) = self.header;
        let width = names.map_or(lead + 3, <[_]>::len);
        let row = |n: usize, cells: Vec<String>| -> String {
            let mut all: Vec<String> = (0..lead).map(|_| n.to_string()).collect();
            all.extend(cells);
            while all.len() < width {
                all.push("7".into());
            }
            all.join(sep)
        };
        let mut text = names.map_or(String::new(), |h| format!("{}\n", h.join(sep)));
        let mut last = row(0, vec!["1".into(), "2".into(), "3".into()]);
        for (n, r) in self.rows.iter().enumerate() {
            let cells = |i: usize| reading(i).map(number).to_vec();
            let line = match r {
                Row::Reading(i) => row(n, cells(*i)),
                Row::Spoiled(i, c, value) => {
                    let mut v = cells(*i);
                    v[*c % 3] = (*value).to_string();
                    row(n, v)
                }
                Row::Short(i) => {
                    let mut all: Vec<String> = (0..lead).map(|_| n.to_string()).collect();
                    all.extend(cells(*i).into_iter().take(2));
                    all.join(sep)
                }
                Row::Long(i) => format!("{}{sep}7{sep}8", row(n, cells(*i))),
                Row::Repeat => last.clone(),
            };
            text.push_str(&line);
            text.push('\n');
            last = line;
        }
        text
    }

    /// `calibrate`'s command line.
    fn calibrate_argv(&self, log: &Path, out: &Path) -> Vec<String> {
        let mut argv: Vec<String> = vec![
            "calibrate".into(),
            log.display().to_string(),
            "--fit".into(),
            self.fit.into(),
            "--json".into(),
            "--out".into(),
            out.display().to_string(),
        ];
        if let Some(c) = &self.columns {
            argv.push(format!("--columns={c}"));
        }
        if self.skip_bad {
            argv.push("--skip-bad".into());
        }
        if let Some(k) = self.reject {
            argv.push(format!("--reject={k}"));
        }
        if let Some(r) = self.magnitude {
            argv.push(format!("--magnitude={r}"));
        }
        match &self.noise {
            Some(Noise::Relative(r)) => argv.push(format!("--noise={:e}", r * self.scale())),
            Some(Noise::Literal(v)) => argv.push(format!("--noise={v}")),
            None => {}
        }
        if let Some(p) = &self.place {
            argv.push(format!("--site={}", p.site));
            argv.push(format!("--date={}", p.date));
            if let Some(u) = p.units {
                argv.push(format!("--units={u}"));
            }
        }
        argv
    }
}

/// Headers with the cells before the reading: plain, prefixed, a time column, a fourth column,
/// names repeated, none.
const HEADERS: &[(Option<&[&str]>, usize)] = &[
    (Some(&["x", "y", "z"]), 0),
    (Some(&["mx", "my", "mz"]), 0),
    (Some(&["MAG_X", "mag_y", "Mag_Z"]), 0),
    (Some(&["a", "b", "c", "d"]), 0),
    (Some(&["t", "x", "y", "z"]), 1),
    (Some(&["x", "y", "z", "x"]), 0),
    (Some(&["x", "x", "z"]), 0),
    (Some(&["t", "t", "x", "y", "z"]), 2),
    (Some(&["\"x\"", "\"y\"", "\"z\""]), 0),
    (Some(&["x", "", "z"]), 0),
    (None, 0),
    (None, 1),
];

const COLUMNS: &[&str] = &[
    "x,y,z",
    "1,2,3",
    "2,3,4",
    "mx,my,mz",
    "X, Y, Z",
    "1,1,2",
    "0,1,2",
    "1,2,99",
    "x,y",
    "x,y,z,t",
    "a,b,c",
    "3,2,1",
    "-1,2,3",
    "",
    "t,x,y",
    "x,y,4",
    "column 1,column 2,column 3",
    "18446744073709551616,1,2",
];

fn cal_edit() -> impl Strategy<Value = CalEdit> {
    let pointer = prop::sample::select(
        &[
            "/p/0/0",
            "/p/0/1",
            "/p/1/1",
            "/p/1/0",
            "/p/2/2",
            "/bias/0",
            "/bias/2",
            "/magnitude",
            "/noise",
            "/k/0/0",
            "/k/1/2",
            "/scale/1",
            "/psi_deg/0",
            "/soft_iron_inverse/0/1",
            "/residual_rms",
            "/samples",
            "/columns/0",
            "/columns",
            "/format",
            "/units",
            "/log_sha256",
            "/usable",
            "/identifiable",
            "/reasons",
            "/std_error",
            "/fit",
        ][..],
    );
    let value = prop::sample::select(
        &[
            "null",
            "0",
            "-0.0",
            "-1",
            "1e308",
            "-1e308",
            "1e-300",
            "5e-324",
            "1",
            "2",
            "\"x\"",
            "[]",
            "{}",
            "\"q\"",
            "\"column 9\"",
            "[\"q\",\"r\",\"s\"]",
            "[\"x\",\"x\",\"x\"]",
            "[\"column 1\",\"column 2\",\"column 3\"]",
            "\"magcal-calibration-2\"",
            "\"G\"",
            "true",
            "false",
            "1e400",
        ][..],
    );
    prop_oneof![
        6 => (pointer.clone(), value).prop_map(|(p, v)| CalEdit::Set(p, v)),
        3 => (pointer.clone(), prop::sample::select(&[1.0 + 1e-12, 1.0 + 1e-6, 2.0, -1.0, 1e-200, 1e200][..]))
            .prop_map(|(p, f)| CalEdit::Scale(p, f)),
        1 => pointer.prop_map(CalEdit::Remove),
        1 => any::<usize>().prop_map(CalEdit::Truncate),
        1 => Just(CalEdit::Bom),
        1 => Just(CalEdit::ExtraField),
    ]
}

impl CalEdit {
    /// The file's bytes after the edit; `None` when the pointer is not in the file.
    fn apply(&self, bytes: &[u8]) -> Option<Vec<u8>> {
        let mut json: serde_json::Value = serde_json::from_slice(bytes).unwrap();
        match self {
            CalEdit::Set(p, v) => *json.pointer_mut(p)? = serde_json::from_str(v).unwrap_or(serde_json::Value::Null),
            CalEdit::Scale(p, f) => {
                let at = json.pointer_mut(p)?;
                let x = at.as_f64()? * f;
                *at = serde_json::Number::from_f64(x).map_or(serde_json::Value::Null, serde_json::Value::Number);
            }
            CalEdit::Remove(p) => {
                let (parent, key) = p.rsplit_once('/')?;
                let parent = if parent.is_empty() {
                    Some(&mut json)
                } else {
                    json.pointer_mut(parent)
                }?;
                match parent {
                    serde_json::Value::Object(m) => {
                        m.remove(key)?;
                    }
                    serde_json::Value::Array(a) => {
                        let i: usize = key.parse().ok()?;
                        (i < a.len()).then(|| a.remove(i))?;
                    }
                    _ => return None,
                }
            }
            CalEdit::Truncate(n) => return Some(bytes[..n % bytes.len()].to_vec()),
            CalEdit::Bom => {
                let mut out = b"\xef\xbb\xbf".to_vec();
                out.extend_from_slice(bytes);
                return Some(out);
            }
            CalEdit::ExtraField => {
                json.as_object_mut()?
                    .insert("comment".into(), serde_json::json!({"by": "hand", "n": [1, 2]}));
            }
        }
        Some(serde_json::to_vec_pretty(&json).unwrap())
    }
}

fn fuzz_log() -> impl Strategy<Value = FuzzLog> {
    let row = prop_oneof![
        40 => (0usize..1000).prop_map(Row::Reading),
        2 => (0usize..1000, 0usize..3, prop::sample::select(&["nan", "inf", "-inf", "1e308", "0", "", "x", "5e-324", "1e400", "1,5", "\"\""][..]))
            .prop_map(|(i, c, v)| Row::Spoiled(i, c, v)),
        1 => (0usize..1000).prop_map(Row::Short),
        1 => (0usize..1000).prop_map(Row::Long),
        1 => Just(Row::Repeat),
    ];
    let format = (
        prop_oneof![2 => prop::sample::select(&HEADERS[..3]), 3 => prop::sample::select(HEADERS)],
        prop_oneof![4 => Just(Sep::Comma), 1 => Just(Sep::Semicolon), 1 => Just(Sep::Tab), 1 => Just(Sep::Spaces)],
        prop::bool::weighted(0.3),
        prop_oneof![
            6 => Just(None),
            2 => prop::sample::select(COLUMNS).prop_map(|c| Some(c.to_string())),
            1 => (1usize..7, 1usize..7, 1usize..7).prop_map(|(a, b, c)| Some(format!("{a},{b},{c}"))),
        ],
    );
    let noise = prop_oneof![
        6 => Just(None),
        2 => prop::sample::select(&[1e-3, 1e-2, 1e-6, 0.3][..]).prop_map(|r| Some(Noise::Relative(r))),
        1 => prop::sample::select(&["0", "-1", "nan", "inf", "1e-300", "1e300", "5e-324", "x"][..]).prop_map(|v| Some(Noise::Literal(v))),
    ];
    let place = prop_oneof![
        6 => Just(None),
        3 => (prop::sample::select(&["nT", "uT", "mG", "G"][..]), prop::bool::weighted(0.7)).prop_map(|(u, matched)| Some(Place {
            site: "28.2,112.97",
            date: "2013.0",
            units: Some(u),
            matched,
        })),
        1 => (
            prop::sample::select(&["28.2,112.97", "90,0", "-90,-360", "0,0,1e6", "91,0", "nan,0", "1,2,3,4", "x"][..]),
            prop::sample::select(&["2013.0", "2013-06-01", "1900", "2100-01-01", "2013-02-30", "2024.99", "x"][..]),
            prop::option::of(prop::sample::select(&["nT", "uT", "mG", "G", "T"][..])),
            any::<bool>(),
        )
            .prop_map(|(site, date, units, matched)| Some(Place { site, date, units, matched })),
    ];
    let edit = prop_oneof![3 => Just(None), 4 => cal_edit().prop_map(Some)];
    (
        format,
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
        noise,
        place,
        edit,
    )
        .prop_map(
            |(
                (header, separator, decimal_comma, columns),
                rows,
                scale,
                fit,
                skip_bad,
                reject,
                magnitude,
                noise,
                place,
                edit,
            )| FuzzLog {
                header,
                separator,
                decimal_comma,
                rows,
                scale,
                columns,
                fit,
                skip_bad,
                reject,
                magnitude: magnitude.filter(|_| place.as_ref().is_none_or(|p| p.units.is_none())),
                noise,
                place,
                edit,
            },
        )
}

/// Longest error line accepted: a calibration's 3 x 3 matrix and a few names fit in it.
const MAX_ERROR_CHARS: usize = 1000;

/// An error of a command: one line, short, naming one of `files` or an option.
fn names_the_input(e: Failure, files: &[&Path]) -> Result<(), String> {
    match e {
        Failure::Input(e) => {
            let message = format!("{e:#}");
            if message.contains('\n') || message.chars().count() > MAX_ERROR_CHARS {
                Err(format!("not one short line: {message}"))
            } else if files.iter().any(|f| message.contains(&f.display().to_string())) || message.contains("--") {
                Ok(())
            } else {
                Err(format!("an error naming neither the input nor an option: {message}"))
            }
        }
        Failure::Regression(r) => Err(format!("a regression from a log command: {r}")),
        Failure::Unusable(r) => Err(format!(
            "an unusable calibration from a command that does not calibrate: {r}"
        )),
    }
}

/// A command line's parse error: it names the option.
fn parse_refused(e: &clap::Error) -> Result<(), String> {
    let message = e.to_string();
    if message.contains("--") {
        Ok(())
    } else {
        Err(format!("a usage error naming no option: {message}"))
    }
}

/// What a usable calibration promises: finite estimates and standard errors, no reasons.
fn check_usable(json: &serde_json::Value) -> Result<(), String> {
    let finite = |pointer: &str, n: usize| -> Result<(), String> {
        let v = json
            .pointer(pointer)
            .and_then(|v| v.as_array())
            .ok_or(format!("{pointer} missing"))?;
        let flat: Vec<&serde_json::Value> = v
            .iter()
            .flat_map(|x| x.as_array().map_or(vec![x], |a| a.iter().collect()))
            .collect();
        if flat.len() == n && flat.iter().all(|x| x.as_f64().is_some_and(f64::is_finite)) {
            Ok(())
        } else {
            Err(format!("{pointer}: {v:?} not {n} finite numbers"))
        }
    };
    for (p, n) in [
        ("/p", 9),
        ("/k", 9),
        ("/bias", 3),
        ("/scale", 3),
        ("/psi_deg", 3),
        ("/std_error/bias", 3),
        ("/std_error/scale", 3),
        ("/std_error/psi_deg", 3),
        ("/interval95/bias", 3),
    ] {
        finite(p, n)?;
    }
    if !json["reasons"].as_array().is_some_and(Vec::is_empty) {
        return Err(format!("usable with reasons {}", json["reasons"]));
    }
    if !json["magnitude"].as_f64().is_some_and(|m| m.is_finite() && m > 0.0) {
        return Err(format!("usable with magnitude {}", json["magnitude"]));
    }
    Ok(())
}

/// `apply`'s output: a header and rows of finite numbers.
fn check_applied(path: &Path) -> Result<(), String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut lines = text.lines();
    if lines.next() != Some("line,x,y,z,norm") {
        return Err(format!("apply's header: {:?}", text.lines().next()));
    }
    for l in lines {
        if !l.split(',').all(|c| c.parse::<f64>().is_ok_and(f64::is_finite)) {
            return Err(format!("apply wrote a row that is not finite: {l}"));
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn mutated_logs_calibrate_apply_and_next_or_say_why(x in fuzz_log()) {
        calibrate_apply_next(&x)?;
    }
}

/// `calibrate` a fuzzed log, then `apply` and `next` with its calibration: each succeeds or says why.
fn calibrate_apply_next(x: &FuzzLog) -> Result<(), TestCaseError> {
    use clap::Parser;
    use magcal_runner::commands::{
        apply::{self, ApplyArgs},
        calibrate::{self, CalibrateArgs},
        next::{self, NextArgs},
    };
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
    let argv = x.calibrate_argv(&log, &out);
    let args = match Calibrate::try_parse_from(&argv) {
        Ok(a) => a.args,
        Err(e) => {
            let why = parse_refused(&e);
            prop_assert!(why.is_ok(), "{}: {why:?}", argv.join(" "));
            return Ok(());
        }
    };
    let json = out.join("calibration.json");
    let usable = match quietly(|| calibrate::run(&args)) {
        Ok(()) => {
            let written: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
            prop_assert!(written["usable"] == true, "exit 0 with {}", written["usable"]);
            let why = check_usable(&written);
            prop_assert!(why.is_ok(), "{}: {why:?}\n{}", argv.join(" "), x.text());
            true
        }
        // A calibration that should not be used is still written, and says why.
        Err(Failure::Unusable(why)) => {
            prop_assert!(why.contains(&log.display().to_string()), "{why}");
            // A log that no model fits gets the report instead of a calibration, and nothing
            // to apply.
            let none = out.join("no_calibration.json");
            if none.exists() {
                prop_assert!(!json.exists(), "a calibration beside the report that there is none");
                let written: serde_json::Value = serde_json::from_slice(&std::fs::read(&none).unwrap()).unwrap();
                prop_assert!(
                    written["format"] == "magcal-no-calibration-1" && written["usable"] == false,
                    "{written}"
                );
                prop_assert!(
                    written["reasons"].as_array().is_some_and(|r| !r.is_empty()),
                    "no calibration without reasons"
                );
                return Ok(());
            }
            let written: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
            prop_assert!(written["usable"] == false, "exit 3 with {}", written["usable"]);
            prop_assert!(
                written["reasons"].as_array().is_some_and(|r| !r.is_empty()),
                "exit 3 without reasons"
            );
            false
        }
        Err(e) => {
            let why = names_the_input(e, &[&log]);
            prop_assert!(why.is_ok(), "{}: {why:?}\n{}", argv.join(" "), x.text());
            // Nothing is written before the error.
            prop_assert!(!out.exists(), "{} exists after an error", out.display());
            return Ok(());
        }
    };
    let cal = tmp.path().join("edited.json");
    let bytes = std::fs::read(&json).unwrap();
    let edited = x.edit.as_ref().and_then(|e| e.apply(&bytes)).unwrap_or(bytes);
    std::fs::write(&cal, &edited).unwrap();
    let applied = tmp.path().join("calibrated.csv");
    let apply = ApplyArgs {
        calibration: cal.clone(),
        log: log.clone(),
        input: LogArgs {
            columns: x.columns.clone(),
            skip_bad: x.skip_bad,
            ..LogArgs::default()
        },
        matrix: Default::default(),
        out: Some(applied.clone()),
    };
    match quietly(|| apply::run(&apply)) {
        Ok(()) => {
            let why = check_applied(&applied);
            prop_assert!(
                why.is_ok(),
                "apply: {why:?}\n{}\n{}",
                String::from_utf8_lossy(&edited),
                x.text()
            );
        }
        Err(e) => {
            // A usable calibration applies to its own log, read with the same options.
            prop_assert!(
                !(usable && x.edit.is_none()),
                "apply refused the log its usable calibration was made from: {}\n{}",
                match &e {
                    Failure::Input(e) => format!("{e:#}"),
                    _ => String::new(),
                },
                x.text()
            );
            let why = names_the_input(e, &[&log, &cal]);
            prop_assert!(why.is_ok(), "apply: {why:?}\n{}", x.text());
            prop_assert!(!applied.exists(), "apply wrote {} and failed", applied.display());
        }
    }
    let mut argv: Vec<String> = vec![
        "next".into(),
        cal.display().to_string(),
        log.display().to_string(),
        "--roll=-5,5".into(),
        "--pitch=-20,20".into(),
        "--site".into(),
        "28.2,112.97".into(),
        "--date".into(),
        "2013.0".into(),
        "--count".into(),
        "2".into(),
    ];
    if let Some(c) = &x.columns {
        argv.push(format!("--columns={c}"));
    }
    if x.skip_bad {
        argv.push("--skip-bad".into());
    }
    let next = Next::try_parse_from(&argv).unwrap().args;
    if let Err(e) = quietly(|| next::run(&next)) {
        let why = names_the_input(e, &[&log, &cal]);
        prop_assert!(
            why.is_ok(),
            "next: {why:?}\n{}\n{}",
            String::from_utf8_lossy(&edited),
            x.text()
        );
    }
    Ok(())
}

/// A log the fuzzer found on CI: one reading repeated nine times, a spoiled row and a long row
/// skipped, nine readings of the ellipsoid, at a scale a thousandth of its units' field.
#[test]
fn a_log_of_one_reading_repeated_and_nine_others() {
    use Row::Reading;
    let mut rows = vec![Reading(0), Row::Spoiled(0, 0, "1e308")];
    rows.extend((0..8).map(|_| Reading(0)));
    rows.extend([Row::Long(0), Reading(0)]);
    rows.extend([124, 169, 366, 915, 779, 612, 551, 60].map(Reading));
    let x = FuzzLog {
        header: HEADERS[0],
        separator: Sep::Semicolon,
        decimal_comma: false,
        rows,
        scale: 1e6,
        columns: None,
        fit: "diagonal",
        skip_bad: true,
        reject: Some(3.0),
        magnitude: None,
        noise: None,
        place: Some(Place::nt_not_matched()),
        edit: None,
    };
    if let Err(e) = calibrate_apply_next(&x) {
        panic!("{e}");
    }
}

/// A command run in this process with what it prints kept, not printed: a passing run of the
/// tests prints what a reader needs, not thousands of reports.
fn quietly<T>(f: impl FnOnce() -> T) -> T {
    magcal_runner::output::capture::capturing(f).0
}

/// `calibrate LOG ARGS --json --out DIR` in-process: the outcome and the calibration written.
fn calibrate_in(dir: &Path, log_text: &str, args: &[&str]) -> (Result<(), Failure>, Option<serde_json::Value>) {
    use clap::Parser;
    use magcal_runner::commands::calibrate::{self, CalibrateArgs};
    #[derive(Parser)]
    struct Calibrate {
        #[command(flatten)]
        args: CalibrateArgs,
    }
    let log = dir.join("log.csv");
    std::fs::write(&log, log_text).unwrap();
    let out = dir.join("cal");
    let mut argv = vec![
        "calibrate".to_string(),
        log.display().to_string(),
        "--json".into(),
        "--out".into(),
        out.display().to_string(),
    ];
    argv.extend(args.iter().map(|a| a.to_string()));
    let result = quietly(|| calibrate::run(&Calibrate::try_parse_from(&argv).unwrap().args));
    let json = std::fs::read(out.join("calibration.json"))
        .ok()
        .map(|b| serde_json::from_slice(&b).unwrap());
    (result, json)
}

/// Readings on an ellipsoid (scale factors 1.3, 0.7, 1.2, an offset) at `scale`, comma-separated
/// under `x,y,z`.
fn ellipsoid_log(scale: f64, n: usize) -> String {
    let mut text = String::from("x,y,z\n");
    for i in 0..n {
        let z = -1.0 + (2 * (i % 40) + 1) as f64 / 40.0;
        let a = i as f64 * 2.4;
        let r = (1.0 - z * z).sqrt();
        text.push_str(&format!(
            "{:e},{:e},{:e}\n",
            scale * (1.3 * r * a.cos() + 0.2),
            scale * (0.7 * r * a.sin() - 0.1),
            scale * (1.2 * z + 0.3)
        ));
    }
    text
}

#[test]
fn a_usable_calibration_far_from_unit_scale_is_one_apply_takes() {
    // Readings at 1e150 fitted to a magnitude of 1: P ~ 1e-150, whose inverse K ~ 1e150 was
    // computed through a d f ~ 1e-450 (zero) and written as null while "usable" said true.
    let tmp = tempfile::TempDir::new().unwrap();
    let (result, json) = calibrate_in(
        tmp.path(),
        &ellipsoid_log(1e150, 60),
        &["--fit=diagonal", "--magnitude=1", "--noise=1e147"],
    );
    assert!(result.is_ok(), "{:?}", result.err().map(|e| format!("{e:?}")));
    let json = json.unwrap();
    check_usable(&json).unwrap();
    // Its scale factors are the readings' 1e150 (1.3, 0.7, 1.2): to the fit's accuracy, which
    // with 60 noise-free readings is near rounding.
    let scale: Vec<f64> = json["scale"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    for (s, want) in scale.iter().zip([1.3e150, 0.7e150, 1.2e150]) {
        assert!((s / want - 1.0).abs() < 1e-9, "{scale:?}");
    }
    // A magnitude 1e300 for readings at 1e-6: P^T P overflows, and the calibration is not usable.
    let tmp = tempfile::TempDir::new().unwrap();
    let (result, json) = calibrate_in(
        tmp.path(),
        &ellipsoid_log(1e-6, 60),
        &["--fit=diagonal", "--magnitude=1e300"],
    );
    match result {
        Err(Failure::Unusable(why)) => assert!(why.contains("fails the checks of apply and next"), "{why}"),
        Err(Failure::Input(e)) => panic!("{e:#}"),
        other => panic!("{:?}", other.err().map(|e| format!("{e:?}"))),
    }
    assert_eq!(json.unwrap()["usable"], false);
}

#[test]
fn apply_finds_the_recorded_columns_in_logs_of_every_separator() {
    use magcal_runner::commands::apply::{self, ApplyArgs};
    // The columns calibrate records were looked up in the log's first row split at commas only:
    // a semicolon-, tab- or space-separated log, or a header with an empty name (`column 2`),
    // was refused by apply without --columns.
    // Runs of spaces have no empty cell: that log's header is plain.
    let plain = ellipsoid_log(48_000.0, 60);
    let empty_name = plain.replace("x,y,z", "x,,z");
    // A name two columns carry was recorded as it is, and apply took its first column twice.
    let twice = plain.replace("x,y,z", "x,x,z");
    for (sep, columns, text, want) in [
        (";", None, &empty_name, ["x", "column 2", "z"]),
        ("\t", None, &empty_name, ["x", "column 2", "z"]),
        ("  ", None, &plain, ["x", "y", "z"]),
        (",", Some("--columns=1,2,3"), &empty_name, ["x", "column 2", "z"]),
        (",", None, &twice, ["column 1", "column 2", "z"]),
        (",", Some("--columns=2,1,3"), &twice, ["column 2", "column 1", "z"]),
    ] {
        let tmp = tempfile::TempDir::new().unwrap();
        let text = text.replace(',', sep);
        let args: Vec<&str> = columns.into_iter().collect();
        let (result, json) = calibrate_in(tmp.path(), &text, &args);
        assert!(result.is_ok(), "{sep:?}: {:?}", result.err().map(|e| format!("{e:?}")));
        assert_eq!(json.unwrap()["columns"], serde_json::json!(want));
        let out = tmp.path().join("applied.csv");
        let apply = ApplyArgs {
            calibration: tmp.path().join("cal/calibration.json"),
            log: tmp.path().join("log.csv"),
            input: LogArgs::default(),
            matrix: Default::default(),
            out: Some(out.clone()),
        };
        if let Err(Failure::Input(e)) = quietly(|| apply::run(&apply)) {
            panic!("{sep:?}: {e:#}");
        }
        // The log's own readings calibrated: 60 rows on the sphere of the magnitude, to the
        // noise-free fit's accuracy.
        check_applied(&out).unwrap();
        let norms: Vec<f64> = std::fs::read_to_string(&out)
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| l.rsplit(',').next().unwrap().parse().unwrap())
            .collect();
        assert_eq!(norms.len(), 60);
        let magnitude = norms.iter().sum::<f64>() / 60.0;
        assert!(
            norms.iter().all(|n| (n / magnitude - 1.0).abs() < 1e-9),
            "{sep:?}: {norms:?}"
        );
    }
}

#[test]
fn rejection_with_no_spread_is_no_truncation() {
    // Five readings fitted exactly by the offset model: the residuals' spread is zero, and
    // `--reject` passed a truncation of zero width to the fit, which panicked.
    let tmp = tempfile::TempDir::new().unwrap();
    // The fuzzer's case: a time column read as the first of three, and a repeated row.
    let x = FuzzLog {
        header: (None, 1),
        separator: Sep::Comma,
        decimal_comma: false,
        rows: vec![
            Row::Reading(510),
            Row::Reading(382),
            Row::Reading(538),
            Row::Reading(29),
            Row::Repeat,
        ],
        scale: 1.0,
        columns: None,
        fit: "offset",
        skip_bad: false,
        reject: Some(3.0),
        magnitude: None,
        noise: None,
        place: Some(Place::nt_not_matched()),
        edit: None,
    };
    let argv = x.calibrate_argv(Path::new("log.csv"), Path::new("cal"));
    // `--fit offset` and what follows `--out`.
    let args: Vec<&str> = argv[2..4].iter().chain(&argv[7..]).map(String::as_str).collect();
    let (result, json) = calibrate_in(tmp.path(), &x.text(), &args);
    let json = json.unwrap_or_else(|| panic!("{:?}", result.err().map(|e| format!("{e:?}"))));
    assert_eq!(json["rejected"], 0);
    assert_eq!(json["noise_estimate"]["truncation_k"], serde_json::Value::Null);
}

#[test]
fn a_bad_row_met_by_apply_is_the_logs_fault_not_the_outputs() {
    use magcal_runner::commands::apply::{self, ApplyArgs};
    // apply streams the log into its output: a bad row part way was reported as
    // "calibrated.csv: cannot write: log.csv: line 5: ...".
    let tmp = tempfile::TempDir::new().unwrap();
    let (result, _) = calibrate_in(tmp.path(), &ellipsoid_log(48_000.0, 60), &[]);
    assert!(result.is_ok());
    let log = tmp.path().join("log.csv");
    let mut text = ellipsoid_log(48_000.0, 3);
    text.push_str("1,2,zz\n");
    std::fs::write(&log, text).unwrap();
    let out = tmp.path().join("calibrated.csv");
    let apply = ApplyArgs {
        calibration: tmp.path().join("cal/calibration.json"),
        log: log.clone(),
        input: LogArgs::default(),
        matrix: Default::default(),
        out: Some(out.clone()),
    };
    let Err(Failure::Input(e)) = quietly(|| apply::run(&apply)) else {
        panic!("apply took a bad row")
    };
    let message = format!("{e:#}");
    assert!(
        message.starts_with(&format!(
            "{}: line 5, column 3 (z): \"zz\" is not a number",
            log.display()
        )),
        "{message}"
    );
    assert!(!message.contains("cannot write") && !out.exists(), "{message}");
}

#[test]
fn apply_gives_the_length_of_calibrated_readings_near_the_largest_number() {
    use magcal_runner::commands::apply::{self, ApplyArgs};
    // Readings on a sphere of radius 8e307 fitted by the offset model calibrate to components
    // near 4.6e307 each in some directions: finite, but the sum of their squares is not, and
    // apply refused the log its usable calibration was made from. Sixty readings, so that the
    // calibration has held-out evidence and is usable; noise-free, the noise given.
    let tmp = tempfile::TempDir::new().unwrap();
    let mut log = String::from("x,y,z\n");
    for i in 0..60 {
        let z = -1.0 + (2 * i + 1) as f64 / 60.0;
        let a = i as f64 * 2.399_963;
        let r = (1.0 - z * z).sqrt();
        let c = [1e306, -1e306, 2e306];
        log.push_str(&format!(
            "{:e},{:e},{:e}\n",
            c[0] + 8e307 * r * a.cos(),
            c[1] + 8e307 * r * a.sin(),
            c[2] + 8e307 * z
        ));
    }
    let (result, json) = calibrate_in(tmp.path(), &log, &["--fit=offset", "--noise=1e297"]);
    assert!(result.is_ok(), "{:?}", result.err().map(|e| format!("{e:?}")));
    let magnitude = json.unwrap()["magnitude"].as_f64().unwrap();
    let out = tmp.path().join("calibrated.csv");
    let apply = ApplyArgs {
        calibration: tmp.path().join("cal/calibration.json"),
        log: tmp.path().join("log.csv"),
        input: LogArgs::default(),
        matrix: Default::default(),
        out: Some(out.clone()),
    };
    if let Err(Failure::Input(e)) = quietly(|| apply::run(&apply)) {
        panic!("{e:#}");
    }
    check_applied(&out).unwrap();
    // Each row's norm is the length of its x, y, z, to a few roundings.
    for line in std::fs::read_to_string(&out).unwrap().lines().skip(1) {
        let v: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
        let s = v[1].abs().max(v[2].abs()).max(v[3].abs());
        let length = s * ((v[1] / s).powi(2) + (v[2] / s).powi(2) + (v[3] / s).powi(2)).sqrt();
        assert!((v[4] / length - 1.0).abs() <= 8.0 * f64::EPSILON, "{line}");
        assert!(v[4] > 0.1 * magnitude, "{line}");
    }
}
