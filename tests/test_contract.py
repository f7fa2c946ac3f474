"""The model contract without friction: fixed parameters as a model transformation
(`mrjax.models.fix`), the scale symmetry that replaces model names as switches, the state
rate's shape, the stiffness estimate on signed boxes, the checks a declaration reports and its
public help text."""

from __future__ import annotations

import os
import pydoc
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import run_cli as run

import mrjax
from mrjax.data import make_batch, simulate
from mrjax.models import (
    Model,
    Parameter,
    ScaleSymmetry,
    box_corners,
    box_points,
    fix,
    from_source,
    get,
    resolve_model,
    safe_abs_pow,
    source_of,
    unregister,
)

EXAMPLES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                        "examples", "my_models.py")
T = np.arange(600) / 500.0
X = 0.008 * np.sin(2 * np.pi * 2.0 * T)
V = 0.008 * 2 * np.pi * 2.0 * np.cos(2 * np.pi * 2.0 * T)
DT = 1 / 500.0
BW_TRUE = dict(c=800.0, k=2000.0, alpha=600.0, f0=-20.0, delta=1500.0, beta=700.0,
               gamma=1000.0, n=1.2)


# ------------------------------------------------------------------------------ fix
@pytest.mark.parametrize("held", [{"delta": 1500.0}, {"f0": -20.0, "n": 1.2},
                                  {"alpha": 600.0, "c": 800.0}])
def test_fixed_model_is_the_model_with_fewer_unknowns(held):
    """A fixed Bouc-Wen: the others' names, units, bounds, linear split and law degrees; its
    force is the unfixed model's at the expanded parameters (the same to the bit, RK4, and the
    L-stable scheme once); its affine form moves a held linear parameter into the offset; stepping
    its state equation one sample at a time gives the same force."""
    bw = get("bouc_wen")
    m = fix(bw, held)
    free = [n for n in bw.param_names if n not in held]
    assert m.param_names == tuple(free) and m.fixed == held and m.unfixed is bw
    assert m.units == tuple(u for n, u in zip(bw.param_names, bw.units) if n in free)
    np.testing.assert_array_equal(m.bounds[1], bw.bounds[1][[bw.param_names.index(n)
                                                             for n in free]])
    assert m.basis_params == tuple(n for n in bw.basis_params if n in free)
    assert m.varying_params == tuple(n for n in bw.varying_params if n in free)
    assert set(m.law_degrees) == set(free)
    full = bw.params(**BW_TRUE)
    theta = m.params(**{n: BW_TRUE[n] for n in free})
    np.testing.assert_array_equal(m.expand(theta), full)
    for sub, scheme in ((2, "rk4"), (1, "sdirk"))[:2 if "delta" in held else 1]:
        a = np.asarray(m.with_substeps(sub, scheme).force(theta, X, V, DT))
        b = np.asarray(bw.with_substeps(sub, scheme).force(full, X, V, DT))
        np.testing.assert_array_equal(a, b)
    r = m.with_substeps(2, "rk4")
    b = np.asarray(bw.with_substeps(2, "rk4").force(full, X, V, DT))
    A, off = r.design(theta, X, V, DT)
    assert A.shape == (X.size, len(m.linear_params))
    rebuilt = np.asarray(A) @ theta[m.linear_index] + np.asarray(off)
    np.testing.assert_allclose(rebuilt, b, rtol=1e-12, atol=1e-9 * np.max(np.abs(b)))
    force_at, advance = jax.jit(r.force_at), jax.jit(r.advance)
    s, f = r.initial_state(X[0], V[0]), []
    for k in range(20):
        f.append(float(force_at(theta, s, X[k], V[k])))
        s = advance(s, theta, X[k], X[k + 1], V[k], V[k + 1], DT)
    np.testing.assert_allclose(f, b[:20], rtol=1e-12, atol=1e-9)
    ode = r.ode()  # the state equation reads the held values too
    np.testing.assert_array_equal(ode.rhs(jnp.array([0.3]), X[3], V[3], jnp.asarray(theta)),
                                  bw.ode().rhs(jnp.array([0.3]), X[3], V[3], jnp.asarray(full)))
    assert resolve_model(m, theta, V, DT).substeps == resolve_model(bw, full, V, DT).substeps


def test_fixed_static_models_fold_columns_into_the_offset():
    """Holding a parameter-free linear parameter (Bingham's fc) or a parameter-dependent one
    (Kwok's alpha) removes its column and adds it, times its value, to the offset."""
    for name, held in (("bingham", {"fc": 300.0}), ("kwok", {"alpha": 500.0})):
        base = get(name)
        lo, hi = base.bounds
        full = 0.5 * (lo + hi)
        full[base.param_names.index(next(iter(held)))] = next(iter(held.values()))
        m = fix(base, held)
        theta = np.array([full[base.param_names.index(n)] for n in m.param_names])
        A, off = m.design(theta, X, V, DT)
        assert A.shape[1] == len(base.linear_params) - 1
        want = np.asarray(base.force(full, X, V, DT))
        np.testing.assert_allclose(np.asarray(A) @ theta[m.linear_index] + np.asarray(off),
                                   want, rtol=1e-12, atol=1e-9)


