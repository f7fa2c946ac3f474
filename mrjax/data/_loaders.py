"""Loaders of measured test data: text, CSV and MATLAB files, into SI :class:`Condition`s.

- `.txt` / `.dat`: headerless whitespace columns `t, x, xdot, F` (UTFSM style) or `t, x, F`,
    one test per file, units by argument (default `s, mm, mm/s, N`), metadata from the file
    name (`25mm0x1Hz0x75A.txt` = 25 mm, 0.1 Hz, 0.75 A).
- `.csv`: long format with a header whose column names carry their units (`time_s`,
    `displacement_mm`, ...), several tests told apart by a `condition` column.
- `.mat`: MATLAB files (up to v7), variables named by the user.

Every loader checks what it reads and raises :class:`mrjax.InputError` with a one-line message
naming the file and the line, column, variable or argument at fault. The checks on the values
themselves (finite, equal lengths, increasing time, enough samples, non-negative metadata) are
those of :class:`Condition`, which is given the file as its `source`.
"""

from __future__ import annotations

import csv
import dataclasses
import inspect
import io
import os
import re
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .._errors import InputError
from ._condition import Batch, Condition, make_batch
from ._units import COLUMN_QUANTITIES, UNITS, parse_column, unit_scale
from ._velocity import estimate_velocity

PathLike = str | os.PathLike

#: File extensions that :func:`load` reads, and the loader of each.
DATA_SUFFIXES: tuple[str, ...] = (".csv", ".txt", ".dat", ".mat")

#: Default units of :func:`load_txt`: time, displacement, velocity, force (UTFSM files).
TXT_UNITS: tuple[str, str, str, str] = ("s", "mm", "mm/s", "N")
#: SI units, the default of :func:`load_mat`.
SI_UNITS: tuple[str, str, str, str] = ("s", "m", "m/s", "N")

_SIGNALS = ("t", "x", "xdot", "force")
_SIGNAL_QUANTITY = {"t": "time", "x": "length", "xdot": "velocity", "force": "force"}
_META = ("current", "frequency", "amplitude")
_META_UNIT = {"current": "A", "frequency": "Hz", "amplitude": "m"}

_NUM = r"\d+(?:[xXpP.]\d+)?"
_SEP = r"[_\-\s]*"
_LABEL_RE = re.compile(
    rf"(?:.*[_\-\s])?(?P<a>{_NUM})(?P<au>mm|m){_SEP}(?P<f>{_NUM})(?:Hz|hz|HZ){_SEP}"
    rf"(?P<i>{_NUM})(?P<iu>mA|A)(?:[_\-\s].*)?"
)


# --------------------------------------------------------------------------------------------
# Helpers


def _stem(path: PathLike) -> str:
    """File name without a known data extension (`25mm0x1Hz0x75A.txt` -> `25mm0x1Hz0x75A`)."""
    name = Path(path).name
    suffix = Path(name).suffix
    return name[: -len(suffix)] if suffix.lower() in DATA_SUFFIXES else name


def _number(text: str) -> float:
    return float(re.sub(r"[xXpP]", ".", text))


def _check_file(path: PathLike) -> Path:
    p = Path(path).expanduser()
    if not p.exists():
        raise InputError(f"{path}: no such file or directory")
    if not p.is_file():
        raise InputError(f"{path}: not a file")
    if p.stat().st_size == 0:
        raise InputError(f"{path}: file is empty")
    return p


def _scales(units: Sequence[str], where: str) -> dict[str, float]:
    """SI factors of (time, displacement, velocity, force) units."""
    if isinstance(units, str) or len(units) != 4:
        raise InputError(
            f"{where}: units must be 4 units (time, displacement, velocity, force), "
            f"e.g. ('s', 'mm', 'mm/s', 'N'); got {units!r}"
        )
    names = ("time", "displacement", "velocity", "force")
    return {
        sig: unit_scale(u, quantity=_SIGNAL_QUANTITY[sig], name=f"{where}: {name} unit")
        for sig, u, name in zip(_SIGNALS, units, names)
    }


