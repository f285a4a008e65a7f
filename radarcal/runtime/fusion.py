"""LiDAR -> camera fusion: a bounded cloud queue, one sparse depth image per cloud, robust depth inside a box.

Following the NUAA radar-station report (2022): every received cloud becomes a depth image aligned with the camera;
the clouds (and their depth images) are kept in a queue bounded by a point budget and an age limit, the oldest
dropped first; the depth of a detection box is a statistic of the points in the box, taken from the newest depth
image and falling back to older ones while the box is (nearly) empty; ``None`` when no image has a point there.

Depth images are sparse (sorted linear pixel index + nearest camera-frame z per pixel): building one is a single
integer sort of ``pixel << 32 | float bits(z)`` (nearest z first within a pixel, since positive float32 bit
patterns order like the floats), and a box query is a ``searchsorted`` per box row. Memory is 8 bytes per
occupied pixel, so a 1 M point queue costs ~8 MB instead of one full-resolution float image per cloud.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from radarcal.camera import Camera
from radarcal.geometry import transform_points

__all__ = ["DepthImage", "BoxDepth", "make_depth_image", "depth_image_from_camera_points", "robust_depth", "robust_depths", "CloudQueue", "SurfaceFilter"]

RAISED_ABOVE_M = 0.01  # m: a surface (max-filtered over the wall margin) this far above the ground is a raised area


@dataclass
class DepthImage:
    t: float
    pix: np.ndarray  # (M,) int64 sorted unique linear pixel index v * width + u
    depth: np.ndarray  # (M,) float32 nearest camera-frame z (m) at that pixel
    n_points: int  # points of the source cloud (counts against the queue budget)
    width: int
    height: int

    def dense(self) -> np.ndarray:
        """(H, W) float32 image, NaN where empty (for display/tests; the runtime never needs it)."""
        img = np.full(self.width * self.height, np.nan, np.float32)
        img[self.pix] = self.depth
        return img.reshape(self.height, self.width)

    def values_in_boxes(self, boxes: np.ndarray, exclude: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Depths of the occupied pixels whose centres lie in each box (B,4) [x1, x2] x [y1, y2] and outside every
        rectangle of that box's ``exclude`` (B,K,4; padded with empty rectangles), and the box of each (V,): all
        boxes in one pass over their rows."""
        v, box, _ = _values_in_boxes(self.pix, self.depth, self.width, self.height, boxes, exclude)
        return v, box

    def values_in_box(self, x1: float, y1: float, x2: float, y2: float, exclude: np.ndarray | None = None) -> np.ndarray:
        """:meth:`values_in_boxes` of one box, ``exclude`` (K,4)."""
        ex = None if exclude is None or not len(exclude) else np.asarray(exclude, float).reshape(1, -1, 4)
        return self.values_in_boxes(np.array([[x1, y1, x2, y2]], float), ex)[0]


