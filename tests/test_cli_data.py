"""Your own files on the command line (issue 14): the data options of `mrjax fit`, `predict`,
`compare` and `inspect`, `mrjax inspect`, and the time-series figures of random records.

The three layouts of the issue (tests/helpers.py: a CSV with its own short headers in cm and
cm/s, a command voltage and non-data lines; a set of lab .mat files with per-file currents; a
.mat matrix without time, one test per column) are written at test time from the tanh model at
the paper's parameters for known currents, with 2 N noise, and fitted end to end from the
command line, with flags only and again with a spec file; the fitted parameters are checked
against the truth. Every bad spec gives one line, exit 2, and writes nothing.
"""

import json

import numpy as np
import pytest
from helpers import (
    CURRENTS,
    OPTIONS_A,
    OPTIONS_B,
    OPTIONS_C,
    TOML_A,
    TOML_B,
    TOML_C,
    check_fit_schema,
    check_pngs,
    exact,
    motion,
    one_error_line,
    outputs,
    previous_output,
    snapshot,
    tanh_force,
    write_layout_a,
    write_layout_b,
    write_layout_c,
)
from helpers import run_cli as run

import mrjax

N_SAMPLES = 3000
NOISE_N = 2.0
#: The flags a user types for each layout (the option strings of tests/helpers.py).
FLAG_NAMES = {"columns": "--columns", "wide": "--wide", "sample_rate": "--sample-rate",
              "current": "--current"}


def flags(options: dict) -> list[str]:
    """`OPTIONS_*` as command-line flags."""
    return [a for k, v in options.items() for a in (FLAG_NAMES[k], v)]


@pytest.fixture(scope="module")
def layouts(tmp_path_factory):
    """The three layouts and their spec files, written once."""
    d = tmp_path_factory.mktemp("layouts")
    for sub in ("a", "b", "c"):
        (d / sub).mkdir()
    truth = {
        "a": write_layout_a(d / "a" / "random.csv", n=N_SAMPLES, noise=NOISE_N),
        "b": write_layout_b(d / "b", n=N_SAMPLES, noise=NOISE_N),
        "c": write_layout_c(d / "c" / "lab.mat", n=N_SAMPLES, noise=NOISE_N),
    }
    for sub, toml in (("a", TOML_A), ("b", TOML_B), ("c", TOML_C)):
        (d / f"{sub}.toml").write_text(toml)
    return dict(
        root=d, truth=truth,
        files={"a": [d / "a" / "random.csv"], "b": [d / "b"], "c": [d / "c" / "lab.mat"]},
        options={"a": OPTIONS_A, "b": OPTIONS_B, "c": OPTIONS_C},
    )


def data_args(layouts, layout: str, kind: str) -> list:
    """FILES plus the data options of a layout: flags only, or the spec file."""
    files = layouts["files"][layout]
    if kind == "flags":
        return [*files, *flags(layouts["options"][layout])]
    return [*files, "--spec", layouts["root"] / f"{layout}.toml"]


#: Per layout: the labels, currents and estimated fields (by flags, by spec) of its tests.
EXPECT = {
    "a": (["random"], [None], (["amplitude", "frequency"], ["amplitude", "frequency"])),
    "b": (["ensaio.B.1", "ensaio.B.2"], [0.5, 1.0],
          (["amplitude", "frequency"],  # velocity from the matrix
           ["amplitude", "frequency", "xdot"])),  # the spec reads the vector: estimated
    "c": ([f"lab_{j}" for j in range(5)], list(CURRENTS),
          (["amplitude", "frequency", "xdot"],) * 2),
}
#: The current whose paper parameters generated each test.
TRUE_CURRENT = {"a": [0.5], "b": [0.5, 1.0], "c": list(CURRENTS)}


# --------------------------------------------------------------------------------------------
# Each layout fitted end to end, flags only and with a spec file


