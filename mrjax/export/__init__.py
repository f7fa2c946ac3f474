"""Export an identified model and its inverse for a controller: C99 source and an FMI 2.0 FMU.

```python
from mrjax.export import C99, FMU, ControllerModel, write

cm = ControllerModel.from_fit("out/fit.json")   # the laws over the command, sub-steps fixed
write(cm, "controller", C99())                   # mrjax_model.h, mrjax_model.c
write(cm, "controller", FMU())                   # mrjax_<model>.fmu (co-simulation, compiled)
```

The C is translated from the model's own JAX functions (their jaxpr, over the primitives of
:data:`PRIMITIVES`), so every built-in and every declared model exports without hand-written C.
"""

from ._build import CFLAGS as CFLAGS
from ._build import CLibrary as CLibrary
from ._build import compile_shared as compile_shared
from ._csource import C99 as C99
from ._emit import PRELUDE as PRELUDE
from ._emit import PRIMITIVES as PRIMITIVES
from ._emit import UnsupportedPrimitive as UnsupportedPrimitive
from ._emit import translate as translate
from ._fmu import FMU as FMU
from ._model import DEFAULT_DT as DEFAULT_DT
from ._model import ControllerModel as ControllerModel
from ._write import Target as Target
from ._write import write as write

__all__ = ["C99", "CFLAGS", "CLibrary", "ControllerModel", "DEFAULT_DT", "FMU", "PRELUDE",
           "PRIMITIVES", "Target", "UnsupportedPrimitive", "compile_shared", "translate", "write"]
