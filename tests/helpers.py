"""Shared test material: every model name, a representative parameter vector per model, Spencer's
1997 modified Bouc-Wen set, and a sinusoidal excitation.

All values are SI. `TRUE_PARAMS[name]` lies inside `mrjax.models.get(name).bounds` and gives forces
of a few hundred newtons to about 1.5 kN at 2.5 Hz / 15 mm, the scale of the RD-1005-3 in Kwok
et al. (2006).
"""

from __future__ import annotations

import numpy as np

import mrjax

#: Every registered model, in the order of the paper.
MODEL_NAMES: tuple[str, ...] = ("bingham", "kwok", "bouc_wen", "modified_bouc_wen", "dahl")
#: The models with internal state integrated by the RK4 scan.
ODE_MODELS: tuple[str, ...] = ("bouc_wen", "modified_bouc_wen", "dahl")
#: The memoryless models.
STATIC_MODELS: tuple[str, ...] = ("bingham", "kwok")


def named(name: str, **values: float) -> np.ndarray:
    """Parameter vector of model `name` from keyword values (all parameters required)."""
    return mrjax.models.get(name).params(**values)


#: Representative "true" parameters, inside the default bounds. Every entry is non-zero, so a
#: relative finite-difference step is well defined.
TRUE_PARAMS: dict[str, np.ndarray] = {
    "bingham": named("bingham", fc=400.0, c0=3000.0, f0=-20.0),
    # Kwok et al. eq 24-29 at i = 1 A.
    "kwok": named("kwok", c=3161.0, k=3400.0, alpha=706.0, beta=100.0, delta=0.88, f0=-275.0),
    "bouc_wen": named(
        "bouc_wen", c=1500.0, k=2000.0, alpha=600.0, f0=-30.0,
        delta=1500.0, beta=800.0, gamma=600.0, n=2.0,
    ),
    "modified_bouc_wen": named(
        "modified_bouc_wen", c0=3000.0, k0=2000.0, c1=30000.0, k1=500.0, alpha=800.0,
        delta=1000.0, beta=600.0, gamma=400.0, n=2.0, f0=-40.0,
    ),
    "dahl": named("dahl", c=1500.0, k=1500.0, alpha=500.0, rho=2000.0, f0=-30.0),
}

#: Spencer et al. (1997), PAPER.md: voltage-independent part.
SPENCER_1997 = dict(
    c0a=2100.0, c0b=350.0, c1a=28300.0, c1b=295.0, alphaa=14000.0, alphab=69500.0,
    k0=4690.0, k1=500.0, x0=0.143, gamma=3.63e6, beta=3.63e6, A=301.0, n=2.0, eta=190.0,
)


def spencer1997(u: float) -> np.ndarray:
    """Spencer et al. (1997) modified Bouc-Wen parameters at voltage `u` [V], in mrjax order
    `(c0, k0, c1, k1, alpha, delta, beta, gamma, n, f0)`, with delta = A and f0 = -k1 x0.

    z is in metres here (alpha in N/m, beta and gamma in 1/m^2), outside the default bounds.
    """
    s = SPENCER_1997
    return named(
        "modified_bouc_wen",
        c0=s["c0a"] + s["c0b"] * u,
        k0=s["k0"],
        c1=s["c1a"] + s["c1b"] * u,
        k1=s["k1"],
        alpha=s["alphaa"] + s["alphab"] * u,
        delta=s["A"],
        beta=s["beta"],
        gamma=s["gamma"],
        n=s["n"],
        f0=-s["k1"] * s["x0"],
    )


def sine(
    frequency: float = 2.5, amplitude: float = 0.015, sample_rate: float = 1000.0,
    cycles: float = 2.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """`(t, x, xdot, dt)` of $x = A \\sin(2\\pi f t)$ sampled at `sample_rate` [Hz]."""
    t, x, v = mrjax.data.sine_excitation(
        frequency, amplitude, sample_rate=sample_rate, cycles=cycles
    )
    return t, x, v, 1.0 / sample_rate


def draw_sine(draw, n: int, min_rate: float):
    """Hypothesis helper: `(t, x, xdot, rate, frequency, amplitude)` of a sinusoid of 1-2 cycles
    in `n` samples at `min_rate`-1000 Hz, 2-15 mm amplitude and random phase (`draw` from
    `st.composite`); SI units."""
    from hypothesis import strategies as st

    rate = draw(st.floats(min_rate, 1000.0))
    cycles = draw(st.floats(1.0, 2.0))
    amp = draw(st.floats(0.002, 0.015))
    phase = draw(st.floats(0.0, 2 * np.pi))
    f = cycles * rate / n
    t, x, v = mrjax.data.sine_excitation(f, amp, sample_rate=rate, cycles=cycles, phase=phase)
    assert x.shape == (n,)
    return t, x, v, rate, f, amp
