"""Calibration-target images with known truth: chessboard and ChArUco rendered through a distorted camera.

Pure numeric core (arrays in, arrays out; no printing, no file I/O except the set writer :func:`write_board_set`
and its reader :func:`load_board_truth`). Rendering is by *inverse mapping*: every output pixel is unprojected through :class:`radarcal.camera.Camera`
(radtan 5/8 or fisheye), the ray is intersected with the board plane and the board's reflectance is looked up there,
averaged over sub-pixel samples. Pixel centres are at integer coordinates, so pixel ``(u, v)`` covers
``[u-0.5, u+0.5] x [v-0.5, v+0.5]`` and its sub-samples are spread symmetrically over that square.

Board model and frame: :class:`radarcal.board.BoardSpec` and :func:`radarcal.board.object_points` (OpenCV's
object-point convention; re-exported here, ``board_object_points`` is the same function). A spec with
``legacy=None`` is rendered with the new (OpenCV >= 4.6) ChArUco layout.

Speed: the per-camera ray grid (one exact ray per pixel plus its derivatives along u and v, used for the
sub-samples by a first-order expansion whose error is < 1e-4 px) is computed once and reused for every view; only
pixels whose 3x3 neighbourhood is not uniform are supersampled, on a Fibonacci lattice of >= S*S points.
"""

from __future__ import annotations

import json
import os
import zlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from radarcal.board import BoardSpec, object_points
from radarcal.camera import Camera
from radarcal.geometry import invert_T, rotvec_to_R

__all__ = [
    "BoardSpec",
    "RenderSettings",
    "BoardRenderer",
    "BoardView",
    "board_object_points",
    "default_camera",
    "default_stereo_camera",
    "bow_warp",
    "bad_view_amplitude",
    "plan_views",
    "render_board",
    "render_blank",
    "board_truth_pixels",
    "write_board_set",
    "video_trajectory",
    "load_board_truth",
    "BoardTruth",
    "TRUTH_FORMAT",
]

TRUTH_FORMAT = "radarcal-synth-board/1"
_TEXELS_PER_SQUARE = 120  # ChArUco texture resolution; square edges fall exactly on texel boundaries


# ------------------------------------------------------------------------------------------------------------------
# board geometry: radarcal.board (BoardSpec, object_points) is the one definition; the old names are re-exported
# ------------------------------------------------------------------------------------------------------------------
board_object_points = object_points  # the same function, under the name this module has always exported


def _board_texture(spec: BoardSpec) -> np.ndarray | None:
    """ChArUco texture in [0, 1] (texel (i, j) covers board [i, i+1) x [j, j+1) * square / texels-per-square)."""
    if spec.kind != "charuco":
        return None
    n = _TEXELS_PER_SQUARE
    img = spec.cv_board().generateImage((spec.squares_x * n, spec.squares_y * n), marginSize=0, borderBits=1)
    return (img.astype(np.float32) / 255.0)


