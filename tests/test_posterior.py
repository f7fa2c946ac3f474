"""The posterior (issue 25): the NUTS core on known answers, the per-test kind on short
simulated records (tanh and Dahl), NaN-safety, seeds, bad options, files and the command
line. The calibration study and the speed figures are in `benchmarks/posterior.py`.
"""

import dataclasses
import json
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import check_pngs, one_error_line, short_batch
from helpers import run_cli as run

import mrjax
from mrjax import InputError
from mrjax.bayes import (
    NUTS,
    ChEES,
    Likelihood,
    LogNormal,
    Normal,
    Sampler,
    Uniform,
    from_box,
    log_jacobian,
    sample,
    to_box,
)

#: The core's known answers are those of one run's draws: no continuation rounds (they are
#: taken by the per-test kind below, at the defaults).
SHORT = Sampler(draws=300, chains=2, warmup=300, continuations=0)
#: One compiled program serves most core tests: same residual, shapes and sampler (priors and
#: boxes are data).
BOX = dict(lower=[-10.0, -10.0], upper=[10.0, 10.0], names=("a", "b"))


def box_sample(residual, theta0, data, *, sampler=SHORT, noise="iid", prior=None, key=0,
               **fields):
    """`mrjax.bayes.sample` on the :class:`Likelihood` of `residual` in the box `BOX` (its
    fields overridden by `fields`)."""
    return sample(Likelihood(residual, theta0, data, **dict(BOX, **fields)), sampler=sampler,
                  noise=noise, prior=prior, key=key)


# --------------------------------------------------------------------------------------------
# The core on a problem with a closed-form posterior


class Line(eqx.Module):  # a module: hashable, so a second call reuses the compiled program
    """Residuals of a straight line a + b t against y on one record; NaN where a > `nan_above`
    (data, so that the NaN test reuses the same compiled program)."""

    nan_above: jax.Array = eqx.field(default_factory=lambda: jnp.asarray(jnp.inf))

    def __call__(self, theta, unit):
        t, y, m = unit
        r = (theta[0] + theta[1] * t) - y
        return ((jnp.where(theta[0] > self.nan_above, jnp.nan, r)[None], m[None]),)


def line_data(U=2, T=200, sigma=0.5, rho=0.0, seed=0):
    """U records y = a + b t + noise (AR(1) with `rho`), truth (U, 2)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, T)
    truth = np.column_stack([rng.uniform(-1, 1, U), rng.uniform(1, 3, U)])
    e = np.zeros((U, T))
    e[:, 0] = rng.standard_normal(U) * sigma
    for k in range(1, T):
        e[:, k] = rho * e[:, k - 1] + np.sqrt(1 - rho**2) * sigma * rng.standard_normal(U)
    y = truth[:, :1] + truth[:, 1:] * t + e
    return (np.broadcast_to(t, (U, T)).copy(), y, np.ones((U, T), bool)), truth


def ols(data):
    """Least-squares estimates (U, 2), their std-errors (U, 2) and covariances (U, 2, 2)."""
    t, y, _ = data
    est, se, cov = [], [], []
    for tt, yy in zip(t, y):
        X = np.column_stack([np.ones_like(tt), tt])
        b, rss, *_ = np.linalg.lstsq(X, yy, rcond=None)
        c = rss[0] / (len(yy) - 2) * np.linalg.inv(X.T @ X)
        est.append(b), se.append(np.sqrt(np.diag(c))), cov.append(c)
    return np.array(est), np.array(se), np.array(cov)


def cut_line(data, n):
    """`Likelihood.trim` of :func:`line_data`'s `(t, y, mask)`."""
    return tuple(a[:, :n] for a in data)


