"""``radarcal run --replay RECORDING``: the match loop over a recording made by ``radarcal record``.

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
from radarcal.errors import InputError

__all__ = ["run_recording"]


def run_recording(replay: Path, *, bundle, speed, detector, names, conf, threads, detections, serial, out, minimap, camera, lidar, team, season,
                  max_frames, no_lidar, quiet, as_json, sentry_xy, marking: dict | None = None) -> None:  # fmt: skip
    from radarcal.bundle import load_bundle
    from radarcal.io.recording import file_sha256, open_recording, paced
    from radarcal.runtime.detector import DetectionsFile, OnnxDetector, read_class_names
    from radarcal.runtime.loop import Pipeline, RunConfig, pick_frames
    from radarcal.runtime.loop import run as run_loop
    from radarcal.runtime.replay import (
        ReplayLink,
        advancing,
        merged_recorded_clouds,
        open_output_port,
        recorded_frames,
    )
    from radarcal.runtime.sources import merge_by_time

    rec = open_recording(replay)
    man = rec.manifest
    if bundle is None:
        if not man.get("bundle"):
            raise InputError("--bundle", "required (the recording names no bundle)")
        bundle = Path(man["bundle"]["path"])
    b = load_bundle(bundle)
    if man.get("bundle") and Path(bundle).is_file() and file_sha256(bundle) != man["bundle"]["sha256"]:
        sys.stderr.write(f"warning: {bundle}: not the bundle the recording was made with (sha256 differs)\n")
    cams = [s["name"] for s in rec.sensors("camera")]
    if not cams:
        raise InputError(replay, "the recording has no camera stream")
    lidars = [s["name"] for s in rec.sensors("lidar") if s.get("sdk")]
    has_clouds = bool(lidars) and not no_lidar
    cam_name, lidar_name = pick_frames(b, camera or (cams[0] if cams[0] in b.cameras else None), lidar or (lidars[0] if has_clouds and lidars[0] in b.sensors else None), has_clouds)
    if cam_name not in cams:
        raise InputError(replay, f"no camera stream {cam_name!r} in the recording ({', '.join(cams)})")
    T = {}
    for n in lidars:
        if has_clouds and n != lidar_name:
            if not b.has_T(lidar_name, n):
                raise InputError(bundle, f"no extrinsic T_{lidar_name}_{n} for the recorded LiDAR {n!r}")
            T[n] = b.T(lidar_name, n)
    sxy = tuple(float(v) for v in sentry_xy.split(",")) if sentry_xy else None
    cfg = RunConfig.from_bundle(b, team=team, season=season, sentry_xy=sxy, **(marking or {}))
    pipe = Pipeline(b, cam_name, lidar_name if has_clouds else None, cfg)
    if detector is not None:
        det = OnnxDetector(detector, read_class_names(names) if names else None, conf_thres=conf, threads=threads)
        def detect(f):
            return det(f.load())
    elif detections is not None:
        dfile = DetectionsFile.read(detections)
        def detect(f):
            return dfile.lookup(f.t, f.name)
    else:
        raise InputError("radarcal run", "no detector: give --detector model.onnx or --detections FILE")
    frames = paced(recorded_frames(rec, cam_name), lambda f: f.t, speed)
    clouds = merged_recorded_clouds(rec.clouds(), T) if has_clouds else None
    out_link = None
    port = open_output_port(serial)
    from radarcal.runtime.serial_link import SerialLink

    if port is not None:
        out_link = SerialLink(getattr(port, "name", "dry-run"), season=cfg.season, serial_factory=lambda *_: port).start()
    else:
        out_link = SerialLink(serial, season=cfg.season).start()
    link = ReplayLink([(t, buf) for t, d, buf in rec.serial_records() if d == 0], out_link)
    try:
        from radarcal.runtime.marking import Marking

        summary = run_loop(pipe, advancing(merge_by_time(frames, clouds), link), detect, out, minimap, link, status=not quiet and not as_json,
                           max_frames=max_frames, write_latency=False, marking=Marking(cfg))  # fmt: skip
    finally:
        link.close()
    summary.pop("results")
    summary.update({"bundle": str(bundle), "recording": str(replay), "camera": cam_name, "lidar": lidar_name if has_clouds else None, "lidars": lidars,
                    "out": str(out) if out else None, "team": link.state.team or cfg.team, "season": cfg.season,
                    "serial": {"output": serial or "dry-run", **link.snapshot()}, "recorded_health": man.get("health")})  # fmt: skip

    def human(s: dict) -> None:
        typer.echo(f"{s['frames']} frames in {s['wall_s']:.1f} s ({s['fps']:.1f} FPS), {s['clouds']} clouds from {', '.join(lidars) or 'no LiDAR'}; "
                   f"referee frames replayed {s['serial']['received']}, sent {s['serial']['sent']} ({s['serial']['output']})")  # fmt: skip
        rf = s["robot_frames"]
        typer.echo(f"  robot positions: {rf.get('depth', 0)} from LiDAR depth, {rf.get('ground', 0)} from the ground ray, {rf.get('predicted', 0)} predicted")
        if s.get("out"):
            typer.echo(f"  tracks -> {s['out']}")

    emit(summary, as_json, human)
