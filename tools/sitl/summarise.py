#!/usr/bin/env python3
"""Markdown table of the horizontal errors in the summary.toml files of flight directories.

usage: summarise.py DIR [DIR ...]   (each DIR holds a summary.toml of ardupilot_flight.py)
"""

import os
import sys
import tomllib


def cell(v):
    return "–" if not isinstance(v, (int, float)) else f"{v:.0f}"


def main():
    rows = []
    for d in sys.argv[1:]:
        with open(os.path.join(d, "summary.toml"), "rb") as f:
            s = tomllib.load(f)
        rows.append((os.path.basename(os.path.normpath(d)), s))
    if not rows:
        sys.exit(__doc__)
    cps = list(rows[0][1].get("error", {}).keys())
    head = ["flight", "mode", "wind from", "done"]
    head += [f"AP {c[1:]}" for c in cps] + [f"ianav {c[1:]}" for c in cps]
    head += ["err ≤ 2.45 hacc", "hacc/err RMS"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for name, s in rows:
        e = s.get("error", {})
        r = [name, s["mode"], f"{s['wind_dir_deg']:g}°", "yes" if s["completed"] else "NO"]
        r += [cell(e.get(c, {}).get("ap_err_h_m")) for c in cps]
        r += [cell(e.get(c, {}).get("ianav_err_h_m")) if s["mode"] != "alone" else "–"
              for c in cps]
        f = s.get("frac_ianav_err_le_2p45_hacc")
        q = s.get("hacc_rms_over_err_rms")
        r += [f"{f:.2f}" if isinstance(f, (int, float)) else "–",
              f"{q:.2f}" if isinstance(q, (int, float)) else "–"]
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main()
