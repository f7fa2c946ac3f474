"""The displacement spectrum: noise floor, signal band, dominant frequency and amplitude.

One periodogram serves the velocity window (`mrjax.data.velocity_window`), the estimates of a
test's frequency and amplitude (`mrjax.data.estimate_motion`) and the broadband check.

- The record is put on a uniform grid at its median sample interval (linear interpolation; a
    uniformly sampled record is unchanged), its linear trend removed, and a Hann window applied.
    The periodogram is normalized so that white noise of variance $\\sigma^2$ has the flat level
    $\\sigma^2$, and $\\overline{x^2} \\approx (2/N)\\sum_{k \\ge 1} P_k$.
- **Noise floor.** The median of the periodogram over the upper half of the band (above a
    quarter of the sample rate) divided by $\\ln 2$ (the median of an exponential
    distribution): measured damper records carry their signal far below that.
- **Signal band.** Bins whose periodogram, averaged over a few neighbours, stands above the
    floor by more than chance would allow anywhere in the spectrum (a Bonferroni bound on the
    chi-square spread of the average).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError

#: Share of the displacement-derivative energy that defines the bandwidth.
BANDWIDTH_SHARE = 0.99
#: A record is broadband when the dominant peak holds less than this share of the velocity
#: energy, or when its bandwidth exceeds this multiple of the peak frequency.
_BROADBAND_PEAK_SHARE = 0.5
_BROADBAND_RATIO = 4.0


@dataclasses.dataclass(frozen=True)
class _Spectrum:
    dt: float
    n: int  # samples on the uniform grid
    nfft: int  # transform length (n zero-padded to a fast length)
    f: np.ndarray  # (K,) bin frequencies [Hz]
    power: np.ndarray  # (K,) normalized Hann periodogram (white noise -> variance)
    noise: float  # noise floor: variance of white displacement noise per sample
    signal: np.ndarray  # (K,) bool: bins significantly above the floor (DC excluded)
    excess: np.ndarray  # (K,) power above the floor on signal bins, else 0


def _uniform(t: np.ndarray, x: np.ndarray) -> tuple[float, np.ndarray]:
    dt = float(np.median(np.diff(t)))
    n = max(int(round((t[-1] - t[0]) / dt)) + 1, 2)
    if np.max(np.abs(np.diff(t) - dt)) <= 1e-3 * dt and n == t.shape[0]:
        return dt, np.asarray(x, dtype=float)
    return dt, np.interp(t[0] + dt * np.arange(n), t, x)


def _detrend(x: np.ndarray) -> np.ndarray:
    s = np.arange(x.shape[0], dtype=float)
    return x - np.polyval(np.polyfit(s, x, 1), s)


def _threshold(k: int, bins: int) -> float:
    """Level (in units of the floor) that a k-bin average of pure noise exceeds anywhere among
    `bins` bins with probability below 1 % (Wilson-Hilferty chi-square quantile)."""
    dof = max(2.0 * k * 2.0 / 3.0, 2.0)  # Hann: neighbouring bins are correlated
    p = 0.01 / max(bins, 1)
    z = math.sqrt(2.0 * math.log(1.0 / p))  # upper normal quantile, Mills-ratio bound
    a = 2.0 / (9.0 * dof)
    return (1.0 - a + z * math.sqrt(a)) ** 3


def spectrum(t: np.ndarray, x: np.ndarray) -> _Spectrum:
    """The normalized Hann periodogram of `x(t)` with its noise floor and signal band (the
    record zero-padded to a fast transform length, which leaves the normalization unchanged)."""
    dt, xu = _uniform(np.asarray(t, float), np.asarray(x, float))
    from scipy.fft import next_fast_len

    n = xu.shape[0]
    nfft = next_fast_len(n, real=True)
    w = np.hanning(n) if n > 2 else np.ones(n)
    power = np.abs(np.fft.rfft(_detrend(xu) * w, nfft)) ** 2 / np.sum(w**2)
    f = np.fft.rfftfreq(nfft, dt)
    upper = f > 0.25 / dt
    noise = float(np.median(power[upper]) / math.log(2.0)) if np.count_nonzero(upper) >= 8 else 0.0
    k = max(3, 2 * int(power.shape[0] / 800) + 1)
    smooth = np.convolve(power, np.ones(k) / k, mode="same")
    signal = smooth > noise * _threshold(k, power.shape[0])
    signal[0] = False
    # the average only decides which bins carry signal; the energy stays where it was measured
    excess = np.where(signal, np.maximum(power - noise, 0.0), 0.0)
    return _Spectrum(dt, n, nfft, f, power, noise, signal, excess)


def bandwidth(sp: _Spectrum, share: float = BANDWIDTH_SHARE) -> float:
    """Frequency [Hz] below which `share` of the signal's derivative energy lies (0 if none)."""
    e = sp.excess * sp.f**2
    total = float(np.sum(e))
    if not total > 0:
        return 0.0
    k = int(np.searchsorted(np.cumsum(e), share * total))
    return float(sp.f[min(k, sp.f.shape[0] - 1)])


