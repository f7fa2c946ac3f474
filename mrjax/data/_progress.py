"""The progress bar of loading: bytes of the files read, drawn once loading has taken
`DELAY_S` seconds (a short load draws nothing).

`mrjax.data.load` opens the bar for all its files (:func:`load_progress`); the readers report
the bytes they have read (:func:`advance`) without knowing whether a bar is shown.
"""

from __future__ import annotations

import contextlib
import contextvars
import sys
from collections.abc import Iterator
from typing import Any

#: Seconds of loading before the bar appears.
DELAY_S = 1.0

_BAR: contextvars.ContextVar[Any] = contextvars.ContextVar("mrjax_load_bar", default=None)


@contextlib.contextmanager
def load_progress(total_bytes: int, enabled: bool | None) -> Iterator[None]:
    """A bar over `total_bytes` for the readers called inside the block; `enabled` None: only
    when stderr is a terminal."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled or _BAR.get() is not None:  # a bar already counts these bytes
        yield
        return
    from tqdm.auto import tqdm  # imported here: only a terminal run draws a bar

    bar = tqdm(total=total_bytes, unit="B", unit_scale=True, desc="loading", delay=DELAY_S,
               file=sys.stderr, leave=False)
    token = _BAR.set(bar)
    try:
        yield
    finally:
        _BAR.reset(token)
        bar.close()


def advance(nbytes: int) -> None:
    """Count `nbytes` more bytes read (nothing without a bar)."""
    bar = _BAR.get()
    if bar is not None:
        bar.update(nbytes)