def _meta_value(value, name: str, where: str) -> float | None:
    if value is None:
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {name} must be a number [{_META_UNIT[name]}], got {value!r}")


def _metadata(
    path: PathLike, given: dict[str, float | None], parse_name: bool
) -> dict[str, float | None]:
    """Metadata given as arguments, the rest read from the file name."""
    where = str(path)
    meta = {k: _meta_value(v, k, where) for k, v in given.items()}
    if parse_name and any(v is None for v in meta.values()):
        try:
            amplitude, frequency, current = parse_label(path)
        except InputError:
            missing = ", ".join(f"{k}=" for k, v in meta.items() if v is None)
            raise InputError(
                f"{where}: cannot read amplitude, frequency and current from the file name "
                f"{_stem(path)!r} (expected e.g. 25mm0x1Hz0x75A, x = decimal point); "
                f"pass {missing} or parse_name=False"
            ) from None
        parsed = {"current": current, "frequency": frequency, "amplitude": amplitude}
        meta = {k: parsed[k] if v is None else v for k, v in meta.items()}
    return meta


def _condition(
    label: str,
    meta: Mapping[str, float | None],
    t: np.ndarray,
    x: np.ndarray,
    xdot: np.ndarray | None,
    force: np.ndarray,
    source: str,
    window_s: float | None,
) -> Condition:
    """A checked :class:`Condition`; velocity estimated from `x` when `xdot` is None."""
    if xdot is not None:
        return Condition(label, meta["current"], meta["frequency"], meta["amplitude"],
                         t, x, xdot, force, source=source)
    x = np.asarray(x, dtype=float)
    cond = Condition(label, meta["current"], meta["frequency"], meta["amplitude"],
                     t, x, np.zeros_like(x), force, source=source)
    try:
        v = estimate_velocity(cond.t, cond.x, window_s=window_s)
    except InputError as e:
        raise InputError(f"{source}: no velocity column, and {e}") from None
    return dataclasses.replace(cond, xdot=v)


# --------------------------------------------------------------------------------------------
# File names


def parse_label(name: PathLike) -> tuple[float, float, float]:
    """Amplitude, frequency and current from a file name such as `25mm0x1Hz0x75A`.

    **Arguments:**

    - `name`: a file name or path (a `.txt`, `.dat`, `.csv` or `.mat` extension is ignored) of
        the form `<amplitude>mm<frequency>Hz<current>A`. The decimal point may be written `x`,
        `p` or `.`; `_`, `-` or spaces may separate the three parts, and the name may carry a
        prefix or suffix set off by one of them (`damper_25mm0p1Hz_0p75A_run2`). The amplitude
        may also be in `m` and the current in `mA`.

    **Returns:** `(amplitude [m], frequency [Hz], current [A])`, e.g. `(0.025, 0.1, 0.75)`.

    Raises :class:`mrjax.InputError` naming the file if the name does not fit the pattern.
    """
    stem = _stem(name)
    m = _LABEL_RE.fullmatch(stem)
    if m is None:
        raise InputError(
            f"{name}: cannot read amplitude, frequency and current from the file name {stem!r}; "
            f"expected e.g. 25mm0x1Hz0x75A (25 mm, 0.1 Hz, 0.75 A; x or p = decimal point)"
        )
    amplitude = _number(m["a"]) * (1e-3 if m["au"] == "mm" else 1.0)
    frequency = _number(m["f"])
    current = _number(m["i"]) * (1e-3 if m["iu"] == "mA" else 1.0)
    return amplitude, frequency, current


# --------------------------------------------------------------------------------------------
# Text files


