"""The joint generalization: the law coefficients fitted on all conditions at once (swarm over
the laws of the nonlinear parameters, variable projection for the linear ones, then one
Levenberg-Marquardt polish of every coefficient)."""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..data import Batch
from ..models import AbstractModel, resolve_model
from ..objective import gram_terms, residuals, rms_from_gram, solve_normal
from ..pso import AbstractObjective, PSOParams, default_params, swarm
from ..refine import lm_solve, status_name
from ._laws import PACK_ROW, LawSet, fit_space, vander
from ._model import total_rms


@dataclasses.dataclass(frozen=True)
class Layout:
    """Host description of the unknowns: per parameter its law kind, number of coefficients
    and interpolation nodes; the node-value <-> coefficient maps."""

    kinds: tuple[str, ...]
    sizes: tuple[int, ...]
    nodes: tuple[np.ndarray, ...]

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
            V[np.ix_(b, b)] = vander(nd, self.sizes[p])
        return V

    @functools.cached_property
    def Vinv(self) -> np.ndarray:
        return np.linalg.inv(self.V)

    def lawset(self, coef) -> LawSet:
        return LawSet(jnp.asarray(coef, float), self.kinds, self.sizes)


def joint_data(model: AbstractModel, batch: Batch, mask: np.ndarray, cur: np.ndarray):
    """`(x, xdot, dt, force, mask, current)` of the joint objective, rows with one current each.

    A static model's force at a sample does not depend on the other samples, so its scored
    samples are packed into rows of `PACK_ROW` samples, each row holding one current (no padding
    of short conditions to the longest one: the same samples, the same total RMS, often several
    times fewer evaluations). Dynamic models keep one row per condition.
    """
    if model.dynamic:
        return (batch.x, batch.xdot, batch.dt, batch.force, jnp.asarray(mask), jnp.asarray(cur))
    arrays = [np.asarray(a, float) for a in (batch.x, batch.xdot, batch.dt, batch.force)]
    L = PACK_ROW
    pieces, currents = [], []
    for v in np.unique(cur):
        r = np.flatnonzero(cur == v)
        samples = [a[r][mask[r]] for a in arrays]
        for start in range(0, samples[0].size, L):
            pieces.append([a[start:start + L] for a in samples])
            currents.append(v)
    R = len(pieces)
    out = np.zeros((4, R, L))
    out[2] = 1.0  # sample interval of the padding (unused by static models)
    keep = np.zeros((R, L), bool)
    for u, piece in enumerate(pieces):
        n = piece[0].size
        for a in range(4):
            out[a, u, :n] = piece[a]
        keep[u, :n] = True
    return (*(jnp.asarray(a) for a in out), jnp.asarray(keep), jnp.asarray(currents, float))


