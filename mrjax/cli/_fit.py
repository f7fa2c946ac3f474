"""`mrjax fit`: identify a model on every test, write fit.json, fit.csv and figures."""

from __future__ import annotations

import argparse
import shutil

import numpy as np

from .. import __version__
from .._errors import InputError
from .._io import atomic_output, check_writable, json_bytes
from ..data import COMMAND_UNITS as COMMAND_UNITS_BY_KIND
from ..fitting import fit
from ..generalize import GeneralizedModel, generalize, identify
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
from ._posterior import add_posterior_options, posterior_settings, run_posterior

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
    post = posterior_settings(args, model.param_names)  # checked before any work
    spec = data_spec(args)
    batch = load_batch(args.files, spec)
    say_estimates(batch)
    varying = _varying_command(batch)
    if args.generalize == "joint" and (varying or _voltage_command(batch)):
        if post is not None:
            raise InputError("--posterior is available for per-test fits; the posterior of "
                             "laws of a time-varying command is not")
        return _run_identify(args, model, bounds, batch, out)
    if varying and args.generalize:
        raise InputError(f"--generalize {args.generalize} needs --generalize joint: "
                         f"{len(varying)} record(s) carry a command that varies in time "
                         f"(first: {varying[0]!r}); joint identifies laws of the command")
    if varying:
        say(f"warning: the command varies in time in {len(varying)} record(s) (first: "
            f"{varying[0]!r}): a per-test fit averages over it; --generalize joint identifies "
            "laws of the command")
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
        gm = generalize(result, batch, method=args.generalize, seed=args.seed, mask=mask,
                        degrees=args.degrees)
    tp, post_files = None, {}
    if post is not None:
        tp, post_files = run_posterior(post, result, batch, bounds=bounds,
                                       transient=args.transient, seed=args.seed,
                                       plots=not args.no_plots)
    files = {"fit.json": result.to_json(generalized=gm, posterior=tp).encode(),
             "fit.csv": result.to_csv().encode(), **post_files}
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
    if tp is not None:
        print()
        print(tp.table(max_rows=args.max_rows))
    return 0


def _command_rows(batch) -> list[tuple[str, int, np.ndarray]]:
    """(label, command kind, command over the fitted samples) of the records with a command."""
    kind = np.asarray(batch.command_kind)
    cmd = np.asarray(batch.command, float)
    mask = np.asarray(batch.mask, bool)
    return [(lab, int(k), c[m]) for lab, k, c, m in zip(batch.labels, kind, cmd, mask)
            if k > 0 and m.any()]


def _varying_command(batch) -> list[str]:
    """Labels of the records whose command (voltage or current) varies in time: a per-test
    fit averages over it; `--generalize joint` identifies laws of the command
    (`mrjax.generalize.identify`)."""
    return [lab for lab, _, c in _command_rows(batch) if np.ptp(c) > 0]


def _voltage_command(batch) -> bool:
    """Whether a record carries a command voltage (laws in volts need `identify`)."""
    return any(COMMAND_UNITS_BY_KIND[k] == "V" for _, k, _ in _command_rows(batch))


def parse_lag(text: str) -> str | float | None:
    """`--lag`: `fit`, `none` or a rate eta [1/s] of the command filter du/dt = -eta (u - v)."""
    t = text.strip().lower()
    if t in ("fit", "none"):
        return None if t == "none" else "fit"
    try:
        v = float(t)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected 'fit', 'none' or a rate in 1/s, got {text!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"the lag rate must be positive (1/s), got {text!r}")
    return v


def parse_degrees(text: str) -> dict[str, int]:
    """`--degrees`: `NAME=DEG,...`, the polynomial degree of each named parameter's law."""
    out: dict[str, int] = {}
    for item in text.split(","):
        name, sep, deg = item.partition("=")
        try:
            d = int(deg)
        except ValueError:
            d = -1
        if not sep or not name.strip() or d < 0:
            raise argparse.ArgumentTypeError(
                f"expected NAME=DEG,... with DEG a non-negative integer, got {item!r}")
        out[name.strip()] = d
    return out


