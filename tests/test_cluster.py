"""Fits on a Dask cluster (`mrjax.Chunks(cluster=...)`, `mrjax fit --cluster`): a real
`distributed.LocalCluster` of two worker processes gives the one-process fit.csv byte for
byte, finishes identically when a worker is SIGKILLed mid-chunk, and names the tests of a
chunk whose data went bad while the other chunks stay in the journal.

The data: 30 tanh tests in three Parquet files of 12, 12 and 6 tests, fitted in chunks of 12
(the smallest chunk of 2 x 200 particles), so that each file is one chunk. The one-process
reference runs first, in its own process, with a persistent compilation cache that the
workers share: they load its compiled programs instead of compiling them again."""

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from helpers import run_cli

import mrjax
from mrjax.data import Source, load, load_batch, paper_grid, to_frame

distributed = pytest.importorskip("distributed")

#: `mrjax fit` options of every fit here (the CLI's defaults otherwise: swarm, polish, retry
#: from the neighbours' optima, std-errors).
OPTIONS = ["--model", "kwok", "--particles", "200", "--max-generations", "30", "--restarts",
           "2", "--seed", "3", "--chunk-size", "1", "--no-plots"]
#: The same fit in Python.
PYTHON = dict(swarm=mrjax.Swarm(n_particles=200, max_generations=30, restarts=2), key=3)
#: The three files and the tests of each.
FILES = {"a.parquet": slice(0, 12), "b.parquet": slice(12, 24), "c.parquet": slice(24, 30)}


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """The data folder, the one-process reference fit.csv, and the cluster: (folder, bytes,
    cluster), the reference computed while the workers start."""
    root = tmp_path_factory.mktemp("cluster")
    conds = paper_grid(currents=np.linspace(0, 2, 15), motions=((1.0, 0.004), (1.0, 0.008)),
                       cycles=1, sample_rate=500.0).conditions()
    data = root / "data"
    data.mkdir()
    for name, part in FILES.items():
        to_frame(conds[part]).to_parquet(data / name, index=False)
    cache = {"JAX_COMPILATION_CACHE_DIR": str(root / "xla"),
             "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0", "JAX_PLATFORMS": "cpu"}
    one = subprocess.Popen([sys.executable, "-m", "mrjax.cli", "fit", str(data), *OPTIONS,
                            "--out", str(root / "one")], env=dict(os.environ, **cache),
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None, env=cache) as cluster:
        _, err = one.communicate(timeout=600)
        assert one.returncode == 0, err[-3000:]
        yield data, (root / "one" / "fit.csv").read_bytes(), cluster


def test_cluster_fit_is_the_one_process_fit(setup, tmp_path):
    """`mrjax fit --cluster`: the workers read their chunks from the Parquet files (the
    check, the fit, the retry with the std-errors: one task per chunk each); same fit.csv."""
    data, reference, cluster = setup
    code, _, err = run_cli(["fit", data, *OPTIONS, "--cluster", cluster.scheduler_address,
                            "--out", tmp_path / "c"])
    assert code == 0, err
    assert "chunk by chunk by the cluster's workers" in err
    assert (tmp_path / "c" / "fit.csv").read_bytes() == reference


def test_a_worker_killed_mid_chunk(setup):
    """An in-memory batch (scattered once to every worker): one worker SIGKILLed while it
    fits a chunk; the scheduler runs the chunk again on a worker, and the fit is the same."""
    data, reference, cluster = setup
    batch = load_batch(data)
    with distributed.Client(cluster, set_as_default=False) as client:
        pids = client.run(os.getpid)
        killed: list[int] = []

        def kill_one_that_fits():
            for _ in range(6000):
                busy = client.run(lambda dask_worker: [
                    str(ts.key) for ts in dask_worker.state.executing])
                for address, keys in busy.items():
                    if any(k.startswith("mrjax-fit-part") for k in keys):
                        os.kill(pids[address], signal.SIGKILL)
                        killed.append(pids[address])
                        return
                time.sleep(0.05)

        killer = threading.Thread(target=kill_one_that_fits, daemon=True)
        killer.start()
        res = mrjax.fit("kwok", batch, chunks=mrjax.Chunks(size=1, cluster=client), **PYTHON)
        killer.join(timeout=10)
        assert killed, "no worker was killed"
        assert killed[0] not in client.run(os.getpid).values()  # restarted by its nanny
    assert res.to_csv().encode() == reference


