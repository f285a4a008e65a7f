"""Wiring of live and recorded match inputs for ``radarcal run`` / ``radarcal record``: several LiDARs merged into one
cloud stream in a common frame, recorded camera frames, and a referee link that replays the recorded serial input
while sending its output to a real port, a pseudo-terminal, or nowhere (dry run)."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator

import numpy as np

from radarcal.io.clouds import Cloud
from radarcal.runtime import referee as rp
from radarcal.runtime.sources import CameraFrame

__all__ = ["LiveClouds", "PtyPort", "ReplayLink", "open_output_port", "recorded_frames", "to_frame"]


def to_frame(c: Cloud, T_common_sensor: np.ndarray | None) -> Cloud:
    """The cloud in the common LiDAR frame (``p_common = T_common_sensor @ p_sensor``)."""
    if T_common_sensor is None:
        return c
    R, t = T_common_sensor[:3, :3].astype(np.float32), T_common_sensor[:3, 3].astype(np.float32)
    return Cloud((c.points @ R.T + t).astype(np.float32), c.intensity, c.t, c.ring, c.sensor, c.name)


class LiveClouds:
    """Several live sources polled as one (clouds moved into the common frame), with their health."""

    def __init__(self, sources: dict[str, object], T_common: dict[str, np.ndarray | None]):
        self.sources, self.T = sources, T_common

    def poll(self) -> list[Cloud]:
        out = [to_frame(c, self.T.get(n)) for n, s in self.sources.items() for c in s.poll()]
        return sorted(out, key=lambda c: c.t)

    def close(self) -> None:
        for s in self.sources.values():
            s.close()

    def sensors_health(self) -> dict[str, dict]:
        return {n: s.snapshot() for n, s in self.sources.items()}


def merged_recorded_clouds(clouds: Iterable[Cloud], T_common: dict[str, np.ndarray | None]) -> Iterator[Cloud]:
    for c in clouds:
        yield to_frame(c, T_common.get(c.sensor))


def recorded_frames(rec, camera: str) -> Iterator[CameraFrame]:
    from radarcal.io.images import decode_image

    for i, (t, name, jpg) in enumerate(rec.camera_frames(camera)):
        yield CameraFrame(t, name, (lambda b=jpg: decode_image(b)), i)


class PtyPort:
    """A pseudo-terminal whose master end radarcal writes to (pyserial-like); another program opens :attr:`name`."""

    def __init__(self):
        import tty

        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.name = os.ttyname(self._slave)
        os.set_blocking(self.master, False)

    @property
    def in_waiting(self) -> int:
        return 0

    def read(self, n: int = 1) -> bytes:
        return b""

    def write(self, b: bytes) -> int:
        try:
            return os.write(self.master, b)
        except BlockingIOError:
            return len(b)  # nobody reads the other end: bytes dropped, like an unplugged cable

    def flush(self) -> None:
        pass

    def close(self) -> None:
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass


class _DryPort:
    name = "dry-run"
    in_waiting = 0

    def read(self, n: int = 1) -> bytes:
        return b""

    def write(self, b: bytes) -> int:
        return len(b)

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


def open_output_port(spec: str | None):
    """``None`` / ``dry-run``: frames counted, not sent; ``pty``: a new pseudo-terminal; else a serial device."""
    if spec in (None, "", "dry-run"):
        return _DryPort()
    if spec == "pty":
        p = PtyPort()
        sys.stderr.write(f"referee output on pseudo-terminal {p.name}\n")
        return p
    return None  # a real port: SerialLink opens it


class ReplayLink:
    """The loop's referee link during a replay: the referee state comes from the recorded received bytes (fed up to
    each frame's time by :meth:`advance`), what the loop sends goes through ``out`` (a SerialLink on a real port or
    pseudo-terminal, or a dry run)."""

    def __init__(self, rx_records: list[tuple[float, bytes]], out=None):
        self.rx = rx_records
        self._i = 0
        self.parser = rp.FrameParser()
        self.state = rp.RefereeState()
        self.out = out
        self.sent = 0
        self.received = 0

    def advance(self, t: float) -> None:
        while self._i < len(self.rx) and self.rx[self._i][0] <= t:
            for f in self.parser.feed(self.rx[self._i][1]):
                self.state.update(f)
                self.received += 1
            self._i += 1

    def send(self, cmd_id: int, data: bytes, key: int = 0) -> None:
        self.sent += 1
        if self.out is not None:
            self.out.send(cmd_id, data, key)

    def snapshot(self) -> dict:
        out = self.out.snapshot() if self.out is not None else {}
        return {"connected": True, "team": self.state.team, "stage": self.state.game.stage if self.state.game else None, "sent": self.sent,
                "received": self.received, "disconnects": out.get("disconnects", 0), "written": out.get("sent")}  # fmt: skip

    def close(self) -> None:
        if self.out is not None:
            self.out.close()


def advancing(pairs, link: ReplayLink):
    """Feed the recorded referee input up to each frame's time before the loop processes the frame."""
    for frame, clouds in pairs:
        link.advance(frame.t)
        yield frame, clouds


# --- recording during a live run -------------------------------------------------------------------------------------
def paced_video(path: str) -> Iterator[CameraFrame]:
    """A video file played at its frame rate, each frame stamped with the host clock when it is due - a live camera
    for station tests (no frame is skipped when the loop is slow: the video then runs late)."""
    import time

    from radarcal.io import clock
    from radarcal.io.video import VideoFile

    video = VideoFile(path, "cannot open video")
    t0 = time.monotonic()
    for i, (_, img) in enumerate(video.frames()):
        delay = t0 + i / video.fps - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        yield CameraFrame(clock.now(), f"{i:06d}", (lambda img=img: img), i)


def start_recording(out, bundle, camera: str, video: str | None, clouds: list[str]):
    from radarcal.io.source_specs import split_named
    from radarcal.io.recording import Recorder

    sensors = [{"name": split_named(c, f"lidar{i}")[0], "kind": "lidar", "url": split_named(c, f"lidar{i}")[1]} for i, c in enumerate(clouds) if "://" in c]
    if video is not None:
        sensors.append({"name": camera, "kind": "camera", "source": video})
    return Recorder(out, sensors, bundle.path if bundle is not None else None)


def recorded(frames, recorder, camera: str):
    """Pass frames through, handing each image (with its time and name) to the recorder."""
    for f in frames:
        if not getattr(f, "stalled", False):
            try:
                img = f.load()
            except Exception:  # noqa: BLE001 - an unreadable frame is the loop's to report
                yield f
                continue
            recorder.camera(camera, f.t, f.name, img)
            f = CameraFrame(f.t, f.name, (lambda img=img: img), f.index)
        yield f


def tapped_serial(recorder):
    from radarcal.io.recording import TapSerial

    def factory(port, baud):
        import serial as pyserial

        return TapSerial(pyserial.Serial(port, baud, bytesize=8, parity="N", stopbits=1, timeout=0, write_timeout=0.2), recorder.serial)

    return factory


def finish_recording(recorder, cloud_src, serial: str | None) -> dict:
    health = cloud_src.sensors_health() if hasattr(cloud_src, "sensors_health") else {}
    for s in recorder.sensors:
        if s["kind"] == "lidar" and s["name"] in health:
            src = cloud_src.sources[s["name"]]
            s.update({"sdk": health[s["name"]]["sdk"], "device": health[s["name"]]["device"], "frame_s": src.frame_s})
    if serial:
        recorder.sensors.append({"name": "referee", "kind": "serial", "port": serial})
    return recorder.close({"health": health})
