"""Pixel (+ depth) -> field coordinates.

With a depth (camera-frame z from the LiDAR): the box centre pixel is back-projected to that depth, mapped into the
field with ``T_field_cam`` (the report's ``inv(R) (inv(M) d [u v 1] - t)``), then moved from the visible face to the
robot's centre along the horizontal viewing direction and put on the surface under it. The robust depth is the
median of the visible surface, which for a round robot of radius r sampled evenly across its apparent width lies
~0.13 r behind its nearest point, hence a correction of ``visible_depth_factor * r`` (0.85 r) there.
Without a depth: the ray through the bottom-centre of the box is intersected with the field surface
(``FieldModel.intersect_rays``; the plane z = 0 without a field model): that is the robot's nearest point, so the
correction is the full radius r.

All functions are vectorised over boxes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radarcal.camera import Camera

__all__ = ["Localiser", "Located", "RayTable", "flat_ground_intersect"]

FOOT_UP_PX = 2.0  # px above a box's bottom edge: the ray just above the foot, which must still meet the surface there
HIDDEN_FOOT_SIGMA_M = 3.0  # m: sigma of a ground ray whose foot the terrain may hide (it may lie metres short)
SURFACE_STEP_M = 0.05  # m: a step of the surface this high at or behind the bottom edge's hit may hide the robot's foot
BEYOND_HIT_M = 0.02  # m: how far beyond a ray's hit (along the view) the surface is looked up for a wall face


_NEWTON_EPS = 1e-7  # RayTable's central differences: the point and its four neighbours
_NEWTON_STEPS = np.array([[0, 0], [_NEWTON_EPS, 0], [-_NEWTON_EPS, 0], [0, _NEWTON_EPS], [0, -_NEWTON_EPS]])


def flat_ground_intersect(origins: np.ndarray, dirs: np.ndarray, z: float = 0.0) -> np.ndarray:
    """Rays (N,3),(N,3) against the plane z = ``z``; NaN rows where the ray does not go down to it."""
    o, d = np.asarray(origins, float), np.asarray(dirs, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (z - o[:, 2]) / d[:, 2]
    s = np.where((s > 0) & np.isfinite(s), s, np.nan)
    return o + d * s[:, None]


class RayTable:
    """Pixel -> undistorted normalised coordinates by bilinear interpolation in a table built once with
    :meth:`Camera.unproject` (every ``step`` px, one step beyond the image). ``Camera.unproject`` inverts the
    distortion with 20 Newton steps from the distorted point; starting from the table's interpolated value, one
    Newton step on :meth:`Camera.distort` (the one camera model) reaches the same answer to ~1e-7 (two: 1e-12) at a
    fraction of the cost."""

    def __init__(self, camera: Camera, step: int = 8, refine: int = 1):
        self.camera = camera
        self.refine = int(refine)
        self.K_inv = np.linalg.inv(camera.K)
        self.step = int(step)
        w, h = camera.image_size
        self.u0, self.v0 = -self.step, -self.step
        gu = np.arange(self.u0, w + 2 * self.step, self.step, dtype=float)
        gv = np.arange(self.v0, h + 2 * self.step, self.step, dtype=float)
        uu, vv = np.meshgrid(gu, gv)
        rays = camera.unproject(np.column_stack([uu.ravel(), vv.ravel()]))
        self.xy = (rays[:, :2] / rays[:, 2:3]).reshape(len(gv), len(gu), 2)

    def normalised(self, uv: np.ndarray) -> np.ndarray:
        uv = np.asarray(uv, float).reshape(-1, 2)
        fu = (uv[:, 0] - self.u0) / self.step
        fv = (uv[:, 1] - self.v0) / self.step
        iu = np.minimum(np.maximum(np.floor(fu).astype(np.int64), 0), self.xy.shape[1] - 2)
        iv = np.minimum(np.maximum(np.floor(fv).astype(np.int64), 0), self.xy.shape[0] - 2)
        a = (fu - iu)[:, None]
        b = (fv - iv)[:, None]
        g = self.xy
        xy = g[iv, iu] * (1 - a) * (1 - b) + g[iv, iu + 1] * a * (1 - b) + g[iv + 1, iu] * (1 - a) * b + g[iv + 1, iu + 1] * a * b
        if self.refine:
            xyd = uv @ self.K_inv[:2, :2].T + self.K_inv[:2, 2]
            dist = self.camera.distort
            eps = _NEWTON_EPS
            for _ in range(self.refine):
                # the point and its four central-difference neighbours in one call
                dd = dist((xy[None] + _NEWTON_STEPS[:, None]).reshape(-1, 2)).reshape(5, -1, 2)
                f = dd[0] - xyd
                jx = (dd[1] - dd[2]) / (2 * eps)
                jy = (dd[3] - dd[4]) / (2 * eps)
                det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
                det = np.where(np.abs(det) < 1e-12, 1e-12, det)
                xy = xy - np.column_stack([(jy[:, 1] * f[:, 0] - jy[:, 0] * f[:, 1]) / det, (-jx[:, 1] * f[:, 0] + jx[:, 0] * f[:, 1]) / det])
        return xy

    def rays(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays (N,3) in the camera frame."""
        xy = self.normalised(uv)
        r = np.column_stack([xy, np.ones(len(xy))])
        return r / np.linalg.norm(r, axis=1, keepdims=True)


