"""``radarcal synth field``: write a generated radar-station replay folder (docs/field.md)."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, command_line, emit, progress
from radarcal.cli.outputs import replace_folder
from radarcal.errors import InputError

__all__ = ["synth_field"]

# what a replay folder holds (an --overwrite never removes a folder holding anything else)
REPLAY_ENTRIES = ("images", "clouds", "detections.jsonl", "truth.jsonl", "truth.json", "meta.json", "calib.yaml", "calib.sessions", "calib.yaml.*.bak", "cameras")


def _parse_gap(text: str | None, option: str = "--lidar-gap") -> tuple[float, float] | None:
    if not text:
        return None
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise InputError(option, f"expected START:DURATION in seconds, got {text!r}") from None
    if a < 0 or b <= 0:
        raise InputError(option, f"START must be >= 0 and DURATION > 0, got {text!r}")
    return a, b


def _multicam(cameras: str | None, gap: str | None, scene):
    """``--cameras`` / ``--camera-gap`` -> a :class:`MultiCameraConfig` (None: the single-camera replay)."""
    if cameras is None:
        if gap is not None:
            raise InputError("--camera-gap", "needs --cameras")
        return None
    from radarcal.synth.field_cameras import MultiCameraConfig, parse_camera_specs

    try:
        specs = parse_camera_specs(cameras)
    except ValueError as e:
        raise InputError("--cameras", str(e)) from None
    gaps = {}
    if gap is not None:
        name, _, rest = gap.partition(":")
        if name not in [c.name for c in specs]:
            raise InputError("--camera-gap", f"no camera {name!r} in --cameras")
        gaps[name] = _parse_gap(rest, "--camera-gap")
    return MultiCameraConfig(scene, specs, gaps=gaps)


def synth_field(
    out: Path = typer.Argument(..., help="Output replay folder (created)."),
    field: str = typer.Option("rmuc2024", "--field", help="Built-in field name or a YAML/JSON field file."),
    frames: int = typer.Option(300, "--frames", help="Camera frames (30 fps)."),
    seed: int = typer.Option(0, "--seed", help="Random seed (the output is deterministic per seed)."),
    robots: int = typer.Option(6, "--robots", help="Number of robots (0..12)."),
    station: str = typer.Option("red", "--station", help="Whose radar station: red (behind x = 0) or blue (behind x = 28)."),
    lidar_gap: str = typer.Option(None, "--lidar-gap", help="START:DURATION seconds without LiDAR clouds (ground-fallback test)."),
    lidar_points: int = typer.Option(10_000, "--lidar-points", help="Points per 0.1 s LiDAR frame (Mid-70: ~10 k)."),
    image_scale: float = typer.Option(0.5, "--image-scale", help="Render at this fraction of 1280x1024 (faster, smaller), resized to full size."),
    jpeg_quality: int = typer.Option(70, "--jpeg-quality", help="JPEG quality 10..100."),
    image_every: int = typer.Option(1, "--image-every", help="Write an image for every k-th frame only (smaller replay; detections/truth stay per frame)."),
    det_jitter: float = typer.Option(0.0, "--det-jitter", help="σ (px) of jitter on detection box edges."),
    det_dropout: float = typer.Option(0.0, "--det-dropout", help="Probability of a missed detection per robot and frame."),
    cameras: str = typer.Option(None, "--cameras", help="Several cameras: NAME=FOCALmm[:WxH][@X:Y],... e.g. cam0=6mm,cam1=16mm (aim point X:Y in field metres); one folder per camera under cameras/."),
    camera_gap: str = typer.Option(None, "--camera-gap", help="With --cameras: NAME:START:DURATION seconds that camera is unplugged."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace OUT when it holds an earlier (or interrupted) replay."),
    as_json: JsonOpt = False,
) -> None:
    """Generate a RoboMaster field replay: images, LiDAR clouds, detections, truth, calib.yaml."""
    from radarcal.field import load_field
    from radarcal.synth.field import FieldSceneConfig, write_field_replay

    if frames < 1:
        raise InputError("--frames", f"must be >= 1, got {frames}")
    if not 0 <= robots <= 12:
        raise InputError("--robots", f"expected 0..12, got {robots}")
    if not 0.05 <= image_scale <= 1.0:
        raise InputError("--image-scale", f"expected 0.05..1, got {image_scale}")
    if not 10 <= jpeg_quality <= 100:
        raise InputError("--jpeg-quality", f"expected 10..100, got {jpeg_quality}")
    if station not in ("red", "blue"):
        raise InputError("--station", f"expected red or blue, got {station!r}")
    if image_every < 1:
        raise InputError("--image-every", f"must be >= 1, got {image_every}")
    if lidar_points < 1:
        raise InputError("--lidar-points", f"must be >= 1, got {lidar_points}")
    if not 0 <= det_dropout <= 1 or det_jitter < 0:
        raise InputError("--det-dropout/--det-jitter", "dropout must be in 0..1 and jitter >= 0")
    fm = load_field(field)
    for req in ("red_outpost", "blue_outpost", "red_base", "blue_base"):
        if req not in fm.landmarks:
            raise InputError(field, f"field model lacks the landmark {req!r} (needed by radarcal run)")
    cfg = FieldSceneConfig(frames=frames, seed=seed, robots=robots, station=station, lidar_gap=_parse_gap(lidar_gap), lidar_points=lidar_points, image_scale=image_scale, jpeg_quality=jpeg_quality, image_every=image_every, det_jitter_px=det_jitter, det_dropout=det_dropout)
    mc = _multicam(cameras, camera_gap, cfg)
    with replace_folder(out, overwrite, REPLAY_ENTRIES, "replay") as tmp:
        prog = lambda it, description="": progress(it, description, enabled=not as_json)  # noqa: E731
        if mc is not None:
            from radarcal.synth.field_cameras import write_multicam_replay

            summary = write_multicam_replay(tmp, fm, mc, generator=command_line(), progress=prog)
        else:
            summary = write_field_replay(tmp, fm, cfg, generator=command_line(), progress=prog)
    summary["out"] = str(out)

    def human(s: dict) -> None:
        typer.echo(f"wrote {s['out']}: {s['frames']} frames ({s['images']} images), {s['clouds']} clouds ({s['cloud_points']} points), {s['robots']} robots, "
                   f"{s['visible_boxes']} visible robot boxes, {s['bytes'] / 1e6:.1f} MB")
        if s.get("cameras"):
            typer.echo(f"  cameras: {', '.join(s['cameras'])} ({s['detections']} detection boxes)")
        else:
            typer.echo(f"  landmarks in view: {', '.join(s['landmarks_in_image'])}")

    emit(summary, as_json, human)
