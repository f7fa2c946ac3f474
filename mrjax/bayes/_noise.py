"""The likelihood of residual records: Gaussian noise, independent (`"iid"`) or AR(1).

A unit's residual function returns blocks `(r, mask)` of R records (rows) by T samples; only
scored samples (`mask`) enter. Each record has its own noise level $\\sigma_r$ [N], the
marginal standard deviation of its residuals. With `"ar1"`, residuals follow
$e_t = \\rho\\, e_{t-1} + \\varepsilon_t$, $\\varepsilon_t \\sim N(0, \\sigma^2 (1 - \\rho^2))$,
one $\\rho \\in (-1, 1)$ per unit; the process restarts (stationary, $e_t \\sim N(0,\\sigma^2)$)
at the first scored sample of each record and after every masked gap, so padding and dropped
transients never link unrelated samples. `"iid"` is $\\rho = 0$.

Why AR(1): the residuals of a damper model on real records are model error, correlated over
hundreds of samples. Treating 19,000 such samples as independent makes every interval
$\\sqrt{(1 + \\rho) / (1 - \\rho)}$ too narrow (a factor 14 at $\\rho = 0.99$); the AR(1)
likelihood counts the information they really carry.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .._errors import InputError

#: The noise models of :func:`block_loglik`.
NOISE_MODELS: tuple[str, ...] = ("iid", "ar1")
#: Starting values of rho are kept inside this (the sampler's map sends +-1 to infinity).
RHO_START_MAX = 0.9999
_LOG_2PI = math.log(2.0 * math.pi)


def check_noise(noise: str) -> str:
    """`noise` checked: one of `NOISE_MODELS`, else :class:`mrjax.InputError`."""
    if noise not in NOISE_MODELS:
        raise InputError(f"noise must be one of {', '.join(NOISE_MODELS)}, got {noise!r}")
    return noise


def log1m_tanh2(v: Float[ArrayLike, "*S"]) -> Float[Array, "*S"]:
    """$\\log(1 - \\tanh^2 v)$, stable for large |v| (where $\\rho = \\tanh v \\to \\pm 1$)."""
    a = jnp.abs(jnp.asarray(v))
    return 2.0 * (math.log(2.0) - a - jnp.log1p(jnp.exp(-2.0 * a)))


def whiten(
    r: Float[ArrayLike, "R T"], mask: Bool[ArrayLike, "R T"], v: Float[ArrayLike, ""] | None
) -> tuple[Float[Array, "R T"], Float[Array, " R"]]:
    """The residuals `r` (R, T) [N] mapped to independent ones of each record's marginal level:
    `(w, n_cont)` with $\\sum_t w_t^2 / \\sigma^2$ the likelihood's quadratic form. With AR(1)
    noise ($\\rho = \\tanh v$), $w_t = (e_t - \\rho e_{t-1}) / \\sqrt{1 - \\rho^2}$ where
    sample `t` follows a scored one (`n_cont` (R,) of them), $w_t = e_t$ at a restart; 0 on
    unscored samples. Linear in `r`."""
    r, mask = jnp.asarray(r), jnp.asarray(mask)
    e = jnp.where(mask, r, 0.0)
    if v is None:
        return e, jnp.zeros(e.shape[0], e.dtype)
    cont = mask[:, 1:] & mask[:, :-1]  # sample t follows a scored sample t - 1
    innov = (e[:, 1:] - jnp.tanh(v) * e[:, :-1]) * jnp.exp(-0.5 * log1m_tanh2(v))
    w = jnp.concatenate([e[:, :1], jnp.where(cont, innov, e[:, 1:])], axis=1)
    return w, jnp.sum(cont, axis=1)


def _base(mask, log_sigma, n_cont, v):
    """Per record: the log-likelihood's terms that do not depend on the residuals."""
    n = jnp.sum(mask, axis=1)
    base = n * (_LOG_2PI + 2.0 * log_sigma)
    return base if v is None else base + n_cont * log1m_tanh2(v)