@pytest.mark.parametrize("kind", ["flags", "spec"])
@pytest.mark.parametrize("layout", ["a", "b", "c"])
def test_fit_layout_end_to_end(layouts, layout, kind, tmp_path):
    out = tmp_path / "out"
    code, stdout, stderr = run(["fit", *data_args(layouts, layout, kind), "--model", "kwok",
                                "--generations", 8, "--no-plots", "--out", out])
    assert code == 0, stderr
    assert outputs(out) == ["fit.csv", "fit.json"]
    doc = json.loads((out / "fit.json").read_text())
    labels, currents, estimated = EXPECT[layout]
    check_fit_schema(doc, len(labels))
    conds = doc["conditions"]
    assert [c["label"] for c in conds] == labels
    assert [c["current_A"] for c in conds] == currents
    want = estimated[kind == "spec"]
    assert all(sorted(c["estimated"]) == want for c in conds)
    assert "estimated, not read" in stderr
    # (a)'s command voltage varies in time: fitted per test, with a warning
    assert ("the command varies in time" in stderr) == (layout == "a")
    names = doc["param_names"]
    for c, i in zip(conds, TRUE_CURRENT[layout]):
        truth = dict(zip(names, mrjax.data.paper_parameters(i).tolist()))
        got = c["params"]
        # 2 N noise on forces of 100-1000 N: every parameter within 1.5 % (measured: 0.52 %
        # at worst, c of lab_1; the same for the measured and the estimated velocity)
        for n, v in truth.items():
            assert got[n] == pytest.approx(v, rel=0.015), (c["label"], n, got[n], v)
        assert c["rms_N"] == pytest.approx(NOISE_N, rel=0.1)  # at the noise floor
        if "frequency" in c["estimated"]:  # the spectral peak, within the band of the motion
            assert 0.3 <= c["frequency_Hz"] <= 4.1


def test_fit_figures_loops_for_sines_force_against_time_for_random_records(tmp_path):
    """A sine test keeps its F-x / F-v loops; a random record gets force against time (whole,
    zoomed, residual). Both read without options: a UTFSM-style txt and a long CSV."""
    sine = mrjax.data.simulate("kwok", mrjax.data.paper_parameters(0.5), frequency=1.0,
                               amplitude=0.008, current=0.5, cycles=1.5, noise=NOISE_N)
    np.savetxt(tmp_path / "8mm1Hz0x5A.txt", np.column_stack([sine.t, sine.x * 1e3,
                                                             sine.xdot * 1e3, sine.force]))
    t, x, v = motion(N_SAMPLES)
    f = tanh_force(x, v, 0.5, noise=NOISE_N)
    rows = ["time_s,displacement_mm,velocity_mm_s,force_N,current_A"] + [
        f"{exact(a)},{exact(b * 1e3)},{exact(c * 1e3)},{exact(d)},0.5"
        for a, b, c, d in zip(t, x, v, f)]
    (tmp_path / "random.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    code, _, stderr = run(["fit", tmp_path / "8mm1Hz0x5A.txt", tmp_path / "random.csv",
                           "--model", "kwok", "--generations", 8, "--out", out])
    assert code == 0, stderr
    pngs = {p for p in outputs(out) if p.endswith(".png")}
    assert {"loops.png", "force_time.png"} <= pngs
    check_pngs(out, pngs)
    doc = json.loads((out / "fit.json").read_text())
    # read by the CSV's conventions (no spec): what the file lacks stays unknown, not estimated
    assert [c["frequency_Hz"] for c in doc["conditions"]] == [1.0, None]
    assert [c["estimated"] for c in doc["conditions"]] == [[], []]
    assert all(c["rms_N"] < 1.2 * NOISE_N for c in doc["conditions"])


