#!/usr/bin/env python3
"""Independent readings of the public flight logs of ../shared/data/, committed as expectations.

`px4()`: pyulog's reading of the PX4 ULog fixtures (`px4/*.ulg`): per magnetometer instance the
count, first and last time and reading, rate, device id and the CAL_MAGn slot matched to it
(PX4's rule: CAL_MAGn_ID == device_id, else n = instance); the firmware version and what the
readings carry (raw from PX4 1.12 on; before, calibrated by the driver as m = SCALE * (r - OFF),
undone here as r = m / SCALE + OFF); the attitude, battery current and throttle series. The Rust
tests (`tests/it/ulog.rs`) compare magcal's reader with these numbers.

Writes crates/magcal-runner/tests/flightlogs.json (each reader's part under its own key; this
script rewrites only the keys it computes).

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install pyulog numpy
    /tmp/venv/bin/python scripts/crosscheck-flightlogs.py
"""

import json
import math
import pathlib

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
OUT = ROOT / "crates" / "magcal-runner" / "tests" / "flightlogs.json"


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
    out["px4"] = px4()
    OUT.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
