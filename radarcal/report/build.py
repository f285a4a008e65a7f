"""Turn a bundle (and the session files its calibration commands saved next to it) into report sections.

This is the I/O edge of :mod:`radarcal.report`: it reads session ``.npz`` files, optional images named in a session's
metadata, and run track files, then calls the pure figure functions. Whatever a session lacks is skipped with a
note in the report, so a report can always be made from what is there.

Session keys (written with :func:`radarcal.bundle.save_session`): ``intrinsics/<camera>``, ``stereo/<cam0>_<cam1>``,
``lidar_camera/<camera>_<lidar>``, ``field_pnp/<camera>``. The arrays each section uses are listed in
``docs/report.md``; several names are accepted for each (``_ALIASES``) so small differences between commands do not
lose a figure.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from radarcal.bundle import Bundle, load_session, read_session_file
from radarcal.camera import Camera
from radarcal.errors import InputError
from radarcal.report import field as rf
from radarcal.report import intrinsics as ri
from radarcal.report import lidar_camera as rl
from radarcal.report.html import Section, Table

__all__ = ["ReportContent", "build_report", "discover_sessions", "read_tracks", "field_drawing_args", "IntrinsicsData", "intrinsics_data", "FieldData", "field_data", "LidarCameraData", "lidar_camera_data"]


@dataclass
class ReportContent:
    sections: list[Section] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # what could not be drawn and why

    @property
    def n_figures(self) -> int:
        return sum(1 for s in self.sections for it in s.items if hasattr(it[0] if isinstance(it, tuple) else it, "savefig"))


# --- array lookup ----------------------------------------------------------------------------------------------------
_ALIASES: dict[str, tuple[str, ...]] = {
    # intrinsics
    "uv": ("uv_observed", "uv_obs", "corners_uv", "uv", "observed_uv", "image_points"),
    "uv_proj": ("uv_projected", "uv_proj", "projected_uv"),
    "residual": ("residual_px", "residuals_px", "residuals", "residual"),
    "view_index": ("view_index", "view_idx", "view_of_point", "view"),
    "view_names": ("view_names", "views", "view_files", "files"),
    "view_error": ("view_error_px", "view_mean_error_px", "per_view_error_px", "view_error", "view_rms_px"),
    "view_outlier": ("view_outlier", "view_rejected", "outlier_views", "view_is_outlier"),
    "point_outlier": ("point_outlier", "corner_outlier", "outlier", "rejected"),
    "sigma_u": ("uncertainty_u", "sigma_grid_u", "uncertainty_grid_u", "grid_u"),
    "sigma_v": ("uncertainty_v", "sigma_grid_v", "uncertainty_grid_v", "grid_v"),
    "sigma_map": ("uncertainty_sigma_px", "uncertainty_px", "sigma_grid_px", "projection_sigma_px", "uncertainty_map", "sigma_grid"),
    "cv_u": ("crossval_u", "cv_grid_u"),
    "cv_v": ("crossval_v", "cv_grid_v"),
    "cv_diff": ("crossval_diff_px", "crossval_diff", "cv_diff_px"),
    "cv_sigma": ("crossval_sigma_px", "crossval_sigma", "cv_sigma_px"),
    # lidar-camera
    "points": ("points_lidar", "cloud_points", "points", "p_lidar"),
    "T_init": ("T_cam_lidar_init", "T_init", "T_before"),
    "T_final": ("T_cam_lidar", "T_final", "T_after"),
    "edge_uv_lidar": ("edge_uv_lidar", "match_uv_lidar", "uv_lidar_edges"),
    "edge_uv_image": ("edge_uv_image", "match_uv_image", "uv_image_edges"),
    "edge_residual": ("edge_residual_px", "match_residual_px", "edge_residual", "residuals_after"),
    "residual_before": ("edge_residual_before_px", "residuals_before"),
    "profile_offsets": ("profile_offsets", "cost_offsets"),
    "profile_costs": ("profile_costs", "cost_profiles", "costs"),
    "sigma6": ("sigma6", "sigma_params", "param_sigma6"),
    # field
    "pick_names": ("pick_names", "names", "landmark_names"),
    "uv_picked": ("uv_picked", "picks_uv", "uv_picks"),
    "uv_reproj": ("uv_reprojected", "uv_reproj", "reprojected_uv"),
    "pick_outlier": ("pick_outlier", "outlier"),
    "err_x": ("error_map_x", "grid_x", "map_x"),
    "err_y": ("error_map_y", "grid_y", "map_y"),
    "err_sigma": ("error_map_m", "error_map", "sigma_m", "map_sigma_m"),
    "T_cam_field": ("T_cam_field",),
}


def _get(arrays: dict[str, np.ndarray], meta: dict, what: str) -> Any:
    for name in _ALIASES.get(what, (what,)):
        if name in arrays:
            return arrays[name]
        if name in meta:
            return meta[name]
    return None


# --- sessions ----------------------------------------------------------------------------------------------------------
def discover_sessions(bundle: Bundle, session_dir: str | os.PathLike | None = None) -> dict[str, tuple[dict, dict]]:
    """All sessions: those referenced by the bundle (looked up in ``session_dir`` by file name when given, for a
    bundle whose session folder moved) plus any other ``*.npz`` in ``session_dir`` (key from the file name,
    ``intrinsics__cam0.npz`` → ``intrinsics/cam0``)."""
    out: dict[str, tuple[dict, dict]] = {}
    sdir = Path(session_dir) if session_dir is not None else None
    if sdir is not None and not sdir.is_dir():
        raise InputError(sdir, "session directory not found")
    for key, rel in sorted(bundle.sessions.items()):
        if sdir is not None and (sdir / Path(rel).name).is_file():
            out[key] = read_session_file(sdir / Path(rel).name)
        else:
            out[key] = load_session(bundle, key)
    if sdir is not None:
        for p in sorted(sdir.glob("*.npz")):
            key = p.stem.replace("__", "/")
            if key not in out:
                out[key] = read_session_file(p)
    return out


def _resolve(name: str, base: Path | None) -> Path | None:
    """A file named in a session: absolute, relative to the bundle's folder, or relative to the working folder."""
    p = Path(name)
    for cand in ([p] if p.is_absolute() else ([base / p] if base is not None else []) + [p]):
        if cand.is_file():
            return cand
    return None


