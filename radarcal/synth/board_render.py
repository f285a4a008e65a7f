"""Calibration-target images with known truth: chessboard and ChArUco rendered through a distorted camera.

Pure numeric core (arrays in, arrays out; no file I/O). Rendering is by *inverse mapping*: every output pixel is unprojected through :class:`radarcal.camera.Camera`
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

from dataclasses import dataclass

import numpy as np

from radarcal.board import BoardSpec, object_points
from radarcal.camera import Camera

__all__ = ["RenderSettings", "BoardRenderer", "bow_warp", "bad_view_amplitude", "render_board", "render_blank", "board_truth_pixels"]

_TEXELS_PER_SQUARE = 120  # ChArUco texture resolution; square edges fall exactly on texel boundaries


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
    p = object_points(spec)
    if warp is not None:
        dx, dy = warp(p[:, 0], p[:, 1])
        p = p + np.stack([dx, dy, np.zeros_like(dx)], axis=1)
    uv, valid, z = camera.project_from(T_cam_board, p)
    uv = np.where(valid[:, None], uv, np.nan)
    vis = valid & camera.in_image(uv, margin)
    return uv, vis

