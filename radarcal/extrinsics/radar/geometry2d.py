"""2D rigid transforms of a level radar: ``Pose2`` (theta, a, b), closed-form Procrustes, the slant-range model of a
2D radar and its nonlinear least-squares fit with Gauss-Newton covariance, and the Cramer-Rao floor.

2D transforms are ``p_dst = R(theta) p_src + t`` and are named like 4x4 ones (``theta_radar_G`` maps G into radar).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from radarcal import geometry

__all__ = ["Fit2D", "Pose2", "deslant", "fit_rigid_2d", "multipath_of", "pose2_to_T", "procrustes_2d", "procrustes_floor", "rot2", "slant_predict", "wrap_angle"]


def rot2(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def wrap_angle(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@dataclass
class Pose2:
    """2D rigid transform ``p_dst = R(theta) p_src + t``."""

    theta: float
    t: np.ndarray

    def apply(self, p: np.ndarray) -> np.ndarray:
        return np.asarray(p, float) @ rot2(self.theta).T + self.t

    def inverse(self) -> Pose2:
        R = rot2(self.theta)
        return Pose2(-self.theta, -R.T @ self.t)

    def compose(self, other: Pose2) -> Pose2:
        """``self @ other`` (apply ``other`` first)."""
        return Pose2(float(wrap_angle(self.theta + other.theta)), rot2(self.theta) @ other.t + self.t)

    def as_array(self) -> np.ndarray:
        return np.array([self.theta, self.t[0], self.t[1]])

    @classmethod
    def from_T(cls, T: np.ndarray) -> Pose2:
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


def multipath_of(m: np.ndarray, q: np.ndarray, z: np.ndarray, height: float, gate: float, ghost_only: bool = False) -> np.ndarray:
    """Which reflector's echo path each radar detection ``m`` (M,2, radar frame) lies on: along the bearing of a
    reflector at horizontal position ``q`` (K,2, radar frame) and height ``z`` (K,, above the ground; radar plane at
    ``height``), within ``gate`` across it, and between its direct slant range and that of its ground-mirror image
    (a ground-bounce multipath ghost: the reflector seen below the ground, ``z -> -z``) widened by ``gate``; with
    ``ghost_only``, within ``gate`` of the mirror image's slant range only (the ghost itself, not the direct echo).
    Returns (M,) the reflector index, -1 for none (the nearest bearing when several)."""
    m = np.asarray(m, float).reshape(-1, 2)
    q = np.asarray(q, float).reshape(-1, 2)
    if len(m) == 0 or len(q) == 0:
        return np.full(len(m), -1, int)
    z = np.asarray(z, float).reshape(-1)
    r = np.linalg.norm(q, axis=1)
    u = q / np.maximum(r, 1e-12)[:, None]  # (K,2) bearings
    along = m @ u.T  # (M,K) range along each bearing
    across = np.abs(m[:, :1] * u[None, :, 1] - m[:, 1:] * u[None, :, 0])
    direct = np.hypot(r, z - height)
    mirror = np.hypot(r, z + height)
    on = (across < gate) & (along > (mirror if ghost_only else direct) - gate) & (along < mirror + gate)
    k = np.argmin(np.where(on, across, np.inf), axis=1)
    return np.where(on.any(axis=1), k, -1)


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

    def leverage(self) -> np.ndarray:
        """(N,2,2) diagonal blocks ``H_ii`` of the hat matrix ``J (J^T J)^-1 J^T`` (weighted coordinates): how much
        correspondence i pulls the fit onto itself (NaN when the Jacobian is singular)."""
        J = self.jac
        n = len(self.residuals)
        try:
            A = np.linalg.inv(J.T @ J)
        except np.linalg.LinAlgError:
            return np.full((n, 2, 2), np.nan)
        Jb = J.reshape(n, 2, -1)
        return np.einsum("nip,pq,njq->nij", Jb, A, Jb)

    def deletion_residuals(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Leave-one-out residuals from one fit (leverage formula ``(I - H_ii)^-1 r_i`` per 2x2 block; exact for a
        linear model, first order for this one): ((N,2) residual vectors (m), (N,2,2) ``I - H_ii``, (N,) bool where
        that block is invertible; the residual is 0 elsewhere). A singular Jacobian gives no leverage (H = 0)."""
        H = self.leverage()
        if not np.isfinite(H).all():
            H = np.zeros_like(H)
        M = np.eye(2)[None] - H
        ok = np.abs(np.linalg.det(M)) > 1e-12
        d = np.zeros((len(self.residuals), 2))
        d[ok] = np.linalg.solve(M[ok], self.residuals[ok][..., None])[..., 0]
        return d, M, ok

    def inverse_sigma(self) -> dict:
        """1-sigma of the inverse pose's (theta, a, b) (e.g. the radar's pose in G when the fit maps G -> radar) by
        first-order propagation of ``cov`` (+ the height's sigma when estimated)."""
        J = _inverse_jacobian(self.pose)
        C = J @ self.cov[:3, :3] @ J.T
        out = {k: float(np.sqrt(max(C[i, i], 0.0))) for i, k in enumerate(["theta", "a", "b"])}
        if "height" in self.sigma:
            out["height"] = self.sigma["height"]
        return out

    @property
    def per_point(self) -> np.ndarray:
        return np.linalg.norm(self.residuals, axis=1)


