"""Columns and metadata of a data spec: `"SOURCE:UNIT"` parsed into a :class:`Column`, and the
:class:`Meta` values (label, current, frequency, amplitude, sample rate) a file cannot tell.

Metadata keys carry their unit as a suffix, like CSV column names: `current_A`, `current_mA`,
`amplitude_mm`, `sample_rate_kHz`; a key without suffix takes a number in SI or a quantity
string (`current = "500 mA"`).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Any

from .._errors import InputError
from ._units import COLUMN_QUANTITIES, check_unit, parse_column, quantity_value

#: Roles a column can play, and the quantity of its unit (None: text): the quantities of the
#: CSV column names, and the `condition` column that tells tests apart.
ROLES: Mapping[str, str | None] = MappingProxyType({**COLUMN_QUANTITIES, "condition": None})
#: Roles whose values vary sample by sample; the others are constant within a condition.
SIGNAL_ROLES: tuple[str, ...] = ("time", "displacement", "velocity", "force", "current", "command")

#: Metadata keys (SI field of :class:`Meta`) and the quantity of their unit suffix.
_META_QUANTITY = {"current": "current", "frequency": "frequency", "amplitude": "length",
                  "sample_rate": "frequency"}
META_SI = {"current": "A", "frequency": "Hz", "amplitude": "m", "sample_rate": "Hz"}


def is_number(cell: str) -> bool:
    """Whether a text cell reads as a number (a data cell rather than a header or units row)."""
    try:
        float(cell)
    except ValueError:
        return False
    return True


# --------------------------------------------------------------------------------------------
# Column


@dataclasses.dataclass(frozen=True)
class Column:
    """Where one signal is in a file, and its unit: the parsed form of `"SOURCE:UNIT"`.

    **Fields:**

    - `name`: a CSV header or DataFrame column name, or a `.mat` variable name; `None` for a
        bare column index.
    - `index`: column k (0-based): of the 2-D variable `name` (`"data[2]"`), or, without a
        name, of a headerless text file or of the only matrix of a `.mat` file (`"2"`).
        A 2-D variable holds one signal per column along its shorter axis.
    - `unit`: the unit of the values (any `pint` unit of the role's dimension), or `None`
        for a `condition` column and for names that carry their unit (`displacement_mm`).
    """

    name: str | None
    index: int | None = None
    unit: str | None = None

    def __post_init__(self):
        if self.name is None and self.index is None:
            raise InputError("a column needs a name or an index")
        if self.index is not None and (isinstance(self.index, bool) or int(self.index) < 0):
            raise InputError(f"column index must be a non-negative integer, got {self.index!r}")

    @classmethod
    def parse(cls, text: str | int | Column, *, where: str = "") -> Column:
        """Parse `"SOURCE:UNIT"`: `"Disp:cm"`, `"data[1]:N"`, `"3:mm"`, `"displacement_mm"`.

        **Arguments:**

        - `text`: the column as written. The unit follows the last `:`; it may be left out
            where the name carries it (a CSV suffix such as `force_kN`) and for a `condition`
            column. An int is a bare column index; a `Column` is returned as is.
        - `where`: the option or file, for messages.

        **Returns:** the :class:`Column` (its unit is checked against a role by
        :class:`DataSpec`).
        """
        if isinstance(text, Column):
            return text
        if isinstance(text, (int,)) and not isinstance(text, bool):
            return cls(None, int(text), None)
        if not isinstance(text, str) or not text.strip():
            raise InputError(f"{where}: a column must be 'SOURCE:UNIT', got {text!r}")
        body = text.strip()
        source, colon, unit = body.rpartition(":")
        if not colon:
            source, unit = body, ""
        source, unit = source.strip(), unit.strip()
        if not source:
            raise InputError(f"{where}: column {text!r} has no source before ':UNIT'")
        m = re.fullmatch(r"(.+?)\s*\[\s*(\d+)\s*\]", source)
        if m:
            return cls(m[1], int(m[2]), unit or None)
        if re.fullmatch(r"\d+", source):
            return cls(None, int(source), unit or None)
        return cls(source, None, unit or None)

    @property
    def source(self) -> str:
        """The source as written: `"Disp"`, `"data[1]"`, `"3"`."""
        if self.name is None:
            return str(self.index)
        return self.name if self.index is None else f"{self.name}[{self.index}]"

    def __str__(self) -> str:
        return self.source if self.unit is None else f"{self.source}:{self.unit}"


def checked_column(col: Column, role: str, where: str) -> Column:
    """The column with its unit checked against the role (a suffix unit made explicit)."""
    quantity = ROLES[role]
    if quantity is None:
        if col.unit is not None:
            raise InputError(f"{where}: the {role} column {col.source!r} is text and takes no unit")
        return col
    unit = col.unit
    if unit is None and col.name is not None and col.index is None:
        try:
            _, unit = parse_column(col.name)
        except InputError:
            unit = None
        if unit is not None:
            check_unit(unit, quantity, what=f"{role} column {col.name!r}", where=where)
    if unit is None:
        raise InputError(
            f"{where}: {role} column {col.source!r} needs a unit: write '{col.source}:UNIT', "
            f"e.g. '{col.source}:{_SI_EXAMPLE[quantity]}'"
        )
    check_unit(unit, quantity, what=role, where=where)
    return dataclasses.replace(col, unit=unit)


_SI_EXAMPLE = {"time": "s", "length": "mm", "velocity": "mm/s", "force": "N", "current": "A",
               "command": "V", "frequency": "Hz"}


# --------------------------------------------------------------------------------------------
# Metadata


@dataclasses.dataclass(frozen=True)
class Meta:
    """What a file cannot tell about a test, in SI; `None` = not given.

    **Fields:** `label` (name of the condition), `current` [A], `frequency` [Hz], `amplitude`
    [m], `sample_rate` [Hz] (used when there is no time column).
    """

    label: str | None = None
    current: float | None = None
    frequency: float | None = None
    amplitude: float | None = None
    sample_rate: float | None = None

    def __post_init__(self):
        for name in ("current", "frequency", "amplitude", "sample_rate"):
            v = getattr(self, name)
            if v is None:
                continue
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise InputError(f"{name} must be a number [{META_SI[name]}], got {v!r}") from None
            low_ok = v > 0 if name == "sample_rate" else v >= 0
            if not (math.isfinite(v) and low_ok):
                what = "positive" if name == "sample_rate" else "non-negative"
                raise InputError(f"{name} must be finite and {what}, got {v:g} {META_SI[name]}")
            object.__setattr__(self, name, v)
        if self.label is not None:
            object.__setattr__(self, "label", str(self.label))

    def merged(self, other: Meta) -> Meta:
        """**Returns:** these values, with the ones `other` sets (not `None`) taking
        precedence."""
        return Meta(**{f.name: getattr(other, f.name) if getattr(other, f.name) is not None
                       else getattr(self, f.name) for f in dataclasses.fields(Meta)})

    @property
    def is_empty(self) -> bool:
        """Whether no value is set."""
        return all(getattr(self, f.name) is None for f in dataclasses.fields(Meta))


def meta_at(where: str, **values: Any) -> Meta:
    """`Meta(**values)`, an :class:`mrjax.InputError` prefixed with `where`."""
    try:
        return Meta(**values)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None


#: The signals of a one-test loader's `units=` argument, and the quantity of each unit.
SIGNAL_UNITS: tuple[tuple[str, str], ...] = (
    ("time", "time"), ("displacement", "length"), ("velocity", "velocity"), ("force", "force"))


def loader_arguments(where: str, units: Sequence[str], **meta: Any
                     ) -> tuple[tuple[str, str, str, str], Meta]:
    """The `units=` (time, displacement, velocity, force) and metadata keywords of a one-test
    loader (`load_txt`, `load_mat`), checked: `(units, Meta)`, or an
    :class:`mrjax.InputError` naming `where`."""
    if isinstance(units, str) or len(units) != 4:
        raise InputError(
            f"{where}: units must be 4 units (time, displacement, velocity, force), "
            f"e.g. ('s', 'mm', 'mm/s', 'N'); got {units!r}"
        )
    units = tuple(str(u) for u in units)
    for (name, quantity), u in zip(SIGNAL_UNITS, units):
        check_unit(u, quantity, what=name, where=where)
    return units, meta_at(where, **meta)  # type: ignore[return-value]


def meta_key(key: str, where: str) -> tuple[str, str | None]:
    """`current_mA` -> ("current", "mA"); `label` -> ("label", None); `current` -> (.., None)."""
    if key == "label":
        return "label", None
    for name in sorted(_META_QUANTITY, key=len, reverse=True):
        if key == name:
            return name, None
        if key.startswith(name + "_"):
            return name, key[len(name) + 1:]
    raise InputError(
        f"{where}: unknown key {key!r}; keys: label, current_A, frequency_Hz, amplitude_m (or "
        f"amplitude_mm, ...), sample_rate_Hz"
    )


def _meta_value(name: str, unit: str | None, value: Any, where: str, key: str) -> Any:
    if name == "label":
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise InputError(f"{where}: {key} must be text, got {value!r}")
        return str(value)
    quantity = _META_QUANTITY[name]
    if unit is None:
        return quantity_value(value, quantity, what=key, where=where)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        try:
            value = float(str(value))
        except ValueError:
            raise InputError(f"{where}: {key} must be a number, got {value!r}") from None
    return float(value) * check_unit(unit, quantity, what=key, where=where)


def meta_from_table(table: Mapping[str, Any], where: str, *, allow_rate: bool = True) -> Meta:
    values: dict[str, Any] = {}
    given: dict[str, str] = {}
    for key, value in table.items():
        name, unit = meta_key(str(key), where)
        if name == "sample_rate" and not allow_rate:
            raise InputError(f"{where}: {key} cannot vary per test; put it in [meta]")
        if name in given:
            raise InputError(f"{where}: {given[name]!r} and {key!r} both give {name}")
        given[name] = str(key)
        values[name] = _meta_value(name, unit, value, where, str(key))
    return meta_at(where, **values)


def as_meta(value: Meta | Mapping[str, Any] | None, where: str) -> Meta:
    if value is None:
        return Meta()
    if isinstance(value, Meta):
        return value
    if isinstance(value, Mapping):
        fields = {f.name for f in dataclasses.fields(Meta)}
        if set(value) <= fields:
            return meta_at(where, **value)
        return meta_from_table(value, where)
    raise InputError(f"{where}: expected metadata (a Meta or a mapping), got {type(value).__name__}")


def check_role(role: str, where: str) -> None:
    if role not in ROLES:
        raise InputError(f"{where}: unknown role {role!r}; roles: {', '.join(ROLES)}")
