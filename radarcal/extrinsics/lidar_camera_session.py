"""Session file of ``radarcal lidar-camera``: :class:`LidarCameraSession`.

Transforms are ``T_cam_lidar`` (4x4, LiDAR frame -> camera frame); pixels px. The result (T, σ, residual summary) lives
in the bundle's transform entry; the session keeps what the report draws.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radarcal.sessions import SessionRecord

__all__ = ["LidarCameraSession"]


@dataclass
class LidarCameraSession(SessionRecord):
    KIND = "lidar_camera"
    PATH_FIELDS = ("pairs",)  # [[image, cloud], ...]
    ARRAY_DICT_KEYS = r"scene\d+_"  # scene<k>_lidar_xyz / _uv / _line_point / _line_normal of the final matching

    T_init: np.ndarray | None = None
    T_final: np.ndarray | None = None
    T_pnp: np.ndarray | None = None  # manual / board PnP, before any refinement
    T_dense: np.ndarray | None = None  # --refine-method dense
    pnp_p_lidar: np.ndarray | None = None  # (M,3) LiDAR points of the correspondences
    pnp_uv: np.ndarray | None = None  # (M,2) their pixels
    pnp_residuals_uv: np.ndarray | None = None  # (M,2) px
    pnp_flagged: np.ndarray | None = None  # (M,) bool: beyond 3σ
    residuals_before: np.ndarray | None = None  # edge residuals (px) at T_init (all scenes, scene 0 first)
    residuals_after: np.ndarray | None = None  # and at T_final
    profile_offsets: np.ndarray | None = None  # (6, n) rx ry rz (rad) tx ty tz (m) around T_final
    profile_costs: np.ndarray | None = None  # (6, n)
    scene_matches: dict[str, np.ndarray] = field(default_factory=dict)
    camera: str = ""
    lidar: str = ""
    init: str = ""  # where T_init came from
    method: str = ""
    converged: bool | None = None
    pairs: list = field(default_factory=list)  # [[image file, cloud file], ...]
    robust_scale_px: float | None = None  # Cauchy loss scale of the edge refinement
    warnings: list = field(default_factory=list)
