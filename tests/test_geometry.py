"""SE(3) helpers: identities checked against hand-built matrices."""

from __future__ import annotations

import numpy as np
import pytest

from radarcal import geometry as g


def _Rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _Ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _random_T(rng):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return g.make_T(g.rotvec_to_R(axis * rng.uniform(0, np.pi)), rng.uniform(-20, 20, 3))


def test_make_T_and_transform_points():
    R = _Rz(0.3) @ _Rx(-1.1)
    t = np.array([1.0, -2.0, 0.5])
    T = g.make_T(R, t)
    assert T.shape == (4, 4) and np.array_equal(T[3], [0, 0, 0, 1])
    p = np.array([[1.0, 2.0, 3.0], [-4.0, 0.0, 0.25]])
    expect = (R @ p.T).T + t
    np.testing.assert_allclose(g.transform_points(T, p), expect, atol=1e-14)
    # float32 clouds stay float32
    assert g.transform_points(T, p.astype(np.float32)).dtype == np.float32


def test_compose_and_invert_identities():
    rng = np.random.default_rng(0)
    for _ in range(50):
        A, B, C = _random_T(rng), _random_T(rng), _random_T(rng)
        np.testing.assert_allclose(g.compose(A, g.invert_T(A)), np.eye(4), atol=1e-12)
        np.testing.assert_allclose(g.compose(g.invert_T(A), A), np.eye(4), atol=1e-12)
        np.testing.assert_allclose(g.invert_T(A), np.linalg.inv(A), atol=1e-12)
        np.testing.assert_allclose(g.compose(A, B, C), A @ B @ C, atol=1e-12)
        np.testing.assert_allclose(g.invert_T(g.compose(A, B)), g.compose(g.invert_T(B), g.invert_T(A)), atol=1e-12)
        np.testing.assert_allclose(g.invert_T(g.invert_T(A)), A, atol=1e-12)
    np.testing.assert_array_equal(g.compose(), np.eye(4))


def test_T_a_b_convention():
    """T_cam_lidar maps a LiDAR point (x forward) into the camera frame (z forward)."""
    R_cam_lidar = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], float)
    T_cam_lidar = g.make_T(R_cam_lidar, [0.0, -0.1, 0.05])
    p_lidar = np.array([[10.0, 0.0, 0.0]])  # 10 m ahead of the LiDAR
    p_cam = g.transform_points(T_cam_lidar, p_lidar)
    np.testing.assert_allclose(p_cam, [[0.0, -0.1, 10.05]])
    np.testing.assert_allclose(g.transform_points(g.invert_T(T_cam_lidar), p_cam), p_lidar, atol=1e-14)


def test_rotvec_round_trip_and_T_to_rotvec():
    rng = np.random.default_rng(1)
    for _ in range(50):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(0, np.pi - 1e-3)
        rv = axis * angle
        R = g.rotvec_to_R(rv)
        # Rodrigues by hand
        Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        np.testing.assert_allclose(R, np.eye(3) + np.sin(angle) * Kx + (1 - np.cos(angle)) * Kx @ Kx, atol=1e-12)
        np.testing.assert_allclose(g.R_to_rotvec(R), rv, atol=1e-10)
        t = rng.normal(size=3)
        six = g.T_to_rotvec(g.T_from_rotvec(rv, t))
        np.testing.assert_allclose(six, np.r_[rv, t], atol=1e-10)
        assert abs(g.rotation_angle(R) - angle) < 1e-10


def test_T_from_xyz_rpy_deg_matches_Rz_Ry_Rx():
    x, y, z, roll, pitch, yaw = 1.5, -0.25, 3.0, 10.0, -35.0, 120.0
    T = g.T_from_xyz_rpy_deg(x, y, z, roll, pitch, yaw)
    R = _Rz(np.radians(yaw)) @ _Ry(np.radians(pitch)) @ _Rx(np.radians(roll))
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-14)
    np.testing.assert_allclose(T[:3, 3], [x, y, z])
    np.testing.assert_allclose(g.T_to_xyz_rpy_deg(T), [x, y, z, roll, pitch, yaw], atol=1e-10)
    # single-axis sanity: yaw 90 deg turns x into y
    np.testing.assert_allclose(g.rpy_deg_to_R(0, 0, 90) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(g.rpy_deg_to_R(90, 0, 0) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(g.rpy_deg_to_R(0, 90, 0) @ [0, 0, 1], [1, 0, 0], atol=1e-15)


def test_rpy_round_trip():
    rng = np.random.default_rng(2)
    rpy = np.c_[rng.uniform(-180, 180, 200), rng.uniform(-89, 89, 200), rng.uniform(-180, 180, 200)]
    for r, p, y in rpy:
        back = g.R_to_rpy_deg(g.rpy_deg_to_R(r, p, y))
        np.testing.assert_allclose(back, [r, p, y], atol=1e-8)


def test_is_rotation():
    assert g.is_rotation(_Rz(0.4) @ _Rx(2.0))
    assert not g.is_rotation(np.diag([1.0, 1.0, -1.0]))  # reflection
    assert not g.is_rotation(np.eye(3) * 1.01)
    assert not g.is_rotation(np.eye(2))
    assert not g.is_rotation(np.full((3, 3), np.nan))


def test_pose_error():
    T_true = g.T_from_xyz_rpy_deg(1, 2, 3, 5, 10, 15)
    assert g.pose_error(T_true, T_true) == pytest.approx((0.0, 0.0), abs=1e-6)
    dR = g.rotvec_to_R(np.radians(2.5) * np.array([0.0, 0.6, 0.8]))
    T_est = T_true.copy()
    T_est[:3, :3] = dR @ T_true[:3, :3]
    T_est[:3, 3] += [0.03, 0.0, -0.04]
    deg, m = g.pose_error(T_est, T_true)
    assert deg == pytest.approx(2.5, abs=1e-9)
    assert m == pytest.approx(0.05, abs=1e-12)


@pytest.mark.parametrize("deg, m", [(0.5, 0.02), (5.0, 0.3), (30.0, 2.0), (0.0, 0.1)])
def test_perturb_T_is_exact(deg, m):
    rng = np.random.default_rng(7)
    T = _random_T(rng)
    for _ in range(20):
        Tp = g.perturb_T(T, deg, m, rng)
        assert g.is_rotation(Tp[:3, :3])
        d_deg, d_m = g.pose_error(Tp, T)
        assert d_deg == pytest.approx(deg, abs=1e-9)
        assert d_m == pytest.approx(m, abs=1e-12)
