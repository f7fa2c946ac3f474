"""Output files: atomic directories (all files or none) and the one JSON writer of mrjax."""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from ._errors import InputError


def check_writable(out_dir: str | os.PathLike) -> Path:
    """Fail early, before any work, if `out_dir` cannot be created or written.

    Raises :class:`mrjax.InputError` naming the directory.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"output path {str(out)!r} exists and is not a directory")
    parent = out if out.exists() else _existing_parent(out)
    if not parent.is_dir():
        raise InputError(f"output directory {str(out)!r} cannot be created: {str(parent)!r} is "
                         f"not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"output directory {str(out)!r} is not writable ({str(parent)!r})")
    try:
        fd, probe = tempfile.mkstemp(prefix=".mrjax-probe-", dir=parent)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise InputError(f"output directory {str(out)!r} is not writable: {e.strerror}") from None
    return out


def _existing_parent(p: Path) -> Path:
    p = p.absolute()
    while not p.exists():
        p = p.parent
    return p


def atomic_output(out_dir: str | os.PathLike, files: dict[str, bytes]) -> Path:
    """Write `files` (name -> bytes) into `out_dir` so that no partial set is ever visible.

    All files are first written into a temporary directory beside `out_dir` (same file
    system). A new `out_dir` is then created by one atomic rename; into an existing one each
    file is moved with an atomic `os.replace`, so a reader never sees a half-written file and
    a failure before the move leaves the directory exactly as it was.
    """
    out = check_writable(out_dir)
    parent = out.parent if not out.exists() else out
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".mrjax-tmp-", dir=parent))
    try:
        for name, data in files.items():
            target = tmp / name
            target.parent.mkdir(parents=True, exist_ok=True)
            with open(target, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
        if not out.exists():
            os.replace(tmp, out)
            return out
        for name in files:
            dest = out / name
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp / name, dest)
        return out
    except OSError as e:
        raise InputError(f"could not write output directory {str(out)!r}: {e.strerror}") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def json_safe(obj):
    """Plain JSON values: NumPy scalars and arrays to Python, NaN and inf to `None` (JSON has
    no NaN), tuples to lists, mapping keys to `str`. The one NaN -> null rule of every mrjax
    JSON file."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


def _dumps(o, indent: int = 0) -> str:
    pad, inner = " " * indent, " " * (indent + 1)
    if isinstance(o, dict):
        if not o:
            return "{}"
        items = [f"{inner}{json.dumps(k)}: {_dumps(v, indent + 1)}" for k, v in o.items()]
        return "{\n" + ",\n".join(items) + f"\n{pad}}}"
    if isinstance(o, list) and any(isinstance(v, (dict, list)) for v in o):
        if all(isinstance(v, list) and not any(isinstance(w, (dict, list)) for w in v)
               for v in o):
            rows = [f"{inner}{json.dumps(v, allow_nan=False)}" for v in o]
        else:
            rows = [f"{inner}{_dumps(v, indent + 1)}" for v in o]
        return "[\n" + ",\n".join(rows) + f"\n{pad}]"
    return json.dumps(o, allow_nan=False)


def json_bytes(doc) -> bytes:
    """A report document as UTF-8 JSON text: :func:`json_safe` values, one key per line, lists
    of plain values kept on one line, a final newline (summary.json, predict.json, ...)."""
    return (_dumps(json_safe(doc)) + "\n").encode()


#: Tags of an array and of a non-finite float in :func:`exact_encode`'s JSON.
_ARRAY, _FLOAT = "__ndarray__", "__float__"


def exact_encode(obj):
    """Plain JSON values that decode (:func:`exact_decode`) to exactly the same data: NumPy
    arrays as `{"__ndarray__": dtype, "shape": [...], "data": [flat values]}`, floats by `repr`
    (the shortest text that reads back to the same float), a non-finite float as
    `{"__float__": "nan"|"inf"|"-inf"}` (in a float array: the bare string); tuples become
    lists. For state that must round-trip bit for bit
    (the journal of a chunked fit); reports use :func:`json_safe` (NaN -> null)."""
    if isinstance(obj, dict):
        return {str(k): exact_encode(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [exact_encode(v) for v in obj]
    if isinstance(obj, np.ndarray):
        flat = obj.ravel().tolist()
        if obj.dtype.kind == "f":
            flat = [v if math.isfinite(v) else repr(v) for v in flat]
        return {_ARRAY: obj.dtype.str, "shape": list(obj.shape), "data": flat}
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else {_FLOAT: repr(v)}
    return obj


def exact_decode(obj):
    """Inverse of :func:`exact_encode` (lists stay lists)."""
    if isinstance(obj, dict):
        if _ARRAY in obj:
            dtype = np.dtype(obj[_ARRAY])
            data = obj["data"]
            if dtype.kind == "f":
                data = [float(v) for v in data]
            return np.asarray(data, dtype=dtype).reshape(obj["shape"])
        if _FLOAT in obj:
            return float(obj[_FLOAT])
        return {k: exact_decode(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [exact_decode(v) for v in obj]
    return obj


def csv_cell(v: Any) -> str:
    """One CSV cell: strings quoted when needed, booleans `true`/`false`, integers as such,
    floats by `repr` (round-trip exact), NaN/inf empty."""
    if isinstance(v, str):
        return '"' + v.replace('"', '""') + '"' if ("," in v or '"' in v) else v
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    v = float(v)
    return "" if not math.isfinite(v) else repr(v)
