"""`FitResult`: per-condition identification results, and the one writer of fit.json / fit.csv."""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .. import __version__
from .._errors import InputError
from .._io import atomic_output, csv_cell, exact_decode, exact_encode, json_safe
from .._warnings import ResultWarning, WarningKind
from ..data import ESTIMATED_FIELDS, Batch
from ..models import AbstractModel, resolve_model, source_of
from ..refine import CORR_LIMIT, Status


def _finite_median(a: np.ndarray) -> float:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else float("nan")


@dataclasses.dataclass(frozen=True, eq=False)
class FitResult:
    """Per-condition identification results (host NumPy arrays, C conditions, P parameters).

    **Fields:**

    - `model`: the model object (its `fixed` parameters held); `method` (`"pso+lm"`,
        `"pso"` or `"lm"`: the stages run), `swarm_mode` (`"separable"`, `"full"`, or `"none"`
        without a swarm), `seed` (None for a key given as an array): how it was fitted.
    - `labels`, `current` [A], `frequency` [Hz], `amplitude` [m] (NaN if unknown),
        `n_samples`: per condition.
    - `theta` (C, P): identified parameters, SI units, `param_names` order.
    - `rms` (C,) [N]: RMS force error on the scored samples; `nrmse` (C,): `rms / max|F|`.
    - `pso_rms` (C,) [N]: the swarm's RMS before the polish (NaN for `method="lm"`).
    - `generations` (C,), `stopped_by_criterion` (C,): swarm generations and whether the
        statistical stop ended it (False: the cap). -1 / False for `method="lm"`.
    - `history` (C, G+1) [N]: group-best RMS per generation (empty for `"lm"`).
    - `polish_steps` (C,), `polish_status` (C,) :class:`mrjax.Status`: Levenberg-Marquardt
        steps (of the full-record polish) and outcome: `SUCCESSFUL`, `REFINED` (converged on
        the swarm's subsampled view, then refined on the full record in its few steps; see
        `mrjax.Swarm`'s `view`), `MAX_STEPS_REACHED`, `KEPT_START`, ..., or `NONE` without
        polish.
    - `stderr` (C, P), `ci95` (C, P, 2), `corr` (C, P, P), `identifiable` (C, P): uncertainty
        from the Jacobian at the optimum (NaN where undefined).
    - `timings`: seconds per stage.
    - `estimated` (C, 3) bool: whether each condition's `xdot`, `frequency`, `amplitude` (the
        columns of `mrjax.data.ESTIMATED_FIELDS`) were estimated rather than read, as
        `Batch.estimated`; `None` when not known.
    - `bounds`: the search box, `{"lower": (P,), "upper": (P,)}` [SI], shared by all
        conditions (a dict, so that per-condition slicing leaves it whole); `None` when not
        known. :meth:`warnings` uses it.
    - `transient`: the initial span left out of the fitness (seconds, `"cycle"` or None).
    - `starts_rms` (C, S) [N]: the RMS on the full record of each polished start (the swarm's,
        then the retry's from a neighbour's optimum, `mrjax.Polish(retry=True)`); `rms` is
        their minimum; a spread above `mrjax.fitting.SPREAD_MARGIN` is warned about (a
        possible local optimum). None without a retry.
    """

    model: AbstractModel
    method: str
    swarm_mode: str
    seed: int | None
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
    polish_status: tuple[Status, ...]
    stderr: np.ndarray
    ci95: np.ndarray
    corr: np.ndarray
    identifiable: np.ndarray
    timings: dict[str, float]
    estimated: np.ndarray | None = None
    bounds: dict[str, Any] | None = None
    starts_rms: np.ndarray | None = None
    transient: float | str | None = None

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

    def subset(self, index: Any) -> FitResult:
        """The results of the conditions at `index` (ints or a boolean mask of length C), in
        that order: every per-condition field is sliced, the rest (model, options, timings)
        kept.

        Each condition's swarm, statistical stop and polish ran independently of the others
        (only its random stream depends on its position in the batch), so a subset is a valid
        fit of those conditions; `mrjax.compare` generalizes each fold's training tests from
        it instead of fitting them again.
        """
        idx = np.arange(self.n_conditions)[np.asarray(index)]
        changes: dict[str, Any] = {}
        for name in self._per_condition():
            v = getattr(self, name)
            changes[name] = tuple(v[int(i)] for i in idx) if isinstance(v, tuple) else v[idx]
        return dataclasses.replace(self, **changes)

    def _per_condition(self) -> list[str]:
        """Names of the per-condition fields (leading length C), as :meth:`subset` slices."""
        C = self.n_conditions
        return [f.name for f in dataclasses.fields(self)
                if (isinstance(v := getattr(self, f.name), np.ndarray) and v.ndim >= 1
                    and v.shape[0] == C) or (isinstance(v, tuple) and len(v) == C)]

    @classmethod
    def concatenate(cls, parts: Sequence[FitResult]) -> FitResult:
        """The results of `parts` (fits of disjoint conditions with the same model and
        options, e.g. the chunks of one fit) as one result, conditions in the order given:
        every per-condition field is concatenated, the rest taken from the first part;
        `timings` are summed per stage [s]."""
        parts = list(parts)
        if not parts:
            raise InputError("concatenate needs at least one FitResult")
        first = parts[0]
        if len(parts) == 1:
            return first
        changes: dict[str, Any] = {}
        for name in first._per_condition():
            vals = [getattr(p, name) for p in parts]
            changes[name] = (sum(vals, ()) if isinstance(vals[0], tuple)
                             else np.concatenate(vals, axis=0))
        timings: dict[str, float] = {}
        for p in parts:
            for k, v in p.timings.items():
                timings[k] = timings.get(k, 0.0) + float(v)
        return dataclasses.replace(first, timings=timings, **changes)

    def to_state(self) -> dict[str, Any]:
        """Every field but `model` as plain JSON values that :meth:`from_state` turns back
        into the same result bit for bit (see `mrjax._io.exact_encode`); `"model"` is the
        model's name. Used by the journal of a chunked fit."""
        state = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                 if f.name != "model"}
        return exact_encode(dict(state, model=self.model.name))

    @classmethod
    def from_state(cls, state: dict[str, Any], model: AbstractModel) -> FitResult:
        """Inverse of :meth:`to_state`, with the model object `model` (whose name must match).

        Raises :class:`mrjax.InputError` for a state of another model or a missing field.
        """
        values = exact_decode(state)
        if values.get("model") != model.name:
            raise InputError(f"saved fit is of model {values.get('model')!r}, not "
                             f"{model.name!r}")
        kw: dict[str, Any] = {"model": model}
        for f in dataclasses.fields(cls):
            if f.name == "model":
                continue
            if f.name not in values:
                if f.default is dataclasses.MISSING:
                    raise InputError(f"saved fit lacks the field {f.name!r}")
                continue
            v = values[f.name]
            kw[f.name] = tuple(v) if isinstance(v, list) else v
        kw["polish_status"] = tuple(Status(s) for s in kw["polish_status"])
        return cls(**kw)

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
        model = resolve_model(self.model, self.theta, data.xdot, data.dt, data.mask)
        f = jax.vmap(lambda th, x, v, d: model.force(th, x, v, d))
        return np.asarray(f(jnp.asarray(self.theta), data.x, data.xdot, data.dt))

    def table(self, *, max_rows: int | None = None) -> str:
        """A readable fixed-width table: one row per condition, then the medians."""
        # imported here: mrjax.report loads matplotlib, which `import mrjax` does not need
        from .._tables import format_table

        head = ["condition", "I[A]", "f[Hz]", "A[mm]", "RMS[N]", "NRMSE%", "gens", "stop"]
        head += list(self.param_names)
        rows = []
        for i in range(self.n_conditions):
            ran = self.generations[i] >= 0
            stop = "crit" if self.stopped_by_criterion[i] else ("cap" if ran else "-")
            rows.append([self.labels[i], self.current[i], self.frequency[i],
                         1e3 * self.amplitude[i], self.rms[i], 100 * self.nrmse[i],
                         int(self.generations[i]) if ran else None, stop]
                        + [float(v) for v in self.theta[i]])
        if max_rows is not None and len(rows) > max_rows:
            rows = rows[:max_rows] + [["..."] + [None] * (len(head) - 1)]
        fmt = ["", ".3g", ".3g", ".3g", ".2f", ".2f", "", ""] + [".4g"] * len(self.param_names)
        med, medn = _finite_median(self.rms), _finite_median(self.nrmse)
        return (format_table(rows, head, floatfmt=fmt)
                + f"\n{self.model.name} ({self.method}, {self.swarm_mode}): {self.n_conditions} "
                f"conditions, median RMS {med:.2f} N, median NRMSE {100 * medn:.2f} %"
                + "".join(f"\nwarning: {w.message}" for w in self.warnings()))

    def warnings(self, generalized: Any = None) -> list[ResultWarning]:
        """What makes these results doubtful, as lmfit's fit report says it: one
        :class:`mrjax.ResultWarning` per kind (its `kind`, `message`, `conditions` and
        `parameters`).

        - `"at_bound"`: a parameter within `AT_BOUND` (0.5 %) of the search box's width of one
            of its bounds and, where it has a std-error, within 1.96 std-errors of it (equal
            bounds, a fixed parameter, excepted): the optimum may lie outside the box.
        - `"not_identifiable"`: a parameter on a numerically null direction of $J^T J$ or
            correlated above `mrjax.refine.CORR_LIMIT` with another (its std-error is null).
        - `"local_optimum"`: tests whose polished starts (the swarm's and the retry's from a
            neighbour's optimum, `starts_rms`) end more than `mrjax.fitting.SPREAD_MARGIN`
            apart (`mrjax.fitting.spread_warnings`).
        - `"too_few_currents"` (with `generalized`, a `GeneralizedModel` of these fits): laws
            whose degree needs more distinct currents than the tests have
            (`GeneralizedModel.law_warnings`).

        **Returns:** the list (empty when nothing is doubtful); also `fit.json`'s `"warnings"`
        (`ResultWarning.to_dict`) and the last lines of :meth:`table`.
        """
        return _warnings(self, generalized)

    def __repr__(self) -> str:
        return (f"FitResult(model={self.model.name!r}, method={self.method!r}, "
                f"swarm_mode={self.swarm_mode!r}, "
                f"C={self.n_conditions}, median RMS={np.nanmedian(self.rms):.3g} N)")

    def to_dict(self, *, generalized: Any = None, posterior: Any = None) -> dict[str, Any]:
        """The public `fit.json` schema (see the README); NaN and inf become `None`.

        **Arguments:** `generalized`: an optional `mrjax.generalize.GeneralizedModel` of these
        fits, written as the `"generalized"` block; `posterior`: an optional
        `mrjax.bayes.TestPosterior` of these fits, written as the `"posterior"` block.
        """
        names = self.param_names
        conds = []
        for i in range(self.n_conditions):
            ran = int(self.generations[i]) >= 0
            conds.append({
                "label": self.labels[i],
                "current_A": self.current[i],
                "frequency_Hz": self.frequency[i],
                "amplitude_m": self.amplitude[i],
                "n_samples": int(self.n_samples[i]),
                "params": dict(zip(names, self.theta[i])),
                "stderr": dict(zip(names, self.stderr[i])),
                "rms_N": self.rms[i],  # null where the model diverges
                "nrmse": self.nrmse[i],
                "pso_rms_N": self.pso_rms[i],
                "generations": int(self.generations[i]) if ran else None,
                "stopped_by_criterion": bool(self.stopped_by_criterion[i]) if ran else None,
                "polish_status": self.polish_status[i],
                "polish_steps": int(self.polish_steps[i]),
                "identifiable": dict(zip(names, self.identifiable[i])),
                "estimated": self._estimated_names(i),
                "starts_rms_N": None if self.starts_rms is None else list(self.starts_rms[i]),
            })
        doc = {
            "format": FIT_JSON_FORMAT,
            "model": self.model.name,
            "model_source": source_of(self.model),
            "fixed": {k: float(v) for k, v in dict(getattr(self.model, "fixed", {}) or {}).items()},
            "bounds": None if self.bounds is None else {
                side: dict(zip(names, np.asarray(self.bounds[side], float)))
                for side in ("lower", "upper")},
            "transient": self.transient,
            "method": self.method,
            "swarm": self.swarm_mode,
            "seed": None if self.seed is None else int(self.seed),
            "param_names": list(names),
            "units": list(self.model.units),
            "mrjax_version": __version__,
            "conditions": conds,
        }
        if generalized is not None:
            doc["generalized"] = generalized.to_dict()
        if posterior is not None:
            doc["posterior"] = posterior.to_dict()
        doc["warnings"] = [w.to_dict() for w in self.warnings(generalized)]
        return json_safe(doc)

    def _estimated_names(self, i: int) -> list[str]:
        """Which of velocity (`xdot`), frequency and amplitude of condition `i` are estimates."""
        if self.estimated is None:
            return []
        return [n for n, e in zip(ESTIMATED_FIELDS, np.asarray(self.estimated)[i]) if e]

    def to_json(self, *, generalized: Any = None, posterior: Any = None) -> str:
        """`fit.json` text, the one writer of that file (see :meth:`to_dict`)."""
        return json.dumps(self.to_dict(generalized=generalized, posterior=posterior), indent=1,
                          allow_nan=False)

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
            out.append(",".join(csv_cell(v) for v in vals))
        return "\n".join(out) + "\n"


