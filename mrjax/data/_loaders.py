"""Load test files into SI :class:`Condition`s: by their own conventions, or by a data spec.

- `.txt` / `.dat`: headerless whitespace columns `t, x, xdot, F` or `t, x, F`,
    one test per file, units by argument (default `s, mm, mm/s, N`), metadata from the file
    name (`25mm0x1Hz0x75A.txt` = 25 mm, 0.1 Hz, 0.75 A). (`mrjax.data.load_txt`)
- `.csv`: long format with a header whose column names carry their units (`time_s`,
    `displacement_mm`, ...), several tests told apart by a `condition` column.
    (`mrjax.data.load_csv`)
- `.mat`: MATLAB files (up to v7), variables named by the user. (`mrjax.data.load_mat`)
- `.parquet` / `.pq`, `.feather` / `.arrow`: columnar files in the long layout of the CSV
    format. (`mrjax.data.load_columnar`)
- **Any other layout** (own column names, any units, no time vector, one test per column,
    metadata per file): a `mrjax.data.DataSpec`, `load(paths, spec=...)`.

Every loader checks what it reads and raises :class:`mrjax.InputError` with a one-line message
naming the file and the line, column, variable or argument at fault. The checks on the values
themselves (finite, equal lengths, increasing time, enough samples, non-negative metadata) are
those of :class:`Condition`, which is given the file as its `source`. Every file goes through
one path (`_build.assemble`): a reader per format finds the columns, then units, tests,
metadata, time axis, velocity and the sanity checks are handled once for all formats.
"""

from __future__ import annotations

import dataclasses
import inspect
import warnings
from collections.abc import Sequence
from pathlib import Path

from .._errors import InputError
from .._warnings import ResultWarning, WarningKind
from ._build import ReadColumns, assemble
from ._columnar import (
    FEATHER_SUFFIXES,
    PARQUET_SUFFIXES,
    ColumnarFile,
    load_columnar,
    read_columnar,
)
from ._columns import Meta
from ._condition import Batch, Condition, make_batch
from ._csv import CsvFile, load_csv, read_csv
from ._files import PathLike, find_files, label_meta
from ._mat import load_mat, read_mat
from ._progress import load_progress
from ._spec import DataSpec, spec_matches
from ._text import load_txt, read_text

_LOADERS = {".csv": load_csv, ".txt": load_txt, ".dat": load_txt, ".mat": load_mat,
            **{s: load_columnar for s in PARQUET_SUFFIXES + FEATHER_SUFFIXES}}
_READERS = {".csv": read_csv, ".txt": read_text, ".dat": read_text, ".mat": read_mat,
            **{s: read_columnar for s in PARQUET_SUFFIXES + FEATHER_SUFFIXES}}
#: The formats read piece by piece (a chunk of tests can be read alone).
_PIECEWISE = {".csv": CsvFile, **{s: ColumnarFile for s in PARQUET_SUFFIXES + FEATHER_SUFFIXES}}



