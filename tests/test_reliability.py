"""Reliability: bad input, numerical faults, determinism and isolation, tried systematically.

1. **Bad input.** One table, `BAD_INPUT`: kind -> how to build it in `tmp_path` -> what the
    one-line message must name. Every kind goes through the Python API (`mrjax.data.load`,
    `mrjax.fit`, `mrjax.models.check_bounds`, `mrjax.fitting.save`: a one-line `mrjax.InputError`) and
    through `mrjax fit` (exit 2, one `mrjax: error:` line, no traceback unless `--debug`, no
    output, every file under `tmp_path`, an existing output directory included, byte-identical).
    Decisions: fewer scored samples than parameters + 1 is an error; a record shorter than one
    excitation period is a warning; a fit without a swarm (`swarm=None`) clips the default
    start onto the bounds.
2. **Numerical faults.** Diverging particles score `inf`, never NaN; the polish never returns
    worse than its start; gradients of the fitness are finite where z = 0 and at n = 1 and 3.
3. **Batch invariance** (hypothesis): the fitness and the swarm's result of a condition do not
    depend on which other conditions share its batch, on their order, or on padding.
4. **Determinism and isolation.** Same seed, byte-identical `fit.json` from fresh processes;
    one broken condition among 36 changes nothing for the other 35.

Compile time dominates, so every swarm fit uses the tanh model with 50 particles and 5
generations on a few shared shapes, (4, 200) above all.
"""

