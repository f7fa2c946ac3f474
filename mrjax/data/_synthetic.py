"""Synthetic test data: sinusoidal tests simulated from any model, and the paper's grid.

`paper_grid()` is mrjax's embedded default data set: Table 1 of Kwok et al. (2006), six currents
times six (frequency, amplitude) pairs, simulated with the tanh model whose parameters follow
the paper's generalized laws (eq 24-29), plus Gaussian force noise.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError
from ._condition import Batch, Condition, make_batch

#: Currents of Table 1 [A].
PAPER_CURRENTS: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0, 2.0)
#: (frequency [Hz], amplitude [m]) pairs of Table 1.
PAPER_MOTIONS: tuple[tuple[float, float], ...] = (
    (1.0, 0.004), (1.0, 0.008), (1.0, 0.012), (2.0, 0.004), (2.0, 0.006), (2.0, 0.008),
)
#: Eq 24-29: polynomial coefficients in current i [A], ascending powers, SI units.
PAPER_COEFFICIENTS: dict[str, tuple[float, ...]] = {
    "c": (1232.0, 1929.0),  # N*s/m
    "k": (5100.0, -1700.0),  # N/m
    "alpha": (32.0, 918.0, -244.0),  # N
    "beta": (100.0,),  # s/m
    "delta": (0.58, 0.30),  # -
    "f0": (-257.0, -18.0),  # N
}
_KWOK_ORDER = ("c", "k", "alpha", "beta", "delta", "f0")


def paper_parameters(current: float | ArrayLike) -> np.ndarray:
    """Tanh-model parameters `(c, k, alpha, beta, delta, f0)` from eq 24-29 at `current` [A].

    Returns shape (6,) for a scalar current, or (..., 6) for an array of currents.
    """
    i = np.asarray(current, dtype=float)
    cols = [np.polynomial.polynomial.polyval(i, PAPER_COEFFICIENTS[n]) for n in _KWOK_ORDER]
    return np.stack(np.broadcast_arrays(*cols), axis=-1)


def sine_excitation(
    frequency: float, amplitude: float, *, sample_rate: float = 1000.0, cycles: float = 2.0,
    phase: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time [s], displacement [m] and analytic velocity [m/s] of
    $x = A\\sin(2\\pi f t + \\varphi)$, `phase` $\\varphi$ in rad (default 0).

    `cycles` periods are sampled at `sample_rate` [Hz], endpoint excluded.
    """
    if not (frequency > 0 and amplitude > 0 and sample_rate > 0 and cycles > 0):
        raise InputError(
            f"sine_excitation needs positive frequency, amplitude, sample_rate and cycles; got "
            f"{frequency}, {amplitude}, {sample_rate}, {cycles}"
        )
    n = int(round(cycles * sample_rate / frequency))
    if n < 3:
        raise InputError(f"sample_rate={sample_rate} Hz gives only {n} samples for {cycles} cycles")
    t = np.arange(n) / sample_rate
    w = 2.0 * np.pi * frequency
    return t, amplitude * np.sin(w * t + phase), amplitude * w * np.cos(w * t + phase)


def simulate(
    model,
    theta: ArrayLike,
    *,
    frequency: float,
    amplitude: float,
    current: float | None = None,
    sample_rate: float = 1000.0,
    cycles: float = 2.0,
    noise: float = 0.0,
    seed: int | np.random.Generator = 0,
    label: str | None = None,
) -> Condition:
    """Simulate one sinusoidal test of `model` with parameters `theta`.

    **Arguments:**

    - `model`: a model name or object (see `mrjax.models.get`).
    - `theta`: parameters (P,) in SI units.
    - `frequency` [Hz], `amplitude` [m], `current` [A] (metadata only).
    - `sample_rate` [Hz], `cycles` number of periods.
    - `noise`: standard deviation of Gaussian force noise [N].
    - `seed`: NumPy seed or generator for the noise.

    **Returns:** a :class:`Condition` whose force is the simulated force plus noise.
    """
    from ..models import get

    model = get(model)
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (model.n_params,):
        raise InputError(
            f"model {model.name!r} takes {model.n_params} parameters {list(model.param_names)}, "
            f"got shape {theta.shape}"
        )
    t, x, v = sine_excitation(frequency, amplitude, sample_rate=sample_rate, cycles=cycles)
    f = np.asarray(model.force(theta, x, v, 1.0 / sample_rate), dtype=float)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    if noise:
        f = f + rng.normal(0.0, float(noise), size=f.shape)
    if label is None:
        cur = "" if current is None else f"_{current:g}A"
        label = f"{frequency:g}Hz_{amplitude * 1e3:g}mm{cur}"
    return Condition(label, current, frequency, amplitude, t, x, v, f, source="simulated")


def paper_grid(
    model="kwok",
    params: ArrayLike | Callable[[float], ArrayLike] | None = None,
    *,
    currents: Sequence[float] = PAPER_CURRENTS,
    motions: Sequence[tuple[float, float]] = PAPER_MOTIONS,
    sample_rate: float = 1000.0,
    cycles: float = 2.0,
    noise: float = 20.0,
    seed: int = 0,
) -> Batch:
    """The paper's Table 1 test grid, simulated: the embedded default data of mrjax.

    **Arguments:**

    - `model`: model name or object used to simulate (default the tanh model `"kwok"`).
    - `params`: the truth: a function of current [A] returning (P,), a fixed (P,) vector, or
        (C, P) rows in grid order. Default: eq 24-29 for the tanh model (required otherwise).
    - `currents` [A] and `motions` [(Hz, m)]: the grid, current-major (default Table 1:
        6 x 6 = 36 conditions).
    - `sample_rate` [Hz] and `cycles`: sampling (default 1 kHz, 2 cycles: 2000 samples at 1 Hz).
    - `noise`: Gaussian force noise standard deviation [N] (default 20 N).
    - `seed`: seed of the noise; the same seed gives the same data.

    **Returns:** a :class:`Batch` of `len(currents) * len(motions)` conditions.
    """
    from ..models import get

    model = get(model)
    grid = [(float(i), float(f), float(a)) for i in currents for (f, a) in motions]
    if not grid:
        raise InputError("paper_grid needs at least one current and one motion")
    if params is None:
        if model.name != "kwok":
            raise InputError(f"paper_grid(model={model.name!r}) needs params (eq 24-29 are tanh)")
        params = paper_parameters
    if callable(params):
        rows = np.stack([np.asarray(params(i), float) for i, _, _ in grid])
    else:
        p = np.asarray(params, float)
        rows = np.broadcast_to(p, (len(grid), model.n_params)) if p.ndim == 1 else p
    if rows.shape != (len(grid), model.n_params):
        raise InputError(f"params must give {model.n_params} values per condition, got {rows.shape}")
    rng = np.random.default_rng(seed)
    conds = [
        simulate(model, rows[j], frequency=f, amplitude=a, current=i, sample_rate=sample_rate,
                 cycles=cycles, noise=noise, seed=rng)
        for j, (i, f, a) in enumerate(grid)
    ]
    return make_batch(conds)


def paper_truth(batch: Batch) -> np.ndarray:
    """Eq 24-29 tanh parameters for every condition of `batch` (from its currents), (C, 6)."""
    cur = np.asarray(batch.current)
    if np.any(~np.isfinite(cur)):
        raise InputError("paper_truth needs the current of every condition")
    return paper_parameters(cur)
