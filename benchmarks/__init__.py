"""mrjax benchmark suite (not tests: nothing here is collected by pytest).

Run everything with `python -m benchmarks` (or `python -m benchmarks --quick` for a reduced
sweep). Results go to `benchmarks/results.md`, `benchmarks/results.json` and PNG figures beside
them. One module per section: `tanh_swarm`, `ode_models`, `polish`, `scaling`, `cold`;
`render` writes results.md from results.json, `run` is the driver (see its docstring for what
is measured and how).
"""

import os as _os

# the sections draw PNGs with pyplot: no display needed (set before matplotlib is imported)
_os.environ.setdefault("MPLBACKEND", "Agg")