def _read_cloud_file(name: str, base: Path | None) -> np.ndarray | None:
    p = _resolve(name, base)
    if p is None:
        return None
    try:
        from radarcal.io import read_cloud

        return read_cloud(p).points
    except InputError:
        return None


def _read_image_file(name: str, base: Path | None) -> np.ndarray | None:
    """An image named in a session (absolute, or relative to the bundle), or None when it is not there."""
    p = _resolve(name, base)
    if p is None:
        return None
    try:
        from radarcal.io import read_image

        return read_image(p)
    except InputError:
        return None


def _read_image_from_meta(meta: dict, base: Path | None, *keys: str) -> np.ndarray | None:
    """The first readable image among the files ``meta[key]`` names (a path or a list of paths)."""
    for k in keys:
        v = meta.get(k)
        if isinstance(v, list):
            v = v[0] if v else None
        if v:
            img = _read_image_file(str(v), base)
            if img is not None:
                return img
    return None


# --- helpers --------------------------------------------------------------------------------------------------------
class _Adder:
    """Adds figures to a section, turning a failure into a note instead of losing the whole report."""

    def __init__(self, section: Section, skipped: list[str]):
        self.section = section
        self.skipped = skipped

    def __call__(self, label: str, make: Callable[[], Any], needs: dict[str, Any] | None = None, caption: str = "") -> None:
        missing = [k for k, v in (needs or {}).items() if v is None]
        if missing:
            msg = f"{self.section.title}: {label} skipped (session lacks {', '.join(missing)})"
            self.skipped.append(msg)
            self.section.add(f"{label}: not available (the session does not contain {', '.join(missing)}).")
            return
        try:
            self.section.add(make(), caption)
        except (ValueError, KeyError, IndexError, TypeError) as e:
            msg = f"{self.section.title}: {label} failed ({e.__class__.__name__}: {e})"
            self.skipped.append(msg)
            self.section.add(f"{label}: could not be drawn ({e}).")


def _str_list(a: Any) -> list[str]:
    if a is None:
        return []
    return [str(x) for x in np.asarray(a).ravel()]


def _camera_param_table(name: str, entry) -> Table:
    cam = entry.camera
    dist_names = ["k1", "k2", "k3", "k4"] if cam.model == "fisheye" else ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4"]
    names = ["fx", "fy", "cx", "cy"] + dist_names[: cam.dist.size]
    values = [cam.fx, cam.fy, cam.cx, cam.cy] + list(cam.dist)
    units = ["px"] * 4 + [""] * cam.dist.size
    sig = entry.sigma or {}
    rows = []
    for n, v, u in zip(names, values, units):
        s = sig.get(n)
        vs, ss = ri.format_value_sigma(float(v), None if s is None else float(s))
        rows.append([n, vs, ss, u])
    if entry.rms_px is not None:
        rows.append(["RMS", f"{entry.rms_px:.4f}", "", "px"])
    return Table(["parameter", "value", "σ", "unit"], rows, caption=f"{name}: {cam.model}, {cam.width}×{cam.height}")


def _overview(bundle: Bundle, skip_cameras: set[str] = frozenset()) -> Section:
    sec = Section("Bundle overview")
    path = str(bundle.path) if bundle.path else "(in memory)"
    sec.add(f"Bundle {path}: {len(bundle.cameras)} camera(s), {len(bundle.transforms)} transform(s), {len(bundle.sessions)} session file(s).")
    for name, entry in sorted(bundle.cameras.items()):
        if name not in skip_cameras:  # those get their table in their intrinsics section
            sec.add(_camera_param_table(name, entry))
    if bundle.transforms:
        from radarcal.geometry import T_to_xyz_rpy_deg

        rows = []
        for key, e in sorted(bundle.transforms.items()):
            with warnings.catch_warnings():  # gimbal lock of the rpy display is harmless here
                warnings.simplefilter("ignore")
                xyzrpy = T_to_xyz_rpy_deg(e.T)
            sig = e.sigma or {}
            sig_txt = ", ".join(f"{k}={v:.3g}" for k, v in sig.items() if isinstance(v, (int, float))) or "—"
            res = e.residual or {}
            res_txt = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in res.items() if isinstance(v, (int, float, str))) or "—"
            rows.append([key, e.method or "—", *(f"{v:.4f}" for v in xyzrpy[:3]), *(f"{v:.3f}" for v in xyzrpy[3:]), sig_txt, res_txt])
        sec.add(Table(["transform", "method", "x (m)", "y (m)", "z (m)", "roll (°)", "pitch (°)", "yaw (°)", "σ", "residual"], rows, caption="Transforms (T_a_b maps b into a)"))
    return sec


