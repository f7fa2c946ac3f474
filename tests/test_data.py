"""Loaders, units and velocity estimation of `mrjax.data`."""

import csv
import math

import numpy as np
import pytest
import scipy.io
from helpers import default_data_dir, raises_one_line

import mrjax.data as md

# --------------------------------------------------------------------------------------------
# Helpers


_raises = raises_one_line


def _sim(current=0.5, frequency=1.0, amplitude=0.008):
    return md.simulate(
        "kwok", md.paper_parameters(current), frequency=frequency, amplitude=amplitude,
        current=current,
    )


def _write_csv(path, rows, header):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def _r(v):
    return repr(float(v))


def _condition_rows(c, *, label=None, mm=True, velocity=False):
    s = 1e3 if mm else 1.0
    rows = []
    for k in range(c.n_samples):
        row = [label] if label is not None else []
        row += [_r(c.current), _r(c.frequency), _r(c.amplitude * s), _r(c.t[k]), _r(c.x[k] * s)]
        if velocity:
            row.append(_r(c.xdot[k] * s))
        row.append(_r(c.force[k]))
        rows.append(row)
    return rows


def _txt(path, data, fmt="%.10e"):
    np.savetxt(path, np.asarray(data), fmt=fmt)
    return path


def _good_table(n=50):
    t = np.arange(n) * 1e-3
    x = 8.0 * np.sin(2 * np.pi * t)
    return np.column_stack([t, x, 8.0 * 2 * np.pi * np.cos(2 * np.pi * t), 100.0 * np.sin(t)])


# --------------------------------------------------------------------------------------------
# Units and file names


def test_units():
    assert md.to_si(25, "mm") == pytest.approx(0.025)
    assert md.to_si(3, "kN") == 3000.0
    assert md.to_si(250, "mA") == pytest.approx(0.25)
    assert md.to_si(5, "ms") == pytest.approx(0.005)
    np.testing.assert_allclose(md.to_si([10.0, 20.0], "mm/s"), [0.01, 0.02])
    np.testing.assert_allclose(md.to_si([10.0], "mm_s"), [0.01])
    assert md.parse_column("velocity_mm_s") == ("velocity", "mm/s")
    assert md.parse_column("condition") == ("condition", None)
    for col in ("displacement_m", "displacement_mm", "velocity_m_s", "velocity_mm_s",
                "amplitude_m", "amplitude_mm", "force_N", "force_kN", "time_s", "time_ms",
                "current_A", "current_mA", "frequency_Hz"):
        assert col in md.column_names()
        md.parse_column(col)
    # Through pint, any unit of the right dimension: inches now convert (hand value 25.4 mm).
    assert md.to_si(2.0, "inch", quantity="length") == pytest.approx(0.0508, rel=1e-15)
    assert md.parse_column("displacement_in", where="f.csv") == ("displacement", "in")
    _raises(lambda: md.to_si(1.0, "N", quantity="length", name="column 'x'"),
            "column 'x'", "'N'", "not a length", "m, mm")
    _raises(lambda: md.to_si(1.0, "furlongz", quantity="length", name="column 'x'"),
            "column 'x'", "'furlongz'", "m, mm")
    _raises(lambda: md.parse_column("displacement_N", where="f.csv"),
            "f.csv", "displacement_N", "'N'", "not a length", "m, mm")
    _raises(lambda: md.parse_column("temperature_C", where="f.csv"), "temperature_C", "force_N")
    _raises(lambda: md.parse_column("force", where="f.csv"), "'force'", "unit", "force_N")


@pytest.mark.parametrize(
    "name, expected",
    [
        ("25mm0x1Hz0x75A", (0.025, 0.1, 0.75)),
        ("10mm1Hz1A", (0.010, 1.0, 1.0)),
        ("2mm5Hz0x25A", (0.002, 5.0, 0.25)),
        ("25mm0x25Hz0A.txt", (0.025, 0.25, 0.0)),
        ("/some/dir/5mm3Hz0x5A.txt", (0.005, 3.0, 0.5)),
        ("25mm0p1Hz0p75A", (0.025, 0.1, 0.75)),
        ("damper_25mm_0p1Hz_750mA_run2", (0.025, 0.1, 0.75)),
        ("12.5mm2Hz0.5A", (0.0125, 2.0, 0.5)),
    ],
)
def test_parse_label(name, expected):
    assert md.parse_label(name) == pytest.approx(expected)


