"""Units of the data files, and their conversion to SI, through `pint`.

mrjax works in SI internally: seconds, metres, metres per second, newtons, amperes, volts,
hertz. Data name their units by a spec (`"Disp:cm"`, see `mrjax.data.DataSpec`), by an argument
(`units=("s", "mm", "mm/s", "N")` of the text and MATLAB loaders) or by a suffix of the column
name in a CSV header (`displacement_mm`, `velocity_in_s`, `force_lbf`). In a column suffix a `/`
is written `_`: `mm_s` is `mm/s`.

Any unit that `pint` knows is accepted if it has the dimension of the quantity: `cm`, `in`,
`ms`, `kN`, `lbf`, `mA`, `mm/s`, `in/s`, `mV`, ... A unit of the wrong dimension is an
:class:`mrjax.InputError` such as "displacement unit 'N' is not a length". The one unit registry
is built on first use (importing `pint` and building its registry take a noticeable
fraction of a second, paid only when a unit other than SI is read).
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Iterator, Mapping
from tokenize import TokenError
from types import MappingProxyType
from typing import Any

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError

#: The physical quantities mrjax reads: a pint dimensionality (or several, for `command`), the
#: SI unit the values are converted to, and the noun used in messages.
_QUANTITIES: Mapping[str, tuple[tuple[str, ...], str, str]] = MappingProxyType(
    {
        "time": (("[time]",), "s", "time"),
        "length": (("[length]",), "m", "length"),
        "velocity": (("[length]/[time]",), "m/s", "velocity"),
        "acceleration": (("[length]/[time]**2",), "m/s**2", "acceleration"),
        "force": (("[force]",), "N", "force"),
        "current": (("[current]",), "A", "current"),
        "voltage": (("[electric_potential]",), "V", "voltage"),
        "command": (("[current]", "[electric_potential]"), "A or V", "current or a voltage"),
        "frequency": (("[frequency]",), "Hz", "frequency"),
    }
)

#: The SI unit(s) of each quantity, as written (factor 1).
_SI: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {"time": ("s",), "length": ("m",), "velocity": ("m/s",), "force": ("N",),
     "current": ("A",), "voltage": ("V",), "command": ("A", "V"), "frequency": ("Hz",)})

#: Common units of each quantity (listed in messages and by `column_names`; any other unit of
#: the right dimension is accepted as well).
_COMMON: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {
        "time": ("s", "ms"),
        "length": ("m", "mm", "cm", "in"),
        "velocity": ("m/s", "mm/s", "cm/s", "in/s"),
        "acceleration": ("m/s**2", "g0"),
        "force": ("N", "kN", "lbf"),
        "current": ("A", "mA"),
        "voltage": ("V", "mV"),
        "command": ("A", "mA", "V", "mV"),
        "frequency": ("Hz",),
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
        "command": "command",
        "frequency": "frequency",
        "amplitude": "length",
        "acceleration": "acceleration",
        "ground_acceleration": "acceleration",
    }
)


@functools.cache
def _registry():
    """The one `pint.UnitRegistry` of mrjax (built on first use)."""
    import pint

    return pint.UnitRegistry()


@functools.cache
def _parse(unit: str):
    """`(pint unit, SI factor, dimensionality)` of a unit string; InputError text on failure."""
    import pint

    ureg = _registry()
    try:
        u = ureg.parse_units(unit)
        q = ureg.Quantity(1.0, u).to_base_units()
        factor = float(q.magnitude)
    except (pint.errors.PintError, ValueError, AttributeError, TypeError, SyntaxError,
            AssertionError, KeyError, IndexError, TokenError, ArithmeticError, RecursionError):
        return None  # (pint divides by a number written 0..., e.g. 'm/018')
    if not (math.isfinite(factor) and factor != 0.0):
        return None
    return u, factor, u.dimensionality


def _canonical(unit: str) -> str:
    """`mm_s` -> `mm/s`, `m_s2` -> `m/s**2` (column-suffix spelling to unit spelling); whitespace
    stripped."""
    return re.sub(r"(?<=/s)(\d)$", r"**\1", str(unit).strip().replace("_", "/"))


def _suffix(unit: str) -> str:
    return unit.replace("/", "_")


@functools.lru_cache(maxsize=256)
def _dimension_ok(dim, quantity: str) -> bool:
    ureg = _registry()
    return any(dim == ureg.get_dimensionality(d) for d in _QUANTITIES[quantity][0])


def _kind_of(dim) -> str | None:
    for q in _QUANTITIES:
        if q != "command" and _dimension_ok(dim, q):
            return q
    return None


def check_unit(unit: str, quantity: str, *, what: str, where: str = "") -> float:
    """The SI factor of `unit`, checked to be a unit of `quantity`.

    **Arguments:**

    - `unit`: a unit string that `pint` reads, e.g. `"cm"`, `"in/s"`, `"lbf"`, `"mA"`; a `_`
        stands for `/` (`"mm_s"`).
    - `quantity`: one of `time`, `length`, `velocity`, `acceleration`, `force`, `current`,
        `voltage`, `command` (a current or a voltage), `frequency`.
    - `what`: what the unit belongs to, e.g. `"displacement"` (used in messages).
    - `where`: the file or option at fault, prefixed to messages.

    **Returns:** the factor that converts a value in `unit` to SI (e.g. 0.0254 for `"in"`).

    Raises :class:`mrjax.InputError` with one line such as
    `"f.csv: displacement unit 'N' is not a length ..."` or
    `"f.csv: unknown unit 'foo' for displacement; ..."`.
    """
    if quantity not in _QUANTITIES:
        raise InputError(f"unknown quantity {quantity!r}; known: {', '.join(_QUANTITIES)}")
    if _canonical(unit) in _SI.get(quantity, ()):  # the SI unit itself: no need of pint's
        return 1.0  # registry (slow to build; a fleet's files are often in SI)
    prefix = f"{where}: " if where else ""
    prefix += f"{what} unit" if what else "unit"
    noun = _QUANTITIES[quantity][2]
    text = _canonical(unit)
    parsed = _parse(text) if text else None
    if parsed is None:
        raise InputError(
            f"{where + ': ' if where else ''}unknown unit {str(unit)!r}"
            f"{' for ' + what if what else ''}; a {noun} unit is e.g. "
            f"{', '.join(_COMMON[quantity])}"
        )
    _, factor, dim = parsed
    if not _dimension_ok(dim, quantity):
        kind = _kind_of(dim)
        is_a = f" (it is a {_QUANTITIES[kind][2]} unit)" if kind else ""
        raise InputError(
            f"{prefix} {str(unit)!r} is not a {noun}{is_a}; use e.g. "
            f"{', '.join(_COMMON[quantity])}"
        )
    return factor


def command_unit(unit: str) -> str:
    """`"A"` if `unit` is a current unit, `"V"` if a voltage unit (as checked by
    `check_unit(unit, "command", ...)`)."""
    parsed = _parse(_canonical(unit))
    return "A" if parsed is not None and _dimension_ok(parsed[2], "current") else "V"


def quantity_value(value: Any, quantity: str, *, what: str, where: str = "") -> float:
    """A number in SI from a number (already in SI) or a string such as `"500 mA"`, `"1 kHz"`.

    **Arguments:** `value`: an int, float or string (`"0.5"`, `"500mA"`, `"8 mm"`); `quantity`,
    `what`, `where` as in :func:`check_unit`.

    **Returns:** the value in the SI unit of `quantity` (A, Hz, m, s, ...).

    Raises :class:`mrjax.InputError` for text that is neither a number nor a quantity of the
    right dimension.
    """
    prefix = f"{where}: " if where else ""
    if isinstance(value, bool):
        raise InputError(f"{prefix}{what} must be a number, got {value!r}")
    if isinstance(value, (int, float, np.integer, np.floating)):
        return float(value)
    if not isinstance(value, str):
        raise InputError(f"{prefix}{what} must be a number, got {type(value).__name__}")
    text = value.strip()
    try:
        return float(text)
    except ValueError:
        pass
    m = re.fullmatch(r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(\S.*)", text)
    if m is None:
        raise InputError(
            f"{prefix}{what} must be a number or a quantity such as "
            f"'{_example(quantity)}', got {value!r}"
        )
    return float(m[1]) * check_unit(m[2], quantity, what=what, where=where)


def _example(quantity: str) -> str:
    return {"current": "500 mA", "frequency": "1 kHz", "length": "8 mm", "time": "20 ms"}.get(
        quantity, "1 " + _COMMON[quantity][0]
    )


class _Units(Mapping):
    """`UNITS[quantity][unit] -> SI factor` for the common units, computed by pint on use."""

    def __getitem__(self, quantity: str) -> Mapping[str, float]:
        if quantity not in _COMMON:
            raise KeyError(quantity)
        return _common_factors(quantity)

    def __iter__(self) -> Iterator[str]:
        return iter(_COMMON)

    def __len__(self) -> int:
        return len(_COMMON)

    def __repr__(self) -> str:
        return f"UNITS({', '.join(f'{q}: {list(u)}' for q, u in _COMMON.items())})"


@functools.cache
def _common_factors(quantity: str) -> Mapping[str, float]:
    return MappingProxyType({u: check_unit(u, quantity, what=quantity) for u in _COMMON[quantity]})


#: Common units of each physical quantity, with the factor that converts a value to SI
#: (`UNITS["length"]["in"] == 0.0254`). Any other `pint` unit of the right dimension is accepted.
UNITS: Mapping[str, Mapping[str, float]] = _Units()


def column_names() -> list[str]:
    """Common CSV column names with a unit, e.g. `displacement_mm`, plus `condition`.

    Any other unit of the right dimension is accepted too (`displacement_ft`)."""
    names = ["condition"]
    for col, quantity in COLUMN_QUANTITIES.items():
        names += [f"{col}_{_suffix(u)}" for u in _COMMON[quantity]]
    return names


def unit_scale(unit: str, *, quantity: str | None = None, name: str = "unit") -> float:
    """The factor that converts a value in `unit` to SI.

    **Arguments:**

    - `unit`: any unit `pint` reads, e.g. `"mm"`, `"in"`, `"mm/s"` (or `"mm_s"`), `"lbf"`.
    - `quantity`: if given, the unit must be of this quantity (`"time"`, `"length"`,
        `"velocity"`, `"force"`, `"current"`, `"voltage"`, `"command"`, `"frequency"`, ...).
        Without it, any unit of one of these quantities is accepted.
    - `name`: what the unit belongs to (column, argument, file), used in error messages.

    **Returns:** the SI factor (e.g. 1e-3 for `"mm"`, 4.4482216152605 for `"lbf"`).

    Raises :class:`mrjax.InputError` naming `name` and the unit for an unknown unit or one of
    the wrong dimension.
    """
    if quantity is not None:
        if quantity not in _QUANTITIES:
            raise InputError(f"{name}: unknown quantity {quantity!r}; known: {', '.join(_QUANTITIES)}")
        return check_unit(unit, quantity, what="", where=name)
    parsed = _parse(_canonical(unit))
    if parsed is None or _kind_of(parsed[2]) is None:
        raise InputError(
            f"{name}: unknown unit {str(unit)!r}; a unit of time, length, velocity, force, "
            f"current, voltage or frequency, e.g. s, mm, mm/s, N, A, V, Hz"
        )
    return parsed[1]


def to_si(
    values: ArrayLike, unit: str, *, quantity: str | None = None, name: str = "unit"
) -> np.ndarray | float:
    """Convert `values` given in `unit` to SI.

    **Arguments:**

    - `values`: a number or array in `unit`.
    - `unit`: e.g. `"mm"` -> m, `"in"` -> m, `"mm/s"` -> m/s, `"lbf"` -> N, `"ms"` -> s,
        `"mA"` -> A.
    - `quantity`, `name`: as in `mrjax.data.unit_scale` (restrict the unit; name the
        column or argument in error messages).

    **Returns:** float64 values in SI units; a Python float for a scalar input.

    For example `to_si(25, "mm") == 0.025` and `to_si(1, "lbf") == 4.4482216152605`.
    """
    scale = unit_scale(unit, quantity=quantity, name=name)
    out = np.asarray(values, dtype=float) * scale
    return float(out) if out.ndim == 0 else out


def parse_column(name: str, *, where: str = "") -> tuple[str, str | None]:
    """Split a CSV column name into its quantity and unit.

    **Arguments:**

    - `name`: a column name: `condition`, or `<quantity>_<unit>` with quantity one of `time`,
        `displacement`, `velocity`, `force`, `current`, `command`, `frequency`, `amplitude`
        and a unit of that quantity with `/` written `_` (`time_ms`, `velocity_in_s`,
        `force_lbf`, `command_V`).
    - `where`: the file, used in error messages.

    **Returns:** `(quantity, unit)`, e.g. `("velocity", "mm/s")`; `("condition", None)`.

    Raises :class:`mrjax.InputError` for an unknown column or unit, a unit of the wrong
    dimension, or a missing unit.
    """
    prefix = f"{where}: " if where else ""
    col = str(name).strip()
    if col == "condition":
        return "condition", None
    # the longest quantity the name starts with (`ground_acceleration_m_s2`)
    quantity = max((q for q in COLUMN_QUANTITIES if col.startswith(q + "_")), key=len,
                   default=col.partition("_")[0])
    sep, unit = ("_", col[len(quantity) + 1:]) if col.startswith(quantity + "_") else ("", "")
    if quantity not in COLUMN_QUANTITIES:
        raise InputError(
            f"{prefix}unknown column {col!r}; accepted columns: condition and <quantity>_<unit> "
            f"with quantity one of {', '.join(COLUMN_QUANTITIES)} and any unit of its "
            f"dimension, e.g. time_s, displacement_mm, velocity_mm_s, force_N, current_A, "
            f"command_V, frequency_Hz, amplitude_mm"
        )
    kind = COLUMN_QUANTITIES[quantity]
    suffixes = [f"{quantity}_{_suffix(u)}" for u in _COMMON[kind]]
    if not sep or not unit:
        raise InputError(
            f"{prefix}column {col!r} needs a unit suffix; use e.g. {', '.join(suffixes)}"
        )
    try:
        check_unit(unit, kind, what=quantity)
    except InputError as e:
        raise InputError(f"{prefix}column {col!r}: {e}") from None
    return quantity, _canonical(unit)
