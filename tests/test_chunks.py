"""Thousands of tests: the condition axis in chunks (`mrjax.fitting.fit_in_chunks`), the
journal and `--resume`, the memory options and `--devices` on the command line."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest
from helpers import SWARM_RTOL, assert_same_polish, assert_same_swarms

import mrjax
from mrjax._io import MANIFEST
from mrjax.cli import main
from mrjax.data import make_batch, paper_grid
from mrjax.engine import row_keys as condition_keys
from mrjax.fitting import FitResult, parse_memory, plan_chunks

FIELDS = ("labels", "current", "frequency", "amplitude", "n_samples", "theta", "rms", "nrmse",
          "pso_rms", "generations", "stopped_by_criterion", "history", "polish_steps",
          "polish_status", "stderr", "ci95", "corr", "identifiable", "estimated")


def assert_identical(a: FitResult, b: FitResult) -> None:
    """Every per-condition field equal bit for bit (NaN where NaN)."""
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        if isinstance(x, tuple):
            assert x == y, f
        else:
            assert x.dtype == y.dtype and x.shape == y.shape, f
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), (f, x, y)


def assert_same_to_rounding(a: FitResult, b: FitResult) -> None:
    """One fit computed in other chunks: the inputs' fields equal, the swarm's and the
    polish's results equal to rounding (`helpers.assert_same_swarms` / `assert_same_polish`:
    a stop within rounding of its threshold may move; polish step counts are not compared).
    Tests fitted in the wrong chunk, with another's key or view, differ by percents."""
    for f in ("labels", "current", "frequency", "amplitude", "n_samples", "estimated"):
        x, y = getattr(a, f), getattr(b, f)
        assert x == y if isinstance(x, tuple) else np.array_equal(x, y, equal_nan=True), f
    assert_same_swarms(a.generations, b.generations, a.history, b.history)
    if a.method == "pso":
        same = a.generations == b.generations
        np.testing.assert_allclose(a.theta[same], b.theta[same], rtol=SWARM_RTOL)
        np.testing.assert_allclose(a.rms[same], b.rms[same], rtol=SWARM_RTOL)
    else:
        assert_same_polish(a.rms, b.rms, a.theta, b.theta)
        np.testing.assert_allclose(a.stderr, b.stderr, rtol=1e-3)


#: Options of every kwok fit here (shared compiled programs). Many particles make small chunks
#: possible (see `mrjax.fitting.MIN_CHUNK_ELEMENTS`): chunks of 12 of these 30 tests.
KWOK_SWARM = mrjax.Swarm(n_particles=200, max_generations=30, restarts=2)
KWOK = dict(swarm=KWOK_SWARM, key=3)
#: The same swarm alone (no polish).
KWOK_PSO = dict(KWOK, polish=None)
#: The smallest chunks allowed.
SMALLEST = mrjax.Chunks(size=1)


@pytest.fixture(scope="module")
def kwok30():
    """30 tanh tests of 500 samples."""
    return paper_grid(currents=np.linspace(0, 2, 15), motions=((1.0, 0.004), (1.0, 0.008)),
                      cycles=1, sample_rate=500.0)


@pytest.fixture(scope="module")
def dahl30():
    """30 Dahl tests: 12 of 1,000 samples, then 18 of 500 (the later chunks alone would have
    a shorter swarm view than the whole batch)."""
    dahl = mrjax.models.get("dahl")
    theta = np.array([2000.0, 1000.0, 500.0, 300.0, 10.0])
    conds = []
    for f, n in ((1.0, 12), (2.0, 18)):
        g = paper_grid(dahl, theta, currents=np.linspace(0, 2, n), motions=((f, 0.006),),
                       cycles=1, sample_rate=1000.0, seed=int(f))
        conds += g.conditions()
    return make_batch(conds)


def test_parse_memory():
    assert parse_memory("8GB") == parse_memory("8 GB") == parse_memory("8g") == 8 * 10**9
    assert parse_memory("512MB") == 512 * 10**6 and parse_memory("1.5GiB") == 3 * 2**29
    assert parse_memory(1000) == 1000 and parse_memory("2e9") == 2 * 10**9
    for bad in ("lots", "8 parsecs", "-1GB", "0", "", True, [1]):
        with pytest.raises(mrjax.InputError):
            parse_memory(bad)
    assert mrjax.fitting.available_memory() > 0