def load_file(path: PathLike, spec: DataSpec) -> list[Condition]:
    """The conditions of one file read by `spec` (see `mrjax.data.DataSpec`).

    **Arguments:** `path`: a data file (`.csv`, `.txt`, `.dat`, `.mat`, `.parquet`, `.pq`,
    `.feather`, `.arrow`); `spec`: the data spec.

    **Returns:** a list of :class:`Condition` in SI units: one per test (a long CSV's
    `condition` values, the wide layout's columns), labelled by the spec's `label`, the
    condition value or the file name (with `_<k>` for the k-th wide column).

    Metadata not given stay unknown (frequency and amplitude are then estimated and marked in
    `Condition.estimated`); a velocity that is not given is estimated. Sanity warnings
    (`RuntimeWarning`) name the file.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in _READERS:
        raise InputError(f"{path}: unknown file type {suffix or '(none)'!r}")
    columns = dict(spec.columns) if (spec.columns or spec.wide) else None
    read = _READERS[suffix](path, columns=columns, wide=spec.wide, strict=False)
    return assemble(read, meta=spec.file_meta(path), wide_meta=spec.wide_meta,
                    window_s=spec.velocity_window, strict=False, fallback=label_meta(path))


def load(
    paths: PathLike | Sequence[PathLike],
    *,
    spec: DataSpec | None = None,
    progress: bool | None = None,
    **options,
) -> list[Condition]:
    """Load test conditions from files, directories, or a list of them.

    **Arguments:**

    - `paths`: a file, a directory (every data file directly inside it, sorted by name), or a
        list of files and directories (see `mrjax.data.find_files`).
    - `spec`: a `mrjax.data.DataSpec` saying where the signals are and in which units, plus
        metadata and the velocity window: for files with their own column names, units and
        layouts. Without one (or with an empty one) every file is read by the conventions of
        its format and `**options`.
    - `**options`: without a spec, keyword options of the loader of each file type:
        `mrjax.data.load_csv` (`.csv`), `mrjax.data.load_txt` (`.txt`, `.dat`),
        `mrjax.data.load_mat` (`.mat`), `mrjax.data.load_columnar` (`.parquet`, `.pq`,
        `.feather`, `.arrow`). An option that the loader of some file does not take is an
        error, not silently ignored.

    **Returns:** a list of :class:`Condition` in SI units, in file order (and, within a file,
    in order of first appearance of its tests).

    Raises :class:`mrjax.InputError` for a missing path, a directory without data files, an
    unknown file type or option, and anything the loaders or the spec reject. Warns
    (`RuntimeWarning`) about a likely unit mix-up, a broadband record whose velocity is
    estimated, and a spec `files` pattern that matches no file.
    """
    files = find_files(paths)
    if spec is not None and not isinstance(spec, DataSpec):
        raise InputError(f"spec must be a mrjax.data.DataSpec, got {type(spec).__name__}")
    with load_progress(sum(f.stat().st_size for f in files), progress):
        return _load(files, spec, options)


def _load(files: list[Path], spec: DataSpec | None, options: dict) -> list[Condition]:
    out: list[Condition] = []
    for f in files:
        out += FilePlan.of(f, spec, options).load()
    warn_unmatched(spec, files)
    return out


def warn_unmatched(spec: DataSpec | None, files: Sequence[Path]) -> None:
    """Warn about each `files` pattern of `spec` that matches none of `files`."""
    for pattern in spec.files if spec is not None else ():
        if not any(spec_matches(pattern, f) for f in files):
            warnings.warn(ResultWarning(
                WarningKind.SPEC_UNMATCHED, f"{spec.origin or 'data spec'}: files entry "
                f"{pattern!r} matches none of the {len(files)} file(s) loaded",
                parameters=(pattern,)), stacklevel=4)


@dataclasses.dataclass(frozen=True)
class FilePlan:
    """How `mrjax.data.load` reads one file (by `spec`, or by its format's conventions and
    `options`): the whole file at once (:meth:`load`), or, for the formats read piece by piece
    (CSV, Parquet, Feather), the opened reader (:meth:`open`) whose table :meth:`finish`
    turns into conditions."""

    path: Path
    spec: DataSpec | None
    options: dict

    @classmethod
    def of(cls, path: Path, spec: DataSpec | None, options: dict) -> FilePlan:
        """The plan of one file; raises for options that its loader does not take."""
        if spec is not None and spec.is_empty:
            spec = None
        if spec is not None and options:
            raise InputError(
                f"give a spec or loader options ({', '.join(options)}), not both; the spec "
                f"covers them (e.g. velocity_window)"
            )
        suffix = path.suffix.lower()
        if spec is None:
            accepted = [n for n, prm in inspect.signature(_LOADERS[suffix]).parameters.items()
                        if prm.kind is inspect.Parameter.KEYWORD_ONLY]
            bad = [k for k in options if k not in accepted]
            if bad:
                raise InputError(
                    f"{path}: option {bad[0]!r} does not apply to {suffix} files; "
                    f"their options: {', '.join(accepted)}"
                )
        return cls(path, spec, dict(options))

    def load(self) -> list[Condition]:
        """The conditions of the whole file."""
        if self.spec is not None:
            return load_file(self.path, self.spec)
        result = _LOADERS[self.path.suffix.lower()](self.path, **self.options)
        return result if isinstance(result, list) else [result]

    def open(self) -> CsvFile | ColumnarFile | None:
        """The file opened for reading piece by piece, or None for a format read whole."""
        kind = _PIECEWISE.get(self.path.suffix.lower())
        if kind is None:
            return None
        if self.spec is None:
            return kind(self.path, columns=None, strict=True)
        columns = dict(self.spec.columns) if (self.spec.columns or self.spec.wide) else None
        return kind(self.path, columns=columns, wide=self.spec.wide, strict=False)

    def finish(self, read: ReadColumns) -> list[Condition]:
        """The conditions of (a part of) the table of an opened file, as :meth:`load` makes
        them."""
        if self.spec is None:
            return assemble(read, meta=Meta(), window_s=self.options.get("velocity_window_s"),
                            strict=True)
        return assemble(read, meta=self.spec.file_meta(self.path), wide_meta=self.spec.wide_meta,
                        window_s=self.spec.velocity_window, strict=False,
                        fallback=label_meta(self.path))

    @property
    def n_wide(self) -> int:
        """Tests per row: the columns of a wide layout (1 without one)."""
        return max(1, self.spec.n_wide) if self.spec is not None else 1


def load_batch(
    paths: PathLike | Sequence[PathLike],
    *,
    spec: DataSpec | None = None,
    length: int | None = None,
    dtype=None,
    progress: bool | None = None,
    **options,
) -> Batch:
    """Load conditions (as `mrjax.data.load`) and stack them into a padded :class:`Batch`.

    **Arguments:**

    - `paths`, `spec`, `progress`, `**options`: as for `mrjax.data.load`.
    - `length`, `dtype`: as for `mrjax.data.make_batch`.

    **Returns:** `make_batch(load(paths, spec=spec, **options), length=length, dtype=dtype)`.
    """
    return make_batch(load(paths, spec=spec, progress=progress, **options), length=length,
                      dtype=dtype)
