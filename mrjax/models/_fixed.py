"""Parameters held at values: one transformation of any model (:func:`fix`).

`fix(model, {"delta": 1.0})` is a model whose unknowns are the other parameters, with their
names, units, bounds, linearity, log-search flags and law degrees; its force and state rate
insert the held values, and its affine form (`design`) moves a held linear parameter's column
into the offset. Every stage of mrjax (swarm, polish, std-errors, laws, posterior) therefore
honours a fixed parameter without knowing of it: it only sees a model with fewer parameters.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._errors import InputError
from ._base import AbstractModel
from ._integrate import ODE
from ._symmetry import ScaleSymmetry


class _Same:
    """A read-only attribute of a :class:`Fixed` model: its unfixed model's."""

    def __init__(self, attr: str):
        self.attr = attr
        self.__doc__ = f"See `AbstractModel`: the unfixed model's `{attr}`."

    def __get__(self, obj, owner=None):
        return self if obj is None else getattr(obj.model, self.attr)


class _Names(_Same):
    """Parameter names of the unfixed model (a list such as `basis_params`), less the held
    ones."""

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        held = dict(obj.values)
        return tuple(n for n in getattr(obj.model, self.attr) if n not in held)


class _PerParameter(_Same):
    """A value per parameter of the unfixed model (`units`, bounds), less the held ones."""

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        held = dict(obj.values)
        return tuple(v for n, v in zip(obj.model.param_names, getattr(obj.model, self.attr))
                     if n not in held)


class Fixed(AbstractModel):
    """`model` with the parameters of `values` held (built by :func:`fix`; see there).

    **Fields:** `model` the model with every parameter an unknown; `values`
    `((name, value), ...)` the held parameters in `model.param_names` order [SI units]. Its
    integration (`substeps`, `scheme`, `tangent`) is `model`'s.
    """

    model: AbstractModel
    values: tuple[tuple[str, float], ...] = eqx.field(static=True)

    def __init__(self, model: AbstractModel, values: tuple[tuple[str, float], ...]):
        self.model = model
        self.values = tuple((str(n), float(v)) for n, v in values)
        self.substeps, self.scheme, self.tangent = model.substeps, model.scheme, model.tangent

    def __check_init__(self):
        names = self.model.param_names
        if self.model.fixed or not self.values or any(n not in names for n, _ in self.values) \
                or len(self.values) >= len(names):
            raise InputError("build a model with fixed parameters with mrjax.models.fix")

    # ----------------------------------------------------------------------- metadata
    name = _Same("name")
    dynamic = _Same("dynamic")
    reference = _Same("reference")
    rk4_limit = _Same("rk4_limit")
    param_names = _Names("param_names")
    basis_params = _Names("basis_params")
    varying_params = _Names("varying_params")
    log_params = _Names("log_params")
    units = _PerParameter("units")
    default_lower = _PerParameter("default_lower")
    default_upper = _PerParameter("default_upper")

    @property
    def description(self) -> str:
        held = ", ".join(f"{n} = {v:g}" for n, v in self.values) + " fixed"
        return f"{self.model.description} ({held})" if self.model.description else held

    @property
    def law_degrees(self) -> dict[str, int]:
        return {n: d for n, d in self.model.law_degrees.items() if n in self.param_names}

    @property
    def voltage_law_degrees(self) -> dict[str, int]:
        return {n: d for n, d in self.model.voltage_law_degrees.items()
                if n in self.param_names}

    @property
    def scale_symmetry(self) -> ScaleSymmetry | None:
        sym = self.model.scale_symmetry
        return None if sym is None else sym.restrict(dict(self.values))

    @property
    def fixed(self) -> dict[str, float]:
        return dict(self.values)

    @property
    def unfixed(self) -> AbstractModel:
        return self.model

    def expand(self, theta: ArrayLike) -> ArrayLike:
        held = dict(self.values)
        xp = jnp if isinstance(theta, jax.Array) else np
        theta = theta if xp is jnp else np.asarray(theta, float)
        cols, j = [], 0
        for n in self.model.param_names:
            if n in held:
                cols.append(xp.full(theta.shape[:-1], held[n], dtype=theta.dtype))
            else:
                cols.append(theta[..., j])
                j += 1
        return xp.stack(cols, axis=-1)

    def with_substeps(self, substeps: int | None, scheme: str | None = None,
                      tangent: str | None = None) -> Fixed:
        return Fixed(self.model.with_substeps(substeps, scheme, tangent), self.values)

    # ----------------------------------------------------------------------- dynamics
    def stiffness(self, theta: ArrayLike, vmax: float) -> float:
        return self.model.stiffness(self.expand(np.asarray(theta, float)), vmax)

    def resolve_substeps(self, theta: ArrayLike, xdot: ArrayLike, dt: ArrayLike) -> int:
        return self.model.resolve_substeps(self.expand(np.atleast_2d(np.asarray(theta, float))),
                                           xdot, dt)

    def integration(self, theta, xdot, dt) -> tuple[int, str]:
        return self.model.integration(self.expand(theta), xdot, dt)

    # ----------------------------------------------------------------------- force
    def _fold(self, Z: Array, b: Array, basis: Callable[[], Array]) -> tuple[Array, Array]:
        """The unfixed model's `(Z, b)` with the held linear parameters' columns (of `Z`, and
        of the parameter-free `basis()`) times their values moved into `b`."""
        held = dict(self.values)
        base = self.model
        on_basis = [(j, held[n]) for j, n in enumerate(base.basis_params) if n in held]
        if on_basis:
            F = basis()
            for j, v in on_basis:
                b = b + v * F[..., j]
        keep = []
        for j, n in enumerate(base.varying_params):
            if n in held:
                b = b + held[n] * Z[..., j]
            else:
                keep.append(j)
        if len(keep) != Z.shape[-1]:
            Z = Z[..., np.asarray(keep, int)]
        return Z, b

    def basis(self, x, xdot):
        F = self.model.basis(x, xdot)
        held = dict(self.values)
        keep = [j for j, n in enumerate(self.model.basis_params) if n not in held]
        return F if len(keep) == F.shape[-1] else F[..., np.asarray(keep, int)]

    def hysteresis(self, theta, x, xdot, dt):
        Z, b = self.model.hysteresis(self.expand(jnp.asarray(theta)), x, xdot, dt)
        return self._fold(Z, b, lambda: self.model.basis(x, xdot))

    def force(self, theta, x, xdot, dt=1e-3):
        """Damper force [N] (arguments as `AbstractModel.force`): the unfixed model's force
        with the held values inserted."""
        return self.model.force(self.expand(jnp.asarray(theta)), x, xdot, dt)

    # ----------------------------------------------------------------------- state
    def ode(self) -> ODE | None:
        ode = self.model.ode()
        if ode is None:
            return None
        ex = self.expand

        def output(states, theta, x, xdot):
            Z, b = ode.output(states, ex(jnp.asarray(theta)), x, xdot)
            return self._fold(Z, b, lambda: self.model.basis(jnp.asarray(x), jnp.asarray(xdot)))

        def wrap(fn, where):  # `fn` with the parameters, argument `where`, expanded
            if fn is None:
                return None
            return lambda *a: fn(*a[:where], ex(a[where]), *a[where + 1:])

        return ODE(rhs=wrap(ode.rhs, 3), initial=ode.initial, output=output,
                   linearize=wrap(ode.linearize, 3), box=wrap(ode.box, 0),
                   flow=wrap(ode.flow, 1))

    def states(self, theta, x, xdot, dt) -> Array:
        return self.model.states(self.expand(jnp.asarray(theta)), x, xdot, dt)

    def initial_state(self, x0: ArrayLike, v0: ArrayLike) -> Array:
        return self.model.initial_state(x0, v0)

    def advance(self, state, theta, x0, x1, v0, v1, dt) -> Array:
        return self.model.advance(state, self.expand(jnp.asarray(theta)), x0, x1, v0, v1, dt)

    def force_at(self, theta, state, x, xdot) -> Array:
        return self.model.force_at(self.expand(jnp.asarray(theta)), state, x, xdot)


