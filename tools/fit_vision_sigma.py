#!/usr/bin/env python3
"""Fit the fused visual position's error growth and check it by NEES (docs/FUSION.md).

Reads `ianav-sim mc` run files (one or more batch directories, each with `runs/run_*.csv`),
takes one visual system's horizontal error against the distance flown, fits the per-axis
variance model of `FusionConfig`

    sigma^2(d) = sigma0^2 + q d + (k d)^2

by weighted least squares on the mean squared error (a horizontal error of two independent axes of
variance sigma^2 has E|e|^2 = 2 sigma^2), with q and k^2 kept non-negative, and prints for
every directory the NEES |e|^2 / sigma^2(d) (chi-square with 2 degrees of freedom: mean 2,
95 % below 5.99) of a model given on the command line or of the fit.

    tools/fit_vision_sigma.py --fit docs/results/vision-mc-s2-mx docs/results/vision-mc-s1-mx
    tools/fit_vision_sigma.py --model 12.4,0,0.0024 docs/results/vision-mc-s1-mx

With --published, the directories are `ianav-sim run --fused` outputs instead: the NEES of the
published (fused) horizontal position against its own published covariance after the GNSS
loss, from `navigation.csv` (error norm and the north and east sigmas, taken as one per-axis
variance, their mean square):

    tools/fit_vision_sigma.py --published out/seed1 out/seed2 ...

The run directories are large (navigation.csv at 10 Hz); --extract OUTDIR writes, per run
directory, the columns this check reads at 1 Hz (`OUTDIR/<run name>.csv`), small enough to
commit, and --published also reads such files:

    tools/fit_vision_sigma.py --extract docs/results/fused-s2-mx/gap out/gap_*
    tools/fit_vision_sigma.py --published docs/results/fused-s2-mx/gap/*.csv

Only the standard library: it runs wherever the run files are.
"""

import argparse
import glob
import math
import os
import sys

CHI2_2_95 = 5.991
# The two-sided 95 % band of chi-square with 2 degrees of freedom (2.5 % and 97.5 % quantiles).
CHI2_2_BAND = (0.05064, 7.378)


def load(path, system):
    """(distance_m, hor_m) of `system` in one run file, finite rows only."""
    current = "ins"
    rows = []
    with open(path) as f:
        for line in f:
            if line.startswith("# system = "):
                current = line.split("=", 1)[1].strip()
                continue
            if not line[:1].isdigit() or current != system:
                continue
            v = line.strip().split(",")
            hor, dist = float(v[6]), float(v[8])
            if math.isfinite(hor) and math.isfinite(dist):
                rows.append((dist, hor))
    return rows


def runs_of(directory, system, seeds):
    out = []
    for p in sorted(glob.glob(os.path.join(directory, "runs", "run_*.csv"))):
        seed = int(os.path.basename(p)[4:-4])
        if seeds and not (seeds[0] <= seed <= seeds[1]):
            continue
        rows = load(p, system)
        if rows:
            out.append((seed, rows))
    return out


def solve3(a, b):
    """Solve a 3x3 linear system by Cramer's rule."""

    def det(m):
        return (
            m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
        )

    d = det(a)
    out = []
    for i in range(3):
        m = [row[:] for row in a]
        for r in range(3):
            m[r][i] = b[r]
        out.append(det(m) / d)
    return out


def fit(samples):
    """Least squares of e^2/2 on [1, d, d^2], weighted by 1/sigma^4 (the variance of e^2/2
    is sigma^4 for two Gaussian axes) by iterated reweighting from equal weights; a negative q
    or k^2 is refitted without it."""

    def lsq(cols, model):
        a = [[0.0] * 3 for _ in range(3)]
        b = [0.0] * 3
        for d, e in samples:
            w = 1.0 if model is None else 1.0 / variance(model, d) ** 2
            x = [1.0, d, d * d]
            y = e * e / 2.0
            for i in cols:
                b[i] += w * x[i] * y
                for j in cols:
                    a[i][j] += w * x[i] * x[j]
        for i in range(3):
            if i not in cols:
                a[i][i] = 1.0
        return solve3(a, b)

    def nonneg(model):
        for cols in ([0, 1, 2], [0, 2], [0, 1], [0]):
            c = lsq(cols, model)
            if all(c[i] >= 0.0 for i in cols):
                return math.sqrt(c[0]), c[1], math.sqrt(c[2])
        raise SystemExit("no non-negative fit")

    model = None
    for _ in range(20):
        model = nonneg(model)
    return model


def variance(model, d):
    s0, q, k = model
    return s0 * s0 + q * d + (k * d) ** 2


