"""Choose a model with evidence: every model on the same tests, information criteria and
held-out validation of the current-dependent models, `mrjax.compare`.

```python
import mrjax
res = mrjax.compare("tests/", models="all",
                    held_out=mrjax.comparison.HeldOut(hold_out={"current": [0.25, 0.75]}))
print(res.table())            # per model: NRMSE, summed AIC / BIC, wins, held-out NRMSE, time
res.ranking                   # ('kwok', 'modified_bouc_wen', ...) by summed BIC
res.summary(), res.to_dict(), res.to_csv(), res.figures()
```

The criteria (:func:`information_criteria`) come from the Gaussian likelihood of each
test's residuals, with the parameters counted by :func:`n_free_parameters` plus one for the
noise variance. The package is named `comparison` so that the function `mrjax.compare` does
not hide a module.
"""

from ._compare import GENERALIZE_METHODS as GENERALIZE_METHODS
from ._compare import HeldOut as HeldOut
from ._compare import compare as compare
from ._criteria import information_criteria as information_criteria
from ._criteria import n_free_parameters as n_free_parameters
from ._folds import Fold as Fold
from ._folds import Plan as Plan
from ._folds import plan_validation as plan_validation
from ._result import CRITERIA_NOTE as CRITERIA_NOTE
from ._result import CompareResult as CompareResult

__all__ = ["CompareResult", "HeldOut", "compare", "information_criteria", "n_free_parameters"]
