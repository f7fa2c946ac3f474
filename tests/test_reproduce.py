"""`mrjax reproduce --quick`: every file, the summary's structure, the acceptance facts quick
mode supports, determinism, and the `--data` path's data handling.

One quick study runs through the CLI (module fixture, cold compile); a second, in-process
through `mrjax.reproduce.run` with the same seed, reuses the compiled programs and must give
identical numbers.
"""

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from mrjax import cli, reproduce
from mrjax._io import MANIFEST
from mrjax.data import PAPER_COEFFICIENTS, PAPER_CURRENTS

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
REPO = Path(__file__).resolve().parents[1]
FIGURES = {
    "fig03_data_loops.png", "fig07_loops_tanh.png", "fig08_loops_bouc_wen.png",
    "fig09_rms_vs_current.png", "fig10_generations_vs_current.png",
    "fig11_params_vs_current.png", "fig12_generalized_loops.png", "rms_identified.png",
    "pso_vs_polish.png", "convergence_tanh.png", "convergence_bouc_wen.png",
}
QUICK_RUNS = ("kwok_paper_swarm", "bouc_wen_paper_swarm", "kwok_paper_swarm_polished",
              "kwok_separable")
FILES = FIGURES | {"summary.json", "summary.md", "fit.json"} | {f"fits/{k}.json"
                                                                  for k in QUICK_RUNS}
#: Keys whose values legitimately differ between two runs with the same seed.
VOLATILE = ("timings_s", "versions")


def _cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce") / "out"
    code, stdout, stderr = _cli(["reproduce", "--quick", "--out", out])
    assert code == 0, stderr
    return out, stdout, stderr, json.loads((out / "summary.json").read_text())


@pytest.fixture(scope="module")
def again(tmp_path_factory, quick):
    out = tmp_path_factory.mktemp("reproduce2") / "out"
    assert reproduce.run(out, quick=True, seed=0, verbose=False) == 0
    return out, json.loads((out / "summary.json").read_text())


def _files(d: Path) -> set[str]:
    """The study's outputs in `d` (the manifest `mrjax._io.MANIFEST` left out)."""
    return {p.relative_to(d).as_posix() for p in d.rglob("*")
            if p.is_file() and p.name != MANIFEST}


def test_every_file_is_written(quick):
    out, _, _, doc = quick
    assert _files(out) == FILES
    assert set(doc["files"]) == FILES
    for name in FIGURES:
        data = (out / name).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 10_000, name
    assert not list(out.parent.glob(".mrjax-tmp-*"))  # the atomic writer cleaned up


def test_console_progress_and_table(quick):
    _, stdout, stderr, doc = quick
    for title in ("tanh, paper's swarm", "Bouc-Wen, paper's swarm", "separable swarm"):
        assert title in stderr and title in stdout
    assert "(a) tanh lower median RMS" in stdout and "(c) generalized coefficients" in stdout
    assert "c: a1·i" in stdout and "eq 24-29" in stdout
    md = (quick[0] / "summary.md").read_text()
    assert md.startswith("# Kwok et al. (2006) reproduced by mrjax")
    assert "| law coefficient | eq 24-29 |" in md and "### Acceptance" in md
    for name in FIGURES:
        assert f"[{name}]({name})" in md


