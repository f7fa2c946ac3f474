"""What mrjax read: one report per condition, for `mrjax inspect` and for a quick look in Python."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from ._checks import check_condition
from ._condition import Batch, Condition
from ._spectrum import estimate_motion
from ._velocity import velocity_window

#: A given (nominal) amplitude further than this fraction from the measured half range is
#: shown beside it.
NOMINAL_TOL = 0.02


@dataclasses.dataclass(frozen=True)
class ConditionReport:
    """What was read for one condition, in SI units.

    **Fields:**

    - `label`, `source`: the condition's name and file.
    - `n_samples`, `sample_rate` [Hz] (median), `duration` [s], `uniform` (sample intervals
        equal within 0.1 %).
    - `x_range` [m], `xdot_range` [m/s], `force_range` [N]: (min, max).
    - `velocity`: `"measured"` or `"estimated"` (from displacement).
    - `frequency` [Hz], `amplitude` [m]: as given, or estimated (then named in `estimated`).
    - `estimated`: which of `xdot`, `frequency`, `amplitude` are estimates.
    - `current` [A] or `None`; `command_unit` (`"A"`, `"V"` or `None`) and `command_range`.
    - `bandwidth_Hz`: frequency below which 99 % of the displacement-derivative energy lies;
        `broadband`: no single frequency describes the motion (see
        `mrjax.data.VelocityWindow`).
    - `notes`: what the loader tolerated or decided; `warnings`: sanity warnings.
    - `amplitude_measured` [m]: half the displacement's range, what the record shows (a
        nominal `amplitude` from a file name such as `2mm5Hz0A` may differ: the line then
        shows both).
    """

    label: str
    source: str
    n_samples: int
    sample_rate: float
    duration: float
    uniform: bool
    x_range: tuple[float, float]
    xdot_range: tuple[float, float]
    force_range: tuple[float, float]
    velocity: str
    frequency: float | None
    amplitude: float | None
    estimated: frozenset[str]
    current: float | None
    command_unit: str | None
    command_range: tuple[float, float] | None
    bandwidth_Hz: float
    broadband: bool
    notes: tuple[str, ...]
    warnings: tuple[str, ...]
    amplitude_measured: float | None = None

    def line(self) -> str:
        """One line: samples, rate, duration, ranges with units, frequency and amplitude
        (`~` marks an estimate), velocity measured or estimated, current or command, warnings."""

        def rng(r, scale, unit):
            return f"{r[0] * scale:.4g}..{r[1] * scale:.4g} {unit}"

        def est(name, text):
            return f"~{text} (estimated)" if name in self.estimated else text

        f = "f ?" if self.frequency is None else "f " + est("frequency", f"{self.frequency:.4g} Hz")
        a = "A ?" if self.amplitude is None else "A " + est("amplitude",
                                                             f"{self.amplitude * 1e3:.4g} mm")
        am = self.amplitude_measured
        if (self.amplitude is not None and "amplitude" not in self.estimated and am is not None
                and abs(am - self.amplitude) > NOMINAL_TOL * self.amplitude):
            a += f" nominal, {am * 1e3:.4g} mm measured (half the range)"
        if self.command_unit is not None:
            drive = f"command {rng(self.command_range, 1.0, self.command_unit)}"
        elif self.current is not None:
            drive = f"current {self.current:g} A"
        else:
            drive = "current unknown"
        parts = [
            f"{self.label}: {self.n_samples} samples at {self.sample_rate:.6g} Hz "
            f"({self.duration:.4g} s{'' if self.uniform else ', non-uniform'})",
            f"x {rng(self.x_range, 1e3, 'mm')}, v {rng(self.xdot_range, 1e3, 'mm/s')} "
            f"({self.velocity}), F {rng(self.force_range, 1.0, 'N')}",
            f"{f}, {a}" + (", broadband" if self.broadband else ""),
            drive,
        ]
        if self.warnings:
            parts.append("warning: " + "; ".join(self.warnings))
        return "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        """The report as JSON-ready values (SI units; lists for ranges and sets)."""
        out = dataclasses.asdict(self)
        out["estimated"] = sorted(self.estimated)
        for k, v in out.items():
            if isinstance(v, tuple):
                out[k] = list(v)
        return out


def _range(a: np.ndarray) -> tuple[float, float]:
    return float(np.min(a)), float(np.max(a))


def describe(conditions: Sequence[Condition] | Batch | Condition) -> list[ConditionReport]:
    """Reports of what was read, one per condition (see :class:`ConditionReport`).

    **Arguments:** `conditions`: conditions as `mrjax.data.load` returns them, a single
    condition, or a :class:`Batch` (whose conditions no longer carry the loader's notes).

    **Returns:** one :class:`ConditionReport` per condition; `[r.line() for r in reports]` is
    a readable summary. Frequency and amplitude that the condition lacks are estimated here
    (and marked so); the sanity checks of `mrjax.data.check_condition` are run again.
    """
    if isinstance(conditions, Condition):
        conditions = [conditions]
    conds = conditions.conditions() if isinstance(conditions, Batch) else list(conditions)
    out = []
    for c in conds:
        estimated = set(c.estimated)
        frequency, amplitude = c.frequency, c.amplitude
        if frequency is None or amplitude is None:
            f_est, a_est = estimate_motion(c.t, c.x)
            if frequency is None and f_est > 0:
                frequency = f_est
                estimated.add("frequency")
            if amplitude is None:
                amplitude = a_est
                estimated.add("amplitude")
        steps = np.diff(c.t)
        vw = velocity_window(c.t, c.x)
        warns = list(c.warnings)
        warns += [w for w in check_condition(c) if w not in warns]
        out.append(ConditionReport(
            label=c.label, source=c.source, n_samples=c.n_samples, sample_rate=c.sample_rate,
            duration=float(c.t[-1] - c.t[0]),
            uniform=bool(np.max(np.abs(steps - np.median(steps))) <= 1e-3 * np.median(steps)),
            x_range=_range(c.x), xdot_range=_range(c.xdot), force_range=_range(c.force),
            velocity="estimated" if "xdot" in c.estimated else "measured",
            frequency=frequency, amplitude=amplitude, estimated=frozenset(estimated),
            current=c.current, command_unit=c.command_unit,
            command_range=None if c.command is None else _range(c.command),
            bandwidth_Hz=vw.bandwidth_Hz, broadband=vw.broadband,
            notes=c.notes, warnings=tuple(warns),
            amplitude_measured=0.5 * float(np.max(c.x) - np.min(c.x)),
        ))
    return out