def _parse_text_table(path: Path, names_for: Mapping[int, tuple[str, ...]]) -> np.ndarray:
    """Slow, exact parse of a whitespace/comma table, naming the line of any fault."""
    rows: list[list[float]] = []
    ncol = None
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            body = re.split(r"[#%]", line, maxsplit=1)[0].strip()
            if not body:
                continue
            cells = re.split(r"[\s,;]+", body)
            if ncol is None:
                ncol = len(cells)
                if ncol not in names_for:
                    raise InputError(
                        f"{path}, line {lineno}: expected 3 columns (t, x, F) or 4 "
                        f"(t, x, xdot, F), found {ncol}"
                    )
            elif len(cells) != ncol:
                raise InputError(
                    f"{path}, line {lineno}: expected {ncol} columns, found {len(cells)}"
                )
            row = []
            for k, cell in enumerate(cells):
                try:
                    row.append(float(cell))
                except ValueError:
                    raise InputError(
                        f"{path}, line {lineno}, column {k + 1} ({names_for[ncol][k]}): "
                        f"not a number: {cell!r}"
                    ) from None
            rows.append(row)
    if ncol is None:
        raise InputError(f"{path}: file is empty (no data rows)")
    return np.asarray(rows, dtype=float)


def _read_text_table(path: Path, names_for: Mapping[int, tuple[str, ...]]) -> np.ndarray:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data = np.loadtxt(path, dtype=float, comments=("#", "%"), ndmin=2)
    except ValueError:
        data = None
    if data is None or data.size == 0 or data.shape[1] not in names_for:
        # The fast reader failed (or found nothing usable): re-read to say exactly where.
        data = _parse_text_table(path, names_for)
    return data


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
    """Load one test from a headerless text file (UTFSM style).

    The file holds whitespace-separated numbers (commas or semicolons also separate them; `#`
    and `%` start comments), in 4 columns `t, x, xdot, F` or 3 columns `t, x, F`. With 3 columns
    the velocity is estimated from the displacement by `mrjax.data.estimate_velocity`.

    **Arguments:**

    - `path`: the file.
    - `units`: units of (time, displacement, velocity, force); default `("s", "mm", "mm/s",
        "N")` as in the UTFSM files. See `mrjax.data.UNITS`. Values are converted to SI.
    - `current` [A], `frequency` [Hz], `amplitude` [m]: test metadata. Those not given are read
        from the file name by `mrjax.data.parse_label`.
    - `label`: name of the condition (default the file name without extension).
    - `parse_name`: if False, metadata not given stay unknown (`None`) instead of being read
        from the file name.
    - `velocity_window_s`: smoothing window [s] of the velocity estimate (3-column files only;
        default chosen from the record, see `estimate_velocity`).

    **Returns:** a :class:`Condition` in SI units with `source` the file path.

    Raises :class:`mrjax.InputError` naming the file (and line and column) for an empty file, a
    non-numeric cell, a wrong number of columns, an unknown unit, an unparsable file name, or
    values that :class:`Condition` rejects.
    """
    p = _check_file(path)
    where = str(path)
    scale = _scales(units, where)
    names_for = {3: ("t", "x", "force"), 4: _SIGNALS}
    data = _read_text_table(p, names_for)
    cols = dict(zip(names_for[data.shape[1]], data.T))
    meta = _metadata(path, {"current": current, "frequency": frequency, "amplitude": amplitude},
                     parse_name)
    xdot = cols["xdot"] * scale["xdot"] if "xdot" in cols else None
    return _condition(
        _stem(path) if label is None else str(label), meta,
        cols["t"] * scale["t"], cols["x"] * scale["x"], xdot, cols["force"] * scale["force"],
        where, velocity_window_s,
    )


# --------------------------------------------------------------------------------------------
# CSV files

_CSV_REQUIRED = ("time", "displacement", "force", "current")


def _csv_delimiter(text: str) -> str:
    header = next((ln for ln in text.splitlines() if ln.strip()), "")
    for d in (",", ";", "\t"):
        if d in header:
            return d
    return ","


