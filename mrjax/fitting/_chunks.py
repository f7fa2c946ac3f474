"""Thousands of tests: `mrjax.fit` over the condition axis in chunks of bounded memory.

A layer above the four stages (`prepare` -> `run_swarm` -> `run_polish` -> `evaluate`): it
checks the whole batch once, plans chunks whose working set fits a memory budget, runs the
stages on each chunk and concatenates the results; optionally it writes each finished chunk to
a journal from which an interrupted fit resumes.

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
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
import math
import os
import re
import shutil
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import numpy as np

from .. import __version__
from .._errors import InputError
from .._io import atomic_output, json_bytes
from ..models import AbstractModel
from ..parallel import pad_conditions, resolve_devices, take_conditions
from ._result import FitResult
from ._stages import Problem, evaluate, prepare, run_polish, run_swarm

#: Default budget: this fraction of the memory available (`MemAvailable` of /proc/meminfo, or
#: a cgroup's remaining limit, whichever is smaller) when the fit starts, on top of what the
#: process already holds. Half leaves room for the rest of the machine.
DEFAULT_MEMORY_FRACTION = 0.5
#: Swarm working set per particle and scored sample, in words of the swarm's float (measured:
#: 2.3-2.5 MB per condition for the tanh model's separable swarm, 50 particles x 2,000
#: samples, float64, i.e. 2.9-3.1 words; 1.3 MB (Bouc-Wen) and 0.6 MB (Dahl, swarm + polish)
#: on their 667-sample views; rounded up).
SWARM_WORDS = 4
#: float64 words per sample of a record held per condition besides the swarm: the chunk's
#: copies of the (C, T) arrays, their placement and the scored force.
RECORD_WORDS = 16
#: float64 words per sample and parameter: the Jacobian of the polish and of the uncertainty
#: and the forward-mode tangents of an ODE model.
JACOBIAN_WORDS = 4
#: Width of XLA:CPU's vectors [bytes] (its preferred width, `xla_cpu_prefer_vector_width`, 256
#: bits by default). An element-wise operation over the rows of a batch runs the last
#: `rows % lanes` rows through scalar code, whose last bits differ from the vector code's
#: (measured, jax 0.10.2: a Dahl swarm's parameters agree across batches of 8, 12, 16, 24, 32
#: and 64 rows, but not of 9 or 18, where the rows past the last multiple of 4 differ). A
#: chunked fit therefore gives every batch a multiple of `VECTOR_BYTES / itemsize` rows.
VECTOR_BYTES = 32
#: The fewest rows per device of a chunk (a batch of fewer, e.g. one vector, is compiled
#: differently: measured at 1 and 4 rows).
MIN_ROWS = 8
#: XLA:CPU computes a batched reduction over at most about 4,096 elements in all with another
#: kernel than a larger one, whose sums differ in the last bits (measured, jax 0.10.2:
#: `jax.vmap(lambda b: b @ b)` over (C, T) differs for C * T <= 4,000). A chunk holds at least
#: `MIN_CHUNK_ELEMENTS` swarm rows x samples and swarm rows x particles, so that the swarm's
#: sums over samples and its per-particle sums over the linear parameters run on the large
#: kernels in every chunk, as in the whole batch.
MIN_CHUNK_ELEMENTS = 4097
#: JAX, XLA and the compiled programs of a fit (measured: 0.2-0.5 GB above the import
#: baseline of about 0.3 GB for the models' swarm + polish; rounded up).
RUNTIME_BYTES = 1_000_000_000

_UNITS = {"": 1, "b": 1, "k": 1e3, "kb": 1e3, "m": 1e6, "mb": 1e6, "g": 1e9, "gb": 1e9,
          "t": 1e12, "tb": 1e12, "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}


def parse_memory(value: int | float | str) -> int:
    """A memory size in bytes: a number of bytes, or text such as `"8GB"`, `"8 GB"`,
    `"512MB"`, `"1.5GiB"` (k, M, G, T: powers of 1000; KiB, MiB, GiB, TiB: of 1024).

    Raises :class:`mrjax.InputError` for anything else or a size that is not positive.
    """
    if isinstance(value, bool):
        raise InputError(f"memory size must be bytes or text like '8GB', got {value!r}")
    if isinstance(value, (int, float, np.integer, np.floating)):
        n = float(value)
    elif isinstance(value, str):
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*", value)
        unit = m.group(2).lower() if m else None
        if m is None or unit not in _UNITS:
            raise InputError(f"memory size {value!r}: expected bytes or a size like '8GB', "
                             f"'512MB', '1.5GiB'")
        n = float(m.group(1)) * _UNITS[unit]
    else:
        raise InputError(f"memory size must be bytes or text like '8GB', got "
                         f"{type(value).__name__}")
    if not (math.isfinite(n) and n >= 1):
        raise InputError(f"memory size must be positive, got {value!r}")
    return int(n)


def _read_int(path: str) -> int | None:
    try:
        text = Path(path).read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def available_memory() -> int:
    """Bytes the process can still allocate: `MemAvailable` of /proc/meminfo (else the
    available physical pages of `os.sysconf`), and at most what a cgroup v2 memory limit
    leaves (`memory.max - memory.current`). 4 GB where nothing can be read."""
    avail = None
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            avail = 4 * 10**9
    limit = _read_int("/sys/fs/cgroup/memory.max")
    used = _read_int("/sys/fs/cgroup/memory.current")
    if limit is not None and used is not None:
        avail = min(avail, max(limit - used, 0))
    return int(avail)


def current_rss() -> int:
    """Resident memory of this process now [bytes] (0 where /proc is not readable)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def condition_bytes(p: Problem) -> int:
    """Estimated working set of one condition of a chunk [bytes]:

    `restarts * n_particles * T_swarm * SWARM_WORDS * itemsize` (the swarm: every particle
    scored on every sample of its view, in the swarm's float) `+ 8 * T * (RECORD_WORDS +
    JACOBIAN_WORDS * P)` (the records, the polish's and the uncertainty's Jacobians).

    The constants come from the peak RSS of fits in fresh processes at 36 and 144 (288)
    conditions of 2,000 samples on the 2-core CPU, jax 0.10.2 (the slope per condition): the
    tanh model's separable swarm 2.3-2.5 MB (estimate 3.4 MB), the Bouc-Wen swarm on its view
    1.3 MB (estimate 1.8 MB), Dahl swarm + polish 0.6 MB (estimate 1.7 MB).
    `benchmarks/scale_conditions.py` checks the estimate at 10,000 conditions.
    """
    T, P = p.source.length, p.model.n_params
    if p.method == "lm":
        swarm = 0
    else:
        t_swarm = p.view.batch.length if p.view is not None else T
        dtype = p.swarm_options.get("dtype")
        itemsize = np.dtype(dtype).itemsize if dtype is not None else 8
        swarm = (p.restarts * int(p.swarm_options["n_particles"]) * t_swarm * SWARM_WORDS
                 * itemsize)
    return int(swarm + 8 * T * (RECORD_WORDS + JACOBIAN_WORDS * P))


