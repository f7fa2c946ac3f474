"""Priors of the posterior's unknowns and the bounded map the sampler runs in.

Every unknown $\\theta_j$ lives in a box $[l_j, h_j]$ (a fit's bounds). NUTS needs an
unbounded space, so the sampler moves $u_j \\in \\mathbb{R}$ with the *soft box*

$$ \\theta_j = l_j + d_j\\,[\\mathrm{sp}(u_j) - \\mathrm{sp}(u_j - W_j)], \\qquad
   W_j = (h_j - l_j) / d_j, \\quad \\mathrm{sp}(x) = \\log(1 + e^x), $$

and adds its log-Jacobian $\\log s(u_j) + \\log s(W_j - u_j)$ ($s$ the logistic function;
+ the constant $\\log d_j + \\log(1 - e^{-W_j})$) to the log-density. `d_j` [the parameter's
unit] is the map's *softness*, a fraction of the parameter's expected posterior spread (the
sampler takes half its starting standard deviation): more than a few `d_j` inside the box the
map is the identity up to a shift and scale ($\\theta \\approx l + d\\,u$), so a Gaussian
posterior stays Gaussian; within a few `d_j` of a bound it bends smoothly into an exponential
tail (a flat prior on the box is a density $\\propto s(u) s(W - u)$ in `u`). With `d_j` as
wide as the box it is a logistic map.

Why not the logistic map $\\theta = l + (h - l)\\,s(u)$ on its own: it is logarithmic in the
distance to a bound, and the damper models' boxes are wide (tanh's `c` in [0, 1e5] N s/m):
a short record's `c` of 2,000 +- 450 N s/m is then log-normal-shaped in `u`, and its 0.9
correlation with `k` (linear in `u`) bends into a banana whose curvature a dense mass matrix
cannot follow. On the 50 short tanh records of the calibration (`benchmarks/posterior.py`)
it gave 16 divergent transitions in 200,000 draws; the soft box none.
*Log coordinates.* A positive unknown far above its lower bound (the sampler's rule:
`mrjax.bayes._start.LOG_AWAY` standard deviations, at the start or at the mode) runs the soft box in
$\\log\\theta$, on $[\\log l, \\log h]$ (a lower bound of 0 taken as `LOG_FLOOR` $h$), with
$\\log\\theta$ added to the log-Jacobian. The damper models' scale parameters trade off as
products (a damping times a hysteretic amplitude), ridges that are straight in logarithms and
curved in the parameters (`benchmarks/posterior_geometry.py`).
(The polish's periodic MINUIT map $\\sin u$ would make every mode repeat; these maps are one
to one.) A user's prior multiplies the flat density on the box: a :class:`Normal` or
:class:`LogNormal` is truncated to it, a :class:`Uniform` narrows it.

Priors are per parameter, by name; they are turned once (:func:`prior_arrays`) into three
arrays (kind, a, b) that the compiled log-density reads (:func:`log_prior`), so new prior
values do not recompile.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InputError

#: Codes of the prior kinds in the arrays of :func:`prior_arrays`.
FLAT, NORMAL, LOGNORMAL = 0, 1, 2
#: A start on (or within this fraction of the box width of) a bound is moved this far inside:
#: the logistic map sends a bound to infinity.
START_NUDGE = 1e-3
#: In log coordinates (:func:`to_box` with `log`), a lower bound of 0 is taken as this
#: fraction of the upper one: the flat prior loses that fraction of its box, where the log map
#: is only used for unknowns many standard deviations above it.
LOG_FLOOR = 1e-12


@dataclasses.dataclass(frozen=True)
class Normal:
    """Normal prior $N(\\mathrm{mean}, \\mathrm{sd}^2)$ on a parameter, truncated to its box.

    **Fields:** `mean`, `sd` (> 0), in the parameter's SI unit."""

    mean: float
    sd: float

    def describe(self) -> str:
        """`normal(mean, sd)`."""
        return f"normal({self.mean:g}, {self.sd:g})"


