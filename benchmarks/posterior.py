"""The posterior (issue 25): calibration, speed, and the record against the swarm's view.

    nice -n 10 python -m benchmarks.posterior calibration [--records 50]
    nice -n 10 python -m benchmarks.posterior speed [--mbw-all]
    nice -n 10 python -m benchmarks.posterior views
    python -m benchmarks.posterior mbw-tests [--draws 200 --jobs 2]   # MBW, each UTFSM test
    nice -n 10 python -m benchmarks.posterior kernels [--model kwok --noise ar1]  # NUTS / ChEES
    python -m benchmarks.posterior render          # posterior.md from posterior.json

1. **Calibration** (known answer, in one process): `--records` short sine records (1-2 Hz,
   4-12 mm, 1.25 cycles at 160 samples per cycle) simulated from known parameters (tanh: the
   paper's laws at a random current in 0-1.5 A; Dahl, a dynamic model: the test set's
   parameters scaled by +-30 % at random), with Gaussian force noise of 2 % of max|F|,
   independent or AR(1) with rho = 0.9 (the same marginal). Each set is fitted (`mrjax.fit`)
   and sampled (`mrjax.posterior`, 4 chains x 1000 draws after 1000 warmup steps); the table
   gives the share of (record, parameter) pairs whose 95 % interval covers the truth, worst
   R-hat, smallest ESS, divergences: iid noise with `noise="iid"`, AR(1) noise with
   `noise="ar1"` (calibrated) and with `noise="iid"` (the intervals collapse).
2. **Speed** (each case a cold process: imports, data, compilation included; the fit is read
   from a cache and timed apart): tanh on the 30 UTFSM tests, 4 chains x 1000 draws (iid and
   AR(1)); modified Bouc-Wen on one UTFSM test (and, with `--mbw-all`, the 30); leapfrog
   steps per draw; and the cost of one gradient of the log-likelihood against one force
   evaluation (warm medians).
3. **Modified Bouc-Wen on each UTFSM test** (`mbw-tests`): one cold process per test
   (AR(1), the view, 4 chains x (`--draws` + `--draws`)), `--jobs` at a time.
4. **Record or view**: the same posteriors on the full records and on the swarm's view
   (cost, and the ratio of the 95 % interval widths).

5. **Kernels** (`kernels`): the posterior of every UTFSM test in one call, cold, with NUTS
   (each chain on its own, 4 x (500 + 1000)) and with ChEES-HMC (every chain of every test in
   lockstep, 8 x (150 + 300)), continuations included: wall, gradient evaluations, R-hat,
   ESS, ESS per second, divergences.

Writes `benchmarks/posterior.json` (sections merged) and `benchmarks/posterior.md`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
OUT_JSON = HERE / "posterior.json"
OUT_MD = HERE / "posterior.md"
#: Samples per excitation cycle of the calibration records.
SAMPLES_PER_CYCLE = 160
#: Excitation cycles of each calibration record.
CYCLES = 2.0
#: How the chains of a speed row start (rows measured before the mode search carry their own).
START = "mode"
#: Where the fits of the UTFSM tests are kept between cases (not in the repository: data-derived).
CACHE = Path(os.environ.get("MRJAX_BENCH_CACHE", "/tmp/mrjax-bench-posterior"))


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def utfsm() -> Path:
    d = os.environ.get("MRJAX_DATA") or str(HERE.parent.parent / "shared" / "data" / "utfsm")
    if not Path(d).is_dir():
        d = "/work/shared/data/utfsm"
    return Path(d)


def mbw_tests(draws: int, warmup: int | None, jobs: int,
              limit_s: float = 900.0) -> list[dict[str, Any]]:
    """The modified Bouc-Wen posterior of each UTFSM test in its own cold process (AR(1), the
    view, 4 chains x (`warmup` + `draws`), `warmup` None: the default), `jobs` processes at a
    time, one CPU device each; a test not done within `limit_s` is reported without a row."""
    res, _, _ = cached_fit("modified_bouc_wen")
    todo, running, rows = list(res.labels), [], []
    env = dict(os.environ, MRJAX_CACHE_DIR="off", JAX_PLATFORMS="cpu")
    while todo or running:
        while todo and len(running) < jobs:
            lab = todo.pop(0)
            argv = [sys.executable, "-m", "benchmarks.posterior", "case", "--model",
                    "modified_bouc_wen", "--tests", lab, "--noise", "ar1", "--draws",
                    str(draws)] + ([] if warmup is None else ["--warmup", str(warmup)])
            p = subprocess.Popen(argv, cwd=HERE.parent, env=env, stdout=subprocess.PIPE,
                                 stderr=subprocess.DEVNULL, text=True)
            running.append((lab, p, time.perf_counter(), os.getloadavg()[0]))
        time.sleep(2.0)
        for item in list(running):
            lab, p, t0, load0 = item
            late = time.perf_counter() - t0 > limit_s
            if p.poll() is None and not late:
                continue
            if late and p.poll() is None:
                p.kill()
            out = p.communicate()[0]
            lines = out.strip().splitlines()
            row = json.loads(lines[-1]) if p.returncode == 0 and lines else None
            rows.append({"label": lab, "rc": p.returncode, "load": [load0, os.getloadavg()[0]],
                         "row": row})
            log(f"{lab}: " + (f"{row['posterior_s']:.0f} s" if row else "not finished"))
            running.remove(item)
    return rows


# ------------------------------------------------------------------------------ one cold case
def cached_fit(model: str):
    """The UTFSM fit of `model` (all 30 tests, seed 0), from the cache or fitted now."""
    import mrjax

    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / f"fit_{model}.json"
    batch = mrjax.data.as_batch(utfsm())
    if path.exists():
        res = mrjax.FitResult.from_state(json.loads(path.read_text()), mrjax.models.get(model))
        return res, batch, 0.0
    t0 = time.perf_counter()
    res = mrjax.fit(model, batch, key=0)
    path.write_text(json.dumps(res.to_state()))
    return res, batch, time.perf_counter() - t0


def run_case(a: argparse.Namespace) -> dict[str, Any]:
    """One posterior in this (fresh) process: timings, diagnostics, interval widths."""
    t_start = time.perf_counter()
    import jax

    import mrjax

    t_import = time.perf_counter() - t_start
    res, batch, t_fit = cached_fit(a.model)
    if a.tests != "all":
        idx = [list(batch.labels).index(s) for s in a.tests.split(",")]
        res, batch = res.subset(idx), batch.subset(idx)
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        kernel = mrjax.bayes.ChEES() if a.kernel == "chees" else mrjax.bayes.NUTS()
        sampler = mrjax.Sampler(draws=a.draws, chains=a.chains, warmup=a.warmup, kernel=kernel)
        tp = mrjax.posterior(res, batch, sampler=sampler, noise=a.noise,
                             likelihood_data=a.data, key=0)
    wall = time.perf_counter() - t0
    post = tp.posterior
    iv = {n: post.interval(n).tolist() for n in post.names}
    return {"model": a.model, "tests": a.tests, "n_tests": len(post.labels), "noise": a.noise,
            "data": tp.data, "kernel": a.kernel, "draws": tp.posterior.sampler.draws,
            "chains": tp.posterior.sampler.chains, "warmup": tp.posterior.sampler.warmup,
            "gradient_evaluations": int(np.sum(post.n_steps) + np.sum(post.warmup_steps)),
            "rounds": post.rounds.tolist(), "cpu_devices": jax.local_device_count(),
            "target_accept": tp.posterior.sampler.target_accept,
            "import_s": t_import, "fit_s": t_fit, "posterior_s": wall,
            "process_s": time.perf_counter() - t_start, "diagnostics": post.diagnostics(),
            "scored_samples": [int(n) for n in tp.n_scored], "labels": list(post.labels),
            "intervals": iv, "warnings": [str(w.message) for w in caught]}


def cold(**kw) -> dict[str, Any]:
    """:func:`run_case` in a fresh process (`nice`d like its parent)."""
    argv = [sys.executable, "-m", "benchmarks.posterior", "case"]
    for k, v in kw.items():
        argv += [f"--{k}", str(v)]
    log("case " + " ".join(argv[4:]))
    env = dict(os.environ, MRJAX_CACHE_DIR="off", JAX_PLATFORMS="cpu")
    load0 = os.getloadavg()[0]
    p = subprocess.run(argv, cwd=HERE.parent, env=env, capture_output=True, text=True)
    if p.returncode:
        raise RuntimeError(p.stderr[-3000:])
    out = json.loads(p.stdout.strip().splitlines()[-1])
    out["load"] = [load0, os.getloadavg()[0]]
    log(f"  {out['posterior_s']:.1f} s, {out['diagnostics']['leapfrog_per_draw']:.1f} "
        f"leapfrog/draw, R-hat {out['diagnostics']['r_hat_max']:.3f}")
    return out


def _child_cpu() -> float:
    """CPU seconds (user + system) of this process's finished children: a load-independent
    measure of a case's work (a shared machine stretches its wall time)."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def cold_cli(model: str, tests: str = "all", extra: tuple[str, ...] = ()) -> dict[str, Any]:
    """`mrjax fit DATA --model M --posterior --no-plots` in a fresh process (imports, loading,
    fit and posterior, compilation included; no compilation cache): wall time, the load
    average before and after, the posterior's own time and diagnostics from fit.json."""
    import shutil
    import tempfile

    tmp = Path(tempfile.mkdtemp(prefix="mrjax-post-cli-"))
    data = [str(utfsm())] if tests == "all" else [str(utfsm() / f"{t}.txt")
                                                  for t in tests.split(",")]
    argv = [str(Path(sys.executable).with_name("mrjax")), "fit", *data, "--model", model, "--posterior",
            "--no-plots", "--out", str(tmp / "out"), *extra]
    log("cli " + " ".join(argv[1:]))
    env = dict(os.environ, MRJAX_CACHE_DIR="off", JAX_PLATFORMS="cpu")
    load0, t0, cpu0 = os.getloadavg()[0], time.perf_counter(), _child_cpu()
    p = subprocess.run(argv, cwd=HERE.parent, env=env, capture_output=True, text=True)
    wall, load1, cpu = time.perf_counter() - t0, os.getloadavg()[0], _child_cpu() - cpu0
    try:
        if p.returncode:
            raise RuntimeError(p.stderr[-3000:])
        post = json.loads((tmp / "out" / "fit.json").read_text())["posterior"]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out = {"model": model, "tests": tests, "command": "mrjax fit DATA --model " + model +
           " --posterior --no-plots --out DIR " + " ".join(extra), "wall_s": wall,
           "posterior_s": float(post["timings_s"].get("sample", float("nan"))), "cpu_s": cpu,
           "load": [load0, load1], "diagnostics": post["diagnostics"],
           "draws": post["draws"], "chains": post["chains"], "warmup": post["warmup"],
           "noise": post["noise"], "data": post["likelihood_data"]}
    log(f"  {wall:.1f} s wall ({out['posterior_s']:.1f} s sampling), {cpu:.1f} s CPU, load "
        f"{load0:.1f} -> {load1:.1f}")
    return out


