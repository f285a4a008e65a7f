"""The live operator console of ``radarcal run --ui [HOST:]PORT`` (docs/console.md).

:class:`LiveConsole` is a publisher beside the loop: the loop hands it each :class:`FrameResult` through the
``on_frame`` callback (``on_frame(n, res)`` stores a reference in a latest-value slot: no copy, no JSON, no waiting),
and optionally the frames/clouds (:meth:`observe_pairs`) and detections (:meth:`observe_detect`) by wrapping the
iterators it already passes. Everything else — JSON, JPEG, drawing, the network — happens in the server's threads,
at the browser's pace, on the newest value only: a slow or closed page costs the loop nothing.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable

import numpy as np

from radarcal.runtime.console.server import LatestSlot, WebServer, asset

__all__ = ["LiveConsole", "chain_callbacks", "paced"]

PACKAGE = "radarcal.runtime.console"


def chain_callbacks(*fns: Callable | None) -> Callable | None:
    """One ``on_frame`` callback calling each given one in order (None entries skipped)."""
    fs = [f for f in fns if f is not None]
    if not fs:
        return None
    if len(fs) == 1:
        return fs[0]

    def call(n, res):
        for f in fs:
            f(n, res)

    return call


def paced(pairs: Iterable, speed: float = 1.0) -> Iterable:
    """Replays at ``speed`` × the camera's time stamps (a replay normally runs as fast as it can). Sleeps in the
    source iterator, before the frame reaches the loop, so the loop's own timings are unchanged."""
    t0_wall = t0_data = None
    for item in pairs:
        frame = item[0]
        if speed > 0:
            if t0_wall is None:
                t0_wall, t0_data = time.perf_counter(), frame.t
            wait = (frame.t - t0_data) / speed - (time.perf_counter() - t0_wall)
            if wait > 0:
                time.sleep(wait)
        yield item


