"""Radar <-> radar and LiDAR <-> radar extrinsics from trihedral corner reflectors (pure numeric cores).

The method follows a patented procedure for mining trucks (CN, "multi-LiDAR and radar joint calibration for mining
areas") and goes beyond it where it is weak:

1. main frame = the front (main) LiDAR's frame;
2. radar <-> radar: 2D rigid transform (theta, a, b) between radars by nonlinear least squares, initialised in closed
   form (2D Procrustes) -> :func:`procrustes_2d`, :func:`fit_rigid_2d`;
3. LiDAR reflector extraction: ground-plane fit, removal of ground points along the plane normal, Euclidean clusters,
   range gate (4 m), tripod removal, cluster centres -> :func:`fit_ground_plane`, :func:`extract_reflectors`;
4. radar detection filtering into sets A (all in the region), B (seen by two or three radars), C (one radar only)
   -> :func:`filter_detections`;
5. LiDAR <-> radar (theta2, a2, b2) from >= 2 matches, chained into the main frame -> :func:`calibrate_rig`.

Beyond the method: the **slant-range model** (a 2D radar reports the slant range to a reflector that is not at its
mounting height; the fit predicts ``q * sqrt(|q|^2 + dz^2) / |q|`` with ``dz`` from the ground plane and the mounting
height, or estimates the height), robust matching (mutual nearest neighbour under the current estimate, RANSAC over
point pairs), per-reflector residuals, leave-one-out cross-validation, sigma of (theta, a, b), a quantisation report,
and a joint refinement of all radars at once (reflectors seen only by radars enter as free 2D points).

Frames: ``G`` is the ground frame of the main LiDAR (z = ground normal, origin = LiDAR origin dropped onto the
ground, x = LiDAR x projected onto the ground). A 2D radar is level at ``mount_height`` above the ground:
``T_G_radar = [Rz(theta), (a, b, mount_height)]`` and ``T_lidar_radar = T_lidar_G @ T_G_radar``.
2D transforms are ``p_dst = R(theta) p_src + t`` and are named like 4x4 ones (``theta_radar_G`` maps G into radar).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from radarcal import geometry

__all__ = [
    "rot2",
    "Pose2",
    "Fit2D",
    "procrustes_2d",
    "slant_predict",
    "deslant",
    "fit_rigid_2d",
    "procrustes_floor",
    "mutual_nn",
    "robust_match_2d",
    "robust_match_sets",
    "GroundPlane",
    "fit_ground_plane",
    "ReflectorExtraction",
    "extract_reflectors",
    "board_reflector_centres",
    "FilterResult",
    "filter_detections",
    "aggregate_frames",
    "quantisation_report",
    "leave_one_out",
    "reject_outliers",
    "SceneObs",
    "RadarResult",
    "RigCalibration",
    "calibrate_rig",
    "pose2_to_T",
    "build_scene_obs",
]


# ---------------------------------------------------------------------------------------------------------------
# 2D rigid transforms
# ---------------------------------------------------------------------------------------------------------------
def rot2(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@dataclass
class Pose2:
    """2D rigid transform ``p_dst = R(theta) p_src + t``."""

    theta: float
    t: np.ndarray

    def apply(self, p: np.ndarray) -> np.ndarray:
        return np.asarray(p, float) @ rot2(self.theta).T + self.t

    def inverse(self) -> "Pose2":
        R = rot2(self.theta)
        return Pose2(-self.theta, -R.T @ self.t)

    def compose(self, other: "Pose2") -> "Pose2":
        """``self @ other`` (apply ``other`` first)."""
        return Pose2(float(_wrap(self.theta + other.theta)), rot2(self.theta) @ other.t + self.t)

    def as_array(self) -> np.ndarray:
        return np.array([self.theta, self.t[0], self.t[1]])

    @classmethod
    def from_T(cls, T: np.ndarray) -> "Pose2":
        """Yaw and xy of a 4x4 (its out-of-plane part is dropped)."""
        T = np.asarray(T, float)
        return cls(float(np.arctan2(T[1, 0], T[0, 0])), T[:2, 3].copy())


def pose2_to_T(pose: Pose2, z: float = 0.0) -> np.ndarray:
    """4x4 ``[Rz(theta), (a, b, z)]``."""
    R = np.eye(3)
    R[:2, :2] = rot2(pose.theta)
    return geometry.make_T(R, [pose.t[0], pose.t[1], z])


def procrustes_2d(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None) -> Pose2:
    """Closed-form least-squares 2D rigid transform ``dst ~ R src + t`` (needs >= 2 distinct points)."""
    src = np.asarray(src, float).reshape(-1, 2)
    dst = np.asarray(dst, float).reshape(-1, 2)
    w = np.ones(len(src)) if weights is None else np.asarray(weights, float)
    w = w / w.sum()
    cs, cd = w @ src, w @ dst
    a, b = src - cs, dst - cd
    s_cos = np.sum(w * (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    s_sin = np.sum(w * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    theta = float(np.arctan2(s_sin, s_cos))
    return Pose2(theta, cd - rot2(theta) @ cs)


def slant_predict(q: np.ndarray, dz: np.ndarray | float) -> np.ndarray:
    """What a 2D radar reports for a reflector at horizontal position ``q`` (radar frame) and height ``dz`` above
    (or below) its scanning plane: the direction of ``q`` with the slant range ``sqrt(|q|^2 + dz^2)``."""
    q = np.asarray(q, float).reshape(-1, 2)
    dz = np.broadcast_to(np.asarray(dz, float), (len(q),))
    r = np.linalg.norm(q, axis=1)
    scale = np.sqrt(r**2 + dz**2) / np.maximum(r, 1e-12)
    return q * scale[:, None]


def deslant(m: np.ndarray, dz: np.ndarray | float) -> np.ndarray:
    """Inverse of :func:`slant_predict`: horizontal position from a slant measurement (range clipped at |dz|)."""
    m = np.asarray(m, float).reshape(-1, 2)
    dz = np.broadcast_to(np.asarray(dz, float), (len(m),))
    r = np.linalg.norm(m, axis=1)
    scale = np.sqrt(np.maximum(r**2 - dz**2, 0.0)) / np.maximum(r, 1e-12)
    return m * scale[:, None]


@dataclass
class Fit2D:
    """Result of :func:`fit_rigid_2d`: ``dst ~ slant(R(theta) src + t, src_z - height)``."""

    pose: Pose2
    height: float | None  # radar scanning-plane height in the src frame (slant model), None for the planar model
    residuals: np.ndarray  # (N,2) dst - prediction
    rms: float  # RMS of the 2D residual vector length
    sigma: dict  # 1-sigma of theta (rad), a, b (m) [and height]
    cov: np.ndarray
    n: int
    model: str  # "planar" | "slant" | "slant+height"
    jac: np.ndarray | None = None  # (2N, p) Jacobian of the prediction at the solution

    def deletion_residuals(self) -> np.ndarray:
        """Leave-one-out residual lengths from one fit (leverage formula ``(I - H_ii)^-1 r_i`` per 2x2 block; exact
        for a linear model, first order for this one)."""
        J = self.jac
        n = len(self.residuals)
        try:
            A = np.linalg.inv(J.T @ J)
        except np.linalg.LinAlgError:
            return np.full(n, np.nan)
        Jb = J.reshape(n, 2, -1)
        H = np.einsum("nip,pq,njq->nij", Jb, A, Jb)
        M = np.eye(2)[None] - H
        ok = np.abs(np.linalg.det(M)) > 1e-12
        out = np.full(n, np.inf)
        out[ok] = np.linalg.norm(np.linalg.solve(M[ok], self.residuals[ok][..., None])[..., 0], axis=1)
        return out

    @property
    def per_point(self) -> np.ndarray:
        return np.linalg.norm(self.residuals, axis=1)


def _jac_cov(J: np.ndarray, r: np.ndarray, sigma_meas: float | None) -> np.ndarray:
    n, p = J.shape
    JTJ = J.T @ J
    if sigma_meas is None:
        dof = max(n - p, 1)
        s2 = float(r @ r) / dof
    else:
        s2 = sigma_meas**2
    try:
        return np.linalg.inv(JTJ) * s2
    except np.linalg.LinAlgError:
        return np.full((p, p), np.inf)


def fit_rigid_2d(
    src: np.ndarray,
    dst: np.ndarray,
    init: Pose2 | None = None,
    src_z: np.ndarray | None = None,
    height: float | None = None,
    estimate_height: bool = False,
    height_init: float = 0.0,
    loss: str = "linear",
    f_scale: float = 0.05,
    sigma_meas: float | None = None,
) -> Fit2D:
    """Nonlinear least squares for ``(theta, a, b)`` (and optionally the radar plane height).

    ``src`` (N,2) horizontal positions (e.g. LiDAR reflector centres in the ground frame), ``dst`` (N,2) the radar's
    measurements. Planar model (the patent's): ``dst = R src + t``. Slant model (``src_z`` given): the radar reports
    the slant range to a reflector ``dz = src_z - height`` above its plane (``height`` known, or estimated with
    ``estimate_height``; only ``|dz|`` is observable, so the solution nearest ``height_init`` is returned).
    Initialised in closed form (:func:`procrustes_2d`) unless ``init`` is given. ``sigma`` comes from the Gauss-Newton
    covariance scaled by the residual variance (or by ``sigma_meas`` when given).
    """
    src = np.asarray(src, float).reshape(-1, 2)
    dst = np.asarray(dst, float).reshape(-1, 2)
    if len(src) < 2:
        raise ValueError("fit_rigid_2d needs at least 2 correspondences")
    slant = src_z is not None
    z = None if src_z is None else np.asarray(src_z, float).reshape(-1)
    est_h = bool(slant and estimate_height)
    if slant and not est_h and height is None:
        raise ValueError("slant model needs a radar height or estimate_height=True")
    if init is None:
        if slant:
            h0 = height_init if est_h else height
            init = procrustes_2d(src, deslant(dst, z - h0))
        else:
            init = procrustes_2d(src, dst)
    x0 = list(init.as_array()) + ([height_init] if est_h else [])

    def predict(x):
        q = src @ rot2(x[0]).T + x[1:3]
        if not slant:
            return q
        h = x[3] if est_h else height
        return slant_predict(q, z - h)

    def resid(x):
        return (predict(x) - dst).ravel()

    sol = least_squares(resid, np.asarray(x0, float), method="trf" if loss != "linear" else "lm" if 2 * len(src) >= len(x0) else "trf",
                        loss=loss, f_scale=f_scale, x_scale="jac")
    x = sol.x
    r = dst - predict(x)
    cov = _jac_cov(sol.jac, r.ravel(), sigma_meas)
    names = ["theta", "a", "b"] + (["height"] if est_h else [])
    sig = {k: float(np.sqrt(max(cov[i, i], 0.0))) for i, k in enumerate(names)}
    pose = Pose2(float(_wrap(x[0])), np.array(x[1:3]))
    h_out = float(x[3]) if est_h else (float(height) if slant else None)
    model = "planar" if not slant else ("slant+height" if est_h else "slant")
    return Fit2D(pose, h_out, r, float(np.sqrt(np.mean(np.sum(r**2, axis=1)))), sig, cov, len(src), model, np.asarray(sol.jac))


def procrustes_floor(src: np.ndarray, sigma: float, pose: Pose2 | None = None, src_z: np.ndarray | None = None, height: float | None = None) -> dict:
    """Cramér-Rao floor of ``dst = R src + t`` (or its slant version when ``src_z``/``height`` are given) with
    i.i.d. N(0, sigma^2) noise on each coordinate of ``dst``: RMS yaw (rad), RMS length of the translation error of
    ``t`` (``translation_m``) and, with ``pose``, of the inverse transform's translation (``inverse_translation_m``:
    the radar's position in the LiDAR ground frame). The least-squares estimate reaches it (Procrustes floor)."""
    src = np.asarray(src, float).reshape(-1, 2)
    pose = pose or Pose2(0.0, np.zeros(2))

    def pred(x):
        q = src @ rot2(x[0]).T + x[1:3]
        return q.ravel() if src_z is None else slant_predict(q, np.asarray(src_z) - height).ravel()

    x0 = pose.as_array()
    J = np.zeros((2 * len(src), 3))
    for k in range(3):  # central differences (3 parameters)
        e = np.zeros(3)
        e[k] = 1e-6
        J[:, k] = (pred(x0 + e) - pred(x0 - e)) / 2e-6
    cov = np.linalg.inv(J.T @ J) * sigma**2
    th, t = pose.theta, pose.t
    dR = np.array([[-np.sin(th), -np.cos(th)], [np.cos(th), -np.sin(th)]])
    Ji = np.zeros((3, 3))
    Ji[0, 0] = -1.0
    Ji[1:, 0] = -dR.T @ t
    Ji[1:, 1:] = -rot2(th).T
    ci = Ji @ cov @ Ji.T
    return {"yaw_rad": float(np.sqrt(cov[0, 0])), "translation_m": float(np.sqrt(cov[1, 1] + cov[2, 2])),
            "inverse_translation_m": float(np.sqrt(ci[1, 1] + ci[2, 2])), "cov": cov}


# ---------------------------------------------------------------------------------------------------------------
# matching
# ---------------------------------------------------------------------------------------------------------------
def mutual_nn(a: np.ndarray, b: np.ndarray, gate: float) -> np.ndarray:
    """(K,2) index pairs (i in a, j in b) that are each other's nearest neighbour and closer than ``gate``."""
    a = np.asarray(a, float).reshape(-1, 2)
    b = np.asarray(b, float).reshape(-1, 2)
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), int)
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    ja = np.argmin(d, axis=1)
    ib = np.argmin(d, axis=0)
    i = np.arange(len(a))
    ok = (ib[ja] == i) & (d[i, ja] < gate)
    return np.stack([i[ok], ja[ok]], axis=1)


