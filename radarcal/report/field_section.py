"""The field-pose and run-track sections of the report: :class:`radarcal.pnp.session.FieldPnPSession` files (exactly
the names ``radarcal field-pnp`` writes) and ``radarcal run`` track files."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from radarcal.camera import Camera
from radarcal.errors import InputError
from radarcal.pnp.session import FieldPnPSession
from radarcal.report import field as rf
from radarcal.report.html import Section
from radarcal.report.sections_common import FigureAdder, note_missing_image, str_list

__all__ = ["field_drawing_args", "FieldData", "field_data", "field_section", "read_tracks", "run_section"]


def field_drawing_args(field_model: Any) -> dict:
    """``size``, ``landmarks`` and ``outline`` polygons for the field figures, from a FieldModel or its dict."""
    if field_model is None:
        return {}
    d = field_model.to_dict() if hasattr(field_model, "to_dict") else dict(field_model)
    outline = []
    if d.get("outline") is not None and len(d["outline"]):
        outline.append(np.asarray(d["outline"], float))
    for a in d.get("areas") or []:
        if a.get("polygon") is not None:
            outline.append(np.asarray(a["polygon"], float))
    size = tuple(float(v) for v in (d.get("size") or (28.0, 15.0))[:2])
    lms = {str(k): np.asarray(v, float) for k, v in (d.get("landmarks") or {}).items()}
    return {"size": size, "landmarks": lms, "outline": outline}


@dataclass
class FieldData:
    """A ``field_pnp/<camera>`` session arranged for the figures."""

    names: list[str] = field(default_factory=list)
    uv_picked: np.ndarray | None = None
    uv_reprojected: np.ndarray | None = None
    pick_outlier: np.ndarray | None = None
    T_cam_field: np.ndarray | None = None
    grid_x: np.ndarray | None = None
    grid_y: np.ndarray | None = None
    error_maps: dict[str, np.ndarray] = field(default_factory=dict)  # label -> (ny, nx) 1σ error (m)
    rms_px: float | None = None
    depth_source: str | None = None
    image_name: str = ""  # the image the picks were made on, as the session names it
    warnings: list[str] = field(default_factory=list)


def field_data(arrays: dict, meta: dict, T_cam_field: np.ndarray | None = None) -> FieldData:
    """A field-pnp session (:class:`FieldPnPSession`) arranged for the figures; ``T_cam_field``: the bundle's, when
    the session holds none."""
    s = FieldPnPSession.from_parts(arrays, meta)
    d = FieldData()
    d.names = str_list(s.names)
    d.uv_picked = s.uv
    if s.uv is not None and s.residuals_px is not None:
        d.uv_reprojected = np.asarray(s.uv, float) - np.asarray(s.residuals_px, float)  # residual = picked - projected
    d.pick_outlier = None if s.inliers is None else ~np.asarray(s.inliers, bool)
    d.T_cam_field = np.asarray(s.T_cam_field, float) if s.T_cam_field is not None else T_cam_field
    d.grid_x, d.grid_y = s.grid_x, s.grid_y
    if s.sigma_lidar is not None:
        d.error_maps["depth from the LiDAR"] = s.sigma_lidar
    if s.sigma_ground is not None:
        d.error_maps["ground-plane fallback (no depth)"] = s.sigma_ground
    d.rms_px = s.rms_px
    d.depth_source = s.depth_source or None
    d.image_name = s.image or ""
    d.warnings = [str(w) for w in s.warnings or []]
    return d


def field_section(camera_name: str, camera: Camera | None, arrays: dict, meta: dict, field_model: Any, T_cam_field: np.ndarray | None, image: np.ndarray | None = None, skipped: list[str] | None = None) -> Section:
    sec = Section(f"Field pose: {camera_name}")
    add = FigureAdder(sec, skipped if skipped is not None else [])
    fa = field_drawing_args(field_model)
    d = field_data(arrays, meta, T_cam_field)
    for w in d.warnings:
        sec.add(f"warning: {w}")
    add("field and landmarks", lambda: rf.field_landmarks_figure(fa["size"], fa["landmarks"], d.T_cam_field, d.names, fa["outline"]), {"field model": fa or None})
    size = camera.image_size if camera is not None else (1280, 1024)
    if image is None and d.uv_picked is not None:
        note_missing_image(sec, add.skipped, "picks and residuals", d.image_name)
    add("picks and residuals", lambda: rf.picks_residual_figure(size, d.names, d.uv_picked, d.uv_reprojected, image, outlier=d.pick_outlier), {"picked pixels": d.uv_picked, "reprojected landmarks": d.uv_reprojected})
    if not d.error_maps:
        add("localisation error map", lambda: None, {"error map": None})
    for label, s in d.error_maps.items():
        title = f"Expected 1σ localisation error, {label}" + (" (used)" if d.depth_source and d.depth_source in label.lower() else "")
        add(f"error map ({label})", lambda s=s, title=title: rf.localisation_error_figure(d.grid_x, d.grid_y, s, fa.get("size", (28.0, 15.0)), d.T_cam_field, fa.get("landmarks"), fa.get("outline"), title=title), {"grid x": d.grid_x, "grid y": d.grid_y})
    return sec


# --- run tracks ---------------------------------------------------------------------------------------------------------
def read_tracks(path: str | os.PathLike, what: str = "track file") -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """A ``radarcal run`` track file (JSON lines, one per frame: ``{"t": s, "robots": [{"label", "x", "y", "z"}]}``) or
    a ``synth field`` ``truth.jsonl`` (robots with ``p_field`` [x, y, z]) -> (times per label, field xyz (N, 3) per label).
    ``InputError`` naming the file: missing, a folder, not text, a line that is not a track record, no robot position,
    a non-finite time or position."""
    from radarcal.errors import read_text

    path = Path(path)
    if path.is_dir():
        raise InputError(path, f"is a folder, expected a {what}")
    t_by: dict[str, list[float]] = {}
    p_by: dict[str, list[list[float]]] = {}
    lines = read_text(path, what).splitlines()
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            t = float(rec["t"])
            for r in rec.get("robots", []):
                p = _robot_xyz(r)
                if p is None:
                    continue
                t_by.setdefault(str(r["label"]), []).append(t)
                p_by.setdefault(str(r["label"]), []).append(p)
        except (ValueError, TypeError, AttributeError, KeyError) as e:
            raise InputError(path, f"line {i}: not a track record ({e.__class__.__name__}: {e})") from None
    if not p_by:
        raise InputError(path, f"no robot positions in the {what} (expected JSON lines {{\"t\", \"robots\": [{{\"label\", \"x\", \"y\"}}]}} as written by radarcal run --out)")
    times = {k: np.asarray(v, float) for k, v in t_by.items()}
    xyz = {k: np.asarray(v, float).reshape(-1, 3) for k, v in p_by.items()}
    if not all(np.all(np.isfinite(v)) for v in (*times.values(), *xyz.values())):
        raise InputError(path, f"non-finite time or position in the {what}")
    return times, xyz


def _robot_xyz(r: dict) -> list[float] | None:
    """x y z of one robot: ``x``/``y``/``z`` (run) or ``p_field`` (truth)."""
    if "x" in r and "y" in r:
        return [float(r["x"]), float(r["y"]), float(r.get("z") or 0.0)]
    v = r.get("p_field")
    if isinstance(v, (list, tuple)) and len(v) >= 2:
        return [float(v[0]), float(v[1]), float(v[2]) if len(v) > 2 and v[2] is not None else 0.0]
    return None


def run_section(tracks_t: dict, tracks_p: dict, field_model: Any = None, truth_t: dict | None = None, truth_p: dict | None = None, skipped: list[str] | None = None) -> Section:
    """Minimap with tracks; with truth (same labels), error over time (truth interpolated at the track times)."""
    sec = Section("Run: tracks")
    add = FigureAdder(sec, skipped if skipped is not None else [])
    fa = field_drawing_args(field_model) or {"size": (28.0, 15.0), "landmarks": None, "outline": None}
    truth_xy = None
    if truth_t and truth_p:
        truth_xy = {k: truth_p[k] for k in tracks_p if k in truth_p}
    add("minimap", lambda: rf.minimap_tracks_figure(fa["size"], tracks_p, truth_xy, fa["outline"], None))
    if truth_t and truth_p:
        common = sorted(set(tracks_p) & set(truth_p))
        err = {}
        for k in common:
            tt, tp = np.asarray(truth_t[k], float), np.asarray(truth_p[k], float)
            order = np.argsort(tt)
            tx = np.interp(tracks_t[k], tt[order], tp[order, 0], left=np.nan, right=np.nan)
            ty = np.interp(tracks_t[k], tt[order], tp[order, 1], left=np.nan, right=np.nan)
            err[k] = np.hypot(tracks_p[k][:, 0] - tx, tracks_p[k][:, 1] - ty)
        add("error over time", lambda: rf.error_over_time_figure({k: tracks_t[k] for k in err}, err), {"labels shared with the truth": err or None})
    return sec
