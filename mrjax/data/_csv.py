"""CSV files with a header: one row per sample, several tests told apart by a column.

**How a file is read.** Its head (the header and the first rows, by Python's `csv` module)
gives the delimiter, the header, the columns to read and the line where the data start. The
rest is read in blocks of about `BLOCK_BYTES` bytes, each ending at a line end outside quotes:
pyarrow's CSV parser (C++, on every core) reads a block straight into float64 columns and the
`condition` column into integer codes. A block it does not read cleanly, row for row (a row
with another number of fields, an empty, non-numeric or `nan` cell, a blank line, unusual
whitespace), is read again by the exact reader: Python's `csv` module, row by row, with the
rules and messages of the format (a bad cell is named by its line and column). A file of
quirks that the rules tolerate is therefore read as they say, and a well-formed file is read by
pyarrow's parser alone. The memory held is the columns asked for plus one block.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import re
from collections.abc import Iterator, Mapping
from typing import BinaryIO

import numpy as np

from .._errors import InputError
from ._build import Codes, LineMap, ReadColumns, assemble
from ._columns import Column, Meta, is_number
from ._condition import Condition
from ._files import PathLike, check_file, stem
from ._pieces import join_codes, join_floats_lazily, view
from ._progress import advance
from ._units import COLUMN_QUANTITIES, UNITS, parse_column

_STRICT_REQUIRED = ("time", "displacement", "force", "current")
#: Rows right after the header that may be skipped as a units row (spec mode).
_MAX_UNIT_ROWS = 3
#: A column with at least this share of empty cells is reported as mostly empty.
_MOSTLY_EMPTY = 0.9
#: Bytes per block of the body (pyarrow reads each on every core; the exact reader redoes one).
BLOCK_BYTES = 16 * 2**20
#: Characters that Python's `str.strip` removes beyond those of RE2's `\s`: a cell holding one
#: of them is left to the exact reader.
_RARE_SPACE = "[\\x1c-\\x1f\\x85\\xa0\\x{1680}\\x{2000}-\\x{200a}\\x{2028}\\x{2029}\\x{202f}" \
              "\\x{205f}\\x{3000}]"


#: What `str.splitlines` takes for a line end.
_LINE_BREAK = re.compile("[\n\r\x0b\x0c\x1c-\x1e\x85\u2028\u2029]")


def _delimiter(text: str) -> str:
    """`,`, `;` or a tab: the first of them in the first non-blank line (`str.splitlines`'s
    lines), else `,`."""
    m = re.search(r"\S", text)
    header = ""
    if m is not None:
        start = max(text.rfind(c, 0, m.start()) for c in "\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029")
        end = _LINE_BREAK.search(text, m.start())
        header = text[start + 1: end.start() if end else len(text)]
    for d in (",", ";", "\t"):
        if d in header:
            return d
    return ","


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


# ------------------------------------------------------------------------------------ blocks


def count_lines(data: bytes) -> int:
    """Line ends in `data` (`\\r\\n`, `\\r` or `\\n`: as Python's csv module counts lines)."""
    n = data.count(b"\n")
    return n + data.count(b"\r") - data.count(b"\r\n") if b"\r" in data else n


def _cut(buf: bytes, odd: bool) -> int:
    """The end of the last line of `buf` that ends outside quotes (0: none), given whether the
    bytes before `buf` hold an odd number of quotes. A `\\r` at the very end of `buf` is not a
    line end yet (a `\\n` may follow)."""
    nl = b"\n" if b"\n" in buf else b"\r"
    end = len(buf) if nl == b"\n" else len(buf) - 1
    p = buf.rfind(nl, 0, end) + 1
    if b'"' not in buf and not odd:
        return p
    parity = (buf.count(b'"', 0, p) + odd) % 2
    while p > 0 and parity:  # inside a quoted field: back one line
        q = buf.rfind(nl, 0, p - 1) + 1
        parity ^= buf.count(b'"', q, p) % 2
        p = q
    return p


def byte_blocks(fh: BinaryIO, size: int = BLOCK_BYTES, line: int = 1,
                count: bool = True) -> Iterator[tuple[bytes, int, int]]:
    """The file from its current position in blocks of about `size` bytes, each ending at a
    line end outside quotes (the last one at the end of the file), with the line each starts
    on (`line` the first) and its number of line ends; `count`: the bytes count on the
    progress bar."""
    carry, odd = b"", False
    while True:
        data = fh.read(size)
        buf = carry + data if carry else data
        if not data:
            if buf:
                yield buf, line, count_lines(buf)
            return
        if count:
            advance(len(data))
        p = _cut(buf, odd)
        if p == 0:  # no line end outside quotes yet
            carry = buf
            continue
        block, carry = buf[:p], buf[p:]
        odd = bool((block.count(b'"') + odd) % 2)
        ends = count_lines(block)
        yield block, line, ends
        line += ends


# ------------------------------------------------------------------------------------ layout


@dataclasses.dataclass
class _Layout:
    """How to read the data rows of a file, from its head."""

    src: str
    delimiter: str
    header: list[str] | None
    width: int
    trailing: bool
    strict: bool
    index: dict[Column, int]  # every column read -> its position
    names: dict[int, str]  # position -> name in messages

    @property
    def text(self) -> dict[Column, int]:
        return {c: j for c, j in self.index.items() if c.unit is None}

    @property
    def numeric(self) -> dict[Column, int]:
        return {c: j for c, j in self.index.items() if c.unit is not None}

    @property
    def unused(self) -> list[int]:
        used = set(self.index.values())
        return [j for j in range(self.width) if j not in used]


def _rows(text: str, delimiter: str, src: str, first_line: int) -> Iterator[tuple[list[str], int]]:
    """The rows of `text` and the line each ends on (blank rows included)."""
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=delimiter)
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as e:
            raise InputError(f"{src}, line {first_line - 1 + reader.line_num}: not CSV: "
                             f"{e}") from None
        yield row, first_line - 1 + reader.line_num


