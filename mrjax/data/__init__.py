"""Test-condition data: conditions and padded, masked batches of them; loaders of long CSV,
headerless text, MATLAB, Parquet and Feather files; data specs for any other layout; a source
of tests left in their files and read a chunk at a time; units; velocity from displacement;
sanity checks and reports of what was read; and the simulated grid of the paper.

```python
import mrjax
conds = mrjax.data.load("tests/")                   # every data file in the folder, in SI
batch = mrjax.data.make_batch(conds)                 # (C, T) arrays, padded and masked
spec = mrjax.data.DataSpec.from_toml("lab.toml")     # where the signals are, in which units
batch = mrjax.data.load_batch("lab.mat", spec=spec)
```
"""

from ._checks import check_condition as check_condition
from ._columnar import load_columnar as load_columnar
from ._columns import Column as Column
from ._columns import Meta as Meta
from ._condition import COMMAND_UNITS as COMMAND_UNITS
from ._condition import ESTIMATED_FIELDS as ESTIMATED_FIELDS
from ._condition import Batch as Batch
from ._condition import Condition as Condition
from ._condition import make_batch as make_batch
from ._csv import load_csv as load_csv
from ._describe import ConditionReport as ConditionReport
from ._describe import describe as describe
from ._files import find_files as find_files
from ._files import parse_label as parse_label
from ._frame import from_frame as from_frame
from ._frame import to_frame as to_frame
from ._loaders import load as load
from ._loaders import load_batch as load_batch
from ._mask import fit_mask as fit_mask
from ._mat import load_mat as load_mat
from ._source import Source as Source
from ._spec import DataSpec as DataSpec
from ._spectrum import estimate_motion as estimate_motion
from ._synthetic import PAPER_COEFFICIENTS as PAPER_COEFFICIENTS
from ._synthetic import PAPER_CURRENTS as PAPER_CURRENTS
from ._synthetic import PAPER_MOTIONS as PAPER_MOTIONS
from ._synthetic import paper_grid as paper_grid
from ._synthetic import paper_parameters as paper_parameters
from ._synthetic import paper_truth as paper_truth
from ._synthetic import simulate as simulate
from ._synthetic import sine_excitation as sine_excitation
from ._text import load_txt as load_txt
from ._units import UNITS as UNITS
from ._units import column_names as column_names
from ._units import parse_column as parse_column
from ._units import quantity_value as quantity_value
from ._units import to_si as to_si
from ._units import unit_scale as unit_scale
from ._velocity import VelocityWindow as VelocityWindow
from ._velocity import estimate_velocity as estimate_velocity
from ._velocity import velocity_window as velocity_window

__all__ = [
    # conditions and batches
    "Condition",
    "Batch",
    "make_batch",
    "COMMAND_UNITS",
    "ESTIMATED_FIELDS",
    "fit_mask",
    # files
    "load",
    "load_batch",
    "load_txt",
    "load_csv",
    "load_mat",
    "load_columnar",
    "find_files",
    "parse_label",
    "DataSpec",
    "Column",
    "Meta",
    "Source",
    "from_frame",
    "to_frame",
    # what was read
    "describe",
    "ConditionReport",
    "check_condition",
    # units
    "UNITS",
    "to_si",
    "unit_scale",
    "quantity_value",
    "parse_column",
    "column_names",
    # velocity and motion
    "estimate_velocity",
    "velocity_window",
    "VelocityWindow",
    "estimate_motion",
    # the paper's simulated grid
    "simulate",
    "sine_excitation",
    "paper_grid",
    "paper_parameters",
    "paper_truth",
    "PAPER_COEFFICIENTS",
    "PAPER_CURRENTS",
    "PAPER_MOTIONS",
]

# The plumbing that the other mrjax packages (fitting, generalize, bayes, ...) import: public,
# so that no private name crosses a package, but not part of the user API (`__all__`).
from ._coerce import as_batch as as_batch  # any form of data -> a Batch
from ._mask import check_mask as check_mask  # a user's (C, T) mask, checked
from ._view import JOINT_SAMPLES_PER_PERIOD as JOINT_SAMPLES_PER_PERIOD
from ._view import View as View  # the swarm's subsampled copy of a batch
from ._view import swarm_view as swarm_view
