"""GPU figures (issue 25 and the fits): the posterior and the fits on an accelerator.

    python -m benchmarks.gpu DATA_DIR OUT.json [SECTION ...]

Sections: `fit` (tanh and modified Bouc-Wen `mrjax.fit` on the 30 UTFSM tests, cold then warm),
`tanh` (the tanh posterior on the 30 tests, 4 chains x 1,000 draws, records), `cost` (one
modified Bouc-Wen log-density gradient on the view of test 10mm1Hz0x5A, as the sampler computes
it, for 1, 4 and 120 positions at once: one chain, one test's chains, the 30 tests' chains),
`mbw` (the modified Bouc-Wen posterior of that test, AR(1) noise, on its view, 4 chains x
(`MBW_STEPS` warmup + `MBW_STEPS` draws)). The modified Bouc-Wen sections read the fit from
`benchmarks.posterior`'s cache (`MRJAX_BENCH_CACHE`) where it is there. Each timing is wall
seconds in this process; the JSON holds every figure and the diagnostics (R-hat, ESS,
divergences, leapfrog steps per draw). Run on the device machine of `/work/.library/device`
(results in `benchmarks/gpu.json`).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import mrjax

#: Warmup steps and draws per chain of the `mbw` section.
MBW_STEPS = 200


def _diag(post) -> dict:
    d = post.posterior.diagnostics() if hasattr(post.posterior, "diagnostics") else {}
    return {k: d.get(k) for k in ("r_hat_max", "ess_bulk_min", "ess_tail_min", "divergences",
                                  "leapfrog_per_draw")}


def main(data: str, out: str, *sections: str) -> None:
    sections = sections or ("fit", "tanh", "cost", "mbw")
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
            timed(f"fit_{name}_cold_s", lambda: mrjax.fit(name, batch, key=0))
            r = timed(f"fit_{name}_warm_s", lambda: mrjax.fit(name, batch, key=0))
            doc[f"fit_{name}_median_nrmse_pct"] = float(100 * sorted(r.nrmse)[len(r.nrmse) // 2])
    if "tanh" in sections:
        res = mrjax.fit("kwok", batch, key=0)
        post = timed("posterior_kwok_30_tests_s",
                     lambda: mrjax.posterior(res, batch, key=0, noise="iid"))
        doc["posterior_kwok"] = _diag(post)
        save()
    if "cost" in sections or "mbw" in sections:
        from benchmarks.posterior import cached_fit

        res, full, _ = cached_fit("modified_bouc_wen")
        i = list(full.labels).index("10mm1Hz0x5A")
        res, one = res.subset([i]), full.subset([i])
    if "cost" in sections:
        doc["gradient_ms"] = mbw_gradient_cost(res, one)
        save()
    if "mbw" in sections:
        sampler = mrjax.bayes.Sampler(draws=MBW_STEPS, warmup=MBW_STEPS, chains=4)
        doc["posterior_mbw_steps"] = f"4 x ({MBW_STEPS} + {MBW_STEPS})"
        post = timed("posterior_mbw_one_test_s",
                      lambda: mrjax.posterior(res, one, key=0, noise="ar1", sampler=sampler))
        doc["posterior_mbw"] = _diag(post)
        doc["posterior_mbw_timings_s"] = dict(post.posterior.timings)
        save()


def mbw_gradient_cost(res, one) -> dict[str, float]:
    """Warm median milliseconds of one force evaluation and one forward-mode Jacobian of the
    residuals (the sampler's gradient) of the modified Bouc-Wen model on the view of one test,
    for B = 1, 4, 120 parameter vectors at once (vmapped)."""
    from benchmarks.posterior import per_call_s

    view = mrjax.data.swarm_view(one)
    b = view.batch
    model = mrjax.models.resolve_model(res.model, res.theta, b.xdot, b.dt, b.mask)
    x, xd, dt, f = b.x[0], b.xdot[0], b.dt[0], b.force[0]
    th0 = jnp.asarray(res.theta[0])
    resid = lambda th: model.force(th, x, xd, dt) - f
    out = {}
    for B in (1, 4, 120):
        T = th0 * (1 + 1e-3 * jnp.linspace(0, 1, B))[:, None]
        for name, fn in (("force", lambda t: jnp.sum(resid(t))),
                         ("jacobian", lambda t: jnp.sum(jax.jacfwd(resid)(t)))):
            ms = 1e3 * per_call_s(lambda T, fn=fn: jax.vmap(fn)(T).sum(), T, 10)
            out[f"{name}_B{B}"] = round(ms, 3)
            print(name, B, out[f"{name}_B{B}"], "ms", flush=True)
    return out


if __name__ == "__main__":
    main(*sys.argv[1:])
