"""Laws of a parameter over the coil current, the first-order current lag, default degrees and
the z-scale normalisation of Bouc-Wen models."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InputError
from ..models import AbstractModel, get

LAW_KINDS: tuple[str, ...] = ("poly", "exp", "sat")
#: Saturation commands [A or V] a `"sat"` law's scale is chosen among, as fractions of the
#: command range of the data (see `mrjax.generalize.choose_laws`).
SAT_SCALES: tuple[float, ...] = (0.1, 0.2, 0.35, 0.5, 0.75, 1.0, 1.5, 2.5)
#: Two currents closer than this [A] count as the same current when grouping conditions.
CURRENT_TOL = 1e-6
#: Units a law's argument (the command u) can have: coil current or command voltage.
COMMAND_UNITS: tuple[str, ...] = ("A", "V")
#: Row length of the packed samples of a static model's joint fit (see `_joint_data`).
PACK_ROW = 1024


# ------------------------------------------------------------------------------ laws
def horner(coefficients, i, xp):
    """Polynomial with ascending `coefficients` at `i` by Horner's rule (`xp` = np or jnp)."""
    acc = xp.zeros_like(i) + coefficients[-1]
    for c in coefficients[-2::-1]:
        acc = acc * i + c
    return acc


def law_basis(kind: str, scale: float, i, size: int, xp) -> list:
    r"""The functions of the command `i` a law is linear in (in its log for `"exp"`): the powers
    $i^0 \dots i^{size-1}$, or for `"sat"` $1$ and $1 - e^{-i/s}$ (`xp` = np or jnp)."""
    if kind == "sat":
        return [xp.ones_like(i), 1.0 - xp.exp(-i / scale)]
    return [i**m for m in range(size)]


def law_value(kind: str, scale: float, coefficients, i, xp):
    """A law of kind `kind` (and saturation `scale` for `"sat"`) with `coefficients` at the
    command `i` (`xp` = np or jnp): the one evaluation of every law."""
    if kind == "sat":
        return coefficients[0] + coefficients[1] * (1.0 - xp.exp(-i / scale))
    p = horner(coefficients, i, xp)
    return xp.exp(p) if kind == "exp" else p


