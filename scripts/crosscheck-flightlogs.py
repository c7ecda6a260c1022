#!/usr/bin/env python3
"""Independent reading of the public flight logs of ../shared/data/ with the autopilots' own
Python tools, written as expectations for the Rust readers' tests.

Each format has its own function and its own key of the JSON file:
- `ardupilot` (ardupilot_dataflash): ardupilot/pymavlink_test.BIN read with pymavlink's
  DFReader: message counts, the magnetometer instances, the COMPASS_* parameters in force, the
  readings with ArduPilot's calibration undone by the formula the reader documents
  (src/log/dataflash.rs), the attitudes and battery currents.

Writes crates/magcal-runner/tests/flightlogs.json (keys of other formats are kept), which
tests/it/dataflash.rs reads.

    pip install pymavlink
    python3 scripts/crosscheck-flightlogs.py
"""

import json
import math
import pathlib

ROOT = pathlib.Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
OUT = ROOT / "crates" / "magcal-runner" / "tests" / "flightlogs.json"

# ArduPilot applies COMPASS_SCALE only within COMPASS_MIN_SCALE_FACTOR..COMPASS_MAX_SCALE_FACTOR.
SCALE_RANGE = (1.0 / 1.5, 1.5)


def middle(k):
    """The middle of the interval an int16 C cast (truncation towards zero) of a value came from."""
    return k + 0.5 * math.copysign(1.0, k) if k != 0 else 0.0


def undo(m, ofs_logged, mo, params, sfx):
    """r = D^-1 (m - MO) / s - OFS with the parameters in force (ArduPilot's correct_field undone)."""
    def p(name, default):
        return params.get(name, default)

    dia = [p(f"COMPASS_DIA{sfx}_{a}", 1.0) for a in "XYZ"]
    if dia == [0.0, 0.0, 0.0]:
        dia = [1.0, 1.0, 1.0]
    odi = [p(f"COMPASS_ODI{sfx}_{a}", 0.0) for a in "XYZ"]
    d = [[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]]
    s = p(f"COMPASS_SCALE{sfx}", 0.0)
    s = s if SCALE_RANGE[0] <= s <= SCALE_RANGE[1] else 1.0
    ofs = []
    for c, a in enumerate("XYZ"):
        pv = params.get(f"COMPASS_OFS{sfx}_{a}")
        ofs.append(pv if pv is not None and math.trunc(pv) == ofs_logged[c] else middle(ofs_logged[c]))
    mm = [middle(a) - middle(b) for a, b in zip(m, mo)]
    r = [x / s - o for x, o in zip(solve(d, mm), ofs)]
    return r, ofs, dia, odi, s


def solve(a, b):
    """x with a x = b, by Gaussian elimination with partial pivoting."""
    n = len(b)
    m = [list(row) + [b[i]] for i, row in enumerate(a)]
    for col in range(n):
        piv = max(range(col, n), key=lambda r: abs(m[r][col]))
        m[col], m[piv] = m[piv], m[col]
        for r in range(col + 1, n):
            f = m[r][col] / m[col][col]
            for c in range(col, n + 1):
                m[r][c] -= f * m[col][c]
    x = [0.0] * n
    for r in reversed(range(n)):
        x[r] = (m[r][n] - sum(m[r][c] * x[c] for c in range(r + 1, n))) / m[r][r]
    return x


def ardupilot_dataflash():
    from pymavlink import DFReader, __version__

    path = DATA / "ardupilot" / "pymavlink_test.BIN"
    followed = ("COMPASS_OFS", "COMPASS_DIA", "COMPASS_ODI", "COMPASS_SCALE")

    # First pass: the first value of each parameter (in force for readings logged before it).
    first = {}
    log = DFReader.DFReader_binary(str(path))
    while (msg := log.recv_msg()) is not None:
        if msg.get_type() == "PARM" and msg.Name.startswith(followed):
            first.setdefault(msg.Name, float(msg.Value))

    params = dict(first)
    counts = {}
    instances = {}
    att, bat = [], []
    log = DFReader.DFReader_binary(str(path))
    while (msg := log.recv_msg()) is not None:
        t = msg.get_type()
        counts[t] = counts.get(t, 0) + 1
        if t == "PARM" and msg.Name.startswith(followed):
            params[msg.Name] = float(msg.Value)
        elif t in ("MAG", "MAG2", "MAG3"):
            k = int(getattr(msg, "I", {"MAG": 0, "MAG2": 1, "MAG3": 2}[t]))
            sfx = "" if k == 0 else str(k + 1)
            mo_names = ("MOX", "MOY", "MOZ") if hasattr(msg, "MOX") else ("MOfsX", "MOfsY", "MOfsZ")
            m = [msg.MagX, msg.MagY, msg.MagZ]
            ofs_logged = [msg.OfsX, msg.OfsY, msg.OfsZ]
            mo = [getattr(msg, n) for n in mo_names]
            raw, ofs, dia, odi, s = undo(m, ofs_logged, mo, params, sfx)
            inst = instances.setdefault(str(k), {"message": t, "samples": []})
            inst.setdefault("in_force", {"ofs": ofs, "dia": dia, "odi": odi, "s": s})
            inst["samples"].append({"time_s": msg.TimeUS * 1e-6, "logged": m, "raw": raw})
        elif t == "ATT":
            att.append({"time_s": msg.TimeUS * 1e-6, "roll": msg.Roll, "pitch": msg.Pitch, "yaw": msg.Yaw})
        elif t == "BAT":
            bat.append({"time_s": msg.TimeUS * 1e-6, "current": msg.Curr})
    return {
        "file": "ardupilot/pymavlink_test.BIN",
        "tool": f"pymavlink {__version__} DFReader_binary",
        "messages": sum(counts.values()),
        "counts": {k: counts[k] for k in ("FMT", "PARM", "MAG", "MAG2", "MAG3", "ATT", "BAT")},
        "instances": instances,
        "attitude": att,
        "current": bat,
    }


def main():
    out = json.loads(OUT.read_text()) if OUT.exists() else {}
    out["ardupilot"] = ardupilot_dataflash()
    OUT.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
