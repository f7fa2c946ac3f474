"""The data spec: any column names, units and layouts, from options, a TOML file or pandas.

The three layouts of issue 14 are generated at test time from mrjax's own tanh model with
known parameters, loaded with the option strings the command line passes (`from_options`) and
with a spec file (`from_toml`), and checked against hand-converted values.
"""

import json
import math
import warnings

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
    motion,
    tanh_force,
    write_layout_a,
    write_layout_b,
    write_layout_c,
)
from helpers import exact as _r

import mrjax.data as md
from mrjax._errors import InputError


def _raises(fn, *needles):
    with pytest.raises(InputError) as info:
        fn()
    msg = str(info.value)
    assert "\n" not in msg
    for n in needles:
        assert n in msg, f"{n!r} not in {msg!r}"
    return msg


def _spec(kind, tmp_path, options, toml):
    if kind == "options":
        return md.DataSpec.from_options(**options)
    (tmp_path / "spec.toml").write_text(toml)
    return md.DataSpec.from_toml(tmp_path / "spec.toml")


@pytest.mark.parametrize("kind", ["options", "toml"])
def test_layout_a_csv(tmp_path, kind):
    truth = write_layout_a(tmp_path / "random.csv")
    spec = _spec(kind, tmp_path, OPTIONS_A, TOML_A)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # nothing suspicious in these units
        (c,) = md.load(tmp_path / "random.csv", spec=spec)
    assert c.label == "random" and c.current is None
    np.testing.assert_allclose(c.t, truth["t"], rtol=0, atol=1e-15)
    np.testing.assert_allclose(c.x, truth["x"], rtol=1e-14, atol=1e-18)  # cm -> m
    np.testing.assert_allclose(c.xdot, truth["v"], rtol=1e-14, atol=1e-17)  # cm/s -> m/s
    np.testing.assert_allclose(c.force, truth["force"], rtol=1e-14)
    np.testing.assert_allclose(c.command, truth["volt"], rtol=1e-14)
    assert c.command_unit == "V"  # kept as a voltage
    assert c.estimated == {"frequency", "amplitude"}  # velocity measured
    notes = " | ".join(c.notes)
    assert "ends with a delimiter" in notes and "empty line" in notes
    assert "'fs' is mostly empty (1 of 3000" in notes and "'acc'" in notes
    # Frequency and amplitude estimated: the spectral peak of a 3 s record of 0.3-4.1 Hz
    # motion (dominated by its lowest components); half the range.
    assert 0.2 < c.frequency < 1.2
    assert c.amplitude == pytest.approx(0.5 * np.ptp(truth["x"]), rel=0.02)


@pytest.mark.parametrize("kind", ["options", "toml"])
def test_layout_b_mat_files(tmp_path, kind):
    truth = write_layout_b(tmp_path)
    spec = _spec(kind, tmp_path, OPTIONS_B, TOML_B)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        conds = md.load(tmp_path, spec=spec)
    # Random motion whose velocity is estimated (the TOML names the displacement vector):
    # a broadband warning per file; none when the velocity is measured.
    assert len(rec) == (0 if kind == "options" else 2)
    assert all("ensaio.B." in str(w.message) and "broadband" in str(w.message) for w in rec)
    assert [c.label for c in conds] == ["ensaio.B.1", "ensaio.B.2"]
    for c, (name, ref) in zip(conds, truth.items()):
        assert c.current == pytest.approx(ref["current"]) and "current" not in c.estimated
        assert c.source.endswith(name)
        np.testing.assert_allclose(c.x, ref["x"], rtol=1e-14, atol=1e-18)
        np.testing.assert_allclose(c.force, ref["force"], rtol=1e-14)
        if kind == "options":  # from the matrix: measured velocity
            np.testing.assert_allclose(c.xdot, ref["v"], rtol=1e-14, atol=1e-17)
            assert "xdot" not in c.estimated
        else:  # from the vector: estimated velocity
            assert "xdot" in c.estimated
            assert np.sqrt(np.mean((c.xdot - ref["v"]) ** 2) / np.mean(ref["v"] ** 2)) < 1e-3


