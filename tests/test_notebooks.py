"""The notebooks run top to bottom in their quick mode, on the CPU, and are committed clean.

Each notebook is executed by nbclient in a fresh `python3` kernel with `MRJAX_NB_QUICK=1`,
`JAX_PLATFORMS=cpu` and `MPLBACKEND=Agg`. The real-data notebook runs on the UTFSM tests when
they are present (see `conftest.utfsm_dir`) and must skip its analysis cleanly when they are
not: that path is tested with `MRJAX_DATA` pointing at an empty directory.
"""

import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
NAMES = ("01_quickstart.ipynb", "02_real_data.ipynb", "03_pso_vs_polish.ipynb",
         "04_your_own_model.ipynb")
CELL_TIMEOUT_S = 600


def execute(name: str, env: dict[str, str]) -> nbformat.NotebookNode:
    """Run notebook `name` (from its own directory) in quick mode; return it with outputs."""
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    old = dict(os.environ)
    os.environ.update({"MRJAX_NB_QUICK": "1", "JAX_PLATFORMS": "cpu", "MPLBACKEND": "Agg",
                       **env})
    try:  # the kernel inherits this process's environment
        NotebookClient(nb, kernel_name="python3", timeout=CELL_TIMEOUT_S,
                       resources={"metadata": {"path": str(NOTEBOOKS)}}).execute()
    finally:
        os.environ.clear()
        os.environ.update(old)
    return nb


def text_of(nb: nbformat.NotebookNode) -> str:
    """Everything the code cells printed (stdout/stderr streams and text results)."""
    out = []
    for cell in nb.cells:
        for o in cell.get("outputs", []):
            if o.get("output_type") == "stream":
                out.append(o.get("text", ""))
            elif "data" in o:
                out.append(o["data"].get("text/plain", ""))
    return "\n".join(out)


@pytest.mark.parametrize("name", NAMES)
def test_committed_without_outputs(name):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    nbformat.validate(nb)
    assert nb.metadata["kernelspec"]["name"] == "python3"
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None, name
    assert "MRJAX_NB_QUICK" in "".join(c.source for c in nb.cells)


def test_quickstart():
    out = text_of(execute("01_quickstart.ipynb", {}))
    assert "quick=True" in out
    assert "median RMS" in out and "generalized model" in out
    assert "error" in out and "paper" in out


def test_real_data(utfsm):
    out = text_of(execute("02_real_data.ipynb", {"MRJAX_DATA": str(utfsm)}))
    assert f"UTFSM data: {utfsm}" in out
    assert "held-out tests" in out and "median NRMSE" in out
    assert "median estimate" in out  # the inverse model ran


def test_real_data_skips_without_data(tmp_path):
    empty = tmp_path / "no-data-here"
    empty.mkdir()
    nb = execute("02_real_data.ipynb", {"MRJAX_DATA": str(empty)})
    out = text_of(nb)
    assert "UTFSM data not found" in out
    assert "held-out tests" not in out
    errors = [o for c in nb.cells for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors


def test_pso_vs_polish():
    out = text_of(execute("03_pso_vs_polish.ipynb", {}))
    for method in ("paper's swarm", "separable swarm + LM", "LM alone"):
        assert method in out
    assert "stuck on" in out


def test_your_own_model():
    out = text_of(execute("04_your_own_model.ipynb", {}))
    assert "derived: parameter-free regressors ('c', 'k', 'f0')" in out
    assert "one line: model 'oops': parameter 'beta' is declared linear but the force" in out
    assert "k = {'kwok': 7, 'asym_tanh': 8}" in out
    assert "same force: largest difference" in out and "asym_tanh generalized" in out
    assert "registered: True" in out and "'kind': 'file'" in out
