//! Bad input, end to end: every case exits 2 with one stderr line naming the file, the key and the
//! value, and leaves an earlier result set byte-identical, with nothing left beside it. The binary
//! runs under an address-space limit ([`crate::common::MEMORY_LIMIT`]), so a size that escaped its bound
//! fails fast here instead of exhausting the machine.

use std::fs;
use std::path::{Path, PathBuf};

use crate::common::{leftovers, magcal, run_into, scenarios, smoke, snapshot};
use tempfile::TempDir;

/// A scenario case: the text of the file, and what its error line must contain (besides its name).
struct Case {
    text: String,
    needles: Vec<String>,
    /// Only `run` refuses it (a bound on the trials, which `design` does not run).
    run_only: bool,
}

fn case(text: String, needles: &[&str]) -> Case {
    Case {
        text,
        needles: needles.iter().map(|s| s.to_string()).collect(),
        run_only: false,
    }
}

fn run_only(c: Case) -> Case {
    Case { run_only: true, ..c }
}

/// The smoke scenario with `from` replaced by `to` (which must occur).
fn smoke_with(from: &str, to: &str) -> String {
    let text = fs::read_to_string(smoke()).unwrap();
    assert!(text.contains(from), "{from:?} not in smoke.toml");
    text.replacen(from, to, 1)
}

/// The wu2014 scenario (field from the WMM) with `from` replaced by `to`.
fn wu_with(from: &str, to: &str) -> String {
    let text = fs::read_to_string(scenarios().join("wu2014.toml")).unwrap();
    assert!(text.contains(from), "{from:?} not in wu2014.toml");
    text.replacen(from, to, 1)
}

/// A scenario with the smoke scenario's header, field, sensor and box, and `designs` as written.
fn with_designs(designs: &str) -> String {
    let text = fs::read_to_string(smoke()).unwrap();
    let head = &text[..text.find("[[design]]").unwrap()];
    format!("{head}{designs}")
}

const EXPLICIT9: &str = "[[design]]\nname = \"u\"\nkind = \"explicit\"\nattitudes = [\n\
  { roll_deg = -5.0, yaw_deg = -60.0, pitch_deg = -20.0 },\n  { roll_deg = -5.0, yaw_deg = 60.0, pitch_deg = -20.0 },\n\
  { roll_deg = -5.0, yaw_deg = 180.0, pitch_deg = -20.0 },\n  { roll_deg = 0.0, yaw_deg = -90.0, pitch_deg = 0.0 },\n\
  { roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = 0.0 },\n  { roll_deg = 0.0, yaw_deg = 90.0, pitch_deg = 0.0 },\n\
  { roll_deg = 0.0, yaw_deg = 180.0, pitch_deg = 0.0 },\n  { roll_deg = 5.0, yaw_deg = -60.0, pitch_deg = 20.0 },\n\
  { roll_deg = 5.0, yaw_deg = 60.0, pitch_deg = 20.0 },\n]\n";