def test_fix_is_validated_and_composes():
    bw = get("bouc_wen")
    cases = (({"A": 1.0}, "no parameter 'A' to fix; the closest is 'alpha'"),
             ({"delta": float("nan")}, "'delta'.*must be a finite number"),
             ({"delta": float("inf")}, "must be a finite number"),
             ({"delta": "one"}, "must be a finite number"),
             ({"delta": True}, "must be a finite number"),
             (dict.fromkeys(bw.param_names, 1.0), "leaves no parameter to fit"))
    for values, message in cases:
        with pytest.raises(mrjax.InputError, match=message) as e:
            fix(bw, values)
        assert "\n" not in str(e.value)
    with pytest.raises(mrjax.InputError, match="mapping name -> value"):
        fix(bw, [("delta", 1.0)])
    m = fix(fix(bw, {"delta": 2.0}), {"n": 1.5, "delta": 1.0})  # adds, and replaces delta
    assert m.fixed == {"delta": 1.0, "n": 1.5} and m.unfixed is bw
    assert get("bw", fixed={"delta": 1.0, "n": 1.5}) == m
    assert fix(bw, {}) is bw and fix(m, {}) == m
    with pytest.raises(mrjax.InputError, match="'delta' of model 'bouc_wen' is fixed at 1"):
        mrjax.models.check_bounds(m, ({"delta": 0.0}, None))


def test_fixed_parameter_known_answer():
    """Bouc-Wen with delta (Spencer's A) held at 1 /m, so that z is in metres and alpha in N/m:
    simulated at the truth on two records with 1 % noise, `mrjax.fit` of the fixed model
    recovers every other parameter within 2 std-errors or 5 %."""
    m = fix(get("bouc_wen"), {"delta": 1.0})
    truth = m.params(c=800.0, k=2000.0, alpha=2.5e5, f0=-20.0, beta=700.0, gamma=1000.0,
                     n=1.2)
    motions = ((2.0, 0.008), (1.0, 0.012))
    clean = [simulate(m, truth, frequency=f, amplitude=a, cycles=1, sample_rate=500)
             for f, a in motions]
    conds = [simulate(m, truth, frequency=f, amplitude=a, cycles=1, sample_rate=500,
                      noise=0.01 * float(np.max(np.abs(c.force))), seed=k)
             for k, ((f, a), c) in enumerate(zip(motions, clean))]
    r = mrjax.fit(m, make_batch(conds), bounds=({"alpha": 0.0}, {"alpha": 1e6}),
                  swarm=mrjax.Swarm(n_particles=20, max_generations=30, view=False),
                  polish=mrjax.Polish(retry=False))
    assert r.model.fixed == {"delta": 1.0}
    for i in range(2):
        est, se = np.asarray(r.theta[i]), np.asarray(r.stderr[i])
        ok = (np.abs(est - truth) <= 0.05 * np.abs(truth)) | (np.abs(est - truth) <= 2 * se)
        assert ok.all(), dict(zip(m.param_names, np.round((est - truth) / truth, 4)))


# ------------------------------------------------------------------------------ sources
MINE = textwrap.dedent("""
    import jax.numpy as jnp
    from mrjax.models import Model, Parameter, fix

    Tanh = Model("c_tanh", [Parameter("c", "N*s/m", 0.0, 1e5, linear=True),
                            Parameter("alpha", "N", 0.0, 2500.0, linear=True),
                            Parameter("beta", "s/m", 1.0, 1e4, log=True),
                            Parameter("f0", "N", -1e3, 1e3, linear=True)],
                 lambda p, x, v, s: p.c * v + p.alpha * jnp.tanh(p.beta * v) + p.f0)
    Tanh0 = fix(Tanh, {"f0": 0.0})
""")