@pytest.mark.parametrize("name", ["run1", "25mm0x1Hz", "mm1Hz1A", "25mm0x1Hz0x75B", "x25mm1Hz1A"])
def test_parse_label_bad(name):
    _raises(lambda: md.parse_label(name + ".txt"), name, "25mm0x1Hz0x75A")


# --------------------------------------------------------------------------------------------
# UTFSM measurements


@pytest.fixture(scope="module")
def utfsm_conditions(utfsm):
    return md.load(utfsm)


def test_utfsm_files(utfsm, utfsm_conditions):
    files = sorted(utfsm.glob("*.txt"))
    assert len(files) == 30
    conds = {c.label: c for c in utfsm_conditions}
    assert sorted(conds) == [f.stem for f in files]
    for c in conds.values():
        a, f, i = md.parse_label(c.label)
        assert (c.amplitude, c.frequency, c.current) == (a, f, i)
        assert c.source.endswith(c.label + ".txt")
        # Sample interval: 1 ms for the 1 Hz and 3 Hz tests, 5 ms for the others.
        dt = 1e-3 if c.frequency in (1.0, 3.0) else 5e-3
        assert np.median(np.diff(c.t)) == pytest.approx(dt, rel=1e-6)
        # Units converted: x [m] reaches about the nominal amplitude (the 2 mm tests reach
        # about 1.6 mm), and velocity [m/s] about 2*pi*f*A.
        xmax = np.max(np.abs(c.x))
        assert 0.7 * c.amplitude < xmax < 1.05 * c.amplitude
        vmax = np.max(np.abs(c.xdot))
        assert 0.6 < vmax / (2 * np.pi * c.frequency * xmax) < 1.6
        assert 100 < np.max(np.abs(c.force)) < 1e4  # newtons
    c = conds["25mm0x1Hz0x75A"]
    assert (c.amplitude, c.frequency, c.current) == pytest.approx((0.025, 0.1, 0.75))
    assert 0.024 < np.max(np.abs(c.x)) < 0.026
    c = conds["2mm5Hz0x25A"]
    assert (c.amplitude, c.frequency, c.current) == pytest.approx((0.002, 5.0, 0.25))
    c = conds["10mm1Hz1A"]
    assert (c.amplitude, c.frequency, c.current) == pytest.approx((0.010, 1.0, 1.0))
    assert default_data_dir() is not None


def test_utfsm_single_file(utfsm):
    c = md.load_txt(utfsm / "25mm0x1Hz0x75A.txt")
    assert (c.amplitude, c.frequency, c.current) == pytest.approx((0.025, 0.1, 0.75))
    raw = np.loadtxt(utfsm / "25mm0x1Hz0x75A.txt")
    np.testing.assert_allclose(c.x, raw[:, 1] * 1e-3)
    np.testing.assert_allclose(c.xdot, raw[:, 2] * 1e-3)
    np.testing.assert_allclose(c.force, raw[:, 3])
    # Same data stated in SI: units override.
    with pytest.warns(RuntimeWarning, match="48.9 m peak to peak, more than a damper stroke"):
        c2 = md.load_txt(utfsm / "25mm0x1Hz0x75A.txt", units=("s", "m", "m/s", "N"),
                         current=2.0)
    np.testing.assert_allclose(c2.x, raw[:, 1])
    assert c2.current == 2.0 and c2.frequency == 0.1


def test_utfsm_batch(utfsm_conditions):
    batch = md.make_batch(utfsm_conditions)
    assert batch.n_conditions == 30
    lengths = np.array([c.n_samples for c in utfsm_conditions])
    np.testing.assert_array_equal(np.asarray(batch.mask).sum(axis=1), lengths)
    assert batch.length == lengths.max()
    i = int(np.argmin(lengths))
    n = lengths[i]
    x = np.asarray(batch.x[i])
    np.testing.assert_array_equal(x[n:], x[n - 1])
    np.testing.assert_array_equal(np.asarray(batch.force[i, n:]), 0.0)
    np.testing.assert_allclose(np.asarray(batch.x[i, :n]), utfsm_conditions[i].x)


