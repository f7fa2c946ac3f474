"""A hysteretic element identified inside a structure (`mrjax.structure`): the input's
interpolations, the simulation against SciPy, a known answer on a short simulated record of the
Bouc-Wen benchmark's system (fit, std-errors, posterior, prediction, fit.json), the command
line and its one-line errors. The full-size benchmark is `benchmarks/structure.py`."""

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import run_cli

import mrjax
import mrjax.structure as ms
from mrjax import InputError
from mrjax.models import get

ROOT = Path(__file__).resolve().parents[1]
SPEC = f"{ROOT / 'examples' / 'structure_bouc_wen.py'}:BenchmarkBoucWen"
FS = 750.0
#: The benchmark's system (Noël & Schoukens 2016), beta held at 1000 1/m by the model.
TRUE = dict(m=2.0, c=10.0, k=5e4, alpha=5e4, gamma=0.8, delta=-1.1, nu=1.0)
#: A short period for the tests (the benchmark's is 8192 samples).
P = 1024


@pytest.fixture(scope="module")
def model():
    return get(SPEC)


def truth_z(model):
    return np.array([TRUE[n] for n in ("m",) + model.param_names])


def multisine(n: int, seed: int, rms: float = 50.0) -> np.ndarray:
    """One period (n,) of a random-phase multisine, 5-150 Hz at 750 Hz, `rms` [N]."""
    rng = np.random.default_rng(seed)
    f = np.fft.rfftfreq(n, 1 / FS)
    lines = (f >= 5) & (f <= 150)
    U = np.zeros(f.size, complex)
    U[lines] = np.exp(1j * rng.uniform(0, 2 * np.pi, lines.sum())) * n / 2
    u = np.fft.irfft(U, n)
    return u * rms / u.std()


def simulated(model, u, periods, structure, substeps=32, label="r"):
    """A record of `periods` periods of `u` in steady state, its response simulated with many
    sub-steps (the band-limited input is exact for a multisine)."""
    n = u.size * periods
    rec = ms.Record(label, np.arange(n) / FS, np.tile(u, periods), np.zeros(n))
    inp = jax.device_put(ms.step_inputs(ms.stack([rec]), structure, substeps))
    y = np.asarray(jax.jit(jax.vmap(lambda z, i: ms.simulate(model, structure, z, i)))(
        jnp.asarray(truth_z(model)[None]), inp))[0]
    return dataclasses.replace(rec, response=y)


# ------------------------------------------------------------------------------ interpolation
def test_interpolations():
    n, m = 64, 3
    t = np.arange(n) / n
    u = np.sin(2 * np.pi * 3 * t) + 0.5 * np.cos(2 * np.pi * 7 * t)  # periodic, band-limited
    a, b, c = ms.BandLimited().stage_inputs(u, m, True)
    tb = (np.arange(n * m) + 0.5) / (n * m)
    exact = np.sin(2 * np.pi * 3 * tb) + 0.5 * np.cos(2 * np.pi * 7 * tb)
    np.testing.assert_allclose(b, exact, atol=1e-12)
    np.testing.assert_allclose(a[::m], u, atol=1e-12)
    np.testing.assert_allclose(c[m - 1::m], np.roll(u, -1), atol=1e-12)
    line = 2.0 * np.arange(10.0)
    a, b, c = ms.Linear().stage_inputs(line, 2, False)
    np.testing.assert_allclose(b, 2.0 * (np.arange(18) + 0.5) / 2, atol=1e-12)
    a, b, c = ms.ZeroOrderHold().stage_inputs(line, 2, False)
    np.testing.assert_array_equal(c, np.repeat(line[:-1], 2))
    # a smooth record that is not periodic: the mirrored interpolant is accurate inside
    x = np.linspace(0, 1, 200)
    s = np.exp(-((x - 0.5) / 0.15) ** 2)
    a, b, c = ms.BandLimited().stage_inputs(s, 1, False)
    mid = np.exp(-(((x[:-1] + x[1:]) / 2 - 0.5) / 0.15) ** 2)
    assert np.max(np.abs(b - mid)) < 1e-6
    with pytest.raises(InputError, match="interpolation"):
        ms.interpolation("cubic")