# ------------------------------------------------------------------------------ joint
class JointObjective(AbstractObjective):
    """Total RMS [N] of one particle (node values of the searched laws) over all conditions;
    the laws of linear parameters come from exact linear least squares."""

    model: AbstractModel
    nu0: Float[Array, " V"]
    Vinv: Float[Array, "V V"]
    V_ls: Float[Array, "K K"]
    search_idx: tuple[int, ...] = eqx.field(static=True)
    ls_idx: tuple[int, ...] = eqx.field(static=True)  # coefficient indices solved by LS
    ls_cols: tuple[tuple[int, int], ...] = eqx.field(static=True)  # (design column, power)
    exp_lin: tuple[tuple[int, int], ...] = eqx.field(static=True)  # (design column, param)
    kinds: tuple[str, ...] = eqx.field(static=True)
    sizes: tuple[int, ...] = eqx.field(static=True)

    def _solve(self, position, data):
        x, xdot, dt, force, mask, cur = data
        nu = self.nu0.at[jnp.asarray(self.search_idx, int)].set(position) if self.search_idx \
            else self.nu0
        coef = self.Vinv @ nu
        theta = LawSet(coef, self.kinds, self.sizes)(cur)  # (C, P); LS entries ignored
        # F: parameter-free regressors (the same for every particle: under the swarm's vmap
        # everything built from F and the force alone is computed once); Z, b: per particle
        F = jax.vmap(self.model.basis)(x, xdot)  # (C, T, p)
        Z, b = jax.vmap(self.model.hysteresis)(theta, x, xdot, dt)  # (C, T, k), (C, T)
        p, k = F.shape[-1], Z.shape[-1]
        for j, q in self.exp_lin:  # linear parameters with an "exp" law: known given nu
            col = F[:, :, j] if j < p else Z[:, :, j - p]
            b = b + theta[:, q][:, None] * col
        gr = jax.vmap(gram_terms)(F, Z, b, force, mask)  # per condition: A = [F, Z], y = force - b
        rr, n = jnp.sum(gr.yy), jnp.sum(gr.n)
        K = len(self.ls_cols)
        if K == 0:
            return nu, rms_from_gram(jnp.zeros(0), jnp.zeros((0, 0)), jnp.zeros(0), rr, n)
        AA = jax.vmap(lambda q: q.G)(gr)  # (C, p+k, p+k)
        Ar = jax.vmap(lambda q: q.g)(gr)  # (C, p+k)
        # expand to the law coefficients: column (j, m) is A_j * i_c^m
        E = jnp.zeros((cur.shape[0], p + k, K), cur.dtype)
        for col, (j, m_) in enumerate(self.ls_cols):
            E = E.at[:, j, col].set(cur**m_)
        GA = jnp.einsum("cjk,cjl,clm->km", E, AA, E)
        g = jnp.einsum("cjk,cj->k", E, Ar)
        none = jnp.zeros((0,), GA.dtype)
        w = solve_normal(none.reshape(0, 0), none.reshape(K, 0), GA, none, g)
        rms = rms_from_gram(w, GA, g, rr, n)
        nu = nu.at[jnp.asarray(self.ls_idx, int)].set(self.V_ls @ w)
        return nu, rms

    def __call__(self, position, data):
        return self._solve(position, data)[1]

    def to_params(self, position, data):
        return self._solve(position, data)[0]


@eqx.filter_jit
def objective_at(obj, position, data):
    """Node values and total RMS [N] of one swarm position (jitted)."""
    return obj._solve(position, data)


@eqx.filter_jit
def polish_laws(model, kinds, sizes, Vinv, nu_start, scale, data, max_steps, tol):
    """Levenberg-Marquardt on every law coefficient, on the stacked residuals of all conditions
    (variables: node values `nu_start + scale * u`). Returns `(coef, total RMS [N], steps,
    status code)` (see `mrjax.refine.lm_solve`)."""
    x, xdot, dt, force, mask, cur = data

    def coef_of(u):
        return Vinv @ (nu_start + scale * u)

    def fn(u, _):
        th = LawSet(coef_of(u), kinds, sizes)(cur)
        r = jax.vmap(lambda t, a, v, h, f, k: residuals(model, t, a, v, h, f, k))(
            th, x, xdot, dt, force, mask)
        return r.ravel()

    sol = lm_solve(fn, jnp.zeros_like(nu_start), max_steps=max_steps, tol=tol)
    coef = coef_of(sol.value)
    return coef, total_rms(model, LawSet(coef, kinds, sizes), data), sol.steps, sol.status


# ------------------------------------------------------------------------------ the joint stage
@dataclasses.dataclass(frozen=True)
class JointStart:
    """The two-step solution the joint fit starts from and is never worse than.

    `theta` (C, P) per-condition parameters (z-scale normalised); `current` (C,) their
    currents [A]; `levels` (U,) the distinct currents [A]; `layout`; `coef` two-step
    coefficients; `rms` [N] their total RMS; `data` the joint objective's rows (see
    :func:`joint_data`); `model_eval` the model with the
    sub-steps the two-step RMS was scored with; `exp_cols` (P,) which laws are `"exp"`.
    """

    theta: np.ndarray
    current: np.ndarray
    levels: np.ndarray
    layout: Layout
    coef: np.ndarray
    rms: float
    data: tuple
    model_eval: AbstractModel
    exp_cols: np.ndarray


