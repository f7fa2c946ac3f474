"""The model abstraction shared by every damper model.

A model is an immutable `equinox.Module`. It declares its parameter names, SI units, default
bounds and which parameters enter the force linearly, and implements one method,
:meth:`AbstractModel.design`, that returns the force as an affine function of the linear
parameters:

$$ f(t) = \\sum_j A_j(t;\\theta_{nl})\\,\\theta_{lin,j} + b(t;\\theta_{nl}). $$

`force` is derived from `design`, so the separable (variable projection) swarm and the plain
simulation can never disagree.
"""

import abc
import dataclasses
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from equinox import AbstractVar
from jaxtyping import Array, ArrayLike, Float

from .._errors import InputError
from ._integrate import (
    ODE,
    SCHEMES,
    TANGENTS,
    TRACED_SUBSTEPS,
    choose_substeps,
    integrate,
    integrate_step,
    max_abs,
)
from ._symmetry import ScaleSymmetry


class AbstractModel(eqx.Module):
    """Base class of the damper models.

    Every model provides (as class variables, like the hand-written models, or as
    properties, like a declared `mrjax.models.Model`):

    - `name`: registry name, e.g. `"kwok"`.
    - `param_names`: parameter names in vector order.
    - `units`: SI unit of each parameter (text, e.g. `"N*s/m"`).
    - `default_lower`, `default_upper`: default bounds of each parameter, SI units (a damper
        of up to about 2 kN).
    - `basis_params`: linear parameters whose regressor depends on no parameter (e.g. `c`
        with regressor $\\dot x$); their columns come from :meth:`basis`.

    and, where the defaults below do not fit, `varying_params`, `log_params`, `dynamic`,
    `description`, `reference`, `rk4_limit`, `law_degrees`, `voltage_law_degrees`,
    `scale_symmetry`.

    Instance fields (static):

    - `substeps`: integrator steps per sample for dynamic models; `None` chooses
        automatically (see `mrjax.models.resolve_model`).
    - `scheme`: `"rk4"`, `"sdirk"` (L-stable) or `None` (automatic); see
        `mrjax.models.integrate`.
    - `tangent`: how the `"sdirk"` scheme is differentiated, `"exact"` or `"implicit"` (the
        cheaper Jacobian a polish uses; see `mrjax.models.integrate`); `None` is `"exact"`
        (`mrjax.models.resolve_model` sets `"implicit"` for a polish). Values are the same.
    """

    name: AbstractVar[str]
    param_names: AbstractVar[tuple[str, ...]]
    units: AbstractVar[tuple[str, ...]]
    default_lower: AbstractVar[tuple[float, ...]]
    default_upper: AbstractVar[tuple[float, ...]]
    basis_params: AbstractVar[tuple[str, ...]]

    substeps: int | None = eqx.field(static=True, default=None)
    scheme: str | None = eqx.field(static=True, default=None)
    tangent: str | None = eqx.field(static=True, default=None)

    # ----------------------------------------------------------------------------- defaults
    @property
    def varying_params(self) -> tuple[str, ...]:
        """Linear parameters whose regressor depends on the nonlinear ones (e.g. `alpha` with
        regressor z); their columns come from :meth:`hysteresis`."""
        return ()

    @property
    def log_params(self) -> tuple[str, ...]:
        """Nonlinear parameters with a wide positive range, which the separable swarm searches
        in log space."""
        return ()

    @property
    def dynamic(self) -> bool:
        """Whether the model has an internal state, integrated by `mrjax.models.integrate`."""
        return False

    @property
    def description(self) -> str:
        """One line: the model's equations."""
        return ""

    @property
    def reference(self) -> str:
        """The model's literature reference, if any."""
        return ""

    @property
    def rk4_limit(self) -> int:
        """Largest RK4 sub-step count the sub-step policy accepts for this model's polish
        before it switches to the L-stable scheme (see `mrjax.models.resolve_model`)."""
        return 8

    @property
    def fixed_params(self) -> tuple[str, ...]:
        """The former name of :attr:`basis_params` (kept for callers not yet moved)."""
        return self.basis_params

    def __check_init__(self):
        if self.substeps is not None and (int(self.substeps) != self.substeps or self.substeps < 1):
            raise InputError(f"substeps must be a positive integer or None, got {self.substeps!r}")
        if self.scheme is not None and self.scheme not in SCHEMES:
            raise InputError(f"scheme must be one of {', '.join(SCHEMES)} or None, got "
                             f"{self.scheme!r}")
        if self.tangent is not None and self.tangent not in TANGENTS:
            raise InputError(f"tangent must be one of {', '.join(TANGENTS)} or None, got "
                             f"{self.tangent!r}")

    # ----------------------------------------------------------------------------- metadata
    @property
    def n_params(self) -> int:
        """Number of parameters P."""
        return len(self.param_names)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Default `(lower, upper)` bounds as float arrays of shape (P,), in SI units."""
        return np.asarray(self.default_lower, float), np.asarray(self.default_upper, float)

    @property
    def linear_params(self) -> tuple[str, ...]:
        """Names of the parameters the force is linear in: `basis_params + varying_params`."""
        return tuple(self.basis_params) + tuple(self.varying_params)

    @property
    def linear_index(self) -> np.ndarray:
        """Indices of the linear parameters, in `param_names` order."""
        return np.array([self.param_names.index(n) for n in self.linear_params], dtype=int)

    @property
    def nonlinear_index(self) -> np.ndarray:
        """Indices of the parameters that are not linear."""
        lin = set(self.linear_params)
        return np.array([i for i, n in enumerate(self.param_names) if n not in lin], dtype=int)

    @property
    def law_degrees(self) -> Mapping[str, int]:
        """Default polynomial degrees of some parameters' laws over the command (a coil current
        in A), by name, that the model declares itself (see
        `mrjax.generalize.default_degrees`); parameters not named take the generic defaults."""
        return {}

    @property
    def voltage_law_degrees(self) -> Mapping[str, int]:
        """Default law degrees over a command *voltage* where they differ from
        :attr:`law_degrees` (e.g. Spencer et al.'s voltage laws of the modified Bouc-Wen);
        parameters not named take :attr:`law_degrees`."""
        return {}

    @property
    def scale_symmetry(self) -> ScaleSymmetry | None:
        """The rescaling of the state that leaves the force unchanged, if the model has one
        (:class:`mrjax.models.ScaleSymmetry`: Bouc-Wen-type models, z -> s z), else None. A
        fitted parameter vector is then one point of a one-parameter family with the same
        force: a joint fit, a posterior or a parameter count must fix the scale."""
        return None

    # ----------------------------------------------------------------------------- fixed
    @property
    def fixed(self) -> dict[str, float]:
        """Parameters held at a value (`mrjax.models.fix`), by name [SI units]; they are not
        among `param_names`. Empty for a model whose parameters are all unknowns."""
        return {}

    @property
    def unfixed(self) -> "AbstractModel":
        """This model with every parameter an unknown (itself when nothing is fixed)."""
        return self

    def expand(self, theta: ArrayLike) -> ArrayLike:
        """Parameters of :attr:`unfixed` (..., P') from this model's (..., P): the fixed
        values inserted in their places (`theta` itself when nothing is fixed)."""
        return theta

    def default_start(self) -> np.ndarray:
        """The neutral start used by `method="lm"`: the centre of the default box (the
        geometric centre for `log_params`), shape (P,). It knows nothing about the data, which
        is the point: it shows what a local fit does without the swarm."""
        lo, hi = self.bounds
        mid = 0.5 * (lo + hi)
        for n in self.log_params:
            i = self.param_names.index(n)
            if lo[i] > 0:
                mid[i] = np.sqrt(lo[i] * hi[i])
        return mid

    def params(self, **values: float) -> np.ndarray:
        """Build a parameter vector from keyword values, e.g. `model.params(c=1232., ...)`.

        Raises :class:`mrjax.InputError` naming missing or unknown parameters.
        """
        unknown = set(values) - set(self.param_names)
        missing = [n for n in self.param_names if n not in values]
        if unknown or missing:
            raise InputError(
                f"model {self.name!r}: unknown parameters {sorted(unknown)}, missing {missing}; "
                f"expected {list(self.param_names)}"
            )
        return np.array([float(values[n]) for n in self.param_names])

    def with_substeps(self, substeps: int | None, scheme: str | None = None,
                      tangent: str | None = None) -> "AbstractModel":
        """Return a copy with a fixed sub-step count and integration scheme (`"rk4"`, the
        default for a fixed count, or `"sdirk"`), or `None` for automatic; `tangent` how
        `"sdirk"` is differentiated (`"exact"`, the default, or `"implicit"`)."""
        return dataclasses.replace(self, substeps=substeps, scheme=scheme, tangent=tangent)

    # ----------------------------------------------------------------------------- dynamics
    def stiffness(self, theta: ArrayLike, vmax: float) -> float:
        """Host-side estimate of the largest state-equation rate $|\\lambda|$ [1/s].

        **Arguments:** `theta` parameters (P,) or a `(lower, upper)`-like array of rows
        (the maximum over rows is taken); `vmax` largest |velocity| [m/s].
        """
        return 0.0

    def resolve_substeps(self, theta: ArrayLike, xdot: ArrayLike, dt: ArrayLike) -> int:
        """Sub-step count for concrete inputs: `self.substeps` if set, else from `stiffness`.

        `theta` may be one vector (P,) or several rows (N, P) (e.g. both bounds); the stiffest
        row decides.
        """
        if not self.dynamic:
            return 1
        if self.substeps is not None:
            return int(self.substeps)
        rows = np.atleast_2d(np.asarray(theta, float))
        vmax = max_abs(xdot)
        rate = max(self.stiffness(r, vmax) for r in rows)
        return choose_substeps(rate, max_abs(dt))

    def integration(self, theta, xdot, dt) -> tuple[int, str]:
        """`(substeps, scheme)` the model integrates with on these inputs: the fixed ones if
        set (a count without a scheme means RK4), `TRACED_SUBSTEPS` RK4 steps on traced inputs,
        else the host rule of `resolve_substeps` (RK4)."""
        if not self.dynamic:
            return 1, "rk4"
        if self.substeps is not None:
            return int(self.substeps), self.scheme or "rk4"
        if self.scheme == "sdirk":
            return 1, "sdirk"
        if any(isinstance(a, jax.core.Tracer) for a in (theta, xdot, dt)):
            return TRACED_SUBSTEPS, "rk4"
        th = np.asarray(theta, float)
        rows = th if th.ndim == 1 else th.reshape(-1, th.shape[-1])
        return self.resolve_substeps(rows, xdot, dt), "rk4"

    # ----------------------------------------------------------------------------- force
    @abc.abstractmethod
    def basis(self, x: Float[ArrayLike, " T"], xdot: Float[ArrayLike, " T"]) -> Float[Array, "T p"]:
        """Parameter-free regressors of `basis_params`, shape (T, p) [N per unit parameter]."""

    def hysteresis(self, theta: Float[ArrayLike, "*T P"], x: Float[ArrayLike, " T"],
                   xdot: Float[ArrayLike, " T"], dt: Float[ArrayLike, "*T"]
                   ) -> tuple[Float[Array, "T k"], Float[Array, " T"]]:
        """Parameter-dependent part: regressors `Z` (T, k) of `varying_params` and the force
        `b` (T,) [N] of the nonlinear parameters alone. Entries of `theta` at linear positions
        are ignored. A dynamic model's is its state equation's output along the integrated
        states (:meth:`ode`, :meth:`states`); a static one without parameter-dependent terms
        has none."""
        theta = jnp.asarray(theta)
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        if self.dynamic:
            return self.ode().output(self.states(theta, x, xdot, dt), theta, x, xdot)
        return jnp.zeros(xdot.shape + (0,), xdot.dtype), jnp.zeros_like(xdot)

    def design(self, theta: Float[ArrayLike, "*T P"], x: Float[ArrayLike, " T"],
               xdot: Float[ArrayLike, " T"], dt: Float[ArrayLike, "*T"]
               ) -> tuple[Float[Array, "T L"], Float[Array, " T"]]:
        """Affine form of the force in the linear parameters.

        **Arguments:** as :meth:`force`. Entries of `theta` at linear positions are ignored.

        **Returns:** `(A, b)` with `A` of shape (T, L) [N per unit of each linear parameter]
        and `b` of shape (T,) [N], so that `force = A @ theta[linear_index] + b`.
        """
        Z, b = self.hysteresis(theta, x, xdot, dt)
        return jnp.concatenate([self.basis(x, xdot), Z], axis=-1), b

    # ----------------------------------------------------------------------------- state
    def ode(self) -> ODE | None:
        """The state equation of a dynamic model (:class:`mrjax.models.ODE`), None for a
        static one. `hysteresis` integrates it over a record; :meth:`initial_state`,
        :meth:`advance` and :meth:`force_at` step it one sample at a time."""
        return None

    def states(self, theta, x, xdot, dt) -> Array:
        """The state at every sample (T, S) of a dynamic model on a record (arguments as
        :meth:`force`), integrated as :meth:`integration` says."""
        ode = self.ode()
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        m, scheme = self.integration(theta, xdot, dt)
        return integrate(ode, ode.initial(x[0], xdot[0]), theta, x, xdot, dt, m, scheme=scheme,
                         tangent=self.tangent or "exact")

    def initial_state(self, x0: ArrayLike, v0: ArrayLike) -> Array:
        """The state (S,) at the first sample of a record starting at `x0` [m], `v0` [m/s]."""
        return self.ode().initial(jnp.asarray(x0), jnp.asarray(v0))

    def advance(self, state: ArrayLike, theta: ArrayLike, x0, x1, v0, v1, dt) -> Array:
        """The state (S,) at the next sample from `state` (S,) at this one, parameters `theta`
        (P,) held over the interval, the excitation going linearly from (`x0` [m], `v0` [m/s])
        to (`x1`, `v1`) over `dt` [s]: one interval of the integration of `force`, with the
        model's sub-steps and scheme (fix them with :meth:`with_substeps` or
        `resolve_model`; otherwise `TRACED_SUBSTEPS` RK4 steps)."""
        m, scheme = self.integration(theta, jnp.stack([jnp.asarray(v0), jnp.asarray(v1)]), dt)
        return integrate_step(self.ode(), state, theta, x0, x1, v0, v1, dt, m, scheme=scheme,
                              tangent=self.tangent or "exact")

    def force_at(self, theta: ArrayLike, state: ArrayLike, x: ArrayLike,
                 xdot: ArrayLike) -> Array:
        """Force [N] at one sample from its state (S,) (ignored by static models), parameters
        `theta` (P,), displacement `x` [m] and velocity `xdot` [m/s]: what `force` gives at
        that sample."""
        theta = jnp.asarray(theta)
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        F = self.basis(x[None], xdot[None])[0]
        ode = self.ode()
        if ode is None:
            Z, b = self.hysteresis(theta, x[None], xdot[None], 1.0)
            Z, b = Z[0], b[0]
        else:
            Z, b = ode.output(jnp.asarray(state), theta, x, xdot)
        return self._combine(theta, F, Z, b)

    def _combine(self, theta, F, Z, f):
        """`f` plus the linear parameters times their regressors `F`, `Z` (the force)."""
        names = self.param_names
        for j, n in enumerate(self.basis_params):
            f = f + theta[..., names.index(n)] * F[..., j]
        for j, n in enumerate(self.varying_params):
            f = f + theta[..., names.index(n)] * Z[..., j]
        return f

    def force(self, theta: Float[ArrayLike, "*T P"], x: Float[ArrayLike, " T"],
              xdot: Float[ArrayLike, " T"], dt: Float[ArrayLike, "*T"] = 1e-3
              ) -> Float[Array, " T"]:
        """Damper force [N] for a displacement record.

        **Arguments:**

        - `theta`: parameters in `param_names` order, shape (P,), or per sample (T, P) for a
            time-varying (current-driven) model.
        - `x`: displacement [m], shape (T,).
        - `xdot`: velocity [m/s], shape (T,).
        - `dt`: sample interval [s], scalar or (T,); used by dynamic models only.

        **Returns:** force [N], shape (T,). Parameters that make an ODE diverge give non-finite
        values; this never raises.
        """
        theta = jnp.asarray(theta)
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        Z, f = self.hysteresis(theta, x, xdot, dt)
        return self._combine(theta, self.basis(x, xdot), Z, f)


def split_theta(theta: Array, names: tuple[str, ...], *wanted: str) -> list[Array]:
    """Columns of `theta` (shape (P,) or (T, P)) by name, each of shape () or (T,)."""
    return [theta[..., names.index(w)] for w in wanted]


def safe_abs_pow(z: Array, n: Array) -> Array:
    """$|z|^n$ with finite value and gradients everywhere, including z = 0 and any n > 0.

    `jnp.abs(z) ** n` has a NaN gradient with respect to `n` at z = 0 (0 * log 0) and an infinite
    one with respect to z for n < 1; this form returns 0 with zero gradient there.
    """
    a = jnp.abs(z)
    pos = a > 0
    a_safe = jnp.where(pos, a, 1.0)
    return jnp.where(pos, a_safe**n, 0.0)
