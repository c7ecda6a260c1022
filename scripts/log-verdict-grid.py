#!/usr/bin/env python3
"""The grid study for logs: each simulated log's verdict (`usable`: among others, at least 95 % of
its check trials at its own readings calibrate) against the truth it was simulated from: whether
every estimate lies within its stated 99 % interval of the scenario's sensor.

Grid (as scripts/verdict-grid.py): roll limit x pitch limit in {0, 5, 15, 30, 45} deg (symmetric,
yaw any), latitude in {0, 20, 40, 60, 80} deg (longitude 10 E, sea level, WMM2025, 2026.5), sigma
in {1, 10, 30, 100, 300} nT; the [P1] IV.A sensor and the nominal one (psi 0, S 1, O 0) alternate
in a checkerboard over the grid's indices. One log per point, of one design: where the sum of the
indices is divisible by 3 a `plan` of 100, 200 or 300 readings (cycling with the point's index),
else a `random` design of 12, 40 or 150 attitudes (cycling likewise); where the box has no plan
(`magcal` says so) a random design of as many readings instead. A limit of 0 is written as
+-0.01 deg (a scenario's range needs its minimum below its maximum).

Per point: the scenario (its design, seed 20270000 + index), `magcal simulate --seed` the same
number, `magcal calibrate LOG --json --magnitude R` with R the field magnitude simulate prints, so
that the scale factors are absolute. The stated 99 % interval of each of psi1..3, S1..3, O1..3
is the JSON's `interval95` half-width times t(0.995, dof) / `interval95.quantile`, where dof is
the residual degrees of freedom (`noise_estimate.dof`) and t Student's quantile, computed here
from the regularised incomplete beta function (`quantile` itself is checked against t(0.975,
dof) to 1e-6, or against the normal 1.96 where the noise is given).

Every seed is fixed, so the study is deterministic; it replaces results/log-verdict-grid/ whole
(written beside it, then renamed). Standard library only.

    cargo build --release --locked -p magcal-runner
    python3 scripts/log-verdict-grid.py [--jobs 2]
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
from concurrent.futures import ThreadPoolExecutor

from student_t import normal_quantile, t_quantile

ROOT = pathlib.Path(__file__).resolve().parent.parent
MAGCAL = pathlib.Path(os.environ["MAGCAL_BIN"]) if os.environ.get("MAGCAL_BIN") else ROOT / "target" / "release" / "magcal"
OUT = ROOT / "results" / "log-verdict-grid"

LIMITS_DEG = [0, 5, 15, 30, 45]
LATS_DEG = [0, 20, 40, 60, 80]
SIGMAS_NT = [1, 10, 30, 100, 300]
ZERO_LIMIT_DEG = 0.01
LON_DEG = 10.0
YEAR = 2026.5
PLAN_READINGS = [100, 200, 300]
RANDOM_M = [12, 40, 150]
SEED_BASE = 20270000
LEVEL = 0.99
BAR = 0.95
TIMEOUT_S = 600
MAGNITUDE = re.compile(r"calibrate with --magnitude ([0-9.eE+-]+)\)")
NO_PLAN = (
    "no design in this attitude box identifies the linear model",
    "no design in it identifies the 9 unknowns of the linear model",
)

SENSORS = {
    "paper": ([1.5, 0.8, 1.4], [1.3, 0.7, 1.2], [3000.0, -6000.0, 5000.0]),
    "nominal": ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]),
}
PARAMETERS = ["psi1", "psi2", "psi3", "s1", "s2", "s3", "o1", "o2", "o3"]

LOG_COLUMNS = [
    "index", "roll_deg", "pitch_deg", "lat_deg", "sigma_nt", "sensor", "design", "readings", "seed",
    "magnitude_nt", "exit_code", "usable", "identifiable", "status", "check_ok", "check_trials",
    "noise_nt", "dof", "quantile95", "t99", "has_interval",
] + [f"{p}_{c}" for p in PARAMETERS for c in ("estimate", "truth", "half99", "inside")] + ["reason"]
SUMMARY_COLUMNS = ["group", "subset", "logs", "parameter", "inside", "share", "se"]


# ---- the grid ------------------------------------------------------------------------------

def points():
    """Every grid point in a fixed order, with its index (its seed), sensor and design."""
    out = []
    for ir, roll in enumerate(LIMITS_DEG):
        for ip, pitch in enumerate(LIMITS_DEG):
            for il, lat in enumerate(LATS_DEG):
                for isg, sigma in enumerate(SIGMAS_NT):
                    i = len(out)
                    s = ir + ip + il + isg
                    kind = "plan" if s % 3 == 0 else "random"
                    readings = (PLAN_READINGS if kind == "plan" else RANDOM_M)[i % 3]
                    out.append(dict(index=i, roll=roll, pitch=pitch, lat=lat, sigma=sigma,
                                    sensor="paper" if s % 2 == 0 else "nominal", kind=kind, readings=readings))
    return out


def name(p):
    return f"loggrid-r{p['roll']:02d}-p{p['pitch']:02d}-lat{p['lat']:02d}-s{p['sigma']:03d}-{p['sensor']}"


def limit(deg):
    half = deg if deg > 0 else ZERO_LIMIT_DEG
    return f"[{-half:.2f}, {half:.2f}]"


def scenario(p, kind, readings):
    psi, scale, bias = SENSORS[p["sensor"]]
    fmt = lambda v: "[" + ", ".join(f"{x:.1f}" for x in v) + "]"
    size = f"readings = {readings}" if kind == "plan" else f"m = {readings}"
    return f"""schema = 1