def resident_bytes(p: Problem) -> int:
    """Memory a chunked fit holds besides its chunks' working sets [bytes]: `RUNTIME_BYTES`,
    the whole batch (and the swarm's view of it) and the results of every condition."""
    arrays = jax.tree.leaves(p.source) + ([] if p.view is None else jax.tree.leaves(p.view.batch))
    data = sum(int(np.asarray(a).nbytes) for a in arrays if hasattr(a, "shape"))
    P, G = p.model.n_params, int(p.swarm_options["max_generations"]) + 1
    results = p.n_real * 8 * (G + 4 * P + 2 * P * P + 16)
    return int(RUNTIME_BYTES + data + results)


@dataclasses.dataclass(frozen=True)
class ChunkPlan:
    """How a fit walks the condition axis.

    **Fields:** `n_conditions` C; `size` conditions per chunk (every chunk is padded to it, a
    multiple of the device count); `budget` [bytes] the memory budget it was planned for (None
    for a given `size`); `per_condition`, `resident` [bytes] the estimates it used.
    """

    n_conditions: int
    size: int
    budget: int | None = None
    per_condition: int = 0
    resident: int = 0

    @property
    def n_chunks(self) -> int:
        """Number of chunks."""
        return -(-self.n_conditions // self.size)

    def bounds(self, j: int) -> tuple[int, int]:
        """`(start, stop)`: the conditions of chunk `j` (0-based)."""
        return j * self.size, min((j + 1) * self.size, self.n_conditions)


def plan_chunks(
    n_conditions: int,
    *,
    per_condition: int,
    resident: int = 0,
    budget: int | None = None,
    devices: int = 1,
    lanes: int = 1,
    minimum: int = 1,
    size: int | None = None,
    strict: bool = True,
) -> ChunkPlan:
    """Plan the chunks of a fit of `n_conditions`.

    **Arguments:**

    - `per_condition`, `resident`: estimated bytes of one condition's working set and of what
        the fit holds besides (see :func:`condition_bytes`, :func:`resident_bytes`).
    - `budget`: the memory the fit may use [bytes]; a chunk holds as many conditions as
        `budget - resident` leaves room for.
    - `devices`: the device count; `lanes`: a chunk holds a multiple of `lanes` conditions per
        device (see `VECTOR_BYTES`).
    - `minimum`: the fewest conditions of a chunk (see `MIN_ROWS`, `MIN_CHUNK_ELEMENTS`).
    - `size`: conditions per chunk instead of a budget (raised to `minimum`).
    - `strict`: a budget too small for a chunk of `minimum` conditions raises; otherwise the
        chunk holds `minimum`.

    A batch of at most `minimum` conditions is one chunk of exactly its conditions (padded to
    a multiple of `devices` only): no other chunking of it is possible. A larger batch, also
    in one chunk, is padded to a multiple of `devices * lanes`, as every chunk is, so that the
    result does not depend on the chunking. C conditions in n chunks hold `ceil(C / n)` each
    (rounded up), so the last chunk needs little padding.

    **Returns:** a :class:`ChunkPlan`. Raises :class:`mrjax.InputError` for a `size` below 1
    and, with `strict`, a budget below `resident + minimum * per_condition`.
    """
    C, d = int(n_conditions), max(1, int(devices))
    q = d * max(1, int(lanes))  # the row quantum of a chunk
    low = -(-max(1, int(minimum)) // q) * q  # the smallest chunk
    if size is not None and (isinstance(size, bool) or int(size) != size or size < 1):
        raise InputError(f"chunk_size must be an integer >= 1, got {size!r}")
    if size is None and budget is None:
        raise InputError("plan_chunks needs a budget or a size")
    if size is not None:
        most = -(-int(size) // q) * q
    else:
        most = (int(budget) - int(resident)) // max(1, int(per_condition)) // q * q
        if most < low:
            if strict:
                need = resident + low * per_condition
                raise InputError(
                    f"memory budget {budget / 1e9:.3g} GB is too small: the data, results and "
                    f"runtime take about {resident / 1e9:.3g} GB and each condition "
                    f"{per_condition / 1e6:.3g} MB; give at least {need / 1e9:.3g} GB")
    most = max(low, most)
    if C <= low:  # one chunk whatever the budget
        chunk = -(-C // d) * d
    else:
        n_chunks = -(-C // most)
        chunk = max(low, -(-(-(-C // n_chunks)) // q) * q)
    return ChunkPlan(C, chunk, None if size is not None else int(budget), int(per_condition),
                     int(resident))


def condition_keys(key: Any, n: int) -> jax.Array:
    """`n` per-row keys: `jax.random.split(key, n)` of one key (a typed key or a raw (2,)
    uint32 key), or `key` itself when it already holds `n` keys. Row i's key does not depend
    on `n` (JAX's partitionable threefry, the default), so a fit's streams are those the whole
    batch gives its rows, whatever the chunking."""
    key = key if isinstance(key, jax.Array) else jax.numpy.asarray(key)
    single = key.ndim == (0 if jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key) else 1)
    if single:
        return jax.random.split(key, n)
    if key.shape[0] != n:
        raise InputError(f"key: got {key.shape[0]} keys for {n} swarm rows (conditions x "
                         f"restarts); pass one key or one per row")
    return key


# ---------------------------------------------------------------------------------- journal

#: Name of the journal format, in its manifest.
JOURNAL_FORMAT = "mrjax-journal/1"
#: The options of `mrjax.fit` that do not change its result (left out of the fingerprint).
_NEUTRAL = frozenset({"progress", "devices", "callback", "max_memory", "chunk_size", "journal",
                      "resume", "view_length", "checked"})


def _canonical(v: Any) -> Any:
    """A JSON-able, exact description of an option value (arrays by their bytes' hash)."""
    if v is None or isinstance(v, (bool, int, float, str)):
        return repr(v)
    if isinstance(v, Mapping):
        return {str(k): _canonical(x) for k, x in sorted(v.items(), key=lambda kv: str(kv[0]))}
    if isinstance(v, (list, tuple)):
        return [_canonical(x) for x in v]
    if isinstance(v, jax.Array) and jax.dtypes.issubdtype(v.dtype, jax.dtypes.prng_key):
        v = jax.random.key_data(v)
    if isinstance(v, (np.ndarray, np.generic, jax.Array)):
        a = np.ascontiguousarray(np.asarray(v))
        return [a.dtype.str, list(a.shape), hashlib.sha256(a.tobytes()).hexdigest()]
    if isinstance(v, eqx.Module):
        leaves, treedef = jax.tree.flatten(v)
        return [str(treedef), [_canonical(x) for x in leaves]]
    return repr(v)


def fingerprint(p: Problem, options: Mapping[str, Any], keys: jax.Array) -> str:
    """SHA-256 of everything a fit's result depends on: the data (every array of the batch and
    the fit mask, the labels), the model, the random streams (`keys`), every option but those
    that leave the result unchanged (`progress`, `devices`, `callback`, the memory and journal
    options) and the mrjax version."""
    h = hashlib.sha256()
    for f in dataclasses.fields(p.source):
        v = getattr(p.source, f.name)
        h.update(f.name.encode())
        h.update(json.dumps(_canonical(list(v) if f.name == "labels" else v)).encode())
    h.update(json.dumps(_canonical(p.mask)).encode())
    doc = {"mrjax_version": __version__, "model": p.model.name, "model_tree": _canonical(p.model),
           "keys": _canonical(keys), "lower": _canonical(p.lower), "upper": _canonical(p.upper),
           "options": {k: _canonical(v) for k, v in sorted(options.items())
                       if k not in _NEUTRAL and k != "key"}}
    h.update(json.dumps(doc, sort_keys=True).encode())
    return h.hexdigest()


class Journal:
    """Finished chunks of a fit on disk, from which an interrupted fit resumes.

    A directory holding `manifest.json` (`{"format": "mrjax-journal/1", "fingerprint": sha256
    of the data and options, "n_conditions": C, "chunk_size": B, "n_chunks": n,
    "mrjax_version": str}`) and one `chunk-NNNNN.json` per finished chunk (`{"chunk": j,
    "start": first condition, "stop": one past the last, "fingerprint": ..., "result":
    FitResult.to_state() of its conditions}`: floats by `repr`, exact), each written
    atomically (`mrjax._io.atomic_output`).
    """

    def __init__(self, path: str | os.PathLike, fp: str, plan: ChunkPlan):
        self.path, self.fingerprint, self.plan = Path(path), fp, plan

    @classmethod
    def open(cls, path: str | os.PathLike, fp: str, plan: ChunkPlan, *,
             resume: bool) -> Journal:
        """The journal at `path` for a fit with fingerprint `fp` planned as `plan`.

        With `resume`, an existing journal is reused (its chunk size replaces the plan's, so
        that its chunks line up) and must have been written for the same fingerprint;
        otherwise an existing journal is discarded. Raises :class:`mrjax.InputError` for a
        journal of other data or options, or a path that is no journal.
        """
        path = Path(path)
        manifest = path / "manifest.json"
        if path.exists():
            if not path.is_dir():
                raise InputError(f"journal {str(path)!r} exists and is not a directory")
            old = cls._read(manifest)
            if old is not None and old.get("format") != JOURNAL_FORMAT:
                old = None
            if old is None and any(path.iterdir()):
                raise InputError(f"journal {str(path)!r} exists and is not an mrjax journal "
                                 f"(no {JOURNAL_FORMAT} manifest.json); remove it or choose "
                                 f"another directory")
            if resume and old is not None:
                if old.get("fingerprint") != fp or old.get("n_conditions") != plan.n_conditions:
                    raise InputError(
                        f"cannot resume: the journal {str(path)!r} was written for other data "
                        f"or options (or another mrjax version); run without resume to start "
                        f"over")
                size = int(old["chunk_size"])
                return cls(path, fp, dataclasses.replace(plan, size=size))
            shutil.rmtree(path)
        doc = {"format": JOURNAL_FORMAT, "fingerprint": fp, "n_conditions": plan.n_conditions,
               "chunk_size": plan.size, "n_chunks": plan.n_chunks, "mrjax_version": __version__}
        atomic_output(path, {"manifest.json": json_bytes(doc)})
        return cls(path, fp, plan)

    @staticmethod
    def _read(path: Path) -> dict | None:
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        return doc if isinstance(doc, dict) else None

    def _name(self, j: int) -> str:
        return f"chunk-{j + 1:05d}.json"

    def finished(self, model: AbstractModel) -> dict[int, FitResult]:
        """The chunks already written, by index; a file that does not match the plan (or is
        unreadable) counts as not written."""
        out: dict[int, FitResult] = {}
        for j in range(self.plan.n_chunks):
            doc = self._read(self.path / self._name(j))
            start, stop = self.plan.bounds(j)
            if (doc is None or doc.get("fingerprint") != self.fingerprint
                    or doc.get("chunk") != j or doc.get("start") != start
                    or doc.get("stop") != stop):
                continue
            try:
                res = FitResult.from_state(doc["result"], model)
            except (InputError, KeyError, TypeError, ValueError):
                continue
            if res.n_conditions == stop - start:
                out[j] = res
        return out

    def record(self, j: int, result: FitResult) -> None:
        """Write chunk `j`'s results atomically."""
        start, stop = self.plan.bounds(j)
        doc = {"chunk": j, "start": start, "stop": stop, "fingerprint": self.fingerprint,
               "result": result.to_state()}
        atomic_output(self.path, {self._name(j): json_bytes(doc)})

    def remove(self) -> None:
        """Delete the journal (after the final outputs are written)."""
        shutil.rmtree(self.path, ignore_errors=True)


# ------------------------------------------------------------------------------- the layer


def run_stages(model: str | AbstractModel, data: Any, options: Mapping[str, Any]) -> FitResult:
    """The four stages on one batch (one chunk), each timed in `FitResult.timings` [s]."""
    timings: dict[str, float] = {}
    method, uncertainty = options["method"], options["uncertainty"]
    t0 = time.perf_counter()
    p = prepare(model, data, options)
    timings["prepare"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    sw = run_swarm(p)
    if method != "lm":
        timings["swarm"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    pol = run_polish(p, sw)
    timings.update(pol.timings)
    if method != "pso":
        timings["polish"] = time.perf_counter() - t1
    elif uncertainty:
        timings["uncertainty"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    result = evaluate(p, sw, pol, timings)
    timings["evaluate"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t0
    return result


def _bar(enabled: bool | None, plan: ChunkPlan):
    """The chunks' progress bar (conditions done, chunk j/n), or None."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled or plan.n_chunks < 2:
        return None
    from tqdm.auto import tqdm  # imported here: only a terminal run draws a bar

    return tqdm(total=plan.n_conditions, desc=f"chunk 0/{plan.n_chunks}", unit="cond",
                file=sys.stderr, position=0)


def _plan(whole: Problem, n_dev: int, max_memory: Any, chunk_size: int | None) -> ChunkPlan:
    """The chunks of a fit whose whole batch `prepare` built as `whole`."""
    budget = None if max_memory is None else parse_memory(max_memory)
    k = whole.restarts
    t_swarm = whole.view.batch.length if whole.view is not None else whole.source.length
    dtype = whole.swarm_options.get("dtype")
    lanes = max(1, VECTOR_BYTES // (np.dtype(dtype).itemsize if dtype is not None else 8))
    minimum = max(MIN_ROWS * n_dev, -(-MIN_CHUNK_ELEMENTS // (k * t_swarm)))
    if whole.method != "lm":
        minimum = max(minimum, -(-MIN_CHUNK_ELEMENTS // (k * int(whole.swarm_options["n_particles"]))))
    shape = dict(per_condition=condition_bytes(whole), resident=resident_bytes(whole),
                 devices=n_dev, lanes=lanes, minimum=minimum)
    if budget is None and chunk_size is None:
        default = current_rss() + int(DEFAULT_MEMORY_FRACTION * available_memory())
        return plan_chunks(whole.n_real, budget=max(default, shape["resident"]), strict=False,
                           **shape)
    return plan_chunks(whole.n_real, budget=budget, size=chunk_size, **shape)


def chunk_plan(model: str | AbstractModel, data: Any, **options: Any) -> ChunkPlan:
    """The chunks `mrjax.fit(model, data, **options)` would run (without fitting): e.g.
    `chunk_plan("kwok", batch, max_memory="8GB").n_chunks`. Raises what `mrjax.fit` raises
    for bad options or data, or a budget too small."""
    from ._stages import fit  # the defaults of every option live in its signature

    sig = inspect.signature(fit)
    unknown = set(options) - set(sig.parameters)
    if unknown:
        raise InputError(f"unknown option(s) of mrjax.fit: {sorted(unknown)}")
    o = {k: v.default for k, v in sig.parameters.items()
         if v.default is not inspect.Parameter.empty}
    o.update(options)
    o.pop("swarm", None)
    whole = prepare(model, data, dict(o, devices=None))
    n_dev = 1 if o["devices"] is None else len(resolve_devices(o["devices"]))
    return _plan(whole, n_dev, o["max_memory"], o["chunk_size"])


def fit_in_chunks(
    model: str | AbstractModel,
    data: Any,
    options: Mapping[str, Any],
    *,
    run: Callable[..., FitResult] | None = None,
) -> FitResult:
    """`mrjax.fit` in chunks (see the module docstring): `options` are all the keyword
    arguments of `mrjax.fit`, including `max_memory`, `chunk_size`, `journal` and `resume`.

    `run(model, batch, options)` fits one chunk (default :func:`run_stages`).
    """
    run = run_stages if run is None else run
    t0 = time.perf_counter()
    o = dict(options)
    max_memory, chunk_size = o.pop("max_memory"), o.pop("chunk_size")
    journal, resume = o.pop("journal"), bool(o.pop("resume"))
    if resume and journal is None:
        raise InputError("resume needs a journal directory (journal=...)")
    # the whole batch checked once, before any work (errors and warnings name its conditions)
    whole = prepare(model, data, dict(o, devices=None))
    C, k = whole.n_real, whole.restarts
    n_dev = 1 if o["devices"] is None else len(resolve_devices(o["devices"]))
    keys = condition_keys(whole.key, k * C)
    plan = _plan(whole, n_dev, max_memory, chunk_size)
    jr = None
    if journal is not None and (resume or plan.n_chunks > 1):  # one chunk: nothing to resume
        jr = Journal.open(journal, fingerprint(whole, o, keys), plan, resume=resume)
        plan = jr.plan
        if plan.size % n_dev:
            raise InputError(f"cannot resume: the journal's chunks of {plan.size} conditions "
                             f"do not divide over {n_dev} devices")
    done = jr.finished(whole.model) if jr is not None else {}
    view_length = whole.view.batch.length if whole.view is not None else None
    rows_keys = keys.reshape(k, C)
    parts: list[FitResult] = []
    bar = _bar(o["progress"], plan)
    try:
        if bar is not None and done:
            bar.update(sum(r.n_conditions for r in done.values()))
        for j in range(plan.n_chunks):
            start, stop = plan.bounds(j)
            if j in done:
                parts.append(done[j])
                continue
            rows = np.arange(start, stop)
            chunk, _ = take_conditions(whole.source, rows)
            chunk, _, n = pad_conditions(chunk, None, plan.size)
            padded = np.concatenate([rows, np.full(plan.size - n, rows[-1])])
            chunk_keys = rows_keys[:, padded].reshape(-1)
            chunk_opts = dict(o, key=chunk_keys, view_length=view_length, checked=True)
            res = run(whole.model, chunk, chunk_opts)
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
    timings = dict(result.timings, total=time.perf_counter() - t0)
    return dataclasses.replace(result, timings=timings)

