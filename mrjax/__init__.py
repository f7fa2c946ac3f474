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

from . import comparison as comparison
from . import data as data
from . import engine as engine
from . import fitting as fitting
from . import generalize as generalize
from . import models as models
from . import objective as objective
from . import pso as pso
from . import refine as refine
from ._errors import InputError as InputError
from .comparison import CompareResult as CompareResult
from .comparison import compare as compare
from .engine import Polish as Polish
from .engine import Swarm as Swarm
from .fitting import FitResult as FitResult
from .fitting import fit as fit
