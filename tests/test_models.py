"""Tests of `mrjax.models`: contract, hand-computed values, accuracy against a stiff reference
solver, gradients, divergence, time-varying parameters, jit/vmap and random properties.

Run `pytest -s tests/test_models.py` to see the accuracy table (NRMSE and RK4 sub-steps).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
from helpers import (
    MODEL_NAMES,
    ODE_MODELS,
    STATIC_MODELS,
    TRUE_PARAMS,
    draw_sine,
    sine,
    spencer1997,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import mrjax
from mrjax.models import get

#: A short record shared by most tests (one shape, so jit compiles are reused): 2.5 Hz, 15 mm,
#: 1 kHz, half a cycle (200 samples, one velocity reversal).
_, X, V, DT = sine(2.5, 0.015, 1000.0, 0.5)
#: Fixed sub-steps for the representative parameters at 1 kHz (auto chooses 1-2).
M = 4

CONTRACT = {
    "bingham": ("fc", "c0", "f0"),
    "kwok": ("c", "k", "alpha", "beta", "delta", "f0"),
    "bouc_wen": ("c", "k", "alpha", "f0", "delta", "beta", "gamma", "n"),
    "modified_bouc_wen": ("c0", "k0", "c1", "k1", "alpha", "delta", "beta", "gamma", "n", "f0"),
    "dahl": ("c", "k", "alpha", "rho", "f0"),
}


@functools.cache
def jforce(name: str, substeps: int | None = M, scheme: str | None = None):
    """`jax.jit(model.force)` for a model with fixed sub-steps (and scheme)."""
    return jax.jit(get(name, substeps=substeps).with_substeps(substeps, scheme).force)


def nrmse(f, ref):
    f, ref = np.asarray(f), np.asarray(ref)
    return float(np.sqrt(np.mean((f - ref) ** 2)) / np.max(np.abs(ref)))


# ------------------------------------------------------------------ independent numpy reference
# The equations of PAPER.md written directly (the textbook form, not mrjax's NaN-safe form), with
# p a dict of named parameters. rhs(y, x, v, p) -> dy/dt; out(y, x, v, p) -> force.


def bw_zdot(z, u, p):
    d, b, g, n = p["delta"], p["beta"], p["gamma"], p["n"]
    return d * u - b * u * np.abs(z) ** n - g * z * np.abs(u) * np.abs(z) ** (n - 1)


def mbw_ydot(y, x, v, p):
    return (p["c0"] * v + p["k0"] * (x - y[0]) + p["alpha"] * y[1]) / (p["c0"] + p["c1"])


NUMPY_ODE = {
    "bouc_wen": (
        lambda y, x, v, p: np.array([bw_zdot(y[0], v, p)]),
        lambda x0: np.array([0.0]),
        lambda y, x, v, p: p["c"] * v + p["k"] * x + p["alpha"] * y[0] + p["f0"],
    ),
    "modified_bouc_wen": (
        lambda y, x, v, p: np.array(
            [mbw_ydot(y, x, v, p), bw_zdot(y[1], v - mbw_ydot(y, x, v, p), p)]
        ),
        lambda x0: np.array([x0, 0.0]),
        lambda y, x, v, p: p["c1"] * mbw_ydot(y, x, v, p) + p["k1"] * x + p["f0"],
    ),
    "dahl": (
        lambda y, x, v, p: np.array([p["rho"] * (v - np.abs(v) * y[0])]),
        lambda x0: np.array([0.0]),
        lambda y, x, v, p: p["c"] * v + p["k"] * x + p["alpha"] * y[0] + p["f0"],
    ),
}


def pdict(name, theta):
    return dict(zip(get(name).param_names, np.asarray(theta, float)))


def numpy_rk4_force(name, theta, x, v, dt, m):
    """Plain-Python RK4 with `m` sub-steps per interval and linear interpolation of x and v."""
    rhs, y0, out = NUMPY_ODE[name]
    p = pdict(name, theta)
    y = y0(x[0])
    F = [out(y, x[0], v[0], p)]
    h = dt / m
    for k in range(len(x) - 1):
        dx, dv = x[k + 1] - x[k], v[k + 1] - v[k]

        def f(y, s, k=k, dx=dx, dv=dv):
            return rhs(y, x[k] + s * dx, v[k] + s * dv, p)

        for j in range(m):
            s0 = j / m
            k1 = f(y, s0)
            k2 = f(y + 0.5 * h * k1, s0 + 0.5 / m)
            k3 = f(y + 0.5 * h * k2, s0 + 0.5 / m)
            k4 = f(y + h * k3, s0 + 1.0 / m)
            y = y + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        F.append(out(y, x[k + 1], v[k + 1], p))
    return np.array(F)


# ================================================================== 1. contract
def test_names_and_unknown():
    # the paper's models first, then the literature models declared through the contract
    # (tests/test_usermodel.py), then any registered or installed ones
    assert mrjax.models.names()[:len(MODEL_NAMES)] == MODEL_NAMES
    for name in MODEL_NAMES:
        assert get(name).name == name
    assert get("tanh").name == "kwok"
    assert get("spencer").name == "modified_bouc_wen"
    with pytest.raises(mrjax.InputError):
        get("no_such_model")
    with pytest.raises(ValueError):
        get("dahl", substeps=0)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_contract(name):
    model = get(name)
    assert model.param_names == CONTRACT[name]
    P = len(CONTRACT[name])
    assert len(model.units) == P and all(isinstance(u, str) and u for u in model.units)
    lo, hi = model.bounds
    assert lo.shape == hi.shape == (P,)
    assert lo.dtype == hi.dtype == np.float64
    assert np.all(lo < hi)
    start = model.default_start()
    assert start.shape == (P,) and np.all((lo <= start) & (start <= hi))
    assert np.all((lo <= TRUE_PARAMS[name]) & (TRUE_PARAMS[name] <= hi))
    assert set(model.linear_params) <= set(model.param_names)
    assert len(set(model.linear_params)) == len(model.linear_params)
    assert model.dynamic == (name in ODE_MODELS)
    if name in ODE_MODELS:
        assert get(name, substeps=3).resolve_substeps(TRUE_PARAMS[name], V, DT) == 3


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_design_is_affine_form_of_force(name):
    """force == A @ theta[linear] + b, and the linear entries of theta do not change (A, b)."""
    model = get(name, substeps=M)
    theta = TRUE_PARAMS[name]
    design = jax.jit(model.design)
    A, b = design(theta, X, V, DT)
    lin = np.asarray(model.linear_index)
    F = np.asarray(jforce(name)(theta, X, V, DT))
    assert A.shape == (len(X), len(lin)) and b.shape == (len(X),)
    np.testing.assert_allclose(np.asarray(A) @ theta[lin] + np.asarray(b), F, rtol=1e-12, atol=1e-9)
    other = theta.copy()
    other[lin] *= -3.0
    A2, b2 = design(other, X, V, DT)
    np.testing.assert_array_equal(np.asarray(A), np.asarray(A2))
    np.testing.assert_array_equal(np.asarray(b), np.asarray(b2))


# ================================================================== 2. hand-computed values
def test_bingham_by_hand():
    fc, c0, f0 = 400.0, 3000.0, -20.0
    x = np.array([0.01, -0.002, 0.0, 0.005])
    v = np.array([0.2, -0.05, 0.0, -0.3])
    expected = np.array(
        [400 + 3000 * 0.2 - 20, -400 + 3000 * -0.05 - 20, -20.0, -400 + 3000 * -0.3 - 20]
    )
    F = get("bingham").force(np.array([fc, c0, f0]), x, v)
    np.testing.assert_allclose(F, expected, rtol=1e-14)


def test_kwok_by_hand():
    c, k, alpha, beta, delta, f0 = 3161.0, 3400.0, 706.0, 100.0, 0.88, -275.0
    x = np.array([0.01, -0.004, 0.0, 0.003])
    v = np.array([0.05, 0.02, -0.1, -0.001])
    z = np.tanh(beta * v + delta * np.array([1.0, -1.0, 0.0, 1.0]))
    expected = c * v + k * x + alpha * z + f0
    # the first point by hand: tanh(5 + 0.88) = tanh(5.88)
    assert expected[0] == pytest.approx(3161 * 0.05 + 34.0 + 706 * np.tanh(5.88) - 275, rel=1e-14)
    F = get("kwok").force(np.array([c, k, alpha, beta, delta, f0]), x, v)
    np.testing.assert_allclose(F, expected, rtol=1e-13)


RK4_MODELS = ("bouc_wen", "modified_bouc_wen")  # Dahl integrates by its exact update


@pytest.mark.parametrize("name", RK4_MODELS)
def test_one_rk4_step_by_hand(name):
    """Two samples, constant velocity, x linear: one classical RK4 step written out in numpy."""
    theta = TRUE_PARAMS[name]
    p = pdict(name, theta)
    rhs, y0f, out = NUMPY_ODE[name]
    v, x0, h = 0.12, 0.003, 1e-3
    x = np.array([x0, x0 + v * h])
    xd = np.array([v, v])
    y0 = y0f(x0)
    k1 = rhs(y0, x0, v, p)
    k2 = rhs(y0 + h / 2 * k1, x0 + v * h / 2, v, p)
    k3 = rhs(y0 + h / 2 * k2, x0 + v * h / 2, v, p)
    k4 = rhs(y0 + h * k3, x0 + v * h, v, p)
    y1 = y0 + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    expected = np.array([out(y0, x[0], v, p), out(y1, x[1], v, p)])
    F = get(name, substeps=1).force(theta, x, xd, h)
    np.testing.assert_allclose(F, expected, rtol=1e-13)
    # the step moved the state: force differs from the z = 0 value
    assert abs(expected[1] - out(y0, x[1], v, p)) > 1e-3


@pytest.mark.parametrize("name", RK4_MODELS)
def test_rk4_substeps_and_interpolation_match_numpy(name):
    """A record with varying velocity, 3 sub-steps: matches the plain-Python RK4 reference."""
    theta = TRUE_PARAMS[name]
    x, v = X[:40], V[:40] * np.linspace(1.0, 3.0, 40)  # velocity not consistent with x: fine
    F = get(name, substeps=3).force(theta, x, v, 2e-3)
    np.testing.assert_allclose(F, numpy_rk4_force(name, theta, x, v, 2e-3, 3), rtol=1e-12)


@pytest.mark.parametrize("v0, v1", [(0.12, 0.12), (0.1, 0.3), (0.1, -0.1), (-0.05, 0.2)])
def test_dahl_exact_update_by_hand(v0, v1):
    """One interval, velocity linear from v0 to v1: w' = rho |v| (sign v - w) integrated in closed
    form, split at the reversal s* = v0 / (v0 - v1) when the sign changes."""
    c, k, alpha, rho, f0 = 0.0, 0.0, 1.0, 2000.0, 0.0
    h = 2e-3
    x = np.array([0.0, 0.5 * h * (v0 + v1)])
    v = np.array([v0, v1])
    w = 0.0
    if v0 * v1 >= 0:
        s = np.sign(v0 + v1)
        w = s + (w - s) * np.exp(-rho * 0.5 * h * (abs(v0) + abs(v1)))
    else:
        ss = v0 / (v0 - v1)
        w = np.sign(v0) + (w - np.sign(v0)) * np.exp(-rho * 0.5 * h * ss * abs(v0))
        w = np.sign(v1) + (w - np.sign(v1)) * np.exp(-rho * 0.5 * h * (1 - ss) * abs(v1))
    F = get("dahl").force(np.array([c, k, alpha, rho, f0]), x, v, h)
    np.testing.assert_allclose(np.asarray(F), [0.0, w], rtol=1e-13, atol=1e-15)


def rk4_factor(q):
    """RK4 amplification factor R(q) of y' = lambda y, q = lambda h."""
    return 1 + q + q**2 / 2 + q**3 / 6 + q**4 / 24


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_dahl_closed_form(sign):
    """Constant velocity v: w = sign(v) (1 - exp(-rho |v| t)), which Dahl's exact update
    reproduces to rounding at any step (the sub-step count does not matter)."""
    c, k, alpha, rho, f0 = 1500.0, 1500.0, 500.0, 2000.0, -30.0
    v, dt, T = sign * 0.1, 1e-3, 50
    t = np.arange(T) * dt
    x, xd = v * t, np.full(T, v)
    w_exact = sign * (1.0 - np.exp(-rho * abs(v) * t))
    base = c * xd + k * x + f0
    for m in (None, 1, 4):
        F = get("dahl", substeps=m).force(np.array([c, k, alpha, rho, f0]), x, xd, dt)
        np.testing.assert_allclose(F, base + alpha * w_exact, rtol=1e-13, atol=1e-10)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_bouc_wen_closed_form_n1(sign):
    """n = 1, constant velocity: z' = v (delta - (beta+gamma) |z|), z = sign(v) z* (1 - e^-lt)."""
    c, k, alpha, f0, delta, beta, gamma = 1500.0, 2000.0, 600.0, -30.0, 1500.0, 800.0, 600.0
    v, dt, m, T = sign * 0.05, 1e-3, 4, 60
    t = np.arange(T) * dt
    x, xd = v * t, np.full(T, v)
    theta = np.array([c, k, alpha, f0, delta, beta, gamma, 1.0])
    F = get("bouc_wen", substeps=m).force(theta, x, xd, dt)
    base = c * xd + k * x + f0
    zs, lam = delta / (beta + gamma), (beta + gamma) * abs(v)
    z_rk4 = sign * zs * (1.0 - rk4_factor(-lam * dt / m) ** (m * np.arange(T)))
    np.testing.assert_allclose(F, base + alpha * z_rk4, rtol=1e-13, atol=1e-10)
    z_exact = sign * zs * (1.0 - np.exp(-lam * t))
    np.testing.assert_allclose(F, base + alpha * z_exact, rtol=0, atol=alpha * 1e-7)


