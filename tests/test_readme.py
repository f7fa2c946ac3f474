"""Every code block of the README runs as written.

The README's blocks are read in order and run in a sandbox folder that holds the files they
name, made here from the tanh model at the paper's parameters (eq 24-29):

- `tests/` and `new_tests/`: UTFSM-style text files (t [s], x [mm], v [mm/s], F [N], named like
  `8mm1Hz0x5A.txt`), the README's "folder of your tests";
- `random.csv`, `campaign/` and `lab.mat`: the three layouts of "Your own files" (written by
  the helpers of tests/helpers.py); the README's TOML blocks are written as the files their
  first line names (`# random.toml`).

A ```python block is executed (in this process, a fresh namespace); a ```bash block's `mrjax`
commands run through `mrjax.cli.main` (shell globs expanded, continuation lines joined) and
must exit 0; a ```toml block is read as a data spec and loads its files. A block preceded by
`<!-- test_readme: skip (why) -->` (minutes of fitting, several devices or processes, an
install) is not run, but still checked: its Python compiles and uses no undefined name, and
each of its `mrjax` command lines parses. Blocks without a language (data samples, outputs)
are text.
"""

from __future__ import annotations

import ast
import builtins
import contextlib
import glob
import io
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from helpers import write_layout_a, write_layout_b, write_layout_c

import mrjax
from mrjax import cli

README = Path(__file__).resolve().parents[1] / "README.md"
SKIP = re.compile(r"<!--\s*test_readme:\s*skip")
#: The files each spec file of the README describes (sandbox names).
SPEC_DATA = {"random.toml": "random.csv", "campaign.toml": "campaign", "lab.toml": "lab.mat"}


def blocks() -> list[tuple[int, str, str, bool]]:
    """The README's fenced blocks: `(line, language, text, skipped)`."""
    lines = README.read_text(encoding="utf-8").splitlines()
    out, k = [], 0
    while k < len(lines):
        m = re.match(r"^```(\w*)\s*$", lines[k])
        if not m:
            k += 1
            continue
        end = next(j for j in range(k + 1, len(lines)) if lines[j].startswith("```"))
        skipped = k > 0 and bool(SKIP.match(lines[k - 1].strip()))
        out.append((k + 1, m.group(1), "\n".join(lines[k + 1:end]), skipped))
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


def undefined_names(code: str) -> set[str]:
    """Names a Python block uses but neither defines nor imports (builtins aside)."""
    tree = ast.parse(code)
    defined, used = set(dir(builtins)), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            (used if isinstance(node.ctx, ast.Load) else defined).add(node.id)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            defined |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            defined.add(node.name)
        elif isinstance(node, ast.arg):
            defined.add(node.arg)
    return used - defined


def _ufsm_txt(path: Path, current: float, frequency: float = 1.0, amplitude: float = 0.008,
              seed: int = 0) -> None:
    """A UTFSM-style record (t s, x mm, v mm/s, F N; 2 cycles at 500 Hz) of the tanh model at
    eq 24-29 for `current` [A], with 20 N noise."""
    t, x, v = mrjax.data.sine_excitation(frequency, amplitude, sample_rate=500.0, cycles=2)
    f = np.asarray(mrjax.models.get("kwok").force(mrjax.data.paper_parameters(current), x, v,
                                                  1 / 500.0))
    f = f + 20.0 * np.random.default_rng(seed).standard_normal(f.shape)
    np.savetxt(path, np.column_stack([t, 1e3 * x, 1e3 * v, f]), fmt="%.9g")


def _name(current: float) -> str:
    return f"8mm1Hz{f'{current:g}'.replace('.', 'x')}A.txt"


@pytest.fixture(scope="module")
def sandbox(tmp_path_factory):
    d = tmp_path_factory.mktemp("readme")
    for folder, currents in (("tests", (0.0, 0.5, 1.0)), ("new_tests", (0.25, 0.75))):
        (d / folder).mkdir()
        for k, i in enumerate(currents):
            _ufsm_txt(d / folder / _name(i), i, seed=k)
    write_layout_a(d / "random.csv", n=1000)
    (d / "campaign").mkdir()
    write_layout_b(d / "campaign", n=1000)
    write_layout_c(d / "lab.mat", n=1000)
    for line, lang, text, _ in blocks():  # the spec files, before the commands that use them
        if lang == "toml":
            name = text.splitlines()[0].lstrip("# ").strip()
            assert name.endswith(".toml"), f"README line {line}: a TOML block names its file"
            (d / name).write_text(text + "\n")
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


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the sandbox data's velocity notes
def test_readme_blocks_run_as_written(sandbox, monkeypatch):
    monkeypatch.chdir(sandbox)
    ran = {"python": 0, "bash": 0, "toml": 0}
    parser = cli.build_parser()
    for line, lang, text, skipped in blocks():
        where = f"README line {line}"
        if lang == "python":
            assert not undefined_names(text), f"{where}: undefined {undefined_names(text)}"
            code = compile(text, f"README.md:{line}", "exec")
            if not skipped:
                with contextlib.redirect_stdout(io.StringIO()):
                    exec(code, {"__name__": "__readme__"})
                ran["python"] += 1
        elif lang == "bash":
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
                ran["bash"] += 1
        elif lang == "toml":
            name = text.splitlines()[0].lstrip("# ").strip()
            conditions = mrjax.data.load(SPEC_DATA[name], spec=mrjax.data.DataSpec.from_toml(name))
            assert conditions and all(c.n_samples == 1000 for c in conditions), where
            ran["toml"] += 1
    assert ran["python"] >= 2 and ran["bash"] >= 5 and ran["toml"] >= 3, ran