# --- sections ----------------------------------------------------------------------------------------------------------
@dataclass
class IntrinsicsData:
    """An intrinsics session normalised for the figures (any field may be None when the session lacks it)."""

    camera: Camera
    uv: np.ndarray | None = None  # (N,2) observed corners
    residual: np.ndarray | None = None  # (N,2) observed − projected, px
    corner_view: np.ndarray | None = None  # (N,) index into view_names
    corner_outlier: np.ndarray | None = None  # (N,) bool
    view_names: list[str] = field(default_factory=list)
    view_files: list[str] = field(default_factory=list)  # image file of each view, when the session names them
    view_error: np.ndarray | None = None  # (V,) px
    view_error_label: str = "mean |residual| (px)"
    view_outlier: np.ndarray | None = None  # (V,) bool
    rejected: list[list[str]] = field(default_factory=list)  # [input, reason] of inputs never solved
    noise_px: float | None = None
    rms_px: float | None = None
    sigma_u: np.ndarray | None = None
    sigma_v: np.ndarray | None = None
    sigma_px: np.ndarray | None = None
    valid_threshold_px: float = 1.0
    cv_u: np.ndarray | None = None
    cv_v: np.ndarray | None = None
    cv_diff_px: np.ndarray | None = None
    cv_sigma_px: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)

    def worst_view(self) -> int | None:
        """Index of the solved view with the largest error among those the solver kept (None if unknown)."""
        if self.view_error is None or np.size(self.view_error) == 0:
            return None
        e = np.asarray(self.view_error, float).copy()
        if self.view_outlier is not None and not np.all(self.view_outlier):
            e[np.asarray(self.view_outlier, bool)] = -np.inf
        return int(np.nanargmax(np.where(np.isfinite(e), e, -np.inf)))

    def view_mask(self, k: int) -> np.ndarray:
        """Mask of the corners of solved view ``k``."""
        return np.asarray(self.corner_view, int).ravel() == k

    def inlier_residuals(self) -> np.ndarray | None:
        """Residuals of corners that are neither outliers nor in an outlier view."""
        if self.residual is None:
            return None
        r = np.asarray(self.residual, float).reshape(-1, 2)
        bad = np.zeros(len(r), bool) if self.corner_outlier is None else np.asarray(self.corner_outlier, bool).ravel()
        if self.view_outlier is not None and self.corner_view is not None:
            vo = np.asarray(self.view_outlier, bool).ravel()
            bad = bad | vo[np.clip(np.asarray(self.corner_view, int).ravel(), 0, vo.size - 1)]
        return r[~bad]


