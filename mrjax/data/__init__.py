"""Test-condition data: conditions, padded batches, loaders, units, velocity, synthetic grid."""

from ._condition import Batch as Batch
from ._condition import Condition as Condition
from ._condition import make_batch as make_batch
from ._synthetic import PAPER_COEFFICIENTS as PAPER_COEFFICIENTS
from ._synthetic import PAPER_CURRENTS as PAPER_CURRENTS
from ._synthetic import PAPER_MOTIONS as PAPER_MOTIONS
from ._synthetic import paper_grid as paper_grid
from ._synthetic import paper_parameters as paper_parameters
from ._synthetic import paper_truth as paper_truth
from ._synthetic import simulate as simulate
from ._synthetic import sine_excitation as sine_excitation
