"""The journal of a chunked fit: each finished chunk on disk, from which an interrupted fit
resumes (`mrjax.fit(..., journal=DIR, resume=True)`)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import numpy as np

from .. import __version__
from .._errors import InputError
from .._io import atomic_output, json_bytes
from ..models import AbstractModel
from ._plan import ChunkPlan
from ._problem import TestsProblem
from ._result import FitResult
from ._run import Run

#: Name of the journal format, in its manifest.
JOURNAL_FORMAT = "mrjax-journal/1"


def _canonical(v: Any) -> Any:
    """A JSON-able, exact description of an option value (arrays by their bytes' hash)."""
    if v is None or isinstance(v, (bool, int, float, str)):
        return repr(v)
    if isinstance(v, Mapping):
        return {str(k): _canonical(x) for k, x in sorted(v.items(), key=lambda kv: str(kv[0]))}
    if isinstance(v, (list, tuple)):
        return [_canonical(x) for x in v]
    if isinstance(v, jax.Array) and jax.dtypes.issubdtype(v.dtype, jax.dtypes.prng_key):
        v = jax.random.key_data(v)
    if isinstance(v, (np.ndarray, np.generic, jax.Array)):
        a = np.ascontiguousarray(np.asarray(v))
        return [a.dtype.str, list(a.shape), hashlib.sha256(a.tobytes()).hexdigest()]
    if isinstance(v, eqx.Module):
        leaves, treedef = jax.tree.flatten(v)
        return [str(treedef), [_canonical(x) for x in leaves]]
    return repr(v)


def _without_callback(swarm):
    """The swarm's settings less its host callback (which does not change the result)."""
    return swarm if swarm is None else dataclasses.replace(swarm, callback=None)


def fingerprint(problem: TestsProblem, run: Run, keys: jax.Array) -> str:
    """SHA-256 of everything a fit's result depends on: the data (every array of the batch and
    the fit mask, the labels), the model, the random streams (`keys`), the bounds, the method,
    the settings objects and the transient (not the progress bar, devices, callback or the
    memory and journal options, which leave the result unchanged), and the mrjax version."""
    h = hashlib.sha256()
    src = problem.source
    for f in dataclasses.fields(src):
        v = getattr(src, f.name)
        h.update(f.name.encode())
        h.update(json.dumps(_canonical(list(v) if f.name == "labels" else v)).encode())
    h.update(json.dumps(_canonical(problem.mask)).encode())
    doc = {"mrjax_version": __version__, "model": problem.model.name,
           "model_tree": _canonical(problem.model), "keys": _canonical(keys),
           "lower": _canonical(problem.lower), "upper": _canonical(problem.upper),
           "options": {k: _canonical(v) for k, v in (
               ("method", run.method), ("swarm", _without_callback(run.swarm)),
               ("polish", run.polish), ("uncertainty", run.uncertainty),
               ("seed", run.seed), ("transient", run.transient))}}
    h.update(json.dumps(doc, sort_keys=True).encode())
    return h.hexdigest()


class Journal:
    """Finished chunks of a fit on disk, from which an interrupted fit resumes.

    A directory holding `manifest.json` (`{"format": "mrjax-journal/1", "fingerprint": sha256
    of the data and options, "n_conditions": C, "chunk_size": B, "n_chunks": n,
    "mrjax_version": str}`) and one `chunk-NNNNN.json` per finished chunk (`{"chunk": j,
    "start": first condition, "stop": one past the last, "fingerprint": ..., "result":
    FitResult.to_state() of its conditions}`: floats by `repr`, exact), each written
    atomically (`mrjax._io.atomic_output`).
    """

    def __init__(self, path: str | os.PathLike, fp: str, plan: ChunkPlan):
        self.path, self.fingerprint, self.plan = Path(path), fp, plan

    @classmethod
    def open(cls, path: str | os.PathLike, fp: str, plan: ChunkPlan, *,
             resume: bool) -> Journal:
        """The journal at `path` for a fit with fingerprint `fp` planned as `plan`.

        With `resume`, an existing journal is reused (its chunk size replaces the plan's, so
        that its chunks line up) and must have been written for the same fingerprint;
        otherwise an existing journal is discarded. Raises :class:`mrjax.InputError` for a
        journal of other data or options, or a path that is no journal.
        """
        path = Path(path)
        manifest = path / "manifest.json"
        if path.exists():
            if not path.is_dir():
                raise InputError(f"journal {str(path)!r} exists and is not a directory")
            old = cls._read(manifest)
            if old is not None and old.get("format") != JOURNAL_FORMAT:
                old = None
            if old is None and any(path.iterdir()):
                raise InputError(f"journal {str(path)!r} exists and is not an mrjax journal "
                                 f"(no {JOURNAL_FORMAT} manifest.json); remove it or choose "
                                 f"another directory")
            if resume and old is not None:
                if old.get("fingerprint") != fp or old.get("n_conditions") != plan.n_conditions:
                    raise InputError(
                        f"cannot resume: the journal {str(path)!r} was written for other data "
                        f"or options (or another mrjax version); run without resume to start "
                        f"over")
                size = int(old["chunk_size"])
                return cls(path, fp, dataclasses.replace(plan, size=size))
            shutil.rmtree(path)
        doc = {"format": JOURNAL_FORMAT, "fingerprint": fp, "n_conditions": plan.n_conditions,
               "chunk_size": plan.size, "n_chunks": plan.n_chunks, "mrjax_version": __version__}
        atomic_output(path, {"manifest.json": json_bytes(doc)})
        return cls(path, fp, plan)

    @staticmethod
    def _read(path: Path) -> dict | None:
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        return doc if isinstance(doc, dict) else None

    def _name(self, j: int) -> str:
        return f"chunk-{j + 1:05d}.json"

    def finished(self, model: AbstractModel) -> dict[int, FitResult]:
        """The chunks already written, by index; a file that does not match the plan (or is
        unreadable) counts as not written."""
        out: dict[int, FitResult] = {}
        for j in range(self.plan.n_chunks):
            doc = self._read(self.path / self._name(j))
            start, stop = self.plan.bounds(j)
            if (doc is None or doc.get("fingerprint") != self.fingerprint
                    or doc.get("chunk") != j or doc.get("start") != start
                    or doc.get("stop") != stop):
                continue
            try:
                res = FitResult.from_state(doc["result"], model)
            except (InputError, KeyError, TypeError, ValueError):
                continue
            if res.n_conditions == stop - start:
                out[j] = res
        return out

    def record(self, j: int, result: FitResult) -> None:
        """Write chunk `j`'s results atomically."""
        start, stop = self.plan.bounds(j)
        doc = {"chunk": j, "start": start, "stop": stop, "fingerprint": self.fingerprint,
               "result": result.to_state()}
        atomic_output(self.path, {self._name(j): json_bytes(doc)})

    def remove(self) -> None:
        """Delete the journal (after the final outputs are written)."""
        shutil.rmtree(self.path, ignore_errors=True)
