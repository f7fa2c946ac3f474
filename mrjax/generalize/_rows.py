"""The records of a joint fit of laws: rows of one shape, grouped by length, with their
commands (constant or per sample)."""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Float

from ..data import Batch
from ._laws import PACK_ROW, lag_current

#: At most this many groups of rows of similar length (each group is one compiled `vmap`).
MAX_GROUPS = 3
#: A grouping is good enough once the padded samples are at most this multiple of the real
#: ones (fewer groups compile faster).
PAD_SLACK = 1.25



class Rows(eqx.Module):
    """Records of one shape for the joint objective: `x` [m], `xdot` [m/s], `dt` [s], `force`
    [N], `mask` (R, T); `command` (R,) constant commands or (R, T) per-sample commands (in the
    laws' unit)."""

    x: Float[Array, "R T"]
    xdot: Float[Array, "R T"]
    dt: Float[Array, "R T"]
    force: Float[Array, "R T"]
    mask: Array
    command: Array

    def signal(self, eta, use_lag: bool):
        """The command the laws see: (R,) constants, or (R, T) through the filter."""
        if self.command.ndim == 1 or not use_lag:
            return self.command
        return jax.vmap(lag_current, in_axes=(0, 0, None))(self.command, self.dt, eta)

    @property
    def n_scored(self) -> int:
        return int(np.asarray(self.mask).sum())


def length_groups(lengths: np.ndarray, max_groups: int = MAX_GROUPS) -> list[np.ndarray]:
    """Indices of rows split into at most `max_groups` groups of similar length: the fewest
    groups whose padded total is within `PAD_SLACK` of the real one (else the best of
    `max_groups`), by dynamic programming over the sorted lengths."""
    lengths = np.asarray(lengths, int)
    order = np.argsort(lengths, kind="stable")
    L = lengths[order]
    n = L.size
    inf = float("inf")
    # best[g][j]: least padded total of the first j rows in g groups; cut[g][j] the start
    best = [[inf] * (n + 1) for _ in range(max_groups + 1)]
    cut = [[0] * (n + 1) for _ in range(max_groups + 1)]
    best[0][0] = 0.0
    for g in range(1, max_groups + 1):
        for j in range(1, n + 1):
            for i in range(j):
                v = best[g - 1][i] + (j - i) * L[j - 1]
                if v < best[g][j]:
                    best[g][j], cut[g][j] = v, i
    real = float(L.sum())
    g_use = next((g for g in range(1, max_groups + 1) if best[g][n] <= PAD_SLACK * real),
                 min(max_groups, n))
    groups, j = [], n
    for g in range(g_use, 0, -1):
        i = cut[g][j]
        if j > i:
            groups.append(order[i:j])
        j = i
    return groups[::-1]


def scored_lengths(mask: np.ndarray) -> np.ndarray:
    """(C,) samples up to the last scored one of each record (1 where none is scored)."""
    mask = np.asarray(mask, bool)
    n = mask.shape[1] - np.argmax(mask[:, ::-1], axis=1)
    return np.where(mask.any(axis=1), n, 1)


def record_order(mask: np.ndarray, max_groups: int = MAX_GROUPS) -> np.ndarray:
    """(C,) the records of constant commands in the order of the rows :func:`make_rows` makes
    of them (group after group), for scored samples `mask` (C, T)."""
    return np.concatenate(length_groups(scored_lengths(mask), max_groups))


def make_rows(batch: Batch, mask: np.ndarray, command: np.ndarray, *,
              max_groups: int = MAX_GROUPS) -> tuple[Rows, ...]:
    """The records of `batch` as groups of rows: per-sample commands and constant ones apart,
    each split by length (:func:`length_groups`).

    **Arguments:** `batch`; `mask` (C, T) scored samples; `command` (C,) constant commands or
    (C, T) per sample (rows whose command does not vary become constant rows).
    """
    mask = np.asarray(mask, bool)
    cmd = np.asarray(command, float)
    n = scored_lengths(mask)
    if cmd.ndim == 2:
        m = np.asarray(batch.mask, bool)
        span = np.array([np.ptp(cmd[i][m[i]]) for i in range(cmd.shape[0])])
        varying = span > 0
        level = np.array([cmd[i][m[i]][0] for i in range(cmd.shape[0])])
    else:
        varying = np.zeros(cmd.shape[0], bool)
        level = cmd
    arrays = {k: np.asarray(getattr(batch, k)) for k in ("x", "xdot", "dt", "force")}
    out = []
    for sel in (np.flatnonzero(~varying), np.flatnonzero(varying)):
        if sel.size == 0:
            continue
        for g in length_groups(n[sel], max_groups):
            idx = sel[g]
            T = int(n[idx].max())
            c = cmd[idx, :T] if varying[idx[0]] else level[idx]
            out.append(Rows(*jax.device_put(tuple(arrays[k][idx, :T] for k in ("x", "xdot",
                                                                               "dt", "force"))),
                            mask=jax.device_put(mask[idx, :T]),
                            command=jax.device_put(np.asarray(c, float))))
    return tuple(out)


def packed_rows(batch: Batch, mask: np.ndarray, current: np.ndarray) -> tuple[Rows, ...]:
    """A static model's scored samples packed into rows of `PACK_ROW` samples, one current
    each: its force at a sample does not depend on the others, so short conditions are not
    padded to the longest one (the same samples, the same total RMS)."""
    arrays = [np.asarray(a, float) for a in (batch.x, batch.xdot, batch.dt, batch.force)]
    L = PACK_ROW
    pieces, currents = [], []
    for v in np.unique(current):
        r = np.flatnonzero(current == v)
        samples = [a[r][mask[r]] for a in arrays]
        for start in range(0, samples[0].size, L):
            pieces.append([a[start:start + L] for a in samples])
            currents.append(v)
    R = len(pieces)
    out = np.zeros((4, R, L))
    out[2] = 1.0  # sample interval of the padding (unused by static models)
    keep = np.zeros((R, L), bool)
    for u, piece in enumerate(pieces):
        k = piece[0].size
        for a in range(4):
            out[a, u, :k] = piece[a]
        keep[u, :k] = True
    return (Rows(*jax.device_put(tuple(out)), mask=jax.device_put(keep),
                 command=jax.device_put(np.asarray(currents, float))),)
