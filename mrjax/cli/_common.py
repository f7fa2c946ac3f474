"""Helpers shared by the `mrjax` commands when they run: bounds, the data spec of the data
options, data loading, figures and fit.json reading (the parser's light helpers are in
`_parse`)."""

from __future__ import annotations

import argparse
import json
import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._errors import InputError
from .._warnings import ResultWarning, WarningKind
from ..data import Batch, Condition, DataSpec, Source, describe, find_files, load, make_batch
from ..fitting import RUNTIME_BYTES, default_budget
from ..models import AbstractModel, check_bounds
from ._parse import DATA_FLAGS, say


def parse_fixed(items: list[str] | None) -> dict[str, float] | None:
    """`--fixed NAME=VALUE` options as `{name: value}` [SI] for `mrjax.models.fix`, or None."""
    if not items:
        return None
    out: dict[str, float] = {}
    for item in items:
        name, eq, text = item.partition("=")
        name = name.strip()
        if not (eq and name):
            raise InputError(f"--fixed {item!r}: expected NAME=VALUE, e.g. delta=1")
        if name in out:
            raise InputError(f"--fixed: parameter {name!r} given twice")
        try:
            out[name] = float(text)
        except ValueError:
            raise InputError(f"--fixed {item!r}: VALUE is not a number: {text.strip()!r}") from None
    return out


def parse_bounds(items: list[str] | None, model: AbstractModel) -> tuple[dict, dict] | None:
    """`--bounds NAME=LO:HI` options (an empty LO or HI keeps the default) as checked
    `(lower, upper)` dicts for `mrjax.fit`, or None."""
    if not items:
        return None
    lower: dict[str, float] = {}
    upper: dict[str, float] = {}
    seen: set[str] = set()
    for item in items:
        name, eq, rng = item.partition("=")
        lo, colon, hi = rng.partition(":")
        name = name.strip()
        if not (eq and colon and name):
            raise InputError(f"--bounds {item!r}: expected NAME=LO:HI, e.g. c=500:5000")
        if name in seen:
            raise InputError(f"--bounds: parameter {name!r} given twice")
        seen.add(name)
        for side, text, d in (("LO", lo, lower), ("HI", hi, upper)):
            if text.strip():
                try:
                    d[name] = float(text)
                except ValueError:
                    raise InputError(f"--bounds {item!r}: {side} is not a number: "
                                     f"{text.strip()!r}") from None
    try:
        check_bounds(model, (lower, upper))
    except InputError as e:
        raise InputError(f"--bounds: {e}") from None
    return lower, upper


# --------------------------------------------------------------------------------------------
# Data options: one data spec (`mrjax.data.DataSpec`) from --spec and flags


def data_spec(args: argparse.Namespace) -> DataSpec | None:
    """The data spec of a command's parsed data options: the `--spec` file with every given
    flag overriding its single key, or `None` when no data option was given (files are then
    read by their own conventions, as `mrjax.data.load(paths)`).

    Raises :class:`mrjax.InputError` (one line naming the option or the spec file) for a
    malformed spec file or flag.
    """
    options = {k: getattr(args, k, None) for k in DATA_FLAGS}
    options = {k: v for k, v in options.items() if v is not None}
    path = getattr(args, "spec", None)
    if path is None and not options:
        return None
    spec = DataSpec.from_toml(path) if path is not None else DataSpec()
    if not options:
        return spec
    try:
        return spec.with_options(**options)
    except InputError as e:
        raise InputError(_blame(spec, options, e)) from None


def _blame(spec: DataSpec, options: dict[str, str], error: InputError) -> str:
    """The message of a data-flag error, led by the flag at fault: the first flag that fails
    alone with the same message (else all the flags given, e.g. lists of different lengths)."""
    msg = str(error)
    for key, value in options.items():
        try:
            spec.with_options(**{key: value})
        except InputError as alone:
            if str(alone) == msg:
                for head in ("options: ", f"{key}: ", f"{key.replace('_', '-')}: "):
                    msg = msg.removeprefix(head)
                return f"{DATA_FLAGS[key]}: {msg}"
    given = ", ".join(DATA_FLAGS[k] for k in options)
    return f"{given}: {msg.removeprefix('options: ')}"


def load_conditions(paths: Sequence[str | os.PathLike],
                    spec: DataSpec | None = None) -> list[Condition]:
    """Expand files and directories, say how many, and load them (`mrjax.data.load`) with
    `spec` (`None`: by the files' own conventions)."""
    files = find_files(paths)
    say(f"loading {len(files)} file{'s' if len(files) != 1 else ''}...")
    return load(files, spec=spec)


#: A fit holds its tests when their parsed columns take at most this share of the budget left
#: after the runtime (the batch built from them takes about as much again; the chunks need the
#: rest); otherwise they are streamed from the files.
HOLD_SHARE = 1 / 3


