"""The record loop of ``radarcal record``: start the LiDARs (Livox SDK 1 / SDK 2), the camera and the referee link,
tap their raw bytes into a :class:`radarcal.io.recording.Recorder` with host receive times until the duration is up,
the video file ends or Ctrl-C, then close everything and write the manifest. The file formats live in ``io/``."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["record", "replay_recording"]

_END = object()  # the camera's frames ended (video file)


def record(out: Path, lidars: list[tuple[str, str]], video: str | None, camera: str, serial: str | None, bundle: Path | None, duration: float | None,
           jpeg_quality: int = 90, status: Callable[[str], None] | None = None) -> dict:  # fmt: skip
    """Record ``lidars`` (name, ``livox://IP`` URL), the camera ``video`` (device index, URL or video file, named
    ``camera``) and the referee port ``serial`` into the new folder ``out``; ``status`` gets a status line every 2 s.
    Returns the summary (streams with their record and byte counts, duration, dropped camera frames, LiDAR health)."""
    from radarcal.io.camera_live import VideoFileFrames
    from radarcal.io.livox import open_livox
    from radarcal.io.recording import Recorder

    video_file = VideoFileFrames(video) if video is not None and not (video.isdigit() or "://" in video) else None
    sensors = [{"name": n, "kind": "lidar", "url": s} for n, s in lidars]
    if video is not None:
        sensors.append({"name": camera, "kind": "camera", "source": video})
    rec = Recorder(out, sensors, bundle, jpeg_quality=jpeg_quality)
    sources, link, n_frames = {}, None, 0
    try:
        for n, s in lidars:
            sources[n] = open_livox(s, sensor=n, packet_tap=rec.lidar)
        link = _open_tapped_link(serial, rec) if serial else None
        n_frames = _record_frames(rec, video_file, video, camera, sources, duration, status)
    finally:
        for s in sources.values():
            s.close()
        if link is not None:
            link.close()
        if video_file is not None:
            video_file.release()
        health = {n: s.snapshot() for n, s in sources.items()}
        for s in sensors:
            if s["kind"] == "lidar":
                s.update({"sdk": health[s["name"]]["sdk"], "device": health[s["name"]]["device"], "frame_s": sources[s["name"]].frame_s})
        if serial:
            sensors.append({"name": "referee", "kind": "serial", "port": serial})
        man = rec.close({"health": health, "camera_frames": n_frames if video else 0})
    mb = sum(c["bytes"] for c in man["streams"].values()) / 1e6
    return {"out": str(out), "duration_s": man["duration_s"], "streams": man["streams"], "megabytes": mb, "dropped_camera_frames": man["dropped_camera_frames"], "lidars": health}


def _open_tapped_link(port: str, rec):
    """The referee link on ``port`` with every byte read or written also going to the recording."""
    from radarcal.io.recording import TapSerial
    from radarcal.runtime.serial_link import SerialLink

    def factory(port, baud):
        import serial as pyserial

        return TapSerial(pyserial.Serial(port, baud, timeout=0, write_timeout=0.2), rec.serial)

    return SerialLink(port, serial_factory=factory).start()


def _record_frames(rec, video_file, video: str | None, camera: str, sources: dict, duration: float | None, status: Callable[[str], None] | None) -> int:
    """Feed camera frames to ``rec`` until ``duration`` (s), the end of the video file or Ctrl-C (the LiDARs and the
    serial link record on their own threads meanwhile); a status line every 2 s. Returns the frames recorded."""
    frames = None
    if video_file is not None:
        frames = iter(video_file)
    elif video is not None:
        from radarcal.io.camera_live import LiveCamera

        frames = (None if getattr(f, "stalled", False) else (f.t, f.name, f.load()) for f in LiveCamera(video, name=camera))  # None: a stall
    t0 = time.monotonic()
    n_frames = 0
    last_status = 0.0
    try:
        while duration is None or time.monotonic() - t0 < duration:
            if frames is not None:
                frame = next(frames, _END)
                if frame is _END:
                    break
                if frame is not None:
                    rec.camera(camera, *frame)
                    n_frames += 1
            else:
                time.sleep(0.05)
            now = time.monotonic()
            if status is not None and now - last_status > 2.0:
                last_status = now
                parts = [f"{n} {h['state']} {h['rate_pts_s'] / 1000:.0f}k pts/s drops {h['drops']}" for n, h in ((n, s.snapshot()) for n, s in sources.items())]
                status(f"rec {now - t0:6.1f}s | frames {n_frames} (dropped {rec.dropped_frames}) | " + " | ".join(parts))
    except KeyboardInterrupt:
        pass
    return n_frames


def replay_recording(replay: Path, *, bundle: Path | None, speed: float, detector, names, conf, threads, detections, serial, out, minimap, camera, lidar, team, season,
                     max_frames, no_lidar, status: bool, sentry_xy: str | None, marking: dict | None = None, log: Callable[[str], None] = lambda s: None) -> dict:  # fmt: skip
    """The match loop over a recording made by :func:`record` (``radarcal run --replay RECORDING``): the recorded
    LiDAR packets through the live decoder, camera frames at their receive times, the recorded referee bytes driving
    the referee state at their times; what the loop sends goes to ``serial`` (a port, ``pty`` or ``dry-run``).
    ``speed`` 1 paces at real speed, 0 as fast as possible (same output). Returns the run's summary."""
    from radarcal.io.recording import open_recording, paced
    from radarcal.runtime.loop import Pipeline, RunConfig
    from radarcal.runtime.loop import run as run_loop
    from radarcal.runtime.marking import Marking
    from radarcal.runtime.replay import ReplayLink, advancing, merged_recorded_clouds, recorded_frames
    from radarcal.runtime.sources import merge_by_time

    rec = open_recording(replay)
    man = rec.manifest
    bundle, b = _recording_bundle(man, bundle, log)
    cam_name, lidar_name, lidars, T = _recording_sensors(b, rec, replay, bundle, camera, lidar, no_lidar)
    sxy = tuple(float(v) for v in sentry_xy.split(",")) if sentry_xy else None
    cfg = RunConfig.from_bundle(b, team=team, season=season, sentry_xy=sxy, **(marking or {}))
    pipe = Pipeline(b, cam_name, lidar_name, cfg)
    detect = _detect_fn(detector, names, conf, threads, detections)
    frames = paced(recorded_frames(rec, cam_name), lambda f: f.t, speed)
    clouds = merged_recorded_clouds(rec.clouds(), T) if lidar_name is not None else None
    link = ReplayLink([(t, buf) for t, d, buf in rec.serial_records() if d == 0], _output_link(serial, cfg.season))
    try:
        summary = run_loop(pipe, advancing(merge_by_time(frames, clouds), link), detect, out, minimap, link, status=status,
                           max_frames=max_frames, write_latency=False, marking=Marking(cfg))  # fmt: skip
    finally:
        link.close()
    summary.pop("results")
    summary.update({"bundle": str(bundle), "recording": str(replay), "camera": cam_name, "lidar": lidar_name, "lidars": lidars,
                    "out": str(out) if out else None, "team": link.state.team or cfg.team, "season": cfg.season,
                    "serial": {"output": serial or "dry-run", **link.snapshot()}, "recorded_health": man.get("health")})  # fmt: skip
    return summary


