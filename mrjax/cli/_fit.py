"""`mrjax fit`: identify a model on every test, write fit.json, fit.csv and figures."""

from __future__ import annotations

import argparse
import shutil

import numpy as np

from .._errors import InputError
from .._io import atomic_output, check_writable
from ..fitting import fit
from ..generalize import generalize
from ..models import get
from ..objective import fit_mask
from ._common import (
    DEFAULT_OUT,
    add_data_options,
    add_scale_options,
    data_spec,
    force_figures,
    load_batch,
    nonneg_int,
    parse_bounds,
    positive_int,
    say,
    say_estimates,
    transient,
    use_agg,
)

#: Where `mrjax fit` keeps the finished chunks of a run, inside its output directory.
JOURNAL = ".mrjax-journal"


def figures(result, batch, gm) -> dict[str, bytes]:
    """The PNG figures of a fit (and of its laws `gm`, if any), name -> bytes: measured vs
    fitted F-x and F-v loops of the periodic tests (`loops.png`), force against time of the
    others (`force_time.png`), and the per-condition summaries."""
    use_agg()
    from .. import report as rp  # imported here: matplotlib only when figures are drawn

    png = rp.save_png_bytes
    name = result.model.name
    out = force_figures(result, batch, result.predict(batch), result.rms,
                        titles=(f"{name}: measured vs fitted loops",
                                f"{name}: measured vs fitted force"))
    out.update({
        "rms_vs_current.png": png(rp.plot_rms_vs_current(result)),
        "params_vs_current.png": png(rp.plot_params_vs_current(result, laws=gm)),
    })
    if result.method in ("pso", "pso+lm"):
        out["generations_vs_current.png"] = png(rp.plot_generations_vs_current(result))
        out["convergence.png"] = png(rp.plot_convergence(result))
    if result.method == "pso+lm":
        out["pso_vs_polish.png"] = png(rp.plot_pso_vs_polish(result))
    return out


def run(args: argparse.Namespace) -> int:
    """Run `mrjax fit` with parsed arguments; returns the exit code."""
    out = check_writable(args.out)
    model = get(args.model)
    if args.generations is not None and args.max_generations is not None:
        raise InputError("give --generations (a fixed count) or --max-generations (a cap), "
                         "not both")
    bounds = parse_bounds(args.bounds, model)
    spec = data_spec(args)
    batch = load_batch(args.files, spec)
    say_estimates(batch)
    unknown = [lab for lab, i in zip(batch.labels, np.asarray(batch.current)) if np.isnan(i)]
    if args.generalize and unknown:  # fail before the fit, not after it
        raise InputError(f"--generalize needs the current of every test; it is unknown for "
                         f"{len(unknown)} of {len(batch.labels)} (first: {unknown[0]!r}): give "
                         f"--current or a spec")
    C = batch.n_conditions
    how = args.method if args.method == "lm" else f"{args.method}, {args.swarm} swarm"
    say(f"fitting {model.name} on {C} condition{'s' if C != 1 else ''} ({how})...")
    journal = out / JOURNAL
    result = fit(
        model, batch, method=args.method, swarm_mode=args.swarm, seed=args.seed,
        n_particles=args.particles,
        max_generations=args.max_generations if args.max_generations is not None else 200,
        generations=args.generations, transient=args.transient, progress=None, bounds=bounds,
        swarm_dtype=args.swarm_dtype, restarts=args.restarts, devices=args.devices,
        max_memory=args.memory, chunk_size=args.chunk_size, journal=journal,
        resume=args.resume,
    )
    gm = None
    if args.generalize:
        say(f"fitting current-dependent laws ({args.generalize})...")
        mask = fit_mask(batch, args.transient) if args.transient is not None else None
        gm = generalize(result, batch, method=args.generalize, seed=args.seed, mask=mask)
    files = {"fit.json": result.to_json(generalized=gm).encode(),
             "fit.csv": result.to_csv().encode()}
    if not args.no_plots:
        say("drawing figures...")
        files.update(figures(result, batch, gm))
    say(f"writing {len(files)} files to {out}...")
    atomic_output(out, files)
    shutil.rmtree(journal, ignore_errors=True)  # the outputs hold everything it held
    print(result.table(max_rows=args.max_rows))
    if gm is not None:
        print()
        print(gm.summary())
    return 0


def add_parser(sub, common: argparse.ArgumentParser) -> None:
    """Register `mrjax fit` and its options."""
    p = sub.add_parser(
        "fit", parents=[common], help="identify a model on every test condition",
        description="Fit one model to every test in the given files at once and write fit.json, "
        "fit.csv and figures into --out (atomically: all files or none): F-x and F-v loops of "
        "periodic tests, force against time (whole, zoomed, residual) of random records. Many "
        "tests are fitted in chunks that fit --memory; each finished chunk is kept in "
        "DIR/.mrjax-journal until the outputs are written, so that an interrupted run "
        "continues with --resume.")
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="data files or directories (.csv, .txt/.dat, .mat; any layout with "
                   "the data options below)")
    p.add_argument("--model", required=True, metavar="NAME",
                   help="model name: bingham, kwok (tanh), bouc_wen, modified_bouc_wen, dahl "
                   "(see `mrjax models`)")
    p.add_argument("--method", choices=("pso", "pso+lm", "lm"), default="pso+lm",
                   help="swarm, swarm then Levenberg-Marquardt polish (default), or polish alone")
    p.add_argument("--swarm", choices=("separable", "full"), default="separable",
                   help="separable: variable projection over the linear parameters (default); "
                   "full: the paper's swarm over all parameters")
    p.add_argument("--restarts", type=positive_int, default=1, metavar="K",
                   help="independent swarms per test, best one polished (default 1)")
    p.add_argument("--swarm-dtype", choices=("float64", "float32"), default=None,
                   help="precision of the swarm's search (default float64; float32 is about "
                   "twice as fast; the polish and the results stay float64)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")
    p.add_argument("--generations", type=positive_int, metavar="N",
                   help="run exactly N swarm generations (no statistical stop)")
    p.add_argument("--max-generations", type=positive_int, metavar="N",
                   help="cap on swarm generations with the statistical stop (default 200)")
    p.add_argument("--particles", type=positive_int, default=50, metavar="N",
                   help="swarm size (default 50)")
    p.add_argument("--transient", type=transient, metavar="SECONDS|cycle",
                   help="leave an initial span out of the fitness: seconds or 'cycle'")
    p.add_argument("--bounds", action="append", metavar="NAME=LO:HI",
                   help="search bounds of one parameter in SI units, e.g. c=500:5000 (repeatable; "
                   "an empty LO or HI keeps the default; see `mrjax models`)")
    p.add_argument("--generalize", choices=("two-step", "joint"),
                   help="also fit current-dependent laws of the parameters")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default ./{DEFAULT_OUT})")
    p.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    p.add_argument("--max-rows", type=positive_int, default=None, metavar="N",
                   help="print at most N rows of the result table (default all)")
    add_scale_options(p, journal=True)
    add_data_options(p)
    p.set_defaults(func=run)
