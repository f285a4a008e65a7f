"""Match recordings: everything radarcal received, with host receive times (:func:`radarcal.io.clock.now`), so a
replay feeds the same bytes in the same order to the same decoders.

A recording is a folder::

    manifest.json            format "radarcal-recording" v1, sensors, bundle path + sha256, versions, counts
    lidar-<name>.rec.zst     raw UDP datagrams of one LiDAR: records <f8 t, u1 kind (0 data, 1 control), u4 n> + bytes
    camera-<name>.jpgs       camera frames: records <f8 t, u4 index, u2 name length, u4 jpeg length> + name + JPEG
    serial.rec.zst           referee serial bytes: records <f8 t, u1 direction (0 received, 1 sent), u4 n> + bytes

LiDAR and serial streams are zstd-compressed (stdlib ``compression.zstd`` on Python >= 3.14, else its backport
``backports.zstd``); JPEG frames are stored as they are (zstd gains nothing on JPEG). :class:`Recorder` takes data
from any thread and writes from one writer thread (compression and JPEG encoding off the receive paths); a camera
frame that finds the writer queue full is dropped and counted (never a LiDAR packet or serial byte).
"""

from __future__ import annotations

import hashlib
import json
import os
import queue
import struct
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from radarcal.errors import InputError
from radarcal.io import clock

try:  # Python >= 3.14
    from compression import zstd  # type: ignore[import-not-found]
except ImportError:  # pragma: no cover - depends on the Python version
    from backports import zstd  # type: ignore[no-redef]

__all__ = ["FORMAT", "Recorder", "Recording", "TapSerial", "is_recording", "open_recording", "paced"]

FORMAT = "radarcal-recording"
VERSION = 1
_PKT = struct.Struct("<dBI")
_JPG = struct.Struct("<dIHI")


def _versions() -> dict:
    import cv2

    import radarcal

    return {"radarcal": getattr(radarcal, "__version__", "0"), "python": sys.version.split()[0], "numpy": np.__version__, "opencv": cv2.__version__,
            "zstd": getattr(zstd, "zstd_version", "?")}  # fmt: skip


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