#: The version of fit.json's layout: 2 added `format`, `fixed`, `bounds` and `transient`
#: (see CHANGELOG.md).
FIT_JSON_FORMAT = 2
#: The two polished starts of a test (the swarm's and the retry's) disagree when their RMS
#: differ by more than this fraction of the lower: a warning (`spread_warnings`).
SPREAD_MARGIN = 0.05
#: A parameter within this fraction of its search box's width of a bound is "at a bound".
AT_BOUND = 5e-3


def _who(labels: Sequence[str]) -> str:
    """The tests a warning concerns, briefly."""
    n = len(labels)
    return f"{n} test{'s' if n != 1 else ''} (first: {labels[0]!r})"


def _warnings(res: FitResult, generalized: Any) -> list[ResultWarning]:
    """:meth:`FitResult.warnings`."""
    out = _at_bound(res) + _not_identifiable(res) + spread_warnings(res)
    if generalized is not None:  # a GeneralizedModel (not imported: generalize uses fitting)
        out += [ResultWarning(w.kind, w.message, conditions=res.labels, parameters=w.parameters)
                for w in generalized.law_warnings(res.current)]
    return out


def _at_bound(res: FitResult) -> list[ResultWarning]:
    if res.bounds is None:
        return []
    names = res.param_names
    theta = np.asarray(res.theta, float)
    lo = np.asarray(res.bounds["lower"], float)
    hi = np.asarray(res.bounds["upper"], float)
    # near a bound, and the data cannot tell it from the bound (within its 95 % interval,
    # or no std-error): a small value resolved far from 0 in a wide box is not flagged
    se = np.asarray(res.stderr, float)
    tol = AT_BOUND * (hi - lo)
    unsure = ~np.isfinite(se)
    d_lo, d_hi = theta - lo, hi - theta
    near_lo = (d_lo <= tol) & (unsure | (d_lo <= 1.96 * se)) & (hi > lo)
    near_hi = (d_hi <= tol) & (unsure | (d_hi <= 1.96 * se)) & (hi > lo)
    at = near_lo | near_hi
    if not at.any():
        return []
    rows, cols = np.nonzero(at)
    i, j = int(rows[0]), int(cols[0])
    side = "lower" if near_lo[i, j] else "upper"
    params = [names[k] for k in np.flatnonzero(at.any(axis=0))]
    tests = [res.labels[k] for k in np.flatnonzero(at.any(axis=1))]
    return [ResultWarning(
        WarningKind.AT_BOUND,
        f"{', '.join(params)} at a bound of the search box in {_who(tests)}: {names[j]} = "
        f"{theta[i, j]:.4g} at its {side} bound {(lo if side == 'lower' else hi)[j]:.4g}; the "
        "optimum may lie outside the box: widen it (--bounds) or check the data",
        conditions=tests, parameters=params)]


