"""Every code block of the README and of the documentation site (`docs/**/*.md`) runs as written.

Each page's blocks are read in order and run in a sandbox folder that holds the files they
name, made here from the tanh model at the paper's parameters (eq 24-29):

- `tests/` and `new_tests/`: UTFSM-style text files (t [s], x [mm], v [mm/s], F [N], named like
  `8mm1Hz0x5A.txt`), the docs' "folder of your tests";
- `random.csv`, `campaign/` and `lab.mat`: the three layouts of the data guide (written by
  the helpers of tests/helpers.py); the TOML blocks are written as the files their first line
  names (`# random.toml`);
- `examples/`: a copy of the repository's, for `--model examples/my_models.py:BoucWen`.

A ```python block is executed in one namespace per page (a page's blocks build on each other);
a ```bash block's `mrjax` commands run through `mrjax.cli.main` (shell globs expanded,
continuation lines joined) and must exit 0; a ```toml block is read as a data spec and loads its
files. A block preceded by `<!-- test_readme: skip (why) -->` (minutes of fitting, several
devices or processes, an install) is not run, but still checked: its Python compiles and uses
no undefined name, and each of its `mrjax` command lines parses. Other blocks (```text, data
samples, outputs) are text.

The site itself is checked here where it is generated: the API pages list every public name of
every public package (`docs/_hooks.py`), the command-line page every command, and the
executed notebooks under `docs/` have the sources of `notebooks/`.
"""

from __future__ import annotations

import ast
import builtins
import contextlib
import glob
import importlib
import importlib.util
import io
import json
import re
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import write_layout_a, write_layout_b, write_layout_c

import mrjax
from mrjax import cli

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md"] + sorted((REPO / "docs").rglob("*.md"))
SKIP = re.compile(r"<!--\s*test_readme:\s*skip\s*\((.+)\)\s*-->")
FENCE = re.compile(r"^(\s*)```(\w*)\s*$")
#: The files each spec file of the docs describes (sandbox names).
SPEC_DATA = {"random.toml": "random.csv", "campaign.toml": "campaign", "lab.toml": "lab.mat"}


def _name(page: Path) -> str:
    return str(page.relative_to(REPO))


def blocks(page: Path) -> list[tuple[int, str, str, bool]]:
    """The fenced blocks of `page`: `(line, language, text, skipped)`. Fences start at column 0
    (an indented one, e.g. in a list, would escape the suite: refused)."""
    lines = page.read_text(encoding="utf-8").splitlines()
    out, k = [], 0
    while k < len(lines):
        m = FENCE.match(lines[k])
        if not m:
            k += 1
            continue
        assert not m.group(1), f"{_name(page)} line {k + 1}: a code fence starts at column 0"
        end = next(j for j in range(k + 1, len(lines)) if lines[j].startswith("```"))
        skipped = k > 0 and bool(SKIP.match(lines[k - 1].strip()))
        out.append((k + 1, m.group(2), "\n".join(lines[k + 1:end]), skipped))
        k = end + 1
    return out


def commands(text: str) -> list[str]:
    """The command lines of a bash block: continuation lines joined, comments dropped."""
    joined = re.sub(r"\\\n\s*", " ", text)
    out = []
    for line in joined.splitlines():
        line = line.split(" #", 1)[0].strip() if not line.lstrip().startswith("#") else ""
        if line:
            out.append(line)
    return out


def names(code: str) -> tuple[set[str], set[str]]:
    """The names a Python block defines (or imports) and those it uses."""
    tree = ast.parse(code)
    defined, used = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            (used if isinstance(node.ctx, ast.Load) else defined).add(node.id)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            defined |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            defined.add(node.name)
        elif isinstance(node, ast.arg):
            defined.add(node.arg)
    return defined, used


def undefined_names(code: str, known: set[str] = frozenset()) -> set[str]:
    """Names a Python block uses but neither defines, imports nor finds in `known` (the names
    of the page's earlier blocks) or the builtins."""
    defined, used = names(code)
    return used - defined - set(known) - set(dir(builtins))


