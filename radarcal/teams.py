"""One colour table by team for every minimap / track figure (the report's and the live minimap): red robots in reds, blue robots in
blues, anything else (unlabelled ``#id`` tracks, other labels) in greys. A robot keeps its shade from figure to
figure (the shade follows its number, not the order of the labels)."""

from __future__ import annotations

import re
from typing import Iterable

__all__ = ["TEAM_SHADES", "team_of", "track_colours"]

TEAM_SHADES: dict[str | None, tuple[str, ...]] = {
    "red": ("#d62728", "#a50f15", "#ff6f61", "#cb181d", "#fb6a4a", "#67000d", "#ef3b2c"),
    "blue": ("#1f77b4", "#08519c", "#6baed6", "#2171b5", "#4292c6", "#08306b", "#3182bd"),
    None: ("#555555", "#888888", "#333333", "#aaaaaa"),
}

_LABEL = re.compile(r"^(red|blue|r|b)[_\- ]?(\d+)?$", re.IGNORECASE)


def team_of(label: str) -> str | None:
    """``red_3`` / ``R3`` / ``red`` -> "red", ``blue_4`` / ``B4`` -> "blue", anything else -> None."""
    m = _LABEL.match(str(label).strip())
    if not m:
        return None
    return "red" if m.group(1).lower() in ("red", "r") else "blue"


def _number(label: str) -> int | None:
    m = _LABEL.match(str(label).strip())
    return int(m.group(2)) if m and m.group(2) else None


def track_colours(labels: Iterable[str]) -> dict[str, str]:
    """Colour (hex) of each label: its team's shade for its robot number (1-based); labels without a number, and
    labels of no team, take the team's next unused shade in sorted order."""
    out: dict[str, str] = {}
    nxt: dict[str | None, int] = {}
    for label in sorted(set(labels), key=str):
        team = team_of(label)
        shades = TEAM_SHADES[team]
        n = _number(label) if team is not None else None
        if n is not None and n >= 1:
            out[label] = shades[(n - 1) % len(shades)]
        else:
            i = nxt.get(team, 0)
            out[label] = shades[i % len(shades)]
            nxt[team] = i + 1
    return out
