"""`mrjax reproduce` and `mrjax models`."""

from __future__ import annotations

import argparse
import importlib

from .._tables import format_table
from ..models import get, names
from ._common import DEFAULT_OUT, nonneg_int


def run_reproduce(args: argparse.Namespace) -> int:
    """Run `mrjax reproduce`; returns the exit code of `mrjax.reproduce.run`."""
    # imported when the command runs: the study loads the figure and report machinery, which
    # the other commands do not need
    reproduce = importlib.import_module("mrjax.reproduce")
    return int(reproduce.run(args.out, quick=args.quick, data=args.data, seed=args.seed) or 0)


def run_models(args: argparse.Namespace) -> int:
    """Print every model: parameters, units, default bounds, which are linear."""
    style = "markdown" if args.markdown else "plain"
    blocks = []
    for name in names():
        m = get(name)
        lo, hi = m.bounds
        lin = set(m.linear_params)
        rows = [[p, u, float(a), float(b), p in lin]
                for p, u, a, b in zip(m.param_names, m.units, lo, hi)]
        kind = "ODE (internal state)" if m.dynamic else "memoryless"
        head = f"{name}  [{kind}]  {m.description}".rstrip()
        if args.markdown:
            head = f"### {name}\n\n{m.description} ({kind})\n"
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
    p.set_defaults(func=run_models)
