"""Tests of `mrjax.generalize`: current-dependent models (eq 24-29), their prediction at any
(also time-varying) current, the inverse tanh model and the `fit.json` block.

Compiled shapes are shared: the known-answer tests all use the 36-condition paper grid and one
per-condition fit of it; the inverse and time-varying tests use the exact eq 24-29 laws.
"""

import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import TRUE_PARAMS, sine

import mrjax
from mrjax import data
from mrjax.data import PAPER_COEFFICIENTS
from mrjax.generalize import (
    GeneralizedModel,
    Law,
    canonical_z_scale,
    default_degrees,
    generalize,
    inverse_current,
    lag_current,
)

TOL = 0.05  # the 5 % on every coefficient


def _paper_model() -> GeneralizedModel:
    """The exact eq 24-29 laws as a generalized tanh model."""
    laws = {n: Law("poly", PAPER_COEFFICIENTS[n]) for n in mrjax.models.get("kwok").param_names}
    return GeneralizedModel("kwok", laws, "two-step", float("nan"), (0.0, 2.0))


def _errors(gm: GeneralizedModel) -> dict[str, np.ndarray]:
    return {n: np.asarray(gm.coefficients(n)) / np.asarray(PAPER_COEFFICIENTS[n]) - 1.0
            for n in gm.param_names}


@pytest.fixture(scope="module")
def grid():
    batch = data.paper_grid()
    t = time.perf_counter()
    res = mrjax.fit("kwok", batch, key=0)
    print(f"\nper-condition fit of the paper grid: {time.perf_counter() - t:.1f} s")
    return batch, res


@pytest.fixture(scope="module")
def generalized(grid):
    batch, res = grid
    out = {}
    for method in ("two-step", "joint"):
        t = time.perf_counter()
        out[method] = generalize(res, batch, method=method)
        print(f"\n{method}: {time.perf_counter() - t:.1f} s, {out[method].report}")
    return out


# ------------------------------------------------------------------------------ known answers
@pytest.mark.parametrize("method", ["two-step", "joint"])
def test_recovers_paper_coefficients(generalized, method):
    gm = generalized[method]
    assert gm.method == method and gm.model.name == "kwok"
    err = _errors(gm)
    print(f"\n{method} ({gm.weighting}) relative coefficient errors [%]:")
    for n, e in err.items():
        print(f"  {n:>5}: {np.array2string(100 * e, precision=2)}   {gm.laws[n].formula()}")
    for n, e in err.items():
        assert gm.laws[n].degree == len(PAPER_COEFFICIENTS[n]) - 1
        assert np.all(np.abs(e) < TOL), (n, e)
    assert gm.current_range == (0.0, 2.0)


def test_paper_two_step_equal_weights(grid):
    """The paper's literal two-step (plain means, ordinary least squares) is noisier: the small
    alpha(0) = 32 N is its weakest coefficient; everything stays within 10 %."""
    batch, res = grid
    gm = generalize(res, batch, method="two-step", weighting="equal")
    assert gm.weighting == "equal"
    err = _errors(gm)
    print("\nequal-weight two-step errors [%]: "
          + ", ".join(f"{n} {np.array2string(100 * e, precision=2)}" for n, e in err.items()))
    assert all(np.all(np.abs(e) < 0.10) for e in err.values())


def test_joint_not_worse_than_two_step(grid, generalized):
    batch, _ = grid
    two, joint = generalized["two-step"], generalized["joint"]
    truth = _paper_model().evaluate(batch)["total_rms"]
    print(f"\ntotal RMS: two-step {two.total_rms:.6f} N, joint {joint.total_rms:.6f} N, "
          f"eq 24-29 truth {truth:.6f} N")
    assert joint.total_rms <= two.total_rms
    # the joint fit is the least-squares optimum of the laws: at or below the truth's RMS
    assert joint.total_rms <= truth * (1 + 1e-9)
    assert two.report.two_step_rms == pytest.approx(two.total_rms)
    for gm in (two, joint):
        ev = gm.evaluate(batch)
        assert ev["total_rms"] == pytest.approx(gm.total_rms, rel=1e-9)
        assert ev["rms"].shape == ev["nrmse"].shape == (batch.n_conditions,)
        assert np.all(ev["rms"] < 21.5)  # sigma = 20 N everywhere


