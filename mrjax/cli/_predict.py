"""`mrjax predict`: evaluate fitted current-dependent laws on other tests."""

from __future__ import annotations

import argparse
from types import SimpleNamespace

import numpy as np

from .. import __version__
from .._errors import InputError
from .._io import OutputDir, csv_cell, json_bytes, json_safe
from .._tables import format_table
from ..data import ESTIMATED_FIELDS
from ..generalize import GeneralizedModel
from ._common import (
    data_spec,
    force_figures,
    load_batch,
    read_fit_json,
    say_estimates,
    use_agg,
)
from ._parse import say
from ._posterior import run_band

_GEN_HINT = "run `mrjax fit DATA... --model NAME --generalize two-step` first"


def _rows(batch, rms, nrmse) -> list[dict]:
    cur, freq, amp = (np.asarray(getattr(batch, k), float) for k in
                      ("current", "frequency", "amplitude"))
    n = np.asarray(batch.n_samples)
    est = np.asarray(batch.estimated, bool)
    return [json_safe({"label": batch.labels[i], "current_A": cur[i], "frequency_Hz": freq[i],
                       "amplitude_m": amp[i], "n_samples": int(n[i]), "rms_N": rms[i],
                       "nrmse": nrmse[i],
                       "estimated": [k for k, e in zip(ESTIMATED_FIELDS, est[i]) if e]})
            for i in range(batch.n_conditions)]


def _csv(rows: list[dict]) -> str:
    cols = [c for c in rows[0] if c != "estimated"]
    lines = [",".join(cols)]
    lines += [",".join(csv_cell(np.nan if r[c] is None else r[c]) for c in cols) for r in rows]
    return "\n".join(lines) + "\n"


#: The columns of `predicted.csv`, one row per sample of every record.
SAMPLE_COLUMNS = ("condition", "time_s", "displacement_m", "velocity_m_s", "current", "measured",
                  "predicted")


def _commands(batch) -> np.ndarray:
    """The command (C, T) each sample sees: its per-sample command where the record has one,
    else the record's current [A]."""
    kind = np.asarray(batch.command_kind)
    cur = np.broadcast_to(np.asarray(batch.current, float)[:, None], np.shape(batch.x))
    return np.where(kind[:, None] > 0, np.asarray(batch.command, float), cur)


def _samples_csv(batch, predicted: np.ndarray) -> bytes:
    """`predicted.csv`: every real sample of every record (`SAMPLE_COLUMNS`), floats round-trip
    exact (repr), so that a check against another implementation sees mrjax's numbers."""
    cols = [np.asarray(a, float) for a in (batch.t, batch.x, batch.xdot, _commands(batch),
                                            batch.force, predicted)]
    real = np.asarray(batch.mask, bool)
    lines = [",".join(SAMPLE_COLUMNS)]
    for i, keep in enumerate(real):
        label = csv_cell(batch.labels[i])
        cells = [[csv_cell(v) for v in c[i, keep].tolist()] for c in cols]
        lines += [",".join((label, *row)) for row in zip(*cells)]
    return ("\n".join(lines) + "\n").encode()


def _table(rows: list[dict], model: str) -> str:
    def num(v, scale=1.0):
        return None if v is None else v * scale

    body = [[r["label"], num(r["current_A"]), num(r["frequency_Hz"]), num(r["amplitude_m"], 1e3),
             num(r["rms_N"]), num(r["nrmse"], 100.0)] for r in rows]
    table = format_table(body, ["condition", "I[A]", "f[Hz]", "A[mm]", "RMS[N]", "NRMSE%"],
                         floatfmt=["", ".3g", ".3g", ".3g", ".2f", ".2f"])
    rms = np.array([np.nan if r["rms_N"] is None else r["rms_N"] for r in rows])
    med = np.nanmedian(rms) if np.any(np.isfinite(rms)) else float("nan")
    return table + f"\ngeneralized {model}: {len(rows)} conditions, median RMS {med:.2f} N"


def _read_model(path: str, model: str | None = None) -> tuple[GeneralizedModel, str]:
    doc = read_fit_json(path)
    if "generalized" not in doc:
        raise InputError(f"{path}: this fit has no current-dependent laws ('generalized' "
                         f"block); {_GEN_HINT}")
    try:
        block = dict(doc["generalized"])
        block.setdefault("model_source", doc.get("model_source"))
        gm = GeneralizedModel.from_dict(block, model=model)
    except InputError as e:
        raise InputError(f"{path}: {e}") from None
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{path}: cannot read the 'generalized' block ({e!r})") from None
    return gm, str(doc.get("model", "model"))


def run(args: argparse.Namespace, out: OutputDir) -> int:
    """Run `mrjax predict` with parsed arguments into the claimed directory `out`; returns the
    exit code."""
    if args.band is not None:  # the posterior predictive band of a per-test fit
        return run_band(args, out)
    from ._structure import is_structure_fit, run_predict

    structure, doc = is_structure_fit(args.fit)
    if structure:  # a structure's fit (`mrjax fit --structure`)
        return run_predict(args, out, doc)
    gm, model = _read_model(args.fit, args.model)
    spec = data_spec(args)
    batch = load_batch(args.files, spec)
    say_estimates(batch)
    C = batch.n_conditions
    say(f"predicting {C} condition{'s' if C != 1 else ''} with the generalized {model}...")
    ev = gm.evaluate(batch)
    rms, nrmse = np.asarray(ev["rms"], float), np.asarray(ev["nrmse"], float)
    rows = _rows(batch, rms, nrmse)
    used = gm.resolved_model(_commands(batch), batch.xdot, batch.dt, batch.mask)
    report = {"fit": str(args.fit), "model": model, "mrjax_version": __version__,
              "median_rms_N": float(np.nanmedian(rms)) if np.any(np.isfinite(rms)) else None,
              "integration": {"scheme": used.scheme, "substeps": used.substeps}
              if used.dynamic else None,
              "conditions": rows}
    files = {"predict.json": json_bytes(report), "predict.csv": _csv(rows).encode(),
             "predicted.csv": _samples_csv(batch, np.asarray(ev["predicted"], float))}
    if not args.no_plots:
        say("drawing figures...")
        use_agg()
        from .. import report as rp  # imported here: matplotlib only when figures are drawn

        files.update(force_figures(
            gm, batch, np.asarray(ev["predicted"], float), rms, prefix="predict_",
            titles=(f"generalized {model}: measured vs predicted loops",
                    f"generalized {model}: measured vs predicted force")))
        pts = SimpleNamespace(current=batch.current, frequency=batch.frequency,
                              amplitude=batch.amplitude, rms=rms, labels=batch.labels)
        files["predict_rms_vs_current.png"] = rp.save_png_bytes(
            rp.plot_rms_vs_current({f"generalized {model}": pts}))
    say(f"writing {len(files)} files to {out.path}...")
    out.write(files)
    print(_table(rows, model))
    return 0
