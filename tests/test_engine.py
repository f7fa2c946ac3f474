"""The identification engine (`mrjax.engine`): every problem kind through the one pipeline,
settings as objects, and known answers over models x engine settings x methods
(`tests/helpers.py` lists them), on short records."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import ENGINE_SETTINGS, METHODS, MODEL_NAMES, PROBLEM_KINDS, short_batch

import mrjax
from mrjax import engine, models
from mrjax.data import paper_grid
from mrjax.objective import rms_per_condition


@pytest.fixture(scope="module")
def grid():
    return paper_grid()


# ------------------------------------------------------------------------ the matrix
#: The float32 swarm on the Bouc-Wen models (13-18 s each on 2 cores) adds no path that Dahl's
#: (the ODE models' float32 integration) and the static models' do not take.
MATRIX = [(n, s) for n in MODEL_NAMES for s in sorted(ENGINE_SETTINGS)
          if not (s == "float32" and n in ("bouc_wen", "modified_bouc_wen"))]


@pytest.mark.parametrize("name,setting", MATRIX, ids=[f"{n}-{s}" for n, s in MATRIX])
def test_every_model_and_setting_reaches_the_noise_floor(name, setting):
    """Known answer over models x settings: on records simulated from known parameters with
    1 % noise, the fit's RMS is at most the true parameters' (the noise floor) up to 0.5 %,
    the polish never raises the swarm's RMS, and the reported swarm is the one set."""
    batch, truth = short_batch(name)
    res = mrjax.fit(name, batch, key=0, **ENGINE_SETTINGS[setting])
    truth_rms = rms_per_condition(models.get(name), truth, batch)
    ratio = res.rms / truth_rms
    print(f"\n{name} / {setting}: RMS / truth {np.round(ratio, 5)}")
    assert np.all(ratio <= 1.005)
    assert np.all(res.rms <= res.pso_rms * (1 + 1e-9))
    assert res.swarm_mode == ENGINE_SETTINGS[setting]["swarm"].mode


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", ["kwok", "dahl"])
def test_methods(name, method):
    """Each method on a static and an ODE model: the swarm alone reaches within 5 % of the noise
    floor; the polish alone never ends above its neutral start (and reports no swarm); with
    both, the noise floor."""
    batch, truth = short_batch(name)
    model = models.get(name)
    res = mrjax.fit(name, batch, key=0, **METHODS[method])
    assert res.method == method
    truth_rms = rms_per_condition(model, truth, batch)
    if method == "lm":
        start = np.broadcast_to(np.clip(model.default_start(), *model.bounds), truth.shape)
        assert np.all(res.rms <= rms_per_condition(model, start, batch) * (1 + 1e-12))
        assert np.all(res.generations == -1) and np.all(np.isnan(res.pso_rms))
        assert res.swarm_mode == "none"
    elif method == "pso":
        assert np.all(res.rms <= 1.05 * truth_rms)
        assert res.polish_status == ("none",) * 2 and np.all(res.polish_steps == 0)
        assert np.all(np.isfinite(res.stderr[:, 0]))  # std-errors without a polish
    else:
        assert np.all(res.rms <= 1.005 * truth_rms)


def test_cli_builds_the_settings_objects_users_build(grid):
    """The settings are objects only (no keyword copies of their fields): the command line's
    options build the same `Swarm` and `Polish` a Python user builds, and the same objects give
    the same fit, bit for bit."""
    from mrjax.cli._fit import fit_settings
    from mrjax.cli._main import build_parser

    def cli(*flags):
        return fit_settings(build_parser().parse_args(["fit", "x.csv", "--model", "kwok", *flags]))

    swarm = mrjax.Swarm(mode="full", restarts=2, max_generations=30)
    assert cli("--swarm", "full", "--restarts", "2", "--max-generations", "30") == (
        swarm, mrjax.Polish())
    assert cli("--method", "pso", "--no-retry") == (mrjax.Swarm(), None)
    assert cli("--method", "lm", "--no-retry") == (None, mrjax.Polish(retry=False))
    sub = grid.subset([0, 20])
    polish = mrjax.Polish(max_steps=40, tol=1e-7)
    a = mrjax.fit("kwok", sub, key=2, swarm=swarm, polish=polish)
    b = mrjax.fit("kwok", sub, key=2, swarm=cli("--swarm", "full", "--restarts", "2",
                                                "--max-generations", "30")[0], polish=polish)
    np.testing.assert_array_equal(a.theta, b.theta)
    np.testing.assert_array_equal(a.history, b.history)
    with pytest.raises(TypeError):  # the old keyword copies of the fields are gone
        mrjax.fit("kwok", sub, max_generations=30)


