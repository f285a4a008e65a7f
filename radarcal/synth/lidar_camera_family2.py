"""A second, independent LiDAR-camera scene family ("family2") for held-out checks of the edge refinement and its verdict.

Nothing here is shared with :mod:`radarcal.synth.lidar_camera` except the output type (so the same writer and the
same CLI outputs serve both): other geometry, other textures and reflectivity, other scan patterns, other noise,
other cameras and mountings. Frames: LiDAR x forward, y left, z up (ground at ``z = -height``); camera x right,
y down, z forward; ``T_cam_lidar`` maps LiDAR points into the camera.

* Layouts (chosen by the seed, or ``layout=``): ``corridor`` (long walls with door recesses, pilasters, posters,
  floor tiles, a ceiling with light panels, an end wall), ``field`` (a RoboMaster-like arena: boundary walls,
  trapezoidal highlands with ramps, robots with light strips on their armour, painted zone lines, a base tower) and
  ``parking`` (painted bays, cars, a grid of columns with painted bands, a back wall with signs, curb stops).
* Textures are rectangular patches on planar faces (posters, lines, tiles, light strips), each with its own visible
  albedo and its own near-infrared factor: the LiDAR reflectivity has the same borders with another contrast (some
  borders nearly vanish), an incidence fall-off ``cos^0.6`` and 8-bit quantisation - unlike the old family, where
  the reflectivity is the visible albedo.
* LiDAR: ``avia`` (six lasers behind two unequal counter-rotating prisms, an elliptic 70.4 x 77.2 deg FoV,
  240 k pts/s), ``horizon`` (five lasers on an incommensurate Lissajous scan, 81.7 x 25.1 deg, 240 k pts/s),
  ``spin32`` / ``spin64`` (spinning multi-beam, non-uniform HDL-like elevations, a per-revolution beam wobble, the
  front +-70 deg kept). Range noise 1-3 cm, angular jitter, 0.3 % spurious returns.
* Camera: 640x512 or 1280x1024, focal length, principal point and distortion (radtan-5 or rational-8) drawn per
  scene; camera 5-25 cm above / beside the LiDAR, pitched down up to 8 deg; two lights, vignetting, gamma, blur.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radarcal import geometry
from radarcal.camera import Camera
from radarcal.synth.lidar_camera import LidarCameraScene, _pixel_rays, _raycast, raycasting_scene, seen_from, subpixel_uv  # exact unproject on a grid, spline in between (the renderer, not the scene)

__all__ = ["Family2Params", "LAYOUTS", "LIDARS", "render_family2_scene", "family2_lidar_directions", "family2_camera"]

LAYOUTS = ("corridor", "field", "parking")
LIDARS = ("avia", "horizon", "spin32", "spin64")
_R_MOUNT = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # camera axes from LiDAR axes


@dataclass
class Family2Params:
    seed: int = 0
    layout: str | None = None  # None: from the seed
    lidar: str | None = None  # None: from the seed (avia / horizon mostly)
    duration_s: float = 1.0
    range_noise_m: float | None = None  # None: 1-3 cm from the seed
    resolution: str | None = None  # "640x512" | "1280x1024" | None (from the seed)
    init_deg: float = 3.0
    init_m: float = 0.10
    image_noise: float | None = None


# ---------------------------------------------------------------------------------------------------------------
# meshes and textured faces
_HEX = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6], [0, 4, 5], [0, 5, 1], [1, 5, 6], [1, 6, 2], [2, 6, 7], [2, 7, 3], [3, 7, 4], [3, 4, 0]], np.int32)


class _World:
    """Objects (triangles, colour, albedo, NIR factor) and texture patches, all in the LiDAR frame."""

    def __init__(self) -> None:
        self.objects: list[dict] = []
        self.patches: list[tuple] = []  # (object, origin, a, b, n, half_a, half_b, albedo, nir)

    def hexa(self, kind, bottom, top, albedo, nir=1.0, colour=None) -> int:
        """A closed solid from a bottom and a top quad (4,3 each, counter-clockwise seen from above)."""
        v = np.vstack([bottom, top]).astype(float)
        self.objects.append({"kind": kind, "v": v, "f": _HEX.copy(), "albedo": float(albedo), "nir": float(nir), "colour": colour})
        return len(self.objects) - 1

    def cuboid(self, kind, centre, size, yaw=0.0, albedo=0.5, nir=1.0, colour=None) -> int:
        sx, sy, sz = np.asarray(size, float) / 2
        c, s = np.cos(yaw), np.sin(yaw)
        q = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]]) @ np.array([[c, s], [-s, c]])
        cx, cy, cz = centre
        bot = np.column_stack([q[:, 0] + cx, q[:, 1] + cy, np.full(4, cz - sz)])
        top = np.column_stack([q[:, 0] + cx, q[:, 1] + cy, np.full(4, cz + sz)])
        return self.hexa(kind, bot, top, albedo, nir, colour)

    def frustum(self, kind, centre_xy, z0, size_bottom, size_top, height, yaw, albedo, nir=1.0, colour=None) -> int:
        c, s = np.cos(yaw), np.sin(yaw)
        Rz = np.array([[c, s], [-s, c]])
        qb = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * np.asarray(size_bottom) / 2 @ Rz
        qt = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * np.asarray(size_top) / 2 @ Rz
        bot = np.column_stack([qb + centre_xy, np.full(4, z0)])
        top = np.column_stack([qt + centre_xy, np.full(4, z0 + height)])
        return self.hexa(kind, bot, top, albedo, nir, colour)

    def patch(self, obj, origin, a, b, half_a, half_b, albedo, nir) -> None:
        a = np.asarray(a, float) / np.linalg.norm(a)
        b = np.asarray(b, float) / np.linalg.norm(b)
        n = np.cross(a, b)
        self.patches.append((obj, np.asarray(origin, float), a, b, n / np.linalg.norm(n), float(half_a), float(half_b), float(albedo), float(nir)))

    def albedo_nir(self, obj_idx: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Visible albedo and NIR reflectance at hit points (loops over objects and patches, vectorised over points)."""
        alb = np.zeros(len(pts))
        nir = np.zeros(len(pts))
        for k, o in enumerate(self.objects):
            m = obj_idx == k
            alb[m] = o["albedo"]
            nir[m] = o["albedo"] * o["nir"]
        for obj, org, a, b, n, ha, hb, pa, pn in self.patches:
            m = np.flatnonzero(obj_idx == obj)
            if len(m) == 0:
                continue
            d = pts[m] - org
            inside = (np.abs(d @ n) < 0.03) & (np.abs(d @ a) < ha) & (np.abs(d @ b) < hb)
            alb[m[inside]] = pa
            nir[m[inside]] = pn
        return alb, nir


