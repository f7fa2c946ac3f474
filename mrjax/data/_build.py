"""From what a reader found in a file to checked SI conditions: the one path of every loader.

Each file format has a reader (`_text.py`, `_csv.py`, `_mat.py`, `_frame.py`) that finds the
columns a spec (or the file's own conventions) asks for and returns a :class:`ReadColumns`: raw values
per column, the line of each row, notes on what it tolerated. :func:`assemble` then converts
units, splits tests (a `condition` column, the wide layout), applies metadata, builds the time
axis from a sample rate when there is no time column, estimates velocity, frequency and
amplitude where the file has none, and runs the sanity checks (`_checks.py`).

Two modes: **strict** (the loaders called without a spec: today's conventions, a current
column must be constant, no estimates of frequency and amplitude) and **spec** (a per-sample
current that varies becomes the condition's command; missing frequency and amplitude are
estimated and marked so).
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from collections.abc import Mapping, Sequence

import numpy as np

from .._errors import InputError
from .._warnings import ResultWarning, WarningKind
from ._checks import check_record
from ._columns import ROLES, SIGNAL_ROLES, Column, Meta
from ._condition import Condition
from ._spectrum import estimate_motion
from ._units import check_unit, command_unit
from ._velocity import estimate_velocity, velocity_window


@dataclasses.dataclass(frozen=True)
class LineMap:
    """The line of the file on which each data row stands, stored as runs: rows `rows[k]`,
    `rows[k] + 1`, ... (up to the next run) stand on lines `lines[k]`, `lines[k] + 1`, ...
    (a fleet's millions of rows take a few runs, not an array of lines)."""

    rows: np.ndarray
    lines: np.ndarray

    @classmethod
    def of(cls, lines: Sequence[int] | np.ndarray) -> LineMap:
        """The map of rows standing on `lines` (one line number per row)."""
        a = np.asarray(lines, dtype=np.int64)
        starts = np.flatnonzero(np.diff(a) != 1) + 1 if a.size else np.zeros(0, np.int64)
        starts = np.concatenate([[0], starts]) if a.size else starts
        return cls(starts.astype(np.int64), a[starts])

    @classmethod
    def run(cls, first_line: int) -> LineMap:
        """Rows on consecutive lines from `first_line`."""
        return cls(np.zeros(1, np.int64), np.asarray([first_line], np.int64))

    @classmethod
    def join(cls, parts: Sequence[tuple[int, LineMap]]) -> LineMap:
        """One map of parts read one after the other: `(first row, map of the part)` each."""
        rows = [m.rows + r0 for r0, m in parts]
        lines = [m.lines for _, m in parts]
        if not rows:
            return cls(np.zeros(0, np.int64), np.zeros(0, np.int64))
        return cls(np.concatenate(rows), np.concatenate(lines))

    def line(self, i: int) -> int:
        """The line of row `i`."""
        k = int(np.searchsorted(self.rows, i, side="right")) - 1
        return int(self.lines[k] + (i - self.rows[k]))

    def taken(self, rows: np.ndarray) -> LineMap:
        """The map of the rows `rows` (increasing) taken out of this one."""
        rows = np.asarray(rows, dtype=np.int64)
        k = np.searchsorted(self.rows, rows, side="right") - 1
        return LineMap.of(self.lines[k] + (rows - self.rows[k]))


@dataclasses.dataclass(frozen=True)
class Codes:
    """A text column (the `condition` column) as integer codes into its distinct values, in
    order of first appearance: row i holds `names[codes[i]]`."""

    codes: np.ndarray
    names: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.codes.shape[0])

    @classmethod
    def of(cls, values: Sequence[str] | np.ndarray) -> Codes:
        """The codes of text values (`str` of each; a file's rows: one dict look-up per row,
        not numpy's fixed-width strings, which drop trailing NUL characters)."""
        index: dict[str, int] = {}
        codes = np.fromiter((index.setdefault(str(v), len(index)) for v in values),
                            dtype=np.int32, count=len(values))
        return cls(codes, tuple(index))


#: The rows of one condition: a slice (rows stored together, as most files do) or their index.
Rows = slice | np.ndarray


def groups(keys: Codes) -> dict[str, Rows]:
    """The rows of each distinct value of `keys`, in order of first appearance: slices where
    each value's rows are stored together, index arrays (in file order) otherwise."""
    c = np.asarray(keys.codes)
    if c.size and np.all(c[1:] >= c[:-1]):  # stored together, in order of appearance
        cuts = np.concatenate([[0], np.flatnonzero(np.diff(c)) + 1, [c.size]])
        return {keys.names[int(c[a])]: slice(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:])}
    order = np.argsort(c, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(np.bincount(c, minlength=len(keys.names)))])
    return {name: order[bounds[k]:bounds[k + 1]] for k, name in enumerate(keys.names)
            if bounds[k + 1] > bounds[k]}


def condition_keys(read: ReadColumns) -> list[str | None]:
    """The `condition` values of a read file in the order :func:`assemble` returns their
    conditions (each repeated for the tests of a wide layout), or `[None]` without that
    column."""
    if "condition" not in read.columns:
        return [None]
    keys = read.values[read.columns["condition"]]
    return list(groups(keys if isinstance(keys, Codes) else Codes.of(keys)))