def _search_box(model: AbstractModel, start: JointStart):
    """Node values of the two-step laws and the swarm's box around them: +-(3 x the scatter of
    the per-condition values about the law + 25 % of the value), non-negative parameters kept
    non-negative. Returns `(nu0, half, box_lo, box_hi)`, each (V,)."""
    layout, kinds = start.layout, start.layout.kinds
    nu0 = layout.V @ start.coef
    law_rows = np.asarray(layout.lawset(start.coef)(jnp.asarray(start.current)))
    dev = np.sqrt(np.mean((fit_space(start.theta, start.exp_cols)
                           - fit_space(law_rows, start.exp_cols)) ** 2, axis=0))
    lo_m, hi_m = model.bounds
    half = np.zeros(layout.n)
    box_lo, box_hi = np.zeros(layout.n), np.zeros(layout.n)
    for p in range(model.n_params):
        b = layout.block(p)
        tiny = 1e-6 * (hi_m[p] - lo_m[p]) + 1e-9
        h = 3.0 * dev[p] + 0.25 * np.abs(nu0[b]) + tiny
        half[b] = h
        box_lo[b], box_hi[b] = nu0[b] - h, nu0[b] + h
        if kinds[p] == "poly" and lo_m[p] >= 0:
            box_lo[b] = np.where(nu0[b] >= 0, np.maximum(box_lo[b], 0.0), box_lo[b])
    return nu0, half, box_lo, box_hi


def _objective(model: AbstractModel, start: JointStart, batch: Batch, nu0, box_lo, box_hi):
    """The swarm's objective over the node values of the searched laws (the laws of linear
    "poly" parameters are solved exactly), and its box `(s_lo, s_hi)`."""
    layout, kinds, names = start.layout, start.layout.kinds, model.param_names
    lin = list(model.linear_params)
    ls_params = [p for p, n in enumerate(names) if n in lin and kinds[p] == "poly"]
    search_params = [p for p in range(len(names)) if p not in ls_params]
    search_idx = tuple(int(k) for p in search_params for k in layout.block(p))
    ls_idx = tuple(int(k) for p in ls_params for k in layout.block(p))
    ls_cols = tuple((lin.index(names[p]), m_) for p in ls_params for m_ in range(layout.sizes[p]))
    exp_lin = tuple((lin.index(names[p]), p) for p in search_params if names[p] in lin)
    V_ls = layout.V[np.ix_(ls_idx, ls_idx)] if ls_idx else np.zeros((0, 0))
    # the swarm's integration (see mrjax.models.resolve_model)
    model_sw = model
    if model.dynamic and model.substeps is None:
        corners = [nu0]
        for side in (box_lo, box_hi):
            corners.append(np.where(np.isin(np.arange(layout.n), search_idx), side, nu0))
        rows = np.concatenate([start.theta] + [np.asarray(layout.lawset(layout.Vinv @ c)(
            jnp.asarray(start.levels))) for c in corners])
        model_sw = resolve_model(model, rows, batch.xdot, batch.dt, batch.mask, swarm=True)
    obj = JointObjective(model_sw, jnp.asarray(nu0), jnp.asarray(layout.Vinv), jnp.asarray(V_ls),
                         search_idx, ls_idx, ls_cols, exp_lin, kinds, layout.sizes)
    idx = list(search_idx)
    return obj, box_lo[idx], box_hi[idx]


