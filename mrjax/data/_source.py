"""Test conditions that stay in their files: indexed by one pass, read a chunk of tests at a time.

A fleet's data may not fit in memory next to the fit. :meth:`Source.scan` reads every file
once, piece by piece (CSV blocks of `STREAM_BLOCK_BYTES`, Parquet row groups, Arrow record
batches; a `.txt`, `.dat` or `.mat` file whole), checking every cell as `mrjax.data.load` does,
and keeps of each test only where its rows are (the pieces holding them) and how many samples
it has; the tests themselves are kept as well while they fit in `keep_bytes`. Then
:meth:`Source.conditions` and :meth:`Source.batch` read just the pieces that hold the tests
asked for and make them exactly as `mrjax.data.load` makes them (the same values, metadata,
labels and checks): a chunk of a fit costs the memory of its own tests.

`mrjax.fit` takes a `Source` and reads it chunk by chunk (see `mrjax.fitting.fit_in_chunks`);
`mrjax fit` scans its files into one when `--memory` cannot hold all the tests.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._errors import InputError
from ._build import Codes, ReadColumns, condition_keys
from ._columnar import ColumnarFile
from ._condition import Batch, Condition, make_batch
from ._csv import CsvFile, Part
from ._files import PathLike, find_files
from ._loaders import FilePlan, warn_unmatched
from ._pieces import join_floats
from ._progress import load_progress
from ._spec import DataSpec

#: Bytes per CSV piece of a source (a chunk of tests reads the pieces that hold them).
STREAM_BLOCK_BYTES = 2**20
#: Bytes per sample of a test held in a :class:`Batch` (t, x, xdot, force, dt, command in
#: float64, the mask).
BATCH_BYTES_PER_SAMPLE = 6 * 8 + 1


@dataclasses.dataclass
class _File:
    """One file of a source: how it is read, where its tests are, and the tests if kept.

    Within a file, test `t` is the `t // n_wide`-th `condition` value (coded in order of first
    appearance, as :func:`mrjax.data.load` orders them; one code without that column) and the
    `t % n_wide`-th column of a wide layout."""

    plan: FilePlan
    opened: CsvFile | ColumnarFile | None  # None: read whole
    n_samples: list[int]  # per test
    pieces: list[tuple[Any, frozenset[int]]]  # (where, codes with rows in it)
    labels: dict[str | None, int]  # `condition` value -> code
    kept: list[Condition] | None


class Source:
    """Test conditions in files, indexed by one pass and read on demand (see the module
    notes). Built by :meth:`scan`.

    **Attributes:** `files` (the data files), `n_conditions`, `n_samples` (C,) samples per
    test, `length` (the longest), `kept` (whether every test is held in memory).
    """

    def __init__(self, files: list[_File], paths: list[Path]):
        self._files = files
        self.files = tuple(paths)
        self._where = [(k, t) for k, f in enumerate(files) for t in range(len(f.n_samples))]
        self.n_samples = np.asarray([n for f in files for n in f.n_samples], dtype=np.int64)

    @property
    def n_conditions(self) -> int:
        """Number of tests C."""
        return len(self._where)

    def __len__(self) -> int:
        return self.n_conditions

    @property
    def length(self) -> int:
        """Samples of the longest test (the padded length of a batch of all of them)."""
        return int(self.n_samples.max()) if self.n_samples.size else 0

    @property
    def kept(self) -> bool:
        """Whether every test is held in memory (then nothing is read again)."""
        return all(f.kept is not None for f in self._files)

    def batch_bytes(self, n: int | None = None) -> int:
        """Bytes of a :class:`Batch` of `n` tests (default all) at the full padded length."""
        return int((self.n_conditions if n is None else n) * self.length
                   * BATCH_BYTES_PER_SAMPLE)

    def __repr__(self) -> str:
        return (f"Source(C={self.n_conditions}, T={self.length}, files={len(self.files)}, "
                f"kept={self.kept})")

    @classmethod
    def scan(
        cls,
        paths: PathLike | Sequence[PathLike],
        *,
        spec: DataSpec | None = None,
        keep_bytes: int | None = None,
        progress: bool | None = None,
        **options: Any,
    ) -> Source:
        """Index the tests of files (one pass), keeping them while they fit `keep_bytes`.

        **Arguments:**

        - `paths`, `spec`, `progress`, `**options`: as for `mrjax.data.load`.
        - `keep_bytes`: the most bytes of parsed columns to hold while scanning (default: no
            limit: every test is kept, as `mrjax.data.load` keeps them); past it nothing is
            held and the tests are read again when asked for.

        **Returns:** the :class:`Source`.

        Raises :class:`mrjax.InputError` for everything `mrjax.data.load` rejects in the
        files' cells; the checks of each test's values (`mrjax.data.Condition`) and the
        sanity warnings come with the test (here for the kept ones, else from
        :meth:`conditions`).
        """
        files = find_files(paths)
        if spec is not None and not isinstance(spec, DataSpec):
            raise InputError(f"spec must be a mrjax.data.DataSpec, got {type(spec).__name__}")
        left = [np.inf if keep_bytes is None else float(keep_bytes)]
        out: list[_File] = []
        with load_progress(sum(f.stat().st_size for f in files), progress):
            for path in files:
                out.append(_scan_file(FilePlan.of(path, spec, options), left))
                if left[0] < 0:  # over the limit: hold nothing
                    for e in out:
                        e.kept = None
        warn_unmatched(spec, files)
        return cls(out, files)

    def conditions(self, index: Sequence[int] | np.ndarray | None = None, *,
                   warn: bool = True) -> list[Condition]:
        """The tests at `index` (ints or a boolean mask; default all), made as
        `mrjax.data.load` makes them, reading only the pieces of the files that hold them.

        **Arguments:** `index`; `warn`: issue the sanity warnings (`RuntimeWarning`) of the
        tests read (they are in `Condition.warnings` either way).

        **Returns:** a list of :class:`Condition`, in the order of `index`.
        """
        idx = np.arange(self.n_conditions)[slice(None) if index is None else np.asarray(index)]
        out: list[Condition | None] = [None] * idx.size
        by_file: dict[int, list[tuple[int, int]]] = {}
        for pos, i in enumerate(idx):
            k, t = self._where[int(i)]
            by_file.setdefault(k, []).append((pos, t))
        with warnings.catch_warnings():
            if not warn:
                warnings.simplefilter("ignore", RuntimeWarning)
            for k, asked in by_file.items():
                got = _read(self._files[k], {t for _, t in asked})
                for pos, t in asked:
                    out[pos] = got[t]
        return out  # type: ignore[return-value]

    def batch(self, index: Sequence[int] | np.ndarray | None = None, *,
              length: int | None = None, dtype: Any = None, warn: bool = True) -> Batch:
        """The tests at `index` (default all) as a padded :class:`Batch` of `length` samples
        (default: the longest of them; `source.length` gives every chunk of a fit the length
        of the whole), read as :meth:`conditions` reads them."""
        return make_batch(self.conditions(index, warn=warn), length=length, dtype=dtype)


# ------------------------------------------------------------------------------------ pieces


def _row_codes(opened: CsvFile | ColumnarFile, values: dict, labels: dict, n: int,
               grow: bool) -> np.ndarray:
    """The code of each row of a piece (`labels`: value -> code, extended with new values
    when `grow`)."""
    col = opened.columns.get("condition")
    if col is None:
        labels.setdefault(None, 0)
        return np.zeros(n, dtype=np.int32)
    local: Codes = values[col]
    remap = np.asarray([labels.setdefault(s, len(labels)) if grow else labels.get(s, -1)
                        for s in local.names], dtype=np.int32)
    return remap[local.codes] if remap.size else np.zeros(0, np.int32)


def _parts(opened: CsvFile | ColumnarFile) -> Any:
    """`(where, part, values, rows)` of every piece of an opened file, in order."""
    if isinstance(opened, CsvFile):
        for offset, data, line, ends in opened.pieces(STREAM_BLOCK_BYTES):
            if data:
                part = opened.parse(data, line, ends)
                yield (offset, len(data), line, ends), part, part.values, part.n
    else:
        for i in range(opened.n_pieces):
            part = opened.read_piece(i)
            yield i, part, part, int(opened.starts[i + 1] - opened.starts[i])


def _read_piece(opened: CsvFile | ColumnarFile, where: Any) -> tuple[Any, dict, int]:
    """`(part, values, rows)` of one piece."""
    if isinstance(opened, CsvFile):
        offset, nbytes, line, ends = where
        part = opened.parse(opened.read_piece(offset, nbytes), line, ends)
        return part, part.values, part.n
    part = opened.read_piece(where)
    return part, part, int(opened.starts[where + 1] - opened.starts[where])


def _scan_file(plan: FilePlan, left: list[float]) -> _File:
    """Index one file (`left`: bytes that may still be held; negative: hold nothing)."""
    opened = plan.open()
    if opened is None:
        conds = plan.load()
        left[0] -= sum(4 * c.t.nbytes for c in conds)
        return _File(plan, None, [c.n_samples for c in conds], [], {}, conds)
    labels: dict[str | None, int] = {}
    counts = np.zeros(0, np.int64)
    pieces, parts = [], []
    for where, part, values, n in _parts(opened):
        codes = _row_codes(opened, values, labels, n, grow=True)
        counts = np.concatenate([counts, np.zeros(len(labels) - counts.size, np.int64)])
        counts += np.bincount(codes, minlength=len(labels))
        pieces.append((where, frozenset(np.unique(codes).tolist())))
        if left[0] >= 0:
            parts.append(part)
            left[0] -= sum(int(v.nbytes) if hasattr(v, "nbytes") else 4 * len(v)
                           for v in values.values())
            if left[0] < 0:
                parts = []  # over the limit: let them go
    if not pieces:
        opened.table([])  # the file's own error (no data rows)
    kept = plan.finish(opened.table(parts)) if left[0] >= 0 else None
    n_wide = plan.n_wide
    n_samples = [int(counts[t // n_wide]) for t in range(counts.size * n_wide)]
    return _File(plan, opened, n_samples, pieces, labels, kept)


def _taken(opened: CsvFile | ColumnarFile, part: Any, keep: np.ndarray) -> Any:
    """The rows `keep` (boolean) of a part."""
    values = part.values if isinstance(part, Part) else part
    taken = {c: Codes(v.codes[keep], v.names) if isinstance(v, Codes)
             else join_floats([v])[keep] for c, v in values.items()}
    if isinstance(part, Part):
        return Part(int(keep.sum()), taken, part.lines.taken(np.flatnonzero(keep)), 0, {})
    return taken


def _read(f: _File, tests: set[int]) -> dict[int, Condition]:
    """The tests `tests` (indices within the file) of one file."""
    if f.kept is not None:
        return {t: f.kept[t] for t in tests}
    if f.opened is None:
        conds = f.plan.load()
        return {t: conds[t] for t in tests}
    n_wide = f.plan.n_wide
    want = np.asarray(sorted({t // n_wide for t in tests}), dtype=np.int32)
    parts = []
    for where, codes in f.pieces:
        if codes.isdisjoint(want.tolist()):
            continue
        part, values, n = _read_piece(f.opened, where)
        rows = _row_codes(f.opened, values, f.labels, n, grow=False)
        parts.append(_taken(f.opened, part, np.isin(rows, want)))
    read: ReadColumns = f.opened.table(parts, whole=False)
    conds = f.plan.finish(read)
    got = {}
    for b, key in enumerate(condition_keys(read)):
        for j in range(n_wide):
            t = f.labels[key] * n_wide + j
            if t in tests:
                got[t] = conds[b * n_wide + j]
    return got
