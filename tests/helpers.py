"""Shared test material: every model name, a representative parameter vector per model, Spencer's
1997 modified Bouc-Wen set, a sinusoidal excitation, the three file layouts of issue 14,
checks of the command line's outputs, and where the UTFSM tests are (`default_data_dir`).

All values are SI. `TRUE_PARAMS[name]` lies inside `mrjax.models.get(name).bounds` and gives forces
of a few hundred newtons to about 1.5 kN at 2.5 Hz / 15 mm, the scale of the RD-1005-3 in Kwok
et al. (2006).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
from pathlib import Path

import numpy as np
import scipy.io

import mrjax
from mrjax import cli

#: Every registered model, in the order of the paper.
MODEL_NAMES: tuple[str, ...] = ("bingham", "kwok", "bouc_wen", "modified_bouc_wen", "dahl")
#: The models with internal state integrated by the RK4 scan.
ODE_MODELS: tuple[str, ...] = ("bouc_wen", "modified_bouc_wen", "dahl")
#: The memoryless models.
STATIC_MODELS: tuple[str, ...] = ("bingham", "kwok")

#: The engine's settings of the test matrix (`tests/test_engine.py`): name -> keyword arguments
#: of `mrjax.fit` (settings objects, the optimistix way). The default (separable, one swarm) is
#: fitted for every model in `tests/test_fit.py`, chunking in `tests/test_chunks.py`, devices
#: in `tests/test_parallel.py`. The paper's full swarm is not a known-answer setting on short
#: records: on the first `SHORT_MOTIONS` record of the tanh model it ends in a local optimum
#: at 5 x the noise floor for seeds 0 and 1 (also with 3 restarts at seed 1), where the
#: separable swarm finds the optimum at every seed; it is tested on the paper grid.
ENGINE_SETTINGS: dict[str, dict] = {
    "restarts": dict(swarm=mrjax.Swarm(restarts=2)),
    "float32": dict(swarm=mrjax.Swarm(dtype="float32")),
}
#: `mrjax.fit`'s methods (`FitResult.method`) and the settings that give each: swarm then
#: polish, swarm alone, polish alone from a neutral start.
METHODS: dict[str, dict] = {"pso+lm": {}, "pso": dict(polish=None), "lm": dict(swarm=None)}
#: The engine's problem kinds and the public function that builds each.
PROBLEM_KINDS: dict[str, str] = {"TestsProblem": "mrjax.fit",
                                 "LawsProblem": "mrjax.generalize.generalize(method='joint'), "
                                                "mrjax.generalize.identify"}


def default_data_dir() -> Path | None:
    """Where the UTFSM damper measurements are, if anywhere.

    **Returns:** the path in the environment variable `MRJAX_DATA` if it is set (whether or not
    it exists, so that a wrong setting fails loudly when loaded); otherwise the first existing
    directory `shared/data/utfsm` in the parent of the working directory or in a parent of this
    checkout (which covers `../shared/data/utfsm` beside it); otherwise `None`.
    """
    env = os.environ.get("MRJAX_DATA")
    if env:
        return Path(env).expanduser()
    tail = Path("shared") / "data" / "utfsm"
    for parent in (Path.cwd().parent, *Path(__file__).resolve().parents):
        if (parent / tail).is_dir():
            return (parent / tail).resolve()
    return None


def named(name: str, **values: float) -> np.ndarray:
    """Parameter vector of model `name` from keyword values (all parameters required)."""
    return mrjax.models.get(name).params(**values)


#: Representative "true" parameters, inside the default bounds. Every entry is non-zero, so a
#: relative finite-difference step is well defined.
TRUE_PARAMS: dict[str, np.ndarray] = {
    "bingham": named("bingham", fc=400.0, c0=3000.0, f0=-20.0),
    # Kwok et al. eq 24-29 at i = 1 A.
    "kwok": named("kwok", c=3161.0, k=3400.0, alpha=706.0, beta=100.0, delta=0.88, f0=-275.0),
    "bouc_wen": named(
        "bouc_wen", c=1500.0, k=2000.0, alpha=600.0, f0=-30.0,
        delta=1500.0, beta=800.0, gamma=600.0, n=2.0,
    ),
    "modified_bouc_wen": named(
        "modified_bouc_wen", c0=3000.0, k0=2000.0, c1=30000.0, k1=500.0, alpha=800.0,
        delta=1000.0, beta=600.0, gamma=400.0, n=2.0, f0=-40.0,
    ),
    "dahl": named("dahl", c=1500.0, k=1500.0, alpha=500.0, rho=2000.0, f0=-30.0),
}

#: Spencer et al. (1997), PAPER.md: voltage-independent part.
SPENCER_1997 = dict(
    c0a=2100.0, c0b=350.0, c1a=28300.0, c1b=295.0, alphaa=14000.0, alphab=69500.0,
    k0=4690.0, k1=500.0, x0=0.143, gamma=3.63e6, beta=3.63e6, A=301.0, n=2.0, eta=190.0,
)


def spencer1997(u: float) -> np.ndarray:
    """Spencer et al. (1997) modified Bouc-Wen parameters at voltage `u` [V], in mrjax order
    `(c0, k0, c1, k1, alpha, delta, beta, gamma, n, f0)`, with delta = A and f0 = -k1 x0.

    z is in metres here (alpha in N/m, beta and gamma in 1/m^2), outside the default bounds.
    """
    s = SPENCER_1997
    return named(
        "modified_bouc_wen",
        c0=s["c0a"] + s["c0b"] * u,
        k0=s["k0"],
        c1=s["c1a"] + s["c1b"] * u,
        k1=s["k1"],
        alpha=s["alphaa"] + s["alphab"] * u,
        delta=s["A"],
        beta=s["beta"],
        gamma=s["gamma"],
        n=s["n"],
        f0=-s["k1"] * s["x0"],
    )


def sine(
    frequency: float = 2.5, amplitude: float = 0.015, sample_rate: float = 1000.0,
    cycles: float = 2.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """`(t, x, xdot, dt)` of $x = A \\sin(2\\pi f t)$ sampled at `sample_rate` [Hz]."""
    t, x, v = mrjax.data.sine_excitation(
        frequency, amplitude, sample_rate=sample_rate, cycles=cycles
    )
    return t, x, v, 1.0 / sample_rate


def draw_sine(draw, n: int, min_rate: float):
    """Hypothesis helper: `(t, x, xdot, rate, frequency, amplitude)` of a sinusoid of 1-2 cycles
    in `n` samples at `min_rate`-1000 Hz, 2-15 mm amplitude and random phase (`draw` from
    `st.composite`); SI units."""
    from hypothesis import strategies as st

    rate = draw(st.floats(min_rate, 1000.0))
    cycles = draw(st.floats(1.0, 2.0))
    amp = draw(st.floats(0.002, 0.015))
    phase = draw(st.floats(0.0, 2 * np.pi))
    f = cycles * rate / n
    t, x, v = mrjax.data.sine_excitation(f, amp, sample_rate=rate, cycles=cycles, phase=phase)
    assert x.shape == (n,)
    return t, x, v, rate, f, amp


# --------------------------------------------------------------------------------------------
# The three file layouts of issue 14 (test_data_spec.py, test_cli_data.py), written at test time
# from the tanh model at the paper's parameters (eq 24-29) for known currents.

KWOK = mrjax.models.get("kwok")
RATE = 1000.0
CURRENTS = (0.0, 0.25, 0.5, 0.75, 1.0)


def motion(n=3000, rate=RATE, peak=0.01):
    """A random-looking displacement [m] (7 sines, 0.3-4.1 Hz) and its analytic velocity."""
    t = np.arange(n) / rate
    f = np.array([0.3, 0.7, 1.1, 1.9, 2.6, 3.3, 4.1])
    a = np.array([1.0, 0.6, 0.4, 0.3, 0.2, 0.15, 0.1])
    ph = np.linspace(0.1, 5.0, f.size)
    w = 2 * np.pi * f[:, None]
    x = (a[:, None] * np.sin(w * t + ph[:, None])).sum(0)
    v = (a[:, None] * w * np.cos(w * t + ph[:, None])).sum(0)
    s = peak / np.max(np.abs(x))
    return t, x * s, v * s


def tanh_force(x, v, current, rate=RATE, noise=0.0, seed=0):
    """The tanh model's force [N] at the paper's parameters for `current` [A] (eq 24-29),
    plus white noise of standard deviation `noise` [N] (fixed `seed`)."""
    f = np.asarray(KWOK.force(mrjax.data.paper_parameters(current), x, v, 1.0 / rate),
                   dtype=float)
    if noise:
        f = f + noise * np.random.default_rng(seed).standard_normal(f.shape)
    return f


def exact(v) -> str:
    """A float written exactly (repr)."""
    return repr(float(v))


def write_layout_a(path, n=3000, noise=0.0):
    """(a) A random-displacement, random-voltage CSV: short headers, cm and cm/s, a voltage
    column, an unused acceleration column, a sample-rate column filled only in its first row,
    a trailing delimiter on every line and an empty last line."""
    t, x, v = motion(n)
    volt = 2.5 + 2.0 * np.sin(2 * np.pi * 0.37 * t) * np.cos(2 * np.pi * 1.3 * t)
    force = tanh_force(x, v, 0.5, noise=noise)
    lines = ["t,x,v,F,V,acc,fs,"]
    acc = np.gradient(v, t)
    for k in range(n):
        fs = "1000" if k == 0 else ""
        lines.append(f"{exact(t[k])},{exact(x[k] * 100)},{exact(v[k] * 100)},{exact(force[k])},"
                     f"{exact(volt[k])},{exact(acc[k])},{fs},")
    path.write_text("\n".join(lines) + "\n\n")
    return dict(t=t, x=x, v=v, force=force, volt=volt)


#: The option strings of layout (a) (`mrjax fit random.csv --columns ...`).
OPTIONS_A = dict(columns="time=t:s,displacement=x:cm,velocity=v:cm/s,force=F:N,command=V:V")
TOML_A = """
[columns]
time = "t:s"
displacement = "x:cm"
velocity = "v:cm/s"
force = "F:N"
command = "V:V"
"""


def write_layout_b(folder, n=3000, noise=0.0):
    """(b) .mat files of a shaking-table campaign: a time vector, displacement in mm, force in
    N and a 3-column matrix [x mm, v mm/s, F N]; names like ensaio.B.1.mat, no current."""
    t, x, v = motion(n)
    out = {}
    for k, current in enumerate((0.5, 1.0), start=1):
        force = tanh_force(x, v, current, noise=noise, seed=k)
        name = f"ensaio.B.{k}.mat"
        scipy.io.savemat(folder / name, {
            "tempo": t[:, None], "desloc": x * 1e3, "forca": force,
            "dados": np.column_stack([x * 1e3, v * 1e3, force]),
        })
        out[name] = dict(t=t, x=x, v=v, force=force, current=current)
    return out


OPTIONS_B = dict(columns="time=tempo:s,displacement=dados[0]:mm,velocity=dados[1]:mm/s,"
                         "force=dados[2]:N",
                 current="ensaio.B.1.mat=0.5,ensaio.B.2.mat=1")
TOML_B = """
[columns]
time         = "tempo:s"
displacement = "desloc:mm"     # the vector; velocity then estimated
force        = "forca:N"

