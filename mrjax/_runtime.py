"""Keep a long-running process (a test session, a notebook doing many fits) within the
operating system's limit on memory maps.

XLA:CPU places the machine code of every compiled program in memory maps of its own, and JAX
keeps every program of a process in its caches: each fit of a new model, shape or setting adds
a few hundred maps. Linux refuses new maps beyond `vm.max_map_count` (65,530 by default), and
the next compilation then crashes the process (a segmentation fault inside LLVM).
:func:`release_code` empties JAX's caches when the process holds more than `MAP_SHARE` of that
limit; the programs are compiled again when they are next used.
"""

from __future__ import annotations

import warnings

#: Clear JAX's caches above this share of `vm.max_map_count`.
MAP_SHARE = 0.6
_DEFAULT_LIMIT = 65530


def _read_int(path: str) -> int | None:
    try:
        with open(path) as fh:
            return int(fh.read().strip())
    except (OSError, ValueError):
        return None


def map_count() -> int | None:
    """The memory maps this process holds (Linux), or None where it cannot be read."""
    try:
        with open("/proc/self/maps", "rb") as fh:
            return sum(1 for _ in fh)
    except OSError:
        return None


def release_code(share: float = MAP_SHARE) -> bool:
    """Empty JAX's caches of compiled programs when the process holds more than `share` of the
    memory maps Linux allows it (see the module docstring). Returns whether it did; a no-op
    where the count cannot be read (other systems)."""
    n = map_count()
    if n is None:
        return False
    limit = _read_int("/proc/sys/vm/max_map_count") or _DEFAULT_LIMIT
    if n <= share * limit:
        return False
    import jax

    jax.clear_caches()
    warnings.warn(f"this process held {n} memory maps ({n / limit:.0%} of vm.max_map_count), "
                  f"mostly compiled programs: JAX's caches were emptied, so the next fits "
                  f"compile again", RuntimeWarning, stacklevel=3)
    return True