def intrinsics_data(arrays: dict, meta: dict, camera: Camera, rms_px: float | None = None) -> IntrinsicsData:
    """Normalise an ``intrinsics/<camera>`` session (the layout ``radarcal intrinsics`` writes, or the generic
    names of ``_ALIASES``). ``camera`` is used when the session does not carry its own K/dist/image_size."""
    summary = meta.get("summary") if isinstance(meta.get("summary"), dict) else {}
    uv = _get(arrays, meta, "uv")
    res = _get(arrays, meta, "residual")
    if res is None and uv is not None and _get(arrays, meta, "uv_proj") is not None:
        res = np.asarray(uv, float) - np.asarray(_get(arrays, meta, "uv_proj"), float)
    d = IntrinsicsData(camera=camera, uv=uv, residual=res)
    if "corner_view" in arrays:
        # `radarcal intrinsics` layout: names/status of every input; view_index = the solved views' input index;
        # corner_view = solved-view index per corner; inliers per corner; view_used / view_rms_px per solved view
        d.corner_view = np.asarray(arrays["corner_view"], int)
        all_names = _str_list(arrays.get("names"))
        vi = np.asarray(arrays.get("view_index", np.arange(int(np.max(d.corner_view, initial=-1)) + 1)), int).ravel()
        d.view_files = [all_names[i] if 0 <= i < len(all_names) else "" for i in vi]
        d.view_names = [Path(f).name if f else f"view {i}" for f, i in zip(d.view_files, vi)]
        d.view_error = arrays.get("view_rms_px")
        d.view_error_label = "RMS of inlier residuals (px)"
        d.view_outlier = ~np.asarray(arrays["view_used"], bool) if "view_used" in arrays else None
        if d.view_error is not None and d.view_outlier is not None and res is not None and d.view_outlier.any():
            # a rejected view's inlier RMS hides why it was rejected: show the RMS over all its corners
            r2 = np.sum(np.asarray(res, float).reshape(-1, 2) ** 2, axis=1)
            ok = np.isfinite(r2)
            n = d.view_outlier.size
            rms_all = np.sqrt(np.bincount(d.corner_view[ok], r2[ok], n) / np.maximum(np.bincount(d.corner_view[ok], None, n), 1))
            d.view_error = np.where(d.view_outlier, rms_all, np.asarray(d.view_error, float))
            d.view_error_label = "RMS residual (px; rejected views: all corners)"
        d.corner_outlier = ~np.asarray(arrays["inliers"], bool) if "inliers" in arrays else None
        status = _str_list(arrays.get("status"))
        d.rejected = [[Path(n).name, st] for n, st in zip(all_names, status) if st != "used"]
    else:
        vidx = _get(arrays, meta, "view_index")
        d.corner_view = None if vidx is None else np.asarray(vidx, int)
        d.view_names = _str_list(_get(arrays, meta, "view_names"))
        d.view_error = _get(arrays, meta, "view_error")
        d.view_outlier = _get(arrays, meta, "view_outlier")
        d.corner_outlier = _get(arrays, meta, "point_outlier")
    if d.view_error is None and res is not None and d.corner_view is not None:
        cv = d.corner_view.ravel()
        n_views = max(len(d.view_names), int(cv.max()) + 1 if cv.size else 0)
        mag = np.linalg.norm(np.asarray(res, float).reshape(-1, 2), axis=1)
        d.view_error = np.bincount(cv, mag, n_views) / np.maximum(np.bincount(cv, None, n_views), 1)
    if d.view_error is not None and len(d.view_names) != np.size(d.view_error):
        d.view_names = [f"view {i}" for i in range(np.size(d.view_error))]
    if all(k in arrays for k in ("K", "dist", "image_size")):  # the camera this session was solved for
        model = "fisheye" if str(summary.get("model", meta.get("model", ""))).startswith("fisheye") else camera.model
        try:
            d.camera = Camera(tuple(int(x) for x in np.asarray(arrays["image_size"]).ravel()[:2]), arrays["K"], arrays["dist"], model)
        except ValueError:
            pass
    d.noise_px = meta.get("noise_sigma_px", meta.get("sigma_px", meta.get("expected_noise_px", summary.get("noise_px"))))
    d.rms_px = meta.get("rms_px", summary.get("rms_px", rms_px))
    d.sigma_u, d.sigma_v, d.sigma_px = _get(arrays, meta, "sigma_u"), _get(arrays, meta, "sigma_v"), _get(arrays, meta, "sigma_map")
    unc = summary.get("uncertainty") if isinstance(summary.get("uncertainty"), dict) else {}
    d.valid_threshold_px = float(meta.get("valid_threshold_px", meta.get("uncertainty_threshold_px", unc.get("threshold_px", d.noise_px if d.noise_px else 1.0))))
    d.cv_u, d.cv_v, d.cv_diff_px, d.cv_sigma_px = _get(arrays, meta, "cv_u"), _get(arrays, meta, "cv_v"), _get(arrays, meta, "cv_diff"), _get(arrays, meta, "cv_sigma")
    d.warnings = [str(w) for w in summary.get("warnings") or []]
    return d


def intrinsics_section(camera_name: str, camera: Camera, arrays: dict, meta: dict, entry=None, image: np.ndarray | None = None, skipped: list[str] | None = None, base: Path | None = None) -> Section:
    """Every intrinsics figure the session allows."""
    sec = Section(f"Intrinsics: {camera_name}")
    add = _Adder(sec, skipped if skipped is not None else [])
    d = intrinsics_data(arrays, meta, camera, entry.rms_px if entry is not None else None)
    size = d.camera.image_size
    if entry is not None:
        sec.add(_camera_param_table(camera_name, entry))
    if d.rejected:
        sec.add(Table(["input", "why not used"], d.rejected, caption=f"{len(d.rejected)} input(s) not used"))
    for w in d.warnings:
        sec.add(f"warning: {w}")
    add("per-view error", lambda: ri.per_view_error_figure(d.view_names, d.view_error, d.view_outlier, meta.get("view_threshold_px"), d.rms_px, ylabel=d.view_error_label), {"per-view errors": d.view_error})
    add("residual vectors", lambda: ri.residual_vectors_figure(d.uv, d.residual, size, image=image, outlier=d.corner_outlier, title="Residual vectors, all views"), {"corner pixels": d.uv, "residuals": d.residual})
    k = d.worst_view()
    if k is not None and d.corner_view is not None and k < len(d.view_files) and d.uv is not None and d.residual is not None:
        img = _read_image_file(d.view_files[k], base)
        if img is not None:
            m = d.view_mask(k)
            sec.add(ri.residual_vectors_figure(np.asarray(d.uv)[m], np.asarray(d.residual)[m], size, image=img, outlier=None if d.corner_outlier is None else np.asarray(d.corner_outlier)[m], title=f"Residual vectors on the worst kept view, {d.view_names[k]}"))
    add("residual histogram", lambda: ri.residual_histogram_figure(d.inlier_residuals(), d.noise_px, title="Residuals (inliers) against the expected noise"), {"residuals": d.residual})
    add("coverage", lambda: ri.coverage_figure(d.uv, size), {"corner pixels": d.uv})
    add("projection uncertainty", lambda: ri.uncertainty_map_figure(d.sigma_u, d.sigma_v, d.sigma_px, size, d.valid_threshold_px, d.uv), {"uncertainty grid": d.sigma_px, "grid u": d.sigma_u, "grid v": d.sigma_v})
    add("distortion field", lambda: ri.distortion_figure(d.camera))
    add("cross-validation", lambda: ri.crossval_difference_figure(d.cv_u, d.cv_v, d.cv_diff_px, size, d.cv_sigma_px), {"cross-validation difference": d.cv_diff_px, "grid u": d.cv_u, "grid v": d.cv_v})
    return sec


