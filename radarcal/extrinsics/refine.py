"""Targetless refinement of ``T_cam_lidar`` by aligning LiDAR plane-intersection edges with image edges.

For every scene (image + cloud seen from the same rig) the projected LiDAR edge samples are matched to image edge
pixels (kd-tree, k nearest, a local line fitted to them, direction consistency with the projected LiDAR edge);
the residual is the signed point-to-line distance in pixels through the full :class:`radarcal.camera.Camera`
model. The 6 parameters (a rotation vector and translation applied on the left, in the camera frame) are solved
by ``scipy.optimize.least_squares`` with a Cauchy loss, re-matching until the update is below a tolerance, over a
coarse-to-fine schedule of match radii. A grid search over rotations (distance-transform score) first widens the
basin. All scenes share one ``T`` (multi-scene joint refinement).

Reported: residual, match counts, sigma of the 6 parameters (from the Jacobian; matches along one edge are
correlated, so treat it as a lower bound) and a block-bootstrap sigma (edge stretches resampled together; more
honest, still without shared biases) widened by a sector jackknife (one image region left out: a bias that region
carries), observability (spread of edge directions, Jacobian conditioning),
convergence, and cost profiles along each parameter for a report.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from radarcal import geometry
from radarcal.camera import Camera
from radarcal.extrinsics.edges import ImageEdges, LidarEdges, edge_score
from radarcal.extrinsics.pose_params import PARAM_NAMES, parameter_profiles  # re-exported: the one definition is there

__all__ = ["EdgeScene", "RefineOptions", "RefineResult", "refine_edges", "refine_edges_choosing", "coarse_rotation_search", "match_edges", "block_bootstrap_sigma",
           "cost_profiles", "parameter_profiles", "PARAM_NAMES", "edge_verdict", "sigma_for_verdict",
           "sector_jackknife", "alignment_cost", "alignment_costs", "paired_cost_increase"]



@dataclass
class EdgeScene:
    camera: Camera
    lidar: LidarEdges
    image: ImageEdges


@dataclass
class RefineOptions:
    radii_px: tuple[float, ...] = (25.0, 12.0, 6.0, 3.0)
    k_neighbours: int = 5
    max_angle_deg: float = 20.0
    loss_scale_px: float = 1.0  # Cauchy scale at the finest radius (coarser stages use radius / 4)
    max_rematch: int = 15
    tol_rot_rad: float = 2e-5
    tol_trans_m: float = 2e-4
    coarse_search_deg: float = 6.0  # half-width of the rotation grid (0 disables)
    coarse_step_deg: float = 1.0
    coarse_oriented: bool = False  # the coarse grid scores distances to parallel image edges only
    fix_translation: bool = False
    min_matches: int = 60
    min_match_fraction: float = 0.35  # matched share of the LiDAR edge samples that project into the image
    translation_prior_m: float = 0.0  # sigma of a prior pulling the translation towards the initial guess (0: none)
    rotation_only_stages: int = 2  # the first (coarsest) radii solve rotation only
    translation_starts_m: float = 0.0  # extra starts with the camera centre moved +-this along each axis (0: none)
    n_starts: int = 3
    stability_checks: int = 4  # restarts from the result (0: none)
    stability_deg: float = 1.0
    stability_m: float = 0.1
    stability_full: bool = True
    stability_margin: float = 0.05  # relative alignment-cost difference that tells two minima apart  # restarts run the whole coarse-to-fine schedule (for larger stability_deg/m)
    valley_steps_m: tuple[float, ...] = (0.08,)  # restarts along the shift/rotation-coupled directions (empty: none)
    valley_depth: bool = True  # also restart along the optical axis
    valley_rounds: int = 5  # still improving after the last round: reported as not converged
    valley_margin: float = 0.01  # relative cost decrease that makes a valley restart the new result
    stability_tol_deg: float = 0.1
    stability_tol_m: float = 0.02  # distinct coarse-search minima refined in full (plus the initial guess itself)
    max_translation_move_m: float = 0.3  # a camera centre that moved farther from the initial guess is not trusted (0.5 before: old-family seed 22 moved 0.31 m into a 0.45 deg / 27 cm minimum; right results move 0.09-0.11 m from a 10 cm start)
    bootstrap: int = 40  # block-bootstrap resamples for sigma_bootstrap (0: none)
    max_bootstrap_sigma_deg: float = 0.15  # a result whose bootstrap sigma exceeds these is weakly constrained
    max_bootstrap_sigma_m: float = 0.03  # camera x and y
    max_bootstrap_sigma_depth_m: float | None = None  # camera z (the optical axis; None: as x and y)
    ambiguity_cost_ratio: float = 1.1  # a restart that ended elsewhere within this alignment-cost ratio widens the sigma
    sigma_floor_deg: float = 0.01  # shared-bias floor of the reported sigma (rotation, translation)
    sigma_floor_m: float = 0.005
    bootstrap_block_m: float = 0.5  # LiDAR edge samples in one block of this size are resampled together
    jackknife_grid: int = 3  # sector_jackknife: the image cut into grid x grid sectors (0: none)
    jackknife_min_matches: int = 10  # sectors with fewer matches are not left out on their own
    unresolved_separation_px: float | None = 0.0  # opt-in thin-stripe edge model (match_edges): > 0 or None (= the finest radius) - matches on the nearest image line only, LiDAR samples / image pixels with a parallel edge closer than this beside them not matched; 0: off (the default: measured not better held-out, docs/lidar_camera.md "Unresolved edge pairs")


@dataclass
class RefineResult:
    T_cam_lidar: np.ndarray
    T_init: np.ndarray
    converged: bool
    message: str
    rms_px: float  # RMS of inlier point-to-line residuals (|r| < 3 * loss scale)
    mean_abs_px: float
    n_matches: int
    n_inliers: int
    sigma: np.ndarray  # (6,) rx ry rz (rad) tx ty tz (m) from the Jacobian: a lower bound (matches along one edge correlate)
    score_before: float  # edge_score (mean capped distance to nearest image edge, px), averaged over scenes
    score_after: float
    observability: dict
    warnings: list[str]
    history: list[dict] = field(default_factory=list)
    matches: dict = field(default_factory=dict)  # arrays of the final matching (for a report)
    residuals_before: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residuals_after: np.ndarray = field(default_factory=lambda: np.zeros(0))
    profiles: dict = field(default_factory=dict)  # name -> (offsets, cost)
    sigma_bootstrap: np.ndarray = field(default_factory=lambda: np.full(6, np.nan))  # (6,) same units, block bootstrap
    checks: dict = field(default_factory=dict)  # what the verdict was decided on (edge_verdict)


def _apply(x: np.ndarray, T0: np.ndarray) -> np.ndarray:
    return geometry.T_from_rotvec(x[:3], x[3:]) @ T0


def unresolved_edges(uv: np.ndarray, dirs_uv: np.ndarray, separation_px: float, same_edge_px: float = 0.5, max_angle_deg: float = 20.0, k: int = 24) -> np.ndarray:
    """Mask of projected LiDAR edge samples that have a *parallel neighbour edge* beside them: another sample whose
    projected direction is within ``max_angle_deg``, offset across the edge by more than ``same_edge_px`` (one
    edge seen twice, e.g. a crease that is also a reflectivity step, is not two edges) and less than
    ``separation_px``, and no farther along it. ``uv`` (n,2) px, ``dirs_uv`` (n,2) unit image directions (NaN: none,
    never unresolved). The image cannot resolve two such edges (a thin painted stripe, a patch border next to a
    crease: blur and the line detector give one line, or one between them) and a point-to-line match to the 5
    nearest edge pixels then lies between them - by an amount that changes with the depth at which they are
    projected, a bias along the optical axis (docs/lidar_camera.md, "Unresolved edge pairs")."""
    n = len(uv)
    out = np.zeros(n, bool)
    has = np.all(np.isfinite(dirs_uv), axis=1)
    if n < 2 or separation_px <= same_edge_px:
        return out
    d, nn = cKDTree(uv).query(uv, k=min(k, n), distance_upper_bound=separation_px)
    ok = np.isfinite(d) & has[np.minimum(nn, n - 1)] & has[:, None]
    nn = np.where(ok, nn, 0)
    off = uv[nn] - uv[:, None, :]
    dr = np.where(has[:, None], dirs_uv, 0.0)
    along = np.abs(np.einsum("nkj,nj->nk", off, dr))
    across = np.abs(off[..., 0] * dr[:, None, 1] - off[..., 1] * dr[:, None, 0])
    parallel = np.abs(np.einsum("nkj,nj->nk", np.where(ok[..., None], dirs_uv[nn], 0.0), dr)) > np.cos(np.radians(max_angle_deg))
    beside = ok & parallel & (across > same_edge_px) & (across < separation_px) & (along < separation_px)
    return beside.any(axis=1)


def _resolved_pixels(ie: ImageEdges, separation_px: float) -> np.ndarray:
    """(K,) mask of the image edge pixels that have no parallel image line beside them closer than
    ``separation_px`` (``unresolved_edges`` on the pixels; cached on ``ie``): the two borders of a stripe a few px
    wide come out of blur and the line detector displaced towards each other (a generated 2 px stripe: LSD lines
    0.67 px off its borders), so neither is used - as the LiDAR samples beside a parallel edge are not."""
    cache = ie.__dict__.setdefault("_resolved", {})
    if separation_px not in cache:
        cache[separation_px] = ~unresolved_edges(ie.uv, ie.dirs, separation_px)
    return cache[separation_px]


def _project_edges(scene: EdgeScene, T: np.ndarray, separation_px: float = 0.0):
    """Projected LiDAR edge samples: uv (n,2) px, unit image directions (n,2; NaN without a 3D direction) and the
    mask of samples in view (in front, inside the image) and - with ``separation_px`` > 0 - resolved
    (``unresolved_edges``)."""
    cam, le = scene.camera, scene.lidar
    uv, valid, z = cam.project_from(T, le.points)
    has_dir = np.all(np.isfinite(le.dirs), axis=1)
    uv2, valid2, _ = cam.project_from(T, le.points + 0.05 * np.where(has_dir[:, None], le.dirs, 0.0))
    ok = valid & (valid2 | ~has_dir) & cam.in_image(uv, 2.0) & (z > 0.3)
    d2 = uv2 - uv
    d2 = np.where((has_dir & valid2)[:, None], d2 / np.maximum(np.linalg.norm(d2, axis=1, keepdims=True), 1e-12), np.nan)
    if separation_px > 0 and ok.any():
        idx = np.flatnonzero(ok)
        ok[idx[unresolved_edges(uv[idx], d2[idx], separation_px)]] = False
    return uv, d2, ok


def match_edges(scene: EdgeScene, T: np.ndarray, radius: float, k: int = 5, max_angle_deg: float = 20.0, separation_px: float = 0.0):
    """Matches of projected LiDAR edge samples to local image edge lines. With ``separation_px`` > 0 (the thin-stripe
    edge model, opt-in) the local line is fitted to the nearest image line's pixels only (``ImageEdges.line_id``) and
    LiDAR samples / image pixels with a parallel edge closer than that beside them (``unresolved_edges``) are not
    matched.
    Returns (index into scene.lidar.points, line point m (n,2), line normal (n,2), residual (n,))."""
    ie = scene.image
    if ie.tree is None or len(scene.lidar.points) == 0:
        return np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)
    uv, dirs_uv, ok = _project_edges(scene, T, separation_px)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)
    hd = np.all(np.isfinite(dirs_uv[idx]), axis=1)
    d2 = np.where(hd[:, None], dirs_uv[idx], 0.0)
    # the k nearest edge pixels *of the nearest pixel's own image line* (when the edges know their lines): two
    # parallel image lines a few px apart (both borders of a thin stripe) would otherwise give a non-linear or an
    # in-between local line - a sample between them unmatched, one beside them matched, a pull that depends on depth
    dist, nn = ie.tree.query(uv[idx], k=k if separation_px <= 0 else 3 * k, distance_upper_bound=radius)  # the model off: the k nearest
    fin = np.isfinite(dist)
    nn = np.where(fin, nn, 0)
    line_id = ie.line_id if separation_px > 0 else None
    use = fin if separation_px <= 0 else fin & _resolved_pixels(ie, separation_px)[nn]
    if line_id is not None:
        first = nn[np.arange(len(nn)), np.argmax(use, axis=1)]  # the nearest usable pixel's line
        use &= line_id[nn] == line_id[first][:, None]
    use &= np.cumsum(use, axis=1) <= k
    cnt = use.sum(1)
    full = cnt >= (k if line_id is None else min(k, 3))
    idx, d2, nn, uvp, hd, use, cnt = idx[full], d2[full], nn[full], uv[idx][full], hd[full], use[full], cnt[full].astype(float)
    wu = use.astype(float)
    pts = ie.uv[nn]  # (n,k,2); (n,3k,2) with the thin-stripe model
    m = np.einsum("nk,nki->ni", wu, pts) / cnt[:, None]
    c = (pts - m[:, None, :]) * wu[..., None]
    cov = np.einsum("nki,nkj->nij", c, c) / cnt[:, None, None]
    w, V = np.linalg.eigh(cov)
    line_dir = V[:, :, 1]
    linear = w[:, 0] < 0.1 * np.maximum(w[:, 1], 1e-9)
    # direction consistency: projected LiDAR edge vs the image line and vs the pixels' gradient-based directions
    cos_l = np.abs(np.sum(line_dir * d2, 1))
    cos_g = np.einsum("nk,nk->n", wu, np.abs(np.einsum("nki,ni->nk", ie.dirs[nn], d2))) / cnt
    cmax = np.cos(np.radians(max_angle_deg))
    keep = linear & (((cos_l > cmax) & (cos_g > cmax)) | ~hd)
    normal = np.stack([-line_dir[:, 1], line_dir[:, 0]], 1)
    r = np.sum((uvp - m) * normal, 1)
    keep &= np.abs(r) < radius
    return idx[keep], m[keep], normal[keep], r[keep]


def _full_params(x: np.ndarray) -> np.ndarray:
    """The 6 parameters from the first 6 or 3 (translation held at zero)."""
    return np.concatenate([x, np.zeros(6 - len(x))])


def _residual_fn(x, T0, scenes, matches):
    """Signed point-to-line residuals (px) at ``exp(x) T0`` (``x``: see ``_full_params``)."""
    T = _apply(_full_params(x), T0)
    out = []
    for sc, (idx, m, n, _) in zip(scenes, matches):
        if len(idx) == 0:
            continue
        uv, valid, _ = sc.camera.project_from(T, sc.lidar.points[idx])
        r = np.sum((uv - m) * n, 1)
        r[~valid] = 50.0
        out.append(r)
    return np.concatenate(out) if out else np.zeros(0)


def _score_all(scenes, T, cap=20.0):
    vals = [edge_score(sc.camera, T, sc.lidar, sc.image, cap) for sc in scenes]
    w = np.array([max(n, 1) for _, n in vals], float)
    return float(np.sum([s * n for (s, _), n in zip(vals, w)]) / w.sum())


def coarse_rotation_search(scenes: list[EdgeScene], T0: np.ndarray, half_width_deg: float = 6.0, step_deg: float = 1.0, max_points: int = 4000,
                           n_best: int = 3, rng=None, oriented: bool = False) -> list[tuple[np.ndarray, float]]:
    """Grid search over rotations about the camera centre (rotation-vector offsets multiplied on the left, which keeps
    the camera centre fixed) minimising a capped distance-transform score; the ``n_best`` distinct grid minima are
    each polished on a finer grid. With ``oriented`` a LiDAR edge sample scores its distance to the nearest image
    edge *parallel* to its projection (``ImageEdges.oriented_distance``), so that a crease without an image edge
    does not score well by crossing an unrelated one. Returns [(T, score)] best first."""
    rng = rng or np.random.default_rng(0)
    subs = []
    for sc in scenes:
        sel = np.arange(len(sc.lidar.points))
        if len(sel) > max_points:
            sel = rng.choice(len(sel), max_points, replace=False)
        pts = sc.lidar.points[sel]
        dirs = sc.lidar.dirs[sel]
        has = np.all(np.isfinite(dirs), axis=1)
        subs.append((pts, pts + 0.05 * np.where(has[:, None], dirs, 0.0), has, sc.image.oriented_distance() if oriented else None))

    def score(T, cap):
        tot, n = 0.0, 0
        for sc, (pts, pts2, has, od) in zip(scenes, subs):
            uv, valid, _ = sc.camera.project_from(T, pts)
            ins = valid & sc.camera.in_image(uv, 2.0)
            ij = np.round(uv[ins]).astype(int)
            d = sc.image.dist[ij[:, 1], ij[:, 0]]
            if od is not None:
                uv2, _, _ = sc.camera.project_from(T, pts2[ins])
                dd = uv2 - uv[ins]
                b = (np.mod(np.arctan2(dd[:, 1], dd[:, 0]), np.pi) / (np.pi / len(od))).astype(int) % len(od)
                d = np.where(has[ins], od[b, ij[:, 1], ij[:, 0]], d)
            d = np.minimum(d, cap)
            tot += d.sum() + cap * (len(pts) - ins.sum())  # points leaving the image count as misses
            n += len(pts)
        return tot / max(n, 1)

    def grid(center, hw, st, cap):
        g = np.radians(np.arange(-hw, hw + 1e-9, st))
        offs = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
        vals = np.array([score(geometry.T_from_rotvec(o, np.zeros(3)) @ center, cap) for o in offs])
        return offs, vals

    if half_width_deg <= 0:
        return [(T0, score(T0, 8.0))]
    offs, vals = grid(T0, half_width_deg, step_deg, 25.0)
    order = np.argsort(vals)
    picked: list[np.ndarray] = []
    for i in order:
        if all(np.degrees(np.linalg.norm(offs[i] - p)) > 1.5 * step_deg for p in picked):
            picked.append(offs[i])
        if len(picked) >= n_best:
            break
    out = []
    for p in picked:
        c = geometry.T_from_rotvec(p, np.zeros(3)) @ T0
        o2, v2 = grid(c, step_deg, step_deg / 4, 8.0)
        k = int(np.argmin(v2))
        out.append((geometry.T_from_rotvec(o2[k], np.zeros(3)) @ c, float(v2[k])))
    out.sort(key=lambda t: t[1])
    return out


def _weighted_fn(x, T0, scenes, matches, fix_t, sw, t_prior, sigma_t, f_scale):
    r = _residual_fn(x, T0, scenes, matches) * sw
    if fix_t or sigma_t <= 0:
        return r
    t = _apply(_full_params(x), T0)[:3, 3]
    # matches along one edge are strongly correlated: weigh the prior as if ~1 in 10 matches were independent
    return np.concatenate([r, np.sqrt(max(len(r), 10) / 10.0) * f_scale * (t - t_prior) / sigma_t])


def _separation_px(o) -> float:
    """Separation (px) below which two parallel projected LiDAR edges count as unresolved (``unresolved_edges``):
    ``o.unresolved_separation_px``, None = the finest match radius (a second parallel edge closer than that is
    among the 5 nearest image edge pixels of a match); 0: the thin-stripe edge model is off."""
    return float(o.radii_px[-1] if o.unresolved_separation_px is None else o.unresolved_separation_px)


def alignment_costs(scenes, T, o) -> np.ndarray:
    """Per LiDAR edge sample (all scenes, concatenated) its truncated alignment cost (px^2): the squared
    point-to-line distance of its direction-consistent match at the finest radius, capped there; the cap without a
    match; NaN out of view."""
    cap = o.radii_px[-1]
    out = []
    for sc in scenes:
        uv, valid, _ = sc.camera.project_from(T, sc.lidar.points)
        c = np.where(valid & sc.camera.in_image(uv, 2.0), cap * cap, np.nan)
        sep = _separation_px(o)
        if sep > 0:  # samples beside a parallel edge the image cannot resolve are neither matched nor counted
            _, _, resolved = _project_edges(sc, T, sep)
            _, _, seen = _project_edges(sc, T)
            c[seen & ~resolved] = np.nan
        idx, _, _, r = match_edges(sc, T, cap, o.k_neighbours, o.max_angle_deg, sep)  # matches are in view
        c[idx] = np.minimum(r * r, cap * cap)
        out.append(c)
    return np.concatenate(out) if out else np.zeros(0)


def alignment_cost(scenes, T, o) -> float:
    """Truncated alignment cost (px^2): the mean of ``alignment_costs`` over the samples in view. Used to rank
    competing minima (unlike a plain distance-to-any-edge score it cannot be lowered by landing on clutter)."""
    c = alignment_costs(scenes, T, o)
    c = c[np.isfinite(c)]
    return float(c.mean()) if len(c) else 0.0


def _block_ids(scenes, o, sel=None) -> np.ndarray:
    """Bootstrap block of every LiDAR edge sample (all scenes concatenated, or the ``sel`` index per scene): samples
    of one scene in one ``o.bootstrap_block_m`` cube share a block (whole stretches of an edge)."""
    keys = []
    for k, sc in enumerate(scenes):
        p = sc.lidar.points if sel is None else sc.lidar.points[sel[k]]
        keys.append(np.column_stack([np.full(len(p), k), np.floor(p / o.bootstrap_block_m).astype(np.int64)]))
    allk = np.concatenate(keys) if keys else np.zeros((0, 4), np.int64)
    return np.unique(allk, axis=0, return_inverse=True)[1].ravel() if len(allk) else np.zeros(0, int)


def paired_cost_increase(scenes, T_a, T_b, o) -> tuple[float, float]:
    """How much worse ``T_b`` aligns than ``T_a``: (ratio of the alignment costs, t = the mean per-sample cost
    increase over its block-robust standard error). Samples in view at both poses are paired; the standard error
    treats every bootstrap block as one independent unit (samples along one edge are not independent)."""
    ca, cb = alignment_costs(scenes, T_a, o), alignment_costs(scenes, T_b, o)
    both = np.isfinite(ca) & np.isfinite(cb)
    if both.sum() < 6:
        return float("nan"), float("nan")
    d = (cb - ca)[both]
    bid = _block_ids(scenes, o)[both]
    n, mean = len(d), float(d.mean())
    per_block = np.bincount(bid, weights=d) - mean * np.bincount(bid)
    nb = int(np.count_nonzero(np.bincount(bid)))
    se = float(np.sqrt(np.sum(per_block ** 2) * nb / max(nb - 1, 1))) / n
    return float(cb[both].mean() / max(ca[both].mean(), 1e-12)), mean / max(se, 1e-12)


def _run_stages(scenes, T, o, t_prior=None):
    """Coarse-to-fine re-matching and robust least squares from one start. Rotation only at the coarse radii
    (translation is weakly observed and would absorb wrong matches), all 6 parameters at the fine ones."""
    history = []
    converged_stage = False
    t_prior = T[:3, 3].copy() if t_prior is None else t_prior
    for si, radius in enumerate(o.radii_px):
        f_scale = o.loss_scale_px if radius == o.radii_px[-1] else max(o.loss_scale_px, radius / 4)
        rot_only = o.fix_translation or si < o.rotation_only_stages
        converged_stage = False
        for it in range(o.max_rematch):
            matches = [match_edges(sc, T, radius, o.k_neighbours, o.max_angle_deg, _separation_px(o)) for sc in scenes]
            n = sum(len(m[0]) for m in matches)
            if n < max(12, o.min_matches // 4):
                history.append({"stage": f"r={radius:g}", "iter": it, "matches": n, "note": "too few matches"})
                break
            x0 = np.zeros(3 if rot_only else 6)
            # IRLS with Cauchy weights (fixed per re-matching) so that the translation prior stays quadratic
            r0 = _residual_fn(x0, T, scenes, matches)
            sw = 1.0 / np.sqrt(1.0 + (r0 / f_scale) ** 2)
            res = least_squares(_weighted_fn, x0, args=(T, scenes, matches, rot_only, sw, t_prior, o.translation_prior_m, f_scale),
                                x_scale=np.array([1e-3] * 3 + [1e-2] * 3)[:len(x0)], method="trf", max_nfev=50)
            x = _full_params(res.x)
            T = _apply(x, T)
            dr, dt = np.linalg.norm(x[:3]), np.linalg.norm(x[3:])
            history.append({"stage": f"r={radius:g}", "iter": it, "matches": n, "cost": float(res.cost), "step_rot_deg": float(np.degrees(dr)), "step_trans_m": float(dt)})
            if dr < o.tol_rot_rad and dt < o.tol_trans_m:
                converged_stage = True
                break
    return T, converged_stage, history


def _coupled_directions(scenes, T) -> list[np.ndarray]:
    """The two parameter combinations edge alignment observes worst: a sideways (vertical) camera shift compensated
    by the yaw (pitch) that keeps points at the median edge depth Z in place - (0, -1/Z, 0, 1, 0, 0) and
    (1/Z, 0, 0, 0, 1, 0) per metre of translation."""
    z = np.concatenate([(sc.lidar.points @ T[:3, :3].T + T[:3, 3])[:, 2] for sc in scenes]) if scenes else np.zeros(0)
    z = z[z > 0.3]
    Z = float(np.median(z)) if len(z) else 10.0
    return [np.array([0.0, -1.0 / Z, 0.0, 1.0, 0.0, 0.0]), np.array([1.0 / Z, 0.0, 0.0, 0.0, 1.0, 0.0])]


def _valley_directions(scenes, T, o) -> list[np.ndarray]:
    """Restart directions of the valley search: the two coupled shift/rotation directions and, with
    ``o.valley_depth``, the optical axis (0, 0, 0, 0, 0, 1) - the translation a far or floor-dominated scene
    observes least (on family2 field scenes right rotations ended 6-10 cm off along it with a higher cost than at
    the truth)."""
    dirs = _coupled_directions(scenes, T)
    if o.valley_depth:
        dirs.append(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0]))
    return dirs


def _valley_restarts(scenes, T, conv, o, T0):
    """The usual wrong minimum trades a sideways (vertical) camera shift against a yaw (pitch): restart the whole
    schedule from the result moved along these coupled directions (translation +-``valley_steps_m`` with the
    compensating rotation) and adopt a lower truncated alignment cost (by ``valley_margin``); repeat from the new result."""
    hist = []
    cost_T = alignment_cost(scenes, T, o)
    settled = False
    for rnd in range(o.valley_rounds):
        best = None
        for v in _valley_directions(scenes, T, o):
          for step in o.valley_steps_m:
            for sg in (-1.0, 1.0):
                Tk = _apply(sg * step * v, T)
                Tk2, conv_k, _ = _run_stages(scenes, Tk, o, t_prior=T0[:3, 3])
                ck = alignment_cost(scenes, Tk2, o)
                hist.append({"stage": "valley", "round": rnd, "step_m": sg * step, "cost": ck, "cost_result": cost_T, "T": Tk2})
                if best is None or ck < best[0]:
                    best = (ck, Tk2, conv_k)
        if best is None or best[0] >= cost_T * (1 - o.valley_margin):
            settled = True
            break
        cost_T, T, conv = best
    return T, conv, settled, hist


def refine_edges(scenes: list[EdgeScene], T_init: np.ndarray, options: RefineOptions | None = None) -> RefineResult:
    """Refine ``T_cam_lidar`` over one or more scenes. Never raises on poor data: ``converged`` and ``message``
    say what happened."""
    o = options or RefineOptions()
    T0 = np.asarray(T_init, float)
    warnings: list[str] = []
    history: list[dict] = []
    score_before = _score_all(scenes, T0)
    starts = _start_poses(scenes, T0, o, history)
    matches0 = [match_edges(sc, T0, o.radii_px[-1], o.k_neighbours, o.max_angle_deg, _separation_px(o)) for sc in scenes]
    residuals_before = np.concatenate([m[3] for m in matches0]) if matches0 else np.zeros(0)
    T, converged_stage = _best_start(scenes, starts, o, T0, history)
    valley_settled = True
    if o.valley_steps_m and not o.fix_translation:
        T, converged_stage, valley_settled, vh = _valley_restarts(scenes, T, converged_stage, o, T0)
        history += vh
    T, converged_stage, stable = _stability_restarts(scenes, T, converged_stage, o, T0, history)
    # final matching, statistics
    matches = [match_edges(sc, T, o.radii_px[-1], o.k_neighbours, o.max_angle_deg, _separation_px(o)) for sc in scenes]
    n_match = sum(len(m[0]) for m in matches)
    r_after = _residual_fn(np.zeros(6), T, scenes, matches)
    inl = np.abs(r_after) < 3 * o.loss_scale_px
    rms = float(np.sqrt(np.mean(r_after[inl] ** 2))) if inl.any() else float("nan")
    mean_abs = float(np.mean(np.abs(r_after))) if len(r_after) else float("nan")
    sigma, JtJ = _jacobian_sigma(scenes, matches, T, o, n_match)
    sigma_boot, boot_samples = block_bootstrap_sigma(scenes, matches, T, o, return_samples=True) if o.bootstrap > 0 and n_match >= 6 else (np.full(6, np.nan), np.zeros((0, 6)))
    jackknife = sector_jackknife(scenes, matches, T, o) if o.bootstrap > 0 and o.jackknife_grid > 0 and n_match >= 6 else np.zeros((0, 9))
    n_in_view = 0
    for sc in scenes:
        uv_, valid_, _ = sc.camera.project_from(T, sc.lidar.points)
        n_in_view += int((valid_ & sc.camera.in_image(uv_, 2.0)).sum())
    match_fraction = n_match / max(n_in_view, 1)
    obs = _observability(scenes, matches, T, JtJ, n_match)
    obs["match_fraction"] = match_fraction
    warnings += obs["warnings"]
    score_after = _score_all(scenes, T)
    # convergence verdict
    moved_deg, moved_m = geometry.pose_error(T, T0)
    stable = stable and valley_settled
    restarts = _restart_offsets(scenes, T, o, history)
    # camera centre in the LiDAR frame: what a tape measure gives; a wrong minimum can drag it far away
    centre_move = float(np.linalg.norm(geometry.invert_T(T)[:3, 3] - geometry.invert_T(T0)[:3, 3]))
    checks = {"sigma_bootstrap": sigma_boot.tolist(), "bootstrap_samples": boot_samples.tolist(), "sigma_jacobian": sigma.tolist(), "centre_move_m": centre_move,
              "converged_stage": bool(converged_stage), "stable": bool(stable), "valley_settled": bool(valley_settled), "match_fraction": float(match_fraction),
              "n_matches": int(n_match), "rms_px": rms, "score_before": score_before, "score_after": score_after, "moved_deg": moved_deg, "moved_m": moved_m, "restarts": restarts,
              "sector_jackknife": jackknife.tolist()}
    ok, msg = edge_verdict(checks, o)
    if np.all(np.isfinite(sigma_boot)):
        sigma_boot = sigma_for_verdict(checks, o)  # reported: robust spread, ambiguity, floor (the raw std stays in checks)
    prof = cost_profiles(scenes, T, matches, o.loss_scale_px)
    return RefineResult(T, T0, bool(ok), msg, rms, mean_abs, n_match, int(inl.sum()), sigma, score_before, score_after, obs, warnings, history,
                        _match_arrays(scenes, T, matches), residuals_before, r_after, prof, sigma_boot, checks)


def refine_edges_choosing(candidates: dict[str, list[EdgeScene]], referee: list[EdgeScene], T_init: np.ndarray,
                          options: RefineOptions | None = None) -> tuple[str, dict[str, RefineResult], dict[str, float]]:
    """Refine once per candidate image-edge set (the same LiDAR edges, e.g. LSD and LSD+Canny) and keep the result
    whose pose has the lowest truncated alignment cost (px^2) against the ``referee`` edges (Canny chains: every
    image edge, so a set that missed low-contrast edges cannot win by ignoring them). The costs of the candidates
    are each measured on their own edges and cannot be compared directly. Returns (name, result, referee cost per
    candidate)."""
    o = options or RefineOptions()
    results = {name: refine_edges(scenes, T_init, o) for name, scenes in candidates.items()}
    costs = {name: alignment_cost(referee, r.T_cam_lidar, o) for name, r in results.items()}
    best = min(costs, key=costs.get)
    return best, results, costs


def _start_poses(scenes, T0, o, history) -> list[np.ndarray]:
    """Starts of the coarse-to-fine schedule: ``T0``, the best rotations of the coarse grid search (logged to
    ``history``) and, with ``translation_starts_m``, the best one shifted +-that along each axis."""
    if o.coarse_search_deg <= 0:
        return [T0]
    starts = coarse_rotation_search(scenes, T0, o.coarse_search_deg, o.coarse_step_deg, n_best=o.n_starts, oriented=o.coarse_oriented)
    for Tc, sc_ in starts:
        history.append({"stage": "coarse-rotation", "score": sc_, "rot_change_deg": geometry.pose_error(Tc, T0)[0]})
    starts = [T0] + [t for t, _ in starts]
    if o.translation_starts_m > 0 and not o.fix_translation:
        Tb = starts[1]
        for ax in range(3):
            for sg in (-1, 1):
                Tt = Tb.copy()
                Tt[ax, 3] += sg * o.translation_starts_m
                starts.append(Tt)
    return starts


def _best_start(scenes, starts, o, T0, history) -> tuple[np.ndarray, bool]:
    """The whole schedule from every start; the result with the lowest capped edge score at the finest radius wins."""
    best = None
    for k, Ts in enumerate(starts):
        T, conv, hist = _run_stages(scenes, Ts, o, t_prior=T0[:3, 3])
        fine = _score_all(scenes, T, cap=o.radii_px[-1])
        history += [{"start": k, **h} for h in hist]
        history.append({"start": k, "final_score_px": fine, "converged": conv})
        if best is None or fine < best[0]:
            best = (fine, T, conv)
    _, T, converged_stage = best
    return T, converged_stage


def _stability_restarts(scenes, T, converged_stage, o, T0, history) -> tuple[np.ndarray, bool, bool]:
    """Stability check: restarts from the result moved by stability_deg / stability_m (whole coarse-to-fine schedule)
    must come back to it; a clearly better minimum nearby is adopted (up to three rounds), one about as good makes
    the result not stable. Returns (T, converged_stage, stable)."""
    stable = True
    if o.stability_checks <= 0:
        return T, converged_stage, stable
    rng = np.random.default_rng(12345)
    fine_opts = o if o.stability_full else RefineOptions(**{**o.__dict__, "radii_px": o.radii_px[-3:], "rotation_only_stages": 0})
    cost_T = alignment_cost(scenes, T, o)
    for rnd in range(3):
        improved = False
        for k in range(o.stability_checks):
            # with a fixed (measured) translation only the rotation is restarted: a moved translation could not come back
            Tk = geometry.perturb_T(T, o.stability_deg, 0.0 if o.fix_translation else o.stability_m, rng)
            if o.stability_full and o.coarse_search_deg > 0:
                Tk = coarse_rotation_search(scenes, Tk, min(o.coarse_search_deg, 2 * o.stability_deg), o.coarse_step_deg / 2, n_best=1, oriented=o.coarse_oriented)[0][0]
            Tk2, conv_k, _ = _run_stages(scenes, Tk, fine_opts, t_prior=T0[:3, 3])
            ck = alignment_cost(scenes, Tk2, o)
            dd, dm = geometry.pose_error(Tk2, T)
            history.append({"stage": "stability", "round": rnd, "check": k, "cost": ck, "cost_result": cost_T, "back_deg": dd, "back_m": dm, "T": Tk2})
            if dd <= o.stability_tol_deg and dm <= o.stability_tol_m:
                continue
            if ck < cost_T * (1 - o.stability_margin):  # a clearly better minimum nearby: adopt it, check again
                T, cost_T, converged_stage, improved = Tk2, ck, conv_k, True
                break
            if ck < cost_T * (1 + o.stability_margin):  # a different minimum about as good: ambiguous
                stable = False
        if not improved:
            break
    return T, converged_stage, stable


def _jacobian_sigma(scenes, matches, T, o, n_match) -> tuple[np.ndarray, np.ndarray]:
    """Sigma of the 6 parameters from the Jacobian at the solution (robust-weighted; inf when under-determined) and
    J^T J (zeros with fewer than 6 matches)."""
    sigma = np.full(6, np.inf)
    JtJ = np.zeros((6, 6))
    if n_match >= 6:
        fin = least_squares(_residual_fn, np.zeros(6), args=(T, scenes, matches), loss="cauchy", f_scale=o.loss_scale_px,
                            x_scale=np.array([1e-3] * 3 + [1e-2] * 3), max_nfev=1)
        J = fin.jac
        JtJ = J.T @ J
        s2 = 2 * fin.cost / max(1, len(fin.fun) - 6)
        try:
            cov = np.linalg.inv(JtJ) * s2
            sigma = np.sqrt(np.abs(np.diag(cov)))
        except np.linalg.LinAlgError:
            pass
    return sigma, JtJ


def _restart_offsets(scenes, T, o, history) -> list:
    """Where the restarts (valley and stability) ended, as parameter offsets (rotvec, translation) from the result,
    and their cost ratio to it; takes the restarts' poses out of ``history``."""
    cost_final = alignment_cost(scenes, T, o) if any(h.get("stage") in ("valley", "stability") for h in history) else float("nan")
    restarts = []
    for h in history:
        if h.get("stage") in ("valley", "stability"):
            dT = h.pop("T") @ geometry.invert_T(T)
            restarts.append([*geometry.R_to_rotvec(dT[:3, :3]).tolist(), *dT[:3, 3].tolist(), float(h["cost"] / max(cost_final, 1e-12))])
    return restarts