def test_fixed_models_are_found_again_from_their_source(tmp_path):
    """A model held in its file (`Tanh0 = fix(Tanh, ...)`) and one held per call: `source_of`
    records the held values, `from_source` rebuilds exactly that model in a fresh registry,
    and `describe_source` says what is held."""
    f = tmp_path / "mine.py"
    f.write_text(MINE)
    try:
        declared = get(f"{f}:Tanh0")
        assert declared.param_names == ("c", "alpha", "beta") and declared.fixed == {"f0": 0.0}
        src = source_of(declared)
        assert src["object"] == "Tanh0" and src["fixed"] == {"f0": 0.0}
        assert "f0 = 0 fixed" in mrjax.models.describe_source(src)
        per_call = fix(declared, {"c": 1000.0})
        src2 = source_of(per_call)
        assert src2["fixed"] == {"c": 1000.0, "f0": 0.0}
        unfixed = declared.unfixed
        assert source_of(unfixed)["fixed"] == {}  # the file's object holds f0: say it is free
        unregister("c_tanh")
        assert from_source("c_tanh", src) == declared
        unregister("c_tanh")
        assert from_source("c_tanh", src2) == per_call
        unregister("c_tanh")
        assert from_source("c_tanh", source_of(unfixed)).fixed == {}
        assert source_of(fix(get("kwok"), {"f0": 0.0})) == {"kind": "builtin",
                                                             "fixed": {"f0": 0.0}}
        assert from_source("kwok", {"kind": "builtin", "fixed": {"f0": 0.0}}).fixed == \
            {"f0": 0.0}
    finally:
        unregister("c_tanh")


# ------------------------------------------------------------------------------ symmetry
def test_scale_symmetry_of_the_bouc_wen_models():
    """The Bouc-Wen models declare their z-scale: a rescaled parameter set gives the same
    force; the canonical member has delta = beta + gamma (|z|max = 1); holding a parameter
    that moves with the scale (delta, alpha; beta with n free) pins it, holding n keeps it."""
    for name in ("bouc_wen", "modified_bouc_wen"):
        m = get(name, substeps=4)
        sym = m.scale_symmetry
        assert sym.gauge == "delta" and set(sym.scaled) == {"alpha", "delta", "beta", "gamma"}
        lo, hi = m.bounds
        th = 0.5 * (lo + hi)
        th[m.param_names.index("beta")] = 700.0
        moved = sym.rescale(th, m.param_names, 3.0)
        f0, f1 = (np.asarray(m.force(t, X, V, DT)) for t in (th, moved))
        np.testing.assert_allclose(f1, f0, rtol=1e-9, atol=1e-9 * np.max(np.abs(f0)))
        can = sym.canonical(moved, m.param_names)
        ix = m.param_names.index
        assert can[ix("delta")] == pytest.approx(can[ix("beta")] + can[ix("gamma")], rel=1e-12)
        np.testing.assert_allclose(can, sym.canonical(th, m.param_names), rtol=1e-12)
    for name in ("kwok", "bingham", "dahl", "lugre"):
        assert get(name).scale_symmetry is None
    bw = get("bouc_wen")
    assert fix(bw, {"delta": 1.0}).scale_symmetry is None
    assert fix(bw, {"alpha": 500.0}).scale_symmetry is None
    assert fix(bw, {"beta": 100.0}).scale_symmetry is None
    assert fix(bw, {"beta": 0.0}).scale_symmetry is not None  # held at 0: moves nowhere
    kept = fix(bw, {"n": 2.0, "c": 0.0}).scale_symmetry
    assert kept is not None and kept.held == (("n", 2.0),)
    assert fix(bw, {"n": 1.0, "beta": 100.0}).scale_symmetry is not None  # beta * s^0
    m = fix(bw, {"n": 2.0})
    th = m.params(**{k: v for k, v in BW_TRUE.items() if k != "n"})
    can = kept.canonical(th, m.param_names)
    ix = m.param_names.index
    assert can[ix("delta")] == pytest.approx(can[ix("beta")] + can[ix("gamma")], rel=1e-12)
    assert bw.scale_symmetry.pinned_by({"delta": 1.0}) and not \
        bw.scale_symmetry.pinned_by({"k": 1.0})


def _bw_parameters():
    return [Parameter("alpha", "N", 0.0, 2500.0, linear=True),
            Parameter("delta", "1/m", 1.0, 5000.0), Parameter("beta", "1/m", 0.0, 5000.0),
            Parameter("gamma", "1/m", 0.0, 5000.0), Parameter("n", "-", 1.0, 3.0)]


def _bw_rate(p, x, v, z):
    zn = safe_abs_pow(z, p.n)
    return p.delta * v - p.beta * v * zn - p.gamma * jnp.abs(v) * jnp.sign(z) * zn


BW_SYMMETRY = ScaleSymmetry([("alpha", -1, 0), ("delta", 1, 0), ("beta", 1, -1),
                             ("gamma", 1, -1)], gauge="delta", balance=("beta", "gamma"),
                            power="n")


