"""One command's outputs per directory (`mrjax._io.OutputDir`), a lock against a concurrent
writer, and a command line that answers at once: "did you mean", no heavy import before a
command runs.

Nothing here fits a model: the refusals come before any data is read, and the commands that
do run are `mrjax inspect --no-plots` on a small file.
"""

import json
import subprocess
import sys
import textwrap

import pytest
from helpers import OPTIONS_A, one_error_line, outputs, previous_output, snapshot, write_layout_a
from helpers import run_cli as run

from mrjax import InputError, cli
from mrjax._io import MANIFEST, OutputDir

WRITERS = ("fit", "predict", "compare", "inspect", "reproduce")


def _argv(command: str, out, data="data.csv") -> list:
    """The shortest valid command line of `command` into `out`."""
    return {"fit": ["fit", data, "--model", "kwok"], "predict": ["predict", "--fit", "f", data],
            "compare": ["compare", data], "inspect": ["inspect", data],
            "reproduce": ["reproduce", "--quick"]}[command] + ["--out", out]


@pytest.fixture(scope="module")
def csv_a(tmp_path_factory):
    """Layout (a) of issue 14: 300 samples, read with `OPTIONS_A`."""
    path = tmp_path_factory.mktemp("a") / "random.csv"
    write_layout_a(path, n=300)
    return path


def _inspect(csv_a, out, *extra):
    return run(["inspect", csv_a, "--columns", OPTIONS_A["columns"], "--no-plots", "--out", out,
                *extra])


def test_each_command_has_its_own_default_directory():
    parser = cli.build_parser()
    for command in WRITERS:
        args = parser.parse_args(_argv(command, "x")[:-2])
        assert args.out == f"mrjax-out/{command}" and args.overwrite is False


@pytest.mark.parametrize("command", ["fit", "predict", "compare", "inspect"])
def test_another_commands_directory_is_refused(command, tmp_path):
    d = previous_output(tmp_path / "d", "reproduce",
                        {"summary.md": b"# study\n", "fits/kwok.json": b"{}\n"})
    before = snapshot(tmp_path)
    code, stdout, err = run(_argv(command, d, data=tmp_path / "none.csv"))
    assert code == 2 and stdout == ""
    line = one_error_line(err)
    assert "holds the outputs of `mrjax reproduce`" in line and "--overwrite" in line, line
    assert "loading" not in err  # refused before any work
    assert snapshot(tmp_path) == before


def test_foreign_files_are_refused(csv_a, tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("my notes\n")
    before = snapshot(tmp_path)
    code, _, err = _inspect(csv_a, tmp_path / "mine")
    assert code == 2 and "did not write ('notes.txt')" in one_error_line(err)
    assert snapshot(tmp_path) == before
    # also beside an inspect's own outputs
    assert _inspect(csv_a, tmp_path / "o")[0] == 0
    (tmp_path / "o" / "notes.txt").write_text("added later\n")
    before = snapshot(tmp_path)
    code, _, err = _inspect(csv_a, tmp_path / "o")
    assert code == 2 and "'notes.txt'" in one_error_line(err)
    assert snapshot(tmp_path) == before


def test_same_command_reuses_its_directory_and_overwrite_takes_another(csv_a, tmp_path):
    out = tmp_path / "o"
    assert _inspect(csv_a, out)[0] == 0
    assert _inspect(csv_a, out)[0] == 0  # a re-run replaces its own outputs
    assert outputs(out) == ["inspect.json", "spec.toml"]
    doc = json.loads((out / MANIFEST).read_text())
    assert doc["command"] == "inspect" and doc["files"] == ["inspect.json", "spec.toml"]
    # another command's directory with a foreign file: --overwrite replaces the other
    # command's outputs and keeps the file mrjax did not write
    d = previous_output(tmp_path / "d", "reproduce",
                        {"summary.md": b"# study\n", "fits/kwok.json": b"{}\n"})
    (d / "notes.txt").write_text("keep me\n")
    code, _, err = _inspect(csv_a, d, "--overwrite")
    assert code == 0, err
    assert outputs(d) == ["inspect.json", "notes.txt", "spec.toml"]
    assert (d / "notes.txt").read_text() == "keep me\n"
    assert json.loads((d / MANIFEST).read_text())["command"] == "inspect"


def test_a_rerun_removes_its_stale_outputs(tmp_path):
    """Every file present belongs to the last run (a figure no longer drawn is removed)."""
    with OutputDir(tmp_path / "o", "fit") as out:
        out.write({"fit.json": b"1", "loops.png": b"png", "sub/a.json": b"a"})
    with OutputDir(tmp_path / "o", "fit") as out:
        out.write({"fit.json": b"2"})
    assert outputs(tmp_path / "o") == ["fit.json"]
    assert (tmp_path / "o" / "fit.json").read_bytes() == b"2"
    # a failed run (nothing written) leaves no directory, nor the parents it made
    with pytest.raises(RuntimeError):
        with OutputDir(tmp_path / "new" / "deep" / "o", "fit"):
            raise RuntimeError("the fit failed")
    assert not (tmp_path / "new").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]  # no lock file left


