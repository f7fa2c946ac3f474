"""`mrjax fit`: identify a model on every test, write fit.json, fit.csv and figures."""

from __future__ import annotations

import argparse
import dataclasses
import shutil

import numpy as np

from .. import __version__
from .._errors import InputError
from .._io import OutputDir, json_bytes
from .._warnings import WarningKind
from ..data import COMMAND_UNITS as COMMAND_UNITS_BY_KIND
from ..data import Source
from ..engine import Chunks, Polish, Swarm
from ..fitting import RUNTIME_BYTES, fit
from ..generalize import GeneralizedModel, generalize, identify
from ..models import get, source_of
from ._common import (
    HOLD_SHARE,
    data_spec,
    force_figures,
    load_tests,
    parse_bounds,
    parse_fixed,
    say_estimates,
    use_agg,
)
from ._parse import say
from ._posterior import posterior_settings, run_posterior

#: Where `mrjax fit` keeps the finished chunks of a run, inside its output directory.
JOURNAL = ".mrjax-journal"


def figures(result, batch, gm, rows=None) -> dict[str, bytes]:
    """The PNG figures of a fit (and of its laws `gm`, if any), name -> bytes: measured vs
    fitted F-x and F-v loops of the periodic tests (`loops.png`), force against time of the
    others (`force_time.png`), and the per-condition summaries. `rows`: the tests of the fit
    that `batch` holds (default all: a streamed fit draws the loops of a sample)."""
    use_agg()
    from .. import report as rp  # imported here: matplotlib only when figures are drawn

    png = rp.save_png_bytes
    name = result.model.name
    shown = result if rows is None else result.subset(rows)
    out = force_figures(shown, batch, shown.predict(batch), shown.rms,
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


def fit_settings(args: argparse.Namespace) -> tuple[Swarm | None, Polish | None]:
    """The swarm's and the polish's settings objects of `mrjax fit`'s (or `mrjax compare`'s)
    options: `--method` says which stages run, `--swarm`, `--particles`, `--max-generations`,
    `--generations`, `--restarts`, `--swarm-dtype` set the swarm's fields, `--no-retry` the
    polish's."""
    swarm = None
    if args.method != "lm":
        swarm = Swarm(mode=args.swarm, n_particles=args.particles, restarts=args.restarts,
                      max_generations=args.max_generations if args.max_generations is not None
                      else 200, generations=getattr(args, "generations", None),
                      dtype=args.swarm_dtype)
    polish = None
    if args.method != "pso":
        polish = Polish(retry=not getattr(args, "no_retry", False))
    return swarm, polish


def run(args: argparse.Namespace, out: OutputDir) -> int:
    """Run `mrjax fit` with parsed arguments into the claimed directory `out`; returns the exit
    code."""
    if args.structure:  # a structure's response (`mrjax.structure`)
        from ._structure import run_fit

        return run_fit(args, out)
    model = get(args.model, fixed=parse_fixed(args.fixed))
    if args.generations is not None and args.max_generations is not None:
        raise InputError("give --generations (a fixed count) or --max-generations (a cap), "
                         "not both")
    if args.laws is not None and not args.generalize:
        raise InputError("--laws sets the form of the laws of --generalize: give both")
    bounds = parse_bounds(args.bounds, model)
    post = posterior_settings(args, model.param_names)  # checked before any work
    spec = data_spec(args)
    data = load_tests(args.files, spec, args.memory,
                      stream=args.cluster is not None and not args.generalize and post is None)
    streamed = isinstance(data, Source)
    survey = _survey(data, args.memory)
    say_estimates(survey.estimated)
    varying = survey.varying
    if streamed and args.generalize:
        need = RUNTIME_BYTES + data.batch_bytes() / HOLD_SHARE
        raise InputError(f"--generalize needs every test in memory, and the {survey.n} tests "
                         f"take more than --memory holds with the fit: give --memory "
                         f"{need / 1e9:.2g}GB or more")
    if streamed and post is not None:
        need = RUNTIME_BYTES + data.batch_bytes() / HOLD_SHARE
        raise InputError(f"--posterior needs every test in memory, and the {survey.n} tests "
                         f"take more than --memory holds with the fit: give --memory "
                         f"{need / 1e9:.2g}GB or more")
    if args.generalize == "joint" and (varying or survey.voltage):
        if post is not None:
            raise InputError("--posterior is available for per-test fits and laws over the "
                             "current; the posterior of laws of a time-varying command is not")
        return _run_identify(args, model, bounds, data, out)
    if varying and args.generalize:
        raise InputError(f"--generalize {args.generalize} needs --generalize joint: "
                         f"{len(varying)} record(s) carry a command that varies in time "
                         f"(first: {varying[0]!r}); joint identifies laws of the command")
    if varying:
        say(f"warning: the command varies in time in {len(varying)} record(s) (first: "
            f"{varying[0]!r}): a per-test fit averages over it; --generalize joint identifies "
            "laws of the command")
    unknown = survey.unknown
    if args.generalize and unknown:  # fail before the fit, not after it
        raise InputError(f"--generalize needs the current of every test; it is unknown for "
                         f"{len(unknown)} of {survey.n} (first: {unknown[0]!r}): give "
                         f"--current or a spec")
    C = survey.n
    how = args.method if args.method == "lm" else f"{args.method}, {args.swarm} swarm"
    say(f"fitting {model.name} on {C} condition{'s' if C != 1 else ''} ({how})...")
    journal = out.path / JOURNAL
    swarm, polish = fit_settings(args)
    chunks = Chunks(max_memory=args.memory, size=args.chunk_size, journal=journal,
                    resume=args.resume, devices=args.devices, cluster=args.cluster)
    result = fit(model, data, swarm=swarm, polish=polish, key=args.seed, bounds=bounds,
                 transient=args.transient, chunks=chunks, progress=None)
    batch, rows = data, None
    if streamed:  # the loops of an even sample of the tests
        rows = np.unique(np.linspace(0, C - 1, min(C, SAMPLE_TESTS)).round().astype(int))
        batch = data.batch(rows, warn=False) if not args.no_plots else None
    gm = None
    if args.generalize:
        say(f"fitting current-dependent laws ({args.generalize})...")
        gm = generalize(result, batch, method=args.generalize, key=args.seed,
                        degrees=args.degrees, laws=args.laws)
    tp, post_files = None, {}
    if post is not None:
        tp, post_files = run_posterior(post, gm if gm is not None else result, batch,
                                       key=args.seed, plots=not args.no_plots)
    files = {"fit.json": result.to_json(generalized=gm, posterior=tp).encode(),
             "fit.csv": result.to_csv().encode(), **post_files}
    if not args.no_plots:
        say("drawing figures...")
        files.update(figures(result, batch, gm, rows))
    say(f"writing {len(files)} files to {out.path}...")
    out.write(files)
    shutil.rmtree(journal, ignore_errors=True)  # the outputs hold everything it held
    print(result.table(max_rows=args.max_rows))  # ends with the per-test warnings
    if gm is not None:
        print()
        print(gm.summary())
        for w in result.warnings(gm):
            if w.kind == WarningKind.TOO_FEW_CURRENTS:
                print(f"warning: {w.message}")
    if tp is not None:
        print()
        print(tp.table(max_rows=args.max_rows))
    return 0


#: Tests whose loops a streamed fit draws (evenly spread).
SAMPLE_TESTS = 36
#: Bytes of tests read at a time to survey a streamed fit's tests before it starts.
SURVEY_BYTES = 256_000_000


@dataclasses.dataclass(frozen=True)
class Survey:
    """What `mrjax fit` asks of every test before the fit: their number `n`, which of velocity,
    frequency and amplitude are estimates (`estimated`, (n, 3)), the labels of the tests whose
    command varies in time (`varying`) or whose current is unknown (`unknown`), and whether a
    command is a voltage (`voltage`)."""

    n: int
    estimated: np.ndarray
    varying: list[str]
    unknown: list[str]
    voltage: bool


def _survey(data, memory: int | None) -> Survey:
    """The :class:`Survey` of a batch, or of a source read a group of tests at a time (within
    a quarter of `memory`)."""
    if isinstance(data, Source):
        cap = SURVEY_BYTES if memory is None else min(SURVEY_BYTES, memory // 4)
        per = max(1, cap // (3 * max(1, data.batch_bytes(1))))
        C = data.n_conditions
        groups = (data.batch(np.arange(a, min(C, a + per))) for a in range(0, C, per))
    else:
        groups = iter([data])
    est, varying, unknown, voltage = [], [], [], False
    for b in groups:
        est.append(np.asarray(b.estimated, bool))
        varying += _varying_command(b)
        voltage = voltage or _voltage_command(b)
        unknown += [lab for lab, i in zip(b.labels, np.asarray(b.current)) if np.isnan(i)]
    estimated = np.concatenate(est)
    return Survey(len(estimated), estimated, varying, unknown, voltage)


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


def _run_identify(args, model, bounds, batch, out: OutputDir) -> int:
    """`mrjax fit` on records with a command voltage or a time-varying current: the laws of the
    command identified from every record at once (`mrjax.generalize.identify`)."""
    C = batch.n_conditions
    if args.method != "pso+lm" or args.swarm != "separable":
        raise InputError("records with a time-varying command are fitted by the joint swarm "
                         "and polish: leave --method and --swarm at their defaults")
    say(f"identifying {model.name} as laws of the command from {C} record"
        f"{'s' if C != 1 else ''} (lag: {args.lag})...")
    swarm = Swarm(n_particles=args.particles, restarts=args.restarts,
                  max_generations=args.generations or args.max_generations or 200)
    gm = identify(batch, model, lag=args.lag, degrees=args.degrees, laws=args.laws, bounds=bounds,
                  transient=args.transient, swarm=swarm, key=args.seed)
    ev = gm.evaluate(batch)
    conds = [{"label": lab, "rms_N": float(r), "nrmse": float(n)}
             for lab, r, n in zip(batch.labels, ev["rms"], ev["nrmse"])]
    doc = {"model": model.name, "model_source": source_of(model),
           "mrjax_version": __version__, "method": "identify",
           "command_unit": gm.command_unit, "lag_1_s": gm.lag,
           "timings_s": gm.report.timings, "conditions": conds,
           "generalized": gm.to_dict()}
    files = {"fit.json": json_bytes(doc), "fit.csv": laws_csv(gm).encode()}
    if not args.no_plots:
        say("drawing figures...")
        use_agg()
        from .. import report as rp  # imported here: matplotlib only when figures are drawn

        files.update(rp.command_figures(gm, batch, np.asarray(ev["predicted"], float)))
    say(f"writing {len(files)} files to {out.path}...")
    out.write(files)
    for c in conds:
        print(f"{c['label']}: RMS {c['rms_N']:.2f} N, NRMSE {100 * c['nrmse']:.2f} %")
    print()
    print(gm.summary())
    return 0
