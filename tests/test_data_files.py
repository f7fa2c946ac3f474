"""Fleet-scale input (issue 28): CSV read in blocks, Parquet and Feather files, the progress bar.

Known answers: tests simulated by mrjax's tanh model are written to files and must come back bit
for bit (floats written exactly), whatever the format and however the file is cut into blocks.
"""

import dataclasses
import io
import re

import numpy as np
import pytest
from helpers import one_error_line, raises_one_line, run_cli, snapshot

import mrjax.data as md
from mrjax.data import _csv as csv_reader
from mrjax.data import _progress
from mrjax.data._csv import _fast, read_csv


def _tests(n=3, samples=(150, 120, 90)):
    """`n` tanh tests of different lengths, currents and frequencies (labels t0, t1, ...)."""
    out = []
    for k in range(n):
        i, f = 0.25 * (k + 1), 1.0 + 0.5 * k
        c = md.simulate("kwok", md.paper_parameters(i), frequency=f, amplitude=0.004 + 0.002 * k,
                        current=i, sample_rate=500.0, noise=5.0, seed=k)
        out.append(dataclasses.replace(c.subsample(1, samples[k % len(samples)]), label=f"t{k}"))
    return out


def _same(got, ref):
    assert [c.label for c in got] == [c.label for c in ref]
    for c, r in zip(got, ref):
        assert (c.current, c.frequency, c.amplitude) == (r.current, r.frequency, r.amplitude)
        for name in ("t", "x", "xdot", "force"):
            np.testing.assert_array_equal(getattr(c, name), getattr(r, name))


# --------------------------------------------------------------------------------------------
# CSV in blocks


def _csv_text(conds, *, newline="\n", interleave=False):
    frame = md.to_frame(conds)
    if interleave:  # rows of the tests alternate: each test is spread over the whole file
        frame = frame.iloc[np.argsort(frame.groupby("condition").cumcount(), kind="stable")]
    buf = io.StringIO()
    frame.to_csv(buf, index=False, lineterminator=newline)
    return buf.getvalue()


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
@pytest.mark.parametrize("interleave", [False, True])
def test_csv_in_many_blocks_reads_back_bit_for_bit(tmp_path, newline, interleave):
    ref = _tests()
    path = tmp_path / "fleet.csv"
    path.write_text(_csv_text(ref, newline=newline, interleave=interleave), newline="")
    for block in (200, 4096, 1 << 24):
        read = read_csv(path, columns=None, strict=True, block_bytes=block)
        exact = read_csv(path, columns=None, strict=True, block_bytes=block, exact=True)
        for c in read.values:
            a, b = read.values[c], exact.values[c]
            if isinstance(a, np.ndarray):
                np.testing.assert_array_equal(a, b)
        assert [read.lines.line(i) for i in range(read.n)] == list(range(2, read.n + 2))
    _same(md.load(path), ref)


def test_csv_quirks_across_blocks(tmp_path, monkeypatch):
    """Blank lines, a trailing delimiter, quoted labels with the delimiter in them and a unit
    row, read in blocks of 300 bytes: the notes and values of one read, by the fast path where
    the blocks allow it."""
    ref = _tests(2)
    ref = [dataclasses.replace(c, label=lab) for c, lab in zip(ref, ("a, first", "b"))]
    text = _csv_text(ref).splitlines()
    header = text[0].split(",")
    lines = [",".join(header) + ",", ",".join("-" if h == "condition" else "[SI]" for h in header)
             + ","]
    for k, ln in enumerate(text[1:]):
        lines.append(ln + ",")  # (pandas quotes "a, first")
        if k in (40, 41, 200):
            lines.append("")
    path = tmp_path / "q.csv"
    path.write_text("\n".join(lines) + "\n")
    spec = md.DataSpec.from_options(
        columns="condition=condition,time=time_s:s,displacement=displacement_m:m,"
                "velocity=velocity_m_s:m/s,force=force_N:N,current=current_A:A")
    got = md.load(path, spec=spec)
    for c, r in zip(got, ref):
        assert c.label == r.label
        np.testing.assert_array_equal(c.x, r.x)
        np.testing.assert_array_equal(c.force, r.force)
    notes = got[0].notes
    assert "every line ends with a delimiter (ignored)" in notes
    assert "3 empty line(s) skipped" in notes
    assert "line(s) 2 not data (skipped)" in notes
    assert "column(s) 'frequency_Hz', 'amplitude_m' not used" in notes
    fast = []
    monkeypatch.setattr(csv_reader, "_fast", lambda *a: fast.append(_fast(*a)) or fast[-1])
    blocks = [read_csv(path, columns=dict(spec.columns), strict=False, block_bytes=b,
                       exact=e) for b in (300, 1 << 20) for e in (False, True)]
    assert any(p is not None for p in fast) and any(p is None for p in fast)  # both paths
    for r in blocks[1:]:
        assert r.notes == blocks[0].notes and r.n == blocks[0].n


