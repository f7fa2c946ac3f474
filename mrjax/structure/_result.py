"""What a structure's identification found: :class:`StructureFit` (the unknowns per record,
their std-errors and intervals, the response error; prediction of other inputs; fit.json), and
:class:`Prediction`."""

from __future__ import annotations

import dataclasses
import json
from typing import Any

import jax.numpy as jnp
import numpy as np

from .. import __version__
from .._errors import InputError
from .._io import json_safe
from .._tables import format_table
from ..engine import Outcome
from ..models import AbstractModel, from_source, source_of
from ._input import interpolation
from ._problem import doubled_substeps
from ._records import VIEW_SAMPLES, Record, Records, stack, step_inputs
from ._system import STRUCTURES, AbstractStructure, simulate_batch

#: fit.json's `kind` of a structure's fit, and its format.
KIND, FORMAT = "structure", 1


@dataclasses.dataclass(frozen=True, eq=False)
class Prediction:
    """The simulated response of records: `labels` (U,), `predicted` and `measured` (U, T)
    (zero after each record's end; `measured` zero where a record has none), `mask` (U, T),
    `t` (U, T) [s], `n` (U,) samples, `rms` (U,) and `nrmse` (U,) (RMS error / RMS of the
    measured response; NaN without a measured response), `fitted` (U,) the label of the fitted
    record whose unknowns each record used, `substeps` the integration's steps per sample."""

    labels: tuple[str, ...]
    n: np.ndarray
    t: np.ndarray
    predicted: np.ndarray
    measured: np.ndarray
    mask: np.ndarray
    rms: np.ndarray
    nrmse: np.ndarray
    fitted: tuple[str, ...]
    substeps: int


