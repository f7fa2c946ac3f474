"""Velocity from measured displacement: a zero-phase Savitzky-Golay differentiator.

Many damper tests record only time, displacement and force. The models need velocity, so
:func:`estimate_velocity` fits a local polynomial (degree `polyorder`, default cubic) to each
window of displacement samples centred on a sample, and takes the polynomial's slope there.

- **Zero phase.** The window is centred, so the estimate has no lag (unlike a causal moving
    average followed by a finite difference, which delays velocity by half the filter length).
    At the two ends of the record the first/last window's polynomial is used instead.
- **Default window: the least expected error** (:func:`velocity_window`). A short window
    passes the whole band of the motion but lets displacement noise through, amplified by
    the derivative; a long one averages the noise but flattens the fast motion. From the
    displacement spectrum (`mrjax.data._spectrum`: Hann periodogram, white-noise floor, signal
    band) the expected mean-square error of each candidate window is

    $$E(W) = \\frac{2}{N}\\sum_k (P_k - \\sigma^2)\\,|H_W(f_k) - 2\\pi i f_k|^2
            + \\sigma^2 \\sum_m h_{W,m}^2,$$

    the smoothing bias on the signal band plus the noise passed by the filter taps $h_W$
    (exact frequency response $H_W$ at every bin), and the window with the least $E$ is used.
    This reads the bandwidth of the signal, not one spectral peak: a broadband (e.g.
    earthquake-type) record gets a window short enough for its fastest motion, a noisy sine
    one long enough to average its noise. A window tied to one spectral peak (a fixed
    fraction of the dominant period) would smooth a broadband record flat.
- **Uniform sampling** (sample intervals equal within 0.1 %) uses `scipy.signal.savgol_filter`.
    **Non-uniform sampling** uses the same fit done directly on the actual sample times: for each
    sample, a least-squares polynomial through the window of neighbouring samples (same number of
    samples as the uniform window at the median interval). On a uniform grid both give the same
    result.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ._spectrum import bandwidth, is_broadband, peak_share, spectrum

#: Largest relative spread of the sample interval still treated as uniform sampling.
_UNIFORM_RTOL = 1e-3
#: Rows of the non-uniform local fit solved at once (bounds memory).
_CHUNK = 16384
#: Candidate windows tried by `velocity_window`: a coarse geometric grid from the smallest
#: window to the record, then a finer one between the neighbours of the best.
_COARSE, _FINE = 16, 12


def _odd_at_least(n: int, low: int) -> int:
    n = max(int(n), low)
    return n if n % 2 else n + 1


@dataclasses.dataclass(frozen=True)
class VelocityWindow:
    """The Savitzky-Golay window chosen for a displacement record, and why.

    **Fields:**

    - `window_s`: window length [s] (`samples` times the median sample interval).
    - `samples`: window length in samples (odd).
    - `bandwidth_Hz`: frequency below which 99 % of the displacement-derivative energy above
        the noise floor lies [Hz] (0 when no signal stands above the floor).
    - `peak_Hz`: the strongest frequency of the displacement [Hz].
    - `peak_share`: share of the velocity energy in the spectral peak at `peak_Hz` (1 for a
        sine).
    - `noise`: standard deviation of the white displacement noise, in the unit of `x`.
    - `expected_error`: expected RMS velocity error relative to the RMS velocity.
    - `broadband`: no single frequency describes the motion (random or earthquake-type
        records): `peak_share < 0.5` or `bandwidth_Hz > 4 * peak_Hz`. Check the estimate,
        or give the window.
    """

    window_s: float
    samples: int
    bandwidth_Hz: float
    peak_Hz: float
    peak_share: float
    noise: float
    expected_error: float
    broadband: bool


def _kernel_response(h: np.ndarray, n: int) -> np.ndarray:
    """$H(f_k) = \\sum_m h_m e^{2\\pi i f_k m\\,dt}$ at the rfft bins of length n (h centred)."""
    half = h.shape[0] // 2
    a = np.zeros(n)
    a[(-np.arange(-half, half + 1)) % n] = h
    return np.fft.rfft(a)


def _derivative_taps(window: int, polyorder: int, dt: float) -> np.ndarray:
    """Savitzky-Golay first-derivative taps of an odd `window` (those of
    `scipy.signal.savgol_coeffs(window, polyorder, deriv=1, delta=dt, use="dot")`), from the
    normal equations on the scaled abscissa [-1, 1]: O(window) instead of a least-squares solve
    of the window's Vandermonde matrix."""
    half = window // 2
    u = np.arange(-half, half + 1) / half
    vander = u[:, None] ** np.arange(polyorder + 1)
    e1 = np.zeros(polyorder + 1)
    e1[1] = 1.0
    return vander @ np.linalg.solve(vander.T @ vander, e1) / (half * dt)


