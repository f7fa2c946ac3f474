"""MATLAB `.mat` files (v4 to v7): vector variables, columns of matrices, scalar metadata."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from .._errors import InputError
from ._build import ReadColumns, assemble
from ._columns import Column, Meta, loader_arguments
from ._condition import Condition
from ._files import PathLike, check_file, name_meta, stem
from ._progress import advance

#: SI units, the default of :func:`load_mat`: time, displacement, velocity, force.
SI_UNITS: tuple[str, str, str, str] = ("s", "m", "m/s", "N")

#: The signals that `load_mat`'s `variables=` and `columns=` arguments name, and their roles.
_SIGNALS = ("t", "x", "xdot", "force")
_ROLE = {"t": "time", "x": "displacement", "xdot": "velocity", "force": "force"}
_META = ("current", "frequency", "amplitude")


def _load(path: PathLike) -> tuple[dict, list[str]]:
    from scipy.io import loadmat

    p = check_file(path)
    try:
        data = loadmat(p)
    except NotImplementedError:
        raise InputError(
            f"{path}: MATLAB v7.3 (HDF5) files are not supported; save with `save(..., '-v7')`"
        ) from None
    except Exception as e:  # scipy raises several types for a corrupt file
        msg = " ".join(str(e).split())
        raise InputError(f"{path}: not a readable MATLAB file ({type(e).__name__}: {msg})") from None
    return data, sorted(k for k in data if not k.startswith("__"))


def _listing(present: list[str]) -> str:
    return ", ".join(present) if present else "none"


def _vector(data: Mapping, name: str, role: str, src: str) -> np.ndarray:
    a = np.asarray(data[name])
    if a.dtype.kind not in "fiub":
        raise InputError(f"{src}: variable {name!r} ({role}) is not numeric (type {a.dtype})")
    if a.ndim == 2 and (1 in a.shape or a.size == 0):
        a = a.ravel()
    if a.ndim != 1:
        raise InputError(f"{src}: variable {name!r} ({role}) must be a vector, got shape {a.shape}")
    return a.astype(float)


def _scalar(data: Mapping, name: str, role: str, src: str) -> float:
    a = np.asarray(data[name])
    if a.dtype.kind not in "fiub" or a.size != 1:
        raise InputError(
            f"{src}: variable {name!r} ({role}) must be a number, got shape {a.shape} of {a.dtype}"
        )
    return float(a.ravel()[0])


def _matrices(data: Mapping, present: list[str]) -> list[str]:
    return [k for k in present if np.asarray(data[k]).ndim == 2 and min(np.asarray(data[k]).shape) > 1]


def _matrix(data: Mapping, name: str, src: str) -> np.ndarray:
    """A 2-D numeric variable, one signal per column (along its shorter axis)."""
    m = np.asarray(data[name])
    if m.dtype.kind not in "fiub" or m.ndim != 2:
        raise InputError(
            f"{src}: variable {name!r} must be a 2-D numeric matrix, got shape {m.shape} of "
            f"{m.dtype}"
        )
    return m.T if m.shape[0] < m.shape[1] else m


def _column(data: Mapping, present: list[str], col: Column, role: str,
            src: str) -> tuple[np.ndarray, str]:
    """The values of `col` and the name of the variable they come from."""
    if col.name is not None and col.name not in data:
        raise InputError(
            f"{src}: variable {col.name!r} ({role}) not found; variables present: "
            f"{_listing(present)}"
        )
    if col.index is None:
        return _vector(data, col.name, role, src), col.name
    name = col.name
    if name is None:
        mats = _matrices(data, present)
        if len(mats) != 1:
            raise InputError(
                f"{src}: {role} column {col.index} names a column of the file's only matrix, but "
                f"the file has {len(mats)} matrices ({_listing(mats)}); write 'NAME[{col.index}]'"
            )
        name = mats[0]
    m = _matrix(data, name, src)
    if col.index >= m.shape[1]:
        raise InputError(
            f"{src}: {role} column {name}[{col.index}] does not exist: {name!r} has shape "
            f"{np.asarray(data[name]).shape}, {m.shape[1]} column(s) numbered from 0"
        )
    return m[:, col.index].astype(float), name


def read_mat(
    path: PathLike,
    *,
    columns: Mapping[str, Column] | None,
    wide: Mapping[str, tuple[Column, ...]] | None = None,
    strict: bool,
    units: Sequence[str] = SI_UNITS,
) -> ReadColumns:
    """Read the columns of a `.mat` file: those given, or by convention variables `t`, `x`,
    `force` (and `xdot`; scalars `current`, `frequency`, `amplitude`) or the only matrix."""
    data, present = _load(path)
    src = str(path)
    wide = dict(wide or {})
    file_meta = Meta()
    if columns is None:
        columns, file_meta = _conventional(data, present, src, units)
    values: dict[Column, np.ndarray] = {}
    lengths: dict[str, int] = {}
    asked = [(r, c) for r, c in columns.items()] + [
        (f"{r}[{j}]", c) for r, cs in wide.items() for j, c in enumerate(cs)]
    used = set(_META)
    for role, c in asked:
        values[c], name = _column(data, present, c, role.partition("[")[0], src)
        lengths[role] = values[c].shape[0]
        used.add(name)
    if len(set(lengths.values())) > 1:
        raise InputError(f"{src}: mismatched column lengths {lengths}")
    notes = []
    if not strict and (unused := [k for k in present if k not in used]):
        notes.append(f"variable(s) {', '.join(unused)} not used")
    n = next(iter(values.values())).shape[0]
    advance(check_file(path).stat().st_size)
    return ReadColumns(src, stem(path), n, dict(columns), wide, values, None, notes, file_meta)


def _conventional(data: Mapping, present: list[str], src: str,
                  units: Sequence[str]) -> tuple[dict[str, Column], Meta]:
    scale = dict(zip(_SIGNALS, units))
    if all(r in data for r in ("t", "x", "force")):
        cols = {_ROLE[r]: Column(r, None, scale[r]) for r in _SIGNALS if r in data}
        meta = Meta(**{r: _scalar(data, r, r, src) for r in _META if r in data})
        return cols, meta
    mats = _matrices(data, present)
    if len(mats) != 1:
        missing = ", ".join(r for r in ("t", "x", "force") if r not in data)
        raise InputError(
            f"{src}: missing variable(s) {missing} (the conventional names are t, x, "
            f"force) and no single data matrix; say where the data are with variables= "
            f"or matrix= (or a DataSpec); variables present: {_listing(present)}"
        )
    return _matrix_columns(data, mats[0], None, src, units, {}), Meta()


def _matrix_columns(data: Mapping, matrix: str, columns: Sequence[str | None] | None, src: str,
                    units: Sequence[str], variables: Mapping[str, str]) -> dict[str, Column]:
    """`load_mat`'s `matrix=`, `columns=` arguments as spec columns (one signal per column)."""
    _matrix(data, matrix, src)  # a 2-D numeric matrix, or the error naming it
    m = np.asarray(data[matrix])
    if columns is None:
        for count in (m.shape[1], m.shape[0]):
            if count in (3, 4):
                columns = ("t", "x", "force") if count == 3 else _SIGNALS
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
    if min(m.shape) != len(columns):
        raise InputError(
            f"{src}: matrix {matrix!r} has shape {m.shape}, but columns has "
            f"{len(columns)} entries {columns}"
        )
    scale = dict(zip(_SIGNALS, units))
    return {_ROLE[c]: Column(matrix, j, scale[c]) for j, c in enumerate(columns) if c is not None}


