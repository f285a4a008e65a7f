"""Inputs of ``radarcal run``: camera frames, live LiDAR clouds, the replay folder, and time pairing.

Camera: a video file, an image folder (times from ``times.csv`` ``file,t`` if present, else numeric file names, else
index / fps), or a live ``cv2.VideoCapture`` index / URL (wall-clock times). Recorded clouds (folders, ROS bags) come
from the cloud-source layer in :mod:`radarcal.io.cloud_sources` / :mod:`radarcal.io.bags`; nothing here decodes a file.

Livox live input: **Livox SDK 1 (LiDAR communication protocol v1)** point-data packets as sent by Mid-40 /
Mid-70 / Horizon / Tele / Avia: an 18-byte header (version u8, slot u8, lidar id u8, reserved u8, status u32,
timestamp type u8, data type u8, timestamp u64 ns) followed by points of data type 0 (cartesian int32 mm + u8
reflectivity, 100 per packet), 1 (spherical: depth u32 mm, theta u16, phi u16 in 0.01 deg, reflectivity), 2
(extended cartesian + tag, 96), 3 (extended spherical, 96), 4 (dual extended cartesian, 48 x 2 returns), 5 (dual
extended spherical). Data type 6 (IMU) is ignored. radarcal only *listens* on the host data port: the SDK1
handshake that makes the sensor stream must be done by another tool (Livox Viewer / the SDK sample / a driver on
the same port is not possible at the same time). SDK2 sensors (Mid-360, HAP) use another packet format and are not
parsed here.
"""

from __future__ import annotations

import dataclasses
import math
import os
import socket
import threading
import time
from collections import deque
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
    "parse_livox_packet",
    "LivoxUdpSource",
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
    """A video file (times from the container) or a live index / URL (wall-clock time since start)."""
    import cv2

    live = source.isdigit() or "://" in source
    cap = cv2.VideoCapture(int(source) if source.isdigit() else source)
    if not cap.isOpened():
        raise InputError(source, "cannot open video source")
    rate = fps or cap.get(cv2.CAP_PROP_FPS) or 30.0
    t0 = time.monotonic()
    i = 0
    try:
        while True:
            ok, img = cap.read()
            if not ok:
                if live:
                    time.sleep(0.01)
                    if time.monotonic() - t0 > 5.0 and i == 0:
                        raise InputError(source, "live source delivers no frames")
                    continue
                break
            if live:
                t = time.monotonic() - t0
            else:
                ms = cap.get(cv2.CAP_PROP_POS_MSEC)
                t = ms / 1000.0 if ms and ms > 0 and i > 0 else i / rate
            yield CameraFrame(t, f"{i:06d}", (lambda img=img: img), i)
            i += 1
    finally:
        cap.release()


def open_camera(spec: str, fps: float = 30.0) -> Iterator[CameraFrame]:
    p = Path(spec)
    if p.is_dir():
        return image_folder_frames(p, fps)
    if p.is_file() or spec.isdigit() or "://" in spec:
        return video_frames(spec)
    raise InputError(spec, "camera source not found (expected an image folder, a video file, a device index or a URL)")