_HOLDER = textwrap.dedent("""
    import sys, time
    from mrjax._io import OutputDir
    with OutputDir(sys.argv[1], "fit") as out:
        print("ready", flush=True)
        sys.stdin.readline()  # until the test says so
        out.write({"fit.json": b"first run"})
""")


def test_a_concurrent_writer_is_refused_at_once(tmp_path):
    """A second command into a directory being written exits 2 at once with one line; the
    first is untouched and finishes."""
    out = tmp_path / "o"
    first = subprocess.Popen([sys.executable, "-c", _HOLDER, str(out)], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert first.stdout.readline().strip() == "ready", first.stderr.read()
        for command in ("fit", "inspect"):
            code, stdout, err = run(_argv(command, out, data=tmp_path / "none.csv"))
            assert code == 2 and stdout == "" and "loading" not in err
            line = one_error_line(err)
            assert "is being written by another mrjax command (mrjax fit, pid" in line, line
        with pytest.raises(InputError, match="being written"):
            OutputDir(out, "fit").__enter__()
        first.stdin.write("go\n")
        first.stdin.flush()
        assert first.wait(timeout=60) == 0, first.stderr.read()
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert (out / "fit.json").read_bytes() == b"first run"
    with OutputDir(out, "fit") as again:  # free again
        again.write({"fit.json": b"second run"})
    assert outputs(out) == ["fit.json"] and not list(tmp_path.glob(".*mrjax-lock"))


def test_mistakes_name_the_closest_option_command_and_model(tmp_path):
    cases = [(["fit", "x.csv", "--modle", "kwok"], "unrecognized option '--modle'; did you mean "
              "'--model'?"),
             (["fit", "x.csv", "--mod", "kwok"], "did you mean '--model'?"),  # no abbreviations
             (["fti", "x.csv"], "unknown command 'fti'; did you mean 'fit'?"),
             (["inspect", "x.csv", "--max-panel", "3"], "did you mean '--max-panels'?")]
    for argv, needle in cases:
        code, stdout, err = run(argv)
        lines = err.strip().splitlines()
        assert code == 2 and stdout == "" and len(lines) == 2, err
        assert lines[0].startswith("usage: mrjax") and needle in lines[1], err
    code, _, err = run(["fit", tmp_path / "x.csv", "--model", "kwk", "--out", tmp_path / "o"])
    assert code == 2 and "unknown model 'kwk'; did you mean 'kwok'?" in one_error_line(err)
    assert "aliases: tanh" in err


_LIGHT = textwrap.dedent("""
    import contextlib, io, sys
    from mrjax.cli import main
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        codes = [main(["--help"]), main(["fit", "--help"]), main(["fit", "x", "--modle", "k"]),
                 main(["--version"])]
    heavy = sorted(m for m in ("jax", "numpy", "matplotlib", "pandas", "scipy", "pint")
                   if m in sys.modules)
    print(codes, heavy)
""")


def test_help_and_usage_errors_import_nothing_heavy():
    """`mrjax --help` and a usage error answer at once: JAX, NumPy, matplotlib, pandas, SciPy
    and pint are imported only by a command that runs (measured: `mrjax --help` 1.3 s ->
    0.14 s)."""
    p = subprocess.run([sys.executable, "-c", _LIGHT], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "[0, 0, 2, 0] []", p.stdout
    p = subprocess.run([sys.executable, "-c", "import sys, mrjax; print('jax' in sys.modules)"],
                       capture_output=True, text=True, timeout=60)
    assert p.stdout.strip() == "False", p.stderr
