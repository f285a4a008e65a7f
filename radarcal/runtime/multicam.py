"""Several cameras in one ``radarcal run`` (issue #19): frames paired by time stamp, one detector call per pairing.

* :func:`group_by_time` merges the cameras' frame streams in time order and pairs them into :class:`CameraTick` s:
  a tick opens with the earliest pending frame and takes, from every other camera, its next frame when it is no
  later than ``window_s`` after it (each camera at most once). A camera whose last frame is more than
  ``missing_after_s`` older than the tick is listed in ``tick.missing`` (unplugged, stalled): the others go on.
  :func:`group_live` does the same for live cameras (one reader thread each, ticks by arrival, stall frames
  dropped).
* :class:`TickDetector` turns a tick into :class:`ViewDetections` (per camera: its frame time, name, boxes): from
  one detections file per camera, or from the recogniser in **one batched call** over the tick's images (the
  detector letterboxes every image to its one input size), optionally one tick ahead in a thread.
* The fusion itself is :class:`radarcal.runtime.pipeline.Pipeline` given several cameras: each camera's boxes are
  matched with the LiDAR tracks at that camera's frame time (one track per robot, however many cameras box it),
  and box-only fixes of the same label from several cameras become one inverse-variance weighted fix.
"""

from __future__ import annotations

import heapq
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator

from radarcal.errors import InputError
from radarcal.runtime.sources import CameraFrame

__all__ = ["CameraTick", "ViewDetections", "group_by_time", "group_live", "TickDetector", "replay_camera_streams", "missing_text", "parse_videos"]


@dataclass
class CameraTick:
    """Frames of several cameras taken at (nearly) one time. ``t``: the latest frame's time (the tick's result is
    reported then); ``name``: ``<camera>/<frame>`` of the first camera present (the truth files use these names)."""

    frames: dict[str, CameraFrame]
    missing: list[str] = field(default_factory=list)
    index: int = 0

    @property
    def t(self) -> float:
        return max(f.t for f in self.frames.values())

    @property
    def name(self) -> str:
        cam, f = next(iter(self.frames.items()))
        return f"{cam}/{f.name}"


@dataclass
class ViewDetections:
    """Per camera of a tick: (camera, frame time, frame name, detections), in time order; cameras missing."""

    views: list[tuple[str, float, str, list]]
    missing: list[str] = field(default_factory=list)


def parse_videos(specs: list[str]) -> dict[str, str] | None:
    """``--video cam0=SRC --video cam1=SRC`` -> {camera: source}; one plain ``--video SRC`` -> None (single camera)."""
    if len(specs) == 1 and "=" not in specs[0].split("://")[0]:
        return None
    out = {}
    for s in specs:
        name, eq, src = s.partition("=")
        if not eq or not name or not src or "://" in name:
            raise InputError("--video", f"several cameras: expected NAME=SRC for each, got {s!r}")
        if name in out:
            raise InputError("--video", f"camera {name!r} given twice")
        out[name] = src
    return out


def group_by_time(streams: dict[str, Iterable[CameraFrame]], window_s: float = 0.017, missing_after_s: float = 0.5) -> Iterator[CameraTick]:
    """Time-ordered streams -> ticks (deterministic: replays, files). The order of ``streams`` is the cameras' order."""
    order = list(streams)
    its = {c: iter(s) for c, s in streams.items()}
    heap: list = []
    for k, c in enumerate(order):
        f = next(its[c], None)
        if f is not None:
            heap.append((f.t, k, c, f))
    heapq.heapify(heap)
    last: dict[str, float] = {}
    n = 0
    while heap:
        t0, _, c0, f0 = heapq.heappop(heap)
        got = {c0: f0}
        nxt = next(its[c0], None)
        if nxt is not None:
            heapq.heappush(heap, (nxt.t, order.index(c0), c0, nxt))
        taken = True
        while taken:
            taken = False
            for i, (t, k, c, f) in enumerate(heap):
                if c not in got and t <= t0 + window_s:
                    got[c] = f
                    heap.pop(i)
                    heapq.heapify(heap)
                    g = next(its[c], None)
                    if g is not None:
                        heapq.heappush(heap, (g.t, k, c, g))
                    taken = True
                    break
        frames = {c: got[c] for c in order if c in got}
        for c, f in frames.items():
            last[c] = f.t
        t = max(f.t for f in frames.values())
        yield CameraTick(frames, [c for c in order if c not in frames and t - last.get(c, -1e18) > missing_after_s], n)
        n += 1


