//! Helpers of the end-to-end tests: the real binary under a memory limit, scenario edits, and
//! snapshots of a result set.

use std::collections::BTreeMap;
use std::fs;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};

/// Address space the binary may use in these tests: a regression that allocates without bound
/// fails fast instead of eating the machine.
pub const MEMORY_LIMIT: u64 = 4 << 30;

/// `magcal` under [`MEMORY_LIMIT`] (setrlimit RLIMIT_AS in the child before exec).
pub fn magcal() -> assert_cmd::Command {
    magcal_with_limits(MEMORY_LIMIT, None)
}

/// `magcal` under an address-space limit and, optionally, a file-size limit (RLIMIT_FSIZE, with
/// SIGXFSZ ignored so that a write past it fails with EFBIG as on a full disk).
pub fn magcal_with_limits(address_space: u64, file_size: Option<u64>) -> assert_cmd::Command {
    assert_cmd::Command::from_std(process_with_limits(address_space, file_size, true))
}

/// `magcal` under [`MEMORY_LIMIT`], as a process to spawn and wait on.
pub fn magcal_process() -> std::process::Command {
    process_with_limits(MEMORY_LIMIT, None, true)
}

/// `magcal` under [`MEMORY_LIMIT`] and a file-size limit with SIGXFSZ left at its default action
/// (which kills): the binary must turn a write past the limit into an error itself.
pub fn magcal_with_file_size(file_size: u64) -> assert_cmd::Command {
    assert_cmd::Command::from_std(process_with_limits(MEMORY_LIMIT, Some(file_size), false))
}

fn process_with_limits(address_space: u64, file_size: Option<u64>, ignore_sigxfsz: bool) -> std::process::Command {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_magcal"));
    // SAFETY: only async-signal-safe calls (setrlimit, signal) between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            let limit = libc::rlimit {
                rlim_cur: address_space,
                rlim_max: address_space,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if let Some(size) = file_size {
                let limit = libc::rlimit {
                    rlim_cur: size,
                    rlim_max: size,
                };
                libc::signal(
                    libc::SIGXFSZ,
                    if ignore_sigxfsz { libc::SIG_IGN } else { libc::SIG_DFL },
                );
                if libc::setrlimit(libc::RLIMIT_FSIZE, &limit) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            Ok(())
        });
    }
    cmd
}

pub fn scenarios() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios")
}

pub fn smoke() -> PathBuf {
    scenarios().join("smoke.toml")
}

