#!/usr/bin/env python3
"""The loop from plan to calibration: the design `magcal design` recommends, flown (simulated) and
calibrated by `magcal calibrate`, gives usable logs as often as design's check calibrated it; a
design that design calls FAILS gives logs that are not usable; and a usable log's heading is
within the budget in truth.

For each vehicle: `magcal design` names the design to fly (`recommended` in design_metrics.csv)
and its check share (`check_ok` of `check_trials`); then, for that design and for the vehicle's
failing design (where it has one), `magcal simulate --seed s` for s = 1..SEEDS writes a log and
`magcal calibrate LOG --magnitude R --scenario SCENARIO --json` (R the field's magnitude that
simulate prints; the scenario's box and field for the heading budget, as design judged the plan)
calibrates it: exit code, `usable`, the log's own check and the first reason, how many of the
nine estimates (psi1..3, S1..3, O1..3) lie outside their stated 99 % interval of the scenario's
sensor (`interval95` times t(0.995, dof) / its quantile; the scale factors are absolute at the
field's magnitude), the heading the log predicts it leaves (95th percentile over the box at every
heading, by the log's trials and by its standard errors) and the true one: the same percentile of
the log's calibration against the scenario's sensor, computed here independently of magcal (the
grid of docs/conventions.md "Heading budget": 5 x 5 rolls and pitches across the box, ends
included, 72 headings, [P1] eq. (2) with the tilt taken as known).

Bounds (the same as tests/it/loop_design_log.rs, which runs fewer seeds):
- the recommended design: the usable share of the logs within 3 standard errors of design's check
  share (of the 20 logs design flew and judged where its heading is above half the budget, else of
  its check trials), the standard error that of the difference of two binomial shares (check trials and
  logs) at their pooled share, the null "both shares are one p": with 200 of 200 check trials ok
  this asks at least 48 of 50 logs usable (47 gives z = 3.5); where both shares are 0 or 1 the
  difference and its standard error are 0, and the bound holds;
- a failing design: not usable in at least the lower 3-standard-error limit of a binomial of
  SEEDS logs refused with probability 0.9 ("most"): 39 of 50; and the usable share not above the
  design's check share by more than 3 pooled standard errors (a log's fit is one trial of its
  design, so its usable share cannot exceed the design's ok share).

Every seed is fixed, so the study is deterministic; it replaces results/loop/ whole (written beside
it, then renamed). Standard library only.

    cargo build --release --locked -p magcal-runner
    python3 scripts/loop.py [--jobs 2] [--seeds 50]
"""

import argparse
import csv
import io
import json
import math
import os
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from concurrent.futures import ThreadPoolExecutor

from student_t import normal_quantile, t_quantile

ROOT = pathlib.Path(__file__).resolve().parent.parent
MAGCAL = pathlib.Path(os.environ["MAGCAL_BIN"]) if os.environ.get("MAGCAL_BIN") else ROOT / "target" / "release" / "magcal"
OUT = ROOT / "results" / "loop"

# Each vehicle and the designs of it that `design` calls FAILS to fly beside the recommended one
# (none where every design works). The ship's grid and the vessel's 300-reading plan calibrate in
# every check trial but leave the heading beyond 2 degrees in more than 5 % of them: they fail the
# budget (the vessel's 1000-reading plan at the same attitudes works; no design of the ship does).
VEHICLES = [
    ("usv", ["random12", "plan300"]),
    ("ship", ["grid36", "random20"]),
    ("drone", []),
    ("plan300", []),
    ("glider", ["surface12"]),
    ("ground-vehicle", ["optimum12"]),
]
SEEDS = 50
Z = 3.0
REFUSED_P = 0.9
TIMEOUT_S = 600
MAGNITUDE = re.compile(r"calibrate with --magnitude ([0-9.eE+-]+)\)")

LOG_COLUMNS = [
    "scenario", "design", "role", "seed", "readings", "magnitude_nt", "exit_code", "usable",
    "identifiable", "log_check_ok", "log_check_trials", "outside99", "max_abs_z",
    "budget_deg", "predicted_trials_deg", "predicted_std_deg", "predicted_deg", "true_deg", "reason",
]
SUMMARY_COLUMNS = [
    "scenario", "design", "role", "verdict", "check_ok", "check_trials", "design_p95_deg", "logs", "usable",
    "exit_0", "exit_3", "usable_outside99", "usable_true_within", "refused_true_beyond", "predicted_covers",
    "median_predicted_deg", "median_true_deg", "z", "bound", "holds",
]