def _colour(rng) -> np.ndarray:
    return rng.uniform(0.7, 1.15, 3)


def _corridor(rng, w: _World, g: float) -> None:
    half = rng.uniform(1.4, 2.4)
    length = rng.uniform(18, 32)
    height = rng.uniform(2.7, 3.4)
    off = rng.uniform(-0.4, 0.4)  # the LiDAR is not on the centre line
    wall_alb = rng.uniform(0.55, 0.8)
    w.cuboid("floor", (length / 2, off, g - 0.05), (length + 6, 2 * half + 1, 0.1), albedo=rng.uniform(0.3, 0.45), nir=1.1)
    floor = len(w.objects) - 1
    tile = rng.uniform(0.6, 1.0)
    for x in np.arange(1.0, length, tile):  # grout lines across the corridor
        w.patch(floor, (x, off, g), (0, 1, 0), (1, 0, 0), half, 0.02, 0.2, 0.5)
    w.cuboid("ceiling", (length / 2, off, g + height + 0.05), (length + 6, 2 * half + 1, 0.1), albedo=0.75, nir=0.9)
    ceil = len(w.objects) - 1
    for x in np.arange(2.0, length - 1, rng.uniform(2.5, 4.0)):  # light panels (bright, dull in NIR)
        w.patch(ceil, (x, off, g + height), (1, 0, 0), (0, 1, 0), 0.3, 0.6, 1.0, 0.35)
    for side in (-1, 1):
        y = off + side * half
        wall = w.cuboid("wall", (length / 2, y + side * 0.1, g + height / 2), (length, 0.2, height), albedo=wall_alb, nir=rng.uniform(0.8, 1.1), colour=_colour(rng))
        face = y  # the face towards the corridor
        x = rng.uniform(2, 4)
        while x < length - 2:
            r = rng.random()
            if r < 0.35:  # a poster
                hw, hh = rng.uniform(0.3, 0.6), rng.uniform(0.4, 0.7)
                w.patch(wall, (x, face, g + rng.uniform(1.3, 1.8)), (1, 0, 0), (0, 0, 1), hw, hh, rng.uniform(0.05, 0.95), rng.uniform(0.1, 1.0))
            elif r < 0.65:  # a pilaster
                w.cuboid("pilaster", (x, y - side * 0.12, g + height / 2), (0.4, 0.24, height), albedo=wall_alb * rng.uniform(0.8, 1.1), nir=1.0, colour=_colour(rng))
            else:  # a door: a dark recessed leaf with a frame (a box slightly in front of the wall)
                door = w.cuboid("door", (x, y - side * 0.03, g + 1.05), (0.95, 0.06, 2.1), albedo=rng.uniform(0.15, 0.35), nir=1.4, colour=_colour(rng))
                w.patch(door, (x + 0.33, y - side * 0.06, g + 1.0), (1, 0, 0), (0, 0, 1), 0.06, 0.03, 0.9, 0.9)  # handle plate
            x += rng.uniform(2.0, 4.0)
        # skirting band
        w.patch(wall, (length / 2, face, g + 0.06), (1, 0, 0), (0, 0, 1), length / 2, 0.06, 0.2, 0.3)
    end = w.cuboid("end wall", (length + 0.1, off, g + height / 2), (0.2, 2 * half + 0.4, height), albedo=rng.uniform(0.4, 0.7), nir=1.0, colour=_colour(rng))
    w.patch(end, (length, off + rng.uniform(-0.5, 0.5), g + 1.5), (0, 1, 0), (0, 0, 1), 0.8, 0.5, 0.1, 0.6)
    for _ in range(rng.integers(1, 4)):  # boxes / cabinets along the walls
        side = rng.choice([-1, 1])
        x = rng.uniform(3, length - 3)
        sz = rng.uniform(0.5, 1.4)
        w.cuboid("cabinet", (x, off + side * (half - 0.35), g + sz / 2), (rng.uniform(0.5, 1.2), 0.6, sz), albedo=rng.uniform(0.2, 0.8), nir=rng.uniform(0.6, 1.3), colour=_colour(rng))


