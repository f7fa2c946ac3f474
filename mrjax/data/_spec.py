"""The data spec: where each signal of a test file is, in which unit, and what the file cannot say.

One immutable :class:`DataSpec` describes a campaign's files; it is read from a TOML file
(:meth:`DataSpec.from_toml`), built from the strings of command-line options
(:meth:`DataSpec.from_options`) or written in Python, and passed to `mrjax.data.load(paths,
spec=...)`. Options override single keys of a file with :meth:`DataSpec.merged`.

```toml
[columns]                       # role = "SOURCE:UNIT"
time         = "Time:s"         # SOURCE: a CSV header name; a .mat variable name; "name[k]" =
displacement = "Disp:cm"        #   column k (0-based) of a 2-D .mat variable; a bare integer
velocity     = "Vel:cm/s"       #   k = column k of a headerless text file or of the only
force        = "Load:N"         #   matrix of a .mat file. UNIT: any unit of the right dimension
command      = "Cmd:V"          # a per-sample command (V or A); "current = ...:A" for a
                                #   measured current
[meta]                          # every condition, unless a layout or [files] says otherwise
sample_rate_Hz = 2000           # required when there is no time column
current_A      = 0.5            # also frequency_Hz, amplitude_m (or amplitude_mm, ...), label

[wide]                          # one test per column: the other roles are shared
force     = ["data[1]:N", "data[2]:N", "data[3]:N"]
current_A = [0.2, 0.4, 0.6]     # per test; also frequency_Hz, amplitude_mm, label

[files."ensaio.B.1.mat"]        # per file (a name or glob pattern): the keys of [meta]
current_A = 0.5

[velocity]
window_ms = 20                  # Savitzky-Golay window of the velocity estimate (default: auto)
```
"""

from __future__ import annotations

import dataclasses
import fnmatch
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any

from .._errors import InputError
from ._units import check_unit, parse_column, quantity_value

#: Roles a column can play, and the quantity of its unit (None: text).
ROLES: Mapping[str, str | None] = MappingProxyType(
    {
        "time": "time",
        "displacement": "length",
        "velocity": "velocity",
        "force": "force",
        "current": "current",
        "command": "command",
        "frequency": "frequency",
        "amplitude": "length",
        "condition": None,
    }
)
#: Roles whose values vary sample by sample; the others are constant within a condition.
SIGNAL_ROLES: tuple[str, ...] = ("time", "displacement", "velocity", "force", "current", "command")

#: Metadata keys (SI field of :class:`Meta`) and the quantity of their unit suffix.
_META_QUANTITY = {"current": "current", "frequency": "frequency", "amplitude": "length",
                  "sample_rate": "frequency"}
_META_SI = {"current": "A", "frequency": "Hz", "amplitude": "m", "sample_rate": "Hz"}

PathLike = str | os.PathLike


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

        The unit follows the last `:`; it may be left out where the name carries it (a CSV
        suffix such as `force_kN`) and for a `condition` column. An int is a bare index.
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


def _checked_column(col: Column, role: str, where: str) -> Column:
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
                raise InputError(f"{name} must be a number [{_META_SI[name]}], got {v!r}") from None
            low_ok = v > 0 if name == "sample_rate" else v >= 0
            if not (math.isfinite(v) and low_ok):
                what = "positive" if name == "sample_rate" else "non-negative"
                raise InputError(f"{name} must be finite and {what}, got {v:g} {_META_SI[name]}")
            object.__setattr__(self, name, v)
        if self.label is not None:
            object.__setattr__(self, "label", str(self.label))

    def merged(self, other: Meta) -> Meta:
        """These values, with the ones `other` sets taking precedence."""
        return Meta(**{f.name: getattr(other, f.name) if getattr(other, f.name) is not None
                       else getattr(self, f.name) for f in dataclasses.fields(Meta)})

    @property
    def is_empty(self) -> bool:
        """Whether no value is set."""
        return all(getattr(self, f.name) is None for f in dataclasses.fields(Meta))


