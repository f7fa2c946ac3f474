"""Timing and environment helpers shared by the benchmark sections.

Every comparison is timed in one process, on the same data and work. A timed callable is run
once as a warm-up (for JAX: trace + compile + first run, reported as `first_s`; the compile time
is `first_s - median_s`), then `repeats` more times; the median and the minimum are reported.
The machine may be shared, so the load average is recorded around every section and the
ratios (taken within one process, interleaved where cheap) are the numbers to quote.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata as md
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

#: The benchmarks directory (results.md, results.json and the PNGs are written here).
HERE = Path(__file__).resolve().parent
REPO = HERE.parent


def default_data_dir() -> Path | None:
    """The UTFSM tests: `$MRJAX_DATA` if set (used as given, so that a wrong setting fails when
    loaded), else the first `shared/data/utfsm` found in the working directory's parent or in a
    parent of this checkout, else None."""
    if os.environ.get("MRJAX_DATA"):
        return Path(os.environ["MRJAX_DATA"]).expanduser()
    found = [p / "shared" / "data" / "utfsm" for p in (Path.cwd().parent, REPO, *REPO.parents)]
    return next((d.resolve() for d in found if d.is_dir()), None)


def log(msg: str) -> None:
    """Progress on stderr with the time of day."""
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def block(x):
    """Wait for JAX results (no-op for host values)."""
    import jax  # here, not at the top: `render` (via fmt_s, md_table) must not need JAX

    return jax.block_until_ready(x)


@dataclasses.dataclass
class Timing:
    """Wall-clock seconds of one benchmarked callable."""

    name: str
    first_s: float
    times_s: list[float]
    cpu_s: list[float]
    note: str = ""

    @property
    def median_s(self) -> float:
        return float(np.median(self.times_s)) if self.times_s else float(self.first_s)

    @property
    def min_s(self) -> float:
        return float(np.min(self.times_s)) if self.times_s else float(self.first_s)

    @property
    def compile_s(self) -> float:
        """First call minus the warm median: tracing + XLA compilation (+ one-off setup)."""
        return max(self.first_s - self.median_s, 0.0) if self.times_s else float("nan")

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "first_s": self.first_s,
            "median_s": self.median_s,
            "min_s": self.min_s,
            "compile_s": self.compile_s,
            "times_s": self.times_s,
            "cpu_median_s": float(np.median(self.cpu_s)) if self.cpu_s else None,
            "repeats": len(self.times_s),
            "note": self.note,
        }


def _once(fn: Callable[[], Any]) -> tuple[float, float]:
    c0 = time.process_time()
    t0 = time.perf_counter()
    block(fn())
    return time.perf_counter() - t0, time.process_time() - c0


def timeit(
    name: str, fn: Callable[[], Any], repeats: int = 3, *, warmup: bool = True, note: str = ""
) -> Timing:
    """Warm-up call (timed as `first_s`), then `repeats` timed calls."""
    first = _once(fn)[0] if warmup else float("nan")
    times, cpus = [], []
    for _ in range(repeats):
        t, c = _once(fn)
        times.append(t)
        cpus.append(c)
    return Timing(name, first, times, cpus, note)


def interleaved(
    fns: dict[str, Callable[[], Any]],
    repeats: int = 3,
    *,
    warmup: bool = True,
    notes: dict[str, str] | None = None,
) -> dict[str, Timing]:
    """Time several callables round-robin (a warm-up each first), so that a change in the
    machine's load affects all of them alike."""
    notes = notes or {}
    first = {k: (_once(f)[0] if warmup else float("nan")) for k, f in fns.items()}
    times: dict[str, list[float]] = {k: [] for k in fns}
    cpus: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeats):
        for k, f in fns.items():
            t, c = _once(f)
            times[k].append(t)
            cpus[k].append(c)
    return {k: Timing(k, first[k], times[k], cpus[k], notes.get(k, "")) for k in fns}


def loadavg() -> list[float]:
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:  # pragma: no cover
        return []


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _cpu_flags() -> list[str]:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    fl = line.split(":", 1)[1].split()
                    return sorted(x for x in fl if x.startswith(("avx", "fma", "sse4")))
    except OSError:
        pass
    return []


def _version(pkg: str) -> str | None:
    try:
        return md.version(pkg)
    except md.PackageNotFoundError:
        return None


def environment() -> dict[str, Any]:
    """CPU, cores, accelerator and package versions of this run."""
    import jax  # as in `block`

    devs = jax.devices()
    gpus = [str(d) for d in devs if d.platform != "cpu"]
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        affinity = os.cpu_count()
    try:
        mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError):  # pragma: no cover
        mem = float("nan")
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            cwd=os.path.dirname(__file__),
        ).stdout.strip()
    except OSError:  # pragma: no cover
        commit = ""
    return {
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "cpu_model": _cpu_model(),
        "cpu_simd_flags": _cpu_flags(),
        "cpu_count": os.cpu_count(),
        "cpu_affinity": affinity,
        "memory_GiB": round(mem, 1),
        "gpu": gpus or "none",
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in devs],
        "platform": platform.platform(),
        "python": sys.version.split()[0],
        "versions": {
            p: _version(p)
            for p in (
                "jax",
                "jaxlib",
                "numpy",
                "scipy",
                "pyswarms",
                "evosax",
                "equinox",
                "optimistix",
                "matplotlib",
                "mrjax",
            )
        },
        "jax_enable_x64": bool(jax.config.jax_enable_x64),
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
        "git_commit": commit,
        "loadavg_start": loadavg(),
    }


def fmt_s(s: float) -> str:
    """Seconds, human readable."""
    if s != s:  # NaN
        return "-"
    if s >= 100:
        return f"{s:.0f} s"
    if s >= 1:
        return f"{s:.2f} s"
    if s >= 1e-3:
        return f"{s * 1e3:.1f} ms"
    return f"{s * 1e6:.0f} us"


def md_table(head: list[str], rows: list[list[Any]]) -> str:
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)