def _match_arrays(scenes, T, matches) -> dict:
    """The final matching's arrays per scene (LiDAR xyz, projected uv, matched line point and normal) for a report."""
    mt = {}
    for k, (sc, (idx, m, n, r)) in enumerate(zip(scenes, matches)):
        uv, _, _ = sc.camera.project_from(T, sc.lidar.points[idx])
        mt[f"scene{k}_lidar_xyz"] = sc.lidar.points[idx]
        mt[f"scene{k}_uv"] = uv
        mt[f"scene{k}_line_point"] = m
        mt[f"scene{k}_line_normal"] = n
    return mt


def edge_verdict(checks: dict, o: RefineOptions) -> tuple[bool, str]:
    """The convergence verdict from the refinement's own checks (``RefineResult.checks``): pure, so that it can be
    calibrated on stored sweeps. Returns (converged, message)."""
    centre_move, converged_stage, stable = checks["centre_move_m"], checks["converged_stage"], checks["stable"]
    valley_settled, match_fraction, n_match, rms = checks["valley_settled"], checks["match_fraction"], checks["n_matches"], checks["rms_px"]
    score_before, score_after, moved_deg, moved_m = checks["score_before"], checks["score_after"], checks["moved_deg"], checks["moved_m"]
    sig = sigma_for_verdict(checks, o)
    boot_deg, boot_m = float(np.degrees(np.max(sig[:3]))), float(np.max(sig[3:]))
    depth_limit = o.max_bootstrap_sigma_m if o.max_bootstrap_sigma_depth_m is None else o.max_bootstrap_sigma_depth_m
    weak = bool(np.all(np.isfinite(sig))) and (boot_deg > o.max_bootstrap_sigma_deg or float(np.max(sig[3:5])) > o.max_bootstrap_sigma_m or float(sig[5]) > depth_limit)
    ok = bool(not weak and centre_move <= o.max_translation_move_m and converged_stage and stable and match_fraction >= o.min_match_fraction and n_match >= o.min_matches and np.isfinite(rms) and rms < 2.5 * o.loss_scale_px and score_after <= score_before + 0.05)
    if centre_move > o.max_translation_move_m:
        msg = (f"did not converge: the camera centre moved {centre_move:.2f} m from the initial guess (> {o.max_translation_move_m:g} m) - "
               f"a wrong minimum; give --init with the measured lever arm or add scenes")
    elif weak and converged_stage and stable and match_fraction >= o.min_match_fraction:
        msg = (f"did not converge: weakly constrained - resampling the edges or leaving out one image region moves the result by {boot_deg:.2f} deg / {boot_m * 100:.1f} cm (1 sigma, "
               f"> {o.max_bootstrap_sigma_deg:g} deg / {o.max_bootstrap_sigma_m * 100:g} cm across, {depth_limit * 100:g} cm along the optical axis); add scenes with near and far structure, or measure the translation (--rotation-only)")
    elif match_fraction < o.min_match_fraction:
        msg = f"did not converge: only {100 * match_fraction:.0f} % of the LiDAR edge samples in view found an image edge (< {100 * o.min_match_fraction:.0f} %) - probably a wrong minimum"
    elif converged_stage and not valley_settled:
        msg = f"did not converge: restarts along the shift/rotation-coupled directions were still finding lower costs after {o.valley_rounds} rounds"
    elif converged_stage and not stable:
        msg = f"did not converge: restarts from the result ({o.stability_deg:g} deg / {o.stability_m * 100:g} cm away) settle elsewhere - the minimum is not well defined (more or closer structure, another scene, or a better initial guess)"
    elif not converged_stage:
        msg = f"did not converge: the update was still moving at the finest radius after {o.max_rematch} re-matchings (improve the initial guess or add scenes)"
    elif n_match < o.min_matches:
        msg = f"did not converge: only {n_match} edge matches at the finest radius (< {o.min_matches}); the initial guess is probably too far off or the scene has too few plane-plane edges"
    elif not (np.isfinite(rms) and rms < 2.5 * o.loss_scale_px):
        msg = f"did not converge: residual {rms:.2f} px is too large for an aligned solution"
    elif score_after > score_before + 0.05:
        msg = f"did not converge: the edge score got worse ({score_before:.2f} -> {score_after:.2f} px)"
    else:
        msg = f"converged: {n_match} matches, rms {rms:.2f} px, moved {moved_deg:.3f} deg / {moved_m * 100:.1f} cm from the initial guess"
    return ok, msg