@pytest.mark.parametrize("kind", ["options", "toml"])
def test_layout_c_wide_matrix_without_time(tmp_path, kind):
    truth = write_layout_c(tmp_path / "lab.mat")
    spec = _spec(kind, tmp_path, OPTIONS_C, TOML_C)
    with pytest.warns(RuntimeWarning, match=r"lab.mat \(force (M\[)?\d\]?\): no velocity column "
                                            r"and the displacement is broadband"):
        conds = md.load(tmp_path / "lab.mat", spec=spec)
    assert [c.label for c in conds] == [f"lab_{j}" for j in range(5)]
    assert [c.current for c in conds] == list(CURRENTS)
    for c, force in zip(conds, truth["forces"]):
        np.testing.assert_allclose(c.t, truth["t"], rtol=1e-15, atol=1e-15)  # from the rate
        np.testing.assert_allclose(c.x, truth["x"], rtol=1e-14, atol=1e-18)
        np.testing.assert_allclose(c.force, force, rtol=1e-14)
        assert c.estimated == {"xdot", "frequency", "amplitude"}
        assert np.sqrt(np.mean((c.xdot - truth["v"]) ** 2) / np.mean(truth["v"] ** 2)) < 1e-3
        assert any("sample rate 1000 Hz" in n for n in c.notes)
    batch = md.make_batch(conds)
    np.testing.assert_allclose(np.asarray(batch.current), CURRENTS)


def test_layout_c_bare_columns_and_named_columns_agree(tmp_path):
    write_layout_c(tmp_path / "lab.mat")
    window = dict(velocity_window="9 ms")  # given: no broadband warning
    a = md.load(tmp_path / "lab.mat", spec=md.DataSpec.from_options(**OPTIONS_C, **window))
    b = md.load(tmp_path / "lab.mat", spec=md.DataSpec.from_options(
        columns="displacement=M[0]:mm", wide="force=M[1]:N,M[2]:N,M[3]:N,M[4]:N,M[5]:N",
        current=list(CURRENTS), sample_rate="1 kHz", **window))
    for ca, cb in zip(a, b):
        np.testing.assert_array_equal(ca.force, cb.force)
        assert ca.current == cb.current


def test_headerless_text_tolerates_what_the_spec_does_not_use(tmp_path):
    t, x, v = motion(1500)
    f = tanh_force(x, v, 0.5)
    lines = ["time disp vel force status", "s mm mm/s N -"]
    lines += [f"{_r(a)};{_r(b * 1e3)};{_r(c * 1e3)};{_r(d)};{'ok' if k % 7 else 'n/a'};"
              for k, (a, b, c, d) in enumerate(zip(t, x, v, f))]
    (tmp_path / "run.dat").write_text("\n".join(lines) + "\n\n")
    spec = md.DataSpec.from_options(columns="time=0:s,displacement=1:mm,velocity=2:mm/s,force=3:N",
                                    current=0.5)
    (c,) = md.load(tmp_path / "run.dat", spec=spec)
    np.testing.assert_allclose(c.x, x, rtol=1e-14, atol=1e-18)
    np.testing.assert_allclose(c.xdot, v, rtol=1e-14, atol=1e-17)
    assert c.current == 0.5
    notes = " | ".join(c.notes)
    assert "line(s) 1, 2 not data (skipped)" in notes and "column(s) 4 not used" in notes
    assert md.find_files(tmp_path) == [tmp_path / "run.dat"]
    lines[700] = lines[700].replace(";", ";x", 1)
    (tmp_path / "run.dat").write_text("\n".join(lines) + "\n")
    _raises(lambda: md.load(tmp_path / "run.dat", spec=spec), "run.dat", "line 701",
            "column 1 (displacement)", "not a number")


# --------------------------------------------------------------------------------------------
# The spec object