def load_csv(path: PathLike, *, velocity_window_s: float | None = None) -> list[Condition]:
    """Load one or more tests from a long-format CSV file with a header.

    One row per sample. Column names carry their unit (see `mrjax.data.UNITS`):

    | column | required | units |
    |---|---|---|
    | `condition` | no | text: the test each row belongs to |
    | `current_A` | yes | `current_A`, `current_mA` |
    | `frequency_Hz` | no | `frequency_Hz` |
    | `amplitude_m` | no | `amplitude_m`, `amplitude_mm` |
    | `time_s` | yes | `time_s`, `time_ms` |
    | `displacement_m` | yes | `displacement_m`, `displacement_mm` |
    | `velocity_m_s` | no | `velocity_m_s`, `velocity_mm_s` |
    | `force_N` | yes | `force_N`, `force_kN` |

    Columns may come in any order; commas, semicolons or tabs separate them. Rows are grouped
    into conditions by `condition`, in order of first appearance (without that column the whole
    file is one condition labelled by the file name). Current, frequency and amplitude must be
    constant within a condition; a missing frequency or amplitude column leaves them unknown.
    Without a velocity column, velocity is estimated from displacement by
    `mrjax.data.estimate_velocity`.

    **Arguments:**

    - `path`: the file.
    - `velocity_window_s`: smoothing window [s] of the velocity estimate (files without a
        velocity column only; default chosen from each record).

    **Returns:** a list of :class:`Condition` in SI units, one per condition.

    Raises :class:`mrjax.InputError` naming the file, and the line (1-based, as in a text
    editor), column or condition at fault.
    """
    p = _check_file(path)
    src = str(path)
    with open(p, newline="", encoding="utf-8-sig", errors="replace") as fh:
        text = fh.read()
    if not text.strip():
        raise InputError(f"{src}: file is empty")
    reader = csv.reader(io.StringIO(text), delimiter=_csv_delimiter(text))

    header = None
    for row in reader:
        if any(cell.strip() for cell in row):
            header = [cell.strip() for cell in row]
            break
    if header is None:
        raise InputError(f"{src}: file is empty")
    quantities: dict[str, tuple[int, str, str | None]] = {}  # quantity -> (index, name, unit)
    for j, name in enumerate(header):
        quantity, unit = parse_column(name, where=src)
        if quantity in quantities:
            raise InputError(
                f"{src}: columns {quantities[quantity][1]!r} and {name!r} both give {quantity}"
            )
        quantities[quantity] = (j, name, unit)
    for quantity in _CSV_REQUIRED:
        if quantity not in quantities:
            si = next(iter(UNITS[COLUMN_QUANTITIES[quantity]])).replace("/", "_")
            raise InputError(
                f"{src}: missing required column {quantity}_<unit> (e.g. {quantity}_{si}); "
                f"columns present: {', '.join(header)}"
            )

    numeric = [(q, j, name) for q, (j, name, unit) in quantities.items() if unit is not None]
    cond_col = quantities["condition"][0] if "condition" in quantities else None
    ncols = len(header)
    values: list[list[float]] = []
    lines: list[int] = []
    groups: dict[str, list[int]] = {}
    for row in reader:
        lineno = reader.line_num
        if not any(cell.strip() for cell in row):
            continue
        if len(row) != ncols:
            raise InputError(f"{src}, line {lineno}: expected {ncols} fields, found {len(row)}")
        vals = []
        for _, j, name in numeric:
            cell = row[j].strip()
            try:
                vals.append(float(cell))
            except ValueError:
                what = "empty cell" if not cell else f"not a number: {cell!r}"
                raise InputError(f"{src}, line {lineno}, column {name!r}: {what}") from None
        if cond_col is None:
            key = _stem(path)
        else:
            key = row[cond_col].strip()
            if not key:
                raise InputError(f"{src}, line {lineno}, column 'condition': empty cell")
        groups.setdefault(key, []).append(len(values))
        values.append(vals)
        lines.append(lineno)
    if not values:
        raise InputError(f"{src}: header only, no data rows")

    table = np.asarray(values, dtype=float)
    line_arr = np.asarray(lines)
    col: dict[str, np.ndarray] = {}
    raw: dict[str, tuple[np.ndarray, str]] = {}
    for k, (q, _, name) in enumerate(numeric):
        unit = quantities[q][2]
        raw[q] = (table[:, k], name)
        col[q] = table[:, k] * unit_scale(unit, quantity=COLUMN_QUANTITIES[q], name=name)

    out = []
    for key, rows in groups.items():
        idx = np.asarray(rows)
        source = src if cond_col is None else f"{src} (condition {key!r})"
        meta: dict[str, float | None] = {}
        for q in _META:
            if q not in col:
                meta[q] = None
                continue
            v, name = raw[q][0][idx], raw[q][1]
            same = (v == v[0]) | (np.isnan(v) & np.isnan(v[0]))
            if not np.all(same):
                k = int(np.argmin(same))
                raise InputError(
                    f"{src}: column {name!r} must be constant within condition {key!r}, but is "
                    f"{v[0]:g} on line {line_arr[idx[0]]} and {v[k]:g} on line {line_arr[idx[k]]}"
                )
            meta[q] = float(col[q][idx[0]])
        xdot = col["velocity"][idx] if "velocity" in col else None
        out.append(
            _condition(key, meta, col["time"][idx], col["displacement"][idx], xdot,
                       col["force"][idx], source, velocity_window_s)
        )
    return out


