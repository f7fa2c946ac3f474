"""The per-test problem kind of the engine: one parameter vector per condition."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._errors import InputError
from ..bayes import Likelihood
from ..data import Batch, View, check_mask, fit_mask, swarm_view
from ..engine import AbstractProblem, StageSpec, Swarm, SwarmSetup, swarm_result
from ..models import AbstractModel, check_bounds, exact_tangent, get, resolve_model
from ..objective import (
    ConditionResidual,
    FullObjective,
    LinearObjective,
    SeparableObjective,
    condition_data,
    log_search_flags,
    rms_per_condition,
)
from ..parallel import shard_batch
from ..pso import AbstractObjective, SwarmResult, default_params
from ..refine import FULL_MAX_STEPS, VIEW_TOL_FACTOR, uncertainty

#: `page_size="auto"`: a dynamic model's swarms (and view polishes) are run this many
#: conditions at a time. A fixed width, and a multiple of the float64 vector width (4): a
#: condition's result then does not depend on how many others share the batch (the chunks of
#: `mrjax.fitting.chunk_plan` are aligned the same way).
AUTO_PAGE = 8


def scale_gauge(model: AbstractModel) -> tuple[str, ...]:
    """The unknown the posterior holds first where the records leave a direction undetermined:
    a Bouc-Wen-type model's z scale (delta)."""
    sym = model.scale_symmetry
    return () if sym is None else (sym.gauge,)


#: `restarts=None` of a per-test fit: a dynamic model's swarms per test are this many over
#: the whole batch, at least one per test (see :func:`default_restarts`).
AUTO_SWARMS = 2


