"""A parameter held at a value through every stage (issue 37): a declared model with `delta`
fixed recovers a known answer through the per-test fit, the joint laws over the current and
both posteriors; `mrjax fit --fixed` records it in fit.json and `mrjax predict` rebuilds it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import mrjax
from mrjax.data import paper_grid, paper_parameters

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "my_models.py"
DELTA = 0.6  # the truth's delta, constant over the current (held in the fit)
CURRENTS = (0.0, 0.5, 1.0)
MOTIONS = ((1.0, 0.008), (2.0, 0.006))


def truth(i):
    """Eq 24-29's tanh parameters at current `i`, delta held at `DELTA`."""
    th = np.array(paper_parameters(i), float)
    th[4] = DELTA
    return th


@pytest.fixture(scope="module")
def data():
    return paper_grid("kwok", truth, currents=CURRENTS, motions=MOTIONS, noise=5.0, seed=3)


@pytest.fixture(scope="module")
def model():
    return mrjax.models.fix(mrjax.models.get(f"{EXAMPLES}:Tanh"), {"delta": DELTA})


@pytest.fixture(scope="module")
def fitted(model, data):
    return mrjax.fit(model, data, swarm=mrjax.Swarm(max_generations=60), key=0)


def test_fit_recovers_the_others_and_holds_delta(fitted, data):
    assert fitted.model.fixed == {"delta": DELTA}
    assert "delta" not in fitted.param_names
    true = np.stack([truth(i) for i in np.asarray(data.current)])
    keep = [0, 1, 2, 3, 5]  # c, k, alpha, beta, f0 (delta held)
    err = np.abs(fitted.theta - true[:, keep])
    assert np.all(err <= 4.0 * fitted.stderr + 1e-6 * np.abs(true[:, keep])), err / fitted.stderr
    doc = json.loads(fitted.to_json())
    assert doc["fixed"] == {"delta": DELTA} and doc["format"] == 2
    assert "delta" not in doc["bounds"]["lower"]


def test_joint_laws_hold_delta_and_recover_the_laws(fitted, data):
    gm = mrjax.generalize.generalize(fitted, data, method="joint",
                                     laws={n: "poly" for n in fitted.param_names})
    assert gm.model.fixed == {"delta": DELTA} and "delta" not in gm.laws
    for i in CURRENTS:
        at = np.asarray(gm.params_at(i))
        want = truth(i)[[0, 1, 2, 3, 5]]
        assert np.all(np.abs(at[:4] - want[:4]) <= 0.05 * np.abs(want[:4])), (i, at, want)
    again = mrjax.generalize.GeneralizedModel.from_dict(json.loads(gm.to_json()))
    assert again.model.fixed == {"delta": DELTA}


def test_posterior_holds_delta_and_covers_the_truth(fitted, data):
    sub = data.subset([0, 5])
    res = fitted.subset([0, 5])
    post = mrjax.posterior(res, sub, sampler=mrjax.Sampler(draws=300, chains=2, warmup=200,
                                                         continuations=0),
                           key=1)
    p = post.posterior
    assert p.names == fitted.param_names
    for u, i in enumerate(np.asarray(sub.current)):
        want = truth(i)[[0, 1, 2, 3, 5]]
        for j, n in enumerate(p.names):
            lo, hi = np.percentile(p.draws(n)[u], [0.5, 99.5])
            assert lo <= want[j] <= hi, (n, i, lo, want[j], hi)


def test_cli_fixed_round_trip(tmp_path, data):
    from mrjax.cli import main
    from mrjax.data import to_frame

    csv = tmp_path / "tests.csv"
    to_frame(data).to_csv(csv, index=False)
    out = tmp_path / "fit"
    code = main(["fit", str(csv), "--model", f"{EXAMPLES}:Tanh", "--fixed", "delta=0.6",
                 "--max-generations", "40", "--no-plots", "--out", str(out)])
    assert code == 0
    doc = json.loads((out / "fit.json").read_text())
    assert doc["fixed"] == {"delta": 0.6} and doc["model_source"]["fixed"] == {"delta": 0.6}
    assert "delta" not in doc["param_names"]
    bad = main(["fit", str(csv), "--model", "kwok", "--fixed", "dleta=1", "--out",
                str(tmp_path / "bad")])
    assert bad == 2 and not (tmp_path / "bad" / "fit.json").exists()
