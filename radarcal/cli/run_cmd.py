"""``radarcal run`` (match-time localisation loop): parses the options, runs the pre-start checks, calls
:mod:`radarcal.runtime.match_run` and prints the summary. ``radarcal hero-offset`` lives in
:mod:`radarcal.cli.hero_offset_cmd`."""

from __future__ import annotations

import math
from pathlib import Path

import typer

from radarcal.cli.common import CloudTopicOpt, JsonOpt, ReplayBundleOpt, emit, err_console
from radarcal.cli.marking_options import DvAtOpt, DvEnemiesInHalfOpt, DvOnDartOpt, DvOnKeyOpt, GuessOpt, RosterOpt, marking_overrides
from radarcal.cli.hero_offset_cmd import compute_hero_offset, hero_offset  # noqa: F401 - registered from here by cli/main.py
from radarcal.cli.outputs import check_outputs
from radarcal.cli.run_checks import check_serial_port, check_season, run_warnings
from radarcal.errors import InputError
from radarcal.runtime.match_run import health_text, live_lidars  # noqa: F401 - public names of this command
from radarcal.runtime.summary_text import run_summary_lines

__all__ = ["run", "hero_offset", "compute_hero_offset"]


def run(
    bundle: ReplayBundleOpt = None,
    replay: Path = typer.Option(None, "--replay", help="A recording (`radarcal record`) or a replay folder (images/, clouds/, detections.jsonl) as written by `radarcal synth field`."),
    video: list[str] = typer.Option(None, "--video", help="Camera: video file, image folder, device index or URL; several cameras: NAME=SRC each (--video cam0=SRC --video cam1=SRC)."),
    clouds: list[str] = typer.Option(None, "--clouds", help="LiDAR: folder of PCD/npy/bin, ROS1/ROS2 bag, or a live Livox [NAME=]livox://IP (livox1:// SDK 1, livox2:// SDK 2; repeat for several LiDARs, merged in the frame of --lidar)."),
    cloud_topic: CloudTopicOpt = None,
    cloud_offset: str = typer.Option("0", "--cloud-time-offset", help="Camera clock minus LiDAR clock, seconds (t_camera = t_cloud + offset; 0: one clock, e.g. a replay "
                                     "or a bag with both topics), or 'first': the first cloud pairs with the first frame."),
    detector: Path = typer.Option(None, "--detector", help="Robot detector ONNX (YOLOv5, YOLOv8/YOLO11/YOLOv12, end-to-end or raw heads)."),
    names: Path = typer.Option(None, "--names", help="Robot class names: YOLO data.yaml, text file, JSON/YAML list (default: the model's metadata)."),
    detector_layout: str = typer.Option(None, "--detector-layout", help="Output layout yolov5|yolov8|end2end|raw (default: from the graph)."),
    anchors: Path = typer.Option(None, "--anchors", help="Raw-head layout: YAML with anchors: (and strides:), e.g. the YOLOv5 model YAML."),
    armour: Path = typer.Option(None, "--armour", help="Armour detector ONNX run on each robot crop (grey/dead class marks the robot dead)."),
    armour_names: Path = typer.Option(None, "--armour-names", help="Armour class names file (default: the model's metadata)."),
    number: Path = typer.Option(None, "--number", help="Number classifier ONNX run on each armour crop (on each robot crop without --armour)."),
    number_names: Path = typer.Option(None, "--number-names", help="Number class names file (default: the model's metadata)."),
    providers: str = typer.Option("cpu", "--providers", help="Inference providers in order, e.g. tensorrt,cuda,cpu (needs onnxruntime-gpu), or openvino (the openvino package: bf16 / int8 on Intel CPUs)."),
    detect_ahead: bool = typer.Option(True, "--detect-ahead/--no-detect-ahead", help="Run the detector one frame ahead in a thread (throughput; +1 frame latency)."),
    conf: float = typer.Option(0.25, "--conf", help="Detector confidence threshold."),
    threads: int = typer.Option(0, "--threads", help="onnxruntime intra-op threads per model (0 = its default)."),
    detect_workers: int = typer.Option(1, "--detect-workers", min=1, max=8, help="Frames detected at once (with --detect-ahead; on 2 cores 2 workers with --threads 1 ran fastest: docs/runtime.md Speed)."),
    roi_windows: int = typer.Option(None, "--roi-windows", help="Native-resolution detector windows per frame around far tracks (0 = off; default auto: 2 on frames >= 3x the detector input, e.g. 12 MP, else 0)."),
    detections: Path = typer.Option(None, "--detections", help="Precomputed detections (JSON lines, one per frame)."),
    serial: str = typer.Option(None, "--serial", help="Referee serial port, e.g. /dev/ttyUSB0 (115200 8N1); replaying a recording also 'pty' (a new pseudo-terminal) or 'dry-run' (default)."),
    out: Path = typer.Option(None, "--out", help="Per-frame JSON lines (robots in field coordinates)."),
    minimap: Path = typer.Option(None, "--minimap", help="Minimap output: .png (last frame + trails) or .mp4."),
    camera: str = typer.Option(None, "--camera", help="Camera name in the bundle (default: the only one); on a multi-camera replay NAME[,NAME]: which of its cameras."),
    lidar: str = typer.Option(None, "--lidar", help="LiDAR name in the bundle (default: the only one with an extrinsic)."),
    team: str = typer.Option(None, "--team", help="Our colour red|blue (default: bundle runtime.team, then the referee link)."),
    season: int = typer.Option(None, "--season", help="Referee protocol season (0x0305 layout, rate limits); default bundle runtime.referee_season."),
    sentry_xy: str = typer.Option(None, "--sentry-xy", help="Our sentry's field position X,Y (m) when it is not tracked."),
    max_frames: int = typer.Option(None, "--max-frames", help="Stop after this many frames."),
    record: Path = typer.Option(None, "--record", help="Live run: also record every input (LiDAR packets, camera frames, serial bytes) into this new folder (replay: --replay)."),
    realtime_video: bool = typer.Option(False, "--realtime-video", help="Play a --video file at its frame rate with receive times, as a live camera (station tests)."),
    no_lidar: bool = typer.Option(False, "--no-lidar", help="Ignore clouds (ground-ray localisation only)."),
    localise: str = typer.Option("auto", "--localise", help="auto (LiDAR tracks + box fallback) | lidar (LiDAR tracks only) | box (box depth, the 2022 way)."),
    no_camera: bool = typer.Option(False, "--no-camera", help="Ignore detections: LiDAR only (every track unlabelled)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No status line."),
    ui: str = typer.Option(None, "--ui", help="Serve the live operator console on [HOST:]PORT (default host 127.0.0.1; docs/console.md)."),
    speed: float = typer.Option(None, "--speed", help="Replay at this multiple of real time (default: 1 with --ui, else as fast as possible; 0 = unpaced)."),
    field_pose: str = typer.Option("auto", "--field-pose", help="Camera field pose: chain (lidar-field T_field_lidar · T_lidar_cam), pnp (field-pnp), auto (chain when lidar-field converged, else pnp)."),
    drift_check_s: float = typer.Option(0.0, "--drift-check-s", help="Every this many seconds re-register the LiDAR's static points to the field and warn when it moved > 2 cm / 0.1 deg (0 = off)."),
    roster: RosterOpt = True,
    guess: GuessOpt = True,
    dv_at: DvAtOpt = None,
    dv_enemies_in_half: DvEnemiesInHalfOpt = None,
    dv_on_key: DvOnKeyOpt = None,
    dv_on_dart: DvOnDartOpt = False,
    as_json: JsonOpt = False,
) -> None:
    """Localise robots on the field from camera(s) + LiDAR, track them, draw the minimap, talk to the referee system."""
    from dataclasses import fields

    from radarcal.cli.lidar_field_cmd import resolve_field_pose
    from radarcal.io.recording import is_recording
    from radarcal.runtime.match_run import RunOptions, execute, plan_run, validate_options

    given = dict(locals())
    o = RunOptions(**{f.name: given[f.name] for f in fields(RunOptions) if f.name in given})
    o.video, o.clouds, o.status = list(video or []), list(clouds or []), not quiet and not as_json
    validate_options(o)
    o.marking = marking_overrides(roster, guess, dv_at, dv_enemies_in_half, dv_on_key, dv_on_dart)
    if replay is not None and is_recording(replay):
        from radarcal.cli.run_recording import run_recording

        return run_recording(replay, bundle=bundle, speed=speed or 0.0, detector=detector, names=names, conf=conf, threads=threads, detections=detections, serial=serial,
                             out=out, minimap=minimap, camera=camera, lidar=lidar, team=team, season=season, max_frames=max_frames, no_lidar=no_lidar,
                             quiet=quiet, as_json=as_json, sentry_xy=sentry_xy, marking=o.marking)  # fmt: skip
    o.cloud_offset, o.sentry_xy, o.drift_check_s = _cloud_offset(cloud_offset), _sentry_xy(sentry_xy), _drift_s(drift_check_s)
    plan = plan_run(o)
    check_season(plan.cfg.season, "--season" if season is not None else f"{plan.bundle_path}: runtime.referee_season")
    check_outputs(plan.bundle_path, [("track file", out), ("minimap", minimap)], plan.bundle, inputs=plan.inputs)
    if serial:
        check_serial_port(serial)
    plan.warnings[:0] = run_warnings(plan.has_clouds, no_lidar, replay is not None)
    for w in plan.warnings:
        err_console.print(f"warning: {w}", style="yellow")
    summary = execute(plan, lambda b, cam, lid: resolve_field_pose(b, cam, lid, field_pose), lambda text: err_console.print(text, highlight=False, markup=False))
    emit(summary, as_json, lambda s: typer.echo("\n".join(run_summary_lines(s))))


def _drift_s(v: float) -> float:
    import math

    if not math.isfinite(v) or v < 0:
        raise InputError("--drift-check-s", f"expected seconds >= 0 (0 = off), got {v}")
    return float(v)


def _cloud_offset(text: str) -> float | str:
    """``--cloud-time-offset``: seconds, or ``first``."""
    if text.strip().lower() == "first":
        return "first"
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise InputError("--cloud-time-offset", f"expected seconds or 'first', got {text!r}")
    return v


def _sentry_xy(text: str | None) -> tuple[float, float] | None:
    if not text:
        return None
    try:
        sxy = tuple(float(v) for v in text.split(","))
    except ValueError:
        sxy = ()
    if len(sxy) != 2:
        raise InputError("--sentry-xy", f"expected X,Y in metres, got {text!r}")
    return sxy
