"""Fleet-scale input: loading and fitting thousands of tests from one file, wall time and peak RSS.

    python -m benchmarks.fleet make --tests 1440 --parquet [--dir /tmp/mrjax-fleet]
    python -m benchmarks.fleet run --tests 1440 --memory 2GB [--steps load,check,fit,pyfit]

`make` writes `fleet<N>.csv` (and with `--parquet` `fleet<N>.parquet`) in the long layout with
the documented header `condition, current_A, frequency_Hz, amplitude_m, time_s,
displacement_m, velocity_m_s, force_N`: the tanh model on copies of the paper grid, each copy
with its own noise (labels `<grid label>_copy<k>`), every record 2,000 samples (as
`benchmarks/scale_conditions.py`), floats written exactly (`repr`). The files are large
(1,440 tests: 291 MB CSV, 34 MB Parquet; 10,000 tests: 2.0 GB CSV): keep them outside the
repository and delete them when done.

`run` runs each step in a fresh process under `/usr/bin/time -v` (peak RSS of the whole
process), cold (`MRJAX_CACHE_DIR=off`):

- `load`: `pandas.read_csv` (or `read_parquet`) of the file, the reference, then
    `mrjax.data.load_batch` of it; each also reports the seconds of the read itself (imports
    excluded);
- `check`: the batch read from the file equals, bit for bit, the same tests built in Python;
- `fit`: `mrjax fit FILE --model kwok --method pso --memory SIZE --no-plots`;
- `pyfit`: `mrjax.fit("kwok", batch, polish=None, chunks=mrjax.Chunks(max_memory=SIZE))` on
    the tests built in Python, and whether its `fit.csv` is byte for byte that of each file's
    `mrjax fit`.

Rows go to `benchmarks/fleet.json` (replacing those of the same test count and step).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
DEFAULT_DIR = Path("/tmp/mrjax-fleet")


def conditions_of(n: int, start: int = 0, stop: int | None = None):
    """Tests `start`..`stop` of the `n`-test fleet: copies of the paper grid (tanh model, 36
    tests of 2,000 samples), copy k with noise seed k and labels `<grid label>_copy<k>`."""
    import dataclasses

    from mrjax.data import PAPER_MOTIONS, paper_grid

    stop = n if stop is None else stop
    first = start // 36
    conds = []
    for copy in range(first, -(-stop // 36)):
        for f, cycles in ((1.0, 2.0), (2.0, 4.0)):
            motions = tuple(m for m in PAPER_MOTIONS if m[0] == f)
            conds += [dataclasses.replace(c, label=f"{c.label}_copy{copy}") for c in
                      paper_grid(motions=motions, cycles=cycles, seed=copy).conditions()]
    return conds[start - 36 * first: stop - 36 * first]


def make(n: int, folder: Path, parquet: bool) -> list[Path]:
    """Write the fleet's CSV (and Parquet) file, 500 tests at a time."""

    from mrjax.data import to_frame

    folder.mkdir(parents=True, exist_ok=True)
    csv_path = folder / f"fleet{n}.csv"
    pq_path = folder / f"fleet{n}.parquet"
    writer = None
    with open(csv_path, "w", newline="") as fh:
        for start in range(0, n, 500):
            frame = to_frame(conditions_of(n, start, min(n, start + 500)))
            frame.to_csv(fh, index=False, header=start == 0, float_format=None)
            if parquet:
                import pyarrow as pa
                import pyarrow.parquet as pq

                table = pa.Table.from_pandas(frame, preserve_index=False)
                if writer is None:
                    writer = pq.ParquetWriter(pq_path, table.schema)
                writer.write_table(table)
            print(f"{min(n, start + 500)}/{n} tests written", file=sys.stderr, flush=True)
    if writer is not None:
        writer.close()
    return [csv_path] + ([pq_path] if parquet else [])


def _timed(argv: list[str], env: dict) -> dict:
    """Run `argv` under `/usr/bin/time -v`: wall [s], peak RSS [bytes], exit code, stderr."""
    t0 = time.perf_counter()
    p = subprocess.run(["/usr/bin/time", "-v", *argv], capture_output=True, text=True, env=env,
                       cwd=HERE.parent)
    wall = time.perf_counter() - t0
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    return {"wall_s": wall, "peak_rss_bytes": int(m.group(1)) * 1024 if m else None,
            "rc": p.returncode, "stdout": p.stdout[-4000:], "stderr": p.stderr[-4000:]}


#: The read steps, each run in a fresh process; `{path}` the file. Each prints the seconds of
#: the read itself (imports excluded) on its last line.
_READ = {
    "pandas.read_csv": "import pandas as pd, time; t = time.perf_counter(); pd.read_csv({path!r})",
    "pandas.read_parquet": "import pandas as pd, time; t = time.perf_counter(); "
                           "pd.read_parquet({path!r})",
    "mrjax.data.load_batch": "import mrjax.data as md, time; t = time.perf_counter(); "
                             "md.load_batch({path!r})",
}
_TAIL = "; print(time.perf_counter() - t)"
#: Checks the data read from the file against the same tests built in Python, bit for bit,
#: and (with `fit`) writes the Python fit's fit.csv; `{path}`, `{n}`, `{memory}`, `{out}`.
_CHECK = """
import sys, numpy as np
sys.path.insert(0, {repo!r})
import mrjax
from mrjax.data import load_batch, make_batch
from benchmarks.fleet import conditions_of
ref = make_batch(conditions_of({n}))
got = load_batch({path!r})
assert got.labels == ref.labels
for f in ("t", "x", "xdot", "force", "dt", "command", "mask", "current", "frequency",
          "amplitude", "command_kind", "estimated"):
    assert np.array_equal(np.asarray(getattr(got, f)), np.asarray(getattr(ref, f)),
                          equal_nan=True), f
print("identical batch")
if {fit}:
    del got
    res = mrjax.fit("kwok", ref, polish=None, key=0, chunks=mrjax.Chunks(max_memory={memory!r}))
    open({out!r}, "w").write(res.to_csv())
"""


