"""Bad input, tried widely: many more mutated files and specs than the test suite runs.

    python -m benchmarks.fuzz_input [--examples 2000] [--seed 0]

Every case (the strategies of `tests/fuzzing.py`: mutated long CSV, UTFSM text, Parquet and
Feather files, spec option strings, mutated spec files) must end in a result or one
`InputError` line; for the CSV cases the fast reader must also read the file as the exact one
does. Prints, per target, the cases run and how many ended in a result and in an error, and
the failures (with the case) if any; writes `benchmarks/fuzz_input.json`. Exit code 1 on any
failure.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=2000, help="cases per target")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", default="", help="run the targets whose name contains this")
    ap.add_argument("--keep", type=Path, default=Path(tempfile.gettempdir()) / "mrjax-fuzz-failed",
                    help="folder where each failing case is written whole (default %(default)s)")
    a = ap.parse_args(argv)

    import fuzzing as fz
    from hypothesis import seed as hseed
    from hypothesis import strategies as st

    import mrjax.data as md
    from mrjax._errors import InputError
    from mrjax.data._csv import read_csv

    tmp = Path(tempfile.mkdtemp(prefix="mrjax-fuzz-"))
    spec = md.DataSpec.from_options(
        columns="time=time_s:s,displacement=displacement_m:m,force=force_N:N,"
                "condition=condition", velocity_window=0.02)
    frame = md.to_frame(md.load(_write(tmp, "v.csv", fz.valid_csv())))
    frame.to_parquet(tmp / "v.parquet", index=False)
    frame.to_feather(tmp / "v.feather")
    columnar_ops = st.sampled_from([fz._truncate, fz._random, fz._insert, fz._delete,
                                    fz._bom_nul])

    def csv_case(data):
        p = _write(tmp, "f.csv", data)
        out = [fz.ends_well(lambda: md.load(p)), fz.ends_well(lambda: md.load(p, spec=spec))]
        for strict, columns in ((True, None), (False, dict(spec.columns))):
            r = [_summary(lambda e=e: read_csv(p, columns=columns, strict=strict,
                                                 block_bytes=97, exact=e), InputError)
                 for e in (False, True)]
            assert r[0] == r[1], "the fast CSV reader disagrees with the exact one"
        return out[0]

    def txt_case(data):
        p = _write(tmp, "8mm1Hz0x5A.txt", data)
        return fz.ends_well(lambda: md.load(p))

    def columnar_case(suffix):
        base = (tmp / f"v{suffix}").read_bytes()

        def case(draw):
            p = _write(tmp, f"f{suffix}", draw(columnar_ops)(draw, base))
            return fz.ends_well(lambda: md.load(p))
        return case

    def toml_case(data):
        p = _write(tmp, "s.toml", data)
        return fz.ends_well(lambda: md.DataSpec.from_toml(p))

    targets = {
        "long CSV (loader, spec, fast = exact)": (fz.mutated(fz.valid_csv()), csv_case),
        "UTFSM text": (fz.mutated(fz.valid_txt()), txt_case),
        "Parquet": (st.data(), lambda d: columnar_case(".parquet")(d.draw)),
        "Feather": (st.data(), lambda d: columnar_case(".feather")(d.draw)),
        "spec options": (fz.option_sets(),
                         lambda o: fz.ends_well(lambda: md.DataSpec.from_options(**o))),
        "spec file (TOML)": (fz.mutated(fz.VALID_TOML), toml_case),
    }
    report, failed = {}, 0
    for k, (name, (strategy, case)) in enumerate(targets.items()):
        if a.only not in name:
            continue
        counts = {"ok": 0, "error": 0, "failed": 0}
        failures: list[dict] = []
        t0 = time.perf_counter()

        run = _runner(strategy, case, counts, failures, a.examples, a.keep / f"target{k}")
        hseed(a.seed + k)(run)()
        n = sum(counts.values())
        report[name] = {**counts, "cases": n, "seconds": round(time.perf_counter() - t0, 1),
                        "failures": failures}
        failed += counts["failed"]
        print(f"{name}: {n} cases, {counts['ok']} results, {counts['error']} one-line "
              f"errors, {counts['failed']} failures ({report[name]['seconds']} s)", flush=True)
        for f in failures:
            print(f["case"][:300], "\n", f["traceback"], file=sys.stderr)
    total = sum(r["cases"] for r in report.values())
    print(f"total: {total} cases, {failed} failures")
    (HERE / "fuzz_input.json").write_text(json.dumps(
        {"examples_per_target": a.examples, "seed": a.seed, "total": total,
         "targets": report}, indent=1) + "\n")
    return 1 if failed else 0


def _runner(strategy, case, counts: dict, failures: list, examples: int, keep: Path):
    """A hypothesis test that runs `case` on `examples` values of `strategy`, counting the
    outcomes and keeping the first failures (without stopping; bytes cases written to
    `keep`)."""
    from hypothesis import HealthCheck, Phase, given, settings

    @settings(max_examples=examples, database=None, deadline=None,
              suppress_health_check=list(HealthCheck), phases=[Phase.generate])
    @given(strategy)
    def run(value):
        try:
            counts[case(value)] += 1
        except Exception:  # a traceback: the failure this script looks for
            counts["failed"] += 1
            if isinstance(value, bytes):
                keep.mkdir(parents=True, exist_ok=True)
                (keep / f"case{counts['failed']}.bin").write_bytes(value)
            if len(failures) < 5:
                failures.append({"case": repr(value)[:2000],
                                 "traceback": traceback.format_exc()[-2000:]})
    return run


def _write(tmp: Path, name: str, data: bytes) -> Path:
    p = tmp / name
    p.write_bytes(data)
    return p


def _summary(fn, error_type):
    try:
        r = fn()
    except error_type as e:
        return ("error", str(e))
    import numpy as np

    vals = []
    for c, v in sorted(r.values.items(), key=lambda kv: str(kv[0])):
        vals.append((str(c), tuple(v.names[k] for k in v.codes) if hasattr(v, "names")
                     else np.asarray(v, float).tobytes()))
    return (r.n, tuple(r.notes), tuple(vals), tuple(r.lines.line(i) for i in range(r.n)))


if __name__ == "__main__":
    sys.exit(main())
