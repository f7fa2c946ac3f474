"""`mrjax inspect`: what mrjax reads from the files, before a long fit."""

from __future__ import annotations

import argparse
import warnings

from .. import __version__
from .._errors import InputError
from .._io import OutputDir, json_bytes
from .._warnings import ResultWarning, WarningKind
from ..data import ConditionReport, describe, find_files
from ._common import data_spec, load_conditions, use_agg
from ._parse import say


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


def run(args: argparse.Namespace, out: OutputDir) -> int:
    """Run `mrjax inspect` with parsed arguments into the claimed directory `out`; returns the
    exit code."""
    spec = data_spec(args)
    files = find_files(args.files)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        conditions = load_conditions(files, spec)
    reports = describe(conditions)
    # the loader's checks of a record are in its line; show only the other warnings
    for w in caught:
        m = w.message
        if not (isinstance(m, ResultWarning) and m.kind == WarningKind.RECORD_CHECK):
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
    say(f"writing {len(outputs)} files to {out.path}...")
    out.write(outputs)
    print(text(reports, notes, len(files)))
    return 0
