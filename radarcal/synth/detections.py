"""Realistic match replays for ``radarcal run`` (``radarcal synth match``): a second scene family, independent of the
exact boxes ``radarcal synth field`` writes.

What a live station would receive, generated from one ray-cast scene (the field solid + structures from
:mod:`radarcal.synth.field`'s public functions, plus a perimeter barrier, a referee's box, people walking along the
boundary, an aerial robot):

* **Boxes of the visible part only**: each robot's projected box is sampled on a pixel grid and ray cast against the
  whole scene; the box is the extent of the samples whose first hit is that robot. A robot whose visible fraction is
  below ``min_visible`` has no box (a detector misses it). Edges jittered by N(0, s), s ~ U(3, 6) px per box;
  5 % missed; false positives (on the people at the boundary and on empty field, labels drawn from every robot
  label, including robots not on the field); 2 % label swaps 3 <-> 4.
* **Clouds as a live sensor delivers them**: the rosette fires point by point over 100 ms while the robots keep
  moving (the scene is re-posed every ``slice_s``); a cloud is written with its *arrival* time (end of the sweep +
  ``cloud_latency_s``), its points in firing order (``meta.json``: ``cloud_stamp: arrival``, ``cloud_sweep_s``,
  ``cloud_latency_s``).
* **Calibration error**: the bundle's ``T_cam_lidar`` is the truth turned by ``calib_rot_deg`` about a random axis
  and shifted by ``calib_trans_m``; the field pose is ``radarcal field-pnp``'s (same solver, bundle entry and
  session) on four landmark clicks with ``pnp_px`` noise, written as ``field_picks.csv``.

Scenarios: ``random`` (robots on smooth random paths) and ``occlusion`` (two pairs of robots crossing behind each
other in the camera's view, one robot driving behind the central highland, one out of the camera's view but in the
LiDAR's). The field is any :class:`~radarcal.field.FieldModel` (``--field``): when the field's mesh replaces the
extruded polygons, :func:`radarcal.synth.field.raycast` casts against it and these replays follow.

``truth.jsonl`` per camera frame: every robot's ``p_field`` at the frame time, ``visible`` (any part seen by the
camera), ``visible_fraction``, ``lidar_hits`` (returns on it in the newest cloud delivered by then), ``in_view``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from radarcal import geometry
from radarcal.field import FieldModel
from radarcal.synth.field import RobotSpec, SceneBoxes, default_rig, image_box, livox_rosette_dirs, make_robots, raycast, render_background, robot_states, scene_boxes

__all__ = ["MatchConfig", "write_match_replay", "visible_boxes", "perturb_T", "four_point_clicks", "match_rngs", "people_states", "occlusion_robots"]

_ALL_LABELS = [f"{c}_{n}" for c in ("red", "blue") for n in (1, 2, 3, 4, 5, 6, 7)]
AERIAL_SIZE = (0.8, 0.8, 0.35)
PERSON_SIZE = (0.4, 0.35, 1.72)


@dataclass
class MatchConfig:
    frames: int = 450
    seed: int = 0
    robots: int = 9  # ground robots (0..12), plus one aerial robot when ``aerial``
    aerial: bool = True
    scenario: str = "random"  # random | occlusion
    fps: float = 30.0
    lidar_hz: float = 10.0
    lidar_points: int = 10_000
    lidar_range_sigma: float = 0.02
    slice_s: float = 0.01  # the scene is re-posed every slice of the sweep (robots move during it)
    cloud_latency_s: float = 0.012  # sweep end -> arrival at the host
    jitter_px: tuple[float, float] = (3.0, 6.0)
    miss: float = 0.05
    min_visible: float = 0.2  # visible fraction of the silhouette below which the detector has no box
    false_positives: float = 0.12  # expected false boxes per frame
    swap: float = 0.02  # 3 <-> 4 label confusion per box
    calib_rot_deg: float = 0.3
    calib_trans_m: float = 0.02
    pnp_px: float = 1.5
    people: int = 4  # walking along the boundary, 0.3-0.9 m outside the field line
    speed: float = 1.5
    station: str = "red"
    camera_miss: tuple = ()  # ((label, t0, t1), ...): the detector drops that robot in [t0, t1]; the LiDAR still sees it
    absent: tuple = ()  # ((label, t0, t1), ...): that robot is truly off the field in [t0, t1] (no returns, no box, not in truth)
    lidar_miss: tuple = ()  # ((label, t0, t1), ...): the LiDAR gets no return from that robot in [t0, t1] (dropout); the camera still sees it


def _in_windows(windows: tuple, label: str, t: np.ndarray) -> np.ndarray:
    """(T,) bool: ``t`` inside one of the ``(label, t0, t1)`` windows of ``label``."""
    t = np.asarray(t, float)
    hit = np.zeros(t.shape, bool)
    for lab, t0, t1 in windows:
        if lab == label:
            hit |= (t >= t0) & (t <= t1)
    return hit


# --- geometry helpers ----------------------------------------------------------------------------------------------
def _ray_hits_box(o: np.ndarray, d: np.ndarray, center: np.ndarray, size: np.ndarray, yaw: float) -> np.ndarray:
    """(N,) bool: rays from ``o`` (3,) along ``d`` (N,3) hit the oriented box standing on ``center``."""
    c, s = np.cos(yaw), np.sin(yaw)
    rel = o - center
    O = np.array([c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1], rel[2] - size[2] / 2])
    D = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]])
    half = np.asarray(size, float) / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - O) / D, (half - O) / D
    lo = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2)).max(1)
    hi = np.where(np.isnan(t2), np.inf, np.maximum(t1, t2)).min(1)
    return (lo <= hi) & (hi > 1e-6)


def perturb_T(T: np.ndarray, rot_deg: float, trans_m: float, rng: np.random.Generator) -> np.ndarray:
    """``T`` turned by ``rot_deg`` about a random axis and shifted by ``trans_m`` in a random direction."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    import cv2

    dR = cv2.Rodrigues(axis * np.deg2rad(rot_deg))[0]
    dt = rng.normal(size=3)
    dt *= trans_m / np.linalg.norm(dt)
    out = np.array(T, float)
    out[:3, :3] = dR @ out[:3, :3]
    out[:3, 3] = out[:3, 3] + dt
    return out


