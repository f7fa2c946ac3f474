"""Reference laws and synthetic records with a time-varying command: Spencer et al.'s 1997
voltage-dependent modified Bouc-Wen model, band-limited random motion and a random held
command (the known answers of `identify`, the inverse and the benchmarks)."""

from __future__ import annotations

import math

import numpy as np

from .._errors import InputError
from ..data import Condition, sine_excitation
from ._laws import Law
from ._model import GeneralizedModel

#: Spencer et al. (1997), PAPER.md: the voltage-dependent modified Bouc-Wen set (SI units, z in
#: metres) and its command filter rate eta [1/s]; c0, c1, alpha = a + b v.
SPENCER_1997: dict[str, float] = dict(
    c0a=2100.0, c0b=350.0, c1a=28300.0, c1b=295.0, alphaa=14000.0, alphab=69500.0,
    k0=4690.0, k1=500.0, x0=0.143, gamma=3.63e6, beta=3.63e6, A=301.0, n=2.0, eta=190.0,
)


def spencer_1997(*, voltage_range: tuple[float, float] = (0.0, 2.25)) -> GeneralizedModel:
    """Spencer et al.'s (1997) modified Bouc-Wen model as laws of the command voltage [V] with
    its filter $\\dot u = -\\eta(u - v)$, $\\eta$ = 190 1/s (PAPER.md): c0, c1 and alpha linear
    in u, the rest constant; delta = A, f0 = -k1 x0; z in metres (alpha in N/m, beta and gamma
    in 1/m^2; :meth:`GeneralizedModel.with_canonical_z` gives the |z|max = 1 form)."""
    s = SPENCER_1997
    laws = {
        "c0": Law("poly", (s["c0a"], s["c0b"])), "k0": Law("poly", (s["k0"],)),
        "c1": Law("poly", (s["c1a"], s["c1b"])), "k1": Law("poly", (s["k1"],)),
        "alpha": Law("poly", (s["alphaa"], s["alphab"])), "delta": Law("poly", (s["A"],)),
        "beta": Law("poly", (s["beta"],)), "gamma": Law("poly", (s["gamma"],)),
        "n": Law("poly", (s["n"],)), "f0": Law("poly", (-s["k1"] * s["x0"],)),
    }
    return GeneralizedModel("modified_bouc_wen", laws, "given", float("nan"),
                            tuple(voltage_range), command_unit="V", lag=s["eta"])


def random_motion(duration: float, sample_rate: float, *, amplitude: float = 0.01,
                  band: tuple[float, float] = (0.1, 5.0), seed: int | np.random.Generator = 0
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Band-limited random displacement: white noise filtered to `band` [Hz] (FFT, zero
    phase), scaled to max |x| = `amplitude` [m]; the velocity is its exact spectral derivative.

    **Returns:** `(t [s], x [m], xdot [m/s])`, each (T,) with T = duration x sample_rate.
    """
    n = int(round(duration * sample_rate))
    if n < 16 or not 0 <= band[0] < band[1]:
        raise InputError(f"random_motion needs >= 16 samples and 0 <= band[0] < band[1], got "
                         f"{n} samples and band {band}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    X = np.fft.rfft(rng.normal(size=n))
    f = np.fft.rfftfreq(n, 1.0 / sample_rate)
    X[(f < band[0]) | (f > band[1])] = 0.0
    x = np.fft.irfft(X, n)
    v = np.fft.irfft(X * 2j * np.pi * f, n)
    s = amplitude / np.max(np.abs(x))
    return np.arange(n) / sample_rate, x * s, v * s


def random_command(t: np.ndarray, *, levels: tuple[float, float] = (0.0, 2.25),
                   hold: tuple[float, float] = (0.1, 0.5),
                   seed: int | np.random.Generator = 0) -> np.ndarray:
    """A random command held piecewise constant: levels uniform in `levels`, each held for a
    time uniform in `hold` [s]. Returns (T,) values on the times `t` [s]."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    t = np.asarray(t, float)
    out = np.empty_like(t)
    k, start = 0, t[0]
    while k < t.size:
        end = start + rng.uniform(*hold)
        j = int(np.searchsorted(t, end, side="left"))
        out[k:max(j, k + 1)] = rng.uniform(*levels)
        k, start = max(j, k + 1), end
    return out


def command_record(gm: GeneralizedModel, *, duration: float = 20.0,
                   sample_rate: float = 3000.0, amplitude: float = 0.01,
                   band: tuple[float, float] = (0.1, 5.0),
                   levels: tuple[float, float] | None = None,
                   hold: tuple[float, float] = (0.1, 0.5), noise: float = 0.02, seed: int = 0,
                   label: str | None = None) -> Condition:
    """A simulated random-motion, random-command record of the laws `gm` (the Spencer 1997
    known answer by default settings): :func:`random_motion` and :func:`random_command`
    (`levels` default `gm.command_range`), force through `gm` and its lag, plus Gaussian noise
    of `noise` x max|F| [N]. The record carries the command in `gm.command_unit`."""
    rng = np.random.default_rng(seed)
    t, x, v = random_motion(duration, sample_rate, amplitude=amplitude, band=band, seed=rng)
    cmd = random_command(t, levels=gm.command_range if levels is None else levels, hold=hold,
                         seed=rng)
    f = np.asarray(gm.force(x, v, 1.0 / sample_rate, cmd), float)
    f = f + rng.normal(0.0, noise * np.max(np.abs(f)), size=f.shape)
    return Condition(label or f"random_{seed}", None, None, None, t, x, v, f,
                     source="simulated", command=cmd, command_unit=gm.command_unit)


def sine_record(gm: GeneralizedModel, level: float, *, frequency: float = 2.0,
                amplitude: float = 0.01, sample_rate: float = 1000.0, cycles: float = 3.0,
                noise: float = 0.02, seed: int = 0, label: str | None = None) -> Condition:
    """A simulated sine test of the laws `gm` at the constant command `level` (in
    `gm.command_unit`, carried as a constant per-sample command), with Gaussian noise of
    `noise` x max|F| [N]."""
    if not math.isfinite(level):
        raise InputError(f"level must be finite, got {level!r}")
    t, x, v = sine_excitation(frequency, amplitude, sample_rate=sample_rate, cycles=cycles)
    cmd = np.full(t.shape, float(level))
    f = np.asarray(gm.force(x, v, 1.0 / sample_rate, cmd), float)
    rng = np.random.default_rng(seed)
    f = f + rng.normal(0.0, noise * np.max(np.abs(f)), size=f.shape)
    unit = gm.command_unit
    cur = float(level) if unit == "A" else None
    return Condition(label or f"sine_{level:g}{unit}", cur, frequency, amplitude, t, x, v, f,
                     source="simulated", command=cmd, command_unit=unit)
