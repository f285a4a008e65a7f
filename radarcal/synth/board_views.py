"""Camera presets and view plans for the board renderer: which poses a generated calibration set shows (spread over
the image, distances and tilts, like a good calibration session) and the smooth trajectory of a board video."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radarcal.board import BoardSpec
from radarcal.camera import Camera
from radarcal.geometry import rotvec_to_R
from radarcal.synth.board_render import board_truth_pixels

__all__ = ["default_camera", "default_stereo_camera", "model_name", "BoardView", "plan_views", "video_trajectory"]


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