import contextlib
import csv
import dataclasses
import functools
import io
import json
import os
import subprocess
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np
import pytest
import scipy.io
from helpers import (
    MODEL_NAMES,
    POLISH_RMS_RTOL,
    SWARM_RTOL,
    TRUE_PARAMS,
    assert_same_polish,
    assert_same_swarms,
    draw_sine,
    previous_output,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import mrjax
from mrjax import InputError, cli
from mrjax.data import Condition, load, make_batch, paper_grid, paper_parameters
from mrjax.fitting import save
from mrjax.fitting import tests_problem as make_problem
from mrjax.models import check_bounds, get
from mrjax.objective import masked_rms, residuals, rms_per_condition

GENERATIONS = 5
#: The swarm alone for a fixed number of generations (`method="pso"` in fit.json).
PSO = dict(swarm=mrjax.Swarm(generations=GENERATIONS), polish=None)


def fitness(model, theta, x, xdot, dt, force, mask):
    """The swarm's fitness of one particle on one condition: the masked RMS [N] of its force."""
    return masked_rms(model.force(theta, x, xdot, dt), force, mask)


# --------------------------------------------------------------------------------------------
# Helpers


def run(argv):
    """`mrjax.cli.main(argv)` in-process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every path under `root` (directories too) with its bytes (None for a directory)."""
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


def _r(v) -> str:
    return repr(float(v))


CSV_HEADER = ["condition", "current_A", "frequency_Hz", "amplitude_mm", "time_s",
              "displacement_mm", "velocity_mm_s", "force_N"]


def csv_rows(conditions) -> list[list[str]]:
    """Long-format CSV rows (exact float round trip) of conditions, header `CSV_HEADER`."""
    rows = []
    for c in conditions:
        for k in range(c.n_samples):
            rows.append([c.label, _r(c.current), _r(c.frequency), _r(c.amplitude * 1e3),
                         _r(c.t[k]), _r(c.x[k] * 1e3), _r(c.xdot[k] * 1e3), _r(c.force[k])])
    return rows


def write_csv(path: Path, rows, header=CSV_HEADER) -> Path:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def _small_grid():
    """4 tanh conditions (0 / 1 A x 1 Hz, 8 mm / 2 Hz, 4 mm), one cycle at 200 Hz: (4, 200)."""
    return paper_grid(currents=(0.0, 1.0), motions=((1.0, 0.008), (2.0, 0.004)), cycles=1,
                      sample_rate=200.0, noise=5.0)


SMALL = _small_grid()


def _good_table(n=60):
    """A headerless UTFSM-style table `t [s], x [mm], xdot [mm/s], F [N]`: one 1 Hz cycle."""
    c = SMALL.condition(0)
    return np.column_stack([c.t, c.x * 1e3, c.xdot * 1e3, c.force])[:n]


def _txt(path: Path, data) -> Path:
    np.savetxt(path, np.asarray(data), fmt="%.12e")
    return path


def _good_csv(tmp: Path, name="good.csv") -> Path:
    return write_csv(tmp / name, csv_rows([SMALL.condition(0)]))


def _edited_csv(tmp: Path, name: str, column: str, row: int, value: str) -> Path:
    rows = csv_rows([SMALL.condition(0)])
    j = CSV_HEADER.index(column)
    for k in ([row] if row >= 0 else range(len(rows))):
        rows[k][j] = value
    return write_csv(tmp / name, rows)


# --------------------------------------------------------------------------------------------
# 1. Bad input: the table


@dataclasses.dataclass
class Bad:
    """A bad input: CLI file arguments and extra options, and the Python calls that must fail.

    `api`: callables that must raise; default `mrjax.data.load(files)` and
    `mrjax.fit(model, files)`. `out`: the `--out` of the CLI run (default an existing
    directory `tmp_path/out` holding two files)."""

    files: list
    cli: list = dataclasses.field(default_factory=list)
    api: list[Callable] | None = None
    model: str = "kwok"
    out: Path | None = None


def _load_and_fit(files):
    return [lambda: load(files), lambda: mrjax.fit("kwok", files)]


def _nan_time(tmp):
    data = _good_table()
    data[5, 0] = np.nan
    return Bad([_txt(tmp / "8mm1Hz0A.txt", data)])


def _inf_displacement(tmp):
    return Bad([_edited_csv(tmp, "inf.csv", "displacement_mm", 7, "inf")])


def _nan_velocity(tmp):
    return Bad([_edited_csv(tmp, "nanv.csv", "velocity_mm_s", 11, "nan")])


def _neg_inf_force(tmp):
    data = _good_table()
    data[12, 3] = -np.inf
    return Bad([_txt(tmp / "8mm1Hz0A.txt", data)])


def _nan_current(tmp):
    return Bad([_edited_csv(tmp, "nani.csv", "current_A", -1, "nan")])


def _empty_file(tmp):
    (tmp / "empty.csv").write_text("")
    return Bad([tmp / "empty.csv"])


def _header_only(tmp):
    return Bad([write_csv(tmp / "header.csv", [])])


def _missing_column(tmp):
    rows = [r[:-1] for r in csv_rows([SMALL.condition(0)])]
    return Bad([write_csv(tmp / "noforce.csv", rows, CSV_HEADER[:-1])])


def _unknown_column(tmp):
    rows = [r + ["21.5"] for r in csv_rows([SMALL.condition(0)])]
    return Bad([write_csv(tmp / "temp.csv", rows, CSV_HEADER + ["temperature_C"])])


def _unknown_unit(tmp):
    header = [h if h != "displacement_mm" else "displacement_furlongz" for h in CSV_HEADER]
    return Bad([write_csv(tmp / "inch.csv", csv_rows([SMALL.condition(0)]), header)])


def _wrong_dimension(tmp):
    header = [h if h != "displacement_mm" else "displacement_N" for h in CSV_HEADER]
    return Bad([write_csv(tmp / "newton.csv", csv_rows([SMALL.condition(0)]), header)])


def _non_numeric_csv(tmp):
    return Bad([_edited_csv(tmp, "text.csv", "force_N", 9, "12.5N")])


def _non_numeric_txt(tmp):
    rows = [[f"{v:.9e}" for v in row] for row in _good_table()]
    rows[2][2] = "abc"
    lines = [" ".join(r) for r in rows]
    (tmp / "8mm1Hz0A.txt").write_text("\n".join(lines) + "\n")
    return Bad([tmp / "8mm1Hz0A.txt"])


def _non_increasing_time(tmp):
    data = _good_table()
    data[10, 0] = data[8, 0]
    return Bad([_txt(tmp / "8mm1Hz0A.txt", data)])


def _duplicated_time(tmp):
    rows = csv_rows([SMALL.condition(0)])
    rows[7][4] = rows[6][4]
    return Bad([write_csv(tmp / "dup.csv", rows)])


def _mat(tmp, name, **variables):
    path = tmp / name
    scipy.io.savemat(path, variables)
    return path


def _zero_length(tmp):
    empty = np.zeros(0)
    return Bad([_mat(tmp, "8mm1Hz0A.mat", t=empty, x=empty, force=empty)])


def _single_sample(tmp):
    return Bad([_txt(tmp / "8mm1Hz0A.txt", _good_table()[:1])])


def _mismatched_lengths(tmp):
    c = SMALL.condition(0)
    return Bad([_mat(tmp, "8mm1Hz0A.mat", t=c.t, x=c.x, xdot=c.xdot, force=c.force[:-3])])


def _ragged_row(tmp):
    lines = [" ".join(f"{v:.9e}" for v in row) for row in _good_table()]
    lines[3] = " ".join(lines[3].split()[:3])
    (tmp / "8mm1Hz0A.txt").write_text("\n".join(lines) + "\n")
    return Bad([tmp / "8mm1Hz0A.txt"])


def _unparsable_name(tmp):
    return Bad([_txt(tmp / "run1.txt", _good_table())])


def _negative_current(tmp):
    return Bad([_edited_csv(tmp, "neg.csv", "current_A", -1, "-0.5")])


def _inverted_bounds(tmp):
    bounds = ({"c": 5000.0}, {"c": 1000.0})
    return Bad([_good_csv(tmp)], ["--bounds", "c=5000:1000"],
               api=[lambda: mrjax.fit("kwok", SMALL, bounds=bounds),
                    lambda: check_bounds(get("kwok"), bounds)])


def _unknown_bound_name(tmp):
    bounds = ({"cc": 1.0}, {"cc": 2.0})
    return Bad([_good_csv(tmp)], ["--bounds", "cc=1:2"],
               api=[lambda: mrjax.fit("kwok", SMALL, bounds=bounds)])


def _malformed_bounds(tmp):
    lo, hi = get("kwok").bounds
    return Bad([_good_csv(tmp)], ["--bounds", "c=5000"],
               api=[lambda: check_bounds(get("kwok"), (lo[:5], hi))])


def _unknown_model(tmp):
    return Bad([_good_csv(tmp)], model="kwk", api=[lambda: mrjax.fit("kwk", SMALL)])


def _mat_missing_variable(tmp):
    c = SMALL.condition(0)
    return Bad([_mat(tmp, "8mm1Hz0A.mat", t=c.t, x=c.x)])


def _tiny_record(tmp):
    """1 MHz, 3 samples, with velocity: loads, but 3 samples cannot fix 6 parameters."""
    t = np.arange(3) * 1e-6
    c = Condition("burst", 0.5, 1000.0, 0.001, t, 1e-3 * np.sin(2e3 * np.pi * t),
                  2 * np.pi * np.cos(2e3 * np.pi * t), np.array([1.0, 2.0, 3.0]))
    files = [write_csv(tmp / "burst.csv", csv_rows([c]))]
    return Bad(files, api=[lambda: mrjax.fit("kwok", files)])


def _tiny_record_no_velocity(tmp):
    """1 MHz, 3 samples, no velocity column: too short to estimate the velocity."""
    rows = [["0.5", _r(k * 1e-6), _r(k * 1e-3), "1.0"] for k in range(3)]
    return Bad([write_csv(tmp / "burst.csv", rows,
                          ["current_A", "time_s", "displacement_mm", "force_N"])])


def _no_data_files(tmp):
    (tmp / "data").mkdir()
    (tmp / "data" / "README.md").write_text("the data are elsewhere\n")
    (tmp / "data" / "notes.xlsx").write_bytes(b"PK")
    return Bad([tmp / "data"])


def _output_under_a_file(tmp):
    (tmp / "afile").write_text("I am a file\n")
    out = tmp / "afile" / "out"
    return Bad([_good_csv(tmp)], out=out, api=[lambda: save(_fit_result(), out)])


def _output_in_proc(tmp):
    out = Path("/proc/mrjax-reliability-out")
    return Bad([_good_csv(tmp)], out=out, api=[lambda: save(_fit_result(), out)])


_RESULT = []


def _fit_result():
    """A real FitResult for the output kinds (the shared (4, 200) swarm compile)."""
    if not _RESULT:
        _RESULT.append(mrjax.fit("kwok", SMALL, **PSO))
    return _RESULT[0]


#: kind -> builder -> substrings the message must contain (both surfaces), or a dict with
#: separate "api" and "cli" substrings.
BAD_INPUT = [
    ("nan-time", _nan_time, ("8mm1Hz0A.txt", "column t", "non-finite value (nan)", "row 5")),
    ("inf-displacement", _inf_displacement, ("inf.csv", "column x", "(inf)", "row 7")),
    ("nan-velocity", _nan_velocity, ("nanv.csv", "column xdot", "(nan)", "row 11")),
    ("-inf-force", _neg_inf_force, ("8mm1Hz0A.txt", "column force", "(-inf)", "row 12")),
    ("nan-current", _nan_current, ("nani.csv", "current is not finite")),
    ("empty-file", _empty_file, ("empty.csv", "file is empty")),
    ("header-only", _header_only, ("header.csv", "header only, no data rows")),
    ("missing-column", _missing_column, ("noforce.csv", "missing required column force_")),
    ("unknown-column", _unknown_column, ("temp.csv", "unknown column 'temperature_C'")),
    ("unknown-unit", _unknown_unit, ("inch.csv", "'displacement_furlongz'",
                                     "unknown unit 'furlongz'")),
    ("wrong-dimension", _wrong_dimension, ("newton.csv", "'displacement_N'",
                                           "displacement unit 'N' is not a length")),
    ("non-numeric-csv", _non_numeric_csv, ("text.csv", "line 11", "'force_N'", "'12.5N'")),
    ("non-numeric-txt", _non_numeric_txt, ("8mm1Hz0A.txt", "line 3", "column 3 (xdot)", "'abc'")),
    ("non-increasing-time", _non_increasing_time,
     ("8mm1Hz0A.txt", "not strictly increasing at row 10")),
    ("duplicated-time", _duplicated_time, ("dup.csv", "not strictly increasing at row 7")),
    ("zero-length", _zero_length, ("8mm1Hz0A.mat", "condition has no samples")),
    ("single-sample", _single_sample, ("8mm1Hz0A.txt", "only 1 sample(s)", "at least 3")),
    ("mismatched-lengths", _mismatched_lengths,
     ("8mm1Hz0A.mat", "mismatched column lengths", "'force': 197")),
    ("ragged-row", _ragged_row, ("8mm1Hz0A.txt", "line 4", "expected 4 columns, found 3")),
    ("unparsable-name", _unparsable_name,
     ("run1.txt", "cannot read amplitude, frequency and current", "'run1'")),
    ("negative-current", _negative_current, ("neg.csv", "current must be non-negative", "-0.5 A")),
    ("inverted-bounds", _inverted_bounds,
     ("parameter 'c'", "inverted: lower 5000 > upper 1000")),
    ("unknown-bound-name", _unknown_bound_name, ("unknown parameter 'cc'", "kwok")),
    ("malformed-bounds", _malformed_bounds,
     {"api": ("6 values",), "cli": ("--bounds 'c=5000'", "NAME=LO:HI")}),
    ("unknown-model", _unknown_model, ("unknown model 'kwk'", "kwok, bouc_wen")),
    ("mat-missing-variable", _mat_missing_variable,
     ("8mm1Hz0A.mat", "missing variable(s) force", "variables present: t, x")),
    ("tiny-record", _tiny_record,
     ("'burst'", "3 scored samples", "6 parameters", "at least 7")),
    ("tiny-record-no-velocity", _tiny_record_no_velocity,
     ("burst.csv", "no velocity column", "3 sample(s)", "at least 5")),
    ("no-data-files", _no_data_files, ("data", "directory has no data files")),
    ("output-under-a-file", _output_under_a_file,
     ("afile/out", "cannot be created", "is not a directory")),
    ("output-in-proc", _output_in_proc, ("/proc/mrjax-reliability-out", "not writable")),
]


def _needles(spec, surface):
    return spec[surface] if isinstance(spec, dict) else spec


def _check_message(msg: str, needles) -> None:
    assert "\n" not in msg and "Traceback" not in msg, msg
    for n in needles:
        assert n in msg, f"{n!r} not in {msg!r}"


@pytest.mark.parametrize("kind, build, needles", BAD_INPUT, ids=[k for k, *_ in BAD_INPUT])
def test_bad_input_api(kind, build, needles, tmp_path):
    bad = build(tmp_path)
    calls = bad.api if bad.api is not None else _load_and_fit(bad.files)
    for call in calls:
        with pytest.raises(InputError) as info:
            call()
        _check_message(str(info.value), _needles(needles, "api"))


@pytest.mark.parametrize("kind, build, needles", BAD_INPUT, ids=[k for k, *_ in BAD_INPUT])
def test_bad_input_cli(kind, build, needles, tmp_path):
    bad = build(tmp_path)
    out = bad.out
    if out is None:
        out = previous_output(tmp_path / "out")
    argv = ["fit", *bad.files, "--model", bad.model, "--out", out, *bad.cli]
    before = snapshot(tmp_path)
    code, stdout, stderr = run(argv)
    assert code == 2 and stdout == ""
    lines = stderr.splitlines()
    errors = [ln for ln in lines if ln.startswith("mrjax: error: ")]
    assert len(errors) == 1 and lines[-1] == errors[0], stderr
    # the only other lines are stage lines ("mrjax: loading 1 file..."): no traceback, warning
    assert all(ln.startswith("mrjax: ") and ln.endswith("...") for ln in lines[:-1]), stderr
    _check_message(errors[0], _needles(needles, "cli"))
    assert snapshot(tmp_path) == before  # nothing written, nothing left behind, old out intact
    assert not Path("/proc/mrjax-reliability-out").exists()
    # --debug shows the traceback instead: the error propagates
    with pytest.raises(InputError):
        run(argv + ["--debug"])
    assert snapshot(tmp_path) == before


def test_key_count_must_match_conditions():
    keys = jax.random.split(jax.random.key(0), 3)
    with pytest.raises(InputError, match="got 3 keys for 4 "):
        mrjax.fit("kwok", SMALL, key=keys, **PSO)


# --------------------------------------------------------------------------------------------
# Edge cases that are not errors: a documented clip, a warning


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory):
    return write_csv(tmp_path_factory.mktemp("small") / "small.csv", csv_rows(SMALL.conditions()))


