"""The baselines mrjax is compared against, written as a user would write them.

- NumPy fitness of the tanh model, vectorised over particles (one condition at a time).
- NumPy RK4 of the Bouc-Wen and modified Bouc-Wen models: the same fixed-step RK4 as
  `mrjax.models.integrate` (same sub-steps, linear interpolation of the excitation inside a
  sample interval), vectorised over particles with a Python loop over time.
- pyswarms `GlobalBestPSO`, SciPy `differential_evolution` and evosax `PSO` drivers.

Each NumPy fitness works on one condition's real (unpadded) samples.
"""

from __future__ import annotations

import numpy as np

# ------------------------------------------------------------------------------ data


def conditions_numpy(batch, mask=None):
    """Per-condition unpadded host arrays: list of dicts x, xdot, force, dt."""
    m = np.asarray(batch.mask if mask is None else mask)
    out = []
    for i in range(batch.n_conditions):
        n = int(m[i].sum())
        out.append({k: np.asarray(getattr(batch, k))[i, :n] for k in ("x", "xdot", "force", "dt")})
    return out


# ------------------------------------------------------------------------------ tanh model


def tanh_fitness(cond):
    """RMS [N] of the tanh model (Kwok eq 7-8) for particles P (N, 6), vectorised over N."""
    x, v, F = cond["x"], cond["xdot"], cond["force"]
    sg = np.sign(x)

    def f(P):
        P = np.atleast_2d(P)
        c, k, a, b, d, f0 = (P[:, j : j + 1] for j in range(6))
        pred = c * v + k * x + a * np.tanh(b * v + d * sg) + f0
        r = np.sqrt(np.mean((pred - F) ** 2, axis=1))
        return np.where(np.isfinite(r), r, np.inf)

    return f


# ------------------------------------------------------------------------------ ODE models


def _bw_zdot(z, u, de, be, ga, n):
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return de * u - np.abs(z) ** n * (be * u + ga * np.abs(u) * np.sign(z))


def bouc_wen_fitness(cond, substeps):
    """RMS [N] of the Bouc-Wen model for particles P (N, 8): NumPy RK4, loop over time."""
    x, v, F, dt = cond["x"], cond["xdot"], cond["force"], cond["dt"]
    m = int(substeps)
    T = x.shape[0]

    def f(P):
        P = np.atleast_2d(P)
        c, k, al, f0, de, be, ga, n = (P[:, j] for j in range(8))
        z = np.zeros(P.shape[0])
        Z = np.empty((T, P.shape[0]))
        Z[0] = z
        for i in range(T - 1):
            v0, dv, h = v[i], v[i + 1] - v[i], dt[i] / m
            for j in range(m):
                s0 = j / m
                ua, ub, uc = v0 + s0 * dv, v0 + (s0 + 0.5 / m) * dv, v0 + (s0 + 1.0 / m) * dv
                k1 = _bw_zdot(z, ua, de, be, ga, n)
                k2 = _bw_zdot(z + 0.5 * h * k1, ub, de, be, ga, n)
                k3 = _bw_zdot(z + 0.5 * h * k2, ub, de, be, ga, n)
                k4 = _bw_zdot(z + h * k3, uc, de, be, ga, n)
                z = z + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            Z[i + 1] = z
        with np.errstate(over="ignore", invalid="ignore"):
            pred = c * v[:, None] + k * x[:, None] + al * Z + f0
            r = np.sqrt(np.mean((pred - F[:, None]) ** 2, axis=0))
        return np.where(np.isfinite(r), r, np.inf)

    return f


def modified_bouc_wen_fitness(cond, substeps):
    """RMS [N] of the modified Bouc-Wen model (Spencer 1997) for particles P (N, 10)."""
    x, v, F, dt = cond["x"], cond["xdot"], cond["force"], cond["dt"]
    m = int(substeps)
    T = x.shape[0]

    def f(P):
        P = np.atleast_2d(P)
        c0, k0, c1, k1, al, de, be, ga, n, f0 = (P[:, j] for j in range(10))
        D = c0 + c1

        def rhs(y, z, xi, u):
            with np.errstate(over="ignore", invalid="ignore"):
                yd = (c0 * u + k0 * (xi - y) + al * z) / D
            return yd, _bw_zdot(z, u - yd, de, be, ga, n)

        y = np.full(P.shape[0], x[0])
        z = np.zeros(P.shape[0])
        Y, Zs = np.empty((T, P.shape[0])), np.empty((T, P.shape[0]))
        Y[0], Zs[0] = y, z
        for i in range(T - 1):
            x0, dx, v0, dv, h = x[i], x[i + 1] - x[i], v[i], v[i + 1] - v[i], dt[i] / m
            for j in range(m):
                s0 = j / m
                sa, sb, sc = s0, s0 + 0.5 / m, s0 + 1.0 / m
                ay, az = rhs(y, z, x0 + sa * dx, v0 + sa * dv)
                by, bz = rhs(y + 0.5 * h * ay, z + 0.5 * h * az, x0 + sb * dx, v0 + sb * dv)
                cy, cz = rhs(y + 0.5 * h * by, z + 0.5 * h * bz, x0 + sb * dx, v0 + sb * dv)
                dy, dz = rhs(y + h * cy, z + h * cz, x0 + sc * dx, v0 + sc * dv)
                y = y + (h / 6.0) * (ay + 2.0 * by + 2.0 * cy + dy)
                z = z + (h / 6.0) * (az + 2.0 * bz + 2.0 * cz + dz)
            Y[i + 1], Zs[i + 1] = y, z
        with np.errstate(over="ignore", invalid="ignore"):
            yd = (c0 * v[:, None] + k0 * (x[:, None] - Y) + al * Zs) / D
            pred = c1 * yd + k1 * x[:, None] + f0
            r = np.sqrt(np.mean((pred - F[:, None]) ** 2, axis=0))
        return np.where(np.isfinite(r), r, np.inf)

    return f


