"""The swarm's view of the data: a shorter, coarser copy of each record.

A swarm only has to find the basin of the optimum; the polish and every reported number use
the full record. Scoring every particle on every sample of a long, densely sampled record
costs far more than that needs (a 0.1 Hz sine test sampled at 200 Hz has 2,000 samples per
cycle and 5-10 cycles). For the swarm, each record is therefore *subsampled* (every k-th
measured sample, nothing filtered) to about `SAMPLES_PER_PERIOD` samples per period of its
known excitation frequency (`ESTIMATED_SAMPLES_PER_PERIOD` of an estimated one), and a
periodic record is cut to its first whole periods, at least `MIN_PERIODS` and about
`MAX_SAMPLES` samples; no record is subsampled below `MIN_SAMPLES` samples. The view starts
where the record starts, so a dynamic model's state starts where it does on the full record.

The frequency of a periodic test is its known excitation frequency (or the spectral estimate
of `mrjax.data.velocity_window`); a broadband record (random motion) keeps its whole length
at `BROADBAND_SAMPLES_PER_PERIOD` samples per period of its bandwidth (the frequency below which
99 % of the velocity energy lies).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ._condition import Batch, Condition, make_batch
from ._mask import fit_mask
from ._velocity import velocity_window

#: Samples per period kept for the swarm (periodic records: per excitation period): fine
#: enough that a hysteretic model's swarm sees the shape of each loop (a coarser view can lead
#: its swarm into a local optimum that the full record would not favour).
SAMPLES_PER_PERIOD = 128
#: Samples per period of the joint laws' swarm (`mrjax.generalize`): the density its coupled
#: search over every record was tuned at (from denser views its full-record polish needs more
#: steps).
JOINT_SAMPLES_PER_PERIOD = 64
#: Samples per period of a broadband record's bandwidth (the whole record is kept).
BROADBAND_SAMPLES_PER_PERIOD = 32
#: Samples per period of the spectral peak of a record without a known frequency (random
#: motion that the bandwidth test does not call broadband): fewer than for a known frequency,
#: so that `MAX_SAMPLES` keeps many of its "periods" rather than cutting the record to its
#: first few.
ESTIMATED_SAMPLES_PER_PERIOD = 64
#: About the most samples per periodic record the swarm scores (whole periods).
MAX_SAMPLES = 1024
#: The fewest periods a periodic record keeps.
MIN_PERIODS = 2
#: A record is never subsampled below this many samples (short records are kept whole).
MIN_SAMPLES = 512


@dataclasses.dataclass(frozen=True)
class View:
    """A swarm's view of a batch: `batch` and `mask` (C, T') the subsampled records, `step`
    (C,) the subsampling step and `stop` (C,) the number of full-record samples covered."""

    batch: Batch
    mask: object
    step: np.ndarray
    stop: np.ndarray


def view_plan(cond: Condition, samples_per_period: float | None = None) -> tuple[int, int]:
    """`(step, stop)` of one record's swarm view (see the module docstring);
    `samples_per_period` replaces `SAMPLES_PER_PERIOD` for a known excitation frequency."""
    n = cond.n_samples
    fs = cond.sample_rate
    f = cond.frequency if cond.frequency and "frequency" not in cond.estimated else None
    broadband = False
    per = SAMPLES_PER_PERIOD if samples_per_period is None else float(samples_per_period)
    if f is None:
        w = velocity_window(cond.t, cond.x)
        broadband = bool(w.broadband)
        f = w.bandwidth_Hz if broadband else w.peak_Hz
        per = BROADBAND_SAMPLES_PER_PERIOD if broadband else ESTIMATED_SAMPLES_PER_PERIOD
    if not (f and math.isfinite(f) and f > 0):
        return 1, n
    step = max(1, min(int(fs / (per * f)), n // MIN_SAMPLES))
    if broadband:
        return step, n
    period = fs / f  # samples per period of the full record
    periods = max(MIN_PERIODS, math.floor(MAX_SAMPLES * step / period))
    return step, min(n, math.ceil(periods * period))


def swarm_view(batch: Batch, transient: float | str | None = None, *,
               length: int | None = None, samples_per_period: float | None = None) -> View:
    """The swarm's view of every condition of `batch` (padded to the longest view, or to
    `length` samples: the chunks of one fit share the view length of the whole batch), with its
    fit mask (the same `transient` rule as the full fit). `samples_per_period`: the density
    for records of known frequency (default `SAMPLES_PER_PERIOD`)."""
    conds = batch.conditions()
    plans = [view_plan(c, samples_per_period) for c in conds]
    views = [c.subsample(step, stop) for c, (step, stop) in zip(conds, plans)]
    vb = make_batch(views, length=length)
    return View(batch=vb, mask=fit_mask(vb, transient), step=np.array([p[0] for p in plans]),
                stop=np.array([p[1] for p in plans]))
