"""`mrjax.report`: figures (axes, labels, lines, fallbacks) and tables, without any fitting."""

import dataclasses

import numpy as np
import pytest

import mrjax
import mrjax.report as rp
from mrjax.data import make_batch, paper_grid, paper_parameters
from mrjax.fitting import FitResult
from mrjax.report._loops import condition_title

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
MOTIONS = ((1.0, 0.008), (2.0, 0.004))


def _result(batch, *, method="pso+lm", gens=(7, 12, 20, 20), seed=0) -> FitResult:
    """A FitResult by hand: the true tanh parameters of each condition, made-up diagnostics."""
    model = mrjax.models.get("kwok")
    C, P = batch.n_conditions, model.n_params
    cur = np.asarray(batch.current, float)
    theta = paper_parameters(np.nan_to_num(cur, nan=0.5))
    rng = np.random.default_rng(seed)
    rms = 18.0 + 4.0 * rng.random(C)
    swarm = method != "lm"
    G = 20
    gens = np.asarray(gens[:C] if swarm else [-1] * C)
    hist = np.zeros((C, 0))
    if swarm:
        g = np.arange(G + 1)
        hist = np.stack([np.maximum(300.0 * 0.7 ** np.minimum(g, k), r) for k, r in zip(gens, rms)])
    return FitResult(
        model=model, method=method, swarm_mode="separable" if swarm else "none", seed=seed,
        labels=tuple(batch.labels), current=cur, frequency=np.asarray(batch.frequency, float),
        amplitude=np.asarray(batch.amplitude, float), n_samples=np.asarray(batch.n_samples),
        theta=theta, rms=rms, nrmse=rms / 1000.0,
        pso_rms=rms * 1.3 if swarm else np.full(C, np.nan), generations=gens,
        stopped_by_criterion=gens < G if swarm else np.zeros(C, bool), history=hist,
        polish_steps=np.full(C, 5), polish_status=("converged",) * C,
        stderr=np.abs(theta) * 0.05, ci95=np.zeros((C, P, 2)), corr=np.zeros((C, P, P)),
        identifiable=np.ones((C, P), bool), timings={},
    )


@pytest.fixture(scope="module")
def batch():
    return paper_grid(currents=(0.0, 1.0), motions=MOTIONS, cycles=1, noise=5.0)


@pytest.fixture(scope="module")
def result(batch):
    return _result(batch)


@pytest.fixture(scope="module")
def unknown_batch(batch):
    """The same tests with current, frequency and amplitude unknown (NaN)."""
    conds = [dataclasses.replace(c, current=None, frequency=None, amplitude=None,
                                 label=f"run{i}") for i, c in enumerate(batch.conditions())]
    return make_batch(conds)


def _visible(fig):
    return [a for a in fig.axes if a.get_visible() and a.get_label() != "<colorbar>"]


def _texts(fig):
    out = [t.get_text() for t in fig.texts]
    if fig._suptitle is not None:
        out.append(fig._suptitle.get_text())
    for ax in fig.axes:
        out += [ax.get_title(), ax.get_title("left"), ax.get_xlabel(), ax.get_ylabel()]
        out += [t.get_text() for t in ax.texts]
    for leg in fig.legends + [ax.get_legend() for ax in fig.axes if ax.get_legend()]:
        out += [t.get_text() for t in leg.get_texts()] + [leg.get_title().get_text()]
    return " | ".join(out)


def _png_ok(fig):
    png = rp.save_png_bytes(fig)
    assert png.startswith(PNG_MAGIC) and len(png) > 5000


# --------------------------------------------------------------------------------------------
# Loops


