"""Files and their names: which files to read, and the metadata a file name carries.

A name such as `25mm0x1Hz0x75A.txt` says 25 mm, 0.1 Hz, 0.75 A (`x` or `p` = decimal point);
:func:`parse_label` reads it. :func:`find_files` expands files and directories into the list of
data files that `mrjax.data.load` reads.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

from .._errors import InputError
from ._columns import Meta

PathLike = str | os.PathLike

#: File extensions that `mrjax.data.load` reads.
DATA_SUFFIXES: tuple[str, ...] = (".csv", ".txt", ".dat", ".mat", ".parquet", ".pq", ".feather",
                                  ".arrow")

_NUM = r"\d+(?:[xXpP.]\d+)?"
_SEP = r"[_\-\s]*"
_LABEL_RE = re.compile(
    rf"(?:.*[_\-\s])?(?P<a>{_NUM})(?P<au>mm|m){_SEP}(?P<f>{_NUM})(?:Hz|hz|HZ){_SEP}"
    rf"(?P<i>{_NUM})(?P<iu>mA|A)(?:[_\-\s].*)?"
)


def stem(path: PathLike) -> str:
    """File name without a known data extension (`25mm0x1Hz0x75A.txt` -> `25mm0x1Hz0x75A`)."""
    name = Path(path).name
    suffix = Path(name).suffix
    return name[: -len(suffix)] if suffix.lower() in DATA_SUFFIXES else name


def _number(text: str) -> float:
    return float(re.sub(r"[xXpP]", ".", text))


def check_file(path: PathLike) -> Path:
    """The path of an existing, non-empty file, or an InputError naming it."""
    p = Path(path).expanduser()
    if not p.exists():
        raise InputError(f"{path}: no such file or directory")
    if not p.is_file():
        raise InputError(f"{path}: not a file")
    if p.stat().st_size == 0:
        raise InputError(f"{path}: file is empty")
    return p


def parse_label(name: PathLike) -> tuple[float, float, float]:
    """Amplitude, frequency and current from a file name such as `25mm0x1Hz0x75A`.

    **Arguments:**

    - `name`: a file name or path (a data file's extension, e.g. `.txt`, is ignored) of
        the form `<amplitude>mm<frequency>Hz<current>A`. The decimal point may be written `x`,
        `p` or `.`; `_`, `-` or spaces may separate the three parts, and the name may carry a
        prefix or suffix set off by one of them (`damper_25mm0p1Hz_0p75A_run2`). The amplitude
        may also be in `m` and the current in `mA`.

    **Returns:** `(amplitude [m], frequency [Hz], current [A])`, e.g. `(0.025, 0.1, 0.75)`.

    Raises :class:`mrjax.InputError` naming the file if the name does not fit the pattern.
    """
    s = stem(name)
    m = _LABEL_RE.fullmatch(s)
    if m is None:
        raise InputError(
            f"{name}: cannot read amplitude, frequency and current from the file name {s!r}; "
            f"expected e.g. 25mm0x1Hz0x75A (25 mm, 0.1 Hz, 0.75 A; x or p = decimal point)"
        )
    amplitude = _number(m["a"]) * (1e-3 if m["au"] == "mm" else 1.0)
    frequency = _number(m["f"])
    current = _number(m["i"]) * (1e-3 if m["iu"] == "mA" else 1.0)
    return amplitude, frequency, current


def name_meta(path: PathLike, given: Meta) -> Meta:
    """`given` completed from the file name where it lacks current, frequency or amplitude
    (the loaders without a spec). A name that does not parse is an error naming the missing
    keywords."""
    if given.current is not None and given.frequency is not None and given.amplitude is not None:
        return given
    try:
        amplitude, frequency, current = parse_label(path)
    except InputError:
        missing = ", ".join(f"{k}=" for k in ("current", "frequency", "amplitude")
                            if getattr(given, k) is None)
        raise InputError(
            f"{path}: cannot read amplitude, frequency and current from the file name "
            f"{stem(path)!r} (expected e.g. 25mm0x1Hz0x75A, x = decimal point); "
            f"pass {missing} or parse_name=False"
        ) from None
    return Meta(current=current, frequency=frequency, amplitude=amplitude).merged(given)


def label_meta(path: PathLike) -> Meta:
    """Current, frequency and amplitude read from a file name, or nothing if it does not parse
    (the weakest source of metadata when a spec is given)."""
    try:
        amplitude, frequency, current = parse_label(path)
    except InputError:
        return Meta()
    return Meta(current=current, frequency=frequency, amplitude=amplitude)


def find_files(paths: PathLike | Sequence[PathLike]) -> list[Path]:
    """The data files named by `paths`, in the order `mrjax.data.load` reads them.

    **Arguments:** `paths`: a file, a directory (every data file directly inside it: `.csv`,
    `.txt`, `.dat`, `.mat`, `.parquet`, `.pq`, `.feather`, `.arrow`; sorted by name, hidden
    files skipped), or a list of files and directories.

    **Returns:** the list of files.

    Raises :class:`mrjax.InputError` for a missing path, a directory without data files, an
    unknown file type or an empty list.
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    files: list[Path] = []
    for item in paths:
        p = Path(item).expanduser()
        if not p.exists():
            raise InputError(f"{item}: no such file or directory")
        if p.is_dir():
            found = sorted(
                (q for q in p.iterdir() if q.is_file() and not q.name.startswith(".")
                 and q.suffix.lower() in DATA_SUFFIXES),
                key=lambda q: q.name,
            )
            if not found:
                raise InputError(
                    f"{item}: directory has no data files ({', '.join(DATA_SUFFIXES)})"
                )
            files += found
        elif p.suffix.lower() in DATA_SUFFIXES:
            files.append(p)
        else:
            raise InputError(
                f"{item}: unknown file type {p.suffix or '(none)'!r}; "
                f"expected one of {', '.join(DATA_SUFFIXES)}"
            )
    if not files:
        raise InputError("no data files given (empty list of paths)")
    return files