# ------------------------------------------------------------------------------ gradient cost
def per_call_s(fn: Callable, theta: Any, n: int) -> float:
    """Warm median seconds per call of `fn(theta) -> scalar`, `n` calls inside one compiled
    loop (no dispatch cost; each call's argument nudged so none is hoisted out)."""
    import jax

    many = jax.jit(lambda th: jax.lax.fori_loop(
        0, n, lambda i, acc: acc + fn(th * (1.0 + 1e-12 * i)), 0.0))
    jax.block_until_ready(many(theta))
    ts = []
    for _ in range(5):
        t0 = time.perf_counter()
        jax.block_until_ready(many(theta))
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)) / n


def gradient_cost() -> list[dict[str, Any]]:
    """Warm median time of one force evaluation and of one value-and-gradient of the Gaussian
    log-likelihood, on one UTFSM test (record and view)."""
    import jax
    import jax.numpy as jnp

    import mrjax
    from mrjax.bayes import block_loglik
    from mrjax.objective import ConditionResidual

    rows = []
    for model_name, data in (("kwok", "record"), ("kwok", "view"),
                             ("modified_bouc_wen", "record"), ("modified_bouc_wen", "view")):
        res, batch, _ = cached_fit(model_name)
        i = list(batch.labels).index("10mm1Hz1A")
        res, batch = res.subset([i]), batch.subset([i])
        mask = batch.mask
        if data == "view":
            v = mrjax.data.swarm_view(batch)
            batch, mask = v.batch, v.mask
        theta = jnp.asarray(res.theta[0])
        model = mrjax.models.resolve_model(res.model, res.theta, batch.xdot, batch.dt, batch.mask)
        unit = (batch.x[0], batch.xdot[0], batch.dt[0], batch.force[0], jnp.asarray(mask)[0])
        resid = ConditionResidual(model, blocks=True)
        force = lambda th: jnp.sum(model.force(th, unit[0], unit[1], unit[2]))
        r_fn = lambda th: resid(th, unit)[0][0]
        ll = lambda r: block_loglik(r, unit[4][None], jnp.zeros(1))
        vg = jax.value_and_grad(lambda th: ll(r_fn(th)))
        rev = lambda th: (lambda v, g: v + jnp.sum(g))(*vg(th))

        def fwd(th):  # the sampler's forward mode: values and Jacobian in one pass, transposed
            J, r = jax.jacfwd(lambda t: (r_fn(t),) * 2, has_aux=True)(th)
            v, g = jax.value_and_grad(ll)(r)
            return v + jnp.sum(jnp.tensordot(g, J, axes=2))

        n = 20 if model.dynamic and data == "record" else 200

        tf, tg, tfw = (per_call_s(f, theta, n) for f in (force, rev, fwd))
        sub, scheme = model.integration(theta, batch.xdot, batch.dt) if model.dynamic else \
            (1, "-")
        rows.append({"model": model_name, "data": data, "samples": int(np.sum(mask)),
                     "integration": f"{scheme} x{sub}" if model.dynamic else "-",
                     "force_ms": 1e3 * tf, "grad_ms": 1e3 * tg, "grad_fwd_ms": 1e3 * tfw,
                     "ratio": tg / tf, "ratio_fwd": tfw / tf})
        log(f"cost {model_name} {data}: force {1e3 * tf:.3f} ms, gradient {1e3 * tg:.3f} ms "
            f"(reverse), {1e3 * tfw:.3f} ms (forward)")
    return rows