def four_point_clicks(field_model: FieldModel, rig, px_sigma: float, rng: np.random.Generator) -> tuple[list[str], np.ndarray]:
    """The four visible landmarks spanning the largest image quadrilateral and their clicks: the true pixels
    (``rig.camera``, ``rig.T_field_cam``) plus N(0, ``px_sigma``) noise per axis. Returns (names, (4,2) px)."""
    import itertools

    import cv2

    cam = rig.camera
    T_cam_field = geometry.invert_T(rig.T_field_cam)
    names = list(field_model.landmarks)
    P = field_model.landmark_array(names)
    uv, valid, _ = cam.project_from(T_cam_field, P)
    o = rig.T_field_cam[:3, 3]
    dvec = P - o
    dist = np.linalg.norm(dvec, axis=1)
    t_hit, _ = raycast(field_model, scene_boxes(field_model), o[None], dvec / dist[:, None])
    seen = valid & cam.in_image(uv, margin=5) & ~(np.isfinite(t_hit) & (t_hit < dist - 0.05))
    idx = np.flatnonzero(seen)
    best, best_area = None, -1.0
    for q in itertools.combinations(idx, 4):
        h = cv2.convexHull(uv[list(q)].astype(np.float32))
        a = float(cv2.contourArea(h))
        if a > best_area:
            best, best_area = list(q), a
    if best is None:
        raise ValueError("fewer than four landmarks visible for the field PnP")
    return [names[i] for i in best], uv[best] + rng.normal(0, px_sigma, (4, 2))


