"""``radarcal run`` (match-time localisation loop) and ``radarcal hero-offset`` (per-match hero range offset)."""

from __future__ import annotations

from pathlib import Path

import typer

from radarcal.cli.marking_options import DvAtOpt, DvEnemiesInHalfOpt, DvOnDartOpt, DvOnKeyOpt, GuessOpt, RosterOpt, marking_overrides
from radarcal.cli.common import BundleOpt, CloudTopicOpt, JsonOpt, ReplayBundleOpt, command_line, emit, err_console
from radarcal.cli.outputs import check_outputs
from radarcal.cli.run_checks import HERO_MAX_SPREAD_M, check_serial_port, check_season, hero_spread_problem, run_warnings
from radarcal.errors import InputError

__all__ = ["run", "hero_offset", "compute_hero_offset"]


def run(
    bundle: ReplayBundleOpt = None,
    replay: Path = typer.Option(None, "--replay", help="A recording (`radarcal record`) or a replay folder (images/, clouds/, detections.jsonl) as written by `radarcal synth field`."),
    video: str = typer.Option(None, "--video", help="Camera: video file, image folder, device index or URL."),
    clouds: list[str] = typer.Option(None, "--clouds", help="LiDAR: folder of PCD/npy/bin, ROS1/ROS2 bag, or a live Livox [NAME=]livox://IP (livox1:// SDK 1, livox2:// SDK 2; repeat for several LiDARs, merged in the frame of --lidar)."),
    cloud_topic: CloudTopicOpt = None,
    cloud_offset: str = typer.Option("0", "--cloud-time-offset", help="Camera clock minus LiDAR clock, seconds (t_camera = t_cloud + offset; 0: one clock, e.g. a replay "
                                     "or a bag with both topics), or 'first': the first cloud pairs with the first frame."),
    detector: Path = typer.Option(None, "--detector", help="Robot detector ONNX (YOLOv5, YOLOv8/YOLO11/YOLOv12, end-to-end or raw heads)."),
    names: Path = typer.Option(None, "--names", help="Robot class names: YOLO data.yaml, text file, JSON/YAML list (default: the model's metadata)."),
    detector_layout: str = typer.Option(None, "--detector-layout", help="Output layout yolov5|yolov8|end2end|raw (default: from the graph)."),
    anchors: Path = typer.Option(None, "--anchors", help="Raw-head layout: YAML with anchors: (and strides:), e.g. the YOLOv5 model YAML."),
    armour: Path = typer.Option(None, "--armour", help="Armour detector ONNX run on each robot crop (grey/dead class marks the robot dead)."),
    armour_names: Path = typer.Option(None, "--armour-names", help="Armour class names file (default: the model's metadata)."),
    number: Path = typer.Option(None, "--number", help="Number classifier ONNX run on each armour crop (on each robot crop without --armour)."),
    number_names: Path = typer.Option(None, "--number-names", help="Number class names file (default: the model's metadata)."),
    providers: str = typer.Option("cpu", "--providers", help="onnxruntime providers in order, e.g. tensorrt,cuda,cpu (needs onnxruntime-gpu)."),
    detect_ahead: bool = typer.Option(True, "--detect-ahead/--no-detect-ahead", help="Run the detector one frame ahead in a thread (throughput; +1 frame latency)."),
    conf: float = typer.Option(0.25, "--conf", help="Detector confidence threshold."),
    threads: int = typer.Option(0, "--threads", help="onnxruntime intra-op threads per model (0 = its default)."),
    detections: Path = typer.Option(None, "--detections", help="Precomputed detections (JSON lines, one per frame)."),
    serial: str = typer.Option(None, "--serial", help="Referee serial port, e.g. /dev/ttyUSB0 (115200 8N1); replaying a recording also 'pty' (a new pseudo-terminal) or 'dry-run' (default)."),
    out: Path = typer.Option(None, "--out", help="Per-frame JSON lines (robots in field coordinates)."),
    minimap: Path = typer.Option(None, "--minimap", help="Minimap output: .png (last frame + trails) or .mp4."),
    camera: str = typer.Option(None, "--camera", help="Camera name in the bundle (default: the only one)."),
    lidar: str = typer.Option(None, "--lidar", help="LiDAR name in the bundle (default: the only one with an extrinsic)."),
    team: str = typer.Option(None, "--team", help="Our colour red|blue (default: bundle runtime.team, then the referee link)."),
    season: int = typer.Option(None, "--season", help="Referee protocol season (0x0305 layout, rate limits); default bundle runtime.referee_season."),
    sentry_xy: str = typer.Option(None, "--sentry-xy", help="Our sentry's field position X,Y (m) when it is not tracked."),
    max_frames: int = typer.Option(None, "--max-frames", help="Stop after this many frames."),
    record: Path = typer.Option(None, "--record", help="Live run: also record every input (LiDAR packets, camera frames, serial bytes) into this new folder (replay: --replay)."),
    realtime_video: bool = typer.Option(False, "--realtime-video", help="Play a --video file at its frame rate with receive times, as a live camera (station tests)."),
    no_lidar: bool = typer.Option(False, "--no-lidar", help="Ignore clouds (ground-ray localisation only)."),
    localise: str = typer.Option("auto", "--localise", help="auto (LiDAR tracks + box fallback) | lidar (LiDAR tracks only) | box (box depth, the 2022 way)."),
    no_camera: bool = typer.Option(False, "--no-camera", help="Ignore detections: LiDAR only (every track unlabelled)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No status line."),
    ui: str = typer.Option(None, "--ui", help="Serve the live operator console on [HOST:]PORT (default host 127.0.0.1; docs/console.md)."),
    speed: float = typer.Option(None, "--speed", help="Replay at this multiple of real time (default: 1 with --ui, else as fast as possible; 0 = unpaced)."),
    field_pose: str = typer.Option("auto", "--field-pose", help="Camera field pose: chain (lidar-field T_field_lidar · T_lidar_cam), pnp (field-pnp), auto (chain when lidar-field converged, else pnp)."),
    roster: RosterOpt = True,
    guess: GuessOpt = True,
    dv_at: DvAtOpt = None,
    dv_enemies_in_half: DvEnemiesInHalfOpt = None,
    dv_on_key: DvOnKeyOpt = None,
    dv_on_dart: DvOnDartOpt = False,
    as_json: JsonOpt = False,
) -> None:
    """Localise robots on the field from camera + LiDAR, track them, draw the minimap, talk to the referee system."""
    from radarcal.bundle import load_bundle
    from radarcal.runtime.detector import DetectionsFile
    from radarcal.io.recording import is_recording
    from radarcal.runtime.loop import OnlineEvaluator, Pipeline, RunConfig, pick_frames
    from radarcal.runtime.loop import run as run_loop
    from radarcal.runtime.sources import merge_by_time, open_camera, open_clouds, open_replay, prefetch_frames
    from radarcal.runtime.loop import cloud_frames_as_pairs

    clouds = list(clouds or [])
    lidar_only = no_camera or (replay is None and video is None and bool(clouds))
    if replay is not None and video is not None or (replay is None and video is None and not clouds):
        raise InputError("radarcal run", "give exactly one of --replay DIR or --video SRC (or --clouds SRC alone: LiDAR only)")
    if localise not in ("auto", "lidar", "box"):
        raise InputError("--localise", f"expected auto, lidar or box, got {localise!r}")
    if lidar_only and (no_lidar or localise == "box"):
        raise InputError("--no-camera", "LiDAR-only needs the clouds and --localise auto or lidar")
    marking_cfg = marking_overrides(roster, guess, dv_at, dv_enemies_in_half, dv_on_key, dv_on_dart)
    if replay is not None and is_recording(replay):
        from radarcal.cli.run_recording import run_recording

        return run_recording(replay, bundle=bundle, speed=speed or 0.0, detector=detector, names=names, conf=conf, threads=threads, detections=detections, serial=serial,
                             out=out, minimap=minimap, camera=camera, lidar=lidar, team=team, season=season, max_frames=max_frames, no_lidar=no_lidar,
                             quiet=quiet, as_json=as_json, sentry_xy=sentry_xy, marking=marking_cfg)  # fmt: skip
    if record is not None and replay is not None:
        raise InputError("--record", "records live inputs: not with --replay")
    live_multi = len(clouds) > 1
    if live_multi and not all("://" in c for c in clouds):
        raise InputError("--clouds", "several --clouds are for live LiDARs (NAME=livox://IP ...)")
    if detector is not None and detections is not None:
        raise InputError("radarcal run", "give at most one of --detector and --detections")
    if team is not None and team not in ("red", "blue"):
        raise InputError("--team", f"expected red or blue, got {team!r}")
    offset = _cloud_offset(cloud_offset)
    rep = open_replay(replay) if replay is not None else None
    if bundle is None:
        if rep is None or rep.bundle is None:
            raise InputError("--bundle", "required (the replay has no calib.yaml)")
        bundle = rep.bundle
    b = load_bundle(bundle)
    has_clouds = not no_lidar and ((rep is not None and bool(rep.clouds)) or bool(clouds))
    cam_name, lidar_name = pick_frames(b, camera or (rep.meta.get("camera") if rep else None), lidar or (rep.meta.get("lidar") if rep and has_clouds else None), has_clouds)
    sxy = None
    if sentry_xy:
        try:
            sxy = tuple(float(v) for v in sentry_xy.split(","))
        except ValueError:
            sxy = ()
        if len(sxy) != 2:
            raise InputError("--sentry-xy", f"expected X,Y in metres, got {sentry_xy!r}")
    timing = {}
    meta = rep.meta if rep is not None else {}
    if "cloud_sweep_s" in meta:  # the replay says when its clouds were fired and delivered
        timing = {"cloud_sweep_s": float(meta["cloud_sweep_s"]), "cloud_latency_s": float(meta.get("cloud_latency_s", 0.0))}
    elif str(meta.get("generator", "")).startswith("radarcal synth field"):  # robots frozen at the cloud stamp
        timing = {"cloud_sweep_s": 0.0, "cloud_latency_s": 0.0}
    cfg = RunConfig.from_bundle(b, team=team, season=season, sentry_xy=sxy, localise="lidar" if lidar_only else localise, **timing, **marking_cfg)
    check_season(cfg.season, "--season" if season is not None else f"{bundle}: runtime.referee_season")
    check_outputs(bundle, [("track file", out), ("minimap", minimap)], b, inputs=[detections, rep.detections if rep else None, rep.truth if rep else None])
    if serial:
        check_serial_port(serial)
    from radarcal.verdicts import forced_entries

    warnings = run_warnings(has_clouds, no_lidar, replay is not None) + [f"bundle {w}" for w in forced_entries(b)]
    for w in warnings:
        err_console.print(f"warning: {w}", style="yellow")
    from radarcal.cli.lidar_field_cmd import resolve_field_pose

    T_fc, _pose_src = resolve_field_pose(b, cam_name, lidar_name, field_pose)
    if T_fc is not None:  # in memory only (run never saves the bundle): the Pipeline reads bundle.T("field", cam)
        b.set_transform("field", cam_name, T_fc, method=f"run --field-pose {field_pose}: {_pose_src}")
    pipe = Pipeline(b, cam_name, lidar_name if has_clouds else None, cfg)

    if detector is None and (armour is not None or number is not None):
        raise InputError("--armour" if armour is not None else "--number", "needs --detector (the robot detector)")
    if lidar_only:
        detect = lambda f: []  # noqa: E731
    elif detector is not None:
        detect = _open_detector(detector, names, detector_layout, anchors, armour, armour_names, number, number_names, providers, conf, threads)
    else:
        det_path = detections or (rep.detections if rep else None)
        if det_path is None:
            raise InputError("radarcal run", "no detector: give --detector model.onnx or --detections FILE (or a replay with detections.jsonl)")
        dfile = DetectionsFile.read(det_path)
        detect = lambda f: dfile.lookup(f.t, f.name)  # noqa: E731

    recorder = camera_health = None
    if rep is not None:
        frames = rep.camera_frames(need_pixels=detector is not None and not lidar_only)
        cloud_src = rep.cloud_frames() if has_clouds else None
    elif video is None:  # --clouds alone: one frame per cloud
        cloud_src = open_clouds(clouds[0], cloud_topic)
        frames = None
    else:
        from radarcal.runtime.replay import paced_video, start_recording

        frames = paced_video(video) if realtime_video else open_camera(video)
        camera_health = getattr(frames, "snapshot", None)
        recorder = start_recording(record, b, cam_name, video, clouds) if record is not None else None
        cloud_src = None
        if has_clouds and any(c.partition("=")[2 if "=" in c.split("://")[0] else 0].startswith("livox") for c in clouds):
            cloud_src = live_lidars(b, clouds, lidar_name, tap=recorder.lidar if recorder else None)
        elif has_clouds:
            cloud_src = open_clouds(clouds[0], cloud_topic)
    if detector is not None and frames is not None and not lidar_only:  # the pixels are needed: decode them ahead in a thread (live sources: newest frame only)
        live = video is not None and (video.isdigit() or "://" in video)
        frames = prefetch_frames(frames, latest_only=live)
        if detect_ahead:
            frames = detect.frames(frames)
    if rep is None and recorder is not None:
        from radarcal.runtime.replay import recorded

        frames = recorded(frames, recorder, cam_name)
    link = None
    if serial:
        from radarcal.runtime.serial_link import SerialLink

        factory = None
        if rep is None and recorder is not None:
            from radarcal.runtime.replay import tapped_serial

            factory = tapped_serial(recorder)
        link = SerialLink(serial, season=cfg.season, serial_factory=factory).start()
    from radarcal.runtime.marking import Marking

    marking = Marking(cfg, field_length_m=pipe.field_model.size[0] if pipe.field_model is not None else 28.0) if link is not None else None
    evaluator = OnlineEvaluator(rep.truth) if rep is not None and rep.truth is not None else None
    pairs = merge_by_time(frames, cloud_src, offset) if frames is not None else cloud_frames_as_pairs(cloud_src, offset if isinstance(offset, float) else 0.0)
    on_frame, console = evaluator, None
    if ui is not None or speed:
        from radarcal.runtime.console.live import chain_callbacks, paced, start_console

        pairs = paced(pairs, speed if speed is not None else 1.0) if rep is not None else pairs
        if ui is not None:
            console = start_console(ui, pipe, b, cam_name, lidar_name if has_clouds else None, {"camera": cam_name, "team": cfg.team, "hero_range_offset_m": cfg.hero_range_offset_m})
            pairs, detect, on_frame = console.observe_pairs(pairs), console.observe_detect(detect), chain_callbacks(evaluator, console.on_frame)
            if marking is not None:
                console.on_action("double_vulnerability", marking.operator_dv)
            for name, src in (("serial", link and link.snapshot), ("clouds", getattr(cloud_src, "health", None))):
                if callable(src):
                    console.add_health(name, src)
    try:
        def sensors_health() -> dict:
            h = dict(cloud_src.sensors_health()) if hasattr(cloud_src, "sensors_health") else {}
            if camera_health is not None:
                h[cam_name] = camera_health()
            return h

        extra = (lambda: health_text(sensors_health())) if hasattr(cloud_src, "sensors_health") or camera_health else None
        summary = run_loop(pipe, pairs, detect, out, minimap, link, status=not quiet and not as_json, max_frames=max_frames, on_frame=on_frame, status_extra=extra, marking=marking)
        if extra is not None:
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

            rec_manifest = finish_recording(recorder, cloud_src, serial)
    summary.pop("results")
    if recorder is not None:
        summary["recording"] = {"out": str(record), "streams": rec_manifest["streams"], "dropped_camera_frames": rec_manifest["dropped_camera_frames"]}
    skipped = getattr(cloud_src, "skipped", None)
    summary["skipped_inputs"] = skipped.total if skipped is not None else 0
    summary["skipped_by_reason"] = dict(skipped.counts) if skipped is not None else {}
    if evaluator is not None:
        summary["accuracy"] = evaluator.summary()
    summary.update({"localise": cfg.localise, "lidar_only": lidar_only, "bundle": str(bundle), "camera": cam_name, "lidar": lidar_name if has_clouds else None, "out": str(out) if out else None,
                    "minimap": str(minimap) if minimap else None, "team": cfg.team, "season": cfg.season})  # fmt: skip
    if link is not None:
        summary["serial"] = {"port": serial, **link.snapshot(), "disconnects": link.stats.disconnects, "last_error": link.stats.last_error}
        if not link.stats.connects:
            warnings.append(f"referee link {serial} never connected ({link.stats.last_error or 'no reply'}): nothing was sent")
    summary["warnings"] = warnings
    if console is not None:
        summary["console"] = {"url": console.server.url, "messages_sent": console.sent, "refused_requests": len(console.server.refusals), "actions": len(console.server.accepted)}

    def human(s: dict) -> None:
        typer.echo(f"{s['frames']} frames in {s['wall_s']:.1f} s ({s['fps']:.1f} FPS), {s['clouds']} clouds; camera {s['camera']}, lidar {s['lidar'] or '-'}")
        lat = s["latency_ms"]
        typer.echo("  latency ms (median / p95): " + ", ".join(f"{k} {v['median']:.2f}/{v['p95']:.2f}" for k, v in lat.items()))
        rf = s["robot_frames"]
        typer.echo(f"  robot positions: {rf.get('depth', 0)} from LiDAR depth, {rf.get('ground', 0)} from the ground ray, {rf.get('predicted', 0)} predicted")
        acc = s.get("accuracy")
        if acc and acc["median_m"] is not None:
            typer.echo(f"  vs truth: {acc['located']}/{acc['visible']} visible robots located; error median {acc['median_m']:.3f} m, p95 {acc['p95_m']:.3f} m, max {acc['max_m']:.3f} m")
            typer.echo(f"  right label within 0.6 m {acc['right_within_0.6m_pct']:.1f} %, false robots {acc['false_per_frame']:.3f} per frame, wrong label "
                       f"{acc['wrong_label_pct'] or 0:.2f} %, any track within 0.3 m of a LiDAR-seen robot {acc['lidar_within_0.3m_pct'] or 0:.1f} %, longest ghost {acc['longest_ghost_s']:.2f} s")
        elif acc:
            typer.echo(f"  vs truth: any track within 0.3 m of a LiDAR-seen robot {acc['lidar_within_0.3m_pct'] or 0:.1f} %, false robots {acc['false_per_frame']:.3f} per frame, longest ghost {acc['longest_ghost_s']:.2f} s")
        if s.get("bad_frames") or s.get("skipped_inputs"):
            typer.echo(f"  skipped: {s['bad_frames']} unreadable frames, {s['skipped_inputs']} unreadable clouds/messages (warnings on stderr)")
        if s.get("out"):
            typer.echo(f"  tracks -> {s['out']}")
        if s.get("minimap"):
            typer.echo(f"  minimap -> {s['minimap']}")
        if s.get("serial"):
            q = s["serial"]
            typer.echo(f"  referee link {q['port']}: {q.get('sent', 0)} frames sent, {q['disconnects']} disconnects{', last error ' + q['last_error'] if q['last_error'] else ''}")
        for w in s["warnings"]:
            typer.echo(f"  warning: {w}")

    emit(summary, as_json, human)


