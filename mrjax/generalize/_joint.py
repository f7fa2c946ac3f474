"""The joint-laws problem kind of the engine: law coefficients (and a command lag) fitted on
every record at once; the engine runs the swarm on the records' views, Levenberg-Marquardt on
the views and then on the full records, and the std-errors.

Both `generalize(result, batch, method="joint")` (a start and a box from the two-step laws of
per-test fits) and :func:`identify` (a box from the parameters' bounds, no per-test fit) build a
:class:`LawsProblem` and call :func:`solve_laws` (`mrjax.engine.solve`).

**Unknowns.** Each law of degree d is represented by its values at d + 1 nodes spread over the
command range (log values for an `"exp"` law): a well-scaled, unit-bearing parametrisation
(`Layout`). The unknowns are these node values and, when fitted, the rate $\\eta$ of the
command filter. :class:`Coding` maps a swarm position, or the vector of the Levenberg-Marquardt
variables, to them:

- the laws of *linear* parameters with `"poly"` laws are not searched by the swarm: given the
    others they are linear in their coefficients (column $A_j(t)\\,u(t)^m$ of the design), so
    every particle gets them by exact least squares (variable projection,
    `mrjax.objective.gram_terms` / `solve_normal`, Gram terms summed over every record);
- in Bouc-Wen-type models the scale of z is redundant (`canonical_z_scale`): it is fixed by
    $\\delta(u_0) = \\beta(u_0) + \\gamma(u_0)$ ($|z|_{max} = 1$) at the first node $u_0$ of
    delta's law, so delta's value there is derived, not an unknown. With constant delta, beta
    and gamma laws and no user bounds on them, :func:`identify`'s swarm searches the shape as
    $(\\log\\delta, q = \\gamma/\\delta)$ instead of $(\\beta, \\gamma)$: the inverse yield
    displacement $1/\\delta$ and the loop's shape, each in its own, data-free range;
- $\\eta$ is searched and polished as $\\log\\eta$.

**Records.** A record is a row with its own command: a constant (a sine test at one current or
voltage) or a per-sample signal $v(t)$, which the laws see through the filter
$u_{k+1} = v_k + (u_k - v_k)e^{-\\eta\\Delta t_k}$, $u_0 = v_0$ (:func:`lag_current`; identity on
a constant). Rows of similar length are grouped (:func:`length_groups`, at most
`MAX_GROUPS` groups), so that a short test is not padded to the longest one; a static model
without per-sample commands packs its samples into rows of `PACK_ROW` (one current each).

**Stages** (`mrjax.engine.solve`, the pipeline of `mrjax.fit`):

1. the batched swarm (`restarts` independent swarms of the one unit) scores every particle on
    the records' *views* (`mrjax.data.swarm_view`:
    `JOINT_SAMPLES_PER_PERIOD` (64) samples per period, or 32 per period of a broadband
    record's bandwidth),
    integrating with one L-stable step per sample;
2. the candidates (the swarm's best and a start given, e.g. the two-step laws) ranked on the
    full records; Levenberg-Marquardt (`mrjax.refine.solve_box`) on every unknown, first on the
    views to `tol`, then on the full records to `FULL_TOL_FACTOR` x `tol`, each with the
    sub-steps of `mrjax.models.resolve_model` for the laws at `N_LEVELS` commands spanning the
    data; where the records need the L-stable scheme (stiff ODE fits; then so do their coarser
    views) the views' polish is skipped and the full records are polished from the start to
    `VIEW_TOL_FACTOR` x `tol` (where the per-test polish on the views stops): there the coupled
    laws' optimum on the coarse views can lie in another basin than on the records. Each
    variable is scaled by the residuals' sensitivity to it at the start (`lm_solve(scale=)`);
3. the total RMS on every scored sample of the full records, and the linearised std-errors of
    every coefficient and of $\\eta$ (`mrjax.refine.jacobian_uncertainty`, mapped to the
    coefficients by the delta method) with identifiability flags.

The result is never worse (total RMS on the full records) than the start it was given.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from ..bayes import Likelihood
from ..engine import (
    AbstractProblem,
    Outcome,
    Polish,
    StageSpec,
    Start,
    Swarm,
    SwarmSetup,
    row_keys,
    solve,
)
from ..models import AbstractModel, exact_tangent, resolve_model
from ..pso import PSOParams, default_params
from ..refine import VIEW_TOL_FACTOR, jacobian_uncertainty
from ._coding import (
    Coding,
    JointObjective,
    Layout,
    coded_law_values,
    coefficients_of,
    from_bounded,
    joint_residual_blocks,
    joint_residuals,
    n_scored,
    node_box,
    objective_at,
    total_rms_of,
)
from ._rows import Rows

#: Commands at which the laws are evaluated for the sub-step policy (spanning the data).
N_LEVELS = 9


class LawResidual(eqx.Module):
    """The one residual of the laws: the residuals [N] of every record (zero on unscored
    samples) for the polish's variables `z` of :class:`Coding` (`Coding.from_bounded`),
    flattened; with `free=True` for the free node values (`Coding.from_free`, the unknowns
    of the posterior) as blocks of rows, `((r (R, T), mask (R, T)), ...)` (see
    `mrjax.bayes.Likelihood`)."""

    model: AbstractModel
    coding: Coding
    free: bool = eqx.field(static=True, default=False)

    def __call__(self, z, data):
        if self.free:
            nu, eta = self.coding.from_free(z)
            return joint_residual_blocks(self.model, self.coding, nu, eta, data)
        nu, eta = self.coding.from_bounded(z)
        return joint_residuals(self.model, self.coding, nu, eta, data)


def node_names(model: AbstractModel, layout: Layout, free: list[int]
               ) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """`(names, units)` of the free node values `free` of `layout`: `"c@0.5A"` (`"log
    beta@0A"` for an `"exp"` law) and the parameter's unit (`"log N/m"`)."""
    names, units = [], []
    for p, (n, u) in enumerate(zip(model.param_names, model.units)):
        log = layout.kinds[p] == "exp"
        for nd in layout.nodes[p]:
            names.append(f"{'log ' if log else ''}{n}@{nd:g}A")
            units.append(f"log {u}" if log else u)
    return tuple(names[k] for k in free), tuple(units[k] for k in free)