# ------------------------------------------------------------------------------ simulation
@pytest.mark.parametrize("kind,response", [("sdof", "displacement"), ("base", "acceleration")])
def test_simulate_against_scipy(model, kind, response):
    from scipy.integrate import solve_ivp

    z = truth_z(model)
    p = dict(TRUE, beta=1000.0)
    freqs, amps = np.array([12.0, 31.0, 47.0]), np.array([20.0, 15.0, 10.0])
    scale = 1.0 if kind == "sdof" else 1.0 / p["m"]

    def u_of(t):
        return scale * np.sum(amps * np.sin(2 * np.pi * freqs * np.asarray(t)[..., None]), -1)

    def rhs(t, s):
        y, v, zz = s
        F = p["c"] * v + p["k"] * y + zz
        zd = p["alpha"] * v - p["beta"] * (p["gamma"] * abs(v) * zz + p["delta"] * v * abs(zz))
        u = u_of(t)
        acc = (u - F) / p["m"] if kind == "sdof" else -u - F / p["m"]
        return [v, acc, zd]

    n = 300
    t = np.arange(n) / FS
    sol = solve_ivp(rhs, (0, t[-1]), [0, 0, 0], t_eval=t, rtol=1e-11, atol=1e-13,
                    method="DOP853", max_step=1 / FS / 4)
    y, v, zz = sol.y
    st = ms.STRUCTURES[kind](response=response, interpolation=ms.BandLimited())
    if response == "acceleration":
        F = p["c"] * v + p["k"] * y + zz
        ref = -F / p["m"]  # the mass's absolute acceleration
    else:
        ref = y
    rec = ms.Record("r", t, u_of(t), ref)
    # the exact input at every Runge-Kutta stage, not an interpolation: the dynamics alone
    m = 16
    ts = (np.arange((n - 1) * 2 * m + 1)) / (FS * 2 * m)
    fine = u_of(ts)
    inp = list(ms.step_inputs(ms.stack([rec]), st, m))
    inp[0], inp[1], inp[2] = fine[None, 0:-1:2], fine[None, 1::2], fine[None, 2::2]
    pred = np.asarray(jax.vmap(lambda zz_, i: ms.simulate(model, st, zz_, i))(
        jnp.asarray(z[None]), tuple(jnp.asarray(a) for a in inp)))[0]
    assert np.sqrt(np.mean((pred - ref) ** 2)) < 1e-4 * np.sqrt(np.mean(ref ** 2))


# ------------------------------------------------------------------------------ known answer
@pytest.fixture(scope="module")
def bench(model):
    """A short known answer: two noisy periods of 1024 samples in steady state, the fit."""
    return noisy_fit(model, P)


def noisy_fit(model, period: int):
    """Two periods of a multisine of `period` samples in steady state, 4e-6 m of noise, and
    the structure's fit: (structure, record, fit)."""
    st = ms.SDOF(period=period)
    rec = simulated(model, multisine(period, 0), 2, st, label="train")
    noise = 4e-6 * np.random.default_rng(1).standard_normal(rec.n)
    rec = dataclasses.replace(rec, response=rec.response + noise)
    res = ms.fit(model, rec, structure=st, swarm=mrjax.Swarm(n_particles=30, max_generations=60),
                 key=0)
    return st, rec, res


def test_fit_known_answer(model, bench):
    st, rec, res = bench
    z = truth_z(model)
    assert res.rms[0] < 5e-6  # the noise's 4e-6 m, and no more than a little model error
    free = res.lower < res.upper
    err = np.abs(res.z[0] - z)[free] / res.stderr[0][free]
    assert np.all(err < 4), dict(zip(np.array(res.names)[free], err))
    np.testing.assert_allclose(res.z[0], z, rtol=0.03, atol=0.03)
    assert res.status[0] in ("successful", "refined")
    # prediction of another input, noise-free: the error is a fraction of the noise
    test = simulated(model, multisine(P, 5), 1, st, label="test")
    pred = res.predict(test)
    assert pred.rms[0] < 2e-6 and pred.fitted == ("train",)
    # fit.json round trip: the same prediction
    back = ms.StructureFit.from_dict(json.loads(res.to_json()))
    np.testing.assert_allclose(back.predict(test).predicted, pred.predicted, rtol=1e-12,
                               atol=1e-15)
    assert back.names == res.names and back.structure == res.structure


