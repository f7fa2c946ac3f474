"""The posterior of every test of the embedded grid (36 tanh tests at 0-2 A, iid noise), at the
defaults, cold, with its fit: wall time, convergence per test (R-hat, ESS, divergences, the
continuation rounds) and the coverage of the true parameters (eq 24-29) by the 95 % intervals.

    python benchmarks/posterior_grid.py [--out benchmarks/posterior_grid.json]

Runs the API of the checkout it is started from (the old keyword API too, for a before/after
on the same machine)."""

from __future__ import annotations

import argparse
import inspect
import json
import os
import platform
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None)
    ap.add_argument("--label", default="")
    a = ap.parse_args()
    t0 = time.perf_counter()
    import numpy as np

    import mrjax

    grid = mrjax.data.paper_grid()
    res = mrjax.fit("kwok", grid)
    t_fit = time.perf_counter() - t0
    new_api = "draws" not in inspect.signature(mrjax.posterior).parameters
    post = mrjax.posterior(res, grid) if new_api else mrjax.posterior(res, grid, seed=0)
    wall = time.perf_counter() - t0
    p = post.posterior
    truth = mrjax.data.paper_truth(grid)
    inside = []
    for j, n in enumerate(p.names):
        lo, hi = p.interval(n).T
        inside.append((truth[:, j] >= lo) & (truth[:, j] <= hi))
    inside = np.array(inside).T
    d = p._diag
    rhat = np.nanmax(np.stack([np.asarray(v).reshape(p.n_units, -1).max(axis=1)
                               for v in d["r_hat"].values()]), axis=0)
    ess = np.nanmin(np.stack([np.asarray(v).reshape(p.n_units, -1).min(axis=1)
                              for k in ("ess_bulk", "ess_tail") for v in d[k].values()]), axis=0)
    div = p.diverging.sum(axis=(1, 2))
    rounds = getattr(p, "rounds", None)
    import resource

    ru = resource.getrusage(resource.RUSAGE_SELF)
    doc = {"label": a.label, "cpu_s": ru.ru_utime + ru.ru_stime, "machine": f"{platform.machine()} {os.cpu_count()} cores",
           "load_1min": os.getloadavg()[0], "date": time.strftime("%Y-%m-%d %H:%M"),
           "wall_s": wall, "fit_s": t_fit, "tests": int(p.n_units),
           "coverage_95": float(inside.mean()),
           "rhat_max": float(np.nanmax(rhat)), "tests_rhat_over_1_01": int(np.sum(rhat > 1.01)),
           "ess_min": float(np.nanmin(ess)), "tests_ess_under_400": int(np.sum(ess < 400)),
           "divergences": int(div.sum()), "tests_with_divergences": int(np.sum(div > 0)),
           "continued_tests": None if rounds is None else int(np.sum(rounds > 0)),
           "rounds": None if rounds is None else [int(r) for r in rounds]}
    print(json.dumps(doc, indent=1))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(doc, f, indent=1)


if __name__ == "__main__":
    main()