class Recorder:
    """Writes a recording. Taps: :meth:`lidar` (sensor, kind, t, bytes) - the ``packet_tap`` of a LivoxSource -,
    :meth:`camera` (name, t, frame name, image), :meth:`serial` (direction, t, bytes). :meth:`close` writes the
    manifest."""

    def __init__(self, out: str | os.PathLike, sensors: list[dict], bundle: str | os.PathLike | None = None, jpeg_quality: int = 90, level: int = 3,
                 max_queued_frames: int = 60, encoders: int = 2):  # fmt: skip
        self.out = Path(out)
        if self.out.exists() and any(self.out.iterdir()):
            raise InputError(self.out, "exists and is not empty (a recording is never overwritten)")
        self.out.mkdir(parents=True, exist_ok=True)
        self.sensors = sensors
        self.bundle = Path(bundle) if bundle else None
        self.quality = int(jpeg_quality)
        self.level = level
        self._q: queue.Queue = queue.Queue()
        self._frames_queued = 0
        self.max_frames = max_queued_frames
        self._lock = threading.Lock()
        self._files: dict[str, object] = {}
        self.counts: dict[str, dict] = {}
        self.dropped_frames = 0
        self.t_first: float | None = None
        self.t_last: float | None = None
        self.started = time.time()
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(max(1, encoders), thread_name_prefix="recorder-jpeg")  # cv2.imencode releases the GIL
        self._pending: dict[str, bytearray] = {}
        self._thread = threading.Thread(target=self._run, daemon=True, name="recorder")
        self._thread.start()

    # --- taps (any thread, never block) ---------------------------------------------------------------------------
    def lidar(self, sensor: str, kind: str, t: float, buf: bytes) -> None:
        self._q.put(("lidar-" + (sensor or "lidar"), 0 if kind == "data" else 1, t, bytes(buf)))

    def serial(self, direction: str, t: float, buf: bytes) -> None:
        if buf:
            self._q.put(("serial", 0 if direction == "rx" else 1, t, bytes(buf)))

    def camera(self, name: str, t: float, frame: str, img: np.ndarray) -> bool:
        with self._lock:
            if self._frames_queued >= self.max_frames:
                self.dropped_frames += 1
                return False
            self._frames_queued += 1
        self._q.put(("camera-" + name, frame, t, self._pool.submit(self._encode, img)))
        return True

    def _encode(self, img: np.ndarray) -> bytes | None:
        import cv2

        ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        return jpg.tobytes() if ok else None

    # --- writer ----------------------------------------------------------------------------------------------------
    def _file(self, key: str):
        f = self._files.get(key)
        if f is None:
            if key.startswith("camera-"):
                f = open(self.out / f"{key}.jpgs", "wb")
            else:
                f = zstd.open(self.out / f"{key}.rec.zst", "wb", level=self.level)
            self._files[key] = f
            self.counts[key] = {"records": 0, "bytes": 0}
        return f

    def _run(self) -> None:
        while True:
            try:
                item = self._q.get(timeout=0.2)
            except queue.Empty:
                self._drain()
                continue
            if item is None:
                break
            key, a, t, payload = item
            f = self._file(key)
            if key.startswith("camera-"):
                data = payload.result()  # frames are written in arrival order; encoding ran in the pool
                with self._lock:
                    self._frames_queued -= 1
                if data is None:
                    continue
                name = str(a).encode()
                f.write(_JPG.pack(t, self.counts[key]["records"], len(name), len(data)) + name + data)
                n = len(data)
            else:  # small records: batched into 64 kB writes (one compressor call per batch, not per datagram)
                buf = self._pending.setdefault(key, bytearray())
                buf += _PKT.pack(t, a, len(payload))
                buf += payload
                if len(buf) >= 1 << 16:
                    f.write(bytes(buf))
                    buf.clear()
                n = len(payload)
            c = self.counts[key]
            c["records"] += 1
            c["bytes"] += n
            self.t_first = t if self.t_first is None else min(self.t_first, t)
            self.t_last = t if self.t_last is None else max(self.t_last, t)

    def _drain(self) -> None:
        for key, buf in self._pending.items():
            if buf:
                self._files[key].write(bytes(buf))
                buf.clear()

    def close(self, extra: dict | None = None) -> dict:
        self._q.put(None)
        self._thread.join()
        self._drain()
        self._pool.shutdown()
        for f in self._files.values():
            f.close()
        man = {"format": FORMAT, "version": VERSION, "created_unix": self.started, "sensors": self.sensors, "versions": _versions(),
               "bundle": None if self.bundle is None else {"path": str(self.bundle), "sha256": file_sha256(self.bundle)},
               "t_first": self.t_first, "t_last": self.t_last, "duration_s": None if self.t_first is None else self.t_last - self.t_first,
               "streams": self.counts, "dropped_camera_frames": self.dropped_frames, **(extra or {})}  # fmt: skip
        tmp = self.out / "manifest.json.tmp"
        tmp.write_text(json.dumps(man, indent=1), encoding="utf-8")
        tmp.replace(self.out / "manifest.json")
        return man


def is_recording(path: str | os.PathLike) -> bool:
    p = Path(path) / "manifest.json"
    if not p.is_file():
        return False
    try:
        return json.loads(p.read_text(encoding="utf-8")).get("format") == FORMAT
    except (ValueError, OSError):
        return False