def joint_laws(
    model: AbstractModel,
    batch: Batch,
    start: JointStart,
    *,
    key: Any,
    n_particles: int,
    max_generations: int,
    pso_params: PSOParams | None,
    polish: bool,
    polish_steps: int,
    info: dict[str, Any],
    timings: dict[str, float],
) -> tuple[np.ndarray, float]:
    """The joint stage: swarm over the node values of the searched laws, then (optionally)
    Levenberg-Marquardt on every coefficient from the better of the swarm's best and the
    two-step laws. Never worse than `start`. Fills `info` and `timings` [s].

    **Returns:** `(coefficients (V,), total RMS [N])`.
    """
    t1 = time.perf_counter()
    layout, data = start.layout, start.data
    nu0, half, box_lo, box_hi = _search_box(model, start)
    obj, s_lo, s_hi = _objective(model, start, batch, nu0, box_lo, box_hi)
    if s_lo.size:
        sw = swarm(obj, s_lo, s_hi, jax.tree.map(lambda a: a[None], data), key=key,
                   params=pso_params or default_params("separable"), n_particles=n_particles,
                   max_generations=max_generations)
        pos = sw.position[0]
        info.update(swarm_generations=int(sw.generations[0]),
                    swarm_stopped_by_criterion=bool(sw.stopped_by_criterion[0]))
    else:
        pos = jnp.zeros((0,))
        info.update(swarm_generations=0, swarm_stopped_by_criterion=False)
    nu_sw = np.asarray(objective_at(obj, pos, data)[0])
    coef_sw = layout.Vinv @ nu_sw
    rms_sw = float(total_rms(start.model_eval, layout.lawset(coef_sw), data))
    info["swarm_total_rms_N"] = rms_sw
    timings["swarm"] = time.perf_counter() - t1
    if np.isfinite(rms_sw) and rms_sw < start.rms:
        nu_start, coef_best, rms_best, info["polish_start"] = nu_sw, coef_sw, rms_sw, "swarm"
    else:
        nu_start, coef_best, rms_best, info["polish_start"] = nu0, start.coef, start.rms, "two-step"
    info.update(polish_steps=0, polish_status="none")
    if polish:
        t2 = time.perf_counter()
        coef_best, rms_best = _polish(model, batch, start, nu_start, half, coef_best, rms_best,
                                      polish_steps, info)
        timings["polish"] = time.perf_counter() - t2
    # the reported total RMS uses sub-steps resolved from the final laws
    if model.dynamic and model.substeps is None:
        rms_best = float(total_rms(_resolved(model, batch, start, coef_best),
                                   layout.lawset(coef_best), data))
    if not rms_best <= start.rms:  # never worse than the two-step laws (also catches NaN)
        coef_best, rms_best = start.coef, start.rms
        info["fell_back_to_two_step"] = True
    return coef_best, rms_best


def _resolved(model: AbstractModel, batch: Batch, start: JointStart, coef) -> AbstractModel:
    """The model with sub-steps resolved from the per-condition fits and the laws `coef`."""
    rows = np.asarray(start.layout.lawset(coef)(jnp.asarray(start.levels)))
    return resolve_model(model, np.concatenate([start.theta, rows]), batch.xdot, batch.dt,
                         batch.mask)


def _polish(model, batch, start, nu_start, half, coef_best, rms_best, polish_steps, info):
    """Levenberg-Marquardt on every coefficient from `nu_start`; kept only if not worse."""
    layout = start.layout
    model_lm = model
    if model.dynamic and model.substeps is None:
        model_lm = _resolved(model, batch, start, coef_best)
    if model_lm.substeps != start.model_eval.substeps:
        rms_best = float(total_rms(model_lm, layout.lawset(coef_best), start.data))
    coef_lm, rms_lm, steps, code = polish_laws(
        model_lm, layout.kinds, layout.sizes, jnp.asarray(layout.Vinv), jnp.asarray(nu_start),
        jnp.asarray(half / 3.0), start.data, int(polish_steps), 1e-8)
    coef_lm, rms_lm = np.asarray(coef_lm), float(rms_lm)
    info.update(polish_steps=int(steps), polish_status=status_name(code))
    if np.all(np.isfinite(coef_lm)) and math.isfinite(rms_lm) and rms_lm <= rms_best:
        return coef_lm, rms_lm
    info["polish_status"] = "kept_start"
    return coef_best, rms_best