# --- Livox SDK1 UDP --------------------------------------------------------------------------------------------------
_LIVOX_HDR = np.dtype([("version", "u1"), ("slot", "u1"), ("id", "u1"), ("rsvd", "u1"), ("status", "<u4"), ("ts_type", "u1"), ("data_type", "u1"), ("timestamp", "<u8")])
_CART = np.dtype([("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("r", "u1")])
_CART_EXT = np.dtype([("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("r", "u1"), ("tag", "u1")])
_SPH = np.dtype([("depth", "<u4"), ("theta", "<u2"), ("phi", "<u2"), ("r", "u1")])
_SPH_EXT = np.dtype([("depth", "<u4"), ("theta", "<u2"), ("phi", "<u2"), ("r", "u1"), ("tag", "u1")])
_DUAL_SPH = np.dtype([("theta", "<u2"), ("phi", "<u2"), ("depth", "<u4"), ("r", "u1"), ("tag", "u1"), ("depth2", "<u4"), ("r2", "u1"), ("tag2", "u1")])
_LIVOX_TYPES = {0: _CART, 1: _SPH, 2: _CART_EXT, 3: _SPH_EXT, 4: _CART_EXT, 5: _DUAL_SPH}


def _sph_to_xyz(depth_mm, theta, phi) -> np.ndarray:
    d = depth_mm.astype(np.float64) * 1e-3
    th = np.radians(theta.astype(np.float64) * 0.01)
    ph = np.radians(phi.astype(np.float64) * 0.01)
    return np.column_stack([d * np.sin(th) * np.cos(ph), d * np.sin(th) * np.sin(ph), d * np.cos(th)])


def parse_livox_packet(buf: bytes) -> tuple[float, np.ndarray, np.ndarray] | None:
    """One Livox SDK1 point-data packet -> (timestamp s, points (N,3) float32 m, reflectivity (N,)); None for IMU,
    unknown or malformed packets. Zero points (no return) are dropped."""
    if len(buf) < _LIVOX_HDR.itemsize:
        return None
    h = np.frombuffer(buf, _LIVOX_HDR, 1)[0]
    dtype = _LIVOX_TYPES.get(int(h["data_type"]))
    if dtype is None:
        return None
    body = buf[_LIVOX_HDR.itemsize :]
    n = len(body) // dtype.itemsize
    if n == 0:
        return None
    p = np.frombuffer(body, dtype, n)
    kind = int(h["data_type"])
    if kind in (0, 2):
        xyz = np.column_stack([p["x"], p["y"], p["z"]]).astype(np.float32) * np.float32(1e-3)
        r = p["r"]
    elif kind == 4:  # two returns per slot, each an extended cartesian point: the array already interleaves them
        xyz = np.column_stack([p["x"], p["y"], p["z"]]).astype(np.float32) * np.float32(1e-3)
        r = p["r"]
    elif kind in (1, 3):
        xyz = _sph_to_xyz(p["depth"], p["theta"], p["phi"]).astype(np.float32)
        r = p["r"]
    else:  # 5: dual spherical
        a = _sph_to_xyz(p["depth"], p["theta"], p["phi"])
        b = _sph_to_xyz(p["depth2"], p["theta"], p["phi"])
        xyz = np.vstack([a, b]).astype(np.float32)
        r = np.concatenate([p["r"], p["r2"]])
    keep = np.any(xyz != 0, axis=1)
    return int(h["timestamp"]) * 1e-9, xyz[keep], r[keep].astype(np.float32)


class LivoxUdpSource:
    """Listens for Livox SDK1 point packets on ``host:port`` in a thread, cuts them into clouds of ``frame_s``
    (by sensor timestamp) and hands out the newest complete clouds with :meth:`poll` (never blocks)."""

    def __init__(self, host: str = "0.0.0.0", port: int = 56001, frame_s: float = 0.1, max_clouds: int = 20):
        self.addr = (host, int(port))
        self.frame_s = float(frame_s)
        self.clouds: deque[Cloud] = deque(maxlen=max_clouds)
        self.packets = 0
        self.bad_packets = 0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._parts: list[tuple[np.ndarray, np.ndarray]] = []
        self._frame_start: float | None = None
        self._t_wall0 = time.monotonic()
        self._sensor_t0: float | None = None
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.sock.bind(self.addr)
        except OSError as e:
            raise InputError(f"livox://{host}:{port}", f"cannot listen ({e.strerror})") from None
        self.sock.settimeout(0.1)
        self._thread = threading.Thread(target=self._run, daemon=True, name="livox-udp")

    def start(self) -> "LivoxUdpSource":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self.sock.close()

    def feed(self, buf: bytes) -> None:
        r = parse_livox_packet(buf)
        if r is None:
            self.bad_packets += 1
            return
        self.packets += 1
        t, xyz, refl = r
        if self._sensor_t0 is None:
            self._sensor_t0 = t
        t -= self._sensor_t0
        if self._frame_start is None:
            self._frame_start = t
        if t - self._frame_start >= self.frame_s and self._parts:
            pts = np.vstack([p for p, _ in self._parts])
            inten = np.concatenate([i for _, i in self._parts])
            with self._lock:
                self.clouds.append(Cloud(pts, inten, t=self._frame_start + self.frame_s, name=f"livox@{self._frame_start:.3f}"))
            self._parts = []
            self._frame_start = t
        self._parts.append((xyz, refl))

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                buf = self.sock.recv(2048)
            except socket.timeout:
                continue
            except OSError:
                break
            self.feed(buf)

    def poll(self) -> list[Cloud]:
        with self._lock:
            out = list(self.clouds)
            self.clouds.clear()
        return out


def open_clouds(spec: str, topic: str | None = None, hz: float = 10.0, sensor: str = ""):
    """A cloud source from a folder or a bag (a :class:`radarcal.io.cloud_sources.CloudSource`), or a live
    ``livox://host:port`` listener (started; polled by :func:`merge_by_time`)."""
    if spec.startswith("livox://"):
        hostport = spec[len("livox://") :]
        host, _, port = hostport.rpartition(":")
        if not port.isdigit():
            raise InputError(spec, "expected livox://HOST:PORT")
        return LivoxUdpSource(host or "0.0.0.0", int(port)).start()
    if not Path(spec).exists():
        raise InputError(spec, "cloud source not found (expected a folder of clouds, a ROS bag or livox://HOST:PORT)")
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


def prefetch_frames(frames: Iterator[CameraFrame], depth: int = 3, latest_only: bool = False) -> Iterator[CameraFrame]:
    """Decode images in a background thread (JPEG decode and the detector then overlap). ``latest_only`` (live
    cameras): keep only the newest decoded frame, dropping older ones, so latency never builds up."""
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
