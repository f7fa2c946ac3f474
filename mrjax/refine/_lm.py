"""The one optimistix call site of mrjax: a bounded-problem-agnostic Levenberg-Marquardt solve.

Both the per-condition polish (`mrjax.refine.polish`) and the joint generalization
(`mrjax.generalize`) minimise a sum of squared residuals with :func:`lm_solve`; the solver, its
linear solve and the decoding of optimistix's status live here only.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array, ArrayLike, Int, PyTree

#: Linear solver of the damped Gauss-Newton step: the P x P damped normal equations
#: $(J^T J + \lambda I)\,\delta = -J^T r$ by Cholesky. LevenbergMarquardt's default, QR of
#: the (T + P) x P system, is as robust but about 3x slower batched on CPU (JAX's batched QR
#: is slow there); $\lambda > 0$ keeps the system positive definite, float64 keeps it accurate,
#: and a failed factorisation only makes the trust region shrink.
LINEAR_SOLVER = lx.Normal(lx.Cholesky())

#: Default stop of :func:`lm_solve`: the relative change of the RMS (see there).
DEFAULT_TOL = 1e-6
#: :func:`lm_solve` stops when the last this many steps lowered the relative RMS by less than
#: its `tol`.
STALL_STEPS = 8

#: Smallest relative scale of a variable in :func:`lm_solve`'s `scale` (at most a 1000 x larger
#: step than the steepest variable's under the same damping).
SCALE_FLOOR = 1e-3

class Status(enum.StrEnum):
    """How a polish ended, per unit (an enumeration whose members are also their names as
    text, so `Status.SUCCESSFUL == "successful"` and fit.json holds the text).

    The Levenberg-Marquardt outcomes (optimistix's `RESULTS`): `SUCCESSFUL` (the stop of
    :func:`lm_solve` met), `MAX_STEPS_REACHED`, `NONLINEAR_DIVERGENCE`, `NONFINITE`,
    `SINGULAR`, `BREAKDOWN`, `STAGNATION`, `CONLIM`, `NONFINITE_INPUT`, `UNKNOWN`; and the
    engine's: `REFINED` (a polish on the swarm's views converged and the full records'
    refinement ran its steps), `KEPT_START` (the polished result was worse than its start,
    which was kept), `NONE` (no polish ran).
    """

    SUCCESSFUL = "successful"
    MAX_STEPS_REACHED = "max_steps_reached"
    NONLINEAR_DIVERGENCE = "nonlinear_divergence"
    NONFINITE = "nonfinite"
    SINGULAR = "singular"
    BREAKDOWN = "breakdown"
    STAGNATION = "stagnation"
    CONLIM = "conlim"
    NONFINITE_INPUT = "nonfinite_input"
    UNKNOWN = "unknown"
    REFINED = "refined"
    KEPT_START = "kept_start"
    NONE = "none"

    @property
    def converged(self) -> bool:
        """Whether the polish ended at an optimum (successful or refined)."""
        return self in (Status.SUCCESSFUL, Status.REFINED)


#: The solve's statuses in the order of :attr:`LMSolution.status`'s codes.
STATUS_NAMES: tuple[Status, ...] = tuple(Status)[:10]
# optimistix.RESULTS members (public attributes) and the name mrjax reports for each
_RESULTS = (
    ("successful", "successful"), ("nonlinear_max_steps_reached", "max_steps_reached"),
    ("nonlinear_divergence", "nonlinear_divergence"), ("nonfinite", "nonfinite"),
    ("max_steps_reached", "max_steps_reached"), ("singular", "singular"),
    ("breakdown", "breakdown"), ("stagnation", "stagnation"), ("conlim", "conlim"),
    ("nonfinite_input", "nonfinite_input"),
)


# The variables travel in a dict under this key, so that the Cauchy test of optimistix can
# tell them from the residuals: `_residual_norm` gives 0 for the variables' change (not
# tested) and the Euclidean norm for the residuals' change (see `lm_solve`'s `tol`).
_VARIABLES = "variables"


def _residual_norm(tree: PyTree) -> Array:
    if isinstance(tree, dict) and _VARIABLES in tree:
        return jnp.zeros(())
    return optx.two_norm(tree)


class LMSolution(eqx.Module):
    """Outcome of :func:`lm_solve`.

    **Fields:** `value` the final iterate (the pytree of `y0`); `steps` () the number of
    steps taken (accepted and rejected); `status` () an index into `STATUS_NAMES` (decode on
    the host with :func:`status_name`).
    """

    value: PyTree
    steps: Int[Array, ""]
    status: Int[Array, ""]


def _status_code(result: optx.RESULTS) -> Int[Array, ""]:
    """Index into `STATUS_NAMES` of an optimistix result, through its public comparisons
    (works batched: under `vmap` each element is decoded)."""
    code = jnp.asarray(STATUS_NAMES.index("unknown"), jnp.int32)
    for attr, name in reversed(_RESULTS):
        item = getattr(optx.RESULTS, attr, None)
        if item is not None:
            code = jnp.where(result == item, jnp.int32(STATUS_NAMES.index(name)), code)
    return code


def status_name(code: ArrayLike) -> Status:
    """The :class:`Status` of an :attr:`LMSolution.status` code (host)."""
    c = int(code)
    return STATUS_NAMES[c] if 0 <= c < len(STATUS_NAMES) else Status.UNKNOWN


def _scaled(fn, y0, args, scale, **kw) -> LMSolution:
    """:func:`lm_solve` on `d * y`, `d` the sensitivities `scale` relative to the largest,
    floored at `SCALE_FLOOR`."""
    d = jnp.asarray(scale, jnp.result_type(y0))
    d = jnp.where(jnp.isfinite(d) & (d > 0), d, 0.0)
    d = jnp.maximum(d / jnp.maximum(jnp.max(d), jnp.finfo(d.dtype).tiny), SCALE_FLOOR)
    sol = lm_solve(lambda v, a: fn(v / d, a), y0 * d, args, **kw)
    return LMSolution(value=sol.value / d, steps=sol.steps, status=sol.status)


def lm_solve(
    fn: Callable[[PyTree, Any], Array],
    y0: PyTree,
    args: Any = None,
    *,
    max_steps: int,
    tol: ArrayLike = DEFAULT_TOL,
    jacobian: str = "linearize",
    scale: ArrayLike | None = None,
) -> LMSolution:
    r"""Minimise $\tfrac12\|r(y)\|^2$ by Levenberg-Marquardt (optimistix) from `y0`.

    **Arguments:**

    - `fn`: residuals `fn(y, args) -> r` (any shape; units of the data, e.g. N).
    - `y0`: the start: unbounded variables of order one (callers map bounds and scales
        through a reparameterisation).
    - `args`: passed to `fn`.
    - `max_steps`: step cap (static).
    - `tol`: the stop, on the fit only. The residuals are divided by their Euclidean norm at
        `y0` (so that zero residuals, e.g. of padded samples, change nothing); the solve ends
        when the last `STALL_STEPS` (8) steps lowered that relative norm, i.e. the RMS
        relative to its start, by less than `tol`, or when one accepted step moves the
        relative residuals by less than `tol` (optimistix's Cauchy test). The variables are
        not tested: a parameter crawling along a flat direction (an active bound, a redundant
        pair) no longer changes the RMS and does not keep the solve going. A runtime value
        (no recompilation).
    - `jacobian`: how the damped step gets the Jacobian (static). `"linearize"` (default):
        optimistix's `jax.linearize`, whose normal equations then push P tangents forward and
        P cotangents backward through `fn` each step. `"forward"`: the Jacobian is
        materialised once per step by forward mode, value and all P tangents in one pass (a
        custom JVP rule `J @ dy`), so the damped solve only multiplies matrices: for a long
        `lax.scan` residual (a dynamic model on 10^4-10^5 samples) a step costs one forward
        pass instead of about three, and no residuals of the scan are stored. Memory N x P.
    - `scale`: per-variable sensitivities `d` (the shape of `y0`, a flat vector), e.g. the
        Jacobian's column norms at the start: the solve runs on `d * y`, with `d` divided by
        its largest entry and floored at `SCALE_FLOOR` (MINPACK's diagonal scaling). Under
        the damping a flat variable then takes steps as large as a steep one, instead of
        crawling. Default: none.

    Never raises on failure (`throw=False`): under `vmap` one failed problem reports its status
    instead of stopping the batch. Jittable.

    **Returns:** an :class:`LMSolution`.
    """
    if scale is not None:
        return _scaled(fn, y0, args, scale, max_steps=max_steps, tol=tol, jacobian=jacobian)
    r0 = jax.lax.stop_gradient(fn(y0, args))
    scale = _norm(r0)
    scale = jnp.where(jnp.isfinite(scale) & (scale > 0), scale, 1.0)

    if jacobian not in ("linearize", "forward"):
        raise ValueError(f"jacobian must be 'linearize' or 'forward', got {jacobian!r}")
    if jacobian == "forward":
        fn = _forward_jacobian(fn)

    def relative(y, a):
        r = fn(y[_VARIABLES], a) / scale
        return r, _norm(r)  # the norm of the relative residuals rides along as `aux`

    # optimistix's documented manual stepping (solver.init / step / terminate): the loop adds
    # the stall test on the RMS, which optimistix's own termination cannot express
    solver = optx.LevenbergMarquardt(rtol=0.0, atol=tol, norm=_residual_norm,
                                     linear_solver=LINEAR_SOLVER)
    y = {_VARIABLES: y0}
    f = eqx.filter_closure_convert(relative, y, args)
    f_struct, aux_struct = f.out_struct
    options, tags = {}, frozenset()
    state = solver.init(f, y, args, options, f_struct, aux_struct, tags)
    dynamic, static = eqx.partition(state, eqx.is_array)  # as optimistix's own loop does
    ok = STATUS_NAMES.index("successful")

    def cond(c):
        return ~c[4]

    def body(c):
        y, dynamic, k, hist, _, _ = c
        y, state, rms = solver.step(f, y, args, options, eqx.combine(static, dynamic), tags)
        term, result = solver.terminate(f, y, args, options, state, tags)
        code = jnp.where(jax.tree.reduce(jnp.logical_and, jax.tree.map(
            lambda a: jnp.all(jnp.isfinite(a)), y)), _status_code(result),
            jnp.int32(STATUS_NAMES.index("nonfinite")))
        k = k + 1
        slot = k % STALL_STEPS
        stalled = (k > STALL_STEPS) & ~(hist[slot] - rms > tol)  # also stops on NaN
        cap = (k >= max_steps) & ~term & ~stalled & (code == ok)
        code = jnp.where(cap, jnp.int32(STATUS_NAMES.index("max_steps_reached")), code)
        stop = term | stalled | (k >= max_steps) | (code != ok)
        return y, eqx.partition(state, eqx.is_array)[0], k, hist.at[slot].set(rms), stop, code

    start = (y, dynamic, jnp.zeros((), jnp.int32), jnp.ones((STALL_STEPS,), f_struct.dtype),
             jnp.asarray(max_steps < 1), jnp.int32(ok))
    y, _, steps, _, _, code = jax.lax.while_loop(cond, body, start)
    return LMSolution(value=y[_VARIABLES], steps=steps, status=code)


def _forward_jacobian(fn: Callable[[PyTree, Any], Array]) -> Callable[[PyTree, Any], Array]:
    """`fn` with a JVP rule that materialises its Jacobian by forward mode (value and every
    tangent of `y` in one pass): linearising it stores J (N, P), and the linear map is
    `J @ dy` (its transpose `J.T @ ct`). `args` are data: their tangents are ignored."""

    @jax.custom_jvp
    def f(y, args):
        return fn(y, args)

    @f.defjvp
    def f_jvp(primals, tangents):
        y, args = primals
        dy, _ = tangents
        flat, unravel = jax.flatten_util.ravel_pytree(y)
        J, r = jax.jacfwd(lambda v: (fn(unravel(v), args),) * 2, has_aux=True)(flat)
        dflat, _ = jax.flatten_util.ravel_pytree(dy)
        return r, (J.reshape(r.size, flat.size) @ dflat).reshape(r.shape)

    return f


def _norm(r: PyTree) -> Array:
    return optx.two_norm(r)
