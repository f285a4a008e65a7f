"""One ``radarcal run`` from its parsed options: inputs opened (replay folder, cameras, clouds, live LiDARs, referee
link, console), the pipeline built from the bundle, the loop run, the summary assembled. The CLI
(:mod:`radarcal.cli.run_cmd`) parses the options, runs its checks on the :class:`RunPlan` and prints the summary.

Two steps, so that the checks that must come before anything starts (outputs, season, serial port) see what the
run will use: :func:`plan_run` (options -> bundle, cameras, LiDAR, config, warnings; nothing started) and
:func:`execute` (sources, detector, loop, cleanup). Several cameras (issue #19, :mod:`radarcal.runtime.multicam`):
``--video cam0=SRC --video cam1=SRC`` or a replay whose ``meta.json`` lists ``cameras``; ``--camera cam0[,cam1]``
chooses among them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from radarcal.errors import InputError
from radarcal.io.source_specs import split_named

__all__ = ["RunOptions", "RunPlan", "validate_options", "plan_run", "execute", "open_detector", "live_lidars", "health_text"]


@dataclass
class RunOptions:
    """What ``radarcal run`` was given (parsed: paths, numbers; None = not given)."""

    bundle: Path | None = None
    replay: Path | None = None
    video: list[str] = field(default_factory=list)
    clouds: list[str] = field(default_factory=list)
    cloud_topic: str | None = None
    cloud_offset: float | str = 0.0
    detector: Path | None = None
    names: Path | None = None
    detector_layout: str | None = None
    anchors: Path | None = None
    armour: Path | None = None
    armour_names: Path | None = None
    number: Path | None = None
    number_names: Path | None = None
    providers: str = "cpu"
    detect_ahead: bool = True
    conf: float = 0.25
    threads: int = 0
    detect_workers: int = 1  # frames detected at once (DetectAhead workers; 2 with --threads 1 is fastest on 2 cores)
    roi_windows: int | None = None  # native-resolution windows around far robots per frame (None: auto, far_windows.auto_windows)
    detections: Path | None = None
    serial: str | None = None
    out: Path | None = None
    minimap: Path | None = None
    camera: str | None = None
    lidar: str | None = None
    team: str | None = None
    season: int | None = None
    sentry_xy: tuple[float, float] | None = None
    max_frames: int | None = None
    record: Path | None = None
    realtime_video: bool = False
    no_lidar: bool = False
    localise: str = "auto"
    no_camera: bool = False
    status: bool = True
    marking: dict = field(default_factory=dict)  # RunConfig fields of the marking side (cli/marking_options.py)
    ui: str | None = None
    speed: float | None = None
    field_pose: str = "auto"
    drift_check_s: float = 0.0  # re-register the LiDAR to the field every this many seconds (0 = off)


@dataclass
class RunPlan:
    opts: RunOptions
    bundle_path: Path
    bundle: object  # radarcal.bundle.Bundle (field poses of this run set in memory only)
    rep: object | None  # radarcal.runtime.sources.Replay
    cameras: list[str]  # the first is the primary (status, console, single-camera outputs)
    lidar: str | None
    has_clouds: bool
    lidar_only: bool
    cfg: object  # RunConfig
    warnings: list[str]  # for the operator (the CLI adds its own checks' warnings)
    videos: dict[str, str] | None  # several --video NAME=SRC
    multi: bool  # the multi-camera path (ticks of camera frames)

    @property
    def camera(self) -> str:
        return self.cameras[0]

    @property
    def inputs(self) -> list:
        r = self.rep
        return [self.opts.detections, r.detections if r else None, r.truth if r else None]


def validate_options(o: RunOptions) -> None:
    """Option combinations that are wrong whatever the inputs hold (before a recording is even opened)."""
    if o.replay is not None and o.video or (o.replay is None and not o.video and not o.clouds):
        raise InputError("radarcal run", "give exactly one of --replay DIR or --video SRC (or --clouds SRC alone: LiDAR only)")
    if o.roi_windows is not None and not 0 <= o.roi_windows <= 8:
        raise InputError("--roi-windows", f"expected 0..8 windows per frame, got {o.roi_windows}")
    if o.localise not in ("auto", "lidar", "box"):
        raise InputError("--localise", f"expected auto, lidar or box, got {o.localise!r}")
    lidar_only = o.no_camera or (o.replay is None and not o.video and bool(o.clouds))
    if lidar_only and (o.no_lidar or o.localise == "box"):
        raise InputError("--no-camera", "LiDAR-only needs the clouds and --localise auto or lidar")


def plan_run(o: RunOptions) -> RunPlan:
    """Options -> what the run will use (bundle loaded, cameras / LiDAR chosen, config); nothing started."""
    from radarcal.bundle import load_bundle
    from radarcal.runtime.loop import RunConfig, pick_frames
    from radarcal.runtime.multicam import parse_videos
    from radarcal.runtime.sources import open_replay
    from radarcal.verdicts import forced_entries

    lidar_only = o.no_camera or (o.replay is None and not o.video and bool(o.clouds))
    if o.record is not None and o.replay is not None:
        raise InputError("--record", "records live inputs: not with --replay")
    if len(o.clouds) > 1 and not all("://" in c for c in o.clouds):
        raise InputError("--clouds", "several --clouds are for live LiDARs (NAME=livox://IP ...)")
    if o.detector is not None and o.detections is not None:
        raise InputError("radarcal run", "give at most one of --detector and --detections")
    if o.team is not None and o.team not in ("red", "blue"):
        raise InputError("--team", f"expected red or blue, got {o.team!r}")
    videos = parse_videos(o.video) if o.video else None
    rep = open_replay(o.replay) if o.replay is not None else None
    bundle = o.bundle
    if bundle is None:
        if rep is None or rep.bundle is None:
            raise InputError("--bundle", "required (the replay has no calib.yaml)")
        bundle = rep.bundle
    b = load_bundle(bundle)
    has_clouds = not o.no_lidar and ((rep is not None and bool(rep.clouds)) or bool(o.clouds))
    meta = rep.meta if rep is not None else {}
    replay_cams = [str(c) for c in meta.get("cameras", [])] if rep is not None else []
    if videos is not None:
        if o.record is not None or o.realtime_video:
            raise InputError("--video", "several cameras: --record and --realtime-video take one camera")
        cams = list(videos)
    elif replay_cams:
        cams = [c.strip() for c in o.camera.split(",")] if o.camera else replay_cams
        for c in cams:
            if c not in replay_cams:
                raise InputError(o.replay, f"no camera {c!r} in the replay (cameras: {', '.join(replay_cams)})")
    else:
        cams = [o.camera or (meta.get("camera") if rep else None)]
    multi = videos is not None or bool(replay_cams)
    if multi and o.ui is not None:
        raise InputError("--ui", "the console follows single-camera runs (one --video or a single-camera replay), not several cameras")
    if multi and o.detections is not None:
        raise InputError("--detections", "several cameras: each camera's detections come from its replay folder (cameras/NAME/detections.jsonl) or --detector")
    cam0, lidar = pick_frames(b, cams[0], o.lidar or (meta.get("lidar") if rep and has_clouds else None), has_clouds)
    cams[0] = cam0
    for c in cams[1:]:
        pick_frames(b, c, lidar, has_clouds)  # its field pose and its extrinsic to the LiDAR
    timing = {}
    if "cloud_sweep_s" in meta:  # the replay says when its clouds were fired and delivered
        timing = {"cloud_sweep_s": float(meta["cloud_sweep_s"]), "cloud_latency_s": float(meta.get("cloud_latency_s", 0.0))}
    elif str(meta.get("generator", "")).startswith("radarcal synth field"):  # robots frozen at the cloud stamp
        timing = {"cloud_sweep_s": 0.0, "cloud_latency_s": 0.0}
    cfg = RunConfig.from_bundle(b, team=o.team, season=o.season, sentry_xy=o.sentry_xy, localise="lidar" if lidar_only else o.localise,
                                drift_check_s=o.drift_check_s, **timing, **o.marking)
    return RunPlan(o, Path(bundle), b, rep, cams, lidar, has_clouds, lidar_only, cfg, [f"bundle {w}" for w in forced_entries(b)], videos, multi)


def execute(plan: RunPlan, resolve_pose: Callable, log: Callable[[str], None]) -> dict:
    """Start the sources, run the loop, close everything; returns the summary.

    ``resolve_pose(bundle, camera, lidar) -> (T_field_cam or None, description)`` (``--field-pose``);
    ``log(text)``: a line for the operator (stderr)."""
    from radarcal.runtime.loop import OnlineEvaluator, Pipeline, cloud_frames_as_pairs
    from radarcal.runtime.loop import run as run_loop
    from radarcal.runtime.marking import Marking
    from radarcal.runtime.sources import merge_by_time

    o, b, rep, cfg = plan.opts, plan.bundle, plan.rep, plan.cfg
    for c in plan.cameras:
        T_fc, src = resolve_pose(b, c, plan.lidar)
        if T_fc is not None:  # in memory only (run never saves the bundle): the Pipeline reads bundle.T("field", cam)
            b.set_transform("field", c, T_fc, method=f"run --field-pose {o.field_pose}: {src}")
    pipe = Pipeline(b, plan.cameras if plan.multi else plan.camera, plan.lidar if plan.has_clouds else None, cfg)
    if o.detector is None and (o.armour is not None or o.number is not None):
        raise InputError("--armour" if o.armour is not None else "--number", "needs --detector (the robot detector)")
    tick_detect = camera_health = recorder = None
    if plan.multi:
        detect, frames, cloud_src, tick_detect = _multi_sources(plan, log)
    else:
        detect, frames, cloud_src, camera_health, recorder = _single_sources(plan, log)
    far = _far_windows(plan, pipe, tick_detect.recogniser if plan.multi else getattr(detect, "recogniser", None), log)
    link = _open_link(plan, recorder)
    marking = Marking(cfg, field_length_m=pipe.field_model.size[0] if pipe.field_model is not None else 28.0) if link is not None else None
    evaluator = OnlineEvaluator(rep.truth) if rep is not None and rep.truth is not None else None
    pairs = merge_by_time(frames, cloud_src, o.cloud_offset) if frames is not None else cloud_frames_as_pairs(cloud_src, o.cloud_offset if isinstance(o.cloud_offset, float) else 0.0)
    on_frame, console = evaluator, None
    if o.ui is not None or o.speed:
        pairs, detect, on_frame, console = _pace_and_console(plan, pipe, pairs, detect, evaluator, link, cloud_src, marking)
    if far is not None:  # the windows follow the tracks of the frame just output
        from radarcal.runtime.console.live import chain_callbacks

        on_frame = chain_callbacks(on_frame, far.observe)
    rec_manifest = None
    try:
        def sensors_health() -> dict:
            h = dict(cloud_src.sensors_health()) if hasattr(cloud_src, "sensors_health") else {}
            if camera_health is not None:
                h[plan.camera] = camera_health()
            return h

        parts = []
        if hasattr(cloud_src, "sensors_health") or camera_health:
            parts.append(lambda: health_text(sensors_health()))
        if tick_detect is not None:
            from radarcal.runtime.multicam import missing_text

            parts.append(lambda: missing_text(tick_detect.last_missing))
        extra = (lambda: "".join(p() for p in parts)) if parts else None
        summary = run_loop(pipe, pairs, detect, o.out, o.minimap, link, status=o.status, max_frames=o.max_frames, on_frame=on_frame, status_extra=extra, marking=marking)
        if hasattr(cloud_src, "sensors_health") or camera_health:
            summary["health"] = sensors_health()
    finally:
        if console is not None:
            console.server.close()
        if link is not None:
            link.close()
        if hasattr(frames, "close"):  # stop the decode / detect-ahead threads before exit (a thread still inside
            frames.close()  # OpenCV or onnxruntime at interpreter exit aborted the process: exit 134 after --max-frames)
        if cloud_src is not None and hasattr(cloud_src, "close"):
            cloud_src.close()
        if recorder is not None:
            from radarcal.runtime.replay import finish_recording

            rec_manifest = finish_recording(recorder, cloud_src, o.serial)
    if far is not None:
        summary["roi_windows"] = far.summary()
    return _finish_summary(summary, plan, cloud_src, evaluator, tick_detect, link, console, rec_manifest)


def _single_sources(plan: RunPlan, log: Callable):
    """One camera (or none): (detect, frames, cloud source, camera health or None, recorder or None)."""
    from radarcal.runtime.detector import DetectionsFile
    from radarcal.runtime.sources import open_camera, open_clouds, prefetch_frames

    o, rep = plan.opts, plan.rep
    if plan.lidar_only:
        detect = lambda f: []  # noqa: E731
    elif o.detector is not None:
        detect = open_detector(o, log)
    else:
        det_path = o.detections or (rep.detections if rep else None)
        if det_path is None:
            raise InputError("radarcal run", "no detector: give --detector model.onnx or --detections FILE (or a replay with detections.jsonl)")
        dfile = DetectionsFile.read(det_path)
        detect = lambda f: dfile.lookup(f.t, f.name)  # noqa: E731
    recorder = camera_health = None
    video = o.video[0] if o.video else None
    if rep is not None:
        frames = rep.camera_frames(need_pixels=o.detector is not None and not plan.lidar_only)
        cloud_src = rep.cloud_frames() if plan.has_clouds else None
    elif video is None:  # --clouds alone: one frame per cloud
        cloud_src = open_clouds(o.clouds[0], o.cloud_topic)
        frames = None
    else:
        from radarcal.runtime.replay import paced_video, start_recording

        frames = paced_video(video) if o.realtime_video else open_camera(video)
        camera_health = getattr(frames, "snapshot", None)
        recorder = start_recording(o.record, plan.bundle, plan.camera, video, o.clouds) if o.record is not None else None
        cloud_src = _live_clouds(plan, recorder)
    if o.detector is not None and frames is not None and not plan.lidar_only:  # decode ahead in a thread (live sources: newest frame only)
        live = video is not None and (video.isdigit() or "://" in video)
        frames = prefetch_frames(frames, latest_only=live, prepare=getattr(detect, "prepare_ahead", None))  # letterbox there too
        if o.detect_ahead:
            frames = detect.frames(frames)
    if rep is None and recorder is not None:
        from radarcal.runtime.replay import recorded

        frames = recorded(frames, recorder, plan.camera)
    return detect, frames, cloud_src, camera_health, recorder


def _far_windows(plan: RunPlan, pipe, recogniser, log: Callable):
    """``--roi-windows``: the recogniser's far-robot windows (:mod:`radarcal.runtime.far_windows`) when some camera
    gets any (auto: frames at least 3x the detector input); None without an ONNX detector or windows."""
    if recogniser is None or plan.lidar_only or not hasattr(recogniser, "robot"):
        return None
    from radarcal.runtime.far_windows import FarWindows

    far = FarWindows.for_pipeline(pipe, recogniser.robot.input_size, plan.opts.roi_windows)
    if not far.active():
        return None
    recogniser.far = far
    h, w = far.input_hw
    log(f"far-robot windows: up to {', '.join(f'{c} {far.count(v[0].image_size[::-1])}' for c, v in far.views.items())} native {w}x{h} windows per frame "
        f"(tracks whose box would be < {far.far_px:.0f} px in the full-frame letterbox)")
    return far


def _open_link(plan: RunPlan, recorder):
    """The referee serial link (``--serial``), tapped into the recording when recording; None without ``--serial``."""
    o = plan.opts
    if not o.serial:
        return None
    from radarcal.runtime.serial_link import SerialLink

    factory = None
    if plan.rep is None and recorder is not None:
        from radarcal.runtime.replay import tapped_serial

        factory = tapped_serial(recorder)
    return SerialLink(o.serial, season=plan.cfg.season, serial_factory=factory).start()


def _pace_and_console(plan: RunPlan, pipe, pairs, detect, evaluator, link, cloud_src, marking):
    """``--speed`` pacing of a replay and the ``--ui`` live console: (pairs, detect, on_frame, console or None)."""
    from radarcal.runtime.console.live import chain_callbacks, paced, start_console

    o, cfg = plan.opts, plan.cfg
    pairs = paced(pairs, o.speed if o.speed is not None else 1.0) if plan.rep is not None else pairs
    if o.ui is None:
        return pairs, detect, evaluator, None
    console = start_console(o.ui, pipe, plan.bundle, plan.camera, plan.lidar if plan.has_clouds else None,
                            {"camera": plan.camera, "team": cfg.team, "hero_range_offset_m": cfg.hero_range_offset_m})  # fmt: skip
    pairs, detect, on_frame = console.observe_pairs(pairs), console.observe_detect(detect), chain_callbacks(evaluator, console.on_frame)
    if marking is not None:
        console.on_action("double_vulnerability", marking.operator_dv)
    for name, src in (("serial", link and link.snapshot), ("clouds", getattr(cloud_src, "health", None)),
                      ("drift", getattr(pipe, "drift", None) and pipe.drift.snapshot)):  # fmt: skip
        if callable(src):
            console.add_health(name, src)
    return pairs, detect, on_frame, console


def _finish_summary(summary: dict, plan: RunPlan, cloud_src, evaluator, tick_detect, link, console, rec_manifest) -> dict:
    """The loop's summary plus what the run knows: inputs skipped, accuracy, the link, the console, warnings."""
    o, cfg = plan.opts, plan.cfg
    summary.pop("results")
    if rec_manifest is not None:
        summary["recording"] = {"out": str(o.record), "streams": rec_manifest["streams"], "dropped_camera_frames": rec_manifest["dropped_camera_frames"]}
    skipped = getattr(cloud_src, "skipped", None)
    summary["skipped_inputs"] = skipped.total if skipped is not None else 0
    summary["skipped_by_reason"] = dict(skipped.counts) if skipped is not None else {}
    if evaluator is not None:
        summary["accuracy"] = evaluator.summary()
    summary.update({"localise": cfg.localise, "lidar_only": plan.lidar_only, "bundle": str(plan.bundle_path), "camera": plan.camera,
                    "lidar": plan.lidar if plan.has_clouds else None, "out": str(o.out) if o.out else None,
                    "minimap": str(o.minimap) if o.minimap else None, "team": cfg.team, "season": cfg.season})  # fmt: skip
    if plan.multi:
        summary["cameras"] = list(plan.cameras)
        summary["camera_missing_frames"] = dict(tick_detect.missing_ticks)
    warnings = list(plan.warnings)
    if link is not None:
        summary["serial"] = {"port": o.serial, **link.snapshot(), "disconnects": link.stats.disconnects, "last_error": link.stats.last_error}
        if not link.stats.connects:
            warnings.append(f"referee link {o.serial} never connected ({link.stats.last_error or 'no reply'}): nothing was sent")
    summary["warnings"] = warnings + summary.get("drift", {}).get("warnings", [])
    if console is not None:
        summary["console"] = {"url": console.server.url, "messages_sent": console.sent, "refused_requests": len(console.server.refusals), "actions": len(console.server.accepted)}
    return summary


