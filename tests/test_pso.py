"""The batched particle swarm: known answers, the statistical stop, batching, robustness."""

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import assert_same_swarms

import mrjax
from mrjax import models
from mrjax.data import paper_grid, paper_truth
from mrjax.fitting import fit_swarm
from mrjax.models import box_corners, check_bounds
from mrjax.objective import condition_data, rms_per_condition
from mrjax.pso import AbstractObjective, PSOParams, stability, swarm


@pytest.fixture(scope="module")
def grid():
    return paper_grid()


@pytest.fixture(scope="module")
def truth_rms(grid):
    return rms_per_condition(models.get("kwok"), paper_truth(grid), grid)


@pytest.fixture(scope="module")
def small():
    return paper_grid(currents=(0.0, 1.0), motions=((1.0, 0.008), (2.0, 0.004)), cycles=1,
                      sample_rate=500.0)


class Sphere(AbstractObjective):
    """Shifted sphere, one optimum per condition: data = centre (D,). NaN outside |x|<4."""

    def __call__(self, position, data):
        f = jnp.sum((position - data) ** 2)
        return jnp.where(jnp.max(jnp.abs(position)) > 4.0, jnp.nan, f)


# ---------------------------------------------------------------------------- known answers


def test_separable_reaches_truth_and_stops_by_criterion(grid, truth_rms):
    res = fit_swarm(models.get("kwok"), grid, key=jax.random.key(0), mode="separable")
    ratio = np.asarray(res.rms) / truth_rms
    gens = np.asarray(res.result.generations)
    print(f"\nseparable tanh: RMS/truth max {ratio.max():.5f} median {np.median(ratio):.5f}; "
          f"generations min/median/max {gens.min()}/{np.median(gens)}/{gens.max()}")
    assert np.all(np.asarray(res.result.stopped_by_criterion))
    assert ratio.max() <= 1.005
    # all parameters are reported, linear ones solved exactly and inside the bounds
    lo, hi = models.get("kwok").bounds
    th = np.asarray(res.theta)
    assert th.shape == (36, 6) and np.all(th >= lo) and np.all(th <= hi)
    assert np.allclose(rms_per_condition(models.get("kwok"), th, grid), res.rms, rtol=1e-9)


def test_full_mode_paper_box_tanh_beats_bouc_wen(grid, truth_rms):
    """The paper's swarm (full mode, statistical stop) in the paper's search box: on the
    tanh-simulated grid the tanh fits end with the lower median RMS (paper's Fig 9), every
    condition stops by the criterion, and the stop falls after 10-40 generations (paper: ~15).
    Measured for seeds 0-2: tanh 34-40 N vs Bouc-Wen 56-62 N. (The paper's "> 30 generations
    for Bouc-Wen" does not reproduce on these data: both stop after ~17-20.)"""
    from mrjax.reproduce import PAPER_BOX

    out = {}
    for name in ("kwok", "bouc_wen"):
        m = models.get(name) if name == "kwok" else models.get(name).with_substeps(1)
        lo, hi = (jnp.asarray(b) for b in PAPER_BOX[name])
        res = fit_swarm(m, grid, key=jax.random.key(1), mode="full", bounds=(lo, hi),
                        max_generations=150)
        gens = np.asarray(res.result.generations)
        rms = np.asarray(res.rms)
        print(f"\nfull {name}, paper box: generations min/median/mean/max {gens.min()}/"
              f"{np.median(gens)}/{gens.mean():.1f}/{gens.max()}, median RMS {np.median(rms):.1f} N "
              f"(truth {np.median(truth_rms):.1f} N)")
        assert np.all(np.isfinite(rms)) and np.all(np.asarray(res.result.stopped_by_criterion))
        assert 10 <= np.median(gens) <= 40
        out[name] = np.median(rms)
    assert out["kwok"] < 0.8 * out["bouc_wen"]


def test_sphere_known_optimum():
    C, D = 3, 4
    centres = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, (C, D)))
    res = swarm(Sphere(), -5.0 * jnp.ones(D), 5.0 * jnp.ones(D), centres, key=jax.random.key(2),
                params=PSOParams(criterion=False), max_generations=150)
    assert np.allclose(res.position, centres, atol=1e-3)
    assert np.all(np.isfinite(res.fitness))  # NaN particles (|x| > 4) never became a best


# ---------------------------------------------------------------------------- batching


def test_determinism(small):
    m = models.get("kwok")
    a = fit_swarm(m, small, key=jax.random.key(3), mode="full", max_generations=20)
    b = fit_swarm(m, small, key=jax.random.key(3), mode="full", max_generations=20)
    assert np.array_equal(a.theta, b.theta) and np.array_equal(a.result.history, b.result.history)
    c = fit_swarm(m, small, key=jax.random.key(4), mode="full", max_generations=20)
    assert not np.array_equal(a.theta, c.theta)


