"""`mrjax.compare`: every model on the same tests, information criteria, held-out validation."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ..data import Batch, as_batch, fit_mask, make_batch
from ..engine import Chunks, Polish, Swarm, check_settings
from ..fitting import FitResult, fit
from ..generalize import generalize
from ..models import AbstractModel, check_bounds, get, names
from ._criteria import information_criteria, n_free_parameters
from ._folds import Plan, plan_validation
from ._result import CompareResult

GENERALIZE_METHODS = ("two-step", "joint")


@dataclasses.dataclass(frozen=True)
class HeldOut:
    """The held-out validation of `mrjax.compare`: which tests are held out, and how each
    model's laws over the current are built on the others.

    **Fields:** the held-out tests, with at most one of `data` (other tests: a batch or
    file/directory path(s); the laws are built on all of the compared tests), `hold_out`
    (`{"current": [0.25, 0.75]}`: the tests at those currents [A]) and `folds` (K folds over
    the tests, a permutation seeded by the key; `"current"`: leave one current out); none of
    them: leave one current out when every current is known and there are at least two, else
    no held-out validation. `methods`: `"two-step"` and/or `"joint"` (default both; `()`: no
    held-out validation). `laws`, `degrees`, `weighting`: the laws' forms and the two-step
    weighting (`mrjax.generalize.generalize`); `swarm`, `polish`: the joint fit's settings.
    """

    data: Any = None
    hold_out: Mapping[str, Sequence[float]] | None = None
    folds: int | str | None = None
    methods: str | Sequence[str] | None = GENERALIZE_METHODS
    laws: Any = "auto"
    degrees: Mapping[str, int] | int | None = None
    weighting: str = "covariance"
    swarm: Swarm | None = Swarm(max_generations=100)
    polish: Polish | None = Polish(max_steps=100)

    def generalize(self, result: FitResult, batch: Batch, method: str, key: Any):
        """The laws of `result` on `batch` by `method` with these settings."""
        return generalize(result, batch, method=method, laws=self.laws, degrees=self.degrees,
                          weighting=self.weighting, swarm=self.swarm, polish=self.polish,
                          key=key)

    def to_dict(self) -> dict[str, Any]:
        """The settings for the record (compare.json's `options`)."""
        return {"methods": list(_checked_methods(self.methods)), "laws": self.laws,
                "degrees": self.degrees, "weighting": self.weighting}


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
              methods: tuple[str, ...], key: Any, transient, held: HeldOut) -> tuple:
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
            gm = held.generalize(sub, train, method, key)
            ev = gm.evaluate(test, mask=_mask(test, transient))
            rms[g, rows], nrmse[g, rows] = ev["rms"], ev["nrmse"]
        start += fold.test.size
    return rms, nrmse


