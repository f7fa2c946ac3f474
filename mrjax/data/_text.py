"""Headerless text files: whitespace-separated columns `t, x, xdot, F` (or `t, x, F`), one test
per file."""

from __future__ import annotations

import re
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .._errors import InputError
from ._build import LineMap, ReadColumns, assemble
from ._columns import Column, is_number, loader_arguments
from ._condition import Condition
from ._files import PathLike, check_file, name_meta, stem
from ._progress import advance

#: Default units of :func:`load_txt`: time, displacement, velocity, force (displacement in
#: millimetres, as damper test rigs usually log it).
TXT_UNITS: tuple[str, str, str, str] = ("s", "mm", "mm/s", "N")

#: Lines before the first data line that may be skipped as headers (spec mode).
_MAX_HEADER_LINES = 5


def _conventional(ncol: int, units: Sequence[str]) -> dict[str, Column]:
    """`t, x, F` (3 columns) or `t, x, xdot, F` (4 columns)."""
    t, x, v, f = units
    cols = {"time": Column(None, 0, t), "displacement": Column(None, 1, x)}
    if ncol == 4:
        cols["velocity"] = Column(None, 2, v)
    cols["force"] = Column(None, ncol - 1, f)
    return cols


def _split(line: str) -> list[str]:
    body = re.split(r"[#%]", line, maxsplit=1)[0].strip()
    if not body:
        return []
    cells = re.split(r"[\s,;]+", body)
    if cells and cells[-1] == "":
        cells = cells[:-1]  # a trailing delimiter
    if cells and cells[0] == "":
        cells = cells[1:]
    return cells


