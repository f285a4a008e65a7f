"""``radarcal field-pnp --ui [HOST:]PORT``: click the landmarks on the camera frame in the browser (docs/field.md).

The page shows the frame (zoom with the wheel or ``z``, pan by dragging with the right button or shift), asks for the
landmarks in the order given (``--landmarks``, default the side's ``DEFAULT_PICKS``; names shown, the current one
highlighted), lets picks be dragged to refine them, and after every change draws what the pose sees: the field
outline, raised areas and every landmark reprojected, with the residual of each pick. Before four picks it shows the
bundle's stored pose (if any), so the same page checks a pose before the match. Keys nudge the six pose parameters
(:data:`NUDGE_PARAMS`) in coarse / medium / fine steps (:data:`STEPS`).

Saving calls the command's own ``check`` (the same solver, options and checks as ``--points picks.csv``); when it
passes, :func:`pick_in_browser` returns the picks (and the nudged pose, if any) and the command writes the picks CSV,
the bundle entry and the session exactly as the CSV path does. Actions need the run's token (radarcal.runtime.console).
"""

from __future__ import annotations

import dataclasses
import json
import threading
from collections.abc import Callable

import numpy as np

from radarcal import geometry
from radarcal.errors import InputError
from radarcal.pnp.field_pnp import (
    FieldPnPError,
    FieldPnPResult,
    PnPOptions,
    solve_field_pnp,
)

__all__ = ["NUDGE_PARAMS", "STEPS", "apply_nudge", "field_overlay", "pick_in_browser", "pose_result", "preview", "view_angles_deg"]

# x y z: camera position in the field frame (m); yaw: about the field's vertical through the camera; pitch: about the
# camera's x axis (+ tilts the view up); roll: about the camera's optical axis (deg at the interface).
NUDGE_PARAMS = ("x", "y", "z", "yaw", "pitch", "roll")
STEPS = {"coarse": (0.5, 2.0), "medium": (0.1, 0.5), "fine": (0.02, 0.1)}  # (metres, degrees) per key press
PACKAGE = "radarcal.pnp"


def apply_nudge(T_cam_field: np.ndarray, nudge) -> np.ndarray:
    """``T_cam_field`` moved by ``nudge`` = [dx, dy, dz (m, field frame), dyaw, dpitch, droll (deg)] (see NUDGE_PARAMS)."""
    d = np.asarray(nudge, float).reshape(6)
    T_field_cam = geometry.invert_T(np.asarray(T_cam_field, float))
    R = T_field_cam[:3, :3]
    Rz = geometry.rpy_deg_to_R(0.0, 0.0, d[3])
    Rx = geometry.rpy_deg_to_R(d[4], 0.0, 0.0)
    Rroll = geometry.rpy_deg_to_R(0.0, 0.0, d[5])  # camera z is its optical axis
    return geometry.invert_T(geometry.make_T(Rz @ R @ Rx @ Rroll, T_field_cam[:3, 3] + d[:3]))


def view_angles_deg(T_cam_field: np.ndarray) -> np.ndarray:
    """The three angles the nudge keys turn, as an operator reads them: heading of the optical axis (deg from field
    +x towards +y), its tilt (deg, + up) and the roll of the image about it (deg, 0 = image x axis horizontal)."""
    T = geometry.invert_T(np.asarray(T_cam_field, float))
    x, z = T[:3, 0], T[:3, 2]
    heading = np.degrees(np.arctan2(z[1], z[0]))
    tilt = np.degrees(np.arcsin(np.clip(z[2], -1, 1)))
    roll = np.degrees(np.arcsin(np.clip(x[2] / max(np.linalg.norm(np.cross(z, [0.0, 0.0, 1.0])), 1e-12), -1, 1)))
    return np.array([heading, tilt, -roll])


