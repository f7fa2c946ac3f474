"""Thousands of tests: wall time and peak memory of `mrjax.fit` against the number of tests.

    python -m benchmarks.scale_conditions [--sizes 36,360,3600,10000] [--memory 8GB]
                                          [--method pso]

The tanh model (`kwok`; separable swarm, no polish by default: `--method pso`) on copies of
the paper grid, each copy with its own noise (seed = copy index), every
record 2,000 samples (the 1 Hz tests 2 cycles, the 2 Hz tests 4, at 1 kHz), under a memory
budget (`max_memory`, default 8 GB). Each size runs in a fresh process, which reports its own
peak RSS (`getrusage(RUSAGE_SELF).ru_maxrss`: everything, i.e. the interpreter, JAX, the
data, its generation and the fit) and the wall times of building the data and of the fit
(compilation included: each process starts cold, without the persistent cache). Writes
`benchmarks/scale_conditions.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def batch_of(n: int):
    """`n` tanh tests of 2,000 samples: copies of the paper grid with their own noise."""
    from mrjax.data import PAPER_MOTIONS, make_batch, paper_grid

    conds, copy = [], 0
    while len(conds) < n:
        for f, cycles in ((1.0, 2.0), (2.0, 4.0)):
            motions = tuple(m for m in PAPER_MOTIONS if m[0] == f)
            conds += paper_grid(motions=motions, cycles=cycles, seed=copy).conditions()
        copy += 1
    return make_batch(conds[:n])


def child(n: int, memory: str, method: str) -> dict:
    """One size, in this (fresh) process."""
    import jax
    import numpy as np

    import mrjax

    t0 = time.perf_counter()
    batch = batch_of(n)
    t_data = time.perf_counter() - t0
    data_bytes = sum(np.asarray(a).nbytes for a in jax.tree.leaves(batch) if hasattr(a, "shape"))
    polish = None if method == "pso" else mrjax.Polish()
    chunks = mrjax.Chunks(max_memory=memory)
    plan = mrjax.fitting.chunk_plan("kwok", batch, polish=polish, chunks=chunks)
    t1 = time.perf_counter()
    res = mrjax.fit("kwok", batch, polish=polish, key=0, chunks=chunks)
    t_fit = time.perf_counter() - t1
    truth_rms = 20.0  # the noise of the simulated data [N]
    return {"conditions": n, "samples": int(batch.length), "method": method, "memory": memory,
            "data_s": t_data, "fit_s": t_fit, "data_bytes": int(data_bytes),
            "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
            "median_rms_N": float(np.median(res.rms)), "noise_N": truth_rms,
            "max_rms_N": float(np.max(res.rms)), "timings": res.timings,
            "chunk": {"size": plan.size, "n_chunks": plan.n_chunks,
                      "per_condition_bytes": plan.per_condition, "resident_bytes": plan.resident}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="36,360,3600,10000")
    ap.add_argument("--memory", default="8GB")
    ap.add_argument("--method", default="pso", choices=("pso", "pso+lm"))
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child is not None:
        print(json.dumps(child(a.child, a.memory, a.method)))
        return 0
    rows = []
    env = dict(os.environ, MRJAX_CACHE_DIR="off")
    for n in [int(v) for v in a.sizes.split(",")]:
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "benchmarks.scale_conditions", "--child",
                            str(n), "--memory", a.memory, "--method", a.method],
                           capture_output=True, text=True, env=env, cwd=HERE.parent)
        if p.returncode:
            print(p.stderr[-3000:], file=sys.stderr)
            return p.returncode
        row = json.loads(p.stdout.strip().splitlines()[-1])
        row["process_s"] = time.perf_counter() - t0
        row["load_avg"] = os.getloadavg()
        rows.append(row)
        print(f"{n:>6} tests: fit {row['fit_s']:.1f} s, peak RSS "
              f"{row['peak_rss_bytes'] / 1e9:.2f} GB, chunks {row['chunk']['n_chunks']} x "
              f"{row['chunk']['size']}, load {row['load_avg'][0]:.1f}", file=sys.stderr,
              flush=True)
        write(rows, a)  # after every size: a long run keeps what it measured
    return 0


def machine() -> str:
    """The machine in words (cores, memory, Python)."""
    mem = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**30
    return (f"{platform.machine()} CPU, {os.cpu_count()} cores, {mem:.0f} GiB, shared with "
            f"other jobs (1-min load average in the table); python {platform.python_version()}")


def write(rows: list[dict], a: argparse.Namespace) -> None:
    """`scale_conditions.json` (the rows) and `scale_conditions.md` (a table)."""
    lines = [f"Machine: {machine()}. `python -m benchmarks.scale_conditions`: tanh model "
             f"(`kwok`), method `{a.method}`, separable swarm, {a.memory} budget, each size in "
             f"a fresh process (cold: compilation included; peak RSS of the whole process).",
             "",
             "| tests | chunks x size | fit wall | per test | peak RSS | data | median RMS | load |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['conditions']:,} | {r['chunk']['n_chunks']} x {r['chunk']['size']} | "
                     f"{r['fit_s']:.0f} s | {1e3 * r['fit_s'] / r['conditions']:.0f} ms | "
                     f"{r['peak_rss_bytes'] / 1e9:.2f} GB | {r['data_bytes'] / 1e6:.0f} MB | "
                     f"{r['median_rms_N']:.1f} N | {r['load_avg'][0]:.1f} |")
    before = HERE / "scale_conditions_before.json"
    if before.exists():  # measured once on the code before chunking (see that file)
        b = json.loads(before.read_text())
        lines += ["", f"Before chunking ({b['code']}): {b['conditions']:,} tests in one program, "
                  f"fit {b['fit_s']:.0f} s, peak RSS {b['peak_rss_bytes'] / 1e9:.2f} GB; "
                  f"{b['note']}"]
    (HERE / "scale_conditions.md").write_text("\n".join(lines) + "\n")
    doc = {"machine": machine(), "method": a.method, "memory": a.memory, "rows": rows}
    (HERE / "scale_conditions.json").write_text(json.dumps(doc, indent=1) + "\n")

if __name__ == "__main__":
    sys.exit(main())
