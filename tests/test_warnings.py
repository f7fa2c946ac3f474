"""Results that say when they are doubtful (lmfit's fit report): parameters at a bound of the
search box, parameters that are not identifiable, laws from fewer currents than their degree
needs; in `FitResult.warnings`, the printed table, fit.json and the command's output.

Known answers on the tanh model at the paper's parameters (eq 24-29): a box that cuts the true
damping in half puts `c` on its upper bound; the same tests fitted in the default box put no
parameter there; laws of the paper's degrees (alpha quadratic, c, k, delta, f0 linear) from
one current, then from two.
"""

import dataclasses
import json

import numpy as np
import pytest
from helpers import run_cli as run

import mrjax
from mrjax.data import paper_grid, paper_truth

#: Two short tests (one cycle at 500 Hz: one compiled shape for every fit here).
ONE_CURRENT = dict(currents=(1.0,), motions=((1.0, 0.008), (1.0, 0.006)), cycles=1,
                   sample_rate=500.0)
TWO_CURRENTS = dict(currents=(0.5, 1.0), motions=((1.0, 0.008),), cycles=1, sample_rate=500.0)


@pytest.fixture(scope="module")
def one_current():
    batch = paper_grid(**ONE_CURRENT)
    return batch, paper_truth(batch)


@pytest.fixture(scope="module")
def capped(one_current):
    """Fitted with `c` capped at half its true value (3161 N s/m at 1 A)."""
    batch, truth = one_current
    return mrjax.fit("kwok", batch, bounds=({}, {"c": 0.5 * truth[0, 0]}), key=0)


@pytest.fixture(scope="module")
def free(one_current):
    return mrjax.fit("kwok", one_current[0], key=0)


def test_a_parameter_at_a_bound_is_flagged(one_current, capped):
    batch, truth = one_current
    np.testing.assert_allclose(capped.param("c"), 0.5 * truth[0, 0], rtol=1e-3)  # on the bound
    (w,) = capped.warnings()
    assert isinstance(w, mrjax.ResultWarning) and str(w) == w.message
    assert w.kind == mrjax.WarningKind.AT_BOUND and w.parameters == ("c",)
    assert w.conditions == tuple(batch.labels)
    assert "c at a bound of the search box in 2 tests" in w.message
    assert "upper bound" in w.message and "--bounds" in w.message
    assert capped.table().splitlines()[-1] == f"warning: {w.message}"
    doc = json.loads(capped.to_json())
    assert doc["warnings"] == [w.to_dict()] and doc["warnings"][0]["kind"] == "at_bound"
    # the search box travels with the result (subsets, chunks, journals)
    assert capped.subset([1]).warnings()[0].conditions == (batch.labels[1],)
    back = mrjax.FitResult.from_state(json.loads(json.dumps(capped.to_state())), capped.model)
    assert back.warnings() == capped.warnings()


def test_a_sound_fit_has_no_warning(one_current, free):
    batch, truth = one_current
    assert np.all(free.rms < 1.05 * 20.0)  # the noise floor: a sound fit
    assert free.warnings() == [] and "warning" not in free.table()
    assert json.loads(free.to_json())["warnings"] == []


def test_not_identifiable_parameters_are_flagged(free):
    ident = np.ones_like(free.identifiable)
    ident[1, [2, 3]] = False  # as `mrjax.refine.uncertainty` flags a null direction
    (w,) = dataclasses.replace(free, identifiable=ident).warnings()
    assert w.kind == mrjax.WarningKind.NOT_IDENTIFIABLE and w.parameters == ("alpha", "beta")
    assert w.conditions == (free.labels[1],)


def test_laws_from_too_few_currents_are_flagged(one_current, free):
    batch, _ = one_current
    gm = mrjax.generalize.generalize(free, batch, method="two-step")
    assert all(len(gm.coefficients(n)) == 1 for n in gm.param_names)  # reduced to constants
    (w,) = [w for w in free.warnings(gm) if w.kind == mrjax.WarningKind.TOO_FEW_CURRENTS]
    assert w.parameters == ("c", "k", "alpha", "delta", "f0")  # beta is constant anyway
    assert "from 1 distinct current (1 A)" in w.message and "constants" in w.message
    assert json.loads(free.to_json(generalized=gm))["warnings"] == [w.to_dict()]
    # two currents determine the linear laws, not alpha's quadratic one
    two = paper_grid(**TWO_CURRENTS)
    res = mrjax.fit("kwok", two, key=0)
    gm2 = mrjax.generalize.generalize(res, two, method="two-step")
    (w2,) = res.warnings(gm2)
    assert w2.parameters == ("alpha",) and "of degree at most 1" in w2.message


def _csv(batch, path):
    rows = ["condition,current_A,frequency_Hz,amplitude_m,time_s,displacement_m,velocity_m_s,"
            "force_N"]
    for c in batch.conditions():
        head = f"{c.label},{c.current!r},{c.frequency!r},{c.amplitude!r}"
        rows += [f"{head},{t!r},{x!r},{v!r},{f!r}" for t, x, v, f in
                 zip(c.t.tolist(), c.x.tolist(), c.xdot.tolist(), c.force.tolist())]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_the_command_prints_and_writes_the_warnings(one_current, tmp_path):
    """The issue's case: `mrjax fit` of tests at one current, with a parameter on its bound,
    and `--generalize`: the table and the laws end with warnings, fit.json lists them."""
    batch, truth = one_current
    csv = _csv(batch, tmp_path / "one_current.csv")
    code, stdout, err = run(["fit", csv, "--model", "kwok", "--bounds",
                             f"c=:{float(0.5 * truth[0, 0])!r}", "--generalize", "two-step",
                             "--no-plots", "--out", tmp_path / "o"])
    assert code == 0, err
    warned = [ln for ln in stdout.splitlines() if ln.startswith("warning: ")]
    assert len(warned) == 2 and "c at a bound" in warned[0], stdout
    assert "laws of c, k, alpha, delta, f0 from 1 distinct current" in warned[1]
    assert stdout.index(warned[1]) > stdout.index("generalized (two-step)")  # after the laws
    doc = json.loads((tmp_path / "o" / "fit.json").read_text())
    assert [w["kind"] for w in doc["warnings"]] == ["at_bound", "too_few_currents"]
