"""`GeneralizedModel`: a damper model whose parameters are laws of the coil current."""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InputError
from ..data import Batch
from ..fitting import as_batch
from ..models import AbstractModel, get, resolve_model
from ..objective import check_mask, masked_rms, nrmse
from ._laws import Law, LawSet, lag_current


# ------------------------------------------------------------------------------ the result
@dataclasses.dataclass(frozen=True, eq=False)
class GeneralizedModel:
    """A damper model whose parameters are laws of the coil current.

    **Fields:**

    - `model`: the :class:`mrjax.models.AbstractModel`.
    - `laws`: parameter name -> :class:`Law`, in `model.param_names` order.
    - `method`: `"two-step"` or `"joint"`.
    - `total_rms`: RMS force error [N] over all scored samples of all conditions of the data it
        was built on.
    - `current_range`: `(min, max)` current [A] of those data (the laws' range of validity).
    - `weighting`: how the two-step stage weighted the per-condition parameters
        (`"covariance"` or `"equal"`; `""` when built from a dict).
    - `support`: plotting data of the two-step stage (see :meth:`curves`), or None.
    - `info`: diagnostics (two-step total RMS, swarm and polish statistics, timings [s]).
    """

    model: AbstractModel
    laws: dict[str, Law]
    method: str
    total_rms: float
    current_range: tuple[float, float]
    weighting: str = ""
    support: dict[str, Any] | None = None
    info: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        model = get(self.model)
        object.__setattr__(self, "model", model)
        if not isinstance(self.laws, Mapping):
            raise InputError("laws must be a mapping from parameter name to Law")
        names = model.param_names
        unknown = sorted(set(self.laws) - set(names))
        missing = [n for n in names if n not in self.laws]
        if unknown or missing:
            raise InputError(f"laws of model {model.name!r}: unknown parameters {unknown}, missing "
                             f"{missing}; expected {list(names)}")
        laws = {}
        for n in names:
            law = self.laws[n]
            laws[n] = law if isinstance(law, Law) else Law.from_dict(law, n)
        object.__setattr__(self, "laws", laws)
        method = str(self.method).replace("_", "-")
        if method not in ("two-step", "joint"):
            raise InputError(f"method must be 'two-step' or 'joint', got {self.method!r}")
        object.__setattr__(self, "method", method)
        try:
            lo, hi = (float(v) for v in self.current_range)
        except (TypeError, ValueError):
            raise InputError(f"current_range must be (min, max) in A, got "
                             f"{self.current_range!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise InputError(f"current_range must be finite with min <= max, got {(lo, hi)}")
        object.__setattr__(self, "current_range", (lo, hi))
        object.__setattr__(self, "total_rms", float(self.total_rms))

    # ----------------------------------------------------------------------------- access
    @property
    def param_names(self) -> tuple[str, ...]:
        """Parameter names, in vector order."""
        return self.model.param_names

    @functools.cached_property
    def _lawset(self) -> LawSet:
        laws = [self.laws[n] for n in self.param_names]
        # a NumPy constant: safe to create inside a trace (no leaked tracer in the cache)
        coef = np.concatenate([np.asarray(law.coefficients, float) for law in laws])
        return LawSet(coef, tuple(law.kind for law in laws),
                       tuple(len(law.coefficients) for law in laws))

    def params_at(self, current: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape P"]:
        """Parameters (..., P) at `current` [A] of any shape (scalar, (C,), (T,), ...), SI
        units, `param_names` order. Pure JAX: traceable and differentiable in `current`."""
        return self._lawset(current)

    def coefficients(self, name: str) -> tuple[float, ...]:
        """Coefficients of parameter `name`'s law, ascending powers of i."""
        if name not in self.laws:
            raise InputError(f"unknown parameter {name!r}; model {self.model.name!r} has "
                             f"{list(self.param_names)}")
        return self.laws[name].coefficients

    # ----------------------------------------------------------------------------- simulate
    def _resolved(self, currents: np.ndarray, xdot, dt, mask=None) -> AbstractModel:
        """The model with its sub-steps fixed on the host for the currents in use (the laws
        at 9 currents spanning them) on data `xdot`, `dt` (`mask`: the real samples)."""
        m = self.model
        if not m.dynamic or m.substeps is not None:
            return m
        c = np.asarray(currents, float)
        c = c[np.isfinite(c)]
        lo, hi = (float(c.min()), float(c.max())) if c.size else self.current_range
        rows = np.asarray(self.params_at(np.linspace(lo, hi, 9)))
        return resolve_model(m, rows, xdot, dt, mask)

    def force(
        self,
        x: Float[ArrayLike, " T"],
        xdot: Float[ArrayLike, " T"],
        dt: Float[ArrayLike, "*T"],
        current: Float[ArrayLike, "*T"],
        *,
        lag: float | None = None,
    ) -> Float[Array, " T"]:
        """Force [N] of one record at a constant or time-varying current.

        **Arguments:**

        - `x` [m], `xdot` [m/s]: the record, (T,).
        - `dt`: sample interval [s], scalar or (T,) (the interval after each sample).
        - `current`: coil current [A], scalar or per sample (T,).
        - `lag`: $\\eta$ [1/s] of the first-order current lag $\\dot u = -\\eta(u - i)$
            (:func:`lag_current`), or None for none.

        **Returns:** force (T,) [N]. A scalar current without lag uses one parameter vector;
        otherwise the parameters are per sample (T, P).
        """
        x, xdot = jnp.asarray(x, float), jnp.asarray(xdot, float)
        if x.ndim != 1 or xdot.shape != x.shape:
            raise InputError(f"x and xdot must have the same shape (T,), got {x.shape} and "
                             f"{xdot.shape}")
        cur = jnp.asarray(current, float)
        if cur.ndim not in (0, 1) or (cur.ndim == 1 and cur.shape != x.shape):
            raise InputError(f"current must be a scalar or have the shape of x {x.shape}, "
                             f"got {cur.shape}")
        lag = check_lag(lag)
        concrete = not any(isinstance(a, jax.core.Tracer) for a in (x, xdot, dt, cur))
        model = self._resolved(np.asarray(cur), np.asarray(xdot), np.asarray(dt)) if concrete \
            else self.model
        return force_one(model, self._lawset, x, xdot, jnp.asarray(dt, float), cur,
                          jnp.asarray(0.0 if lag is None else lag), lag is not None)

    def _batch_currents(self, batch: Batch, current) -> np.ndarray:
        C, T = batch.n_conditions, batch.length
        if current is None:
            cur = np.asarray(batch.current, float)
            bad = np.flatnonzero(~np.isfinite(cur))
            if bad.size:
                raise InputError(f"condition {batch.labels[bad[0]]!r} has no current; pass "
                                 "current=")
            return cur
        cur = np.asarray(current, float)
        if cur.ndim == 0:
            cur = np.full(C, float(cur))
        if cur.shape not in ((C,), (C, T)):
            raise InputError(f"current must be a scalar, (C,) = ({C},) or (C, T) = ({C}, {T}), "
                             f"got {cur.shape}")
        if not np.all(np.isfinite(cur)):
            raise InputError("current must be finite")
        return cur

    def predict(
        self, batch: Batch, *, current: ArrayLike | None = None, lag: float | None = None
    ) -> np.ndarray:
        """Force [N] of every condition of `batch`, (C, T) NumPy (padding included).

        **Arguments:** `batch` any conditions (a `mrjax.data.Batch`, or what `mrjax.fit`
        accepts); `current` [A]: None (each condition's own current), a scalar, (C,), or per
        sample (C, T); `lag`: $\\eta$ [1/s] of the current lag (per-sample parameters).
        """
        batch = as_batch(batch)
        cur = self._batch_currents(batch, current)
        lag = check_lag(lag)
        model = self._resolved(cur, batch.xdot, batch.dt, batch.mask)
        per_sample = cur.ndim == 2 or lag is not None
        if cur.ndim == 1 and per_sample:
            cur = np.broadcast_to(cur[:, None], (batch.n_conditions, batch.length))
        f = force_batch(model, self._lawset, batch.x, batch.xdot, batch.dt, jnp.asarray(cur),
                         jnp.asarray(0.0 if lag is None else lag), lag is not None, per_sample)
        return np.asarray(f)

    def evaluate(
        self,
        batch: Batch,
        *,
        current: ArrayLike | None = None,
        lag: float | None = None,
        mask: ArrayLike | None = None,
    ) -> dict[str, Any]:
        """Score the model on `batch` (arguments as :meth:`predict`; `mask` (C, T) selects the
        scored samples, default the batch mask).

        **Returns:** a dict with `labels`; per condition `rms` (C,) [N], `nrmse` (C,)
        (rms / max |F| over the scored samples); `total_rms` [N] over all scored samples;
        `median_nrmse`; and `predicted` (C, T) [N].
        """
        batch = as_batch(batch)
        pred = self.predict(batch, current=current, lag=lag)
        m = check_mask(batch, mask)
        rms, total = scores(jnp.asarray(pred), batch.force, jnp.asarray(m))
        rms = np.asarray(rms)
        nr = nrmse(rms, batch.force, m)
        return {"labels": tuple(batch.labels), "rms": rms, "nrmse": nr,
                "total_rms": float(total), "median_nrmse": float(np.median(nr)),
                "predicted": pred}

    def curves(self, n: int = 101, *, current: ArrayLike | None = None) -> dict[str, Any]:
        """Plotting data (the paper's Fig 11): each law on a current grid with the per-current
        averages and per-condition values it was built from.

        **Returns:** a dict with `param_names`, `units`, `current` (n,) [A] (default: the
        current range), `params` (n, P) law values, and when available (two-step stage)
        `points_current` (U,), `points_mean` (U, P), `points_stderr` (U, P) [NaN where
        unknown], `conditions_current` (C,), `conditions_theta` (C, P). Bouc-Wen-type
        parameters are on the |z|max = 1 scale.
        """
        lo, hi = self.current_range
        grid = np.linspace(lo, hi, int(n)) if current is None else np.asarray(current, float)
        out = {"param_names": self.param_names, "units": tuple(self.model.units),
               "current": grid, "params": np.asarray(self.params_at(grid))}
        if self.support:
            out.update(self.support)
        return out

    # ----------------------------------------------------------------------------- text, I/O
    def summary(self) -> str:
        """One line per law, then the method and total RMS."""
        w = max(len(n) for n in self.param_names)
        lines = [f"{n:>{w}} = {self.laws[n].formula()}  [{u}]"
                 for n, u in zip(self.param_names, self.model.units)]
        lo, hi = self.current_range
        lines.append(f"{self.model.name} generalized ({self.method}), i in [{lo:g}, {hi:g}] A: "
                     f"total RMS {self.total_rms:.4g} N")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.summary()

    def __repr__(self) -> str:
        return (f"GeneralizedModel(model={self.model.name!r}, method={self.method!r}, "
                f"total_rms={self.total_rms:.4g} N, laws={{"
                + ", ".join(f"{n}: {law.kind}{law.degree}" for n, law in self.laws.items())
                + "})")

    def to_dict(self) -> dict[str, Any]:
        """The `"generalized"` block of `fit.json`."""
        total = self.total_rms if math.isfinite(self.total_rms) else None
        return {
            "method": self.method,
            "model": self.model.name,
            "total_rms_N": total,
            "current_range_A": [self.current_range[0], self.current_range[1]],
            "laws": {n: self.laws[n].to_dict() for n in self.param_names},
            "weighting": self.weighting or None,
            "units": {n: u for n, u in zip(self.param_names, self.model.units)},
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> GeneralizedModel:
        """Inverse of :meth:`to_dict` (also accepts a whole `fit.json` with a `"generalized"`
        block). Raises :class:`mrjax.InputError` for a malformed block."""
        if not isinstance(d, Mapping):
            raise InputError("generalized model must be a JSON object")
        if "generalized" in d and "laws" not in d:
            d = d["generalized"]
        for k in ("model", "laws"):
            if k not in d:
                raise InputError(f"generalized model block lacks {k!r}")
        total = d.get("total_rms_N")
        rng = d.get("current_range_A") or [0.0, 0.0]
        return cls(model=get(d["model"]), laws=dict(d["laws"]),
                   method=d.get("method", "two-step"),
                   total_rms=float("nan") if total is None else float(total),
                   current_range=tuple(rng), weighting=d.get("weighting") or "")

    def to_json(self, **kw) -> str:
        """JSON text of :meth:`to_dict`."""
        return json.dumps(self.to_dict(), indent=kw.pop("indent", 1), allow_nan=False, **kw)

    @classmethod
    def from_json_file(cls, path: str | os.PathLike) -> GeneralizedModel:
        """Read a model written by :meth:`to_json` (or a `fit.json` with a `"generalized"`
        block)."""
        p = Path(path)
        try:
            d = json.loads(p.read_text())
        except OSError as e:
            raise InputError(f"{path}: cannot read ({e.strerror})") from None
        except json.JSONDecodeError as e:
            raise InputError(f"{path}: not valid JSON (line {e.lineno}: {e.msg})") from None
        return cls.from_dict(d)


def check_lag(lag):
    if lag is None:
        return None
    if isinstance(lag, jax.core.Tracer):
        return lag
    v = float(lag)
    if not (math.isfinite(v) and v > 0):
        raise InputError(f"lag (eta) must be a positive rate in 1/s, got {lag!r}")
    return v


# ------------------------------------------------------------------------------ compiled cores
def _theta_signal(laws: LawSet, cur, dt, eta, use_lag: bool):
    if use_lag:
        cur = lag_current(cur, dt, eta)
    return laws(cur)


@eqx.filter_jit
def force_one(model, laws, x, xdot, dt, cur, eta, use_lag):
    if cur.ndim == 0 and not use_lag:
        return model.force(laws(cur), x, xdot, dt)
    cur = jnp.broadcast_to(cur, x.shape)
    return model.force(_theta_signal(laws, cur, dt, eta, use_lag), x, xdot, dt)


@eqx.filter_jit
def force_batch(model, laws, x, xdot, dt, cur, eta, use_lag, per_sample):
    def one(xc, vc, dc, ic):
        th = _theta_signal(laws, ic, dc, eta, use_lag) if per_sample else laws(ic)
        return model.force(th, xc, vc, dc)

    return jax.vmap(one)(x, xdot, dt, cur)


@jax.jit
def scores(pred, force, mask):
    per = jax.vmap(masked_rms)(pred, force, mask)
    return per, masked_rms(pred.ravel(), force.ravel(), mask.ravel())


@eqx.filter_jit
def total_rms(model, laws, data):
    """RMS [N] over every scored sample of every condition (the joint objective)."""
    x, xdot, dt, force, mask, cur = data
    pred = jax.vmap(model.force)(laws(cur), x, xdot, dt)
    return masked_rms(pred.ravel(), force.ravel(), mask.ravel())