def test_summary_structure(quick):
    _, _, _, doc = quick
    assert doc["schema"] == reproduce.SUMMARY_SCHEMA and doc["seed"] == 0 and doc["quick"]
    data = doc["data"]
    C = data["n_conditions"]
    assert C == 2 * len(PAPER_CURRENTS) and data["truth"]
    assert sorted(set(data["current_A"])) == list(PAPER_CURRENTS)
    for key in ("labels", "current_A", "frequency_Hz", "amplitude_m", "n_samples"):
        assert len(data[key]) == C
    assert list(doc["runs"]) == list(QUICK_RUNS)
    assert doc["models"] == {"kwok": ["kwok_paper_swarm", "kwok_paper_swarm_polished",
                                      "kwok_separable"],
                             "bouc_wen": ["bouc_wen_paper_swarm"]}
    for key, run in doc["runs"].items():
        assert run["title"] == reproduce.RUN_TITLES[key]
        assert len(run["rms_N"]) == C and all(v > 0 for v in run["rms_N"])
        assert run["median_rms_N"] == pytest.approx(np.median(run["rms_N"]))
        gens = run["generations"]
        assert len(gens) == C and all(isinstance(g, int) and 1 <= g <= 60 for g in gens)
        assert run["median_generations"] == pytest.approx(np.median(gens))
        assert len(run["params"]) == C and len(run["params"][0]) == len(run["param_names"])
    gen = doc["generalized"]
    assert set(gen) == {"two-step", "two-step-equal"}
    for g in gen.values():
        assert set(g["coefficients"]) == set(PAPER_COEFFICIENTS)
        for name, ref in PAPER_COEFFICIENTS.items():
            assert len(g["coefficients"][name]) == len(ref) == len(g["error_pct"][name])
            for c, r, e in zip(g["coefficients"][name], ref, g["error_pct"][name]):
                assert e == pytest.approx(100 * (c - r) / abs(r))
    for stage in ("data", "kwok_paper_swarm", "bouc_wen_paper_swarm", "kwok_separable",
                  "generalize", "run_wall", "run_cpu", "process_cpu"):
        assert doc["timings_s"][stage] >= 0, stage
    assert {"mrjax", "jax", "jaxlib", "numpy", "python", "platform"} <= set(doc["versions"])
    fit = json.loads((quick[0] / "fit.json").read_text())
    assert fit["model"] == "kwok" and fit["generalized"]["method"] == "two-step"


def test_acceptance_facts(quick):
    _, _, _, doc = quick
    acc = doc["acceptance"]
    a, b, c = (acc[k] for k in ("a_tanh_lower_rms", "b_tanh_fewer_generations",
                                "c_coefficients"))
    runs = doc["runs"]
    # (a), (b): the verdicts are those of the numbers (they are not robust, so not asserted)
    assert a["paper_swarm"]["tanh_N"] == runs["kwok_paper_swarm"]["median_rms_N"]
    assert a["paper_swarm"]["bouc_wen_N"] == runs["bouc_wen_paper_swarm"]["median_rms_N"]
    assert a["paper_swarm"]["holds"] == (a["paper_swarm"]["tanh_N"] < a["paper_swarm"]
                                         ["bouc_wen_N"])
    assert a["separable_swarm"] is None  # no Bouc-Wen separable swarm in quick mode
    assert b["tanh_median"] == runs["kwok_paper_swarm"]["median_generations"]
    assert b["bouc_wen_median"] == runs["bouc_wen_paper_swarm"]["median_generations"]
    assert b["holds"] == (b["tanh_median"] < b["bouc_wen_median"])
    assert b["holds_by_mean"] == (b["tanh_mean"] < b["bouc_wen_mean"])
    # the accurate tanh fit reaches the noise level (20 N) and the polish never hurts
    sep = runs["kwok_separable"]
    assert 18.0 < sep["median_rms_N"] < 22.0
    assert all(r <= s + 1e-9 for r, s in zip(sep["rms_N"], sep["swarm_rms_N"]))
    pol = runs["kwok_paper_swarm_polished"]
    assert all(r <= s + 1e-9 for r, s in zip(pol["rms_N"], pol["swarm_rms_N"]))
    # (c): eq 24-29 recovered within 5 % by the two-step laws
    assert c["applicable"] and c["holds"]
    assert c["max_abs_error_pct"] <= reproduce.COEF_TOLERANCE_PCT
    assert doc["generalized"]["two-step"]["total_rms_N"] < 22.0