def test_batch_equals_per_condition_runs(small):
    m = models.get("kwok")
    keys = jax.random.split(jax.random.key(5), small.n_conditions)
    whole = fit_swarm(m, small, key=keys, mode="full", max_generations=40)
    ones = [fit_swarm(m, small.subset([i]), key=keys[i:i + 1], mode="full", max_generations=40)
            for i in range(small.n_conditions)]
    # equal to rounding (a batch of one vectorises its sums differently), a stop moved by a
    # near-tie excepted (see `helpers.assert_same_swarms`)
    assert_same_swarms([o.result.generations[0] for o in ones], whole.result.generations,
                       [o.result.history[0] for o in ones], whole.result.history,
                       [o.theta[0] for o in ones], whole.theta)


def test_frozen_condition_ignores_others():
    # condition 0 is identical in both batches; condition 1 runs for very different lengths
    centres_a = jnp.asarray([[0.5, -0.5], [1.0, 1.0]])
    centres_b = jnp.asarray([[0.5, -0.5], [-2.0, 3.0]])
    keys = jax.random.split(jax.random.key(6), 2)
    p = PSOParams(window=3, min_generations=0)
    ra = swarm(Sphere(), -5 * jnp.ones(2), 5 * jnp.ones(2), centres_a, key=keys, params=p,
               max_generations=300)
    rb = swarm(Sphere(), -5 * jnp.ones(2), 5 * jnp.ones(2), centres_b, key=keys, params=p,
               max_generations=300)
    assert np.array_equal(ra.position[0], rb.position[0])
    assert np.array_equal(ra.history[0], rb.history[0])
    assert int(ra.generations[0]) == int(rb.generations[0])
    # a stopped condition's history is frozen at its final best
    g = int(ra.generations[0])
    assert np.all(np.asarray(ra.history[0, g:]) == float(ra.fitness[0]))
    # and the group best never increases
    assert np.all(np.diff(np.asarray(ra.history), axis=1) <= 0)


class CountingSphere(AbstractObjective):
    """Sphere that also counts its evaluations per condition (host callback), to check that
    paging scores only the conditions still running."""

    def __call__(self, position, data):
        centre, index = data
        jax.debug.callback(_count, index, ordered=False)
        return jnp.sum((position - centre) ** 2)


_COUNTS: dict[int, int] = {}


def _count(i):
    _COUNTS[int(i)] = _COUNTS.get(int(i), 0) + 1


@pytest.mark.parametrize("page", [1, 2, 3])
def test_pages_score_only_running_conditions_same_result(page):
    # seven conditions with very different difficulty stop at different generations
    C, D, N = 7, 3, 6
    centres = jnp.asarray(np.random.default_rng(3).uniform(-3, 3, (C, D)))
    data = (centres, jnp.arange(C))
    keys = jax.random.split(jax.random.key(8), C)
    p = PSOParams(window=4)
    _COUNTS.clear()
    whole = swarm(CountingSphere(), -5 * jnp.ones(D), 5 * jnp.ones(D), data, key=keys,
                  params=p, n_particles=N, max_generations=200)
    all_counts = dict(_COUNTS)
    _COUNTS.clear()
    paged = swarm(CountingSphere(), -5 * jnp.ones(D), 5 * jnp.ones(D), data, key=keys,
                  params=p, n_particles=N, max_generations=200, page_size=page)
    gens = np.asarray(whole.generations)
    assert len(set(gens.tolist())) > 1  # the conditions do stop at different generations
    # the same swarms, to rounding (pages are narrower batches; a stop moved by a near-tie
    # excepted, see `helpers.assert_same_swarms`)
    assert_same_swarms(whole.generations, paged.generations, whole.history, paged.history,
                       whole.position, paged.position)
    same = np.asarray(whole.generations) == np.asarray(paged.generations)
    assert np.array_equal(np.asarray(whole.stopped_by_criterion)[same],
                          np.asarray(paged.stopped_by_criterion)[same])
    # unpaged: every condition scored every generation until the last stops (+ the start);
    # `unit` callbacks per scoring of one condition (JAX may batch the particles' callbacks)
    unit = all_counts[0] // (gens.max() + 1)
    assert unit >= 1
    assert all(all_counts[i] == unit * (gens.max() + 1) for i in range(C))
    # paged: each condition until its own stop; padding of the last page (conditions that
    # already stopped) is the only extra work
    work = sum(_COUNTS.values()) / unit
    gp = np.asarray(paged.generations)
    assert all(_COUNTS[i] >= unit * (gp[i] + 1) for i in range(C))
    assert work <= sum(gp + 1) + (page - 1) * gp.max()
    assert work < sum(all_counts.values()) / unit


def test_page_size_validated():
    with pytest.raises(mrjax.InputError, match="page_size"):
        swarm(Sphere(), -jnp.ones(2), jnp.ones(2), jnp.zeros((3, 2)), key=jax.random.key(0),
              page_size=0)


# ---------------------------------------------------------------------------- statistical stop


