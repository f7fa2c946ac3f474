"""Tests of `mrjax.refine`: the batched, bounded Levenberg-Marquardt polish and its uncertainty.

The polish of per-test parameters from given starts is the engine's polish stage alone
(`mrjax.engine.solve` without a swarm on `mrjax.fitting.tests_problem`); the paging of the one
bounded solve (`mrjax.refine.solve_box`) is tested on it directly.

Compiled shapes are shared: every tanh test uses the 36-condition paper grid (one compile of the
polish), the Bouc-Wen tests share one small batch.
"""

import numpy as np
import pytest
from helpers import assert_same_polish

import mrjax
from mrjax import data, engine, models, objective
from mrjax.fitting import tests_problem as make_problem
from mrjax.models import resolve_model
from mrjax.objective import ConditionResidual
from mrjax.refine import Status, Uncertainty, solve_box, uncertainty

KWOK = models.get("kwok")
BINGHAM = models.get("bingham")
BOUC_WEN = models.get("bouc_wen", substeps=2)
BW_TRUTH = np.array([1000.0, 3000.0, 500.0, -100.0, 300.0, 200.0, 100.0, 1.0])  # n = 1


def polish(model, start, batch, *, bounds=None, transient=None, max_steps=100):
    """The engine's polish stage alone from `start` (C, P) on the per-test problem of `model`
    (its box `bounds`, default the model's; its `transient` left out of the score): one stage
    on the full records to `tol`, never worse than the start. The start is clipped into the
    box, as the polish clips it, so that its RMS is the one the polish must not exceed."""
    problem = make_problem(model, batch, bounds=bounds, transient=transient)
    start = np.clip(np.asarray(start, float), problem.lower, problem.upper)
    return engine.solve(problem, swarm=None, polish=mrjax.Polish(max_steps=max_steps),
                        start=start)


def _perturbed(truth, seed, lo=0.05, hi=0.10):
    """Truth times 1 +- U(lo, hi), with random signs (fixed seed)."""
    rng = np.random.default_rng(seed)
    size = rng.uniform(lo, hi, truth.shape) * rng.choice([-1.0, 1.0], truth.shape)
    return truth * (1.0 + size)


@pytest.fixture(scope="module")
def grid():
    batch = data.paper_grid(noise=20.0)
    return batch, data.paper_truth(batch)


@pytest.fixture(scope="module")
def grid_fit(grid):
    batch, truth = grid
    return polish(KWOK, _perturbed(truth, 0), batch)


@pytest.fixture(scope="module")
def bw_batch():
    motions = [(1.0, 0.008), (2.0, 0.006), (2.0, 0.008)]
    return data.paper_grid(BOUC_WEN, BW_TRUTH, currents=(0.0,), motions=motions,
                           sample_rate=500.0, cycles=1.5, noise=10.0, seed=3)


# ------------------------------------------------------------------------------ known answers
def test_known_answer_noisy_grid(grid, grid_fit):
    batch, truth = grid
    res = grid_fit
    assert isinstance(res, engine.Outcome) and res.start.source == "given"
    rms_true = objective.rms_per_condition(KWOK, truth, batch)
    ratio = np.asarray(res.rms) / rms_true
    err = np.abs(np.asarray(res.z) / truth - 1.0)
    print(f"\nrms/rms_true: max {ratio.max():.5f}, median {np.median(ratio):.5f}; "
          f"param rel. error median {np.median(err):.4f}, per param {np.median(err, 0).round(4)}")
    assert np.all(ratio <= 1.001)
    assert np.median(err) < 0.05
    assert np.all(np.asarray(res.rms) <= np.asarray(res.start.rms))
    assert np.all(np.asarray(res.rms) < np.asarray(res.start.rms))  # every condition improved
    assert set(res.status) <= {Status.SUCCESSFUL, Status.MAX_STEPS_REACHED}
    assert [st.name for st in res.stages] == ["full"] and not res.kept_start.any()
    # the reported rms is the objective's rms of the returned parameters
    np.testing.assert_allclose(res.rms, objective.rms_per_condition(KWOK, res.z, batch),
                               rtol=1e-12)
    assert "1Hz_4mm_0A" in res.uncertainty.summary(batch.labels)


