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
