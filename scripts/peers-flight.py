#!/usr/bin/env python3
"""An ordinary flight calibrated by magcal and by pymavlink's magfit_WMM.py (the method of
ArduPilot's MAGFit), side by side, on synthetic DataFlash logs of a known compass.

The logs are the flights of tests/it/gps.rs (20 km from 60 N, level legs and full turns at 10
degrees of bank, 10,000 readings at 10 Hz, a compass raw = diag(s) b + O + d * current with 1 mGauss
of noise), written by its generator test. For each: `magcal calibrate LOG --fit vector-diagonal
--motor current --json` (the field along the GPS track) and `magfit_WMM.py --cmot --elliptical
--att-source ATT --reduce R LOG` (ArduPilot's declination and intensity table at the first 3D fix;
its heading from the corrected compass). magfit_WMM corrects as corrected = D s (raw + ofs) + cmot
* current, so its estimate of O is -ofs. Prints a Markdown table of the offsets' errors (mGauss).

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install pymavlink numpy scipy matplotlib
    MPLBACKEND=Agg /tmp/venv/bin/python scripts/peers-flight.py [FLIGHTS] [REDUCE]
"""

import json
import os
import pathlib
import re
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
MAGCAL = pathlib.Path(os.environ["MAGCAL_BIN"]) if os.environ.get("MAGCAL_BIN") else ROOT / "target" / "release" / "magcal"
OUT = pathlib.Path("/tmp/magcal-peers-flights")


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    reduce = int(sys.argv[2]) if len(sys.argv) > 2 else 10
    env = dict(os.environ, MAGCAL_FLIGHTS_DIR=str(OUT), MAGCAL_FLIGHTS=str(n), MPLBACKEND="Agg")
    subprocess.run(
        ["cargo", "test", "--release", "-p", "magcal-runner", "--test", "it", "--", "--ignored", "--exact",
         "gps::write_flights_for_the_peers"],
        cwd=ROOT, env=env, check=True, capture_output=True)
    truth = json.loads((OUT / "truth.json").read_text())
    o = truth["bias"]
    magfit = pathlib.Path(sys.executable).parent / "magfit_WMM.py"
    print("| flight | magcal O error (x, y, z) | magcal std errors | magcal s | magfit_WMM O error (x, y, z) | magfit_WMM diag, scale | seconds (magcal, magfit) |")
    print("|---|---|---|---|---|---|---|")
    for seed in range(1, n + 1):
        log = OUT / f"flight{seed}.bin"
        t0 = time.time()
        r = subprocess.run([str(MAGCAL), "calibrate", str(log), "--fit", "vector-diagonal", "--motor", "current", "--json"],
                           capture_output=True, text=True)
        t1 = time.time()
        c = json.loads(r.stdout)
        m = subprocess.run([sys.executable, str(magfit), "--cmot", "--elliptical", "--att-source", "ATT",
                            "--reduce", str(reduce), str(log)], capture_output=True, text=True, env=env)
        t2 = time.time()
        new = [l for l in m.stdout.splitlines() if l.startswith("New:")]
        if not new:
            print(f"| {seed} | magfit_WMM failed: {m.stdout[-300:]} {m.stderr[-300:]} |")
            continue
        nums = [float(x) for x in re.findall(r"-?\d+\.\d+(?:e-?\d+)?", new[0])]
        ofs, diag, scale = nums[0:3], nums[3:6], nums[-1]
        err_c = [c["bias"][i] - o[i] for i in range(3)]
        err_m = [-ofs[i] - o[i] for i in range(3)]
        f = lambda v: ", ".join(f"{x:+.2f}" for x in v)
        print(f"| {seed} | {f(err_c)} | {', '.join(f'{x:.2f}' for x in c['std_error']['bias'])} | "
              f"{', '.join(f'{x:.4f}' for x in c['scale'])} | {f(err_m)} | {', '.join(f'{x:.3f}' for x in diag)}, {scale:.2f} | "
              f"{t1 - t0:.1f}, {t2 - t1:.1f} |")


if __name__ == "__main__":
    main()