def run(n: int, folder: Path, memory: str, steps: list[str]) -> list[dict]:
    """The timed steps on the fleet files of `n` tests (see the module notes)."""
    env = dict(os.environ, MRJAX_CACHE_DIR="off")
    py = sys.executable
    rows = []
    for path in (folder / f"fleet{n}.csv", folder / f"fleet{n}.parquet"):
        if not path.exists():
            continue
        fmt = path.suffix[1:]
        reference = "pandas.read_csv" if fmt == "csv" else "pandas.read_parquet"
        for what in (reference, "mrjax.data.load_batch"):
            if "load" not in steps:
                break
            r = _timed([py, "-c", _READ[what].format(path=str(path)) + _TAIL], env)
            read_s = float(r["stdout"].strip().splitlines()[-1]) if r["rc"] == 0 else None
            rows.append({"tests": n, "format": fmt, "step": what, "size_bytes": path.stat().st_size,
                         "read_s": read_s, "load_avg": os.getloadavg()[0], **_short(r)})
            _say(rows[-1])
        if "check" in steps:
            r = _timed([py, "-c", _CHECK.format(repo=str(HERE.parent), n=n, path=str(path),
                                                 fit=False, memory=memory, out="")], env)
            rows.append({"tests": n, "format": fmt, "step": "identical to the Python batch",
                         "ok": r["rc"] == 0 and "identical batch" in r["stdout"], **_short(r)})
            _say(rows[-1])
        if "fit" in steps:
            out = folder / f"out-{fmt}"
            mrjax = str(Path(py).with_name("mrjax"))
            r = _timed([mrjax, "fit", str(path), "--model", "kwok", "--method", "pso",
                        "--memory", memory, "--no-plots", "--max-rows", "3", "--out", str(out)],
                       env)
            rows.append({"tests": n, "format": fmt, "step": f"mrjax fit --memory {memory}",
                         "size_bytes": path.stat().st_size, "load_avg": os.getloadavg()[0],
                         **_short(r)})
            _say(rows[-1])
    if "pyfit" in steps:  # the same tests fitted from Python arrays: the same fit.csv?
        out = folder / "out-python.csv"
        path = folder / f"fleet{n}.csv"
        r = _timed([py, "-c", _CHECK.format(repo=str(HERE.parent), n=n, path=str(path), fit=True,
                                             memory=memory, out=str(out))], env)
        same = {fmt: (folder / f"out-{fmt}" / "fit.csv").exists()
                and (folder / f"out-{fmt}" / "fit.csv").read_bytes() == out.read_bytes()
                for fmt in ("csv", "parquet")} if out.exists() else {}
        rows.append({"tests": n, "format": "python", "step": f"mrjax.fit --memory {memory}",
                     "same_fit_csv": same, "load_avg": os.getloadavg()[0], **_short(r)})
        _say(rows[-1])
    return rows


def _short(r: dict) -> dict:
    return {k: r[k] for k in ("wall_s", "peak_rss_bytes", "rc")} | (
        {"stderr": r["stderr"][-1500:]} if r["rc"] else {})


def _say(row: dict) -> None:
    rss = row["peak_rss_bytes"] or 0
    extra = {k: row[k] for k in ("read_s", "ok", "same_fit_csv") if k in row}
    print(f"{row['tests']} {row['format']} {row['step']}: {row['wall_s']:.1f} s, "
          f"{rss / 1e9:.2f} GB (rc {row['rc']}, load {os.getloadavg()[0]:.1f}) {extra}",
          file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("action", choices=("make", "run"))
    ap.add_argument("--tests", type=int, default=1440)
    ap.add_argument("--dir", type=Path, default=DEFAULT_DIR)
    ap.add_argument("--parquet", action="store_true")
    ap.add_argument("--memory", default="2GB")
    ap.add_argument("--steps", default="load,check,fit,pyfit",
                    help="of load, check, fit, pyfit (default all)")
    a = ap.parse_args(argv)
    if a.action == "make":
        for p in make(a.tests, a.dir, a.parquet):
            print(f"{p}: {p.stat().st_size / 1e6:.0f} MB", file=sys.stderr)
        return 0
    rows = run(a.tests, a.dir, a.memory, a.steps.split(","))
    store = HERE / "fleet.json"
    doc = json.loads(store.read_text()) if store.exists() else {"rows": []}
    doc["rows"] = [r for r in doc["rows"] if r["tests"] != a.tests
                   or r["step"] not in {x["step"] for x in rows}] + rows
    store.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
