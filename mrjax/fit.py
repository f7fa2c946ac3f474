"""`mrjax.fit`: swarm -> optional Levenberg-Marquardt polish -> a result a user can read.

```python
import jax, mrjax
batch = mrjax.data.paper_grid()
res = mrjax.fit("kwok", batch, key=jax.random.key(0))
print(res.table())
res.params_of(0)          # {'c': ..., 'k': ..., ...}
```
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from . import __version__
from ._errors import InputError
from .data._condition import Batch, Condition, make_batch
from .models import AbstractModel, get
from .objective import fit_mask, rms_per_condition
from .pso import PSOParams, check_bounds, default_params, fit_swarm, resolve_model

Method = Literal["pso", "pso+lm", "lm"]
SwarmMode = Literal["separable", "full"]


@dataclasses.dataclass(frozen=True, eq=False)
class FitResult:
    """Per-condition identification results (host NumPy arrays, C conditions, P parameters).

    **Fields:**

    - `model`: the model object; `method`, `swarm`, `seed`: how it was fitted.
    - `labels`, `current` [A], `frequency` [Hz], `amplitude` [m] (NaN if unknown),
        `n_samples`: per condition.
    - `theta` (C, P): identified parameters, SI units, `param_names` order.
    - `rms` (C,) [N]: RMS force error on the scored samples; `nrmse` (C,): `rms / max|F|`.
    - `pso_rms` (C,) [N]: the swarm's RMS before the polish (NaN for `method="lm"`).
    - `generations` (C,), `stopped_by_criterion` (C,): swarm generations and whether the
        statistical stop ended it (False: the cap). -1 / False for `method="lm"`.
    - `history` (C, G+1) [N]: group-best RMS per generation (empty for `"lm"`).
    - `polish_steps` (C,), `polish_status` (C,) str: Levenberg-Marquardt steps and outcome
        (`"none"` without polish).
    - `stderr` (C, P), `ci95` (C, P, 2), `corr` (C, P, P), `identifiable` (C, P): uncertainty
        from the Jacobian at the optimum (NaN where undefined).
    - `timings`: seconds per stage.
    """

    model: AbstractModel
    method: str
    swarm: str
    seed: int
    labels: tuple[str, ...]
    current: np.ndarray
    frequency: np.ndarray
    amplitude: np.ndarray
    n_samples: np.ndarray
    theta: np.ndarray
    rms: np.ndarray
    nrmse: np.ndarray
    pso_rms: np.ndarray
    generations: np.ndarray
    stopped_by_criterion: np.ndarray
    history: np.ndarray
    polish_steps: np.ndarray
    polish_status: tuple[str, ...]
    stderr: np.ndarray
    ci95: np.ndarray
    corr: np.ndarray
    identifiable: np.ndarray
    timings: dict[str, float]

    @property
    def param_names(self) -> tuple[str, ...]:
        """Parameter names, in vector order."""
        return self.model.param_names

    @property
    def n_conditions(self) -> int:
        """Number of conditions C."""
        return len(self.labels)

    def __len__(self) -> int:
        return self.n_conditions

    def params_of(self, i: int) -> dict[str, float]:
        """Parameters of condition `i` by name [SI units]."""
        return {n: float(v) for n, v in zip(self.param_names, self.theta[i])}

    def param(self, name: str) -> np.ndarray:
        """One parameter across all conditions, shape (C,)."""
        if name not in self.param_names:
            raise InputError(f"unknown parameter {name!r}; model {self.model.name!r} has "
                             f"{list(self.param_names)}")
        return self.theta[:, self.param_names.index(name)]

    def predict(self, data: Batch) -> np.ndarray:
        """Force [N] of each condition's parameters on `data` (same conditions), (C, T)."""
        model = resolve_model(self.model, self.theta, data)
        f = jax.vmap(lambda th, x, v, d: model.force(th, x, v, d))
        return np.asarray(f(jnp.asarray(self.theta), data.x, data.xdot, data.dt))

    def table(self, *, max_rows: int | None = None) -> str:
        """A readable fixed-width table: one row per condition."""
        names = self.param_names
        head = ["condition", "I[A]", "f[Hz]", "A[mm]", "RMS[N]", "NRMSE%", "gens", "stop"]
        head += list(names)
        rows = []
        for i in range(self.n_conditions):
            def num(v, fmt):
                return "-" if not np.isfinite(v) else format(v, fmt)

            stop = ("crit" if self.stopped_by_criterion[i] else
                    ("cap" if self.generations[i] >= 0 else "-"))
            r = [self.labels[i], num(self.current[i], ".3g"), num(self.frequency[i], ".3g"),
                 num(self.amplitude[i] * 1e3, ".3g"), num(self.rms[i], ".2f"),
                 num(100 * self.nrmse[i], ".2f"),
                 str(self.generations[i]) if self.generations[i] >= 0 else "-", stop]
            r += [f"{v:.4g}" for v in self.theta[i]]
            rows.append(r)
        if max_rows is not None and len(rows) > max_rows:
            rows = rows[:max_rows] + [["..."] + [""] * (len(head) - 1)]
        w = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
        lines = ["  ".join(str(x).rjust(k) for x, k in zip(head, w))]
        lines.append("  ".join("-" * k for k in w))
        lines += ["  ".join(str(x).rjust(k) for x, k in zip(r, w)) for r in rows]
        med = np.median(self.rms[np.isfinite(self.rms)]) if np.any(np.isfinite(self.rms)) else np.nan
        medn = (np.median(self.nrmse[np.isfinite(self.nrmse)])
                if np.any(np.isfinite(self.nrmse)) else np.nan)
        lines.append(f"{self.model.name} ({self.method}, {self.swarm}): {self.n_conditions} "
                     f"conditions, median RMS {med:.2f} N, median NRMSE {100 * medn:.2f} %")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (f"FitResult(model={self.model.name!r}, method={self.method!r}, swarm={self.swarm!r}, "
                f"C={self.n_conditions}, median RMS={np.nanmedian(self.rms):.3g} N)")

    def to_dict(self) -> dict[str, Any]:
        """The public `fit.json` schema (see the README)."""

        def opt(v):
            v = float(v)
            return None if not math.isfinite(v) else v

        conds = []
        for i in range(self.n_conditions):
            gen = int(self.generations[i])
            conds.append({
                "label": self.labels[i],
                "current_A": opt(self.current[i]),
                "frequency_Hz": opt(self.frequency[i]),
                "amplitude_m": opt(self.amplitude[i]),
                "n_samples": int(self.n_samples[i]),
                "params": {n: float(v) for n, v in zip(self.param_names, self.theta[i])},
                "stderr": {n: opt(v) for n, v in zip(self.param_names, self.stderr[i])},
                "rms_N": opt(self.rms[i]),  # null where the model diverges
                "nrmse": opt(self.nrmse[i]),
                "pso_rms_N": opt(self.pso_rms[i]),
                "generations": gen if gen >= 0 else None,
                "stopped_by_criterion": bool(self.stopped_by_criterion[i]) if gen >= 0 else None,
                "polish_status": self.polish_status[i],
                "polish_steps": int(self.polish_steps[i]),
                "identifiable": {n: bool(v) for n, v in zip(self.param_names, self.identifiable[i])},
            })
        return {
            "model": self.model.name,
            "method": self.method,
            "swarm": self.swarm,
            "seed": int(self.seed),
            "param_names": list(self.param_names),
            "units": list(self.model.units),
            "mrjax_version": __version__,
            "conditions": conds,
        }

    def to_json(self, **kw) -> str:
        """`fit.json` text (NaN and inf written as `null`)."""
        return json.dumps(self.to_dict(), indent=kw.pop("indent", 1), allow_nan=False, **kw)

    def to_csv(self) -> str:
        """`fit.csv` text: one row per condition."""
        cols = ["label", "current_A", "frequency_Hz", "amplitude_m", "n_samples", "rms_N", "nrmse",
                "pso_rms_N", "generations", "stopped_by_criterion", "polish_status"]
        cols += list(self.param_names) + [f"stderr_{n}" for n in self.param_names]
        out = [",".join(cols)]
        for i in range(self.n_conditions):
            vals = [self.labels[i], self.current[i], self.frequency[i], self.amplitude[i],
                    self.n_samples[i], self.rms[i], self.nrmse[i], self.pso_rms[i],
                    self.generations[i], bool(self.stopped_by_criterion[i]), self.polish_status[i]]
            vals += list(self.theta[i]) + list(self.stderr[i])
            out.append(",".join(_csv_cell(v) for v in vals))
        return "\n".join(out) + "\n"


