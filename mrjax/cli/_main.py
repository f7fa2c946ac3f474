"""The parser of the `mrjax` command and its entry point.

Building the parser imports nothing heavy (see `_parse`): a command's module, and with it JAX,
is imported only when that command runs, after its output directory is claimed.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings

from .. import __version__
from .._errors import InputError
from .._io import OutputDir
from ._export import add_parser as _export_parser
from ._parse import (
    KERNELS,
    POSTERIOR_DEFAULTS,
    Parser,
    add_data_options,
    add_output_options,
    add_posterior_options,
    add_scale_options,
    nonneg_int,
    one_line,
    parse_degrees,
    parse_lag,
    parse_laws,
    positive_int,
    show_warning,
    transient,
)

#: Environment variable naming the persistent XLA compilation cache of the `mrjax` command
#: (default `~/.cache/mrjax/xla`; `off` disables it).
CACHE_ENV = "MRJAX_CACHE_DIR"

#: The commands that write an output directory (`--out`, `--overwrite`).
WRITERS = ("fit", "predict", "compare", "inspect", "reproduce", "export")


def _fit_parser(sub, common) -> None:
    p = sub.add_parser(
        "fit", parents=[common], help="identify a model on every test condition",
        description="Fit one model to every test in the given files at once and write fit.json, "
        "fit.csv and figures into --out (atomically: all files or none): F-x and F-v loops of "
        "periodic tests, force against time (whole, zoomed, residual) of random records. Many "
        "tests are fitted in chunks that fit --memory; each finished chunk is kept in "
        "DIR/.mrjax-journal until the outputs are written, so that an interrupted run "
        "continues with --resume.")
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="data files or directories (.csv, .txt/.dat, .mat, .parquet, "
                   ".feather/.arrow; any layout with the data options below)")
    p.add_argument("--model", required=True, metavar="NAME|FILE.py:NAME",
                   help="model name: bingham, kwok (alias tanh), bouc_wen (bw), "
                   "modified_bouc_wen (spencer, mbw), dahl, lugre, herschel_bulkley, polynomial, "
                   "an installed one (see `mrjax models`), or your own model in a Python file, "
                   "path/to/file.py:Name")
    p.add_argument("--method", choices=("pso", "pso+lm", "lm"), default="pso+lm",
                   help="swarm, swarm then Levenberg-Marquardt polish (default), or polish alone")
    p.add_argument("--swarm", choices=("separable", "full"), default="separable",
                   help="separable: variable projection over the linear parameters (default); "
                   "full: the paper's swarm over all parameters")
    p.add_argument("--restarts", type=positive_int, default=None, metavar="K",
                   help="independent swarms per test, best one polished (default 1; 2 for "
                   "an ODE model on a single test)")
    p.add_argument("--no-retry", action="store_true",
                   help="do not polish each test again from its neighbours' optima (the "
                   "default retry finds the optima one swarm misses and warns where the two "
                   "results disagree)")
    p.add_argument("--swarm-dtype", choices=("float64", "float32"), default=None,
                   help="precision of the swarm's search (default float64; float32 is about "
                   "twice as fast; the polish and the results stay float64)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")
    p.add_argument("--generations", type=positive_int, metavar="N",
                   help="run exactly N swarm generations (no statistical stop)")
    p.add_argument("--max-generations", type=positive_int, metavar="N",
                   help="cap on swarm generations with the statistical stop (default 200)")
    p.add_argument("--particles", type=positive_int, default=50, metavar="N",
                   help="swarm size (default 50)")
    p.add_argument("--transient", type=transient, metavar="SECONDS|cycle",
                   help="leave an initial span out of the fitness: seconds or 'cycle'")
    p.add_argument("--bounds", action="append", metavar="NAME=LO:HI",
                   help="search bounds of one parameter in SI units, e.g. c=500:5000 (repeatable; "
                   "an empty LO or HI keeps the default; see `mrjax models`)")
    p.add_argument("--fixed", action="append", metavar="NAME=VALUE",
                   help="hold one parameter at a value in SI units, e.g. delta=1 (repeatable): "
                   "every stage, the laws and the posterior keep it; fit.json records it")
    p.add_argument("--generalize", choices=("two-step", "joint"),
                   help="also fit current-dependent laws of the parameters (needed by "
                   "`mrjax predict`); records with a command voltage or a time-varying current "
                   "need 'joint' (the laws are then identified from every record at once)")
    p.add_argument("--degrees", type=parse_degrees, metavar="NAME=DEG,...",
                   help="polynomial degree of the named parameters' laws of the current or "
                   "command (0: constant; default per model, e.g. Spencer's c0, c1, alpha "
                   "linear in a command voltage)")
    p.add_argument("--laws", type=parse_laws, metavar="auto|fixed|NAME=KIND,...",
                   help="form of the laws of --generalize: 'auto' (default for laws of the "
                   "current) chooses each parameter's among polynomial degree 0-2, "
                   "exponential and saturating by the lowest BIC of the per-test values (shown "
                   "in the summary and fit.json; --degrees fixes the named ones); 'fixed': the "
                   "model's default degrees (default for a time-varying command); NAME=KIND "
                   "with KIND poly, exp or sat, the others fixed")
    p.add_argument("--lag", type=parse_lag, default="fit", metavar="fit|none|RATE",
                   help="command filter du/dt = -eta (u - v) of time-varying commands: 'fit' "
                   "(default), 'none', or eta in 1/s to fix it (Spencer 1997: 190)")
    _structure_options(p, fit=True)
    add_output_options(p, "fit")
    p.add_argument("--max-rows", type=positive_int, default=None, metavar="N",
                   help="print at most N rows of the result table (default all)")
    add_scale_options(p, journal=True)
    add_posterior_options(p)
    add_data_options(p)
    p.set_defaults(run=("_fit", "run"))


def _predict_parser(sub, common) -> None:
    p = sub.add_parser(
        "predict", parents=[common], help="evaluate fitted current-dependent laws on tests",
        description="Predict the force of other tests from the current-dependent laws in a "
        "fit.json written by `mrjax fit --generalize`; write predict.json, predict.csv and "
        "figures (loops of periodic tests, force against time of random records).")
    p.add_argument("--fit", required=True, metavar="FIT.json",
                   help="fit.json of `mrjax fit --generalize` (or its directory)")
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="data files or directories (any layout with the data options below)")
    p.add_argument("--model", metavar="FILE.py:NAME",
                   help="where the fitted model is, when it is not a model of this installation "
                   "and fit.json's record of its file or module no longer finds it")
    p.add_argument("--band", type=float, metavar="PCT",
                   help="the posterior predictive force band of a fit written with "
                   "`mrjax fit --posterior` (its posterior.nc), e.g. 95, with its coverage of "
                   "the measured force: a per-test fit on records of the same tests, laws "
                   "(`--generalize ... --posterior`) on records at any current")
    _structure_options(p, fit=False)
    add_output_options(p, "predict")
    add_data_options(p)
    p.set_defaults(run=("_predict", "run"))


def _structure_options(p, *, fit: bool) -> None:
    """A structure's fit (`mrjax.structure`): the structure, a periodic input, the input
    between samples."""
    if fit:
        p.add_argument("--structure", choices=("sdof", "base"),
                       help="identify the model inside a mass-on-element structure from the "
                       "response to its input (output error): sdof, driven by a force_<unit> "
                       "column; base, by a ground_acceleration_<unit> column; the response is "
                       "displacement_<unit> (or acceleration_<unit>); the mass is an unknown "
                       "m [kg] (--bounds m=LO:HI)")
    p.add_argument("--periodic", metavar="N|DURATION",
                   help="structure records of whole periods of a periodic input in steady "
                   "state: N samples (or a duration such as 10.92s) per period; one period "
                   "is simulated first and discarded (default: from rest)")
    p.add_argument("--interpolation", choices=("fft", "linear", "zoh"),
                   help="a structure's input between samples: band-limited (default), linear "
                   "or zero-order hold")


def _compare_parser(sub, common) -> None:
    p = sub.add_parser(
        "compare", parents=[common], help="compare models on the same tests (criteria, "
        "held-out validation)",
        description="Fit every model to the same tests, rank them by information criteria "
        "(AIC, AICc, BIC) and score their current-dependent laws on held-out tests; write "
        "compare.json, compare.csv and figures into --out (atomically: all files or none). "
        "Default validation: leave one current out when the currents are known.")
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="data files or directories (as `mrjax fit`)")
    p.add_argument("--models", default="all", metavar="all|NAME,...",
                   help="models to compare, e.g. kwok,bouc_wen,path/to/mine.py:Mine (default "
                   "all: every model of `mrjax models`)")
    held = p.add_mutually_exclusive_group()
    held.add_argument("--validate", nargs="+", metavar="FILE",
                      help="score the laws built on all FILES on these other tests, read with "
                      "the same data options (put it after FILES)")
    held.add_argument("--hold-out", metavar="current=A,...",
                      help="hold out the tests at these currents, e.g. current=0.25,0.75")
    held.add_argument("--folds", metavar="K|current",
                      help="K folds over the tests, or 'current' (leave one current out)")
    p.add_argument("--generalize", default="two-step,joint", metavar="METHODS",
                   help="generalization methods scored on held-out tests: two-step, joint, "
                   "two-step,joint (default) or none")
    p.add_argument("--method", choices=("pso", "pso+lm", "lm"), default="pso+lm",
                   help="per-test fit: swarm, swarm then polish (default), or polish alone")
    p.add_argument("--restarts", type=positive_int, default=None, metavar="K",
                   help="independent swarms per test and model, best one polished (default 1; "
                   "2 for an ODE model on a single test)")
    p.add_argument("--no-retry", action="store_true",
                   help="do not polish each test again from its neighbours' optima (as "
                   "`mrjax fit`)")
    p.add_argument("--max-generations", type=positive_int, default=200, metavar="N",
                   help="cap on swarm generations with the statistical stop (default 200)")
    p.add_argument("--particles", type=positive_int, default=50, metavar="N",
                   help="swarm size (default 50)")
    p.add_argument("--polish-steps", type=positive_int, default=200, metavar="N",
                   help="maximum Levenberg-Marquardt steps per test (default 200)")
    p.add_argument("--transient", type=transient, metavar="SECONDS|cycle",
                   help="leave an initial span out of the fitness and the scores")
    p.add_argument("--swarm-dtype", choices=("float64", "float32"), default=None,
                   help="precision of the swarm's search (default float64)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")
    add_output_options(p, "compare")
    add_scale_options(p, journal=False)
    add_data_options(p)
    p.set_defaults(run=("_compare", "run"))


def _inspect_parser(sub, common) -> None:
    p = sub.add_parser(
        "inspect", parents=[common], help="show what mrjax reads from files (check a data spec)",
        description="Read the files as `mrjax fit` would and print one line per test: samples, "
        "rate, duration, ranges with units, frequency and amplitude (~ marks an estimate; "
        "nominal values from a file name are shown beside the measured half range when they "
        "differ), velocity measured or estimated, current or command, warnings; then the "
        "loader's notes (skipped lines, unused columns). Writes inspect.png (every signal "
        "against time), inspect.json and, when data options were given, spec.toml (the "
        "effective spec, reusable with --spec) into --out, atomically.")
    p.add_argument("files", nargs="+", metavar="FILE", help="data files or directories")
    add_output_options(p, "inspect", no_plots="write no PNG figure")
    p.add_argument("--max-panels", type=positive_int, default=12, metavar="N",
                   help="at most N tests in inspect.png, evenly spread (default 12)")
    add_data_options(p)
    p.set_defaults(run=("_inspect", "run"))


def _misc_parsers(sub, common) -> None:
    p = sub.add_parser("reproduce", parents=[common],
                       help="reproduce the paper's study on the embedded data",
                       description="Reproduce the study of Kwok et al. (2006).")
    p.add_argument("--quick", action="store_true", help="a small, fast version")
    p.add_argument("--data", metavar="DIR", help="measured data directory (default: embedded)")
    add_output_options(p, "reproduce", no_plots=None)
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")
    p.set_defaults(run=("_misc", "run_reproduce"))

    p = sub.add_parser("models", parents=[common],
                       help="list models with aliases, parameters, units and default bounds")
    p.add_argument("--markdown", action="store_true", help="markdown tables")
    p.add_argument("--model", action="append", metavar="FILE.py:NAME",
                   help="also check and list your own model (repeatable)")
    p.set_defaults(run=("_misc", "run_models"))


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the `mrjax` command (all sub-commands). Imports nothing heavy.

    **Returns:** the parser; `parse_args` gives a namespace whose `run` is `(module, function)`
    of the command, in `mrjax.cli`.
    """
    common = Parser(add_help=False)
    common.add_argument("--debug", action="store_true",
                        help="show the full traceback of errors instead of one line")
    parser = Parser(
        prog="mrjax", description="Identify magnetorheological damper models (Kwok et al. 2006) "
        "with a batched JAX particle swarm and a Levenberg-Marquardt polish.",
        epilog="Run `mrjax COMMAND --help` for the options of a command.")
    parser.add_argument("--version", action="version", version=f"mrjax {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    _fit_parser(sub, common)
    _predict_parser(sub, common)
    _compare_parser(sub, common)
    _inspect_parser(sub, common)
    _export_parser(sub, common)
    _misc_parsers(sub, common)
    return parser


#: Environment variable that gives JAX's CPU backend several devices (read when JAX starts).
CPU_DEVICES_ENV = "JAX_NUM_CPU_DEVICES"


def spread_chains(chains: int) -> int:
    """Before JAX starts, give its CPU backend one device per chain, up to the CPU count
    (`JAX_NUM_CPU_DEVICES`, unless the user set it or `XLA_FLAGS` names a device count), so that
    `mrjax.bayes.sample` runs a test's chains side by side on the cores
    (`mrjax.bayes.chain_devices`); nothing else uses the extra devices unless asked
    (`--devices`).

    **Returns:** the device count asked for (1: nothing changed)."""
    if "jax" in sys.modules or os.environ.get(CPU_DEVICES_ENV) or \
            "device_count" in os.environ.get("XLA_FLAGS", ""):
        return 1
    n = min(max(int(chains), 1), os.cpu_count() or 1)
    if n > 1:
        os.environ[CPU_DEVICES_ENV] = str(n)
    return n


def enable_compilation_cache() -> str | None:
    """Point JAX's persistent compilation cache at `$MRJAX_CACHE_DIR` (default
    `~/.cache/mrjax/xla`) unless the user configured one (`JAX_COMPILATION_CACHE_DIR`) or set
    `MRJAX_CACHE_DIR=off`. A repeated `mrjax fit` then loads its compiled programs instead of
    compiling them (the cold 36-test fit: 10.5 s -> 6.3 s; see benchmarks/results.md). The
    directory is JAX's own cache format; delete it to reclaim the space (a few MB per model
    and data shape). (`jax_compilation_cache_max_size` is left unset: with jax 0.10.2 setting
    it stopped every write, measured.)

    **Returns:** the directory in use, or None. Never fails: an unusable directory only means
    no cache.
    """
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return os.environ["JAX_COMPILATION_CACHE_DIR"]
    path = os.environ.get(CACHE_ENV, os.path.join("~", ".cache", "mrjax", "xla"))
    if path.strip().lower() in ("", "off", "0", "none", "false"):
        return None
    path = os.path.expanduser(path)
    try:
        os.makedirs(path, exist_ok=True)
        if not os.access(path, os.W_OK):
            return None
        import jax

        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    except (OSError, AttributeError, ValueError):  # pragma: no cover - depends on the host
        return None
    return path


def _dispatch(args: argparse.Namespace) -> int:
    """Claim the command's output directory (refusal and lock before anything heavy is
    imported), import the command and run it."""
    module, name = args.run
    if getattr(args, "posterior", False):
        kernel = KERNELS.get(args.kernel or POSTERIOR_DEFAULTS["kernel"], (0, 1))
        spread_chains(args.chains or kernel[1])
    if args.command in ("fit", "predict", "reproduce", "compare"):
        enable_compilation_cache()
    if args.command not in WRITERS:
        return int(getattr(importlib.import_module(f"mrjax.cli.{module}"), name)(args))
    with OutputDir(args.out, args.command, overwrite=args.overwrite) as out:
        run = getattr(importlib.import_module(f"mrjax.cli.{module}"), name)
        return int(run(args, out))


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `mrjax` console script; returns the exit code.

    **Arguments:** `argv` the arguments without the program name (default `sys.argv[1:]`).

    **Returns:** 0 on success, 2 for a usage or input error (one line on stderr), 130 when
    interrupted.
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # usage errors (2), --help and --version (0)
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    debug = bool(getattr(args, "debug", False))
    try:
        with warnings.catch_warnings():
            warnings.showwarning = show_warning
            return _dispatch(args)
    except BrokenPipeError:  # e.g. `mrjax models | head`: stop quietly, like other tools
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError, AttributeError):
            pass
        return 141
    except KeyboardInterrupt:
        if debug:
            raise
        print("mrjax: interrupted", file=sys.stderr)
        return 130
    except (InputError, OSError) as e:  # OSError covers FileNotFoundError, PermissionError
        if debug:
            raise
        print(f"mrjax: error: {one_line(e)}", file=sys.stderr)
        return 2
