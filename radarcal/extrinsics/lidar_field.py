"""LiDAR-to-field registration (``radarcal lidar-field``): ``T_field_lidar`` from an accumulated cloud and the
field mesh. Pure numeric core: arrays in, arrays out (the mesh is queried through a :class:`MeshTarget`).

Method
- Robust point-to-plane Gauss-Newton against the mesh triangles (closest point + triangle normal), coarse to
  fine: correspondence gates 1.0 → 0.5 → 0.25 → 0.12 → 0.06 m with a Geman-McClure weight of scale gate / 2;
  points beyond the gate are rejected (robots, people, the venue are not in the mesh).
- Restarts against local minima: from the converged pose, ±2.5° of yaw, ±0.4 m along x and y and ±1° of pitch
  and roll are tried again; the pose with the most points within 3 cm of the mesh wins.
- ``--side`` only: the floor plane (RANSAC) gives roll, pitch and height; a grid over x, y, yaw behind that end
  of the field is scored on a distance field of the mesh with the points that are not floor, and the best distinct
  candidates are refined as above.
- σ of the six parameters: the larger of the Gauss-Newton covariance and a jackknife over 12 azimuth sectors of
  the cloud (model errors are spatially correlated; the jackknife sees them, the formal σ does not).
- Degeneracy: eigen-directions of the normal matrix whose σ exceeds the thresholds are named (x, y, yaw, ...).
- Verdict: ``converged`` only when the fit explains the cloud (inlier share, residual), σ is small, nothing is
  weak and no distinct restart explains it nearly as well; otherwise ``ambiguous``, ``degenerate`` or ``failed``
  with the reason.

Frames: points in the LiDAR frame; ``T_field_lidar`` maps them into the field frame (metres, radians inside).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from radarcal import geometry
from radarcal.registration import point_to_plane_rows, robust_point_to_plane

__all__ = ["MeshTarget", "LidarFieldOptions", "LidarFieldResult", "register_lidar_field", "floor_plane", "side_search", "PARAMS"]

PARAMS = ("x", "y", "z", "roll", "pitch", "yaw")


class MeshTarget:
    """Closest-point queries against a triangle mesh (open3d ``RaycastingScene``, built once) and a coarse
    distance field for the global search. ``mesh``: :class:`radarcal.io.meshes.TriangleMesh` in the field frame."""

    def __init__(self, mesh, distance_voxel: float = 0.1):
        from radarcal.field import _o3d_scene

        self.mesh = mesh
        self.scene = _o3d_scene(mesh)
        self.normals = mesh.normals()
        self.distance_voxel = distance_voxel
        self._dfield = None

    def closest(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,3) -> closest points on the mesh (N,3), unit normals there (N,3)."""
        import open3d as o3d

        r = self.scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(p, np.float32)))
        q = r["points"].numpy().astype(float)
        n = self.normals[r["primitive_ids"].numpy().astype(np.int64)]
        return q, n

    def distance_field(self):
        """Unsigned distance to the mesh on a ``distance_voxel`` grid (truncated at 2 m), for cheap scoring."""
        if self._dfield is None:
            from scipy.ndimage import distance_transform_edt

            v = self.distance_voxel
            pts = self.mesh.sample_surface(v / 2)
            lo = pts.min(0) - 2.0
            shape = np.ceil((pts.max(0) + 2.0 - lo) / v).astype(np.int64) + 1
            occ = np.zeros(shape, bool)
            idx = np.floor((pts - lo) / v).astype(np.int64)
            occ[idx[:, 0], idx[:, 1], idx[:, 2]] = True
            d = distance_transform_edt(~occ, sampling=v).astype(np.float32)
            self._dfield = (lo, v, np.minimum(d, 2.0))
        return self._dfield

    def distance_lookup(self, p: np.ndarray) -> np.ndarray:
        lo, v, d = self.distance_field()
        idx = np.floor((p - lo) / v).astype(np.int64)
        ok = np.all((idx >= 0) & (idx < np.array(d.shape)), axis=-1)
        out = np.full(p.shape[:-1], 2.0, np.float32)
        ii = idx[ok]
        out[ok] = d[ii[:, 0], ii[:, 1], ii[:, 2]]
        return out


