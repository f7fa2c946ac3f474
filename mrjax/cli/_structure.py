"""`mrjax fit --structure` (a hysteretic element identified inside a structure from its
response) and `mrjax predict` of such a fit (`mrjax.structure`)."""

from __future__ import annotations

import argparse
import dataclasses
import re

import numpy as np

from .. import __version__
from .._errors import InputError
from .._io import OutputDir, csv_cell, json_bytes, json_safe
from ._common import parse_bounds, parse_fixed, read_fit_json, use_agg
from ._parse import say
from ._posterior import posterior_settings

#: `mrjax fit` options that a structure's fit does not take (their flags, for the message).
NOT_FOR_STRUCTURE = {"generalize": "--generalize", "transient": "--transient",
                     "laws": "--laws", "degrees": "--degrees", "cluster": "--cluster",
                     "devices": "--devices", "chunk_size": "--chunk-size",
                     "resume": "--resume", "spec": "--spec"}


def period_samples(text: str | None, dt: float) -> int | None:
    """`--periodic N` (samples) or a duration (`10.92s`, `500ms`) at the sample interval `dt`
    [s], as samples; None without it."""
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*", text)
    if m:
        return int(m[1])
    from ..data import quantity_value

    seconds = quantity_value(text, "time", what="--periodic")
    n = int(round(seconds / dt))
    if n < 2 or abs(n * dt - seconds) > 1e-3 * seconds:
        raise InputError(f"--periodic {text}: {seconds:g} s is not a whole number of samples "
                         f"at {1 / dt:g} Hz")
    return n


def _structure(args: argparse.Namespace, kind: str, response: str):
    """The structure object of the command line (its period set once the records' rate is
    known)."""
    from ..structure import STRUCTURES, interpolation

    return STRUCTURES[kind](response=response,
                            interpolation=interpolation(args.interpolation or "fft"))


def _records(args, structure):
    """The records of the files with the structure's response (the displacement where the
    files have it, else the acceleration) and period."""
    from ..structure import load_records

    recs = load_records(args.files, structure)
    if structure.response == "displacement" and all(r.response is None for r in recs):
        alt = dataclasses.replace(structure, response="acceleration")
        alt_recs = load_records(args.files, alt)
        if any(r.response is not None for r in alt_recs):
            recs, structure = alt_recs, alt
    return recs, dataclasses.replace(structure, period=period_samples(args.periodic,
                                                                      recs[0].dt))


def _bounds(items, model):
    """`--bounds` with the mass (`m=LO:HI` [kg]) and the model's parameters."""
    items = list(items or [])
    mass = [i for i in items if i.partition("=")[0].strip() == "m"]
    rest = [i for i in items if i not in mass]
    parsed = parse_bounds(rest, model) or ({}, {})
    for item in mass:
        lo, colon, hi = item.partition("=")[2].partition(":")
        if not colon:
            raise InputError(f"--bounds {item!r}: expected m=LO:HI [kg], e.g. m=1:10")
        try:
            if lo.strip():
                parsed[0]["m"] = float(lo)
            if hi.strip():
                parsed[1]["m"] = float(hi)
        except ValueError:
            raise InputError(f"--bounds {item!r}: LO and HI must be numbers [kg]") from None
    return parsed if items else None


def _settings(args):
    from ..engine import Polish, Swarm

    if args.generations is not None and args.max_generations is not None:
        raise InputError("give --generations (a fixed count) or --max-generations (a cap), "
                         "not both")
    swarm = None if args.method == "lm" else Swarm(
        n_particles=args.particles, restarts=args.restarts, generations=args.generations,
        max_generations=args.max_generations or 200, dtype=args.swarm_dtype)
    return swarm, (None if args.method == "pso" else Polish())


def _figure(pred, fit, title: str) -> bytes:
    use_agg()
    from ..report import save_png_bytes
    from ..structure._figures import response_figure

    return save_png_bytes(response_figure(pred, title=title,
                                          unit=fit.structure.response_unit))


