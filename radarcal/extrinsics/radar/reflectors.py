"""LiDAR side: the ground plane and corner-reflector extraction from a cloud (LiDAR frame, metres)."""

from __future__ import annotations

from dataclasses import dataclass, field

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
    centres: np.ndarray  # (K,3) reflector reference points (apexes) in the LiDAR frame
    heights: np.ndarray  # (K,) above the ground plane
    n_points: np.ndarray  # (K,) points used for each centre
    ground: GroundPlane
    rejected: list  # [(centre xyz, reason)]
    method: list = field(default_factory=list)  # per centre: "plates" (three fitted plates intersected) | "offset"
    boresight: np.ndarray | None = None  # (K,3) unit opening direction (LiDAR frame), NaN where not resolved
    plate_rms: np.ndarray | None = None  # (K,) RMS distance of the head points to their plate (m), NaN for "offset"


@dataclass
class TrihedralFit:
    apex: np.ndarray  # (3,) intersection of the three plates
    normals: np.ndarray  # (3,3) unit plate normals (rows), oriented towards the opening
    boresight: np.ndarray  # (3,) unit opening direction: normalised sum of the normals
    rms: float  # point-to-plate RMS (m)
    inliers: int


def _plane_svd(p: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    c = p.mean(axis=0)
    _, sv, vt = np.linalg.svd(p - c, full_matrices=False)
    return vt[2], float(-vt[2] @ c), sv / np.sqrt(len(p))


def fit_trihedral(points: np.ndarray, edge: float | None = None, tol: float = 0.012, iterations: int = 300, rng: np.random.Generator | None = None) -> TrihedralFit | None:
    """The three plates of a trihedral corner reflector in a cluster's head points: sequential RANSAC planes (each
    next one within 15 deg of perpendicular to those found), least squares on their inliers, apex = their
    intersection. A plate must span two dimensions (its in-plane spread >= 5 % of the edge, or 1 cm): a tripod
    leg, a pole or a wire lies in many planes but spans none. Returns None when three such plates are not found
    (too few points, a flat board, legs)."""
    rng = np.random.default_rng(0) if rng is None else rng
    p = np.asarray(points, float).reshape(-1, 3)
    min_spread = max(0.05 * (edge or 0.2), 0.01)
    if len(p) < 30:
        return None
    rest = np.arange(len(p))
    planes = []
    for _k in range(3):  # three plates, each vectorised over RANSAC hypotheses
        q = p[rest]
        if len(q) < 10:
            return None
        idx = rng.integers(0, len(q), size=(iterations, 3))
        n = np.cross(q[idx[:, 1]] - q[idx[:, 0]], q[idx[:, 2]] - q[idx[:, 0]])
        nn = np.linalg.norm(n, axis=1)
        ok = nn > 1e-9
        n[ok] /= nn[ok, None]
        for m, _ in planes:  # perpendicular to the plates found so far
            ok &= np.abs(n @ m) < 0.26
        if not ok.any():
            return None
        n, d = n[ok], -np.sum(n[ok] * q[idx[ok, 0]], axis=1)
        counts = (np.abs(q @ n.T + d) < tol).sum(axis=0)
        k = int(np.argmax(counts))
        inl = np.abs(q @ n[k] + d[k]) < tol
        if inl.sum() < 10:
            return None
        m, dm, sv = _plane_svd(q[inl])
        inl = np.abs(q @ m + dm) < tol
        m, dm, sv = _plane_svd(q[inl])
        if sv[1] < min_spread:
            return None  # the inliers lie along a line: a leg, not a plate
        planes.append((m, dm))
        rest = rest[~inl]
    N = np.array([m for m, _ in planes])
    D = np.array([d for _, d in planes])
    for _it in range(3):  # each point to its nearest plate, refit (points near an edge are within tol of two)
        dist = np.abs(p @ N.T + D)
        own = np.argmin(dist, axis=1)
        for k in range(3):
            sel = (own == k) & (dist[np.arange(len(p)), own] < tol)
            if sel.sum() < 10:
                return None
            N[k], D[k], _ = _plane_svd(p[sel])
    if abs(np.linalg.det(N)) < 0.5:
        return None
    apex = np.linalg.solve(N, -D)
    # orient each normal towards the points' side (the opening): the points lie on the positive side of the others
    c = p.mean(axis=0)
    N = N * np.sign((c - apex) @ N.T)[:, None]
    bore = N.sum(axis=0)
    bore /= np.linalg.norm(bore)
    dist = np.min(np.abs(p @ N.T - (apex @ N.T)[None, :]), axis=1)
    used = dist < 2 * tol
    if used.mean() < 0.7 or np.linalg.norm(apex - c) > 1.5 * (edge or 0.4):
        return None
    return TrihedralFit(apex, N, bore, float(np.sqrt(np.mean(dist[used] ** 2))), int(used.sum()))


def linear_fraction(points: np.ndarray, k: int = 8) -> float:
    """Share of points whose ``k`` nearest neighbours lie along a line (largest covariance eigenvalue > 90 % of the
    total): ~1 for tripod legs, poles and wires, ~0 for plates."""
    p = np.asarray(points, float).reshape(-1, 3)
    if len(p) <= k:
        return 0.0
    _, nb = cKDTree(p).query(p, k=k)
    Q = p[nb] - p[nb].mean(axis=1, keepdims=True)
    C = np.einsum("nki,nkj->nij", Q, Q) / k
    ev = np.linalg.eigvalsh(C)
    return float(np.mean(ev[:, 2] > 0.9 * np.maximum(ev.sum(axis=1), 1e-18)))


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
    edge: float | None = None,
    intensity: np.ndarray | None = None,
) -> ReflectorExtraction:
    """Reflector apexes from a LiDAR cloud (LiDAR frame).

    Ground-plane fit (unless given), removal of points within ``ground_tol`` of it along its normal, Euclidean clusters
    (``cluster_tol``), clusters farther than ``range_gate`` (horizontal distance of their centre) dropped, the head
    kept (each cluster's top ``head_size`` metres along the normal: drops a mast below the head), then per head:

    - wider than ``max_extent`` (walls, vehicles) or, with ``edge`` known, more than 3 edges across: rejected;
    - line-like (:func:`linear_fraction` > 0.6: tripod legs, poles, wires): rejected;
    - intensity (when given): a head duller than 1.5x the ground's median while brighter clusters exist: rejected;
    - the three plates fitted (:func:`fit_trihedral`): apex = their intersection, right for a reflector turned away
      from the LiDAR too; otherwise the head's centroid moved by ``offset`` along the viewing ray (right only for a
      trihedral facing the sensor).
    """
    p = np.asarray(points, float).reshape(-1, 3)
    if ground is None:
        ground = fit_ground_plane(p, tol=ground_tol)
    h = ground.height(p)
    T_lg = ground.T_lidar_ground()
    T_gl = geometry.invert_T(T_lg)
    pg = geometry.transform_points(T_gl, p)
    keep = (h > ground_tol) & (np.linalg.norm(pg[:, :2], axis=1) < range_gate + 1.5 * max_extent)
    q, hq, qg = p[keep], h[keep], pg[keep]
    inten = None if intensity is None else np.asarray(intensity, float).reshape(-1)
    ground_lum = float(np.median(inten[~keep])) if inten is not None and (~keep).any() else None
    qi = None if inten is None else inten[keep]
    heads = []  # (centre, idx of head points)
    rejected = []
    for idx in _clusters(q, cluster_tol, min_points):
        hi = idx[hq[idx] >= hq[idx].max() - head_size]
        centre = q[hi].mean(axis=0)
        why = _head_rejection(q, qg, idx, hi, range_gate, max_extent, edge)
        if why is not None:
            rejected.append((centre, why))
        else:
            heads.append((centre, hi))
    bright = _bright_heads(qi, ground_lum, heads)
    centres, heights, npts, method, bores, prms = [], [], [], [], [], []
    for k, (centre, hi) in enumerate(heads):
        if bright is not None and not bright[k]:
            rejected.append((centre, f"dull (median intensity {np.median(qi[hi]):.3g} vs ground {ground_lum:.3g}): not a metal reflector"))
            continue
        apex, how, bore, rms = _head_apex(q[hi], centre, edge, offset)
        centres.append(apex)
        heights.append(float(ground.height(apex[None])[0]))
        npts.append(len(hi))
        method.append(how)
        bores.append(bore)
        prms.append(rms)
    return ReflectorExtraction(np.array(centres).reshape(-1, 3), np.array(heights), np.array(npts, int), ground, rejected, method,
                               np.array(bores).reshape(-1, 3), np.array(prms))


