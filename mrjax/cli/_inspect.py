"""`mrjax inspect`: what mrjax reads from the files, before a long fit."""

from __future__ import annotations

import argparse
import warnings

from .. import __version__
from .._errors import InputError
from .._io import atomic_output, check_writable, json_bytes
from ..data import ConditionReport, describe, find_files
from ._common import (
    DEFAULT_OUT,
    add_data_options,
    data_spec,
    load_conditions,
    positive_int,
    say,
    use_agg,
)


def _who(labels: list[str], n_all: int) -> str:
    """The conditions a note applies to, briefly."""
    if len(labels) == n_all and n_all > 2:
        return f"all {n_all} tests"
    if len(labels) > 4:
        return f"{', '.join(labels[:3])}, ... ({len(labels)} tests)"
    return ", ".join(labels)


def _notes(reports: list[ConditionReport]) -> list[str]:
    """The loader's notes, each once, with the tests it applies to: `tests: note`."""
    who: dict[str, list[str]] = {}
    for r in reports:
        for n in r.notes:
            who.setdefault(n, []).append(r.label)
    return [f"{_who(labels, len(reports))}: {n}" for n, labels in who.items()]


def text(reports: list[ConditionReport], notes: list[str], n_files: int) -> str:
    """The printed report: one line per condition, then the notes and what `~` means."""
    lines = [r.line() for r in reports]
    if notes:
        lines += ["notes (what the loader tolerated or decided):"] + [f"  {n}" for n in notes]
    if any(r.estimated & {"frequency", "amplitude"} for r in reports):
        lines.append("~: estimated from the displacement spectrum (peak frequency, half the "
                     "range); give --frequency/--amplitude to set them")
    n_warn = sum(bool(r.warnings) for r in reports)
    lines.append(f"{len(reports)} test(s) from {n_files} file(s)"
                 + (f", {n_warn} with warnings" if n_warn else ", no warnings"))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Run `mrjax inspect` with parsed arguments; returns the exit code."""
    out = check_writable(args.out)
    spec = data_spec(args)
    files = find_files(args.files)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        conditions = load_conditions(files, spec)
    reports = describe(conditions)
    # the loader's warnings about a condition are in its line; show only the others
    in_lines = [w for r in reports for w in r.warnings]
    for w in caught:
        if not any(s in str(w.message) for s in in_lines):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    notes = _notes(reports)
    toml = None
    if spec is not None:
        try:
            toml = spec.to_toml()
        except InputError as e:  # e.g. per-test values given for some tests only
            say(f"the data spec is not written as spec.toml: {e}")
    doc = {"mrjax_version": __version__, "spec": toml,
           "conditions": [r.to_dict() for r in reports]}
    outputs = {"inspect.json": json_bytes(doc)}
    if toml is not None:
        outputs["spec.toml"] = toml.encode()
    if not args.no_plots:
        use_agg()
        from .. import report as rp  # imported here: matplotlib only when figures are drawn

        names = [f.name for f in files]
        title = f"What mrjax read: {', '.join(names[:3])}" + (
            f" and {len(names) - 3} more file(s)" if len(names) > 3 else "")
        outputs["inspect.png"] = rp.save_png_bytes(
            rp.plot_records(conditions, max_panels=args.max_panels, title=title))
    say(f"writing {len(outputs)} files to {out}...")
    atomic_output(out, outputs)
    print(text(reports, notes, len(files)))
    return 0


def add_parser(sub, common: argparse.ArgumentParser) -> None:
    """Register `mrjax inspect` and its options."""
    p = sub.add_parser(
        "inspect", parents=[common], help="show what mrjax reads from files (check a data spec)",
        description="Read the files as `mrjax fit` would and print one line per test: samples, "
        "rate, duration, ranges with units, frequency and amplitude (~ marks an estimate), "
        "velocity measured or estimated, current or command, warnings; then the loader's "
        "notes (skipped lines, unused columns). Writes inspect.png (every signal against "
        "time), inspect.json and, when data options were given, spec.toml (the effective "
        "spec, reusable with --spec) into --out, atomically.")
    p.add_argument("files", nargs="+", metavar="FILE", help="data files or directories")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default ./{DEFAULT_OUT})")
    p.add_argument("--max-panels", type=positive_int, default=12, metavar="N",
                   help="at most N tests in inspect.png, evenly spread (default 12)")
    p.add_argument("--no-plots", action="store_true", help="write no PNG figure")
    add_data_options(p)
    p.set_defaults(func=run)
