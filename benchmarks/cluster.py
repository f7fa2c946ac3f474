"""Fits on a Dask cluster (issue 41): 1,440 tests from Parquet in one process vs a local cluster.

    python -m benchmarks.cluster make [--tests 1440] [--dir /tmp/mrjax-cluster]
    python -m benchmarks.cluster run [--tests 1440] [--workers 2] [--chunk-size 96]

`make` writes `fleet<N>.parquet` (the tests of `benchmarks/fleet.py`: the tanh model on copies
of the paper grid, 2,000 samples each, each copy with its own noise) in row groups of 36 tests
(one grid copy), so that a chunk reads only the row groups that hold its tests, and
`warm.parquet` (its first two chunks' worth of tests), whose fit fills the persistent
compilation cache with the programs of the chunk shape.

`run`, every `mrjax fit` in a fresh process under `/usr/bin/time -v` (wall, peak RSS and the
CPU seconds of that process, the client's), with `MRJAX_CACHE_DIR=<dir>/xla`, warm (filled
first by a fit of `warm.parquet`), so that every side measures the fit, not the compiler:

- `one process`: `mrjax fit FILE --model kwok --chunk-size C --no-plots` (the default method:
    swarm, polish, the retry from the neighbours' optima, the std-errors) on `warm.parquet`
    and on `fleet<N>.parquet`;
- `cluster`: the same with `--cluster ADDRESS` on a `distributed.LocalCluster` of `--workers`
    processes of one thread each, started here: `warm.parquet` first (new workers: their start
    is in it), then `fleet<N>.parquet`; the workers take the client's cache directory
    (`mrjax.fitting._cluster.apply_settings`) and read their chunks from the file; fit.csv
    compared byte for byte with the one process's; the scheduler's task stream gives each
    task's time;
- `dask round trip`: one no-op task per chunk through the same pool (`ClusterPool.map`);
- `read a chunk`: the same tasks reading their chunk from the Parquet file on a worker and
    checking its tests' digests (`Chunked.take`).

The machine is shared, so walls move with the load; CPU seconds move much less. The CPU of
each side is measured: the one process's and the cluster's client (`time -v`), the workers
(`psutil` in each worker, before and after each fit) and the scheduler and nannies (this
process, `time.process_time`). Two sizes give each side's CPU per test (the slope) and its
fixed part (imports, starting); from these the overhead per chunk task (the cluster's CPU per
test minus the one process's, per task) and the estimate for a million tests on N one-core
workers: `T(N) = fixed + client_per_test * 1e6 + (worker_per_test * 1e6 + tasks_per_million
* round_trip) / N`. Rows go to `benchmarks/cluster.json`, the tables to
`benchmarks/cluster.md`.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

from benchmarks._common import HERE, environment, loadavg, md_table

DEFAULT_DIR = Path("/tmp/mrjax-cluster")
#: Tests per Parquet row group (one copy of the paper grid).
GROUP_TESTS = 36
#: The workers' counts of the million-test estimate.
ESTIMATE_WORKERS = (1, 10, 100, 1000)


def make(n: int, folder: Path, chunk: int) -> list[Path]:
    """Write `fleet<n>.parquet` and `warm.parquet` (see the module notes)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from benchmarks.fleet import conditions_of
    from mrjax.data import to_frame

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, count in ((f"fleet{n}.parquet", n), ("warm.parquet", 2 * chunk)):
        writer = None
        for start in range(0, count, 4 * GROUP_TESTS):
            conds = conditions_of(n, start, min(count, start + 4 * GROUP_TESTS))
            table = pa.Table.from_pandas(to_frame(conds), preserve_index=False)
            if writer is None:
                writer = pq.ParquetWriter(folder / name, table.schema)
            writer.write_table(table, row_group_size=GROUP_TESTS * 2000)
        writer.close()
        out.append(folder / name)
    return out


class LoadSampler:
    """The 1-minute load average every `period` seconds while it runs (a thread)."""

    def __init__(self, period: float = 5.0):
        self.period, self.samples, self._stop = period, [], threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.wait(self.period):
            self.samples.append(os.getloadavg()[0])

    def __enter__(self):
        self.samples.append(os.getloadavg()[0])
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.samples.append(os.getloadavg()[0])

    @property
    def mean(self) -> float:
        return round(sum(self.samples) / len(self.samples), 2)


