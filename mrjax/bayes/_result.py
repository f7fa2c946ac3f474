"""`Posterior`: the draws of the sampler, their arviz form, diagnostics, tables and files."""

from __future__ import annotations

import dataclasses
import functools
import os
import tempfile
import warnings
from typing import Any

import numpy as np

from .._errors import InputError
from .._io import json_safe
from .._warnings import ResultWarning, WarningKind

#: A parameter whose rank-normalized split R-hat exceeds this has not converged (Vehtari et
#: al. 2021).
RHAT_MAX = 1.01
#: Fewer effective draws than this (bulk or tail) are too few for a 95 % interval's ends.
ESS_MIN = 400
#: The quantiles of the summary table, %.
QUANTILES = (2.5, 50.0, 97.5)
#: Names of the noise variables (`rho` is a parameter of the Dahl model).
SIGMA, RHO = "noise_sigma", "noise_rho"


def arviz():
    """`arviz`, imported quietly (its import warns of a coming refactor) and only when needed."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz as az
    return az


@dataclasses.dataclass(frozen=True, eq=False)
class Posterior:
    """Draws of the unknowns of U units (conditions), C chains x N draws each, host arrays.

    **Fields:**

    - `names` (K,), `labels` (U,), `row_labels` (R,) or None, `unit_dim` (`"condition"`).
    - `theta` (U, C, N, K): draws in SI units (fixed unknowns constant).
    - `sigma` (U, C, N, R) [N]: noise level of each record; `rho` (U, C, N) AR(1) coefficient
        (None for `noise="iid"`).
    - `lp` (U, C, N) log posterior density (up to a constant; of the sampler's coordinates);
        `diverging` (U, C, N); `n_steps` (U, C, N) leapfrog steps of each draw;
        `accept` (U, C, N) mean acceptance probability; `step_size` (U, C) adapted;
        `warmup_steps` (U, C) leapfrog steps of each chain's warmup and `warmup_length` (U,)
        its steps (None if not kept); `rounds` (U,) the continuation rounds each unit took
        (0: converged in the first; see `mrjax.bayes.Sampler.continuations`: a unit of round
        r kept every 2^r-th of 2^r x the draws after 2^r x the warmup);
        `gradient_error` the largest whitened error of an approximate gradient at the start
        (None where the gradient is exact; above `GRADIENT_TOL` the exact one was used, see
        `mrjax.bayes.sample`); `linear` the names of the unknowns integrated out of the
        log-density and drawn from their conditional at each draw (`mrjax.bayes.sample`).
    - `theta0` (U, K) the optimum the chains started around; `lower`, `upper` (U, K) the box
        (after uniform priors); `free` (K,) which unknowns were sampled.
    - `noise`, `prior` {name: description}, `sampler` (the `mrjax.bayes.Sampler`), `seed`,
        `timings` [s], `param_units` (K,) or None.
    """

    names: tuple[str, ...]
    labels: tuple[str, ...]
    row_labels: tuple[str, ...] | None
    unit_dim: str
    theta: np.ndarray
    sigma: np.ndarray
    rho: np.ndarray | None
    lp: np.ndarray
    diverging: np.ndarray
    n_steps: np.ndarray
    accept: np.ndarray
    step_size: np.ndarray
    theta0: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    free: np.ndarray
    noise: str
    prior: dict[str, str]
    sampler: Any
    seed: int
    timings: dict[str, float]
    param_units: tuple[str, ...] | None = None
    warmup_steps: np.ndarray | None = None
    warmup_length: np.ndarray | None = None
    rounds: np.ndarray | None = None
    gradient_error: float | None = None
    linear: tuple[str, ...] = ()

    # ----------------------------------------------------------------------------- shapes
    @property
    def n_units(self) -> int:
        """Units (conditions) U."""
        return self.theta.shape[0]

    @property
    def n_chains(self) -> int:
        """Chains per unit C."""
        return self.theta.shape[1]

    @property
    def n_draws(self) -> int:
        """Draws per chain N."""
        return self.theta.shape[2]

    def draws(self, name: str) -> np.ndarray:
        """All draws of one variable (a parameter, `noise_sigma` or `noise_rho`), chains
        pooled: (U, C * N) (`noise_sigma`: (U, C * N, R))."""
        U = self.n_units
        if name == SIGMA:
            return self.sigma.reshape(U, -1, self.sigma.shape[-1])
        if name == RHO:
            if self.rho is None:
                raise KeyError(f"{RHO}: the noise model is {self.noise!r}, not 'ar1'")
            return self.rho.reshape(U, -1)
        return self.theta[..., self.names.index(name)].reshape(U, -1)

    @property
    def held(self) -> np.ndarray:
        """(U, K) the unknowns held at `theta0` in each unit, because the data left a
        direction of the unknowns undetermined (see `mrjax.bayes.sample`): sampled unknowns
        whose box is a point."""
        point = np.asarray(self.upper, float) <= np.asarray(self.lower, float)
        return np.asarray(self.free, bool)[None, :] & point

    def interval(self, name: str, level: float = 0.95) -> np.ndarray:
        """Central credible interval of `name` per unit, (U, 2), SI units."""
        q = 50.0 * (1.0 - level), 50.0 * (1.0 + level)
        return np.moveaxis(np.percentile(self.draws(name), q, axis=1), 0, -1)

    def _variables(self) -> list[str]:
        """The sampled variables: free unknowns, then the noise parameters."""
        out = [n for n, f in zip(self.names, self.free) if f] + [SIGMA]
        return out + ([RHO] if self.rho is not None else [])

    # ----------------------------------------------------------------------------- arviz
    @functools.cached_property
    def idata(self) -> Any:
        """The draws as an `arviz.InferenceData`: group `posterior` with one variable per
        unknown (named as the model names it) and `noise_sigma` (`noise_rho`), dims `chain`,
        `draw`, `condition` (test labels as coordinates; `record` for units of several
        records); group `sample_stats` with `diverging`, `n_steps`, `acceptance_rate`, `lp`."""
        az = arviz()
        u = self.unit_dim
        post, dims = {}, {}
        for j, n in enumerate(self.names):
            post[n] = np.moveaxis(self.theta[..., j], 0, -1)
            dims[n] = [u]
        R = self.sigma.shape[-1]
        if R == 1:
            post[SIGMA], dims[SIGMA] = np.moveaxis(self.sigma[..., 0], 0, -1), [u]
        else:
            post[SIGMA], dims[SIGMA] = np.moveaxis(self.sigma, 0, 2), [u, "record"]
        if self.rho is not None:
            post[RHO], dims[RHO] = np.moveaxis(self.rho, 0, -1), [u]
        stats = {"diverging": self.diverging, "n_steps": self.n_steps,
                 "acceptance_rate": self.accept, "lp": self.lp}
        stats = {k: np.moveaxis(v, 0, -1) for k, v in stats.items()}
        dims.update({k: [u] for k in stats})
        coords = {u: list(self.labels)}
        if R > 1:
            coords["record"] = list(self.row_labels or map(str, range(R)))
        attrs = {"noise": self.noise, "seed": self.seed, "sampler": self.sampler.kernel.name,
                 "warmup": int(self.sampler.warmup), "dense_mass": int(self.sampler.dense_mass),
                 "integrated_out": ", ".join(self.linear) or "none",
                 "prior": "; ".join(f"{k}: {v}" for k, v in self.prior.items()) or "flat on box"}
        if self.sampler.target_accept is not None:  # None: a Posterior built by hand
            attrs["target_accept"] = float(self.sampler.target_accept)
        if self.param_units is not None:
            attrs["units"] = ", ".join(f"{n} [{un}]" for n, un in zip(self.names,
                                                                      self.param_units))
        return az.from_dict(posterior=post, sample_stats=stats, dims=dims, coords=coords,
                            attrs=attrs)

    @functools.cached_property
    def _diag(self) -> dict[str, dict[str, np.ndarray]]:
        """R-hat, bulk and tail ESS of every sampled variable (arviz), arrays over units
        (and records)."""
        az = arviz()
        post = self.idata.posterior[self._variables()]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # constant draws: NaN R-hat
            out = {"r_hat": az.rhat(post, method="rank"),
                   "ess_bulk": az.ess(post, method="bulk"),
                   "ess_tail": az.ess(post, method="tail")}
        diag = {k: {v: np.asarray(ds[v].values, float) for v in ds.data_vars}
                for k, ds in out.items()}
        held = self.held
        for j in np.flatnonzero(held.any(axis=0)):  # constant draws: no diagnostic
            for k in diag:
                diag[k][self.names[j]] = np.where(held[:, j], np.nan, diag[k][self.names[j]])
        return diag

    # ----------------------------------------------------------------------------- tables
    def summary(self) -> Any:
        """The summary table as a `pandas.DataFrame`, one row per variable and unit (and
        record): `variable`, `condition`, (`record`), `mean`, `sd`, `q2.5`, `q50`, `q97.5`
        (SI units), `r_hat`, `ess_bulk`, `ess_tail`, and `divergences` of the unit."""
        import pandas as pd

        rows = []
        div = self.diverging.sum(axis=(1, 2))
        for v in self._variables():
            d = self.draws(v)
            if d.ndim == 2:
                d = d[..., None]
            for i, lab in enumerate(self.labels):
                for k in range(d.shape[-1]):
                    x = d[i, :, k]
                    row = {"variable": v, self.unit_dim: lab}
                    if d.shape[-1] > 1:
                        row["record"] = (self.row_labels or [str(k) for k in range(d.shape[-1])])[k]
                    row.update(mean=float(np.mean(x)), sd=float(np.std(x, ddof=1)))
                    for q, val in zip(QUANTILES, np.percentile(x, QUANTILES)):
                        row[f"q{q:g}"] = float(val)
                    for s in ("r_hat", "ess_bulk", "ess_tail"):
                        a = self._diag[s][v]
                        row[s] = float(a[i] if a.ndim == 1 else a[i, k])
                    row["divergences"] = int(div[i])
                    rows.append(row)
        df = pd.DataFrame(rows)
        if "record" in df.columns:  # beside the unit, also where the first rows have none
            df.insert(2, "record", df.pop("record").fillna(""))
        return df

    def diagnostics(self) -> dict[str, Any]:
        """Convergence figures: worst R-hat, smallest bulk / tail ESS over every sampled
        variable and unit, divergent transitions (total and per unit), mean leapfrog steps per
        draw (and per warmup step), mean acceptance, median adapted step size."""
        def worst(k, f):
            vals = np.concatenate([a.ravel() for a in self._diag[k].values()])
            vals = vals[np.isfinite(vals)]
            return float(f(vals)) if vals.size else float("nan")

        return {"r_hat_max": worst("r_hat", np.max), "ess_bulk_min": worst("ess_bulk", np.min),
                "ess_tail_min": worst("ess_tail", np.min),
                "divergences": int(self.diverging.sum()),
                "divergences_per_unit": [int(v) for v in self.diverging.sum(axis=(1, 2))],
                "leapfrog_per_draw": float(self.n_steps.mean()),
                "leapfrog_per_warmup_step": self._per_warmup_step(),
                "continued_units": int(np.sum(self.rounds > 0)) if self.rounds is not None
                else 0,
                "gradient_error": float("nan") if self.gradient_error is None
                else self.gradient_error,
                "acceptance": float(self.accept.mean()),
                "step_size_median": float(np.median(self.step_size))}

    def _per_warmup_step(self) -> float:
        if self.warmup_steps is None:
            return float("nan")
        length = (np.full(self.n_units, self.sampler.warmup) if self.warmup_length is None
                  else np.asarray(self.warmup_length))
        return float(np.sum(self.warmup_steps) / max(np.sum(length) * self.n_chains, 1))

    def unconverged(self) -> np.ndarray:
        """(U,) the units whose chains missed: R-hat > `RHAT_MAX` or bulk or tail ESS below
        `ESS_MIN` (or a quarter of the draws kept, where they are fewer than 4 x `ESS_MIN`:
        more rounds of the same draws could not reach it) for a sampled variable (held ones
        excepted), or a divergent transition."""
        bad = self.diverging.any(axis=(1, 2))
        ess_min = min(ESS_MIN, 0.25 * self.n_chains * self.n_draws)
        for key, miss in (("r_hat", lambda a: a > RHAT_MAX), ("ess_bulk", lambda a: a < ess_min),
                          ("ess_tail", lambda a: a < ess_min)):
            for v, a in self._diag[key].items():
                a2 = a.reshape(a.shape[0], -1)
                skip = self.held[:, self.names.index(v)] if v in self.names else False
                bad = bad | (np.any(~np.isfinite(a2) | miss(a2), axis=1) & ~skip)
        return bad

    def with_units(self, rows: np.ndarray, other: Posterior, round_: int) -> Posterior:
        """This posterior with the units `rows` replaced by `other`'s (a continuation round
        `round_` of those units, in their order)."""
        rows = np.asarray(rows, int)
        out = {}
        for f in ("theta", "sigma", "rho", "lp", "diverging", "n_steps", "accept", "step_size",
                  "warmup_steps", "warmup_length", "rounds"):
            a, b = getattr(self, f), getattr(other, f)
            if a is None or b is None:
                continue
            a = np.array(a)
            a[rows] = round_ if f == "rounds" else b
            out[f] = a
        return dataclasses.replace(self, **out)

    def problems(self) -> list[ResultWarning]:
        """One :class:`mrjax.ResultWarning` per convergence problem: R-hat > `RHAT_MAX`, bulk
        or tail ESS < `ESS_MIN`, divergent transitions, unknowns held, draws of an unknown
        integrated out beyond its bounds; empty when none."""
        return self._convergence() + self._held_and_beyond() + self._divergences()

    def _units(self, n: int) -> str:  # "3 conditions", "1 condition", "the laws"
        if self.unit_dim == "laws":
            return "the laws"
        return f"{n} {self.unit_dim}{'' if n == 1 else 's'}"

    def _convergence(self) -> list[ResultWarning]:
        out = []
        for key, bad, what in (("r_hat", lambda a: a > RHAT_MAX, f"R-hat > {RHAT_MAX}"),
                               ("ess_bulk", lambda a: a < ESS_MIN, f"bulk ESS < {ESS_MIN}"),
                               ("ess_tail", lambda a: a < ESS_MIN, f"tail ESS < {ESS_MIN}")):
            hits = []
            for v, a in self._diag[key].items():
                a2 = a.reshape(a.shape[0], -1)
                skip = self.held[:, self.names.index(v)] if v in self.names else \
                    np.zeros(a2.shape[0], bool)
                for i in np.flatnonzero(np.any(~np.isfinite(a2) | bad(a2), axis=1) & ~skip):
                    val = a2[i][np.isfinite(a2[i])]
                    hits.append((v, self.labels[i], float(val.max() if key == "r_hat" else
                                                         val.min()) if val.size else np.nan))
            if hits:
                worst = max(hits, key=lambda h: h[2]) if key == "r_hat" else \
                    min(hits, key=lambda h: h[2])
                labels = sorted({h[1] for h in hits})
                rounds = "" if self.rounds is None or not np.any(self.rounds) else \
                    f" after {int(np.max(self.rounds))} continuation round(s)"
                out.append(ResultWarning(
                    WarningKind.NOT_CONVERGED,
                    f"posterior not converged{rounds}: {what} for {len(hits)} variable(s) in "
                    f"{self._units(len(labels))} (worst {worst[0]} on {worst[1]!r}: "
                    f"{worst[2]:.4g}); give more draws / warmup or continuations",
                    conditions=labels, parameters=sorted({h[0] for h in hits})))
        return out

    def _held_and_beyond(self) -> list[ResultWarning]:
        out = []
        held = self.held
        for j in np.flatnonzero(held.any(axis=0)):
            rows = np.flatnonzero(held[:, j])
            out.append(ResultWarning(
                WarningKind.HELD,
                f"posterior: {self.names[j]} held at its fitted value in "
                f"{self._units(rows.size)} (first {self.labels[rows[0]]!r}): the data leave "
                "a direction of the unknowns undetermined (a symmetry of the model, or no "
                "effect on these records); the others' posterior is conditional on it",
                conditions=[self.labels[i] for i in rows], parameters=[self.names[j]]))
        for n in self.linear:  # integrated out: a flat prior on the whole line, not the box
            j = self.names.index(n)
            th = self.theta[..., j]
            out_box = (th < self.lower[:, None, None, j]) | (th > self.upper[:, None, None, j])
            if out_box.any():
                i = int(np.argmax(out_box.sum(axis=(1, 2))))
                out.append(ResultWarning(
                    WarningKind.BEYOND_BOUNDS,
                    f"posterior: {n}, integrated out of the log-density, has "
                    f"{int(out_box.sum())} draw(s) beyond its bounds (most on "
                    f"{self.labels[i]!r}): its posterior reaches a bound, where the integral "
                    "over the whole line is not the box's",
                    conditions=[self.labels[k] for k in np.flatnonzero(out_box.any(axis=(1, 2)))],
                    parameters=[n]))
        return out

    def _divergences(self) -> list[ResultWarning]:
        div = self.diverging.sum(axis=(1, 2))
        if not div.sum():
            return []
        i = int(np.argmax(div))
        return [ResultWarning(
            WarningKind.DIVERGENCES,
            f"posterior: {int(div.sum())} divergent transition(s) in "
            f"{self._units(int(np.sum(div > 0)))} (most: {int(div[i])} on {self.labels[i]!r}): "
            "the draws near a sharp or non-finite region may be biased",
            conditions=[self.labels[k] for k in np.flatnonzero(div)])]

    def table(self, *, max_rows: int | None = None) -> str:
        """A readable fixed-width summary table, then the diagnostics line."""
        from .._tables import format_table

        df = self.summary()
        cols = [c for c in df.columns if c != "divergences"]
        rows = df[cols].values.tolist()
        if max_rows is not None and len(rows) > max_rows:
            rows = rows[:max_rows] + [["..."] + [None] * (len(cols) - 1)]
        n_text = 3 if "record" in cols else 2
        fmt = [""] * n_text + [".5g"] * 5 + [".4f", ".0f", ".0f"]
        d = self.diagnostics()
        return (format_table(rows, cols, floatfmt=fmt)
                + f"\nposterior ({self.noise} noise, {self.n_chains} chains x {self.n_draws} "
                f"draws): R-hat max {d['r_hat_max']:.4f}, ESS min {d['ess_bulk_min']:.0f} "
                f"(bulk) / {d['ess_tail_min']:.0f} (tail), {d['divergences']} divergences, "
                f"{d['leapfrog_per_draw']:.1f} leapfrog steps per draw")

    # ----------------------------------------------------------------------------- files
    def to_dict(self) -> dict[str, Any]:
        """The `posterior` entry of fit.json: settings, diagnostics, warnings and per unit the
        summary of every variable (NaN becomes null)."""
        df = self.summary()
        stats = [c for c in df.columns if c not in ("variable", self.unit_dim, "record",
                                                    "divergences")]
        units = []
        for i, lab in enumerate(self.labels):
            sub = df[df[self.unit_dim] == lab]
            entry: dict[str, Any] = {"label": lab, "divergences": int(
                self.diverging[i].sum())}
            for v, g in sub.groupby("variable", sort=False):
                recs = [{s: float(r[s]) for s in stats} for _, r in g.iterrows()]
                entry[v] = recs[0] if len(recs) == 1 else recs
            units.append(entry)
        s = self.sampler
        doc = {"sampler": s.kernel.name, "noise": self.noise, "draws": int(s.draws),
               "chains": int(s.chains), "warmup": int(s.warmup), "dense_mass": bool(s.dense_mass),
               "target_accept": None if s.target_accept is None else float(s.target_accept),
               "integrated_out": list(self.linear),
               "seed": self.seed, "prior": self.prior or "flat on the bounds",
               "diagnostics": self.diagnostics(),
               "warnings": [w.message for w in self.problems()],
               "timings_s": dict(self.timings), "conditions": units}
        return json_safe(doc)

    def to_csv(self) -> str:
        """`posterior.csv`: the summary table (:meth:`summary`), one row per variable and unit."""
        return self.summary().to_csv(index=False, float_format="%.10g")

    def netcdf_bytes(self) -> bytes:
        """`posterior.nc`: :attr:`idata` as netCDF-4 (h5netcdf), readable by
        `arviz.from_netcdf` and `xarray.open_dataset(..., group="posterior")`."""
        return netcdf_bytes(self.idata)

    def __repr__(self) -> str:
        return (f"Posterior(U={self.n_units}, chains={self.n_chains}, draws={self.n_draws}, "
                f"noise={self.noise!r}, params={list(self.names)})")


def netcdf_bytes(idata: Any) -> bytes:
    """The bytes of `idata` (`arviz.InferenceData`) written as netCDF-4 (`posterior.nc`)."""
    fd, path = tempfile.mkstemp(suffix=".nc")
    os.close(fd)
    try:
        idata.to_netcdf(path)
        with open(path, "rb") as f:
            return f.read()
    finally:
        os.unlink(path)


class PosteriorFront:
    """What the result of every problem kind's posterior (`mrjax.bayes.TestPosterior`,
    `mrjax.bayes.LawPosterior`) shows of its :class:`Posterior` (the `posterior` field):
    the summary, its table, the convergence warnings, `posterior.csv` and `posterior.nc` of
    its `idata`."""

    posterior: Posterior

    @property
    def idata(self) -> Any:
        """The draws as `arviz.InferenceData` (see :attr:`Posterior.idata`)."""
        return self.posterior.idata

    def summary(self) -> Any:
        """The summary table (`pandas.DataFrame`), see :meth:`Posterior.summary`."""
        return self.posterior.summary()

    def table(self, *, max_rows: int | None = None) -> str:
        """A readable summary table with its diagnostics line."""
        return self.posterior.table(max_rows=max_rows)

    def problems(self) -> list[ResultWarning]:
        """Convergence warnings (see :meth:`Posterior.problems`)."""
        return self.posterior.problems()

    def to_csv(self) -> str:
        """`posterior.csv` text."""
        return self.posterior.to_csv()

    def netcdf_bytes(self) -> bytes:
        """`posterior.nc` bytes (:attr:`idata` as netCDF-4)."""
        return netcdf_bytes(self.idata)

    def predict_band(self, data: Any, *, level: float = 0.95, n_draws: int = 200,
                     noise_draws: int = 4, seed: int = 0) -> Any:
        """The posterior predictive force band on records `data` (a batch, condition(s) or
        file path(s)): `n_draws` draws spread evenly over the chains, each draw's model force
        plus `noise_draws` Gaussian noise samples of its noise level, the central `level`
        interval at every sample.

        **Returns:** a :class:`mrjax.bayes.PredictiveBand` with the coverage of the measured
        force per record. Raises :class:`mrjax.InputError` for a non-positive count or a
        level outside (0, 1)."""
        from ..data import as_batch  # here: the data layer is only needed to predict

        if n_draws < 1:
            raise InputError("n_draws must be positive")
        return self.band(as_batch(data), n_draws, level, noise_draws, seed)

    def band(self, batch: Any, n_draws: int, level: float, noise_draws: int,
             seed: int) -> Any:
        """The kind's band on `batch` (see :meth:`predict_band`)."""
        raise NotImplementedError
