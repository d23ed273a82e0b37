#!/usr/bin/env python3
"""The daemon's heading error beside PX4, from flights of tools/sitl/px4.py (motion.csv).

usage: heading_fit.py FLIGHT_DIR [FLIGHT_DIR ...]

Per flight, over wings-level samples (|roll| < 5°) from 150 s before the loss to the end:
the heading error fitted as `c + a sin ψ + b cos ψ` (ψ the true heading): a constant `c` is a
NED-fixed error (declination, magnetic-model error), the once-per-revolution amplitude
`√(a² + b²)` a body-fixed magnetometer error; its RMS against the daemon's published yaw σ;
and the daemon's wind error at its last fix before the loss (summary.toml).
"""

import csv
import math
import sys
import tomllib
from pathlib import Path

import numpy as np


def fit(flight: Path):
    rows = []
    with open(flight / "motion.csv") as f:
        for r in csv.DictReader(f):
            try:
                rows.append([float(r["t_s"]), float(r["ianav_yaw_err_deg"]),
                             float(r["truth_yaw_deg"]), float(r["truth_roll_deg"]),
                             float(r.get("ianav_yaw_sigma_deg") or "nan")])
            except ValueError:
                continue  # a sample without the daemon's or SIH's value
    t, err, hdg, roll, sigma = np.array(rows).T
    m = (np.abs(roll) < 5) & (t > -150)
    h = np.radians(hdg[m])
    a = np.column_stack([np.ones(m.sum()), np.sin(h), np.cos(h)])
    x, *_ = np.linalg.lstsq(a, err[m], rcond=None)
    s = tomllib.loads((flight / "summary.toml").read_text())
    w = s.get("ianav_wind_at_loss", {})
    wind = math.hypot(w["error_n_mps"], w["error_e_mps"]) if w else float("nan")
    sig = float(np.nanmean(sigma[m])) if np.isfinite(sigma[m]).any() else float("nan")
    return x[0], math.hypot(x[1], x[2]), float(np.sqrt(np.mean(err[m] ** 2))), sig, wind


def main(dirs):
    print("| flight | constant (°) | once per revolution (°) | RMS (°) | published σ (°) "
          "| wind error at loss (m/s) |")
    print("|---|---|---|---|---|---|")
    for d in dirs:
        p = Path(d)
        if not (p / "motion.csv").exists():
            print(f"no motion.csv in {p}", file=sys.stderr)
            continue
        c, amp, rms, sig, wind = fit(p)
        print(f"| {p.parent.name}/{p.name} | {c:+.2f} | {amp:.2f} | {rms:.2f} | {sig:.2f} "
              f"| {wind:.2f} |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