def timed_fit(argv: list[str], env: dict) -> dict:
    """`mrjax fit ARGV` in a fresh process under `/usr/bin/time -v`: wall [s], CPU [s] of the
    process, peak RSS [bytes], the exit code, the load average during it."""
    mrjax = str(Path(sys.executable).with_name("mrjax"))
    with LoadSampler() as load:
        t0 = time.perf_counter()
        p = subprocess.run(["/usr/bin/time", "-v", mrjax, "fit", *argv], capture_output=True,
                           text=True, env=env)
        wall = time.perf_counter() - t0

    def field(name: str) -> float:
        m = re.search(rf"{re.escape(name)}: ([0-9.]+)", p.stderr)
        return float(m.group(1)) if m else float("nan")

    row = {"wall_s": round(wall, 2), "cpu_s": round(field("User time (seconds)")
                                                  + field("System time (seconds)"), 2),
           "peak_rss_bytes": int(field("Maximum resident set size (kbytes)") * 1024),
           "rc": p.returncode, "load_avg_mean": load.mean, "load_avg": load.samples}
    if p.returncode:
        row["stderr"] = p.stderr[-2000:]
    return row


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process (a worker's)."""
    import psutil

    t = psutil.Process().cpu_times()
    return t.user + t.system


def _noop(j: int, shared) -> int:
    """A task without work (the round trip of a chunk's task)."""
    return j


def _read(j: int, chunked) -> int:
    """A task that reads chunk `j` from its files and checks its digests."""
    return chunked.chunk(j)[2]


def task_times(client, t0: float) -> dict[str, dict]:
    """Compute seconds of the mrjax tasks since `t0`, by pass: count, sum, median, first."""
    import numpy as np

    out: dict[str, list] = {}
    for rec in client.get_task_stream(start=t0):
        key = str(rec["key"])
        m = re.match(r"mrjax-(.+)-part-\d+-", key)
        if not m:
            continue
        compute = sum(s["stop"] - s["start"] for s in rec["startstops"]
                      if s["action"] == "compute")
        out.setdefault(m.group(1), []).append((min(s["start"] for s in rec["startstops"]),
                                               compute))
    return {k: {"tasks": len(v), "sum_s": round(sum(c for _, c in v), 2),
                "median_s": round(float(np.median([c for _, c in v])), 3),
                "first_s": round(min(v)[1], 3)} for k, v in out.items()}


def pool_overheads(client, folder: Path, n: int, chunk: int) -> dict:
    """The round trip of a no-op task per chunk, and a chunk's read on a worker [ms]."""
    import mrjax
    from mrjax.data import Source
    from mrjax.fitting import _chunks
    from mrjax.fitting._cluster import ClusterPool
    from mrjax.fitting._run import make_run

    pool = ClusterPool(client)
    model = mrjax.models.get("kwok")
    source = Source.scan(folder / f"fleet{n}.parquet", keep_bytes=0)
    run = make_run(model, n, swarm=mrjax.Swarm(), polish=mrjax.Polish(), key=0,
                   chunks=mrjax.Chunks(size=chunk, cluster=client))
    t0 = time.perf_counter()
    _, chunked = _chunks.layout(model, source, run, 0, pool, 1)
    check_s = time.perf_counter() - t0
    work = pool.share(chunked)
    js = range(chunked.plan.n_chunks)
    out = {"check_pass_s": round(check_s, 2), "chunks": chunked.plan.n_chunks}
    for name, fn in (("round_trip", _noop), ("read_chunk", _read)):
        list(pool.map(fn, js, work, describe=chunked.describe))  # warm
        t0 = time.perf_counter()
        list(pool.map(fn, js, work, describe=chunked.describe))
        out[f"{name}_ms_per_chunk"] = round(1e3 * (time.perf_counter() - t0) / len(js), 1)
    return out


def run(n: int, folder: Path, workers: int, chunk: int) -> dict:
    """The timed fits and the derived figures (see the module notes)."""
    import distributed

    small, data = folder / "warm.parquet", folder / f"fleet{n}.parquet"
    env = dict(os.environ, MRJAX_CACHE_DIR=str(folder / "xla"), JAX_PLATFORMS="cpu")
    common = ["--model", "kwok", "--chunk-size", str(chunk), "--no-plots", "--max-rows", "3",
              "--overwrite"]
    rows = {"environment": environment(), "tests": n, "small_tests": 2 * chunk,
            "workers": workers, "chunk_size": chunk, "dask": distributed.__version__}

    def fit(name: str, path: Path, *extra: str) -> dict:
        rows[name] = timed_fit([str(path), *common, *extra, "--out", str(folder / name)], env)
        print(f"{name}: {rows[name]}", file=sys.stderr, flush=True)
        return rows[name]

    fit("fill_cache", small)
    fit("one_process_small", small)
    fit("one_process", data)
    with distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster, set_as_default=False) as client:
        client.get_task_stream()  # starts the recording
        for name, path in (("cluster_small", small), ("cluster", data)):  # cold, then warm
            t0, cpu0, here0 = time.time(), client.run(_cpu_seconds), time.process_time()
            row = fit(name, path, "--cluster", cluster.scheduler_address)
            cpu1 = client.run(_cpu_seconds)
            row["workers_cpu_s"] = round(sum(cpu1[w] - cpu0.get(w, 0.0) for w in cpu1), 2)
            row["scheduler_cpu_s"] = round(time.process_time() - here0, 2)
            row["tasks"] = task_times(client, t0)
        rows["pool"] = pool_overheads(client, folder, n, chunk)
    one, cl = (folder / d / "fit.csv" for d in ("one_process", "cluster"))
    rows["identical_fit_csv"] = one.exists() and cl.exists() and one.read_bytes() == cl.read_bytes()
    rows["estimate"] = estimate(rows)
    rows["loadavg_end"] = loadavg()
    return rows