# --------------------------------------------------------------------------------------------
# MATLAB files


def _mat_vector(data: Mapping, name: str, role: str, src: str) -> np.ndarray:
    a = np.asarray(data[name])
    if a.dtype.kind not in "fiub":
        raise InputError(f"{src}: variable {name!r} ({role}) is not numeric (type {a.dtype})")
    if a.ndim == 2 and (1 in a.shape or a.size == 0):
        a = a.ravel()
    if a.ndim != 1:
        raise InputError(f"{src}: variable {name!r} ({role}) must be a vector, got shape {a.shape}")
    return a.astype(float)


def _mat_scalar(data: Mapping, name: str, role: str, src: str) -> float:
    a = np.asarray(data[name])
    if a.dtype.kind not in "fiub" or a.size != 1:
        raise InputError(
            f"{src}: variable {name!r} ({role}) must be a number, got shape {a.shape} of {a.dtype}"
        )
    return float(a.ravel()[0])


def load_mat(
    path: PathLike,
    *,
    variables: Mapping[str, str] | None = None,
    matrix: str | None = None,
    columns: Sequence[str | None] | None = None,
    units: Sequence[str] = SI_UNITS,
    current: float | None = None,
    frequency: float | None = None,
    amplitude: float | None = None,
    label: str | None = None,
    parse_name: bool = True,
    velocity_window_s: float | None = None,
) -> list[Condition]:
    """Load one test from a MATLAB `.mat` file (format v4 to v7; v7.3 is HDF5, not read).

    Say where the data are in one of two ways, or neither to use the conventional names:

    - **Variables:** `variables={"t": "time", "x": "disp", "xdot": "vel", "force": "F"}` maps
        each signal to a vector variable. `t`, `x` and `force` are required; without `xdot`
        the velocity is estimated by `mrjax.data.estimate_velocity`. The map may also name
        scalar variables `current` [A], `frequency` [Hz], `amplitude` [m].
    - **Matrix:** `matrix="data", columns=("t", "x", "xdot", "force")` reads one 2-D variable,
        one signal per column (a matrix stored one signal per row is transposed). `None` in
        `columns` skips a column. Default columns: `("t", "x", "xdot", "force")` for 4 columns,
        `("t", "x", "force")` for 3. `variables` may still name the scalar metadata.
    - **Neither:** variables named `t`, `x`, `force` (and `xdot`, `current`, `frequency`,
        `amplitude` if present) are used; failing that, the file's only 2-D variable is read as
        the matrix.

    **Arguments:**

    - `path`: the file.
    - `variables`, `matrix`, `columns`: as above.
    - `units`: units of (time, displacement, velocity, force); default SI `("s", "m", "m/s",
        "N")`. Scalar metadata variables are in SI.
    - `current` [A], `frequency` [Hz], `amplitude` [m]: metadata; these override metadata
        variables, and whatever is still missing is read from the file name by
        `mrjax.data.parse_label` unless `parse_name=False` (then it stays unknown).
    - `label`: name of the condition (default the file name without extension).
    - `velocity_window_s`: smoothing window [s] of the velocity estimate, when there is no
        `xdot` (default chosen from the record).

    **Returns:** a list holding one :class:`Condition` in SI units (a list, like
    `mrjax.data.load_csv`, so that every loader of several files returns the same type).

    Raises :class:`mrjax.InputError` naming the file and the variable, listing the variables
    present when one is missing.
    """
    from scipy.io import loadmat

    p = _check_file(path)
    src = str(path)
    scale = _scales(units, src)
    try:
        data = loadmat(p)
    except NotImplementedError:
        raise InputError(
            f"{src}: MATLAB v7.3 (HDF5) files are not supported; save with `save(..., '-v7')`"
        ) from None
    except Exception as e:  # scipy raises several types for a corrupt file
        msg = " ".join(str(e).split())
        raise InputError(f"{src}: not a readable MATLAB file ({type(e).__name__}: {msg})") from None
    present = sorted(k for k in data if not k.startswith("__"))
    listing = ", ".join(present) if present else "none"
    roles = _SIGNALS + _META

    if columns is not None and matrix is None and variables is not None:
        raise InputError(f"{src}: columns= applies only with matrix=")
    if variables is None and matrix is None:
        if all(r in data for r in ("t", "x", "force")):
            variables = {r: r for r in roles if r in data}
        else:
            mats = [k for k in present if np.asarray(data[k]).ndim == 2
                    and min(np.asarray(data[k]).shape) > 1]
            if len(mats) != 1:
                missing = ", ".join(r for r in ("t", "x", "force") if r not in data)
                raise InputError(
                    f"{src}: missing variable(s) {missing} (the conventional names are t, x, "
                    f"force) and no single data matrix; say where the data are with variables= "
                    f"or matrix=; variables present: {listing}"
                )
            matrix = mats[0]
    variables = dict(variables or {})
    for role, name in variables.items():
        if role not in roles:
            raise InputError(
                f"{src}: unknown key {role!r} in variables; accepted: {', '.join(roles)}"
            )
        if name not in data:
            raise InputError(
                f"{src}: variable {name!r} ({role}) not found; variables present: {listing}"
            )

    signals: dict[str, np.ndarray] = {}
    if matrix is not None:
        if matrix not in data:
            raise InputError(
                f"{src}: matrix variable {matrix!r} not found; variables present: {listing}"
            )
        m = np.asarray(data[matrix])
        if m.dtype.kind not in "fiub" or m.ndim != 2:
            raise InputError(
                f"{src}: variable {matrix!r} must be a 2-D numeric matrix, got shape {m.shape} "
                f"of {m.dtype}"
            )
        if columns is None:
            for shape_cols in (m.shape[1], m.shape[0]):
                if shape_cols in (3, 4):
                    columns = ("t", "x", "force") if shape_cols == 3 else _SIGNALS
                    break
            else:
                raise InputError(
                    f"{src}: matrix {matrix!r} has shape {m.shape}; give its columns= "
                    f"(3 or 4 columns are read as t, x, force or t, x, xdot, force)"
                )
        columns = tuple(columns)
        named = [c for c in columns if c is not None]
        for c in named:
            if c not in _SIGNALS:
                raise InputError(
                    f"{src}: unknown column {c!r} in columns; accepted: {', '.join(_SIGNALS)} "
                    f"or None"
                )
        if len(set(named)) != len(named):
            raise InputError(f"{src}: columns {columns} names a signal twice")
        clash = [c for c in named if c in variables]
        if clash:
            raise InputError(f"{src}: {clash[0]!r} is given both by columns and by variables")
        if m.shape[1] != len(columns) and m.shape[0] == len(columns):
            m = m.T
        if m.shape[1] != len(columns):
            raise InputError(
                f"{src}: matrix {matrix!r} has shape {m.shape}, but columns has "
                f"{len(columns)} entries {columns}"
            )
        for j, c in enumerate(columns):
            if c is not None:
                signals[c] = m[:, j].astype(float)
    for role in _SIGNALS:
        if role in variables:
            signals[role] = _mat_vector(data, variables[role], role, src)
    for role in ("t", "x", "force"):
        if role not in signals:
            raise InputError(
                f"{src}: no variable given for {role!r} (variables={{{role!r}: ...}}); "
                f"variables present: {listing}"
            )

    given = {"current": current, "frequency": frequency, "amplitude": amplitude}
    for role in _META:
        if given[role] is None and role in variables:
            given[role] = _mat_scalar(data, variables[role], role, src)
    meta = _metadata(path, given, parse_name)
    xdot = signals["xdot"] * scale["xdot"] if "xdot" in signals else None
    cond = _condition(
        _stem(path) if label is None else str(label), meta,
        signals["t"] * scale["t"], signals["x"] * scale["x"], xdot,
        signals["force"] * scale["force"], src, velocity_window_s,
    )
    return [cond]