[files."ensaio.B.1.mat"]
current_A = 0.5

[files."ensaio.B.2.mat"]
current_mA = 1000
"""


def write_layout_c(path, n=3000, noise=0.0):
    """(c) A .mat matrix with no time vector: column 0 displacement in mm, columns 1-5 force
    at five currents (one test per column); the rate, 1 kHz, is in the lab's notes."""
    t, x, v = motion(n)
    forces = [tanh_force(x, v, i, noise=noise, seed=k) for k, i in enumerate(CURRENTS)]
    scipy.io.savemat(path, {"M": np.column_stack([x * 1e3, *forces])})
    return dict(t=t, x=x, v=v, forces=forces)


OPTIONS_C = dict(columns="displacement=0:mm", wide="force=1,2,3,4,5:N",
                 current="0,0.25,0.5,0.75,1", sample_rate="1000")
TOML_C = """
[columns]
displacement = "0:mm"

[meta]
sample_rate_Hz = 1000

[wide]
force     = ["M[1]:N", "M[2]:N", "M[3]:N", "M[4]:N", "M[5]:N"]
current_A = [0, 0.25, 0.5, 0.75, 1.0]
"""

# --------------------------------------------------------------------------------------------
# The command line (test_cli.py, test_cli_data.py)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NoneType = type(None)


