"""Field scene generator (``radarcal synth field``): a radar station (camera + Livox-Mid-70-like LiDAR ≈ 2.5 m high
at the field edge) watching robots drive over a RoboMaster field, written as the replay folder of
``notes/REPLAY_FORMAT.md`` (``docs/field.md`` describes it).

Everything is ray casting in numpy against one scene: the field's surface solid (ground + raised areas with walls,
:meth:`radarcal.field.FieldModel.ray_hits`) plus oriented boxes (structures such as bases/outposts, and robots).
Pure functions build the scene (rig, robot paths, LiDAR rays, image boxes, images); :func:`write_field_replay`
is the only function that touches files. Deterministic for a given seed.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from radarcal import geometry
from radarcal.camera import Camera
from radarcal.field import FieldModel
from radarcal.synth.lidar_patterns import livox_rosette_dirs

__all__ = [
    "FieldSceneConfig",
    "Rig",
    "RobotSpec",
    "SceneBoxes",
    "default_rig",
    "make_robots",
    "robot_states",
    "scene_boxes",
    "raycast",
    "object_names",
    "object_kinds",
    "livox_rosette_dirs",
    "simulate_lidar",
    "box_corners",
    "image_box",
    "render_background",
    "render_frame",
    "write_field_replay",
    "write_frame_jpeg",
    "write_lidar_clouds",
    "write_truth_bundle",
    "ROBOT_TYPES",
]

# RoboMaster robot ids: 1 hero, 2 engineer, 3/4/5 infantry, 7 sentry. (length, width, height) of the box, metres.
ROBOT_TYPES: dict[int, tuple[float, float, float]] = {
    1: (0.60, 0.55, 0.50),
    2: (0.55, 0.55, 0.60),
    3: (0.50, 0.50, 0.45),
    4: (0.50, 0.50, 0.45),
    5: (0.50, 0.50, 0.45),
    7: (0.55, 0.55, 0.55),
}
_ROBOT_ORDER = ["blue_1", "blue_3", "blue_7", "blue_2", "blue_4", "red_3", "blue_5", "red_1", "red_4", "red_2", "red_5", "red_7"]

# reflectivity (LiDAR intensity, 0..255) and BGR colour per object kind
_KIND_REFLECT = {"ground": 20.0, "area": 35.0, "structure": 90.0, "robot": 60.0}


@dataclass
class FieldSceneConfig:
    """Options of a generated field replay (all deterministic given ``seed``)."""

    frames: int = 300
    seed: int = 0
    robots: int = 6
    fps: float = 30.0
    lidar_hz: float = 10.0
    lidar_points: int = 10_000           # points per LiDAR frame (Mid-70: ~100 k points/s -> 10 k per 0.1 s)
    lidar_range_sigma: float = 0.02      # m, along the ray
    lidar_gap: tuple[float, float] | None = None  # (start s, duration s): no clouds in that window
    image_scale: float = 0.5             # render at this fraction of the resolution, then resize to full size
    jpeg_quality: int = 70
    image_every: int = 1                 # write an image for every k-th camera frame only (size); detections every frame
    det_jitter_px: float = 0.0           # σ of Gaussian jitter on detection box edges
    det_dropout: float = 0.0             # probability that a visible robot has no detection in a frame
    speed: float = 1.5                   # typical robot speed, m/s
    station: str = "red"                 # whose radar station: red (x < 0 end) or blue (x > 28 end)


@dataclass
class Rig:
    camera: Camera
    T_field_cam: np.ndarray
    T_cam_lidar: np.ndarray

    @property
    def T_field_lidar(self) -> np.ndarray:
        return self.T_field_cam @ self.T_cam_lidar


@dataclass
class RobotSpec:
    """One robot: label, box size (l, w, h) and a smooth closed path ``xy(t) = c + Σ a_k sin(w_k t + φ_k)``."""

    label: str
    size: tuple[float, float, float]
    center: np.ndarray        # (2,)
    amp: np.ndarray           # (K,2)
    omega: np.ndarray         # (K,)
    phase: np.ndarray         # (K,2)

    def to_dict(self) -> dict:
        return {"id": self.label, "label": self.label, "size_lwh": list(self.size), "path": {"center": self.center.tolist(), "amp": self.amp.tolist(), "omega": self.omega.tolist(), "phase": self.phase.tolist(), "formula": "xy(t) = center + sum_k amp_k * sin(omega_k t + phase_k), then pushed out of structures and clamped to the field"}}


@dataclass
class SceneBoxes:
    """Oriented boxes standing on z0: bottom centre (B,3), size (B,3) l w h, yaw (B,), names, kinds ("structure"|"robot")."""

    center: np.ndarray
    size: np.ndarray
    yaw: np.ndarray
    names: list[str] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    colors: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.names)


# --- rig -------------------------------------------------------------------------------------------------------
def default_rig(field_model: FieldModel, rng: np.random.Generator | None = None, station: str = "red") -> Rig:
    """Radar station: camera 2.5 m high at its own end of the field (red: x < 0, blue: x > 28, the central mirror),
    looking over the field; LiDAR mounted just below.

    1280x1024, fx = fy = 1100 px (≈ 5.3 mm lens on 4.8 µm pixels, ±30° horizontal), mild radtan distortion.
    ``rng`` adds a small random variation of the mounting (seeded scenes differ a little)."""
    L, W = field_model.size
    cam = Camera((1280, 1024), np.array([[1100.0, 0.0, 641.3], [0.0, 1100.0, 509.2], [0.0, 0.0, 1.0]]), np.array([-0.08, 0.05, 0.0005, -0.0003, 0.0]))
    jitter = rng.normal(0, 1, 6) if rng is not None else np.zeros(6)
    pos = np.array([-0.6, W * 0.77, 2.5]) + jitter[:3] * [0.05, 0.1, 0.05]
    target = np.array([L * 0.55, W * 0.45, 0.0])
    fwd = target - pos
    yaw = np.arctan2(fwd[1], fwd[0]) + np.deg2rad(jitter[3] * 1.0)
    pitch = np.deg2rad(16.0 + jitter[4] * 0.5)   # down
    roll = np.deg2rad(jitter[5] * 0.5)
    # body frame (x forward, y left, z up) -> camera axes (x right, y down, z forward)
    R_field_body = geometry.rpy_deg_to_R(np.rad2deg(roll), np.rad2deg(pitch), np.rad2deg(yaw))
    R_body_cam = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    T_field_cam = geometry.make_T(R_field_body @ R_body_cam, pos)
    if station == "blue":  # the field is centrally symmetric: turn the red station 180° about the centre's vertical
        T_field_cam = np.array([[-1.0, 0, 0, L], [0, -1.0, 0, W], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]) @ T_field_cam
    elif station != "red":
        raise ValueError(f"station: expected red or blue, got {station!r}")
    # LiDAR (x forward, y left, z up) 9 cm below, 4 cm left of, 3 cm behind the camera, tilted ~1.2° against it
    R_cam_lidar = R_body_cam.T @ geometry.rpy_deg_to_R(0.6, -1.0, 0.8)
    T_cam_lidar = geometry.make_T(R_cam_lidar, np.array([-0.04, 0.09, -0.03]))
    return Rig(cam, T_field_cam, T_cam_lidar)


# --- robots ----------------------------------------------------------------------------------------------------
def make_robots(field_model: FieldModel, n: int, rng: np.random.Generator, speed: float = 1.5, station: str = "red") -> list[RobotSpec]:
    """``n`` robots (the enemy's first: a red station watches blue robots) with smooth random paths over the field."""
    if not 0 <= n <= len(_ROBOT_ORDER):
        raise ValueError(f"robots: expected 0..{len(_ROBOT_ORDER)}, got {n}")
    L, W = field_model.size
    out = []
    swap = {"red": "blue", "blue": "red"}
    order = _ROBOT_ORDER if station == "red" else ["_".join([swap[lb.split("_")[0]], lb.split("_")[1]]) for lb in _ROBOT_ORDER]
    for label in order[:n]:
        rid = int(label.split("_")[1])
        K = 3
        omega = rng.uniform(0.08, 0.35, K)
        amp = rng.uniform(0.5, 1.0, (K, 2)) * np.array([L * 0.22, W * 0.25]) / K * 1.6
        # scale amplitudes so the mean speed is about `speed`
        v = np.sqrt(np.sum((amp * omega[:, None]) ** 2) / 2)
        amp *= min(1.0, speed / max(v, 1e-6)) if v > speed else 1.0
        center = np.array([rng.uniform(0.25 * L, 0.85 * L), rng.uniform(0.3 * W, 0.7 * W)])
        if station == "blue":
            center = np.array([L, W]) - center
        out.append(RobotSpec(label, ROBOT_TYPES[rid], center, amp, omega, rng.uniform(0, 2 * np.pi, (K, 2))))
    return out


def _push_out(field_model: FieldModel, xy: np.ndarray, clearance: float = 0.75) -> np.ndarray:
    """Keep robot centres off structures (radial push) and inside the field (clamp)."""
    xy = xy.copy()
    for s in field_model.structures:
        c = np.asarray(s["center"][:2], float)
        r = 0.5 * float(np.hypot(s["size"][0], s["size"][1])) + clearance
        d = xy - c
        dist = np.linalg.norm(d, axis=-1, keepdims=True)
        inside = dist < r
        xy = np.where(inside, c + d / np.maximum(dist, 1e-9) * r, xy)
    L, W = field_model.size
    return np.clip(xy, [0.5, 0.5], [L - 0.5, W - 0.5])


def robot_states(field_model: FieldModel, robots: list[RobotSpec], t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Robot ground positions ``p_field`` (T,R,3) (z = surface under the centre) and headings (T,R) at times t (T,)."""
    t = np.atleast_1d(np.asarray(t, float))
    if not robots:
        return np.zeros((len(t), 0, 3)), np.zeros((len(t), 0))

    def xy_at(tt: np.ndarray) -> np.ndarray:
        cols = []
        for r in robots:
            s = np.sin(r.omega[None, :, None] * tt[:, None, None] + r.phase[None])  # (T,K,2)
            cols.append(r.center[None] + np.sum(r.amp[None] * s, axis=1))
        return _push_out(field_model, np.stack(cols, axis=1))

    xy = xy_at(t)
    dt = 0.05
    vel = xy_at(t + dt) - xy_at(t - dt)
    yaw = np.arctan2(vel[..., 1], vel[..., 0])
    z = field_model.surface_z(xy.reshape(-1, 2)).reshape(xy.shape[:2])
    return np.concatenate([xy, z[..., None]], axis=-1), yaw


def scene_boxes(field_model: FieldModel, robots: list[RobotSpec] | None = None, p_field: np.ndarray | None = None, yaw: np.ndarray | None = None) -> SceneBoxes:
    """Structures of the field plus (optionally) robots at one instant (``p_field`` (R,3), ``yaw`` (R,))."""
    c, s, y, names, kinds, colors = [], [], [], [], [], []
    for st in field_model.structures:
        c.append(st["center"])
        s.append(st["size"])
        y.append(st.get("yaw", 0.0))
        names.append(st["name"])
        kinds.append("structure")
        colors.append(str(st.get("color", "grey")))
    for i, r in enumerate(robots or []):
        c.append(p_field[i])
        s.append(r.size)
        y.append(yaw[i])
        names.append(r.label)
        kinds.append("robot")
        colors.append(r.label.split("_")[0])
    return SceneBoxes(np.asarray(c, float).reshape(-1, 3), np.asarray(s, float).reshape(-1, 3), np.asarray(y, float).reshape(-1), names, kinds, colors)


# --- ray casting -----------------------------------------------------------------------------------------------
def _ray_boxes(o: np.ndarray, d: np.ndarray, boxes: SceneBoxes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slab test of rays (N,3) against oriented boxes: (t (N,) inf=none, box index (N,), normal (N,3) field frame)."""
    n = len(o)
    if len(boxes) == 0 or n == 0:
        return np.full(n, np.inf), np.full(n, -1), np.zeros((n, 3))
    cy, sy = np.cos(boxes.yaw), np.sin(boxes.yaw)  # (B,)
    # into box frames: p_box = Rz(-yaw) (p - c) - [0, 0, h/2]
    rel = o[:, None, :] - boxes.center[None]  # (N,B,3)
    ox = cy * rel[..., 0] + sy * rel[..., 1]
    oy = -sy * rel[..., 0] + cy * rel[..., 1]
    oz = rel[..., 2] - boxes.size[None, :, 2] / 2
    dx = cy * d[:, None, 0] + sy * d[:, None, 1]
    dy = -sy * d[:, None, 0] + cy * d[:, None, 1]
    dz = np.broadcast_to(d[:, None, 2], dx.shape)
    half = boxes.size[None] / 2  # (1,B,3)
    O = np.stack([ox, oy, oz], -1)
    D = np.stack([dx, dy, dz], -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / D
        t1 = (-half - O) * inv
        t2 = (half - O) * inv
    tlo = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
    thi = np.where(np.isnan(t2), np.inf, np.maximum(t1, t2))
    tnear = tlo.max(-1)
    axis = tlo.argmax(-1)  # (N,B)
    tfar = thi.min(-1)
    ok = (tnear <= tfar) & (tnear > 1e-9)
    tb = np.where(ok, tnear, np.inf)
    j = np.argmin(tb, axis=1)
    t = tb[np.arange(n), j]
    ax = axis[np.arange(n), j]
    sgn = -np.sign(D[np.arange(n), j, ax])
    nl = np.zeros((n, 3))
    nl[np.arange(n), ax] = sgn
    c, s = cy[j], sy[j]
    normal = np.stack([c * nl[:, 0] - s * nl[:, 1], s * nl[:, 0] + c * nl[:, 1], nl[:, 2]], -1)
    return t, np.where(np.isfinite(t), j, -1), normal


def _surface_normals(field_model: FieldModel, p: np.ndarray, area: np.ndarray) -> np.ndarray:
    """Normals of field-surface hits: ground / area tops (plane normal) or walls (normal of the nearest edge)."""
    nrm = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    for j, a in enumerate(field_model.areas):
        m = np.nonzero(area == j)[0]
        if len(m) == 0:
            continue
        pa, pb, pc = (a["plane"] if a.get("plane") is not None else (0.0, 0.0, a["z"]))
        top = pa * p[m, 0] + pb * p[m, 1] + pc
        nt = np.array([-pa, -pb, 1.0]) / np.sqrt(pa * pa + pb * pb + 1)
        nrm[m] = nt
        wall = m[p[m, 2] < top - 1e-6]
        if len(wall):
            q0 = a["polygon"]
            e = np.roll(q0, -1, axis=0) - q0
            rel = p[wall, None, :2] - q0[None]
            s = np.clip(np.sum(rel * e[None], -1) / np.sum(e * e, -1)[None], 0, 1)
            dist = np.linalg.norm(rel - s[..., None] * e[None], axis=-1)
            k = np.argmin(dist, axis=1)
            en = np.stack([e[k, 1], -e[k, 0]], -1)
            en /= np.linalg.norm(en, axis=1, keepdims=True)
            nrm[wall] = np.concatenate([en, np.zeros((len(wall), 1))], 1)
    return nrm


def raycast(field_model: FieldModel, boxes: SceneBoxes, origins: np.ndarray, dirs: np.ndarray, normals: bool = False):
    """First hit of rays (field frame) with the field solid and the boxes.

    Returns ``t`` (N,) (NaN: no hit; hit point = o + t d), ``obj`` (N,) object index into :func:`object_names`
    order — 0 ground, 1..A areas, A+1.. boxes — and, with ``normals=True``, unit normals (N,3) facing the ray."""
    o = np.asarray(origins, float).reshape(-1, 3)
    d = np.asarray(dirs, float).reshape(-1, 3)
    o = np.broadcast_to(o, d.shape) if len(o) == 1 else o
    nmesh = None
    if field_model.mesh is not None:  # a mesh-backed field: exact triangles (open3d), the whole mesh is object 0
        tf, nmesh = field_model.raycast_exact(o, d)
        area = np.full(len(tf), -1, dtype=np.int64)
    else:
        tf, area = field_model.ray_hits(o, d)
    tf = np.where(np.isnan(tf), np.inf, tf)
    tb, jb, nb = _ray_boxes(o, d, boxes)
    use_box = tb < tf
    t = np.where(use_box, tb, tf)
    A = len(field_model.areas)
    obj = np.where(use_box, A + 1 + jb, area + 1)
    t = np.where(np.isfinite(t), t, np.nan)
    obj = np.where(np.isfinite(t), obj, -1)
    if not normals:
        return t, obj
    p = o + np.nan_to_num(t)[:, None] * d
    nf = _surface_normals(field_model, p, np.where(use_box, -2, area)) if nmesh is None else np.nan_to_num(nmesh)
    nrm = np.where(use_box[:, None], nb, nf)
    flip = np.sum(nrm * d, axis=1) > 0
    nrm[flip] *= -1
    return t, obj, nrm


def object_names(field_model: FieldModel, boxes: SceneBoxes) -> list[str]:
    return ["ground"] + [a["name"] for a in field_model.areas] + list(boxes.names)


def object_kinds(field_model: FieldModel, boxes: SceneBoxes) -> list[str]:
    return ["ground"] + ["area"] * len(field_model.areas) + list(boxes.kinds)


# --- LiDAR -----------------------------------------------------------------------------------------------------
def simulate_lidar(field_model: FieldModel, boxes: SceneBoxes, T_field_lidar: np.ndarray, t0: float, n_points: int, rng: np.random.Generator, point_rate: float = 100_000.0, range_sigma: float = 0.02):
    """One LiDAR frame: points (M,3) in the LiDAR frame, intensity (M,), hit object index (M,) (see :func:`raycast`),
    true range (M,). Points that hit nothing (sky) are dropped, as a real LiDAR returns nothing for them."""
    t = t0 + np.arange(n_points) / point_rate
    d_l = livox_rosette_dirs(t)
    R = T_field_lidar[:3, :3]
    d_f = d_l @ R.T
    o_f = T_field_lidar[:3, 3][None]
    tt, obj = raycast(field_model, boxes, o_f, d_f)
    keep = np.isfinite(tt) & (tt > 0.05) & (tt < 260.0)
    rng_true = tt[keep]
    noisy = rng_true + rng.normal(0.0, range_sigma, rng_true.size)
    pts = d_l[keep] * noisy[:, None]
    kinds = object_kinds(field_model, boxes)
    refl = np.array([_KIND_REFLECT[k] for k in kinds])[obj[keep]]
    inten = np.clip(refl + rng.normal(0, 3.0, refl.size), 0, 255)
    return pts.astype(np.float32), inten.astype(np.float32), obj[keep], rng_true


# --- image boxes -----------------------------------------------------------------------------------------------
def box_corners(center: np.ndarray, size: np.ndarray, yaw: float) -> np.ndarray:
    """8 corners (8,3) of a box standing on ``center`` (bottom centre) with size (l, w, h) and heading ``yaw``."""
    l, w, h = size
    sx = np.array([-1, 1, 1, -1, -1, 1, 1, -1]) * l / 2
    sy = np.array([-1, -1, 1, 1, -1, -1, 1, 1]) * w / 2
    sz = np.array([0, 0, 0, 0, 1, 1, 1, 1]) * h
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([center[0] + c * sx - s * sy, center[1] + s * sx + c * sy, center[2] + sz], 1)


_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]])