def compare(
    data: Batch | str | Sequence[Any],
    *,
    models: str | Sequence[str] = "all",
    held_out: HeldOut | None = HeldOut(),
    swarm: Swarm | None = Swarm(),
    polish: Polish | None = Polish(),
    bounds: Mapping[str, tuple[ArrayLike, ArrayLike]] | None = None,
    transient: float | str | None = None,
    chunks: Chunks | None = None,
    key: int = 0,
    log: Callable[[str], None] | None = None,
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

    **Held-out validation** (:class:`HeldOut`). Each model's per-test fits of the training
    tests are generalized over the current (by every method of `held_out.methods`) and the
    laws are scored on the held-out tests. A per-test fit does not depend on the other tests,
    so every fold reuses the fits of its training tests (`FitResult.subset`): each model is
    fitted once, in one compiled program for all tests.

    **Arguments:**

    - `data`: the tests (a `mrjax.data.Batch`, condition(s), or file/directory path(s)).
    - `models`: `"all"` (every model of `mrjax.models.names`), a list of names, places
        (`"path/to/file.py:Name"`) or model objects, or `"kwok,bouc_wen"`.
    - `held_out`: a :class:`HeldOut` (default: leave one current out, two-step and joint
        laws), or None: no held-out validation.
    - `swarm`, `polish`, `transient`, `chunks`: the per-test fits' settings, the same for
        every model (see `mrjax.fit`). With `transient`, the criteria and held-out scores use
        the same scored samples as the fit.
    - `bounds`: model name -> `(lower, upper)` search bounds of that model (SI; as
        `mrjax.fit`); parameters fixed by equal bounds are not counted by the criteria.
    - `key`: integer seed of every fit, every joint generalization and the fold assignment;
        the same seed gives the same result.
    - `log`: called with a progress line (str) before and after each model, or None.

    **Returns:** a :class:`CompareResult` (`.table()`, `.summary()`, `.ranking`,
    `.to_dict()`, `.to_csv()`, `.figures()`).

    Raises :class:`mrjax.InputError` (one line) for an unknown model or option, an empty
    hold-out or training set, held-out validation on tests without a current, or bad data,
    all before any fit.
    """
    t_all = time.perf_counter()
    say = log if log is not None else (lambda msg: None)
    by_name = _models(models)
    if isinstance(key, bool) or not isinstance(key, (int, np.integer)) or key < 0:
        raise InputError(f"compare's key must be a non-negative integer seed, got {key!r}")
    held = held_out if held_out is not None else HeldOut(methods=())
    if not isinstance(held, HeldOut):
        raise InputError(f"held_out must be a mrjax.comparison.HeldOut or None, got "
                         f"{type(held).__name__}")
    check_settings(swarm, polish, chunks)
    methods = _checked_methods(held.methods)
    bounds = _checked_bounds(bounds, by_name)
    batch = as_batch(data)
    source = as_batch(held.data) if held.data is not None else batch
    plan = plan_validation(batch, validate=source if held.data is not None else None,
                           hold_out=held.hold_out, folds=held.folds, seed=key,
                           enabled=bool(methods))
    if not plan.folds:
        methods = ()
    fits, ho_rms, ho_nrmse, timings = {}, [], [], {}
    M = len(by_name)
    for i, (name, model) in enumerate(by_name.items()):
        say(f"[{i + 1}/{M}] {name}: fitting {batch.n_conditions} test"
            f"{'s' if batch.n_conditions != 1 else ''}...")
        t0 = time.perf_counter()
        res = fit(model, batch, swarm=swarm, polish=polish, key=key, bounds=bounds.get(name),
                  transient=transient, chunks=chunks)
        t1 = time.perf_counter()
        if methods:
            say(f"[{i + 1}/{M}] {name}: generalizing over {len(plan.folds)} "
                f"fold{'s' if len(plan.folds) != 1 else ''} ({', '.join(methods)})...")
        r, n = _held_out(res, batch, source, plan, methods, key, transient, held)
        t2 = time.perf_counter()
        fits[name], timings[name] = res, {"fit": t1 - t0, "holdout": t2 - t1, "total": t2 - t0}
        ho_rms.append(r)
        ho_nrmse.append(n)
        held_txt = "".join(f", held-out {m} median {100 * np.nanmedian(n[g]):.2f} %"
                           for g, m in enumerate(methods) if n.shape[1])
        say(f"[{i + 1}/{M}] {name}: done in {t2 - t0:.1f} s; median NRMSE "
            f"{100 * np.nanmedian(res.nrmse):.2f} %{held_txt}")
    timings["all"] = {"total": time.perf_counter() - t_all}
    options = {"swarm": swarm, "polish": polish, "transient": transient, "bounds": bounds,
               "held_out": held.to_dict()}
    return _result(fits, by_name, bounds, batch, source, plan, methods,
                   np.moveaxis(np.stack(ho_rms), 0, 1), np.moveaxis(np.stack(ho_nrmse), 0, 1),
                   timings, key, options)


def _result(fits, by_name, bounds, batch, source, plan, methods, ho_rms, ho_nrmse, timings,
            key, options) -> CompareResult:
    """The :class:`CompareResult` of every model's fit and held-out scores (G, M, H)."""
    model_names = tuple(by_name)
    k = np.array([n_free_parameters(by_name[m], bounds.get(m)) + 1 for m in model_names])
    n = fits[model_names[0]].n_samples
    rms = np.stack([fits[m].rms for m in model_names])
    crit = information_criteria(n[None, :] * rms**2, n[None, :], k[:, None])
    order = np.concatenate([f.test for f in plan.folds]) if plan.folds else np.zeros(0, int)
    fold_of = np.concatenate([np.full(f.test.size, j) for j, f in enumerate(plan.folds)]) \
        if plan.folds else np.zeros(0, int)
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
        timings=timings, seed=int(key), options=options)
