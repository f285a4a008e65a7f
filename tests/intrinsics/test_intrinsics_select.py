"""ROS-style view descriptors, novelty gate and coverage."""

from __future__ import annotations

import numpy as np

from radarcal.camera import Camera
from radarcal.intrinsics.detect import BoardSpec, object_points
from radarcal.intrinsics.select import coverage, novel_mask, view_descriptor
from radarcal.synth.intrinsics_views import radar_station_camera, simulate_views

BOARD = BoardSpec("chessboard", 9, 6, 0.05)
CAM = Camera((1280, 1024), np.array([[1000.0, 0, 639.5], [0, 1000.0, 511.5], [0, 0, 1]]), np.zeros(5))


def _view(x, y, z, tilt_deg=0.0):
    from scipy.spatial.transform import Rotation

    obj = object_points(BOARD)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.deg2rad(tilt_deg) * np.array([1.0, 1.0, 0.0]) / np.sqrt(2)).as_matrix()
    T[:3, 3] = np.array([x, y, z]) - T[:3, :3] @ obj.mean(axis=0)
    uv, _v, _z = CAM.project_from(T, obj)
    return uv


def test_descriptor_of_a_centred_frontal_board():
    uv = _view(0, 0, 2.0)
    X, Y, size, skew = view_descriptor(uv, np.arange(54), BOARD.grid_shape, CAM.image_size)
    assert abs(X - 0.5) < 0.01 and abs(Y - 0.5) < 0.01
    # board 0.4 x 0.25 m at 2 m = 200 x 125 px
    assert abs(size - np.sqrt(200 * 125 / (1280 * 1024))) < 0.005
    assert skew < 0.01


def test_descriptor_position_and_skew_respond():
    left = view_descriptor(_view(-0.8, 0, 2.0), np.arange(54), BOARD.grid_shape, CAM.image_size)
    low = view_descriptor(_view(0, 0.6, 2.0), np.arange(54), BOARD.grid_shape, CAM.image_size)
    tilted = view_descriptor(_view(0.3, 0.2, 1.5, tilt_deg=50), np.arange(54), BOARD.grid_shape, CAM.image_size)
    assert left[0] < 0.15 and low[1] > 0.8
    assert tilted[3] > 0.1


def test_novelty_gate_drops_near_duplicates():
    d = np.array([[0.5, 0.5, 0.3, 0.0], [0.52, 0.5, 0.31, 0.0], [0.1, 0.5, 0.3, 0.0], [0.11, 0.52, 0.3, 0.02], [0.9, 0.9, 0.5, 0.4]])
    assert novel_mask(d, 0.2).tolist() == [True, False, True, False, True]
    assert novel_mask(d, 0.0).all()
    assert novel_mask(d[:1], 0.2, kept=d[:1]).tolist() == [False]


def test_coverage_warns_about_missing_y():
    uvs = [_view(x, 0.0, 2.0) for x in (-0.8, -0.4, 0.0, 0.4, 0.8)]
    descs = np.array([view_descriptor(u, np.arange(54), BOARD.grid_shape, CAM.image_size) for u in uvs])
    cov = coverage(descs, np.concatenate(uvs), CAM.image_size)
    assert cov.progress["X"] > 0.9 and cov.progress["Y"] < 0.05
    assert any(w.startswith("coverage Y") for w in cov.warnings)
    assert cov.grid_fraction < 0.6 and any("image" in w for w in cov.warnings)
    # a well spread simulated session has no warnings on X/Y
    sim = simulate_views(radar_station_camera(), BoardSpec("chessboard", 14, 10, 0.03), 30, 0.1, np.random.default_rng(0), max_tilt_deg=50, fill=(0.4, 0.9), margin_px=3)
    d2 = np.array([view_descriptor(u, np.arange(140), (10, 14), (1280, 1024)) for u in sim.image_points])
    c2 = coverage(d2, np.concatenate(sim.image_points), (1280, 1024))
    assert c2.progress["X"] == 1.0 and c2.progress["Y"] == 1.0 and c2.grid_fraction > 0.9
