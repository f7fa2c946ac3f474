"""The declaration of a user's model: its parameters, checked once, and what mrjax derives
from it on the host (see `mrjax.models.Model`, which turns it into a model).

- :class:`Parameter`: one parameter (name, SI unit, default bounds, linear, log search, law
    degree); :class:`Params`: the parameters of one instant by name, as the user's functions
    receive them.
- :class:`Declaration`: the checked declaration (the checks of `mrjax.models.Model`, and the
    list of those that passed), the split of the linear parameters into parameter-free and
    parameter-dependent regressors, and the stiffness estimate of the sub-step policy.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import keyword
import math
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._errors import InputError
from ._integrate import ODE, integrate
from ._names import reserved_names
from ._symmetry import ScaleSymmetry

#: Random points at which a declaration is checked (fixed key: the same answer every time).
CHECK_POINTS = 8
#: Relative size of a second derivative below which the force counts as affine.
LINEAR_TOL = 1e-7
#: Reference records of the stiffness estimate: sine amplitudes [m], samples per period, periods.
STIFFNESS_AMPLITUDES = (1e-3, 1e-2, 1e-1, 1.0)
STIFFNESS_SAMPLES = 64
STIFFNESS_PERIODS = 2
#: A stiffness estimate that is not finite becomes this rate [1/s]: the sub-step policy then
#: takes the L-stable scheme with its step doubling, which needs no estimate.
STIFFNESS_UNKNOWN = 1e12


@dataclasses.dataclass(frozen=True)
class Parameter:
    """One parameter of a declared model.

    **Fields:**

    - `name`: a Python identifier (the force reads it as `p.name`).
    - `unit`: its SI unit, e.g. `"N*s/m"` (text, shown in tables and fit.json).
    - `lower`, `upper`: default search bounds, SI units (a fit may override them).
    - `linear`: whether the force is linear in it (checked): the separable swarm solves such
        parameters exactly instead of searching them. Only parameters that do not enter the
        state equation can be linear.
    - `log`: search it on a log scale (a wide positive range; needs `lower > 0`).
    - `degree`: default polynomial degree of its law over the current (`mrjax.generalize`);
        `None`: mrjax's generic default (1, and 2 for a parameter named `alpha`).

    To hold a parameter at a value, declare it and fix it: `mrjax.models.fix(model, {name:
    value})` (in the model's file, or per fit with `fixed=`).
    """

    name: str
    unit: str
    lower: float | None = None
    upper: float | None = None
    linear: bool = False
    log: bool = False
    degree: int | None = None


class Params:
    """The parameters of one instant, as `force`, `rate` and `box` receive them: `p.c` or
    `p["c"]` by name, `p[0]` by position, `len(p)`, iteration in declaration order. Values are
    JAX scalars (or arrays of one common shape)."""

    __slots__ = ("_values", "_index")

    def __init__(self, values: Sequence[Array], index: dict[str, int]):
        object.__setattr__(self, "_values", tuple(values))
        object.__setattr__(self, "_index", index)

    def __getattr__(self, name: str) -> Array:
        try:
            return self._values[self._index[name]]
        except KeyError:
            raise AttributeError(f"no parameter {name!r}; the parameters are "
                                 f"{', '.join(self._index)}") from None

    def __getitem__(self, key: str | int) -> Array:
        return self._values[self._index[key] if isinstance(key, str) else key]

    def __len__(self) -> int:
        return len(self._values)

    def __iter__(self):
        return iter(self._values)

    def __setattr__(self, name, value):
        raise AttributeError("parameters are read-only")

    def __repr__(self) -> str:
        return "Params(" + ", ".join(f"{n}={self._values[i]}" for n, i in self._index.items()) + ")"


def param_columns(theta: Array) -> tuple[Array, ...]:
    """The columns of `theta` (..., P) as a tuple of P arrays (...)."""
    return tuple(theta[..., i] for i in range(theta.shape[-1]))


def _code_text(fn: Callable | None) -> str:
    """The source of `fn` if it can be read, else its qualified name and bytecode (for the
    fingerprint of a declaration: stable across processes)."""
    if fn is None:
        return ""
    try:
        return inspect.getsource(fn)
    except (OSError, TypeError):
        code = getattr(fn, "__code__", None)
        return f"{getattr(fn, '__qualname__', repr(type(fn)))}:{code.co_code.hex() if code else ''}"


class Declaration:
    """The checked declaration of a :class:`Model` and everything derived from it (host side).

    Built once per model; copies of the model (other sub-steps or schemes) share it. Hashes by
    identity; its `repr` is its name and a fingerprint of its parameters and source code, the
    same in every process (a chunked fit's journal keys on it).
    """

    def __init__(self, name, parameters, force, rate, state_size, initial, box, description,
                 reference, check, symmetry=None):
        self.name = _checked_name(name, force)
        self.parameters = _checked_parameters(self.name, parameters)
        what = f"model {self.name!r}"
        if not callable(force):
            raise InputError(f"{what}: force must be a function force(p, x, xdot, state), got "
                             f"{type(force).__name__}")
        try:
            S = int(state_size)
        except (TypeError, ValueError):
            S = -1
        if S < 0 or S != state_size:
            raise InputError(f"{what}: state_size must be a non-negative integer, got "
                             f"{state_size!r}")
        if S > 0 and not callable(rate):
            raise InputError(f"{what}: state_size={S} needs rate(p, x, xdot, state) -> "
                             f"dstate/dt, got {type(rate).__name__}")
        if S == 0 and rate is not None:
            raise InputError(f"{what}: a rate is given but state_size is 0; give the size of "
                             f"the state")
        for label, fn in (("initial", initial), ("box", box)):
            if fn is not None and S == 0:
                raise InputError(f"{what}: {label} is given but the model has no state")
        self.force_fn, self.rate_fn, self.state_size = force, rate, S
        self.initial_value = initial
        self.box_fn = box
        self.description = str(description or "")
        self.reference = str(reference or "")
        self.checked = check
        ps = self.parameters
        self.param_names = tuple(p.name for p in ps)
        self.index = {n: i for i, n in enumerate(self.param_names)}
        self.units = tuple(str(p.unit) for p in ps)
        self.lower = tuple(float(p.lower) for p in ps)
        self.upper = tuple(float(p.upper) for p in ps)
        self.linear = tuple(p.name for p in ps if p.linear)
        self.log_params = tuple(p.name for p in ps if p.log)
        self.degrees = {p.name: int(p.degree) for p in ps if p.degree is not None}
        h = hashlib.sha256()
        for part in (self.name, repr(ps), str(S), repr(symmetry), *(_code_text(f) for f in
                                                   (force, rate, initial, box))):
            h.update(part.encode())
        self.fingerprint = h.hexdigest()
        #: the checks that passed, one line each (`mrjax models --model` prints them)
        self.checks: list[str] = [_parameters_line(ps)]
        self._check_shapes()
        # the split of the linear parameters: parameter-free regressors (basis) first
        # unchecked: every regressor is computed per particle (right whatever it depends on)
        on_basis = self._check_values() if check else ()
        if not check:
            self.checks.append("numerical checks skipped (check=False): every linear "
                               "parameter's regressor is computed per particle")
        self.on_basis = tuple(n for n in self.linear if n in on_basis)
        self.varying = tuple(n for n in self.linear if n not in on_basis)
        self.symmetry = self._checked_symmetry(symmetry, check)
        self.checks = tuple(self.checks)
        self._stiff_fn = None

    def __repr__(self) -> str:
        return f"Declaration({self.name!r}, sha256={self.fingerprint[:16]})"

    # ----------------------------------------------------------------------- one instant
    def params(self, values: Sequence[Array]) -> Params:
        """The parameters `values` (P arrays, SI units) by name, as the user's functions get
        them."""
        return Params(values, self.index)

    def force_at(self, cols, x, v, s) -> Array:
        """The declared force at one instant from parameter columns `cols` (P scalars)."""
        return jnp.reshape(self.force_fn(self.params(cols), x, v, s), ())

    def rate_at(self, cols, x, v, s) -> Array:
        """The declared rate (S,) at one instant."""
        return jnp.reshape(self.rate_fn(self.params(cols), x, v, s), (self.state_size,))

    def initial_at(self, x0, v0) -> Array:
        """The state (S,) at the first sample of a record."""
        x0 = jnp.asarray(x0)
        # the record's float type (a float32 swarm stays float32), else the default float
        dtype = x0.dtype if jnp.issubdtype(x0.dtype, jnp.floating) else jnp.result_type(float)
        if self.initial_value is None:
            return jnp.zeros((self.state_size,), dtype)
        if callable(self.initial_value):
            y0 = self.initial_value(x0, jnp.asarray(v0))
        else:
            y0 = self.initial_value
        return jnp.reshape(jnp.asarray(y0, dtype), (self.state_size,))

    def box_at(self, cols) -> tuple[Array, Array]:
        """The declared box `(lower, upper)` of the state, each (S,), for parameter columns
        `cols`."""
        lo, hi = self.box_fn(self.params(cols))
        S = (self.state_size,)
        return jnp.broadcast_to(jnp.asarray(lo), S), jnp.broadcast_to(jnp.asarray(hi), S)

    # ----------------------------------------------------------------------- checks
    def _sample_point(self):
        """A representative instant: the centre of the default box, 10 mm, 0.1 m/s."""
        lo, hi = np.asarray(self.lower), np.asarray(self.upper)
        theta = 0.5 * (lo + hi)
        x, v = jnp.asarray(0.01), jnp.asarray(0.1)
        return theta, x, v

    def _check_shapes(self) -> None:
        what = f"model {self.name!r}"
        theta, x, v = self._sample_point()
        cols = tuple(jax.ShapeDtypeStruct((), jnp.result_type(float)) for _ in theta)
        S = self.state_size
        sds = jax.ShapeDtypeStruct

        def run(label, fn, *args):
            try:
                return jax.eval_shape(fn, *args)
            except InputError:
                raise
            except Exception as e:  # the user's code: any error is reported in one line
                msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
                raise InputError(f"{what}: {label} fails on one sample: {type(e).__name__}"
                                 + (f": {msg}" if msg else "")) from None

        if S and self.initial_value is not None:
            y0 = run("initial(x0, v0)", lambda a, b: jnp.asarray(
                self.initial_value(a, b) if callable(self.initial_value)
                else self.initial_value, float), x, v)
            if y0.shape != (S,) and not (S == 1 and y0.shape == ()):
                raise InputError(f"{what}: initial must give the state, shape ({S},), got "
                                 f"shape {tuple(y0.shape)}")
            self.checks.append(f"initial(x0, v0): the state, shape ({S},)")
        state = sds((S,), jnp.result_type(float))
        out = run("force(p, x, xdot, state)", lambda c, a, b, s: self.force_fn(
            self.params(c), a, b, s), cols, x, v, state)
        if getattr(out, "shape", None) != ():
            raise InputError(f"{what}: force must return one value (shape ()) for one instant, "
                             f"got shape {tuple(getattr(out, 'shape', ('?',)))}; write it for "
                             f"one sample, mrjax maps it over the record")
        if not jnp.issubdtype(out.dtype, jnp.floating):
            raise InputError(f"{what}: force must return a float, got {out.dtype}")
        self.checks.append("force(p, x, xdot, state): one float per instant")
        if S:
            r = run("rate(p, x, xdot, state)", lambda c, a, b, s: self.rate_fn(
                self.params(c), a, b, s), cols, x, v, state)
            if r.shape != (S,):
                raise InputError(f"{what}: rate must return dstate/dt of the state's shape "
                                 f"({S},), got shape {tuple(r.shape)}"
                                 + (" (a scalar; return an array like the state, e.g. "
                                    "jnp.stack([zdot]))" if r.shape == () else ""))
            self.checks.append(f"rate(p, x, xdot, state): dstate/dt of shape ({S},)")
        if self.box_fn is not None:
            b = run("box(p)", lambda c: self.box_fn(self.params(c)), cols)
            if not (isinstance(b, (tuple, list)) and len(b) == 2 and all(
                    np.broadcast_shapes(tuple(e.shape), (S,)) == (S,) for e in b)):
                raise InputError(f"{what}: box must return (lower, upper), each of shape "
                                 f"({S},) or a scalar")
            self.checks.append(f"box(p): (lower, upper) of shape ({S},)")

    def _points(self):
        """`CHECK_POINTS` random instants (fixed seed): parameters uniform in the default box,
        log-uniform for log parameters and where a positive box spans more than two decades;
        |x| log-uniform in 10 um - 30 mm and |xdot| in 0.1 mm/s - 0.3 m/s, random signs (a
        saturating function of a parameter times the velocity is then seen off its
        plateau); the state in +-1, or in the box where it is finite."""
        rng = np.random.default_rng(20240901)
        K, S = CHECK_POINTS, self.state_size
        lo, hi = np.asarray(self.lower), np.asarray(self.upper)
        u = rng.uniform(size=(K, lo.size))
        th = lo + u * (hi - lo)
        wide = (lo > 0) & (hi > 100.0 * lo)
        for i in range(lo.size):
            if self.param_names[i] in self.log_params or wide[i]:
                th[:, i] = np.exp(np.log(lo[i]) + u[:, i] * (np.log(hi[i]) - np.log(lo[i])))

        def signed_log(a, b):
            return rng.choice((-1.0, 1.0), K) * np.exp(rng.uniform(np.log(a), np.log(b), K))

        x = signed_log(1e-5, 0.03)
        v = signed_log(1e-4, 0.3)
        s = rng.uniform(-1.0, 1.0, (K, S))
        if self.box_fn is not None and S:
            blo, bhi = jax.jit(jax.vmap(lambda t: self.box_at(param_columns(t))))(jnp.asarray(th))
            blo = np.broadcast_to(np.asarray(blo, float), (K, S))
            bhi = np.broadcast_to(np.asarray(bhi, float), (K, S))
            fin = np.isfinite(blo) & np.isfinite(bhi)
            s = np.where(fin, blo + 0.5 * (s + 1.0) * (bhi - blo), s)
        return th, x, v, s

    def _probe(self, th, x, v, s):
        """Value and first and second derivatives of the force and rate at one instant."""
        lin = np.array([self.index[n] for n in self.linear], int)

        def F(t, xs):
            return self.force_at(param_columns(t), x, v, xs)

        gF = jax.grad(F, argnums=(0, 1))
        g_t, g_s = gF(th, s)
        H_tt, H_ts = jax.jacfwd(lambda t, xs: jax.grad(F)(t, xs)[lin], argnums=(0, 1))(th, s)
        out = {"F": F(th, s), "g_t": g_t, "g_s": g_s, "H_tt": H_tt, "H_ts": H_ts}
        if self.state_size:
            def R(t, xs):
                return self.rate_at(param_columns(t), x, v, xs)
            out["R"] = R(th, s)
            out["JR_t"], out["JR_s"] = jax.jacfwd(R, argnums=(0, 1))(th, s)
        return out

    def _check_values(self) -> tuple[str, ...]:
        """The numerical checks (see the module docstring); returns the linear parameters whose
        regressor depends on no parameter and no state."""
        what = f"model {self.name!r}"
        th, x, v, s = self._points()
        # the last point is the rest point of `_warn_rest`: the centre of the box, x = 0,
        # xdot = 0, the initial state
        rest = 0.5 * (np.asarray(self.lower) + np.asarray(self.upper))
        s0 = np.asarray(jax.jit(self.initial_at)(0.0, 0.0), float)
        th, x, v = np.vstack([th, rest]), np.append(x, 0.0), np.append(v, 0.0)
        s = np.vstack([s, s0[None, :]])
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                pr = jax.jit(jax.vmap(self._probe))(jnp.asarray(th), jnp.asarray(x),
                                                    jnp.asarray(v), jnp.asarray(s))
        except Exception as e:
            msg = str(e).strip().splitlines()[0] if str(e).strip() else ""
            raise InputError(f"{what}: its force or rate cannot be differentiated by JAX: "
                             f"{type(e).__name__}" + (f": {msg}" if msg else "")) from None
        pr = {k: np.asarray(a, float) for k, a in pr.items()}
        rest = self._warn_rest({k: a[-1] for k, a in pr.items()})
        pr = {k: a[:-1] for k, a in pr.items()}
        th, x, v, s = th[:-1], x[:-1], v[:-1], s[:-1]
        finite = np.isfinite(pr["F"]) & np.all(np.isfinite(pr["g_t"]), axis=1)
        if self.state_size:
            finite &= np.all(np.isfinite(pr["R"]), axis=1)
        if not finite.any():
            raise InputError(f"{what}: the force (or rate) is not finite at any of "
                             f"{CHECK_POINTS} random points of the default box (first: "
                             + ", ".join(f"{n}={t:.4g}" for n, t in zip(self.param_names, th[0]))
                             + f", x={x[0]:.3g} m, xdot={v[0]:.3g} m/s)")
        r = np.maximum(np.maximum(np.abs(self.lower), np.abs(self.upper)), 1e-300)
        lin = [self.index[n] for n in self.linear]
        nonlin = [i for i in range(len(r)) if i not in lin]
        fixed = []
        for k in np.flatnonzero(finite):
            scale = abs(pr["F"][k]) + float(np.sum(np.abs(pr["g_t"][k]) * r)) + 1e-300
            H = np.abs(pr["H_tt"][k][:, lin]) * r[lin][:, None] * r[lin][None, :]
            bad = np.argwhere(~(H <= LINEAR_TOL * scale))
            if bad.size:
                diag = bad[bad[:, 0] == bad[:, 1]]  # a parameter not linear in itself first
                a, b = (self.linear[j] for j in (diag if diag.size else bad)[0])
                if a == b:
                    raise InputError(f"{what}: parameter {a!r} is declared linear but the force "
                                     f"is not linear in it (its second derivative is not zero "
                                     f"at {_where(self, th[k], x[k], v[k])}); declare it "
                                     f"linear=False")
                raise InputError(f"{what}: parameters {a!r} and {b!r} are declared linear but "
                                 f"the force multiplies them; declare one of them "
                                 f"linear=False")
            if self.state_size:
                JR = np.abs(pr["JR_t"][k])
                rs = (np.abs(pr["R"][k]) + JR @ r + np.abs(pr["JR_s"][k]) @ np.abs(s[k])
                      + 1e-300)
                dep = JR[:, lin] * r[lin][None, :] > LINEAR_TOL * rs[:, None]
                if dep.any():
                    a = self.linear[int(np.argwhere(dep)[0][1])]
                    raise InputError(f"{what}: parameter {a!r} is declared linear but the rate "
                                     f"depends on it, so the force is not linear in it; declare "
                                     f"it linear=False")
        for j, i in enumerate(lin):
            mixed = []
            for k in np.flatnonzero(finite):
                scale = abs(pr["F"][k]) + float(np.sum(np.abs(pr["g_t"][k]) * r)) + 1e-300
                m_t = np.abs(pr["H_tt"][k][j, nonlin]) * r[nonlin] * r[i]
                m_s = np.abs(pr["H_ts"][k][j]) * np.maximum(np.abs(s[k]), 1.0) * r[i]
                mixed.append(bool(np.any(~(m_t <= 1e-12 * scale)) or np.any(
                    ~(m_s <= 1e-12 * scale))))
            if not any(mixed):
                fixed.append(self.linear[j])
        n_ok = int(finite.sum())
        if self.linear:
            self.checks.append(f"linear in {', '.join(self.linear)}: the force is affine in them "
                               f"jointly (exact second derivatives at {n_ok} random points of "
                               f"the default box)")
            if self.state_size:
                self.checks.append(f"rate independent of {', '.join(self.linear)}")
            self.checks.append(
                "regressors: parameter-free " + (", ".join(fixed) or "none")
                + "; parameter-dependent " + (", ".join(n for n in self.linear if n not in fixed)
                                              or "none"))
        if rest:
            self.checks.append(rest)
        return tuple(fixed)

    def _warn_rest(self, pr: dict[str, np.ndarray]) -> str | None:
        """Warn when the derivatives at the rest point (x = 0, xdot = 0, the initial state, the
        centre of the box) are not finite: a polish's Jacobian would be NaN there. Returns the
        check line of those that are finite (None if neither)."""
        parts = [("force", pr["g_t"], pr["g_s"])]
        if self.state_size:
            parts.append(("rate", pr["JR_t"], pr["JR_s"]))
        fine = []
        for label, d_t, d_s in parts:
            # (one infinite partial derivative makes every forward-mode column NaN, so the
            # culprit cannot be named)
            if not (np.all(np.isfinite(d_t)) and np.all(np.isfinite(d_s))):
                warnings.warn(f"model {self.name!r}: the derivatives of its {label} are not "
                              f"finite at rest (x = 0, xdot = 0, the initial state): a fit's "
                              f"Jacobian is NaN there; write |z|**n as "
                              f"mrjax.models.safe_abs_pow(z, n)", stacklevel=8)
            else:
                fine.append(label)
        if fine:
            return (f"derivatives of the {' and '.join(fine)} finite at rest (x = 0, xdot = 0, "
                    f"the initial state)")
        return None

    def _checked_symmetry(self, sym: ScaleSymmetry | None, check: bool) -> ScaleSymmetry | None:
        """The declared scale symmetry, checked: its names are parameters, its state exponents
        one per state component, and (with `check`) the force and rate at the random points
        are unchanged (the rate scaled like the state) by a rescaling, s = 2, and so is the
        initial state."""
        if sym is None:
            return None
        what = f"model {self.name!r}"
        if not isinstance(sym, ScaleSymmetry):
            raise InputError(f"{what}: scale_symmetry must be a mrjax.models.ScaleSymmetry, got "
                             f"{type(sym).__name__}")
        named = [e[0] for e in sym.exponents] + ([sym.power] if sym.power else [])
        unknown = [n for n in named if n not in self.index]
        if unknown:
            raise InputError(f"{what}: scale_symmetry names {unknown[0]!r}, which is not one of "
                             f"its parameters")
        if len(sym.state) != self.state_size or not self.state_size:
            raise InputError(f"{what}: scale_symmetry needs one state exponent per state "
                             f"component ({self.state_size}), got {len(sym.state)}")
        if not check:
            return sym
        th, x, v, st = self._points()
        th2 = sym.rescale(th, self.param_names, 2.0)
        st2 = st * 2.0 ** np.asarray(sym.state, float)

        def both(t, xi, vi, y):
            cols = param_columns(t)
            return self.force_at(cols, xi, vi, y), self.rate_at(cols, xi, vi, y)

        run = jax.jit(jax.vmap(both))
        (f1, r1), (f2, r2) = (tuple(np.asarray(a, float) for a in run(
            jnp.asarray(t), jnp.asarray(x), jnp.asarray(v), jnp.asarray(y)))
            for t, y in ((th, st), (th2, st2)))
        y0 = np.asarray(self.initial_at(0.01, 0.1), float)
        e = 2.0 ** np.asarray(sym.state, float)
        ok = np.isfinite(f1) & np.all(np.isfinite(r1), axis=1)

        def moved(new, old):  # relative to each value and the largest one
            return ~(np.abs(new - old) <= 1e-9 * (np.abs(old) + np.max(np.abs(old[ok]),
                                                                        initial=0.0)))

        problem = ("nothing is finite to check it on" if not ok.any() else
                   "the force changes" if np.any(moved(f2, f1)[ok]) else
                   "the rate does not scale like the state" if np.any(
                       moved(r2, r1 * e)[ok]) else
                   "the initial state changes" if np.any(y0 * (e - 1.0) != 0.0) else None)
        if problem:
            raise InputError(f"{what}: its scale_symmetry does not hold: {problem} under the "
                             f"rescaling s = 2")
        self.checks.append(f"scale symmetry: force and rate unchanged by a rescaling of the "
                           f"state at {int(ok.sum())} random points")
        return sym

    # ----------------------------------------------------------------------- stiffness
    def stiffness_rows(self, rows: np.ndarray, vmax: float) -> float:
        """Largest |eigenvalue| [1/s] of the state Jacobian along the reference records (and at
        the state box's corners) of every finite row; 0 for a static model or vmax = 0.

        A reference record on which the state diverges (a parameter set that is unstable at
        that amplitude: the data's own integration diverges too, whatever the step) says
        nothing about the step the data need and is left out, as are non-finite box corners;
        a row that diverges on every record adds nothing. A Jacobian that is not finite on a
        finite state makes the estimate `STIFFNESS_UNKNOWN`."""
        if not self.state_size or not (vmax > 0 and math.isfinite(vmax)):
            return 0.0
        if self._stiff_fn is None:
            self._stiff_fn = jax.jit(self._jacobians)
        S = self.state_size
        best = 0.0
        for row in np.atleast_2d(np.asarray(rows, float)):
            if not np.all(np.isfinite(row)):
                continue
            finite, records, corners = (np.asarray(a) for a in self._stiff_fn(
                jnp.asarray(row), jnp.asarray(float(vmax))))
            parts = [J for ok, J in zip(finite, records) if ok]
            if not all(np.all(np.isfinite(J)) for J in parts):
                return STIFFNESS_UNKNOWN
            corners = corners.reshape(-1, S, S)
            parts.append(corners[np.all(np.isfinite(corners), axis=(1, 2))])
            for J in parts:
                if J.size:
                    best = max(best, float(np.max(np.abs(np.linalg.eigvals(J)))))
        return best

    def _jacobians(self, row: Array, vmax: Array) -> tuple[Array, Array, Array]:
        """For one parameter row: whether the state stays finite along each reference record
        (R,), the state Jacobians along them (R, n, S, S), and at the corners of a finite
        state box at +-vmax (K, S, S), K = 0 without a box."""
        S = self.state_size
        cols = param_columns(row)

        def rhs(y, xi, vi, p):
            return self.rate_at(param_columns(p), xi, vi, y)

        def jac(y, xi, vi):
            return jax.jacfwd(lambda yy: self.rate_at(cols, xi, vi, yy))(y)

        box = (lambda p: self.box_at(param_columns(p))) if self.box_fn is not None else None
        records, finite = [], []
        n = STIFFNESS_SAMPLES * STIFFNESS_PERIODS
        phase = 2.0 * jnp.pi * jnp.arange(n) / STIFFNESS_SAMPLES
        for A in STIFFNESS_AMPLITUDES:
            w = vmax / A
            x, v = A * jnp.sin(phase), vmax * jnp.cos(phase)
            dt = 2.0 * jnp.pi / (w * STIFFNESS_SAMPLES)
            ys = integrate(ODE(rhs, box=box), self.initial_at(x[0], v[0]), row, x, v, dt, 4,
                           scheme="sdirk")
            records.append(jax.vmap(jac)(ys, x, v))
            finite.append(jnp.all(jnp.isfinite(ys)))
        corners = [jnp.zeros((0, S, S), records[0].dtype)]
        if box is not None and S <= 4:
            lo, hi = self.box_at(cols)
            lo = jnp.broadcast_to(lo, (S,))
            hi = jnp.broadcast_to(hi, (S,))
            bits = (np.arange(2 ** S)[:, None] >> np.arange(S)[None, :]) & 1
            ys = jnp.where(jnp.asarray(bits, bool), hi, lo)
            ys = jnp.where(jnp.isfinite(ys), ys, 0.0)
            for sv in (1.0, -1.0):
                corners.append(jax.vmap(lambda y: jac(y, jnp.zeros(()), sv * vmax))(ys))
        return jnp.stack(finite), jnp.stack(records), jnp.concatenate(corners, axis=0)


def _parameters_line(ps: tuple[Parameter, ...]) -> str:
    """The check line of the parameters."""
    extra = [f"log search: {', '.join(p.name for p in ps if p.log)}"] if any(
        p.log for p in ps) else []
    return (f"{len(ps)} parameters ({', '.join(p.name for p in ps)}): identifiers with units "
            f"and finite, ordered default bounds" + "".join(f"; {e}" for e in extra))


def _where(decl: Declaration, theta, x, v) -> str:
    return (", ".join(f"{n}={t:.4g}" for n, t in zip(decl.param_names, theta))
            + f", x={x:.3g} m, xdot={v:.3g} m/s")


def _checked_name(name: Any, force: Any) -> str:
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"a model needs a name (a non-empty string), got {name!r}")
    key = name.strip()
    if not key.replace("_", "a").replace("-", "a").isalnum() or key != key.lower():
        raise InputError(f"model name {name!r} must be lower case letters, digits, '_' or '-'")
    # names of mrjax's own models are reserved: only mrjax's modules may declare them
    module = getattr(force, "__module__", "") or ""
    if key.replace("-", "_") in reserved_names() and not module.startswith("mrjax."):
        raise InputError(f"model name {key!r} collides with a built-in model of mrjax; choose "
                         f"another name")
    return key


def _checked_parameters(model: str, parameters: Any) -> tuple[Parameter, ...]:
    what = f"model {model!r}"
    if isinstance(parameters, Parameter) or not isinstance(parameters, Sequence) or \
            isinstance(parameters, str):
        raise InputError(f"{what}: parameters must be a list of mrjax.models.Parameter")
    if not parameters:
        raise InputError(f"{what}: declare at least one parameter")
    seen = set()
    out = []
    for p in parameters:
        if not isinstance(p, Parameter):
            raise InputError(f"{what}: parameters must be mrjax.models.Parameter, got "
                             f"{type(p).__name__}")
        n = p.name
        if not isinstance(n, str) or not n.isidentifier() or keyword.iskeyword(n) or \
                n.startswith("_"):
            raise InputError(f"{what}: parameter name {n!r} must be a Python identifier not "
                             f"starting with '_'")
        if n in seen:
            raise InputError(f"{what}: parameter {n!r} is declared twice")
        seen.add(n)
        if not isinstance(p.unit, str):
            raise InputError(f"{what}: the unit of parameter {n!r} must be text, e.g. 'N*s/m'")
        if p.lower is None or p.upper is None:
            raise InputError(f"{what}: parameter {n!r} needs default bounds lower= and upper= "
                             f"(SI units)")
        try:
            lo, hi = float(p.lower), float(p.upper)
        except (TypeError, ValueError):
            raise InputError(f"{what}: the bounds of parameter {n!r} must be numbers, got "
                             f"[{p.lower!r}, {p.upper!r}]") from None
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise InputError(f"{what}: the bounds of parameter {n!r} must be finite, got "
                             f"[{lo:g}, {hi:g}]")
        if lo > hi:
            raise InputError(f"{what}: the bounds of parameter {n!r} are inverted: lower "
                             f"{lo:g} > upper {hi:g}")
        if p.log and lo <= 0:
            raise InputError(f"{what}: parameter {n!r} is searched on a log scale (log=True) "
                             f"but its lower bound {lo:g} is not positive")
        if p.log and p.linear:
            raise InputError(f"{what}: parameter {n!r} is linear (solved exactly), so it is not "
                             f"searched: log=True does not apply")
        if p.degree is not None and (int(p.degree) != p.degree or p.degree < 0):
            raise InputError(f"{what}: the law degree of parameter {n!r} must be a "
                             f"non-negative integer, got {p.degree!r}")
        out.append(p)
    return tuple(out)
