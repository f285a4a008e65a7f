"""Dynamic points -> robot clusters.

Points (field frame) go into a voxel grid (``voxel_xy`` x ``voxel_xy`` x ``voxel_z``); occupied voxels are joined
to their neighbours (connected components, :func:`connected_labels`) — within one voxel
near the sensor (the *strict* set) and within two beyond ``loose_range_m`` (the *loose* set: a far robot gets few,
scattered returns from the sparse rosette). This is Euclidean clustering with eps ~ one or two voxels, on voxels, so
its cost follows the number of occupied voxels, not of points. Each component is gated by size (robot footprint
``footprint_m``, top ``height_m`` above the surface; an aerial robot's cluster floats ``aerial_min_m`` above the
field) and by a point count that falls with range; a component wider than ``split_m`` (two robots touching) is split
by k-means on x, y into ``ceil(width / robot_m)`` parts, which are gated again.

The robot's centre, along the horizontal viewing direction: ``push_face_m`` behind the nearest return, or mid-way
between the nearest and the farthest when they span more (the top face seen from 2.5 m up); across it: the
centroid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ClusterParams", "Clusters", "cluster_points", "connected_labels", "REJECT_REASONS"]

# the first gate a component failed (Clusters.rejected): what a miss breakdown reports
REJECT_REASONS = ("kept", "too few points", "aerial gate (footprint / thickness)", "footprint too small", "footprint too large", "top too low", "top too high",
                  "bottom too high (not aerial)")  # fmt: skip


@dataclass
class ClusterParams:
    voxel_xy: float = 0.1
    voxel_z: float = 0.15
    loose_range_m: float = 10.0
    min_points_near: int = 8  # strict set (HITSZ: 12 / 0.15 eps strict, 6 / 0.4 loose)
    min_points_far: int = 3  # at 25 m and beyond
    min_points_sparse: int = 3  # a sparse component (Clusters.sparse) a track may take (pipeline: 2 LiDAR only)
    footprint_m: tuple[float, float] = (0.12, 1.2)
    height_m: tuple[float, float] = (0.12, 1.6)  # top above the surface
    max_bottom_m: float = 0.6  # a ground robot's lowest point above the surface (lower parts may be filtered/hidden)
    aerial_min_m: float = 0.9  # an aerial robot's lowest point above the surface
    aerial_extent_m: float = 0.9
    split_m: float = 0.95
    merge_gap_m: float = 0.3
    merge_max_m: float = 0.75
    robot_m: float = 0.65
    push_aerial_m: float = 0.4  # the aerial robot is ~0.8 m across
    sparse_aerial: bool = True  # the aerial robot's sparse returns as Clusters.sparse too (pipeline: LiDAR only)
    push_face_m: float = 0.30  # nearest return -> centre along the view (0.5 m robots at a random heading: 0.32 on average)


@dataclass
class Clusters:
    """K clusters: ``centre`` (K,3) robot centre (z = lowest point's surface for ground robots, the cluster's
    mid-height for aerial ones), ``centroid`` (K,3), ``lo``/``hi`` (K,3) extents, ``n`` (K,) points, ``t`` (K,) mean
    point time, ``aerial`` (K,) bool, ``range_m`` (K,), ``labels`` (M,) cluster of every input point (-1 none)."""

    centre: np.ndarray
    centroid: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    n: np.ndarray
    t: np.ndarray
    aerial: np.ndarray
    range_m: np.ndarray
    labels: np.ndarray
    component: np.ndarray | None = None  # (M,) component of every input point before the gates (-1 none)
    rejected: np.ndarray | None = None  # (C,) why each component failed the gates: a REJECT_REASONS index, 0 = kept
    sparse: "Clusters | None" = None  # rejected components a robot's track may take (few points, small; not larger than a robot)

    def __len__(self) -> int:
        return len(self.n)


def _offsets(r_xy: int, r_z: int) -> np.ndarray:
    g = np.array(np.meshgrid(np.arange(-r_xy, r_xy + 1), np.arange(-r_xy, r_xy + 1), np.arange(-r_z, r_z + 1), indexing="ij")).reshape(3, -1).T
    # half of the neighbourhood (the graph is symmetric)
    lin = (g[:, 0] * 1000 + g[:, 1]) * 1000 + g[:, 2]
    return g[lin > 0]


_NEAR = _offsets(1, 1)


def connected_labels(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected components of the undirected graph on ``n`` nodes with edges ``a[i] - b[i]``: label (n,) per node,
    0..k-1 numbered in the order of each component's smallest node (as ``scipy.sparse.csgraph.connected_components``
    numbers them). Vectorised union-find: every root is hooked onto the smallest root across its edges, then labels
    are compressed by pointer jumping, until no edge joins two roots. A few numpy passes for robot-sized graphs,
    without scipy.sparse's per-call checks (which cost more than the search on a few hundred voxels)."""
    lab = np.arange(n)
    if n == 0 or len(a) == 0:
        return lab
    a, b = np.asarray(a, np.int64), np.asarray(b, np.int64)
    while True:
        la, lb = lab[a], lab[b]
        diff = la != lb
        if not diff.any():
            break
        la, lb = la[diff], lb[diff]
        m = np.minimum(la, lb)
        np.minimum.at(lab, la, m)  # la, lb are roots (lab[r] == r): hooks go to smaller labels only, no cycles
        np.minimum.at(lab, lb, m)
        while True:
            nxt = lab[lab]
            if np.array_equal(nxt, lab):
                break
            lab = nxt
    return np.unique(lab, return_inverse=True)[1].reshape(-1)