def _reweighted_solve(scenes, matches, T, weights, n_par, o) -> np.ndarray:
    """The 6 parameters (a move from ``T``) re-solved robustly (Cauchy) with the matches held and each residual
    multiplied by ``weights`` (resampling counts, or 0 for left-out matches); ``n_par`` 3 holds the translation."""
    res = least_squares(lambda x: weights * _residual_fn(x, T, scenes, matches), np.zeros(n_par), loss="cauchy", f_scale=o.loss_scale_px,
                        x_scale=np.array([1e-3] * 3 + [1e-2] * 3)[:n_par], max_nfev=30)
    return _full_params(res.x)


def block_bootstrap_sigma(scenes, matches, T, o: RefineOptions, return_samples: bool = False):
    """Spread (1 sigma, rx ry rz rad, tx ty tz m) of the 6 parameters over ``o.bootstrap`` robust re-solves in
    which the matched LiDAR edge samples are resampled with replacement in spatial blocks of
    ``o.bootstrap_block_m`` (whole stretches of an edge at once), matches held fixed. Unlike the Jacobian sigma it
    keeps the correlation of the samples along one edge and the spread of per-edge biases; on generated scenes
    it is 1.1-3.6x the Jacobian figure (docs/lidar_camera.md), still not the whole error (biases shared by every
    edge, a wrong minimum)."""
    bid = _block_ids(scenes, o, [idx for idx, _, _, _ in matches])
    none = (np.full(6, np.nan), np.zeros((0, 6))) if return_samples else np.full(6, np.nan)
    if len(bid) < 6:
        return none
    nb = int(bid.max()) + 1
    if nb < 4:
        return none
    rng = np.random.default_rng(2024)
    n_par = 3 if o.fix_translation else 6
    xs = []
    for _ in range(o.bootstrap):
        xs.append(_reweighted_solve(scenes, matches, T, np.sqrt(np.bincount(rng.integers(0, nb, nb), minlength=nb).astype(float))[bid], n_par, o))
    xs = np.asarray(xs)
    sd = np.std(xs, axis=0, ddof=1)
    return (sd, xs) if return_samples else sd



