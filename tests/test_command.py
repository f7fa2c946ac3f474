"""Time-varying command (issue 15): identification from random-command records (Spencer et
al.'s 1997 voltage-dependent modified Bouc-Wen known answer), the inverse of a dynamic model
and its closed loop, the command line (`mrjax fit --generalize joint` on files with a
per-sample command, `--lag`, `mrjax predict` replaying the command) and the figures.

The known answer here is a short record (3 s at 1 kHz instead of 20 s at 3 kHz: the full size
is `benchmarks/command.py`); the mixed campaign (sine tests + a random record) runs with
MRJAX_SLOW=1; the command-line tests use the tanh model's laws (fast) with a lag.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from helpers import one_error_line
from helpers import run_cli as run

import mrjax
from mrjax.data import make_batch
from mrjax.generalize import (
    GeneralizedModel,
    Law,
    closed_loop,
    command_record,
    identify,
    inverse,
    random_motion,
    sine_record,
    spencer_1997,
)
from mrjax.pso import PSOParams


# ------------------------------------------------------------------------------ known answer
def test_spencer_1997_known_answer():
    """Identify Spencer's model from one random-command record: every coefficient within 5 %
    or 2 std-errors, eta within 10 %, validation NRMSE within 0.2 points of the truth's."""
    truth = spencer_1997()
    rec = command_record(truth, duration=3.0, sample_rate=1000.0, seed=1)
    val = command_record(truth, duration=3.0, sample_rate=1000.0, seed=2)
    gm = identify(rec, "modified_bouc_wen", lag="fit", key=0,
                  swarm=mrjax.Swarm(params=PSOParams(window=25, min_generations=100)))
    assert gm.command_unit == "V" and gm.report.lag_fitted
    tc = truth.with_canonical_z()
    unc = gm.uncertainty
    loose = gm.loosely_determined()
    for n in gm.param_names:
        got, want = np.asarray(gm.coefficients(n)), np.asarray(tc.coefficients(n))
        se = np.asarray(unc.stderr[n], float)
        assert got.shape == want.shape, n
        rel = np.abs(got - want) / np.abs(want)
        z = np.abs(got - want) / se
        print(f"{n}: {got} vs {want}, rel {rel}, z {z}")
        assert np.all((rel <= 0.05) | (z <= 2.0)), (n, got, want, se)
        # a coefficient further than 5 % from the truth is one the flags call loose
        assert np.all((rel <= 0.05) | np.asarray(loose[n])), (n, got, want, se)
    assert abs(gm.lag - 190.0) / 190.0 <= 0.10, gm.lag
    assert unc.lag_stderr is not None and unc.lag_stderr > 0
    vb = make_batch([val])
    nr, nr_true = gm.evaluate(vb)["nrmse"][0], truth.evaluate(vb)["nrmse"][0]
    print(f"eta {gm.lag:.2f}; validation NRMSE {100 * nr:.3f} % vs true {100 * nr_true:.3f} %")
    assert abs(nr - nr_true) <= 0.002


@pytest.mark.skipif(os.environ.get("MRJAX_SLOW") != "1",
                    reason="about 2 min on 2 cores; set MRJAX_SLOW=1 (full size: "
                    "benchmarks/command.py)")
def test_mixed_campaign_predicts_a_random_record():
    """Sine tests at 0, 1, 2 V plus one random-command record predict another random record
    within 0.5 points of the true model's NRMSE (measured: +0.002 points)."""
    truth = spencer_1997()
    rec = command_record(truth, duration=3.0, sample_rate=1000.0, seed=1)
    val = command_record(truth, duration=3.0, sample_rate=1000.0, seed=2)
    sines = [sine_record(truth, lv, seed=10 + k) for k, lv in enumerate((0.0, 1.0, 2.0))]
    gm = identify(sines + [rec], "modified_bouc_wen", lag="fit", key=0,
                  polish=mrjax.Polish(uncertainty=False))
    vb = make_batch([val])
    nr, nr_true = gm.evaluate(vb)["nrmse"][0], truth.evaluate(vb)["nrmse"][0]
    assert abs(nr - nr_true) <= 0.005
    assert abs(gm.lag - 190.0) / 190.0 <= 0.10


