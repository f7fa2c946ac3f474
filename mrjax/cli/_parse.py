"""What the `mrjax` parser needs, and nothing heavy: the parser class ("did you mean"),
argument types, the option groups shared by commands, the output options and the one-line
messages. JAX, NumPy, matplotlib and pandas are imported by the commands, when they run, so
that `mrjax --help` and a usage error answer at once."""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Iterable

from .._errors import InputError

#: The folder under which each command writes by default, one sub-folder per command
#: (`mrjax-out/fit`, `mrjax-out/predict`, ...), so that commands never mix their outputs.
DEFAULT_ROOT = "mrjax-out"


def default_out(command: str) -> str:
    """The default output directory of `command`: `mrjax-out/COMMAND`."""
    return f"{DEFAULT_ROOT}/{command}"


def say(msg: str) -> None:
    """A short stage line on stderr (the table and results go to stdout)."""
    print(f"mrjax: {msg}", file=sys.stderr, flush=True)


def one_line(e: BaseException) -> str:
    """The message of an error as one line (OSError: `file: reason`)."""
    if isinstance(e, OSError) and not isinstance(e, InputError) and e.strerror:
        msg = f"{e.filename}: {e.strerror}" if e.filename else e.strerror
    else:
        msg = str(e) or type(e).__name__
    return " ".join(msg.split())


def show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line `mrjax: warning: ...` on stderr."""
    print(f"mrjax: warning: {' '.join(str(message).split())}", file=sys.stderr, flush=True)


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """`"; did you mean 'X'?"` for the choice closest to a mistyped `word`, or `""`."""
    import difflib  # imported here: only a mistake needs it

    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


_NUMBER = re.compile(r"^-\d+$|^-\d*\.\d+([eE][-+]?\d+)?$")


class Parser(argparse.ArgumentParser):
    """argparse with whole option names only (`allow_abbrev=False`), "did you mean" for a
    mistyped option or command, and a short usage error: one line naming the mistake, after a
    one-line usage pointing at `--help`, exit code 2."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        self._commands: argparse._SubParsersAction | None = None

    def add_subparsers(self, **kwargs):
        """As argparse's; the commands are remembered for "did you mean"."""
        self._commands = super().add_subparsers(**kwargs)
        return self._commands

    def parse_known_args(self, args=None, namespace=None):
        args = sys.argv[1:] if args is None else list(args)
        self._check_names(args)
        return super().parse_known_args(args, namespace)

    def _check_names(self, args: list[str]) -> None:
        """Unknown options (and, for the top parser, an unknown command) before argparse's
        own checks, which would otherwise first complain about a missing required option."""
        commands = list(self._commands.choices) if self._commands is not None else None
        # argparse has no public list of a parser's option strings: read it here, once
        options = self._option_string_actions
        for token in args:
            if token == "--":
                return
            if token.startswith("-") and token != "-":
                if _NUMBER.match(token):  # a negative number is a value
                    continue
                name = token.split("=", 1)[0]
                if name not in options:
                    self.error(f"unrecognized option {name!r}{did_you_mean(name, options)}")
            elif commands is not None:  # the command: the rest is its own parser's
                if token not in commands:
                    self.error(f"unknown command {token!r}{did_you_mean(token, commands)} "
                               f"(commands: {', '.join(commands)})")
                return

    def error(self, message: str):
        """Print a one-line usage and one error line on stderr; exit with code 2."""
        print(f"usage: {self.prog} ... (see `{self.prog} --help`)", file=sys.stderr)
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


# --------------------------------------------------------------------------------------------
# Argument types


def _int_at_least(text: str, low: int, what: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if v < low:
        raise argparse.ArgumentTypeError(f"expected {what}, got {v}")
    return v


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    return _int_at_least(text, 1, "a positive integer")


def nonneg_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    return _int_at_least(text, 0, "a non-negative integer")


def memory_size(text: str) -> int:
    """argparse type: a memory size such as `8GB`, `512MB` (see `mrjax.fitting.parse_memory`)."""
    from ..fitting import parse_memory  # imported here: only when the option is given

    try:
        return parse_memory(text)
    except InputError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def device_count(text: str) -> int | str:
    """argparse type: `all` or a positive number of devices."""
    if text.strip().lower() == "all":
        return "all"
    return _int_at_least(text, 1, "a positive number of devices or 'all'")


def transient(text: str) -> float | str:
    """argparse type: seconds >= 0 or `cycle`."""
    if text.strip().lower() == "cycle":
        return "cycle"
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected seconds (e.g. 0.5) or 'cycle', got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected non-negative seconds, got {text!r}")
    return v


def parse_lag(text: str) -> str | float | None:
    """`--lag`: `fit`, `none` or a rate eta [1/s] of the command filter du/dt = -eta (u - v)."""
    t = text.strip().lower()
    if t in ("fit", "none"):
        return None if t == "none" else "fit"
    try:
        v = float(t)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected 'fit', 'none' or a rate in 1/s, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"the lag rate must be positive (1/s), got {text!r}")
    return v


