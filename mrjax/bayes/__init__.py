"""The sampler of mrjax: the posterior of any problem's unknowns by NUTS (blackjax), with its
diagnostics and files through arviz.

A problem kind supplies a :class:`Likelihood` (its residuals as blocks of records, the
optimum, the box); :func:`sample` finds the posterior's mode, runs NUTS on every unit at once
and continues the units that missed convergence, and returns a :class:`Posterior`. Users call
`mrjax.posterior` on a fit, which rebuilds the fit's problem and calls the engine's posterior
stage (`mrjax.engine.sample`), the one caller of :func:`sample`:

```python
import mrjax
res = mrjax.fit("kwok", batch)
post = mrjax.posterior(res, batch, sampler=mrjax.Sampler(draws=1000), noise="ar1")
print(post.table())          # mean, sd, 2.5/50/97.5 %, R-hat, ESS per parameter and test
post.idata                   # arviz.InferenceData (dims chain, draw, condition)
band = post.predict_band(batch)   # posterior predictive force band and its coverage
```

The package is named `bayes` so that the function `mrjax.posterior` does not hide a module.
"""

from ._band import PredictiveBand as PredictiveBand
from ._band import predictive_band as predictive_band
from ._band import read_draws as read_draws
from ._noise import NOISE_MODELS as NOISE_MODELS
from ._noise import block_loglik as block_loglik
from ._noise import check_noise as check_noise
from ._noise import lag_grams as lag_grams
from ._noise import linear_marginal as linear_marginal
from ._priors import LogNormal as LogNormal
from ._priors import Normal as Normal
from ._priors import Uniform as Uniform
from ._priors import at_bounds as at_bounds
from ._priors import check_priors as check_priors
from ._priors import from_box as from_box
from ._priors import log_jacobian as log_jacobian
from ._priors import log_prior as log_prior
from ._priors import parse_prior as parse_prior
from ._priors import to_box as to_box
from ._result import ESS_MIN as ESS_MIN
from ._result import RHAT_MAX as RHAT_MAX
from ._result import RHO as RHO
from ._result import SIGMA as SIGMA
from ._result import Posterior as Posterior
from ._result import PosteriorFront as PosteriorFront
from ._result import arviz as arviz
from ._sample import Likelihood as Likelihood
from ._sample import length_groups as length_groups
from ._sample import sample as sample
from ._sampler import NUTS as NUTS
from ._sampler import ChEES as ChEES
from ._sampler import Sampler as Sampler
from ._sampler import chain_devices as chain_devices

__all__ = ["ESS_MIN", "NOISE_MODELS", "NUTS", "RHAT_MAX", "ChEES", "Likelihood", "LogNormal",
           "Normal", "Posterior", "PredictiveBand", "Sampler", "Uniform", "block_loglik", "parse_prior",
           "length_groups", "predictive_band", "read_draws", "sample"]
