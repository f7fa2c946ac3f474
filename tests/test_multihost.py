"""The multi-host recipe, run: two local processes, one swarm sharded over both.

`examples/multihost.py` (the README's recipe, verbatim) is started twice with
`jax.distributed.initialize(coordinator_address="127.0.0.1:PORT", num_processes=2,
process_id=i)` and CPU collectives over loopback TCP (gloo); each process holds one CPU device,
so the condition axis is split between the processes. The gathered result must equal a
single-process `mrjax.fit` of the same batch with the same key to rounding (bit for bit on the
machines measured; the per-condition sums are tiled for the local shape, so not on every CPU).
"""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from helpers import SWARM_RTOL, assert_same_swarms

import mrjax

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "examples" / "multihost.py"
#: Hard limit on the two processes together [s].
TIMEOUT = 60
#: A two-process job without mrjax: can this platform run CPU processes with collectives?
_PROBE = """
import sys, jax
jax.config.update("jax_cpu_collectives_implementation", "gloo")
jax.distributed.initialize(coordinator_address=sys.argv[1], num_processes=2,
                           process_id=int(sys.argv[2]))
import numpy as np
from jax.experimental.multihost_utils import process_allgather
assert process_allgather(np.array([int(sys.argv[2])])).ravel().tolist() == [0, 1]
jax.distributed.shutdown()
"""


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _recipe(text: str) -> str:
    """The lines between the recipe markers, dedented."""
    block = text.split("# --- recipe ---\n", 1)[1].split("# --- end of recipe ---", 1)[0]
    lines = block.splitlines()
    indent = min(len(x) - len(x.lstrip()) for x in lines if x.strip())
    return "\n".join(x[indent:] for x in lines).strip()


def test_readme_shows_the_recipe_the_test_runs():
    recipe = _recipe(SCRIPT.read_text())
    assert "jax.distributed.initialize" in recipe and "process_allgather" in recipe
    assert recipe in (REPO / "docs" / "how-to" / "devices.md").read_text()


def _run_two(args: list[str], env: dict) -> tuple[list[int], list[str]]:
    """Start `python ARGS... ADDRESS RANK-args` twice (ranks 0 and 1) on a free loopback port;
    returns their exit codes and stderr. Fails the test past `TIMEOUT`."""
    address = f"127.0.0.1:{_free_port()}"
    procs = [subprocess.Popen([sys.executable, *[a.format(address=address, rank=r) for a in args]],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for r in range(2)]
    errors = []
    try:
        for p in procs:
            errors.append(p.communicate(timeout=TIMEOUT)[1])
    except subprocess.TimeoutExpired:
        pytest.fail(f"two processes did not finish within {TIMEOUT} s: {args}")
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    return [p.returncode for p in procs], errors


def test_two_processes_equal_one(tmp_path):
    env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS="",
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    codes, errors = _run_two(["-c", _PROBE, "{address}", "{rank}"], env)
    if any(codes):
        pytest.skip("this platform cannot run two JAX CPU processes with collectives: "
                    + " ".join(errors[0].strip().splitlines()[-1:]))
    codes, errors = _run_two([str(SCRIPT), "--coordinator", "{address}", "--num-processes", "2",
                              "--process-id", "{rank}", "--out", str(tmp_path / "rank{rank}.json")],
                             env)
    assert not any(codes), "\n".join(e[-2000:] for e in errors)
    docs = [json.loads((tmp_path / f"rank{r}.json").read_text()) for r in range(2)]
    for rank, d in enumerate(docs):
        assert d["process_id"] == rank
        # one device per process, the batch split over both
        assert d["n_devices"] == 2 and d["n_local_devices"] == 1 and d["n_devices_of_x"] == 2
    assert docs[0]["theta"] == docs[1]["theta"] and docs[0]["rms"] == docs[1]["rms"]

    batch = mrjax.data.paper_grid(currents=(0.0, 0.5, 1.0, 2.0), motions=((1.0, 0.008),),
                                  cycles=1, sample_rate=500.0)
    one = mrjax.fit("kwok", batch, polish=None, key=jax.random.key(0))
    theta = np.asarray(docs[0]["theta"])
    # The same swarms to rounding: XLA tiles the per-condition sums for the local shape (2
    # conditions per process here), as on several devices of one process (test_parallel.py),
    # so the fitness agrees to ~1e-13 and a stop within rounding of its threshold may move
    # (`helpers.assert_same_swarms`). A process fitting another's conditions, or a key reused,
    # differs from the first generation.
    assert_same_swarms(docs[0]["generations"], one.generations, np.array(docs[0]["history"]),
                       one.history, theta, one.theta)
    same = np.equal(docs[0]["generations"], one.generations)
    np.testing.assert_allclose(np.asarray(docs[0]["rms"])[same], one.pso_rms[same],
                               rtol=SWARM_RTOL)
