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
from .._io import json_safe
from .._warnings import ResultWarning, WarningKind
from ..data import COMMAND_UNITS as COMMAND_UNITS_BY_KIND
from ..data import Batch, as_batch, check_mask
from ..models import AbstractModel, from_source, get, resolve_model, source_of
from ..objective import masked_rms, nrmse
from ._laws import (
    COMMAND_UNITS,
    Law,
    LawSet,
    default_degrees,
    group_currents,
    lag_current,
)
from ._report import LawReport

#: Methods a :class:`GeneralizedModel` can come from: the paper's two-step generalization, the
#: joint fit of the law coefficients (`generalize(method="joint")` and `identify`), or laws
#: given by hand (e.g. a published set, :func:`spencer_1997`).
METHODS: tuple[str, ...] = ("two-step", "joint", "given")


class ModelLag:
    """Sentinel of `lag=`: use the model's own lag (`GeneralizedModel.lag`)."""

    def __repr__(self) -> str:
        return "MODEL_LAG"


#: Default of every `lag=` argument: the lag the model was identified with (none for laws
#: built from constant-current tests).
MODEL_LAG = ModelLag()


@dataclasses.dataclass(frozen=True)
class LawUncertainty:
    """Linearised uncertainty of identified laws (see `mrjax.refine.jacobian_uncertainty`).

    **Fields:**

    - `stderr`: parameter name -> std-error of each law coefficient (ascending powers of u,
        units of the coefficient); NaN where undefined.
    - `identifiable`: parameter name -> per coefficient, False where the data do not determine
        it (a numerically null direction of $J^T J$, or |corr| > 0.9999 with another unknown).
    - `lag_stderr`: std-error of the lag rate $\\eta$ [1/s] (None when the lag was not fitted).
    - `lag_identifiable`: whether $\\eta$ is determined (None when not fitted).
    - `sigma`: residual standard deviation [N]; `dof`: scored samples minus unknowns.
    - `fixed`: parameter name -> coefficients not estimated (e.g. the one the z-scale of
        Bouc-Wen models fixes); their std-error is 0.
    """

    stderr: dict[str, tuple[float, ...]]
    identifiable: dict[str, tuple[bool, ...]]
    lag_stderr: float | None = None
    lag_identifiable: bool | None = None
    sigma: float = float("nan")
    dof: int = 0
    fixed: dict[str, tuple[bool, ...]] = dataclasses.field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The uncertainty entries of the `"generalized"` block of `fit.json`."""
        return {"stderr": {n: list(v) for n, v in self.stderr.items()},
                "identifiable": {n: list(v) for n, v in self.identifiable.items()},
                "lag_stderr_1_s": self.lag_stderr, "lag_identifiable": self.lag_identifiable,
                "sigma_N": self.sigma, "dof": int(self.dof)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> LawUncertainty | None:
        """Inverse of :meth:`to_dict` (None when `d` holds no std-errors)."""
        if not isinstance(d, Mapping) or not isinstance(d.get("stderr"), Mapping):
            return None
        nan = float("nan")
        se = {n: tuple(nan if v is None else float(v) for v in vals)
              for n, vals in d["stderr"].items()}
        ok = {n: tuple(bool(v) for v in vals) for n, vals in (d.get("identifiable") or {}).items()}
        lag_se = d.get("lag_stderr_1_s")
        return cls(stderr=se, identifiable=ok,
                   lag_stderr=None if lag_se is None else float(lag_se),
                   lag_identifiable=d.get("lag_identifiable"),
                   sigma=nan if d.get("sigma_N") is None else float(d["sigma_N"]),
                   dof=int(d.get("dof") or 0))


# ------------------------------------------------------------------------------ the result
@dataclasses.dataclass(frozen=True, eq=False)
class GeneralizedModel:
    """A damper model whose parameters are laws of the command u: the coil current [A] or a
    command voltage [V] (`command_unit`), optionally seen through a first-order lag.

    **Fields:**

    - `model`: the :class:`mrjax.models.AbstractModel`.
    - `laws`: parameter name -> :class:`Law` of u, in `model.param_names` order.
    - `method`: `"two-step"`, `"joint"` (also :func:`identify`) or `"given"`.
    - `total_rms`: RMS force error [N] over all scored samples of all conditions of the data it
        was built on.
    - `current_range`: `(min, max)` of the command u of those data, in `command_unit` (the
        laws' range of validity; also :attr:`command_range`).
    - `weighting`: how the two-step stage weighted the per-condition parameters
        (`"covariance"` or `"equal"`; `""` otherwise).
    - `support`: plotting data of the two-step stage (see :meth:`curves`), or None.
    - `report`: a :class:`LawReport` (how the forms were chosen, the two-step total RMS, the
        engine's outcome of a joint fit, timings [s]).
    - `command_unit`: `"A"` (laws of the coil current, default) or `"V"` (laws of a command
        voltage: every coefficient of power m is per $V^m$).
    - `lag`: $\\eta$ [1/s] of the command filter $\\dot u = -\\eta(u - v)$ the laws see (the
        command v of a record is filtered before the laws are applied), or None for none.
    - `uncertainty`: a :class:`LawUncertainty` of the coefficients and the lag, or None.
    - `transient`: the initial span of each record left out of the fit (seconds, `"cycle"` or
        None); the laws' posterior scores the same samples.
    """

    model: AbstractModel
    laws: dict[str, Law]
    method: str
    total_rms: float
    current_range: tuple[float, float]
    weighting: str = ""
    support: dict[str, Any] | None = None
    report: LawReport = LawReport()
    command_unit: str = "A"
    lag: float | None = None
    uncertainty: LawUncertainty | None = None
    transient: float | str | None = None

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
        if method not in METHODS:
            raise InputError(f"method must be one of {list(METHODS)}, got {self.method!r}")
        object.__setattr__(self, "method", method)
        if self.command_unit not in COMMAND_UNITS:
            raise InputError(f"command_unit must be one of {list(COMMAND_UNITS)}, got "
                             f"{self.command_unit!r}")
        object.__setattr__(self, "lag", check_lag(self.lag))
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
    def command_range(self) -> tuple[float, float]:
        """`(min, max)` command of the data the laws were built on [`command_unit`]."""
        return self.current_range

    @property
    def param_names(self) -> tuple[str, ...]:
        """Parameter names, in vector order."""
        return self.model.param_names

    @functools.cached_property
    def lawset(self) -> LawSet:
        """Every law as one traceable function `lawset(u) -> (..., P)` of the command (the
        parameters in SI units at `u` in `command_unit`): what :meth:`params_at`, the force
        and the inverse evaluate."""
        laws = [self.laws[n] for n in self.param_names]
        # a NumPy constant: safe to create inside a trace (no leaked tracer in the cache)
        coef = np.concatenate([np.asarray(law.coefficients, float) for law in laws])
        return LawSet(coef, tuple(law.kind for law in laws),
                      tuple(len(law.coefficients) for law in laws),
                      tuple(law.scale or 1.0 for law in laws))

    def params_at(self, current: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape P"]:
        """Parameters (..., P) at the command `current` (in `command_unit`, A or V) of any
        shape (scalar, (C,), (T,), ...), SI units, `param_names` order. Pure JAX: traceable and
        differentiable in `current`. No lag is applied (the value of u itself)."""
        return self.lawset(current)

    def with_canonical_z(self, reference: float | None = None) -> GeneralizedModel:
        """The same model with the z-scale of Bouc-Wen-type models normalised to
        $|z|_{max} = (\\delta/(\\beta+\\gamma))^{1/n} = 1$ at the command `reference`
        (default: the low end of `command_range`), the form :func:`identify` reports; other
        models are returned unchanged. The force is unchanged where delta, beta, gamma and n
        are constant (their default laws); the map is one global scale of z
        (`canonical_z_scale`): alpha / s, delta * s, beta and gamma * s^(1 - n)."""
        sym = self.model.scale_symmetry
        if sym is None:
            return self
        u = self.current_range[0] if reference is None else float(reference)
        th = np.asarray(self.params_at(u), float)
        if not sym.has_canonical(th, self.param_names):
            return self
        scale = sym.factors(th, self.param_names, sym.canonical_scale(th, self.param_names))
        scale = {n: f for n, f in scale.items() if n in self.laws}
        laws = dict(self.laws)
        for name, f in scale.items():
            law = laws[name]
            c = np.asarray(law.coefficients, float)
            c = c * f if law.kind != "exp" else np.concatenate([[c[0] + np.log(f)], c[1:]])
            laws[name] = Law(law.kind, c, law.scale)
        return dataclasses.replace(self, laws=laws, uncertainty=None)

    def coefficients(self, name: str) -> tuple[float, ...]:
        """Coefficients of parameter `name`'s law, ascending powers of i."""
        if name not in self.laws:
            raise InputError(f"unknown parameter {name!r}; model {self.model.name!r} has "
                             f"{list(self.param_names)}")
        return self.laws[name].coefficients

    # ----------------------------------------------------------------------------- simulate
    def resolved_model(self, currents: np.ndarray, xdot, dt, mask=None) -> AbstractModel:
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
        lag: float | None | ModelLag = MODEL_LAG,
    ) -> Float[Array, " T"]:
        """Force [N] of one record at a constant or time-varying command.

        **Arguments:**

        - `x` [m], `xdot` [m/s]: the record, (T,).
        - `dt`: sample interval [s], scalar or (T,) (the interval after each sample).
        - `current`: the command v in `command_unit` (coil current [A] or voltage [V]),
            scalar or per sample (T,).
        - `lag`: $\\eta$ [1/s] of the first-order command filter $\\dot u = -\\eta(u - v)$
            (:func:`lag_current`, $u_0 = v_0$), None for none; default the model's own `lag`.

        **Returns:** force (T,) [N]. A scalar command without lag uses one parameter vector;
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
        lag = self.lag if lag is MODEL_LAG else check_lag(lag)
        concrete = not any(isinstance(a, jax.core.Tracer) for a in (x, xdot, dt, cur))
        model = self.resolved_model(np.asarray(cur), np.asarray(xdot), np.asarray(dt)) if concrete \
            else self.model
        return force_one(model, self.lawset, x, xdot, jnp.asarray(dt, float), cur,
                          jnp.asarray(0.0 if lag is None else lag), lag is not None)

    def _batch_currents(self, batch: Batch, current) -> np.ndarray:
        C, T = batch.n_conditions, batch.length
        if current is None:
            return batch_command(batch, self.command_unit)
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
        self, batch: Batch, *, current: ArrayLike | None = None,
        lag: float | None | ModelLag = MODEL_LAG,
    ) -> np.ndarray:
        """Force [N] of every condition of `batch`, (C, T) NumPy (padding included).

        **Arguments:** `batch` any conditions (a `mrjax.data.Batch`, or what `mrjax.fit`
        accepts); `current`: the command in `command_unit`: None (each condition's own: its
        per-sample command when it has one, replayed through the lag, else its constant
        current [A]), a scalar, (C,), or per sample (C, T); `lag`: $\\eta$ [1/s] of the command
        filter, None for none, default the model's own.

        Raises :class:`mrjax.InputError` when a condition's command is in another unit than
        the laws (a voltage record for laws of the current, or the reverse), or a condition
        has neither a command nor, for laws of the current, a current.
        """
        batch = as_batch(batch)
        cur = self._batch_currents(batch, current)
        lag = self.lag if lag is MODEL_LAG else check_lag(lag)
        model = self.resolved_model(cur, batch.xdot, batch.dt, batch.mask)
        per_sample = cur.ndim == 2 or lag is not None
        if cur.ndim == 1 and per_sample:
            cur = np.broadcast_to(cur[:, None], (batch.n_conditions, batch.length))
        f = force_batch(model, self.lawset, batch.x, batch.xdot, batch.dt, jnp.asarray(cur),
                         jnp.asarray(0.0 if lag is None else lag), lag is not None, per_sample)
        return np.asarray(f)

    def evaluate(
        self,
        batch: Batch,
        *,
        current: ArrayLike | None = None,
        lag: float | None | ModelLag = MODEL_LAG,
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
    def law_warnings(self, currents: ArrayLike) -> list[ResultWarning]:
        """Laws that the tests' currents cannot determine: with U distinct `currents` [in
        `command_unit`] a law of degree d needs d + 1 of them, so where the model's default
        degree (:func:`default_degrees`) is higher than U - 1 the law was reduced to degree
        U - 1 (constant for one current) or is not determined. As `FitResult.warnings`:
        `[ResultWarning(TOO_FEW_CURRENTS, ...)]` or `[]`.
        (Laws identified from time-varying commands, `identify`, see a continuum of commands:
        this check is for laws through tests at constant currents.)"""
        cur = np.asarray(currents, float).ravel()
        levels, _ = group_currents(cur[np.isfinite(cur)]) if np.isfinite(cur).any() else (
            np.zeros(0), None)
        wanted = default_degrees(self.model, unit=self.command_unit)
        short = [n for n in self.param_names
                 if max(wanted.get(n, 0), len(self.coefficients(n)) - 1) + 1 > levels.size]
        if not short:
            return []
        need = max(max(wanted.get(n, 0), len(self.coefficients(n)) - 1) for n in short) + 1
        have = ", ".join(f"{v:g}" for v in levels[:6]) + (" ..." if levels.size > 6 else "")
        U = levels.size
        return [ResultWarning(
            WarningKind.TOO_FEW_CURRENTS,
            f"laws of {', '.join(short)} from {U} distinct current"
            f"{'s' if U != 1 else ''} ({have} {self.command_unit}): their degrees need up to "
            f"{need} distinct currents, so they are "
            f"{'constants' if U == 1 else f'of degree at most {U - 1}'} or not determined by "
            "the data; test more currents", parameters=short)]

    def loosely_determined(self, rel: float = 0.025) -> dict[str, tuple[bool, ...]]:
        """Which law coefficients the data determine only loosely: std-error above `rel`
        (dimensionless, default 2.5 %) of the coefficient's magnitude, so that two std-errors
        exceed 5 % (for an `"exp"` law, whose coefficients act on the logarithm, std-error
        above `rel` itself). Unlike `uncertainty.identifiable` (a null direction or a
        near-perfect correlation), this names the coefficients a record pins down only to
        several percent. Empty without an uncertainty."""
        unc = self.uncertainty
        if unc is None:
            return {}
        out = {}
        for n, se in unc.stderr.items():
            law = self.laws[n]
            ref = (np.ones(len(law.coefficients)) if law.kind == "exp"
                   else np.abs(np.asarray(law.coefficients, float)))
            s = np.asarray(se, float)
            out[n] = tuple(bool(not np.isfinite(a) or a > rel * r) for a, r in zip(s, ref))
        return out

    def summary(self) -> str:
        """One line per law, then the method and total RMS. `*` marks a loosely determined
        coefficient (:meth:`loosely_determined`: std-error above 2.5 % of it)."""
        w = max(len(n) for n in self.param_names)
        var = "v" if self.command_unit == "V" else "i"
        unc = self.uncertainty
        lines = []
        for n, u in zip(self.param_names, self.model.units):
            line = f"{n:>{w}} = {self.laws[n].formula(var)}  [{u}]"
            if unc is not None and n in unc.stderr:
                loose = self.loosely_determined().get(n, ())
                se = ", ".join(f"{v:.3g}{'*' if k < len(loose) and loose[k] else ''}"
                               for k, v in enumerate(unc.stderr[n]))
                bad = "" if all(unc.identifiable.get(n, (True,))) else "  (not identifiable)"
                line += f"  std-err ({se}){bad}"
            lines.append(line)
        if self.lag is not None:
            se = "" if unc is None or unc.lag_stderr is None else f" +- {unc.lag_stderr:.3g}"
            lines.append(f"{'eta':>{w}} = {self.lag:.6g}{se}  [1/s]  (command filter "
                         f"du/dt = -eta (u - {var}))")
        lo, hi = self.current_range
        lines.append(f"{self.model.name} generalized ({self.method}), {var} in [{lo:g}, {hi:g}] "
                     f"{self.command_unit}: total RMS {self.total_rms:.4g} N")
        if self.report.law_criteria is not None:
            lines.append("law forms chosen by the data (lowest BIC of the per-test values): "
                         + ", ".join(f"{n} {self.laws[n].form}" for n in self.param_names))
        if any(any(v) for v in self.loosely_determined().values()):
            lines.append("* loosely determined: std-error above 2.5 % of the coefficient")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.summary()

    def __repr__(self) -> str:
        lag = "" if self.lag is None else f", lag={self.lag:.4g} 1/s"
        return (f"GeneralizedModel(model={self.model.name!r}, method={self.method!r}, "
                f"unit={self.command_unit!r}{lag}, total_rms={self.total_rms:.4g} N, laws={{"
                + ", ".join(f"{n}: {law.form}" for n, law in self.laws.items())
                + "})")

    def to_dict(self) -> dict[str, Any]:
        """The `"generalized"` block of `fit.json`."""
        total = self.total_rms if math.isfinite(self.total_rms) else None
        rng = [self.current_range[0], self.current_range[1]]
        out = {
            "method": self.method,
            "model": self.model.name,
            "model_source": source_of(self.model),
            "total_rms_N": total,
            "current_range_A": rng if self.command_unit == "A" else None,
            "laws": {n: self.laws[n].to_dict() for n in self.param_names},
            "law_forms": {n: self.laws[n].form for n in self.param_names},
            "law_choice": self.report.law_choice,
            "weighting": self.weighting or None,
            "units": {n: u for n, u in zip(self.param_names, self.model.units)},
            "command_unit": self.command_unit,
            "command_range": rng,
            "lag_1_s": self.lag,
            "lag_fitted": self.report.lag_fitted,
        }
        if self.report.law_criteria is not None:
            out["law_criteria"] = self.report.law_criteria
        if self.transient is not None:
            out["transient"] = self.transient
        if self.uncertainty is not None:
            out.update(self.uncertainty.to_dict())
        return json_safe(out)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], *, model: AbstractModel | None = None
                  ) -> GeneralizedModel:
        """Inverse of :meth:`to_dict` (also accepts a whole `fit.json` with a `"generalized"`
        block). The model is found again from its name and recorded source
        (`mrjax.models.from_source`: a user's model from its file or module), or given as
        `model` (whose name must match). Raises :class:`mrjax.InputError` for a malformed
        block, or one line saying what to pass when the model cannot be found."""
        if not isinstance(d, Mapping):
            raise InputError("generalized model must be a JSON object")
        if "generalized" in d and "laws" not in d:
            d = d["generalized"]
        for k in ("model", "laws"):
            if k not in d:
                raise InputError(f"generalized model block lacks {k!r}")
        total = d.get("total_rms_N")
        rng = d.get("command_range") or d.get("current_range_A") or [0.0, 0.0]
        unit = d.get("command_unit") or "A"
        lag = d.get("lag_1_s")
        if model is None:
            model = from_source(d["model"], d.get("model_source"))
        else:
            model = get(model)
            if model.name != str(d["model"]).strip().lower():
                raise InputError(f"the laws are of model {d['model']!r}, not {model.name!r}")
        return cls(model=model, laws=dict(d["laws"]),
                   method=d.get("method", "two-step"),
                   total_rms=float("nan") if total is None else float(total),
                   current_range=tuple(rng), weighting=d.get("weighting") or "",
                   command_unit=unit, lag=None if lag is None else float(lag),
                   uncertainty=LawUncertainty.from_dict(d), transient=d.get("transient"),
                   report=LawReport(law_choice=d.get("law_choice") or "given",
                                    law_criteria=d.get("law_criteria"),
                                    lag_mode="fit" if d.get("lag_fitted") else (
                                        "none" if lag is None else "fixed")))

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


def batch_command(batch: Batch, unit: str) -> np.ndarray:
    """The command u of every condition of `batch` for laws in `unit`: (C, T) per sample when
    any condition carries a per-sample command (the others' constant current broadcast), else
    (C,) constant currents [A].

    Raises :class:`mrjax.InputError` naming the condition whose command is in another unit or
    that has no command (and, for laws of the current, no current).
    """
    kind = np.asarray(batch.command_kind)
    cur = np.asarray(batch.current, float)
    for i in range(batch.n_conditions):
        have = COMMAND_UNITS_BY_KIND[int(kind[i])]
        if have is not None and have != unit:
            what = {"A": "a current", "V": "a command voltage"}
            raise InputError(f"condition {batch.labels[i]!r} carries {what[have]} [{have}] but "
                             f"the laws are of {what[unit]} [{unit}]")
        if have is None and (unit != "A" or not np.isfinite(cur[i])):
            need = "a per-sample command voltage" if unit == "V" else "a current"
            raise InputError(f"condition {batch.labels[i]!r} has no command: the laws need "
                             f"{need} [{unit}] (pass current=)")
    if not np.any(kind > 0):
        return cur
    cmd = np.asarray(batch.command, float)
    return np.where(kind[:, None] > 0, cmd, cur[:, None])


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
