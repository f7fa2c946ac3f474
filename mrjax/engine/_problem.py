"""What a problem kind supplies to the engine (:class:`AbstractProblem`), and what the engine
gives back (:class:`Start`, :class:`SwarmOutcome`, :class:`StageOutcome`, :class:`Outcome`)."""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, ClassVar

import equinox as eqx
import numpy as np

from .._errors import InputError
from ..bayes import Likelihood
from ..pso import AbstractObjective, PSOParams
from ..refine import FULL_TOL_FACTOR, Status
from ._settings import Swarm


@dataclasses.dataclass(frozen=True, eq=False)
class SwarmSetup:
    """The swarm of a problem: `objective` the fitness of one swarm position on one row (an
    `mrjax.pso.AbstractObjective`); `lower`, `upper` (D,) the search box; `data` a pytree whose
    leaves have a leading row axis: row `k * n_real + i` is copy k of unit i (`restarts`
    copies), then any padding rows (copies of the last unit); `params` the problem's default
    hyperparameters; `page_size` the swarm's pages (see `mrjax.pso.swarm`); `dtype` the
    swarm's float dtype (None: the default)."""

    objective: AbstractObjective
    lower: np.ndarray
    upper: np.ndarray
    data: Any
    params: PSOParams
    page_size: int | None = None
    dtype: Any = None


@dataclasses.dataclass(frozen=True, eq=False)
class StageSpec:
    """One polish stage of a problem, for `mrjax.refine.solve_box`: `residual` an
    `equinox.Module` `residual(z (K,), unit_args) -> r` [N]; `args` the units' data (leading
    axis U); `n` (U,) scored samples; `lower`, `upper` (K,) the box of the unknowns; `free`
    the unknowns varied (None: all); `jacobian`, `scaled`, `snap`, `page_size` as
    `solve_box`; `integration` a note of the integration used (e.g. `(substeps, scheme)`)."""

    residual: eqx.Module
    args: Any
    n: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    free: tuple[int, ...] | None = None
    jacobian: str = "forward"
    scaled: bool = False
    snap: bool = False
    page_size: int | None = None
    integration: Any = None


@dataclasses.dataclass(frozen=True)
class Start:
    """Where the polish starts, per unit: `z` (U, K) unknowns, `rms` (U,) [N] their RMS on the
    full records (the polish's integration), `source` which candidate it is (`"swarm"`,
    `"start"`, `"default"`, ...), `candidates` the RMS [N] of every candidate the problem
    ranked (by name)."""

    z: np.ndarray
    rms: np.ndarray
    source: str = "swarm"
    candidates: dict[str, float] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class SwarmOutcome:
    """The swarm stage, per unit (the best of its restarts): `z` (U, K) unknowns of the best
    position, `rms` (U,) [N] its fitness on the data the swarm scored (the views, or the full
    records), `generations` (U,), `stopped_by_criterion` (U,), `history` (U, G + 1) [N],
    `restarts`."""

    z: np.ndarray
    rms: np.ndarray
    generations: np.ndarray
    stopped_by_criterion: np.ndarray
    history: np.ndarray
    restarts: int = 1


@dataclasses.dataclass(frozen=True)
class StageOutcome:
    """One polish stage: `name` (`"view"` or `"full"`), `steps` (U,), `status` per unit (a
    name of `mrjax.refine.STATUS_NAMES`, or `"kept_start"`), `tol` the stop it ran to,
    `max_steps`, `integration` (the problem's note of how it integrated)."""

    name: str
    steps: np.ndarray
    status: tuple[Status, ...]
    tol: float
    max_steps: int
    integration: Any = None


@dataclasses.dataclass(frozen=True)
class Outcome:
    """What :func:`mrjax.engine.solve` found, per unit.

    **Fields:** `z` (U, K) the unknowns; `rms` (U,) [N] on the full records (never above the
    start's); `start` the :class:`Start` of the polish; `swarm` the :class:`SwarmOutcome` (None
    without a swarm); `stages` the polish stages run (empty without polish); `kept_start` (U,)
    where the polished result was worse than the start and the start was kept; `uncertainty`
    the problem's uncertainty at `z` (None if not asked); `timings` [s] per stage."""

    z: np.ndarray
    rms: np.ndarray
    start: Start
    swarm: SwarmOutcome | None
    stages: tuple[StageOutcome, ...]
    kept_start: np.ndarray
    uncertainty: Any
    timings: dict[str, float]

    @property
    def steps(self) -> np.ndarray:
        """(U,) steps of the last polish stage (zeros without polish)."""
        return self.stages[-1].steps if self.stages else np.zeros(self.z.shape[0], int)

    @property
    def status(self) -> tuple[Status, ...]:
        """Per unit, the polish's outcome: `"refined"` where a view polish converged and the
        full records' refinement ran its few steps (or converged), else the first failure;
        the last stage's status for a one-stage polish; `"kept_start"` where the start was
        kept; `"none"` without polish."""
        U = self.z.shape[0]
        if not self.stages:
            return (Status.NONE,) * U
        if len(self.stages) == 1:
            out = self.stages[0].status
        else:
            out = tuple(refined(a, b) for a, b in zip(self.stages[0].status,
                                                       self.stages[-1].status))
        return tuple(Status.KEPT_START if k else s for k, s in zip(self.kept_start, out))