@dataclasses.dataclass(frozen=True)
class Law:
    """A parameter as a function of the coil current i [A].

    **Fields:**

    - `kind`: `"poly"`, $p(i) = \\sum_m a_m i^m$, `"exp"`, $p(i) = \\exp(\\sum_m a_m i^m)$
        ($\\exp(a + b\\,i)$ at degree 1), or `"sat"`, $p(i) = a_0 + a_1 (1 - e^{-i/s})$ (a
        change $a_1$ that saturates above a few times the current $s$).
    - `coefficients`: $a_0, a_1, \\dots$ in ascending powers of i, SI units of the parameter
        per $A^m$ (`"poly"`) or of its logarithm (`"exp"`); for `"sat"` $a_0, a_1$ in the
        parameter's units.
    - `scale`: $s$ of a `"sat"` law, in the command's unit (A or V); None for the others.

    Calling a law evaluates it: NumPy in, NumPy out; JAX in (also traced), JAX out.
    """

    kind: str
    coefficients: tuple[float, ...]
    scale: float | None = None

    def __post_init__(self):
        if self.kind not in LAW_KINDS:
            raise InputError(f"law kind must be one of {list(LAW_KINDS)}, got {self.kind!r}")
        if self.kind == "sat":
            s = self.scale
            if isinstance(s, bool) or not isinstance(s, (int, float, np.floating)) \
                    or not (math.isfinite(s) and s > 0):
                raise InputError(f"a 'sat' law needs a positive scale, got {s!r}")
            object.__setattr__(self, "scale", float(s))
            if len(np.ravel(self.coefficients)) != 2:
                raise InputError(f"a 'sat' law has 2 coefficients, got "
                                 f"{len(np.ravel(self.coefficients))}")
        elif self.scale is not None:
            raise InputError(f"only a 'sat' law has a scale, not {self.kind!r}")
        try:
            coef = tuple(float(c) for c in np.asarray(self.coefficients, float).ravel())
        except (TypeError, ValueError):
            raise InputError(f"law coefficients must be numbers, got {self.coefficients!r}") \
                from None
        if not coef:
            raise InputError("a law needs at least one coefficient")
        if not all(math.isfinite(c) for c in coef):
            raise InputError(f"law coefficients must be finite, got {list(coef)}")
        object.__setattr__(self, "coefficients", coef)

    @property
    def degree(self) -> int:
        """Polynomial degree (in i, or in the exponent for `"exp"`; 1 for `"sat"`)."""
        return len(self.coefficients) - 1

    @property
    def form(self) -> str:
        """The law's form in words: `"poly2"`, `"exp1"`, `"sat(0.5)"`."""
        return f"sat({self.scale:g})" if self.kind == "sat" else f"{self.kind}{self.degree}"

    def __call__(self, current):
        """Value of the law at `current` [A] (any shape)."""
        xp = jnp if isinstance(current, jax.Array) else np
        i = current if xp is jnp else np.asarray(current, dtype=float)
        return law_value(self.kind, self.scale or 1.0, self.coefficients, i, xp)

    def formula(self, var: str = "i") -> str:
        """Readable formula, e.g. `'1232 + 1929*i'`, `'exp(4.6 - 0.2*i)'` or
        `'120 + 1100*(1 - exp(-i/0.5))'`."""
        if self.kind == "sat":
            a, b = self.coefficients
            return (f"{a:.6g} {'-' if b < 0 else '+'} {abs(b):.6g}*(1 - exp(-{var}/"
                    f"{self.scale:g}))")
        terms = []
        for m, a in enumerate(self.coefficients):
            mag = f"{abs(a):.6g}"
            t = mag if m == 0 else (f"{mag}*{var}" if m == 1 else f"{mag}*{var}^{m}")
            terms.append(("-" if a < 0 else "+", t))
        s = ("-" if terms[0][0] == "-" else "") + terms[0][1]
        for sign, t in terms[1:]:
            s += f" {sign} {t}"
        return f"exp({s})" if self.kind == "exp" else s

    def to_dict(self) -> dict[str, Any]:
        """`{"law": kind, "degree": d, "coefficients": [a0, a1, ...]}`, and `"scale"` of a
        `"sat"` law."""
        d = {"law": self.kind, "degree": self.degree, "coefficients": list(self.coefficients)}
        if self.kind == "sat":
            d["scale"] = self.scale
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], name: str = "law") -> Law:
        """Inverse of :meth:`to_dict`; raises :class:`mrjax.InputError` naming `name`."""
        if not isinstance(d, Mapping) or "coefficients" not in d:
            raise InputError(f"law of {name!r} must be an object with 'law' and 'coefficients'")
        scale = d.get("scale")
        law = cls(str(d.get("law", "poly")), d["coefficients"],
                  None if scale is None else float(scale))
        if "degree" in d and d["degree"] is not None and int(d["degree"]) != law.degree:
            raise InputError(f"law of {name!r}: degree {d['degree']} does not match "
                             f"{len(law.coefficients)} coefficients")
        return law


