"""Identification of a damper model on every test condition at once: `mrjax.fit`.

```python
import jax, mrjax
batch = mrjax.data.paper_grid()
res = mrjax.fit("kwok", batch, key=jax.random.key(0))
print(res.table())
res.params_of(0)          # {'c': ..., 'k': ..., ...}
```

`fit` runs four stages (`prepare`, `run_swarm`, `run_polish`, `evaluate`) on chunks of the
condition axis sized by a memory budget (`fit_in_chunks`, `plan_chunks`; a `Journal` lets an
interrupted fit resume) and returns a :class:`FitResult`; :func:`save` and `FitResult.to_json`
are the one writer of `fit.json`.
The package is named `fitting` so that the function `mrjax.fit` does not hide a module.
"""

from ._chunks import DEFAULT_MEMORY_FRACTION as DEFAULT_MEMORY_FRACTION
from ._chunks import ChunkPlan as ChunkPlan
from ._chunks import Journal as Journal
from ._chunks import available_memory as available_memory
from ._chunks import chunk_plan as chunk_plan
from ._chunks import condition_bytes as condition_bytes
from ._chunks import condition_keys as condition_keys
from ._chunks import fit_in_chunks as fit_in_chunks
from ._chunks import parse_memory as parse_memory
from ._chunks import plan_chunks as plan_chunks
from ._chunks import resident_bytes as resident_bytes
from ._chunks import run_stages as run_stages
from ._result import FitResult as FitResult
from ._result import csv_cell as csv_cell
from ._result import save as save
from ._stages import PolishStage as PolishStage
from ._stages import Problem as Problem
from ._stages import SwarmStage as SwarmStage
from ._stages import as_batch as as_batch
from ._stages import evaluate as evaluate
from ._stages import fit as fit
from ._stages import prepare as prepare
from ._stages import run_polish as run_polish
from ._stages import run_swarm as run_swarm
from ._swarm import ModelSwarm as ModelSwarm
from ._swarm import fit_swarm as fit_swarm
from ._view import JOINT_SAMPLES_PER_PERIOD as JOINT_SAMPLES_PER_PERIOD
from ._view import View as View
from ._view import swarm_view as swarm_view
from ._view import view_plan as view_plan
