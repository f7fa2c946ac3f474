"""The names only mrjax's own models may take (a leaf module: the declaration checks them, the
registry maps them to models)."""

from __future__ import annotations

#: mrjax's hand-written models, in the order `mrjax.models.names` lists them.
BUILTIN_NAMES: tuple[str, ...] = ("bingham", "kwok", "bouc_wen", "modified_bouc_wen", "dahl")
#: mrjax's literature models, declared through the public contract.
LITERATURE_NAMES: tuple[str, ...] = ("lugre", "herschel_bulkley", "polynomial")
#: Other names of the built-in models: alias -> name.
ALIASES: dict[str, str] = {"tanh": "kwok", "spencer": "modified_bouc_wen", "bw": "bouc_wen",
                           "mbw": "modified_bouc_wen"}


def reserved_names() -> frozenset[str]:
    """Names only mrjax's own models may take: the built-ins, their aliases and the
    literature models."""
    return frozenset(BUILTIN_NAMES) | frozenset(ALIASES) | frozenset(LITERATURE_NAMES)