def test_predict_and_compare_with_data_options(layouts, tmp_path):
    """Laws fitted on the wide matrix (flags) predict the .mat set (spec file); `compare
    --validate` reads both sets with one spec whose per-file entries each match one set."""
    fit_out = tmp_path / "fit"
    code, _, err = run(["fit", *data_args(layouts, "c", "flags"), "--model", "kwok",
                        "--generations", 8, "--generalize", "two-step", "--no-plots",
                        "--out", fit_out])
    assert code == 0, err
    out = tmp_path / "pred"
    code, stdout, err = run(["predict", "--fit", fit_out, *data_args(layouts, "b", "flags"),
                             "--out", out])
    assert code == 0, err
    assert outputs(out) == ["predict.csv", "predict.json", "predict_force_time.png",
                            "predict_rms_vs_current.png", "predicted.csv"]
    doc = json.loads((out / "predict.json").read_text())
    assert [c["current_A"] for c in doc["conditions"]] == [0.5, 1.0]
    assert all(c["estimated"] == ["frequency", "amplitude"] for c in doc["conditions"])
    assert all(c["rms_N"] < 3 * NOISE_N for c in doc["conditions"])  # laws exact in current
    assert "estimated" not in (out / "predict.csv").read_text().splitlines()[0]

    d = layouts["root"]
    out = tmp_path / "cmp"
    code, stdout, err = run(["compare", d / "b" / "ensaio.B.1.mat", "--validate",
                             d / "b" / "ensaio.B.2.mat", "--models", "bingham",
                             "--generalize", "none", "--max-generations", 5, "--no-plots",
                             *flags(OPTIONS_B), "--out", out])
    assert code == 0, err
    assert "matches none" not in err  # each per-file current matches one of the two sets
    doc = json.loads((out / "compare.json").read_text())
    assert "bingham" in json.dumps(doc)


def test_time_series_figures_keep_peaks_of_long_records():
    """A 60 s record at 1 kHz is drawn through its min/max envelope: a few thousand points per
    line that keep every peak; the zoom is centred on the largest force or given."""
    from mrjax.report import plot_force_time, plot_records

    t = np.arange(60_000) / 1000.0
    x = 0.01 * np.sin(2 * np.pi * 0.05 * t) * np.sin(2 * np.pi * 1.3 * t)
    v = np.gradient(x, t)
    f = tanh_force(x, v, 0.5, noise=NOISE_N)
    f[41_234] = f.max() + 900.0  # one spike
    cond = mrjax.data.Condition("long", 0.5, None, None, t, x, v, f,
                                command=np.full(t.size, 2.0), command_unit="V")
    batch = mrjax.data.make_batch([cond])
    model = f - 1.0
    fig = plot_force_time(None, batch, force=model[None], rms=[1.0])
    whole, zoom = fig.axes[0], fig.axes[2]
    measured = whole.lines[0].get_ydata()
    assert measured.size <= 4002 and measured.max() == f.max() and measured.min() == f.min()
    lo, hi = zoom.get_xlim()
    assert hi - lo == pytest.approx(60.0 / 8, rel=1e-3) and lo < t[41_234] < hi
    np.testing.assert_allclose(fig.axes[1].lines[0].get_ydata(), 1.0)  # the residual
    fig = plot_force_time(None, batch, force=model[None], zoom=(10.0, 10.5))
    assert fig.axes[2].get_xlim() == (10.0, 10.5)
    with pytest.raises(ValueError, match="t1 > t0"):
        plot_force_time(None, batch, force=model[None], zoom=(2.0, 1.0))
    fig = plot_records([cond] * 20, max_panels=3)
    assert len(fig.axes) == 3 * 4  # x, v, F and the command, for 3 of the 20
    assert "(3 of 20 conditions shown)" in fig.get_suptitle()
    assert "command [V]" in fig.axes[3].get_ylabel()


# --------------------------------------------------------------------------------------------
# mrjax inspect