@pytest.fixture(scope="module")
def small_batch(small_csv):
    batch = make_batch(load(small_csv))
    assert (batch.n_conditions, batch.length) == (4, 200)
    return batch


@pytest.fixture(scope="module")
def small_fit(small_batch):
    """The in-process twin of `mrjax fit small.csv --generations 5 --seed 3` (compiles the
    shared (4, 200) swarm and polish)."""
    return mrjax.fit("kwok", small_batch, swarm=mrjax.Swarm(generations=GENERATIONS), key=3)


def test_lm_start_outside_bounds_is_clipped(small_batch, small_fit, small_csv, tmp_path):
    """The default start (c = 50000 N s/m, beta = 100 s/m) lies outside these bounds: `"lm"`
    starts from it clipped onto them (documented in `mrjax.fit`), not an error."""
    lo, hi = {"c": 1000.0, "beta": 200.0}, {"c": 5000.0, "beta": 2000.0}
    start = get("kwok").default_start()
    assert not (lo["c"] <= start[0] <= hi["c"]) and not (lo["beta"] <= start[3] <= hi["beta"])
    res = mrjax.fit("kwok", small_batch, swarm=None, bounds=(lo, hi),
                    polish=mrjax.Polish(uncertainty=False))
    th = res.theta
    assert np.all((th[:, 0] >= 1000.0) & (th[:, 0] <= 5000.0))
    assert np.all((th[:, 3] >= 200.0) & (th[:, 3] <= 2000.0))
    assert np.all(np.isfinite(res.rms)) and set(res.polish_status) <= {
        "successful", "max_steps_reached", "kept_start"}
    code, _, err = run(["fit", small_csv, "--model", "kwok", "--method", "lm", "--no-plots",
                        "--bounds", "c=1000:5000", "--bounds", "beta=200:2000",
                        "--out", tmp_path / "o"])
    assert code == 0, err
    doc = json.loads((tmp_path / "o" / "fit.json").read_text())
    cs = [c["params"]["c"] for c in doc["conditions"]]
    assert all(1000.0 <= c <= 5000.0 for c in cs)
    np.testing.assert_array_equal(cs, th[:, 0])