def test_loops_grid_measured_vs_fitted(result, batch):
    fig = rp.plot_loops_grid(result, batch)
    axes = _visible(fig)
    assert len(axes) == 2 * batch.n_conditions  # one F-x and one F-v panel per condition
    for ax in axes:
        lines = ax.get_lines()
        assert len(lines) == 2  # measured, fitted
        assert lines[0].get_color() != lines[1].get_color()
    # every panel has its x label (rows are other motions), F-x above F-v
    assert [ax.get_xlabel() for ax in axes] == ["x [mm]", "v [mm/s]"] * batch.n_conditions
    assert any(ax.get_ylabel() == "F [N]" for ax in axes)
    text = _texts(fig)
    for i in range(batch.n_conditions):  # readable titles: "8 mm, 1 Hz, 0 A"
        name = condition_title(batch.labels[i], batch.frequency[i], batch.amplitude[i],
                                  batch.current[i])
        assert name == (f"{1e3 * batch.amplitude[i]:g} mm, {batch.frequency[i]:g} Hz, "
                        f"{batch.current[i]:g} A")
        assert f"{name}\nRMS {result.rms[i]:.3g} N" in text
    assert "measured" in text and "model" in text
    assert rp.TANH_STEP_NOTE.split(":")[0] in text.replace("\n", " ")  # the tanh model's step
    # a readable size: two columns of cells about 2 in wide, ticks of 7 pt
    assert fig.get_size_inches()[0] <= 6.0
    assert axes[0].xaxis.get_ticklabels()[0].get_fontsize() >= 7
    # the fitted line is the model force on the real (unpadded) samples
    n0 = int(batch.n_samples[0])
    f_fit = np.asarray(result.predict(batch))[0, :n0]
    np.testing.assert_allclose(axes[0].get_lines()[1].get_ydata(), f_fit)
    _png_ok(fig)


def test_loops_grid_max_panels_and_explicit_force(result, batch):
    force = np.zeros((batch.n_conditions, batch.length))
    fig = rp.plot_loops_grid(result, batch, max_panels=2, force=force, rms=[1.0, 2.0, 3.0, 4.0],
                             title="custom")
    assert len(_visible(fig)) == 4
    text = _texts(fig)
    assert "2 of 4 conditions shown" in text and "custom" in text
    assert "RMS 1 N" in text and "RMS 4 N" in text  # first and last are kept
    with pytest.raises(ValueError, match="shape"):
        rp.plot_loops_grid(result, batch, force=np.zeros((2, 3)))


def test_loops_grid_unknown_metadata_falls_back(result, unknown_batch):
    fig = rp.plot_loops_grid(result, unknown_batch, rms=[np.nan, 1, 2, 3])
    assert len(_visible(fig)) == 8
    assert "run0\nRMS -" in _texts(fig)  # no metadata: the label
    _png_ok(fig)


def test_data_loops_by_current(batch):
    fig = rp.plot_data_loops(batch)
    axes = _visible(fig)
    assert len(axes) == 2 * len(MOTIONS)
    assert any(a.get_label() == "<colorbar>" for a in fig.axes)  # colour = current
    assert "current [A]" in [a.get_ylabel() for a in fig.axes]
    assert {a.get_ylabel() for a in axes} == {"force F [N]"}
    assert {"displacement x [mm]", "velocity v [mm/s]"} <= {a.get_xlabel() for a in axes}
    for ax in axes:  # one loop per current; colours differ with the current
        lines = ax.get_lines()
        assert len(lines) == 2 and lines[0].get_color() != lines[1].get_color()
    one = rp.plot_data_loops(batch, motion=(2.0, 0.004))
    assert len(_visible(one)) == 2 and "2 Hz, 4 mm" in _texts(one)
    with pytest.raises(ValueError, match="not in the batch"):
        rp.plot_data_loops(batch, motion=(5.0, 0.001))


def test_data_loops_unknown_current_uses_legend(unknown_batch):
    fig = rp.plot_data_loops(unknown_batch)
    assert not any(a.get_label() == "<colorbar>" for a in fig.axes)
    assert "run3" in _texts(fig) and "unknown motion" in _texts(fig)
    _png_ok(fig)


# --------------------------------------------------------------------------------------------
# Scalars vs current


