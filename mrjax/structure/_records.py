"""A structure's records: :class:`Record` (one measured or simulated test: the input and the
response), :class:`Records` (records padded into (U, T) arrays), the simulation's step inputs
(:func:`step_inputs`) and the equation-error view of the swarm (:func:`equation_view`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from .._errors import InputError
from ..data import estimate_velocity
from ._system import AbstractStructure

#: Relative spread of the sample intervals a record may have (rounded time stamps).
UNIFORM_RTOL = 1e-4
#: The swarm's equation-error view: at most this many samples of a record that is not
#: periodic (a periodic one: its first period).
VIEW_SAMPLES = 8192
#: Lines of a periodic input counted as excited: amplitude above this fraction of the largest.
EXCITED = 1e-3
#: The share of the swarm's view left out at its start: the element's state starts at zero
#: there, not where the record left it.
VIEW_SETTLE = 0.1


@dataclasses.dataclass(frozen=True, eq=False)
class Record:
    """One record of a structure, in SI units.

    **Fields:** `label`; `t` (n,) time [s], uniformly sampled; `input` (n,) the force [N]
    (`SDOF`) or the ground acceleration [m/s²] (`BaseExcited`); `response` (n,) the measured
    displacement [m] or absolute acceleration [m/s²], or None (a record to predict only);
    `source` where it came from (for messages).
    """

    label: str
    t: np.ndarray
    input: np.ndarray
    response: np.ndarray | None = None
    source: str = ""

    def __post_init__(self):
        where = self.source or self.label
        t = np.asarray(self.t, float)
        u = np.asarray(self.input, float)
        y = None if self.response is None else np.asarray(self.response, float)
        for name, a in (("time", t), ("input", u), ("response", y)):
            if a is not None and a.ndim != 1:
                raise InputError(f"{where}: {name} must be one-dimensional, got shape {a.shape}")
        if u.shape != t.shape or (y is not None and y.shape != t.shape):
            raise InputError(f"{where}: time, input and response differ in length "
                             f"({t.size}, {u.size}, {None if y is None else y.size})")
        if t.size < 3:
            raise InputError(f"{where}: {t.size} sample(s); a record needs at least 3")
        for name, a in (("time", t), ("input", u), ("response", y)):
            bad = np.array([], int) if a is None else np.flatnonzero(~np.isfinite(a))
            if bad.size:
                raise InputError(f"{where}: the {name} has a non-finite value ({a[bad[0]]}) at "
                                 f"row {bad[0]}")
        d = np.diff(t)
        dt = float(np.median(d))
        if not dt > 0 or np.any(np.abs(d - dt) > UNIFORM_RTOL * dt):
            i = int(np.argmax(np.abs(d - dt)))
            raise InputError(f"{where}: a structure's record needs a uniform sample rate (the "
                             f"interval at row {i + 1} is {d[i]:g} s, the median {dt:g} s)")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "input", u)
        object.__setattr__(self, "response", y)
        object.__setattr__(self, "label", str(self.label))

    @property
    def n(self) -> int:
        """Samples."""
        return int(self.t.size)

    @property
    def dt(self) -> float:
        """Sample interval [s]."""
        return float((self.t[-1] - self.t[0]) / (self.n - 1))


@dataclasses.dataclass(frozen=True, eq=False)
class Records:
    """Records padded into (U, T) arrays (zeros after each record's end).

    **Fields:** `labels` (U,); `t`, `input`, `response` (U, T); `mask` (U, T) the samples
    with a measured response; `n` (U,) samples; `dt` (U,) [s]; `items` the records.
    """

    labels: tuple[str, ...]
    t: np.ndarray
    input: np.ndarray
    response: np.ndarray
    mask: np.ndarray
    n: np.ndarray
    dt: np.ndarray
    items: tuple[Record, ...]

    @property
    def n_units(self) -> int:
        return len(self.labels)

    def first(self, length: int) -> Records:
        """The first `length` samples of every record (the shorter ones whole)."""
        return stack([dataclasses.replace(r, t=r.t[:length], input=r.input[:length],
                                          response=None if r.response is None
                                          else r.response[:length])
                      for r in self.items])


def stack(records: Sequence[Record]) -> Records:
    """The records padded into (U, T) arrays (:class:`Records`); labels must differ."""
    records = list(records)
    if not records:
        raise InputError("no records")
    labels = tuple(r.label for r in records)
    if len(set(labels)) != len(labels):
        dup = next(lab for lab in labels if labels.count(lab) > 1)
        raise InputError(f"two records are labelled {dup!r}")
    U, T = len(records), max(r.n for r in records)
    t, u, y = np.zeros((U, T)), np.zeros((U, T)), np.zeros((U, T))
    mask = np.zeros((U, T), bool)
    for i, r in enumerate(records):
        t[i, : r.n], u[i, : r.n] = r.t, r.input
        t[i, r.n:] = r.t[-1] + r.dt * np.arange(1, T - r.n + 1)
        if r.response is not None:
            y[i, : r.n] = r.response
            mask[i, : r.n] = True
    return Records(labels, t, u, y, mask, np.array([r.n for r in records]),
                   np.array([r.dt for r in records]), tuple(records))


def check_periods(records: Records, structure: AbstractStructure) -> None:
    """Errors for records that are not whole periods of a periodic structure's input."""
    P = structure.period
    if P is None:
        return
    for lab, n in zip(records.labels, records.n):
        if n < P or n % P:
            raise InputError(f"record {lab!r}: {int(n)} samples are not whole periods of "
                             f"{P} samples (--periodic)")


def step_inputs(records: Records, structure: AbstractStructure, substeps: int) -> tuple:
    """The step inputs of :func:`mrjax.structure.simulate` for every record: `(start, middle,
    end, h, active, take)`, each (U, S) with S = (W + T - 1) m (W the period's warm-up, T the
    longest record, m `substeps`), `take` (U, T). One period of a periodic input runs first and
    is discarded; a shorter record's steps after its end do not run."""
    m = int(substeps)
    W = structure.period or 0
    U, T = records.input.shape
    S = (W + T - 1) * m
    start, middle, end = (np.zeros((U, S)) for _ in range(3))
    h, active = np.zeros((U, S)), np.zeros((U, S), bool)
    for i, rec in enumerate(records.items):
        a, b, c = structure.interpolation.stage_inputs(rec.input, m, W > 0)
        run = (W + rec.n - 1) * m
        for out, v in ((start, a), (middle, b), (end, c)):
            out[i, : W * m] = v[: W * m]
            out[i, W * m: run] = v[: (rec.n - 1) * m]
        h[i] = rec.dt / m
        active[i, :run] = True
    take = np.broadcast_to((W + np.arange(T)) * m, (U, T)).copy()
    return start, middle, end, h, active, take


def input_lines(u: np.ndarray) -> np.ndarray:
    """(n // 2 + 1,) the lines of one period of a periodic input that carry it (amplitude
    above `EXCITED` of the largest), and the mean."""
    U = np.abs(np.fft.rfft(u))
    return (U > EXCITED * U.max()) | (np.arange(U.size) == 0)


def _spectral(signal: np.ndarray, dt: float, power: int, low: int = 0) -> np.ndarray:
    """`signal` (one period) times $(i\\omega)^{power}$ in its spectrum (a derivative for
    power > 0; an integral for power < 0, without the lines below `low`)."""
    n = signal.size
    w = 2.0 * np.pi * np.fft.rfftfreq(n, dt)
    S = np.fft.rfft(signal)
    if power:
        k = np.arange(w.size)
        ok = (w > 0) & (k >= low)
        S = np.where(ok, S * np.where(ok, 1j * w, 1.0) ** power, 0.0)
    return np.fft.irfft(S, n)


def motion(rec: Record, structure: AbstractStructure) -> tuple[np.ndarray, ...]:
    """`(y, v, a)` the displacement, velocity and acceleration of y a record implies: of a
    periodic record one period (P,), averaged over its periods, by its spectrum (an
    acceleration integrated on the lines from the input's lowest up); otherwise (n,) from a
    displacement by two Savitzky-Golay derivatives (`mrjax.data.estimate_velocity`)."""
    P = structure.period
    if P is None:
        if structure.response != "displacement":
            raise InputError(f"record {rec.label!r}: the swarm's start needs the displacement "
                             f"and velocity; from an acceleration it needs a periodic record "
                             f"(--periodic)")
        v = estimate_velocity(rec.t, rec.response)
        return rec.response, v, estimate_velocity(rec.t, v)
    mean = rec.response.reshape(-1, P).mean(axis=0)
    if structure.response == "displacement":
        return mean, _spectral(mean, rec.dt, 1), _spectral(mean, rec.dt, 2)
    low = int(np.flatnonzero(input_lines(rec.input[:P]))[1:].min(initial=1))
    acc = mean - structure.absolute(rec.input[:P], 0.0)
    return _spectral(acc, rec.dt, -2, low), _spectral(acc, rec.dt, -1, low), acc


def equation_view(records: Records, structure: AbstractStructure, mass: float | None
                  ) -> tuple[np.ndarray, ...]:
    """The swarm's view of every record, as an equation error: `(y, v, a, target, mask, dt,
    keep)`, (U, L) each but `dt` (U,) and `keep`: the motion of y (:func:`motion`) and the
    force the element must give, `target`: the input (a force) where the mass is unknown
    (`mass` None: the swarm solves it with the element's linear parameters), else what the
    input, the mass and the acceleration leave for it. A periodic record's view is its
    periodic part twice (L = 2P) with `keep` (U, P // 2 + 1) its input's lines
    (:func:`input_lines`; see `EquationObjective`); any other record's its first
    `VIEW_SAMPLES`, the first `VIEW_SETTLE` of it not scored (`keep` unused)."""
    P = structure.period
    L = 2 * P if P is not None else min(int(records.n.max()), VIEW_SAMPLES)
    U = records.n_units
    out = [np.zeros((U, L)) for _ in range(4)]
    mask = np.zeros((U, L), bool)
    keep = np.zeros((U, 1 if P is None else P // 2 + 1))
    for i, rec in enumerate(records.items):
        y, v, a = (np.asarray(s)[:L] for s in motion(rec, structure))
        u = rec.input[:L] if P is None else rec.input[:P]
        target = u if mass is None else structure.target(u, a, mass)
        if P is not None:
            y, v, a, target = (np.tile(s, 2) for s in (y, v, a, target))
            mask[i, P:] = True
            keep[i] = input_lines(rec.input[:P])
        else:
            k = len(u)
            mask[i, int(VIEW_SETTLE * k): k - max(k // 50, 1)] = True
        for o, s in zip(out, (y, v, a, target)):
            o[i, : s.size] = s
    return (*out, mask, records.dt.copy(), keep)
