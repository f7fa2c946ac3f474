"""Helpers shared by the `mrjax` commands: messages, argument types, data loading."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from .._errors import InputError
from ..data import Batch, find_files, load, make_batch
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


def load_batch(paths: list[str]) -> Batch:
    """Expand files/directories, say how many, load them into one padded batch."""
    files = find_files(paths)
    say(f"loading {len(files)} file{'s' if len(files) != 1 else ''}...")
    return make_batch(load(files))


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