def robust_match_2d(
    src: np.ndarray,
    dst: np.ndarray,
    init: Pose2 | None = None,
    gate: float = 0.3,
    max_rotation_from_init: float = np.radians(45.0),
    min_pair_distance: float = 0.3,
) -> tuple[np.ndarray, Pose2 | None]:
    """Correspondences between two 2D point sets related by an unknown rigid transform ``dst ~ R src + t``
    (see :func:`robust_match_sets`). Returns (pairs (K,2), pose) or (empty, None) when fewer than 2 matches exist."""
    pairs, pose = robust_match_sets([src], [dst], init, gate, max_rotation_from_init, min_pair_distance)
    return pairs[0], pose


def robust_match_sets(
    srcs: Sequence[np.ndarray],
    dsts: Sequence[np.ndarray],
    init: Pose2 | None = None,
    gate: float = 0.3,
    max_rotation_from_init: float = np.radians(45.0),
    min_pair_distance: float = 0.3,
    max_hypotheses: int = 400,
) -> tuple[list, Pose2 | None]:
    """One rigid transform ``dst ~ R src + t`` shared by several placements (lists of point sets, one pair per scene).

    Hypotheses: ``init`` itself (when given) and, in every scene, every pair of src points against every ordered pair
    of dst points whose separations agree within ``gate`` (RANSAC over pairs, exhaustive: the sets are small). A
    hypothesis is scored by its mutual-nearest-neighbour inliers within ``gate`` summed over all scenes (ties: the
    smaller mean squared residual), refined in closed form on them and re-matched. With ``init``, hypotheses are limited
    to rotations within ``max_rotation_from_init`` of it. More than ``max_hypotheses`` pair hypotheses are subsampled
    (seeded, so the result is deterministic). Returns (pairs per scene, pose) or (empties, None).
    """
    S = [np.asarray(x, float).reshape(-1, 2) for x in srcs]
    D = [np.asarray(x, float).reshape(-1, 2) for x in dsts]
    hyps: list[Pose2] = [init] if init is not None else []
    for src, dst in zip(S, D):
        ns, nd = len(src), len(dst)
        if ns < 2 or nd < 2:
            continue
        i1, i2 = np.triu_indices(ns, 1)
        j1, j2 = np.nonzero(~np.eye(nd, dtype=bool))  # ordered dst pairs
        ds = np.linalg.norm(src[i1] - src[i2], axis=1)
        dd = np.linalg.norm(dst[j1] - dst[j2], axis=1)
        ok = (np.abs(ds[:, None] - dd[None, :]) < gate) & (ds[:, None] > min_pair_distance)
        pi, pj = np.nonzero(ok)
        va = src[i2[pi]] - src[i1[pi]]
        vb = dst[j2[pj]] - dst[j1[pj]]
        th = np.arctan2(vb[:, 1], vb[:, 0]) - np.arctan2(va[:, 1], va[:, 0])
        if init is not None:
            keep = np.abs(_wrap(th - init.theta)) < max_rotation_from_init
            pi, pj, th = pi[keep], pj[keep], th[keep]
        cs = 0.5 * (src[i1[pi]] + src[i2[pi]])
        cd = 0.5 * (dst[j1[pj]] + dst[j2[pj]])
        c, s_ = np.cos(th), np.sin(th)
        t = cd - np.stack([c * cs[:, 0] - s_ * cs[:, 1], s_ * cs[:, 0] + c * cs[:, 1]], axis=1)
        hyps += [Pose2(float(th[k]), t[k]) for k in range(len(th))]
    if len(hyps) > max_hypotheses:
        first = hyps[:1] if init is not None else []
        pick = np.random.default_rng(0).choice(len(hyps) - len(first), max_hypotheses, replace=False) + len(first)
        hyps = first + [hyps[k] for k in np.sort(pick)]

    def match(pose):
        return [mutual_nn(pose.apply(a), b, gate) for a, b in zip(S, D)]

    def stack(pairs):
        a = np.concatenate([S[k][p[:, 0]] for k, p in enumerate(pairs)]) if pairs else np.zeros((0, 2))
        b = np.concatenate([D[k][p[:, 1]] for k, p in enumerate(pairs)]) if pairs else np.zeros((0, 2))
        return a, b

    empty = [np.zeros((0, 2), int) for _ in S]
    best = (empty, None, 0, np.inf)
    seen = set()
    for h in hyps:  # loop over hypotheses (a few hundred at most), each vectorised
        key = (round(h.theta, 3), round(float(h.t[0]), 2), round(float(h.t[1]), 2))
        if key in seen:
            continue
        seen.add(key)
        pose, pairs = h, match(h)
        for _ in range(3):
            a, b = stack(pairs)
            if len(a) < 2:
                break
            pose = procrustes_2d(a, b)
            if init is not None and abs(_wrap(pose.theta - init.theta)) > max_rotation_from_init:
                pairs = empty
                break
            new = match(pose)
            if all(np.array_equal(x, y) for x, y in zip(new, pairs)):
                break
            pairs = new
        a, b = stack(pairs)
        if len(a) < 2:
            continue
        cost = float(np.mean(np.sum((pose.apply(a) - b) ** 2, axis=1)))
        if len(a) > best[2] or (len(a) == best[2] and cost < best[3]):
            best = (pairs, pose, len(a), cost)
    return best[0], best[1]


