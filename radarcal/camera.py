"""The one camera model of radarcal: pinhole + OpenCV radtan/rational/thin-prism, or fisheye (equidistant).

Frames and units: points in the camera frame (x right, y down, z forward, metres); pixels with centres at
integer coordinates (OpenCV). ``project`` and ``unproject`` are vectorised over (N,3) / (N,2) arrays and agree
with ``cv2.projectPoints`` / ``cv2.fisheye.projectPoints`` to ~1e-9 px.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Camera", "PINHOLE_DIST_SIZES", "FISHEYE_DIST_SIZE"]

PINHOLE_DIST_SIZES = (4, 5, 8, 12)
FISHEYE_DIST_SIZE = 4
_MODELS = ("pinhole", "fisheye")


@dataclass
class Camera:
    """Intrinsics of one camera.

    model: ``"pinhole"`` (OpenCV dist order k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4]]]) or ``"fisheye"``
    (equidistant, k1..k4 as in ``cv2.fisheye``). ``K`` is 3x3 (skew allowed), ``image_size`` is (width, height).
    """

    image_size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    model: str = "pinhole"

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, float).reshape(3, 3)
        self.dist = np.asarray(self.dist, float).ravel()
        self.image_size = (int(self.image_size[0]), int(self.image_size[1]))
        problem = self.problem()
        if problem:
            raise ValueError(problem)

    def problem(self) -> str | None:
        """A one-line description of what is wrong with these intrinsics, or None."""
        if self.model not in _MODELS:
            return f"model: expected one of {_MODELS}, got {self.model!r}"
        if self.model == "pinhole" and self.dist.size not in PINHOLE_DIST_SIZES:
            return f"dist: pinhole needs {'/'.join(map(str, PINHOLE_DIST_SIZES))} coefficients, got {self.dist.size}"
        if self.model == "fisheye" and self.dist.size != FISHEYE_DIST_SIZE:
            return f"dist: fisheye needs {FISHEYE_DIST_SIZE} coefficients, got {self.dist.size}"
        if not np.all(np.isfinite(self.K)):
            return "K: non-finite value"
        if not np.all(np.isfinite(self.dist)):
            return "dist: non-finite value"
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            return f"K: focal lengths must be positive, got fx={self.K[0, 0]:g}, fy={self.K[1, 1]:g}"
        if not np.allclose(self.K[2], [0, 0, 1]) or self.K[1, 0] != 0:
            return "K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]]"
        if self.image_size[0] <= 0 or self.image_size[1] <= 0:
            return f"image_size: must be positive, got {self.image_size}"
        return None

    # --- convenience -------------------------------------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def width(self) -> int:
        return self.image_size[0]

    @property
    def height(self) -> int:
        return self.image_size[1]

    def to_dict(self) -> dict:
        return {
            "model": self.model,
            "image_size": list(self.image_size),
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        return cls(image_size=tuple(d["image_size"]), K=np.asarray(d["K"], float), dist=np.asarray(d["dist"], float), model=d.get("model", "pinhole"))

    # --- distortion in normalised coordinates --------------------------------------------------------------------
    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates (N,2) (x/z, y/z) -> distorted normalised coordinates (N,2)."""
        xy = np.asarray(xy, float)
        x, y = xy[:, 0], xy[:, 1]
        d = self.dist
        r2 = x * x + y * y
        if self.model == "fisheye":
            r = np.sqrt(r2)
            theta = np.arctan(r)
            t2 = theta * theta
            theta_d = theta * (1 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))
            scale = np.where(r > 1e-12, theta_d / np.where(r > 1e-12, r, 1.0), 1.0)
            return xy * scale[:, None]
        k = np.zeros(12)
        k[: d.size] = d
        k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = k
        r4 = r2 * r2
        r6 = r4 * r2
        radial = (1 + k1 * r2 + k2 * r4 + k3 * r6) / (1 + k4 * r2 + k5 * r4 + k6 * r6)
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r4
        return np.stack([xd, yd], axis=1)

    def _radial_table(self) -> tuple[np.ndarray, np.ndarray]:
        """Samples of the radial map on its monotonic branch: pinhole ``r -> r*radial(r)`` (undistorted ->
        distorted normalised radius), fisheye ``theta -> theta_d``. Stops at the first fold (where the map stops
        increasing), beyond which a distorted radius has no unique undistorted one."""
        d = self.dist
        if self.model == "fisheye":
            x = np.linspace(0.0, np.pi, 8001)
            t2 = x * x
            g = x * (1 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))
            ok_den = np.ones_like(x, dtype=bool)
        else:
            x = np.tan(np.linspace(0.0, np.radians(89.8), 8001))  # r = tan(angle off axis), up to ~290
            k = np.zeros(12)
            k[: d.size] = d
            r2 = x * x
            num = 1 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))
            den = 1 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]))
            ok_den = den > 0
            with np.errstate(divide="ignore", invalid="ignore"):
                g = x * num / den
        bad = ~(ok_den[1:] & (np.diff(g) > 0) & np.isfinite(g[1:]))
        stop = int(np.argmax(bad)) + 1 if bad.any() else len(x)
        return x[:stop], g[:stop]

    def _invert_radius(self, rd: np.ndarray) -> np.ndarray:
        """Undistorted radius (pinhole: normalised r; fisheye: angle theta) for distorted radii ``rd`` on the
        monotonic branch of the lens model; NaN where ``rd`` lies beyond the fold (no unique inverse)."""
        x_tab, g_tab = self._radial_table()
        rd = np.asarray(rd, float)
        x = np.interp(rd, g_tab, x_tab)
        x[~(rd <= g_tab[-1])] = np.nan  # beyond the fold (or NaN input)
        return x

    def _fisheye_theta(self, theta_d: np.ndarray) -> np.ndarray:
        """Angle off axis for distorted fisheye radii: tabulated inverse + Newton on
        ``theta_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)``; NaN past the fold."""
        d = self.dist
        theta = self._invert_radius(theta_d)
        for _ in range(6):
            t2 = theta * theta
            g = theta * (1 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3])))) - theta_d
            dg = 1 + t2 * (3 * d[0] + t2 * (5 * d[1] + t2 * (7 * d[2] + t2 * 9 * d[3])))
            theta = theta - g / dg
        return theta

    def _distort_jacobian(self, xy: np.ndarray) -> tuple[np.ndarray, ...]:
        """Analytic 2x2 Jacobian of the pinhole :meth:`distort` at undistorted ``xy``: (dxd/dx, dxd/dy, dyd/dx, dyd/dy)."""
        k = np.zeros(12)
        k[: self.dist.size] = self.dist
        k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = k
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        dnum = k1 + r2 * (2 * k2 + r2 * 3 * k3)
        dden = k4 + r2 * (2 * k5 + r2 * 3 * k6)
        radial = num / den
        drad = (dnum * den - num * dden) / (den * den)  # d radial / d r2
        px = s1 + 2 * s2 * r2
        py = s3 + 2 * s4 * r2
        j00 = radial + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x + 2 * x * px
        j01 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * y * px
        j10 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * x * py
        j11 = radial + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x + 2 * y * py
        return j00, j01, j10, j11

    def undistort(self, xyd: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Inverse of :meth:`distort`: distorted normalised coordinates (N,2) -> undistorted (N,2).

        Pinhole: starts from the exact inverse of the radial part (tabulated on the polynomial's monotonic
        branch, so strong barrel distortion cannot send it onto the wrong branch), then Newton steps with the
        analytic Jacobian (halved where a full step does not reduce the residual) for the tangential and
        thin-prism terms. Fisheye: the angle is solved in 1-D. Points with no inverse (past the fold of the
        distortion polynomial, or a fisheye angle of 90 degrees or more) or that do not converge are NaN.
        """
        xyd = np.asarray(xyd, float).reshape(-1, 2)
        rd = np.hypot(xyd[:, 0], xyd[:, 1])
        nonzero = rd > 1e-300
        if self.model == "fisheye":
            theta = self._fisheye_theta(rd)
            with np.errstate(invalid="ignore", divide="ignore"):
                ok = theta < np.pi / 2 - 1e-12
                scale = np.where(nonzero, np.tan(np.where(ok, theta, 0.0)) / np.where(nonzero, rd, 1.0), 1.0)
            xy = xyd * scale[:, None]
            xy[~ok] = np.nan
            return xy
        r0 = self._invert_radius(rd)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(nonzero, r0 / np.where(nonzero, rd, 1.0), 1.0)
        xy = xyd * scale[:, None]
        f = self.distort(xy) - xyd
        err = np.hypot(f[:, 0], f[:, 1])
        tol = 1e-15 * np.maximum(1.0, rd)
        active = np.flatnonzero(np.isfinite(err) & (err > tol))
        for _ in range(max(int(iterations), 1)):
            if active.size == 0:
                break
            p, fp, e0 = xy[active], f[active], err[active]
            j00, j01, j10, j11 = self._distort_jacobian(p)
            det = j00 * j11 - j01 * j10
            det = np.where(np.abs(det) < 1e-300, 1e-300, det)
            step = np.stack([(j11 * fp[:, 0] - j01 * fp[:, 1]) / det, (-j10 * fp[:, 0] + j00 * fp[:, 1]) / det], axis=1)
            cand = p - step
            fc = self.distort(cand) - xyd[active]
            ec = np.hypot(fc[:, 0], fc[:, 1])
            lam = 1.0
            worse = ~(ec < e0)
            for _half in range(8):  # step halving where the full step does not help
                if not worse.any():
                    break
                lam *= 0.5
                sub = np.flatnonzero(worse)
                c2 = p[sub] - lam * step[sub]
                f2 = self.distort(c2) - xyd[active[sub]]
                e2 = np.hypot(f2[:, 0], f2[:, 1])
                better = e2 < e0[sub]
                cand[sub[better]], fc[sub[better]], ec[sub[better]] = c2[better], f2[better], e2[better]
                worse[sub[better]] = False
            improved = ~worse
            idx = active[improved]
            xy[idx], f[idx], err[idx] = cand[improved], fc[improved], ec[improved]
            # points that cannot improve any more have reached rounding level (or are stuck: judged below)
            active = idx[err[idx] > tol[idx]]
        bad = ~(err <= 1e-10 * np.maximum(1.0, rd))
        xy[bad] = np.nan
        return xy

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Pixels (N,2) -> unit rays (N,3) in the camera frame (NaN rows for pixels no ray maps to).

        Fisheye rays may point more than 90 degrees off axis (z <= 0) when the lens sees that far."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        Kinv = np.linalg.inv(self.K)
        xyd = uv @ Kinv[:2, :2].T + Kinv[:2, 2]
        if self.model == "fisheye":
            theta_d = np.hypot(xyd[:, 0], xyd[:, 1])
            theta = self._fisheye_theta(theta_d)
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.where(theta_d > 1e-300, np.sin(theta) / np.where(theta_d > 1e-300, theta_d, 1.0), 1.0)
            return np.concatenate([xyd * s[:, None], np.cos(theta)[:, None]], axis=1)
        xy = self.undistort(xyd)
        rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    # --- projection ------------------------------------------------------------------------------------------
    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points (N,3) -> pixels (N,2) and a validity mask (in front of the camera, finite).

        Points behind the camera get NaN pixels and ``valid=False``. Use :meth:`in_image` to test the image bounds.
        """
        p = np.asarray(points_cam, float).reshape(-1, 3)
        z = p[:, 2]
        valid = z > 1e-9
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p[:, :2] / np.where(valid, z, np.nan)[:, None]
        xyd = self.distort(xy)
        uv = xyd @ self.K[:2, :2].T + self.K[:2, 2]
        valid &= np.all(np.isfinite(uv), axis=1)
        return uv, valid

    def project_from(self, T_cam_x: np.ndarray, points_x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Project points given in frame x: returns (uv, valid, depth z in the camera frame)."""
        T = np.asarray(T_cam_x, float)
        p_cam = np.asarray(points_x, float) @ T[:3, :3].T + T[:3, 3]
        uv, valid = self.project(p_cam)
        return uv, valid, p_cam[:, 2]

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Mask of pixels inside the image (pixel centres at integers, so the edge is at -0.5 / size-0.5)."""
        uv = np.asarray(uv, float)
        w, h = self.image_size
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= -0.5 + margin)
                & (uv[:, 0] <= w - 0.5 - margin)
                & (uv[:, 1] >= -0.5 + margin)
                & (uv[:, 1] <= h - 0.5 - margin)
            )

    def scaled(self, factor: float) -> "Camera":
        """The same lens at ``factor`` times the resolution (for pyramids/supersampling)."""
        K = self.K.copy()
        K[:2] *= factor
        K[0, 2] = (self.cx + 0.5) * factor - 0.5
        K[1, 2] = (self.cy + 0.5) * factor - 0.5
        size = (int(round(self.width * factor)), int(round(self.height * factor)))
        return Camera(size, K, self.dist.copy(), self.model)