def test_csv_bad_cell_deep_in_a_later_block_names_its_line(tmp_path):
    text = _csv_text(_tests()).split("\n")
    k = 300  # a data line well past the first blocks
    cells = text[k - 1].split(",")
    cells[6] = "12,5x"
    text[k - 1] = ",".join(cells[:6]) + ',"12,5x",' + ",".join(cells[7:])
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(text))
    raises_one_line(lambda: read_csv(path, columns=None, strict=True, block_bytes=512), "bad.csv",
            f"line {k}", "'velocity_m_s'", "not a number: '12,5x'")
    raises_one_line(lambda: md.load(path), f"line {k}", "'velocity_m_s'")
    text[k - 1] = "t1,0.5"  # a short row
    path.write_text("\n".join(text))
    raises_one_line(lambda: read_csv(path, columns=None, strict=True, block_bytes=512),
            f"line {k}", "expected 8 fields, found 2")


def test_csv_metadata_that_varies_names_both_lines(tmp_path):
    text = _csv_text(_tests()).split("\n")
    text[260] = text[260].replace(",0.5,", ",0.55,", 1)  # current of t1 changes on one row
    path = tmp_path / "c.csv"
    path.write_text("\n".join(text))
    raises_one_line(lambda: md.load(path), "'current_A'", "condition 't1'", "line 152", "line 261")


# --------------------------------------------------------------------------------------------
# Parquet and Feather


def _write(frame, path):
    if path.suffix in (".parquet", ".pq"):
        frame.to_parquet(path, index=False)
    else:
        frame.reset_index(drop=True).to_feather(path)
    return path


@pytest.mark.parametrize("suffix", [".parquet", ".feather", ".arrow", ".pq"])
def test_columnar_round_trip(tmp_path, suffix):
    pytest.importorskip("pyarrow")
    ref = _tests()
    path = _write(md.to_frame(ref), tmp_path / f"fleet{suffix}")
    _same(md.load(path), ref)
    _same(md.load_columnar(path), ref)
    _same(md.load(tmp_path), ref)  # found in a directory


def test_columnar_condition_as_category_or_integers_and_pandas_index(tmp_path):
    ref = _tests()
    frame = md.to_frame(ref)
    frame["condition"] = frame["condition"].astype("category")
    _same(md.load(_write(frame, tmp_path / "cat.parquet")), ref)
    frame["condition"] = frame["condition"].str[1:].astype(int) + 10  # ids 10, 11, 12
    frame.index = frame.index + 5  # a pandas index stored as __index_level_0__
    frame.to_parquet(tmp_path / "ids.parquet")
    got = md.load(tmp_path / "ids.parquet")
    assert [c.label for c in got] == ["10", "11", "12"]
    np.testing.assert_array_equal(got[2].force, ref[2].force)


def test_columnar_with_a_spec(tmp_path):
    ref = _tests(2)
    frame = md.to_frame(ref)
    own = frame.rename(columns={"time_s": "Time", "force_N": "Load", "condition": "run"})
    own["Disp"] = own.pop("displacement_m") * 100.0  # cm
    path = _write(own, tmp_path / "own.feather")
    spec = md.DataSpec.from_options(
        columns="condition=run,time=Time:s,displacement=Disp:cm,velocity=velocity_m_s:m/s,"
                "force=Load:N,current=current_A:A,frequency=frequency_Hz:Hz")
    got = md.load(path, spec=spec)
    assert [c.label for c in got] == ["t0", "t1"]
    for c, r in zip(got, ref):
        np.testing.assert_allclose(c.x, r.x, rtol=1e-15, atol=1e-19)
        assert c.current == r.current and "amplitude" in c.estimated
    assert "column(s) 'amplitude_m' not used" in got[0].notes


def test_columnar_bad_input(tmp_path):
    frame = md.to_frame(_tests(2))
    bad = frame.copy()
    bad.loc[7, "force_N"] = None
    raises_one_line(lambda: md.load(_write(bad, tmp_path / "null.parquet")), "null.parquet", "row 7",
            "'force_N'", "empty cell")
    bad = frame.astype({"displacement_m": str})
    bad.loc[3, "displacement_m"] = "1,5"
    raises_one_line(lambda: md.load(_write(bad, tmp_path / "text.feather")), "text.feather", "row 3",
            "'displacement_m'", "not a number: '1,5'")
    raises_one_line(lambda: md.load(_write(frame.assign(force_N=True), tmp_path / "b.parquet")),
            "'force_N' holds bool, not numbers")
    raises_one_line(lambda: md.load(_write(frame.drop(columns="current_A"), tmp_path / "m.parquet")),
            "missing required column current_<unit>")
    raises_one_line(lambda: md.load(_write(frame.iloc[:0], tmp_path / "empty.parquet")), "no data rows")
    (tmp_path / "junk.parquet").write_text("condition,time_s\n")
    raises_one_line(lambda: md.load(tmp_path / "junk.parquet"), "junk.parquet",
            "not a readable Parquet file")
    (tmp_path / "junk.feather").write_bytes(b"ARROW1\x00\x00" + bytes(100))
    raises_one_line(lambda: md.load(tmp_path / "junk.feather"), "junk.feather",
            "not a readable Feather file")


