"""The posterior of laws over the current: its plan for the engine's posterior stage
(`mrjax.posterior` on a `GeneralizedModel`), its result :class:`LawPosterior`, and the
predictive band of the laws on new records (unseen currents).

**Unknowns.** The laws' values at their nodes, as the joint fit polishes them
(`mrjax.generalize`'s `Coding.from_free`: the value of each parameter at d + 1 currents spread
over the laws' range, log values for an `"exp"` law; in a Bouc-Wen-type model the z-scale's
delta node derived from beta and gamma). The coefficients are a fixed linear map of them, so
the default flat prior on the node values' box (every node value within its parameter's
bounds, `mrjax.generalize.node_box`) is flat on the coefficients too. One unit holds the whole
data set: one block of rows per group of records of similar length
(`mrjax.generalize.joint_residual_blocks`, the residuals of the joint fit), one noise level
per record, one AR(1) coefficient for all of them with `noise="ar1"`. The chains start at the
laws' node values with the Gauss-Newton covariance of these unknowns on the likelihood's data
as the start of the mass matrix (`mrjax.bayes.sample`).

**Predictive band on a new record.** Each kept draw gives the coefficients, hence the
parameters at the record's current and its force (the model through the one integrator), plus
Gaussian noise. The noise level of a measurement is the scale of the residuals: each fitted
record's RMS residual [N] at the posterior-median laws (`LawPosterior.residual_rms`). Not the
sampled noise level: with `noise="ar1"` on real records rho -> 1 and the marginal sigma is fixed
by little more than each record's first sample, often several times the residuals' RMS (a band
of that sigma covers everything); with `"iid"` the two agree. A fitted record (same label and
current) keeps its own level; a new record's is not known, and the rule (:data:`NOISE_RULE`)
pools the fitted records' levels relative to their force scale (max |F| measured; root mean
square) and scales the result by the new record's *predicted* force scale (max |F| of the median
laws' force on it: no measured force needed). The pool is the fitted records of the new record's
motion (same frequency and amplitude, at other currents) where there are any, else all of them.
Why relative: on real records the noise is model error, which grows with the force. Why by
motion: the model error depends on the motion more than on the current, and a band pooled over
every motion covers some held-out records far less than its level (`benchmarks/posterior.md`)."""

from __future__ import annotations

import dataclasses
import functools
import os
import warnings
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from .._warnings import ResultWarning, WarningKind
from ..bayes import (
    RHO,
    SIGMA,
    Posterior,
    PosteriorFront,
    PredictiveBand,
    arviz,
    at_bounds,
    predictive_band,
)
from ..data import JOINT_SAMPLES_PER_PERIOD, Batch, Condition, as_batch, check_mask, fit_mask, swarm_view
from ..engine import PosteriorPlan, register_posterior
from ._coding import Layout, bounded_box, build_objective, node_box
from ._joint import N_LEVELS, LawsProblem, node_names
from ._laws import Law, nodes
from ._model import GeneralizedModel
from ._rows import make_rows, record_order

#: How a new record's noise level is chosen (see the module notes).
NOISE_RULE = ("relative, by motion: the root mean square over the fitted records of the same "
              "frequency and amplitude (all, where none) of their RMS residual at the median "
              "laws / max|F measured|, times the new record's max|F| of the median laws")


@eqx.filter_jit
def _coefficients(coding, phi):
    """Law coefficients (S, V) of free node values (S, Q)."""
    return jax.vmap(lambda p: coding.coefficients(coding.from_free(p)[0]))(phi)


@eqx.filter_jit
def _params(lawset, coef, current):
    """Parameters (S, C, P) of coefficient draws (S, V) at the currents (C,) [A]."""
    return jax.vmap(lambda c: eqx.tree_at(lambda s: s.coef, lawset, c)(current))(coef)