# --------------------------------------------------------------------------------------------
# Round trips


def test_csv_round_trip_mm_without_velocity(tmp_path):
    a, b = _sim(0.5), _sim(1.0, frequency=2.0, amplitude=0.004)
    header = ["condition", "current_A", "frequency_Hz", "amplitude_mm", "time_s",
              "displacement_mm", "force_N"]
    path = _write_csv(tmp_path / "sim.csv", _condition_rows(a, label="first")
                      + _condition_rows(b, label="second"), header)
    got = md.load_csv(path)
    assert [c.label for c in got] == ["first", "second"]
    for c, ref in zip(got, (a, b)):
        assert (c.current, c.frequency) == (ref.current, ref.frequency)
        assert c.amplitude == pytest.approx(ref.amplitude, rel=1e-12)
        np.testing.assert_allclose(c.t, ref.t, rtol=0, atol=1e-15)
        np.testing.assert_allclose(c.x, ref.x, rtol=1e-12, atol=1e-17)
        np.testing.assert_allclose(c.force, ref.force, rtol=1e-12)
        # Velocity estimated from displacement.
        err = np.sqrt(np.mean((c.xdot - ref.xdot) ** 2) / np.mean(ref.xdot**2))
        assert err < 1e-3
        assert str(path) in c.source
    assert [c.label for c in md.load(tmp_path)] == ["first", "second"]


