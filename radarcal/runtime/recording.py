"""The record loop of ``radarcal record``: start the LiDARs (Livox SDK 1 / SDK 2), the camera and the referee link,
tap their raw bytes into a :class:`radarcal.io.recording.Recorder` with host receive times until the duration is up,
the video file ends or Ctrl-C, then close everything and write the manifest. The file formats live in ``io/``."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["record"]

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