def parse_degrees(text: str) -> dict[str, int]:
    """`--degrees`: `NAME=DEG,...`, the polynomial degree of each named parameter's law."""
    out: dict[str, int] = {}
    for item in text.split(","):
        name, sep, deg = item.partition("=")
        try:
            d = int(deg)
        except ValueError:
            d = -1
        if not sep or not name.strip() or d < 0:
            raise argparse.ArgumentTypeError(
                f"expected NAME=DEG,... with DEG a non-negative integer, got {item!r}")
        out[name.strip()] = d
    return out


def parse_laws(text: str) -> str | dict[str, str]:
    """`--laws`: `auto` (every law's form chosen by the data), `fixed` (the model's default
    degrees) or `NAME=KIND,...` (KIND `poly`, `exp` or `sat`: checked by `generalize`)."""
    t = text.strip().lower()
    if t in ("auto", "fixed"):
        return t
    out: dict[str, str] = {}
    for item in text.split(","):
        name, sep, kind = item.partition("=")
        if not sep or not name.strip() or not kind.strip():
            raise argparse.ArgumentTypeError(
                f"expected 'auto', 'fixed' or NAME=KIND,... (KIND poly, exp or sat), got "
                f"{item!r}")
        out[name.strip()] = kind.strip().lower()
    return out


# --------------------------------------------------------------------------------------------
# Option groups shared by commands


def add_output_options(parser: argparse.ArgumentParser, command: str, *,
                       no_plots: str | None = "write no PNG figures") -> None:
    """`--out DIR` (default `mrjax-out/COMMAND`), `--overwrite` and, unless `no_plots` is
    None, `--no-plots` (its help): where and what a command writes. A directory holds one
    command's outputs (see `mrjax._io.OutputDir`)."""
    parser.add_argument("--out", default=default_out(command), metavar="DIR",
                        help=f"output directory (default ./{default_out(command)}); it holds "
                        f"the outputs of `mrjax {command}` only, and one run at a time")
    parser.add_argument("--overwrite", action="store_true",
                        help="write into DIR even if another command's outputs or other files "
                        "are there (files mrjax did not write are kept)")
    if no_plots is not None:
        parser.add_argument("--no-plots", action="store_true", help=no_plots)


def add_scale_options(parser: argparse.ArgumentParser, *, journal: bool) -> None:
    """`--memory`, `--devices`, `--cluster` (and for `mrjax fit`, `--chunk-size` and
    `--resume`): how a fit of many tests uses the machine or a cluster; none of them changes
    the results."""
    g = parser.add_argument_group(
        "many tests", "how the fit uses the machine or a cluster; the results do not depend on "
        "these (see 'Thousands of tests' in the README)")
    g.add_argument("--memory", type=memory_size, metavar="SIZE",
                   help="memory budget, e.g. 8GB or 512MB: the tests are fitted in chunks "
                   "whose estimated memory fits it (default: half of the available memory)")
    g.add_argument("--devices", type=device_count, metavar="N|all",
                   help="shard each chunk's tests over the first N local JAX devices, or all "
                   "(default one; on a CPU, set XLA_FLAGS=--xla_force_host_platform_device_"
                   "count=N to expose N devices; with --cluster, each worker's own)")
    g.add_argument("--cluster", metavar="ADDRESS",
                   help="fit the chunks on the Dask cluster of this scheduler, e.g. "
                   "tcp://host:8786, one task per chunk; the workers read their chunks from "
                   "the files; --memory is then per worker thread (default: half of a "
                   "worker's memory limit) (needs pip install 'mrjax[cluster]')")
    if journal:
        g.add_argument("--chunk-size", type=positive_int, metavar="N",
                       help="tests per chunk instead of --memory")
        g.add_argument("--resume", action="store_true",
                       help="reuse the chunks an interrupted run left in DIR/.mrjax-journal "
                       "(same data and options required) and fit only the missing ones")


#: The data flags and the `DataSpec.from_options` argument each one sets.
DATA_FLAGS: dict[str, str] = {
    "columns": "--columns", "wide": "--wide", "sample_rate": "--sample-rate",
    "current": "--current", "frequency": "--frequency", "amplitude": "--amplitude",
    "label": "--label", "velocity_window": "--velocity-window",
}