def test_noise_free_recovers_truth(grid):
    batch = data.paper_grid(noise=0.0)  # same shapes as the noisy grid: no recompilation
    truth = data.paper_truth(batch)
    res = polish(KWOK, _perturbed(truth, 1), batch)
    err = np.abs(np.asarray(res.z) / truth - 1.0)
    print(f"\nnoise-free: max rel. parameter error {err.max():.2e}, max rms {res.rms.max():.2e} N")
    assert err.max() < 1e-6
    assert np.all(np.asarray(res.rms) < 1e-6)


def test_confidence_intervals_cover_truth(grid, grid_fit):
    batch, truth = grid
    unc = grid_fit.uncertainty
    ci = np.asarray(unc.ci95)
    inside = (ci[..., 0] <= truth) & (truth <= ci[..., 1])
    print(f"\n95 % CI coverage over 36 x 6 parameters: {inside.mean():.3f} "
          f"(per parameter {inside.mean(axis=0).round(3)})")
    assert 0.80 <= inside.mean() <= 1.0
    assert np.all(np.asarray(unc.identifiable))
    assert np.all(np.isfinite(unc.stderr)) and np.all(np.asarray(unc.stderr) > 0)
    np.testing.assert_array_equal(np.asarray(unc.dof), np.asarray(batch.n_samples) - 6)
    corr = np.asarray(unc.corr)
    np.testing.assert_allclose(np.diagonal(corr, axis1=1, axis2=2), 1.0, rtol=1e-12)
    np.testing.assert_allclose(corr, np.swapaxes(corr, 1, 2), atol=1e-12)
    # a wider level gives a wider interval, the same one at 0.95
    np.testing.assert_allclose(unc.interval(0.95), ci, rtol=1e-12)
    assert np.all(np.diff(unc.interval(0.99), axis=-1) > np.diff(ci, axis=-1))


# ------------------------------------------------------------------------------ never worse
def test_never_worse_from_optimum(grid, grid_fit):
    batch, _ = grid
    res = polish(KWOK, grid_fit.z, batch)
    assert np.all(np.asarray(res.rms) <= np.asarray(res.start.rms))
    np.testing.assert_allclose(res.rms, grid_fit.rms, rtol=1e-10)
    np.testing.assert_allclose(res.z, grid_fit.z, rtol=1e-5, atol=1e-8)
    # where the start was kept (the solve was worse), it is returned as it was
    kept = np.array([s == Status.KEPT_START for s in res.status])
    assert np.all(kept[res.kept_start])
    np.testing.assert_array_equal(res.z[kept], grid_fit.z[kept])


def test_mask_restricts_scored_samples(grid, grid_fit):
    """A fit mask without the first 0.1 s (the transient): the rms and the degrees of freedom
    use only it."""
    batch, _ = grid
    mask = mrjax.data.fit_mask(batch, transient=0.1)
    res = polish(KWOK, grid_fit.z, batch, transient=0.1)  # same shapes: no recompilation
    np.testing.assert_allclose(res.rms, objective.rms_per_condition(KWOK, res.z, batch, mask),
                               rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(res.uncertainty.dof),
                                  np.asarray(mask).sum(axis=1) - 6)
    assert np.all(np.asarray(res.uncertainty.dof) == np.asarray(batch.n_samples) - 106)