def _components(vox: np.ndarray) -> np.ndarray:
    """Connected components (26-neighbourhood) of occupied voxels ``vox`` (V,3) int."""
    V = len(vox)
    base = vox.min(0) - 2
    span = vox.max(0) + 2 - base + 1
    key = ((vox[:, 0] - base[0]) * span[1] + (vox[:, 1] - base[1])) * span[2] + (vox[:, 2] - base[2])
    order = np.argsort(key)
    ks = key[order]
    okey = (_NEAR[:, 0] * span[1] + _NEAR[:, 1]) * span[2] + _NEAR[:, 2]
    qk = key[:, None] + okey[None]
    pos = np.minimum(np.searchsorted(ks, qk), V - 1)
    hit = ks[pos] == qk
    a = np.broadcast_to(np.arange(V)[:, None], qk.shape)[hit]
    b = order[pos[hit]]
    return connected_labels(V, a, b)


def _kmeans_split(xy: np.ndarray, k: int, iters: int = 6) -> np.ndarray:
    """Labels (N,) of ``k`` groups along the principal axis of ``xy`` (N,2) (k-means seeded on that axis)."""
    c = xy.mean(0)
    u = np.linalg.svd(xy - c, full_matrices=False)[2][0]
    s = (xy - c) @ u
    cent = c + np.quantile(s, (np.arange(k) + 0.5) / k)[:, None] * u
    lab = np.zeros(len(xy), np.int64)
    for _ in range(iters):
        lab = np.argmin(((xy[:, None] - cent[None]) ** 2).sum(-1), axis=1)
        for j in range(k):
            m = lab == j
            if m.any():
                cent[j] = xy[m].mean(0)
    return lab


def _merge_close(p: np.ndarray, comp: np.ndarray, q: ClusterParams) -> np.ndarray:
    """Join components of one robot that sparse sampling left apart: x-y boxes closer than ``merge_gap_m`` whose
    union stays within ``merge_max_m`` (and at the same height class). Components are few; pairs are vectorised."""
    nc = comp.max() + 1
    if nc < 2:
        return comp
    lo = np.full((nc, 3), np.inf)  # component labels here are roots, not 0..nc-1: the absent ones stay empty
    hi = np.full((nc, 3), -np.inf)
    present, compact = np.unique(comp, return_inverse=True)
    lo[present], hi[present] = _group_min_max(p, *_groups(compact.reshape(-1), len(present)))
    gap = np.maximum(0.0, np.maximum(lo[:, None, :2] - hi[None, :, :2], lo[None, :, :2] - hi[:, None, :2])).max(-1)
    union = (np.maximum(hi[:, None, :2], hi[None, :, :2]) - np.minimum(lo[:, None, :2], lo[None, :, :2])).max(-1)
    zgap = np.maximum(0.0, np.maximum(lo[:, None, 2] - hi[None, :, 2], lo[None, :, 2] - hi[:, None, 2]))
    join = (gap < q.merge_gap_m) & (union <= q.merge_max_m) & (zgap < 0.5)
    np.fill_diagonal(join, False)
    if not join.any():
        return comp
    a, b = np.nonzero(join)
    return connected_labels(nc, a, b)[comp]