# ---------------------------------------------------------------------------------------------------------------
# LiDAR side: ground plane and reflector clusters
# ---------------------------------------------------------------------------------------------------------------
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


# ---------------------------------------------------------------------------------------------------------------
# radar side: frame aggregation, A/B/C filtering, quantisation
# ---------------------------------------------------------------------------------------------------------------
def aggregate_frames(xy: np.ndarray, gate: float = 0.3, min_fraction: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Average repeated detections of one radar over many frames: greedy single-linkage clusters within ``gate``,
    cluster means; clusters seen in fewer than ``min_fraction`` of the most-seen cluster's frames are dropped
    (ghosts). Returns (means (K,2), counts (K,))."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if len(xy) == 0:
        return xy, np.zeros(0, int)
    pairs = cKDTree(xy).query_pairs(gate, output_type="ndarray")
    from scipy.sparse import coo_matrix

    ncomp, lab = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(xy), len(xy))), directed=False)
    counts = np.bincount(lab, minlength=ncomp)
    sums = np.zeros((ncomp, 2))
    np.add.at(sums, lab, xy)
    means = sums / counts[:, None]
    keep = counts >= max(1, min_fraction * counts.max())
    return means[keep], counts[keep]


@dataclass
class FilterResult:
    """Detections of all radars in the reference radar frame, split as in the patent.

    ``A``: indices of detections inside the region; ``B``: those seen by two or three radars (a detection of another
    radar within ``gate``); ``C``: seen by one radar only. ``groups`` (per B detection) lists the merged cluster id.
    """

    points: np.ndarray  # (M,2) all detections in the reference frame
    radar: np.ndarray  # (M,) radar index
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    cluster: np.ndarray  # (M,) cluster id (-1 outside the region)
    cluster_means: np.ndarray  # (K,2)
    cluster_radars: np.ndarray  # (K,) number of distinct radars in the cluster

    def counts(self) -> dict:
        return {"A": int(len(self.A)), "B": int(len(self.B)), "C": int(len(self.C))}


