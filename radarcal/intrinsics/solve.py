"""Intrinsics solve: OpenCV's optimiser wrapped with outlier rejection, honest σ and a projection-uncertainty map.

Pure numeric core. ``calibrate`` iterates *solve → residuals → drop corners beyond k·σ and views that do not fit →
re-solve* until nothing changes. In the first ``free_iterations`` rounds every corner and view is re-judged (a
gross outlier biases the first fit, so good corners near it come back); later rejections are final (as in mrcal:
the loop then settles even when the model cannot fit the lens exactly). Then the solution is linearised with radarcal's
:class:`~radarcal.camera.Camera` (the one projection function; numeric Jacobian, vectorised over all corners) to get
per-parameter σ = sqrt(diag(σ_obs² (JᵀJ)⁻¹)), σ_obs from the inlier residuals.

``projection_uncertainty`` follows mrcal's "mean frames" idea: a pixel is unprojected, mapped into every board
frame, and mapped back with the perturbed poses (averaged), so a principal-point shift that the board poses absorb
does not count as uncertainty. The result is the worst-direction σ (px) on a grid, and the "valid region" where
σ < the per-coordinate pixel noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from radarcal.camera import Camera
from radarcal.intrinsics._blas import single_thread_blas

__all__ = [
    "MODELS",
    "Calibration",
    "UncertaintyMap",
    "SolveError",
    "calibrate",
    "solve_once",
    "residuals",
    "projection_uncertainty",
    "param_names",
    "board_pose",
]

MODELS = ("pinhole5", "pinhole8", "fisheye", "pinhole4")  # pinhole4: k3 fixed at 0 (Kalibr radtan, ROS plumb_bob with 4 terms)
_DIST_NAMES = {
    "pinhole4": ["k1", "k2", "p1", "p2"],
    "pinhole5": ["k1", "k2", "p1", "p2", "k3"],
    "pinhole8": ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"],
    "fisheye": ["k1", "k2", "k3", "k4"],
}


class SolveError(RuntimeError):
    """The optimiser failed (too few views, degenerate geometry, OpenCV assertion)."""


def param_names(model: str) -> list[str]:
    return ["fx", "fy", "cx", "cy"] + _DIST_NAMES[model]


@dataclass
class Calibration:
    """Result of :func:`calibrate`. Per-view arrays cover ALL input views (rejected ones too: their pose comes from
    PnP with the final intrinsics; NaN if that failed). ``residuals[v]`` = observed − projected (N_v,2) px."""

    camera: Camera
    model: str
    rvecs: np.ndarray  # (V,3) board -> camera
    tvecs: np.ndarray  # (V,3)
    residuals: list[np.ndarray]
    inliers: list[np.ndarray]  # (N_v,) bool: corner used in the final solve
    view_used: np.ndarray  # (V,) bool
    view_reasons: list[str]  # "" for used views, else why it was rejected
    rms_px: float  # sqrt(mean |r|²) over inlier corners of used views (OpenCV's definition)
    noise_px: float  # per-coordinate σ of the inlier residuals, corrected for the degrees of freedom
    params: np.ndarray
    sigma: dict[str, float]
    cov: np.ndarray  # intrinsics covariance (P,P), marginal over the poses
    cov_full: np.ndarray = field(repr=False)  # intrinsics + 6 per used view (rvec, tvec)
    iterations: int = 1
    dropped_corners: int = 0

    @property
    def param_names(self) -> list[str]:
        return param_names(self.model)

    def view_rms(self) -> np.ndarray:
        """Per-view RMS (px) over that view's inlier corners (NaN for views without a pose)."""
        out = np.full(len(self.residuals), np.nan)
        for v, (r, m) in enumerate(zip(self.residuals, self.inliers)):
            if m.any() and np.all(np.isfinite(r[m])):
                out[v] = float(np.sqrt(np.mean(np.sum(r[m] ** 2, axis=1))))
        return out