def test_column_parse():
    c = md.Column.parse("Disp:cm")
    assert (c.name, c.index, c.unit, c.source, str(c)) == ("Disp", None, "cm", "Disp", "Disp:cm")
    c = md.Column.parse("data[2]:N")
    assert (c.name, c.index, c.unit, str(c)) == ("data", 2, "N", "data[2]:N")
    c = md.Column.parse(" 3 : mm ")
    assert (c.name, c.index, c.unit, str(c)) == (None, 3, "mm", "3:mm")
    c = md.Column.parse("displacement_mm")
    assert (c.name, c.unit) == ("displacement_mm", None)
    assert md.Column.parse(4) == md.Column(None, 4, None)


def test_spec_from_options_and_toml_agree(tmp_path):
    opts = md.DataSpec.from_options(
        columns="time=Time:ms,displacement=Disp:cm,force=Load:lbf", sample_rate="2 kHz",
        current="500 mA", frequency=1.5, amplitude="8 mm", label="run",
        velocity_window="20 ms")
    (tmp_path / "s.toml").write_text("""
[columns]
time = "Time:ms"
displacement = "Disp:cm"
force = "Load:lbf"
[meta]
sample_rate_kHz = 2
current_mA = 500
frequency_Hz = 1.5
amplitude_mm = 8
label = "run"
[velocity]
window_ms = 20
""")
    toml = md.DataSpec.from_toml(tmp_path / "s.toml")
    assert dict(opts.columns) == dict(toml.columns)
    assert opts.meta == toml.meta == md.Meta("run", 0.5, 1.5, 0.008, 2000.0)
    assert opts.velocity_window == toml.velocity_window == pytest.approx(0.02)
    assert toml.origin == str(tmp_path / "s.toml")
    assert not opts.is_empty and md.DataSpec().is_empty and md.DataSpec.from_options().is_empty


@pytest.mark.parametrize("toml", [TOML_A, TOML_B, TOML_C])
def test_to_toml_round_trip(tmp_path, toml):
    (tmp_path / "a.toml").write_text(toml)
    spec = md.DataSpec.from_toml(tmp_path / "a.toml").with_options(velocity_window="15 ms",
                                                                  label="x")
    (tmp_path / "b.toml").write_text(spec.to_toml())
    back = md.DataSpec.from_toml(tmp_path / "b.toml")
    assert back.replace(origin="") == spec.replace(origin="")


def test_suffix_names_carry_their_unit():
    spec = md.DataSpec.from_options(columns="displacement=displacement_cm,force=force_lbf")
    assert spec.columns["displacement"].unit == "cm"
    assert spec.columns["force"].unit == "lbf"


def test_options_override_single_keys_of_a_file(tmp_path):
    (tmp_path / "s.toml").write_text(TOML_C)
    base = md.DataSpec.from_toml(tmp_path / "s.toml")
    spec = base.with_options(columns="displacement=0:cm", sample_rate=500, current=None)
    assert spec.columns["displacement"].unit == "cm"  # overridden
    assert spec.meta.sample_rate == 500.0
    assert len(spec.wide["force"]) == 5 and spec.wide_meta == base.wide_meta  # kept
    # A flag naming a wide role replaces the wide layout's role by a shared column.
    one = base.with_options(columns="force=1:kN")
    assert "force" not in one.wide and one.columns["force"] == md.Column(None, 1, "kN")
    assert one.wide_meta == ()
    # Per-file metadata merge per file and key.
    spec = md.DataSpec.from_options(current="a.mat=0.5,b*.mat=1").merged(
        md.DataSpec.from_options(frequency="a.mat=2"))
    assert spec.file_meta("x/a.mat") == md.Meta(current=0.5, frequency=2.0)
    assert spec.file_meta("b7.mat").current == 1.0 and spec.file_meta("c.mat").current is None
    assert spec.replace(velocity_window=0.01).velocity_window == 0.01
    # Per-test values refer to the file's wide layout and override per test and key.
    (tmp_path / "w.toml").write_text(TOML_C + "frequency_Hz = [1, 2, 3, 4, 5]\n")
    wide = md.DataSpec.from_toml(tmp_path / "w.toml").with_options(current="0,0.5,1,1.5,2")
    assert dict(wide.wide) == dict(base.wide)
    assert [(m.current, m.frequency) for m in wide.wide_meta] == [
        (0.0, 1.0), (0.5, 2.0), (1.0, 3.0), (1.5, 4.0), (2.0, 5.0)]
    _raises(lambda: base.with_options(current="0,1"), "differ in length", "current: 2")