def _is_blank(row: list[str]) -> bool:
    return not any(cell.strip() for cell in row)


def _fixed(row: list[str], line: int, lay: _Layout) -> list[str]:
    """A data row with `lay.width` cells (a trailing delimiter dropped, a short row padded in
    spec mode), or the error of a row with another number of fields."""
    if lay.trailing and len(row) == lay.width + 1 and not row[-1].strip():
        row = row[:-1]
    if len(row) != lay.width:
        if lay.strict or (len(row) > lay.width and any(c.strip() for c in row[lay.width:])):
            raise InputError(f"{lay.src}, line {line}: expected {lay.width} fields, found "
                             f"{len(row)}")
        row = row[:lay.width] + [""] * (lay.width - len(row))
    return row


@dataclasses.dataclass
class _Head:
    """What the head of a file says: the layout, the columns, the byte offset and line where
    the data rows start, the blank lines before them and the notes so far."""

    layout: _Layout
    columns: dict[str, Column]
    offset: int
    first_line: int
    blank: int
    notes: list[str]


def _head(data: bytes, eof: bool, src: str, columns: Mapping[str, Column] | None,
          wide: dict[str, tuple[Column, ...]], strict: bool) -> _Head | None:
    """The head of the file (`data`: its first bytes; `eof`: the whole file), or None when
    `data` holds too few rows to tell (read more)."""
    text = data.decode("utf-8-sig", errors="replace")
    rows: list[tuple[list[str], int]] = []
    blank_lines = []
    for row, line in _rows(text, _delimiter(text), src, 1):
        if _is_blank(row):
            blank_lines.append(line)
            continue
        rows.append((row, line))
        if len(rows) > _MAX_UNIT_ROWS + 1:
            break
    if len(rows) <= _MAX_UNIT_ROWS + 1 and not eof:
        return None
    if not rows:
        raise InputError(f"{src}: file is empty")
    delimiter = _delimiter(text)
    asked = ([] if columns is None else list(columns.items())) + [
        (r, c) for r, cs in wide.items() for c in cs]
    first = rows[0][0]
    headerless = (not strict and columns is not None and all(c.name is None for _, c in asked)
                  and all(is_number(c) for c in first if c.strip()))
    header = None if headerless else [cell.strip() for cell in first]
    body = rows if headerless else rows[1:]
    notes: list[str] = []
    trailing, width = False, len(first)
    if header is not None and len(header) > 1 and header[-1] == "":
        header, width, trailing = header[:-1], width - 1, True
    elif header is None and first[-1].strip() == "":
        width, trailing = width - 1, True
    if trailing:
        notes.append("every line ends with a delimiter (ignored)")
    if columns is None:
        columns = conventional_columns(header, src, strict)
        asked = list(columns.items()) + [(r, c) for r, cs in wide.items() for c in cs]
    index = {c: column_index(header, c, role, src) for role, c in asked}
    names = {j: header[j] if header is not None else str(j) for j in range(width)}
    lay = _Layout(src, delimiter, header, width, trailing, strict, index, names)
    if not body:
        raise InputError(f"{src}: header only, no data rows")
    cells = [_fixed(row, line, lay) for row, line in body]
    skipped = 0
    if not strict and lay.numeric:
        limit = min(_MAX_UNIT_ROWS, len(cells) - 1)  # the head holds every row when < 4
        while skipped < limit and not any(is_number(cells[skipped][j])
                                          for j in lay.numeric.values()):
            skipped += 1
        if skipped:
            notes.append(f"line(s) {', '.join(str(ln) for _, ln in body[:skipped])} not data "
                         f"(skipped)")
    after = body[skipped - 1][1] if skipped else (0 if headerless else rows[0][1])
    offset = 0
    for k, m in enumerate(re.finditer(rb"\r\n|\r|\n", data)):
        if k + 1 == after:
            offset = m.end()
            break
    return _Head(lay, dict(columns), offset, after + 1,
                 sum(1 for line in blank_lines if line <= after), notes)


