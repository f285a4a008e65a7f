"""Errors raised at the boundary (files, bundle, CLI input). The CLI turns them into one line and exit code 2."""

from __future__ import annotations

__all__ = ["InputError"]


class InputError(Exception):
    """Bad user input: a file that cannot be read or a value that makes no sense.

    ``source`` names the file (or option) at fault; ``str(err)`` is ``"<source>: <message>"``.
    """

    def __init__(self, source: object, message: str):
        self.source = str(source) if source is not None else ""
        self.message = message
        super().__init__(f"{self.source}: {message}" if self.source else message)
