"""The project's error type.

Every problem caused by the user's input (a file, a parameter) is raised as an
:class:`AptFiltersError` whose message is one line naming the file (if any) and the
problem. The CLI prints that line and exits with status 2; any other exception is a bug.
"""

from __future__ import annotations

import os

MAX_WORD = 200
"""Characters kept of one word (a bad token quoted from a file may be megabytes long)."""
MAX_LINE = 2000
"""Characters kept of a whole message."""


def readable(text: str) -> str:
    """``text`` on one line, each word cut to :data:`MAX_WORD` characters and the whole to
    :data:`MAX_LINE`, each cut saying how much was left out."""
    words = [w if len(w) <= MAX_WORD else f"{w[:MAX_WORD]}…[{len(w) - MAX_WORD} more characters]"
             for w in str(text).split()]
    line = " ".join(words)
    return line if len(line) <= MAX_LINE else f"{line[:MAX_LINE]}…[{len(line) - MAX_LINE} more characters]"


class AptFiltersError(Exception):
    """A user-facing error: one line of readable length, naming the file and the problem."""

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        text = readable(message)
        super().__init__(f"{readable(self.path)}: {text}" if self.path else text)


class InputError(AptFiltersError):
    """A file that cannot be read as what it claims to be (bad size, bad values, bad syntax)."""
