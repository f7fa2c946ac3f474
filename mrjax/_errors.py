"""Errors raised by mrjax for bad input.

Every user-facing error is an :class:`InputError`: a `ValueError` whose message is a single line
naming the offending file, column, row or argument. The command line turns it into a one-line
message on stderr and exit code 2.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad input: a file, column, row, argument or option that mrjax cannot use.

    The message is always one line and names what is wrong and where.
    """

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))
