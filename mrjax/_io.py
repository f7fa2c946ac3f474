"""Output files: atomic directories (all files or none), one command's outputs per directory
(:class:`OutputDir`: ownership, a lock, a manifest) and the one JSON writer of mrjax.

NumPy is imported by the functions that need it, so that the command line can claim its
output directory before anything heavy is imported.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

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


# --------------------------------------------------------------------------------------------
# One command's outputs per directory

#: The manifest of an output directory: which command wrote which files (written last, with
#: them, atomically).
MANIFEST = ".mrjax-outputs.json"
#: Entries of an output directory that are mrjax's own bookkeeping, never foreign files: the
#: manifest, the journal of an interrupted `mrjax fit` and a crashed writer's temporary folder.
_OWN_PREFIXES = (MANIFEST, ".mrjax-journal", ".mrjax-tmp-", ".mrjax-probe-", ".mrjax-lock")


def _read_manifest(out: Path) -> dict | None:
    """The manifest of `out` as a dict, or None when there is none (or it is unreadable)."""
    try:
        doc = json.loads((out / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not (isinstance(doc, dict) and isinstance(doc.get("command"), str)
            and isinstance(doc.get("files"), list)):
        return None
    return doc


class OutputDir:
    """The output directory of one `mrjax` command: it holds that command's outputs only.

    Use as a context manager around the command (`with OutputDir(path, "fit") as out: ...;
    out.write(files)`). On entry, before any work:

    - a directory written by another command (its manifest `.mrjax-outputs.json` says which),
      or holding files mrjax did not write, is refused with one line (:class:`mrjax.InputError`)
      unless `overwrite`; a directory this command wrote before is reused;
    - an exclusive lock (`fcntl.flock` on the hidden file `.NAME.mrjax-lock` beside the
      directory) is taken: a second command writing into the same directory at the same time
      is refused at once with one line, and the first is untouched.

    :meth:`write` writes the files atomically (:func:`atomic_output`) with the manifest, then
    removes the files of this directory's previous run that the new set does not replace (a
    figure that is no longer drawn), so that every file present belongs to the last run. Files
    mrjax did not write are never deleted. On exit the lock is released; a directory created
    here and left empty (a failed run) is removed.

    **Arguments:** `path` the directory; `command` the command's name (`fit`, `predict`, ...);
    `overwrite` write into a directory of another command or with foreign files anyway (the
    other command's listed outputs are then removed, foreign files kept).
    """

    def __init__(self, path: str | os.PathLike, command: str, *, overwrite: bool = False):
        self.path = Path(path)
        self.command = str(command)
        self.overwrite = bool(overwrite)
        self._lock_fd: int | None = None
        full = Path(os.path.abspath(self.path))
        self._lock_path = full.parent / f".{full.name}.mrjax-lock"
        self._created: list[Path] = []
        self._previous: list[str] = []

    # -- entry: ownership, then the lock
    def __enter__(self) -> OutputDir:
        out = check_writable(self.path)
        previous = self._check_owner(out)
        self._make_parents()
        self._lock()
        try:  # the owner may have changed while we waited for nothing: check again, locked
            self._previous = self._check_owner(out) if out.exists() else previous
        except BaseException:
            self._unlock()
            raise
        return self

    def _check_owner(self, out: Path) -> list[str]:
        """Refuse a directory of another command or with foreign files (unless `overwrite`);
        returns the files the manifest lists (to remove once replaced)."""
        if not out.is_dir():
            return []
        doc = _read_manifest(out)
        listed = [str(f) for f in doc["files"]] if doc else []
        tops = {f.split("/", 1)[0] for f in listed}
        foreign = sorted(p.name for p in out.iterdir()
                         if p.name not in tops and not p.name.startswith(_OWN_PREFIXES))
        if self.overwrite:
            return listed
        where = f"output directory {str(out)!r}"
        fix = "choose another --out (or add --overwrite)"
        if doc is not None and doc["command"] != self.command:
            raise InputError(f"{where} holds the outputs of `mrjax {doc['command']}`, not of "
                             f"`mrjax {self.command}`: {fix}")
        if foreign:
            more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
            raise InputError(f"{where} holds files that `mrjax {self.command}` did not write "
                             f"({foreign[0]!r}{more}): {fix}")
        return listed

    def _make_parents(self) -> None:
        missing = []
        p = self.path.absolute().parent
        while not p.exists():
            missing.append(p)
            p = p.parent
        for p in reversed(missing):
            try:
                p.mkdir()
            except FileExistsError:
                continue
            except OSError as e:
                raise InputError(f"output directory {str(self.path)!r} cannot be created: "
                                 f"{e.strerror}") from None
            self._created.append(p)

    def _lock(self) -> None:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: no lock
            return
        while True:
            try:
                fd = os.open(self._lock_path, os.O_RDWR | os.O_CREAT, 0o644)
            except PermissionError:
                if not self.path.is_dir() or self._lock_path.parent == self.path:
                    raise InputError(f"output directory {str(self.path)!r}: cannot create its "
                                     "lock file beside it or in it") from None
                self._lock_path = self.path / ".mrjax-lock"  # its parent is read-only
                continue
            except OSError as e:
                raise InputError(f"output directory {str(self.path)!r}: cannot create its lock "
                                 f"file: {e.strerror}") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                holder = os.read(fd, 200).decode("utf-8", "replace").strip()
                os.close(fd)
                who = f" ({holder})" if holder else ""
                raise InputError(f"output directory {str(self.path)!r} is being written by "
                                 f"another mrjax command{who}: wait for it to finish or choose "
                                 "another --out") from None
            try:  # the file we locked may have been removed by a finishing owner: retry
                same = os.fstat(fd).st_ino == os.stat(self._lock_path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"mrjax {self.command}, pid {os.getpid()}, since "
                     f"{time.strftime('%H:%M:%S')}".encode())
        self._lock_fd = fd

    # -- the outputs
    def write(self, files: Mapping[str, bytes]) -> Path:
        """Write `files` (name -> bytes; names may hold `/`) atomically with the manifest, then
        remove the previous run's files that were not replaced.

        **Returns:** the directory.
        """
        doc = {"command": self.command, "files": sorted(files)}
        out = atomic_output(self.path, {**files, MANIFEST: (json.dumps(doc, indent=1) + "\n")
                                        .encode()})
        for name in set(self._previous) - set(files):
            stale = out / name
            try:
                if stale.is_file() and stale.resolve().is_relative_to(out.resolve()):
                    stale.unlink()
                    for d in stale.relative_to(out).parents:  # empty folders it leaves
                        if d != Path(".") and not any((out / d).iterdir()):
                            (out / d).rmdir()
            except OSError:  # best effort: the manifest already says what is current
                pass
        self._previous = sorted(files)
        return out

    # -- exit
    def _unlock(self) -> None:
        if self._lock_fd is None:
            return
        try:
            os.unlink(self._lock_path)
        except OSError:
            pass
        os.close(self._lock_fd)  # closing releases the lock
        self._lock_fd = None

    def __exit__(self, *exc) -> None:
        self._unlock()
        for d in reversed(self._created):  # parents made for a run that wrote nothing
            try:
                d.rmdir()
            except OSError:  # not empty: in use
                break


def _plain(obj, array, nonfinite):
    """`obj` as plain JSON values: mapping keys to `str`, tuples and lists to lists, NumPy
    scalars to Python; a NumPy array through `array(a)`, a non-finite float through
    `nonfinite(v)`."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): _plain(v, array, nonfinite) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v, array, nonfinite) for v in obj]
    if isinstance(obj, np.ndarray):
        return array(obj)
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else nonfinite(v)
    return obj


def json_safe(obj):
    """Plain JSON values: NumPy scalars and arrays to Python, NaN and inf to `None` (JSON has
    no NaN), tuples to lists, mapping keys to `str`. The one NaN -> null rule of every mrjax
    JSON file."""
    return _plain(obj, lambda a: [json_safe(v) for v in a], lambda v: None)


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
    lists. For state that must round-trip bit for bit (the journal of a chunked fit); reports
    use :func:`json_safe` (NaN -> null)."""
    return _plain(obj, _array_record, lambda v: {_FLOAT: repr(v)})


def _array_record(a) -> dict:
    """A NumPy array as :func:`exact_encode` writes it."""
    flat = a.ravel().tolist()
    if a.dtype.kind == "f":
        flat = [v if math.isfinite(v) else repr(v) for v in flat]
    return {_ARRAY: a.dtype.str, "shape": list(a.shape), "data": flat}


def exact_decode(obj):
    """Inverse of :func:`exact_encode` (lists stay lists)."""
    import numpy as np

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
    import numpy as np  # imported here: `mrjax._io` stays light for the command line

    if isinstance(v, str):
        return '"' + v.replace('"', '""') + '"' if ("," in v or '"' in v) else v
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    v = float(v)
    return "" if not math.isfinite(v) else repr(v)