def test_csv_with_velocity_and_interleaved_rows(tmp_path):
    a, b = _sim(0.0), _sim(0.25)
    header = ["condition", "current_mA", "time_ms", "displacement_m", "velocity_mm_s",
              "force_kN", "frequency_Hz", "amplitude_m"]
    rows = []
    for k in range(a.n_samples):
        for lab, c in (("A", a), ("B", b)):
            rows.append([lab, _r(c.current * 1e3), _r(c.t[k] * 1e3), _r(c.x[k]),
                         _r(c.xdot[k] * 1e3), _r(c.force[k] / 1e3), _r(c.frequency),
                         _r(c.amplitude)])
    path = _write_csv(tmp_path / "two.csv", rows, header)
    got = md.load(path)
    assert [c.label for c in got] == ["A", "B"]
    for c, ref in zip(got, (a, b)):
        assert c.current == pytest.approx(ref.current)
        np.testing.assert_allclose(c.t, ref.t, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(c.xdot, ref.xdot, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(c.force, ref.force, rtol=1e-12)


def test_csv_without_condition_column(tmp_path):
    ref = _sim()
    header = ["current_A", "frequency_Hz", "amplitude_mm", "time_s", "displacement_mm",
              "force_N"]
    path = _write_csv(tmp_path / "10mm1Hz1A.csv", _condition_rows(ref), header)
    (c,) = md.load_csv(path)
    assert c.label == "10mm1Hz1A"
    assert c.current == 0.5  # from the column, not the file name
    np.testing.assert_allclose(c.x, ref.x, rtol=1e-12, atol=1e-17)
    # Optional metadata columns may be left out: unknown.
    rows = [[r[0], r[3], r[4], r[5]] for r in _condition_rows(ref)]
    path = _write_csv(tmp_path / "b.csv", rows, ["current_A", "time_s", "displacement_mm",
                                                 "force_N"])
    (c,) = md.load_csv(path)
    assert c.frequency is None and c.amplitude is None


@pytest.mark.parametrize("orient", ["columns", "rows"])
def test_mat_round_trip(tmp_path, orient):
    ref = _sim(0.75)
    # Variables style, SI, metadata as scalar variables.
    path = tmp_path / "vars.mat"
    scipy.io.savemat(path, {"time": ref.t, "disp": ref.x, "vel": ref.xdot, "F": ref.force,
                            "I": 0.75, "f": 1.0, "A": 0.008})
    (c,) = md.load_mat(path, variables={"t": "time", "x": "disp", "xdot": "vel", "force": "F",
                                        "current": "I", "frequency": "f", "amplitude": "A"})
    assert (c.label, c.current, c.frequency, c.amplitude) == ("vars", 0.75, 1.0, 0.008)
    for k in ("t", "x", "xdot", "force"):
        np.testing.assert_array_equal(getattr(c, k), getattr(ref, k))
    # Matrix style, mm units, metadata from the file name.
    m = np.column_stack([ref.t, ref.x * 1e3, ref.xdot * 1e3, ref.force])
    path = tmp_path / "8mm1Hz0x75A.mat"
    scipy.io.savemat(path, {"data": m if orient == "columns" else m.T, "other": 1.0})
    (c,) = md.load_mat(path, matrix="data", columns=("t", "x", "xdot", "force"),
                       units=("s", "mm", "mm/s", "N"))
    assert (c.current, c.frequency, c.amplitude) == pytest.approx((0.75, 1.0, 0.008))
    np.testing.assert_allclose(c.x, ref.x, rtol=1e-14)
    np.testing.assert_allclose(c.xdot, ref.xdot, rtol=1e-14, atol=1e-18)
    # Found automatically as the only matrix; via load(); skip a column, estimate velocity.
    assert md.load(path, units=("s", "mm", "mm/s", "N"))[0].x == pytest.approx(ref.x)
    (c,) = md.load_mat(path, matrix="data", columns=("t", "x", None, "force"),
                       units=("s", "mm", "mm/s", "N"))
    assert np.sqrt(np.mean((c.xdot - ref.xdot) ** 2) / np.mean(ref.xdot**2)) < 1e-3


def test_mat_conventional_names(tmp_path):
    ref = _sim()
    path = tmp_path / "run.mat"
    scipy.io.savemat(path, {"t": ref.t, "x": ref.x, "xdot": ref.xdot, "force": ref.force,
                            "current": 0.5})
    (c,) = md.load_mat(path, parse_name=False)
    assert (c.current, c.frequency, c.amplitude) == (0.5, None, None)
    np.testing.assert_array_equal(c.force, ref.force)


def test_txt_three_columns_and_overrides(tmp_path):
    ref = _sim()
    path = _txt(tmp_path / "8mm1Hz0x5A.dat", np.column_stack([ref.t, ref.x * 1e3, ref.force]))
    (c,) = md.load(path)
    assert (c.current, c.frequency, c.amplitude) == pytest.approx((0.5, 1.0, 0.008))
    assert np.sqrt(np.mean((c.xdot - ref.xdot) ** 2) / np.mean(ref.xdot**2)) < 1e-3
    c = md.load_txt(path, label="mine", current=0.0, velocity_window_s=0.011)
    assert (c.label, c.current, c.frequency) == ("mine", 0.0, 1.0)
    path = _txt(tmp_path / "run.txt", np.column_stack([ref.t, ref.x * 1e3, ref.force]))
    c = md.load_txt(path, parse_name=False, frequency=1.0)
    assert (c.current, c.frequency, c.amplitude) == (None, 1.0, None)


def test_load_batch_and_lists(tmp_path):
    a, b = _sim(0.0), _sim(1.0, frequency=2.0, amplitude=0.004)
    pa = _txt(tmp_path / "8mm1Hz0A.txt",
              np.column_stack([a.t, a.x * 1e3, a.xdot * 1e3, a.force]))
    pb = _txt(tmp_path / "4mm2Hz1A.txt",
              np.column_stack([b.t, b.x * 1e3, b.xdot * 1e3, b.force]))
    batch = md.load_batch([pa, pb])
    assert batch.labels == ("8mm1Hz0A", "4mm2Hz1A")
    np.testing.assert_array_equal(np.asarray(batch.mask).sum(axis=1), [a.n_samples, b.n_samples])
    assert [c.label for c in md.load(tmp_path)] == ["4mm2Hz1A", "8mm1Hz0A"]  # sorted


def test_default_data_dir(monkeypatch, tmp_path):
    monkeypatch.setenv("MRJAX_DATA", str(tmp_path))
    assert default_data_dir() == tmp_path
    monkeypatch.setenv("MRJAX_DATA", str(tmp_path / "missing"))  # as given: fails when loaded
    assert default_data_dir() == tmp_path / "missing"
    assert not hasattr(md, "default_data_dir")  # a test convenience, not library API


# --------------------------------------------------------------------------------------------
# Velocity


def _rel_rms(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2)))


