"""Model registry: `mrjax.models.get(name)`."""

from __future__ import annotations

from .._errors import InputError
from ._base import AbstractModel
from ._hysteretic import BoucWen, Dahl, ModifiedBoucWen
from ._static import Bingham, Kwok

_REGISTRY: dict[str, type[AbstractModel]] = {
    cls.name: cls for cls in (Bingham, Kwok, BoucWen, ModifiedBoucWen, Dahl)
}
_ALIASES = {"tanh": "kwok", "spencer": "modified_bouc_wen", "bw": "bouc_wen", "mbw": "modified_bouc_wen"}


def names() -> tuple[str, ...]:
    """Registered model names, in the order of the paper."""
    return tuple(_REGISTRY)


def get(name: str | AbstractModel, *, substeps: int | None = None) -> AbstractModel:
    """Return the model called `name` (`bingham`, `kwok`, `bouc_wen`, `modified_bouc_wen`,
    `dahl`; aliases `tanh`, `spencer`).

    **Arguments:** `name` a registered name or a model instance (returned as is, with
    `substeps` applied when given); `substeps` fixed RK4 sub-steps per sample for ODE models
    (`None`: automatic from a stiffness estimate).

    Raises :class:`mrjax.InputError` for an unknown name.
    """
    if isinstance(name, AbstractModel):
        return name if substeps is None else name.with_substeps(substeps)
    key = str(name).strip().lower().replace("-", "_")
    key = _ALIASES.get(key, key)
    if key not in _REGISTRY:
        raise InputError(f"unknown model {name!r}; choose one of {', '.join(_REGISTRY)}")
    return _REGISTRY[key](substeps=substeps)
