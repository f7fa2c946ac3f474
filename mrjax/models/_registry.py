"""Model registry: `mrjax.models.get(name)`."""

from __future__ import annotations

import difflib

from .._errors import InputError
from ._base import AbstractModel
from ._hysteretic import BoucWen, Dahl, ModifiedBoucWen
from ._static import Bingham, Kwok

_REGISTRY: dict[str, type[AbstractModel]] = {
    cls.name: cls for cls in (Bingham, Kwok, BoucWen, ModifiedBoucWen, Dahl)
}
_ALIASES = {"tanh": "kwok", "spencer": "modified_bouc_wen", "bw": "bouc_wen",
            "mbw": "modified_bouc_wen"}


def names() -> tuple[str, ...]:
    """Registered model names, in the order of the paper."""
    return tuple(_REGISTRY)


def aliases() -> dict[str, str]:
    """Other names accepted by :func:`get`: alias -> registered name (`tanh` -> `kwok`, ...)."""
    return dict(_ALIASES)


def get(name: str | AbstractModel, *, substeps: int | None = None) -> AbstractModel:
    """Return the model called `name` (`bingham`, `kwok`, `bouc_wen`, `modified_bouc_wen`,
    `dahl`; aliases `tanh`, `spencer`, `bw`, `mbw`: :func:`aliases`).

    **Arguments:** `name` a registered name or a model instance (returned as is, with
    `substeps` applied when given); `substeps` fixed RK4 sub-steps per sample for ODE models
    (`None`: automatic from a stiffness estimate).

    Raises :class:`mrjax.InputError` for an unknown name (naming the closest one).
    """
    if isinstance(name, AbstractModel):
        return name if substeps is None else name.with_substeps(substeps)
    key = str(name).strip().lower().replace("-", "_")
    key = _ALIASES.get(key, key)
    if key not in _REGISTRY:
        close = difflib.get_close_matches(key, [*_REGISTRY, *_ALIASES], n=1, cutoff=0.6)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise InputError(f"unknown model {name!r}; {hint}choose one of {', '.join(_REGISTRY)} "
                         f"(aliases: {', '.join(_ALIASES)})")
    return _REGISTRY[key](substeps=substeps)
