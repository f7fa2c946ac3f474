"""Statistics over the conditions that skip non-finite values (a diverged fit is `inf`)."""

from __future__ import annotations

import numpy as np


def finite_median(a) -> float:
    """Median of the finite values of `a`; NaN when there is none."""
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else float("nan")


def finite_mean(a) -> float:
    """Mean of the finite values of `a`; NaN when there is none."""
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.mean(a)) if a.size else float("nan")
