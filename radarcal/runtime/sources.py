"""Inputs of ``radarcal run``: camera frames, live LiDAR clouds, the replay folder, and time pairing.

Camera: a video file (:mod:`radarcal.io.video`), an image folder (times from ``times.csv`` ``file,t`` if present, else numeric file names, else
index / fps), or a live ``cv2.VideoCapture`` index / URL (host-clock receive times, reconnecting:
:mod:`radarcal.io.camera_live`). Live Livox LiDARs are started and read by :mod:`radarcal.io.livox`. Recorded clouds (folders, ROS bags) come
from the cloud-source layer in :mod:`radarcal.io.cloud_sources` / :mod:`radarcal.io.bags`; nothing here decodes a file.

"""

from __future__ import annotations

import dataclasses
import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from radarcal.errors import InputError
from radarcal.io import read_image
from radarcal.io.cloud_sources import CloudSource, open_cloud_source, timed_files
from radarcal.io.clouds import Cloud
from radarcal.io.replay import IMAGE_SUFFIXES, ReplayFolder, replay_fields

__all__ = [
    "CameraFrame",
    "image_folder_frames",
    "video_frames",
    "Replay",
    "open_replay",
    "open_camera",
    "open_clouds",
    "merge_by_time",
    "prefetch_frames",
    "IMAGE_SUFFIXES",
    "MAX_CLOCK_GAP_S",
]


@dataclass
class CameraFrame:
    t: float
    name: str
    load: Callable[[], np.ndarray]  # decode on demand (a replay with --detections never needs the pixels)
    index: int = 0


# --- camera ----------------------------------------------------------------------------------------------------------
def image_folder_frames(folder: str | os.PathLike, fps: float = 30.0) -> Iterator[CameraFrame]:
    for i, (t, p) in enumerate(timed_files(Path(folder), IMAGE_SUFFIXES, fps, "image")):
        yield CameraFrame(t, p.name, (lambda p=p: read_image(p)), i)


def video_frames(source: str, fps: float | None = None) -> Iterator[CameraFrame]:
    """A video file (times from the container) or a live index / URL (:class:`radarcal.io.camera_live.LiveCamera`:
    host-clock receive times, reopened when unplugged, stall frames instead of waiting)."""
    if source.isdigit() or "://" in source:
        from radarcal.io.camera_live import LiveCamera

        yield from LiveCamera(source)
        return
    from radarcal.io.video import VideoFile

    for i, (t, img) in enumerate(VideoFile(source, "cannot open video source").frames(fps)):
        yield CameraFrame(t, f"{i:06d}", (lambda img=img: img), i)


def open_camera(spec: str, fps: float = 30.0) -> Iterator[CameraFrame]:
    p = Path(spec)
    if p.is_dir():
        return image_folder_frames(p, fps)
    if not p.is_file() and (spec.isdigit() or "://" in spec):
        from radarcal.io.camera_live import LiveCamera

        return LiveCamera(spec, name="camera")  # iterable; .snapshot() is its health
    if p.is_file():
        return video_frames(spec)
    raise InputError(spec, "camera source not found (expected an image folder, a video file, a device index or a URL)")


def open_clouds(spec: str, topic: str | None = None, hz: float = 10.0, sensor: str = ""):
    """A cloud source from a folder or a bag (a :class:`radarcal.io.cloud_sources.CloudSource`), or a live Livox
    (``livox://IP``, ``livox1://`` SDK 1, ``livox2://`` SDK 2: a started :class:`radarcal.io.livox.LivoxSource`, polled
    by :func:`merge_by_time`)."""
    if spec.startswith(("livox://", "livox1://", "livox2://")):
        from radarcal.io.livox import open_livox

        return open_livox(spec)
    if not Path(spec).exists():
        raise InputError(spec, "cloud source not found (expected a folder of clouds, a ROS bag or livox://IP)")
    return open_cloud_source(spec, topic, hz, sensor)


# --- replay folder ---------------------------------------------------------------------------------------------------
class Replay(ReplayFolder):
    """A replay folder (:class:`radarcal.io.replay.ReplayFolder`) with its camera frames and cloud source."""

    def camera_frames(self, need_pixels: bool = False) -> Iterator[CameraFrame]:
        """The camera frames. Driven by detections (``need_pixels=False``) every frame of ``detections.jsonl`` is
        yielded even when ``synth field --image-every K`` wrote only every K-th image; a detector needs the pixels
        and gets the frames that have an image."""
        if need_pixels or self.timeline is None:
            for i, (t, p) in enumerate(self.frames):
                yield CameraFrame(t, p.name, (lambda p=p: read_image(p)), i)
            return
        images = self.root / "images"
        for i, (t, name) in enumerate(self.timeline):
            p = images / name
            yield CameraFrame(t, name, (lambda p=p: read_image(p)), i)

    def cloud_frames(self, quiet: bool = False) -> CloudSource:
        """The recorded clouds (same clock as the frames)."""
        return self.cloud_source(quiet)


def open_replay(folder: str | os.PathLike) -> Replay:
    """A replay folder as written by ``radarcal synth field`` (see docs): images/, clouds/, detections.jsonl ..."""
    return Replay(**replay_fields(folder))


