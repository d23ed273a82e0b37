#!/usr/bin/env python3
"""Acceptance checks over repeated PX4 SITL flights (tools/sitl/px4.py output).

usage: px4_compare.py DIR[:MODE,...] [DIR[:MODE,...] ...]

Each DIR is one repetition holding `wind<deg>_<mode>/summary.toml` flights (modes `open`,
`closed`, `alone`); `DIR:alone` takes only the listed modes from it (e.g. the alone flights of
another daemon commit's repetitions, flown with the same harness). Prints, per wind and checkpoint (1, 2, 5, 10 min after the loss):
- open loop: ianav's horizontal error against PX4's own estimate in the same flight (PX4
  ignores the daemon there, so it is PX4 alone on that very trajectory);
- closed loop: PX4's error with the daemon against PX4 alone, flight by flight in the order
  the directories are given, as means over the repetitions, and against the mean of PX4
  without the daemon pooled over the alone flights and PX4's own estimate in the open flights
  (it ignores the daemon there); PX4's dead reckoning varies between flights of the same
  setup (printed below), so single pairs are noisy;
- ianav's consistency: share of post-loss samples within 2.45 x its published accuracy and
  published-accuracy RMS / error RMS per flight, and both pooled over all flights.
"""

import sys
import tomllib
from pathlib import Path

CHECKPOINTS = (1, 2, 5, 10)


def load(dirs):
    flights = {}  # (wind, mode) -> list of summaries, one per directory
    for arg in dirs:
        d, _, only = arg.partition(":")
        modes = set(only.split(",")) if only else None
        for f in sorted(Path(d).glob("wind*_*/summary.toml")):
            s = tomllib.loads(f.read_text())
            if modes is not None and s["mode"] not in modes:
                continue
            if not s.get("completed"):
                print(f"skipped (not completed): {f.parent}", file=sys.stderr)
                continue
            s["_heading"] = heading_consistency(f.parent / "motion.csv")
            flights.setdefault((s["wind_from_deg"], s["mode"]), []).append(s)
    return flights


def heading_consistency(path):
    """Share of the daemon's heading errors within 2.45 × its published yaw σ, over the last
    60 s before the loss and the whole time after it (motion.csv), with the error RMS."""
    import csv
    import math

    try:
        rows = list(csv.DictReader(path.open()))
    except OSError:
        return None
    out = {}
    for name, lo, hi in (("before", -60.0, 0.0), ("after", 0.0, math.inf)):
        e, sig = [], []
        for r in rows:
            try:
                t, y, sg = float(r["t_s"]), float(r["ianav_yaw_err_deg"]), float(
                    r["ianav_yaw_sigma_deg"])
            except (KeyError, ValueError):
                continue
            if lo <= t < hi:
                e.append(y)
                sig.append(sg)
        if e:
            out[name] = (sum(abs(a) <= 2.45 * b for a, b in zip(e, sig)) / len(e),
                         math.sqrt(sum(a * a for a in e) / len(e)),
                         math.sqrt(sum(b * b for b in sig) / len(sig)))
    return out


def err(s, who, m):
    return s.get("horizontal_error_after_loss", {}).get(f"{who}_{m}min_m")


def fmt(v):
    return "–" if v is None else f"{v:.0f}"


def mean(vals):
    vals = [v for v in vals if v is not None]
    return sum(vals) / len(vals) if vals else None