@dataclasses.dataclass(frozen=True)
class LogNormal:
    """Log-normal prior on a positive parameter: $\\log\\theta \\sim N(\\log m, s^2)$,
    truncated to its box (which must lie in $\\theta \\ge 0$).

    **Fields:** `median` $m$ (> 0) in the parameter's SI unit; `sigma` $s$ (> 0) the standard
    deviation of $\\log\\theta$ (dimensionless; 0.5 is a factor of about 1.65 either way)."""

    median: float
    sigma: float

    def describe(self) -> str:
        """`lognormal(median, sigma)`."""
        return f"lognormal({self.median:g}, {self.sigma:g})"


@dataclasses.dataclass(frozen=True)
class Uniform:
    """Uniform prior on `[lower, upper]` (SI units): the sampler's box becomes its
    intersection with the fit's bounds."""

    lower: float
    upper: float

    def describe(self) -> str:
        """`uniform(lower, upper)`."""
        return f"uniform({self.lower:g}, {self.upper:g})"


Prior = Normal | LogNormal | Uniform
_KINDS = {"normal": Normal, "lognormal": LogNormal, "uniform": Uniform}


def parse_prior(spec: Any, name: str = "parameter") -> Prior:
    """One prior from a :class:`Normal` / :class:`LogNormal` / :class:`Uniform`, a tuple
    `("normal", mean, sd)`, or text `"normal:MEAN:SD"` (also `lognormal:MEDIAN:SIGMA`,
    `uniform:LO:HI`), checked.

    Raises :class:`mrjax.InputError` naming `name` for an unknown kind, a wrong count of
    values or an impossible value (sd <= 0, median <= 0, lower >= upper, non-finite)."""
    if isinstance(spec, str):
        kind, *vals = [s.strip() for s in spec.split(":")]
        spec = (kind, *vals)
    if isinstance(spec, (tuple, list)):
        if not spec or not isinstance(spec[0], str) or spec[0].lower() not in _KINDS:
            kinds = ", ".join(_KINDS)
            raise InputError(f"prior of {name!r}: expected one of {kinds} with two values "
                             f"(e.g. normal:MEAN:SD), got {spec!r}")
        if len(spec) != 3:
            raise InputError(f"prior of {name!r}: {spec[0]} takes two values, got "
                             f"{len(spec) - 1}")
        try:
            a, b = float(spec[1]), float(spec[2])
        except (TypeError, ValueError):
            raise InputError(f"prior of {name!r}: values must be numbers, got {spec[1:]!r}") \
                from None
        spec = _KINDS[spec[0].lower()](a, b)
    if not isinstance(spec, (Normal, LogNormal, Uniform)):
        raise InputError(f"prior of {name!r} must be Normal, LogNormal, Uniform or text like "
                         f"'normal:MEAN:SD', got {type(spec).__name__}")
    vals = dataclasses.astuple(spec)
    if not all(math.isfinite(float(v)) for v in vals):
        raise InputError(f"prior of {name!r}: non-finite value in {spec.describe()}")
    if isinstance(spec, Normal) and spec.sd <= 0:
        raise InputError(f"prior of {name!r}: sd must be positive, got {spec.sd:g}")
    if isinstance(spec, LogNormal) and (spec.median <= 0 or spec.sigma <= 0):
        raise InputError(f"prior of {name!r}: median and sigma must be positive, got "
                         f"{spec.describe()}")
    if isinstance(spec, Uniform) and not spec.lower < spec.upper:
        raise InputError(f"prior of {name!r}: uniform needs lower < upper, got "
                         f"{spec.describe()}")
    return spec


def check_priors(prior: Mapping[str, Any] | None, names: Sequence[str]) -> dict[str, Prior]:
    """The user's priors by parameter name, checked (:func:`parse_prior`); an unknown name is an
    :class:`mrjax.InputError` with the closest names."""
    if prior is None:
        return {}
    if not isinstance(prior, Mapping):
        raise InputError(f"prior must be a mapping from parameter name to prior, got "
                         f"{type(prior).__name__}")
    out = {}
    for n, spec in prior.items():
        if n not in names:
            near = difflib.get_close_matches(str(n), list(names), n=1)
            hint = f"; did you mean {near[0]!r}?" if near else f"; parameters: {list(names)}"
            raise InputError(f"prior for unknown parameter {n!r}{hint}")
        out[n] = parse_prior(spec, n)
    return out


