"""Current-dependent (generalized) damper models: parameters as laws of the coil current.

A controller needs one model whose parameters are functions of the coil current $i$ [A]
(Kwok et al. 2006, eq 24-29), not one parameter set per test. This module builds such models
from per-condition fits, evaluates them at any (also time-varying) current, and inverts the
tanh model for the current that produces a wanted force.

```python
import mrjax
from mrjax.generalize import generalize, inverse_current

batch = mrjax.data.paper_grid()
res = mrjax.fit("kwok", batch, seed=0)
gm = generalize(res, batch, method="joint")
print(gm)                           # c = 1232 + 1929 i, ...
gm.params_at(0.6)                   # (P,) parameters at 0.6 A
gm.force(x, xdot, 1e-3, i_signal, lag=190.0)   # time-varying current with a first-order lag
inverse_current(gm, x, xdot, f_wanted, i_max=2.0)
```

**Laws.** Each parameter follows a :class:`Law` of the current: `"poly"`,
$p(i) = \\sum_m a_m i^m$ (coefficients in ascending powers), `"exp"`,
$p(i) = \\exp(\\sum_m a_m i^m)$, i.e. $\\exp(a + b\\,i)$ at degree 1 (a law used in the
literature for a Bouc-Wen $\\beta$), or `"sat"`, $p(i) = a + b(1 - e^{-i/s})$ (a change that saturates
above a few times the current s, like the yield force with the magnetic field).

**Forms chosen by the data** (`laws="auto"`, :func:`choose_forms`): per parameter the form with
the lowest BIC of the per-test values among polynomial degree 0-2, exponential and saturating;
on the paper's grid it picks eq 24-29's forms. The chosen forms are in the summary and in
`fit.json` (`law_forms`, `law_criteria`).

**Default degrees** (:func:`default_degrees`). The tanh model (`"kwok"`) uses the paper's:
c, k, delta, f0 linear, alpha quadratic, beta constant. The other built-in models make their
force scales linear, their yield/hysteretic force (`alpha`, `fc`) quadratic and the shape of
their hysteresis constant (after Spencer et al. 1997); an unknown model gets degree 1 for every
parameter and 2 for `alpha`. An `"exp"` law defaults to degree 1. Default degrees
are lowered to (number of distinct currents - 1) when the data have fewer currents; a degree
given explicitly is never lowered (too high a degree is an error).

**Two-step generalization** (the paper's). Group the per-condition parameters by current,
average them per current, then fit each law to the averages by least squares (an `"exp"` law
is fitted to the logarithm). With `weighting="equal"` this is literally the paper's procedure
(plain means, ordinary least squares, one parameter at a time). The default,
`weighting="covariance"`, uses the per-condition covariances of the fit
(`FitResult.stderr`/`corr`): each current's average is the inverse-covariance-weighted mean, and
all laws are fitted together by generalized least squares with the covariance of those means
(the minimum-distance estimator; it weights well-determined conditions more and uses the
correlations between parameters). It falls back to `"equal"` (recorded in
`GeneralizedModel.weighting`) where a covariance is missing, singular or not identifiable.

**Joint generalization.** The law coefficients themselves are the unknowns, fitted to all
conditions at once: the objective is the RMS force error over every scored sample of every
condition (:func:`mrjax.objective.masked_rms` on the flattened batch; swarm particles get the
same number from Gram sums through :func:`mrjax.objective.rms_from_gram`, as in the separable
per-condition swarm), computed in one batched evaluation. A static model's scored samples are
packed by current first, so short tests are not padded to the longest one. The batched particle
swarm (:func:`mrjax.pso.swarm`, one "condition" holding the whole batch) searches the laws of
the nonlinear parameters; the laws of the parameters the force is linear in (c, k, alpha, f0 of
the tanh model) are linear in their coefficients too, so every particle gets them by exact
linear least squares (variable projection). The swarm searches each law through its *values at
d+1 nodes* spread over the current range (a well-scaled, unit-bearing parametrization of a
degree-d polynomial; log values for an `"exp"` law), in a box around the two-step solution:
$\\pm$(3 x the scatter of the per-condition values about the two-step law + 25 % of the value).
A float64 Levenberg-Marquardt polish (optimistix) then refines every coefficient on the stacked
residuals of all conditions, starting from the better of the swarm's best and the two-step
solution, and is kept only if it lowers the total RMS, so the joint total RMS is never above
the two-step one on the same data.

**Hysteretic scale of Bouc-Wen models.** In Bouc-Wen and modified Bouc-Wen models the scale of
z is redundant (see `mrjax.models.BoucWen`): per-condition fits may pick different scales,
and averaging their `alpha`, `delta`, `beta`, `gamma` would be meaningless. Before
generalizing, each condition's parameters are mapped to the equivalent set (identical force)
whose z saturates at $|z|_{max} = (\\delta/(\\beta+\\gamma))^{1/n} = 1$, so `alpha` is the
hysteretic force amplitude in N. The laws of those models refer to this scale; their per-
condition covariance is singular, so their two-step weighting is `"equal"`.

**Time-varying current.** :meth:`GeneralizedModel.force` accepts a per-sample current; the
parameters then vary per sample (every model accepts parameters of shape (T, P)). An optional
first-order current lag $\\dot u = -\\eta (u - i)$ (Spencer et al. 1997) is discretized exactly
per sample, $u_{k+1} = i_k + (u_k - i_k)\\,e^{-\\eta\\,\\Delta t_k}$, $u_0 = i_0$
(:func:`lag_current`).

**Identification from time-varying commands.** :func:`identify` fits the laws (and the lag
$\\eta$, fitted or fixed) from records whose current or command voltage varies per sample,
constant-command sine tests, or any mix (Spencer et al. 1997; :func:`spencer_1997`,
:func:`command_record` and :func:`sine_record` give the known answers).

**Inverse model.** :func:`inverse` (and :func:`inverse_current`, its command alone) returns
the command in the admissible range whose force is closest to a wanted force: pointwise for
static models, by a scan carrying the state (and the lag) for dynamic ones; it saturates at
the limits, flagged, when the force is out of reach. :func:`closed_loop` simulates a
one-storey structure with the damper driven by it under a skyhook law.
"""

