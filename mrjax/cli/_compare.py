"""`mrjax compare`: every model on the same tests; criteria, held-out validation, figures."""

from __future__ import annotations

import argparse

from .._errors import InputError
from .._io import atomic_output, check_writable, json_bytes
from ..comparison import compare
from ._common import (
    DEFAULT_OUT,
    add_data_options,
    add_scale_options,
    data_spec,
    load_batch,
    load_batches,
    nonneg_int,
    positive_int,
    say,
    transient,
    use_agg,
)


def parse_hold_out(text: str) -> dict[str, list[float]]:
    """`--hold-out current=0.25,0.75` as `{"current": [0.25, 0.75]}` (InputError otherwise)."""
    key, eq, values = text.partition("=")
    if not eq or key.strip().lower() != "current":
        raise InputError(f"--hold-out {text!r}: expected current=A[,A...], e.g. "
                         "current=0.25,0.75")
    items = [v.strip() for v in values.split(",") if v.strip()]
    if not items:
        raise InputError("--hold-out: the hold-out set is empty; give at least one current, "
                         "e.g. current=0.25")
    try:
        return {"current": [float(v) for v in items]}
    except ValueError:
        raise InputError(f"--hold-out {text!r}: currents must be numbers in A") from None


def parse_folds(text: str) -> int | str:
    """`--folds K|current`."""
    if text.strip().lower() == "current":
        return "current"
    try:
        return int(text)
    except ValueError:
        raise InputError(f"--folds {text!r}: expected an integer K >= 2 or 'current'") from None


def figures(result) -> dict[str, bytes]:
    """The PNG figures of a comparison, name -> bytes."""
    use_agg()
    from ..report import save_png_bytes  # imported here: matplotlib only when drawing

    return {name: save_png_bytes(fig) for name, fig in result.figures().items()}


def run(args: argparse.Namespace) -> int:
    """Run `mrjax compare` with parsed arguments; returns the exit code."""
    out = check_writable(args.out)
    hold_out = parse_hold_out(args.hold_out) if args.hold_out is not None else None
    folds = parse_folds(args.folds) if args.folds is not None else None
    fit_options = dict(method=args.method, restarts=args.restarts, n_particles=args.particles,
                       max_generations=args.max_generations, polish_steps=args.polish_steps,
                       transient=args.transient, swarm_dtype=args.swarm_dtype, progress=None,
                       max_memory=args.memory, devices=args.devices,
                       retry=not args.no_retry)
    spec = data_spec(args)
    if args.validate:
        batch, validate = load_batches([args.files, args.validate], spec)
    else:  # without data options, today's one-argument call (tests replace it)
        batch = load_batch(args.files) if spec is None else load_batch(args.files, spec)
        validate = None
    result = compare(batch, models=args.models, validate=validate, hold_out=hold_out,
                     folds=folds, generalize_methods=args.generalize, seed=args.seed, log=say,
                     **fit_options)
    files = {"compare.json": json_bytes(result.to_dict()),
             "compare.csv": result.to_csv().encode()}
    if not args.no_plots:
        say("drawing figures...")
        files.update(figures(result))
    say(f"writing {len(files)} files to {out}...")
    atomic_output(out, files)
    print(result.table())
    return 0


def add_parser(sub, common: argparse.ArgumentParser) -> None:
    """Register `mrjax compare` and its options."""
    p = sub.add_parser(
        "compare", parents=[common], help="compare models on the same tests (criteria, "
        "held-out validation)",
        description="Fit every model to the same tests, rank them by information criteria "
        "(AIC, AICc, BIC) and score their current-dependent laws on held-out tests; write "
        "compare.json, compare.csv and figures into --out (atomically: all files or none). "
        "Default validation: leave one current out when the currents are known.")
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="data files or directories (as `mrjax fit`)")
    p.add_argument("--models", default="all", metavar="all|NAME,...",
                   help="models to compare, e.g. kwok,bouc_wen (default all)")
    held = p.add_mutually_exclusive_group()
    held.add_argument("--validate", nargs="+", metavar="FILE",
                      help="score the laws built on all FILES on these other tests, read with "
                      "the same data options (put it after FILES)")
    held.add_argument("--hold-out", metavar="current=A,...",
                      help="hold out the tests at these currents, e.g. current=0.25,0.75")
    held.add_argument("--folds", metavar="K|current",
                      help="K folds over the tests, or 'current' (leave one current out)")
    p.add_argument("--generalize", default="two-step,joint", metavar="METHODS",
                   help="generalization methods scored on held-out tests: two-step, joint, "
                   "two-step,joint (default) or none")
    p.add_argument("--method", choices=("pso", "pso+lm", "lm"), default="pso+lm",
                   help="per-test fit: swarm, swarm then polish (default), or polish alone")
    p.add_argument("--restarts", type=positive_int, default=None, metavar="K",
                   help="independent swarms per test, best one polished (default 1; 2 for "
                   "an ODE model on a single test)")
    p.add_argument("--no-retry", action="store_true",
                   help="do not polish each test again from its neighbours' optima (the "
                   "default retry finds the optima one swarm misses and warns where the two "
                   "results disagree)")
    p.add_argument("--max-generations", type=positive_int, default=200, metavar="N",
                   help="cap on swarm generations with the statistical stop (default 200)")
    p.add_argument("--particles", type=positive_int, default=50, metavar="N",
                   help="swarm size (default 50)")
    p.add_argument("--polish-steps", type=positive_int, default=200, metavar="N",
                   help="maximum Levenberg-Marquardt steps per test (default 200)")
    p.add_argument("--transient", type=transient, metavar="SECONDS|cycle",
                   help="leave an initial span out of the fitness and the scores")
    p.add_argument("--swarm-dtype", choices=("float64", "float32"), default=None,
                   help="precision of the swarm's search (default float64)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default ./{DEFAULT_OUT})")
    p.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    add_scale_options(p, journal=False)
    add_data_options(p)
    p.set_defaults(func=run)
