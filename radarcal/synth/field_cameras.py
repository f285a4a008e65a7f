"""Several cameras over one field scene (``radarcal synth field --cameras cam0=6mm,cam1=16mm``), issue #19.

The scene, robots and LiDAR are those of :mod:`radarcal.synth.field` (same public functions); what this adds:

* **Cameras**: each a pinhole of its focal length (``pixel_um`` pixels, 1280x1024 by default) at the radar station,
  0.2 m apart sideways, aimed at its own field point (the first camera like the single-camera rig, a tele at the far
  half by default). Each camera's clock is offset by ``offset_s`` (``k * 11 ms``): frames of different cameras never
  share a time stamp.
* **A detector that depends on pixels**, per camera: it boxes the visible part of a robot (ray cast,
  :func:`radarcal.synth.detections.visible_boxes`; none below 20 % visible); a box of height ``h`` px is missed with probability rising
  from 3 % at 16 px to 100 % at 6 px; its edges jitter by ``0.8 + 0.03 h`` px; its robot number is misread with
  probability ``0.01 + 0.45 clip((48 - h) / 30, 0, 1)`` — in spells (the state is redrawn on ~1 frame in 8), so a
  far robot is misread for a quarter of a second at a time, as a real classifier does, not independently per frame.
  The colour is always right. So a far robot in a 6 mm wide camera (20-30 px) is often misread and its ground ray is
  poor; the 16 mm tele sees it 2.7x larger.
* **A camera gap** (``gaps``): a camera delivers nothing between START and START + DURATION (unplugged).

Layout (``docs/synth.md``): ``cameras/<name>/images/`` (+ ``times.csv``), ``cameras/<name>/detections.jsonl``;
``clouds/``; ``truth.jsonl`` with one line per frame of every camera (frame ``<name>/<file>``, the robots at that
frame's time, ``visible`` = seen by any camera, ``visible_in`` = which); ``truth.json``; ``calib.yaml`` holding every
camera (intrinsics, ``T_<name>_lidar0``, ``T_field_<name>``); ``meta.json`` with ``cameras``.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from radarcal import geometry
from radarcal.camera import Camera
from radarcal.field import FieldModel
from radarcal.synth.detections import visible_boxes
from radarcal.synth.field import FieldSceneConfig, Rig, SceneBoxes, default_rig, make_robots, render_background, robot_states, scene_boxes, write_frame_jpeg, write_lidar_clouds, write_truth_bundle

__all__ = ["CameraSpec", "MultiCameraConfig", "parse_camera_specs", "camera_rigs", "detector_model", "write_multicam_replay"]

_SPEC = re.compile(r"^(?P<name>[A-Za-z][\w-]*)=(?P<f>\d+(\.\d+)?)mm(:(?P<w>\d+)x(?P<h>\d+))?(@(?P<x>-?\d+(\.\d+)?):(?P<y>-?\d+(\.\d+)?))?$")
_NUMBERS = (1, 2, 3, 4, 5, 7)
MIN_VISIBLE = 0.2  # visible fraction of the silhouette below which the detector has no box (as synth match)


@dataclass
class CameraSpec:
    name: str
    focal_mm: float
    size: tuple[int, int] = (1280, 1024)
    aim: tuple[float, float] | None = None  # field point (m, red-station frame) the optical axis meets; None: default
    pixel_um: float = 4.8


@dataclass
class MultiCameraConfig:
    scene: FieldSceneConfig
    cameras: list[CameraSpec]
    camera_offset_s: float = 0.011  # camera k's frame times are k * this later
    gaps: dict[str, tuple[float, float]] = field(default_factory=dict)  # camera -> (start s, duration s) unplugged


def parse_camera_specs(text: str) -> list[CameraSpec]:
    """``cam0=6mm,cam1=16mm:1280x1024@21:6`` -> specs (``NAME=FOCALmm[:WxH][@X:Y]``, aim point in field metres)."""
    out = []
    for part in [p.strip() for p in text.split(",") if p.strip()]:
        m = _SPEC.match(part)
        if m is None:
            raise ValueError(f"expected NAME=FOCALmm[:WxH][@X:Y], got {part!r}")
        size = (int(m["w"]), int(m["h"])) if m["w"] else (1280, 1024)
        aim = (float(m["x"]), float(m["y"])) if m["x"] is not None else None
        out.append(CameraSpec(m["name"], float(m["f"]), size, aim))
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise ValueError(f"camera names repeat: {', '.join(names)}")
    if not out:
        raise ValueError("no camera given")
    if any(not 1.0 <= c.focal_mm <= 100.0 or min(c.size) < 64 for c in out):
        raise ValueError("focal lengths 1..100 mm and sizes of at least 64 px")
    return out


def _look_at(pos: np.ndarray, target: np.ndarray) -> np.ndarray:
    """R_field_cam for a camera at ``pos`` whose optical axis passes through ``target``, no roll."""
    z = target - pos
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def camera_rigs(field_model: FieldModel, specs: list[CameraSpec], rng: np.random.Generator, station: str = "red") -> tuple[dict[str, Rig], np.ndarray]:
    """One :class:`Rig` per camera (all sharing the LiDAR of the single-camera rig) and ``T_field_lidar``.

    The first camera without an aim point keeps the single-camera rig's pose; the others sit 0.2 m further along
    the station (-y) and look at their aim point (default: the far half, (0.75 L, 0.42 W))."""
    L, W = field_model.size
    base = default_rig(field_model, rng, "red")
    T_field_lidar = base.T_field_lidar
    mirror = np.array([[-1.0, 0, 0, L], [0, -1.0, 0, W], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
    rigs = {}
    for k, s in enumerate(specs):
        w, h = s.size
        f = s.focal_mm / (s.pixel_um * 1e-3)
        wide = f < 2000
        dist = np.array([-0.08, 0.05, 0.0005, -0.0003, 0.0]) if wide else np.array([-0.01, 0.0, 0.0002, -0.0001, 0.0])
        cam = Camera((w, h), np.array([[f, 0.0, (w - 1) / 2 + 1.3], [0.0, f, (h - 1) / 2 - 2.3], [0.0, 0.0, 1.0]]), dist)
        if k == 0 and s.aim is None:
            T_field_cam = base.T_field_cam
        else:
            pos = base.T_field_cam[:3, 3] + np.array([0.0, -0.2 * k, 0.0])
            aim = np.array([*(s.aim if s.aim is not None else (0.75 * L, 0.42 * W)), 0.0])
            T_field_cam = geometry.make_T(_look_at(pos, aim), pos)
        rigs[s.name] = Rig(cam, T_field_cam, geometry.invert_T(T_field_cam) @ T_field_lidar)
    if station == "blue":
        T_field_lidar = mirror @ T_field_lidar
        rigs = {n: Rig(r.camera, mirror @ r.T_field_cam, r.T_cam_lidar) for n, r in rigs.items()}
    elif station != "red":
        raise ValueError(f"station: expected red or blue, got {station!r}")
    return rigs, T_field_lidar


def detector_model(h_px: np.ndarray | float) -> dict:
    """Per box height (px): miss probability, edge jitter sigma (px), number misread probability."""
    h = np.asarray(h_px, float)
    return {"miss": np.clip(0.03 + 0.97 * (16.0 - h) / 10.0, 0.03, 1.0), "jitter_px": 0.8 + 0.03 * h,
            "misread": 0.01 + 0.45 * np.clip((48.0 - h) / 30.0, 0.0, 1.0)}  # fmt: skip


def _fmt(x: float, nd: int = 4) -> float:
    return float(round(float(x), nd))


def write_multicam_replay(out_dir: str | Path, field_model: FieldModel, mc: MultiCameraConfig, generator: str = "radarcal synth field", progress: Callable | None = None) -> dict:
    """Generate the scene and write the multi-camera replay folder; returns a summary."""
    cfg = mc.scene
    out = Path(out_dir)
    ss = np.random.SeedSequence(cfg.seed)
    rng_rig, rng_rob, rng_lidar, rng_det = (np.random.default_rng(s) for s in ss.spawn(4))
    rigs, T_field_lidar = camera_rigs(field_model, mc.cameras, rng_rig, cfg.station)
    robots = make_robots(field_model, cfg.robots, rng_rob, cfg.speed, cfg.station)
    track = progress or (lambda it, **_: it)
    n = cfg.frames
    names = [s.name for s in mc.cameras]
    vis: dict[str, np.ndarray] = {}
    lines: dict[str, list] = {}
    n_images = n_boxes = 0
    for k, cname in enumerate(names):
        vis[cname], lines[cname], n_img, n_box = _write_camera(out / "cameras" / cname, field_model, rigs[cname], cname, robots, mc, k, rng_det, track)
        n_images += n_img
        n_boxes += n_box
    _write_truth_lines(out / "truth.jsonl", names, robots, lines, vis)
    n_clouds, n_points = write_lidar_clouds(out / "clouds", field_model, robots, T_field_lidar, cfg, rng_lidar, track)  # on the first camera's clock (as synth field)
    write_truth_bundle(out / "calib.yaml", field_model, rigs, generator, {s.name: {"focal_mm": s.focal_mm} for s in mc.cameras}, lidar_first=True)
    truth = {"seed": cfg.seed, "field": field_model.name, "cameras": {s.name: {**asdict(s), "camera": rigs[s.name].camera.to_dict(), "T_field_cam": rigs[s.name].T_field_cam.tolist(),
             "T_cam_lidar0": rigs[s.name].T_cam_lidar.tolist(), "frame_offset_s": k * mc.camera_offset_s} for k, s in enumerate(mc.cameras)},
             "T_field_lidar0": T_field_lidar.tolist(), "robots": [r.to_dict() for r in robots],
             "detector_model": "miss 0.03 + 0.97 (16 - h) / 10 clipped to [0.03, 1]; jitter 0.8 + 0.03 h px; number misread 0.01 + 0.45 clip((48 - h) / 30, 0, 1) in spells (redrawn 1 frame in 8)",
             "gaps": {k: list(v) for k, v in mc.gaps.items()}, "config": asdict(cfg), "field_model": field_model.to_dict()}  # fmt: skip
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    meta = {"camera": names[0], "cameras": names, "lidar": "lidar0", "station": cfg.station, "field": field_model.name, "fps": cfg.fps, "lidar_hz": cfg.lidar_hz,
            "n_frames": n, "seed": cfg.seed, "generator": generator}  # fmt: skip
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    return {"out": str(out), "frames": n, "cameras": names, "images": n_images, "clouds": n_clouds, "robots": len(robots), "visible_boxes": int(sum(v.sum() for v in vis.values())),
            "detections": n_boxes, "cloud_points": n_points, "landmarks_in_image": [], "bytes": size}  # fmt: skip


def _write_camera(folder: Path, field_model: FieldModel, rig: Rig, cname: str, robots: list, mc: MultiCameraConfig, k: int, rng_det, track):
    """Camera ``k``'s ``images/`` (+ ``times.csv``) and ``detections.jsonl`` under ``folder`` (nothing while it is
    unplugged). Returns the (frames, robots) visibility, (t, p_field, yaw) per frame, images and boxes written."""
    cfg = mc.scene
    n = cfg.frames
    (folder / "images").mkdir(parents=True, exist_ok=True)
    t_img = np.arange(n) / cfg.fps + k * mc.camera_offset_s
    gap = mc.gaps.get(cname)
    alive = np.ones(n, bool) if gap is None else ~((t_img >= gap[0]) & (t_img < gap[0] + gap[1]))
    p_all, yaw_all = robot_states(field_model, robots, t_img)
    background = render_background(field_model, rig, cfg.image_scale)
    ns = len(scene_boxes(field_model))
    misread = np.zeros(len(robots), bool)  # the state of each robot's number reading, in spells
    wrong = np.array([int(rng_det.choice([m for m in _NUMBERS if m != int(r.label.split("_")[1])])) for r in robots], int)
    v = np.zeros((n, len(robots)), bool)
    det_lines, img_times = [], []
    n_boxes = 0
    for f in track(range(n), description=f"{cname} frames"):
        boxes_f = scene_boxes(field_model, robots, p_all[f], yaw_all[f])
        fname = f"{f:06d}.jpg"
        dets = _detect_frame(field_model, rig, robots, boxes_f, ns, v[f], misread, wrong, bool(alive[f]), rng_det)
        if not alive[f]:
            continue  # unplugged: no image, no detections line
        n_boxes += len(dets)
        det_lines.append(json.dumps({"t": _fmt(t_img[f], 6), "frame": fname, "boxes": dets}))
        if f % max(1, cfg.image_every) == 0:
            write_frame_jpeg(folder / "images" / fname, field_model, rig, background, boxes_f, ns, cfg.image_scale, cfg.jpeg_quality)
            img_times.append((fname, t_img[f]))
    (folder / "detections.jsonl").write_text("\n".join(det_lines) + "\n")
    (folder / "images" / "times.csv").write_text("file,t\n" + "".join(f"{a},{b:.6f}\n" for a, b in img_times))
    return v, [(t_img[f], p_all[f], yaw_all[f]) for f in range(n)], len(img_times), n_boxes


def _detect_frame(field_model: FieldModel, rig: Rig, robots: list, boxes_f: SceneBoxes, n_static: int, visible: np.ndarray, misread: np.ndarray, wrong: np.ndarray,
                  alive: bool, rng_det) -> list[dict]:  # fmt: skip
    """The pixel-dependent detector on one frame (:func:`detector_model`): boxes of the visible parts, misses,
    jitter, number misreads in spells. Fills ``visible`` (per robot) and updates the spell state ``misread`` /
    ``wrong`` in place; the noise is drawn for every robot, also when the camera is unplugged (``alive`` False)."""
    cam = rig.camera
    dets = []
    vboxes, vfrac, _ = visible_boxes(field_model, cam, rig.T_field_cam, boxes_f, list(range(n_static, n_static + len(robots))))
    for j, r in enumerate(robots):
        bb = vboxes[j]  # the visible part: what a detector boxes
        visible[j] = vfrac[j] > 0
        h = float(bb[3] - bb[1]) if visible[j] else 0.0
        model = detector_model(h)
        if rng_det.random() < 1 / 8:  # a new spell of reading (or misreading) the number
            misread[j] = rng_det.random() < model["misread"]
            if misread[j]:
                wrong[j] = int(rng_det.choice([m for m in _NUMBERS if m != int(r.label.split("_")[1])]))
        jit = rng_det.normal(0, model["jitter_px"], 4)
        miss = rng_det.random() < model["miss"]
        if vfrac[j] < MIN_VISIBLE or miss or not alive:
            continue
        b = np.clip(bb + jit, [-0.5, -0.5, -0.5, -0.5], [cam.width - 0.5, cam.height - 0.5] * 2)
        if b[2] - b[0] < 1 or b[3] - b[1] < 1:
            continue
        label = f"{r.label.split('_')[0]}_{wrong[j]}" if misread[j] else r.label
        dets.append({"xyxy": [_fmt(x, 2) for x in b], "label": label, "score": _fmt(rng_det.uniform(0.6, 0.99), 3)})
    return dets


def _write_truth_lines(path: Path, names: list[str], robots: list, lines: dict, vis: dict) -> None:
    """``truth.jsonl``: one line per frame of every camera, in time order, with which cameras see each robot."""
    truth_lines = []
    for cname in names:
        for f, (t, p, yw) in enumerate(lines[cname]):
            rob = [{"id": r.label, "label": r.label, "p_field": [_fmt(x) for x in p[j]], "yaw": _fmt(yw[j]), "visible": bool(any(vis[c][f, j] for c in names)),
                    "visible_in": [c for c in names if vis[c][f, j]]} for j, r in enumerate(robots)]  # fmt: skip
            truth_lines.append((t, json.dumps({"t": _fmt(t, 6), "frame": f"{cname}/{f:06d}.jpg", "robots": rob})))
    truth_lines.sort(key=lambda x: x[0])
    path.write_text("\n".join(s for _, s in truth_lines) + "\n")
