"""The form of each parameter's law over the current: given by the user (`degrees`, `laws`), the
model's defaults, or chosen by the data (`laws="auto"`, :func:`choose_forms`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from .._errors import InputError
from ..models import AbstractModel
from ._laws import SAT_SCALES, group_currents, law_value, vander
from ._two_step import law_spec

#: The candidate forms of `laws="auto"`, in the order of preference among equals.
AUTO_FORMS: tuple[str, ...] = ("poly0", "poly1", "exp1", "poly2", "sat")
#: Relative residual of a law below which the per-test values count as fitted exactly.
RESOLUTION = 1e-6


@dataclasses.dataclass(frozen=True)
class LawForms:
    """The form of every parameter's law: `kinds` (`"poly"`, `"exp"`, `"sat"`), `degrees`,
    `scales` (the saturation command of a `"sat"` law, in the command unit; 1 elsewhere) per
    parameter, and for laws chosen by the data `criteria`: parameter name -> {form: BIC}
    of every candidate (`"poly2"`, `"sat(0.5)"`, ...; inf where not applicable)."""

    kinds: tuple[str, ...]
    degrees: tuple[int, ...]
    scales: tuple[float, ...]
    criteria: dict[str, dict[str, float]] | None = None

    @property
    def sizes(self) -> tuple[int, ...]:
        """Coefficients per law."""
        return tuple(d + 1 for d in self.degrees)

    def form(self, p: int) -> str:
        """The form of law `p` in words: `"poly2"`, `"exp1"`, `"sat(0.5)"`."""
        k = self.kinds[p]
        return f"sat({self.scales[p]:g})" if k == "sat" else f"{k}{self.degrees[p]}"


def _fit(kind: str, degree: int, scale: float, i: np.ndarray, y: np.ndarray,
         w: np.ndarray) -> np.ndarray:
    """Coefficients of a law fitted to values `y` at currents `i`: weighted least squares with
    weights `w` on the residuals (an `"exp"` law: least squares of the logarithm)."""
    X = vander(i, degree + 1, kind, scale)
    if kind == "exp":
        return np.linalg.lstsq(X, np.log(y), rcond=None)[0]
    return np.linalg.lstsq(X * w[:, None], y * w, rcond=None)[0]


def _bic(rss: float, n: int, k: int) -> float:
    """The Bayesian information criterion of a Gaussian fit with `k` unknowns to `n` values
    (`inf` without a residual degree of freedom)."""
    if not (math.isfinite(rss) and rss > 0) or n - k - 1 <= 0:
        return math.inf
    return n * math.log(rss / n) + k * math.log(n)


def candidates(i: np.ndarray, y: np.ndarray, n_currents: int, span: float
               ) -> dict[str, tuple[float, str, int, float]]:
    """Every candidate law of one parameter with per-test values `y` at currents `i`:
    form -> `(BIC, kind, degree, scale)`.

    Each candidate is fitted by least squares (a `"sat"` law for each scale of `SAT_SCALES` x
    `span`, the best kept, its scale counted as an unknown) and scored on the residuals it was
    fitted to: relative, $(y - p(i))/y$, where every value is positive (an `"exp"` law is
    fitted to the logarithm, whose residual is the relative one to first order), else
    absolute. A form needs at least as many distinct currents as unknowns; `"exp"` positive
    values.
    """
    positive = bool(np.all(y > 0))
    w = 1.0 / y if positive else np.ones_like(y)
    n = y.size
    # residuals below RESOLUTION (relative) are rounding: a constant (e.g. a parameter on its
    # bound in every test) is not "explained" better by a curve through its last bits
    floor = n * (RESOLUTION * (1.0 if positive else float(np.max(np.abs(y)) or 1.0))) ** 2
    out: dict[str, tuple[float, str, int, float]] = {}

    def score(kind, degree, scale):
        pred = law_value(kind, scale, _fit(kind, degree, scale, i, y, w), i, np)
        r = (y - pred) * w
        return float(np.sum(r * r)) + floor if np.all(np.isfinite(r)) else math.inf

    for d in range(3):
        if d + 1 <= n_currents:
            out[f"poly{d}"] = (_bic(score("poly", d, 1.0), n, d + 1), "poly", d, 1.0)
    if positive and n_currents >= 2:
        out["exp1"] = (_bic(score("exp", 1, 1.0), n, 2), "exp", 1, 1.0)
    if n_currents >= 3 and span > 0:  # a, b and the scale
        best = min(((score("sat", 1, f * span), f * span) for f in SAT_SCALES),
                   key=lambda t: t[0])
        out[f"sat({best[1]:g})"] = (_bic(best[0], n, 3), "sat", 1, best[1])
    return out


def choose_forms(model: AbstractModel, theta: np.ndarray | None, current: np.ndarray | None,
                 degrees: Mapping[str, int] | int | None, laws: Mapping[str, str] | str | None,
                 n_currents: float, unit: str = "A") -> LawForms:
    """The law forms of a generalization.

    - `laws="auto"`: per parameter the form with the lowest BIC (:func:`candidates`) of the
        per-test values `theta` (C, P) (z-scale normalised) at their currents `current` (C,),
        among polynomial degree 0-2, exponential ($\\exp(a + b\\,i)$) and saturating
        ($a + b(1 - e^{-i/s})$); the earlier of `AUTO_FORMS` among equals (within 1e-9).
        Parameters named in `degrees` keep a polynomial of that degree.
    - `laws="fixed"` (or None) or a mapping of parameter names to kinds: the user's `degrees`
        and kinds on the model's defaults (`law_spec`, `default_degrees`); a `"sat"` law's
        scale is chosen by least squares on the per-test values (the scale of `SAT_SCALES` x
        the current range with the lowest residual).

    **Arguments:** `n_currents` distinct command levels (`math.inf` for a time-varying
    command, where `"auto"` and `"sat"` are not available: they need per-test values).

    Raises :class:`mrjax.InputError` for unknown names, bad kinds or too high a degree.
    """
    names = model.param_names
    if isinstance(laws, str):
        if laws not in ("auto", "fixed"):
            raise InputError(f"laws must be 'auto', 'fixed' or a mapping of parameter names to "
                             f"kinds, got {laws!r}")
        auto = laws == "auto"
        laws = None
    else:
        auto = False
    if laws is not None and not isinstance(laws, Mapping):
        raise InputError(f"laws must be 'auto', 'fixed' or a mapping of parameter names to "
                         f"kinds, got {laws!r}")
    if auto or (laws and "sat" in dict(laws).values()):
        if theta is None or current is None:
            raise InputError("laws='auto' and 'sat' laws are chosen from per-test fits at "
                             "constant currents: use mrjax.generalize.generalize")
    fixed = {} if (not auto or degrees is None) else (
        {n: int(degrees) for n in names} if isinstance(degrees, int | np.integer)
        else dict(degrees))
    kinds, degs = law_spec(model, degrees, laws, n_currents, unit)
    scales = [1.0] * len(names)
    criteria: dict[str, dict[str, float]] | None = None
    if theta is not None and current is not None:
        i = np.asarray(current, float)
        levels, _ = group_currents(i)
        span = float(np.ptp(levels)) if levels.size else 0.0
        kinds, degs = list(kinds), list(degs)
        if auto:
            criteria = {}
        for p, n in enumerate(names):
            y = np.asarray(theta[:, p], float)
            if auto and n not in fixed:
                cand = candidates(i, y, levels.size, span)
                criteria[n] = {f: c[0] for f, c in cand.items()}
                order = sorted(cand, key=lambda f: (round(cand[f][0], 9),
                                                    AUTO_FORMS.index(f.split("(")[0])))
                _, kinds[p], degs[p], scales[p] = cand[order[0]]
            elif kinds[p] == "sat":
                cand = candidates(i, y, levels.size, span)
                key = next((f for f in cand if f.startswith("sat")), None)
                if key is None:
                    raise InputError(f"law 'sat' of {n!r}: no saturating law fits its values")
                scales[p] = cand[key][3]
    return LawForms(tuple(kinds), tuple(degs), tuple(scales), criteria)


def forms_choice(forms: LawForms) -> dict[str, Any]:
    """The `mrjax.generalize.LawReport` fields of the law forms: `law_choice` and, for forms
    chosen by the data, `law_criteria` (name -> {form: BIC})."""
    if forms.criteria is None:
        return {"law_choice": "given"}
    return {"law_choice": "auto (lowest BIC of the per-test values)",
            "law_criteria": forms.criteria}
