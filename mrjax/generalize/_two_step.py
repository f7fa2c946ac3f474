"""The paper's two-step generalization: average the per-condition parameters per current, then
fit each law (optionally weighted by the fits' covariances)."""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ..fitting import FitResult
from ._laws import LAW_KINDS, default_degrees, fit_space, group_currents, vander

#: Relative eigenvalue floor of a per-condition correlation matrix below which its covariance
#: counts as singular (the two-step "covariance" weighting then falls back to "equal").
COV_EIG_FLOOR = 1e-12


def law_spec(model, degrees, laws, n_currents, unit: str = "A"
             ) -> tuple[tuple[str, ...], tuple[int, ...]]:
    """Law kinds and degrees per parameter from the user's `degrees` (dict or one int) and
    `laws` (dict of kinds), the model's defaults for laws in `unit` (see `default_degrees`)
    capped at `n_currents - 1` distinct command levels (`math.inf` for a time-varying command).
    Raises :class:`mrjax.InputError` for unknown names, bad kinds or too high a degree."""
    names = model.param_names
    laws = {} if laws is None else dict(laws)
    if isinstance(degrees, int | np.integer):
        degrees = {n: int(degrees) for n in names}
    degrees = {} if degrees is None else dict(degrees)
    for what, d in (("laws", laws), ("degrees", degrees)):
        unknown = sorted(set(d) - set(names))
        if unknown:
            raise InputError(f"{what} names unknown parameters {unknown} of model "
                             f"{model.name!r}; expected some of {list(names)}")
    for n, k in laws.items():
        if k not in LAW_KINDS:
            raise InputError(f"law of {n!r} must be one of {list(LAW_KINDS)}, got {k!r}")
        if k == "sat" and n_currents < 3:
            raise InputError(f"law 'sat' of {n!r} needs at least 3 distinct currents; the "
                             f"data have {n_currents}")
    dflt = default_degrees(model, unit=unit)
    kinds, degs = [], []
    for n in names:
        kind = laws.get(n, "poly")
        if kind == "sat":
            if n in degrees and degrees[n] != 1:
                raise InputError(f"a 'sat' law has degree 1 (2 coefficients), not "
                                 f"{degrees[n]!r} for {n!r}")
            d = 1
        elif n in degrees:
            d = degrees[n]
            if isinstance(d, bool) or int(d) != d or d < 0:
                raise InputError(f"degree of {n!r} must be a non-negative integer, got {d!r}")
            d = int(d)
            if d > n_currents - 1:
                raise InputError(f"degree {d} of {n!r} needs at least {d + 1} distinct currents; "
                                 f"the data have {n_currents}")
        else:
            d = int(min(1 if kind == "exp" else dflt[n], n_currents - 1))
        kinds.append(kind)
        degs.append(d)
    return tuple(kinds), tuple(degs)


def covariances(result: FitResult, theta: np.ndarray, exp_cols: np.ndarray):
    """Per-condition covariances in the fitted space (log for "exp" laws), or None with the
    reason when any is unusable."""
    se = np.asarray(result.stderr, float)
    corr = np.asarray(result.corr, float)
    if se.shape != theta.shape or corr.shape != theta.shape + (theta.shape[1],):
        return None, "no per-condition covariance"
    if not (np.all(np.isfinite(se)) and np.all(se > 0) and np.all(np.isfinite(corr))):
        return None, "a per-condition standard error is missing or zero"
    if not np.all(np.asarray(result.identifiable, bool)):
        return None, "a per-condition parameter is not identifiable"
    se_t = np.where(exp_cols[None, :], se / np.abs(np.where(exp_cols[None, :], theta, 1.0)), se)
    eig = np.linalg.eigvalsh(corr)
    if np.any(eig[:, 0] <= COV_EIG_FLOOR * eig[:, -1]):
        return None, "a per-condition covariance is singular"
    return corr * se_t[:, :, None] * se_t[:, None, :], ""


def two_step_coefficients(theta, cur, kinds, degs, cov, weighting, scales=None):
    """Law coefficients (V,) from per-condition parameters (C, P) and support data; `scales`
    (P,) those of the `"sat"` laws (1 elsewhere)."""
    C, P = theta.shape
    scales = tuple(scales) if scales else (1.0,) * P
    exp_cols = np.array([k == "exp" for k in kinds])
    sizes = [d + 1 for d in degs]
    levels, gid = group_currents(cur)
    U = levels.size
    counts = np.bincount(gid, minlength=U)
    mean = np.array([theta[gid == u].mean(axis=0) for u in range(U)])
    with np.errstate(invalid="ignore", divide="ignore"):
        sd = np.array([theta[gid == u].std(axis=0, ddof=1) if counts[u] > 1 else
                       np.full(P, np.nan) for u in range(U)])
        stderr = sd / np.sqrt(counts)[:, None]
    offs = np.concatenate([[0], np.cumsum(sizes)])
    if weighting == "equal":
        coef = np.zeros(offs[-1])
        for p in range(P):
            y = mean[:, p]
            if exp_cols[p]:
                y = np.log(y)
            X = vander(levels, sizes[p], kinds[p], scales[p])
            coef[offs[p]:offs[p + 1]] = np.linalg.lstsq(X, y, rcond=None)[0]
    else:
        t = fit_space(theta, exp_cols)
        W = np.linalg.inv(cov)  # (C, P, P)
        A = np.zeros((offs[-1], offs[-1]))
        g = np.zeros(offs[-1])
        for u in range(U):
            Wu = W[gid == u].sum(axis=0)
            mu = np.linalg.solve(Wu, np.einsum("cij,cj->i", W[gid == u], t[gid == u]))
            X = np.zeros((P, offs[-1]))
            for p in range(P):
                X[p, offs[p]:offs[p + 1]] = vander(levels[u:u + 1], sizes[p], kinds[p],
                                                   scales[p])[0]
            A += X.T @ Wu @ X
            g += X.T @ Wu @ mu
            su = np.sqrt(np.diag(np.linalg.inv(Wu)))
            e = np.exp(np.where(exp_cols, mu, 0.0))
            mean[u] = np.where(exp_cols, e, mu)
            stderr[u] = np.where(exp_cols, su * e, su)
        d = np.sqrt(np.diag(A))
        d = np.where(d > 0, d, 1.0)
        coef = np.linalg.solve(A / np.outer(d, d), g / d) / d
    support = {"points_current": levels, "points_mean": mean, "points_stderr": stderr,
               "conditions_current": cur.copy(), "conditions_theta": theta.copy()}
    return coef, support