def _field(rng, w: _World, g: float) -> None:
    depth = rng.uniform(14, 22)
    half = rng.uniform(6, 9)
    ground = w.cuboid("ground", (depth / 2, 0, g - 0.05), (depth + 10, 2 * half + 10, 0.1), albedo=rng.uniform(0.25, 0.4), nir=1.2)
    for x in np.arange(2.0, depth, rng.uniform(2.5, 4.0)):  # zone lines
        w.patch(ground, (x, 0, g), (0, 1, 0), (1, 0, 0), half, 0.04, 0.9, 0.8)
    w.patch(ground, (depth * 0.5, 0, g), (1, 0, 0), (0, 1, 0), depth * 0.5, 0.04, 0.9, 0.8)
    wall_h = rng.uniform(0.6, 2.4)
    for y in (-half, half):
        wall = w.cuboid("boundary", (depth / 2, y + np.sign(y) * 0.1, g + wall_h / 2), (depth + 2, 0.2, wall_h), albedo=0.45, nir=1.0, colour=_colour(rng))
        w.patch(wall, (depth / 2, y, g + wall_h * 0.5), (1, 0, 0), (0, 0, 1), depth / 2, 0.08, 0.95, 0.4)  # LED band
    back = w.cuboid("boundary", (depth + 0.1, 0, g + wall_h / 2 + 0.5), (0.2, 2 * half, wall_h + 1), albedo=0.5, nir=1.0, colour=_colour(rng))
    for y in np.arange(-half + 1.5, half - 1, 3.0):  # sponsor boards
        w.patch(back, (depth, y, g + 0.9), (0, 1, 0), (0, 0, 1), 0.9, 0.35, rng.uniform(0.05, 0.95), rng.uniform(0.2, 1.2))
    for _ in range(rng.integers(2, 4)):  # highlands with ramps
        cx, cy = rng.uniform(5, depth - 3), rng.uniform(-half + 2.5, half - 2.5)
        sb = rng.uniform(2.0, 4.5, 2)
        hgt = rng.uniform(0.3, 0.8)
        yaw = rng.uniform(-0.5, 0.5)
        hl = w.frustum("highland", (cx, cy), g, sb, sb - 2 * hgt * rng.uniform(0.2, 0.8), hgt, yaw, albedo=rng.uniform(0.3, 0.7), nir=rng.uniform(0.7, 1.3), colour=_colour(rng))
        c, s = np.cos(yaw), np.sin(yaw)
        top = w.objects[hl]["v"][4:]
        w.patch(hl, top.mean(0), top[1] - top[0], top[3] - top[0], 0.5 * np.linalg.norm(top[1] - top[0]) - 0.08, 0.5 * np.linalg.norm(top[3] - top[0]) - 0.08, 0.85, 0.5)
        # ramp: a wedge from the ground to the highland top along the highland's x axis
        ax = np.array([c, s])
        start = np.array([cx, cy]) - ax * (sb[0] / 2 + 1.8)
        end_ = np.array([cx, cy]) - ax * (sb[0] / 2 - 0.1)
        perp = np.array([-s, c]) * 0.6
        bot = np.array([np.r_[start - perp, g], np.r_[end_ - perp, g], np.r_[end_ + perp, g], np.r_[start + perp, g]])
        topr = bot.copy()
        topr[1:3, 2] = g + hgt
        topr[[0, 3], 2] = g + 0.01
        w.hexa("ramp", bot, topr, albedo=rng.uniform(0.3, 0.6), nir=1.0, colour=_colour(rng))
    for _ in range(rng.integers(3, 6)):  # robots: chassis, turret, armour light strips
        x, y = rng.uniform(3.5, depth - 2), rng.uniform(-half + 1, half - 1)
        yaw = rng.uniform(-np.pi, np.pi)
        ch = w.cuboid("robot", (x, y, g + 0.25), (0.6, 0.5, 0.35), yaw, albedo=rng.uniform(0.15, 0.4), nir=1.3, colour=_colour(rng))
        w.cuboid("turret", (x, y, g + 0.55), (0.3, 0.25, 0.25), yaw + rng.uniform(-1, 1), albedo=rng.uniform(0.2, 0.6), nir=1.0, colour=_colour(rng))
        v = w.objects[ch]["v"]
        for i0, i1 in ((0, 1), (1, 2), (2, 3), (3, 0)):  # a light strip on every side face
            a = v[i1] - v[i0]
            mid = 0.5 * (v[i0] + v[i1]) + np.array([0, 0, 0.25])
            w.patch(ch, mid, a, (0, 0, 1), 0.35 * np.linalg.norm(a), 0.04, 0.98, 0.3)
    bx, by = depth - 2.5, rng.uniform(-2, 2)
    w.cuboid("base", (bx, by, g + 0.75), (1.4, 1.4, 1.5), albedo=0.6, nir=0.9, colour=_colour(rng))
    w.frustum("base roof", (bx, by), g + 1.5, (1.4, 1.4), (0.3, 0.3), 0.6, 0.0, albedo=0.5, nir=1.0, colour=_colour(rng))