def test_units_of_different_lengths_are_drawn_cut_to_their_group():
    """Records padded to the longest (a campaign's) are drawn in groups of similar length,
    each cut to its longest scored sample: the same draws as uncut (to rounding: padding
    adds masked zeros only), the groups those of least padded work."""
    from mrjax.bayes import length_groups

    assert [g.tolist() for g in length_groups(np.array([200, 60, 200]))] == [[0, 2], [1]]
    assert [g.tolist() for g in length_groups(np.array([100, 96, 99]))] == [[0, 1, 2]]
    assert [g.tolist() for g in length_groups(np.array([7]))] == [[0]]
    (t, y, m), _ = line_data(U=3)
    m = m.copy()
    m[1, 60:] = False  # record 1: 60 samples, padded with zeros
    y = np.where(m, y, 0.0)
    data = (t, y, m)
    est = ols((t[:, :60], y[:, :60], m[:, :60]))[0]
    s = Sampler(draws=40, chains=2, warmup=40, continuations=0)
    cut = box_sample(Line(), est, data, sampler=s, trim=cut_line)
    whole = box_sample(Line(), est, data, sampler=s)
    np.testing.assert_allclose(cut.theta, whole.theta, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(cut.sigma, whole.sigma, rtol=1e-7)


def test_pages_of_similar_trajectory_length_spread_over_devices():
    """The draws' pages hold units of similar adapted trajectory length (a vmapped page
    advances at its longest), of the one size that leaves the busiest device the least
    predicted work; calls go to devices longest first, each to the least loaded."""
    from mrjax.bayes._pages import assign, page_cost, shared_pages, sorted_pages

    where, work = assign([5.0, 4.0, 3.0, 3.0, 3.0], 2)
    assert where.tolist() == [0, 1, 1, 0, 1] and work == 10.0
    assert assign([2.0, 1.0], 1) == (pytest.approx(np.zeros(2)), 3.0)
    s = Sampler(chains=2, vectorize="all", kernel=ChEES())
    n = np.array([5.0, 30.0, 6.0, 29.0])
    # pages of 2 sorted units (6 x 14 + 30 x 14) cost less than one of 4 (30 x 22) or four
    # of 1 ((5 + 6 + 29 + 30) x 10), with the fixed cost of a step of 6 chains
    assert page_cost(n, s) == 30.0 * 14.0
    cut, work = sorted_pages(n, s, 4, 1)
    assert [sorted(p.tolist()) for p in cut] == [[0, 2], [1, 3]] and work == 6 * 10 + 30 * 10
    # mapped units (not vmapped) never wait: one page of all of them
    m = dataclasses.replace(s, vectorize="chains")
    assert [sorted(p.tolist()) for p in sorted_pages(n, m, 4, 1)[0]] == [[0, 1, 2, 3]]
    # one long unit left on 2 devices: its 8 chains in 2 shares, one a device ((6 + 4) x 30
    # each against (6 + 8) x 30 on one); many similar units: whole
    e = Sampler(chains=8, vectorize="all", kernel=ChEES())
    shares, cut = shared_pages(np.array([30.0]), e, 1, 2)
    assert shares == 2 and [p.tolist() for p in cut] == [[0], [1]]
    assert shared_pages(np.full(6, 10.0), e, 3, 2)[0] == 1
    assert shared_pages(np.array([30.0]), e, 1, 1)[0] == 1


def test_chees_draws_do_not_depend_on_the_pages(monkeypatch):
    """A unit's ChEES draws are its own whatever page it runs in: the same (to rounding) with
    the 5 units in one page, in pages of 2 (the last padded), and with each unit's chains in
    2 shares drawn as units of their own (as on 2 devices)."""
    import mrjax.bayes._calls as calls_module
    from mrjax.bayes._pages import sorted_pages

    data, _ = line_data(U=5)
    est = ols(data)[0]
    run = lambda p: box_sample(Line(), est, data, sampler=Sampler(
        draws=30, chains=4, warmup=30, continuations=0, vectorize="all",
        kernel=ChEES(page=p)))
    runs = [run(5), run(2)]
    halves = lambda n, s, most, d: (2, sorted_pages(np.repeat(n, 2), s, 2 * most, d, 2)[0])
    monkeypatch.setattr(calls_module, "shared_pages", halves)
    runs.append(run(5))
    assert {"warmup", "draws", "sample", "mode"} <= set(runs[0].timings)
    for other in runs[1:]:
        np.testing.assert_allclose(other.theta, runs[0].theta, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(other.step_size, runs[0].step_size, rtol=1e-7)
        np.testing.assert_array_equal(other.warmup_steps, runs[0].warmup_steps)


def test_per_test_likelihood_cuts_records_to_their_first_samples():
    """The per-test kind's `Likelihood.trim` (a dynamic model, one time step per sample): the
    residuals of records cut to their first n samples are the first n of the uncut ones."""
    from mrjax.fitting import tests_problem

    batch, truth = short_batch("dahl")
    lk = tests_problem("dahl", batch).likelihood(truth, False)
    n = int(np.asarray(batch.mask).sum(axis=1).min())
    cut = lk.trim(lk.data, n)
    assert all(np.shape(a)[-1] in (n,) for a in cut if np.ndim(a) == 2)
    for i in range(2):
        unit = lambda d: jax.tree.map(lambda a: a[i], d)  # noqa: B023 - used at once
        (r, m), = lk.residual(jnp.asarray(truth[i]), unit(lk.data))
        (rc, mc), = lk.residual(jnp.asarray(truth[i]), unit(cut))
        np.testing.assert_allclose(rc, r[:, :n], rtol=1e-12, atol=1e-9)
        np.testing.assert_array_equal(mc, m[:, :n])


def test_core_matches_least_squares_posterior():
    """Flat priors, iid noise: the posterior of a line is centred on least squares with its
    std-errors (large n: the Student-t is nearly normal); the noise level is the residuals'
    RMS."""
    data, _ = line_data()
    est, se, cov = ols(data)
    post = box_sample(Line(), est, data)
    th = post.theta.reshape(2, -1, 2)
    # Monte Carlo error of a mean: sd / sqrt(ESS), ESS >= 150 -> < 0.1 sd
    np.testing.assert_array_less(np.abs(th.mean(axis=1) - est) / se, 0.3)
    np.testing.assert_allclose(th.std(axis=1) / se, 1.0, atol=0.2)
    sig = post.draws("noise_sigma")[..., 0]
    resid = [np.sqrt(np.mean((y - e[0] - e[1] * t) ** 2)) for t, y, e in zip(data[0], data[1],
                                                                              est)]
    np.testing.assert_allclose(np.median(sig, axis=1), resid, rtol=0.05)
    d = post.diagnostics()
    assert d["r_hat_max"] < 1.02 and d["divergences"] == 0
    # sample alone: reverse mode
    S = post.sampler
    assert S.gradient == "reverse"
    # the warmup's cost is kept: leapfrog steps of each chain's warmup, of 2^r x the warmup
    # steps in a unit continued r rounds
    assert post.warmup_steps.shape == (2, S.chains) and post.rounds.shape == (2,)
    length = S.warmup * 2 ** post.rounds
    np.testing.assert_array_equal(post.warmup_length, length)
    assert np.all(post.warmup_steps >= length[:, None])
    assert np.all(post.warmup_steps <= length[:, None] * (2**S.max_doublings - 1))
    assert d["leapfrog_per_warmup_step"] == pytest.approx(
        post.warmup_steps.sum() / (length.sum() * S.chains), rel=1e-12)


class SkewedLine(eqx.Module):
    """The line's residuals with an approximate derivative: the slope's column scaled by
    `skew` (as the L-stable scheme's implicit tangent approximates the exact one)."""

    skew: float = eqx.field(static=True)

    def __call__(self, theta, unit):
        t, y, m = unit

        @jax.custom_jvp
        def r(th):
            return (th[0] + th[1] * t) - y

        @r.defjvp
        def r_jvp(primals, tangents):
            (th,), (dth,) = primals, tangents
            return r(th), dth[0] + self.skew * dth[1] * t

        return ((r(theta)[None], m[None]),)


@pytest.mark.parametrize("skew, switched", [(1.0, False), (1.0 + 1e-7, False), (-1.0, True)])
def test_an_approximate_gradient_is_checked_at_the_start(skew, switched):
    """An approximate derivative (`residual`) is kept where its whitened gradient is within
    GRADIENT_TOL of the exact one (`exact`), else the exact one is used: the posterior is least
    squares in short trees either way (with the slope's derivative of the wrong sign, NUTS
    alone would shrink its step towards 0 and run every tree to its cap)."""
    from mrjax.bayes._start import GRADIENT_TOL

    data, _ = line_data()
    est, se, _ = ols(data)
    post = box_sample(SkewedLine(skew), est, data, exact=Line())
    assert (post.gradient_error > GRADIENT_TOL) == switched, post.gradient_error
    if skew == 1.0:  # exact: equal to the central differences to their rounding
        assert post.gradient_error < 1e-6
    th = post.theta.reshape(2, -1, 2)
    np.testing.assert_array_less(np.abs(th.mean(axis=1) - est) / se, 0.3)
    np.testing.assert_allclose(th.std(axis=1) / se, 1.0, atol=0.2)
    d = post.diagnostics()
    assert d["divergences"] == 0 and d["leapfrog_per_draw"] < 10, d


def test_exact_tangent_of_a_resolved_model():
    """The L-stable scheme's implicit tangent has an exact counterpart with the same forces and
    finite-difference derivatives; RK4 and static models have none (already exact)."""
    mbw = mrjax.models.get("modified_bouc_wen")
    implicit = mbw.with_substeps(1, "sdirk", "implicit")
    exact = mrjax.models.exact_tangent(implicit)
    assert (exact.scheme, exact.tangent, exact.substeps) == ("sdirk", "exact", 1)
    assert mrjax.models.exact_tangent(mbw.with_substeps(2, "rk4")) is None
    assert mrjax.models.exact_tangent(mrjax.models.get("kwok")) is None
    t = np.linspace(0.0, 1.0, 201)
    x, v = 0.01 * np.sin(2 * np.pi * t), 0.02 * np.pi * np.cos(2 * np.pi * t)
    th = jnp.asarray(0.5 * (np.asarray(mbw.bounds[0]) + np.asarray(mbw.bounds[1])))
    f = lambda m, p: m.force(p, jnp.asarray(x), jnp.asarray(v), 0.005)
    np.testing.assert_allclose(f(exact, th), f(implicit, th), rtol=1e-12, atol=1e-9)
    j = jax.jacfwd(lambda p: f(exact, p))(th)[:, 4]  # alpha
    h = 1e-6 * max(abs(float(th[4])), 1.0)
    fd = (f(exact, th.at[4].add(h)) - f(exact, th.at[4].add(-h))) / (2 * h)
    np.testing.assert_allclose(j, fd, rtol=1e-5, atol=1e-6 * float(jnp.max(jnp.abs(fd))))


def test_forward_mode_gradient_integrates_once():
    """A dynamic model's log-density gradient (forward mode, `_start.forward_values`) runs one
    integration: the values come from the Jacobian's own pass (a second traced call cost a
    second scan, 35 % of each gradient), and it equals reverse mode's to rounding."""
    import re

    from mrjax.bayes import _start as core  # noqa: SLF001

    mbw = mrjax.models.get("modified_bouc_wen").with_substeps(2, "sdirk", "exact")
    t = np.linspace(0.0, 1.0, 201)
    x, v = 0.01 * np.sin(2 * np.pi * t), 0.02 * np.pi * np.cos(2 * np.pi * t)
    th = jnp.asarray(0.5 * (np.asarray(mbw.bounds[0]) + np.asarray(mbw.bounds[1])))
    unit = (jnp.asarray(x), jnp.asarray(v), 0.005, jnp.zeros_like(jnp.asarray(x)),
            jnp.ones(x.shape, bool))
    residual = mrjax.objective.ConditionResidual(mbw, blocks=True)
    free = np.array([0, 2, 4, 8])
    scale = jnp.asarray(th[free])

    def forward(w):
        (r,) = core.forward_values(residual, th, free, scale * (1.0 + w), unit)
        return jnp.sum(jnp.tanh(r / 100.0))

    def reverse(w):
        ((r, _),) = residual(th.at[free].set(scale * (1.0 + w)), unit)
        return jnp.sum(jnp.tanh(r / 100.0))

    w = jnp.full(free.shape, 0.01)
    hlo = jax.jit(jax.grad(forward)).lower(w).compile().as_text()
    assert len(re.findall(r"\bwhile\(", hlo)) == 1
    g_f, g_r = jax.grad(forward)(w), jax.grad(reverse)(w)
    np.testing.assert_allclose(g_f, g_r, rtol=1e-9, atol=1e-9 * float(jnp.max(jnp.abs(g_r))))


def test_start_is_the_posterior_mode_with_its_hessian():
    """The chains start at the posterior's mode, not at the optimum they are given: a normal
    prior on a, 3 std-errors off the least-squares value, moves the mode to the penalised least
    squares with s^2 = RSS / n (a fixed point, solved here in closed form per s); the start's
    covariance is the inverse of the exact Hessian of (a, b, log s) there."""
    from mrjax.bayes import _priors as priors  # noqa: SLF001 - the start is internal
    from mrjax.bayes import _start as core  # noqa: SLF001

    data, _ = line_data()
    est, se, _ = ols(data)
    mu, tau = est[:, 0] + 3.0 * se[:, 0], se[:, 0]
    names, K = ("a", "b"), 2
    lo, hi = np.full((2, K), -10.0), np.full((2, K), 10.0)
    for i in range(2):
        t, y, _ = (np.asarray(d[i], float) for d in data)
        X, n, P = np.column_stack([np.ones_like(t), t]), t.size, np.diag([1 / tau[i] ** 2, 0])
        beta, s2 = est[i], 1.0
        for _ in range(200):  # the joint mode: beta given s, then s given beta
            beta = np.linalg.solve(X.T @ X / s2 + P, X.T @ y / s2 + P @ [mu[i], 0.0])
            s2 = np.sum((X @ beta - y) ** 2) / n
        r = X @ beta - y
        H = np.zeros((3, 3))  # -Hessian of the log density in (a, b, log s)
        H[:2, :2] = X.T @ X / s2 + P
        H[:2, 2] = H[2, :2] = -2.0 * X.T @ r / s2
        H[2, 2] = 2.0 * n
        prior = {"a": Normal(float(mu[i]), float(tau[i]))}
        kind, a, b, lo_i, hi_i = priors.prior_arrays(priors.check_priors(prior, names), names,
                                                    lo[i:i + 1], hi[i:i + 1])
        unit = jax.tree.map(lambda d: jnp.asarray(d[i:i + 1]), data)
        st = core.start(Line(), est[i:i + 1], lo_i, hi_i, unit, (0, 1), "iid", names)
        z0, imm, soft, lo_f, hi_f = st.z0, st.imm, st.soft, st.lo, st.hi
        assert not st.log.any()  # boxes reaching below 0: linear coordinates
        target = core.Target(residual=Line(), free=(0, 1), rows=(1,), noise="iid")
        units = core.Unit(unit, jnp.asarray(lo_f), jnp.asarray(hi_f), jnp.asarray(soft),
                          jnp.asarray(st.log), jnp.asarray(est[i:i + 1]),
                          tuple(map(jnp.asarray, st.masks)))
        L = np.linalg.cholesky(imm)
        found = jax.device_get(core.find_mode(target, tuple(map(jnp.asarray, (kind, a, b))),
                                          units, jnp.asarray(z0), jnp.asarray(L)))
        assert found[1][0] > found[2][0] + 1.0  # it climbed (from the least-squares start)
        z, L2 = core.laplace(*found, z0, L)
        th = np.asarray(to_box(z[0, :2], lo_f[0], hi_f[0], soft[0]))
        np.testing.assert_allclose(th, beta, rtol=0, atol=1e-4 * se[i].min())
        np.testing.assert_allclose(np.exp(z[0, 2]), np.sqrt(s2), rtol=1e-6)
        # in z = (u, log s) the map is linear inside the box: d theta / du = softness
        g = np.append(soft[0], 1.0)
        cov = np.linalg.inv(H) / np.outer(g, g)
        np.testing.assert_allclose(L2[0] @ L2[0].T, cov, rtol=1e-4, atol=1e-9 * cov.max())


SPREAD = """
import json, sys
import jax
import jax.numpy as jnp
import numpy as np
sys.path.insert(0, sys.argv[1])
from test_posterior import Line, line_data, ols
from mrjax.bayes import ChEES, Likelihood, Sampler, chain_devices, sample
data, _ = line_data()
est, se, _ = ols(data)
s = Sampler(draws=300, chains=4, warmup=300, gradient="forward", continuations=0)
post = sample(Likelihood(Line(), est, data, lower=[-10, -10], upper=[10, 10], names=("a", "b")),
              sampler=s)
th = post.theta.reshape(2, -1, 2)
data3, _ = line_data(U=3)
est3, se3, _ = ols(data3)
c = Sampler(draws=200, chains=4, warmup=150, vectorize="all", continuations=0,
            kernel=ChEES())
lock = sample(Likelihood(Line(), est3, data3, lower=[-10, -10], upper=[10, 10],
                         names=("a", "b")), sampler=c)
th3 = lock.theta.reshape(3, -1, 2)
import threading
from mrjax.bayes._pages import spread
meet = threading.Barrier(2, timeout=60)  # broken unless both devices' calls run at once
def on_device(x):
    meet.wait()
    return next(iter(x.devices())).id
compiles = []
jax.monitoring.register_event_duration_secs_listener(
    lambda e, d, **k: compiles.append(e) if e.endswith("backend_compile_duration") else None)
twice = jax.jit(lambda x: jnp.sin(x) * 2.0)
once = spread([(twice, (np.zeros(3),)), (twice, (np.ones(3),))], [2.0, 1.0])
compiled = len(compiles)
from mrjax.bayes._calls import by_units
cut, meet2 = [], threading.Barrier(2, timeout=60)
def paged(x):  # a page of units, both pages at once
    cut.append(x.shape[0])
    meet2.wait()
    return 2.0 * jnp.sin(x)
mapped = by_units(paged, 5, np.arange(5.0))
print(json.dumps({"devices": chain_devices(s), "cut": cut, "mapped": mapped.tolist(),
                  "together": spread([(on_device, (jnp.zeros(1),))] * 2, [2.0, 1.0]),
                  "compiled": compiled, "once": np.asarray(once).tolist(),
                  "z": (np.abs(th.mean(1) - est) / se).tolist(),
                  "sd": (th.std(1) / se).tolist(), "r_hat": post.diagnostics()["r_hat_max"],
                  "z3": (np.abs(th3.mean(1) - est3) / se3).tolist(),
                  "r_hat3": lock.diagnostics()["r_hat_max"]}))
"""


def test_chains_spread_over_cpu_devices():
    """With 2 CPU devices (JAX_NUM_CPU_DEVICES, as `mrjax fit --posterior` sets it) a unit's 4
    NUTS chains run 2 per device, and ChEES's 3 units in pages on each device (no collective,
    the devices at once; on a CPU all on its first device, each program compiled once), the
    mode search's units one page per device, and the posterior is still the least-squares
    one."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, JAX_NUM_CPU_DEVICES="2", JAX_PLATFORMS="cpu")
    p = subprocess.run([sys.executable, "-c", SPREAD, os.path.dirname(__file__)], env=env,
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["devices"] == 2
    # CPU devices are one memory: both calls on the first, at once, one program compiled
    assert out["together"] == [0, 0]
    assert out["compiled"] == 1
    # the mode search's units: one page per device (padded to one shape), side by side
    assert out["cut"] == [3, 3]
    np.testing.assert_allclose(out["mapped"], 2.0 * np.sin(np.arange(5.0)))
    np.testing.assert_allclose(out["once"], [np.zeros(3), 2.0 * np.sin(np.ones(3))])
    np.testing.assert_array_less(out["z"], 0.3)
    np.testing.assert_allclose(out["sd"], 1.0, atol=0.2)
    assert out["r_hat"] < 1.02
    np.testing.assert_array_less(out["z3"], 0.4)
    assert out["r_hat3"] < 1.03


def test_core_ar1_recovers_rho_and_widens_intervals():
    """AR(1) noise with rho = 0.8: the ar1 likelihood covers rho and gives intervals about
    sqrt((1 + rho) / (1 - rho)) = 3 x the iid ones (for the slope of a line through
    correlated noise)."""
    data, truth = line_data(rho=0.8, seed=1)
    est, se, cov = ols(data)
    iid = box_sample(Line(), est, data, noise="iid")
    ar1 = box_sample(Line(), est, data, noise="ar1")
    lo, hi = ar1.interval("noise_rho", 0.999).T  # 200 samples: rho is known to +-0.1
    assert np.all((lo < 0.8) & (0.8 < hi)), (lo, hi)
    ratio = np.ptp(ar1.interval("b"), axis=1) / np.ptp(iid.interval("b"), axis=1)
    assert np.all((ratio > 2.0) & (ratio < 4.5)), ratio
    assert "noise_rho" in ar1.idata.posterior


def test_priors_pull_and_narrow():
    """A tight normal prior pulls the posterior mean to it; a uniform prior cuts the box."""
    data, _ = line_data()
    est, se, cov = ols(data)
    target = est[0, 0] + 5 * se[0, 0]
    p = box_sample(Line(), est, data, prior={"a": Normal(target, se[0, 0] / 10)})
    assert abs(p.draws("a")[0].mean() - target) < 0.2 * se[0, 0]
    cut = est[0, 1] - se[0, 1]
    q = box_sample(Line(), est, data, prior={"b": Uniform(-10.0, cut)})
    assert q.draws("b")[0].max() <= cut
    assert q.prior == {"b": f"uniform(-10, {cut:g})"}


def test_nan_model_output_is_minus_inf_never_nan():
    """A residual that is NaN on half of the box (a > 0) while the likelihood peaks at
    a = -0.05 (half a std-error inside): no NaN anywhere, every draw in the finite half."""

    data, _ = line_data()
    est, se, cov = ols(data)
    shift = -0.5 * se[:, :1] - est[:, :1]
    data = (data[0], data[1] + shift, data[2])
    est[:, :1] += shift
    post = box_sample(Line(jnp.asarray(0.0)), est, data)
    assert np.all(np.isfinite(post.theta)) and np.all(np.isfinite(post.lp))
    assert post.theta[..., 0].max() <= 0.0
    assert np.all(post.theta[..., 0].min(axis=(1, 2)) < est[:, 0] - se[:, 0])  # explored


def test_same_seed_same_draws():
    data, _ = line_data()
    est, _, cov = ols(data)
    a = box_sample(Line(), est, data, key=3)
    b = box_sample(Line(), est, data, key=3)
    c = box_sample(Line(), est, data, key=4)
    np.testing.assert_array_equal(a.theta, b.theta)
    np.testing.assert_array_equal(a.sigma, b.sigma)
    assert not np.array_equal(a.theta, c.theta)


def test_soft_box_round_trip_and_jacobian():
    """The bounded map: `from_box` inverts `to_box` (in the bulk and near a bound), and
    `log_jacobian` is log(d theta / du) up to its constant log d + log(1 - exp(-W))."""
    lo, hi, d = np.array([0.0, -5.0, 1.0]), np.array([10.0, 5.0, 2.0]), np.array([0.01, 3.0, 10.0])
    for th in (np.array([0.02, 4.2, 1.5]), np.array([9.98, -4.9, 1.01])):
        u = from_box(th, lo, hi, d)
        np.testing.assert_allclose(np.asarray(to_box(u, lo, hi, d)), th, rtol=1e-9)
    for u in (np.array([-20.0, 0.3, 2.0]), np.array([1010.0, 3.0, -4.0])):
        slope = np.diag(np.asarray(jax.jacfwd(lambda v: to_box(v, lo, hi, d))(jnp.asarray(u))))
        const = np.sum(np.log(d) + np.log1p(-np.exp(-(hi - lo) / d)))
        np.testing.assert_allclose(float(log_jacobian(u, lo, hi, d)) + const,
                                   np.sum(np.log(slope)), rtol=1e-9)


def test_soft_box_in_log_coordinates():
    """With `log`, the soft box runs in log theta (a lower bound of 0 taken as LOG_FLOOR x the
    upper one): `from_box` inverts `to_box`, `box_slope` is its derivative, and `log_jacobian`
    is log(d theta / du) up to the constant of the map in log theta."""
    from mrjax.bayes import _priors as priors  # noqa: SLF001 - box_slope is internal

    lo, hi = np.array([0.0, 2000.0, -5.0, 1.0]), np.array([2500.0, 2e5, 5.0, 3.0])
    d, lg = np.array([0.01, 0.005, 0.2, 0.02]), np.array([True, True, False, True])
    lo_t = np.log(np.where(lg, np.maximum(lo, priors.LOG_FLOOR * hi), 1.0))
    lo_t, hi_t = np.where(lg, lo_t, lo), np.where(lg, np.log(np.where(lg, hi, 1.0)), hi)
    const = np.sum(np.log(d) + np.log1p(-np.exp(-(hi_t - lo_t) / d)))
    for th in (np.array([659.0, 39445.0, 0.3, 2.8]), np.array([1e-3, 2020.0, -4.9, 2.95])):
        u = from_box(th, lo, hi, d, lg)
        np.testing.assert_allclose(np.asarray(to_box(u, lo, hi, d, jnp.asarray(lg))), th,
                                   rtol=1e-9)
        jac = np.diag(np.asarray(jax.jacfwd(lambda v: to_box(v, lo, hi, d, jnp.asarray(lg)))(
            jnp.asarray(u))))
        np.testing.assert_allclose(priors.box_slope(u, lo, hi, d, lg), jac, rtol=1e-9)
        np.testing.assert_allclose(float(log_jacobian(u, lo, hi, d, jnp.asarray(lg))) + const,
                                   np.sum(np.log(jac)), rtol=1e-9)
    # a positive unknown many standard deviations above its lower bound runs in log theta
    from mrjax.bayes import _start as core  # noqa: SLF001

    data, _ = line_data(sigma=0.1)
    est, se, _ = ols(data)
    st = core.start(Line(), est, np.array([[-10.0, 0.0]] * 2), np.array([[10.0, 10.0]] * 2),
                    jax.tree.map(jnp.asarray, data), (0, 1), "iid", ("a", "b"))
    assert np.all(est[:, 1] > core.LOG_AWAY * se[:, 1])
    np.testing.assert_array_equal(st.log, [[False, True]] * 2)
    post = box_sample(Line(), est, data, lower=[-10.0, 0.0])
    th = post.theta.reshape(2, -1, 2)
    np.testing.assert_array_less(np.abs(th.mean(axis=1) - est) / se, 0.3)
    np.testing.assert_allclose(th.std(axis=1) / se, 1.0, atol=0.2)


def test_linear_marginal_is_the_gaussian_integral():
    """Known answer: the likelihood with linear unknowns integrated out (AR(1) noise, two
    records with a masked gap, L = 1 and 2) equals the integral of `block_loglik` over them
    (trapezoid on a grid of +-9 conditional sd), and the conditional's mean and covariance
    equal the grid's moments."""
    from mrjax.bayes import block_loglik, linear_marginal

    rng = np.random.default_rng(5)
    R, T = 2, 40
    r = rng.standard_normal((R, T))
    m = np.ones((R, T), bool)
    m[0, 10:14] = m[1, :3] = False
    log_sigma, v = np.log([0.7, 1.3]), np.arctanh(0.6)
    for L in (1, 2):
        A = rng.standard_normal((R, T, L))
        A[..., 0] = 1.0  # an offset
        ll, delta, C, d = jax.device_get(linear_marginal(((r, m),), (A,), log_sigma, v))
        cov = np.diag(d) @ np.linalg.inv(C @ C.T) @ np.diag(d)
        sd = np.sqrt(np.diag(cov))
        axes = [delta[k] + sd[k] * np.linspace(-9, 9, 721 if L == 1 else 181) for k in range(L)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, L)
        f = np.asarray(jax.vmap(lambda dl: block_loglik(r + A @ dl, m, log_sigma, v))(grid))
        f = f.reshape([len(a) for a in axes])
        top = f.max()
        w = np.exp(f - top)
        mass = w
        for a in reversed(axes):
            mass = np.trapezoid(mass, a, axis=-1)
        np.testing.assert_allclose(top + np.log(mass), ll, rtol=0, atol=1e-8)
        pw = (w / w.sum()).reshape(-1)
        mean = pw @ grid
        np.testing.assert_allclose(mean, delta, rtol=0, atol=1e-6 * sd.max())
        np.testing.assert_allclose((grid - mean).T @ ((grid - mean) * pw[:, None]), cov,
                                   rtol=1e-4)


@pytest.mark.parametrize("linear", [("a",), ("a", "b")])
def test_linear_unknowns_integrated_out(linear):
    """Known answer: a line's unknowns are both linear; integrated out of the log-density and
    drawn from their conditional, the posterior is still least squares (iid) and covers rho
    with AR(1) noise like the sampled one. Same seed, same draws."""
    data, _ = line_data()
    est, se, _ = ols(data)
    post = box_sample(Line(), est, data, linear=linear)
    assert post.linear == linear
    th = post.theta.reshape(2, -1, 2)
    np.testing.assert_array_less(np.abs(th.mean(axis=1) - est) / se, 0.3)
    np.testing.assert_allclose(th.std(axis=1) / se, 1.0, atol=0.15)
    assert post.diagnostics()["r_hat_max"] < 1.02
    assert not any(w.kind == mrjax.WarningKind.BEYOND_BOUNDS for w in post.problems())
    theta = post.theta.copy()
    theta[1, 0, 5, 0] = 10.5  # a draw beyond the box of a (upper 10): a warning line
    lines = dataclasses.replace(post, theta=theta).problems()
    assert any("a, integrated out of the log-density, has 1 draw(s) beyond its bounds (most "
               "on '1')" in str(w) for w in lines), lines
    (w,) = [w for w in lines if w.kind == mrjax.WarningKind.BEYOND_BOUNDS]
    assert w.parameters == ("a",) and w.conditions == ("1",)
    np.testing.assert_array_equal(post.theta, box_sample(Line(), est, data,
                                                         linear=linear).theta)
    data, _ = line_data(rho=0.8, seed=1)
    est, se, _ = ols(data)
    ar1 = box_sample(Line(), est, data, noise="ar1", linear=linear)
    full = box_sample(Line(), est, data, noise="ar1")
    assert ar1.linear == linear and full.linear == ()
    lo, hi = ar1.interval("noise_rho", 0.999).T
    assert np.all((lo < 0.8) & (0.8 < hi)), (lo, hi)
    ratio = np.ptp(ar1.interval("b"), axis=1) / np.ptp(full.interval("b"), axis=1)
    np.testing.assert_allclose(ratio, 1.0, atol=0.2)


class BentLine(eqx.Module):
    """A line whose slope enters as b^2: not affine in b."""

    def __call__(self, theta, unit):
        t, y, m = unit
        return (((theta[0] + theta[1] ** 2 * t) - y)[None], m[None]),


def test_linear_unknowns_kept_where_they_may_not_be_integrated_out():
    """An unknown stays sampled where integrating it out would be wrong: a normal prior on it,
    an optimum a few std-errors from its bound, or a residual not affine in it (declared
    linear by mistake: the regressor check finds it)."""
    data, _ = line_data()
    est, se, _ = ols(data)
    p = box_sample(Line(), est, data, linear=("a",), prior={"a": Normal(0.0, 1.0)})
    assert p.linear == ()
    near = [float(est[:, 0].max() - 3 * se[:, 0].min()), -10.0]
    assert box_sample(Line(), est, data, linear=("a",), lower=near).linear == ()
    bent = np.column_stack([est[:, 0], np.sqrt(est[:, 1])])
    q = box_sample(BentLine(), bent, data, linear=("a", "b"))
    assert q.linear == ("a",)


def test_near_a_bound_truncated_normal_without_divergences():
    """Known answer near a bound: an intercept 1.5 std-errors above its lower bound 0 and
    correlated -0.87 with the slope. Flat priors: its marginal is the normal of least squares
    truncated at 0 (checked at its quartiles), and no transition diverges (the logistic map
    bends such a posterior into a banana)."""
    from scipy.stats import norm

    data, _ = line_data(seed=2)
    est, se, cov = ols(data)
    shift = 1.5 * se[:, 0] - est[:, 0]
    data = (data[0], data[1] + shift[:, None], data[2])
    est[:, 0] += shift
    post = box_sample(Line(), est, data, lower=[0.0, -10.0])
    a = post.draws("a")
    for i in range(2):
        cdf = lambda x: (norm.cdf((x - est[i, 0]) / se[i, 0]) - norm.cdf(-1.5)) / norm.sf(-1.5)
        got = cdf(np.quantile(a[i], [0.25, 0.5, 0.75]))
        np.testing.assert_allclose(got, [0.25, 0.5, 0.75], atol=0.08)
    assert a.min() >= 0.0 and post.diagnostics()["divergences"] == 0


def test_sampler_defaults_by_model_kind():
    """The target acceptance is chosen by the model's kind where it is not given, a given one
    kept; the CLI's defaults (written out: its parser imports no JAX) are the Sampler's."""
    from mrjax.cli._parse import POSTERIOR_DEFAULTS  # noqa: SLF001

    s = Sampler()
    assert s.target_accept is None and s.gradient is None
    dyn, stat = s.for_model(True), s.for_model(False)
    assert (dyn.target_accept, dyn.gradient) == (0.8, "forward")
    assert (stat.target_accept, stat.gradient) == (0.9, "reverse")
    assert Sampler(target_accept=0.95).for_model(True).target_accept == 0.95
    assert isinstance(s.kernel, NUTS)  # the default kernel, with the CLI's counts
    assert {k: getattr(s, k) for k in ("draws", "chains", "warmup")} == {
        k: POSTERIOR_DEFAULTS[k] for k in ("draws", "chains", "warmup")}
    with pytest.raises(InputError, match="target_accept must be in"):
        Sampler(target_accept=1.0).check()


@pytest.mark.parametrize("bad, match", [
    (dict(sampler=Sampler(draws=0)), "draws must be a positive integer"),
    (dict(sampler=Sampler(chains=-1)), "chains must be"),
    (dict(noise="gauss"), "noise must be one of iid, ar1"),
    (dict(prior={"bb": Normal(0, 1)}), "did you mean 'b'"),
    (dict(prior={"b": Normal(0, -1)}), "sd must be positive"),
    (dict(prior={"b": "cauchy:0:1"}), "expected one of normal"),
    (dict(prior={"b": LogNormal(1.0, 0.5)}), "log-normal prior needs a box"),
    (dict(prior={"b": Uniform(20.0, 30.0)}), "does not meet the bounds"),
])
def test_bad_options_one_line(bad, match):
    data, _ = line_data()
    with pytest.raises(InputError, match=match) as e:
        box_sample(Line(), np.zeros((2, 2)), data, **bad)
    assert "\n" not in str(e.value)


class Product(eqx.Module):
    """Residuals of y = a b t + c: `a` and `b` enter only through their product (a symmetry,
    as modified Bouc-Wen's z scale), `c` alone."""

    def __call__(self, theta, unit):
        t, y, m = unit
        return (((theta[0] * theta[1] * t + theta[2] - y)[None], m[None]),)


@pytest.mark.parametrize("gauge", [("b",), ()])
def test_a_symmetry_is_held_and_the_rest_is_conditional(gauge):
    """Known answer: with an exact symmetry (only a b is determined) one unknown is held at the
    optimum (the `gauge` name where given), the posterior of the other, times it, is the
    least-squares slope with its std-error, and a problems line says which was held."""
    data, truth = line_data(U=1, T=300)
    est, se, _ = ols(data)
    a0, b0 = 2.0, est[0, 1] / 2.0  # an optimum on the symmetry's orbit
    theta0 = np.array([[a0, b0, est[0, 0]]])
    post = box_sample(Product(), theta0, data, lower=[0.1, 0.1, -10.0],
                      upper=[10.0, 10.0, 10.0], names=("a", "b", "c"), gauge=gauge)
    held = post.held[0]
    assert held.sum() == 1 and not held[2]
    if gauge:
        assert held[1]
    j, k = (1, 0) if held[1] else (0, 1)
    fixed = theta0[0, j]
    assert np.all(post.theta[0, ..., j] == fixed)
    slope = post.theta[0, ..., k] * fixed
    assert abs(slope.mean() - est[0, 1]) < 0.3 * se[0, 1]
    np.testing.assert_allclose(slope.std() / se[0, 1], 1.0, atol=0.2)
    lines = post.problems()
    assert any(f"{'ab'[j]} held at its fitted value in 1 condition" in str(w) for w in lines), \
        lines
    held_w = [w for w in lines if w.kind == mrjax.WarningKind.HELD]
    assert [w.parameters for w in held_w] == [("ab"[j],)]
    assert post.diagnostics()["r_hat_max"] < 1.05  # the held unknown's NaN left out


def test_diagnostics_flag_split_chains_and_divergences():
    """Known answer for the checks: two chains centred 5 sd apart give R-hat >> 1.01, a
    divergent draw is counted, and well-mixed independent draws pass."""
    from mrjax.bayes import Posterior

    rng = np.random.default_rng(0)
    U, C, N = 2, 2, 1000
    theta = rng.standard_normal((U, C, N, 1))
    theta[1, 1] += 5.0
    div = np.zeros((U, C, N), bool)
    div[1, 0, 7] = True
    post = Posterior(
        names=("a",), labels=("ok", "bad"), row_labels=None, unit_dim="condition", theta=theta,
        sigma=np.exp(0.01 * rng.standard_normal((U, C, N, 1))), rho=None, lp=np.zeros((U, C, N)),
        diverging=div, n_steps=np.full((U, C, N), 3), accept=np.full((U, C, N), 0.8),
        step_size=np.ones((U, C)), theta0=np.zeros((U, 1)), lower=np.full((U, 1), -9.0),
        upper=np.full((U, 1), 9.0), free=np.array([True]), noise="iid", prior={},
        sampler=Sampler(draws=N, chains=C), seed=0, timings={})
    lines = post.problems()
    assert any("R-hat > 1.01" in str(w) and "'bad'" in str(w) for w in lines), lines
    assert any("1 divergent transition(s) in 1 condition " in str(w) for w in lines), lines
    kinds = {w.kind: w for w in lines}
    assert "bad" in kinds[mrjax.WarningKind.NOT_CONVERGED].conditions
    assert kinds[mrjax.WarningKind.DIVERGENCES].conditions == ("bad",)
    np.testing.assert_array_equal(post.unconverged(), [False, True])
    df = post.summary()
    ok = df[(df.variable == "a") & (df.condition == "ok")].iloc[0]
    assert ok.r_hat < 1.01 and ok.ess_bulk > 1000
    assert df[(df.variable == "a") & (df.condition == "bad")].iloc[0].r_hat > 1.5


# --------------------------------------------------------------------------------------------
# The per-test kind on short simulated records


#: The per-test posterior's settings of the tanh tests here (one compiled program).
TANH = Sampler(draws=400, chains=2, warmup=400)


@pytest.fixture(scope="module")
def tanh_post():
    batch, truth = short_batch("kwok", noise_frac=0.02)
    res = mrjax.fit("kwok", batch, key=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        tp = mrjax.posterior(res, batch, sampler=TANH, key=0)
    return batch, truth, res, tp


def with_upper(res, **upper):
    """`res` with the upper bounds of its search box in `upper` (name -> value [SI])."""
    lo, hi = (np.array(b, float) for b in res.model.bounds) if res.bounds is None else (
        np.array(res.bounds["lower"], float), np.array(res.bounds["upper"], float))
    for n, v in upper.items():
        hi[res.param_names.index(n)] = v
    return dataclasses.replace(res, bounds={"lower": lo, "upper": hi})


def covered(tp, truth, level=0.95):
    post = tp.posterior
    return np.array([[lo <= t <= hi for (lo, hi), t in zip(post.interval(n, level), truth[:, j])]
                     for j, n in enumerate(post.names)]).T


def test_tanh_intervals_cover_the_truth(tanh_post):
    """Known answer: the 95 % intervals of the 2 x 6 parameters cover the truth (at most one
    miss: 12 pairs at 95 % miss 0.6 on average), and every truth lies in its 99.9 % interval."""
    batch, truth, res, tp = tanh_post
    assert covered(tp, truth).sum() >= 11, tp.table()
    assert covered(tp, truth, 0.999).all(), tp.table()
    d = tp.posterior.diagnostics()
    assert d["r_hat_max"] < 1.05 and d["divergences"] == 0
    assert tp.data == "record" and list(tp.n_scored) == list(res.n_samples)


def test_chees_lockstep_covers_the_truth(tanh_post):
    """Known answer for the lockstep kernel: ChEES-HMC (`Sampler(kernel=ChEES())` at its
    defaults, 8 chains x (150 + 300)) on the simulated tanh tests covers the truth as NUTS
    does (at most one of the 12 pairs outside its 95 % interval, none outside 99.9 %), with
    R-hat <= 1.01, bulk and tail ESS >= 400 and no divergence; every chain of a unit takes
    the same number of leapfrog steps at every draw (lockstep); same key, same draws."""
    batch, truth, res, _ = tanh_post
    sampler = Sampler(kernel=ChEES())
    tp = mrjax.posterior(res, batch, sampler=sampler, key=0)
    post = tp.posterior
    assert (post.n_chains, post.n_draws, post.sampler.warmup) == (8, 300, 150)
    assert covered(tp, truth).sum() >= 11, tp.table()
    assert covered(tp, truth, 0.999).all(), tp.table()
    d = post.diagnostics()
    assert d["r_hat_max"] <= 1.01 and d["divergences"] == 0, d
    assert min(d["ess_bulk_min"], d["ess_tail_min"]) >= 400, d
    steps = post.n_steps
    np.testing.assert_array_equal(steps, np.broadcast_to(steps[:, :1], steps.shape))
    assert post.to_dict()["sampler"] == "blackjax ChEES"
    again = mrjax.posterior(res, batch, sampler=sampler, key=0).posterior
    np.testing.assert_array_equal(again.theta, post.theta)


def test_predictive_band_covers_new_records(tanh_post):
    """A new record of the same tests (other noise): the 95 % predictive band covers about 95 %
    of it; the band of the model force alone covers far less (it leaves the noise out)."""
    batch, truth, res, tp = tanh_post
    new, _ = short_batch("kwok", noise_frac=0.02, seed=10)
    band = tp.predict_band(new)
    assert np.all((band.coverage > 0.88) & (band.coverage < 0.995)), band.coverage
    assert np.all(band.force_coverage < band.coverage)
    assert band.lower.shape == np.asarray(new.force).shape
    with pytest.raises(InputError, match="band level"):
        tp.predict_band(new, level=95)


def test_posterior_files_and_fit_json(tanh_post, tmp_path):
    """posterior.nc opens in arviz and xarray with the model's names, dims chain / draw /
    condition and the test labels; posterior.csv and the fit.json entry hold the summary."""
    az = mrjax.bayes._result.arviz()  # noqa: SLF001 - the quiet import
    import xarray as xr

    batch, truth, res, tp = tanh_post
    path = tmp_path / "posterior.nc"
    path.write_bytes(tp.netcdf_bytes())
    idata = az.from_netcdf(path)
    ds = xr.open_dataset(path, group="posterior", engine="h5netcdf")
    for name in res.param_names:
        assert ds[name].dims == ("chain", "draw", "condition")
    assert list(ds["condition"].values) == list(batch.labels)
    assert ds.sizes["chain"] == 2 and ds.sizes["draw"] == 400
    assert "diverging" in idata.sample_stats
    np.testing.assert_allclose(ds["c"].values, np.moveaxis(tp.posterior.theta[..., 0], 0, -1))
    csv = tp.to_csv().splitlines()
    assert csv[0].split(",")[:9] == ["variable", "condition", "mean", "sd", "q2.5", "q50",
                                     "q97.5", "r_hat", "ess_bulk"]
    assert len(csv) == 1 + 2 * 7  # 6 parameters and noise_sigma, two tests
    doc = json.loads(res.to_json(posterior=tp))
    p = doc["posterior"]
    assert p["draws"] == 400 and p["noise"] == "iid" and p["likelihood_data"] == "record"
    assert set(p["conditions"][0]) >= {"label", "c", "noise_sigma", "divergences"}
    assert set(p["conditions"][0]["c"]) == {"mean", "sd", "q2.5", "q50", "q97.5", "r_hat",
                                            "ess_bulk", "ess_tail"}
    # which parameters were integrated out of the log-density (here the offset at least)
    assert "f0" in tp.posterior.linear
    assert p["integrated_out"] == list(tp.posterior.linear)
    assert idata.attrs["integrated_out"] == ", ".join(tp.posterior.linear)


def test_figures(tanh_post):
    import mrjax.report as rp

    batch, truth, res, tp = tanh_post
    pngs = rp.posterior_figures(tp, tp.predict_band(batch))
    assert set(pngs) == {"posterior_pair.png", "posterior_intervals.png", "posterior_band.png"}
    assert all(v[:4] == b"\x89PNG" and len(v) > 5000 for v in pngs.values())


def test_dynamic_model_intervals_cover_the_truth():
    """Known answer with an ODE model (Dahl) on two short records (500 and 833 samples), its
    likelihood on the swarm's view (the default for dynamic models; whole short records):
    every truth in its 99.9 % interval, at most one of 10 outside its 95 % one."""
    batch, truth = short_batch("dahl", noise_frac=0.02)
    res = mrjax.fit("dahl", batch, key=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        # the user's settings: their gradient left to the model, forward mode for a dynamic one
        tp = mrjax.posterior(res, batch, key=0,
                             sampler=mrjax.bayes.Sampler(draws=300, chains=2, warmup=300))
    assert tp.data == "view"
    assert tp.posterior.sampler.gradient == "forward"
    assert covered(tp, truth).sum() >= 9, tp.table()
    assert covered(tp, truth, 0.999).all(), tp.table()
    assert np.all(np.isfinite(tp.posterior.theta))


def test_warnings_without_polish_and_at_bounds(tanh_post):
    batch, _, _, _ = tanh_post
    res = mrjax.fit("kwok", batch, key=0, swarm=mrjax.Swarm(max_generations=5), polish=None)
    # the posterior's box is the fit's: the fit's upper bound of c moved to its largest c
    res = with_upper(res, c=res.param("c").max())
    with pytest.warns(RuntimeWarning) as rec:  # the start's warnings: no continuation needed
        mrjax.posterior(res, batch, sampler=dataclasses.replace(TANH, continuations=0))
    text = " ".join(str(w.message) for w in rec)
    assert "without polish" in text
    assert "at bounds" in text and "c = " in text
    kinds = {w.message.kind for w in rec if isinstance(w.message, mrjax.ResultWarning)}
    assert {mrjax.WarningKind.DOUBTFUL_START, mrjax.WarningKind.AT_BOUND} <= kinds


def test_per_test_bad_input(tanh_post):
    batch, _, res, _ = tanh_post
    with pytest.raises(InputError, match="draws must be a positive integer"):
        mrjax.posterior(res, batch, sampler=Sampler(draws=0))
    with pytest.raises(InputError, match="sampler must be a mrjax.Sampler"):
        mrjax.posterior(res, batch, sampler={"draws": 100})
    with pytest.raises(InputError, match="noise must be one of"):
        mrjax.posterior(res, batch, noise="white")
    with pytest.raises(InputError, match="likelihood_data must be one of"):
        mrjax.posterior(res, batch, likelihood_data="both")
    with pytest.raises(InputError, match="not the fit's conditions"):
        mrjax.posterior(res, batch.subset([0]))
    with pytest.raises(InputError, match="outside the bounds"):  # e.g. an edited fit.json
        mrjax.posterior(with_upper(res, c=0.5 * res.theta[0, 0]), batch)


# --------------------------------------------------------------------------------------------
# The command line


def write_tests(folder):
    """The two records of the `tanh_post` fixture in the UTFSM text layout (t [s], x [mm],
    v [mm/s], F [N]; frequency and amplitude in the file name): the command line's posterior
    then reuses the fixture's compiled program."""
    folder.mkdir()
    batch, _ = short_batch("kwok", noise_frac=0.02)
    for c, name in zip(batch.conditions(), ("15mm2x5Hz0A.txt", "8mm1x5Hz0A.txt")):
        np.savetxt(folder / name, np.c_[c.t, c.x * 1e3, c.xdot * 1e3, c.force])
    return folder


def test_cli_posterior_writes_files(tanh_post, tmp_path):
    data = write_tests(tmp_path / "data")
    out = tmp_path / "out"
    code, stdout, err = run(["fit", data, "--model", "kwok", "--posterior", "--draws", "400",
                             "--chains", "2", "--warmup", "400", "--prior",
                             "beta=lognormal:100:1", "--out", out])
    assert code == 0, err
    assert "noise_sigma" in stdout and "leapfrog steps per draw" in stdout
    doc = json.loads((out / "fit.json").read_text())
    assert doc["posterior"]["noise"] == "iid" and doc["posterior"]["chains"] == 2
    assert doc["posterior"]["prior"] == {"beta": "lognormal(100, 1)"}
    assert [c["label"] for c in doc["posterior"]["conditions"]] == ["15mm2x5Hz0A", "8mm1x5Hz0A"]
    check_pngs(out, ["posterior_pair.png", "posterior_intervals.png", "posterior_band.png"])
    assert (out / "posterior.nc").read_bytes()[:4] == b"\x89HDF"
    assert (out / "posterior.csv").read_text().startswith("variable,condition,mean")
    # the predictive band of that fit on the same records, from its posterior.nc
    pred = tmp_path / "pred"
    code, stdout, err = run(["predict", "--fit", out, "--band", "95", data, "--out", pred])
    assert code == 0, err
    band = json.loads((pred / "predict.json").read_text())["band"]
    assert band["level"] == 0.95 and len(band["conditions"]) == 2
    assert all(0.85 < c["coverage"] <= 1.0 for c in band["conditions"]), band
    check_pngs(pred, ["predict_band.png"])
    code, _, err = run(["predict", "--fit", out, "--band", "0", data, "--out", pred / "x"])
    assert code == 2 and "--band must be a percentage" in one_error_line(err)


@pytest.mark.parametrize("argv, match", [
    (["--posterior", "--draws", "0"], "draws must be a positive integer"),
    (["--posterior", "--noise", "gauss"], "--noise must be one of iid, ar1"),
    (["--draws", "10"], "--draws needs --posterior"),
    (["--posterior", "--prior", "c"], "--prior expects NAME=KIND:A:B"),
    (["--posterior", "--prior", "cc=normal:1:1"], "did you mean 'c'"),
    (["--posterior", "--posterior-data", "all"], "--posterior-data must be one of"),
    (["--posterior", "--kernel", "mala"], "--kernel must be one of nuts, chees"),
    (["--kernel", "chees"], "--kernel needs --posterior"),
])
def test_cli_bad_posterior_options(tmp_path, argv, match):
    """Impossible options: one error line, exit 2, nothing written, before any fit."""
    data = write_tests(tmp_path / "data")
    out = tmp_path / "out"
    code, _, err = run(["fit", data, "--model", "kwok", "--out", out, *argv])
    assert code == 2
    assert match in one_error_line(err)
    assert not out.exists()
