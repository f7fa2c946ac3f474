"""`summary.json`: every run's numbers, the generalized laws against eq 24-29, and the
acceptance checks (a) RMS, (b) generations and (c) coefficients."""

from __future__ import annotations

import os
import platform
from collections.abc import Sequence
from typing import Any

import jax
import jaxlib
import matplotlib
import numpy as np

from .. import __version__
from .._io import json_safe
from ..data import PAPER_COEFFICIENTS, paper_truth
from ..fitting import FitResult
from ._stats import finite_mean, finite_median
from ._study import RUN_TITLES, Study

#: Relative tolerance [%] of acceptance (c) on the generalized coefficients.
COEF_TOLERANCE_PCT = 5.0
#: Version of the `summary.json` layout.
SUMMARY_SCHEMA = 1


def _versions() -> dict[str, str]:
    return {"mrjax": __version__, "jax": jax.__version__, "jaxlib": jaxlib.__version__,
            "numpy": np.__version__, "matplotlib": matplotlib.__version__,
            "python": platform.python_version(), "platform": platform.platform(),
            "machine": platform.machine(), "jax_backend": jax.default_backend(),
            "cpu_count": str(os.cpu_count())}


def _run_summary(res: FitResult) -> dict[str, Any]:
    """One run's entry of "runs": medians over the conditions and the per-condition values."""
    gens = np.asarray(res.generations)
    swarm = bool(np.any(gens >= 0))
    return {
        "model": res.model.name, "method": res.method, "swarm": res.swarm_mode,
        "median_rms_N": json_safe(finite_median(res.rms)),
        "mean_rms_N": json_safe(finite_mean(res.rms)),
        "max_rms_N": json_safe(np.nanmax(res.rms)),
        "median_nrmse": json_safe(finite_median(res.nrmse)),
        "rms_N": json_safe(np.asarray(res.rms, float)),
        "swarm_rms_N": json_safe(np.asarray(res.pso_rms, float)),
        "median_swarm_rms_N": json_safe(finite_median(res.pso_rms)),
        "generations": [int(g) for g in gens] if swarm else None,
        "stopped_by_criterion": [bool(s) for s in res.stopped_by_criterion] if swarm else None,
        "median_generations": json_safe(np.median(gens)) if swarm else None,
        "mean_generations": json_safe(np.mean(gens)) if swarm else None,
        "max_generations_run": int(gens.max()) if swarm else None,
        "generation_cap": int(np.asarray(res.history).shape[1] - 1) if swarm else None,
        "param_names": list(res.param_names),
        "params": [[float(v) for v in row] for row in np.asarray(res.theta)],
    }


def _coefficient_table(study: Study) -> dict[str, Any] | None:
    """Generalized law coefficients next to eq 24-29 (when they are the truth)."""
    if not study.generalized:
        return None
    truth = study.data_info["truth"]
    out: dict[str, Any] = {}
    for method, gm in study.generalized.items():
        laws, errs = {}, {}
        worst = 0.0
        for name in gm.param_names:
            coef = [float(c) for c in gm.coefficients(name)]
            laws[name] = coef
            if truth:
                ref = PAPER_COEFFICIENTS[name]
                e = [100.0 * (c - r) / abs(r) if len(coef) == len(ref) else None
                     for c, r in zip(coef, ref)]
                errs[name] = e
                worst = max([worst] + [abs(v) for v in e if v is not None])
        ev = study.generalized_eval[method]
        out[method] = {
            "weighting": gm.weighting, "total_rms_N": json_safe(float(gm.total_rms)),
            "median_rms_N": json_safe(finite_median(ev["rms"])),
            "rms_N": json_safe(np.asarray(ev["rms"], float)),
            "coefficients": laws,
            "error_pct": errs if truth else None,
            "max_abs_error_pct": worst if truth else None,
            "formulas": {n: gm.laws[n].formula() for n in gm.param_names},
        }
    return out


def _truth_errors(study: Study) -> dict[str, Any] | None:
    """Median |relative error| [%] of the per-test tanh parameters against eq 24-29."""
    if not study.data_info["truth"]:
        return None
    truth = paper_truth(study.batch)
    out = {}
    for key in ("kwok_separable", "kwok_paper_swarm", "kwok_paper_swarm_polished"):
        res = study.runs[key]
        rel = 100.0 * np.abs(res.theta - truth) / np.abs(truth)
        out[key] = {n: float(np.median(rel[:, p])) for p, n in enumerate(res.param_names)}
    return out