class LawSet(eqx.Module):
    """All laws of a model as one traceable function: `coef` (V,) concatenated coefficients,
    `kinds`, `sizes` (number of coefficients) and `scales` (of `"sat"` laws, else 1) per
    parameter, static."""

    coef: Float[Array, " V"]
    kinds: tuple[str, ...] = eqx.field(static=True)
    sizes: tuple[int, ...] = eqx.field(static=True)
    scales: tuple[float, ...] = eqx.field(static=True, default=())

    def __call__(self, current: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape P"]:
        i = jnp.asarray(current, dtype=self.coef.dtype)
        scales = self.scales or (1.0,) * len(self.kinds)
        cols, o = [], 0
        for kind, s, sc in zip(self.kinds, self.sizes, scales):
            cols.append(law_value(kind, sc, [self.coef[o + m] for m in range(s)], i, jnp))
            o += s
        return jnp.stack(cols, axis=-1)


# ------------------------------------------------------------------------------ helpers
def lag_current(
    current: Float[ArrayLike, " T"], dt: Float[ArrayLike, "*T"], eta: Float[ArrayLike, ""]
) -> Float[Array, " T"]:
    """First-order current lag $\\dot u = -\\eta (u - i)$, discretized exactly per sample.

    With the current held at $i_k$ over the interval $\\Delta t_k$ after sample k:
    $u_{k+1} = i_k + (u_k - i_k)\\,e^{-\\eta \\Delta t_k}$, $u_0 = i_0$.

    **Arguments:** `current` commanded current [A] (T,); `dt` interval after each sample [s],
    scalar or (T,); `eta` lag rate [1/s] (Spencer et al. 1997: 190 1/s). Jittable.

    **Returns:** the effective current u [A], shape (T,).
    """
    i = jnp.asarray(current, dtype=float)
    a = jnp.exp(-jnp.asarray(eta, dtype=float) * jnp.broadcast_to(jnp.asarray(dt, float), i.shape))

    def step(u, inp):
        ik, ak = inp
        return ik + (u - ik) * ak, u

    _, u = jax.lax.scan(step, i[0], (i, a))
    return u


def default_degrees(model: str | AbstractModel, n_currents: int | None = None, *,
                    unit: str = "A") -> dict[str, int]:
    """Default polynomial degree of each parameter's law.

    - `"kwok"`: the paper's (eq 24-29): c, k, delta, f0 linear; alpha quadratic; beta constant.
    - The other built-in models follow the same idea and Spencer et al. (1997), who make the
        modified Bouc-Wen c0, c1 and alpha linear in the command and keep every other parameter
        constant: the force scales (damping, stiffness, offset) are linear in the current, the
        yield or hysteretic force (`alpha`, Bingham's `fc`) is quadratic (it saturates with
        the magnetic field, like the paper's alpha), and the *shape* of the hysteresis
        (Bouc-Wen delta, beta, gamma, n on the |z|max = 1 scale; Dahl rho) is constant. The
        modified Bouc-Wen keeps Spencer's constant k0, k1 and f0 (= -k1 x0). Letting the shape
        parameters follow the current as well makes these strongly nonlinear models interpolate
        badly between measured currents (`benchmarks/defaults.md`).
    - Any other model: the degrees it declares (`AbstractModel.law_degrees`, e.g.
        `mrjax.models.Parameter(..., degree=0)`), else degree 1, and 2 for `alpha`.
    - With `unit="V"` (laws of a command voltage) the modified Bouc-Wen takes Spencer's 1997
        voltage laws exactly: c0, c1 and alpha linear, every other parameter constant
        (the model's `voltage_law_degrees`); the other models keep the table above.

    With `n_currents` given (the number of distinct command levels), degrees are capped at
    `n_currents - 1`.
    """
    model = get(model)
    if unit not in COMMAND_UNITS:
        raise InputError(f"command unit must be one of {list(COMMAND_UNITS)}, got {unit!r}")
    deg = {n: (2 if n == "alpha" else 1) for n in model.param_names}
    deg.update(model.law_degrees)  # what the model says of its own parameters
    if unit == "V":
        deg.update(model.voltage_law_degrees)
    if n_currents is not None:
        deg = {n: min(d, max(int(n_currents) - 1, 0)) for n, d in deg.items()}
    return deg


def canonical_z_scale(model: AbstractModel, theta: ArrayLike) -> np.ndarray:
    """Map Bouc-Wen / modified Bouc-Wen parameters (..., P) to the equivalent set (same force)
    with $|z|_{max} = (\\delta/(\\beta+\\gamma))^{1/n} = 1$; other models pass unchanged.

    With $s = (\\delta/(\\beta+\\gamma))^{-1/n}$: $\\delta \\to s\\delta$,
    $\\beta, \\gamma \\to s^{1-n}\\beta, s^{1-n}\\gamma$, $\\alpha \\to \\alpha/s$. Rows with
    $\\beta + \\gamma \\le 0$ or $\\delta \\le 0$ are left as they are.
    """
    sym = model.scale_symmetry
    if sym is None:
        return np.array(theta, dtype=float, copy=True)
    return sym.canonical(theta, model.param_names)


def group_currents(cur: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct currents (U,) (within `CURRENT_TOL`) and each condition's group index (C,)."""
    order = np.argsort(cur, kind="stable")
    ids = np.zeros(cur.shape[0], int)
    levels: list[list[float]] = []
    for j in order:
        if levels and abs(cur[j] - levels[-1][0]) <= CURRENT_TOL:
            levels[-1].append(cur[j])
        else:
            levels.append([cur[j]])
        ids[j] = len(levels) - 1
    return np.array([np.mean(v) for v in levels]), ids


def fit_space(theta: np.ndarray, exp_cols: np.ndarray) -> np.ndarray:
    """Parameters in the space their law is polynomial in: log for "exp" laws."""
    e = exp_cols[None, :]
    return np.where(e, np.log(np.abs(np.where(e, theta, 1.0))), theta)


def vander(i: np.ndarray, size: int, kind: str = "poly", scale: float = 1.0) -> np.ndarray:
    """(len(i), size) design of a law at the commands `i`: the Vandermonde matrix in ascending
    powers, or the `"sat"` basis (:func:`law_basis`)."""
    i = np.asarray(i, float)
    return np.stack(law_basis(kind, scale, i, size, np), axis=-1)


def nodes(lo: float, hi: float, size: int) -> np.ndarray:
    """`size` interpolation nodes [A] spread over [lo, hi] (the mid-point for one)."""
    if size == 1:
        return np.array([0.5 * (lo + hi)])
    return np.linspace(lo, hi, size)