# --- scene contents ------------------------------------------------------------------------------------------------
def people_states(field_model: FieldModel, n: int, t: np.ndarray, rng_seed: int) -> np.ndarray:
    """(T, n, 3) positions of people walking back and forth along the boundary, 0.3-0.9 m outside the line."""
    L, W = field_model.size
    rng = np.random.default_rng(rng_seed)
    out = np.zeros((len(t), n, 3))
    for k in range(n):
        side = k % 4
        off = rng.uniform(0.3, 0.9)
        a, b = rng.uniform(0.1, 0.9, 2) * (L if side < 2 else W)
        lo, hi = min(a, b), max(a, b) + 2.0
        v = rng.uniform(0.6, 1.3)
        span = hi - lo
        s = lo + span * np.abs(((t * v / span + rng.uniform()) % 2.0) - 1.0)  # triangle wave along the side
        if side == 0:
            out[:, k, :2] = np.column_stack([np.clip(s, 0, L), np.full(len(t), -off)])
        elif side == 1:
            out[:, k, :2] = np.column_stack([np.clip(s, 0, L), np.full(len(t), W + off)])
        elif side == 2:
            out[:, k, :2] = np.column_stack([np.full(len(t), L + off), np.clip(s, 0, W)])
        else:
            out[:, k, :2] = np.column_stack([np.full(len(t), -1.6 - off), np.clip(s, 0, W)])  # behind the station
    return out


def occlusion_robots(field_model: FieldModel) -> list[RobotSpec]:
    """Fixed paths for the occlusion replay (red station behind x = 0, camera near y = 11.5 looking down the field):
    two pairs crossing in the image at different ranges, one robot driving behind the central highland
    (x 12-16, y 5-10, 0.6 m high) and back, one out of the camera's view but in the LiDAR's."""
    def lin(label, size, c, amp, omega, phase):
        return RobotSpec(label, size, np.array(c, float), np.array(amp, float).reshape(1, 2), np.array([omega], float), np.array(phase, float).reshape(1, 2))

    s = (0.5, 0.5, 0.45)
    # the camera looks along ~(16, -4.8): robots moving across that direction cross in the image
    return [
        lin("blue_3", s, (8.0, 6.5), (1.2, 3.0), 0.35, (0.0, 0.0)),
        lin("blue_4", s, (11.0, 5.3), (-1.2, -3.0), 0.35, (0.0, 0.0)),
        lin("blue_1", (0.6, 0.55, 0.5), (19.0, 5.0), (0.6, 3.5), 0.3, (1.0, 1.0)),
        lin("blue_5", s, (21.5, 4.5), (-0.6, -3.5), 0.3, (1.0, 1.0)),
        lin("blue_7", (0.55, 0.55, 0.55), (17.4, 8.0), (1.0, 1.6), 0.25, (np.pi / 2, 0.0)),  # behind the highland
        lin("blue_2", (0.55, 0.55, 0.6), (4.4, 12.9), (0.6, 0.15), 0.3, (0.0, 0.0)),  # beside the station: LiDAR only
    ]


def _ground_yaw(xy_fn: Callable[[np.ndarray], np.ndarray], t: np.ndarray) -> np.ndarray:
    v = xy_fn(t + 0.05) - xy_fn(t - 0.05)
    return np.arctan2(v[..., 1], v[..., 0])


def _aerial_states(field_model: FieldModel, t: np.ndarray, rng_seed: int) -> np.ndarray:
    """(T,3) aerial robot: slow loops 1.6-2.2 m above the enemy half."""
    L, W = field_model.size
    rng = np.random.default_rng(rng_seed)
    w = rng.uniform(0.15, 0.3, 2)
    ph = rng.uniform(0, 2 * np.pi, 2)
    x = L * 0.62 + 3.5 * np.sin(w[0] * t + ph[0])
    y = W * 0.5 + 3.0 * np.sin(w[1] * t + ph[1])
    z = 1.9 + 0.3 * np.sin(0.5 * t)
    return np.column_stack([x, y, z])