def _layout(gm: GeneralizedModel) -> Layout:
    """The joint fit's layout of the laws of `gm`: nodes spread over its current range."""
    laws = [gm.laws[n] for n in gm.param_names]
    lo, hi = gm.current_range
    sizes = tuple(len(law.coefficients) for law in laws)
    return Layout(tuple(law.kind for law in laws), sizes,
                  tuple(nodes(lo, hi, s) for s in sizes),
                  tuple(float(law.scale or 1.0) for law in laws))


def coefficient_names(gm: GeneralizedModel) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """`(names, units)` of every law coefficient of `gm`, in `lawset` order: `name[m]`, the
    coefficient of $i^m$ (a `"sat"` law: `[0]` a, `[1]` b), in SI units per A^m (an `"exp"`
    law's act on the logarithm)."""
    out, units = [], []
    for n, u in zip(gm.param_names, gm.model.units):
        law = gm.laws[n]
        for m in range(len(law.coefficients)):
            out.append(f"{n}[{m}]")
            if law.kind == "sat":
                units.append(u)
            elif law.kind == "exp":
                units.append(f"log {u}" if m == 0 else f"1/A^{m}")
            else:
                units.append(u if m == 0 else f"{u}/A^{m}")
    return tuple(out), tuple(units)


def _constant_currents(batch: Batch) -> np.ndarray:
    """(C,) the records' constant currents [A]; InputError for a missing or varying one."""
    cur = np.asarray(batch.current, float)
    kind = np.asarray(batch.command_kind)
    for i in range(batch.n_conditions):
        if kind[i] > 0:
            raise InputError(f"record {batch.labels[i]!r} carries a per-sample command: the "
                             "posterior of laws of a time-varying command is not available")
        if not np.isfinite(cur[i]):
            raise InputError(f"record {batch.labels[i]!r} has no current: the laws need the "
                             "current of every record (give --current or a spec)")
    return cur


