"""The start of the one sampler (`mrjax.bayes.sample`): one unit's log-density, and where its
chains start with which mass matrix.

- :class:`Target` and :func:`log_density`: the log posterior density of one unit in the
    sampler's position `z = [u, log s, v]` (see `mrjax.bayes._sampler`);
- :func:`start`: the position and inverse mass matrix from the polished optimum and the
    Gauss-Newton covariance of the residuals there, one unknown held per direction the data
    leave undetermined (:func:`undetermined`), the bounded map's softness;
- :func:`find_mode` and :func:`laplace`: a damped Newton search from there to the posterior's
    mode, and the inverse Hessian there as the mass matrix the warmup starts from.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._noise import block_loglik, linear_marginal, log1m_tanh2, noise_start
from ._priors import FLAT, box_slope, from_box, log_bounds, log_jacobian, log_prior, to_box

#: Variance (in the bounded map's `u`) given to an unknown whose Jacobian variance is undefined
#: (not identifiable, or at a bound: its softness is then its box width, and a posterior that
#: fills the box or piles against a bound spans a few units of `u`), and the most any
#: unknown's starting variance may be.
FALLBACK_U_VAR = 1.0
MAX_U_VAR = 4.0
#: The bounded map's softness `d` (`mrjax.bayes.to_box`) is this fraction of an unknown's
#: starting standard deviation (the Gauss-Newton one, widened for AR(1) noise), at most the
#: box width (the box width where it is undefined): the map is linear over the posterior's
#: bulk unless that reaches within a few `d` of a bound. A posterior ridge that reaches into
#: the map's curved zone is bent there, which a dense mass matrix cannot follow; a smaller
#: softness does not straighten it. The value is the calibration's (`benchmarks/posterior.md`).
SOFTNESS = 0.5
#: A direction of the unknowns whose Gauss-Newton standard deviation exceeds this many box
#: widths is undetermined by the data: one unknown along it is held (see `undetermined`).
UNDETERMINED = 1.0
#: An unknown with a lower bound >= 0 that lies at least this many standard deviations above
#: it, at the start (the optimum, its Gauss-Newton sd) or at the mode (its Laplace sd: see
#: :func:`to_log`), runs in log coordinates (`mrjax.bayes.to_box`): the damper models'
#: scale parameters trade off as products, a curved ridge in linear coordinates and a
#: straighter one in log coordinates (`benchmarks/posterior_geometry.py`). An unknown near
#: its lower bound keeps the linear map, which near the bound is already exponential.
LOG_AWAY = 10.0
#: A linear unknown is integrated out of the log-density (:func:`collapsible`) where the
#: posterior's mode lies at least this many of its Laplace standard deviations inside its box
#: in every unit, and where its
#: regressor at a second point differs by at most `AFFINE_TOL` of its largest entry.
#: Integrating out a force offset removes the funnel it makes with an AR(1) coefficient rho
#: (the innovations see the offset only through (1 - rho) f0).
COLLAPSE_MARGIN = 8.0
AFFINE_TOL = 1e-9
#: A `gauge` unknown is held for an undetermined direction where its component (in box
#: widths) is at least this share of the largest one.
GAUGE_SHARE = 0.1


class Target(eqx.Module):
    """What the compiled log-density needs that is the same for every unit (static): the
    residual function, the unknowns the sampler moves (`free`) and those integrated out
    (`linear`, see :func:`mrjax.bayes.linear_marginal`), records per block, the noise model,
    and whether the residuals are differentiated in forward mode."""

    residual: Callable
    free: tuple[int, ...] = eqx.field(static=True)
    rows: tuple[int, ...] = eqx.field(static=True)  # records per block
    noise: str = eqx.field(static=True)
    forward: bool = eqx.field(static=True, default=False)
    linear: tuple[int, ...] = eqx.field(static=True, default=())


class Unit(NamedTuple):
    """One unit's arrays for the compiled log-density (a pytree; a leading unit axis where
    batched): its `data`; the moved unknowns' box `lo`, `hi` (SI units), the bounded map's
    softness `soft` and `log` (bool) which of them run in log coordinates
    (`mrjax.bayes.to_box`); `theta` (K,) the optimum, which gives the held unknowns and the
    reference of the linear ones; `regressors`, per residual block (R_b, T_b, L) the
    derivative of the residuals in the linear unknowns integrated out (constant) and `grams`
    their :func:`mrjax.bayes.lag_grams` (None: computed where used); `masks`,
    per residual block, its scored samples (R_b, T_b) (they do not depend on the unknowns:
    read once, at the start)."""

    data: Any
    lo: Any
    hi: Any
    soft: Any
    log: Any
    theta: Any
    masks: tuple
    regressors: tuple = ()
    grams: tuple | None = None


def _values(residual: Callable, theta_full, idx: np.ndarray, tf, data) -> tuple:
    """The residual blocks' values at `theta_full` with its entries `idx` set to `tf`."""
    return tuple(r for r, _ in residual(theta_full.at[idx].set(tf), data))