def _ufsm_txt(path: Path, current: float, frequency: float = 1.0, amplitude: float = 0.008,
              seed: int = 0) -> None:
    """A UTFSM-style record (t s, x mm, v mm/s, F N; 2 cycles at 500 Hz) of the tanh model at
    eq 24-29 for `current` [A], with 20 N noise."""
    t, x, v = mrjax.data.sine_excitation(frequency, amplitude, sample_rate=500.0, cycles=2)
    f = np.asarray(mrjax.models.get("kwok").force(mrjax.data.paper_parameters(current), x, v,
                                                  1 / 500.0))
    f = f + 20.0 * np.random.default_rng(seed).standard_normal(f.shape)
    np.savetxt(path, np.column_stack([t, 1e3 * x, 1e3 * v, f]), fmt="%.9g")


def _file_name(current: float) -> str:
    return f"8mm1Hz{f'{current:g}'.replace('.', 'x')}A.txt"


def _spec_name(page: Path, line: int, text: str) -> str:
    name = text.splitlines()[0].lstrip("# ").strip()
    assert name in SPEC_DATA, f"{_name(page)} line {line}: a TOML block names its file"
    return name


@pytest.fixture(scope="module")
def sandbox(tmp_path_factory):
    d = tmp_path_factory.mktemp("docs")
    for folder, currents in (("tests", (0.0, 0.5, 1.0)), ("new_tests", (0.25, 0.75))):
        (d / folder).mkdir()
        for k, i in enumerate(currents):
            _ufsm_txt(d / folder / _file_name(i), i, seed=k)
    write_layout_a(d / "random.csv", n=1000)
    (d / "campaign").mkdir()
    write_layout_b(d / "campaign", n=1000)
    write_layout_c(d / "lab.mat", n=1000)
    shutil.copytree(REPO / "examples", d / "examples")
    for page in PAGES:  # the spec files, before the commands that use them
        for line, lang, text, _ in blocks(page):
            if lang == "toml":
                (d / _spec_name(page, line, text)).write_text(text + "\n")
    return d


def _run_cli(line: str, where: Path) -> tuple[int, str]:
    argv = []
    for word in shlex.split(line)[1:]:
        hits = sorted(glob.glob(str(where / word))) if any(c in word for c in "*?[") else []
        argv += [str(Path(h).relative_to(where)) for h in hits] or [word]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, err.getvalue()


def _python(page: Path, line: int, text: str, skipped: bool, namespace: dict, known: set[str]):
    where = f"{_name(page)} line {line}"
    missing = undefined_names(text, known)
    assert not missing, f"{where}: undefined {missing}"
    code = compile(text, f"{_name(page)}:{line}", "exec")
    known |= names(text)[0]
    if not skipped:
        with contextlib.redirect_stdout(io.StringIO()):
            exec(code, namespace)


def _bash(page: Path, line: int, text: str, skipped: bool, sandbox: Path, parser) -> int:
    where, ran = f"{_name(page)} line {line}", 0
    for cmd in commands(text):
        if not cmd.startswith("mrjax "):
            assert skipped, f"{where}: only `mrjax` commands run here: {cmd!r}"
            continue
        if skipped:
            with contextlib.redirect_stderr(io.StringIO()):
                parser.parse_args(shlex.split(cmd)[1:])  # SystemExit if not
            continue
        code, err = _run_cli(cmd, sandbox)
        assert code == 0, f"{where}: {cmd}\n{err}"
        ran += 1
    return ran


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the sandbox data's velocity notes
@pytest.mark.parametrize("page", PAGES, ids=_name)
def test_blocks_run_as_written(page, sandbox, monkeypatch):
    monkeypatch.chdir(sandbox)
    namespace, known = {"__name__": "__docs__"}, set()
    parser = cli.build_parser()
    for line, lang, text, skipped in blocks(page):
        if lang == "python":
            _python(page, line, text, skipped, namespace, known)
        elif lang == "bash":
            _bash(page, line, text, skipped, sandbox, parser)
        elif lang == "toml":
            name = _spec_name(page, line, text)
            conditions = mrjax.data.load(SPEC_DATA[name],
                                         spec=mrjax.data.DataSpec.from_toml(name))
            assert conditions and all(c.n_samples == 1000 for c in conditions), line


