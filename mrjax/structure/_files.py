"""A structure's records from files: columns named as mrjax reads them (`time_s`, `force_N`,
`ground_acceleration_m_s2`, `displacement_mm`, `acceleration_g0`, ...)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._errors import InputError
from ..data import find_files, parse_column, unit_scale
from ._records import Record
from ._system import AbstractStructure

#: File types the structure's loader reads (a long table with a header).
SUFFIXES = (".csv", ".txt", ".dat", ".parquet", ".pq", ".feather", ".arrow")


def _table(path: Path):
    """The file as a pandas DataFrame (every column as read)."""
    import pandas as pd  # imported here: only a load needs it

    suffix = path.suffix.lower()
    try:
        if suffix in (".parquet", ".pq"):
            return pd.read_parquet(path)
        if suffix in (".feather", ".arrow"):
            return pd.read_feather(path)
        return pd.read_csv(path, sep=None, engine="python", skipinitialspace=True)
    except (ValueError, OSError, ImportError) as e:
        raise InputError(f"{path}: cannot read it as a table ({str(e).splitlines()[0]})") from None


def _columns(frame, where: str) -> dict[str, tuple[str, float]]:
    """`{quantity: (column, SI factor)}` of the columns named `<quantity>_<unit>`."""
    found: dict[str, tuple[str, float]] = {}
    for col in frame.columns:
        try:
            quantity, unit = parse_column(str(col), where=where)
        except InputError:
            continue
        if quantity == "condition":
            found[quantity] = (col, 1.0)
            continue
        if quantity in found:
            raise InputError(f"{where}: columns {found[quantity][0]!r} and {col!r} both give "
                             f"{quantity}")
        found[quantity] = (col, unit_scale(unit, name=f"{where}: column {col!r}"))
    return found


def _signal(frame, spec: tuple[str, float], where: str) -> np.ndarray:
    col, scale = spec
    try:
        return np.asarray(frame[col], float) * scale
    except (TypeError, ValueError):
        raise InputError(f"{where}: column {col!r} is not numeric") from None


def read_records(path: str | os.PathLike, structure: AbstractStructure) -> list[Record]:
    """The records of one file: its `time_<unit>` column, the structure's input
    (`force_<unit>` or `ground_acceleration_<unit>`) and its response (`displacement_<unit>` or
    `acceleration_<unit>`, optional: without it the records can be predicted, not fitted);
    a `condition` column splits the rows into records (else one, named after the file)."""
    path = Path(path)
    where = str(path)
    frame = _table(path)
    cols = _columns(frame, where)
    need = structure.input_name
    if need not in cols:
        raise InputError(f"{where}: no input column {need}_<unit> for a {structure.name} "
                         f"structure (e.g. {need}_{'N' if need == 'force' else 'm_s2'}); "
                         f"columns: {', '.join(map(str, frame.columns))}")
    if "time" not in cols:
        raise InputError(f"{where}: no time column (time_s, time_ms, ...)")
    has_response = structure.response in cols
    keys = (frame[cols["condition"][0]].astype(str).to_numpy() if "condition" in cols
            else np.full(len(frame), path.stem))
    t, u = _signal(frame, cols["time"], where), _signal(frame, cols[need], where)
    y = _signal(frame, cols[structure.response], where) if has_response else None
    out = []
    for key in dict.fromkeys(keys):
        rows = keys == key
        src = where if "condition" not in cols else f"{where} (condition {key!r})"
        out.append(Record(str(key), t[rows], u[rows], None if y is None else y[rows],
                          source=src))
    return out


def load_records(paths: str | os.PathLike | Sequence[str | os.PathLike],
                 structure: AbstractStructure) -> list[Record]:
    """The records of every file and directory in `paths` (see :func:`read_records`): a
    CSV (or other delimited text) with a header, a Parquet or a Feather file.

    Raises :class:`mrjax.InputError` naming the file for a missing input or time column, a
    non-numeric column, a non-finite value, a record that is not uniformly sampled."""
    out: list[Record] = []
    for f in find_files(paths):
        if f.suffix.lower() not in SUFFIXES:
            raise InputError(f"{f}: a structure's records are read from tables with a header "
                             f"({', '.join(SUFFIXES)})")
        out += read_records(f, structure)
    return out
