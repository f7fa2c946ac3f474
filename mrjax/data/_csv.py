"""CSV files with a header: one row per sample, several tests told apart by a column."""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping

import numpy as np

from .._errors import InputError
from ._build import ReadColumns, assemble
from ._columns import Column, Meta
from ._condition import Condition
from ._files import PathLike, check_file, stem
from ._units import COLUMN_QUANTITIES, UNITS, parse_column

_STRICT_REQUIRED = ("time", "displacement", "force", "current")
#: Rows right after the header that may be skipped as a units row (spec mode).
_MAX_UNIT_ROWS = 3
#: A column with at least this share of empty cells is reported as mostly empty.
_MOSTLY_EMPTY = 0.9


def _delimiter(text: str) -> str:
    header = next((ln for ln in text.splitlines() if ln.strip()), "")
    for d in (",", ";", "\t"):
        if d in header:
            return d
    return ","


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def conventional_columns(header: list[str], src: str, strict: bool) -> dict[str, Column]:
    """Columns named `<quantity>_<unit>` (and `condition`); strict: every column must be one,
    and time, displacement, force and current are required."""
    found: dict[str, Column] = {}
    for name in header:
        try:
            quantity, unit = parse_column(name, where=src)
        except InputError:
            if strict:
                raise
            continue
        if quantity in found:
            raise InputError(
                f"{src}: columns {found[quantity].name!r} and {name!r} both give {quantity}"
            )
        found[quantity] = Column(name, None, unit)
    if strict:
        for quantity in _STRICT_REQUIRED:
            if quantity not in found:
                si = next(iter(UNITS[COLUMN_QUANTITIES[quantity]])).replace("/", "_")
                raise InputError(
                    f"{src}: missing required column {quantity}_<unit> (e.g. {quantity}_{si}); "
                    f"columns present: {', '.join(header)}"
                )
    return found


def column_index(header: list[str] | None, col: Column, role: str, src: str) -> int:
    if col.index is not None and col.name is not None:
        raise InputError(
            f"{src}: {role} column {col.source!r}: 'name[k]' picks a column of a .mat variable; "
            f"in a CSV file name the column by its header or its number (0-based)"
        )
    if col.name is None:
        width = len(header) if header is not None else None
        if width is not None and col.index >= width:
            raise InputError(
                f"{src}: {role} column {col.index} does not exist: the file has {width} "
                f"column(s), numbered from 0"
            )
        return col.index
    if header is None:
        raise InputError(f"{src}: the file has no header; give {role} as a column number")
    if col.name in header:
        return header.index(col.name)
    folded = [j for j, h in enumerate(header) if h.casefold() == col.name.casefold()]
    if len(folded) == 1:
        return folded[0]
    raise InputError(
        f"{src}: unknown column {col.name!r} ({role}); columns present: {', '.join(header)}"
    )