fn scenario_cases() -> Vec<Case> {
    let many_sigmas = format!(
        "sigma_nt = [{}]",
        (1..=1001).map(|i| format!("{i}.0")).collect::<Vec<_>>().join(", ")
    );
    let many_designs: String = (0..1001)
        .map(|i| format!("[[design]]\nname = \"r{i}\"\nkind = \"random\"\nm = 9\n"))
        .collect();
    vec![
        // Syntax, schema and types.
        case(smoke_with("seed = 7", "seed = [7"), &[":5:1", "expected `,`"]),
        case(
            smoke_with("seed = 7", "seed = 7\nbogus = 1"),
            &[":5:1", "unknown field `bogus`", "(in: bogus = 1)"],
        ),
        case(
            smoke_with("seed = 7", "seed = \"seven\""),
            &[":4:8", "invalid type", "\"seven\""],
        ),
        case(String::new(), &["missing field `schema`"]),
        case(smoke_with("schema = 1", "schema = 2"), &["schema = 2", "schema 1"]),
        // Names that would escape results/ or cannot name a file.
        case(
            smoke_with("name = \"smoke\"", "name = \"..\""),
            &["name = \"..\"", "not starting with '.'"],
        ),
        case(smoke_with("name = \"smoke\"", "name = \".\""), &["name = \".\""]),
        case(smoke_with("name = \"smoke\"", "name = \"a/b\""), &["name = \"a/b\""]),
        case(
            smoke_with("name = \"smoke\"", &format!("name = \"{}\"", "n".repeat(300))),
            &["name = \"nnnn", "(300 characters)", "at most 64"],
        ),
        case(
            smoke_with("name = \"optimum\"", &format!("name = \"{}\"", "d".repeat(300))),
            &["design[3].name", "at most 64"],
        ),
        // Trials.
        case(smoke_with("trials = 200", "trials = 0"), &["trials = 0", "at least 1"]),
        case(
            smoke_with("trials = 200", "trials = 100000000"),
            &["trials = 100000000", "at most 10000000"],
        ),
        case(smoke_with("trials = 200", "trials = 1e9"), &["invalid type", "1e9"]),
        run_only(case(
            smoke_with("trials = 200", "trials = 10000000"),
            &[
                "trials = 10000000",
                "needs about",
                "trial outcomes",
                "the limit is",
                "RLIMIT_AS",
            ],
        )),
        // Noise levels.
        case(
            smoke_with("sigma_nt = [10.0, 30.0]", "sigma_nt = []"),
            &["sigma_nt = []"],
        ),
        case(
            smoke_with("sigma_nt = [10.0, 30.0]", "sigma_nt = [10.0, -30.0]"),
            &["sigma_nt[1] = -30", "negative"],
        ),
        case(
            smoke_with("sigma_nt = [10.0, 30.0]", "sigma_nt = [nan]"),
            &["sigma_nt[0] = NaN", "finite"],
        ),
        case(
            smoke_with("sigma_nt = [10.0, 30.0]", "sigma_nt = [0.0, -0.0]"),
            &["sigma_nt[1] = -0", "listed twice"],
        ),
        case(
            smoke_with("sigma_nt = [10.0, 30.0]", "sigma_nt = [10.0, 1e-308]"),
            &["sigma_nt[1] = 1e-308", "must be 0 or lie in [1e-6, 100000000] nT"],
        ),
        case(
            smoke_with("sigma_nt = [10.0, 30.0]", "sigma_nt = [5e-324, 30.0]"),
            &["sigma_nt[0] = 5e-324"],
        ),
        case(
            smoke_with("sigma_nt = [10.0, 30.0]", "sigma_nt = [10.0, 1.797e308]"),
            &["sigma_nt[1] = 1.797e308"],
        ),
        case(
            smoke_with("sigma_nt = [10.0, 30.0]", "sigma_nt = [1e100]"),
            &["sigma_nt[0] = 1e100"],
        ),
        case(
            smoke_with("sigma_nt = [10.0, 30.0]", &many_sigmas),
            &["invalid length 1001", "at most 1000 noise levels"],
        ),
        case(
            smoke_with("sigma_nt = [10.0, 30.0]", "sigma_nt = \"30\""),
            &["invalid type", "a number or a list"],
        ),
        // The field given as numbers.
        case(
            smoke_with("north_nt = 35272.34", "north_nt = inf"),
            &["field.north_nt = inf", "finite"],
        ),
        case(
            smoke_with("north_nt = 35272.34", "north_nt = 1e308"),
            &["field.north_nt = 1e308", "[-10000000, 10000000] nT"],
        ),
        case(
            smoke_with(
                "north_nt = 35272.34\neast_nt = -2085.74\ndown_nt = 32897.67",
                "north_nt = 0.0\neast_nt = 0.0\ndown_nt = 0.0",
            ),
            &["north_nt, east_nt, down_nt = [0, 0, 0]", "at least 1 nT"],
        ),
        case(smoke_with("down_nt = 32897.67\n", ""), &["field.down_nt is missing"]),
        case(
            smoke_with("yaw_offset_deg = 0.0", "yaw_offset_deg = 1e308"),
            &["field.yaw_offset_deg = 1e308", "[-360, 360] degrees"],
        ),
        // The field from the World Magnetic Model.
        case(
            wu_with("year = 2013.0", "year = 2016.0"),
            &["field.year = 2016", "validity window of WMM2010"],
        ),
        case(
            wu_with("lat_deg = 28.2", "lat_deg = 95.0"),
            &["field.lat_deg = 95", "[-90, 90]"],
        ),
        case(
            wu_with("model = \"WMM2010\"", "model = \"IGRF13\""),
            &["field.model = \"IGRF13\"", "unknown model"],
        ),
        case(wu_with("alt_m = 0.0\n", ""), &["field.alt_m is missing"]),
        case(
            wu_with("alt_m = 0.0\n", "alt_m = 0.0\nnorth_nt = 1.0\n"),
            &["[field]", "not both"],
        ),
        case(
            wu_with("alt_m = 0.0", "alt_m = -6378137.0"),
            &["field.alt_m = -6378137", "[-1000, 850000] m"],
        ),
        case(
            wu_with("lon_deg = 112.97", "lon_deg = nan"),
            &["field.lon_deg = NaN", "finite"],
        ),
        // The sensor.
        case(
            smoke_with("psi_deg = [1.5, 0.8, 1.4]", "psi_deg = [1.5, 0.8, 1.4, 2.0]"),
            &["invalid length 4", "exactly 3 numbers"],
        ),
        case(
            smoke_with("psi_deg = [1.5, 0.8, 1.4]", "psi_deg = [1.5, 0.8, 1.4, \"junk\"]"),
            &["invalid type", "\"junk\""],
        ),
        case(
            smoke_with("psi_deg = [1.5, 0.8, 1.4]", "psi_deg = [95.0, 0.8, 1.4]"),
            &["sensor.psi_deg[0] = 95", "[-45, 45]"],
        ),
        case(
            smoke_with("scale = [1.3, 0.7, 1.2]", "scale = [1.3, 0.0, 1.2]"),
            &["sensor.scale[1] = 0", "[0.001, 1000]"],
        ),
        case(
            smoke_with("scale = [1.3, 0.7, 1.2]", "scale = [1.3, 0.7, 1e9]"),
            &["sensor.scale[2] = 1000000000"],
        ),
        case(
            smoke_with("bias_nt = [3000.0, -6000.0, 5000.0]", "bias_nt = [1e9, 1e9, 1e9]"),
            &["sensor.bias_nt[0] = 1000000000"],
        ),
        case(
            smoke_with("bias_nt = [3000.0, -6000.0, 5000.0]", "bias_nt = [3000.0, -6000.0]"),
            &["invalid length 2"],
        ),
        // The attitude box.
        case(
            smoke_with("roll_deg = [-5.0, 5.0]", "roll_deg = [5.0, -5.0]"),
            &["attitude_box.roll_deg = [5, -5]", "minimum must be below"],
        ),
        case(
            smoke_with("roll_deg = [-5.0, 5.0]", "roll_deg = [-5.0, 5.0, 99.0]"),
            &["invalid length 3", "exactly 2"],
        ),
        case(
            smoke_with("pitch_deg = [-20.0, 20.0]", "pitch_deg = [nan, 20.0]"),
            &["attitude_box.pitch_deg = [NaN, 20]", "finite"],
        ),
        case(
            smoke_with("yaw_deg = [-180.0, 180.0]", "yaw_deg = [-180.0, 360.0]"),
            &["attitude_box.yaw_deg = [-180, 360]", "more than 360"],
        ),
        case(
            smoke_with("roll_deg = [-5.0, 5.0]", "roll_deg = [-1e308, 5.0]"),
            &["attitude_box.roll_deg = [-1e308, 5]", "[-360, 360]"],
        ),
        // Calibration.
        case(
            smoke_with("[calibration]", "[calibration]\nmax_iterations = 0"),
            &["calibration.max_iterations = 0"],
        ),
        case(
            smoke_with("residual = \"paper\"", "residual = \"papre\""),
            &["calibration.residual = \"papre\"", "expected \"readings\""],
        ),
        case(
            smoke_with("[calibration]", "[verdict]\ntrials = 5\n\n[calibration]"),
            &["verdict.trials = 5", "at least 20"],
        ),
        case(
            smoke_with("[calibration]", "[calibration]\nmax_iterations = 10000000"),
            &["calibration.max_iterations = 10000000", "at most 1000000"],
        ),
        // Execution error.
        case(
            smoke_with(
                "sigma_nt = [10.0, 30.0]",
                "sigma_nt = [10.0, 30.0]\nattitude_sigma_deg = -1.0",
            ),
            &["attitude_sigma_deg[0] = -1", "[0, 30] degrees"],
        ),
        case(
            smoke_with(
                "sigma_nt = [10.0, 30.0]",
                "sigma_nt = [10.0, 30.0]\nattitude_sigma_deg = [0.0, 45.0]",
            ),
            &["attitude_sigma_deg[1] = 45", "[0, 30] degrees"],
        ),
        case(
            smoke_with(
                "sigma_nt = [10.0, 30.0]",
                "sigma_nt = [10.0, 30.0]\nattitude_sigma_deg = nan",
            ),
            &["attitude_sigma_deg[0] = NaN"],
        ),
        case(
            smoke_with(
                "sigma_nt = [10.0, 30.0]",
                "sigma_nt = [10.0, 30.0]\nattitude_sigma_deg = []",
            ),
            &["attitude_sigma_deg = []"],
        ),
        case(
            smoke_with(
                "sigma_nt = [10.0, 30.0]",
                "sigma_nt = [10.0, 30.0]\nattitude_sigma_deg = [1.0, 1.0]",
            ),
            &["attitude_sigma_deg[1] = 1", "listed twice"],
        ),
        // Certificate.
        case(
            smoke_with("[attitude_box]", "[certificate]\ncandidates = 10\n\n[attitude_box]"),
            &["certificate.candidates = 10", "at least 100"],
        ),
        case(
            smoke_with(
                "[attitude_box]",
                "[certificate]\ncandidates = 100000000\n\n[attitude_box]",
            ),
            &["certificate.candidates = 100000000", "at most 200000"],
        ),
        case(
            smoke_with("[attitude_box]", "[certificate]\ntolerance = 0.0\n\n[attitude_box]"),
            &["certificate.tolerance = 0"],
        ),
        case(
            smoke_with("[attitude_box]", "[certificate]\ntolerance = nan\n\n[attitude_box]"),
            &["certificate.tolerance = NaN"],
        ),
        case(
            smoke_with("[attitude_box]", "[certificate]\nmax_rounds = 0\n\n[attitude_box]"),
            &["certificate.max_rounds = 0"],
        ),
        case(
            smoke_with("[attitude_box]", "[certificate]\nstarts = 3\n\n[attitude_box]"),
            &["unknown field `starts`"],
        ),
        // Designs.
        case(with_designs(""), &["missing field `design`"]),
        case(
            smoke_with("  { roll_deg = 5.0, yaw_deg = 60.0, pitch_deg = 20.0 },\n]", "]"),
            &["design[0] (\"uniform\").attitudes (count) = 8", "at least 9"],
        ),
        case(
            smoke_with(
                "{ roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = 0.0 }",
                "{ roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = 25.0 }",
            ),
            &[
                "design[0] (\"uniform\").attitudes[4].pitch_deg = 25",
                "outside the attitude box [-20, 20]",
            ],
        ),
        case(
            smoke_with(
                "{ roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = 0.0 }",
                "{ roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = -60 }",
            ),
            &["attitudes[4].pitch_deg = -60: outside"],
        ),
        case(
            smoke_with(
                "{ roll_deg = 0.0, yaw_deg = 0.0, pitch_deg = 0.0 }",
                "{ roll_deg = nan, yaw_deg = 0.0, pitch_deg = 0.0 }",
            ),
            &["attitudes[4].roll_deg = NaN"],
        ),
        case(
            smoke_with("m = 9\n# [P1] Table I", "m = 8\n# [P1] Table I"),
            &["design[2] (\"pso\").m = 8", "at least 9"],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 8\n"),
            &["design[0] (\"p\").readings = 8", "at least 9"],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 1000000000\n"),
            &["design[0] (\"p\").readings = 1000000000", "at most 100000"],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmax_attitudes = 0\n"),
            &["design[0] (\"p\").max_attitudes = 0", "at least 9", "\"all\""],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmax_attitudes = 8\n"),
            &["design[0] (\"p\").max_attitudes = 8", "at least 9", "9 unknowns"],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmax_attitudes = -12\n"),
            &["design[0] (\"p\").max_attitudes = -12", "at least 9"],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmax_attitudes = 12.5\n"),
            &[
                "design[0] (\"p\").max_attitudes = 12.5",
                "a whole number of attitudes or \"all\"",
            ],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmax_attitudes = \"many\"\n"),
            &[
                "design[0] (\"p\").max_attitudes = \"many\"",
                "a whole number of attitudes",
            ],
        ),
        case(
            with_designs(&format!(
                "[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmax_attitudes = \"{}\"\n",
                "x".repeat(5000)
            )),
            &[
                "design[0] (\"p\").max_attitudes = \"xxx",
                "xxx...\":",
                "a whole number of attitudes",
            ],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmin_readings_per_attitude = 0\n"),
            &["design[0] (\"p\").min_readings_per_attitude = 0", "at least 1"],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmin_readings_per_attitude = 34\n"),
            &[
                "design[0] (\"p\").min_readings_per_attitude = 34",
                "at most 33",
                "readings = 300",
            ],
        ),
        case(
            with_designs(
                "[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmin_readings_per_attitude = 2.5\n",
            ),
            &[
                "design[0] (\"p\").min_readings_per_attitude = 2.5",
                "a whole number of readings",
            ],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmin_readings_per_attitude = -1\n"),
            &["design[0] (\"p\").min_readings_per_attitude = -1", "at least 1"],
        ),
        case(
            with_designs("[[design]]\nname = \"p\"\nkind = \"plan\"\nreadings = 300\nmax_attitude = 12\n"),
            &["unknown field `max_attitude`"],
        ),
        case(
            with_designs("[[design]]\nname = \"r\"\nkind = \"random\"\nm = 1000000000\n"),
            &["design[0] (\"r\").m = 1000000000", "at most 100000"],
        ),
        case(
            with_designs(
                "[[design]]\nname = \"g\"\nkind = \"grid\"\nlevels = { roll = 100000, yaw = 100000, pitch = 1 }\n",
            ),
            &[
                "design[0] (\"g\").levels (roll x yaw x pitch) = 100000 x 100000 x 1 = 10000000000",
                "at most 100000",
            ],
        ),
        case(
            with_designs(
                "[[design]]\nname = \"g\"\nkind = \"grid\"\nlevels = { roll = 9223372036854775807, yaw = 3, pitch = 3 }\n",
            ),
            &["levels.roll = 9223372036854775807", "at most 100000"],
        ),
        case(
            with_designs("[[design]]\nname = \"g\"\nkind = \"grid\"\nlevels = { roll = 0, yaw = 9, pitch = 3 }\n"),
            &["levels.roll = 0", "at least 1"],
        ),
        case(
            with_designs("[[design]]\nname = \"g\"\nkind = \"grid\"\nlevels = { roll = 2, yaw = 2, pitch = 2 }\n"),
            &["= 2 x 2 x 2 = 8", "at least 9"],
        ),
        case(
            smoke_with("particles = 40", "particles = 0"),
            &["design[2] (\"pso\").particles = 0", "at least 1"],
        ),
        case(
            smoke_with("particles = 40", "particles = 9223372036854775807"),
            &["particles = 9223372036854775807", "at most 100000"],
        ),
        case(
            smoke_with("iterations = 150", "iterations = 0"),
            &["design[2] (\"pso\").iterations = 0"],
        ),
        case(
            smoke_with("particles = 40", "particles = 40\nw_min = 0.95"),
            &[
                "design[2] (\"pso\").w_min = 0.95",
                "w_max = 0.9",
                "minimum must be below",
            ],
        ),
        case(
            smoke_with("particles = 40", "particles = 40\nvmax_fraction = 2.0"),
            &["design[2] (\"pso\").vmax_fraction = 2", "(0, 1]"],
        ),
        case(
            smoke_with("particles = 40", "particles = 40\nc1 = -1.0"),
            &["design[2] (\"pso\").c1 = -1", "[0, 10]"],
        ),
        case(
            smoke_with("starts = 16", "starts = 1000000000"),
            &["design[3] (\"optimum\").starts = 1000000000", "at most 100000"],
        ),
        case(
            smoke_with("starts = 16", "starts = 16\ngradient_tolerance = 0.0"),
            &["design[3] (\"optimum\").gradient_tolerance = 0"],
        ),
        case(
            smoke_with("name = \"optimum\"", "name = \"pso\""),
            &["design[3].name = \"pso\"", "another design"],
        ),
        case(
            smoke_with("kind = \"optimum\"", "kind = \"magic\""),
            &["unknown variant `magic`"],
        ),
        case(
            with_designs(&many_designs),
            &["[[design]] (count) = 1001", "at most 1000"],
        ),
        // Repeated PSO runs.
        case(
            smoke_with("design = \"pso\"", "design = \"uniform\""),
            &["pso_runs.design = \"uniform\"", "explicit, not pso"],
        ),
        case(
            smoke_with("design = \"pso\"", "design = \"nope\""),
            &["pso_runs.design = \"nope\"", "no design"],
        ),
        case(smoke_with("runs = 4", "runs = 0"), &["pso_runs.runs = 0"]),
        case(
            smoke_with("runs = 4", "runs = 1000000000"),
            &["pso_runs.runs = 1000000000", "at most 100000"],
        ),
        // A valid explicit design, for the shape of the base text.
        case(
            with_designs(&EXPLICIT9.replace("name = \"u\"", "name = \"\"")),
            &["design[0].name = \"\""],
        ),
    ]
}