def test_velocity_clean_sine():
    # 1 Hz, 8 mm sine sampled at 1 kHz: the default window (1/20 period, cubic) is bias-free.
    t, x, v = md.sine_excitation(1.0, 0.008, sample_rate=1000.0, cycles=2.0)
    assert _rel_rms(md.estimate_velocity(t, x), v) < 1e-4
    # Coarse sampling (40 samples per cycle, the UTFSM 5 Hz tests): the smallest window, still
    # accurate; any lag of even one sample would give an error of about 8 %.
    t, x, v = md.sine_excitation(5.0, 0.002, sample_rate=200.0, cycles=3.0)
    assert _rel_rms(md.estimate_velocity(t, x), v) < 2e-3


def test_velocity_noisy_sine():
    # 5 um of displacement noise on an 8 mm, 1 Hz sine at 1 kHz: < 1 % RMS velocity error.
    t, x, v = md.sine_excitation(1.0, 0.008, sample_rate=1000.0, cycles=2.0)
    xn = x + np.random.default_rng(0).normal(0.0, 5e-6, x.shape)
    assert _rel_rms(md.estimate_velocity(t, xn), v) < 1e-2


def test_velocity_non_uniform_sampling():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 2000))
    x = 0.008 * np.sin(2 * np.pi * t)
    v = 0.008 * 2 * np.pi * np.cos(2 * np.pi * t)
    assert _rel_rms(md.estimate_velocity(t, x), v) < 1e-3
    assert _rel_rms(md.estimate_velocity(t, x, window_s=0.02, polyorder=2), v) < 1e-2


def test_velocity_errors():
    t = np.arange(4) * 1e-3
    _raises(lambda: md.estimate_velocity(t, t), "4 sample(s)", "at least 5")
    t, x, _ = md.sine_excitation(1.0, 0.008)
    _raises(lambda: md.estimate_velocity(t, x, window_s=0.002), "window_s", "at least 5")
    _raises(lambda: md.estimate_velocity(t, x, window_s=10.0), "window_s", "2000")
    _raises(lambda: md.estimate_velocity(t, x, polyorder=0), "polyorder")
    _raises(lambda: md.estimate_velocity(t, x[:-1]), "equal length")
    _raises(lambda: md.estimate_velocity(t[::-1], x), "strictly increasing")
    x = x.copy()
    x[7] = np.nan
    _raises(lambda: md.estimate_velocity(t, x), "x", "row 7")


# --------------------------------------------------------------------------------------------
# Bad input: every error is one line naming the file and what is wrong.

_HEADER = ["condition", "current_A", "time_s", "displacement_m", "force_N"]


def _csv_rows(n=20, cond="c1", current="0.5"):
    return [[cond, current, f"{k * 1e-3:.6f}", f"{math.sin(k / 5):.6f}", f"{k:.1f}"]
            for k in range(n)]


def test_bad_nan_and_inf(tmp_path):
    data = _good_table()
    data[5, 3] = np.nan
    path = _txt(tmp_path / "8mm1Hz0A.txt", data)
    _raises(lambda: md.load_txt(path), str(path), "force", "non-finite", "row 5")
    rows = _csv_rows()
    rows[3][3] = "inf"
    path = _write_csv(tmp_path / "inf.csv", rows, _HEADER)
    _raises(lambda: md.load_csv(path), str(path), "'c1'", "x", "non-finite", "row 3")


def test_bad_empty_and_header_only(tmp_path):
    for name in ("8mm1Hz0A.txt", "e.csv", "e.mat"):
        (tmp_path / name).write_text("")
        _raises(lambda: md.load(tmp_path / name), name, "empty")
    (tmp_path / "blank.txt").write_text("\n \n# comment\n")
    _raises(lambda: md.load_txt(tmp_path / "blank.txt"), "blank.txt", "empty")
    path = _write_csv(tmp_path / "h.csv", [], _HEADER)
    _raises(lambda: md.load_csv(path), "h.csv", "header only")
    (tmp_path / "hdr.txt").write_text("time x xdot force\n")
    _raises(lambda: md.load_txt(tmp_path / "hdr.txt", parse_name=False),
            "hdr.txt", "line 1", "column 1 (t)", "'time'")