@eqx.filter_jit
def _jacobian_pass(residual: Callable, theta_full, free: tuple[int, ...], tf, data):
    """`(J, values)` of the residual blocks in the `free` unknowns `tf` (one forward-mode pass,
    one tangent per free unknown). Jitted: a sampler's program differentiates the log-density
    at a dozen places (the mode search, the warmup, the draws, ...), and each would trace the
    integration's forward mode again; a jitted function is traced once per shape and
    reused."""
    idx = np.asarray(free, int)
    # the values from the same forward pass as the Jacobian: one traced call, returned as
    # output and aux (two calls would trace two scans, and XLA keeps both)
    J, vals = jax.jacfwd(lambda t: (_values(residual, theta_full, idx, t, data),) * 2,
                         has_aux=True)(tf)
    return J, vals


def forward_values(residual: Callable, theta_full, free, th_free, data):
    """The residual blocks' values at `theta_full` with its `free` entries set to `th_free`,
    differentiated in forward mode in `th_free`: their Jacobian (one pass with one tangent per
    free unknown, none for the held ones) is what reverse mode transposes. Through a
    sequential integration this is cheaper than a reverse pass, which stores and replays every
    step (`benchmarks/posterior.md`)."""
    free = tuple(int(j) for j in np.asarray(free, int))

    @jax.custom_jvp
    def f(tf):
        return _values(residual, theta_full, np.asarray(free, int), tf, data)

    @f.defjvp
    def f_jvp(primals, tangents):
        (tf,), (dtf,) = primals, tangents
        J, vals = _jacobian_pass(residual, theta_full, free, tf, data)
        return vals, tuple(j @ dtf for j in J)

    return f(th_free)


def _likelihood(target: Target, prior, unit: Unit, z):
    """Log prior + log-Jacobian + log-likelihood of one unit at `z`, and the blocks' noise
    (log sigma, v) and residuals (the linear unknowns at their reference)."""
    kind, a, b = prior
    Kf, R = len(target.free), sum(target.rows)
    free = np.asarray(target.free, int)
    u, log_sigma = z[:Kf], z[Kf:Kf + R]
    v = z[Kf + R] if target.noise == "ar1" else None
    if v is not None:  # the position holds the innovations' level: the marginal one from it
        log_sigma = log_sigma - 0.5 * log1m_tanh2(v)
    th_free = to_box(u, unit.lo, unit.hi, unit.soft, unit.log)
    if target.forward:
        vals = forward_values(target.residual, unit.theta, free, th_free, unit.data)
    else:
        vals = _values(target.residual, unit.theta, free, th_free, unit.data)
    blocks = tuple(zip(vals, unit.masks))
    lp = log_prior(th_free, kind[free], a[free], b[free]) + log_jacobian(
        u, unit.lo, unit.hi, unit.soft, unit.log)
    if v is not None:
        lp = lp + log1m_tanh2(v)  # uniform prior on rho = tanh v in (-1, 1)
    return lp, blocks, log_sigma, v


