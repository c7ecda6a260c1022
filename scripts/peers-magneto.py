#!/usr/bin/env python3
"""Magneto's ellipsoid fit (Li and Griffiths 2004, as Magneto 1.2 and its Python ports do it) in
numpy, file reading included: the peer `calibrate` is measured against on long logs (README
"Benchmarks"). Prints the bias, the correction matrix and the CPU seconds it took.

    /usr/bin/time -f "%e s wall, %U user, %M KB" python3 scripts/peers-magneto.py LOG.csv [FIELD]

LOG.csv: a header line, then x,y,z per row. FIELD: the magnitude to scale to (default: the
fit's own mean radius)."""
import sys
import time

import numpy as np


def fit(x):
    """Bias b and matrix A^-1 with |A^-1 (x - b)| = F for every reading x, by Li-Griffiths."""
    X, Y, Z = x[:, 0], x[:, 1], x[:, 2]
    D = np.array([X * X, Y * Y, Z * Z, 2 * Y * Z, 2 * X * Z, 2 * X * Y, 2 * X, 2 * Y, 2 * Z, np.ones_like(X)])
    S = D @ D.T
    S11, S12, S22 = S[:6, :6], S[:6, 6:], S[6:, 6:]
    C = np.array([[-1, 1, 1, 0, 0, 0], [1, -1, 1, 0, 0, 0], [1, 1, -1, 0, 0, 0],
                  [0, 0, 0, -4, 0, 0], [0, 0, 0, 0, -4, 0], [0, 0, 0, 0, 0, -4]], dtype=float)
    E = np.linalg.inv(C) @ (S11 - S12 @ np.linalg.inv(S22) @ S12.T)
    w, v = np.linalg.eig(E)
    v1 = np.real(v[:, np.argmax(np.real(w))])
    if v1[0] < 0:
        v1 = -v1
    v2 = -np.linalg.inv(S22) @ S12.T @ v1
    M = np.array([[v1[0], v1[5], v1[4]], [v1[5], v1[1], v1[3]], [v1[4], v1[3], v1[2]]])
    n = v2[:3]
    d = v2[3]
    Minv = np.linalg.inv(M)
    b = -Minv @ n
    scale = np.sqrt(n @ Minv @ n - d)
    w, v = np.linalg.eigh(M)
    sqrtM = v @ np.diag(np.sqrt(np.abs(w))) @ v.T
    return b, sqrtM / scale


def main():
    start = time.process_time()
    x = np.loadtxt(sys.argv[1], delimiter=",", skiprows=1)
    read = time.process_time() - start
    b, A1 = fit(x)
    radius = np.mean(np.linalg.norm((x - b) @ A1.T, axis=1))
    field = float(sys.argv[2]) if len(sys.argv) > 2 else radius
    A1 = A1 * field / radius
    total = time.process_time() - start
    print(f"{len(x)} readings; bias {b[0]:.3f} {b[1]:.3f} {b[2]:.3f}")
    print("A^-1", np.array2string(A1, precision=7).replace("\n", " "))
    print(f"CPU: reading {read:.2f} s, all {total:.2f} s")


if __name__ == "__main__":
    main()