# ------------------------------------------------------------------------------ inverse
def test_inverse_dynamic_round_trip_and_saturation():
    """Desired force -> command (scan carrying the Bouc-Wen state and the lag) -> the model
    replayed under that command: RMS < 1 % of max|F| where reachable; 1.5 x the force is
    partly out of reach, flagged, with the command at a limit there."""
    truth = spencer_1997()
    rec = command_record(truth, duration=1.5, sample_rate=1000.0, noise=0.0, seed=3)
    dt = 1e-3
    fd = np.asarray(rec.force)
    inv = inverse(truth, rec.x, rec.xdot, fd, dt=dt)
    back = np.asarray(truth.force(rec.x, rec.xdot, dt, np.asarray(inv.command)))
    reach = ~np.asarray(inv.out_of_reach)
    assert reach.mean() > 0.95
    err = np.sqrt(np.mean((back - fd)[reach] ** 2)) / np.max(np.abs(fd))
    print(f"round trip RMS {100 * err:.2e} % of max|F|")
    assert err < 0.01
    cmd = np.asarray(inv.command)
    assert np.all((cmd >= 0.0) & (cmd <= 2.25))
    big = inverse(truth, rec.x, rec.xdot, 1.5 * fd, dt=dt)
    out = np.asarray(big.out_of_reach)
    assert 0.05 < out.mean() < 0.95
    assert np.asarray(big.saturated)[out].mean() > 0.9
    np.testing.assert_allclose(np.asarray(big.force), np.asarray(
        truth.force(rec.x, rec.xdot, dt, np.asarray(big.command))), atol=1e-6 * np.abs(fd).max())
    with pytest.raises(mrjax.InputError, match="dt"):
        inverse(truth, rec.x, rec.xdot, fd)


def test_closed_loop_skyhook():
    """The inverse in a closed loop (no lag): it tracks the skyhook force better than either
    passive setting, and its response lies between them."""
    truth = spencer_1997()
    fs = 1000.0
    _, _, vg = random_motion(3.0, fs, amplitude=0.02, band=(0.5, 5.0), seed=4)
    ag = np.gradient(vg, 1 / fs)
    mass = 200.0
    k = mass * (2 * np.pi * 1.5) ** 2
    res = {c: closed_loop(truth, ag, 1 / fs, mass=mass, stiffness=k, gain=10000.0, control=c,
                          lag=None) for c in ("off", "on", "inverse")}
    track = {c: float(np.sqrt(np.mean((np.asarray(r.force) - np.asarray(r.desired)) ** 2)))
             for c, r in res.items()}
    print(track)
    assert track["inverse"] < min(track["off"], track["on"])
    cmd = np.asarray(res["inverse"].command)
    assert cmd.min() >= 0.0 and cmd.max() <= 2.25 and np.ptp(cmd) > 1.0
    with pytest.raises(mrjax.InputError, match="control"):
        closed_loop(truth, ag, 1 / fs, mass=mass, stiffness=k, gain=1.0, control="max")


# ------------------------------------------------------------------------------ command line
def _tanh_laws() -> GeneralizedModel:
    laws = {"c": Law("poly", (1000.0, 2000.0)), "k": Law("poly", (2000.0,)),
            "alpha": Law("poly", (200.0, 400.0)), "beta": Law("poly", (100.0,)),
            "delta": Law("poly", (0.9,)), "f0": Law("poly", (-50.0,))}
    return GeneralizedModel("kwok", laws, "given", float("nan"), (0.0, 2.25),
                            command_unit="V", lag=190.0)


def _write(path, cond) -> None:
    rows = ["t,x,v,F,V"] + [f"{a!r},{b!r},{c!r},{d!r},{e!r}" for a, b, c, d, e in zip(
        *(np.asarray(s, float).tolist() for s in (cond.t, cond.x * 100, cond.xdot * 100,
                                                  cond.force, cond.command)))]
    path.write_text("\n".join(rows) + "\n")


COLUMNS = "time=t:s,displacement=x:cm,velocity=v:cm/s,force=F:N,command=V:V"


