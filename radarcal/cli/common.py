"""Shared CLI plumbing: stderr console for progress/logs, JSON vs human output, option helpers.

Errors: commands raise :class:`radarcal.errors.InputError`; :func:`radarcal.cli.main.main` turns it into
``error: <file>: <what is wrong>`` on stderr and exit code 2 (``--debug`` shows the traceback).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any, Callable, Optional

import typer
from rich.console import Console

from radarcal.errors import InputError
from radarcal.plain import to_plain

__all__ = ["err_console", "emit", "progress", "BundleOpt", "ReplayBundleOpt", "JsonOpt", "CloudTopicOpt", "to_jsonable", "command_line", "parse_image_size"]

# Progress bars and logs go to stderr so that --json output on stdout stays clean.
err_console = Console(stderr=True)

# Options shared by several commands, declared once (typer ``Annotated``): ``bundle: BundleOpt = ...`` (required),
# ``as_json: JsonOpt = False``.
BundleOpt = Annotated[Path, typer.Option("--bundle", "-b", help="Calibration bundle (YAML); a calibration command creates it when missing and adds its result.")]
ReplayBundleOpt = Annotated[Optional[Path], typer.Option("--bundle", "-b", help="Calibration bundle (default: calib.yaml inside --replay).")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Machine-readable summary on stdout.")]
CloudTopicOpt = Annotated[Optional[str], typer.Option("--cloud-topic", help="Bag topic of the clouds (default: every Livox CustomMsg / PointCloud2 topic; a scene bag with several needs one).")]


def to_jsonable(obj: Any) -> Any:
    """Plain JSON-safe Python (NaN/inf become null)."""
    return to_plain(obj, json_safe=True)


def emit(summary: dict, as_json: bool, human: Callable[[dict], None]) -> None:
    """Print ``summary`` as JSON on stdout, or call ``human(summary)`` for people."""
    if as_json:
        sys.stdout.write(json.dumps(to_jsonable(summary), indent=2) + "\n")
    else:
        human(summary)


def progress(iterable, description: str, total: int | None = None, enabled: bool = True):
    """A rich progress bar on stderr (silent when stderr is not a terminal or ``enabled`` is False)."""
    from rich.progress import track

    if not enabled or not err_console.is_terminal:
        return iterable
    return track(iterable, description=description, total=total, console=err_console, transient=True)


_current_argv: list[str] | None = None  # set by radarcal.cli.main.main() while a command runs


def command_line() -> str:
    """The command line as typed (shell-quoted), for provenance; also right when the CLI runs in-process
    through ``radarcal.cli.main.main([...])``."""
    import shlex

    argv = sys.argv[1:] if _current_argv is None else _current_argv
    return " ".join(["radarcal", *(shlex.quote(str(a)) for a in argv)])


def parse_image_size(text: str, flag: str = "--image-size") -> tuple[int, int]:
    """``WIDTHxHEIGHT`` (``1280x1024``, also ``1280*1024``) -> (width, height); ``InputError(flag, ...)`` otherwise."""
    try:
        w, h = (int(v) for v in text.lower().replace("*", "x").split("x"))
    except ValueError:
        raise InputError(flag, f"expected WIDTHxHEIGHT, e.g. 1280x1024, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise InputError(flag, f"width and height must be positive, got {text!r}")
    return w, h