def test_bouc_wen_closed_form_n2():
    """n = 2, constant positive velocity: z = sqrt(d/s) tanh(sqrt(d s) v t), s = beta + gamma."""
    c, k, alpha, f0, delta, beta, gamma = 1500.0, 2000.0, 600.0, -30.0, 1500.0, 800.0, 600.0
    v, dt, m, T = 0.05, 1e-3, 4, 60
    t = np.arange(T) * dt
    theta = np.array([c, k, alpha, f0, delta, beta, gamma, 2.0])
    F = get("bouc_wen", substeps=m).force(theta, v * t, np.full(T, v), dt)
    s = beta + gamma
    z = np.sqrt(delta / s) * np.tanh(np.sqrt(delta * s) * v * t)
    np.testing.assert_allclose(F, c * v + k * v * t + f0 + alpha * z, rtol=0, atol=alpha * 1e-7)


def test_modified_bouc_wen_initial_force():
    """y(0) = x(0), z(0) = 0: F(0) = c1 c0 v0 / (c0 + c1) + k1 x0 + f0."""
    theta = TRUE_PARAMS["modified_bouc_wen"]
    p = pdict("modified_bouc_wen", theta)
    F = jforce("modified_bouc_wen")(theta, X + 0.004, V, DT)
    F0 = p["c1"] * p["c0"] * V[0] / (p["c0"] + p["c1"]) + p["k1"] * 0.004 + p["f0"]
    assert float(F[0]) == pytest.approx(F0, rel=1e-14)