# --------------------------------------------------------------------------------------------
# Bad specs: one clear line each


def _csv(tmp_path, name="data.csv"):
    t, x, v = motion(200)
    f = tanh_force(x, v, 0.5)
    rows = ["Time,Disp,Load"] + [f"{_r(a)},{_r(b * 100)},{_r(c)}" for a, b, c in zip(t, x, f)]
    (tmp_path / name).write_text("\n".join(rows) + "\n")
    return tmp_path / name


def test_bad_unknown_column(tmp_path):
    path = _csv(tmp_path)
    spec = md.DataSpec.from_options(columns="time=Time:s,displacement=Disp:cm,force=Force:N")
    _raises(lambda: md.load(path, spec=spec), "data.csv", "unknown column 'Force' (force)",
            "columns present: Time, Disp, Load")


def test_bad_role_given_twice(tmp_path):
    _raises(lambda: md.DataSpec.from_options(columns="force=Load:N,force=F:N"),
            "role 'force' given twice")
    (tmp_path / "s.toml").write_text('[columns]\nforce = "F:N"\n[wide]\nforce = ["a:N"]\n')
    _raises(lambda: md.DataSpec.from_toml(tmp_path / "s.toml"), "s.toml",
            "role 'force' given twice")
    _raises(lambda: md.DataSpec.from_options(columns="current=I:A,command=V:V"),
            "current or a command column, not both")


def test_bad_wrong_dimension(tmp_path):
    _raises(lambda: md.DataSpec.from_options(columns="displacement=Disp:N"),
            "displacement unit 'N' is not a length")
    _raises(lambda: md.DataSpec.from_options(columns="command=V:N"),
            "command unit 'N' is not a current or a voltage")
    (tmp_path / "s.toml").write_text('[columns]\nvelocity = "v:mm"\n')
    _raises(lambda: md.DataSpec.from_toml(tmp_path / "s.toml"), "s.toml",
            "velocity unit 'mm' is not a velocity")
    _raises(lambda: md.DataSpec.from_options(current="3 V"), "current unit 'V' is not a current")


def test_bad_missing_rate_without_time(tmp_path):
    write_layout_c(tmp_path / "lab.mat")
    spec = md.DataSpec.from_options(columns="displacement=0:mm", wide="force=1,2:N")
    _raises(lambda: md.load(tmp_path / "lab.mat", spec=spec), "lab.mat",
            "no time column and no sample rate", "sample_rate_Hz")


def test_bad_malformed_spec_file(tmp_path):
    (tmp_path / "s.toml").write_text('[columns]\ntime = "t:s"\nforce = F:N\n')
    _raises(lambda: md.DataSpec.from_toml(tmp_path / "s.toml"), "s.toml",
            "malformed spec file", "line 3")
    _raises(lambda: md.DataSpec.from_toml(tmp_path / "none.toml"), "none.toml", "no such")
    (tmp_path / "s.toml").write_text('[colums]\ntime = "t:s"\n')
    _raises(lambda: md.DataSpec.from_toml(tmp_path / "s.toml"), "unknown key 'colums'",
            "columns, meta, wide, files, velocity")
    (tmp_path / "s.toml").write_text('[meta]\ncurent_A = 0.5\n')
    _raises(lambda: md.DataSpec.from_toml(tmp_path / "s.toml"), "[meta]",
            "unknown key 'curent_A'")
    (tmp_path / "s.toml").write_text('[columns]\ndisp = "x:mm"\n')
    _raises(lambda: md.DataSpec.from_toml(tmp_path / "s.toml"), "unknown role 'disp'",
            "displacement")
    (tmp_path / "s.toml").write_text('[wide]\nforce = ["1:N", "2:N"]\ncurrent_A = [0.1]\n')
    _raises(lambda: md.DataSpec.from_toml(tmp_path / "s.toml"), "lists differ in length",
            "force: 2", "current_A: 1")


