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
    parameters, units, default bounds and which are linear. A model that fails its checks is an
    error (exit 2)."""
    from .._tables import format_table
    from ..models import aliases, describe_source, get, names, source_of

    style = "markdown" if args.markdown else "plain"
    other = {}
    for alias, name in aliases().items():
        other.setdefault(name, []).append(alias)
    blocks = []
    listed = list(names())
    models = [get(spec) for spec in args.model or ()]  # loaded first: checked, registered
    listed += [m.name for m in models if m.name not in listed]
    for name in listed:
        m = get(name)
        lo, hi = m.bounds
        lin = set(m.linear_params)
        rows = [[p, u, float(a), float(b), p in lin]
                for p, u, a, b in zip(m.param_names, m.units, lo, hi)]
        kind = "ODE (internal state)" if m.dynamic else "memoryless"
        also = f" (also: {', '.join(other[name])})" if name in other else ""
        source = describe_source(source_of(m))
        ref = getattr(m, "reference", "")
        head = f"{name}{also}  [{kind}; {source}]  {m.description}".rstrip()
        if ref:
            head += f" ({ref})"
        if args.markdown:
            head = (f"### {name}\n\n{m.description} ({kind}; {source}"
                    + (f"; {ref}" if ref else "") + ")"
                    + (f"; aliases: {', '.join(f'`{a}`' for a in other[name])}" if also else "")
                    + "\n")
        blocks.append(head + "\n" + format_table(
            rows, ["parameter", "unit", "lower", "upper", "linear"], style=style, floatfmt="g"))
    print("\n\n".join(blocks))
    return 0
