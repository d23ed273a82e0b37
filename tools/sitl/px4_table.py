#!/usr/bin/env python3
"""Markdown table of PX4 SITL flights: horizontal error after GNSS loss per flight and mode.

Reads `<dir>/*/summary.toml` written by tools/sitl/px4.py and prints one row per flight:
PX4's error (GLOBAL_POSITION_INT) and ianav's (ODOMETRY) at 1, 2, 5, 10 min after the loss,
ianav's consistency (fraction of samples with error ≤ 2.45 hacc, hacc RMS / error RMS).
"""

import sys
import tomllib
from pathlib import Path


def cell(d, key):
    v = d.get(key)
    return "–" if v is None else f"{v:.0f}"


def main(dirs):
    print("| flight | mode | wind from | PX4 1 / 2 / 5 / 10 min (m) | ianav 1 / 2 / 5 / 10 min (m) "
          "| ianav ≤ 2.45 hacc | hacc RMS / err RMS | completed |")
    print("|---|---|---|---|---|---|---|---|")
    for root in dirs:
        for f in sorted(Path(root).glob("*/summary.toml")):
            s = tomllib.loads(f.read_text())
            e = s.get("horizontal_error_after_loss", {})
            c = s.get("ianav_consistency", {})
            ap = " / ".join(cell(e, f"ap_{m}min_m") for m in (1, 2, 5, 10))
            ia = " / ".join(cell(e, f"ianav_{m}min_m") for m in (1, 2, 5, 10))
            frac = c.get("fraction_err_le_2p45_hacc")
            ratio = c.get("hacc_rms_over_err_rms")
            print(f"| {f.parent.name} | {s['mode']} | {s['wind_from_deg']:g}° "
                  f"{s['wind_mps']:g} m/s | {ap} | {ia if s['mode'] != 'alone' else '–'} | "
                  f"{'–' if frac is None else f'{frac:.2f}'} | "
                  f"{'–' if ratio is None else f'{ratio:.2f}'} | {s['completed']} |")


if __name__ == "__main__":
    main(sys.argv[1:] or ["docs/results/px4"])