def _named_columns(data: Mapping, present: list[str], src: str, units: Sequence[str],
                   variables: Mapping[str, str], matrix: str | None,
                   columns: Sequence[str | None] | None) -> dict[str, Column]:
    """The columns that `load_mat`'s `variables=` and `matrix=`, `columns=` arguments name."""
    listing = _listing(present)
    roles = _SIGNALS + _META
    for role, name in variables.items():
        if role not in roles:
            raise InputError(
                f"{src}: unknown key {role!r} in variables; accepted: {', '.join(roles)}"
            )
        if name not in data:
            raise InputError(
                f"{src}: variable {name!r} ({role}) not found; variables present: {listing}"
            )
    cols: dict[str, Column] = {}
    if matrix is not None:
        if matrix not in data:
            raise InputError(
                f"{src}: matrix variable {matrix!r} not found; variables present: {listing}"
            )
        cols = _matrix_columns(data, matrix, columns, src, units, variables)
    scale = dict(zip(_SIGNALS, units))
    for role in _SIGNALS:
        if role in variables:
            cols[_ROLE[role]] = Column(variables[role], None, scale[role])
    for role in ("t", "x", "force"):
        if _ROLE[role] not in cols:
            raise InputError(
                f"{src}: no variable given for {role!r} (variables={{{role!r}: ...}}); "
                f"variables present: {listing}"
            )
    return cols


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

    Say where the data are in one of two ways, or neither to use the conventional names (for
    other layouts, e.g. one test per matrix column, pass a `mrjax.data.DataSpec` to
    `mrjax.data.load`):

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
        "N")`; any unit of the right dimension. Scalar metadata variables are in SI.
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
    src = str(path)
    units, given = loader_arguments(src, units, label=label, current=current,
                                    frequency=frequency, amplitude=amplitude)
    data, present = _load(path)
    if columns is not None and matrix is None and variables is not None:
        raise InputError(f"{src}: columns= applies only with matrix=")
    if variables is None and matrix is None:
        read = read_mat(path, columns=None, strict=True, units=units)
    else:
        variables = dict(variables or {})
        cols = _named_columns(data, present, src, units, variables, matrix, columns)
        read = read_mat(path, columns=cols, strict=True, units=units)
        read.file_meta = Meta(**{r: _scalar(data, variables[r], r, src) for r in _META
                                 if r in variables})
    meta = read.file_meta.merged(given)
    if parse_name:
        meta = name_meta(path, meta)
    return assemble(read, meta=meta, window_s=velocity_window_s, strict=True)
