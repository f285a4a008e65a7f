"""LiDAR side: the ground plane and corner-reflector extraction from a cloud (LiDAR frame, metres)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from radarcal import geometry

__all__ = ["GroundPlane", "ReflectorExtraction", "board_reflector_centres", "extract_reflectors", "fit_ground_plane"]


@dataclass
class GroundPlane:
    """``normal . p + d = 0`` in the LiDAR frame, ``normal`` unit and pointing up (towards the LiDAR)."""

    normal: np.ndarray
    d: float
    inliers: int
    rms: float

    def height(self, p: np.ndarray) -> np.ndarray:
        """Signed height of points above the plane along its normal."""
        return np.asarray(p, float) @ self.normal + self.d

    def T_lidar_ground(self) -> np.ndarray:
        """Ground frame: z = normal, origin = LiDAR origin dropped onto the plane, x = LiDAR x projected."""
        n = self.normal
        ex = np.array([1.0, 0.0, 0.0]) - n[0] * n
        if np.linalg.norm(ex) < 1e-6:
            ex = np.array([0.0, 1.0, 0.0]) - n[1] * n
        ex /= np.linalg.norm(ex)
        ey = np.cross(n, ex)
        return geometry.make_T(np.stack([ex, ey, n], axis=1), -self.d * n)


def fit_ground_plane(points: np.ndarray, max_range: float = 15.0, tol: float = 0.05, iterations: int = 300, rng: np.random.Generator | None = None,
                     up_hint: np.ndarray = (0.0, 0.0, 1.0), max_tilt: float = np.radians(30.0)) -> GroundPlane:
    """RANSAC plane (normal within ``max_tilt`` of ``up_hint``, the one with most inliers and below the sensor) +
    least-squares refit on its inliers. Vectorised over all hypotheses at once."""
    rng = np.random.default_rng(0) if rng is None else rng
    p = np.asarray(points, float).reshape(-1, 3)
    p = p[np.linalg.norm(p[:, :2], axis=1) < max_range]
    if len(p) < 3:
        raise ValueError("too few points for a ground plane")
    up = np.asarray(up_hint, float) / np.linalg.norm(up_hint)
    # prefer low points: the ground is below the sensor
    sub = p if len(p) <= 20000 else p[rng.choice(len(p), 20000, replace=False)]
    idx = rng.integers(0, len(sub), size=(iterations, 3))
    a, b, c = sub[idx[:, 0]], sub[idx[:, 1]], sub[idx[:, 2]]
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    good = norm > 1e-9
    n[good] /= norm[good, None]
    n *= np.sign(n @ up)[:, None] + (n @ up == 0)[:, None]
    good &= (n @ up) > np.cos(max_tilt)
    d = -np.sum(n * a, axis=1)
    good &= d > 0  # sensor (origin) above the plane
    if not good.any():
        raise ValueError("no ground plane found")
    n, d = n[good], d[good]
    counts = np.zeros(len(n), int)
    for s in range(0, len(n), 50):  # chunks of hypotheses x all points
        counts[s:s + 50] = np.sum(np.abs(sub @ n[s:s + 50].T + d[s:s + 50]) < tol, axis=0)
    k = int(np.argmax(counts))
    nk, dk = n[k], d[k]
    t = tol
    for _ in range(4):  # least squares on the inliers, shrinking the band to 3x their robust scale
        r = np.abs(p @ nk + dk)
        inl = p[r < t]
        t = min(tol, max(3.0 * 1.4826 * float(np.median(r[r < t])), 1e-6))
        c0 = inl.mean(axis=0)
        _, _, vt = np.linalg.svd(inl - c0, full_matrices=False)
        nk = vt[2] * np.sign(vt[2] @ up)
        dk = -float(nk @ c0)
    dist = p @ nk + dk
    inl = np.abs(dist) < t
    return GroundPlane(nk, dk, int(inl.sum()), float(np.sqrt(np.mean(dist[inl] ** 2))))


@dataclass
class ReflectorExtraction:
    centres: np.ndarray  # (K,3) reflector reference points in the LiDAR frame
    heights: np.ndarray  # (K,) above the ground plane
    n_points: np.ndarray  # (K,) points used for each centre
    ground: GroundPlane
    rejected: list  # [(centre xyz, reason)]


def extract_reflectors(
    points: np.ndarray,
    ground: GroundPlane | None = None,
    range_gate: float = 4.0,
    ground_tol: float = 0.05,
    cluster_tol: float = 0.12,
    min_points: int = 8,
    head_size: float = 0.35,
    max_extent: float = 0.8,
    offset: float = 0.0,
) -> ReflectorExtraction:
    """Reflector centres from a LiDAR cloud (LiDAR frame).

    Ground-plane fit (unless given), removal of points within ``ground_tol`` of it along its normal, Euclidean clusters
    (``cluster_tol``), clusters farther than ``range_gate`` (horizontal distance of their centre) dropped, tripod removed
    by keeping each cluster's top ``head_size`` metres along the normal, clusters wider than ``max_extent`` (walls,
    vehicles) rejected. The centre is the mean of the head points moved by ``offset`` along the viewing ray (the
    surface centroid of a trihedral facing the sensor lies in front of its apex, the radar's phase centre).
    """
    p = np.asarray(points, float).reshape(-1, 3)
    if ground is None:
        ground = fit_ground_plane(p, tol=ground_tol)
    h = ground.height(p)
    T_lg = ground.T_lidar_ground()
    pg = geometry.transform_points(geometry.invert_T(T_lg), p)
    keep = (h > ground_tol) & (np.linalg.norm(pg[:, :2], axis=1) < range_gate + 1.5 * max_extent)
    q, hq = p[keep], h[keep]
    centres, heights, npts, rejected = [], [], [], []
    if len(q):
        pairs = cKDTree(q).query_pairs(cluster_tol, output_type="ndarray")
        from scipy.sparse import coo_matrix

        adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(q), len(q)))
        ncomp, labels = connected_components(adj, directed=False)
        order = np.argsort(labels, kind="stable")
        bounds = np.searchsorted(labels[order], np.arange(ncomp + 1))
        for c in range(ncomp):  # loop over clusters (tens), each vectorised
            idx = order[bounds[c]:bounds[c + 1]]
            if len(idx) < min_points:
                continue
            cp, ch = q[idx], hq[idx]
            head = ch >= ch.max() - head_size
            hp = cp[head]
            centre = hp.mean(axis=0)
            cg = geometry.transform_points(geometry.invert_T(T_lg), centre[None])[0]
            if np.linalg.norm(cg[:2]) > range_gate:
                rejected.append((centre, f"farther than the {range_gate:g} m range gate"))
                continue
            ext = np.ptp(geometry.transform_points(geometry.invert_T(T_lg), cp)[:, :2], axis=0).max()
            if ext > max_extent:
                rejected.append((centre, f"{ext:.2f} m wide (> {max_extent:g} m): not a reflector"))
                continue
            if offset:
                centre = centre + offset * centre / np.linalg.norm(centre)
            centres.append(centre)
            heights.append(float(ground.height(centre[None])[0]))
            npts.append(int(head.sum()))
    return ReflectorExtraction(np.array(centres).reshape(-1, 3), np.array(heights), np.array(npts, int), ground, rejected)


def board_reflector_centres(circles: np.ndarray, offset: float = 0.105) -> np.ndarray:
    """Reflector reference points of TU Delft-style boards: mean of each board's circle centres (M,K,3) moved by
    ``offset`` along the board normal, away from the sensor (the trihedral sits behind the board)."""
    c = np.asarray(circles, float)
    mean = c.mean(axis=1)
    _, _, vt = np.linalg.svd(c - mean[:, None, :])
    n = vt[:, 2, :]
    n *= np.sign(np.sum(n * mean, axis=1))[:, None]
    return mean + offset * n