def load_tests(paths: Sequence[str | os.PathLike], spec: DataSpec | None,
               memory: int | None, *, stream: bool = False) -> Batch | Source:
    """The tests of a fit within `memory` bytes (None: the default budget of
    `mrjax.fitting.default_budget`): one padded batch when the budget holds them
    (`HOLD_SHARE`), else a `mrjax.data.Source` that the fit reads chunk by chunk; always the
    `Source` with `stream` (a cluster's workers read their chunks from the files)."""
    files = find_files(paths)
    budget = memory if memory is not None else default_budget()
    keep = 0 if stream else max(0, int(HOLD_SHARE * (budget - RUNTIME_BYTES)))
    say(f"loading {len(files)} file{'s' if len(files) != 1 else ''}...")
    source = Source.scan(files, spec=spec, keep_bytes=keep)
    C = source.n_conditions
    if stream:
        say(f"the {C} tests are read from the files chunk by chunk by the cluster's workers")
        return source
    if source.kept:
        return source.batch()
    say(f"the {C} tests take more than the memory budget ({budget / 1e9:.3g} GB) can hold "
        f"with the fit: they are read from the files chunk by chunk")
    return source


def load_batch(paths: Sequence[str | os.PathLike], spec: DataSpec | None = None) -> Batch:
    """Expand files/directories, say how many, load them (with `spec`, if any) into one padded
    batch."""
    return make_batch(load_conditions(paths, spec))


def load_batches(sets: Sequence[Sequence[str | os.PathLike]],
                 spec: DataSpec | None = None) -> list[Batch]:
    """Several sets of files read with one spec (`mrjax compare FILES --validate FILES`), one
    batch per set. A spec's `[files]` entry (or `FILE=VALUE` flag) need match only one of the
    sets: the loader's warning that it matches no file is kept only when it matches none."""
    batches, unmatched = [], []
    for paths in sets:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            batches.append(load_batch(paths, spec))
        keys = set()
        for w in caught:
            if _unmatched(w.message):
                keys.add(w.message.parameters[0])
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        unmatched.append((keys, caught))
    common = set.intersection(*(k for k, _ in unmatched)) if unmatched else set()
    for w in unmatched[0][1]:
        if _unmatched(w.message) and w.message.parameters[0] in common:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return batches


def _unmatched(message: Any) -> bool:
    """Whether a warning says a spec's `files` entry matched no file."""
    return isinstance(message, ResultWarning) and message.kind == WarningKind.SPEC_UNMATCHED


def say_estimates(batch: Batch | np.ndarray) -> None:
    """One stage line saying how many tests' velocity, frequency or amplitude are estimates
    rather than read (nothing when none is; `batch`: the tests, or their (C, 3) `estimated`
    flags); the outputs list them per test."""
    est = np.asarray(batch.estimated if isinstance(batch, Batch) else batch, bool)
    parts = [f"{what} of {int(est[:, j].sum())}"
             for j, what in enumerate(("velocity", "frequency", "amplitude")) if est[:, j].any()]
    if parts:
        C = est.shape[0]
        say(f"estimated, not read ('estimated' in the JSON output): {', '.join(parts)} of the "
            f"{C} test{'s' if C != 1 else ''}")


def force_figures(model: object, batch: Batch, force: np.ndarray, rms: np.ndarray, *,
                  titles: tuple[str, str], prefix: str = "") -> dict[str, bytes]:
    """The measured vs model force figures of a batch, name -> PNG bytes: `loops.png` (F-x and
    F-v loops) of the periodic conditions and `force_time.png` (force against time, whole and
    zoomed, with the residual) of those whose motion has no single dominant frequency
    (`mrjax.data.describe(batch)[i].broadband`: random, earthquake-type records); each only
    when it has conditions.

    **Arguments:** `model`: the fitted object (for names); `batch`: the data; `force` (C, T)
    [N]: the model's force; `rms` (C,) [N]; `titles`: of the loops and of the time-series
    figure; `prefix` of the file names.
    """
    use_agg()
    from .. import report as rp  # imported here: matplotlib only when figures are drawn

    wide = np.array([r.broadband for r in describe(batch)], bool)
    out = {}
    for name, sel, plot, title in (("loops.png", ~wide, rp.plot_loops_grid, titles[0]),
                                   ("force_time.png", wide, rp.plot_force_time, titles[1])):
        idx = np.flatnonzero(sel)
        if idx.size == 0:
            continue
        sub = batch if idx.size == batch.n_conditions else batch.subset(idx)
        f = np.asarray(force, float)[idx][:, : sub.length]
        out[prefix + name] = rp.save_png_bytes(plot(model, sub, force=f, rms=np.asarray(rms)[idx],
                                                    title=title))
    return out


def read_fit_json(path: str) -> dict:
    """A `fit.json` (or the one in a directory) as a dict; InputError if it is not one."""
    p = Path(path).expanduser()
    if p.is_dir():
        p = p / "fit.json"
    if not p.is_file():
        raise InputError(f"{path}: no such file (expected a fit.json written by `mrjax fit`)")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a fit.json (not UTF-8 text)") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: not valid JSON (line {e.lineno}, column {e.colno}: "
                         f"{e.msg})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: not a fit.json (expected a JSON object)")
    return doc


def use_agg() -> None:
    """Select matplotlib's Agg backend (no display) before any figure is drawn."""
    import matplotlib  # imported here: only commands that draw need it

    matplotlib.use("Agg")