def stereo_section(key: str, arrays: dict, meta: dict, skipped: list[str] | None = None) -> Section:
    """``stereo/<cam0>_<cam1>`` (``radarcal intrinsics --right``): per-pair RMS in both cameras and the residuals."""
    sec = Section(f"Stereo: {key.split('/', 1)[-1]}")
    add = _Adder(sec, skipped if skipped is not None else [])
    r0, r1, pair = arrays.get("residuals0"), arrays.get("residuals1"), arrays.get("pair_of_corner")
    inl = np.asarray(arrays["inliers"], bool).ravel() if "inliers" in arrays else None
    names = [" / ".join(Path(str(x)).name for x in np.atleast_1d(row)) for row in np.asarray(arrays.get("pair_names", np.zeros((0, 2), str)))]

    def per_pair() -> Any:
        p = np.asarray(pair, int).ravel()
        n = max(len(names), int(p.max()) + 1 if p.size else 0)
        m = np.ones(p.size, bool) if inl is None else inl
        r2 = np.sum(np.asarray(r0, float) ** 2, axis=1) + np.sum(np.asarray(r1, float) ** 2, axis=1)
        rms = np.sqrt(np.bincount(p[m], r2[m] / 2, n) / np.maximum(np.bincount(p[m], None, n), 1))
        labels = names if len(names) == n else [f"pair {i}" for i in range(n)]
        return ri.per_view_error_figure(labels, rms, None, title="Stereo: RMS per pair (both cameras)", ylabel="RMS residual (px)")

    add("per-pair error", per_pair, {"residuals0": r0, "residuals1": r1, "pair_of_corner": pair})
    add("stereo residual histogram", lambda: ri.residual_histogram_figure(np.r_[np.asarray(r0)[inl if inl is not None else slice(None)], np.asarray(r1)[inl if inl is not None else slice(None)]], title="Stereo residuals (both cameras, inliers)"), {"residuals0": r0, "residuals1": r1})
    return sec


@dataclass
class LidarCameraData:
    """A ``lidar_camera/<camera>_<lidar>`` session normalised for the figures."""

    points_lidar: np.ndarray | None = None
    T_init: np.ndarray | None = None
    T_final: np.ndarray | None = None
    edge_uv_lidar: np.ndarray | None = None
    edge_uv_image: np.ndarray | None = None
    edge_residual_px: np.ndarray | None = None
    residual_before_px: np.ndarray | None = None
    profile_offsets: np.ndarray | None = None  # (6, n) rx ry rz (rad) tx ty tz (m)
    profile_costs: np.ndarray | None = None  # (6, n)
    sigma6: np.ndarray | None = None  # rx ry rz (rad) tx ty tz (m)
    robust_scale_px: float | None = None
    image_files: list[str] = field(default_factory=list)
    cloud_files: list[str] = field(default_factory=list)
    pick_p_lidar: np.ndarray | None = None  # manual correspondences (PnP mode): LiDAR points
    pick_uv: np.ndarray | None = None  # and their clicked pixels
    pick_flagged: np.ndarray | None = None  # picks beyond 3σ
    converged: bool | None = None
    method: str = ""
    warnings: list[str] = field(default_factory=list)


