"""Shared synthetic scene for the runtime tests: a radar-station camera over a flat field."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal.camera import Camera
from radarcal.geometry import invert_T, make_T


def station_T_field_cam(pitch_deg: float = 12.0, pos=(-1.0, 7.5, 2.5)) -> np.ndarray:
    a = np.radians(pitch_deg)
    x = np.array([0.0, -1.0, 0.0])
    z = np.array([np.cos(a), 0.0, -np.sin(a)])
    y = np.cross(z, x)
    return make_T(np.column_stack([x, y, z]), np.asarray(pos, float))


@pytest.fixture
def station():
    cam = Camera((1280, 1024), np.array([[1400.0, 0, 639.5], [0, 1400.0, 511.5], [0, 0, 1]]), np.array([-0.05, 0.02, 0.0, 0.0, 0.0]))
    T_field_cam = station_T_field_cam()
    # LiDAR 10 cm beside the camera, axes x forward / y left / z up
    R_cam_lidar = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])
    T_cam_lidar = make_T(R_cam_lidar, np.array([0.1, 0.05, 0.0]))
    return {"camera": cam, "T_field_cam": T_field_cam, "T_cam_lidar": T_cam_lidar, "T_lidar_field": invert_T(T_field_cam @ T_cam_lidar)}


def robot_cloud(center_xy, radius=0.25, height=0.45, n=400, rng=None, viewer_xy=(-1.0, 7.5)):
    """Points a LiDAR at ``viewer_xy`` sees on a vertical cylinder standing on z = 0 (a robot): only the visible
    half, sampled uniformly across its apparent width (as a scanner does)."""
    rng = rng or np.random.default_rng(0)
    c = np.asarray(center_xy, float)
    to_viewer = np.asarray(viewer_xy, float) - c
    base = np.arctan2(to_viewer[1], to_viewer[0])
    ang = base + np.arcsin(rng.uniform(-1, 1, n))
    z = rng.uniform(0.05, height, n)
    return np.column_stack([c[0] + radius * np.cos(ang), c[1] + radius * np.sin(ang), z])