def _recording_bundle(man: dict, bundle: Path | None, log: Callable[[str], None]):
    """The bundle to replay with (default: the one the manifest names) and its path; warns when its sha256 is not
    the recorded one."""
    from radarcal.bundle import load_bundle
    from radarcal.errors import InputError
    from radarcal.io.recording import file_sha256

    if bundle is None:
        if not man.get("bundle"):
            raise InputError("--bundle", "required (the recording names no bundle)")
        bundle = Path(man["bundle"]["path"])
    b = load_bundle(bundle)
    if man.get("bundle") and Path(bundle).is_file() and file_sha256(bundle) != man["bundle"]["sha256"]:
        log(f"warning: {bundle}: not the bundle the recording was made with (sha256 differs)")
    return bundle, b


def _recording_sensors(b, rec, replay: Path, bundle: Path, camera: str | None, lidar: str | None, no_lidar: bool):
    """The camera and main LiDAR to run on (``lidar_name`` None: no clouds), every recorded LiDAR's name and
    ``T_<main>_<other>`` for the others (from the bundle)."""
    from radarcal.errors import InputError
    from radarcal.runtime.loop import pick_frames

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
    return cam_name, lidar_name if has_clouds else None, lidars, T


def _detect_fn(detector, names, conf, threads, detections):
    """``detect(frame) -> boxes``: the ONNX model ``detector`` or the ``detections`` file looked up by time / name."""
    from radarcal.errors import InputError
    from radarcal.io.detector_files import read_class_names
    from radarcal.runtime.detector import DetectionsFile, OnnxDetector

    if detector is not None:
        det = OnnxDetector(detector, read_class_names(names) if names else None, conf_thres=conf, threads=threads)
        return lambda f: det(f.load())
    if detections is not None:
        dfile = DetectionsFile.read(detections)
        return lambda f: dfile.lookup(f.t, f.name)
    raise InputError("radarcal run", "no detector: give --detector model.onnx or --detections FILE")


def _output_link(serial: str | None, season):
    """The started referee link the loop sends on: a real port, a pseudo-terminal (``pty``) or none (``dry-run``)."""
    from radarcal.runtime.replay import open_output_port
    from radarcal.runtime.serial_link import SerialLink

    port = open_output_port(serial)
    if port is not None:
        return SerialLink(getattr(port, "name", "dry-run"), season=season, serial_factory=lambda *_: port).start()
    return SerialLink(serial, season=season).start()