def test_exp_law_for_beta(grid):
    batch, res = grid
    gm = generalize(res, batch, laws={"beta": "exp"})
    law = gm.laws["beta"]
    assert law.kind == "exp" and law.degree == 1
    b = np.asarray(law(np.array([0.0, 1.0, 2.0])))
    print(f"\nbeta = {law.formula()} -> {b}")
    np.testing.assert_allclose(b, 100.0, rtol=0.05)
    # a law given with a degree keeps it; too high a degree is an error
    assert generalize(res, batch, degrees={"beta": 1}).laws["beta"].degree == 1
    with pytest.raises(mrjax.InputError, match="distinct currents"):
        generalize(res, batch, degrees={"c": 6})


# ------------------------------------------------------------------------------ prediction
def test_params_at_shapes_and_jit():
    gm = _paper_model()
    np.testing.assert_allclose(gm.params_at(0.6), data.paper_parameters(0.6), rtol=1e-12)
    cur = np.array([0.0, 0.25, 2.0])
    np.testing.assert_allclose(gm.params_at(cur), data.paper_parameters(cur), rtol=1e-12)
    assert gm.params_at(jnp.zeros((5,))).shape == (5, 6)
    np.testing.assert_allclose(jax.jit(gm.params_at)(cur), gm.params_at(cur), rtol=1e-14)
    # Law: NumPy in, NumPy out; JAX in, JAX out
    assert isinstance(gm.laws["alpha"](cur), np.ndarray)
    assert isinstance(gm.laws["alpha"](jnp.asarray(cur)), jax.Array)


def test_time_varying_current_constant_signal():
    t, x, v, dt = sine(2.0, 0.008)
    gm = _paper_model()
    scalar = np.asarray(gm.force(x, v, dt, 0.75))
    signal = np.asarray(gm.force(x, v, dt, np.full(x.shape, 0.75)))
    np.testing.assert_allclose(signal, scalar, rtol=1e-12, atol=1e-9)
    # the same through an ODE model (per-sample parameters through the RK4 scan)
    bw = mrjax.models.get("bouc_wen")
    th = TRUE_PARAMS["bouc_wen"]
    laws = {n: Law("poly", (th[j], 0.1 * th[j])) for j, n in enumerate(bw.param_names)}
    gbw = GeneralizedModel(bw, laws, "two-step", 0.0, (0.0, 1.0))
    np.testing.assert_allclose(gbw.force(x, v, dt, np.full(x.shape, 0.5)),
                               gbw.force(x, v, dt, 0.5), rtol=1e-10, atol=1e-8)
    # a batch prediction at each condition's own current equals the per-record force
    batch = data.paper_grid(currents=(0.5, 1.0), motions=((2.0, 0.008),), noise=0.0)
    pred = gm.predict(batch)
    np.testing.assert_allclose(pred[1], gm.force(batch.x[1], batch.xdot[1], batch.dt[1], 1.0),
                               rtol=1e-12)
    np.testing.assert_allclose(pred, gm.predict(batch, current=np.asarray(batch.current)[:, None]
                                                * np.ones(batch.x.shape)), rtol=1e-12)


def test_current_lag_first_order_step():
    t, x, v, dt = sine(1.0, 0.008, cycles=1.0)
    k0, eta = 100, 50.0
    i = np.where(np.arange(t.size) >= k0, 1.0, 0.0)
    u = np.asarray(lag_current(i, dt, eta))
    expected = np.where(np.arange(t.size) > k0, 1.0 - np.exp(-eta * (t - t[k0])), 0.0)
    np.testing.assert_allclose(u, expected, atol=1e-12)
    gm = _paper_model()
    f_lag = np.asarray(gm.force(x, v, dt, i, lag=eta))
    np.testing.assert_allclose(f_lag, gm.force(x, v, dt, expected), rtol=1e-12, atol=1e-9)
    # before the step: the 0 A force; five time constants after it: the 1 A force
    f0, f1 = np.asarray(gm.force(x, v, dt, 0.0)), np.asarray(gm.force(x, v, dt, 1.0))
    np.testing.assert_allclose(f_lag[:k0 + 1], f0[:k0 + 1], rtol=1e-12)
    late = np.arange(t.size) > k0 + 5 / (eta * dt)
    assert np.max(np.abs(f_lag[late] - f1[late])) < 0.01 * np.max(np.abs(f1))
    assert np.max(np.abs(f_lag[k0 + 1:k0 + 5] - f1[k0 + 1:k0 + 5])) > 50.0  # it does lag
    with pytest.raises(mrjax.InputError, match="lag"):
        gm.force(x, v, dt, i, lag=-1.0)