def test_statistical_stop_rule_by_hand():
    """Replay the rule on the returned history: lambda^-1_t = (f_0 - f_t)/t, stop at the first
    t >= max(min_gen, W) where the mean of the last W improvements <= -ln(conf) lambda^-1_t."""
    centres = jnp.asarray(np.random.default_rng(1).uniform(-1, 1, (4, 3)))
    p = PSOParams(window=4, min_generations=6, confidence=0.905)
    res = swarm(Sphere(), -5 * jnp.ones(3), 5 * jnp.ones(3), centres, key=jax.random.key(7),
                params=p, max_generations=200)
    H = np.asarray(res.history)
    for c in range(4):
        imp = -np.diff(H[c])
        stop = None
        for t in range(6, 201):
            lam = (H[c, 0] - H[c, t]) / t
            if imp[t - 4:t].mean() <= -np.log(0.905) * lam:
                stop = t
                break
        assert stop == int(res.generations[c])
        assert bool(res.stopped_by_criterion[c])
        g = int(res.generations[c])
        np.testing.assert_allclose(float(res.lambda_inv[c]), (H[c, 0] - H[c, g]) / g, rtol=1e-9)


def test_fixed_generation_mode_and_cap(small):
    res = fit_swarm(models.get("kwok"), small, key=jax.random.key(8), mode="separable",
                    params=PSOParams(criterion=False), max_generations=12)
    assert np.all(np.asarray(res.result.generations) == 12)
    assert not np.any(np.asarray(res.result.stopped_by_criterion))


def test_hyperparameters_do_not_recompile():
    traces = []

    class Counting(AbstractObjective):
        def __call__(self, position, data):
            traces.append(1)
            return jnp.sum((position - data) ** 2)

    centres = jnp.zeros((2, 2))
    for w, c in [(0.65, 2.0), (0.5, 1.5), (0.7, 1.8)]:
        swarm(Counting(), -jnp.ones(2), jnp.ones(2), centres, key=jax.random.key(0),
              params=PSOParams(inertia=w, c1_max=c, c2_max=c, confidence=0.9, window=3),
              max_generations=10)
    n_first = len(traces)
    assert n_first > 0
    swarm(Counting(), -jnp.ones(2), jnp.ones(2), centres, key=jax.random.key(0),
          params=PSOParams(inertia=0.3, window=7, min_generations=2), max_generations=10)
    assert len(traces) == n_first


# ---------------------------------------------------------------------------- robustness


def test_bounds_respected_and_nan_particles_harmless(small):
    m = models.get("bouc_wen")
    lo, hi = m.bounds
    lo, hi = lo.copy(), hi.copy()
    # wide enough that many particles diverge (negative beta + gamma lets z grow)
    lo[m.param_names.index("beta")] = -5000.0
    lo[m.param_names.index("gamma")] = -5000.0
    res = fit_swarm(m, small, key=jax.random.key(9), mode="full", bounds=(lo, hi),
                    max_generations=15)
    th = np.asarray(res.theta)
    assert np.all(th >= lo) and np.all(th <= hi)
    assert np.all(np.isfinite(np.asarray(res.rms)))
    assert np.all(np.isfinite(np.asarray(res.result.history)))


def test_stability_eigenvalues_by_hand():
    eig, ok = stability(0.65, 2.0, 2.0)
    # lambda^2 + 0.35 lambda + 0.65 = 0
    expect = np.roots([1.0, 0.35, 0.65])
    np.testing.assert_allclose(np.sort_complex(eig), np.sort_complex(expect), atol=1e-12)
    np.testing.assert_allclose(np.abs(eig), np.sqrt(0.65), atol=1e-12)
    assert ok
    _, ok = stability(1.2, 2.0, 2.0)
    assert not ok
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        PSOParams(inertia=1.2).check()
    assert any("unstable" in str(x.message) for x in w)


def test_bad_bounds_and_options(small):
    m = models.get("kwok")
    lo, hi = m.bounds
    with pytest.raises(mrjax.InputError, match="inverted"):
        check_bounds(m, (hi, lo))
    with pytest.raises(mrjax.InputError, match="6 values"):
        check_bounds(m, (lo[:3], hi[:3]))
    with pytest.raises(mrjax.InputError, match="confidence"):
        PSOParams(confidence=1.5).check()
    with pytest.raises(mrjax.InputError, match="mode"):
        fit_swarm(m, small, key=jax.random.key(0), mode="nope")


def test_box_corners_cover_the_box():
    m = models.get("bouc_wen")
    lo, hi = m.bounds
    rows = box_corners(m, lo, hi)
    assert rows.shape == (16, 8)
    nl = m.nonlinear_index
    assert np.all(rows[:, nl].min(0) == lo[nl]) and np.all(rows[:, nl].max(0) == hi[nl])


def test_objective_is_generic_pytree_data():
    """The swarm only needs (position, one condition's data): e.g. a joint objective."""

    class Joint(AbstractObjective):
        weights: jax.Array

        def __call__(self, position, data):
            return jnp.sum(self.weights * (position - data["centre"]) ** 2)

    data = {"centre": jnp.asarray([[0.25, -0.75]])}
    res = swarm(Joint(jnp.asarray([1.0, 3.0])), -jnp.ones(2), jnp.ones(2), data,
                key=jax.random.key(10), params=PSOParams(criterion=False), max_generations=100)
    np.testing.assert_allclose(res.position[0], [0.25, -0.75], atol=1e-4)
    assert isinstance(condition_data.__doc__, str) and eqx.is_array(res.fitness)