@dataclass
class Located:
    p_field: np.ndarray  # (K,3) robot centre on the ground, field frame; NaN rows where nothing could be found
    source: np.ndarray  # (K,) "depth" | "ground" | "none"
    sigma: np.ndarray  # (K,) 1-sigma horizontal position uncertainty (m), NaN if unknown
    range_m: np.ndarray  # (K,) horizontal distance camera -> robot
    ground: np.ndarray  # (K,3) ground-ray centres (:meth:`Localiser.from_ground`): every box's when ``locate`` had ``foot``, else those of the boxes that took the ground ray; NaN rows elsewhere and where a ray misses


class Localiser:
    def __init__(self, camera: Camera, T_field_cam: np.ndarray, field_model=None, robot_radius_m: float = 0.25, visible_depth_factor: float = 0.85, pixel_sigma: float = 1.0):
        self.camera = camera
        self.T_field_cam = np.asarray(T_field_cam, float)
        self.field = field_model
        self.radius = float(robot_radius_m)
        self.visible_depth_factor = float(visible_depth_factor)
        self.pixel_sigma = float(pixel_sigma)
        self.cam_origin = self.T_field_cam[:3, 3].copy()
        self.ray_table = RayTable(camera)

    def outside_field(self, p: np.ndarray) -> np.ndarray:
        """(K,) True where the field point's xy lies beyond the field's boundary (never without a field model)."""
        size = getattr(self.field, "size", None) if self.field is not None else None
        if size is None:
            return np.zeros(len(p), bool)
        x, y = p[:, 0], p[:, 1]
        return np.isfinite(x) & ((x < 0) | (x > size[0]) | (y < 0) | (y > size[1]))

    def surface_z(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        if self.field is None:
            return np.zeros(len(xy))
        z = np.asarray(self.field.surface_z(xy), float)
        return np.where(np.isfinite(z), z, 0.0)

    def rays_field(self, uv: np.ndarray) -> np.ndarray:
        rays_cam = self.ray_table.rays(uv)
        return rays_cam @ self.T_field_cam[:3, :3].T

    def _push_back(self, p: np.ndarray, dist: float) -> np.ndarray:
        """Move points from the robot's visible face to its centre: ``dist`` further along the horizontal view."""
        d = p[:, :2] - self.cam_origin[:2]
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            out_xy = p[:, :2] + np.where(norm > 1e-9, d / norm, 0.0) * dist
        return out_xy

    def from_depth(self, uv: np.ndarray, depth_z: np.ndarray, rays: np.ndarray | None = None) -> np.ndarray:
        """Box-centre pixels (K,2) + camera-frame z (K,) -> robot centres (K,3) in the field. ``rays``: the pixels'
        unit camera rays when already looked up (:meth:`box_rays`)."""
        xy = self._depth_xy(uv, depth_z, rays)
        return np.column_stack([xy, self.surface_z(xy)])

    def _depth_xy(self, uv: np.ndarray, depth_z: np.ndarray, rays: np.ndarray | None = None) -> np.ndarray:
        """:meth:`from_depth` without the surface height: (K,2) field xy."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        rays = self.ray_table.rays(uv) if rays is None else rays
        with np.errstate(divide="ignore", invalid="ignore"):
            p_cam = rays / rays[:, 2:3] * np.asarray(depth_z, float).reshape(-1, 1)
        p = p_cam @ self.T_field_cam[:3, :3].T + self.T_field_cam[:3, 3]
        return self._push_back(p, self.visible_depth_factor * self.radius)

    def _surface_hits(self, uv: np.ndarray, rays_cam: np.ndarray | None = None) -> np.ndarray:
        """Pixels (K,2) -> (K,3) first hits of their rays with the field surface (the plane z = 0 without a field
        model); NaN rows where a ray misses. ``rays_cam``: their unit camera rays when already looked up."""
        dirs = self.rays_field(uv) if rays_cam is None else rays_cam @ self.T_field_cam[:3, :3].T
        origins = np.broadcast_to(self.cam_origin, dirs.shape)
        if self.field is not None:
            return np.asarray(self.field.intersect_rays(np.ascontiguousarray(origins), dirs), float)
        return flat_ground_intersect(origins, dirs)

    def from_ground(self, uv_bottom: np.ndarray, hit: np.ndarray | None = None) -> np.ndarray:
        """Bottom-centre pixels (K,2) -> robot centres (K,3) on the field surface (NaN where the ray misses).
        ``hit``: the rays' surface hits when already cast (:meth:`_surface_hits`)."""
        hit = self._surface_hits(np.asarray(uv_bottom, float).reshape(-1, 2)) if hit is None else hit
        xy = self._push_back(hit, self.radius)
        return np.column_stack([xy, self.surface_z(xy)]) * np.where(np.isfinite(hit[:, :1]), 1.0, np.nan)

    def box_rays(self, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Boxes (K,4) -> surface hits (K,3) of the rays through each bottom-centre pixel and :data:`FOOT_UP_PX`
        above it (:meth:`from_ground`, :meth:`hidden_foot`), cast together, and the unit camera rays (K,3) through
        the box centres (:meth:`from_depth`): all from one table lookup (:meth:`locate` takes the lot as ``foot``)."""
        b = np.asarray(boxes, float).reshape(-1, 4)
        k = len(b)
        uv = np.column_stack([0.5 * (b[:, 0] + b[:, 2]), b[:, 3]])
        rays = self.ray_table.rays(np.vstack([uv, uv - [0.0, FOOT_UP_PX], np.column_stack([uv[:, 0], (b[:, 1] + b[:, 3]) / 2])]))
        hits = self._surface_hits(None, rays[: 2 * k])
        return hits[:k], hits[k:], rays[2 * k :]

    def hidden_foot(self, uv_bottom: np.ndarray, hit: np.ndarray | None = None, above: np.ndarray | None = None) -> np.ndarray:
        """(K,) bool: boxes' bottom-centre pixels (K,2) where the terrain may hide the robot's foot, so that the bottom
        edge may be the outline of a raised area (or a step) in front of the robot, whose ground ray then lies short
        by up to the hidden stretch (a robot behind a highland: its height x range / (camera height - its height)):
        the ray meets a wall face (the surface :data:`BEYOND_HIT_M` beyond the hit is :data:`SURFACE_STEP_M` or more above it), or
        the ray :data:`FOOT_UP_PX` above meets the surface :data:`SURFACE_STEP_M` or more lower (the area ends right
        behind the hit). A robot standing at a step or on the very edge of an area looks alike: ambiguous, not
        wrong. False without a field model (flat ground hides nothing). ``hit``, ``above``: the rays' hits when already
        cast (:meth:`box_rays`)."""
        uv_bottom = np.asarray(uv_bottom, float).reshape(-1, 2)
        if self.field is None or not len(uv_bottom):
            return np.zeros(len(uv_bottom), bool)
        hit = self._surface_hits(uv_bottom) if hit is None else hit
        above = self._surface_hits(uv_bottom - [0.0, FOOT_UP_PX]) if above is None else above
        return self._hidden_foot(hit, above, self.surface_z(self._beyond(hit)))

    def _beyond(self, hit: np.ndarray) -> np.ndarray:
        """(K,2) where :meth:`hidden_foot` looks up the surface: :data:`BEYOND_HIT_M` beyond each hit along the view."""
        view = hit[:, :2] - self.cam_origin[:2]
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.nan_to_num(hit[:, :2] + BEYOND_HIT_M * view / np.linalg.norm(view, axis=1, keepdims=True))

    @staticmethod
    def _hidden_foot(hit: np.ndarray, above: np.ndarray, z_beyond: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            return (z_beyond > hit[:, 2] + SURFACE_STEP_M) | (above[:, 2] < hit[:, 2] - SURFACE_STEP_M)

    def locate(self, boxes: np.ndarray, depth_z: np.ndarray, depth_sigma: np.ndarray | None = None, foot: tuple[np.ndarray, ...] | None = None) -> Located:
        """Boxes (K,4) xyxy + depths (K,) (NaN = no LiDAR depth) -> :class:`Located`. ``foot``: :meth:`box_rays`
        of the boxes when already cast. One surface lookup serves the depth centres, the ground-ray centres
        (:attr:`Located.ground`) and the wall check of :meth:`hidden_foot`."""
        boxes = np.asarray(boxes, float).reshape(-1, 4)
        depth_z = np.asarray(depth_z, float).reshape(-1)
        k = len(boxes)
        p = np.full((k, 3), np.nan)
        src = np.full(k, "none", dtype=object)
        sigma = np.full(k, np.nan)
        if k == 0:
            return Located(p, src.astype(str), sigma, np.zeros(0), np.zeros((0, 3)))
        has = np.isfinite(depth_z) & (depth_z > 0)
        cx = (boxes[:, 0] + boxes[:, 2]) / 2
        uvb = np.column_stack([cx, boxes[:, 3]])
        hit, above, rays_c = (None, None, None) if foot is None else foot
        xy_d = self._depth_xy(np.column_stack([cx[has], (boxes[has, 1] + boxes[has, 3]) / 2]), depth_z[has], None if rays_c is None else rays_c[has])
        # a robot's centre is inside the field: a depth that puts it beyond the boundary came from the perimeter
        # wall (or the crowd) behind a robot the LiDAR missed, so that box takes the ground ray instead
        out = np.zeros(k, bool)
        out[has] = self.outside_field(xy_d)
        ground_ray = ~has | out
        if hit is None:  # without ``foot`` only the boxes that take the ground ray cast theirs
            hit = np.full((k, 3), np.nan)
            if ground_ray.any():
                hit[ground_ray] = self._surface_hits(uvb[ground_ray])
        hidden = self.field is not None and ground_ray.any()
        xy_g = self._push_back(hit, self.radius)
        beyond = self._beyond(hit[ground_ray]) if hidden else np.zeros((0, 2))
        z = self.surface_z(np.vstack([xy_d, xy_g, beyond]))
        nd, nk = len(xy_d), len(xy_d) + k
        ground = np.column_stack([xy_g, z[nd:nk]]) * np.where(np.isfinite(hit[:, :1]), 1.0, np.nan)
        if has.any():
            p[has] = np.column_stack([xy_d, z[:nd]])
            has &= ~out
            p[out] = np.nan
            src[has] = "depth"
            ds = np.asarray(depth_sigma, float).reshape(-1)[has] if depth_sigma is not None else np.full(has.sum(), 0.05)
            # along-ray depth error + lateral pixel error (small) + the radius model (robots are not cylinders)
            lateral = depth_z[has] * self.pixel_sigma / self.camera.fx
            sigma[has] = np.sqrt(ds**2 + lateral**2 + (0.25 * self.radius) ** 2)
        if ground_ray.any():
            g = ground[ground_ray]
            g[self.outside_field(g)] = np.nan  # a robot's centre is inside the field: the ray passed over what hides it
            p[ground_ray] = g
            ok = np.isfinite(g[:, 0])
            src[np.flatnonzero(ground_ray)[ok]] = "ground"
            # ground error for a pixel error dv: dR = (R^2 + h^2) / h * dv / f
            rng_h = np.linalg.norm(g[:, :2] - self.cam_origin[:2], axis=1)
            h = np.maximum(self.cam_origin[2] - g[:, 2], 0.1)
            sig_g = np.sqrt(((rng_h**2 + h**2) / h * self.pixel_sigma / self.camera.fy) ** 2 + (0.25 * self.radius) ** 2)
            # where the terrain may hide the foot the ray may lie metres short: kept, but weak (dropping it lost robots
            # climbing steps on the 2024 mesh replays)
            if hidden:
                hit_g = hit[ground_ray]
                up = self._surface_hits(uvb[ground_ray] - [0.0, FOOT_UP_PX]) if above is None else above[ground_ray]
                sig_g = np.where(self._hidden_foot(hit_g, up, z[nk:]), np.maximum(sig_g, HIDDEN_FOOT_SIGMA_M), sig_g)
            sigma[ground_ray] = sig_g
        # a box cut by the image's left or right edge holds only part of the robot: its centre column, hence the
        # bearing, may be off by up to the robot's radius (family A's tele: |across| p95 0.25 m vs 0.04 m beyond 15 m)
        w = self.camera.image_size[0]
        cut = (boxes[:, 0] <= 1.0) | (boxes[:, 2] >= w - 2.0)
        sigma[cut] = np.hypot(sigma[cut], self.radius)
        range_m = np.linalg.norm(p[:, :2] - self.cam_origin[:2], axis=1)
        return Located(p, src.astype(str), sigma, range_m, ground)
