"""ODE-based hysteretic models: Bouc-Wen (eq 2-3), modified Bouc-Wen (eq 4-6) and Dahl.

All three define only their right-hand side; the shared RK4 `lax.scan` in `_integrate` steps it.

A note on the scale of z. The equations are invariant under $z \\to s z$ with
$\\alpha \\to \\alpha/s$, $\\delta \\to s\\delta$, $\\beta, \\gamma \\to s^{1-n}\\beta, s^{1-n}\\gamma$,
so one of (alpha, delta, beta, gamma) is redundant (`AbstractModel.scale_symmetry`). mrjax's
*default bounds* assume a
dimensionless z of order one, so `alpha` is in N and `delta`, `beta`, `gamma` in 1/m.
Spencer et al.'s 1997 set (PAPER.md) measures z in metres (alpha in N/m, beta and gamma in
m^-n); the equations are the same and `force` accepts either.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from ._base import AbstractModel, split_theta
from ._integrate import ODE
from ._symmetry import ScaleSymmetry

#: The z-scale of the Bouc-Wen evolution (see the module docstring): alpha / s, delta * s,
#: beta and gamma * s^(1 - n); canonical |z|max = (delta / (beta + gamma))^(1/n) = 1.
BW_EXPONENTS = (("alpha", -1.0, 0.0), ("delta", 1.0, 0.0), ("beta", 1.0, -1.0),
                ("gamma", 1.0, -1.0))


def bw_zdot_lin(z, u, delta, beta, gamma, n):
    r"""`(zdot, d zdot/dz, d zdot/du)` of the Bouc-Wen evolution
    $\dot z = \delta u - |z|^n (\beta u + \gamma |u| \mathrm{sign}(z))$, which equals
    $\delta u - \beta u |z|^n - \gamma z |u| |z|^{n-1}$, for relative velocity `u`.

    Speed (this runs C x N x steps times per sample): one `log` and one `exp` for the value and
    both derivatives ($|z|^{n-1}$ as `exp((n-1) log|z|)`, which XLA:CPU vectorises where `pow`
    is a scalar libm call, then $|z|^n = |z|\,|z|^{n-1}$); signs as selects. 0 at z = 0 with
    finite gradients (the `safe_abs_pow` convention). d zdot/dz is positive only on the
    unstable unloading branch of beta > gamma; the models' Newton matrices clip it at 0 there,
    where it could only make the L-stable scheme's Newton matrix singular (it enters no
    solution, only the iteration), while their Jacobians keep it (the implicit tangent's)."""
    a = jnp.abs(z)
    nz = a > 0
    q = jnp.where(nz, jnp.exp((n - 1.0) * jnp.log(jnp.where(nz, a, 1.0))), 0.0)
    pw = a * q
    one = jnp.ones_like(pw)  # keeps float32 in float32 (a bare 1.0 is float64 under x64)
    sz = jnp.where(z >= 0, one, -one)
    su = jnp.where(u >= 0, one, -one)
    au = jnp.abs(u)
    zd = delta * u - beta * u * pw - gamma * au * sz * pw
    dz = -n * q * (beta * u * sz + gamma * au)
    du = delta - (beta + gamma * su * sz) * pw
    return zd, dz, du


def _bw_zdot(z, u, delta, beta, gamma, n):
    r"""The Bouc-Wen evolution $\dot z$ alone (XLA drops the derivatives' unused parts)."""
    return bw_zdot_lin(z, u, delta, beta, gamma, n)[0]


def bw_zmax(delta, beta, gamma, n):
    r"""The bound of the Bouc-Wen z from z(0) = 0: $|z| \le (\delta/(\beta+\gamma))^{1/n}$
    (the loading fixed point; unloading only shrinks |z|). `inf` where beta + gamma <= 0 or
    delta <= 0 (unbounded: a diverging particle stays visible). Finite gradients."""
    s = beta + gamma
    ok = (s > 0) & (delta > 0)
    r = jnp.where(ok, delta / jnp.where(ok, s, 1.0), 1.0)
    return jnp.where(ok, jnp.exp(jnp.log(r) / n), jnp.inf)


def dahl_flow(w, rho, v0, v1, h):
    r"""Exact Dahl update over an interval in which the velocity goes linearly from v0 to v1.

    For a fixed sign s of v, $\dot w = \rho|v|(s - w)$ gives
    $w_1 = s + (w_0 - s)e^{-\rho\int|v|}$; a sign change at $s^* = v_0/(v_0 - v_1)$ splits
    the interval in two such pieces. Two `exp`, no stiffness limit, |w| <= 1 kept exactly;
    finite gradients (guarded division)."""
    cross = v0 * v1 < 0
    sstar = jnp.where(cross, v0 / jnp.where(cross, v0 - v1, 1.0), 1.0)
    a0, a1 = jnp.abs(v0), jnp.abs(v1)
    i1 = 0.5 * h * sstar * (a0 + jnp.where(cross, 0.0, a1))
    s1 = jnp.sign(v0 + jnp.where(cross, 0.0, v1))
    w = s1 + (w - s1) * jnp.exp(-rho * i1)
    i2 = jnp.where(cross, 0.5 * h * (1.0 - sstar) * a1, 0.0)
    s2 = jnp.sign(v1)
    return s2 + (w - s2) * jnp.exp(-rho * i2)


def _zero_state(x0, v0):
    """The state (1,) at the first sample of a one-state model: 0."""
    return jnp.zeros((1,), jnp.asarray(x0).dtype)


def _state_regressor(states, theta, x, xdot):
    """`(Z, b)` of a model whose one state is the regressor of its varying parameter."""
    return states, jnp.zeros_like(jnp.asarray(xdot))


def _bw_rate(delta, beta, gamma, n, vmax):
    """|d zdot / d z| bound: n (|beta|+|gamma|) |z|max^(n-1) vmax, |z|max the steady state."""
    s = abs(beta) + abs(gamma)
    if s <= 0 or not np.isfinite(s):
        return 0.0
    n = max(float(n), 1e-6)
    zmax = max((abs(delta) / s) ** (1.0 / n), 1e-12)
    return n * s * zmax ** (n - 1.0) * vmax + 0.0


class BoucWen(AbstractModel):
    """Bouc-Wen model (eq 2-3), z(0) = 0.

    $$ f = c\\dot x + k x + \\alpha z + f_0,\\qquad
       \\dot z = \\delta\\dot x - \\beta\\dot x|z|^n - \\gamma z|\\dot x||z|^{n-1}. $$

    Parameters: `c` [N·s/m], `k` [N/m], `alpha` [N] (z dimensionless), `f0` [N],
    `delta` [1/m], `beta` [1/m], `gamma` [1/m], `n` [-]. Linear: c, k, alpha, f0.
    """

    name: ClassVar[str] = "bouc_wen"
    param_names: ClassVar[tuple[str, ...]] = ("c", "k", "alpha", "f0", "delta", "beta", "gamma", "n")
    units: ClassVar[tuple[str, ...]] = ("N*s/m", "N/m", "N", "N", "1/m", "1/m", "1/m", "-")
    default_lower: ClassVar[tuple[float, ...]] = (0.0, -100000.0, 0.0, -1000.0, 1.0, 0.0, 0.0, 1.0)
    default_upper: ClassVar[tuple[float, ...]] = (
        100000.0, 100000.0, 2500.0, 1000.0, 5000.0, 5000.0, 5000.0, 3.0,
    )
    basis_params: ClassVar[tuple[str, ...]] = ("c", "k", "f0")
    varying_params: ClassVar[tuple[str, ...]] = ("alpha",)
    dynamic: ClassVar[bool] = True
    rk4_limit: ClassVar[int] = 3  # above, the L-stable scheme's Jacobian pass is cheaper
    description: ClassVar[str] = "Bouc-Wen: f = c*v + k*x + alpha*z + f0, z' = BW(delta, beta, gamma, n)"
    #: force scales linear in the current, the hysteretic force quadratic (it saturates with
    #: the field), the loop's shape constant (on the |z|max = 1 scale)
    law_degrees: ClassVar[Mapping[str, int]] = MappingProxyType(dict(c=1, k=1, alpha=2, f0=1,
        delta=0, beta=0, gamma=0, n=0))
    scale_symmetry: ClassVar[ScaleSymmetry] = ScaleSymmetry(
        BW_EXPONENTS, gauge="delta", balance=("beta", "gamma"), power="n", state=(1.0,))

    def basis(self, x, xdot):
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        return jnp.stack([xdot, x, jnp.ones_like(xdot)], axis=-1)

    def stiffness(self, theta, vmax):
        d, b, g, n = (float(theta[self.param_names.index(k)]) for k in ("delta", "beta", "gamma", "n"))
        return _bw_rate(d, b, g, n, vmax)

    def ode(self) -> ODE:
        names = self.param_names

        def shape(p):
            return split_theta(p, names, "delta", "beta", "gamma", "n")

        def rhs(state, xi, vi, p):
            return _bw_zdot(state, vi, *shape(p))

        def lin(state, xi, vi, p):  # the scalar Newton step clips d zdot/dz at 0 itself
            zd, dz, _ = bw_zdot_lin(state[0], vi, *shape(p))
            return zd[None], dz[None, None]

        def box(p):
            zm = bw_zmax(*shape(p))
            return -zm, zm

        return ODE(rhs=rhs, initial=_zero_state, output=_state_regressor, linearize=lin, box=box)


class ModifiedBoucWen(AbstractModel):
    """Modified Bouc-Wen model of Spencer et al. 1997 (eq 4-6), y(0) = x(0), z(0) = 0.

    $$ f = c_1\\dot y + k_1 x + f_0,\\qquad
       \\dot y = \\frac{c_0\\dot x + k_0(x-y) + \\alpha z}{c_0 + c_1},$$
    $$ \\dot z = \\delta(\\dot x-\\dot y) - \\beta(\\dot x-\\dot y)|z|^n
                - \\gamma z|\\dot x-\\dot y||z|^{n-1}. $$

    Parameters: `c0` [N·s/m], `k0` [N/m], `c1` [N·s/m] (the paper's d1), `k1` [N/m], `alpha`
    [N] (z dimensionless; N/m for Spencer's z in metres), `delta` [1/m] (Spencer's A),
    `beta` [1/m], `gamma` [1/m], `n` [-], `f0` [N] ($= -k_1 x_0$). Linear: k1, f0.

    The default box lets `beta` be negative (down to -5000 /m): the Bouc-Wen loop shape only
    needs $\\gamma + \\beta > 0$, and measured dampers often sit near $\\beta \\approx -\\gamma$,
    where a box with $\\beta \\ge 0$ would hold the fit on its bound. A particle with
    $\\gamma + \\beta \\le 0$ has an unbounded z: a poor score, `inf` where it overflows.
    """

    name: ClassVar[str] = "modified_bouc_wen"
    param_names: ClassVar[tuple[str, ...]] = (
        "c0", "k0", "c1", "k1", "alpha", "delta", "beta", "gamma", "n", "f0",
    )
    units: ClassVar[tuple[str, ...]] = (
        "N*s/m", "N/m", "N*s/m", "N/m", "N", "1/m", "1/m", "1/m", "-", "N",
    )
    default_lower: ClassVar[tuple[float, ...]] = (
        0.0, 0.0, 2000.0, -100000.0, 0.0, 1.0, -5000.0, 0.0, 1.0, -1000.0,
    )
    default_upper: ClassVar[tuple[float, ...]] = (
        100000.0, 100000.0, 200000.0, 100000.0, 2500.0, 5000.0, 5000.0, 5000.0, 3.0, 1000.0,
    )
    basis_params: ClassVar[tuple[str, ...]] = ("k1", "f0")
    dynamic: ClassVar[bool] = True
    # RK4 while it needs at most 2 sub-steps per L-stable one: the cost ratio of their
    # Jacobian passes for this model (see `mrjax.models.resolve_model`)
    rk4_limit: ClassVar[int] = 2
    description: ClassVar[str] = "Modified Bouc-Wen (Spencer 1997): f = c1*y' + k1*x + f0"
    #: the dashpots linear in the current, the hysteretic force quadratic, Spencer's constant
    #: springs and offset (f0 = -k1 x0), the loop's shape constant
    law_degrees: ClassVar[Mapping[str, int]] = MappingProxyType(dict(c0=1, k0=0, c1=1, k1=0,
        alpha=2, delta=0, beta=0, gamma=0, n=0, f0=0))
    #: Spencer et al.'s laws of the filtered command voltage: c0, c1 and alpha linear
    voltage_law_degrees: ClassVar[Mapping[str, int]] = MappingProxyType(dict(alpha=1))
    scale_symmetry: ClassVar[ScaleSymmetry] = ScaleSymmetry(
        BW_EXPONENTS, gauge="delta", balance=("beta", "gamma"), power="n", state=(0.0, 1.0))

    def basis(self, x, xdot):
        x = jnp.asarray(x)
        return jnp.stack([x, jnp.ones_like(x)], axis=-1)

    def stiffness(self, theta, vmax):
        idx = self.param_names.index
        d, b, g, n = (float(theta[idx(k)]) for k in ("delta", "beta", "gamma", "n"))
        c0, c1, k0 = float(theta[idx("c0")]), float(theta[idx("c1")]), float(theta[idx("k0")])
        alpha = float(theta[idx("alpha")])
        # The (y, z) Jacobian is [[-k0/D, alpha/D], [g k0/D, -g alpha/D - w]] with D = c0 + c1,
        # g = d zdot / d u in [0, 2|delta|] on the envelope |z|^n <= |delta| / (|beta| + |gamma|)
        # and |w| <= the Bouc-Wen rate. With w = 0 its eigenvalues are 0 and -(k0 + g alpha)/D,
        # so |lambda| <= (k0 + g alpha)/D + |w| (the coupling is missed by the BW rate alone).
        s = abs(b) + abs(g)
        g_u = 2.0 * abs(d) if 0 < s < np.inf else abs(d)
        coupling = (abs(k0) + g_u * abs(alpha)) / max(abs(c0 + c1), 1e-12)
        return _bw_rate(d, b, g, n, vmax) + coupling

    def ode(self) -> ODE:
        names = self.param_names

        def ydot_of(state, xi, vi, p):
            c0, k0, c1, alpha = split_theta(p, names, "c0", "k0", "c1", "alpha")
            y, z = state[0], state[1]
            return (c0 * vi + k0 * (xi - y) + alpha * z) / (c0 + c1)

        def shape(p):
            return split_theta(p, names, "delta", "beta", "gamma", "n")

        def rhs(state, xi, vi, p):
            yd = ydot_of(state, xi, vi, p)
            return jnp.stack([yd, _bw_zdot(state[1], vi - yd, *shape(p))])

        def lin(state, xi, vi, p):
            # J = [[-k0/D, alpha/D], [Z_u k0/D, Z_z - Z_u alpha/D]], D = c0 + c1, u = xdot - ydot;
            # the Newton matrix the same with Z_z clipped at 0 (see `bw_zdot_lin`)
            c0, k0, c1, alpha = split_theta(p, names, "c0", "k0", "c1", "alpha")
            D = c0 + c1
            yd = ydot_of(state, xi, vi, p)
            zd, zz, zu = bw_zdot_lin(state[1], vi - yd, *shape(p))

            def jac(zz):
                return jnp.stack([jnp.stack([-k0 / D, alpha / D]),
                                  jnp.stack([zu * k0 / D, zz - zu * alpha / D])])

            return jnp.stack([yd, zd]), jac(zz), jac(jnp.minimum(zz, 0.0))

        def box(p):
            zm = bw_zmax(*shape(p))
            inf = jnp.full_like(zm, jnp.inf)
            return jnp.stack([-inf, -zm]), jnp.stack([inf, zm])

        def initial(x0, v0):
            x0 = jnp.asarray(x0)
            return jnp.stack([x0, jnp.zeros((), x0.dtype)])

        def output(states, theta, x, xdot):
            st = jnp.moveaxis(jnp.asarray(states), -1, 0)  # (S, ...)
            th = jnp.broadcast_to(theta, st.shape[1:] + (theta.shape[-1],))
            yd = ydot_of(st, x, xdot, th)
            (c1,) = split_theta(th, names, "c1")
            xdot = jnp.asarray(xdot)
            return jnp.zeros(xdot.shape + (0,), xdot.dtype), c1 * yd

        return ODE(rhs=rhs, initial=initial, output=output, linearize=lin, box=box)


class Dahl(AbstractModel):
    """Dahl-type model: $f = c\\dot x + k x + \\alpha w + f_0$,
    $\\dot w = \\rho(\\dot x - |\\dot x| w)$, w(0) = 0.

    Parameters: `c` [N·s/m], `k` [N/m], `alpha` [N], `rho` [1/m], `f0` [N].
    Linear: c, k, alpha, f0.
    """

    name: ClassVar[str] = "dahl"
    param_names: ClassVar[tuple[str, ...]] = ("c", "k", "alpha", "rho", "f0")
    units: ClassVar[tuple[str, ...]] = ("N*s/m", "N/m", "N", "1/m", "N")
    default_lower: ClassVar[tuple[float, ...]] = (0.0, -100000.0, 0.0, 1.0, -1000.0)
    default_upper: ClassVar[tuple[float, ...]] = (100000.0, 100000.0, 2500.0, 10000.0, 1000.0)
    basis_params: ClassVar[tuple[str, ...]] = ("c", "k", "f0")
    varying_params: ClassVar[tuple[str, ...]] = ("alpha",)
    dynamic: ClassVar[bool] = True
    description: ClassVar[str] = "Dahl: f = c*v + k*x + alpha*w + f0, w' = rho*(v - |v| w)"
    law_degrees: ClassVar[Mapping[str, int]] = MappingProxyType(dict(c=1, k=1, alpha=2, rho=0,
        f0=1))


    def basis(self, x, xdot):
        x, xdot = jnp.asarray(x), jnp.asarray(xdot)
        return jnp.stack([xdot, x, jnp.ones_like(xdot)], axis=-1)

    def stiffness(self, theta, vmax):
        # integrated by its exact update (`dahl_flow`): no stiffness limit, one step per sample
        return 0.0

    def ode(self) -> ODE:
        names = self.param_names

        def rhs(state, xi, vi, p):
            (rho,) = split_theta(p, names, "rho")
            return rho * (vi - jnp.abs(vi) * state)

        def flow(state, p, a, b, h):
            (rho,) = split_theta(p, names, "rho")
            return dahl_flow(state, rho, a[1], b[1], h)

        return ODE(rhs=rhs, initial=_zero_state, output=_state_regressor, flow=flow)

    def integration(self, theta, xdot, dt):
        # the exact update needs one step per sample whatever the stiffness
        return 1, "rk4"
