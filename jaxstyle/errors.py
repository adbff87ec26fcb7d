"""The exception types jaxstyle raises for bad input."""

from __future__ import annotations

import os


class JaxstyleError(Exception):
    """Base class of every error jaxstyle raises about its inputs."""


class MotionDataError(JaxstyleError, ValueError):
    """Malformed or unusable motion data.

    The message always names the file (and the 1-based line where the problem was found, when
    there is one), so a user can open the file at the right place. ``path`` and ``line`` are also
    kept as attributes for programmatic use.
    """

    def __init__(self, message: str, path: str | os.PathLike | None = None, line: int | None = None):
        self.path = None if path is None else os.fspath(path)
        self.line = line
        where = ""
        if self.path is not None:
            where = self.path if line is None else f"{self.path}, line {line}"
            where += ": "
        super().__init__(where + message)
        self.reason = message