def test_posterior_covers_truth(model):
    """The posterior through the engine on a shorter record (two noisy periods of 256 samples:
    every leapfrog step integrates the structure, so the suite keeps it small), ChEES's
    4 chains in lockstep (one batch); its 99 % intervals cover the truth."""
    _, rec, res = noisy_fit(model, 256)
    post = mrjax.posterior(res, rec, sampler=mrjax.Sampler(
        draws=100, warmup=100, chains=4, continuations=0, kernel=mrjax.bayes.ChEES()), key=0)
    z = truth_z(model)
    for j, name in enumerate(res.names):
        lo, hi = post.interval(name, 0.99)[0]
        assert lo <= z[j] <= hi, (name, lo, z[j], hi)


# ------------------------------------------------------------------------------ bad input
def test_bad_records(model):
    t = np.arange(100) / FS
    with pytest.raises(InputError, match="non-finite"):
        ms.Record("r", t, np.ones(100), np.r_[np.nan, np.zeros(99)])
    with pytest.raises(InputError, match="uniform sample rate"):
        ms.Record("r", np.r_[t[:50], t[50:] + 0.1], np.ones(100), np.zeros(100))
    short = ms.Record("s", t[:5], np.ones(5), np.zeros(5))
    with pytest.raises(InputError, match="too few"):
        ms.fit(model, short, swarm=None)
    with pytest.raises(InputError, match="whole periods"):
        ms.fit(model, ms.Record("r", t, np.ones(100), np.zeros(100)),
               structure=ms.SDOF(period=64), swarm=None)
    with pytest.raises(InputError, match="give the mass"):
        ms.fit(model, ms.Record("r", t, np.ones(100), np.zeros(100)),
               structure=ms.BaseExcited(), swarm=None)


def _csv(path, rec, input_col="force_N", response_col="displacement_m"):
    rows = [f"time_s,{input_col},{response_col}"]
    rows += [f"{a:.17g},{b:.17g},{c:.17g}" for a, b, c in zip(rec.t, rec.input, rec.response)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_cli(model, bench, tmp_path):
    st, rec, res = bench
    train = _csv(tmp_path / "train.csv", rec)
    test = _csv(tmp_path / "test.csv", simulated(model, multisine(P, 5), 1, st))
    code, out, err = run_cli(["fit", train, "--structure", "sdof", "--periodic", str(P),
                              "--model", SPEC, "--particles", 30, "--max-generations", 60,
                              "--out", tmp_path / "fit", "--no-plots"])
    assert code == 0, err
    doc = json.loads((tmp_path / "fit" / "fit.json").read_text())
    assert doc["kind"] == "structure" and doc["structure"]["period"] == P
    got = doc["records"][0]["params"]
    for name, v in TRUE.items():
        assert abs(got[name] - v) <= 0.03 * abs(v) + 0.03, (name, got[name], v)
    code, out, err = run_cli(["predict", "--fit", tmp_path / "fit", test, "--periodic", str(P),
                              "--out", tmp_path / "pred"])
    assert code == 0, err
    pj = json.loads((tmp_path / "pred" / "predict.json").read_text())
    assert pj["records"][0]["rms_m"] < 2e-6
    head = (tmp_path / "pred" / "predicted.csv").read_text().splitlines()[0]
    assert head == "condition,time_s,measured,predicted"
    assert (tmp_path / "pred" / "predict_response.png").stat().st_size > 0


@pytest.mark.parametrize("case,needle", [
    ("no_input", "no input column force_<unit>"),
    ("nonfinite", "non-finite"),
    ("short", "too few"),
])
def test_cli_bad_input(tmp_path, case, needle):
    t = np.arange(200) / FS
    rec = ms.Record("r", t, np.sin(t * 60), 1e-3 * np.sin(t * 60))
    if case == "no_input":
        path = _csv(tmp_path / "d.csv", rec, input_col="current_A")
    elif case == "nonfinite":
        path = _csv(tmp_path / "d.csv", rec)
        lines = path.read_text().splitlines()
        lines[5] = lines[5].rsplit(",", 1)[0] + ",nan"
        path.write_text("\n".join(lines) + "\n")
    else:
        path = _csv(tmp_path / "d.csv", ms.Record("r", t[:6], rec.input[:6], rec.response[:6]))
    code, out, err = run_cli(["fit", path, "--structure", "sdof", "--model", SPEC,
                              "--out", tmp_path / "o"])
    assert code == 2
    assert err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "o" / "fit.json").exists()
