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
    """Print every model: aliases, parameters, units, default bounds, which are linear."""
    from ..models import aliases, get, names
    from ..report import format_table

    style = "markdown" if args.markdown else "plain"
    other = {}
    for alias, name in aliases().items():
        other.setdefault(name, []).append(alias)
    blocks = []
    for name in names():
        m = get(name)
        lo, hi = m.bounds
        lin = set(m.linear_params)
        rows = [[p, u, float(a), float(b), p in lin]
                for p, u, a, b in zip(m.param_names, m.units, lo, hi)]
        kind = "ODE (internal state)" if m.dynamic else "memoryless"
        also = f" (also: {', '.join(other[name])})" if name in other else ""
        head = f"{name}{also}  [{kind}]  {m.description}".rstrip()
        if args.markdown:
            head = f"### {name}\n\n{m.description} ({kind}){'.' if not also else ';'}" + (
                f" aliases: {', '.join(f'`{a}`' for a in other[name])}\n" if also else "\n")
        blocks.append(head + "\n" + format_table(
            rows, ["parameter", "unit", "lower", "upper", "linear"], style=style, floatfmt="g"))
    print("\n\n".join(blocks))
    return 0
