"""The settings of an identification, as objects (the optimistix way): :class:`Swarm`,
:class:`Polish` and :class:`Chunks`. `mrjax.fit`, `mrjax.generalize.generalize`,
`mrjax.generalize.identify`, `mrjax.compare` and the command line all pass these objects; the
posterior's settings are `mrjax.Sampler`."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import equinox as eqx

from .._errors import InputError
from ..pso import PSOParams
from ..refine import DEFAULT_TOL

SwarmMode = Literal["separable", "full"]
#: The swarm's modes (see :class:`Swarm`).
MODES: tuple[str, ...] = ("separable", "full")


class Swarm(eqx.Module):
    """The batched particle swarm's settings (`mrjax.pso`).

    **Fields:**

    - `n_particles`: particles per swarm (default 50, the paper's).
    - `max_generations`: the cap on generations with the statistical stop (default 200).
    - `generations`: run exactly this many generations, no statistical stop (benchmarks), or
        None.
    - `restarts`: independent swarms per unit (condition, or the whole data of a joint fit),
        one compiled program; the best is polished. None (default): the problem's choice
        (per test: `mrjax.fitting.default_restarts`, one swarm per test on a batch of tests
        whose optima seed each other's retry, two for a dynamic model on one test; 1 for joint
        laws).
    - `mode`: `"separable"` (variable projection over the parameters the force is linear in;
        default) or `"full"` (the paper's swarm over every parameter). Joint laws always
        solve their linear laws by least squares.
    - `params`: :class:`mrjax.pso.PSOParams` hyperparameters, or None for the problem's
        default (`mrjax.pso.default_params(mode)` per test; window 25 and, for a dynamic
        model's command laws, at least 100 generations).
    - `view`: score the swarm (and a first polish) on each record's view
        (`mrjax.data.swarm_view`), then polish on the full records; None: for the ODE models.
    - `dtype`: float dtype of the search (e.g. `"float32"`: about twice as fast on a CPU; the
        best positions are re-scored, polished and reported in float64), or None for the
        default float.
    - `callback`: a host function `callback(generation (R,), done (R,), best (R,) [N])` called
        after every generation with the swarm rows' state (see `mrjax.pso.swarm`), or None.

    ```python
    mrjax.fit("modified_bouc_wen", data, swarm=mrjax.Swarm(restarts=2))
    ```
    """

    n_particles: int = eqx.field(static=True, default=50)
    max_generations: int = eqx.field(static=True, default=200)
    generations: int | None = eqx.field(static=True, default=None)
    restarts: int | None = eqx.field(static=True, default=None)
    mode: str = eqx.field(static=True, default="separable")
    params: PSOParams | None = None
    view: bool | None = eqx.field(static=True, default=None)
    dtype: Any = eqx.field(static=True, default=None)
    callback: Callable | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if self.callback is not None and not callable(self.callback):
            raise InputError(f"swarm callback must be callable, got {self.callback!r}")
        for name in ("n_particles", "max_generations", "restarts"):
            v = getattr(self, name)
            if v is None and name == "restarts":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or int(v) != v or v < 1:
                raise InputError(f"{name} must be an integer >= 1, got {v!r}")
        g = self.generations
        if g is not None and (isinstance(g, bool) or int(g) != g or g < 1):
            raise InputError(f"generations must be at least 1, got {g!r}")
        if self.mode not in MODES:
            raise InputError(f"swarm mode must be 'separable' or 'full', got {self.mode!r}")
        if self.params is not None and not isinstance(self.params, PSOParams):
            raise InputError(f"params must be a mrjax.pso.PSOParams, got "
                             f"{type(self.params).__name__}")

    @property
    def n_restarts(self) -> int:
        """`restarts`, 1 where it is None (the problem kinds resolve None before a swarm)."""
        return 1 if self.restarts is None else int(self.restarts)

    @property
    def generation_cap(self) -> int:
        """The generations the history holds: `generations` if set, else `max_generations`."""
        return int(self.generations if self.generations is not None else self.max_generations)


class Polish(eqx.Module):
    """The Levenberg-Marquardt polish's settings (`mrjax.refine`).

    **Fields:**

    - `max_steps`: steps per polish stage (default 200).
    - `tol`: the stop: 8 steps lowering the RMS by less than this fraction (see
        `mrjax.refine.lm_solve`; default 1e-6). A first polish on the swarm's views stops at a
        multiple of it and the full records are refined (see `mrjax.engine.solve`).
    - `uncertainty`: std-errors, intervals and identifiability at the result (default True).
        Without a polish (`polish=None`) the std-errors are computed at the swarm's best.
    - `retry`: per-test fits only: after the polish, polish every test once more from the best
        of its neighbours' optima (`mrjax.fitting.retry_starts`: the optima of the tests
        nearest in current, frequency and amplitude, their linear parameters solved on the
        test, ranked on its view) and keep the better; the two results are the evidence of a
        possible local optimum (`FitResult.starts_rms`, a warning where they disagree by more
        than `mrjax.fitting.SPREAD_MARGIN`). Default True; needs at least two tests.
    """

    max_steps: int = eqx.field(static=True, default=200)
    tol: float = eqx.field(static=True, default=DEFAULT_TOL)
    uncertainty: bool = eqx.field(static=True, default=True)
    retry: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        if not isinstance(self.retry, bool):
            raise InputError(f"polish retry must be True or False, got {self.retry!r}")
        v = self.max_steps
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise InputError(f"polish max_steps must be an integer >= 1, got {v!r}")
        if not (isinstance(self.tol, (int, float)) and math.isfinite(self.tol) and self.tol > 0):
            raise InputError(f"polish tol must be a positive number, got {self.tol!r}")


class Chunks(eqx.Module):
    """How a per-test fit is split and placed (`mrjax.fit`): the condition axis in chunks of
    bounded memory, a journal to resume from, the devices, a Dask cluster. None of these
    changes a result.

    **Fields:**

    - `max_memory`: memory budget of the fit [bytes], or text such as `"8GB"`, `"512MB"`. The
        conditions are fitted in chunks whose estimated working set fits it, every chunk with
        the same shape (one compiled program) and each condition with its own random stream,
        so the result does not depend on the chunking (see `mrjax.fitting.ChunkPlan`). None
        (default): the memory the process holds plus half of what is available.
    - `size`: conditions per chunk instead of a budget (raised to the smallest chunk that keeps
        the result independent of the chunking, a multiple of the device count; see
        `mrjax.fitting.plan_chunks`).
    - `journal`: a directory where each finished chunk is written (atomically) when the fit has
        more than one chunk; with `resume` the chunks it holds are reused after checking that
        they were written for the same data and settings (`mrjax.fitting.Journal`).
    - `resume`: see `journal`.
    - `devices`: shard the condition axis over these devices: `"all"`, a count, or a list of
        `jax.Device` (None: one device); see `mrjax.parallel`. Same key, same result. With a
        `cluster`, each worker shards its chunks over its own devices (`"all"` or a count).
    - `cluster`: fit the chunks on a Dask cluster, each chunk one task (`pip install
        'mrjax[cluster]'`): a `distributed.Client`, a Dask cluster object (e.g.
        `distributed.LocalCluster`) or a scheduler address such as `"tcp://host:8786"`. The
        workers read their chunks of a `mrjax.data.Source` from its files; `max_memory` is then
        the budget of one worker thread (default: half of the workers' memory limit per
        thread). Same chunks, same result as in one process (see `mrjax.fitting.Journal` for
        resuming, and the how-to "From one machine to a cluster").

    ```python
    mrjax.fit("kwok", "tests/", chunks=mrjax.Chunks(max_memory="4GB", journal="journal/"))
    ```
    """

    max_memory: int | float | str | None = eqx.field(static=True, default=None)
    size: int | None = eqx.field(static=True, default=None)
    journal: str | Path | None = eqx.field(static=True, default=None)
    resume: bool = eqx.field(static=True, default=False)
    devices: Any = eqx.field(static=True, default=None)
    cluster: Any = eqx.field(static=True, default=None)

    def __check_init__(self):
        c = self.cluster
        if c is not None and not (isinstance(c, str) and c.strip() or hasattr(c, "submit")
                                  or hasattr(c, "scheduler_address")):
            raise InputError(f"cluster must be a distributed.Client, a Dask cluster or a "
                             f"scheduler address like 'tcp://host:8786', got {c!r}")
        if c is not None and self.devices is not None and not isinstance(self.devices,
                                                                         (str, int)):
            raise InputError("with a cluster, devices is 'all' or a count: each worker uses "
                             "its own devices")
        if not isinstance(self.resume, bool):
            raise InputError(f"chunks resume must be True or False, got {self.resume!r}")
        if self.resume and self.journal is None:
            raise InputError("resume needs a journal directory (Chunks(journal=..., resume=True))")
        v = self.size
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or int(v) != v
                              or v < 1):
            raise InputError(f"chunk size must be an integer >= 1, got {v!r}")


def check_settings(swarm: Any, polish: Any, chunks: Any = None
                   ) -> tuple[Swarm | None, Polish | None]:
    """`(swarm, polish)` checked: each a settings object of its kind or None (the stage does
    not run), and at least one of them. Raises :class:`mrjax.InputError` otherwise."""
    for name, v, kind in (("swarm", swarm, Swarm), ("polish", polish, Polish),
                          ("chunks", chunks, Chunks)):
        if v is not None and not isinstance(v, kind):
            raise InputError(f"{name} must be a mrjax.{kind.__name__} or None, got "
                             f"{type(v).__name__}")
    if swarm is None and polish is None:
        raise InputError("nothing to run: give a swarm, a polish or both")
    return swarm, polish