def default_restarts(model: AbstractModel, n_conditions: int) -> int:
    """Swarms per test when `mrjax.Swarm(restarts=None)` (the default of `mrjax.fit`, the CLI
    and `mrjax.compare`): 1 for a static model; for a dynamic model `ceil(AUTO_SWARMS / C)`
    (2 for one test, 1 from two tests on): on a batch the tests' optima seed each other's
    retry (`mrjax.Polish(retry=True)`, see `mrjax.fitting.retry_starts`), which finds the
    optima that one swarm per test misses, where a second swarm per test still misses some,
    at a fraction of its cost; a lone test has no neighbour and gets two swarms."""
    if not model.dynamic:
        return 1
    return max(1, -(-AUTO_SWARMS // max(int(n_conditions), 1)))


def auto_page_size(model: AbstractModel, n_conditions: int) -> int | None:
    """Conditions per page for the batched swarm and the view polish of `model` on
    `n_conditions` (see `mrjax.pso.swarm`'s `page_size`): `AUTO_PAGE` (8) for a dynamic model
    on at least 16 conditions, else `None` (one batch)."""
    if model.dynamic and n_conditions >= 2 * AUTO_PAGE:
        return AUTO_PAGE
    return None


def check_records(model: AbstractModel, batch: Batch, mask) -> None:
    """Error for fewer scored samples than parameters + 1; warning for a record shorter than
    one excitation period."""
    n = np.asarray(mask).sum(axis=1)
    short = np.flatnonzero(n <= model.n_params)
    if short.size:
        i = int(short[0])
        raise InputError(
            f"condition {batch.labels[i]!r}: {int(n[i])} scored samples are too few for model "
            f"{model.name!r} with {model.n_params} parameters (at least {model.n_params + 1} "
            f"needed)")
    m = np.asarray(mask)
    rows = np.arange(m.shape[0])
    first, last = np.argmax(m, axis=1), m.shape[1] - 1 - np.argmax(m[:, ::-1], axis=1)
    t, dt = np.asarray(batch.t), np.asarray(batch.dt)
    span = t[rows, last] - t[rows, first] + dt[rows, last]  # scored duration, last interval in
    freq = np.asarray(batch.frequency, float)
    with np.errstate(invalid="ignore"):
        partial = np.flatnonzero(np.isfinite(freq) & (freq > 0) & (span * freq < 0.99))
    if partial.size:
        i = int(partial[0])
        warnings.warn(
            f"condition {batch.labels[i]!r}: the scored record spans {span[i]:.3g} s, less than "
            f"one period of its {freq[i]:g} Hz excitation ({partial.size} such condition(s)); "
            f"its parameters are poorly determined", RuntimeWarning, stacklevel=5)


def _place(batch: Batch, mask, devices) -> tuple[Batch, Any]:
    """The batch and mask on the devices (sharded and padded), or as they are."""
    return (batch, mask) if devices is None else shard_batch(batch, mask, devices)


def swarm_objective(model: AbstractModel, mode: str, lo: np.ndarray, hi: np.ndarray
                    ) -> tuple[AbstractObjective, jax.Array, jax.Array]:
    """The swarm's fitness of `model` in `mode` (`"separable"`: variable projection over the
    nonlinear parameters, log-searched where `mrjax.objective.log_search_flags` says; `"full"`:
    the paper's, every parameter) and its search box `(lower, upper)` (D,)."""
    lo_j, hi_j = jax.device_put((np.asarray(lo, float), np.asarray(hi, float)))
    if mode == "full":
        return FullObjective(model), lo_j, hi_j
    if mode != "separable":
        raise InputError(f"swarm mode must be 'separable' or 'full', got {mode!r}")
    nl = model.nonlinear_index
    if nl.size == 0:  # fully linear model: one exact solve, no swarm needed; 1 dummy dimension
        return LinearObjective(model, lo_j, hi_j), np.zeros(1), np.zeros(1)
    logs = log_search_flags(model, lo)[nl]
    obj = SeparableObjective(model, lo_j, hi_j, tuple(bool(v) for v in logs))
    s_lo = np.where(logs, np.log(np.where(logs, lo[nl], 1.0)), lo[nl])
    s_hi = np.where(logs, np.log(np.where(logs, hi[nl], 1.0)), hi[nl])
    return obj, s_lo, s_hi


class TestsProblem(AbstractProblem):
    """Per-test parameters: every condition of a batch is a unit with the model's P
    parameters as unknowns (SI units) in the box `[lower, upper]`.

    Built by :func:`tests_problem`. The swarm scores each record's view (ODE models by
    default, `mrjax.data.swarm_view`) with the model's separable or full objective; the view
    polish integrates as the swarm does, in pages for a dynamic model; the full records are
    then refined in at most `FULL_MAX_STEPS` steps to 100 x tol (without a view: polished to
    tol); every score uses the sub-steps `mrjax.models.resolve_model` chooses at the
    parameters.

    **Fields:** `model`; `source` the unpadded batch and `mask` its fit mask; `batch`,
    `placed_mask` as placed on the devices (padded to a multiple of their count); `view` the
    swarm's :class:`mrjax.data.View` or None; `lower`, `upper` (P,) [SI]; `transient`;
    `devices`; `mode` the swarm mode.
    """

    view_tol_factor = VIEW_TOL_FACTOR
    search_tol_factor = 1.0
    refine_max_steps = FULL_MAX_STEPS

    def __init__(self, model: AbstractModel, source: Batch, mask: Any, lower: np.ndarray,
                 upper: np.ndarray, *, view: View | None, transient: Any, devices: Any,
                 mode: str):
        self.model, self.source, self.mask = model, source, mask
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.view, self.transient, self.devices, self.mode = view, transient, devices, mode
        self.batch, self.placed_mask = _place(source, mask, devices)

    # ------------------------------------------------------------------ engine interface
    @property
    def n_units(self) -> int:
        return self.batch.n_conditions

    @property
    def n_real(self) -> int:
        return self.source.n_conditions

    @property
    def has_view(self) -> bool:
        return self.view is not None

    def swarm_setup(self, swarm: Swarm) -> SwarmSetup:
        src = self.source if self.view is None else self.view.batch
        if swarm.n_restarts > 1:  # every condition `restarts` times: copy k of i at row k*n + i
            src = src.subset(np.tile(np.arange(self.n_real), swarm.n_restarts))
            batch, mask = _place(src, fit_mask(src, self.transient), self.devices)
        elif self.view is not None:
            batch, mask = _place(src, self.view.mask, self.devices)
        else:
            batch, mask = self.batch, self.placed_mask
        model = resolve_model(self.model, self.lower, batch.xdot, batch.dt, batch.mask,
                              swarm=True)
        obj, s_lo, s_hi = swarm_objective(model, swarm.mode, self.lower, self.upper)
        # sharded over devices, the pages' gathers would move data between them: one batch
        page = auto_page_size(model, batch.n_conditions) if self.devices is None else None
        return SwarmSetup(objective=obj, lower=s_lo, upper=s_hi,
                          data=condition_data(batch, mask), params=default_params(swarm.mode),
                          page_size=page, dtype=swarm.dtype)

    def from_swarm(self, setup: SwarmSetup, position, fitness):
        return swarm_params(setup, position, fitness)

    def rank(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Candidate parameters of every unit scored where the swarm scores them (each unit's
        view, or its record; the swarm's integration), their linear parameters solved on the
        unit (separable mode).

        **Arguments:** `theta` (U, M, P) M candidates per unit [SI] (U the units as placed,
        device padding included), inside the bounds.

        **Returns:** `(theta (U, M, P), rms (U, M) [N])`: the candidates as scored and their
        RMS (`inf` where not finite).
        """
        setup = self.swarm_setup(Swarm(mode=self.mode))
        pos = swarm_position(setup.objective, np.asarray(theta, float))
        th, rms = _rank(setup.objective, jax.device_put(np.moveaxis(pos, 1, 0)), setup.data)
        th, rms = np.moveaxis(np.asarray(th), 0, 1), np.asarray(rms).T
        return th, np.where(np.isfinite(rms), rms, np.inf)

    def default_start(self) -> np.ndarray:
        start = np.clip(self.model.default_start(), self.lower, self.upper)
        return np.broadcast_to(start, (self.n_units, self.model.n_params)).copy()

    def _resolved(self, theta, batch: Batch, swarm: bool = False) -> AbstractModel:
        return resolve_model(self.model, theta, batch.xdot, batch.dt, batch.mask, swarm=swarm)

    def stage(self, z: np.ndarray, on_view: bool) -> StageSpec:
        if on_view:
            batch, mask = _place(self.view.batch, self.view.mask, self.devices)
            # the swarm's integration: on the view's coarse grid step doubling would ask for
            # many steps, and this stage only has to bring the full-record polish close
            model = self._resolved(z, batch, swarm=True)
            # in pages: the solves differ a lot in length, and a page stops with its own
            # slowest
            page = auto_page_size(self.model, self.n_units) if self.devices is None else None
        else:
            batch, mask, page = self.batch, self.placed_mask, None
        model = self._resolved(z, batch) if not on_view else model
        m = check_mask(batch, mask)
        free = tuple(int(i) for i in np.flatnonzero(self.lower < self.upper))
        if not free:
            raise InputError("no free parameters: every parameter is fixed (lower == upper)")
        return StageSpec(residual=ConditionResidual(model),
                         args=(batch.x, batch.xdot, batch.dt, batch.force, jax.device_put(m)),
                         n=m.sum(axis=1), lower=self.lower, upper=self.upper, free=free,
                         jacobian="forward", snap=True, page_size=page,
                         integration=(model.substeps, model.scheme))

    def score(self, z: np.ndarray) -> np.ndarray:
        model = self._resolved(z, self.batch)
        return rms_per_condition(model, z, self.batch, self.placed_mask)

    def uncertainty(self, z: np.ndarray):
        return uncertainty(self.model, z, self.batch, mask=self.placed_mask)

    def likelihood(self, z: np.ndarray, on_view: bool) -> Likelihood:
        """The posterior's likelihood: each condition one unit, its residuals on its view or
        its record, the model integrated with the sub-steps the polish uses at `z`."""
        if on_view and self.view is None:
            raise InputError("the posterior on the views needs a problem built with a view")
        batch, mask = (self.view.batch, self.view.mask) if on_view else (self.source, self.mask)
        theta0 = np.clip(np.asarray(z, float)[: self.n_real], self.lower, self.upper)
        model = resolve_model(self.model, theta0, batch.xdot, batch.dt, batch.mask)
        exact = exact_tangent(model)
        return Likelihood(
            residual=ConditionResidual(model, blocks=True), theta0=theta0,
            data=(batch.x, batch.xdot, batch.dt, batch.force, jnp.asarray(mask)),
            lower=self.lower, upper=self.upper, names=self.model.param_names,
            units=self.model.units, labels=tuple(batch.labels),
            gauge=scale_gauge(self.model),
            exact=None if exact is None else ConditionResidual(exact, blocks=True),
            linear=tuple(self.model.basis_params), dynamic=self.model.dynamic,
            trim=cut_records)


def cut_records(data: tuple, n: int) -> tuple:
    """The per-test likelihood's data `(x, xdot, dt, force, mask)` (leading test axis;
    `dt` one step per record or one per sample) cut to the first `n` samples of every record
    (`Likelihood.trim`)."""
    x, xdot, dt, force, mask = data
    dt = dt[:, :n] if jnp.ndim(dt) == 2 else dt
    return x[:, :n], xdot[:, :n], dt, force[:, :n], mask[:, :n]


def tests_problem(
    model: str | AbstractModel,
    data: Batch,
    *,
    bounds: tuple[ArrayLike, ArrayLike] | None = None,
    transient: float | str | None = None,
    swarm: Swarm | None = None,
    devices: Any = None,
    view_length: int | None = None,
    checked: bool = False,
    view: bool | None = None,
) -> TestsProblem:
    """The per-test problem of `model` on `data` (a :class:`mrjax.data.Batch`).

    **Arguments:** `bounds` `(lower, upper)` (P,) or dicts by name [SI] (default the model's);
    `transient` an initial span left out of the fitness (s, `"cycle"` or None); `swarm` the
    swarm's settings (None: no swarm, so no view); `devices` to shard the conditions over;
    `view_length` pad the swarm's views to this many samples (the view length of a whole
    batch, for its chunks); `checked` skip the checks of the records (a chunk of a batch that
    passed them); `view` whether to make the records' views (default: where the swarm scores
    them).

    Raises :class:`mrjax.InputError` for bad bounds or too few scored samples; warns for a
    record shorter than one excitation period.
    """
    model = get(model)
    lo, hi = check_bounds(model, bounds)
    mask = fit_mask(data, transient)
    if not checked:
        check_records(model, data, mask)
    if view is None:
        view = swarm is not None and (model.dynamic if swarm.view is None else swarm.view)
    views = swarm_view(data, transient, length=view_length) if view else None
    return TestsProblem(model, data, mask, lo, hi, view=views, transient=transient,
                        devices=devices, mode=swarm.mode if swarm is not None else "separable")


def swarm_position(obj: AbstractObjective, theta: np.ndarray) -> np.ndarray:
    """The swarm positions (..., D) of parameters `theta` (..., P) [SI] for the objective `obj`
    of :func:`swarm_objective`: the nonlinear parameters (their logarithms where searched so)
    for the separable objective, `theta` itself for the full one, a dummy for a fully linear
    model."""
    if isinstance(obj, SeparableObjective):
        nl = obj.model.nonlinear_index
        logs = np.asarray(obj.log_mask or (False,) * len(nl), bool)
        v = theta[..., nl]
        return np.where(logs, np.log(np.where(logs, np.maximum(v, 1e-300), 1.0)), v)
    if isinstance(obj, LinearObjective):
        return np.zeros(theta.shape[:-1] + (1,))
    return theta


@eqx.filter_jit
def _rank(obj, position, data):
    """`(theta (M, U, P), rms (M, U))` of candidate positions (M, U, D): one candidate of
    every unit at a time (`lax.map`: the memory of one swarm generation of U particles)."""
    def one(pos):
        return jax.vmap(obj.to_params)(pos, data), jax.vmap(obj)(pos, data)

    return jax.lax.map(one, position)


@eqx.filter_jit
def _to_params(obj, position, data):
    return jax.vmap(obj.to_params)(position, data)


@eqx.filter_jit
def _to_params_rms(obj, position, data):
    return jax.vmap(obj.to_params)(position, data), jax.vmap(obj)(position, data)


def swarm_params(setup: SwarmSetup, position, fitness):
    """`(theta (R, P), rms (R,) [N])` of the swarm's best positions on every row: the full
    parameter vectors (the linear ones solved, in separable mode) and their fitness; a
    low-precision swarm's positions re-scored in the default float."""
    obj, data = setup.objective, setup.data
    dtype = np.asarray(setup.lower).dtype
    if setup.dtype is None or jnp.dtype(setup.dtype) == dtype:
        return _to_params(obj, position, data), fitness
    return _to_params_rms(obj, position.astype(dtype), data)


class ModelSwarm(eqx.Module):
    """Result of :func:`fit_swarm`: the swarm outcome in model parameters.

    **Fields:** `theta` (C, P) best parameters (all of them, also in separable mode), SI units;
    `rms` (C,) [N]; `result` the underlying :class:`mrjax.pso.SwarmResult`; `mode` static.
    """

    theta: Float[Array, "C P"]
    rms: Float[Array, " C"]
    result: SwarmResult
    mode: str = eqx.field(static=True)


def fit_swarm(
    model: AbstractModel,
    batch: Batch,
    *,
    key: PRNGKeyArray,
    mode: Literal["separable", "full"] = "separable",
    bounds: tuple[ArrayLike, ArrayLike] | None = None,
    mask: ArrayLike | None = None,
    params: Any = None,
    n_particles: int = 50,
    max_generations: int = 200,
    callback: Callable | None = None,
    dtype: Any = None,
    page_size: int | Literal["auto"] | None = "auto",
) -> ModelSwarm:
    """The batched swarm alone on every condition of `batch` (no view, no polish): the swarm
    stage of `mrjax.fit` as a function, e.g. for benchmarks or a multi-host run (its arrays
    stay on the devices).

    **Arguments:**

    - `model`: an `AbstractModel` (see `mrjax.models.get`).
    - `batch`: the conditions (`mrjax.data.Batch`), placed as they are (e.g. sharded).
    - `key`: PRNG key, or (C,) keys, one per condition (see `mrjax.pso.swarm`).
    - `mode`: `"separable"` (variable projection over the nonlinear parameters; default) or
        `"full"` (the paper's swarm over every parameter).
    - `bounds`: `(lower, upper)` (P,) in SI units, default `model.bounds`.
    - `mask`: (C, T) samples to score, default `batch.mask` (see `mrjax.data.fit_mask`).
    - `params` (:class:`mrjax.pso.PSOParams`; default `mrjax.pso.default_params(mode)`),
        `n_particles`, `max_generations`, `callback`, `dtype`: see `mrjax.pso.swarm`. The
        returned `theta` and `rms` are recomputed in the default float from the best positions
        of a lower-precision swarm.
    - `page_size`: score only the running conditions, this many at a time; `"auto"`
        (default): :func:`auto_page_size`.

    ODE models integrate with the swarm's policy of `mrjax.models.resolve_model` (one L-stable
    step per sample).

    **Returns:** a :class:`ModelSwarm` with the full parameter vectors and their RMS [N].
    """
    model = get(model)
    lo, hi = check_bounds(model, bounds)
    model = resolve_model(model, lo, batch.xdot, batch.dt, batch.mask, swarm=True)
    obj, s_lo, s_hi = swarm_objective(model, mode, lo, hi)
    if page_size == "auto":
        page_size = auto_page_size(model, batch.n_conditions)
    setup = SwarmSetup(objective=obj, lower=s_lo, upper=s_hi,
                       data=condition_data(batch, mask), params=default_params(mode),
                       page_size=page_size, dtype=dtype)
    res = swarm_result(setup, Swarm(n_particles=n_particles, max_generations=max_generations,
                                    mode=mode, params=params, dtype=dtype), key,
                       callback=callback)
    theta, rms = swarm_params(setup, res.position, res.fitness)
    return ModelSwarm(theta=theta, rms=rms, result=res, mode=mode)