def test_skips_say_why_and_most_blocks_run():
    """A skipped block names its reason; the docs keep runnable examples of each kind."""
    ran = {"python": 0, "bash": 0, "toml": 0}
    for page in PAGES:
        lines = page.read_text(encoding="utf-8").splitlines()
        for k, ln in enumerate(lines):
            if ln.startswith("<!--") and "test_readme:" in ln:
                assert SKIP.match(ln.strip()), f"{_name(page)} line {k + 1}: skip (reason)"
        for _, lang, _, skipped in blocks(page):
            if lang in ran and not skipped:
                ran[lang] += 1
    assert ran["python"] >= 8 and ran["bash"] >= 8 and ran["toml"] >= 3, ran


def test_readme_is_a_landing_page():
    """At most 150 lines, the two set-up commands in its first screen."""
    lines = (REPO / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 150, len(lines)
    first_screen = "\n".join(lines[:30])
    assert 'pip install -e ".[dev]" && mrjax reproduce' in first_screen
    assert 'pip install -e ".[dev]" && pytest' in first_screen
    text = "\n".join(lines)
    links = re.findall(r"\]\((docs/[^)#]+)", text) + re.findall(r"\]\(([\w./-]+\.png)\)", text)
    assert links and all((REPO / link).is_file() for link in links), links


# --- the generated pages ------------------------------------------------------------------------

def _hooks():
    spec = importlib.util.spec_from_file_location("docs_hooks", REPO / "docs" / "_hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_api_pages_list_every_public_name():
    """Each public package's page renders every name of its `__all__` (or, without one, every
    name it re-exports), and each such name exists."""
    hooks = _hooks()
    modules = hooks.public_modules()
    assert {"mrjax", "mrjax.data", "mrjax.models", "mrjax.fitting", "mrjax.bayes"} <= set(modules)
    for module in modules:
        mod = importlib.import_module(module)
        listed = hooks.public_names(module)
        if hasattr(mod, "__all__"):
            assert listed == list(mod.__all__), module
        assert listed, module
        page = hooks.api_page(module)
        for name in listed:
            assert hasattr(mod, name), f"{module}.{name}"
            assert f"\n::: {module}.{name}\n" in page, f"{module}.{name}"
    assert "fit" in hooks.public_names("mrjax")


def test_cli_page_documents_every_command():
    page = _hooks().cli_page()
    for command in ("fit", "predict", "compare", "inspect", "reproduce", "models"):
        assert f"## `mrjax {command}`" in page, command
    assert "`--model` `NAME" in page and "`--memory` `SIZE`" in page


def test_executed_notebooks_have_the_sources_of_notebooks():
    """docs/ renders executed copies of the notebooks (`python docs/execute_notebooks.py`
    writes them): each has the cells of its source, and outputs."""
    spec = importlib.util.spec_from_file_location("execute_notebooks",
                                                  REPO / "docs" / "execute_notebooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    for source, copy in module.NOTEBOOKS.items():
        src = json.loads((REPO / source).read_text(encoding="utf-8"))
        out = json.loads((REPO / copy).read_text(encoding="utf-8"))
        cells = [(c["cell_type"], "".join(c["source"])) for c in src["cells"]]
        assert cells == [(c["cell_type"], "".join(c["source"])) for c in out["cells"]], \
            f"{copy} is stale: run `python docs/execute_notebooks.py`"
        assert any(c.get("outputs") for c in out["cells"] if c["cell_type"] == "code"), copy
