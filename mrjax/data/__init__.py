"""Test-condition data: conditions, padded batches, loaders, units, velocity, synthetic grid."""

from ._condition import Batch as Batch
from ._condition import Condition as Condition
from ._condition import make_batch as make_batch
from ._loaders import DATA_SUFFIXES as DATA_SUFFIXES
from ._loaders import default_data_dir as default_data_dir
from ._loaders import load as load
from ._loaders import load_batch as load_batch
from ._loaders import load_csv as load_csv
from ._loaders import load_mat as load_mat
from ._loaders import load_txt as load_txt
from ._loaders import parse_label as parse_label
from ._synthetic import PAPER_COEFFICIENTS as PAPER_COEFFICIENTS
from ._synthetic import PAPER_CURRENTS as PAPER_CURRENTS
from ._synthetic import PAPER_MOTIONS as PAPER_MOTIONS
from ._synthetic import paper_grid as paper_grid
from ._synthetic import paper_parameters as paper_parameters
from ._synthetic import paper_truth as paper_truth
from ._synthetic import simulate as simulate
from ._synthetic import sine_excitation as sine_excitation
from ._units import COLUMN_QUANTITIES as COLUMN_QUANTITIES
from ._units import UNITS as UNITS
from ._units import column_names as column_names
from ._units import parse_column as parse_column
from ._units import to_si as to_si
from ._units import unit_scale as unit_scale
from ._velocity import estimate_velocity as estimate_velocity