def group_live(streams: dict[str, Iterable[CameraFrame]], window_s: float = 0.017, missing_after_s: float = 0.5) -> Iterator[CameraTick]:
    """Live cameras: one reader thread per camera; a tick takes the first frame to arrive and whatever the other
    cameras deliver within ``window_s`` of wall time. Stall frames (``stalled``: no image) are not frames."""
    import queue
    import threading
    import time

    q: queue.Queue = queue.Queue(maxsize=64)
    stop = threading.Event()
    order = list(streams)
    done = object()

    def read(c, s):
        try:
            for f in s:
                if stop.is_set():
                    return
                if not getattr(f, "stalled", False):
                    q.put((c, f))
        finally:
            q.put((c, done))

    threads = [threading.Thread(target=read, args=(c, s), daemon=True, name=f"camera-{c}") for c, s in streams.items()]
    for th in threads:
        th.start()
    alive, last, n = set(order), {}, 0
    try:
        while alive:
            c, f = q.get()
            if f is done:
                alive.discard(c)
                continue
            got = {c: f}
            t_end = time.monotonic() + window_s
            while len(got) < len(alive):
                try:
                    c2, f2 = q.get(timeout=max(t_end - time.monotonic(), 0.0))
                except queue.Empty:
                    break
                if f2 is done:
                    alive.discard(c2)
                elif c2 in got:  # a camera twice before the others: its older frame goes, the tick keeps the newest
                    got[c2] = f2
                else:
                    got[c2] = f2
            frames = {k: got[k] for k in order if k in got}
            now = time.monotonic()
            for k in frames:
                last[k] = now
            yield CameraTick(frames, [k for k in order if k not in frames and now - last.get(k, -1e18) > missing_after_s], n)
            n += 1
    finally:
        stop.set()
        for s in streams.values():
            if hasattr(s, "close"):
                s.close()


def missing_text(missing: list[str]) -> str:
    """Status-line part for cameras that deliver nothing (empty when all do)."""
    return "".join(f" | {c} MISSING (other cameras only)" for c in missing)


class TickDetector:
    """``detect(tick) -> ViewDetections`` for the loop, from detections files (``files``: camera -> DetectionsFile)
    or a recogniser (one batched call per tick). ``frames(ticks)``: detection one tick ahead in a thread (``workers``
    ticks at once, each worker with its own view of the recogniser: ``radarcal run --detect-workers``)."""

    def __init__(self, recogniser=None, files: dict | None = None, ahead: bool = False, workers: int = 1):
        if (recogniser is None) == (files is None):
            raise ValueError("give exactly one of recogniser and files")
        self.recogniser, self.files = recogniser, files
        self.last_timings_ms: dict[str, float] = {}
        self.last_missing: list[str] = []  # cameras missing at the last tick (status line)
        self.missing_ticks: dict[str, int] = {}  # camera -> ticks it was missing
        self._ahead = None
        if ahead and recogniser is not None:
            from radarcal.runtime.stages import DetectAhead

            outer = self

            class _Ahead(DetectAhead):
                def _run(self, tick):
                    return outer._detect(tick, self._own())

            self._ahead = _Ahead(recogniser, workers=workers)

    def _detect(self, tick: CameraTick, recogniser=None) -> tuple[ViewDetections, dict]:
        rec = self.recogniser if recogniser is None else recogniser
        views = {}
        if self.files is not None:
            for c, f in tick.frames.items():
                views[c] = (c, f.t, f.name, self.files[c].lookup(f.t, f.name))
            timings = {}
        else:
            cams, imgs = [], []
            for c, f in tick.frames.items():
                try:
                    imgs.append(f.load())
                    cams.append(c)
                except InputError as e:  # one camera's unreadable image: that camera has no boxes this tick
                    sys.stderr.write(f"warning: {e} ({c} frame skipped)\n")
                    views[c] = (c, f.t, f.name, [])
            out = rec(imgs, cameras=cams) if imgs else []
            for c, dets in zip(cams, out):
                f = tick.frames[c]
                views[c] = (c, f.t, f.name, dets)
            timings = dict(getattr(rec, "last_timings_ms", {}) or {})
        return ViewDetections(sorted(views.values(), key=lambda v: v[1]), list(tick.missing)), timings

    def frames(self, ticks):
        return self._ahead.frames(ticks) if self._ahead is not None else ticks

    def __call__(self, tick: CameraTick) -> ViewDetections:
        self.last_missing = list(tick.missing)
        for c in tick.missing:
            self.missing_ticks[c] = self.missing_ticks.get(c, 0) + 1
        if self._ahead is not None:
            out = self._ahead(tick)
            self.last_timings_ms = self._ahead.last_timings_ms
            return out
        out, self.last_timings_ms = self._detect(tick)
        return out


def replay_camera_streams(root: Path, cameras: list[str], need_pixels: bool) -> tuple[dict[str, Iterator[CameraFrame]], dict[str, Path]]:
    """A multi-camera replay's per-camera frames and detections files (``cameras/<name>/``)."""
    from radarcal.runtime.sources import open_replay

    streams, dets = {}, {}
    for c in cameras:
        sub = Path(root) / "cameras" / c
        if not sub.is_dir():
            raise InputError(root, f"no camera folder cameras/{c}")
        rep = open_replay(sub)
        streams[c] = rep.camera_frames(need_pixels=need_pixels)
        if rep.detections is not None:
            dets[c] = rep.detections
    return streams, dets
