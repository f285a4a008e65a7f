"""``radarcal run``: the match-time loop. Sources -> detector -> pipeline (cloud queue / LiDAR-first tracks / box
depth -> localisation -> tracks) -> outputs (JSON lines, minimap, status line, referee serial link: minimap 0x0305,
sentry guidance and hero range via 0x0301).

The jobs live in their own modules: :mod:`radarcal.runtime.pipeline` (per-frame core, arrays in,
:class:`FrameResult` out, no I/O), :mod:`radarcal.runtime.minimap` (top view, stage timer),
:mod:`radarcal.runtime.evaluation` (accuracy against a replay's truth); this module is the I/O loop (:func:`run`)
and re-exports them. Nothing here imports a solver: the bundle is read once at start.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Callable

from radarcal.bundle import Bundle
from radarcal.errors import InputError
from radarcal.io.run_results import RunResultsWriter
from radarcal.runtime.evaluation import OnlineEvaluator, Scorer, evaluate_tracks
from radarcal.runtime.minimap import Minimap, StageTimer
from radarcal.runtime.pipeline import LOCALISE_MODES, FrameResult, Pipeline, RobotOut, RunConfig

__all__ = ["RunConfig", "RobotOut", "FrameResult", "Pipeline", "Minimap", "StageTimer", "run", "pick_frames", "evaluate_tracks", "OnlineEvaluator",
           "Scorer", "limit_blas_threads", "LOCALISE_MODES"]  # fmt: skip

STAGES = ("cloud", "detect", "depth", "localise", "track", "output")


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


def cloud_frames_as_pairs(clouds, cloud_offset_s: float = 0.0):
    """LiDAR only (no camera): one loop frame per cloud, at the cloud's time, named after it."""
    import dataclasses

    from radarcal.runtime.sources import CameraFrame

    for i, c in enumerate(clouds):
        c = dataclasses.replace(c, t=c.t + cloud_offset_s)  # a new Cloud on the loop's clock: the source's stamps stay
        yield CameraFrame(c.t, c.name or f"cloud{i:06d}", lambda: None, i), [c]


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
        status_extra: Callable[[], str] | None = None, write_latency: bool = True, marking=None) -> dict:  # fmt: skip
    """Run the loop over ``pairs`` (camera frame, new clouds). ``detect(frame) -> list[Detection]``.

    Writes one JSON line per frame to ``out_path``; the minimap to ``minimap_path`` (.png: last frame with whole
    trails; .mp4/.avi: a video at the camera rate); sends referee frames through ``link``. ``status_extra()`` adds
    sensor health to the status line; ``write_latency=False`` leaves the wall-clock latencies out of the JSON lines
    (replays of a recording: byte-identical output); ``marking`` (:class:`radarcal.runtime.marking.Marking`) decides
    what goes on the link (roster, guesses, bandwidth, double vulnerability). Returns a summary."""
    timer = StageTimer()
    out_f = RunResultsWriter(out_path) if out_path else None
    mm = _MinimapOutput(pipeline.field_model, minimap_path) if minimap_path else None
    last_status = 0.0
    results = [] if keep_results else None
    n = 0
    located = {"depth": 0, "ground": 0, "predicted": 0}
    bad_frames = 0
    tty = sys.stderr.isatty()
    t_start = time.perf_counter()
    last = None
    last_missing = None
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
            for k, v in (getattr(detect, "last_timings_ms", None) or {}).items():  # detector stages: robot / armour / number
                timings[f"detect_{k}"] = v
            team = pipeline.cfg.team
            if link is not None and link.state.team:
                team = link.state.team
            res = pipeline.process(frame.t, frame.name, dets, timings, team)
            tic = time.perf_counter()
            d = res.to_dict()
            if out_f:
                out_f.write(d if write_latency else {k: v for k, v in d.items() if k != "latency_ms"})
            if mm is not None:
                mm.add(res)
            if link is not None:
                msgs = marking.messages(res, team, link.state) if marking is not None else pipeline.referee_messages(res, team)
                for cmd, data, key in msgs:
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
            missing_changed = res.missing != last_missing  # a camera unplugged or back (several cameras): say so at once
            last_missing = res.missing
            if status and (now - last_status > (0.5 if tty else 5.0) or missing_changed):
                last_status = now
                line = _status_line(n, res, timer, pipeline, link, marking, status_extra)
                sys.stderr.write(("\r" + line + "\x1b[K") if tty else line + "\n")
                sys.stderr.flush()
            if max_frames is not None and n >= max_frames:
                break
    finally:
        blas.__exit__(None, None, None)
        if getattr(pipeline, "drift", None) is not None:
            pipeline.drift.finish()  # the last check belongs in the summary
        if out_f:
            out_f.close()
        if mm is not None:
            mm.close()
        if status and tty:
            sys.stderr.write("\n")
    if mm is not None and last is not None:
        mm.write_png(last)
    wall = time.perf_counter() - t_start
    return {"frames": n, "wall_s": wall, "fps": n / wall if wall > 0 else 0.0, "latency_ms": timer.summary(), "robot_frames": located,
            "clouds": pipeline.clouds_in, "bad_frames": bad_frames, "results": results,
            **({"drift": pipeline.drift.summary()} if getattr(pipeline, "drift", None) is not None else {}),
            **({"marking": marking.summary()} if marking is not None else {})}  # fmt: skip


_VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv")


class _MinimapOutput:
    """``--minimap``: a video (.mp4/.avi/.mkv, one image per frame at 30 fps) or a PNG of the last frame with the whole
    run's trails (kept bounded: the older half thinned past 3000 points per robot)."""

    def __init__(self, field_model, path: Path):
        from radarcal.io.video import VideoFileWriter

        self.path, self.map = Path(path), Minimap(field_model)
        self.video = self.path.suffix.lower() in _VIDEO_SUFFIXES
        self.writer = VideoFileWriter(self.path, 30.0) if self.video else None  # opened by the first frame

    def add(self, res: FrameResult) -> None:
        if self.video:
            self.writer.write(self.map.draw(res))
            return
        for r in res.robots:
            hist = self.map.history.setdefault(r.key, [])
            hist.append((res.t, float(r.p_field[0]), float(r.p_field[1])))
            if len(hist) > 3000:
                hist[:2000] = hist[:2000:2]

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()

    def write_png(self, last: FrameResult) -> None:
        if self.video:
            return
        from radarcal.io.images import write_image

        write_image(self.path, self.map.draw(FrameResult(last.t, last.frame, last.robots, None, None, {}), full_trails=True), "minimap image")


def _status_line(n: int, res: FrameResult, timer: StageTimer, pipeline, link, marking, status_extra) -> str:
    """The operator's status line: frame, FPS, per-stage ms (detector sub-stages), robots by source, link, health."""
    rec = timer.recent()
    stages = " ".join(f"{k} {rec.get(k, 0):.1f}" for k in STAGES)
    sub = " ".join(f"{k[7:]} {v:.1f}" for k, v in rec.items() if k.startswith("detect_"))
    if sub:
        stages = stages.replace(f"detect {rec.get('detect', 0):.1f}", f"detect {rec.get('detect', 0):.1f} ({sub})", 1)
    srcs: dict[str, int] = {}
    for r in res.robots:
        srcs[r.source] = srcs.get(r.source, 0) + 1
    ser = ""
    if link is not None:
        s = link.snapshot()
        ser = f" | serial {'ok' if s['connected'] else 'DOWN'} tx {s['sent']} rx {s['received']}" + (marking.status_text() if marking is not None else "")
    line = f"frame {n:6d} t={res.t:8.2f}s | {timer.fps():5.1f} FPS | ms: {stages} | robots {len(res.robots)} {srcs}{ser}"
    if status_extra is not None:
        line += status_extra()
    if getattr(pipeline, "drift", None) is not None:
        line += pipeline.drift.status_text()
    return line