def _not_identifiable(res: FitResult) -> list[ResultWarning]:
    """Parameters on a null direction of J^T J (no std-error) or correlated above
    `CORR_LIMIT` with another (a std-error of the combination the data determine)."""
    bad = ~np.asarray(res.identifiable, bool)
    if not bad.any():
        return []
    names = res.param_names
    params = [names[k] for k in np.flatnonzero(bad.any(axis=0))]
    tests = [res.labels[k] for k in np.flatnonzero(bad.any(axis=1))]
    finite = np.isfinite(np.asarray(res.stderr, float)) & bad
    if not finite.any():
        why = "a null direction of J^T J: the data do not determine them (no std-errors)"
    elif finite[bad].all():
        why = (f"correlated above {CORR_LIMIT} with another parameter: the data determine a "
               "combination of them, not each (their std-errors are finite but describe that "
               "ridge)")
    else:
        why = ("a null direction of J^T J (no std-error) or a correlation above "
               f"{CORR_LIMIT} with another parameter (a finite std-error along a ridge): the "
               "data do not determine each of them")
    return [ResultWarning(WarningKind.NOT_IDENTIFIABLE,
                          f"{', '.join(params)} not identifiable in {_who(tests)}: {why}",
                          conditions=tests, parameters=params)]


def save(
    result: FitResult,
    out_dir: str | os.PathLike,
    *,
    generalized: Any = None,
    extra_files: dict[str, bytes] | None = None,
) -> Path:
    """Write `fit.json` (with the `"generalized"` block of `generalized` if given), `fit.csv`
    and `extra_files` (name -> bytes) into `out_dir` atomically: all files or none."""
    files = {"fit.json": result.to_json(generalized=generalized).encode(),
             "fit.csv": result.to_csv().encode()}
    files.update(extra_files or {})
    return atomic_output(out_dir, files)


