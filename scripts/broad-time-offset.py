#!/usr/bin/env python3
"""The time offset between a BROAD trial's magnetometer and its motion capture, measured with
magcal's own tools: the readings are shifted by k rows against the attitudes (k > 0: each
attitude meets the reading k rows later), `magcal evaluate --raw` aligns each shifted log with
its attitudes, and its heading and direction rms (the angle between the raw field in the capture room's
frame and the fitted field, docs/conventions.md "Heading against a reference attitude") is
printed per k. The k of least rms is the offset in rows (3.5 ms each at 285.7 Hz). A heading
error of a fast-turning trial is dominated by such an offset: at 300 degrees a second, 17.5 ms is
5 degrees. Standard library only; needs target/release/magcal.

Usage: scripts/broad-time-offset.py ../shared/data/broad/30_disturbed_stationary_magnet_C.csv [...]
"""
import csv
import os
import re
import subprocess
import sys
import tempfile

MAGCAL = os.environ.get("MAGCAL_BIN") or os.path.join(os.path.dirname(__file__), "..", "target", "release", "magcal")
SHIFTS = [-10, -5, -3, 0, 3, 4, 5, 6, 7, 10]


def rms_errors(path):
    """Heading rms and direction rms, degrees, of the raw readings against the attitudes."""
    out = subprocess.run(
        [MAGCAL, "evaluate", "--raw", path, "--columns", "mx,my,mz", "--quaternion", "qw,qx,qy,qz",
         "--attitude-frame", "enu"],
        capture_output=True, text=True, check=True).stdout
    m = re.search(r"^uncalibrated +([0-9.]+) +[0-9.]+ +[0-9.]+ +([0-9.]+)$", out, re.M)
    if not m:
        sys.exit(f"no error rms in the output of evaluate for {path}:\n{out}")
    return float(m.group(1)), float(m.group(2))


def shifted(rows, k, path):
    # Row i keeps its attitude and takes the reading of row i + k; rows without one are dropped.
    n = len(rows)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["mx", "my", "mz", "qw", "qx", "qy", "qz"])
        for i, r in enumerate(rows):
            j = i + k
            if 0 <= j < n and r["qw"] != "":
                s = rows[j]
                w.writerow([s["mx"], s["my"], s["mz"], r["qw"], r["qx"], r["qy"], r["qz"]])


def main():
    for trial in sys.argv[1:]:
        with open(trial, newline="") as f:
            rows = list(csv.DictReader(f))
        with tempfile.TemporaryDirectory() as tmp:
            found = []
            for k in SHIFTS:
                path = os.path.join(tmp, f"shift{k}.csv")
                shifted(rows, k, path)
                found.append((k, *rms_errors(path)))
        best = min(found, key=lambda x: x[2])
        print(os.path.basename(trial))
        for k, heading, direction in found:
            least = "  <- least" if k == best[0] else ""
            print(f"  shift {k:+3d} rows: heading rms {heading:.3f}, direction rms {direction:.3f} deg{least}")


if __name__ == "__main__":
    main()