def test_chunk_plan_of_a_fit(kwok30):
    """What a fit would run: 30 tests, 2 restarts x 200 particles: chunks of at least 11
    tests (4,097 rows x particles), in vectors of 4 (float64)."""
    plan = mrjax.fitting.chunk_plan("kwok", kwok30, swarm=KWOK_SWARM, chunks=SMALLEST)
    assert (plan.size, plan.n_chunks) == (12, 3)
    assert mrjax.fitting.chunk_plan("kwok", kwok30, swarm=KWOK_SWARM).size == 32  # aligned
    plan = mrjax.fitting.chunk_plan("kwok", kwok30, chunks=mrjax.Chunks(max_memory="8GB"))
    assert plan.n_chunks == 1 and 0.5e6 < plan.per_condition < 5e6
    with pytest.raises(TypeError, match="max_memroy"):
        mrjax.Chunks(max_memroy="8GB")


def test_plan_chunks():
    # the budget left after the resident part, per condition; balanced chunks
    p = plan_chunks(10_000, per_condition=3_000_000, resident=2 * 10**9, budget=8 * 10**9)
    assert (p.size, p.n_chunks) == (2000, 5) and p.bounds(4) == (8000, 10_000)
    p = plan_chunks(10_000, per_condition=3_400_000, resident=2 * 10**9, budget=8 * 10**9)
    assert (p.size, p.n_chunks) == (1667, 6) and p.bounds(5) == (8335, 10_000)
    assert plan_chunks(36, per_condition=10**6, budget=10**9).n_chunks == 1
    # a multiple of devices x lanes, never below the minimum, a given size
    p = plan_chunks(13, per_condition=1, size=3, minimum=5, devices=2)
    assert p.size == 6 and [p.bounds(j) for j in range(p.n_chunks)] == [(0, 6), (6, 12), (12, 13)]
    p = plan_chunks(30, per_condition=1, size=1, minimum=11, lanes=4)
    assert p.size == 12 and p.n_chunks == 3
    assert plan_chunks(20, per_condition=1, size=1, minimum=9).size == 9
    # one chunk: the batch as it is when no other chunking is possible, else aligned
    assert plan_chunks(5, per_condition=1, size=2, minimum=9, lanes=4).size == 5
    assert plan_chunks(30, per_condition=1, budget=100, minimum=11, lanes=4).size == 32
    with pytest.raises(mrjax.InputError, match="too small.*at least"):
        plan_chunks(100, per_condition=10**6, resident=10**9, budget=10**9 + 10)
    assert plan_chunks(100, per_condition=10**6, resident=10**9, budget=10**9,
                       strict=False).size == 1
    with pytest.raises(mrjax.InputError):
        plan_chunks(10, per_condition=1, size=0)


def test_condition_keys_do_not_depend_on_the_count():
    key = jax.random.key(7)
    many, few = condition_keys(key, 12), condition_keys(key, 5)
    assert np.array_equal(jax.random.key_data(many)[:5], jax.random.key_data(few))
    assert condition_keys(many, 12) is many
    with pytest.raises(mrjax.InputError, match="12 keys for 5"):
        condition_keys(many, 5)


@pytest.mark.parametrize("model", ["kwok", "dahl"])
def test_chunked_equals_unchunked(model, kwok30, dahl30):
    """The same fit: every condition has its own stream (restarts: copy k of condition i at row
    k*C + i of the whole batch's keys), the same padded record and view length and the same
    place in a vector of rows; Dahl is an ODE model whose integration never depends on the
    batch (one exact step per sample), fitted here by its swarm alone (on its view). Bit for
    bit on the x86-64 CPUs measured (Intel Xeon, AMD EPYC); asserted to rounding, since the
    chunk and the whole batch are different compiled shapes, whose sums another CPU may
    vectorise differently."""
    if model == "kwok":  # 3 chunks
        batch, options = kwok30, dict(KWOK, polish=mrjax.Polish(max_steps=30))
    else:  # 2 chunks
        batch, options = dahl30, dict(swarm=mrjax.Swarm(n_particles=200, max_generations=6),
                                      polish=None, key=3)
    one = mrjax.fit(model, batch, **options)
    chunked = mrjax.fit(model, batch, chunks=SMALLEST, **options)
    assert_same_to_rounding(one, chunked)
    assert set(chunked.timings) >= {"prepare", "swarm", "start", "total"}


def test_progress_bar_counts_chunks_and_conditions(capsys):
    import mrjax.fitting._chunks as chunks

    plan = plan_chunks(10, per_condition=1, size=4)
    bar = chunks._bar(True, plan)
    bar.update(4)
    bar.set_description("chunk 1/3")
    bar.close()
    err = capsys.readouterr().err
    assert "chunk 1/3" in err and "4/10" in err
    assert chunks._bar(True, plan_chunks(10, per_condition=1, size=10)) is None  # one chunk
    assert chunks._bar(None, plan) is None  # not a terminal


