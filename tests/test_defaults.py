"""Right by default: the per-test fit's retry from the neighbours' optima and its evidence of a
local optimum, the swarms per test chosen per model and batch, and law forms chosen by the data
(`laws="auto"`, the saturating law). Known answers: a corrupted optimum recovered from its
neighbours, the paper's eq 24-29 forms recovered from the grid's true parameters, a saturating
law recovered from tests simulated on it. The real-data figures are in `benchmarks/defaults.md`.
"""

import dataclasses
import json

import numpy as np
import pytest

import mrjax
from mrjax.cli._main import build_parser
from mrjax.data import PAPER_COEFFICIENTS, paper_grid, paper_truth
from mrjax.engine import Polish, solve
from mrjax.fitting import (
    SPREAD_MARGIN,
    default_restarts,
    neighbours,
    retry_starts,
)
from mrjax.fitting import (
    tests_problem as make_problem,
)
from mrjax.generalize import GeneralizedModel, Law, choose_forms, generalize
from mrjax.objective import rms_per_condition


@pytest.fixture(scope="module")
def one_current():
    """The six tests of the paper grid at one current (they share their true parameters),
    with 0.5 % force noise, and their truth."""
    grid = paper_grid()
    idx = np.arange(12, 18)
    truth = paper_truth(grid)[idx]
    conds = []
    for k, i in enumerate(idx):
        c = grid.condition(int(i))
        rng = np.random.default_rng(k)
        f = np.asarray(c.force, float)
        conds.append(dataclasses.replace(
            c, force=f + 0.005 * np.max(np.abs(f)) * rng.standard_normal(f.shape)))
    return mrjax.data.make_batch(conds), truth


def test_default_restarts_per_model_and_batch():
    """One swarm per test, two for a dynamic model's lone test (no neighbour to retry from);
    the CLI leaves the choice to the library (`--restarts` unset, retry on)."""
    assert default_restarts(mrjax.models.get("kwok"), 1) == 1
    assert default_restarts(mrjax.models.get("modified_bouc_wen"), 1) == 2
    assert default_restarts(mrjax.models.get("modified_bouc_wen"), 2) == 1
    assert default_restarts(mrjax.models.get("dahl"), 30) == 1
    for cmd in ("fit", "compare"):
        extra = ["--model", "kwok"] if cmd == "fit" else []
        args = build_parser().parse_args([cmd, "x.csv", *extra])
        assert args.restarts is None and args.no_retry is False
        args = build_parser().parse_args([cmd, "x.csv", *extra, "--no-retry"])
        assert args.no_retry is True
    with pytest.raises(mrjax.InputError, match="retry"):
        mrjax.Polish(retry=1)


def test_neighbours_prefer_the_same_current():
    cur = np.array([0.0, 0.0, 1.0, 1.0, 0.5, np.nan])
    freq = np.array([1.0, 2.0, 1.0, 2.0, 1.0, 1.0])
    amp = np.array([0.01, 0.01, 0.01, 0.01, 0.01, 0.01])
    d = neighbours(cur, freq, amp, k=2)
    assert d.shape == (6, 2)
    assert d[0, 0] == 1 and d[2, 0] == 3  # same current first
    assert d[4, 0] in (0, 2) and 4 not in d[4]  # never itself
    assert neighbours(cur[:1], freq[:1], amp[:1]).shape == (1, 0)


def test_retry_recovers_a_corrupted_optimum(one_current):
    """Test 0's optimum replaced by a poor point: its retry start is a neighbour's optimum with
    its linear parameters solved on test 0, and the polish from it reaches the truth."""
    batch, truth = one_current
    model = mrjax.models.get("kwok")
    theta = truth.copy()
    bad = theta[0].copy()
    bad[model.param_names.index("beta")] = 5.0
    bad[model.param_names.index("delta")] = 0.05
    theta[0] = bad
    problem = make_problem(model, batch)
    donors = neighbours(np.asarray(batch.current), np.asarray(batch.frequency),
                        np.asarray(batch.amplitude))
    z0, donor = retry_starts(problem, donors, theta, np.arange(6))
    assert donor[0] != 0
    nl = list(model.nonlinear_index)
    np.testing.assert_allclose(z0[0, nl], truth[donor[0], nl])
    rms_true = rms_per_condition(model, truth, batch)
    rms_bad = rms_per_condition(model, theta, batch)
    assert rms_bad[0] > 3 * rms_true[0]
    out = solve(problem, swarm=None, polish=Polish(), uncertainty=False, start=z0)
    assert out.start.source == "given"
    assert out.rms[0] <= rms_true[0] * 1.001
    # the optimum the polish reaches from the truth itself
    ref = solve(problem, swarm=None, polish=Polish(), uncertainty=False, start=truth)
    assert out.rms[0] <= ref.rms[0] * (1 + 1e-5)
    np.testing.assert_allclose(out.z[0], ref.z[0], rtol=0.02)
    with pytest.raises(mrjax.InputError, match="swarm or a start"):
        solve(problem, swarm=mrjax.Swarm(), polish=Polish(), start=z0)