NUMPY_FITNESS = {"bouc_wen": bouc_wen_fitness, "modified_bouc_wen": modified_bouc_wen_fitness}


# ------------------------------------------------------------------------------ optimisers


def pyswarms_fit(conds, lower, upper, *, iters=100, n_particles=50, seed=0):
    """pyswarms GlobalBestPSO on each condition in turn: (best cost (C,), best pos (C, D)).

    Settings as close to mrjax's as pyswarms allows: w = 0.65, c1 = c2 = 2 (pyswarms multiplies
    them by U[0, 1] per particle and dimension, as mrjax does with c_max = 2), 50 particles,
    the same box, out-of-bounds positions clipped onto the wall (`bh_strategy="nearest"`).
    pyswarms has no per-dimension velocity clamp (mrjax clamps to the box width) and keeps the
    velocity of a clipped particle (mrjax zeroes it).
    """
    import logging

    from pyswarms.single import GlobalBestPSO

    logging.getLogger("pyswarms").setLevel(logging.WARNING)
    costs, poss = [], []
    for i, cond in enumerate(conds):
        np.random.seed(seed + i)  # pyswarms draws from NumPy's global generator
        opt = GlobalBestPSO(
            n_particles=n_particles,
            dimensions=len(lower),
            options={"c1": 2.0, "c2": 2.0, "w": 0.65},
            bounds=(np.asarray(lower), np.asarray(upper)),
            bh_strategy="nearest",
        )
        cost, pos = opt.optimize(tanh_fitness(cond), iters=iters, verbose=False)
        costs.append(cost)
        poss.append(pos)
    return np.asarray(costs), np.asarray(poss)


def de_fit(conds, lower, upper, *, maxiter=100, popsize=8, seed=0, vectorized=True):
    """SciPy differential_evolution per condition at ~ the PSO's evaluation budget:
    population popsize x D = 48 for D = 6, (maxiter + 1) x 48 = 4848 evaluations (PSO:
    50 x 101 = 5050); `tol=0` so that it runs every iteration, no final polish."""
    from scipy.optimize import differential_evolution

    costs, nfev = [], []
    for i, cond in enumerate(conds):
        f = tanh_fitness(cond)
        if vectorized:
            fun = lambda X, f=f: f(np.asarray(X).T)  # noqa: E731  (D, S) -> (S,)
        else:
            fun = lambda x, f=f: float(f(x[None])[0])  # noqa: E731
        r = differential_evolution(
            fun,
            list(zip(lower, upper)),
            maxiter=maxiter,
            popsize=popsize,
            tol=0.0,
            atol=0.0,
            polish=False,
            seed=seed + i,
            updating="deferred" if vectorized else "immediate",
            vectorized=vectorized,
        )
        costs.append(r.fun)
        nfev.append(r.nfev)
    return np.asarray(costs), np.asarray(nfev)


def evosax_runner(objective, lower, upper, *, n_particles=50, generations=100):
    """evosax `PSO` (ask/tell), vmapped by hand over conditions, `lax.scan` over generations,
    fitness = the same mrjax objective. Positions leaving the box are clipped onto it (evosax's
    PSO has no bounds). evosax shares r1, r2 across dimensions and uses w = 0.65, c1 = c2 = 2.

    Returns a jitted `run(keys (C,), data) -> best fitness (C,)`.
    """
    import jax
    import jax.numpy as jnp
    from evosax.algorithms import PSO

    lo, hi = jnp.asarray(lower), jnp.asarray(upper)
    es = PSO(population_size=n_particles, solution=jnp.zeros(lo.shape[0], lo.dtype))
    params = es.default_params.replace(inertia_coeff=0.65, cognitive_coeff=2.0, social_coeff=2.0)
    fitness = jax.vmap(objective, in_axes=(0, None))

    def one(key, data):
        k0, k1, k2 = jax.random.split(key, 3)
        pop = lo + jax.random.uniform(k0, (n_particles, lo.shape[0]), lo.dtype) * (hi - lo)
        fit = fitness(pop, data)
        state = es.init(k1, pop, fit, params)

        def gen(state, k):
            x, state = es.ask(k, state, params)
            # evosax draws its coefficients in JAX's default float: keep the swarm's dtype
            x = jnp.clip(x, lo, hi).astype(lo.dtype)
            f = fitness(x, data).astype(lo.dtype)
            f = jnp.where(jnp.isnan(f), jnp.inf, f)
            state, _ = es.tell(k, x, f, state, params)
            return state, None

        state, _ = jax.lax.scan(gen, state, jax.random.split(k2, generations))
        return state.best_fitness

    return jax.jit(jax.vmap(one))
