#!/usr/bin/env python3
"""Independent readings of the public flight logs of ../shared/data/ with the autopilots' own
Python tools, committed as expectations for the Rust readers' tests. Each format has its own
function and its own key of the JSON file (this script rewrites only the keys it computes):

- `ardupilot` (`ardupilot_dataflash()`): ardupilot/pymavlink_test.BIN read with pymavlink's
  DFReader: message counts, the magnetometer instances, the COMPASS_* parameters in force, the
  readings with ArduPilot's calibration undone by the formula the reader documents
  (src/log/dataflash.rs), the attitudes and battery currents. Read by tests/it/dataflash.rs.
- `px4` (`px4()`): pyulog's reading of the PX4 ULog fixtures (`px4/*.ulg`): per magnetometer
  instance the count, first and last time and reading, rate, device id and the CAL_MAGn slot
  matched to it (PX4's rule: CAL_MAGn_ID == device_id, else n = instance); the firmware version
  and what the readings carry (raw from PX4 1.12 on; before, calibrated by the driver as
  m = SCALE * (r - OFF), undone here as r = m / SCALE + OFF); the attitude, battery current and
  throttle series. Read by tests/it/ulog.rs.

Writes crates/magcal-runner/tests/flightlogs.json.

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install pymavlink pyulog numpy
    /tmp/venv/bin/python scripts/crosscheck-flightlogs.py
"""

import json
import math
import pathlib

import numpy as np

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

def f(x):
    """A float32 or float64 as the float64 it is exactly."""
    return float(x)


def series(ts, values):
    keep = [i for i in range(len(ts)) if all(math.isfinite(f(v)) for v in values[i])]
    if not keep:
        return None
    return {
        "count": len(keep),
        "first_t_s": int(ts[keep[0]]) * 1e-6,
        "last_t_s": int(ts[keep[-1]]) * 1e-6,
        "first": [f(v) for v in values[keep[0]]],
        "last": [f(v) for v in values[keep[-1]]],
    }


def px4():
    from pyulog import ULog
    import pyulog

    files = {}
    for path in sorted((DATA / "px4").glob("*.ulg")):
        u = ULog(str(path))
        params = u.initial_parameters
        ver = u.msg_info_dict.get("ver_sw_release")
        by_topic = {}
        for d in u.data_list:
            by_topic.setdefault(d.name, {})[d.multi_id] = d.data
        topic = "sensor_mag" if "sensor_mag" in by_topic else "vehicle_magnetometer"
        if topic == "vehicle_magnetometer":
            in_force = "calibrated"
        elif ver is None or ver == 0:
            in_force = "calibrated"
        elif (ver >> 16) >= 0x010C:
            in_force = "raw"
        else:
            in_force = "undone"
        instances = {}
        for multi_id, d in sorted(by_topic[topic].items()):
            ts = d["timestamp"]
            cols = ["x", "y", "z"] if topic == "sensor_mag" else [f"magnetometer_ga[{k}]" for k in range(3)]
            m = np.stack([d[c] for c in cols], axis=1)
            dev = int(d["device_id"][0]) if "device_id" in d else None
            n, matched = None, "none"
            if dev is not None:
                for k in range(10):
                    v = params.get(f"CAL_MAG{k}_ID")
                    if v is not None and (int(v) & 0xFFFFFFFF) == dev:
                        n, matched = k, "device_id"
                        break
            if n is None and f"CAL_MAG{multi_id}_XOFF" in params:
                n, matched = multi_id, "instance"
            raw = [[f(x) for x in row] for row in m]
            if in_force == "undone":
                off = [f(params[f"CAL_MAG{n}_{a}OFF"]) for a in "XYZ"]
                scale = [f(params[f"CAL_MAG{n}_{a}SCALE"]) for a in "XYZ"]
                raw = [[row[k] / scale[k] + off[k] for k in range(3)] for row in raw]
            span = (int(ts[-1]) - int(ts[0])) * 1e-6
            instances[str(multi_id)] = {
                "count": len(ts),
                "first_t_s": int(ts[0]) * 1e-6,
                "last_t_s": int(ts[-1]) * 1e-6,
                "rate_hz": (len(ts) - 1) / span if span > 0 else 0.0,
                "device_id": dev,
                "logged_first": [f(x) for x in m[0]],
                "logged_last": [f(x) for x in m[-1]],
                "raw_first": raw[0],
                "raw_last": raw[-1],
                "calibration_index": n,
                "matched_by": matched,
                "parameters": {k: f(v) for k, v in sorted(params.items())
                               if n is not None and k.startswith(f"CAL_MAG{n}_")},
                "monotonic": bool(np.all(np.diff(ts.astype(np.int64)) >= 0)),
            }
        att = by_topic.get("vehicle_attitude", {}).get(0)
        attitude = None
        if att is not None:
            q = np.stack([att[f"q[{k}]"] for k in range(4)], axis=1)
            attitude = series(att["timestamp"], q)
        comp_typ = params.get("CAL_MAG_COMP_TYP", 0)
        bat_instance = 1 if comp_typ == 3 else 0
        bat = by_topic.get("battery_status", {}).get(bat_instance)
        current = None
        if bat is not None:
            current = series(bat["timestamp"], bat["current_a"][:, None])
            current["instance"] = bat_instance
        throttle = None
        if "actuator_controls_0" in by_topic:
            c = by_topic["actuator_controls_0"][0]
            throttle = series(c["timestamp"], c["control[3]"][:, None])
            throttle["topic"] = "actuator_controls_0"
        elif "vehicle_thrust_setpoint" in by_topic:
            c = by_topic["vehicle_thrust_setpoint"][0]
            xyz = np.stack([c[f"xyz[{k}]"].astype(np.float64) for k in range(3)], axis=1)
            # magcal keeps the norm as a float32, as the components are.
            norm = np.sqrt((xyz ** 2).sum(axis=1)).astype(np.float32)
            throttle = series(c["timestamp"], norm[:, None])
            throttle["topic"] = "vehicle_thrust_setpoint"
        files[path.name] = {
            "ver_sw_release": ver,
            "topic": topic,
            "in_force": in_force,
            "instances": instances,
            "attitude": attitude,
            "current": current,
            "throttle": throttle,
            "sensor_mag_instances": sorted(by_topic.get("sensor_mag", {}).keys()),
            "vehicle_magnetometer_count": sum(len(d["timestamp"]) for d in by_topic.get("vehicle_magnetometer", {}).values()),
        }
    return {"pyulog": pyulog.__version__ if hasattr(pyulog, "__version__") else "1.3.0", "files": files}


def main():
    out = json.loads(OUT.read_text()) if OUT.exists() else {}
    out["ardupilot"] = ardupilot_dataflash()
    out["px4"] = px4()
    OUT.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
