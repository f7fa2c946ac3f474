"""The structure problem kind of the engine: a mass on a model identified from the structure's
response to a known input (output error), one unit per record."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from ..bayes import Likelihood
from ..engine import AbstractProblem, StageSpec, Swarm, SwarmSetup
from ..models import AbstractModel, check_bounds, resolve_model
from ..objective import log_search_flags
from ..pso import default_params
from ..refine import Uncertainty, intervals, jacobian_uncertainty
from ._equation import equation_objective, position_of, solve_positions
from ._records import VIEW_SAMPLES, Records, check_periods, equation_view, step_inputs
from ._system import AbstractStructure, ResponseResidual, response_rms, simulate_batch

#: Default box of the mass [kg]: small rigs to storeys (the swarm solves the mass by least
#: squares, so the width costs nothing).
MASS_BOUNDS = (1e-3, 1e6)
#: Sub-steps by step doubling: the count m is kept where the responses of m and 2m steps per
#: sample differ by at most this fraction of the response's RMS on every record's view.
SUBSTEP_TOL = 1e-4
#: The first and the largest count the doubling tries.
FIRST_SUBSTEPS, MAX_SUBSTEPS = 2, 64


def structure_bounds(model: AbstractModel, bounds) -> tuple[np.ndarray, np.ndarray]:
    """The box `(lower, upper)` (1 + P,) of `z = [m, theta]`: `bounds` a pair of dicts by name
    (`"m"` and the model's parameters; missing ones keep their default) or of (1 + P,) arrays,
    or None (the mass in `MASS_BOUNDS`, the model's parameters in its default box)."""
    if bounds is None:
        lo, hi = model.bounds
        return np.r_[MASS_BOUNDS[0], lo], np.r_[MASS_BOUNDS[1], hi]
    try:
        lo, hi = bounds
    except (TypeError, ValueError):
        raise InputError("bounds must be a pair (lower, upper)") from None
    if isinstance(lo, dict) or isinstance(hi, dict) or lo is None or hi is None:
        lo, hi = dict(lo or {}), dict(hi or {})
        m_lo, m_hi = lo.pop("m", MASS_BOUNDS[0]), hi.pop("m", MASS_BOUNDS[1])
        th_lo, th_hi = check_bounds(model, (lo, hi))
    else:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        if lo.shape != (1 + model.n_params,) or hi.shape != lo.shape:
            raise InputError(f"bounds need {1 + model.n_params} values each (m, "
                             f"{', '.join(model.param_names)}), got {lo.shape} and {hi.shape}")
        (m_lo, th_lo), (m_hi, th_hi) = (lo[0], lo[1:]), (hi[0], hi[1:])
        th_lo, th_hi = check_bounds(model, (th_lo, th_hi))
    if not (np.isfinite(m_lo) and np.isfinite(m_hi) and 0 < m_lo <= m_hi):
        raise InputError(f"the mass's bounds must be positive with lower <= upper, got "
                         f"{m_lo:g}:{m_hi:g} kg")
    return np.r_[float(m_lo), th_lo], np.r_[float(m_hi), th_hi]


class StructureProblem(AbstractProblem):
    """A mass on `model` from each record's response (see `mrjax.structure`): every record is
    a unit whose unknowns are `z = [m, theta]` (SI) in the box `[lower, upper]`.

    The swarm scores the equation error on each record's view (`mrjax.structure.equation_view`,
    the model and the mass solved by least squares where they are linear); the polish fits the
    simulated response to the measured one on the full records (output error, forward-mode
    Jacobian through the simulation), with the sub-steps of :meth:`substeps`; the std-errors
    and the posterior's likelihood use the same residual. The view of the output error (the
    posterior's `"view"`) is each record's first period, or its first `VIEW_SAMPLES`.

    **Coordinates.** The engine works on `w`: `z` with the mass and the model's log-searched
    parameters (a positive box, `mrjax.objective.log_search_flags`) as logarithms
    (:meth:`to_engine`, :meth:`from_engine`): the polish's bounded map then resolves a mass of
    2 kg in a box up to 1e6 kg. Std-errors and the posterior are in `z`.

    **Fields:** `model`, `structure`, `records` (:class:`Records`), `view` (their first
    samples), `lower`, `upper` (1 + P,), `log_mask` (1 + P,).
    """

    def __init__(self, model: AbstractModel, structure: AbstractStructure, records: Records,
                 lower: np.ndarray, upper: np.ndarray):
        self.model, self.structure, self.records = model, structure, records
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.log_mask = np.r_[True, log_search_flags(model, self.lower[1:])]
        self.view = records.first(structure.period or VIEW_SAMPLES)
        self._inputs: dict = {}
        self._substeps: dict = {}

    @property
    def names(self) -> tuple[str, ...]:
        """The unknowns' names: `m`, then the model's parameters."""
        return ("m",) + tuple(self.model.param_names)

    @property
    def units(self) -> tuple[str, ...]:
        return ("kg",) + tuple(self.model.units)

    @property
    def mass(self) -> float | None:
        """The mass [kg] where it is held (equal bounds), else None."""
        return float(self.lower[0]) if self.lower[0] == self.upper[0] else None

    @property
    def free(self) -> tuple[int, ...]:
        return tuple(int(i) for i in np.flatnonzero(self.lower < self.upper))

    def to_engine(self, z: np.ndarray) -> np.ndarray:
        """The engine's coordinates `w` of unknowns `z` (..., 1 + P)."""
        z = np.asarray(z, float)
        return np.where(self.log_mask, np.log(np.where(self.log_mask, z, 1.0)), z)

    def from_engine(self, w: np.ndarray) -> np.ndarray:
        """The unknowns `z` of engine coordinates `w` (..., 1 + P)."""
        w = np.asarray(w, float)
        return np.where(self.log_mask, np.exp(np.where(self.log_mask, w, 0.0)), w)

    # ------------------------------------------------------------------ integration
    def inputs(self, m: int, on_view: bool = False):
        """The step inputs of the records (or their views) with `m` sub-steps, on the
        device (kept per count)."""
        key = (int(m), bool(on_view))
        if key not in self._inputs:
            recs = self.view if on_view else self.records
            self._inputs[key] = jax.device_put(step_inputs(recs, self.structure, m))
        return self._inputs[key]

    def substeps(self, z: np.ndarray) -> int:
        """The sub-steps per sample at unknowns `z` (U, 1 + P): doubled from `FIRST_SUBSTEPS`
        until every view's response changes by at most `SUBSTEP_TOL` of its RMS (the last
        count's error is about a third of that change: Runge-Kutta converges at second
        order across the kinks of hysteresis), at most `MAX_SUBSTEPS`. Kept per `z`."""
        z = np.asarray(z, float)
        key = z.astype(np.float32).tobytes()
        if key not in self._substeps:
            self._substeps[key] = doubled_substeps(self.model, self.structure, z,
                                                   lambda m: self.inputs(m, True),
                                                   self.view.mask)
        return self._substeps[key]

    def data(self, z: np.ndarray, on_view: bool):
        """`(residual args, n (U,))` of the records or their views with the sub-steps at
        unknowns `z`."""
        recs = self.view if on_view else self.records
        args = (self.inputs(self.substeps(z), on_view), jnp.asarray(recs.response),
                jnp.asarray(recs.mask))
        return args, recs.mask.sum(axis=1)

    # ------------------------------------------------------------------ engine interface
    @property
    def n_units(self) -> int:
        return self.records.n_units

    @property
    def has_view(self) -> bool:
        return True

    def polish_view(self, z: np.ndarray) -> bool:
        return False  # the swarm's view is an equation error: the polish starts on the records

    def _objective(self):
        model = resolve_model(self.model, self.lower[1:], None, None, swarm=True)
        return equation_objective(model, self.lower, self.upper, self.mass is None,
                                  self.structure.period)

    def swarm_setup(self, swarm: Swarm) -> SwarmSetup:
        obj, s_lo, s_hi = self._objective()
        view = equation_view(self.records, self.structure, self.mass)
        k = swarm.n_restarts
        data = tuple(np.tile(a, (k,) + (1,) * (a.ndim - 1)) for a in view)
        return SwarmSetup(objective=obj, lower=s_lo, upper=s_hi, data=jax.device_put(data),
                          params=default_params("separable"), dtype=swarm.dtype)

    def from_swarm(self, setup: SwarmSetup, position, fitness):
        pos = jnp.asarray(position, jnp.result_type(float))
        z, rms = solve_positions(setup.objective, pos, setup.data)
        return self.to_engine(np.clip(np.asarray(z), self.lower, self.upper)), np.asarray(rms)

    def default_start(self) -> np.ndarray:
        """The model's default nonlinear parameters, the mass and the linear ones solved by
        least squares on each record's view (the equation error)."""
        obj, _, _ = self._objective()
        start = np.r_[0.5 * (self.lower[0] + self.upper[0]), self.model.default_start()]
        pos = np.broadcast_to(position_of(obj, np.clip(start, self.lower, self.upper)),
                              (self.n_units, max(self.model.nonlinear_index.size, 1)))
        view = jax.device_put(equation_view(self.records, self.structure, self.mass))
        z, _ = solve_positions(obj, jnp.asarray(pos), view)
        return self.to_engine(np.clip(np.asarray(z), self.lower, self.upper))

    def stage(self, w: np.ndarray, on_view: bool) -> StageSpec:
        if not self.free:
            raise InputError("no free unknowns: every bound is fixed (lower == upper)")
        z = self.from_engine(w)
        args, n = self.data(z, on_view)
        return StageSpec(residual=ResponseResidual(self.model, self.structure,
                                                   log_mask=tuple(map(bool, self.log_mask))),
                         args=args, n=n, lower=self.to_engine(self.lower),
                         upper=self.to_engine(self.upper), free=self.free,
                         jacobian="forward", snap=True,
                         integration=(self.substeps(z), "rk4"))

    def score(self, w: np.ndarray) -> np.ndarray:
        z = self.from_engine(w)
        (inputs, measured, mask), _ = self.data(z, False)
        return response_rms(self.model, self.structure, z, inputs, measured, mask)

    def uncertainty(self, w: np.ndarray) -> Uncertainty:
        """The linearised uncertainty of `z` (SI) at engine coordinates `w`."""
        z = self.from_engine(w)
        args, n = self.data(z, False)
        out = _uncertainty(ResponseResidual(self.model, self.structure), self.free, z, args,
                           jnp.asarray(n))
        se_f, cov_f, corr_f, ok_f, dof, sigma = (np.asarray(a) for a in out)
        U, K = z.shape
        idx = np.asarray(self.free, int)
        stderr, ok = np.zeros((U, K)), np.ones((U, K), bool)
        cov, corr = np.zeros((U, K, K)), np.broadcast_to(np.eye(K), (U, K, K)).copy()
        stderr[:, idx], ok[:, idx] = se_f, ok_f
        cov[:, idx[:, None], idx[None, :]] = cov_f
        corr[:, idx[:, None], idx[None, :]] = corr_f
        return Uncertainty(
            **jax.device_put(dict(theta=z, stderr=stderr, cov=cov, corr=corr,
                                  ci95=intervals(z, stderr, dof, 0.95), identifiable=ok,
                                  dof=dof, sigma=sigma)),
            param_names=self.names, free=tuple(bool(self.lower[j] < self.upper[j])
                                               for j in range(K)))

    def likelihood(self, w: np.ndarray, on_view: bool) -> Likelihood:
        """The posterior's likelihood: each record a unit, its response residuals on its view
        or on the record, with the polish's sub-steps at the optimum `w`; its unknowns `z`
        (SI)."""
        z = np.clip(self.from_engine(w), self.lower, self.upper)
        args, _ = self.data(z, on_view)
        sym = self.model.scale_symmetry
        return Likelihood(
            residual=ResponseResidual(self.model, self.structure, blocks=True), theta0=z,
            data=args, lower=self.lower, upper=self.upper, names=self.names,
            units=self.units, labels=self.records.labels,
            gauge=(sym.gauge,) if sym is not None and sym.gauge in self.names else (),
            dynamic=True)


@eqx.filter_jit
def _uncertainty(residual, free, z, args, n):
    """Per unit: `mrjax.refine.jacobian_uncertainty` of the residuals at `z` (U, K) over the
    unknowns `free` (static)."""
    idx = np.asarray(free, int)

    def one(zz, a, k):
        def res(zf):
            return residual(zz.at[idx].set(zf), a)

        return jacobian_uncertainty(res(zz[idx]), jax.jacfwd(res)(zz[idx]), k)

    return jax.vmap(one)(z, args, n)


def doubled_substeps(model: AbstractModel, structure: AbstractStructure, z: np.ndarray,
                     inputs_of, mask: np.ndarray) -> int:
    """The sub-step count by step doubling (see :meth:`StructureProblem.substeps`): `z` (U,
    1 + P) the unknowns of every record; `inputs_of(m)` the step inputs with m sub-steps;
    `mask` (U, T) the samples compared."""
    m_mask = np.asarray(mask, bool)

    def response(m):
        with np.errstate(invalid="ignore", over="ignore"):
            return np.asarray(simulate_batch(model, structure, jnp.asarray(z), inputs_of(m)))

    m, y = FIRST_SUBSTEPS, response(FIRST_SUBSTEPS)
    while 2 * m <= MAX_SUBSTEPS:
        y2 = response(2 * m)
        with np.errstate(invalid="ignore", over="ignore"):
            d = np.sqrt(np.sum(np.where(m_mask, y - y2, 0.0) ** 2, axis=1))
            s = np.sqrt(np.sum(np.where(m_mask, y2, 0.0) ** 2, axis=1))
        if np.all(np.isfinite(d) & (d <= SUBSTEP_TOL * s)):
            break
        m, y = 2 * m, y2
    return m


def structure_problem(model: AbstractModel, structure: AbstractStructure, records: Records,
                      bounds=None) -> StructureProblem:
    """The problem of `model` in `structure` on `records` (checked: whole periods of a
    periodic input, a response on every record, enough samples for the unknowns, a known mass
    under base excitation)."""
    lo, hi = structure_bounds(model, bounds)
    check_periods(records, structure)
    n = records.mask.sum(axis=1)
    K = int(np.sum(lo < hi))
    for lab, k in zip(records.labels, n):
        if k == 0:
            raise InputError(f"record {lab!r} has no measured {structure.response}")
        if k <= K:
            raise InputError(f"record {lab!r}: {int(k)} samples are too few for the {K} "
                             f"unknowns of a structure on model {model.name!r} (at least "
                             f"{K + 1} needed)")
    if not structure.mass_identifiable and lo[0] != hi[0]:
        raise InputError(f"a {structure.name} structure's response depends on the element's "
                         f"force per unit mass only: give the mass, e.g. bounds m=2:2 "
                         f"(--bounds m=2:2)")
    return StructureProblem(model, structure, records, lo, hi)
