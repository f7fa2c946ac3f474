"""Identification of a damper model on every test condition at once: `mrjax.fit`.

```python
import jax, mrjax
batch = mrjax.data.paper_grid()
res = mrjax.fit("kwok", batch, key=jax.random.key(0))
print(res.table())
res.params_of(0)          # {'c': ..., 'k': ..., ...}
```

`fit` maps its options onto the settings objects (`mrjax.Swarm`, `mrjax.Polish`), splits the
condition axis into chunks sized by a memory budget (`chunk_plan`, `plan_chunks`; a `Journal`
lets an interrupted fit resume), builds each chunk's per-test problem (:class:`TestsProblem`)
and runs the engine (`mrjax.engine.solve`) on it; it returns a :class:`FitResult`, and
:func:`save` / `FitResult.to_json` are the one writer of `fit.json`. :func:`fit_swarm` runs the
swarm stage alone. With two or more tests every test is then polished once more from the best
of its neighbours' optima (:func:`retry_starts`), the better kept and both reported
(`FitResult.starts_rms`, a warning where they disagree). The package is named `fitting` so that
the function `mrjax.fit` does not hide a module.
"""

from ._chunks import chunk_plan as chunk_plan
from ._fit import fit as fit
from ._journal import Journal as Journal
from ._plan import DEFAULT_MEMORY_FRACTION as DEFAULT_MEMORY_FRACTION
from ._plan import RUNTIME_BYTES as RUNTIME_BYTES
from ._plan import ChunkPlan as ChunkPlan
from ._plan import available_memory as available_memory
from ._plan import condition_bytes as condition_bytes
from ._plan import default_budget as default_budget
from ._plan import parse_memory as parse_memory
from ._plan import plan_chunks as plan_chunks
from ._posterior import TestPosterior as TestPosterior
from ._posterior import posterior_plan as posterior_plan
from ._problem import AUTO_SWARMS as AUTO_SWARMS
from ._problem import ModelSwarm as ModelSwarm
from ._problem import TestsProblem as TestsProblem
from ._problem import default_restarts as default_restarts
from ._problem import fit_swarm as fit_swarm
from ._problem import tests_problem as tests_problem
from ._result import SPREAD_MARGIN as SPREAD_MARGIN
from ._result import FitResult as FitResult
from ._result import save as save
from ._result import spread_warnings as spread_warnings
from ._retry import RETRY_DONORS as RETRY_DONORS
from ._retry import neighbours as neighbours
from ._retry import retry_starts as retry_starts
from ._run import polish_fit as polish_fit

__all__ = ["ChunkPlan", "FitResult", "Journal", "ModelSwarm", "TestPosterior", "TestsProblem",
           "chunk_plan", "fit", "fit_swarm", "parse_memory", "plan_chunks", "polish_fit", "save",
           "tests_problem"]
