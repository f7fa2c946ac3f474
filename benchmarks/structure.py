"""A hysteretic element identified inside a structure (issue 40): the Bouc-Wen benchmark of
Noël & Schoukens (2016), simulated, identified by `mrjax.structure.fit`, and against SciPy.

    python -m benchmarks.structure [--posterior] [--scipy-iterations 2] [--out DIR]

**Data** (simulated here from the benchmark's published system; its data files are not used):
`m y'' + c y' + k y + z = u`, `z' = alpha y' - beta (gamma |y'| |z|^(nu-1) z + delta y' |z|^nu)`,
m = 2 kg, c = 10 N s/m, k = 5e4 N/m, alpha = 5e4 N/m, beta = 1e3 1/m, gamma = 0.8, delta = -1.1,
nu = 1; sampled at 750 Hz. The truth is integrated by classic Runge-Kutta at 20x the sample
rate (`truth`, written out here, apart from mrjax's simulation), the multisine input evaluated
exactly at every stage (its FFT interpolant is its own formula), the sweep from its formula.

- **Training**: a random-phase multisine, 5-150 Hz, 50 N RMS, periods of 8,192 samples;
  after 2 periods from rest, 4 periods in steady state (32,768 samples), plus white Gaussian
  output noise of 8e-6 m RMS (band-limited by the 750 Hz sampling).
- **Tests**, noise-free: a fresh multisine period in steady state (another seed), and a
  linear sine sweep of 40 N from 20 to 50 Hz at 10 Hz/min (180 s, 135,000 samples) from
  rest, crossing the resonance (about 35.6 Hz).

**Fit**: `mrjax.structure.fit(BenchmarkBoucWen, ...)` (`examples/structure_bouc_wen.py`: the
benchmark's form through the contract, beta held at 1e3), `SDOF(period=8192)`, defaults
otherwise; wall and CPU time of the first (cold: compilation included) call in this process.

**Errors**: RMS of simulated - true displacement on each test set, with the fitted and with the
true parameters (the floor of each input interpolation: zero-order hold, linear,
band-limited).

**Posterior** (`--posterior`): `mrjax.posterior` on the records' view (the first period),
95 % intervals against the truth.

**SciPy**: `scipy.optimize.least_squares` (trf, 2-point Jacobian, the same log coordinates
for m and alpha, the same box) over `scipy.integrate.solve_ivp` (RK45, rtol 1e-6) from mrjax's
start (the swarm's best), `--scipy-iterations` Jacobian evaluations; seconds per simulation and
per iteration, and the RMS reached.

Writes `benchmarks/structure.json`, `benchmarks/structure.md` and
`docs/how-to/structure_response.png`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from ._common import environment, loadavg, log, md_table

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
MODEL = f"{REPO / 'examples' / 'structure_bouc_wen.py'}:BenchmarkBoucWen"
FS, N = 750.0, 8192
TRUE = dict(m=2.0, c=10.0, k=5e4, alpha=5e4, beta=1e3, gamma=0.8, delta=-1.1, nu=1.0)
NOISE = 8e-6
SWEEP = dict(amplitude=40.0, f0=20.0, f1=50.0, rate_hz_per_s=10.0 / 60.0)
#: The truth's Runge-Kutta steps per sample.
TRUTH_SUBSTEPS = 20


# ------------------------------------------------------------------------------ the truth
def rhs(s, u, p, xp=np):
    """The benchmark's state rate (y, v, z) for input u [N] (NumPy or jax.numpy, `xp`)."""
    y, v, z = s[0], s[1], s[2]
    a = xp.abs(z)
    an = a ** p["nu"]  # |z|^(nu-1) z as sign(z) |z|^nu: finite at z = 0 for any nu
    zd = p["alpha"] * v - p["beta"] * (p["gamma"] * xp.abs(v) * xp.sign(z) * an
                                       + p["delta"] * v * an)
    return xp.stack([v, (u - p["c"] * v - p["k"] * y - z) / p["m"], zd])