/// Every file below `dir` (relative path -> bytes).
pub fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.insert(rel, fs::read(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// Entries beside `dir` that a staging or set-aside step left.
pub fn leftovers(dir: &Path) -> Vec<String> {
    let name = dir.file_name().unwrap().to_string_lossy().into_owned();
    fs::read_dir(dir.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|f| f.starts_with(&format!(".{name}.")) || f.ends_with(".tmp"))
        .collect()
}

/// Runs the smoke scenario with 20 trials and `seed` into `out` (a result set to compare against).
pub fn run_into(out: &Path, seed: u64) {
    magcal()
        .args(["run", "--quiet", "--trials", "20", "--seed", &seed.to_string(), "--out"])
        .arg(out)
        .arg(smoke())
        .assert()
        .success();
}

/// `s` less its `manifest.json` (a calibration set's records the command line) and `run.json`
/// (a run's timings, threads and command line).
pub fn without_manifest(mut s: BTreeMap<String, Vec<u8>>) -> BTreeMap<String, Vec<u8>> {
    s.remove("manifest.json");
    s.remove("run.json");
    s
}

/// Puts back a snapshot of `dir` taken by [`snapshot`], removing what else is there.
pub fn restore(dir: &Path, files: &BTreeMap<String, Vec<u8>>) {
    if dir.exists() {
        fs::remove_dir_all(dir).unwrap();
    }
    for (rel, bytes) in files {
        let p = dir.join(rel);
        fs::create_dir_all(p.parent().unwrap()).unwrap();
        fs::write(p, bytes).unwrap();
    }
}

/// A public log of `../shared/data/` beside the repository, where it is (saying so where not).
pub fn data(path: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(path);
    if p.is_file() {
        Some(p)
    } else {
        eprintln!(
            "skipped: {} is absent (../shared/data/ holds the public logs)",
            p.display()
        );
        None
    }
}

/// How calibrate reads a BROAD trial: the field in uT, the ENU quaternion of the capture room.
pub const BROAD_ARGS: [&str; 8] = [
    "--columns",
    "mx,my,mz",
    "--quaternion",
    "qw,qx,qy,qz",
    "--attitude-frame",
    "enu",
    "--units",
    "uT",
];

/// BROAD trial 02's rows with movement and an attitude (32,280), written to `dir/moving.csv`;
/// `None` where the public log is absent.
pub fn broad_02_moving(dir: &Path) -> Option<PathBuf> {
    let path = data("broad/02_undisturbed_slow_rotation_B.csv")?;
    let text = fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let mut moving = format!("{}\n", lines.next().unwrap());
    for line in lines.filter(|l| l.ends_with(",1") && !l.contains(",,")) {
        moving.push_str(line);
        moving.push('\n');
    }
    let log = dir.join("moving.csv");
    fs::write(&log, moving).unwrap();
    Some(log)
}

/// The lines of an error on stderr, without what clap adds to a usage error: its indented
/// details (tips, possible values, the arguments missing), blank lines, the usage line and the
/// pointer to `--help`.
pub fn error_lines(stderr: &str) -> Vec<&str> {
    stderr
        .lines()
        .filter(|l| {
            !l.trim().is_empty()
                && !l.starts_with(char::is_whitespace)
                && !l.starts_with("Usage: ")
                && !l.starts_with("For more information, try")
        })
        .collect()
}

/// Exit 2 with one line on stderr (and clap's trailer to a usage error) that starts with
/// `magcal: error: ` and holds every `needle`, and nothing on stdout.
pub fn assert_refused((code, stdout, stderr): &(i32, String, String), needles: &[&str]) {
    assert_eq!(*code, 2, "{stderr}");
    assert!(stdout.is_empty(), "{stdout}");
    assert_eq!(error_lines(stderr).len(), 1, "{stderr}");
    assert!(stderr.starts_with("magcal: error: "), "{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "{n:?} not in {stderr}");
    }
}

/// The calibration at `cal` with `edit` applied to its JSON, written beside it as `name`.
pub fn edited(cal: &Path, name: &str, edit: impl FnOnce(&mut serde_json::Value)) -> PathBuf {
    let mut j: serde_json::Value = serde_json::from_slice(&fs::read(cal).unwrap()).unwrap();
    edit(&mut j);
    let path = cal.with_file_name(name);
    fs::write(&path, serde_json::to_vec_pretty(&j).unwrap()).unwrap();
    path
}

/// `magcal calibrate LOG ARGS --json`: the exit code, the JSON printed and stderr.
pub fn calibrate_json(
    log: &Path,
    args: &[&str],
) -> (Option<i32>, magcal_runner::log::calibration::CalibrationJson, String) {
    let out = magcal()
        .arg("calibrate")
        .arg(log)
        .args(args)
        .arg("--json")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    let json = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {stderr}"));
    (out.status.code(), json, stderr)
}

/// `magcal simulate scenarios/NAME.toml --design DESIGN --out OUT`: the scenario's path and
/// stderr.
pub fn simulate(name: &str, design: &str, out: &Path) -> (PathBuf, String) {
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../scenarios/{name}.toml"));
    let o = magcal()
        .arg("simulate")
        .arg(&scenario)
        .args(["--design", design, "--out"])
        .arg(out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{stderr}");
    (scenario, stderr)
}