name = "{name(p)}"
description = "log verdict grid point {p['index']}"
seed = {SEED_BASE + p['index']}
trials = 1
sigma_nt = {float(p['sigma']):.1f}

[field]
model = "WMM2025"
lat_deg = {float(p['lat']):.1f}
lon_deg = {LON_DEG:.1f}
alt_m = 0.0
year = {YEAR}

[sensor]
psi_deg = {fmt(psi)}
scale = {fmt(scale)}
bias_nt = {fmt(bias)}

[attitude_box]
roll_deg = {limit(p['roll'])}
yaw_deg = [-180.0, 180.0]
pitch_deg = {limit(p['pitch'])}

[[design]]
name = "log"
kind = "{kind}"
{size}
"""


def magcal(*args):
    return subprocess.run([str(MAGCAL), *map(str, args)], capture_output=True, text=True, timeout=TIMEOUT_S)


def run_point(p, work):
    """Simulates and calibrates the point's log; its row."""
    scen = work / f"{name(p)}.toml"
    log = work / f"{name(p)}.csv"
    seed = SEED_BASE + p["index"]
    kind = p["kind"]
    scen.write_text(scenario(p, kind, p["readings"]))
    r = magcal("simulate", scen, "--design", "log", "--seed", seed, "--out", log)
    if kind == "plan" and r.returncode == 2 and any(m in r.stderr for m in NO_PLAN):
        kind = "random"
        scen.write_text(scenario(p, kind, p["readings"]))
        r = magcal("simulate", scen, "--design", "log", "--seed", seed, "--out", log)
    m = MAGNITUDE.search(r.stderr)
    if r.returncode != 0 or m is None:
        raise RuntimeError(f"{scen}: simulate exited {r.returncode}: {r.stderr.strip()[:500]}")
    magnitude = m.group(1)
    c = magcal("calibrate", log, "--json", "--magnitude", magnitude)
    if c.returncode not in (0, 3):
        raise RuntimeError(f"{log}: calibrate exited {c.returncode}: {c.stderr.strip()[:500]}")
    j = json.loads(c.stdout)
    scen.unlink()
    log.unlink()
    return row(p, kind, seed, magnitude, c.returncode, j)


