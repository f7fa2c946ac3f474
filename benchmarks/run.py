"""The mrjax benchmark suite: `python -m benchmarks [--quick] [--only SECTION ...]`.

Sections (the standard work is the paper grid: 36 conditions x 50 particles x 2000 samples,
`mrjax.data.paper_grid()`, 1 kHz, 2 cycles, the 2 Hz tests padded from 1000 to 2000 samples):

1. `tanh` (`tanh_swarm.py`): the tanh model, 100 fixed generations. mrjax (full and separable
   swarm, float64 and float32), pyswarms, SciPy differential evolution, evosax, and the bare
   fitness kernel x 100.
2. `ode` (`ode_models.py`): Bouc-Wen and modified Bouc-Wen, one swarm generation: mrjax, the
   bare `lax.scan` fitness kernel, and a NumPy RK4 (same sub-steps and interpolation).
3. `polish` (`polish.py`): swarm alone vs swarm + Levenberg-Marquardt polish vs polish alone:
   RMS/sigma against wall time (tanh and Bouc-Wen), `polish.png`.
4. `scaling` (`scaling.py`): time per generation against conditions, particles and samples
   (log-log PNG, fitted slopes).
5. `cold` (`cold.py`): `mrjax fit --no-plots` as a cold process against a pyswarms script
   process.

Writes `benchmarks/results.md` (`render.py`), `benchmarks/results.json` and the PNGs beside
them.
"""

from __future__ import annotations

import argparse
import json
import time
import traceback
from pathlib import Path

from ._common import HERE, environment, loadavg, log
from ._work import DTYPES
from .cold import section_cold
from .ode_models import section_ode
from .polish import section_polish
from .render import render
from .scaling import section_scaling
from .tanh_swarm import section_tanh


class Config:
    """Repeats and sweep sizes of a full or a `--quick` run, and where the PNGs go."""

    def __init__(self, quick: bool, out: Path = HERE):
        self.quick = quick
        self.out = Path(out)
        self.repeats = 3 if quick else 5
        self.repeats_slow = 2 if quick else 3
        self.de_conditions = 2 if quick else 6
        self.ode_generations = 3 if quick else 5
        self.scaling_generations = 6 if quick else 8
        self.scaling_repeats = 1
        self.cold_repeats = 1 if quick else 2
        if quick:
            self.sweeps = {"C": [1, 36, 200], "N": [10, 50, 300], "T": [500, 2000, 8000]}
            self.scaling_dtypes = {"float64": None}
        else:
            self.sweeps = {
                "C": [1, 10, 36, 100, 300, 1000],
                "N": [10, 30, 100, 300, 1000],
                "T": [500, 1000, 2000, 5000, 20000],
            }
            self.scaling_dtypes = DTYPES


SECTIONS = {
    "tanh": section_tanh,
    "ode": section_ode,
    "polish": section_polish,
    "scaling": section_scaling,
    "cold": section_cold,
}


def _write(out: Path, results: dict) -> None:
    (out / "results.json").write_text(json.dumps(results, indent=1, default=float))
    (out / "results.md").write_text(render(results))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--quick", action="store_true", help="reduced repeats and sweeps")
    ap.add_argument(
        "--only",
        nargs="+",
        choices=list(SECTIONS),
        help="run only these sections (merged into an existing results.json)",
    )
    ap.add_argument("--out", default=str(HERE), help="directory for results.md/.json/PNGs")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = Config(args.quick, out)
    results: dict = {}
    jpath = out / "results.json"
    if args.only and jpath.exists():
        results = json.loads(jpath.read_text())
    results.update(quick=args.quick, environment=environment())
    results.setdefault("errors", {})
    for name in args.only or SECTIONS:
        log(f"section {name}")
        la = loadavg()
        t0 = time.perf_counter()
        try:
            results[name] = SECTIONS[name](cfg)
            results["errors"].pop(name, None)
        except Exception as e:  # keep going; record it
            traceback.print_exc()
            results["errors"][name] = f"{type(e).__name__}: {e}"
            continue
        results[name]["section_wall_s"] = time.perf_counter() - t0
        results[name]["loadavg_before_after"] = [la, loadavg()]
        _write(out, results)
    results["environment"]["loadavg_end"] = loadavg()
    _write(out, results)
    log(f"wrote {out / 'results.md'} and {jpath}")
    return 1 if results["errors"] else 0
