"""The `mrjax` command line: identify MR damper models from measured tests.

```
mrjax fit DATA... --model kwok [--out DIR]          fit every test, write fit.json/csv + figures
mrjax fit DATA... --model kwok --generalize two-step   ... plus current-dependent laws
mrjax predict --fit DIR/fit.json DATA... [--out DIR]  evaluate the laws on other tests
mrjax reproduce [--quick]                           the paper's study on the embedded data
mrjax models                                        models, parameters, units, default bounds
```

Errors in the input (missing or malformed files, unknown models, bad options, unwritable
output) print one line `mrjax: error: ...` on stderr and exit with code 2; `--debug` shows the
traceback instead. Ctrl-C exits with 130. Outputs are written atomically: all of them or none.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import math
import sys
import warnings
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from . import __version__
from ._errors import InputError

DEFAULT_OUT = "mrjax-out"
_GEN_HINT = "run `mrjax fit DATA... --model NAME --generalize two-step` first"


# --------------------------------------------------------------------------------------------
# Small helpers


def _say(msg: str) -> None:
    """A short stage line on stderr (the table and results go to stdout)."""
    print(f"mrjax: {msg}", file=sys.stderr, flush=True)


def _one_line(e: BaseException) -> str:
    if isinstance(e, OSError) and not isinstance(e, InputError) and e.strerror:
        msg = f"{e.filename}: {e.strerror}" if e.filename else e.strerror
    else:
        msg = str(e) or type(e).__name__
    return " ".join(msg.split())


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def _nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {v}")
    return v


def _transient(text: str) -> float | str:
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


def _bounds(items: list[str] | None, model) -> tuple[dict, dict] | None:
    """`--bounds NAME=LO:HI` options (an empty LO or HI keeps the default) as checked
    `(lower, upper)` dicts for `mrjax.fit`, or None."""
    if not items:
        return None
    from .pso import check_bounds

    lower: dict[str, float] = {}
    upper: dict[str, float] = {}
    seen: set[str] = set()
    for item in items:
        name, eq, rng = item.partition("=")
        lo, colon, hi = rng.partition(":")
        name = name.strip()
        if not (eq and colon and name):
            raise InputError(f"--bounds {item!r}: expected NAME=LO:HI, e.g. c=500:5000")
        if name in seen:
            raise InputError(f"--bounds: parameter {name!r} given twice")
        seen.add(name)
        for side, text, d in (("LO", lo, lower), ("HI", hi, upper)):
            if text.strip():
                try:
                    d[name] = float(text)
                except ValueError:
                    raise InputError(f"--bounds {item!r}: {side} is not a number: "
                                     f"{text.strip()!r}") from None
    try:
        check_bounds(model, (lower, upper))
    except InputError as e:
        raise InputError(f"--bounds: {e}") from None
    return lower, upper


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line `mrjax: warning: ...` on stderr."""
    print(f"mrjax: warning: {' '.join(str(message).split())}", file=sys.stderr, flush=True)


