r"""Your own model: a damper model declared by its physics, everything else derived with JAX.

A user declares what only they know:

- the parameters (:class:`Parameter`): name, SI unit, default bounds, whether the force is
    linear in it, optionally a log-scale search and a default law degree over the current;
- `force(p, x, xdot, state) -> F` [N] for one instant (`p.name` reads a parameter);
- for a model with internal state: `state_size`, `rate(p, x, xdot, state) -> dstate/dt`,
    optionally `initial(x0, v0)` (default zeros) and `box(p) -> (lower, upper)`, a region the
    state never leaves (it makes the L-stable scheme's Newton iterates safer).

:class:`Model` turns that into an :class:`mrjax.models.AbstractModel` that every path of mrjax
accepts unchanged. It derives:

- the **regressors of the linear parameters** for the separable swarm: the force is affine in
    them, so its derivative with respect to each (`jax.jacfwd`) is its regressor, and the force
    with all of them at zero is the rest. A regressor that depends on no parameter and no state
    is computed once per record (`basis`); the others per particle (`hysteresis`);
- the **state Jacobian** of the L-stable scheme (`jax.jacfwd` of `rate`, in the integrator);
- a **stiffness estimate** for the sub-step policy: the largest $|\lambda|$ of the state
    Jacobian along reference sine records at the largest |velocity| (and on the corners of a
    finite box);
- **NaN safety**: a non-finite force is an `inf` fitness (`mrjax.objective.masked_rms`), and a
    derivative that is not finite at rest is reported when the model is declared.

It checks the declaration once, each failure one :class:`mrjax.InputError` line naming the
model and the parameter: bounds missing, inverted or non-finite; a log search with a lower
bound <= 0; a name that collides with a built-in; a force or rate of the wrong shape or that
fails to run; a parameter declared linear that is not (tested with exact second derivatives at
random points: the force must be affine in the linear parameters jointly, and the rate must not
depend on them).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from ._base import AbstractModel
from ._declaration import Declaration, Parameter, param_columns
from ._integrate import ODE


def _float_of(*arrays: Array):
    """The float type of the records (float32 for a float32 swarm), else the default float."""
    t = jnp.result_type(*arrays)
    return t if jnp.issubdtype(t, jnp.floating) else jnp.result_type(float)


def _pointwise(fn: Callable, theta: Array, x: Array, xdot: Array, states: Array):
    """`fn(theta_row, x, xdot, state)` at every sample of any leading shape: `theta` (P,) or
    (..., P), `x`, `xdot` (...), `states` (..., S)."""
    shape = x.shape
    if not shape:
        return fn(theta, x, xdot, states)
    flat = int(np.prod(shape))
    x1, v1 = x.reshape(flat), xdot.reshape(flat)
    s1 = states.reshape((flat, states.shape[-1]))
    if theta.ndim > 1:
        th = jnp.broadcast_to(theta, shape + theta.shape[-1:]).reshape(flat, theta.shape[-1])
        out = jax.vmap(fn)(th, x1, v1, s1)
    else:
        out = jax.vmap(fn, in_axes=(None, 0, 0, 0))(theta, x1, v1, s1)
    return jax.tree.map(lambda a: a.reshape(shape + a.shape[1:]), out)


class Model(AbstractModel):
    r"""A damper model declared by its physics (see the module docstring of
    `mrjax.models._declare` and the README section "Your own model").

    **Arguments:**

    - `name`: the model's name (lower case; not one of mrjax's built-in names).
    - `parameters`: a list of :class:`Parameter`, in vector order.
    - `force`: `force(p, x, xdot, state) -> F` [N] for one instant: `p` the parameters by
        name (:class:`Params`), `x` [m], `xdot` [m/s], `state` (S,) (empty for a static model).
        Any jittable JAX code; write `|z|**n` as `mrjax.models.safe_abs_pow(z, n)`.
    - `rate`: `rate(p, x, xdot, state) -> dstate/dt` (S,) for a model with a state.
    - `state_size`: S, 0 for a static (memoryless) model.
    - `initial`: the state at the first sample, a function `initial(x0, v0) -> (S,)` of the
        first displacement [m] and velocity [m/s] or a constant (S,); default zeros.
    - `box`: optional `box(p) -> (lower, upper)`, each (S,) or scalar: a region the state
        never leaves (+-inf allowed; from the nonlinear parameters only); the L-stable scheme
        clips its Newton iterates onto it.
    - `description`, `reference`: one line each, shown by `mrjax models`.
    - `check`: run the numerical checks (default True; they cost about a second). Without
        them every linear parameter's regressor is recomputed per particle.
    - `substeps`, `scheme`, `tangent`: as for every model (`mrjax.models.AbstractModel`).

    Raises :class:`mrjax.InputError` (one line) for a bad declaration.
    """

    declaration: Declaration = eqx.field(static=True)

    rk4_limit: ClassVar[int] = 3

    def __init__(self, name: str, parameters: Sequence[Parameter], force: Callable, *,
                 rate: Callable | None = None, state_size: int = 0,
                 initial: Callable | ArrayLike | None = None, box: Callable | None = None,
                 description: str = "", reference: str = "", check: bool = True,
                 substeps: int | None = None, scheme: str | None = None,
                 tangent: str | None = None):
        self.declaration = Declaration(name, parameters, force, rate, state_size, initial, box,
                                       description, reference, check)
        self.substeps = substeps
        self.scheme = scheme
        self.tangent = tangent

    # ----------------------------------------------------------------------- metadata
    @property
    def name(self) -> str:
        return self.declaration.name

    @property
    def param_names(self) -> tuple[str, ...]:
        return self.declaration.param_names

    @property
    def units(self) -> tuple[str, ...]:
        return self.declaration.units

    @property
    def default_lower(self) -> tuple[float, ...]:
        return self.declaration.lower

    @property
    def default_upper(self) -> tuple[float, ...]:
        return self.declaration.upper

    @property
    def fixed_params(self) -> tuple[str, ...]:
        return self.declaration.fixed

    @property
    def varying_params(self) -> tuple[str, ...]:
        return self.declaration.varying

    @property
    def log_params(self) -> tuple[str, ...]:
        return self.declaration.log_params

    @property
    def dynamic(self) -> bool:
        return self.declaration.state_size > 0

    @property
    def state_size(self) -> int:
        """Size S of the internal state (0 for a static model)."""
        return self.declaration.state_size

    @property
    def description(self) -> str:
        return self.declaration.description

    @property
    def reference(self) -> str:
        """The model's literature reference, if declared."""
        return self.declaration.reference

    @property
    def law_degrees(self) -> dict[str, int]:
        return dict(self.declaration.degrees)

    def with_substeps(self, substeps: int | None, scheme: str | None = None,
                      tangent: str | None = None) -> Model:
        """A copy with a fixed sub-step count and scheme (as `AbstractModel.with_substeps`),
        sharing this model's checked declaration."""
        new = object.__new__(Model)
        for f in dataclasses.fields(self):
            object.__setattr__(new, f.name, getattr(self, f.name))
        object.__setattr__(new, "substeps", substeps)
        object.__setattr__(new, "scheme", scheme)
        object.__setattr__(new, "tangent", tangent)
        new.__check_init__()
        return new

    # ----------------------------------------------------------------------- derived
    def _states(self, theta, x, xdot, dt):
        if self.dynamic:
            return self.states(theta, x, xdot, dt)
        return jnp.zeros(x.shape + (0,), _float_of(x))

    def _split(self, theta, x, xdot, states):
        """`(Z, b)` at every sample: regressors of `varying_params` and the force with every
        linear parameter at zero."""
        d = self.declaration
        zero = {d.index[n] for n in d.linear}
        var = [d.index[n] for n in d.varying]

        def point(th, xi, vi, si):
            cols = [jnp.zeros_like(c) if i in zero else c for i, c in enumerate(param_columns(th))]
            b = d.force_at(cols, xi, vi, si)
            if not var:
                return jnp.zeros((0,), b.dtype), b

            def f(w):
                c = list(cols)
                for j, i in enumerate(var):
                    c[i] = w[j]
                return d.force_at(c, xi, vi, si)

            return jax.jacfwd(f)(jnp.zeros((len(var),), b.dtype)), b

        return _pointwise(point, theta, x, xdot, states)

    def basis(self, x, xdot):
        d = self.declaration
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        dtype = _float_of(x, xdot)
        fixed = [d.index[n] for n in d.fixed]
        if not fixed:
            return jnp.zeros(x.shape + (0,), dtype)
        lo, hi = np.asarray(d.lower), np.asarray(d.upper)
        ref = [jnp.asarray(0.0 if i in fixed else 0.5 * (a + b), dtype)
               for i, (a, b) in enumerate(zip(lo, hi))]
        s0 = jnp.zeros((d.state_size,), dtype)

        def point(xi, vi):
            def f(w):
                c = list(ref)
                for j, i in enumerate(fixed):
                    c[i] = w[j]
                return d.force_at(c, xi, vi, s0)
            return jax.jacfwd(f)(jnp.zeros((len(fixed),), dtype))

        if not x.shape:
            return point(x, xdot)
        return jax.vmap(point)(x.reshape(-1), xdot.reshape(-1)).reshape(x.shape + (len(fixed),))

    def hysteresis(self, theta, x, xdot, dt):
        theta = jnp.asarray(theta)
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        return self._split(theta, x, xdot, self._states(theta, x, xdot, dt))

    def force(self, theta, x, xdot, dt=1e-3):
        """Damper force [N] for a displacement record (arguments as
        `AbstractModel.force`): the declared force at every sample, from the integrated state
        of a dynamic model. Equal, to rounding, to `design`'s affine form (checked at
        declaration), which the separable swarm uses."""
        theta = jnp.asarray(theta)
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        d = self.declaration
        states = self._states(theta, x, xdot, dt)
        return _pointwise(lambda th, xi, vi, si: d.force_at(param_columns(th), xi, vi, si),
                          theta, x, xdot, states)

    def force_at(self, theta, state, x, xdot):
        theta = jnp.asarray(theta)
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        d = self.declaration
        s = jnp.asarray(state) if self.dynamic else jnp.zeros((0,), _float_of(x))
        return d.force_at(param_columns(theta), x, xdot, s)

    def ode(self) -> ODE | None:
        if not self.dynamic:
            return None
        d = self.declaration

        def rhs(state, xi, vi, p):
            return d.rate_at(param_columns(p), xi, vi, state)

        def output(states, theta, x, xdot):
            return self._split(jnp.asarray(theta), jnp.asarray(x), jnp.asarray(xdot),
                               jnp.asarray(states))

        box = (lambda p: d.box_at(param_columns(p))) if d.box_fn is not None else None
        return ODE(rhs=rhs, initial=d.initial_at, output=output, box=box)

    def stiffness(self, theta, vmax):
        """Largest |eigenvalue| [1/s] of the state Jacobian (`jax.jacfwd` of `rate`) along
        reference sine records with velocity amplitude `vmax` [m/s] and amplitudes of 1 mm to
        1 m, integrated from the initial state, and on the corners of a finite box; the
        maximum over rows of `theta` ((P,) or (N, P)). Not finite: `STIFFNESS_UNKNOWN`."""
        return self.declaration.stiffness_rows(np.asarray(theta, float), float(vmax))