def spread_warnings(result: FitResult) -> list[ResultWarning]:
    """The warning (lmfit's fit-report style) of the tests whose polished starts disagree by
    more than `SPREAD_MARGIN` (relative RMS): their error surface has more than one optimum,
    the lower is reported and a still lower one may exist (try more `restarts`). An empty
    list without a retry.

    **Returns:** `[ResultWarning(LOCAL_OPTIMUM, ...)]` or `[]`.
    """
    s = result.starts_rms
    if s is None or np.ndim(s) != 2 or s.shape[1] < 2:
        return []
    with np.errstate(invalid="ignore", divide="ignore"):
        lo, hi = np.nanmin(s, axis=1), np.nanmax(s, axis=1)
        bad = ~(hi <= (1.0 + SPREAD_MARGIN) * lo)
    bad &= np.isfinite(lo)
    if not bad.any():
        return []
    idx = np.flatnonzero(bad)
    tests: Sequence[str] = [result.labels[i] for i in idx]
    i = int(idx[np.argmax((hi - lo)[idx] / lo[idx])])
    scale = result.nrmse[i] / result.rms[i] if result.rms[i] > 0 else np.nan
    return [ResultWarning(
        WarningKind.LOCAL_OPTIMUM,
        f"the swarm's start and the retry from a neighbour's optimum end more than "
        f"{100 * SPREAD_MARGIN:g} % apart in {len(tests)} test{'s' if len(tests) != 1 else ''} "
        f"(first: {tests[0]!r}; widest: {result.labels[i]!r}, NRMSE "
        f"{100 * lo[i] * scale:.2f} % vs {100 * hi[i] * scale:.2f} %): a local optimum is "
        "possible there; the lower is reported (try more restarts)",
        conditions=tests)]


def retry_wins(first_rms: np.ndarray, retry_rms: np.ndarray) -> np.ndarray:
    """Per test whether the retry is the better fit (lower RMS on the full record; NaN-safe:
    a non-finite retry never wins), as :func:`merge` chooses."""
    return np.asarray(retry_rms) < np.asarray(first_rms)


def merge(first: FitResult, retry: FitResult) -> FitResult:
    """Per test the better (lower RMS on the full record) of the first fit and its retry, and
    `starts_rms` (C, 2): both RMS [N]. The swarm's figures (`pso_rms`, generations, history)
    stay the first fit's; the polish's (parameters, RMS, steps, status) are the winner's."""
    better = retry_wins(first.rms, retry.rms)
    changes: dict[str, Any] = {}
    for name in ("theta", "rms", "nrmse", "polish_steps"):
        a, b = getattr(first, name), getattr(retry, name)
        shape = (-1,) + (1,) * (np.ndim(a) - 1)
        changes[name] = np.where(better.reshape(shape), b, a)
    changes["polish_status"] = tuple(r if w else f for f, r, w in
                                     zip(first.polish_status, retry.polish_status, better))
    changes["starts_rms"] = np.stack([first.rms, retry.rms], axis=1)
    return dataclasses.replace(first, **changes)
