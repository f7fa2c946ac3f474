"""Time-varying command (issue 15): Spencer et al.'s 1997 voltage-dependent modified Bouc-Wen
model identified from random-command records, at full size.

    python -m benchmarks.command [--duration 20] [--rate 3000]

1. **Known answer.** Simulate the model (PAPER.md, eta = 190 1/s) under band-limited random
   displacement (+-1 cm, 0.1-5 Hz) and a random command voltage (0-2.25 V held 0.1-0.5 s), 3 kHz
   for 20 s, noise 2 % of max|F| (`mrjax.generalize.command_record`, seed 1); identify it from
   that record alone (`mrjax.generalize.identify`, swarm seed 0, lag fitted); compare every
   coefficient with the truth (on the |z|max = 1 scale) and validate on a record of seed 2
   against the true model's NRMSE.
2. **Mixed campaign.** Sine tests at 0, 1 and 2 V (2 Hz, 1 cm, 1 kHz) plus the seed-1 record
   -> predict the seed-2 record.
3. **Inverse.** Desired force = the noise-free true force of a record of seed 3 -> command
   (`mrjax.generalize.inverse`, identified model) -> the identified model's force replayed under
   that command: RMS error / max|F|; the same with 1.5 x the force (partly out of reach: the
   flagged fraction). A closed-loop simulation (`mrjax.generalize.closed_loop`): a one-storey
   structure on a random ground motion with a skyhook law, against the passive off/on
   dampers.

Writes `benchmarks/command.json` and `benchmarks/command.md` (wall times measured on this
machine, cold: compilation included) and the figures `benchmarks/command_*.png`.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _coef_table(gm, truth, stderr) -> list[dict]:
    rows = []
    tc = truth.with_canonical_z()
    for n in gm.param_names:
        got, want = np.asarray(gm.coefficients(n)), np.asarray(tc.coefficients(n))
        se = np.asarray(stderr.get(n, [np.nan] * got.size), float) if stderr else \
            np.full(got.size, np.nan)
        for k in range(got.size):
            rel = abs(got[k] - want[k]) / abs(want[k])
            z = abs(got[k] - want[k]) / se[k] if se[k] > 0 else np.inf
            rows.append({"param": n if got.size == 1 else f"{n}[{k}]", "true": float(want[k]),
                         "recovered": float(got[k]), "stderr": float(se[k]),
                         "rel_err_pct": 100 * float(rel), "z": float(z),
                         "ok": bool(rel <= 0.05 or z <= 2.0)})
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; write command.json, command.md and the figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--rate", type=float, default=3000.0)
    ap.add_argument("--no-mixed", action="store_true")
    ap.add_argument("--reuse", action="store_true",
                    help="keep the identifications stored in command.json; rerun the inverse, "
                    "the closed loop and the figures")
    ap.add_argument("--render-only", action="store_true",
                    help="rewrite command.md from command.json")
    a = ap.parse_args(argv)
    if a.render_only:
        (HERE / "command.md").write_text(render(json.loads((HERE / "command.json").read_text())))
        return 0
    t_import = time.perf_counter()
    import mrjax  # noqa: F401  (the import time is reported)
    from mrjax.data import make_batch
    from mrjax.generalize import GeneralizedModel, command_record, spencer_1997
    from mrjax.pso import PSOParams

    from ._common import environment, loadavg, log

    t_import = time.perf_counter() - t_import
    truth = spencer_1997()
    dur, fs = a.duration, a.rate
    rec = command_record(truth, duration=dur, sample_rate=fs, seed=1)
    val = command_record(truth, duration=dur, sample_rate=fs, seed=2)
    vb = make_batch([val])
    nr_true = float(truth.evaluate(vb)["nrmse"][0])
    nr_true_fit = float(truth.evaluate(make_batch([rec]))["nrmse"][0])
    pso = PSOParams(window=25, min_generations=100)
    out: dict = {"environment": environment(), "import_s": t_import, "duration_s": dur,
                 "sample_rate_Hz": fs, "n_samples": int(rec.t.size)}
    if a.reuse:
        out = json.loads((HERE / "command.json").read_text())
        gm = GeneralizedModel.from_dict(out["known_answer"]["generalized"])
        out["inverse_rerun"] = time.strftime("%Y-%m-%d %H:%M:%S %Z")
    else:
        gm = _identify_all(a, out, truth, rec, val, vb, nr_true, nr_true_fit, pso)
    _inverse_and_loop(gm, truth, out, dur, fs)
    try:
        from mrjax.report import plot_command_record, plot_laws_vs_command

        figs = {"command_force.png": plot_command_record(gm, val, reference=truth),
                "command_laws.png": plot_laws_vs_command(gm, reference=truth)}
        for name, fig in figs.items():
            fig.savefig(HERE / name, dpi=90)
        log(f"figures: {sorted(figs)}")
    except ImportError:
        pass
    out["loadavg_end"] = loadavg()
    (HERE / "command.json").write_text(json.dumps(out, indent=1, default=float))
    (HERE / "command.md").write_text(render(out))
    print(render(out))
    return 0


def _identify_all(a, out, truth, rec, val, vb, nr_true, nr_true_fit, pso):
    """The known answer and the mixed campaign; fills `out`, returns the identified laws."""
    from mrjax import Swarm
    from mrjax.data import make_batch
    from mrjax.generalize import identify, sine_record

    from ._common import log

    dur, fs = a.duration, a.rate
    log(f"known answer: identify from one {dur:g} s, {fs:g} Hz record...")
    t0 = time.perf_counter()
    gm = identify(rec, "modified_bouc_wen", lag="fit", key=0, swarm=Swarm(params=pso))
    wall = time.perf_counter() - t0
    unc = gm.uncertainty
    table = _coef_table(gm, truth, unc.stderr if unc else None)
    eta_err = abs(gm.lag - truth.lag) / truth.lag
    nr_val = float(gm.evaluate(vb)["nrmse"][0])
    nr_fit = float(gm.evaluate(make_batch([rec]))["nrmse"][0])
    out["known_answer"] = {
        "wall_s": wall, "timings_s": gm.report.timings, "table": table,
        "eta_true": truth.lag, "eta": gm.lag,
        "eta_stderr": unc.lag_stderr if unc else None, "eta_rel_err_pct": 100 * eta_err,
        "all_ok": all(r["ok"] for r in table) and eta_err <= 0.10,
        "nrmse_fit_pct": 100 * nr_fit, "nrmse_fit_true_pct": 100 * nr_true_fit,
        "nrmse_val_pct": 100 * nr_val, "nrmse_val_true_pct": 100 * nr_true,
        "val_gap_points": 100 * (nr_val - nr_true),
        "polish_steps": list(gm.report.polish_steps), "generalized": gm.to_dict(),
    }
    log(f"  {wall:.1f} s, eta {gm.lag:.1f}, validation NRMSE {100 * nr_val:.3f} % "
        f"(true {100 * nr_true:.3f} %)")

    if not a.no_mixed:
        log("mixed campaign: sine tests at 0, 1, 2 V + the random record...")
        sines = [sine_record(truth, lv, seed=10 + k) for k, lv in enumerate((0.0, 1.0, 2.0))]
        t0 = time.perf_counter()
        gm_mix = identify(sines + [rec], "modified_bouc_wen", lag="fit", key=0,
                          swarm=Swarm(params=pso))
        wall_mix = time.perf_counter() - t0
        nr_mix = float(gm_mix.evaluate(vb)["nrmse"][0])
        out["mixed"] = {"wall_s": wall_mix, "eta": gm_mix.lag, "nrmse_val_pct": 100 * nr_mix,
                        "nrmse_val_true_pct": 100 * nr_true,
                        "val_gap_points": 100 * (nr_mix - nr_true),
                        "generalized": gm_mix.to_dict()}
        log(f"  {wall_mix:.1f} s, validation NRMSE {100 * nr_mix:.3f} %")
    return gm


def _inverse_and_loop(gm, truth, out, dur, fs) -> None:
    """The inverse round trip and the closed loop of the identified laws `gm`."""
    from mrjax.generalize import closed_loop, command_record, inverse, random_motion

    from ._common import log

    log("inverse round trip...")
    r3 = command_record(truth, duration=min(dur, 5.0), sample_rate=fs, noise=0.0, seed=3)
    dt = 1.0 / fs
    fd = np.asarray(r3.force)
    fmax = float(np.max(np.abs(fd)))
    t0 = time.perf_counter()
    inv = inverse(gm, r3.x, r3.xdot, fd, dt=dt)
    back = np.asarray(gm.force(r3.x, r3.xdot, dt, np.asarray(inv.command)))
    wall_inv = time.perf_counter() - t0
    reach = ~np.asarray(inv.out_of_reach)
    inv2 = inverse(gm, r3.x, r3.xdot, 1.5 * fd, dt=dt)
    out["inverse"] = {
        "wall_s": wall_inv, "n_samples": int(fd.size),
        "reachable_fraction": float(reach.mean()),
        "rms_err_pct_of_max": 100 * float(np.sqrt(np.mean((back - fd)[reach] ** 2))) / fmax,
        "x1.5_out_of_reach_fraction": float(np.asarray(inv2.out_of_reach).mean()),
        "x1.5_saturated_fraction": float(np.asarray(inv2.saturated).mean()),
    }
    log(f"  round trip RMS {out['inverse']['rms_err_pct_of_max']:.2e} % of max|F|")

    fs_cl = 1000.0
    _, _, vg = random_motion(10.0, fs_cl, amplitude=0.02, band=(0.5, 5.0), seed=4)
    ag = np.gradient(vg, 1.0 / fs_cl)
    mass, f_n = 200.0, 1.5
    k = mass * (2 * np.pi * f_n) ** 2
    cl = {}
    t0 = time.perf_counter()
    for c in ("off", "on", "inverse"):
        s = closed_loop(gm, ag, 1.0 / fs_cl, mass=mass, stiffness=k, gain=10000.0, control=c)
        x, f, want = (np.asarray(v) for v in (s.x, s.force, s.desired))
        cl[c] = {"rms_x_mm": 1e3 * float(np.sqrt(np.mean(x ** 2))),
                 "max_x_mm": 1e3 * float(np.max(np.abs(x))),
                 "rms_force_N": float(np.sqrt(np.mean(f ** 2))),
                 "tracking_rms_N": float(np.sqrt(np.mean((f - want) ** 2)))}
    cl["wall_s"] = time.perf_counter() - t0
    cl["setup"] = (f"one storey {mass:g} kg, {f_n:g} Hz, no structural damping; ground motion "
                   f"band-limited 0.5-5 Hz, 2 cm; skyhook f_d = 10000 N s/m x xdot; 1 kHz, 10 s")
    out["closed_loop"] = cl
    log(f"  closed loop: rms x off {cl['off']['rms_x_mm']:.2f} mm, on "
        f"{cl['on']['rms_x_mm']:.2f} mm, inverse {cl['inverse']['rms_x_mm']:.2f} mm")


def render(out: dict) -> str:
    """The Markdown report of a result dict."""
    ka = out["known_answer"]
    env = out["environment"]
    lines = [
        "# Time-varying command: Spencer 1997 known answer",
        "",
        f"Machine: {env.get('cpu', env.get('cpu_model', '?'))}, "
        f"{env.get('cpu_count', env.get('n_cpu', '?'))} CPU cores (shared with other jobs; load "
        f"{out.get('loadavg_end', 'load average not recorded')} at the end of the last run). "
        "Cold: JAX compilation included.",
        "",
        f"Record: {out['duration_s']:g} s at {out['sample_rate_Hz']:g} Hz "
        f"({out['n_samples']} samples), noise 2 % of max|F|.",
        "",
        f"**Identification: {ka['wall_s']:.1f} s** (stages: " + ", ".join(
            f"{k} {v:.1f} s" for k, v in ka["timings_s"].items() if k != "total") + ").",
        "",
        "| parameter | true | recovered | std-err | error % | error / std-err | ok |",
        "|---|---:|---:|---:|---:|---:|:-:|",
    ]
    for r in ka["table"]:
        lines.append(f"| {r['param']} | {r['true']:.5g} | {r['recovered']:.5g} | "
                     f"{r['stderr']:.3g} | {r['rel_err_pct']:.2f} | {r['z']:.2f} | "
                     f"{'yes' if r['ok'] else 'NO'} |")
    lines += [
        f"| eta [1/s] | {ka['eta_true']:g} | {ka['eta']:.4g} | {ka['eta_stderr'] or float('nan'):.3g} "
        f"| {ka['eta_rel_err_pct']:.2f} | | {'yes' if ka['eta_rel_err_pct'] <= 10 else 'NO'} |",
        "",
        "(the Bouc-Wen z-scale on |z|max = 1; ok = within 5 % or 2 std-errors, eta within 10 %)",
        "",
        f"NRMSE on the fitted record {ka['nrmse_fit_pct']:.3f} % (true model "
        f"{ka['nrmse_fit_true_pct']:.3f} %); **validation (seed 2) {ka['nrmse_val_pct']:.3f} % "
        f"against the true model's {ka['nrmse_val_true_pct']:.3f} %: "
        f"{ka['val_gap_points']:+.3f} points**.",
        "",
    ]
    if "mixed" in out:
        mx = out["mixed"]
        lines += [f"**Mixed campaign** (sines at 0, 1, 2 V + the random record, "
                  f"{mx['wall_s']:.1f} s): validation NRMSE {mx['nrmse_val_pct']:.3f} % against "
                  f"{mx['nrmse_val_true_pct']:.3f} % ({mx['val_gap_points']:+.3f} points), "
                  f"eta {mx['eta']:.4g} 1/s.", ""]
    iv = out["inverse"]
    if "inverse_rerun" in out:
        lines += [f"(Inverse, closed loop and figures rerun on the stored laws, `--reuse`, "
                  f"{out['inverse_rerun']}.)", ""]
    lines += [f"**Inverse** ({iv['n_samples']} samples, {iv['wall_s']:.1f} s): round trip "
              f"desired force -> command -> model force, RMS error "
              f"{iv['rms_err_pct_of_max']:.2e} % of max|F| on the {100 * iv['reachable_fraction']:.1f} % "
              f"of samples within reach; at 1.5 x the force {100 * iv['x1.5_out_of_reach_fraction']:.1f} % "
              f"flagged out of reach ({100 * iv['x1.5_saturated_fraction']:.1f} % saturated).", ""]
    cl = out["closed_loop"]
    lines += [f"**Closed loop** ({cl['setup']}; {cl['wall_s']:.1f} s for the three runs):", "",
              "| damper | RMS x [mm] | max x [mm] | RMS force [N] |", "|---|---:|---:|---:|"]
    for c in ("off", "on", "inverse"):
        r = cl[c]
        lines.append(f"| {'skyhook via inverse' if c == 'inverse' else 'passive ' + c} | "
                     f"{r['rms_x_mm']:.2f} | {r['max_x_mm']:.2f} | {r['rms_force_N']:.0f} |")
    lines += ["", "![force against time](command_force.png)", "",
              "![laws against the command](command_laws.png)"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