@dataclasses.dataclass(frozen=True, eq=False)
class LawPosterior(PosteriorFront):
    """The posterior of the laws of a `GeneralizedModel` (one unit: the whole data set).

    **Fields:** `posterior` the coefficients' draws (a :class:`mrjax.bayes.Posterior` with
    one unit `"laws"`, variables `name[m]` the coefficient of $i^m$, noise levels per
    record); `nodes` the sampled unknowns' draws (node values, with their box); `model` the
    `GeneralizedModel` the chains started from (its laws); `records` (R,) the labels of the
    records in the likelihood, `currents` (R,) [A], `force_scale` (R,) [N] (max |F|
    measured), `residual_rms` (R,) [N] (at the posterior-median laws: the noise level of
    the predictive band) and `motion` (R, 2) (frequency [Hz], amplitude [m]) of each;
    `data` (`"record"` or `"view"`) what the likelihood scored;
    `n_scored` (R,) samples per record.
    """

    posterior: Posterior
    nodes: Posterior
    model: GeneralizedModel
    records: tuple[str, ...]
    currents: np.ndarray
    force_scale: np.ndarray
    residual_rms: np.ndarray
    motion: np.ndarray
    data: str
    n_scored: np.ndarray

    @property
    def labels(self) -> tuple[str, ...]:
        """The labels of the records the laws were sampled on."""
        return self.records

    @functools.cached_property
    def idata(self) -> Any:
        """The draws as `arviz.InferenceData`: group `posterior` with one variable per model
        parameter, dims `chain`, `draw`, `<name>_coefficient` (the coefficient of $i^m$),
        `noise_sigma` (dim `record`) [N] and `noise_rho`; `sample_stats`; `constant_data` with
        each record's `current` [A], `force_scale` and `residual_rms` [N] (the band's noise)."""
        az = arviz()
        post, dims, coords = {}, {}, {"record": list(self.records)}
        th = self.posterior.theta[0]
        o = 0
        for n in self.model.param_names:
            k = len(self.model.laws[n].coefficients)
            post[n], dims[n] = th[..., o:o + k], [f"{n}_coefficient"]
            coords[f"{n}_coefficient"] = list(range(k))
            o += k
        post[SIGMA], dims[SIGMA] = self.posterior.sigma[0], ["record"]
        if self.posterior.rho is not None:
            post[RHO] = self.posterior.rho[0]
        p = self.posterior
        stats = {"diverging": p.diverging[0], "n_steps": p.n_steps[0],
                 "acceptance_rate": p.accept[0], "lp": p.lp[0]}
        const = {"current": np.asarray(self.currents, float),
                 "force_scale": np.asarray(self.force_scale, float),
                 "residual_rms": np.asarray(self.residual_rms, float),
                 "frequency": np.asarray(self.motion, float)[:, 0],
                 "amplitude": np.asarray(self.motion, float)[:, 1]}
        dims.update({k: ["record"] for k in const})
        gm = self.model
        attrs = {"kind": "laws", "model": gm.model.name, "noise": p.noise, "seed": p.seed,
                 "sampler": p.sampler.kernel.name, "warmup": int(p.sampler.warmup),
                 "likelihood_data": self.data, "noise_rule": NOISE_RULE,
                 "prior": "; ".join(f"{k}: {v}" for k, v in p.prior.items())
                 or "flat on the node values' box",
                 "laws": "; ".join(f"{n}: {gm.laws[n].formula('i')}" for n in gm.param_names)}
        return az.from_dict(posterior=post, sample_stats=stats, constant_data=const,
                            dims=dims, coords=coords, attrs=attrs)

    def to_dict(self) -> dict[str, Any]:
        """The `posterior` entry of fit.json: `kind: "laws"`, the summary per coefficient and
        record noise level, the records, their currents and force scales, the noise rule."""
        return dict(self.posterior.to_dict(), kind="laws", likelihood_data=self.data,
                    records=list(self.records),
                    currents_A=[float(c) for c in self.currents],
                    force_scale_N=[float(s) for s in self.force_scale],
                    residual_rms_N=[float(s) for s in self.residual_rms],
                    scored_samples=[int(n) for n in self.n_scored], noise_rule=NOISE_RULE)

    def draws(self, max_draws: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """`(coefficients (S, V), sigma (S, R) [N])`, chains pooled, at most `max_draws`
        spread evenly over them."""
        p = self.posterior
        coef = p.theta[0].reshape(-1, p.theta.shape[-1])
        sigma = p.sigma[0].reshape(-1, p.sigma.shape[-1])
        pick = _spread(coef.shape[0], max_draws)
        return coef[pick], sigma[pick]

    def law_values(self, current: ArrayLike, *, max_draws: int | None = 400) -> np.ndarray:
        """(S, C, P) the parameters [SI] at currents `current` (C,) [A] of S <= `max_draws`
        coefficient draws."""
        coef = self.draws(max_draws)[0]
        cur = np.atleast_1d(np.asarray(current, float))
        return np.asarray(_params(self.model.lawset, jnp.asarray(coef), jnp.asarray(cur)))

    def generalized(self) -> GeneralizedModel:
        """The `GeneralizedModel` of the coefficients' posterior medians."""
        return with_coefficients(self.model, np.median(self.draws()[0], axis=0))

    def band(self, batch: Batch, n_draws: int, level: float, noise_draws: int,
             seed: int) -> PredictiveBand:
        """The band of `PosteriorFront.predict_band`: the laws at each record's own (constant)
        current, new or fitted (see :func:`law_band`)."""
        return law_band(self.model, self.draws(n_draws)[0], self.residual_rms, self.records,
                        self.currents, self.force_scale, batch, motion=self.motion,
                        level=level, noise_draws=noise_draws, seed=seed)

    def __repr__(self) -> str:
        return (f"LawPosterior(model={self.model.model.name!r}, records={len(self.records)}, "
                f"data={self.data!r}, {self.posterior!r})")


def _spread(total: int, max_draws: int | None) -> np.ndarray:
    n = total if max_draws is None else min(int(max_draws), total)
    return np.unique(np.linspace(0, total - 1, n).round().astype(int))


def with_coefficients(gm: GeneralizedModel, coef: ArrayLike) -> GeneralizedModel:
    """`gm` with the law coefficients `coef` (V,) (`lawset` order), no uncertainty."""
    coef = np.asarray(coef, float)
    laws, o = {}, 0
    for n in gm.param_names:
        law = gm.laws[n]
        k = len(law.coefficients)
        laws[n] = Law(law.kind, coef[o:o + k], law.scale)
        o += k
    return dataclasses.replace(gm, laws=laws, uncertainty=None)


def law_band(
    gm: GeneralizedModel,
    coef: ArrayLike,
    noise: ArrayLike,
    records: Sequence[str],
    currents: ArrayLike,
    force_scale: ArrayLike,
    data: Batch | Condition | Sequence[Condition] | str | os.PathLike,
    *,
    motion: ArrayLike | None = None,
    level: float = 0.95,
    noise_draws: int = 4,
    seed: int = 0,
) -> PredictiveBand:
    """The posterior predictive force band of laws on records `data`, each at its constant
    current: every draw's coefficients -> parameters at the record's current -> force, plus
    Gaussian noise (`mrjax.bayes.predictive_band`). A record of the likelihood (same label
    and current) keeps its own noise level; any other gets the rule :data:`NOISE_RULE` (see
    the module notes).

    **Arguments:** `gm` the laws' form (kinds, sizes, scales); `coef` (S, V) coefficient
    draws; `noise` (R,) [N] the noise levels (RMS residuals) of the R `records` at `currents`
    (R,) [A] with force scales `force_scale` (R,) [N]; `data` the records to predict;
    `motion` (R, 2) the fitted records' frequency [Hz] and amplitude [m] (None: the rule
    pools every record); `level` in (0, 1);
    `noise_draws` per draw; `seed` of the noise.

    **Returns:** a :class:`mrjax.bayes.PredictiveBand`.

    Raises :class:`mrjax.InputError` for a record without a constant current, a bad level
    or shapes that do not match.
    """
    coef, noise = np.asarray(coef, float), np.asarray(noise, float)
    scale = np.asarray(force_scale, float)
    fitted_cur = np.asarray(currents, float)
    R = len(records)
    if coef.ndim != 2 or noise.shape != (R,) or scale.shape != (R,) \
            or fitted_cur.shape != (R,):
        raise InputError("law draws do not match: coefficients (S, V) and R records with "
                         "their noise levels, currents and force scales (R,)")
    batch = as_batch(data)
    cur = _constant_currents(batch)
    lo, hi = gm.current_range
    out = np.flatnonzero((cur < lo - 1e-9) | (cur > hi + 1e-9))
    if out.size:
        warnings.warn(f"{out.size} record(s) outside the laws' current range [{lo:g}, {hi:g}] "
                      f"A (first {batch.labels[out[0]]!r} at {cur[out[0]]:g} A): the band "
                      "extrapolates the laws", RuntimeWarning, stacklevel=2)
    theta = np.moveaxis(np.asarray(_params(gm.lawset, jnp.asarray(coef), jnp.asarray(cur))),
                        0, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel2 = (noise / np.where(scale > 0, scale, np.nan)) ** 2
    mot = np.full((R, 2), np.nan) if motion is None else np.asarray(motion, float)
    new_mot = np.column_stack([np.asarray(batch.frequency, float),
                               np.asarray(batch.amplitude, float)])
    pred = with_coefficients(gm, np.median(coef, axis=0)).predict(batch)
    m = np.asarray(batch.mask, bool)
    pred_scale = np.max(np.where(m, np.abs(pred), 0.0), axis=1)
    pos = {lab: r for r, lab in enumerate(records)}
    sig = np.empty((batch.n_conditions, coef.shape[0]))
    for c, lab in enumerate(batch.labels):
        r = pos.get(lab)
        own = r is not None and abs(fitted_cur[r] - cur[c]) <= 1e-9
        if own:
            sig[c] = noise[r]
            continue
        same = np.all(np.isclose(mot, new_mot[c], rtol=1e-3, atol=0.0), axis=1)
        pool = rel2[same] if same.any() else rel2
        sig[c] = float(np.sqrt(np.nanmean(pool))) * pred_scale[c]
    return predictive_band(gm.model, theta, sig, batch.labels, batch, level=level,
                           noise_draws=noise_draws, seed=seed)


def read_law_draws(path: str | os.PathLike, gm: GeneralizedModel, *, max_draws: int = 200
                   ) -> tuple[np.ndarray, np.ndarray, tuple[str, ...], np.ndarray, np.ndarray]:
    """Law draws from a `posterior.nc` of a laws' posterior (`mrjax fit --generalize
    ... --posterior`): `(coef (S, V), residual_rms (R,) [N], records (R,), currents (R,) [A],
    force_scale (R,) [N], motion (R, 2) [Hz, m])` (the arguments of :func:`law_band`),
    S <= `max_draws` spread over chains and draws.

    Raises :class:`mrjax.InputError` for a file that is not a posterior of these laws."""
    import xarray as xr

    try:
        with xr.open_dataset(path, group="posterior", engine="h5netcdf") as ds, \
                xr.open_dataset(path, group="constant_data", engine="h5netcdf") as cd:
            parts = []
            for n in gm.param_names:
                k = len(gm.laws[n].coefficients)
                dim = f"{n}_coefficient"
                if n not in ds or dim not in ds[n].dims or ds.sizes[dim] != k:
                    raise InputError(f"{path}: not a posterior of these laws ({n!r} with "
                                     f"{k} coefficient(s) missing)")
                v = ds[n].transpose("chain", "draw", dim).values
                parts.append(np.asarray(v, float).reshape(-1, k))
            coef = np.concatenate(parts, axis=1)
            records = tuple(str(v) for v in ds["record"].values)
            currents = np.asarray(cd["current"].values, float)
            scale = np.asarray(cd["force_scale"].values, float)
            noise = np.asarray(cd["residual_rms"].values, float)
            motion = np.column_stack([np.asarray(cd[k].values, float)
                                      for k in ("frequency", "amplitude")])
    except (OSError, ValueError, KeyError) as e:
        raise InputError(f"{path}: cannot read the laws' posterior ({e})") from None
    pick = _spread(coef.shape[0], max_draws)
    return coef[pick], noise, records, currents, scale, motion


def law_posterior_plan(gm: GeneralizedModel, batch: Batch, likelihood_data: str | None
                       ) -> PosteriorPlan:
    """The posterior plan of laws over the current on records `batch` at constant currents:
    the laws' problem (one row per record, on the records or their views), the free node
    values of the laws as the optimum, the view for a dynamic model by default. Warns for
    laws that are not a joint optimum and node values at their bounds. Raises
    :class:`mrjax.InputError` for laws of a time-varying command or a voltage, and records
    without a constant current."""
    if gm.lag is not None or gm.command_unit != "A":
        raise InputError("the posterior of laws of a time-varying command (lag or voltage) is "
                         "not available; laws over a constant current only")
    model = gm.model
    cur = _constant_currents(batch)
    layout = _layout(gm)
    z_scale = model.scale_symmetry is not None
    if z_scale:  # the joint fit's z-scale: delta = beta + gamma at u0
        gm = gm.with_canonical_z(layout.nodes[model.param_names.index(
            model.scale_symmetry.gauge)][0])
    coef0 = np.concatenate([np.asarray(gm.laws[n].coefficients, float)
                            for n in gm.param_names])
    obj = build_objective(model, layout, layout.V @ coef0, z_scale=z_scale)
    coding = obj.coding
    choice = likelihood_data or ("view" if model.dynamic else "record")
    m = check_mask(batch, None if gm.transient is None else fit_mask(batch, gm.transient))
    scale = np.max(np.where(m, np.abs(np.asarray(batch.force, float)), 0.0), axis=1)
    full, order = make_rows(batch, m, cur), record_order(m)
    view, m_like, order_like = None, m, order
    if choice == "view":
        v = swarm_view(batch, samples_per_period=JOINT_SAMPLES_PER_PERIOD)
        m_like = np.asarray(v.mask, bool) & np.asarray(v.batch.mask, bool)
        view, order_like = make_rows(v.batch, m_like, cur), record_order(m_like)
    lm_lo, lm_hi = bounded_box(model, layout, coding, *model.bounds)
    D = coding.n_position
    labels = tuple(batch.labels[i] for i in order_like)
    problem = LawsProblem(model, layout, obj, lm_lo[:D], lm_hi[:D], lm_lo, lm_hi, full, view,
                          np.linspace(cur.min(), cur.max(), N_LEVELS),
                          row_labels=(tuple(batch.labels[i] for i in order), labels))
    free = list(coding.free)
    phi0 = np.asarray(coding.free_of(np.asarray(layout.V @ coef0), 0.0), float)
    _check_laws(gm, phi0, layout, free)

    def finish(post: Posterior) -> LawPosterior:
        return _law_result(gm, coding, post, batch, m, cur, scale, labels, order_like, choice,
                           m_like)

    return PosteriorPlan(problem, phi0[None], choice == "view", finish)


def _check_laws(gm: GeneralizedModel, phi0: np.ndarray, layout: Layout, free: list[int]):
    """Warnings: laws that are not a joint optimum; node values at their bounds."""
    if gm.method != "joint":
        warnings.warn(ResultWarning(
            WarningKind.DOUBTFUL_START, f"posterior of {gm.method} laws: the chains start from "
            "them, not from the joint least-squares optimum, and need a longer warmup"),
            stacklevel=5)
    lo, hi = node_box(gm.model, layout, *gm.model.bounds)
    hit = at_bounds(phi0[None], lo[free][None], hi[free][None])[0]
    if hit.any():
        names = node_names(gm.model, layout, free)[0]
        warnings.warn(ResultWarning(
            WarningKind.AT_BOUND, f"{int(hit.sum())} law node value(s) at the bounds (first: "
            f"{names[int(np.argmax(hit))]}): their posterior is cut by the bound",
            parameters=[names[k] for k in np.flatnonzero(hit)]), stacklevel=5)


def _law_result(gm, coding, post: Posterior, batch, m, cur, scale, labels, order, choice,
                m_like) -> LawPosterior:
    """The :class:`LawPosterior` of the node values' draws `post`: the coefficients' draws,
    the warnings, each record's residual RMS at the posterior-median laws."""
    Q = len(coding.free)
    C, N = post.n_chains, post.n_draws
    coef = np.asarray(_coefficients(coding, jnp.asarray(post.theta[0].reshape(-1, Q))))
    coef = coef.reshape(1, C, N, -1)
    coef0 = np.concatenate([np.asarray(gm.laws[n].coefficients, float)
                            for n in gm.param_names])
    cnames, cunits = coefficient_names(gm)
    V = len(cnames)
    cpost = dataclasses.replace(
        post, names=cnames, theta=coef, theta0=coef0[None], lower=np.full((1, V), -np.inf),
        upper=np.full((1, V), np.inf), free=np.ptp(coef.reshape(-1, V), axis=0) > 0,
        param_units=cunits, linear=())
    for w in cpost.problems() + [w for w in post.problems()
                                  if w.kind == WarningKind.BEYOND_BOUNDS]:
        warnings.warn(w, stacklevel=4)
    # the band's noise levels: the residuals' RMS of every record at the median laws
    med = with_coefficients(gm, np.median(coef.reshape(-1, V), axis=0))
    rms = np.asarray(med.evaluate(batch, mask=m)["rms"], float)
    return LawPosterior(posterior=cpost, nodes=post, model=gm, records=labels,
                        currents=cur[order], force_scale=scale[order],
                        residual_rms=rms[order], motion=np.column_stack(
                            [np.asarray(batch.frequency, float),
                             np.asarray(batch.amplitude, float)])[order],
                        data=choice, n_scored=m_like.sum(axis=1)[order])


register_posterior(GeneralizedModel, law_posterior_plan)
