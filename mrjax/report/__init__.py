"""Figures and tables of data and fit results.

Figures are `matplotlib.figure.Figure` objects made without `pyplot` (no display needed);
`save_png_bytes(fig)` renders one to PNG bytes.

```python
import mrjax, mrjax.report as rp
res = mrjax.fit("kwok", batch)
png = rp.save_png_bytes(rp.plot_loops_grid(res, batch))      # periodic tests: F-x, F-v loops
png = rp.save_png_bytes(rp.plot_force_time(res, batch))      # random records: force vs time
png = rp.save_png_bytes(rp.plot_records(mrjax.data.load("tests/")))   # what was read
```
"""

from .._tables import format_table as format_table
from ._command import command_figures as command_figures
from ._command import plot_command_record as plot_command_record
from ._command import plot_laws_vs_command as plot_laws_vs_command
from ._figures import plot_convergence as plot_convergence
from ._figures import plot_generations_vs_current as plot_generations_vs_current
from ._figures import plot_params_vs_current as plot_params_vs_current
from ._figures import plot_pso_vs_polish as plot_pso_vs_polish
from ._figures import plot_rms_vs_current as plot_rms_vs_current
from ._figures import save_png_bytes as save_png_bytes
from ._loops import plot_data_loops as plot_data_loops
from ._loops import plot_loops_grid as plot_loops_grid
from ._posterior import law_posterior_figures as law_posterior_figures
from ._posterior import plot_law_intervals as plot_law_intervals
from ._posterior import plot_posterior_intervals as plot_posterior_intervals
from ._posterior import plot_posterior_pair as plot_posterior_pair
from ._posterior import plot_predictive_band as plot_predictive_band
from ._posterior import posterior_figures as posterior_figures
from ._timeseries import plot_force_time as plot_force_time
from ._timeseries import plot_records as plot_records

__all__ = [
    # per-test fits
    "plot_loops_grid",
    "plot_force_time",
    "plot_rms_vs_current",
    "plot_params_vs_current",
    "plot_generations_vs_current",
    "plot_convergence",
    "plot_pso_vs_polish",
    # the data as read
    "plot_data_loops",
    "plot_records",
    # laws of a time-varying command
    "command_figures",
    "plot_command_record",
    "plot_laws_vs_command",
    # posteriors
    "posterior_figures",
    "law_posterior_figures",
    "plot_posterior_intervals",
    "plot_posterior_pair",
    "plot_predictive_band",
    "plot_law_intervals",
    # output
    "save_png_bytes",
    "format_table",
]

# Imported by `mrjax.reproduce`'s figures, not part of the user API (`__all__`).
from ._loops import TANH_STEP_NOTE as TANH_STEP_NOTE