def filter_detections(points_ref: Sequence[np.ndarray], forward: tuple[float, float] = (0.0, 5.0), lateral: tuple[float, float] = (-5.0, 5.0),
                      gate: float = 0.3) -> FilterResult:
    """Sets A/B/C of the patent from every radar's detections already mapped into the reference radar frame.

    The patent's region is x in (-5, 5), y in (0, 5) with y forward; here ``forward`` bounds x and ``lateral`` bounds
    y of the reference radar frame (x forward, y left)."""
    pts = np.concatenate([np.asarray(p, float).reshape(-1, 2) for p in points_ref]) if len(points_ref) else np.zeros((0, 2))
    rid = np.concatenate([np.full(len(np.asarray(p).reshape(-1, 2)), i) for i, p in enumerate(points_ref)]) if len(points_ref) else np.zeros(0, int)
    inside = (pts[:, 0] > forward[0]) & (pts[:, 0] < forward[1]) & (pts[:, 1] > lateral[0]) & (pts[:, 1] < lateral[1])
    A = np.nonzero(inside)[0]
    cluster = np.full(len(pts), -1)
    means = np.zeros((0, 2))
    nrad = np.zeros(0, int)
    B = C = np.zeros(0, int)
    if len(A):
        pa = pts[A]
        pairs = cKDTree(pa).query_pairs(gate, output_type="ndarray")
        pairs = pairs[rid[A][pairs[:, 0]] != rid[A][pairs[:, 1]]]  # only links between different radars
        from scipy.sparse import coo_matrix

        ncomp, lab = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(A), len(A))), directed=False)
        cluster[A] = lab
        means = np.zeros((ncomp, 2))
        np.add.at(means, lab, pa)
        means /= np.bincount(lab, minlength=ncomp)[:, None]
        nrad = np.array([len(np.unique(rid[A][lab == k])) for k in range(ncomp)])  # loop over clusters
        multi = nrad[lab] >= 2
        B, C = A[multi], A[~multi]
    return FilterResult(pts, rid, A, B, C, cluster, means, nrad)


def quantisation_report(xy: np.ndarray, candidates: Sequence[float] = (0.2, 0.1, 0.25, 0.5, 0.05)) -> dict:
    """Detect a coordinate grid (ARS408 object lists: 0.2 m) and what it costs: the per-axis error of a quantised
    value is uniform with sigma ``q / sqrt(12)``; it is a deterministic function of the true position, so averaging
    frames does not remove it (only noise larger than ``q`` would dither it away)."""
    xy = np.asarray(xy, float).ravel()
    xy = xy[np.isfinite(xy)]
    for q in candidates:
        if len(xy) >= 4 and np.all(np.abs(xy / q - np.round(xy / q)) < 1e-3):
            return {"quantised": True, "step_m": q, "sigma_per_axis_m": q / np.sqrt(12.0), "averaging_removes_it": False,
                    "note": f"coordinates lie on a {q:g} m grid: a {q / np.sqrt(12):.3f} m per-axis error that averaging frames cannot remove"}
    return {"quantised": False, "step_m": None, "sigma_per_axis_m": 0.0, "averaging_removes_it": True, "note": "no coordinate grid detected"}