def lidar_camera_data(arrays: dict, meta: dict, T_final: np.ndarray | None = None, transform_sigma: dict | None = None) -> LidarCameraData:
    """Normalise a LiDAR-camera session: the layout ``radarcal lidar-camera`` writes (``T_init``, ``T_final``,
    ``scene<k>_uv`` / ``scene<k>_line_point``, ``residuals_before/after``, ``profile_<p>_offset/_cost``, ``pnp_*``;
    meta ``pairs`` = [[image, cloud], …]) or the generic names of ``_ALIASES``. ``transform_sigma`` is the bundle
    entry's σ (block-bootstrap ``edge_bootstrap_rot_deg`` / ``_trans_m`` if stored, else the Jacobian ``edge_rot_deg``,
    ``edge_trans_m``) when the session holds none."""
    d = LidarCameraData()
    d.points_lidar = _get(arrays, meta, "points")
    T0, T1 = _get(arrays, meta, "T_init"), _get(arrays, meta, "T_final")
    d.T_init = None if T0 is None else np.asarray(T0, float)
    d.T_final = np.asarray(T1, float) if T1 is not None else T_final
    d.edge_uv_lidar, d.edge_uv_image = _get(arrays, meta, "edge_uv_lidar"), _get(arrays, meta, "edge_uv_image")
    if d.edge_uv_lidar is None and "scene0_uv" in arrays and "scene0_line_point" in arrays:
        d.edge_uv_lidar, d.edge_uv_image = arrays["scene0_uv"], arrays["scene0_line_point"]
    r = _get(arrays, meta, "edge_residual")
    if r is not None and d.edge_uv_lidar is not None:
        r = np.abs(np.asarray(r, float).ravel())[: len(d.edge_uv_lidar)]  # scene 0 comes first in a multi-scene solve
    if r is None and d.edge_uv_lidar is not None and d.edge_uv_image is not None:
        r = np.linalg.norm(np.asarray(d.edge_uv_image, float).reshape(-1, 2) - np.asarray(d.edge_uv_lidar, float).reshape(-1, 2), axis=1)
    d.edge_residual_px = r
    d.residual_before_px = _get(arrays, meta, "residual_before")
    d.profile_offsets, d.profile_costs = _get(arrays, meta, "profile_offsets"), _get(arrays, meta, "profile_costs")
    if d.profile_costs is None and all(f"profile_{n}_cost" in arrays for n in rl.PARAM_NAMES):
        d.profile_offsets = np.stack([np.asarray(arrays[f"profile_{n}_offset"], float) for n in rl.PARAM_NAMES])
        d.profile_costs = np.stack([np.asarray(arrays[f"profile_{n}_cost"], float) for n in rl.PARAM_NAMES])
    if d.profile_costs is None and all(f"profile_{n}" in arrays for n in rl.PARAM_NAMES):
        prof = [np.asarray(arrays[f"profile_{n}"], float) for n in rl.PARAM_NAMES]
        d.profile_offsets = np.stack([p[0] for p in prof])
        d.profile_costs = np.stack([p[1] for p in prof])
    s6 = _get(arrays, meta, "sigma6")
    d.sigma6 = None if s6 is None else np.asarray(s6, float).ravel()
    ts = transform_sigma or {}
    for rot_key, trans_key in (("edge_bootstrap_rot_deg", "edge_bootstrap_trans_m"), ("edge_rot_deg", "edge_trans_m")):  # the more honest one first
        if d.sigma6 is None and rot_key in ts and trans_key in ts:
            d.sigma6 = np.r_[np.radians(np.asarray(ts[rot_key], float).ravel()), np.asarray(ts[trans_key], float).ravel()]
    if "pnp_p_lidar" in arrays and "pnp_uv" in arrays:
        d.pick_p_lidar, d.pick_uv = np.asarray(arrays["pnp_p_lidar"], float), np.asarray(arrays["pnp_uv"], float)
        d.pick_flagged = np.asarray(arrays["pnp_flagged"], bool) if "pnp_flagged" in arrays else None
    d.converged = meta.get("converged")
    d.method = str(meta.get("method", ""))
    pairs = meta.get("pairs")
    if isinstance(pairs, list) and pairs and all(isinstance(p, (list, tuple)) and len(p) == 2 for p in pairs):
        d.image_files = [str(p[0]) for p in pairs]
        d.cloud_files = [str(p[1]) for p in pairs]
    rs = meta.get("robust_scale_px", meta.get("loss_scale_px"))
    d.robust_scale_px = float(rs) if isinstance(rs, (int, float)) else None
    if not d.image_files:
        imgs = meta.get("images", meta.get("image"))
        d.image_files = [str(x) for x in (imgs if isinstance(imgs, list) else [imgs] if imgs else [])]
    if not d.cloud_files:
        cl = meta.get("clouds", meta.get("cloud"))
        d.cloud_files = [str(x) for x in (cl if isinstance(cl, list) else [cl] if cl else [])]
    d.warnings = [str(w) for w in meta.get("warnings") or []]
    return d


def lidar_camera_section(key: str, camera: Camera, arrays: dict, meta: dict, T_final_bundle: np.ndarray | None = None, image: np.ndarray | None = None, skipped: list[str] | None = None, transform_sigma: dict | None = None) -> Section:
    sec = Section(f"LiDAR-camera: {key.split('/', 1)[-1]}")
    add = _Adder(sec, skipped if skipped is not None else [])
    d = lidar_camera_data(arrays, meta, T_final_bundle, transform_sigma)
    if d.method or d.converged is not None:
        sec.add(f"method: {d.method or '?'}; " + ("converged" if d.converged else "did NOT converge (stored with --force)" if d.converged is False else ""))
    for w in d.warnings:
        sec.add(f"warning: {w}")
    if d.pick_p_lidar is not None and d.T_final is not None:
        def picks():
            uv_proj, _, _ = camera.project_from(d.T_final, d.pick_p_lidar)
            names = [f"#{i}" for i in range(len(d.pick_uv))]
            return rf.picks_residual_figure(camera.image_size, names, d.pick_uv, uv_proj, image, outlier=d.pick_flagged, title="Manual correspondences: clicks and reprojected LiDAR points")

        add("manual correspondences", picks)
    transforms = {k: v for k, v in (("before", d.T_init), ("after", d.T_final)) if v is not None}
    add("cloud over image", lambda: rl.cloud_overlay_figure(image, camera, d.points_lidar, transforms), {"cloud points": d.points_lidar, "a transform": transforms or None})
    add("edge matches", lambda: rl.edge_matches_figure(image, camera.image_size, d.edge_uv_lidar, d.edge_uv_image, d.edge_residual_px), {"projected edge points": d.edge_uv_lidar, "matched image points": d.edge_uv_image})
    add("edge residual histogram", lambda: rl.edge_residual_histogram_figure(d.edge_residual_px, d.robust_scale_px, before_px=d.residual_before_px), {"edge residuals": d.edge_residual_px})
    deg = math.degrees(1.0)
    add("cost profiles", lambda: rl.cost_profile_figure(d.profile_offsets, d.profile_costs, display_scale=[deg] * 3 + [1.0] * 3, sigma=d.sigma6), {"cost profiles": d.profile_costs, "profile offsets": d.profile_offsets})
    if d.sigma6 is not None:
        rows = [[n, f"{v * (deg if i < 3 else 1):.4g}", "deg" if i < 3 else "m"] for i, (n, v) in enumerate(zip(rl.PARAM_NAMES, d.sigma6))]
        sec.add(Table(["parameter", "σ", "unit"], rows, caption="σ of the result (from the Jacobian)"))
    return sec


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
    """A ``field_pnp/<camera>`` session normalised for the figures."""

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
    warnings: list[str] = field(default_factory=list)


