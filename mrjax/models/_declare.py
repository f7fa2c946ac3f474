"""Your own model: :class:`Model`, a damper model declared by its physics, everything else
derived with JAX (see its docstring)."""

from __future__ import annotations

import weakref
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from ._base import AbstractModel
from ._declaration import Declaration, Parameter, param_columns
from ._integrate import ODE
from ._symmetry import ScaleSymmetry


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


class _Declared:
    """A read-only attribute of a :class:`Model`: the declaration's attribute `attr`."""

    def __init__(self, attr: str, doc: str | None = None):
        self.attr = attr
        self.__doc__ = doc

    def __set_name__(self, owner, name):
        if self.__doc__ is None:  # the contract's description of the attribute
            self.__doc__ = f"See `AbstractModel`: the declared `{name}`."

    def __get__(self, obj, owner=None):
        return self if obj is None else getattr(obj.declaration, self.attr)


class Model(AbstractModel):
    r"""A damper model declared by its physics; mrjax derives the rest with JAX.

    You declare what only you know: the parameters, the force for one instant and, for a model
    with internal state, the state's rate. The result is an `AbstractModel` that every path of
    mrjax accepts unchanged (fits, laws, posterior, prediction, the command line).

    ```python
    import jax.numpy as jnp
    from mrjax.models import Model, Parameter, fix

    def force(p, x, xdot, w):           # one instant; w the state, shape (1,)
        return p.c * xdot + p.alpha * w[0] + p.f0

    def rate(p, x, xdot, w):            # dw/dt, an array of the state's shape (1,)
        return p.rho * (xdot - jnp.abs(xdot) * w)

    MyDahl = Model("my_dahl", [
        Parameter("c", "N*s/m", 0.0, 1e5, linear=True),
        Parameter("alpha", "N", 0.0, 2500.0, linear=True),
        Parameter("rho", "1/m", 1.0, 1e4, log=True),
        Parameter("f0", "N", -1e3, 1e3, linear=True),
    ], force, rate=rate, state_size=1)
    MyDahl0 = fix(MyDahl, {"f0": 0.0})  # f0 held at 0: three unknowns
    ```

    `mrjax fit DATA --model file.py:MyDahl0` (or `mrjax.fit(MyDahl0, data)`) fits it;
    `mrjax models --model file.py:MyDahl0` lists it with the checks it passed. More in
    `examples/my_models.py` (Bouc-Wen by its equations).

    **Arguments:**

    - `name`: the model's name (lower case letters, digits, `_`, `-`; not one of mrjax's
        built-in names).
    - `parameters`: a list of :class:`Parameter` (name, SI unit, default bounds, whether the
        force is linear in it, a log-scale search, a default law degree), in vector order.
    - `force`: `force(p, x, xdot, state) -> F` [N] for one instant: `p` the parameters by
        name (`p.c` or `p["c"]`, JAX scalars; :class:`Params`), `x` [m], `xdot` [m/s], `state`
        (S,) (empty for a static model). Any jittable JAX code; write `|z|**n` as
        `mrjax.models.safe_abs_pow(z, n)`.
    - `rate`: `rate(p, x, xdot, state) -> dstate/dt`, an array of the state's shape (S,), for
        a model with a state.
    - `state_size`: S, 0 for a static (memoryless) model.
    - `initial`: the state at the first sample, a function `initial(x0, v0) -> (S,)` of the
        first displacement [m] and velocity [m/s] or a constant (S,); default zeros.
    - `box`: optional `box(p) -> (lower, upper)`, each (S,) or scalar: a region the state
        never leaves (+-inf allowed; from the nonlinear parameters only); the L-stable scheme
        clips its Newton iterates onto it.
    - `description`, `reference`: one line each, shown by `mrjax models`.
    - `check`: run the numerical checks (default True; they take about a second, once per
        declaration). Without them every linear parameter's regressor is recomputed per
        particle.
    - `scale_symmetry`: a :class:`ScaleSymmetry` if the force is unchanged by a rescaling of
        the state (a Bouc-Wen-type z; checked at declaration): joint laws, the posterior and
        the parameter count then fix the scale, as for the built-in Bouc-Wen models.
    - `substeps`, `scheme`, `tangent`: as for every model (`AbstractModel`).

    **What mrjax derives:**

    - the **regressors of the linear parameters** for the separable swarm: the force is
        affine in them, so its derivative with respect to each (`jax.jacfwd`) is its regressor
        and the force with all of them at zero is the rest. A regressor that depends on no
        parameter and no state is computed once per record (`basis`), the others per particle
        (`hysteresis`);
    - the **state Jacobian** of the L-stable scheme (`jax.jacfwd` of `rate`);
    - a **stiffness estimate** for the sub-step policy (`stiffness`): the largest
        $|\lambda|$ of the state Jacobian along reference sine records at the data's largest
        velocity (records on which the state diverges left out) and at the corners of a finite
        state box;
    - **NaN safety**: a non-finite force is an `inf` fitness.

    **What it checks**, once, at declaration (copies share the result): each failure is one
    :class:`mrjax.InputError` line naming the model and the parameter: bounds missing,
    inverted or non-finite; a log search with a lower bound <= 0; a name that collides with a
    built-in; a force that does not give one float per instant, a rate not of the state's
    shape (a scalar for a (1,) state included), an initial state or box of the wrong shape, or
    any of them failing to run; a parameter declared linear that is not (exact second
    derivatives at random points of the default box: the force must be affine in the linear
    parameters jointly, and the rate must not depend on them). A derivative that is not finite
    at rest (x = xdot = 0, the initial state) is a warning. :attr:`checks` lists the checks
    that passed.

    **Fixed parameters:** declare the parameter and hold it with `mrjax.models.fix` (in the
    file, as above, or per fit: `mrjax.fit(model, data, fixed={"A": 1.0})`).
    """

    declaration: Declaration = eqx.field(static=True)

    rk4_limit: ClassVar[int] = 3

    def __init__(self, name: str, parameters: Sequence[Parameter], force: Callable, *,
                 rate: Callable | None = None, state_size: int = 0,
                 initial: Callable | ArrayLike | None = None, box: Callable | None = None,
                 description: str = "", reference: str = "", check: bool = True,
                 scale_symmetry: ScaleSymmetry | None = None, substeps: int | None = None,
                 scheme: str | None = None, tangent: str | None = None):
        self.declaration = _declared(name, parameters, force, rate, state_size, initial, box,
                                     description, reference, check, scale_symmetry)
        self.substeps = substeps
        self.scheme = scheme
        self.tangent = tangent

    # ----------------------------------------------------------------------- metadata
    name = _Declared("name")
    param_names = _Declared("param_names")
    units = _Declared("units")
    default_lower = _Declared("lower")
    default_upper = _Declared("upper")
    basis_params = _Declared("on_basis")
    varying_params = _Declared("varying")
    log_params = _Declared("log_params")
    state_size = _Declared("state_size", "Size S of the internal state (0 for a static model).")
    description = _Declared("description")
    reference = _Declared("reference")
    scale_symmetry = _Declared("symmetry")

    @property
    def dynamic(self) -> bool:
        return self.declaration.state_size > 0

    @property
    def law_degrees(self) -> dict[str, int]:
        return dict(self.declaration.degrees)

    @property
    def checks(self) -> tuple[str, ...]:
        """The declaration's checks that passed, one line each (see the class docstring)."""
        return self.declaration.checks

    def with_substeps(self, substeps: int | None, scheme: str | None = None,
                      tangent: str | None = None) -> Model:
        """A copy with a fixed sub-step count and scheme (as `AbstractModel.with_substeps`),
        sharing this model's checked declaration."""
        d = self.declaration
        return Model(d.name, d.parameters, d.force_fn, rate=d.rate_fn, state_size=d.state_size,
                     initial=d.initial_value, box=d.box_fn, description=d.description,
                     reference=d.reference, check=d.checked, scale_symmetry=d.symmetry,
                     substeps=substeps, scheme=scheme, tangent=tangent)

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
        fixed = [d.index[n] for n in d.on_basis]
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
        maximum over rows of `theta` ((P,) or (N, P)); records on which the state diverges are
        left out, and where nothing finite is left the estimate is `STIFFNESS_UNKNOWN`."""
        return self.declaration.stiffness_rows(np.asarray(theta, float), float(vmax))


#: Checked declarations by their inputs, so that a copy of a model (other sub-steps) and a model
#: declared again from the same functions share one declaration and its checks.
_DECLARATIONS: weakref.WeakValueDictionary = weakref.WeakValueDictionary()


def _declared(name, parameters, force, rate, state_size, initial, box, description, reference,
              check, symmetry) -> Declaration:
    """The checked declaration of these inputs, made once."""
    args = (name, parameters, force, rate, state_size, initial, box, description, reference,
            check, symmetry)
    try:
        key: Any = (name, tuple(parameters), force, rate, state_size,
                    initial if initial is None or callable(initial) else id(initial), box,
                    description, reference, check, symmetry)
        hash(key)
    except TypeError:  # unhashable input: checked (and refused) without the cache
        return Declaration(*args)
    found = _DECLARATIONS.get(key)
    if found is None:
        found = _DECLARATIONS[key] = Declaration(*args)
    return found