@eqx.filter_jit
def _positions(obj: JointObjective, position, data):
    """`(nu, eta, RMS [N])` of every swarm row's best position (R, D) on its data."""
    return jax.vmap(obj.solve)(position, data)


@eqx.filter_jit
def law_uncertainty(model, coding, data, phi):
    """Std-errors of every coefficient and of eta, and their identifiability, from the
    Jacobian of the residuals with respect to the free node values and eta (in their units;
    `mrjax.refine.jacobian_uncertainty`), mapped to the coefficients by the delta method.

    **Returns:** `(stderr (V + 1,), identifiable (V + 1,), dof, sigma [N])`, the last entry
    eta's."""
    fit = coding.lag == "fit"
    Q = len(coding.free)

    def to_phi(psi):  # natural variables: node values and eta itself
        return psi.at[Q].set(jnp.log(psi[Q])) if fit else psi

    psi0 = phi.at[Q].set(jnp.exp(phi[Q])) if fit else phi

    def res(psi):
        nu, eta = coding.from_free(to_phi(psi))
        return joint_residuals(model, coding, nu, eta, data)

    r = res(psi0)
    J = jax.jacfwd(res)(psi0)
    se, cov, _, ident, dof, sigma = jacobian_uncertainty(r, J, n_scored(data))

    def outputs(psi):
        nu, eta = coding.from_free(to_phi(psi))
        return jnp.concatenate([coding.coefficients(nu), jnp.reshape(eta, (1,))])

    H = jax.jacfwd(outputs)(psi0)  # (V + 1, Q')
    dep = H != 0
    known = jnp.isfinite(se)
    cov0 = jnp.where(jnp.isfinite(cov), cov, 0.0)
    var = jnp.einsum("ij,jk,ik->i", H, cov0, H)
    undefined = jnp.any(dep & ~known[None, :], axis=1)
    se_out = jnp.where(undefined, jnp.nan, jnp.sqrt(jnp.maximum(var, 0.0)))
    ident_out = jnp.all(~dep | ident[None, :], axis=1)
    return se_out, ident_out, dof, sigma




