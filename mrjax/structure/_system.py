r"""A single-degree-of-freedom structure around a model, and its simulation.

A mass $m$ on the element $F(y, \dot y, s)$ (any mrjax model: its force for one instant and,
for a model with a state $s$, the state's rate):

- :class:`SDOF`, driven by a force: $m\ddot y + F(y, \dot y, s) = u(t)$;
- :class:`BaseExcited`, driven by a ground acceleration $a_g$ with $y$ relative to the ground:
    $m\ddot y + F(y, \dot y, s) = -m\,a_g(t)$.

:func:`simulate` integrates the state $(y, \dot y, s)$ with classic Runge-Kutta steps in one
`lax.scan`, calling the model's own `force_at` and state rate (`AbstractModel.ode`); the input
between samples is the structure's interpolation (`mrjax.structure.BandLimited` by default).
The observed response is the displacement $y$ or the mass's absolute acceleration.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from ..models import AbstractModel
from ._input import AbstractInterpolation, BandLimited

#: What a structure's record may measure.
RESPONSES: tuple[str, ...] = ("displacement", "acceleration")


class AbstractStructure(eqx.Module):
    """How a single-degree-of-freedom structure is driven and observed.

    **Fields:**

    - `response`: what the record measures: `"displacement"` [m] (relative to the ground for
        a base-excited structure) or `"acceleration"` [m/s²] (the mass's absolute one).
    - `interpolation`: the input between its samples (:class:`mrjax.structure.BandLimited`,
        default; `Linear`, `ZeroOrderHold`).
    - `period`: samples per period of a periodic input in steady state, or None (the
        structure starts from rest). With a period the records hold whole periods; every
        simulation first runs one period and discards it.
    """

    response: str = eqx.field(static=True, default="displacement")
    interpolation: AbstractInterpolation = BandLimited()
    period: int | None = eqx.field(static=True, default=None)

    #: The name of the structure (the command line's `--structure`) and of its input.
    name: ClassVar[str]
    input_name: ClassVar[str]
    input_unit: ClassVar[str]
    #: Whether the records determine the mass (else it must be given).
    mass_identifiable: ClassVar[bool]

    def __check_init__(self):
        if self.response not in RESPONSES:
            raise InputError(f"response must be one of {', '.join(RESPONSES)}, got "
                             f"{self.response!r}")
        if not isinstance(self.interpolation, AbstractInterpolation):
            raise InputError(f"interpolation must be a mrjax.structure interpolation, got "
                             f"{type(self.interpolation).__name__}")
        p = self.period
        if p is not None and (isinstance(p, bool) or int(p) != p or p < 2):
            raise InputError(f"period must be a number of samples >= 2, got {p!r}")

    @abc.abstractmethod
    def acceleration(self, u, force, mass):
        """The acceleration of $y$ [m/s²] from the input `u`, the element's force [N] and the
        mass [kg]."""

    @abc.abstractmethod
    def absolute(self, u, acceleration):
        """The mass's absolute acceleration [m/s²] from that of $y$."""

    @abc.abstractmethod
    def target(self, u, acceleration, mass):
        """The element's force [N] the records imply: what the input, the mass and the measured
        acceleration of $y$ leave for it."""

    @property
    def response_unit(self) -> str:
        """The SI unit of the response."""
        return "m" if self.response == "displacement" else "m/s^2"


class SDOF(AbstractStructure):
    r"""A mass driven by a measured force $u$ [N]: $m\ddot y + F = u$."""

    name: ClassVar[str] = "sdof"
    input_name: ClassVar[str] = "force"
    input_unit: ClassVar[str] = "N"
    mass_identifiable: ClassVar[bool] = True

    def acceleration(self, u, force, mass):
        return (u - force) / mass

    def absolute(self, u, acceleration):
        return acceleration

    def target(self, u, acceleration, mass):
        return u - mass * acceleration


class BaseExcited(AbstractStructure):
    r"""A mass on the element over a ground that accelerates by $a_g$ [m/s²]:
    $m\ddot y + F = -m a_g$, $y$ relative to the ground. The response depends on $F/m$ only,
    so the mass must be known (its bounds equal)."""

    name: ClassVar[str] = "base"
    input_name: ClassVar[str] = "ground_acceleration"
    input_unit: ClassVar[str] = "m/s^2"
    mass_identifiable: ClassVar[bool] = False

    def acceleration(self, u, force, mass):
        return -u - force / mass

    def absolute(self, u, acceleration):
        return acceleration + u

    def target(self, u, acceleration, mass):
        return -mass * (u + acceleration)


#: The structures by name (the command line's `--structure`).
STRUCTURES: dict[str, type[AbstractStructure]] = {c.name: c for c in (SDOF, BaseExcited)}


def simulate(model: AbstractModel, structure: AbstractStructure, z, inputs) -> jax.Array:
    """The response of one record (jittable, differentiable): the state from rest integrated
    by classic Runge-Kutta steps over the record's sub-steps.

    **Arguments:**

    - `model`: the element (`force_at` and its state equation `ode().rhs`).
    - `structure`: an :class:`AbstractStructure`.
    - `z`: the unknowns (1 + P,): the mass [kg], then the model's parameters [SI].
    - `inputs`: `(start, middle, end, h, active, take)`: the input at the start, middle and
        end of every step (S,) (:meth:`AbstractInterpolation.stage_inputs`), the step lengths
        h (S,) [s], whether each step runs (S,) (padding and a shorter warm-up do not), and
        the step indices (n,) at whose start the record's samples lie.

    **Returns:** the response at every sample (n,) [m or m/s²]; non-finite where the
    parameters make the state diverge (never raises).
    """
    start, middle, end, h, active, take = inputs
    mass, theta = z[0], z[1:]
    ode = model.ode()
    s0 = jnp.zeros((0,), z.dtype) if ode is None else jnp.asarray(
        model.initial_state(jnp.zeros((), z.dtype), jnp.zeros((), z.dtype)), z.dtype)
    y0 = jnp.concatenate([jnp.zeros(2, z.dtype), s0])
    observe_acc = structure.response == "acceleration"

    def rate(y, u):
        s = y[2:]
        f = model.force_at(theta, s, y[0], y[1])
        acc = structure.acceleration(u, f, mass)
        ds = ode.rhs(s, y[0], y[1], theta) if ode is not None else s
        return jnp.concatenate([y[1:2], jnp.reshape(acc, (1,)), jnp.reshape(ds, s.shape)]), acc

    def step(y, inp):
        a, b, c, dt, run = inp
        k1, acc = rate(y, a)
        k2, _ = rate(y + 0.5 * dt * k1, b)
        k3, _ = rate(y + 0.5 * dt * k2, b)
        k4, _ = rate(y + dt * k3, c)
        out = structure.absolute(a, acc) if observe_acc else y[0]
        nxt = y + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return jnp.where(run, nxt, y), out

    y_end, outs = jax.lax.scan(step, y0, (start, middle, end, h, active))
    if observe_acc:
        last = structure.absolute(end[-1], rate(y_end, end[-1])[1])
    else:
        last = y_end[0]
    return jnp.append(outs, last)[take]


class ResponseResidual(eqx.Module):
    """The masked residuals of one record: simulated minus measured response, zero on unscored
    samples: `ResponseResidual(model, structure)(z (1 + P,), (inputs, measured (n,), mask
    (n,))) -> (n,)` [m or m/s²] (see :func:`simulate`); with `blocks=True` the posterior's
    form, `((r (1, n), mask (1, n)),)`; with `log_mask` (1 + P,) the unknowns so marked are
    given as their logarithms (a polish's coordinates for a wide positive range)."""

    model: AbstractModel
    structure: AbstractStructure
    blocks: bool = eqx.field(static=True, default=False)
    log_mask: tuple[bool, ...] | None = eqx.field(static=True, default=None)

    def __call__(self, z, data):
        inputs, measured, mask = data
        if self.log_mask is not None:
            z = jnp.where(np.asarray(self.log_mask), jnp.exp(z), z)
        pred = simulate(self.model, self.structure, z, inputs)
        r = jnp.where(mask, pred - measured, 0.0)
        return ((r[None, :], mask[None, :]),) if self.blocks else r


@eqx.filter_jit
def simulate_batch(model, structure, z, inputs):
    """Responses (U, n) of every record with its unknowns `z` (U, 1 + P) (compiled once per
    model, structure and shape)."""
    return jax.vmap(lambda zz, inp: simulate(model, structure, zz, inp))(z, inputs)


def response_rms(model, structure, z: np.ndarray, inputs, measured, mask) -> np.ndarray:
    """(U,) RMS [m or m/s²] of the simulated minus measured responses over the scored samples
    (`inf` where not finite or nothing is scored), on the host."""
    pred = np.asarray(simulate_batch(model, structure, jnp.asarray(z, float), inputs))
    m = np.asarray(mask, bool)
    with np.errstate(invalid="ignore", over="ignore"):
        err = np.where(m, pred - np.asarray(measured), 0.0)
        rms = np.sqrt(np.sum(err * err, axis=1) / np.maximum(m.sum(axis=1), 1))
    return np.where(np.isfinite(rms) & (m.sum(axis=1) > 0), rms, np.inf)