def truth(u_stage, dt: float, substeps: int = TRUTH_SUBSTEPS) -> np.ndarray:
    """The displacement at every sample from rest: `u_stage` the input at every half step
    (2 substeps per sample interval, n_intervals * 2 substeps + 1 values)."""
    import jax
    import jax.numpy as jnp

    p = {k: jnp.asarray(v) for k, v in TRUE.items()}
    h = dt / substeps
    u = jnp.asarray(u_stage)

    def step(s, abc):
        a, b, c = abc
        k1 = rhs(s, a, p, jnp)
        k2 = rhs(s + 0.5 * h * k1, b, p, jnp)
        k3 = rhs(s + 0.5 * h * k2, b, p, jnp)
        k4 = rhs(s + h * k3, c, p, jnp)
        s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return s, s[0]

    _, ys = jax.jit(lambda u: jax.lax.scan(step, jnp.zeros(3), (u[0:-1:2], u[1::2], u[2::2])))(u)
    return np.r_[0.0, np.asarray(ys)[substeps - 1::substeps]]


def multisine(seed: int, up: int = 1) -> tuple[np.ndarray, dict]:
    """One period of the benchmark's multisine at `up` points per sample, and its lines."""
    rng = np.random.default_rng(seed)
    f = np.fft.rfftfreq(N, 1 / FS)
    lines = (f >= 5) & (f <= 150)
    amp = 50.0 * np.sqrt(2.0 / lines.sum())
    U = np.zeros(N * up // 2 + 1, complex)
    idx = np.flatnonzero(lines)
    U[idx] = amp * np.exp(1j * rng.uniform(0, 2 * np.pi, lines.sum())) * N * up / 2
    return np.fft.irfft(U, N * up), dict(f=f[lines], amp=amp, phase=np.angle(U[idx]))


def periodic_truth(seed: int, periods: int, settle: int = 2) -> tuple[np.ndarray, ...]:
    """(u, y) samples of `periods` periods after `settle` from rest, and the input's lines."""
    fine, lines = multisine(seed, 2 * TRUTH_SUBSTEPS)
    total = settle + periods
    y = truth(np.r_[np.tile(fine, total), fine[0]], 1 / FS)
    u = fine[:: 2 * TRUTH_SUBSTEPS]
    return np.tile(u, periods), y[settle * N: total * N], lines


def sweep_input(t: np.ndarray) -> np.ndarray:
    r = SWEEP["rate_hz_per_s"]
    return SWEEP["amplitude"] * np.sin(2 * np.pi * (SWEEP["f0"] * t + 0.5 * r * t * t))


def sweep_truth() -> tuple[np.ndarray, np.ndarray]:
    duration = (SWEEP["f1"] - SWEEP["f0"]) / SWEEP["rate_hz_per_s"]
    n = int(round(duration * FS))
    ts = np.arange((n - 1) * 2 * TRUTH_SUBSTEPS + 1) / (FS * 2 * TRUTH_SUBSTEPS)
    y = truth(sweep_input(ts), 1 / FS)
    return sweep_input(np.arange(n) / FS), y


# ------------------------------------------------------------------------------ sections
def data() -> dict:
    log("simulating the truth (RK4 at 20x the sample rate)...")
    u, y, lines = periodic_truth(0, 4)
    noise = NOISE * np.random.default_rng(1).standard_normal(y.size)
    ut, yt, _ = periodic_truth(2, 1)
    us, ys = sweep_truth()
    return dict(train=(u, y + noise, y), multisine=(ut, yt), sweep=(us, ys), lines=lines)


def fit_section(d: dict):
    import mrjax.structure as ms

    st = ms.SDOF(period=N)
    u, y, _ = d["train"]
    rec = ms.Record("train", np.arange(y.size) / FS, u, y)
    load0 = loadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    res = ms.fit(MODEL, rec, structure=st)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    log(f"fit: {wall:.1f} s wall, {cpu:.1f} s CPU")
    return st, rec, res, dict(wall_s=wall, cpu_s=cpu, load_before=load0, load_after=loadavg(),
                              stages_s=res.timings, substeps=res.substeps,
                              polish_steps=int(res.outcome.steps[0]),
                              swarm_generations=int(res.outcome.swarm.generations[0]),
                              status=res.status[0], rms_train_m=float(res.rms[0]))


def errors_section(d: dict, st, res) -> dict:
    """RMS errors [m] on each test set with the fitted and the true parameters, per
    interpolation; the fitted model's predictions for the figure."""
    import mrjax.structure as ms

    true_fit = dataclasses.replace(res, z=np.array([[TRUE[n] for n in res.names]]))
    sets = {"multisine": (d["multisine"], st),
            "sweep": (d["sweep"], dataclasses.replace(st, period=None))}
    out, preds = {}, {}
    for name, ((u, y), structure) in sets.items():
        rec = ms.Record(name, np.arange(y.size) / FS, u, y)
        for interp in (ms.BandLimited(), ms.Linear(), ms.ZeroOrderHold()):
            s = dataclasses.replace(structure, interpolation=interp)
            for who, f in (("fitted", res), ("true", true_fit)):
                p = f.predict(rec, structure=s)
                out[f"{name}/{interp.name}/{who}"] = dict(rms_m=float(p.rms[0]),
                                                         substeps=p.substeps)
                if who == "fitted" and interp.name == "fft":
                    preds[name] = p
        log(f"{name}: RMS error {out[f'{name}/fft/fitted']['rms_m']:.3g} m (fitted, fft)")
    return out, preds


def params_section(res, post=None) -> list[dict]:
    rows = []
    for j, n in enumerate(res.names):
        row = dict(name=n, unit=res.units[j], true=TRUE[n], value=float(res.z[0, j]),
                   stderr=float(res.stderr[0, j]), ci95=[float(v) for v in res.ci95[0, j]])
        row["in_ci95"] = bool(row["ci95"][0] <= TRUE[n] <= row["ci95"][1])
        if post is not None:
            lo, hi = post.interval(n, 0.95)[0]
            row.update(post_mean=float(np.mean(post.draws(n))), post_ci95=[float(lo), float(hi)],
                       in_post_ci95=bool(lo <= TRUE[n] <= hi))
        rows.append(row)
    for a, b in (("gamma", "beta*gamma"), ("delta", "beta*delta")):
        j = res.names.index(a)
        rows.append(dict(name=b, unit="1/m", true=TRUE["beta"] * TRUE[a],
                         value=TRUE["beta"] * float(res.z[0, j]),
                         stderr=TRUE["beta"] * float(res.stderr[0, j]),
                         ci95=[TRUE["beta"] * float(v) for v in res.ci95[0, j]],
                         in_ci95=rows[j]["in_ci95"]))
    return rows


def posterior_section(res, rec, draws: int, warmup: int, chains: int):
    import mrjax

    log(f"posterior ({chains} chains x {draws} draws after {warmup}, the records' view)...")
    t0, c0 = time.perf_counter(), time.process_time()
    post = mrjax.posterior(res, rec, sampler=mrjax.Sampler(draws=draws, warmup=warmup,
                                                           chains=chains), key=0)
    info = dict(wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0, draws=draws,
                warmup=warmup, chains=chains, diagnostics=post.diagnostics())
    return post, info


def scipy_section(d: dict, res, st, rec, iterations: int) -> dict:
    """SciPy's `least_squares` over `solve_ivp` on the same records, from the same start, in
    the same coordinates and box: `iterations` Jacobian evaluations (each 1 + 7 simulations
    of the 5 periods), with the time of one simulation and of one iteration."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import least_squares

    import mrjax.structure as ms

    lines = d["lines"]
    w, ph = 2 * np.pi * lines["f"], lines["phase"]
    periods = rec.n // N
    t_eval = np.arange((periods + 1) * N) / FS
    prob = ms.structure_problem(res.model, st, ms.stack([rec]), (res.lower, res.upper))
    names = res.names

    def simulate(z):
        p = dict(zip(names, z), beta=TRUE["beta"])

        def f(t, s):
            return rhs(s, lines["amp"] * np.sum(np.cos(w * t + ph)), p)

        sol = solve_ivp(f, (0, t_eval[-1]), [0.0, 0.0, 0.0], t_eval=t_eval, rtol=1e-6,
                        atol=1e-12)
        if not sol.success:
            return np.full(t_eval.size, 1e3)
        return sol.y[0]

    def residual(x):
        return simulate(prob.from_engine(x))[N:] - rec.response

    x0 = np.asarray(res.outcome.start.z[0], float)
    lo, hi = prob.to_engine(res.lower), prob.to_engine(res.upper)
    t0 = time.perf_counter()
    r0 = residual(x0)
    one = time.perf_counter() - t0
    log(f"scipy: one simulation {one:.1f} s; {iterations} iteration(s)...")
    if iterations == 0:  # the simulation's time only: a 2-point Jacobian costs 1 + K of them
        return dict(simulation_s=one, iterations=0, jacobians=0, time_s=0.0,
                    jacobian_estimate_s=one * (1 + int(np.sum(res.lower < res.upper))),
                    rms_start_m=float(np.sqrt(np.mean(r0 ** 2))))
    t0 = time.perf_counter()
    sol = least_squares(residual, x0, bounds=(lo, hi), method="trf", jac="2-point",
                        x_scale="jac", max_nfev=iterations)
    total = time.perf_counter() - t0
    return dict(simulation_s=one, iterations=int(sol.nfev), jacobians=int(sol.njev),
                time_s=total, rms_start_m=float(np.sqrt(np.mean(r0 ** 2))),
                rms_end_m=float(np.sqrt(np.mean(sol.fun ** 2))), status=int(sol.status),
                message=str(sol.message),
                z_end=dict(zip(names, map(float, prob.from_engine(sol.x)))))


def mrjax_simulation_s(res, st, rec) -> float:
    """Seconds of one warm simulation of the training records by mrjax (the polish's
    sub-steps), the median of 5."""
    import jax
    import jax.numpy as jnp

    import mrjax.structure as ms

    inp = jax.device_put(ms.step_inputs(ms.stack([rec]), st, res.substeps))
    f = jax.jit(jax.vmap(lambda z, i: ms.simulate(res.model, st, z, i)))
    z = jnp.asarray(res.z)
    jax.block_until_ready(f(z, inp))
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        jax.block_until_ready(f(z, inp))
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def figure(preds: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import mrjax.structure as ms
    from mrjax.report import save_png_bytes

    p1, p2 = preds["multisine"], preds["sweep"]
    both = dataclasses.replace(
        p1, labels=("fresh multisine", "40 N sine sweep"),
        n=np.r_[p1.n, p2.n], t=_pad2(p1.t, p2.t), predicted=_pad2(p1.predicted, p2.predicted),
        measured=_pad2(p1.measured, p2.measured), mask=_pad2(p1.mask, p2.mask),
        rms=np.r_[p1.rms, p2.rms], nrmse=np.r_[p1.nrmse, p2.nrmse])
    fig = ms.response_figure(both, title="Bouc-Wen benchmark (simulated): true vs simulated "
                             "displacement of the fitted structure")
    path.write_bytes(save_png_bytes(fig))


def _pad2(a, b):
    T = max(a.shape[1], b.shape[1])
    out = np.zeros((2, T), a.dtype)
    out[0, : a.shape[1]], out[1, : b.shape[1]] = a[0], b[0]
    return out


def markdown(doc: dict) -> str:
    f = doc["fit"]
    lines = ["# A hysteretic element inside a structure: the Bouc-Wen benchmark (simulated)", "",
             "`python -m benchmarks.structure` (see its docstring for the data and the method).",
             f"Machine: {doc['environment'].get('cpu_model', '?')}, "
             f"{doc['environment'].get('cpu_affinity', '?')} cores, "
             f"{doc['environment'].get('date')}; load average before/after the "
             f"fit {f['load_before']} / {f['load_after']}.", "",
             "## Fit (4 noisy periods of 8,192 samples)", "",
             f"Cold fit (compilation included): {f['wall_s']:.1f} s wall, {f['cpu_s']:.1f} s "
             f"CPU; stages {', '.join(f'{k} {v:.1f} s' for k, v in f['stages_s'].items())}. "
             f"Swarm {f['swarm_generations']} generations, polish {f['polish_steps']} steps "
             f"({f['status']}), {f['substeps']} Runge-Kutta steps per sample; RMS on the "
             f"training records {f['rms_train_m']:.3g} m (noise {NOISE:g} m).", ""]
    rows = [[p["name"], p["unit"], f"{p['true']:.6g}", f"{p['value']:.6g}", f"{p['stderr']:.3g}",
             f"[{p['ci95'][0]:.6g}, {p['ci95'][1]:.6g}]", "yes" if p["in_ci95"] else "NO"]
            + ([f"[{p['post_ci95'][0]:.6g}, {p['post_ci95'][1]:.6g}]",
                "yes" if p["in_post_ci95"] else "NO"] if "post_ci95" in p else [])
            for p in doc["parameters"]]
    head = ["parameter", "unit", "true", "fitted", "std-error", "95 % (linearised)", "covers"]
    if any("post_ci95" in p for p in doc["parameters"]):
        head += ["95 % (posterior)", "covers"]
    lines += [md_table(head, rows), "", "## Errors on noise-free test sets [m RMS]", ""]
    e = doc["errors"]
    rows = [[s, i, f'{e[f"{s}/{i}/fitted"]["rms_m"]:.3g}', f'{e[f"{s}/{i}/true"]["rms_m"]:.3g}',
             e[f"{s}/{i}/fitted"]["substeps"]]
            for s in ("multisine", "sweep") for i in ("fft", "linear", "zoh")]
    lines += [md_table(["test set", "interpolation", "fitted", "true parameters (floor)",
                        "steps/sample"], rows), ""]
    if "scipy" in doc:
        s = doc["scipy"]
        if s["iterations"] == 0:
            lines += ["## SciPy (solve_ivp, RK45, rtol 1e-6)", "",
                      f"One simulation of the 5 periods: SciPy {s['simulation_s']:.1f} s, mrjax "
                      f"{doc['mrjax_simulation_s']:.3f} s (warm); one 2-point Jacobian of "
                      f"`least_squares` would take about {s['jacobian_estimate_s']:.0f} s "
                      f"(1 + K simulations), against the whole mrjax fit's "
                      f"{f['wall_s']:.0f} s.", ""]
        else:
            lines += ["## SciPy (least_squares over solve_ivp, same start)", "",
                      f"One simulation of the 5 periods: SciPy {s['simulation_s']:.1f} s, mrjax "
                      f"{doc['mrjax_simulation_s']:.3f} s (warm). {s['iterations']} SciPy "
                      f"iteration(s) ({s['jacobians']} Jacobian(s)) in {s['time_s']:.0f} s: RMS "
                      f"{s['rms_start_m']:.3g} -> {s['rms_end_m']:.3g} m; mrjax's polish took "
                      f"{f['polish_steps']} steps from the same start.", ""]
    if "posterior" in doc:
        p = doc["posterior"]
        lines += ["## Posterior", "", f"{p['chains']} chains x {p['draws']} draws after "
                  f"{p['warmup']} warmup, on the records' view: {p['wall_s']:.0f} s wall, "
                  f"{p['cpu_s']:.0f} s CPU.", ""]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--posterior", action="store_true", help="also sample the posterior")
    ap.add_argument("--draws", type=int, default=300)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--chains", type=int, default=2)
    ap.add_argument("--scipy-iterations", type=int, default=1,
                    help="SciPy iterations (0: time one SciPy simulation only; -1: skip SciPy)")
    ap.add_argument("--out", default=str(HERE))
    args = ap.parse_args(argv)
    out = Path(args.out)
    d = data()
    st, rec, res, fit_info = fit_section(d)
    errors, preds = errors_section(d, st, res)
    post = None
    doc = dict(environment=environment(), fit=fit_info, errors=errors)
    if args.posterior:
        post, doc["posterior"] = posterior_section(res, rec, args.draws, args.warmup,
                                                   args.chains)
    doc["parameters"] = params_section(res, post)
    doc["mrjax_simulation_s"] = mrjax_simulation_s(res, st, rec)
    if args.scipy_iterations >= 0:
        doc["scipy"] = scipy_section(d, res, st, rec, args.scipy_iterations)
    (out / "structure.json").write_text(json.dumps(doc, indent=2, default=float) + "\n")
    (out / "structure.md").write_text(markdown(doc))
    figure(preds, REPO / "docs" / "how-to" / "structure_response.png")
    log(f"wrote {out / 'structure.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