# ------------------------------------------------------------------------------ bounds
def test_results_stay_inside_bounds(grid):
    batch, truth = grid
    lo, hi = KWOK.bounds
    hi = hi.copy()
    lo = lo.copy()
    hi[0] = 1500.0  # c: truth is 1232 ... 5090 N s/m
    lo[4] = 0.9  # delta: truth 0.58 ... 1.18
    res = polish(KWOK, truth, batch, bounds=(lo, hi))  # start clipped into the box
    th = np.asarray(res.z)
    assert np.all(th >= lo) and np.all(th <= hi)
    assert np.all(np.asarray(res.rms) <= np.asarray(res.start.rms))
    # active bounds are reached exactly (the sine map alone only approaches them)
    tol = 1e-6 * (hi - lo)
    at = (th - lo <= tol) | (hi - th <= tol)
    assert np.all(th[truth[:, 0] > 1700.0, 0] == 1500.0) and np.all(at[truth[:, 0] > 1700.0, 0])
    assert np.all(th[truth[:, 4] < 0.8, 4] == 0.9) and np.all(at[truth[:, 4] < 0.8, 4])
    assert not np.any(at[:, [1, 2, 3, 5]])
    print(f"\nactive bounds: statuses {sorted(set(res.status))}, steps max {res.steps.max()}")


def test_input_errors(grid):
    batch, truth = grid
    lo, hi = KWOK.bounds
    with pytest.raises(mrjax.InputError, match=r"inverted: lower \S+ > upper"):
        polish(KWOK, truth, batch, bounds=(hi, lo))
    with pytest.raises(mrjax.InputError, match="unknown"):
        polish(KWOK, truth, batch, bounds=(None, {"c": 1e4, "nope": 1.0}))
    with pytest.raises(mrjax.InputError, match="no free"):
        polish(KWOK, truth, batch, bounds=(truth[0], truth[0]))
    with pytest.raises(mrjax.InputError, match="max_steps"):
        mrjax.Polish(max_steps=0)


# ------------------------------------------------------------------------------ std-errors
def _ols(batch, fixed_f0=None):
    """Closed-form Bingham least squares per condition (numpy): estimates and std-errors."""
    est, se = [], []
    for i in range(batch.n_conditions):
        m = np.asarray(batch.mask[i])
        v = np.asarray(batch.xdot[i])[m]
        y = np.asarray(batch.force[i])[m]
        A = np.stack([np.sign(v), v, np.ones_like(v)], axis=1)
        if fixed_f0 is not None:
            A, y = A[:, :2], y - fixed_f0
        w = np.linalg.solve(A.T @ A, A.T @ y)
        r = y - A @ w
        s2 = r @ r / (len(y) - A.shape[1])
        est.append(w)
        se.append(np.sqrt(np.diag(s2 * np.linalg.inv(A.T @ A))))
    return np.array(est), np.array(se)


def test_bingham_stderr_matches_ordinary_least_squares():
    """Bingham is linear in its parameters: J is the OLS design matrix, exactly."""
    batch = data.paper_grid(BINGHAM, [500.0, 3000.0, -100.0], currents=(0.0,), noise=15.0)
    est, se = _ols(batch)
    unc = uncertainty(BINGHAM, est, batch)
    assert isinstance(unc, Uncertainty)
    np.testing.assert_allclose(unc.stderr, se, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(unc.dof), batch.n_samples - 3)
    # f0 known: two free parameters, OLS on the other two, f0 reported with zero error
    est2, se2 = _ols(batch, fixed_f0=-100.0)
    theta2 = np.column_stack([est2, np.full(len(est2), -100.0)])
    unc2 = uncertainty(BINGHAM, theta2, batch, free=["fc", "c0"])
    np.testing.assert_allclose(np.asarray(unc2.stderr)[:, :2], se2, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(unc2.stderr)[:, 2], 0.0)
    np.testing.assert_array_equal(np.asarray(unc2.dof), batch.n_samples - 2)
    assert unc2.free == (True, True, False) and "(fixed)" in unc2.summary()