def _values_in_boxes(keys: np.ndarray, depth: np.ndarray, width: int, height: int, boxes: np.ndarray, exclude: np.ndarray | None = None,
                     layers: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """:meth:`DepthImage.values_in_boxes` of ``layers`` depth images stacked: ``keys`` (M,) sorted ``layer * width *
    height + v * width + u``, ``depth`` (M,). Returns the values (V,), their box (V,) and layer (V,); every row of
    every box in every layer is one range of ``keys`` (one search for all)."""
    b = np.asarray(boxes, float).reshape(-1, 4)
    if not len(b) or not len(keys):
        return np.zeros(0, np.float32), np.zeros(0, np.int64), np.zeros(0, np.int64)
    u0, v0 = np.maximum(np.ceil(b[:, 0]), 0).astype(np.int64), np.maximum(np.ceil(b[:, 1]), 0).astype(np.int64)
    u1, v1 = np.minimum(np.floor(b[:, 2]), width - 1).astype(np.int64), np.minimum(np.floor(b[:, 3]), height - 1).astype(np.int64)
    nrows = np.where((u1 >= u0) & (v1 >= v0), v1 - v0 + 1, 0)
    row_box = np.repeat(np.arange(len(b)), nrows)
    rows = (v0[row_box] + np.arange(len(row_box)) - np.repeat(np.cumsum(nrows) - nrows, nrows)) * width
    first, last = rows + u0[row_box], rows + u1[row_box]
    size = width * height
    if layers > 1:
        off = np.repeat(np.arange(layers, dtype=np.int64) * size, len(rows))
        first, last, row_box = np.tile(first, layers) + off, np.tile(last, layers) + off, np.tile(row_box, layers)
    lo = np.searchsorted(keys, first, "left")
    counts = np.searchsorted(keys, last, "right") - lo
    idx = np.repeat(lo - (np.cumsum(counts) - counts), counts) + np.arange(int(counts.sum()))
    box = np.repeat(row_box, counts)
    if exclude is not None and len(idx):
        pix = keys[idx] % size
        u, v = (pix % width)[:, None], (pix // width)[:, None]
        ex = np.asarray(exclude, float)[box]  # (V, K, 4)
        keep = ~((u >= ex[..., 0]) & (u <= ex[..., 2]) & (v >= ex[..., 1]) & (v <= ex[..., 3])).any(axis=1)
        idx, box = idx[keep], box[keep]
    layer = keys[idx] // size if layers > 1 else np.zeros(len(idx), np.int64)
    return depth[idx], box, layer


def make_depth_image(camera: Camera, T_cam_lidar: np.ndarray, points_lidar: np.ndarray, t: float = 0.0, min_depth: float = 0.3) -> DepthImage:
    """Project a cloud into the camera and keep the nearest z per pixel (pixel centres at integer coordinates)."""
    pts = np.asarray(points_lidar, np.float32).reshape(-1, 3)
    return depth_image_from_camera_points(camera, transform_points(T_cam_lidar, pts), t, min_depth)


def depth_image_from_camera_points(camera: Camera, p_cam: np.ndarray, t: float = 0.0, min_depth: float = 0.3, n_points: int | None = None) -> DepthImage:
    """The depth image of points already in the camera frame (m); ``n_points``: what the image counts against the
    queue's budget (default: these points)."""
    p_cam = np.asarray(p_cam).reshape(-1, 3)
    n = len(p_cam) if n_points is None else int(n_points)
    w, h = camera.image_size
    if not len(p_cam):
        return DepthImage(t, np.zeros(0, np.int64), np.zeros(0, np.float32), n, w, h)
    front = p_cam[:, 2] > min_depth
    p_cam = p_cam[front]
    uv, valid = camera.project(p_cam)
    ui = np.rint(uv[:, 0])
    vi = np.rint(uv[:, 1])
    with np.errstate(invalid="ignore"):
        valid &= (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    lin = vi[valid].astype(np.int64) * w + ui[valid].astype(np.int64)
    z = p_cam[valid, 2].astype(np.float32)
    key = (lin << 32) | z.view(np.uint32).astype(np.int64)
    key.sort()
    lin_sorted = key >> 32
    first = np.empty(len(key), bool)
    if len(key):
        first[0] = True
        np.not_equal(lin_sorted[1:], lin_sorted[:-1], out=first[1:])
    depth = (key[first] & 0xFFFFFFFF).astype(np.uint32).view(np.float32)
    return DepthImage(t, lin_sorted[first], depth, n, w, h)


class SurfaceFilter:
    """Drops LiDAR returns from the field surface (ground, highland tops, ramps) before they enter a depth image, so
    a box's depth comes from what stands on the field (robots, structures) and not from the terrain around or in
    front of it (a robot half hidden behind a highland edge would otherwise take the highland's depth).

    The surface height is rasterised once (``res`` m cells, from ``surface_z``) and looked up per point, so the
    filter costs a transform and a gather per cloud. The raster is max-filtered over ``wall_margin`` so that returns
    from the vertical walls of raised areas (the surface height jumps there) count as terrain too. Without a field
    model the surface is the plane z = 0.

    On raised areas (where the max-filtered surface is above the ground) the height tolerance grows with the
    horizontal range from the LiDAR: ``max(min_height, raised_tol_of_range(range))`` when that function is given
    (:class:`Pipeline`: ``surface_raised_k_sigma`` x the calibration's range sigma). A rotation error of 0.3 deg lifts
    a highland's top 8 cm at 16 m, and returns from its far edge then pass a fixed 8 cm tolerance and give the depth
    of a robot behind it whose lower part the highland hides (`synth match` 25: blue_3 put 2.7 m short on the
    highland for 2 s). On the ground the fixed tolerance stays: growing it there too took the few returns of far
    robots (seed 7 lost 2.7 points of right labels).

    ``structures`` (the field model's static boxes: bases, outposts — ``{"center": [x, y, z_bottom], "size":
    [lx, ly, lz], "yaw"}``) are removed too, grown by ``structure_margin``: a robot behind an outpost must not take
    the outpost's depth (with its own points gone, its box falls back to older clouds or to the ground ray, which
    passes through structures)."""

    def __init__(self, T_field_lidar: np.ndarray, surface_z=None, bounds: tuple[float, float, float, float] = (-2.0, -2.0, 30.0, 17.0), min_height: float = 0.08,
                 res: float = 0.05, wall_margin: float = 0.1, structures: list[dict] | None = None, structure_margin: float = 0.1,
                 raised_tol_of_range=None):  # fmt: skip
        self.T = np.asarray(T_field_lidar, float)
        self.raised_tol_of_range = raised_tol_of_range
        self.sensor_xy = self.T[:2, 3].copy()
        self.structures = []
        for st in structures or []:
            c = np.asarray(st["center"], float)
            half = np.asarray(st["size"], float) / 2 + structure_margin
            yaw = float(st.get("yaw", 0.0))
            self.structures.append((c, half, np.cos(yaw), np.sin(yaw)))
        self.min_height = float(min_height)
        self.res = float(res)
        self.x0, self.y0, x1, y1 = bounds
        nx, ny = int(np.ceil((x1 - self.x0) / res)), int(np.ceil((y1 - self.y0) / res))
        if surface_z is None:
            self.grid = np.zeros((ny, nx), np.float32)
        else:
            gx = self.x0 + (np.arange(nx) + 0.5) * res
            gy = self.y0 + (np.arange(ny) + 0.5) * res
            xx, yy = np.meshgrid(gx, gy)
            z = np.asarray(surface_z(np.column_stack([xx.ravel(), yy.ravel()])), float)
            grid = np.where(np.isfinite(z), z, 0.0).reshape(ny, nx)
            k = 2 * int(np.ceil(wall_margin / res)) + 1
            if k > 1:
                from scipy.ndimage import maximum_filter

                grid = maximum_filter(grid, size=k, mode="nearest")
            self.grid = grid.astype(np.float32)

    def _surface(self, p: np.ndarray) -> np.ndarray:
        ix = np.clip(((p[:, 0] - self.x0) / self.res).astype(np.int64), 0, self.grid.shape[1] - 1)
        iy = np.clip(((p[:, 1] - self.y0) / self.res).astype(np.int64), 0, self.grid.shape[0] - 1)
        return self.grid[iy, ix]

    def _heights(self, p: np.ndarray) -> np.ndarray:
        return p[:, 2] - self._surface(p)

    def heights(self, points_lidar: np.ndarray) -> np.ndarray:
        """Height of each point above the surface under it (m)."""
        return self._heights(transform_points(self.T, np.asarray(points_lidar, np.float32)))

    def __call__(self, points_lidar: np.ndarray) -> np.ndarray:
        """Mask of the points to keep (above the surface by the height tolerance and outside every structure)."""
        return self.keep_field(transform_points(self.T, np.asarray(points_lidar, np.float32)))

    def keep_field(self, p: np.ndarray) -> np.ndarray:
        """The same mask from points already in the field frame (m)."""
        surface = self._surface(p)
        height = p[:, 2] - surface
        keep = height > self.min_height
        if self.raised_tol_of_range is not None:
            # only points that pass the fixed tolerance on a raised area can fail the grown one: range for those alone
            i = np.flatnonzero(keep & (surface > RAISED_ABOVE_M))
            rng = np.hypot(p[i, 0] - self.sensor_xy[0], p[i, 1] - self.sensor_xy[1])
            keep[i] = height[i] > self.raised_tol_of_range(rng)
        for c, half, cs, sn in self.structures:
            dx, dy = p[:, 0] - c[0], p[:, 1] - c[1]
            inside = (np.abs(cs * dx + sn * dy) <= half[0]) & (np.abs(-sn * dx + cs * dy) <= half[1]) & (p[:, 2] - c[2] <= 2 * half[2]) & (p[:, 2] >= c[2] - 0.1)
            keep &= ~inside
        return keep


@dataclass
class BoxDepth:
    depth: float  # camera-frame z (m)
    sigma: float  # standard error of that depth (m)
    n: int  # points in the chosen cluster
    n_box: int  # points in the box of the image used
    age_s: float  # query time - time of the oldest cloud whose points the depth came from
    images_used: int  # depth images consulted within the age limit (1 = newest)


def robust_depth(values: np.ndarray, min_points: int = 3, min_fraction: float = 0.15, gap_m: float = 0.35, gap_rel: float = 0.03) -> tuple[float, float, int] | None:
    """Depth of the object in a box from the depths of the points in it: (depth, sigma, n_used) or None.

    The statistic depends on how many points there are: fewer than ``min_points`` -> the nearest value (a robot in
    front of a far background: the few points that hit it are the nearest); otherwise the points are split into
    depth clusters at gaps larger than ``max(gap_m, gap_rel * depth)`` and the nearest cluster holding at least
    ``max(min_points, min_fraction * n)`` points wins (single stray near returns are skipped); its median is the
    depth and ``1.4826 MAD / sqrt(k)`` (floored at 2 cm) its sigma. The one-box case of :func:`robust_depths`."""
    v = np.asarray(values, np.float32).reshape(-1)
    d, sig, k = robust_depths(v, np.zeros(len(v), np.int64), 1, min_points, min_fraction, gap_m, gap_rel)
    return None if not k[0] else (float(d[0]), float(sig[0]), int(k[0]))


def robust_depths(values: np.ndarray, box: np.ndarray, n_boxes: int, min_points: int = 3, min_fraction: float = 0.15,
                  gap_m: float = 0.35, gap_rel: float = 0.03) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`robust_depth` of many boxes at once: ``values`` (V,) float32 with their ``box`` (V,) in ``0..n_boxes-1``
    -> depth, sigma (float64, NaN where a box has no finite value) and the points used (int, 0 there)."""
    v, box = np.asarray(values, np.float32), np.asarray(box, np.int64)
    fin = np.isfinite(v)
    v, box = v[fin], box[fin]
    order = np.lexsort((v, box))  # by box, then depth
    v, box = v[order], box[order]
    n = np.bincount(box, minlength=n_boxes)
    start = np.cumsum(n) - n
    depth, sigma, used = np.full(n_boxes, np.nan), np.full(n_boxes, np.nan), np.zeros(n_boxes, np.int64)
    few = np.flatnonzero((n > 0) & (n < min_points))  # the nearest value
    if len(few):
        first, last = v[start[few]], v[start[few] + n[few] - 1]
        depth[few], sigma[few], used[few] = first, np.maximum((last - first).astype(np.float64), 0.05), n[few]
    many = n >= min_points
    if not many.any():
        return depth, sigma, used
    keep = many[box]
    v, box = v[keep], box[keep]
    # depth clusters: a new one where the box changes or the gap to the previous depth is too large
    gaps = np.diff(v) > np.maximum(gap_m, gap_rel * v[1:])
    cid = np.concatenate(([0], np.cumsum(gaps | (box[1:] != box[:-1]))))
    counts = np.bincount(cid)
    c_start = np.cumsum(counts) - counts
    c_box = box[c_start]
    need = np.maximum(min_points, np.ceil(min_fraction * n[c_box]).astype(np.int64))
    # per box its nearest cluster with enough points, else its largest (the first of equal ones)
    boxes = np.flatnonzero(many)
    ok = np.flatnonzero(counts >= need)
    none = np.iinfo(np.int64).max
    first_ok = np.full(n_boxes, none)
    ok_box = c_box[ok]  # ascending (clusters are numbered box by box, nearest first): each box's first is its nearest
    lead_ok = np.ones(len(ok), bool)
    lead_ok[1:] = ok_box[1:] != ok_box[:-1]
    first_ok[ok_box[lead_ok]] = ok[lead_ok]
    chosen = first_ok[boxes]
    if (chosen == none).any():  # boxes without a cluster of enough points: their largest
        rank = np.lexsort((np.arange(len(counts)), -counts, c_box))  # by box, most points first, then the nearer
        lead = rank[np.r_[True, c_box[rank][1:] != c_box[rank][:-1]]]
        big = np.full(n_boxes, -1, np.int64)
        big[c_box[lead]] = lead
        chosen = np.where(chosen != none, chosen, big[boxes])
    k, s0 = counts[chosen], c_start[chosen]
    med = _sorted_medians(v, s0, k)
    member = np.repeat(np.arange(len(chosen)), k)
    pos = np.repeat(s0, k) + np.arange(int(k.sum())) - np.repeat(np.cumsum(k) - k, k)
    dev = np.abs(v[pos] - med[member])
    dev = dev[np.lexsort((dev, member))]
    mad = _sorted_medians(dev, np.cumsum(k) - k, k)
    depth[boxes], used[boxes] = med, k
    sigma[boxes] = np.maximum(1.4826 * mad.astype(np.float64) / np.sqrt(k), 0.02)
    return depth, sigma, used


def _sorted_medians(v: np.ndarray, start: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``np.median`` of the sorted runs ``v[start : start + k]`` (k > 0), in ``v``'s dtype."""
    mid = start + k // 2
    return np.where(k % 2 == 1, v[mid], (v[mid - 1 + (k % 2)] + v[mid]) / v.dtype.type(2))


class CloudQueue:
    """The last clouds as depth images, bounded by ``max_points`` (sum of cloud sizes) and ``max_age_s``.

    ``point_filter``: points (LiDAR frame) -> keep mask; a :class:`SurfaceFilter` (anything with ``keep_field`` and
    its ``T`` = ``T_field_lidar``) is applied to field-frame points that come out of the same single matrix product
    as the camera-frame ones, so each cloud is transformed once."""

    def __init__(self, camera: Camera, T_cam_lidar: np.ndarray, max_points: int = 200_000, max_age_s: float = 1.0, min_box_points: int = 3, point_filter=None):
        self.point_filter = point_filter
        self.camera = camera
        self.T_cam_lidar = np.asarray(T_cam_lidar, float)
        self._keep_field = getattr(point_filter, "keep_field", None)
        if self._keep_field is not None:  # rows 0-2: camera frame, rows 3-5: field frame
            self._stacked = np.vstack([self.T_cam_lidar[:3], np.asarray(point_filter.T, float)[:3]])
        self.max_points = int(max_points)
        self.max_age_s = float(max_age_s)
        self.min_box_points = int(min_box_points)
        self.images: deque[DepthImage] = deque()
        self.points = 0
        self.dropped = 0
        self._stack_cache: tuple[list[DepthImage], np.ndarray, np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.images)

    def push(self, t: float, points_lidar: np.ndarray) -> DepthImage:
        pts = np.asarray(points_lidar, np.float32).reshape(-1, 3)
        n = len(pts)  # the budget counts what the sensor delivered
        if self._keep_field is not None and n:
            both = pts @ self._stacked[:, :3].T.astype(np.float32) + self._stacked[:, 3].astype(np.float32)
            p_cam = both[:, :3][self._keep_field(both[:, 3:])]
        else:
            if self.point_filter is not None and n:
                pts = pts[self.point_filter(pts)]
            p_cam = transform_points(self.T_cam_lidar, pts)
        img = depth_image_from_camera_points(self.camera, p_cam, t, n_points=n)
        self.images.append(img)
        self.points += img.n_points
        self.expire(t)
        return img

    def expire(self, now: float) -> None:
        """Drop the oldest clouds while over the point budget (always keeping the newest) or older than the limit."""
        while len(self.images) > 1 and (self.points > self.max_points or now - self.images[0].t > self.max_age_s):
            old = self.images.popleft()
            self.points -= old.n_points
            self.dropped += 1
        if self.images and now - self.images[0].t > self.max_age_s:  # even the newest is stale
            old = self.images.popleft()
            self.points -= old.n_points
            self.dropped += 1

    def clear(self) -> None:
        self.images.clear()
        self._stack_cache = None
        self.points = 0

    def depth_in_box(self, xyxy, t: float | None = None, shrink: float = 0.1, max_age_s: float | None = None, exclude: np.ndarray | None = None) -> BoxDepth | None:
        """Robust depth for a detection box from the newest depth image, falling back to older ones while the box
        holds fewer than ``min_box_points`` points (their points are pooled, newest first), back to ``max_age_s``
        (default: the queue's age limit; a moving robot's old points are in the wrong place, so the loop uses a
        shorter limit than the queue). ``shrink`` trims that fraction of the box width/height on each side.
        ``exclude``: rectangles (K,4) whose pixels are ignored — the boxes of robots standing in front of this one."""
        return self.depths_in_boxes(np.asarray(xyxy, float).reshape(1, 4), t, shrink, max_age_s, [exclude])[0]

    def depths_in_boxes(self, boxes: np.ndarray, t: float | None = None, shrink: float = 0.1, max_age_s: float | None = None,
                        excludes: list | None = None) -> list[BoxDepth | None]:  # fmt: skip
        """:meth:`depth_in_box` of every box (B,4) at once, ``excludes``: one ``exclude`` (K,4 or None) per box."""
        b = np.asarray(boxes, float).reshape(-1, 4)
        out: list[BoxDepth | None] = [None] * len(b)
        if not self.images or not len(b):
            return out
        dx, dy = (b[:, 2] - b[:, 0]) * shrink, (b[:, 3] - b[:, 1]) * shrink
        shrunk = np.column_stack([b[:, 0] + dx, b[:, 1] + dy, b[:, 2] - dx, b[:, 3] - dy])
        ex = None
        if excludes is not None and any(e is not None and len(e) for e in excludes):
            k = max(len(e) for e in excludes if e is not None)
            ex = np.tile(np.array([np.inf, np.inf, -np.inf, -np.inf]), (len(b), k, 1))  # empty rectangles
            for i, e in enumerate(excludes):
                if e is not None and len(e):
                    ex[i, : len(e)] = np.asarray(e, float).reshape(-1, 4)
        t_now = self.images[-1].t if t is None else float(t)
        limit = self.max_age_s if max_age_s is None else min(float(max_age_s), self.max_age_s)
        window = []  # the images within the age limit, newest first
        for img in reversed(self.images):
            if t_now - img.t > limit:
                break
            window.append(img)
        if not window:
            return out
        keys, depths = self._stack(window)
        R = len(window)
        v, j, r = _values_in_boxes(keys, depths, window[0].width, window[0].height, shrunk, ex, R)
        # each box reads the newest image, then older ones while it holds fewer than min_box_points points
        got = np.bincount(j * R + r, minlength=len(b) * R).reshape(len(b), R)
        cum = np.cumsum(got, axis=1)
        reach = cum >= self.min_box_points
        cut = np.where(reach.any(axis=1), np.argmax(reach, axis=1), R - 1)  # the oldest layer each box reads
        n = cum[np.arange(len(b)), cut]
        gave = (got > 0) & (np.arange(R)[None] <= cut[:, None])
        oldest = R - 1 - np.argmax(gave[:, ::-1], axis=1)
        times = np.array([img.t for img in window])
        oldest_t = np.where(gave.any(axis=1), times[oldest], t_now)  # time of the oldest image that gave points
        keep = r <= cut[j]
        depth, sigma, k = robust_depths(v[keep], j[keep], len(b))
        for i in np.flatnonzero(k):
            out[i] = BoxDepth(float(depth[i]), float(sigma[i]), int(k[i]), int(n[i]), t_now - float(oldest_t[i]), int(cut[i]) + 1)
        return out

    def _stack(self, window: list[DepthImage]) -> tuple[np.ndarray, np.ndarray]:
        """``window`` (newest first) as one sorted key array (layer k = the k-th newest: ``k * width * height`` +
        pixel) and its depths; kept until the window changes (a frame's queries share it, as do the frames until
        the next cloud)."""
        c = self._stack_cache
        if c is not None and len(c[0]) == len(window) and all(a is b for a, b in zip(c[0], window)):
            return c[1], c[2]
        size = window[0].width * window[0].height
        keys = np.concatenate([img.pix + k * size for k, img in enumerate(window)])
        depths = np.concatenate([img.depth for img in window])
        self._stack_cache = (list(window), keys, depths)
        return keys, depths
