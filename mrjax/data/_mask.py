"""The samples a fit scores: a batch's mask, a user's mask, and the initial transient left out."""

from __future__ import annotations

import jax
import numpy as np
from jaxtyping import Array, ArrayLike, Bool

from .._errors import InputError
from ._condition import Batch


def check_mask(batch: Batch, mask: ArrayLike | None) -> np.ndarray:
    """Host-side scored-sample mask: `batch.mask` and a user `mask` of the batch shape (C, T).

    Raises :class:`mrjax.InputError` for a mask of the wrong shape.
    """
    base = np.asarray(batch.mask, bool)
    if mask is None:
        return base
    m = np.asarray(mask)
    if m.shape != base.shape:
        raise InputError(f"mask must have the batch shape {base.shape}, got {m.shape}")
    return m.astype(bool) & base


def fit_mask(batch: Batch, transient: float | str | None = None) -> Bool[Array, "C T"]:
    """The samples a fit scores: the batch mask, optionally without an initial transient.

    **Arguments:**

    - `batch`: the conditions.
    - `transient`: `None` (keep all), a time span [s] to drop from the start of each
        condition, or `"cycle"` to drop the first excitation cycle (needs the frequency).
    """
    mask = np.asarray(batch.mask)
    if transient is None:
        return batch.mask
    t = np.asarray(batch.t) - np.asarray(batch.t)[:, :1]
    if isinstance(transient, str):
        if transient != "cycle":
            raise InputError(f"transient must be a time in s, 'cycle' or None, got {transient!r}")
        freq = np.asarray(batch.frequency)
        if np.any(~np.isfinite(freq)) or np.any(freq <= 0):
            raise InputError("transient='cycle' needs the frequency of every condition")
        span = 1.0 / freq
    else:
        span = np.full(batch.n_conditions, float(transient))
        if not np.all(np.isfinite(span)) or np.any(span < 0):
            raise InputError(f"transient must be a non-negative time in s, got {transient!r}")
    keep = mask & (t >= span[:, None])
    short = np.flatnonzero(keep.sum(axis=1) < 3)
    if short.size:
        raise InputError(
            f"condition {batch.labels[short[0]]!r}: fewer than 3 samples remain after dropping "
            f"the transient ({transient!r})"
        )
    return jax.device_put(keep)
