"""The posterior predictive force band of parameter draws on records, and the draws read back
from a `posterior.nc`."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ..data import Batch, Condition, as_batch
from ..models import AbstractModel, resolve_model


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
