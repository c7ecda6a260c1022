"""Calibrates a shipped log from Python and shows what the calibration did.

    python crates/magcal-py/examples/calibrate_log.py                 # the CK-Explorer log, printed
    python crates/magcal-py/examples/calibrate_log.py --plot out.png  # and drawn (needs matplotlib)
    python crates/magcal-py/examples/calibrate_log.py LOG --columns mx,my,mz --units uT

Prints the estimates with their standard errors, the verdict, and the spread of the field's
magnitude before and after: a calibrated sensor reads one magnitude in every direction.
"""

import argparse
import pathlib

import numpy as np

import pymagcal

SHIPPED = pathlib.Path(__file__).resolve().parents[3].parent / "shared" / "data" / "ck-explorer" / "acc_mag_log.csv"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", nargs="?", default=str(SHIPPED))
    parser.add_argument("--columns", default="mx,my,mz")
    parser.add_argument("--units", default="G", help="the log's units: nT, uT, mG or G")
    parser.add_argument("--plot", metavar="PNG", help="draw the magnitudes before and after")
    args = parser.parse_args()

    log = pymagcal.read_log(args.log, columns=args.columns)
    cal = pymagcal.calibrate(log, units=args.units)
    print(f"{log.path}: {len(log)} readings, {cal.fit} fit, {'usable' if cal.usable else 'NOT usable'}")
    for reason in cal.reasons:
        print(f"  not usable: {reason}")
    if cal.fit is None:
        return 3
    se = cal.std_error
    for name, values, errors in [("bias", cal.bias, se["bias"]), ("scale", cal.scale, se["scale"]), ("psi_deg", cal.psi_deg, se["psi_deg"])]:
        shown = ", ".join(f"{v:.6g} +- {e:.2g}" if errors else f"{v:.6g}" for v, e in zip(values, errors or [None] * 3))
        print(f"  {name:8} {shown}")

    before = np.linalg.norm(log.readings, axis=1)
    after = np.linalg.norm(cal.apply(log.readings), axis=1)
    for label, m in [("raw", before), ("calibrated", after)]:
        print(f"  |field| {label:10} mean {m.mean():.6g} {args.units}, rms spread {100 * m.std() / m.mean():.3f} %")

    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(8, 4))
        ax.plot(before, ".", ms=1, label="raw")
        ax.plot(after, ".", ms=1, label="calibrated")
        ax.axhline(cal.magnitude, color="k", lw=0.8, label="magnitude")
        ax.set_xlabel("reading")
        ax.set_ylabel(f"|field|, {args.units}")
        ax.legend()
        fig.savefig(args.plot, dpi=120, bbox_inches="tight")
        print(f"  drawn: {args.plot}")
    return 0 if cal.usable else 3


if __name__ == "__main__":
    raise SystemExit(main())