def _reflectance(spec: BoardSpec, texture: np.ndarray | None, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Board reflectance at board-frame points: 0 black .. 1 white, -1 where the point is off the paper."""
    x0, y0, x1, y1 = spec.squares_extent
    m = spec.paper_margin
    on_paper = (X >= x0 - m) & (X < x1 + m) & (Y >= y0 - m) & (Y < y1 + m)
    in_squares = (X >= x0) & (X < x1) & (Y >= y0) & (Y < y1)
    out = np.where(on_paper, 1.0, -1.0).astype(np.float32)
    if texture is None:
        i = np.floor((X[in_squares] - x0) / spec.square)
        j = np.floor((Y[in_squares] - y0) / spec.square)
        black = ((i + j) % 2) == 0  # the top-left outer square is black (as OpenCV's pattern.png)
        out[in_squares] = np.where(black, 0.0, 1.0)
    else:
        n = _TEXELS_PER_SQUARE
        ti = np.clip(np.floor((X[in_squares] - x0) / spec.square * n).astype(np.int64), 0, texture.shape[1] - 1)
        tj = np.clip(np.floor((Y[in_squares] - y0) / spec.square * n).astype(np.int64), 0, texture.shape[0] - 1)
        out[in_squares] = texture[tj, ti]
    return out


# ------------------------------------------------------------------------------------------------------------------
# cameras
# ------------------------------------------------------------------------------------------------------------------
def default_camera(model: str = "pinhole5", image_size: tuple[int, int] = (1280, 1024), fisheye_fov_deg: float = 190.0) -> Camera:
    """A plausible camera for a synthetic set.

    pinhole5: fx = 0.78 * width (1000 px at 1280x1024), principal point a few px off-centre, mild radtan distortion.
    pinhole8: same K, stronger rational (k1..k6) distortion. fisheye: equidistant lens whose ``fisheye_fov_deg``
    image circle spans the image height.
    """
    w, h = int(image_size[0]), int(image_size[1])
    cx, cy = (w - 1) / 2 + 0.0031 * w, (h - 1) / 2 - 0.0025 * h
    if model in ("pinhole5", "pinhole8"):
        f = 0.78 * w
        K = [[f, 0, cx], [0, f * 1.0008, cy], [0, 0, 1]]
        if model == "pinhole5":
            dist = [-0.11, 0.075, 0.0004, -0.0003, -0.018]
        else:
            dist = [0.05, -0.005, 0.0004, -0.0003, 0.0005, 0.3, 0.002, 0.0]
        return Camera((w, h), K, dist, "pinhole")
    if model == "fisheye":
        dist = np.array([0.02, -0.006, 0.001, -0.0002])
        th = np.radians(fisheye_fov_deg / 2)
        th2 = th * th
        theta_d = th * (1 + th2 * (dist[0] + th2 * (dist[1] + th2 * (dist[2] + th2 * dist[3]))))
        f = (min(w, h) / 2 - 2) / theta_d
        return Camera((w, h), [[f, 0, cx], [0, f, cy], [0, 0, 1]], dist, "fisheye")
    raise ValueError(f"model: expected pinhole5, pinhole8 or fisheye, got {model!r}")


def default_stereo_camera(camera: Camera, baseline: float) -> tuple[Camera, np.ndarray]:
    """A second camera of the same kind ``baseline`` metres to the right of ``camera``: (camera1, T_cam1_cam0).

    Slightly different intrinsics (fx +0.3 %, principal point moved by a few px, distortion x 0.9) and a slightly
    convergent mounting (yaw 1.5 deg towards camera 0, pitch 0.2 deg, roll 0.3 deg).
    """
    K = camera.K.copy()
    K[0, 0] *= 1.003
    K[1, 1] *= 1.0025
    K[0, 2] += 0.0041 * camera.width
    K[1, 2] -= 0.0030 * camera.height
    cam1 = Camera(camera.image_size, K, camera.dist * 0.9, camera.model)
    R = rotvec_to_R(np.radians([0.2, -1.5, 0.3]))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.array([float(baseline), 0.0, 0.0])  # camera 1's centre sits at x = +baseline in camera 0
    return cam1, T


def model_name(camera: Camera) -> str:
    """``pinhole5`` / ``pinhole8`` / ``fisheye`` / ``pinhole<n>`` for a camera."""
    return "fisheye" if camera.model == "fisheye" else f"pinhole{camera.dist.size}"


# ------------------------------------------------------------------------------------------------------------------
# rendering
# ------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RenderSettings:
    """Photometry of a rendered view (grey levels on the 0..255 scale).

    blur_sigma: Gaussian blur sigma in px (optics), noise_sigma: Gaussian sensor noise sigma in grey levels
    (before 8-bit rounding), vignetting: relative darkening at the image corner (``1 - v * (r/r_corner)^2``),
    black/white: board print levels, background: mean scene level, supersample: sub-samples per pixel axis.
    """

    supersample: int = 4
    blur_sigma: float = 0.6
    noise_sigma: float = 0.5
    vignetting: float = 0.25
    black: float = 28.0
    white: float = 218.0
    background: float = 95.0
    fisheye_fov_deg: float = 190.0

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass
class _RayGrid:
    rays: np.ndarray  # (h, w, 3) ray of each pixel centre (pinhole: (x, y, 1); fisheye: unit vector, may look backwards)
    drays_du: np.ndarray  # (h, w, 3) d ray / d u (per pixel)
    drays_dv: np.ndarray  # (h, w, 3)
    valid: np.ndarray  # (h, w) bool: exact ray, neighbours valid too
    lens: np.ndarray  # (h, w) float32 in [0, 1]: pixel area inside the lens' image circle (all 1 for pinhole)


def _unproject_grid(camera: Camera, step: int = 8, tol: float = 1e-13, max_iter: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalised coordinates (h, w, 2) of every pixel centre and a convergence mask (h, w).

    ``Camera.unproject`` (exact) on a coarse grid every ``step`` px, bilinear interpolation to every pixel, then
    chord-Newton iterations ``xy -= J^-1 (camera.distort(xy) - xyd)`` with the interpolated inverse Jacobian:
    the same answer as ``Camera.unproject`` per pixel (|residual| < 1e-13) at a fraction of the cost.
    """
    import cv2

    w, h = camera.image_size
    us = np.unique(np.r_[np.arange(0, w, step), w - 1]).astype(float)
    vs = np.unique(np.r_[np.arange(0, h, step), h - 1]).astype(float)
    cu, cv_ = np.meshgrid(us, vs)
    rays = camera.unproject(np.stack([cu.ravel(), cv_.ravel()], axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        coarse = (rays[:, :2] / rays[:, 2:3]).reshape(len(vs), len(us), 2)
    coarse = np.where(np.isfinite(coarse), coarse, 0.0)
    # bilinear interpolation of the coarse grid at every pixel (coarse spacing is uniform except the last cell)
    fu = np.interp(np.arange(w, dtype=float), us, np.arange(len(us), dtype=float)).astype(np.float32)
    fv = np.interp(np.arange(h, dtype=float), vs, np.arange(len(vs), dtype=float)).astype(np.float32)
    mu, mv = np.meshgrid(fu, fv)
    xy = np.stack([cv2.remap(coarse[..., i].astype(np.float64), mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                   for i in range(2)], axis=-1).reshape(-1, 2)
    # inverse Jacobian d(xy)/d(xyd) = d(xy)/d(uv) @ d(uv)/d(xyd)
    J = np.stack([np.gradient(xy.reshape(h, w, 2), axis=1), np.gradient(xy.reshape(h, w, 2), axis=0)], axis=-1).reshape(-1, 2, 2)
    J = J @ camera.K[:2, :2]
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    Kinv = np.linalg.inv(camera.K)
    xyd = uv @ Kinv[:2, :2].T + Kinv[:2, 2]
    active = np.arange(len(xy))
    sub_xy, sub_xyd, sub_J = xy[active], xyd[active], J[active]
    with np.errstate(all="ignore"):
        for _ in range(max_iter):
            f = camera.distort(sub_xy) - sub_xyd
            if not np.nanmax(np.abs(f), initial=0.0) >= tol:
                break
            sub_xy -= np.einsum("nij,nj->ni", sub_J, f)
        err = np.abs(camera.distort(sub_xy) - sub_xyd).max(axis=1)
    ok = np.zeros(len(xy), bool)
    ok[active] = err < 1e-11
    xy[active] = sub_xy
    return xy.reshape(h, w, 2), ok.reshape(h, w)


def _fisheye_rays(camera: Camera, max_theta: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (h, w, 3) of an equidistant fisheye for every pixel, also beyond 90 deg, and a validity mask.

    ``Camera.unproject`` goes through normalised coordinates (z = 1) and so stops short of 90 deg; a 190 deg lens
    needs the polar form: theta from theta_d = |K^-1 uv| by Newton on theta (1 + k1 theta^2 + ... + k4 theta^8),
    ray = (sin theta * xyd / theta_d, cos theta). Agrees with ``Camera.project`` wherever that is defined.
    """
    w, h = camera.image_size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    Kinv = np.linalg.inv(camera.K)
    xyd = np.stack([u, v], axis=-1) @ Kinv[:2, :2].T + Kinv[:2, 2]
    td = np.linalg.norm(xyd, axis=-1)
    k1, k2, k3, k4 = camera.dist
    th = td.copy()
    for _ in range(30):
        t2 = th * th
        g = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - td
        dg = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        th = th - g / np.where(np.abs(dg) > 1e-9, dg, 1e-9)
    t2 = th * th
    g = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - td
    dg = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
    ok = (np.abs(g) < 1e-12) & (dg > 0) & (th >= 0) & (th <= max_theta)
    scale = np.where(td > 1e-15, np.sin(th) / np.where(td > 1e-15, td, 1.0), 1.0)
    rays = np.concatenate([xyd * scale[..., None], np.cos(th)[..., None]], axis=-1)
    return np.where(ok[..., None], rays, 0.0), ok


def _ray_grid(camera: Camera, fisheye_fov_deg: float) -> _RayGrid:
    w, h = camera.image_size
    lens = np.ones((h, w), np.float32)
    if camera.model == "fisheye":
        th = np.radians(fisheye_fov_deg / 2)
        rays, ok = _fisheye_rays(camera, th + np.radians(3.0))
        d, t2 = camera.dist, th * th
        theta_d = th * (1 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))
        u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        Kinv = np.linalg.inv(camera.K)
        r_d = np.linalg.norm(np.stack([u, v], axis=-1) @ Kinv[:2, :2].T + Kinv[:2, 2], axis=-1)
        f = 0.5 * (camera.fx + camera.fy)
        lens = np.clip(0.5 + (theta_d - r_d) * f, 0.0, 1.0).astype(np.float32)  # anti-aliased circle edge
    else:
        xy, ok = _unproject_grid(camera)
        xy = np.where(ok[..., None], xy, 0.0)
        rays = np.concatenate([xy, np.ones((h, w, 1))], axis=-1)
    # central differences (one-sided at the border); a pixel is usable only when its neighbours are valid too
    drays_du = np.gradient(rays, axis=1)
    drays_dv = np.gradient(rays, axis=0)
    good = ok.copy()
    good[:, 1:] &= ok[:, :-1]
    good[:, :-1] &= ok[:, 1:]
    good[1:, :] &= ok[:-1, :]
    good[:-1, :] &= ok[1:, :]
    return _RayGrid(rays, drays_du, drays_dv, good, lens)


def bow_warp(spec: BoardSpec, amplitude: float) -> "callable":
    """A printed-pattern defect for an outlier view: the pattern bows along y by ``amplitude`` metres.

    Returns ``d(X, Y) -> (dX, dY)``: the pattern point printed (nominally) at ``(X, Y)`` appears at
    ``(X + dX, Y + dY)``. The bow is zero at the board's left/right edges and ``amplitude`` in the middle column.
    """
    x0, _, x1, _ = spec.squares_extent
    xm, half = (x0 + x1) / 2, (x1 - x0) / 2

    def d(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = np.clip((X - xm) / half, -1.0, 1.0)
        return np.zeros_like(X), amplitude * (1.0 - s * s)

    return d


def bad_view_amplitude(camera: Camera, spec: BoardSpec, T_cam_board: np.ndarray, max_px: float) -> float:
    """The :func:`bow_warp` amplitude (metres) that moves this view's corners by at most ``max_px`` pixels."""
    uv, _ = board_truth_pixels(camera, spec, T_cam_board)
    amp = 0.01 * spec.square
    for _ in range(3):  # displacement is nearly linear in the amplitude
        uv_a, _ = board_truth_pixels(camera, spec, T_cam_board, warp=bow_warp(spec, amp))
        disp = float(np.nanmax(np.linalg.norm(uv_a - uv, axis=1)))
        amp *= max_px / max(disp, 1e-12)
    return amp


def _invert_warp(warp, X: np.ndarray, Y: np.ndarray, iterations: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Pattern coordinates (c) whose printed point appears at (X, Y): solve c + d(c) = (X, Y) by fixed point."""
    cx, cy = X.copy(), Y.copy()
    for _ in range(iterations):
        dx, dy = warp(cx, cy)
        cx, cy = X - dx, Y - dy
    return cx, cy


def _sample_offsets(S: int) -> np.ndarray:
    """Sub-pixel sample offsets in [-0.5, 0.5)^2: a Fibonacci lattice of at least S*S points.

    Unlike a regular S x S grid, every sample has its own x and its own y offset, so an edge parallel to the pixel
    grid is resolved in N = len(offsets) coverage steps instead of S (a regular grid quantises such edges to 1/S px).
    """
    a, b = 1, 2
    while b < S * S:
        a, b = b, a + b
    k = np.arange(b)
    return np.stack([(k + 0.5) / b - 0.5, ((k * a) % b + 0.5) / b - 0.5], axis=1)


class BoardRenderer:
    """Renders one board through one camera; the per-camera ray grid is computed once and reused."""

    def __init__(self, camera: Camera, spec: BoardSpec, settings: RenderSettings = RenderSettings()):
        self.camera = camera
        self.spec = spec
        self.settings = settings
        self._grid: _RayGrid | None = None
        self._texture = _board_texture(spec)
        self._bg: np.ndarray | None = None

    @property
    def grid(self) -> _RayGrid:
        if self._grid is None:
            self._grid = _ray_grid(self.camera, self.settings.fisheye_fov_deg)
        return self._grid

    def background(self) -> np.ndarray:
        """Smooth, corner-free background radiance (h, w) float32 (grey levels)."""
        if self._bg is None:
            w, h = self.camera.image_size
            u = np.arange(w, dtype=np.float32)[None, :] / w
            v = np.arange(h, dtype=np.float32)[:, None] / h
            bg = self.settings.background * (1.0 + 0.18 * np.sin(2.1 * u + 0.7) * np.cos(1.7 * v - 0.4) + 0.08 * (v - 0.5))
            self._bg = bg.astype(np.float32)
        return self._bg

    def coverage(self, T_cam_board: np.ndarray, warp=None) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free, blur-free board image: (reflectance sum image, board coverage fraction), both (h, w) float32.

        ``radiance = refl + (1 - frac) * background`` where ``refl`` is the mean over sub-samples of the board
        reflectance (0..1, zero where the sample misses the paper) and ``frac`` the fraction of sub-samples on
        the paper.
        """
        g = self.grid
        T = np.asarray(T_cam_board, float)
        R, t = T[:3, :3], T[:3, 3]
        H = np.column_stack([R[:, 0], R[:, 1], t])  # normalised image point ~ H @ [X, Y, 1]
        Hinv = np.linalg.inv(H)

        def sample(rx, ry, rz, valid):
            # ray d ~ lambda H [X, Y, 1]  =>  Hinv d = lambda [X, Y, 1]; the board is hit in front iff lambda > 0
            q0 = Hinv[0, 0] * rx + Hinv[0, 1] * ry + Hinv[0, 2] * rz
            q1 = Hinv[1, 0] * rx + Hinv[1, 1] * ry + Hinv[1, 2] * rz
            q2 = Hinv[2, 0] * rx + Hinv[2, 1] * ry + Hinv[2, 2] * rz
            front = valid & (q2 > 1e-12)
            with np.errstate(divide="ignore", invalid="ignore"):
                X = np.where(front, q0 / np.where(front, q2, 1.0), np.inf)
                Y = np.where(front, q1 / np.where(front, q2, 1.0), np.inf)
            if warp is not None:
                fin = np.isfinite(X)
                X[fin], Y[fin] = _invert_warp(warp, X[fin], Y[fin])
            return _reflectance(self.spec, self._texture, X, Y)

        # pass 1: one sample at each pixel centre
        centre = sample(g.rays[..., 0], g.rays[..., 1], g.rays[..., 2], g.valid)
        refl = np.maximum(centre, 0.0)
        frac = (centre >= 0).astype(np.float32)
        # pass 2: supersample the pixels whose 3x3 neighbourhood is not uniform
        import cv2

        k = np.ones((3, 3), np.uint8)
        c = centre.astype(np.float32)
        busy = (cv2.dilate(c, k) != cv2.erode(c, k))
        busy |= (cv2.erode(g.valid.astype(np.uint8), k) == 0) & (cv2.dilate(g.valid.astype(np.uint8), k) == 1)
        rows, cols = np.nonzero(busy)
        S = max(1, int(self.settings.supersample))
        if rows.size and S > 1:
            r0 = g.rays[rows, cols]
            ru = g.drays_du[rows, cols]
            rv = g.drays_dv[rows, cols]
            val = g.valid[rows, cols]
            acc = np.zeros(rows.size, np.float32)
            hit = np.zeros(rows.size, np.float32)
            offsets = _sample_offsets(S)
            for du, dv in offsets:
                ray = r0 + ru * du + rv * dv
                r = sample(ray[:, 0], ray[:, 1], ray[:, 2], val)
                acc += np.maximum(r, 0.0)
                hit += r >= 0
            refl[rows, cols] = acc / len(offsets)
            frac[rows, cols] = hit / len(offsets)
        return refl.astype(np.float32), frac

    def radiance(self, T_cam_board: np.ndarray | None, warp=None, gain: float = 1.0) -> np.ndarray:
        """Noise-free image in grey levels (float32, before blur/vignetting/noise); None pose = no board."""
        s = self.settings
        bg = self.background()
        if T_cam_board is None:
            img = bg.copy()
        else:
            refl, frac = self.coverage(T_cam_board, warp)
            img = (s.black * frac + (s.white - s.black) * refl) + (1.0 - frac) * bg
        img = img * np.float32(gain)
        if self.camera.model == "fisheye":
            lens = self.grid.lens
            img = lens * img + (1.0 - lens) * np.float32(4.0)
        return img.astype(np.float32)

    def finish(self, radiance: np.ndarray, rng: np.random.Generator, blur_sigma: float | None = None,
               motion_blur_px: float = 0.0, motion_angle: float = 0.0) -> np.ndarray:
        """Optics and sensor: [motion blur], blur, vignetting, noise, 8-bit rounding -> uint8 (h, w).

        ``motion_blur_px``: length of a straight motion streak at ``motion_angle`` (radians from the image x axis),
        symmetric about the pixel so that it smears but does not shift the corners.
        """
        import cv2

        s = self.settings
        img = radiance.astype(np.float32)
        sigma = s.blur_sigma if blur_sigma is None else blur_sigma
        if motion_blur_px > 0:
            L = int(np.ceil(motion_blur_px)) | 1
            t = np.linspace(-0.5, 0.5, 8 * L) * motion_blur_px
            kern = np.zeros((L, L), np.float32)
            np.add.at(kern, (np.rint(L // 2 + t * np.sin(motion_angle)).astype(int),
                             np.rint(L // 2 + t * np.cos(motion_angle)).astype(int)), 1.0)
            kern = 0.5 * (kern + kern[::-1, ::-1])  # exactly point-symmetric: no shift
            img = cv2.filter2D(img, -1, kern / kern.sum(), borderType=cv2.BORDER_REFLECT)
        if sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
        if s.vignetting:
            w, h = self.camera.image_size
            cx, cy = self.camera.cx, self.camera.cy
            u = (np.arange(w, dtype=np.float32)[None, :] - cx) ** 2
            v = (np.arange(h, dtype=np.float32)[:, None] - cy) ** 2
            r2max = max(cx, w - 1 - cx) ** 2 + max(cy, h - 1 - cy) ** 2
            img = img * (1.0 - np.float32(s.vignetting) * (u + v) / np.float32(r2max))
        if s.noise_sigma > 0:
            img = img + rng.standard_normal(img.shape, dtype=np.float32) * np.float32(s.noise_sigma)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def render(self, T_cam_board: np.ndarray | None, rng: np.random.Generator, warp=None, gain: float = 1.0,
               motion_blur_px: float = 0.0, motion_angle: float = 0.0) -> np.ndarray:
        """Full image (uint8, h x w) of the board at ``T_cam_board`` (None: no board in view)."""
        return self.finish(self.radiance(T_cam_board, warp, gain), rng, motion_blur_px=motion_blur_px, motion_angle=motion_angle)


def render_board(camera: Camera, spec: BoardSpec, T_cam_board: np.ndarray, settings: RenderSettings = RenderSettings(),
                 seed: int = 0) -> np.ndarray:
    """One-shot render (uint8 gray image). For many views of the same camera use :class:`BoardRenderer`."""
    return BoardRenderer(camera, spec, settings).render(T_cam_board, np.random.default_rng(seed))


def render_blank(renderer: BoardRenderer, rng: np.random.Generator) -> np.ndarray:
    """A frame without a board: the background plus a few plain grey rectangles (clutter without corners grids)."""
    import cv2

    img = renderer.radiance(None).copy()
    w, h = renderer.camera.image_size
    for _ in range(3):
        x0, y0 = int(rng.uniform(0, w * 0.8)), int(rng.uniform(0, h * 0.8))
        x1, y1 = x0 + int(rng.uniform(0.05, 0.2) * w), y0 + int(rng.uniform(0.05, 0.2) * h)
        cv2.rectangle(img, (x0, y0), (x1, y1), float(rng.uniform(40, 200)), thickness=-1)
    return renderer.finish(img, rng)


def board_truth_pixels(camera: Camera, spec: BoardSpec, T_cam_board: np.ndarray, warp=None,
                       margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """True pixels (N,2) of the board's inner corners (NaN when behind the camera) and their visibility mask.

    With ``warp`` (see :func:`bow_warp`) the corners are where the defective print really puts them.
    Visible = in front of the camera (z > 0, so < 90 deg off-axis for a fisheye) and inside the image by ``margin`` px.
    """
    p = board_object_points(spec)
    if warp is not None:
        dx, dy = warp(p[:, 0], p[:, 1])
        p = p + np.stack([dx, dy, np.zeros_like(dx)], axis=1)
    uv, valid, z = camera.project_from(T_cam_board, p)
    uv = np.where(valid[:, None], uv, np.nan)
    vis = valid & camera.in_image(uv, margin)
    return uv, vis


# ------------------------------------------------------------------------------------------------------------------
# view planning
# ------------------------------------------------------------------------------------------------------------------
@dataclass
class BoardView:
    """One planned image of a set: kind in full | partial | bad | blurred | blank | corrupt."""

    kind: str
    T_cam_board: np.ndarray | None
    gain: float = 1.0


def _rot(axis, angle: float) -> np.ndarray:
    return rotvec_to_R(np.asarray(axis, float) * angle)


def _align_z(d: np.ndarray) -> np.ndarray:
    """A rotation taking +z onto the unit vector d (minimal rotation)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, d)
    s = np.linalg.norm(axis)
    if s < 1e-12:
        return np.eye(3)
    return _rot(axis / s, np.arctan2(s, z @ d))


def _outline(spec: BoardSpec, grow: float = 0.0) -> np.ndarray:
    x0, y0, x1, y1 = spec.squares_extent
    xs = np.linspace(x0 - grow, x1 + grow, 9)
    ys = np.linspace(y0 - grow, y1 + grow, 9)
    pts = [(x, y0 - grow) for x in xs] + [(x, y1 + grow) for x in xs] + [(x0 - grow, y) for y in ys] + [(x1 + grow, y) for y in ys]
    return np.array([[x, y, 0.0] for x, y in pts])


def _pose(camera: Camera, spec: BoardSpec, centre_uv, distance, tilt_x, tilt_y, roll) -> np.ndarray:
    ray = camera.unproject(np.asarray(centre_uv, float).reshape(1, 2))[0]
    R = _align_z(ray) @ _rot([1, 0, 0], tilt_x) @ _rot([0, 1, 0], tilt_y) @ _rot([0, 0, 1], roll)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = ray * distance - R @ spec.centre
    return T


def _check_full(camera: Camera, spec: BoardSpec, T: np.ndarray, min_square_px: float) -> bool:
    uv, vis = board_truth_pixels(camera, spec, T)
    if not vis.all():
        return False
    out, ok, z = camera.project_from(T, _outline(spec, 0.35 * spec.square))
    w, h = camera.image_size
    if not (ok.all() and camera.in_image(out, margin=3.0).all()):
        return False
    if camera.model == "fisheye":
        p_cam = _outline(spec, 0.35 * spec.square) @ T[:3, :3].T + T[:3, 3]
        if np.any(p_cam[:, 2] / np.linalg.norm(p_cam, axis=1) < np.cos(np.radians(80.0))):
            return False
    grid = uv.reshape(spec.corners_y, spec.corners_x, 2)
    gaps = []
    if spec.corners_x > 1:
        gaps.append(np.linalg.norm(np.diff(grid, axis=1), axis=2).min())
    if spec.corners_y > 1:
        gaps.append(np.linalg.norm(np.diff(grid, axis=0), axis=2).min())
    # the board must face the camera reasonably (detectors fail at grazing angles)
    n = T[:3, 2]
    c = T[:3, :3] @ spec.centre + T[:3, 3]
    facing = n @ (c / np.linalg.norm(c))
    return min(gaps) >= min_square_px and facing > np.cos(np.radians(62.0))


def plan_views(camera: Camera, spec: BoardSpec, n_views: int, rng: np.random.Generator, coverage: str = "full",
               n_partial: int = 2, n_bad: int = 0, max_tilt_deg: float = 45.0, n_blurred: int = 0,
               also_full_in: tuple[Camera, np.ndarray] | None = None) -> list[BoardView]:
    """Board poses for a set of ``n_views`` board images (``n_partial`` partly outside, ``n_bad`` outliers,
    ``n_blurred`` to be rendered with motion blur; the last two are placed like full views).

    ``also_full_in=(camera1, T_cam1_cam0)``: every non-partial view must also be fully visible in a second camera
    (stereo sets); partial views are partial in ``camera``.

    coverage ``"full"``: board centres stratified over the whole image, tilts up to ``max_tilt_deg`` about the
    board's x and y axes, sizes 30-75 % of the image diagonal. ``"poor"``: small, mildly tilted boards in the
    upper-left part of the image only (a set that should trigger coverage warnings).
    """
    if coverage not in ("full", "poor"):
        raise ValueError(f"coverage: expected full or poor, got {coverage!r}")
    w, h = camera.image_size
    diag = float(np.hypot(w, h))
    x0, y0, x1, y1 = spec.squares_extent
    board_diag = float(np.hypot(x1 - x0, y1 - y0))
    f = 0.5 * (camera.fx + camera.fy)
    n_partial = min(n_partial, n_views)
    n_bad = min(n_bad, n_views - n_partial)
    n_blurred = min(n_blurred, n_views - n_partial - n_bad)
    kinds = ["partial"] * n_partial + ["bad"] * n_bad + ["blurred"] * n_blurred + ["full"] * (n_views - n_partial - n_bad - n_blurred)
    kinds = [kinds[i] for i in rng.permutation(len(kinds))]
    # stratified centres for full views: a shuffled k x k grid of cells, jittered inside the cell
    k = max(2, int(np.ceil(np.sqrt(max(1, n_views)))))
    cells = [(i, j) for i in range(k) for j in range(k)]
    order = rng.permutation(len(cells))
    views: list[BoardView] = []
    min_sq = 9.0
    max_tilt = np.radians(max_tilt_deg)
    for idx, kind in enumerate(kinds):
        T = None
        for attempt in range(400):
            shrink = min(1.0, attempt / 200)  # give up on extreme choices gradually
            if kind == "partial":
                side = rng.integers(4)
                t = rng.uniform(0.2, 0.8)
                edge = [(t * w, 0), (t * w, h), (0, t * h), (w, t * h)][side]
                centre = np.array(edge) * 0.85 + np.array([w / 2, h / 2]) * 0.15
                size = rng.uniform(0.45, 0.7)
                tx, ty, roll = rng.uniform(-0.35, 0.35, 2).tolist() + [rng.uniform(-0.2, 0.2)]
            elif coverage == "poor":
                centre = np.array([rng.uniform(0.22, 0.4) * w, rng.uniform(0.22, 0.4) * h])
                size = rng.uniform(0.22, 0.32)
                tx, ty = rng.uniform(-0.3, 0.3, 2)
                roll = rng.uniform(-0.15, 0.15)
            else:
                ci, cj = cells[order[idx % len(cells)]]
                lo, hi = 0.12 + 0.76 * np.array([ci, cj]) / k, 0.12 + 0.76 * (np.array([ci, cj]) + 1) / k
                cell_uv = rng.uniform(lo, hi)
                cell_uv = cell_uv * (1 - shrink) + 0.5 * shrink * rng.uniform(0.6, 1.4, 2)
                centre = cell_uv * [w, h]
                size = rng.uniform(0.3, 0.75) * (1 - 0.4 * shrink)
                tilt = rng.uniform(0.2, 1.0) * max_tilt * (1 - 0.6 * shrink)
                phi = rng.uniform(0, 2 * np.pi)
                tx, ty = tilt * np.cos(phi), tilt * np.sin(phi)
                roll = rng.uniform(-0.26, 0.26)
            dist = f * board_diag / (size * diag)
            if camera.model == "fisheye":
                dist *= 0.8
            T = _pose(camera, spec, centre, dist, tx, ty, roll)
            if kind == "partial":
                uv, vis = board_truth_pixels(camera, spec, T)
                frac = vis.mean()
                facing = T[:3, 2] @ T[:3, 3] > 0
                if 0.3 <= frac <= 0.8 and facing:
                    break
            elif _check_full(camera, spec, T, min_sq) and (
                    also_full_in is None or _check_full(also_full_in[0], spec, also_full_in[1] @ T, min_sq)):
                break
            T = None
        if T is None:
            raise ValueError(f"cannot place a {spec.corners_x}x{spec.corners_y}-corner board fully inside a {w}x{h} image "
                             f"with corners >= {min_sq:g} px apart (view {idx}, {kind}): use a larger image or fewer corners")
        views.append(BoardView(kind, T, float(rng.uniform(0.9, 1.06))))
    return views


# ------------------------------------------------------------------------------------------------------------------
# the set writer (the only function here that touches files)
# ------------------------------------------------------------------------------------------------------------------
def _nan_to_none(a: np.ndarray) -> list:
    return [[None if not np.isfinite(x) else round(float(x), 6) for x in row] for row in np.asarray(a)]


def write_board_set(out_dir: str | os.PathLike, camera: Camera, spec: BoardSpec, n_views: int = 25, seed: int = 0,
                    settings: RenderSettings = RenderSettings(), coverage: str = "full", n_partial: int = 2,
                    n_blank: int = 2, n_corrupt: int = 1, bad_view: bool = False, bad_px: float = 1.5,
                    n_blurred: int = 0, blur_streak: tuple[float, float] = (0.01, 0.016),
                    stereo: tuple[Camera, np.ndarray] | None = None, video_seconds: float = 0.0, video_fps: float = 10.0,
                    command: str = "", progress=None) -> dict:
    """Write ``n_views`` board PNGs (+ blank and corrupt files) and ``truth.json`` into ``out_dir``; return the truth.

    Deterministic: the same arguments give bit-identical files. The corrupt file is a rendered board PNG
    truncated to a third of its bytes. ``bad_view`` bows the printed pattern of one view (see :func:`bow_warp`) so
    that its corners sit up to ``bad_px`` pixels away from where a flat board would put them. ``n_blurred`` views get
    a motion streak in a random direction, its length drawn from ``blur_streak`` x image width (12.8-20 px at 1280
    px): symmetric, so the true corners do not move, but detections on such views are poor.

    ``stereo=(camera1, T_cam1_cam0)``: every view is also rendered through a second camera; images go to
    ``cam0/img_NNN.png`` and ``cam1/img_NNN.png`` (same name = same instant) and the truth gains a ``stereo`` block
    and ``*_cam1`` keys per view. Mono sets (the default) write ``img_NNN.png`` at the top level.

    ``video_seconds > 0`` also writes ``video.avi`` (MJPG, camera 0): the board moving smoothly through the full
    views' poses, dwelling at each, motion-blurred in proportion to its speed; per-frame truth under ``video``.
    """
    import cv2

    if spec.legacy is None:  # "decide automatically" means nothing to a renderer: it draws the new layout
        spec = replace(spec, legacy=False)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if (out / "truth.json").is_file():  # a previous set lives here: drop its images so no stale file survives
        for pattern in ("img_[0-9][0-9][0-9].png", "cam[01]/img_[0-9][0-9][0-9].png", "video.avi"):
            for old in out.glob(pattern):
                old.unlink()
    prefix0, prefix1 = ("cam0/", "cam1/") if stereo is not None else ("", "")
    for prefix in {prefix0, prefix1} - {""}:
        (out / prefix).mkdir(exist_ok=True)
    root = np.random.SeedSequence(int(seed))
    plan_seed, *view_seeds = root.spawn(1 + n_views + n_blank + n_corrupt)
    rng = np.random.default_rng(plan_seed)
    views = plan_views(camera, spec, n_views, rng, coverage, n_partial=n_partial, n_bad=1 if bad_view else 0,
                       n_blurred=n_blurred, also_full_in=stereo)
    # corrupt files are rendered board views too (then truncated); blanks have no board
    extra_corrupt = plan_views(camera, spec, n_corrupt, rng, coverage, n_partial=0, also_full_in=stereo) if n_corrupt else []
    for v in extra_corrupt:
        v.kind = "corrupt"
    all_views = views + [BoardView("blank", None, float(rng.uniform(0.9, 1.06))) for _ in range(n_blank)] + extra_corrupt
    order = rng.permutation(len(all_views))
    rigs = [(camera, np.eye(4), BoardRenderer(camera, spec, settings), prefix0, "")]
    stereo_seeds: list = []
    if stereo is not None:
        cam1, T_cam1_cam0 = stereo[0], np.asarray(stereo[1], float)
        rigs.append((cam1, T_cam1_cam0, BoardRenderer(cam1, spec, settings), prefix1, "_cam1"))
        stereo_seeds = np.random.SeedSequence([int(seed), 1]).spawn(len(all_views))
    obj = board_object_points(spec)
    entries = []
    iterator = range(len(order)) if progress is None else progress(range(len(order)))
    for i in iterator:
        view = all_views[order[i]]
        name = f"img_{i:03d}.png"
        entry: dict = {"kind": view.kind, "has_board": view.T_cam_board is not None,
                       "readable": view.kind != "corrupt", "gain": round(view.gain, 6)}
        warp, amplitude = None, 0.0
        if view.kind == "bad":
            amplitude = bad_view_amplitude(camera, spec, view.T_cam_board, bad_px)
            warp = bow_warp(spec, amplitude)
            entry["bad_reason"] = f"printed pattern bowed by {amplitude * 1000:.3f} mm along y (not flat)"
            entry["bad_bow_m"] = round(amplitude, 12)
        streak, angle = 0.0, 0.0
        for cam, T_ci_cam0, renderer, prefix, sfx in rigs:
            vrng = np.random.default_rng(view_seeds[order[i]] if not sfx else stereo_seeds[order[i]])
            entry["file" + sfx] = prefix + name
            if view.T_cam_board is None:
                img = render_blank(renderer, vrng)
                entry.update({"T_cam_board" if not sfx else "T_cam1_board": None, "corners_uv" + sfx: None,
                              "visible" + sfx: None, "corner_ids" + sfx: [], "n_visible" + sfx: 0})
            else:
                T = T_ci_cam0 @ view.T_cam_board
                if view.kind == "blurred" and not sfx:
                    streak = float(vrng.uniform(*blur_streak)) * cam.width
                    angle = float(vrng.uniform(0, np.pi))
                    entry.update(motion_blur_px=round(streak, 4), motion_blur_angle_deg=round(np.degrees(angle), 4))
                img = renderer.render(T, vrng, warp=warp, gain=view.gain, motion_blur_px=streak, motion_angle=angle)
                uv, vis = board_truth_pixels(cam, spec, T)
                entry.update({"T_cam_board" if not sfx else "T_cam1_board": np.round(T, 12).tolist(),
                              "corners_uv" + sfx: _nan_to_none(uv), "visible" + sfx: vis.tolist(),
                              "corner_ids" + sfx: np.nonzero(vis)[0].tolist(), "n_visible" + sfx: int(vis.sum())})
                if warp is not None:
                    uv_a, _ = board_truth_pixels(cam, spec, T, warp=warp)
                    entry["corners_uv_actual" + sfx] = _nan_to_none(uv_a)
                    entry["bad_displacement_px_max" + sfx] = round(float(np.nanmax(np.linalg.norm(uv_a - uv, axis=1))), 4)
            ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 3])
            data = buf.tobytes()
            if view.kind == "corrupt":
                data = data[: max(64, len(data) // 3)]
            (out / (prefix + name)).write_bytes(data)
            entry["crc32" + sfx] = format(zlib.crc32(data) & 0xFFFFFFFF, "08x")
        entries.append(_ordered_entry(entry))

    def file_lists(key: str) -> dict:
        kinds = ("full", "partial", "bad", "blurred", "blank", "corrupt")
        lists = {"all": [e[key] for e in entries],
                 "board": [e[key] for e in entries if e["kind"] in ("full", "partial", "bad", "blurred")]}
        lists.update({k: [e[key] for e in entries if e["kind"] == k] for k in kinds})
        return lists

    truth = {
        "format": TRUTH_FORMAT,
        "seed": int(seed),
        "command": command,
        "model": model_name(camera),
        "camera": camera.to_dict(),
        "image_size": list(camera.image_size),
        "K": camera.K.tolist(),
        "dist": camera.dist.tolist(),
        "board": spec.to_dict(),
        "object_points": obj.tolist(),
        "render": settings.to_dict(),
        "noise": {"image_noise_sigma_dn": settings.noise_sigma, "blur_sigma_px": settings.blur_sigma,
                  "vignetting": settings.vignetting, "supersample": settings.supersample},
        "coverage": coverage,
        "files": file_lists("file"),
        "views": entries,
    }
    if video_seconds > 0:
        keyviews = [j for j, v in enumerate(views) if v.kind == "full"] or list(range(len(views)))
        if keyviews:
            file_of = {int(j): entries[i]["file"] for i, j in enumerate(order)}
            truth["video"] = _write_video(out, rigs[0][2], spec, [views[j].T_cam_board for j in keyviews],
                                          video_seconds, video_fps, seed)
            truth["video"]["keyframe_files"] = [file_of[j] for j in keyviews][: len(truth["video"]["keyframes"])]
    if stereo is not None:
        cam1, T10 = rigs[1][0], rigs[1][1]
        truth["stereo"] = {"model1": model_name(cam1), "camera1": cam1.to_dict(), "T_cam1_cam0": np.round(T10, 12).tolist(),
                           "baseline_m": round(float(np.linalg.norm(invert_T(T10)[:3, 3])), 12), "files1": file_lists("file_cam1")}
    tmp = out / "truth.json.tmp"
    tmp.write_text(json.dumps(truth, indent=1) + "\n")
    tmp.replace(out / "truth.json")
    return truth


def video_trajectory(spec: BoardSpec, keyposes: list[np.ndarray], n_frames: int,
                     offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A smooth board trajectory through ``keyposes`` (T_cam_board list): (n_frames, 4, 4) poses, keyframe indices.

    The board dwells at each key pose (smoothstep easing: zero speed there) and moves fastest half-way between,
    rotation by slerp, board centre linearly. ``offset`` shifts the sampling instants by that many frames (clipped
    to the trajectory), e.g. +-0.5 for the pose at the start/end of an exposure.
    """
    from scipy.spatial.transform import Rotation, Slerp

    keys = [np.asarray(T, float) for T in keyposes]
    if len(keys) == 1:
        keys = keys * 2
    n_seg = len(keys) - 1
    step = n_seg / max(n_frames - 1, 1)
    s0 = np.linspace(0.0, n_seg, n_frames)
    s = np.clip(s0 + offset * step, 0.0, n_seg)
    seg = np.minimum(np.floor(s).astype(int), n_seg - 1)
    a = s - seg
    a = a * a * (3 - 2 * a)  # smoothstep: zero speed at the key poses
    rots = Slerp(np.arange(len(keys)), Rotation.from_matrix(np.stack([T[:3, :3] for T in keys])))(seg + a).as_matrix()
    centres = np.stack([T[:3, :3] @ spec.centre + T[:3, 3] for T in keys])
    c = centres[seg] * (1 - a)[:, None] + centres[seg + 1] * a[:, None]
    T = np.tile(np.eye(4), (n_frames, 1, 1))
    T[:, :3, :3] = rots
    T[:, :3, 3] = c - rots @ spec.centre
    key_idx = sorted({int(np.argmin(np.abs(s0 - k))) for k in range(min(len(keyposes), n_seg + 1))})
    return T, np.asarray(key_idx)


def _write_video(out: Path, renderer: BoardRenderer, spec: BoardSpec, keyposes: list[np.ndarray], seconds: float,
                 fps: float, seed: int, exposure: float = 0.5) -> dict:
    """Render the trajectory through ``keyposes`` as ``video.avi`` (MJPG); return its truth block."""
    import cv2

    cam = renderer.camera
    n_seg = max(1, len(keyposes) - 1)
    per_seg = max(1, int(round((seconds * fps - 1) / n_seg)))
    n = per_seg * n_seg + 1  # ~seconds * fps frames, with every key pose exactly on a frame
    poses, keys = video_trajectory(spec, keyposes, n)
    centre = spec.centre[None, :]
    # image motion of the board centre while the shutter is open (exposure x frame interval, centred on the frame)
    before = video_trajectory(spec, keyposes, n, offset=-exposure / 2)[0]
    after = video_trajectory(spec, keyposes, n, offset=+exposure / 2)[0]
    motion = np.array([cam.project_from(a, centre)[0][0] - cam.project_from(b, centre)[0][0] for b, a in zip(before, after)])
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 2]))
    writer = cv2.VideoWriter(str(out / "video.avi"), cv2.VideoWriter_fourcc(*"MJPG"), float(fps), cam.image_size, isColor=False)
    if not writer.isOpened():  # pragma: no cover - OpenCV builds without a video backend
        raise OSError("cannot open an MJPG video writer")
    frames = []
    try:
        for i, T in enumerate(poses):
            streak = float(np.hypot(*motion[i])) if np.all(np.isfinite(motion[i])) else 0.0
            angle = float(np.arctan2(motion[i][1], motion[i][0])) if streak > 0 else 0.0
            streak = streak if streak >= 1.0 else 0.0
            writer.write(renderer.render(T, rng, motion_blur_px=streak, motion_angle=angle))
            _, vis = board_truth_pixels(cam, spec, T)
            frames.append({"T_cam_board": np.round(T, 12).tolist(), "n_visible": int(vis.sum()),
                           "motion_blur_px": round(streak, 4), "keyframe": bool(i in set(keys.tolist()))})
    finally:
        writer.release()
    return {"file": "video.avi", "codec": "MJPG", "fps": float(fps), "n_frames": n, "exposure_fraction": exposure,
            "keyframes": keys.tolist(), "frames": frames}


_ENTRY_ORDER = ("file", "kind", "has_board", "readable", "gain", "T_cam_board", "corners_uv", "visible", "corner_ids",
                "n_visible", "corners_uv_actual", "bad_reason", "bad_bow_m", "bad_displacement_px_max", "motion_blur_px",
                "motion_blur_angle_deg", "crc32")


def _ordered_entry(entry: dict) -> dict:
    """Stable key order in truth.json: camera-0 keys first (as in mono sets), then the ``*_cam1`` keys."""
    first = {k: entry[k] for k in _ENTRY_ORDER if k in entry}
    return first | {k: v for k, v in entry.items() if k not in first}


@dataclass
class BoardTruth:
    """A parsed ``truth.json`` of a board set (see docs/synth.md for the keys)."""

    folder: Path
    camera: Camera
    spec: BoardSpec
    object_points: np.ndarray  # (N, 3)
    views: list[dict]  # as stored, plus numpy arrays: "uv" (N, 2; NaN = not projectable), "vis" (N,), "T" (4x4 or None)
    raw: dict

    def files(self, kind: str = "all") -> list[Path]:
        """Paths of the files of one kind (all | board | full | partial | bad | blurred | blank | corrupt)."""
        return [self.folder / f for f in self.raw["files"].get(kind, [])]


def load_board_truth(path: str | os.PathLike) -> BoardTruth:
    """Read a set's ``truth.json`` (path to the file or to its folder)."""
    path = Path(path)
    file = path / "truth.json" if path.is_dir() else path
    raw = json.loads(file.read_text())
    if raw.get("format") != TRUTH_FORMAT:
        raise ValueError(f"{file}: not a {TRUTH_FORMAT} truth file (format {raw.get('format')!r})")
    views = []
    for v in raw["views"]:
        v = dict(v)
        if v.get("corners_uv") is not None:
            v["uv"] = np.array([[np.nan if x is None else x for x in row] for row in v["corners_uv"]], float)
            v["vis"] = np.asarray(v["visible"], bool)
        v["T"] = None if v.get("T_cam_board") is None else np.asarray(v["T_cam_board"], float)
        views.append(v)
    return BoardTruth(file.parent, Camera.from_dict(raw["camera"]), BoardSpec.from_dict(raw["board"]),
                      np.asarray(raw["object_points"], float), views, raw)