def image_box(camera: Camera, T_cam_field: np.ndarray, center: np.ndarray, size: np.ndarray, yaw: float, samples: int = 24) -> np.ndarray | None:
    """Tight image box [x1, y1, x2, y2] of a projected 3D box, clipped to the image (None if not in view).

    Edges are sampled densely (lens distortion bends them), so the box is the true extent to ≪ 1 px."""
    C = box_corners(center, size, yaw)
    s = np.linspace(0, 1, samples)
    P = C[_EDGES[:, 0], None] * (1 - s)[None, :, None] + C[_EDGES[:, 1], None] * s[None, :, None]
    uv, valid, z = camera.project_from(T_cam_field, P.reshape(-1, 3))
    if not np.all(valid) or np.any(z < 0.1):
        return None  # part of the box behind the camera: not a sensible detection
    w, h = camera.image_size
    x1, y1 = uv.min(0)
    x2, y2 = uv.max(0)
    x1, x2 = np.clip([x1, x2], -0.5, w - 0.5)
    y1, y2 = np.clip([y1, y2], -0.5, h - 0.5)
    if x2 - x1 < 1.0 or y2 - y1 < 1.0:
        return None
    return np.array([x1, y1, x2, y2])


# --- rendering -------------------------------------------------------------------------------------------------
_BGR = {"red": (50, 50, 200), "blue": (200, 90, 40), "grey": (150, 150, 150)}
_LIGHT = np.array([0.35, 0.25, 0.9]) / np.linalg.norm([0.35, 0.25, 0.9])


