"""Robust point-to-plane registration of a cloud to a surface — the numeric core shared by the ``lidar-field``
solver (:mod:`radarcal.extrinsics.lidar_field`, closest points from open3d) and the runtime's drift monitor
(:mod:`radarcal.runtime.drift`, closest points from :class:`SurfaceSamples`: scipy ``cKDTree``, no open3d).

Pure numpy: arrays in, arrays out. Frames: ``points`` in the sensor frame, ``T`` (4x4) maps them into the surface's
frame (``T_field_lidar``); metres and radians. A target is anything with ``closest(p (N,3)) -> (q (N,3), n (N,3))``:
the closest surface point and the unit normal there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radarcal import geometry

__all__ = ["SurfaceSamples", "point_to_plane_rows", "robust_point_to_plane", "point_to_plane_normal_matrix", "pose_delta"]


def point_to_plane_rows(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Jacobian rows (N,6) of ``r = n · (p + ω × p + v)`` with respect to the left perturbation (ω, v): ``[p × n, n]``."""
    return np.hstack([np.cross(p, n), n])


def robust_point_to_plane(points: np.ndarray, T: np.ndarray, target, gates: tuple[float, ...], iters: int, min_points: int = 50) -> np.ndarray:
    """Gauss-Newton on the point-to-plane residuals, coarse to fine: for each correspondence gate (m), up to ``iters``
    steps with the points farther than the gate from the surface rejected and a Geman-McClure weight of scale
    gate / 2 on the rest. Returns the refined ``T`` (the input ``T`` when fewer than ``min_points`` correspond)."""
    points = np.asarray(points, float)
    T = np.asarray(T, float)
    for gate in gates:
        for _ in range(iters):
            p = points @ T[:3, :3].T + T[:3, 3]
            q, n = target.closest(p)
            d = np.linalg.norm(p - q, axis=1)
            m = d < gate
            if m.sum() < min_points:
                return T
            r = np.sum((p[m] - q[m]) * n[m], axis=1)
            s = gate / 2
            w = (s * s / (s * s + r * r)) ** 2  # Geman-McClure
            J = point_to_plane_rows(p[m], n[m])
            H = (J * w[:, None]).T @ J + 1e-9 * np.eye(6)
            g = (J * w[:, None]).T @ r
            dx = -np.linalg.solve(H, g)
            T = geometry.make_T(geometry.rotvec_to_R(dx[:3]), dx[3:]) @ T
            if np.linalg.norm(dx[:3]) < 2e-6 and np.linalg.norm(dx[3:]) < 2e-5:
                break
    return T


def point_to_plane_normal_matrix(points: np.ndarray, T: np.ndarray, target, gate: float) -> tuple[np.ndarray, float, int]:
    """At ``T``: the weighted normal matrix H (6x6, left perturbation (ω, v) in the target frame), the residual
    variance s² (m²) and the number of points within ``gate``. ``s² · H⁻¹`` is the formal covariance."""
    p = np.asarray(points, float) @ T[:3, :3].T + T[:3, 3]
    q, n = target.closest(p)
    m = np.linalg.norm(p - q, axis=1) < gate
    if m.sum() < 7:
        return np.zeros((6, 6)), float("nan"), int(m.sum())
    r = np.sum((p[m] - q[m]) * n[m], axis=1)
    s = gate / 2
    w = (s * s / (s * s + r * r)) ** 2
    J = point_to_plane_rows(p[m], n[m])
    H = (J * w[:, None]).T @ J
    return H, float(np.sum(w * r * r) / max(1, int(m.sum()) - 6)), int(m.sum())


def pose_delta(T_new: np.ndarray, T_ref: np.ndarray) -> tuple[float, float]:
    """How far a sensor moved between two poses ``T_field_sensor``: (rotation in degrees, displacement of its origin
    in metres)."""
    return geometry.pose_error(T_new, T_ref)


@dataclass
class SurfaceSamples:
    """Points sampled on a triangle mesh with the unit normal of their triangle, in a ``cKDTree``: closest-point
    queries in numpy/scipy (no open3d), exact point-to-plane distances on the flat parts of the surface."""

    points: np.ndarray   # (M,3) in the mesh frame
    normals: np.ndarray  # (M,3)
    spacing: float

    def __post_init__(self) -> None:
        from scipy.spatial import cKDTree

        self.tree = cKDTree(self.points)

    @classmethod
    def from_mesh(cls, mesh, spacing: float = 0.05, seed: int = 0) -> "SurfaceSamples":
        """About one sample per ``spacing``² of surface (at least three per triangle). ``mesh``:
        :class:`radarcal.io.meshes.TriangleMesh`."""
        rng = np.random.default_rng(seed)
        c = mesh.corners
        a = mesh.areas()
        nrm = mesh.normals()
        keep = a > 0
        c, a, nrm = c[keep], a[keep], nrm[keep]
        k = np.maximum(3, np.ceil(a / spacing**2)).astype(np.int64)
        idx = np.repeat(np.arange(len(c)), k)
        r1 = np.sqrt(rng.random(len(idx)))
        r2 = rng.random(len(idx))
        pts = (1 - r1)[:, None] * c[idx, 0] + (r1 * (1 - r2))[:, None] * c[idx, 1] + (r1 * r2)[:, None] * c[idx, 2]
        return cls(pts, nrm[idx], float(spacing))

    def closest(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,3) -> nearest sample (N,3), its normal (N,3)."""
        _, i = self.tree.query(np.asarray(p, float), k=1)
        return self.points[i], self.normals[i]

    def distance(self, p: np.ndarray, upper: float = np.inf) -> np.ndarray:
        """(N,) distance to the nearest sample (``inf`` beyond ``upper``)."""
        d, _ = self.tree.query(np.asarray(p, float), k=1, distance_upper_bound=upper)
        return d
