"""The per-test kind of the posterior: `mrjax.posterior` on a `mrjax.fit` result.

Each condition is one unit of `mrjax.bayes.sample`: its unknowns are the model's parameters in
the fit's bounds, its residuals those of `mrjax.objective.residuals` (the model's `force`,
dynamic models integrated with the sub-steps of `mrjax.models.resolve_model` as the polish
does), one record per unit.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ..data import Batch, Condition, as_batch, fit_mask, swarm_view
from ..fitting import FitResult
from ..generalize import Z_SCALE_MODELS, GeneralizedModel
from ..models import AbstractModel, check_bounds, exact_tangent, resolve_model
from ..objective import residuals
from ._noise import check_noise
from ._priors import at_bounds
from ._result import Posterior, PosteriorFront
from ._sampler import CHAINS, DRAWS, WARMUP, Sampler, sample

if TYPE_CHECKING:  # `_laws` builds on this module
    from ._laws import LawPosterior

#: The unknown held first where the records leave a direction undetermined, in the models of
#: `mrjax.generalize.Z_SCALE_MODELS` (their z scale: Spencer's A, a common choice to fix).
GAUGE: tuple[str, ...] = ("delta",)
#: What the likelihood scores: the full `record`, or the swarm's `view` of it (every k-th
#: sample, the first whole periods; see `mrjax.fitting.swarm_view`).
DATA_CHOICES: tuple[str, ...] = ("record", "view")


class PerTestResidual(eqx.Module):
    """Residual function of one condition for `mrjax.bayes.sample`: one block of one record,
    `model.force - force` [N] on the scored samples (`mrjax.objective.residuals`)."""

    model: AbstractModel

    def __call__(self, theta, unit):
        x, xdot, dt, force, mask = unit
        r = residuals(self.model, theta, x, xdot, dt, force, mask)
        return ((r[None, :], mask[None, :]),)


@dataclasses.dataclass(frozen=True, eq=False)
class PredictiveBand:
    """Posterior predictive force band on records (host arrays, C conditions x T samples).

    **Fields:** `labels` (C,); `t` (C, T) [s]; `measured` (C, T) [N]; `mask` (C, T) scored
    samples; `median` (C, T) [N] of the model force; `lower`, `upper` (C, T) [N] the central
    `level` band of a new measurement (model force plus the noise of each draw);
    `force_lower`, `force_upper` (C, T) [N] the band of the model force alone (parameter
    uncertainty); `level`; `coverage` (C,) the fraction of scored measured samples inside the
    predictive band (a calibrated band covers about `level`); `force_coverage` (C,) inside the
    force band; `nrmse` (C,) of the median force.
    """

    labels: tuple[str, ...]
    t: np.ndarray
    measured: np.ndarray
    mask: np.ndarray
    median: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    force_lower: np.ndarray
    force_upper: np.ndarray
    level: float
    coverage: np.ndarray
    force_coverage: np.ndarray
    nrmse: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        """Per condition: label, coverage of the predictive and of the force band, NRMSE."""
        return {"level": self.level, "conditions": [
            {"label": lab, "coverage": float(c), "force_coverage": float(fc), "nrmse": float(e)}
            for lab, c, fc, e in zip(self.labels, self.coverage, self.force_coverage,
                                     self.nrmse)]}


@eqx.filter_jit
def _forces(model, thetas, x, xdot, dt):
    """Forces (S, T) of S parameter draws on one record (compiled once per shape)."""
    return jax.vmap(lambda th: model.force(th, x, xdot, dt))(thetas)


@dataclasses.dataclass(frozen=True, eq=False)
class TestPosterior(PosteriorFront):
    """The posterior of a per-test fit: `posterior` (a :class:`mrjax.bayes.Posterior` over the
    conditions), the `model`, the `fit` it started from, and `data` (`"record"` or `"view"`,
    what the likelihood scored), `n_scored` (C,) samples it scored."""

    posterior: Posterior
    model: AbstractModel
    fit: FitResult
    data: str
    n_scored: np.ndarray

    @property
    def labels(self) -> tuple[str, ...]:
        """Condition labels."""
        return self.posterior.labels

    def to_dict(self) -> dict[str, Any]:
        """The `posterior` entry of fit.json (with `likelihood_data`)."""
        return dict(self.posterior.to_dict(), likelihood_data=self.data,
                    scored_samples=[int(n) for n in self.n_scored])

    def predict_band(
        self,
        data: Batch | Condition | Sequence[Condition] | str | os.PathLike,
        *,
        level: float = 0.95,
        n_draws: int = 200,
        noise_draws: int = 4,
        seed: int = 0,
    ) -> PredictiveBand:
        """The posterior predictive force band of each condition on records `data` (see
        :func:`predictive_band`), from `n_draws` draws spread evenly over the chains.

        **Returns:** a :class:`PredictiveBand` with the coverage of the measured force.
        """
        if n_draws < 1:
            raise InputError("n_draws must be positive")
        post = self.posterior
        total = post.n_chains * post.n_draws
        pick = np.unique(np.linspace(0, total - 1, min(n_draws, total)).round().astype(int))
        theta = post.theta.reshape(post.n_units, total, -1)[:, pick]
        sigma = post.sigma.reshape(post.n_units, total)[:, pick]
        return predictive_band(self.model, theta, sigma, self.labels, data, level=level,
                               noise_draws=noise_draws, seed=seed)

    def __repr__(self) -> str:
        return (f"TestPosterior(model={self.model.name!r}, C={len(self.labels)}, "
                f"data={self.data!r}, {self.posterior!r})")


def _match(labels: Sequence[str], wanted: Sequence[str]) -> np.ndarray:
    """Index into `labels` of each of `wanted`: by label, else by position if counts match."""
    pos = {lab: i for i, lab in enumerate(labels)}
    if all(w in pos for w in wanted):
        return np.array([pos[w] for w in wanted], int)
    if len(wanted) == len(labels):
        return np.arange(len(labels))
    missing = [w for w in wanted if w not in pos]
    raise InputError(f"record {missing[0]!r} matches no condition of the posterior "
                     f"({len(labels)} conditions, e.g. {labels[0]!r})")


def predictive_band(
    model: AbstractModel,
    theta: ArrayLike,
    sigma: ArrayLike,
    labels: Sequence[str],
    data: Batch | Condition | Sequence[Condition] | str | os.PathLike,
    *,
    level: float = 0.95,
    noise_draws: int = 4,
    seed: int = 0,
) -> PredictiveBand:
    """The posterior predictive force band on records `data`.

    Each record is predicted with the draws of the condition of the same label (or, if the
    labels differ, of the same position when the counts match): every draw's model force
    plus `noise_draws` Gaussian noise samples of its own noise level (an AR(1) process has the
    same marginal), and the band is their central `level` interval at every sample.

    **Arguments:** `model`; `theta` (U, S, P) parameter draws [SI] and `sigma` (U, S) their
    noise levels [N] of the U conditions `labels`; `data` the records; `level` in (0, 1);
    `noise_draws`; `seed` of the noise samples.

    **Returns:** a :class:`PredictiveBand` with the coverage of the measured force.

    Raises :class:`mrjax.InputError` for a level outside (0, 1), a non-positive count, or
    records that match no condition.
    """
    if not 0.0 < float(level) < 1.0:
        raise InputError(f"band level must be in (0, 1), got {level!r}")
    if noise_draws < 1:
        raise InputError("noise_draws must be positive")
    theta, sigma = np.asarray(theta, float), np.asarray(sigma, float)
    batch = as_batch(data)
    idx = _match(tuple(labels), batch.labels)
    rows = theta[idx].reshape(-1, theta.shape[-1])
    run_model = resolve_model(model, rows, batch.xdot, batch.dt, batch.mask)
    rng = np.random.default_rng(seed)
    q = (50.0 * (1.0 - level), 50.0, 50.0 * (1.0 + level))
    out: dict[str, list] = {k: [] for k in ("median", "lower", "upper", "force_lower",
                                             "force_upper")}
    for c, i in enumerate(idx):
        F = np.asarray(_forces(run_model, jnp.asarray(theta[i]), batch.x[c], batch.xdot[c],
                               batch.dt[c]))
        lo_f, med, hi_f = np.percentile(F, q, axis=0)
        y = F[:, None, :] + sigma[i][:, None, None] * rng.standard_normal(
            (F.shape[0], noise_draws, F.shape[1]))
        lo, hi = np.percentile(y.reshape(-1, F.shape[1]), (q[0], q[2]), axis=0)
        for k, v in zip(out, (med, lo, hi, lo_f, hi_f)):
            out[k].append(v)
    arr = {k: np.stack(v) for k, v in out.items()}
    meas, mask = np.asarray(batch.force, float), np.asarray(batch.mask, bool)
    n = np.maximum(mask.sum(axis=1), 1)

    def inside(lo, hi):
        return np.sum(mask & (meas >= lo) & (meas <= hi), axis=1) / n

    fmax = np.max(np.where(mask, np.abs(meas), 0.0), axis=1)
    rms = np.sqrt(np.sum(np.where(mask, arr["median"] - meas, 0.0) ** 2, axis=1) / n)
    with np.errstate(invalid="ignore", divide="ignore"):
        nrmse = rms / np.where(fmax > 0, fmax, np.nan)
    return PredictiveBand(
        labels=tuple(batch.labels), t=np.asarray(batch.t, float), measured=meas, mask=mask,
        level=float(level), coverage=inside(arr["lower"], arr["upper"]),
        force_coverage=inside(arr["force_lower"], arr["force_upper"]), nrmse=nrmse, **arr)


def read_draws(path: str | os.PathLike, names: Sequence[str], *,
               max_draws: int = 200) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Parameter draws from a `posterior.nc` (of `mrjax fit --posterior`): `(labels (U,),
    theta (U, S, P), sigma (U, S))`, S <= `max_draws` spread evenly over chains and draws.

    Raises :class:`mrjax.InputError` for a file that is not such a posterior."""
    import xarray as xr

    try:
        with xr.open_dataset(path, group="posterior", engine="h5netcdf") as ds:
            missing = [n for n in (*names, "noise_sigma") if n not in ds]
            if missing or "condition" not in ds.dims:
                raise InputError(f"{path}: not a per-test posterior of these parameters "
                                 f"(missing {missing[:3] or ['condition']})")
            labels = tuple(str(v) for v in ds["condition"].values)
            stack = lambda v: np.moveaxis(np.asarray(v.transpose("chain", "draw", "condition")
                                                     .values, float), -1, 0).reshape(
                len(labels), -1)
            theta = np.stack([stack(ds[n]) for n in names], axis=-1)
            sigma = stack(ds["noise_sigma"])
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read the posterior ({e})") from None
    total = theta.shape[1]
    pick = np.unique(np.linspace(0, total - 1, min(max_draws, total)).round().astype(int))
    return labels, theta[:, pick], sigma[:, pick]