/// Runs `args` against `out` (which holds an earlier set), expects exit 2, a message containing
/// every needle, and the earlier set untouched with nothing beside it; what is wrong, if anything.
fn refusal(args: &[&std::ffi::OsStr], out: &Path, needles: &[String], one_line: bool) -> Option<String> {
    let before = snapshot(out);
    let output = magcal().args(args).output().unwrap();
    let stderr = String::from_utf8(output.stderr).unwrap();
    let mut wrong = Vec::new();
    if output.status.code() != Some(2) {
        wrong.push(format!("exit {:?}", output.status.code()));
    }
    wrong.extend(
        needles
            .iter()
            .filter(|n| !stderr.contains(n.as_str()))
            .map(|n| format!("{n:?} missing")),
    );
    if one_line && crate::common::error_lines(&stderr).len() != 1 {
        wrong.push("not one line".into());
    }
    if stderr.contains("panicked") {
        wrong.push("panicked".into());
    }
    if snapshot(out) != before {
        wrong.push("earlier results touched".into());
    }
    if !leftovers(out).is_empty() {
        wrong.push(format!("left beside: {:?}", leftovers(out)));
    }
    (!wrong.is_empty()).then(|| format!("{args:?}: {}\n    stderr: {stderr}", wrong.join(", ")))
}