def _json_safe(obj: Any) -> Any:
    """Plain JSON values: NumPy scalars/arrays to Python, NaN and inf to None."""
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _json_safe(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


def _dumps(doc: dict) -> bytes:
    return (json.dumps(_json_safe(doc), indent=1, allow_nan=False) + "\n").encode()


def _load_batch(paths: list[str]):
    """Expand files/directories, say how many, load them into one padded batch."""
    from .data import load, make_batch
    from .data._loaders import _expand

    files = _expand(paths)
    _say(f"loading {len(files)} file{'s' if len(files) != 1 else ''}...")
    return make_batch(load(files))


def _module(name: str):
    """The module `name` if this installation has it, else None (errors inside it propagate)."""
    if name not in sys.modules and importlib.util.find_spec(name) is None:
        return None
    return importlib.import_module(name)


def _import_generalize():
    """`mrjax.generalize`, or an InputError if this installation does not have it yet."""
    mod = _module("mrjax.generalize")
    if mod is None:
        raise InputError("current-dependent models (mrjax.generalize) are not available in "
                         "this version of mrjax")
    return mod


def _use_agg() -> None:
    import matplotlib

    matplotlib.use("Agg")


def _png(fig) -> bytes:
    from .report import save_png_bytes

    return save_png_bytes(fig)


# --------------------------------------------------------------------------------------------
# fit


def _fit_figures(result, batch, gm) -> dict[str, bytes]:
    _use_agg()
    from . import report as rp

    out = {
        "loops.png": _png(rp.plot_loops_grid(result, batch)),
        "rms_vs_current.png": _png(rp.plot_rms_vs_current(result)),
        "params_vs_current.png": _png(rp.plot_params_vs_current(result, laws=gm)),
    }
    if result.method in ("pso", "pso+lm"):
        out["generations_vs_current.png"] = _png(rp.plot_generations_vs_current(result))
        out["convergence.png"] = _png(rp.plot_convergence(result))
    if result.method == "pso+lm":
        out["pso_vs_polish.png"] = _png(rp.plot_pso_vs_polish(result))
    return out


def _cmd_fit(args: argparse.Namespace) -> int:
    from ._io import atomic_output, check_writable
    from .fit import fit
    from .models import get

    out = check_writable(args.out)
    model = get(args.model)
    if args.generations is not None and args.max_generations is not None:
        raise InputError("give --generations (a fixed count) or --max-generations (a cap), "
                         "not both")
    bounds = _bounds(args.bounds, model)
    gen_mod = _import_generalize() if args.generalize else None

    batch = _load_batch(args.files)
    C = batch.n_conditions
    how = args.method if args.method == "lm" else f"{args.method}, {args.swarm} swarm"
    _say(f"fitting {model.name} on {C} condition{'s' if C != 1 else ''} ({how})...")
    result = fit(
        model, batch, method=args.method, swarm=args.swarm, seed=args.seed,
        n_particles=args.particles,
        max_generations=args.max_generations if args.max_generations is not None else 200,
        generations=args.generations, transient=args.transient, progress=None, bounds=bounds,
        swarm_dtype=args.swarm_dtype, restarts=args.restarts,
    )

    gm = None
    if gen_mod is not None:
        _say(f"fitting current-dependent laws ({args.generalize})...")
        kw: dict[str, Any] = {"seed": args.seed}
        if args.transient is not None:  # score the laws on the samples the fit scored
            from .objective import fit_mask

            kw["mask"] = fit_mask(batch, args.transient)
        gm = gen_mod.generalize(result, batch, method=args.generalize, **kw)
        doc = result.to_dict()
        doc["generalized"] = gm.to_dict()
        files = {"fit.json": _dumps(doc)}
    else:
        files = {"fit.json": result.to_json().encode()}
    files["fit.csv"] = result.to_csv().encode()
    if not args.no_plots:
        _say("drawing figures...")
        files.update(_fit_figures(result, batch, gm))

    _say(f"writing {len(files)} files to {out}...")
    atomic_output(out, files)
    print(result.table())
    if gm is not None:
        print()
        print(gm.summary() if hasattr(gm, "summary") else gm)
    return 0


# --------------------------------------------------------------------------------------------
# predict


def _read_fit_json(path: str) -> dict:
    p = Path(path).expanduser()
    if p.is_dir():
        p = p / "fit.json"
    if not p.is_file():
        raise InputError(f"{path}: no such file (expected a fit.json written by `mrjax fit`)")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a fit.json (not UTF-8 text)") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: not valid JSON (line {e.lineno}, column {e.colno}: "
                         f"{e.msg})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: not a fit.json (expected a JSON object)")
    return doc


