"""The `mrjax` command line: fit / predict / reproduce / models, errors, atomic output.

Most tests call `mrjax.cli.main` in-process. Two small fits (a 4-condition CSV and three short
UTFSM files, 5 generations each) are shared by module fixtures; every error test fails before
any fitting.
"""

import csv
import importlib.machinery
import io
import json
import math
import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from helpers import (
    check_fit_schema,
    check_pngs,
    one_error_line,
    outputs,
    previous_output,
    snapshot,
)
from helpers import run_cli as run

import mrjax
from mrjax import InputError, cli
from mrjax.data import paper_grid

UTFSM_FILES = ("2mm5Hz0A.txt", "2mm5Hz0x5A.txt", "2mm5Hz1A.txt")
FIT_PNGS = {"loops.png", "rms_vs_current.png", "params_vs_current.png",
            "generations_vs_current.png", "convergence.png", "pso_vs_polish.png"}


# --------------------------------------------------------------------------------------------
# Helpers


def write_csv(path, batch):
    """A long-format CSV (one row per sample, `condition` column) of a Batch."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["condition", "current_A", "frequency_Hz", "amplitude_mm", "time_s",
                    "displacement_mm", "velocity_mm_s", "force_N"])
        for c in batch.conditions():
            for k in range(c.n_samples):
                w.writerow([c.label, c.current, c.frequency, c.amplitude * 1e3,
                            *(repr(float(v)) for v in (c.t[k], c.x[k] * 1e3, c.xdot[k] * 1e3,
                                                       c.force[k]))])
    return path


# --------------------------------------------------------------------------------------------
# Fixtures: two real fits, shared


@pytest.fixture(scope="module")
def grid():
    return paper_grid(currents=(0.0, 1.0), motions=((1.0, 0.008), (2.0, 0.004)), cycles=1,
                      noise=5.0)


@pytest.fixture(scope="module")
def csv_file(grid, tmp_path_factory):
    return write_csv(tmp_path_factory.mktemp("csv") / "tests.csv", grid)


@pytest.fixture(scope="module")
def csv_run(csv_file, tmp_path_factory):
    """`mrjax fit tests.csv --model kwok --generations 5 --generalize two-step`."""
    out = tmp_path_factory.mktemp("fitcsv") / "out"
    code, stdout, stderr = run(["fit", csv_file, "--model", "kwok", "--generations", 5,
                                "--out", out, "--generalize", "two-step", "--seed", 3])
    return types.SimpleNamespace(code=code, out=out, stdout=stdout, stderr=stderr)


@pytest.fixture(scope="module")
def utfsm_run(utfsm, tmp_path_factory):
    """`mrjax fit <3 UTFSM files> --model tanh --method lm --no-plots` (no swarm: the cheapest
    compile, and the nullable fields of fit.json)."""
    out = tmp_path_factory.mktemp("fitutfsm") / "out"
    files = [utfsm / f for f in UTFSM_FILES]
    code, stdout, stderr = run(["fit", *files, "--model", "tanh", "--method", "lm",
                                "--no-plots", "--out", out])
    return types.SimpleNamespace(code=code, out=out, stdout=stdout, stderr=stderr)


# --------------------------------------------------------------------------------------------
# mrjax fit


def test_fit_csv_end_to_end(csv_run, csv_file, grid):
    assert csv_run.code == 0, csv_run.stderr
    files = set(outputs(csv_run.out))
    assert files == {"fit.json", "fit.csv"} | FIT_PNGS  # no temporary leftovers either
    assert not [p for p in os.listdir(csv_run.out.parent) if p.startswith(".mrjax")]
    check_pngs(csv_run.out, FIT_PNGS)

    doc = json.loads((csv_run.out / "fit.json").read_text())
    check_fit_schema(doc, 4)
    assert (doc["model"], doc["method"], doc["swarm"], doc["seed"]) == (
        "kwok", "pso+lm", "separable", 3)
    conds = doc["conditions"]
    assert [c["label"] for c in conds] == list(grid.labels)  # the CSV condition column
    assert [c["current_A"] for c in conds] == [0.0, 0.0, 1.0, 1.0]
    assert [c["amplitude_m"] for c in conds] == pytest.approx([0.008, 0.004, 0.008, 0.004])
    assert [c["n_samples"] for c in conds] == [1000, 500, 1000, 500]
    assert all(c["generations"] == 5 and c["stopped_by_criterion"] is False for c in conds)
    assert all(c["rms_N"] < 15.0 for c in conds)  # it did fit: noise is 5 N
    assert all(c["pso_rms_N"] >= c["rms_N"] - 1e-6 for c in conds)

    # --generalize: the laws of the fitted parameters are stored, readable back
    gen = doc["generalized"]
    assert gen["method"] == "two-step" and list(gen["laws"]) == list(mrjax.models.get("kwok")
                                                                     .param_names)
    gm = mrjax.generalize.GeneralizedModel.from_dict(gen)
    res = mrjax.generalize.generalize(mrjax.fit("kwok", mrjax.data.load_batch(csv_file),
                                                swarm=mrjax.Swarm(generations=5), key=3),
                                      mrjax.data.load_batch(csv_file), method="two-step")
    for n in gm.param_names:
        assert gm.coefficients(n) == pytest.approx(res.coefficients(n), rel=1e-9, abs=1e-9)

    rows = list(csv.DictReader(io.StringIO((csv_run.out / "fit.csv").read_text())))
    assert [r["label"] for r in rows] == list(grid.labels)
    assert [float(r["rms_N"]) for r in rows] == pytest.approx([c["rms_N"] for c in conds])

    for lab in grid.labels:
        assert lab in csv_run.stdout
    assert "median RMS" in csv_run.stdout and "kwok generalized (two-step)" in csv_run.stdout
    stages = csv_run.stderr.splitlines()
    assert "mrjax: loading 1 file..." in stages
    assert "mrjax: fitting kwok on 4 conditions (pso+lm, separable swarm)..." in stages
    assert f"mrjax: writing 8 files to {csv_run.out}..." in stages
    assert "Traceback" not in csv_run.stderr


def test_fit_utfsm_no_plots(utfsm_run):
    assert utfsm_run.code == 0, utfsm_run.stderr
    assert outputs(utfsm_run.out) == ["fit.csv", "fit.json"]  # --no-plots
    doc = json.loads((utfsm_run.out / "fit.json").read_text())
    check_fit_schema(doc, 3)
    assert "generalized" not in doc
    assert (doc["model"], doc["method"], doc["swarm"]) == ("kwok", "lm", "none")
    conds = doc["conditions"]
    assert [c["label"] for c in conds] == [Path(f).stem for f in UTFSM_FILES]  # file stems
    assert [c["current_A"] for c in conds] == [0.0, 0.5, 1.0]  # from the file names
    assert all(c["frequency_Hz"] == 5.0 and c["amplitude_m"] == pytest.approx(0.002)
               for c in conds)
    # no swarm: its fields are null, the polish ran
    assert all(c["generations"] is None and c["stopped_by_criterion"] is None
               and c["pso_rms_N"] is None and c["polish_status"] != "none" for c in conds)
    assert len((utfsm_run.out / "fit.csv").read_text().strip().splitlines()) == 1 + 3
    assert "2mm5Hz0x5A" in utfsm_run.stdout and "mrjax: loading 3 files..." in utfsm_run.stderr


# --------------------------------------------------------------------------------------------
# mrjax predict


def test_predict_with_generalized_fit(csv_run, csv_file, tmp_path):
    out = tmp_path / "pred"
    code, stdout, stderr = run(["predict", "--fit", csv_run.out / "fit.json", csv_file,
                                "--out", out])
    assert code == 0, stderr
    assert set(outputs(out)) == {"predict.json", "predict.csv", "predicted.csv",
                                    "predict_loops.png", "predict_rms_vs_current.png"}
    check_pngs(out, ["predict_loops.png", "predict_rms_vs_current.png"])
    doc = json.loads((out / "predict.json").read_text())
    assert doc["model"] == "kwok" and len(doc["conditions"]) == 4
    gm = mrjax.generalize.GeneralizedModel.from_json_file(csv_run.out / "fit.json")
    expect = gm.evaluate(mrjax.data.load_batch(csv_file))
    got = [c["rms_N"] for c in doc["conditions"]]
    assert got == pytest.approx(expect["rms"].tolist())
    assert [c["nrmse"] for c in doc["conditions"]] == pytest.approx(expect["nrmse"].tolist())
    assert doc["median_rms_N"] == pytest.approx(float(np.median(expect["rms"])))
    rows = list(csv.DictReader(io.StringIO((out / "predict.csv").read_text())))
    assert [r["label"] for r in rows] == [c["label"] for c in doc["conditions"]]
    assert "1Hz_8mm_1A" in stdout and "median RMS" in stdout
    # a directory holding fit.json is accepted too; --no-plots writes no figures
    code, _, _ = run(["predict", "--fit", csv_run.out, csv_file, "--out", out / "again",
                      "--no-plots"])
    assert code == 0 and outputs(out / "again") == ["predict.csv", "predict.json",
                                                    "predicted.csv"]


def test_predict_needs_a_generalized_block(utfsm_run, utfsm, tmp_path):
    code, _, err = run(["predict", "--fit", utfsm_run.out / "fit.json", utfsm / UTFSM_FILES[0],
                        "--out", tmp_path / "p"])
    assert code == 2
    line = one_error_line(err)
    assert "--generalize" in line and "fit.json" in line
    assert not (tmp_path / "p").exists()


@pytest.mark.parametrize("content, needle", [
    ("{not json", "not valid JSON (line 1"),
    ("[1, 2]", "expected a JSON object"),
    ('{"model": "kwok", "generalized": {"kind": "other"}}', "generalized model block lacks"),
])
def test_predict_bad_fit_json(content, needle, csv_file, tmp_path):
    fit_json = tmp_path / "fit.json"
    fit_json.write_text(content)
    code, _, err = run(["predict", "--fit", fit_json, csv_file, "--out", tmp_path / "p"])
    assert code == 2 and needle in one_error_line(err)


# --------------------------------------------------------------------------------------------
# Errors: one line, exit 2, nothing written, an existing directory untouched


@pytest.fixture
def existing_out(tmp_path):
    return previous_output(tmp_path / "out")


def _nan_csv(csv_file, tmp_path):
    lines = Path(csv_file).read_text().splitlines()
    cells = lines[5].split(",")
    cells[-1] = "nan"
    lines[5] = ",".join(cells)
    bad = tmp_path / "nan.csv"
    bad.write_text("\n".join(lines) + "\n")
    return bad


@pytest.mark.parametrize("case", ["missing-file", "unknown-model", "nan-in-csv", "bad-suffix",
                                  "empty-dir", "both-generation-flags"])
def test_bad_input_one_line_exit_2_directory_untouched(case, csv_file, existing_out, tmp_path):
    args = {"model": "kwok", "files": [csv_file], "extra": []}
    needle = {"missing-file": "no such file", "unknown-model": "unknown model 'kwk'",
              "nan-in-csv": "non-finite value", "bad-suffix": "unknown file type '.xlsx'",
              "empty-dir": "no data files", "both-generation-flags": "not both"}[case]
    if case == "missing-file":
        args["files"] = [tmp_path / "nope.txt"]
    elif case == "unknown-model":
        args["model"] = "kwk"
    elif case == "nan-in-csv":
        args["files"] = [_nan_csv(csv_file, tmp_path)]
    elif case == "bad-suffix":
        (tmp_path / "data.xlsx").write_text("x")
        args["files"] = [tmp_path / "data.xlsx"]
    elif case == "empty-dir":
        (tmp_path / "empty").mkdir()
        args["files"] = [tmp_path / "empty"]
    else:
        args["extra"] = ["--generations", 3, "--max-generations", 10]
    before = snapshot(existing_out)
    code, stdout, err = run(["fit", *args["files"], "--model", args["model"], "--out",
                             existing_out, *args["extra"]])
    assert code == 2
    line = one_error_line(err)
    assert needle in line, line
    assert "fitting" not in err  # failed before any fitting
    assert stdout == ""
    assert snapshot(existing_out) == before  # byte-identical, nothing added
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".mrjax")) == []


def test_nan_error_names_file_and_row(csv_file, tmp_path):
    bad = _nan_csv(csv_file, tmp_path)
    code, _, err = run(["fit", bad, "--model", "kwok", "--out", tmp_path / "o"])
    line = one_error_line(err)
    assert code == 2 and "nan.csv" in line and "column force" in line
    assert not (tmp_path / "o").exists()


def test_unwritable_output_fails_before_loading(csv_file, tmp_path):
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    code, _, err = run(["fit", tmp_path / "missing.txt", "--model", "kwok", "--out", blocker])
    assert code == 2
    line = one_error_line(err)
    assert "is not a directory" in line and "loading" not in err  # output checked first
    assert blocker.read_text() == "x"


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0,
                    reason="root can write anywhere")
def test_read_only_output_directory(csv_file, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        code, _, err = run(["fit", csv_file, "--model", "kwok", "--out", ro / "out"])
    finally:
        ro.chmod(0o700)
    assert code == 2 and "not writable" in one_error_line(err)


@pytest.mark.parametrize("exc, code, needle", [
    (KeyboardInterrupt(), 130, "mrjax: interrupted"),
    (InputError("swarm bounds must be finite"), 2, "mrjax: error: swarm bounds must be finite"),
    (PermissionError(13, "Permission denied", "/x/y"), 2, "mrjax: error: /x/y: Permission denied"),
])
def test_failure_during_fit_writes_nothing(exc, code, needle, csv_file, existing_out,
                                           monkeypatch):
    def boom(*a, **k):
        raise exc

    monkeypatch.setattr("mrjax.cli._fit.fit", boom)  # the function the command calls
    before = snapshot(existing_out)
    new = existing_out.parent / "new"
    for out in (existing_out, new):
        got, stdout, err = run(["fit", csv_file, "--model", "kwok", "--out", out])
        assert got == code and err.strip().splitlines()[-1] == needle and stdout == ""
    assert snapshot(existing_out) == before and not new.exists()


def test_debug_reraises(csv_file, tmp_path):
    with pytest.raises(InputError, match="unknown model"):
        run(["fit", csv_file, "--model", "nope", "--out", tmp_path / "o", "--debug"])


@pytest.mark.parametrize("argv", [
    [], ["frobnicate"], ["fit"], ["fit", "x.csv"], ["fit", "x.csv", "--model", "kwok",
                                                     "--method", "sgd"],
    ["fit", "x.csv", "--model", "kwok", "--transient", "soon"],
    ["fit", "x.csv", "--model", "kwok", "--generations", "0"],
    ["predict", "x.csv"],
])
def test_usage_errors_exit_2(argv):
    code, stdout, err = run(argv)
    assert code == 2 and "usage: mrjax" in err and stdout == ""


def test_help_and_version():
    code, out, _ = run(["--version"])
    assert code == 0 and out.strip() == f"mrjax {mrjax.__version__}"
    code, out, _ = run(["fit", "--help"])
    assert code == 0 and "--generalize" in out and "--transient" in out


def test_compilation_cache_setting(tmp_path, monkeypatch):
    """`mrjax fit/predict/reproduce` use a persistent compilation cache: `$MRJAX_CACHE_DIR`,
    `off` disables it, and a user's `JAX_COMPILATION_CACHE_DIR` wins."""
    import jax

    before = jax.config.jax_compilation_cache_dir
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    try:
        monkeypatch.setenv("MRJAX_CACHE_DIR", "off")
        assert cli.enable_compilation_cache() is None
        target = tmp_path / "cache" / "xla"
        monkeypatch.setenv("MRJAX_CACHE_DIR", str(target))
        assert cli.enable_compilation_cache() == str(target)
        assert target.is_dir() and jax.config.jax_compilation_cache_dir == str(target)
        monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", "/somewhere/else")
        assert cli.enable_compilation_cache() == "/somewhere/else"
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


