"""pandas DataFrames: conditions from a long-format frame, and back."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from .._errors import InputError
from ._build import Codes, ReadColumns, assemble
from ._columns import Column
from ._condition import Batch, Condition
from ._csv import column_index, conventional_columns
from ._spec import DataSpec

if TYPE_CHECKING:
    import pandas as pd


def _numeric(frame, j: int, name: str, where: str) -> np.ndarray:
    import pandas as pd

    series = frame.iloc[:, j]
    values = pd.to_numeric(series, errors="coerce")
    bad = values.isna() & series.notna()
    if bad.any():
        k = int(np.argmax(bad.to_numpy()))
        raise InputError(
            f"{where}, row {k} (index {frame.index[k]!r}), column {name!r}: not a number: "
            f"{series.iloc[k]!r}"
        )
    return np.array(values.to_numpy(dtype=float, na_value=np.nan), copy=True)  # not a view
    # of the caller's frame: the conditions hold slices of it


def from_frame(frame: pd.DataFrame, spec: DataSpec | None = None, *,
               name: str = "DataFrame") -> list[Condition]:
    """Conditions from a pandas DataFrame, one row per sample.

    **Arguments:**

    - `frame`: the DataFrame. Without a spec its columns are read by the names of the CSV
        format (`time_s`, `displacement_mm`, `velocity_m_s`, `force_N`, `current_A`,
        `command_V`, `frequency_Hz`, `amplitude_mm`, any unit; `condition` tells tests apart);
        other columns are left unused (listed in `Condition.notes`).
    - `spec`: a `mrjax.data.DataSpec` naming the columns (`"Disp:cm"`; a bare integer is a
        column position), the wide layout, metadata and the velocity window, as for files.
        Its `files` entries match `name`.
    - `name`: what to call the frame in messages and default labels.

    **Returns:** a list of :class:`Condition` in SI units, as `mrjax.data.load` gives for a
    file: metadata that the frame and spec do not give stay unknown, except frequency and
    amplitude, which are estimated from the displacement (and marked in
    `Condition.estimated`); a velocity that is not given is estimated.

    Raises :class:`mrjax.InputError` naming the frame, row and column for an unknown column,
    a non-numeric cell, and whatever a file with the same content would raise.
    """
    import pandas as pd

    if not isinstance(frame, pd.DataFrame):
        raise InputError(f"{name}: expected a pandas DataFrame, got {type(frame).__name__}")
    spec = spec if spec is not None else DataSpec()
    if frame.shape[0] == 0:
        raise InputError(f"{name}: the frame has no rows")
    header = [str(c) for c in frame.columns]
    if len(set(header)) != len(header):
        raise InputError(f"{name}: duplicate column names {header}")
    if spec.columns or spec.wide:
        columns = dict(spec.columns)
    else:
        columns = conventional_columns(header, name, strict=False)
    wide = dict(spec.wide)
    asked = list(columns.items()) + [(r, c) for r, cs in wide.items() for c in cs]
    values: dict[Column, np.ndarray] = {}
    for role, c in asked:
        j = column_index(header, c, role, name)
        if c.unit is None:
            codes, labels = pd.factorize(frame.iloc[:, j].astype(str).str.strip(), sort=False)
            values[c] = Codes(codes.astype(np.int32), tuple(str(s) for s in labels))
        else:
            values[c] = _numeric(frame, j, header[j], name)
    unused = [h for h in header if h not in {header[column_index(header, c, r, name)] for r, c in asked}]
    notes = [f"column(s) {', '.join(map(repr, unused))} not used"] if unused else []
    read = ReadColumns(name, name, frame.shape[0], columns, wide, values, None, notes)
    meta = spec.file_meta(name)
    return assemble(read, meta=meta, wide_meta=spec.wide_meta, window_s=spec.velocity_window,
                    strict=False)


def to_frame(conditions: Sequence[Condition] | Batch) -> pd.DataFrame:
    """A long-format DataFrame of conditions (one row per sample), in SI units.

    **Arguments:** `conditions`: a list of :class:`Condition` or a :class:`Batch` (padding
    removed).

    **Returns:** a DataFrame with columns `condition`, `current_A`, `frequency_Hz`,
    `amplitude_m`, `time_s`, `displacement_m`, `velocity_m_s`, `force_N` and, if any condition
    has a per-sample command, `command_A` or `command_V` (NaN for conditions without one).
    Unknown metadata are NaN. `from_frame(to_frame(cs))` gives the conditions back.

    Raises :class:`mrjax.InputError` if the commands mix currents and voltages.
    """
    import pandas as pd

    conds = conditions.conditions() if isinstance(conditions, Batch) else list(conditions)
    if not conds:
        raise InputError("to_frame: no conditions")
    units = {c.command_unit for c in conds if c.command is not None}
    unit = next(iter(units)) if units else None
    if len(units) > 1:
        raise InputError("to_frame: the commands mix currents [A] and voltages [V]; "
                         "write them to separate frames")

    def meta(v):
        return np.nan if v is None else v

    parts = []
    for c in conds:
        cols = {
            "condition": np.full(c.n_samples, c.label, dtype=object),
            "current_A": np.full(c.n_samples, meta(c.current)),
            "frequency_Hz": np.full(c.n_samples, meta(c.frequency)),
            "amplitude_m": np.full(c.n_samples, meta(c.amplitude)),
            "time_s": c.t, "displacement_m": c.x, "velocity_m_s": c.xdot, "force_N": c.force,
        }
        if unit is not None:
            cols[f"command_{unit}"] = (c.command if c.command is not None
                                       else np.full(c.n_samples, np.nan))
        parts.append(pd.DataFrame(cols))
    return pd.concat(parts, ignore_index=True)