def log_density(target: Target, prior, unit: Unit, z):
    """Log posterior density (up to a constant) of one unit at `z`; NaN or inf -> -inf. The
    linear unknowns of `target.linear` are integrated out (:func:`mrjax.bayes.linear_marginal`)."""
    lp, blocks, log_sigma, v = _likelihood(target, prior, unit, z)
    if target.linear:
        lp = lp + linear_marginal(blocks, unit.regressors, log_sigma, v, unit.grams)[0]
    else:
        off = 0
        for (r, m), n in zip(blocks, target.rows):
            lp = lp + block_loglik(r, m, log_sigma[off:off + n], v)
            off += n
    return jnp.where(jnp.isfinite(lp), lp, -jnp.inf)


def linear_draw(target: Target, prior, unit: Unit, z, key):
    """The linear unknowns integrated out of the log-density, drawn from their Gaussian
    conditional at `z` (SI units, (L,)): with `z` a posterior draw, a draw of the joint
    posterior. Non-finite where the residuals are."""
    _, blocks, log_sigma, v = _likelihood(target, prior, unit, z)
    _, delta, C, d = linear_marginal(blocks, unit.regressors, log_sigma, v, unit.grams)
    eps = jax.random.normal(key, delta.shape, delta.dtype)
    delta = delta + d * jax.scipy.linalg.solve_triangular(C, eps, lower=True, trans="T")
    return unit.theta[np.asarray(target.linear, int)] + delta


#: Damped Newton steps of the mode search that moves the start onto the posterior's mode
#: (`find_mode`), and its stop: the Newton decrement g^T H^-1 g / 2 at the current point below
#: this many log-density units (the last Newton step, a few hundredths of a standard deviation,
#: is then taken without a further evaluation).
MODE_STEPS = 25
MODE_TOL = 1e-3
#: Step of the central differences of the gradient that give the Hessian at the mode, in the
#: whitened coordinates of the Gauss-Newton start (where the posterior spans O(1)).
HESS_STEP = 1e-4
#: Gradients evaluated side by side for that Hessian (2 per unknown in all): a joint-laws unit
#: holds every record, and its reverse-mode gradient the whole forward pass.
HESS_BATCH = 8
#: Eigenvalues of the mode's covariance, in those coordinates, are kept within these bounds
#: (wide of the narrowest and widest directions seen on real records).
MODE_EIG = (1e-6, 1e3)


#: Probes of :func:`gradient_error`: standard normal points of each unit's starting metric.
GRADIENT_PROBES = 8
#: Largest whitened gradient error [log-density units per unit length] of an approximate
#: derivative that the sampler keeps (above it, the exact one): over a trajectory of a few
#: units it moves the energy by a few tenths at most.
GRADIENT_TOL = 0.05
#: Step of the central differences :func:`gradient_error` checks a gradient against, in the
#: whitened coordinates (a log-density of 10^5 loses about 2e-6 to rounding, a cubic term of
#: O(1) 2e-11 to truncation).
FD_STEP = 1e-5


@eqx.filter_jit
def gradient_error(target, prior, units, z0, L):
    """Largest difference |g - g_fd| of the log-density's gradient under `target` (an
    approximate derivative, e.g. the L-stable scheme's implicit tangent) and central differences
    of its values (step `FD_STEP`, the derivative of the computed log-density, which an exact
    tangent gives), in the whitened coordinates `w` (`z = z0 + L w`), over `GRADIENT_PROBES`
    standard normal points of every unit (non-finite ones skipped), per unit (U,). Values only: an exact
    tangent's gradient would be a second compiled gradient. NUTS stays exact with an approximate
    gradient (its leapfrog map is still reversible and volume-preserving), but its energy error
    no longer vanishes with the step: where the gradient is off, the step-size adaptation
    shrinks the step towards 0 and every tree runs to its cap."""
    W = jax.random.normal(jax.random.key(0), (GRADIENT_PROBES, z0.shape[-1]), z0.dtype)

    def one(unit, z, m):
        ld = lambda w: log_density(target, prior, unit, z + m @ w)
        D = z.shape[0]
        steps = FD_STEP * jnp.eye(D, dtype=z.dtype)

        def probe(w):
            f = jax.vmap(ld)(jnp.concatenate([w + steps, w - steps]))
            return jax.grad(ld)(w) - (f[:D] - f[D:]) / (2.0 * FD_STEP)

        d = jnp.linalg.norm(jax.lax.map(probe, W), axis=-1)
        return jnp.max(jnp.where(jnp.isfinite(d), d, 0.0))

    return jax.lax.map(lambda a: one(*a), (units, z0, L))


