"""`mrjax reproduce` and `mrjax models`."""

from __future__ import annotations

import argparse
import importlib

from .._io import OutputDir


def run_reproduce(args: argparse.Namespace, out: OutputDir) -> int:
    """Run `mrjax reproduce` into the claimed directory `out`; returns the exit code of
    `mrjax.reproduce.run`."""
    # imported when the command runs: the study loads the figure and report machinery, which
    # the other commands do not need
    reproduce = importlib.import_module("mrjax.reproduce")
    return int(reproduce.run(out, quick=args.quick, data=args.data, seed=args.seed) or 0)


def run_models(args: argparse.Namespace) -> int:
    """Print every model (and those of `--model`): its aliases, where it comes from, its
    parameters, units, default bounds, which are linear and which are fixed; for each model of
    `--model`, the checks its declaration passed. A model that fails its checks is an error
    (exit 2)."""
    from .._tables import format_table
    from ..models import aliases, describe_source, get, names, source_of

    other: dict[str, list[str]] = {}
    for alias, name in aliases().items():
        other.setdefault(name, []).append(alias)
    listed = list(names())
    models = [get(spec) for spec in args.model or ()]  # loaded first: checked, registered
    listed += [m.name for m in models if m.name not in listed]
    given = {m.name: m for m in models}
    blocks = []
    for name in listed:
        m = given.get(name) or get(name)
        blocks.append(_model_block(m, other.get(name, []), describe_source(source_of(m)),
                                   args.markdown, format_table))
        checks = getattr(m.unfixed, "checks", ()) if name in given else ()
        if checks:
            blocks[-1] += "\n" + ("checks passed:\n" if not args.markdown else
                                  "\nchecks passed:\n\n") + "\n".join(f"- {c}" for c in checks)
    print("\n\n".join(blocks))
    return 0


def _model_block(m, also: list[str], source: str, markdown: bool, format_table) -> str:
    """One model's heading and parameter table."""
    lo, hi = m.bounds
    lin = set(m.linear_params)
    rows = [[p, u, float(a), float(b), p in lin]
            for p, u, a, b in zip(m.param_names, m.units, lo, hi)]
    kind = "ODE (internal state)" if m.dynamic else "memoryless"
    ref = getattr(m, "reference", "")
    if markdown:
        head = (f"### {m.name}\n\n{m.description} ({kind}; {source}"
                + (f"; {ref}" if ref else "") + ")"
                + (f"; aliases: {', '.join(f'`{a}`' for a in also)}" if also else "") + "\n")
    else:
        names = f"{m.name} (also: {', '.join(also)})" if also else m.name
        head = f"{names}  [{kind}; {source}]  {m.description}".rstrip()
        head += f" ({ref})" if ref else ""
    table = format_table(rows, ["parameter", "unit", "lower", "upper", "linear"],
                         style="markdown" if markdown else "plain", floatfmt="g")
    held = ", ".join(f"{n} = {v:g}" for n, v in m.fixed.items())
    return head + "\n" + table + ((("\n\n" if markdown else "\n") + f"fixed: {held}")
                                   if held else "")