def _open_detector(detector, names, layout, anchors, armour, armour_names, number, number_names, providers, conf, threads):
    """The robot detector (+ optional armour and number stages) as ``detect(frame)`` with ``last_timings_ms`` and
    ``frames(src)`` (detection one frame ahead in a thread)."""
    from radarcal.runtime.detector import OnnxDetector, read_class_names
    from radarcal.runtime.stages import DetectAhead, NumberClassifier, Recogniser

    anchor_cfg = None
    if anchors is not None:
        import yaml

        from radarcal.errors import read_text

        try:
            anchor_cfg = yaml.safe_load(read_text(anchors, "anchor config"))
        except yaml.YAMLError:
            raise InputError(anchors, "anchor config: not valid YAML") from None
        if not isinstance(anchor_cfg, dict) or "anchors" not in anchor_cfg:
            raise InputError(anchors, "anchor config: expected a mapping with anchors:")

    def names_of(p):
        return read_class_names(p) if p else None

    robot = OnnxDetector(detector, names_of(names), conf_thres=conf, threads=threads, layout=layout, providers=providers, anchors=anchor_cfg, names_source=names)
    arm = OnnxDetector(armour, names_of(armour_names), conf_thres=conf, threads=threads, providers=providers, names_source=armour_names,
                       what="armour model") if armour else None  # fmt: skip
    num = NumberClassifier(number, names_of(number_names), number_names, threads=threads, providers=providers) if number else None
    err_console.print(f"detector {robot.describe()}" + (f"; armour {arm.describe()}" if arm else "") + (f"; number {num.path.name}" if num else ""),
                      highlight=False, markup=False)  # fmt: skip
    return DetectAhead(Recogniser(robot, arm, num))


