"""Section 5, `cold`: `mrjax fit --no-plots` as a cold process against a pyswarms script
process on the same CSV, and where a cold mrjax process spends its time."""

from __future__ import annotations

import importlib.util
import json
import os
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mrjax.data import paper_grid
from mrjax.models import get

from ._common import HERE, REPO, log

_BREAKDOWN = r"""
import json, sys, time
t0 = time.perf_counter()
import mrjax
from mrjax.cli import enable_compilation_cache
from mrjax.data import as_batch
from mrjax.fitting import save
enable_compilation_cache()  # as the `mrjax` command does ($MRJAX_CACHE_DIR; off: none)
t1 = time.perf_counter()
batch = as_batch(sys.argv[1])
t2 = time.perf_counter()
r = mrjax.fit("kwok", batch, key=0)
t3 = time.perf_counter()
save(r, sys.argv[2])
t4 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "load_s": t2 - t1, "fit_s": t3 - t2, "save_s": t4 - t3,
                  "fit_stages_s": r.timings}))
"""

_COLD = "mrjax fit (cold, no cache)"
_SCRIPT = "pyswarms script"
_WARM = "mrjax fit (persistent compilation cache warm)"


def write_csv(batch, path) -> None:
    """Long-format CSV that `mrjax.data.load_csv` (and the pyswarms script) read."""
    cols = [
        "condition",
        "current_A",
        "frequency_Hz",
        "amplitude_m",
        "time_s",
        "displacement_m",
        "velocity_m_s",
        "force_N",
    ]
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for c in batch.conditions():
            meta = f"{c.label},{float(c.current)!r},{float(c.frequency)!r},{float(c.amplitude)!r}"
            for j in range(c.n_samples):
                f.write(
                    f"{meta},{float(c.t[j])!r},{float(c.x[j])!r},{float(c.xdot[j])!r},"
                    f"{float(c.force[j])!r}\n"
                )


def _run(cmd, env=None) -> float:
    """Wall time [s] of the process `cmd`; raises if it fails."""
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO)
    dt = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({p.returncode}): {p.stderr[-2000:]}")
    return dt


def _script_bounds_match_mrjax() -> bool:
    spec = importlib.util.spec_from_file_location("pyswarms_script", HERE / "pyswarms_script.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    lo, hi = get("kwok").bounds
    return bool(np.array_equal(script.LOWER, lo) and np.array_equal(script.UPPER, hi))


def _rounds(n: int, mr_cmd, ps_cmd, env, cache_env) -> tuple[dict[str, list[float]], float]:
    """`n` interleaved rounds of the three processes, after one run that fills the cache."""
    runs: dict[str, list[float]] = {_COLD: [], _SCRIPT: [], _WARM: []}
    log("cold: priming the persistent compilation cache")
    prime = _run(mr_cmd, cache_env)
    for i in range(n):
        log(f"cold: round {i + 1}/{n}")
        runs[_COLD].append(_run(mr_cmd, env))
        runs[_SCRIPT].append(_run(ps_cmd, env))
        runs[_WARM].append(_run(mr_cmd, cache_env))
    return runs, prime


def _breakdown(tmp: Path, csv: Path, env, key: str) -> dict | str:
    """Import, load, fit (by stage) and save times of one process (its stderr if it fails);
    it saves into `tmp / key`."""
    bd = tmp / "breakdown.py"
    bd.write_text(_BREAKDOWN)
    p = subprocess.run(
        [sys.executable, str(bd), str(csv), str(tmp / key)],
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO,
    )
    return json.loads(p.stdout.strip().splitlines()[-1]) if p.returncode == 0 else p.stderr[-1000:]


def _warm_cache_profile(tmp: Path, mr_cmd, cache_env) -> dict:
    """A warm-cache process under cProfile: how much of it is JAX tracing."""
    prof = tmp / "warm.prof"
    _run([sys.executable, "-m", "cProfile", "-o", str(prof), *mr_cmd[1:]], cache_env)
    st = pstats.Stats(str(prof)).stats
    total = max(v[3] for v in st.values())
    trace = sum(v[3] for (f, _, name), v in st.items()
                if name == "trace_to_jaxpr" and f.endswith("partial_eval.py"))
    return {"process_s_under_cprofile": total, "tracing_s": trace,
            "tracing_fraction": trace / total}


def _import_jax_s(env) -> float:
    p = subprocess.run(
        [
            sys.executable,
            "-c",
            "import time; t=time.perf_counter(); import jax; print(time.perf_counter()-t)",
        ],
        capture_output=True,
        text=True,
        env=env,
    )
    return float(p.stdout.strip() or "nan")


def section_cold(cfg) -> dict:
    out: dict = {"script_bounds_match_mrjax": _script_bounds_match_mrjax()}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        csv = tmp / "grid.csv"
        write_csv(paper_grid(), csv)
        env = dict(os.environ, MPLBACKEND="Agg", MRJAX_CACHE_DIR="off")
        env.pop("JAX_COMPILATION_CACHE_DIR", None)
        mr_cmd = [sys.executable, "-m", "mrjax.cli", "fit", str(csv), "--model", "kwok",
                  "--no-plots", "--out", str(tmp / "mr")]
        ps_cmd = [sys.executable, str(HERE / "pyswarms_script.py"), str(csv), "--out",
                  str(tmp / "ps")]
        cache_env = dict(
            env,
            MRJAX_CACHE_DIR=str(tmp / "jax-cache"),
            JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
            JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0",
        )
        runs, prime = _rounds(cfg.cold_repeats, mr_cmd, ps_cmd, env, cache_env)
        out["runs_s"] = runs
        out["cache_priming_run_s"] = prime
        m = out["median_s"] = {k: float(np.median(v)) for k, v in runs.items()}
        for key, e in (("breakdown", env), ("breakdown_warm_cache", cache_env)):
            out[key] = _breakdown(tmp, csv, e, key)
        out["warm_cache_profile"] = _warm_cache_profile(tmp, mr_cmd, cache_env)
        out["import_jax_s"] = _import_jax_s(env)
        out["ratios"] = {
            "pyswarms script / mrjax fit (cold)": m[_SCRIPT] / m[_COLD],
            "pyswarms script / mrjax fit (warm cache)": m[_SCRIPT] / m[_WARM],
        }
        out["command"] = " ".join(mr_cmd[1:]).replace(str(tmp), "$TMP")
        out["pyswarms_command"] = " ".join(ps_cmd[1:]).replace(str(tmp), "$TMP")
    return out
