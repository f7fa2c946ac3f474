"""The settings of an identification, as objects (the optimistix way): :class:`Swarm` and
:class:`Polish`, and the one place where the keyword options of `mrjax.fit`,
`mrjax.generalize.generalize` and `mrjax.generalize.identify` become them."""

from __future__ import annotations

import math
from typing import Any, Literal

import equinox as eqx

from .._errors import InputError
from ..pso import PSOParams
from ..refine import DEFAULT_TOL

SwarmMode = Literal["separable", "full"]
Method = Literal["pso", "pso+lm", "lm"]
METHODS: tuple[str, ...] = ("pso", "pso+lm", "lm")
MODES: tuple[str, ...] = ("separable", "full")


class Swarm(eqx.Module):
    """The batched particle swarm's settings (`mrjax.pso`).

    **Fields:**

    - `n_particles`: particles per swarm (default 50, the paper's).
    - `max_generations`: the cap on generations with the statistical stop (default 200).
    - `generations`: run exactly this many generations, no statistical stop (benchmarks), or
        None.
    - `restarts`: independent swarms per unit (condition, or the whole data of a joint fit),
        one compiled program; the best is polished. None (default): the problem's choice
        (per test: `mrjax.fitting.default_restarts`, one swarm per test on a batch of tests
        whose optima seed each other's retry, two for a dynamic model on one test; 1 for joint
        laws).
    - `mode`: `"separable"` (variable projection over the parameters the force is linear in;
        default) or `"full"` (the paper's swarm over every parameter). Joint laws always
        solve their linear laws by least squares.
    - `params`: :class:`mrjax.pso.PSOParams` hyperparameters, or None for the problem's
        default (`mrjax.pso.default_params(mode)` per test; window 25 and, for a dynamic
        model's command laws, at least 100 generations).
    - `view`: score the swarm (and a first polish) on each record's view
        (`mrjax.data.swarm_view`), then polish on the full records; None: for the ODE models.
    - `dtype`: float dtype of the search (e.g. `"float32"`), or None for the default float.

    ```python
    mrjax.fit("modified_bouc_wen", data, swarm=mrjax.Swarm(restarts=2))
    ```
    """

    n_particles: int = eqx.field(static=True, default=50)
    max_generations: int = eqx.field(static=True, default=200)
    generations: int | None = eqx.field(static=True, default=None)
    restarts: int | None = eqx.field(static=True, default=None)
    mode: str = eqx.field(static=True, default="separable")
    params: PSOParams | None = None
    view: bool | None = eqx.field(static=True, default=None)
    dtype: Any = eqx.field(static=True, default=None)

    def __check_init__(self):
        for name in ("n_particles", "max_generations", "restarts"):
            v = getattr(self, name)
            if v is None and name == "restarts":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or int(v) != v or v < 1:
                raise InputError(f"{name} must be an integer >= 1, got {v!r}")
        g = self.generations
        if g is not None and (isinstance(g, bool) or int(g) != g or g < 1):
            raise InputError(f"generations must be at least 1, got {g!r}")
        if self.mode not in MODES:
            raise InputError(f"swarm mode must be 'separable' or 'full', got {self.mode!r}")
        if self.params is not None and not isinstance(self.params, PSOParams):
            raise InputError(f"params must be a mrjax.pso.PSOParams, got "
                             f"{type(self.params).__name__}")

    @property
    def n_restarts(self) -> int:
        """`restarts`, 1 where it is None (the problem kinds resolve None before a swarm)."""
        return 1 if self.restarts is None else int(self.restarts)

    @property
    def generation_cap(self) -> int:
        """The generations the history holds: `generations` if set, else `max_generations`."""
        return int(self.generations if self.generations is not None else self.max_generations)


