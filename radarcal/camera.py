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
        if not (np.all(np.isfinite(self.K)) and np.all(np.isfinite(self.dist))):
            return "K/dist: non-finite value"
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

    def undistort(self, xyd: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Inverse of :meth:`distort` by Newton iterations (vectorised, numeric 2x2 Jacobian)."""
        xyd = np.asarray(xyd, float)
        xy = xyd.copy()
        eps = 1e-7
        for _ in range(iterations):
            f = self.distort(xy) - xyd
            if np.nanmax(np.abs(f), initial=0.0) < 1e-14:
                break
            jx = (self.distort(xy + [eps, 0]) - self.distort(xy - [eps, 0])) / (2 * eps)
            jy = (self.distort(xy + [0, eps]) - self.distort(xy - [0, eps])) / (2 * eps)
            det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
            det = np.where(np.abs(det) < 1e-12, 1e-12, det)
            dx = (jy[:, 1] * f[:, 0] - jy[:, 0] * f[:, 1]) / det
            dy = (-jx[:, 1] * f[:, 0] + jx[:, 0] * f[:, 1]) / det
            xy = xy - np.stack([dx, dy], axis=1)
        return xy

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

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Pixels (N,2) -> unit rays (N,3) in the camera frame."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        Kinv = np.linalg.inv(self.K)
        xyd = uv @ Kinv[:2, :2].T + Kinv[:2, 2]
        xy = self.undistort(xyd)
        rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

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