def _inverse_jacobian(pose: Pose2) -> np.ndarray:
    """(3,3) Jacobian of the inverse pose's (theta, a, b) with respect to ``pose``'s (theta, a, b)."""
    th, t = pose.theta, pose.t
    dR = np.array([[-np.sin(th), -np.cos(th)], [np.cos(th), -np.sin(th)]])
    J = np.zeros((3, 3))
    J[0, 0] = -1.0
    J[1:, 0] = -dR.T @ t
    J[1:, 1:] = -rot2(th).T
    return J


def _jac_cov(J: np.ndarray, r: np.ndarray, sigma_meas: float | None) -> np.ndarray:
    """Gauss-Newton covariance of the parameters. With the noise estimated from the residuals (``sigma_meas`` None)
    the parameters are Student-t with ``dof`` degrees of freedom: their variance is that of the normal times
    ``dof / (dof - 2)`` (taken as 3 below 3 dof), which a few matches make far from 1."""
    n, p = J.shape
    JTJ = J.T @ J
    if sigma_meas is None:
        dof = max(n - p, 1)
        s2 = float(r @ r) / dof * (dof / (dof - 2) if dof >= 3 else 3.0)
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
    weights: np.ndarray | None = None,
) -> Fit2D:
    """Nonlinear least squares for ``(theta, a, b)`` (and optionally the radar plane height).

    ``src`` (N,2) horizontal positions (e.g. LiDAR reflector centres in the ground frame), ``dst`` (N,2) the radar's
    measurements. Planar model (the patent's): ``dst = R src + t``. Slant model (``src_z`` given): the radar reports
    the slant range to a reflector ``dz = src_z - height`` above its plane (``height`` known, or estimated with
    ``estimate_height``; only ``|dz|`` is observable, so the solution nearest ``height_init`` is returned).
    Initialised in closed form (:func:`procrustes_2d`) unless ``init`` is given. ``sigma`` comes from the Gauss-Newton
    covariance scaled by the residual variance (or by ``sigma_meas`` when given). ``weights`` (N,): relative
    inverse variances of the correspondences (e.g. from RCS); the residual variance is then that of unit weight.
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

    sw = np.ones(len(src)) if weights is None else np.sqrt(np.asarray(weights, float).reshape(-1))

    def resid(x):
        return ((predict(x) - dst) * sw[:, None]).ravel()

    sol = least_squares(resid, np.asarray(x0, float), method="trf" if loss != "linear" else "lm" if 2 * len(src) >= len(x0) else "trf",
                        loss=loss, f_scale=f_scale, x_scale="jac")
    x = sol.x
    r = dst - predict(x)
    cov = _jac_cov(sol.jac, (r * sw[:, None]).ravel(), sigma_meas)
    names = ["theta", "a", "b"] + (["height"] if est_h else [])
    sig = {k: float(np.sqrt(max(cov[i, i], 0.0))) for i, k in enumerate(names)}
    pose = Pose2(float(wrap_angle(x[0])), np.array(x[1:3]))
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
    Ji = _inverse_jacobian(pose)
    ci = Ji @ cov @ Ji.T
    return {"yaw_rad": float(np.sqrt(cov[0, 0])), "translation_m": float(np.sqrt(cov[1, 1] + cov[2, 2])),
            "inverse_translation_m": float(np.sqrt(ci[1, 1] + ci[2, 2])), "cov": cov}

