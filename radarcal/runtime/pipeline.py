"""The per-frame core of ``radarcal run`` (arrays in, :class:`FrameResult` out, no I/O).

Two ways to localise, chosen by ``RunConfig.localise`` (``--localise``):

* ``box``: the 2021-2022 way (NUAA report) — a box, then the depth of the LiDAR points inside it
  (:mod:`radarcal.runtime.fusion`), else the ground ray (:mod:`radarcal.runtime.localise`), one Kalman track per label
  (:class:`radarcal.runtime.tracks.TrackManager`).
* ``lidar`` / ``auto`` (default): robots found in the cloud and tracked in 3D, identities from the boxes
  (:mod:`radarcal.runtime.lidar_first`); ``auto`` adds box-only fixes (box depth, then ground ray) for boxes that no
  LiDAR track explains. Without a camera (no detections) it is LiDAR only: every track unlabelled.

Outputs mark what is a prediction: ``source`` is ``lidar`` / ``depth`` / ``ground`` when this frame has evidence,
``predicted`` when not (and ``"predicted": true``); unlabelled tracks carry ``"label": null``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from radarcal.bundle import Bundle
from radarcal.runtime import referee as rp
from radarcal.runtime.background import range_sigma
from radarcal.runtime.config import LOCALISE_MODES, RunConfig
from radarcal.runtime.detector import Detection
from radarcal.runtime.fusion import CloudQueue, SurfaceFilter
from radarcal.runtime.identity import intersection_areas
from radarcal.runtime.localise import Localiser
from radarcal.runtime.tracks import TrackManager

__all__ = ["RunConfig", "RobotOut", "FrameResult", "Pipeline", "CameraView", "LOCALISE_MODES", "fuse_by_label"]


@dataclass
class CameraView:
    """One camera of the station: its projection, field pose, localiser and depth images (cloud queue)."""

    name: str
    camera: object  # radarcal.Camera
    T_field_cam: np.ndarray
    localiser: Localiser
    queue: CloudQueue | None
    pad_px: float
    primary: bool

    @property
    def T_cam_field(self) -> np.ndarray:
        from radarcal.geometry import invert_T

        return invert_T(self.T_field_cam)

@dataclass
class RobotOut:
    label: str | None  # None: a LiDAR track no box has named (yet)
    p_field: np.ndarray  # (3,) filtered position
    source: str  # lidar | depth | ground | predicted (no measurement this frame)
    sigma: float
    depth: float | None
    score: float | None
    raw: np.ndarray | None  # (3,) this frame's unfiltered measurement
    track_id: int | None = None
    state: str | None = None  # tentative | confirmed | lost (LiDAR-first tracks)
    velocity: np.ndarray | None = None
    t_seen: float | None = None
    votes: dict = field(default_factory=dict)
    dead: bool = False  # its armour was grey when last seen: tracked, never sent as a target

    @property
    def predicted(self) -> bool:
        return self.source == "predicted"

    @property
    def key(self) -> str:
        """Label, or ``#<track id>`` for an unlabelled track (minimap trails, status)."""
        return self.label if self.label is not None else f"#{self.track_id}"

    def to_dict(self) -> dict:
        d = {"label": self.label, "x": round(float(self.p_field[0]), 3), "y": round(float(self.p_field[1]), 3), "z": round(float(self.p_field[2]), 3),
             "source": self.source, "predicted": self.predicted, "sigma": round(self.sigma, 3) if np.isfinite(self.sigma) else None,
             "depth": None if self.depth is None else round(self.depth, 3)}  # fmt: skip
        if self.track_id is not None:
            d["id"] = self.track_id
            d["state"] = self.state
            if self.velocity is not None:
                d["v"] = [round(float(v), 3) for v in self.velocity]
            if self.t_seen is not None and np.isfinite(self.t_seen):
                d["t_seen"] = round(float(self.t_seen), 4)
            if self.votes:
                d["votes"] = {k: round(float(v), 2) for k, v in sorted(self.votes.items(), key=lambda kv: -kv[1])[:3]}
        if self.raw is not None:
            d["raw"] = [round(float(v), 3) for v in self.raw]
        if self.score is not None:
            d["score"] = round(self.score, 3)
        if self.dead:
            d["dead"] = True
        return d


