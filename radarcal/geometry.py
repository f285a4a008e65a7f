"""SE(3) helpers. Pure numpy (+ scipy's Rotation).

``T_a_b`` (4x4) maps points in frame b into frame a: ``p_a = T_a_b @ p_b``; compose as ``T_a_c = T_a_b @ T_b_c``.
Angles are radians except in the ``*_deg`` helpers, which exist for the user interface.
Roll-pitch-yaw means intrinsic z-y'-x'' (yaw about z, then pitch about y, then roll about x): ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

import numpy as np


def _Rotation():
    """scipy's Rotation, imported on first use (scipy.spatial costs ~0.3 s at CLI start-up)."""
    from scipy.spatial.transform import Rotation

    return Rotation

__all__ = [
    "make_T",
    "invert_T",
    "compose",
    "transform_points",
    "rotvec_to_R",
    "R_to_rotvec",
    "T_from_rotvec",
    "T_to_rotvec",
    "rpy_deg_to_R",
    "R_to_rpy_deg",
    "T_from_xyz_rpy_deg",
    "T_to_xyz_rpy_deg",
    "is_rotation",
    "rotation_angle",
    "pose_error",
    "perturb_T",
]


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform from a 3x3 rotation and a translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, float)
    T[:3, 3] = np.asarray(t, float).reshape(3)
    return T


def invert_T(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform: ``T_b_a`` from ``T_a_b`` (exact, no general matrix inverse)."""
    T = np.asarray(T, float)
    R = T[:3, :3]
    return make_T(R.T, -R.T @ T[:3, 3])


def compose(*Ts: np.ndarray) -> np.ndarray:
    """``compose(T_a_b, T_b_c, ...) = T_a_b @ T_b_c @ ...``."""
    out = np.eye(4)
    for T in Ts:
        out = out @ np.asarray(T, float)
    return out


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Map (N,3) points from frame b into frame a."""
    T_a_b = np.asarray(T_a_b, float)
    pts = np.asarray(points_b)
    return pts @ T_a_b[:3, :3].T.astype(pts.dtype, copy=False) + T_a_b[:3, 3].astype(pts.dtype, copy=False)


def rotvec_to_R(rotvec: np.ndarray) -> np.ndarray:
    return _Rotation().from_rotvec(np.asarray(rotvec, float).reshape(3)).as_matrix()


def R_to_rotvec(R: np.ndarray) -> np.ndarray:
    return _Rotation().from_matrix(np.asarray(R, float)).as_rotvec()


def T_from_rotvec(rotvec: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Transform from a rotation vector (rad) and translation (m): the 6-vector used by solvers."""
    return make_T(rotvec_to_R(rotvec), t)


def T_to_rotvec(T: np.ndarray) -> np.ndarray:
    """6-vector ``[rx, ry, rz, tx, ty, tz]`` (rad, m)."""
    T = np.asarray(T, float)
    return np.concatenate([R_to_rotvec(T[:3, :3]), T[:3, 3]])


def rpy_deg_to_R(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` with angles in degrees (user interface)."""
    return _Rotation().from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()


def R_to_rpy_deg(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rpy_deg_to_R`: ``[roll, pitch, yaw]`` in degrees."""
    yaw, pitch, roll = _Rotation().from_matrix(np.asarray(R, float)).as_euler("ZYX", degrees=True)
    return np.array([roll, pitch, yaw])


def T_from_xyz_rpy_deg(x: float, y: float, z: float, roll: float, pitch: float, yaw: float) -> np.ndarray:
    return make_T(rpy_deg_to_R(roll, pitch, yaw), [x, y, z])


def T_to_xyz_rpy_deg(T: np.ndarray) -> np.ndarray:
    T = np.asarray(T, float)
    return np.concatenate([T[:3, 3], R_to_rpy_deg(T[:3, :3])])


def is_rotation(R: np.ndarray, tol: float = 1e-6) -> bool:
    """True when R is orthonormal with determinant +1 (within ``tol``)."""
    R = np.asarray(R, float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        return False
    return bool(np.abs(R.T @ R - np.eye(3)).max() < tol and abs(np.linalg.det(R) - 1.0) < tol)


def rotation_angle(R: np.ndarray) -> float:
    """Angle (rad) of a rotation matrix, robust near 0 and pi."""
    return float(np.linalg.norm(R_to_rotvec(R)))


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(rotation error in degrees, translation error in metres) between two transforms of the same direction."""
    dT = invert_T(T_true) @ np.asarray(T_est, float)
    return float(np.degrees(rotation_angle(dT[:3, :3]))), float(np.linalg.norm(np.asarray(T_est)[:3, 3] - np.asarray(T_true)[:3, 3]))


def perturb_T(T: np.ndarray, angle_deg: float, translation_m: float, rng: np.random.Generator) -> np.ndarray:
    """``T`` moved by a rotation of exactly ``angle_deg`` about a random axis and a random translation of
    exactly ``translation_m`` (applied on the left, in the target frame). Used for initial guesses in tests."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    dT = make_T(rotvec_to_R(axis * np.radians(angle_deg)), direction * translation_m)
    out = dT @ np.asarray(T, float)
    # keep the translation error exactly translation_m regardless of the rotation's effect on t
    out[:3, 3] = np.asarray(T, float)[:3, 3] + direction * translation_m
    return out