# ------------------------------------------------------------------------------------ bodies


@dataclasses.dataclass
class Part:
    """The rows of one piece of the body: `n` rows, the values of the columns read (float64
    arrays, arrow or numpy; `Codes` of the `condition` column), the line of each row, the
    blank lines skipped and the empty cells of each unused column."""

    n: int
    values: dict[Column, np.ndarray | Codes]
    lines: LineMap
    blank: int
    empty: dict[int, int]  # unused column -> empty cells


def _exact(data: bytes, first_line: int, lay: _Layout) -> Part:
    """Read a piece row by row with Python's csv module: the format's rules and messages."""
    rows, lines, blank = [], [], 0
    for row, line in _rows(data.decode("utf-8", errors="replace"), lay.delimiter, lay.src,
                           first_line):
        if _is_blank(row):
            blank += 1
            continue
        rows.append(_fixed(row, line, lay))
        lines.append(line)
    values: dict[Column, np.ndarray | Codes] = {}
    for c, j in lay.index.items():
        name = lay.names[j]
        if c.unit is None:  # text: the condition column
            col = [row[j].strip() for row in rows]
            for k, v in enumerate(col):
                if not v:
                    raise InputError(f"{lay.src}, line {lines[k]}, column {name!r}: empty cell")
            values[c] = Codes.of(col)
            continue
        out = np.empty(len(rows))
        for k, row in enumerate(rows):
            cell = row[j].strip()
            try:
                out[k] = float(cell)
            except ValueError:
                what = "empty cell" if not cell else f"not a number: {cell!r}"
                raise InputError(f"{lay.src}, line {lines[k]}, column {name!r}: {what}") from None
        values[c] = out
    empty = {} if lay.strict else {
        j: sum(1 for row in rows if not row[j].strip()) for j in lay.unused}
    return Part(len(rows), values, LineMap.of(lines), blank, empty)