@eqx.filter_jit
def find_mode(target, prior, units, z0, L):
    """Each unit's posterior mode and the Hessian of the log-density there, in the whitened
    coordinates `w` of the start (`z = z0 + L w`), by damped Newton from `w = 0`: the Hessian by
    central differences of the gradient (`HESS_STEP`), |eigenvalues| floored, a Levenberg
    damping raised where a step does not climb. Each step evaluates the log-density and its
    gradient at the trial point and its 2 D neighbours in one batch: one gradient in the
    compiled program, not three. Returns `(w, logdensity, logdensity at 0, negative Hessian)`
    per unit (the first log-density and the Hessian at the point the last Newton step starts
    from)."""

    def one(unit, z, m):
        ld = lambda w: log_density(target, prior, unit, z + m @ w)
        vg = jax.value_and_grad(ld)
        D = z.shape[0]
        eye = jnp.eye(D, dtype=z.dtype)

        def evaluate(w):  # log-density, gradient and negative Hessian at w
            pts = jnp.concatenate([w[None], w + HESS_STEP * eye, w - HESS_STEP * eye])
            f, g = jax.lax.map(vg, pts, batch_size=HESS_BATCH)  # bounded memory on big units
            H = -(g[1:D + 1] - g[D + 1:]) / (2.0 * HESS_STEP)
            H = 0.5 * (H + H.T)
            return f[0], jnp.where(jnp.isfinite(g[0]), g[0], 0.0), jnp.where(
                jnp.isfinite(H), H, 0.0)

        def cond(c):
            k, dec = c[0], c[-1]
            return (k <= MODE_STEPS) & (dec > MODE_TOL)

        def body(c):
            k, w, f, g, H, f0, lam, w_try, _ = c
            f_t, g_t, H_t = evaluate(w_try)
            up = jnp.isfinite(f_t) & ((f_t >= f) | (k == 0))  # k = 0: the start itself
            w, f = jnp.where(up, w_try, w), jnp.where(up, f_t, f)
            g, H = jnp.where(up, g_t, g), jnp.where(up, H_t, H)
            f0 = jnp.where(k == 0, f_t, f0)
            lam = jnp.where(k == 0, lam, jnp.where(up, lam / 4.0, 4.0 * lam + 1e-3))
            e, V = jnp.linalg.eigh(H)
            e = jnp.maximum(jnp.abs(e), MODE_EIG[0])
            gv = V.T @ g
            dec = jnp.where(jnp.isfinite(f), 0.5 * jnp.sum(gv * gv / e), 0.0)
            return (k + 1, w, f, g, H, f0, lam, w + V @ (gv / (e + lam)), dec)

        w0 = jnp.zeros_like(z)
        neg_inf = jnp.asarray(-jnp.inf, z.dtype)
        init = (jnp.zeros((), jnp.int32), w0, neg_inf, w0, jnp.zeros((D, D), z.dtype), neg_inf,
                jnp.asarray(1e-3, z.dtype), w0, jnp.asarray(jnp.inf, z.dtype))
        _, w, f, _, H, f0, _, w_next, dec = jax.lax.while_loop(cond, body, init)
        return jnp.where(dec <= MODE_TOL, w_next, w), f, f0, H

    return jax.vmap(one)(units, z0, L)


