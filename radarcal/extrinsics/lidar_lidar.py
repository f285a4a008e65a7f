"""LiDAR <-> LiDAR registration from an initial guess (open3d GICP or point-to-plane ICP, coarse to fine).

Patent step 6: every other LiDAR is registered to the main one. ``open3d`` is imported inside the function (about
1 s). Fitness (fraction of source points with a target point within ``eval_distance``) and inlier RMSE are reported
for the initial guess and for the result at the same ``eval_distance`` so the two are comparable.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radarcal import geometry

__all__ = ["LidarRegistration", "register_lidar", "overlap_metrics", "ground_prealign"]


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


def ground_prealign(source: np.ndarray, target: np.ndarray, T_init: np.ndarray, max_tilt_deg: float = 60.0, tol: float = 0.1) -> tuple[np.ndarray, dict]:
    """Correct the initial guess's roll/pitch and height with the ground: fit the ground plane in both clouds (the
    source's searched around the target's up direction mapped through ``T_init``), rotate the source minimally so the
    two normals agree and shift it along the normal so the planes coincide (CROON's rough step). Yaw and the in-plane
    translation are kept from ``T_init``."""
    from radarcal.extrinsics.radar_lidar import fit_ground_plane

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
    return LidarRegistration(T, method, f1, r1, f0, r0, eval_distance, stages, dR, dt, pre)
