"""``radarcal lidar-camera --ui [HOST:]PORT``: nudge the initial ``T_cam_lidar`` by eye with the cloud drawn over the
image in the browser, before the command solves (docs/console.md).

The server draws the first pair's cloud over its image through the current pose (``overlay.overlay_cloud``, the one
projection) and sends it as a JPEG after every change; the keys move the pose in the camera frame
(:data:`NUDGE_PARAMS`) by the same coarse / medium / fine steps as field-pnp's page. "use this pose" returns the
nudged pose, which the command then uses as its initial guess (``--init``) for the refinement or board pairing.
Actions need the run's token (radarcal.runtime.console.server).
"""

from __future__ import annotations

import json
import threading

import numpy as np

from radarcal import geometry
from radarcal.pnp.ui import STEPS

__all__ = ["NUDGE_PARAMS", "apply_nudge", "nudge_in_browser"]

# tx ty tz: the LiDAR's origin moved along the camera's axes (right, down, forward; m); tilt / pan / roll: the cloud
# turned about the camera's x (right), y (down) and z (optical) axes (deg)
NUDGE_PARAMS = ("tx", "ty", "tz", "tilt", "pan", "roll")
PACKAGE = "radarcal.extrinsics"


def apply_nudge(T_cam_lidar: np.ndarray, nudge) -> np.ndarray:
    """``T_cam_lidar`` moved by ``nudge`` = [tx, ty, tz (m), tilt, pan, roll (deg)] in the camera frame:
    ``R' = Rz(roll) Ry(pan) Rx(tilt) R``, ``t' = Rz Ry Rx t + [tx, ty, tz]`` (a rotation of the cloud about the camera)."""
    d = np.asarray(nudge, float).reshape(6)
    Rd = geometry.rpy_deg_to_R(d[3], d[4], d[5])
    T = np.asarray(T_cam_lidar, float)
    return geometry.make_T(Rd @ T[:3, :3], Rd @ T[:3, 3] + d[:3])


def nudge_in_browser(image_bgr: np.ndarray, camera, points_lidar: np.ndarray, T_init: np.ndarray, bind: str = "127.0.0.1:0", max_range: float = 60.0,
                     ready=None, log=None) -> np.ndarray:  # fmt: skip
    """Serve the nudge page until the operator takes a pose; returns it (``T_cam_lidar``). Ctrl-C: InputError."""
    import cv2

    from radarcal.extrinsics.overlay import overlay_cloud
    from radarcal.runtime.console.server import WebServer, asset, parse_bind

    host, port = parse_bind(bind)
    srv = WebServer(host, port, name="lidar-camera", log=log)
    pts = np.asarray(points_lidar, float)
    pts = pts[np.linalg.norm(pts, axis=1) < max_range]
    if len(pts) > 150_000:
        pts = pts[np.random.default_rng(0).choice(len(pts), 150_000, replace=False)]
    state = {"jpeg": None}
    lock = threading.Lock()
    done = threading.Event()
    result: dict = {}

    def render(nudge) -> bytes:
        T = apply_nudge(T_init, nudge)
        img = overlay_cloud(image_bgr, camera, T, pts)
        _, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 85])
        return buf.tobytes()

    def parse(args: dict) -> np.ndarray:
        d = np.asarray(args.get("nudge") or [0.0] * 6, float).reshape(6)
        if not np.all(np.isfinite(d)) or np.any(np.abs(d[:3]) > 5) or np.any(np.abs(d[3:]) > 45):
            raise ValueError("nudge out of range (|t| <= 5 m, |angle| <= 45 deg)")
        return d

    def update(args: dict) -> dict:
        d = parse(args)
        jpg = render(d)
        with lock:
            state["jpeg"] = jpg
            state["n"] = state.get("n", 0) + 1
        T = apply_nudge(T_init, d)
        return {"frame": state["n"], "pose": [round(float(v), 4) for v in geometry.T_to_xyz_rpy_deg(T)], "moved_deg_m": list(geometry.pose_error(T, T_init))}

    def take(args: dict) -> dict:
        result["T"] = apply_nudge(T_init, parse(args))
        done.set()
        return {"ok": True}

    state["jpeg"], state["n"] = render(np.zeros(6)), 0
    setup = {"params": list(NUDGE_PARAMS), "steps": STEPS, "image_size": [int(image_bgr.shape[1]), int(image_bgr.shape[0])], "points": len(pts)}
    srv.get["/"] = lambda q: ("text/html; charset=utf-8", asset(PACKAGE, "nudge.html"))
    srv.get["/api/setup"] = lambda q: ("application/json", json.dumps(setup).encode())
    srv.get["/overlay.jpg"] = lambda q: ("image/jpeg", state["jpeg"])
    srv.actions["update"] = update
    srv.actions["take"] = take
    srv.serve_until(done, ready, "closed without taking a pose: nothing written")
    return result["T"]