@dataclass
class LidarFieldOptions:
    gates_m: tuple[float, ...] = (1.0, 0.5, 0.25, 0.12, 0.06)
    iterations_per_gate: int = 6
    max_points: int = 12_000              # points used per iteration (a fixed random subset of the cloud)
    restart_points: int = 6_000           # points used to refine each restart (coarse gates only)
    polish_points: int = 48_000           # points of the final refinement and of σ
    inlier_m: float = 0.03                # "explained" = within this of the mesh
    restarts: bool = True
    restart_yaw_deg: float = 2.5
    restart_xy_m: float = 0.4
    restart_tilt_deg: float = 1.0
    jackknife_sectors: int = 12
    max_sigma_deg: float = 0.05           # converged only below these
    max_sigma_m: float = 0.02
    min_inlier_share: float = 0.15        # of the points within 0.5 m of the mesh at the start pose... see verdict
    min_inliers: int = 2000
    ambiguity_ratio: float = 0.97         # a distinct restart with >= this share of the best inliers -> ambiguous
    distinct_deg: float = 0.3
    distinct_m: float = 0.1
    seed: int = 0


@dataclass
class LidarFieldResult:
    T_field_lidar: np.ndarray
    verdict: str                          # converged | ambiguous | degenerate | failed
    reasons: list[str]
    rms_m: float                          # RMS point-to-plane residual of the inliers
    inliers: int
    inlier_share: float                   # of the points the mesh could explain (within 0.5 m at the solution)
    sigma: dict[str, float]               # x, y, z (m), roll, pitch, yaw (deg)
    sigma_formal: dict[str, float]
    weak_directions: list[str]
    cov: np.ndarray                       # 6x6 (rotvec rad, translation m), left perturbation in the field frame
    n_points: int
    candidates: list[dict] = field(default_factory=list)
    seconds: float = 0.0

    def summary(self) -> dict:
        xyz_rpy = geometry.T_to_xyz_rpy_deg(self.T_field_lidar)
        return {"verdict": self.verdict, "reasons": self.reasons, "rms_m": round(self.rms_m, 4), "inliers": self.inliers,
                "inlier_share": round(self.inlier_share, 4), "sigma": {k: round(v, 5) for k, v in self.sigma.items()},
                "sigma_formal": {k: round(v, 5) for k, v in self.sigma_formal.items()}, "weak_directions": self.weak_directions,
                "xyz_rpy_deg": [round(float(v), 5) for v in xyz_rpy], "n_points": self.n_points, "seconds": round(self.seconds, 2),
                "candidates": self.candidates}


def _gn(points: np.ndarray, T: np.ndarray, target: MeshTarget, gates, iters: int) -> np.ndarray:
    """Robust coarse-to-fine point-to-plane Gauss-Newton (the shared core, :func:`radarcal.registration.robust_point_to_plane`)."""
    return robust_point_to_plane(points, T, target, tuple(gates), iters)


def _score(points: np.ndarray, T: np.ndarray, target: MeshTarget, inlier_m: float) -> tuple[int, int]:
    p = points @ T[:3, :3].T + T[:3, 3]
    q, _ = target.closest(p)
    d = np.linalg.norm(p - q, axis=1)
    return int(np.sum(d < inlier_m)), int(np.sum(d < 0.5))