# ---------------------------------------------------------------------------------------------------------------
# cross-validation and outliers
# ---------------------------------------------------------------------------------------------------------------
def leave_one_out(src: np.ndarray, dst: np.ndarray, **fit_kw) -> dict:
    """Refit without each correspondence in turn: its prediction error (hold-out residual), the parameter spread
    and the jackknife standard errors of (theta, a, b)."""
    src = np.asarray(src, float).reshape(-1, 2)
    dst = np.asarray(dst, float).reshape(-1, 2)
    n = len(src)
    min_n = 3 if fit_kw.get("estimate_height") else 2
    if n <= min_n:
        return {"n": n, "holdout_residuals": np.full(n, np.nan), "holdout_rms": float("nan"), "params": np.zeros((0, 3)), "jackknife_sigma": {}}
    z = fit_kw.pop("src_z", None)
    res = np.zeros(n)
    params = np.zeros((n, 3))
    for i in range(n):  # loop over reflectors (few)
        m = np.arange(n) != i
        f = fit_rigid_2d(src[m], dst[m], src_z=None if z is None else np.asarray(z)[m], **fit_kw)
        q = f.pose.apply(src[i:i + 1])
        pred = q if z is None else slant_predict(q, np.asarray(z)[i] - f.height)
        res[i] = float(np.linalg.norm(pred[0] - dst[i]))
        params[i] = f.pose.as_array()
    params[:, 0] = params[0, 0] + _wrap(params[:, 0] - params[0, 0])
    jk = np.sqrt((n - 1) / n * np.sum((params - params.mean(axis=0)) ** 2, axis=0))
    return {"n": n, "holdout_residuals": res, "holdout_rms": float(np.sqrt(np.mean(res**2))), "params": params,
            "std": {"theta": float(params[:, 0].std()), "a": float(params[:, 1].std()), "b": float(params[:, 2].std())},
            "jackknife_sigma": {"theta": float(jk[0]), "a": float(jk[1]), "b": float(jk[2])}}


def reject_outliers(src: np.ndarray, dst: np.ndarray, threshold: float = 0.15, min_keep: int = 3, k_sigma: float = 4.0, **fit_kw) -> tuple[np.ndarray, list]:
    """Iteratively drop the correspondence with the largest leave-one-out residual (leverage formula to pick it, an
    exact refit without it to test it) while that hold-out residual exceeds both ``threshold`` (m) and ``k_sigma``
    times the RMS residual of the fit without it. Returns (keep mask, [(index, reason)])."""
    src = np.asarray(src, float).reshape(-1, 2)
    dst = np.asarray(dst, float).reshape(-1, 2)
    keep = np.ones(len(src), bool)
    reasons = []
    z = fit_kw.pop("src_z", None)
    zz = None if z is None else np.asarray(z, float)
    n_par = 4 if fit_kw.get("estimate_height") else 3
    while keep.sum() > max(min_keep, 2) and 2 * (keep.sum() - 1) > n_par:
        idx = np.nonzero(keep)[0]
        f = fit_rigid_2d(src[idx], dst[idx], src_z=None if zz is None else zz[idx], **fit_kw)
        if f.rms <= threshold / k_sigma / 4:
            break  # everything already fits far below the threshold
        r = f.deletion_residuals()
        j = int(np.nanargmax(np.where(np.isfinite(r), r, -1)))
        rest = np.delete(idx, j)
        g = fit_rigid_2d(src[rest], dst[rest], src_z=None if zz is None else zz[rest], init=f.pose, **fit_kw)
        q = g.pose.apply(src[idx[j]][None])
        pred = q if zz is None else slant_predict(q, zz[idx[j]] - g.height)
        rj = float(np.linalg.norm(pred[0] - dst[idx[j]]))
        if rj > threshold and rj > k_sigma * g.rms:
            keep[idx[j]] = False
            reasons.append((int(idx[j]), f"hold-out residual {rj:.3f} m > {threshold:g} m and > {k_sigma:g}x the others' RMS ({g.rms:.3f} m)"))
        else:
            break
    return keep, reasons


# ---------------------------------------------------------------------------------------------------------------
# the whole rig
# ---------------------------------------------------------------------------------------------------------------
@dataclass
class SceneObs:
    """One reflector placement: LiDAR reflector centres (main LiDAR frame) and each radar's detections (its frame)."""

    name: str
    lidar_centres: np.ndarray  # (K,3)
    radar_xy: dict  # radar name -> (M,2)
    ground: GroundPlane | None = None
    raw_radar_xy: dict | None = None  # before frame averaging (for the quantisation report)


@dataclass
class RadarResult:
    name: str
    pose_G: Pose2  # T_G_radar in 2D (radar -> ground frame)
    mount_height: float
    T_lidar_radar: np.ndarray  # 4x4, radar -> main LiDAR
    fit: Fit2D  # LiDAR <-> radar fit of the final model (dst = radar measurement, src = ground-frame xy)
    pairwise_pose_ref: Pose2 | None  # (theta1, a1, b1): this radar -> reference radar (patent step 2)
    per_reflector: list  # dicts: scene, lidar index, radar xy, residual (m)
    loo: dict
    rejected: list
    patent_pose_G: Pose2 | None = None  # (theta2, a2, b2) chain before joint refinement
    sigma_G: dict = field(default_factory=dict)  # 1-sigma of T_G_radar's (theta, a, b) (+ height when estimated)


@dataclass
class RigCalibration:
    T_lidar_G: np.ndarray
    radars: dict  # name -> RadarResult
    filter_counts: dict  # scene -> {A, B, C}
    radar_radar: dict  # name -> {pose_ref, rms, n}
    joint: dict  # summary of the joint refinement
    quantisation: dict
    model: str
    notes: list


def _obs_for_radar(scenes, lidar_G, name, pose_G, mount_h, gate, slant):
    """Mutual-NN matches of one radar's detections with the LiDAR reflectors under ``pose_G`` (T_G_radar)."""
    src, dst, z, info = [], [], [], []
    inv = pose_G.inverse()
    for si, sc in enumerate(scenes):
        m = np.asarray(sc.radar_xy.get(name, np.zeros((0, 2))), float).reshape(-1, 2)
        pg = lidar_G[si]
        if len(m) == 0 or len(pg) == 0:
            continue
        q = inv.apply(pg[:, :2])
        pred = slant_predict(q, pg[:, 2] - mount_h) if slant else q
        pairs = mutual_nn(pred, m, gate)
        for i, j in pairs:
            src.append(pg[i, :2]), dst.append(m[j]), z.append(pg[i, 2]), info.append((sc.name, int(i), int(j)))
    return np.array(src).reshape(-1, 2), np.array(dst).reshape(-1, 2), np.array(z), info