@dataclass
class UncertaintyMap:
    """Worst-direction projection σ (px) on a pixel grid; ``valid`` where σ < ``threshold_px``."""

    u: np.ndarray  # (nx,) pixel columns of the grid
    v: np.ndarray  # (ny,)
    sigma_px: np.ndarray  # (ny, nx)
    valid: np.ndarray  # (ny, nx) bool
    threshold_px: float
    distance_m: float | None  # None = at infinity

    @property
    def valid_fraction(self) -> float:
        return float(np.mean(self.valid))

    def at_centre(self) -> float:
        return float(self.sigma_px[len(self.v) // 2, len(self.u) // 2])


# --- parameter vector <-> Camera -------------------------------------------------------------------------------
def _theta(cam: Camera, model: str) -> np.ndarray:
    n = len(_DIST_NAMES[model])
    d = np.zeros(n)
    d[: min(n, cam.dist.size)] = cam.dist[:n]
    return np.concatenate([[cam.fx, cam.fy, cam.cx, cam.cy], d])


def _camera(theta: np.ndarray, model: str, size: tuple[int, int]) -> Camera:
    K = np.array([[theta[0], 0, theta[2]], [0, theta[1], theta[3]], [0, 0, 1.0]])
    return Camera(size, K, np.asarray(theta[4:], float), "fisheye" if model == "fisheye" else "pinhole")


def _project(theta, model, size, rvecs, tvecs, obj, vidx) -> np.ndarray:
    """All corners at once: (N,2) pixels (NaN behind the camera)."""
    cam = _camera(theta, model, size)
    R = Rotation.from_rotvec(rvecs).as_matrix()
    p_cam = np.einsum("nij,nj->ni", R[vidx], obj) + tvecs[vidx]
    uv, valid = cam.project(p_cam)
    uv[~valid] = np.nan
    return uv


def residuals(camera: Camera, rvecs: np.ndarray, tvecs: np.ndarray, object_points: list[np.ndarray], image_points: list[np.ndarray]) -> list[np.ndarray]:
    """observed − projected (N_v,2) per view, projected with :class:`Camera`."""
    obj = np.concatenate([np.asarray(o, float).reshape(-1, 3) for o in object_points])
    img = np.concatenate([np.asarray(i, float).reshape(-1, 2) for i in image_points])
    vidx = np.repeat(np.arange(len(object_points)), [len(o) for o in object_points])
    model = model_of(camera)
    r = img - _project(_theta(camera, model), model, camera.image_size, np.asarray(rvecs, float).reshape(-1, 3), np.asarray(tvecs, float).reshape(-1, 3), obj, vidx)
    return np.split(r, np.cumsum([len(o) for o in object_points])[:-1])


def model_of(camera: Camera) -> str:
    """The solver model a camera's distortion vector belongs to."""
    if camera.model == "fisheye":
        return "fisheye"
    return "pinhole8" if camera.dist.size >= 8 else "pinhole4" if camera.dist.size == 4 else "pinhole5"


# --- one OpenCV solve ----------------------------------------------------------------------------------------
def solve_once(object_points: list[np.ndarray], image_points: list[np.ndarray], image_size: tuple[int, int], model: str, guess: Camera | None = None) -> tuple[Camera, np.ndarray, np.ndarray, float]:
    """cv2.calibrateCamera / cv2.fisheye.calibrate: (camera, rvecs (V,3), tvecs (V,3), OpenCV RMS)."""
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    if len(object_points) < 3:
        raise SolveError(f"need at least 3 views, have {len(object_points)}")
    size = (int(image_size[0]), int(image_size[1]))
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 300, 1e-12)
    try:
        if model == "fisheye":
            obj = [np.asarray(o, np.float64).reshape(1, -1, 3) for o in object_points]
            img = [np.asarray(i, np.float64).reshape(1, -1, 2) for i in image_points]
            flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW
            if guess is not None and guess.model == "fisheye":
                starts = [(guess.K.copy(), guess.dist.reshape(4, 1).copy())]
            else:
                # OpenCV's own start (f from the image size) diverges on wide lenses (RMS 221 px on a rendered 190°
                # set, 0.037 px from a better start): try a ladder of equidistant focal lengths, keep the best
                base = min(size) / np.pi
                starts = [(np.array([[f, 0, (size[0] - 1) / 2], [0, f, (size[1] - 1) / 2], [0, 0, 1.0]]), np.zeros((4, 1))) for f in base * np.array([0.7, 1.0, 1.4, 2.0, 3.0, 4.5])]
            best = None
            last_err: Exception | None = None
            for K0, D0 in starts:
                try:
                    out = cv2.fisheye.calibrate(obj, img, size, K0, D0, flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=crit)
                except cv2.error as e:
                    last_err = e
                    continue
                if np.isfinite(out[0]) and (best is None or out[0] < best[0]):
                    best = out
            if best is None:
                raise last_err if last_err is not None else SolveError("fisheye solve failed")
            rms, K, D, rv, tv = best
            dist = np.asarray(D, float).ravel()
        else:
            obj = [np.asarray(o, np.float32).reshape(-1, 3) for o in object_points]
            img = [np.asarray(i, np.float32).reshape(-1, 2) for i in image_points]
            flags = cv2.CALIB_RATIONAL_MODEL if model == "pinhole8" else cv2.CALIB_FIX_K3 if model == "pinhole4" else 0
            K, D = None, None
            if guess is not None and guess.model == "pinhole":
                K = guess.K.copy()
                n = 8 if model == "pinhole8" else 5
                D = np.zeros(n)
                D[: min(n, guess.dist.size)] = guess.dist[:n]
                flags |= cv2.CALIB_USE_INTRINSIC_GUESS
            rms, K, D, rv, tv = cv2.calibrateCamera(obj, img, size, K, D, flags=flags, criteria=crit)
            dist = np.asarray(D, float).ravel()[: len(_DIST_NAMES[model])]
    except cv2.error as e:
        msg = str(e).strip().splitlines()
        raise SolveError(f"OpenCV {model} solve failed: {msg[-1] if msg else e}") from None
    cam = Camera(size, K, dist, "fisheye" if model == "fisheye" else "pinhole")
    return cam, np.asarray(rv, float).reshape(-1, 3), np.asarray(tv, float).reshape(-1, 3), float(rms)


def board_pose(cam: Camera, obj: np.ndarray, img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Board pose (rvec, tvec of T_cam_board) of one view given the intrinsics; NaN when it cannot be solved."""
    if len(obj) < 4:
        return np.full(3, np.nan), np.full(3, np.nan)
    if cam.model == "fisheye":
        xy = cam.undistort((np.asarray(img, float) - cam.K[:2, 2]) @ np.linalg.inv(cam.K[:2, :2]).T)
        K, D, pts = np.eye(3), None, xy
    else:
        K, D, pts = cam.K, cam.dist, np.asarray(img, float)
    obj = np.asarray(obj, float)
    pts = pts.astype(float)
    # OpenCV 5's SOLVEPNP_ITERATIVE asserts on fewer than 6 points; the board is planar, so IPPE (>= 4 points)
    # gives the initial pose and LM refines it.
    planar = np.ptp(obj[:, 2]) < 1e-9
    try:
        ok, rv, tv = cv2.solvePnP(obj, pts, K, D, flags=cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_SQPNP)
        if ok:
            rv, tv = cv2.solvePnPRefineLM(obj, pts, K, D, rv, tv)
    except cv2.error:
        ok = False
    if not ok:
        return np.full(3, np.nan), np.full(3, np.nan)
    return rv.ravel(), tv.ravel()


# --- Jacobian and covariance -------------------------------------------------------------------------------------
def _jacobian(theta, model, size, rvecs, tvecs, obj, vidx):
    """Numeric Jacobian of the projected corners (2N rows: u0 v0 u1 v1 ...): intrinsics (2N,P) and the 6 pose
    parameters of each corner's own view (2N,6) (perturbing one component of all views at once: each corner only
    depends on its own view)."""
    P = len(theta)
    Ji = np.empty((2 * len(obj), P))
    for j in range(P):
        h = 1e-6 * max(1.0, abs(theta[j]))
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        Ji[:, j] = ((_project(tp, model, size, rvecs, tvecs, obj, vidx) - _project(tm, model, size, rvecs, tvecs, obj, vidx)) / (2 * h)).ravel()
    Jp = np.empty((2 * len(obj), 6))
    for j in range(6):
        h = 1e-7 if j < 3 else 1e-7 * max(1.0, float(np.nanmax(np.abs(tvecs))))
        rp, rm, tp, tm = rvecs.copy(), rvecs.copy(), tvecs.copy(), tvecs.copy()
        if j < 3:
            rp[:, j] += h
            rm[:, j] -= h
        else:
            tp[:, j - 3] += h
            tm[:, j - 3] -= h
        Jp[:, j] = ((_project(theta, model, size, rp, tp, obj, vidx) - _project(theta, model, size, rm, tm, obj, vidx)) / (2 * h)).ravel()
    return Ji, Jp


def _normal_matrix(Ji: np.ndarray, Jp: np.ndarray, vidx_rows: np.ndarray, n_views: int) -> np.ndarray:
    """JᵀJ for parameters [intrinsics, view0(6), view1(6), ...] from the block-sparse Jacobian."""
    P = Ji.shape[1]
    N = np.zeros((P + 6 * n_views, P + 6 * n_views))
    N[:P, :P] = Ji.T @ Ji
    order = np.argsort(vidx_rows, kind="stable")
    starts = np.searchsorted(vidx_rows[order], np.arange(n_views))
    B = np.add.reduceat(np.einsum("mp,mq->mpq", Ji[order], Jp[order]), starts, axis=0)  # (V,P,6)
    C = np.add.reduceat(np.einsum("mp,mq->mpq", Jp[order], Jp[order]), starts, axis=0)  # (V,6,6)
    for v in range(n_views):
        s = P + 6 * v
        N[:P, s : s + 6] = B[v]
        N[s : s + 6, :P] = B[v].T
        N[s : s + 6, s : s + 6] = C[v]
    return N


# --- the full calibration ------------------------------------------------------------------------------------------
@single_thread_blas
def calibrate(
    object_points: list[np.ndarray],
    image_points: list[np.ndarray],
    image_size: tuple[int, int],
    model: str = "pinhole5",
    reject: bool = True,
    k_sigma: float = 4.0,
    max_outlier_fraction: float = 0.3,
    view_rms_factor: float = 3.0,
    max_iterations: int = 15,
    free_iterations: int = 3,
) -> Calibration:
    """Calibrate from per-view board points (N_v,3) and image corners (N_v,2); see the module doc.

    Corner rule: |r| > k_sigma · σ (σ = robust per-coordinate σ from the median |r| of all corners of used views);
    after ``free_iterations`` rounds rejected corners and views stay rejected.
    View rule: more than ``max_outlier_fraction`` of its corners are outliers, or its inlier RMS exceeds
    ``view_rms_factor`` × the expected RMS (√2 σ). At least half of the views (and 3) are always kept.

    The loop solves, applies one :func:`_rejection_round` and stops when the inliers settle.
    """
    V = len(object_points)
    obj = [np.asarray(o, float).reshape(-1, 3) for o in object_points]
    img = [np.asarray(i, float).reshape(-1, 2) for i in image_points]
    if V < 3:
        raise SolveError(f"need at least 3 views with a board, have {V}")
    inl = [np.ones(len(o), bool) for o in obj]
    used = np.ones(V, bool)
    reasons = [""] * V
    guess = None
    it = 0
    while True:
        it += 1
        sel = np.flatnonzero(used)
        cam, rv_u, tv_u, _ = solve_once([obj[v][inl[v]] for v in sel], [img[v][inl[v]] for v in sel], image_size, model, guess)
        guess = cam
        rvecs = np.full((V, 3), np.nan)
        tvecs = np.full((V, 3), np.nan)
        rvecs[sel], tvecs[sel] = rv_u, tv_u
        for v in np.flatnonzero(~used):
            rvecs[v], tvecs[v] = board_pose(cam, obj[v][inl[v]] if inl[v].sum() >= 4 else obj[v], img[v][inl[v]] if inl[v].sum() >= 4 else img[v])
        res = _residuals_all(cam, model, rvecs, tvecs, obj, img)
        if not reject or it >= max_iterations:
            break
        monotone = it > free_iterations
        new_inl, new_used, new_reasons = _rejection_round(res, sel, inl, used, reasons, monotone, k_sigma, max_outlier_fraction, view_rms_factor)
        n_flips = sum(int(np.sum(a != b)) for a, b in zip(new_inl, inl))
        views_changed = not np.array_equal(new_used, used)
        n_total = sum(len(o) for o in obj)
        settled = n_flips == 0 or (monotone and n_flips <= max(1, 0.001 * n_total))  # a trickle of tail corners
        inl, used, reasons = new_inl, new_used, new_reasons
        if settled and not views_changed:
            if n_flips:  # the last few rejections: one more solve so that the result matches the inlier set
                sel = np.flatnonzero(used)
                cam, rv_u, tv_u, _ = solve_once([obj[v][inl[v]] for v in sel], [img[v][inl[v]] for v in sel], image_size, model, cam)
                rvecs[sel], tvecs[sel] = rv_u, tv_u
                for v in np.flatnonzero(~used):
                    rvecs[v], tvecs[v] = board_pose(cam, obj[v], img[v])
                res = _residuals_all(cam, model, rvecs, tvecs, obj, img)
            break
    # make the final state consistent: 'inl' and 'used' are what the last solve used when we broke on no change
    return _finish(cam, model, rvecs, tvecs, obj, img, res, inl, used, reasons, it)


def _rejection_round(res: list, sel: np.ndarray, inl: list, used: np.ndarray, reasons: list, monotone: bool, k_sigma: float, max_outlier_fraction: float,
                     view_rms_factor: float) -> tuple[list, np.ndarray, list]:  # fmt: skip
    """One round of :func:`calibrate`'s corner and view rules on the residuals ``res`` of every view (``sel``: the
    views used by the solve): the new inlier corners, used views and rejection reasons. ``monotone``: rejected
    corners and views stay rejected."""
    V = len(res)
    # σ from the median over ALL corners of the used views (robust; does not shrink as outliers go, so the
    # monotone rejection settles instead of eating into the tails of a model that cannot fit exactly)
    r_all = np.concatenate([res[v] for v in sel])
    r_all = r_all[np.all(np.isfinite(r_all), axis=1)]
    sigma = max(float(np.sqrt(np.median(np.sum(r_all**2, axis=1)) / (2 * np.log(2)))), 1e-3)
    thr = k_sigma * sigma
    new_inl = []
    new_used = np.ones(V, bool)
    new_reasons = [""] * V
    badness = np.zeros(V)
    for v in range(V):
        if monotone and not used[v]:  # late rejections are final (stable on misfit models, terminates)
            new_inl.append(inl[v])
            new_used[v], new_reasons[v], badness[v] = False, reasons[v], 1e9
            continue
        n = np.linalg.norm(res[v], axis=1)
        m_all = np.isfinite(n) & (n < thr)
        m = (inl[v] & m_all) if monotone else m_all
        new_inl.append(m)
        frac_out = 1.0 - m_all.mean()
        rms_v = float(np.sqrt(np.mean(n[m] ** 2))) if m.sum() else np.inf
        if not np.all(np.isfinite(res[v])):
            new_used[v], new_reasons[v] = False, "outlier: pose failed"
            badness[v] = np.inf
        elif frac_out > max_outlier_fraction:
            new_used[v], new_reasons[v] = False, f"outlier: {frac_out:.0%} of corners beyond {thr:.2f} px (view RMS {np.sqrt(np.mean(n**2)):.2f} px)"
            badness[v] = frac_out + 1
        elif rms_v > view_rms_factor * np.sqrt(2) * sigma:
            new_used[v], new_reasons[v] = False, f"outlier: view RMS {rms_v:.2f} px > {view_rms_factor * np.sqrt(2) * sigma:.2f} px"
            badness[v] = rms_v / sigma
        elif m.sum() < 6:
            new_used[v], new_reasons[v] = False, "outlier: fewer than 6 corners fit"
            badness[v] = 1
    keep_min = max(3, (V + 1) // 2)
    if new_used.sum() < keep_min:  # keep the least bad views, with all their corners
        order = np.argsort(badness, kind="stable")
        new_used[:] = False
        new_used[order[:keep_min]] = True
        for v in order[:keep_min]:
            new_reasons[v] = ""
            if new_inl[v].sum() < 6:
                new_inl[v] = np.all(np.isfinite(res[v]), axis=1)
    return new_inl, new_used, new_reasons


def _residuals_all(cam, model, rvecs, tvecs, obj, img):
    cat_obj = np.concatenate(obj)
    vidx = np.repeat(np.arange(len(obj)), [len(o) for o in obj])
    ok = np.all(np.isfinite(rvecs), axis=1)
    rv = np.where(ok[:, None], rvecs, 0.0)
    tv = np.where(ok[:, None], tvecs, 1.0)
    uv = _project(_theta(cam, model), model, cam.image_size, rv, tv, cat_obj, vidx)
    uv[~ok[vidx]] = np.nan
    r = np.concatenate(img) - uv
    return np.split(r, np.cumsum([len(o) for o in obj])[:-1])


def _finish(cam, model, rvecs, tvecs, obj, img, res, inl, used, reasons, it) -> Calibration:
    sel = np.flatnonzero(used)
    theta = _theta(cam, model)
    o = np.concatenate([obj[v][inl[v]] for v in sel])
    vloc = np.repeat(np.arange(len(sel)), [int(inl[v].sum()) for v in sel])
    Ji, Jp = _jacobian(theta, model, cam.image_size, rvecs[sel], tvecs[sel], o, vloc)
    rows_view = np.repeat(vloc, 2)
    N = _normal_matrix(Ji, Jp, rows_view, len(sel))
    r_in = np.concatenate([res[v][inl[v]] for v in sel])
    M = r_in.size
    Ptot = N.shape[0]
    noise = float(np.sqrt(np.sum(r_in**2) / max(M - Ptot, 1)))
    # scale for conditioning, then invert
    d = np.sqrt(np.maximum(np.diag(N), 1e-30))
    Ninv = np.linalg.pinv(N / d[:, None] / d[None, :], rcond=1e-14) / d[:, None] / d[None, :]
    cov_full = noise**2 * Ninv
    P = len(theta)
    cov = cov_full[:P, :P]
    names = param_names(model)
    sig = {n: float(np.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(names)}
    rms = float(np.sqrt(np.mean(np.sum(r_in**2, axis=1))))
    dropped = int(sum((~inl[v]).sum() for v in sel))
    return Calibration(cam, model, rvecs, tvecs, res, inl, used, reasons, rms, noise, theta, sig, cov, cov_full, it, dropped)


# --- projection uncertainty -------------------------------------------------------------------------------------
@single_thread_blas
def projection_uncertainty(cal: Calibration, nx: int = 40, ny: int | None = None, distance_m: float | None = None, threshold_px: float | None = None) -> UncertaintyMap:
    """Worst-direction σ (px) of the projection of a fixed world point, on an ``nx`` x ``ny`` pixel grid.

    distance_m: depth of the test point along the ray (None = at infinity: only rotations matter).
    threshold_px: σ below which a pixel is "valid" (default: the calibration's per-coordinate noise).
    """
    cam = cal.camera
    w, h = cam.image_size
    ny = ny or max(2, int(round(nx * h / w)))
    u = np.linspace(0, w - 1, nx)
    v = np.linspace(0, h - 1, ny)
    q = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)
    rays = cam.unproject(q)
    p_cam = rays * (distance_m if distance_m else 1.0)
    sel = np.flatnonzero(cal.view_used)
    R = Rotation.from_rotvec(cal.rvecs[sel]).as_matrix()  # (U,3,3)
    t = cal.tvecs[sel] if distance_m else np.zeros((len(sel), 3))
    U = len(sel)
    p_board = np.einsum("uji,ugj->ugi", R, p_cam[None] - t[:, None])  # Rᵀ (p - t): (U,G,3)
    theta = cal.params
    model = cal.model
    P = len(theta)
    G = len(q)

    def proj(th, p):
        c = _camera(th, model, cam.image_size)
        uv, ok = c.project(p)
        uv[~ok] = np.nan
        return uv

    Jq = np.zeros((G, 2, P + 6 * U))
    for j in range(P):
        hh = 1e-6 * max(1.0, abs(theta[j]))
        tp, tm = theta.copy(), theta.copy()
        tp[j] += hh
        tm[j] -= hh
        Jq[:, :, j] = (proj(tp, p_cam) - proj(tm, p_cam)) / (2 * hh)
    # d q / d p_cam (G,2,3)
    dqdp = np.empty((G, 2, 3))
    scale = np.linalg.norm(p_cam, axis=1, keepdims=True)
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1e-6
        dqdp[:, :, k] = (proj(theta, p_cam + e * scale) - proj(theta, p_cam - e * scale)) / (2e-6 * scale)
    # d p' / d pose_v: p' = mean_v (R_v p_board_v + t_v)
    for k in range(3):
        hh = 1e-7
        rp, rm = cal.rvecs[sel].copy(), cal.rvecs[sel].copy()
        rp[:, k] += hh
        rm[:, k] -= hh
        Rp = Rotation.from_rotvec(rp).as_matrix()
        Rm = Rotation.from_rotvec(rm).as_matrix()
        dp = (np.einsum("uij,ugj->ugi", Rp, p_board) - np.einsum("uij,ugj->ugi", Rm, p_board)) / (2 * hh) / U  # (U,G,3)
        Jq[:, :, P + 6 * np.arange(U) + k] = np.einsum("gkc,ugc->gku", dqdp, dp)
        if distance_m:
            Jq[:, :, P + 6 * np.arange(U) + 3 + k] = (dqdp[:, :, k] / U)[:, :, None]
    S = np.einsum("gkp,pq,glq->gkl", Jq, cal.cov_full, Jq, optimize=True)
    tr = S[:, 0, 0] + S[:, 1, 1]
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    lam = tr / 2 + np.sqrt(np.maximum(tr**2 / 4 - det, 0))
    sigma = np.sqrt(np.maximum(lam, 0)).reshape(ny, nx)
    thr = float(threshold_px if threshold_px is not None else cal.noise_px)
    return UncertaintyMap(u, v, sigma, np.isfinite(sigma) & (sigma < thr), thr, distance_m)
