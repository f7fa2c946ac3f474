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
    r, mask = jnp.asarray(r), jnp.asarray(mask)
    e = jnp.where(mask, r, 0.0)
    inv_var = jnp.exp(-2.0 * log_sigma)
    n = jnp.sum(mask, axis=1)
    base = n * (_LOG_2PI + 2.0 * log_sigma)
    if v is None:
        return -0.5 * jnp.sum(base + inv_var * jnp.sum(e * e, axis=1))
    rho = jnp.tanh(v)
    l1m = log1m_tanh2(v)
    cont = mask[:, 1:] & mask[:, :-1]  # sample t follows a scored sample t - 1
    innov = jnp.where(cont, e[:, 1:] - rho * e[:, :-1], 0.0)
    start = jnp.where(cont, 0.0, e[:, 1:])  # restarts: first scored sample and after gaps
    ss_start = e[:, 0] ** 2 + jnp.sum(start * start, axis=1)
    ss_cont = jnp.sum(innov * innov, axis=1)
    n_cont = jnp.sum(cont, axis=1)
    quad = inv_var * (ss_start + ss_cont * jnp.exp(-l1m))
    return -0.5 * jnp.sum(base + n_cont * l1m + quad)


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