# ------------------------------------------------------------------------------ calibration
def simulate_set(model: str, n: int, noise: str, seed: int):
    """`(batch, truth (n, P))`: n short sine records of `model`, 2 % force noise, iid or
    AR(1) rho = 0.9."""
    import mrjax
    from mrjax.data import make_batch, paper_parameters, simulate

    rng = np.random.default_rng(seed)
    m = mrjax.models.get(model)
    conds, truth = [], []
    base = m.params(c=1500.0, k=1500.0, alpha=500.0, rho=2000.0, f0=-30.0) \
        if model == "dahl" else None
    for r in range(n):
        if model == "kwok":
            th = paper_parameters(rng.uniform(0.0, 1.5))
        else:
            th = base * rng.uniform(0.7, 1.3, m.n_params)
        f, amp = rng.choice([1.0, 2.0]), rng.uniform(0.004, 0.012)
        clean = simulate(model, th, frequency=f, amplitude=amp, sample_rate=SAMPLES_PER_CYCLE * f,
                         cycles=CYCLES, label=f"r{r:02d}")
        sd = 0.02 * float(np.max(np.abs(clean.force)))
        e = rng.standard_normal(clean.force.size)
        if noise == "ar1":
            for k in range(1, e.size):
                e[k] = 0.9 * e[k - 1] + np.sqrt(1 - 0.81) * e[k]
        conds.append(dataclasses.replace(clean, force=clean.force + sd * e))
        truth.append(th)
    return make_batch(conds), np.array(truth)


