"""The gradient polish: bounded Levenberg-Marquardt per condition, batched, with uncertainty.

:func:`solve_box` is the one bounded, batched polish of mrjax: every unit of a problem (a
condition of a per-test fit; the whole data of a joint-law fit) solved side by side by
:func:`lm_solve` (the one optimistix call site) on its residuals in a box; the engine
(`mrjax.engine.solve`) calls it for every problem kind.

The residual function is written for *one* unit and `jax.vmap` batches
`optimistix.least_squares` with `optimistix.LevenbergMarquardt` over the units inside one
`eqx.filter_jit` compiled function. :func:`uncertainty` then linearises a model at the optimum
for standard errors, covariances, correlations, 95 % intervals and an identifiability flag.
To polish a fit, use `mrjax.fit` (its `Polish` stage) or `mrjax.fitting.polish_fit`.

**Bounds.** optimistix has no bounds, so the polish runs in the unbounded MINUIT/lmfit
reparameterisation

$$ \\theta_j = l_j + (h_j - l_j)\\,\\frac{\\sin u_j + 1}{2}, $$

which keeps every iterate inside $[l_j, h_j]$ and makes each variable $u_j$ dimensionless and
O(1) (the box maps to $[-\\pi/2, \\pi/2]$) whatever the unit and magnitude of $\\theta_j$:
mrjax's parameters span 1e-1 to 1e4, and optimistix's Levenberg-Marquardt damps every variable
alike ($\\lambda I$) and tests convergence per variable. At a bound
$\\partial\\theta/\\partial u = 0$, so a start on a bound is moved inside by `BOUND_NUDGE`
(1e-3) of the box width before the solve; the start itself is still what `rms_start` scores
and what is returned if the solve does not improve on it. A result can approach a bound but
the linearised uncertainty there is only that of the unconstrained problem.
Parameters with $l_j = h_j$, or not in `free`, are held at their start and are not variables
of the solve.

**Never worse.** Per condition, the LM result is returned only if it is finite and its RMS is
no larger than the start's; otherwise the start is returned with status
`Status.KEPT_START`.

Everything runs in float64 (mrjax enables `jax_enable_x64` on import).
"""

from ._lm import DEFAULT_TOL as DEFAULT_TOL
from ._lm import LINEAR_SOLVER as LINEAR_SOLVER
from ._lm import STATUS_NAMES as STATUS_NAMES
from ._lm import LMSolution as LMSolution
from ._lm import Status as Status
from ._lm import lm_solve as lm_solve
from ._lm import status_name as status_name
from ._polish import BOUND_NUDGE as BOUND_NUDGE
from ._polish import BOUND_SNAP as BOUND_SNAP
from ._polish import FULL_MAX_STEPS as FULL_MAX_STEPS
from ._polish import FULL_TOL_FACTOR as FULL_TOL_FACTOR
from ._polish import VIEW_TOL_FACTOR as VIEW_TOL_FACTOR
from ._polish import BoxSolution as BoxSolution
from ._polish import solve_box as solve_box
from ._uncertainty import CORR_LIMIT as CORR_LIMIT
from ._uncertainty import EIG_RTOL as EIG_RTOL
from ._uncertainty import NULL_LOADING as NULL_LOADING
from ._uncertainty import Uncertainty as Uncertainty
from ._uncertainty import intervals as intervals
from ._uncertainty import jacobian_uncertainty as jacobian_uncertainty
from ._uncertainty import uncertainty as uncertainty

__all__ = ["DEFAULT_TOL", "Status", "Uncertainty", "jacobian_uncertainty", "lm_solve", "solve_box",
           "uncertainty"]