def block_loglik(
    r: Float[ArrayLike, "R T"],
    mask: Bool[ArrayLike, "R T"],
    log_sigma: Float[ArrayLike, " R"],
    v: Float[ArrayLike, ""] | None = None,
) -> Float[Array, ""]:
    """Gaussian log-likelihood [log density of residuals in 1/N^n] of one block of records.

    **Arguments:** `r` (R, T) residuals [N]; `mask` (R, T) scored samples; `log_sigma` (R,)
    log noise levels (log N); `v` the AR(1) coefficient as $\\rho = \\tanh v$, or `None` for
    independent noise. Non-finite residuals on scored samples give NaN or inf (the caller maps
    them to `-inf`); unscored samples are never read.
    """
    mask = jnp.asarray(mask)
    w, n_cont = whiten(r, mask, v)
    quad = jnp.exp(-2.0 * log_sigma) * jnp.sum(w * w, axis=1)
    return -0.5 * jnp.sum(_base(mask, log_sigma, n_cont, v) + quad)


def lag_grams(A: Float[ArrayLike, "*B R T L"], mask: Bool[ArrayLike, "*B R T"]
              ) -> Float[Array, "*B R 4 L L"]:
    """The sums of products of constant regressors `A` (..., R, T, L) over each record's
    scored samples `mask` that the whitened regressors' Gram matrix is made of, for any AR(1)
    coefficient (:func:`linear_marginal`): per record `[P0, P1, P2, Q]` (L, L) with
    $P_0 = \\sum_c a_t a_t^T$, $P_1 = \\sum_c a_t a_{t-1}^T$, $P_2 = \\sum_c a_{t-1}
    a_{t-1}^T$ over the samples `c` that follow a scored one, and $Q = \\sum a_t a_t^T$ over
    the restarts. Computed once per unit: the sampler's every gradient then costs O(L^2) per
    record for the Gram matrix instead of whitening every regressor."""
    mask = jnp.asarray(mask)
    A = jnp.where(mask[..., None], jnp.asarray(A), 0.0)
    cont = mask[..., 1:] & mask[..., :-1]
    restart = mask & ~jnp.concatenate([jnp.zeros_like(mask[..., :1]), cont], axis=-1)
    a1 = jnp.where(cont[..., None], A[..., 1:, :], 0.0)
    a0 = A[..., :-1, :]
    gram = lambda x, y: jnp.einsum("...tl,...tk->...lk", x, y)
    return jnp.stack([gram(a1, A[..., 1:, :]), gram(a1, a0),
                      gram(jnp.where(cont[..., None], a0, 0.0), a0),
                      gram(jnp.where(restart[..., None], A, 0.0), A)], axis=-3)


def _whitened_gram(G, v):
    """Per record (R, L, L): the Gram matrix of the whitened regressors from their
    :func:`lag_grams` `G` (R, 4, L, L)."""
    if v is None:
        return G[:, 0] + G[:, 3]
    rho, s2 = jnp.tanh(v), jnp.exp(-log1m_tanh2(v))
    P1 = G[:, 1]
    return s2 * (G[:, 0] - rho * (P1 + jnp.swapaxes(P1, -1, -2)) + rho * rho * G[:, 2]) + G[:, 3]


