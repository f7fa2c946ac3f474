"""Thousands of tests: `mrjax.fit` over the condition axis in chunks of bounded memory.

A layer above the engine: it checks the whole batch once, plans chunks whose working set fits
a memory budget (`mrjax.fitting.plan_chunks`), builds each chunk's per-test problem and runs the
engine on it (`fit_chunk`), and concatenates the results; optionally it writes each finished
chunk to a journal (`mrjax.fitting.Journal`) from which an interrupted fit resumes.

**Same result, whatever the chunking.** Every condition's fit depends only on its own data and
its own random stream (`mrjax.pso.swarm` with one key per row), so the chunk layer

- splits the key once for the whole batch, `jax.random.split(key, restarts * C)` (copy k of
  condition i at row k*C + i, as `restarts` orders them), and gives each chunk its rows' keys;
- takes each chunk's rows with the padded length T of the whole batch
  (`mrjax.parallel.take_conditions`) and pads the swarm's view to the view length of the whole
  batch, so that every sum over samples runs over the same samples;
- gives every chunk the same number of conditions (the last one padded with copies of its last
  condition, fitted and dropped, as `mrjax.parallel.pad_conditions` pads for devices), so that
  one compiled program serves every chunk; that number is a multiple of XLA's vector width per
  device (`VECTOR_BYTES`), and a batch that could be chunked is padded alike when it runs in one
  chunk, so that every condition runs in vector code, never in the scalar remainder loop;
- holds at least `MIN_CHUNK_ELEMENTS` swarm rows x samples and rows x particles per chunk, so
  that the swarm's batched sums run on the same XLA kernels in every chunk as in the whole
  batch.

The results are then bit for bit those of one chunk (`tests/test_chunks.py`). Two limits: a
batched sum over a few elements per condition (below XLA's kernel threshold in a small chunk,
above it in the whole batch) can differ in its last bits; and the ODE models integrated by
RK4 (`bouc_wen`, `modified_bouc_wen`) choose the polish's sub-step count for the stiffest
condition of the compiled batch (`mrjax.models.resolve_model`), so two chunkings agree only
where their chunks choose the same count: fix it (`mrjax.models.get(name, substeps=m)`) for
results that never depend on the chunking. Static models and Dahl (one exact step per sample)
have no such choice.

**Memory.** A chunk's working set is estimated per condition from the model, the record and
view lengths, the swarm size and precision and the restarts (:func:`condition_bytes`, a model
calibrated by measuring the peak RSS of fits in fresh processes; see its docstring), the
resident part from the data and the results (:func:`resident_bytes`). The chunk holds as many
conditions as the budget leaves room for: by default `DEFAULT_MEMORY_FRACTION` (half) of the
memory available when the fit starts, on top of what the process already holds.

**Streamed.** Tests that stay in their files (a `mrjax.data.Source` not held in memory) are
read twice, a group of tests at a time: once, `CHECK_BYTES` at a time, to check every test as a
whole batch is checked (its errors and warnings before any work) and to find the swarm view's
length of the whole; then chunk by chunk, each read as it is fitted
(`Source.batch(rows, length=source.length)`, rows bit for bit those of the whole batch). The
resident part is then the runtime and the results only; reading a chunk costs
`READ_BATCHES` batches of its tests on top of its working set. Same chunks, same keys, same
view length: the result is that of the fit of the same tests held in memory.
"""

from __future__ import annotations

import dataclasses
import hashlib
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from .._errors import InputError
from ..data import Batch, Source, as_batch
from ..engine import Chunks, Polish, Swarm, row_keys, solve
from ..models import AbstractModel, get
from ..objective import nrmse
from ..parallel import pad_conditions, resolve_devices, take_conditions
from ..refine import Status
from ._journal import Journal, fingerprint
from ._plan import (
    MIN_CHUNK_ELEMENTS,
    MIN_ROWS,
    RUNTIME_BYTES,
    VECTOR_BYTES,
    ChunkPlan,
    condition_bytes,
    default_budget,
    parse_memory,
    plan_chunks,
    resident_bytes,
    results_bytes,
)
from ._problem import TestsProblem
from ._result import FitResult, merge
from ._retry import neighbours, retry_starts
from ._run import Run, fit_chunk, make_run, problem_of, uncertainty_fields, wants_retry