def _parse(path: Path, names: Mapping[int, str] | None, strict: bool,
           notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Slow, exact parse naming the line of any fault; `names`: column index -> role to read
    (None: the conventional 3 or 4 columns). Returns (table, line numbers)."""
    rows: list[list[float]] = []
    lines: list[int] = []
    ncol = None
    skipped: list[int] = []
    ignored = 0
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            cells = _split(line)
            if not cells:
                continue
            if ncol is None:
                if names is None:
                    if len(cells) not in (3, 4):
                        raise InputError(
                            f"{path}, line {lineno}: expected 3 columns (t, x, F) or 4 "
                            f"(t, x, xdot, F), found {len(cells)}"
                        )
                    role_of = {k: n for k, n in enumerate(
                        ("t", "x", "force") if len(cells) == 3 else ("t", "x", "xdot", "force"))}
                else:
                    role_of = dict(names)
                used = [k for k in role_of if k < len(cells)]
                if (not strict and not any(is_number(cells[k]) for k in used)
                        and len(skipped) < _MAX_HEADER_LINES):
                    skipped.append(lineno)
                    continue
                ncol = len(cells)
                missing = [k for k in role_of if k >= ncol]
                if missing:
                    k = missing[0]
                    raise InputError(
                        f"{path}, line {lineno}: column {k} ({role_of[k]}) does not exist: the "
                        f"file has {ncol} column(s), numbered from 0"
                    )
            elif len(cells) != ncol:
                raise InputError(
                    f"{path}, line {lineno}: expected {ncol} columns, found {len(cells)}"
                )
            row = []
            for k in range(ncol):
                cell = cells[k]
                try:
                    row.append(float(cell))
                except ValueError:
                    if k in role_of:
                        # numbered as the user wrote them: from 1 by convention, else from 0
                        num = k + 1 if names is None else k
                        raise InputError(
                            f"{path}, line {lineno}, column {num} ({role_of[k]}): "
                            f"not a number: {cell!r}"
                        ) from None
                    row.append(np.nan)
                    ignored += 1
            rows.append(row)
            lines.append(lineno)
    if ncol is None:
        raise InputError(f"{path}: file is empty (no data rows)")
    if skipped:
        notes.append(f"line(s) {', '.join(map(str, skipped))} not data (skipped)")
    if ignored:
        notes.append(f"{ignored} non-numeric cell(s) in unused columns (ignored)")
    return np.asarray(rows, dtype=float), np.asarray(lines)


def read_text(
    path: PathLike,
    *,
    columns: Mapping[str, Column] | None,
    wide: Mapping[str, tuple[Column, ...]] | None = None,
    strict: bool,
    units: Sequence[str] = TXT_UNITS,
) -> ReadColumns:
    """Read the columns of a headerless text file: those given (bare column numbers), or by
    convention `t, x, F` / `t, x, xdot, F` in `units`."""
    p = check_file(path)
    where = str(path)
    wide = dict(wide or {})
    notes: list[str] = []
    names: dict[int, str] | None = None
    if columns is not None:
        names = {}
        for role, cs in [(r, (c,)) for r, c in columns.items()] + list(wide.items()):
            for c in cs:
                if c.name is not None:
                    raise InputError(
                        f"{where}: a text file has no header: give {role} as a column number "
                        f"(0-based), e.g. '1:mm', not {c.source!r}"
                    )
                names[c.index] = role
    data = None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data = np.loadtxt(p, dtype=float, comments=("#", "%"), ndmin=2)
    except ValueError:
        data = None
    lines = None
    ok = data is not None and data.size > 0 and (
        data.shape[1] in (3, 4) if names is None else max(names) < data.shape[1])
    if not ok:
        data, lines = _parse(p, names, strict, notes)
    if names is None:
        columns = _conventional(data.shape[1], units)
    values = {}
    for c in list(columns.values()) + [c for cs in wide.values() for c in cs]:
        values[c] = data[:, c.index]
    unused = sorted(set(range(data.shape[1])) - {c.index for c in values})
    if unused and not strict:
        notes.append(f"column(s) {', '.join(map(str, unused))} not used")
    advance(p.stat().st_size)
    return ReadColumns(where, stem(path), data.shape[0], dict(columns), wide, values,
                       None if lines is None else LineMap.of(lines), notes)


def load_txt(
    path: PathLike,
    *,
    units: Sequence[str] = TXT_UNITS,
    current: float | None = None,
    frequency: float | None = None,
    amplitude: float | None = None,
    label: str | None = None,
    parse_name: bool = True,
    velocity_window_s: float | None = None,
) -> Condition:
    """Load one test from a headerless text file of whitespace-separated columns.

    The file holds whitespace-separated numbers (commas or semicolons also separate them; `#`
    and `%` start comments; a trailing delimiter is ignored), in 4 columns `t, x, xdot, F` or 3
    columns `t, x, F`. With 3 columns the velocity is estimated from the displacement by
    `mrjax.data.estimate_velocity`. For other layouts pass a `mrjax.data.DataSpec` to
    `mrjax.data.load`.

    **Arguments:**

    - `path`: the file.
    - `units`: units of (time, displacement, velocity, force); default `("s", "mm", "mm/s",
        "N")`. Any unit of the right dimension (see `mrjax.data.UNITS`).
        Values are converted to SI.
    - `current` [A], `frequency` [Hz], `amplitude` [m]: test metadata. Those not given are read
        from the file name by `mrjax.data.parse_label`.
    - `label`: name of the condition (default the file name without extension).
    - `parse_name`: if False, metadata not given stay unknown (`None`) instead of being read
        from the file name.
    - `velocity_window_s`: smoothing window [s] of the velocity estimate (3-column files only;
        default chosen from the record, see `mrjax.data.velocity_window`).

    **Returns:** a :class:`Condition` in SI units with `source` the file path.

    Raises :class:`mrjax.InputError` naming the file (and line and column) for an empty file, a
    non-numeric cell, a wrong number of columns, an unknown unit, an unparsable file name, or
    values that :class:`Condition` rejects.
    """
    units, given = loader_arguments(str(path), units, label=label, current=current,
                                    frequency=frequency, amplitude=amplitude)
    read = read_text(path, columns=None, strict=True, units=units)
    meta = name_meta(path, given) if parse_name else given
    (cond,) = assemble(read, meta=meta, window_s=velocity_window_s, strict=True)
    return cond