def _acceptance_rms(runs: dict[str, FitResult]) -> dict[str, Any]:
    """(a) The tanh model ends with a lower median RMS than Bouc-Wen: with the paper's swarm,
    and with the separable swarms (converged fits) where both were run."""
    rk, rb = runs["kwok_paper_swarm"], runs["bouc_wen_paper_swarm"]
    a_paper = {"tanh_N": finite_median(rk.rms), "bouc_wen_N": finite_median(rb.rms)}
    a_paper["holds"] = a_paper["tanh_N"] < a_paper["bouc_wen_N"]
    a: dict[str, Any] = {"statistic": "median RMS over the conditions", "paper_swarm": a_paper,
                         "separable_swarm": None}
    if "bouc_wen_separable" in runs:
        ks = runs["kwok_separable"]
        a_sep = {"tanh_N": finite_median(ks.pso_rms),
                 "bouc_wen_N": finite_median(runs["bouc_wen_separable"].rms),
                 "tanh_polished_N": finite_median(ks.rms)}
        a_sep["holds"] = a_sep["tanh_N"] < a_sep["bouc_wen_N"]
        a["separable_swarm"] = a_sep
    return a


def _acceptance_generations(runs: dict[str, FitResult]) -> dict[str, Any]:
    """(b) The tanh model's swarm stops in fewer generations than Bouc-Wen's (same seed)."""
    rk, rb = runs["kwok_paper_swarm"], runs["bouc_wen_paper_swarm"]
    g_t, g_b = np.asarray(rk.generations, float), np.asarray(rb.generations, float)
    b = {"statistic": "median generations over the conditions (paper's swarm, same seed)",
         "tanh_median": float(np.median(g_t)), "bouc_wen_median": float(np.median(g_b)),
         "tanh_mean": float(np.mean(g_t)), "bouc_wen_mean": float(np.mean(g_b)),
         "tanh_capped": int(np.sum(~np.asarray(rk.stopped_by_criterion))),
         "bouc_wen_capped": int(np.sum(~np.asarray(rb.stopped_by_criterion)))}
    b["holds"] = b["tanh_median"] < b["bouc_wen_median"]
    b["holds_by_mean"] = b["tanh_mean"] < b["bouc_wen_mean"]
    b["robust"] = bool(b["holds"] and b["holds_by_mean"]
                       and b["bouc_wen_median"] - b["tanh_median"] >= 2.0)
    b["robust_rule"] = ("median and mean agree and the medians differ by at least 2 "
                        "generations")
    return b


def _acceptance_coefficients(study: Study, coefs: dict[str, Any] | None) -> dict[str, Any]:
    """(c) The two-step laws' coefficients within `COEF_TOLERANCE_PCT` of eq 24-29 (embedded
    data only)."""
    c: dict[str, Any] = {"tolerance_pct": COEF_TOLERANCE_PCT, "method": "two-step",
                         "applicable": bool(study.data_info["truth"] and coefs)}
    if c["applicable"]:
        c["max_abs_error_pct"] = coefs["two-step"]["max_abs_error_pct"]
        c["holds"] = c["max_abs_error_pct"] <= COEF_TOLERANCE_PCT
        c["max_abs_error_pct_equal_weighting"] = coefs["two-step-equal"]["max_abs_error_pct"]
    else:
        c["holds"] = None
    return c


def summarize(study: Study, files: Sequence[str] = ()) -> dict[str, Any]:
    """The `summary.json` document of a :class:`Study` (timings included)."""
    b = study.batch
    coefs = _coefficient_table(study)
    doc: dict[str, Any] = {
        "schema": SUMMARY_SCHEMA,
        "title": "Kwok et al. (2006) reproduced by mrjax",
        "seed": study.seed,
        "quick": study.quick,
        "data": {
            "source": study.data_info["source"], "truth": study.data_info["truth"],
            "n_conditions": b.n_conditions, "labels": list(b.labels),
            "current_A": json_safe(np.asarray(b.current, float)),
            "frequency_Hz": json_safe(np.asarray(b.frequency, float)),
            "amplitude_m": json_safe(np.asarray(b.amplitude, float)),
            "n_samples": [int(n) for n in b.n_samples],
            "trimmed_to_last_cycles": study.data_info["trimmed"],
        },
        "runs": {k: {"title": RUN_TITLES[k], **_run_summary(r)} for k, r in study.runs.items()},
        "generalized": coefs,
        "paper_coefficients": ({k: list(v) for k, v in PAPER_COEFFICIENTS.items()}
                               if study.data_info["truth"] else None),
        "param_error_vs_truth_pct": _truth_errors(study),
        "acceptance": {"a_tanh_lower_rms": _acceptance_rms(study.runs),
                       "b_tanh_fewer_generations": _acceptance_generations(study.runs),
                       "c_coefficients": _acceptance_coefficients(study, coefs)},
        "notes": list(study.notes),
        "timings_s": dict(study.timings),
        "versions": _versions(),
        "files": sorted(files),
        "models": {m: [k for k, r in study.runs.items() if r.model.name == m]
                   for m in ("kwok", "bouc_wen")},
    }
    return doc
