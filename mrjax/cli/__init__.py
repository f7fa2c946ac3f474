"""The `mrjax` command line: identify MR damper models from measured tests.

```
mrjax fit DATA... --model kwok [--out DIR]          fit every test, write fit.json/csv + figures
mrjax fit DATA... --model kwok --generalize two-step   ... plus current-dependent laws
mrjax fit DATA... --model modified_bouc_wen --generalize joint [--lag fit|none|RATE]
                                                    records with a per-sample command: laws
                                                    of the command (and its lag) identified
mrjax predict --fit DIR/fit.json DATA... [--out DIR]  evaluate the laws on other tests
mrjax compare DATA... [--models all|kwok,...] [--hold-out current=0.25,0.75 | --folds K |
              --validate FILES] [--out DIR]        rank every model: criteria + held-out laws
mrjax inspect DATA... [data options] [--out DIR]    what is read: one line per test + a figure
mrjax reproduce [--quick]                           the paper's study on the embedded data
mrjax models                                        models, aliases, parameters, units, bounds
```

`fit`, `predict`, `compare` and `inspect` share the data options, for files with their own
column names, units and layouts: `--spec FILE.toml` and the flags `--columns`, `--wide`,
`--sample-rate`, `--current`, `--frequency`, `--amplitude`, `--label`, `--velocity-window`,
which override single keys of the spec file (`mrjax.data.DataSpec`).

Outputs: each command writes into its own directory (default `mrjax-out/COMMAND`), which holds
that command's outputs only (a directory of another command, or with other files, is refused
unless `--overwrite`), written atomically (all of them or none) by one run at a time (a second
run into the same directory is refused at once).

Errors in the input (missing or malformed files, unknown models, bad options, unwritable
output) print one line `mrjax: error: ...` on stderr and exit with code 2; `--debug` shows the
traceback instead. A mistyped option, command or model name is answered with the closest
one. Ctrl-C exits with 130. Building the parser imports nothing heavy: `mrjax --help` answers
at once.
"""

from ._main import CACHE_ENV as CACHE_ENV
from ._main import build_parser as build_parser
from ._main import enable_compilation_cache as enable_compilation_cache
from ._main import main as main
