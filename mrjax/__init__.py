"""mrjax: JAX-accelerated, differentiable identification of magnetorheological damper models.

Implements Kwok et al. (2006): the tanh hysteretic model, Bingham, Bouc-Wen, modified Bouc-Wen
(Spencer) and Dahl models; a batched particle swarm with the paper's statistical stop; a
Levenberg-Marquardt polish through optimistix; and current-dependent (generalized) models.
"""

__version__ = "0.1.0"

# Fitting needs float64 (the polish, the std-errors, long RMS sums); the swarm may still run in
# float32 where asked. Set MRJAX_X64=0 to leave JAX's default alone.
import os as _os

import jax as _jax

if _os.environ.get("MRJAX_X64", "1") != "0":
    _jax.config.update("jax_enable_x64", True)

import sys as _sys

from . import bayes as bayes
from . import comparison as comparison
from . import data as data
from . import fitting as fitting
from . import generalize as generalize
from . import models as models
from . import objective as objective
from . import pso as pso
from . import refine as refine
from ._errors import InputError as InputError
from .bayes import posterior as posterior
from .comparison import CompareResult as CompareResult
from .comparison import compare as compare
from .fitting import FitResult as FitResult
from .fitting import fit as fit

# `mrjax.fit` (the module) became `mrjax.fitting`, so that the function `mrjax.fit` no longer
# hides it; `from mrjax.fit import ...` keeps working for one release.
_sys.modules.setdefault(__name__ + ".fit", fitting)