def _pixel_rays(camera: Camera, T_field_cam: np.ndarray) -> np.ndarray:
    w, h = camera.image_size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    rays_c = camera.unproject(np.stack([u.ravel(), v.ravel()], 1))
    return (rays_c @ T_field_cam[:3, :3].T).reshape(h, w, 3)


def _shade(field_model: FieldModel, boxes: SceneBoxes, p: np.ndarray, obj: np.ndarray, nrm: np.ndarray) -> np.ndarray:
    """BGR colours (N,3) float for hit points: flat Lambert shading, a faint 2 m grid on the ground, border lines."""
    A = len(field_model.areas)
    base = np.zeros((len(p), 3))
    ground = obj == 0
    base[ground] = (95, 110, 100)
    L, W = field_model.size
    inside = (p[:, 0] >= 0) & (p[:, 0] <= L) & (p[:, 1] >= 0) & (p[:, 1] <= W)
    base[ground & ~inside] = (70, 70, 70)
    # faint 2 m grid (texture for people looking at the image; not a landmark)
    fx, fy = np.abs(p[:, 0] / 2 - np.round(p[:, 0] / 2)), np.abs(p[:, 1] / 2 - np.round(p[:, 1] / 2))
    base[ground & inside & ((fx < 0.01) | (fy < 0.01))] = (110, 124, 115)
    border = ground & inside & ((p[:, 0] < 0.08) | (p[:, 0] > L - 0.08) | (p[:, 1] < 0.08) | (p[:, 1] > W - 0.08))
    base[border] = (235, 235, 235)
    for j, a in enumerate(field_model.areas):
        m = obj == j + 1
        base[m] = (150, 165, 175) if a.get("plane") is None else (120, 150, 180)
    for k in range(len(boxes)):
        base[obj == A + 1 + k] = _BGR.get(boxes.colors[k], _BGR["grey"])
    lam = 0.45 + 0.55 * np.clip(nrm @ _LIGHT, 0, 1)
    col = base * lam[:, None]
    col[obj < 0] = (200, 180, 160)  # sky / hall
    return col