def laplace(w, f, f0, H, z0, L):
    """Host: the start moved onto the mode and its covariance from the Hessian there (in the
    whitened coordinates, eigenvalues within `MODE_EIG`); a unit whose search did not climb
    or whose Hessian is not finite keeps the Gauss-Newton start. Returns `(z0, L)`."""
    w, f, f0, H, z0, L = (np.asarray(a, float) for a in (w, f, f0, H, z0, L))
    z0, L = z0.copy(), L.copy()
    for i in range(z0.shape[0]):
        if not (np.isfinite(f[i]) and f[i] >= f0[i] and np.all(np.isfinite(H[i]))
                and np.all(np.isfinite(w[i]))):
            continue
        e, V = np.linalg.eigh(0.5 * (H[i] + H[i].T))
        var = np.clip(1.0 / np.maximum(e, 1.0 / MODE_EIG[1]), *MODE_EIG)
        z0[i] = z0[i] + L[i] @ w[i]
        L[i] = L[i] @ np.linalg.cholesky((V * var) @ V.T)
    return z0, L


@eqx.filter_jit
def linearize(residual, free: tuple[int, ...], theta0, data):
    """Every unit's residual blocks, masks and their Jacobian in the free unknowns at the
    optimum (forward mode), one compiled program per residual function."""
    idx = np.asarray(free, int)

    def one(th, d):
        J, vals = _jacobian_pass(residual, th, tuple(free), th[idx], d)
        return vals, tuple(m for _, m in residual(th, d)), J

    return jax.vmap(one)(theta0, data)


def undetermined(H: np.ndarray, width: np.ndarray, names: Sequence[str],
                  gauge: Sequence[str]) -> list[int]:
    """Host: which unknowns to hold at the optimum, so that the data determine the rest.

    `H` (K, K) the Gauss-Newton precision of the unknowns [1 / unit^2], `width` (K,) their box
    widths. A direction whose posterior standard deviation (in box widths) exceeds
    `UNDETERMINED` x the box is one the data leave to the prior: a symmetry of the model
    (modified Bouc-Wen's z scale: alpha z, delta, beta, gamma scale together and the force
    does not change) or an unknown without effect on these records. NUTS on such a ridge,
    curved through the box, builds trees of hundreds of steps; holding one unknown per
    direction (a `gauge` name where it takes part, else the largest component) removes it.
    Returns the indices held, in order."""
    held: list[int] = []
    live = [k for k in range(H.shape[0]) if width[k] > 0]
    while live:
        Hs = H[np.ix_(live, live)] * np.outer(width[live], width[live])
        if not np.all(np.isfinite(Hs)):
            break
        w, V = np.linalg.eigh(0.5 * (Hs + Hs.T))
        if w[0] * UNDETERMINED ** 2 >= 1.0:
            break
        comp = np.abs(V[:, 0])
        big = comp >= GAUGE_SHARE * comp.max()
        pref = [i for i in np.flatnonzero(big) if names[live[i]] in gauge]
        pick = live[pref[0] if pref else int(np.argmax(comp))]
        held.append(pick)
        live.remove(pick)
    return held


class Start(NamedTuple):
    """Host arrays of :func:`start`, per unit (U leading) and free unknown (Kf): `z0` (U, D)
    and `imm` (U, D, D) the position and inverse mass matrix; the bounded map's `soft`,
    box `lo`, `hi` and `log` coordinates; `held` (U, Kf) the unknowns held; `sd` (U, Kf) the
    starting standard deviations [SI] (NaN where undefined); `jacobians`, per residual block,
    (U, R_b, T_b, Kf) the residuals' derivatives at the optimum, and `masks` (U, R_b, T_b)
    its scored samples."""

    z0: np.ndarray
    imm: np.ndarray
    soft: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    held: np.ndarray
    log: np.ndarray
    sd: np.ndarray
    jacobians: tuple
    masks: tuple