def _short_record_batch():
    """Three small-grid conditions and one 20-sample record at 1 MHz of a 1 Hz test."""
    t = np.arange(20) * 1e-6
    short = Condition("short", 0.5, 1.0, 0.008, t, 0.008 * np.sin(2 * np.pi * t),
                      0.008 * 2 * np.pi * np.cos(2 * np.pi * t), np.linspace(-20.0, 20.0, 20))
    return make_batch(SMALL.conditions()[:3] + [short])


def test_record_shorter_than_a_period_warns(small_fit, tmp_path):
    batch = _short_record_batch()
    assert (batch.n_conditions, batch.length) == (4, 200)
    with pytest.warns(RuntimeWarning, match="'short'.*less than one period of its 1 Hz"):
        res = mrjax.fit("kwok", batch, **PSO)
    assert np.all(np.isfinite(res.rms)) and np.all(np.isfinite(res.theta))
    csv_file = write_csv(tmp_path / "short.csv", csv_rows(batch.conditions()))
    code, _, err = run(["fit", csv_file, "--model", "kwok", "--generations", GENERATIONS,
                        "--no-plots", "--out", tmp_path / "o"])
    assert code == 0, err
    warn = [ln for ln in err.splitlines() if "warning" in ln.lower()]
    assert len(warn) == 1 and warn[0].startswith("mrjax: warning: condition 'short'"), err
    assert "Traceback" not in err and (tmp_path / "o" / "fit.json").is_file()


