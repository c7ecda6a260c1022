#!/usr/bin/env python3
"""Independent cross-check of `magcal calibrate --fit full` on the public logs of ../shared/data/.

A different method from magcal's (linear ellipsoid fit, then Levenberg-Marquardt on the
normal equations): scipy.optimize.least_squares (trust-region reflective) on the norm residual
|P (s - O)| - 1 directly, from a sphere fit, with P upper triangular. The quantities compared do
not depend on the reference magnitude: the bias O (the log's units), the non-orthogonality psi
(degrees, CONVENTIONS.md inverse map), the scale factors relative to their geometric mean, and the
residual rms in percent of R.

Writes crates/magcal-runner/tests/crosscheck.json, which `tests/calibrate.rs` reads as
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


def fit(s):
    # Sphere |s|^2 = 2 c.s + k by linear least squares: the start.
    a = np.hstack([2.0 * s, np.ones((len(s), 1))])
    t, *_ = np.linalg.lstsq(a, (s * s).sum(axis=1), rcond=None)
    c = t[:3]
    r = math.sqrt(t[3] + c @ c)
    x0 = np.array([1 / r, 0, 0, 1 / r, 0, 1 / r, *c])
    out = least_squares(residual, x0, args=(s,), method="trf", x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=20000)
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
    return {
        "bias": list(o),
        "psi_deg": psi,
        "relative_scale": list(relative),
        "residual_rms_percent": 100 * rms,
        "evaluations": int(out.nfev),
        "status": int(out.status),
    }


def main():
    if not DATA.is_dir():
        sys.exit(f"{DATA} is absent")
    result = {
        "method": f"scipy {scipy.__version__} least_squares (trf) on |P (s - O)| - 1 from a sphere fit; numpy {np.__version__}",
        "logs": {},
    }
    for name, columns in LOGS.items():
        result["logs"][name] = fit(read(DATA / name, columns))
        print(name, json.dumps(result["logs"][name]))
    out = ROOT / "crates" / "magcal-runner" / "tests" / "crosscheck.json"
    out.write_text(json.dumps(result, indent=2) + "\n")
    print("written", out)


if __name__ == "__main__":
    main()
