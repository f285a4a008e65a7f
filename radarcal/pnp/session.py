"""Session file of ``radarcal field-pnp``: :class:`FieldPnPSession`.

``T_cam_field`` maps field points (origin at a corner, x along 28 m, z up; m) into the camera; pixels px;
``residuals_px`` = picked - reprojected. The error maps are the expected 1σ localisation error (m) on the
``grid_x`` x ``grid_y`` field grid, with LiDAR depth and with the ground-plane fallback.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from radarcal.sessions import SessionRecord

__all__ = ["FieldPnPSession"]


@dataclass
class FieldPnPSession(SessionRecord):
    KIND = "field_pnp"
    PATH_FIELDS = ("image",)  # the image drawn under the picks

    names: np.ndarray | None = None  # (N,) landmark names
    uv: np.ndarray | None = None  # (N,2) picked pixels
    p_field: np.ndarray | None = None  # (N,3) landmark positions
    residuals_px: np.ndarray | None = None  # (N,2)
    inliers: np.ndarray | None = None  # (N,) bool
    T_cam_field: np.ndarray | None = None
    cov_pose: np.ndarray | None = None  # (6,6)
    camera_position: np.ndarray | None = None  # (3,) field frame
    grid_x: np.ndarray | None = None
    grid_y: np.ndarray | None = None
    sigma_lidar: np.ndarray | None = None  # (ny, nx) m
    sigma_ground: np.ndarray | None = None  # (ny, nx) m
    field: str = ""  # field model name
    camera: str = ""
    click_sigma_px: float | None = None
    pixel_sigma_px: float | None = None
    range_sigma_m: float | None = None
    rms_px: float | None = None
    depth_source: str = ""  # lidar | ground: the one the runtime will use
    lidar: str | None = None
    image: str = ""  # the image the picks were made on, when given
    picks_file: str = ""
    warnings: list = dataclasses.field(default_factory=list)