def row(p, kind, seed, magnitude, code, j):
    psi, scale, bias = SENSORS[p["sensor"]]
    truth = psi + scale + bias
    estimate = j["psi_deg"] + j["scale"] + j["bias"]
    iv = j.get("interval95")
    noise = j.get("noise_estimate") or {}
    dof = noise.get("dof")
    t99 = None
    if iv is not None:
        if noise.get("source") == "residuals" and dof:
            t95, t99 = t_quantile(0.975, dof), t_quantile(0.995, dof)
        else:
            t95, t99 = normal_quantile(0.975), normal_quantile(0.995)
        if abs(iv["quantile"] - t95) > 1e-6 * t95:
            raise RuntimeError(f"point {p['index']}: interval95.quantile {iv['quantile']} is not t(0.975, {dof}) = {t95}")
    half95 = (iv["psi_deg"] + iv["scale"] + iv["bias"]) if iv is not None else [None] * 9
    check = j.get("check") or {}
    out = dict(
        index=p["index"], roll_deg=p["roll"], pitch_deg=p["pitch"], lat_deg=p["lat"], sigma_nt=p["sigma"],
        sensor=p["sensor"], design=kind, readings=j["samples"], seed=seed, magnitude_nt=f"{float(magnitude):.3f}",
        exit_code=code, usable=str(j["usable"]).lower(), identifiable=str(j["identifiable"]).lower(),
        status=j["status"], check_ok=check.get("ok", ""), check_trials=check.get("trials", ""),
        noise_nt=g(j.get("noise")), dof=dof if dof is not None else "",
        quantile95=g(iv["quantile"]) if iv is not None else "", t99=g(t99),
        has_interval=str(iv is not None).lower(), reason=(j["reasons"] or [""])[0][:160],
    )
    for k, name_ in enumerate(PARAMETERS):
        half99 = None if half95[k] is None else half95[k] * t99 / iv["quantile"]
        inside = "" if half99 is None else str(abs(estimate[k] - truth[k]) <= half99).lower()
        out[f"{name_}_estimate"] = g(estimate[k])
        out[f"{name_}_truth"] = g(truth[k])
        out[f"{name_}_half99"] = g(half99)
        out[f"{name_}_inside"] = inside
    return out


def g(x):
    return "" if x is None else f"{x:.10g}"


# ---- summary -------------------------------------------------------------------------------

def share_rows(group, subset, logs):
    out = []
    for name_ in PARAMETERS:
        n = len(logs)
        inside = sum(1 for r in logs if r[f"{name_}_inside"] == "true")
        share = inside / n if n else math.nan
        se = math.sqrt(share * (1 - share) / n) if n else math.nan
        out.append(dict(group=group, subset=subset, logs=n, parameter=name_, inside=inside,
                        share=f"{share:.4f}", se=f"{se:.4f}"))
    return out


def groups(rows):
    """The logs judged: usable ones, and not-usable ones that still state intervals."""
    usable = [r for r in rows if r["usable"] == "true"]
    refused = [r for r in rows if r["usable"] != "true" and r["has_interval"] == "true"]
    return usable, refused


def summary(rows):
    usable, refused = groups(rows)
    out = []
    for group, logs in (("usable", usable), ("not_usable_with_intervals", refused)):
        out += share_rows(group, "all", logs)
        for sigma in SIGMAS_NT:
            out += share_rows(group, f"sigma_nt={sigma}", [r for r in logs if r["sigma_nt"] == sigma])
        for kind in ("plan", "random"):
            out += share_rows(group, f"design={kind}", [r for r in logs if r["design"] == kind])
        for sensor in SENSORS:
            out += share_rows(group, f"sensor={sensor}", [r for r in logs if r["sensor"] == sensor])
        for m in sorted({r["readings"] for r in rows}):
            out += share_rows(group, f"readings={m}", [r for r in logs if r["readings"] == m])
    return out


def write_csv(rows, columns, path):
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    path.write_text(buf.getvalue())


def table(rows, summ, by_readings=False):
    usable, refused = groups(rows)

    def line(group, subset):
        shares = [s for s in summ if s["group"] == group and s["subset"] == subset]
        return " | ".join("-" if s["logs"] == 0 else f"{float(s['share']):.3f}" for s in shares)

    out = ["| logs | n | " + " | ".join(PARAMETERS) + " |", "|---|---|" + "---|" * len(PARAMETERS)]
    out.append(f"| usable | {len(usable)} | {line('usable', 'all')} |")
    if by_readings:
        for m in sorted({r["readings"] for r in rows}):
            n = sum(1 for r in usable if r["readings"] == m)
            out.append(f"| usable, {m} readings | {n} | {line('usable', f'readings={m}')} |")
    out.append(f"| not usable, with intervals | {len(refused)} | {line('not_usable_with_intervals', 'all')} |")
    return out