def test_state_round_trip_and_concatenate(kwok30):
    res = mrjax.fit("kwok", kwok30, **KWOK_PSO)
    res = FitResult.concatenate([res.subset([0, 1]), res.subset(np.arange(2, 30))])
    back = FitResult.from_state(json.loads(json.dumps(res.to_state())), res.model)
    assert_identical(res, back)
    assert back.to_json() == res.to_json() and back.to_csv() == res.to_csv()
    with pytest.raises(mrjax.InputError, match="model 'kwok'"):
        FitResult.from_state(res.to_state(), mrjax.models.get("dahl"))


def test_budget_too_small_fails_before_any_work(kwok30, tmp_path):
    with pytest.raises(mrjax.InputError, match="memory budget .* too small"):
        mrjax.fit("kwok", kwok30, chunks=mrjax.Chunks(max_memory="10MB"))
    with pytest.raises(mrjax.InputError, match="resume needs a journal"):
        mrjax.fit("kwok", kwok30, chunks=mrjax.Chunks(resume=True))
    (tmp_path / "notes.txt").write_text("mine")  # never deleted as if it were a journal
    with pytest.raises(mrjax.InputError, match="not an mrjax journal"):
        mrjax.fit("kwok", kwok30, chunks=mrjax.Chunks(journal=tmp_path, size=1), **KWOK)
    assert (tmp_path / "notes.txt").read_text() == "mine"


class Interrupt:
    """Replaces the fit of one chunk: fails at call `fail_at` (1-based), counts the calls."""

    def __init__(self, stage, fail_at, exc):
        self.stage, self.fail_at, self.exc, self.calls = stage, fail_at, exc, 0

    def __call__(self, *args, **kwargs):
        self.calls += 1
        if self.calls == self.fail_at:
            raise self.exc
        return self.stage(*args, **kwargs)


def test_journal_resume_in_python(kwok30, tmp_path, monkeypatch):
    import mrjax.fitting._chunks as chunks

    kw = KWOK_PSO
    whole = mrjax.fit("kwok", kwok30, chunks=SMALLEST, **kw)
    journal = tmp_path / "journal"
    written = mrjax.Chunks(size=1, journal=journal)
    resume = mrjax.Chunks(size=1, journal=journal, resume=True)
    stage = Interrupt(chunks.fit_chunk, 2, RuntimeError("power cut"))
    monkeypatch.setattr(chunks, "fit_chunk", stage)
    with pytest.raises(RuntimeError, match="power cut"):
        mrjax.fit("kwok", kwok30, chunks=written, **kw)
    assert sorted(p.name for p in journal.iterdir()) == ["chunk-00001.json", "manifest.json"]
    manifest = json.loads((journal / "manifest.json").read_text())
    assert manifest["n_chunks"] == 3 and manifest["chunk_size"] == 12
    # resume: only the two missing chunks run; the result is the uninterrupted one
    stage = Interrupt(chunks.fit_chunk.stage, 0, None)
    monkeypatch.setattr(chunks, "fit_chunk", stage)
    resumed = mrjax.fit("kwok", kwok30, chunks=resume, **kw)
    assert stage.calls == 2
    assert_identical(whole, resumed)
    # another seed: the journal does not match
    with pytest.raises(mrjax.InputError, match="cannot resume.*other data or options"):
        mrjax.fit("kwok", kwok30, chunks=resume, **dict(kw, key=4))


@pytest.fixture(scope="module")
def csv30(kwok30, tmp_path_factory):
    """The 30 tests as a long CSV."""
    rows = ["condition,current_A,frequency_Hz,amplitude_m,time_s,displacement_m,velocity_m_s,"
            "force_N"]
    for c in kwok30.conditions():
        head = f"{c.label},{c.current!r},{c.frequency!r},{c.amplitude!r}"
        rows += [f"{head},{t!r},{x!r},{v!r},{f!r}"
                 for t, x, v, f in zip(c.t.tolist(), c.x.tolist(), c.xdot.tolist(),
                                       c.force.tolist())]
    path = tmp_path_factory.mktemp("csv") / "tests.csv"
    path.write_text("\n".join(rows) + "\n")
    return path


