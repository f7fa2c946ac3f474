"""Damper models: pure, jittable, differentiable force functions in SI units.

Use `mrjax.models.get(name)`; see :class:`AbstractModel` for the contract. This package is also
the home of the one integrator (`integrate`), the one bounds check (`check_bounds`,
`box_corners`) and the one sub-step policy (`resolve_model`, `choose_substeps`).
"""

from ._base import AbstractModel as AbstractModel
from ._base import safe_abs_pow as safe_abs_pow
from ._bounds import box_corners as box_corners
from ._bounds import check_bounds as check_bounds
from ._bounds import check_box as check_box
from ._hysteretic import BoucWen as BoucWen
from ._hysteretic import Dahl as Dahl
from ._hysteretic import ModifiedBoucWen as ModifiedBoucWen
from ._integrate import SCHEMES as SCHEMES
from ._integrate import integrate as integrate
from ._integrate import integrate_step as integrate_step
from ._registry import get as get
from ._registry import names as names
from ._static import Bingham as Bingham
from ._static import Kwok as Kwok
from ._substeps import MAX_SUBSTEPS as MAX_SUBSTEPS
from ._substeps import STEP_TARGET as STEP_TARGET
from ._substeps import TRACED_SUBSTEPS as TRACED_SUBSTEPS
from ._substeps import choose_substeps as choose_substeps
from ._substeps import doubled_substeps as doubled_substeps
from ._substeps import resolve_model as resolve_model
