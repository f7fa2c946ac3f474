"""Sanity checks that catch the classic unit mistakes of a test record.

- **Velocity against displacement.** A measured velocity should equal the derivative of the
    displacement. If it is a constant multiple of it (least-squares ratio away from 1 by more
    than 1.5x, correlation above 0.9), a unit was probably mixed up; the message names the
    nearest of the usual factors (10, 100, 1000, 25.4, 2.54 and their inverses: cm/mm, m/cm,
    m/mm, in/mm, in/cm) and the units that give it. An opposite sign is reported too. The
    ratio is taken between the *integral* of the measured velocity (trapezoid rule on the
    sample times) and the displacement, an offset and a linear drift removed from both: the
    same ratio as velocity to the derivative of displacement, without differentiating the
    displacement's noise, in O(T) (a fleet's thousands of records are checked as they load).
- **Displacement range.** A damper stroke spans roughly 0.1 mm to 1 m; a displacement that
    spans more than 1 m or less than 10 um peak to peak is probably in the wrong unit (the
    lower bound only for records of at least one period of their known frequency: a shorter
    record may well move little).

:func:`check_condition` returns the messages; the loaders issue them as `RuntimeWarning`s
naming the file and keep them in `Condition.warnings`.
"""

from __future__ import annotations

import math

import numpy as np

from ._condition import Condition

#: Largest and smallest plausible displacement span (peak to peak) of a damper test [m].
STROKE_RANGE_M: tuple[float, float] = (1e-5, 1.0)
#: Ratios of measured velocity to the derivative of displacement still taken as agreement.
_AGREE = 1.5
#: Usual unit factors and the (larger, smaller) unit pairs that give them.
_FACTORS: dict[float, tuple[str, str]] = {
    10.0: ("cm", "mm"), 100.0: ("m", "cm"), 1000.0: ("m", "mm"), 25.4: ("in", "mm"),
    2.54: ("in", "cm"), 39.37007874015748: ("m", "in"),
}


def _factor_hint(ratio: float) -> str:
    """Which usual factor `ratio` (measured / derivative, > 0, not ~1) is, and its units."""
    big = ratio > 1.0
    r = ratio if big else 1.0 / ratio
    best = min(_FACTORS, key=lambda f: abs(math.log(r / f)))
    if abs(math.log(r / best)) > math.log(1.15):
        return "not a usual unit factor; check the units of both"
    large, small = _FACTORS[best]
    if big:
        return (f"likely a factor {best:g}: velocity in {small}/s given as {large}/s, or "
                f"displacement in {large} given as {small}?")
    return (f"likely a factor 1/{best:g}: velocity in {large}/s given as {small}/s, or "
            f"displacement in {small} given as {large}?")


def _ratio(t: np.ndarray, x: np.ndarray, xdot: np.ndarray) -> tuple[float, float] | None:
    """`(ratio, correlation)` of the measured velocity to the derivative of the displacement,
    or None when the record is too short or the motion too small to tell (fewer than 16
    samples, or no displacement signal).

    The ratio is the least-squares ratio of the integral of the velocity to the displacement
    (see the module notes), both with their offset and linear drift removed; the correlation
    is theirs.
    """
    with np.errstate(over="ignore", invalid="ignore"):  # absurd values: no ratio, no noise
        got = _ratio_of(t, x, xdot)
    return got if got is not None and all(map(math.isfinite, got)) else None


def _ratio_of(t: np.ndarray, x: np.ndarray, xdot: np.ndarray) -> tuple[float, float] | None:
    if t.shape[0] < 16 or not np.ptp(x) > 0:
        return None
    t = t - t[0]
    moved = np.concatenate([[0.0], np.cumsum(0.5 * (xdot[1:] + xdot[:-1]) * np.diff(t))])
    tc = t - t.mean()
    tt = float(np.dot(tc, tc))

    def residual(a: np.ndarray) -> np.ndarray:  # a less its offset and linear drift
        a = a - a.mean()
        return a - tc * (float(np.dot(tc, a)) / tt)

    x, m = residual(x), residual(moved)
    xx, mm = float(np.dot(x, x)), float(np.dot(m, m))
    if not (xx > 0 and mm > 0):
        return None
    xm = float(np.dot(x, m))
    return xm / xx, xm / math.sqrt(xx * mm)


def check_condition(cond: Condition) -> list[str]:
    """The sanity checks of one condition (see the module notes).

    **Arguments:** `cond`: a :class:`Condition` (SI units).

    **Returns:** one line per problem found (empty if none), without the file name.
    """
    return check_record(cond.t, cond.x, None if "xdot" in cond.estimated else cond.xdot,
                        cond.frequency)


def check_record(t: np.ndarray, x: np.ndarray, xdot: np.ndarray | None,
                 frequency: float | None) -> list[str]:
    """:func:`check_condition` on the arrays of a record (SI): `xdot` None where the velocity
    was estimated (then not checked against the displacement)."""
    out = []
    with np.errstate(over="ignore", invalid="ignore"):
        span = float(np.ptp(x))
    lo, hi = STROKE_RANGE_M
    if span > hi:
        out.append(
            f"displacement spans {span:.4g} m peak to peak, more than a damper stroke: is its "
            f"unit right (mm given as m?)"
        )
    elif span < lo and (frequency is None or frequency * float(t[-1] - t[0]) >= 1.0):
        out.append(
            f"displacement spans {span:.3g} m peak to peak, less than {lo * 1e6:g} um: is its "
            f"unit right (m given as mm?)"
        )
    if xdot is not None:
        got = _ratio(t, x, xdot)
        if got is not None:
            ratio, corr = got
            if corr < -0.9:
                out.append(
                    f"measured velocity has the opposite sign of the derivative of the "
                    f"displacement (ratio {ratio:.3g}): is one of them inverted?"
                )
            elif corr > 0.9 and not (1.0 / _AGREE < ratio < _AGREE):
                out.append(
                    f"measured velocity is {ratio:.3g} x the derivative of the displacement: "
                    f"{_factor_hint(ratio)}"
                )
    return out
