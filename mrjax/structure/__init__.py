"""A hysteretic element identified inside a structure from the structure's response (output
error): a mass on any mrjax model, driven by a measured force or a ground acceleration.

```python
import mrjax.structure as ms
st = ms.SDOF(period=8192)                          # a periodic input in steady state
records = ms.load_records("bench/", st)            # time_s, force_N, displacement_m
res = ms.fit("examples/my_models.py:BenchmarkBoucWen", records, structure=st)
print(res.table())                                 # m, the model's parameters, RMS [m]
pred = res.predict(ms.load_records("test.csv", st))
post = mrjax.posterior(res, records)               # NUTS on the response residuals
```

:func:`fit` runs the engine (`mrjax.engine.solve`) on a :class:`StructureProblem`: the swarm
on each record's equation error (:class:`EquationObjective`), the polish and the std-errors on
the simulated response (:func:`simulate`: classic Runge-Kutta steps in one `lax.scan` over the
model's own force and state rate; the input between samples from the structure's
interpolation, :class:`BandLimited` by default), and `mrjax.posterior` samples the same
residuals.
"""

from . import _fit  # noqa: F401  (registers the posterior of a StructureFit)
from ._equation import EquationObjective as EquationObjective
from ._figures import response_figure as response_figure
from ._files import load_records as load_records
from ._files import read_records as read_records
from ._fit import fit as fit
from ._input import INTERPOLATIONS as INTERPOLATIONS
from ._input import AbstractInterpolation as AbstractInterpolation
from ._input import BandLimited as BandLimited
from ._input import Linear as Linear
from ._input import ZeroOrderHold as ZeroOrderHold
from ._input import interpolation as interpolation
from ._problem import MASS_BOUNDS as MASS_BOUNDS
from ._problem import StructureProblem as StructureProblem
from ._problem import structure_problem as structure_problem
from ._records import Record as Record
from ._records import Records as Records
from ._records import equation_view as equation_view
from ._records import motion as motion
from ._records import stack as stack
from ._records import step_inputs as step_inputs
from ._result import Prediction as Prediction
from ._result import StructureFit as StructureFit
from ._system import SDOF as SDOF
from ._system import STRUCTURES as STRUCTURES
from ._system import AbstractStructure as AbstractStructure
from ._system import BaseExcited as BaseExcited
from ._system import ResponseResidual as ResponseResidual
from ._system import simulate as simulate

__all__ = ["SDOF", "AbstractInterpolation", "AbstractStructure", "BandLimited", "BaseExcited",
           "Linear", "Prediction", "Record", "StructureFit", "StructureProblem",
           "ZeroOrderHold", "fit", "load_records", "response_figure", "simulate"]
