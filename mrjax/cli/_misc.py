"""`mrjax reproduce` and `mrjax models`."""

from __future__ import annotations

import argparse
import importlib

from .._tables import format_table
from ..models import describe_source, get, names, source_of
from ._common import DEFAULT_OUT, nonneg_int


def run_reproduce(args: argparse.Namespace) -> int:
    """Run `mrjax reproduce`; returns the exit code of `mrjax.reproduce.run`."""
    # imported when the command runs: the study loads the figure and report machinery, which
    # the other commands do not need
    reproduce = importlib.import_module("mrjax.reproduce")
    return int(reproduce.run(args.out, quick=args.quick, data=args.data, seed=args.seed) or 0)


def run_models(args: argparse.Namespace) -> int:
    """Print every model (and those of `--model`): where it comes from, its parameters, units,
    default bounds and which are linear. A model that fails its checks is an error (exit 2)."""
    style = "markdown" if args.markdown else "plain"
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
        source = describe_source(source_of(m))
        ref = getattr(m, "reference", "")
        head = f"{name}  [{kind}; {source}]  {m.description}".rstrip()
        if ref:
            head += f" ({ref})"
        if args.markdown:
            head = (f"### {name}\n\n{m.description} ({kind}; {source}"
                    + (f"; {ref}" if ref else "") + ")\n")
        blocks.append(head + "\n" + format_table(
            rows, ["parameter", "unit", "lower", "upper", "linear"], style=style, floatfmt="g"))
    print("\n\n".join(blocks))
    return 0


def add_parsers(sub, common: argparse.ArgumentParser) -> None:
    """Register `mrjax reproduce` and `mrjax models`."""
    p = sub.add_parser("reproduce", parents=[common],
                       help="reproduce the paper's study on the embedded data",
                       description="Reproduce the study of Kwok et al. (2006).")
    p.add_argument("--quick", action="store_true", help="a small, fast version")
    p.add_argument("--data", metavar="DIR", help="measured data directory (default: embedded)")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default ./{DEFAULT_OUT})")
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")
    p.set_defaults(func=run_reproduce)

    p = sub.add_parser("models", parents=[common],
                       help="list models with parameters, units and default bounds")
    p.add_argument("--markdown", action="store_true", help="markdown tables")
    p.add_argument("--model", action="append", metavar="FILE.py:NAME",
                   help="also check and list your own model (repeatable)")
    p.set_defaults(func=run_models)