def read_csv(
    path: PathLike,
    *,
    columns: Mapping[str, Column] | None,
    wide: Mapping[str, tuple[Column, ...]] | None = None,
    strict: bool,
) -> ReadColumns:
    """Read the columns of a CSV file: those given, or those named `<quantity>_<unit>`."""
    p = check_file(path)
    src = str(path)
    with open(p, newline="", encoding="utf-8-sig", errors="replace") as fh:
        text = fh.read()
    if not text.strip():
        raise InputError(f"{src}: file is empty")
    reader = csv.reader(io.StringIO(text), delimiter=_delimiter(text))
    rows: list[list[str]] = []
    lines: list[int] = []
    blank = 0
    for row in reader:
        if not any(cell.strip() for cell in row):
            blank += 1
            continue
        rows.append(row)
        lines.append(reader.line_num)
    if not rows:
        raise InputError(f"{src}: file is empty")
    notes: list[str] = []
    wide = dict(wide or {})
    asked = ([] if columns is None else list(columns.items())) + [
        (r, c) for r, cs in wide.items() for c in cs]
    headerless = (not strict and columns is not None and all(c.name is None for _, c in asked)
                  and all(_is_number(c) for c in rows[0] if c.strip()))
    header = None if headerless else [cell.strip() for cell in rows[0]]
    body, body_lines = (rows, lines) if headerless else (rows[1:], lines[1:])
    trailing = False
    width = len(rows[0])
    if header is not None and len(header) > 1 and header[-1] == "":
        header, width, trailing = header[:-1], width - 1, True
    elif header is None and rows[0][-1].strip() == "":
        width, trailing = width - 1, True
    if trailing:
        notes.append("every line ends with a delimiter (ignored)")
    if blank and not strict:
        notes.append(f"{blank} empty line(s) skipped")
    if columns is None:
        columns = conventional_columns(header, src, strict)
        asked = list(columns.items()) + [(r, c) for r, cs in wide.items() for c in cs]
    index = {c: column_index(header, c, role, src) for role, c in asked}
    numeric = {c: j for c, j in index.items() if c.unit is not None}
    if not body:
        raise InputError(f"{src}: header only, no data rows")
    cells: list[list[str]] = []
    for row, lineno in zip(body, body_lines):
        if trailing and len(row) == width + 1 and not row[-1].strip():
            row = row[:-1]
        if len(row) != width:
            if strict or (len(row) > width and any(c.strip() for c in row[width:])):
                raise InputError(f"{src}, line {lineno}: expected {width} fields, found {len(row)}")
            row = row[:width] + [""] * (width - len(row))
        cells.append(row)
    skipped = 0
    if not strict and numeric:
        while (skipped < min(_MAX_UNIT_ROWS, len(cells) - 1)
               and not any(_is_number(cells[skipped][j]) for j in numeric.values())):
            skipped += 1
        if skipped:
            notes.append(f"line(s) {', '.join(str(n) for n in body_lines[:skipped])} not data "
                         f"(skipped)")
            cells, body_lines = cells[skipped:], body_lines[skipped:]
    values: dict[Column, np.ndarray] = {}
    for c, j in index.items():
        name = header[j] if header is not None else str(j)
        if c.unit is None:  # text: the condition column
            col = [row[j].strip() for row in cells]
            for k, v in enumerate(col):
                if not v:
                    raise InputError(f"{src}, line {body_lines[k]}, column {name!r}: empty cell")
            values[c] = np.asarray(col, dtype=object)
            continue
        out = np.empty(len(cells))
        for k, row in enumerate(cells):
            cell = row[j].strip()
            try:
                out[k] = float(cell)
            except ValueError:
                what = "empty cell" if not cell else f"not a number: {cell!r}"
                raise InputError(f"{src}, line {body_lines[k]}, column {name!r}: {what}") from None
        values[c] = out
    if not strict:
        used = set(index.values())
        unused = []
        for j in range(width):
            if j in used:
                continue
            name = header[j] if header is not None else str(j)
            empty = sum(1 for row in cells if not row[j].strip())
            if empty >= _MOSTLY_EMPTY * len(cells):
                notes.append(f"column {name!r} is mostly empty ({len(cells) - empty} of "
                             f"{len(cells)} cells filled), not used")
            else:
                unused.append(repr(name))
        if unused:
            notes.append(f"column(s) {', '.join(unused)} not used")
    return ReadColumns(src, stem(path), len(cells), dict(columns), wide, values,
                 np.asarray(body_lines), notes)


def load_csv(path: PathLike, *, velocity_window_s: float | None = None) -> list[Condition]:
    """Load one or more tests from a long-format CSV file with a header.

    One row per sample. Column names carry their unit (any unit of the right dimension, see
    `mrjax.data.UNITS`; `/` written `_`):

    | column | required | e.g. |
    |---|---|---|
    | `condition` | no | text: the test each row belongs to |
    | `current_<unit>` | yes | `current_A`, `current_mA` |
    | `frequency_<unit>` | no | `frequency_Hz` |
    | `amplitude_<unit>` | no | `amplitude_m`, `amplitude_mm`, `amplitude_in` |
    | `time_<unit>` | yes | `time_s`, `time_ms` |
    | `displacement_<unit>` | yes | `displacement_m`, `displacement_mm`, `displacement_in` |
    | `velocity_<unit>` | no | `velocity_m_s`, `velocity_mm_s`, `velocity_in_s` |
    | `force_<unit>` | yes | `force_N`, `force_kN`, `force_lbf` |

    Columns may come in any order; commas, semicolons or tabs separate them (a trailing
    delimiter on every line is ignored). Rows are grouped into conditions by `condition`, in
    order of first appearance (without that column the whole file is one condition labelled by
    the file name). Current, frequency and amplitude must be constant within a condition; a
    missing frequency or amplitude column leaves them unknown. Without a velocity column,
    velocity is estimated from displacement by `mrjax.data.estimate_velocity`. Files with
    other column names: pass a `mrjax.data.DataSpec` to `mrjax.data.load`.

    **Arguments:**

    - `path`: the file.
    - `velocity_window_s`: smoothing window [s] of the velocity estimate (files without a
        velocity column only; default chosen from each record).

    **Returns:** a list of :class:`Condition` in SI units, one per condition.

    Raises :class:`mrjax.InputError` naming the file, and the line (1-based, as in a text
    editor), column or condition at fault.
    """
    read = read_csv(path, columns=None, strict=True)
    return assemble(read, meta=Meta(), window_s=velocity_window_s, strict=True)
