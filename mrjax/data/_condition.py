"""Test conditions and padded, masked batches of them.

A :class:`Condition` is one measured (or simulated) test on the host, in SI units. A
:class:`Batch` stacks conditions of different lengths and sample rates into `(C, T)` arrays,
padded at the end and masked, so that fitting code can `vmap` over conditions.

Padding holds the displacement (and the per-sample command, if any) at its last value with
zero velocity and force; the padded sample interval repeats the last real one. Causal models
(all ODE models here) therefore never see padding before the real samples end, and the mask
removes it from every fitness.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._errors import InputError

#: Units of a per-sample command, indexed by `Batch.command_kind`: 0 none, 1 current [A],
#: 2 voltage [V].
COMMAND_UNITS: tuple[str | None, ...] = (None, "A", "V")
#: Fields of a condition that a loader may have estimated rather than read (columns of
#: `Batch.estimated`).
ESTIMATED_FIELDS: tuple[str, ...] = ("xdot", "frequency", "amplitude")


@dataclasses.dataclass(frozen=True, eq=False)
class Condition:
    """One test condition, in SI units.

    **Fields:**

    - `label`: name of the test (file stem, or the CSV `condition` value).
    - `current`: coil current [A], or `None` if unknown.
    - `frequency`: excitation frequency [Hz], or `None`.
    - `amplitude`: displacement amplitude [m], or `None`.
    - `t`: time [s], strictly increasing, shape (T,).
    - `x`: displacement [m], shape (T,).
    - `xdot`: velocity [m/s], shape (T,).
    - `force`: measured force [N], shape (T,).
    - `source`: where it came from (file path), for error messages.
    - `command`: a per-sample command signal, shape (T,), or `None`: a measured coil current
        [A] or a command voltage [V] (see `command_unit`). Kept through batching; unused by the
        fit of constant-current models.
    - `command_unit`: `"A"` (current) or `"V"` (voltage) when there is a `command`, else `None`.
    - `estimated`: names of the fields that were estimated rather than read: a subset of
        `{"xdot", "frequency", "amplitude"}` (velocity from displacement, frequency and
        amplitude from the spectrum; see `mrjax.data.estimate_motion`).
    - `notes`: what the loader tolerated or decided (skipped lines, unused columns, the
        velocity window), one line each; shown by `mrjax.data.describe`.
    - `warnings`: the loader's warnings about this condition (a likely unit mix-up, a
        broadband record whose velocity was estimated), one line each, also issued as
        `RuntimeWarning`s.

    The first nine fields may be given positionally, in this order.
    """

    label: str
    current: float | None
    frequency: float | None
    amplitude: float | None
    t: np.ndarray
    x: np.ndarray
    xdot: np.ndarray
    force: np.ndarray
    source: str = ""
    command: np.ndarray | None = None
    command_unit: str | None = None
    estimated: frozenset[str] = frozenset()
    notes: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()

    def __post_init__(self):
        where = self.source or self.label
        arrays = {}
        names = ("t", "x", "xdot", "force") + (("command",) if self.command is not None else ())
        for name in names:
            a = np.asarray(getattr(self, name), dtype=float)
            if a.ndim != 1:
                raise InputError(f"{where}: column {name} must be one-dimensional, got shape {a.shape}")
            arrays[name] = a
        lengths = {k: v.shape[0] for k, v in arrays.items()}
        if len(set(lengths.values())) != 1:
            raise InputError(f"{where}: mismatched column lengths {lengths}")
        n = lengths["t"]
        if n == 0:
            raise InputError(f"{where}: condition has no samples")
        if n < 3:
            raise InputError(f"{where}: condition has only {n} sample(s); at least 3 are needed")
        for name, a in arrays.items():
            bad = np.flatnonzero(~np.isfinite(a))
            if bad.size:
                raise InputError(
                    f"{where}: column {name} has a non-finite value ({a[bad[0]]}) at row {bad[0]}"
                )
        dt = np.diff(arrays["t"])
        bad = np.flatnonzero(dt <= 0)
        if bad.size:
            i = int(bad[0]) + 1
            raise InputError(
                f"{where}: time is not strictly increasing at row {i} "
                f"(t[{i - 1}]={arrays['t'][i - 1]:g} s, t[{i}]={arrays['t'][i]:g} s)"
            )
        for name in ("current", "frequency", "amplitude"):
            v = getattr(self, name)
            if v is None:
                continue
            v = float(v)
            if not math.isfinite(v):
                raise InputError(f"{where}: {name} is not finite ({v})")
            if v < 0:
                unit = {"current": "A", "frequency": "Hz", "amplitude": "m"}[name]
                raise InputError(f"{where}: {name} must be non-negative, got {v:g} {unit}")
            object.__setattr__(self, name, v)
        for k, v in arrays.items():
            v.setflags(write=False)
            object.__setattr__(self, k, v)
        object.__setattr__(self, "label", str(self.label))
        if (self.command is None) != (self.command_unit is None) or (
            self.command_unit not in COMMAND_UNITS
        ):
            raise InputError(
                f"{where}: a command needs command_unit 'A' (current) or 'V' (voltage), and "
                f"command_unit needs a command; got command_unit={self.command_unit!r}"
            )
        estimated = frozenset(self.estimated)
        unknown = sorted(estimated - set(ESTIMATED_FIELDS))
        if unknown:
            raise InputError(
                f"{where}: estimated names unknown field(s) {', '.join(unknown)}; "
                f"allowed: {', '.join(ESTIMATED_FIELDS)}"
            )
        object.__setattr__(self, "estimated", estimated)
        object.__setattr__(self, "notes", tuple(str(n) for n in self.notes))
        object.__setattr__(self, "warnings", tuple(str(n) for n in self.warnings))

    @property
    def n_samples(self) -> int:
        """Number of samples T."""
        return int(self.t.shape[0])

    @property
    def dt(self) -> np.ndarray:
        """Interval after each sample [s], shape (T,); the last entry repeats the previous."""
        d = np.diff(self.t)
        return np.append(d, d[-1])

    @property
    def sample_rate(self) -> float:
        """Median sample rate [Hz]."""
        return float(1.0 / np.median(np.diff(self.t)))

    def subsample(self, step: int = 1, stop: int | None = None) -> Condition:
        """The condition at every `step`-th sample of its first `stop` samples (default all),
        starting with the first: a shorter record of the same test on a coarser grid.

        Nothing is filtered: the samples kept are the measured ones, so a fitness over them is
        the fitness of the full record at those instants (a swarm searching on it scores the
        same model output there). The command, if any, is subsampled alike.
        """
        step = int(step)
        if step < 1:
            raise InputError(f"{self.source or self.label}: subsample step must be >= 1, got {step}")
        sl = slice(0, self.n_samples if stop is None else int(stop), step)
        cmd = None if self.command is None else self.command[sl]
        return dataclasses.replace(self, t=self.t[sl], x=self.x[sl], xdot=self.xdot[sl],
                                   force=self.force[sl], command=cmd)

    def __repr__(self) -> str:
        def f(v, unit, scale=1.0):
            return "?" if v is None else f"{v * scale:g} {unit}"

        est = f", estimated={sorted(self.estimated)}" if self.estimated else ""
        cmd = f", command [{self.command_unit}]" if self.command is not None else ""
        return (
            f"Condition({self.label!r}, i={f(self.current, 'A')}, f={f(self.frequency, 'Hz')}, "
            f"A={f(self.amplitude, 'mm', 1e3)}, T={self.n_samples}, fs={self.sample_rate:g} Hz"
            f"{cmd}{est})"
        )


def _nan_if_none(v: float | None) -> float:
    return np.nan if v is None else float(v)


class Batch(eqx.Module):
    """A batch of C conditions, padded to a common length T and masked.

    Arrays (all `(C, T)` unless stated): `t` [s], `x` [m], `xdot` [m/s], `force` [N],
    `dt` [s] (interval after each sample), `mask` (True on real samples); `current` [A],
    `frequency` [Hz], `amplitude` [m] of shape (C,), NaN where unknown; `command` the
    per-sample command (A or V; 0 where a condition has none, its last value on padding) with
    `command_kind` (C,) int: an index into `mrjax.data.COMMAND_UNITS` (0 none, 1 current [A],
    2 voltage [V]); `estimated` (C, 3) bool: whether `xdot`, `frequency`, `amplitude` (the
    columns of `mrjax.data.ESTIMATED_FIELDS`) were estimated. `labels` is static.
    """

    t: Float[Array, "C T"]
    x: Float[Array, "C T"]
    xdot: Float[Array, "C T"]
    force: Float[Array, "C T"]
    dt: Float[Array, "C T"]
    mask: Bool[Array, "C T"]
    current: Float[Array, " C"]
    frequency: Float[Array, " C"]
    amplitude: Float[Array, " C"]
    command: Float[Array, "C T"]
    command_kind: Int[Array, " C"]
    estimated: Bool[Array, "C 3"]
    labels: tuple[str, ...] = eqx.field(static=True)

    @property
    def n_conditions(self) -> int:
        """Number of conditions C."""
        return int(self.x.shape[0])

    @property
    def length(self) -> int:
        """Padded length T."""
        return int(self.x.shape[1])

    @property
    def n_samples(self) -> np.ndarray:
        """Real samples per condition, shape (C,)."""
        return np.asarray(self.mask).sum(axis=1)

    @property
    def has_command(self) -> np.ndarray:
        """Whether each condition carries a per-sample command, shape (C,) bool."""
        return np.asarray(self.command_kind) > 0

    def __len__(self) -> int:
        return self.n_conditions

    def condition(self, i: int) -> Condition:
        """Condition `i` with its padding removed."""
        n = int(self.n_samples[i])

        def g(a):
            return np.asarray(a[i, :n])

        def meta(a):
            v = float(np.asarray(a[i]))
            return None if math.isnan(v) else v

        unit = COMMAND_UNITS[int(np.asarray(self.command_kind[i]))]
        est = np.asarray(self.estimated[i])
        return Condition(
            self.labels[i], meta(self.current), meta(self.frequency), meta(self.amplitude),
            g(self.t), g(self.x), g(self.xdot), g(self.force),
            command=None if unit is None else g(self.command), command_unit=unit,
            estimated=frozenset(n for n, e in zip(ESTIMATED_FIELDS, est) if e),
        )

    def conditions(self) -> list[Condition]:
        """All conditions, unpadded."""
        return [self.condition(i) for i in range(self.n_conditions)]

    def subset(self, index: Sequence[int] | np.ndarray) -> Batch:
        """The conditions at `index` (ints or a boolean mask), re-padded to their own length."""
        idx = np.arange(self.n_conditions)[np.asarray(index)]
        return make_batch([self.condition(int(i)) for i in idx])

    def __repr__(self) -> str:
        return f"Batch(C={self.n_conditions}, T={self.length}, labels={list(self.labels)[:4]}...)"


def make_batch(
    conditions: Sequence[Condition], *, length: int | None = None, dtype=None
) -> Batch:
    """Stack conditions into a padded, masked :class:`Batch`.

    **Arguments:**

    - `conditions`: one or more :class:`Condition`.
    - `length`: padded length T (default: the longest condition).
    - `dtype`: float dtype of the arrays (default: JAX's default float, float64 under x64).

    Raises :class:`mrjax.InputError` for an empty list or a `length` shorter than a condition.
    """
    conditions = list(conditions)
    if not conditions:
        raise InputError("no test conditions given (empty list or no data files)")
    for c in conditions:
        if not isinstance(c, Condition):
            raise InputError(f"expected mrjax.data.Condition objects, got {type(c).__name__}")
    longest = max(c.n_samples for c in conditions)
    T = longest if length is None else int(length)
    if T < longest:
        raise InputError(f"length={T} is shorter than the longest condition ({longest} samples)")
    C = len(conditions)
    fdt = dtype if dtype is not None else jnp.zeros(()).dtype
    n = np.asarray([c.n_samples for c in conditions])

    def stacked(name: str):
        """One (C, T) field, built on the host and handed to JAX before the next one (the
        host copy of a fleet's batch is one field, not all of them)."""
        out = np.zeros((C, T))
        for i, c in enumerate(conditions):
            k = n[i]
            if name == "t":
                out[i, :k] = c.t
                out[i, k:] = c.t[-1] + (c.t[-1] - c.t[-2]) * np.arange(1, T - k + 1)
            elif name == "dt":
                out[i, :k - 1] = np.diff(c.t)
                out[i, k - 1:] = c.t[-1] - c.t[-2]
            elif name in ("x", "command"):
                a = c.x if name == "x" else c.command
                if a is not None:
                    out[i, :k] = a
                    out[i, k:] = a[-1]
            else:
                out[i, :k] = getattr(c, name)
        return jax.device_put(out.astype(fdt, copy=False))

    arrays = {k: stacked(k) for k in ("t", "x", "xdot", "force", "dt", "command")}
    mask = np.arange(T)[None, :] < n[:, None]
    kind = np.asarray([0 if c.command is None else COMMAND_UNITS.index(c.command_unit)
                       for c in conditions], dtype=np.int32)
    estimated = np.asarray([[name in c.estimated for name in ESTIMATED_FIELDS]
                            for c in conditions], dtype=bool).reshape(C, len(ESTIMATED_FIELDS))

    def meta(name):
        return np.asarray([_nan_if_none(getattr(c, name)) for c in conditions], dtype=fdt)

    # host arrays moved to the device as they are (`device_put` transfers; `jnp.asarray` of a
    # host array would compile a program per shape)
    return Batch(**arrays, **jax.device_put(dict(
        mask=np.asarray(mask), current=meta("current"), frequency=meta("frequency"),
        amplitude=meta("amplitude"), command_kind=np.asarray(kind),
        estimated=np.asarray(estimated))), labels=tuple(c.label for c in conditions))
