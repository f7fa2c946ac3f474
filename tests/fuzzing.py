"""Bad input, tried widely: hypothesis strategies that mutate valid files and specs, and the
check that every case ends in a result or one `InputError` line (issue 27).

Used by `tests/test_fuzz_input.py` (a few hundred cases in the suite) and
`benchmarks/fuzz_input.py` (many more). The valid files are made at import time from mrjax's
own tanh model (two short tests); the mutations are those a corrupted, hand-edited or foreign
file shows: truncation, random bytes, inserted or deleted spans, mixed delimiters, other line
ends, unicode or empty headers, huge, special or malformed numbers, emptied columns,
duplicated or dropped lines, stray quotes, a byte-order mark, NUL bytes.
"""

from __future__ import annotations

import functools
import io
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
from hypothesis import strategies as st

import mrjax
from mrjax import InputError, ResultWarning

#: Numbers and non-numbers that a cell may be replaced with.
ODD_CELLS = ("1e308", "1e400", "-1e999", "nan", "NaN", "inf", "-inf", "1_000", "0x10", "١٢",
             "", " ", "1,5", "1.2.3", "+", "e5", "nan(1)", "\ufeff1", "1e-400", "0", "-0",
             "9" * 400, "\x00", '"1"', '"', "A", "é")


@functools.cache
def valid_csv() -> bytes:
    """A valid long CSV: two tanh tests of 60 samples (conditions `a` and `b`)."""
    conds = [mrjax.data.simulate("kwok", mrjax.data.paper_parameters(i), frequency=f,
                                 amplitude=0.006, current=i, sample_rate=200.0, cycles=0.3 * f)
             for i, f in ((0.25, 1.0), (0.75, 1.0))]
    conds = [c.subsample(1, 60) for c in conds]
    frame = mrjax.data.to_frame([dataclass_relabel(c, lab) for c, lab in zip(conds, "ab")])
    buf = io.StringIO()
    frame.to_csv(buf, index=False)
    return buf.getvalue().encode()


def with_cell(data: bytes, line: int, column: int, text: bytes) -> bytes:
    """`data` (a CSV) with the cell of 0-based `line` and `column` replaced by `text`."""
    lines = data.split(b"\n")
    cells = lines[line].split(b",")
    cells[column] = text
    lines[line] = b",".join(cells)
    return b"\n".join(lines)


def dataclass_relabel(c, label):
    import dataclasses

    return dataclasses.replace(c, label=label)


@functools.cache
def valid_txt() -> bytes:
    """A valid UTFSM-style text file: t, x [mm], v [mm/s], F [N], 60 rows."""
    c = mrjax.data.simulate("kwok", mrjax.data.paper_parameters(0.5), frequency=1.0,
                            amplitude=0.008, current=0.5, sample_rate=200.0)
    out = io.BytesIO()
    np.savetxt(out, np.column_stack([c.t, c.x * 1e3, c.xdot * 1e3, c.force])[:60], fmt="%.8g")
    return out.getvalue()


VALID_TOML = b'''[columns]
time = "time_s:s"
displacement = "displacement_m:m"
force = "force_N:N"
condition = "condition"

[meta]
current_A = 0.5

[velocity]
window_ms = 20
'''


@st.composite
def mutated(draw: Callable, base: bytes) -> bytes:
    """`base` with one to four mutations (see the module notes)."""
    data = base
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(MUTATIONS))
        data = op(draw, data)
    return data


def _pos(draw, data: bytes) -> int:
    return draw(st.integers(0, len(data)))


def _truncate(draw, data):
    return data[:_pos(draw, data)]


def _random(draw, data):
    return draw(st.binary(max_size=600))


def _insert(draw, data):
    k = _pos(draw, data)
    return data[:k] + draw(st.binary(min_size=1, max_size=40)) + data[k:]


def _delete(draw, data):
    a = _pos(draw, data)
    return data[:a] + data[a + draw(st.integers(1, 200)):]


def _delimiters(draw, data):
    new = draw(st.sampled_from([b";", b"\t", b" ", b",,", b", ", b"|"]))
    every = draw(st.booleans())
    if every:
        return data.replace(b",", new)
    k = data.find(b",", _pos(draw, data))
    return data if k < 0 else data[:k] + new + data[k + 1:]


def _line_ends(draw, data):
    return data.replace(b"\n", draw(st.sampled_from([b"\r\n", b"\r", b"\n\n", b"\n \n"])))


