"""Ground-truth LiDAR-camera scene: a structured scene ray-cast by a Livox-like LiDAR and a distorted camera.

The scene lives in the LiDAR frame (x forward, y left, z up; the ground is at ``z = -lidar_height``). It holds
boxes, steps, pillars and walls; walls and the ground carry flat painted stripes (image edges without depth edges,
the distractors a targetless method must ignore) and optionally chessboard calibration boards on stands.

* LiDAR: Livox-Mid-70-like non-repetitive rosette (two counter-rotating Risley prisms, 70.4 deg circular FoV,
  ``point_rate`` points/s accumulated over ``duration_s``) or a spinning multi-beam pattern; range noise along the
  ray, reflectivity from the painted albedo and the incidence angle.
* Camera: every pixel's ray (through :meth:`radarcal.camera.Camera.unproject`, so the full distortion model) is cast
  into the same scene from the camera centre given by the true ``T_cam_lidar``; Lambert shading of the albedo,
  optional supersampling, noise.

``render_lidar_camera_scene`` is the pure core (arrays in, arrays out); ``write_lidar_camera_scene`` writes the
files users have: ``image.png``, ``cloud.pcd``, ``truth.json``, ``init.json``, ``bundle.yaml`` (camera ``cam0``,
sensor ``lidar0``). open3d is imported lazily.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from radarcal import geometry
from radarcal.camera import Camera
from radarcal.synth.lidar_patterns import livox_rosette_dirs, spinning_directions

__all__ = [
    "LidarCameraSceneParams",
    "LidarCameraScene",
    "default_camera",
    "default_T_cam_lidar",
    "MOUNT_R_CAM_LIDAR",
    "rosette_directions",
    "spinning_directions",
    "render_lidar_camera_scene",
    "raycasting_scene",
    "seen_from",
    "subpixel_uv",
    "write_lidar_camera_scene",
]

# Usual mounting: camera z = LiDAR x, camera x = -LiDAR y, camera y = -LiDAR z.
MOUNT_R_CAM_LIDAR = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def default_camera() -> Camera:
    """A 1280x1024 industrial camera with a 6 mm-class lens (≈ 71 x 59 deg) and radtan-5 distortion."""
    K = np.array([[900.0, 0.0, 639.5], [0.0, 900.0, 511.5], [0.0, 0.0, 1.0]])
    return Camera((1280, 1024), K, np.array([-0.12, 0.09, 0.0008, -0.0005, -0.02]))


def default_T_cam_lidar(rng: np.random.Generator) -> np.ndarray:
    """The usual mounting plus a random tilt of a few degrees and a ~10 cm lever arm (camera below/right)."""
    dR = geometry.rotvec_to_R(np.radians(rng.uniform(-3.0, 3.0, 3)))
    t_lidar_cam = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.12, -0.04), rng.uniform(-0.12, -0.05)])  # camera centre in LiDAR frame
    R = dR @ MOUNT_R_CAM_LIDAR
    return geometry.make_T(R, -R @ t_lidar_cam)


@dataclass
class LidarCameraSceneParams:
    seed: int = 0
    lidar: str = "rosette"  # "rosette" (Livox Mid-70-like) | "spinning"
    duration_s: float = 2.0
    point_rate: float = 100_000.0
    fov_deg: float = 70.4  # rosette circular FoV
    range_noise_m: float = 0.02
    max_range_m: float = 90.0
    beams: int = 64  # spinning
    beam_elevation_deg: tuple[float, float] = (-24.8, 2.0)
    spin_hz: float = 10.0
    lidar_height_m: float = 1.5
    boards: int = 0
    board_size_m: tuple[float, float] = (1.0, 0.8)  # width, height
    board_squares: tuple[int, int] = (5, 4)
    camera: Camera | None = None
    T_cam_lidar: np.ndarray | None = None
    init_deg: float = 3.0
    init_m: float = 0.10
    supersample: int = 2
    image_noise: float = 2.0


@dataclass
class LidarCameraScene:
    image: np.ndarray  # (H,W,3) uint8 BGR
    id_image: np.ndarray  # (H,W) int32 object id seen at each pixel centre (0 = sky)
    points: np.ndarray  # (N,3) float32 LiDAR frame
    intensity: np.ndarray  # (N,) float32 reflectivity 0..255
    point_ids: np.ndarray  # (N,) int32 object hit by each LiDAR ray
    cam_visible: np.ndarray  # (N,) bool: the noise-free hit point is not occluded from the camera centre
    camera: Camera
    T_cam_lidar: np.ndarray
    T_init: np.ndarray
    objects: list[dict]
    boards: list[dict] = field(default_factory=list)  # {"id", "corners_lidar" (4,3), "corners_uv" (4,2), "size_m"}
    params: dict = field(default_factory=dict)
    meshes: list = field(default_factory=list, repr=False)  # (vertices (n,3), triangles (m,3)) per object, LiDAR frame


# ------------------------------------------------------------------------------------------------------------------
# LiDAR scan patterns
def rosette_directions(n: int, fov_deg: float = 70.4, rate: float = 100_000.0, phase: float = 0.0) -> np.ndarray:
    """Directions (n,3) of ``n`` consecutive rosette firings at ``rate`` points/s starting at time ``phase`` s."""
    return livox_rosette_dirs(np.arange(n, dtype=float) / rate + phase, fov_deg, rates_hz=(121.13, -77.97), phase2=0.0)


# ------------------------------------------------------------------------------------------------------------------
# scene geometry
_BOX_TRIS = np.array(
    [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]],
    dtype=np.int32,
)


def _box(center, size, yaw=0.0, R=None):
    """8 vertices / 12 triangles of an oriented box (center, size = (sx, sy, sz), yaw about z)."""
    sx, sy, sz = np.asarray(size, float) / 2
    v = np.array([[-sx, -sy, -sz], [sx, -sy, -sz], [sx, sy, -sz], [-sx, sy, -sz], [-sx, -sy, sz], [sx, -sy, sz], [sx, sy, sz], [-sx, sy, sz]])
    if R is None:
        c, s = np.cos(yaw), np.sin(yaw)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return v @ R.T + np.asarray(center, float), _BOX_TRIS.copy()


def _prism(center, radius, height, sides=12):
    """A pillar: a regular ``sides``-gon prism standing on z = center.z - height/2."""
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1)
    cx, cy, cz = center
    bot = np.column_stack([ring[:, 0] + cx, ring[:, 1] + cy, np.full(sides, cz - height / 2)])
    top = np.column_stack([ring[:, 0] + cx, ring[:, 1] + cy, np.full(sides, cz + height / 2)])
    v = np.vstack([bot, top, [[cx, cy, cz - height / 2], [cx, cy, cz + height / 2]]])
    i = np.arange(sides)
    j = (i + 1) % sides
    side = np.concatenate([np.stack([i, j, j + sides], 1), np.stack([i, j + sides, i + sides], 1)])
    caps = np.concatenate([np.stack([np.full(sides, 2 * sides), j, i], 1), np.stack([np.full(sides, 2 * sides + 1), i + sides, j + sides], 1)])
    return v, np.concatenate([side, caps]).astype(np.int32)


def _build_scene(rng: np.random.Generator, p: LidarCameraSceneParams) -> tuple[list[dict], list[dict]]:
    """Objects (vertices, triangles, albedo, texture) of a random structured scene, in the LiDAR frame."""
    g = -p.lidar_height_m
    objs: list[dict] = []

    def add(kind, v, f, albedo, stripes=None, board=None):
        objs.append({"kind": kind, "v": v, "f": f, "albedo": float(albedo), "stripes": stripes, "board": board})

    # ground: a big quad with painted lane-like stripes
    add("ground", np.array([[-5, -60, g], [120, -60, g], [120, 60, g], [-5, 60, g]], float), np.array([[0, 1, 2], [0, 2, 3]], np.int32), 0.35,
        stripes={"axis": np.array([0.0, 1.0, 0.0]), "period": 3.7, "duty": 0.12, "contrast": 0.45})
    # back wall and two side walls with painted stripes (no depth edge at the stripe borders)
    back = rng.uniform(24, 30)
    add("wall", *_box((back, 0, g + 4), (0.4, 44, 8), yaw=np.radians(rng.uniform(-8, 8))), 0.6,
        stripes={"axis": np.array([0, np.sin(0.3), np.cos(0.3)]), "period": rng.uniform(2.5, 4.0), "duty": 0.35, "contrast": 0.55})
    for side in (-1, 1):
        y = side * rng.uniform(9, 12)
        add("wall", *_box((back / 2 + 2, y, g + 2.5), (back - 2, 0.3, 5), yaw=np.radians(rng.uniform(-4, 4))), 0.55,
            stripes={"axis": np.array([1.0, 0, 0]), "period": rng.uniform(1.5, 3.0), "duty": 0.5, "contrast": 0.5})
    near = 9.5 if p.boards else 4.0  # keep the foreground free for the boards
    # boxes on the ground
    for _ in range(8):
        x = rng.uniform(near, 18)
        y = rng.uniform(-0.55, 0.55) * x
        sx, sy, sz = rng.uniform(0.8, 2.0), rng.uniform(0.8, 2.5), rng.uniform(0.6, 2.2)
        add("box", *_box((x, y, g + sz / 2), (sx, sy, sz), yaw=rng.uniform(-0.8, 0.8)), rng.uniform(0.25, 0.85))
    # steps: stacked slabs
    x0, y0 = rng.uniform(max(6, near + 1), 12), rng.uniform(-3, 3)
    yaw = rng.uniform(-0.5, 0.5)
    for k in range(4):
        h = 0.35 * (k + 1)
        off = np.array([np.cos(yaw), np.sin(yaw)]) * 0.6 * k
        add("step", *_box((x0 + off[0], y0 + off[1], g + h / 2), (0.6, 3.0, h), yaw=yaw), 0.5 + 0.08 * k)
    # pillars (polygonal) and square columns
    for _ in range(3):
        x = rng.uniform(max(8, near), 22)
        y = rng.uniform(-0.6, 0.6) * x
        h = rng.uniform(3, 6)
        add("pillar", *_prism((x, y, g + h / 2), rng.uniform(0.2, 0.4), h), rng.uniform(0.3, 0.8))
    for _ in range(2):
        x = rng.uniform(max(8, near), 22)
        y = rng.uniform(-0.6, 0.6) * x
        h = rng.uniform(3, 6)
        add("pillar", *_box((x, y, g + h / 2), (0.5, 0.5, h), yaw=rng.uniform(0, 1.5)), rng.uniform(0.3, 0.8))
    # calibration boards on thin stands, facing the sensors
    boards = []
    bw, bh = p.board_size_m
    # boards spread in azimuth, alternately near/low and far/high so that they do not hide each other
    azimuths = np.linspace(-28, 28, p.boards) if p.boards > 1 else np.zeros(p.boards)
    for k in range(p.boards):
        far = k % 2 == 1
        r = rng.uniform(6.5, 8.0) if far else rng.uniform(4.0, 5.5)
        az = np.radians(azimuths[k] + rng.uniform(-1.5, 1.5))
        x, y = r * np.cos(az), r * np.sin(az)
        zc = g + (rng.uniform(2.0, 2.4) if far else rng.uniform(0.9, 1.3))
        yaw = np.arctan2(-y, -x) + rng.uniform(-0.4, 0.4)  # board normal roughly towards the origin
        tilt = rng.uniform(-0.3, 0.3)
        roll = rng.uniform(-0.5, 0.5)
        n = np.array([np.cos(yaw) * np.cos(tilt), np.sin(yaw) * np.cos(tilt), np.sin(tilt)])
        u0 = np.cross([0, 0, 1.0], n)
        u0 /= np.linalg.norm(u0)
        v0 = np.cross(n, u0)
        u = np.cos(roll) * u0 + np.sin(roll) * v0
        v = np.cross(n, u)
        R = np.column_stack([u, v, n])  # board frame: x along width, y along height, z = normal
        c = np.array([x, y, zc])
        verts, tris = _box(c, (bw, bh, 0.02), R=R)
        corners = c + np.array([[-bw / 2, -bh / 2], [bw / 2, -bh / 2], [bw / 2, bh / 2], [-bw / 2, bh / 2]]) @ np.column_stack([u, v]).T + 0.01 * n
        add("board", verts, tris, 0.9, board={"R": R, "c": c, "size": (bw, bh), "squares": p.board_squares})
        boards.append({"object": len(objs) - 1, "corners_lidar": corners, "size_m": [bw, bh]})
        add("stand", *_box((x - n[0] * 0.1, y - n[1] * 0.1, (g + zc - bh / 2 * np.cos(tilt)) / 2), (0.05, 0.05, max(0.1, zc - bh / 2 * np.cos(tilt) - g)), yaw=yaw), 0.3)
    return objs, boards


def _albedo(objs: list[dict], obj_idx: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Painted albedo at hit points (vectorised per object)."""
    out = np.zeros(len(obj_idx))
    for k, o in enumerate(objs):  # loop over objects (tens), not points
        m = obj_idx == k
        if not np.any(m):
            continue
        a = np.full(int(m.sum()), o["albedo"])
        if o["stripes"] is not None:
            s = o["stripes"]
            phase = (pts[m] @ s["axis"]) / s["period"]
            painted = (phase - np.floor(phase)) < s["duty"]
            a = np.where(painted, a * (1 - s["contrast"]) if o["albedo"] > 0.45 else np.minimum(1.0, a + s["contrast"]), a)
        if o["board"] is not None:
            b = o["board"]
            local = (pts[m] - b["c"]) @ b["R"]
            nx, ny = b["squares"]
            bw, bh = b["size"]
            ix = np.floor((local[:, 0] + bw / 2) / bw * nx)
            iy = np.floor((local[:, 1] + bh / 2) / bh * ny)
            front = local[:, 2] > 0
            a = np.where(front & (((ix + iy) % 2) == 0), 0.08, 0.9)
        out[m] = a
    return out