def _row(idx: Rows, k: int) -> int:
    """The file row of the k-th row of a condition."""
    return idx.start + k if isinstance(idx, slice) else int(idx[k])


@dataclasses.dataclass
class ReadColumns:
    """What a reader found: every column asked for, raw (in the file's units)."""

    where: str  # the file, for messages
    stem: str  # the default label
    n: int  # number of data rows
    columns: dict[str, Column]  # shared roles
    wide: dict[str, tuple[Column, ...]]  # one column per test
    values: dict[Column, np.ndarray | Codes]  # float (n,) per numeric column; Codes for text
    lines: LineMap | None = None  # the line of each row in the file (text formats)
    notes: list[str] = dataclasses.field(default_factory=list)
    file_meta: Meta = Meta()  # metadata the file itself states (e.g. .mat scalar variables)

    def row_name(self, i: int) -> str:
        return f"line {self.lines.line(i)}" if self.lines is not None else f"row {i}"


def _label(base: str, parts: Sequence[str]) -> str:
    return "_".join([base, *parts]) if parts else base


@functools.lru_cache(maxsize=1024)
def _unit_scale(unit: str, role: str, where: str) -> float:
    return check_unit(unit, ROLES[role], what=role, where=where)


def _scale(read: ReadColumns, col: Column, role: str) -> float:
    """The SI factor of a column's unit in a role (checked once per unit, role and file)."""
    return _unit_scale(col.unit, role, read.where)


def _constant(read: ReadColumns, col: Column, role: str, idx: Rows, group: str | None,
              strict: bool) -> float | None:
    """The value of a per-condition column (constant within the condition), in SI."""
    raw = read.values[col][idx]
    same = (raw == raw[0]) | (np.isnan(raw) & np.isnan(raw[0]))
    if not np.all(same):
        k = int(np.argmin(same))
        within = f"condition {group!r}" if group is not None else "the file"
        raise InputError(
            f"{read.where}: column {col.source!r} must be constant within {within}, but is "
            f"{raw[0]:g} on {read.row_name(_row(idx, 0))} and {raw[k]:g} on "
            f"{read.row_name(_row(idx, k))}"
        )
    if not strict and np.isnan(raw[0]):
        return None  # an empty metadata column: not given
    return float(raw[0]) * _scale(read, col, role)


def _signal(read: ReadColumns, col: Column, role: str, idx: Rows) -> np.ndarray:
    """The condition's samples of a signal in SI (a view of the column where the file holds
    them in SI and together)."""
    scale = _scale(read, col, role)
    raw = read.values[col][idx]
    return raw if scale == 1.0 else raw * scale


def assemble(
    read: ReadColumns,
    *,
    meta: Meta,
    wide_meta: Sequence[Meta] = (),
    window_s: float | None = None,
    strict: bool,
    fallback: Meta = Meta(),
) -> list[Condition]:
    """The conditions of one read file (see the module notes).

    Metadata, strongest first: `wide_meta` (one Meta per test of the wide layout), `meta` (the
    caller's: spec and arguments), the file's own (`read.file_meta`, then metadata columns),
    `fallback` (the file name), and in spec mode estimates. `window_s` is the velocity window
    (None: automatic).
    """
    where = read.where
    roles = set(read.columns) | set(read.wide)
    for need in ("displacement", "force"):
        if need not in roles:
            have = ", ".join(f"{r}={c}" for r, c in read.columns.items()) or "none"
            raise InputError(
                f"{where}: no {need} column; give it as {need}=SOURCE:UNIT (columns: {have})"
            )
    meta = read.file_meta.merged(meta)
    if "condition" in read.columns:
        keys = read.values[read.columns["condition"]]
        by_key: dict[str | None, Rows] = groups(keys if isinstance(keys, Codes) else Codes.of(keys))
    else:
        by_key = {None: slice(0, read.n)}
    n_wide = len(next(iter(read.wide.values()))) if read.wide else 0
    tests = list(range(n_wide)) if n_wide else [None]
    out = []
    for key, idx in by_key.items():
        for j in tests:
            cols = dict(read.columns)
            m = meta
            if j is not None:
                cols.update({r: cs[j] for r, cs in read.wide.items()})
                if wide_meta:
                    m = m.merged(wide_meta[j])
            parts = [p for p in (key, None if j is None else str(j)) if p is not None]
            source = where
            if key is not None:
                source += f" (condition {key!r})"
            if j is not None:
                source += f" ({', '.join(f'{r} {cs[j].source}' for r, cs in read.wide.items())})"
            if j is not None and wide_meta and wide_meta[j].label is not None:
                label = wide_meta[j].label
            elif key is not None and m.label is None:
                label = _label(key, [str(j)] if j is not None else [])
            else:
                label = _label(m.label if m.label is not None else read.stem, parts)
            # absurd values (1e308) overflow in the estimates and checks: their non-finite
            # results are caught by the checks of the condition, not printed by numpy
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                out.append(_one(read, cols, idx, key, m, fallback, label, source, window_s,
                                strict))
    return out