def prefetch_frames(frames: Iterator[CameraFrame], depth: int = 3, latest_only: bool = False, prepare=None) -> Iterator[CameraFrame]:
    """Decode images in a background thread (JPEG decode and the detector then overlap). ``latest_only`` (live
    cameras): keep only the newest decoded frame, dropping older ones, so latency never builds up. ``prepare``:
    called on each decoded image in that thread too (the detector's letterbox, ``OnnxDetector.prepare_ahead``)."""
    import queue

    q: queue.Queue = queue.Queue(maxsize=1 if latest_only else depth)
    done = object()
    stop = threading.Event()

    def work():
        try:
            for f in frames:
                if stop.is_set():
                    break
                try:
                    img = f.load()
                    if prepare is not None:
                        prepare(img)
                    g = CameraFrame(f.t, f.name, (lambda img=img: img), f.index)
                except InputError as e:
                    g = CameraFrame(f.t, f.name, (lambda e=e: (_ for _ in ()).throw(e)), f.index)
                if latest_only:
                    try:
                        q.get_nowait()  # drop the stale frame
                    except queue.Empty:
                        pass
                    q.put(g)
                else:
                    while not stop.is_set():
                        try:
                            q.put(g, timeout=0.1)
                            break
                        except queue.Full:
                            continue
        finally:
            q.put(done)

    th = threading.Thread(target=work, daemon=True, name="frame-prefetch")
    th.start()
    try:
        while True:
            g = q.get()
            if g is done:
                break
            yield g
    finally:
        stop.set()
        while th.is_alive():  # unblock a put on a full queue and wait: a thread still decoding at exit aborts Python
            try:
                q.get_nowait()
            except queue.Empty:
                pass
            th.join(timeout=0.05)


# --- pairing ---------------------------------------------------------------------------------------------------------
MAX_CLOCK_GAP_S = 3600.0  # first cloud vs first frame further apart than this (on the camera clock): the clocks differ


def _on_camera_clock(c: Cloud, offset: float) -> Cloud:
    """The cloud with its time on the camera clock (a new object: the source's cloud is not changed)."""
    if c.t is None:
        raise InputError(c.name or "cloud", "cloud has no time stamp")
    return dataclasses.replace(c, t=c.t + offset) if offset else c


class _CloudClock:
    """Cloud time -> camera time (``+ offset``); ``offset None``: set by the first cloud to the frame it pairs with."""

    def __init__(self, offset_s: float | str):
        if offset_s == "first":
            self.offset = None
        elif isinstance(offset_s, (int, float)) and math.isfinite(offset_s):
            self.offset = float(offset_s)
        else:
            raise InputError("--cloud-time-offset", f"expected seconds or 'first', got {offset_s!r}")
        self.checked = False

    def to_camera(self, c: Cloud, frame_t: float) -> Cloud:
        if c.t is None:
            raise InputError(c.name or "cloud", "cloud has no time stamp")
        if self.offset is None:
            self.offset = frame_t - float(c.t)
        if not self.checked:
            self.checked = True
            gap = float(c.t) + self.offset - frame_t
            if abs(gap) > MAX_CLOCK_GAP_S:
                raise InputError("--cloud-time-offset", f"the first cloud ({c.name}, t={c.t:.3f} s) is {gap:+.0f} s from the camera frame at t={frame_t:.3f} s: "
                                 "the two clocks differ; give the offset in seconds (t_camera = t_cloud + offset) or 'first'")  # fmt: skip
        return dataclasses.replace(c, t=float(c.t) + self.offset) if self.offset else c


def merge_by_time(frames: Iterator[CameraFrame], clouds, cloud_offset_s: float | str = 0.0) -> Iterator[tuple[CameraFrame, list[Cloud]]]:
    """Yield each camera frame with the clouds that arrived since the previous frame, their ``t`` on the camera clock.

    ``t_camera = t_cloud + cloud_offset_s`` (seconds; ``run --cloud-time-offset``); the clouds handed out are new
    objects, the source's time stamps are never changed. ``"first"`` sets the offset so that the first cloud
    coincides with the frame it pairs with (recordings whose clocks each started at their own 0, or a video file
    beside a bag with absolute stamps). A numeric offset that leaves the first cloud more than
    :data:`MAX_CLOCK_GAP_S` from its frame is an ``InputError``: the clocks differ and nothing would pair.

    ``clouds``: None; a live source (anything with a non-blocking ``poll() -> list[Cloud]``: what arrived since the
    last frame pairs with this one); or an iterable of clouds in time order (a
    :class:`radarcal.io.cloud_sources.CloudSource`, read ahead lazily: a cloud pairs with the first frame not older)."""
    if clouds is None:
        for f in frames:
            yield f, []
        return
    clock = _CloudClock(cloud_offset_s)
    poll = getattr(clouds, "poll", None)
    if callable(poll):
        for f in frames:
            yield f, [clock.to_camera(c, f.t) for c in poll()]
        return
    it = iter(clouds)
    pending: Cloud | None = None
    done = False
    for f in frames:
        batch: list[Cloud] = []
        while not done:
            if pending is None:
                c = next(it, None)
                if c is None:
                    done = True
                    break
                pending = clock.to_camera(c, f.t)
            if pending.t > f.t + 1e-9:
                break
            batch.append(pending)
            pending = None
        yield f, batch