def run_cli(argv):
    """`mrjax.cli.main(argv)` in-process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def snapshot(d: Path) -> dict[str, bytes]:
    """Every file under `d` (relative name -> bytes)."""
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def raises_one_line(fn, *needles) -> str:
    """Call `fn`, expect a one-line `mrjax.InputError` whose message contains every needle;
    returns the message."""
    import pytest

    with pytest.raises(mrjax.InputError) as info:
        fn()
    msg = str(info.value)
    assert "\n" not in msg
    for n in needles:
        assert str(n) in msg, f"{n!r} not in {msg!r}"
    return msg


def one_error_line(err: str) -> str:
    """The last stderr line, checked to be one `mrjax: error: ...` line without a traceback."""
    lines = err.strip().splitlines()
    assert len(lines) >= 1 and lines[-1].startswith("mrjax: error: "), err
    assert not any("Traceback" in ln for ln in lines), err
    return lines[-1]


_TOP = {"model": str, "method": str, "swarm": str, "seed": int, "param_names": list,
        "units": list, "mrjax_version": str, "conditions": list, "warnings": list}
_COND = {"label": str, "current_A": (float, NoneType), "frequency_Hz": (float, NoneType),
         "amplitude_m": (float, NoneType), "n_samples": int, "params": dict, "stderr": dict,
         "rms_N": float, "nrmse": float, "pso_rms_N": (float, NoneType),
         "generations": (int, NoneType), "stopped_by_criterion": (bool, NoneType),
         "polish_status": str, "polish_steps": int, "identifiable": dict, "estimated": list}


def _is(v, types_):
    types_ = types_ if isinstance(types_, tuple) else (types_,)
    if isinstance(v, bool):  # bool is an int subclass: only where bool is allowed
        return bool in types_
    return isinstance(v, types_)


def check_fit_schema(doc: dict, n_conditions: int) -> None:
    """The fit.json schema of `FitResult.to_dict`: keys and types, per condition too."""
    for key, t in _TOP.items():
        assert key in doc, f"fit.json lacks {key!r}"
        assert _is(doc[key], t), f"{key}: {type(doc[key]).__name__}"
    names = doc["param_names"]
    assert names == list(mrjax.models.get(doc["model"]).param_names)
    assert len(doc["units"]) == len(names) and all(isinstance(u, str) for u in doc["units"])
    assert len(doc["conditions"]) == n_conditions
    labels = {c["label"] for c in doc["conditions"]}
    for w in doc["warnings"]:
        assert set(w) == {"kind", "message", "conditions", "parameters"}, w
        assert w["kind"] in ("at_bound", "not_identifiable", "too_few_currents"), w
        assert set(w["conditions"]) <= labels and set(w["parameters"]) <= set(names), w
    for c in doc["conditions"]:
        for key, t in _COND.items():
            assert key in c, f"condition lacks {key!r}"
            assert _is(c[key], t), f"{key}: {c[key]!r}"
        assert list(c["params"]) == names and all(_is(v, float) for v in c["params"].values())
        assert list(c["stderr"]) == names
        assert all(_is(v, (float, NoneType)) for v in c["stderr"].values())
        assert list(c["identifiable"]) == names
        assert set(c["estimated"]) <= set(mrjax.data.ESTIMATED_FIELDS)
        assert c["n_samples"] > 0 and math.isfinite(c["rms_N"]) and c["rms_N"] >= 0


def check_pngs(d: Path, names) -> None:
    """Each named file in `d` is a real PNG."""
    for n in names:
        data = (d / n).read_bytes()
        assert data[:8] == PNG_MAGIC and len(data) > 2000, n


#: Short records for the per-model known answers: two sine tests at 1 kHz.
SHORT_MOTIONS: tuple[tuple[float, float, float], ...] = ((2.5, 0.015, 1.25), (1.5, 0.008, 1.25))


def short_batch(name: str, *, noise_frac: float = 0.01, seed: int = 0):
    """`(batch, truth)`: the two `SHORT_MOTIONS` tests simulated by model `name` at
    `TRUE_PARAMS[name]`, with Gaussian force noise of `noise_frac` x max|F|; truth (2, P)."""
    theta = TRUE_PARAMS[name]
    conds = []
    for k, (f, a, cycles) in enumerate(SHORT_MOTIONS):
        clean = mrjax.data.simulate(name, theta, frequency=f, amplitude=a, cycles=cycles)
        sigma = noise_frac * float(np.max(np.abs(clean.force)))
        conds.append(mrjax.data.simulate(name, theta, frequency=f, amplitude=a, cycles=cycles,
                                         noise=sigma, seed=seed + k))
    return mrjax.data.make_batch(conds), np.broadcast_to(theta, (2, len(theta))).copy()


# --------------------------------------------------------------------------------------------
# One result computed two ways (a batch and its parts, pages, chunks, devices): equal to
# rounding, on any CPU. XLA vectorises a reduction differently for different batch widths and
# CPUs (AVX-512, AVX2, NEON), so the two agree to ~1e-13 relative, not bit for bit. A count
# decided by a stopping test moves when that test's margin is within rounding: the polish's
# stall test compares RMS changes of ~1e-12 near an optimum, so its step counts move freely
# (seen: [6, 6, 7] vs [6, 6, 12] on an AMD EPYC); the swarm's statistical stop compares a mean
# improvement with a threshold far above rounding, so its generation counts move only in a rare
# near-tie.

#: Relative agreement of swarm fitness and positions computed two ways (measured ~1e-13).
SWARM_RTOL = 1e-9
#: Relative agreement of two polishes of one problem that stopped at different steps: the stall
#: test stops when 8 steps lower the RMS by less than `mrjax.refine.DEFAULT_TOL` (1e-6), so
#: their RMS agree to about that; a step count itself is never compared.
POLISH_RMS_RTOL = 2e-6


def assert_same_swarms(gens_a, gens_b, hist_a, hist_b, pos_a=None, pos_b=None, *,
                       rtol: float = SWARM_RTOL, max_moved: int = 1) -> None:
    """Swarms of the same conditions computed two ways: each best-fitness history agrees to
    `rtol` up to the earlier of the two stops; the generation counts agree except for at most
    `max_moved` conditions (a statistical stop within rounding of its threshold); where they
    agree, the final positions agree to `rtol` too.

    A real defect (conditions mixed, a key reused, a stop ignored) fails: histories differ from
    generation 0 (every condition has its own data and stream), or many counts differ.
    """
    ga, gb = np.asarray(gens_a).reshape(-1), np.asarray(gens_b).reshape(-1)
    ha, hb = np.asarray(hist_a).reshape(ga.size, -1), np.asarray(hist_b).reshape(gb.size, -1)
    assert ga.shape == gb.shape
    for c, (x, y) in enumerate(zip(ga, gb)):
        g = int(min(x, y)) + 1 if x >= 0 else ha.shape[1]
        np.testing.assert_allclose(ha[c, :g], hb[c, :g], rtol=rtol, err_msg=f"condition {c}")
    moved = np.flatnonzero(ga != gb)
    assert moved.size <= max_moved, f"generations {ga} vs {gb}"
    if pos_a is not None:
        same = ga == gb
        np.testing.assert_allclose(np.asarray(pos_a)[same], np.asarray(pos_b)[same], rtol=rtol,
                                   atol=0)


def assert_same_polish(rms_a, rms_b, theta_a=None, theta_b=None, *,
                       rms_rtol: float = POLISH_RMS_RTOL, theta_rtol: float = 1e-4) -> None:
    """Polishes of the same conditions computed two ways (possibly stopped at different steps):
    RMS equal to `rms_rtol`, parameters to `theta_rtol` (well-determined fits; a defect such as
    a condition polished on another's data moves them by percents)."""
    np.testing.assert_allclose(np.asarray(rms_a), np.asarray(rms_b), rtol=rms_rtol)
    if theta_a is not None:
        np.testing.assert_allclose(np.asarray(theta_a), np.asarray(theta_b), rtol=theta_rtol)


def outputs(d) -> list[str]:
    """The names of a command's outputs in directory `d`, sorted: every entry but the manifest
    that says which command wrote them (`mrjax._io.MANIFEST`, checked in test_outputs.py)."""
    from mrjax._io import MANIFEST

    return sorted(p for p in os.listdir(d) if p != MANIFEST)


def previous_output(d: Path, command: str = "fit", files: dict[str, bytes] | None = None) -> Path:
    """Directory `d` as a previous run of `mrjax COMMAND` left it (its files and the manifest,
    written by `mrjax._io.OutputDir`); default files: an old fit.json and loops.png."""
    from mrjax._io import OutputDir

    if files is None:
        files = {"fit.json": b'{"previous": "run"}\n', "loops.png": PNG_MAGIC + b"old"}
    with OutputDir(d, command) as out:
        out.write(files)
    return d