def _live_clouds(plan: RunPlan, recorder):
    o = plan.opts
    if not plan.has_clouds:
        return None
    if any(split_named(c, "")[1].startswith("livox") for c in o.clouds):
        return live_lidars(plan.bundle, o.clouds, plan.lidar, tap=recorder.lidar if recorder else None)
    from radarcal.runtime.sources import open_clouds

    return open_clouds(o.clouds[0], o.cloud_topic)


def _multi_sources(plan: RunPlan, log: Callable):
    """Several cameras: per-camera frame streams paired into ticks, one TickDetector, the clouds."""
    from radarcal.runtime.detector import DetectionsFile
    from radarcal.runtime.multicam import TickDetector, group_by_time, group_live, replay_camera_streams
    from radarcal.runtime.sources import open_camera, prefetch_frames

    o, rep = plan.opts, plan.rep
    need_pixels = o.detector is not None and not plan.lidar_only
    if rep is not None:
        streams, det_files = replay_camera_streams(rep.root, plan.cameras, need_pixels)
        cloud_src = rep.cloud_frames() if plan.has_clouds else None
    else:
        streams = {c: open_camera(src) for c, src in plan.videos.items()}
        det_files = {}
        cloud_src = _live_clouds(plan, None)
    live = rep is None and any(s.isdigit() or "://" in s for s in plan.videos.values())
    rec = open_detector(o, log).recogniser if need_pixels else None
    if need_pixels:  # each camera decoded and letterboxed for the detector in its own thread
        streams = {c: prefetch_frames(s, latest_only=live, prepare=rec.robot.prepare_ahead) for c, s in streams.items()}
    ticks = (group_live if live else group_by_time)(streams)
    if plan.lidar_only:
        tick_detect = TickDetector(files={c: _NoBoxes() for c in plan.cameras})
    elif o.detector is not None:
        tick_detect = TickDetector(recogniser=rec, ahead=o.detect_ahead, workers=o.detect_workers)
    else:
        missing = [c for c in plan.cameras if c not in det_files]
        if missing:
            raise InputError(rep.root if rep is not None else "radarcal run", f"no detections for camera {', '.join(missing)}: give --detector model.onnx")
        tick_detect = TickDetector(files={c: DetectionsFile.read(p) for c, p in det_files.items()})
    return tick_detect, tick_detect.frames(ticks), cloud_src, tick_detect


