"""What the fitting functions accept as data: a batch, conditions, or files."""

from __future__ import annotations

import os
from collections.abc import Sequence

from ._condition import Batch, Condition, make_batch
from ._loaders import load


def as_batch(data: Batch | Condition | Sequence[Condition] | str | os.PathLike | Sequence) -> Batch:
    """A :class:`Batch` of `data`: a batch (returned as is), one or more :class:`Condition`,
    or file/directory path(s) (read by :func:`mrjax.data.load`).

    Raises :class:`mrjax.InputError` for files that cannot be read (see `load`)."""
    if isinstance(data, Batch):
        return data
    if isinstance(data, Condition):
        return make_batch([data])
    if isinstance(data, (str, os.PathLike)):
        return make_batch(load(data))
    data = list(data)
    if data and all(isinstance(d, (str, os.PathLike)) for d in data):
        return make_batch(load(data))
    return make_batch(data)
