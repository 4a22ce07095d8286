"""The project's error type.

Every problem caused by the user's input (a file, a parameter) is raised as an
:class:`AptFiltersError` whose message is one line naming the file (if any) and the
problem. The CLI prints that line and exits with status 2; any other exception is a bug.
"""

from __future__ import annotations

import os


class AptFiltersError(Exception):
    """A user-facing error: one line, naming the file and the problem."""

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        text = " ".join(str(message).split())  # one line, whatever the caller passed
        super().__init__(f"{self.path}: {text}" if self.path else text)


class InputError(AptFiltersError):
    """A file that cannot be read as what it claims to be (bad size, bad values, bad syntax)."""