def test_declared_scale_symmetry_is_checked():
    """A declared model may state its scale symmetry; the declaration checks it (the force and
    the rate at random points) and refuses a wrong one in one line."""
    m = Model("c_bw", _bw_parameters(), lambda p, x, v, z: p.alpha * z[0], rate=_bw_rate,
              state_size=1, scale_symmetry=BW_SYMMETRY)
    assert m.scale_symmetry == get("bouc_wen").scale_symmetry
    assert any(c.startswith("scale symmetry") for c in m.checks)
    assert fix(m, {"delta": 1.0}).scale_symmetry is None
    wrong = ScaleSymmetry([("alpha", -1, 0), ("delta", 1, 0), ("beta", 1, 0),
                           ("gamma", 1, 0)], gauge="delta", balance=("beta", "gamma"))
    for sym, message in ((wrong, "scale_symmetry does not hold: the rate does not scale"),
                         (ScaleSymmetry([("a", 1, 0)], gauge="a", balance=("a",)),
                          "names 'a', which is not one of its parameters")):
        with pytest.raises(mrjax.InputError, match=message) as e:
            Model("c_bw2", _bw_parameters(), lambda p, x, v, z: p.alpha * z[0],
                  rate=_bw_rate, state_size=1, scale_symmetry=sym)
        assert "\n" not in str(e.value)


# ------------------------------------------------------------------------------ contract
def test_rate_of_the_wrong_shape_is_refused():
    """A scalar rate for a (1,) state is refused at declaration, naming the model and both
    shapes."""
    with pytest.raises(mrjax.InputError) as e:
        Model("c_scalar", _bw_parameters(), lambda p, x, v, z: p.alpha * z[0],
              rate=lambda p, x, v, z: p.delta * v - p.beta * v * z[0], state_size=1)
    msg = str(e.value)
    assert "'c_scalar'" in msg and "shape (1,)" in msg and "got shape ()" in msg
    assert "\n" not in msg


def test_stiffness_on_a_signed_box():
    """Bouc-Wen declared by its equations, searched in a box with signed beta and gamma: some
    parameter sets there make the state diverge; the estimate leaves those records out
    instead of giving up (which asked for the maximum of 256 sub-steps), and the box's
    interior (`box_points`) asks what the data need: one RK4 step, as at the truth."""
    m = get(f"{EXAMPLES}:BoucWen")
    lo, hi = m.bounds
    lo[m.param_names.index("beta")] = lo[m.param_names.index("gamma")] = -5000.0
    vmax = float(np.max(np.abs(V)))
    rates = [m.stiffness(r, vmax) for r in box_corners(m, lo, hi)]
    assert all(np.isfinite(rates)) and max(rates) < 1e6
    truth = m.params(**BW_TRUE)
    at_truth = resolve_model(m, truth, V, DT)
    pts = box_points(m, lo, hi)
    inside = resolve_model(m, pts, V, DT)
    assert (at_truth.substeps, at_truth.scheme) == (1, "rk4")
    assert (inside.substeps, inside.scheme) == (1, "rk4")
    assert pts.shape == (16, 8) and np.all((pts >= lo) & (pts <= hi))
    diverging = m.params(**dict(BW_TRUE, beta=-5000.0, gamma=-5000.0, n=2.0))
    assert m.stiffness(diverging, vmax) < 1e6  # its diverging records are left out
    unregister("my_bouc_wen")


def test_help_and_checks_of_a_declaration():
    """`help(Model)` is the contract itself (no pointer to a private module); a copy of a model
    shares its checked declaration; `mrjax models --model FILE:NAME` prints the checks that
    passed."""
    text = pydoc.render_doc(Model, renderer=pydoc.plaintext)
    doc = Model.__doc__
    for part in ("**Arguments:**", "What mrjax derives", "What it checks", "Fixed parameters",
                 "rate(p, x, xdot, state)", "scale_symmetry"):
        assert part in text and part in doc
    assert "_declare" not in doc and "module docstring" not in doc
    m = get("lugre")
    assert m.with_substeps(2, "rk4").declaration is m.declaration
    assert any(c.startswith("rate(p, x, xdot, state): dstate/dt of shape (1,)")
               for c in m.checks)
    code, out, _ = run(["models", "--model", f"{EXAMPLES}:BoucWen1"])
    try:
        assert code == 0
        block = out.split("my_bouc_wen  [")[1]
        assert "fixed: n = 1" in block and "checks passed:" in block
        assert "- linear in c, k, alpha, f0" in block and "- rate(p, x, xdot, state)" in block
    finally:
        unregister("my_bouc_wen")


def test_jit_and_grad_through_a_fixed_model():
    """A fixed model is a pytree like any other: jit and grad see only its unknowns."""
    m = fix(get("kwok"), {"delta": 0.5})
    th = m.params(c=1000.0, k=100.0, alpha=400.0, beta=50.0, f0=-10.0)
    f = jax.jit(lambda t: jnp.sum(m.force(t, X, V, DT) ** 2))
    g = jax.grad(f)(jnp.asarray(th))
    assert g.shape == (5,) and np.all(np.isfinite(np.asarray(g)))
