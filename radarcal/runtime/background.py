"""What never moves: the field model's occupancy plus a background learnt from the clouds themselves.

A LiDAR point (field frame, after ``T_field_lidar``) is *dynamic* when it is

1. inside the crop (the field's rectangle inset by ``crop_inset_m``, up to ``max_height_m`` above the surface) —
   people walking along the boundary, the perimeter barrier and the station itself are outside it;
2. not part of the field model (:func:`field_occupancy`): above the surface by more than a tolerance that follows
   the range and the calibration's sigma (a 0.3 deg rotation error moves a point at 20 m by 10 cm; fixed tolerances
   let highland edges through, measured cause 3 of issue #15), with the surface max-filtered over a horizontal margin
   that grows with range too (returns from a raised area's wall), and outside every static structure grown by
   ``structure_grow_m`` (0.3 m, HITSZ 2024);
3. not in a voxel of the learnt background (:class:`VoxelBackground`): voxel occupancy over time, the count of
   clouds that hit a voxel decayed with a 20 s time constant (it learns in the first seconds and refreshes slowly),
   updated lazily (only voxels hit by a cloud are touched). Voxels near named or moving tracks and inside detection
   boxes are not learnt, so robots that stand still are not absorbed.

All vectorised; a 100 k-point cloud costs a few milliseconds. The field-model dependency is one function,
:func:`field_occupancy`: when ``FieldModel.occupancy_grid`` lands it replaces the body of that function.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FieldOccupancy", "field_occupancy", "VoxelBackground", "StaticFilter", "range_sigma", "transform_f32"]


def transform_f32(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``T @ p`` for points (N,3) in float32 by columns: no BLAS call (BLAS threads stall for tens of ms on a busy
    machine; three fused multiply-adds per column are as fast single-threaded)."""
    T = np.asarray(T, np.float32)
    p = np.asarray(p, np.float32).reshape(-1, 3)
    out = np.empty_like(p)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    for i in range(3):
        np.multiply(x, T[i, 0], out=out[:, i])
        out[:, i] += y * T[i, 1]
        out[:, i] += z * T[i, 2]
        out[:, i] += T[i, 3]
    return out


def range_sigma(range_m: np.ndarray, sigma_rot_rad: float, sigma_trans_m: float, sigma_range_m: float = 0.02) -> np.ndarray:
    """1-sigma position error (m) of a LiDAR point at ``range_m`` from calibration rotation/translation sigma."""
    r = np.asarray(range_m, float)
    return np.sqrt((sigma_rot_rad * r) ** 2 + sigma_trans_m**2 + sigma_range_m**2)