@dataclasses.dataclass(frozen=True, eq=False)
class StructureFit:
    """A structure identified on its records (`mrjax.structure.fit`).

    **Fields:** `model`; `structure`; `labels` (U,) the records; `names` (K,) the unknowns (`m`
    [kg], then the model's parameters) and their `units`; `z` (U, K) their values [SI];
    `stderr` (U, K) and `ci95` (U, K, 2) the linearised std-errors and 95 % intervals (None
    without uncertainty), `identifiable` (U, K); `rms` (U,) the response's RMS error [m or
    m/s²] and `nrmse` (U,) relative to the response's RMS; `sigma` (U,) the residuals' std;
    `lower`, `upper` (K,) the box; `substeps` the simulation's steps per sample; `status` the
    polish's outcome per record; `swarm_rms` (U,) the swarm's equation error [N] (None without
    a swarm); `timings` [s]; `outcome` the engine's :class:`mrjax.engine.Outcome` (None when
    read from fit.json).
    """

    model: AbstractModel
    structure: AbstractStructure
    labels: tuple[str, ...]
    names: tuple[str, ...]
    units: tuple[str, ...]
    z: np.ndarray
    stderr: np.ndarray | None
    ci95: np.ndarray | None
    identifiable: np.ndarray | None
    rms: np.ndarray
    nrmse: np.ndarray
    sigma: np.ndarray | None
    lower: np.ndarray
    upper: np.ndarray
    substeps: int
    status: tuple[str, ...]
    swarm_rms: np.ndarray | None = None
    timings: dict[str, float] = dataclasses.field(default_factory=dict)
    outcome: Outcome | None = None

    @property
    def n_records(self) -> int:
        return len(self.labels)

    def params_of(self, i: int | str = 0) -> dict[str, float]:
        """The unknowns of record `i` (index or label) by name [SI]."""
        row = self._row(i)
        return {n: float(v) for n, v in zip(self.names, self.z[row])}

    def _row(self, i: int | str) -> int:
        if isinstance(i, str):
            if i not in self.labels:
                raise InputError(f"no fitted record {i!r}; fitted: {', '.join(self.labels)}")
            return self.labels.index(i)
        return int(i)

    def rows_for(self, labels) -> list[int]:
        """The fitted record whose unknowns predict each record: the one of the same label,
        else the only one."""
        rows = []
        for lab in labels:
            if lab in self.labels:
                rows.append(self.labels.index(lab))
            elif self.n_records == 1:
                rows.append(0)
            else:
                raise InputError(f"record {lab!r}: the fit holds {self.n_records} records "
                                 f"({', '.join(self.labels)}); name the record to predict with "
                                 f"one of their labels, or fit one record")
        return rows

    def predict(self, records: Record | list[Record] | Records, *,
                structure: AbstractStructure | None = None) -> Prediction:
        """The simulated response of `records` (their inputs) with the fitted unknowns (see
        :meth:`rows_for`), integrated with sub-steps found by step doubling at them.

        **Arguments:** `records`; `structure` how they are driven and observed, where it is
        not as fitted (e.g. `dataclasses.replace(fit.structure, period=None)`: a record that
        starts from rest, such as a sine sweep, after a fit in periodic steady state).

        **Returns:** a :class:`Prediction` (RMS error and NRMSE where a record has a
        measured response)."""
        st = self.structure if structure is None else structure
        recs = records if isinstance(records, Records) else stack(
            [records] if isinstance(records, Record) else list(records))
        P = st.period
        for lab, n in zip(recs.labels, recs.n):
            if P is not None and (n < P or n % P):
                raise InputError(f"record {lab!r}: {int(n)} samples are not whole periods of "
                                 f"{P} samples (the fit's period)")
        z = self.z[self.rows_for(recs.labels)]
        view = recs.first(P or VIEW_SAMPLES)
        m = doubled_substeps(self.model, st, z, lambda k: step_inputs(view, st, k),
                             np.arange(view.t.shape[1])[None, :] < view.n[:, None])
        pred = np.asarray(simulate_batch(self.model, st, jnp.asarray(z),
                                         step_inputs(recs, st, m)))
        mk = recs.mask
        n = np.maximum(mk.sum(axis=1), 1)
        with np.errstate(invalid="ignore", over="ignore"):
            rms = np.sqrt(np.sum(np.where(mk, pred - recs.response, 0.0) ** 2, axis=1) / n)
            scale = np.sqrt(np.sum(np.where(mk, recs.response, 0.0) ** 2, axis=1) / n)
        has = mk.any(axis=1)
        real = np.arange(recs.input.shape[1])[None, :] < recs.n[:, None]
        return Prediction(recs.labels, recs.n, recs.t, np.where(real, pred, 0.0), recs.response, mk,
                          np.where(has, rms, np.nan), np.where(has, rms / scale, np.nan),
                          tuple(self.labels[r] for r in self.rows_for(recs.labels)), m)

    # ------------------------------------------------------------------ reports
    def table(self) -> str:
        """The unknowns per record, value ± std-error, and the response's RMS error."""
        rows = []
        for i, lab in enumerate(self.labels):
            cells = [lab]
            for j in range(len(self.names)):
                fixed = self.lower[j] == self.upper[j]
                se = None if self.stderr is None else self.stderr[i, j]
                cells.append(f"{self.z[i, j]:.6g} (fixed)" if fixed else
                             f"{self.z[i, j]:.6g}" + ("" if se is None else f" ±{se:.2g}"))
            cells += [self.rms[i], 100 * self.nrmse[i]]
            rows.append(cells)
        unit = self.structure.response_unit
        head = ["record", *(f"{n}[{u}]" for n, u in zip(self.names, self.units)),
                f"RMS[{unit}]", "NRMSE%"]
        return format_table(rows, head, floatfmt=[""] * (1 + len(self.names)) + [".3g", ".3g"])

    def to_dict(self) -> dict[str, Any]:
        """fit.json's content (see :meth:`from_dict`)."""
        st = self.structure
        per = []
        for i, lab in enumerate(self.labels):
            entry = {"label": lab, "rms": self.rms[i], "nrmse": self.nrmse[i],
                     "status": self.status[i], "params": dict(zip(self.names, self.z[i]))}
            if self.stderr is not None:
                entry["stderr"] = dict(zip(self.names, self.stderr[i]))
                entry["ci95"] = {n: list(self.ci95[i, j]) for j, n in enumerate(self.names)}
                entry["identifiable"] = dict(zip(self.names, map(bool, self.identifiable[i])))
            if self.sigma is not None:
                entry["sigma"] = self.sigma[i]
            if self.swarm_rms is not None:
                entry["swarm_equation_rms_N"] = self.swarm_rms[i]
            per.append(entry)
        return json_safe({
            "kind": KIND, "format": FORMAT, "mrjax_version": __version__,
            "model": self.model.name, "model_source": source_of(self.model),
            "structure": {"name": st.name, "input": st.input_name, "response": st.response,
                          "response_unit": st.response_unit,
                          "interpolation": st.interpolation.name, "period": st.period},
            "names": list(self.names), "units": list(self.units),
            "bounds": {"lower": dict(zip(self.names, self.lower)),
                       "upper": dict(zip(self.names, self.upper))},
            "integration": {"scheme": "rk4", "substeps": self.substeps},
            "timings_s": self.timings, "records": per})

    def to_json(self, *, posterior: Any = None) -> str:
        """fit.json as text (with the posterior's summary where given)."""
        doc = self.to_dict()
        if posterior is not None:
            doc["posterior"] = json_safe(posterior.to_dict())
        return json.dumps(doc, indent=2)

    @classmethod
    def from_dict(cls, doc: dict, model: AbstractModel | str | None = None) -> StructureFit:
        """A fit read back from fit.json's content (`model`: where the model is, if fit.json's
        record of its source no longer finds it)."""
        if doc.get("kind") != KIND:
            raise InputError("not a structure's fit.json (no 'kind': 'structure')")
        try:
            st = doc["structure"]
            structure = STRUCTURES[st["name"]](
                response=st["response"], interpolation=interpolation(st["interpolation"]),
                period=st["period"])
            if model is None:
                model = from_source(doc["model"], doc.get("model_source"))
            elif isinstance(model, str):
                from ..models import get

                model = get(model)
            names = tuple(doc["names"])
            recs = doc["records"]
            z = np.array([[r["params"][n] for n in names] for r in recs], float)
            has_se = all("stderr" in r for r in recs)

            def per(key):
                return np.array([[_num(r[key][n]) for n in names] for r in recs], float)

            return cls(
                model=model, structure=structure, labels=tuple(r["label"] for r in recs),
                names=names, units=tuple(doc["units"]), z=z,
                stderr=per("stderr") if has_se else None,
                ci95=np.array([[[_num(v) for v in r["ci95"][n]] for n in names]
                               for r in recs]) if has_se else None,
                identifiable=np.array([[r["identifiable"][n] for n in names] for r in recs])
                if has_se else None,
                rms=np.array([_num(r["rms"]) for r in recs]),
                nrmse=np.array([_num(r["nrmse"]) for r in recs]),
                sigma=np.array([_num(r.get("sigma")) for r in recs]),
                lower=np.array([doc["bounds"]["lower"][n] for n in names], float),
                upper=np.array([doc["bounds"]["upper"][n] for n in names], float),
                substeps=int(doc["integration"]["substeps"]),
                status=tuple(r["status"] for r in recs), timings=dict(doc.get("timings_s", {})))
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"cannot read the structure's fit ({e!r})") from None

    def __repr__(self) -> str:
        return (f"StructureFit(model={self.model.name!r}, structure={self.structure.name!r}, "
                f"records={self.n_records}, rms={np.array2string(self.rms, precision=3)} "
                f"{self.structure.response_unit})")


def _num(v) -> float:
    return float("nan") if v is None else float(v)
