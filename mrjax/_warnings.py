"""What makes a result doubtful, as typed records: :class:`ResultWarning` (a `RuntimeWarning`
that carries its :class:`WarningKind` and the conditions and parameters it concerns), returned
by the results' `warnings()` / `problems()` and issued with `warnings.warn`, so that callers
(the command line among them) act on the kind, never on the text."""

from __future__ import annotations

import enum
from collections.abc import Iterable
from typing import Any


class WarningKind(enum.StrEnum):
    """The kinds of :class:`ResultWarning` (their values are fit.json's `"kind"`)."""

    #: A parameter at a bound of the search box: the optimum may lie outside it.
    AT_BOUND = "at_bound"
    #: A parameter the data do not determine (a null direction of J^T J, or a near-perfect
    #: correlation with another).
    NOT_IDENTIFIABLE = "not_identifiable"
    #: Two polished starts of a test ended apart: one of them is a local optimum.
    LOCAL_OPTIMUM = "local_optimum"
    #: Laws whose degree needs more distinct currents than the tests have.
    TOO_FEW_CURRENTS = "too_few_currents"
    #: The model's force is not finite at the fitted parameters.
    DIVERGED = "diverged"
    #: A record shorter than one period of its excitation.
    SHORT_RECORD = "short_record"
    #: Posterior chains that missed R-hat or ESS after every continuation.
    NOT_CONVERGED = "not_converged"
    #: Divergent transitions left in the posterior's draws.
    DIVERGENCES = "divergences"
    #: Unknowns held at their fitted value in the posterior (an undetermined direction).
    HELD = "held"
    #: Draws of an unknown integrated out of the log-density beyond its bounds.
    BEYOND_BOUNDS = "beyond_bounds"
    #: A posterior that starts from a doubtful place (no polish, parameters at bounds).
    DOUBTFUL_START = "doubtful_start"
    #: A record's data look doubtful (a check of the loader; also in its `warnings`).
    RECORD_CHECK = "record_check"
    #: A record's metadata given twice and one of them ignored.
    IGNORED_METADATA = "ignored_metadata"
    #: A data spec's `files` entry (its `parameters[0]`) matches none of the files loaded.
    SPEC_UNMATCHED = "spec_unmatched"


class ResultWarning(RuntimeWarning):
    """A typed warning about a result: `kind` (:class:`WarningKind`), `message` (one line for
    a person), `conditions` (the test labels concerned) and `parameters` (the names
    concerned). Returned in lists by the results (`FitResult.warnings`,
    `Posterior.problems`) and issued with `warnings.warn(w)`, where `w.message` is the
    record itself."""

    def __init__(self, kind: WarningKind | str, message: str, *,
                 conditions: Iterable[str] = (), parameters: Iterable[str] = ()):
        super().__init__(message)
        self.kind = WarningKind(kind)
        self.message = str(message)
        self.conditions = tuple(str(c) for c in conditions)
        self.parameters = tuple(str(p) for p in parameters)

    def __str__(self) -> str:
        return self.message

    def __repr__(self) -> str:
        return f"ResultWarning({self.kind.value!r}, {self.message!r})"

    def __eq__(self, other: Any) -> bool:
        return isinstance(other, ResultWarning) and self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash((self.kind, self.message, self.conditions, self.parameters))

    def to_dict(self) -> dict[str, Any]:
        """`{"kind", "message", "conditions": [...], "parameters": [...]}` (fit.json)."""
        return {"kind": self.kind.value, "message": self.message,
                "conditions": list(self.conditions), "parameters": list(self.parameters)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ResultWarning:
        """The record of :meth:`to_dict`."""
        return cls(d["kind"], d["message"], conditions=d.get("conditions", ()),
                   parameters=d.get("parameters", ()))