def open_detector(o: RunOptions, log: Callable[[str], None]):
    """The robot detector (+ optional armour and number stages) as ``detect(frame)`` with ``last_timings_ms`` and
    ``frames(src)`` (detection one frame ahead in a thread); ``.recogniser``: the batched stages."""
    from radarcal.runtime.detector import OnnxDetector
    from radarcal.runtime.stages import DetectAhead, NumberClassifier, Recogniser

    from radarcal.io.detector_files import read_anchor_file, read_class_names

    anchor_cfg = read_anchor_file(o.anchors) if o.anchors is not None else None

    def names_of(p):
        return read_class_names(p) if p else None

    robot = OnnxDetector(o.detector, names_of(o.names), conf_thres=o.conf, threads=o.threads, layout=o.detector_layout, providers=o.providers, anchors=anchor_cfg,
                         names_source=o.names)  # fmt: skip
    arm = OnnxDetector(o.armour, names_of(o.armour_names), conf_thres=o.conf, threads=o.threads, providers=o.providers, names_source=o.armour_names,
                       what="armour model") if o.armour else None  # fmt: skip
    num = NumberClassifier(o.number, names_of(o.number_names), o.number_names, threads=o.threads, providers=o.providers) if o.number else None
    log(f"detector {robot.describe()}" + (f"; armour {arm.describe()}" if arm else "") + (f"; number {num.path.name}" if num else ""))
    return DetectAhead(Recogniser(robot, arm, num), workers=o.detect_workers)


