"""The study's computations: every identification (the jobs), the generalization, and the
two threads that share them."""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..data import Batch
from ..engine import Swarm
from ..fitting import FitResult, fit, polish_fit
from ..generalize import generalize
from ..models import AbstractModel, get, resolve_model
from ..objective import nrmse, rms_per_condition
from ._data import DATA_CYCLES, load_study_data
from ._stats import finite_median

#: Generation cap of every swarm in `quick` mode (full mode: `mrjax.fit`'s 200).
QUICK_GENERATIONS = 60
#: Longest RK4 step [s] of the Bouc-Wen swarms (sub-steps = ceil(sample interval / this)).
BW_SWARM_STEP_S = 1e-3

#: Search box of the paper's swarm on the embedded data, SI units in each model's parameter
#: order: about twice the range that eq 24-29 span over 0-2 A (c <= 5090 N*s/m, |k| <= 5100 N/m,
#: alpha <= 892 N, beta = 100 s/m, delta <= 1.18, |f0| <= 293 N), the a-priori scale an engineer
#: sets for an RD-1005-3 damper; Bouc-Wen's (delta, beta, gamma, n) keep mrjax's defaults. The
#: paper's swarm (no variable projection, 50 particles, statistical stop) depends on the box:
#: in mrjax's wide default box (c up to 1e5 N*s/m) it stops before either model is near its
#: optimum. Measured data (`--data`) use the models' default boxes.
PAPER_BOX: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "kwok": ((0.0, -1e4, 0.0, 1.0, 0.0, -500.0), (1e4, 1e4, 2000.0, 1000.0, 2.0, 500.0)),
    "bouc_wen": ((0.0, -1e4, 0.0, -500.0, 1.0, 0.0, 0.0, 1.0),
                 (1e4, 1e4, 2000.0, 500.0, 5000.0, 5000.0, 5000.0, 3.0)),
}

#: Runs (keys of `Study.runs` and of `summary.json`'s "runs") and what they are, in the order
#: they are reported.
RUN_TITLES = {
    "kwok_paper_swarm": "tanh, paper's swarm",
    "bouc_wen_paper_swarm": "Bouc-Wen, paper's swarm",
    "kwok_paper_swarm_polished": "tanh, paper's swarm + LM polish",
    "kwok_separable": "tanh, separable swarm + LM polish",
    "bouc_wen_separable": "Bouc-Wen, separable swarm",
}


# --------------------------------------------------------------------------------------------
# Progress and the second thread


class StageLog:
    """Stage progress on stderr, and the wall time of every stage."""

    def __init__(self, verbose: bool):
        self.verbose = verbose
        self.t0 = time.perf_counter()
        self.timings: dict[str, float] = {}
        self._lock = threading.Lock()

    def say(self, msg: str) -> None:
        if self.verbose:
            with self._lock:
                print(f"mrjax reproduce [{time.perf_counter() - self.t0:5.1f} s] {msg}",
                      file=sys.stderr, flush=True)


class _Background:
    """Run `fn(cancel)` in a second thread; `cancel` is a `threading.Event` that `fn` checks
    between its stages. `result()` joins and re-raises the thread's exception; `stop()` asks
    it to stop after its current stage and waits (a thread still inside XLA when the
    interpreter exits would abort the process)."""

    def __init__(self, fn: Callable[[threading.Event], Any]):
        self._out: Any = None
        self._err: BaseException | None = None
        self.cancel = threading.Event()
        self._thread = threading.Thread(target=self._main, args=(fn,),
                                        name="mrjax-reproduce-background")
        self._thread.start()

    def _main(self, fn):
        try:
            self._out = fn(self.cancel)
        except BaseException as e:  # re-raised in the caller's thread
            self._err = e

    def result(self) -> Any:
        self._thread.join()
        if self._err is not None:
            raise self._err
        return self._out

    def stop(self) -> None:
        self.cancel.set()
        self._thread.join()


# --------------------------------------------------------------------------------------------
# The study and its jobs


@dataclasses.dataclass
class Study:
    """Everything `run` computes: the data, every identification and the generalized models.

    **Fields:** `batch`, `data_info`, `seed`, `quick`; `runs` name -> `mrjax.FitResult` (see
    `RUN_TITLES`); `generalized` name -> `GeneralizedModel` (`"two-step"`: covariance
    weighting, `"two-step-equal"`: the paper's plain means, `"joint"`: measured data only, not
    in quick mode; empty when currents are unknown);
    `generalized_eval` name -> `GeneralizedModel.evaluate` dict; `timings` [s] per stage;
    `notes` strings for the summary.
    """

    batch: Any
    data_info: dict[str, Any]
    seed: int
    quick: bool
    runs: dict[str, Any] = dataclasses.field(default_factory=dict)
    generalized: dict[str, Any] = dataclasses.field(default_factory=dict)
    generalized_eval: dict[str, Any] = dataclasses.field(default_factory=dict)
    timings: dict[str, float] = dataclasses.field(default_factory=dict)
    notes: list[str] = dataclasses.field(default_factory=list)


