"""Planning a chunked fit: the memory budget, the working set of a condition, the chunks of
the condition axis and every condition's random stream (see `mrjax.fitting._chunks`)."""

from __future__ import annotations

import dataclasses
import math
import os
import re
from pathlib import Path

import jax
import numpy as np

from .._errors import InputError
from ._problem import TestsProblem
from ._run import Run

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


def default_budget() -> int:
    """The memory budget of a fit given none [bytes]: what the process holds now plus
    `DEFAULT_MEMORY_FRACTION` of the memory available (see :func:`available_memory`)."""
    return current_rss() + int(DEFAULT_MEMORY_FRACTION * available_memory())


def condition_bytes(p: TestsProblem, run: Run) -> int:
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
    if run.swarm is None:
        swarm = 0
    else:
        t_swarm = p.view.batch.length if p.view is not None else T
        dtype = run.swarm.dtype
        itemsize = np.dtype(dtype).itemsize if dtype is not None else 8
        swarm = (run.swarm.n_restarts * run.swarm.n_particles * t_swarm * SWARM_WORDS
                 * itemsize)
    return int(swarm + 8 * T * (RECORD_WORDS + JACOBIAN_WORDS * P))


def resident_bytes(p: TestsProblem, run: Run) -> int:
    """Memory a chunked fit holds besides its chunks' working sets [bytes]: `RUNTIME_BYTES`,
    the whole batch (and the swarm's view of it) and the results of every condition."""
    arrays = jax.tree.leaves(p.source) + ([] if p.view is None else jax.tree.leaves(p.view.batch))
    data = sum(int(np.asarray(a).nbytes) for a in arrays if hasattr(a, "shape"))
    return int(RUNTIME_BYTES + data + results_bytes(p.model.n_params, run, p.n_real))


def results_bytes(n_params: int, run: Run, n_conditions: int) -> int:
    """Memory of the results of `n_conditions` conditions [bytes]: parameters, errors,
    intervals, correlations and the swarm's history of each."""
    P = n_params
    G = run.swarm.generation_cap + 1 if run.swarm is not None else 0
    return int(n_conditions * 8 * (G + 4 * P + 2 * P * P + 16))


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


