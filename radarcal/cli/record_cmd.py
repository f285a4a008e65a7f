"""``radarcal record``: record a match's raw inputs (LiDAR packets, camera frames, referee serial bytes) for replay."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, emit
from radarcal.errors import InputError
from radarcal.io.source_specs import split_named

__all__ = ["record"]


def record(
    out: Path = typer.Argument(..., help="Recording folder to create (must not exist or be empty)."),
    clouds: list[str] = typer.Option(None, "--clouds", help="LiDAR [NAME=]livox://IP | livox1://IP | livox2://IP (repeat for several; names default lidar0, lidar1 ...)."),
    video: str = typer.Option(None, "--video", help="Camera: device index, URL, or a video file (read at its frame rate)."),
    camera: str = typer.Option("cam0", "--camera", help="Name of the camera in the recording (as in the bundle)."),
    serial: str = typer.Option(None, "--serial", help="Referee serial port (e.g. /dev/ttyUSB0 or a /dev/pts/N pseudo-terminal)."),
    bundle: Path = typer.Option(None, "--bundle", "-b", help="Bundle in use (its path and sha256 go into the manifest)."),
    duration: float = typer.Option(None, "--duration", help="Stop after this many seconds (default: Ctrl-C, or the end of a video file)."),
    jpeg_quality: int = typer.Option(90, "--jpeg-quality", help="JPEG quality of the recorded frames."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No status line."),
    as_json: JsonOpt = False,
) -> None:
    """Record raw LiDAR packets, camera frames (JPEG) and serial bytes with host receive times (replay: `radarcal run --replay OUT`)."""
    from radarcal.io.livox import parse_livox_url
    from radarcal.runtime.recording import record as record_session

    if not clouds and not video and not serial:
        raise InputError("radarcal record", "nothing to record: give --clouds, --video and/or --serial")
    if bundle is not None and not bundle.is_file():
        raise InputError(bundle, "bundle not found")
    if not 1 <= jpeg_quality <= 100:
        raise InputError("--jpeg-quality", "expected 1..100")
    named = [split_named(c, f"lidar{i}") for i, c in enumerate(clouds or [])]
    for _name, spec in named:
        if parse_livox_url(spec)["listen_port"] is not None:
            raise InputError(spec, "record starts the LiDAR itself: give livox://IP (no port)")
    if len({n for n, _ in named}) != len(named):
        raise InputError("--clouds", "two LiDARs with the same name")
    status = None if quiet or as_json else (lambda line: sys.stderr.write(line + "\n"))
    summary = record_session(out, named, video, camera, serial, bundle, duration, jpeg_quality, status)

    def human(s: dict) -> None:
        typer.echo(f"recorded {out}: {s['duration_s'] or 0:.1f} s, {s['megabytes']:.1f} MB, " + ", ".join(f"{k} {v['records']}" for k, v in s["streams"].items())
                   + f"; camera frames dropped {s['dropped_camera_frames']}")  # fmt: skip

    emit(summary, as_json, human)
