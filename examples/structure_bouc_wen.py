"""The Bouc-Wen element of the nonlinear system identification benchmark of Noël & Schoukens
(2016), declared through mrjax's contract, for `mrjax fit --structure sdof`:

    m y'' + c y' + k y + z = u,
    z' = alpha y' - beta (gamma |y'| |z|^(nu - 1) z + delta y' |z|^nu),

z a force [N]. beta, gamma and delta enter only as the products beta*gamma and beta*delta, so
beta is held (`BenchmarkBoucWen`, beta = 1000 1/m, the benchmark's value): six unknowns and the
mass.

    mrjax fit data.csv --structure sdof --periodic 8192 \
        --model examples/structure_bouc_wen.py:BenchmarkBoucWen
"""

import jax.numpy as jnp

from mrjax.models import Model, Parameter, fix, safe_abs_pow


def force(p, y, ydot, z):  # the element's force for one instant; z the state, shape (1,)
    return p.c * ydot + p.k * y + z[0]


def rate(p, y, ydot, z):  # dz/dt
    zn = safe_abs_pow(z, p.nu)  # |z|^nu, finite derivatives at z = 0
    return p.alpha * ydot - p.beta * (p.gamma * jnp.abs(ydot) * jnp.sign(z) * zn
                                      + p.delta * ydot * zn)


BoucWenForce = Model("bouc_wen_force", [
    Parameter("c", "N*s/m", 0.0, 1e3, linear=True),
    Parameter("k", "N/m", 0.0, 1e6, linear=True),
    Parameter("alpha", "N/m", 1e3, 1e6, log=True),
    Parameter("beta", "1/m", 1.0, 1e4, log=True),
    Parameter("gamma", "-", -5.0, 5.0),
    Parameter("delta", "-", -5.0, 5.0),
    Parameter("nu", "-", 0.5, 3.0),
], force, rate=rate, state_size=1,
    description="Bouc-Wen, z a force: F = c*v + k*y + z, "
                "z' = alpha*v - beta*(gamma*|v|*|z|^(nu-1)*z + delta*v*|z|^nu)",
    reference="Noel & Schoukens (2016), Hysteretic benchmark with a dynamic nonlinearity")

BenchmarkBoucWen = fix(BoucWenForce, {"beta": 1000.0})