def peak_share(sp: _Spectrum) -> tuple[float, float]:
    """`(f_peak [Hz], share)`: the strongest bin of the displacement and the share of the
    velocity energy within the main lobe of the Hann window around it (+-2 bins, at least
    +-2 % of the frequency)."""
    if sp.power.shape[0] < 2:
        return 0.0, 1.0
    kp = int(np.argmax(sp.power[1:])) + 1
    e = sp.excess * sp.f**2
    total = float(np.sum(e))
    if not total > 0:
        return float(sp.f[kp]), 1.0
    df = sp.f[1] - sp.f[0]
    near = np.abs(sp.f - sp.f[kp]) <= max(2 * df, 0.02 * sp.f[kp])
    return float(sp.f[kp]), float(np.sum(e[near]) / total)


def is_broadband(sp: _Spectrum) -> bool:
    """Whether no single frequency describes the motion: the dominant peak holds less than half
    the velocity energy, or 99 % of it reaches beyond 4 times the peak frequency (a long
    dominant period with fast motion on top, as in earthquake records)."""
    f_peak, share = peak_share(sp)
    return share < _BROADBAND_PEAK_SHARE or bandwidth(sp) > _BROADBAND_RATIO * f_peak


def _sine_residual(t: np.ndarray, x: np.ndarray, f: float) -> float:
    w = 2.0 * np.pi * f
    a = np.column_stack([np.ones_like(t), t - t[0], np.cos(w * t), np.sin(w * t)])
    coef, *_ = np.linalg.lstsq(a, x, rcond=None)
    return float(np.sum((x - a @ coef) ** 2))


def estimate_motion(t: ArrayLike, x: ArrayLike) -> tuple[float, float]:
    """Estimates of a test's frequency and amplitude from its displacement record.

    - **Frequency**: the peak of the displacement spectrum (mean removed, zero-padded 8x),
        refined by a least-squares fit of one sinusoid (plus offset and drift) at frequencies
        within one spectral bin of it. On a sine test this is the excitation frequency to a
        few parts in $10^5$; on a random record it is the dominant frequency.
    - **Amplitude**: half the spread between the 0.5th and 99.5th percentiles of the
        displacement, a half peak-to-peak that ignores isolated spikes. For a sine
        $A\\sin(2\\pi f t)$ it is $A$ to 0.02 %.

    **Arguments:** `t` time [s], strictly increasing, (T,); `x` displacement [m], (T,).

    **Returns:** `(frequency [Hz], amplitude [m])`.

    Raises :class:`mrjax.InputError` for mismatched shapes or fewer than 4 samples.
    """
    from scipy.optimize import minimize_scalar

    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.ndim != 1 or t.shape != x.shape or t.shape[0] < 4:
        raise InputError(
            f"estimate_motion: t and x must be 1-D of equal length >= 4, got {t.shape}, {x.shape}"
        )
    lo, hi = np.percentile(x, [0.5, 99.5])
    amplitude = 0.5 * float(hi - lo)
    dt, xu = _uniform(t, x)
    n = xu.shape[0]
    spec = np.abs(np.fft.rfft(xu - np.mean(xu), 8 * n))
    f = np.fft.rfftfreq(8 * n, dt)
    if spec.shape[0] < 2 or not np.any(spec[1:] > 0):
        return 0.0, amplitude
    fc = float(f[int(np.argmax(spec[1:])) + 1])
    bin_ = 1.0 / (n * dt)
    lo_f, hi_f = max(fc - bin_, 0.25 * fc), fc + bin_
    res = minimize_scalar(lambda v: _sine_residual(t, x, v), bounds=(lo_f, hi_f),
                          method="bounded", options={"xatol": 1e-7 * fc})
    frequency = float(res.x) if res.success else fc
    return frequency, amplitude