def test_bad_non_numeric_cell(tmp_path):
    path = _csv(tmp_path)
    lines = path.read_text().splitlines()
    lines[5] = lines[5].split(",")[0] + ",abc," + lines[5].split(",")[2]
    path.write_text("\n".join(lines) + "\n")
    spec = md.DataSpec.from_options(columns="time=Time:s,displacement=Disp:cm,force=Load:N")
    _raises(lambda: md.load(path, spec=spec), "data.csv", "line 6", "column 'Disp'",
            "not a number: 'abc'")


def test_bad_other_specs(tmp_path):
    _raises(lambda: md.DataSpec.from_options(columns="displacement=Disp"),
            "displacement column 'Disp' needs a unit", "'Disp:mm'")
    _raises(lambda: md.DataSpec.from_options(columns="displacement"), "KEY=VALUE")
    _raises(lambda: md.DataSpec.from_options(current="0.1,0.2"), "need a wide layout")
    _raises(lambda: md.DataSpec.from_options(wide="force=1,2:N", current="0.1,0.2,0.3"),
            "differ in length")
    _raises(lambda: md.DataSpec.from_options(sample_rate="-5"), "sample_rate", "positive")
    _raises(lambda: md.DataSpec.from_options(velocity_window="0 s"), "positive")
    path = _csv(tmp_path)
    _raises(lambda: md.load(path, spec=md.DataSpec.from_options(columns="time=Time:s")),
            "data.csv", "no displacement column")
    _raises(lambda: md.load(path, spec=md.DataSpec(velocity_window=0.01), units=("s",)),
            "not both")
    write_layout_c(tmp_path / "lab.mat")
    spec = md.DataSpec.from_options(columns="displacement=0:mm", wide="force=1,9:N",
                                    sample_rate=1000)
    _raises(lambda: md.load(tmp_path / "lab.mat", spec=spec), "lab.mat", "M[9]",
            "does not exist", "6 column(s)")
    spec = md.DataSpec.from_options(columns="displacement=X[0]:mm,force=M[1]:N", sample_rate=1)
    _raises(lambda: md.load(tmp_path / "lab.mat", spec=spec), "variable 'X' (displacement)",
            "variables present: M")


# --------------------------------------------------------------------------------------------
# Metadata, file names, legacy behaviour


def test_metadata_precedence_and_file_names(tmp_path):
    t, x, v = motion(2000)
    data = np.column_stack([t, x * 1e3, v * 1e3, tanh_force(x, v, 0.75)])
    np.savetxt(tmp_path / "8mm1Hz0x75A.txt", data)
    np.savetxt(tmp_path / "run1.txt", data)
    # No spec: file names are required (today's behaviour).
    _raises(lambda: md.load(tmp_path / "run1.txt"), "cannot read amplitude")
    # A spec: the name is read where it parses; otherwise unknown (frequency and amplitude
    # estimated). The spec's values win over the name's.
    spec = md.DataSpec.from_options(frequency="run1=0.3")
    named, run1 = md.load([tmp_path / "8mm1Hz0x75A.txt", tmp_path / "run1.txt"], spec=spec)
    assert (named.current, named.frequency, named.amplitude) == (0.75, 1.0, 0.008)
    assert named.estimated == frozenset()
    assert run1.current is None and run1.frequency == 0.3
    assert run1.estimated == {"amplitude"}
    np.testing.assert_allclose(run1.x, x, rtol=1e-9)
    (c,) = md.load(tmp_path / "8mm1Hz0x75A.txt", spec=md.DataSpec.from_options(current=2))
    assert c.current == 2.0 and c.frequency == 1.0