def start(residual, theta0, lo, hi, data, free, noise, names=(), gauge=()) -> Start:
    """Host: the sampler's start (:class:`Start`) from the optimum and the Gauss-Newton
    covariance of the residuals there (the likelihood's own data: records or views, every
    block): `lo`, `hi` (U, Kf) the free unknowns' boxes. An unknown with a lower bound >= 0
    and an optimum at least `LOG_AWAY` starting standard deviations above it runs in log
    coordinates (`mrjax.bayes.to_box`)."""
    vals, masks, jacs = jax.device_get(linearize(residual, tuple(free), jnp.asarray(theta0),
                                                  data))
    idx = np.asarray(free, int)
    Kf = idx.size
    lo, hi = np.array(lo, float), np.array(hi, float)
    z0, imm, soft, held_all, logs, sds = [], [], [], [], [], []
    for i in range(theta0.shape[0]):
        blocks = [(np.asarray(r[i]), np.asarray(m[i])) for r, m in zip(vals, masks)]
        sig, rho, n = noise_start(blocks)
        n = np.maximum(n, 1).astype(float)
        # AR(1) residuals carry (1 - rho) / (1 + rho) of the information of independent ones
        infl = min((1.0 + rho) / (1.0 - rho), 1e4) if noise == "ar1" and rho > 0 else 1.0
        H, off = np.zeros((Kf, Kf)), 0
        for (r, m), J in zip(blocks, jacs):
            Jb = np.where((m & np.isfinite(r))[..., None], np.asarray(J[i], float), 0.0)
            w = 1.0 / sig[off:off + r.shape[0]] ** 2
            H += np.einsum("rtk,r,rtl->kl", Jb, w, Jb)
            off += r.shape[0]
        H /= infl
        held = undetermined(H, hi[i] - lo[i], [names[k] for k in idx] if names else [],
                             gauge)
        held_mask = np.zeros(Kf, bool)
        held_mask[held] = True
        lo[i, held_mask] = hi[i, held_mask] = np.clip(theta0[i, idx], lo[i], hi[i])[held_mask]
        keep = np.flatnonzero(~held_mask & (hi[i] > lo[i]))
        cov = np.full((Kf, Kf), np.nan)
        Hk = H[np.ix_(keep, keep)]
        if keep.size and np.all(np.isfinite(Hk)):
            cov[np.ix_(keep, keep)] = np.linalg.pinv(Hk, rcond=1e-12, hermitian=True)
        with np.errstate(invalid="ignore"):
            sd = np.sqrt(np.diag(cov))
        th_i = np.clip(theta0[i, idx], lo[i], hi[i])
        lg = log_rule(lo[i], hi[i], th_i, sd)
        d = softness(cov, lo[i], hi[i], lg, th_i)
        u0 = from_box(th_i, lo[i], hi[i], d, lg)
        cu = u_cov(cov, box_slope(u0, lo[i], hi[i], d, lg))
        point = hi[i] <= lo[i]  # held: `u` a nuisance of logistic density (variance pi^2 / 3)
        cu[point, :] = cu[:, point] = 0.0
        cu[point, point] = np.pi ** 2 / 3.0
        var = [np.minimum(1.0 / (2.0 * n), MAX_U_VAR)]  # log sigma: 1 / (2 n) each
        zi = [u0, np.log(sig)]
        if noise == "ar1":  # the innovations' level sigma sqrt(1 - rho^2), and atanh(rho)
            zi[1] = zi[1] + 0.5 * np.log1p(-rho * rho)
            zi.append(np.array([np.arctanh(rho)]))
            var.append(np.array([min(1.0 / (n.sum() * (1.0 - rho * rho)), MAX_U_VAR)]))
        dv = np.concatenate(var)
        M = np.zeros((Kf + dv.size, Kf + dv.size))
        M[:Kf, :Kf] = clip_cov(cu)
        M[Kf:, Kf:] = np.diag(dv)
        z0.append(np.concatenate(zi))
        imm.append(M)
        soft.append(d)
        held_all.append(held_mask)
        logs.append(lg)
        sds.append(sd)
    return Start(np.stack(z0), np.stack(imm), np.stack(soft), lo, hi, np.stack(held_all),
                 np.stack(logs), np.stack(sds), tuple(jacs), tuple(masks))


