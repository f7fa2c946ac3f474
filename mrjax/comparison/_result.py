"""`CompareResult`: every model on the same tests, with criteria, ranking and held-out scores."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .. import __version__
from .._errors import InputError
from .._io import csv_cell, json_safe
from ..data import Batch
from ..fitting import FitResult

#: The convention of the criteria, written into compare.json.
CRITERIA_NOTE = ("Gaussian likelihood of the residuals per test: AIC = n ln(RSS/n) + 2k, "
                 "AICc = AIC + 2k(k+1)/(n-k-1), BIC = n ln(RSS/n) + k ln n, RSS in N^2, the "
                 "constant n(ln 2pi + 1) dropped; k = free parameters (those fixed by equal "
                 "bounds and the redundant z scale of Bouc-Wen models not counted) + 1 for the "
                 "noise variance")


def _finite_stat(a: np.ndarray, fn) -> float:
    a = np.asarray(a, float)
    a = a[~np.isnan(a)]
    return float(fn(a)) if a.size else float("nan")


def _argmin_rows(a: np.ndarray) -> np.ndarray:
    """Index of the smallest entry per column of (M, C), NaN treated as +inf (ties: first)."""
    return np.argmin(np.where(np.isnan(a), np.inf, a), axis=0)


@dataclasses.dataclass(frozen=True, eq=False)
class CompareResult:
    """Every model fitted to the same tests: per-test criteria, per-model summary, ranking
    and held-out scores of the generalized (current-dependent) models. Host NumPy arrays; M
    models, C compared tests, H held-out tests, G generalization methods.

    **Fields:**

    - `models` (M,): model names, in the order asked.
    - `fits`: model name -> its :class:`mrjax.FitResult` on all C tests.
    - `batch`: the compared tests (a `mrjax.data.Batch`).
    - `k` (M,): parameters counted by the criteria, noise variance included
        (:func:`n_free_parameters` + 1).
    - `n_samples` (C,): scored samples per test.
    - `rms` (M, C) [N], `nrmse` (M, C): per-test fit error (`FitResult.rms`, `.nrmse`).
    - `aic`, `aicc`, `bic` (M, C): per-test criteria (:func:`information_criteria`).
    - `generations` (M, C), `stopped_by_criterion` (M, C): swarm generations and whether the
        statistical stop ended them.
    - `scheme`, `description`: the held-out validation (`"leave-one-current-out"`,
        `"hold-out"`, `"folds"`, `"validate"` or `"none"`) in words.
    - `fold_names` (F,), `fold_train` (F,) tuples of training-test labels.
    - `methods` (G,): generalization methods scored (`"two-step"`, `"joint"`).
    - `holdout_labels`, `holdout_current` [A], `holdout_frequency` [Hz],
        `holdout_amplitude` [m] (H,); `holdout_fold` (H,) fold index; `holdout_index` (H,)
        index into the compared tests (-1 for validation files).
    - `holdout_rms` (G, M, H) [N], `holdout_nrmse` (G, M, H): scores of each model's laws,
        built on the fold's training tests, on each held-out test.
    - `timings`: model name -> seconds `{"fit", "holdout", "total"}` (the fit is one
        batched program for all tests, so there is no per-test time); `"all"` -> `{"total"}`.
    - `seed`, `options`: how it was run (fit and generalization options, for the record).
    """

    models: tuple[str, ...]
    fits: dict[str, FitResult]
    batch: Batch
    k: np.ndarray
    n_samples: np.ndarray
    rms: np.ndarray
    nrmse: np.ndarray
    aic: np.ndarray
    aicc: np.ndarray
    bic: np.ndarray
    generations: np.ndarray
    stopped_by_criterion: np.ndarray
    scheme: str
    description: str
    fold_names: tuple[str, ...]
    fold_train: tuple[tuple[str, ...], ...]
    methods: tuple[str, ...]
    holdout_labels: tuple[str, ...]
    holdout_current: np.ndarray
    holdout_frequency: np.ndarray
    holdout_amplitude: np.ndarray
    holdout_fold: np.ndarray
    holdout_index: np.ndarray
    holdout_rms: np.ndarray
    holdout_nrmse: np.ndarray
    timings: dict[str, dict[str, float]]
    seed: int
    options: dict[str, Any]

    # ------------------------------------------------------------------------------ tests
    @property
    def labels(self) -> tuple[str, ...]:
        """Labels of the compared tests (C,)."""
        return tuple(self.batch.labels)

    @property
    def current(self) -> np.ndarray:
        """Coil current [A] of each compared test (C,), NaN where unknown."""
        return np.asarray(self.batch.current, float)

    @property
    def frequency(self) -> np.ndarray:
        """Excitation frequency [Hz] of each compared test (C,), NaN where unknown."""
        return np.asarray(self.batch.frequency, float)

    @property
    def amplitude(self) -> np.ndarray:
        """Displacement amplitude [m] of each compared test (C,), NaN where unknown."""
        return np.asarray(self.batch.amplitude, float)

    @property
    def n_tests(self) -> int:
        """Number of compared tests C."""
        return len(self.labels)

    # ------------------------------------------------------------------------------ summary
    @property
    def winners(self) -> np.ndarray:
        """Index (into `models`) of the model with the lowest BIC on each test, (C,)."""
        return _argmin_rows(self.bic)

    @property
    def wins(self) -> np.ndarray:
        """Number of tests each model wins by BIC, (M,)."""
        return np.bincount(self.winners, minlength=len(self.models))

    @property
    def sum_aic(self) -> np.ndarray:
        """Summed AIC over the tests, (M,) (`inf` where a fit diverged)."""
        return np.sum(self.aic, axis=1)

    @property
    def sum_bic(self) -> np.ndarray:
        """Summed BIC over the tests, (M,)."""
        return np.sum(self.bic, axis=1)

    @property
    def ranking(self) -> tuple[str, ...]:
        """Model names from best to worst by summed BIC (ties broken by summed AIC)."""
        b = np.where(np.isnan(self.sum_bic), np.inf, self.sum_bic)
        a = np.where(np.isnan(self.sum_aic), np.inf, self.sum_aic)
        order = np.lexsort((np.arange(len(self.models)), a, b))
        return tuple(self.models[i] for i in order)

    def _margin(self, crit: np.ndarray) -> float:
        if len(self.models) < 2:
            return float("nan")
        r = self.ranking
        i, j = self.models.index(r[0]), self.models.index(r[1])
        with np.errstate(invalid="ignore"):
            return float(crit[j] - crit[i])

    @property
    def margin_aic(self) -> float:
        """Summed AIC of the runner-up minus that of the best model (both by the BIC
        ranking): positive when AIC agrees with the ranking. NaN for one model."""
        return self._margin(self.sum_aic)

    @property
    def margin_bic(self) -> float:
        """Summed BIC of the runner-up minus that of the best model (>= 0)."""
        return self._margin(self.sum_bic)

    def summary(self) -> list[dict[str, Any]]:
        """One dict per model (in `models` order): `model`, `rank` (1 = best by summed BIC),
        `k`, `median_nrmse`, `worst_nrmse`, `worst_test`, `sum_aic`, `sum_aicc`, `sum_bic`,
        `delta_aic`, `delta_bic` (to the lowest sum), `wins`, `median_generations`,
        `stopped_fraction`, `holdout` (method -> `median_nrmse`, `worst_nrmse`,
        `worst_test`, `median_rms_N`), and `fit_time_s`, `holdout_time_s`, `time_s`."""
        rank = {m: i + 1 for i, m in enumerate(self.ranking)}
        with np.errstate(invalid="ignore"):
            d_aic = self.sum_aic - _finite_stat(self.sum_aic, np.min)
            d_bic = self.sum_bic - _finite_stat(self.sum_bic, np.min)
        wins = self.wins
        out = []
        for i, m in enumerate(self.models):
            nr = self.nrmse[i]
            worst = int(np.argmax(np.where(np.isnan(nr), -np.inf, nr))) if nr.size else -1
            ho = {}
            for g, method in enumerate(self.methods):
                h = self.holdout_nrmse[g, i]
                hw = int(np.argmax(np.where(np.isnan(h), -np.inf, h))) if h.size else -1
                ho[method] = {"median_nrmse": _finite_stat(h, np.median),
                              "worst_nrmse": _finite_stat(h, np.max),
                              "worst_test": self.holdout_labels[hw] if hw >= 0 else None,
                              "median_rms_N": _finite_stat(self.holdout_rms[g, i], np.median)}
            t = self.timings.get(m, {})
            out.append({
                "model": m, "rank": rank[m], "k": int(self.k[i]),
                "median_nrmse": _finite_stat(nr, np.median), "worst_nrmse": _finite_stat(nr, np.max),
                "worst_test": self.labels[worst] if worst >= 0 else None,
                "sum_aic": float(self.sum_aic[i]), "sum_aicc": float(np.sum(self.aicc[i])),
                "sum_bic": float(self.sum_bic[i]), "delta_aic": float(d_aic[i]),
                "delta_bic": float(d_bic[i]), "wins": int(wins[i]),
                "median_generations": _finite_stat(
                    np.where(self.generations[i] >= 0, self.generations[i], np.nan), np.median),
                "stopped_fraction": float(np.mean(self.stopped_by_criterion[i])),
                "holdout": ho, "fit_time_s": t.get("fit", float("nan")),
                "holdout_time_s": t.get("holdout", float("nan")),
                "time_s": t.get("total", float("nan")),
            })
        return out

    # ------------------------------------------------------------------------------ select
    def subset(self, index: Any) -> CompareResult:
        """The comparison restricted to the compared tests at `index` (ints or a boolean mask
        of length C): criteria, wins and ranking over those tests only, with no new fit.
        Held-out scores are kept for the held-out tests among them (scores on validation
        files are dropped)."""
        C = self.n_tests
        idx = np.arange(C)[np.asarray(index)]
        if idx.size == 0:
            raise InputError("subset of a comparison needs at least one test")
        keep = np.isin(self.holdout_index, idx)
        pos = {int(j): n for n, j in reversed(list(enumerate(idx)))}
        cut = {n: getattr(self, n)[:, idx] for n in
               ("rms", "nrmse", "aic", "aicc", "bic", "generations", "stopped_by_criterion")}
        return dataclasses.replace(
            self, fits={m: f.subset(idx) for m, f in self.fits.items()},
            batch=self.batch.subset(idx), n_samples=self.n_samples[idx], **cut,
            holdout_labels=tuple(lb for lb, k in zip(self.holdout_labels, keep) if k),
            holdout_current=self.holdout_current[keep],
            holdout_frequency=self.holdout_frequency[keep],
            holdout_amplitude=self.holdout_amplitude[keep], holdout_fold=self.holdout_fold[keep],
            holdout_index=np.array([pos[int(j)] for j in self.holdout_index[keep]], int),
            holdout_rms=self.holdout_rms[:, :, keep], holdout_nrmse=self.holdout_nrmse[:, :, keep])

    def predict(self, i: int) -> dict[str, np.ndarray]:
        """Each model's force [N] on compared test `i` (its own per-test fit), unpadded:
        model name -> (T_i,)."""
        n = int(self.batch.n_samples[i])
        one = self.batch.subset([i])
        return {m: self.fits[m].subset([i]).predict(one)[0, :n] for m in self.models}

    # ------------------------------------------------------------------------------ text
    def table(self) -> str:
        """A readable fixed-width table: one row per model from best to worst (summed BIC),
        then the ranking line with the runner-up margins."""
        from .._tables import format_table  # imported here: mrjax.report loads matplotlib

        summ = {s["model"]: s for s in self.summary()}
        head = ["rank", "model", "k", "NRMSE% med", "worst", "sum AIC", "dAIC", "sum BIC",
                "dBIC", "wins"]
        fmt = ["", "", "", ".2f", ".2f", ".1f", ".1f", ".1f", ".1f", ""]
        for method in self.methods:
            head += [f"{method} med%", "worst"]
            fmt += [".2f", ".2f"]
        head += ["time[s]"]
        fmt += [".1f"]
        rows = []
        for m in self.ranking:
            s = summ[m]
            row = [s["rank"], m, s["k"], 100 * s["median_nrmse"], 100 * s["worst_nrmse"],
                   s["sum_aic"], s["delta_aic"], s["sum_bic"], s["delta_bic"],
                   f"{s['wins']}/{self.n_tests}"]
            for method in self.methods:
                h = s["holdout"][method]
                row += [100 * h["median_nrmse"], 100 * h["worst_nrmse"]]
            rows.append(row + [s["time_s"]])
        r = self.ranking
        lines = [format_table(rows, head, floatfmt=fmt),
                 f"{self.n_tests} tests; ranking by summed BIC: {' > '.join(r)}"]
        if len(r) > 1:
            lines.append(f"{r[0]} leads {r[1]} by {self.margin_bic:.1f} in summed BIC and "
                         f"{self.margin_aic:.1f} in summed AIC")
        if self.methods:
            lines.append(f"held-out NRMSE of the current-dependent laws "
                         f"({', '.join(self.methods)}): {self.description}")
        else:
            lines.append(f"held-out validation: {self.description}")
        return "\n".join(lines)

    def test_table(self) -> str:
        """Per-test NRMSE [%] of every model and the BIC winner, one row per test."""
        from .._tables import format_table

        head = ["test", "I[A]", "f[Hz]", "A[mm]"] + [f"{m} %" for m in self.models] + ["best"]
        fmt = ["", ".3g", ".3g", ".3g"] + [".2f"] * len(self.models) + [""]
        win = self.winners
        rows = [[self.labels[j], self.current[j], self.frequency[j], 1e3 * self.amplitude[j]]
                + [100 * float(self.nrmse[i, j]) for i in range(len(self.models))]
                + [self.models[win[j]]] for j in range(self.n_tests)]
        return format_table(rows, head, floatfmt=fmt)

    def __repr__(self) -> str:
        return (f"CompareResult(models={list(self.models)}, tests={self.n_tests}, "
                f"ranking={list(self.ranking)}, validation={self.scheme!r})")

    # ------------------------------------------------------------------------------ files
    def to_dict(self) -> dict[str, Any]:
        """The `compare.json` document (NaN and inf become `null`)."""
        win = self.winners
        tests = []
        for j in range(self.n_tests):
            per = {m: {"rms_N": self.rms[i, j], "nrmse": self.nrmse[i, j],
                       "aic": self.aic[i, j], "aicc": self.aicc[i, j], "bic": self.bic[i, j],
                       "generations": int(self.generations[i, j])
                       if self.generations[i, j] >= 0 else None,
                       "stopped_by_criterion": bool(self.stopped_by_criterion[i, j])}
                   for i, m in enumerate(self.models)}
            tests.append({"label": self.labels[j], "current_A": self.current[j],
                          "frequency_Hz": self.frequency[j], "amplitude_m": self.amplitude[j],
                          "n_samples": int(self.n_samples[j]), "best_bic": self.models[win[j]],
                          "models": per})
        held = []
        for h in range(len(self.holdout_labels)):
            per = {m: {method: {"rms_N": self.holdout_rms[g, i, h],
                                "nrmse": self.holdout_nrmse[g, i, h]}
                       for g, method in enumerate(self.methods)}
                   for i, m in enumerate(self.models)}
            held.append({"label": self.holdout_labels[h], "current_A": self.holdout_current[h],
                         "frequency_Hz": self.holdout_frequency[h],
                         "amplitude_m": self.holdout_amplitude[h],
                         "fold": self.fold_names[int(self.holdout_fold[h])], "models": per})
        folds = [{"name": n, "train": list(tr),
                  "test": [self.holdout_labels[h] for h in np.flatnonzero(self.holdout_fold == f)]}
                 for f, (n, tr) in enumerate(zip(self.fold_names, self.fold_train))]
        return json_safe({
            "mrjax_version": __version__, "seed": int(self.seed), "models": list(self.models),
            "criteria": CRITERIA_NOTE, "options": {k: _plain(v) for k, v in self.options.items()},
            "ranking": list(self.ranking), "margin_aic": self.margin_aic,
            "margin_bic": self.margin_bic, "summary": self.summary(), "tests": tests,
            "validation": {"scheme": self.scheme, "description": self.description,
                           "methods": list(self.methods), "folds": folds},
            "held_out": held, "timings_s": self.timings,
        })

    def to_csv(self) -> str:
        """`compare.csv` text: one row per test and model. Compared tests carry the per-test
        fit and criteria and, where the test was held out, the scores of the model's laws
        (`holdout_<method>_rms_N`, `..._nrmse`); validation files carry only the latter."""
        cols = ["label", "role", "current_A", "frequency_Hz", "amplitude_m", "n_samples",
                "model", "k", "rms_N", "nrmse", "aic", "aicc", "bic", "delta_bic",
                "best_bic", "generations", "stopped_by_criterion", "fold"]
        for method in self.methods:
            tag = method.replace("-", "_")
            cols += [f"holdout_{tag}_rms_N", f"holdout_{tag}_nrmse"]
        out = [",".join(cols)]
        nan = float("nan")
        win = self.winners
        best = np.nanmin(np.where(np.isnan(self.bic), np.inf, self.bic), axis=0) \
            if self.n_tests else np.zeros(0)
        where = {int(j): h for h, j in enumerate(self.holdout_index) if j >= 0}

        def held(i, h):
            vals = [self.fold_names[int(self.holdout_fold[h])] if h is not None else ""]
            for g in range(len(self.methods)):
                vals += [nan, nan] if h is None else [self.holdout_rms[g, i, h],
                                                     self.holdout_nrmse[g, i, h]]
            return vals

        for j in range(self.n_tests):
            h = where.get(j)
            for i, m in enumerate(self.models):
                gen = int(self.generations[i, j])
                vals = [self.labels[j], "compared", self.current[j], self.frequency[j],
                        self.amplitude[j], int(self.n_samples[j]), m, int(self.k[i]),
                        self.rms[i, j], self.nrmse[i, j], self.aic[i, j], self.aicc[i, j],
                        self.bic[i, j], self.bic[i, j] - best[j], bool(win[j] == i),
                        gen if gen >= 0 else nan, bool(self.stopped_by_criterion[i, j])]
                out.append(",".join(csv_cell(v) for v in vals + held(i, h)))
        for h in np.flatnonzero(self.holdout_index < 0):
            for i, m in enumerate(self.models):
                vals = [self.holdout_labels[h], "validation", self.holdout_current[h],
                        self.holdout_frequency[h], self.holdout_amplitude[h], nan, m,
                        int(self.k[i])] + [nan] * 6 + ["", nan, ""]
                out.append(",".join(csv_cell(v) for v in vals + held(i, int(h))))
        return "\n".join(out) + "\n"

    def figures(self) -> dict[str, Any]:
        """The four figures as `matplotlib.figure.Figure` objects (no pyplot): file name ->
        figure, `nrmse_per_test.png`, `delta_aic.png`, `holdout_nrmse.png` (only with held-out
        scores) and `worst_test.png`. Save one with `mrjax.report.save_png_bytes`."""
        from . import _figures  # imported here: matplotlib only when figures are drawn

        out = {"nrmse_per_test.png": _figures.plot_nrmse_per_test(self),
               "delta_aic.png": _figures.plot_delta_aic(self)}
        if len(self.holdout_labels) and self.methods:
            out["holdout_nrmse.png"] = _figures.plot_holdout_nrmse(self)
        out["worst_test.png"] = _figures.plot_worst_test(self)
        return out


def _plain(v: Any) -> Any:
    """An option value as JSON can hold it (objects by their repr)."""
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (list, tuple)) and all(isinstance(x, (bool, int, float, str)) for x in v):
        return list(v)
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    return repr(v)
