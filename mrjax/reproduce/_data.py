"""The conditions of the study: the embedded Table 1 grid, or measured tests cut to their last
cycles, and the motions that Figs 7-8 show."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..data import Batch, Condition, load, make_batch, paper_grid

#: Motions (frequency [Hz], amplitude [m]) of the paper's Figs 7-8 and of `quick` mode.
FIG_MOTIONS: tuple[tuple[float, float], ...] = ((1.0, 0.008), (2.0, 0.004))
#: Records of `data=DIR` are cut to their last this many cycles.
DATA_CYCLES = 2


def _last_cycles(cond: Condition, cycles: float) -> Condition:
    """`cond` cut to its last `cycles` periods (unchanged without a frequency or if shorter)."""
    if cond.frequency is None or cond.frequency <= 0:
        return cond
    keep = cond.t >= cond.t[-1] - cycles / cond.frequency
    if keep.sum() < 3 or keep.all():
        return cond
    return Condition(cond.label, cond.current, cond.frequency, cond.amplitude, cond.t[keep],
                     cond.x[keep], cond.xdot[keep], cond.force[keep], source=cond.source)


def _motion_keys(batch: Batch) -> list[tuple[float, float] | None]:
    f, a = np.asarray(batch.frequency, float), np.asarray(batch.amplitude, float)
    return [(float(fi), float(ai)) if math.isfinite(fi) and math.isfinite(ai) else None
            for fi, ai in zip(f, a)]


def figure_motions(batch: Batch) -> list[tuple[float, float]]:
    """The motions of Figs 7-8: the paper's (1 Hz / 8 mm, 2 Hz / 4 mm) when the batch has them,
    else its slowest and fastest motion (by frequency, then amplitude)."""
    keys = _motion_keys(batch)
    have = sorted({k for k in keys if k is not None})
    want = [m for m in FIG_MOTIONS if any(np.allclose(m, h) for h in have)]
    if len(want) == len(FIG_MOTIONS):
        return [next(h for h in have if np.allclose(m, h)) for m in FIG_MOTIONS]
    return have[:1] + have[-1:] if len(have) > 1 else have


def motion_index(batch: Batch, motions) -> np.ndarray:
    """Indices of the conditions of `batch` whose (frequency, amplitude) is one of `motions`."""
    keys = _motion_keys(batch)
    return np.array([i for i, k in enumerate(keys)
                     if k is not None and any(np.allclose(k, m) for m in motions)], int)


def load_study_data(
    data: str | os.PathLike | None = None, *, quick: bool = False
) -> tuple[Batch, dict[str, Any]]:
    """The conditions of the study and a description of them.

    **Arguments:** `data` a directory (or file) of measured tests, or None for the embedded
    grid; `quick` the reduced selection (two motions).

    **Returns:** `(batch, info)`; `info` has `source`, `truth` (whether eq 24-29 are the
    truth) and `trimmed` (labels cut to their last cycles).
    """
    if data is None:
        motions = FIG_MOTIONS if quick else None
        batch = paper_grid() if motions is None else paper_grid(motions=motions)
        return batch, {"source": "embedded: mrjax.data.paper_grid() (Table 1 simulated from "
                                 "eq 24-29, tanh model, 20 N noise, 1 kHz, 2 cycles)",
                       "truth": True, "trimmed": []}
    conds = load(data)
    cut = [_last_cycles(c, DATA_CYCLES) for c in conds]
    trimmed = [c.label for c, k in zip(conds, cut) if k is not c]
    batch = make_batch(cut)
    if quick:
        idx = motion_index(batch, figure_motions(batch))
        if 0 < idx.size < batch.n_conditions:
            batch = batch.subset(idx)
    return batch, {"source": str(Path(data)), "truth": False, "trimmed": trimmed}
