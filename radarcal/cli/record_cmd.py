"""``radarcal record``: record a match's raw inputs (LiDAR packets, camera frames, referee serial bytes) for replay."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from radarcal.cli.common import JsonOpt, emit
from radarcal.errors import InputError
from radarcal.io.source_specs import split_named

__all__ = ["record"]


def record(
    out: Path = typer.Argument(..., help="Recording folder to create (must not exist or be empty)."),
    clouds: list[str] = typer.Option(None, "--clouds", help="LiDAR [NAME=]livox://IP | livox1://IP | livox2://IP (repeat for several; names default lidar0, lidar1 ...)."),
    video: str = typer.Option(None, "--video", help="Camera: device index, URL, or a video file (read at its frame rate)."),
    camera: str = typer.Option("cam0", "--camera", help="Name of the camera in the recording (as in the bundle)."),
    serial: str = typer.Option(None, "--serial", help="Referee serial port (e.g. /dev/ttyUSB0 or a /dev/pts/N pseudo-terminal)."),
    bundle: Path = typer.Option(None, "--bundle", "-b", help="Bundle in use (its path and sha256 go into the manifest)."),
    duration: float = typer.Option(None, "--duration", help="Stop after this many seconds (default: Ctrl-C, or the end of a video file)."),
    jpeg_quality: int = typer.Option(90, "--jpeg-quality", help="JPEG quality of the recorded frames."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No status line."),
    as_json: JsonOpt = False,
) -> None:
    """Record raw LiDAR packets, camera frames (JPEG) and serial bytes with host receive times (replay: `radarcal run --replay OUT`)."""
    import sys

    from radarcal.io import clock
    from radarcal.io.livox import open_livox, parse_livox_url
    from radarcal.io.recording import Recorder, TapSerial

    if not clouds and not video and not serial:
        raise InputError("radarcal record", "nothing to record: give --clouds, --video and/or --serial")
    if bundle is not None and not bundle.is_file():
        raise InputError(bundle, "bundle not found")
    if not 1 <= jpeg_quality <= 100:
        raise InputError("--jpeg-quality", "expected 1..100")
    named = [split_named(c, f"lidar{i}") for i, c in enumerate(clouds or [])]
    for name, spec in named:
        o = parse_livox_url(spec)
        if o["listen_port"] is not None:
            raise InputError(spec, "record starts the LiDAR itself: give livox://IP (no port)")
    if len({n for n, _ in named}) != len(named):
        raise InputError("--clouds", "two LiDARs with the same name")
    cap_file = None
    if video is not None and not (video.isdigit() or "://" in video):
        import cv2

        if not Path(video).is_file():
            raise InputError(video, "video file not found")
        cap_file = cv2.VideoCapture(video)
        if not cap_file.isOpened():
            raise InputError(video, "cannot open video")
    sensors = [{"name": n, "kind": "lidar", "url": s} for n, s in named]
    if video is not None:
        sensors.append({"name": camera, "kind": "camera", "source": video})
    rec = Recorder(out, sensors, bundle, jpeg_quality=jpeg_quality)
    lidars = {}
    link = cam = None
    try:
        for n, s in named:
            lidars[n] = open_livox(s, sensor=n, packet_tap=rec.lidar)
        if serial:
            from radarcal.runtime.serial_link import SerialLink

            def factory(port, baud):
                import serial as pyserial

                return TapSerial(pyserial.Serial(port, baud, timeout=0, write_timeout=0.2), rec.serial)

            link = SerialLink(serial, serial_factory=factory).start()
        if video is not None and cap_file is None:
            from radarcal.io.camera_live import LiveCamera

            cam = iter(LiveCamera(video, name=camera))
        fps = (cap_file.get(5) or 30.0) if cap_file is not None else None  # CAP_PROP_FPS
        t0 = time.monotonic()
        n_frames = 0
        last_status = 0.0
        next_file_frame = t0
        while duration is None or time.monotonic() - t0 < duration:
            if cap_file is not None:
                now = time.monotonic()
                if now < next_file_frame:
                    time.sleep(min(0.005, next_file_frame - now))
                    continue
                ok, img = cap_file.read()
                if not ok:
                    break
                rec.camera(camera, clock.now(), f"{n_frames:06d}", img)
                n_frames += 1
                next_file_frame += 1.0 / fps
            elif cam is not None:
                f = next(cam)
                if not getattr(f, "stalled", False):
                    rec.camera(camera, f.t, f.name, f.load())
                    n_frames += 1
            else:
                time.sleep(0.05)
            now = time.monotonic()
            if not quiet and not as_json and now - last_status > 2.0:
                last_status = now
                parts = [f"{n} {h['state']} {h['rate_pts_s'] / 1000:.0f}k pts/s drops {h['drops']}" for n, h in ((n, s.snapshot()) for n, s in lidars.items())]
                sys.stderr.write(f"rec {now - t0:6.1f}s | frames {n_frames} (dropped {rec.dropped_frames}) | " + " | ".join(parts) + "\n")
    except KeyboardInterrupt:
        pass
    finally:
        for s in lidars.values():
            s.close()
        if link is not None:
            link.close()
        if cap_file is not None:
            cap_file.release()
        health = {n: s.snapshot() for n, s in lidars.items()}
        for s in sensors:
            if s["kind"] == "lidar":
                s.update({"sdk": health[s["name"]]["sdk"], "device": health[s["name"]]["device"], "frame_s": lidars[s["name"]].frame_s})
        if serial:
            sensors.append({"name": "referee", "kind": "serial", "port": serial})
        man = rec.close({"health": health, "camera_frames": n_frames if video else 0})
    mb = sum(c["bytes"] for c in man["streams"].values()) / 1e6
    summary = {"out": str(out), "duration_s": man["duration_s"], "streams": man["streams"], "megabytes": mb, "dropped_camera_frames": man["dropped_camera_frames"],
               "lidars": health}  # fmt: skip
    emit(summary, as_json, lambda s: typer.echo(f"recorded {out}: {s['duration_s'] or 0:.1f} s, {mb:.1f} MB, " + ", ".join(f"{k} {v['records']}" for k, v in s["streams"].items())
                                                + f"; camera frames dropped {s['dropped_camera_frames']}"))  # fmt: skip