def main(dirs):
    flights = load(dirs)
    winds = sorted({w for w, _ in flights})
    total = {"open": [0, 0], "closed_mean": [0, 0], "closed_pair": [0, 0],
             "closed_mean_pooled": [0, 0]}
    print("| wind from | mode | checkpoint | PX4 (alone or same flight) | ianav or PX4 with ianav "
          "| no worse |")
    print("|---|---|---|---|---|---|")
    for w in winds:
        opens = flights.get((w, "open"), [])
        for m in CHECKPOINTS:
            a = [err(s, "ap", m) for s in opens]
            b = [err(s, "ianav", m) for s in opens]
            ok = [x is not None and y is not None and y <= x for x, y in zip(a, b)]
            total["open"][0] += sum(ok)
            total["open"][1] += len(ok)
            print(f"| {w:g}° | open | {m} min | {' / '.join(map(fmt, a))} | "
                  f"{' / '.join(map(fmt, b))} | {sum(ok)} of {len(ok)} |")
        closed = flights.get((w, "closed"), [])
        alone = flights.get((w, "alone"), [])
        for m in CHECKPOINTS:
            a = [err(s, "ap", m) for s in alone]
            b = [err(s, "ap", m) for s in closed]
            pairs = [x is not None and y is not None and y <= x for x, y in zip(a, b)]
            ma, mb = mean(a), mean(b)
            ok_mean = ma is not None and mb is not None and mb <= ma
            total["closed_pair"][0] += sum(pairs)
            total["closed_pair"][1] += len(pairs)
            total["closed_mean"][0] += int(ok_mean)
            total["closed_mean"][1] += 1
            # PX4 in the open flights ignores the daemon: more samples of PX4 alone.
            mp = mean(a + [err(s, "ap", m) for s in opens])
            ok_pooled = mp is not None and mb is not None and mb <= mp
            total["closed_mean_pooled"][0] += int(ok_pooled)
            total["closed_mean_pooled"][1] += 1
            print(f"| {w:g}° | closed | {m} min | {' / '.join(map(fmt, a))} (mean {fmt(ma)}; "
                  f"with the open flights' PX4 {fmt(mp)}) | "
                  f"{' / '.join(map(fmt, b))} (mean {fmt(mb)}) | pairs {sum(pairs)} of "
                  f"{len(pairs)}, mean {'yes' if ok_mean else 'no'}, pooled "
                  f"{'yes' if ok_pooled else 'no'} |")
    print()
    for k, (n, d) in total.items():
        print(f"- {k}: {n} of {d} checkpoints no worse")
    # Consistency per flight and pooled (weights: samples).
    fr, rat, n_all, frac_sum = [], [], 0, 0.0
    for (w, mode), ss in sorted(flights.items()):
        for s in ss:
            c = s.get("ianav_consistency")
            if not c:
                continue
            fr.append(c["fraction_err_le_2p45_hacc"])
            rat.append(c["hacc_rms_over_err_rms"])
            n_all += c["samples"]
            frac_sum += c["samples"] * c["fraction_err_le_2p45_hacc"]
    if fr:
        print(f"- ianav within 2.45 x hacc: {min(fr):.3f}–{max(fr):.3f} per flight, "
              f"{frac_sum / n_all:.3f} pooled ({len(fr)} flights); under 0.90: "
              f"{sum(f < 0.90 for f in fr)}")
        print(f"- hacc RMS / error RMS: {min(rat):.2f}–{max(rat):.2f} per flight, "
              f"median {sorted(rat)[len(rat) // 2]:.2f}; over 5: {sum(r > 5 for r in rat)}")
    hd = [(w, mode, s["_heading"]) for (w, mode), ss in sorted(flights.items()) for s in ss
          if s.get("_heading")]
    for w, mode, h in hd:
        parts = [f"{k} {v[0]:.2f} within 2.45 σ (error RMS {v[1]:.2f}°, σ RMS {v[2]:.2f}°)"
                 for k, v in h.items()]
        print(f"- heading, wind {w:g}° {mode}: " + "; ".join(parts))
    # PX4's own spread between flights of the same setup: what a comparison must beat.
    for (w, mode), ss in sorted(flights.items()):
        for m in CHECKPOINTS:
            vals = [v for v in (err(s, "ap", m) for s in ss) if v is not None]
            if len(vals) > 1 and mode == "alone" and m == 10:
                mu = sum(vals) / len(vals)
                sd = (sum((v - mu) ** 2 for v in vals) / (len(vals) - 1)) ** 0.5
                print(f"- PX4 alone, wind {w:g}°, 10 min: {' / '.join(map(fmt, vals))} m "
                      f"(mean {mu:.0f}, sample σ {sd:.0f})")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