# --------------------------------------------------------------------------------------------
# 2. Numerical faults


#: Bouc-Wen with one fixed RK4 step per sample (one compile for the swarm and the polish) and
#: bounds wide enough that many particles diverge: negative beta and gamma let z grow without
#: bound, a large delta makes the RK4 step unstable.
BW1 = get("bouc_wen", substeps=1)


def _wide_bw_bounds():
    lo, hi = BW1.bounds
    lo, hi = lo.copy(), hi.copy()
    names = BW1.param_names
    lo[names.index("beta")] = lo[names.index("gamma")] = -5000.0
    hi[names.index("delta")] = 1e5
    return lo, hi


def test_diverging_particles_score_inf_and_reported_rms_is_finite(small_batch, tmp_path):
    lo, hi = _wide_bw_bounds()
    # a third or more of the box diverges (uniform draws, scored like a particle)
    thetas = lo + np.random.default_rng(0).random((64, BW1.n_params)) * (hi - lo)
    c = small_batch
    scores = jax.jit(jax.vmap(lambda th: fitness(BW1, th, c.x[0], c.xdot[0], c.dt[0],
                                                 c.force[0], c.mask[0])))(thetas)
    scores = np.asarray(scores)
    assert not np.any(np.isnan(scores)) and np.mean(np.isinf(scores)) > 0.3
    res = mrjax.fit(BW1, small_batch, bounds=(lo, hi), swarm=mrjax.Swarm(generations=GENERATIONS),
                    polish=mrjax.Polish(max_steps=1))
    for a in (res.rms, res.pso_rms, res.history, res.theta):
        assert np.all(np.isfinite(a))
    assert np.all(np.diff(res.history, axis=1) <= 0)  # the group best never gets worse
    assert np.all(res.rms <= res.pso_rms * (1 + 1e-9))
    assert np.all((res.theta >= lo) & (res.theta <= hi))
    # The polish keeps its start when LM fails: one step only, and a start that blows up.
    start = res.theta.copy()
    names = BW1.param_names
    start[2, [names.index(n) for n in ("delta", "beta", "gamma")]] = 1e5, -5000.0, -5000.0
    assert not np.isfinite(rms_per_condition(BW1, start, small_batch)[2])
    # (the engine's polish stage alone from `start`, inside the box)
    assert np.all((start >= lo) & (start <= hi))
    pol = mrjax.engine.solve(make_problem(BW1, small_batch, bounds=(lo, hi)), swarm=None,
                             polish=mrjax.Polish(max_steps=1), start=start)
    rms, rms0 = np.asarray(pol.rms), np.asarray(pol.start.rms)
    assert np.all(rms[[0, 1, 3]] <= rms0[[0, 1, 3]]) and np.all(np.isfinite(rms[[0, 1, 3]]))
    assert pol.status[2] == "kept_start" and np.isinf(rms0[2])
    np.testing.assert_array_equal(np.asarray(pol.z)[2], start[2])
    # Bounds where every start diverges: the fit warns and reports inf (null in fit.json).
    # (Before, FitResult.to_json raised "Out of range float values are not JSON compliant".)
    doomed = ({"delta": 4000.0, "beta": -5000.0, "gamma": -5000.0},
              {"beta": -4000.0, "gamma": -4000.0})
    with pytest.warns(RuntimeWarning, match="not finite at the fitted parameters"):
        res = mrjax.fit(BW1, small_batch, swarm=None, bounds=doomed,
                        polish=mrjax.Polish(max_steps=1))
    assert np.all(np.isinf(res.rms)) and set(res.polish_status) == {"kept_start"}
    save(res, tmp_path / "o")
    doc = json.loads((tmp_path / "o" / "fit.json").read_text())
    assert [c["rms_N"] for c in doc["conditions"]] == [None] * 4