class FieldOccupancy:
    """The field model's surface and structures as rasters: ``contains(p, tol_z, margin_xy)``.

    The surface height is rasterised at ``res`` and max-filtered for the horizontal ``margins_m`` offered, each over
    ``ceil(m / res)`` cells each side (default: k = 1 .. ``MAX_MARGIN_M / res`` cells, margins ``k * res``); a margin
    asked for takes the smallest one offered that covers it (on the default grid at most one cell more). A point is
    occupied when ``z < surface_max(margin) + tol_z`` or inside a structure grown by ``grow``."""

    MAX_MARGIN_M = 0.5
    # the five margins offered until 2026-12 (a 0.20 m margin took 0.25 m, filtered over 4 cells: 0.32 m); kept with
    # box fixes (LidarFirstConfig.wall_margins_m: the sample replay's p95 0.305 -> 0.325 m on the cell grid)
    COARSE_MARGINS_M = (0.08, 0.16, 0.25, 0.35, 0.5)

    def __init__(self, surface_z, structures: list[dict], bounds: tuple[float, float, float, float], res: float = 0.08, grow: float = 0.3,
                 margins_m: tuple[float, ...] | None = None):  # fmt: skip
        from scipy.ndimage import maximum_filter

        self.res = float(res)
        self.x0, self.y0, x1, y1 = bounds
        nx, ny = int(np.ceil((x1 - self.x0) / res)), int(np.ceil((y1 - self.y0) / res))
        gx = self.x0 + (np.arange(nx) + 0.5) * res
        gy = self.y0 + (np.arange(ny) + 0.5) * res
        xx, yy = np.meshgrid(gx, gy)
        z = np.asarray(surface_z(np.column_stack([xx.ravel(), yy.ravel()])), float) if surface_z is not None else np.zeros(xx.size)
        base = np.where(np.isfinite(z), z, 0.0).reshape(ny, nx)
        self.surface = base.astype(np.float32)
        grid = res * np.arange(1, int(np.ceil(self.MAX_MARGIN_M / res - 1e-9)) + 1)
        self.margins = np.sort(np.asarray(margins_m, float)) if margins_m is not None else grid
        cells = np.ceil(self.margins / res - 1e-9).astype(int)
        self.grids = np.stack([maximum_filter(base, size=2 * k + 1, mode="nearest") for k in cells]).astype(np.float32)
        self.structures = []
        for st in structures or []:
            c = np.asarray(st["center"], float)
            half = np.asarray(st["size"], float) / 2 + grow
            yaw = float(st.get("yaw", 0.0))
            self.structures.append((c, half, np.cos(yaw), np.sin(yaw), float(st["size"][2]) + grow))

    def _margin_index(self, margin_m: np.ndarray) -> np.ndarray:
        """Index into :attr:`grids` of the fewest cells covering ``margin_m`` (at least one, at most the largest)."""
        return np.minimum(np.searchsorted(self.margins, np.asarray(margin_m, float) - 1e-9), len(self.margins) - 1)

    def _cells(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ix = np.clip(((p[:, 0] - self.x0) / self.res).astype(np.int64), 0, self.surface.shape[1] - 1)
        iy = np.clip(((p[:, 1] - self.y0) / self.res).astype(np.int64), 0, self.surface.shape[0] - 1)
        return iy, ix

    def surface_at(self, p: np.ndarray) -> np.ndarray:
        iy, ix = self._cells(p)
        return self.surface[iy, ix]

    def column_heights(self, sensor_xy: np.ndarray, tol_of_range, margin_of_range) -> np.ndarray:
        """(ny, nx) float32 raster: the height below which a point in that cell belongs to the field — surface
        max-filtered over the margin for the cell's range + the tolerance for that range, raised to the top of any
        structure (grown) standing there. With it the per-point test is one gather and one compare."""
        ny, nx = self.surface.shape
        gx = self.x0 + (np.arange(nx) + 0.5) * self.res
        gy = self.y0 + (np.arange(ny) + 0.5) * self.res
        xx, yy = np.meshgrid(gx, gy)
        r = np.hypot(xx - sensor_xy[0], yy - sensor_xy[1])
        k = self._margin_index(margin_of_range(r))
        thr = np.take_along_axis(self.grids, k[None], 0)[0] + tol_of_range(r)
        for c, half, cs, sn, top in self.structures:
            dx, dy = xx - c[0], yy - c[1]
            inside = (np.abs(cs * dx + sn * dy) <= half[0]) & (np.abs(-sn * dx + cs * dy) <= half[1])
            thr = np.where(inside, np.maximum(thr, c[2] + top), thr)
        return thr.astype(np.float32)

    def contains(self, p: np.ndarray, tol_z: np.ndarray | float = 0.08, margin_xy: np.ndarray | float = 0.08) -> np.ndarray:
        """(N,) bool: points (N,3) field frame that belong to the field or its structures."""
        p = np.asarray(p)
        iy, ix = self._cells(p)
        k = self._margin_index(np.broadcast_to(np.asarray(margin_xy, float), (len(p),)))
        occ = p[:, 2] < self.grids[k, iy, ix] + tol_z
        for c, half, cs, sn, top in self.structures:
            dx, dy = p[:, 0] - c[0], p[:, 1] - c[1]
            occ |= (np.abs(cs * dx + sn * dy) <= half[0]) & (np.abs(-sn * dx + cs * dy) <= half[1]) & (p[:, 2] <= c[2] + top)
        return occ


def field_occupancy(field_model, bounds: tuple[float, float, float, float], voxel: float = 0.08, grow: float = 0.3,
                    margins_m: tuple[float, ...] | None = None) -> FieldOccupancy:  # fmt: skip
    """The one place the background depends on the field model (surface_z + structures today; the field's mesh
    occupancy, ``FieldModel.occupancy_grid(voxel, grow)``, when it lands)."""
    if field_model is None:
        return FieldOccupancy(None, [], bounds, voxel, grow, margins_m)
    return FieldOccupancy(field_model.surface_z, list(getattr(field_model, "structures", []) or []), bounds, voxel, grow, margins_m)


class VoxelBackground:
    """Learnt static occupancy on a dense voxel grid over the crop: ``occ`` counts the clouds that hit a voxel,
    decayed with time constant ``tau_s`` (lazily, from ``t_last``: only voxels a cloud hits are touched). A voxel
    hit by at least ``threshold`` (decayed) clouds is background. The rosette hits a far static object in only
    10-20 % of the clouds, so the test is a count, not a rate; what keeps robots out of it is that voxels near
    named or moving tracks (and inside detection boxes) are never counted (:meth:`StaticFilter.learn`)."""

    def __init__(self, bounds3: tuple[float, float, float, float, float, float], voxel: float = 0.2, tau_s: float = 20.0, threshold: float = 4.0):
        self.voxel = float(voxel)
        self.lo = np.array(bounds3[:3], float)
        hi = np.array(bounds3[3:], float)
        self.shape = tuple(int(v) for v in np.ceil((hi - self.lo) / voxel))
        n = int(np.prod(self.shape))
        self.occ = np.zeros(n, np.float32)
        self.t_last = np.zeros(n, np.float32)
        self.tau_s, self.threshold = float(tau_s), float(threshold)

    def keys(self, p: np.ndarray) -> np.ndarray:
        """Linear voxel index per point (-1 outside the grid)."""
        ijk = np.floor((p - self.lo) / self.voxel).astype(np.int64)
        ok = np.all((ijk >= 0) & (ijk < np.array(self.shape)), axis=1)
        lin = (ijk[:, 0] * self.shape[1] + ijk[:, 1]) * self.shape[2] + ijk[:, 2]
        return np.where(ok, lin, -1)

    def occupancy(self, keys: np.ndarray, t: float) -> np.ndarray:
        """Decayed count of clouds that hit each voxel, at time ``t``."""
        k = np.maximum(keys, 0)
        eff = self.occ[k] * np.exp(-(t - self.t_last[k]) / self.tau_s)
        return np.where(keys >= 0, eff, 0.0)

    def is_background(self, keys: np.ndarray, t: float, grow: int = 1) -> np.ndarray:
        """Voxels of ``keys`` or (``grow`` = 1) any of their 8 horizontal neighbours learnt as background (a sparse
        scan leaves holes in what it learnt). One gather of the 9 neighbourhood voxels per key."""
        if not grow:
            return self.occupancy(keys, t) >= self.threshold
        sx, sy = self.shape[1] * self.shape[2], self.shape[2]
        off = np.array([dx * sx + dy * sy for dx in (-1, 0, 1) for dy in (-1, 0, 1)], np.int64)
        k = np.clip(keys[:, None] + off[None], 0, len(self.occ) - 1)
        hit = self.occ[k] * np.exp(-(t - self.t_last[k]) / self.tau_s) >= self.threshold
        return hit.any(axis=1) & (keys >= 0)

    def update(self, keys: np.ndarray, t: float, protect: np.ndarray | None = None) -> None:
        """One cloud at time ``t``: the voxels of ``keys`` (not ``protect``ed) were hit."""
        k = keys[keys >= 0] if protect is None else keys[(keys >= 0) & ~protect]
        if not len(k):
            return
        k = np.unique(k)
        self.occ[k] = self.occ[k] * np.exp(-(t - self.t_last[k]) / self.tau_s) + 1.0
        self.t_last[k] = t


@dataclass
class StaticFilter:
    """Field occupancy + crop + learnt background: points (N,3) in the LiDAR frame -> dynamic points in the field
    frame. Tolerances: ``tol_z = base_tol_m + k_sigma * range_sigma(r)``, ``margin = 0.08 + k_sigma * range_sigma(r)``."""

    T_field_lidar: np.ndarray
    occupancy: FieldOccupancy
    background: VoxelBackground | None
    crop: tuple[float, float, float, float]  # x0, y0, x1, y1 (field frame)
    max_height_m: float = 2.6
    base_tol_m: float = 0.05
    k_sigma: float = 2.0
    sigma_rot_rad: float = np.deg2rad(0.25)
    sigma_trans_m: float = 0.03

    ground_fit: bool = True
    plane: np.ndarray | None = None  # (a, b, c): the flat ground as the cloud sees it, z = a x + b y + c
    plane_rms: float = 0.03  # rms residual of the ground returns about the plane (m), smoothed over clouds
    min_rms_m: float = 0.03  # floor of plane_rms in the tolerance (LidarFirst: 1 cm LiDAR only)

    def _fit_ground(self, p: np.ndarray, surf: np.ndarray) -> None:
        """Fit the flat ground (cells where the surface is z = 0) seen in this cloud: a calibration tilt of a few
        tenths of a degree lifts or sinks the far ground by 10 cm; corrected, the height tolerance can stay small.
        Least squares, trimmed twice; smoothed over clouds. (The caller passes every ``len // 20000``-th point.)"""
        step = max(1, len(p) // 20000)
        p, surf = p[::step], surf[::step]
        ref = 0.0 if self.plane is None else p[:, 0] * self.plane[0] + p[:, 1] * self.plane[1] + self.plane[2]
        sel = np.flatnonzero((surf == 0) & (np.abs(p[:, 2] - ref) < 0.3))
        if len(sel) < 300:
            return
        if len(sel) > 4000:
            sel = sel[:: len(sel) // 4000]  # the same points as subsampling p[mask], without gathering all of them
        g = p[sel].astype(np.float64)
        # least squares by the 3x3 normal equations about the points' mean, summed over the kept points (well
        # conditioned; np.linalg.lstsq's SVD of the gathered rows took 0.4 ms of each cloud's 4000 points)
        mx, my = float(g[:, 0].mean()), float(g[:, 1].mean())
        x, y, z = g[:, 0] - mx, g[:, 1] - my, np.ascontiguousarray(g[:, 2])
        w = np.ones(len(g))
        coef = np.zeros(3)
        for _ in range(3):
            wx, wy = w * x, w * y
            sx, sy, sw = wx.sum(), wy.sum(), w.sum()
            M = np.array([[wx @ x, wx @ y, sx], [wx @ y, wy @ y, sy], [sx, sy, sw]])
            c = np.linalg.solve(M, np.array([wx @ z, wy @ z, w @ z]))
            res = z - (c[0] * x + c[1] * y + c[2])
            rms = float(np.sqrt(np.mean(res[w > 0] ** 2)))
            w = (np.abs(res) < max(2.5 * rms, 0.03)).astype(np.float64)
            coef = np.array([c[0], c[1], c[2] - c[0] * mx - c[1] * my])
        first = self.plane is None
        self.plane = coef if first else 0.8 * self.plane + 0.2 * coef
        self.plane_rms = rms if first else 0.8 * self.plane_rms + 0.2 * rms

    _thr: np.ndarray | None = None  # column heights (see FieldOccupancy.column_heights), built on first use
    _thr_rms: float = np.nan  # the plane_rms they were built for (rebuilt when it moves by more than 20 %)

    def _tolerances(self):
        """Height tolerance and wall margin as functions of range: with the ground fitted, the calibration tilt is
        removed and what is left is the fit's rms residual (:attr:`plane_rms`, floored at ``min_rms_m``) and a tenth
        of the rotation sigma. (Until 2026-12 a fixed 3 cm stood for the residual, ~9 mm on `synth match`: 0.115
        instead of 0.08 m at 24 m, and a far robot's lowest returns, often all it gave, went with the ground.)"""
        k, base = self.k_sigma, self.base_tol_m
        if self.ground_fit:
            rms = max(self.plane_rms, self.min_rms_m)
            tol = lambda r: base + k * range_sigma(r, 0.1 * self.sigma_rot_rad, 0.0, rms)  # noqa: E731
        else:
            tol = lambda r: base + k * range_sigma(r, self.sigma_rot_rad, self.sigma_trans_m)  # noqa: E731
        margin = lambda r: 0.08 + k * range_sigma(r, self.sigma_rot_rad, self.sigma_trans_m)  # noqa: E731
        return tol, margin

    def __call__(self, points_lidar: np.ndarray, t: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points (N,3) LiDAR frame -> (points off the field model (M,3) field frame, their indices into the input
        (M,), mask (M,) of those in the learnt background at time ``t``; all False without ``t``). The dynamic
        points are ``p[~bg]``; :meth:`learn` takes all M.

        With ``ground_fit`` heights are measured from the ground plane fitted to the clouds (:meth:`_fit_ground`),
        so the calibration's tilt does not eat into the tolerance. Cost: a transform, a crop, one raster gather."""
        occ = self.occupancy
        p = transform_f32(self.T_field_lidar, points_lidar)
        x0, y0, x1, y1 = self.crop
        px, py = p[:, 0], p[:, 1]
        inside = (px > x0) & (px < x1) & (py > y0) & (py < y1)
        # every test on the whole cloud and one gather at the end (gathering the crop first costs more than testing
        # the few points outside it)
        iy = ((py - occ.y0) * (1.0 / occ.res)).astype(np.int32)
        ix = ((px - occ.x0) * (1.0 / occ.res)).astype(np.int32)
        np.clip(iy, 0, occ.surface.shape[0] - 1, out=iy)
        np.clip(ix, 0, occ.surface.shape[1] - 1, out=ix)
        cell = iy * occ.surface.shape[1] + ix
        z = p[:, 2]
        if self.ground_fit:
            sub = np.flatnonzero(inside)
            sub = sub[:: max(1, len(sub) // 20000)]  # what _fit_ground would take of the cropped cloud
            self._fit_ground(p[sub], occ.surface.ravel()[cell[sub]])
            if self.plane is not None:
                a, b, c = (np.float32(v) for v in self.plane)
                z = z - (a * px + b * py + c)
        if self._thr is None or not abs(self.plane_rms - self._thr_rms) <= 0.2 * self._thr_rms:
            self._thr = occ.column_heights(np.asarray(self.T_field_lidar, float)[:2, 3], *self._tolerances())
            self._thr_rms = self.plane_rms
            self._top = (occ.surface + self.max_height_m).astype(np.float32)
        inside &= (z >= self._thr.ravel()[cell]) & (z <= self._top.ravel()[cell])
        idx = np.flatnonzero(inside)
        p = p[idx]
        bg = np.zeros(len(p), bool)
        if self.background is not None and t is not None and len(p):
            bg = self.background.is_background(self.background.keys(p), t)
        return p, idx, bg

    def learn(self, p_field: np.ndarray, t: float, protect_xy: np.ndarray | None = None, protect_r: float = 0.6) -> None:
        """Feed the points (field frame, outside the field occupancy) of one cloud to the learnt background; points
        within ``protect_r`` of ``protect_xy`` (K,2) (tracked robots) are not learnt."""
        if self.background is None or not len(p_field):
            return
        keys = self.background.keys(p_field)
        prot = None
        if protect_xy is not None and len(protect_xy):
            d2 = ((p_field[:, None, :2] - np.asarray(protect_xy, np.float32)[None]) ** 2).sum(-1)
            prot = (d2 < protect_r**2).any(axis=1)
        self.background.update(keys, t, prot)
