"""How well can laws of the current do on the UTFSM tests? (issue 26: the tanh model's held-out goal)

    python -m benchmarks.laws_ceiling [MODEL]

Laws fitted on the 18 tests at 0, 0.5 and 1 A, scored in-sample and at the held-out 0.25 and
0.75 A: the default (`laws="auto"`), every law quadratic (one parameter set per training
current: the most a law of the current can express with three currents), a saturating alpha,
and the two-step laws; each then refitted with every record weighted by its force scale
(1 / (max|F| sqrt(n)): the sum of squared NRMSE, the metric's own weighting) by SciPy's
least squares from the mrjax result. Reads $MRJAX_DATA or ../shared/data/utfsm. Measured
(kwok, 2-core CPU, seed 0): auto 12.75 % held-out (11.72 % in-sample), weighted 11.87 %;
quadratic 14.15 % (11.97 % in-sample), weighted 13.70 % (11.58 %); saturating alpha 14.34 %;
two-step 12.74 %, weighted 11.87 %.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

import mrjax
from mrjax.generalize import generalize

TRAIN = ("0A.txt", "0x5A.txt", "1A.txt")


def main(model: str = "kwok") -> None:
    root = Path(os.environ.get("MRJAX_DATA") or Path(__file__).resolve().parents[2]
                / "shared" / "data" / "utfsm")
    files = sorted(str(p) for p in root.glob("*.txt"))
    train = [f for f in files if f.split("Hz")[1] in TRAIN]
    test = [f for f in files if f not in train]
    tr, te = mrjax.data.load_batch(train), mrjax.data.load_batch(test)
    r = mrjax.fit(model, tr, key=0, progress=False)
    fmax = np.max(np.where(tr.mask, np.abs(tr.force), 0), axis=1)
    w = 1.0 / (fmax * np.sqrt(np.asarray(tr.mask).sum(1)))
    variants = [("auto", {}), ("quadratic", dict(laws="fixed", degrees=2)),
                ("saturating alpha", dict(laws={"alpha": "sat"})),
                ("two-step auto", dict(method="two-step"))]
    for label, kw in variants:
        t0 = time.perf_counter()
        gm = generalize(r, tr, key=0, **{"method": "joint", **kw})
        names = gm.param_names
        sizes = [len(gm.laws[n].coefficients) for n in names]
        c0 = np.concatenate([np.asarray(gm.laws[n].coefficients, float) for n in names])

        def with_coef(c, gm=gm, names=names, sizes=sizes):
            laws, o = {}, 0
            for n, s in zip(names, sizes):
                laws[n] = dataclasses.replace(gm.laws[n], coefficients=tuple(map(float, c[o:o + s])))
                o += s
            return dataclasses.replace(gm, laws=laws)

        def res(c, with_coef=with_coef):
            p = with_coef(c).predict(tr)
            return (np.where(tr.mask, p - np.asarray(tr.force), 0) * w[:, None]).ravel()

        sol = least_squares(res, c0, x_scale=np.maximum(np.abs(c0), 1e-3), max_nfev=200)
        g2 = with_coef(sol.x)
        e, e2 = gm.evaluate(te), g2.evaluate(te)
        print(f"{model} {label}: held-out median {100 * e['median_nrmse']:.2f} % (in-sample "
              f"{100 * gm.evaluate(tr)['median_nrmse']:.2f} %); weighted "
              f"{100 * e2['median_nrmse']:.2f} % (in-sample "
              f"{100 * g2.evaluate(tr)['median_nrmse']:.2f} %) [{time.perf_counter() - t0:.0f} s]",
              flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