class LiveConsole:
    """The console's state (newest frame result, camera frame, cloud, detections, health providers) and its pages."""

    def __init__(self, server: WebServer, field_model=None, camera=None, T_cam_lidar: np.ndarray | None = None, info: dict | None = None,
                 max_hz: float = 30.0, camera_hz: float = 4.0):  # fmt: skip
        self.server = server
        self.field = field_model
        self.camera = camera
        self.T_cam_lidar = None if T_cam_lidar is None else np.asarray(T_cam_lidar, float)
        self.info = dict(info or {})
        self.max_hz = float(max_hz)
        self.camera_hz = float(camera_hz)
        self.results = LatestSlot()  # (n, FrameResult, wall time of the frame's result)
        self._frame = None  # newest CameraFrame (a reference)
        self._cloud = None  # newest non-empty cloud points (a reference)
        self._dets = None  # newest detections list (a reference)
        self._health: dict[str, Callable[[], dict]] = {}
        self._fps_t: deque = deque(maxlen=60)
        self._jpeg: tuple[float, bytes] | None = None
        self._jpeg_lock = threading.Lock()
        self.requests: deque = deque(maxlen=32)  # operator actions for a policy to take (e.g. the double-vulnerability trigger)
        self.sent = 0
        s = server
        s.get["/"] = lambda q: ("text/html; charset=utf-8", asset(PACKAGE, "console.html"))
        s.get["/console.js"] = lambda q: ("text/javascript; charset=utf-8", asset(PACKAGE, "console.js"))
        s.get["/console.css"] = lambda q: ("text/css; charset=utf-8", asset(PACKAGE, "console.css"))
        s.get["/api/field"] = lambda q: ("application/json", json.dumps(self.field_geometry()).encode())
        s.get["/api/camera.jpg"] = lambda q: ("image/jpeg", self.camera_jpeg())
        s.streams["/api/events"] = self._events
        self.on_action("double_vulnerability", None)

    # --- the loop's side: references only -------------------------------------------------------------------------
    def on_frame(self, n: int, res) -> None:
        """``run(..., on_frame=console.on_frame)``: keep the newest result (constant time, never waits for a page)."""
        now = time.time()
        self._fps_t.append(now)
        self.results.put((n, res, now))

    def observe_pairs(self, pairs: Iterable) -> Iterable:
        """Wrap the loop's (frame, clouds) iterator: remembers the newest frame and non-empty cloud (references)."""
        for frame, clouds in pairs:
            self._frame = frame
            for c in clouds:
                if len(c.points):
                    self._cloud = c.points
            yield frame, clouds

    def observe_detect(self, detect: Callable) -> Callable:
        def wrapped(frame):
            dets = detect(frame)
            self._dets = (frame.name, dets)
            return dets

        return wrapped

    def add_health(self, name: str, fn: Callable[[], dict]) -> None:
        """A health provider (serial link, sensors): ``fn()`` returns a small dict, called from the server thread."""
        self._health[name] = fn

    def on_action(self, name: str, fn: Callable[[dict], dict] | None) -> None:
        """Register an operator action (token + session + sequence checked by the server). Without ``fn`` the request
        is queued in :attr:`requests` for whoever implements the policy (it must not block the loop)."""

        def queue_it(args: dict, name=name) -> dict:
            self.requests.append({"action": name, "args": args, "t": time.time()})
            return {"queued": True, "action": name}

        self.server.actions[name] = fn or queue_it

    # --- the server's side ------------------------------------------------------------------------------------------
    def field_geometry(self) -> dict:
        f = self.field
        if f is None:
            return {"size": [28.0, 15.0], "outline": [[0, 0], [28, 0], [28, 15], [0, 15]], "areas": [], "landmarks": {}, "info": self.info}
        return {"name": f.name, "size": list(map(float, f.size)), "outline": np.asarray(f.outline, float).round(3).tolist(),
                "areas": [{"name": a.get("name", ""), "z": float(a.get("z", 0.0)), "polygon": np.asarray(a["polygon"], float).round(3).tolist()} for a in f.areas],
                "landmarks": {k: np.asarray(v, float).round(3).tolist() for k, v in f.landmarks.items()}, "info": self.info}  # fmt: skip

    def fps(self) -> float:
        t = list(self._fps_t)
        return (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else 0.0

    def health(self) -> dict:
        out = {}
        for name, fn in list(self._health.items()):
            try:
                out[name] = fn()
            except Exception as e:  # noqa: BLE001 - a failing provider shows as such, never breaks the page
                out[name] = {"error": f"{e.__class__.__name__}: {e}"}
        return out

    def message(self, n: int, res, wall: float) -> dict:
        d = res.to_dict()
        return {"seq": n, "wall": wall, "sent": time.time(), "fps": round(self.fps(), 2), "result": d, "health": self.health(),
                "requests": list(self.requests)[-5:], "info": self.info}  # fmt: skip

    def _events(self, write, q: dict, alive: Callable[[], bool]) -> None:
        seq = 0
        min_dt = 1.0 / self.max_hz if self.max_hz > 0 else 0.0
        last = 0.0
        write("hello", json.dumps({"info": self.info}))
        while alive():
            seq, item = self.results.get_newer(seq, timeout=1.0)
            if item is None:
                write("ping", "{}")  # keeps the connection checked; a dead page raises here
                continue
            wait = last + min_dt - time.perf_counter()
            if wait > 0:  # at most max_hz per page; the newest value is taken after the wait
                time.sleep(wait)
                seq, item = self.results.seq, self.results.value
            last = time.perf_counter()
            write(None, json.dumps(self.message(*item), separators=(",", ":"), default=_jsonable))
            self.sent += 1

    def camera_jpeg(self) -> bytes:
        """The newest camera frame with this frame's boxes and the newest cloud projected, at most ``camera_hz``."""
        import cv2

        with self._jpeg_lock:
            now = time.perf_counter()
            if self._jpeg is not None and now - self._jpeg[0] < 1.0 / self.camera_hz:
                return self._jpeg[1]
            frame, dets, cloud = self._frame, self._dets, self._cloud
            img = None
            if frame is not None:
                try:
                    img = frame.load()
                except Exception:  # noqa: BLE001 - a replay frame without an image, a dropped live frame
                    img = None
            if img is None:
                if self._jpeg is not None:
                    return self._jpeg[1]
                img = np.full((240, 320, 3), 30, np.uint8)
                cv2.putText(img, "no camera frame yet", (40, 120), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (200, 200, 200), 1, cv2.LINE_AA)
            else:
                img = img.copy() if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
                s = img.shape[1] / self.camera.width if self.camera is not None else 1.0
                if cloud is not None and self.camera is not None and self.T_cam_lidar is not None:
                    pts = cloud[:: max(1, len(cloud) // 20000)]
                    uv, valid, z = self.camera.project_from(self.T_cam_lidar, pts)
                    ok = valid & self.camera.in_image(uv)
                    uv, z = uv[ok] * s, z[ok]
                    if len(z):
                        hue = np.clip(z / 30.0 * 150, 0, 150).astype(np.uint8)
                        col = cv2.cvtColor(np.stack([hue, np.full_like(hue, 255), np.full_like(hue, 255)], -1)[None], cv2.COLOR_HSV2BGR)[0]
                        ij = np.round(uv).astype(int)
                        inb = (ij[:, 0] >= 0) & (ij[:, 0] < img.shape[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < img.shape[0])
                        img[ij[inb, 1], ij[inb, 0]] = col[inb]
                if dets is not None and frame is not None and dets[0] == frame.name:
                    for d in dets[1]:
                        b = np.asarray(d.xyxy, float) * s
                        if b.shape == (4,) and np.all(np.isfinite(b)):
                            c = (60, 60, 255) if str(d.label).startswith("red") else (255, 150, 40)
                            cv2.rectangle(img, (int(b[0]), int(b[1])), (int(b[2]), int(b[3])), c, 2)
                            cv2.putText(img, f"{d.label} {d.score:.2f}", (int(b[0]), int(b[1]) - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.45, c, 1, cv2.LINE_AA)
                cv2.putText(img, frame.name, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 75])
            self._jpeg = (now, buf.tobytes())
            return self._jpeg[1]


def _jsonable(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    return str(o)


def start_console(bind: str, pipeline, bundle, camera_name: str, lidar_name: str | None, info: dict | None = None) -> LiveConsole:
    """Build, start and announce the console for ``radarcal run --ui`` (the CLI's one call)."""
    from radarcal.runtime.console.server import parse_bind

    host, port = parse_bind(bind)
    srv = WebServer(host, port, name="console")
    T = bundle.T(camera_name, lidar_name) if lidar_name else None
    con = LiveConsole(srv, pipeline.field_model, pipeline.camera, T, info)
    srv.start()
    srv.announce()
    sys.stderr.flush()
    return con