def _parking(rng, w: _World, g: float) -> None:
    depth = rng.uniform(20, 30)
    ground = w.cuboid("asphalt", (depth / 2, 0, g - 0.05), (depth + 10, 40, 0.1), albedo=rng.uniform(0.15, 0.3), nir=1.3)
    bay = rng.uniform(2.4, 2.8)
    rows = (rng.uniform(5, 8), rng.uniform(12, 16))
    cars = []
    for x_row in rows:
        for y in np.arange(-12, 12.01, bay):  # bay lines 5 m long
            w.patch(ground, (x_row, y, g), (1, 0, 0), (0, 1, 0), 2.5, 0.06, 0.95, 0.85)
        for y in np.arange(-12 + bay / 2, 12, bay):
            if rng.random() < 0.45:
                cars.append((x_row + rng.uniform(-0.3, 0.3), y + rng.uniform(-0.2, 0.2)))
            elif rng.random() < 0.3:  # curb stop
                w.cuboid("curb", (x_row + 2.2, y, g + 0.06), (0.15, 1.6, 0.12), albedo=0.8, nir=0.9)
    for x, y in cars:
        yaw = rng.uniform(-0.08, 0.08)
        body = w.cuboid("car", (x, y, g + 0.55), (4.3, 1.8, 0.8), yaw, albedo=rng.uniform(0.1, 0.9), nir=rng.uniform(0.6, 1.2), colour=_colour(rng))
        w.cuboid("cabin", (x + 0.2, y, g + 1.2), (2.2, 1.6, 0.5), yaw, albedo=rng.uniform(0.05, 0.3), nir=0.5, colour=_colour(rng))
        w.patch(body, np.array([x - 2.15 * np.cos(yaw), y - 2.15 * np.sin(yaw), g + 0.55]), (np.sin(yaw), -np.cos(yaw), 0), (0, 0, 1), 0.26, 0.06, 0.95, 1.6)  # plate
    for x in (rows[0] + 3.4, rows[1] + 3.4):
        for y in np.arange(-10, 10.01, rng.uniform(5, 8)):  # columns with painted bands
            col = w.cuboid("column", (x, y, g + 1.75), (0.6, 0.6, 3.5), albedo=0.7, nir=1.0, colour=_colour(rng))
            for face_y in (-0.3, 0.3):
                w.patch(col, (x, y + face_y, g + 0.9), (1, 0, 0), (0, 0, 1), 0.3, 0.25, 0.15, 0.9)
            w.patch(col, (x - 0.3, y, g + 0.9), (0, 1, 0), (0, 0, 1), 0.3, 0.25, 0.15, 0.9)
    back = w.cuboid("back wall", (depth + 0.1, 0, g + 2), (0.2, 30, 4), albedo=rng.uniform(0.4, 0.7), nir=1.0, colour=_colour(rng))
    for y in np.arange(-10, 10.01, rng.uniform(3, 5)):  # signs
        w.patch(back, (depth, y, g + rng.uniform(1.2, 2.5)), (0, 1, 0), (0, 0, 1), rng.uniform(0.3, 0.8), rng.uniform(0.2, 0.5), rng.uniform(0.05, 0.95), rng.uniform(0.2, 1.5))
    w.cuboid("ceiling", (depth / 2, 0, g + 3.55), (depth + 10, 40, 0.1), albedo=0.5, nir=1.0) if rng.random() < 0.5 else None