@pytest.mark.parametrize("name", ["bouc_wen", "modified_bouc_wen"])
def test_fitness_gradients_finite_at_z0_and_n_at_its_bounds(name):
    """What the polish differentiates: the masked residuals and RMS of a padded record that
    starts at rest (z = 0 exactly for 30 samples), at n = 1 and n = 3 (the default bounds).
    Extends tests/test_models.py::test_gradient_matches_finite_differences (force only)."""
    model = get(name, substeps=1)
    theta = TRUE_PARAMS[name].copy()
    k = model.param_names.index("n")
    thetas = np.stack([np.r_[theta[:k], n, theta[k + 1:]] for n in (1.0, 3.0)])
    fs, n_rest, n_move = 500.0, 30, 170
    t = np.arange(n_rest + n_move) / fs
    s = np.clip(t - n_rest / fs, 0.0, None)
    x, v = 0.01 * np.sin(2 * np.pi * s), 0.01 * 2 * np.pi * np.cos(2 * np.pi * s) * (s > 0)
    force = np.asarray(model.force(theta, x, v, 1 / fs)) + np.random.default_rng(1).normal(
        0, 10, t.size)
    b = make_batch([Condition("rest", 1.0, 1.0, 0.01, t, x, v, force)], length=240)
    args = (b.x[0], b.xdot[0], b.dt[0], b.force[0], b.mask[0])
    jac = jax.jit(jax.vmap(jax.jacfwd(lambda th: residuals(model, th, *args))))(thetas)
    grad = jax.jit(jax.vmap(jax.grad(lambda th: fitness(model, th, *args))))(thetas)
    assert np.all(np.isfinite(np.asarray(jac))) and np.all(np.isfinite(np.asarray(grad)))
    assert np.all(np.asarray(jac)[:, 200:] == 0.0)  # padding carries no residual, no gradient
    assert np.all(np.asarray(grad)[:, k] != 0.0)  # and n does matter


