"""`mrjax fit --posterior`: the options of the per-test posterior and its outputs."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

from .._errors import InputError
from ._common import say, use_agg

#: The posterior options and their defaults (None in argparse: given or not is checked).
DEFAULTS = {"draws": 1000, "chains": 4, "warmup": 1000, "noise": "iid"}


def add_posterior_options(p: argparse.ArgumentParser) -> None:
    """Register `--posterior` and its options on the `mrjax fit` parser."""
    g = p.add_argument_group("posterior (Bayesian identification by NUTS)")
    g.add_argument("--posterior", action="store_true",
                   help="after the fit, sample the posterior of every test's parameters "
                   "(NUTS, blackjax) and write posterior.nc, posterior.csv, a 'posterior' "
                   "entry in fit.json and figures")
    g.add_argument("--draws", type=int, metavar="N",
                   help=f"draws kept per chain (default {DEFAULTS['draws']})")
    g.add_argument("--chains", type=int, metavar="K",
                   help=f"chains per test (default {DEFAULTS['chains']})")
    g.add_argument("--warmup", type=int, metavar="N",
                   help=f"adaptation steps per chain (default {DEFAULTS['warmup']})")
    g.add_argument("--noise", metavar="iid|ar1",
                   help="residual model: iid (default) or ar1 (correlated model error: "
                   "honest intervals on real records)")
    g.add_argument("--posterior-data", metavar="record|view",
                   help="what the likelihood scores: the whole record, or the swarm's "
                   "subsampled view (default: view for the dynamic models, record otherwise)")
    g.add_argument("--prior", action="append", metavar="NAME=KIND:A:B",
                   help="prior of one parameter: normal:MEAN:SD, lognormal:MEDIAN:SIGMA or "
                   "uniform:LO:HI, SI units (repeatable; default flat on the bounds)")


def posterior_settings(args: argparse.Namespace, names: Sequence[str]) -> dict[str, Any] | None:
    """The checked keyword arguments of `mrjax.posterior` from the command line, or None
    without `--posterior`; `names` the model's parameters. Raises :class:`mrjax.InputError`
    (before any fitting) for an impossible option or for one given without `--posterior`."""
    from ..bayes import DATA_CHOICES, NOISE_MODELS, Sampler, check_priors

    given = [f"--{k.replace('_', '-')}" for k in (*DEFAULTS, "posterior_data", "prior")
             if getattr(args, k, None) is not None]
    if not args.posterior:
        if given:
            raise InputError(f"{given[0]} needs --posterior")
        return None
    kw = {k: (getattr(args, k) if getattr(args, k) is not None else v)
          for k, v in DEFAULTS.items()}
    Sampler(draws=kw["draws"], chains=kw["chains"], warmup=kw["warmup"]).check()
    if kw["noise"] not in NOISE_MODELS:
        raise InputError(f"--noise must be one of {', '.join(NOISE_MODELS)}, got "
                         f"{kw['noise']!r}")
    if args.posterior_data is not None and args.posterior_data not in DATA_CHOICES:
        raise InputError(f"--posterior-data must be one of {', '.join(DATA_CHOICES)}, got "
                         f"{args.posterior_data!r}")
    prior = {}
    for item in args.prior or ():
        name, sep, spec = item.partition("=")
        if not sep or not name.strip():
            raise InputError(f"--prior expects NAME=KIND:A:B, got {item!r}")
        prior[name.strip()] = spec
    kw.update(likelihood_data=args.posterior_data, prior=check_priors(prior, names) or None)
    return kw


def run_posterior(settings: dict[str, Any], result: Any, batch: Any, *, bounds: Any,
                  transient: Any, seed: int, plots: bool) -> tuple[Any, dict[str, bytes]]:
    """The posterior of a per-test fit and its files: `posterior.nc`, `posterior.csv` and (with
    `plots`) the figures of `mrjax.report.posterior_figures`."""
    from ..bayes import posterior

    how = settings["likelihood_data"] or ("view" if result.model.dynamic else "record")
    say(f"sampling the posterior ({settings['chains']} chains x {settings['draws']} draws, "
        f"{settings['noise']} noise, {how})...")
    tp = posterior(result, batch, seed=seed, bounds=bounds, transient=transient, progress=None,
                   **settings)
    files = {"posterior.nc": tp.netcdf_bytes(), "posterior.csv": tp.to_csv().encode()}
    if plots:
        use_agg()
        from .. import report as rp  # imported here: matplotlib only when figures are drawn

        band = tp.predict_band(batch)
        files.update(rp.posterior_figures(tp, band))
    return tp, files
