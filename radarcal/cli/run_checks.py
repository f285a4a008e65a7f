"""Match-time settings of ``radarcal run`` / ``radarcal hero-offset`` checked before the loop starts, so that none
fails silently: the referee serial port exists, the season is one the referee module knows, a run without LiDAR
clouds says so, and a hero range measured on a hero that moved is not stored without ``--force``."""

from __future__ import annotations

import os

from radarcal.errors import InputError

__all__ = ["check_serial_port", "check_season", "run_warnings", "hero_spread_problem", "HERO_MAX_SPREAD_M"]

HERO_MAX_SPREAD_M = 0.5  # p90 - p10 of the hero range over a recording of a hero standing still (LiDAR: a few cm)


def _ports() -> list[str]:
    try:
        from serial.tools import list_ports

        return sorted(p.device for p in list_ports.comports())
    except Exception:  # noqa: BLE001 - listing is a hint only
        return []


def check_serial_port(port: str) -> None:
    """A device path that does not exist is an error (a URL such as ``socket://`` or ``rfc2217://`` is left to pyserial)."""
    if "://" in port:
        return
    if not os.path.exists(port):
        known = ", ".join(_ports()) or "none found"
        raise InputError("--serial", f"no serial port {port!r} (ports: {known})")


def check_season(season: int, source: str) -> None:
    from radarcal.runtime.referee import KNOWN_SEASONS

    if int(season) not in KNOWN_SEASONS:
        raise InputError(source, f"referee season {season} is not one radarcal knows ({KNOWN_SEASONS[0]}..{KNOWN_SEASONS[-1]})")


def run_warnings(has_clouds: bool, no_lidar: bool, is_replay: bool) -> list[str]:
    """Warnings for the start of a run (printed on stderr and kept in the summary)."""
    out = []
    if not has_clouds and not no_lidar:
        where = "the replay has no clouds/" if is_replay else "no --clouds given"
        out.append(f"{where}: ground-ray localisation only (metres of error at range instead of decimetres); --no-lidar silences this")
    return out


def hero_spread_problem(spread_m: float, max_spread_m: float = HERO_MAX_SPREAD_M) -> str | None:
    """Why a hero range measured over a recording should not be stored, or None."""
    if not spread_m <= max_spread_m:
        return (f"the hero range spreads {spread_m:.2f} m over the recording (10-90 %; more than {max_spread_m:g} m): "
                "the hero moved or was mislocated, so the median is not its range at the marker")
    return None