def _files(d: Path) -> dict[str, bytes]:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_cli_resume_gives_the_same_bytes(csv30, tmp_path, monkeypatch, capsys):
    import mrjax.fitting._chunks as chunks

    argv = [str(csv30), "--model", "kwok", "--method", "pso", "--max-generations", "30",
            "--particles", "200", "--restarts", "2", "--chunk-size", "1", "--no-plots",
            "--seed", "3"]
    assert main(["fit", *argv, "--out", str(tmp_path / "whole")]) == 0
    out = tmp_path / "cut"
    monkeypatch.setattr(chunks, "fit_chunk", Interrupt(chunks.fit_chunk, 2, KeyboardInterrupt()))
    assert main(["fit", *argv, "--out", str(out)]) == 130  # interrupted after the first chunk
    assert sorted(_files(out)) == [".mrjax-journal/chunk-00001.json",
                                   ".mrjax-journal/manifest.json"]
    # other options: refused in one line, nothing touched
    capsys.readouterr()
    before = _files(out)
    assert main(["fit", *argv[:-1], "4", "--out", str(out), "--resume"]) == 2
    err = [x for x in capsys.readouterr().err.strip().splitlines() if "error" in x]
    assert len(err) == 1 and err[0].startswith("mrjax: error: cannot resume")
    assert _files(out) == before
    stage = Interrupt(chunks.fit_chunk.stage, 0, None)
    monkeypatch.setattr(chunks, "fit_chunk", stage)
    assert main(["fit", *argv, "--out", str(out), "--resume"]) == 0
    assert stage.calls == 2  # only the missing chunks
    assert _files(out) == _files(tmp_path / "whole")  # byte for byte; the journal is gone
    assert sorted(_files(out)) == [MANIFEST, "fit.csv", "fit.json"]


def test_cli_memory_and_devices_options(csv30, tmp_path, capsys):
    assert main(["fit", str(csv30), "--model", "kwok", "--memory", "lots",
                 "--out", str(tmp_path / "o")]) == 2
    assert "memory size 'lots'" in capsys.readouterr().err
    assert main(["fit", str(csv30), "--model", "kwok", "--memory", "1MB",
                 "--out", str(tmp_path / "o")]) == 2
    assert "too small" in capsys.readouterr().err and not (tmp_path / "o").exists()
    assert main(["fit", str(csv30), "--model", "kwok", "--devices", "0",
                 "--out", str(tmp_path / "o")]) == 2
    capsys.readouterr()
    assert main(["fit", str(csv30), "--model", "kwok", "--devices", "5",
                 "--out", str(tmp_path / "o")]) == 2
    assert "devices=5: 1 device(s) available" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_cli_devices_two_cpu_devices(csv30, tmp_path):
    """`mrjax fit --devices 2` on two forced CPU devices gives the one-device result."""
    script = textwrap.dedent("""
        import sys
        import jax
        from mrjax.cli import main
        assert len(jax.devices()) == 2, jax.devices()
        csv, out = sys.argv[1], sys.argv[2]
        for n in ("1", "2"):
            code = main(["fit", csv, "--model", "kwok", "--method", "pso", "--particles", "200",
                         "--generations", "5", "--no-plots", "--chunk-size", "1", "--seed", "5",
                         "--devices", n, "--out", f"{out}/d{n}"])  # 2 chunks
            assert code == 0, code
    """)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu", MRJAX_CACHE_DIR="off")
    p = subprocess.run([sys.executable, "-c", script, str(csv30), str(tmp_path)],
                       capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    one, two = (json.loads((tmp_path / d / "fit.json").read_text()) for d in ("d1", "d2"))
    assert [c["label"] for c in one["conditions"]] == [c["label"] for c in two["conditions"]]
    for a, b in zip(one["conditions"], two["conditions"]):
        # a fixed generation count and no polish: no count can move
        for k in ("generations", "stopped_by_criterion", "polish_steps", "polish_status"):
            assert a[k] == b[k], (k, a[k], b[k])
        # equal to rounding (bit for bit on the CPUs measured, except the swarm's own RMS and
        # the std-errors: XLA tiles their sums for the local shape, see test_parallel.py)
        np.testing.assert_allclose(list(a["params"].values()), list(b["params"].values()),
                                   rtol=SWARM_RTOL)
        for k in ("rms_N", "nrmse", "pso_rms_N"):
            np.testing.assert_allclose(a[k], b[k], rtol=SWARM_RTOL, err_msg=k)
        np.testing.assert_allclose(list(a["stderr"].values()), list(b["stderr"].values()),
                                   rtol=1e-9)


def test_compare_passes_the_memory_options(kwok30):
    with pytest.raises(mrjax.InputError, match="memory budget .* too small"):  # before any fit
        mrjax.compare(kwok30, models=["bingham"], held_out=None,
                      chunks=mrjax.Chunks(max_memory="1MB"))
