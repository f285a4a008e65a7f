"""Stereo extrinsics ``T_cam1_cam0`` from synchronised board views, intrinsics held fixed.

Pure numeric core. Unknowns: T_cam1_cam0 (rotation vector + translation) and the board pose in cam0 for every pair;
residuals: the corners of both images, projected with radarcal's :class:`~radarcal.camera.Camera` (any model,
fisheye included, so no OpenCV ``stereoCalibrate`` API differences). Solved with scipy's Levenberg-Marquardt-type
``least_squares`` from a PnP start (median of per-pair relative poses); σ of the 6 parameters and of the baseline
from the Jacobian scaled by the residual noise. Corner pairs whose residual exceeds ``k_sigma`` σ are dropped once
and the problem re-solved.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.spatial.transform import Rotation

from radarcal import geometry
from radarcal.camera import Camera

__all__ = ["StereoResult", "stereo_calibrate", "pair_by_name"]


@dataclass
class StereoResult:
    T_cam1_cam0: np.ndarray  # maps points in cam0 into cam1
    baseline_m: float
    rms_px: float  # over both cameras' inlier corners
    noise_px: float
    sigma: dict[str, float]  # rx ry rz (rad), tx ty tz (m), baseline_m
    rvecs_cam0: np.ndarray  # (P,3) board -> cam0 per pair
    tvecs_cam0: np.ndarray
    residuals0: list[np.ndarray]
    residuals1: list[np.ndarray]
    inliers: list[np.ndarray]
    n_pairs: int


def pair_by_name(names0: list[str], names1: list[str]) -> list[tuple[int, int]]:
    """Pair files by the digits in their names (left07 <-> right07); by order if that is ambiguous."""
    import re

    def key(n):
        d = re.findall(r"\d+", n.rsplit("/", 1)[-1])
        return d[-1].lstrip("0") or "0" if d else None

    k0 = [key(n) for n in names0]
    k1 = [key(n) for n in names1]
    if None not in k0 and None not in k1 and len(set(k0)) == len(k0) and len(set(k1)) == len(k1):
        m1 = {k: j for j, k in enumerate(k1)}
        return [(i, m1[k]) for i, k in enumerate(k0) if k in m1]
    return [(i, i) for i in range(min(len(names0), len(names1)))]


def _pnp(cam: Camera, obj: np.ndarray, img: np.ndarray) -> np.ndarray:
    rays = cam.unproject(img)
    xy = rays[:, :2] / rays[:, 2:3]
    ok, rv, tv = cv2.solvePnP(obj.astype(float), xy.astype(float), np.eye(3), None, flags=cv2.SOLVEPNP_ITERATIVE)
    return geometry.T_from_rotvec(rv.ravel(), tv.ravel())


def stereo_calibrate(cam0: Camera, cam1: Camera, object_points: list[np.ndarray], image_points0: list[np.ndarray], image_points1: list[np.ndarray], k_sigma: float = 4.0) -> StereoResult:
    """Solve T_cam1_cam0. object_points[p] (N_p,3) are seen as image_points0[p] in cam0 and image_points1[p] in cam1."""
    n = len(object_points)
    if n < 1:
        raise ValueError("stereo needs at least one synchronised pair with the board in both images")
    obj = [np.asarray(o, float).reshape(-1, 3) for o in object_points]
    q0 = [np.asarray(q, float).reshape(-1, 2) for q in image_points0]
    q1 = [np.asarray(q, float).reshape(-1, 2) for q in image_points1]
    T0 = [_pnp(cam0, o, a) for o, a in zip(obj, q0)]
    T1 = [_pnp(cam1, o, b) for o, b in zip(obj, q1)]
    rel = np.array([geometry.T_to_rotvec(t1 @ geometry.invert_T(t0)) for t0, t1 in zip(T0, T1)])
    x_rel = np.median(rel, axis=0)
    x0 = np.concatenate([x_rel] + [geometry.T_to_rotvec(t) for t in T0])
    inl = [np.ones(len(o), bool) for o in obj]

    def unpack(x):
        return x[:6], x[6:].reshape(n, 6)

    def solve(x0, inl):
        o = np.concatenate([obj[p][inl[p]] for p in range(n)])
        a = np.concatenate([q0[p][inl[p]] for p in range(n)])
        b = np.concatenate([q1[p][inl[p]] for p in range(n)])
        vid = np.repeat(np.arange(n), [int(m.sum()) for m in inl])

        def fun(x):
            rel6, poses = unpack(x)
            R0 = Rotation.from_rotvec(poses[:, :3]).as_matrix()
            p0 = np.einsum("nij,nj->ni", R0[vid], o) + poses[vid, 3:]
            Rr = Rotation.from_rotvec(rel6[:3]).as_matrix()
            p1 = p0 @ Rr.T + rel6[3:]
            u0, _ = cam0.project(p0)
            u1, _ = cam1.project(p1)
            r = np.concatenate([(a - u0).ravel(), (b - u1).ravel()])
            return np.nan_to_num(r, nan=1e3)

        m = len(o)
        rows = np.concatenate([2 * np.arange(m), 2 * np.arange(m) + 1, 2 * m + 2 * np.arange(m), 2 * m + 2 * np.arange(m) + 1])
        pt = np.tile(np.arange(m), 4)
        rr_ = np.repeat(rows, 6)
        cc_ = (6 + 6 * vid[pt])[:, None] + np.arange(6)[None, :]
        r_all = np.concatenate([rr_, np.repeat(np.arange(4 * m), 6)])
        c_all = np.concatenate([cc_.ravel(), np.tile(np.arange(6), 4 * m)])
        S = coo_matrix((np.ones(len(r_all), int), (r_all, c_all)), shape=(4 * m, 6 + 6 * n))
        sol = least_squares(fun, x0, jac_sparsity=S, method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
        return sol, fun, vid

    sol, fun, vid = solve(x0, inl)
    # one round of corner-pair rejection
    r = fun(sol.x)
    m = len(vid)
    ra = r[: 2 * m].reshape(-1, 2)
    rb = r[2 * m :].reshape(-1, 2)
    nrm = np.maximum(np.linalg.norm(ra, axis=1), np.linalg.norm(rb, axis=1))
    sigma = np.sqrt(np.median(np.sum(np.concatenate([ra, rb]) ** 2, axis=1)) / (2 * np.log(2)))
    bad = nrm > k_sigma * max(sigma, 1e-3)
    if bad.any():
        flat = np.concatenate([np.flatnonzero(mk) for mk in inl])
        starts = np.cumsum([0] + [int(mk.sum()) for mk in inl])
        inl = [mk.copy() for mk in inl]
        for p in range(n):
            inl[p][flat[starts[p] : starts[p + 1]][bad[starts[p] : starts[p + 1]]]] = False
        sol, fun, vid = solve(sol.x, inl)
    r = fun(sol.x)
    J = sol.jac.toarray() if hasattr(sol.jac, "toarray") else np.asarray(sol.jac)
    dof = max(r.size - J.shape[1], 1)
    noise = float(np.sqrt(np.sum(r**2) / dof))
    JtJ = J.T @ J
    d = np.sqrt(np.maximum(np.diag(JtJ), 1e-30))
    cov = noise**2 * np.linalg.pinv(JtJ / d[:, None] / d[None, :]) / d[:, None] / d[None, :]
    rel6, poses = unpack(sol.x)
    T = geometry.T_from_rotvec(rel6[:3], rel6[3:])
    t = rel6[3:]
    base = float(np.linalg.norm(t))
    g = t / max(base, 1e-12)
    names = ["rx", "ry", "rz", "tx", "ty", "tz"]
    sig = {nm: float(np.sqrt(max(cov[i, i], 0))) for i, nm in enumerate(names)}
    sig["baseline_m"] = float(np.sqrt(max(g @ cov[3:6, 3:6] @ g, 0)))
    # residuals for all corners (inliers and not)
    res0, res1 = [], []
    Rr = Rotation.from_rotvec(rel6[:3]).as_matrix()
    for p in range(n):
        Tp = geometry.T_from_rotvec(poses[p, :3], poses[p, 3:])
        u0, _, _ = cam0.project_from(Tp, obj[p])
        pc = geometry.transform_points(Tp, obj[p]) @ Rr.T + t
        u1, _ = cam1.project(pc)
        res0.append(q0[p] - u0)
        res1.append(q1[p] - u1)
    m = len(vid)
    rr = r.reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum(rr**2, axis=1))))
    return StereoResult(T, base, rms, noise, sig, poses[:, :3].copy(), poses[:, 3:].copy(), res0, res1, inl, n)
