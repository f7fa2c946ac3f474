"""The parser of the `mrjax` command and its entry point."""

from __future__ import annotations

import argparse
import os
import sys
import warnings

from .. import __version__
from .._errors import InputError
from . import _compare, _fit, _inspect, _misc, _predict
from ._common import one_line, show_warning

#: Environment variable naming the persistent XLA compilation cache of the `mrjax` command
#: (default `~/.cache/mrjax/xla`; `off` disables it).
CACHE_ENV = "MRJAX_CACHE_DIR"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the `mrjax` command (all sub-commands)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true",
                        help="show the full traceback of errors instead of one line")
    parser = argparse.ArgumentParser(
        prog="mrjax", description="Identify magnetorheological damper models (Kwok et al. 2006) "
        "with a batched JAX particle swarm and a Levenberg-Marquardt polish.",
        epilog="Run `mrjax COMMAND --help` for the options of a command.")
    parser.add_argument("--version", action="version", version=f"mrjax {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    _fit.add_parser(sub, common)
    _predict.add_parser(sub, common)
    _compare.add_parser(sub, common)
    _inspect.add_parser(sub, common)
    _misc.add_parsers(sub, common)
    return parser


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
    if getattr(args, "command", None) in ("fit", "predict", "reproduce", "compare"):
        enable_compilation_cache()
    try:
        with warnings.catch_warnings():
            warnings.showwarning = show_warning
            return int(args.func(args))
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
