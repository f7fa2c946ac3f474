"""Parquet and Feather (Arrow IPC) files in the long layout, read by pyarrow.

The columns are those of the long CSV format (`condition`, `time_s`, `displacement_mm`, ...:
names that carry their unit, see `mrjax.data.load_csv`), or any names through a data spec
(`"Disp:cm"`; a bare integer is a column position). Only the columns asked for are read, one
piece (a Parquet row group, an Arrow record batch) at a time, straight into float64 arrays and
integer codes of the `condition` column; a pandas index stored as a column
(`__index_level_0__`) is ignored. The checks and messages are those of the CSV format, rows
numbered from 0 as pyarrow and pandas number them: a null is an "empty cell", text that is not
a number is named with its row and column, and the values then go through the same checks
(`mrjax.data.Condition`) as any file's.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._errors import InputError
from ._build import Codes, ReadColumns, assemble
from ._columns import Column, Meta
from ._condition import Condition
from ._csv import column_index, conventional_columns
from ._files import PathLike, check_file, stem
from ._pieces import join_codes, join_floats_lazily, view
from ._progress import advance

#: File extensions read as Parquet and as Feather (Arrow IPC).
PARQUET_SUFFIXES: tuple[str, ...] = (".parquet", ".pq")
FEATHER_SUFFIXES: tuple[str, ...] = (".feather", ".arrow")
_INDEX = re.compile(r"__index_level_\d+__")


def _kind(path: Path) -> str:
    return "Parquet" if path.suffix.lower() in PARQUET_SUFFIXES else "Feather"


class ColumnarFile:
    """A Parquet or Feather file opened for reading: its schema and columns, its pieces
    (Parquet row groups, Arrow record batches) read one at a time (:meth:`pieces`,
    :meth:`read_piece`) and joined into one table (:meth:`table`)."""

    def __init__(self, path: PathLike, *, columns: Mapping[str, Column] | None,
                 wide: Mapping[str, tuple[Column, ...]] | None = None, strict: bool):
        p = check_file(path)
        self.src, self.stem, self.strict = str(path), stem(path), strict
        self.kind = _kind(p)
        self.size = p.stat().st_size
        self._file: Any = None
        schema, rows = self._open(p)
        #: first row of each piece, and the number of rows
        self.starts = np.concatenate([[0], np.cumsum(rows)]).astype(np.int64)
        self.n_rows = int(self.starts[-1])
        names = [n for n in schema.names if not _INDEX.fullmatch(str(n))]
        self.header = [str(n) for n in names]
        if len(set(self.header)) != len(self.header):
            dup = next(h for h in self.header if self.header.count(h) > 1)
            raise InputError(f"{self.src}: column {dup!r} appears twice")
        if self.n_rows == 0:
            raise InputError(f"{self.src}: no data rows")
        self.wide = dict(wide or {})
        if columns is None:
            columns = conventional_columns(self.header, self.src, strict)
        self.columns = dict(columns)
        asked = list(self.columns.items()) + [(r, c) for r, cs in self.wide.items() for c in cs]
        self.index = {c: column_index(self.header, c, role, self.src) for role, c in asked}
        self.used = sorted(set(self.index.values()))
        self._names = [names[j] for j in self.used]

    def _open(self, p: Path) -> tuple[Any, list[int]]:
        """Open the file: `self._file` set; returns its schema and the rows of each piece."""
        import pyarrow as pa

        try:
            if self.kind == "Parquet":
                import pyarrow.parquet as pq

                self._file = pq.ParquetFile(p)
                schema = self._file.schema_arrow
                rows = [self._file.metadata.row_group(i).num_rows
                        for i in range(self._file.num_row_groups)]
            else:
                try:
                    self._file = pa.ipc.open_file(pa.OSFile(str(p)))
                except pa.ArrowInvalid:  # Feather version 1: read whole
                    import pyarrow.feather as feather

                    self._file = feather.read_table(str(p), memory_map=False).combine_chunks()
                schema = self._file.schema
                rows = ([self._file.num_rows] if isinstance(self._file, pa.Table)
                        else [self._file.get_batch(i).num_rows
                              for i in range(self._file.num_record_batches)])
        except (pa.ArrowException, OSError, ValueError) as e:
            raise InputError(f"{self.src}: not a readable {self.kind} file "
                             f"({one_line(e)})") from None
        return schema, rows

    def __getstate__(self) -> dict[str, Any]:
        """Pickled without the open file (e.g. for a worker of a Dask cluster)."""
        return {**self.__dict__, "_file": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickled: the file is opened again when a piece is first read."""
        self.__dict__.update(state)

    @property
    def n_pieces(self) -> int:
        return len(self.starts) - 1

    def read_piece(self, i: int) -> dict[Column, Any]:
        """The columns asked for of piece `i` (float64 arrow arrays; `Codes` for the
        `condition` column), checked."""
        import pyarrow as pa

        if self._file is None:  # unpickled
            self._open(Path(self.src).expanduser())
        try:
            if self.kind == "Parquet":
                batch = self._file.read_row_group(i, columns=self._names)
            elif isinstance(self._file, pa.Table):
                batch = self._file.select(self._names)
            else:
                batch = self._file.get_batch(i).select(self._names)
        except (pa.ArrowException, OSError) as e:
            raise InputError(f"{self.src}: not a readable {self.kind} file "
                             f"({one_line(e)})") from None
        row0 = int(self.starts[i])
        out = {}
        for c, j in self.index.items():
            arr = batch.column(self.used.index(j))
            if isinstance(arr, pa.ChunkedArray):
                arr = arr.combine_chunks()
            read = _floats if c.unit is not None else _codes
            out[c] = read(arr, self.header[j], row0, self.src)
        advance(int(self.size * (self.starts[i + 1] - row0) / max(self.n_rows, 1)))
        return out

    def table(self, parts: list[dict[Column, Any]], *, whole: bool = True) -> ReadColumns:
        """The pieces read as one table; `whole`: all of them (the notes are then those of
        the file)."""
        values = {c: join_floats_lazily([p[c] for p in parts]) if c.unit is not None
                  else join_codes([p[c] for p in parts]) for c in self.index}
        n = sum(len(next(iter(p.values()))) for p in parts) if parts else 0
        notes = []
        unused = [repr(h) for j, h in enumerate(self.header) if j not in self.used]
        if whole and unused and not self.strict:
            notes.append(f"column(s) {', '.join(unused)} not used")
        return ReadColumns(self.src, self.stem, n, self.columns, self.wide, values, None, notes)