def test_file_content_beats_the_file_name(tmp_path):
    t, x, v = motion(600)
    rows = ["current_A,time_s,displacement_mm,force_N"] + [
        f"0.5,{_r(a)},{_r(b * 1e3)},{_r(c)}" for a, b, c in zip(t, x, tanh_force(x, v, 0.5))]
    (tmp_path / "10mm1Hz1A.csv").write_text("\n".join(rows) + "\n")
    spec = md.DataSpec.from_options(velocity_window=0.011)
    (c,) = md.load(tmp_path / "10mm1Hz1A.csv", spec=spec)
    assert (c.current, c.frequency, c.amplitude) == (0.5, 1.0, 0.010)  # column, name, name
    (c,) = md.load(tmp_path / "10mm1Hz1A.csv", spec=spec.with_options(current=2))
    assert c.current == 2.0  # the spec beats both


def test_empty_spec_is_todays_behaviour(tmp_path):
    t, x, v = motion(500)
    np.savetxt(tmp_path / "8mm1Hz0x5A.txt", np.column_stack([t, x * 1e3, tanh_force(x, v, 0.5)]))
    a = md.load(tmp_path)
    b = md.load(tmp_path, spec=md.DataSpec())
    np.testing.assert_array_equal(a[0].xdot, b[0].xdot)
    assert a[0].estimated == {"xdot"} and a[0].frequency == 1.0


def test_spec_files_pattern_matching_nothing_warns(tmp_path):
    write_layout_b(tmp_path)
    spec = md.DataSpec.from_options(**OPTIONS_B).with_options(current="ensaio.C.*=2")
    with pytest.warns(RuntimeWarning, match="'ensaio.C.\\*' matches none"):
        md.load(tmp_path, spec=spec)


def test_varying_current_column_becomes_the_command(tmp_path):
    t, x, v = motion(1000)
    i = 0.5 + 0.3 * np.sin(2 * np.pi * 0.5 * t)
    rows = ["time_s,displacement_mm,force_N,I_mA"] + [
        f"{_r(a)},{_r(b * 1e3)},{_r(c)},{_r(d * 1e3)}"
        for a, b, c, d in zip(t, x, tanh_force(x, v, 0.5), i)]
    (tmp_path / "var.csv").write_text("\n".join(rows) + "\n")
    spec = md.DataSpec.from_options(
        columns="time=time_s,displacement=displacement_mm,force=force_N,current=I_mA:mA",
        velocity_window=0.011)
    (c,) = md.load(tmp_path / "var.csv", spec=spec)
    assert c.command_unit == "A" and c.current is None
    np.testing.assert_allclose(c.command, i, rtol=1e-14)
    # A constant current column is the condition's current, not a command.
    rows = [r.rsplit(",", 1)[0] + ",250" for r in rows[1:]]
    (tmp_path / "const.csv").write_text("time_s,displacement_mm,force_N,I_mA\n" + "\n".join(rows))
    (c,) = md.load(tmp_path / "const.csv", spec=spec)
    assert c.current == pytest.approx(0.25) and c.command is None


# --------------------------------------------------------------------------------------------
# pandas


def test_frame_round_trip():
    pytest.importorskip("pandas")
    t, x, v = motion(400)
    a = md.simulate("kwok", md.paper_parameters(0.5), frequency=2.0, amplitude=0.004,
                    current=0.5)
    b = md.Condition("b", None, 1.3, None, t, x, v, tanh_force(x, v, 0.2),
                     command=np.linspace(0.0, 2.0, t.size), command_unit="V")
    df = md.to_frame([a, b])
    assert list(df.columns) == ["condition", "current_A", "frequency_Hz", "amplitude_m",
                                "time_s", "displacement_m", "velocity_m_s", "force_N",
                                "command_V"]
    got = md.from_frame(df)
    assert [c.label for c in got] == [a.label, "b"]
    for c, ref in zip(got, (a, b)):
        for k in ("t", "x", "xdot", "force"):
            np.testing.assert_array_equal(getattr(c, k), getattr(ref, k))
        assert c.current == ref.current and c.frequency == ref.frequency
    assert got[0].command is None and got[0].amplitude == a.amplitude
    np.testing.assert_array_equal(got[1].command, b.command)
    assert got[1].command_unit == "V"
    assert got[1].estimated == {"amplitude"}  # unknown in the frame: estimated
    # A frame with its own names, through a spec; a batch converts too.
    df2 = df.rename(columns={"time_s": "T", "displacement_m": "X", "force_N": "F"})
    df2["X"] *= 100
    spec = md.DataSpec.from_options(columns="time=T:s,displacement=X:cm,force=F:N,"
                                            "condition=condition")
    got2 = md.from_frame(df2, spec)
    np.testing.assert_allclose(got2[1].x, x, rtol=1e-14)
    assert "xdot" in got2[1].estimated
    assert len(md.to_frame(md.make_batch([a, b]))) == len(df)
    _raises(lambda: md.from_frame(df.assign(force_N="x")), "DataFrame", "row 0",
            "'force_N'", "not a number")


