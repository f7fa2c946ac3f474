"""Shared test fixtures: float64, CPU, and the optional UTFSM data directory."""

import os
import warnings
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("MPLBACKEND", "Agg")
# the `mrjax` command's persistent compilation cache stays off in tests (tested on its own)
os.environ.setdefault("MRJAX_CACHE_DIR", "off")

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)


def utfsm_dir() -> Path | None:
    """The UTFSM data (`helpers.default_data_dir`: $MRJAX_DATA, or ../shared/data/utfsm beside
    the repository) if it holds the tests, else None."""
    from helpers import default_data_dir

    d = default_data_dir()
    return d.resolve() if d is not None and d.is_dir() and any(d.glob("*A.txt")) else None


#: Most test processes of `pytest -n auto` (`pytest-xdist`, set in `pyproject.toml`): each
#: compiles its own programs and holds its own caches.
MAX_WORKERS = 4


def pytest_xdist_auto_num_workers(config) -> int:
    """Processes of `-n auto`: one per core this process may run on, at most `MAX_WORKERS`
    (a test file runs whole in one of them, `--dist loadfile`: its fixtures are made once)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(cores or 1, MAX_WORKERS))


@pytest.fixture(autouse=True)
def _release_compiled_code():
    """The suite compiles thousands of programs in one process; XLA:CPU maps each one's code
    into memory, and past Linux's `vm.max_map_count` the next compilation crashes the process.
    Empty JAX's caches before a test when the process holds more than 40 % of the limit (the
    engine does so at 60 %, see `mrjax._runtime`)."""
    from mrjax._runtime import release_code

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        release_code(share=0.4)
    yield


@pytest.fixture(scope="session")
def utfsm():
    d = utfsm_dir()
    if d is None:
        pytest.skip("UTFSM data not found (set MRJAX_DATA or place ../shared/data/utfsm)")
    return d