def _check_start(result: FitResult, lo: np.ndarray, hi: np.ndarray) -> None:
    """Warnings: a fit without polish; parameters at their bounds. An error: parameters
    outside the bounds (a fit with other bounds)."""
    names = result.param_names
    th = np.asarray(result.theta, float)
    tol = 1e-9 * np.maximum(hi - lo, 1e-300)
    out = (th < lo - tol) | (th > hi + tol)
    if out.any():
        i, j = np.argwhere(out)[0]
        raise InputError(f"condition {result.labels[i]!r}: {names[j]} = {th[i, j]:g} lies "
                         f"outside the bounds [{lo[j]:g}, {hi[j]:g}]: pass the fit's bounds")
    if result.method == "pso" or all(s == "none" for s in result.polish_status):
        warnings.warn("posterior on a fit without polish: the chains start from the swarm's "
                      "best, not from a least-squares optimum, and need a longer warmup",
                      RuntimeWarning, stacklevel=3)
    hit = at_bounds(th, lo, hi)
    if hit.any():
        i, j = np.argwhere(hit)[0]
        warnings.warn(f"{int(hit.sum())} parameter(s) at bounds in {int(hit.any(axis=1).sum())} "
                      f"condition(s) (first: {names[j]} = {th[i, j]:g} on {result.labels[i]!r}): "
                      "their posterior is cut by the bound (a prior the data did not choose)",
                      RuntimeWarning, stacklevel=3)


