"""`mrjax.compare`: every model on the same tests, information criteria, held-out validation."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ..data import Batch, as_batch, fit_mask, make_batch
from ..fitting import FitResult, fit
from ..generalize import generalize
from ..models import AbstractModel, check_bounds, get, names
from ._criteria import information_criteria, n_free_parameters
from ._folds import Plan, plan_validation
from ._result import CompareResult

#: Options of `mrjax.fit` that `compare` passes on (the same for every model).
FIT_OPTIONS = ("method", "swarm", "polish", "swarm_mode", "transient", "n_particles",
               "max_generations", "generations", "pso_params", "polish_steps", "polish_tol",
               "uncertainty", "progress", "devices", "swarm_dtype", "swarm_view", "restarts",
               "max_memory", "chunk_size", "retry")
#: Options of `mrjax.generalize.generalize` that `compare` passes on.
GENERALIZE_OPTIONS = ("degrees", "laws", "weighting", "swarm", "polish", "n_particles",
                      "max_generations", "pso_params", "restarts", "polish_steps", "tol",
                      "swarm_view", "uncertainty")
GENERALIZE_METHODS = ("two-step", "joint")


def _models(models: str | Sequence[Any]) -> dict[str, AbstractModel]:
    """The models to compare by name, in the order given: names, places
    (`path/file.py:Name`) or model objects (a user's model need not be registered)."""
    if isinstance(models, str):
        if models.strip().lower() == "all":
            return {n: get(n) for n in names()}
        models = [m for m in models.split(",")]
    out: dict[str, AbstractModel] = {}
    for m in models:
        if isinstance(m, str) and not m.strip():
            raise InputError(f"empty model name in the model list {models!r}")
        model = get(m)  # InputError for an unknown model
        if model.name in out:
            raise InputError(f"model {model.name!r} is listed twice")
        out[model.name] = model
    if not out:
        raise InputError("no model to compare")
    return out


def _checked_options(given: Mapping[str, Any], allowed: Sequence[str], what: str) -> dict:
    unknown = sorted(set(given) - set(allowed))
    if unknown:
        raise InputError(f"unknown {what} option {unknown[0]!r}; allowed: {', '.join(allowed)}")
    return dict(given)


def _checked_methods(methods: str | Sequence[str] | None) -> tuple[str, ...]:
    if methods is None:
        return ()
    if isinstance(methods, str):
        none = methods.strip().lower() == "none"
        methods = [] if none else [m for m in methods.split(",") if m.strip()]
    out = []
    for m in methods:
        m = str(m).strip().replace("_", "-")
        if m not in GENERALIZE_METHODS:
            raise InputError(f"generalization method must be 'two-step' or 'joint', got {m!r}")
        if m not in out:
            out.append(m)
    return tuple(out)


def _checked_bounds(bounds: Mapping[str, Any] | None, models: dict[str, AbstractModel]) -> dict:
    if bounds is None:
        return {}
    if not isinstance(bounds, Mapping):
        raise InputError("bounds must map a model name to its (lower, upper) bounds")
    out = {}
    for name, b in bounds.items():
        key = str(name).strip().lower() if str(name).strip().lower() in models else \
            get(name).name
        if key not in models:
            raise InputError(f"bounds given for model {key!r}, which is not compared")
        check_bounds(models[key], b)
        out[key] = b
    return out


def _padded(batch: Batch, index: np.ndarray) -> Batch:
    """The tests at `index`, padded to the full batch length so that folds of the same size
    share one compiled program."""
    return make_batch([batch.condition(int(i)) for i in index], length=batch.length)


def _mask(batch: Batch, transient) -> Any:
    return None if transient is None else fit_mask(batch, transient)


def _held_out(result: FitResult, batch: Batch, source: Batch, plan: Plan,
              methods: tuple[str, ...], seed: int, transient, gen_options: dict) -> tuple:
    """Scores (G, H) of the model's laws, generalized on each fold's training tests from the
    per-test fits of those tests (no refit), on the fold's held-out tests."""
    H = sum(f.test.size for f in plan.folds)
    rms = np.full((len(methods), H), np.nan)
    nrmse = np.full((len(methods), H), np.nan)
    start = 0
    for fold in plan.folds:
        train = _padded(batch, fold.train)
        test = _padded(source, fold.test)
        sub = result.subset(fold.train)
        rows = slice(start, start + fold.test.size)
        for g, method in enumerate(methods):
            gm = generalize(sub, train, method=method, seed=seed, mask=_mask(train, transient),
                            **gen_options)
            ev = gm.evaluate(test, mask=_mask(test, transient))
            rms[g, rows], nrmse[g, rows] = ev["rms"], ev["nrmse"]
        start += fold.test.size
    return rms, nrmse


def compare(
    data: Batch | str | Sequence[Any],
    *,
    models: str | Sequence[str] = "all",
    validate: Batch | str | Sequence[Any] | None = None,
    hold_out: Mapping[str, Sequence[float]] | None = None,
    folds: int | str | None = None,
    generalize_methods: str | Sequence[str] | None = GENERALIZE_METHODS,
    generalize_options: Mapping[str, Any] | None = None,
    bounds: Mapping[str, tuple[ArrayLike, ArrayLike]] | None = None,
    seed: int = 0,
    log: Callable[[str], None] | None = None,
    **fit_options: Any,
) -> CompareResult:
    """Fit every model to the same tests and compare them: per-test error and information
    criteria, a ranking, and how well each model's current-dependent version predicts tests
    it was not built on.

    **Per test and model:** RMS [N] and NRMSE of the per-test fit (`mrjax.fit`), AIC, AICc
    and BIC from the Gaussian likelihood of the residuals (:func:`information_criteria`,
    with k = :func:`n_free_parameters` + 1 for the noise variance), generations and whether
    the statistical stop fired. **Per model:** median and worst NRMSE, summed AIC and BIC,
    the ranking by summed BIC, the number of tests each model wins (lowest BIC), and the
    summed-AIC difference of the runner-up to the best (`CompareResult.margin_aic`).

    **Held-out validation.** Each model's per-test fits of the training tests are generalized
    over the current (`mrjax.generalize.generalize`, by every method in
    `generalize_methods`) and the resulting laws are scored on the held-out tests
    (`GeneralizedModel.evaluate`). A per-test fit does not depend on the other tests, so every
    fold reuses the fits of its training tests (`FitResult.subset`) instead of fitting again:
    each model is fitted once, in one compiled program for all tests, and each fold's tests
    are padded to the full record length so that folds of equal size share the compiled
    generalization. The held-out tests are, with at most one of:

    - `validate`: other tests (a batch, or file/directory path(s)); the laws are built on all
        of `data`;
    - `hold_out={"current": [0.25, 0.75]}`: the tests at those currents [A];
    - `folds=K`: K folds over the tests (a permutation seeded by `seed`); `folds="current"`:
        leave one current out;
    - none of them: leave one current out when every current is known and there are at
        least two, else no held-out validation.

    **Arguments:**

    - `data`: the tests (a `mrjax.data.Batch`, condition(s), or file/directory path(s)).
    - `models`: `"all"` (every model of `mrjax.models.names`), a list of names, places
        (`"path/to/file.py:Name"`) or model objects, or `"kwok,bouc_wen"`.
    - `validate`, `hold_out`, `folds`: the held-out tests, see above.
    - `generalize_methods`: `"two-step"` and/or `"joint"` (default both); `()` or None: no
        held-out validation.
    - `generalize_options`: keyword arguments of `generalize` (`degrees`, `laws`,
        `weighting`, `n_particles`, `max_generations`, `pso_params`, `polish`,
        `polish_steps`).
    - `bounds`: model name -> `(lower, upper)` search bounds of that model (SI; as
        `mrjax.fit`); parameters fixed by equal bounds are not counted by the criteria.
    - `seed`: seed of every fit, every joint generalization and the fold assignment; the same
        seed gives the same result.
    - `log`: called with a progress line (str) before and after each model, or None.
    - `**fit_options`: options of `mrjax.fit`, the same for every model (`method`,
        `swarm_mode`, `transient`, `n_particles`, `max_generations`, `generations`,
        `pso_params`, `polish_steps`, `uncertainty`, `progress`, `devices`, `swarm_dtype`,
        `restarts`, `retry`, `max_memory`, `chunk_size`: each model's fit runs in chunks of
        bounded memory; the defaults are `mrjax.fit`'s). With `transient`, the criteria and
        held-out scores use the same scored samples as the fit.

    **Returns:** a :class:`CompareResult` (`.table()`, `.summary()`, `.ranking`,
    `.to_dict()`, `.to_csv()`, `.figures()`).

    Raises :class:`mrjax.InputError` (one line) for an unknown model or option, an empty
    hold-out or training set, held-out validation on tests without a current, or bad data,
    all before any fit.
    """
    t_all = time.perf_counter()
    say = log if log is not None else (lambda msg: None)
    by_name = _models(models)
    model_names = tuple(by_name)
    if "key" in fit_options:
        raise InputError("compare takes seed= (the same for every model), not key=")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    fit_options = _checked_options(fit_options, FIT_OPTIONS, "fit")
    gen_options = _checked_options(generalize_options or {}, GENERALIZE_OPTIONS, "generalize")
    methods = _checked_methods(generalize_methods)
    bounds = _checked_bounds(bounds, by_name)
    batch = as_batch(data)
    source = as_batch(validate) if validate is not None else batch
    plan = plan_validation(batch, validate=source if validate is not None else None,
                           hold_out=hold_out, folds=folds, seed=seed, enabled=bool(methods))
    if not plan.folds:
        methods = ()
    transient = fit_options.get("transient")
    k = np.array([n_free_parameters(by_name[m], bounds.get(m)) + 1 for m in model_names])
    C, M, G = batch.n_conditions, len(model_names), len(methods)
    H = sum(f.test.size for f in plan.folds)
    fits: dict[str, FitResult] = {}
    ho_rms, ho_nrmse = np.full((G, M, H), np.nan), np.full((G, M, H), np.nan)
    timings: dict[str, dict[str, float]] = {}
    for i, name in enumerate(model_names):
        say(f"[{i + 1}/{M}] {name}: fitting {C} test{'s' if C != 1 else ''}...")
        t0 = time.perf_counter()
        res = fit(by_name[name], batch, seed=seed, bounds=bounds.get(name), **fit_options)
        t1 = time.perf_counter()
        if G:
            say(f"[{i + 1}/{M}] {name}: generalizing over {len(plan.folds)} "
                f"fold{'s' if len(plan.folds) != 1 else ''} ({', '.join(methods)})...")
            ho_rms[:, i], ho_nrmse[:, i] = _held_out(res, batch, source, plan, methods, seed,
                                                     transient, gen_options)
        t2 = time.perf_counter()
        fits[name] = res
        timings[name] = {"fit": t1 - t0, "holdout": t2 - t1, "total": t2 - t0}
        held = "".join(f", held-out {m} median {100 * np.nanmedian(ho_nrmse[g, i]):.2f} %"
                       for g, m in enumerate(methods) if H)
        say(f"[{i + 1}/{M}] {name}: done in {t2 - t0:.1f} s; median NRMSE "
            f"{100 * np.nanmedian(res.nrmse):.2f} %{held}")
    n = fits[model_names[0]].n_samples
    rms = np.stack([fits[m].rms for m in model_names])
    crit = information_criteria(n[None, :] * rms**2, n[None, :], k[:, None])
    order = np.concatenate([f.test for f in plan.folds]) if plan.folds else np.zeros(0, int)
    fold_of = np.concatenate([np.full(f.test.size, j) for j, f in enumerate(plan.folds)]) \
        if plan.folds else np.zeros(0, int)
    options = dict(fit_options, generalize_options=gen_options, bounds=bounds)
    timings["all"] = {"total": time.perf_counter() - t_all}
    return CompareResult(
        models=model_names, fits=fits, batch=batch, k=k, n_samples=np.asarray(n, int),
        rms=rms, nrmse=np.stack([fits[m].nrmse for m in model_names]), aic=crit["aic"],
        aicc=crit["aicc"], bic=crit["bic"],
        generations=np.stack([fits[m].generations for m in model_names]),
        stopped_by_criterion=np.stack([fits[m].stopped_by_criterion for m in model_names]),
        scheme=plan.scheme, description=plan.description,
        fold_names=tuple(f.name for f in plan.folds),
        fold_train=tuple(tuple(batch.labels[int(j)] for j in f.train) for f in plan.folds),
        methods=methods, holdout_labels=tuple(source.labels[int(j)] for j in order),
        holdout_current=np.asarray(source.current, float)[order],
        holdout_frequency=np.asarray(source.frequency, float)[order],
        holdout_amplitude=np.asarray(source.amplitude, float)[order],
        holdout_fold=fold_of.astype(int),
        holdout_index=order.astype(int) if plan.scheme != "validate"
        else np.full(order.size, -1), holdout_rms=ho_rms, holdout_nrmse=ho_nrmse,
        timings=timings, seed=int(seed), options=options)
