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
view length: the result is that of the fit of the same tests held in memory. The check keeps
each test's SHA-256 (:func:`test_digests`); a chunk read again must match it, so that a file
changed during the fit fails with its tests named instead of fitting other data than was
checked.

**Where chunks run.** Every pass (the streamed check; the fit; the retry with the std-errors,
each chunk read once for both) maps a function of one chunk over the chunks through a pool
(`mrjax.fitting._cluster`): in this process, or, with `Chunks(cluster=...)`, one Dask task per
chunk. What a chunk needs travels once, as one :class:`Chunked` (the model, the settings, the
plan, every row's key, and where the tests are: the checked batch held in memory, or the
`Source` index from which each worker reads its own chunks from the files); the results come
back to this process in chunk order (the journal written as they come). Each chunk's result
depends only on its data, its keys and the chunk shape, so a cluster's result is bit for bit
that of one process with the same chunks.
"""

from __future__ import annotations

import dataclasses
import hashlib
import sys
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from .._errors import InputError
from .._warnings import ResultWarning
from ..data import Batch, Source, as_batch
from ..engine import Chunks, Polish, Swarm, row_keys, solve
from ..models import AbstractModel, get
from ..objective import nrmse
from ..parallel import pad_conditions, take_conditions
from ..refine import Status
from ._cluster import ClusterPool, LocalPool, open_pool
from ._journal import Journal, fingerprint
from ._plan import (
    MIN_CHUNK_ELEMENTS,
    MIN_ROWS,
    RUNTIME_BYTES,
    VECTOR_BYTES,
    ChunkPlan,
    condition_bytes,
    parse_memory,
    plan_chunks,
    resident_bytes,
    results_bytes,
)
from ._problem import TestsProblem
from ._result import FitResult, merge, retry_wins
from ._retry import neighbours, retry_starts
from ._run import Run, fit_chunk, make_run, problem_of, uncertainty_fields, wants_retry

Pool = LocalPool | ClusterPool


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
#: The fields of a test its digest covers (with its label), as the batch holds them.
DIGEST_FIELDS = ("t", "x", "xdot", "force", "dt", "command", "mask", "current", "frequency",
                 "amplitude", "command_kind", "estimated")


def test_digests(batch: Batch) -> np.ndarray:
    """The SHA-256 of each test of `batch` (its label and `DIGEST_FIELDS` as held, padding
    included), (C, 32) uint8."""
    arrays = [np.asarray(getattr(batch, name)) for name in DIGEST_FIELDS]
    out = np.empty((batch.n_conditions, 32), np.uint8)
    for i, label in enumerate(batch.labels):
        h = hashlib.sha256(label.encode())
        for a in arrays:
            h.update(np.ascontiguousarray(a[i]).tobytes())
        out[i] = np.frombuffer(h.digest(), np.uint8)
    return out


def _plan(whole: TestsProblem, run: Run, n_dev: int, pool: Pool, *,
          n_conditions: int | None = None, resident: int | None = None,
          extra_per_condition: int = 0) -> ChunkPlan:
    """The chunks of a fit whose whole batch is the problem `whole` (a streamed fit: a
    problem of a few of its tests, with the whole's `n_conditions`, `resident` bytes and the
    reading's `extra_per_condition` bytes), by `run.chunks`' budget or size (none: the
    `pool`'s default budget)."""
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
        return plan_chunks(C, budget=max(pool.default_budget(), shape["resident"]),
                           strict=False, **shape)
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
    with open_pool(run.chunks) as pool:
        return _plan(problem_of(model, data, run, devices=None), run,
                     pool.device_count(run.devices), pool)


@dataclasses.dataclass(frozen=True, eq=False)
class Chunked:
    """A per-test fit laid out in chunks (:func:`layout`): what the work on any chunk needs,
    in one object that a cluster's workers get once. `model` the model as the whole batch
    resolved it, `run` the settings (without the cluster and the progress bar), `plan` the
    chunks, `keys` (k, C, 2) every swarm row's key, `view_length` the swarm views' length of
    the whole, `tests` where a chunk's tests are read from (the checked batch, or the
    `mrjax.data.Source` of a streamed fit), `length` the padded length T of the whole,
    `labels` (C,) and, streamed, `digests` (C, 32) each test's SHA-256 as checked."""

    model: AbstractModel
    run: Run
    plan: ChunkPlan
    keys: np.ndarray
    view_length: int | None
    tests: Batch | Source
    length: int
    labels: tuple[str, ...]
    digests: np.ndarray | None = None

    @property
    def digest(self) -> str:
        """The SHA-256 of a streamed fit's tests ("" for tests held in memory)."""
        return "" if self.digests is None else hashlib.sha256(self.digests.tobytes()).hexdigest()

    def named(self, rows: np.ndarray) -> str:
        """The tests at `rows` (consecutive) in words, for a message."""
        labs = [repr(self.labels[int(i)]) for i in rows]
        shown = labs if len(labs) <= 6 else labs[:3] + ["..."] + labs[-2:]
        return f"tests {', '.join(shown)} ({len(labs)} tests, rows {rows[0]} to {rows[-1]})"

    def take(self, rows: np.ndarray, what: str | None = None) -> Batch:
        """The tests at `rows`, padded to the length of the whole; read from their files,
        they must be those checked. Raises :class:`mrjax.InputError` naming them (`what`:
        in these words) otherwise."""
        if isinstance(self.tests, Batch):
            return take_conditions(self.tests, rows)[0]
        what = self.named(rows) if what is None else what
        try:
            batch = self.tests.batch(rows, length=self.length, warn=False)
        except (InputError, OSError) as e:
            raise InputError(f"{what}: {e}") from None
        changed = np.flatnonzero((test_digests(batch) != self.digests[rows]).any(axis=1))
        if changed.size:
            more = f" (and {changed.size - 1} more)" if changed.size > 1 else ""
            raise InputError(f"{what}: test {batch.labels[changed[0]]!r}{more} changed in its "
                             f"file since the fit checked it; run the fit again")
        return batch

    def chunk(self, j: int) -> tuple[Batch, np.ndarray, int]:
        """Chunk `j`: its batch padded to the plan's size, the rows (padded rows repeat the
        last), and its real conditions."""
        start, stop = self.plan.bounds(j)
        rows = np.arange(start, stop)
        chunk, _, n = pad_conditions(self.take(rows, self.describe(j)), None, self.plan.size)
        return chunk, np.concatenate([rows, np.full(self.plan.size - n, rows[-1])]), n

    def chunk_keys(self, padded: np.ndarray) -> np.ndarray:
        """The swarm rows' keys of a chunk's (padded) rows."""
        k = self.keys.shape[0]
        return self.keys[:, padded].reshape(k * padded.size, 2)

    def problem(self, j: int) -> tuple[TestsProblem, np.ndarray, int]:
        """The per-test problem of chunk `j`, its padded rows and its real conditions."""
        chunk, padded, n = self.chunk(j)
        return (problem_of(self.model, chunk, self.run, view_length=self.view_length,
                           checked=True), padded, n)

    def describe(self, j: int) -> str:
        """Chunk `j`'s tests in words."""
        start, stop = self.plan.bounds(j)
        return f"chunk {j + 1} of {self.plan.n_chunks}, {self.named(np.arange(start, stop))}"


def _task_run(run: Run, pool: Pool) -> Run:
    """The settings a chunk's work runs with: no cluster, no journal (and on a cluster no
    progress bar)."""
    chunks = run.chunks
    return dataclasses.replace(
        run, progress=run.progress if isinstance(pool, LocalPool) else False,
        chunks=Chunks(max_memory=chunks.max_memory, size=chunks.size, devices=chunks.devices))


def layout(model: AbstractModel, data: Batch | Source, run: Run, key: Any, pool: Pool,
           n_dev: int) -> tuple[TestsProblem, Chunked]:
    """The chunks of a fit on the `pool` with `n_dev` devices per chunk (see the module
    docstring): the whole batch checked once before any work (errors and warnings name its
    conditions), the plan, one stream per swarm row split once for the whole batch. Returns
    the problem of the whole batch (of its first tests, streamed) and the
    :class:`Chunked`."""
    k = run.swarm.n_restarts if run.swarm is not None else 1
    if isinstance(data, Source) and not data.kept:
        return _streamed(model, data, run, n_dev, key, pool)
    if isinstance(data, Source):
        data = data.batch()
    whole = problem_of(model, data, run, devices=None)
    plan = _plan(whole, run, n_dev, pool)
    keys = row_keys(key, k * whole.n_real).reshape(k, whole.n_real, 2)
    view_length = whole.view.batch.length if whole.view is not None else None
    return whole, Chunked(whole.model, _task_run(run, pool), plan, keys, view_length, whole.source,
                          whole.source.length, tuple(whole.source.labels))


def _journal(whole: TestsProblem, chunked: Chunked, run: Run, n_dev: int
             ) -> tuple[Journal | None, Chunked]:
    """The journal of a fit with more than one chunk (or asked to resume), and the layout with
    the journal's plan."""
    ch = run.chunks
    if ch.journal is None or not (ch.resume or chunked.plan.n_chunks > 1):
        return None, chunked
    fp = fingerprint(whole, run, chunked.keys.reshape(-1, 2)) + chunked.digest
    jr = Journal.open(ch.journal, fp, chunked.plan, resume=bool(ch.resume))
    if jr.plan.size % n_dev:
        raise InputError(f"cannot resume: the journal's chunks of {jr.plan.size} conditions "
                         f"do not divide over {n_dev} devices")
    return jr, dataclasses.replace(chunked, plan=jr.plan)


def fit_in_chunks(model: AbstractModel, data: Batch | Source, run: Run, key: Any
                  ) -> FitResult:
    """`mrjax.fit` in chunks (see the module docstring): `run` the settings of the fit, `key`
    its seed or PRNG key; `data` a batch, or a `mrjax.data.Source` (streamed from its files
    unless it holds its tests); on `run.chunks.cluster`, if any."""
    t0 = time.perf_counter()
    retry = wants_retry(run, model, data.n_conditions)
    with open_pool(run.chunks) as pool:
        n_dev = pool.device_count(run.devices)
        whole, chunked = layout(model, data, run, key, pool, n_dev)
        jr, chunked = _journal(whole, chunked, run, n_dev)
        work = pool.share(chunked, model=chunked.model)
        # std-errors once, after the retry, at the better of the two starts
        result = _first_pass(chunked, work, pool, jr, run.uncertainty and not retry,
                             run.progress)
        timings = dict(result.timings)
        if retry:
            result, seconds = _retry(result, chunked, work, pool, run.uncertainty)
            timings.update(seconds)
    timings["total"] = time.perf_counter() - t0
    return dataclasses.replace(result, timings=timings)


def _first_pass(chunked: Chunked, work: Any, pool: Pool, jr: Journal | None,
                uncertainty: bool, progress: bool | None) -> FitResult:
    """Every chunk not in the journal fitted (`_fit_part`), written to the journal as it
    comes, and the results concatenated in chunk order."""
    plan = chunked.plan
    parts = jr.finished(chunked.model) if jr is not None else {}
    resumed = len(parts)
    todo = [j for j in range(plan.n_chunks) if j not in parts]
    bar = _bar(progress, plan)
    try:
        if bar is not None and parts:
            bar.update(sum(r.n_conditions for r in parts.values()))
        for j, res in pool.map(_fit_part, todo, work, uncertainty, describe=chunked.describe):
            res = dataclasses.replace(res, model=chunked.model)  # this process's model
            if jr is not None:
                jr.record(j, res)
            parts[j] = res
            if bar is not None:
                bar.set_description(f"chunk {len(parts)}/{plan.n_chunks}")
                bar.update(res.n_conditions)
    except InputError as e:
        if jr is None or len(parts) == resumed:
            raise
        raise InputError(f"{e}; the {len(parts)} chunk(s) fitted are kept in the journal "
                         f"{jr.path}: resume to fit only the others") from None
    finally:
        if bar is not None:
            bar.close()
    return FitResult.concatenate([parts[j] for j in range(plan.n_chunks)])


def _fit_part(j: int, chunked: Chunked, uncertainty: bool) -> FitResult:
    """The fit of chunk `j` (a task): the engine on its problem, its padding cut off."""
    chunk, padded, n = chunked.chunk(j)
    res = fit_chunk(chunked.model, chunk, chunked.run, chunked.chunk_keys(padded),
                    uncertainty=uncertainty, view_length=chunked.view_length, checked=True)
    return res.subset(np.arange(n)) if res.n_conditions != n else res


@dataclasses.dataclass(frozen=True, eq=False)
class _Check:
    """What the check of a streamed fit's group of tests needs (:func:`_check_part`)."""

    model: AbstractModel
    run: Run
    source: Source
    group: int


@dataclasses.dataclass(frozen=True)
class _Checked:
    """A group of tests checked: their swarm view's length (0: no view), labels, digests,
    and the warnings their checks issued (category, message or `ResultWarning.to_dict()`)."""

    view_length: int
    labels: tuple[str, ...]
    digests: np.ndarray
    warned: tuple[tuple[type, Any], ...]


def _check_part(g: int, check: _Check) -> _Checked:
    """The check of group `g` of a streamed fit's tests (a task), as a whole batch is
    checked; its warnings recorded to be issued where the fit runs."""
    C, T = check.source.n_conditions, check.source.length
    rows = np.arange(g * check.group, min(C, (g + 1) * check.group))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        batch = check.source.batch(rows, length=T)
        p = problem_of(check.model, batch, check.run, devices=None)
    warned = tuple((w.category, w.message.to_dict() if isinstance(w.message, ResultWarning)
                    else str(w.message)) for w in caught)
    return _Checked(p.view.batch.length if p.view is not None else 0, tuple(batch.labels),
                    test_digests(batch), warned)


def _reissue(warned: tuple[tuple[type, Any], ...]) -> None:
    """The warnings a check recorded, issued here."""
    for category, message in warned:
        w = ResultWarning.from_dict(message) if isinstance(message, dict) else message
        warnings.warn(w if isinstance(w, Warning) else category(w), stacklevel=5)


def _streamed(model: AbstractModel, source: Source, run: Run, n_dev: int, key: Any,
              pool: Pool) -> tuple[TestsProblem, Chunked]:
    """A streamed fit's check pass (see the module docstring; on the pool: `CHECK_BYTES` of
    tests, or a quarter of the memory budget, per task): its layout, with a problem of its
    first tests for the plan and the journal, the view length of the whole and every test's
    label and digest."""
    C, T = source.n_conditions, source.length
    per_test = max(1, source.batch_bytes(1))
    max_memory = run.chunks.max_memory
    budget = CHECK_BYTES if max_memory is None else min(CHECK_BYTES, parse_memory(max_memory) // 4)
    group = max(1, budget // (READ_BATCHES * per_test))
    task_run = _task_run(run, pool)
    checked: dict[int, _Checked] = dict(pool.map(
        _check_part, range(-(-C // group)),
        pool.share(_Check(model, task_run, source, group), model=model),
        describe=lambda g: f"tests {g * group} to {min(C, (g + 1) * group) - 1}"))
    parts = [checked[g] for g in sorted(checked)]
    for part in parts:
        _reissue(part.warned)
    view = max(p.view_length for p in parts) or None
    first = source.batch(np.arange(min(C, MIN_ROWS)), length=T, warn=False)
    probe = problem_of(model, first, run, devices=None, view_length=view, checked=True)
    resident = RUNTIME_BYTES + results_bytes(probe.model.n_params, run, C)
    plan = _plan(probe, run, n_dev, pool, n_conditions=C, resident=resident,
                 extra_per_condition=READ_BATCHES * per_test)
    k = run.swarm.n_restarts if run.swarm is not None else 1
    keys = row_keys(key, k * C).reshape(k, C, 2)
    labels = tuple(lab for p in parts for lab in p.labels)
    digests = np.concatenate([p.digests for p in parts])
    return probe, Chunked(probe.model, task_run, plan, keys, view, source, T, labels, digests)


def _map_chunks(pool: Pool, fn: Callable, chunked: Chunked, *args: Any) -> list:
    """`fn(j, *args)` of every chunk on the pool, in chunk order."""
    out = dict(pool.map(fn, range(chunked.plan.n_chunks), *args, describe=chunked.describe))
    return [out[j] for j in range(chunked.plan.n_chunks)]


def _retry_part(j: int, chunked: Chunked, starts: tuple[np.ndarray, ...], uncertainty: bool
                ) -> dict[str, Any]:
    """The retry of chunk `j` (a task) from its neighbours' optima (`starts`: the donors, the
    optima and the RMS of the whole batch's first fit): its polished parameters, RMS, NRMSE,
    steps and status; with `uncertainty`, the std-errors, intervals and identifiability at the
    better of the two fits of each test (`retry_wins`, as `merge` keeps it); the seconds of
    each stage."""
    donors, theta, rms = starts
    t0 = time.perf_counter()
    problem, padded, n = chunked.problem(j)
    rows = padded[:n]
    z0, _ = retry_starts(problem, donors, theta, rows)
    out = solve(problem, swarm=None, polish=chunked.run.polish, uncertainty=False, start=z0)
    part: dict[str, Any] = {
        "theta": out.z[:n], "rms": out.rms[:n],
        "nrmse": np.asarray(nrmse(out.rms, problem.batch.force, problem.placed_mask))[:n],
        "polish_steps": np.asarray(out.steps, int)[:n], "polish_status": tuple(out.status[:n])}
    t1 = time.perf_counter()
    if uncertainty:
        best = np.where(retry_wins(rms[rows], part["rms"])[:, None], part["theta"], theta[rows])
        # padding (of the chunk and of the devices) repeats the last test
        z = best[np.minimum(np.arange(problem.n_units), n - 1)]
        part["uncertainty"] = uncertainty_fields(problem, z, n)
    part["seconds"] = {"retry": t1 - t0, "uncertainty": time.perf_counter() - t1}
    return part


def _retry(result: FitResult, chunked: Chunked, work: Any, pool: Pool, uncertainty: bool
           ) -> tuple[FitResult, dict[str, float]]:
    """Every test polished again from the best of its neighbours' optima (`retry_starts`),
    chunk by chunk (the chunks' shapes: the first pass's compiled polish serves), per test the
    better of the two kept (`merge`) and, with `uncertainty`, its std-errors (in the same
    task: each chunk read once); the seconds of each stage, summed over the chunks."""
    donors = neighbours(result.current, result.frequency, result.amplitude)
    starts = pool.share((donors, np.asarray(result.theta, float),
                         np.asarray(result.rms, float)))
    parts = _map_chunks(pool, _retry_part, chunked, work, starts, uncertainty)
    status: tuple[Status, ...] = sum((p["polish_status"] for p in parts), ())
    again = dataclasses.replace(result, polish_status=status, **{
        k: np.concatenate([p[k] for p in parts]) for k in ("theta", "rms", "nrmse",
                                                            "polish_steps")})
    merged = merge(result, again)
    if uncertainty:
        merged = dataclasses.replace(merged, **{
            k: np.concatenate([p["uncertainty"][k] for p in parts])
            for k in parts[0]["uncertainty"]})
    stages = ("retry", "uncertainty") if uncertainty else ("retry",)
    return merged, {k: sum(p["seconds"][k] for p in parts) for k in stages}
