#!/usr/bin/env python3
"""Replay a recorded tools/sitl/px4.py flight with other navigation settings and score the
result against SIH's truth.

usage: px4_replay_score.py FLIGHT [--daemon BIN] [--set KEY=VALUE ...] [--label NAME]

FLIGHT is a flight directory of `px4.py --record` (it holds `summary.toml`, `motion.csv`,
`flight.csv` and `logs/daemon.bin`, or `daemon.bin.xz` beside them). The recording goes through
`ianav replay` with every `--set` passed on (docs/REPLAY.md), so one flight can be tried with
another filter setting without flying it again. Printed, open loop only (in closed loop PX4
would have flown differently):
- the attitude lag: least-squares slope of the roll error on the roll rate and of the heading
  error on the yaw rate, before (last 150 s) and after the loss (s; negative = behind);
- heading error RMS before the loss and after it, wings level (|roll| < 5°) and banked;
- the mean north / east velocity error after the loss (m/s);
- the horizontal error 1 / 2 / 5 / 10 min after the loss (m), and PX4's in the same flight.
"""

from __future__ import annotations

import argparse
import csv
import lzma
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
EARTH_RADIUS_M = 6378137.0
CHECKPOINTS_MIN = (1, 2, 5, 10)


def recording(flight: Path, tmp: Path) -> Path:
    for p in (flight / "logs" / "daemon.bin", flight / "daemon.bin"):
        if p.exists():
            return p
    xz = flight / "daemon.bin.xz"
    if not xz.exists():
        sys.exit(f"{flight}: no logs/daemon.bin or daemon.bin.xz (fly it with px4.py --record)")
    out = tmp / "daemon.bin"
    with lzma.open(xz) as src, open(out, "wb") as dst:
        shutil.copyfileobj(src, dst)
    return out


def replay(daemon: str, log: Path, sets: list[str], out: Path):
    cmd = [daemon, "replay", str(log), "--out", str(out), "--every", "2"]
    for s in sets:
        cmd += ["--set", s]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(r.stderr.strip())
    return np.genfromtxt(out / "solutions.csv", delimiter=",", names=True)


def euler_deg(w, x, y, z):
    roll = np.degrees(np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)))
    pitch = np.degrees(np.arcsin(np.clip(2 * (w * y - z * x), -1, 1)))
    yaw = np.unwrap(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    return roll, pitch, yaw


def column(rows, key):
    return np.array([float(r[key]) if r[key] != "" else np.nan for r in rows])


def lag_s(err, rate, sel):
    s = sel & np.isfinite(err) & (np.abs(rate) < 60)
    if s.sum() < 10:
        return float("nan")
    return float(np.linalg.lstsq(np.c_[np.ones(s.sum()), rate[s]], err[s], rcond=None)[0][1])


def rms(v):
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("flight", type=Path)
    ap.add_argument("--daemon", default=str(REPO / "target" / "release" / "ianav"))
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--label", default="")
    a = ap.parse_args()
    summary = tomllib.loads((a.flight / "summary.toml").read_text())
    if summary.get("mode") != "open":
        sys.exit("open-loop flights only: in closed loop PX4 flew on the daemon's output")
    t_loss_us = summary["gnss_loss_px4_time_s"] * 1e6

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sol = replay(a.daemon, recording(a.flight, tmp), a.sets, tmp / "out")
    t = (sol["t_us"] - t_loss_us) / 1e6
    roll, pitch, yaw = euler_deg(sol["q_w"], sol["q_x"], sol["q_y"], sol["q_z"])

    m = list(csv.DictReader(open(a.flight / "motion.csv")))
    mt = column(m, "t_s")
    keep = (mt > t[0]) & (mt < t[-1]) & np.isfinite(column(m, "truth_v_n_mps"))
    m = [r for r, k in zip(m, keep) if k]
    mt = mt[keep]
    t_roll, t_yaw = column(m, "truth_roll_deg"), np.radians(column(m, "truth_yaw_deg"))
    e_yaw = np.degrees(np.angle(np.exp(1j * (np.interp(mt, t, yaw) - t_yaw))))
    e_roll = np.interp(mt, t, roll) - t_roll
    e_vn = np.interp(mt, t, sol["v_n_mps"]) - column(m, "truth_v_n_mps")
    e_ve = np.interp(mt, t, sol["v_e_mps"]) - column(m, "truth_v_e_mps")
    yaw_rate = np.gradient(np.degrees(np.unwrap(t_yaw)), mt)
    roll_rate = np.gradient(t_roll, mt)
    pre, post = (mt < 0) & (mt > -150), mt > 20
    level = np.abs(t_roll) < 5

    f = list(csv.DictReader(open(a.flight / "flight.csv")))
    ft = column(f, "t_s")
    lat, lon = np.radians(column(f, "truth_lat_deg")), np.radians(column(f, "truth_lon_deg"))
    d_n = (np.interp(ft, t, sol["lat_rad"]) - lat) * EARTH_RADIUS_M
    d_e = (np.interp(ft, t, sol["lon_rad"]) - lon) * EARTH_RADIUS_M * np.cos(lat)
    e_h = np.hypot(d_n, d_e)
    ap_h = column(f, "ap_err_h_m")

    def at(err, minutes):
        return float(np.interp(60.0 * minutes, ft, err))

    print(f"{a.label or ' '.join(a.sets) or 'as recorded'}: "
          f"lag roll {lag_s(e_roll, roll_rate, pre):+.3f} / {lag_s(e_roll, roll_rate, post):+.3f} s, "
          f"yaw {lag_s(e_yaw, yaw_rate, pre):+.3f} / {lag_s(e_yaw, yaw_rate, post):+.3f} s | "
          f"heading RMS before {rms(e_yaw[pre]):.2f}°, after level {rms(e_yaw[post & level]):.2f}° "
          f"banked {rms(e_yaw[post & ~level]):.2f}° | velocity error after "
          f"{np.nanmean(e_vn[post]):+.2f} N {np.nanmean(e_ve[post]):+.2f} E m/s | "
          "error 1/2/5/10 min " + " / ".join(f"{at(e_h, k):.0f}" for k in CHECKPOINTS_MIN)
          + " m (PX4 " + " / ".join(f"{at(ap_h, k):.0f}" for k in CHECKPOINTS_MIN) + " m)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
