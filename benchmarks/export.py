"""Export (issue 39): identified models as C99 and FMUs, their errors and their cost per sample.

    python -m benchmarks.export [--fits DIR] [--repeats 7]

1. **UTFSM laws.** Joint laws fitted on the UTFSM tests at 0, 0.5 and 1 A (all six motions,
   18 tests) for the tanh model (`kwok`), the modified Bouc-Wen and a declared model
   (`examples/my_models.py:Tanh`), `mrjax fit DATA --model M --generalize joint` (or the fits in
   `--fits DIR/<name>`); `mrjax predict` on the tests at 0.25 and 0.75 A (12 tests) writes
   `predicted.csv`; `mrjax export --to c --data <those tests>` and `--to fmu`.
2. **Errors.** The C library (gcc -std=c99 -Wall -Wextra -Werror -O2) run on the held-out
   records against predicted.csv: max |C - predicted| / force RMS over every sample of every
   record; the inverse at every sample for the force a random admissible command gives there:
   max |force at the returned command - desired| / force RMS, and whether a force of +-1e9 N
   saturates at a range's end; the FMU through `fmpy.validate_fmu` and `fmpy.simulate_fmu` on one
   record against the C force.
3. **Cost.** A C driver times `mrjax_step` and `mrjax_inverse` over the held-out records
   (every sample, `--repeats` passes, median ns per sample), for the three models above and
   for the other built-in models and the declared Bouc-Wen with laws around the test values
   (their cost does not depend on the fit).

Writes `benchmarks/export.json` and `benchmarks/export.md`.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ._common import default_data_dir, environment, loadavg, log, md_table

HERE = Path(__file__).resolve().parent
EXAMPLES = HERE.parent / "examples" / "my_models.py"
#: name in the report -> `--model` of `mrjax fit`.
FITTED = {"kwok": "kwok", "modified_bouc_wen": "modified_bouc_wen",
          "my_tanh (declared)": f"{EXAMPLES}:Tanh"}
MOTIONS = ("10mm1Hz", "25mm0x1Hz", "25mm0x25Hz", "25mm0x5Hz", "2mm5Hz", "5mm3Hz")
#: name in the report -> `--model` of the models timed on a fit of one test (`PER_TEST`).
TIMED = {"bingham": "bingham", "bouc_wen": "bouc_wen", "dahl": "dahl", "lugre": "lugre",
         "herschel_bulkley": "herschel_bulkley", "polynomial": "polynomial",
         "my_bouc_wen (declared)": f"{EXAMPLES}:BoucWen"}
PER_TEST = "5mm3Hz0x5A"

#: The timing and checking driver: reads records (x, xdot, command, dt since the last sample
#: (0 at a record's start), a random admissible command), writes the forces, prints JSON.
DRIVER = r"""
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "mrjax_model.h"

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts); /* CPU time: the machine may be shared */
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static int by_value(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv)
{
    FILE *in = fopen(argv[1], "rb"), *out = fopen(argv[2], "wb");
    const int repeats = argc > 3 && atoi(argv[3]) > 0 ? (atoi(argv[3]) < 64 ? atoi(argv[3]) : 64) : 1;
    const int S = MRJAX_STATE_SIZE;
    long T, k;
    int r;
    double *rec, *states, *force, *desired, *cmd, tstep[64], tinv[64], worst = 0.0;
    double t0, sink = 0.0;
    long saturation_failures = 0, at_end = 0;
    fseek(in, 0, SEEK_END);
    T = ftell(in) / (5 * sizeof(double));
    rewind(in);
    rec = malloc(T * 5 * sizeof(double));
    states = malloc(T * S * sizeof(double));
    force = malloc(T * sizeof(double));
    desired = malloc(T * sizeof(double));
    cmd = malloc(T * sizeof(double));
    if (fread(rec, sizeof(double), T * 5, in) != (size_t)(T * 5))
        return 1;
    for (r = 0; r < repeats; ++r) {
        double state[MRJAX_STATE_SIZE];
        t0 = now();
        for (k = 0; k < T; ++k) {
            const double *x = rec + 5 * k;
            if (x[3] == 0.0)
                mrjax_init(state, x[0], x[1], x[2]);
            force[k] = mrjax_step(state, x[0], x[1], x[2], x[3]);
            if (r == 0)
                memcpy(states + S * k, state, sizeof state);
        }
        tstep[r] = (now() - t0) / T * 1e9;
    }
    for (k = 0; k < T; ++k) {
        const double *x = rec + 5 * k;
        double copy[MRJAX_STATE_SIZE];
        memcpy(copy, states + S * k, sizeof copy);
        desired[k] = mrjax_step(copy, x[0], x[1], x[4], 0.0);
    }
    for (r = 0; r < repeats; ++r) {
        t0 = now();
        for (k = 0; k < T; ++k) {
            const double *x = rec + 5 * k;
            cmd[k] = mrjax_inverse(states + S * k, x[0], x[1], desired[k], x[3] > 0 ? x[3] : 1e-3);
        }
        tinv[r] = (now() - t0) / T * 1e9;
    }
    for (k = 0; k < T; ++k) {
        const double *x = rec + 5 * k;
        double copy[MRJAX_STATE_SIZE];
        int s;
        memcpy(copy, states + S * k, sizeof copy);
        worst = fmax(worst, fabs(mrjax_step(copy, x[0], x[1], cmd[k], 0.0) - desired[k]));
        for (s = -1; s <= 1; s += 2) { /* a force out of reach: +-1e9 N */
            const double u = mrjax_inverse(states + S * k, x[0], x[1], s * 1e9, 1e-3);
            double lo[MRJAX_STATE_SIZE], hi[MRJAX_STATE_SIZE], at[MRJAX_STATE_SIZE];
            double flo, fhi, fu, best;
            memcpy(lo, states + S * k, sizeof lo);
            memcpy(hi, states + S * k, sizeof hi);
            memcpy(at, states + S * k, sizeof at);
            flo = mrjax_step(lo, x[0], x[1], MRJAX_COMMAND_MIN, 0.0);
            fhi = mrjax_step(hi, x[0], x[1], MRJAX_COMMAND_MAX, 0.0);
            fu = mrjax_step(at, x[0], x[1], u, 0.0);
            best = s > 0 ? fmax(flo, fhi) : fmin(flo, fhi);
            if (s * (fu - best) < -1e-12 * fabs(best)) /* worse than the better end */
                ++saturation_failures;
            if (u == MRJAX_COMMAND_MIN || u == MRJAX_COMMAND_MAX)
                ++at_end;
        }
        sink += cmd[k];
    }
    fwrite(force, sizeof(double), T, out);
    qsort(tstep, repeats, sizeof(double), by_value);
    qsort(tinv, repeats, sizeof(double), by_value);
    printf("{\"samples\": %ld, \"step_ns\": %.1f, \"inverse_ns\": %.1f, \"inverse_max_error_N\":"
           " %.3e, \"saturation_failures\": %ld, \"at_end\": %ld, \"checksum\": %.6g}\n", T,
           tstep[repeats / 2], tinv[repeats / 2], worst, saturation_failures, at_end, sink);
    fclose(in);
    fclose(out);
    return 0;
}
"""


def cli(*args) -> None:
    """`mrjax ARGS` in this process; raises on a non-zero exit."""
    from mrjax import cli as mcli

    code = mcli.main([str(a) for a in args])
    if code != 0:
        raise SystemExit(f"mrjax {args[0]} failed ({code})")


def read_predicted(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """predicted.csv as column -> values per condition (floats parsed round-trip exact)."""
    import pandas as pd

    table = pd.read_csv(path, float_precision="round_trip")
    return {str(c): {k: g[k].to_numpy(float) for k in g.columns if k != "condition"}
            for c, g in table.groupby("condition", sort=False)}


def drive(c_dir: Path, recs: dict, repeats: int, work: Path, seed: int = 0) -> tuple[dict, dict]:
    """Compile the driver with the export in `c_dir`, run it on the records; returns its JSON
    and the C force per record."""
    from mrjax.export import CFLAGS

    rng = np.random.default_rng(seed)
    rows, spans = [], {}
    for name, r in recs.items():
        dt = np.diff(r["time_s"], prepend=r["time_s"][0])
        c0 = rng.uniform(0.0, 1.0, dt.size)  # a random command in the UTFSM range, [0, 1] A
        spans[name] = (len(rows), len(rows) + dt.size)
        rows += list(zip(r["displacement_m"], r["velocity_m_s"], r["current"], dt, c0))
    src = work / "driver.c"
    src.write_text(DRIVER)
    exe = work / "driver"
    subprocess.run(["gcc", *CFLAGS, f"-I{c_dir}", str(src), str(c_dir / "mrjax_model.c"),
                    "-o", str(exe), "-lm"], check=True)
    np.asarray(rows, float).tofile(work / "records.bin")
    run = subprocess.run([str(exe), str(work / "records.bin"), str(work / "forces.bin"),
                          str(repeats)], capture_output=True, text=True, check=True)
    forces = np.fromfile(work / "forces.bin")
    return json.loads(run.stdout), {n: forces[a:b] for n, (a, b) in spans.items()}


def fmu_error(fmu: Path, rec: dict, c_force: np.ndarray) -> dict:
    """validate_fmu's problems and max |fmpy force at t_{k+1} - C force of sample k| / RMS on
    one record (fmpy reads a co-simulation FMU's outputs after each step)."""
    import fmpy
    from fmpy.validation import validate_fmu

    t = rec["time_s"] - rec["time_s"][0]
    sig = np.rec.fromarrays([t, rec["displacement_m"], rec["velocity_m_s"], rec["current"],
                             rec["measured"]],
                            names=["time", "x", "xdot", "command", "desired_force"])
    dt = float(np.median(np.diff(t)))
    res = fmpy.simulate_fmu(str(fmu), stop_time=t[-1], step_size=dt, output_interval=dt,
                            input=sig, output=["force"])
    n = min(len(res), len(c_force))
    rms = float(np.sqrt(np.mean(rec["measured"] ** 2)))
    err = max(abs(res["force"][0] - c_force[0]),
              float(np.max(np.abs(res["force"][1:n] - c_force[:n - 1]))))
    return {"problems": validate_fmu(str(fmu)), "max_rel_error": err / rms, "samples": n}


def fitted(name: str, model: str, data: Path, fits: Path, work: Path, repeats: int) -> dict:
    """Fit (or reuse), predict, export, check and time one model."""
    fit_dir = fits / name.split()[0]
    train = [data / f"{m}{c}A.txt" for m in MOTIONS for c in ("0", "0x5", "1")]
    held = [data / f"{m}{c}A.txt" for m in MOTIONS for c in ("0x25", "0x75")]
    timing = fits / f"{fit_dir.name}-fit_s.json"  # the fit's wall time, kept beside it
    if not (fit_dir / "fit.json").is_file():
        log(f"{name}: fitting joint laws on {len(train)} tests...")
        t0 = time.time()
        cli("fit", *train, "--model", model, "--generalize", "joint", "--out", fit_dir,
            "--no-plots")
        timing.write_text(json.dumps({"fit_s": time.time() - t0, "load": loadavg()}))
    t_fit = json.loads(timing.read_text()) if timing.is_file() else None
    pred, c_dir, f_dir = work / f"{name}-p", work / f"{name}-c", work / f"{name}-fmu"
    cli("predict", "--fit", fit_dir, *held, "--out", pred, "--no-plots")
    t0 = time.time()
    cli("export", "--fit", fit_dir, "--to", "c", "--out", c_dir, "--data", *held)
    t_c = time.time() - t0
    t0 = time.time()
    cli("export", "--fit", fit_dir, "--to", "fmu", "--out", f_dir, "--data", *held)
    t_fmu = time.time() - t0
    recs = read_predicted(pred / "predicted.csv")
    drv, forces = drive(c_dir, recs, repeats, work)
    rel = {c: float(np.max(np.abs(forces[c] - r["predicted"]))
                    / np.sqrt(np.mean(r["measured"] ** 2))) for c, r in recs.items()}
    rms = min(float(np.sqrt(np.mean(r["measured"] ** 2))) for r in recs.values())
    first = sorted(recs)[0]
    fmu = next(f_dir.glob("*.fmu"))
    integ = json.loads((pred / "predict.json").read_text()).get("integration")
    return {"model": name, "fit_s": t_fit, "export_c_s": t_c, "export_fmu_s": t_fmu,
            "integration": integ, "records": len(recs), "samples": drv["samples"],
            "step_max_rel_error": max(rel.values()), "step_rel_error_by_record": rel,
            "inverse_max_rel_error": drv["inverse_max_error_N"] / rms,
            "saturation_failures": drv["saturation_failures"],
            "saturated_at_an_end": drv["at_end"] / (2 * drv["samples"]),
            "fmu": {"record": first, **fmu_error(fmu, recs[first], forces[first])},
            "step_ns": drv["step_ns"], "inverse_ns": drv["inverse_ns"]}


def per_test(name: str, model: str, data: Path, fits: Path, held: list[Path], work: Path,
             repeats: int) -> dict:
    """Cost of a model fitted on one test (`PER_TEST`, one parameter set: the command is fixed),
    exported with `--data` the held-out records and run on them."""
    fit_dir = fits / name.split()[0]
    if not (fit_dir / "fit.json").is_file():
        log(f"{name}: fitting {PER_TEST}...")
        cli("fit", data / f"{PER_TEST}.txt", "--model", model, "--out", fit_dir, "--no-plots")
    c_dir = work / f"{name.split()[0]}-c"
    cli("export", "--fit", fit_dir, "--to", "c", "--out", c_dir, "--data", *held)
    recs = {}
    for p in held:  # the records as the export reads them (SI units, the file's time base)
        t, x, v, _ = np.loadtxt(p, unpack=True)
        recs[p.stem] = {"time_s": t, "displacement_m": x * 1e-3, "velocity_m_s": v * 1e-3,
                        "current": np.zeros_like(t)}
    drv, _ = drive(c_dir, recs, repeats, work)
    text = (c_dir / "mrjax_model.h").read_text()
    integ = next((ln.split("integration: ", 1)[1].split(" (")[0] for ln in text.splitlines()
                  if "integration: " in ln), None)
    return {"model": name, "integration": integ, "samples": drv["samples"],
            "step_ns": drv["step_ns"], "inverse_ns": drv["inverse_ns"]}


def render(doc: dict) -> str:
    env = doc["environment"]
    lines = ["# Export: the identified model and its inverse as C99 and an FMI 2.0 FMU", "",
             f"Machine: {env['cpu_model']}, {env['cpu_count']} CPU cores (shared with other "
             f"jobs: load {doc['load_start']} at the start, {doc['load_end']} at the end). "
             f"Date: {env['date']}. gcc: {doc['gcc']}, flags `{' '.join(doc['cflags'])}`.", "",
             f"Command: `{doc['command']}`", "",
             "Laws: joint laws (`mrjax fit DATA --model M --generalize joint`) on the UTFSM "
             "tests at 0, 0.5 and 1 A (6 motions, 18 tests); `mrjax predict` and the export "
             "(`--data`) on the tests at 0.25 and 0.75 A (12 tests, "
             f"{doc['fitted'][0]['samples']} samples).", "",
             "## Errors (fraction of the record's force RMS)", ""]
    rows = []
    for r in doc["fitted"]:
        integ = r["integration"]
        how = "static" if integ is None else f"{integ['scheme']}, {integ['substeps']} sub-steps"
        rows.append([r["model"], how, f"{r['step_max_rel_error']:.1e}",
                     f"{r['inverse_max_rel_error']:.1e}",
                     f"{r['saturation_failures']} ({100 * r['saturated_at_an_end']:.1f} %)",
                     "none" if not r["fmu"]["problems"] else len(r["fmu"]["problems"]),
                     f"{r['fmu']['max_rel_error']:.1e}"])
    lines.append(md_table(["model", "integration", "step vs predicted.csv (max)",
                           "inverse, reachable force (max)", "out of reach: misses (at an end)",
                           "validate_fmu problems", "simulate_fmu vs C (max)"], rows))
    lines += ["", "Step: max over every sample of the 12 held-out records of |mrjax_step - "
              "predicted| / force RMS (issue: <= 1e-9). Inverse: at every sample, the desired "
              "force is the force there under a random command in [0, 1] A; max |force at the "
              "returned command - desired| / force RMS (issue: <= 1e-6). Out of reach: for "
              "+-1e9 N at every sample, a miss is a command whose force is worse than the better "
              "end of the range's; in brackets, how often the command is exactly an end (the "
              "rest: the force is not monotone in the current there and the search finds the "
              "interior extreme). FMU: one record through `fmpy.simulate_fmu`, force at t_{k+1} against the "
              "C force of sample k (fmpy reads a co-simulation FMU's outputs after each step, "
              "before the next inputs).", "", "## Cost per sample (CPU time, median of "
              f"{doc['repeats']} passes over the held-out records)", ""]
    rows = []
    for r in doc["fitted"] + doc["timed"]:
        integ = r["integration"]
        how = ("static" if integ is None else integ if isinstance(integ, str) else
               f"{integ['scheme']}, {integ['substeps']} sub-steps")
        rows.append([r["model"], how, f"{r['step_ns']:.0f}", f"{r['inverse_ns']:.0f}"])
    lines.append(md_table(["model", "integration (scheme, sub-steps)", "mrjax_step [ns]",
                           "mrjax_inverse [ns]"], rows))
    lines += ["", "Goal (issue): <= 2 us per step and <= 20 us per inverse for the modified "
              "Bouc-Wen. The inverse evaluates only the force at the sample (64 grid points, "
              "then 40 bisection or golden-section steps), never the integration. The models "
              f"below the three with laws are fitted on one test ({PER_TEST}, `mrjax fit FILE "
              "--model M`: one parameter set, exported as it is), their integration chosen on "
              "the held-out records.", ""]
    fits = [f"{r['model']} {r['fit_s']['fit_s']:.0f} s (load {r['fit_s']['load'][0]:g})"
            for r in doc["fitted"] if r["fit_s"]]
    exports = [f"{r['model']} {r['export_c_s']:.1f} s (C), {r['export_fmu_s']:.1f} s (FMU)"
               for r in doc["fitted"]]
    if fits:
        lines.append(f"Fits (wall; reused fits were made by this script, their time kept "
                     f"beside them): {', '.join(fits)}.")
    lines.append(f"Exports (wall, with loading the 12 records): {'; '.join(exports)}.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fits", type=Path, default=None,
                    help="directory of the fits (DIR/kwok, DIR/modified_bouc_wen, DIR/my_tanh); "
                    "missing ones are fitted there (default: a temporary directory)")
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    data = default_data_dir()
    if data is None or not data.is_dir():
        log("UTFSM data not found (set MRJAX_DATA): nothing to do")
        return 0
    os.environ.setdefault("MRJAX_CACHE_DIR", "off")
    env = environment()
    load_start = loadavg()
    with tempfile.TemporaryDirectory(prefix="mrjax-bench-export-") as tmp:
        work = Path(tmp)
        fits = args.fits or work / "fits"
        done = []
        for name, model in FITTED.items():
            log(f"{name}...")
            done.append(fitted(name, model, data, fits, work, args.repeats))
        held = [data / f"{m}{c}A.txt" for m in MOTIONS for c in ("0x25", "0x75")]
        timed = []
        for name, model in TIMED.items():
            log(f"{name}...")
            timed.append(per_test(name, model, data, fits, held, work, args.repeats))
    gcc = subprocess.run(["gcc", "--version"], capture_output=True, text=True).stdout
    doc = {"environment": env, "load_start": load_start, "load_end": loadavg(),
           "command": "python -m benchmarks.export " + " ".join(argv or sys.argv[1:]),
           "gcc": gcc.splitlines()[0] if gcc else shutil.which("gcc"),
           "cflags": list(__import__("mrjax.export", fromlist=["CFLAGS"]).CFLAGS),
           "repeats": args.repeats, "fitted": done, "timed": timed}
    (HERE / "export.json").write_text(json.dumps(doc, indent=1) + "\n")
    (HERE / "export.md").write_text(render(doc))
    log("wrote benchmarks/export.json and benchmarks/export.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