def _one(read: ReadColumns, cols: Mapping[str, Column], idx: Rows, key: str | None, meta: Meta,
         fallback: Meta, label: str, source: str, window_s: float | None,
         strict: bool) -> Condition:
    notes = list(read.notes)
    sig = {r: _signal(read, c, r, idx) for r, c in cols.items() if r in SIGNAL_ROLES}
    values = dict(current=meta.current, frequency=meta.frequency, amplitude=meta.amplitude)
    for role in ("frequency", "amplitude"):
        if role in cols and values[role] is None:
            values[role] = _constant(read, cols[role], role, idx, key, strict)
    command = unit = None
    if "current" in cols:
        raw = read.values[cols["current"]][idx]
        constant = bool(np.all((raw == raw[0]) | (np.isnan(raw) & np.isnan(raw[0]))))
        # (an empty current column of a condition without one reads as all NaN: not given)
        if strict or constant:
            given = _constant(read, cols["current"], "current", idx, key, strict)
            if values["current"] is None:
                values["current"] = given
        else:
            command, unit = sig["current"], "A"
            notes.append(f"current varies within the test ({np.min(command):g} to "
                         f"{np.max(command):g} A): kept as a per-sample command")
    for name in ("current", "frequency", "amplitude"):
        if values[name] is None:
            values[name] = getattr(fallback, name)
    if "command" in cols and not (not strict and np.all(np.isnan(sig["command"]))):
        command, unit = sig["command"], command_unit(cols["command"].unit)
    if "time" in sig:
        t = sig["time"]
        if meta.sample_rate is not None and len(t) > 1:
            fs = 1.0 / float(np.median(np.diff(t)))
            if abs(fs / meta.sample_rate - 1.0) > 0.01:
                _warn(source, f"sample rate {meta.sample_rate:g} Hz ignored: the time column "
                              f"gives {fs:.6g} Hz", WarningKind.IGNORED_METADATA)
    elif meta.sample_rate is not None:
        t = np.arange(len(sig["displacement"])) / meta.sample_rate
        notes.append(f"no time column: time from the sample rate {meta.sample_rate:g} Hz")
    else:
        raise InputError(
            f"{read.where}: no time column and no sample rate; give time=SOURCE:UNIT, or "
            f"sample_rate_Hz in [meta] (--sample-rate)"
        )
    x, force = sig["displacement"], sig["force"]
    estimated: set[str] = set()
    xdot = sig.get("velocity")
    cond = Condition(label, values["current"], values["frequency"], values["amplitude"], t, x,
                     np.zeros_like(x) if xdot is None else xdot, force, source=source,
                     command=command, command_unit=unit)
    cond_warnings: list[str] = []
    if xdot is None:
        try:
            if window_s is None:
                vw = velocity_window(cond.t, cond.x)
                window = vw.samples * float(np.median(np.diff(cond.t)))
                how = f"automatic window {vw.samples} samples ({window:.4g} s)"
                if vw.expected_error > 0:
                    how += f", expected error {100 * vw.expected_error:.2g} %"
                if vw.broadband:
                    cond_warnings.append(
                        f"no velocity column and the displacement is broadband (its peak at "
                        f"{vw.peak_Hz:.3g} Hz holds {100 * vw.peak_share:.0f} % of the velocity "
                        f"energy; 99 % lies below {vw.bandwidth_Hz:.3g} Hz): velocity estimated "
                        f"with an automatic {window:.3g} s window; check it, or set the "
                        f"velocity window"
                    )
            else:
                window, how = window_s, f"given window {window_s:g} s"
            v = estimate_velocity(cond.t, cond.x, window_s=window)
        except InputError as e:
            raise InputError(f"{source}: no velocity column, and {e}") from None
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:  # displacements near the float limit
            raise InputError(
                f"{source}: no velocity column, and the velocity estimated from the "
                f"displacement is not finite at row {bad[0]} (the displacement reaches "
                f"{np.max(np.abs(cond.x)):g} m): check its values and unit")
        notes.append(f"velocity estimated from displacement (Savitzky-Golay, {how})")
        estimated.add("xdot")
    changes: dict[str, object] = {} if xdot is not None else {"xdot": v}
    frequency = cond.frequency
    if not strict and (cond.frequency is None or cond.amplitude is None):
        f_est, a_est = estimate_motion(cond.t, cond.x)
        if cond.frequency is None and f_est > 0:
            changes["frequency"] = frequency = f_est
            estimated.add("frequency")
        if cond.amplitude is None:
            changes["amplitude"] = a_est
            estimated.add("amplitude")
    cond_warnings = check_record(cond.t, cond.x, xdot if xdot is None else cond.xdot,
                                 frequency) + cond_warnings
    for w in cond_warnings:
        _warn(source, w, WarningKind.RECORD_CHECK)
    return dataclasses.replace(cond, **changes, estimated=frozenset(estimated),
                               notes=tuple(notes), warnings=tuple(cond_warnings))


def _warn(source: str, message: str, kind: WarningKind) -> None:
    warnings.warn(ResultWarning(kind, f"{source}: {message}", conditions=(source,)), stacklevel=5)
