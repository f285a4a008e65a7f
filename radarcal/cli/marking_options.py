"""``radarcal run`` options of the marking side (roster, guessing, double-vulnerability policies), declared once.

Each is a typer ``Annotated`` type; :func:`marking_overrides` checks them and returns the :class:`RunConfig` fields.
The double-vulnerability policies are all off by default (docs/runtime.md).
"""

from __future__ import annotations

import math
from typing import Annotated, Optional

import typer

from radarcal.errors import InputError

__all__ = ["RosterOpt", "GuessOpt", "DvAtOpt", "DvEnemiesInHalfOpt", "DvOnKeyOpt", "DvOnDartOpt", "marking_overrides"]

RosterOpt = Annotated[bool, typer.Option("--roster/--no-roster", help="Fixed robot slots kept by label history; a lost robot predicted for a while (--no-roster: each frame's labels as they are).")]
GuessOpt = Annotated[bool, typer.Option("--guess/--no-guess", help="For a robot nobody sees, send its most plausible position; keep it while the referee's mark progress of that robot rises.")]
DvAtOpt = Annotated[Optional[float], typer.Option("--dv-at", metavar="SECONDS", help="Request double vulnerability (0x0121) at this match time (s since the match started). Off by default.")]
DvEnemiesInHalfOpt = Annotated[Optional[int], typer.Option("--dv-enemies-in-half", metavar="N", help="Request double vulnerability when at least N enemy robots are in our half. Off by default.")]
DvOnKeyOpt = Annotated[Optional[str], typer.Option("--dv-on-key", metavar="KEY", help="Request double vulnerability when the aerial operator's map command (0x0303) carries this key (a letter, or a key code). Off by default.")]
DvOnDartOpt = Annotated[bool, typer.Option("--dv-on-dart", help="Request double vulnerability when our dart hits (0x0105 dart info). Off by default.")]


def marking_overrides(roster: bool = True, guess: bool = True, dv_at: float | None = None, dv_enemies_in_half: int | None = None, dv_on_key: str | None = None,
                      dv_on_dart: bool = False) -> dict:  # fmt: skip
    """The checked options as :class:`radarcal.runtime.config.RunConfig` overrides (InputError naming the option)."""
    if dv_at is not None and not (math.isfinite(dv_at) and 0 <= dv_at <= 3600):
        raise InputError("--dv-at", f"expected a match time in seconds (0..3600), got {dv_at}")
    if dv_enemies_in_half is not None and not 1 <= dv_enemies_in_half <= 7:
        raise InputError("--dv-enemies-in-half", f"expected 1..7 robots, got {dv_enemies_in_half}")
    if dv_on_key is not None:
        from radarcal.runtime.marking import key_code

        try:
            key_code(dv_on_key)
        except ValueError as e:
            raise InputError("--dv-on-key", str(e)) from None
    return {"roster": bool(roster), "guess": bool(guess) and bool(roster), "dv_at_s": dv_at, "dv_enemies_in_half": dv_enemies_in_half, "dv_on_key": dv_on_key,
            "dv_on_dart": bool(dv_on_dart)}  # fmt: skip