def run_fit(args: argparse.Namespace, out: OutputDir) -> int:
    """`mrjax fit FILE... --structure sdof|base --model M`: the structure's fit, fit.json,
    fit.csv, the figure of measured against simulated response (and the posterior)."""
    from ..engine import posterior
    from ..models import get
    from ..structure import fit, stack, structure_problem

    given = [flag for k, flag in NOT_FOR_STRUCTURE.items() if getattr(args, k, None)]
    if given:
        raise InputError(f"{given[0]} is not available with --structure")
    model = get(args.model, fixed=parse_fixed(getattr(args, "fixed", None)))
    structure = _structure(args, args.structure, "displacement")
    records, structure = _records(args, structure)
    bounds = _bounds(args.bounds, model)
    post = posterior_settings(args, ("m",) + tuple(model.param_names))
    swarm, polish = _settings(args)
    records = stack(records)
    structure_problem(model, structure, records, bounds)  # the records' checks, before any work
    n = len(records.labels)
    say(f"identifying {model.name} in a {structure.name} structure from {n} "
        f"record{'s' if n != 1 else ''} ({structure.response}, "
        f"{structure.interpolation.name} input"
        f"{f', period {structure.period}' if structure.period else ', from rest'})...")
    res = fit(model, records, structure=structure, swarm=swarm, polish=polish, bounds=bounds,
              key=args.seed, progress=None)
    files, tp = {}, None
    if post is not None:
        say(f"sampling the posterior ({post.sampler.chains} chains x {post.sampler.draws} "
            f"draws)...")
        tp = posterior(res, records, sampler=post.sampler, noise=post.noise,
                       prior=post.prior, likelihood_data=post.likelihood_data, key=args.seed)
        files["posterior.csv"] = tp.to_csv().encode()
    files["fit.json"] = res.to_json(posterior=tp).encode()
    files["fit.csv"] = _fit_csv(res).encode()
    if not args.no_plots:
        files["response.png"] = _figure(res.predict(records), res,
                                        f"{model.name} in a {structure.name} structure")
    say(f"writing {len(files)} files to {out.path}...")
    out.write(files)
    print(res.table())
    if tp is not None:
        print()
        print(tp.table())
    return 0


def _fit_csv(res) -> str:
    lines = ["record,parameter,value,stderr,ci95_low,ci95_high,unit"]
    for i, lab in enumerate(res.labels):
        for j, (n, u) in enumerate(zip(res.names, res.units)):
            se = "" if res.stderr is None else csv_cell(res.stderr[i, j])
            lo, hi = ("", "") if res.ci95 is None else (csv_cell(res.ci95[i, j, 0]),
                                                        csv_cell(res.ci95[i, j, 1]))
            lines.append(",".join((csv_cell(lab), n, csv_cell(res.z[i, j]), se, lo, hi, u)))
    return "\n".join(lines) + "\n"


def _samples_csv(pred) -> bytes:
    """`predicted.csv`: every sample of every record (`condition`, `time_s`, `measured`,
    `predicted`), floats that round-trip exactly."""
    lines = ["condition,time_s,measured,predicted"]
    for i, lab in enumerate(pred.labels):
        n = int(pred.n[i])
        meas = pred.measured[i, :n] if pred.mask[i].any() else np.full(n, np.nan)
        cells = zip(pred.t[i, :n].tolist(), meas.tolist(), pred.predicted[i, :n].tolist())
        lines += [",".join((csv_cell(lab), *(csv_cell(v) for v in row))) for row in cells]
    return ("\n".join(lines) + "\n").encode()


def run_predict(args: argparse.Namespace, out: OutputDir, doc: dict) -> int:
    """`mrjax predict --fit DIR FILE...` of a structure's fit: each record's input simulated;
    predict.json (RMS error of the response, NRMSE), predicted.csv and the figure."""
    from ..structure import StructureFit

    try:
        res = StructureFit.from_dict(doc, model=args.model)
    except InputError as e:
        raise InputError(f"{args.fit}: {e}") from None
    from ..structure import interpolation

    structure = res.structure if not args.interpolation else dataclasses.replace(
        res.structure, interpolation=interpolation(args.interpolation))
    records, structure = _records(args, structure)
    say(f"predicting {len(records)} record{'s' if len(records) != 1 else ''} with the "
        f"fitted {res.model.name} structure...")
    pred = res.predict(records, structure=structure)
    unit = structure.response_unit
    rows = [{"label": lab, "n_samples": int(n), f"rms_{unit.replace('/', '_')}": r,
             "nrmse": e, "fitted_record": f}
            for lab, n, r, e, f in zip(pred.labels, pred.n, pred.rms, pred.nrmse, pred.fitted)]
    report = {"fit": str(args.fit), "kind": "structure", "model": res.model.name,
              "mrjax_version": __version__, "response": structure.response, "unit": unit,
              "interpolation": structure.interpolation.name, "period": structure.period,
              "integration": {"scheme": "rk4", "substeps": pred.substeps},
              "records": json_safe(rows)}
    files = {"predict.json": json_bytes(report), "predicted.csv": _samples_csv(pred)}
    if not args.no_plots:
        files["predict_response.png"] = _figure(pred, res, f"predicted {res.model.name}")
    say(f"writing {len(files)} files to {out.path}...")
    out.write(files)
    for r in rows:
        rms = r[f"rms_{unit.replace('/', '_')}"]
        print(f"{r['label']}: RMS {rms:.3g} {unit}, NRMSE {100 * r['nrmse']:.3g} %")
    return 0


def is_structure_fit(path: str) -> tuple[bool, dict]:
    """Whether `path` (a fit.json or its directory) holds a structure's fit, and its content."""
    doc = read_fit_json(path)
    return doc.get("kind") == "structure", doc

