"""Argument checks shared by the polish and the uncertainty (host side)."""

from __future__ import annotations

import jax
import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ..models import AbstractModel


def require_x64() -> None:
    """Raise unless JAX runs in float64 (the polish and std-errors need it)."""
    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            "mrjax.refine needs float64: enable jax_enable_x64 (do not set MRJAX_X64=0)"
        )


def as_theta(model: AbstractModel, theta: ArrayLike, C: int, what: str) -> np.ndarray:
    """`theta` as a finite (C, P) float array ((P,) is broadcast); InputError naming `what`."""
    th = np.asarray(theta, dtype=float)
    P = model.n_params
    if th.ndim == 1:
        th = np.broadcast_to(th, (C, th.shape[0]))
    if th.shape != (C, P):
        raise InputError(
            f"{what} must have shape ({C}, {P}) (conditions x parameters {list(model.param_names)})"
            f" or ({P},), got {np.shape(theta)}"
        )
    if not np.all(np.isfinite(th)):
        i, j = np.argwhere(~np.isfinite(th))[0]
        raise InputError(f"{what}[{i}, {j}] ({model.param_names[j]}) is not finite: {th[i, j]}")
    return np.array(th)


def as_free(model: AbstractModel, free) -> np.ndarray:
    """(P,) bool mask of the free parameters from a mask, names or None (all free)."""
    P = model.n_params
    if free is None:
        return np.ones(P, bool)
    if isinstance(free, str):
        free = [free]
    items = list(np.asarray(free).tolist()) if not isinstance(free, list | tuple) else list(free)
    if items and all(isinstance(f, str) for f in items):
        unknown = [f for f in items if f not in model.param_names]
        if unknown:
            raise InputError(f"free names unknown parameters {unknown} of model {model.name!r}; "
                             f"expected some of {list(model.param_names)}")
        return np.array([n in items for n in model.param_names])
    f = np.asarray(free)
    if f.shape != (P,) or f.dtype != bool:
        raise InputError(f"free must be a ({P},) bool mask or parameter names, got {free!r}")
    return f.copy()
