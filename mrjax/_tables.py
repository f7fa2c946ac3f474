"""Plain-text and markdown tables for the console and for reports."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np


def _cell(v: Any, floatfmt: str) -> str:
    if v is None:
        return "-"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return "-" if not math.isfinite(float(v)) else format(float(v), floatfmt)
    return str(v)


def _numeric(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def format_table(
    rows: Sequence[Sequence[Any]],
    headers: Sequence[str],
    *,
    style: Literal["plain", "markdown"] = "plain",
    floatfmt: str | Sequence[str] = ".4g",
) -> str:
    """Format rows as an aligned plain-text or markdown table.

    **Arguments:**

    - `rows`: a sequence of rows, each with one value per header. Floats are written with
        `floatfmt`; NaN, inf and `None` as `-`; booleans as `yes`/`no`; anything else by `str`.
    - `headers`: column titles.
    - `style`: `"plain"` (space-aligned, a dashed rule under the header) or `"markdown"`
        (a GitHub pipe table).
    - `floatfmt`: format spec of float cells, or one spec per column.

    Columns whose values are all numbers are right-aligned, the others left-aligned.

    **Returns:** the table as one string without a trailing newline.

    Raises `ValueError` if a row does not have one value per header or `style` is unknown.
    """
    headers = [str(h) for h in headers]
    rows = [list(r) for r in rows]
    for k, r in enumerate(rows):
        if len(r) != len(headers):
            raise ValueError(f"row {k} has {len(r)} values, expected {len(headers)} ({headers})")
    if style not in ("plain", "markdown"):
        raise ValueError(f"style must be 'plain' or 'markdown', got {style!r}")
    fmts = [floatfmt] * len(headers) if isinstance(floatfmt, str) else list(floatfmt)
    if len(fmts) != len(headers):
        raise ValueError(f"floatfmt has {len(fmts)} entries, expected {len(headers)}")
    text = [[_cell(v, f) for v, f in zip(r, fmts)] for r in rows]
    right = [bool(rows) and all(_numeric(r[j]) or r[j] is None for r in rows)
             for j in range(len(headers))]
    if style == "markdown":
        def esc(s: str) -> str:
            return s.replace("|", "\\|")

        lines = ["| " + " | ".join(esc(h) for h in headers) + " |",
                 "|" + "|".join("---:" if r else "---" for r in right) + "|"]
        lines += ["| " + " | ".join(esc(c) for c in r) + " |" for r in text]
        return "\n".join(lines)
    width = [max([len(headers[j])] + [len(r[j]) for r in text]) for j in range(len(headers))]

    def line(cells):
        out = [c.rjust(w) if r else c.ljust(w) for c, w, r in zip(cells, width, right)]
        return "  ".join(out).rstrip()

    lines = [line(headers), "  ".join("-" * w for w in width)]
    lines += [line(r) for r in text]
    return "\n".join(lines)
