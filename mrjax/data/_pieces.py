"""Columns read piece by piece (CSV blocks, Parquet row groups, Arrow record batches) joined
into one table: one float64 array per numeric column, made in one copy, and one set of
`condition` codes merged by label."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ._build import Codes


def view(arr: Any, dtype: Any) -> np.ndarray:
    """The values of an arrow array without nulls as a (read-only) numpy view, no copy (and,
    unlike `to_numpy`, without importing pandas)."""
    dtype = np.dtype(dtype)
    return np.frombuffer(arr.buffers()[1], dtype=dtype, count=len(arr),
                         offset=arr.offset * dtype.itemsize)


def join_floats(pieces: Sequence[Any]) -> np.ndarray:
    """One float64 array of numpy arrays and arrow (chunked) float64 arrays without nulls, in
    one copy."""
    out = np.empty(sum(len(a) for a in pieces))
    k = 0
    for a in pieces:
        for ch in (a.chunks if hasattr(a, "chunks") else [a]):
            v = ch if isinstance(ch, np.ndarray) else view(ch, np.float64)
            out[k:k + len(v)] = v
            k += len(v)
    return out


class Pieces:
    """A float64 column held as the arrays of the pieces it was read in (no joined copy):
    `column[a:b]` is a view where rows a..b lie in one piece (a test's rows, mostly), a copy
    of the parts where they span pieces; other indices join the column once."""

    def __init__(self, pieces: Sequence[np.ndarray]):
        self._pieces = [p for p in pieces if len(p)] or [np.zeros(0)]
        self._starts = np.concatenate([[0], np.cumsum([len(p) for p in self._pieces])])
        self._joined: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self._starts[-1])

    @property
    def shape(self) -> tuple[int]:
        return (len(self),)

    @property
    def nbytes(self) -> int:
        return 8 * len(self)

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        if self._joined is None:
            self._joined = np.concatenate(self._pieces)
        return self._joined if dtype is None else self._joined.astype(dtype)

    def __getitem__(self, idx: Any) -> np.ndarray:
        if isinstance(idx, slice) and idx.step in (None, 1):
            a, b, _ = idx.indices(len(self))
            k = int(np.searchsorted(self._starts, a, side="right")) - 1
            if k < len(self._pieces) and b <= self._starts[k + 1]:  # within one piece
                return self._pieces[k][a - self._starts[k]:b - self._starts[k]]
            last = int(np.searchsorted(self._starts, b, side="left"))
            return np.concatenate([p[max(a - s0, 0):max(b - s0, 0)] for p, s0 in
                                   zip(self._pieces[k:last], self._starts[k:last])])
        return np.asarray(self)[idx]


def join_floats_lazily(pieces: Sequence[Any]) -> Pieces:
    """A :class:`Pieces` column of numpy arrays and arrow (chunked) float64 arrays without
    nulls (views of the arrow buffers: no copy)."""
    arrays = []
    for a in pieces:
        for ch in (a.chunks if hasattr(a, "chunks") else [a]):
            arrays.append(ch if isinstance(ch, np.ndarray) else view(ch, np.float64))
    return Pieces(arrays)


def join_codes(pieces: Sequence[Codes]) -> Codes:
    """The codes of the pieces as one column, the labels merged (in order of first
    appearance over the pieces)."""
    seen: dict[str, int] = {}
    codes = []
    for local in pieces:
        remap = np.asarray([seen.setdefault(s, len(seen)) for s in local.names], np.int32)
        codes.append(remap[local.codes] if remap.size else local.codes)
    return Codes(np.concatenate(codes) if codes else np.zeros(0, np.int32), tuple(seen))
