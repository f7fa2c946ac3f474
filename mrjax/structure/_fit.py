"""`mrjax.structure.fit`: identify a structure through the engine, and its posterior's plan."""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._errors import InputError
from ..bayes import Posterior, at_bounds
from ..engine import Polish, PosteriorPlan, Swarm, register_posterior, row_keys, solve
from ..models import AbstractModel, get
from ._files import load_records
from ._problem import structure_problem
from ._records import Record, Records, stack
from ._result import StructureFit
from ._system import SDOF, AbstractStructure


def as_records(data: Any, structure: AbstractStructure) -> Records:
    """`data` as :class:`Records`: a :class:`Record`, a list of them, `Records`, or files and
    directories (`mrjax.structure.load_records`)."""
    if isinstance(data, Records):
        return data
    if isinstance(data, Record):
        return stack([data])
    if isinstance(data, (str, os.PathLike)):
        return stack(load_records([data], structure))
    items = list(data)
    if items and all(isinstance(r, Record) for r in items):
        return stack(items)
    if items and all(isinstance(r, (str, os.PathLike)) for r in items):
        return stack(load_records(items, structure))
    raise InputError(f"data must be structure records (mrjax.structure.Record) or files, got "
                     f"{type(data).__name__}")


def fit(
    model: str | AbstractModel,
    data: Record | Sequence[Record] | Records | str | os.PathLike,
    *,
    structure: AbstractStructure | None = None,
    swarm: Swarm | None = Swarm(),
    polish: Polish | None = Polish(),
    bounds: tuple[Any, Any] | None = None,
    key: Any = 0,
    progress: bool | None = False,
) -> StructureFit:
    """Identify a mass on `model` from each record's response to its input (output error).

    The engine (`mrjax.engine.solve`) runs on a :class:`mrjax.structure.StructureProblem`: the
    swarm on each record's equation error (the model's nonlinear parameters searched, its
    linear ones and the mass solved by least squares), the start ranked on the simulated
    response, Levenberg-Marquardt on the response of the full records (forward-mode Jacobian
    through the simulation), the linearised std-errors.

    **Arguments:**

    - `model`: the element, any mrjax model (name, object or `"file.py:Name"`); fix its
        parameters with `mrjax.models.fix`.
    - `data`: the records (:class:`Record` or a list; files, see
        :func:`mrjax.structure.load_records`), each its own unit.
    - `structure`: :class:`SDOF` (default) or :class:`BaseExcited`, with what is measured, the
        input's interpolation and the period of a periodic input.
    - `swarm`, `polish`: the stages' settings (None: skipped; `Swarm(restarts=None)` is one
        swarm per record).
    - `bounds`: `(lower, upper)` dicts by name (`"m"` [kg] and the model's parameters) or
        (1 + P,) arrays; default the mass in `MASS_BOUNDS`, the model's default box. Equal
        bounds hold an unknown (a base-excited structure needs the mass held).
    - `key`: the swarm's seed or PRNG key.
    - `progress`: a progress bar of the swarm (None: on a terminal).

    **Returns:** a :class:`StructureFit`.

    Raises :class:`mrjax.InputError` for records without a response, too short for the
    unknowns, not whole periods of a periodic input, bad bounds or settings.
    """
    model = get(model)
    structure = SDOF() if structure is None else structure
    if not isinstance(structure, AbstractStructure):
        raise InputError(f"structure must be mrjax.structure.SDOF or BaseExcited, got "
                         f"{type(structure).__name__}")
    for name, v, kind in (("swarm", swarm, Swarm), ("polish", polish, Polish)):
        if v is not None and not isinstance(v, kind):
            raise InputError(f"{name} must be a mrjax.{kind.__name__} or None")
    records = as_records(data, structure)
    problem = structure_problem(model, structure, records, bounds)
    rows = swarm.n_restarts * problem.n_units if swarm is not None else 1
    out = solve(problem, swarm=swarm, polish=polish, key=row_keys(key, rows), progress=progress,
                uncertainty=polish is None or polish.uncertainty)
    unc = out.uncertainty
    z = problem.from_engine(out.z)
    scale = np.sqrt(np.sum(records.response ** 2 * records.mask, axis=1)
                    / np.maximum(records.mask.sum(axis=1), 1))
    return StructureFit(
        model=model, structure=structure, labels=records.labels, names=problem.names,
        units=problem.units, z=z,
        stderr=None if unc is None else np.asarray(unc.stderr),
        ci95=None if unc is None else np.asarray(unc.ci95),
        identifiable=None if unc is None else np.asarray(unc.identifiable),
        rms=out.rms, nrmse=out.rms / scale,
        sigma=None if unc is None else np.asarray(unc.sigma),
        lower=problem.lower, upper=problem.upper, substeps=problem.substeps(z),
        status=tuple(str(s) for s in out.status),
        swarm_rms=None if out.swarm is None else out.swarm.rms, timings=out.timings,
        outcome=out)


def posterior_plan(result: StructureFit, data: Any, likelihood_data: str | None
                   ) -> PosteriorPlan:
    """The posterior of a structure's fit on its records: its problem rebuilt (the fit's model,
    structure and box), its optimum; the likelihood on each record's view (its first period)
    by default, the record with `likelihood_data="record"`."""
    records = as_records(data, result.structure)
    if tuple(records.labels) != tuple(result.labels):
        raise InputError(f"data are not the fit's records: {records.labels} for "
                         f"{result.labels}")
    problem = structure_problem(result.model, result.structure, records,
                                (result.lower, result.upper))
    hit = at_bounds(result.z, result.lower, result.upper)
    if hit.any():
        j = int(np.argwhere(hit)[0][1])
        warnings.warn(f"{result.names[j]} is at a bound of the fit: its posterior is cut by it",
                      RuntimeWarning, stacklevel=4)

    def finish(post: Posterior) -> Posterior:
        for w in post.problems():
            warnings.warn(w, stacklevel=4)
        return post

    return PosteriorPlan(problem, problem.to_engine(result.z), likelihood_data != "record",
                         finish)


register_posterior(StructureFit, posterior_plan, batch=False)