# ------------------------------------------------------------------------------ Bouc-Wen
def test_bouc_wen_scale_redundancy_not_identifiable(bw_batch):
    """z -> s z, alpha -> alpha/s, delta -> s delta, beta, gamma -> s^(1-n) beta, gamma leaves
    the force unchanged: with n = 1 (alpha, delta) are exactly redundant, with n free at
    n != 1 beta and gamma join them."""
    theta = np.broadcast_to(BW_TRUTH, (bw_batch.n_conditions, 8))
    unc = uncertainty(BOUC_WEN, theta, bw_batch)
    names = BOUC_WEN.param_names
    ident = np.asarray(unc.identifiable)
    print("\n" + unc.summary(bw_batch.labels))
    for j, name in enumerate(names):
        assert np.all(ident[:, j] == (name not in ("alpha", "delta"))), name
    assert np.all(np.isnan(np.asarray(unc.stderr)[:, [2, 4]]))
    assert np.all(np.isfinite(np.asarray(unc.stderr)[:, [0, 1, 3, 5, 6, 7]]))
    # at n = 1.7 (same shapes: no recompilation) the redundancy also moves beta and gamma
    th2 = theta.copy()
    th2[:, 7] = 1.7
    ident2 = np.asarray(uncertainty(BOUC_WEN, th2, bw_batch).identifiable)
    for j, name in enumerate(names):
        assert np.all(ident2[:, j] == (name not in ("alpha", "delta", "beta", "gamma"))), name


def test_nan_start_does_not_affect_other_conditions(bw_batch):
    """A start whose RK4 integration overflows (stiff beyond stability) is kept, and the other
    conditions' results are identical to a run without it. n is held by equal bounds."""
    C = bw_batch.n_conditions
    lo, hi = BOUC_WEN.bounds
    lo, hi = lo.copy(), hi.copy()
    hi[4:6] = 1e6  # delta, beta: room for a start that blows up the integrator
    lo[7] = hi[7] = 1.0  # n held
    good = _perturbed(np.broadcast_to(BW_TRUTH, (C, 8)), 5)
    good[:, 7] = 1.0
    bad = good.copy()
    bad[1, 4:7] = 1e5, 1e5, 0.0  # RK4 at |lambda| h ~ 10 overshoots into z' = u (delta + beta|z|)
    assert not np.isfinite(objective.rms_per_condition(BOUC_WEN, bad, bw_batch)[1])
    kw = dict(bounds=(lo, hi), max_steps=60)
    ref = polish(BOUC_WEN, good, bw_batch, **kw)
    res = polish(BOUC_WEN, bad, bw_batch, **kw)
    assert res.status[1] == Status.KEPT_START
    assert not res.rms[1] < res.start.rms[1] and np.isinf(float(res.start.rms[1]))
    np.testing.assert_array_equal(np.asarray(res.z)[1], bad[1])
    others = np.arange(C) != 1
    np.testing.assert_allclose(np.asarray(res.z)[others], np.asarray(ref.z)[others],
                               rtol=1e-12)
    np.testing.assert_allclose(np.asarray(res.rms)[others], np.asarray(ref.rms)[others],
                               rtol=1e-12)
    assert res.status[0] == ref.status[0] and res.status[2] == ref.status[2]
    # the good runs fit to the noise level, keep n fixed and flag the (alpha, delta) scale
    rms_true = objective.rms_per_condition(BOUC_WEN, np.broadcast_to(BW_TRUTH, (C, 8)),
                                           bw_batch)
    assert np.all(np.asarray(ref.rms) <= 1.001 * rms_true)
    np.testing.assert_array_equal(np.asarray(ref.z)[:, 7], 1.0)
    ident = np.asarray(ref.uncertainty.identifiable)
    assert np.all(~ident[:, 2] & ~ident[:, 4])