def _groups(comp: np.ndarray, nc: int) -> tuple[np.ndarray, np.ndarray]:
    """The points' order grouped by component (``comp`` (M,) in 0..nc-1, every component non-empty) and where each
    group starts in it."""
    order = np.argsort(comp, kind="stable")
    return order, np.searchsorted(comp[order], np.arange(nc))


def _group_min_max(v: np.ndarray, order: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-component min and max of ``v`` (M,) or (M,D) (:func:`_groups`; reduceat: ufunc.at was the slow part)."""
    s = v[order]
    return np.minimum.reduceat(s, starts, axis=0), np.maximum.reduceat(s, starts, axis=0)


def cluster_points(p: np.ndarray, t: np.ndarray, surface_z: np.ndarray, sensor_xy: np.ndarray, params: ClusterParams | None = None) -> Clusters:
    """Cluster dynamic points ``p`` (M,3) field frame with times ``t`` (M,) and the surface height under each
    ``surface_z`` (M,); ``sensor_xy`` (2,) the LiDAR's field position (ranges, viewing directions)."""
    q = params or ClusterParams()
    M = len(p)
    empty = Clusters(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, int), np.zeros(0), np.zeros(0, bool), np.zeros(0), np.full(M, -1))
    if M == 0:
        return empty
    rng_p = np.hypot(p[:, 0] - sensor_xy[0], p[:, 1] - sensor_xy[1])
    far = rng_p > q.loose_range_m  # loose set: voxels twice as large (eps ~ 0.2-0.4 m), its own grid
    scale = np.where(far, 2.0, 1.0)[:, None]
    vox_all = np.floor(p / (np.array([q.voxel_xy, q.voxel_xy, q.voxel_z]) * scale)).astype(np.int64)
    vox_all[:, 0] += far * 1_000_000  # the two grids never touch
    # unique voxels through one int64 key per point (np.unique on rows sorts a structured view: ~5x slower); keys
    # ordered like the rows (x, then y, then z), so voxels come out in the same order
    lo_v = vox_all.min(0)
    span = vox_all.max(0) - lo_v + 1
    key = ((vox_all[:, 0] - lo_v[0]) * span[1] + (vox_all[:, 1] - lo_v[1])) * span[2] + (vox_all[:, 2] - lo_v[2])
    ukey, first, inv = np.unique(key, return_index=True, return_inverse=True)
    vox = vox_all[first]
    inv = inv.reshape(-1)
    comp = _components(vox)[inv]
    comp = _merge_close(p, comp, q)  # fragments of one sparsely sampled robot
    # split wide components (touching robots)
    _, comp = np.unique(comp, return_inverse=True)
    comp = comp.reshape(-1)
    nc = comp.max() + 1
    lo, hi = _group_min_max(p[:, :2], *_groups(comp, nc))
    width = np.max(hi - lo, axis=1)
    wide = np.flatnonzero(width > q.split_m)
    next_id = nc
    for c in wide:  # few per cloud; the split itself is vectorised
        m = np.flatnonzero(comp == c)
        k = int(max(2, round(width[c] / q.robot_m)))
        if k > 4 or len(m) < 2 * q.min_points_far:  # wider than four robots side by side: not robots (a wall)
            continue
        sub = _kmeans_split(p[m, :2], k)
        comp[m[sub > 0]] = next_id + sub[sub > 0] - 1
        next_id += k - 1
    _, comp = np.unique(comp, return_inverse=True)
    comp = comp.reshape(-1)
    nc = comp.max() + 1
    n = np.bincount(comp, minlength=nc)
    cen = np.stack([np.bincount(comp, p[:, i], nc) for i in range(3)], 1) / n[:, None]
    groups = _groups(comp, nc)
    lo, hi = _group_min_max(p, *groups)
    smin = _group_min_max(np.asarray(surface_z, float), *groups)[0]
    tm = np.bincount(comp, t, nc) / n
    rng = np.hypot(cen[:, 0] - sensor_xy[0], cen[:, 1] - sensor_xy[1])
    foot = np.max(hi[:, :2] - lo[:, :2], axis=1)
    top = hi[:, 2] - smin
    bottom = lo[:, 2] - smin
    need = np.round(np.interp(rng, [q.loose_range_m * 0.6, 25.0], [q.min_points_near, q.min_points_far])).astype(int)
    ground = (foot >= q.footprint_m[0]) & (foot <= q.footprint_m[1]) & (top >= q.height_m[0]) & (top <= q.height_m[1]) & (bottom <= q.max_bottom_m)
    aerial_z = bottom >= q.aerial_min_m  # at the aerial robot's height (whatever its size)
    aerial = aerial_z & (foot >= 0.2) & (foot <= 1.4) & (hi[:, 2] - lo[:, 2] <= q.aerial_extent_m)
    ok = (ground | aerial) & (n >= need)
    why = np.select([ok, n < need, bottom >= q.aerial_min_m, foot < q.footprint_m[0], foot > q.footprint_m[1], top < q.height_m[0], top > q.height_m[1]],
                    np.arange(7), 7)  # fmt: skip
    keep = np.flatnonzero(ok)
    remap = np.full(nc, -1)
    remap[keep] = np.arange(len(keep))
    # centre: the LiDAR sees the near side (and, from 2.5 m up, often the top). Along the horizontal view the centre
    # is half a robot behind the nearest return, or mid-way between the nearest and farthest when the returns span
    # the robot's depth; across the view it is the centroid
    v_all = cen[:, :2] - sensor_xy
    v_all /= np.maximum(np.linalg.norm(v_all, axis=1, keepdims=True), 1e-9)
    along = np.einsum("ij,ij->i", p[:, :2], v_all[comp])
    amin, amax = _group_min_max(along, *groups)
    # every component's centre (the kept ones and the sparse ones a track may still take: Clusters.sparse)
    target = np.maximum(0.5 * (amin + amax), amin + np.where(aerial_z, q.push_aerial_m, q.push_face_m))
    cen_along = np.einsum("ij,ij->i", cen[:, :2], v_all)
    centre_all = np.column_stack([cen[:, :2] + v_all * (target - cen_along)[:, None], np.where(aerial_z, 0.5 * (lo[:, 2] + hi[:, 2]), smin)])
    centre = centre_all[keep]
    out = Clusters(centre, cen[keep], lo[keep], hi[keep], n[keep], tm[keep], aerial[keep], rng[keep], remap[comp], comp, why)
    # sparse: too few points or too small a footprint for a robot of its own (a far robot's 3-7 returns from one
    # rosette pass, the aerial robot's 4-6), but no larger than one: a track may take it (Tracker3D.update_sparse)
    sp = np.flatnonzero((np.isin(why, (1, 2, 3)) | ((why == 7) & (bottom <= q.aerial_min_m))) & (n >= q.min_points_sparse) & (foot <= q.footprint_m[1])
                        & (hi[:, 2] - smin <= q.height_m[1] + (q.aerial_extent_m + 2.0) * aerial_z) & (q.sparse_aerial | ~aerial_z))  # fmt: skip
    smap = np.full(nc, -1)
    smap[sp] = np.arange(len(sp))
    out.sparse = Clusters(centre_all[sp], cen[sp], lo[sp], hi[sp], n[sp], tm[sp], aerial_z[sp], rng[sp], smap[comp])
    return out