def pooled_z(x1, n1, x2, n2):
    """The difference x2/n2 - x1/n1 in standard errors of the difference of two binomial shares
    at their pooled share; 0 where both shares are 0 or both 1."""
    p = (x1 + x2) / (n1 + n2)
    se = math.sqrt(p * (1 - p) * (1 / n1 + 1 / n2))
    diff = x2 / n2 - x1 / n1
    return 0.0 if se == 0 else diff / se


def min_refused(n):
    """The fewest not-usable logs of n that 'most are refused' allows: the lower 3-standard-error
    limit of a binomial of n logs each refused with probability REFUSED_P."""
    return math.ceil(REFUSED_P * n - Z * math.sqrt(REFUSED_P * (1 - REFUSED_P) * n))


def min_usable(check_ok, check_trials, n):
    """The fewest usable logs of n within Z pooled standard errors of the check's share."""
    return min(k for k in range(n + 1) if abs(pooled_z(check_ok, check_trials, k, n)) <= Z)


def max_usable(check_ok, check_trials, n):
    """The most usable logs of n not above the check's share by more than Z pooled standard errors."""
    return max(k for k in range(n + 1) if pooled_z(check_ok, check_trials, k, n) <= Z)


def run(args):
    return subprocess.run([str(MAGCAL), *args], capture_output=True, text=True, timeout=TIMEOUT_S)


def design(scenario, work):
    """`magcal design`: the design metrics per design name."""
    out = work / f"design-{scenario}"
    r = run(["design", str(ROOT / "scenarios" / f"{scenario}.toml"), "--out", str(out), "--quiet",
             "--threads", "1"])
    if r.returncode != 0:
        raise RuntimeError(f"magcal design {scenario}: exit {r.returncode}: {r.stderr.strip()[:500]}")
    with open(out / "design_metrics.csv", newline="") as f:
        rows = {d["design"]: d for d in csv.DictReader(f)}
    revision = json.loads((out / "run.json").read_text()).get("git_revision", "unknown")
    return rows, revision


def truth(scenario):
    """The scenario's sensor: psi (deg), S, O (nT), nine numbers."""
    with open(ROOT / "scenarios" / f"{scenario}.toml", "rb") as f:
        s = tomllib.load(f)["sensor"]
    return [float(v) for v in s["psi_deg"] + s["scale"] + s["bias_nt"]]


def against_truth(scenario, j):
    """How many estimates lie outside their stated 99 % interval of the truth, and the largest
    error in standard errors; empty where the log states no interval."""
    iv = j.get("interval95")
    if iv is None:
        return "", ""
    noise = j.get("noise_estimate") or {}
    dof = noise.get("dof")
    given = noise.get("source") != "residuals" or not dof
    t99 = normal_quantile(0.995) if given else t_quantile(0.995, dof)
    estimate = j["psi_deg"] + j["scale"] + j["bias"]
    half95 = iv["psi_deg"] + iv["scale"] + iv["bias"]
    z = [abs(e - t) / (h / iv["quantile"]) for e, t, h in zip(estimate, truth(scenario), half95)]
    return sum(1 for v in z if v > t99), f"{max(z):.2f}"


def sensor_k(scenario):
    """The scenario's K = diag(S) N(psi) (docs/conventions.md "Sensor error model") and O, nT."""
    t = truth(scenario)
    p1, p2, p3 = (math.radians(v) for v in t[:3])
    n = [[math.cos(p2) * math.cos(p3), math.cos(p2) * math.sin(p3), math.sin(p2)],
         [0.0, math.cos(p1), math.sin(p1)],
         [0.0, 0.0, 1.0]]
    return [[t[3 + i] * v for v in n[i]] for i in range(3)], t[6:]


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def quantile(values, q):
    """numpy's default: linear between order statistics at (n - 1) q."""
    v = sorted(values)
    at = (len(v) - 1) * q
    lo = math.floor(at)
    return v[lo] if lo + 1 >= len(v) else v[lo] + (at - lo) * (v[lo + 1] - v[lo])


