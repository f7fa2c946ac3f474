"""Damper models declared through mrjax's contract (`help(mrjax.models.Model)`).

`mrjax fit DATA --model examples/my_models.py:BoucWen` fits the dynamic one. `BoucWen` is
Bouc-Wen written from its equations only, with nothing hand-derived: mrjax's tests and
`benchmarks/usermodel.py` compare it with the hand-written built-in `bouc_wen`. `BoucWen1` is
the same model with its exponent held at n = 1 (`mrjax.models.fix`): seven unknowns.
"""

import jax.numpy as jnp

from mrjax.models import Model, Parameter, fix, safe_abs_pow


def tanh_force(p, x, xdot, state):  # static: one instant, no state
    return p.c * xdot + p.k * x + p.alpha * jnp.tanh(p.beta * xdot + p.delta * jnp.sign(x)) + p.f0


Tanh = Model("my_tanh", [
    Parameter("c", "N*s/m", 0.0, 1e5, linear=True),
    Parameter("k", "N/m", -1e5, 1e5, linear=True),
    Parameter("alpha", "N", 0.0, 2500.0, linear=True),
    Parameter("beta", "s/m", 1.0, 1e4, log=True),
    Parameter("delta", "-", 0.0, 5.0),
    Parameter("f0", "N", -1e3, 1e3, linear=True),
], tanh_force)


def bw_force(p, x, xdot, z):  # z: the state, shape (1,)
    return p.c * xdot + p.k * x + p.alpha * z[0] + p.f0


def bw_rate(p, x, xdot, z):  # dz/dt
    zn = safe_abs_pow(z, p.n)  # |z|^n, finite derivatives at z = 0
    return p.delta * xdot - p.beta * xdot * zn - p.gamma * jnp.abs(xdot) * jnp.sign(z) * zn


BoucWen = Model("my_bouc_wen", [
    Parameter("c", "N*s/m", 0.0, 1e5, linear=True),
    Parameter("k", "N/m", -1e5, 1e5, linear=True),
    Parameter("alpha", "N", 0.0, 2500.0, linear=True),
    Parameter("f0", "N", -1e3, 1e3, linear=True),
    Parameter("delta", "1/m", 1.0, 5000.0),
    Parameter("beta", "1/m", 0.0, 5000.0),
    Parameter("gamma", "1/m", 0.0, 5000.0),
    Parameter("n", "-", 1.0, 3.0),
], bw_force, rate=bw_rate, state_size=1)

BoucWen1 = fix(BoucWen, {"n": 1.0})
