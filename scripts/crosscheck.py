#!/usr/bin/env python3
"""Independent cross-check of `magcal calibrate --fit full` on the public logs of ../shared/data/.

A different method from magcal's (linear ellipsoid fit, then Levenberg-Marquardt on the
normal equations): scipy.optimize.least_squares (trust-region reflective) from a sphere fit, with
P upper triangular, on each of magcal's two residuals: [P1]'s norm residual |P (s - O)| - 1
(`--residual paper`, under "logs") and the readings' distance from the ellipsoid to first order,
(|P (s - O)| - 1) / |P^T w|, w = P (s - O) / |P (s - O)| (the default, under "readings_logs",
which adds the restricted-tilt hamagure set 2). The quantities compared do
not depend on the reference magnitude: the bias O (the log's units), the non-orthogonality psi
(degrees, docs/conventions.md inverse map), the scale factors relative to their geometric mean, and the
residual rms in percent of R; and the two coverage heuristics of the calibrated directions
(MotionCal's gaps over 100 equal-area regions, MicroStrain's occupied share of 18 x 32
equal-angle bins), binned here with numpy from their definitions.

Writes crates/magcal-runner/tests/crosscheck.json, which `tests/it/calibrate.rs` reads as
expectations (tolerances there come from magcal's standard errors).

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install numpy scipy
    /tmp/venv/bin/python scripts/crosscheck.py
"""

import json
import math
import pathlib
import sys

import numpy as np
import scipy
from scipy.optimize import least_squares

ROOT = pathlib.Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
LOGS = {
    "ck-explorer/acc_mag_log.csv": ("mx", "my", "mz"),
    "hamagure/data-set_1.csv": ("x", "y", "z"),
}
READINGS_LOGS = {**LOGS, "hamagure/data-set_2.csv": ("x", "y", "z")}


def read(path, columns):
    with open(path) as f:
        header = [c.strip() for c in f.readline().split(",")]
        index = [header.index(c) for c in columns]
        rows = [[float(v) for v in line.split(",")] for line in f if line.strip()]
    return np.array(rows)[:, index]


def unpack(x):
    p = np.array([[x[0], x[1], x[2]], [0.0, x[3], x[4]], [0.0, 0.0, x[5]]])
    return p, x[6:9]


def residual(x, s):
    p, o = unpack(x)
    return np.linalg.norm((s - o) @ p.T, axis=1) - 1.0


def distance(x, s):
    """(|P (s - O)| - 1) / |P^T w|: the reading's distance from the ellipsoid to first order."""
    p, o = unpack(x)
    b = (s - o) @ p.T
    n = np.linalg.norm(b, axis=1)
    g = (b / n[:, None]) @ p
    return (n - 1.0) / np.linalg.norm(g, axis=1)


def motioncal_gaps(d):
    """PJRC MotionCal quality.c: 100 equal-area regions; 1 per empty, 0.2 per single, 0.01 per pair."""
    z = d[:, 2]
    turn = np.mod(np.arctan2(d[:, 1], d[:, 0]) / (2 * math.pi), 1.0)
    bands = [(z > 0.98, 0, 1), ((z <= 0.98) & (z > 0.68), 1, 15), ((z <= 0.68) & (z >= 0), 16, 34),
             ((z < 0) & (z >= -0.68), 50, 34), ((z < -0.68) & (z >= -0.98), 84, 15), (z < -0.98, 99, 1)]
    counts = np.zeros(100, dtype=int)
    for mask, first, n in bands:
        idx = first + np.minimum((turn[mask] * n).astype(int), n - 1)
        np.add.at(counts, idx, 1)
    weight = np.select([counts == 0, counts == 1, counts == 2], [1.0, 0.2, 0.01], 0.0)
    return float(weight.sum())


def microstrain_coverage(d):
    """MicroStrain microstrain_mag_cal calculateSpatialCoverage: 18 latitude x 32 longitude bins."""
    lat = np.arcsin(np.clip(d[:, 2], -1, 1))
    lon = np.arctan2(d[:, 1], d[:, 0])
    i = np.clip(((lat + math.pi / 2) / math.pi * 18).astype(int), 0, 17)
    j = np.clip(((lon + math.pi) / (2 * math.pi) * 32).astype(int), 0, 31)
    return 100.0 * len(set(zip(i.tolist(), j.tolist()))) / 576


def fit(s, objective=residual):
    # Sphere |s|^2 = 2 c.s + k by linear least squares: the start.
    a = np.hstack([2.0 * s, np.ones((len(s), 1))])
    t, *_ = np.linalg.lstsq(a, (s * s).sum(axis=1), rcond=None)
    c = t[:3]
    r = math.sqrt(t[3] + c @ c)
    x0 = np.array([1 / r, 0, 0, 1 / r, 0, 1 / r, *c])
    out = least_squares(objective, x0, args=(s,), method="trf", x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=20000)
    p, o = unpack(out.x)
    # Positive diagonal representative (a row of P may change sign).
    p = p * np.sign(np.diag(p))[:, None]
    k = np.linalg.inv(p)
    scale = np.linalg.norm(np.triu(k), axis=1)
    n = np.triu(k) / scale[:, None]
    psi = [
        math.degrees(math.atan2(n[1, 2], n[1, 1])),
        math.degrees(math.asin(max(-1.0, min(1.0, n[0, 2])))),
        math.degrees(math.atan2(n[0, 1], n[0, 0])),
    ]
    relative = scale / np.prod(scale) ** (1 / 3)
    # With R = 1, |calibrated| - 1 is already relative.
    rms = math.sqrt(np.mean(residual(out.x, s) ** 2))
    b = (s - o) @ p.T
    d = b / np.linalg.norm(b, axis=1)[:, None]
    return {
        "bias": list(o),
        "psi_deg": psi,
        "relative_scale": list(relative),
        "residual_rms_percent": 100 * rms,
        "motioncal_gap_percent": motioncal_gaps(d),
        "microstrain_coverage_percent": microstrain_coverage(d),
        "evaluations": int(out.nfev),
        "status": int(out.status),
    }


def main():
    if not DATA.is_dir():
        sys.exit(f"{DATA} is absent")
    result = {
        "method": f"scipy {scipy.__version__} least_squares (trf) from a sphere fit, on |P (s - O)| - 1 (logs) and on (|P (s - O)| - 1) / |P^T w| (readings_logs); numpy {np.__version__}",
        "logs": {},
        "readings_logs": {},
    }
    for name, columns in LOGS.items():
        result["logs"][name] = fit(read(DATA / name, columns))
        print(name, json.dumps(result["logs"][name]))
    for name, columns in READINGS_LOGS.items():
        result["readings_logs"][name] = fit(read(DATA / name, columns), distance)
        print(name, "readings", json.dumps(result["readings_logs"][name]))
    out = ROOT / "crates" / "magcal-runner" / "tests" / "crosscheck.json"
    out.write_text(json.dumps(result, indent=2) + "\n")
    print("written", out)


if __name__ == "__main__":
    main()
