"""Tests that stay in their files (issue 28): `mrjax.fit` on a `mrjax.data.Source` that holds
nothing reads and fits them chunk by chunk and gives the result of the same tests held in
memory, bit for bit (same chunks, keys, padded length and swarm-view length)."""

import numpy as np
import pytest
from test_chunks import KWOK_PSO, SMALLEST, assert_identical

import mrjax
import mrjax.fitting._chunks as chunks
from mrjax.data import Source, make_batch, paper_grid, to_frame


@pytest.fixture(scope="module")
def kwok_csv(tmp_path_factory):
    """30 tanh tests of 500 samples, in memory and in a long CSV file."""
    batch = paper_grid(currents=np.linspace(0, 2, 15), motions=((1.0, 0.004), (1.0, 0.008)),
                       cycles=1, sample_rate=500.0)
    path = tmp_path_factory.mktemp("stream") / "fleet.csv"
    to_frame(batch).to_csv(path, index=False)
    return batch, path


def test_streamed_fit_equals_the_fit_in_memory(kwok_csv, monkeypatch):
    batch, path = kwok_csv
    source = Source.scan(path, keep_bytes=0)
    assert not source.kept and source.n_conditions == 30
    monkeypatch.setattr(chunks, "CHECK_BYTES", 20 * source.batch_bytes(1))  # check 5 at a time
    options = dict(KWOK_PSO, chunks=SMALLEST)  # chunks of 12
    reads = []
    take = chunks.Source.batch
    monkeypatch.setattr(chunks.Source, "batch",
                        lambda self, rows=None, **kw: reads.append(len(rows)) or take(self, rows, **kw))
    streamed = mrjax.fit("kwok", source, **options)
    assert_identical(mrjax.fit("kwok", batch, **options), streamed)
    assert max(reads) <= 12  # never more than a chunk of tests at a time


def test_streamed_fit_keeps_the_view_of_the_whole(tmp_path, monkeypatch):
    """Dahl on its swarm view: 8 tests of 1,000 samples, then 16 of 500, checked 4 at a time:
    the later groups alone would have a shorter view than the whole."""
    dahl = mrjax.models.get("dahl")
    theta = np.array([2000.0, 1000.0, 500.0, 300.0, 10.0])
    conds = []
    for f, n in ((1.0, 8), (2.0, 16)):
        conds += paper_grid(dahl, theta, currents=np.linspace(0, 2, n), motions=((f, 0.006),),
                            cycles=1, sample_rate=1000.0, seed=int(f)).conditions()
    batch = make_batch(conds)
    to_frame(batch).to_parquet(tmp_path / "dahl.parquet", index=False)
    source = Source.scan(tmp_path / "dahl.parquet", keep_bytes=0)
    monkeypatch.setattr(chunks, "CHECK_BYTES", 12 * source.batch_bytes(1))
    options = dict(swarm=mrjax.Swarm(n_particles=200, max_generations=6), polish=None, key=3,
                   chunks=SMALLEST)
    assert_identical(mrjax.fit("dahl", batch, **options), mrjax.fit("dahl", source, **options))


def test_streamed_fit_checks_every_test_before_any_work(kwok_csv, tmp_path, monkeypatch):
    _, path = kwok_csv
    lines = path.read_text().splitlines()
    row = lines[-3].split(",")
    row[4] = lines[-4].split(",")[4]  # the last test's time stops increasing
    lines[-3] = ",".join(row)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    fitted = []
    monkeypatch.setattr(chunks, "fit_chunk", lambda *a, **k: fitted.append(1))
    with pytest.raises(mrjax.InputError, match="not strictly increasing"):
        mrjax.fit("kwok", Source.scan(tmp_path / "bad.csv", keep_bytes=0), chunks=SMALLEST,
                  **KWOK_PSO)
    assert not fitted


def test_cli_streams_when_the_budget_cannot_hold_the_tests(kwok_csv, tmp_path, monkeypatch):
    """`mrjax fit` with a budget that cannot hold the tests (here: a hold share of 0) reads
    them chunk by chunk: the same fit.csv as when it holds them; loops of a sample."""
    from helpers import check_pngs, one_error_line, run_cli

    import mrjax.cli._common as common

    _, path = kwok_csv
    argv = ["fit", path, "--model", "kwok", "--method", "pso", "--generations", "3",
            "--particles", "200", "--memory", "3GB", "--chunk-size", "1"]
    code, out, err = run_cli(argv + ["--no-plots", "--out", tmp_path / "held"])
    assert code == 0, err
    monkeypatch.setattr(common, "HOLD_SHARE", 0.0)
    code, out, err = run_cli(argv + ["--out", tmp_path / "streamed"])
    assert code == 0, err
    assert "read from the files chunk by chunk" in err
    held, streamed = (tmp_path / d / "fit.csv" for d in ("held", "streamed"))
    assert streamed.read_bytes() == held.read_bytes()
    check_pngs(tmp_path / "streamed", ["loops.png", "rms_vs_current.png"])
    code, out, err = run_cli(argv + ["--generalize", "two-step", "--out", tmp_path / "g"])
    assert code == 2 and "--generalize needs every test in memory" in one_error_line(err)
    assert not (tmp_path / "g").exists()
