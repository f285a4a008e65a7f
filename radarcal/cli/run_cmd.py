"""``radarcal run`` (match-time localisation loop) and ``radarcal hero-offset`` (per-match hero range offset)."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, command_line, emit, err_console
from radarcal.errors import InputError

__all__ = ["run", "hero_offset", "compute_hero_offset"]


def run(
    bundle: Path = typer.Option(None, "--bundle", "-b", help="Calibration bundle (default: calib.yaml inside --replay)."),
    replay: Path = typer.Option(None, "--replay", help="A recording (`radarcal record`) or a replay folder (images/, clouds/, detections.jsonl) as written by `radarcal synth field`."),
    speed: float = typer.Option(0.0, "--speed", help="Replay of a recording: 1 = real speed, 2 = twice as fast, 0 = as fast as possible."),
    video: str = typer.Option(None, "--video", help="Camera: video file, image folder, device index or URL."),
    clouds: list[str] = typer.Option(None, "--clouds", help="LiDAR: folder of PCD/npy/bin, ROS1/ROS2 bag, or a live Livox [NAME=]livox://IP (livox1:// SDK 1, livox2:// SDK 2; repeat for several LiDARs, merged in the frame of --lidar)."),
    cloud_topic: str = typer.Option(None, "--cloud-topic", help="Bag topic (default: every Livox CustomMsg / PointCloud2 topic)."),
    cloud_offset: float = typer.Option(0.0, "--cloud-time-offset", help="Seconds added to cloud times before pairing with frames."),
    detector: Path = typer.Option(None, "--detector", help="YOLOv5-style ONNX model."),
    names: Path = typer.Option(None, "--names", help="Class names file (default: the model's metadata)."),
    conf: float = typer.Option(0.25, "--conf", help="Detector confidence threshold."),
    threads: int = typer.Option(0, "--threads", help="onnxruntime intra-op threads (0 = its default)."),
    detections: Path = typer.Option(None, "--detections", help="Precomputed detections (JSON lines, one per frame)."),
    serial: str = typer.Option(None, "--serial", help="Referee serial port, e.g. /dev/ttyUSB0 (115200 8N1); replaying a recording also 'pty' (a new pseudo-terminal) or 'dry-run' (default)."),
    out: Path = typer.Option(None, "--out", help="Per-frame JSON lines (robots in field coordinates)."),
    minimap: Path = typer.Option(None, "--minimap", help="Minimap output: .png (last frame + trails) or .mp4."),
    camera: str = typer.Option(None, "--camera", help="Camera name in the bundle (default: the only one)."),
    lidar: str = typer.Option(None, "--lidar", help="LiDAR name in the bundle (default: the only one with an extrinsic)."),
    team: str = typer.Option(None, "--team", help="Our colour red|blue (default: bundle runtime.team, then the referee link)."),
    season: int = typer.Option(None, "--season", help="Referee protocol season (0x0305 layout, rate limits); default bundle runtime.referee_season."),
    sentry_xy: str = typer.Option(None, "--sentry-xy", help="Our sentry's field position X,Y (m) when it is not tracked."),
    max_frames: int = typer.Option(None, "--max-frames", help="Stop after this many frames."),
    record: Path = typer.Option(None, "--record", help="Live run: also record every input (LiDAR packets, camera frames, serial bytes) into this new folder (replay: --replay)."),
    realtime_video: bool = typer.Option(False, "--realtime-video", help="Play a --video file at its frame rate with receive times, as a live camera (station tests)."),
    no_lidar: bool = typer.Option(False, "--no-lidar", help="Ignore clouds (ground-ray localisation only)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No status line."),
    as_json: bool = JsonOpt,
) -> None:
    """Localise robots on the field from camera + LiDAR, track them, draw the minimap, talk to the referee system."""
    from radarcal.bundle import load_bundle
    from radarcal.io.recording import is_recording
    from radarcal.runtime.detector import DetectionsFile, OnnxDetector, read_class_names
    from radarcal.runtime.loop import OnlineEvaluator, Pipeline, RunConfig, pick_frames
    from radarcal.runtime.loop import run as run_loop
    from radarcal.runtime.sources import merge_by_time, open_camera, open_clouds, open_replay, prefetch_frames

    if (replay is None) == (video is None):
        raise InputError("radarcal run", "give exactly one of --replay DIR or --video SRC")
    if replay is not None and is_recording(replay):
        from radarcal.cli.run_recording import run_recording

        return run_recording(replay, bundle=bundle, speed=speed, detector=detector, names=names, conf=conf, threads=threads, detections=detections, serial=serial,
                             out=out, minimap=minimap, camera=camera, lidar=lidar, team=team, season=season, max_frames=max_frames, no_lidar=no_lidar,
                             quiet=quiet, as_json=as_json, sentry_xy=sentry_xy)  # fmt: skip
    if record is not None and replay is not None:
        raise InputError("--record", "records live inputs: not with --replay")
    clouds = list(clouds or [])
    live_multi = len(clouds) > 1
    if live_multi and not all("://" in c for c in clouds):
        raise InputError("--clouds", "several --clouds are for live LiDARs (NAME=livox://IP ...)")
    if detector is not None and detections is not None:
        raise InputError("radarcal run", "give at most one of --detector and --detections")
    if team is not None and team not in ("red", "blue"):
        raise InputError("--team", f"expected red or blue, got {team!r}")
    rep = open_replay(replay) if replay is not None else None
    if bundle is None:
        if rep is None or rep.bundle is None:
            raise InputError("--bundle", "required (the replay has no calib.yaml)")
        bundle = rep.bundle
    b = load_bundle(bundle)
    has_clouds = not no_lidar and ((rep is not None and bool(rep.clouds)) or bool(clouds))
    cam_name, lidar_name = pick_frames(b, camera or (rep.meta.get("camera") if rep else None), lidar or (rep.meta.get("lidar") if rep and has_clouds else None), has_clouds)
    sxy = None
    if sentry_xy:
        try:
            sxy = tuple(float(v) for v in sentry_xy.split(","))
        except ValueError:
            sxy = ()
        if len(sxy) != 2:
            raise InputError("--sentry-xy", f"expected X,Y in metres, got {sentry_xy!r}")
    cfg = RunConfig.from_bundle(b, team=team, season=season, sentry_xy=sxy)
    pipe = Pipeline(b, cam_name, lidar_name if has_clouds else None, cfg)

    if detector is not None:
        det = OnnxDetector(detector, read_class_names(names) if names else None, conf_thres=conf, threads=threads)
        detect = lambda f: det(f.load())  # noqa: E731
    else:
        det_path = detections or (rep.detections if rep else None)
        if det_path is None:
            raise InputError("radarcal run", "no detector: give --detector model.onnx or --detections FILE (or a replay with detections.jsonl)")
        dfile = DetectionsFile.read(det_path)
        detect = lambda f: dfile.lookup(f.t, f.name)  # noqa: E731

    recorder = camera_health = None
    if rep is not None:
        frames = rep.camera_frames(need_pixels=detector is not None)
        cloud_src = rep.cloud_frames() if has_clouds else None
    else:
        from radarcal.runtime.replay import paced_video, start_recording

        frames = paced_video(video) if realtime_video else open_camera(video)
        camera_health = getattr(frames, "snapshot", None)
        recorder = start_recording(record, b, cam_name, video, clouds) if record is not None else None
        cloud_src = None
        if has_clouds and any(c.partition("=")[2 if "=" in c.split("://")[0] else 0].startswith("livox") for c in clouds):
            cloud_src = live_lidars(b, clouds, lidar_name, tap=recorder.lidar if recorder else None)
        elif has_clouds:
            cloud_src = open_clouds(clouds[0], cloud_topic)
    if detector is not None:  # the pixels are needed: decode them ahead in a thread (live sources: newest frame only)
        live = video is not None and (video.isdigit() or "://" in video)
        frames = prefetch_frames(frames, latest_only=live)
    if rep is None and recorder is not None:
        from radarcal.runtime.replay import recorded

        frames = recorded(frames, recorder, cam_name)
    link = None
    if serial:
        from radarcal.runtime.serial_link import SerialLink

        factory = None
        if rep is None and recorder is not None:
            from radarcal.runtime.replay import tapped_serial

            factory = tapped_serial(recorder)
        link = SerialLink(serial, season=cfg.season, serial_factory=factory).start()
    evaluator = OnlineEvaluator(rep.truth) if rep is not None and rep.truth is not None else None
    try:
        def sensors_health() -> dict:
            h = dict(cloud_src.sensors_health()) if hasattr(cloud_src, "sensors_health") else {}
            if camera_health is not None:
                h[cam_name] = camera_health()
            return h

        extra = (lambda: health_text(sensors_health())) if hasattr(cloud_src, "sensors_health") or camera_health else None
        summary = run_loop(pipe, merge_by_time(frames, cloud_src, cloud_offset), detect, out, minimap, link, status=not quiet and not as_json,
                           max_frames=max_frames, on_frame=evaluator, status_extra=extra)  # fmt: skip
        if extra is not None:
            summary["health"] = sensors_health()
    finally:
        if link is not None:
            link.close()
        if cloud_src is not None and hasattr(cloud_src, "close"):
            cloud_src.close()
        if recorder is not None:
            from radarcal.runtime.replay import finish_recording

            rec_manifest = finish_recording(recorder, cloud_src, serial)
    summary.pop("results")
    if recorder is not None:
        summary["recording"] = {"out": str(record), "streams": rec_manifest["streams"], "dropped_camera_frames": rec_manifest["dropped_camera_frames"]}
    from radarcal.runtime.sources import SKIPPED

    summary["skipped_inputs"] = len(SKIPPED)
    if evaluator is not None:
        summary["accuracy"] = evaluator.summary()
    summary.update({"bundle": str(bundle), "camera": cam_name, "lidar": lidar_name if has_clouds else None, "out": str(out) if out else None,
                    "minimap": str(minimap) if minimap else None, "team": cfg.team, "season": cfg.season})  # fmt: skip
    if link is not None:
        summary["serial"] = {"port": serial, **link.snapshot(), "disconnects": link.stats.disconnects, "last_error": link.stats.last_error}

    def human(s: dict) -> None:
        typer.echo(f"{s['frames']} frames in {s['wall_s']:.1f} s ({s['fps']:.1f} FPS), {s['clouds']} clouds; camera {s['camera']}, lidar {s['lidar'] or '-'}")
        lat = s["latency_ms"]
        typer.echo("  latency ms (median / p95): " + ", ".join(f"{k} {v['median']:.2f}/{v['p95']:.2f}" for k, v in lat.items()))
        rf = s["robot_frames"]
        typer.echo(f"  robot positions: {rf.get('depth', 0)} from LiDAR depth, {rf.get('ground', 0)} from the ground ray, {rf.get('predicted', 0)} predicted")
        acc = s.get("accuracy")
        if acc and acc["median_m"] is not None:
            typer.echo(f"  vs truth: {acc['located']}/{acc['visible']} visible robots located; error median {acc['median_m']:.3f} m, p95 {acc['p95_m']:.3f} m, max {acc['max_m']:.3f} m")
        if s.get("bad_frames") or s.get("skipped_inputs"):
            typer.echo(f"  skipped: {s['bad_frames']} unreadable frames, {s['skipped_inputs']} unreadable clouds/messages (warnings on stderr)")
        if s.get("out"):
            typer.echo(f"  tracks -> {s['out']}")
        if s.get("minimap"):
            typer.echo(f"  minimap -> {s['minimap']}")

    emit(summary, as_json, human)


def compute_hero_offset(measured_m: float, actual_m: float) -> float:
    """The fixed per-match correction: actual - measured (added to every later hero range)."""
    return float(actual_m) - float(measured_m)


def hero_offset(
    bundle: Path = typer.Option(..., "--bundle", "-b", help="Calibration bundle to update."),
    measured: float = typer.Option(None, "--measured", help="Hero -> enemy outpost distance radarcal reported (m, without offset)."),
    actual: float = typer.Option(None, "--actual", help="The true distance (m)."),
    replay: Path = typer.Option(None, "--replay", help="Instead of --measured: a short recording (replay folder) with our hero standing at a known point."),
    marker: str = typer.Option(None, "--marker", help="With --replay, instead of --actual: the field landmark the hero stands at."),
    team: str = typer.Option(None, "--team", help="Our colour red|blue (default: bundle runtime.team)."),
    as_json: bool = JsonOpt,
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
    b = load_bundle(bundle)
    team = team or str(b.runtime.get("team", "red"))
    if team not in ("red", "blue"):
        raise InputError("--team", f"expected red or blue, got {team!r}")
    extra = {}
    if replay is not None:
        measured, extra = _hero_range_from_recording(b, replay, team)
        if marker is not None:
            from radarcal.field import FieldModel

            if not b.field_model:
                raise InputError(bundle, "no field model in the bundle (needed for --marker)")
            fm = FieldModel.from_dict(b.field_model, bundle)
            enemy = "blue" if team == "red" else "red"
            for name in (marker, f"{enemy}_outpost"):
                if name not in fm.landmarks:
                    raise InputError("--marker", f"no landmark {name!r} in the field model ({', '.join(sorted(fm.landmarks))})")
            actual = float(np.linalg.norm(fm.landmarks[marker][:2] - fm.landmarks[f"{enemy}_outpost"][:2]))
    for name, v in (("--measured", measured), ("--actual", actual)):
        if not math.isfinite(v) or v <= 0 or v > 60:
            raise InputError(name, f"expected a distance in metres (0..60], got {v}")
    old = float(b.runtime.get("hero_range_offset_m", 0.0))
    off = compute_hero_offset(measured, actual)
    b.runtime["hero_range_offset_m"] = off
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


def live_lidars(b, specs: list[str], primary: str | None, tap=None):
    """Start every live LiDAR (``[NAME=]livox://IP``); clouds move into the frame of ``primary`` through the bundle."""
    from radarcal.cli.record_cmd import split_named
    from radarcal.io.livox import open_livox
    from radarcal.runtime.replay import LiveClouds

    sources, T = {}, {}
    try:
        for i, spec in enumerate(specs):
            name, url = split_named(spec, primary if i == 0 and primary else f"lidar{i}")
            if primary and name != primary:
                if not b.has_T(primary, name):
                    raise InputError(b.path, f"no extrinsic between {primary!r} and {name!r} (T_{primary}_{name}) for the second LiDAR")
                T[name] = b.T(primary, name)
            sources[name] = open_livox(url, sensor=name, packet_tap=tap)
    except Exception:
        for s in sources.values():
            s.close()
        raise
    return LiveClouds(sources, T)


def health_text(health: dict[str, dict]) -> str:
    """Status-line part of the sensors' health: rate, silence (ground-ray fallback), drops, reconnects."""
    parts = []
    for name, h in health.items():
        age = h.get("last_seen_age_s")
        if "rate_pts_s" not in h:  # a camera
            if h["state"] != "streaming" or (age is not None and age > 0.5):
                parts.append(f"{name} {h['state'].upper()} {'-' if age is None else f'{age:.1f}s'} reconn {h['reconnects']}")
            elif h["reconnects"]:
                parts.append(f"{name} ok reconn {h['reconnects']}")
            continue
        if age is None or age > 1.0:
            parts.append(f"{name} SILENT {'-' if age is None else f'{age:.1f}s'} (ground-ray fallback)")
        else:
            parts.append(f"{name} {h['rate_pts_s'] / 1000:.0f}k pts/s")
        if h.get("drops") or h.get("reconnects") or h.get("bad_packets") or h.get("truncated_packets"):
            parts[-1] += f" drops {h['drops']} reconn {h['reconnects']} bad {h['bad_packets'] + h['truncated_packets']}"
    return (" | " + " | ".join(parts)) if parts else ""


_ = err_console  # stderr console kept for symmetry with other commands
