"""LiDAR <-> LiDAR registration from an initial guess (open3d GICP or point-to-plane ICP, coarse to fine).

Patent step 6: every other LiDAR is registered to the main one. ``open3d`` is imported inside the function (about
1 s). Fitness (fraction of source points with a target point within ``eval_distance``) and inlier RMSE are reported
for the initial guess and for the result at the same ``eval_distance`` so the two are comparable.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radarcal import geometry
from radarcal.extrinsics.radar.matching import mutual_nn

__all__ = ["LidarRegistration", "ground_prealign", "overlap_metrics", "register_lidar"]


@dataclass
class LidarRegistration:
    T_target_source: np.ndarray  # 4x4: source LiDAR -> target (main) LiDAR
    method: str
    fitness: float  # at eval_distance, after
    inlier_rmse: float
    initial_fitness: float  # at eval_distance, from the initial guess
    initial_rmse: float
    eval_distance: float
    stages: list = field(default_factory=list)  # per scale: voxel, max_corr, fitness, rmse
    correction_deg: float = 0.0  # rotation between the initial guess and the result
    correction_m: float = 0.0
    prealign: dict | None = None  # ground-plane pre-alignment (tilt fixed, m shifted), when used
    T_start: np.ndarray | None = None  # the guess after the ground pre-alignment (what the registration started from)


def ground_prealign(source: np.ndarray, target: np.ndarray, T_init: np.ndarray, max_tilt_deg: float = 60.0, tol: float = 0.1) -> tuple[np.ndarray, dict]:
    """Correct the initial guess's roll/pitch and height with the ground: fit the ground plane in both clouds (the
    source's searched around the target's up direction mapped through ``T_init``), rotate the source minimally so the
    two normals agree and shift it along the normal so the planes coincide (CROON's rough step). Yaw and the in-plane
    translation are kept from ``T_init``."""
    from radarcal.extrinsics.radar.reflectors import fit_ground_plane

    T_init = np.asarray(T_init, float)
    gt = fit_ground_plane(target, tol=tol, iterations=1000)
    up_src = T_init[:3, :3].T @ gt.normal
    gs = fit_ground_plane(source, tol=tol, iterations=1000, up_hint=up_src, max_tilt=np.radians(max_tilt_deg))
    n_now = T_init[:3, :3] @ gs.normal  # source ground normal in the target frame under T_init
    axis = np.cross(n_now, gt.normal)
    ang = float(np.arctan2(np.linalg.norm(axis), n_now @ gt.normal))
    R_fix = geometry.rotvec_to_R(axis / np.linalg.norm(axis) * ang) if np.linalg.norm(axis) > 1e-12 else np.eye(3)
    T = geometry.make_T(R_fix, np.zeros(3)) @ T_init
    # a point on the source ground plane, mapped: its height above the target plane must be 0
    p0 = -gs.d * gs.normal
    h = float(gt.height(geometry.transform_points(T, p0[None]))[0])
    T[:3, 3] -= h * gt.normal
    return T, {"tilt_fixed_deg": float(np.degrees(ang)), "height_shift_m": -h, "target_ground_rms_m": gt.rms, "source_ground_rms_m": gs.rms}


def overlap_metrics(source: np.ndarray, target: np.ndarray, T_target_source: np.ndarray, distance: float) -> tuple[float, float]:
    """(fitness, inlier RMSE): share of transformed source points with a target neighbour within ``distance`` and
    the RMS distance of those (scipy KD-tree, no open3d)."""
    from scipy.spatial import cKDTree

    src = geometry.transform_points(T_target_source, np.asarray(source, float).reshape(-1, 3))
    d, _ = cKDTree(np.asarray(target, float).reshape(-1, 3)).query(src, distance_upper_bound=distance)
    ok = np.isfinite(d)
    if not ok.any():
        return 0.0, float("nan")
    return float(ok.mean()), float(np.sqrt(np.mean(d[ok] ** 2)))


def register_lidar(
    source: np.ndarray,
    target: np.ndarray,
    T_init: np.ndarray,
    method: str = "gicp",
    voxel: float = 0.1,
    scales: tuple = (4.0, 2.0, 1.0),
    max_iterations: int = 60,
    eval_distance: float = 0.3,
    max_range: float | None = 60.0,
    prealign: bool = True,
) -> LidarRegistration:
    """Refine ``T_target_source`` from ``T_init``: voxel-downsample both clouds, then GICP (``method="gicp"``) or
    point-to-plane ICP (``"point_to_plane"``) at voxel sizes ``voxel * scales`` with correspondence distance
    ``2.5 x`` the voxel size. With ``prealign`` the guess's tilt and height are first fixed from the ground planes
    (:func:`ground_prealign`; skipped when either cloud has no ground)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    src = np.asarray(source, float).reshape(-1, 3)
    tgt = np.asarray(target, float).reshape(-1, 3)
    if max_range:
        src = src[np.linalg.norm(src, axis=1) < max_range]
        tgt = tgt[np.linalg.norm(tgt, axis=1) < max_range]
    if len(src) < 10 or len(tgt) < 10:
        raise ValueError("too few points to register")
    f0, r0 = overlap_metrics(src, tgt, T_init, eval_distance)

    def pcd(p):
        c = o3d.geometry.PointCloud()
        c.points = o3d.utility.Vector3dVector(p)
        return c

    ps, pt = pcd(src), pcd(tgt)
    T = np.asarray(T_init, float).copy()
    pre = None
    if prealign:
        try:
            T, pre = ground_prealign(src, tgt, T)
            pre["fitness"], pre["rmse_m"] = overlap_metrics(src, tgt, T, eval_distance)
        except ValueError:
            pre = None
    stages = []
    T_start = T.copy()
    for s in scales:
        v = voxel * s
        a, b = ps.voxel_down_sample(v), pt.voxel_down_sample(v)
        knn = o3d.geometry.KDTreeSearchParamHybrid(radius=3 * v, max_nn=30)
        a.estimate_normals(knn)
        b.estimate_normals(knn)
        crit = reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=max_iterations)
        if method == "gicp":
            res = reg.registration_generalized_icp(a, b, 2.5 * v, T, reg.TransformationEstimationForGeneralizedICP(), crit)
        elif method == "point_to_plane":
            res = reg.registration_icp(a, b, 2.5 * v, T, reg.TransformationEstimationPointToPlane(), crit)
        else:
            raise ValueError(f"unknown method {method!r} (gicp, point_to_plane)")
        T = np.asarray(res.transformation, float).copy()
        stages.append({"voxel_m": v, "max_corr_m": 2.5 * v, "fitness": float(res.fitness), "rmse_m": float(res.inlier_rmse)})
    f1, r1 = overlap_metrics(src, tgt, T, eval_distance)
    dR, dt = geometry.pose_error(T, T_init)
    return LidarRegistration(T, method, f1, r1, f0, r0, eval_distance, stages, dR, dt, pre, T_start)


