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


def join_codes(pieces: Sequence[Codes]) -> Codes:
    """The codes of the pieces as one column, the labels merged (in order of first
    appearance over the pieces)."""
    seen: dict[str, int] = {}
    codes = []
    for local in pieces:
        remap = np.asarray([seen.setdefault(s, len(seen)) for s in local.names], np.int32)
        codes.append(remap[local.codes] if remap.size else local.codes)
    return Codes(np.concatenate(codes) if codes else np.zeros(0, np.int32), tuple(seen))
