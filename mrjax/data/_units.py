"""Units of the data files, and their conversion to SI.

mrjax works in SI internally: seconds, metres, metres per second, newtons, amperes, hertz. Data
files name their units either by an argument (`units=("s", "mm", "mm/s", "N")` of the text and
MATLAB loaders) or by a suffix of the column name in a CSV header (`displacement_mm`,
`velocity_mm_s`, ...). In a column suffix a `/` is written `_`: `mm_s` is `mm/s`.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError

#: Known units of each physical quantity, with the factor that converts a value to SI.
UNITS: Mapping[str, Mapping[str, float]] = MappingProxyType(
    {
        "time": MappingProxyType({"s": 1.0, "ms": 1e-3}),
        "length": MappingProxyType({"m": 1.0, "mm": 1e-3}),
        "velocity": MappingProxyType({"m/s": 1.0, "mm/s": 1e-3}),
        "force": MappingProxyType({"N": 1.0, "kN": 1e3}),
        "current": MappingProxyType({"A": 1.0, "mA": 1e-3}),
        "frequency": MappingProxyType({"Hz": 1.0}),
    }
)

#: CSV column quantities (the part of a column name before its unit) and what they measure.
COLUMN_QUANTITIES: Mapping[str, str] = MappingProxyType(
    {
        "time": "time",
        "displacement": "length",
        "velocity": "velocity",
        "force": "force",
        "current": "current",
        "frequency": "frequency",
        "amplitude": "length",
    }
)


def _canonical(unit: str) -> str:
    """`mm_s` -> `mm/s` (column-suffix spelling to unit spelling); whitespace stripped."""
    return str(unit).strip().replace("_", "/")


def _suffix(unit: str) -> str:
    return unit.replace("/", "_")


def column_names() -> list[str]:
    """Every accepted CSV column name with a unit, e.g. `displacement_mm`, plus `condition`."""
    names = ["condition"]
    for col, quantity in COLUMN_QUANTITIES.items():
        names += [f"{col}_{_suffix(u)}" for u in UNITS[quantity]]
    return names


def unit_scale(unit: str, *, quantity: str | None = None, name: str = "unit") -> float:
    """The factor that converts a value in `unit` to SI.

    **Arguments:**

    - `unit`: a unit from `mrjax.data.UNITS`, e.g. `"mm"`, `"mm/s"` (or `"mm_s"`), `"kN"`.
    - `quantity`: if given, the unit must be one of this quantity's (`"time"`, `"length"`,
        `"velocity"`, `"force"`, `"current"`, `"frequency"`).
    - `name`: what the unit belongs to (column, argument, file), used in error messages.

    **Returns:** the SI factor (e.g. 1e-3 for `"mm"`).

    Raises :class:`mrjax.InputError` naming `name` and the unit, listing the allowed units.
    """
    if quantity is not None and quantity not in UNITS:
        raise InputError(f"{name}: unknown quantity {quantity!r}; known: {', '.join(UNITS)}")
    u = _canonical(unit)
    tables = {quantity: UNITS[quantity]} if quantity is not None else UNITS
    for table in tables.values():
        if u in table:
            return float(table[u])
    allowed = [v for table in tables.values() for v in table]
    what = f" for {quantity}" if quantity is not None else ""
    raise InputError(f"{name}: unknown unit {unit!r}{what}; allowed: {', '.join(allowed)}")


def to_si(
    values: ArrayLike, unit: str, *, quantity: str | None = None, name: str = "unit"
) -> np.ndarray | float:
    """Convert `values` given in `unit` to SI.

    **Arguments:**

    - `values`: a number or array in `unit`.
    - `unit`: e.g. `"mm"` -> m, `"mm/s"` -> m/s, `"kN"` -> N, `"ms"` -> s, `"mA"` -> A.
    - `quantity`, `name`: as in `mrjax.data.unit_scale` (restrict the unit; name the
        column or argument in error messages).

    **Returns:** float64 values in SI units; a Python float for a scalar input.

    For example `to_si(25, "mm") == 0.025`.
    """
    scale = unit_scale(unit, quantity=quantity, name=name)
    out = np.asarray(values, dtype=float) * scale
    return float(out) if out.ndim == 0 else out


def parse_column(name: str, *, where: str = "") -> tuple[str, str | None]:
    """Split a CSV column name into its quantity and unit.

    **Arguments:**

    - `name`: a column name: `condition`, or `<quantity>_<unit>` with quantity one of `time`,
        `displacement`, `velocity`, `force`, `current`, `frequency`, `amplitude` and a unit
        of that quantity with `/` written `_` (`time_ms`, `velocity_mm_s`, `force_kN`).
    - `where`: the file, used in error messages.

    **Returns:** `(quantity, unit)`, e.g. `("velocity", "mm/s")`; `("condition", None)`.

    Raises :class:`mrjax.InputError` for an unknown column or unit, or a missing unit.
    """
    prefix = f"{where}: " if where else ""
    col = str(name).strip()
    if col == "condition":
        return "condition", None
    quantity, sep, unit = col.partition("_")
    if quantity not in COLUMN_QUANTITIES:
        raise InputError(
            f"{prefix}unknown column {col!r}; accepted columns: {', '.join(column_names())}"
        )
    kind = COLUMN_QUANTITIES[quantity]
    suffixes = [f"{quantity}_{_suffix(u)}" for u in UNITS[kind]]
    if not sep or not unit:
        raise InputError(
            f"{prefix}column {col!r} needs a unit suffix; use one of {', '.join(suffixes)}"
        )
    u = _canonical(unit)
    if u not in UNITS[kind]:
        raise InputError(
            f"{prefix}column {col!r} has unknown unit {unit!r}; use one of {', '.join(suffixes)}"
        )
    return quantity, u
