"""How a structure's input is known between its samples: the interpolations.

The simulation (`mrjax.structure.simulate`) integrates each sample interval in `substeps`
classic Runge-Kutta steps, which read the input at the start, the middle and the end of every
step. An interpolation gives those values from the sampled input; the choice sets the floor of
the simulation error (what remains with the true parameters, see `docs/how-to/structure.md`):

- :class:`ZeroOrderHold`: the input held at each sample until the next (a digital controller's
    output, before any reconstruction filter);
- :class:`Linear`: a straight line between samples;
- :class:`BandLimited` (default): the band-limited (trigonometric, FFT) interpolant, exact for
    an input sampled above twice its bandwidth (an anti-aliased measurement, a multisine). A
    record of whole periods (`period=`) is interpolated as one period; any other record through
    its even extension (mirrored at both ends), which has no jump where the FFT wraps around.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import numpy as np

from .._errors import InputError


class AbstractInterpolation(eqx.Module):
    """The input between its samples (see the module docstring). Subclasses give the values on
    a grid `r` times finer than the samples (:meth:`fine`); a held input gives its steps'
    values itself (:meth:`stage_inputs`)."""

    name: ClassVar[str]

    @abc.abstractmethod
    def fine(self, u: np.ndarray, r: int, periodic: bool) -> np.ndarray:
        """The input at $t_0 + j\\,\\Delta t / r$ for every interval: `u` (n,) the samples;
        `r` points per interval; `periodic`: the samples are whole periods (the last interval
        returns to `u[0]`). **Returns:** (I r + 1,) with I = n intervals if periodic, else
        n - 1."""

    def stage_inputs(self, u: np.ndarray, substeps: int, periodic: bool
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The input at the start, middle and end of every Runge-Kutta step: `u` (n,) the
        samples, `substeps` m steps per interval, `periodic` as :meth:`fine`.

        **Returns:** `(start, middle, end)`, each (I m,) (I intervals, see :meth:`fine`)."""
        g = self.fine(np.asarray(u, float), 2 * int(substeps), periodic)
        return g[0:-1:2], g[1::2], g[2::2]


def _intervals(n: int, periodic: bool) -> int:
    return n if periodic else n - 1


class ZeroOrderHold(AbstractInterpolation):
    """The input held at each sample's value until the next sample."""

    name: ClassVar[str] = "zoh"

    def fine(self, u, r, periodic):
        n = _intervals(len(u), periodic)
        return np.append(np.repeat(np.asarray(u, float)[:n], r), u[0] if periodic else u[-1])

    def stage_inputs(self, u, substeps, periodic):
        n = _intervals(len(u), periodic)
        held = np.repeat(np.asarray(u, float)[:n], int(substeps))
        return held, held, held  # the step that ends on the next sample still sees this one


class Linear(AbstractInterpolation):
    """A straight line between consecutive samples."""

    name: ClassVar[str] = "linear"

    def fine(self, u, r, periodic):
        u = np.asarray(u, float)
        if periodic:
            u = np.append(u, u[0])
        n = len(u) - 1
        return np.interp(np.arange(n * r + 1) / r, np.arange(n + 1), u)


class BandLimited(AbstractInterpolation):
    """The band-limited interpolant (zero-padded FFT): a record of whole periods as one period;
    any other record through its even extension."""

    name: ClassVar[str] = "fft"

    def fine(self, u, r, periodic):
        u = np.asarray(u, float)
        n = len(u)
        e = u if periodic else np.concatenate([u, u[-2:0:-1]])  # mirrored: no wrap-around jump
        M = len(e)
        U = np.fft.rfft(e)
        Z = np.zeros(M * r // 2 + 1, complex)
        Z[: U.size] = U
        if M % 2 == 0:  # the Nyquist line: half on each side of the finer grid's spectrum
            Z[M // 2] *= 0.5
        g = np.fft.irfft(Z, M * r) * r
        return np.append(g, g[0])[: _intervals(n, periodic) * r + 1]


#: The interpolations by their names (the command line's `--interpolation`).
INTERPOLATIONS: dict[str, type[AbstractInterpolation]] = {
    c.name: c for c in (ZeroOrderHold, Linear, BandLimited)}


def interpolation(name: str | AbstractInterpolation) -> AbstractInterpolation:
    """The interpolation named `name` (`"zoh"`, `"linear"`, `"fft"`), or `name` itself."""
    if isinstance(name, AbstractInterpolation):
        return name
    if name not in INTERPOLATIONS:
        raise InputError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got "
                         f"{name!r}")
    return INTERPOLATIONS[name]()