def test_rms_vs_current_one_colour_per_model_one_marker_per_motion(result, batch):
    other = _result(batch, seed=1)
    fig = rp.plot_rms_vs_current({"kwok": result, "bouc_wen": other})
    (ax,) = fig.axes
    assert ax.get_xlabel() == "current [A]" and ax.get_ylabel() == "RMS force error [N]"
    pts = np.concatenate([c.get_offsets() for c in ax.collections])
    assert len(pts) == 2 * batch.n_conditions
    assert sorted(pts[:, 1]) == pytest.approx(sorted(np.r_[result.rms, other.rms]))
    colors = {tuple(np.round(c.get_edgecolor()[0], 3)) for c in ax.collections}
    assert len(colors) == 2
    paths = {c.get_paths()[0].vertices.tobytes() for c in ax.collections}
    assert len(paths) == len(MOTIONS)
    text = _texts(fig)
    assert "kwok" in text and "bouc_wen" in text and "1 Hz, 8 mm" in text and "2 Hz, 4 mm" in text
    _png_ok(rp.plot_rms_vs_current(result, logy=True))


def test_rms_vs_current_unknown_current_uses_index(unknown_batch):
    res = _result(unknown_batch)
    ax = rp.plot_rms_vs_current(res).axes[0]
    assert "condition index" in ax.get_xlabel()
    xs = np.sort(np.concatenate([c.get_offsets()[:, 0] for c in ax.collections]))
    np.testing.assert_allclose(xs, np.arange(4), atol=0.2)


def test_generations_vs_current(result, batch):
    fig = rp.plot_generations_vs_current([result])
    (ax,) = fig.axes
    assert ax.get_ylabel() == "generations" and ax.get_xlabel() == "current [A]"
    ys = np.sort(np.concatenate([c.get_offsets()[:, 1] for c in ax.collections]))
    np.testing.assert_array_equal(ys, np.sort(result.generations))
    # filled = stopped by the criterion, open = hit the cap (dashed line at the cap)
    filled = [c for c in ax.collections if c.get_facecolor().size]
    assert sum(len(c.get_offsets()) for c in filled) == int(result.stopped_by_criterion.sum())
    assert [ln.get_ydata()[0] for ln in ax.get_lines()] == [20]
    assert "hit the cap" in _texts(fig)
    lm = rp.plot_generations_vs_current(_result(batch, method="lm"))
    assert "no swarm generations" in _texts(lm)


def _law(i):
    return paper_parameters(i)


class _Laws:
    def params_at(self, currents):
        return paper_parameters(np.asarray(currents))


@pytest.mark.parametrize("laws", [None, _law, _Laws()], ids=["none", "callable", "params_at"])
def test_params_vs_current(result, laws):
    fig = rp.plot_params_vs_current(result, laws=laws)
    axes = _visible(fig)
    assert len(axes) == 6
    assert [a.get_title() for a in axes] == list(result.param_names)
    assert axes[0].get_ylabel() == "c [N·s/m]" and axes[4].get_ylabel() == "delta [-]"
    assert all(a.get_xlabel() == "current [A]" for a in axes)
    lo, hi = result.current.min(), result.current.max()
    for p, ax in enumerate(axes):
        # one error-bar series per motion, values = the parameter
        ys = np.sort(np.concatenate([c.lines[0].get_ydata() for c in ax.containers]))
        np.testing.assert_allclose(ys, np.sort(result.theta[:, p]))
        # spread sideways, but never outside the tested currents (no marker below 0 A)
        xs = np.concatenate([c.lines[0].get_xdata() for c in ax.containers])
        assert lo <= xs.min() < xs.max() <= hi and len(set(xs.round(9))) == len(xs)
        curves = [ln for ln in ax.get_lines() if len(ln.get_xdata()) == 200]
        assert len(curves) == (0 if laws is None else 1)
        if curves:
            np.testing.assert_allclose(curves[0].get_ydata()[[0, -1]],
                                       paper_parameters(np.array([0.0, 1.0]))[:, p])
    assert ("fitted law" in _texts(fig)) == (laws is not None)