def _choose_window(t: np.ndarray, x: np.ndarray, polyorder: int, smallest: int) -> VelocityWindow:
    sp = spectrum(t, x)
    n, dt = sp.n, sp.dt
    largest = min(t.shape[0], n)
    largest = largest if largest % 2 else largest - 1
    f_band = bandwidth(sp)
    f_peak, share = peak_share(sp)
    omega = 2.0 * np.pi * sp.f
    v_ms = 2.0 / sp.nfft * float(np.sum(sp.excess * omega**2))
    # The bias sum runs over the signal band (twice the bandwidth): above it the periodogram is
    # noise, whose excess over the floor averages zero and only adds scatter to E.
    band = (sp.f > 0) & (sp.f <= max(2.0 * f_band, 8.0 * (sp.f[1] if n > 2 else 0.0)))
    excess = sp.power[band] - sp.noise
    def error(w: int) -> float:
        h = _derivative_taps(w, polyorder, dt)
        resp = _kernel_response(h, sp.nfft)[band]
        e = 2.0 / sp.nfft * float(np.sum(excess * np.abs(resp - 1j * omega[band]) ** 2))
        return max(e, 0.0) + sp.noise * float(np.sum(h**2))

    def grid(lo: int, hi: int, count: int) -> list[int]:
        return sorted({min(max(int(round(v)) | 1, lo), hi) for v in np.geomspace(lo, hi, count)})

    tried = {w: error(w) for w in grid(smallest, largest, _COARSE)}
    coarse = sorted(tried)
    k = coarse.index(min(tried, key=tried.get))
    lo, hi = coarse[max(k - 1, 0)], coarse[min(k + 1, len(coarse) - 1)]
    for w in grid(lo, hi, _FINE):
        if w not in tried:
            tried[w] = error(w)
    w = min(tried, key=tried.get)
    best = (tried[w], w)
    e, w = best
    rel = float(np.sqrt(e / v_ms)) if v_ms > 0 else 0.0
    return VelocityWindow(w * dt, w, f_band, f_peak, share, float(np.sqrt(sp.noise)), rel,
                          is_broadband(sp))


def _check_record(t: np.ndarray, x: np.ndarray, polyorder: int) -> tuple[np.ndarray, np.ndarray,
                                                                          int, int]:
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.ndim != 1 or x.ndim != 1 or t.shape != x.shape:
        raise InputError(
            f"estimate_velocity: t and x must be 1-D of equal length, got {t.shape} and {x.shape}"
        )
    if isinstance(polyorder, bool) or int(polyorder) != polyorder or polyorder < 1:
        raise InputError(f"estimate_velocity: polyorder must be an integer >= 1, got {polyorder}")
    polyorder = int(polyorder)
    n = t.shape[0]
    smallest = _odd_at_least(polyorder + 2, 3)
    if n < smallest:
        raise InputError(
            f"estimate_velocity: record has {n} sample(s); at least {smallest} are needed to "
            f"estimate velocity with polyorder={polyorder}"
        )
    for name, a in (("t", t), ("x", x)):
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise InputError(
                f"estimate_velocity: {name} has a non-finite value ({a[bad[0]]}) at row {bad[0]}"
            )
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        raise InputError(
            f"estimate_velocity: time is not strictly increasing at row {int(bad[0]) + 1}"
        )
    return t, x, polyorder, smallest