def _clusters(q: np.ndarray, cluster_tol: float, min_points: int) -> list[np.ndarray]:
    """Euclidean clusters of ``q`` (points closer than ``cluster_tol`` linked): index arrays of those with at least
    ``min_points`` points, in label order."""
    if not len(q):
        return []
    from scipy.sparse import coo_matrix

    pairs = cKDTree(q).query_pairs(cluster_tol, output_type="ndarray")
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(q), len(q)))
    ncomp, labels = connected_components(adj, directed=False)
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(ncomp + 1))
    out = []
    for c in range(ncomp):  # loop over clusters (tens)
        idx = order[bounds[c]:bounds[c + 1]]
        if len(idx) >= min_points:
            out.append(idx)
    return out


def _head_rejection(q, qg, idx, hi, range_gate, max_extent, edge) -> str | None:
    """Why cluster ``idx`` (head points ``hi``; ``qg`` in the ground frame) is not a reflector, or None: beyond the
    range gate, too wide, a head more than 3 edges across, or line-like."""
    cg = qg[hi].mean(axis=0)
    if np.linalg.norm(cg[:2]) > range_gate:
        return f"farther than the {range_gate:g} m range gate"
    ext = np.ptp(qg[idx][:, :2], axis=0).max()
    ext_head = np.ptp(qg[hi], axis=0).max()
    if ext > max_extent and (edge is None or ext_head > 3 * edge):
        return f"{ext:.2f} m wide (> {max_extent:g} m): not a reflector"
    if edge is not None and ext_head > 3 * edge:
        return f"head {ext_head:.2f} m across (> 3 reflector edges): not a reflector"
    lin = linear_fraction(q[hi])
    if lin > 0.6:
        return f"line-like ({100 * lin:.0f} % of its points on lines): a tripod leg, pole or wire"
    return None