def estimate(rows: dict) -> dict:
    """The derived figures and the million-test estimate (see the module notes): CPU seconds
    per test (the slope between the two sizes) and fixed (the intercept) of the one process
    and of the cluster's client; the workers' per test from the large fit (warm workers) and
    their start (the small fit's CPU beyond its tests'); the overhead per chunk task."""
    n, m = rows["tests"], rows["small_tests"]
    one, one_s, cl, cl_s = (rows[k] for k in ("one_process", "one_process_small", "cluster",
                                               "cluster_small"))
    one_pt = (one["cpu_s"] - one_s["cpu_s"]) / (n - m)
    client_pt = (cl["cpu_s"] - cl_s["cpu_s"]) / (n - m)
    client_fixed = cl_s["cpu_s"] - m * client_pt
    worker_pt = (cl["workers_cpu_s"] + cl["scheduler_cpu_s"]) / n
    worker_start = (cl_s["workers_cpu_s"] + cl_s["scheduler_cpu_s"] - m * worker_pt) / rows[
        "workers"]
    n_tasks = sum(t["tasks"] for t in cl["tasks"].values())
    overhead = (client_pt + worker_pt - one_pt) * n / n_tasks
    round_trip = rows["pool"]["round_trip_ms_per_chunk"] / 1e3
    tasks_per_million = n_tasks * 1e6 / n
    est = {f"{w}_workers_h": round((client_fixed + worker_start + client_pt * 1e6
                                    + (worker_pt * 1e6 + tasks_per_million * round_trip) / w)
                                   / 3600, 2) for w in ESTIMATE_WORKERS}
    return {"chunk_tasks": n_tasks, "one_process_cpu_s_per_test": round(one_pt, 4),
            "one_process_cpu_s_fixed": round(one_s["cpu_s"] - m * one_pt, 2),
            "client_cpu_s_per_test": round(client_pt, 5),
            "client_cpu_s_fixed": round(client_fixed, 2),
            "worker_cpu_s_per_test": round(worker_pt, 4),
            "worker_start_cpu_s": round(worker_start, 2),
            "overhead_cpu_ms_per_task": round(1e3 * overhead),
            "million_tests": est}