def test_a_bad_chunk_names_its_tests_and_the_rest_is_kept(setup, tmp_path, monkeypatch):
    """b.parquet changes after the check (the force of one test): its chunk fails with its
    tests named in one line (exit 2), the other two chunks are in the journal; restored,
    `--resume` fits it alone and gives the one-process fit.csv."""
    import mrjax.fitting._chunks as chunks

    data, reference, cluster = setup
    bad = data / "b.parquet"
    original = bad.read_bytes()
    checked = chunks.layout

    def check_then_change(*args, **kwargs):
        out = checked(*args, **kwargs)
        frame = to_frame(load(bad))
        frame.loc[0, "force_N"] += 1.0
        frame.to_parquet(bad, index=False)
        return out

    monkeypatch.setattr(chunks, "layout", check_then_change)
    argv = ["fit", data, *OPTIONS, "--cluster", cluster.scheduler_address, "--out",
            tmp_path / "o"]
    try:
        code, _, err = run_cli(argv)
    finally:
        bad.write_bytes(original)
    assert code == 2
    lines = [x for x in err.splitlines() if "error" in x]
    first = load(data)[12].label
    assert len(lines) == 1 and "chunk 2 of 3" in lines[0] and repr(first) in lines[0], err
    assert "changed in its file" in lines[0] and "resume" in lines[0]
    journal = sorted(p.name for p in (tmp_path / "o" / ".mrjax-journal").iterdir())
    assert journal == ["chunk-00001.json", "chunk-00003.json", "manifest.json"]
    monkeypatch.setattr(chunks, "layout", checked)
    code, _, err = run_cli(argv + ["--resume"])
    assert code == 0, err
    assert (tmp_path / "o" / "fit.csv").read_bytes() == reference


#: A model in a file of its own (its module, `mrjax_user_mine_<sha>`, exists in this process
#: only).
MINE = """
import jax.numpy as jnp
from mrjax.models import Model, Parameter

def tanh_force(p, x, xdot, s):
    return p.alpha * jnp.tanh(p.beta * xdot)

Mine = Model("mine_tanh", [Parameter("alpha", "N", 0.0, 2500.0, linear=True),
                           Parameter("beta", "s/m", 1.0, 1e4, log=True)], tanh_force)
"""


def test_a_model_from_a_file_travels_to_the_workers(setup, tmp_path):
    """`mrjax fit --model path.py:Name` on a cluster: the file's code goes with the work (the
    workers cannot import its module by name)."""
    from mrjax.fitting._cluster import ClusterPool

    (tmp_path / "mine.py").write_text(MINE)
    model = mrjax.models.get(f"{tmp_path / 'mine.py'}:Mine")
    with distributed.Client(setup[2], set_as_default=False) as client:
        pool = ClusterPool(client)
        work = pool.share({"model": model}, model=model)
        got = dict(pool.map(lambda j, w: (w["model"].name, w["model"].param_names), [0], work,
                            describe=str))
    assert got == {0: ("mine_tanh", ("alpha", "beta"))}


def test_cluster_settings_are_checked(setup, tmp_path):
    """The settings refused in one line; the plan's budget and devices asked of the workers:
    half of a worker's memory limit per thread, their own device count."""
    from mrjax.fitting._cluster import ClusterPool

    with distributed.Client(setup[2], set_as_default=False) as client:
        pool = ClusterPool(client)
        limits = [w["memory_limit"] for w in client.scheduler_info()["workers"].values()]
        assert pool.default_budget() == int(mrjax.fitting.DEFAULT_MEMORY_FRACTION * min(limits))
        assert pool.device_count("all") == 1 and pool.device_count(2) == 2
    with pytest.raises(mrjax.InputError, match="cluster must be"):
        mrjax.Chunks(cluster=5)
    with pytest.raises(mrjax.InputError, match="devices is 'all' or a count"):
        mrjax.Chunks(cluster="tcp://127.0.0.1:1", devices=[object()])
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        code, _, err = run_cli(["fit", setup[0], "--model", "kwok", "--cluster",
                                "tcp://127.0.0.1:9", "--out", tmp_path / "o"])
    assert code == 2
    assert "mrjax: error: cannot reach the Dask scheduler at 'tcp://127.0.0.1:9'" in err


def test_streamed_check_is_a_task_per_group(setup):
    """The check of a streamed fit on the cluster: one task per group, the warnings of the
    checks issued in the client, the view length and digests those of one process."""
    import mrjax.fitting._chunks as chunks
    from mrjax.fitting._cluster import LocalPool, open_pool
    from mrjax.fitting._run import make_run

    data, _, cluster = setup
    model = mrjax.models.get("kwok")
    source = Source.scan(data, keep_bytes=0)
    run = make_run(model, 30, chunks=mrjax.Chunks(size=1, cluster=cluster), polish=None,
                   **PYTHON)
    with open_pool(run.chunks) as pool:
        _, there = chunks.layout(model, source, run, 3, pool, 1)
    _, here = chunks.layout(model, source, run, 3, LocalPool(), 1)
    assert there.view_length == here.view_length and there.labels == here.labels
    assert np.array_equal(there.digests, here.digests) and there.plan == here.plan