def test_params_vs_current_bad_laws(result):
    with pytest.raises(ValueError, match="expected"):
        rp.plot_params_vs_current(result, laws=lambda i: np.zeros(3))
    with pytest.raises(TypeError):
        rp.plot_params_vs_current(result, laws=42)


# --------------------------------------------------------------------------------------------
# Diagnostics


def test_convergence(result, batch):
    fig = rp.plot_convergence(result)
    ax = fig.axes[0]
    assert ax.get_yscale() == "log" and ax.get_xlabel() == "generation"
    assert "[N]" in ax.get_ylabel()
    curves = [ln for ln in ax.get_lines() if len(ln.get_xdata()) > 1]
    assert len(curves) == batch.n_conditions
    assert sorted(len(c.get_xdata()) - 1 for c in curves) == sorted(result.generations)
    assert any(a.get_label() == "<colorbar>" for a in fig.axes)
    assert "no swarm history" in _texts(rp.plot_convergence(_result(batch, method="lm")))


def test_pso_vs_polish(result, batch):
    fig = rp.plot_pso_vs_polish(result)
    (ax,) = fig.axes
    assert [t.get_text() for t in ax.get_xticklabels()] == list(batch.labels)
    assert ax.get_ylabel() == "RMS force error [N]"
    ys = [c.get_offsets()[:, 1] for c in ax.collections if len(c.get_offsets()) == 4]
    np.testing.assert_allclose(ys[0], result.pso_rms)
    np.testing.assert_allclose(ys[1], result.rms)
    assert "median reduction 23.1 %" in _texts(fig)
    assert "no swarm result" in _texts(rp.plot_pso_vs_polish(_result(batch, method="lm")))


def test_save_png_bytes_is_png(result):
    png = rp.save_png_bytes(rp.plot_rms_vs_current(result), dpi=50)
    assert png[:8] == PNG_MAGIC
    assert int.from_bytes(png[16:20], "big") > 100  # IHDR width in pixels


# --------------------------------------------------------------------------------------------
# Tables


def test_format_table_plain_and_markdown():
    rows = [["a", 1.23456, 3, None], ["long name", float("nan"), 12, True]]
    plain = rp.format_table(rows, ["name", "x", "n", "ok"])
    lines = plain.splitlines()
    assert lines[0].split() == ["name", "x", "n", "ok"]
    assert set(lines[1]) <= {"-", " "}
    assert lines[2].startswith("a        ") and lines[2].rstrip().endswith("-")
    assert "1.235" in lines[2] and lines[3].split()[2] == "-"  # NaN shown as '-'
    assert lines[2].index(" 3 ") + 2 == lines[3].index("12") + 2  # numbers right-aligned
    md = rp.format_table(rows, ["name", "x", "n", "ok"], style="markdown", floatfmt=".2f")
    assert md.splitlines()[0] == "| name | x | n | ok |"
    assert md.splitlines()[1] == "|---|---:|---:|---|"
    assert md.splitlines()[2] == "| a | 1.23 | 3 | - |"
    assert "| yes |" in md
    per_col = rp.format_table(rows, ["name", "x", "n", "ok"], floatfmt=["", ".1f", "", ""])
    assert per_col.splitlines()[2].split()[:2] == ["a", "1.2"]
    with pytest.raises(ValueError, match="row 0"):
        rp.format_table([[1]], ["a", "b"])
    with pytest.raises(ValueError, match="style"):
        rp.format_table([], ["a"], style="html")


def test_figures_are_not_registered_with_pyplot():
    fig = rp.plot_data_loops(paper_grid(currents=(0.5,), motions=((1.0, 0.004),), cycles=1))
    assert type(fig).__name__ == "Figure"
    assert fig.canvas.manager is None  # no window, no pyplot registry to leak figures into