def test_settings_are_checked_at_construction():
    for bad in (dict(n_particles=0), dict(restarts=1.5), dict(mode="ring"), dict(generations=0),
                dict(params="fast")):
        with pytest.raises(mrjax.InputError):
            mrjax.Swarm(**bad)
    for bad in (dict(max_steps=0), dict(tol=-1.0), dict(tol=float("nan"))):
        with pytest.raises(mrjax.InputError):
            mrjax.Polish(**bad)
    for bad in (dict(size=0), dict(resume=True), dict(journal="j", resume="yes")):
        with pytest.raises(mrjax.InputError):
            mrjax.Chunks(**bad)
    with pytest.raises(mrjax.InputError, match="nothing to run"):
        engine.check_settings(None, None)
    with pytest.raises(mrjax.InputError, match="must be a mrjax.Swarm"):
        mrjax.fit("kwok", paper_grid().subset([0]), swarm="full")


def test_every_kind_runs_through_the_one_engine(grid, monkeypatch):
    """`mrjax.fit`, `generalize(method="joint")` and `identify` each build a problem and run the
    one pipeline: every swarm and every polish of the three goes through `mrjax.engine.solve`
    (its swarm stage and `mrjax.refine.solve_box`), with the problem kind of `PROBLEM_KINDS`;
    the per-test fit's retry from the neighbours' optima is a second polish of the engine."""
    import mrjax.engine._run as run

    seen: list[tuple[str, str]] = []
    real_swarm, real_box = run.run_swarm, run.solve_box

    def swarm(problem, *a, **k):
        seen.append(("swarm", type(problem).__name__))
        return real_swarm(problem, *a, **k)

    def box(*a, **k):
        seen.append(("polish", type(a[0]).__name__))
        return real_box(*a, **k)

    monkeypatch.setattr(run, "run_swarm", swarm)
    monkeypatch.setattr(run, "solve_box", box)
    sub = grid.subset([0, 6, 12, 18, 24, 30])  # 1 Hz / 4 mm at six currents
    res = mrjax.fit("kwok", sub, key=0, swarm=mrjax.Swarm(max_generations=40))
    assert seen == [("swarm", "TestsProblem"), ("polish", "ConditionResidual"),
                    ("polish", "ConditionResidual")]
    assert res.starts_rms.shape == (6, 2)
    assert np.all(res.rms <= res.starts_rms.min(axis=1) * (1 + 1e-12))
    seen.clear()
    gm = mrjax.generalize.generalize(res, sub, method="joint", key=0,
                                     swarm=mrjax.Swarm(max_generations=20))
    assert seen == [("swarm", "LawsProblem"), ("polish", "LawResidual")]
    assert gm.total_rms <= gm.report.two_step_rms
    seen.clear()
    mrjax.generalize.identify(sub, "kwok", lag=None, key=0, swarm=mrjax.Swarm(max_generations=20))
    assert seen == [("swarm", "LawsProblem"), ("polish", "LawResidual")]
    assert set(PROBLEM_KINDS) == {"TestsProblem", "LawsProblem"}


def test_compiled_code_is_released_near_the_map_limit(grid):
    """A long session keeps every compiled program, each in memory maps of its own; past
    Linux's `vm.max_map_count` the next compilation crashes the process. `release_code` empties
    JAX's caches above a share of the limit (the engine calls it before each solve), and leaves
    them alone below it."""
    from mrjax._runtime import map_count, release_code

    if map_count() is None:
        pytest.skip("no /proc/self/maps on this system")
    mrjax.fit("kwok", grid.subset([0, 3]), key=0, swarm=mrjax.Swarm(n_particles=17),
              polish=mrjax.Polish(uncertainty=False))
    before = map_count()
    assert not release_code(share=1.0) and map_count() >= before - 50
    with pytest.warns(RuntimeWarning, match="caches were emptied"):
        assert release_code(share=0.0)
    assert map_count() < before - 100  # the programs' code maps are gone