class _NoBoxes:
    def lookup(self, t: float, frame: str | None = None) -> list:
        return []


def live_lidars(b, specs: list[str], primary: str | None, tap=None):
    """Start every live LiDAR (``[NAME=]livox://IP``); clouds move into the frame of ``primary`` through the bundle."""

    from radarcal.io.livox import open_livox
    from radarcal.runtime.replay import LiveClouds

    sources, T = {}, {}
    try:
        for i, spec in enumerate(specs):
            name, url = split_named(spec, primary if i == 0 and primary else f"lidar{i}")
            if primary and name != primary:
                if not b.has_T(primary, name):
                    raise InputError(b.path, f"no extrinsic between {primary!r} and {name!r} (T_{primary}_{name}) for the second LiDAR")
                T[name] = b.T(primary, name)
            sources[name] = open_livox(url, sensor=name, packet_tap=tap)
    except Exception:
        for s in sources.values():
            s.close()
        raise
    return LiveClouds(sources, T)


def health_text(health: dict[str, dict]) -> str:
    """Status-line part of the sensors' health: rate, silence (ground-ray fallback), drops, reconnects."""
    parts = []
    for name, h in health.items():
        age = h.get("last_seen_age_s")
        if "rate_pts_s" not in h:  # a camera
            if h["state"] != "streaming" or (age is not None and age > 0.5):
                parts.append(f"{name} {h['state'].upper()} {'-' if age is None else f'{age:.1f}s'} reconn {h['reconnects']}")
            elif h["reconnects"]:
                parts.append(f"{name} ok reconn {h['reconnects']}")
            continue
        if age is None or age > 1.0:
            parts.append(f"{name} SILENT {'-' if age is None else f'{age:.1f}s'} (ground-ray fallback)")
        else:
            parts.append(f"{name} {h['rate_pts_s'] / 1000:.0f}k pts/s")
        if h.get("drops") or h.get("reconnects") or h.get("bad_packets") or h.get("truncated_packets"):
            parts[-1] += f" drops {h['drops']} reconn {h['reconnects']} bad {h['bad_packets'] + h['truncated_packets']}"
    return (" | " + " | ".join(parts)) if parts else ""