def _readme_quick_ranges() -> dict[str, tuple[tuple[float, float], tuple[float, float]]]:
    """The table of `mrjax reproduce --quick` numbers in docs/benchmarks/reproduce.md: run
    title -> ((RMS low, high), (generations low, high)); a single number `v` printed with d
    decimals is v +- half its last digit."""
    lines = (REPO / "docs" / "benchmarks" / "reproduce.md").read_text(encoding="utf-8").splitlines()
    start = next(k for k, ln in enumerate(lines) if "reproduce-quick-ranges" in ln)

    def span(cell: str) -> tuple[float, float]:
        lo, _, hi = cell.strip().replace("–", "-").partition("-")
        if hi:
            return float(lo), float(hi)
        half = 0.5 * 10.0 ** -len(lo.partition(".")[2])
        return float(lo) - half, float(lo) + half

    out = {}
    for ln in lines[start + 3:]:
        if not ln.startswith("|"):
            break
        title, rms, gens = (c.strip() for c in ln.strip("|").split("|"))
        out[title] = (span(rms), span(gens))
    return out


def test_readme_quick_numbers_hold(quick):
    """The numbers docs/benchmarks/reproduce.md states for `mrjax reproduce --quick` (ranges
    that hold on any CPU; a single number to its printed digits) are what this run gives."""
    _, _, _, doc = quick
    ranges = _readme_quick_ranges()
    assert set(ranges) == {reproduce.RUN_TITLES[k] for k in QUICK_RUNS}
    for key in QUICK_RUNS:
        run = doc["runs"][key]
        (rlo, rhi), (glo, ghi) = ranges[run["title"]]
        assert rlo <= run["median_rms_N"] <= rhi, (key, run["median_rms_N"], (rlo, rhi))
        assert glo <= run["median_generations"] <= ghi, (key, run["median_generations"])
    readme = (REPO / "docs" / "benchmarks" / "reproduce.md").read_text(encoding="utf-8")
    worst = doc["acceptance"]["c_coefficients"]["max_abs_error_pct"]
    assert f"within {worst:.2f} % (quick)" in readme, worst


def test_same_seed_same_numbers(quick, again):
    out1, _, _, doc1 = quick
    out2, doc2 = again
    for k in VOLATILE:
        doc1, doc2 = dict(doc1), dict(doc2)
        doc1.pop(k), doc2.pop(k)
    assert doc1 == doc2
    assert (out1 / "fit.json").read_bytes() == (out2 / "fit.json").read_bytes()
    for k in QUICK_RUNS:
        assert (out1 / f"fits/{k}.json").read_bytes() == (out2 / f"fits/{k}.json").read_bytes()


def test_cli_default_output_directory():
    args = cli.build_parser().parse_args(["reproduce"])
    assert args.out == "mrjax-out/reproduce" and args.seed == 0 and not args.quick and args.data is None


def test_missing_data_directory_fails_before_any_work(tmp_path):
    code, out, err = _cli(["reproduce", "--quick", "--data", tmp_path / "nope", "--out",
                           tmp_path / "o"])
    assert code == 2 and "nope" in err and "no such file" in err
    assert not (tmp_path / "o").exists()


def test_data_directory_is_trimmed_to_last_cycles(utfsm, tmp_path):
    """The `--data` path's loading (no fitting): records cut to their last cycles, the
    Figs 7-8 motions fall back to the slowest and fastest ones, quick keeps those two."""
    names = ["10mm1Hz0A.txt", "10mm1Hz0x5A.txt", "2mm5Hz0A.txt", "2mm5Hz0x5A.txt",
             "25mm0x1Hz0A.txt"]
    for n in names:
        (tmp_path / n).symlink_to(utfsm / n)
    batch, info = reproduce.load_study_data(tmp_path)
    assert batch.n_conditions == len(names) and not info["truth"]
    assert "10mm1Hz0A" in info["trimmed"]
    for i in range(batch.n_conditions):
        c = batch.condition(i)
        span = c.t[-1] - c.t[0]
        assert span <= reproduce.DATA_CYCLES / c.frequency + 1e-9
    assert reproduce.figure_motions(batch) == [(0.1, 0.025), (5.0, 0.002)]
    small, _ = reproduce.load_study_data(tmp_path, quick=True)
    assert sorted(small.labels) == ["25mm0x1Hz0A", "2mm5Hz0A", "2mm5Hz0x5A"]