class LawsProblem(AbstractProblem):
    """Law coefficients (and the lag of a time-varying command) from every record at once: one
    unit, whose unknowns are the polish's variables of the :class:`Coding` (swarm coordinates,
    then the node values the swarm solves by least squares) in the box `lm_lower`, `lm_upper`.

    **Polish plan:** where the views are polished (the records do not need the L-stable
    scheme), to `tol`, then the full records to 100 x `tol` with no step cap (the coupled laws'
    refinement); where they are not (stiff records: the coupled laws' optimum on the coarse
    views can lie in another basin), the full records from the start to `VIEW_TOL_FACTOR` x
    `tol`, where the per-test polish on the views stops.

    **Fields:** `model`; `layout`; `objective` the swarm's :class:`JointObjective` (its
    `coding` serves the polish); `lower`, `upper` (D,) the swarm's box; `lm_lower`,
    `lm_upper` (D + K,) the polish's box; `full` the records; `view` their swarm views or None;
    `levels` commands spanning the data (sub-step policy); `start` `(nu, eta)` a candidate to
    be never worse than (e.g. the two-step laws) or None; `pso_params` the swarm's default
    hyperparameters; `row_labels` the labels of the records of `full` and of `view`, in row
    order (one row per record: the posterior's noise levels), or None.
    """

    view_tol_factor = 1.0
    search_tol_factor = VIEW_TOL_FACTOR
    refine_max_steps = None

    def __init__(self, model: AbstractModel, layout: Layout, objective: JointObjective,
                 lower: np.ndarray, upper: np.ndarray, lm_lower: np.ndarray,
                 lm_upper: np.ndarray, full: tuple[Rows, ...], view: tuple[Rows, ...] | None,
                 levels: np.ndarray, start: tuple[np.ndarray, float] | None = None,
                 pso_params: PSOParams | None = None,
                 row_labels: tuple[tuple[str, ...], tuple[str, ...] | None] | None = None):
        self.model, self.layout, self.objective = model, layout, objective
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.lm_lower, self.lm_upper = np.asarray(lm_lower, float), np.asarray(lm_upper, float)
        self.full, self.view, self.levels, self.start = full, view, np.asarray(levels), start
        self.pso_params = pso_params if pso_params is not None else default_params("separable")
        self.row_labels = row_labels
        self._policy: dict = {}  # the sub-step policy's answers (see `resolved`)

    @property
    def coding(self) -> Coding:
        return self.objective.coding

    # ------------------------------------------------------------------ unknowns
    def unknowns(self, nu, eta) -> np.ndarray:
        """(K,) the polish's variables of node values `nu` and lag rate `eta`, in the box."""
        return np.clip(self.coding.bounded_of(nu, eta), self.lm_lower, self.lm_upper)

    def laws_of(self, z) -> tuple[np.ndarray, float]:
        """`(nu (V,), eta)` of the polish's variables `z` (K,) (host)."""
        nu, eta = from_bounded(self.coding, np.asarray(z, float))
        return np.asarray(nu), float(eta)

    def swarm_model(self) -> AbstractModel:
        """The model with the swarm's integration policy (one L-stable step per sample, no
        estimate needed); static models unchanged."""
        return resolve_model(self.model, self.lower, None, None, swarm=True)

    def resolved(self, nu, eta, data: tuple[Rows, ...]) -> AbstractModel:
        """The model with the polish's sub-step policy for the laws at `levels` on `data`: the
        stiffest level decides (its step doubling integrates every row of each group side by
        side). The answer is kept per `(nu, eta, data)` to float32 precision (a round trip
        through the polish's variables changes the last bits): the policy's step doubling
        costs a few forward integrations."""
        model = self.model
        if not model.dynamic or model.substeps is not None:
            return model
        nu = np.asarray(nu, float)
        key = (nu.astype(np.float32).tobytes(), np.float32(eta), id(data))
        if key in self._policy:
            return self._policy[key]
        rows = np.asarray(coded_law_values(self.coding, nu, self.levels))
        xdot = tuple(np.asarray(r.xdot) for r in data)
        dt = tuple(np.asarray(r.dt) for r in data)
        mask = tuple(np.asarray(r.mask, bool) for r in data)
        vmax = max(float(np.max(np.abs(np.where(m, v, 0.0)))) if m.any() else 0.0
                   for v, m in zip(xdot, mask))
        with np.errstate(all="ignore"):
            rate = np.array([model.stiffness(r, vmax) if np.all(np.isfinite(r)) else -1.0
                             for r in rows])
        rows = rows[np.argsort(-np.nan_to_num(rate, nan=-1.0))]
        rows = rows[np.all(np.isfinite(rows), axis=1)]
        if rows.size == 0:  # no law gives finite parameters: the policy that needs no estimate
            out = self.swarm_model()
        else:
            out = resolve_model(model, rows[:1], xdot, dt, mask)
        self._policy[key] = out
        return out

    # ------------------------------------------------------------------ engine interface
    @property
    def n_units(self) -> int:
        return 1

    @property
    def has_view(self) -> bool:
        return self.view is not None

    def swarm_setup(self, swarm: Swarm) -> SwarmSetup:
        data = self.view if self.view is not None else self.full
        K = swarm.n_restarts
        rep = jax.device_put(jax.tree.map(
            lambda a: np.broadcast_to(np.asarray(a)[None], (K,) + a.shape), data))
        obj = eqx.tree_at(lambda o: o.model, self.objective, self.swarm_model())
        return SwarmSetup(objective=obj, lower=self.lower, upper=self.upper, data=rep,
                          params=self.pso_params, page_size=None, dtype=swarm.dtype)

    def from_swarm(self, setup: SwarmSetup, position, fitness):
        nu, eta, rms = (np.asarray(a) for a in _positions(setup.objective, position,
                                                            setup.data))
        z = np.stack([self.unknowns(n, e) for n, e in zip(nu, eta)])
        return z, rms

    def default_start(self) -> np.ndarray:
        if self.start is not None:
            return self.unknowns(*self.start)[None]
        obj = eqx.tree_at(lambda o: o.model, self.objective, self.swarm_model())
        nu, eta, _ = objective_at(obj, np.zeros(0), self.view or self.full)
        return self.unknowns(np.asarray(nu), float(eta))[None]

    def choose_start(self, z: np.ndarray, source: str) -> Start:
        # every candidate on the full records with the swarm's integration (one compiled
        # function for all; they are only ranked here), then the chosen one with its own
        # sub-steps
        cands = [(source, np.asarray(z[0], float))]
        if self.start is not None and source != "default":
            cands.append(("start", self.unknowns(*self.start)))
        m_rank = self.swarm_model()
        scored = []
        for name, zc in cands:
            nu, eta = self.laws_of(zc)
            scored.append((float(total_rms_of(m_rank, self.coding, nu, eta, self.full)), name,
                           zc))
        _, name, best = min(scored, key=lambda s: (not np.isfinite(s[0]), s[0]))
        return Start(z=best[None], rms=self.score(best[None]), source=name,
                     candidates={s[1]: s[0] for s in scored})

    def polish_view(self, z: np.ndarray) -> bool:
        # a view samples its record at least as coarsely: where the full records need the
        # L-stable scheme, so do the views (their own policy is not asked). There the coupled
        # laws' optimum on the views (coarse grid, one L-stable step) can lie in another basin
        # than the full records', which a few full-record steps do not leave
        # (`benchmarks/tuning.md`)
        if self.view is None:
            return False
        nu, eta = self.laws_of(z[0])
        m_full = self.resolved(nu, eta, self.full)
        if m_full.dynamic and m_full.scheme == "sdirk":
            return False
        m_view = self.resolved(nu, eta, self.view)
        return not (m_view.dynamic and m_view.scheme == "sdirk")

    def stage(self, z: np.ndarray, on_view: bool) -> StageSpec:
        data = self.view if on_view else self.full
        nu, eta = self.laws_of(z[0])
        m = self.resolved(nu, eta, data)
        return StageSpec(residual=LawResidual(m, self.coding),
                         args=jax.tree.map(lambda a: a[None], data),
                         n=np.array([sum(r.n_scored for r in data)]), lower=self.lm_lower,
                         upper=self.lm_upper,
                         jacobian="forward" if self.model.dynamic else "linearize",
                         scaled=True, integration=(m.substeps, m.scheme))

    def score(self, z: np.ndarray) -> np.ndarray:
        nu, eta = self.laws_of(z[0])
        m = self.resolved(nu, eta, self.full)
        return np.array([float(total_rms_of(m, self.coding, nu, eta, self.full))])

    def likelihood(self, z: np.ndarray, on_view: bool) -> Likelihood:
        """The posterior's likelihood: one unit, the whole data set, one noise level per row
        (record); its unknowns the free node values `z` (1, Q) of the :class:`Coding`
        (`Coding.free_of`), in the box of every node value within the model's bounds
        (:func:`node_box`); the laws' residuals on the views or the records, integrated with
        the polish's sub-step policy."""
        data = self.view if on_view else self.full
        if data is None or self.row_labels is None:
            raise InputError("the laws' posterior needs a problem built with one row per "
                             "record (and the views where they are scored)")
        phi0 = np.asarray(z, float)
        nu, eta = self.coding.from_free(jnp.asarray(phi0[0]))
        m = self.resolved(np.asarray(nu), float(eta), data)
        exact = exact_tangent(m)
        free = list(self.coding.free)
        lo, hi = node_box(self.model, self.layout, *self.model.bounds)
        names, units = node_names(self.model, self.layout, free)
        fixed = set(self.model.basis_params)
        return Likelihood(
            residual=LawResidual(m, self.coding, free=True), theta0=phi0,
            data=jax.tree.map(lambda a: a[None], data), lower=lo[free], upper=hi[free],
            names=names, units=units, labels=("laws",),
            row_labels=self.row_labels[1 if on_view else 0], unit_dim="laws",
            exact=None if exact is None else LawResidual(exact, self.coding, free=True),
            linear=tuple(n for n in names if n.split("@")[0] in fixed),
            dynamic=self.model.dynamic)

    def uncertainty(self, z: np.ndarray):
        if not self.coding.n_free:
            return None
        nu, eta = self.laws_of(z[0])
        m = self.resolved(nu, eta, self.full)
        se, ok, dof, sigma = law_uncertainty(m, self.coding, self.full,
                                             self.coding.free_of(nu, eta))
        return np.asarray(se), np.asarray(ok), int(dof), float(sigma)