def calibration(records: int, draws: int, models: list[str]) -> list[dict[str, Any]]:
    """Coverage of the 95 % intervals on simulated records (see the module docstring); each
    set's row is merged into posterior.json as soon as it is measured."""
    import mrjax
    from mrjax.bayes import Sampler

    doc = json.loads(OUT_JSON.read_text()) if OUT_JSON.exists() else {}
    rows = [r for r in doc.get("calibration", []) if r["model"] not in models]
    for model in models:
        # the dynamic model's records are short sequential integrations: one vmapped batch
        # of all chains amortises the integrator's per-step cost (see Sampler.vectorize)
        # (the warmup, the gradient and the target acceptance: the defaults, Sampler.for_model)
        sampler = Sampler(draws=draws, chains=4, vectorize=model == "dahl")
        for data_noise, fit_noise in (("iid", "iid"), ("ar1", "ar1"), ("ar1", "iid")):
            batch, truth = simulate_set(model, records, data_noise, seed=1)
            t0 = time.perf_counter()
            res = mrjax.fit(model, batch, key=0)
            t_fit = time.perf_counter() - t0
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                tp = mrjax.posterior(res, batch, sampler=sampler, noise=fit_noise, key=0)
            t_post = time.perf_counter() - t0
            post = tp.posterior
            cov = np.array([[lo <= t <= hi for (lo, hi), t in
                             zip(post.interval(n), truth[:, j])]
                            for j, n in enumerate(post.names)]).T  # (records, P)
            jac = np.asarray(res.ci95, float)
            jcov = (jac[..., 0] <= truth) & (truth <= jac[..., 1])
            d = post.diagnostics()
            rows.append({"model": model, "data_noise": data_noise, "likelihood": fit_noise,
                         "records": records, "samples_per_record": int(np.median(
                             np.asarray(batch.n_samples))), "coverage": float(cov.mean()),
                         "coverage_per_param": dict(zip(post.names, cov.mean(axis=0).tolist())),
                         "jacobian_coverage": float(np.mean(jcov)),
                         "r_hat_max": d["r_hat_max"], "ess_bulk_min": d["ess_bulk_min"],
                         "ess_tail_min": d["ess_tail_min"], "divergences": d["divergences"],
                         "leapfrog_per_draw": d["leapfrog_per_draw"], "fit_s": t_fit,
                         "target_accept": post.sampler.target_accept,
                         "warmup": post.sampler.warmup,
                         "posterior_s": t_post})
            log(f"calibration {model} {data_noise}/{fit_noise}: coverage {cov.mean():.3f} "
                f"(Jacobian {np.mean(jcov):.3f}), R-hat {d['r_hat_max']:.4f}, "
                f"{d['divergences']} div, {t_post:.0f} s")
            merge("calibration", rows)
    return rows


# ------------------------------------------------------------------------------ sections
def merge(section: str, value: Any) -> None:
    doc = json.loads(OUT_JSON.read_text()) if OUT_JSON.exists() else {}
    doc[section] = value
    doc.setdefault("machine", {})[section] = machine()
    OUT_JSON.write_text(json.dumps(doc, indent=1))
    _write_md(render(doc))


def machine() -> dict[str, Any]:
    import platform

    try:
        cpu = next(ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo")
                   if ln.startswith("model name"))
    except (OSError, StopIteration):
        cpu = platform.processor()
    return {"cpu": cpu, "cores": os.cpu_count(), "loadavg": list(os.getloadavg()),
            "date": time.strftime("%Y-%m-%d %H:%M")}


def _md(head: list[str], rows: list[list[Any]]) -> str:
    def cell(v):
        if isinstance(v, float):
            return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"
        return str(v)

    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(cell(v) for v in r) + " |" for r in rows]
    return "\n".join(out)