def _cloud_offset(text: str) -> float | str:
    """``--cloud-time-offset``: seconds, or ``first``."""
    import math

    if text.strip().lower() == "first":
        return "first"
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise InputError("--cloud-time-offset", f"expected seconds or 'first', got {text!r}")
    return v


def compute_hero_offset(measured_m: float, actual_m: float) -> float:
    """The fixed per-match correction: actual - measured (added to every later hero range)."""
    return float(actual_m) - float(measured_m)


def hero_offset(
    bundle: BundleOpt = ...,
    measured: float = typer.Option(None, "--measured", help="Hero -> enemy outpost distance radarcal reported (m, without offset)."),
    actual: float = typer.Option(None, "--actual", help="The true distance (m)."),
    replay: Path = typer.Option(None, "--replay", help="Instead of --measured: a short recording (replay folder) with our hero standing at a known point."),
    marker: str = typer.Option(None, "--marker", help="With --replay, instead of --actual: the field landmark the hero stands at."),
    team: str = typer.Option(None, "--team", help="Our colour red|blue (default: bundle runtime.team)."),
    max_spread: float = typer.Option(HERO_MAX_SPREAD_M, "--max-spread", help="With --replay: refuse when the hero range spreads more than this (m, 10-90 %) over the recording."),
    force: bool = typer.Option(False, "--force", help="Store the offset even when the recording's hero range spread says the hero moved."),
    as_json: JsonOpt = False,
) -> None:
    """Store the per-match hero range offset (actual - measured) in the bundle (runtime.hero_range_offset_m)."""
    import math

    import numpy as np

    from radarcal.bundle import load_bundle, save_bundle

    if (measured is None) == (replay is None):
        raise InputError("radarcal hero-offset", "give exactly one of --measured M or --replay DIR")
    if (actual is None) == (marker is None):
        raise InputError("radarcal hero-offset", "give exactly one of --actual A or --marker LANDMARK")
    if marker is not None and replay is None:
        raise InputError("--marker", "needs --replay (a recording with the hero at the marker)")
    if not max_spread > 0:
        raise InputError("--max-spread", f"must be > 0 m, got {max_spread}")
    b = load_bundle(bundle)
    team = team or str(b.runtime.get("team", "red"))
    if team not in ("red", "blue"):
        raise InputError("--team", f"expected red or blue, got {team!r}")
    extra = {}
    if replay is not None:
        measured, extra = _hero_range_from_recording(b, replay, team)
        if marker is not None:
            fm = b.field()
            if fm is None:
                raise InputError(bundle, "no field model in the bundle (needed for --marker)")
            enemy = "blue" if team == "red" else "red"
            for name in (marker, f"{enemy}_outpost"):
                if name not in fm.landmarks:
                    raise InputError("--marker", f"no landmark {name!r} in the field model ({', '.join(sorted(fm.landmarks))})")
            actual = float(np.linalg.norm(fm.landmarks[marker][:2] - fm.landmarks[f"{enemy}_outpost"][:2]))
    for name, v in (("--measured", measured), ("--actual", actual)):
        if not math.isfinite(v) or v <= 0 or v > 60:
            raise InputError(name, f"expected a distance in metres (0..60], got {v}")
    problem = hero_spread_problem(extra["measured_spread_m"], max_spread) if replay is not None else None
    if problem and not force:
        raise InputError(replay, f"{problem}; nothing stored (--force to store it anyway)")
    if problem:
        extra["warnings"] = [problem]
        err_console.print(f"warning: {problem} (stored because of --force)", style="yellow")
    old = float(b.runtime.get("hero_range_offset_m", 0.0))
    off = compute_hero_offset(measured, actual)
    b.runtime["hero_range_offset_m"] = off
    b.runtime.pop("hero_range_offset_forced", None)
    if problem:
        b.runtime["hero_range_offset_forced"] = problem
    b.runtime["hero_range_offset_note"] = f"{command_line()}"
    save_bundle(b, bundle)
    emit({"bundle": str(bundle), "hero_range_offset_m": off, "previous_m": old, "measured_m": measured, "actual_m": actual, **extra}, as_json,
         lambda s: typer.echo(f"hero range offset {s['hero_range_offset_m']:+.3f} m (actual {s['actual_m']:.3f} - measured {s['measured_m']:.3f}) "
                              f"stored in {s['bundle']} (was {s['previous_m']:+.3f} m)"))  # fmt: skip