class _Scene:
    """Everything that can be hit at an instant: field structures + barrier + referee box + people + robots."""

    def __init__(self, field_model: FieldModel, robots: list[RobotSpec], cfg: MatchConfig, aerial_label: str | None):
        self.field = field_model
        self.robots = robots
        self.cfg = cfg
        self.aerial_label = aerial_label
        L, W = field_model.size
        st = scene_boxes(field_model)
        c, s, y, names, kinds = list(st.center), list(st.size), list(st.yaw), list(st.names), list(st.kinds)
        # perimeter barrier 0.5 m high, 0.15 m outside the line (not part of the field model)
        for nm, cc, ss in (("wall_s", (L / 2, -0.25, 0), (L + 0.7, 0.1, 0.5)), ("wall_n", (L / 2, W + 0.25, 0), (L + 0.7, 0.1, 0.5)),
                           ("wall_e", (L + 0.25, W / 2, 0), (0.1, W + 0.7, 0.5))):  # fmt: skip
            c.append(cc), s.append(ss), y.append(0.0), names.append(nm), kinds.append("static")
        c.append((L - 0.7, 0.6, 0.0)), s.append((0.5, 0.4, 0.8)), y.append(0.3), names.append("referee_box"), kinds.append("static")
        self.static = SceneBoxes(np.asarray(c, float), np.asarray(s, float), np.asarray(y, float), names, kinds)

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Robot bottom centres (T,R,3), headings (T,R) and people (T,P,3) at times t (T,)."""
        p, yaw = robot_states(self.field, self.robots, t)
        if self.aerial_label is not None:
            a = _aerial_states(self.field, t, self.cfg.seed + 101)
            ay = 0.2 * t
            p = np.concatenate([p, a[:, None]], axis=1)
            yaw = np.concatenate([yaw, ay[:, None]], axis=1)
        for i, lab in enumerate(self.labels):  # off the field: far below the floor behind the station, where no ray reaches
            gone = _in_windows(self.cfg.absent, lab, t)
            if gone.any():
                p = p.copy()
                p[gone, i] = (-500.0 if self.cfg.station == "red" else self.field.size[0] + 500.0, self.field.size[1] / 2, -1000.0)
        ppl = people_states(self.field, self.cfg.people, t, self.cfg.seed + 202)
        return p, yaw, ppl

    @property
    def labels(self) -> list[str]:
        return [r.label for r in self.robots] + ([self.aerial_label] if self.aerial_label else [])

    @property
    def sizes(self) -> np.ndarray:
        return np.array([r.size for r in self.robots] + ([AERIAL_SIZE] if self.aerial_label else []), float).reshape(-1, 3)

    def boxes(self, p: np.ndarray, yaw: np.ndarray, ppl: np.ndarray) -> SceneBoxes:
        """Static boxes + people + robots (robots last, in label order)."""
        st = self.static
        n_p = len(ppl)
        sizes = self.sizes
        c = np.vstack([st.center, ppl, p])
        s = np.vstack([st.size, np.tile(PERSON_SIZE, (n_p, 1)), sizes])
        y = np.concatenate([st.yaw, np.zeros(n_p), yaw])
        names = st.names + [f"person_{k}" for k in range(n_p)] + self.labels
        kinds = st.kinds + ["person"] * n_p + ["robot"] * len(self.labels)
        return SceneBoxes(c, s, y, names, kinds)


def visible_boxes(field_model: FieldModel, camera, T_field_cam: np.ndarray, boxes: SceneBoxes, which: list[int], step_max: float = 3.0):
    """Visible-part image boxes of ``boxes[which]``: (len(which),4) xyxy (NaN rows: not visible), visible fraction of
    each silhouette, full projected boxes. Ray casting on a grid of at most ``step_max`` px inside each full box."""
    T_cam_field = geometry.invert_T(T_field_cam)
    o = T_field_cam[:3, 3]
    out = np.full((len(which), 4), np.nan)
    frac = np.zeros(len(which))
    full = np.full((len(which), 4), np.nan)
    uvs, owners = [], []
    for i, k in enumerate(which):
        bb = image_box(camera, T_cam_field, boxes.center[k], boxes.size[k], float(boxes.yaw[k]))
        if bb is None:
            continue
        full[i] = bb
        step = min(step_max, max(0.75, min(bb[2] - bb[0], bb[3] - bb[1]) / 14))
        u = np.arange(bb[0] + step / 2, bb[2], step)
        v = np.arange(bb[1] + step / 2, bb[3], step)
        uu, vv = np.meshgrid(u, v)
        uvs.append(np.column_stack([uu.ravel(), vv.ravel()]))
        owners.append(np.full(uu.size, i))
    if not uvs:
        return out, frac, full
    uv = np.vstack(uvs)
    own = np.concatenate(owners)
    rays = camera.unproject(uv) @ T_field_cam[:3, :3].T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    _, obj = raycast(field_model, boxes, o[None], rays)
    A1 = len(field_model.areas) + 1
    for i, k in enumerate(which):
        m = own == i
        if not m.any():
            continue
        sil = _ray_hits_box(o, rays[m], boxes.center[k], boxes.size[k], float(boxes.yaw[k]))
        vis = obj[m] == A1 + k
        n_sil = int(sil.sum())
        frac[i] = vis.sum() / n_sil if n_sil else 0.0
        if vis.any():
            q = uv[m][vis]
            step = min(step_max, max(0.75, min(full[i, 2] - full[i, 0], full[i, 3] - full[i, 1]) / 14))
            out[i] = [max(q[:, 0].min() - step / 2, full[i, 0]), max(q[:, 1].min() - step / 2, full[i, 1]), min(q[:, 0].max() + step / 2, full[i, 2]), min(q[:, 1].max() + step / 2, full[i, 3])]
    return out, frac, full


def _swap_label(label: str) -> str:
    team, num = label.split("_")
    return team + "_" + {"3": "4", "4": "3"}.get(num, num)


def _fmt(x: float, nd: int = 4) -> float:
    return float(round(float(x), nd))


def match_rngs(seed: int) -> tuple[np.random.Generator, ...]:
    """The five independent generators of a ``synth match`` replay: (rig, robots, LiDAR, detections, calibration)."""
    return tuple(np.random.default_rng(s) for s in np.random.SeedSequence(seed + 7919).spawn(5))


def write_match_replay(out_dir: str | Path, field_model: FieldModel, cfg: MatchConfig, generator: str = "radarcal synth match", progress: Callable | None = None) -> dict:
    """Generate the scene for ``cfg`` and write a replay folder (clouds/, detections.jsonl, truth.jsonl, calib.yaml,
    meta.json, truth.json; no images). Returns a summary."""
    out = Path(out_dir)
    (out / "clouds").mkdir(parents=True, exist_ok=True)
    rng_rig, rng_rob, rng_lidar, rng_det, rng_cal = match_rngs(cfg.seed)
    rig = default_rig(field_model, rng_rig, cfg.station)
    if cfg.scenario == "occlusion":
        robots = occlusion_robots(field_model)
    elif cfg.scenario == "random":
        robots = make_robots(field_model, cfg.robots, rng_rob, cfg.speed, cfg.station)
    else:
        raise ValueError(f"scenario: expected random or occlusion, got {cfg.scenario!r}")
    enemy = "blue" if cfg.station == "red" else "red"
    scene = _Scene(field_model, robots, cfg, f"{enemy}_6" if cfg.aerial and cfg.scenario == "random" else None)
    track = progress or (lambda it, **_: it)
    t_arrive, hits_per_cloud, n_pts_total = _write_match_clouds(out, field_model, scene, rig.T_field_lidar, cfg, rng_lidar, track)
    counts = _write_match_frames(out, field_model, scene, rig, cfg, rng_det, t_arrive, hits_per_cloud, track)
    _write_still(out, field_model, rig)
    err, pnp_names = _write_match_bundle(out / "calib.yaml", field_model, rig, cfg, rng_cal, generator)
    labels = scene.labels
    truth = {"seed": cfg.seed, "field": field_model.name, "config": asdict(cfg), "labels": labels, "T_cam0_lidar0": rig.T_cam_lidar.tolist(),
             "T_field_cam0": rig.T_field_cam.tolist(), "bundle_errors": err, "pnp_landmarks": pnp_names, "robots": [r.to_dict() for r in robots]}  # fmt: skip
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    meta = {"camera": "cam0", "lidar": "lidar0", "station": cfg.station, "field": field_model.name, "fps": cfg.fps, "lidar_hz": cfg.lidar_hz, "n_frames": cfg.frames,
            "seed": cfg.seed, "generator": generator, "cloud_stamp": "arrival", "cloud_sweep_s": 1.0 / cfg.lidar_hz, "cloud_latency_s": cfg.cloud_latency_s}  # fmt: skip
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    return {"out": str(out), "frames": cfg.frames, "clouds": len(t_arrive), "robots": len(labels), **counts, "cloud_points": n_pts_total, **err}


def _write_match_clouds(out: Path, field_model: FieldModel, scene: _Scene, T_field_lidar: np.ndarray, cfg: MatchConfig, rng_lidar, track):
    """``clouds/`` as a live sensor delivers them: points fired over the sweep, the scene re-posed every slice, each
    cloud stamped with its arrival (sweep end + latency) in ``times.csv``. Returns the arrival times, the LiDAR returns
    on every robot per cloud (clouds, robots) and the number of points."""
    from radarcal.io import write_pcd

    labels = scene.labels
    R = len(labels)
    sweep = 1.0 / cfg.lidar_hz
    n_clouds = int(np.floor(cfg.frames / cfg.fps / sweep + 1e-9))
    per_slice = max(1, int(round(cfg.slice_s / sweep * cfg.lidar_points)))
    cloud_rows, hits_per_cloud = [], np.zeros((n_clouds, R), int)
    n_pts_total = 0
    first_robot = len(field_model.areas) + 1 + len(scene.static) + cfg.people  # object id of the first robot
    for k in track(range(n_clouds), description="clouds"):
        t_fire = k * sweep + np.arange(cfg.lidar_points) / (cfg.lidar_points * cfg.lidar_hz)
        d_l = livox_rosette_dirs(t_fire)
        d_f = d_l @ T_field_lidar[:3, :3].T
        o_f = T_field_lidar[:3, 3]
        t_all = np.full(len(t_fire), np.nan)
        obj_all = np.full(len(t_fire), -1)
        starts = np.arange(0, len(t_fire), per_slice)
        tc = t_fire[np.minimum(starts + per_slice // 2, len(t_fire) - 1)]
        P, Y, PP = scene.at(tc)
        for j, a in enumerate(starts):
            b = min(a + per_slice, len(t_fire))
            tt, obj = raycast(field_model, scene.boxes(P[j], Y[j], PP[j]), o_f[None], d_f[a:b])
            t_all[a:b], obj_all[a:b] = tt, obj
        keep = np.isfinite(t_all) & (t_all > 0.05) & (t_all < 260.0)
        for i, lab in enumerate(labels):  # LiDAR dropout: that robot's returns are lost (not replaced by what is behind it)
            if cfg.lidar_miss:
                keep &= ~((obj_all == first_robot + i) & _in_windows(cfg.lidar_miss, lab, t_fire))
        rng_true = t_all[keep]
        pts = d_l[keep] * (rng_true + rng_lidar.normal(0, cfg.lidar_range_sigma, rng_true.size))[:, None]
        robot_idx = obj_all[keep] - first_robot
        hits_per_cloud[k] = np.bincount(robot_idx[(robot_idx >= 0) & (robot_idx < R)], minlength=R)
        kind = np.where(robot_idx >= 0, 60.0, np.where(obj_all[keep] >= len(field_model.areas) + 1, 90.0, 25.0))
        inten = np.clip(kind + rng_lidar.normal(0, 3.0, kind.size), 0, 255).astype(np.float32)
        name = f"{k:06d}.pcd"
        write_pcd(out / "clouds" / name, pts.astype(np.float32), inten)
        cloud_rows.append((name, (k + 1) * sweep + cfg.cloud_latency_s))
        n_pts_total += len(pts)
    (out / "clouds" / "times.csv").write_text("file,t\n" + "".join(f"{a},{b:.6f}\n" for a, b in cloud_rows))
    return np.array([b for _, b in cloud_rows]), hits_per_cloud, n_pts_total


def _write_match_frames(out: Path, field_model: FieldModel, scene: _Scene, rig, cfg: MatchConfig, rng_det, t_arrive: np.ndarray, hits_per_cloud: np.ndarray, track) -> dict:
    """``detections.jsonl`` and ``truth.jsonl``, one line per camera frame: visible-part boxes, misses, false
    positives, label swaps. Returns the counts of the summary."""
    labels = scene.labels
    R = len(labels)
    t_img = np.arange(cfg.frames) / cfg.fps
    P, Y, PP = scene.at(t_img)
    det_lines, truth_lines = [], []
    counts = {"visible_robot_frames": 0, "boxes": 0, "false_positives": 0, "label_swaps": 0}
    for f in track(range(cfg.frames), description="frames"):
        bx = scene.boxes(P[f], Y[f], PP[f])
        vb, frac, full = visible_boxes(field_model, rig.camera, rig.T_field_cam, bx, list(range(len(bx) - R, len(bx))))
        last = int(np.searchsorted(t_arrive, t_img[f] + 1e-9, "right")) - 1
        hits = hits_per_cloud[last] if last >= 0 else np.zeros(R, int)
        dets, truth = _robot_boxes(cfg, rig.camera, labels, t_img[f : f + 1], P[f], vb, frac, full, hits, rng_det, counts)
        fps = _false_positive_boxes(field_model, rig, bx, R, cfg, rng_det)
        counts["false_positives"] += len(fps)
        people = [{"p_field": [_fmt(v) for v in PP[f, k]]} for k in range(cfg.people)]
        fname = f"{f:06d}.jpg"
        det_lines.append(json.dumps({"t": _fmt(t_img[f], 6), "frame": fname, "boxes": dets + fps}))
        truth_lines.append(json.dumps({"t": _fmt(t_img[f], 6), "frame": fname, "robots": truth, "people": people}))
    (out / "detections.jsonl").write_text("\n".join(det_lines) + "\n")
    (out / "truth.jsonl").write_text("\n".join(truth_lines) + "\n")
    return counts


def _robot_boxes(cfg: MatchConfig, cam, labels: list[str], t_f: np.ndarray, p_f: np.ndarray, vb: np.ndarray, frac: np.ndarray, full: np.ndarray, hits: np.ndarray,
                 rng_det, counts: dict) -> tuple[list, list]:  # fmt: skip
    """One frame's robot detections (jittered visible-part boxes; misses, swaps 3 <-> 4, camera-miss windows) and
    truth entries; adds to ``counts``. ``t_f``: the frame time as a 1-element array."""
    dets, truth = [], []
    for i, lab in enumerate(labels):
        if _in_windows(cfg.absent, lab, t_f)[0]:
            continue  # truly not on the field: no box, not in the truth
        visible = bool(np.isfinite(vb[i, 0]))
        counts["visible_robot_frames"] += visible
        cam_miss = bool(_in_windows(cfg.camera_miss, lab, t_f)[0])
        truth.append({"label": lab, "p_field": [_fmt(v) for v in p_f[i]], "visible": visible, "visible_fraction": _fmt(frac[i], 3),
                      "in_view": bool(np.isfinite(full[i, 0])), "lidar_hits": int(hits[i]),
                      "xyxy": None if not visible else [_fmt(v, 2) for v in vb[i]], **({"camera_miss": True} if cam_miss else {}),
                      **({"lidar_miss": True} if _in_windows(cfg.lidar_miss, lab, t_f)[0] else {})})  # fmt: skip
        if not visible or frac[i] < cfg.min_visible or rng_det.random() < cfg.miss:
            continue
        b = vb[i] + rng_det.normal(0, rng_det.uniform(*cfg.jitter_px), 4)
        b = np.array([min(b[0], b[2] - 2), min(b[1], b[3] - 2), max(b[2], b[0] + 2), max(b[3], b[1] + 2)])
        b = np.clip(b, -0.5, [cam.width - 0.5, cam.height - 0.5, cam.width - 0.5, cam.height - 0.5])
        out_lab = lab
        if lab.split("_")[1] in ("3", "4") and rng_det.random() < cfg.swap:
            out_lab = _swap_label(lab)
            counts["label_swaps"] += 1
        score = _fmt(rng_det.uniform(0.55, 0.98), 3)
        if cam_miss:  # dropped after its noise was drawn: the other boxes keep the noise of the replay without the window
            continue
        dets.append({"xyxy": [_fmt(v, 2) for v in b], "label": out_lab, "score": score})
        counts["boxes"] += 1
    return dets, truth


def _false_positive_boxes(field_model: FieldModel, rig, bx: SceneBoxes, R: int, cfg: MatchConfig, rng_det) -> list[dict]:
    """Poisson(``cfg.false_positives``) wrong boxes on one frame, labels drawn from every robot label: on a person
    at the boundary, or robot-sized somewhere on the field."""
    cam = rig.camera
    dets = []
    for _ in range(rng_det.poisson(cfg.false_positives)):
        lab = str(rng_det.choice(_ALL_LABELS))
        ppl_k = list(range(len(bx) - R - cfg.people, len(bx) - R))
        pb = None
        if ppl_k and rng_det.random() < 0.5:  # on a person at the boundary
            pv, _, _ = visible_boxes(field_model, cam, rig.T_field_cam, bx, [int(rng_det.choice(ppl_k))])
            if np.isfinite(pv[0, 0]):
                pb = pv[0] + rng_det.normal(0, 4, 4)
        if pb is None:  # somewhere on the field, robot-sized for that range
            xy = rng_det.uniform([1, 1], np.array(field_model.size) - 1)
            g = np.array([xy[0], xy[1], float(field_model.surface_z(xy[None])[0])])
            pb = image_box(cam, geometry.invert_T(rig.T_field_cam), g, np.array([0.5, 0.5, 0.45]), 0.0)
            if pb is None:
                continue
        if pb[2] - pb[0] < 3 or pb[3] - pb[1] < 3:
            continue
        dets.append({"xyxy": [_fmt(v, 2) for v in pb], "label": lab, "score": _fmt(rng_det.uniform(0.3, 0.75), 3)})
    return dets


def _write_still(out: Path, field_model: FieldModel, rig) -> None:
    """One still of the static scene in ``images/`` (the replay reader wants an image; the detections drive every frame)."""
    import cv2

    (out / "images").mkdir(exist_ok=True)
    still = cv2.resize(render_background(field_model, rig, 0.25)[0], rig.camera.image_size, interpolation=cv2.INTER_LINEAR)
    cv2.imwrite(str(out / "images" / "000000.jpg"), still, [cv2.IMWRITE_JPEG_QUALITY, 70])
    (out / "images" / "times.csv").write_text("file,t\n000000.jpg,0.000000\n")


def _write_match_bundle(path: Path, field_model: FieldModel, rig, cfg: MatchConfig, rng_cal, generator: str) -> tuple[dict, list[str]]:
    """The calibration a station would have: LiDAR-camera off by ``calib_rot_deg`` / ``calib_trans_m``, the field
    pose from four clicks (``field_picks.csv`` beside the bundle) stored by ``radarcal field-pnp``'s own
    ``calibrate(...).store(...)``. Returns the field pose's errors and the landmarks clicked."""
    from radarcal.bundle import Bundle, Provenance
    from radarcal.pnp.calibrate import FieldPnPOptions, calibrate
    from radarcal.pnp.picks import read_picks, write_picks

    T_cam_lidar_est = perturb_T(rig.T_cam_lidar, cfg.calib_rot_deg, cfg.calib_trans_m, rng_cal)
    picks = path.parent / "field_picks.csv"
    write_picks(picks, *four_point_clicks(field_model, rig, cfg.pnp_px, rng_cal))
    pnp_names, clicks = read_picks(picks, field_model.landmarks)  # what `radarcal field-pnp --points` reads
    bnd = Bundle()
    bnd.path = path
    prov = Provenance(command=generator)
    bnd.set_camera("cam0", rig.camera, rms_px=0.3, provenance=prov, extra={"synthetic": True})
    bnd.set_sensor("lidar0", type="lidar", model="Livox Mid-70 (simulated, per-point firing time)", fov_deg=70.4)
    bnd.set_transform("cam0", "lidar0", T_cam_lidar_est, method=f"synthetic truth perturbed {cfg.calib_rot_deg} deg / {cfg.calib_trans_m} m",
                      sigma={"rot_deg": cfg.calib_rot_deg, "trans_m": cfg.calib_trans_m}, provenance=prov)  # fmt: skip
    cal = calibrate(bnd, "cam0", field_model, field_model.name, pnp_names, clicks, picks, FieldPnPOptions(click_sigma=cfg.pnp_px))
    cal.store(bnd, path, generator)
    rot_deg, _ = geometry.pose_error(cal.result.T_field_cam, rig.T_field_cam)
    err = {"field_pose_rot_deg": rot_deg, "field_pose_cam_centre_m": float(np.linalg.norm(cal.result.camera_position - rig.T_field_cam[:3, 3]))}
    return err, pnp_names