def headline_generalized(study: Study) -> str | None:
    """The generalized model of Figs 11-12 and `fit.json`: `"joint"` where it was run
    (measured data), else `"two-step"`; None without one."""
    for k in ("joint", "two-step"):
        if k in study.generalized:
            return k
    return None


def _reevaluated(result: FitResult, model: AbstractModel, batch: Batch) -> FitResult:
    """`result` with `model` (sub-steps resolved from its parameters) and its RMS recomputed."""
    m = resolve_model(model, result.theta, batch.xdot, batch.dt, batch.mask)
    rms = np.asarray(rms_per_condition(m, result.theta, batch, batch.mask), float)
    return dataclasses.replace(result, model=model, rms=rms,
                               nrmse=nrmse(rms, batch.force, batch.mask))


def _bouc_wen_swarm_model(batch: Batch) -> AbstractModel:
    """Bouc-Wen with one RK4 step per `BW_SWARM_STEP_S` of the longest sample interval."""
    dt = np.where(np.asarray(batch.mask), np.asarray(batch.dt), 0.0)
    n_sub = max(1, math.ceil(float(np.max(dt)) / BW_SWARM_STEP_S - 1e-9))
    return get("bouc_wen").with_substeps(n_sub)


def _paper_box(study: Study, model: str):
    """`PAPER_BOX[model]` on the embedded data, None (the model's default box) otherwise."""
    return PAPER_BOX[model] if study.data_info["truth"] else None


def _swarm(study: Study, mode: str) -> Swarm:
    """The study's swarm in `mode` (capped at `QUICK_GENERATIONS` in a quick study)."""
    return Swarm(mode=mode, max_generations=QUICK_GENERATIONS if study.quick else 200)


def _job_kwok_paper_swarm(study: Study) -> FitResult:
    return fit("kwok", study.batch, swarm=_swarm(study, "full"), polish=None, key=study.seed,
               bounds=_paper_box(study, "kwok"))


def _job_bouc_wen_paper_swarm(study: Study) -> FitResult:
    r = fit(_bouc_wen_swarm_model(study.batch), study.batch, swarm=_swarm(study, "full"),
            polish=None, key=study.seed, bounds=_paper_box(study, "bouc_wen"))
    return _reevaluated(r, get("bouc_wen"), study.batch)


def _job_bouc_wen_separable(study: Study) -> FitResult:
    r = fit(_bouc_wen_swarm_model(study.batch), study.batch, swarm=_swarm(study, "separable"),
            polish=None, key=study.seed)
    return _reevaluated(r, get("bouc_wen"), study.batch)


def _job_kwok_separable(study: Study) -> FitResult:
    return fit("kwok", study.batch, swarm=_swarm(study, "separable"), key=study.seed)


def _job_kwok_paper_swarm_polished(study: Study) -> FitResult:
    """The paper's-swarm tanh result after the engine's Levenberg-Marquardt polish, in the
    model's own box (the optimum may lie outside the paper's narrower swarm box)."""
    swarm_only = dataclasses.replace(study.runs["kwok_paper_swarm"], bounds=None)
    return polish_fit(swarm_only, study.batch)


_JOBS: dict[str, Callable[[Study], FitResult]] = {
    "kwok_paper_swarm": _job_kwok_paper_swarm,
    "bouc_wen_paper_swarm": _job_bouc_wen_paper_swarm,
    "bouc_wen_separable": _job_bouc_wen_separable,
    "kwok_separable": _job_kwok_separable,
    "kwok_paper_swarm_polished": _job_kwok_paper_swarm_polished,
}


def _describe(name: str, res: FitResult) -> str:
    title = RUN_TITLES[name]
    if name == "kwok_separable":
        return (f"{title}: median RMS {finite_median(res.pso_rms):.2f} N (swarm) -> "
                f"{finite_median(res.rms):.2f} N")
    if res.method == "pso":
        return (f"{title}: median {finite_median(res.generations):g} generations, median RMS "
                f"{finite_median(res.rms):.1f} N")
    return f"{title}: median RMS {finite_median(res.rms):.2f} N"


