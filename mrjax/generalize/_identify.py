"""`identify`: a current- or voltage-dependent model identified directly from records whose
command varies in time (the Spencer et al. 1997 workflow), sine tests at constant commands, or
any mix of them."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

import equinox as eqx
import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ..data import COMMAND_UNITS as COMMAND_UNITS_BY_KIND
from ..data import JOINT_SAMPLES_PER_PERIOD, Batch, Condition, as_batch, fit_mask
from ..data import swarm_view as make_view
from ..engine import Polish, Swarm, check_settings
from ..models import AbstractModel, check_bounds, get
from ..pso import PSOParams
from ._coding import LOG_FLOOR, Layout, bounded_box, build_objective
from ._forms import choose_forms
from ._generalize import law_uncertainty_of, make_generalized
from ._joint import N_LEVELS, LawsProblem, solve_laws
from ._laws import group_currents, nodes
from ._model import GeneralizedModel, batch_command
from ._report import LawReport
from ._rows import make_rows, packed_rows

#: Default range of the command filter's rate eta [1/s] searched when the lag is fitted: time
#: constants from 0.1 ms to 1 s (Spencer et al. 1997: 190 1/s; an RD-1005-3 responds in
#: < 25 ms).
LAG_BOUNDS: tuple[float, float] = (1.0, 1e4)
#: Without `pso_params`, the swarm of a dynamic model runs at least this many generations
#: (capped by `max_generations`) before the statistical stop may end it (window 25): on a
#: random-command record the improvements come in bursts, and an early stop leaves the polish
#: far from the optimum.
MIN_GENERATIONS_DYNAMIC = 100


def command_unit_of(batch: Batch) -> str:
    """The unit of the command of every condition of `batch`: `"V"` when the records carry a
    command voltage, else `"A"` (a measured or commanded current, or each condition's constant
    current). Raises :class:`mrjax.InputError` for records in both units."""
    kinds = np.asarray(batch.command_kind)
    units = sorted({COMMAND_UNITS_BY_KIND[int(k)] for k in kinds if k > 0})
    if len(units) > 1:
        first = {u: batch.labels[int(np.flatnonzero(kinds == COMMAND_UNITS_BY_KIND.index(u))[0])]
                 for u in units}
        raise InputError(f"the records mix a current command (first: {first['A']!r}) and a "
                         f"voltage command (first: {first['V']!r}); laws need one unit")
    return units[0] if units else "A"


def _lag_mode(lag: Any, varying: bool, notes: list[str]
              ) -> tuple[str, float, tuple[float, float]]:
    """`(mode, eta0, bounds)` of `identify`'s `lag`: mode `"none"`, `"fit"` or `"fixed"`."""
    if lag is None or (isinstance(lag, str) and lag.lower() == "none"):
        return "none", 0.0, LAG_BOUNDS
    if isinstance(lag, str):
        if lag.lower() != "fit":
            raise InputError(f"lag must be 'fit', a rate in 1/s, a Lag or None, got {lag!r}")
        lag = Lag()
    elif not isinstance(lag, Lag):
        try:
            lag = Lag(rate=float(lag))
        except (TypeError, ValueError):
            raise InputError(f"lag must be 'fit', a rate in 1/s, a Lag or None, got "
                             f"{lag!r}") from None
    if lag.rate is not None:
        return "fixed", float(lag.rate), lag.bounds
    if not varying:
        notes.append("no record has a time-varying command: the lag has no effect and is "
                     "not fitted")
        return "none", 0.0, lag.bounds
    return "fit", 0.0, lag.bounds


def _user_bounded(model: AbstractModel, bounds) -> set[str]:
    if bounds is None:
        return set()
    out: set[str] = set()
    for side in bounds:
        if isinstance(side, Mapping):
            out |= set(side)
        elif side is not None:
            out |= set(model.param_names)
    return out


class Lag(eqx.Module):
    """The first-order command filter $\\dot u = -\\eta(u - v)$ of :func:`identify`, fitted
    (`rate=None`, searched in `bounds` [1/s]) or fixed at `rate` [1/s]. `identify`'s `lag`
    also takes `"fit"` (`Lag()`), a rate (`Lag(rate=...)`) or None (no filter)."""

    rate: float | None = eqx.field(static=True, default=None)
    bounds: tuple[float, float] = eqx.field(static=True, default=LAG_BOUNDS)

    def __check_init__(self):
        check_lag_bounds(self.bounds)
        if self.rate is not None:
            v = float(self.rate)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"lag (eta) must be a positive rate in 1/s, got {self.rate!r}")