def _bar(enabled: bool | None, plan: ChunkPlan):
    """The chunks' progress bar (conditions done, chunk j/n), or None."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled or plan.n_chunks < 2:
        return None
    from tqdm.auto import tqdm  # imported here: only a terminal run draws a bar

    return tqdm(total=plan.n_conditions, desc=f"chunk 0/{plan.n_chunks}", unit="cond",
                file=sys.stderr, position=0)


#: Bytes of tests a streamed fit reads at a time to check them (before the plan).
CHECK_BYTES = 256_000_000
#: Batches' worth of memory per test that reading a chunk from its files costs (the parsed
#: columns, the conditions, the batch on the host), on top of the chunk's working set.
READ_BATCHES = 3


def _plan(whole: TestsProblem, run: Run, n_dev: int, *, n_conditions: int | None = None,
          resident: int | None = None, extra_per_condition: int = 0) -> ChunkPlan:
    """The chunks of a fit whose whole batch is the problem `whole` (a streamed fit: a
    problem of a few of its tests, with the whole's `n_conditions`, `resident` bytes and the
    reading's `extra_per_condition` bytes), by `run.chunks`' budget or size."""
    max_memory, chunk_size = run.chunks.max_memory, run.chunks.size
    budget = None if max_memory is None else parse_memory(max_memory)
    sw = run.swarm
    k = sw.n_restarts if sw is not None else 1
    t_swarm = whole.view.batch.length if whole.view is not None else whole.source.length
    dtype = sw.dtype if sw is not None else None
    lanes = max(1, VECTOR_BYTES // (np.dtype(dtype).itemsize if dtype is not None else 8))
    minimum = max(MIN_ROWS * n_dev, -(-MIN_CHUNK_ELEMENTS // (k * t_swarm)))
    if sw is not None:
        minimum = max(minimum, -(-MIN_CHUNK_ELEMENTS // (k * sw.n_particles)))
    shape = dict(per_condition=condition_bytes(whole, run) + extra_per_condition,
                 resident=resident_bytes(whole, run) if resident is None else resident,
                 devices=n_dev, lanes=lanes, minimum=minimum)
    C = whole.n_real if n_conditions is None else n_conditions
    if budget is None and chunk_size is None:
        return plan_chunks(C, budget=max(default_budget(), shape["resident"]), strict=False,
                           **shape)
    return plan_chunks(C, budget=budget, size=chunk_size, **shape)


def chunk_plan(model: str | AbstractModel, data: Any, *, swarm: Swarm | None = Swarm(),
               polish: Polish | None = Polish(), bounds: Any = None, transient: Any = None,
               chunks: Chunks | None = None) -> ChunkPlan:
    """The chunks `mrjax.fit(model, data, ...)` would run with the same arguments (without
    fitting): e.g. `chunk_plan("kwok", batch, chunks=mrjax.Chunks(max_memory="8GB")).n_chunks`.
    Raises what `mrjax.fit` raises for bad settings or data, or a budget too small."""
    model, data = get(model), as_batch(data)
    run = make_run(model, data.n_conditions, swarm=swarm, polish=polish, key=0, bounds=bounds,
                   transient=transient, chunks=chunks)
    return _plan(problem_of(model, data, run, devices=None), run, _device_count(run))


def _device_count(run: Run) -> int:
    return 1 if run.devices is None else len(resolve_devices(run.devices))


@dataclasses.dataclass(frozen=True, eq=False)
class Chunked:
    """A per-test fit laid out in chunks (:func:`layout`): `whole` the problem of the whole
    batch (of its first tests, streamed), `plan` the chunks, `keys` (k, C, 2) every swarm row's
    key, `view_length` the swarm views' length of the whole, `take(rows) -> Batch` the reader
    of a chunk's tests, `digest` the SHA-256 of a streamed fit's tests ("" otherwise)."""

    whole: TestsProblem
    plan: ChunkPlan
    keys: np.ndarray
    view_length: int | None
    take: Callable
    digest: str = ""

    def chunk(self, j: int) -> tuple[Batch, np.ndarray, int]:
        """Chunk `j`: its batch padded to the plan's size, the rows (padded rows repeat the
        last), and its real conditions."""
        start, stop = self.plan.bounds(j)
        rows = np.arange(start, stop)
        chunk, _, n = pad_conditions(self.take(rows), None, self.plan.size)
        return chunk, np.concatenate([rows, np.full(self.plan.size - n, rows[-1])]), n

    def chunk_keys(self, padded: np.ndarray) -> np.ndarray:
        """The swarm rows' keys of a chunk's (padded) rows."""
        k = self.keys.shape[0]
        return self.keys[:, padded].reshape(k * padded.size, 2)

    def problem(self, j: int, run: Run) -> tuple[TestsProblem, np.ndarray, int]:
        """The per-test problem of chunk `j`, its padded rows and its real conditions."""
        chunk, padded, n = self.chunk(j)
        return (problem_of(self.whole.model, chunk, run, view_length=self.view_length,
                           checked=True), padded, n)


def layout(model: AbstractModel, data: Batch | Source, run: Run, key: Any) -> Chunked:
    """The chunks of a fit (see the module docstring): the whole batch checked once before
    any work (errors and warnings name its conditions), the plan, one stream per swarm row
    split once for the whole batch."""
    k = run.swarm.n_restarts if run.swarm is not None else 1
    n_dev = _device_count(run)
    if isinstance(data, Source) and not data.kept:
        return _streamed(model, data, run, n_dev, key)
    if isinstance(data, Source):
        data = data.batch()
    whole = problem_of(model, data, run, devices=None)
    plan = _plan(whole, run, n_dev)
    keys = row_keys(key, k * whole.n_real).reshape(k, whole.n_real, 2)
    view_length = whole.view.batch.length if whole.view is not None else None
    return Chunked(whole, plan, keys, view_length,
                   lambda rows: take_conditions(whole.source, rows)[0])


def _journal(chunked: Chunked, run: Run) -> tuple[Journal | None, Chunked]:
    """The journal of a fit with more than one chunk (or asked to resume), and the layout with
    the journal's plan."""
    ch = run.chunks
    if ch.journal is None or not (ch.resume or chunked.plan.n_chunks > 1):
        return None, chunked
    fp = fingerprint(chunked.whole, run, chunked.keys.reshape(-1, 2)) + chunked.digest
    jr = Journal.open(ch.journal, fp, chunked.plan, resume=bool(ch.resume))
    n_dev = _device_count(run)
    if jr.plan.size % n_dev:
        raise InputError(f"cannot resume: the journal's chunks of {jr.plan.size} conditions "
                         f"do not divide over {n_dev} devices")
    return jr, dataclasses.replace(chunked, plan=jr.plan)


