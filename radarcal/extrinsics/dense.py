"""Dense (Levinson-Thrun style) edge correlation for targetless LiDAR-camera refinement.

Instead of sparse point-to-line matches, every LiDAR edge point scores the image's smoothed, direction-aware edge
energy where it projects, and the mean score is maximised over the 6 parameters of ``T_cam_lidar``.

LiDAR side: depth discontinuities as the LiDAR saw them. The cloud is z-buffered into 2 px cells of a virtual
camera at the LiDAR origin with the camera's orientation and intrinsics (sampling gaps closed); a cell is a *depth
edge* when a cell within ``radius_cells`` lies clearly behind it (> max(``min_jump_m``, ``rel_jump`` x depth)) or
is a large empty region inside the covered area (no return: glass, sky). Its edge normal (image plane) points
towards the far side. Extracting from the LiDAR origin (``edge_viewpoint="lidar"``) keeps the edge set independent of
the translation being solved; from the estimated camera position a wrong pose makes its own, self-consistent edges.
Optional plane-intersection (crease) samples from :func:`radarcal.extrinsics.edges.lidar_edges` join with the
normal perpendicular to their projected direction. Every edge point carries a second 3-D point a few pixels along
its normal so that the normal follows the transform.

Image side: the gradient of the grey image with its magnitude clipped at a high percentile (so a few high-contrast
edges do not dominate), turned into the structure tensor ``g g^T`` and blurred with a Gaussian of ``sigma`` px
(coarse-to-fine). The score of an edge point with unit image normal ``n`` is ``sqrt(n^T J n)`` at its projection
(bilinear): high on image edges running parallel to the LiDAR edge, smooth in the pose, no matching step.

Frames and units: ``T_cam_lidar`` maps LiDAR points (m) into the camera (OpenCV axes); pixels with centres at integer
coordinates; the parameter vector is a rotation vector (rad) and a translation (m) applied on the left (camera
frame). All per-point / per-pixel work is vectorised (numpy / OpenCV).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

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
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the LiDAR's position in the points' frame (m)


@dataclass
class DenseOptions:
    sigmas_px: tuple[float, ...] = (8.0, 4.0, 2.0, 1.0)  # image-energy blur per stage, coarse to fine
    coarse_search_deg: float = 4.0  # half-width of the rotation grid at the coarsest sigma (0: none)
    coarse_step_deg: float = 1.0
    min_jump_m: float = 0.5  # depth edge: neighbour behind by more than max(min_jump_m, rel_jump * depth)
    rel_jump: float = 0.1
    max_range_m: float = 80.0
    max_edge_points: int = 20000  # per scene (random subset, fixed seed)
    fix_translation: bool = False
    rot_scale_deg: float = 0.5  # optimiser parameter scales
    trans_scale_m: float = 0.05
    max_eval: int = 600  # per stage
    stability_checks: int = 3  # restarts from the result moved by stability_deg / stability_m (0: none)
    stability_deg: float = 1.0
    stability_m: float = 0.05
    stability_sigmas_px: tuple[float, ...] = (4.0, 2.0, 1.0)
    stability_tol_deg: float = 0.1  # restarts must come back this close for "converged"
    stability_tol_m: float = 0.02
    adopt_margin: float = 0.005  # relative score gain that makes a restart the new result
    ambiguity_margin: float = 0.02  # restarts ending > this much (relative) below the result are worse minima, ignored
    observe_m: float = 0.05  # translation observability check: the score must drop by >= observe_min_drop at +-observe_m
    observe_min_drop: float = 0.01  # along the weak directions (0 observe_m: no check)
    min_edge_points: int = 500
    max_translation_m: float = 0.3  # the translation stays within this distance of the initial guess
    edge_viewpoint: str = "lidar"  # "lidar": depth edges as the LiDAR saw them (independent of the translation being
    # solved - a view from a wrongly placed camera makes its own, self-consistent edges); "camera": from the estimate
    fit_edge_offset: bool = False  # also fit a LiDAR edge-position bias (bx, by) px along the edge normals


@dataclass
class DenseResult:
    T_cam_lidar: np.ndarray
    T_init: np.ndarray
    converged: bool
    message: str
    score_init: float  # dense score at the finest sigma, edges extracted at the result (higher = better aligned)
    score: float
    n_edge_points: int
    spread_deg: float  # largest distance of a restart's end point from the result (rotation, deg / translation, m)
    spread_m: float
    history: list = field(default_factory=list)
    edge_offset_px: tuple = (0.0, 0.0)  # fitted LiDAR edge-position bias (bx, by), with fit_edge_offset
    translation_drops: dict = field(default_factory=dict)  # relative score drop at +-observe_m along the weak directions


def view_depth_edges(camera: Camera, T_cam_lidar: np.ndarray, points: np.ndarray, cell_px: int = 2, radius_cells: int = 1, min_jump_m: float = 0.5,
                     rel_jump: float = 0.1, max_range_m: float = 80.0, hole_cells: int = 3, coverage_cells: int = 15, helper_px: float = 3.0,
                     empty_is_far: bool = True) -> DenseEdgePoints:
    """Occlusion-aware depth-discontinuity edge points of ``points`` (LiDAR frame) as seen by ``camera`` at
    ``T_cam_lidar``. The points are z-buffered into ``cell_px`` cells (sampling gaps up to ``2 * hole_cells + 1`` cells wide closed
    with the nearest depth around them); a cell is an edge when a cell within ``radius_cells`` lies clearly behind it, or (with
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
    # sampling gaps (narrower than 2 * hole_cells + 1 cells) are closed and take the nearest depth of the window;
    # larger empty regions stay empty (no return: glass, sky, beyond range)
    k = 2 * hole_cells + 1
    ker = np.ones((k, k), np.uint8)
    filled = cv2.morphologyEx(have.astype(np.uint8), cv2.MORPH_CLOSE, ker).astype(bool) | have
    zf = np.where(have, zb, np.where(filled, cv2.erode(zb, ker), BIG))
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


def dense_score(camera: Camera, T_cam_lidar: np.ndarray, edges: DenseEdgePoints, energy: ImageEnergy, sigma: float, offset_px: tuple[float, float] = (0.0, 0.0)) -> float:
    """Weighted mean of ``sqrt(n^T J_sigma n)`` over the edge points (0 for points leaving the image).
    ``offset_px`` = (bx, by): depth-edge points are moved by (bx n_x, by n_y) px along their normal (towards the far
    side for positive values) - a LiDAR edge-position bias (beam divergence, edge band) fitted with the pose."""
    if len(edges.points) == 0:
        return 0.0
    uv, valid, _ = camera.project_from(T_cam_lidar, edges.points)
    uvh, validh, _ = camera.project_from(T_cam_lidar, edges.helpers)
    ins = valid & validh & camera.in_image(uv, 1.0)
    n = uvh[ins] - uv[ins]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-9)
    uv = uv[ins]
    if offset_px[0] or offset_px[1]:
        dep = (edges.kind[ins] == 0)[:, None]
        uv = uv + dep * n * np.asarray(offset_px, float)
    J = _bilinear(energy.J[sigma], uv)
    e = J[0] * n[:, 0] ** 2 + 2 * J[1] * n[:, 0] * n[:, 1] + J[2] * n[:, 1] ** 2
    return float(np.sum(edges.weights[ins] * np.sqrt(np.maximum(e, 0))) / max(edges.weights.sum(), 1e-9))