@pytest.fixture(scope="module")
def command_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cmd")
    gm = _tanh_laws()
    for s in (1, 2):
        _write(d / f"rand{s}.csv", command_record(gm, duration=3.0, sample_rate=500.0,
                                                  noise=0.01, seed=s))
    return d


@pytest.mark.parametrize("lag", ["190", "fit"])
def test_cli_fit_and_predict_command(command_files, tmp_path, lag):
    out = tmp_path / "fit"
    degrees = ["--degrees", "alpha=1,beta=0"] if lag == "fit" else []
    code, stdout, err = run(["fit", command_files / "rand1.csv", "--model", "kwok",
                             "--generalize", "joint", "--lag", lag, "--columns", COLUMNS,
                             "--out", out, "--max-generations", "60", *degrees])
    assert code == 0, err
    doc = json.loads((out / "fit.json").read_text())
    g = doc["generalized"]
    assert doc["method"] == "identify" and doc["command_unit"] == "V"
    assert g["command_unit"] == "V" and g["current_range_A"] is None
    assert g["laws"]["c"]["degree"] >= 1 and g["laws"]["alpha"]["degree"] >= 1
    if degrees:
        assert g["laws"]["alpha"]["degree"] == 1 and g["laws"]["beta"]["degree"] == 0
    if lag == "190":
        assert doc["lag_1_s"] == 190.0 and not g["lag_fitted"]
    else:
        assert g["lag_fitted"] and abs(doc["lag_1_s"] - 190.0) < 40.0
        assert g["lag_stderr_1_s"] > 0
    truth, got = _tanh_laws(), GeneralizedModel.from_dict(g)
    u = np.array([0.0, 1.0, 2.0])
    for n in ("c", "alpha"):  # the laws of the voltage, where the record spans it
        p = got.param_names.index(n)
        np.testing.assert_allclose(np.asarray(got.params_at(u))[:, p],
                                   np.asarray(truth.params_at(u))[:, p], rtol=0.1)
    csv_text = (out / "fit.csv").read_text()
    assert csv_text.startswith("parameter,power,coefficient,stderr,unit,command_unit")
    assert "eta,0," in csv_text
    assert {"force_time.png", "laws_vs_command.png"} <= {p.name for p in out.iterdir()}
    assert doc["conditions"][0]["nrmse"] < 0.02
    if lag == "fit":
        return
    pred = tmp_path / "pred"
    code, stdout, err = run(["predict", "--fit", out, command_files / "rand2.csv",
                             "--columns", COLUMNS, "--out", pred])
    assert code == 0, err
    assert any(p.suffix == ".png" for p in pred.iterdir())
    rep = json.loads((pred / "predict.json").read_text())
    nr = rep["conditions"][0]["nrmse"]
    # the command replayed through the lag: close to the noise floor; without it, far worse
    gm = GeneralizedModel.from_json_file(out / "fit.json")
    cond = mrjax.data.load(command_files / "rand2.csv",
                           spec=mrjax.data.DataSpec.from_options(columns=COLUMNS))
    b = make_batch(cond)
    assert nr == pytest.approx(float(gm.evaluate(b)["nrmse"][0]), rel=1e-6)
    assert nr < 0.02 < float(gm.evaluate(b, lag=None)["nrmse"][0]) * 2


@pytest.mark.parametrize("argv, match", [
    (["--lag", "-3"], "--lag"),
    (["--lag", "fast"], "--lag"),
    (["--generalize", "joint", "--degrees", "zz=1"], "zz"),
    (["--generalize", "two-step"], "joint"),
])
def test_cli_command_errors(command_files, tmp_path, argv, match):
    base = ["fit", command_files / "rand1.csv", "--model", "kwok", "--columns", COLUMNS,
            "--out", tmp_path / "o"]
    if argv[:1] == ["--lag"]:
        base += ["--generalize", "joint"]
    code, _, err = run(base + argv)
    assert code == 2 and "Traceback" not in err
    last = err.strip().splitlines()[-1]
    if argv[:1] == ["--lag"]:  # a usage error: the usage, then one line naming the flag
        assert "error: argument --lag" in last, err
    else:
        assert match in one_error_line(err)
    assert not (tmp_path / "o").exists()