def field_overlay(camera, T_cam_field: np.ndarray, field_model, samples: int = 40) -> dict:
    """What the pose sees, in pixels: polylines of the outline and raised-area top edges (sampled, so distortion
    bends them; pieces behind the camera dropped) and every landmark's projection (None when not in front)."""
    lines = []

    def polyline(poly_xyz: np.ndarray, kind: str) -> None:
        closed = np.vstack([poly_xyz, poly_xyz[:1]])
        s = np.linspace(0, 1, samples)[None, :, None]
        pts = (closed[:-1, None] * (1 - s) + closed[1:, None] * s).reshape(-1, 3)
        q, valid, _ = camera.project_from(T_cam_field, pts)
        q = q.reshape(len(closed) - 1, -1, 2)
        valid = valid.reshape(len(closed) - 1, -1) & (np.abs(q) < 1e5).all(-1)
        for seg, ok in zip(q, valid):
            seg = seg[ok]
            if len(seg) > 1:
                lines.append({"kind": kind, "uv": np.round(seg, 2).tolist()})

    o = np.asarray(field_model.outline, float)
    polyline(np.column_stack([o, np.zeros(len(o))]), "outline")
    for a in field_model.areas:
        poly = np.asarray(a["polygon"], float)
        pa, pb, pc = a["plane"] if a.get("plane") is not None else (0.0, 0.0, a["z"])
        polyline(np.column_stack([poly, pa * poly[:, 0] + pb * poly[:, 1] + pc]), "area")
    names = list(field_model.landmarks)
    q, valid, _ = camera.project_from(T_cam_field, field_model.landmark_array(names))
    lm = {n: ([round(float(p[0]), 3), round(float(p[1]), 3)] if ok and np.all(np.abs(p) < 1e5) else None) for n, p, ok in zip(names, q, valid)}
    return {"lines": lines, "landmarks": lm}


def pose_result(camera, res: FieldPnPResult, T_cam_field: np.ndarray, options: PnPOptions | None = None) -> FieldPnPResult:
    """The solver's result with the pose replaced by a hand-nudged one: residuals, RMS and camera position recomputed
    at that pose and the same RMS check (σ stays the solver's, from the clicks). Raises FieldPnPError."""
    opt = options or PnPOptions()
    q, valid, _ = camera.project_from(T_cam_field, res.p_field)
    if not valid.all():
        raise FieldPnPError("the nudged pose puts picked landmarks behind the camera")
    r = res.uv - q
    rms = float(np.sqrt(np.mean(np.sum(r[res.inliers] ** 2, axis=1))))
    if rms > opt.max_rms_px:
        raise FieldPnPError(f"the nudged pose is {rms:.1f} px RMS from the picks, above the threshold {opt.max_rms_px:g} px")
    dang, dpos = geometry.pose_error(T_cam_field, res.T_cam_field)
    T_field_cam = geometry.invert_T(T_cam_field)
    warn = f"pose nudged by hand: {dang:.3f} deg / {dpos:.3f} m from the PnP solution ({res.rms_px:.2f} -> {rms:.2f} px RMS)"
    return dataclasses.replace(res, T_cam_field=np.asarray(T_cam_field, float), residuals_px=r, rms_px=rms, camera_position=T_field_cam[:3, 3].copy(),
                               method=res.method + " + manual nudge", warnings=[*res.warnings, warn])  # fmt: skip


def preview(camera, field_model, names: list[str], uv: np.ndarray, nudge, options: PnPOptions | None = None, T_init: np.ndarray | None = None) -> dict:
    """The page's live feedback: solve from the picks (>= 4, the same solver and options as the command), else the
    stored pose; apply the nudge; project the field and the picks' residuals."""
    out: dict = {"solved": False, "error": None, "pose": None, "rms_px": None, "residuals": {}, "overlay": None, "base": None}
    T = None
    if len(names) >= 4:
        try:
            res = solve_field_pnp(camera, field_model.landmark_array(names), uv, names, options, surface_z=field_model.surface_z)
            T, out["solved"], out["base"] = res.T_cam_field, True, "picks"
            out["warnings"] = res.warnings
            out["inliers"] = {n: bool(k) for n, k in zip(names, res.inliers)}
        except FieldPnPError as e:
            out["error"] = str(e)
    if T is None and T_init is not None:
        T, out["base"] = np.asarray(T_init, float), "bundle"
    if T is None:
        return out
    T = apply_nudge(T, nudge) if np.any(np.asarray(nudge, float) != 0) else T
    T_field_cam = geometry.invert_T(T)
    out["pose"] = [round(float(v), 4) for v in geometry.T_to_xyz_rpy_deg(T_field_cam)]
    out["view_deg"] = [round(float(v), 3) for v in view_angles_deg(T)]
    out["overlay"] = field_overlay(camera, T, field_model)
    if len(names):
        q, valid, _ = camera.project_from(T, field_model.landmark_array(names))
        r = np.where(valid[:, None], uv - q, np.nan)
        out["residuals"] = {n: (None if not ok else [round(float(a), 3), round(float(b), 3)]) for n, (a, b), ok in zip(names, r, valid)}
        ok = valid
        if ok.any():
            out["rms_px"] = round(float(np.sqrt(np.mean(np.sum(r[ok] ** 2, axis=1)))), 3)
    return out


