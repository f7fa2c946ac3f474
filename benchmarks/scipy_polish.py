"""The modified Bouc-Wen polish the way a SciPy user would write it, against mrjax's.

    python -m benchmarks.scipy_polish [--tests 2mm5Hz0x5A,10mm1Hz0x5A,25mm0x5Hz0x5A]

For a few UTFSM tests (read from $MRJAX_DATA or ../shared/data/utfsm; never committed): mrjax's
swarm gives one start per test (`mrjax.fit(..., polish=None)`, seed 0). From that same start

- **SciPy**: `scipy.optimize.least_squares` (trust-region reflective, bounds = the model's box,
  `x_scale="jac"`) on residuals computed by `scipy.integrate.solve_ivp` (LSODA, rtol 1e-6,
  atol 1e-9) of Spencer's equations, the excitation linearly interpolated between samples;
  finite-difference Jacobian. One test at a time, as a script would.
- **mrjax**: `mrjax.fitting.polish_fit` on the same tests (the engine's polish stage: one
  compiled, batched program; its compilation is timed separately).

Prints and writes `benchmarks/scipy_polish.json`: wall time per test and the NRMSE each
reaches (RMS / max|F|), on the 2-core CPU the numbers in the README were measured on.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from ._common import HERE, default_data_dir, environment, log

DEFAULT_TESTS = ("2mm5Hz0x5A", "10mm1Hz0x5A", "25mm0x5Hz0x5A")


def spencer_residuals(cond: dict, rtol: float = 1e-6, atol: float = 1e-9):
    """Residual function `r(theta) -> (T,)` [N] of the modified Bouc-Wen model on one test by
    `solve_ivp` (LSODA), as a SciPy user writes it."""
    from scipy.integrate import solve_ivp

    t, x, v, F = cond["t"], cond["x"], cond["xdot"], cond["force"]

    def rhs(ti, s, th):
        c0, k0, c1, k1, al, de, be, ga, n, f0 = th
        xi, vi = np.interp(ti, t, x), np.interp(ti, t, v)
        y, z = s
        yd = (c0 * vi + k0 * (xi - y) + al * z) / (c0 + c1)
        u = vi - yd
        az = abs(z) ** n
        zd = de * u - be * u * az - ga * abs(u) * az * np.sign(z)
        return [yd, zd]

    def residuals(th):
        sol = solve_ivp(rhs, (t[0], t[-1]), [x[0], 0.0], method="LSODA", t_eval=t, args=(th,),
                        rtol=rtol, atol=atol)
        if not sol.success or sol.y.shape[1] != t.shape[0]:
            return np.full(t.shape, 1e6)
        y, z = sol.y
        c0, k0, c1, k1, al, de, be, ga, n, f0 = th
        yd = (c0 * v + k0 * (x - y) + al * z) / (c0 + c1)
        return c1 * yd + k1 * x + f0 - F

    return residuals


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--tests", default=",".join(DEFAULT_TESTS))
    ap.add_argument("--data", default=None)
    ap.add_argument("--careful", action="store_true",
                    help="the careful user's settings: LSODA at rtol 1e-9, atol 1e-11 and "
                    "least_squares(diff_step=1e-5), so that the finite-difference Jacobian "
                    "is not integration noise (the default run stops on xtol within ~10 "
                    "evaluations); writes scipy_polish_careful.json")
    ap.add_argument("--max-nfev", type=int, default=220,
                    help="SciPy's cap on residual evaluations per test (default 220: 20 "
                    "finite-difference Jacobians of the 10 parameters)")
    args = ap.parse_args(argv)

    from scipy.optimize import least_squares

    import mrjax
    from mrjax.data import load, make_batch
    from mrjax.fitting import polish_fit

    d = args.data or default_data_dir()
    if d is None:
        print("UTFSM data not found: set MRJAX_DATA or pass --data DIR")
        return 2
    names = args.tests.split(",")
    conds = [c for c in load(d) if c.label in names]
    batch = make_batch(conds)
    model = mrjax.models.get("modified_bouc_wen")
    log("swarm starts (mrjax, polish=None, seed 0)")
    start = mrjax.fit(model, batch, polish=None, key=0)
    lo, hi = model.bounds
    settings = mrjax.Polish(max_steps=200, retry=False)
    t0 = time.perf_counter()
    pol = polish_fit(start, batch, polish=settings)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    pol = polish_fit(start, batch, polish=settings)
    warm = time.perf_counter() - t0
    rows = []
    for i, c in enumerate(conds):
        fmax = float(np.max(np.abs(c.force)))
        tols = dict(rtol=1e-9, atol=1e-11) if args.careful else {}
        r = spencer_residuals({"t": c.t, "x": c.x, "xdot": c.xdot, "force": c.force}, **tols)
        th0 = np.clip(start.theta[i], lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
        log(f"SciPy least_squares + solve_ivp on {c.label} ({c.n_samples} samples)")
        t0 = time.perf_counter()
        sol = least_squares(r, th0, bounds=(lo, hi), x_scale="jac", max_nfev=args.max_nfev,
                            diff_step=1e-5 if args.careful else None)
        wall = time.perf_counter() - t0
        rows.append({"test": c.label, "samples": c.n_samples,
                     "start_nrmse_pct": 100 * float(start.rms[i]) / fmax,
                     "scipy_nrmse_pct": 100 * float(np.sqrt(np.mean(sol.fun ** 2))) / fmax,
                     "scipy_s": wall, "scipy_nfev": int(sol.nfev),
                     "scipy_status": int(sol.status), "scipy_s_per_eval": wall / max(1, sol.nfev),
                     "mrjax_nrmse_pct": 100 * float(pol.rms[i]) / fmax})
        log(f"  {rows[-1]}")
    out = {"environment": environment(), "tests": rows, "mrjax_polish_warm_s": warm,
           "mrjax_polish_first_s": first, "scipy_total_s": sum(r["scipy_s"] for r in rows)}
    out["ratio_scipy_over_mrjax_warm"] = out["scipy_total_s"] / warm
    name = "scipy_polish_careful.json" if args.careful else "scipy_polish.json"
    out["settings"] = {"careful": args.careful, "max_nfev": args.max_nfev}
    (HERE / name).write_text(json.dumps(out, indent=1))
    print(json.dumps({k: v for k, v in out.items() if k != "environment"}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
