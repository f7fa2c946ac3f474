"""Bad input, tried widely (issue 27): mutated files and specs end in a result or one
`InputError` line, never a traceback; and the CSV reader's fast path reads every file as its
exact row-by-row path does (the same values, lines, notes, or the same message).

The cases come from `tests/fuzzing.py` (hypothesis, derandomized: the same cases every run);
`benchmarks/fuzz_input.py` runs many more.
"""

import tempfile
from pathlib import Path

import fuzzing as fz
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import mrjax.data as md
from mrjax._errors import InputError
from mrjax.data._build import Codes
from mrjax.data._csv import read_csv

TMP = Path(tempfile.mkdtemp(prefix="mrjax-fuzz-"))
SETTINGS = dict(deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
SPEC = md.DataSpec.from_options(
    columns="time=time_s:s,displacement=displacement_m:m,force=force_N:N,condition=condition",
    velocity_window=0.02)


def _write(name: str, data: bytes) -> Path:
    p = TMP / name
    p.write_bytes(data)
    return p


#: Cases found by fuzzing, kept: a corrupted (binary) file named .csv, whose carriage returns
#: made Python's csv module raise (issue 27); a header whose unit pint divides by zero; a
#: displacement of 1e308, whose sanity check overflowed (a numpy warning line).
FOUND = (bytes(range(256)) * 3,
         b"condition,current_A,time_s,displacement_m,velocity_m_018846455,force_N\na,0,0,0,0,0\n",
         fz.with_cell(fz.valid_csv(), 70, 5, b"1e308"))


@settings(max_examples=120, **SETTINGS)
@given(fz.mutated(fz.valid_csv()))
@example(FOUND[0])
@example(FOUND[1])
@example(FOUND[2])
def test_mutated_csv_ends_in_a_result_or_one_line(data):
    p = _write("fuzz.csv", data)
    fz.ends_well(lambda: md.load(p))
    fz.ends_well(lambda: md.load(p, spec=SPEC))


@settings(max_examples=40, **SETTINGS)
@given(fz.mutated(fz.valid_txt()))
def test_mutated_txt_ends_in_a_result_or_one_line(data):
    p = _write("8mm1Hz0x5A.txt", data)
    fz.ends_well(lambda: md.load(p))
    fz.ends_well(lambda: md.load(p, spec=md.DataSpec.from_options(
        columns="time=0:s,displacement=1:mm,force=3:N")))


@pytest.fixture(scope="module")
def columnar_files():
    frame = md.to_frame(md.load(_write("v.csv", fz.valid_csv())))
    frame.to_parquet(TMP / "v.parquet", index=False)
    frame.to_feather(TMP / "v.feather")
    return {s: (TMP / f"v{s}").read_bytes() for s in (".parquet", ".feather")}


@pytest.mark.parametrize("suffix", [".parquet", ".feather"])
def test_mutated_columnar_ends_in_a_result_or_one_line(columnar_files, suffix):
    base = columnar_files[suffix]

    @settings(max_examples=30, **SETTINGS)
    @given(st.sampled_from([fz._truncate, fz._random, fz._insert, fz._delete, fz._bom_nul]),
           st.data())
    def case(op, data):
        p = _write(f"fuzz{suffix}", op(data.draw, base))
        fz.ends_well(lambda: md.load(p))

    case()


@settings(max_examples=60, **SETTINGS)
@given(fz.option_sets())
def test_spec_options_end_in_a_spec_or_one_line(options):
    fz.ends_well(lambda: md.DataSpec.from_options(**options))


@settings(max_examples=40, **SETTINGS)
@given(fz.mutated(fz.VALID_TOML))
def test_mutated_spec_file_ends_in_a_spec_or_one_line(data):
    p = _write("spec.toml", data)
    fz.ends_well(lambda: md.DataSpec.from_toml(p))


def _outcome(fn):
    """A comparable summary of a `read_csv` result (values bit for bit), or its message."""
    try:
        r = fn()
    except InputError as e:
        return ("error", str(e))
    values = []
    for c, v in sorted(r.values.items(), key=lambda kv: str(kv[0])):
        if isinstance(v, Codes):
            values.append((str(c), tuple(v.names[k] for k in v.codes)))
        else:
            values.append((str(c), np.asarray(v, float).tobytes()))
    lines = tuple(r.lines.line(i) for i in range(r.n))
    return (r.n, tuple(r.notes), tuple(values), lines)


@settings(max_examples=100, **SETTINGS)
@given(fz.mutated(fz.valid_csv()), st.sampled_from([64, 700, 1 << 20]), st.booleans())
@example(fz.with_cell(fz.valid_csv(), 12, 0, "\ufeff1".encode()), 97, True)  # found: a block
def test_fast_csv_path_reads_as_the_exact_one(data, block, strict):  # starting with U+FEFF
    p = _write("same.csv", data)
    columns = None if strict else dict(SPEC.columns)

    def read(exact):
        return read_csv(p, columns=columns, strict=strict, block_bytes=block, exact=exact)

    assert _outcome(lambda: read(False)) == _outcome(lambda: read(True))