def laws_csv(gm: GeneralizedModel) -> str:
    """The laws as CSV: one row per coefficient (parameter, power of the command, value,
    std-error, unit of the parameter, command unit), then the lag rate."""
    unc = gm.uncertainty
    rows = ["parameter,power,coefficient,stderr,unit,command_unit"]
    for n, u in zip(gm.param_names, gm.model.units):
        se = unc.stderr.get(n) if unc is not None else None
        for k, c in enumerate(gm.coefficients(n)):
            e = "" if se is None or not np.isfinite(se[k]) else f"{se[k]:.10g}"
            rows.append(f"{n},{k},{c:.10g},{e},{u},{gm.command_unit}")
    if gm.lag is not None:
        e = unc.lag_stderr if unc is not None and unc.lag_stderr is not None else None
        rows.append(f"eta,0,{gm.lag:.10g},{'' if e is None else f'{e:.10g}'},1/s,"
                    f"{gm.command_unit}")
    return "\n".join(rows) + "\n"


def _run_identify(args, model, bounds, batch, out) -> int:
    """`mrjax fit` on records with a command voltage or a time-varying current: the laws of the
    command identified from every record at once (`mrjax.generalize.identify`)."""
    C = batch.n_conditions
    if args.method != "pso+lm" or args.swarm != "separable":
        raise InputError("records with a time-varying command are fitted by the joint swarm "
                         "and polish: leave --method and --swarm at their defaults")
    say(f"identifying {model.name} as laws of the command from {C} record"
        f"{'s' if C != 1 else ''} (lag: {args.lag})...")
    gm = identify(batch, model, lag=args.lag, degrees=args.degrees, bounds=bounds, transient=args.transient,
                  seed=args.seed, n_particles=args.particles,
                  max_generations=args.generations or args.max_generations or 200,
                  restarts=args.restarts)
    ev = gm.evaluate(batch)
    conds = [{"label": lab, "rms_N": float(r), "nrmse": float(n)}
             for lab, r, n in zip(batch.labels, ev["rms"], ev["nrmse"])]
    doc = {"model": model.name, "mrjax_version": __version__, "method": "identify",
           "command_unit": gm.command_unit, "lag_1_s": gm.lag,
           "timings_s": gm.info.get("timings"), "conditions": conds,
           "generalized": gm.to_dict()}
    files = {"fit.json": json_bytes(doc), "fit.csv": laws_csv(gm).encode()}
    if not args.no_plots:
        say("drawing figures...")
        use_agg()
        from .. import report as rp  # imported here: matplotlib only when figures are drawn

        files.update(rp.command_figures(gm, batch, np.asarray(ev["predicted"], float)))
    say(f"writing {len(files)} files to {out}...")
    atomic_output(out, files)
    for c in conds:
        print(f"{c['label']}: RMS {c['rms_N']:.2f} N, NRMSE {100 * c['nrmse']:.2f} %")
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
                   help="also fit current-dependent laws of the parameters; records with a "
                   "command voltage or a time-varying current need 'joint' (the laws are then "
                   "identified from every record at once)")
    p.add_argument("--degrees", type=parse_degrees, metavar="NAME=DEG,...",
                   help="polynomial degree of the named parameters' laws of the current or "
                   "command (0: constant; default per model, e.g. Spencer's c0, c1, alpha "
                   "linear in a command voltage)")
    p.add_argument("--lag", type=parse_lag, default="fit", metavar="fit|none|RATE",
                   help="command filter du/dt = -eta (u - v) of time-varying commands: 'fit' "
                   "(default), 'none', or eta in 1/s to fix it (Spencer 1997: 190)")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default ./{DEFAULT_OUT})")
    p.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    p.add_argument("--max-rows", type=positive_int, default=None, metavar="N",
                   help="print at most N rows of the result table (default all)")
    add_posterior_options(p)
    add_scale_options(p, journal=True)
    add_data_options(p)
    p.set_defaults(func=run)
