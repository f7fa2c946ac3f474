"""Right by default on the 30 UTFSM sine tests (issue 26): the `mrjax fit` command with no
tuning flags against the previous defaults, seeds 0-4, and the held-out currents.

    python -m benchmarks.defaults [--sections fit,seeds,reference,holdout] [--models ...]
                                  [--seeds 0,1,2,3,4] [--resume]

Every run is the `mrjax` command in a fresh process (cold: JAX import and compilation included,
`MRJAX_CACHE_DIR=off`, `--no-plots`), niced; its wall time and the load average (`uptime`)
before and after are recorded. Reads the tests from $MRJAX_DATA or ../shared/data/utfsm (never
committed).

- `fit`: per model, `mrjax fit DATA --model M` (the new defaults: one swarm per test, the retry
    from the neighbours' optima) and the previous defaults (`--restarts 1 --no-retry`), seed 0,
    in the same period.
- `seeds`: the new defaults at seeds 0-4 (and the previous ones, for the table).
- `reference`: `--restarts 4` at seed 0 with the retry: with every other run, the best known
    optimum per test.
- `holdout`: laws from the 18 tests at 0, 0.5 and 1 A (`mrjax fit TRAIN --generalize joint`,
    `--laws fixed` (the model's default degrees, the previous default) and `--laws auto` (the
    new default); the tanh model also two-step) predicted at 0.25 and 0.75 A with
    `mrjax predict`.

Writes `benchmarks/defaults.json` (every run, resumable) and `benchmarks/defaults.md`.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
JSON = HERE / "defaults.json"
MODELS = "modified_bouc_wen,bouc_wen,dahl"
OLD = ["--restarts", "1", "--no-retry"]
TRAIN_CURRENTS = ("0A", "0x5A", "1A")


def _load() -> str:
    return Path("/proc/loadavg").read_text().split()[0] if Path("/proc/loadavg").exists() \
        else "?"


def run_cli(args: list[str], out: Path) -> dict:
    """`mrjax ARGS --out OUT --no-plots` in a fresh niced process: wall [s], load before and
    after, the fit.json / predict.json it wrote."""
    env = dict(os.environ, MRJAX_CACHE_DIR="off", JAX_PLATFORMS="cpu")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    cmd = ["nice", "-n", "10", sys.executable, "-m", "mrjax.cli", *args, "--out", str(out),
           "--no-plots"]
    load0 = _load()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed:\n{p.stderr[-3000:]}")
    doc = {}
    for name in ("fit.json", "predict.json"):
        if (out / name).exists():
            doc = json.loads((out / name).read_text())
    return {"args": args, "wall_s": wall, "cpu_s": cpu, "load_before": load0,
            "load_after": _load(),
            "doc": doc, "stdout_tail": p.stdout[-2500:]}


def per_test(doc: dict) -> dict[str, float]:
    """Label -> NRMSE [%] of a fit.json or predict.json."""
    return {c["label"]: 100 * float(c["nrmse"]) for c in doc["conditions"]}


def summary(r: dict) -> dict:
    """Median / worst NRMSE [%], wall [s], loads and warnings of one run."""
    nr = per_test(r["doc"])
    v = np.array(list(nr.values()))
    worst = max(nr, key=nr.get)
    return {"args": r["args"], "wall_s": round(r["wall_s"], 1), "cpu_s": round(r["cpu_s"], 1),
            "load": f"{r['load_before']} -> {r['load_after']}",
            "median_pct": float(np.median(v)), "worst_pct": float(v.max()), "worst_test": worst,
            "per_test_pct": nr,
            "warnings": [w.get("message", "") for w in r["doc"].get("warnings", [])],
            "law_forms": (r["doc"].get("generalized") or {}).get("law_forms")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sections", default="fit,seeds,reference,holdout")
    ap.add_argument("--models", default=MODELS)
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--data", default=None)
    ap.add_argument("--resume", action="store_true", help="skip the runs defaults.json holds")
    args = ap.parse_args(argv)
    from ._common import default_data_dir

    data = Path(args.data) if args.data else default_data_dir()
    out = json.loads(JSON.read_text()) if (args.resume and JSON.exists()) else {}
    out.setdefault("machine", f"{os.uname().machine}, {os.cpu_count()} cores, CPU only")
    runs = out.setdefault("runs", {})
    sections = args.sections.split(",")
    models = args.models.split(",")
    seeds = [int(s) for s in args.seeds.split(",")]
    tmp = Path(tempfile.mkdtemp(prefix="mrjax-defaults-"))

    def do(key: str, cli: list[str]) -> None:
        if key in runs:
            return
        print(f"[{time.strftime('%H:%M:%S')}] {key}: mrjax {' '.join(cli)}", file=sys.stderr,
              flush=True)
        r = run_cli(cli, tmp / key.replace("/", "_"))
        runs[key] = summary(r)
        s = runs[key]
        print(f"    {s['median_pct']:.2f} % median, worst {s['worst_pct']:.2f} % "
              f"({s['worst_test']}), {s['wall_s']:.0f} s wall, {s['cpu_s']:.0f} s CPU, load "
              f"{s['load']}", file=sys.stderr,
              flush=True)
        JSON.write_text(json.dumps(out, indent=1))

    for m in models:
        if "fit" in sections:
            do(f"{m}/new/seed0", ["fit", str(data), "--model", m, "--seed", "0"])
            do(f"{m}/old/seed0", ["fit", str(data), "--model", m, "--seed", "0", *OLD])
        if "seeds" in sections:
            for s in seeds:
                do(f"{m}/new/seed{s}", ["fit", str(data), "--model", m, "--seed", str(s)])
                do(f"{m}/old/seed{s}", ["fit", str(data), "--model", m, "--seed", str(s), *OLD])
        if "reference" in sections:
            do(f"{m}/reference", ["fit", str(data), "--model", m, "--seed", "0",
                                  "--restarts", "4"])
    if "holdout" in sections:
        files = sorted(data.glob("*.txt"))
        train = [str(f) for f in files if f.stem.endswith(TRAIN_CURRENTS)
                 and not f.stem.endswith(("0x25A", "0x75A"))]
        test = [str(f) for f in files if f.stem.endswith(("0x25A", "0x75A"))]
        for m, method, laws in (("modified_bouc_wen", "joint", "fixed"),
                                ("modified_bouc_wen", "joint", "auto"),
                                ("kwok", "two-step", "fixed"), ("kwok", "two-step", "auto"),
                                ("kwok", "joint", "fixed"), ("kwok", "joint", "auto")):
            key = f"holdout/{m}/{method}/{laws}"
            if key in runs:
                continue
            fit_dir = tmp / (key.replace("/", "_") + "_fit")
            cli = ["fit", *train, "--model", m, "--generalize", method, "--laws", laws]
            print(f"[{time.strftime('%H:%M:%S')}] {key}", file=sys.stderr, flush=True)
            r_fit = run_cli(cli, fit_dir)
            r_pred = run_cli(["predict", "--fit", str(fit_dir / "fit.json"), *test],
                             tmp / (key.replace("/", "_") + "_predict"))
            s = summary(r_pred)
            s["fit_wall_s"] = round(r_fit["wall_s"], 1)
            s["fit_load"] = f"{r_fit['load_before']} -> {r_fit['load_after']}"
            s["law_forms"] = (r_fit["doc"].get("generalized") or {}).get("law_forms")
            s["train_median_pct"] = float(np.median(list(per_test(r_fit["doc"]).values())))
            runs[key] = s
            print(f"    held-out {s['median_pct']:.2f} % median, worst {s['worst_pct']:.2f} %; "
                  f"forms {s['law_forms']}", file=sys.stderr, flush=True)
            JSON.write_text(json.dumps(out, indent=1))
    (HERE / "defaults.md").write_text(render(out) + "\n")
    print(render(out))
    return 0


def _best_known(runs: dict, model: str) -> dict[str, float]:
    """Per test, the lowest NRMSE [%] of every run of `model` in this benchmark."""
    best: dict[str, float] = {}
    for k, r in runs.items():
        if k.startswith(model + "/"):
            for lab, v in r["per_test_pct"].items():
                best[lab] = min(best.get(lab, np.inf), v)
    return best


def render(out: dict) -> str:
    """The markdown tables of `defaults.json`."""
    runs = out["runs"]
    lines = ["# Right by default: the UTFSM tests with no tuning flags", "",
             f"Machine: {out['machine']}; the shared 2-core CPU, other engineers' jobs running "
             "(load average before -> after each run in the tables; CPU = user + system time "
             "of the process, less sensitive to the load than the wall time). Every run is the "
             "`mrjax` "
             "command in a fresh process, cold (`MRJAX_CACHE_DIR=off`), `--no-plots`, `nice -n "
             "10`. New: the defaults of this release (one swarm per test, then every test "
             "polished again from the best of its neighbours' optima). Old: `--restarts 1 "
             "--no-retry` (the previous defaults). Best known: per test, the lowest NRMSE of "
             "every run below (seeds 0-4 old and new, `--restarts 4`).", "",
             "| model | defaults | seed | median NRMSE | worst test | above best known "
             "(max) | wall | CPU | load |", "|---|---|---:|---:|---|---:|---:|---:|---|"]
    models = sorted({k.split("/")[0] for k in runs if not k.startswith("holdout")})
    for m in models:
        best = _best_known(runs, m)
        for k in sorted(k for k in runs if k.startswith(m + "/")):
            r = runs[k]
            gap = max(v - best[lab] for lab, v in r["per_test_pct"].items())
            _, kind, seed = (k.split("/") + [""])[:3]
            lines.append(f"| {m} | {kind} | {seed.replace('seed', '')} | {r['median_pct']:.2f} % "
                         f"| {r['worst_pct']:.2f} % ({r['worst_test']}) | {gap:+.2f} pts "
                         f"| {r['wall_s']:.0f} s | {r.get('cpu_s', float('nan')):.0f} s "
                         f"| {r['load']} |")
    ho = {k: r for k, r in runs.items() if k.startswith("holdout/")}
    if ho:
        lines += ["", "Held-out currents: laws from the 18 tests at 0, 0.5 and 1 A (`mrjax fit "
                  "TRAIN --generalize METHOD [--laws auto]`), predicted at 0.25 and 0.75 A "
                  "(`mrjax predict`):", "",
                  "| model | method | forms | held-out median | worst | train median | "
                  "fit wall | load | forms chosen |", "|---|---|---|---:|---:|---:|---:|---|---|"]
        for k, r in ho.items():
            _, m, method, laws = k.split("/")
            forms = ", ".join(f"{n} {f}" for n, f in (r.get("law_forms") or {}).items())
            lines.append(f"| {m} | {method} | {laws} | {r['median_pct']:.2f} % | "
                         f"{r['worst_pct']:.2f} % | {r['train_median_pct']:.2f} % | "
                         f"{r['fit_wall_s']:.0f} s | {r['fit_load']} | {forms} |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