def _metrics(ev: Any, C: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-condition (RMS [N], NRMSE) from what `GeneralizedModel.evaluate` returns: a pair,
    a mapping or an object with `rms`/`rms_N` and `nrmse`."""
    def pick(names):
        for n in names:
            if isinstance(ev, dict) and n in ev:
                return ev[n]
            if not isinstance(ev, dict) and hasattr(ev, n):
                return getattr(ev, n)
        return None

    rms, nrmse = pick(("rms", "rms_N")), pick(("nrmse",))
    if rms is None and isinstance(ev, (tuple, list)) and len(ev) == 2:
        rms, nrmse = ev
    if rms is None or nrmse is None:
        raise TypeError(f"unexpected result of GeneralizedModel.evaluate: {type(ev).__name__}")
    rms, nrmse = np.asarray(rms, float).reshape(-1), np.asarray(nrmse, float).reshape(-1)
    if rms.shape != (C,) or nrmse.shape != (C,):
        raise TypeError(f"GeneralizedModel.evaluate gave shapes {rms.shape}, {nrmse.shape} "
                        f"for {C} conditions")
    return rms, nrmse


def _predict_rows(batch, rms, nrmse) -> list[dict]:
    def opt(v):
        v = float(v)
        return v if math.isfinite(v) else None

    cur, freq, amp = (np.asarray(getattr(batch, k), float) for k in
                      ("current", "frequency", "amplitude"))
    n = np.asarray(batch.n_samples)
    return [{"label": batch.labels[i], "current_A": opt(cur[i]), "frequency_Hz": opt(freq[i]),
             "amplitude_m": opt(amp[i]), "n_samples": int(n[i]), "rms_N": opt(rms[i]),
             "nrmse": opt(nrmse[i])} for i in range(batch.n_conditions)]


def _predict_csv(rows: list[dict]) -> str:
    from .fit import _csv_cell

    cols = list(rows[0])
    lines = [",".join(cols)]
    lines += [",".join(_csv_cell(np.nan if r[c] is None else r[c]) for c in cols) for r in rows]
    return "\n".join(lines) + "\n"


def _predict_table(rows: list[dict], model: str) -> str:
    from .report import format_table

    def num(v, scale=1.0):
        return None if v is None else v * scale

    body = [[r["label"], num(r["current_A"]), num(r["frequency_Hz"]), num(r["amplitude_m"], 1e3),
             num(r["rms_N"]), num(r["nrmse"], 100.0)] for r in rows]
    table = format_table(body, ["condition", "I[A]", "f[Hz]", "A[mm]", "RMS[N]", "NRMSE%"],
                         floatfmt=["", ".3g", ".3g", ".3g", ".2f", ".2f"])
    rms = np.array([np.nan if r["rms_N"] is None else r["rms_N"] for r in rows])
    med = np.nanmedian(rms) if np.any(np.isfinite(rms)) else float("nan")
    return table + (f"\ngeneralized {model}: {len(rows)} conditions, median RMS {med:.2f} N")


def _cmd_predict(args: argparse.Namespace) -> int:
    from ._io import atomic_output, check_writable

    out = check_writable(args.out)
    doc = _read_fit_json(args.fit)
    if "generalized" not in doc:
        raise InputError(f"{args.fit}: this fit has no current-dependent laws ('generalized' "
                         f"block); {_GEN_HINT}")
    gen_mod = _import_generalize()
    try:
        gm = gen_mod.GeneralizedModel.from_dict(doc["generalized"])
    except InputError as e:
        raise InputError(f"{args.fit}: {e}") from None
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{args.fit}: cannot read the 'generalized' block ({e!r})") from None
    model = str(doc.get("model", "model"))

    batch = _load_batch(args.files)
    C = batch.n_conditions
    _say(f"predicting {C} condition{'s' if C != 1 else ''} with the generalized {model}...")
    ev = gm.evaluate(batch)
    rms, nrmse = _metrics(ev, C)
    pred = ev.get("predicted") if isinstance(ev, dict) else None
    force = np.asarray(gm.predict(batch) if pred is None else pred, float)
    rows = _predict_rows(batch, rms, nrmse)
    report = {"fit": str(args.fit), "model": model, "mrjax_version": __version__,
              "median_rms_N": float(np.nanmedian(rms)) if np.any(np.isfinite(rms)) else None,
              "conditions": rows}
    files = {"predict.json": _dumps(report), "predict.csv": _predict_csv(rows).encode()}
    if not args.no_plots:
        _say("drawing figures...")
        _use_agg()
        from . import report as rp

        title = f"generalized {model}: measured vs predicted loops"
        files["predict_loops.png"] = _png(
            rp.plot_loops_grid(gm, batch, force=force, rms=rms, title=title))
        pts = SimpleNamespace(current=batch.current, frequency=batch.frequency,
                              amplitude=batch.amplitude, rms=rms, labels=batch.labels)
        files["predict_rms_vs_current.png"] = _png(
            rp.plot_rms_vs_current({f"generalized {model}": pts}))
    _say(f"writing {len(files)} files to {out}...")
    atomic_output(out, files)
    print(_predict_table(rows, model))
    return 0


# --------------------------------------------------------------------------------------------
# reproduce, models


def _cmd_reproduce(args: argparse.Namespace) -> int:
    reproduce = _module("mrjax.reproduce")
    if reproduce is None:
        print("mrjax reproduce: not yet available in this version of mrjax.")
        return 0
    code = reproduce.run(args.out, quick=args.quick, data=args.data, seed=args.seed)
    return int(code or 0)


def _cmd_models(args: argparse.Namespace) -> int:
    from .models import get, names
    from .report import format_table

    style = "markdown" if args.markdown else "plain"
    blocks = []
    for name in names():
        m = get(name)
        lo, hi = m.bounds
        lin = set(m.linear_params)
        rows = [[p, u, float(a), float(b), p in lin]
                for p, u, a, b in zip(m.param_names, m.units, lo, hi)]
        kind = "ODE (internal state)" if m.dynamic else "memoryless"
        head = f"{name}  [{kind}]  {m.description}".rstrip()
        if args.markdown:
            head = f"### {name}\n\n{m.description} ({kind})\n"
        blocks.append(head + "\n" + format_table(
            rows, ["parameter", "unit", "lower", "upper", "linear"], style=style, floatfmt="g"))
    print("\n\n".join(blocks))
    return 0


# --------------------------------------------------------------------------------------------
# Parser and entry point


def _parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true",
                        help="show the full traceback of errors instead of one line")

    parser = argparse.ArgumentParser(
        prog="mrjax", description="Identify magnetorheological damper models (Kwok et al. 2006) "
        "with a batched JAX particle swarm and a Levenberg-Marquardt polish.",
        epilog="Run `mrjax COMMAND --help` for the options of a command.")
    parser.add_argument("--version", action="version", version=f"mrjax {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser(
        "fit", parents=[common], help="identify a model on every test condition",
        description="Fit one model to every test in the given files at once and write fit.json, "
        "fit.csv and figures into --out (atomically: all files or none).")
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="data files or directories (.csv long format, .txt/.dat UTFSM-style "
                   "columns t x v F, .mat)")
    p.add_argument("--model", required=True, metavar="NAME",
                   help="model name: bingham, kwok (tanh), bouc_wen, modified_bouc_wen, dahl "
                   "(see `mrjax models`)")
    p.add_argument("--method", choices=("pso", "pso+lm", "lm"), default="pso+lm",
                   help="swarm, swarm then Levenberg-Marquardt polish (default), or polish alone")
    p.add_argument("--swarm", choices=("separable", "full"), default="separable",
                   help="separable: variable projection over the linear parameters (default); "
                   "full: the paper's swarm over all parameters")
    p.add_argument("--restarts", type=_positive_int, default=1, metavar="K",
                   help="independent swarms per test, best one polished (default 1)")
    p.add_argument("--swarm-dtype", choices=("float64", "float32"), default=None,
                   help="precision of the swarm's search (default float64; float32 is about "
                   "twice as fast; the polish and the results stay float64)")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="random seed (default 0)")
    p.add_argument("--generations", type=_positive_int, metavar="N",
                   help="run exactly N swarm generations (no statistical stop)")
    p.add_argument("--max-generations", type=_positive_int, metavar="N",
                   help="cap on swarm generations with the statistical stop (default 200)")
    p.add_argument("--particles", type=_positive_int, default=50, metavar="N",
                   help="swarm size (default 50)")
    p.add_argument("--transient", type=_transient, metavar="SECONDS|cycle",
                   help="leave an initial span out of the fitness: seconds or 'cycle'")
    p.add_argument("--bounds", action="append", metavar="NAME=LO:HI",
                   help="search bounds of one parameter in SI units, e.g. c=500:5000 (repeatable; "
                   "an empty LO or HI keeps the default; see `mrjax models`)")
    p.add_argument("--generalize", choices=("two-step", "joint"),
                   help="also fit current-dependent laws of the parameters")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default ./{DEFAULT_OUT})")
    p.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    p.set_defaults(func=_cmd_fit)

    p = sub.add_parser(
        "predict", parents=[common], help="evaluate fitted current-dependent laws on tests",
        description="Predict the force of other tests from the current-dependent laws in a "
        "fit.json written by `mrjax fit --generalize`; write predict.json, predict.csv and "
        "figures.")
    p.add_argument("--fit", required=True, metavar="FIT.json",
                   help="fit.json of `mrjax fit --generalize` (or its directory)")
    p.add_argument("files", nargs="+", metavar="FILE", help="data files or directories")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default ./{DEFAULT_OUT})")
    p.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    p.set_defaults(func=_cmd_predict)

    p = sub.add_parser("reproduce", parents=[common],
                       help="reproduce the paper's study on the embedded data",
                       description="Reproduce the study of Kwok et al. (2006).")
    p.add_argument("--quick", action="store_true", help="a small, fast version")
    p.add_argument("--data", metavar="DIR", help="measured data directory (default: embedded)")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default ./{DEFAULT_OUT})")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="random seed (default 0)")
    p.set_defaults(func=_cmd_reproduce)

    p = sub.add_parser("models", parents=[common],
                       help="list models with parameters, units and default bounds")
    p.add_argument("--markdown", action="store_true", help="markdown tables")
    p.set_defaults(func=_cmd_models)
    return parser


#: Environment variable naming the persistent XLA compilation cache of the `mrjax` command
#: (default `~/.cache/mrjax/xla`; `off` disables it).
CACHE_ENV = "MRJAX_CACHE_DIR"


def _enable_compilation_cache() -> str | None:
    """Point JAX's persistent compilation cache at `$MRJAX_CACHE_DIR` (default
    `~/.cache/mrjax/xla`) unless the user configured one (`JAX_COMPILATION_CACHE_DIR`) or set
    `MRJAX_CACHE_DIR=off`. A repeated `mrjax fit` then loads its compiled programs instead of
    compiling them (the cold 36-test fit: 10.5 s -> 6.3 s; see benchmarks/results.md). The
    directory is JAX's own cache format; delete it to reclaim the space (a few MB per model
    and data shape). (`jax_compilation_cache_max_size` is left unset: with jax 0.10.2 setting
    it stopped every write, measured.)
    Returns the directory in use, or None. Never fails: an unusable directory only means no
    cache."""
    import os

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
    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # usage errors (2), --help and --version (0)
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    debug = bool(getattr(args, "debug", False))
    if getattr(args, "command", None) in ("fit", "predict", "reproduce"):
        _enable_compilation_cache()
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return int(args.func(args))
    except BrokenPipeError:  # e.g. `mrjax models | head`: stop quietly, like other tools
        try:
            import os

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
        print(f"mrjax: error: {_one_line(e)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