# --------------------------------------------------------------------------------------------
# The per-sample command through batching and padding


def test_command_through_batch_subset_and_padding():
    t, x, v = motion(300)
    cmd = np.linspace(0.0, 1.0, 200)
    a = md.Condition("a", None, None, None, t[:200], x[:200], v[:200], tanh_force(x, v, 0)[:200],
                     command=cmd, command_unit="A")
    b = md.simulate("kwok", md.paper_parameters(1.0), frequency=1.0, amplitude=0.008,
                    current=1.0, cycles=0.3)
    batch = md.make_batch([a, b])
    assert batch.command.shape == (2, 300)
    np.testing.assert_array_equal(np.asarray(batch.command[0, :200]), cmd)
    np.testing.assert_array_equal(np.asarray(batch.command[0, 200:]), 1.0)  # last value held
    np.testing.assert_array_equal(np.asarray(batch.command[1]), 0.0)
    np.testing.assert_array_equal(np.asarray(batch.command_kind), [1, 0])
    np.testing.assert_array_equal(batch.has_command, [True, False])
    assert md.COMMAND_UNITS[int(batch.command_kind[0])] == "A"
    back = batch.condition(0)
    np.testing.assert_array_equal(back.command, cmd)
    assert back.command_unit == "A" and batch.condition(1).command is None
    sub = batch.subset([1, 0])
    np.testing.assert_array_equal(sub.has_command, [False, True])
    from mrjax.parallel import pad_conditions

    padded, mask, n = pad_conditions(batch, None, 3)
    assert n == 2 and padded.n_conditions == 3
    np.testing.assert_array_equal(np.asarray(padded.command_kind), [1, 0, 0])
    np.testing.assert_array_equal(np.asarray(padded.estimated), np.asarray(batch.estimated)[[0, 1, 1]])
    assert padded.labels[-1] == "b_1Hz_8mm_1A#pad0" or padded.labels[-1].endswith("#pad0")


def test_condition_validates_the_command():
    t, x, v = motion(50)
    f = tanh_force(x, v, 0)
    _raises(lambda: md.Condition("c", None, None, None, t, x, v, f, command=t[:-1],
                                 command_unit="V"), "mismatched column lengths", "'command': 49")
    bad = t.copy()
    bad[3] = np.nan
    _raises(lambda: md.Condition("c", None, None, None, t, x, v, f, command=bad,
                                 command_unit="V"), "column command", "row 3")
    _raises(lambda: md.Condition("c", None, None, None, t, x, v, f, command=t),
            "command_unit")
    _raises(lambda: md.Condition("c", None, None, None, t, x, v, f, command=t,
                                 command_unit="mA"), "command_unit")
    _raises(lambda: md.Condition("c", None, None, None, t, x, v, f, estimated={"force"}),
            "unknown field(s) force")
    # Positional construction of before issue 14 still works.
    c = md.Condition("c", 0.5, 1.0, 0.008, t, x, v, f, "src")
    assert c.source == "src" and c.command is None and c.estimated == frozenset()


# --------------------------------------------------------------------------------------------
# Sanity checks


def _measured(tmp_path, v_scale, x_unit="mm", v_unit="mm/s", x_scale=1e3, name="s.csv"):
    t, x, v = motion(2000)
    rows = ["T,X,V,F"] + [f"{_r(a)},{_r(b * x_scale)},{_r(c * v_scale)},{_r(d)}"
                          for a, b, c, d in zip(t, x, v, tanh_force(x, v, 0.5))]
    (tmp_path / name).write_text("\n".join(rows) + "\n")
    spec = md.DataSpec.from_options(
        columns=f"time=T:s,displacement=X:{x_unit},velocity=V:{v_unit},force=F:N")
    return tmp_path / name, spec


