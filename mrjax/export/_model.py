"""`ControllerModel`: an identified damper model as a controller runs it, sample by sample.

It holds the laws over the command (a :class:`mrjax.generalize.GeneralizedModel`; a per-test fit
is one parameter set, constant laws), the model with its integration fixed by mrjax's sub-step
policy (`mrjax.models.resolve_model`), the inverse's search settings and where it came from.
Its three JAX functions of one sample (:meth:`ControllerModel.initial`,
:meth:`ControllerModel.step`, :meth:`ControllerModel.output`) are what the C emitter translates.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InputError
from ..data import Batch
from ..generalize import GeneralizedModel, Law
from ..models import SCHEMES, AbstractModel, fix, from_source, get, resolve_model

#: Default sample interval [s] the sub-steps are chosen for when no records are given (a 1 kHz
#: controller).
DEFAULT_DT = 1e-3
#: Default grid size and refinement steps of the inverse's search (`mrjax.generalize.inverse`'s).
N_GRID, ITERS = 64, 40
#: Longest synthesized record [samples] per test motion when the sub-steps are chosen on the
#: fit's test motions.
MOTION_SAMPLES = 20_000

_FIT_HINT = "run `mrjax fit DATA --model NAME --generalize joint` (or fit one test)"


@dataclasses.dataclass(frozen=True, eq=False)
class ControllerModel:
    """An identified model, ready to export: laws, integration, inverse, provenance.

    **Fields:**

    - `laws`: the :class:`mrjax.generalize.GeneralizedModel` (its laws over the command u, its
        admissible `command_range`, `command_unit` and `lag`).
    - `model`: `laws.model` with its integration fixed (sub-steps and scheme; see
        :meth:`from_generalized`); a static model as it is.
    - `source`: what it was built from (the fit.json path; `""` when built in Python).
    - `sha256`: SHA-256 of that fit.json (`""` when none).
    - `resolved_on`: what the sub-steps were chosen on, in words.
    - `n_grid`, `iters`: the inverse's search: a grid of `n_grid` commands over the range, then
        `iters` bisection (or golden-section) steps (`mrjax.generalize.inverse`'s algorithm).
    """

    laws: GeneralizedModel
    model: AbstractModel
    source: str = ""
    sha256: str = ""
    resolved_on: str = ""
    n_grid: int = N_GRID
    iters: int = ITERS

    def __post_init__(self):
        if int(self.n_grid) < 2 or int(self.iters) < 1:
            raise InputError("the inverse needs n_grid >= 2 and iters >= 1")
        if self.model.dynamic and self.model.substeps is None:
            raise InputError("the model's integration must be fixed (substeps and scheme): "
                             "build it with ControllerModel.from_generalized")

    # ----------------------------------------------------------------------------- building
    @classmethod
    def from_generalized(
        cls,
        laws: GeneralizedModel,
        *,
        records: Batch | None = None,
        motions: ArrayLike | None = None,
        dt: float = DEFAULT_DT,
        substeps: int | None = None,
        scheme: str | None = None,
        source: str = "",
        sha256: str = "",
        n_grid: int = N_GRID,
        iters: int = ITERS,
    ) -> ControllerModel:
        """The exportable model of `laws`, its integration fixed by mrjax's sub-step policy.

        **Arguments:**

        - `laws`: a :class:`mrjax.generalize.GeneralizedModel`.
        - `records`: records like those the controller will see (a `mrjax.data.Batch`): the
            sub-steps are chosen on them exactly as `mrjax predict` chooses them (so the export
            equals `predict` on them to rounding).
        - `motions`: else, sine motions `(frequency [Hz], amplitude [m])` (M, 2), e.g. the
            fit's tests, sampled at `dt` [s] (default 1 ms) over the whole command range.
        - `substeps`, `scheme`: or the integration itself (`scheme` `"rk4"`, the default,
            or `"sdirk"`), overriding both.
        - `source`, `sha256`: provenance written into the header; `n_grid`, `iters`: the
            inverse's search.

        Raises :class:`mrjax.InputError` when a dynamic model gets none of `records`,
        `motions` with a finite frequency and amplitude, or `substeps`.
        """
        if not isinstance(laws, GeneralizedModel):
            raise InputError(f"export needs a GeneralizedModel, got {type(laws).__name__}")
        model, how = _integration(laws, records, motions, dt, substeps, scheme)
        return cls(laws=laws, model=model, source=str(source), sha256=str(sha256),
                   resolved_on=how, n_grid=int(n_grid), iters=int(iters))

    @classmethod
    def from_fit(
        cls,
        path: str | os.PathLike,
        *,
        model: str | AbstractModel | None = None,
        records: Batch | None = None,
        dt: float = DEFAULT_DT,
        substeps: int | None = None,
        scheme: str | None = None,
        n_grid: int = N_GRID,
        iters: int = ITERS,
    ) -> ControllerModel:
        """The exportable model of a `fit.json` written by `mrjax fit` (or its directory): its
        laws (`--generalize`), or its one parameter set (a fit of one test: the command is then
        fixed at that test's current). Without `records` or `substeps` the sub-steps are
        chosen on the fit's test motions sampled at `dt` [s]. `model`: where a user's model is
        when the fit's record of it no longer finds it. Other arguments as
        :meth:`from_generalized`.

        Raises :class:`mrjax.InputError` (one line) for a missing or malformed file, or a fit of
        several tests without laws.
        """
        raw, where = read_fit(path)
        doc = json.loads(raw)
        laws = laws_of(doc, where, model)
        motions = [(c.get("frequency_Hz"), c.get("amplitude_m"))
                   for c in doc.get("conditions") or [] if isinstance(c, Mapping)]
        motions = np.array([[np.nan if v is None else float(v) for v in m] for m in motions],
                           float).reshape(-1, 2)
        return cls.from_generalized(laws, records=records, motions=motions, dt=dt,
                                    substeps=substeps, scheme=scheme, source=str(where),
                                    sha256=hashlib.sha256(raw).hexdigest(), n_grid=n_grid,
                                    iters=iters)

    # ----------------------------------------------------------------------------- layout
    @property
    def model_state_size(self) -> int:
        """S: the size of the model's own state (0 for a static model)."""
        if not self.model.dynamic:
            return 0
        return int(np.shape(self.model.initial_state(0.0, 0.0))[0])

    @property
    def state_size(self) -> int:
        """The exported state's size: the model's S values, then the displacement [m] and
        velocity [m/s] of the last sample, the effective command u there (after the lag) and
        the command given there."""
        return self.model_state_size + 4

    @property
    def command_range(self) -> tuple[float, float]:
        """The admissible command `(min, max)` in `laws.command_unit`."""
        return self.laws.command_range

    # ----------------------------------------------------------------------------- one sample
    def initial(self, x: Float[ArrayLike, ""], xdot: Float[ArrayLike, ""],
                command: Float[ArrayLike, ""]) -> Float[Array, " N"]:
        """The state (N,) at the first sample: the model's initial state at `x` [m], `xdot`
        [m/s], and the command there (the lag starts at it, as `mrjax.generalize.lag_current`)."""
        x, xdot, command = (jnp.asarray(a, float) for a in (x, xdot, command))
        y = self.model.initial_state(x, xdot) if self.model.dynamic else jnp.zeros((0,))
        return jnp.concatenate([jnp.asarray(y, float), jnp.stack([x, xdot, command, command])])

    def step(self, state: Float[ArrayLike, " N"], x: Float[ArrayLike, ""],
             xdot: Float[ArrayLike, ""], command: Float[ArrayLike, ""],
             dt: Float[ArrayLike, ""]) -> tuple[Float[Array, " N"], Float[Array, ""]]:
        """`(state, force)` at the next sample `x` [m], `xdot` [m/s] with `command`, `dt` [s]
        after the last one: the model's state advanced over the interval with the parameters at
        the last effective command (`AbstractModel.advance`, as `force` integrates a record),
        the lag's output $u_{k+1} = v_k + (u_k - v_k)e^{-\\eta\\,dt}$ (without a lag,
        $u_{k+1}$ = `command`), and the force [N] there. `dt = 0`: no time passes (the state
        is kept exactly; the command is recorded)."""
        S = self.model_state_size
        state = jnp.asarray(state, float)
        x, xdot, command, dt = (jnp.asarray(a, float) for a in (x, xdot, command, dt))
        y, x0, v0, u0, c0 = state[:S], state[S], state[S + 1], state[S + 2], state[S + 3]
        moved = dt > 0
        if self.model.dynamic:
            y1 = self.model.advance(y, self.laws.params_at(u0), x0, x, v0, xdot, dt)
            y = jnp.where(moved, y1, y)
        if self.laws.lag is None:
            u = command
        else:
            u = jnp.where(moved, c0 + (u0 - c0) * jnp.exp(-self.laws.lag * dt), u0)
        force = self.model.force_at(self.laws.params_at(u), y, x, xdot)
        return jnp.concatenate([y, jnp.stack([x, xdot, u, command])]), force

    def output(self, state: Float[ArrayLike, " N"], x: Float[ArrayLike, ""],
               xdot: Float[ArrayLike, ""], u: Float[ArrayLike, ""]) -> Float[Array, ""]:
        """The force [N] at the sample of `state` (`x` [m], `xdot` [m/s]) were the effective
        command `u`: the function the inverse searches."""
        y = jnp.asarray(state, float)[:self.model_state_size]
        return self.model.force_at(self.laws.params_at(jnp.asarray(u, float)), y,
                                   jnp.asarray(x, float), jnp.asarray(xdot, float))

    def summary(self) -> list[str]:
        """Lines that say what is exported: model, laws, command, lag, integration."""
        gm = self.laws
        var = "v" if gm.command_unit == "V" else "i"
        what = "command voltage v [V]" if gm.command_unit == "V" else "coil current i [A]"
        lo, hi = self.command_range
        lines = [f"model: {self.model.name}" + (f" ({self.model.description})"
                                                if self.model.description else "")]
        fixed = lo == hi and all(len(gm.laws[n].coefficients) == 1 for n in gm.param_names)
        lines.append("one parameter set (the command has no effect)" if fixed else
                      f"laws of the {what} ({gm.method}; 6 digits here, exact in the code):")
        for n, u in zip(gm.param_names, self.model.units):
            lines.append(f"  {n} = {gm.laws[n].formula(var)}  [{u}]")
        lines.append(f"admissible command: [{lo!r}, {hi!r}] {gm.command_unit}")
        lines.append("no command lag" if gm.lag is None else
                     f"command lag du/dt = -eta (u - {var}), eta = {gm.lag!r} 1/s")
        if self.model.dynamic:
            m, scheme = self.model.substeps, self.model.scheme or "rk4"
            name = {"rk4": "RK4", "sdirk": "L-stable SDIRK2"}[scheme]
            lines.append(f"integration: {name}, {m} sub-step{'s' if m != 1 else ''} per sample "
                         f"({self.resolved_on})")
        return lines


# ------------------------------------------------------------------------------ fit.json
def read_fit(path: str | os.PathLike) -> tuple[bytes, Path]:
    """The bytes of a `fit.json` (or of the one in a directory) and its path. Raises
    :class:`mrjax.InputError` when it is missing or not a JSON object."""
    p = Path(path).expanduser()
    p = p / "fit.json" if p.is_dir() else p
    if not p.is_file():
        raise InputError(f"{path}: no such file (expected a fit.json written by `mrjax fit`)")
    raw = p.read_bytes()
    try:
        doc = json.loads(raw)
    except ValueError as e:  # not UTF-8, or not JSON
        raise InputError(f"{path}: not a fit.json ({' '.join(str(e).split())})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: not a fit.json (expected a JSON object)")
    return raw, p


def laws_of(doc: Mapping[str, Any], where, model=None) -> GeneralizedModel:
    """The laws of a fit.json document: its `"generalized"` block, or its one parameter set as
    constant laws at that test's current (method `"given"`). Raises :class:`mrjax.InputError`
    for a fit of several tests without laws."""
    try:
        if "generalized" in doc:
            block = dict(doc["generalized"])
            block.setdefault("model_source", doc.get("model_source"))
            return GeneralizedModel.from_dict(block, model=model)
        conds = [c for c in doc.get("conditions") or [] if isinstance(c, Mapping)]
        if len(conds) != 1:
            raise InputError(f"this fit has {len(conds)} parameter sets (one per test) and no "
                             f"laws over the current ('generalized' block): an export needs one "
                             f"model; {_FIT_HINT}")
        source = doc.get("model_source") or {}
        if model is None:
            m = from_source(doc["model"], source)
        else:  # the user's model, with the parameters the fit held fixed
            m = get(model)
            held = source.get("fixed") if isinstance(source, Mapping) else None
            m = fix(m.unfixed, held) if held and not m.fixed else m
        params = conds[0]["params"]
        laws = {n: Law("poly", (float(params[n]),)) for n in m.param_names}
        cur = conds[0].get("current_A")
        cur = 0.0 if cur is None or not math.isfinite(float(cur)) else float(cur)
        rms = conds[0].get("rms_N")
        return GeneralizedModel(model=m, laws=laws, method="given",
                                total_rms=float("nan") if rms is None else float(rms),
                                current_range=(cur, cur))
    except InputError as e:
        raise InputError(f"{where}: {e}") from None
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{where}: cannot read the fit ({e!r})") from None


# ------------------------------------------------------------------------------ integration
def _integration(gm: GeneralizedModel, records, motions, dt, substeps, scheme):
    """`(model with its integration fixed, what it was chosen on)` (see `from_generalized`)."""
    m = gm.model
    if not m.dynamic:
        return m, "static model"
    if substeps is not None:
        scheme = scheme or "rk4"
        if scheme not in SCHEMES:
            raise InputError(f"scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")
        return m.with_substeps(int(substeps), scheme), "given"
    if records is not None:  # exactly as `GeneralizedModel.predict` resolves on them
        kind = np.asarray(records.command_kind)
        cur = np.where(kind[:, None] > 0, np.asarray(records.command, float),
                       np.asarray(records.current, float)[:, None])
        return (gm.resolved_model(cur, records.xdot, records.dt, records.mask),
                f"chosen by mrjax's sub-step policy on {records.n_conditions} records")
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f"dt must be a positive interval in s, got {dt!r}")
    mo = np.asarray(motions if motions is not None else np.zeros((0, 2)), float).reshape(-1, 2)
    mo = mo[np.all(np.isfinite(mo), axis=1) & (mo[:, 0] > 0) & (mo[:, 1] > 0)]
    if mo.size == 0:
        raise InputError("the sub-steps of a dynamic model are chosen on records like the "
                         "controller's (`--data`, records=) or on test motions with a frequency "
                         "and amplitude; or give them (`--substeps`, substeps=)")
    xdots, dts = _sines(mo, dt)
    lo, hi = gm.command_range
    rows = np.asarray(gm.params_at(np.linspace(lo, hi, 9)))
    model = resolve_model(m, rows, xdots, dts)
    return model, (f"chosen by mrjax's sub-step policy for dt = {dt:g} s on {len(mo)} sine "
                   f"motions up to {max(2 * np.pi * f * a for f, a in mo):.3g} m/s over the "
                   "command range")


def _sines(motions: np.ndarray, dt: float) -> tuple[tuple, tuple]:
    """Velocity records (one period each, at most `MOTION_SAMPLES`) of sine motions
    `(frequency [Hz], amplitude [m])` sampled at `dt` [s]: groups for `resolve_model`."""
    xdots, dts = [], []
    for f, a in motions:
        n = int(min(MOTION_SAMPLES, max(8, math.ceil(1.0 / (f * dt)) + 1)))
        t = np.arange(n) * dt
        xdots.append((2 * np.pi * f * a * np.cos(2 * np.pi * f * t))[None, :])
        dts.append(np.full((1, n), dt))
    return tuple(xdots), tuple(dts)


def check_names(names: Sequence[str]) -> None:
    """Raise :class:`mrjax.InputError` unless every name is a C identifier."""
    for n in names:
        if not (n and (n[0].isalpha() or n[0] == "_") and all(c.isalnum() or c == "_"
                                                               for c in n) and n.isascii()):
            raise InputError(f"{n!r} is not a C identifier (letters, digits, _)")