def _fast(data: bytes, first_line: int, ends: int, lay: _Layout) -> Part | None:
    """Read a piece (`ends` line ends) with pyarrow, or None where it does not read it as the
    exact reader would (see the module notes). Numeric columns stay arrow arrays (joined
    into one numpy array per column by :func:`_join`)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    from pyarrow import csv as pacsv

    if data.startswith(b"\xef\xbb\xbf"):  # pyarrow would drop it as a byte-order mark; in
        return None  # the middle of a file it is a character of the first cell
    n_lines = ends + (0 if data.endswith((b"\n", b"\r")) else 1)
    names = [f"f{j}" for j in range(lay.width + lay.trailing)]
    others = ([lay.width] if lay.trailing else []) + ([] if lay.strict else lay.unused)
    include = sorted(set(lay.index.values()) | set(others))
    types = {names[j]: pa.string() for j in include}
    types.update({names[j]: pa.float64() for j in lay.numeric.values()})
    types.update({names[j]: pa.dictionary(pa.int32(), pa.string()) for j in lay.text.values()})
    try:
        table = pacsv.read_csv(
            pa.py_buffer(data),
            read_options=pacsv.ReadOptions(column_names=names, block_size=2**21),
            parse_options=pacsv.ParseOptions(delimiter=lay.delimiter, newlines_in_values=False,
                                             ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(
                column_types=types, include_columns=[names[j] for j in include],
                null_values=[""], strings_can_be_null=True, quoted_strings_can_be_null=True),
            memory_pool=pa.system_memory_pool())  # freed memory goes back to the system
    except pa.ArrowInvalid:  # a row or cell it does not read: the exact reader says which
        return None
    if table.num_rows != n_lines:  # blank lines skipped or rows over several lines
        return None
    for j in include:
        if j in lay.index.values() and table.column(names[j]).null_count:
            return None  # an empty cell: the exact reader names it
    values: dict[Column, np.ndarray | Codes] = {}
    for c, j in lay.numeric.items():
        a = table.column(names[j])
        if pc.any(pc.is_nan(a)).as_py():  # "nan" or a form Python does not read: the exact
            return None  # reader decides
        values[c] = a
    for c, j in lay.text.items():
        col = table.column(names[j]).unify_dictionaries().combine_chunks()
        labels = [s.strip() for s in col.dictionary.to_pylist()]
        if not all(labels):
            return None
        values[c] = Codes(view(col.indices, np.int32),
                          tuple(labels))
    empty = {}
    for j in others:
        col = table.column(names[j])
        if pc.any(pc.match_substring_regex(col, _RARE_SPACE)).as_py():
            return None
        blank_cells = pc.sum(pc.match_substring_regex(col, "^[ \\t\\n\\r\\x0b\\x0c]*$")).as_py()
        k = col.null_count + int(blank_cells or 0)
        if j == lay.width:
            if k != table.num_rows:  # the trailing delimiter's column holds something
                return None
        else:
            empty[j] = k
    return Part(table.num_rows, values, LineMap.run(first_line), 0, empty)


def _join(parts: list[Part], lay: _Layout) -> tuple[int, dict[Column, np.ndarray | Codes],
                                                    LineMap, int, dict[int, int]]:
    """The parts as one table: codes of the text columns merged by label."""
    n = sum(p.n for p in parts)
    values: dict[Column, np.ndarray | Codes] = {}
    for c in lay.index:
        pieces = [p.values.pop(c) for p in parts]
        values[c] = join_floats_lazily(pieces) if c.unit is not None else join_codes(pieces)
    starts = np.cumsum([0] + [p.n for p in parts])
    lines = LineMap.join([(int(r0), p.lines) for r0, p in zip(starts, parts)])
    blank = sum(p.blank for p in parts)
    empty = {j: sum(p.empty.get(j, 0) for p in parts) for j in lay.unused}
    return n, values, lines, blank, empty


#: Bytes read at a time while looking for the header and the first rows.
_HEAD_BYTES = 2**16


class CsvFile:
    """A CSV file opened for reading: its head read (the layout of its rows, the columns, the
    notes), its body read piece by piece (:meth:`pieces`), from any piece's offset
    (:meth:`read_piece`), each piece parsed on its own (:meth:`parse`) and the parts joined
    into one table (:meth:`table`)."""

    def __init__(self, path: PathLike, *, columns: Mapping[str, Column] | None,
                 wide: Mapping[str, tuple[Column, ...]] | None = None, strict: bool):
        self.path = check_file(path)
        self.src, self.stem, self.strict = str(path), stem(path), strict
        self.wide = dict(wide or {})
        with open(self.path, "rb") as fh:
            data, head = b"", None
            for block, _, _ in byte_blocks(fh, _HEAD_BYTES, count=False):
                data += block
                head = _head(data, False, self.src, columns, self.wide, strict)
                if head is not None:
                    break
        if head is None:
            if not data.decode("utf-8-sig", errors="replace").strip():
                raise InputError(f"{self.src}: file is empty")
            head = _head(data, True, self.src, columns, self.wide, strict)
        self.head, self.layout, self.columns = head, head.layout, head.columns

    def pieces(self, block_bytes: int = BLOCK_BYTES) -> Iterator[tuple[int, bytes, int, int]]:
        """`(byte offset, bytes, first line, line ends)` of each piece of the body, in order."""
        with open(self.path, "rb") as fh:
            fh.seek(self.head.offset)
            offset = self.head.offset
            for block, line, ends in byte_blocks(fh, block_bytes, line=self.head.first_line):
                yield offset, block, line, ends
                offset += len(block)

    def read_piece(self, offset: int, nbytes: int) -> bytes:
        """The bytes of a piece that :meth:`pieces` gave."""
        with open(self.path, "rb") as fh:
            fh.seek(offset)
            return fh.read(nbytes)

    def parse(self, data: bytes, first_line: int, ends: int, exact: bool = False) -> Part:
        """The rows of a piece: by pyarrow where it reads them cleanly, else (or with
        `exact`) by the exact reader."""
        part = None if exact else _fast(data, first_line, ends, self.layout)
        return part if part is not None else _exact(data, first_line, self.layout)

    def table(self, parts: list[Part], *, whole: bool = True) -> ReadColumns:
        """The parts as one table; `whole`: the parts are the whole body (the notes on blank
        lines and unused columns are then those of the file, and no rows is an error)."""
        lay, notes = self.layout, list(self.head.notes)
        n, values, lines, blank, empty = _join(parts, lay)
        blank += self.head.blank
        if whole and blank and not self.strict:
            notes.insert(1 if lay.trailing else 0, f"{blank} empty line(s) skipped")
        if whole and n == 0:
            raise InputError(f"{self.src}: header only, no data rows")
        if whole and not self.strict:
            unused = []
            for j in lay.unused:
                if empty[j] >= _MOSTLY_EMPTY * n:
                    notes.append(f"column {lay.names[j]!r} is mostly empty ({n - empty[j]} of "
                                 f"{n} cells filled), not used")
                else:
                    unused.append(repr(lay.names[j]))
            if unused:
                notes.append(f"column(s) {', '.join(unused)} not used")
        return ReadColumns(self.src, self.stem, n, dict(self.columns), self.wide, values, lines,
                           notes)


def read_csv(
    path: PathLike,
    *,
    columns: Mapping[str, Column] | None,
    wide: Mapping[str, tuple[Column, ...]] | None = None,
    strict: bool,
    block_bytes: int = BLOCK_BYTES,
    exact: bool = False,
) -> ReadColumns:
    """Read the columns of a CSV file: those given, or those named `<quantity>_<unit>` (see
    the module notes). `block_bytes`: the size of a block; `exact`: read every block with the
    exact reader (the reference the fast one is tested against)."""
    f = CsvFile(path, columns=columns, wide=wide, strict=strict)
    parts = [f.parse(data, line, ends, exact) for _, data, line, ends in f.pieces(block_bytes)
             if data]
    return f.table(parts)


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
    other column names: pass a `mrjax.data.DataSpec` to `mrjax.data.load`. Parquet and
    Feather files with the same columns: `mrjax.data.load_columnar`.

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