def sector_jackknife(scenes, matches, T, o: RefineOptions) -> np.ndarray:
    """Leave-one-sector-out re-solves: each scene's image cut into ``o.jackknife_grid`` x ``o.jackknife_grid`` sectors, the matches
    of one sector (with at least ``o.jackknife_min_matches``) left out and the 6 parameters re-solved robustly,
    matches held fixed. Rows (scene, sector, matches left out, rx ry rz rad, tx ty tz m: the move from ``T``)."""
    rows, sectors = [], []
    for k, (sc, (idx, _, _, _)) in enumerate(zip(scenes, matches)):
        uv, _, _ = sc.camera.project_from(T, sc.lidar.points[idx])
        w, h = sc.camera.image_size
        g = o.jackknife_grid
        sectors.append(k * g * g + np.clip((uv[:, 1] * g / h).astype(int), 0, g - 1) * g + np.clip((uv[:, 0] * g / w).astype(int), 0, g - 1))
    sector = np.concatenate(sectors) if sectors else np.zeros(0, int)
    n_par = 3 if o.fix_translation else 6
    for s_id in np.unique(sector):
        out = sector == s_id
        if out.sum() < o.jackknife_min_matches or (~out).sum() < 6:
            continue
        g2 = o.jackknife_grid ** 2
        rows.append([s_id // g2, s_id % g2, int(out.sum()), *_reweighted_solve(scenes, matches, T, (~out).astype(float), n_par, o)])
    return np.asarray(rows, float).reshape(-1, 9)


def cost_profiles(scenes, T, matches, f_scale=1.0, rot_deg: float = 1.0, trans_m: float = 0.1, n: int = 21) -> dict:
    """Robust cost (Cauchy, fixed matches) along each of the 6 parameters around ``T``: a flat profile means the
    parameter is poorly observed."""

    def robust_cost(x):
        r = _residual_fn(x, T, scenes, matches)
        return float(np.sum(np.log1p((r / f_scale) ** 2))) if len(r) else np.nan

    offs, costs = parameter_profiles(robust_cost, np.zeros(6), [np.radians(rot_deg)] * 3 + [trans_m] * 3, n)
    return {name: (offs[i], costs[i]) for i, name in enumerate(PARAM_NAMES)}


def _observability(scenes, matches, T, JtJ, n_match) -> dict:
    warnings = []
    normals = np.concatenate([m[2] for m in matches]) if n_match else np.zeros((0, 2))
    if len(normals):
        S = normals.T @ normals / len(normals)
        ev = np.linalg.eigvalsh(S)
        spread = float(ev[0] / max(ev[1], 1e-12))
    else:
        spread = 0.0
    if n_match < 100:
        warnings.append(f"only {n_match} edge matches: the result is weakly constrained")
    if spread < 0.1:
        warnings.append(f"edge directions are nearly all parallel (spread {spread:.3f} < 0.1): one rotation/translation direction is unobserved")
    cond = float("inf")
    weakest = None
    if np.all(np.isfinite(JtJ)) and np.any(JtJ):
        D = np.sqrt(np.maximum(np.diag(JtJ), 1e-30))
        Jn = JtJ / np.outer(D, D)
        w, V = np.linalg.eigh(Jn)
        cond = float(w[-1] / max(w[0], 1e-30))
        weakest = {PARAM_NAMES[i]: round(float(V[i, 0]), 3) for i in range(6)}
        if cond > 1e4:
            warnings.append(f"poorly conditioned (condition number {cond:.1e}); weakest direction {weakest}")
    return {"direction_spread": spread, "condition_number": cond, "weakest_direction": weakest, "n_matches": int(n_match), "warnings": warnings}


def sigma_for_verdict(checks: dict, o: RefineOptions | None = None) -> np.ndarray:
    """The 1-sigma (rx ry rz rad, tx ty tz m) the verdict uses and the command reports, per parameter the larger of

    * the block bootstrap's robust spread: half the 16-84 % interval of the re-solves (a few resamples that lose
      the near structure run far along the weakly observed direction; their standard deviation once said 9 cm where
      the result was 1.6 cm from the truth), and
    * the ambiguity: the largest offset of a restart (valley or stability) that ended elsewhere at an alignment cost
      within ``o.ambiguity_cost_ratio`` of the result's - a minimum about as good that the data cannot rule out, and
    * the sector jackknife (``sector_jackknife``): the largest move of the result when one image sector's matches
      are left out - a result that one region of the image pulls (a bias the bootstrap, resampling small blocks
      around the same minimum, does not see: family2 seeds 208, 218, 228 were 5.6-7.8 cm off along the optical axis
      with a bootstrap spread of 1.3-2.2 cm), and
    * the Jacobian sigma (a lower bound), and
    * a floor for the biases every edge shares (``o.sigma_floor_deg`` / ``o.sigma_floor_m``: right results on the
      structured family were up to 1.3 cm off with a bootstrap spread of 0.1-0.3 cm).
    Falls back to the standard deviation when the samples were not kept."""
    o = o or RefineOptions()
    xs = np.asarray(checks.get("bootstrap_samples", []), float).reshape(-1, 6)
    if len(xs) >= 10:
        sig = 0.5 * (np.percentile(xs, 84, axis=0) - np.percentile(xs, 16, axis=0))
    else:
        sig = np.asarray(checks["sigma_bootstrap"], float).copy()
    rs = np.asarray(checks.get("restarts", []), float).reshape(-1, 7)
    close = rs[rs[:, 6] <= o.ambiguity_cost_ratio, :6] if len(rs) else np.zeros((0, 6))
    if len(close):
        sig = np.maximum(sig, np.abs(close).max(axis=0))
    jk = np.asarray(checks.get("sector_jackknife", []), float).reshape(-1, 9)
    if len(jk):
        sig = np.maximum(sig, np.abs(jk[:, 3:]).max(axis=0))
    jac = np.asarray(checks.get("sigma_jacobian", np.zeros(6)), float)
    sig = np.maximum(sig, np.where(np.isfinite(jac), jac, 0.0))  # never below the Jacobian's lower bound
    return np.maximum(sig, np.array([np.radians(o.sigma_floor_deg)] * 3 + [o.sigma_floor_m] * 3))
