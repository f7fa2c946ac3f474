"""Bayesian identification: the posterior of any problem kind's unknowns by NUTS (blackjax),
with its diagnostics and files through arviz.

```python
import mrjax
res = mrjax.fit("kwok", batch)
post = mrjax.posterior(res, batch, draws=1000, chains=4, noise="ar1")
print(post.table())          # mean, sd, 2.5/50/97.5 %, R-hat, ESS per parameter and test
post.idata                   # arviz.InferenceData (dims chain, draw, condition)
band = post.predict_band(batch)   # posterior predictive force band and its coverage
```

On laws over the current (`mrjax.generalize.generalize(res, batch, method="joint")`), the
same call samples the law coefficients (one unit: the whole data set, one noise level per
record) and returns a :class:`LawPosterior`, whose `predict_band` predicts records at new
currents:

```python
gm = mrjax.generalize.generalize(res, batch, method="joint")
lp = mrjax.posterior(gm, batch, noise="ar1")      # a LawPosterior
lp.predict_band(held_out).coverage                # per record, at unseen currents
```

The core, :func:`sample`, takes a residual function of one unit's unknowns in a box (one
condition of a per-test fit; the whole data set of a joint-law fit) and returns a
:class:`Posterior`; :func:`posterior` is the per-test kind on a `mrjax.fit` result. The package
is named `bayes` so that the function `mrjax.posterior` does not hide a module.
"""

from ._laws import NOISE_RULE as NOISE_RULE
from ._laws import LawBlocks as LawBlocks
from ._laws import LawPosterior as LawPosterior
from ._laws import coefficient_names as coefficient_names
from ._laws import law_band as law_band
from ._laws import law_posterior as law_posterior
from ._laws import read_law_draws as read_law_draws
from ._laws import with_coefficients as with_coefficients
from ._noise import NOISE_MODELS as NOISE_MODELS
from ._noise import block_loglik as block_loglik
from ._noise import linear_marginal as linear_marginal
from ._pertest import DATA_CHOICES as DATA_CHOICES
from ._pertest import PerTestResidual as PerTestResidual
from ._pertest import PredictiveBand as PredictiveBand
from ._pertest import TestPosterior as TestPosterior
from ._pertest import posterior as posterior
from ._pertest import predictive_band as predictive_band
from ._pertest import read_draws as read_draws
from ._priors import LogNormal as LogNormal
from ._priors import Normal as Normal
from ._priors import Uniform as Uniform
from ._priors import check_priors as check_priors
from ._priors import from_box as from_box
from ._priors import log_jacobian as log_jacobian
from ._priors import log_prior as log_prior
from ._priors import parse_prior as parse_prior
from ._priors import to_box as to_box
from ._result import ESS_MIN as ESS_MIN
from ._result import RHAT_MAX as RHAT_MAX
from ._result import Posterior as Posterior
from ._result import PosteriorFront as PosteriorFront
from ._result import netcdf_bytes as netcdf_bytes
from ._sampler import Sampler as Sampler
from ._sampler import chain_devices as chain_devices
from ._sampler import sample as sample