# ================================================================== 3. accuracy vs LSODA
REFERENCE_CASES = {
    "spencer_0V": ("modified_bouc_wen", spencer1997(0.0)),
    "spencer_1V": ("modified_bouc_wen", spencer1997(1.0)),
    "spencer_2.25V": ("modified_bouc_wen", spencer1997(2.25)),
    # stiff-ish, inside the default bounds: |z|max = 1, rate 2 delta |v| ~ 2400 1/s
    "bouc_wen_n2": (
        "bouc_wen",
        np.array([1000.0, 500.0, 800.0, -50.0, 5000.0, 3000.0, 2000.0, 2.0]),
    ),
    "bouc_wen_n1": (
        "bouc_wen",
        np.array([1000.0, 500.0, 800.0, -50.0, 5000.0, 3500.0, 1500.0, 1.0]),
    ),
    "dahl": ("dahl", np.array([1000.0, 500.0, 800.0, 9000.0, -50.0])),
}


@functools.cache
def lsoda_reference(case):
    """LSODA (rtol 1e-10) on the continuous 2.5 Hz, 15 mm sinusoid, 2 cycles, at 5 kHz.

    `max_step` is needed: on a loading branch z can sit on its fixed point (z' = 0 exactly for
    n = 1), and LSODA then steps straight over the next velocity reversal."""
    name, theta = REFERENCE_CASES[case]
    rhs, y0, out = NUMPY_ODE[name]
    p = pdict(name, theta)
    A, w = 0.015, 2 * np.pi * 2.5
    t, x, v, _ = sine(2.5, A, 5000.0, 2.0)
    sol = scipy.integrate.solve_ivp(
        lambda s, y: rhs(y, A * np.sin(w * s), A * w * np.cos(w * s), p),
        (0.0, t[-1]), y0(0.0), method="LSODA", rtol=1e-10, atol=1e-13, t_eval=t,
        max_step=t[1] - t[0],
    )
    assert sol.success, sol.message
    return t, np.array([out(sol.y[:, i], x[i], v[i], p) for i in range(len(t))])