def true_heading_p95(scenario, j):
    """The 95th percentile of the heading error the log's calibration (j's P and bias) leaves over
    the budget's grid (j's tilts and inclination), readings made by the scenario's sensor."""
    b = j["heading_budget"]
    inc = math.radians(b["inclination_deg"])
    k, o = sensor_k(scenario)
    p, bias, r = j["p"], j["bias"], j["magnitude"]
    field = [math.cos(inc), -math.sin(inc), 0.0]

    def steps(lo, hi):
        return [lo] if lo == hi else [lo + (hi - lo) * i / 4 for i in range(5)]

    errors = []
    for roll in steps(*b["tilts"]["roll_deg"]):
        for pitch in steps(*b["tilts"]["pitch_deg"]):
            rr, pp = math.radians(roll), math.radians(pitch)
            rx = [[1, 0, 0], [0, math.cos(rr), math.sin(rr)], [0, -math.sin(rr), math.cos(rr)]]
            rz = [[math.cos(pp), math.sin(pp), 0], [-math.sin(pp), math.cos(pp), 0], [0, 0, 1]]
            tilt = matmul(rx, rz)
            for h in range(72):
                y = math.radians(5 * h - 180)
                ry = [[math.cos(y), 0, -math.sin(y)], [0, 1, 0], [math.sin(y), 0, math.cos(y)]]
                c = matmul(tilt, ry)
                body = [r * sum(c[i][m] * field[m] for m in range(3)) for i in range(3)]
                raw = [sum(k[i][m] * body[m] for m in range(3)) + o[i] for i in range(3)]
                cal = [sum(p[i][m] * (raw[m] - bias[m]) for m in range(3)) for i in range(3)]
                tx, tz = (sum(tilt[i][col] * body[i] for i in range(3)) for col in (0, 2))
                vx, vz = (sum(tilt[i][col] * cal[i] for i in range(3)) for col in (0, 2))
                errors.append(abs(math.degrees(math.atan2(tx * vz - tz * vx, tx * vx + tz * vz))))
    return quantile(errors, 0.95)


def one_log(scenario, name, role, seed, work):
    """Simulates and calibrates one log; its row."""
    log = work / f"{scenario}-{name}-{seed}.csv"
    r = run(["simulate", str(ROOT / "scenarios" / f"{scenario}.toml"), "--design", name, "--seed", str(seed),
             "--out", str(log)])
    m = MAGNITUDE.search(r.stderr)
    if r.returncode != 0 or m is None:
        raise RuntimeError(f"magcal simulate {scenario} {name} {seed}: exit {r.returncode}: {r.stderr.strip()[:500]}")
    magnitude = m.group(1)
    c = run(["calibrate", str(log), "--magnitude", magnitude, "--scenario",
             str(ROOT / "scenarios" / f"{scenario}.toml"), "--json"])
    if c.returncode not in (0, 3):
        raise RuntimeError(f"magcal calibrate {log}: exit {c.returncode}: {c.stderr.strip()[:500]}")
    j = json.loads(c.stdout)
    log.unlink()
    check = j.get("check") or {}
    outside, max_z = against_truth(scenario, j)
    b = j.get("heading_budget") or {}
    fmt = lambda v: "" if v is None else f"{v:.4f}"
    return dict(
        scenario=scenario, design=name, role=role, seed=seed, readings=j["samples"],
        magnitude_nt=f"{float(magnitude):.3f}", exit_code=c.returncode, usable=str(j["usable"]).lower(),
        identifiable=str(j["identifiable"]).lower(), log_check_ok=check.get("ok", ""),
        log_check_trials=check.get("trials", ""), outside99=outside, max_abs_z=max_z,
        budget_deg=fmt(b.get("budget_deg")), predicted_trials_deg=fmt(b.get("by_trials_deg")),
        predicted_std_deg=fmt(b.get("with_std_deg")), predicted_deg=fmt(b.get("predicted_deg")),
        true_deg=fmt(true_heading_p95(scenario, j)) if b else "",
        reason=(j["reasons"] or [""])[0][:160],
    )


