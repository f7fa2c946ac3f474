"""`mrjax compare`: every model on the same tests; criteria, held-out validation, figures."""

from __future__ import annotations

import argparse

from .._errors import InputError
from .._io import OutputDir, json_bytes
from ..comparison import HeldOut, compare
from ..engine import Chunks, Polish, Swarm
from ._common import data_spec, load_batch, load_batches, use_agg
from ._parse import say


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


def run(args: argparse.Namespace, out: OutputDir) -> int:
    """Run `mrjax compare` with parsed arguments into the claimed directory `out`; returns the
    exit code."""
    hold_out = parse_hold_out(args.hold_out) if args.hold_out is not None else None
    folds = parse_folds(args.folds) if args.folds is not None else None
    swarm = None if args.method == "lm" else Swarm(
        n_particles=args.particles, max_generations=args.max_generations,
        restarts=args.restarts, dtype=args.swarm_dtype)
    polish = None if args.method == "pso" else Polish(max_steps=args.polish_steps,
                                                      retry=not args.no_retry)
    chunks = Chunks(max_memory=args.memory, devices=args.devices, cluster=args.cluster)
    spec = data_spec(args)
    if args.validate:
        batch, validate = load_batches([args.files, args.validate], spec)
    else:  # without data options, today's one-argument call (tests replace it)
        batch = load_batch(args.files) if spec is None else load_batch(args.files, spec)
        validate = None
    held = HeldOut(data=validate, hold_out=hold_out, folds=folds, methods=args.generalize)
    result = compare(batch, models=args.models, held_out=held, swarm=swarm, polish=polish,
                     transient=args.transient, chunks=chunks, key=args.seed, log=say)
    files = {"compare.json": json_bytes(result.to_dict()),
             "compare.csv": result.to_csv().encode()}
    if not args.no_plots:
        say("drawing figures...")
        files.update(figures(result))
    say(f"writing {len(files)} files to {out.path}...")
    out.write(files)
    print(result.table())
    return 0
