"""A live camera (``cv2.VideoCapture`` device index or URL) that survives being unplugged: a thread reads frames
and stamps them with the host clock (:func:`radarcal.io.clock.now`) at receive time; when reads fail it releases the
device and reopens it every ``reopen_s`` (counted). The consumer never waits for a stalled camera: after
``stall_s`` without a frame it gets *stall frames* (``stalled=True``; loading their pixels raises InputError) every
``stall_s``, so the match loop keeps running (tracks coast, the referee link keeps sending) and reports the stall.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from radarcal.errors import InputError
from radarcal.io import clock

__all__ = ["CameraHealth", "LiveCamera", "LiveFrame", "VideoFileFrames"]


@dataclass
class CameraHealth:
    name: str = "camera"
    state: str = "opening"  # opening | streaming | stalled | reopening | closed
    frames: int = 0
    stalls: int = 0  # stall frames handed out
    reconnects: int = 0  # successful reopenings after a failure
    open_failures: int = 0
    last_t: float | None = None

    def snapshot(self, now: float | None = None) -> dict:
        now = clock.now() if now is None else now
        return {"sensor": self.name, "state": self.state, "frames": self.frames, "stalls": self.stalls, "reconnects": self.reconnects,
                "open_failures": self.open_failures, "last_seen_age_s": None if self.last_t is None else round(now - self.last_t, 3)}  # fmt: skip


@dataclass
class LiveFrame:
    t: float
    name: str
    load: Callable[[], np.ndarray]
    index: int = 0
    stalled: bool = False


def _stall_image() -> np.ndarray:
    raise InputError("camera", "stalled: no frame")


class LiveCamera:
    """Frames of a live camera as an iterator (``iter(cam)``), newest first: frames arriving while the consumer is
    busy are dropped (latency never builds up). ``opener()`` returns an object with ``read() -> (ok, img)``,
    ``release()``, ``isOpened()`` (default: ``cv2.VideoCapture(spec)``)."""

    def __init__(self, spec: str, opener: Callable | None = None, stall_s: float = 0.5, reopen_s: float = 0.5, name: str = "camera",
                 max_frames: int | None = None, first_frame_timeout_s: float = 5.0):  # fmt: skip
        self.spec = spec
        self.opener = opener or self._cv2_opener
        self.stall_s, self.reopen_s = stall_s, reopen_s
        self.health = CameraHealth(name=name)
        self.max_frames = max_frames
        self.first_timeout = first_frame_timeout_s
        self._cond = threading.Condition()
        self._latest: tuple[float, np.ndarray] | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"camera-{name}")
        self._ever_ok = False

    def _cv2_opener(self):
        import cv2

        return cv2.VideoCapture(int(self.spec) if self.spec.isdigit() else self.spec)

    def start(self) -> LiveCamera:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self._thread.join(2.0)
        self.health.state = "closed"

    def snapshot(self) -> dict:
        return self.health.snapshot()

    def _run(self) -> None:
        cap = None
        while not self._stop.is_set():
            if cap is None:
                try:
                    cap = self.opener()
                    if cap is None or not cap.isOpened():
                        raise OSError("cannot open")
                except Exception:  # noqa: BLE001 - device missing, driver errors ...
                    self.health.open_failures += 1
                    self.health.state = "reopening" if self._ever_ok else "opening"
                    cap = None
                    self._stop.wait(self.reopen_s)
                    continue
            try:
                ok, img = cap.read()
            except Exception:  # noqa: BLE001
                ok, img = False, None
            if not ok or img is None:
                try:
                    cap.release()
                except Exception:  # noqa: BLE001
                    pass
                cap = None
                self.health.state = "reopening"
                self._stop.wait(self.reopen_s)
                continue
            t = clock.now()
            if self.health.state in ("reopening",) and self._ever_ok:
                self.health.reconnects += 1
            self._ever_ok = True
            self.health.state = "streaming"
            self.health.frames += 1
            self.health.last_t = t
            with self._cond:
                self._latest = (t, img)
                self._cond.notify_all()
        if cap is not None:
            cap.release()

    def __iter__(self) -> Iterator[LiveFrame]:
        if not self._thread.is_alive() and not self._stop.is_set():
            self.start()
        i = 0
        t_start = time.monotonic()
        last_yield = clock.now()
        try:
            while not self._stop.is_set() and (self.max_frames is None or i < self.max_frames):
                with self._cond:
                    if self._latest is None:
                        self._cond.wait(self.stall_s)
                    item, self._latest = self._latest, None
                now = clock.now()
                if item is not None:
                    t, img = item
                    yield LiveFrame(t, f"{i:06d}", (lambda img=img: img), i)
                    last_yield = now
                    i += 1
                elif not self._ever_ok and time.monotonic() - t_start > self.first_timeout:
                    raise InputError(self.spec, "live camera delivers no frames")
                elif self._ever_ok and now - last_yield >= self.stall_s:
                    self.health.stalls += 1
                    if self.health.state == "streaming":
                        self.health.state = "stalled"
                    yield LiveFrame(now, f"stall{i:06d}", _stall_image, i, stalled=True)
                    last_yield = now
                    i += 1
        finally:
            self.close()


class VideoFileFrames:
    """A video file read at its own frame rate as a live camera would deliver it: iterating yields
    ``(t, name, image)`` with host-clock receive times (:func:`radarcal.io.clock.now`), frame names ``000000`` ...,
    waiting (in steps of at most 5 ms) until each frame is due; ends with the file. ``release()`` closes it."""

    def __init__(self, path: str):
        from pathlib import Path

        from radarcal.io.video import VideoFile

        if not Path(path).is_file():
            raise InputError(path, "video file not found")
        self._video = VideoFile(path, "cannot open video")
        self._frames = self._video.frames()
        self.fps = self._video.fps

    def __iter__(self) -> Iterator[tuple[float, str, np.ndarray]]:
        next_frame = time.monotonic()
        k = 0
        while True:
            now = time.monotonic()
            if now < next_frame:
                time.sleep(min(0.005, next_frame - now))
                continue
            t_img = next(self._frames, None)
            if t_img is None:
                return
            img = t_img[1]
            yield clock.now(), f"{k:06d}", img
            k += 1
            next_frame += 1.0 / self.fps

    def release(self) -> None:
        self._video.close()
