"""The LiDAR-camera section of the report, from :class:`radarcal.extrinsics.lidar_camera_session.LidarCameraSession`
files (exactly the names ``radarcal lidar-camera`` writes)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from radarcal.camera import Camera
from radarcal.extrinsics.lidar_camera_session import LidarCameraSession
from radarcal.report import field as rf
from radarcal.report import lidar_camera as rl
from radarcal.report.html import Section, Table
from radarcal.report.sections_common import FigureAdder, note_missing_image

__all__ = ["LidarCameraData", "lidar_camera_data", "lidar_camera_section"]


@dataclass
class LidarCameraData:
    """A ``lidar_camera/<camera>_<lidar>`` session arranged for the figures."""

    points_lidar: np.ndarray | None = None  # the scene cloud (read from the file the session names)
    T_init: np.ndarray | None = None
    T_final: np.ndarray | None = None
    edge_uv_lidar: np.ndarray | None = None
    edge_uv_image: np.ndarray | None = None
    edge_residual_px: np.ndarray | None = None
    residual_before_px: np.ndarray | None = None
    profile_offsets: np.ndarray | None = None  # (6, n) rx ry rz (rad) tx ty tz (m)
    profile_costs: np.ndarray | None = None  # (6, n)
    sigma6: np.ndarray | None = None  # rx ry rz (rad) tx ty tz (m): the one shaded on the profiles (first of sigmas)
    sigmas: dict[str, np.ndarray] = field(default_factory=dict)  # what the σ was computed by -> sigma6, bootstrap first
    robust_scale_px: float | None = None
    image_files: list[str] = field(default_factory=list)
    cloud_files: list[str] = field(default_factory=list)
    pick_p_lidar: np.ndarray | None = None  # manual correspondences (PnP mode): LiDAR points
    pick_uv: np.ndarray | None = None  # and their clicked pixels
    pick_flagged: np.ndarray | None = None  # picks beyond 3σ
    converged: bool | None = None
    method: str = ""
    warnings: list[str] = field(default_factory=list)


# bundle σ keys of a LiDAR-camera transform, by what computed them (the more honest one first)
SIGMA_SOURCES = {"block bootstrap": ("edge_bootstrap_rot_deg", "edge_bootstrap_trans_m"), "Jacobian": ("edge_rot_deg", "edge_trans_m")}


def sigma_sources(transform_sigma: dict | None) -> dict[str, np.ndarray]:
    """The σ of a LiDAR-camera transform entry by what computed it: ``{"block bootstrap": sigma6, "Jacobian": sigma6}``
    (those stored; sigma6 = rx ry rz (rad) tx ty tz (m))."""
    ts = transform_sigma or {}
    out = {}
    for name, (rot_key, trans_key) in SIGMA_SOURCES.items():
        if rot_key in ts and trans_key in ts:
            out[name] = np.r_[np.radians(np.asarray(ts[rot_key], float).ravel()), np.asarray(ts[trans_key], float).ravel()]
    return out


def lidar_camera_data(arrays: dict, meta: dict, T_final: np.ndarray | None = None, transform_sigma: dict | None = None) -> LidarCameraData:
    """A LiDAR-camera session (:class:`LidarCameraSession`) arranged for the figures. ``T_final``: the bundle's
    transform when the session holds none; ``transform_sigma``: the bundle entry's σ (block-bootstrap
    ``edge_bootstrap_rot_deg`` / ``_trans_m`` when stored, else the Jacobian ``edge_rot_deg`` / ``edge_trans_m``)."""
    s = LidarCameraSession.from_parts(arrays, meta)
    d = LidarCameraData()
    d.T_init = None if s.T_init is None else np.asarray(s.T_init, float)
    d.T_final = np.asarray(s.T_final, float) if s.T_final is not None else T_final
    m = s.scene_matches
    if "scene0_uv" in m and "scene0_line_point" in m:  # the figures show scene 0
        d.edge_uv_lidar, d.edge_uv_image = m["scene0_uv"], m["scene0_line_point"]
    if s.residuals_after is not None and d.edge_uv_lidar is not None:
        d.edge_residual_px = np.abs(np.asarray(s.residuals_after, float).ravel())[: len(d.edge_uv_lidar)]  # scene 0 comes first
    d.residual_before_px = s.residuals_before
    d.profile_offsets, d.profile_costs = s.profile_offsets, s.profile_costs
    d.sigmas = sigma_sources(transform_sigma)
    d.sigma6 = next(iter(d.sigmas.values()), None)  # the more honest one (block bootstrap) first
    if s.pnp_p_lidar is not None and s.pnp_uv is not None:
        d.pick_p_lidar, d.pick_uv = np.asarray(s.pnp_p_lidar, float), np.asarray(s.pnp_uv, float)
        d.pick_flagged = None if s.pnp_flagged is None else np.asarray(s.pnp_flagged, bool)
    d.converged = s.converged
    d.method = s.method
    pairs = [p for p in s.pairs or [] if isinstance(p, (list, tuple)) and len(p) == 2]
    d.image_files = [str(p[0]) for p in pairs]
    d.cloud_files = [str(p[1]) for p in pairs]
    d.robust_scale_px = s.robust_scale_px
    d.warnings = [str(w) for w in s.warnings or []]
    return d


def lidar_camera_section(key: str, camera: Camera, arrays: dict, meta: dict, T_final_bundle: np.ndarray | None = None, image: np.ndarray | None = None, skipped: list[str] | None = None,
                         transform_sigma: dict | None = None, points_lidar: np.ndarray | None = None) -> Section:  # fmt: skip
    """Every LiDAR-camera figure the session allows; ``points_lidar``: the scene cloud (the session names its file)."""
    sec = Section(f"LiDAR-camera: {key.split('/', 1)[-1]}")
    add = FigureAdder(sec, skipped if skipped is not None else [])
    d = lidar_camera_data(arrays, meta, T_final_bundle, transform_sigma)
    d.points_lidar = points_lidar
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
    if image is None and (d.points_lidar is not None or d.edge_uv_lidar is not None or d.pick_uv is not None):
        note_missing_image(sec, add.skipped, "LiDAR-camera figures", d.image_files[0] if d.image_files else None)
    add("cloud over image", lambda: rl.cloud_overlay_figure(image, camera, d.points_lidar, transforms), {"cloud points": d.points_lidar, "a transform": transforms or None})
    add("edge matches", lambda: rl.edge_matches_figure(image, camera.image_size, d.edge_uv_lidar, d.edge_uv_image, d.edge_residual_px), {"projected edge points": d.edge_uv_lidar, "matched image points": d.edge_uv_image})
    add("edge residual histogram", lambda: rl.edge_residual_histogram_figure(d.edge_residual_px, d.robust_scale_px, before_px=d.residual_before_px), {"edge residuals": d.edge_residual_px})
    deg = math.degrees(1.0)
    add("cost profiles", lambda: rl.cost_profile_figure(d.profile_offsets, d.profile_costs, display_scale=[deg] * 3 + [1.0] * 3, sigma=d.sigma6), {"cost profiles": d.profile_costs, "profile offsets": d.profile_offsets})
    if d.sigmas:
        kinds = list(d.sigmas)
        rows = [[n, *(f"{d.sigmas[k][i] * (deg if i < 3 else 1):.4g}" for k in kinds), "deg" if i < 3 else "m"] for i, n in enumerate(rl.PARAM_NAMES)]
        cols = ["parameter", *(f"σ ({k})" for k in kinds), "unit"]
        shaded = f"; the profiles shade the {kinds[0]} σ" if d.profile_costs is not None else ""
        sec.add(Table(cols, rows, caption=f"σ of the result (from the {' and the '.join(kinds)}{shaded})"))
    return sec