def _width_ratio(a: dict, b: dict) -> float:
    """Median over parameters and tests of the 95 % interval width of `a` over that of `b`."""
    r = []
    for n in a["intervals"]:
        wa = np.ptp(np.asarray(a["intervals"][n]), axis=1)
        wb = np.ptp(np.asarray(b["intervals"][n]), axis=1)
        ok = (wb > 0) & np.isfinite(wa) & np.isfinite(wb)
        r += list(wa[ok] / wb[ok])
    return float(np.median(r)) if r else float("nan")


def _write_md(text: str) -> None:
    """posterior.md: `text`, then the sections other scripts write there (from
    `benchmarks/posterior_laws.py`'s on), kept as they are."""
    old = OUT_MD.read_text() if OUT_MD.exists() else ""
    i = old.find(LAWS_SECTION)
    OUT_MD.write_text(text.rstrip("\n") + ("\n\n" + old[i:] if i >= 0 else "\n"))


#: The first heading of the sections of posterior.md that `benchmarks.posterior_laws` writes.
LAWS_SECTION = "## Laws over current"


def render(doc: dict[str, Any]) -> str:
    """posterior.md from posterior.json."""
    out = ["# Posterior (issue 25): calibration, speed, record or view", ""]
    m = doc.get("machine", {})
    if m:
        any_m = next(iter(m.values()))
        out += [f"Machine: {any_m['cpu']}, {any_m['cores']} cores, shared with other jobs "
                f"(load average per section: " + ", ".join(
                    f"{k} {v['loadavg'][0]:.1f} ({v['date']})" for k, v in m.items()) + ").",
                ""]
    if "calibration" in doc:
        rows = doc["calibration"]
        out += ["## Calibration (known answer)", "",
                f"{rows[0]['records']} simulated records per set, about "
                f"{rows[0]['samples_per_record']} samples each, noise 2 % of max|F|; "
                "4 chains x 1000 draws after the warmup steps shown. Coverage: share of "
                "(record, parameter) pairs whose 95 % interval holds the truth (nominal 0.95; "
                "the Jacobian intervals of the fit beside it).", "",
                _md(["model", "noise in data", "likelihood", "warmup", "target acceptance",
                     "coverage", "Jacobian coverage", "R-hat max", "ESS bulk min",
                     "ESS tail min", "divergences", "leapfrog/draw", "posterior s"],
                    [[r["model"], r["data_noise"], r["likelihood"], r.get("warmup", 1000),
                      r.get("target_accept", 0.9), r["coverage"], r["jacobian_coverage"],
                      f"{r['r_hat_max']:.4f}", r["ess_bulk_min"], r["ess_tail_min"], r["divergences"],
                      r["leapfrog_per_draw"], r["posterior_s"]] for r in rows]), ""]
        out += [f"- {r['model']} {r['data_noise']} / {r['likelihood']}: {r['note']}"
                for r in rows if r.get("note")]
        out += [""] if any(r.get("note") for r in rows) else []
    if "speed_cli" in doc:
        out += ["## Speed: the command line (cold process)", "",
                "Fresh process, `MRJAX_CACHE_DIR=off` (no compilation cache), `nice -n 10`: "
                "imports, loading the 30 UTFSM tests, the fit (swarm, polish, retry, "
                "std-errors) and the posterior (4 chains x (1000 warmup + 1000 draws)). "
                "Goal (issue 25): <= 5 min. CPU s: user + system time of the process, which "
                "a loaded machine does not stretch (the process uses about one core).", "",
                _md(["command", "tests", "noise", "data", "wall s", "sampling s", "CPU s",
                     "load before / after", "leapfrog/draw", "R-hat max", "ESS bulk min",
                     "ESS tail min", "divergences"],
                    [[f"`{r['command'].strip()}`", r["tests"], r["noise"], r["data"],
                      r["wall_s"], r["posterior_s"], r.get("cpu_s", float("nan")),
                      f"{r['load'][0]:.1f} / {r['load'][1]:.1f}",
                      r["diagnostics"]["leapfrog_per_draw"],
                      f"{r['diagnostics']['r_hat_max']:.4f}", r["diagnostics"]["ess_bulk_min"],
                      r["diagnostics"]["ess_tail_min"], r["diagnostics"]["divergences"]]
                     for r in doc["speed_cli"]]), ""]
    if "speed" in doc:
        rows = doc["speed"]
        out += ["## Speed (cold processes)", "",
                "posterior s: `mrjax.posterior` alone, compilation included; process s: the "
                "whole process (imports, data, cached fit read, posterior). A case run with "
                "fewer than 1000 draws (and as many warmup steps) is extrapolated linearly to "
                "4 chains x (1000 + 1000) steps (compilation included: an upper bound). CPU "
                "devices: `JAX_NUM_CPU_DEVICES` (a test's chains spread over them, "
                "`mrjax.bayes.chain_devices`).", "",
                _md(["model", "tests", "noise", "data", "start", "CPU devices",
                     "chains x (warmup + draws)",
                     "posterior s", "process s", "at 4 x (1000 + 1000) s", "leapfrog/draw",
                     "R-hat max", "ESS bulk min", "divergences", "load before / after"],
                    [[r["model"], r["n_tests"] if r["n_tests"] > 1 else r["tests"], r["noise"],
                      r["data"], r.get("start", START), r.get("devices", 1),
                      f"{r['chains']} x ({r['warmup']} + {r['draws']})", r["posterior_s"],
                      r["process_s"], r["posterior_s"] * 2000 * 4 / (
                          r["chains"] * (r["warmup"] + r["draws"])),
                      r["diagnostics"]["leapfrog_per_draw"],
                      f"{r['diagnostics']['r_hat_max']:.4f}",
                      r["diagnostics"]["ess_bulk_min"], r["diagnostics"]["divergences"],
                      "/".join(f"{v:.1f}" for v in r.get("load", []))]
                     for r in rows]), ""]
    if doc.get("mbw_tests"):
        rows = [r for r in doc["mbw_tests"] if r.get("row")]
        failed = [r["label"] for r in doc["mbw_tests"] if not r.get("row")
                  and not r.get("not_run")]
        failed += [f"{r['label']} (first try, 1 device)" for r in doc["mbw_tests"]
                   if r.get("first_try_unfinished")]
        skipped = [r["label"] for r in doc["mbw_tests"] if r.get("not_run")]
        t = np.array([r["row"]["posterior_s"] for r in rows])
        n = rows[0]["row"] if rows else {}
        out += ["## Modified Bouc-Wen on each of the 30 UTFSM tests (cold processes)", "",
                f"One fresh process per test, two at a time on the 2 cores, "
                f"{n.get('chains')} chains x ({n.get('warmup')} + {n.get('draws')}) steps, "
                f"AR(1) noise, the swarm's view, the start at the posterior's mode; "
                f"`at the defaults`: 4 x (500 + 1000), extrapolated linearly from a shorter "
                f"run (compilation included: an upper bound). Posterior s over the "
                f"{len(rows)} tests: median {np.median(t):.0f}, max {t.max():.0f}, total "
                f"{t.sum():.0f}." if rows else "", "",
                _md(["test", "CPU devices", "posterior s", "at the defaults s",
                     "leapfrog/draw",
                     "step size", "R-hat max", "ESS bulk min", "ESS tail min", "divergences",
                     "held", "load before / after"],
                    [[r["label"], r.get("devices", 1), r["row"]["posterior_s"],
                      r["row"]["posterior_s"] * 1500 * 4 / (
                          r["row"]["chains"] * (r["row"]["warmup"] + r["row"]["draws"])),
                      r["row"]["diagnostics"]["leapfrog_per_draw"],
                      r["row"]["diagnostics"]["step_size_median"],
                      f"{r['row']['diagnostics']['r_hat_max']:.4f}",
                      r["row"]["diagnostics"]["ess_bulk_min"],
                      r["row"]["diagnostics"]["ess_tail_min"],
                      r["row"]["diagnostics"]["divergences"], ", ".join(
                          w.split(" held")[0].removeprefix("posterior: ")
                          for w in r["row"]["warnings"] if " held at its fitted" in w) or "-",
                      "/".join(f"{v:.1f}" for v in r.get("load", []))] for r in rows]), ""]
        if failed:
            out += [f"Not finished within the 900 s limit: {', '.join(failed)}.", ""]
        if skipped:
            out += [f"Not run (the session's time ran out): {', '.join(skipped)}.", ""]
    if doc.get("speed_notes"):
        out += ["Runs that did not finish (measured by hand, see the notes' commands):", ""]
        out += [f"- {n}" for n in doc["speed_notes"]] + [""]
    if "mbw_geometry" in doc:
        g = doc["mbw_geometry"]
        out += ["## Where the modified Bouc-Wen posterior spends its leapfrog steps", "",
                g["intro"], "",
                _md(["sampler", "target acceptance", "posterior s", "leapfrog/draw",
                     "leapfrog/warmup step",
                     "step size", "gradients per device (warmup + draws)", "ms per gradient step",
                     "R-hat max", "ESS bulk / tail min", "divergences", "load"],
                    [[r.get("label", ""), r["target_accept"], r["posterior_s"],
                      r["leapfrog_per_draw"],
                      r["leapfrog_per_warmup_step"], r["step_size_median"],
                      " / ".join(f"{w} + {d}" for w, d in zip(r["work_warmup"], r["work_draws"])),
                      1e3 * r["posterior_s"] / max(w + d for w, d in zip(r["work_warmup"],
                                                                          r["work_draws"])),
                      f"{r['r_hat_max']:.4f}", f"{r['ess_bulk_min']:.0f} / {r['ess_tail_min']:.0f}",
                      r["divergences"], r["load"]] for r in g["runs"]]), ""]
        out += [f"- {n}" for n in g["notes"]] + [""]
        if "hessian" in g:
            h = g["hessian"]
            out += [f"The curvature (`python -m benchmarks.posterior_geometry`, test {h['test']}, "
                    f"{h['draws']} draws whitened by their covariance, the Hessian of -log "
                    f"density at {h['points']} of them; 1 everywhere for a Gaussian):", "",
                    "Sampler coordinates: log for "
                    f"{', '.join(h.get('log_coordinates', [])) or 'none'}; integrated out: "
                    f"{', '.join(h.get('linear', [])) or 'none'}.", "",
                    _md(["largest eigenvalue median", "90 %", "max", "smallest median",
                         "its direction (draws)"],
                        [[h["largest_eigenvalue"]["median"], h["largest_eigenvalue"]["p90"],
                          h["largest_eigenvalue"]["max"],
                          h.get("smallest_eigenvalue", {}).get("median", float("nan")),
                          "; ".join(f"{d} ({n})" for d, n in sorted(
                              h["directions"].items(), key=lambda t: -t[1]))]]), "",
                    _md(["", *h["skew"]],
                        [["skew", *h["skew"].values()],
                         ["excess kurtosis", *h["excess_kurtosis"].values()]]), ""]
        if "reparametrisation" in g:
            rp = g["reparametrisation"]
            out += [rp["intro"], "",
                    _md(["coordinates", "largest eigenvalue median", "90 %", "max",
                         "smallest median", "largest along"],
                        [[r["coordinates"], r["lmax_median"], r["lmax_p90"], r["lmax_max"],
                          r["lmin_median"], r["top_direction"]] for r in rp["rows"]]), "",
                    rp["note"], ""]
    if "cost" in doc:
        out += ["## One gradient against one force evaluation (test 10mm1Hz1A, warm)", "",
                "Inside one compiled loop (no dispatch cost). The sampler uses the reverse "
                "gradient for the static models and the forward one (the residuals' Jacobian "
                "by `jax.jacfwd`, then transposed) for the dynamic models.", "",
                _md(["model", "data", "scored samples", "integration", "force ms",
                     "gradient ms (reverse)", "ratio", "gradient ms (forward)", "ratio"],
                    [[r["model"], r["data"], r["samples"], r["integration"], r["force_ms"],
                      r["grad_ms"], r["ratio"], r.get("grad_fwd_ms", float("nan")),
                      r.get("ratio_fwd", float("nan"))] for r in doc["cost"]]), ""]
    if "figure" in doc:
        rows = []
        for model, d in doc["figure"].items():
            ratio, none, cov_j, cov_p, n = [], 0, 0, 0, 0
            for p in d["params"].values():
                j, q = np.asarray(p["jacobian"], float), np.asarray(p["posterior"], float)
                ok = np.all(np.isfinite(j), axis=1) & (np.ptp(j, axis=1) > 0)
                none += int(np.sum(~ok))
                ratio += list(np.ptp(q[ok], axis=1) / np.ptp(j[ok], axis=1))
                if p.get("truth") is not None:
                    t = np.asarray(p["truth"], float)
                    cov_j += int(np.sum((j[:, 0] <= t) & (t <= j[:, 1])))
                    cov_p += int(np.sum((q[:, 0] <= t) & (t <= q[:, 1])))
                    n += t.size
            dg = d["diagnostics"]
            rows.append([model, len(d["labels"]), d["run"], float(np.median(ratio)),
                         float(np.min(ratio)), float(np.max(ratio)), none,
                         f"{cov_j}/{n}" if n else "-", f"{cov_p}/{n}" if n else "-",
                         f"{dg['r_hat_max']:.4f}", dg["ess_bulk_min"], dg["divergences"],
                         dg["leapfrog_per_draw"], d["posterior_s"]])
        out += ["## Jacobian against posterior intervals (the README's figure)", "",
                "`python -m benchmarks.posterior_figure`: `docs/posterior_intervals.png`. "
                "Width ratio: the posterior's 95 % interval over the Jacobian's, over "
                "parameters and tests that have a Jacobian interval.", "",
                _md(["model", "tests", "run", "width ratio median", "min", "max",
                     "no Jacobian interval", "truth in Jacobian", "truth in posterior",
                     "R-hat max", "ESS bulk min", "divergences", "leapfrog/draw",
                     "posterior s"], rows), ""]
    if "views" in doc:
        v = doc["views"]
        rows = []
        for pair in v:
            rec, view = pair["record"], pair["view"]
            rows.append([rec["model"], rec["n_tests"], rec["noise"],
                         f"{rec['chains']} x {rec['draws']}", rec["posterior_s"],
                         view["posterior_s"], _width_ratio(view, rec),
                         rec["diagnostics"]["leapfrog_per_draw"],
                         view["diagnostics"]["leapfrog_per_draw"]])
        out += ["## Record or view", "",
                "Width ratio: median over parameters and tests of the 95 % interval width on "
                "the view over that on the record.", "",
                _md(["model", "tests", "noise", "chains x draws", "record s", "view s",
                     "width view / record", "leapfrog/draw record", "leapfrog/draw view"],
                    rows), ""]
    out += _render_kernels(doc.get("kernels", []))
    if doc.get("kernels_note"):
        out += [f"- {line}" for line in doc["kernels_note"]] + [""]
    return "\n".join(out)


