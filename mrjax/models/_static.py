"""Static (memoryless) models: Bingham (eq 1) and the Kwok et al. tanh model (eq 7-8)."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import ClassVar

import jax.numpy as jnp

from ._base import AbstractModel, split_theta


class Bingham(AbstractModel):
    """Bingham plastic model (eq 1): $f = f_c\\,\\mathrm{sign}(\\dot x) + c_0 \\dot x + f_0$.

    Parameters: `fc` [N] Coulomb (yield) force, `c0` [N·s/m] viscous damping, `f0` [N] offset.
    All three are linear, so the separable swarm solves it exactly.
    """

    name: ClassVar[str] = "bingham"
    param_names: ClassVar[tuple[str, ...]] = ("fc", "c0", "f0")
    units: ClassVar[tuple[str, ...]] = ("N", "N*s/m", "N")
    default_lower: ClassVar[tuple[float, ...]] = (0.0, 0.0, -1000.0)
    default_upper: ClassVar[tuple[float, ...]] = (2500.0, 100000.0, 1000.0)
    basis_params: ClassVar[tuple[str, ...]] = ("fc", "c0", "f0")
    description: ClassVar[str] = "Bingham: f = fc*sign(v) + c0*v + f0"
    #: the yield force saturates with the field (quadratic), the viscous terms linear
    law_degrees: ClassVar[Mapping[str, int]] = MappingProxyType(dict(fc=2, c0=1, f0=1))

    def basis(self, x, xdot):
        xdot = jnp.asarray(xdot)
        return jnp.stack([jnp.sign(xdot), xdot, jnp.ones_like(xdot)], axis=-1)


class Kwok(AbstractModel):
    """The tanh hysteretic model of Kwok et al. 2006 (eq 7-8).

    $$ f = c\\,\\dot x + k\\,x + \\alpha\\,z + f_0,\\qquad
       z = \\tanh\\big(\\beta\\,\\dot x + \\delta\\,\\mathrm{sign}(x)\\big). $$

    Parameters: `c` [N·s/m] viscous damping (loop slope at the ends), `k` [N/m] stiffness,
    `alpha` [N] hysteretic force scale (loop height), `beta` [s/m] hysteretic slope,
    `delta` [-] loop width, `f0` [N] offset. Linear: c, k, alpha, f0.
    """

    name: ClassVar[str] = "kwok"
    param_names: ClassVar[tuple[str, ...]] = ("c", "k", "alpha", "beta", "delta", "f0")
    units: ClassVar[tuple[str, ...]] = ("N*s/m", "N/m", "N", "s/m", "-", "N")
    default_lower: ClassVar[tuple[float, ...]] = (0.0, -100000.0, 0.0, 1.0, 0.0, -1000.0)
    default_upper: ClassVar[tuple[float, ...]] = (100000.0, 100000.0, 2500.0, 10000.0, 5.0, 1000.0)
    basis_params: ClassVar[tuple[str, ...]] = ("c", "k", "f0")
    varying_params: ClassVar[tuple[str, ...]] = ("alpha",)
    log_params: ClassVar[tuple[str, ...]] = ("beta",)
    description: ClassVar[str] = "Kwok tanh: f = c*v + k*x + alpha*tanh(beta*v + delta*sign(x)) + f0"
    #: Kwok et al.'s laws over the current (eq 24-29)
    law_degrees: ClassVar[Mapping[str, int]] = MappingProxyType(dict(c=1, k=1, alpha=2, beta=0,
        delta=1, f0=1))


    def basis(self, x, xdot):
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        return jnp.stack([xdot, x, jnp.ones_like(xdot)], axis=-1)

    def hysteresis(self, theta, x, xdot, dt):
        theta = jnp.asarray(theta)
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        beta, delta = split_theta(theta, self.param_names, "beta", "delta")
        # sign(x) as two compares: XLA:CPU fuses this far better than `sign` in float64
        sgn = (x > 0).astype(x.dtype) - (x < 0).astype(x.dtype)
        z = jnp.tanh(beta * xdot + delta * sgn)
        return z[:, None], jnp.zeros_like(xdot)
