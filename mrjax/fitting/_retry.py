"""The retry of a per-test fit: every test polished once more from the best of its neighbours'
optima, and the evidence of a possible local optimum (the spread of the two results).

One swarm per test misses some optima of the many-parameter ODE models on real records (on the
30 UTFSM tests, modified Bouc-Wen, one swarm per test: 3 to 4 of the 30 tests, 16-24 % NRMSE
where the optimum is 7-9 %, different tests for different seeds), and more swarms per test
only lower the odds (two swarms per test still missed one). The tests of one batch are measured
on one damper, so the optimum of a test is, once its linear parameters are solved again, a good
start for its neighbours (same current, other frequency or amplitude): from the best of them
the polish lands in the optimum the swarm missed (every such test of seeds 0-4 found), at the
cost of one more polish.

`mrjax.fit` runs it over the whole batch after the chunks (`fit_in_chunks`): the donors of a
test are chosen from the whole batch, so the result does not depend on the chunking.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # `FitResult` writes the warnings of this module
    from ._problem import TestsProblem
    from ._result import FitResult

#: Donors per test: the optima of this many nearest tests are ranked on its view.
RETRY_DONORS = 16
#: Weight of the current in the distance between tests (against the log frequency and log
#: amplitude, each over its range in the batch): tests at the same current come first.
CURRENT_WEIGHT = 4.0
#: Distances computed per block of at most this many pairs (memory of a fleet's retry).
NEIGHBOUR_BLOCK = 4_000_000
#: The two polished starts of a test (the swarm's and the retry's) disagree when their RMS
#: differ by more than this fraction of the lower: a warning (`spread_warnings`).
SPREAD_MARGIN = 0.05


def _feature(values: np.ndarray, log: bool) -> np.ndarray:
    """A condition feature scaled to [0, 1] over the batch (NaN where unknown)."""
    v = np.asarray(values, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.where(v > 0, np.log(np.where(v > 0, v, 1.0)), np.nan) if log else v
    ok = np.isfinite(v)
    if ok.sum() < 2:
        return np.full(v.shape, np.nan)
    span = np.ptp(v[ok])
    return (v - np.min(v[ok])) / span if span > 0 else np.where(ok, 0.0, np.nan)


def neighbours(current: np.ndarray, frequency: np.ndarray, amplitude: np.ndarray,
               k: int = RETRY_DONORS) -> np.ndarray:
    """The donors of every test: `(C, min(k, C - 1))` indices of the nearest other tests.

    The distance is `CURRENT_WEIGHT` x |current difference| + |log frequency difference| +
    |log amplitude difference|, each over its range in the batch (a feature unknown for both
    tests adds nothing, for one of them its whole range); in order of distance, ties to the
    earlier test (at the k-th distance, which of equals is taken is deterministic but not
    necessarily the earliest).

    **Arguments:** `current` [A], `frequency` [Hz], `amplitude` [m], each (C,) (NaN where
    unknown); `k` donors per test.
    """
    C = np.asarray(current).shape[0]
    m = min(int(k), C - 1)
    feats = [(_feature(current, False), CURRENT_WEIGHT), (_feature(frequency, True), 1.0),
             (_feature(amplitude, True), 1.0)]
    out = np.zeros((C, max(m, 0)), int)
    if m <= 0:
        return out
    step = max(1, NEIGHBOUR_BLOCK // C)  # rows per block: the distances of a fleet stay small
    for r0 in range(0, C, step):
        rows = np.arange(r0, min(r0 + step, C))
        d = np.zeros((rows.size, C))
        for f, w in feats:
            diff = np.abs(f[rows, None] - f[None, :])
            known = np.isfinite(f)
            # unknown for both: no difference; for one of the two: the largest
            diff = np.where(known[rows, None] & known[None, :], diff,
                            np.where(known[rows, None] | known[None, :], 1.0, 0.0))
            d += w * diff
        d[np.arange(rows.size), rows] = np.inf
        if m < C - 1:  # the m nearest (deterministic), then in order of distance and index
            part = np.sort(np.argpartition(d, m - 1, axis=1)[:, :m], axis=1)
            order = np.argsort(np.take_along_axis(d, part, axis=1), axis=1, kind="stable")
            out[rows] = np.take_along_axis(part, order, axis=1)
        else:
            out[rows] = np.argsort(d, axis=1, kind="stable")[:, :m]
    return out


def retry_starts(problem: TestsProblem, donors: np.ndarray, theta: np.ndarray,
                 rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each unit of `problem` (a chunk of the batch) is polished again from: the best of
    its donors' optima with the unit's linear parameters solved, scored on its view
    (`TestsProblem.rank`).

    **Arguments:** `donors` (C, M) of the whole batch (:func:`neighbours`); `theta` (C, P) the
    batch's optima [SI]; `rows` (n,) the batch rows of the chunk's first n units (the others,
    padding, repeat the last).

    **Returns:** `(z (U, P), donor (U,))`: the starts and which batch row each came from.
    """
    U = problem.n_units
    idx = np.concatenate([rows, np.full(U - rows.size, rows[-1])])[:U]
    cand_rows = donors[idx]  # (U, M)
    th, rms = problem.rank(theta[cand_rows])
    best = np.argmin(rms, axis=1)
    pick = np.arange(U)
    return th[pick, best], cand_rows[pick, best]