def _bright_heads(qi, ground_lum, heads) -> np.ndarray | None:
    """Per head: median intensity above 1.5x the ground's; None when intensity is unknown or no head is bright
    (then intensity says nothing here)."""
    if qi is None or ground_lum is None or not heads:
        return None
    lum = np.array([np.median(qi[hi]) for _, hi in heads])
    bright = lum > 1.5 * max(ground_lum, 1e-6)
    return bright if bright.any() else None


def _head_apex(head: np.ndarray, centre: np.ndarray, edge, offset: float):
    """A head's apex (LiDAR frame): from its three fitted plates, else its centroid moved by ``offset`` along the
    viewing ray. Returns (apex, method, boresight or NaN, plate RMS or NaN)."""
    fit = fit_trihedral(head, edge=edge)
    if fit is not None:
        # with the plate centroid's offset known, the centroid moved back along the fitted boresight is less noisy
        # than the plates' intersection (the orientation is good to ~1 deg: ~2 mm at a 0.1 m offset)
        apex = centre - offset * fit.boresight if offset else fit.apex
        return apex, "plates", fit.boresight, fit.rms
    apex = centre + offset * centre / np.linalg.norm(centre) if offset else centre
    return apex, "offset", np.full(3, np.nan), float("nan")


def board_reflector_centres(circles: np.ndarray, offset: float = 0.105) -> np.ndarray:
    """Reflector reference points of TU Delft-style boards: mean of each board's circle centres (M,K,3) moved by
    ``offset`` along the board normal, away from the sensor (the trihedral sits behind the board)."""
    c = np.asarray(circles, float)
    mean = c.mean(axis=1)
    _, _, vt = np.linalg.svd(c - mean[:, None, :])
    n = vt[:, 2, :]
    n *= np.sign(np.sum(n * mean, axis=1))[:, None]
    return mean + offset * n

