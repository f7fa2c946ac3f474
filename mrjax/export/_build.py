"""Compiling an export with the machine's C compiler, and calling it from Python (ctypes)."""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from jaxtyping import ArrayLike

from .._errors import InputError

#: The flags every export compiles with: C99, every warning an error.
CFLAGS: tuple[str, ...] = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-O2")


def compile_shared(sources: Mapping[str, bytes], output: str | os.PathLike, *,
                   include: Sequence[str | os.PathLike] = (), compiler: str = "gcc",
                   flags: Sequence[str] = CFLAGS) -> Path:
    """Compile C `sources` (file name -> text; headers among them are found) into the shared
    library `output`, with `flags` (default :data:`CFLAGS`), `-fPIC -shared` and `-lm`.

    **Returns:** the library's path. Raises :class:`mrjax.InputError` when the compiler is
    missing or reports anything (its first line of output).
    """
    exe = shutil.which(compiler)
    if exe is None:
        raise InputError(f"the C compiler {compiler!r} is not on PATH (needed to build the "
                         f"library)")
    out = Path(output).absolute()
    with tempfile.TemporaryDirectory(prefix="mrjax-cc-") as tmp:
        for name, data in sources.items():
            (Path(tmp) / name).write_bytes(data)
        units = [str(Path(tmp) / n) for n in sources if n.endswith(".c")]
        cmd = [exe, *flags, "-fPIC", "-shared", f"-I{tmp}",
               *(f"-I{Path(i).absolute()}" for i in include), *units, "-o", str(out), "-lm"]
        run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0 or run.stderr.strip():
        first = (run.stderr.strip() or run.stdout.strip() or "failed").splitlines()[0]
        raise InputError(f"{compiler} could not compile the export: {first}")
    return out


class CLibrary:
    """A compiled C export called through ctypes: the C functions one sample at a time, and a
    record at once (for checks and examples; a controller calls the C directly).

    **Arguments:** `path` of the shared library; `prefix` of its names (default `"mrjax"`).
    """

    def __init__(self, path: str | os.PathLike, prefix: str = "mrjax"):
        self.lib = ctypes.CDLL(str(Path(path).absolute()))
        d, pd = ctypes.c_double, ctypes.POINTER(ctypes.c_double)
        self._size = getattr(self.lib, f"{prefix}_state_size")
        self._size.restype, self._size.argtypes = ctypes.c_int, []
        self._init = getattr(self.lib, f"{prefix}_init")
        self._init.restype, self._init.argtypes = None, [pd, d, d, d]
        self._step = getattr(self.lib, f"{prefix}_step")
        self._step.restype, self._step.argtypes = d, [pd, d, d, d, d]
        self._inverse = getattr(self.lib, f"{prefix}_inverse")
        self._inverse.restype, self._inverse.argtypes = d, [pd, d, d, d, d]

    @property
    def state_size(self) -> int:
        """Doubles of one damper's state."""
        return int(self._size())

    def init(self, x: float, xdot: float, command: float) -> np.ndarray:
        """A new state at the first sample (`x` [m], `xdot` [m/s], `command`)."""
        state = np.zeros(self.state_size)
        self._init(_ptr(state), x, xdot, command)
        return state

    def step(self, state: np.ndarray, x: float, xdot: float, command: float,
             dt: float) -> float:
        """`PREFIX_step`: the force [N]; `state` (float64, C-contiguous) is updated."""
        return float(self._step(_ptr(state), x, xdot, command, dt))

    def inverse(self, state: np.ndarray, x: float, xdot: float, desired_force: float,
                dt: float) -> float:
        """`PREFIX_inverse`: the command; `state` unchanged."""
        return float(self._inverse(_ptr(state), x, xdot, desired_force, dt))

    def force(self, x: ArrayLike, xdot: ArrayLike, command: ArrayLike,
              dt: ArrayLike) -> np.ndarray:
        """The force [N] (T,) of a record: `x` [m], `xdot` [m/s] (T,), `command` scalar or
        (T,), `dt` [s] the interval after each sample, scalar or (T,): init at the first
        sample, then one step per sample."""
        x, xdot = np.asarray(x, float), np.asarray(xdot, float)
        cmd = np.broadcast_to(np.asarray(command, float), x.shape)
        h = np.broadcast_to(np.asarray(dt, float), x.shape)
        state = self.init(x[0], xdot[0], cmd[0])
        out = np.empty(x.shape)
        out[0] = self.step(state, x[0], xdot[0], cmd[0], 0.0)
        for k in range(1, x.shape[0]):
            out[k] = self.step(state, x[k], xdot[k], cmd[k], h[k - 1])
        return out


def _ptr(a: np.ndarray):
    if a.dtype != np.float64 or not a.flags.c_contiguous:
        raise InputError("the state must be a C-contiguous float64 array")
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