def _voxel_first(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point per occupied voxel (the first), numpy only."""
    if len(points) == 0:
        return points
    key = np.floor(points / voxel).astype(np.int64)
    _, idx = np.unique(key, axis=0, return_index=True)
    return points[np.sort(idx)]


def _normals(points: np.ndarray, tree, k: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (smallest covariance eigenvector of the ``k`` nearest neighbours) and planarity in [0, 1] (0 where
    the neighbourhood is thick: a corner between two planes gives a normal that neither has)."""
    _, nb = tree.query(points, k=min(k, len(tree.data)))
    Q = tree.data[nb] - tree.data[nb].mean(axis=1, keepdims=True)
    C = np.einsum("nki,nkj->nij", Q, Q)
    ev, vec = np.linalg.eigh(C)
    planar = (ev[:, 1] - ev[:, 0]) / np.maximum(ev[:, 2], 1e-18)
    planar = np.where(ev[:, 0] < 0.05 * ev[:, 1], planar, 0.0)  # thick neighbourhoods (corners, edges) tilt the normal
    return vec[:, :, 0], planar


@dataclass
class LidarRefinement:
    """Point-to-plane + reflector-point Gauss-Newton refinement of ``T_target_source`` and what it observes."""

    T_target_source: np.ndarray
    cov: np.ndarray  # (6,6) of the left perturbation (rotation about the source origin, rad; translation, m) in the target frame
    sigma_rot_deg: np.ndarray  # (3,) marginal 1-sigma about the target's x, y, z
    sigma_trans_m: np.ndarray  # (3,) along the target's x, y, z
    worst_rot: tuple  # (1-sigma deg, unit axis in the target frame)
    worst_trans: tuple  # (1-sigma m, unit direction in the target frame)
    n_plane: int  # point-to-plane correspondences used
    n_reflectors: int  # reflector pairs used
    plane_rms_m: float
    reflector_rms_m: float
    reflector_pairs: list = field(default_factory=list)  # [(scene index, source index, target index, residual m)]


def refine_with_reflectors(source: np.ndarray, target: np.ndarray, T_init: np.ndarray, src_reflectors: list | None = None, tgt_reflectors: list | None = None,
                           voxel: float = 0.2, max_corr: float = 0.3, reflector_gate: float = 0.3, reflector_sigma: float = 0.01, iterations: int = 15,
                           plane_sigma_floor: float = 0.01) -> LidarRefinement:
    """Refine ``T_target_source`` with point-to-plane residuals (source voxel points against the target's local
    planes, Huber-weighted) and, beside the geometry, the corner reflectors both LiDARs see as 3D point
    constraints (``src_reflectors`` / ``tgt_reflectors``: per scene (K,3) apexes in each LiDAR's frame, matched as
    mutual nearest neighbours within ``reflector_gate`` under the current estimate). Open ground and one wall leave
    a direction unconstrained; the reflectors fix it. The covariance is the inverse information matrix scaled by the
    residual variances (plane residuals at their robust RMS but at least ``plane_sigma_floor``: neighbouring
    correspondences are not independent and two samplings of a surface differ by more than the range noise;
    reflectors at ``reflector_sigma`` or their RMS if larger), from which the worst-observed rotation axis and translation direction are reported.
    Each Gauss-Newton pass: :func:`_plane_information`, :func:`_reflector_pairs`, :func:`_add_reflector_information`,
    :func:`_step`."""
    from scipy.spatial import cKDTree

    src = _voxel_first(np.asarray(source, float).reshape(-1, 3), voxel)
    tgt_all = np.asarray(target, float).reshape(-1, 3)
    tgt = _voxel_first(tgt_all, voxel / 2)
    tree = cKDTree(tgt)
    tgt_normals, tgt_planar = _normals(tgt, tree)  # the target's local planes, once
    T = np.asarray(T_init, float).copy()
    pairs_out = []
    s_plane = max_corr / 3
    final = False  # the last pass only evaluates the information at the solution (reflectors at their own RMS)
    for _it in range(iterations + 1):  # Gauss-Newton (few iterations), each vectorised over the points
        final = final or _it == iterations
        H, g, s_plane, n_plane = _plane_information(T, src, tgt, tree, tgt_normals, tgt_planar, max_corr, s_plane, plane_sigma_floor)
        rp = _reflector_pairs(T, src_reflectors, tgt_reflectors, reflector_gate)
        if rp:
            _add_reflector_information(H, g, T, rp, reflector_sigma, final)
        if final:
            break
        try:
            delta = -np.linalg.solve(H + 1e-9 * np.eye(6) * max(np.trace(H), 1.0), g)
        except np.linalg.LinAlgError:
            break
        T = _step(T, delta)
        if np.linalg.norm(delta[:3]) < 1e-7 and np.linalg.norm(delta[3:]) < 1e-6:
            final = True
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        cov = np.full((6, 6), np.inf)
    rp = _reflector_pairs(T, src_reflectors, tgt_reflectors, reflector_gate)
    if rp:
        e = np.linalg.norm(geometry.transform_points(T, np.array([x[3] for x in rp])) - np.array([x[4] for x in rp]), axis=1)
        pairs_out = [(x[0], x[1], x[2], float(ei)) for x, ei in zip(rp, e)]
    ref_rms = float(np.sqrt(np.mean([p[3] ** 2 for p in pairs_out]))) if pairs_out else float("nan")
    sr, st = _worst_direction(cov[:3, :3]), _worst_direction(cov[3:, 3:])
    return LidarRefinement(T, cov, np.degrees(np.sqrt(np.maximum(np.diag(cov)[:3], 0))), np.sqrt(np.maximum(np.diag(cov)[3:], 0)),
                           (float(np.degrees(sr[0])), sr[1]), st, n_plane, len(rp), float(s_plane), ref_rms, pairs_out)


def _reflector_pairs(T, src_reflectors, tgt_reflectors, gate) -> list:
    """Mutual nearest-neighbour reflector pairs within ``gate`` under ``T`` (source -> target), per scene:
    (scene, source index, target index, source apex, target apex)."""
    out = []
    if not src_reflectors or not tgt_reflectors:
        return out
    for si, (a, b) in enumerate(zip(src_reflectors, tgt_reflectors)):
        a = np.asarray(a, float).reshape(-1, 3)
        b = np.asarray(b, float).reshape(-1, 3)
        if len(a) == 0 or len(b) == 0:
            continue
        out += [(si, int(i), int(j), a[i], b[j]) for i, j in mutual_nn(geometry.transform_points(T, a), b, gate)]
    return out


def _plane_information(T, src, tgt, tree, tgt_normals, tgt_planar, max_corr, s_plane, plane_sigma_floor):
    """Point-to-plane normal equations under ``T``: source points against their target neighbour's local plane
    (planar ones within ``max_corr``), Huber-weighted at the robust RMS (at least ``plane_sigma_floor``; the previous
    ``s_plane`` when nothing matches). Parameters: rotation about the current translation, then translation.
    Returns (H (6,6), g (6,), s_plane, residual count)."""
    c = T[:3, 3]
    ps = geometry.transform_points(T, src)
    dist, nb = tree.query(ps, distance_upper_bound=max_corr)
    ok = np.isfinite(dist)
    idx = nb[ok]
    n, planar = tgt_normals[idx], tgt_planar[idx]
    good = planar > 0.3
    p_ok, q_ok, n = ps[ok][good], tgt[idx[good]], n[good]
    r = np.sum(n * (p_ok - q_ok), axis=1)
    s_plane = max(1.4826 * float(np.median(np.abs(r))), plane_sigma_floor) if len(r) else s_plane
    w = np.minimum(1.0, 2.0 * s_plane / np.maximum(np.abs(r), 1e-12))  # Huber
    J = np.concatenate([np.cross(p_ok - c, n), n], axis=1)
    H = (J * (w / s_plane**2)[:, None]).T @ J
    g = (J * (w * r / s_plane**2)[:, None]).sum(axis=0)
    return H, g, s_plane, len(r)


def _add_reflector_information(H, g, T, rp, reflector_sigma, final) -> None:
    """Add the reflector pairs' point constraints to ``H`` / ``g`` in place, at ``reflector_sigma`` (on the final
    pass with more than two pairs: their RMS if larger)."""
    c = T[:3, 3]
    A = np.array([x[3] for x in rp])
    B = np.array([x[4] for x in rp])
    pa = geometry.transform_points(T, A)
    e = pa - B
    s_ref = max(reflector_sigma, float(np.sqrt(np.mean(e**2)))) if final and len(rp) > 2 else reflector_sigma
    for k in range(len(rp)):  # few reflectors
        Jr = np.concatenate([-_skew(pa[k] - c), np.eye(3)], axis=1)
        H += Jr.T @ Jr / s_ref**2
        g += Jr.T @ e[k] / s_ref**2


def _step(T, delta) -> np.ndarray:
    """``T`` updated by ``delta`` (rotation vector about T's translation, then translation)."""
    c = T[:3, 3]
    dR = geometry.rotvec_to_R(delta[:3])
    T_new = np.eye(4)
    T_new[:3, :3] = dR @ T[:3, :3]
    T_new[:3, 3] = dR @ (T[:3, 3] - c) + c + delta[3:]
    return T_new


def _worst_direction(block):
    """Largest 1-sigma of a 3x3 covariance block and its axis (sign fixed: largest component positive)."""
    ev, vec = np.linalg.eigh(block)
    return float(np.sqrt(max(ev[-1], 0.0))), vec[:, -1] * np.sign(vec[np.argmax(np.abs(vec[:, -1])), -1])


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def axis_name(v: np.ndarray, frame: str) -> str:
    """``"y of lidar_front"`` for a direction within 10 deg of an axis, else the vector."""
    v = np.asarray(v, float) / np.linalg.norm(v)
    k = int(np.argmax(np.abs(v)))
    if abs(v[k]) > np.cos(np.radians(10)):
        return f"{'xyz'[k]} of {frame}"
    return f"({v[0]:.2f}, {v[1]:.2f}, {v[2]:.2f}) in {frame}"