@pytest.mark.parametrize(
    "v_scale, v_unit, needle",
    [
        (1e3, "cm/s", "is 10 x the derivative of the displacement: likely a factor 10"),
        (1e3, "m/s", "likely a factor 1000"),
        (1e3 / 25.4, "mm/s", "likely a factor 1/25.4"),
        (1e3, "in/s", "likely a factor 25.4"),
        (-1e3, "mm/s", "opposite sign"),
    ],
)
def test_velocity_unit_mix_up_warns(tmp_path, v_scale, v_unit, needle):
    path, spec = _measured(tmp_path, v_scale, v_unit=v_unit)
    with pytest.warns(RuntimeWarning, match="s.csv: measured velocity") as rec:
        (c,) = md.load(path, spec=spec)
    assert any(needle in str(w.message) for w in rec), [str(w.message) for w in rec]
    assert any(needle in w for w in c.warnings)


def test_displacement_range_warns(tmp_path):
    span = np.ptp(motion(2000)[1])  # 14.55 mm
    path, spec = _measured(tmp_path, 1e3, x_unit="m", v_unit="mm/s")  # mm data declared m
    with pytest.warns(RuntimeWarning) as rec:
        md.load(path, spec=spec)
    msgs = [str(w.message) for w in rec]
    assert any(f"displacement spans {span * 1e3:.4g} m peak to peak, more than a damper "
               f"stroke" in m for m in msgs), msgs
    assert any("likely a factor 1/1000" in m for m in msgs), msgs
    path, spec = _measured(tmp_path, 1e-3, x_scale=1e-3, v_unit="mm/s")  # km data declared mm
    with pytest.warns(RuntimeWarning, match=f"displacement spans {span * 1e-6:.3g} m peak to "
                                            f"peak, less than 10 um"):
        md.load(path, spec=spec)


def test_real_data_raises_no_warning(utfsm):
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        conds = md.load(utfsm, spec=md.DataSpec.from_options(
            columns="time=0:s,displacement=1:mm,velocity=2:mm/s,force=3:N"))
    assert len(conds) == 30 and all(not c.warnings for c in conds)
    assert all(c.estimated == frozenset() for c in conds)  # metadata from the file names
    assert all(md.check_condition(c) == [] for c in conds)


# --------------------------------------------------------------------------------------------
# Reports


def test_describe(tmp_path):
    write_layout_a(tmp_path / "random.csv")
    (c,) = md.load(tmp_path / "random.csv", spec=md.DataSpec.from_options(**OPTIONS_A))
    (r,) = md.describe([c])
    assert (r.n_samples, r.velocity, r.command_unit) == (3000, "measured", "V")
    assert r.sample_rate == pytest.approx(1000.0, rel=1e-12)
    assert r.duration == pytest.approx(2.999)
    assert r.x_range == pytest.approx((c.x.min(), c.x.max()))
    assert r.estimated == {"frequency", "amplitude"} and r.uniform
    line = r.line()
    assert line.startswith("random: 3000 samples at 1000 Hz (2.999 s)")
    assert "(measured)" in line and "~" in line and "(estimated)" in line and "command" in line
    assert " V" in line and "\n" not in line
    json.dumps(r.to_dict())
    # A hand-made condition with a unit mix-up: the check runs in describe too.
    t, x, v = motion(1000)
    bad = md.Condition("bad", 0.5, None, None, t, x, 10 * v, tanh_force(x, v, 0.5))
    (r,) = md.describe(bad)
    assert 0.2 < r.frequency < 1.2 and "frequency" in r.estimated
    assert "likely a factor 10" in r.line() and r.current == 0.5
    batch_reports = md.describe(md.make_batch([c, bad]))
    assert [b.label for b in batch_reports] == ["random", "bad"]
    assert math.isfinite(batch_reports[0].bandwidth_Hz)
