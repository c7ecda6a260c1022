#!/usr/bin/env python3
"""Regression check of a committed replay set (results/replay-*/): the files must still have the
SHA-256 its manifest records, and replaying again with the manifest's command (into a temporary
directory) must give the same CSV files: the same rows and columns, numbers within 1e-9 relative
(replay is deterministic; the margin covers another CPU's rounding). Exit 1 when something moved,
2 when the set is damaged or the replay fails. Standard library only.

Usage: scripts/check-replay.py results/replay-handheld-02 [...]
       scripts/check-replay.py --against FRESH results/replay-handheld-02
With --against, the set is compared with FRESH, a replay already made with its command (as
scripts/replay-broad.sh makes one), instead of replaying again.
"""
import csv
import hashlib
import json
import os
import subprocess
import sys
import tempfile

MAGCAL = os.environ.get("MAGCAL_BIN") or os.path.join(os.path.dirname(__file__), "..", "target", "release", "magcal")


def same(a, b):
    if a == b:
        return True
    try:
        x, y = float(a), float(b)
    except ValueError:
        return False
    return abs(x - y) <= 1e-9 * max(abs(x), abs(y))


def check(directory, against=None):
    with open(os.path.join(directory, "manifest.json"), "rb") as f:
        manifest = json.loads(f.read())
    if manifest.get("kind") != "replay":
        print(f"{directory}: not a replay set", file=sys.stderr)
        return 2
    for name, digest in manifest["file_sha256"].items():
        with open(os.path.join(directory, name), "rb") as f:
            if hashlib.sha256(f.read()).hexdigest() != digest:
                print(f"{directory}/{name}: edited since it was written (SHA-256 differs)", file=sys.stderr)
                return 2
    with tempfile.TemporaryDirectory() as tmp:
        if against is not None:
            out = against
        else:
            command = list(manifest["command"][1:])
            out = os.path.join(tmp, "again")
            i = command.index("--out")
            command[i + 1] = out
            if "--quiet" not in command:
                command.append("--quiet")
            done = subprocess.run([MAGCAL] + command, capture_output=True, text=True)
            if done.returncode != 0:
                print(f"{directory}: the replay failed: {done.stderr.strip()}", file=sys.stderr)
                return 2
        moved = []
        for name in manifest["files"]:
            if not name.endswith(".csv"):
                continue
            with open(os.path.join(directory, name), newline="") as f:
                base = list(csv.reader(f))
            with open(os.path.join(out, name), newline="") as f:
                now = list(csv.reader(f))
            if len(base) != len(now):
                moved.append(f"{name}: {len(base)} rows, now {len(now)}")
                continue
            for k, (a, b) in enumerate(zip(base, now)):
                if len(a) != len(b) or not all(same(x, y) for x, y in zip(a, b)):
                    moved.append(f"{name} line {k + 1}: {','.join(a)[:120]} -> {','.join(b)[:120]}")
                    break
    for m in moved:
        print(f"{directory}: {m}", file=sys.stderr)
    return 1 if moved else 0


if __name__ == "__main__":
    status = 0
    args = sys.argv[1:]
    against = None
    if args[:1] == ["--against"]:
        if len(args) != 3:
            sys.exit("usage: scripts/check-replay.py --against FRESH SET")
        against, args = args[1], args[2:]
    for d in args:
        s = check(d, against)
        print(("ok      " if s == 0 else "MOVED   ") + d)
        status = max(status, s)
    sys.exit(status)