def _picks_from(args: dict, known: dict) -> tuple[list[str], np.ndarray, np.ndarray]:
    picks = args.get("picks") or {}
    if not isinstance(picks, dict):
        raise TypeError("picks must be an object name -> [u, v]")
    names, uv = [], []
    for n, p in picks.items():
        if n not in known:
            raise ValueError(f"unknown landmark {n!r}")
        u, v = (float(p[0]), float(p[1]))
        if not (np.isfinite(u) and np.isfinite(v)):
            raise ValueError(f"non-finite pick for {n}")
        names.append(str(n))
        uv.append((u, v))
    nudge = np.asarray(args.get("nudge") or [0.0] * 6, float).reshape(6)
    if not np.all(np.isfinite(nudge)):
        raise ValueError("non-finite nudge")
    return names, np.array(uv, float).reshape(-1, 2), nudge


def pick_in_browser(image_bgr: np.ndarray, camera, field_model, order: list[str], check: Callable, bind: str = "127.0.0.1:0",
                    T_init: np.ndarray | None = None, options: PnPOptions | None = None, initial: dict | None = None,
                    ready: Callable | None = None, log=None) -> tuple[list[str], np.ndarray, np.ndarray | None]:  # fmt: skip
    """Serve the clicking page until a save passes ``check(names, uv, T_nudged_or_None) -> dict`` (it raises
    InputError / FieldPnPError with the reason, shown on the page). Returns names, picks (N,2), the nudged
    ``T_cam_field`` or None. ``initial``: picks to start from (name -> (u, v)). Ctrl-C: InputError, nothing written."""
    import cv2

    from radarcal.runtime.console.server import WebServer, asset, parse_bind

    host, port = parse_bind(bind)
    srv = WebServer(host, port, name="field-pnp", log=log)
    ok, png = cv2.imencode(".png", image_bgr)
    if not ok:
        raise InputError("--ui", "cannot encode the image for the page")
    png = png.tobytes()
    extras = [n for n in sorted(field_model.landmarks) if n not in order]
    setup = {"order": list(order), "extras": extras, "image_size": [int(image_bgr.shape[1]), int(image_bgr.shape[0])],
             "camera_size": [int(camera.width), int(camera.height)], "params": list(NUDGE_PARAMS), "steps": STEPS,
             "has_stored_pose": T_init is not None, "initial": {k: [float(v[0]), float(v[1])] for k, v in (initial or {}).items()},
             "landmarks": {n: np.asarray(p, float).round(3).tolist() for n, p in field_model.landmarks.items()}}  # fmt: skip
    done = threading.Event()
    result: dict = {}

    def update(args: dict) -> dict:
        names, uv, nudge = _picks_from(args, field_model.landmarks)
        return preview(camera, field_model, names, uv, nudge, options, T_init)

    def save(args: dict) -> dict:
        names, uv, nudge = _picks_from(args, field_model.landmarks)
        if done.is_set():
            return {"ok": False, "error": "already saved"}
        T_nudged = None
        if np.any(nudge != 0):
            base = preview(camera, field_model, names, uv, np.zeros(6), options, None)
            if not base["solved"]:
                return {"ok": False, "error": base["error"] or "need at least 4 picks to save"}
            T_nudged = apply_nudge(solve_field_pnp(camera, field_model.landmark_array(names), uv, names, options, surface_z=field_model.surface_z).T_cam_field, nudge)
        try:
            summary = check(names, uv, T_nudged)
        except (InputError, FieldPnPError) as e:
            return {"ok": False, "error": str(e)}
        result.update(names=names, uv=uv, T=T_nudged)
        done.set()
        return {"ok": True, "summary": summary}

    srv.get["/"] = lambda q: ("text/html; charset=utf-8", asset(PACKAGE, "pnp.html"))
    srv.get["/pnp.js"] = lambda q: ("text/javascript; charset=utf-8", asset(PACKAGE, "pnp.js"))
    srv.get["/image.png"] = lambda q: ("image/png", png)
    srv.get["/api/setup"] = lambda q: ("application/json", json.dumps(setup).encode())
    srv.actions["update"] = update
    srv.actions["save"] = save
    srv.serve_until(done, ready, "closed without saving: nothing written")
    return result["names"], result["uv"], result["T"]