def collapsible(residual, theta0, data, free, st: Start, kind, candidates, centre,
                sd) -> list[int]:
    """Host: which of the `candidates` (indices of unknowns the residuals are declared affine
    in, with a regressor no unknown changes: a model's `basis_params`) the log-density
    integrates out (:func:`mrjax.bayes.linear_marginal`), as positions in `free`. One is
    where, in every unit, it is free and not held, its prior flat (`kind` FLAT), the
    posterior's mode `centre` (U, Kf) at least `COLLAPSE_MARGIN` of its standard deviations
    `sd` (U, Kf) inside its box (the Gaussian integral then leaves out a negligible mass
    beyond it), and its regressor is the same at a second point (the optimum `theta0` moved
    half a starting standard deviation in every free unknown: the declaration checked)."""
    pos = [list(free).index(j) for j in candidates if j in free and kind[j] == FLAT]
    th = np.clip(np.asarray(theta0, float)[:, np.asarray(free, int)], st.lo, st.hi)
    ok = []
    for k in pos:
        s, c = sd[:, k], centre[:, k]
        if (st.held[:, k].any() or not np.all(np.isfinite(s) & (s > 0) & np.isfinite(c))
                or np.any(c - st.lo[:, k] < COLLAPSE_MARGIN * s)
                or np.any(st.hi[:, k] - c < COLLAPSE_MARGIN * s)):
            continue
        ok.append(k)
    if not ok:
        return []
    step = np.where(np.isfinite(st.sd) & ~st.held, 0.5 * st.sd, 0.0)
    moved = np.asarray(theta0, float).copy()
    moved[:, np.asarray(free, int)] = np.clip(th + step, st.lo, st.hi)
    jacs = jax.device_get(linearize(residual, tuple(free), jnp.asarray(moved), data))[2]
    keep = []
    for k in ok:
        same = True
        for J0, J1 in zip(st.jacobians, jacs):
            a, b = np.asarray(J0[..., k], float), np.asarray(J1[..., k], float)
            scale = float(np.max(np.abs(a), initial=0.0))
            if not (scale > 0 and np.all(np.isfinite(b))
                    and np.max(np.abs(a - b)) <= AFFINE_TOL * scale):
                same = False
        if same:
            keep.append(k)
    return keep