def test_bad_columns(tmp_path):
    path = _write_csv(tmp_path / "m.csv", [r[:4] for r in _csv_rows()], _HEADER[:4])
    _raises(lambda: md.load_csv(path), "m.csv", "missing required column", "force_")
    path = _write_csv(tmp_path / "nc.csv", [r[:1] + r[2:] for r in _csv_rows()],
                      _HEADER[:1] + _HEADER[2:])
    _raises(lambda: md.load_csv(path), "nc.csv", "current_")
    path = _write_csv(tmp_path / "u.csv", [r + ["20"] for r in _csv_rows()],
                      _HEADER + ["temperature_C"])
    _raises(lambda: md.load_csv(path), "u.csv", "unknown column 'temperature_C'", "force_N")
    path = _write_csv(tmp_path / "unit.csv", _csv_rows(),
                      ["condition", "current_A", "time_s", "displacement_N", "force_N"])
    _raises(lambda: md.load_csv(path), "unit.csv", "displacement_N", "'N'", "not a length")
    path = _write_csv(tmp_path / "dup.csv", [r + [r[3]] for r in _csv_rows()],
                      _HEADER + ["displacement_mm"])
    _raises(lambda: md.load_csv(path), "dup.csv", "displacement_m", "displacement_mm")
    path = _txt(tmp_path / "8mm1Hz0A.txt", _good_table())
    _raises(lambda: md.load_txt(path, units=("s", "N", "mm/s", "N")), "8mm1Hz0A.txt",
            "displacement", "'N'", "not a length", "m, mm")
    _raises(lambda: md.load_txt(path, units=("s", "mm")), "8mm1Hz0A.txt", "4 units")
    path = _txt(tmp_path / "8mm1Hz0A.txt", _good_table()[:, :2])
    _raises(lambda: md.load_txt(path), "8mm1Hz0A.txt", "found 2")


def test_bad_cells(tmp_path):
    rows = _csv_rows()
    rows[4][4] = "12,5x"
    path = _write_csv(tmp_path / "n.csv", rows, _HEADER)
    _raises(lambda: md.load_csv(path), "n.csv", "line 6", "'force_N'", "'12,5x'")
    rows = _csv_rows()
    rows[0][2] = ""
    path = _write_csv(tmp_path / "e.csv", rows, _HEADER)
    _raises(lambda: md.load_csv(path), "e.csv", "line 2", "'time_s'", "empty cell")
    rows = _csv_rows()
    rows[2] = rows[2][:3]
    path = _write_csv(tmp_path / "f.csv", rows, _HEADER)
    _raises(lambda: md.load_csv(path), "f.csv", "line 4", "expected 5 fields")
    lines = ["0 1 2 3", "0.001 1 2 3", "0.002 1 abc 3", "0.003 1 2 3"]
    (tmp_path / "8mm1Hz0A.txt").write_text("\n".join(lines) + "\n")
    _raises(lambda: md.load_txt(tmp_path / "8mm1Hz0A.txt"), "8mm1Hz0A.txt", "line 3",
            "column 3 (xdot)", "'abc'")
    (tmp_path / "8mm1Hz0A.txt").write_text("0 1 2 3\n0.001 1 2\n")
    _raises(lambda: md.load_txt(tmp_path / "8mm1Hz0A.txt"), "8mm1Hz0A.txt", "line 2",
            "expected 4 columns")


def test_bad_time(tmp_path):
    data = _good_table()
    data[10, 0] = data[9, 0]
    path = _txt(tmp_path / "8mm1Hz0A.txt", data)
    _raises(lambda: md.load_txt(path), "8mm1Hz0A.txt", "not strictly increasing", "row 10")
    data = _good_table()
    data[10, 0] = data[8, 0]
    path = _txt(tmp_path / "8mm1Hz0A.txt", data)
    _raises(lambda: md.load_txt(path), "8mm1Hz0A.txt", "not strictly increasing", "row 10")
    rows = _csv_rows()
    rows[7][2] = rows[6][2]
    path = _write_csv(tmp_path / "t.csv", rows, _HEADER)
    _raises(lambda: md.load_csv(path), "t.csv", "'c1'", "not strictly increasing")