def summarise(scenario, name, role, metrics, logs):
    d = metrics[name]
    ok, trials = int(d["check_ok"]), int(d["check_trials"])
    n = len(logs)
    usable = sum(1 for r in logs if r["usable"] == "true")
    # Against the logs design flew where it flew them (a design near the budget), else its check.
    said = (int(d["check_logs_usable"]), int(d["check_logs"])) if d.get("check_logs_usable") else (ok, trials)
    z = pooled_z(*said, usable, n)
    if role == "recommended":
        bound = f">= {min_usable(*said, n)} usable"
        holds = abs(z) <= Z
    else:
        most = min_refused(n)
        bound = f">= {most} not usable, <= {max_usable(*said, n)} usable"
        holds = n - usable >= most and z <= Z
    judged = [r for r in logs if r["true_deg"] != ""]
    median = lambda v: f"{quantile(v, 0.5):.3f}" if v else ""
    return dict(
        scenario=scenario, design=name, role=role, verdict="works" if d["works"] == "true" else "FAILS",
        check_ok=ok, check_trials=trials, design_p95_deg=d.get("check_budget_p95_deg", ""), logs=n, usable=usable,
        exit_0=sum(1 for r in logs if r["exit_code"] == 0), exit_3=sum(1 for r in logs if r["exit_code"] == 3),
        usable_outside99=sum(r["outside99"] for r in logs if r["usable"] == "true" and r["outside99"] != ""),
        usable_true_within=sum(1 for r in judged if r["usable"] == "true" and float(r["true_deg"]) <= float(r["budget_deg"])),
        refused_true_beyond=sum(1 for r in judged if r["usable"] != "true" and float(r["true_deg"]) > float(r["budget_deg"])),
        predicted_covers=sum(1 for r in judged if r["predicted_deg"] != "" and float(r["predicted_deg"]) >= float(r["true_deg"])),
        median_predicted_deg=median([float(r["predicted_deg"]) for r in judged if r["predicted_deg"] != ""]),
        median_true_deg=median([float(r["true_deg"]) for r in judged]),
        z=f"{z:+.2f}", bound=bound, holds=str(holds).lower(),
    )


def write_csv(rows, columns, path):
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    path.write_text(buf.getvalue())


