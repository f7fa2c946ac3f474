"""Writing an export: the files of a target, all or none."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Protocol

from .._io import atomic_output
from ._model import ControllerModel


class Target(Protocol):
    """What an export is written as (:class:`mrjax.export.C99`, :class:`mrjax.export.FMU`)."""

    def files(self, cm: ControllerModel) -> dict[str, bytes]:
        """The files (name -> bytes) of `cm` in this form."""


def write(cm: ControllerModel, out: str | os.PathLike, target: Target) -> Path:
    """Write the export of `cm` as `target` (e.g. `C99()` or `FMU()`) into the directory
    `out`, atomically (every file or none: an unsupported primitive or a failed compilation
    leaves `out` as it was).

    **Returns:** the directory. Raises :class:`mrjax.InputError` (one line) for what the
    target cannot translate or build.
    """
    return atomic_output(out, target.files(cm))