@dataclass
class FrameResult:
    t: float
    frame: str
    robots: list[RobotOut]
    sentry: dict | None
    hero_range_m: float | None
    timings_ms: dict[str, float]
    cameras: dict[str, str] | None = None  # several cameras: camera -> frame name used in this result
    missing: list[str] | None = None  # several cameras: those that delivered nothing lately

    def to_dict(self) -> dict:
        d = {"t": round(self.t, 4), "frame": self.frame, "robots": [r.to_dict() for r in self.robots], "sentry": self.sentry,
             "hero_range_m": None if self.hero_range_m is None else round(self.hero_range_m, 3),
             "latency_ms": {k: round(v, 3) for k, v in self.timings_ms.items()}}  # fmt: skip
        if self.cameras is not None:
            d["cameras"] = self.cameras
            d["missing_cameras"] = self.missing or []
        return d


def _team_of(label: str | None) -> str | None:
    return label.split("_", 1)[0] if label and label.startswith(("red_", "blue_")) else None


def _number_of(label: str | None) -> int | None:
    if not label:
        return None
    tail = label.split("_", 1)[-1]
    return int(tail) if tail.isdigit() else None


_ASK = object()  # :meth:`Pipeline._depth_order`: this box's depth is not known yet


def boxes_in_front(boxes: np.ndarray, frame_boxes: np.ndarray) -> np.ndarray:
    """(K, M) bool: box m of the camera frame (pixels xyxy) overlaps box k and its bottom edge is lower (> 2 px) in
    the image — a robot standing nearer, whose pixels hide part of box k."""
    b, f = np.asarray(boxes, float).reshape(-1, 4), np.asarray(frame_boxes, float).reshape(-1, 4)
    return (f[None, :, 3] > b[:, None, 3] + 2) & (intersection_areas(b, f) > 0)


def _overlapping_others(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(A, B) bool: box b[j] overlaps box a[i] and is not the same box (pixel boxes xyxy)."""
    return (intersection_areas(a, b) > 0) & ~np.all(a[:, None] == b[None], axis=2)


def no_ground_ray(boxes: np.ndarray, frame_boxes: np.ndarray, min_aspect: float) -> np.ndarray:
    """(K,) bool: boxes whose bottom edge is not the robot's foot point, so a ground ray from it lands elsewhere:
    much wider than high (``height < min_aspect * width``: the top of a robot hidden below), or with the bottom
    centre inside the box of a robot in front (the edge is that robot's outline: family A seed 5, the tele's box of
    blue_2 behind blue_1 put it 4.4 m short, on red_1)."""
    b = np.asarray(boxes, float).reshape(-1, 4)
    flat = (b[:, 3] - b[:, 1]) < min_aspect * (b[:, 2] - b[:, 0])
    f = np.asarray(frame_boxes, float).reshape(-1, 4)
    cx = 0.5 * (b[:, 0] + b[:, 2])
    foot = boxes_in_front(b, f) & (f[None, :, 0] <= cx[:, None]) & (cx[:, None] <= f[None, :, 2])
    return flat | foot.any(axis=1)


def foot_beyond(localiser: Localiser, boxes: np.ndarray, frame_boxes: np.ndarray, p_field: np.ndarray, min_aspect: float, ground: np.ndarray | None = None) -> np.ndarray:
    """(K,) how far (m, horizontally along the view) beyond its located centre ``p_field`` (K,3) the bottom edge of
    each box puts its robot: the range of the bottom centre's ground ray (``Localiser.from_ground``, on the field's
    surface, so a robot on a highland far behind is not taken for one in front) minus the located range; inf where the
    edge is not the robot's foot (:func:`no_ground_ray`: a robot in front hides it, or a hidden robot's top) or the
    ray meets no surface. A box-depth fix taken from a robot standing in front lies well short of it. ``ground``:
    the boxes' ground-ray centres when already cast (:meth:`Localiser.box_rays`)."""
    b = np.asarray(boxes, float).reshape(-1, 4)
    g = localiser.from_ground(np.column_stack([0.5 * (b[:, 0] + b[:, 2]), b[:, 3]])) if ground is None else ground
    o = localiser.cam_origin[:2]
    beyond = np.linalg.norm(g[:, :2] - o, axis=1) - np.linalg.norm(np.asarray(p_field, float).reshape(-1, 3)[:, :2] - o, axis=1)
    return np.where(np.isfinite(beyond) & ~no_ground_ray(b, frame_boxes, min_aspect), beyond, np.inf)


