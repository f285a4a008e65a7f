"""``radarcal run --replay RECORDING``: the match loop over a recording made by ``radarcal record``
(:func:`radarcal.runtime.recording.replay_recording`).

The recorded LiDAR packets go through the live decoder (same clouds), camera frames keep their receive times, the
recorded referee bytes drive the referee state at their times; what the loop sends goes to ``--serial`` (a port,
``pty`` or ``dry-run``, the default). ``--speed 1`` paces the replay at real speed, ``0`` runs as fast as possible:
the output is the same either way, and two replays write byte-identical ``--out`` files (no wall-clock latencies in
them)."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from radarcal.cli.common import emit

__all__ = ["run_recording"]


def run_recording(replay: Path, *, quiet: bool, as_json: bool, **options) -> None:
    """Run :func:`~radarcal.runtime.recording.replay_recording` with the ``run`` options and print its summary."""
    from radarcal.runtime.recording import replay_recording

    summary = replay_recording(replay, status=not quiet and not as_json, log=lambda s: sys.stderr.write(s + "\n"), **options)

    def human(s: dict) -> None:
        typer.echo(f"{s['frames']} frames in {s['wall_s']:.1f} s ({s['fps']:.1f} FPS), {s['clouds']} clouds from {', '.join(s['lidars']) or 'no LiDAR'}; "
                   f"referee frames replayed {s['serial']['received']}, sent {s['serial']['sent']} ({s['serial']['output']})")  # fmt: skip
        rf = s["robot_frames"]
        typer.echo(f"  robot positions: {rf.get('depth', 0)} from LiDAR depth, {rf.get('ground', 0)} from the ground ray, {rf.get('predicted', 0)} predicted")
        if s.get("out"):
            typer.echo(f"  tracks -> {s['out']}")

    emit(summary, as_json, human)