@pytest.mark.parametrize("layout", ["a", "b", "c"])
def test_inspect_each_layout(layouts, layout, tmp_path):
    out = tmp_path / "out"
    code, stdout, stderr = run(["inspect", *data_args(layouts, layout, "flags"), "--out", out])
    assert code == 0, stderr
    assert outputs(out) == ["inspect.json", "inspect.png", "spec.toml"]
    check_pngs(out, ["inspect.png"])
    labels, currents, estimated = EXPECT[layout]
    lines = stdout.splitlines()
    for lab, line in zip(labels, lines):
        assert line.startswith(f"{lab}: {N_SAMPLES} samples at 1000 Hz (2.999 s)")
        assert "~" in line and "(estimated)" in line and "broadband" in line
    assert lines[-1].startswith(f"{len(labels)} test(s) from ")
    doc = json.loads((out / "inspect.json").read_text())
    assert [c["label"] for c in doc["conditions"]] == labels
    assert [c["current"] for c in doc["conditions"]] == currents
    truth = layouts["truth"][layout]
    ref = truth if layout != "b" else truth["ensaio.B.1.mat"]
    for c in doc["conditions"]:
        assert c["x_range"] == pytest.approx([ref["x"].min(), ref["x"].max()], rel=1e-12)
        assert sorted(c["estimated"]) == estimated[0]
    if layout == "a":  # the voltage command, kept as a voltage; the tolerated non-data lines
        assert "command 0.8" in lines[0] and " V" in lines[0]
        text = stdout
        for note in ("every line ends with a delimiter (ignored)", "1 empty line(s) skipped",
                     "column 'fs' is mostly empty (1 of 3000 cells filled), not used",
                     "column(s) 'acc' not used"):
            assert f"  random: {note}" in text, note
        assert doc["conditions"][0]["command_unit"] == "V"
    if layout == "c":  # one note for the five columns; the broadband warning in each line
        assert "  all 5 tests: no time column: time from the sample rate 1000 Hz" in stdout
        assert all("warning: no velocity column and the displacement is broadband" in ln
                   for ln in lines[:5])
        assert "mrjax: warning" not in stderr  # not repeated on stderr
    # The written spec is the one given: re-reading it gives the same report.
    code, again, err = run(["inspect", *layouts["files"][layout], "--spec", out / "spec.toml",
                            "--out", tmp_path / "again", "--no-plots"])
    assert code == 0, err
    assert again == stdout
    assert outputs(tmp_path / "again") == ["inspect.json", "spec.toml"]


def test_inspect_without_options_reads_files_by_their_conventions(tmp_path):
    grid = mrjax.data.paper_grid(currents=(0.5,), motions=((1.0, 0.008),), cycles=1)
    c = grid.condition(0)
    np.savetxt(tmp_path / "8mm1Hz0x5A.txt", np.column_stack([c.t, c.x * 1e3, c.xdot * 1e3,
                                                             c.force]))
    code, stdout, err = run(["inspect", tmp_path / "8mm1Hz0x5A.txt", "--out", tmp_path / "o"])
    assert code == 0, err
    assert stdout.splitlines()[0].startswith("8mm1Hz0x5A: 1000 samples at 1000 Hz")
    assert "f 1 Hz, A 8 mm; current 0.5 A" in stdout and "~" not in stdout
    assert outputs(tmp_path / "o") == ["inspect.json", "inspect.png"]  # no spec


def test_flags_override_single_keys_of_the_spec_file(layouts, tmp_path):
    files = layouts["files"]["c"]
    spec = layouts["root"] / "c.toml"
    code, stdout, err = run(["inspect", *files, "--spec", spec, "--sample-rate", "2 kHz",
                             "--current", "0,0.5,1,1.5,2", "--no-plots", "--out", tmp_path])
    assert code == 0, err
    doc = json.loads((tmp_path / "inspect.json").read_text())
    assert all(c["sample_rate"] == pytest.approx(2000.0) for c in doc["conditions"])
    assert [c["current"] for c in doc["conditions"]] == [0.0, 0.5, 1.0, 1.5, 2.0]
    assert stdout.startswith(f"lab_0: {N_SAMPLES} samples at 2000 Hz")
    written = (tmp_path / "spec.toml").read_text()
    assert "sample_rate_Hz = 2000.0" in written and 'force = ["M[1]:N"' in written


