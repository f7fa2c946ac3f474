"""GPU figures (issue 25 and the fits): the posterior and the fits on an accelerator.

    python -m benchmarks.gpu DATA_DIR OUT.json [SECTION ...]

Sections: `fit` (tanh and modified Bouc-Wen `mrjax.fit` on the 30 UTFSM tests, cold then warm),
`tanh` (the tanh posterior on the 30 tests, 4 chains x 1,000 draws, records), `mbw` (the modified
Bouc-Wen posterior of one test, 10mm1Hz0x5A, AR(1) noise, on its view, 4 x 1,000). Each timing is
wall seconds in this process; the JSON holds every figure and the diagnostics (R-hat, ESS,
divergences, leapfrog steps per draw). Run on the device machine of `/work/.library/device`
(results in `benchmarks/gpu.json`).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import jax

import mrjax


def _diag(post) -> dict:
    d = post.posterior.diagnostics() if hasattr(post.posterior, "diagnostics") else {}
    return {k: d.get(k) for k in ("r_hat_max", "ess_bulk_min", "ess_tail_min", "divergences",
                                  "leapfrog_per_draw")}


def main(data: str, out: str, *sections: str) -> None:
    sections = sections or ("fit", "tanh", "mbw")
    files = sorted(str(p) for p in Path(data).glob("*.txt"))
    batch = mrjax.data.load_batch(files)
    doc: dict = {"device": str(jax.devices()[0]), "jax": jax.__version__,
                 "tests": batch.n_conditions}

    def save():
        Path(out).write_text(json.dumps(doc, indent=1, default=float))

    def timed(key, fn):
        t0 = time.perf_counter()
        r = fn()
        doc[key] = round(time.perf_counter() - t0, 2)
        print(key, doc[key], flush=True)
        save()
        return r

    if "fit" in sections:
        for name in ("kwok", "modified_bouc_wen"):
            timed(f"fit_{name}_cold_s", lambda: mrjax.fit(name, batch, seed=0))
            r = timed(f"fit_{name}_warm_s", lambda: mrjax.fit(name, batch, seed=0))
            doc[f"fit_{name}_median_nrmse_pct"] = float(100 * sorted(r.nrmse)[len(r.nrmse) // 2])
    if "tanh" in sections:
        res = mrjax.fit("kwok", batch, seed=0)
        post = timed("posterior_kwok_30_tests_s",
                     lambda: mrjax.posterior(res, batch, seed=0, noise="iid"))
        doc["posterior_kwok"] = _diag(post)
        save()
    if "mbw" in sections:
        one = mrjax.data.load_batch([f for f in files if f.endswith("10mm1Hz0x5A.txt")])
        res = mrjax.fit("modified_bouc_wen", one, seed=0)
        post = timed("posterior_mbw_one_test_s",
                     lambda: mrjax.posterior(res, one, seed=0, noise="ar1"))
        doc["posterior_mbw"] = _diag(post)
        save()


if __name__ == "__main__":
    main(*sys.argv[1:])
