#!/usr/bin/env python3
"""The heading budget on every shipped real log: what `magcal calibrate` predicts the calibration
leaves (95th percentile of the heading error over level headings, by the log's trials and with
the standard errors its held-out fits allow), whether it is usable, and why not.

The truths are elsewhere: BROAD's, with a sensor imposed on the trials' movement rows, from
`cargo run --release -p magcal-core --example broad_heading` (the estimate against the trial's
own calibration); the synthetic flights', from the sensor they were written with
(data/synthetic/README.md), here.

    cargo build --release --locked -p magcal-runner
    python3 scripts/budget-real.py            # prints a markdown table

Reads ../shared/data/ (skips what is absent). Standard library only.
"""

import json
import math
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
MAGCAL = pathlib.Path(os.environ["MAGCAL_BIN"]) if os.environ.get("MAGCAL_BIN") else ROOT / "target" / "release" / "magcal"
DATA = ROOT.parent / "shared" / "data"
BROAD = ["--columns", "mx,my,mz", "--quaternion", "qw,qx,qy,qz", "--attitude-frame", "enu", "--units", "uT",
         "--time", "t_s"]

# (label, log, flags)
LOGS = [
    ("BROAD 02, movement rows", DATA / "broad/02_undisturbed_slow_rotation_B.csv", BROAD + ["--where", "movement=1"]),
    ("BROAD 02, every row", DATA / "broad/02_undisturbed_slow_rotation_B.csv", BROAD),
    ("BROAD 05, movement rows", DATA / "broad/05_undisturbed_slow_rotation_with_breaks_B.csv", BROAD + ["--where", "movement=1"]),
    ("BROAD 10, movement rows", DATA / "broad/10_undisturbed_slow_translation_A.csv", BROAD + ["--where", "movement=1"]),
    ("BROAD 10, 50-90 s, vector, magnitude 44.1", DATA / "broad/10_undisturbed_slow_translation_A.csv",
     BROAD[:6] + ["--time", "t_s", "--where", "movement=1", "--fit", "vector", "--magnitude", "44.1", "--from", "50", "--to", "90"]),
    ("BROAD 30, movement rows (magnet in the room)", DATA / "broad/30_disturbed_stationary_magnet_C.csv", BROAD + ["--where", "movement=1"]),
    ("BROAD 33, 99-169 s (after the magnet)", DATA / "broad/33_disturbed_attached_magnet_2cm.csv", BROAD + ["--from", "99", "--to", "168.973"]),
    ("ck-explorer (handheld)", DATA / "ck-explorer/acc_mag_log.csv", ["--units", "G"]),
    ("hamagure set 1", DATA / "hamagure/data-set_1.csv", ["--columns", "x,y,z", "--units", "G"]),
    ("hamagure set 1, --reject 4", DATA / "hamagure/data-set_1.csv", ["--columns", "x,y,z", "--units", "G", "--reject", "4"]),
    ("hamagure set 2 (restricted tilt)", DATA / "hamagure/data-set_2.csv", ["--columns", "x,y,z", "--units", "G"]),
    ("PX4 esc_status_log", DATA / "px4/esc_status_log.ulg", []),
    ("PX4 quadrotor_local, compass 0", DATA / "px4/quadrotor_local.ulg", ["--compass", "0"]),
    ("synthetic ArduPilot flight, vector-diagonal, motor", ROOT / "data/synthetic/flight.bin", ["--fit", "vector-diagonal", "--motor", "current"]),
]

# The synthetic flights' compass (data/synthetic/README.md): bias in mGauss.
SYNTHETIC_BIAS = [2.5, -1.2, 4.0]


def row(label, log, flags):
    if not log.is_file():
        return f"| {label} | (absent) | | | | |"
    r = subprocess.run([str(MAGCAL), "calibrate", str(log), *flags, "--json"], capture_output=True, text=True)
    if r.returncode not in (0, 3):
        return f"| {label} | exit {r.returncode}: {r.stderr.strip()[:80]} | | | | |"
    j = json.loads(r.stdout)
    if "heading_budget" not in j:
        why = "; ".join(j.get("reasons", []))[:120]
        return f"| {label} | no calibration | | | 3 | {why} |"
    b = j["heading_budget"] or {}
    trials = b.get("by_trials_deg")
    std = b.get("with_std_deg")
    h = j.get("held_out") or {}
    widened = " (widened)" if h.get("widened") else ""
    truth = ""
    if "synthetic" in label:
        # The estimate's bias against the flight's compass, across the horizontal field.
        err = math.dist(j["bias"], SYNTHETIC_BIAS)
        truth = f"; bias {err:.3f} mG from the truth"
    reasons = "; ".join(x.split(":")[0] for x in j["reasons"]) or "usable"
    fmt = lambda v: "-" if v is None else f"{v:.2f}"
    return (f"| {label} | {fmt(trials)} / {fmt(std)}{widened} | {b.get('inclination_deg', float('nan')):.1f} "
            f"({b.get('field', '')[:28]}) | {'yes' if h.get('evidence') else 'no'} | {r.returncode} | {reasons}{truth} |")


def main():
    if not MAGCAL.is_file():
        sys.exit(f"budget-real.py: {MAGCAL} missing: run `cargo build --release --locked -p magcal-runner`")
    print("| log | heading p95, deg: by trials / with the standard errors | inclination, deg (from) | held-out evidence | exit | verdict |")
    print("|---|---|---|---|---|---|")
    for label, log, flags in LOGS:
        print(row(label, log, flags), flush=True)


if __name__ == "__main__":
    main()