def _render_kernels(rows: list[dict[str, Any]]) -> list[str]:
    """The section of the `kernels` rows: NUTS against ChEES on one campaign."""
    if not rows:
        return []
    table = []
    for r in rows:
        d = r["diagnostics"]
        ess = min(d["ess_bulk_min"], d["ess_tail_min"])
        table.append([r["model"], r["n_tests"], r["noise"], r["data"], r["kernel"],
                      r.get("cpu_devices", 1), r.get("version", "-"),
                      f"{r['chains']} x ({r['warmup']} + {r['draws']})",
                      f"{r['posterior_s']:.0f}", f"{r['cpu_s']:.0f}" if "cpu_s" in r else "-",
                      r["gradient_evaluations"],
                      f"{d['r_hat_max']:.4f}", f"{d['ess_bulk_min']:.0f}",
                      f"{d['ess_tail_min']:.0f}", f"{ess / r['posterior_s']:.2f}",
                      d["divergences"], sum(1 for x in r["rounds"] if x),
                      f"{d['leapfrog_per_draw']:.1f}",
                      "-" if "load" not in r else f"{r['load'][0]:.1f} -> {r['load'][1]:.1f}"])
    return ["## Kernels: NUTS per chain against ChEES-HMC in lockstep (issue 42)", "",
            "Each row a cold process (`case --kernel`), the posterior stage alone (the fit from "
            "the cache), every test of the campaign in one call at the kernel's defaults "
            "(continuations included). Gradient evaluations: leapfrog steps of every chain "
            "(warmup and draws of the last round of each test). CPU s: the process's user + "
            "system time (the wall time of a shared machine stretches with its load). ESS/s: "
            "the smallest bulk or tail ESS over tests and variables per second of the wall "
            "time.", "",
            _md(["model", "tests", "noise", "data", "kernel", "CPU devices", "code",
                 "chains x (warmup + draws)",
                 "wall s", "CPU s", "gradient evaluations", "R-hat max", "ESS bulk min", "ESS tail min",
                 "min ESS/s", "divergences", "tests continued", "leapfrog/draw", "load"],
                table), ""]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("calibration", "speed", "views", "cost", "render", "case",
                                     "kernels",
                                     "mbw-tests"))
    ap.add_argument("--jobs", type=int, default=2, help="mbw-tests: processes at a time")
    ap.add_argument("--records", type=int, default=50)
    ap.add_argument("--draws", type=int, default=1000)
    ap.add_argument("--chains", type=int, default=4)
    ap.add_argument("--kernel", choices=("nuts", "chees"), default="nuts",
                    help="case: the sampler's kernel")
    ap.add_argument("--warmup", type=int, default=None, help="default: the Sampler's")
    ap.add_argument("--model", default="kwok")
    ap.add_argument("--tests", default="all")
    ap.add_argument("--noise", default="iid")
    ap.add_argument("--data", default=None)
    ap.add_argument("--mbw-all", action="store_true")
    ap.add_argument("--models", default="kwok,dahl", help="calibration: models")
    ap.add_argument("--mbw-test", default="10mm1Hz0x5A", help="speed: the modified Bouc-Wen test")
    ap.add_argument("--mbw-draws", type=int, default=100,
                    help="speed: draws (and warmup steps) of the modified Bouc-Wen case")
    a = ap.parse_args(argv)
    if a.what == "case":
        if a.data == "None":
            a.data = None
        print(json.dumps(run_case(a)))
        return 0
    if a.what == "render":
        _write_md(render(json.loads(OUT_JSON.read_text())))
        return 0
    if a.what == "calibration":
        calibration(a.records, a.draws, a.models.split(","))
    elif a.what == "mbw-tests":
        merge("mbw_tests", mbw_tests(a.draws, a.warmup, a.jobs))
    elif a.what == "cost":
        merge("cost", gradient_cost())
    elif a.what == "speed":
        # the acceptance case: the CLI, fit included, then the posterior stage alone
        rows = [cold_cli("kwok"), cold(model="kwok", noise="iid"),
                cold(model="kwok", noise="ar1")]
        merge("speed_cli", rows[:1])
        # modified Bouc-Wen: a short run, extrapolated in the table (see the module docstring)
        rows.append(cold(model="modified_bouc_wen", tests=a.mbw_test, noise="ar1",
                         draws=a.mbw_draws, warmup=a.mbw_draws, chains=a.chains))
        if a.mbw_all:
            rows.append(cold(model="modified_bouc_wen", noise="ar1", draws=a.mbw_draws,
                             warmup=a.mbw_draws, chains=a.chains))
        merge("speed", rows[1:])
    elif a.what == "kernels":  # one campaign, NUTS then ChEES at their defaults
        merge("kernels", [cold(model=a.model, noise=a.noise, kernel=k, draws=d, chains=c)
                          for k, d, c in (("nuts", 1000, 4), ("chees", 300, 8))])
    elif a.what == "views":
        pairs = []
        for noise in ("iid", "ar1"):
            kw = dict(model="kwok", tests="all", noise=noise, draws=a.draws, warmup=a.draws)
            pairs.append({"record": cold(data="record", **kw), "view": cold(data="view", **kw)})
            merge("views", pairs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
