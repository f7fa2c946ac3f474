"""Which tests train the current-dependent laws and which score them: the validation plan of
`mrjax.compare` (other files, tests held out by current, K folds, or leave-one-current-out)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .._errors import InputError
from ..data import Batch
from ..generalize import CURRENT_TOL, group_currents


@dataclasses.dataclass(frozen=True)
class Fold:
    """One split: the generalized laws are built on `train` and scored on `test`.

    **Fields:** `name` (e.g. `"I=0.25A"`, `"fold 2/5"`); `train` indices of the compared
    tests; `test` indices of the held-out tests, into the compared tests or, for
    `scheme == "validate"`, into the validation tests.
    """

    name: str
    train: np.ndarray
    test: np.ndarray


@dataclasses.dataclass(frozen=True)
class Plan:
    """The validation plan: `scheme` (`"validate"`, `"hold-out"`, `"folds"`,
    `"leave-one-current-out"` or `"none"`), a one-line `description`, and the `folds`."""

    scheme: str
    description: str
    folds: tuple[Fold, ...]


def _currents(batch: Batch, what: str, purpose: str) -> np.ndarray:
    cur = np.asarray(batch.current, float)
    bad = np.flatnonzero(~np.isfinite(cur))
    if bad.size:
        raise InputError(f"{what} {batch.labels[bad[0]]!r} has no current; {purpose} needs the "
                         f"current of every test (held-out laws are functions of the current)")
    return cur


def _fmt_currents(values) -> str:
    return ", ".join(f"{v:g}" for v in values)


def _hold_out_currents(hold_out: Any) -> list[float]:
    if not isinstance(hold_out, Mapping):
        raise InputError(f"hold_out must be a mapping such as {{'current': [0.25, 0.75]}}, got "
                         f"{hold_out!r}")
    unknown = sorted(str(k) for k in hold_out if k != "current")
    if unknown:
        raise InputError(f"hold_out can select tests by 'current' only, got {unknown[0]!r}")
    if "current" not in hold_out:
        raise InputError("hold_out needs a 'current' entry, e.g. {'current': [0.25, 0.75]}")
    values = hold_out["current"]
    if isinstance(values, (int, float)) and not isinstance(values, bool):
        values = [values]
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        raise InputError(f"hold_out currents must be numbers in A, got {values!r}") from None
    if not out:
        raise InputError("the hold-out set is empty: give at least one current to hold out")
    if not all(math.isfinite(v) for v in out):
        raise InputError(f"hold_out currents must be finite, got {_fmt_currents(out)}")
    return out


def plan_validation(
    batch: Batch,
    *,
    validate: Batch | None = None,
    hold_out: Mapping[str, Sequence[float]] | None = None,
    folds: int | str | None = None,
    seed: int = 0,
    enabled: bool = True,
) -> Plan:
    """Decide the held-out validation of `mrjax.compare` (see its docstring).

    **Arguments:** `batch` the compared tests; at most one of `validate` (a batch of other
    tests), `hold_out` (`{"current": [A, ...]}`: the tests at those currents are held out)
    and `folds` (an integer K >= 2: K folds over the tests, assigned by a permutation seeded
    with `seed`; or `"current"`: leave one current out). With none of them, leave one current
    out when every test's current is known and there are at least two currents, else no
    validation. `enabled=False` (no generalization method asked) gives no validation.

    **Returns:** a :class:`Plan`.

    Raises :class:`mrjax.InputError` (one line) for two options at once, an empty hold-out
    or training set, a hold-out current no test has, a test without current where one is
    needed, or a bad fold count.
    """
    given = [n for n, v in (("validate", validate), ("hold_out", hold_out), ("folds", folds))
             if v is not None]
    if len(given) > 1:
        raise InputError(f"give one of validate, hold_out or folds, not {' and '.join(given)}")
    C = batch.n_conditions
    everything = np.arange(C)
    if not enabled:
        return Plan("none", "no held-out validation (no generalization method)", ())
    if validate is not None:
        _currents(batch, "test", "validation on other tests")
        _currents(validate, "validation test", "validation on other tests")
        return Plan("validate", f"laws from all {C} tests, scored on {validate.n_conditions} "
                    "validation tests", (Fold("validate", everything,
                                              np.arange(validate.n_conditions)),))
    if hold_out is not None:
        wanted = _hold_out_currents(hold_out)
        cur = _currents(batch, "test", "a hold-out by current")
        held = np.zeros(C, bool)
        for v in wanted:
            hit = np.abs(cur - v) <= CURRENT_TOL
            if not hit.any():
                levels, _ = group_currents(cur)
                raise InputError(f"the hold-out set is empty at {v:g} A: no test has that current "
                                 f"(currents in the data: {_fmt_currents(levels)} A)")
            held |= hit
        if held.all():
            raise InputError("the training set is empty: every test is held out; hold out "
                             "fewer currents")
        return Plan("hold-out", f"laws from {int((~held).sum())} tests, scored on the "
                    f"{int(held.sum())} tests at {_fmt_currents(wanted)} A",
                    (Fold(f"I={_fmt_currents(wanted)}A", np.flatnonzero(~held),
                          np.flatnonzero(held)),))
    if folds is None or (isinstance(folds, str) and folds.strip().lower() == "current"):
        explicit = folds is not None
        cur = np.asarray(batch.current, float)
        if not explicit and not np.all(np.isfinite(cur)):
            return Plan("none", "no held-out validation (the currents of the tests are not "
                        "all known)", ())
        cur = _currents(batch, "test", "leave-one-current-out")
        levels, ids = group_currents(cur)
        if levels.size < 2:
            if explicit:
                raise InputError(f"the training set is empty: leave-one-current-out needs at "
                                 f"least two currents, the data have {_fmt_currents(levels)} A")
            return Plan("none", f"no held-out validation (one current only: "
                        f"{_fmt_currents(levels)} A)", ())
        return Plan("leave-one-current-out", f"leave one current out ({levels.size} folds)",
                    tuple(Fold(f"I={lv:g}A", np.flatnonzero(ids != u), np.flatnonzero(ids == u))
                          for u, lv in enumerate(levels)))
    if isinstance(folds, bool) or not isinstance(folds, (int, np.integer)):
        raise InputError(f"folds must be an integer >= 2 or 'current', got {folds!r}")
    K = int(folds)
    if K < 2:
        raise InputError(f"folds must be at least 2 (with {K} fold the training set is empty)")
    if K > C:
        raise InputError(f"folds={K} is more than the {C} tests: some folds would be empty")
    _currents(batch, "test", "K-fold validation")
    perm = np.random.default_rng(int(seed)).permutation(C)
    out = []
    for j in range(K):
        test = np.sort(perm[j::K])
        out.append(Fold(f"fold {j + 1}/{K}", np.setdiff1d(everything, test), test))
    return Plan("folds", f"{K}-fold over the tests (seed {int(seed)})", tuple(out))