def merge(first: FitResult, retry: FitResult) -> FitResult:
    """Per test the better (lower RMS on the full record) of the first fit and its retry, and
    `starts_rms` (C, 2): both RMS [N]. The swarm's figures (`pso_rms`, generations, history)
    stay the first fit's; the polish's (parameters, RMS, steps, status) are the winner's."""
    better = retry.rms < first.rms  # NaN-safe: a non-finite retry never wins
    changes: dict[str, Any] = {}
    for name in ("theta", "rms", "nrmse", "polish_steps"):
        a, b = getattr(first, name), getattr(retry, name)
        shape = (-1,) + (1,) * (np.ndim(a) - 1)
        changes[name] = np.where(better.reshape(shape), b, a)
    changes["polish_status"] = tuple(r if w else f for f, r, w in
                                     zip(first.polish_status, retry.polish_status, better))
    changes["starts_rms"] = np.stack([first.rms, retry.rms], axis=1)
    return dataclasses.replace(first, **changes)


def spread_warnings(result: FitResult) -> list[dict[str, Any]]:
    """The warning (lmfit's fit-report style) of the tests whose polished starts disagree by
    more than `SPREAD_MARGIN` (relative RMS): their error surface has more than one optimum,
    the lower is reported and a still lower one may exist (try more `restarts`). An empty
    list without a retry.

    **Returns:** `[{"kind": "local_optimum", "message", "conditions", "parameters": []}]` or
    `[]`.
    """
    s = result.starts_rms
    if s is None or np.ndim(s) != 2 or s.shape[1] < 2:
        return []
    with np.errstate(invalid="ignore", divide="ignore"):
        lo, hi = np.nanmin(s, axis=1), np.nanmax(s, axis=1)
        bad = ~(hi <= (1.0 + SPREAD_MARGIN) * lo)
    bad &= np.isfinite(lo)
    if not bad.any():
        return []
    idx = np.flatnonzero(bad)
    tests: Sequence[str] = [result.labels[i] for i in idx]
    i = int(idx[np.argmax((hi - lo)[idx] / lo[idx])])
    scale = result.nrmse[i] / result.rms[i] if result.rms[i] > 0 else np.nan
    return [{
        "kind": "local_optimum",
        "message": f"the swarm's start and the retry from a neighbour's optimum end more than "
        f"{100 * SPREAD_MARGIN:g} % apart in {len(tests)} test{'s' if len(tests) != 1 else ''} "
        f"(first: {tests[0]!r}; widest: {result.labels[i]!r}, NRMSE "
        f"{100 * lo[i] * scale:.2f} % vs {100 * hi[i] * scale:.2f} %): a local optimum is "
        "possible there; the lower is reported (try more restarts)",
        "conditions": list(tests), "parameters": []}]