def render(doc: dict) -> str:
    """benchmarks/cluster.md."""
    env, est, pool = doc["environment"], doc["estimate"], doc["pool"]
    n, m = doc["tests"], doc["small_tests"]
    gb = 1e9

    def row(name: str, label: str) -> list:
        r = doc[name]
        return [label, r["wall_s"], r["load_avg_mean"], r["cpu_s"], r.get("workers_cpu_s", ""),
                r.get("scheduler_cpu_s", ""), round(r["peak_rss_bytes"] / gb, 2)]

    cl = f"local cluster, {doc['workers']} workers x 1 thread"
    lines = [
        "# Fits on a Dask cluster: one process vs a local cluster",
        "",
        f"`python -m benchmarks.cluster run --tests {n} --workers {doc['workers']}` on "
        f"{env['cpu_model']}, {env['cpu_affinity']} cores shared with other work, jax "
        f"{env['versions']['jax']}, dask {doc.get('dask', '')}, {env['date']}. {n:,} tanh tests "
        "of 2,000 samples in one Parquet file (row groups of 36 tests), and its first "
        f"{m} tests; chunks of {doc['chunk_size']} ({pool['chunks']} chunks of the {n:,}), the "
        "default method (swarm, polish, retry, std-errors); every fit warm (persistent "
        "compilation cache filled first), each `mrjax fit` a fresh process. The one process "
        "holds the tests in memory; the cluster's workers read their chunks from the file "
        f"(the {m}-test fit first, on new workers; then the {n:,}-test one). fit.csv of the "
        f"{n:,} tests identical to the one process's: **{doc['identical_fit_csv']}**.",
        "",
        md_table(["fit", "wall [s]", "load avg", "CPU [s]: client", "workers",
                  "scheduler + nannies", "client peak RSS [GB]"], [
            row("one_process_small", f"one process, {m} tests"),
            row("one_process", f"one process, {n:,} tests"),
            row("cluster_small", f"{cl}, {m} tests (new workers)"),
            row("cluster", f"{cl}, {n:,} tests")]),
        "",
        "On these two shared cores the cluster's two workers compete with each other and with "
        "the other work for the same cores: the walls say little about a cluster of machines; "
        "the CPU seconds are the cost model.",
        "",
        md_table(["pass (tasks on the workers)", "tasks", "task time [s]", "median [s]",
                  "first [s]"],
                 [[k, t["tasks"], t["sum_s"], t["median_s"], t["first_s"]]
                  for k, t in doc["cluster"]["tasks"].items()]),
        "",
        md_table(["overhead per chunk task", "ms"], [
            ["CPU: the cluster's per test (client, workers, scheduler) minus the one "
             "process's, per task", est["overhead_cpu_ms_per_task"]],
            ["Dask round trip of a no-op task (wall)", pool["round_trip_ms_per_chunk"]],
            ["a worker reads its chunk from the Parquet file and checks its digests (wall)",
             pool["read_chunk_ms_per_chunk"]]]),
        "",
        md_table(["CPU seconds", "per test", "fixed"], [
            ["one process", est["one_process_cpu_s_per_test"], est["one_process_cpu_s_fixed"]],
            ["cluster: client (serial: index scan, the CLI's survey, gathering, journal, "
             "fit.csv; fixed: imports, connecting)", est["client_cpu_s_per_test"],
             est["client_cpu_s_fixed"]],
            ["cluster: workers and scheduler (fixed: per worker, its start: imports, the "
             "programs loaded from the cache)", est["worker_cpu_s_per_test"],
             est["worker_start_cpu_s"]]]),
        "",
        "A million tests on N one-core workers, `T = fixed + client * 1e6 + (worker * 1e6 + "
        "tasks * round trip) / N`:",
        "",
        md_table(["workers", "hours"], [[w.split("_")[0], h]
                                        for w, h in est["million_tests"].items()]),
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("action", choices=("make", "run", "render"))
    ap.add_argument("--tests", type=int, default=1440)
    ap.add_argument("--dir", type=Path, default=DEFAULT_DIR)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--chunk-size", type=int, default=96)
    a = ap.parse_args(argv)
    if a.action == "make":
        for p in make(a.tests, a.dir, a.chunk_size):
            print(f"{p}: {p.stat().st_size / 1e6:.0f} MB", file=sys.stderr)
        return 0
    store = HERE / "cluster.json"
    if a.action == "run":
        doc = run(a.tests, a.dir, a.workers, a.chunk_size)
        store.write_text(json.dumps(doc, indent=1) + "\n")
    doc = json.loads(store.read_text())
    (HERE / "cluster.md").write_text(render(doc))
    print(json.dumps(doc["estimate"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