def _apply(x: np.ndarray, T: np.ndarray) -> np.ndarray:
    return geometry.T_from_rotvec(x[:3], x[3:]) @ T


def _scene_edges(sc: DenseScene, T: np.ndarray, o: DenseOptions, rng) -> DenseEdgePoints:
    Tv = np.asarray(T, float)
    if o.edge_viewpoint == "lidar":  # virtual camera at the LiDAR origin with the camera's orientation
        Tv = Tv.copy()
        Tv[:3, 3] = -Tv[:3, :3] @ np.asarray(sc.origin, float)
    e = view_depth_edges(sc.camera, Tv, sc.points, min_jump_m=o.min_jump_m, rel_jump=o.rel_jump, max_range_m=o.max_range_m)
    if sc.creases is not None and len(sc.creases.points):
        c = _crease_points(sc.camera, T, sc.creases)
        e = DenseEdgePoints(np.concatenate([e.points, c.points]), np.concatenate([e.helpers, c.helpers]), np.concatenate([e.weights, c.weights]),
                            np.concatenate([e.kind, c.kind]))
    if len(e.points) > o.max_edge_points:
        k = rng.choice(len(e.points), o.max_edge_points, replace=False)
        e = DenseEdgePoints(e.points[k], e.helpers[k], e.weights[k], e.kind[k])
    return e