def below_bar(summ):
    """Cells of usable logs whose share inside lies below the bar."""
    return [s for s in summ if s["group"] == "usable" and int(s["logs"]) > 0 and float(s["share"]) < BAR]


def readme(rows, summ, seconds, jobs, revision):
    usable, refused = groups(rows)
    n = len(rows)
    no_interval = sum(1 for r in rows if r["usable"] != "true" and r["has_interval"] != "true")
    fell_back = sum(1 for r, p in zip(rows, points()) if p["kind"] == "plan" and r["design"] == "random")
    se_bar = math.sqrt(LEVEL * (1 - LEVEL) / max(len(usable), 1))
    lines = [
        "# Does the log verdict hold? Usable logs against their stated intervals",
        "",
        "Written by `scripts/log-verdict-grid.py` (do not edit by hand). One simulated log per grid point,",
        "calibrated by `magcal calibrate --json --magnitude R`; for each of the nine parameters, whether the",
        "estimate lies within its stated 99 % interval of the sensor the log was simulated from.",
        "",
        "```sh",
        "cargo build --release --locked -p magcal-runner",
        f"python3 scripts/log-verdict-grid.py --jobs {jobs}",
        "```",
        "",
        f"magcal of git revision `{revision}`; {n} logs in {seconds / 60:.1f} min with {jobs} processes.",
        "",
        "## Grid",
        "",
        f"- roll limit x pitch limit: {{{', '.join(map(str, LIMITS_DEG))}}} deg each, symmetric, yaw any; a limit of",
        f"  0 is written as +-{ZERO_LIMIT_DEG} deg",
        f"- latitude {{{', '.join(map(str, LATS_DEG))}}} deg, longitude {LON_DEG:g} E, sea level, WMM2025, {YEAR}",
        f"- sigma {{{', '.join(map(str, SIGMAS_NT))}}} nT",
        "- sensor: the [P1] IV.A sensor where the sum of the grid indices is even, the nominal one where odd",
        f"- design: a `plan` of {', '.join(map(str, PLAN_READINGS))} readings where the sum of the indices is divisible",
        f"  by 3, else a `random` design of {', '.join(map(str, RANDOM_M))} attitudes, the size cycling with the",
        f"  point's index; {fell_back} points whose box has no plan take a random design of as many readings",
        f"- seeds: {SEED_BASE} + the point's index (scenario and simulate's noise)",
        "- 99 % interval: `interval95` times t(0.995, dof) / `quantile`, t Student's quantile of the",
        "  residual degrees of freedom (each log's `quantile` equals t(0.975, dof) to 1e-6)",
        "",
        "## Result",
        "",
        f"- logs: {n}; usable (exit 0): {len(usable)}; not usable (exit 3): {n - len(usable)}, of which "
        f"{len(refused)} state intervals and {no_interval} do not",
        "",
        "Share of logs whose estimate lies within its stated 99 % interval of the truth:",
        "",
    ]
    lines += table(rows, summ, by_readings=True)
    low = below_bar(summ)
    lines += [
        "",
        f"The bar: at least {BAR:.0%} of usable logs per parameter. At the nominal {LEVEL:.0%} a share over the "
        f"{len(usable)} usable logs has a standard error of {100 * se_bar:.2f} points.",
        "",
        "Cells of usable logs below the bar (all, per sigma, per design, per sensor, per readings):",
        "",
    ]
    lines += [f"- {s['subset']}, {s['parameter']}: {s['inside']} of {s['logs']} ({s['share']})" for s in low] or ["None."]
    misses = [r for r in usable if any(r[f"{q}_inside"] == "false" for q in PARAMETERS)]
    lines += ["", f"Usable logs with at least one estimate outside its 99 % interval: {len(misses)}", ""]
    if misses:
        lines += ["| index | roll | pitch | lat | sigma | sensor | design | readings | noise estimated (dof) | outside: error vs 99 % half-width |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for r in misses:
            outside = ", ".join(
                f"{q} ({float(r[f'{q}_estimate']) - float(r[f'{q}_truth']):+.3g} vs +-{float(r[f'{q}_half99']):.3g})"
                for q in PARAMETERS if r[f"{q}_inside"] == "false")
            lines.append(f"| {r['index']} | {r['roll_deg']} | {r['pitch_deg']} | {r['lat_deg']} | {r['sigma_nt']} | "
                         f"{r['sensor']} | {r['design']} | {r['readings']} | {float(r['noise_nt']):.3g} ({r['dof']}) | {outside} |")
    lines += [
        "",
        "## Files",
        "",
        "- `logs.csv`: one row per log: the point, the design, calibrate's exit code, `usable`, `identifiable`,",
        "  its status and check, the noise, degrees of freedom and quantiles, and per parameter the estimate,",
        "  the truth, the 99 % half-width and whether the truth lies inside; `reason` is the first of",
        "  calibrate's `reasons`, cut at 160 characters",
        "- `summary.csv`: per group (usable; not usable with intervals), subset (all, per sigma, per design,",
        "  per sensor, per readings) and parameter: logs, inside, share, its binomial standard error",
        "",
    ]
    return "\n".join(lines)


def publish(files):
    """Writes the result set beside OUT and renames it into place, replacing the old one whole."""
    OUT.parent.mkdir(parents=True, exist_ok=True)
    staged = pathlib.Path(tempfile.mkdtemp(prefix=".log-verdict-grid-", dir=OUT.parent))
    try:
        for name_, write in files.items():
            write(staged / name_)
        os.chmod(staged, 0o755)
        old = None
        if OUT.exists():
            old = OUT.with_name(f".log-verdict-grid-old-{os.getpid()}")
            OUT.rename(old)
        staged.rename(OUT)
        if old is not None:
            shutil.rmtree(old)
    except BaseException:
        shutil.rmtree(staged, ignore_errors=True)
        raise


def revision_of(work):
    """The git revision magcal was built from, as its run.json records it (`magcal design` of the
    first point)."""
    p = points()[0]
    scen = work / "revision.toml"
    scen.write_text(scenario(p, "random", RANDOM_M[0]))
    r = magcal("design", scen, "--out", work / "revision", "--quiet", "--threads", "1")
    if r.returncode != 0:
        return "unknown"
    return json.loads((work / "revision" / "run.json").read_text()).get("git_revision", "unknown")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--jobs", type=int, default=2, help="magcal processes at a time (default 2)")
    ap.add_argument("--limit", type=int, default=None, help="only the first N points (a trial run)")
    args = ap.parse_args()
    if args.jobs < 1:
        sys.exit("log-verdict-grid.py: --jobs must be at least 1")
    if not MAGCAL.is_file():
        sys.exit(f"log-verdict-grid.py: {MAGCAL} missing: run `cargo build --release --locked -p magcal-runner`")
    grid = points()[: args.limit]
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="log-verdict-grid-") as work:
        work = pathlib.Path(work)
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            futures = [pool.submit(run_point, p, work) for p in grid]
            rows = []
            for i, f in enumerate(futures):
                rows.append(f.result())
                if (i + 1) % 50 == 0:
                    print(f"{i + 1}/{len(grid)} logs, {time.monotonic() - started:.0f} s", file=sys.stderr)
        seconds = time.monotonic() - started
        revision = revision_of(work)
    summ = summary(rows)
    publish({
        "logs.csv": lambda p: write_csv(rows, LOG_COLUMNS, p),
        "summary.csv": lambda p: write_csv(summ, SUMMARY_COLUMNS, p),
        "README.md": lambda p: p.write_text(readme(rows, summ, seconds, args.jobs, revision)),
    })
    print("\n".join(table(rows, summ)))
    print(f"{len(rows)} logs in {seconds / 60:.1f} min; written to {OUT}")


if __name__ == "__main__":
    main()