def _pixel_rays(cam: Camera, uv: np.ndarray, step: int = 4) -> np.ndarray:
    """Unit camera-frame rays of many pixels: exact :meth:`Camera.unproject` on a grid every ``step`` px, cubic
    spline interpolation of the normalised coordinates in between (< 0.002 px round-trip error, 5x faster)."""
    from scipy.ndimage import map_coordinates

    w, h = cam.image_size
    gu = np.arange(-16, w + 20, step, dtype=float)
    gv = np.arange(-16, h + 20, step, dtype=float)
    grid = np.stack(np.meshgrid(gu, gv), -1).reshape(-1, 2)
    r = cam.unproject(grid)
    xy = (r[:, :2] / r[:, 2:]).reshape(len(gv), len(gu), 2)
    bad = ~np.isfinite(xy).all(-1)
    if bad.any():  # the grid's margin lies outside where a strong distortion inverts: the spline's prefilter would
        # spread one NaN over the whole image (family2 seeds 123/124 rendered black); take the nearest valid node there
        from scipy.ndimage import distance_transform_edt

        idx = distance_transform_edt(bad, return_distances=False, return_indices=True)
        xy = xy[idx[0], idx[1]]
    ci = (uv[:, 1] - gv[0]) / step
    cj = (uv[:, 0] - gu[0]) / step
    x = map_coordinates(xy[..., 0], [ci, cj], order=3, mode="nearest")
    y = map_coordinates(xy[..., 1], [ci, cj], order=3, mode="nearest")
    rays = np.stack([x, y, np.ones_like(x)], axis=1)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def _raycast(scene, origins: np.ndarray, dirs: np.ndarray):
    """Cast rays (origins (1,3) or (N,3), unit directions (N,3)) into an open3d ``RaycastingScene``: hit distance
    (inf: none), geometry id, primitive normal."""
    import open3d as o3d

    rays = np.concatenate([np.broadcast_to(origins, dirs.shape), dirs], axis=1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t = ans["t_hit"].numpy().astype(float)
    gid = ans["geometry_ids"].numpy().astype(np.int64)
    nrm = ans["primitive_normals"].numpy().astype(float)
    return t, gid, nrm


def raycasting_scene(meshes: list[tuple[np.ndarray, np.ndarray]]):
    """An open3d ``RaycastingScene`` of the (vertices, faces) meshes and ``obj_of(geometry ids) -> mesh index``
    (-1: no hit)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    gid_to_obj = {}
    for k, (v, f) in enumerate(meshes):
        gid = scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
        gid_to_obj[int(gid)] = k
    lut = np.full(max(gid_to_obj) + 2, -1, np.int64)
    for g_, k in gid_to_obj.items():
        lut[g_] = k
    invalid = np.iinfo(np.uint32).max

    def obj_of(gid):
        out = np.full(gid.shape, -1, np.int64)
        ok = (gid != invalid) & (gid >= 0) & (gid < len(lut))
        out[ok] = lut[gid[ok]]
        return out

    return scene, obj_of


def seen_from(scene, pts_lidar: np.ndarray, c_lidar: np.ndarray) -> np.ndarray:
    """Which LiDAR points the camera centre ``c_lidar`` (LiDAR frame) sees unoccluded (parallax between the sensors)."""
    to_pt = pts_lidar - c_lidar
    dist = np.linalg.norm(to_pt, axis=1)
    tv, _, _ = _raycast(scene, c_lidar[None, :], to_pt / dist[:, None])
    return tv > dist - 0.01


def subpixel_uv(w: int, h: int, ss: int) -> np.ndarray:
    """(h*ss*w*ss, 2) pixel coordinates of an ``ss`` x ``ss`` sample grid in every pixel, row-major."""
    off = (np.arange(ss) + 0.5) / ss - 0.5
    uu, vv = np.meshgrid(np.arange(w * ss) // ss + np.tile(off, w), np.arange(h * ss) // ss + np.tile(off, h))
    return np.stack([uu.ravel(), vv.ravel()], axis=1)


def render_lidar_camera_scene(params: LidarCameraSceneParams | None = None) -> LidarCameraScene:
    """Build and ray-cast a scene (deterministic for a seed). Pure: no files written."""
    p = params or LidarCameraSceneParams()
    rng = np.random.default_rng(p.seed)
    cam = p.camera or default_camera()
    T_cam_lidar = np.asarray(p.T_cam_lidar, float) if p.T_cam_lidar is not None else default_T_cam_lidar(rng)
    objs, boards = _build_scene(rng, p)
    scene, obj_of = raycasting_scene([(o["v"], o["f"]) for o in objs])
    points, refl, obj, pts_true = _lidar_returns(rng, p, scene, obj_of, objs)
    T_lidar_cam = geometry.invert_T(T_cam_lidar)
    cam_visible = seen_from(scene, pts_true, T_lidar_cam[:3, 3])
    img, id_full = _render_camera(rng, p, cam, T_lidar_cam, scene, obj_of, objs)
    objects = [{"id": k + 1, "kind": o["kind"], "albedo": o["albedo"]} for k, o in enumerate(objs)]
    board_out = []
    for b in boards:
        uvb, valid, _ = cam.project_from(T_cam_lidar, b["corners_lidar"])
        board_out.append({"id": b["object"] + 1, "corners_lidar": b["corners_lidar"], "corners_uv": uvb, "visible": bool(np.all(valid & cam.in_image(uvb))), "size_m": b["size_m"]})
    T_init = geometry.perturb_T(T_cam_lidar, p.init_deg, p.init_m, rng)
    pd = {k: (v.to_dict() if isinstance(v, Camera) else v) for k, v in p.__dict__.items() if k not in ("T_cam_lidar",)}
    return LidarCameraScene(img, id_full.astype(np.int32), points, refl.astype(np.float32), (obj + 1).astype(np.int32), cam_visible, cam, T_cam_lidar, T_init, objects, board_out, pd, [(o["v"], o["f"]) for o in objs])


def _lidar_returns(rng, p: LidarCameraSceneParams, scene, obj_of, objs: list):
    """The LiDAR's returns (LiDAR frame): noisy points (N,3) float32, reflectivity (albedo x incidence + noise),
    object index of each, exact points."""
    n_pts = int(round(p.point_rate * p.duration_s))
    if p.lidar == "rosette":
        dirs = rosette_directions(n_pts, p.fov_deg, p.point_rate, phase=rng.uniform(0, 10))
    elif p.lidar == "spinning":
        dirs = spinning_directions(p.beams, p.beam_elevation_deg, p.duration_s, p.spin_hz, p.point_rate)
    else:
        raise ValueError(f"lidar: expected 'rosette' or 'spinning', got {p.lidar!r}")
    t, gid, nrm = _raycast(scene, np.zeros((1, 3)), dirs)
    hit = np.isfinite(t) & (t < p.max_range_m)
    obj = obj_of(gid)
    hit &= obj >= 0
    dirs, t, obj, nrm = dirs[hit], t[hit], obj[hit], nrm[hit]
    pts_true = dirs * t[:, None]
    alb = _albedo(objs, obj, pts_true)
    cos_inc = np.abs(np.sum(nrm * dirs, axis=1))
    refl = np.clip(255 * alb * (0.3 + 0.7 * cos_inc) + rng.normal(0, 2.0, len(t)), 0, 255)
    r_noisy = t + rng.normal(0, p.range_noise_m, len(t))
    return (dirs * r_noisy[:, None]).astype(np.float32), refl, obj, pts_true


def _render_camera(rng, p: LidarCameraSceneParams, cam: Camera, T_lidar_cam: np.ndarray, scene, obj_of, objs: list):
    """The camera image (rays of every sub-pixel through the distorted model, shaded albedo, tinted per object, sky
    bright, noise) and the id image (object + 1 at each pixel centre, 0: sky)."""
    ss = max(1, int(p.supersample))
    w, h = cam.image_size
    rays_l = _pixel_rays(cam, subpixel_uv(w, h, ss)) @ T_lidar_cam[:3, :3].T
    tc, gc, nc = _raycast(scene, T_lidar_cam[:3, 3][None, :], rays_l)
    oc = obj_of(gc)
    hitc = np.isfinite(tc) & (oc >= 0)
    pc = T_lidar_cam[:3, 3] + rays_l * np.where(hitc, tc, 0)[:, None]
    albc = np.zeros(len(tc))
    albc[hitc] = _albedo(objs, oc[hitc], pc[hitc])
    light = np.array([0.4, 0.3, 0.86])
    light /= np.linalg.norm(light)
    shade = 0.45 + 0.55 * np.abs(nc @ light)
    base = np.where(hitc, albc * shade, 0.85)  # sky bright
    tint = np.array([[1.0, 1.0, 1.0]] + [[0.85 + 0.3 * ((k * 37) % 5) / 5, 0.9, 0.85 + 0.3 * ((k * 53) % 7) / 7] for k in range(len(objs))])
    col = base[:, None] * tint[np.where(hitc, oc + 1, 0)]
    img = col.reshape(h, ss, w, ss, 3).mean(axis=(1, 3)) if ss > 1 else col.reshape(h, w, 3)
    img = np.clip(img * 235 + 10 + rng.normal(0, p.image_noise, img.shape), 0, 255).astype(np.uint8)
    # id image: the object at each pixel centre (sub-sample nearest the centre for odd ss, else re-cast centres)
    if ss % 2 == 1:
        id_full = np.where(hitc, oc + 1, 0).reshape(h, ss, w, ss)[:, ss // 2, :, ss // 2]
    else:
        uvc = np.stack(np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float)), -1).reshape(-1, 2)
        r0 = _pixel_rays(cam, uvc) @ T_lidar_cam[:3, :3].T
        t0, g0, _ = _raycast(scene, T_lidar_cam[:3, 3][None, :], r0)
        o0 = obj_of(g0)
        id_full = np.where(np.isfinite(t0) & (o0 >= 0), o0 + 1, 0).reshape(h, w)
    return img, id_full


def write_lidar_camera_scene(scene: LidarCameraScene, out_dir: str | Path, command: str = "") -> dict[str, Path]:
    """Write image.png, cloud.pcd, truth.json, init.json, ids.npz and bundle.yaml (camera cam0, sensor lidar0)."""
    import cv2

    from radarcal.bundle import Bundle, Provenance, save_bundle
    from radarcal.io import write_pcd

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"image": out / "image.png", "cloud": out / "cloud.pcd", "truth": out / "truth.json", "init": out / "init.json", "bundle": out / "bundle.yaml", "ids": out / "ids.npz"}
    cv2.imwrite(str(paths["image"]), scene.image)
    write_pcd(paths["cloud"], scene.points, scene.intensity)
    np.savez_compressed(paths["ids"], point_ids=scene.point_ids, cam_visible=scene.cam_visible, id_image=scene.id_image)
    truth = {
        "T_cam_lidar": scene.T_cam_lidar.tolist(),
        "camera": scene.camera.to_dict(),
        "objects": scene.objects,
        "boards": [{"id": b["id"], "corners_lidar": np.asarray(b["corners_lidar"]).tolist(), "corners_uv": np.asarray(b["corners_uv"]).tolist(), "visible": b["visible"], "size_m": list(b["size_m"])} for b in scene.boards],
        "n_points": int(len(scene.points)),
        "params": scene.params,
        "files": {k: v.name for k, v in paths.items()},
        "notes": "T_cam_lidar maps LiDAR points into the camera (p_cam = T @ p_lidar). ids.npz: point_ids per cloud point, cam_visible (not occluded from the camera) and id_image per pixel (0 = sky/nothing) refer to objects[].id.",
    }
    paths["truth"].write_text(json.dumps(truth, indent=1))
    paths["init"].write_text(json.dumps({"T_cam_lidar": scene.T_init.tolist()}, indent=1))
    b = Bundle()
    b.set_camera("cam0", scene.camera, provenance=Provenance(command=command or "radarcal synth lidar-camera"), extra={"synthetic": True})
    b.set_sensor("lidar0", type="lidar", model=scene.params.get("sensor_model") or ("livox-mid70-like" if scene.params.get("lidar") == "rosette" else "spinning"))
    save_bundle(b, paths["bundle"])
    return paths