def _total(scenes, edges, T, sigma, offset_px=(0.0, 0.0)) -> float:
    return float(np.mean([dense_score(sc.camera, T, e, sc.energy, sigma, offset_px) for sc, e in zip(scenes, edges)]))


def _stages(scenes, T, o: DenseOptions, sigmas, rng, hist, T_init, offset):
    import nlopt

    n_pose = 3 if o.fix_translation else 6
    n_par = n_pose + (2 if o.fit_edge_offset else 0)
    scale = np.r_[[np.radians(o.rot_scale_deg)] * 3, [o.trans_scale_m] * 3][:n_pose]
    scale = np.r_[scale, [1.0] * (n_par - n_pose)]
    t_init = T_init[:3, 3]
    for sigma in sigmas:
        edges = [_scene_edges(sc, T, o, rng) for sc in scenes]
        Tc = T.copy()

        def unpack(y, Tc=Tc):
            x = np.zeros(6)
            x[:n_pose] = y[:n_pose] * scale[:n_pose]
            off = tuple(y[n_pose:]) if n_par > n_pose else (0.0, 0.0)
            return _apply(x, Tc), off

        def f(y, grad, edges=edges, sigma=sigma):
            Tx, off = unpack(y)
            pen = max(np.linalg.norm(Tx[:3, 3] - t_init) - o.max_translation_m, 0.0) * 10.0  # stay within the bound
            return -_total(scenes, edges, Tx, sigma, off) + pen

        opt = nlopt.opt(nlopt.LN_BOBYQA, n_par)
        opt.set_min_objective(f)
        opt.set_lower_bounds(-np.full(n_par, 8.0))
        opt.set_upper_bounds(np.full(n_par, 8.0))
        opt.set_initial_step(np.full(n_par, 0.5 if sigma >= 4 else 0.25))
        opt.set_xtol_abs(np.full(n_par, 0.01))
        opt.set_maxeval(o.max_eval)
        y = opt.optimize(np.zeros(n_par) if n_par == n_pose else np.r_[np.zeros(n_pose), offset[0]])
        T, off = unpack(y)
        offset[0] = np.asarray(off, float)
        hist.append({"stage": f"sigma={sigma:g}", "score": -opt.last_optimum_value(), "evals": opt.get_numevals(), "edge_offset_px": list(map(float, off))})
    return T