# --------------------------------------------------------------------------------------------
# 3. Batch split / padding invariance (hypothesis)

LENGTHS = (37, 64, 90)
PADDED = 128


@functools.cache
def _jit_force(name):
    return jax.jit(get(name, substeps=8).force)


@st.composite
def random_tests(draw, name, lengths=LENGTHS, damper=False):
    """Conditions of the given lengths: random bounded sinusoids (1-2 cycles, 2-15 mm, any
    phase, 200 Hz-1 kHz) with a random force (a phase-shifted sinusoid of up to 2 kN plus
    noise), and random parameters inside the default bounds to score on each. `damper=True`
    (tanh only) makes the force that of a real damper instead: eq 24-29 at a random current,
    each parameter scaled by 0.7-1.3, plus noise."""
    model = get(name)
    lo, hi = model.bounds
    unit = st.floats(0.0, 1.0)
    conds, thetas = [], []
    for j, n in enumerate(lengths):
        t, x, v, rate, f, amp = draw_sine(draw, n, 200.0)
        force = np.random.default_rng(draw(st.integers(0, 2**16))).normal(0, 20.0, n)
        if damper:
            scale = draw(st.lists(st.floats(0.7, 1.3), min_size=len(lo), max_size=len(lo)))
            truth = np.clip(paper_parameters(draw(st.floats(0.0, 2.0))) * scale, lo, hi)
            force += np.asarray(_jit_force(name)(truth, x, v, 1 / rate))
        else:
            force += draw(st.floats(0.0, 2000.0)) * np.sin(2 * np.pi * f * t + draw(unit))
        conds.append(Condition(f"c{j}", 1.0, f, amp, t, x, v, force))
        thetas.append(lo + np.array(draw(st.lists(unit, min_size=len(lo), max_size=len(lo))))
                      * (hi - lo))
    order = draw(st.permutations(range(len(lengths))))
    return conds, np.array(thetas), list(order)


