r"""Published MR-damper models that mrjax's paper does not cover, declared only through the
public contract (`mrjax.models.Model`, `Parameter`, `safe_abs_pow`): what a user writes.

- **LuGre** (`"lugre"`): the LuGre friction model adapted to MR dampers by Sakai, Ohmori &
    Sano (2003) and Jiménez & Álvarez-Icaza (2005). One bristle state z [m]:

    $$ \dot z = \dot x - a_0 |\dot x| z,\qquad F = \sigma_0 z + \sigma_1 \dot z
       + \sigma_2 \dot x + f_0. $$

    Jiménez & Álvarez-Icaza write $\dot z = \dot x - \sigma_0 a_0 |\dot x| z$ and let
    $\sigma_0$, $\sigma_2$ grow with the command v ($\sigma_0 \to \sigma_a + \sigma_0 v$,
    $\sigma_2 \to \sigma_2 + \sigma_b v$); at a constant command their model is this one with
    $a_0 \to \sigma_0 a_0$. The bristle state never leaves $|z| \le 1/a_0$ (declared as its box).
- **Herschel–Bulkley** (`"herschel_bulkley"`): the quasi-static Herschel–Bulkley damper of
    Wang & Gordaninejad (1999, 2000), a Bingham plastic whose post-yield force grows as a power
    of the velocity (shear thinning for m < 1):

    $$ F = \big(f_y + K\,|\dot x / v_r|^{m}\big)\,\mathrm{sign}(\dot x) + f_0,\qquad
       v_r = 1\ \mathrm{m/s}. $$
- **Polynomial** (`"polynomial"`): the hysteresis model of Choi, Lee & Park (2001): the force
    on the upper and on the lower branch of the loop is a polynomial in the velocity, the
    branch chosen by the sign of the acceleration. mrjax's contract gives the force the
    displacement and velocity, and on a sine about x = 0 the acceleration's sign is
    $-\mathrm{sign}(x)$ (the same device as the $\delta\,\mathrm{sign}(x)$ of Kwok et al.'s
    tanh model):

    $$ F = \sum_{i=0}^{6} \big(a_i + b_i\,s\big)\,(\dot x / v_r)^i,\qquad
       s = -\mathrm{sign}(x),\quad v_r = 0.1\ \mathrm{m/s}. $$

    Every parameter is linear, so the separable swarm solves it exactly; Choi et al. make each
    coefficient linear in the current (the default law degree here).

References:

- C. Sakai, H. Ohmori, A. Sano (2003), Modeling of MR damper with hysteresis for adaptive
    vibration control, Proc. 42nd IEEE Conf. on Decision and Control, 3840-3845.
- N. Jiménez, L. Álvarez-Icaza (2005), LuGre friction model for a magnetorheological damper,
    Structural Control and Health Monitoring 12, 91-116.
- X. Wang, F. Gordaninejad (1999), Flow analysis of field-controllable, electro- and
    magneto-rheological fluids using Herschel-Bulkley model, J. Intelligent Material Systems
    and Structures 10, 601-608.
- S.-B. Choi, S.-K. Lee, Y.-P. Park (2001), A hysteresis model for the field-dependent damping
    force of a magnetorheological damper, J. Sound and Vibration 245(2), 375-383.

`REFERENCE_PARAMS` holds one parameter set per model, used by the known-answer tests: the
least-squares fit (`mrjax.fit`, 3 significant digits) of the model to the force of a published
damper model that mrjax carries: Kwok et al.'s generalized tanh model (2006, eq 24-29) at 1 A
on a 2 Hz / 8 mm sine for the LuGre and polynomial models, Spencer et al.'s modified Bouc-Wen
(1997, PAPER.md) at 1 V on their 2.5 Hz / 15 mm sine for the Herschel-Bulkley model. They are
the scale of a 1-2 kN damper in each model's own parameters, not the papers' values.
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp

from ._base import safe_abs_pow
from ._declaration import Parameter
from ._declare import Model

#: Reference velocity of the Herschel-Bulkley power law [m/s].
HB_VREF = 1.0
#: Reference velocity and order of the polynomial model [m/s], [-].
POLY_VREF = 0.1
POLY_ORDER = 6


# ------------------------------------------------------------------------------ LuGre
def lugre_rate(p, x, xdot, z):
    """Bristle deflection rate dz/dt [m/s]."""
    return xdot - p.a0 * jnp.abs(xdot) * z


def lugre_force(p, x, xdot, z):
    """LuGre damper force [N]."""
    zdot = xdot - p.a0 * jnp.abs(xdot) * z[0]
    return p.sigma0 * z[0] + p.sigma1 * zdot + p.sigma2 * xdot + p.f0


def lugre_box(p):
    """|z| <= 1/a0 from z(0) = 0."""
    r = 1.0 / p.a0
    return -r, r


def lugre() -> Model:
    """The LuGre MR-damper model (Sakai et al. 2003; Jiménez & Álvarez-Icaza 2005)."""
    return Model(
        "lugre",
        [Parameter("sigma0", "N/m", 0.0, 1e10, linear=True, degree=2),
         Parameter("sigma1", "N*s/m", -1e5, 1e5, linear=True, degree=1),
         Parameter("sigma2", "N*s/m", 0.0, 1e5, linear=True, degree=1),
         Parameter("a0", "1/m", 10.0, 1e6, log=True, degree=0),
         Parameter("f0", "N", -1000.0, 1000.0, linear=True, degree=1)],
        lugre_force, rate=lugre_rate, state_size=1, box=lugre_box,
        description="LuGre: z' = v - a0 |v| z, f = sigma0 z + sigma1 z' + sigma2 v + f0",
        reference="Sakai et al. 2003; Jimenez & Alvarez-Icaza 2005")


# ------------------------------------------------------------------------------ Herschel-Bulkley
def herschel_bulkley_force(p, x, xdot, state):
    """Herschel-Bulkley damper force [N]."""
    one = jnp.ones_like(xdot)
    sgn = jnp.where(xdot > 0, one, jnp.where(xdot < 0, -one, 0.0 * one))
    return (p.fy + p.K * safe_abs_pow(xdot / HB_VREF, p.m)) * sgn + p.f0


def herschel_bulkley() -> Model:
    """The Herschel-Bulkley damper model (Wang & Gordaninejad 1999, 2000)."""
    return Model(
        "herschel_bulkley",
        [Parameter("fy", "N", 0.0, 2500.0, linear=True, degree=2),
         Parameter("K", "N", 0.0, 1e5, linear=True, degree=1),
         Parameter("m", "-", 0.05, 3.0, degree=0),
         Parameter("f0", "N", -1000.0, 1000.0, linear=True, degree=1)],
        herschel_bulkley_force,
        description="Herschel-Bulkley: f = (fy + K |v/1 m/s|^m) sign(v) + f0",
        reference="Wang & Gordaninejad 1999")


# ------------------------------------------------------------------------------ polynomial
def polynomial_force(p, x, xdot, state):
    """Choi et al.'s two-branch polynomial force [N]."""
    one = jnp.ones_like(x)
    s = jnp.where(x > 0, -one, jnp.where(x < 0, one, 0.0 * one))  # the sign of the acceleration
    u = xdot / POLY_VREF
    f = jnp.zeros_like(u)
    for i in range(POLY_ORDER, -1, -1):  # Horner
        f = f * u + (p[f"a{i}"] + p[f"b{i}"] * s)
    return f