class Polish(eqx.Module):
    """The Levenberg-Marquardt polish's settings (`mrjax.refine`).

    **Fields:**

    - `max_steps`: steps per polish stage (default 200).
    - `tol`: the stop: 8 steps lowering the RMS by less than this fraction (see
        `mrjax.refine.lm_solve`; default 1e-6). A first polish on the swarm's views stops at a
        multiple of it and the full records are refined (see `mrjax.engine.solve`).
    - `uncertainty`: std-errors, intervals and identifiability at the result (default True).
    - `retry`: per-test fits only: after the polish, polish every test once more from the best
        of its neighbours' optima (`mrjax.fitting.retry_starts`: the optima of the tests
        nearest in current, frequency and amplitude, their linear parameters solved on the
        test, ranked on its view) and keep the better; the two results are the evidence of a
        possible local optimum (`FitResult.starts_rms`, a warning where they disagree by more
        than `mrjax.fitting.SPREAD_MARGIN`). Default True; needs at least two tests.
    """

    max_steps: int = eqx.field(static=True, default=200)
    tol: float = eqx.field(static=True, default=DEFAULT_TOL)
    uncertainty: bool = eqx.field(static=True, default=True)
    retry: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        if not isinstance(self.retry, bool):
            raise InputError(f"polish retry must be True or False, got {self.retry!r}")
        v = self.max_steps
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise InputError(f"polish max_steps must be an integer >= 1, got {v!r}")
        if not (isinstance(self.tol, (int, float)) and math.isfinite(self.tol) and self.tol > 0):
            raise InputError(f"polish tol must be a positive number, got {self.tol!r}")


def _replace(obj: eqx.Module, **changes: Any) -> eqx.Module:
    """`obj` with the fields in `changes` that are not None replaced (checks rerun)."""
    changes = {k: v for k, v in changes.items() if v is not None}
    if not changes:
        return obj
    fields = {k: getattr(obj, k) for k in obj.__dataclass_fields__}
    fields.update(changes)
    return type(obj)(**fields)


def settings(
    *,
    method: str | None = "pso+lm",
    swarm: Swarm | None = None,
    polish: Polish | bool | None = None,
    swarm_default: Swarm | None = None,
    polish_default: Polish | None = None,
    **keywords: Any,
) -> tuple[Swarm | None, Polish | None, bool]:
    """The one mapping of keyword options onto settings objects.

    **Arguments:** `method` `"pso+lm"` (swarm then polish), `"pso"` (no polish; std-errors
    still where `uncertainty`), `"lm"` (polish alone from the problem's neutral start);
    `swarm`, `polish` settings objects (`polish=False`: no polish, `True`: the default); the
    defaults of the caller; keywords: `n_particles`, `max_generations`, `generations`,
    `restarts`, `swarm_mode`, `pso_params`, `swarm_view`, `swarm_dtype` (onto :class:`Swarm`),
    `polish_steps`, `polish_tol`/`tol`, `uncertainty`, `retry` (onto :class:`Polish`); None
    leaves the object's value.

    **Returns:** `(swarm or None, polish or None, uncertainty)`: None where the stage does not
    run. Raises :class:`mrjax.InputError` for an unknown method or a bad value.
    """
    if method not in METHODS:
        raise InputError(f"method must be 'pso', 'pso+lm' or 'lm', got {method!r}")
    unknown = set(keywords) - _KEYWORDS
    if unknown:
        raise InputError(f"unknown option(s): {sorted(unknown)}")
    k = keywords
    sw = swarm if swarm is not None else (swarm_default or Swarm())
    if not isinstance(sw, Swarm):
        raise InputError(f"swarm must be a mrjax.Swarm, got {type(sw).__name__}")
    sw = _replace(sw, n_particles=k.get("n_particles"), max_generations=k.get("max_generations"),
                  generations=k.get("generations"), restarts=k.get("restarts"),
                  mode=k.get("swarm_mode"), params=k.get("pso_params"), view=k.get("swarm_view"),
                  dtype=k.get("swarm_dtype"))
    run_polish = polish is not False and method != "pso"
    po = polish if isinstance(polish, Polish) else (polish_default or Polish())
    tol = k.get("polish_tol", k.get("tol"))
    po = _replace(po, max_steps=k.get("polish_steps"), tol=tol, uncertainty=k.get("uncertainty"),
                  retry=k.get("retry"))
    return (None if method == "lm" else sw), (po if run_polish else None), po.uncertainty


_KEYWORDS = frozenset({"n_particles", "max_generations", "generations", "restarts", "swarm_mode",
                       "pso_params", "swarm_view", "swarm_dtype", "polish_steps", "polish_tol",
                       "tol", "uncertainty", "retry"})