def _hero_range_from_recording(b, replay: Path, team: str) -> tuple[float, dict]:
    """Median hero -> enemy outpost range (without offset) over a recording, with its spread."""
    import numpy as np

    from radarcal.runtime.detector import DetectionsFile
    from radarcal.runtime.loop import Pipeline, RunConfig, pick_frames
    from radarcal.runtime.loop import run as run_loop
    from radarcal.runtime.sources import merge_by_time, open_replay

    rep = open_replay(replay)
    if rep.detections is None:
        raise InputError(replay, "the recording has no detections.jsonl")
    cam, lidar = pick_frames(b, rep.meta.get("camera"), rep.meta.get("lidar") if rep.clouds else None, bool(rep.clouds))
    pipe = Pipeline(b, cam, lidar, RunConfig.from_bundle(b, team=team, hero_range_offset_m=0.0))
    dets = DetectionsFile.read(rep.detections)
    ranges: list[float] = []
    run_loop(pipe, merge_by_time(rep.camera_frames(), rep.cloud_frames() if lidar else None), lambda f: dets.lookup(f.t, f.name), status=False,
             on_frame=lambda n, res: ranges.append(res.hero_range_m) if res.hero_range_m is not None else None)  # fmt: skip
    if len(ranges) < 5:
        raise InputError(replay, f"our hero ({team}_1) was located in only {len(ranges)} frames")
    r = np.asarray(ranges)
    return float(np.median(r)), {"frames_with_hero": len(r), "measured_spread_m": float(np.percentile(r, 90) - np.percentile(r, 10))}


def live_lidars(b, specs: list[str], primary: str | None, tap=None):
    """Start every live LiDAR (``[NAME=]livox://IP``); clouds move into the frame of ``primary`` through the bundle."""
    from radarcal.cli.record_cmd import split_named
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


_ = err_console  # stderr console kept for symmetry with other commands