class Recording:
    """A recording opened for replay."""

    def __init__(self, root: Path, manifest: dict):
        self.root = root
        self.manifest = manifest

    def sensors(self, kind: str) -> list[dict]:
        return [s for s in self.manifest.get("sensors", []) if s.get("kind") == kind]

    def _records(self, path: Path) -> Iterator[tuple[float, int, bytes]]:
        if not path.is_file():
            return
        try:
            with zstd.open(path, "rb") as f:
                while True:
                    head = f.read(_PKT.size)
                    if len(head) < _PKT.size:
                        return
                    t, kind, n = _PKT.unpack(head)
                    buf = f.read(n)
                    if len(buf) < n:
                        return  # a recording cut short (power loss): its complete records are kept
                    yield t, kind, buf
        except (zstd.ZstdError, EOFError, OSError) as e:
            sys.stderr.write(f"warning: {path}: stream ends early ({e.__class__.__name__}); replaying what was read\n")

    def lidar_packets(self, name: str) -> Iterator[tuple[float, int, bytes]]:
        return self._records(self.root / f"lidar-{name}.rec.zst")

    def serial_records(self) -> Iterator[tuple[float, int, bytes]]:
        return self._records(self.root / "serial.rec.zst")

    def camera_frames(self, name: str) -> Iterator[tuple[float, str, bytes]]:
        path = self.root / f"camera-{name}.jpgs"
        if not path.is_file():
            raise InputError(path, "camera stream not found in the recording")
        with open(path, "rb") as f:
            while True:
                head = f.read(_JPG.size)
                if len(head) < _JPG.size:
                    return
                t, _, ln, n = _JPG.unpack(head)
                name_b = f.read(ln)
                data = f.read(n)
                if len(data) < n:
                    return
                yield t, name_b.decode(), data

    def clouds(self, frame_s: float = 0.1):
        """Clouds of every recorded LiDAR, decoded from the raw packets by the live decoder, merged by time."""
        import heapq

        from radarcal.io.livox import PacketDecoder

        def one(s: dict):
            dec = PacketDecoder(int(s["sdk"]), float(s.get("frame_s", frame_s)), s["name"])
            for t, kind, buf in self.lidar_packets(s["name"]):
                if kind == 0:
                    dec.feed(buf, t)
                    if dec.pending() >= 256:
                        yield from dec.flush()
            yield from dec.finish()

        streams = [one(s) for s in self.sensors("lidar") if s.get("sdk")]
        return heapq.merge(*streams, key=lambda c: c.t)


def open_recording(path: str | os.PathLike) -> Recording:
    root = Path(path)
    p = root / "manifest.json"
    if not p.is_file():
        raise InputError(root, "not a recording (no manifest.json)")
    try:
        man = json.loads(p.read_text(encoding="utf-8"))
    except ValueError:
        raise InputError(p, "not valid JSON") from None
    if man.get("format") != FORMAT:
        raise InputError(p, f"not a radarcal recording (format {man.get('format')!r})")
    if int(man.get("version", 0)) > VERSION:
        raise InputError(p, f"recording format version {man['version']} is newer than this radarcal reads ({VERSION})")
    return Recording(root, man)


class TapSerial:
    """Wraps a pyserial-like port (read / write / in_waiting / flush / close) and hands every byte read or written,
    with its time, to ``tap(direction, t, bytes)`` - for ``SerialLink(serial_factory=...)``."""

    def __init__(self, port, tap):
        self.port, self.tap = port, tap

    @property
    def in_waiting(self) -> int:
        return self.port.in_waiting

    def read(self, n: int = 1) -> bytes:
        b = self.port.read(n)
        self.tap("rx", clock.now(), b)
        return b

    def write(self, b: bytes):
        n = self.port.write(b)
        self.tap("tx", clock.now(), bytes(b))
        return n

    def flush(self) -> None:
        self.port.flush()

    def close(self) -> None:
        self.port.close()


def paced(items, t_of, speed: float | None):
    """Yield ``items`` no faster than ``speed`` x real time by their times ``t_of(item)`` (None: as fast as possible)."""
    if not speed:
        yield from items
        return
    wall0 = t0 = None
    for it in items:
        t = t_of(it)
        if t0 is None:
            wall0, t0 = time.monotonic(), t
        delay = (t - t0) / speed - (time.monotonic() - wall0)
        if delay > 0:
            time.sleep(delay)
        yield it