def polynomial() -> Model:
    """The two-branch polynomial model of Choi, Lee & Park (2001), order 6."""
    params = [Parameter(f"a{i}", "N", -1e6, 1e6, linear=True, degree=1)
              for i in range(POLY_ORDER + 1)]
    params += [Parameter(f"b{i}", "N", -1e6, 1e6, linear=True, degree=1)
               for i in range(POLY_ORDER + 1)]
    return Model("polynomial", params, polynomial_force,
                 description="Choi polynomial: f = sum_i (a_i + b_i sgn(a)) (v / 0.1 m/s)^i, "
                 "sgn(a) = -sign(x)", reference="Choi, Lee & Park 2001")


#: The literature models by name (built when first asked for: their checks take a moment).
LITERATURE: dict[str, Callable[[], Model]] = {
    "lugre": lugre, "herschel_bulkley": herschel_bulkley, "polynomial": polynomial,
}

#: One parameter set per literature model (see the module docstring), SI units.
REFERENCE_PARAMS: dict[str, dict[str, float]] = {
    # fitted to Kwok et al. (2006) eq 24-29 at 1 A, 2 Hz / 8 mm
    "lugre": dict(sigma0=1.04e7, sigma1=7840.0, sigma2=3660.0, a0=1.56e4, f0=-275.0),
    # fitted to Spencer et al. (1997) at 1 V, 2.5 Hz / 15 mm (this model has no hysteresis)
    "herschel_bulkley": dict(fy=65.2, K=1660.0, m=0.392, f0=-72.6),
    # fitted to Kwok et al. (2006) eq 24-29 at 1 A, 2 Hz / 8 mm; the near-zero coefficients
    # are those the loop's symmetry leaves out
    "polynomial": dict(a0=-275.0, a1=2770.0, a2=0.610, a3=-3990.0, a4=-2.01, a5=2290.0,
                       a6=1.59, b0=-282.0, b1=0.481, b2=1910.0, b3=-2.54, b4=-3650.0,
                       b5=2.51, b6=2040.0),
}