def _meta_key(key: str, where: str) -> tuple[str, str | None]:
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


def _meta_from_table(table: Mapping[str, Any], where: str, *, allow_rate: bool = True) -> Meta:
    values: dict[str, Any] = {}
    given: dict[str, str] = {}
    for key, value in table.items():
        name, unit = _meta_key(str(key), where)
        if name == "sample_rate" and not allow_rate:
            raise InputError(f"{where}: {key} cannot vary per test; put it in [meta]")
        if name in given:
            raise InputError(f"{where}: {given[name]!r} and {key!r} both give {name}")
        given[name] = str(key)
        values[name] = _meta_value(name, unit, value, where, str(key))
    try:
        return Meta(**values)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None


def _as_meta(value: Meta | Mapping[str, Any] | None, where: str) -> Meta:
    if value is None:
        return Meta()
    if isinstance(value, Meta):
        return value
    if isinstance(value, Mapping):
        fields = {f.name for f in dataclasses.fields(Meta)}
        if set(value) <= fields:
            try:
                return Meta(**value)
            except InputError as e:
                raise InputError(f"{where}: {e}") from None
        return _meta_from_table(value, where)
    raise InputError(f"{where}: expected metadata (a Meta or a mapping), got {type(value).__name__}")


# --------------------------------------------------------------------------------------------
# The spec