# --------------------------------------------------------------------------------------------
# Any files


_LOADERS = {".csv": load_csv, ".txt": load_txt, ".dat": load_txt, ".mat": load_mat}


def expand_paths(paths: PathLike | Sequence[PathLike]) -> list[Path]:
    """The data files named by `paths`: files as given, directories expanded to the data files
    directly inside them (`DATA_SUFFIXES`, sorted by name, hidden files skipped).

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


def load(paths: PathLike | Sequence[PathLike], **options) -> list[Condition]:
    """Load test conditions from files, directories, or a list of them.

    **Arguments:**

    - `paths`: a file, a directory (every `.csv`, `.txt`, `.dat`, `.mat` file directly inside
        it, sorted by name), or a list of files and directories.
    - `**options`: keyword options of the loader of each file type:
        `mrjax.data.load_csv` (`.csv`), `mrjax.data.load_txt` (`.txt`, `.dat`),
        `mrjax.data.load_mat` (`.mat`). An option that the loader of some file does not
        take is an error, not silently ignored.

    **Returns:** a list of :class:`Condition` in SI units, in file order (and, within a CSV
    file, in order of first appearance).

    Raises :class:`mrjax.InputError` for a missing path, a directory without data files, an
    unknown file type or option, and anything the loaders reject.
    """
    out: list[Condition] = []
    for f in expand_paths(paths):
        loader = _LOADERS[f.suffix.lower()]
        accepted = [
            n for n, prm in inspect.signature(loader).parameters.items()
            if prm.kind is inspect.Parameter.KEYWORD_ONLY
        ]
        bad = [k for k in options if k not in accepted]
        if bad:
            raise InputError(
                f"{f}: option {bad[0]!r} does not apply to {f.suffix.lower()} files; "
                f"their options: {', '.join(accepted)}"
            )
        result = loader(f, **options)
        out += result if isinstance(result, list) else [result]
    return out


def load_batch(
    paths: PathLike | Sequence[PathLike],
    *,
    length: int | None = None,
    dtype=None,
    **options,
) -> Batch:
    """Load conditions (as `mrjax.data.load`) and stack them into a padded :class:`Batch`.

    **Arguments:**

    - `paths`, `**options`: as for `mrjax.data.load`.
    - `length`, `dtype`: as for `mrjax.data.make_batch`.

    **Returns:** `make_batch(load(paths, **options), length=length, dtype=dtype)`.
    """
    return make_batch(load(paths, **options), length=length, dtype=dtype)


def default_data_dir() -> Path | None:
    """Where the UTFSM damper measurements are, if anywhere.

    **Returns:** the path in the environment variable `MRJAX_DATA` if it is set (whether or not
    it exists, so that a wrong setting fails loudly when loaded); otherwise the first existing
    directory `shared/data/utfsm` in the parent of the working directory, or in a parent of the
    installed package (which covers `../shared/data/utfsm` beside a source checkout); otherwise
    `None`.
    """
    env = os.environ.get("MRJAX_DATA")
    if env:
        return Path(env).expanduser()
    tail = Path("shared") / "data" / "utfsm"
    candidates = [Path.cwd().parent / tail]
    candidates += [parent / tail for parent in Path(__file__).resolve().parents]
    for c in candidates:
        if c.is_dir():
            return c.resolve()
    return None