def test_bad_metadata(tmp_path):
    path = _write_csv(tmp_path / "neg.csv", _csv_rows(current="-0.5"), _HEADER)
    _raises(lambda: md.load_csv(path), "neg.csv", "current", "non-negative")
    rows = _csv_rows()
    rows[9][1] = "0.75"
    path = _write_csv(tmp_path / "c.csv", rows, _HEADER)
    _raises(lambda: md.load_csv(path), "c.csv", "'current_A'", "'c1'", "line 2", "line 11")
    path = _txt(tmp_path / "8mm1Hz0A.txt", _good_table())
    _raises(lambda: md.load_txt(path, current=-1.0), "8mm1Hz0A.txt", "current", "non-negative")
    _raises(lambda: md.load_txt(path, current="lots"), "8mm1Hz0A.txt", "current", "'lots'")
    path = _txt(tmp_path / "run1.txt", _good_table())
    _raises(lambda: md.load_txt(path), "run1.txt", "'run1'", "parse_name=False")


def test_bad_mat(tmp_path):
    ref = _sim()
    path = tmp_path / "8mm1Hz0A.mat"
    scipy.io.savemat(path, {"time": ref.t, "disp": ref.x, "F": ref.force[:-1]})
    names = {"t": "time", "x": "disp", "force": "F"}
    _raises(lambda: md.load_mat(path, variables=names), "8mm1Hz0A.mat", "mismatched",
            "'force': 1999")
    _raises(lambda: md.load_mat(path, variables={**names, "force": "Force"}), "8mm1Hz0A.mat",
            "'Force'", "disp, time")
    _raises(lambda: md.load_mat(path, variables={"t": "time", "x": "disp"}), "8mm1Hz0A.mat",
            "'force'", "F, disp, time")
    _raises(lambda: md.load_mat(path, variables={**names, "speed": "disp"}), "'speed'")
    _raises(lambda: md.load_mat(path, matrix="data"), "8mm1Hz0A.mat", "'data'", "F, disp, time")
    _raises(lambda: md.load_mat(path), "8mm1Hz0A.mat", "variables=", "F, disp, time")
    scipy.io.savemat(path, {"data": np.ones((10, 5))})
    _raises(lambda: md.load_mat(path, matrix="data", columns=("t", "x", "force")),
            "8mm1Hz0A.mat", "(10, 5)")
    _raises(lambda: md.load_mat(path, matrix="data"), "8mm1Hz0A.mat", "(10, 5)", "columns=")
    (tmp_path / "junk.mat").write_text("not a mat file")
    _raises(lambda: md.load_mat(tmp_path / "junk.mat"), "junk.mat")


def test_bad_paths(tmp_path):
    (tmp_path / "README.md").write_text("no data here")
    _raises(lambda: md.load(tmp_path), str(tmp_path), "no data files")
    _raises(lambda: md.load(tmp_path / "missing.csv"), "missing.csv", "no such file")
    _raises(lambda: md.load(tmp_path / "README.md"), "README.md", "'.md'")
    _raises(lambda: md.load([]), "no data files")
    path = _txt(tmp_path / "8mm1Hz0A.txt", _good_table())
    _raises(lambda: md.load(path, variables={}), "8mm1Hz0A.txt", "'variables'")
    _raises(lambda: md.load(path, bogus=1), "8mm1Hz0A.txt", "'bogus'")


def test_bad_too_short(tmp_path):
    path = _txt(tmp_path / "8mm1Hz0A.txt", _good_table()[:1])
    _raises(lambda: md.load_txt(path), "8mm1Hz0A.txt", "only 1 sample")
    path = _write_csv(tmp_path / "one.csv", _csv_rows(n=1), _HEADER)
    _raises(lambda: md.load_csv(path), "one.csv", "only 1 sample")
    # Three columns but too few samples to estimate velocity.
    path = _txt(tmp_path / "8mm1Hz0A.txt", _good_table()[:4, [0, 1, 3]])
    _raises(lambda: md.load_txt(path), "8mm1Hz0A.txt", "velocity", "at least 5")
