"""`mrjax reproduce`: the study of Kwok et al. (2006) in one command.

```
mrjax reproduce                      # the paper's study on the embedded Table 1 grid
mrjax reproduce --quick              # a reduced version (12 conditions), for tests
mrjax reproduce --data DIR           # the same study on a directory of measured tests
```

```python
import mrjax.reproduce
mrjax.reproduce.run("mrjax-out/reproduce", quick=True, seed=0)   # writes the files, returns 0
```

**Data.** By default the embedded grid `mrjax.data.paper_grid()`: Table 1's 36 tests
(6 currents x 6 motions, 1 kHz, 2 cycles) simulated with the tanh model whose parameters follow
eq 24-29, plus 20 N Gaussian noise (noise seed 0: the data never change; `seed` only seeds the
swarms). The truth is known, so the generalized coefficients are compared with eq 24-29. With
`data=DIR` the tests are loaded from DIR and every truth comparison is skipped; each record is
cut to its last `DATA_CYCLES` cycles (when its frequency is known) so that the study runs in
minutes (`mrjax fit` uses whole records). `quick=True` keeps two motions (1 Hz / 8 mm and
2 Hz / 4 mm, those of Figs 7-8) at every current and caps the swarms at `QUICK_GENERATIONS`.

**Stages.**

1. *The paper's study* (Figs 7-10): the tanh and the Bouc-Wen model identified on every test by
   the paper's particle swarm with its statistical stop (`mrjax.fit(...,
   swarm=mrjax.Swarm(mode="full"), polish=None)`: 50 particles, inertia 0.65,
   c1,max = c2,max = 2, confidence 0.905), same seed for both. Its RMS and generations are the
   paper's Figs 9 and 10.
2. *Accurate identification* (mrjax's method): the tanh model by the separable swarm (variable
   projection) and the Levenberg-Marquardt polish (`mrjax.fit` defaults), with std-errors. The
   paper's swarm result is also polished, for the "swarm alone vs swarm + polish" figure.
   The Bouc-Wen model is identified by the separable swarm alone (its polish, through the ODE,
   costs more than the whole study; not run by `quick`). The two separable swarms, same seed,
   no polish, give the like-for-like model comparison of acceptance (a).
3. *Generalization* over current (Figs 11-12): the tanh parameters of stage 2 by
   `mrjax.generalize.generalize` in two steps (group by current, average, fit eq 24-29's
   polynomials), with mrjax's default covariance weighting and with the paper's plain means.
   On measured data (not in quick mode) the laws are also fitted jointly on all tests
   (`method="joint"`), and Figs 11-12 and `fit.json` show those: averages of nonlinear
   parameters can make poor laws on real tests. On the embedded data the two-step laws are
   already at the noise level, and the joint fit is left out to keep within the time budget.

The Bouc-Wen stages run in a second thread while the tanh stages and their figures run in the
main one (XLA compiles and runs without the Python lock, so the two cores are both used); the
results do not depend on it. Bouc-Wen swarms integrate with one RK4 step per millisecond of
record (`BW_SWARM_STEP_S`; mrjax's automatic choice for the stiffest corner of the default box
is about two): a particle beyond RK4's stability limit scores `inf`, and every reported
Bouc-Wen RMS is re-evaluated with sub-steps resolved from the found parameters.

**Outputs** (written atomically into `out`): `fig03_data_loops.png`, `fig07_loops_tanh.png`,
`fig08_loops_bouc_wen.png`, `fig09_rms_vs_current.png`, `fig10_generations_vs_current.png`,
`fig11_params_vs_current.png`, `fig12_generalized_loops.png`, `rms_identified.png`,
`pso_vs_polish.png`, `convergence_tanh.png`, `convergence_bouc_wen.png`, `summary.json`,
`summary.md`, `fit.json` (the accurate tanh fit with its generalized laws, readable by
`mrjax predict --fit`) and `fits/<run>.json` (every identification, `mrjax.FitResult.to_json`).

**Layout.** `_data` (the conditions of the study), `_study` (`Study`, its jobs, the two
threads, `compute`), `_figures` (every figure, `draw_figures`), `_summary` (`summarize`:
summary.json and the acceptance checks), `_render` (the text tables and summary.md), `_run`
(`run`: everything, written atomically).
"""

from ._data import DATA_CYCLES as DATA_CYCLES
from ._data import FIG_MOTIONS as FIG_MOTIONS
from ._data import figure_motions as figure_motions
from ._data import load_study_data as load_study_data
from ._figures import draw_figures as draw_figures
from ._render import markdown as markdown
from ._render import tables as tables
from ._run import run as run
from ._study import BW_SWARM_STEP_S as BW_SWARM_STEP_S
from ._study import PAPER_BOX as PAPER_BOX
from ._study import QUICK_GENERATIONS as QUICK_GENERATIONS
from ._study import RUN_TITLES as RUN_TITLES
from ._study import Study as Study
from ._study import compute as compute
from ._study import headline_generalized as headline_generalized
from ._summary import COEF_TOLERANCE_PCT as COEF_TOLERANCE_PCT
from ._summary import SUMMARY_SCHEMA as SUMMARY_SCHEMA
from ._summary import summarize as summarize

__all__ = ["PAPER_BOX", "Study", "compute", "run", "summarize"]
