r"""The swarm's fitness of a structure: the equation error.

Simulating the structure for every particle would cost one sequential integration of the whole
structure per particle and generation, on a landscape whose basin (the resonance) is narrow.
The swarm scores the element instead, as mrjax scores a damper: the records imply the motion
$(y, \dot y, \ddot y)$ of the mass (`mrjax.structure.motion`), and the element must give the
force $u - m\ddot y$ (`SDOF`; base excitation: $-m(a_g + \ddot y)$). Given the model's
nonlinear parameters, that force is linear in the model's linear parameters and in the mass:
they are solved by least squares (`mrjax.objective.gram_terms`, `solve_normal`), so the swarm
searches the nonlinear parameters only. The polish then fits the simulated response (output
error) from the swarm's best.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..models import AbstractModel
from ..objective import gram_terms, log_search_flags, rms_from_gram, solve_normal
from ..pso import AbstractObjective


class EquationObjective(AbstractObjective):
    """The equation error [N] of one particle on one record's view (see the module
    docstring): positions hold the model's nonlinear parameters (their logarithms where
    `log_mask` says), the unknowns `z = [m, theta]` are completed by least squares.

    A periodic record's view is two periods (`period` samples each) of its periodic part: the
    first lets the element's state settle, and the equation of the second is projected onto
    the lines of the input's spectrum (the view's `keep`), where the record's signal is and its
    noise is least (the equation holds at every line; the motion's derivatives amplify the
    noise at the others).

    **Fields:** `model` (with the swarm's integration); `lower`, `upper` (1 + P,) the box of
    `z`; `log_mask` per nonlinear parameter; `mass_free` whether the mass is solved (else it is
    in the view's target); `period` the samples of a periodic view's period, or None.
    """

    model: AbstractModel
    lower: Float[Array, " K"]
    upper: Float[Array, " K"]
    log_mask: tuple[bool, ...] = eqx.field(static=True, default=())
    mass_free: bool = eqx.field(static=True, default=True)
    period: int | None = eqx.field(static=True, default=None)

    @property
    def linear_z(self) -> np.ndarray:
        """Positions in `z` of the least-squares solution's entries: the model's basis
        parameters, the mass (when free), the model's varying parameters."""
        names = self.model.param_names
        basis = [1 + names.index(n) for n in self.model.basis_params]
        varying = [1 + names.index(n) for n in self.model.varying_params]
        return np.array(basis + ([0] if self.mass_free else []) + varying, int)

    def full(self, position) -> Array:
        """`z` (1 + P,) of a position: its nonlinear parameters, the rest at the box's
        centre."""
        nl = self.model.nonlinear_index + 1
        base = 0.5 * (self.lower + self.upper)
        if nl.size == 0:
            return base
        logs = np.asarray(self.log_mask, bool)
        return base.at[nl].set(jnp.where(logs, jnp.exp(position), position))

    def solve(self, position, data) -> tuple[Array, Array]:
        """`(z (1 + P,), rms [N])` of a position on one record's view."""
        y, v, a, target, mask, dt, keep = data
        z = self.full(position)
        Z, b = self.model.hysteresis(z[1:], y, v, dt)
        F = self.model.basis(y, v)
        if self.mass_free:
            F = jnp.concatenate([F, a[:, None]], axis=1)
        if self.period is not None:  # the second period, on the input's lines
            P, p, k = self.period, F.shape[1], Z.shape[1]
            cols = jnp.concatenate([F, Z, b[:, None], target[:, None]], axis=1)[-P:]
            cols = jnp.fft.irfft(jnp.fft.rfft(cols, axis=0) * keep[:, None], P, axis=0)
            F, Z, b, target = cols[:, :p], cols[:, p:p + k], cols[:, p + k], cols[:, -1]
            mask = mask[-P:]
        gr = gram_terms(F, Z, b, target, mask)
        w = solve_normal(gr.FF, gr.ZF, gr.ZZ, gr.Fy, gr.Zy)
        idx = self.linear_z
        w = jnp.clip(w, self.lower[idx], self.upper[idx])
        return z.at[idx].set(w), rms_from_gram(w, gr.G, gr.g, gr.yy, gr.n)

    def __call__(self, position, data):
        return self.solve(position, data)[1]

    def to_params(self, position, data):
        return self.solve(position, data)[0]


def equation_objective(model: AbstractModel, lower: np.ndarray, upper: np.ndarray,
                       mass_free: bool, period: int | None
                       ) -> tuple[EquationObjective, np.ndarray, np.ndarray]:
    """The swarm's objective of `model` (with the swarm's integration) in the box `[lower,
    upper]` (1 + P,) of `z` (`mass_free`, `period` as :class:`EquationObjective`), and its
    search box (D,): the nonlinear parameters, log-searched where
    `mrjax.objective.log_search_flags` says (one dummy dimension without any)."""
    nl = model.nonlinear_index
    if nl.size == 0:
        return EquationObjective(model, *jax.device_put((lower, upper)), (), mass_free,
                                 period), np.zeros(1), np.zeros(1)
    logs = log_search_flags(model, lower[1:])[nl]
    lo, hi = lower[1:][nl], upper[1:][nl]
    s_lo = np.where(logs, np.log(np.where(logs, lo, 1.0)), lo)
    s_hi = np.where(logs, np.log(np.where(logs, hi, 1.0)), hi)
    obj = EquationObjective(model, *jax.device_put((np.asarray(lower, float),
                                                    np.asarray(upper, float))),
                            tuple(bool(v) for v in logs), mass_free, period)
    return obj, s_lo, s_hi


def position_of(obj: EquationObjective, z: np.ndarray) -> np.ndarray:
    """The swarm positions (..., D) of unknowns `z` (..., 1 + P)."""
    nl = obj.model.nonlinear_index
    if nl.size == 0:
        return np.zeros(z.shape[:-1] + (1,))
    v = np.asarray(z)[..., nl + 1]
    logs = np.asarray(obj.log_mask, bool)
    return np.where(logs, np.log(np.where(logs, np.maximum(v, 1e-300), 1.0)), v)


@eqx.filter_jit
def solve_positions(obj: EquationObjective, position, data):
    """`(z (R, 1 + P), rms (R,) [N])` of one position per row of the view `data`."""
    return jax.vmap(obj.solve)(position, data)
