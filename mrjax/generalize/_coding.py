"""How the unknowns of a joint fit map to law coefficients: the laws' layout (node values), the
coding of swarm positions and polish variables, the swarm's objective (variable projection for
the linear laws), the residuals and the boxes. See `mrjax.generalize._joint` for the fit."""

from __future__ import annotations

import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..models import AbstractModel
from ..objective import gram_terms, rms_from_gram, solve_normal
from ..pso import AbstractObjective
from ._laws import LawSet, law_value, vander
from ._rows import Rows

#: Range [1/m] of delta, the inverse yield displacement of a Bouc-Wen-type model on the
#: |z|max = 1 scale, when delta, beta and gamma are constant laws not bounded by the user:
#: yield within 10 um to 1 m of travel (Spencer's 1997 set: 21 um).
DELTA_RANGE: tuple[float, float] = (1.0, 1e5)
#: Range of q = gamma / delta with it (beta = (1 - q) delta): q = 0.5 is beta = gamma
#: (Spencer's), q = 10 is beta = -0.9 gamma (seen on real dampers).
Q_RANGE: tuple[float, float] = (0.0, 20.0)
#: A non-negative parameter whose box spans two decades or more is searched as a logarithm
#: (where the caller asks for it), from max(lower, LOG_FLOOR x upper) to its upper bound.
LOG_FLOOR = 1e-4



# ------------------------------------------------------------------------------ layout
@dataclasses.dataclass(frozen=True)
class Layout:
    """Host description of the laws: per parameter its law kind, number of coefficients,
    interpolation nodes (in the command unit) and the scale of a `"sat"` law (1 elsewhere;
    all 1 when empty); the node-value <-> coefficient maps."""

    kinds: tuple[str, ...]
    sizes: tuple[int, ...]
    nodes: tuple[np.ndarray, ...]
    scales: tuple[float, ...] = ()

    @property
    def law_scales(self) -> tuple[float, ...]:
        """The scale of every law (1 where it has none)."""
        return tuple(self.scales) or (1.0,) * len(self.kinds)

    @property
    def offsets(self) -> np.ndarray:
        return np.concatenate([[0], np.cumsum(self.sizes)]).astype(int)

    @property
    def n(self) -> int:
        return int(sum(self.sizes))

    def block(self, p: int) -> np.ndarray:
        o = self.offsets
        return np.arange(o[p], o[p + 1])

    @functools.cached_property
    def V(self) -> np.ndarray:
        """(V, V) block-diagonal: node values (log values for "exp") = V @ coefficients."""
        V = np.zeros((self.n, self.n))
        for p, nd in enumerate(self.nodes):
            b = self.block(p)
            V[np.ix_(b, b)] = vander(nd, self.sizes[p], self.kinds[p], self.law_scales[p])
        return V

    @functools.cached_property
    def Vinv(self) -> np.ndarray:
        return np.linalg.inv(self.V)

    def lawset(self, coef) -> LawSet:
        return LawSet(np.asarray(coef, float), self.kinds, self.sizes, self.law_scales)