def linear_marginal(
    blocks, regressors, log_sigma: Float[ArrayLike, " R"], v: Float[ArrayLike, ""] | None,
    grams: tuple | None = None,
) -> tuple[Float[Array, ""], Float[Array, " L"], Float[Array, "L L"], Float[Array, " L"]]:
    """The likelihood with L linear unknowns integrated out, and their conditional.

    The residuals are affine in the unknowns $\\beta$ (L,): $r(\\beta) = r + A\\,\\delta$,
    $\\delta = \\beta - \\beta_0$, with `blocks` `((r (R_b, T_b), mask), ...)` at
    $\\beta_0$ and `regressors` `(A (R_b, T_b, L), ...)` [N per unit of each unknown], constant.
    With a flat prior on $\\beta$, the Gaussian integral over it is the likelihood at its
    conditional mode times $(2\\pi)^{L/2} \\det(M)^{-1/2}$, $M = \\sum A_w^T A_w / \\sigma^2$
    ($A_w$ the whitened regressors, :func:`whiten`), $M$ from the regressors' :func:`lag_grams`
    (`grams`, one per block; computed here when None).

    **Returns:** `(log marginal likelihood, delta_hat (L,), C (L, L), d (L,))`: the conditional
    of $\\delta$ is $N(\\hat\\delta, M^{-1})$ with $M^{-1} = D C^{-T} C^{-1} D$, $D$ =
    diag(`d`), $C$ the Cholesky factor of $D M D$ (a draw: $\\hat\\delta + d \\odot
    C^{-T} \\varepsilon$). The flat prior's density, constant, is left out.
    """
    if grams is None:
        grams = tuple(lag_grams(A, m) for (_, m), A in zip(blocks, regressors))
    ll, M, c, off = 0.0, 0.0, 0.0, 0
    for (r, m), A, G in zip(blocks, regressors, grams):
        m = jnp.asarray(m)
        n = m.shape[0]
        ls = log_sigma[off:off + n]
        off += n
        w, n_cont = whiten(r, m, v)
        iv = jnp.exp(-2.0 * ls)
        ll = ll - 0.5 * jnp.sum(_base(m, ls, n_cont, v) + iv * jnp.sum(w * w, axis=1))
        M = M + jnp.einsum("rlk,r->lk", _whitened_gram(G, v), iv)
        # A_w^T w = A^T (W^T w), W^T the transpose of the (linear) whitening
        y = jax.linear_transpose(lambda e: whiten(e, m, v)[0], r)(w)[0]
        c = c + jnp.einsum("rtl,rt->l", jnp.where(m[..., None], jnp.asarray(A), 0.0),
                           iv[:, None] * y)
    d = 1.0 / jnp.sqrt(jnp.diagonal(M))
    C = jnp.linalg.cholesky(M * d[:, None] * d[None, :])
    y = jax.scipy.linalg.cho_solve((C, True), d * c)
    L = c.shape[0]
    logdet = 2.0 * jnp.sum(jnp.log(jnp.diagonal(C))) - 2.0 * jnp.sum(jnp.log(d))
    ll = ll + 0.5 * jnp.dot(d * c, y) + 0.5 * (L * _LOG_2PI - logdet)
    return ll, -d * y, C, d


def noise_start(blocks: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, float, np.ndarray]:
    """Host starting values from one unit's residual blocks `[(r (R_b, T_b), mask), ...]` at the
    optimum: `(sigma (R,) [N], rho, n (R,))`, the RMS of each record (1 N where it is zero),
    the lag-1 autocorrelation over consecutive scored samples of all records (clipped to
    +-`RHO_START_MAX`) and the scored samples of each record."""
    sig, n, num, den = [], [], 0.0, 0.0
    for r, mask in blocks:
        r, m = np.asarray(r, float), np.asarray(mask, bool)
        e = np.where(m & np.isfinite(r), r, 0.0)
        k = m.sum(axis=1)
        s = np.sqrt((e * e).sum(axis=1) / np.maximum(k, 1))
        sig.append(np.where(s > 0, s, 1.0))
        n.append(k)
        cont = m[:, 1:] & m[:, :-1]
        num += float(np.sum(np.where(cont, e[:, 1:] * e[:, :-1], 0.0)))
        den += float(np.sum(np.where(cont, e[:, :-1] ** 2, 0.0)))
    rho = float(np.clip(num / den, -RHO_START_MAX, RHO_START_MAX)) if den > 0 else 0.0
    return np.concatenate(sig), rho, np.concatenate(n)