from ._coding import DELTA_RANGE as DELTA_RANGE
from ._coding import LOG_FLOOR as LOG_FLOOR
from ._coding import Q_RANGE as Q_RANGE
from ._coding import Layout as Layout
from ._coding import build_objective as build_objective
from ._coding import joint_residual_blocks as joint_residual_blocks
from ._coding import node_box as node_box
from ._forms import AUTO_FORMS as AUTO_FORMS
from ._forms import LawForms as LawForms
from ._forms import choose_forms as choose_forms
from ._generalize import generalize as generalize
from ._identify import LAG_BOUNDS as LAG_BOUNDS
from ._identify import MIN_GENERATIONS_DYNAMIC as MIN_GENERATIONS_DYNAMIC
from ._identify import Lag as Lag
from ._identify import command_unit_of as command_unit_of
from ._identify import identify as identify
from ._inverse import ClosedLoop as ClosedLoop
from ._inverse import Inverse as Inverse
from ._inverse import closed_loop as closed_loop
from ._inverse import inverse as inverse
from ._inverse import inverse_current as inverse_current
from ._laws import COMMAND_UNITS as COMMAND_UNITS
from ._laws import CURRENT_TOL as CURRENT_TOL
from ._laws import LAW_KINDS as LAW_KINDS
from ._laws import SAT_SCALES as SAT_SCALES
from ._laws import Law as Law
from ._laws import canonical_z_scale as canonical_z_scale
from ._laws import default_degrees as default_degrees
from ._laws import group_currents as group_currents
from ._laws import lag_current as lag_current
from ._laws import nodes as nodes
from ._model import MODEL_LAG as MODEL_LAG
from ._model import GeneralizedModel as GeneralizedModel
from ._model import LawUncertainty as LawUncertainty
from ._posterior import NOISE_RULE as NOISE_RULE
from ._posterior import LawPosterior as LawPosterior
from ._posterior import coefficient_names as coefficient_names
from ._posterior import law_band as law_band
from ._posterior import law_posterior_plan as law_posterior_plan
from ._posterior import read_law_draws as read_law_draws
from ._posterior import with_coefficients as with_coefficients
from ._records import SPENCER_1997 as SPENCER_1997
from ._records import command_record as command_record
from ._records import random_command as random_command
from ._records import random_motion as random_motion
from ._records import sine_record as sine_record
from ._records import spencer_1997 as spencer_1997
from ._report import LawReport as LawReport
from ._rows import make_rows as make_rows
from ._rows import record_order as record_order

__all__ = ["ClosedLoop", "GeneralizedModel", "Inverse", "Lag", "Law", "LawPosterior", "LawReport",
           "LawUncertainty", "NOISE_RULE", "SPENCER_1997", "choose_forms", "closed_loop", "command_record",
           "default_degrees", "generalize", "identify", "inverse", "inverse_current", "lag_current",
           "law_band", "random_command", "random_motion", "read_law_draws", "sine_record", "spencer_1997"]