@dataclasses.dataclass(frozen=True)
class JointOutcome:
    """What :func:`solve_laws` found: `coef` (V,) law coefficients, `eta` the lag rate [1/s]
    (or None without lag), `rms` total RMS [N] on the full records, `stderr` (V + 1,) and
    `identifiable` (V + 1,) (last entry eta's; None without uncertainty), `sigma` [N], `dof`,
    and the engine's `outcome`."""

    coef: np.ndarray
    eta: float | None
    rms: float
    stderr: np.ndarray | None = None
    identifiable: np.ndarray | None = None
    sigma: float = float("nan")
    dof: int = 0
    outcome: Outcome | None = None


def solve_laws(problem: LawsProblem, *, swarm: Swarm | None, polish: Polish | None,
               uncertainty: bool, key: Any) -> JointOutcome:
    """Run the engine on `problem` (no swarm where it has nothing to search) and read the laws
    off its outcome: swarm -> candidates -> polish (views, then full records) -> std-errors.
    The result is never worse (total RMS on the full records) than the start it was given."""
    coding = problem.coding
    if coding.n_position == 0:
        swarm = None
    if not coding.n_free:
        polish = None
    rows = swarm.n_restarts if swarm is not None else 1
    out = solve(problem, swarm=swarm, polish=polish, uncertainty=uncertainty,
                key=row_keys(key, rows))
    nu, eta = problem.laws_of(out.z[0])
    coef = np.asarray(coefficients_of(coding, nu))
    res = JointOutcome(coef=coef, eta=float(eta) if coding.use_lag else None,
                       rms=float(out.rms[0]), outcome=out)
    if out.uncertainty is not None:
        se, ok, dof, sigma = out.uncertainty
        res = dataclasses.replace(res, stderr=se, identifiable=ok, dof=dof, sigma=sigma)
    return res