def refined(view_status: Status, full_status: Status) -> Status:
    """The status of a two-stage polish: `REFINED` where the view polish converged and the
    full-record refinement ran its steps (or converged), else the first failure."""
    done = (Status.MAX_STEPS_REACHED, Status.SUCCESSFUL)
    if full_status in (*done, Status.KEPT_START) and view_status == Status.SUCCESSFUL:
        return Status.REFINED if full_status != Status.KEPT_START else Status.SUCCESSFUL
    return full_status if full_status not in done else view_status


class AbstractProblem(abc.ABC):
    """A problem kind of the identification engine (:func:`mrjax.engine.solve`).

    A problem has U *units* solved side by side (the conditions of a per-test fit; one unit,
    the whole data, for laws over the current or a command) with K unknowns each in a box. It
    supplies its swarm (objective, box, data: :meth:`swarm_setup`, :meth:`from_swarm`), its
    starts (:meth:`default_start`, :meth:`choose_start`), the residuals of each polish stage on
    the swarm's views or on the full records (:meth:`stage`), its score on the full records
    (:meth:`score`) and its uncertainty (:meth:`uncertainty`); the engine runs
    view -> swarm -> view polish -> full-record polish -> uncertainty once for every kind, and
    the caller assembles its result from the :class:`Outcome`; its posterior samples the
    residuals of :meth:`likelihood` (`mrjax.engine.sample`).

    **Polish plan** (class attributes): with a view, the view stage stops at
    `view_tol_factor` x `Polish.tol` and the full records are refined to `refine_tol_factor`
    x tol in at most `refine_max_steps` steps (None: `Polish.max_steps`); without a view stage
    the full records are polished to `search_tol_factor` x tol.
    """

    view_tol_factor: ClassVar[float] = 10.0
    search_tol_factor: ClassVar[float] = 1.0
    refine_tol_factor: ClassVar[float] = FULL_TOL_FACTOR
    refine_max_steps: ClassVar[int | None] = None

    @property
    @abc.abstractmethod
    def n_units(self) -> int:
        """U, the units as solved (including any device padding)."""

    @property
    def n_real(self) -> int:
        """The real units (the first `n_real` of `n_units`)."""
        return self.n_units

    @property
    @abc.abstractmethod
    def has_view(self) -> bool:
        """Whether the swarm (and a first polish) score the records' views."""

    @abc.abstractmethod
    def swarm_setup(self, swarm: Swarm) -> SwarmSetup:
        """The swarm's objective, box and data (`swarm.restarts` copies of each unit)."""

    @abc.abstractmethod
    def from_swarm(self, setup: SwarmSetup, position: Any, fitness: Any
                   ) -> tuple[np.ndarray, np.ndarray]:
        """`(z (R, K), rms (R,) [N])` of the swarm's best positions (R, D) on every row."""

    @abc.abstractmethod
    def default_start(self) -> np.ndarray:
        """(U, K): the start without a swarm."""

    def choose_start(self, z: np.ndarray, source: str) -> Start:
        """The polish's start from the swarm's (or the default) unknowns `z` (U, K): by default
        `z` itself, scored on the full records."""
        return Start(z=z, rms=self.score(z), source=source)

    def polish_view(self, z: np.ndarray) -> bool:
        """Whether to polish on the views before the full records (default: when there are
        views)."""
        return self.has_view

    @abc.abstractmethod
    def stage(self, z: np.ndarray, on_view: bool) -> StageSpec:
        """The polish stage from `z` (U, K) on the views or on the full records."""

    @abc.abstractmethod
    def score(self, z: np.ndarray) -> np.ndarray:
        """(U,) RMS [N] on the full records, integration resolved at `z`."""

    @abc.abstractmethod
    def uncertainty(self, z: np.ndarray) -> Any:
        """The linearised uncertainty at `z`."""

    def likelihood(self, z: np.ndarray, on_view: bool) -> Likelihood:
        """What the posterior samples (`mrjax.bayes.Likelihood`): the residuals the polish
        minimises, as blocks of records, on the records' views or on the records, from the
        optimum `z` (U, K). A kind without a posterior raises :class:`mrjax.InputError`."""
        raise InputError(f"{type(self).__name__} has no posterior")
