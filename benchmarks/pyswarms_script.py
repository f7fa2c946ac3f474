"""A user's pyswarms script: fit the tanh model (Kwok et al. 2006) to every test in a CSV file.

    python benchmarks/pyswarms_script.py grid.csv --out DIR

Reads the long-format CSV that mrjax reads (`condition, current_A, frequency_Hz, amplitude_m,
time_s, displacement_m, velocity_m_s, force_N`), runs pyswarms' `GlobalBestPSO` (50 particles,
100 iterations, w = 0.65, c1 = c2 = 2, mrjax's default bounds) on each condition one after the
other, and writes `DIR/fit.csv` (parameters and RMS per condition). Used by
`python -m benchmarks` as the cold-process baseline of `mrjax fit`.
"""

import argparse
import csv
import logging
import os
from collections import OrderedDict

import numpy as np
from pyswarms.single import GlobalBestPSO

NAMES = ("c", "k", "alpha", "beta", "delta", "f0")
LOWER = np.array([0.0, -100000.0, 0.0, 1.0, 0.0, -1000.0])
UPPER = np.array([100000.0, 100000.0, 2500.0, 10000.0, 5.0, 1000.0])


def load(path):
    tests = OrderedDict()
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            d = tests.setdefault(
                row["condition"], {"current": float(row["current_A"]), "x": [], "v": [], "F": []}
            )
            d["x"].append(float(row["displacement_m"]))
            d["v"].append(float(row["velocity_m_s"]))
            d["F"].append(float(row["force_N"]))
    return {
        k: {"current": d["current"], **{c: np.asarray(d[c]) for c in ("x", "v", "F")}}
        for k, d in tests.items()
    }


def fitness(x, v, F):
    sx = np.sign(x)

    def f(P):
        c, k, a, b, d, f0 = (P[:, j : j + 1] for j in range(6))
        pred = c * v + k * x + a * np.tanh(b * v + d * sx) + f0
        return np.sqrt(np.mean((pred - F) ** 2, axis=1))

    return f


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("csv")
    ap.add_argument("--out", default="pyswarms-out")
    ap.add_argument("--iters", type=int, default=100)
    ap.add_argument("--particles", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    logging.getLogger("pyswarms").setLevel(logging.WARNING)
    np.random.seed(args.seed)
    rows = []
    for label, d in load(args.csv).items():
        opt = GlobalBestPSO(
            n_particles=args.particles,
            dimensions=6,
            options={"c1": 2.0, "c2": 2.0, "w": 0.65},
            bounds=(LOWER, UPPER),
            bh_strategy="nearest",
        )
        cost, pos = opt.optimize(fitness(d["x"], d["v"], d["F"]), iters=args.iters, verbose=False)
        rows.append([label, d["current"], cost, *pos])
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "fit.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["label", "current_A", "rms_N", *NAMES])
        w.writerows(rows)
    print(f"fitted {len(rows)} conditions; median RMS {np.median([r[2] for r in rows]):.2f} N")


if __name__ == "__main__":
    main()