def field_data(arrays: dict, meta: dict, T_cam_field: np.ndarray | None = None) -> FieldData:
    """Normalise a field-pnp session (the layout ``radarcal field-pnp`` writes, or the generic names)."""
    d = FieldData()
    d.names = _str_list(_get(arrays, meta, "pick_names"))
    d.uv_picked = arrays.get("uv") if "residuals_px" in arrays and "uv" in arrays else _get(arrays, meta, "uv_picked")
    d.uv_reprojected = _get(arrays, meta, "uv_reproj")
    if d.uv_reprojected is None and d.uv_picked is not None and "residuals_px" in arrays:
        d.uv_reprojected = np.asarray(d.uv_picked, float) - np.asarray(arrays["residuals_px"], float)  # residual = picked − projected
    if "inliers" in arrays:
        d.pick_outlier = ~np.asarray(arrays["inliers"], bool)
    else:
        d.pick_outlier = _get(arrays, meta, "pick_outlier")
    T = _get(arrays, meta, "T_cam_field")
    d.T_cam_field = np.asarray(T, float) if T is not None else T_cam_field
    d.grid_x, d.grid_y = _get(arrays, meta, "err_x"), _get(arrays, meta, "err_y")
    if "sigma_lidar" in arrays:
        d.error_maps["depth from the LiDAR"] = arrays["sigma_lidar"]
    if "sigma_ground" in arrays:
        d.error_maps["ground-plane fallback (no depth)"] = arrays["sigma_ground"]
    if not d.error_maps and _get(arrays, meta, "err_sigma") is not None:
        d.error_maps["expected"] = _get(arrays, meta, "err_sigma")
    d.rms_px = meta.get("rms_px")
    d.depth_source = meta.get("depth_source")
    d.warnings = [str(w) for w in meta.get("warnings") or []]
    return d


def field_section(camera_name: str, camera: Camera | None, arrays: dict, meta: dict, field_model: Any, T_cam_field: np.ndarray | None, image: np.ndarray | None = None, skipped: list[str] | None = None) -> Section:
    sec = Section(f"Field pose: {camera_name}")
    add = _Adder(sec, skipped if skipped is not None else [])
    fa = field_drawing_args(field_model if field_model is not None else meta.get("field") if isinstance(meta.get("field"), dict) else None)
    d = field_data(arrays, meta, T_cam_field)
    for w in d.warnings:
        sec.add(f"warning: {w}")
    add("field and landmarks", lambda: rf.field_landmarks_figure(fa["size"], fa["landmarks"], d.T_cam_field, d.names, fa["outline"]), {"field model": fa or None})
    size = camera.image_size if camera is not None else tuple(meta.get("image_size", (1280, 1024)))
    add("picks and residuals", lambda: rf.picks_residual_figure(size, d.names, d.uv_picked, d.uv_reprojected, image, outlier=d.pick_outlier), {"picked pixels": d.uv_picked, "reprojected landmarks": d.uv_reprojected})
    if not d.error_maps:
        add("localisation error map", lambda: None, {"error map": None})
    for label, s in d.error_maps.items():
        title = f"Expected 1σ localisation error, {label}" + (" (used)" if d.depth_source and d.depth_source in label.lower() else "")
        add(f"error map ({label})", lambda s=s, title=title: rf.localisation_error_figure(d.grid_x, d.grid_y, s, fa.get("size", (28.0, 15.0)), d.T_cam_field, fa.get("landmarks"), fa.get("outline"), title=title), {"grid x": d.grid_x, "grid y": d.grid_y})
    return sec


