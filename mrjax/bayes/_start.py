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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._noise import block_loglik, log1m_tanh2, noise_start
from ._priors import box_slope, from_box, log_jacobian, log_prior, to_box

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
#: the map's curved zone is bent there, which a dense mass matrix cannot follow (modified
#: Bouc-Wen on a UTFSM test, beta and gamma correlated -1.00 with gamma 6 /m below its
#: bound: step sizes of 0.01 in the whitened coordinates at 0.5 and 0.1, 0.03-0.2 at 0.02
#: but trees still of hundreds of steps, 10 warmup steps each); 0.5 is the value of the
#: tanh and Dahl calibration (0 divergences in 200,000 draws each).
SOFTNESS = 0.5
#: A direction of the unknowns whose Gauss-Newton standard deviation exceeds this many box
#: widths is undetermined by the data: one unknown along it is held (see `undetermined`).
UNDETERMINED = 1.0
#: A `gauge` unknown is held for an undetermined direction where its component (in box
#: widths) is at least this share of the largest one.
GAUGE_SHARE = 0.1


class Target(eqx.Module):
    """What the compiled log-density needs that is the same for every unit (static)."""

    residual: Callable
    free: tuple[int, ...] = eqx.field(static=True)
    rows: tuple[int, ...] = eqx.field(static=True)  # records per block
    noise: str = eqx.field(static=True)
    forward: bool = eqx.field(static=True, default=False)


def forward_values(residual: Callable, theta_full, free, th_free, data):
    """The residual blocks' values at `theta_full` with its `free` entries set to `th_free`,
    differentiated in forward mode in `th_free`: their Jacobian (one pass with one tangent per
    free unknown, none for the held ones) is what reverse mode transposes. Through a
    sequential integration this is cheaper than a reverse pass, which stores and replays every
    step (modified Bouc-Wen on a 1,000-sample view: 13 ms against 24 ms per gradient)."""

    def values(tf):
        return tuple(r for r, _ in residual(theta_full.at[free].set(tf), data))

    @jax.custom_jvp
    def f(tf):
        return values(tf)

    @f.defjvp
    def f_jvp(primals, tangents):
        (tf,), (dtf,) = primals, tangents
        # the values from the same forward pass as the Jacobian (a second pass cost 2.2 of 9 ms)
        J, vals = jax.jacfwd(lambda t: (values(t), values(t)), has_aux=True)(tf)
        return vals, tuple(j @ dtf for j in J)

    return f(th_free)


def log_density(target: Target, prior, unit, z):
    """Log posterior density (up to a constant) of one unit at `z`; NaN or inf -> -inf."""
    data, lo, hi, soft, theta_full = unit
    kind, a, b = prior
    Kf, R = len(target.free), sum(target.rows)
    free = np.asarray(target.free, int)
    u, log_sigma = z[:Kf], z[Kf:Kf + R]
    v = z[Kf + R] if target.noise == "ar1" else None
    if v is not None:  # the position holds the innovations' level: the marginal one from it
        log_sigma = log_sigma - 0.5 * log1m_tanh2(v)
    th_free = to_box(u, lo, hi, soft)
    theta = theta_full.at[free].set(th_free)
    blocks = target.residual(theta, data)
    if target.forward:  # the masks above; their values (dead code there) from forward mode
        blocks = tuple(zip(forward_values(target.residual, theta_full, free, th_free, data),
                           (m for _, m in blocks)))
    lp = log_prior(th_free, kind[free], a[free], b[free]) + log_jacobian(u, lo, hi, soft)
    off = 0
    for (r, m), n in zip(blocks, target.rows):
        lp = lp + block_loglik(r, m, log_sigma[off:off + n], v)
        off += n
    if v is not None:
        lp = lp + log1m_tanh2(v)  # uniform prior on rho = tanh v in (-1, 1)
    return jnp.where(jnp.isfinite(lp), lp, -jnp.inf)


#: Damped Newton steps of the mode search that moves the start onto the posterior's mode
#: (`find_mode`), and its stop: the Newton decrement g^T H^-1 g / 2 below this many log-density
#: units.
MODE_STEPS = 25
MODE_TOL = 1e-3
#: Step of the central differences of the gradient that give the Hessian at the mode, in the
#: whitened coordinates of the Gauss-Newton start (where the posterior spans O(1)).
HESS_STEP = 1e-4
#: Gradients evaluated side by side for that Hessian (2 per unknown in all): a joint-laws unit
#: holds every record, and its reverse-mode gradient the whole forward pass.
HESS_BATCH = 8
#: Eigenvalues of the mode's covariance, in those coordinates, are kept within these bounds
#: (the narrowest direction measured on a UTFSM test was 2e-3, the widest 80).
MODE_EIG = (1e-6, 1e3)


#: Probes of :func:`gradient_error`: standard normal points of each unit's starting metric.
GRADIENT_PROBES = 8
#: Largest whitened gradient error [log-density units per unit length] of an approximate
#: derivative that the sampler keeps (above it, the exact one): over a trajectory of a few
#: units it moves the energy by a few tenths at most.
GRADIENT_TOL = 0.05