# ------------------------------------------------------------------------------ inverse
def test_inverse_round_trip():
    gm = _paper_model()
    rng = np.random.default_rng(0)
    n = 2000
    x = rng.uniform(-0.012, 0.012, n)
    v = rng.uniform(-0.1, 0.1, n)
    i = rng.uniform(0.0, 2.0, n)
    f_of = jax.jit(jax.vmap(lambda a, b, c: gm.model.force(gm.params_at(c), a[None], b[None])[0]))
    fd = np.asarray(f_of(x, v, i))
    inv = jax.jit(lambda a, b, c: inverse_current(gm, a, b, c, i_max=2.0))
    ic = np.asarray(inv(x, v, fd))
    err = np.abs(np.asarray(f_of(x, v, ic)) - fd)
    print(f"\ninverse round trip: max force error {err.max():.2e} N, "
          f"max |i - i_true| {np.max(np.abs(ic - i)):.2e} A")
    assert np.all((ic >= 0.0) & (ic <= 2.0))
    assert err.max() < 1.0
    np.testing.assert_allclose(inverse_current(gm, x, v, fd, i_max=2.0), ic, atol=1e-12)
    # shapes broadcast
    assert inverse_current(gm, x[:6].reshape(2, 3), 0.05, 100.0).shape == (2, 3)

    # unreachable forces: the closest force, exactly at a limit where f(i) is monotone
    grid = np.linspace(0.0, 2.0, 2001)
    fg = np.asarray(jax.vmap(lambda c: f_of(x[:200], v[:200], jnp.full(200, c)))(grid))  # (G, n)
    for far in (-5000.0, 5000.0):
        want = np.where(far > 0, fg.max(0) + 300.0, fg.min(0) - 300.0) + 0 * far
        got = np.asarray(inverse_current(gm, x[:200], v[:200], want, i_max=2.0))
        best = np.min(np.abs(fg - want), axis=0)
        np.testing.assert_array_less(np.abs(np.asarray(f_of(x[:200], v[:200], got)) - want),
                                     best + 1e-6)
        mono = np.all(np.diff(fg, axis=0) > 0, axis=0) | np.all(np.diff(fg, axis=0) < 0, axis=0)
        assert mono.sum() > 100
        assert np.all(np.isin(got[mono], [0.0, 2.0]))
    with pytest.raises(mrjax.InputError, match="dt"):  # a dynamic model needs a record
        bw = GeneralizedModel("bouc_wen", {n: Law("poly", (float(v),)) for n, v in
                                           zip(mrjax.models.get("bouc_wen").param_names,
                                               TRUE_PARAMS["bouc_wen"])},
                              "given", 0.0, (0.0, 1.0))
        inverse_current(bw, x[:10], v[:10], fd[:10])


# ------------------------------------------------------------------------------ I/O, errors
def test_dict_round_trip(generalized, tmp_path):
    gm = generalized["joint"]
    d = gm.to_dict()
    assert d["method"] == "joint" and d["model"] == "kwok"
    assert d["total_rms_N"] == pytest.approx(gm.total_rms)
    assert d["current_range_A"] == [0.0, 2.0]
    assert d["laws"]["alpha"]["law"] == "poly" and d["laws"]["alpha"]["degree"] == 2
    assert len(d["laws"]["alpha"]["coefficients"]) == 3
    back = GeneralizedModel.from_dict(json.loads(json.dumps(d)))
    assert back.to_dict() == d
    cur = np.linspace(0.0, 2.0, 7)
    np.testing.assert_array_equal(back.params_at(cur), gm.params_at(cur))
    path = tmp_path / "fit.json"
    path.write_text(json.dumps({"model": "kwok", "generalized": d}))
    assert GeneralizedModel.from_json_file(path).to_dict() == d
    (tmp_path / "g.json").write_text(gm.to_json())
    assert GeneralizedModel.from_json_file(tmp_path / "g.json").laws == gm.laws
    bad = dict(d, laws={k: v for k, v in d["laws"].items() if k != "beta"})
    with pytest.raises(mrjax.InputError, match="missing"):
        GeneralizedModel.from_dict(bad)


def test_input_errors(grid):
    batch, res = grid
    with pytest.raises(mrjax.InputError, match="unknown parameters"):
        generalize(res, batch, degrees={"gamma": 1})
    with pytest.raises(mrjax.InputError, match="positive"):
        generalize(res, batch, laws={"f0": "exp"})
    with pytest.raises(mrjax.InputError, match="method"):
        generalize(res, batch, method="three-step")
    with pytest.raises(mrjax.InputError, match="conditions"):
        generalize(res, batch.subset(range(6)))
    with pytest.raises(mrjax.InputError, match="kind"):
        Law("cubic", (1.0,))