def fit_in_chunks(model: AbstractModel, data: Batch | Source, run: Run, key: Any
                  ) -> FitResult:
    """`mrjax.fit` in chunks (see the module docstring): `run` the settings of the fit, `key`
    its seed or PRNG key; `data` a batch, or a `mrjax.data.Source` (streamed from its files
    unless it holds its tests)."""
    t0 = time.perf_counter()
    retry = wants_retry(run, model, data.n_conditions)
    chunked = layout(model, data, run, key)
    jr, chunked = _journal(chunked, run)
    plan = chunked.plan
    done = jr.finished(chunked.whole.model) if jr is not None else {}
    parts: list[FitResult] = []
    bar = _bar(run.progress, plan)
    try:
        if bar is not None and done:
            bar.update(sum(r.n_conditions for r in done.values()))
        for j in range(plan.n_chunks):
            if j in done:
                parts.append(done[j])
                continue
            chunk, padded, n = chunked.chunk(j)
            # std-errors once, after the retry, at the better of the two starts
            res = fit_chunk(chunked.whole.model, chunk, run, chunked.chunk_keys(padded),
                            uncertainty=run.uncertainty and not retry,
                            view_length=chunked.view_length, checked=True)
            res = res.subset(np.arange(n)) if res.n_conditions != n else res
            if jr is not None:
                jr.record(j, res)
            parts.append(res)
            if bar is not None:
                bar.set_description(f"chunk {j + 1}/{plan.n_chunks}")
                bar.update(n)
    finally:
        if bar is not None:
            bar.close()
    result = FitResult.concatenate(parts)
    timings = dict(result.timings)
    if retry:
        t1 = time.perf_counter()
        result = _retry(result, run, chunked)
        timings["retry"] = time.perf_counter() - t1
        if run.uncertainty:
            t2 = time.perf_counter()
            result = _uncertainty(result, run, chunked)
            timings["uncertainty"] = time.perf_counter() - t2
    timings["total"] = time.perf_counter() - t0
    return dataclasses.replace(result, timings=timings)


