"""The identification engine: one pipeline for every problem kind, and its settings.

```python
import mrjax
res = mrjax.fit("kwok", data, swarm=mrjax.Swarm(restarts=2), polish=mrjax.Polish(tol=1e-7))
post = mrjax.posterior(res, data, sampler=mrjax.Sampler(draws=2000), noise="ar1")
```

:func:`solve` runs view -> swarm -> view polish -> full-record polish -> uncertainty on an
:class:`AbstractProblem`, and :func:`sample` its posterior: per-test parameters (`mrjax.fit`),
joint laws over the current (`mrjax.generalize.generalize(method="joint")`) and laws of a
time-varying command (`mrjax.generalize.identify`) are kinds of it. The settings are objects
(`equinox.Module`s): :class:`Swarm`, :class:`Polish`, :class:`Chunks` and
`mrjax.Sampler`; :func:`posterior` is `mrjax.posterior`.
"""


from ._posterior import DATA_CHOICES as DATA_CHOICES
from ._posterior import PosteriorPlan as PosteriorPlan
from ._posterior import posterior as posterior
from ._posterior import register_posterior as register_posterior
from ._posterior import sample as sample
from ._problem import AbstractProblem as AbstractProblem
from ._problem import Outcome as Outcome
from ._problem import StageOutcome as StageOutcome
from ._problem import StageSpec as StageSpec
from ._problem import Start as Start
from ._problem import SwarmOutcome as SwarmOutcome
from ._problem import SwarmSetup as SwarmSetup
from ._problem import refined as refined
from ._run import solve as solve
from ._settings import MODES as MODES
from ._settings import Chunks as Chunks
from ._settings import Polish as Polish
from ._settings import Swarm as Swarm
from ._settings import check_settings as check_settings
from ._swarm import best_restart as best_restart
from ._swarm import progress_callback as progress_callback
from ._swarm import row_keys as row_keys
from ._swarm import run_swarm as run_swarm
from ._swarm import swarm_result as swarm_result

__all__ = ["AbstractProblem", "Chunks", "Outcome", "Polish", "PosteriorPlan", "StageOutcome",
           "StageSpec", "Swarm", "SwarmOutcome", "SwarmSetup", "posterior", "register_posterior",
           "sample", "solve"]