def render_background(field_model: FieldModel, rig: Rig, scale: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Static scene (field + structures) seen by the camera at ``scale``: BGR image (h,w,3) uint8, depth along the
    ray (h,w) (inf: sky), unit pixel rays in the field frame (h,w,3)."""
    cam = rig.camera.scaled(scale)
    rays = _pixel_rays(cam, rig.T_field_cam)
    h, w = rays.shape[:2]
    boxes = scene_boxes(field_model)
    o = rig.T_field_cam[:3, 3][None]
    d = rays.reshape(-1, 3)
    t, obj, nrm = raycast(field_model, boxes, o, d, normals=True)
    p = o + np.nan_to_num(t)[:, None] * d
    col = _shade(field_model, boxes, p, obj, nrm)
    img = np.clip(col, 0, 255).astype(np.uint8).reshape(h, w, 3)
    depth = np.where(np.isfinite(t), t, np.inf).reshape(h, w)
    return img, depth, rays


def render_frame(field_model: FieldModel, rig: Rig, background: tuple[np.ndarray, np.ndarray, np.ndarray], robots: SceneBoxes, scale: float = 0.5) -> np.ndarray:
    """Background + robots (ray cast only inside each robot's projected box), resized to the camera's full size."""
    import cv2

    img, depth, rays = background
    img = img.copy()
    cam = rig.camera.scaled(scale)
    T_cam_field = geometry.invert_T(rig.T_field_cam)
    o = rig.T_field_cam[:3, 3][None]
    h, w = depth.shape
    rects = []
    for k in range(len(robots)):
        bb = image_box(cam, T_cam_field, robots.center[k], robots.size[k], robots.yaw[k])
        if bb is not None:
            rects.append(bb)
    if rects:
        r = np.array(rects)
        x1, y1 = int(max(0, np.floor(r[:, 0].min()))), int(max(0, np.floor(r[:, 1].min())))
        x2, y2 = int(min(w - 1, np.ceil(r[:, 2].max()))), int(min(h - 1, np.ceil(r[:, 3].max())))
        # cast only the pixels inside any robot rectangle
        yy, xx = np.mgrid[y1 : y2 + 1, x1 : x2 + 1]
        m = np.zeros(yy.shape, bool)
        for bb in rects:
            m |= (xx >= bb[0] - 1) & (xx <= bb[2] + 1) & (yy >= bb[1] - 1) & (yy <= bb[3] + 1)
        ys, xs = yy[m], xx[m]
        d = rays[ys, xs]
        t, j, nrm = _ray_boxes(np.broadcast_to(o, d.shape), d, robots)
        front = np.isfinite(t) & (t < depth[ys, xs])
        if np.any(front):
            obj = len(field_model.areas) + 1 + j[front]
            col = _shade(field_model, robots, np.zeros((front.sum(), 3)), obj, nrm[front])
            img[ys[front], xs[front]] = np.clip(col, 0, 255).astype(np.uint8)
    W_, H_ = rig.camera.image_size
    if img.shape[1] != W_ or img.shape[0] != H_:
        img = cv2.resize(img, (W_, H_), interpolation=cv2.INTER_LINEAR)
    return img


# --- writer ----------------------------------------------------------------------------------------------------
def _fmt(x: float, nd: int = 4) -> float:
    return float(round(float(x), nd))


def write_field_replay(out_dir: str | Path, field_model: FieldModel, config: FieldSceneConfig, generator: str = "radarcal synth field", progress: Callable | None = None) -> dict:
    """Generate the scene for ``config`` and write the replay folder. Returns a summary dict."""
    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    (out / "clouds").mkdir(parents=True, exist_ok=True)
    ss = np.random.SeedSequence(config.seed)
    rng_rig, rng_rob, rng_lidar, rng_det = (np.random.default_rng(s) for s in ss.spawn(4))
    rig = default_rig(field_model, rng_rig, config.station)
    robots = make_robots(field_model, config.robots, rng_rob, config.speed, config.station)
    track = progress or (lambda it, **_: it)
    landmark_px, hidden = _landmark_pixels(field_model, rig)
    n_images, n_vis = _write_camera_frames(out, field_model, rig, robots, config, rng_det, track)
    n_clouds, n_points_total = write_lidar_clouds(out / "clouds", field_model, robots, rig.T_field_lidar, config, rng_lidar, track, gap=config.lidar_gap)
    write_truth_bundle(out / "calib.yaml", field_model, {"cam0": rig}, generator, {"cam0": {}})
    truth = {
        "seed": config.seed,
        "field": field_model.name,
        "camera": rig.camera.to_dict(),
        "T_cam0_lidar0": rig.T_cam_lidar.tolist(),
        "T_field_cam0": rig.T_field_cam.tolist(),
        "T_field_lidar0": rig.T_field_lidar.tolist(),
        "landmark_pixels": landmark_px,
        "landmarks_hidden": hidden,
        "landmarks_field": {k: v.tolist() for k, v in field_model.landmarks.items()},
        "robots": [r.to_dict() for r in robots],
        "noise": {"lidar_range_sigma_m": config.lidar_range_sigma, "det_jitter_px": config.det_jitter_px, "det_dropout": config.det_dropout, "image_jpeg_quality": config.jpeg_quality},
        "lidar": {"pattern": "risley rosette 121.57 Hz / -77.73 Hz, 70.4 deg circular FOV", "points_per_frame": config.lidar_points, "hz": config.lidar_hz, "gap": list(config.lidar_gap) if config.lidar_gap else None, "robots_frozen_at_cloud_stamp": True},
        "config": asdict(config),
        "field_model": field_model.to_dict(),
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    n = config.frames
    meta = {"camera": "cam0", "lidar": "lidar0", "station": config.station, "field": field_model.name, "fps": config.fps, "lidar_hz": config.lidar_hz, "n_frames": n, "seed": config.seed, "generator": generator}
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    return {"out": str(out), "frames": n, "images": n_images, "clouds": n_clouds, "robots": len(robots), "visible_boxes": n_vis, "cloud_points": n_points_total, "landmarks_in_image": sorted(landmark_px), "bytes": size}


def _landmark_pixels(field_model: FieldModel, rig: Rig) -> tuple[dict, list]:
    """The landmarks' true pixels (those inside the image) and the names of those hidden behind the field solid or
    a structure (a person could not click them)."""
    cam = rig.camera
    names = list(field_model.landmarks)
    P = field_model.landmark_array(names)
    uv, valid, _ = cam.project_from(geometry.invert_T(rig.T_field_cam), P)
    inimg = valid & cam.in_image(uv)
    landmark_px = {n: [float(uv[i, 0]), float(uv[i, 1])] for i, n in enumerate(names) if inimg[i]}
    dvec = P - rig.T_field_cam[:3, 3]
    dist = np.linalg.norm(dvec, axis=1)
    t_hit, _ = raycast(field_model, scene_boxes(field_model), rig.T_field_cam[:3, 3][None], dvec / dist[:, None])
    hidden = [n for i, n in enumerate(names) if inimg[i] and np.isfinite(t_hit[i]) and t_hit[i] < dist[i] - 0.05]
    return landmark_px, hidden


def write_frame_jpeg(path: Path, field_model: FieldModel, rig: Rig, background: tuple, boxes: SceneBoxes, n_static: int, scale: float, quality: int) -> None:
    """Render the robots of ``boxes`` (those after the ``n_static`` structures) over ``background`` and write the
    JPEG to ``path``."""
    import cv2

    s = slice(n_static, None)
    robots = SceneBoxes(boxes.center[s], boxes.size[s], boxes.yaw[s], boxes.names[s], boxes.kinds[s], boxes.colors[s])
    ok, buf = cv2.imencode(".jpg", render_frame(field_model, rig, background, robots, scale), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError(f"JPEG encoding failed for {path}")
    path.write_bytes(buf.tobytes())


def _write_camera_frames(out: Path, field_model: FieldModel, rig: Rig, robots: list[RobotSpec], config: FieldSceneConfig, rng_det, track) -> tuple[int, int]:
    """``images/`` (every ``image_every``-th frame, ``times.csv``), ``detections.jsonl`` and ``truth.jsonl`` (one
    line per frame); returns (images written, visible robot boxes)."""
    n = config.frames
    t_img = np.arange(n) / config.fps
    p_all, yaw_all = robot_states(field_model, robots, t_img)
    background = render_background(field_model, rig, config.image_scale)
    ns = len(scene_boxes(field_model))
    det_lines, truth_lines, img_times = [], [], []
    n_vis = 0
    for f in track(range(n), description="frames"):
        fname = f"{f:06d}.jpg"
        boxes_f = scene_boxes(field_model, robots, p_all[f], yaw_all[f])
        if f % max(1, config.image_every) == 0:
            write_frame_jpeg(out / "images" / fname, field_model, rig, background, boxes_f, ns, config.image_scale, config.jpeg_quality)
            img_times.append((fname, t_img[f]))
        rob_truth, dets = _frame_robots(field_model, rig, robots, boxes_f, ns, p_all[f], yaw_all[f], config, rng_det)
        n_vis += sum(r["visible"] for r in rob_truth)
        det_lines.append(json.dumps({"t": _fmt(t_img[f], 6), "frame": fname, "boxes": dets}))
        truth_lines.append(json.dumps({"t": _fmt(t_img[f], 6), "frame": fname, "robots": rob_truth}))
    (out / "detections.jsonl").write_text("\n".join(det_lines) + "\n")
    (out / "truth.jsonl").write_text("\n".join(truth_lines) + "\n")
    (out / "images" / "times.csv").write_text("file,t\n" + "".join(f"{a},{b:.6f}\n" for a, b in img_times))
    return len(img_times), n_vis


def _frame_robots(field_model: FieldModel, rig: Rig, robots: list[RobotSpec], boxes_f: SceneBoxes, n_static: int, p: np.ndarray, yaw: np.ndarray, config: FieldSceneConfig, rng_det):
    """One frame: every robot's truth (full projected box, visible = one of 9 points on its box in the image and not
    occluded) and the detections of the visible ones (dropout, edge jitter, score)."""
    cam = rig.camera
    T_cam_field = geometry.invert_T(rig.T_field_cam)
    o_cam = rig.T_field_cam[:3, 3]
    rob_truth, dets = [], []
    for k, r in enumerate(robots):
        c, size, yw = p[k], np.asarray(r.size), yaw[k]
        bb = image_box(cam, T_cam_field, c, size, yw)
        visible = False
        if bb is not None:
            pts = np.vstack([box_corners(c, size * [0.98, 0.98, 0.98], yw), c + [0, 0, size[2] / 2]])
            uvp, vp, _ = cam.project_from(T_cam_field, pts)
            dvec = pts - o_cam
            dist = np.linalg.norm(dvec, axis=1)
            tt, obj = raycast(field_model, boxes_f, o_cam[None], dvec / dist[:, None])
            own = obj == len(field_model.areas) + 1 + n_static + k
            unblocked = own | (np.nan_to_num(tt, nan=np.inf) >= dist - 0.05)
            visible = bool(np.any(vp & cam.in_image(uvp) & unblocked))
        rob_truth.append({"id": r.label, "label": r.label, "p_field": [_fmt(v) for v in c], "yaw": _fmt(yw), "xyxy": None if bb is None else [_fmt(v, 2) for v in bb], "visible": visible})
        if visible:
            if rng_det.random() < config.det_dropout:
                continue
            b = bb + (rng_det.normal(0, config.det_jitter_px, 4) if config.det_jitter_px > 0 else 0)
            b = np.clip(b, [-0.5, -0.5, -0.5, -0.5], [cam.width - 0.5, cam.height - 0.5] * 2)
            dets.append({"xyxy": [_fmt(v, 2) for v in b], "label": r.label, "score": _fmt(rng_det.uniform(0.6, 0.99), 3)})
    return rob_truth, dets


def write_lidar_clouds(folder: Path, field_model: FieldModel, robots: list[RobotSpec], T_field_lidar: np.ndarray, config: FieldSceneConfig, rng_lidar, track,
                       gap: tuple[float, float] | None = None) -> tuple[int, int]:  # fmt: skip
    """``folder/NNNNNN.pcd`` at ``config.lidar_hz`` over the replay (robots frozen at each cloud's stamp) and
    ``folder/times.csv``; none in ``gap`` = (start s, duration s). Returns (clouds written, points)."""
    from radarcal.io import write_pcd

    folder.mkdir(parents=True, exist_ok=True)
    n_clouds = int(np.floor(config.frames / config.fps * config.lidar_hz + 1e-9))
    t_cloud = np.arange(n_clouds) / config.lidar_hz
    p_c, yaw_c = robot_states(field_model, robots, t_cloud)
    cloud_times = []
    n_points = 0
    for k in track(range(n_clouds), description="clouds"):
        boxes_k = scene_boxes(field_model, robots, p_c[k], yaw_c[k])
        pts, inten, _, _ = simulate_lidar(field_model, boxes_k, T_field_lidar, t_cloud[k], config.lidar_points, rng_lidar, point_rate=config.lidar_points * config.lidar_hz, range_sigma=config.lidar_range_sigma)
        if gap is not None and gap[0] <= t_cloud[k] < gap[0] + gap[1]:
            continue  # the rng was still advanced, so the clouds outside the gap do not depend on it
        cname = f"{k:06d}.pcd"
        write_pcd(folder / cname, pts, inten)
        cloud_times.append((cname, t_cloud[k]))
        n_points += len(pts)
    (folder / "times.csv").write_text("file,t\n" + "".join(f"{a},{b:.6f}\n" for a, b in cloud_times))
    return len(cloud_times), n_points


def write_truth_bundle(path: Path, field_model: FieldModel, rigs: dict[str, Rig], generator: str, camera_extra: dict[str, dict], lidar_first: bool = False) -> None:
    """The calibration bundle of a generated replay: every camera (``camera_extra[name]`` added to its ``extra``),
    the LiDAR ``lidar0``, the true ``T_<camera>_lidar0`` and ``T_field_<camera>``, the field model. ``lidar_first``:
    the sensors' order in the file (the multi-camera replays list the LiDAR first)."""
    from radarcal.bundle import Bundle, Provenance, save_bundle

    b = Bundle()
    prov = Provenance(command=generator)
    if lidar_first:
        b.set_sensor("lidar0", type="lidar", model="Livox Mid-70 (simulated)", fov_deg=70.4)
    for name, rig in rigs.items():
        b.set_camera(name, rig.camera, rms_px=0.0, provenance=prov, extra={"synthetic": True, **camera_extra.get(name, {})})
        if not lidar_first:
            b.set_sensor("lidar0", type="lidar", model="Livox Mid-70 (simulated)", fov_deg=70.4)
        b.set_transform(name, "lidar0", rig.T_cam_lidar, method="synthetic truth", provenance=prov)
        b.set_transform("field", name, rig.T_field_cam, method="synthetic truth", provenance=prov)
    b.field_model = field_model.to_dict()
    save_bundle(b, path)
