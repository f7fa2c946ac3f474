"""The retry of a per-test fit: every test polished once more from the best of its neighbours'
optima, and the evidence of a possible local optimum (the spread of the two results).

One swarm per test misses some optima of the many-parameter ODE models on real records, on
different tests for different seeds, and more swarms per test only lower the odds
(`benchmarks/real_data.md`). The tests of one batch are measured on one damper, so the optimum
of a test is, once its linear parameters are solved again, a good start for its neighbours
(same current, other frequency or amplitude): from the best of them the polish lands in the
optimum the swarm missed, at the cost of one more polish.

`mrjax.fit` runs it over the whole batch after the chunks (`fit_in_chunks`): the donors of a
test are chosen from the whole batch, so the result does not depend on the chunking.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ._problem import TestsProblem

#: Donors per test: the optima of this many nearest tests are ranked on its view.
RETRY_DONORS = 16
#: Weight of the current in the distance between tests (against the log frequency and log
#: amplitude, each over its range in the batch): tests at the same current come first.
CURRENT_WEIGHT = 4.0
#: Distances computed per block of at most this many pairs (memory of a fleet's retry).
NEIGHBOUR_BLOCK = 4_000_000


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