def identify(
    data: Batch | Condition | Sequence[Condition] | str | Sequence[str],
    model: str | AbstractModel,
    *,
    laws: Mapping[str, str] | None = None,
    degrees: Mapping[str, int] | int | None = None,
    lag: Lag | str | float | None = "fit",
    bounds: tuple[Any, Any] | None = None,
    transient: float | str | None = None,
    swarm: Swarm | None = Swarm(),
    polish: Polish | None = Polish(),
    key: int | ArrayLike = 0,
) -> GeneralizedModel:
    """Identify a model whose parameters are laws of the command, from every record at once.

    The records may be sine tests at constant currents or voltages and records whose current
    or command voltage varies in time (a per-sample `command` of `mrjax.data.Condition`), from
    one file or many. Each parameter is a :class:`Law` of the command u; a time-varying command
    v reaches the laws through the first-order filter $\\dot u = -\\eta(u - v)$ (Spencer et al.
    1997), with $\\eta$ fitted or fixed. The law coefficients (and $\\eta$) are found by the
    joint fit of `mrjax.generalize` (swarm on the records' views with variable projection for
    the linear parameters, Levenberg-Marquardt on the views then on the full records,
    std-errors), scored on every sample of every record (an initial `transient` left out).

    **Arguments:**

    - `data`: a `mrjax.data.Batch`, condition(s) or file path(s). Every record needs a
        command: a per-sample `command` (in A or V: one unit for all records) or, for laws of
        the current, a constant `current`.
    - `model`: a model name or object.
    - `degrees`: parameter name -> polynomial degree of its law (or one int for all); the
        others get :func:`default_degrees` for the command's unit (a voltage: Spencer's c0,
        c1, alpha linear for the modified Bouc-Wen), capped by the distinct constant levels
        when no command varies.
    - `laws`: parameter name -> `"poly"` (default) or `"exp"`, the others by `degrees` and
        the defaults (`"fixed"`, None); the forms chosen by the data (`"auto"`) and `"sat"`
        laws need per-test fits at constant commands (`generalize`).
    - `lag`: a :class:`Lag` (fitted in its `bounds` [1/s], or fixed at its `rate`), `"fit"`
        (default: `Lag()`, $\\eta$ searched in `LAG_BOUNDS`), a rate [1/s] to fix it, or None
        for no filter. Without a time-varying command the lag has no effect and is not fitted.
    - `bounds`: `(lower, upper)` of the *parameters* (as `mrjax.fit`): each law's value at
        every node of the command range is searched in it. Default the model's bounds, except
        that a Bouc-Wen-type model's constant delta, beta, gamma are searched on the
        |z|max = 1 scale as delta in `DELTA_RANGE` and q = gamma / delta in `Q_RANGE`.
    - `transient`: drop an initial span of each record from the score: seconds, `"cycle"`
        or None.
    - `swarm`: the swarm's :class:`mrjax.Swarm` (default `Swarm()`; its `params` default:
        window 25 and, for dynamic models, at least `MIN_GENERATIONS_DYNAMIC` generations;
        its `mode` does not apply: the linear laws are always solved by least squares; its
        `view`: score the swarm and a first polish on the records' views,
        `mrjax.data.swarm_view`, by default for the ODE models). None: no swarm.
    - `polish`: the Levenberg-Marquardt stages' :class:`mrjax.Polish` (default `Polish()`;
        views to `tol`, full records to 100 x `tol`; 10 x `tol` where the views' polish is
        skipped; its `uncertainty`: std-errors and identifiability of every coefficient and of
        $\\eta$). None: no polish.
    - `key`: the swarm's seed or PRNG key; same key, same result.

    **Returns:** a :class:`GeneralizedModel` with `method="joint"`, `command_unit` `"A"` or
    `"V"`, `lag` the rate [1/s] (None without a filter), `uncertainty`, and `report` (stage
    timings [s], swarm and polish statistics, which redundancy was fixed). Bouc-Wen-type laws
    are reported on the |z|max = 1 scale at the bottom of the command range.

    Raises :class:`mrjax.InputError` for records without a command, commands in two units,
    bad options, or too few scored samples.
    """
    t0 = time.perf_counter()
    batch = as_batch(data)
    model = get(model)
    unit = command_unit_of(batch)
    cmd = batch_command(batch, unit)
    mask = np.asarray(fit_mask(batch, transient), bool)
    notes: list[str] = []
    n_scored = int(mask.sum())
    if n_scored <= model.n_params:
        raise InputError(f"{n_scored} scored samples are too few for model {model.name!r}")
    lo, hi, varying, n_levels = _command_levels(batch, cmd, mask)
    mode, eta0, lag_box = _lag_mode(lag, varying, notes)
    forms = choose_forms(model, None, None, degrees, laws, n_levels, unit)
    layout = Layout(forms.kinds, forms.sizes, tuple(nodes(lo, hi, d + 1) for d in forms.degrees))
    sw, po = check_settings(swarm, polish)
    problem = _problem(model, batch, layout, bounds, transient, (mode, eta0, lag_box), sw,
                       (cmd, mask, unit, lo, hi), notes)
    timings = {"prepare": time.perf_counter() - t0}
    out = solve_laws(problem, swarm=sw, polish=po,
                     uncertainty=po.uncertainty if po is not None else True, key=key)
    timings.update(out.outcome.timings)
    timings["total"] = time.perf_counter() - t0
    report = LawReport(law_choice="given", lag_mode=mode, notes=tuple(notes), timings=timings,
                       outcome=out.outcome)
    return make_generalized(model, layout, out.coef, "joint", out.rms, (lo, hi), "", None, report,
                            command_unit=unit, lag=None if mode == "none" else out.eta,
                            uncertainty=law_uncertainty_of(model, layout, out))