def test_cli_reads_columnar_files(tmp_path):
    ref = _tests(2)
    path = _write(md.to_frame(ref), tmp_path / "two.parquet")
    code, out, err = run_cli(["inspect", path, "--no-plots", "--out", tmp_path / "i"])
    assert code == 0, err
    assert "2 test(s) from 1 file(s)" in out and out.startswith("t0: 150 samples")
    bad = md.to_frame(ref)
    bad.loc[4, "time_s"] = None
    _write(bad, tmp_path / "bad.feather")
    code, out, err = run_cli(["inspect", tmp_path / "bad.feather", "--out", tmp_path / "j"])
    assert code == 2 and re.search(r"bad\.feather, row 4, column 'time_s': empty cell",
                                   one_error_line(err))
    assert not (tmp_path / "j").exists() or snapshot(tmp_path / "j") == {}


# --------------------------------------------------------------------------------------------
# Progress


def test_load_draws_a_progress_bar_when_asked(tmp_path, monkeypatch, capsys):
    path = tmp_path / "p.csv"
    path.write_text(_csv_text(_tests()))
    monkeypatch.setattr(_progress, "DELAY_S", 0.0)
    md.load(path, progress=True)
    err = capsys.readouterr().err
    assert "loading" in err and "B" in err
    md.load(path, progress=False)
    assert capsys.readouterr().err == ""


# --------------------------------------------------------------------------------------------
# A source: tests indexed in the files and read a chunk at a time


def _lazy(tmp_path, name, writer):
    """A file of 5 tests written by `writer(conds, path)`, its source scanned holding nothing
    (pieces of 2 kB for CSV), and the reference `load` of it."""
    ref = _tests(5, samples=(150, 120, 90, 140, 60))
    path = tmp_path / name
    writer(ref, path)
    return md.Source.scan(path, keep_bytes=0), md.load(path), ref


@pytest.mark.parametrize("name", ["f.csv", "i.csv", "f.parquet", "f.feather"])
def test_source_reads_any_subset_as_load_does(tmp_path, monkeypatch, name):
    from mrjax.data import _source

    monkeypatch.setattr(_source, "STREAM_BLOCK_BYTES", 2048)

    def write(conds, path):
        if path.suffix == ".csv":
            path.write_text(_csv_text(conds, interleave=path.stem == "i"))
        else:
            _write(md.to_frame(conds), path)

    src, full, ref = _lazy(tmp_path, name, write)
    assert src.n_conditions == 5 and not src.kept
    assert list(src.n_samples) == [150, 120, 90, 140, 60] and src.length == 150
    for index in ([4, 0], [1], [3, 2, 1], np.arange(5) % 2 == 0):
        got = src.conditions(index)
        want = [full[i] for i in np.arange(5)[np.asarray(index)]]
        _same(got, want)
    b = src.batch([2, 3], length=src.length)
    assert b.length == 150 and b.labels == ("t2", "t3")
    _same(md.Source.scan(tmp_path / name).conditions(), ref)  # kept: read once
    assert md.Source.scan(tmp_path / name).kept


def test_source_of_several_files_and_layouts(tmp_path):
    from helpers import OPTIONS_C, write_layout_c

    ref = _tests(3)
    for k, c in enumerate(ref):  # UTFSM-style text files, one test each
        np.savetxt(tmp_path / f"{4 + 2 * k}mm{1 + k}Hz0x{25 * (k + 1)}A.txt",
                   np.column_stack([c.t, c.x * 1e3, c.xdot * 1e3, c.force]), fmt="%.17g")
    src = md.Source.scan(tmp_path, keep_bytes=0)
    full = md.load(tmp_path)
    _same(src.conditions([2, 0]), [full[2], full[0]])
    write_layout_c(tmp_path / "wide.mat", n=400)  # one test per column, 5 columns
    spec = md.DataSpec.from_options(**OPTIONS_C)
    src = md.Source.scan(tmp_path / "wide.mat", spec=spec, keep_bytes=0)
    full = md.load(tmp_path / "wide.mat", spec=spec)
    assert src.n_conditions == 5
    _same(src.conditions([4, 1]), [full[4], full[1]])


def test_source_checks_cells_while_scanning(tmp_path):
    text = _csv_text(_tests()).split("\n")
    text[200] = text[200].replace(",", ",x", 1)
    (tmp_path / "bad.csv").write_text("\n".join(text))
    raises_one_line(lambda: md.Source.scan(tmp_path / "bad.csv", keep_bytes=0), "line 201",
                    "'current_A'", "not a number")


def test_si_units_skip_the_registry_and_agree_with_it():
    """The SI unit of each quantity is checked without pint's registry (fast, for a fleet in
    SI); pint gives it the factor 1 and the right dimension too."""
    from mrjax.data import _units

    for quantity, units in _units._SI.items():
        for unit in units:
            _, factor, dim = _units._parse(unit)
            assert factor == 1.0 and _units._dimension_ok(dim, quantity), (quantity, unit)
            assert _units.check_unit(unit, quantity, what="x") == 1.0
    raises_one_line(lambda: _units.check_unit("m", "force", what="force"), "'m' is not a force")