def refine_dense(scenes: list[DenseScene], T_init: np.ndarray, options: DenseOptions | None = None) -> DenseResult:
    """Maximise the mean dense edge score over the scenes (one shared ``T_cam_lidar``): a rotation grid at the
    coarsest sigma, then a derivative-free local search (nlopt BOBYQA; rotation vector + translation applied on the
    left) per sigma, coarse to fine, with the edges re-extracted at the current rotation before each stage (from the
    LiDAR origin by default, so they do not depend on the translation being solved). Verdict: ``stability_checks`` restarts from the result moved by ``stability_deg`` / ``stability_m`` that
    end with about the same score (within ``ambiguity_margin``) must be within ``stability_tol_deg`` /
    ``stability_tol_m`` of it (another minimum about as good = ambiguous); restarts ending clearly lower fell into a
    worse minimum and are ignored (at least one must come back); a clearly higher one is adopted and the check
    repeated; then the score must drop by >= ``observe_min_drop`` at +-``observe_m`` along the three weakest
    translation directions, else "did not converge" (translation not observed). Never raises on poor data."""
    o = options or DenseOptions()
    T0 = np.asarray(T_init, float)
    rng = np.random.default_rng(0)
    hist: list = []
    T = T0.copy()
    if o.coarse_search_deg > 0:
        T = _rotation_grid(scenes, T, o, rng, hist)
    offset = [np.zeros(2)]
    T = _stages(scenes, T, o, o.sigmas_px, rng, hist, T0, offset)
    spread, n_worse = (0.0, 0.0), 0
    if o.stability_checks > 0:
        T, spread, n_worse = _stability_restarts(scenes, T, o, rng, hist, T0, offset)
    edges = [_scene_edges(sc, T, o, rng) for sc in scenes]
    s_init, s_end = _total(scenes, edges, T0, o.sigmas_px[-1]), _total(scenes, edges, T, o.sigmas_px[-1], tuple(offset[0]))
    drops = _translation_drops(scenes, edges, T, o, offset, hist) if o.observe_m > 0 and not o.fix_translation else {}
    n_pts = int(sum(len(e.points) for e in edges))
    ok, msg = _dense_verdict(o, n_pts, spread, n_worse, drops, s_init, s_end, geometry.pose_error(T, T0))
    return DenseResult(T, T0, bool(ok), msg, s_init, s_end, n_pts, float(spread[0]), float(spread[1]), hist, tuple(map(float, offset[0])), drops)


def _rotation_grid(scenes, T, o: DenseOptions, rng, hist) -> np.ndarray:
    """Best rotation offset (applied on the left) on a +-``coarse_search_deg`` grid at the coarsest sigma, scored on
    up to 3000 edge points per scene."""
    edges = [_scene_edges(sc, T, o, rng) for sc in scenes]
    sub = []
    for e in edges:
        k = rng.choice(len(e.points), min(len(e.points), 3000), replace=False)
        sub.append(DenseEdgePoints(e.points[k], e.helpers[k], e.weights[k], e.kind[k]))
    g = np.radians(np.arange(-o.coarse_search_deg, o.coarse_search_deg + 1e-9, o.coarse_step_deg))
    offs = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
    vals = np.array([_total(scenes, sub, _apply(np.r_[v, 0, 0, 0], T), o.sigmas_px[0]) for v in offs])
    best = offs[int(np.argmax(vals))]
    hist.append({"stage": "grid", "score": float(vals.max()), "offset_deg": np.degrees(best).tolist()})
    return _apply(np.r_[best, 0, 0, 0], T)


def _stability_restarts(scenes, T, o: DenseOptions, rng, hist, T0, offset):
    """Restarts from the result moved by ``stability_deg`` / ``stability_m``: a clearly higher end is adopted and the
    check repeated (three rounds at most); otherwise the spread (deg, m) of the ends about as good as the result
    (NaN when none; inf when every round adopted) and how many ended clearly worse. Returns (T, spread, n_worse)."""
    spread, n_worse = (0.0, 0.0), 0
    srng = np.random.default_rng(12345)
    for rnd in range(3):
        edges = [_scene_edges(sc, T, o, rng) for sc in scenes]
        s_T = _total(scenes, edges, T, o.sigmas_px[-1], tuple(offset[0]))
        ends = []
        for _ in range(o.stability_checks):
            Tk = geometry.perturb_T(T, o.stability_deg, 0.0 if o.fix_translation else o.stability_m, srng)
            ends.append(_stages(scenes, Tk, o, o.stability_sigmas_px, rng, hist, T0, [offset[0].copy()]))
        sk = [_total(scenes, edges, Te, o.sigmas_px[-1], tuple(offset[0])) for Te in ends]
        dev = [geometry.pose_error(Te, T) for Te in ends]
        hist.append({"stage": "stability", "round": rnd, "score_result": s_T, "scores": sk, "dev": dev})
        k = int(np.argmax(sk))
        if sk[k] > s_T * (1 + o.adopt_margin):
            T = ends[k]
            continue
        # restarts ending in a clearly worse minimum say nothing about this one; those about as good must be it
        near = [d for d, v in zip(dev, sk) if v >= s_T * (1 - o.ambiguity_margin)]
        n_worse = len(dev) - len(near)
        spread = (max(d[0] for d in near), max(d[1] for d in near)) if near else (float("nan"), float("nan"))
        break
    else:
        spread = (float("inf"), float("inf"))
    return T, spread, n_worse