def add_data_options(parser: argparse.ArgumentParser) -> None:
    """Add the data options (where each signal is, in which unit, and what the files cannot
    say) to a sub-command's parser: `--spec FILE.toml` and the flags of
    `mrjax.data.DataSpec.from_options`, which override single keys of the spec file.

    **Arguments:** `parser`: the sub-command's parser; `mrjax.cli._common.data_spec` reads
    the result.
    """
    g = parser.add_argument_group(
        "data options",
        "How to read files with their own column names, units and layouts (default: each "
        "format's conventions: long CSV with unit-suffixed headers, headerless txt t x v F, "
        "metadata from names like 25mm0x1Hz0x75A). UNIT is any unit of the right dimension "
        "(s, ms; m, mm, cm, in; mm/s, cm/s, in/s; N, kN, lbf; A, mA; V for a command). "
        "The flags override single keys of --spec. Check a spec with `mrjax inspect`.")
    g.add_argument("--spec", metavar="FILE.toml",
                   help="data spec file: [columns], [meta], [wide], [files], [velocity] (see "
                   "the README, 'Your own files')")
    g.add_argument("--columns", metavar="ROLE=SOURCE:UNIT,...",
                   help="where each signal is: ROLE is time, displacement, velocity, force, "
                   "current (measured, per sample), command (per-sample current or voltage), "
                   "frequency, amplitude or condition; SOURCE a CSV header, a .mat variable, "
                   "name[k] (column k, 0-based, of a 2-D .mat variable) or a bare k (column k "
                   "of a headerless text file or of the only .mat matrix); e.g. "
                   "time=t:s,displacement=x:cm,velocity=v:cm/s,force=F:N,command=V:V")
    g.add_argument("--wide", metavar="ROLE=SOURCE,...:UNIT",
                   help="one test per column: the columns of ROLE, one per test, a unit on "
                   "the last one applying to all, e.g. force=1,2,3,4,5:N (several roles: "
                   "separate by ';'); the roles of --columns are shared by all tests")
    g.add_argument("--sample-rate", metavar="HZ",
                   help="sample rate when there is no time column, e.g. 1000 or '1 kHz' "
                   "(or FILE=HZ,...)")
    g.add_argument("--current", metavar="A",
                   help="coil current of the tests: one value (0.5, '500 mA'), one per "
                   "column of --wide (0,0.25,0.5), or per file (FILE=A,...; FILE may be a "
                   "glob pattern, e.g. ensaio.B.1.mat=0.5,ensaio.B.2.mat=1)")
    g.add_argument("--frequency", metavar="HZ",
                   help="excitation frequency, given like --current (default: from the file "
                   "or its name; with data options, else estimated from the displacement "
                   "spectrum and reported as an estimate)")
    g.add_argument("--amplitude", metavar="M",
                   help="displacement amplitude in m or with a unit ('8 mm'), given like "
                   "--current (default: as --frequency; the estimate is half the range)")
    g.add_argument("--label", metavar="NAME",
                   help="test label(s), given like --current (default: the CSV condition "
                   "column or the file name, with _k for the k-th --wide column)")
    g.add_argument("--velocity-window", metavar="SECONDS",
                   help="window of the velocity estimated from displacement (when no velocity "
                   "column is read), e.g. 0.02 or '20 ms' (default: chosen from the bandwidth "
                   "of each record)")


#: The posterior options of `mrjax fit --posterior` and their defaults (None in argparse: given
#: or not is checked), those of `mrjax.bayes.Sampler` (written out: the parser imports no JAX).
POSTERIOR_DEFAULTS = {"draws": 1000, "chains": 4, "warmup": 500, "noise": "iid",
                      "kernel": "nuts"}
#: The sampler kernels `--kernel` names, and each one's defaults of draws, chains and warmup.
KERNELS = {"nuts": (1000, 4, 500), "chees": (500, 8, 300)}


def add_posterior_options(p: argparse.ArgumentParser) -> None:
    """Register `--posterior` and its options on the `mrjax fit` parser."""
    g = p.add_argument_group("posterior (Bayesian identification by NUTS or ChEES-HMC)")
    g.add_argument("--posterior", action="store_true",
                   help="after the fit, sample the posterior of every test's parameters "
                   "(with --generalize: of the laws' coefficients) "
                   "(blackjax) and write posterior.nc, posterior.csv, a 'posterior' "
                   "entry in fit.json and figures")
    g.add_argument("--kernel", metavar="|".join(KERNELS),
                   help="how the chains move: nuts (each chain on its own) or chees "
                   "(ChEES-HMC: every chain of every test in lockstep, one compiled batch) "
                   f"(default {POSTERIOR_DEFAULTS['kernel']})")
    per = lambda i: ", ".join(f"{k} {v[i]}" for k, v in KERNELS.items())
    g.add_argument("--draws", type=int, metavar="N",
                   help=f"draws kept per chain (default: the kernel's, {per(0)})")
    g.add_argument("--chains", type=int, metavar="K",
                   help=f"chains per test (default: the kernel's, {per(1)})")
    g.add_argument("--warmup", type=int, metavar="N",
                   help=f"adaptation steps per chain (default: the kernel's, {per(2)})")
    g.add_argument("--noise", metavar="iid|ar1",
                   help="residual model: iid (default) or ar1 (correlated model error: "
                   "honest intervals on real records)")
    g.add_argument("--posterior-data", metavar="record|view",
                   help="what the likelihood scores: the whole record, or the swarm's "
                   "subsampled view (default: view for the dynamic models, record otherwise)")
    g.add_argument("--prior", action="append", metavar="NAME=KIND:A:B",
                   help="prior of one parameter: normal:MEAN:SD, lognormal:MEDIAN:SIGMA or "
                   "uniform:LO:HI, SI units (repeatable; default flat on the bounds)")
