"""``radarcal run``: the match-time loop. Sources -> detector -> cloud queue / box depth -> localisation -> tracks
-> outputs (JSON lines, minimap, status line, referee serial link: minimap 0x0305, sentry guidance and hero range
via 0x0301).

:class:`Pipeline` is the per-frame core (arrays in, :class:`FrameResult` out, no I/O); :func:`run` wires sources,
outputs and the serial link around it. Nothing here imports a solver: the bundle is read once at start.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from radarcal.bundle import Bundle
from radarcal.errors import InputError
from radarcal.runtime import referee as rp
from radarcal.runtime.detector import Detection
from radarcal.runtime.fusion import CloudQueue, SurfaceFilter
from radarcal.runtime.localise import Localiser
from radarcal.runtime.tracks import TrackManager

__all__ = ["RunConfig", "RobotOut", "FrameResult", "Pipeline", "Minimap", "StageTimer", "run", "pick_frames", "evaluate_tracks", "OnlineEvaluator", "limit_blas_threads"]

STAGES = ("cloud", "detect", "depth", "localise", "track", "output")


@dataclass
class RunConfig:
    team: str = "red"  # our colour; the referee link (0x0201) overrides it when connected
    season: int = 2024
    robot_radius_m: float = 0.27
    visible_depth_factor: float = 0.85
    cloud_queue_points: int = 200_000
    cloud_queue_age_s: float = 1.0
    depth_max_age_s: float = 0.5  # oldest cloud a box depth may come from (robots move ~1.5 m/s)
    min_score: float = 0.25
    max_coast_s: float = 1.0
    accel_sigma: float = 3.0
    sentry_xy: tuple[float, float] | None = None  # fixed sentry position when it is not tracked
    sentry_cmd_id: int = 0x0200  # robot-to-robot sub-id of the sentry guidance message
    hero_cmd_id: int = 0x0201  # robot-to-robot sub-id of the hero range message
    hero_range_offset_m: float = 0.0
    surface_filter: bool = True  # drop LiDAR returns from the field surface before box depth
    surface_min_height_m: float = 0.08

    @classmethod
    def from_bundle(cls, bundle: Bundle, **overrides) -> "RunConfig":
        rt = bundle.runtime or {}
        cfg = cls(
            season=int(rt.get("referee_season", 2024)),
            robot_radius_m=float(rt.get("robot_radius_m", cls.robot_radius_m)),
            cloud_queue_points=int(rt.get("cloud_queue_points", cls.cloud_queue_points)),
            cloud_queue_age_s=float(rt.get("cloud_queue_age_s", cls.cloud_queue_age_s)),
            depth_max_age_s=float(rt.get("depth_max_age_s", cls.depth_max_age_s)),
            hero_range_offset_m=float(rt.get("hero_range_offset_m", 0.0)),
            team=str(rt.get("team", "red")),
        )
        if rt.get("sentry_xy") is not None:
            cfg.sentry_xy = tuple(float(v) for v in rt["sentry_xy"])[:2]  # type: ignore[assignment]
        for k, v in overrides.items():
            if v is not None:
                setattr(cfg, k, v)
        return cfg


@dataclass
class RobotOut:
    label: str
    p_field: np.ndarray  # (3,) filtered position
    source: str  # depth | ground | predicted (no measurement this frame)
    sigma: float
    depth: float | None
    score: float | None
    raw: np.ndarray | None  # (3,) this frame's unfiltered measurement

    def to_dict(self) -> dict:
        d = {"label": self.label, "x": round(float(self.p_field[0]), 3), "y": round(float(self.p_field[1]), 3), "z": round(float(self.p_field[2]), 3),
             "source": self.source, "sigma": round(self.sigma, 3) if np.isfinite(self.sigma) else None,
             "depth": None if self.depth is None else round(self.depth, 3)}  # fmt: skip
        if self.raw is not None:
            d["raw"] = [round(float(v), 3) for v in self.raw]
        if self.score is not None:
            d["score"] = round(self.score, 3)
        return d


@dataclass
class FrameResult:
    t: float
    frame: str
    robots: list[RobotOut]
    sentry: dict | None
    hero_range_m: float | None
    timings_ms: dict[str, float]

    def to_dict(self) -> dict:
        return {"t": round(self.t, 4), "frame": self.frame, "robots": [r.to_dict() for r in self.robots], "sentry": self.sentry,
                "hero_range_m": None if self.hero_range_m is None else round(self.hero_range_m, 3),
                "latency_ms": {k: round(v, 3) for k, v in self.timings_ms.items()}}  # fmt: skip


def _team_of(label: str) -> str | None:
    return label.split("_", 1)[0] if label.startswith(("red_", "blue_")) else None


def _number_of(label: str) -> int | None:
    tail = label.split("_", 1)[-1]
    return int(tail) if tail.isdigit() else None


class Pipeline:
    """Per-frame core: clouds in, detections in, located + tracked robots out."""

    def __init__(self, bundle: Bundle, camera: str, lidar: str | None, cfg: RunConfig):
        self.cfg = cfg
        self.camera = bundle.camera(camera)
        self.T_field_cam = bundle.T("field", camera)
        self.field_model = None
        if bundle.field_model:
            from radarcal.field import FieldModel

            self.field_model = FieldModel.from_dict(bundle.field_model, bundle.path)
        self.queue = None
        if lidar is not None:
            flt = None
            if cfg.surface_filter:
                surf = self.field_model.surface_z if self.field_model is not None else None
                structs = getattr(self.field_model, "structures", None) if self.field_model is not None else None
                flt = SurfaceFilter(self.T_field_cam @ bundle.T(camera, lidar), surf, min_height=cfg.surface_min_height_m, structures=structs)
            self.queue = CloudQueue(self.camera, bundle.T(camera, lidar), cfg.cloud_queue_points, cfg.cloud_queue_age_s, point_filter=flt)
        self.localiser = Localiser(self.camera, self.T_field_cam, self.field_model, cfg.robot_radius_m, cfg.visible_depth_factor)
        self.tracks = TrackManager(accel_sigma=cfg.accel_sigma, max_coast_s=cfg.max_coast_s)
        self.clouds_in = 0

    def add_cloud(self, t: float, points: np.ndarray) -> None:
        if self.queue is not None and len(points):
            self.queue.push(t, points)
            self.clouds_in += 1

    def process(self, t: float, frame: str, detections: list[Detection], timings: dict[str, float] | None = None, team: str | None = None) -> FrameResult:
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
        depth = np.full(len(dets), np.nan)
        dsig = np.full(len(dets), np.nan)
        if self.queue is not None:
            self.queue.expire(t)
            for i, d in enumerate(dets):
                # robots standing nearer (box bottom lower in the image) and overlapping this box hide part of it:
                # their pixels are not this robot's
                b = boxes[i]
                front = (boxes[:, 3] > b[3] + 2) & (boxes[:, 0] < b[2]) & (boxes[:, 2] > b[0]) & (boxes[:, 1] < b[3]) & (boxes[:, 3] > b[1])
                bd = self.queue.depth_in_box(d.xyxy, t, max_age_s=self.cfg.depth_max_age_s, exclude=boxes[front] if front.any() else None)
                if bd is not None:
                    depth[i], dsig[i] = bd.depth, bd.sigma
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

    # --- match functions ---------------------------------------------------------------------------------------------
    def sentry_guidance(self, robots: list[RobotOut], team: str) -> dict | None:
        """Nearest enemy to our sentry as a relative field vector (NUAA 2022: enemy - sentry, sent to the sentry)."""
        sentry = next((r for r in robots if r.label == f"{team}_7"), None)
        s_xy = sentry.p_field[:2] if sentry is not None else (np.asarray(self.cfg.sentry_xy, float) if self.cfg.sentry_xy else None)
        if s_xy is None:
            return None
        enemies = [r for r in robots if _team_of(r.label) not in (None, team)]
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
        enemy = {n: tuple(r.p_field[:2]) for r in res.robots if _team_of(r.label) == enemy_team and (n := _number_of(r.label))}
        ally = {n: tuple(r.p_field[:2]) for r in res.robots if _team_of(r.label) == team and (n := _number_of(r.label))}
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


# --- minimap ---------------------------------------------------------------------------------------------------------
class Minimap:
    """Top view of the field (outline, raised areas, bases/outposts) with robots and their recent trails."""

    def __init__(self, field_model, size_m: tuple[float, float] = (28.0, 15.0), px_per_m: float = 30.0, trail_s: float = 2.0):
        import cv2

        self.field = field_model
        self.s = float(px_per_m)
        self.m = 20
        L, W = (field_model.size if field_model is not None else size_m)
        self.W, self.H = int(L * self.s) + 2 * self.m, int(W * self.s) + 2 * self.m
        base = np.full((self.H, self.W, 3), 40, np.uint8)
        if field_model is not None:
            cv2.fillPoly(base, [self._px(field_model.outline)], (70, 110, 70))
            for a in field_model.areas:
                g = int(np.clip(110 + 120 * a["z"], 0, 255))
                cv2.fillPoly(base, [self._px(a["polygon"])], (g - 30, g, g - 30))
            cv2.polylines(base, [self._px(field_model.outline)], True, (255, 255, 255), 2, cv2.LINE_AA)
            for name, p in field_model.landmarks.items():
                if name.endswith(("_base", "_outpost")):
                    c = (60, 60, 230) if name.startswith("red") else (230, 120, 40)
                    q = self._px(p[None, :2])[0]
                    cv2.rectangle(base, tuple(int(v) for v in q - 6), tuple(int(v) for v in q + 6), c, -1)
        else:
            cv2.rectangle(base, (self.m, self.m), (self.W - self.m, self.H - self.m), (255, 255, 255), 2)
        self.base = base
        self.trail_s = trail_s
        self.history: dict[str, list[tuple[float, float, float]]] = {}

    def _px(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        return np.column_stack([self.m + xy[:, 0] * self.s, self.H - self.m - xy[:, 1] * self.s]).astype(np.int32)

    def draw(self, res: FrameResult, full_trails: bool = False) -> np.ndarray:
        import cv2

        img = self.base.copy()
        for r in res.robots:
            self.history.setdefault(r.label, []).append((res.t, float(r.p_field[0]), float(r.p_field[1])))
        for label, hist in self.history.items():
            pts = [(x, y) for t, x, y in hist if full_trails or res.t - t <= self.trail_s]
            if len(pts) > 1:
                c = (80, 80, 255) if label.startswith("red") else (255, 160, 60)
                cv2.polylines(img, [self._px(np.array(pts))], False, c, 1, cv2.LINE_AA)
        for r in res.robots:
            c = (40, 40, 255) if r.label.startswith("red") else (255, 140, 30)
            q = tuple(int(v) for v in self._px(r.p_field[None, :2])[0])
            cv2.circle(img, q, 8, c, -1 if r.source != "predicted" else 2, cv2.LINE_AA)
            cv2.putText(img, r.label.split("_")[-1], (q[0] + 9, q[1] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        cv2.putText(img, f"t={res.t:7.2f}s", (8, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        for label, hist in self.history.items():  # bounded memory
            if not full_trails and len(hist) > 400:
                del hist[:200]
        return img


class StageTimer:
    """Per-stage latency in fixed-size ring buffers (flat memory however long the match): the recent window feeds the
    status line, the last ``keep`` frames the summary percentiles."""

    def __init__(self, window: int = 60, keep: int = 4096):
        self.window = window
        self.keep = keep
        self.buf: dict[str, np.ndarray] = {}
        self.n: dict[str, int] = {}
        self.frame_times = np.zeros(window)
        self.frames = 0

    def add(self, timings: dict[str, float]) -> None:
        for k, v in timings.items():
            if k not in self.buf:
                self.buf[k] = np.zeros(self.keep)
                self.n[k] = 0
            self.buf[k][self.n[k] % self.keep] = v
            self.n[k] += 1
        self.frame_times[self.frames % self.window] = time.perf_counter()
        self.frames += 1

    def _values(self, k: str, last: int | None = None) -> np.ndarray:
        n = self.n[k]
        m = min(n, self.keep if last is None else min(last, self.keep))
        idx = (np.arange(n - m, n)) % self.keep
        return self.buf[k][idx]

    def fps(self) -> float:
        m = min(self.frames, self.window)
        if m < 2:
            return 0.0
        ft = self.frame_times[(np.arange(self.frames - m, self.frames)) % self.window]
        return (m - 1) / (ft[-1] - ft[0]) if ft[-1] > ft[0] else 0.0

    def recent(self) -> dict[str, float]:
        return {k: float(np.mean(self._values(k, self.window))) for k in self.buf if self.n[k]}

    def summary(self) -> dict[str, dict[str, float]]:
        out = {}
        for k in self.buf:
            v = self._values(k)
            if len(v):
                out[k] = {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(np.max(v))}
        return out


# --- evaluation (replays with truth.jsonl) -------------------------------------------------------------------------------
def evaluate_tracks(results: Iterable[dict], truth_by_frame: dict[str, dict]) -> dict:
    """Horizontal errors of the output positions against ``truth.jsonl`` for every visible true robot."""
    errs, src, missing, present = [], [], 0, 0
    for res in results:
        tr = truth_by_frame.get(res["frame"])
        if tr is None:
            continue
        out = {r["label"]: r for r in res["robots"]}
        for rob in tr["robots"]:
            if not rob.get("visible", True):
                continue
            present += 1
            o = out.get(rob["label"])
            if o is None:
                missing += 1
                continue
            errs.append(float(np.hypot(o["x"] - rob["p_field"][0], o["y"] - rob["p_field"][1])))
            src.append(o["source"])
    e = np.asarray(errs)
    src_a = np.asarray(src)
    by = {s: {"n": int((src_a == s).sum()), "median_m": float(np.median(e[src_a == s]))} for s in sorted(set(src)) if (src_a == s).any()}
    return {"visible": present, "located": present - missing, "missing": missing, "median_m": float(np.median(e)) if len(e) else None,
            "p95_m": float(np.percentile(e, 95)) if len(e) else None, "max_m": float(e.max()) if len(e) else None, "by_source": by}  # fmt: skip


class OnlineEvaluator:
    """Accumulates horizontal errors against ``truth.jsonl`` while the loop runs, reading the truth lazily in frame
    order (flat memory on long replays: only floats are kept)."""

    def __init__(self, truth_path: Path):
        self._f = open(truth_path, encoding="utf-8")
        self._pending: dict[str, dict] = {}
        self.errors: list[float] = []
        self.sources: list[str] = []
        self.visible = 0
        self.missing = 0

    def _truth(self, frame: str) -> dict | None:
        if frame in self._pending:
            return self._pending.pop(frame)
        for line in self._f:
            if not line.strip():
                continue
            d = json.loads(line)
            if str(d.get("frame")) == frame:
                return d
            self._pending[str(d.get("frame"))] = d
            if len(self._pending) > 1000:  # frames without results (e.g. --max-frames): do not hoard
                self._pending.pop(next(iter(self._pending)))
        return None

    def __call__(self, n: int, res: FrameResult) -> None:
        tr = self._truth(res.frame)
        if tr is None:
            return
        out = {r.label: r for r in res.robots}
        for rob in tr["robots"]:
            if not rob.get("visible", True):
                continue
            self.visible += 1
            o = out.get(rob["label"])
            if o is None:
                self.missing += 1
                continue
            self.errors.append(float(np.hypot(o.p_field[0] - rob["p_field"][0], o.p_field[1] - rob["p_field"][1])))
            self.sources.append(o.source)

    def summary(self) -> dict:
        self._f.close()
        e, src = np.asarray(self.errors), np.asarray(self.sources)
        by = {s: {"n": int((src == s).sum()), "median_m": float(np.median(e[src == s]))} for s in sorted(set(self.sources))}
        return {"visible": self.visible, "located": self.visible - self.missing, "missing": self.missing, "median_m": float(np.median(e)) if len(e) else None,
                "p95_m": float(np.percentile(e, 95)) if len(e) else None, "max_m": float(e.max()) if len(e) else None, "by_source": by}  # fmt: skip


# --- the loop with I/O --------------------------------------------------------------------------------------------------
def pick_frames(bundle: Bundle, camera: str | None, lidar: str | None, need_lidar: bool) -> tuple[str, str | None]:
    cams = list(bundle.cameras)
    if camera is None:
        if len(cams) != 1:
            raise InputError(bundle.path, f"bundle has {len(cams)} cameras ({', '.join(cams) or 'none'}): choose one with --camera")
        camera = cams[0]
    bundle.camera(camera)  # InputError naming the bundle when the camera is not there
    if not bundle.has_T("field", camera):
        raise InputError(bundle.path, f"no field pose for {camera!r} (run `radarcal field-pnp` first: T_field_{camera} is missing)")
    if need_lidar and lidar is None:
        lidars = [n for n, m in bundle.sensors.items() if m.get("type") == "lidar" and bundle.has_T(camera, n)]
        if len(lidars) != 1:
            raise InputError(bundle.path, f"{len(lidars)} LiDARs with an extrinsic to {camera!r} ({', '.join(lidars) or 'none'}): choose one with --lidar")
        lidar = lidars[0]
    if lidar is not None and not bundle.has_T(camera, lidar):
        raise InputError(bundle.path, f"no extrinsic between {camera!r} and {lidar!r} (T_{camera}_{lidar})")
    return camera, lidar


def limit_blas_threads(n: int = 1):
    """The loop's numpy work is many small (N,3)x(3,3) products: BLAS threads only add wake-up latency and, on a
    busy or pinned CPU, can stall for tens of ms. Returns a context (no-op without ``threadpoolctl``)."""
    import contextlib

    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(n, user_api="blas")


def run(pipeline: Pipeline, pairs, detect: Callable, out_path: Path | None = None, minimap_path: Path | None = None, link=None,
        status: bool = True, max_frames: int | None = None, keep_results: bool = False, on_frame: Callable | None = None,
        status_extra: Callable[[], str] | None = None, write_latency: bool = True) -> dict:  # fmt: skip
    """Run the loop over ``pairs`` (camera frame, new clouds). ``detect(frame) -> list[Detection]``.

    Writes one JSON line per frame to ``out_path``; the minimap to ``minimap_path`` (.png: last frame with whole
    trails; .mp4/.avi: a video at the camera rate); sends referee frames through ``link``. ``status_extra()`` adds
    sensor health to the status line; ``write_latency=False`` leaves the wall-clock latencies out of the JSON lines
    (replays of a recording: byte-identical output). Returns a summary."""
    import cv2

    timer = StageTimer()
    out_f = open(out_path, "w", encoding="utf-8") if out_path else None
    mm = Minimap(pipeline.field_model) if minimap_path else None
    writer = None
    last_status = 0.0
    results = [] if keep_results else None
    n = 0
    located = {"depth": 0, "ground": 0, "predicted": 0}
    bad_frames = 0
    tty = sys.stderr.isatty()
    t_start = time.perf_counter()
    last = None
    blas = limit_blas_threads(1)
    blas.__enter__()
    try:
        for frame, clouds in pairs:
            tic = time.perf_counter()
            for c in clouds:
                pipeline.add_cloud(c.t, c.points)
            toc = time.perf_counter()
            timings = {"cloud": (toc - tic) * 1e3}
            try:
                dets = detect(frame)
            except InputError as e:  # an unreadable image: report, locate nothing new this frame, keep going
                bad_frames += 1
                sys.stderr.write(f"warning: {e} (frame skipped)\n")
                dets = []
            tic = time.perf_counter()
            timings["detect"] = (tic - toc) * 1e3
            team = pipeline.cfg.team
            if link is not None and link.state.team:
                team = link.state.team
            res = pipeline.process(frame.t, frame.name, dets, timings, team)
            tic = time.perf_counter()
            d = res.to_dict()
            if out_f:
                out_f.write(json.dumps(d if write_latency else {k: v for k, v in d.items() if k != "latency_ms"}, separators=(",", ":")) + "\n")
            if mm is not None:
                if minimap_path.suffix.lower() in (".mp4", ".avi", ".mkv"):
                    img = mm.draw(res)
                    if writer is None:
                        fourcc = cv2.VideoWriter_fourcc(*("mp4v" if minimap_path.suffix.lower() == ".mp4" else "MJPG"))
                        writer = cv2.VideoWriter(str(minimap_path), fourcc, 30.0, (img.shape[1], img.shape[0]))
                    writer.write(img)
                else:
                    for r in res.robots:
                        hist = mm.history.setdefault(r.label, [])
                        hist.append((res.t, float(r.p_field[0]), float(r.p_field[1])))
                        if len(hist) > 3000:  # whole-run trails for the PNG, bounded: thin the older half
                            hist[:2000] = hist[:2000:2]
            if link is not None:
                for cmd, data, key in pipeline.referee_messages(res, team):
                    link.send(cmd, data, key)
            res.timings_ms["output"] = (time.perf_counter() - tic) * 1e3
            timer.add(res.timings_ms)
            for r in res.robots:
                located[r.source] = located.get(r.source, 0) + 1
            if results is not None:
                results.append(d)
            if on_frame is not None:
                on_frame(n, res)
            last = res
            n += 1
            now = time.perf_counter()
            if status and now - last_status > (0.5 if tty else 5.0):
                last_status = now
                rec = timer.recent()
                stages = " ".join(f"{k} {rec.get(k, 0):.1f}" for k in STAGES)
                srcs = {}
                for r in res.robots:
                    srcs[r.source] = srcs.get(r.source, 0) + 1
                ser = ""
                if link is not None:
                    s = link.snapshot()
                    ser = f" | serial {'ok' if s['connected'] else 'DOWN'} tx {s['sent']} rx {s['received']}"
                line = f"frame {n:6d} t={res.t:8.2f}s | {timer.fps():5.1f} FPS | ms: {stages} | robots {len(res.robots)} {srcs}{ser}"
                if status_extra is not None:
                    line += status_extra()
                sys.stderr.write(("\r" + line + "\x1b[K") if tty else line + "\n")
                sys.stderr.flush()
            if max_frames is not None and n >= max_frames:
                break
    finally:
        blas.__exit__(None, None, None)
        if out_f:
            out_f.close()
        if writer is not None:
            writer.release()
        if status and tty:
            sys.stderr.write("\n")
    if mm is not None and last is not None and minimap_path.suffix.lower() not in (".mp4", ".avi", ".mkv"):
        img = mm.draw(FrameResult(last.t, last.frame, last.robots, None, None, {}), full_trails=True)
        if not cv2.imwrite(str(minimap_path), img):
            raise InputError(minimap_path, "cannot write minimap image")
    wall = time.perf_counter() - t_start
    return {"frames": n, "wall_s": wall, "fps": n / wall if wall > 0 else 0.0, "latency_ms": timer.summary(), "robot_frames": located,
            "clouds": pipeline.clouds_in, "bad_frames": bad_frames, "results": results}  # fmt: skip
