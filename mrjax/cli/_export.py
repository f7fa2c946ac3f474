"""`mrjax export`: the identified model and its inverse as C99 source or an FMI 2.0 FMU.

The parser part (`add_parser`) imports nothing heavy; `run` imports the export package (and
JAX) when the command runs.
"""

from __future__ import annotations

import argparse

from .._errors import InputError
from .._io import OutputDir
from ._parse import add_data_options, add_output_options, positive_int, say


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not v > 0 or v != v or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text!r}")
    return v


def add_parser(sub, common) -> None:
    """The `export` sub-command's parser."""
    p = sub.add_parser(
        "export", parents=[common], help="export the fitted model and its inverse as C99 or an "
        "FMI 2.0 FMU",
        description="Translate the model of a fit.json (its laws over the current or command "
        "of `mrjax fit --generalize`, or the one parameter set of a fit of one test) and its "
        "inverse into C99 (PREFIX_model.h, PREFIX_model.c: double precision, no allocation, "
        "only math.h) or an FMI 2.0 co-simulation FMU compiled for this platform, from the "
        "model's own JAX functions; written into --out atomically. The integration (scheme "
        "and sub-steps) is mrjax's, chosen on --data (as `mrjax predict` chooses it on the "
        "same records, so the export equals predict there), else on the fit's test motions "
        "sampled at --dt.")
    p.add_argument("--fit", required=True, metavar="FIT.json",
                   help="fit.json of `mrjax fit` (or its directory)")
    p.add_argument("--to", required=True, choices=("c", "fmu"),
                   help="c: C99 header and source; fmu: an FMI 2.0 co-simulation FMU")
    p.add_argument("--data", nargs="+", metavar="FILE",
                   help="records like those the controller will see: the sub-steps are chosen "
                   "on them as `mrjax predict` chooses them (read with the data options below)")
    p.add_argument("--dt", type=_positive_float, default=None, metavar="SECONDS",
                   help="the controller's sample interval the sub-steps are chosen for, without "
                   "--data (default 0.001); also the FMU's default step (default: --data's "
                   "sample interval, else 0.001)")
    p.add_argument("--substeps", type=positive_int, metavar="N",
                   help="integrate with N sub-steps per sample instead (with --scheme)")
    p.add_argument("--scheme", choices=("rk4", "sdirk"), default=None,
                   help="the scheme of --substeps (default rk4)")
    p.add_argument("--prefix", default="mrjax", metavar="NAME",
                   help="prefix of the C names and files (default mrjax: mrjax_step, ...); "
                   "for an FMU, its model identifier (default mrjax_MODEL)")
    p.add_argument("--model", metavar="FILE.py:NAME",
                   help="where the fitted model is, when it is not a model of this installation "
                   "and fit.json's record of its file or module no longer finds it")
    add_output_options(p, "export", no_plots=None)
    add_data_options(p)
    p.set_defaults(run=("_export", "run"))


def run(args: argparse.Namespace, out: OutputDir) -> int:
    """Run `mrjax export` with parsed arguments into the claimed directory `out`; returns the
    exit code."""
    import numpy as np

    from ..export import C99, DEFAULT_DT, FMU, ControllerModel  # imported here: JAX
    from ._common import data_spec, load_batch

    if args.scheme is not None and args.substeps is None:
        raise InputError("--scheme needs --substeps")
    records = load_batch(args.data, data_spec(args)) if args.data else None
    dt = args.dt if args.dt is not None else DEFAULT_DT
    cm = ControllerModel.from_fit(args.fit, model=args.model, records=records, dt=dt,
                                  substeps=args.substeps, scheme=args.scheme)
    if args.to == "c":
        target = C99(prefix=args.prefix)
    else:  # its default step: --dt, else the records' sample interval
        step = dt if records is None or args.dt is not None else float(
            np.median(np.asarray(records.dt)[np.asarray(records.mask)]))
        target = FMU(identifier=None if args.prefix == "mrjax" else args.prefix, step=step)
    say(f"translating {cm.model.name} into {'C99' if args.to == 'c' else 'an FMU'}...")
    files = target.files(cm)
    say(f"writing {', '.join(sorted(files))} to {out.path}...")
    out.write(files)
    print("\n".join(cm.summary()))
    return 0