# --- run tracks ---------------------------------------------------------------------------------------------------------
def read_tracks(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """A ``radarcal run`` track file (JSON lines, one per frame: ``{"t": s, "robots": [{"label", "x", "y", …}]}``;
    ``xyz``/``p_field``/``field`` lists are accepted too) → (times per label, field xyz (N, 3) per label)."""
    path = Path(path)
    t_by: dict[str, list[float]] = {}
    p_by: dict[str, list[list[float]]] = {}
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise InputError(path, f"cannot read track file ({e.__class__.__name__})") from None
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            t = float(rec.get("t", rec.get("time", i)))
            robots = rec.get("robots", rec.get("tracks", rec.get("targets", [])))
            for r in robots:
                label = str(r.get("label", r.get("id", r.get("name", "?"))))
                p = _robot_xyz(r)
                if p is None:
                    continue
                t_by.setdefault(label, []).append(t)
                p_by.setdefault(label, []).append(p)
        except (ValueError, TypeError, AttributeError) as e:
            raise InputError(path, f"line {i}: not a track record ({e.__class__.__name__})") from None
    return ({k: np.asarray(v) for k, v in t_by.items()}, {k: np.asarray(v, float).reshape(-1, 3) for k, v in p_by.items()})


def _robot_xyz(r: dict) -> list[float] | None:
    for k in ("xyz", "p_field", "field", "position", "pos"):
        v = r.get(k)
        if isinstance(v, (list, tuple)) and len(v) >= 2:
            return [float(v[0]), float(v[1]), float(v[2]) if len(v) > 2 and v[2] is not None else 0.0]
        if isinstance(v, dict) and "x" in v:
            return [float(v["x"]), float(v["y"]), float(v.get("z", 0.0))]
    if "x" in r and "y" in r:
        return [float(r["x"]), float(r["y"]), float(r.get("z", 0.0) or 0.0)]
    return None


def run_section(tracks_t: dict, tracks_p: dict, field_model: Any = None, truth_t: dict | None = None, truth_p: dict | None = None, skipped: list[str] | None = None) -> Section:
    """Minimap with tracks; with truth (same labels), error over time (truth interpolated at the track times)."""
    sec = Section("Run: tracks")
    add = _Adder(sec, skipped if skipped is not None else [])
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


# --- the whole report --------------------------------------------------------------------------------------------------
def build_report(bundle: Bundle, session_dir: str | os.PathLike | None = None, tracks: str | os.PathLike | None = None, truth_tracks: str | os.PathLike | None = None) -> ReportContent:
    """All sections the bundle's sessions (and an optional run track file) allow."""
    content = ReportContent()
    sessions = discover_sessions(bundle, session_dir)
    base = bundle.path.parent if bundle.path else None
    field_model = bundle.field_model
    order = {"intrinsics": 0, "stereo": 1, "lidar_camera": 2, "field_pnp": 3}
    with_intrinsics = {k.partition("/")[2] for k in sessions if k.startswith("intrinsics/")}
    content.sections.append(_overview(bundle, skip_cameras=with_intrinsics))
    for key, (arrays, meta) in sorted(sessions.items(), key=lambda kv: (order.get(kv[0].partition("/")[0], 9), kv[0])):
        kind, _, rest = key.partition("/")
        if kind == "intrinsics":
            cam_name = rest
            if cam_name in bundle.cameras:
                cam, entry = bundle.cameras[cam_name].camera, bundle.cameras[cam_name]
            elif "camera" in meta:
                cam, entry = Camera.from_dict(meta["camera"]), None
            else:
                content.skipped.append(f"{key}: camera {cam_name!r} not in the bundle")
                continue
            img = _read_image_from_meta(meta, base, "image", "images", "image_files", "view_files")
            content.sections.append(intrinsics_section(cam_name, cam, arrays, meta, entry, img, content.skipped, base))
        elif kind == "stereo":
            content.sections.append(stereo_section(key, arrays, meta, content.skipped))
        elif kind == "lidar_camera":
            known = sorted((c for c in bundle.cameras if rest.startswith(c + "_")), key=len, reverse=True)
            cam_name = meta.get("camera") or (known[0] if known else rest.split("_")[0])
            lidar_name = meta.get("lidar") or rest[len(cam_name) + 1 :]
            if cam_name not in bundle.cameras:
                content.skipped.append(f"{key}: camera {cam_name!r} not in the bundle")
                continue
            T_b = bundle.T(cam_name, lidar_name) if bundle.has_T(cam_name, lidar_name) else None
            entry = bundle.transforms.get(f"T_{cam_name}_{lidar_name}")
            d0 = lidar_camera_data(arrays, meta)
            img = next((im for im in (_read_image_file(f, base) for f in d0.image_files[:1]) if im is not None), None)
            if _get(arrays, meta, "points") is None:  # no subsample in the session: the cloud file it names
                pts = next((c for c in (_read_cloud_file(f, base) for f in d0.cloud_files[:1]) if c is not None), None)
                if pts is not None:
                    arrays = {**arrays, "points_lidar": pts}
            content.sections.append(lidar_camera_section(key, bundle.cameras[cam_name].camera, arrays, meta, T_b, img, content.skipped, entry.sigma if entry else None))
        elif kind == "field_pnp":
            cam_name = rest
            cam = bundle.cameras[cam_name].camera if cam_name in bundle.cameras else None
            T = bundle.T(cam_name, "field") if bundle.has_T(cam_name, "field") else None
            img = _read_image_from_meta(meta, base, "image")
            content.sections.append(field_section(cam_name, cam, arrays, meta, field_model, T, img, content.skipped))
        else:
            sec = Section(f"Session {key}")
            sec.add(f"No report section for this kind of session; arrays: {', '.join(sorted(arrays)) or 'none'}.")
            content.sections.append(sec)
    if tracks is not None:
        tt, tp = read_tracks(tracks)
        gt, gp = read_tracks(truth_tracks) if truth_tracks is not None else (None, None)
        content.sections.append(run_section(tt, tp, field_model, gt, gp, content.skipped))
    return content
