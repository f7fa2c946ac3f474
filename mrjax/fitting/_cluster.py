"""Where the chunks of a fit run: one after the other in this process (:class:`LocalPool`), or
as tasks of a Dask cluster (:class:`ClusterPool`), behind the one interface every pass of the
chunk layer uses (`mrjax.fitting._chunks`).

A pool `share`s what the tasks need (on a cluster: scattered once to every worker,
`Client.scatter(broadcast=True)`; a worker that joins or restarts later fetches it from a
worker that holds it), `map`s a function over chunk indices, yielding each `(j, result)` as it
finishes, and tells the plan the memory budget of one task (`default_budget`) and the devices
a task shards over (`device_count`).

**Workers** are processes with JAX in each (Dask starts them by `spawn`, never by a fork of a
process that has loaded JAX). Before each task a worker takes the client's JAX settings that
change results or say where compiled programs are cached (`JAX_SETTINGS`): with a persistent
compilation cache in the client (`mrjax.cli.enable_compilation_cache`, or
`jax_compilation_cache_dir`), workers without one of their own share its directory.

**Faults.** A worker that dies mid-task (killed, out of memory) loses its task; the scheduler
runs it again on another worker (Dask's `distributed.scheduler.allowed-failures`), from the
same inputs: the same result. A task that raises does not stop the others; once all have
finished (each result yielded as it came), the first error is raised: an
:class:`mrjax.InputError` naming its chunk's tests for bad data or a task whose workers kept
dying, the task's own exception otherwise.
"""

from __future__ import annotations

import contextlib
import pickle
import sys
import uuid
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

from .._errors import InputError
from ..engine import Chunks
from ..models import AbstractModel, source_of
from ..parallel import resolve_devices
from ._plan import DEFAULT_MEMORY_FRACTION, default_budget

#: The client's JAX settings a worker takes before each task: those that change a result
#: (precision, random streams), and the persistent compilation cache's (`CACHE_SETTINGS`,
#: taken only by a worker without a cache directory of its own).
JAX_SETTINGS: tuple[str, ...] = (
    "jax_enable_x64", "jax_default_matmul_precision", "jax_default_prng_impl",
    "jax_threefry_partitionable", "jax_compilation_cache_dir",
    "jax_persistent_cache_min_compile_time_secs", "jax_persistent_cache_min_entry_size_bytes",
)
#: The settings of the persistent compilation cache, its directory first.
CACHE_SETTINGS: tuple[str, ...] = JAX_SETTINGS[4:]


class LocalPool:
    """The chunks run one after the other in this process; an error stops the pass."""

    def share(self, obj: Any, *, model: AbstractModel | None = None) -> Any:
        """`obj` itself."""
        return obj

    def map(self, fn: Callable, js: Iterable[int], *args: Any,
            describe: Callable[[int], str]) -> Iterator[tuple[int, Any]]:
        """`(j, fn(j, *args))` for each chunk `j`, in order."""
        for j in js:
            yield j, fn(j, *args)

    def default_budget(self) -> int:
        """The memory budget of a fit given none: this process's (`default_budget`)."""
        return default_budget()

    def device_count(self, devices: Any) -> int:
        """The devices a chunk is sharded over."""
        return 1 if devices is None else len(resolve_devices(devices))


class ClusterPool:
    """The chunks as tasks of the Dask cluster of `client` (see the module docstring)."""

    def __init__(self, client: Any):
        self.client = client
        self.settings = jax_settings()

    def share(self, obj: Any, *, model: AbstractModel | None = None) -> Any:
        """`obj` scattered once to every worker: a future the tasks take as an argument. With
        a `model` defined in a file that the workers cannot import by name (`mrjax.models.get
        ("path.py:Name")`), that file's code travels with `obj` (:class:`Pickled`)."""
        modules = _file_modules(model) if model is not None else []
        if modules:
            obj = Pickled(obj, modules)
        return self.client.scatter(obj, broadcast=True, hash=False)

    def map(self, fn: Callable, js: Iterable[int], *args: Any,
            describe: Callable[[int], str]) -> Iterator[tuple[int, Any]]:
        """`(j, fn(j, *args))` for each chunk `j`, one task each, as they finish; then the
        first failure, if any (`describe(j)`: chunk `j`'s tests in words)."""
        from distributed import as_completed

        token = uuid.uuid4().hex[:8]
        name = fn.__name__.strip("_").replace("_", "-")
        futures = {self.client.submit(run_task, self.settings, fn, j, *args, pure=False,
                                      key=f"mrjax-{name}-{j}-{token}"): j for j in js}
        failed: list[tuple[int, BaseException]] = []
        try:
            for fut in as_completed(futures, loop=self.client.loop):
                j = futures[fut]
                if fut.status == "finished":
                    yield j, fut.result()
                else:
                    failed.append((j, _exception(fut)))
                fut.release()
        finally:
            self.client.cancel([f for f in futures if not f.done()])
        if failed:
            raise _failure(sorted(failed, key=lambda f: f[0]), describe)

    def _workers(self) -> dict[str, dict]:
        try:
            info = self.client.scheduler_info(n_workers=-1)  # all workers (newer Dask)
        except TypeError:
            info = self.client.scheduler_info()
        workers = info["workers"]
        if not workers:
            raise InputError(f"the Dask cluster at {self.client.scheduler.address} has no "
                             f"workers")
        return workers

    def default_budget(self) -> int:
        """The memory budget of one task given none: `DEFAULT_MEMORY_FRACTION` of the least
        memory limit per thread of the workers (this process's budget where a worker has no
        limit)."""
        workers = self._workers().values()
        per = [w["memory_limit"] / max(1, w["nthreads"]) for w in workers
               if w.get("memory_limit")]
        if len(per) < len(workers):
            return default_budget()
        return int(DEFAULT_MEMORY_FRACTION * min(per))

    def device_count(self, devices: Any) -> int:
        """The devices a task shards its chunk over, on every worker alike (`"all"`: asked
        of the workers; a count: checked by each worker when it places its chunk)."""
        if devices is None or not isinstance(devices, str):
            return 1 if devices is None else int(devices)
        self._workers()
        counts = set(self.client.run(_local_devices, devices).values())
        if len(counts) != 1:
            raise InputError(f"the workers have {sorted(counts)} devices: give a device "
                             f"count that every worker has")
        return counts.pop()