@pytest.mark.parametrize("policy", ["polish", "swarm"])
@pytest.mark.parametrize("rate", [1000.0, 5000.0])
@pytest.mark.parametrize("case", list(REFERENCE_CASES))
def test_accuracy_against_lsoda(case, rate, policy):
    """Force NRMSE against LSODA (rtol 1e-10) below the 0.5 % bar with each integration the
    sub-step policy picks: a polish's (RK4 with the stability count, or the L-stable scheme
    by step doubling) and a swarm's (one L-stable step per sample, whatever the stiffness)."""
    name, theta = REFERENCE_CASES[case]
    t_ref, F_ref = lsoda_reference(case)
    _, x, v, dt = sine(2.5, 0.015, rate, 2.0)
    F_ref = F_ref[:: int(round(5000 / rate))]
    assert len(F_ref) == len(x)
    model = mrjax.models.resolve_model(get(name), theta, v, dt, swarm=policy == "swarm")
    F = model.force(theta, x, v, dt)
    err = nrmse(F, F_ref)
    print(f"\nACCURACY {case:14s} {rate / 1000:.0f} kHz  {policy:6s} NRMSE {err:.2e}  "
          f"{model.scheme} x {model.substeps}")
    assert np.all(np.isfinite(F))
    assert err < 5e-3
    # the bar can fail: RK4 with a quarter of its steps is visibly worse (or unstable), and the
    # L-stable scheme at 1 kHz is not exact
    if model.scheme == "rk4" and model.substeps >= 4:
        coarse = nrmse(get(name, substeps=model.substeps // 4).force(theta, x, v, dt), F_ref)
        assert not coarse < err
    if model.scheme == "sdirk" and name != "dahl" and rate == 1000.0:
        assert err > 1e-6


def test_auto_substeps_cover_modified_bouc_wen_coupling():
    """Regression: small c0 + c1 with large alpha and delta (a corner of the default bounds) makes
    z relax at ~ 2 delta alpha / (c0 + c1) through ydot. An estimate from the Bouc-Wen rate alone
    chose 1 sub-step at 1 kHz and the force diverged."""
    model = get("modified_bouc_wen")
    lo, hi = model.bounds
    theta = model.params(
        c0=lo[0], k0=1000.0, c1=100.0, k1=0.0, alpha=hi[4], delta=hi[5],
        beta=100.0, gamma=100.0, n=2.0, f0=0.0,
    )
    F = np.asarray(model.force(theta, X, V, DT))
    assert model.resolve_substeps(theta, V, DT) > 100
    assert np.all(np.isfinite(F))
    ref = numpy_rk4_force("modified_bouc_wen", theta, X[:40], V[:40], DT, 400)
    assert nrmse(F[:40], ref) < 1e-4


# ================================================================== 4. gradients (float64)
@pytest.mark.parametrize("n", [0.5, 1.0, 2.0])
def test_safe_abs_pow(n):
    """|z|^n with finite value and gradients at z = 0 (jnp.abs(z)**n has d/dz = inf for n < 1)."""
    z = np.array([-0.7, 0.0, 0.3])
    np.testing.assert_allclose(mrjax.models.safe_abs_pow(z, n), np.abs(z) ** n, rtol=1e-15)
    dz = np.asarray(jax.vmap(jax.grad(mrjax.models.safe_abs_pow), in_axes=(0, None))(z, n))
    dn = np.asarray(jax.vmap(jax.grad(mrjax.models.safe_abs_pow, 1), in_axes=(0, None))(z, n))
    a = np.abs(z[[0, 2]])
    np.testing.assert_allclose(dz[[0, 2]], np.sign(z[[0, 2]]) * n * a ** (n - 1), rtol=1e-14)
    np.testing.assert_allclose(dn[[0, 2]], a**n * np.log(a), rtol=1e-14)
    assert dz[1] == 0.0 and dn[1] == 0.0



_, XG, VG, DTG = sine(2.5, 0.015, 1000.0, 0.75)  # 300 samples, two reversals
#: Spencer's stiff set needs a finer record for one RK4 step per sample: 25 Hz, 1.5 mm (the same
#: peak velocity as 2.5 Hz, 15 mm) at 20 kHz, 300 samples (one reversal).
_, XSP, VSP, DTSP = sine(25.0, 0.0015, 20000.0, 0.375)
#: A start-up record of the same shape: one interval at constant velocity from z = 0, then the
#: velocity ramps to zero and x holds.
XS = np.r_[0.0, np.full(len(XG) - 1, 0.1 * DTG)]
VS = np.r_[0.1, 0.1, np.zeros(len(XG) - 2)]

#: (name, theta, x, v, dt, substeps). One RK4 step per sample keeps the reverse-mode compiles
#: short (~1.5 s per sub-step on CPU); one case with 2 goes through the sub-step loop.
GRAD_CASES = (
    [(name, TRUE_PARAMS[name], XG, VG, DTG, 1) for name in MODEL_NAMES]
    + [("dahl", TRUE_PARAMS["dahl"], XG, VG, DTG, 2)]
    + [
        ("bouc_wen", TRUE_PARAMS["bouc_wen"] * np.r_[np.ones(7), n / 2], XG, VG, DTG, 1)
        for n in (1, 1.5, 3)
    ]
    + [("modified_bouc_wen", spencer1997(1.0), XSP, VSP, DTSP, 1)]
    + [(name, TRUE_PARAMS[name], XS, VS, DTG, 1) for name in ODE_MODELS]
    # the L-stable scheme: its Newton iterations and the clipping onto the z box, also on
    # Spencer's stiff set at 1 kHz (where one RK4 step per sample diverges) and from z = 0
    + [(name, TRUE_PARAMS[name], XG, VG, DTG, "sdirk") for name in RK4_MODELS]
    + [("modified_bouc_wen", spencer1997(1.0), XG, VG, DTG, "sdirk")]
    + [(name, TRUE_PARAMS[name], XS, VS, DTG, "sdirk") for name in RK4_MODELS]
    + [("bouc_wen", TRUE_PARAMS["bouc_wen"] * np.r_[np.ones(7), 0.5], XG, VG, DTG, "sdirk")]
)
GRAD_IDS = [
    f"{c[0]}-{i}" + ("-startup" if c[2] is XS else "") + ("-sdirk" if c[5] == "sdirk" else "")
    for i, c in enumerate(GRAD_CASES)
]


@functools.cache
def loss_and_grad(name, m):
    model = get(name).with_substeps(1, "sdirk") if m == "sdirk" else get(name, substeps=m)

    def loss(theta, x, v, dt):
        return jnp.sum(model.force(theta, x, v, dt) ** 2)

    return jax.jit(loss), jax.jit(jax.grad(loss))


@pytest.mark.parametrize("name,theta,x,v,dt,m", GRAD_CASES, ids=GRAD_IDS)
def test_gradient_matches_finite_differences(name, theta, x, v, dt, m):
    """jax.grad of sum(F^2) against central differences with relative step 1e-6. Every ODE record
    starts at z = 0, where |z|^n has a 0*log(0) derivative in n: it must stay finite."""
    loss, grad = loss_and_grad(name, m)
    g = np.asarray(grad(theta, x, v, dt))
    assert np.all(np.isfinite(g))
    fd = np.empty_like(g)
    for i in range(len(theta)):
        h = 1e-6 * abs(theta[i])
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        fd[i] = (float(loss(tp, x, v, dt)) - float(loss(tm, x, v, dt))) / (2 * h)
    # compare sensitivities to a relative change of each parameter
    gs, fds = g * np.abs(theta), fd * np.abs(theta)
    np.testing.assert_allclose(gs, fds, rtol=1e-5, atol=1e-7 * np.max(np.abs(fds)))
    if x is XS and name != "dahl":
        assert g[get(name).param_names.index("n")] != 0.0  # z left 0 in the first step



#: The L-stable cases of GRAD_CASES, and a UTFSM-like modified Bouc-Wen fit (a 10 mm, 1 Hz,
#: 0.5 A test's parameters on a 1 Hz, 10 mm sine at 1 kHz, two cycles).
_, XU, VU, DTU = sine(1.0, 0.010, 1000.0, 2.0)
UTFSM_LIKE = np.array([1408.0, 6420.0, 10354.0, -3234.0, 979.0, 552.0, -294.0, 5000.0, 1.0045,
                       -0.26])
#: The same with beta > gamma (a posterior's mode on a 25 mm, 0.1 Hz, 1 A test): z's unloading
#: branch is unstable, d zdot/dz > 0, where the models' Newton matrix differs from their Jacobian.
UNLOADING = np.array([38000.0, 9600.0, 167000.0, -4800.0, 314.0, 3004.6, 107.0, 62.0, 2.966,
                      50.0])
TANGENT_CASES = [c[:5] for c in GRAD_CASES if c[5] == "sdirk"] + [
    ("modified_bouc_wen", UTFSM_LIKE, XU, VU, DTU), ("modified_bouc_wen", UNLOADING, XU, VU, DTU)]


@pytest.mark.parametrize("name,theta,x,v,dt", TANGENT_CASES,
                         ids=[f"{c[0]}-{i}" for i, c in enumerate(TANGENT_CASES)])
def test_implicit_tangent_is_the_exact_jacobian_to_the_newton_correction(name, theta, x, v, dt):
    """The polish's cheaper derivative of the L-stable scheme (`tangent="implicit"`, what
    `resolve_model` picks): the same forces, and a forward-mode Jacobian that differs from the
    exact one by the last Newton correction, column by column: 1e-4 on the UTFSM-like fits
    (measured 5e-5, and 8e-6 with beta > gamma, where the tangent solved with the Newton
    matrix in place of the Jacobian was off by 12 %), 1 % on the stiff test sets at one step
    per sample, where two Newton iterations leave a visible correction (measured up to
    0.2 %; 5 % with the Newton matrix); a finite reverse-mode gradient."""
    exact = get(name).with_substeps(1, "sdirk")
    implicit = get(name).with_substeps(1, "sdirk", "implicit")
    assert implicit.tangent == "implicit" and exact.tangent is None
    F_e, F_i = (np.asarray(jax.jit(m.force)(theta, x, v, dt)) for m in (exact, implicit))
    np.testing.assert_allclose(F_i, F_e, rtol=1e-13, atol=1e-10)  # two programs: to rounding
    J_e, J_i = (np.asarray(jax.jit(jax.jacfwd(m.force))(theta, x, v, dt))
                for m in (exact, implicit))
    norm = np.linalg.norm(J_e, axis=0)
    live = norm > 1e-9 * norm.max()
    err = np.linalg.norm(J_i - J_e, axis=0)[live] / norm[live]
    print(f"\nTANGENT {name} max column error {np.max(err):.1e}")
    assert np.all(err < (1e-4 if theta is UTFSM_LIKE or theta is UNLOADING else 0.01)), err
    # it is an approximation: somewhere it differs from the exact one
    assert np.max(err) > 1e-12
    g = jax.grad(lambda q: jnp.sum(implicit.force(q, x, v, dt) ** 2))(theta)
    assert np.all(np.isfinite(np.asarray(g)))


@pytest.mark.parametrize("name", [n for n in mrjax.models.names()
                                  if get(n).dynamic and get(n).ode().linearize is not None])
def test_linearize_gives_the_derivative_and_its_newton_matrix(name):
    """A model's `linearize` keeps its contract: its J is d rhs / d state (forward mode, to
    rounding) at every state, the unstable branch included; a third entry, where given, is the
    Newton matrix (Bouc-Wen's clips d zdot/dz at 0). J is what the implicit tangent solves
    with: the clipped one in its place was off by 12 % on an unloading branch."""
    from mrjax.models._integrate import _newton_lin  # noqa: SLF001

    model = get(name)
    ode = model.ode()
    lo, hi = (np.asarray(b, float) for b in model.bounds)
    rng = np.random.default_rng(0)
    lin = jax.jit(_newton_lin(ode.linearize))
    jac = jax.jit(jax.jacfwd(ode.rhs))
    positive = False
    S = int(np.shape(ode.initial(0.0, 0.0))[0])
    for _ in range(40):
        p = lo + rng.uniform(size=lo.size) * (hi - lo)
        # a state inside the box the state never leaves (+-2 cm where it is unbounded)
        box = ode.box(jnp.asarray(p)) if ode.box is not None else (-np.inf, np.inf)
        lo_s, hi_s = (np.broadcast_to(np.asarray(b, float), (S,)) for b in box)
        y = rng.uniform(np.where(np.isfinite(lo_s), lo_s, -0.02),
                        np.where(np.isfinite(hi_s), hi_s, 0.02))
        xi, vi = rng.normal() * 0.01, rng.normal() * 0.1
        f, J, M = (np.asarray(a) for a in lin(y, xi, vi, p))
        # two programs (one jitted): equal to rounding, on the scale of the largest entry
        np.testing.assert_allclose(f, np.asarray(ode.rhs(y, xi, vi, p)), rtol=1e-10,
                                   atol=1e-10 * np.max(np.abs(f)) + 1e-300)
        Jad = np.asarray(jac(y, xi, vi, p))
        np.testing.assert_allclose(J, Jad, rtol=1e-9, atol=1e-9 * np.max(np.abs(Jad)))
        assert np.all(np.asarray(M) <= np.asarray(J) + 1e-12)  # clipped, never raised
        # the unstable branch: d zdot/dz > 0 (a scalar Newton step clips it itself)
        positive |= bool(np.any(J > 0) if S == 1 else np.any(M != J))
    if name in ("bouc_wen", "modified_bouc_wen"):
        assert positive  # that branch was among the states checked


def test_tangent_is_validated_and_set_by_the_policy():
    with pytest.raises(mrjax.InputError, match="tangent"):
        get("bouc_wen").with_substeps(1, "sdirk", "adjoint")
    bw = get("bouc_wen")
    assert mrjax.models.resolve_model(bw, TRUE_PARAMS["bouc_wen"], V, DT,
                                      swarm=True).tangent == "implicit"
    # a user's fixed integration keeps the exact derivative
    fixed = bw.with_substeps(1, "sdirk")
    assert mrjax.models.resolve_model(fixed, TRUE_PARAMS["bouc_wen"], V, DT) is fixed

# ================================================================== 5. divergence
DIVERGENT = {
    # negative beta + gamma: z' = v (delta + |beta + gamma| z^2) blows up in finite time (in the
    # modified Bouc-Wen model the growth of z feeds back through ydot and stays bounded)
    "bouc_wen": np.array([1000.0, 500.0, 800.0, 0.0, 5000.0, -1e6, -1e6, 2.0]),
}
#: A stiffness no scheme of mrjax can take in one explicit step: RK4 diverges (the L-stable
#: scheme and Dahl's exact update stay finite, see below).
TOO_STIFF_FOR_RK4 = np.array([3000.0, 2000.0, 1000.0, 500.0, 2500.0, 1e9, 1.0, 1.0, 2.0, 0.0])


@pytest.mark.parametrize("scheme", ["rk4", "sdirk"])
@pytest.mark.parametrize("name", list(DIVERGENT))
def test_divergence_gives_nonfinite_without_raising(name, scheme):
    theta = DIVERGENT[name]
    F = np.asarray(jforce(name, 1, scheme)(theta, X, V, DT))  # inside jit
    assert F.shape == X.shape and not np.all(np.isfinite(F))
    assert np.isfinite(F[0])  # the initial sample is still finite
    F = np.asarray(get(name).force(theta, X, V, DT))  # the automatic integration (eager)
    assert not np.all(np.isfinite(F))


def test_stiffness_diverges_rk4_not_the_l_stable_scheme():
    F = np.asarray(jforce("modified_bouc_wen", 1, "rk4")(TOO_STIFF_FOR_RK4, X, V, DT))
    assert not np.all(np.isfinite(F))
    F = np.asarray(jforce("modified_bouc_wen", 1, "sdirk")(TOO_STIFF_FOR_RK4, X, V, DT))
    assert np.all(np.isfinite(F)) and np.max(np.abs(F)) < 1e5
    F = np.asarray(get("dahl").force(np.array([1000.0, 500.0, 800.0, 1e9, 0.0]), X, V, DT))
    assert np.all(np.isfinite(F)) and np.all(np.abs(F - 1000.0 * V - 500.0 * X) <= 800.0 + 1e-9)


# ================================================================== 6. time-varying parameters
@pytest.mark.parametrize("name", MODEL_NAMES)
def test_time_varying_parameters(name):
    theta = TRUE_PARAMS[name]
    T, P = len(X), len(theta)
    model, force = get(name), jforce(name)  # (the automatic count: test_spencer_voltage_ramp)
    const = np.broadcast_to(theta, (T, P))
    F1 = np.asarray(force(theta, X, V, DT))
    np.testing.assert_allclose(force(const, X, V, DT), F1, rtol=1e-13, atol=1e-10)
    # a genuine variation: +-20 % on every parameter over the record
    wobble = 1.0 + 0.2 * np.sin(np.linspace(0, 3 * np.pi, T))[:, None] * np.ones(P)
    if name in ("bouc_wen", "modified_bouc_wen"):
        wobble[:, model.param_names.index("n")] = 1.0 + 0.2 * np.linspace(0, 1, T)
    F = np.asarray(force(theta * wobble, X, V, DT))
    assert F.shape == (T,) and np.all(np.isfinite(F))
    assert not np.allclose(F, F1)
    # a switch at sample k: per-sample parameters act on the interval that starts at their sample
    k = 120
    other = theta * 1.3
    switched = np.where(np.arange(T)[:, None] < k, theta, other)
    Fs = np.asarray(force(switched, X, V, DT))
    np.testing.assert_allclose(Fs[:k], F1[:k], rtol=1e-13, atol=1e-10)
    assert not np.allclose(Fs[k:], F1[k:])
    if name in STATIC_MODELS:
        np.testing.assert_allclose(Fs[k:], force(other, X, V, DT)[k:], rtol=1e-13)


def test_spencer_voltage_ramp():
    """Current-driven use: Spencer's parameters following a voltage ramp 0 -> 2.25 V, with the
    automatic sub-step count (the stiffest row decides)."""
    u = np.linspace(0.0, 2.25, len(X))
    theta = np.stack([spencer1997(ui) for ui in u])
    model = get("modified_bouc_wen")
    assert model.resolve_substeps(theta, V, DT) == model.resolve_substeps(theta[-1], V, DT) > 8
    F = np.asarray(model.force(theta, X, V, DT))
    assert F.shape == X.shape and np.all(np.isfinite(F))
    # |velocity| is symmetric over the half cycle; the end, at 2.25 V, carries far more force
    assert np.max(np.abs(F[-50:])) > 2 * np.max(np.abs(F[:50]))


# ================================================================== 7. jit and vmap
@pytest.mark.parametrize("name", MODEL_NAMES)
def test_jit_and_vmap(name):
    theta = TRUE_PARAMS[name]
    model = get(name, substeps=M)
    eager = np.asarray(model.force(theta, X, V, DT))
    np.testing.assert_allclose(jforce(name)(theta, X, V, DT), eager, rtol=1e-13, atol=1e-10)
    batch = theta * np.array([[1.0], [0.8], [1.25]])
    vm = jax.jit(jax.vmap(model.force, in_axes=(0, None, None, None)))(batch, X, V, DT)
    loop = np.stack([jforce(name)(b, X, V, DT) for b in batch])
    assert vm.shape == (3, len(X))
    np.testing.assert_allclose(vm, loop, rtol=1e-13, atol=1e-10)


def test_jit_with_automatic_substeps():
    """Traced inputs give no stiffness estimate; a fixed count is used and the result is close."""
    theta = TRUE_PARAMS["bouc_wen"]
    F = np.asarray(jax.jit(get("bouc_wen").force)(theta, X, V, DT))
    assert nrmse(F, get("bouc_wen").force(theta, X, V, DT)) < 1e-3


# ================================================================== 8. properties (hypothesis)
N_REAL, N_PAD = 1000, 1200


@st.composite
def excitation_and_params(draw, name):
    """Uniform parameters in the default bounds; a sinusoid with 1-2 cycles in N_REAL samples at
    500 Hz-1 kHz (so 0.5-2 Hz), 2-15 mm amplitude and random phase, padded to N_PAD."""
    lo, hi = get(name).bounds
    u = np.array(draw(st.lists(st.floats(0, 1), min_size=len(lo), max_size=len(lo))))
    theta = lo + u * (hi - lo)
    names = get(name).param_names
    if "beta" in names and "gamma" in names:
        # the box allows beta < 0; a well-posed Bouc-Wen loop needs gamma + beta >= 0 (outside
        # it z grows without bound: the swarm scores such particles inf, see test_reliability)
        b, g = names.index("beta"), names.index("gamma")
        theta[b] = max(theta[b], -theta[g])
    _, x, v, rate, _, _ = draw_sine(draw, N_REAL, 500.0)
    return theta, x, v, 1.0 / rate


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_random_parameters_finite_and_padding_invariant(name):
    model = get(name)

    @settings(
        max_examples=15, deadline=None, derandomize=True, database=None,
        suppress_health_check=[HealthCheck.too_slow],
    )
    @given(excitation_and_params(name))
    def check(args):
        theta, x, v, dt = args
        # the automatic count, on the host, exactly as `model.force` would choose it
        m = model.resolve_substeps(theta, v, dt)
        force = jforce(name, m)
        F = np.asarray(force(theta, x, v, dt))
        assert np.all(np.isfinite(F)), (m, dict(zip(model.param_names, theta)))
        pad = N_PAD - N_REAL
        xp = np.concatenate([x, np.full(pad, x[-1])])
        vp = np.concatenate([v, np.zeros(pad)])
        assert model.resolve_substeps(theta, vp, dt) == m
        Fp = np.asarray(force(theta, xp, vp, dt))
        np.testing.assert_allclose(Fp[:N_REAL], F, rtol=1e-13, atol=1e-10)  # two programs
        assert np.all(np.isfinite(Fp))

    check()


def test_policy_ignores_padding_and_takes_groups():
    """The polish's policy on Spencer's stiff set (L-stable scheme by step doubling): a record
    padded with zero velocity after its end gets the count of the record alone (the jump to
    zero is not a sample; unmasked it asked for RK4 x 16), and groups of records of different
    lengths get the largest of their counts, with the implicit tangent."""
    mbw = get("modified_bouc_wen")
    th = spencer1997(1.0)
    _, _, v1, dt1 = sine(2.5, 0.015, 1000.0, 1.0)  # 400 samples
    _, _, v2, dt2 = sine(1.0, 0.010, 1000.0, 0.5)  # 500 samples
    alone1 = mrjax.models.resolve_model(mbw, th, v1, dt1)
    alone2 = mrjax.models.resolve_model(mbw, th, v2, dt2)
    assert alone1.scheme == alone2.scheme == "sdirk" and alone1.tangent == "implicit"
    V = np.zeros((1, len(v2)))
    V[0, :len(v1)] = v1
    M = np.zeros(V.shape, bool)
    M[0, :len(v1)] = True
    H = np.full(V.shape, dt1)
    padded = mrjax.models.resolve_model(mbw, th, V, H, M)
    assert (padded.scheme, padded.substeps) == (alone1.scheme, alone1.substeps)
    unmasked = mrjax.models.resolve_model(mbw, th, V, H)
    assert (unmasked.scheme, unmasked.substeps) != (padded.scheme, padded.substeps)
    groups = mrjax.models.resolve_model(mbw, th, (v1[None], v2[None]),
                                        (np.full((1, len(v1)), dt1), np.full((1, len(v2)), dt2)))
    assert groups.scheme == "sdirk"
    assert groups.substeps == max(alone1.substeps, alone2.substeps)