def test_units_on_the_command_line_against_hand_values(tmp_path):
    """Inches, pound-force and milliseconds through the flags: SI values by hand."""
    t, x, v = motion(600)
    f = tanh_force(x, v, 0.5)
    rows = ["ms;inch;lbf"] + [f"{exact(a * 1e3)};{exact(b / 0.0254)};{exact(c / 4.4482216152605)}"
                              for a, b, c in zip(t, x, f)]
    (tmp_path / "imperial.csv").write_text("\n".join(rows) + "\n")
    code, stdout, err = run(["inspect", tmp_path / "imperial.csv", "--columns",
                             "time=ms:ms,displacement=inch:in,force=lbf:lbf", "--current",
                             "500 mA", "--velocity-window", "15 ms", "--no-plots",
                             "--out", tmp_path / "o"])
    assert code == 0, err
    (c,) = json.loads((tmp_path / "o" / "inspect.json").read_text())["conditions"]
    assert c["x_range"] == pytest.approx([x.min(), x.max()], rel=1e-12)
    assert c["force_range"] == pytest.approx([f.min(), f.max()], rel=1e-12)
    assert c["duration"] == pytest.approx(t[-1], rel=1e-12)
    assert c["current"] == 0.5 and c["velocity"] == "estimated"
    assert "given window 0.015 s" in " ".join(c["notes"])


# --------------------------------------------------------------------------------------------
# Bad specs: one line, exit 2, nothing written


def _bad_csv(tmp_path):
    lines = ["Time,Disp,Load"] + [f"{k / 1000},{np.sin(k / 50)},{np.cos(k / 50)}"
                                  for k in range(200)]
    lines[6] = "0.005,abc,1.0"
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    return tmp_path / "bad.csv"


BAD = {
    "unknown column": (["--columns", "time=Time:s,displacement=Dsp:cm,force=Load:N"],
                       ["data.csv", "unknown column 'Dsp' (displacement)",
                        "columns present: Time, Disp, Load"]),
    "role given twice": (["--columns", "time=Time:s,force=Load:N,force=Disp:N"],
                         ["--columns: role 'force' given twice"]),
    "wrong dimension": (["--columns", "time=Time:s,displacement=Disp:N,force=Load:N"],
                        ["--columns: displacement unit 'N' is not a length"]),
    "missing rate without time": (["--columns", "displacement=Disp:cm,force=Load:N"],
                                  ["data.csv", "no time column and no sample rate"]),
    "malformed spec file": (["--spec", "SPEC"], ["s.toml", "malformed spec file", "line 2"]),
    "missing spec file": (["--spec", "nope.toml"], ["nope.toml", "no such spec file"]),
    "non-numeric cell": (["--columns", "time=Time:s,displacement=Disp:cm,force=Load:N", "BAD"],
                         ["bad.csv", "line 7", "column 'Disp'", "not a number: 'abc'"]),
    "per-test values without wide": (["--current", "0.1,0.2"], ["--current:",
                                                                "need a wide layout"]),
    "lists of different lengths": (["--wide", "force=1,2:N", "--current", "0,1,2"],
                                   ["--wide, --current:", "differ in length"]),
    "bad sample rate": (["--sample-rate", "fast"], ["--sample-rate:", "'fast'"]),
}


@pytest.mark.parametrize("command", ["fit", "inspect"])
@pytest.mark.parametrize("case", list(BAD))
def test_bad_spec_one_line_exit_2_nothing_written(case, command, tmp_path):
    rows = ["Time,Disp,Load"] + [f"{k / 1000},{np.sin(k / 50)},{np.cos(k / 50)}"
                                 for k in range(200)]
    (tmp_path / "data.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "s.toml").write_text('[columns]\ntime = t:s\n')
    argv, needles = BAD[case]
    files = [tmp_path / "data.csv"]
    argv = [str(tmp_path / "s.toml") if a == "SPEC" else a for a in argv]
    if "BAD" in argv:
        argv.remove("BAD")
        files = [_bad_csv(tmp_path)]
    existing = previous_output(tmp_path / "existing", command)
    before = snapshot(existing)
    extra = ["--model", "kwok"] if command == "fit" else []
    for out in (existing, tmp_path / "new"):
        code, stdout, err = run([command, *files, *argv, *extra, "--out", out])
        assert code == 2, err
        line = one_error_line(err)
        for n in needles:
            assert n in line, (n, line)
        assert stdout == "" and "fitting" not in err and "writing" not in err
    assert snapshot(existing) == before and not (tmp_path / "new").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".mrjax")]