@eqx.filter_jit
def gradient_error(target, exact, prior, units, z0, L):
    """Largest difference |g - g_exact| of the log-density's gradient under `target` (an
    approximate derivative, e.g. the L-stable scheme's implicit tangent) and `exact`, in the
    whitened coordinates `w` (`z = z0 + L w`), over `GRADIENT_PROBES` standard normal points
    of every unit (non-finite gradients skipped). NUTS stays exact with an approximate
    gradient (its leapfrog map is still reversible and volume-preserving), but its energy
    error no longer vanishes with the step: where the gradient is off, the step-size
    adaptation shrinks the step towards 0 and every tree runs to its cap."""
    W = jax.random.normal(jax.random.key(0), (GRADIENT_PROBES, z0.shape[-1]), z0.dtype)

    def one(unit, z, m):
        def grads(t):
            return jax.vmap(jax.grad(lambda w: log_density(t, prior, unit, z + m @ w)))(W)

        d = jnp.linalg.norm(grads(target) - grads(exact), axis=-1)
        return jnp.max(jnp.where(jnp.isfinite(d), d, 0.0))

    return jnp.max(jax.lax.map(lambda a: one(*a), (units, z0, L)))


@eqx.filter_jit
def find_mode(target, prior, units, z0, L):
    """Each unit's posterior mode and the Hessian of the log-density there, in the whitened
    coordinates `w` of the start (`z = z0 + L w`), by damped Newton from `w = 0`: the Hessian
    by central differences of the gradient (`HESS_STEP`), |eigenvalues| floored, a
    Levenberg damping raised where a step does not climb. Returns `(w, logdensity at w,
    logdensity at 0, negative Hessian)` per unit."""

    def one(unit, z, m):
        ld = lambda w: log_density(target, prior, unit, z + m @ w)
        grad = jax.grad(ld)
        D = z.shape[0]
        eye = jnp.eye(D, dtype=z.dtype)

        def neg_hess(w):
            pts = jnp.concatenate([w + HESS_STEP * eye, w - HESS_STEP * eye])
            g = jax.lax.map(grad, pts, batch_size=HESS_BATCH)  # bounded memory on big units
            H = -(g[:D] - g[D:]) / (2.0 * HESS_STEP)
            H = 0.5 * (H + H.T)
            return jnp.where(jnp.isfinite(H), H, 0.0)

        def cond(c):
            k, _, _, _, dec = c
            return (k < MODE_STEPS) & (dec > MODE_TOL)

        def body(c):
            k, w, f, lam, _ = c
            g = grad(w)
            g = jnp.where(jnp.isfinite(g), g, 0.0)
            e, V = jnp.linalg.eigh(neg_hess(w))
            e = jnp.maximum(jnp.abs(e), MODE_EIG[0])
            gv = V.T @ g
            dw = V @ (gv / (e + lam))
            f_new = ld(w + dw)
            up = jnp.isfinite(f_new) & (f_new >= f)
            dec = jnp.where(up, 0.5 * jnp.sum(gv * gv / e), jnp.inf)
            return (k + 1, jnp.where(up, w + dw, w), jnp.where(up, f_new, f),
                    jnp.where(up, lam / 4.0, 4.0 * lam + 1e-3), dec)

        w0 = jnp.zeros_like(z)
        f0 = ld(w0)
        _, w, f, _, _ = jax.lax.while_loop(
            cond, body, (jnp.zeros((), jnp.int32), w0, f0, jnp.asarray(1e-3, z.dtype),
                         jnp.asarray(jnp.inf, z.dtype)))
        return w, f, f0, neg_hess(w)

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
        f = lambda tf: tuple(r for r, _ in residual(th.at[idx].set(tf), d))
        masks = tuple(m for _, m in residual(th, d))
        return f(th[idx]), masks, jax.jacfwd(f)(th[idx])

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


def start(residual, theta0, lo, hi, data, free, noise, names=(), gauge=()):
    """Host: the sampler's start `z0` (U, D), inverse mass matrix (U, D, D), the bounded map's
    softness (U, Kf) and box (U, Kf) per unit (`lo`, `hi` the free unknowns' boxes), and the
    unknowns held (U, Kf) bool, from the optimum and the Gauss-Newton covariance of the
    residuals there (the likelihood's own data: records or views, every block)."""
    vals, masks, jacs = jax.device_get(linearize(residual, tuple(free), jnp.asarray(theta0),
                                                  data))
    idx = np.asarray(free, int)
    Kf = idx.size
    lo, hi = np.array(lo, float), np.array(hi, float)
    z0, imm, soft, held_all = [], [], [], []
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
        d = softness(cov, lo[i], hi[i])
        u0 = from_box(theta0[i, idx], lo[i], hi[i], d)
        cu = u_cov(cov, box_slope(u0, lo[i], hi[i], d))
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
    return np.stack(z0), np.stack(imm), np.stack(soft), lo, hi, np.stack(held_all)


def softness(cov: np.ndarray | None, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The bounded map's softness `d` (Kf,) [SI]: `SOFTNESS` x the starting standard deviation
    of each unknown, within [1e-9, 1] x its box width (the box width where undefined)."""
    w = np.where(hi > lo, hi - lo, 1.0)  # a point box (a held unknown): any softness
    if cov is None:
        return w
    with np.errstate(invalid="ignore"):
        sd = np.sqrt(np.diag(np.asarray(cov, float)))
    ok = np.isfinite(sd) & (sd > 0)
    return np.where(ok, np.clip(SOFTNESS * np.where(ok, sd, 0.0), 1e-9 * w, w), w)


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