@pytest.mark.parametrize("page", [1, 2])
def test_pages_give_the_batch_result(bw_batch, page):
    """`page_size`: conditions solved a page at a time (each page stops with its own slowest
    condition) give the one-batch result up to rounding, padding included (3 conditions,
    pages of 2). The per-test polish's solve: `solve_box` on each condition's residuals, n
    held."""
    C = bw_batch.n_conditions
    start = _perturbed(np.broadcast_to(BW_TRUTH, (C, 8)), 7)
    lo, hi = BOUC_WEN.bounds
    m = np.asarray(bw_batch.mask)
    args = (bw_batch.x, bw_batch.xdot, bw_batch.dt, bw_batch.force, m)
    kw = dict(free=[j for j, n in enumerate(BOUC_WEN.param_names) if n != "n"], max_steps=60,
              jacobian="forward", snap=True)
    residual = ConditionResidual(BOUC_WEN)
    ref = solve_box(residual, start, lo, hi, args, m.sum(axis=1), **kw)
    res = solve_box(residual, start, lo, hi, args, m.sum(axis=1), page_size=page, **kw)
    assert len(set(np.asarray(ref.steps).tolist())) > 1  # the solves do differ in length
    # Equal up to rounding: a narrower batch vectorises differently, and the stall test then
    # stops some solves steps apart (on an AMD EPYC [6, 6, 12] vs [6, 6, 9]; the step counts are
    # therefore not compared), at an RMS equal to the stall test's tolerance. A page polishing
    # another condition's data, or padding leaking in, moves them by percents (the starts are
    # 5-10 % off).
    assert_same_polish(res.rms, ref.rms, res.z, ref.z)
    assert np.all(np.asarray(res.rms) < np.asarray(res.rms_start))  # it did polish
    np.testing.assert_array_equal(res.status, ref.status)
    np.testing.assert_array_equal(res.kept, ref.kept)
    with pytest.raises(mrjax.InputError, match="page_size"):
        solve_box(residual, start, lo, hi, args, m.sum(axis=1), page_size=0, **kw)


def test_substeps_resolved_on_host(bw_batch):
    auto = models.get("bouc_wen")
    lo, hi = auto.bounds
    rows = np.vstack([lo, hi, BW_TRUTH])
    resolved = resolve_model(auto, rows, bw_batch.xdot, bw_batch.dt, bw_batch.mask)
    expected = auto.resolve_substeps(rows, np.asarray(bw_batch.xdot), np.asarray(bw_batch.dt))
    assert resolved.substeps == expected >= 1
    assert resolve_model(BOUC_WEN, rows, bw_batch.xdot, bw_batch.dt) is BOUC_WEN
    assert resolve_model(KWOK, rows, bw_batch.xdot, bw_batch.dt) is KWOK


def test_lm_scale_moves_a_flat_variable():
    """`lm_solve(scale=)`: a steep amplitude and a time constant whose residuals are 10^6 times
    less sensitive at the start (it enters as exp(-t / (0.01 e^y1)) with y1 = -2, far below
    the truth 1.5). Unscaled, the damped steps barely move it and the stall test stops the solve
    short; scaled by the start's column norms, the known answer is recovered."""
    import jax
    import jax.numpy as jnp

    from mrjax.refine import lm_solve

    t = jnp.linspace(0.0, 1.0, 50)

    def step_response(y):
        return y[0] * (1.0 - jnp.exp(-t / (0.01 * jnp.exp(y[1]))))

    target = step_response(jnp.array([2.0, 1.5]))

    def fn(y, _):
        return step_response(y) - target

    y0 = jnp.array([1.0, -2.0])
    cols = jnp.linalg.norm(jax.jacfwd(fn)(y0, None), axis=0)
    assert cols[1] < 1e-4 * cols[0]
    plain = lm_solve(fn, y0, None, max_steps=500, tol=1e-8)
    scaled = lm_solve(fn, y0, None, max_steps=500, tol=1e-8, scale=cols)
    assert abs(float(plain.value[1]) - 1.5) > 1.0  # stuck near its start
    np.testing.assert_allclose(np.asarray(scaled.value), [2.0, 1.5], rtol=1e-4)
    assert int(scaled.status) == 0 and int(scaled.steps) < 100