def posterior(
    result: FitResult | GeneralizedModel,
    data: Batch | Condition | Sequence[Condition] | str | os.PathLike,
    *,
    draws: int = DRAWS,
    chains: int = CHAINS,
    warmup: int = WARMUP,
    noise: str = "iid",
    prior: Mapping[str, Any] | None = None,
    key: ArrayLike | None = None,
    seed: int = 0,
    likelihood_data: str | None = None,
    bounds: tuple[Any, Any] | None = None,
    transient: float | str | None = None,
    sampler: Sampler | None = None,
    progress: bool | None = False,
) -> TestPosterior | LawPosterior:
    """The posterior of a per-test fit's parameters on every condition, or of the laws of a
    `GeneralizedModel` over the current (:func:`mrjax.bayes.law_posterior`, which this calls
    with the same options: it returns a :class:`mrjax.bayes.LawPosterior`), by NUTS.

    **Arguments:**

    - `result`: a `mrjax.fit` result (the polished optimum the search for the posterior's
        mode starts from; the chains start around the mode, with the inverse Hessian there as
        mass matrix, see `mrjax.bayes.sample`).
    - `data`: the conditions it was fitted on (same labels), as `mrjax.fit` takes them.
    - `draws`, `chains`, `warmup`: kept draws per chain, chains per condition, adaptation
        steps per chain (see `mrjax.bayes.Sampler`; `sampler` overrides all three; where its
        `gradient` is None, a dynamic model is differentiated in forward mode).
    - `noise`: `"iid"` (independent Gaussian residuals) or `"ar1"` (AR(1), rho fitted per
        condition: use it on real records, whose model error is correlated; see
        `mrjax.bayes.block_loglik`). One noise level per condition in both.
    - `prior`: {parameter: prior}, `mrjax.bayes.Normal` / `LogNormal` / `Uniform` or text such
        as `"normal:3000:300"`; default flat on the bounds.
    - `key`, `seed`: the PRNG key (default `jax.random.key(seed)`): same key, same draws.
    - `likelihood_data`: `"record"` (every scored sample) or `"view"` (the swarm's view: every
        k-th sample of the first whole periods, `mrjax.fitting.swarm_view`). Default (None):
        `"view"` for the dynamic models, `"record"` for the static ones. Measured on the 30
        UTFSM tests (`benchmarks/posterior.md`): the tanh model's record likelihood costs
        seconds per thousand draws, so it keeps the record; a dynamic model's gradient is
        one sequential integration (modified Bouc-Wen on one 19,000-sample record: about 19 x
        the view's cost), and with the AR(1) noise the view's intervals match the record's
        (the record's extra samples are correlated model error that carries little new
        information), so the dynamic models use the view.
    - `bounds`: the fit's bounds `(lower, upper)` as `mrjax.fit` takes them (default the
        model's): the uniform prior's box.
    - `transient`: the fit's `transient` (the same samples are scored).
    - `progress`: a progress bar (None: only on a TTY).

    **Returns:** a :class:`TestPosterior` (laws: a :class:`mrjax.bayes.LawPosterior`).

    Warns (`RuntimeWarning`) for a fit without polish, parameters at their bounds, and chains
    that did not converge (R-hat > 1.01, ESS < 400, divergent transitions). Raises
    :class:`mrjax.InputError` for impossible options (draws <= 0, unknown noise model or data
    choice, bad priors) and for data that are not the fit's conditions.
    """
    if isinstance(result, GeneralizedModel):  # the joint-laws kind
        from ._laws import law_posterior  # here: `_laws` builds on this module

        if bounds is not None:
            raise InputError("bounds do not apply to laws: their node values are kept within "
                             "the model's bounds")
        mask = None if transient is None else fit_mask(as_batch(data), transient)
        return law_posterior(result, data, draws=draws, chains=chains, warmup=warmup,
                             noise=noise, prior=prior, key=key, seed=seed,
                             likelihood_data=likelihood_data, mask=mask, sampler=sampler,
                             progress=progress)
    if not isinstance(result, FitResult):
        raise InputError(f"posterior needs a mrjax.fit result (FitResult) or laws over the "
                         f"current (GeneralizedModel), got {type(result).__name__}")
    model = result.model
    # a dynamic model's residuals are one sequential integration: forward mode (see Sampler)
    sampler = (sampler or Sampler(draws=draws, chains=chains, warmup=warmup)).for_model(
        model.dynamic).check()
    check_noise(noise)
    if likelihood_data is not None and likelihood_data not in DATA_CHOICES:
        raise InputError(f"likelihood_data must be one of {', '.join(DATA_CHOICES)}, got "
                         f"{likelihood_data!r}")
    batch = as_batch(data)
    if tuple(batch.labels) != tuple(result.labels):
        raise InputError(f"data are not the fit's conditions: {batch.n_conditions} records "
                         f"(first {batch.labels[0]!r}) for {result.n_conditions} fitted "
                         f"(first {result.labels[0]!r})")
    lo, hi = check_bounds(model, bounds)
    _check_start(result, lo, hi)
    choice = likelihood_data or ("view" if model.dynamic else "record")
    mask = fit_mask(batch, transient)
    if choice == "view":
        view = swarm_view(batch, transient)
        batch, mask = view.batch, view.mask
    n_scored = np.asarray(mask).sum(axis=1)
    theta0 = np.clip(np.asarray(result.theta, float), lo, hi)
    run_model = resolve_model(model, theta0, batch.xdot, batch.dt, batch.mask)
    units = (batch.x, batch.xdot, batch.dt, batch.force, jnp.asarray(mask))
    post = sample(PerTestResidual(run_model), theta0, units, lower=lo, upper=hi,
                  names=model.param_names, labels=batch.labels, sampler=sampler,
                  noise=noise, prior=prior, key=key, seed=seed, progress=progress,
                  units=model.units, gauge=GAUGE if model.name in Z_SCALE_MODELS else (),
                  exact=None if (exact := exact_tangent(run_model)) is None
                  else PerTestResidual(exact), linear=model.fixed_params)
    for line in post.problems():
        warnings.warn(line, RuntimeWarning, stacklevel=2)
    return TestPosterior(posterior=post, model=model, fit=result, data=choice,
                         n_scored=n_scored)
