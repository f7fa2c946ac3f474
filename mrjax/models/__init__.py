"""Damper models: pure, jittable, differentiable force functions in SI units.

Use `mrjax.models.get(name)`; see :class:`AbstractModel` for what every model provides. Declare
your own with :class:`Model` and :class:`Parameter` (the force, and the state's rate, for one
instant; mrjax derives the rest) and :func:`register` it, or name its file
(`get("path/to/file.py:Name")`). Hold parameters at values with :func:`fix`.

This package is also the home of the one integrator (:func:`integrate`), the one bounds check
(:func:`check_bounds`) and the one sub-step policy (:func:`resolve_model`), which the rest of
mrjax uses.
"""

from ._base import AbstractModel as AbstractModel
from ._base import safe_abs_pow as safe_abs_pow
from ._bounds import box_corners as box_corners
from ._bounds import check_bounds as check_bounds
from ._bounds import check_box as check_box
from ._declaration import Parameter as Parameter
from ._declaration import Params as Params
from ._declare import Model as Model
from ._fixed import fix as fix
from ._hysteretic import BoucWen as BoucWen
from ._hysteretic import Dahl as Dahl
from ._hysteretic import ModifiedBoucWen as ModifiedBoucWen
from ._integrate import ODE as ODE
from ._integrate import SCHEMES as SCHEMES
from ._integrate import integrate as integrate
from ._integrate import integrate_step as integrate_step
from ._literature import REFERENCE_PARAMS as REFERENCE_PARAMS
from ._registry import ENTRY_POINT_GROUP as ENTRY_POINT_GROUP
from ._registry import aliases as aliases
from ._registry import describe_source as describe_source
from ._registry import from_source as from_source
from ._registry import get as get
from ._registry import load as load
from ._registry import names as names
from ._registry import register as register
from ._registry import source_of as source_of
from ._registry import unregister as unregister
from ._static import Bingham as Bingham
from ._static import Kwok as Kwok
from ._substeps import box_points as box_points
from ._substeps import exact_tangent as exact_tangent
from ._substeps import resolve_model as resolve_model
from ._symmetry import ScaleSymmetry as ScaleSymmetry

__all__ = [
    # models and their registry
    "AbstractModel", "Bingham", "Kwok", "BoucWen", "ModifiedBoucWen", "Dahl",
    "get", "names", "aliases", "register", "unregister", "load", "ENTRY_POINT_GROUP",
    "source_of", "describe_source", "from_source",
    # your own model, fixed parameters, the scale symmetry
    "Model", "Parameter", "Params", "safe_abs_pow", "REFERENCE_PARAMS", "fix", "ScaleSymmetry",
    # the integrator, its sub-step policy and the bounds check (used across mrjax)
    "ODE", "integrate", "integrate_step", "SCHEMES", "resolve_model", "exact_tangent",
    "box_points", "box_corners", "check_bounds", "check_box",
]
