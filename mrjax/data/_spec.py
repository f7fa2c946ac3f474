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
import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any

from .._errors import InputError
from ._columns import (
    META_SI,
    ROLES,
    Column,
    Meta,
    as_meta,
    check_role,
    checked_column,
    meta_from_table,
    meta_key,
)
from ._units import check_unit, parse_column, quantity_value

PathLike = str | os.PathLike

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
            check_role(role, f"{where}: columns")
            cols[role] = checked_column(Column.parse(col, where=where), role, where)
        wide = {}
        for role, cs in dict(self.wide or {}).items():
            check_role(role, f"{where}: wide")
            if role == "condition":
                raise InputError(f"{where}: wide: condition cannot vary per column")
            if isinstance(cs, (str, Column)) or not isinstance(cs, Sequence) or not cs:
                raise InputError(f"{where}: wide {role} must be a non-empty list of columns")
            wide[role] = tuple(checked_column(Column.parse(c, where=where), role, where)
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
        meta = as_meta(self.meta, f"{where}: meta")
        wide_meta = tuple(as_meta(m, f"{where}: wide") for m in (self.wide_meta or ()))
        if wide_meta:
            if not wide:
                raise InputError(
                    f"{where}: per-test values ({len(wide_meta)}) need a wide layout (one test "
                    f"per column); for several files give FILE=VALUE pairs ([files] in a spec "
                    f"file)"
                )
            n = lengths.pop() if lengths else 0
            if len(wide_meta) != n:
                raise InputError(
                    f"{where}: wide has {n} test column(s) but {len(wide_meta)} per-test values"
                )
            if any(m.sample_rate is not None for m in wide_meta):
                raise InputError(f"{where}: sample_rate cannot vary per test; put it in meta")
        files = {str(k): as_meta(v, f"{where}: files {k!r}")
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
        """A copy with fields replaced, checked again.

        **Arguments:** `**changes`: field values, as for the constructor (e.g.
        `velocity_window=0.02`, `meta=Meta(current=0.5)`).

        **Returns:** the new :class:`DataSpec`.
        """
        return dataclasses.replace(self, **changes)

    def merged(self, other: DataSpec | None) -> DataSpec:
        """This spec with every key that `other` sets overriding it (e.g. command-line options
        over a spec file).

        **Arguments:** `other`: the overriding spec (`None`: nothing to override).

        **Returns:** the merged :class:`DataSpec`. Per key: a role of `other.columns` replaces
        that role here (in `columns` or `wide`); a wide layout of `other` replaces this one
        (with its per-test values, or these if it has none; the same layout's per-test values
        override these per test and field); metadata override per field and per file pattern;
        a set velocity window replaces this one.
        """
        if other is None:
            return self
        columns = {r: c for r, c in self.columns.items() if r not in other.wide}
        columns.update(other.columns)
        if other.wide:
            wide, wide_meta = dict(other.wide), other.wide_meta or self.wide_meta
            if (wide == dict(self.wide) and other.wide_meta
                    and len(other.wide_meta) == len(self.wide_meta)):
                # the same layout: per-test values override per test and key
                wide_meta = tuple(a.merged(b) for a, b in zip(self.wide_meta, other.wide_meta))
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
        """Options override single keys: `self.merged(DataSpec.from_options(**options))`.

        **Arguments:** `**options`: as for :meth:`from_options` (`None` = not given).
            Per-test values (`current="0,0.5,1"`) without a `wide` option refer to this
            spec's wide layout.

        **Returns:** the merged :class:`DataSpec`.
        """
        if (self.wide and options.get("wide") is None
                and any(_per_test(k, v) for k, v in options.items())):
            options = {**options, "wide": dict(self.wide)}
        return self.merged(DataSpec.from_options(**options))

    def to_toml(self) -> str:
        """The spec as a spec file (`DataSpec.from_toml` reads it back to an equal spec),
        metadata in SI (`current_A`, `frequency_Hz`, `amplitude_m`, `sample_rate_Hz`)."""

        def q(v: Any) -> str:
            return json.dumps(v) if isinstance(v, str) else repr(float(v))

        def meta_lines(m: Meta) -> list[str]:
            return [f"{k}{'' if k == 'label' else '_' + META_SI[k]} = {q(getattr(m, k))}"
                    for k in ("label", "current", "frequency", "amplitude", "sample_rate")
                    if getattr(m, k) is not None]

        out = []
        if self.columns:
            out += ["[columns]"] + [f"{r} = {q(str(c))}" for r, c in self.columns.items()] + [""]
        if not self.meta.is_empty:
            out += ["[meta]"] + meta_lines(self.meta) + [""]
        if self.wide:
            out += ["[wide]"] + [f"{r} = [{', '.join(q(str(c)) for c in cs)}]"
                                 for r, cs in self.wide.items()]
            for k in ("label", "current", "frequency", "amplitude"):
                vals = [getattr(m, k) for m in self.wide_meta]
                if vals and any(v is not None for v in vals):
                    if any(v is None for v in vals):
                        raise InputError(f"{self.origin or 'data spec'}: per-test {k} is missing "
                                         f"for some tests; a spec file needs all or none")
                    key = k if k == "label" else f"{k}_{META_SI[k]}"
                    out.append(f"{key} = [{', '.join(q(v) for v in vals)}]")
            out.append("")
        for pattern, m in self.files.items():
            out += [f"[files.{json.dumps(pattern)}]"] + meta_lines(m) + [""]
        if self.velocity_window is not None:
            out += ["[velocity]", f"window_s = {q(self.velocity_window)}", ""]
        return "\n".join(out)

    def file_meta(self, path: PathLike) -> Meta:
        """The metadata of one file.

        **Arguments:** `path`: the file (matched by name, name without extension, or path).

        **Returns:** `meta` merged with every `files` pattern that matches `path` (in order,
        later patterns winning).
        """
        meta = self.meta
        for pattern, m in self.files.items():
            if spec_matches(pattern, path):
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
            check_role(role, f"{where}: [columns]")
            if not isinstance(text, (str, int)) or isinstance(text, bool):
                raise InputError(f"{where}: [columns] {role} must be a string 'SOURCE:UNIT'")
            columns[role] = Column.parse(text, where=f"{where}: [columns] {role}")
        meta = meta_from_table(doc.get("meta", {}), f"{where}: [meta]")
        wide: dict[str, list[Column]] = {}
        per_test: dict[str, tuple[str, list]] = {}
        for key, value in doc.get("wide", {}).items():
            if not isinstance(value, list) or not value:
                raise InputError(f"{where}: [wide] {key} must be a non-empty list")
            if key in ROLES:
                wide[key] = [Column.parse(v, where=f"{where}: [wide] {key}") for v in value]
            else:
                meta_key(key, f"{where}: [wide]")
                per_test[key] = value
        n = {len(v) for v in list(wide.values()) + list(per_test.values())}
        if len(n) > 1:
            sizes = ", ".join(f"{k}: {len(v)}" for k, v in {**wide, **per_test}.items())
            raise InputError(f"{where}: [wide] lists differ in length ({sizes})")
        wide_meta = tuple(
            meta_from_table({k: v[j] for k, v in per_test.items()}, f"{where}: [wide] test {j}",
                             allow_rate=False)
            for j in range(n.pop() if n and per_test else 0)
        )
        files = {}
        for pattern, table in doc.get("files", {}).items():
            if not isinstance(table, Mapping):
                raise InputError(f"{where}: [files] {pattern!r} must be a table of metadata")
            files[pattern] = meta_from_table(table, f"{where}: [files.{pattern!r}]")
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
                check_role(role, "columns")
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
                check_role(role, "wide")
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
            elif isinstance(value, (list, tuple)) or _per_test(name, value):
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


def _per_test(name: str, value: Any) -> bool:
    """Whether an option value of :meth:`DataSpec.from_options` gives one value per test of a
    wide layout (a list, or a comma list without FILE= pairs)."""
    if name not in ("current", "frequency", "amplitude", "label") or value is None:
        return False
    if isinstance(value, (list, tuple)):
        return True
    return isinstance(value, str) and "," in value and "=" not in value


def _meta_number(value: Any, where: str, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{where}: {key} must be a number, got {value!r}")
    return float(value)


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


def spec_matches(pattern: str, path: PathLike) -> bool:
    p = Path(path)
    names = {p.name, p.stem, str(path)}
    return any(fnmatch.fnmatchcase(n, pattern) for n in names)