# ------------------------------------------------------------------------------ coding
class Coding(eqx.Module):
    """How the unknowns map to the law coefficients and the lag rate (see the module notes).

    **Fields:** `nu0` (V,) node values where nothing else sets them; `Vinv` (V, V) node
    values -> coefficients; `eta0` the lag rate [1/s] when it is not fitted; static: `kinds`,
    `sizes` of the laws; `direct` the node indices a swarm position sets (its first dims),
    `direct_log` whether each is searched as a logarithm; `pair` the (beta, gamma) node
    indices set from `(log delta, q)` dims after them, or (); `derived` `(delta node index,
    delta parameter, beta parameter, gamma parameter, u0)` of the z-scale, or (); `free` the
    node indices the Levenberg-Marquardt polish varies; `lag` `"fit"`, `"fixed"` or `"none"`.
    """

    nu0: Float[Array, " V"]
    Vinv: Float[Array, "V V"]
    eta0: Float[Array, ""]
    kinds: tuple[str, ...] = eqx.field(static=True)
    sizes: tuple[int, ...] = eqx.field(static=True)
    direct: tuple[int, ...] = eqx.field(static=True)
    direct_log: tuple[bool, ...] = eqx.field(static=True)
    pair: tuple[int, ...] = eqx.field(static=True)
    derived: tuple = eqx.field(static=True)
    free: tuple[int, ...] = eqx.field(static=True)
    lag: str = eqx.field(static=True)
    ls: tuple[int, ...] = eqx.field(static=True, default=())
    scales: tuple[float, ...] = eqx.field(static=True, default=())

    @property
    def use_lag(self) -> bool:
        return self.lag != "none"

    @property
    def n_position(self) -> int:
        """Dimension of a swarm position."""
        return len(self.direct) + 2 * bool(self.pair) + (self.lag == "fit")

    @property
    def n_free(self) -> int:
        """Number of Levenberg-Marquardt variables."""
        return len(self.free) + (self.lag == "fit")

    def coefficients(self, nu):
        """Law coefficients (V,) of node values `nu` (derived entries completed)."""
        return self.Vinv @ self.complete(nu)

    def lawset(self, nu) -> LawSet:
        return LawSet(self.coefficients(nu), self.kinds, self.sizes, self.scales)

    def _law_value(self, coef, p: int, u: float):
        o = int(sum(self.sizes[:p]))
        scale = self.scales[p] if self.scales else 1.0
        return law_value(self.kinds[p], scale, [coef[o + m] for m in range(self.sizes[p])],
                         jnp.asarray(u, coef.dtype), jnp)

    def complete(self, nu):
        """`nu` with the z-scale's derived node value: delta(u0) = beta(u0) + gamma(u0)."""
        if not self.derived:
            return nu
        k, pd, pb, pg, u0 = self.derived
        coef = self.Vinv @ nu
        target = self._law_value(coef, pb, u0) + self._law_value(coef, pg, u0)
        if self.kinds[pd] == "exp":
            target = jnp.log(target)
        return nu.at[k].set(target)

    def from_position(self, position):
        """`(nu, eta)` of a swarm position (linear laws' entries left at `nu0`)."""
        D = len(self.direct)
        nu = self.nu0
        if D:
            v = position[:D]
            logs = np.asarray(self.direct_log, bool)
            if logs.any():
                v = jnp.where(logs, jnp.exp(v), v)
            nu = nu.at[jnp.asarray(self.direct, int)].set(v)
        k = D
        if self.pair:
            d, q = jnp.exp(position[k]), position[k + 1]
            nu = nu.at[self.pair[0]].set((1.0 - q) * d).at[self.pair[1]].set(q * d)
            k += 2
        eta = jnp.exp(position[k]) if self.lag == "fit" else self.eta0
        return self.complete(nu), eta

    def from_bounded(self, z):
        """`(nu, eta)` of the polish's variables `z`: a swarm position followed by the node
        values of the laws the swarm solves by least squares (see :meth:`bounded_of`)."""
        D = self.n_position
        nu, eta = self.from_position(z[:D])
        if self.ls:
            nu = nu.at[jnp.asarray(self.ls, int)].set(z[D:])
        return self.complete(nu), eta

    def bounded_of(self, nu, eta) -> np.ndarray:
        """The polish's variables of `(nu, eta)` (host): the swarm's coordinates (node values,
        their logarithms, `(log delta, q)`, `log eta`) and the least-squares node values."""
        nu = np.asarray(nu, float)
        z = [np.log(nu[k]) if lg else nu[k] for k, lg in zip(self.direct, self.direct_log)]
        if self.pair:
            b, g = nu[self.pair[0]], nu[self.pair[1]]
            d = b + g
            z += [math.log(d) if d > 0 else -np.inf, g / d if d != 0 else 0.0]
        if self.lag == "fit":
            z.append(math.log(float(eta)))
        z += [nu[k] for k in self.ls]
        return np.asarray(z, float)

    def from_free(self, phi):
        """`(nu, eta)` of the polish's variables: the free node values, then log eta."""
        nu = self.nu0.at[jnp.asarray(self.free, int)].set(phi[:len(self.free)]) if self.free \
            else self.nu0
        eta = jnp.exp(phi[len(self.free)]) if self.lag == "fit" else self.eta0
        return self.complete(nu), eta

    def free_of(self, nu, eta) -> np.ndarray:
        """The polish's variables of `(nu, eta)` (host)."""
        phi = np.asarray(nu, float)[list(self.free)]
        if self.lag == "fit":
            phi = np.append(phi, math.log(float(eta)))
        return phi


