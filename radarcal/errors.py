"""Errors raised at the boundary (files, bundle, CLI input). The CLI turns them into one line and exit code 2."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["InputError", "read_text"]


class InputError(Exception):
    """Bad user input: a file that cannot be read or a value that makes no sense.

    ``source`` names the file (or option) at fault; ``str(err)`` is ``"<source>: <message>"``.
    """

    def __init__(self, source: object, message: str):
        self.source = str(source) if source is not None else ""
        self.message = message
        super().__init__(f"{self.source}: {message}" if self.source else message)


def read_text(path: str | os.PathLike, what: str = "file", encoding: str = "utf-8", errors: str = "strict") -> str:
    """The text of ``path``, or :class:`InputError` naming it: ``<what> not found`` / ``cannot read <what> as text``."""
    path = Path(path)
    try:
        return path.read_text(encoding=encoding, errors=errors)
    except FileNotFoundError:
        raise InputError(path, f"{what} not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(path, f"cannot read {what} as text ({e.__class__.__name__})") from None