def prior_arrays(
    priors: Mapping[str, Prior], names: Sequence[str], lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The priors as arrays for the compiled log-density, and the box they leave.

    **Arguments:** `priors` by name (checked); `names` (K,); `lower`, `upper` (U, K) the boxes
    of the U units, SI units.

    **Returns:** `(kind (K,) int, a (K,), b (K,), lower (U, K), upper (U, K))`: `kind` is
    `FLAT`, `NORMAL` (a = mean, b = sd) or `LOGNORMAL` (a = log median, b = sigma); a uniform
    prior is flat on the box narrowed to it.

    Raises :class:`mrjax.InputError` where a uniform prior misses a box or a log-normal prior
    meets a box reaching below zero."""
    K = len(names)
    kind, a, b = np.full(K, FLAT), np.zeros(K), np.ones(K)
    lo, hi = np.array(lower, float), np.array(upper, float)
    for j, n in enumerate(names):
        p = priors.get(n)
        if isinstance(p, Normal):
            kind[j], a[j], b[j] = NORMAL, p.mean, p.sd
        elif isinstance(p, LogNormal):
            if np.any(lo[:, j] < 0):
                raise InputError(f"prior of {n!r}: a log-normal prior needs a box in "
                                 f"{n} >= 0, the lower bound is {lo[:, j].min():g}")
            kind[j], a[j], b[j] = LOGNORMAL, math.log(p.median), p.sigma
        elif isinstance(p, Uniform):
            lo[:, j], hi[:, j] = np.maximum(lo[:, j], p.lower), np.minimum(hi[:, j], p.upper)
            if np.any(lo[:, j] > hi[:, j]):
                raise InputError(f"prior of {n!r}: {p.describe()} does not meet the bounds "
                                 f"[{lower[:, j].min():g}, {upper[:, j].max():g}]")
    return kind, a, b, lo, hi


def log_prior(
    theta: Float[ArrayLike, " K"], kind: ArrayLike, a: ArrayLike, b: ArrayLike
) -> Float[Array, ""]:
    """Log prior density of `theta` (K,) up to a constant (jittable): the sum over parameters
    of the normal / log-normal log-densities, 0 for flat ones; `-inf` for a log-normal
    parameter at or below zero (never NaN)."""
    theta = jnp.asarray(theta)
    z_n = (theta - a) / b
    pos = theta > 0
    lt = jnp.log(jnp.where(pos, theta, 1.0))
    z_l = (lt - a) / b
    lp = jnp.where(kind == NORMAL, -0.5 * z_n * z_n,
                   jnp.where(kind == LOGNORMAL,
                             jnp.where(pos, -lt - 0.5 * z_l * z_l, -jnp.inf), 0.0))
    return jnp.sum(lp)


def log_bounds(lower: ArrayLike, upper: ArrayLike, log: ArrayLike | None):
    """The box in the coordinates the soft box runs in: `(lower, upper)` unchanged, and for the
    unknowns flagged in `log` (bool, broadcastable) their logarithms, a lower bound of 0 taken
    as `LOG_FLOOR` x the upper one (jittable)."""
    if log is None:
        return lower, upper
    lo_pos = jnp.maximum(lower, LOG_FLOOR * upper)
    return (jnp.where(log, jnp.log(jnp.where(log, lo_pos, 1.0)), lower),
            jnp.where(log, jnp.log(jnp.where(log, upper, 1.0)), upper))


def to_box(u: Float[ArrayLike, " K"], lower: ArrayLike, upper: ArrayLike,
           scale: ArrayLike, log: ArrayLike | None = None) -> Float[Array, " K"]:
    """The soft box: $\\theta = l + d\\,[\\mathrm{sp}(u) - \\mathrm{sp}(u - W)]$,
    $W = (h - l) / d$ (see the module docstring): the unbounded variables `u` [-] mapped
    into the box [`lower`, `upper`] (SI units) with softness `scale` $d$ > 0 (SI units).
    Unknowns flagged in `log` (bool (K,), default none) run in log coordinates: the same map
    gives $\\log\\theta$ in $[\\log l, \\log h]$ (softness in units of $\\log\\theta$)."""
    u = jnp.asarray(u)
    lo, hi = log_bounds(lower, upper, log)
    width = (hi - lo) / scale
    th = lo + scale * (jax.nn.softplus(u) - jax.nn.softplus(u - width))
    th = jnp.clip(th, lo, hi)
    if log is None:
        return th
    return jnp.where(log, jnp.exp(jnp.where(log, th, 0.0)), th)


def log_jacobian(u: Float[ArrayLike, " K"], lower: ArrayLike, upper: ArrayLike,
                 scale: ArrayLike, log: ArrayLike | None = None) -> Float[Array, ""]:
    """$\\sum_j \\log s(u_j) + \\log s(W_j - u_j)$ (plus $\\log\\theta_j$ where `log`):
    the log-Jacobian of :func:`to_box` without its constant
    $\\log d_j + \\log(1 - e^{-W_j})$; finite for every finite `u`."""
    u = jnp.asarray(u)
    lo, hi = log_bounds(lower, upper, log)
    width = (hi - lo) / scale
    lj = jnp.sum(jax.nn.log_sigmoid(u) + jax.nn.log_sigmoid(width - u))
    if log is None:
        return lj
    psi = jnp.clip(lo + scale * (jax.nn.softplus(u) - jax.nn.softplus(u - width)), lo, hi)
    return lj + jnp.sum(jnp.where(log, psi, 0.0))


def _host_box(theta, lower, upper, scale, log):
    """Host: theta, box and softness in the coordinates the soft box runs in."""
    th, lo, hi, d = (np.asarray(v, float) for v in (theta, lower, upper, scale))
    if log is None:
        return th, lo, hi, d, None
    lg = np.broadcast_to(np.asarray(log, bool), np.broadcast(th, lo).shape)
    lo_t, hi_t = (np.asarray(b, float) for b in log_bounds(lo, hi, lg))
    with np.errstate(divide="ignore", invalid="ignore"):
        th_t = np.where(lg, np.log(np.where(lg, np.maximum(th, 1e-300), 1.0)), th)
    return th_t, lo_t, hi_t, d, lg


def from_box(theta: ArrayLike, lower: ArrayLike, upper: ArrayLike,
             scale: ArrayLike, log: ArrayLike | None = None) -> np.ndarray:
    """Host inverse of :func:`to_box`, in closed form
    ($u = \\log(e^t - 1) - \\log(1 - e^{t - W})$, $t = (\\theta - l) / d$, with
    $\\log\\theta$ and the log box where `log`): `u` of `theta`,
    moved inside by `START_NUDGE` of the box width (at most half a softness) where it sits on
    (or beyond) a bound; 0 where the box is a point."""
    th, lo, hi, d, _ = _host_box(theta, lower, upper, scale, log)
    live = hi > lo
    d = np.where(live & (d > 0), d, 1.0)
    width = np.where(live, (hi - lo) / d, 1.0)
    nudge = np.minimum(START_NUDGE * width, 0.5)
    t = np.clip(np.where(live, (th - lo) / d, 0.5), nudge, width - nudge)
    with np.errstate(over="ignore"):
        log_em1 = np.where(t > 30.0, t + np.log1p(-np.exp(-np.minimum(t, 700.0))),
                           np.log(np.expm1(np.minimum(t, 30.0))))
    u = log_em1 - np.log(-np.expm1(t - width))
    return np.where(live, u, 0.0)


def box_slope(u: ArrayLike, lower: ArrayLike, upper: ArrayLike, scale: ArrayLike,
              log: ArrayLike | None = None) -> np.ndarray:
    """Host: $d\\theta / du$ of :func:`to_box` at `u` (SI units per unit of `u`)."""
    u = np.asarray(u, float)
    _, lo, hi, d, lg = _host_box(np.zeros_like(u), lower, upper, scale, log)
    width = (hi - lo) / d
    with np.errstate(over="ignore"):
        slope = d * (1.0 / (1.0 + np.exp(-u)) - 1.0 / (1.0 + np.exp(width - u)))
    if lg is None:
        return slope
    return np.where(lg, slope * np.asarray(to_box(u, lower, upper, scale, lg)), slope)


def at_bounds(theta: ArrayLike, lower: ArrayLike, upper: ArrayLike,
              rtol: float = 1e-6) -> np.ndarray:
    """Host: whether each entry of `theta` lies within `rtol` of its box width of a bound
    (point boxes, fixed parameters, excluded)."""
    th, lo, hi = (np.asarray(v, float) for v in (theta, lower, upper))
    w = hi - lo
    return (w > 0) & ((th - lo <= rtol * w) | (hi - th <= rtol * w))