# ------------------------------------------------------------------------------ objectives
class JointObjective(AbstractObjective):
    """Total RMS [N] of one swarm position over every scored sample of every record; the laws
    of linear "poly" parameters come from exact linear least squares."""

    model: AbstractModel
    coding: Coding
    V_ls: Float[Array, "K K"]
    ls_idx: tuple[int, ...] = eqx.field(static=True)  # node indices solved by LS
    ls_cols: tuple[tuple[int, int], ...] = eqx.field(static=True)  # (design column, power)
    # per ls_cols entry: 0 for a power of u, else the scale s of a "sat" law's 1 - exp(-u/s)
    ls_scales: tuple[float, ...] = eqx.field(static=True)
    n_basis: int = eqx.field(static=True)  # leading ls_cols on parameter-free columns
    exp_lin: tuple[tuple[int, int], ...] = eqx.field(static=True)  # (design column, param)

    def _gram(self, rows: Rows, laws: LawSet, eta):
        u = rows.signal(eta, self.coding.use_lag)
        theta = laws(u)  # (R, P) or (R, T, P)
        F = jax.vmap(self.model.basis)(rows.x, rows.xdot)  # (R, T, p)
        Z, b = jax.vmap(self.model.hysteresis)(theta, rows.x, rows.xdot, rows.dt)
        p = F.shape[-1]
        uT = u if u.ndim == 2 else jnp.broadcast_to(u[:, None], rows.x.shape)

        def col(j):
            return F[..., j] if j < p else Z[..., j - p]

        def param(q):
            return theta[..., q] if theta.ndim == 3 else theta[:, q][:, None]

        for j, q in self.exp_lin:  # linear parameters with an "exp" law: known given nu
            b = b + param(q) * col(j)

        def basis(m, sc):
            return uT**m if sc == 0 else 1.0 - jnp.exp(-uT / sc)

        def cols(which, scales):
            c = [col(j) if m == 0 else col(j) * basis(m, sc)
                 for (j, m), sc in zip(which, scales)]
            return jnp.stack(c, axis=-1) if c else jnp.zeros(rows.x.shape + (0,), rows.x.dtype)

        # F-type columns (parameter-free with a data-only command) are computed once under the
        # swarm's vmap over particles; the Z-type ones per particle
        nb = self.n_basis
        gr = jax.vmap(gram_terms)(cols(self.ls_cols[:nb], self.ls_scales[:nb]),
                                  cols(self.ls_cols[nb:], self.ls_scales[nb:]), b, rows.force,
                                  rows.mask)
        return jax.tree.map(lambda a: jnp.sum(a, axis=0), gr)

    def solve(self, position, data):
        """`(nu, eta, total RMS [N])` of a swarm position: its node values with the linear
        laws' solved by least squares, the lag rate, and the RMS over every record."""
        nu, eta = self.coding.from_position(position)
        laws = self.coding.lawset(nu)
        gr = None
        for rows in data:
            g = self._gram(rows, laws, eta)
            gr = g if gr is None else jax.tree.map(jnp.add, gr, g)
        if not self.ls_cols:
            none = jnp.zeros((0,), gr.yy.dtype)
            return nu, eta, rms_from_gram(none, none.reshape(0, 0), none, gr.yy, gr.n)
        w = solve_normal(gr.FF, gr.ZF, gr.ZZ, gr.Fy, gr.Zy)
        rms = rms_from_gram(w, gr.G, gr.g, gr.yy, gr.n)
        nu = nu.at[jnp.asarray(self.ls_idx, int)].set(self.V_ls @ w)
        return nu, eta, rms

    def __call__(self, position, data):
        return self.solve(position, data)[2]

    def to_params(self, position, data):
        nu, eta, _ = self.solve(position, data)
        return jnp.concatenate([nu, jnp.reshape(eta, (1,))])


@eqx.filter_jit
def law_values(laws: LawSet, u) -> Array:
    """The parameters (..., P) of `laws` at commands `u` (jitted: compiled once per law
    layout and shape)."""
    return laws(u)


