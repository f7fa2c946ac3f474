"""Scale the condition axis across devices with `jax.sharding`.

Every condition of a fit is independent: its own swarm, its own random stream, its own
statistical stop and its own Levenberg-Marquardt polish. mrjax therefore scales beyond one
device by sharding the *condition* axis: each device holds `C / n_devices` conditions (all their
samples and particles) and runs the same compiled program on them. The only cross-device
traffic is the swarm's "is any condition still running?" test once per generation.

```python
import jax, mrjax
batch = mrjax.data.paper_grid()
res = mrjax.fit("kwok", batch, devices="all")          # every device JAX sees
res = mrjax.fit("kwok", batch, devices=jax.devices()[:2])
```

The result is the same as on one device with the same key: the conditions are padded to a
multiple of the device count with copies of the last condition, which are fitted like the
others and cut off the result (`unpad`). A condition's random stream is
`jax.random.split(key, C)[i]`, which does not depend on C under JAX's default
`jax_threefry_partitionable=True`, so padding does not change the real conditions' streams.

On one host with several CPU cores, `XLA_FLAGS=--xla_force_host_platform_device_count=K` (set
before JAX starts) exposes K CPU devices. Across hosts, call `jax.distributed.initialize()` in
every process first; `jax.devices()` then lists the devices of all hosts and
`shard_batch(..., devices="all")` fills each host's devices with its share of the conditions.
`mrjax.fit` converts its per-condition results to NumPy on the host, which needs every shard
addressable (one process); across hosts use the swarm directly and gather its results with
`jax.experimental.multihost_utils.process_allgather` (the README's recipe,
`examples/multihost.py`, which `tests/test_multihost.py` runs as two processes).

:func:`take_conditions` selects conditions keeping the padded length: the chunks of a fit of
many tests (`mrjax.fitting.fit_in_chunks`) and the device padding are built with it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._errors import InputError
from .data import Batch

__all__ = ["shard_batch", "Devices", "AXIS"]
# `resolve_devices`, `pad_conditions`, `take_conditions` and `unpad` are public for
# `mrjax.fitting` (its chunks and devices), not part of the user API (`__all__`).

#: Name of the mesh axis the conditions are sharded over.
AXIS = "conditions"
#: What a `devices=` argument takes: `"all"`, a count, a sequence of `jax.Device`, or `None`
#: (see :func:`resolve_devices`).
Devices = str | int | Sequence[Any] | None


def resolve_devices(devices: Devices) -> list:
    """The devices to shard over.

    **Arguments:** `devices`: `"all"` (every device `jax.devices()` lists, all hosts after
    `jax.distributed.initialize()`), an int n (the first n of them), a sequence of
    `jax.Device`, or `None` (JAX's default device only).

    **Returns:** a non-empty list of distinct devices. Raises :class:`mrjax.InputError` for
    anything else.
    """
    if devices is None:
        return [jax.devices()[0]]
    if isinstance(devices, str):
        if devices.strip().lower() != "all":
            raise InputError(f"devices must be 'all', a count or a list of jax devices, got "
                             f"{devices!r}")
        return list(jax.devices())
    if isinstance(devices, (int, np.integer)) and not isinstance(devices, bool):
        avail = jax.devices()
        if not 1 <= int(devices) <= len(avail):
            raise InputError(f"devices={int(devices)}: {len(avail)} device(s) available")
        return list(avail[: int(devices)])
    try:
        devs = list(devices)
    except TypeError:
        raise InputError(f"devices must be 'all', a count or a list of jax devices, got "
                         f"{type(devices).__name__}") from None
    if not devs:
        raise InputError("devices is empty")
    for d in devs:
        if not (hasattr(d, "platform") and hasattr(d, "id")):
            raise InputError(f"not a jax device: {d!r}")
    if len({(d.platform, d.id) for d in devs}) != len(devs):
        raise InputError("devices lists a device twice")
    return devs


def pad_conditions(batch: Batch, mask: Any, multiple: int) -> tuple[Batch, Any, int]:
    """Pad the condition axis to a multiple of `multiple` with copies of the last condition.

    The copies keep their samples and mask, so they are ordinary, well-posed fits (an
    all-masked dummy would score `inf` for every particle and give the polish an empty
    problem); they only cost their share of the work and are cut off by :func:`unpad`.

    **Returns:** `(batch, mask, n_real)`.
    """
    C = batch.n_conditions
    Cp = int(math.ceil(C / multiple) * multiple)
    mask = batch.mask if mask is None else mask
    if Cp == C:
        return batch, mask, C
    idx = np.concatenate([np.arange(C), np.full(Cp - C, C - 1)])
    labels = tuple(batch.labels) + tuple(f"{batch.labels[-1]}#pad{k}" for k in range(Cp - C))
    padded, padded_mask = take_conditions(batch, idx, mask, labels=labels)
    return padded, padded_mask, C


def take_conditions(batch: Batch, index: Any, mask: Any = None, *,
                    labels: Sequence[str] | None = None) -> tuple[Batch, Any]:
    """The conditions at `index` (ints, repeats allowed, or a boolean mask), *keeping the padded
    length T* of `batch` (unlike `Batch.subset`, which re-pads to the subset's own longest
    record): every row is bit for bit the row of `batch`, so a fit of the rows computes
    exactly what a fit of the whole batch computes for them (sums over the same T samples).

    **Arguments:** `batch`; `index`; `mask` (C, T) samples to score (default `batch.mask`),
    taken alike; `labels` of the new rows (default those of `batch`).

    **Returns:** `(batch, mask)` with host-built arrays on JAX's default device.
    """
    idx = np.arange(batch.n_conditions)[np.asarray(index)]
    mask = batch.mask if mask is None else mask
    arrays = {f.name: np.asarray(getattr(batch, f.name))[idx]
              for f in dataclasses.fields(batch) if f.name != "labels"}
    names = tuple(batch.labels[int(i)] for i in idx) if labels is None else tuple(labels)
    if len(names) != idx.size:
        raise InputError(f"take_conditions: {len(names)} labels for {idx.size} conditions")
    taken = Batch(**jax.device_put(arrays), labels=names)
    return taken, jax.device_put(np.asarray(mask)[idx])


def shard_batch(batch: Batch, mask: Any = None, devices: Devices = "all") -> tuple[Batch, Any]:
    """Place a batch (and its fit mask) with the condition axis sharded over `devices`.

    **Arguments:**

    - `batch`: the conditions (`mrjax.data.Batch`).
    - `mask`: (C, T) samples to score (default `batch.mask`), sharded alike.
    - `devices`: see :func:`resolve_devices` (default `"all"`).

    **Returns:** `(batch, mask)`, padded to a multiple of the device count with copies of the
    last condition (see :func:`pad_conditions`; `mrjax.fit` cuts the result back to the real
    conditions with :func:`unpad`). With a single device nothing is padded: the arrays are
    only placed on it. Every jitted mrjax computation that receives these arrays runs sharded
    (XLA's SPMD partitioner follows the input shardings).
    """
    devs = resolve_devices(devices)
    mask = batch.mask if mask is None else mask
    if len(devs) == 1:
        return jax.device_put((batch, jax.numpy.asarray(mask)), devs[0])
    batch, mask, _ = pad_conditions(batch, mask, len(devs))
    mesh = Mesh(np.asarray(devs, dtype=object), (AXIS,))

    def put(a):
        if not isinstance(a, (jax.Array, np.ndarray)) or np.ndim(a) == 0:
            return a
        spec = PartitionSpec(AXIS, *([None] * (np.ndim(a) - 1)))
        host = np.asarray(a)
        # from the host copy every process holds: works on one host and across hosts
        # (after `jax.distributed.initialize()`), where each process fills its own devices
        return jax.make_array_from_callback(host.shape, NamedSharding(mesh, spec),
                                            lambda idx: host[idx])

    return jax.tree.map(put, batch), put(jax.numpy.asarray(mask))


def unpad(result: Any, n: int) -> Any:
    """Cut a per-condition result (a dataclass such as `mrjax.FitResult`) back to its first `n`
    conditions: every array field and tuple field whose leading length is the padded condition
    count is sliced; everything else is kept."""
    C = len(getattr(result, "labels"))
    if n == C:
        return result
    changes = {}
    for f in dataclasses.fields(result):
        v = getattr(result, f.name)
        if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == C:
            changes[f.name] = v[:n]
        elif isinstance(v, tuple) and len(v) == C:
            changes[f.name] = v[:n]
    return dataclasses.replace(result, **changes)
