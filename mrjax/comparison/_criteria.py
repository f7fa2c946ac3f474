"""Information criteria from the Gaussian likelihood of the residuals, and the honest count of
fitted parameters they need."""

from __future__ import annotations

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ..models import AbstractModel, check_bounds, get


def n_free_parameters(
    model: str | AbstractModel,
    bounds: tuple[ArrayLike, ArrayLike] | None = None,
) -> int:
    """Number of free parameters of `model` fitted within `bounds` (the noise variance not
    included).

    Every parameter counts once, except:

    - a parameter fixed by equal bounds (`lower == upper`) is not fitted and not counted;
    - in the Bouc-Wen and modified Bouc-Wen models the scale of z is redundant (the force is
        unchanged under $z \\to s z$, $\\alpha \\to \\alpha/s$, $\\delta \\to s\\delta$,
        $\\beta, \\gamma \\to s^{1-n}\\beta, s^{1-n}\\gamma$; see `mrjax.models.BoucWen`), so
        the model family has one dimension fewer than its parameter vector: one is
        subtracted, unless a fixed parameter pins the scale (`alpha` or `delta` fixed at a
        non-zero value, or `beta` or `gamma` fixed at a non-zero value with `n` fixed at a
        value other than 1).

    Parameters that end a fit on a bound are still counted (they were free).

    **Arguments:** `model` a name or model object; `bounds` `(lower, upper)` as for
    `mrjax.fit` (default the model's box).

    **Returns:** the count, e.g. 3 for `bingham`, 6 for `kwok`, 5 for `dahl`, 7 for
    `bouc_wen`, 9 for `modified_bouc_wen` with their default bounds.
    """
    model = get(model)
    lo, hi = check_bounds(model, bounds)
    fixed = lo == hi
    k = int(np.sum(~fixed))
    sym = model.scale_symmetry
    if sym is not None:
        names = model.param_names
        held = {n: float(lo[i]) for i, n in enumerate(names) if fixed[i]}
        free_scaled = sum(n in names and not fixed[names.index(n)] for n in sym.scaled)
        if not sym.pinned_by(held) and free_scaled >= 2:
            k -= 1
    return k


def information_criteria(
    rss: ArrayLike, n: ArrayLike, k: ArrayLike
) -> dict[str, np.ndarray]:
    """AIC, AICc and BIC of least-squares fits with Gaussian residuals of unknown variance.

    With $n$ scored samples, residual sum of squares $\\mathrm{RSS}$ [N²] and $k$ estimated
    parameters *including the noise variance* (`n_free_parameters(model) + 1`), the
    maximised log-likelihood is
    $\\ln L = -\\tfrac{n}{2}\\,[\\ln(2\\pi\\,\\mathrm{RSS}/n) + 1]$. mrjax drops the constant
    $n\\,(\\ln 2\\pi + 1)$, which is the same for every model scored on the same samples, and
    uses RSS in N², so only differences between models on the same tests mean anything:

    - $\\mathrm{AIC} = n\\ln(\\mathrm{RSS}/n) + 2k$,
    - $\\mathrm{AICc} = \\mathrm{AIC} + 2k(k+1)/(n-k-1)$ (NaN where $n \\le k + 1$),
    - $\\mathrm{BIC} = n\\ln(\\mathrm{RSS}/n) + k\\ln n$.

    Lower is better. A non-finite RSS (a diverged fit) gives `inf`; an RSS of exactly zero
    gives `-inf`.

    **Arguments:** `rss` [N²], `n` (samples) and `k` (parameters), broadcastable arrays.

    **Returns:** a dict `{"aic", "aicc", "bic"}` of float arrays of the broadcast shape.
    """
    rss, n, k = np.broadcast_arrays(np.asarray(rss, float), np.asarray(n, float),
                                    np.asarray(k, float))
    if np.any(n < 1) or np.any(k < 1):
        raise InputError("information criteria need n >= 1 samples and k >= 1 parameters")
    if np.any(rss < 0):
        raise InputError("the residual sum of squares cannot be negative")
    with np.errstate(divide="ignore", invalid="ignore"):
        fit = n * np.log(np.where(np.isfinite(rss), rss, np.inf) / n)
        aic = fit + 2.0 * k
        denom = n - k - 1.0
        aicc = np.where(denom > 0, aic + 2.0 * k * (k + 1.0) / np.where(denom > 0, denom, 1.0),
                        np.nan)
        bic = fit + k * np.log(n)
    return {"aic": aic, "aicc": aicc, "bic": bic}