def fix(model: AbstractModel, values: Mapping[str, float]) -> AbstractModel:
    """`model` with the parameters of `values` held at those values.

    The result is a model like any other: its unknowns (`param_names`) are the other
    parameters, with their units, bounds, linearity, log-search flags and law degrees; its
    force and state rate insert the held values; `model.fixed` gives them and `model.unfixed`
    the model with every parameter an unknown. Every stage of mrjax (swarm, polish,
    std-errors, laws, posterior) therefore honours it. Fixing a model that already holds
    parameters adds to them (a value given again replaces the held one).

    **Arguments:**

    - `model`: any model (`mrjax.models.get` gives one by name).
    - `values`: parameter name -> value [SI units], e.g. `{"delta": 1.0}`.

    **Returns:** the model with those parameters held (`model` itself for empty `values`).

    Raises :class:`mrjax.InputError` for a name the model does not have (naming the closest
    parameter), a value that is not a finite number, or values that would fix every parameter.
    """
    if not isinstance(model, AbstractModel):
        raise InputError(f"fix: got {type(model).__name__}, not an mrjax model")
    if not isinstance(values, Mapping):
        raise InputError(f"fixed values must be a mapping name -> value, e.g. {{'A': 1.0}}; "
                         f"got {type(values).__name__}")
    base = model.unfixed
    names = base.param_names
    held = dict(model.fixed)
    for key, value in values.items():
        if key not in names:
            raise InputError(f"model {base.name!r} has no parameter {key!r} to fix; the "
                             f"closest is {_closest(str(key), names)!r} (its parameters: "
                             f"{', '.join(names)})")
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = math.nan
        if isinstance(value, bool) or not math.isfinite(v):
            raise InputError(f"the value to fix parameter {key!r} of model {base.name!r} at "
                             f"must be a finite number, got {value!r}")
        held[key] = v
    if not held:
        return base
    if len(held) == len(names):
        raise InputError(f"model {base.name!r}: fixing {', '.join(names)} leaves no parameter "
                         f"to fit; fix fewer")
    return Fixed(base, tuple((n, held[n]) for n in names if n in held))


def _closest(key: str, names: tuple[str, ...]) -> str:
    """The parameter name most like `key` (case-insensitive): one it starts, or that starts
    it, else the closest spelling."""
    lower = {n.lower(): n for n in names}
    k = key.lower()
    starts = [n for n in lower if n.startswith(k) or k.startswith(n)]
    if starts:
        return lower[min(starts, key=lambda n: abs(len(n) - len(k)))]
    return lower[difflib.get_close_matches(k, list(lower), n=1, cutoff=0.0)[0]]