def _translation_drops(scenes, edges, T, o: DenseOptions, offset, hist) -> dict:
    """Observability of the translation: relative score drop +-``observe_m`` along the three weakest directions
    (sideways / vertical shift with the yaw / pitch that keeps the median edge depth in place, and the optical axis)."""
    drops = {}
    z = np.concatenate([(e.points @ T[:3, :3].T + T[:3, 3])[:, 2] for e in edges]) if edges else np.zeros(0)
    Z = float(np.median(z[z > 0.3])) if np.any(z > 0.3) else 10.0
    V = {"x (with yaw)": np.array([0.0, -1.0 / Z, 0.0, 1.0, 0.0, 0.0]), "y (with pitch)": np.array([1.0 / Z, 0.0, 0.0, 0.0, 1.0, 0.0]),
         "z": np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])}
    for name, v in V.items():
        sc_pm = [_total(scenes, edges, _apply(sg * o.observe_m * v, T), o.sigmas_px[-2] if len(o.sigmas_px) > 1 else o.sigmas_px[-1], tuple(offset[0])) for sg in (-1.0, 1.0)]
        s_mid = _total(scenes, edges, T, o.sigmas_px[-2] if len(o.sigmas_px) > 1 else o.sigmas_px[-1], tuple(offset[0]))
        drops[name] = float(1.0 - max(sc_pm) / max(s_mid, 1e-12))
    hist.append({"stage": "observability", "median_depth_m": Z, "drops": drops})
    return drops


def _dense_verdict(o: DenseOptions, n_pts, spread, n_worse, drops, s_init, s_end, moved) -> tuple[bool, str]:
    """(converged, message) from the edge point count, the restarts' spread, the translation drops and the scores."""
    weak = [k for k, d in drops.items() if d < o.observe_min_drop]
    if n_pts < o.min_edge_points:
        return False, f"did not converge: only {n_pts} LiDAR edge points in view (< {o.min_edge_points})"
    if np.isnan(spread[0]):
        return False, f"did not converge: none of the {o.stability_checks} restarts {o.stability_deg:g} deg / {o.stability_m * 100:g} cm away came back (all ended in worse minima) - the basin is very narrow"
    if not np.isfinite(spread[0]):
        return False, "did not converge: restarts from the result kept finding higher scores"
    if spread[0] > o.stability_tol_deg or spread[1] > o.stability_tol_m:
        return False, (f"did not converge: restarts {o.stability_deg:g} deg / {o.stability_m * 100:g} cm away end up to {spread[0]:.3f} deg / "
                       f"{spread[1] * 100:.1f} cm from the result (tolerance {o.stability_tol_deg:g} deg / {o.stability_tol_m * 100:g} cm) - the optimum is not pinned down that well")
    if weak:
        return False, ("did not converge: the translation is not observed to " + f"{o.observe_m * 100:g} cm along " + ", ".join(weak) + " (the score drops by only "
                       + ", ".join(f"{100 * drops[k]:.2f} %" for k in weak) + f" at +-{o.observe_m * 100:g} cm, < {100 * o.observe_min_drop:g} %) - add near structure or scenes, or measure the translation")
    if s_end < s_init:
        return False, f"did not converge: the dense score got worse ({s_init:.4f} -> {s_end:.4f})"
    worse = f" ({n_worse} of {o.stability_checks} ended in a clearly worse minimum)" if n_worse else ""
    return True, f"converged: dense score {s_init:.4f} -> {s_end:.4f}, moved {moved[0]:.3f} deg / {moved[1] * 100:.1f} cm, restarts within {spread[0]:.3f} deg / {spread[1] * 100:.1f} cm{worse}"
