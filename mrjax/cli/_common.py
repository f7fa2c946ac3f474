"""Helpers shared by the `mrjax` commands: messages, argument types, the data options and
data loading."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._errors import InputError
from ..data import Batch, Condition, DataSpec, Source, describe, find_files, load, make_batch
from ..fitting import RUNTIME_BYTES, default_budget, parse_memory
from ..models import AbstractModel, check_bounds

DEFAULT_OUT = "mrjax-out"


def say(msg: str) -> None:
    """A short stage line on stderr (the table and results go to stdout)."""
    print(f"mrjax: {msg}", file=sys.stderr, flush=True)


def one_line(e: BaseException) -> str:
    """The message of an error as one line (OSError: `file: reason`)."""
    if isinstance(e, OSError) and not isinstance(e, InputError) and e.strerror:
        msg = f"{e.filename}: {e.strerror}" if e.filename else e.strerror
    else:
        msg = str(e) or type(e).__name__
    return " ".join(msg.split())


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line `mrjax: warning: ...` on stderr."""
    print(f"mrjax: warning: {' '.join(str(message).split())}", file=sys.stderr, flush=True)


def _int_at_least(text: str, low: int, what: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if v < low:
        raise argparse.ArgumentTypeError(f"expected {what}, got {v}")
    return v


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    return _int_at_least(text, 1, "a positive integer")


def nonneg_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    return _int_at_least(text, 0, "a non-negative integer")


def memory_size(text: str) -> int:
    """argparse type: a memory size such as `8GB`, `512MB` (see `mrjax.fitting.parse_memory`)."""
    try:
        return parse_memory(text)
    except InputError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def device_count(text: str) -> int | str:
    """argparse type: `all` or a positive number of devices."""
    if text.strip().lower() == "all":
        return "all"
    return _int_at_least(text, 1, "a positive number of devices or 'all'")


def add_scale_options(parser: argparse.ArgumentParser, *, journal: bool) -> None:
    """`--memory`, `--devices` (and for `mrjax fit`, `--chunk-size` and `--resume`): how a
    fit of many tests uses the machine; none of them changes the results."""
    g = parser.add_argument_group(
        "many tests", "how the fit uses the machine; the results do not depend on these "
        "(see 'Thousands of tests' in the README)")
    g.add_argument("--memory", type=memory_size, metavar="SIZE",
                   help="memory budget, e.g. 8GB or 512MB: the tests are fitted in chunks "
                   "whose estimated memory fits it (default: half of the available memory)")
    g.add_argument("--devices", type=device_count, metavar="N|all",
                   help="shard each chunk's tests over the first N local JAX devices, or all "
                   "(default one; on a CPU, set XLA_FLAGS=--xla_force_host_platform_device_"
                   "count=N to expose N devices)")
    if journal:
        g.add_argument("--chunk-size", type=positive_int, metavar="N",
                       help="tests per chunk instead of --memory")
        g.add_argument("--resume", action="store_true",
                       help="reuse the chunks an interrupted run left in DIR/.mrjax-journal "
                       "(same data and options required) and fit only the missing ones")


def transient(text: str) -> float | str:
    """argparse type: seconds >= 0 or `cycle`."""
    if text.strip().lower() == "cycle":
        return "cycle"
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected seconds (e.g. 0.5) or 'cycle', got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected non-negative seconds, got {text!r}")
    return v


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


#: The data flags and the `DataSpec.from_options` argument each one sets.
DATA_FLAGS: dict[str, str] = {
    "columns": "--columns", "wide": "--wide", "sample_rate": "--sample-rate",
    "current": "--current", "frequency": "--frequency", "amplitude": "--amplitude",
    "label": "--label", "velocity_window": "--velocity-window",
}


def add_data_options(parser: argparse.ArgumentParser) -> None:
    """Add the data options (where each signal is, in which unit, and what the files cannot
    say) to a sub-command's parser: `--spec FILE.toml` and the flags of
    `mrjax.data.DataSpec.from_options`, which override single keys of the spec file.

    **Arguments:** `parser`: the sub-command's parser; :func:`data_spec` reads the result.
    """
    g = parser.add_argument_group(
        "data options",
        "How to read files with their own column names, units and layouts (default: each "
        "format's conventions: long CSV with unit-suffixed headers, UTFSM txt t x v F, "
        "metadata from names like 25mm0x1Hz0x75A). UNIT is any unit of the right dimension "
        "(s, ms; m, mm, cm, in; mm/s, cm/s, in/s; N, kN, lbf; A, mA; V for a command). "
        "The flags override single keys of --spec. Check a spec with `mrjax inspect`.")
    g.add_argument("--spec", metavar="FILE.toml",
                   help="data spec file: [columns], [meta], [wide], [files], [velocity] (see "
                   "the README, 'Your own files')")
    g.add_argument("--columns", metavar="ROLE=SOURCE:UNIT,...",
                   help="where each signal is: ROLE is time, displacement, velocity, force, "
                   "current (measured, per sample), command (per-sample current or voltage), "
                   "frequency, amplitude or condition; SOURCE a CSV header, a .mat variable, "
                   "name[k] (column k, 0-based, of a 2-D .mat variable) or a bare k (column k "
                   "of a headerless text file or of the only .mat matrix); e.g. "
                   "time=t:s,displacement=x:cm,velocity=v:cm/s,force=F:N,command=V:V")
    g.add_argument("--wide", metavar="ROLE=SOURCE,...:UNIT",
                   help="one test per column: the columns of ROLE, one per test, a unit on "
                   "the last one applying to all, e.g. force=1,2,3,4,5:N (several roles: "
                   "separate by ';'); the roles of --columns are shared by all tests")
    g.add_argument("--sample-rate", metavar="HZ",
                   help="sample rate when there is no time column, e.g. 1000 or '1 kHz' "
                   "(or FILE=HZ,...)")
    g.add_argument("--current", metavar="A",
                   help="coil current of the tests: one value (0.5, '500 mA'), one per "
                   "column of --wide (0,0.25,0.5), or per file (FILE=A,...; FILE may be a "
                   "glob pattern, e.g. ensaio.B.1.mat=0.5,ensaio.B.2.mat=1)")
    g.add_argument("--frequency", metavar="HZ",
                   help="excitation frequency, given like --current (default: from the file "
                   "or its name; with data options, else estimated from the displacement "
                   "spectrum and reported as an estimate)")
    g.add_argument("--amplitude", metavar="M",
                   help="displacement amplitude in m or with a unit ('8 mm'), given like "
                   "--current (default: as --frequency; the estimate is half the range)")
    g.add_argument("--label", metavar="NAME",
                   help="test label(s), given like --current (default: the CSV condition "
                   "column or the file name, with _k for the k-th --wide column)")
    g.add_argument("--velocity-window", metavar="SECONDS",
                   help="window of the velocity estimated from displacement (when no velocity "
                   "column is read), e.g. 0.02 or '20 ms' (default: chosen from the bandwidth "
                   "of each record)")


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
               memory: int | None) -> Batch | Source:
    """The tests of a fit within `memory` bytes (None: the default budget of
    `mrjax.fitting.default_budget`): one padded batch when the budget holds them
    (`HOLD_SHARE`), else a `mrjax.data.Source` that the fit reads chunk by chunk."""
    files = find_files(paths)
    budget = memory if memory is not None else default_budget()
    keep = max(0, int(HOLD_SHARE * (budget - RUNTIME_BYTES)))
    say(f"loading {len(files)} file{'s' if len(files) != 1 else ''}...")
    source = Source.scan(files, spec=spec, keep_bytes=keep)
    if source.kept:
        return source.batch()
    C = source.n_conditions
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
    # `mrjax.data.load` warns "<spec>: files entry '<pattern>' matches none of the N file(s)
    # loaded"; the part before " matches none of the " names the entry.
    batches, unmatched = [], []
    for paths in sets:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            batches.append(load_batch(paths, spec))
        keys = set()
        for w in caught:
            head, sep, _ = str(w.message).partition(" matches none of the ")
            if sep:
                keys.add(head)
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        unmatched.append((keys, caught))
    common = set.intersection(*(k for k, _ in unmatched)) if unmatched else set()
    for w in unmatched[0][1]:
        head, sep, _ = str(w.message).partition(" matches none of the ")
        if sep and head in common:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return batches


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