def nees_report(name, runs, model):
    values = []
    per_run = []
    for seed, rows in runs:
        v = [e * e / variance(model, d) for d, e in rows]
        values += v
        per_run.append((seed, sum(v) / len(v)))
    values.sort()
    mean = sum(values) / len(values)
    inside = sum(1 for v in values if v <= CHI2_2_95) / len(values)
    worst = max(per_run, key=lambda r: r[1])
    print(
        f"{name}: {len(runs)} runs, {len(values)} samples: NEES mean {mean:.2f} (2 expected), "
        f"{100 * inside:.1f} % within {CHI2_2_95} (95 % expected), "
        f"worst run seed {worst[0]} mean {worst[1]:.2f}"
    )


EXTRACT_COLUMNS = ["t_s", "gnss_denied", "err_hor_m", "sigma_n_m", "sigma_e_m"]


def extract(out_dir, directories):
    """The columns `published_nees` reads, at 1 Hz, one file per run directory."""
    os.makedirs(out_dir, exist_ok=True)
    for d in directories:
        src = os.path.join(d, "navigation.csv")
        dst = os.path.join(out_dir, os.path.basename(os.path.normpath(d)) + ".csv")
        with open(src) as f, open(dst, "w") as out:
            header = f.readline().strip().split(",")
            col = [header.index(c) for c in EXTRACT_COLUMNS]
            out.write(",".join(EXTRACT_COLUMNS) + "\n")
            next_t = -math.inf
            for line in f:
                v = line.strip().split(",")
                t = float(v[col[0]])
                if t + 1e-6 < next_t:
                    continue
                next_t = math.floor(t + 1e-6) + 1.0
                out.write(",".join(v[i] for i in col) + "\n")
        print(f"{src} -> {dst}")


def published_nees(directories):
    """NEES of the published position after the loss, per run and over all runs."""
    values = []
    for d in directories:
        path = d if d.endswith(".csv") else os.path.join(d, "navigation.csv")
        with open(path) as f:
            header = f.readline().strip().split(",")
            col = {name: i for i, name in enumerate(header)}
            run = []
            for line in f:
                v = line.strip().split(",")
                if v[col["gnss_denied"]] != "1":
                    continue
                e = float(v[col["err_hor_m"]])
                var = 0.5 * (float(v[col["sigma_n_m"]]) ** 2 + float(v[col["sigma_e_m"]]) ** 2)
                if math.isfinite(e) and var > 0.0:
                    run.append(e * e / var)
        if not run:
            sys.exit(f"{path}: no denied sample")
        inside = sum(1 for x in run if x <= CHI2_2_95) / len(run)
        print(f"{d}: {len(run)} samples, NEES mean {sum(run) / len(run):.2f}, "
              f"{100 * inside:.1f} % within {CHI2_2_95}, "
              f"{100 * in_band(run):.1f} % in [{CHI2_2_BAND[0]}, {CHI2_2_BAND[1]}]")
        values += run
    inside = sum(1 for x in values if x <= CHI2_2_95) / len(values)
    print(f"all {len(directories)} runs: {len(values)} samples, NEES mean "
          f"{sum(values) / len(values):.2f}, {100 * inside:.1f} % within {CHI2_2_95}, "
          f"{100 * in_band(values):.1f} % in [{CHI2_2_BAND[0]}, {CHI2_2_BAND[1]}]")


def in_band(values):
    """The share of `values` inside the two-sided 95 % band."""
    return sum(1 for x in values if CHI2_2_BAND[0] <= x <= CHI2_2_BAND[1]) / len(values)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dirs", nargs="+", help="mc batch directories")
    ap.add_argument("--system", default="ia-vns", help="visual system (run-file section)")
    ap.add_argument("--fit", action="store_true", help="fit the model on all directories")
    ap.add_argument("--model", help="sigma0_m,q_m2_per_m,k_per_m to check instead")
    ap.add_argument("--seeds", default="1-100", help="seed range used, inclusive (A-B)")
    ap.add_argument("--published", action="store_true",
                    help="the directories are `ianav-sim run --fused` outputs (or --extract files)")
    ap.add_argument("--extract", metavar="OUTDIR",
                    help="write the --published columns of each run directory at 1 Hz to OUTDIR")
    args = ap.parse_args()
    if args.extract:
        extract(args.extract, args.dirs)
        return
    if args.published:
        published_nees(args.dirs)
        return
    lo, hi = (int(x) for x in args.seeds.split("-"))
    batches = [(d, runs_of(d, args.system, (lo, hi))) for d in args.dirs]
    for d, runs in batches:
        if not runs:
            sys.exit(f"{d}: no run with a '{args.system}' section in seeds {args.seeds}")
    if args.fit:
        samples = [s for _, runs in batches for _, rows in runs for s in rows]
        model = fit(samples)
        print(
            f"fit over {sum(len(r) for _, r in batches)} runs, {len(samples)} samples: "
            f"sigma0_m = {model[0]:.2f}, q_m2_per_m = {model[1]:.4g}, k_per_m = {model[2]:.5f}"
        )
    elif args.model:
        model = tuple(float(x) for x in args.model.split(","))
    else:
        sys.exit("give --fit or --model")
    for d, runs in batches:
        nees_report(d, runs, model)


if __name__ == "__main__":
    main()