@eqx.filter_jit
def coded_law_values(coding: Coding, nu, u) -> Array:
    """The parameters (..., P) at commands `u` of the laws of node values `nu` (jitted)."""
    return coding.lawset(nu)(u)


@eqx.filter_jit
def from_bounded(coding: Coding, z) -> tuple[Array, Array]:
    """`(nu, eta)` of the polish's variables `z` (jitted :meth:`Coding.from_bounded`)."""
    return coding.from_bounded(z)


@eqx.filter_jit
def coefficients_of(coding: Coding, nu) -> Array:
    """Law coefficients (V,) of node values `nu`, derived entries completed (jitted)."""
    return coding.coefficients(coding.complete(nu))


@eqx.filter_jit
def objective_at(obj: JointObjective, position, data):
    """`(nu, eta, total RMS [N])` of one swarm position (jitted)."""
    return obj.solve(position, data)


def joint_residual_blocks(model: AbstractModel, coding: Coding, nu, eta,
                          data: tuple[Rows, ...]) -> tuple[tuple[Array, Array], ...]:
    """Masked residuals [N] of the laws of node values `nu` (and lag `eta`) on every record:
    per group of rows `(r (R, T), mask (R, T))`, zero on unscored samples (the blocks of
    `mrjax.bayes.sample`, one noise level per row)."""
    laws = coding.lawset(nu)
    out = []
    for rows in data:
        theta = laws(rows.signal(eta, coding.use_lag))
        pred = jax.vmap(model.force)(theta, rows.x, rows.xdot, rows.dt)
        out.append((jnp.where(rows.mask, pred - rows.force, 0.0), rows.mask))
    return tuple(out)


def joint_residuals(model: AbstractModel, coding: Coding, nu, eta, data: tuple[Rows, ...]):
    """Masked residuals [N] of the laws of node values `nu` (and lag `eta`) on every record,
    flattened (zero on unscored samples)."""
    return jnp.concatenate([r.ravel() for r, _ in
                            joint_residual_blocks(model, coding, nu, eta, data)])


def _rms(r, n):
    rms = jnp.sqrt(jnp.sum(r * r) / jnp.maximum(n, 1))
    return jnp.where(jnp.isfinite(rms), rms, jnp.inf)


def n_scored(data):
    return sum(jnp.sum(r.mask) for r in data)


@eqx.filter_jit
def total_rms_of(model, coding, nu, eta, data):
    """Total RMS [N] over every scored sample of every record (`inf` if not finite)."""
    return _rms(joint_residuals(model, coding, nu, eta, data), n_scored(data))


def build_objective(
    model: AbstractModel,
    layout: Layout,
    nu0: np.ndarray,
    *,
    eta0: float = 0.0,
    lag: str = "none",
    log_params: tuple[str, ...] = (),
    z_scale: bool = False,
    pair: bool = False,
) -> JointObjective:
    """The swarm objective (and coding) of laws `layout` of `model`.

    **Arguments:** `nu0` (V,) node values where nothing else sets them; `eta0` [1/s] the lag
    rate when `lag` is `"fixed"`; `lag` `"fit"`, `"fixed"` or `"none"`; `log_params` the
    searched parameters whose node values the swarm searches as logarithms; `z_scale` fix the
    redundant z-scale of a Bouc-Wen-type model by delta(u0) = beta(u0) + gamma(u0); `pair`
    search constant beta, gamma as `(log delta, q = gamma / delta)` (needs `z_scale`).
    """
    names, kinds = model.param_names, layout.kinds
    lin = list(model.linear_params)
    n_fixed = len(model.basis_params)
    ls_params = [p for p, n in enumerate(names) if n in lin and kinds[p] != "exp"]
    scales = layout.law_scales
    derived: tuple = ()
    if z_scale:
        sym = model.scale_symmetry
        pd, pb, pg = (names.index(k) for k in (sym.gauge, *sym.balance))
        derived = (int(layout.block(pd)[0]), pd, pb, pg, float(layout.nodes[pd][0]))
    pair_idx: tuple[int, ...] = ()
    if pair:
        pd, pb, pg = derived[1:4]
        pair_idx = (int(layout.block(pb)[0]), int(layout.block(pg)[0]))
    skip = set(pair_idx) | ({derived[0]} if derived else set())
    direct, direct_log = [], []
    for p, n in enumerate(names):
        if p in ls_params:
            continue
        for k in layout.block(p):
            if int(k) not in skip:
                direct.append(int(k))
                direct_log.append(n in log_params)
    ls = [(lin.index(names[p]), m, int(layout.block(p)[m]),
           scales[p] if kinds[p] == "sat" else 0.0) for p in ls_params
          for m in range(layout.sizes[p])]
    ls.sort(key=lambda e: e[0] >= n_fixed)  # parameter-free (basis) columns first
    ls_idx = tuple(e[2] for e in ls)
    V_ls = layout.V[np.ix_(ls_idx, ls_idx)] if ls_idx else np.zeros((0, 0))
    exp_lin = tuple((lin.index(names[p]), p) for p, n in enumerate(names)
                    if n in lin and kinds[p] == "exp")
    free = tuple(int(k) for k in range(layout.n) if not derived or k != derived[0])
    coding = Coding(*jax.device_put((np.asarray(nu0, float), np.asarray(layout.Vinv),
                                     np.asarray(eta0, float))),
                    kinds, layout.sizes, tuple(direct), tuple(direct_log), pair_idx, derived,
                    free, lag, ls_idx, scales)
    return JointObjective(model, coding, jax.device_put(np.asarray(V_ls, float)), ls_idx,
                          tuple((e[0], e[1]) for e in ls), tuple(e[3] for e in ls),
                          sum(e[0] < n_fixed for e in ls), exp_lin)