fn expect_refusal(args: &[&std::ffi::OsStr], out: &Path, needles: &[String], one_line: bool) {
    if let Some(wrong) = refusal(args, out, needles, one_line) {
        panic!("{wrong}");
    }
}

#[test]
fn every_bad_scenario_is_one_clear_line_and_leaves_results_untouched() {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    run_into(&out, 7);
    let cases = scenario_cases();
    assert!(cases.len() >= 70, "{} cases", cases.len());
    let mut wrong = Vec::new();
    for (i, c) in cases.iter().enumerate() {
        let file = tmp.path().join(format!("case{i}.toml"));
        fs::write(&file, &c.text).unwrap();
        let mut needles = c.needles.clone();
        needles.push(format!("case{i}.toml"));
        for command in ["run", "design"].iter().take(if c.run_only { 1 } else { 2 }) {
            let args = [
                command.as_ref(),
                "--quiet".as_ref(),
                "--out".as_ref(),
                out.as_os_str(),
                file.as_os_str(),
            ];
            wrong.extend(refusal(&args, &out, &needles, true));
        }
    }
    assert!(
        wrong.is_empty(),
        "{} of {} refusals wrong:\n{}",
        wrong.len(),
        2 * cases.len(),
        wrong.join("\n")
    );
    // Not UTF-8, and a file that does not exist.
    let binary = tmp.path().join("binary.toml");
    fs::write(&binary, [0xff, 0xfe, 0x00, 0x41]).unwrap();
    let missing = tmp.path().join("missing.toml");
    for (file, needle) in [(&binary, "not UTF-8"), (&missing, "cannot read")] {
        let args = ["run".as_ref(), "--out".as_ref(), out.as_os_str(), file.as_os_str()];
        let needles = [
            needle.to_string(),
            file.file_name().unwrap().to_string_lossy().into_owned(),
        ];
        expect_refusal(&args, &out, &needles, true);
    }
}

