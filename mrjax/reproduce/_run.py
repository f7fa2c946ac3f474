"""`run`: compute the study, draw its figures, summarize it and write every file at once."""

from __future__ import annotations

import os
import time
from pathlib import Path

from .._errors import InputError
from .._io import OutputDir, json_bytes
from ._figures import draw_figures
from ._render import markdown, reading_notes, tables
from ._study import StageLog, Study, compute, headline_generalized
from ._summary import summarize


def _process_times() -> dict[str, float | None]:
    """CPU time of this process so far (all threads) and its age [s] where known."""
    out: dict[str, float | None] = {"process_cpu_s": time.process_time(), "process_wall_s": None}
    try:
        import psutil  # optional: only the process age needs it

        out["process_wall_s"] = time.time() - psutil.Process().create_time()
    except Exception:  # psutil is optional
        pass
    return out


def _fit_files(study: Study) -> dict[str, bytes]:
    """`fit.json` (the accurate tanh fit with its headline generalized laws, readable by
    `mrjax predict --fit`) and `fits/<run>.json` for every run."""
    key = headline_generalized(study)
    gm = study.generalized[key] if key is not None else None
    files = {"fit.json": study.runs["kwok_separable"].to_json(generalized=gm).encode()}
    for k, r in study.runs.items():
        files[f"fits/{k}.json"] = r.to_json().encode()
    return files


def run(
    out: str | os.PathLike | OutputDir = "mrjax-out/reproduce",
    *,
    quick: bool = False,
    data: str | os.PathLike | None = None,
    seed: int = 0,
    verbose: bool = True,
    overwrite: bool = False,
) -> int:
    """Reproduce the study of Kwok et al. (2006) and write its figures and summary.

    **Arguments:**

    - `out`: output directory (created), or one claimed by the caller (`mrjax._io.OutputDir`).
        It holds the study's outputs only: a directory of another command, or with files mrjax
        did not write, is refused unless `overwrite`, and a second study writing into it at
        the same time is refused. All files are built in memory and written at the end,
        atomically; those of a previous study that are not replaced are removed.
    - `quick`: the reduced version (two motions, swarms capped at `QUICK_GENERATIONS`, no
        Bouc-Wen separable swarm).
    - `data`: a directory of measured tests (see `mrjax.data.load`), or None for the embedded
        Table 1 grid.
    - `seed`: seed of every swarm (the same seed gives the same numbers).
    - `verbose`: print stage progress on stderr and the summary tables on stdout.
    - `overwrite`: see `out`.

    **Returns:** 0. Raises :class:`mrjax.InputError` for unusable data or output directory.
    """
    if not isinstance(out, OutputDir):
        with OutputDir(out, "reproduce", overwrite=overwrite) as claimed:
            return run(claimed, quick=quick, data=data, seed=seed, verbose=verbose)
    log = StageLog(verbose)
    cpu0 = time.process_time()
    outp = out.path
    if data is not None and not Path(data).exists():
        raise InputError(f"{data}: no such file or directory")
    files: dict[str, bytes] = {}

    def figures(study: Study, final: bool) -> None:
        t = time.perf_counter()
        drawn = draw_figures(study, files, final=final)
        key = "figures_final" if final else "figures_early"
        log.timings[key] = log.timings.get(key, 0.0) + time.perf_counter() - t
        if drawn:
            log.say(f"drew {len(drawn)} figure{'s' if len(drawn) != 1 else ''}")

    study = compute(data, quick=quick, seed=seed, log=log, on_progress=figures)
    files.update(_fit_files(study))

    names = sorted(files) + ["summary.json", "summary.md"]
    log.timings["run_wall"] = time.perf_counter() - log.t0
    proc = _process_times()
    log.timings["run_cpu"] = time.process_time() - cpu0
    log.timings["process_cpu"] = proc["process_cpu_s"]
    if proc["process_wall_s"] is not None:
        log.timings["process_wall"] = proc["process_wall_s"]
    doc = summarize(study, names)
    files["summary.json"] = json_bytes(doc)
    files["summary.md"] = markdown(doc).encode()
    log.say(f"writing {len(files)} files to {outp}...")
    out.write(files)
    if verbose:
        print(tables(doc))
        print()
        print("\n".join(reading_notes(doc)))
        print(f"\nmrjax reproduce: {len(files)} files in {outp} "
              f"({log.timings['run_wall']:.1f} s wall, {proc['process_cpu_s']:.1f} s CPU in this "
              "process)")
    return 0