@dataclasses.dataclass(frozen=True)
class DataSpec:
    """Where each signal of a test file is and in which unit, plus what the file cannot say.

    Every field is optional; an empty spec reads files by their own conventions (see
    `mrjax.data.load`).

    **Fields:**

    - `columns`: role -> :class:`Column` (or its text `"SOURCE:UNIT"`). Roles: `time`,
        `displacement`, `velocity`, `force` (per sample); `current` (a measured per-sample
        current [A]) or `command` (a per-sample command, current [A] or voltage [V]);
        `frequency`, `amplitude` (constant within a test) and `condition` (text telling the
        tests of a long CSV apart). `displacement` and `force` are required where the
        file's conventions do not give them, `time` unless `sample_rate` is set. When given,
        these columns are the whole mapping: other columns of the file are not read.
    - `wide`: role -> one column per test ("one test per column"); the roles in `columns`
        are shared by all tests. All lists have the same length N.
    - `meta`: :class:`Meta` of every condition: `label`, `current` [A], `frequency` [Hz],
        `amplitude` [m], `sample_rate` [Hz].
    - `wide_meta`: N :class:`Meta`, one per test of `wide` (no `sample_rate`).
    - `files`: file name or glob pattern -> :class:`Meta` for the matching files (matched
        against the name, with or without extension; later patterns win).
    - `velocity_window`: window of the velocity estimate [s] (default: chosen per record, see
        `mrjax.data.velocity_window`).
    - `origin`: where the spec came from (a file, "options"), used in messages.

    Metadata precedence, strongest first: `wide_meta`, `files`, `meta`, the file's own content
    (CSV metadata columns), its name (`25mm0x1Hz0x75A`), and for frequency and amplitude an
    estimate from the displacement (`mrjax.data.estimate_motion`, marked in
    `Condition.estimated`).
    """

    columns: Mapping[str, Column] = dataclasses.field(default_factory=dict)
    wide: Mapping[str, tuple[Column, ...]] = dataclasses.field(default_factory=dict)
    meta: Meta = Meta()
    wide_meta: tuple[Meta, ...] = ()
    files: Mapping[str, Meta] = dataclasses.field(default_factory=dict)
    velocity_window: float | None = None
    origin: str = ""

    def __post_init__(self):
        where = self.origin or "data spec"
        cols = {}
        for role, col in dict(self.columns or {}).items():
            _check_role(role, f"{where}: columns")
            cols[role] = _checked_column(Column.parse(col, where=where), role, where)
        wide = {}
        for role, cs in dict(self.wide or {}).items():
            _check_role(role, f"{where}: wide")
            if role == "condition":
                raise InputError(f"{where}: wide: condition cannot vary per column")
            if isinstance(cs, (str, Column)) or not isinstance(cs, Sequence) or not cs:
                raise InputError(f"{where}: wide {role} must be a non-empty list of columns")
            wide[role] = tuple(_checked_column(Column.parse(c, where=where), role, where)
                               for c in cs)
            if role in cols:
                raise InputError(f"{where}: role {role!r} given twice (in columns and in wide)")
        lengths = {len(v) for v in wide.values()}
        if len(lengths) > 1:
            sizes = ", ".join(f"{r}: {len(v)}" for r, v in wide.items())
            raise InputError(f"{where}: wide lists differ in length ({sizes})")
        roles = set(cols) | set(wide)
        if {"current", "command"} <= roles:
            raise InputError(
                f"{where}: give a per-sample current or a command column, not both"
            )
        meta = _as_meta(self.meta, f"{where}: meta")
        wide_meta = tuple(_as_meta(m, f"{where}: wide") for m in (self.wide_meta or ()))
        if wide_meta:
            if not wide:
                raise InputError(
                    f"{where}: per-test values ({len(wide_meta)}) need a wide layout (one test "
                    f"per column); for several files use [files]"
                )
            n = lengths.pop() if lengths else 0
            if len(wide_meta) != n:
                raise InputError(
                    f"{where}: wide has {n} test column(s) but {len(wide_meta)} per-test values"
                )
            if any(m.sample_rate is not None for m in wide_meta):
                raise InputError(f"{where}: sample_rate cannot vary per test; put it in meta")
        files = {str(k): _as_meta(v, f"{where}: files {k!r}")
                 for k, v in dict(self.files or {}).items()}
        window = self.velocity_window
        if window is not None:
            window = quantity_value(window, "time", what="velocity window", where=where)
            if not (math.isfinite(window) and window > 0):
                raise InputError(f"{where}: velocity window must be positive, got {window:g} s")
        object.__setattr__(self, "columns", MappingProxyType(cols))
        object.__setattr__(self, "wide", MappingProxyType(wide))
        object.__setattr__(self, "meta", meta)
        object.__setattr__(self, "wide_meta", wide_meta)
        object.__setattr__(self, "files", MappingProxyType(files))
        object.__setattr__(self, "velocity_window", window)
        object.__setattr__(self, "origin", str(self.origin))

    # ----------------------------------------------------------------------------------------

    @property
    def n_wide(self) -> int:
        """Number of tests per file in the wide layout (0 without one)."""
        return len(next(iter(self.wide.values()))) if self.wide else 0

    @property
    def is_empty(self) -> bool:
        """Whether the spec sets nothing (files are then read by their own conventions)."""
        return (not self.columns and not self.wide and self.meta.is_empty and not self.wide_meta
                and not self.files and self.velocity_window is None)

    def replace(self, **changes: Any) -> DataSpec:
        """A copy with fields replaced (`dataclasses.replace`), checked again."""
        return dataclasses.replace(self, **changes)

    def merged(self, other: DataSpec | None) -> DataSpec:
        """This spec with every key that `other` sets overriding it (e.g. command-line options
        over a spec file).

        Per key: a role of `other.columns` replaces that role here (in `columns` or `wide`); a
        wide layout of `other` replaces this one; metadata override per field, per file
        pattern; a set velocity window replaces this one.
        """
        if other is None:
            return self
        columns = {r: c for r, c in self.columns.items() if r not in other.wide}
        columns.update(other.columns)
        if other.wide:
            wide, wide_meta = dict(other.wide), other.wide_meta or self.wide_meta
        else:
            wide = {r: c for r, c in self.wide.items() if r not in other.columns}
            wide_meta = other.wide_meta or (self.wide_meta if wide else ())
        files = dict(self.files)
        for k, m in other.files.items():
            files[k] = files[k].merged(m) if k in files else m
        return DataSpec(
            columns=columns, wide=wide, meta=self.meta.merged(other.meta), wide_meta=wide_meta,
            files=files,
            velocity_window=other.velocity_window if other.velocity_window is not None
            else self.velocity_window,
            origin=" + ".join(o for o in (self.origin, other.origin) if o),
        )

    def with_options(self, **options: Any) -> DataSpec:
        """`self.merged(DataSpec.from_options(**options))`: options override single keys."""
        return self.merged(DataSpec.from_options(**options))

    def file_meta(self, path: PathLike) -> Meta:
        """`meta` merged with every `files` pattern that matches `path` (in order)."""
        meta = self.meta
        for pattern, m in self.files.items():
            if _matches(pattern, path):
                meta = meta.merged(m)
        return meta

    # ----------------------------------------------------------------------------------------

    @classmethod
    def from_toml(cls, path: PathLike) -> DataSpec:
        """Read a spec file (TOML; the keys are in the module notes and the README).

        **Arguments:** `path`: the `.toml` file.

        **Returns:** the :class:`DataSpec`, with `origin` the path.

        Raises :class:`mrjax.InputError` naming the file for a missing file, a TOML syntax
        error (with its line and column), an unknown table or key, an unknown role, a role
        given twice, a unit of the wrong dimension, or lists of different lengths.
        """
        import tomllib

        p = Path(path).expanduser()
        if not p.is_file():
            raise InputError(f"{path}: no such spec file")
        try:
            doc = tomllib.loads(p.read_text(encoding="utf-8"))
        except tomllib.TOMLDecodeError as e:
            raise InputError(f"{path}: malformed spec file: {e}") from None
        except UnicodeDecodeError as e:
            raise InputError(f"{path}: spec file is not UTF-8 text ({e.reason})") from None
        return cls.from_dict(doc, origin=str(path))

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any], *, origin: str = "") -> DataSpec:
        """A spec from the parsed TOML document (tables `columns`, `meta`, `wide`, `files`,
        `velocity`), as :meth:`from_toml` reads it."""
        where = origin or "data spec"
        tables = ("columns", "meta", "wide", "files", "velocity")
        for key, value in doc.items():
            if key not in tables:
                raise InputError(
                    f"{where}: unknown key {key!r}; the spec has tables {', '.join(tables)}"
                )
            if not isinstance(value, Mapping):
                raise InputError(f"{where}: {key} must be a table ([{key}])")
        columns = {}
        for role, text in doc.get("columns", {}).items():
            _check_role(role, f"{where}: [columns]")
            if not isinstance(text, (str, int)) or isinstance(text, bool):
                raise InputError(f"{where}: [columns] {role} must be a string 'SOURCE:UNIT'")
            columns[role] = Column.parse(text, where=f"{where}: [columns] {role}")
        meta = _meta_from_table(doc.get("meta", {}), f"{where}: [meta]")
        wide: dict[str, list[Column]] = {}
        per_test: dict[str, tuple[str, list]] = {}
        for key, value in doc.get("wide", {}).items():
            if not isinstance(value, list) or not value:
                raise InputError(f"{where}: [wide] {key} must be a non-empty list")
            if key in ROLES:
                wide[key] = [Column.parse(v, where=f"{where}: [wide] {key}") for v in value]
            else:
                _meta_key(key, f"{where}: [wide]")
                per_test[key] = value
        n = {len(v) for v in list(wide.values()) + list(per_test.values())}
        if len(n) > 1:
            sizes = ", ".join(f"{k}: {len(v)}" for k, v in {**wide, **per_test}.items())
            raise InputError(f"{where}: [wide] lists differ in length ({sizes})")
        wide_meta = tuple(
            _meta_from_table({k: v[j] for k, v in per_test.items()}, f"{where}: [wide] test {j}",
                             allow_rate=False)
            for j in range(n.pop() if n and per_test else 0)
        )
        files = {}
        for pattern, table in doc.get("files", {}).items():
            if not isinstance(table, Mapping):
                raise InputError(f"{where}: [files] {pattern!r} must be a table of metadata")
            files[pattern] = _meta_from_table(table, f"{where}: [files.{pattern!r}]")
        window = None
        vel = doc.get("velocity", {})
        for key, value in vel.items():
            if key == "window" or key.startswith("window_"):
                if window is not None:
                    raise InputError(f"{where}: [velocity] gives the window twice")
                unit = key[len("window_"):] if key != "window" else None
                window = (quantity_value(value, "time", what=f"[velocity] {key}", where=where)
                          if unit is None else
                          _meta_number(value, where, key) *
                          check_unit(unit, "time", what=f"[velocity] {key}", where=where))
            else:
                raise InputError(f"{where}: [velocity] unknown key {key!r}; use window_s")
        return cls(columns=columns, wide=wide, meta=meta, wide_meta=wide_meta, files=files,
                   velocity_window=window, origin=origin)

    @classmethod
    def from_options(
        cls,
        *,
        columns: str | Mapping[str, str | Column] | None = None,
        wide: str | Mapping[str, Sequence[str | Column]] | None = None,
        sample_rate: float | str | None = None,
        current: Any = None,
        frequency: Any = None,
        amplitude: Any = None,
        label: Any = None,
        velocity_window: float | str | None = None,
    ) -> DataSpec:
        """A spec from the strings of command-line options (or the same values in Python).

        **Arguments** (all optional; `None` = not given):

        - `columns`: `"time=Time:s,displacement=Disp:cm,force=Load:N"`: `role=SOURCE:UNIT`
            pairs separated by commas (or a mapping role -> column).
        - `wide`: one test per column: `"force=1:N,2:N,3:N"` (a unit written only on the
            last item applies to the items before it: `"force=1,2,3:N"`); several roles are
            separated by `;`. Or a mapping role -> list of columns.
        - `sample_rate`: `1000` [Hz] or `"1 kHz"`; needed when there is no time column.
        - `current` [A], `frequency` [Hz], `amplitude` [m], `label`: one value for all
            conditions (`0.5`, `"500 mA"`, `"8 mm"`); a comma list with one value per test of
            the wide layout (`"0,0.25,0.5"`); or per file, `"FILE=VALUE,..."`
            (`"ensaio.B.1.mat=0.5,ensaio.B.2.mat=1"`; FILE may be a glob pattern). Lists and
            dicts are accepted in Python.
        - `velocity_window`: window of the velocity estimate: seconds or `"20 ms"`.

        **Returns:** the :class:`DataSpec` (`origin` "options").

        Raises :class:`mrjax.InputError` naming the option for a malformed pair, an unknown
        role, a role given twice, a wrong unit, or lists that do not match the wide layout.
        """
        cols: dict[str, Column] = {}
        if columns is not None:
            items = _pairs(columns, "columns") if isinstance(columns, str) else list(
                dict(columns).items())
            for role, text in items:
                _check_role(role, "columns")
                if role in cols:
                    raise InputError(f"columns: role {role!r} given twice")
                cols[role] = Column.parse(text, where=f"columns {role}")
        wide_cols: dict[str, tuple[Column, ...]] = {}
        if wide is not None:
            if isinstance(wide, str):
                groups = [g for g in wide.split(";") if g.strip()]
                items = []
                for g in groups:
                    role, eq, rest = g.partition("=")
                    if not eq:
                        raise InputError(f"wide: expected ROLE=SOURCE:UNIT,..., got {g.strip()!r}")
                    items.append((role.strip(), [v for v in rest.split(",")]))
            else:
                items = list(dict(wide).items())
            for role, values in items:
                _check_role(role, "wide")
                if role in wide_cols:
                    raise InputError(f"wide: role {role!r} given twice")
                wide_cols[role] = _shared_unit(values, f"wide {role}")
        meta: dict[str, Any] = {}
        per_test: dict[str, list] = {}
        per_file: dict[str, dict[str, Any]] = {}
        for name, value, quantity in (("current", current, "current"),
                                      ("frequency", frequency, "frequency"),
                                      ("amplitude", amplitude, "length"),
                                      ("label", label, None),
                                      ("sample_rate", sample_rate, "frequency")):
            if value is None:
                continue
            what = name.replace("_", "-")

            def conv(v, what=what, quantity=quantity):
                if quantity is None:
                    return str(v).strip()
                return quantity_value(v, quantity, what=what)

            if isinstance(value, Mapping) or (isinstance(value, str) and "=" in value):
                pairs = _pairs(value, what) if isinstance(value, str) else list(value.items())
                for pattern, v in pairs:
                    per_file.setdefault(pattern, {})[name] = conv(v)
            elif isinstance(value, (list, tuple)) or (isinstance(value, str) and "," in value
                                                       and name != "sample_rate"):
                vals = value.split(",") if isinstance(value, str) else value
                if name == "sample_rate":
                    raise InputError("sample-rate: one rate for all tests, or FILE=RATE pairs")
                per_test[name] = [conv(v) for v in vals]
            else:
                meta[name] = conv(value)
        n = {len(v) for v in list(wide_cols.values()) + list(per_test.values())}
        if per_test and len(n) > 1:
            sizes = ", ".join(f"{k}: {len(v)}" for k, v in {**wide_cols, **per_test}.items())
            raise InputError(f"per-test lists differ in length ({sizes})")
        count = n.pop() if per_test else 0
        wide_meta = tuple(Meta(**{k: v[j] for k, v in per_test.items()}) for j in range(count))
        return cls(columns=cols, wide=wide_cols, meta=Meta(**meta), wide_meta=wide_meta,
                   files={k: Meta(**v) for k, v in per_file.items()},
                   velocity_window=velocity_window, origin="options")