def _sigmas(points: np.ndarray, T: np.ndarray, target: MeshTarget, opt: LidarFieldOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int]:
    """Formal and jackknife covariances (6x6), the normal matrix, inlier RMS and count at the final gate."""
    p = points @ T[:3, :3].T + T[:3, 3]
    q, n = target.closest(p)
    d = np.linalg.norm(p - q, axis=1)
    gate = opt.gates_m[-1]
    m = d < gate
    if m.sum() < 3 * opt.jackknife_sectors:  # nothing to estimate from (the verdict will say "failed")
        big = np.eye(6) * 1e6
        return big, big, np.zeros((6, 6)), float("nan"), int(m.sum())
    r = np.sum((p[m] - q[m]) * n[m], axis=1)
    s = gate / 2
    w = (s * s / (s * s + r * r)) ** 2
    J = point_to_plane_rows(p[m], n[m])
    Jw = J * w[:, None]
    H = Jw.T @ J + 1e-12 * np.eye(6)
    g = Jw.T @ r
    dof = max(1, int(m.sum()) - 6)
    s2 = float(np.sum(w * r * r) / dof)
    Hinv = np.linalg.inv(H)
    cov_formal = s2 * Hinv
    # jackknife over azimuth sectors of the cloud (LiDAR frame)
    az = np.arctan2(points[m, 1], points[m, 0])
    K = opt.jackknife_sectors
    edges = np.quantile(az, np.linspace(0, 1, K + 1))
    sec = np.clip(np.searchsorted(edges, az, side="right") - 1, 0, K - 1)
    deltas = []
    for k in range(K):
        mk = sec == k
        Hk = H - Jw[mk].T @ J[mk]
        gk = g - Jw[mk].T @ r[mk]
        try:
            deltas.append(-np.linalg.solve(Hk, gk))
        except np.linalg.LinAlgError:
            continue
    D = np.array(deltas)
    cov_jk = (len(D) - 1) / len(D) * (D - D.mean(0)).T @ (D - D.mean(0)) if len(D) > 2 else cov_formal
    rms = float(np.sqrt(np.mean(r * r))) if len(r) else float("nan")
    return cov_formal, cov_jk, H, rms, int(m.sum())


def _param_sigma(cov: np.ndarray, T: np.ndarray) -> dict[str, float]:
    """σ of x, y, z (m) and roll, pitch, yaw (deg) from a left-perturbation covariance (rotvec, translation).

    The translation part of a left perturbation of T also moves t by ω × t; map (ω, v) -> (δt = v + ω × t, δrpy)."""
    t = T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, 3:] = np.eye(3)
    A[:3, :3] = -geometry_skew(t)
    # small rotation ω on the left: roll/pitch/yaw change by M ω (numerically)
    rpy0 = geometry.R_to_rpy_deg(T[:3, :3])
    eps = 1e-6
    for i in range(3):
        w = np.zeros(3)
        w[i] = eps
        rpy = geometry.R_to_rpy_deg(geometry.rotvec_to_R(w) @ T[:3, :3])
        A[3:, i] = (np.radians((rpy - rpy0 + 180) % 360 - 180)) / eps
    C = A @ cov @ A.T
    s = np.sqrt(np.clip(np.diag(C), 0, None))
    return {"x": float(s[0]), "y": float(s[1]), "z": float(s[2]), "roll": float(np.degrees(s[3])), "pitch": float(np.degrees(s[4])), "yaw": float(np.degrees(s[5]))}


def geometry_skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _weak_directions(cov: np.ndarray, T: np.ndarray, opt: LidarFieldOptions) -> list[str]:
    """Eigen-directions of the covariance whose σ exceeds the thresholds, named by their dominant parameters."""
    sig = _param_sigma(cov, T)
    weak = [k for k in PARAMS if sig[k] > (opt.max_sigma_m if k in ("x", "y", "z") else opt.max_sigma_deg)]
    return weak


def _distinct(Ta: np.ndarray, Tb: np.ndarray, opt: LidarFieldOptions) -> bool:
    deg, m = geometry.pose_error(Ta, Tb)
    return deg > opt.distinct_deg or m > opt.distinct_m


