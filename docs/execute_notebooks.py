"""Write the executed copies of the notebooks that the documentation site renders.

    python docs/execute_notebooks.py            # every notebook (minutes on a 2-core CPU)
    python docs/execute_notebooks.py quickstart # those whose copy's name contains a word

`notebooks/` keeps the notebooks without outputs (the test suite runs them in their quick mode,
`tests/test_notebooks.py`); the site shows them with the outputs of a full run, executed here
once rather than at every build, so that `mkdocs build` stays a matter of seconds in CI.
`tests/test_readme.py` checks that each copy has the cells of its source: after editing a
notebook, run this again.

Each notebook runs in a fresh `python3` kernel from `notebooks/`, on the CPU, in full mode
(`MRJAX_NB_QUICK` unset); the real-data notebook reads the UTFSM tests from `$MRJAX_DATA` or
`../shared/data/utfsm` (without them it says so and skips its analysis). Volatile metadata
(execution times, kernel versions) is dropped so that a re-run changes only what it shows.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Source notebook -> executed copy (paths relative to the repository).
NOTEBOOKS = {
    "notebooks/01_quickstart.ipynb": "docs/tutorials/quickstart.ipynb",
    "notebooks/02_real_data.ipynb": "docs/tutorials/real-data.ipynb",
    "notebooks/03_pso_vs_polish.ipynb": "docs/explanation/pso-vs-polish.ipynb",
    "notebooks/04_your_own_model.ipynb": "docs/tutorials/your-own-model.ipynb",
}
CELL_TIMEOUT_S = 1800


def _clean(nb) -> None:
    """Drop what changes from run to run without changing what the page shows."""
    for cell in nb.cells:
        cell.metadata.pop("execution", None)
    nb.metadata.pop("widgets", None)
    nb.metadata.get("language_info", {}).pop("version", None)


def execute(source: str, copy: str) -> float:
    """Run `source` top to bottom and write it, with its outputs, to `copy`; the seconds."""
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(ROOT / source, as_version=4)
    env = {"JAX_PLATFORMS": "cpu", "MPLBACKEND": "module://matplotlib_inline.backend_inline"}
    old = dict(os.environ)
    os.environ.update(env)
    os.environ.pop("MRJAX_NB_QUICK", None)
    start = time.perf_counter()
    try:  # the kernel inherits this process's environment
        NotebookClient(nb, kernel_name="python3", timeout=CELL_TIMEOUT_S,
                       resources={"metadata": {"path": str(ROOT / "notebooks")}}).execute()
    finally:
        os.environ.clear()
        os.environ.update(old)
    _clean(nb)
    nbformat.write(nb, ROOT / copy)
    return time.perf_counter() - start


def main(words: list[str]) -> None:
    for source, copy in NOTEBOOKS.items():
        if words and not any(w in copy for w in words):
            continue
        print(f"{source} -> {copy}: {execute(source, copy):.0f} s", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
