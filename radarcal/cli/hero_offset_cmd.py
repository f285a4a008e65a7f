"""``radarcal hero-offset``: the per-match hero range offset (actual - measured), from numbers or a short recording."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal.cli.common import BundleOpt, JsonOpt, command_line, emit, err_console
from radarcal.cli.run_checks import HERO_MAX_SPREAD_M, hero_spread_problem
from radarcal.errors import InputError

__all__ = ["hero_offset", "compute_hero_offset"]


def compute_hero_offset(measured_m: float, actual_m: float) -> float:
    """The fixed per-match correction: actual - measured (added to every later hero range)."""
    return float(actual_m) - float(measured_m)


def hero_offset(
    bundle: BundleOpt = ...,
    measured: float = typer.Option(None, "--measured", help="Hero -> enemy outpost distance radarcal reported (m, without offset)."),
    actual: float = typer.Option(None, "--actual", help="The true distance (m)."),
    replay: Path = typer.Option(None, "--replay", help="Instead of --measured: a short recording (replay folder) with our hero standing at a known point."),
    marker: str = typer.Option(None, "--marker", help="With --replay, instead of --actual: the field landmark the hero stands at."),
    team: str = typer.Option(None, "--team", help="Our colour red|blue (default: bundle runtime.team)."),
    max_spread: float = typer.Option(HERO_MAX_SPREAD_M, "--max-spread", help="With --replay: refuse when the hero range spreads more than this (m, 10-90 %) over the recording."),
    force: bool = typer.Option(False, "--force", help="Store the offset even when the recording's hero range spread says the hero moved."),
    as_json: JsonOpt = False,
) -> None:
    """Store the per-match hero range offset (actual - measured) in the bundle (runtime.hero_range_offset_m)."""
    import math

    import numpy as np

    from radarcal.bundle import load_bundle, save_bundle

    if (measured is None) == (replay is None):
        raise InputError("radarcal hero-offset", "give exactly one of --measured M or --replay DIR")
    if (actual is None) == (marker is None):
        raise InputError("radarcal hero-offset", "give exactly one of --actual A or --marker LANDMARK")
    if marker is not None and replay is None:
        raise InputError("--marker", "needs --replay (a recording with the hero at the marker)")
    if not max_spread > 0:
        raise InputError("--max-spread", f"must be > 0 m, got {max_spread}")
    b = load_bundle(bundle)
    team = team or str(b.runtime.get("team", "red"))
    if team not in ("red", "blue"):
        raise InputError("--team", f"expected red or blue, got {team!r}")
    extra = {}
    if replay is not None:
        measured, extra = _hero_range_from_recording(b, replay, team)
        if marker is not None:
            fm = b.field()
            if fm is None:
                raise InputError(bundle, "no field model in the bundle (needed for --marker)")
            enemy = "blue" if team == "red" else "red"
            for name in (marker, f"{enemy}_outpost"):
                if name not in fm.landmarks:
                    raise InputError("--marker", f"no landmark {name!r} in the field model ({', '.join(sorted(fm.landmarks))})")
            actual = float(np.linalg.norm(fm.landmarks[marker][:2] - fm.landmarks[f"{enemy}_outpost"][:2]))
    for name, v in (("--measured", measured), ("--actual", actual)):
        if not math.isfinite(v) or v <= 0 or v > 60:
            raise InputError(name, f"expected a distance in metres (0..60], got {v}")
    problem = hero_spread_problem(extra["measured_spread_m"], max_spread) if replay is not None else None
    if problem and not force:
        raise InputError(replay, f"{problem}; nothing stored (--force to store it anyway)")
    if problem:
        extra["warnings"] = [problem]
        err_console.print(f"warning: {problem} (stored because of --force)", style="yellow")
    old = float(b.runtime.get("hero_range_offset_m", 0.0))
    off = compute_hero_offset(measured, actual)
    b.runtime["hero_range_offset_m"] = off
    b.runtime.pop("hero_range_offset_forced", None)
    if problem:
        b.runtime["hero_range_offset_forced"] = problem
    b.runtime["hero_range_offset_note"] = f"{command_line()}"
    save_bundle(b, bundle)
    emit({"bundle": str(bundle), "hero_range_offset_m": off, "previous_m": old, "measured_m": measured, "actual_m": actual, **extra}, as_json,
         lambda s: typer.echo(f"hero range offset {s['hero_range_offset_m']:+.3f} m (actual {s['actual_m']:.3f} - measured {s['measured_m']:.3f}) "
                              f"stored in {s['bundle']} (was {s['previous_m']:+.3f} m)"))  # fmt: skip


def _hero_range_from_recording(b, replay: Path, team: str) -> tuple[float, dict]:
    """Median hero -> enemy outpost range (without offset) over a recording, with its spread."""
    import numpy as np

    from radarcal.runtime.detector import DetectionsFile
    from radarcal.runtime.loop import Pipeline, RunConfig, pick_frames
    from radarcal.runtime.loop import run as run_loop
    from radarcal.runtime.sources import merge_by_time, open_replay

    rep = open_replay(replay)
    if rep.detections is None:
        raise InputError(replay, "the recording has no detections.jsonl")
    cam, lidar = pick_frames(b, rep.meta.get("camera"), rep.meta.get("lidar") if rep.clouds else None, bool(rep.clouds))
    pipe = Pipeline(b, cam, lidar, RunConfig.from_bundle(b, team=team, hero_range_offset_m=0.0))
    dets = DetectionsFile.read(rep.detections)
    ranges: list[float] = []
    run_loop(pipe, merge_by_time(rep.camera_frames(), rep.cloud_frames() if lidar else None), lambda f: dets.lookup(f.t, f.name), status=False,
             on_frame=lambda n, res: ranges.append(res.hero_range_m) if res.hero_range_m is not None else None)  # fmt: skip
    if len(ranges) < 5:
        raise InputError(replay, f"our hero ({team}_1) was located in only {len(ranges)} frames")
    r = np.asarray(ranges)
    return float(np.median(r)), {"frames_with_hero": len(r), "measured_spread_m": float(np.percentile(r, 90) - np.percentile(r, 10))}
