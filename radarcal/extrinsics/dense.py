"""Dense (Levinson-Thrun style) edge correlation for targetless LiDAR-camera refinement.

Instead of sparse point-to-line matches, every LiDAR edge point scores the image's smoothed, direction-aware edge
energy where it projects, and the mean score is maximised over the 6 parameters of ``T_cam_lidar``.

LiDAR side (view dependent, occlusion aware): the cloud is projected with the current estimate, a coarse z-buffer
(min depth per 2x2-px cell, spread to the 3x3 neighbouring cells) decides which points are visible, and a visible
point is a *depth edge* when visible points within ``edge_radius_px`` lie clearly behind it (> max(``min_jump_m``,
``rel_jump`` x depth)). Its edge normal (image plane) points from it towards the background. Optional
plane-intersection (crease) samples from :func:`radarcal.extrinsics.edges.lidar_edges` join with the normal
perpendicular to their projected direction. Every edge point carries a second 3-D point a few pixels along its
normal so that the normal follows the transform.

Image side: the gradient of the grey image with its magnitude clipped at a high percentile (so a few high-contrast
edges do not dominate), turned into the structure tensor ``g g^T`` and blurred with a Gaussian of ``sigma`` px
(coarse-to-fine). The score of an edge point with unit image normal ``n`` is ``sqrt(n^T J n)`` at its projection
(bilinear): high on image edges running parallel to the LiDAR edge, smooth in the pose, no matching step.

Frames and units: ``T_cam_lidar`` maps LiDAR points (m) into the camera (OpenCV axes); pixels with centres at integer
coordinates; the parameter vector is a rotation vector (rad) and a translation (m) applied on the left (camera
frame). All per-point / per-pixel work is vectorised (numpy / OpenCV / cKDTree).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from radarcal import geometry
from radarcal.camera import Camera

__all__ = ["DenseEdgePoints", "ImageEnergy", "DenseScene", "DenseOptions", "DenseResult", "view_depth_edges", "image_energy", "dense_score", "refine_dense"]


@dataclass
class DenseEdgePoints:
    points: np.ndarray  # (M,3) edge points, LiDAR frame (m)
    helpers: np.ndarray  # (M,3) points a few px along the edge normal (towards the background), LiDAR frame
    weights: np.ndarray  # (M,) weights
    kind: np.ndarray  # (M,) 0 depth edge, 1 crease


@dataclass
class ImageEnergy:
    sigmas: tuple[float, ...]
    J: dict = field(repr=False)  # sigma -> (3,H,W) float32 blurred structure tensor (Jxx, Jxy, Jyy)


@dataclass
class DenseScene:
    camera: Camera
    points: np.ndarray  # (N,3) cloud, LiDAR frame (m)
    energy: ImageEnergy
    creases: object = None  # optional LidarEdges (plane intersections), LiDAR frame


@dataclass
class DenseOptions:
    sigmas_px: tuple[float, ...] = (8.0, 4.0, 2.0, 1.0)
    coarse_search_deg: float = 4.0  # half-width of the rotation grid at the coarsest sigma (0: none)
    coarse_step_deg: float = 1.0
    edge_radius_px: float = 6.0
    min_jump_m: float = 0.5
    rel_jump: float = 0.1
    max_range_m: float = 80.0
    max_edge_points: int = 20000  # per scene (random subset, fixed seed)
    fix_translation: bool = False
    rot_scale_deg: float = 0.5  # optimiser step scales
    trans_scale_m: float = 0.05
    max_eval: int = 600  # per stage
    rerender: bool = True  # re-extract the view-dependent depth edges at every stage


@dataclass
class DenseResult:
    T_cam_lidar: np.ndarray
    T_init: np.ndarray
    score_init: float  # dense score at the finest sigma (higher = better aligned)
    score: float
    n_edge_points: int
    history: list = field(default_factory=list)


def view_depth_edges(camera: Camera, T_cam_lidar: np.ndarray, points: np.ndarray, cell_px: int = 2, radius_cells: int = 2, min_jump_m: float = 0.5,
                     rel_jump: float = 0.1, max_range_m: float = 80.0, hole_cells: int = 1, coverage_cells: int = 15, helper_px: float = 3.0,
                     empty_is_far: bool = True) -> DenseEdgePoints:
    """Occlusion-aware depth-discontinuity edge points of ``points`` (LiDAR frame) as seen by ``camera`` at
    ``T_cam_lidar``. The points are z-buffered into ``cell_px`` cells (holes up to ``hole_cells`` filled from their
    nearest neighbours); a cell is an edge when a cell within ``radius_cells`` lies clearly behind it, or (with
    ``empty_is_far``) is empty while inside the covered area (no return: glass, sky, beyond range). The visible
    points of edge cells are the edge points; the image normal points towards the far side."""
    P = np.asarray(points, float)
    T = np.asarray(T_cam_lidar, float)
    empty = DenseEdgePoints(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, int))
    uv, valid, z = camera.project_from(T, P)
    ok = valid & camera.in_image(uv, 0.0) & (z > 0.3) & (z < max_range_m)
    P, uv, z = P[ok], uv[ok], z[ok]
    if len(P) < 10:
        return empty
    w, h = camera.image_size
    cw, ch = w // cell_px + 1, h // cell_px + 1
    ci = np.clip(np.floor((uv + 0.5) / cell_px).astype(np.int64), 0, [cw - 1, ch - 1])
    cell = ci[:, 1] * cw + ci[:, 0]
    BIG = np.float32(1e6)
    zb = np.full(cw * ch, BIG, np.float32)
    np.minimum.at(zb, cell, z.astype(np.float32))
    zb = zb.reshape(ch, cw)
    have = zb < BIG
    k = 2 * hole_cells + 1
    zf = np.where(have, zb, cv2.erode(zb, np.ones((k, k), np.uint8)))
    filled = zf < BIG
    kc = 2 * (coverage_cells // 2) + 1
    cover = cv2.morphologyEx(filled.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((kc, kc), np.uint8)).astype(bool)
    cover = cv2.erode(cover.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    # depth of each neighbour; empty cells inside the coverage count as far (if empty_is_far), outside as unknown
    far_depth = np.where(filled, zf, BIG if empty_is_far else np.float32(-1))
    far_depth = np.where(cover, far_depth, np.float32(-1))
    thr = np.where(filled, zf + np.maximum(min_jump_m, rel_jump * zf), BIG)
    r = radius_cells
    pad = np.pad(far_depth, r, constant_values=-1)
    nsum = np.zeros((ch, cw, 2), np.float32)
    is_edge = np.zeros((ch, cw), bool)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dx == 0 and dy == 0:
                continue
            nb = pad[r + dy:r + dy + ch, r + dx:r + dx + cw]
            f = nb > thr
            is_edge |= f
            wgt = f / np.hypot(dx, dy)
            nsum[..., 0] += wgt * dx
            nsum[..., 1] += wgt * dy
    is_edge &= have & cover
    # visible points of edge cells
    zc = zf.ravel()[cell]
    sel = is_edge.ravel()[cell] & (z <= zc * 1.03 + 0.1)
    idx = np.flatnonzero(sel)
    if len(idx) == 0:
        return empty
    nv = nsum.reshape(-1, 2)[cell[idx]]
    nrm = nv / np.maximum(np.linalg.norm(nv, axis=1, keepdims=True), 1e-9)
    uvh = uv[idx] + helper_px * nrm
    rays = camera.unproject(uvh)
    ph_cam = rays / rays[:, 2:3] * z[idx, None]
    Ti = geometry.invert_T(T)
    ph = ph_cam @ Ti[:3, :3].T + Ti[:3, 3]
    good = np.linalg.norm(nv, axis=1) > 0.3
    return DenseEdgePoints(P[idx][good], ph[good], np.ones(int(good.sum())), np.zeros(int(good.sum()), int))


def _crease_points(camera, T, creases, helper_m: float = 0.05) -> DenseEdgePoints:
    """Plane-intersection samples as edge points: the helper point is moved perpendicular to the line (in the
    image plane) so that the image normal is perpendicular to the projected line."""
    pts, dirs = creases.points, creases.dirs
    good = np.all(np.isfinite(dirs), 1)
    pts, dirs = pts[good], dirs[good]
    if len(pts) == 0:
        return DenseEdgePoints(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, int))
    R, t = T[:3, :3], T[:3, 3]
    pc = pts @ R.T + t
    dc = dirs @ R.T
    ray = pc / np.linalg.norm(pc, axis=1, keepdims=True)
    perp = np.cross(ray, dc)
    perp /= np.maximum(np.linalg.norm(perp, axis=1, keepdims=True), 1e-9)
    hc = pc + helper_m * perp * (np.linalg.norm(pc, axis=1, keepdims=True) / 10.0)
    ph = (hc - t) @ R
    return DenseEdgePoints(pts, ph, np.ones(len(pts)), np.ones(len(pts), int))


def image_energy(image: np.ndarray, sigmas: tuple[float, ...] = (8.0, 4.0, 2.0, 1.0), clip_percentile: float = 95.0, pre_blur: float = 1.0) -> ImageEnergy:
    """Blurred structure tensors of the clipped image gradient, one per ``sigma`` (px)."""
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    g = cv2.GaussianBlur(gray.astype(np.float32), (0, 0), pre_blur) if pre_blur > 0 else gray.astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    mag = np.hypot(gx, gy)
    cap = float(np.percentile(mag, clip_percentile)) + 1e-6
    s = np.minimum(mag, cap) / cap / np.maximum(mag, 1e-6)  # unit-normalised below the cap
    gx, gy = gx * s, gy * s
    J = {}
    for sg in sigmas:
        comps = [cv2.GaussianBlur(c, (0, 0), sg) for c in (gx * gx, gx * gy, gy * gy)]
        J[sg] = np.stack(comps)
    return ImageEnergy(tuple(sigmas), J)


def _bilinear(maps: np.ndarray, uv: np.ndarray) -> np.ndarray:
    _, h, w = maps.shape
    x = np.clip(uv[:, 0], 0, w - 1.001)
    y = np.clip(uv[:, 1], 0, h - 1.001)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[None], (y - y0)[None]
    return (maps[:, y0, x0] * (1 - fx) * (1 - fy) + maps[:, y0, x0 + 1] * fx * (1 - fy) + maps[:, y0 + 1, x0] * (1 - fx) * fy + maps[:, y0 + 1, x0 + 1] * fx * fy)


def dense_score(camera: Camera, T_cam_lidar: np.ndarray, edges: DenseEdgePoints, energy: ImageEnergy, sigma: float) -> float:
    """Weighted mean of ``sqrt(n^T J_sigma n)`` over the edge points (0 for points leaving the image)."""
    if len(edges.points) == 0:
        return 0.0
    uv, valid, _ = camera.project_from(T_cam_lidar, edges.points)
    uvh, validh, _ = camera.project_from(T_cam_lidar, edges.helpers)
    ins = valid & validh & camera.in_image(uv, 1.0)
    n = uvh[ins] - uv[ins]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)
    J = _bilinear(energy.J[sigma], uv[ins])
    e = J[0] * n[:, 0] ** 2 + 2 * J[1] * n[:, 0] * n[:, 1] + J[2] * n[:, 1] ** 2
    return float(np.sum(edges.weights[ins] * np.sqrt(np.maximum(e, 0))) / max(edges.weights.sum(), 1e-9))


def _apply(x: np.ndarray, T: np.ndarray) -> np.ndarray:
    return geometry.T_from_rotvec(x[:3], x[3:]) @ T


def _scene_edges(sc: DenseScene, T: np.ndarray, o: DenseOptions, rng) -> DenseEdgePoints:
    e = view_depth_edges(sc.camera, T, sc.points, min_jump_m=o.min_jump_m, rel_jump=o.rel_jump, max_range_m=o.max_range_m)
    if sc.creases is not None and len(sc.creases.points):
        c = _crease_points(sc.camera, T, sc.creases)
        e = DenseEdgePoints(np.concatenate([e.points, c.points]), np.concatenate([e.helpers, c.helpers]), np.concatenate([e.weights, c.weights]),
                            np.concatenate([e.kind, c.kind]))
    if len(e.points) > o.max_edge_points:
        k = rng.choice(len(e.points), o.max_edge_points, replace=False)
        e = DenseEdgePoints(e.points[k], e.helpers[k], e.weights[k], e.kind[k])
    return e


def _total(scenes, edges, T, sigma) -> float:
    return float(np.mean([dense_score(sc.camera, T, e, sc.energy, sigma) for sc, e in zip(scenes, edges)]))


def refine_dense(scenes: list[DenseScene], T_init: np.ndarray, options: DenseOptions | None = None) -> DenseResult:
    """Maximise the mean dense edge score over the scenes (one shared ``T_cam_lidar``): an optional rotation grid at
    the coarsest sigma, then a derivative-free local search (nlopt BOBYQA) per sigma, coarse to fine, the
    view-dependent edges re-extracted at the current estimate before each stage."""
    import nlopt

    o = options or DenseOptions()
    T0 = np.asarray(T_init, float)
    rng = np.random.default_rng(0)
    hist = []
    T = T0.copy()
    edges = [_scene_edges(sc, T, o, rng) for sc in scenes]
    s_fine_init = _total(scenes, edges, T0, o.sigmas_px[-1])
    if o.coarse_search_deg > 0:
        sub = []
        for e in edges:
            k = rng.choice(len(e.points), min(len(e.points), 3000), replace=False)
            sub.append(DenseEdgePoints(e.points[k], e.helpers[k], e.weights[k], e.kind[k]))
        g = np.radians(np.arange(-o.coarse_search_deg, o.coarse_search_deg + 1e-9, o.coarse_step_deg))
        offs = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
        vals = np.array([_total(scenes, sub, _apply(np.r_[v, 0, 0, 0], T), o.sigmas_px[0]) for v in offs])
        best = offs[int(np.argmax(vals))]
        T = _apply(np.r_[best, 0, 0, 0], T)
        hist.append({"stage": "grid", "score": float(vals.max()), "offset_deg": np.degrees(best).tolist()})
    n_par = 3 if o.fix_translation else 6
    scale = np.r_[[np.radians(o.rot_scale_deg)] * 3, [o.trans_scale_m] * 3][:n_par]
    for sigma in o.sigmas_px:
        if o.rerender:
            edges = [_scene_edges(sc, T, o, rng) for sc in scenes]
        Tc = T.copy()

        def f(y, grad):
            x = np.zeros(6)
            x[:n_par] = y * scale
            return -_total(scenes, edges, _apply(x, Tc), sigma)

        opt = nlopt.opt(nlopt.LN_BOBYQA, n_par)
        opt.set_min_objective(f)
        opt.set_lower_bounds(-np.full(n_par, 8.0))
        opt.set_upper_bounds(np.full(n_par, 8.0))
        opt.set_initial_step(np.full(n_par, 0.5 if sigma >= 4 else 0.25))
        opt.set_xtol_abs(np.full(n_par, 0.01))
        opt.set_maxeval(o.max_eval)
        y = opt.optimize(np.zeros(n_par))
        x = np.zeros(6)
        x[:n_par] = y * scale
        T = _apply(x, Tc)
        hist.append({"stage": f"sigma={sigma:g}", "score": -opt.last_optimum_value(), "evals": opt.get_numevals(), "step": x.tolist()})
    edges = [_scene_edges(sc, T, o, rng) for sc in scenes]
    return DenseResult(T, T0, s_fine_init, _total(scenes, edges, T, o.sigmas_px[-1]), int(sum(len(e.points) for e in edges)), hist)