def _streamed(model: AbstractModel, source: Source, run: Run, n_dev: int, key: Any
              ) -> Chunked:
    """A streamed fit's check pass (see the module docstring): its layout, with a problem of
    its first tests for the plan and the journal, the view length of the whole, the chunk
    reader and the SHA-256 of every test read."""
    C, T = source.n_conditions, source.length
    per_test = max(1, source.batch_bytes(1))
    max_memory = run.chunks.max_memory
    budget = CHECK_BYTES if max_memory is None else min(CHECK_BYTES, parse_memory(max_memory) // 4)
    group = max(1, budget // (READ_BATCHES * per_test))
    view_length, h = 0, hashlib.sha256()
    for start in range(0, C, group):
        batch = source.batch(np.arange(start, min(C, start + group)), length=T)
        p = problem_of(model, batch, run, devices=None)  # the checks of the whole, by groups
        if p.view is not None:
            view_length = max(view_length, p.view.batch.length)
        for i in range(batch.n_conditions):  # per test: the same digest however grouped
            h.update(batch.labels[i].encode())
            for name in ("t", "x", "xdot", "force", "dt", "command", "mask", "current",
                         "frequency", "amplitude", "command_kind", "estimated"):
                h.update(np.asarray(getattr(batch, name)[i]).tobytes())
    view = view_length or None
    first = source.batch(np.arange(min(C, MIN_ROWS)), length=T, warn=False)
    probe = problem_of(model, first, run, devices=None, view_length=view, checked=True)
    resident = RUNTIME_BYTES + results_bytes(probe.model.n_params, run, C)
    plan = _plan(probe, run, n_dev, n_conditions=C, resident=resident,
                 extra_per_condition=READ_BATCHES * per_test)
    k = run.swarm.n_restarts if run.swarm is not None else 1
    keys = row_keys(key, k * C).reshape(k, C, 2)
    return Chunked(probe, plan, keys, view,
                   lambda rows: source.batch(rows, length=T, warn=False), h.hexdigest())


def _retry(result: FitResult, run: Run, chunked: Chunked) -> FitResult:
    """Every test polished again from the best of its neighbours' optima (`retry_starts`),
    chunk by chunk (the chunks' shapes: the first pass's compiled polish serves), and per test
    the better of the two kept (`merge`)."""
    donors = neighbours(result.current, result.frequency, result.amplitude)
    theta = np.asarray(result.theta, float)
    parts: dict[str, list] = {"theta": [], "rms": [], "nrmse": [], "polish_steps": []}
    status: tuple[Status, ...] = ()
    for j in range(chunked.plan.n_chunks):
        problem, padded, n = chunked.problem(j, run)
        z0, _ = retry_starts(problem, donors, theta, padded[:n])
        out = solve(problem, swarm=None, polish=run.polish, uncertainty=False, start=z0)
        parts["theta"].append(out.z[:n])
        parts["rms"].append(out.rms[:n])
        parts["nrmse"].append(np.asarray(nrmse(out.rms, problem.batch.force,
                                               problem.placed_mask))[:n])
        parts["polish_steps"].append(np.asarray(out.steps, int)[:n])
        status += tuple(out.status[:n])
    again = dataclasses.replace(result, polish_status=status,
                                **{k: np.concatenate(v) for k, v in parts.items()})
    return merge(result, again)


def _uncertainty(result: FitResult, run: Run, chunked: Chunked) -> FitResult:
    """The std-errors, intervals and identifiability of `result`, chunk by chunk."""
    theta = np.asarray(result.theta, float)
    fields: dict[str, list] = {}
    for j in range(chunked.plan.n_chunks):
        problem, padded, n = chunked.problem(j, run)
        z = theta[padded]
        if problem.n_units > z.shape[0]:  # device padding repeats the last condition
            z = np.concatenate([z, np.repeat(z[-1:], problem.n_units - z.shape[0], axis=0)])
        for k, v in uncertainty_fields(problem, z, n).items():
            fields.setdefault(k, []).append(v)
    return dataclasses.replace(result, **{k: np.concatenate(v) for k, v in fields.items()})