def _header(draw, data):
    head, nl, rest = data.partition(b"\n")
    names = draw(st.lists(st.text(max_size=12), min_size=1, max_size=10))
    return ",".join(names).encode("utf-8", "surrogatepass") + nl + rest


def _cell(draw, data):
    lines = data.split(b"\n")
    i = draw(st.integers(0, max(len(lines) - 1, 0)))
    cells = lines[i].split(b",")
    j = draw(st.integers(0, max(len(cells) - 1, 0)))
    cells[j] = draw(st.sampled_from(ODD_CELLS)).encode()
    lines[i] = b",".join(cells)
    return b"\n".join(lines)


def _empty_column(draw, data):
    lines = data.split(b"\n")
    j = draw(st.integers(0, 9))
    drop = draw(st.booleans())  # remove the cells, or leave them empty
    out = []
    for ln in lines:
        cells = ln.split(b",")
        if j < len(cells):
            if drop:
                del cells[j]
            else:
                cells[j] = b""
        out.append(b",".join(cells))
    return b"\n".join(out)


def _lines(draw, data):
    lines = data.split(b"\n")
    i = draw(st.integers(0, max(len(lines) - 1, 0)))
    if draw(st.booleans()):
        lines.insert(i, lines[i])
    else:
        del lines[i]
    return b"\n".join(lines)


def _quote(draw, data):
    k = _pos(draw, data)
    return data[:k] + b'"' + data[k:]


def _bom_nul(draw, data):
    if draw(st.booleans()):
        return b"\xef\xbb\xbf" + data
    k = _pos(draw, data)
    return data[:k] + b"\x00" + data[k:]


MUTATIONS = (_truncate, _random, _insert, _delete, _delimiters, _line_ends, _header, _cell,
             _empty_column, _lines, _quote, _bom_nul)

#: Pieces of the option strings of `DataSpec.from_options`: plausible and odd.
ROLES = ("time", "displacement", "velocity", "force", "current", "command", "condition",
         "frequency", "amplitude", "disp", "", " force ")
SOURCES = ("t", "x", "0", "1", "12", "data[2]", "M[0]", "time_s", "force_N", "", "é", "a:b",
           "[1]", " 3 ")
UNITS = ("s", "ms", "mm", "cm", "m", "in", "mm/s", "cm/s", "N", "kN", "lbf", "A", "mA", "V",
         "Hz", "", "N/m", "furlong", "1/s", "%")
VALUES = ("0", "0.5", "-1", "1e400", "nan", "inf", "500 mA", "8 mm", "1 kHz", "20 ms", "3 V",
          "", "x", "0,0.5,1", "a.mat=0.5,b.mat=1", "*=2", "=1", "0.5,", ",", "1e-300")
OPTION_KEYS = ("columns", "wide", "sample_rate", "current", "frequency", "amplitude", "label",
               "velocity_window")


@st.composite
def option_sets(draw: Callable) -> dict[str, str]:
    """Keyword arguments of `DataSpec.from_options`: `role=SOURCE:UNIT` lists and metadata
    values, made of plausible and odd pieces, with an odd separator now and then."""
    out = {}
    for key in draw(st.lists(st.sampled_from(OPTION_KEYS), min_size=1, max_size=4,
                             unique=True)):
        if key in ("columns", "wide"):
            items = []
            for _ in range(draw(st.integers(1, 4))):
                role, src, unit = (draw(st.sampled_from(x)) for x in (ROLES, SOURCES, UNITS))
                colon = draw(st.sampled_from([":", ":", ":", "", "::"]))
                if key == "wide":
                    srcs = draw(st.lists(st.sampled_from(SOURCES), min_size=1, max_size=3))
                    items.append(f"{role}={','.join(srcs)}{colon}{unit}")
                else:
                    items.append(f"{role}={src}{colon}{unit}")
            out[key] = draw(st.sampled_from([",", ";"])).join(items)
        else:
            out[key] = draw(st.sampled_from(VALUES))
    return out


def ends_well(fn: Callable[[], Any]) -> str:
    """Run `fn`; it must return or raise one `InputError` line. Returns `"ok"` or
    `"error"`; anything else (another exception, a warning other than mrjax's
    `ResultWarning`s about the data) fails."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            fn()
            outcome = "ok"
        except InputError as e:
            msg = str(e)
            assert msg and "\n" not in msg, repr(msg)
            outcome = "error"
    for w in caught:  # mrjax's sanity warnings, not numpy's floating-point ones
        text = str(w.message)
        assert w.category in (RuntimeWarning, ResultWarning) and "encountered" not in text, (
            f"unexpected warning: {w.category.__name__}: {text}")
    return outcome
