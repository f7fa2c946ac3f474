"""`mrjax fit --posterior`: the options of the per-test posterior and its outputs."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from typing import Any

from .._errors import InputError
from ._common import use_agg
from ._parse import KERNELS, say
from ._parse import POSTERIOR_DEFAULTS as DEFAULTS


@dataclasses.dataclass(frozen=True)
class PosteriorRequest:
    """What `mrjax fit --posterior` asks of `mrjax.posterior`: the `sampler` (a
    `mrjax.Sampler`), the `noise` model, the `prior` ({name: prior} or None) and the
    `likelihood_data` (None: the default for the model)."""

    sampler: Any
    noise: str
    prior: dict[str, Any] | None
    likelihood_data: str | None


def posterior_settings(args: argparse.Namespace, names: Sequence[str]
                       ) -> PosteriorRequest | None:
    """The posterior's settings objects from the command line, or None without
    `--posterior`; `names` the model's parameters. Raises :class:`mrjax.InputError` (before
    any fitting) for an impossible option or for one given without `--posterior`."""
    from ..bayes import NOISE_MODELS, NUTS, ChEES, Sampler, check_priors
    from ..engine import DATA_CHOICES

    given = [f"--{k.replace('_', '-')}" for k in (*DEFAULTS, "posterior_data", "prior")
             if getattr(args, k, None) is not None]
    if not args.posterior:
        if given:
            raise InputError(f"{given[0]} needs --posterior")
        return None
    kw = {k: (getattr(args, k) if getattr(args, k) is not None else v)
          for k, v in DEFAULTS.items()}
    if kw["kernel"] not in KERNELS:
        raise InputError(f"--kernel must be one of {', '.join(KERNELS)}, got "
                         f"{kw['kernel']!r}")
    sampler = Sampler(draws=args.draws, chains=args.chains, warmup=args.warmup,
                      kernel=ChEES() if kw["kernel"] == "chees" else NUTS()).check()
    if kw["noise"] not in NOISE_MODELS:
        raise InputError(f"--noise must be one of {', '.join(NOISE_MODELS)}, got "
                         f"{kw['noise']!r}")
    if args.posterior_data is not None and args.posterior_data not in DATA_CHOICES:
        raise InputError(f"--posterior-data must be one of {', '.join(DATA_CHOICES)}, got "
                         f"{args.posterior_data!r}")
    if getattr(args, "generalize", None) and args.prior:
        raise InputError("--prior applies to per-test parameters; the posterior of the laws "
                         "(--generalize) is flat on their node values")
    prior = {}
    for item in args.prior or ():
        name, sep, spec = item.partition("=")
        if not sep or not name.strip():
            raise InputError(f"--prior expects NAME=KIND:A:B, got {item!r}")
        prior[name.strip()] = spec
    return PosteriorRequest(sampler=sampler, noise=kw["noise"],
                            prior=check_priors(prior, names) or None,
                            likelihood_data=args.posterior_data)


def run_posterior(request: PosteriorRequest, fitted: Any, batch: Any, *, key: int,
                  plots: bool) -> tuple[Any, dict[str, bytes]]:
    """The posterior of `fitted` (a per-test fit, or the `GeneralizedModel` of
    `--generalize`: its laws) and its files: `posterior.nc`, `posterior.csv` and (with
    `plots`) the figures of `mrjax.report.posterior_figures` (laws:
    `mrjax.report.law_posterior_figures`)."""
    from ..engine import posterior
    from ..generalize import GeneralizedModel

    laws = isinstance(fitted, GeneralizedModel)
    model = fitted.model
    how = request.likelihood_data or ("view" if model.dynamic else "record")
    s = request.sampler
    say(f"sampling the posterior{' of the laws' if laws else ''} ({s.chains} chains x "
        f"{s.draws} draws, {request.noise} noise, {how})...")
    post = posterior(fitted, batch, sampler=s, noise=request.noise, prior=request.prior,
                     key=key, likelihood_data=request.likelihood_data, progress=None)
    files = {"posterior.nc": post.netcdf_bytes(), "posterior.csv": post.to_csv().encode()}
    if plots:
        use_agg()
        from .. import report as rp  # imported here: matplotlib only when figures are drawn

        band = post.predict_band(batch)
        figures = rp.law_posterior_figures if laws else rp.posterior_figures
        files.update(figures(post, band))
    return post, files


def run_band(args: argparse.Namespace, out: Any) -> int:
    """`mrjax predict --fit DIR --band PCT`: the posterior predictive band of a per-test fit
    (its `posterior.nc`) on records of the same tests, or of a laws' posterior
    (`--generalize ... --posterior`) on records at any current, with the coverage of the
    measured force; writes predict.json, predict.csv and predict_band.png."""
    from pathlib import Path

    import numpy as np

    from .. import __version__
    from .._io import json_bytes
    from .._tables import format_table
    from ..bayes import predictive_band, read_draws
    from ..generalize import NOISE_RULE, GeneralizedModel, law_band, read_law_draws
    from ..models import from_source, get
    from ._common import data_spec, load_batch, read_fit_json, say_estimates

    if not 0.0 < args.band < 100.0:
        raise InputError(f"--band must be a percentage in (0, 100), got {args.band:g}")
    doc = read_fit_json(args.fit)
    fit_dir = Path(args.fit).expanduser()
    fit_dir = fit_dir if fit_dir.is_dir() else fit_dir.parent
    nc = fit_dir / "posterior.nc"
    if not nc.is_file():
        raise InputError(f"{args.fit}: no posterior.nc beside the fit.json; run `mrjax fit "
                         f"DATA... --model NAME --posterior` first")
    laws = (doc.get("posterior") or {}).get("kind") == "laws"
    if laws:  # the laws over the current, on records at any current
        if "generalized" not in doc:
            raise InputError(f"{args.fit}: a posterior of laws without its 'generalized' block")
        block = dict(doc["generalized"])
        block.setdefault("model_source", doc.get("model_source"))
        gm = GeneralizedModel.from_dict(block, model=args.model)
        model = gm.model
        coef, noise, records, currents, scale, motion = read_law_draws(nc, gm)
        n_used, what = coef.shape[0], f"laws of {len(records)} record(s)"
    else:
        model = (get(args.model) if args.model else
                 from_source(str(doc.get("model")), doc.get("model_source")))
        labels, theta, sigma = read_draws(nc, model.param_names)
        n_used, what = theta.shape[1], f"{len(labels)} test(s)"
    batch = load_batch(args.files, data_spec(args))
    say_estimates(batch)
    say(f"predicting {batch.n_conditions} record(s) with the posterior of {what}, "
        f"{args.band:g} % band...")
    if laws:
        band = law_band(gm, coef, noise, records, currents, scale, batch, motion=motion,
                        level=args.band / 100.0)
    else:
        band = predictive_band(model, theta, sigma, labels, batch, level=args.band / 100.0)
    pooled = float(np.sum(band.coverage * band.mask.sum(axis=1)) / max(band.mask.sum(), 1))
    report = {"fit": str(args.fit), "model": model.name, "mrjax_version": __version__,
              "kind": "laws" if laws else "per-test", "band": band.to_dict(),
              "coverage_mean": float(np.mean(band.coverage)), "coverage_pooled": pooled,
              "draws_used": int(n_used)}
    if laws:
        report["noise_rule"] = NOISE_RULE
    rows = [[lab, 100 * c, 100 * fc, 100 * e] for lab, c, fc, e in
            zip(band.labels, band.coverage, band.force_coverage, band.nrmse)]
    csv = "label,coverage,force_coverage,nrmse\n" + "".join(
        f"{lab},{c:.6g},{fc:.6g},{e:.6g}\n" for lab, c, fc, e in
        zip(band.labels, band.coverage, band.force_coverage, band.nrmse))
    files = {"predict.json": json_bytes(report), "predict.csv": csv.encode()}
    if not args.no_plots:
        use_agg()
        from .. import report as rp  # imported here: matplotlib only when figures are drawn

        files["predict_band.png"] = rp.save_png_bytes(rp.plot_predictive_band(band))
    say(f"writing {len(files)} files to {out.path}...")
    out.write(files)
    print(format_table(rows, ["record", f"in {args.band:g}% band %", "in force band %",
                              "NRMSE%"], floatfmt=["", ".1f", ".1f", ".2f"]))
    print(f"{model.name} posterior{' of the laws' if laws else ''}: the {args.band:g} % band "
          f"covers {100 * float(np.mean(band.coverage)):.1f} % of the measured force (mean "
          f"over {len(rows)} record(s); {100 * pooled:.1f} % of all samples)")
    return 0
