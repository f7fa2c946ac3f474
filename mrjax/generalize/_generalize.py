"""`generalize`: a current-dependent model from per-condition fits (two-step or joint)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ..data import JOINT_SAMPLES_PER_PERIOD, Batch, as_batch, check_mask, fit_mask
from ..data import swarm_view as make_view
from ..engine import Polish, Swarm, check_settings
from ..fitting import FitResult
from ..models import AbstractModel, resolve_model
from ._coding import Layout, bounded_box, build_objective, law_values, total_rms_of
from ._forms import choose_forms, forms_choice
from ._joint import N_LEVELS, JointOutcome, LawsProblem, solve_laws
from ._laws import Law, canonical_z_scale, fit_space, group_currents, nodes
from ._model import GeneralizedModel, LawUncertainty
from ._report import LawReport
from ._rows import make_rows, packed_rows
from ._two_step import covariances, two_step_coefficients

LawKind = Literal["poly", "exp", "sat"]
GeneralizeMethod = Literal["two-step", "joint"]
Weighting = Literal["covariance", "equal"]


def _checked(result: FitResult, batch: Batch, method: str, weighting: str):
    """The per-condition parameters (C, P) and currents (C,) after checking the inputs."""
    if not isinstance(result, FitResult):
        raise InputError(f"result must be a mrjax.FitResult, got {type(result).__name__}")
    if method not in ("two-step", "joint"):
        raise InputError(f"method must be 'two-step' or 'joint', got {method!r}")
    if weighting not in ("covariance", "equal"):
        raise InputError(f"weighting must be 'covariance' or 'equal', got {weighting!r}")
    C = batch.n_conditions
    if result.n_conditions != C:
        raise InputError(f"result has {result.n_conditions} conditions but batch has {C}")
    if tuple(result.labels) != tuple(batch.labels):
        i = next(j for j, (a, b) in enumerate(zip(result.labels, batch.labels)) if a != b)
        raise InputError(f"result and batch disagree at condition {i}: {result.labels[i]!r} vs "
                         f"{batch.labels[i]!r}")
    cur = np.asarray(batch.current, float)
    bad = np.flatnonzero(~np.isfinite(cur))
    if bad.size:
        raise InputError(f"condition {batch.labels[bad[0]]!r} has no current; generalizing needs "
                         "the current of every condition")
    theta = np.asarray(result.theta, float)
    if not np.all(np.isfinite(theta)):
        i, j = np.argwhere(~np.isfinite(theta))[0]
        raise InputError(f"condition {batch.labels[i]!r}: parameter "
                         f"{result.model.param_names[j]!r} is not finite")
    return theta, cur


@dataclasses.dataclass(frozen=True)
class TwoStep:
    """The two-step laws and what the joint stage starts from: `theta` (C, P) per-condition
    parameters (z-scale normalised), `current` (C,) [A], `levels` (U,) distinct currents,
    `layout`, `coef` (V,) two-step coefficients, `rms` [N] their total RMS on the records,
    `rows` the records, `exp_cols` (P,) which laws are `"exp"`."""

    theta: np.ndarray
    current: np.ndarray
    levels: np.ndarray
    layout: Layout
    coef: np.ndarray
    rms: float
    rows: tuple
    exp_cols: np.ndarray


def _two_step_stage(result, batch, theta, cur, degrees, laws, weighting, mask):
    """The two-step laws and everything the joint stage starts from.

    **Returns:** `(TwoStep, weighting used, support, LawReport)`."""
    model = result.model
    levels, _ = group_currents(cur)
    forms = choose_forms(model, theta, cur, degrees, "auto" if laws is None else laws,
                         levels.size)
    kinds, degs = forms.kinds, forms.degrees
    exp_cols = np.array([k == "exp" for k in kinds])
    for p in np.flatnonzero(exp_cols):
        neg = np.flatnonzero(theta[:, p] <= 0)
        if neg.size:
            raise InputError(f"law 'exp' of {model.param_names[p]!r} needs positive values; "
                             f"condition {batch.labels[neg[0]]!r} has {theta[neg[0], p]:g}")
    m = check_mask(batch, mask)
    used, note, cov = weighting, "", None
    if weighting == "covariance":
        if model.scale_symmetry is not None:
            note = "the z-scale of Bouc-Wen models makes the covariance singular"
        else:
            cov, note = covariances(result, theta, exp_cols)
        if cov is None:
            used = "equal"
    coef, support = two_step_coefficients(theta, cur, kinds, degs, cov, used, forms.scales)
    lo_i, hi_i = float(levels.min()), float(levels.max())
    layout = Layout(kinds, forms.sizes, tuple(nodes(lo_i, hi_i, d + 1) for d in degs),
                    forms.scales)
    rows = packed_rows(batch, m, cur) if not model.dynamic else make_rows(batch, m, cur)
    rms = _score(model, layout, coef, rows, np.concatenate(
        [theta, np.asarray(law_values(layout.lawset(coef), levels))]))
    start = TwoStep(theta=theta, current=cur, levels=levels, layout=layout, coef=coef, rms=rms,
                    rows=rows, exp_cols=exp_cols)
    return start, used, support, LawReport(two_step_rms=float(rms), weighting_note=note,
                                           **forms_choice(forms))


def _score(model: AbstractModel, layout: Layout, coef, rows, theta_rows) -> float:
    """Total RMS [N] of the laws `coef` on `rows`, sub-steps resolved for `theta_rows`."""
    obj = build_objective(model, layout, layout.V @ np.asarray(coef, float))
    if model.dynamic:
        xdot = np.concatenate([np.asarray(r.xdot).ravel() for r in rows])
        dt = np.concatenate([np.asarray(r.dt).ravel() for r in rows])
        mask = np.concatenate([np.asarray(r.mask).ravel() for r in rows])
        model = resolve_model(model, theta_rows, xdot, dt, mask)
    return float(total_rms_of(model, obj.coding, obj.coding.nu0, 0.0, rows))


def _search_box(model: AbstractModel, start: TwoStep):
    """Node values of the two-step laws and the swarm's box around them: +-(3 x the scatter of
    the per-condition values about the law + 25 % of the value), non-negative parameters kept
    non-negative. Returns `(nu0, half, box_lo, box_hi)`, each (V,)."""
    layout, kinds = start.layout, start.layout.kinds
    nu0 = layout.V @ start.coef
    law_rows = np.asarray(law_values(layout.lawset(start.coef), start.current))
    dev = np.sqrt(np.mean((fit_space(start.theta, start.exp_cols)
                           - fit_space(law_rows, start.exp_cols)) ** 2, axis=0))
    lo_m, hi_m = model.bounds
    half = np.zeros(layout.n)
    box_lo, box_hi = np.zeros(layout.n), np.zeros(layout.n)
    for p in range(model.n_params):
        b = layout.block(p)
        tiny = 1e-6 * (hi_m[p] - lo_m[p]) + 1e-9
        h = 3.0 * dev[p] + 0.25 * np.abs(nu0[b]) + tiny
        half[b] = h
        box_lo[b], box_hi[b] = nu0[b] - h, nu0[b] + h
        if kinds[p] != "exp" and lo_m[p] >= 0:
            box_lo[b] = np.where(nu0[b] >= 0, np.maximum(box_lo[b], 0.0), box_lo[b])
    return nu0, half, box_lo, box_hi


def _joint_problem(model, batch, start: TwoStep, mask, use_view: bool,
                   pso_params: Any) -> LawsProblem:
    """The joint fit's problem around the two-step laws: the swarm searches the box of
    :func:`_search_box` (a Bouc-Wen shape as `(log delta, q)` around the per-condition values),
    intersected with the polish's box (`bounded_box`: every node value within the model's
    bounds)."""
    nu0, half, box_lo, box_hi = _search_box(model, start)
    names, kinds, sizes = model.param_names, start.layout.kinds, start.layout.sizes
    sym = model.scale_symmetry
    z_scale = sym is not None
    shape_ix = [names.index(k) for k in (sym.gauge, *sym.balance)] if z_scale else []
    pair = z_scale and all(sizes[p] == 1 and kinds[p] == "poly" for p in shape_ix)
    obj = build_objective(model, start.layout, nu0, z_scale=z_scale, pair=pair)
    coding = obj.coding
    lm_lo, lm_hi = bounded_box(model, start.layout, coding, *model.bounds)
    D = coding.n_position
    s_lo = list(box_lo[list(coding.direct)])
    s_hi = list(box_hi[list(coding.direct)])
    if pair:  # (log delta, q) of every condition about the two-step value
        th = start.theta
        d_c = np.log(np.maximum(th[:, shape_ix[0]], 1e-300))
        q_c = th[:, shape_ix[2]] / th[:, shape_ix[0]]
        z0 = coding.bounded_of(nu0, 0.0)[len(s_lo):len(s_lo) + 2]
        for v, c in zip(z0, (d_c, q_c)):
            h = 3.0 * np.sqrt(np.mean((c - v) ** 2)) + 0.25 * abs(v) + 1e-6
            s_lo.append(v - h)
            s_hi.append(v + h)
    s_lo = np.clip(np.asarray(s_lo, float), lm_lo[:D], lm_hi[:D])
    s_hi = np.clip(np.asarray(s_hi, float), lm_lo[:D], lm_hi[:D])
    view = None
    if use_view:
        v = make_view(batch, samples_per_period=JOINT_SAMPLES_PER_PERIOD)
        view = make_rows(v.batch, np.asarray(v.mask) & np.asarray(v.batch.mask),
                         np.asarray(v.batch.current, float))
    lo, hi = float(start.levels.min()), float(start.levels.max())
    return LawsProblem(model, start.layout, obj, s_lo, s_hi, lm_lo, lm_hi, start.rows, view,
                       np.linspace(lo, hi, N_LEVELS), start=(nu0, 0.0), pso_params=pso_params)


def generalize(
    result: FitResult,
    batch: Batch,
    *,
    method: GeneralizeMethod = "two-step",
    laws: Mapping[str, LawKind] | Literal["auto", "fixed"] | None = "auto",
    degrees: Mapping[str, int] | int | None = None,
    weighting: Weighting = "covariance",
    swarm: Swarm | None = Swarm(max_generations=100),
    polish: Polish | None = Polish(max_steps=100),
    key: int | ArrayLike = 0,
    mask: ArrayLike | None = None,
) -> GeneralizedModel:
    """Make a current-dependent model from per-condition fits (eq 24-29).

    **Arguments:**

    - `result`: the per-condition :class:`mrjax.FitResult` of `batch`.
    - `batch`: the conditions it was fitted on (their currents must be known). Records with
        a per-sample current or command are identified by :func:`identify` instead.
    - `method`: `"two-step"` (group by current, average, fit the laws: the paper's) or
        `"joint"` (law coefficients fitted on all conditions at once, starting from the
        two-step laws: the joint fit of :func:`identify`, swarm then polish; never worse than
        two-step on these data). See the package docstring.
    - `degrees`: parameter name -> polynomial degree (or one int for all); the others get
        their form from `laws`.
    - `laws`: `"auto"` (default; also None): every form chosen by the data, per parameter the lowest
        BIC of its per-test values among polynomial degree 0-2, exponential and saturating
        (`choose_forms`; a parameter named in `degrees` keeps that polynomial degree);
        `"fixed"`: the model's :func:`default_degrees` (polynomials; the forms of the last
        release); or parameter name -> `"poly"`, `"exp"` ($\\exp(a + b\\,i)$ at degree 1) or
        `"sat"` ($a + b(1 - e^{-i/s})$, the scale s fitted to the per-test values), the others
        fixed. The forms are in `GeneralizedModel.laws` (`Law.form`; the criteria in
        `report.law_criteria`), the summary and fit.json. Auto is the default because on real
        records it predicts held-out currents better or as well (`benchmarks/defaults.md`);
        on the paper's grid it picks eq 24-29's forms.
    - `weighting`: two-step averaging, `"covariance"` (default; inverse-covariance weighted,
        generalized least squares) or `"equal"` (the paper's plain means).
    - `swarm`: the joint swarm's :class:`mrjax.Swarm` (default `Swarm(max_generations=100)`;
        its `mode` does not apply: the linear laws are always solved by least squares; its
        `view`: let the swarm and a first polish score the records' views,
        `mrjax.data.swarm_view`, by default for the ODE models). None: the polish starts from
        the two-step laws.
    - `polish`: the joint Levenberg-Marquardt polish's :class:`mrjax.Polish` (default
        `Polish(max_steps=100)`, per stage; its `tol` stops `mrjax.refine.lm_solve`: the full
        records to 100 x `tol` after the views, to 10 x `tol` where the views' polish is
        skipped; its `uncertainty`: std-errors of the joint coefficients,
        `GeneralizedModel.uncertainty`). None: no polish.
    - `key`: the joint swarm's seed or PRNG key; same key, same result.
    - `mask`: (C, T) samples to score (default the fit's: the batch mask less the fit's
        `transient`; combined with the batch mask). The swarm's views score every sample of
        theirs.

    **Returns:** a :class:`GeneralizedModel` (laws of the current, in A).
    """
    t0 = time.perf_counter()
    batch = as_batch(batch)
    method = str(method).replace("_", "-")
    theta_raw, cur = _checked(result, batch, method, weighting)
    if mask is None and result.transient is not None:  # the fit's scored samples
        mask = fit_mask(batch, result.transient)
    model = result.model
    theta = canonical_z_scale(model, theta_raw)
    start, used, support, report = _two_step_stage(result, batch, theta, cur, degrees, laws,
                                                   weighting, mask)
    timings = {"two_step": time.perf_counter() - t0}
    rng = (float(start.levels.min()), float(start.levels.max()))
    if method == "two-step":
        report = dataclasses.replace(report, timings=timings)
        return make_generalized(model, start.layout, start.coef, "two-step", start.rms, rng, used,
                                support, report, transient=result.transient)
    sw, po = check_settings(swarm, polish)
    view = sw.view if sw is not None else None
    use_view = model.dynamic if view is None else bool(view)
    problem = _joint_problem(model, batch, start, check_mask(batch, mask), use_view,
                             sw.params if sw is not None else None)
    out = solve_laws(problem, swarm=sw, polish=po,
                     uncertainty=po.uncertainty if po is not None else True, key=key)
    timings.update(out.outcome.timings)
    report = dataclasses.replace(report, outcome=out.outcome)
    if not out.rms <= start.rms:  # never worse than the two-step laws (also catches NaN)
        out = JointOutcome(coef=start.coef, eta=None, rms=start.rms)
        report = dataclasses.replace(report, fell_back_to_two_step=True)
    timings["total"] = time.perf_counter() - t0
    return make_generalized(model, start.layout, out.coef, "joint", out.rms, rng, used, support,
                            dataclasses.replace(report, timings=timings),
                            uncertainty=law_uncertainty_of(model, start.layout, out),
                            transient=result.transient)


def law_uncertainty_of(model: AbstractModel, layout: Layout, out: JointOutcome
                       ) -> LawUncertainty | None:
    """The :class:`LawUncertainty` of a joint outcome (None without std-errors)."""
    if out.stderr is None:
        return None
    names = model.param_names
    se = {n: tuple(float(v) for v in out.stderr[layout.block(p)]) for p, n in enumerate(names)}
    ok = {n: tuple(bool(v) for v in out.identifiable[layout.block(p)])
          for p, n in enumerate(names)}
    lag = out.eta is not None and out.stderr.size > layout.n and np.isfinite(out.stderr[-1]) \
        and out.stderr[-1] > 0
    return LawUncertainty(stderr=se, identifiable=ok,
                          lag_stderr=float(out.stderr[-1]) if lag else None,
                          lag_identifiable=bool(out.identifiable[-1]) if lag else None,
                          sigma=out.sigma, dof=out.dof)


def make_generalized(model: AbstractModel, layout: Layout, coef, method: str, rms: float, rng,
                     weighting, support, report: LawReport, **extra) -> GeneralizedModel:
    """The :class:`GeneralizedModel` of law coefficients `coef` in `layout`."""
    scales = layout.law_scales
    laws = {n: Law(layout.kinds[p], np.asarray(coef)[layout.block(p)],
                   scales[p] if layout.kinds[p] == "sat" else None)
            for p, n in enumerate(model.param_names)}
    return GeneralizedModel(model=model, laws=laws, method=method, total_rms=rms,
                            current_range=rng, weighting=weighting, support=support, report=report,
                            **extra)