class Pipeline:
    """Per-frame core: clouds in, detections in, located + tracked robots out."""

    def __init__(self, bundle: Bundle, camera: str | list[str], lidar: str | None, cfg: RunConfig):
        """``camera``: one name, or several (the first is the primary: its attributes below; :attr:`views` holds all)."""
        cameras = [camera] if isinstance(camera, str) else list(camera)
        camera = cameras[0]
        self.cfg = cfg
        self.camera = bundle.camera(camera)
        self.T_field_cam = bundle.T("field", camera)
        self.field_model = bundle.field()
        self.queue = None
        T_cam_lidar = bundle.T(camera, lidar) if lidar is not None else None  # solved once
        sig = bundle.transforms.get(f"T_{camera}_{lidar}") if lidar is not None else None
        sig = sig.sigma if sig is not None else {}
        # the calibration's sigma, floored (a bundle may claim less than a match-day rig holds)
        sigma_rot_deg, sigma_trans_m = max(float(sig.get("rot_deg", 0.25)), 0.1), max(float(sig.get("trans_m", 0.03)), 0.01)
        if lidar is not None:
            flt = None
            if cfg.surface_filter:
                surf = self.field_model.surface_z if self.field_model is not None else None
                structs = getattr(self.field_model, "structures", None) if self.field_model is not None else None
                k, s_rot = cfg.surface_raised_k_sigma, np.deg2rad(sigma_rot_deg)
                flt = SurfaceFilter(self.T_field_cam @ T_cam_lidar, surf, min_height=cfg.surface_min_height_m, structures=structs,
                                    raised_tol_of_range=(lambda r: k * range_sigma(r, s_rot, sigma_trans_m)) if k > 0 else None)
            self.queue = CloudQueue(self.camera, T_cam_lidar, cfg.cloud_queue_points, cfg.cloud_queue_age_s, point_filter=flt)
        self.localiser = Localiser(self.camera, self.T_field_cam, self.field_model, cfg.robot_radius_m, cfg.visible_depth_factor)
        self.tracks = TrackManager(accel_sigma=cfg.accel_sigma, max_coast_s=cfg.max_coast_s)
        self.clouds_in = 0
        self.dead: dict[str, bool] = {}  # label -> its armour was grey when last detected
        if cfg.localise not in LOCALISE_MODES:
            raise ValueError(f"localise: expected one of {', '.join(LOCALISE_MODES)}, got {cfg.localise!r}")
        self.drift = None  # LiDAR drift monitor (--drift-check-s): re-registers the static points in a worker thread
        if lidar is not None and cfg.drift_check_s > 0 and self.field_model is not None:
            from radarcal.runtime.drift import DriftConfig, DriftMonitor

            self.drift = DriftMonitor(self.field_model, self.T_field_cam @ T_cam_lidar, DriftConfig(check_every_s=cfg.drift_check_s, window_s=min(cfg.drift_check_s, 2.0)), lidar)
        self.lidar_first = None
        if lidar is not None and cfg.localise != "box":
            from radarcal.runtime.lidar_first import LidarFirst, LidarFirstConfig

            lidar_only = cfg.localise == "lidar"  # no box fixes: only clusters measure the tracks
            lf_cfg = LidarFirstConfig(window_sweeps=cfg.window_sweeps, sweep_s=cfg.cloud_sweep_s, latency_s=cfg.cloud_latency_s, learn_background=cfg.learn_background,
                                      box_shadow=cfg.box_shadow, lidar_only=lidar_only, sigma_rot_deg=sigma_rot_deg, sigma_trans_m=sigma_trans_m)  # fmt: skip
            from radarcal.runtime.clusters import ClusterParams

            # the aerial robot's sparse returns only without box fixes: in auto its box-depth fix is the better one
            # (measured, docs/runtime.md: the sparse centre is up to 0.4 m off across the view); two returns make a
            # sparse component LiDAR only (with box fixes auto lost: seed 2 right 90.2 -> 89.2 %, sample replay p95)
            params = ClusterParams(sparse_aerial=lidar_only, min_points_sparse=2 if lidar_only else 3)
            self.lidar_first = LidarFirst(self.T_field_cam @ T_cam_lidar, self.field_model, lf_cfg, params, camera=self.camera, T_field_cam=self.T_field_cam)
            if cfg.localise == "lidar":
                self.queue = None  # no box path
        self.views: dict[str, CameraView] = {camera: CameraView(camera, self.camera, self.T_field_cam, self.localiser, self.queue,
                                                                 self.lidar_first.pad_px if self.lidar_first is not None else 0.0, True)}  # fmt: skip
        for name in cameras[1:]:
            self.views[name] = self._view(bundle, name, lidar)

    def _view(self, bundle: Bundle, name: str, lidar: str | None) -> "CameraView":
        """Another camera: its own projection, field pose, localiser and depth images of the same clouds."""
        cam, T_field_cam = bundle.camera(name), bundle.T("field", name)
        queue = None
        if self.queue is not None:
            T_cam_lidar = bundle.T(name, lidar)
            # the surface filter works in the LiDAR frame (T_field_lidar): one for every camera
            queue = CloudQueue(cam, T_cam_lidar, self.cfg.cloud_queue_points, self.cfg.cloud_queue_age_s, point_filter=self.queue.point_filter)
        loc = Localiser(cam, T_field_cam, self.field_model, self.cfg.robot_radius_m, self.cfg.visible_depth_factor)
        pad = 3.0 + cam.fx * np.deg2rad(self.lidar_first.cfg.sigma_rot_deg) if self.lidar_first is not None else 0.0
        return CameraView(name, cam, T_field_cam, loc, queue, pad, False)

    def add_cloud(self, t: float, points: np.ndarray) -> None:
        """One cloud (LiDAR frame, points in firing order) with its time on the camera clock (arrival)."""
        if not len(points):
            return
        for v in self.views.values():
            if v.queue is not None:
                v.queue.push(t, points)
        if self.lidar_first is not None:
            self.lidar_first.add_cloud(t, points)
        if self.drift is not None:
            self.drift.add_cloud(t, points)
        if self.queue is not None or self.lidar_first is not None:
            self.clouds_in += 1

    @staticmethod
    def _valid(d: Detection, min_score: float) -> bool:
        b = np.asarray(d.xyxy, float)
        return b.shape == (4,) and bool(np.all(np.isfinite(b))) and b[2] > b[0] and b[3] > b[1] and bool(np.isfinite(d.score)) and d.score >= min_score

    def _box_depths(self, boxes: np.ndarray, t: float, queue: CloudQueue | None = None, frame_boxes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """LiDAR depth (camera z) and its sigma for each box from the cloud queue (NaN: none); robots standing nearer
        (box bottom lower in the image) and overlapping a box hide part of it: their pixels are not this robot's.
        ``frame_boxes``: every box of the camera frame (default ``boxes``) — a robot in front hides pixels whether or
        not its own box is located here (one a LiDAR track explains is not)."""
        depth = np.full(len(boxes), np.nan)
        dsig = np.full(len(boxes), np.nan)
        queue = self.queue if queue is None else queue
        if queue is None:
            return depth, dsig
        queue.expire(t)
        boxes = np.asarray(boxes, float).reshape(-1, 4)
        fb = boxes if frame_boxes is None else np.asarray(frame_boxes, float).reshape(-1, 4)
        fronts, answered = self._depth_order(boxes, fb, t, queue)
        bds = list(answered)
        todo = [k for k, bd in enumerate(answered) if bd is _ASK]
        if todo:
            got = queue.depths_in_boxes(boxes[todo], t, max_age_s=self.cfg.depth_max_age_s, excludes=[fb[fronts[k]] if fronts[k].any() else None for k in todo])
            for k, bd in zip(todo, got):
                bds[k] = bd
        for i, bd in enumerate(bds):
            if bd is not None:
                depth[i], dsig[i] = bd.depth, bd.sigma
        return depth, dsig

    def _depth_order(self, boxes: np.ndarray, frame_boxes: np.ndarray, t: float, queue: CloudQueue) -> tuple[np.ndarray, list]:
        """(K, M) bool: frame box m hides part of box k (:func:`boxes_in_front`), ordered by the LiDAR where it can:
        two overlapping boxes whose own pixels (the overlap excluded) are more than ``max(0.35 m, 3 %)`` apart in
        depth are in that order, whatever their bottom edges say — a nearer robot whose bottom a terrain edge
        hides has its box bottom higher than the robot behind it (both cameras of family A / B: most of the box
        depths over 0.4 m short beyond 15 m). A box without 3 returns of its own keeps the bottom-edge order.

        Also (K,) the box depth (:meth:`CloudQueue.depths_in_boxes`, ``None``: no depth) of each box whose pixels
        hidden by the boxes in front are already known from the same query — all of its box (nothing in front), or
        its own pixels (every box it overlaps is in front) — and :data:`_ASK` for the others: one query answers most
        frames."""
        b = np.asarray(boxes, float).reshape(-1, 4)
        f = np.asarray(frame_boxes, float).reshape(-1, 4)
        front = boxes_in_front(b, f)
        overlap = _overlapping_others(b, f)
        if not overlap.any():
            return front, [_ASK] * len(b)
        # own depths once per frame box (the boxes located are frame boxes too: looked up, not computed twice), and
        # in the same query every located box whole
        ff_overlap = _overlapping_others(f, f)
        same = np.all(b[:, None] == f[None], axis=2)
        need = np.flatnonzero(overlap.any(axis=0) | (same & overlap.any(axis=1)[:, None]).any(axis=0))
        has_same = same.any(axis=1)
        alone = np.flatnonzero(~has_same & overlap.any(axis=1))  # located boxes that are not frame boxes
        others = [f[ff_overlap[m]] for m in need] + [f[overlap[k]] for k in alone]
        bds = queue.depths_in_boxes(np.vstack([f[need], b[alone], b]), t, max_age_s=self.cfg.depth_max_age_s,
                                    excludes=[o if len(o) else None for o in others] + [None] * len(b))  # fmt: skip
        n_own = len(need) + len(alone)
        twin = np.argmax(same, axis=1)
        own_row = dict(zip(need.tolist(), range(len(need))))  # frame box -> its row of the query
        # one or two returns of its own: maybe the background, so no order from them
        own_depth = np.array([bd.depth if bd is not None and bd.n >= 3 else np.nan for bd in bds[:n_own]])
        own_f = np.full(len(f), np.nan)
        own_f[need] = own_depth[: len(need)]
        own_b = np.full(len(b), np.nan)
        own_b[has_same] = own_f[twin[has_same]]
        own_b[alone] = own_depth[len(need) :]
        own_b[~overlap.any(axis=1)] = np.nan
        gap = np.maximum(0.35, 0.03 * own_b[:, None])
        known = np.isfinite(own_b)[:, None] & np.isfinite(own_f)[None, :]
        fronts = overlap & np.where(known, own_f[None, :] < own_b[:, None] - gap, front) | (front & known & (np.abs(own_f[None, :] - own_b[:, None]) <= gap))
        answered: list = [_ASK] * len(b)
        alone_row = dict(zip(alone.tolist(), range(len(need), n_own)))
        for k in range(len(b)):
            if not fronts[k].any():
                answered[k] = bds[n_own + k]
            elif np.array_equal(fronts[k], overlap[k]):  # its own pixels (a box that overlaps: a frame box in need, or alone)
                answered[k] = bds[own_row[int(twin[k])] if has_same[k] else alone_row[k]]
        return fronts, answered

    def process(self, t: float, frame: str, detections, timings: dict[str, float] | None = None, team: str | None = None) -> FrameResult:
        """``detections``: a list (the primary camera) or :class:`radarcal.runtime.multicam.ViewDetections` (several)."""
        views = getattr(detections, "views", None)
        for d in (detections if views is None else [d for v in views for d in v[3]]):
            if d.label:
                self.dead[d.label] = bool(getattr(d, "dead", False))
        if views is not None:
            res = self._process_views(t, frame, detections, timings, team)
        else:
            res = (self._process_lidar_first if self.lidar_first is not None else self._process_box)(t, frame, detections, timings, team)
        if any(self.dead.values()):
            for r in res.robots:
                r.dead = bool(r.label and self.dead.get(r.label, False))
            team = team or self.cfg.team
            res.sentry = self.sentry_guidance(res.robots, team)  # a dead robot is never the sentry's target
        return res

    def _process_lidar_first(self, t: float, frame: str, detections: list[Detection], timings: dict[str, float] | None, team: str | None) -> FrameResult:
        timings = dict(timings or {})
        tic = time.perf_counter()
        boxes, labels, scores = self._view_boxes(detections)
        fixes: dict[int, tuple] = {}
        locate_boxes = self._locator(next(iter(self.views.values())), t, boxes, fixes) if self.cfg.localise == "auto" else None
        live = self.lidar_first.frame(t, boxes, labels, scores, locate_boxes)
        toc = time.perf_counter()
        timings["depth"] = 0.0
        timings["localise"] = (toc - tic) * 1e3
        robots = []
        zs = self.localiser.surface_z(np.array([tr.x[:2] for tr in live]).reshape(-1, 2)) if live else []
        for tr, zsurf in zip(live, zs):
            src = self.lidar_first.seen_source(tr, t)
            j = tr.last_box
            z = tr.z if tr.aerial else float(zsurf)
            fx = fixes.get(j) if j is not None else None
            robots.append(RobotOut(tr.label, np.array([tr.x[0], tr.x[1], z]), src, tr.sigma, fx[1] if fx else None, float(scores[j]) if j is not None else None,
                                   fx[0] if fx is not None and src != "predicted" else None, tr.id, tr.state, tr.x[2:].copy(), tr.t_seen, dict(tr.votes)))  # fmt: skip
        robots.sort(key=lambda r: (r.label is None, r.label or "", r.track_id or 0))
        timings["track"] = (time.perf_counter() - toc) * 1e3
        team = team or self.cfg.team
        return FrameResult(t, frame, robots, self.sentry_guidance(robots, team), self.hero_range(robots, team), timings)

    def _process_box(self, t: float, frame: str, detections: list[Detection], timings: dict[str, float] | None = None, team: str | None = None) -> FrameResult:
        timings = dict(timings or {})
        tic = time.perf_counter()
        best: dict[str, Detection] = {}
        for d in detections:
            b = np.asarray(d.xyxy, float)
            if b.shape != (4,) or not np.all(np.isfinite(b)) or b[2] <= b[0] or b[3] <= b[1] or not np.isfinite(d.score):
                continue  # a malformed box is dropped, never fatal
            if d.score >= self.cfg.min_score and (d.label not in best or d.score > best[d.label].score):
                best[d.label] = d
        dets = list(best.values())
        boxes = np.array([d.xyxy for d in dets], float).reshape(-1, 4)
        depth, dsig = self._box_depths(boxes, t)
        toc = time.perf_counter()
        timings["depth"] = (toc - tic) * 1e3
        loc = self.localiser.locate(boxes, depth, dsig)
        tic = time.perf_counter()
        timings["localise"] = (tic - toc) * 1e3
        meas = [(d.label, loc.p_field[i, :2], loc.sigma[i], str(loc.source[i])) for i, d in enumerate(dets) if loc.source[i] != "none"]
        live = self.tracks.update(t, meas)
        seen = {d.label: i for i, d in enumerate(dets)}
        robots = []
        live = sorted(live, key=lambda tr: tr.label)
        zs = self.localiser.surface_z(np.array([tr.xy for tr in live]).reshape(-1, 2)) if live else []
        for tr, z in zip(live, zs):
            i = seen.get(tr.label)
            measured = i is not None and loc.source[i] != "none" and tr.t_update == t
            xy = tr.xy
            robots.append(RobotOut(tr.label, np.array([xy[0], xy[1], float(z)]), tr.source if measured else "predicted", tr.sigma,
                                   float(depth[i]) if measured and np.isfinite(depth[i]) else None,
                                   dets[i].score if i is not None else None, loc.p_field[i] if measured else None))  # fmt: skip
        toc = time.perf_counter()
        timings["track"] = (toc - tic) * 1e3
        team = team or self.cfg.team
        return FrameResult(t, frame, robots, self.sentry_guidance(robots, team), self.hero_range(robots, team), timings)

    def _locator(self, view: CameraView, t: float, boxes: np.ndarray, fixes: dict):
        """``locate_boxes(indices)`` of one camera frame (box depth from its depth images, else the ground ray)."""

        def locate_boxes(idx: list[int]):
            b = boxes[idx]
            depth, dsig = self._box_depths(b, t, view.queue, boxes)
            foot = view.localiser.box_rays(b)  # the rays cast once for the box depth, the ground ray and foot_beyond
            loc = view.localiser.locate(b, depth, dsig, foot)
            loc.source[no_ground_ray(b, boxes, self.cfg.ground_min_aspect) & (loc.source == "ground")] = "none"
            for n, j in enumerate(idx):
                fixes[j] = (loc.p_field[n], float(depth[n]) if np.isfinite(depth[n]) else None)
            return loc.p_field, loc.sigma, loc.source, foot_beyond(view.localiser, b, boxes, loc.p_field, self.cfg.ground_min_aspect, loc.ground)

        return locate_boxes

    def _view_boxes(self, dets: list) -> tuple[np.ndarray, list, np.ndarray]:
        dets = [d for d in dets if self._valid(d, self.cfg.min_score)]
        return np.array([d.xyxy for d in dets], float).reshape(-1, 4), [d.label for d in dets], np.array([d.score for d in dets], float)

    def _process_views(self, t: float, frame: str, vd, timings: dict[str, float] | None, team: str | None) -> FrameResult:
        """Several cameras (issue #19): every camera frame of the tick at its own time, one output per robot."""
        timings = dict(timings or {})
        tic = time.perf_counter()
        per_view = []
        for cam, tv, _name, dets in vd.views:
            if cam not in self.views:
                raise ValueError(f"detections of camera {cam!r}, which this pipeline does not have ({', '.join(self.views)})")
            boxes, labels, scores = self._view_boxes(dets)
            per_view.append((self.views[cam], tv, boxes, labels, scores, {}))
        cams = {cam: name for cam, _tv, name, _d in vd.views}
        if self.lidar_first is None:
            robots = self._views_box(t, per_view)
        else:
            auto = self.cfg.localise == "auto"
            args = [(v, tv, b, lab, sc, self._locator(v, tv, b, fx) if auto else None) for v, tv, b, lab, sc, fx in per_view]
            live = self.lidar_first.frame_views(t, args or [(None, t, np.zeros((0, 4)), [], np.zeros(0), None)])
            robots = []
            zs = self.localiser.surface_z(np.array([tr.x[:2] for tr in live]).reshape(-1, 2)) if live else []
            for tr, zsurf in zip(live, zs):
                src = self.lidar_first.seen_source(tr, t)
                kj = self.lidar_first.last_boxes.get(tr.id)
                fx = per_view[kj[0]][5].get(kj[1]) if kj is not None else None
                score = float(per_view[kj[0]][4][kj[1]]) if kj is not None else None
                z = tr.z if tr.aerial else float(zsurf)
                robots.append(RobotOut(tr.label, np.array([tr.x[0], tr.x[1], z]), src, tr.sigma, fx[1] if fx else None, score,
                                       fx[0] if fx is not None and src != "predicted" else None, tr.id, tr.state, tr.x[2:].copy(), tr.t_seen, dict(tr.votes)))  # fmt: skip
            robots.sort(key=lambda r: (r.label is None, r.label or "", r.track_id or 0))
        toc = time.perf_counter()
        timings["depth"] = 0.0
        timings["localise"] = (toc - tic) * 1e3
        timings["track"] = 0.0
        team = team or self.cfg.team
        return FrameResult(t, frame, robots, self.sentry_guidance(robots, team), self.hero_range(robots, team), timings, cams, list(vd.missing))

    def _views_box(self, t: float, per_view: list) -> list[RobotOut]:
        """``--localise box`` with several cameras: per camera the best box per label, located; the same label
        from several cameras fused (:func:`fuse_by_label`); one Kalman track per label."""
        meas = []
        for v, tv, boxes, labels, scores, _fx in per_view:
            best: dict[str, int] = {}
            for i, lab in enumerate(labels):
                if lab not in best or scores[i] > scores[best[lab]]:
                    best[lab] = i
            idx = list(best.values())
            b = boxes[idx]
            depth, dsig = self._box_depths(b, tv, v.queue)
            loc = v.localiser.locate(b, depth, dsig)
            meas += [(labels[i], loc.p_field[n, :2], float(loc.sigma[n]), str(loc.source[n]), float(scores[i]), float(depth[n])) for n, i in enumerate(idx) if loc.source[n] != "none"]
        fused = fuse_by_label(meas)
        live = sorted(self.tracks.update(t, [(lab, xy, sg, src) for lab, xy, sg, src, _s, _d in fused]), key=lambda tr: tr.label)
        seen = {m[0]: m for m in fused}
        zs = self.localiser.surface_z(np.array([tr.xy for tr in live]).reshape(-1, 2)) if live else []
        robots = []
        for tr, z in zip(live, zs):
            m = seen.get(tr.label)
            measured = m is not None and tr.t_update == t
            robots.append(RobotOut(tr.label, np.array([tr.xy[0], tr.xy[1], float(z)]), tr.source if measured else "predicted", tr.sigma,
                                   m[5] if measured and np.isfinite(m[5]) else None, m[4] if m is not None else None,
                                   np.r_[m[1], float(z)] if measured else None))  # fmt: skip
        return robots

    # --- match functions ---------------------------------------------------------------------------------------------
    def sentry_guidance(self, robots: list[RobotOut], team: str) -> dict | None:
        """Nearest enemy to our sentry as a relative field vector (NUAA 2022: enemy - sentry, sent to the sentry)."""
        sentry = next((r for r in robots if r.label == f"{team}_7"), None)
        s_xy = sentry.p_field[:2] if sentry is not None else (np.asarray(self.cfg.sentry_xy, float) if self.cfg.sentry_xy else None)
        if s_xy is None:
            return None
        enemies = [r for r in robots if _team_of(r.label) not in (None, team) and not r.dead]
        if not enemies:
            return {"target": None, "sentry": [round(float(v), 3) for v in s_xy], "from": "track" if sentry is not None else "config"}
        d = np.array([r.p_field[:2] - s_xy for r in enemies])
        k = int(np.argmin(np.linalg.norm(d, axis=1)))
        return {"target": enemies[k].label, "dx": round(float(d[k, 0]), 3), "dy": round(float(d[k, 1]), 3), "distance": round(float(np.linalg.norm(d[k])), 3),
                "sentry": [round(float(v), 3) for v in s_xy], "from": "track" if sentry is not None else "config"}  # fmt: skip

    def hero_range(self, robots: list[RobotOut], team: str) -> float | None:
        """Horizontal distance from our hero to the enemy outpost + the per-match offset from the bundle."""
        if self.field_model is None:
            return None
        enemy = "blue" if team == "red" else "red"
        outpost = self.field_model.landmarks.get(f"{enemy}_outpost")
        hero = next((r for r in robots if r.label == f"{team}_1"), None)
        if outpost is None or hero is None:
            return None
        return float(np.linalg.norm(hero.p_field[:2] - outpost[:2]) + self.cfg.hero_range_offset_m)

    def referee_messages(self, res: FrameResult, team: str) -> list[tuple[int, bytes, int]]:
        """(cmd_id, data, mailbox key) to send for a frame: minimap 0x0305, sentry guidance, hero range."""
        enemy_team = "blue" if team == "red" else "red"
        live = [r for r in res.robots if not r.dead]  # a dead robot (grey armour) is tracked but never sent
        enemy = {n: tuple(r.p_field[:2]) for r in live if _team_of(r.label) == enemy_team and (n := _number_of(r.label))}
        ally = {n: tuple(r.p_field[:2]) for r in live if _team_of(r.label) == team and (n := _number_of(r.label))}
        out = []
        for i, payload in enumerate(rp.map_payload(self.cfg.season, enemy, ally, enemy_team)):
            out.append((rp.CMD_MAP, payload, i))
        radar = rp.robot_id(team, 9)
        if res.sentry is not None:
            tgt = res.sentry.get("target")
            content = rp.sentry_guidance_content(_number_of(tgt) or 0 if tgt else 0, res.sentry.get("dx", np.nan), res.sentry.get("dy", np.nan), res.sentry.get("distance", np.nan))
            out.append((rp.CMD_INTERACTION, rp.interaction_payload(self.cfg.sentry_cmd_id, radar, rp.robot_id(team, 7), content), self.cfg.sentry_cmd_id))
        if res.hero_range_m is not None:
            content = rp.hero_range_content(res.hero_range_m)
            out.append((rp.CMD_INTERACTION, rp.interaction_payload(self.cfg.hero_cmd_id, radar, rp.robot_id(team, 1), content), self.cfg.hero_cmd_id))
        return out




def fuse_by_label(meas: list[tuple], gate_m: float = 0.5) -> list[tuple]:
    """Box-path measurements of several cameras ``(label, xy (2,), sigma, source, score, depth)`` -> one per label:
    the inverse-variance weighted mean of those within ``gate_m + 3 sigma`` of the most precise one (the others,
    another robot under a wrong label, are dropped)."""
    by: dict[str, list[tuple]] = {}
    for m in meas:
        by.setdefault(m[0], []).append(m)
    out = []
    for lab, ms in by.items():
        ms = sorted(ms, key=lambda m: m[2])
        ref = ms[0]
        keep = [m for m in ms if np.linalg.norm(np.asarray(m[1]) - ref[1]) <= gate_m + 3.0 * np.hypot(m[2], ref[2])]
        w = np.array([1.0 / m[2] ** 2 for m in keep])
        xy = np.sum([np.asarray(m[1]) * wi for m, wi in zip(keep, w)], axis=0) / w.sum()
        src = "depth" if any(m[3] == "depth" for m in keep) else keep[0][3]
        depth = next((m[5] for m in keep if np.isfinite(m[5])), np.nan)
        out.append((lab, xy, float(1.0 / np.sqrt(w.sum())), src, max(m[4] for m in keep), depth))
    return out