def test_compilation_cache_is_written(csv_file, tmp_path):
    """A real `mrjax fit` process fills `$MRJAX_CACHE_DIR` with compiled programs."""
    cache = tmp_path / "xla"
    env = dict(os.environ, MRJAX_CACHE_DIR=str(cache), JAX_PLATFORMS="cpu")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    p = subprocess.run([sys.executable, "-m", "mrjax.cli", "fit", str(csv_file), "--model", "kwok",
                        "--generations", "2", "--no-plots", "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert cache.is_dir() and any(cache.iterdir())


def test_fit_float32_swarm(csv_file, tmp_path):
    out = tmp_path / "f32"
    code, _, err = run(["fit", csv_file, "--model", "kwok", "--swarm-dtype", "float32",
                        "--no-plots", "--out", out])
    assert code == 0, err
    doc = json.loads((out / "fit.json").read_text())
    assert all(math.isfinite(c["rms_N"]) for c in doc["conditions"])


def test_console_script_missing_file(tmp_path):
    """The installed `mrjax` script (or `python -m mrjax.cli`): exit 2, one line, no traceback."""
    exe = [sys.executable, "-m", "mrjax.cli"]
    script = Path(sys.executable).with_name("mrjax")
    if script.exists():
        exe = [str(script)]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    p = subprocess.run([*exe, "fit", str(tmp_path / "missing.txt"), "--model", "kwok",
                        "--out", str(tmp_path / "o")], capture_output=True, text=True,
                       timeout=120, env=env, cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    assert p.stderr.strip().splitlines() == [
        f"mrjax: error: {tmp_path / 'missing.txt'}: no such file or directory"]
    assert p.stdout == "" and not (tmp_path / "o").exists()


# --------------------------------------------------------------------------------------------
# mrjax models, mrjax reproduce


def test_models_lists_every_model():
    code, out, _ = run(["models"])
    assert code == 0
    for name in mrjax.models.names():
        m = mrjax.models.get(name)
        assert name in out and m.description in out
        for p in m.param_names:
            assert any(line.split()[:1] == [p] for line in out.splitlines()), p
    # every alias is listed with its model and names it (`mrjax fit --model tanh` works)
    for alias, name in mrjax.models.aliases().items():
        assert alias in out.split(f"{name} (also: ")[1].split(")")[0]
        assert mrjax.models.get(alias).name == name
    kwok_rows = {ln.split()[0]: ln.split()
                 for ln in out.split("kwok (also: tanh)  [")[1].splitlines()[3:9]}
    lo, hi = mrjax.models.get("kwok").bounds
    assert kwok_rows["beta"][1] == "s/m" and float(kwok_rows["beta"][3]) == hi[3]
    code, md, _ = run(["models", "--markdown"])
    assert code == 0 and "### kwok" in md and "|---|---|---:|---:|---|" in md


def test_reproduce_delegates(monkeypatch, tmp_path):
    calls = []
    mod = types.ModuleType("mrjax.reproduce")
    mod.__spec__ = importlib.machinery.ModuleSpec("mrjax.reproduce", None)
    mod.run = lambda out, **kw: calls.append((out, kw)) or 3
    monkeypatch.setitem(sys.modules, "mrjax.reproduce", mod)
    code, _, _ = run(["reproduce", "--quick", "--data", tmp_path, "--out", tmp_path / "r",
                      "--seed", 7])
    assert code == 3
    (out, kw), = calls  # the claimed output directory of the command
    assert out.path == tmp_path / "r" and out.command == "reproduce"
    assert kw == {"quick": True, "data": str(tmp_path), "seed": 7}


# --------------------------------------------------------------------------------------------
# With the real mrjax.generalize (skipped until it exists)


def test_fit_generalize_then_predict_real(csv_file, tmp_path):
    gen = pytest.importorskip("mrjax.generalize")
    out = tmp_path / "fit"
    # the same fit as `csv_run` (compiled already), now with the real laws
    code, _, err = run(["fit", csv_file, "--model", "kwok", "--generations", 5, "--seed", 3,
                        "--generalize", "two-step", "--no-plots", "--out", out])
    assert code == 0, err
    doc = json.loads((out / "fit.json").read_text())
    check_fit_schema(doc, 4)
    gm = gen.GeneralizedModel.from_dict(doc["generalized"])
    assert np.asarray(gm.params_at(np.array([0.0, 1.0]))).shape == (2, 6)
    code, _, err = run(["predict", "--fit", out / "fit.json", csv_file, "--out", tmp_path / "p"])
    assert code == 0, err
    pred = json.loads((tmp_path / "p" / "predict.json").read_text())
    assert len(pred["conditions"]) == 4
    assert all(c["rms_N"] is not None and c["rms_N"] >= 0 for c in pred["conditions"])