def _command_levels(batch: Batch, cmd: np.ndarray, mask: np.ndarray
                    ) -> tuple[float, float, bool, float]:
    """`(lowest, highest command, whether a record's command varies in time, distinct
    constant levels (inf where a command varies))` over the scored samples."""
    if cmd.ndim == 2:
        values = cmd[mask]
        varying = bool(np.ptp(values) > 0) and any(
            np.ptp(cmd[i][mask[i]]) > 0 for i in range(batch.n_conditions) if mask[i].any())
    else:
        values = np.repeat(cmd, mask.sum(axis=1))
        varying = False
    if varying:
        return float(values.min()), float(values.max()), True, math.inf
    per = cmd if cmd.ndim == 1 else np.array([c[m][0] for c, m in zip(cmd, mask)])
    return float(values.min()), float(values.max()), False, group_currents(per)[0].size


def _problem(model: AbstractModel, batch: Batch, layout: Layout, bounds: Any, transient: Any,
             lag: tuple[str, float, tuple[float, float]], sw: Swarm | None, command: tuple,
             notes: list[str]) -> LawsProblem:
    """The laws problem of `identify`: the coding (a Bouc-Wen shape searched as
    `(log delta, q)` where it can be), the boxes, the records and their views."""
    mode, eta0, lag_box = lag
    cmd, mask, unit, lo, hi = command
    kinds = layout.kinds
    lo_b, hi_b = check_bounds(model, bounds)
    user = _user_bounded(model, bounds)
    names = model.param_names
    sym = model.scale_symmetry
    z_scale = sym is not None
    shape = {sym.gauge, *sym.balance} if z_scale else set()
    shape_ix = [names.index(k) for k in shape]
    pair = z_scale and all(layout.sizes[p] == 1 and kinds[p] == "poly" for p in shape_ix) \
        and not (user & shape)
    logs = tuple(n for p, n in enumerate(names)
                 if kinds[p] == "poly" and lo_b[p] >= 0 and hi_b[p] > 0
                 and hi_b[p] / max(lo_b[p], LOG_FLOOR * hi_b[p]) >= 100)
    # where nothing else sets a node value (the linear laws' swarm placeholders): mid-box
    nu0 = np.concatenate([np.full(layout.sizes[p], 0.5 * (lo_b[p] + hi_b[p]))
                          for p in range(len(names))])
    obj = build_objective(model, layout, nu0, eta0=eta0, lag=mode, log_params=logs,
                          z_scale=z_scale, pair=pair)
    coding = obj.coding
    lm_lo, lm_hi = bounded_box(model, layout, coding, lo_b, hi_b, lag_box,
                               free_shape=not (user & shape))
    D = coding.n_position
    if z_scale:
        notes.append(f"|z|max = 1 at u = {coding.derived[4]:g} {unit}: "
                     f"delta(u0) = beta(u0) + gamma(u0)")
    full = packed_rows(batch, mask, cmd) if not model.dynamic and cmd.ndim == 1 else \
        make_rows(batch, mask, cmd)
    use_view = model.dynamic if sw is None or sw.view is None else bool(sw.view)
    view = None
    if use_view:
        v = make_view(batch, transient, samples_per_period=JOINT_SAMPLES_PER_PERIOD)
        view = make_rows(v.batch, np.asarray(v.mask) & np.asarray(v.batch.mask),
                         batch_command(v.batch, unit))
    params = sw.params if sw is not None and sw.params is not None else PSOParams(
        window=25, min_generations=min(MIN_GENERATIONS_DYNAMIC if model.dynamic else 0,
                                       sw.generation_cap if sw is not None else 0))
    return LawsProblem(model, layout, obj, lm_lo[:D], lm_hi[:D], lm_lo, lm_hi, full, view,
                       np.linspace(lo, hi, N_LEVELS), pso_params=params)


def check_lag_bounds(lag_bounds) -> tuple[float, float]:
    """`(low, high)` [1/s] of a fitted lag, checked."""
    try:
        a, b = (float(v) for v in lag_bounds)
    except (TypeError, ValueError):
        raise InputError(f"lag_bounds must be (low, high) in 1/s, got {lag_bounds!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and 0 < a < b):
        raise InputError(f"lag_bounds must satisfy 0 < low < high, got {lag_bounds!r}")
    return a, b