# ---------------------------------------------------------------------------------------------------------------
# scan patterns
def family2_lidar_directions(kind: str, duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """Unit ray directions (N,3), LiDAR frame, of the family's scan patterns (see the module docstring)."""
    if kind == "avia":
        n = int(240_000 * duration_s)
        t = np.arange(n) / 240_000.0 + rng.uniform(0, 5)
        laser = np.arange(n) % 6
        w1, w2 = 2 * np.pi * 97.13, -2 * np.pi * 61.37
        px = 0.56 * np.cos(w1 * t) + 0.44 * np.cos(w2 * t + 0.7)
        py = 0.56 * np.sin(w1 * t) + 0.44 * np.sin(w2 * t + 0.7)
        px = px + 0.04 * (laser - 2.5) / 2.5
        az = np.radians(35.2) * px  # horizontal half-FoV
        el = np.radians(38.6) * py
    elif kind == "horizon":
        n = int(240_000 * duration_s)
        t = np.arange(n) / 240_000.0 + rng.uniform(0, 5)
        laser = np.arange(n) % 5
        az = np.radians(40.85) * np.sin(2 * np.pi * 10.07 * t + 1.3 * laser)
        el = np.radians(12.55) * (np.sin(2 * np.pi * 377.3 * t + 0.9 * laser) * 0.8 + 0.2 * (laser - 2) / 2)
    elif kind in ("spin32", "spin64"):
        beams = 32 if kind == "spin32" else 64
        if beams == 32:
            el0 = np.linspace(-30.67, 10.67, 32)
        else:  # denser near the horizon, like HDL-64 / OS-64 upper-lower blocks
            el0 = np.concatenate([np.linspace(-24.8, -8.5, 32), np.linspace(-8.2, 2.0, 32)])
        revs = max(1, int(round(10 * duration_s)))
        n_az = 800  # +-70 deg at 0.175 deg
        az1 = np.radians(np.linspace(-70, 70, n_az, endpoint=False))
        rev = np.repeat(np.arange(revs), beams * n_az)
        beam = np.tile(np.repeat(np.arange(beams), n_az), revs)
        az = np.tile(az1, beams * revs) + np.radians(rng.uniform(0, 0.175, revs))[rev]
        wobble = np.radians(0.06) * np.sin(2 * np.pi * rng.random(revs))[rev]
        el = np.radians(el0)[beam] + wobble
    else:
        raise ValueError(f"lidar: expected one of {LIDARS}, got {kind!r}")
    az = az + np.radians(0.03) * rng.standard_normal(len(az))
    el = el + np.radians(0.03) * rng.standard_normal(len(el))
    ce = np.cos(el)
    return np.stack([ce * np.cos(az), ce * np.sin(az), np.sin(el)], axis=1)


def family2_camera(rng: np.random.Generator, resolution: str | None = None) -> Camera:
    """Intrinsics drawn per scene: size, focal length (55-80 deg horizontal FoV), principal point, distortion."""
    res = resolution or ("640x512" if rng.random() < 0.5 else "1280x1024")
    w, h = (int(v) for v in res.split("x"))
    hfov = np.radians(rng.uniform(55, 80))
    f = (w / 2) / np.tan(hfov / 2)
    K = np.array([[f, 0, (w - 1) / 2 + rng.uniform(-0.02, 0.02) * w], [0, f * rng.uniform(0.998, 1.002), (h - 1) / 2 + rng.uniform(-0.02, 0.02) * h], [0, 0, 1]])
    border = np.concatenate([np.stack([np.linspace(0, w - 1, 64), np.full(64, v)], 1) for v in (0.0, h - 1.0)]
                            + [np.stack([np.full(64, u), np.linspace(0, h - 1, 64)], 1) for u in (0.0, w - 1.0)])
    for _ in range(50):  # redraw until the model is invertible over the whole image
        if rng.random() < 0.5:
            dist = np.array([rng.uniform(-0.3, 0.05), rng.uniform(-0.02, 0.12), rng.uniform(-1e-3, 1e-3), rng.uniform(-1e-3, 1e-3), rng.uniform(-0.02, 0.0)])
        else:  # rational: k1 k2 p1 p2 k3 k4 k5 k6
            dist = np.array([rng.uniform(-0.2, 0.3), rng.uniform(-0.1, 0.1), rng.uniform(-1e-3, 1e-3), rng.uniform(-1e-3, 1e-3), 0.0, rng.uniform(0.0, 0.3), 0.0, 0.0])
        cam = Camera((w, h), K, dist)
        rays = cam.unproject(border)
        if np.all(np.isfinite(rays)) and np.all(rays[:, 2] > 0.2):
            uv, ok = cam.project(rays)
            if np.all(ok) and np.max(np.abs(uv - border)) < 1e-3:
                return cam
    return Camera((w, h), K, np.zeros(5))


def _true_pose(rng) -> np.ndarray:
    """Camera 5-25 cm above, up to 20 cm beside and -10..+15 cm ahead of the LiDAR, pitched down 0-8 deg."""
    pitch, yaw, roll = np.radians([rng.uniform(0, 8), rng.uniform(-5, 5), rng.uniform(-2, 2)])
    dR = geometry.rotvec_to_R(np.array([pitch, 0, 0])) @ geometry.rotvec_to_R(np.array([0, yaw, 0])) @ geometry.rotvec_to_R(np.array([0, 0, roll]))
    R = dR @ _R_MOUNT
    c_lidar = np.array([rng.uniform(-0.10, 0.15), rng.uniform(-0.2, 0.2), rng.uniform(0.05, 0.25)])
    return geometry.make_T(R, -R @ c_lidar)


def render_family2_scene(params: Family2Params | None = None) -> LidarCameraScene:
    """Build and ray-cast one family-2 scene (deterministic for a seed). Pure: no files written."""
    p = params or Family2Params()
    rng = np.random.default_rng(10_000 + p.seed)
    layout = p.layout or LAYOUTS[p.seed % 3]
    lidar = p.lidar or ("avia", "horizon", "avia", "spin64", "horizon")[(p.seed // 3) % 5]
    if layout not in LAYOUTS:
        raise ValueError(f"layout: expected one of {LAYOUTS}, got {layout!r}")
    height = rng.uniform(0.6, 1.8) if layout != "field" else rng.uniform(0.8, 1.5)
    cam = family2_camera(rng, p.resolution)
    T = _true_pose(rng)
    w = _World()
    {"corridor": _corridor, "field": _field, "parking": _parking}[layout](rng, w, -height)
    rc, obj_of = raycasting_scene([(o["v"], o["f"]) for o in w.objects])
    points, refl, obj, pts_true, sigma_r = _family2_lidar(rng, p, lidar, w, rc, obj_of)
    c_l = geometry.invert_T(T)[:3, 3]
    cam_visible = seen_from(rc, pts_true, c_l)
    img, id_img, noise = _family2_image(rng, p, cam, geometry.invert_T(T), w, rc, obj_of)
    T_init = geometry.perturb_T(T, p.init_deg, p.init_m, rng)
    objects = [{"id": k + 1, "kind": ob["kind"], "albedo": ob["albedo"]} for k, ob in enumerate(w.objects)]
    model = {"avia": "livox-avia-like", "horizon": "livox-horizon-like", "spin32": "spinning-32", "spin64": "spinning-64"}[lidar]
    pd = {"family": "family2", "seed": p.seed, "layout": layout, "lidar": lidar, "sensor_model": model, "duration_s": p.duration_s, "range_noise_m": float(sigma_r),
          "lidar_height_m": float(height), "init_deg": p.init_deg, "init_m": p.init_m, "camera": cam.to_dict(), "image_noise": float(noise)}
    return LidarCameraScene(img, id_img, points, refl.astype(np.float32), (obj + 1).astype(np.int32), cam_visible, cam, T, T_init, objects, [], pd,
                            [(ob["v"], ob["f"]) for ob in w.objects])


def _family2_lidar(rng, p: Family2Params, lidar: str, w: _World, rc, obj_of):
    """The LiDAR's returns: range noise, spurious short returns, NIR reflectivity in 8 bits. Returns noisy points
    (N,3) float32, reflectivity, object index, exact points, the range sigma (m)."""
    dirs = family2_lidar_directions(lidar, p.duration_s, rng)
    t, gid, nrm = _raycast(rc, np.zeros((1, 3)), dirs)
    obj = obj_of(gid)
    hit = np.isfinite(t) & (t < 120) & (obj >= 0) & (t > 0.3)
    dirs, t, obj, nrm = dirs[hit], t[hit], obj[hit], nrm[hit]
    pts_true = dirs * t[:, None]
    _, nir = w.albedo_nir(obj, pts_true)
    cos_inc = np.abs(np.sum(nrm * dirs, 1))
    refl = np.clip(np.round(255 * np.clip(nir, 0, 1) * cos_inc ** 0.6 + rng.normal(0, 3.0, len(t))), 0, 255)
    sigma_r = p.range_noise_m if p.range_noise_m is not None else rng.uniform(0.01, 0.03)
    r = t + rng.normal(0, sigma_r, len(t))
    spurious = rng.random(len(t)) < 0.003
    r[spurious] = t[spurious] * rng.uniform(0.2, 0.95, int(spurious.sum()))
    return (dirs * r[:, None]).astype(np.float32), refl, obj, pts_true, sigma_r


def _family2_image(rng, p: Family2Params, cam: Camera, T_lidar_cam: np.ndarray, w: _World, rc, obj_of):
    """The camera image (two lights, coloured objects, sky gradient, vignetting, gamma, blur, noise; BGR), the id
    image (object + 1, 0: sky) and the image noise sigma."""
    from scipy.ndimage import gaussian_filter

    c_l = T_lidar_cam[:3, 3]
    wpx, hpx = cam.image_size
    ss = 2 if wpx <= 640 else 1
    rays = _pixel_rays(cam, subpixel_uv(wpx, hpx, ss)) @ T_lidar_cam[:3, :3].T
    tc, gc, nc = _raycast(rc, c_l[None], rays)
    oc = obj_of(gc)
    hitc = np.isfinite(tc) & (oc >= 0)
    pc = c_l + rays * np.where(hitc, tc, 0)[:, None]
    alb = np.zeros(len(tc))
    alb[hitc], _ = w.albedo_nir(oc[hitc], pc[hitc])
    l1 = np.array([0.2, -0.5, 0.84]) / np.linalg.norm([0.2, -0.5, 0.84])
    l2 = np.array([-0.7, 0.4, 0.3]) / np.linalg.norm([-0.7, 0.4, 0.3])
    shade = 0.3 + 0.5 * np.abs(nc @ l1) + 0.25 * np.abs(nc @ l2)
    colours = np.array([[1.0, 1.0, 1.0]] + [ob["colour"] if ob["colour"] is not None else [1.0, 1.0, 1.0] for ob in w.objects])
    sky = 0.6 + 0.3 * np.clip(-rays[:, 2], -1, 1)
    col = np.where(hitc[:, None], (alb * shade)[:, None] * colours[np.where(hitc, oc + 1, 0)], sky[:, None] * np.array([1.0, 0.95, 0.85]))
    img = col.reshape(hpx, ss, wpx, ss, 3).mean(axis=(1, 3))
    yy, xx = np.mgrid[0:hpx, 0:wpx]
    rr = np.hypot((xx - wpx / 2) / wpx, (yy - hpx / 2) / hpx)
    img = img * (1 - rng.uniform(0.1, 0.35) * rr[..., None] ** 2 * 2)
    img = np.clip(img, 0, 1) ** rng.uniform(0.8, 1.25)
    blur = rng.uniform(0.4, 0.9) if ss == 1 else rng.uniform(0.2, 0.6)
    img = np.stack([gaussian_filter(img[..., c], blur) for c in range(3)], -1)
    noise = p.image_noise if p.image_noise is not None else rng.uniform(1.0, 4.0)
    img = np.clip(img * 240 + 8 + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)[..., ::-1].copy()
    id_img = np.where(hitc, oc + 1, 0).reshape(hpx, ss, wpx, ss)[:, 0, :, 0].astype(np.int32)
    return img, id_img, noise