def test_generalize_without_current_fails_before_fitting(layouts, tmp_path):
    code, stdout, err = run(["fit", *data_args(layouts, "a", "flags"), "--model", "kwok",
                             "--generalize", "two-step", "--out", tmp_path / "o"])
    assert code == 2 and stdout == "" and "fitting" not in err
    line = one_error_line(err)
    # layout (a) has no current and a command voltage that varies in time: only the joint
    # identification (laws of the command) can generalize it
    assert "--generalize two-step needs --generalize joint" in line and "'random'" in line
    assert "varies in time" in line and not (tmp_path / "o").exists()


def test_generalize_without_current_or_command_fails_before_fitting(layouts, tmp_path):
    """Layout (a) read without its command column: no current for --generalize."""
    columns = OPTIONS_A["columns"].replace(",command=V:V", "")
    code, stdout, err = run(["fit", *layouts["files"]["a"], "--columns", columns, "--model",
                             "kwok", "--generalize", "two-step", "--out", tmp_path / "o"])
    assert code == 2 and stdout == "" and "fitting" not in err
    line = one_error_line(err)
    assert "--generalize needs the current of every test" in line and "'random'" in line
    assert "--current" in line and not (tmp_path / "o").exists()


def test_data_options_in_help():
    for command in ("fit", "predict", "compare", "inspect"):
        code, out, _ = run([command, "--help"])
        assert code == 0
        for flag in ("--spec", "--columns", "--wide", "--sample-rate", "--current",
                     "--frequency", "--amplitude", "--label", "--velocity-window"):
            assert flag in out, (command, flag)


def test_readme_examples_are_the_tested_ones():
    """The data guide's commands use the flags fitted above, and its spec files say the same."""
    import re
    import tomllib
    from pathlib import Path

    section = (Path(__file__).resolve().parents[1] / "docs" / "how-to" / "data.md").read_text()
    specs = dict(re.findall(r"```toml\n# (\S+)\n(.*?)```", section, re.S))
    assert set(specs) == {"random.toml", "campaign.toml", "lab.toml"}
    for name, options in (("random.toml", OPTIONS_A), ("campaign.toml", OPTIONS_B),
                          ("lab.toml", OPTIONS_C)):
        for flag, value in zip(flags(options)[::2], flags(options)[1::2]):
            quoted = f"{flag} '{value}'" if "[" in value else f"{flag} {value}"
            assert quoted in section, quoted
        from_file = mrjax.data.DataSpec.from_dict(tomllib.loads(specs[name]))
        from_flags = mrjax.data.DataSpec.from_options(**options)
        assert from_file == from_flags.replace(origin=""), name


def test_inspect_shows_the_measured_amplitude_beside_a_nominal_one(tmp_path):
    """A UTFSM-style name gives the nominal amplitude (2 mm); the record spans +-1.62 mm:
    `inspect` shows both. Where they agree (within 2 %) only the one value is shown."""
    for name, amp in (("2mm5Hz0A.txt", 1.62e-3), ("10mm1Hz0A.txt", 10e-3)):
        t, x, v = mrjax.data.sine_excitation(1.0, amp, sample_rate=200.0, cycles=3)
        f = 300.0 * np.tanh(v / 0.01)
        np.savetxt(tmp_path / name, np.column_stack([t, x * 1e3, v * 1e3, f]))
    code, stdout, err = run(["inspect", tmp_path / "2mm5Hz0A.txt", tmp_path / "10mm1Hz0A.txt",
                             "--no-plots", "--out", tmp_path / "o"])
    assert code == 0, err
    small, large = (ln for ln in stdout.splitlines() if ln.startswith(("2mm", "10mm")))
    assert "A 2 mm nominal, 1.62 mm measured (half the range)" in small, small
    assert "A 10 mm" in large and "nominal" not in large, large
    doc = json.loads((tmp_path / "o" / "inspect.json").read_text())
    np.testing.assert_allclose([c["amplitude_measured"] for c in doc["conditions"]],
                               [1.62e-3, 10e-3], rtol=1e-3)
