"""mrjax: JAX-accelerated, differentiable identification of magnetorheological damper models.

Implements Kwok et al. (2006): the tanh hysteretic model, Bingham, Bouc-Wen, modified Bouc-Wen
(Spencer) and Dahl models; a batched particle swarm with the paper's statistical stop; a
Levenberg-Marquardt polish through optimistix; and current-dependent (generalized) models.

`import mrjax` is cheap: the sub-packages (and JAX) are imported on first use of a name
(`mrjax.fit`, `mrjax.data`, ...), so that `mrjax --help` starts at once.
"""

from __future__ import annotations

import importlib as _importlib
import os as _os
import sys as _sys
from typing import TYPE_CHECKING

from ._errors import InputError as InputError

__version__ = "0.1.0"


def _enable_x64() -> None:
    """Fitting needs float64 (the polish, the std-errors, long RMS sums); the swarm may still
    run in float32 where asked. Set `MRJAX_X64=0` to leave JAX's default alone. Before JAX is
    imported this only sets `JAX_ENABLE_X64=1` in the environment (JAX reads it on import);
    afterwards it updates JAX's configuration."""
    if _os.environ.get("MRJAX_X64", "1") == "0":
        return
    if "jax" in _sys.modules:
        _sys.modules["jax"].config.update("jax_enable_x64", True)
    else:
        _os.environ["JAX_ENABLE_X64"] = "1"


_enable_x64()

#: Public names imported on first use: name -> (module, attribute or None for the module).
_LAZY: dict[str, tuple[str, str | None]] = {
    "comparison": ("mrjax.comparison", None),
    "data": ("mrjax.data", None),
    "engine": ("mrjax.engine", None),
    "export": ("mrjax.export", None),
    "fitting": ("mrjax.fitting", None),
    "generalize": ("mrjax.generalize", None),
    "models": ("mrjax.models", None),
    "bayes": ("mrjax.bayes", None),
    "objective": ("mrjax.objective", None),
    "parallel": ("mrjax.parallel", None),
    "pso": ("mrjax.pso", None),
    "refine": ("mrjax.refine", None),
    "report": ("mrjax.report", None),
    "reproduce": ("mrjax.reproduce", None),
    "CompareResult": ("mrjax.comparison", "CompareResult"),
    "compare": ("mrjax.comparison", "compare"),
    "posterior": ("mrjax.engine", "posterior"),
    "Sampler": ("mrjax.bayes", "Sampler"),
    "Chunks": ("mrjax.engine", "Chunks"),
    "Status": ("mrjax.refine", "Status"),
    "ResultWarning": ("mrjax._warnings", "ResultWarning"),
    "WarningKind": ("mrjax._warnings", "WarningKind"),
    "FitResult": ("mrjax.fitting", "FitResult"),
    "fit": ("mrjax.fitting", "fit"),
    "Polish": ("mrjax.engine", "Polish"),
    "Swarm": ("mrjax.engine", "Swarm"),
}

if TYPE_CHECKING:  # what the lazy names are, for type checkers and readers
    from . import bayes as bayes
    from . import comparison as comparison
    from . import data as data
    from . import engine as engine
    from . import export as export
    from . import fitting as fitting
    from . import generalize as generalize
    from . import models as models
    from . import objective as objective
    from . import parallel as parallel
    from . import pso as pso
    from . import refine as refine
    from . import report as report
    from . import reproduce as reproduce
    from ._warnings import ResultWarning as ResultWarning
    from ._warnings import WarningKind as WarningKind
    from .bayes import Sampler as Sampler
    from .comparison import CompareResult as CompareResult
    from .comparison import compare as compare
    from .engine import Chunks as Chunks
    from .engine import Polish as Polish
    from .engine import Swarm as Swarm
    from .engine import posterior as posterior
    from .fitting import FitResult as FitResult
    from .fitting import fit as fit
    from .refine import Status as Status


def __getattr__(name: str):
    """Import a public sub-package or name on first use (PEP 562)."""
    try:
        module, attr = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'mrjax' has no attribute {name!r}") from None
    value = _importlib.import_module(module)
    if attr is not None:
        value = getattr(value, attr)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = ["Chunks", "CompareResult", "FitResult", "InputError", "Polish", "ResultWarning",
           "Sampler", "Status", "Swarm", "WarningKind", "compare", "fit", "posterior"]