HYPOTHESIS = dict(max_examples=10, deadline=None, derandomize=True, database=None,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_fitness_independent_of_batch_split_and_padding(name):
    """`rms_per_condition` of each condition alone (unpadded) equals its value inside a batch of
    conditions of other lengths, in any order, and inside a batch padded further."""
    model = get(name)

    @settings(**HYPOTHESIS)
    @given(random_tests(name))
    def check(case):
        conds, thetas, order = case
        alone = np.array([rms_per_condition(model, thetas[i:i + 1], make_batch([c]))[0]
                          for i, c in enumerate(conds)])
        perm = [conds[i] for i in order]
        together = rms_per_condition(model, thetas[order], make_batch(perm))
        padded = rms_per_condition(model, thetas[order], make_batch(perm, length=PADDED))
        np.testing.assert_allclose(together, alone[order], rtol=1e-12)
        np.testing.assert_allclose(padded, together, rtol=1e-12)

    check()


def _compare_fits(a, i, b, j):
    """Condition i of FitResult a against condition j of b."""
    assert a.labels[i] == b.labels[j]
    assert a.generations[i] == b.generations[j]
    for field in ("rms", "pso_rms", "history", "theta"):
        np.testing.assert_allclose(getattr(a, field)[i], getattr(b, field)[j], rtol=1e-9,
                                   atol=1e-9, err_msg=field)


@settings(**{**HYPOTHESIS, "max_examples": 8})
@given(random_tests("kwok", lengths=(200, 150, 120, 90), damper=True), st.integers(0, 3))
def test_swarm_result_independent_of_batch_split_and_padding(case, alone_index):
    """`mrjax.fit(polish=None)` with per-condition keys: a condition's result is the same in
    the batch, fitted alone, and in the batch padded further (shapes (4, 200), (1, 200) and
    (4, 256): three compiles for all examples).

    Equal to rounding, not bit-identical: XLA sums in a different order for 1 and 4 conditions
    (relative 1e-13 measured). The truth is a plausible damper because on a degenerate one
    (alpha = 0 leaves beta and delta without effect) particles of equal fitness tie, and those
    last-bit differences pick different, equally good, parameters."""
    conds, _, order = case
    keys = jax.random.split(jax.random.key(42), 4)  # one per condition, in `conds` order
    kw = PSO
    batch = make_batch([conds[i] for i in order])
    k = keys[np.asarray(order)]
    whole = mrjax.fit("kwok", batch, key=k, **kw)
    padded = mrjax.fit("kwok", make_batch([conds[i] for i in order], length=256), key=k, **kw)
    for j in range(4):
        _compare_fits(whole, j, padded, j)
    i = alone_index
    alone = mrjax.fit("kwok", make_batch([conds[i]], length=200), key=keys[i:i + 1], **kw)
    _compare_fits(alone, 0, whole, order.index(i))


# --------------------------------------------------------------------------------------------
# 4. Determinism and isolation


def test_same_seed_byte_identical_fit_json_in_fresh_processes(small_csv, small_fit, tmp_path):
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONHASHSEED": "random"}
    procs = {}
    for name in ("A", "B"):  # two fresh processes, side by side
        procs[name] = subprocess.Popen(
            [sys.executable, "-m", "mrjax.cli", "fit", str(small_csv), "--model", "kwok",
             "--generations", str(GENERATIONS), "--seed", "3", "--no-plots",
             "--out", str(tmp_path / name)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True)
    for name, p in procs.items():
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    a, b = (tmp_path / "A" / "fit.json").read_bytes(), (tmp_path / "B" / "fit.json").read_bytes()
    assert a == b
    assert (tmp_path / "A" / "fit.csv").read_bytes() == (tmp_path / "B" / "fit.csv").read_bytes()
    # and the same bytes as the same fit in this process
    assert small_fit.to_json().encode() == a
    assert json.loads(a)["seed"] == 3


@pytest.fixture(scope="module")
def broken_grid():
    """The paper grid (36 conditions, one cycle at 250 Hz) with condition 20's force replaced
    by a dead sensor: a constant offset with 10 % of the samples hit by +-200 kN spikes."""
    grid = paper_grid(cycles=1, sample_rate=250.0)
    conds = grid.conditions()
    c = conds[BROKEN]
    rng = np.random.default_rng(0)
    spikes = np.where(rng.random(c.n_samples) < 0.1, 2e5 * rng.choice([-1.0, 1.0], c.n_samples),
                      0.0)
    conds[BROKEN] = dataclasses.replace(c, force=50.0 + spikes, label=c.label + "_broken")
    return make_batch(conds)


BROKEN = 20


def test_one_broken_condition_leaves_the_other_35_unchanged(broken_grid):
    keys = jax.random.split(jax.random.key(7), 36)
    others = np.flatnonzero(np.arange(36) != BROKEN)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning either
        r36 = mrjax.fit("kwok", broken_grid, key=keys)
        r35 = mrjax.fit("kwok", broken_grid.subset(others), key=keys[others])
    assert r35.n_conditions == 35 and broken_grid.subset(others).length == broken_grid.length
    assert [r36.labels[i] for i in others] == list(r35.labels)
    # The other 35 are the same fits, to rounding: 35 and 36 conditions vectorise their sums
    # differently, so a stop within rounding of its threshold may move (the polish's step
    # counts are not compared; see `helpers.assert_same_swarms`). A broken condition that
    # leaked into the others (a shared best, a shared stop, NaN) moves them by percents.
    assert_same_swarms(r36.generations[others], r35.generations, r36.history[others],
                       r35.history)
    same = r36.generations[others] == r35.generations
    np.testing.assert_allclose(r36.pso_rms[others][same], r35.pso_rms[same], rtol=SWARM_RTOL)
    assert_same_polish(r36.rms[others], r35.rms, r36.theta[others], r35.theta)
    np.testing.assert_allclose(r36.nrmse[others], r35.nrmse, rtol=POLISH_RMS_RTOL)
    np.testing.assert_allclose(r36.stderr[others], r35.stderr, rtol=1e-3)
    # the broken condition is flagged by its error: finite, and far above every other one
    bad = BROKEN
    print(f"\nbroken condition: rms {r36.rms[bad]:.4g} N, nrmse {r36.nrmse[bad]:.3f}, "
          f"pso_rms {r36.pso_rms[bad]:.4g} N, status {r36.polish_status[bad]!r}, "
          f"steps {r36.polish_steps[bad]}, generations {r36.generations[bad]}, "
          f"by criterion {r36.stopped_by_criterion[bad]}, identifiable "
          f"{r36.identifiable[bad].tolist()}; the others: max rms {np.max(r35.rms):.3g} N, "
          f"max nrmse {np.max(r35.nrmse):.4f}, statuses {sorted(set(r35.polish_status))}")
    assert np.isfinite(r36.rms[bad]) and r36.rms[bad] > 100 * np.max(r35.rms)
    assert r36.nrmse[bad] > 3 * np.max(r35.nrmse)
    # the polish may converge (its residual stops changing) on garbage: what flags it is the
    # error above and the parameters the data cannot pin down
    assert not np.all(r36.identifiable[bad])