def _meta_number(value: Any, where: str, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{where}: {key} must be a number, got {value!r}")
    return float(value)


def _check_role(role: str, where: str) -> None:
    if role not in ROLES:
        raise InputError(f"{where}: unknown role {role!r}; roles: {', '.join(ROLES)}")


def _pairs(text: str | Mapping, what: str) -> list[tuple[str, str]]:
    if isinstance(text, Mapping):
        return [(str(k), v) for k, v in text.items()]
    out = []
    for item in text.split(","):
        if not item.strip():
            continue
        key, eq, value = item.partition("=")
        if not eq or not key.strip() or not value.strip():
            raise InputError(f"{what}: expected KEY=VALUE pairs separated by commas, got {item!r}")
        out.append((key.strip(), value.strip()))
    if not out:
        raise InputError(f"{what}: empty")
    return out


def _shared_unit(values: Sequence[str | Column], where: str) -> tuple[Column, ...]:
    """Parse a list of columns; an item without a unit takes the next item's unit."""
    cols = [Column.parse(v.strip() if isinstance(v, str) else v, where=where) for v in values]
    unit = None
    for j in range(len(cols) - 1, -1, -1):
        if cols[j].unit is None and unit is not None and not _names_unit(cols[j]):
            cols[j] = dataclasses.replace(cols[j], unit=unit)
        unit = cols[j].unit or unit
    if not cols:
        raise InputError(f"{where}: no columns")
    return tuple(cols)


def _names_unit(col: Column) -> bool:
    if col.name is None or col.index is not None:
        return False
    try:
        return parse_column(col.name)[1] is not None
    except InputError:
        return False


def _matches(pattern: str, path: PathLike) -> bool:
    p = Path(path)
    names = {p.name, p.stem, str(path)}
    return any(fnmatch.fnmatchcase(n, pattern) for n in names)
