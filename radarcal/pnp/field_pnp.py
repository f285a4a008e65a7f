"""The camera's pose on the field from four or more clicked landmarks (pure numeric core of ``radarcal field-pnp``).

Pipeline (:func:`solve_field_pnp`):

1. checks on the input: at least 4 picks, finite, no two picks on the same pixel, no two landmarks at the same place,
   picks / landmarks not (nearly) collinear;
2. with more than 4 picks, RANSAC over 4-point subsets (exhaustive when there are few, MSAC score) to reject wrong
   clicks;
3. candidate poses from SQPnP (all points), IPPE (when the landmarks are coplanar: its two solutions) and P3P on every
   triple (up to 4 solutions each) — together they contain every local minimum of the 4-point problem, so the
   4-point ambiguity is resolved explicitly, not by luck;
4. Levenberg-Marquardt refinement of each candidate on the reprojection error in pixels through
   :class:`radarcal.camera.Camera` (any lens model; the points are undistorted with ``Camera.unproject`` for the
   closed-form solvers, so fisheye works too);
5. choice: among the candidates that put the camera above the field and every landmark in front of it, the one with
   the smallest reprojection error; another plausible candidate that fits almost as well is reported as ambiguity;
6. covariance of the pose from the Jacobian and the assumed click noise, σ of the camera position on the field,
   per-point residuals; errors for an implausible pose, a poorly determined pose or a reprojection error above the
   threshold.

Errors are :class:`FieldPnPError` (a ``ValueError``) with a one-line message; the CLI names the picks file.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from radarcal import geometry
from radarcal.camera import Camera

__all__ = ["FieldPnPError", "FieldPnPResult", "PnPOptions", "solve_field_pnp", "pose_to_params", "params_to_pose", "reprojection_jacobian"]


class FieldPnPError(ValueError):
    """The picks do not determine a sensible pose; the message says why in one line."""


@dataclass
class PnPOptions:
    click_sigma_px: float = 1.0        # assumed σ of a click (per axis), for the pose covariance
    max_rms_px: float = 5.0            # reprojection RMS above this -> error (wrong landmark / wrong intrinsics)
    ransac_threshold_px: float = 8.0   # a pick further than this from the pose's projection is an outlier (> 4 picks)
    min_separation_px: float = 3.0     # two picks closer than this: the same point clicked twice
    min_line_spread_px: float = 3.0    # picks whose RMS distance from their best-fit line is below this: collinear
    max_position_sigma_m: float = 3.0  # camera-position σ above this (for the assumed click noise): degenerate picks
    min_camera_height_m: float = 0.0   # the camera must be above the surface by at least this
    ransac_max_subsets: int = 400      # exhaustive below this many 4-subsets, else this many random ones (seeded)


@dataclass
class FieldPnPResult:
    """``T_cam_field`` maps field points into the camera. Residuals are observed − projected pixels."""

    T_cam_field: np.ndarray
    names: list[str]
    uv: np.ndarray                  # (N,2) picks
    p_field: np.ndarray             # (N,3) landmark coordinates
    inliers: np.ndarray             # (N,) bool
    residuals_px: np.ndarray        # (N,2)
    rms_px: float                   # over inliers (per pick, i.e. sqrt(mean |r|^2))
    cov_pose: np.ndarray            # (6,6) covariance of [rotvec, t] of T_cam_field for the assumed click noise
    sigma: dict                     # rot_deg (3,), t_m (3,), camera_position_m (3,), click_px
    camera_position: np.ndarray     # (3,) camera centre in the field frame
    method: str
    candidates: list[dict] = field(default_factory=list)   # every distinct local minimum: rms, plausible, why not
    warnings: list[str] = field(default_factory=list)

    @property
    def T_field_cam(self) -> np.ndarray:
        return geometry.invert_T(self.T_cam_field)

    @property
    def per_point_px(self) -> np.ndarray:
        return np.linalg.norm(self.residuals_px, axis=1)


# --- parameterisation --------------------------------------------------------------------------------------------
def pose_to_params(T: np.ndarray) -> np.ndarray:
    """4x4 -> [rotvec (3), t (3)]."""
    return np.concatenate([geometry.R_to_rotvec(T[:3, :3]), T[:3, 3]])


def params_to_pose(x: np.ndarray) -> np.ndarray:
    return geometry.make_T(geometry.rotvec_to_R(x[:3]), x[3:])


def _project(camera: Camera, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    uv, valid, _ = camera.project_from(params_to_pose(x), P)
    return uv, valid


def reprojection_jacobian(camera: Camera, x: np.ndarray, P: np.ndarray, eps: float = 1e-7) -> np.ndarray:
    """d(uv)/d(x) (2N,6) by central differences (the Camera's projection is the one truth for every lens model)."""
    J = np.empty((2 * len(P), 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        up, _ = _project(camera, x + d, P)
        um, _ = _project(camera, x - d, P)
        J[:, i] = ((up - um) / (2 * eps)).ravel()
    return J


def _refine(camera: Camera, x0: np.ndarray, P: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, float]:
    """Levenberg-Marquardt on pixel residuals (scipy's MINPACK LM with our Jacobian). Returns (x, rms px)."""
    from scipy.optimize import least_squares

    def fun(x):
        u, _ = _project(camera, x, P)  # a point behind the camera has NaN pixels -> a large finite residual
        r = (u - uv).ravel()
        return np.where(np.isfinite(r), r, 1e6)

    try:
        sol = least_squares(fun, x0, jac=lambda x: reprojection_jacobian(camera, x, P), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200)
        x = sol.x
    except (ValueError, np.linalg.LinAlgError):
        x = x0
    u, valid = _project(camera, x, P)
    if not np.all(valid):
        return x, float("inf")
    r = u - uv
    return x, float(np.sqrt(np.mean(np.sum(r * r, axis=1))))


# --- candidates ----------------------------------------------------------------------------------------------------
def _normalised(camera: Camera, uv: np.ndarray) -> np.ndarray:
    rays = camera.unproject(uv)
    return rays[:, :2] / rays[:, 2:3]


def _closed_form(P: np.ndarray, xy: np.ndarray, flags: int) -> list[np.ndarray]:
    """Every pose ``[rotvec, t]`` (T_cam_field) the OpenCV solver ``flags`` returns for normalised image points
    ``xy``; P3P takes exactly three points (``cv2.solveP3P``: ``solvePnPGeneric`` refuses three since OpenCV 5)."""
    import cv2

    P, xy = P.astype(np.float64), xy.astype(np.float64).reshape(-1, 1, 2)
    try:
        if flags == cv2.SOLVEPNP_P3P:
            n, rvecs, tvecs = cv2.solveP3P(P, xy, np.eye(3), None, flags=flags)
        else:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(P, xy, np.eye(3), None, flags=flags)
    except cv2.error:
        return []
    return [np.concatenate([np.ravel(r), np.ravel(t)]) for r, t in zip(rvecs, tvecs)][: int(n)] if n else []


def _coplanar(P: np.ndarray) -> bool:
    c = P - P.mean(0)
    s = np.linalg.svd(c, compute_uv=False)
    return s[2] < 1e-6 * max(s[0], 1e-12)


def _candidate_params(camera: Camera, P: np.ndarray, uv: np.ndarray) -> list[np.ndarray]:
    import cv2

    xy = _normalised(camera, uv)
    cands = _closed_form(P, xy, cv2.SOLVEPNP_SQPNP)
    if _coplanar(P):
        # IPPE in OpenCV 5.0 returns a wrong pose for a plane off z = 0 (measured: 144 deg off for the central
        # highland's top at z = 0.6 m), so solve in a plane-aligned frame and map back
        c = P.mean(0)
        Vt = np.linalg.svd(P - c)[2]
        if np.linalg.det(Vt) < 0:
            Vt[2] *= -1
        Q = (P - c) @ Vt.T
        Q[:, 2] = 0.0
        T_plane_field = geometry.make_T(Vt, -Vt @ c)
        for x in _closed_form(Q, xy, cv2.SOLVEPNP_IPPE):
            cands.append(pose_to_params(params_to_pose(x) @ T_plane_field))
    triples = list(itertools.combinations(range(len(P)), 3))
    if len(triples) > 20:
        triples = triples[:: max(1, len(triples) // 20)]
    for tri in triples:
        idx = list(tri)
        cands += _closed_form(P[idx], xy[idx], cv2.SOLVEPNP_P3P)
    if len(P) >= 6:
        cands += _closed_form(P, xy, cv2.SOLVEPNP_EPNP)
    return [c for c in cands if np.all(np.isfinite(c))]


def _plausibility(x: np.ndarray, P: np.ndarray, surface_z, min_height: float) -> str | None:
    """None when the camera is above the field and every landmark is in front of it; else the reason."""
    T = params_to_pose(x)
    z = (P @ T[:3, :3].T + T[:3, 3])[:, 2]
    C = -T[:3, :3].T @ T[:3, 3]
    ground = float(surface_z(C[None, :2])[0]) if surface_z is not None else 0.0
    if np.any(z <= 0):
        return f"{int(np.sum(z <= 0))} landmark(s) behind the camera"
    if C[2] < ground + min_height:
        return f"camera below the field surface (z = {C[2]:.2f} m)"
    if np.linalg.norm(C[:2] - P[:, :2].mean(0)) > 200 or C[2] > 100:
        return f"camera implausibly far away ({C[0]:.1f}, {C[1]:.1f}, {C[2]:.1f}) m"
    return None


# --- checks ----------------------------------------------------------------------------------------------------
def _check_inputs(P: np.ndarray, uv: np.ndarray, names: list[str], opt: PnPOptions) -> None:
    n = len(uv)
    if n < 4:
        raise FieldPnPError(f"need at least 4 picks of distinct landmarks, got {n}" + (f" ({', '.join(names)})" if names else ""))
    if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(P))):
        raise FieldPnPError("non-finite pixel or landmark coordinate")
    for i, j in itertools.combinations(range(n), 2):
        dpx = float(np.linalg.norm(uv[i] - uv[j]))
        if dpx < opt.min_separation_px:
            raise FieldPnPError(f"picks {names[i]} and {names[j]} are only {dpx:.1f} px apart (the same point clicked twice?)")
        if np.linalg.norm(P[i] - P[j]) < 0.01:
            raise FieldPnPError(f"landmarks {names[i]} and {names[j]} are at the same place in the field model")
    c = uv - uv.mean(0)
    s = np.linalg.svd(c, compute_uv=False)
    if s[1] / np.sqrt(n) < opt.min_line_spread_px:
        raise FieldPnPError(f"the {n} picks are (nearly) collinear in the image (spread off their line {s[1] / np.sqrt(n):.1f} px); pick landmarks that surround the area of interest")
    s3 = np.linalg.svd(P - P.mean(0), compute_uv=False)
    if s3[1] < 1e-3 * s3[0]:
        raise FieldPnPError("the chosen landmarks are collinear in the field: their pose about that line is undetermined")
    if n == 4:
        for tri in itertools.combinations(range(4), 3):
            a, b, cc = uv[list(tri)]
            base = max(np.linalg.norm(b - a), np.linalg.norm(cc - a), np.linalg.norm(cc - b))
            area2 = abs((b[0] - a[0]) * (cc[1] - a[1]) - (b[1] - a[1]) * (cc[0] - a[0]))
            if area2 / max(base, 1e-9) < opt.min_line_spread_px:
                raise FieldPnPError(f"picks {', '.join(names[k] for k in tri)} are (nearly) on one line in the image; with 4 picks that leaves the pose ill-determined — choose another landmark or add a fifth")


# --- main entry ----------------------------------------------------------------------------------------------------
def _ransac(camera: Camera, P: np.ndarray, uv: np.ndarray, opt: PnPOptions) -> np.ndarray:
    """Inlier mask of the best 4-subset hypothesis (MSAC)."""
    import cv2

    n = len(P)
    subsets = list(itertools.combinations(range(n), 4))
    if len(subsets) > opt.ransac_max_subsets:
        rng = np.random.default_rng(0)
        subsets = [tuple(sorted(rng.choice(n, 4, replace=False))) for _ in range(opt.ransac_max_subsets)]
    xy = _normalised(camera, uv)
    thr2 = opt.ransac_threshold_px ** 2
    best, best_score = None, np.inf
    for sub in subsets:
        idx = list(sub)
        for x in _closed_form(P[idx], xy[idx], cv2.SOLVEPNP_SQPNP):
            u, valid = _project(camera, x, P)
            e2 = np.where(valid, np.sum((u - uv) ** 2, axis=1), np.inf)
            score = np.sum(np.minimum(e2, thr2))
            if score < best_score:
                best_score, best = score, e2 < thr2
    if best is None or best.sum() < 4:
        raise FieldPnPError(f"no consistent pose: fewer than 4 of the {n} picks agree within {opt.ransac_threshold_px:g} px")
    return best


def solve_field_pnp(camera: Camera, p_field: np.ndarray, uv: np.ndarray, names: list[str] | None = None, options: PnPOptions | None = None, surface_z=None) -> FieldPnPResult:
    """Pose of the camera on the field from picks ``uv`` (N,2) of landmarks at ``p_field`` (N,3).

    ``surface_z``: optional callable (M,2) -> (M,) (e.g. ``FieldModel.surface_z``) for the "camera above the field"
    check (default: the ground z = 0). Raises :class:`FieldPnPError` for degenerate or implausible input."""
    opt = options or PnPOptions()
    P = np.asarray(p_field, float).reshape(-1, 3)
    uv = np.asarray(uv, float).reshape(-1, 2)
    names = list(names) if names is not None else [f"#{i}" for i in range(len(uv))]
    if len(P) != len(uv) or len(names) != len(uv):
        raise FieldPnPError(f"{len(uv)} picks but {len(P)} landmark coordinates / {len(names)} names")
    _check_inputs(P, uv, names, opt)
    n = len(uv)
    warnings: list[str] = []
    inl = np.ones(n, bool)
    method = "sqpnp+p3p candidates, LM"
    if n > 4:
        inl = _ransac(camera, P, uv, opt)
        method = "RANSAC(4-subsets, SQPnP) + " + method
    best, ok, cands, inl = _refine_on_inliers(camera, P, uv, inl, surface_z, opt)
    x = best["x"]
    T = params_to_pose(x)
    u, valid = _project(camera, x, P)
    res = uv - u
    rms = float(np.sqrt(np.mean(np.sum(res[inl] ** 2, axis=1))))
    if rms > opt.max_rms_px:
        worst = int(np.argmax(np.where(inl, np.linalg.norm(res, axis=1), -1)))
        raise FieldPnPError(f"reprojection error {rms:.1f} px RMS is above the threshold {opt.max_rms_px:g} px (worst: {names[worst]} {np.linalg.norm(res[worst]):.1f} px) — a wrong landmark, wrong order or wrong intrinsics?")
    for c in ok[1:]:
        dang, dpos = geometry.pose_error(params_to_pose(c["x"]), T)
        if c["rms_px"] < max(2.0 * rms, rms + opt.click_sigma_px) and (dang > 1.0 or dpos > 0.2):
            warnings.append(f"ambiguous: another plausible pose fits almost as well ({c['rms_px']:.2f} px vs {rms:.2f} px, {dang:.1f} deg / {dpos:.2f} m away); add a fifth landmark")
            break
    cov, C, sig_c = _pose_covariance(camera, x, T, P[inl], opt)
    sigma = {
        "click_px": opt.click_sigma_px,
        "rot_deg": np.degrees(np.sqrt(np.clip(np.diag(cov)[:3], 0, None))).tolist(),
        "t_m": np.sqrt(np.clip(np.diag(cov)[3:], 0, None)).tolist(),
        "camera_position_m": sig_c.tolist(),
    }
    if (~inl).any():
        warnings.append("outliers rejected: " + ", ".join(f"{names[i]} ({np.linalg.norm(res[i]):.1f} px)" for i in np.nonzero(~inl)[0]))
    cand_out = [{"rms_px": c["rms_px"], "plausible": c["plausible"], "why_not": c["why_not"], "T_cam_field": params_to_pose(c["x"])} for c in cands]
    return FieldPnPResult(T, names, uv, P, inl, res, rms, cov, sigma, C, method, cand_out, warnings)


def _pose_candidates(camera: Camera, Pi: np.ndarray, ui: np.ndarray, surface_z, opt: PnPOptions) -> list[dict]:
    """Every closed-form start refined (LM) on the picks ``ui`` of ``Pi``, duplicates dropped, each with its RMS (px)
    and plausibility (camera above the field, landmarks in front)."""
    cands = []
    for x0 in _candidate_params(camera, Pi, ui):
        x, rms = _refine(camera, x0, Pi, ui)
        if any(np.linalg.norm(x - c["x"]) < 1e-6 for c in cands):
            continue
        why = _plausibility(x, Pi, surface_z, opt.min_camera_height_m)
        cands.append({"x": x, "rms_px": rms, "plausible": why is None, "why_not": why})
    return cands


def _refine_on_inliers(camera: Camera, P, uv, inl, surface_z, opt: PnPOptions):
    """Refine on the inliers, re-select the inliers under the best plausible pose; up to three rounds. Returns (best
    candidate, plausible candidates by RMS, all candidates, inliers); raises when no candidate is plausible."""
    n = len(uv)
    for _ in range(3):
        cands = _pose_candidates(camera, P[inl], uv[inl], surface_z, opt)
        if not cands:
            raise FieldPnPError("no pose fits these picks (all closed-form solvers failed)")
        ok = [c for c in cands if c["plausible"]]
        if not ok:
            best = min(cands, key=lambda c: c["rms_px"])
            fit = f" (best fit {best['rms_px']:.1f} px)" if np.isfinite(best["rms_px"]) else ""
            raise FieldPnPError(f"camera pose implausible: {best['why_not']}{fit} — are the picks in the right order / the right landmarks?")
        ok.sort(key=lambda c: c["rms_px"])
        best = ok[0]
        if n == 4 or inl.all():
            break
        u, valid = _project(camera, best["x"], P)
        new = valid & (np.linalg.norm(u - uv, axis=1) < opt.ransac_threshold_px)
        if new.sum() < 4 or np.array_equal(new, inl):
            break
        inl = new
    return best, ok, cands, inl


def _pose_covariance(camera: Camera, x: np.ndarray, T: np.ndarray, P_inl: np.ndarray, opt: PnPOptions):
    """Covariance of the 6 pose parameters from the Jacobian and the assumed click noise, the camera position C in
    the field frame and its 1-sigma (m); raises when the picks leave the pose undetermined or poorly determined."""
    J = reprojection_jacobian(camera, x, P_inl)
    JtJ = J.T @ J
    if np.linalg.cond(JtJ) > 1e14:
        raise FieldPnPError("the picks do not determine the pose (singular Jacobian): choose landmarks spread over the image and in depth")
    cov = opt.click_sigma_px ** 2 * np.linalg.inv(JtJ)
    # camera position C = -R^T t: its Jacobian wrt x numerically
    Jc = np.empty((3, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = 1e-7
        Tp, Tm = params_to_pose(x + d), params_to_pose(x - d)
        Jc[:, i] = ((-Tp[:3, :3].T @ Tp[:3, 3]) - (-Tm[:3, :3].T @ Tm[:3, 3])) / 2e-7
    cov_c = Jc @ cov @ Jc.T
    C = -T[:3, :3].T @ T[:3, 3]
    sig_c = np.sqrt(np.clip(np.diag(cov_c), 0, None))
    if np.linalg.norm(sig_c) > opt.max_position_sigma_m:
        raise FieldPnPError(f"the picks determine the pose poorly: camera position σ = {np.linalg.norm(sig_c):.1f} m for {opt.click_sigma_px:g} px clicks (limit {opt.max_position_sigma_m:g} m); choose landmarks spread over the image and in depth")
    return cov, C, sig_c