def test_defaults_and_z_scale():
    assert default_degrees("kwok") == {"c": 1, "k": 1, "alpha": 2, "beta": 0, "delta": 1,
                                       "f0": 1}
    assert default_degrees("dahl", n_currents=2) == {"c": 1, "k": 1, "alpha": 1, "rho": 0,
                                                     "f0": 1}
    mbw = default_degrees("modified_bouc_wen")
    assert (mbw["c0"], mbw["c1"], mbw["alpha"], mbw["beta"], mbw["n"]) == (1, 1, 2, 0, 0)
    assert set(default_degrees("modified_bouc_wen", n_currents=1).values()) == {0}
    # the |z|max = 1 normalisation leaves the Bouc-Wen force unchanged
    t, x, v, dt = sine(2.0, 0.008)
    m = mrjax.models.get("bouc_wen", substeps=4)
    th = TRUE_PARAMS["bouc_wen"]
    tc = canonical_z_scale(m, th)
    ix = m.param_names.index
    assert tc[ix("delta")] / (tc[ix("beta")] + tc[ix("gamma")]) == pytest.approx(1.0)
    np.testing.assert_allclose(m.force(tc, x, v, dt), m.force(th, x, v, dt), rtol=1e-9,
                               atol=1e-9)


# ------------------------------------------------------------------------------ real data
#: The real-data runs beyond the tanh two-step one take minutes (joint tanh) to tens of
#: minutes (modified Bouc-Wen on 18 long tests, 2 CPU cores): run them with MRJAX_SLOW=1.
needs_slow = pytest.mark.skipif(os.environ.get("MRJAX_SLOW") != "1",
                                reason="long real-data run; set MRJAX_SLOW=1")


def _held_out(utfsm, model: str, method: str, fit_kw=None, gen_kw=None):
    """Fit every motion at 0, 0.5 and 1 A, generalize, predict the 0.25 and 0.75 A tests."""
    conds = data.load(utfsm)
    train = data.make_batch([c for c in conds if c.current in (0.0, 0.5, 1.0)])
    test = data.make_batch([c for c in conds if c.current in (0.25, 0.75)])
    t = time.perf_counter()
    res = mrjax.fit(model, train, key=0, **(fit_kw or {}))
    t_fit = time.perf_counter() - t
    t = time.perf_counter()
    gm = generalize(res, train, method=method, **(gen_kw or {}))
    t_gen = time.perf_counter() - t
    ev = gm.evaluate(test)
    print(f"\nUTFSM {model} ({method}): fit {t_fit:.1f} s, generalize {t_gen:.1f} s; "
          f"per-test fits median NRMSE {100 * np.median(res.nrmse):.2f} %; generalized: "
          f"training total RMS {gm.total_rms:.1f} N, held-out 0.25/0.75 A median NRMSE "
          f"{100 * ev['median_nrmse']:.2f} % (max {100 * np.max(ev['nrmse']):.2f} %)")
    print(gm)
    assert gm.current_range == (0.0, 1.0)
    assert np.all(np.isfinite(ev["nrmse"]))
    return res, gm, ev


def test_utfsm_held_out_currents_tanh(utfsm):
    """The goal is <= 9 % (the data authors' 12-parameter Bouc-Wen model, fitted on all tests).
    The tanh model with current-only laws does not reach it: one parameter set per current
    shared by all six motions already gives about 12 % on the *training* tests (its parameters
    depend on the motion, not only on the current). This guards the measured 13 %."""
    _, _, ev = _held_out(utfsm, "kwok", "two-step")
    assert ev["median_nrmse"] <= 0.145


@pytest.mark.slow
@needs_slow
def test_utfsm_held_out_currents_tanh_joint(utfsm):
    _, gm, ev = _held_out(utfsm, "kwok", "joint")  # measured: 13.9 %
    assert gm.total_rms <= gm.report.two_step_rms
    assert ev["median_nrmse"] <= 0.15


@pytest.mark.slow
@needs_slow
def test_utfsm_held_out_currents_modified_bouc_wen(utfsm):
    """About 1 min on 2 cores (62 s measured; 45 min before the dynamic-model work). The
    per-test polish of this stiff model on 18 long records once took over an hour, so the
    swarm's per-test parameters are generalized. They
    scatter wildly between motions (many on their bounds), so the two-step averages are useless
    here (55 % held-out); the joint fit reaches 11.0 % (measured with these settings)."""
    _, gm, ev = _held_out(utfsm, "modified_bouc_wen", "joint",
                          fit_kw=dict(swarm=mrjax.Swarm(max_generations=80), polish=None),
                          gen_kw=dict(swarm=mrjax.Swarm(max_generations=30),
                                      polish=mrjax.Polish(max_steps=20)))
    assert gm.total_rms <= gm.report.two_step_rms
    assert ev["median_nrmse"] <= 0.13
