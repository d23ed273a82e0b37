#!/usr/bin/env python3
"""The PX4 comparison as one command: every mode and wind, repeated, with tools/sitl/px4.py.

usage: px4_campaign.py --px4-build DIR --out OUT [--reps N] [--winds 0,135,270]
                       [--modes alone,open,closed] [--first-rep K] [-- px4.py options]

Flies OUT/rep<k>/wind<deg>_<mode>/ for k = first-rep .. first-rep + reps - 1, one flight at a
time (flights share the machine's cores; SIH's lockstep keeps PX4's physics independent of the
load, the achieved speed is not). A flight whose summary.toml says `completed = true` is not
flown again, so an interrupted campaign resumes where it stopped; a flight that failed is
flown once more, then left failed (its summary says why). Everything after `--` goes to px4.py
unchanged. The published defaults of px4.py are the campaign's: change them there, not here.
Then: `python3 tools/sitl/px4_compare.py OUT/rep1 OUT/rep2 ...`.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
import tomllib
from pathlib import Path

HERE = Path(__file__).resolve().parent


def completed(flight: Path) -> bool:
    try:
        return bool(tomllib.loads((flight / "summary.toml").read_text()).get("completed"))
    except (OSError, tomllib.TOMLDecodeError):
        return False


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = []
    if "--" in argv:
        i = argv.index("--")
        argv, extra = argv[:i], argv[i + 1:]
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--px4-build", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--first-rep", type=int, default=1)
    ap.add_argument("--winds", default="0,135,270", help="directions the wind blows from, deg")
    ap.add_argument("--modes", default="alone,open,closed")
    a = ap.parse_args(argv)
    winds = [float(w) for w in a.winds.split(",") if w]
    modes = [m for m in a.modes.split(",") if m]
    failed = []
    for rep in range(a.first_rep, a.first_rep + a.reps):
        for wind in winds:
            for mode in modes:
                flight = Path(a.out) / f"rep{rep}" / f"wind{wind:g}_{mode}"
                for attempt in (1, 2):
                    if completed(flight):
                        break
                    print(f"[px4_campaign {time.strftime('%H:%M:%S')}] {flight} "
                          f"(attempt {attempt})", flush=True)
                    subprocess.run([sys.executable, str(HERE / "px4.py"), "--px4-build",
                                    a.px4_build, "--mode", mode, "--wind-from-deg", f"{wind:g}",
                                    "--csv-period-s", "1.0", "--out", str(flight), *extra],
                                   check=False)
                if not completed(flight):
                    failed.append(str(flight))
    for f in failed:
        print(f"failed: {f}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
