"""Per-season referee rules: the one table of 0x0305 layouts, send rates, byte budgets, mark rules and
double-vulnerability semantics (2021..2026).

Every value is a :class:`Fact` with the source tag of ``/work/shared/referee_protocol.md`` (``[S1]``..``[S9]``) or
``/work/shared/radar_station_practice.md`` (``practice §N``) and an ``uncertain`` flag where no primary document
confirmed it. Light on purpose (no numpy, no other radarcal import): :mod:`radarcal.runtime.referee`,
:mod:`radarcal.runtime.serial_link`, the marking side and the referee simulator all read this table.

Mark rules (``mark_rule``):

- ``"distance"`` (2021-2023): a mark counts as correct while the sent position is within ``mark_radius_m`` of the
  robot's true position; there is no per-robot progress and no vulnerability on the link.
- ``"progress"`` (2024-2025): per-robot progress 0..``progress_max`` (0x020C sends it as 6 x u8); the robot is
  vulnerable at progress >= ``vulnerable_at``.
- ``"progress_bits"`` (2026): the same progress, 0x020C sends one *vulnerable* bit per enemy robot (progress >= 100).

Progress moves by ``progress_up_per_s`` while the mark is correct and ``progress_down_per_s`` while it is wrong or
not sent (a team's summary of the 2026 manual: +5 / -10 per s, 0..150; UNCERTAIN, configurable). The score a
simulated match reports uses ``score_correct_per_s`` / ``score_wrong_per_s`` (same figures, same caveat).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

__all__ = ["Fact", "SeasonRules", "SEASONS", "KNOWN_SEASONS", "rules", "MAP_LAYOUTS", "MAP_LAYOUT_BYTES", "season_table_rows", "LINE_BYTES_PER_S"]

#: 115200 baud, 8N1 = 10 bit times per byte (physical ceiling of the user serial port, [S1] [S2])
LINE_BYTES_PER_S = 115200 // 10

#: 0x0305 layout name -> data length in bytes
MAP_LAYOUT_BYTES = {"single14": 14, "single10": 10, "all24": 24, "all48": 48}
#: 0x0305 layout name -> (enemy slots, ally slots) as robot numbers (1 hero, 2 engineer, 3/4/5 infantry, 6 aerial, 7 sentry)
MAP_LAYOUTS = {"single14": ((), ()), "single10": ((), ()), "all24": ((1, 2, 3, 4, 5, 7), ()), "all48": ((1, 2, 3, 4, 6, 7), (1, 2, 3, 4, 6, 7))}


@dataclass(frozen=True)
class Fact:
    """One table entry: its value, where it comes from, and whether a primary document confirmed it."""

    value: Any
    source: str = ""
    uncertain: bool = False
    note: str = ""

    def __str__(self) -> str:
        return f"{self.value}{' (UNCERTAIN)' if self.uncertain else ''}"


def _f(value, source="", uncertain=False, note="") -> Fact:
    return Fact(value, source, uncertain, note)


@dataclass(frozen=True)
class SeasonRules:
    """The referee facts radarcal needs for one season. Read ``.value`` of each field (see :func:`rules`)."""

    season: int
    map_layout: Fact  # 0x0305 layout name (MAP_LAYOUTS)
    map_hz: Fact  # 0x0305 max send rate
    interaction_hz: Fact  # 0x0301 max send rate (the whole cmd_id)
    interaction_bytes_per_s: Fact  # 0x0301 byte budget per 1000 ms
    interaction_max_content: Fact  # bytes of 0x0301 content after its 6-byte header
    link_bytes_per_s: Fact  # budget radarcal keeps on the whole link (every frame, overhead included)
    mark_rule: Fact  # "distance" | "progress" | "progress_bits"
    mark_radius_m: Fact  # a mark within this distance of the truth is correct
    progress_max: Fact  # mark progress ceiling (None: no progress this season)
    vulnerable_at: Fact  # progress at which the robot is vulnerable
    progress_up_per_s: Fact  # progress gained per second of correct marking
    progress_down_per_s: Fact  # progress lost per second wrong or not sent (negative)
    score_correct_per_s: Fact  # simulated score per second a robot is correctly marked
    score_wrong_per_s: Fact  # per second wrong or not sent (negative)
    mark_feedback_bytes: Fact  # 0x020C length (None: no such command)
    radar_info_bytes: Fact  # 0x020E length (None: no such command)
    radar_cmd_bytes: Fact  # 0x0121 content length inside 0x0301 (None: no double vulnerability)
    dv_semantics: Fact  # how 0x0121 requests double vulnerability ("counter": raise radar_cmd by exactly 1)
    dv_max_chances: Fact  # chances the radar can hold (0x020E bits 0-1)
    dv_duration_s: Fact  # how long one double vulnerability lasts
    game_status_bytes: Fact  # 0x0001 length
    hp_bytes: Fact  # 0x0003 length
    hp_enemy_robots: Fact  # does 0x0003 carry enemy robot HP

    @property
    def map_bytes(self) -> int:
        return MAP_LAYOUT_BYTES[self.map_layout.value]

    @property
    def map_slots(self) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """(enemy slots, ally slots) of the 0x0305 layout; both empty for single-target layouts."""
        return MAP_LAYOUTS[self.map_layout.value]

    @property
    def single_target(self) -> bool:
        return self.map_layout.value.startswith("single")

    @property
    def has_progress(self) -> bool:
        return self.mark_rule.value != "distance"

    def facts(self) -> dict[str, Fact]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "season"}

    def replace(self, **values) -> "SeasonRules":
        """A copy with some values changed (configurable items: ``rules(2026).replace(score_wrong_per_s=-5)``)."""
        new = {k: dataclasses.replace(getattr(self, k), value=v, note="overridden") for k, v in values.items()}
        return dataclasses.replace(self, **new)


# --- shared entries --------------------------------------------------------------------------------------------------
_TEAM_2026 = "practice §3.5 (team summary of the 2026 manual V1.4.0)"
_PROGRESS_UP = _f(5.0, _TEAM_2026, True, "+5/s while correctly marked")
_PROGRESS_DOWN = _f(-10.0, _TEAM_2026, True, "-10/s while wrong or not sent")
_SCORE_UP = _f(5.0, _TEAM_2026, True, "issue #20 reads the +5/s as points; configurable")
_SCORE_DOWN = _f(-10.0, _TEAM_2026, True, "issue #20 reads the -10/s as points; configurable")
_RADIUS_GUESS = _f(0.6, "practice §3.1 (2023 rule carried over)", True, "no later metre threshold found")
_LINK = _f(5120, "[S2] 2026 radar receive budget per 1000 ms, used as the whole-link budget", True, "line rate 11520 B/s")


def _old(season: int, layout: str, radius: Fact) -> SeasonRules:
    return SeasonRules(
        season=season,
        map_layout=_f(layout, "[S7]", True, "season mapping of the single-target layouts is approximate"),
        map_hz=_f(10.0, "[S5]", True, "10 Hz stated for 2024; assumed earlier"),
        interaction_hz=_f(10.0, "[S5]", True),
        interaction_bytes_per_s=_f(3720, "[S2] (2026 figure for non-radar robots)", True),
        interaction_max_content=_f(112, "[S1] [S2]"),
        link_bytes_per_s=_LINK,
        mark_rule=_f("distance", "practice §3.1", season != 2023),
        mark_radius_m=radius,
        progress_max=_f(None, "no 0x020C before 2024", True),
        vulnerable_at=_f(None, "no vulnerability on the link before 2024", True),
        progress_up_per_s=_f(None, "", True),
        progress_down_per_s=_f(None, "", True),
        score_correct_per_s=_SCORE_UP,
        score_wrong_per_s=_SCORE_DOWN,
        mark_feedback_bytes=_f(None, "no 0x020C before 2024", True),
        radar_info_bytes=_f(None, "no 0x020E before 2024", True),
        radar_cmd_bytes=_f(None, "no 0x0121 before 2024", True),
        dv_semantics=_f(None, "", True),
        dv_max_chances=_f(0, "", True),
        dv_duration_s=_f(None, "", True),
        game_status_bytes=_f(11, "[S1] gives 3 bytes (2020); 11 from 2024 [S5]", True),
        hp_bytes=_f(32, "[S1] [S5]"),
        hp_enemy_robots=_f(True, "[S1] [S5]"),
    )


def _progress(season: int) -> SeasonRules:
    y2025 = season == 2025
    return SeasonRules(
        season=season,
        map_layout=_f("all24", "[S5] V1.6.3; practice §3.2 (arrived mid-2024)", y2025, "2025: same size believed"),
        map_hz=_f(10.0, "[S5]", y2025),
        interaction_hz=_f(10.0, "[S5] (comment)", True),
        interaction_bytes_per_s=_f(3720, "[S2] (2026 figure for non-radar robots)", True),
        interaction_max_content=_f(112, "[S1] [S2] [S5]"),
        link_bytes_per_s=_LINK,
        mark_rule=_f("progress", "[S5] 0x020C: 6 x u8 per-robot progress", y2025),
        mark_radius_m=_RADIUS_GUESS,
        progress_max=_f(120, "practice §3.3 (several team headers: 0..120)", True),
        vulnerable_at=_f(100, "practice §3.3 (ZJU header: exact value only from 100)", True),
        progress_up_per_s=_PROGRESS_UP,
        progress_down_per_s=_PROGRESS_DOWN,
        score_correct_per_s=_SCORE_UP,
        score_wrong_per_s=_SCORE_DOWN,
        mark_feedback_bytes=_f(6, "[S5]", y2025),
        radar_info_bytes=_f(1, "[S5]"),
        radar_cmd_bytes=_f(1, "[S5] 1-byte radar_cmd", y2025),
        dv_semantics=_f("counter", "[S2] (2026 text); assumed for 1-byte radar_cmd", True),
        dv_max_chances=_f(2, "[S5] 0x020E bits 0-1"),
        dv_duration_s=_f(10.0, "recollection of the 2024 manual", True),
        game_status_bytes=_f(11, "[S5]"),
        hp_bytes=_f(32, "[S5]; 2025 [S3b]", y2025),
        hp_enemy_robots=_f(True, "[S5]; 2025 [S3b]", y2025),
    )


def _y2026() -> SeasonRules:
    return SeasonRules(
        season=2026,
        map_layout=_f("all48", "[S2] 表1-36, [S4] (V1.3.0 revision)"),
        map_hz=_f(5.0, "[S2] [S4]"),
        interaction_hz=_f(30.0, "[S2] 表1-25"),
        interaction_bytes_per_s=_f(5120, "[S2] radar/sentry receive budget per 1000 ms"),
        interaction_max_content=_f(112, "[S2] (frame <= 127 bytes)"),
        link_bytes_per_s=_LINK,
        mark_rule=_f("progress_bits", "[S2] 表1-22: bit per enemy robot at progress >= 100"),
        mark_radius_m=_RADIUS_GUESS,
        progress_max=_f(150, _TEAM_2026, True),
        vulnerable_at=_f(100, "[S2] 表1-22"),
        progress_up_per_s=_PROGRESS_UP,
        progress_down_per_s=_PROGRESS_DOWN,
        score_correct_per_s=_SCORE_UP,
        score_wrong_per_s=_SCORE_DOWN,
        mark_feedback_bytes=_f(2, "[S2] V2.0.0 bitfield"),
        radar_info_bytes=_f(1, "[S2] 表1-24"),
        radar_cmd_bytes=_f(8, "[S2] 表1-34"),
        dv_semantics=_f("counter", "[S2] 表1-34: raise radar_cmd by exactly 1 per request; queued while one is active"),
        dv_max_chances=_f(2, "[S2] 表1-24"),
        dv_duration_s=_f(30.0, _TEAM_2026, True),
        game_status_bytes=_f(11, "[S2] 表1-6"),
        hp_bytes=_f(20, "[S2] 表1-8 (V2.0.0)"),
        hp_enemy_robots=_f(False, "[S2] own side only from 2026"),
    )


SEASONS: dict[int, SeasonRules] = {
    2021: _old(2021, "single14", _f(0.6, "practice §3.1 (2023 figure)", True)),
    2022: _old(2022, "single14", _f(0.6, "practice §3.1 (2023 figure)", True)),
    2023: _old(2023, "single10", _f(0.6, "practice §3.1 (T-DT README)")),
    2024: _progress(2024),
    2025: _progress(2025),
    2026: _y2026(),
}
KNOWN_SEASONS = tuple(sorted(SEASONS))


def rules(season: int) -> SeasonRules:
    """The rules of ``season``; ``KeyError`` naming the known seasons otherwise."""
    try:
        return SEASONS[int(season)]
    except KeyError:
        raise KeyError(f"referee season {season} is not one radarcal knows ({KNOWN_SEASONS[0]}..{KNOWN_SEASONS[-1]})") from None


#: (field name, column heading, unit) of the docs table
_TABLE = [("map_layout", "0x0305 layout", ""), ("map_hz", "0x0305 max", "Hz"), ("interaction_hz", "0x0301 max", "Hz"),
          ("interaction_bytes_per_s", "0x0301 budget", "B/s"), ("link_bytes_per_s", "link budget", "B/s"),
          ("mark_rule", "mark rule", ""), ("mark_radius_m", "mark radius", "m"), ("progress_max", "progress max", ""),
          ("vulnerable_at", "vulnerable at", ""), ("progress_up_per_s", "progress +", "/s"), ("progress_down_per_s", "progress -", "/s"),
          ("score_correct_per_s", "score correct", "/s"), ("score_wrong_per_s", "score wrong", "/s"),
          ("mark_feedback_bytes", "0x020C", "B"), ("radar_cmd_bytes", "0x0121", "B"), ("dv_semantics", "DV request", ""),
          ("dv_max_chances", "DV chances", ""), ("dv_duration_s", "DV lasts", "s"), ("hp_bytes", "0x0003", "B")]  # fmt: skip


def season_table_rows() -> list[list[str]]:
    """Markdown-ready rows: one per table item, one column per season; '?' marks UNCERTAIN values."""
    rows = [["item"] + [str(s) for s in KNOWN_SEASONS]]
    for name, head, unit in _TABLE:
        cells = []
        for s in KNOWN_SEASONS:
            f = getattr(SEASONS[s], name)
            v = "—" if f.value is None else str(f.value)
            cells.append(v + (" ?" if f.uncertain else ""))
        rows.append([head + (f" ({unit})" if unit else "")] + cells)
    return rows