def _restart_poses(T: np.ndarray, opt: LidarFieldOptions) -> list[np.ndarray]:
    out = []
    c = T[:3, 3]
    for yaw in (-opt.restart_yaw_deg, opt.restart_yaw_deg):
        R = geometry.rpy_deg_to_R(0, 0, yaw)
        out.append(geometry.make_T(R @ T[:3, :3], c))
    for dx, dy in ((opt.restart_xy_m, 0), (-opt.restart_xy_m, 0), (0, opt.restart_xy_m), (0, -opt.restart_xy_m)):
        Tn = T.copy()
        Tn[:3, 3] = c + [dx, dy, 0]
        out.append(Tn)
    for r, p in ((opt.restart_tilt_deg, 0), (0, opt.restart_tilt_deg), (0, -opt.restart_tilt_deg)):
        out.append(geometry.make_T(T[:3, :3] @ geometry.rpy_deg_to_R(r, p, 0), c))
    return out


def register_lidar_field(points_lidar: np.ndarray, target: MeshTarget, T_init: np.ndarray | list[np.ndarray], options: LidarFieldOptions | None = None) -> LidarFieldResult:
    """Register the cloud to the mesh from one start pose (or a list of them: each is refined, the best kept)."""
    t0 = time.perf_counter()
    opt = options or LidarFieldOptions()
    P = np.asarray(points_lidar, float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    n_all = len(P)
    rng = np.random.default_rng(opt.seed)
    sub = P[rng.choice(n_all, opt.max_points, replace=False)] if n_all > opt.max_points else P
    starts = [np.asarray(T_init, float)] if isinstance(T_init, np.ndarray) and np.asarray(T_init).ndim == 2 else [np.asarray(T, float) for T in T_init]
    cands = []
    if len(starts) > 2:  # many starts (a global search): coarse gates on a small subset first, refine the best two
        small = sub[: opt.restart_points]
        pre = []
        for T0 in starts:
            T1 = _gn(small, T0, target, tuple(g for g in opt.gates_m if g >= 0.2), 4)
            pre.append((T1, *_score(small, T1, target, opt.inlier_m)))
        pre.sort(key=lambda c: -c[1])
        cands.extend(pre[2:])
        starts = [c[0] for c in pre[:2]]
    for T0 in starts:
        T1 = _gn(sub, T0, target, opt.gates_m, opt.iterations_per_gate)
        cands.append((T1, *_score(sub, T1, target, opt.inlier_m)))
    hopeless = max(c[1] for c in cands) < min(opt.min_inliers, 0.02 * len(sub)) or max(c[2] for c in cands) < 0.05 * len(sub)
    if opt.restarts and not hopeless:  # (a cloud the mesh cannot explain at all is not worth restarting)
        small = sub[: opt.restart_points]
        coarse = tuple(g for g in opt.gates_m if g >= 0.1)[1:]
        for rnd in range(3):  # restart around the best; again while a restart finds a better, distinct pose
            best = max(cands, key=lambda c: c[1])[0]
            new = []
            for Tr in _restart_poses(best, opt):
                T1 = _gn(small, Tr, target, coarse, 4)
                new.append((T1, *_score(small, T1, target, opt.inlier_m)))
            new.sort(key=lambda c: -c[1])
            # refine the best two restarts fully, keep them all as (scored) candidates
            for T1, _, _ in new[:2]:
                T2 = _gn(sub, T1, target, opt.gates_m[-2:], opt.iterations_per_gate)
                cands.append((T2, *_score(sub, T2, target, opt.inlier_m)))
            b2 = max(cands, key=lambda c: c[1])[0]
            if not _distinct(b2, best, opt):
                break
    cands.sort(key=lambda c: -c[1])
    T_best, inl_best, near_best = cands[0]
    # polish on the whole cloud (up to 4x the subset) at the finest gates
    full = P if n_all <= opt.polish_points else P[rng.choice(n_all, opt.polish_points, replace=False)]
    T_best = _gn(full, T_best, target, opt.gates_m[-1:], 4)
    cov_f, cov_j, H, rms, n_in = _sigmas(full, T_best, target, opt)
    cov = np.where(np.trace(cov_j) > np.trace(cov_f), 1, 0) * cov_j + np.where(np.trace(cov_j) > np.trace(cov_f), 0, 1) * cov_f
    # per parameter: the larger of the two
    sig_f = _param_sigma(cov_f, T_best)
    sig_j = _param_sigma(cov_j, T_best)
    sig = {k: max(sig_f[k], sig_j[k]) for k in PARAMS}
    inl_full, near_full = _score(full, T_best, target, opt.inlier_m)
    share = inl_full / max(near_full, 1)
    reasons = []
    weak = [k for k in PARAMS if sig[k] > (opt.max_sigma_m if k in ("x", "y", "z") else opt.max_sigma_deg)]
    # competing minima: distinct candidates that explain nearly as many points
    rivals = [c for c in cands[1:] if _distinct(c[0], cands[0][0], opt) and c[1] >= opt.ambiguity_ratio * inl_best]
    verdict = "converged"
    if inl_full < opt.min_inliers or near_full < 0.05 * len(full):
        verdict = "failed"
        reasons.append(f"the mesh explains too little of the cloud: {inl_full} points within {opt.inlier_m * 100:.0f} cm, {near_full} of {len(full)} within 0.5 m")
    elif share < 0.5:
        verdict = "failed"
        reasons.append(f"only {share:.0%} of the points near the mesh lie within {opt.inlier_m * 100:.0f} cm of it (a wrong minimum or a different field)")
    elif rms > 0.6 * opt.gates_m[-1]:
        verdict = "failed"
        reasons.append(f"residual {rms * 100:.1f} cm RMS is too large for a correct fit")
    if verdict == "converged" and rivals:
        verdict = "ambiguous"
        deg, m = geometry.pose_error(rivals[0][0], cands[0][0])
        reasons.append(f"a distinct pose {deg:.2f} deg / {m * 100:.0f} cm away explains {rivals[0][1] / inl_best:.0%} as many points")
    if verdict == "converged" and weak:
        verdict = "degenerate"
        reasons.append("weakly observed: " + ", ".join(f"{k} (σ {sig[k]:.3f} {'m' if k in 'xyz' else 'deg'})" for k in weak))
    cand_out = []
    for T, inl, near in cands[:6]:
        deg, m = geometry.pose_error(T, T_best)
        cand_out.append({"inliers": inl, "near": near, "deg_from_best": round(deg, 4), "m_from_best": round(m, 4)})
    return LidarFieldResult(T_best, verdict, reasons, rms, n_in, share, sig, sig_f, weak, cov, n_all, cand_out, time.perf_counter() - t0)


# --- global search from the side ----------------------------------------------------------------------------
def floor_plane(points_lidar: np.ndarray, rng: np.random.Generator, iters: int = 300, tol: float = 0.05) -> tuple[np.ndarray, float, np.ndarray]:
    """RANSAC of the dominant horizontal-ish plane below the sensor: unit normal ``n`` (pointing up, LiDAR frame),
    offset ``h`` (the sensor's height above it), inlier mask. The LiDAR is assumed within 45° of upright."""
    P = np.asarray(points_lidar, float)
    sub = P[rng.choice(len(P), min(len(P), 20000), replace=False)]
    best, best_n, best_h = -1, np.array([0, 0, 1.0]), 0.0
    for _ in range(iters):
        a, b, c = sub[rng.choice(len(sub), 3, replace=False)]
        n = np.cross(b - a, c - a)
        ln = np.linalg.norm(n)
        if ln < 1e-9:
            continue
        n /= ln
        if n[2] < 0:
            n = -n
        if n[2] < np.cos(np.radians(45)):
            continue
        h = -float(n @ a)  # plane n·p + h = 0 -> the sensor (origin) is h above it
        if h <= 0.3:
            continue
        cnt = int(np.sum(np.abs(sub @ n + h) < tol))
        if cnt > best:
            best, best_n, best_h = cnt, n, h
    m = np.abs(P @ best_n + best_h) < tol
    # least squares refit on the inliers
    Q = P[m]
    c = Q.mean(0)
    _, _, Vt = np.linalg.svd(Q - c, full_matrices=False)
    n = Vt[-1] if Vt[-1][2] > 0 else -Vt[-1]
    h = -float(n @ c)
    m = np.abs(P @ n + h) < tol
    return n, h, m


def side_search(points_lidar: np.ndarray, target: MeshTarget, field_size: tuple[float, float], side: str, rng: np.random.Generator | None = None,
                behind_m: tuple[float, float] = (0.0, 4.0), height_m: tuple[float, float] = (2.0, 4.0), n_best: int = 6) -> list[np.ndarray]:
    """Start poses for a station behind the ``side`` end (red: x < 0, blue: x > L): floor plane -> roll, pitch,
    height; grid over x (behind_m), y (across the field), yaw (±70° about facing the other end) scored on the
    distance field with the non-floor points. Returns up to ``n_best`` distinct poses, best first."""
    rng = rng or np.random.default_rng(0)
    L, W = field_size
    P = np.asarray(points_lidar, float)
    n, h, floor = floor_plane(P, rng)
    # rotation taking the floor normal to +z (minimal), then yaw about z
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(n, z)
    s, c = np.linalg.norm(v), float(n @ z)
    R_tilt = np.eye(3) if s < 1e-12 else geometry.rotvec_to_R(v / s * np.arctan2(s, c))
    structure = P[~floor]
    # points that rise above the floor and are not far away (the field's raised parts, structures)
    Pt = structure @ R_tilt.T
    above = Pt[:, 2] + h
    keep = (above > 0.05) & (above < 3.0) & (np.linalg.norm(Pt[:, :2], axis=1) < 35)
    S = Pt[keep]
    if len(S) > 1500:
        S = S[rng.choice(len(S), 1500, replace=False)]
    Fp = (P[floor] @ R_tilt.T)
    if len(Fp) > 500:
        Fp = Fp[rng.choice(len(Fp), 500, replace=False)]
    if height_m[0] > h or h > height_m[1] + 1.0:
        pass  # the plane says otherwise; trust the cloud (the verdict will judge the fit)
    base_yaw = 0.0 if side == "red" else 180.0
    xs = -np.arange(behind_m[0], behind_m[1] + 1e-9, 0.5) if side == "red" else L + np.arange(behind_m[0], behind_m[1] + 1e-9, 0.5)
    ys = np.arange(-1.0, W + 1.0 + 1e-9, 0.5)
    yaws = np.radians(base_yaw + np.arange(-69, 69.1, 3.0))
    best = []
    S2 = np.vstack([S, Fp])
    wts = np.concatenate([np.ones(len(S)), 0.3 * np.ones(len(Fp))])
    for yw in yaws:
        cz, sz = np.cos(yw), np.sin(yw)
        Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        Q = S2 @ Rz.T  # rotated, origin at the sensor, z relative to the sensor
        X, Y = np.meshgrid(xs, ys, indexing="ij")
        off = np.stack([X.ravel(), Y.ravel(), np.full(X.size, h)], 1)  # (G,3)
        pts = Q[None, :, :] + off[:, None, :]
        d = target.distance_lookup(pts.reshape(-1, 3)).reshape(len(off), len(Q))
        score = (np.minimum(d, 0.5) * wts[None]).sum(1) / wts.sum()
        for g in np.argsort(score)[:3]:
            best.append((float(score[g]), yw, off[g]))
    best.sort(key=lambda b: b[0])
    out = []
    for sc, yw, off in best:
        cz, sz = np.cos(yw), np.sin(yw)
        Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        T = geometry.make_T(Rz @ R_tilt, off)
        if all(geometry.pose_error(T, o)[0] > 3.0 or geometry.pose_error(T, o)[1] > 0.7 for o in out):
            out.append(T)
        if len(out) >= n_best:
            break
    return out