@contextlib.contextmanager
def open_pool(chunks: Chunks) -> Iterator[LocalPool | ClusterPool]:
    """The pool of a fit's `chunks.cluster`: a :class:`LocalPool` without one; else a
    :class:`ClusterPool` on the client given, or on a client connected to the cluster's
    scheduler for the fit (and closed after it). Raises :class:`mrjax.InputError` without
    Dask's `distributed` or for a scheduler that cannot be reached."""
    cluster = chunks.cluster
    if cluster is None:
        yield LocalPool()
        return
    try:
        import distributed
    except ImportError:
        raise InputError("a cluster needs Dask's distributed: pip install 'mrjax[cluster]'"
                         ) from None
    if hasattr(cluster, "submit"):  # a client
        yield ClusterPool(cluster)
        return
    address = getattr(cluster, "scheduler_address", cluster)
    try:
        client = distributed.Client(address.strip(), set_as_default=False)
    except (OSError, ValueError) as e:  # TimeoutError is an OSError
        raise InputError(f"cannot reach the Dask scheduler at {address!r}: {e}") from None
    with client:
        yield ClusterPool(client)


def jax_settings() -> dict[str, Any]:
    """This process's values of `JAX_SETTINGS`."""
    import jax

    return {name: getattr(jax.config, name) for name in JAX_SETTINGS}


def apply_settings(settings: dict[str, Any]) -> None:
    """Take `settings` (see `JAX_SETTINGS`) in this process, a worker's."""
    import jax

    own_cache = getattr(jax.config, CACHE_SETTINGS[0]) or settings[CACHE_SETTINGS[0]] is None
    for name, value in settings.items():
        if (name not in CACHE_SETTINGS or not own_cache) and getattr(jax.config, name) != value:
            jax.config.update(name, value)
    if not own_cache:  # JAX sets its cache up once: again, in case this worker compiled before
        from jax.experimental.compilation_cache import compilation_cache

        compilation_cache.reset_cache()


def run_task(settings: dict[str, Any], fn: Callable, j: int, *args: Any) -> Any:
    """A task on a worker: the client's JAX settings, then `fn(j, *args)`."""
    apply_settings(settings)
    return fn(j, *(a.get() if isinstance(a, Pickled) else a for a in args))


class Pickled:
    """An object pickled with the code of `modules` by value (cloudpickle), for workers that
    cannot import those modules by name; unpickled once in each process that uses it."""

    def __init__(self, obj: Any, modules: list[ModuleType]):
        import cloudpickle

        for m in modules:
            cloudpickle.register_pickle_by_value(m)
        try:
            self.data = cloudpickle.dumps(obj)
        finally:
            for m in modules:
                cloudpickle.unregister_pickle_by_value(m)
        self._obj: Any = None

    def get(self) -> Any:
        """The object."""
        if self._obj is None:
            self._obj = pickle.loads(self.data)
        return self._obj

    def __getstate__(self) -> dict[str, bytes]:
        return {"data": self.data}

    def __setstate__(self, state: dict[str, bytes]) -> None:
        self.data, self._obj = state["data"], None


def _file_modules(model: AbstractModel) -> list[ModuleType]:
    """The module of a model defined in a file (`mrjax.models.source_of` kind `"file"`), which
    other processes cannot import by name; none for any other model."""
    src = source_of(model)
    if src.get("kind") != "file":
        return []
    path = Path(str(src["file"])).resolve()
    return [m for m in list(sys.modules.values())
            if getattr(m, "__file__", None) and Path(m.__file__).resolve() == path]


def _local_devices(devices: Any) -> int:
    return len(resolve_devices(devices))


def _exception(fut: Any) -> BaseException:
    """The exception of a future that did not finish (cancelled: lost by the scheduler)."""
    if fut.status == "error":
        return fut.exception()
    return RuntimeError(f"task {fut.key} was {fut.status} by the Dask scheduler")


def _failure(failed: list[tuple[int, BaseException]], describe: Callable[[int], str]
             ) -> BaseException:
    """The error raised for failed chunks (sorted by index): the first one's, an
    :class:`mrjax.InputError` for bad data or a task whose workers kept dying."""
    from distributed import KilledWorker

    j, exc = failed[0]
    more = f" ({len(failed) - 1} more chunk(s) failed)" if len(failed) > 1 else ""
    if isinstance(exc, InputError):
        return InputError(f"{exc}{more}")
    if isinstance(exc, KilledWorker):
        return InputError(f"{describe(j)}: every worker that ran it died (killed, or out of "
                          f"memory: lower the memory per worker or the chunk size){more}")
    return exc