def node_box(model: AbstractModel, layout: Layout, lower: np.ndarray, upper: np.ndarray,
             free_shape: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The box (V,) of the laws' node values: each within its parameter's bounds `lower`,
    `upper` (P,) (their logarithms for `"exp"` laws); with `free_shape`, the delta, beta, gamma
    nodes of a Bouc-Wen-type model in the ranges `DELTA_RANGE` and `Q_RANGE` allow (the
    |z|max = 1 scale)."""
    lo_n, hi_n = np.zeros(layout.n), np.zeros(layout.n)
    sym = model.scale_symmetry
    shape = {} if sym is None or not free_shape else dict(zip(
        (sym.gauge, *sym.balance), (DELTA_RANGE, ((1.0 - Q_RANGE[1]) * DELTA_RANGE[1],
                                                 DELTA_RANGE[1]), (0.0, Q_RANGE[1] * DELTA_RANGE[1]))))
    for p, n in enumerate(model.param_names):
        b = layout.block(p)
        a, c = float(lower[p]), float(upper[p])
        if n in shape:
            a, c = shape[n]
        if layout.kinds[p] == "exp":
            a, c = math.log(max(a, 1e-300)), math.log(c)
        lo_n[b], hi_n[b] = a, c
    return lo_n, hi_n


def bounded_box(model: AbstractModel, layout: Layout, coding: Coding, lower: np.ndarray,
                upper: np.ndarray, lag_bounds: tuple[float, float] | None = None,
                free_shape: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The box of the polish's variables (:meth:`Coding.bounded_of`): every node value of a
    law within its parameter's bounds `lower`, `upper` (P,) (their logarithms for log-searched
    nodes and `"exp"` laws), the Bouc-Wen shape as `(log delta, q)` in `DELTA_RANGE` x
    `Q_RANGE` (or, with delta, beta, gamma not constant, beta and gamma node values in the box
    those ranges allow, unless `free_shape` is False), `log eta` in `lag_bounds` [1/s]."""
    lo_n, hi_n = node_box(model, layout, lower, upper, free_shape)
    lo, hi = [], []
    for k, lg in zip(coding.direct, coding.direct_log):
        a, c = lo_n[k], hi_n[k]
        lo.append(math.log(max(a, LOG_FLOOR * c)) if lg else a)
        hi.append(math.log(c) if lg else c)
    if coding.pair:
        lo += [math.log(DELTA_RANGE[0]), Q_RANGE[0]]
        hi += [math.log(DELTA_RANGE[1]), Q_RANGE[1]]
    if coding.lag == "fit":
        a, c = lag_bounds
        lo.append(math.log(a))
        hi.append(math.log(c))
    lo += [lo_n[k] for k in coding.ls]
    hi += [hi_n[k] for k in coding.ls]
    return np.asarray(lo, float), np.asarray(hi, float)