def _run_jobs(study: Study, names: Sequence[str], log: StageLog, target: dict[str, Any],
              cancel: threading.Event | None = None) -> dict[str, Any]:
    """Run the jobs `names` in order, storing each result in `target` as it comes."""
    for name in names:
        if cancel is not None and cancel.is_set():
            break
        t = time.perf_counter()
        target[name] = _JOBS[name](study)
        log.timings[name] = time.perf_counter() - t
        log.say(_describe(name, target[name]))
    return target


def _generalize(study: Study) -> None:
    """Stage 3: the two-step laws of the accurate tanh fit (skipped without currents)."""
    batch = study.batch
    cur = np.asarray(batch.current, float)
    if not np.all(np.isfinite(cur)):
        study.notes.append("Generalization skipped: some conditions have no current.")
        return
    if np.unique(cur).size < 2:
        study.notes.append("Generalization skipped: the data have a single current.")
        return
    res = study.runs["kwok_separable"]
    # the paper's forms (eq 24-29: the tanh model's default degrees), whose coefficients the
    # study compares, not the forms the data would choose (`laws="auto"`)
    study.generalized["two-step"] = generalize(res, batch, method="two-step", laws="fixed")
    study.generalized["two-step-equal"] = generalize(res, batch, method="two-step",
                                                     weighting="equal", laws="fixed")
    if not study.data_info["truth"] and not study.quick:
        # measured data: laws of per-test averages of nonlinear parameters can fit poorly;
        # the joint fit of the law coefficients on all tests never does worse
        study.generalized["joint"] = generalize(res, batch, method="joint", key=study.seed,
                                                laws="fixed")
    for k, gm in study.generalized.items():
        study.generalized_eval[k] = gm.evaluate(batch)


# --------------------------------------------------------------------------------------------
# compute


def compute(
    data: str | os.PathLike | None = None,
    *,
    quick: bool = False,
    seed: int = 0,
    verbose: bool = True,
    log: StageLog | None = None,
    on_progress: Callable[[Study, bool], None] | None = None,
) -> Study:
    """Run every identification of the study (no figures, no files).

    Two threads share the work: the background one runs the Bouc-Wen swarms (and, in quick
    mode, where there is no Bouc-Wen separable swarm, first the tanh paper's swarm), the main
    one the tanh identifications and the generalization. No result depends on the split.

    **Arguments:** `data`, `quick`, `seed` as for :func:`run`; `verbose` prints stage progress
    on stderr; `on_progress(study, final)` is called in the main thread after the main
    thread's stages (`final=False`, while the background stages may still run) and at the end
    (`final=True`); `run` draws there every figure whose inputs are ready.

    **Returns:** a :class:`Study`.
    """
    log = log or StageLog(verbose)
    t = time.perf_counter()
    batch, info = load_study_data(data, quick=quick)
    log.timings["data"] = time.perf_counter() - t
    study = Study(batch=batch, data_info=info, seed=int(seed), quick=bool(quick),
                  timings=log.timings)
    log.say(f"data: {batch.n_conditions} conditions ({info['source']})"
            + (", quick" if quick else ""))
    if info["trimmed"]:
        study.notes.append(f"{len(info['trimmed'])} records were cut to their last "
                           f"{DATA_CYCLES} cycles.")

    if quick:
        bg_names = ["kwok_paper_swarm", "bouc_wen_paper_swarm"]
        main_names = ["kwok_separable"]
    else:
        bg_names = ["bouc_wen_paper_swarm", "bouc_wen_separable"]
        main_names = ["kwok_paper_swarm", "kwok_separable", "kwok_paper_swarm_polished"]
    bg = _Background(lambda cancel: _run_jobs(study, bg_names, log, {}, cancel))
    try:
        _run_jobs(study, main_names, log, study.runs)
        t = time.perf_counter()
        _generalize(study)
        log.timings["generalize"] = time.perf_counter() - t
        for k, gm in study.generalized.items():
            log.say(f"generalized ({k}): total RMS {gm.total_rms:.2f} N")
        if on_progress is not None:
            on_progress(study, False)
        t = time.perf_counter()
        study.runs.update(bg.result())
        log.timings["wait_background"] = time.perf_counter() - t
    except BaseException:
        bg.stop()
        raise
    if "kwok_paper_swarm_polished" not in study.runs:
        _run_jobs(study, ["kwok_paper_swarm_polished"], log, study.runs)
    study.runs = {k: study.runs[k] for k in RUN_TITLES if k in study.runs}
    if on_progress is not None:
        on_progress(study, True)
    return study
