"""The one bounds check of mrjax: a model's search box, validated once, for every optimiser.

Bounds live with the model (`AbstractModel.bounds`); a fit may override them by name or as
arrays. :func:`check_bounds` is the only place that validates them (the swarm, the polish, the
joint generalization and the command line all call it), and :func:`box_corners` gives the
corners of a box (the stiffest points for the built-in models' monotone stiffness bounds).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ._base import AbstractModel

#: What :func:`check_bounds` accepts for one side: `None` (the model's default), a (P,) array,
#: or a mapping from parameter name to value (the others keep their default).
Side = ArrayLike | Mapping[str, float] | None


def check_bounds(
    model: AbstractModel, bounds: tuple[Side, Side] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Validate `(lower, upper)` for `model` and return them as float arrays of shape (P,).

    **Arguments:**

    - `model`: the model whose parameters are bounded.
    - `bounds`: `None` (the model's default box), or a pair `(lower, upper)` where each side is
        `None` (the default), a (P,) array in `param_names` order, or a dict by parameter name
        (missing names keep their default). SI units.

    **Returns:** `(lower, upper)`, two new float arrays of shape (P,).

    Raises :class:`mrjax.InputError` naming the parameter for an unknown name, a wrong shape,
    a non-finite value or lower > upper.
    """
    d_lo, d_hi = model.bounds
    if bounds is None:
        return d_lo, d_hi
    try:
        lo, hi = bounds
    except (TypeError, ValueError):
        raise InputError("bounds must be a pair (lower, upper)") from None
    lo = _side(model, lo, d_lo)
    hi = _side(model, hi, d_hi)
    P = model.n_params
    if lo.shape != (P,) or hi.shape != (P,):
        raise InputError(
            f"bounds for model {model.name!r} need {P} values each {list(model.param_names)}, "
            f"got shapes {lo.shape} and {hi.shape}"
        )
    check_box(lo, hi, names=model.param_names)
    return lo, hi


def check_box(lower: ArrayLike, upper: ArrayLike, *, names: Sequence[str] | None = None,
              what: str = "bounds") -> None:
    """Raise :class:`mrjax.InputError` unless `lower <= upper` elementwise and both are finite.

    **Arguments:** `lower`, `upper` broadcastable arrays (a box of shape (D,) or (C, D));
    `names` (D,) names of the last axis for the message (e.g. parameter names), else the
    dimension index is named; `what` what the box is, for the message.
    """
    lo, hi = np.broadcast_arrays(np.asarray(lower, float), np.asarray(upper, float))

    def where(i) -> str:
        d = i[-1] if len(i) else 0
        return f"of parameter {names[d]!r}" if names is not None else f"in dimension {d}"

    bad = np.argwhere(~(np.isfinite(lo) & np.isfinite(hi)))
    if bad.size:
        i = tuple(bad[0])
        raise InputError(f"{what} {where(i)} must be finite, got [{lo[i]}, {hi[i]}]")
    bad = np.argwhere(lo > hi)
    if bad.size:
        i = tuple(bad[0])
        raise InputError(f"{what} {where(i)} are inverted: lower {lo[i]:g} > upper {hi[i]:g}")


def _side(model: AbstractModel, side: Side, default: np.ndarray) -> np.ndarray:
    if side is None:
        return default.copy()
    if isinstance(side, Mapping):
        unknown = [k for k in side if k not in model.param_names]
        held = [k for k in unknown if k in model.fixed]
        if held:
            raise InputError(f"parameter {held[0]!r} of model {model.name!r} is fixed at "
                             f"{model.fixed[held[0]]:g}: it has no bounds")
        if unknown:
            raise InputError(f"bounds name unknown parameter {unknown[0]!r} of model "
                             f"{model.name!r}; its parameters: {', '.join(model.param_names)}")
        return np.array([side.get(n, default[i]) for i, n in enumerate(model.param_names)],
                        float)
    try:
        return np.array(side, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"bounds of model {model.name!r} must be numbers, got {side!r}") \
            from None


def box_corners(model: AbstractModel, lower: ArrayLike, upper: ArrayLike) -> np.ndarray:
    """Corners of the box over the *nonlinear* parameters (linear ones at mid-range), (K, P).

    The linear parameters never enter an ODE, so for the monotone stiffness bounds of the
    built-in models the stiffest point of a box is among these rows.
    """
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    nl = model.nonlinear_index
    mid = 0.5 * (lo + hi)
    if nl.size == 0:
        return mid[None]
    bits = (np.arange(2 ** nl.size)[:, None] >> np.arange(nl.size)[None, :]) & 1
    rows = np.repeat(mid[None], bits.shape[0], axis=0)
    rows[:, nl] = np.where(bits, hi[nl], lo[nl])
    return rows