def table(summary):
    lines = [
        "| scenario | design | design's verdict | check trials ok | design's heading p95 (deg) | usable logs | usable with the true heading within the budget | refused with it beyond | predicted >= true | median predicted / true (deg) | estimates of usable logs outside their 99 % interval | z | bound | holds |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        p95 = s["design_p95_deg"]
        p95 = f"{float(p95):.3f}" if p95 not in ("", None) else "-"
        lines.append(
            f"| `{s['scenario']}` | `{s['design']}` ({s['role']}) | {s['verdict']} | {s['check_ok']} / {s['check_trials']} | {p95} | "
            f"{s['usable']} / {s['logs']} | {s['usable_true_within']} / {s['usable']} | {s['refused_true_beyond']} / {s['logs'] - s['usable']} | "
            f"{s['predicted_covers']} / {s['logs']} | {s['median_predicted_deg']} / {s['median_true_deg']} | "
            f"{s['usable_outside99']} of {9 * s['usable']} | {s['z']} | {s['bound']} | {s['holds']} |")
    return lines


def readme(summary, logs, seconds, jobs, seeds, revision):
    lines = [
        "# The loop: what `design` recommends, flown and calibrated",
        "",
        "Written by `scripts/loop.py` (do not edit by hand). For each vehicle, `magcal design` names the",
        "design to fly and its check share; each design below is simulated with seeds 1 to "
        f"{seeds} (`magcal simulate",
        "--seed s`) and each log calibrated by `magcal calibrate LOG --magnitude R --scenario SCENARIO",
        "--json`, R the field's magnitude that simulate prints. The bounds, and how the true heading is",
        "computed, are in the script's documentation.",
        "",
        "```sh",
        "cargo build --release --locked -p magcal-runner",
        f"python3 scripts/loop.py --jobs {jobs} --seeds {seeds}",
        "```",
        "",
        f"magcal of git revision `{revision}`; {len(logs)} logs in {seconds / 60:.1f} min with {jobs} processes.",
        "",
    ]
    lines += table(summary)
    refused = [r for r in logs if r["role"] == "recommended" and r["usable"] != "true"]
    accepted = [r for r in logs if r["role"] == "fails" and r["usable"] == "true"]
    lines += ["", "Logs of a recommended design that are not usable:", ""]
    lines += [f"- `{r['scenario']}` `{r['design']}` seed {r['seed']}: log check {r['log_check_ok']} / "
              f"{r['log_check_trials']}; {r['reason']}" for r in refused] or ["None."]
    lines += ["", "Logs of a failing design that are usable:", ""]
    lines += [f"- `{r['scenario']}` `{r['design']}` seed {r['seed']}: log check {r['log_check_ok']} / "
              f"{r['log_check_trials']}; {r['outside99']} of 9 estimates outside their 99 % interval of the "
              f"truth, the farthest {r['max_abs_z']} standard errors off" for r in accepted] or ["None."]
    lines += [
        "",
        "## Files",
        "",
        "- `logs.csv`: one row per log: " + ", ".join(f"`{c}`" for c in LOG_COLUMNS) + ". `outside99` counts",
        "  the estimates (of psi1..3, S1..3, O1..3) whose stated 99 % interval misses the scenario's sensor",
        "  and `max_abs_z` is the largest error in standard errors (both empty where the log states no",
        "  interval); `reason` is the first of calibrate's `reasons` (empty when usable), cut at 160",
        "  characters",
        "- `summary.csv`: one row per design: " + ", ".join(f"`{c}`" for c in SUMMARY_COLUMNS) + ".",
        "  `usable_outside99` sums `outside99` over the usable logs, of 9 estimates each;",
        "  `usable_true_within` counts the usable logs whose true heading is within the budget,",
        "  `refused_true_beyond` the refused ones whose true heading is beyond it, `predicted_covers` the",
        "  logs whose predicted heading is at least the true one",
        "",
    ]
    return "\n".join(lines)


def publish(files):
    """Writes the result set beside OUT and renames it into place, replacing the old one whole."""
    OUT.parent.mkdir(parents=True, exist_ok=True)
    staged = pathlib.Path(tempfile.mkdtemp(prefix=".loop-", dir=OUT.parent))
    try:
        for name, write in files.items():
            write(staged / name)
        os.chmod(staged, 0o755)
        old = None
        if OUT.exists():
            old = OUT.with_name(f".loop-old-{os.getpid()}")
            OUT.rename(old)
        staged.rename(OUT)
        if old is not None:
            shutil.rmtree(old)
    except BaseException:
        shutil.rmtree(staged, ignore_errors=True)
        raise


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--jobs", type=int, default=2, help="magcal processes at a time (default 2)")
    ap.add_argument("--seeds", type=int, default=SEEDS, help=f"logs per design (default {SEEDS})")
    args = ap.parse_args()
    if args.jobs < 1 or args.seeds < 1:
        sys.exit("loop.py: --jobs and --seeds must be at least 1")
    if not MAGCAL.is_file():
        sys.exit(f"loop.py: {MAGCAL} missing: run `cargo build --release --locked -p magcal-runner`")
    started = time.monotonic()
    summary, logs, revisions = [], [], set()
    with tempfile.TemporaryDirectory(prefix="loop-") as work:
        work = pathlib.Path(work)
        for scenario, failing in VEHICLES:
            metrics, revision = design(scenario, work)
            revisions.add(revision)
            recommended = [n for n, d in metrics.items() if d["recommended"] == "true"]
            for f in failing:
                if metrics[f]["works"] == "true":
                    raise RuntimeError(f"{scenario}: {f} works; the loop needs a design that fails")
            jobs = [(n, "recommended") for n in recommended] + [(f, "fails") for f in failing]
            for name, role in jobs:
                with ThreadPoolExecutor(max_workers=args.jobs) as pool:
                    rows = list(pool.map(lambda s: one_log(scenario, name, role, s, work),
                                         range(1, args.seeds + 1)))
                logs += rows
                summary.append(summarise(scenario, name, role, metrics, rows))
                s = summary[-1]
                print(f"{scenario} {name} ({role}): check {s['check_ok']}/{s['check_trials']}, usable "
                      f"{s['usable']}/{s['logs']}, z {s['z']}, holds {s['holds']}; "
                      f"{time.monotonic() - started:.0f} s", file=sys.stderr)
    seconds = time.monotonic() - started
    revision = ", ".join(sorted(revisions))
    publish({
        "logs.csv": lambda p: write_csv(logs, LOG_COLUMNS, p),
        "summary.csv": lambda p: write_csv(summary, SUMMARY_COLUMNS, p),
        "README.md": lambda p: p.write_text(readme(summary, logs, seconds, args.jobs, args.seeds, revision)),
    })
    print("\n".join(table(summary)))
    print(f"{len(logs)} logs in {seconds / 60:.1f} min; written to {OUT}")
    if not all(s["holds"] == "true" for s in summary):
        sys.exit(1)


if __name__ == "__main__":
    main()