def one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def _floats(arr: Any, name: str, row0: int, src: str) -> Any:
    """A column of a batch as float64 (arrow), or the error naming the first bad row."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if pa.types.is_dictionary(arr.type):
        arr = arr.dictionary_decode()
    if arr.null_count:
        k = int(np.flatnonzero(arr.is_null().to_numpy(zero_copy_only=False))[0])
        raise InputError(f"{src}, row {row0 + k}, column {name!r}: empty cell")
    t = arr.type
    if pa.types.is_floating(t) or pa.types.is_integer(t) or pa.types.is_decimal(t):
        return pc.cast(arr, pa.float64())
    if pa.types.is_string(t) or pa.types.is_large_string(t):
        try:
            return pc.cast(pc.utf8_trim_whitespace(arr), pa.float64())
        except pa.ArrowInvalid:
            for k, cell in enumerate(arr.to_pylist()):  # the error path: find the bad cell
                try:
                    float(cell.strip())
                except ValueError:
                    what = "empty cell" if not cell.strip() else f"not a number: {cell!r}"
                    raise InputError(f"{src}, row {row0 + k}, column {name!r}: {what}") from None
            raise
    raise InputError(f"{src}: column {name!r} holds {t}, not numbers")


def _codes(arr: Any, name: str, row0: int, src: str) -> Codes:
    """A `condition` column of a batch as codes of its (stripped) text."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if arr.null_count:
        k = int(np.flatnonzero(arr.is_null().to_numpy(zero_copy_only=False))[0])
        raise InputError(f"{src}, row {row0 + k}, column {name!r}: empty cell")
    if not pa.types.is_dictionary(arr.type):
        arr = pc.dictionary_encode(arr if pa.types.is_string(arr.type)
                                   else pc.cast(arr, pa.string()))
    labels = [str(s).strip() for s in arr.dictionary.to_pylist()]
    codes = view(arr.indices, str(arr.indices.type)).astype(np.int32, copy=False)
    if not all(labels):
        bad = {j for j, s in enumerate(labels) if not s}
        k = int(np.flatnonzero(np.isin(codes, list(bad)))[0])
        raise InputError(f"{src}, row {row0 + k}, column {name!r}: empty cell")
    return join_codes([Codes(codes, tuple(labels))])  # labels equal once stripped: one code


def read_columnar(
    path: PathLike,
    *,
    columns: Mapping[str, Column] | None,
    wide: Mapping[str, tuple[Column, ...]] | None = None,
    strict: bool,
) -> ReadColumns:
    """Read the columns of a Parquet or Feather file: those given, or those named
    `<quantity>_<unit>` (see the module notes)."""
    f = ColumnarFile(path, columns=columns, wide=wide, strict=strict)
    return f.table([f.read_piece(i) for i in range(f.n_pieces)])


def load_columnar(path: PathLike, *,
                  velocity_window_s: float | None = None) -> list[Condition]:
    """Load one or more tests from a Parquet (`.parquet`, `.pq`) or Feather (`.feather`,
    `.arrow`: Arrow IPC) file in the long layout.

    One row per sample, the columns of the long CSV format (see `mrjax.data.load_csv`):
    names that carry their unit (`time_s`, `displacement_mm`, `velocity_m_s`, `force_N`,
    `current_A`, optional `frequency_Hz`, `amplitude_mm`), several tests told apart by a
    `condition` column (text, or integers); every column must be one of them. Numbers may be
    stored as integers, floats, decimals or text. Files with other column names: pass a
    `mrjax.data.DataSpec` to `mrjax.data.load`. Write one from Python with
    `mrjax.data.to_frame(conditions).to_parquet(path)`.

    **Arguments:**

    - `path`: the file.
    - `velocity_window_s`: smoothing window [s] of the velocity estimate (files without a
        velocity column only; default chosen from each record).

    **Returns:** a list of :class:`Condition` in SI units, one per condition, in order of
    first appearance.

    Raises :class:`mrjax.InputError` naming the file, and the row (from 0), column or
    condition at fault.
    """
    read = read_columnar(path, columns=None, strict=True)
    return assemble(read, meta=Meta(), window_s=velocity_window_s, strict=True)