#[test]
fn bad_command_lines_and_outputs_are_refused_before_any_work() {
    let tmp = TempDir::new().unwrap();
    let out = tmp.path().join("out");
    run_into(&out, 7);
    let s = smoke();
    let s = s.as_os_str();
    let o = out.as_os_str();
    // clap's own messages (several lines, with usage).
    for (args, needle) in [
        (
            vec![
                "run".as_ref(),
                "--threads".as_ref(),
                "0".as_ref(),
                "--out".as_ref(),
                o,
                s,
            ],
            "--threads",
        ),
        (
            vec![
                "run".as_ref(),
                "--threads".as_ref(),
                "1000000".as_ref(),
                "--out".as_ref(),
                o,
                s,
            ],
            "1..=256",
        ),
        (
            vec![
                "run".as_ref(),
                "--trials".as_ref(),
                "0".as_ref(),
                "--out".as_ref(),
                o,
                s,
            ],
            "--trials",
        ),
        (
            vec!["check".as_ref(), "--threads".as_ref(), "0".as_ref(), s],
            "--threads",
        ),
    ] {
        expect_refusal(&args, &out, &[needle.to_string()], false);
    }
    // Output directories that may not be replaced.
    let foreign = tmp.path().join("foreign");
    fs::create_dir(&foreign).unwrap();
    fs::write(foreign.join("thesis.tex"), "years of work").unwrap();
    let file = tmp.path().join("a-file");
    fs::write(&file, "x").unwrap();
    let under_file = file.join("out");
    let cases: Vec<(PathBuf, &str)> = vec![
        (foreign.clone(), "is not a magcal results directory"),
        (file.clone(), "exists and is not a directory"),
        (under_file, "cannot create"),
        (PathBuf::from("."), "name the output directory itself"),
        (tmp.path().join(".."), "name the output directory itself"),
    ];
    for (target, needle) in cases {
        let args = [
            "run".as_ref(),
            "--quiet".as_ref(),
            "--out".as_ref(),
            target.as_os_str(),
            s,
        ];
        expect_refusal(&args, &out, &[needle.to_string()], true);
    }
    assert_eq!(fs::read_to_string(foreign.join("thesis.tex")).unwrap(), "years of work");
    assert_eq!(fs::read_to_string(&file).unwrap(), "x");
}