def log_rule(lo: np.ndarray, hi: np.ndarray, theta: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """Which unknowns run in log coordinates: a box with a lower bound >= 0 and `theta` at
    least `LOG_AWAY` standard deviations `sd` above it (bool, broadcast shape; SI units)."""
    ok = np.isfinite(sd) & (sd > 0)
    return ((lo >= 0.0) & (hi > lo) & ok
            & (theta - lo >= LOG_AWAY * np.where(ok, sd, np.inf)))


def softness(cov: np.ndarray | None, lo: np.ndarray, hi: np.ndarray,
             log: np.ndarray | None = None, theta: np.ndarray | None = None,
             sd: np.ndarray | None = None) -> np.ndarray:
    """The bounded map's softness `d` (Kf,): `SOFTNESS` x the standard deviation of each
    unknown [SI] (`sd`, else the square root of `cov`'s diagonal; of its logarithm, sd / theta,
    where `log`), within [1e-9, 1] x its box width in those coordinates (the box width where
    undefined)."""
    if log is not None and np.any(log):
        lo, hi = (np.asarray(b, float) for b in log_bounds(lo, hi, log))
    w = np.where(hi > lo, hi - lo, 1.0)  # a point box (a held unknown): any softness
    if cov is None and sd is None:
        return w
    with np.errstate(invalid="ignore", divide="ignore"):
        if sd is None:
            sd = np.sqrt(np.diag(np.asarray(cov, float)))
        if log is not None:
            sd = np.where(log, sd / np.where(log, theta, 1.0), sd)
    ok = np.isfinite(sd) & (sd > 0)
    return np.where(ok, np.clip(SOFTNESS * np.where(ok, sd, 0.0), 1e-9 * w, w), w)


def to_log(st: Start, z0: np.ndarray, cov: np.ndarray, moved: Sequence[int],
           centre: np.ndarray, sd: np.ndarray):
    """Host: the unknowns that run in log coordinates once the mode is known. The start's rule
    (:func:`log_rule`) reads the Gauss-Newton standard deviation, which AR(1) noise inflates
    by up to two orders of magnitude; at the mode, `centre` (U, Kf) with its Laplace `sd`
    (U, Kf), more pass. For those,
    the position `z0` (U, D) and covariance `cov` (U, D, D) (the first `len(moved)` entries
    the moved unknowns' `u`) are carried into the new coordinates, to first order. Returns
    `(st, z0, cov)` with `st.log` and `st.soft` updated."""
    lg = st.log | (log_rule(st.lo, st.hi, centre, sd) & ~st.held)
    turn = lg & ~st.log
    if not turn.any():
        return st, z0, cov
    soft = np.where(turn, softness(None, st.lo, st.hi, lg, centre, sd), st.soft)
    m = np.asarray(moved, int)
    u_old = np.zeros_like(centre)
    u_old[:, m] = z0[:, :m.size]
    u_new = from_box(centre, st.lo, st.hi, soft, lg)
    with np.errstate(invalid="ignore", divide="ignore"):  # point boxes: 0 / 0, not turned
        ratio = box_slope(u_old, st.lo, st.hi, st.soft, st.log) / box_slope(
            u_new, st.lo, st.hi, soft, lg)
    scale = np.ones(z0.shape)
    scale[:, :m.size] = np.where(turn[:, m], ratio[:, m], 1.0)
    z0 = z0.copy()
    z0[:, :m.size] = np.where(turn[:, m], u_new[:, m], z0[:, :m.size])
    return st._replace(log=lg, soft=soft), z0, cov * scale[:, :, None] * scale[:, None, :]


def u_cov(cov: np.ndarray | None, slope: np.ndarray) -> np.ndarray:
    """The covariance of the bounded map's `u` from a covariance of theta (delta method,
    `slope` the map's d theta / du), `FALLBACK_U_VAR` where it is undefined, variances capped
    at `MAX_U_VAR`."""
    K = slope.size
    g = np.where(slope > 0, slope, 1.0)
    if cov is None:
        return np.eye(K) * FALLBACK_U_VAR
    c = np.asarray(cov, float) / np.outer(g, g)
    var = np.diag(c).copy()
    ok = np.isfinite(var) & (var > 0)
    big = ok & (var > MAX_U_VAR)
    if big.any() and np.all(np.isfinite(c[np.ix_(ok, ok)])):
        # shrink the long axes, not the variances one by one: a variance cut while its
        # correlations stay makes a thin ridge (near a bound, where the map's slope is small)
        # a wide one across (modified Bouc-Wen: a start 100x too wide across beta-gamma)
        sub = c[np.ix_(ok, ok)]
        w, V = np.linalg.eigh(0.5 * (sub + sub.T))
        c[np.ix_(ok, ok)] = (V * np.clip(w, 0.0, MAX_U_VAR)) @ V.T
        var = np.where(ok, np.diag(c), var)
    var = np.where(ok, np.minimum(var, MAX_U_VAR), FALLBACK_U_VAR)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = c / np.sqrt(np.outer(np.diag(c), np.diag(c)))
    good = np.outer(ok, ok) & np.isfinite(corr)
    corr = np.where(good, np.clip(corr, -1.0, 1.0), 0.0)
    np.fill_diagonal(corr, 1.0)
    sd = np.sqrt(var)
    return corr * np.outer(sd, sd)


def clip_cov(c: np.ndarray) -> np.ndarray:
    """A symmetric positive-definite matrix near `c`: eigenvalues floored at 1e-8 of the largest,
    variances capped at `MAX_U_VAR`."""
    c = 0.5 * (c + c.T)
    w, V = np.linalg.eigh(c)
    w = np.maximum(w, 1e-8 * max(float(w.max()), 1e-300))
    c = (V * w) @ V.T
    d = np.sqrt(np.diag(c))
    scale = np.minimum(1.0, np.sqrt(MAX_U_VAR) / d)
    return c * np.outer(scale, scale)