def calibrate_rig(
    scenes: Sequence[SceneObs],
    radar_names: Sequence[str],
    mount_heights: dict,
    reference: str | None = None,
    init_T_lidar_radar: dict | None = None,
    model: str = "slant",
    gate: float = 0.35,
    forward: tuple[float, float] = (0.0, 5.0),
    lateral: tuple[float, float] = (-5.0, 5.0),
    outlier_threshold: float = 0.15,
    joint: bool = True,
    ground: GroundPlane | None = None,
) -> RigCalibration:
    """Every radar into the main LiDAR frame (patent steps 2-5, then the improvements).

    ``model``: ``"slant"`` (radar mounting heights + ground plane; default), ``"planar"`` (the patent: reflector
    centres' z dropped in the LiDAR frame, no slant). ``mount_heights``: radar scanning-plane height above the ground
    (m); a radar without one gets it estimated (slant model). ``init_T_lidar_radar``: optional nominal poses (used to
    pick correspondences; without them RANSAC over pairs decides).
    """
    notes: list[str] = []
    if not scenes:
        raise ValueError("no scenes")
    radar_names = list(radar_names)
    reference = reference or (radar_names[len(radar_names) // 2])
    slant = model == "slant"
    # --- ground frame -------------------------------------------------------------------------------------------
    if model == "planar":
        T_lidar_G = np.eye(4)
    else:
        planes = [s.ground for s in scenes if s.ground is not None]
        if ground is None and planes:
            n = np.mean([g.normal for g in planes], axis=0)
            n /= np.linalg.norm(n)
            ground = GroundPlane(n, float(np.mean([g.d for g in planes])), int(sum(g.inliers for g in planes)), float(np.mean([g.rms for g in planes])))
        T_lidar_G = ground.T_lidar_ground() if ground is not None else np.eye(4)
        if ground is None:
            notes.append("no ground plane: the LiDAR frame is taken as level (z up) and heights are LiDAR z")
    T_G_lidar = geometry.invert_T(T_lidar_G)
    lidar_G = [geometry.transform_points(T_G_lidar, np.asarray(s.lidar_centres, float).reshape(-1, 3)) for s in scenes]
    all_z = np.concatenate([p[:, 2] for p in lidar_G]) if lidar_G else np.zeros(0)
    z_nominal = float(np.median(all_z)) if len(all_z) else 0.0
    init_G: dict[str, Pose2] = {}
    for r in radar_names:
        if init_T_lidar_radar and r in init_T_lidar_radar and init_T_lidar_radar[r] is not None:
            init_G[r] = Pose2.from_T(T_G_lidar @ np.asarray(init_T_lidar_radar[r], float))
    heights = {r: (None if mount_heights.get(r) is None else float(mount_heights[r])) for r in radar_names}
    for r in radar_names:
        if slant and heights[r] is None:
            notes.append(f"{r}: no mounting height given: estimated from the slant model (only |dz| is observable)")

    # unknown height: start below the reflectors (bumper height); dz = 0 is a stationary point of the slant model
    h_guess = 0.5 if abs(z_nominal - 0.5) > 0.15 else z_nominal - 0.4

    def _desl(name, m):
        if not slant:
            return np.asarray(m, float).reshape(-1, 2)
        h = heights[name] if heights[name] is not None else h_guess
        return deslant(m, z_nominal - h)

    # --- step 2: radar <-> radar (theta1, a1, b1): each radar into the reference radar ---------------------------
    radar_radar: dict[str, dict] = {}
    pose_ref: dict[str, Pose2] = {reference: Pose2(0.0, np.zeros(2))}
    for r in radar_names:
        if r == reference:
            continue
        init = None
        if reference in init_G and r in init_G:
            init = init_G[reference].inverse().compose(init_G[r])
        A_ = [_desl(r, sc.radar_xy.get(r, np.zeros((0, 2)))) for sc in scenes]
        B_ = [_desl(reference, sc.radar_xy.get(reference, np.zeros((0, 2)))) for sc in scenes]
        pairs_l, _ = robust_match_sets(A_, B_, init=init, gate=gate)
        src = [a[p[:, 0]] for a, p in zip(A_, pairs_l) if len(p)]
        dst = [b[p[:, 1]] for b, p in zip(B_, pairs_l) if len(p)]
        if src and sum(len(s) for s in src) >= 2:
            s_, d_ = np.concatenate(src), np.concatenate(dst)
            f = fit_rigid_2d(s_, d_)
            pose_ref[r] = f.pose
            radar_radar[r] = {"pose_ref": f.pose, "rms": f.rms, "n": f.n, "sigma": f.sigma}
        else:
            notes.append(f"{r}: no common reflectors with {reference}: calibrated against the LiDAR only")
    # --- step 4: filter detections in the reference frame (A/B/C) -------------------------------------------------
    filter_counts = {}
    merged = []  # per scene: (means (K,2) in ref frame, is_multi (K,))
    for sc in scenes:
        pts = [pose_ref[r].apply(_desl(r, sc.radar_xy.get(r, np.zeros((0, 2))))) if r in pose_ref else np.zeros((0, 2)) for r in radar_names]
        fr = filter_detections(pts, forward, lateral, gate)
        filter_counts[sc.name] = fr.counts()
        nb = int((fr.cluster_radars >= 2).sum())
        if nb < 2:
            notes.append(f"scene {sc.name}: {nb} reflector(s) seen by two or more radars (set B): set A used for the LiDAR match")
        if len(fr.C) > len(fr.B):
            notes.append(f"scene {sc.name}: more single-radar detections (C = {len(fr.C)}) than multi-radar ones (B = {len(fr.B)}): ghosts or radars that see too little")
        merged.append((fr.cluster_means, fr.cluster_radars >= 2))
    # --- step 5: LiDAR <-> reference radar (theta2, a2, b2) with B (+ C consistent with the LiDAR) ----------------
    init_ref_G = init_G.get(reference)
    b_sets = [means[multi] if multi.sum() >= 2 else means for means, multi in merged]  # patent: keep B; too few -> A
    pairs_l, _ = robust_match_sets(b_sets, [p[:, :2] for p in lidar_G], init=init_ref_G, gate=gate)
    src = [b[p[:, 0]] for b, p in zip(b_sets, pairs_l) if len(p)]
    dst = [g[p[:, 1], :2] for g, p in zip(lidar_G, pairs_l) if len(p)]
    if sum(len(x) for x in src) < 2:
        raise ValueError("fewer than 2 reflectors matched between the LiDAR and the radars")
    f_ref = fit_rigid_2d(np.concatenate(src), np.concatenate(dst))  # ref radar -> G
    patent_G = {r: f_ref.pose.compose(pose_ref[r]) for r in pose_ref}
    # --- per radar: final model fit (slant), robust re-matching, outliers -----------------------------------------
    results: dict[str, RadarResult] = {}
    pose_G = dict(patent_G)
    for r in radar_names:
        if r not in pose_G:
            if r in init_G:
                pose_G[r] = init_G[r]
            else:
                notes.append(f"{r}: no initial pose and no radar-radar link: skipped")
                continue
    fits: dict[str, Fit2D] = {}
    keepinfo: dict[str, tuple] = {}
    for r in list(pose_G):
        h = heights[r] if heights[r] is not None else h_guess
        for _ in range(3):
            s_, d_, z_, info = _obs_for_radar(scenes, lidar_G, r, pose_G[r], h, gate, slant)
            if len(s_) < 2:
                break
            kw = _fit_kw(slant, heights[r], h)
            keep, rej = reject_outliers(s_, d_, threshold=outlier_threshold, **({**kw, "src_z": z_} if slant else kw))
            f = fit_rigid_2d(s_[keep], d_[keep], src_z=z_[keep] if slant else None, **kw)
            # f maps G -> radar; pose_G is radar -> G
            new = f.pose.inverse()
            h = f.height if f.height is not None else h
            converged = abs(_wrap(new.theta - pose_G[r].theta)) < 1e-10 and np.allclose(new.t, pose_G[r].t, atol=1e-9)
            pose_G[r] = new
            fits[r] = f
            keepinfo[r] = (s_, d_, z_, info, keep, rej, kw)
            if converged:
                break
        if r not in fits:
            notes.append(f"{r}: fewer than 2 reflectors matched to the LiDAR: not calibrated")
        if r in fits and heights[r] is None and slant:
            heights[r] = float(fits[r].height)
    # --- joint refinement: all radars at once, radar-only reflectors as free 2D points ----------------------------
    joint_info = {"enabled": bool(joint), "free_points": 0, "n_obs": 0}
    if joint and len(fits) >= 2:
        ref_inv = pose_G[reference].inverse() if reference in pose_G else Pose2(0.0, np.zeros(2))

        def in_region(p_G):
            q = ref_inv.apply(p_G)
            return (q[:, 0] > forward[0]) & (q[:, 0] < forward[1]) & (q[:, 1] > lateral[0]) & (q[:, 1] < lateral[1])

        pose_G, heights, joint_info = _joint_refine(scenes, lidar_G, pose_G, heights, fits, keepinfo, slant, gate, z_nominal, in_region)
    # --- results ------------------------------------------------------------------------------------------------
    for r in fits:
        s_, d_, z_, info, keep, rej, kw = keepinfo[r]
        h = heights[r]
        kw2 = _fit_kw(slant, h, h)
        # LiDAR-anchored fit at the final height: sigma and leave-one-out; the pose is the joint one (same when no
        # radar-only reflectors exist)
        f = fit_rigid_2d(s_[keep], d_[keep], src_z=z_[keep] if slant else None, init=pose_G[r].inverse(), **kw2)
        if not joint_info.get("free_points"):
            pose_G[r] = f.pose.inverse()
        loo = leave_one_out(s_[keep], d_[keep], **({**kw2, "src_z": z_[keep]} if slant else kw2))
        q = pose_G[r].inverse().apply(s_)
        pred = slant_predict(q, z_ - h) if slant else q
        res_vec = d_ - pred
        resid = np.linalg.norm(res_vec, axis=1)
        f.residuals = res_vec[keep]
        f.rms = float(np.sqrt(np.mean(resid[keep] ** 2))) if keep.any() else float("nan")
        kidx = np.cumsum(keep) - 1
        per = []
        for k, (scn, i, j) in enumerate(info):  # per reflector observation (few)
            per.append({"scene": scn, "lidar_index": i, "radar_index": j, "radar_xy": d_[k], "residual_m": float(resid[k]), "used": bool(keep[k]),
                        "holdout_residual_m": float(loo["holdout_residuals"][kidx[k]]) if keep[k] and len(loo["holdout_residuals"]) else float("nan")})
        mh = h if h is not None else 0.0
        T_G_radar = pose2_to_T(pose_G[r], mh if slant else 0.0)
        results[r] = RadarResult(r, pose_G[r], mh, T_lidar_G @ T_G_radar, f, radar_radar.get(r, {}).get("pose_ref"), per, loo,
                                 [(info[i], why) for i, why in rej], patent_G.get(r), _inverse_sigma(f))
    allxy = np.concatenate([np.asarray(v, float).reshape(-1, 2) for s in scenes for v in (s.raw_radar_xy or s.radar_xy).values()]) if scenes else np.zeros((0, 2))
    return RigCalibration(T_lidar_G, results, filter_counts, radar_radar, joint_info, quantisation_report(allxy), model, notes)


def _inverse_sigma(f: Fit2D) -> dict:
    """Sigma of the inverse pose's (theta, a, b) by first-order propagation of ``f.cov`` (fit maps G -> radar)."""
    th, t = f.pose.theta, f.pose.t
    R = rot2(th)
    dR = np.array([[-np.sin(th), -np.cos(th)], [np.cos(th), -np.sin(th)]])
    J = np.zeros((3, 3))
    J[0, 0] = -1.0
    J[1:, 0] = -dR.T @ t
    J[1:, 1:] = -R.T
    C = J @ f.cov[:3, :3] @ J.T
    out = {k: float(np.sqrt(max(C[i, i], 0.0))) for i, k in enumerate(["theta", "a", "b"])}
    if "height" in f.sigma:
        out["height"] = f.sigma["height"]
    return out


def _fit_kw(slant: bool, known_h, h_guess) -> dict:
    if not slant:
        return {}
    if known_h is None:
        return {"estimate_height": True, "height_init": float(h_guess)}
    return {"height": float(known_h)}


def _joint_refine(scenes, lidar_G, pose_G, heights, fits, keepinfo, slant, gate, z_nominal, in_region):
    """All radar poses at once. Observations: every radar's matched LiDAR reflectors (kept ones), plus detections of
    reflectors that two or more radars see but the LiDAR does not (free 2D points at the median reflector height)."""
    names = list(fits)
    # free points: per scene, cluster unmatched detections (in G under current poses) seen by >= 2 radars
    free_obs = []  # (radar index, free point index, measurement)
    free_init = []
    for si, sc in enumerate(scenes):
        pts, rid, mids = [], [], []
        for k, r in enumerate(names):
            m = np.asarray(sc.radar_xy.get(r, np.zeros((0, 2))), float).reshape(-1, 2)
            if len(m) == 0:
                continue
            used = {j for (scn, i, j), kp in zip(keepinfo[r][3], keepinfo[r][4]) if scn == sc.name}
            un = np.array([j for j in range(len(m)) if j not in used], int)
            if len(un) == 0:
                continue
            h = heights[r] if heights[r] is not None else 0.0
            mg = pose_G[r].apply(deslant(m[un], z_nominal - h) if slant else m[un])
            inside = in_region(mg)
            un, mg = un[inside], mg[inside]
            if len(un) == 0:
                continue
            pts.append(mg), rid.append(np.full(len(un), k)), mids.append(m[un])
        if not pts:
            continue
        fr = filter_detections([np.concatenate(pts)[np.concatenate(rid) == k] for k in range(len(names))], (-np.inf, np.inf), (-np.inf, np.inf), gate)
        allm = np.concatenate(mids)
        allr = np.concatenate(rid)
        order = np.argsort(allr, kind="stable")  # filter_detections concatenates radar by radar
        allm, allr = allm[order], allr[order]
        for c in np.nonzero(fr.cluster_radars >= 2)[0]:
            members = np.nonzero(fr.cluster == c)[0]
            if len(np.unique(allr[members])) != len(members):
                continue  # two detections of one radar in a cluster: ambiguous, skip
            fid = len(free_init)
            free_init.append(fr.cluster_means[c])
            for mi in members:
                free_obs.append((int(allr[mi]), fid, allm[mi]))
    est_h = [slant and heights[r] is None for r in names]
    nr = len(names)
    x0 = np.concatenate([np.concatenate([pose_G[r].as_array() for r in names]), np.array([heights[r] or 0.0 for r in names]), np.array(free_init).ravel()])
    anchored = []
    for k, r in enumerate(names):
        s_, d_, z_, info, keep, rej, kw = keepinfo[r]
        anchored.append((k, s_[keep], d_[keep], z_[keep]))
    fo_r = np.array([o[0] for o in free_obs], int)
    fo_f = np.array([o[1] for o in free_obs], int)
    fo_m = np.array([o[2] for o in free_obs]).reshape(-1, 2)
    fixed_h = np.array([heights[r] if heights[r] is not None else 0.0 for r in names])

    def unpack(x):
        P = x[:3 * nr].reshape(nr, 3)
        H = np.where(est_h, x[3 * nr:4 * nr], fixed_h)
        F = x[4 * nr:].reshape(-1, 2)
        return P, H, F

    def pred_radar(P, H, k, pg_xy, pz):
        inv = Pose2(P[k, 0], P[k, 1:]).inverse()
        q = inv.apply(pg_xy)
        return slant_predict(q, pz - H[k]) if slant else q

    def resid(x):
        P, H, F = unpack(x)
        out = []
        for k, s_, d_, z_ in anchored:  # loop over radars
            out.append((pred_radar(P, H, k, s_, z_) - d_).ravel())
        for k in range(nr):
            sel = fo_r == k
            if sel.any():
                out.append((pred_radar(P, H, k, F[fo_f[sel]], np.full(sel.sum(), z_nominal)) - fo_m[sel]).ravel())
        return np.concatenate(out)

    free_mask = np.ones(len(x0), bool)
    free_mask[3 * nr:4 * nr] = est_h
    def resid_free(xf):
        x = x0.copy()
        x[free_mask] = xf
        return resid(x)

    sol = least_squares(resid_free, x0[free_mask], method="trf", x_scale="jac", ftol=1e-12, xtol=1e-12, gtol=1e-12)
    x = x0.copy()
    x[free_mask] = sol.x
    P, H, F = unpack(x)
    new_pose = {r: Pose2(float(_wrap(P[k, 0])), P[k, 1:].copy()) for k, r in enumerate(names)}
    new_h = {r: (float(H[k]) if (slant or heights[r] is not None) else None) for k, r in enumerate(names)}
    for r in heights:
        if r not in new_h:
            new_h[r] = heights[r]
    rr = resid(x)
    return new_pose, new_h, {"enabled": True, "free_points": len(free_init), "n_obs": int(len(rr) // 2), "rms": float(np.sqrt(np.mean(rr.reshape(-1, 2) ** 2) * 2)) if len(rr) else 0.0}


def build_scene_obs(name: str, main_points: np.ndarray, radar_xy: dict, range_gate: float = 4.0, ground_tol: float = 0.05, cluster_tol: float = 0.12,
                    head_size: float = 0.35, offset: float = 0.0, aggregate: bool = True, aggregate_gate: float = 0.3) -> tuple[SceneObs, ReflectorExtraction, dict]:
    """One placement's observations from raw arrays: reflector extraction on the main LiDAR cloud and, when a radar
    reported several frames, averaging of its repeated detections (:func:`aggregate_frames`). Returns the
    :class:`SceneObs`, the extraction details and per-radar frame counts."""
    ext = extract_reflectors(main_points, range_gate=range_gate, ground_tol=ground_tol, cluster_tol=cluster_tol, head_size=head_size, offset=offset)
    out, counts = {}, {}
    for r, xy in radar_xy.items():
        xy = np.asarray(xy, float).reshape(-1, 2)
        if aggregate and len(xy):
            means, c = aggregate_frames(xy, gate=aggregate_gate)
            if c.max() > 1:
                out[r], counts[r] = means, c
                continue
        out[r], counts[r] = xy, np.ones(len(xy), int)
    raw = {r: np.asarray(xy, float).reshape(-1, 2) for r, xy in radar_xy.items()}
    return SceneObs(name, ext.centres, out, ext.ground, raw), ext, counts
