"""Damper models: pure, jittable, differentiable force functions in SI units.

Use `mrjax.models.get(name)`; see :class:`AbstractModel` for the contract.
"""

from ._base import AbstractModel as AbstractModel
from ._base import safe_abs_pow as safe_abs_pow
from ._hysteretic import BoucWen as BoucWen
from ._hysteretic import Dahl as Dahl
from ._hysteretic import ModifiedBoucWen as ModifiedBoucWen
from ._integrate import choose_substeps as choose_substeps
from ._integrate import rk4_scan as rk4_scan
from ._registry import get as get
from ._registry import names as names
from ._static import Bingham as Bingham
from ._static import Kwok as Kwok