def _csv_cell(v) -> str:
    if isinstance(v, str):
        return '"' + v.replace('"', '""') + '"' if ("," in v or '"' in v) else v
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    v = float(v)
    return "" if not math.isfinite(v) else repr(v)


def as_batch(data: Batch | Condition | Sequence[Condition] | str | os.PathLike | Sequence) -> Batch:
    """Accept a :class:`Batch`, one or more :class:`Condition`, or file/directory path(s)."""
    if isinstance(data, Batch):
        return data
    if isinstance(data, Condition):
        return make_batch([data])
    if isinstance(data, (str, os.PathLike)):
        from .data import load
        return make_batch(load(data))
    data = list(data)
    if data and all(isinstance(d, (str, os.PathLike)) for d in data):
        from .data import load
        return make_batch(load(data))
    return make_batch(data)


def _progress_callback(enabled: bool | None, max_generations: int, C: int):
    """A tqdm bar driven from inside the compiled swarm, or None (costs nothing)."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled:
        return None, None
    from tqdm.auto import tqdm

    bar = tqdm(total=max_generations, desc="swarm", unit="gen", leave=False, file=sys.stderr)

    def cb(gen, done, best):
        g = int(np.max(gen))
        bar.n = min(g, max_generations)
        finite = best[np.isfinite(best)]
        bar.set_postfix(running=int(np.sum(~done)), best=f"{np.max(finite):.3g}N" if finite.size else "-",
                        refresh=False)
        bar.refresh()

    return cb, bar


def _check_records(model: AbstractModel, batch: Batch, mask) -> None:
    """Error for fewer scored samples than parameters + 1; warning for a record shorter than
    one excitation period."""
    n = np.asarray(mask).sum(axis=1)
    short = np.flatnonzero(n <= model.n_params)
    if short.size:
        i = int(short[0])
        raise InputError(
            f"condition {batch.labels[i]!r}: {int(n[i])} scored samples are too few for model "
            f"{model.name!r} with {model.n_params} parameters (at least {model.n_params + 1} "
            f"needed)")
    m = np.asarray(mask)
    rows = np.arange(m.shape[0])
    first, last = np.argmax(m, axis=1), m.shape[1] - 1 - np.argmax(m[:, ::-1], axis=1)
    t, dt = np.asarray(batch.t), np.asarray(batch.dt)
    span = t[rows, last] - t[rows, first] + dt[rows, last]  # scored duration, last interval in
    freq = np.asarray(batch.frequency, float)
    with np.errstate(invalid="ignore"):
        partial = np.flatnonzero(np.isfinite(freq) & (freq > 0) & (span * freq < 0.99))
    if partial.size:
        i = int(partial[0])
        warnings.warn(
            f"condition {batch.labels[i]!r}: the scored record spans {span[i]:.3g} s, less than "
            f"one period of its {freq[i]:g} Hz excitation ({partial.size} such condition(s)); "
            f"its parameters are poorly determined", RuntimeWarning, stacklevel=3)


def fit(
    model: str | AbstractModel,
    data: Batch | Condition | Sequence[Condition] | str | os.PathLike,
    *,
    method: Method = "pso+lm",
    swarm: SwarmMode = "separable",
    key: ArrayLike | None = None,
    seed: int = 0,
    bounds: tuple[ArrayLike, ArrayLike] | None = None,
    transient: float | str | None = None,
    n_particles: int = 50,
    max_generations: int = 200,
    generations: int | None = None,
    pso_params: PSOParams | None = None,
    polish_steps: int = 200,
    uncertainty: bool = True,
    progress: bool | None = False,
    devices: Sequence | None = None,
    callback: Callable | None = None,
    swarm_dtype: Any = None,
    restarts: int = 1,
) -> FitResult:
    """Identify `model` on every test condition of `data` at once.

    **Arguments:**

    - `model`: a model name (`"kwok"`, `"bouc_wen"`, ...) or object.
    - `data`: a `mrjax.data.Batch`, condition(s), or file/directory path(s).
    - `method`: `"pso+lm"` (swarm, then the Levenberg-Marquardt polish; default), `"pso"`
        (swarm only), or `"lm"` (polish alone from the model's default start: it shows why the
        swarm is needed). Where `bounds` exclude the default start, it is clipped onto them.
    - `swarm`: `"separable"` (variable projection; default) or `"full"` (the paper's swarm).
    - `key`: JAX PRNG key; default `jax.random.key(seed)`. Same key, same result.
    - `seed`: integer seed used when `key` is None, and recorded in the result.
    - `bounds`: `(lower, upper)`, (P,) arrays or dicts by name, SI units (default
        `model.bounds`).
    - `transient`: drop an initial span from the fitness: seconds, `"cycle"`, or None.
    - `n_particles`, `max_generations`: swarm size and generation cap.
    - `generations`: run exactly this many generations (no statistical stop; for benchmarks).
    - `pso_params`: :class:`mrjax.pso.PSOParams` hyperparameters.
    - `polish_steps`: maximum Levenberg-Marquardt steps.
    - `uncertainty`: compute std-errors and intervals (needs the polish machinery; also for
        `method="pso"`).
    - `progress`: show a progress bar (None: only on a TTY).
    - `devices`: shard the condition axis over these devices: `"all"`, a count, or a list of
        `jax.Device` (default: one device); see `mrjax.parallel`. Same key, same result.
    - `callback`: host callback for the swarm, see `mrjax.pso.swarm`.
    - `swarm_dtype`: float dtype of the swarm's search, e.g. `"float32"` (about twice as fast
        on CPU; see benchmarks/results.md). Default: the default float (float64 when x64 is
        on). The swarm's best positions are re-scored, polished and reported in float64.
    - `restarts`: run this many independent swarms per condition (one compiled program: the
        conditions are repeated along the batch axis, each copy with its own random stream) and
        polish the best of them. Costs `restarts` times the swarm; guards the many-parameter
        ODE models (modified Bouc-Wen) against a swarm that ends in a poor basin. The reported
        generations, stop flag and history are those of the chosen swarm. Default 1.

    **Returns:** a :class:`FitResult`.

    Raises :class:`mrjax.InputError` for bad options or data, including a condition with no
    more scored samples than the model has parameters. Warns (`RuntimeWarning`) for a condition
    whose record is shorter than one excitation period (known frequency): it has no complete
    hysteresis loop, so its parameters are poorly determined.
    """
    from .refine import polish as lm_polish
    from .refine import uncertainty as lm_uncertainty

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    model = get(model)
    if method not in ("pso", "pso+lm", "lm"):
        raise InputError(f"method must be 'pso', 'pso+lm' or 'lm', got {method!r}")
    if swarm not in ("separable", "full"):
        raise InputError(f"swarm must be 'separable' or 'full', got {swarm!r}")
    batch = as_batch(data)
    lo, hi = check_bounds(model, bounds)
    mask = fit_mask(batch, transient)
    _check_records(model, batch, mask)
    if key is None:
        key = jax.random.key(int(seed))
    if generations is not None:
        if int(generations) < 1:
            raise InputError(f"generations must be at least 1, got {generations}")
        base = pso_params or default_params(swarm)
        pso_params = PSOParams(
            inertia=base.inertia, c1_max=base.c1_max, c2_max=base.c2_max,
            confidence=base.confidence, window=base.window,
            min_generations=base.min_generations, criterion=False,
            velocity_clamp=base.velocity_clamp)
        max_generations = int(generations)
    if isinstance(restarts, bool) or int(restarts) != restarts or restarts < 1:
        raise InputError(f"restarts must be an integer >= 1, got {restarts!r}")
    restarts = int(restarts)
    n_real = batch.n_conditions
    orig_batch = batch
    if devices is not None:
        from .parallel import shard_batch
        batch, mask = shard_batch(batch, mask, devices)  # may pad C to a multiple of devices
    timings["prepare"] = time.perf_counter() - t0

    C = batch.n_conditions
    G = int(max_generations)
    pso_rms = np.full(C, np.nan)
    gens = np.full(C, -1)
    crit = np.zeros(C, bool)
    hist = np.zeros((C, 0))
    if method in ("pso", "pso+lm"):
        t1 = time.perf_counter()
        s_batch, s_mask = batch, mask
        if restarts > 1:  # every condition `restarts` times: copy k of condition i at row k*n_real + i
            s_batch = orig_batch.subset(np.tile(np.arange(n_real), restarts))
            s_mask = fit_mask(s_batch, transient)
            if devices is not None:
                from .parallel import shard_batch
                s_batch, s_mask = shard_batch(s_batch, s_mask, devices)
        cb, bar = _progress_callback(progress, G, s_batch.n_conditions)
        if callback is not None:
            user_cb, prog_cb = callback, cb

            def cb(g, d, b):  # noqa: F811
                if prog_cb is not None:
                    prog_cb(g, d, b)
                user_cb(g, d, b)
        try:
            sw = fit_swarm(model, s_batch, key=key, mode=swarm, bounds=(lo, hi), mask=s_mask,
                           params=pso_params, n_particles=n_particles, max_generations=G,
                           callback=cb, dtype=swarm_dtype)
            jax.block_until_ready(sw.rms)
        finally:
            if bar is not None:
                bar.close()
        theta = np.asarray(sw.theta)
        pso_rms = np.asarray(sw.rms, float)
        gens = np.asarray(sw.swarm.generations)
        crit = np.asarray(sw.swarm.stopped_by_criterion)
        hist = np.asarray(sw.swarm.history)
        if restarts > 1:
            theta, pso_rms, gens, crit, hist = _best_restart(
                n_real, restarts, C, theta, pso_rms, gens, crit, hist)
        timings["swarm"] = time.perf_counter() - t1
    else:
        theta = np.broadcast_to(np.clip(model.default_start(), lo, hi), (C, model.n_params)).copy()

    steps = np.zeros(C, int)
    status = ("none",) * C
    unc = None
    if method in ("pso+lm", "lm"):
        t1 = time.perf_counter()
        pol = lm_polish(model, theta, batch, mask=mask, lower=lo, upper=hi, max_steps=polish_steps)
        theta = np.asarray(pol.theta)
        steps = np.asarray(pol.steps)
        status = tuple(str(s) for s in pol.status)
        unc = pol.uncertainty if uncertainty else None
        timings["polish"] = time.perf_counter() - t1
    elif uncertainty:
        t1 = time.perf_counter()
        unc = lm_uncertainty(model, theta, batch, mask=mask)
        timings["uncertainty"] = time.perf_counter() - t1

    # every reported RMS uses sub-steps resolved from the final parameters (uncapped)
    t1 = time.perf_counter()
    final_model = resolve_model(model, theta, batch)
    rms = rms_per_condition(final_model, theta, batch, mask)
    diverged = np.flatnonzero(~np.isfinite(rms))
    if diverged.size:
        warnings.warn(
            f"condition {batch.labels[diverged[0]]!r}: the model's force is not finite at the "
            f"fitted parameters ({diverged.size} such condition(s)); its RMS is reported as inf "
            f"(null in fit.json): narrow the bounds", RuntimeWarning, stacklevel=2)
    fmax = np.max(np.where(np.asarray(mask), np.abs(np.asarray(batch.force)), 0.0), axis=1)
    nrmse = rms / np.where(fmax > 0, fmax, np.nan)
    P = model.n_params
    if unc is not None:
        stderr = np.asarray(unc.stderr, float)
        ci95 = np.asarray(unc.ci95, float)
        corr = np.asarray(unc.corr, float)
        ident = np.asarray(unc.identifiable, bool)
    else:
        stderr = np.full((C, P), np.nan)
        ci95 = np.full((C, P, 2), np.nan)
        corr = np.full((C, P, P), np.nan)
        ident = np.ones((C, P), bool)
    timings["evaluate"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t0
    result = FitResult(
        model=model, method=method, swarm=swarm if method != "lm" else "none", seed=int(seed),
        labels=tuple(batch.labels), current=np.asarray(batch.current, float),
        frequency=np.asarray(batch.frequency, float), amplitude=np.asarray(batch.amplitude, float),
        n_samples=np.asarray(np.asarray(mask).sum(axis=1), int), theta=theta, rms=rms,
        nrmse=nrmse, pso_rms=pso_rms, generations=gens, stopped_by_criterion=crit, history=hist,
        polish_steps=steps, polish_status=status, stderr=stderr, ci95=ci95, corr=corr,
        identifiable=ident, timings=timings,
    )
    if result.n_conditions != n_real:  # drop the padding added by shard_batch
        from .parallel import unpad
        result = unpad(result, n_real)
    return result


def _best_restart(n: int, k: int, c: int, *arrays):
    """Rows of the best of `k` swarms per condition (copy j of condition i at row j*n + i,
    best = lowest finite RMS, the second array), padded back to `c` rows with copies of the
    last condition (as `shard_batch` pads)."""
    rms = np.asarray(arrays[1], float)[: n * k].reshape(k, n)
    best = np.argmin(np.where(np.isfinite(rms), rms, np.inf), axis=0)
    rows = best * n + np.arange(n)
    rows = np.concatenate([rows, np.full(c - n, rows[-1])])
    return tuple(np.asarray(a)[rows] for a in arrays)


def save(
    result: FitResult, out_dir: str | os.PathLike, *, extra_files: dict[str, bytes] | None = None
) -> Path:
    """Write `fit.json` and `fit.csv` (plus `extra_files`) into `out_dir` atomically."""
    from ._io import atomic_output

    files = {"fit.json": result.to_json().encode(), "fit.csv": result.to_csv().encode()}
    files.update(extra_files or {})
    return atomic_output(out_dir, files)