def test_fit_retries_and_warns_where_the_starts_disagree(one_current, monkeypatch):
    """The first pass's optimum of one test corrupted: the fit's retry finds it again, the two
    starts are in `starts_rms`, and the warning names the test in the table and fit.json."""
    import mrjax.fitting._chunks as chunks

    batch, truth = one_current
    real = chunks.fit_chunk

    def corrupted(model, data, run, *args, **kw):
        res = real(model, data, run, *args, **kw)
        theta = res.theta.copy()
        theta[0] = theta[0] * np.array([1.0, 1.0, 0.3, 0.05, 0.2, 1.0])
        rms = res.rms.copy()
        rms[0] = rms_per_condition(model, theta[:1], data.subset([0]))[0]
        return dataclasses.replace(res, theta=theta, rms=rms, nrmse=res.nrmse * rms / res.rms)

    monkeypatch.setattr(chunks, "fit_chunk", corrupted)
    swarm = mrjax.Swarm(max_generations=40)
    res = mrjax.fit("kwok", batch, key=0, swarm=swarm)
    assert res.starts_rms.shape == (6, 2)
    assert res.starts_rms[0, 0] > (1 + SPREAD_MARGIN) * res.starts_rms[0, 1]
    np.testing.assert_allclose(res.rms, res.starts_rms.min(axis=1))
    assert np.all(np.isfinite(res.stderr))  # std-errors at the kept optimum
    assert np.all(np.abs(res.theta[0] - truth[0]) <= 4 * res.stderr[0])
    text = res.table()
    assert "warning:" in text and repr(batch.labels[0]) in text
    doc = json.loads(res.to_json())
    w = [x for x in doc["warnings"] if x["kind"] == "local_optimum"]
    assert w and w[0]["conditions"] == [batch.labels[0]]
    assert len(doc["conditions"][0]["starts_rms_N"]) == 2
    # without the retry: one start, no evidence, no warning
    off = mrjax.fit("kwok", batch, key=0, swarm=swarm, polish=Polish(retry=False))
    assert off.starts_rms is None and "warning" not in off.table()
    assert off.rms[0] > 3 * res.rms[0]


def test_auto_laws_recover_the_paper_forms():
    """The grid's true parameters (eq 24-29) with 1 % scatter: the lowest BIC picks the
    paper's forms (c, k, delta, f0 linear, alpha quadratic, beta constant), each in most of
    eight scatter draws (an information criterion picks a needless term now and then: k and
    delta quadratic in 2 and 1 of these 8)."""
    grid = paper_grid()
    cur = np.asarray(grid.current, float)
    model = mrjax.models.get("kwok")
    want = {n: f"poly{len(PAPER_COEFFICIENTS[n]) - 1}" for n in model.param_names}
    hits = dict.fromkeys(want, 0)
    for seed in range(8):
        rng = np.random.default_rng(seed)
        theta = paper_truth(grid) * (1 + 0.01 * rng.standard_normal((grid.n_conditions, 6)))
        forms = choose_forms(model, theta, cur, None, "auto", 6)
        for p, n in enumerate(model.param_names):
            hits[n] += forms.form(p) == want[n]
    assert all(h >= 5 for h in hits.values()), hits
    assert set(forms.criteria) == set(model.param_names)
    # a degree given by the user is kept
    forms = choose_forms(model, theta, cur, {"beta": 1}, "auto", 6)
    assert forms.form(model.param_names.index("beta")) == "poly1"
    with pytest.raises(mrjax.InputError, match="auto"):
        choose_forms(model, theta, cur, None, "best", 6)
    with pytest.raises(mrjax.InputError, match="per-test"):
        choose_forms(model, None, None, None, "auto", 6)


def test_saturating_law_recovered_jointly():
    """Tests simulated on a tanh model whose alpha saturates, a + b (1 - exp(-i/s)), at five
    currents: `laws="auto"` picks the saturating law with its scale, and the joint fit gets
    its coefficients back; the law survives fit.json."""
    model = mrjax.models.get("kwok")
    truth = dict(zip(model.param_names, (800.0, 1500.0, 300.0, 60.0, 0.6, 4.0)))
    s_true = 0.4  # one of the scales searched: 0.2 x the 0-2 A range
    laws = {n: Law("poly", (v,)) for n, v in truth.items()}
    laws["alpha"] = Law("sat", (100.0, 900.0), s_true)
    gm_true = GeneralizedModel(model, laws, "given", float("nan"), (0.0, 2.0))
    conds = []
    for i in (0.0, 0.25, 0.5, 1.0, 2.0):
        th = np.asarray(gm_true.params_at(i))
        for f, a in ((1.0, 0.01), (2.5, 0.004)):
            c = mrjax.data.simulate(model, th, frequency=f, amplitude=a, current=i,
                                    cycles=1.5, noise=2.0, seed=int(40 * i + f))
            conds.append(c)
    batch = mrjax.data.make_batch(conds)
    res = mrjax.fit(model, batch, key=0, swarm=mrjax.Swarm(max_generations=40))
    gm = generalize(res, batch, method="joint", key=0,
                    swarm=mrjax.Swarm(max_generations=20))  # auto: default
    assert gm.laws["alpha"].kind == "sat" and gm.laws["alpha"].scale == pytest.approx(s_true)
    np.testing.assert_allclose(gm.laws["alpha"].coefficients, (100.0, 900.0), rtol=0.03)
    assert gm.laws["alpha"].form == "sat(0.4)" and gm.report.law_choice.startswith("auto")
    assert "law forms chosen by the data" in gm.summary()
    doc = json.loads(gm.to_json())
    assert doc["law_forms"]["alpha"] == "sat(0.4)" and doc["law_choice"].startswith("auto")
    back = GeneralizedModel.from_dict(doc)
    u = np.linspace(0, 2, 7)
    np.testing.assert_allclose(np.asarray(back.params_at(u)), np.asarray(gm.params_at(u)))
    fixed = generalize(res, batch, laws="fixed")  # the model's default degrees
    assert fixed.laws["alpha"].form == "poly2" and fixed.report.law_choice == "given"
    assert json.loads(fixed.to_json())["law_choice"] == "given"
    with pytest.raises(mrjax.InputError, match="scale"):
        Law("sat", (1.0, 2.0))
    with pytest.raises(mrjax.InputError, match="2 coefficients"):
        Law("sat", (1.0, 2.0, 3.0), 0.5)