def velocity_window(t: ArrayLike, x: ArrayLike, *, polyorder: int = 3) -> VelocityWindow:
    """The window `estimate_velocity` uses by default: the least expected error.

    **Arguments:**

    - `t`: time [s], strictly increasing, shape (T,).
    - `x`: displacement [m] (or any length unit), shape (T,).
    - `polyorder`: degree of the local polynomial (default 3).

    **Returns:** a :class:`VelocityWindow` with the window, the signal's bandwidth and
    dominant frequency, the noise level, the expected relative error and whether the record is
    broadband. See the module notes for the criterion.
    """
    t, x, polyorder, smallest = _check_record(t, x, polyorder)
    return _choose_window(t, x, polyorder, smallest)


def _local_polyfit_slope(t: np.ndarray, x: np.ndarray, window: int, polyorder: int) -> np.ndarray:
    """Savitzky-Golay slope on arbitrary sample times: least squares per centred window."""
    n = t.shape[0]
    half = window // 2
    start = np.clip(np.arange(n) - half, 0, n - window)
    powers = np.arange(polyorder + 1)
    out = np.empty(n)
    for lo in range(0, n, _CHUNK):
        rows = np.arange(lo, min(lo + _CHUNK, n))
        idx = start[rows, None] + np.arange(window)
        tau = t[idx] - t[rows, None]
        scale = np.max(np.abs(tau), axis=1, keepdims=True)
        vander = (tau / scale)[..., None] ** powers  # (R, W, P+1)
        coef = np.einsum("rpw,rw->rp", np.linalg.pinv(vander), x[idx])
        out[rows] = coef[:, 1] / scale[:, 0]
    return out


def estimate_velocity(
    t: ArrayLike,
    x: ArrayLike,
    *,
    window_s: float | None = None,
    polyorder: int = 3,
) -> np.ndarray:
    """Velocity $\\dot x$ from displacement by a zero-phase Savitzky-Golay derivative.

    **Arguments:**

    - `t`: time [s], strictly increasing, shape (T,). Need not be uniformly sampled.
    - `x`: displacement [m] (any length unit gives velocity in that unit per second), (T,).
    - `window_s`: length of the smoothing window [s]. Default: the window of least expected
        error for this record, `mrjax.data.velocity_window(t, x).window_s` (see the module
        notes). A given window is rounded to an odd number of samples at the median sample
        interval.
    - `polyorder`: degree of the local polynomial (default 3, cubic); at least 1.

    **Returns:** velocity [m/s], shape (T,), without lag (centred window).

    Raises :class:`mrjax.InputError` for mismatched or non-finite inputs, non-increasing time,
    a record shorter than `polyorder + 2` samples, or a `window_s` that spans fewer than
    `polyorder + 2` samples or more than the record.
    """
    t, x, polyorder, smallest = _check_record(t, x, polyorder)
    n = t.shape[0]
    steps = np.diff(t)
    dt = float(np.median(steps))
    if window_s is None:
        window = _choose_window(t, x, polyorder, smallest).samples
    else:
        if not (np.isfinite(window_s) and window_s > 0):
            raise InputError(f"estimate_velocity: window_s must be positive, got {window_s}")
        window = int(round(window_s / dt))
        window = window if window % 2 else window + 1
        if window < smallest:
            raise InputError(
                f"estimate_velocity: window_s={window_s:g} s spans {window} sample(s) at "
                f"dt={dt:g} s; polyorder={polyorder} needs at least {smallest}"
            )
        if window > n:
            raise InputError(
                f"estimate_velocity: window_s={window_s:g} s spans {window} samples but the "
                f"record has only {n}"
            )
    if np.max(np.abs(steps - dt)) <= _UNIFORM_RTOL * dt:
        from scipy.signal import savgol_filter  # imported here: scipy.signal is slow to import

        return savgol_filter(x, window, polyorder, deriv=1, delta=dt, mode="interp")
    return _local_polyfit_slope(t, x, window, polyorder)
