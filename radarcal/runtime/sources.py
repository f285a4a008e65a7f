"""Inputs of ``radarcal run``: camera frames, LiDAR clouds, a replay folder, and time pairing.

Camera: a video file, an image folder (times from ``times.csv`` ``file,t`` if present, else index / fps), or a live
``cv2.VideoCapture`` index / URL (host-clock receive times, reconnecting: :mod:`radarcal.io.camera_live`).
Clouds: a folder of ``.pcd/.npy/.bin/.ply`` (times from ``times.csv`` or index / hz); a ROS1 ``.bag`` or ROS2 bag
directory / ``.mcap`` / ``.db3`` with Livox ``CustomMsg`` (livox_ros_driver / livox_ros_driver2) or
``sensor_msgs/PointCloud2``, read with ``rosbags`` (no ROS) and decoded to numpy from the message definitions stored
in the bag (a small layout walker, no per-point Python objects); or a live Livox LiDAR (SDK 1 or 2, started and
read by :mod:`radarcal.io.livox`).

"""

from __future__ import annotations

import csv
import json
import os
import re
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from radarcal.errors import InputError
from radarcal.io import read_cloud, read_image
from radarcal.io.clouds import CLOUD_SUFFIXES

__all__ = [
    "CameraFrame",
    "CloudFrame",
    "image_folder_frames",
    "video_frames",
    "cloud_folder",
    "bag_clouds",
    "decode_pointcloud2",
    "Replay",
    "open_replay",
    "open_camera",
    "open_clouds",
    "merge_by_time",
    "prefetch_frames",
    "IMAGE_SUFFIXES",
    "SKIPPED",
]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")


def _warn(err: Exception) -> None:
    """A bad input file in the middle of a stream is reported and skipped: the match loop must not stop."""
    import sys

    SKIPPED.append(str(err))
    if len(SKIPPED) > 1000:
        del SKIPPED[:500]
    sys.stderr.write(f"warning: {err} (skipped)\n")


SKIPPED: list[str] = []  # problems skipped so far (bounded), for the run summary


@dataclass
class CameraFrame:
    t: float
    name: str
    load: Callable[[], np.ndarray]  # decode on demand (a replay with --detections never needs the pixels)
    index: int = 0


@dataclass
class CloudFrame:
    t: float
    points: np.ndarray  # (N,3) float32, LiDAR frame
    intensity: np.ndarray | None = None
    name: str = ""


# --- times ---------------------------------------------------------------------------------------------------------
def _read_times(folder: Path) -> dict[str, float]:
    p = folder / "times.csv"
    if not p.is_file():
        return {}
    out = {}
    try:
        with open(p, newline="", encoding="utf-8") as f:
            for i, row in enumerate(csv.reader(f)):
                if not row or (i == 0 and not _is_float(row[-1])):
                    continue
                if len(row) < 2 or not _is_float(row[1]):
                    raise InputError(p, f"row {i + 1}: expected 'file,t' with t in seconds")
                out[row[0].strip()] = float(row[1])
    except OSError as e:
        raise InputError(p, f"cannot read ({e.__class__.__name__})") from None
    return out


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _stem_time(stem: str) -> float | None:
    """Time from a numeric file name: seconds (``1700000000.123``) or nanoseconds (19 digits)."""
    if re.fullmatch(r"\d{16,20}", stem):
        return int(stem) * 1e-9
    if re.fullmatch(r"\d+\.\d+", stem):
        return float(stem)
    return None


def _timed_files(folder: Path, suffixes: tuple[str, ...], rate_hz: float, what: str) -> list[tuple[float, Path]]:
    if not folder.is_dir():
        raise InputError(folder, f"{what} folder not found")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes)
    if not files:
        raise InputError(folder, f"no {what} files ({', '.join(suffixes)})")
    times = _read_times(folder)
    out = []
    stem_times = [_stem_time(p.stem) for p in files]
    use_stems = not times and all(s is not None for s in stem_times)
    t0 = min(stem_times) if use_stems else 0.0
    for i, p in enumerate(files):
        if times:
            if p.name not in times:
                raise InputError(folder / "times.csv", f"no time for {p.name}")
            t = times[p.name]
        elif use_stems:
            t = stem_times[i] - t0
        else:
            t = i / rate_hz
        out.append((t, p))
    out.sort(key=lambda x: x[0])
    return out


# --- camera ----------------------------------------------------------------------------------------------------------
def image_folder_frames(folder: str | os.PathLike, fps: float = 30.0) -> Iterator[CameraFrame]:
    for i, (t, p) in enumerate(_timed_files(Path(folder), IMAGE_SUFFIXES, fps, "image")):
        yield CameraFrame(t, p.name, (lambda p=p: read_image(p)), i)


def video_frames(source: str, fps: float | None = None) -> Iterator[CameraFrame]:
    """A video file (times from the container) or a live index / URL (:class:`radarcal.io.camera_live.LiveCamera`:
    host-clock receive times, reopened when unplugged, stall frames instead of waiting)."""
    import cv2

    if source.isdigit() or "://" in source:
        from radarcal.io.camera_live import LiveCamera

        yield from LiveCamera(source)
        return
    cap = cv2.VideoCapture(source)
    if not cap.isOpened():
        raise InputError(source, "cannot open video source")
    rate = fps or cap.get(cv2.CAP_PROP_FPS) or 30.0
    i = 0
    try:
        while True:
            ok, img = cap.read()
            if not ok:
                break
            ms = cap.get(cv2.CAP_PROP_POS_MSEC)
            t = ms / 1000.0 if ms and ms > 0 and i > 0 else i / rate
            yield CameraFrame(t, f"{i:06d}", (lambda img=img: img), i)
            i += 1
    finally:
        cap.release()


def open_camera(spec: str, fps: float = 30.0) -> Iterator[CameraFrame]:
    p = Path(spec)
    if p.is_dir():
        return image_folder_frames(p, fps)
    if not p.is_file() and (spec.isdigit() or "://" in spec):
        from radarcal.io.camera_live import LiveCamera

        return LiveCamera(spec, name="camera")  # iterable; .snapshot() is its health
    if p.is_file():
        return video_frames(spec)
    raise InputError(spec, "camera source not found (expected an image folder, a video file, a device index or a URL)")


# --- cloud folders ---------------------------------------------------------------------------------------------------
def _read_clouds(items: list[tuple[float, Path]]) -> Iterator[CloudFrame]:
    for t, p in items:
        try:
            c = read_cloud(p)
        except InputError as e:
            _warn(e)
            continue
        yield CloudFrame(t, c.points, c.intensity, p.name)


def cloud_folder(folder: str | os.PathLike, hz: float = 10.0) -> Iterator[CloudFrame]:
    return _read_clouds(_timed_files(Path(folder), CLOUD_SUFFIXES, hz, "point-cloud"))


# --- ROS bags --------------------------------------------------------------------------------------------------------
LIVOX_CUSTOM_MSG = """std_msgs/Header header
uint64 timebase
uint32 point_num
uint8 lidar_id
uint8[3] rsvd
{pkg}/CustomPoint[] points
"""
LIVOX_CUSTOM_POINT = """uint32 offset_time
float32 x
float32 y
float32 z
uint8 reflectivity
uint8 tag
uint8 line
"""
LIVOX_TYPES = ("livox_ros_driver/msg/CustomMsg", "livox_ros_driver2/msg/CustomMsg")
PC2_TYPE = "sensor_msgs/msg/PointCloud2"

_PRIM = {"bool": "u1", "byte": "u1", "char": "u1", "int8": "i1", "uint8": "u1", "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4",
         "int64": "<i8", "uint64": "<u8", "float32": "<f4", "float64": "<f8"}  # fmt: skip


class _Walker:
    """Reads a serialized ROS message (ROS1 packed little-endian, or ROS2 CDR little-endian with alignment) from
    the field definitions of a rosbags typestore. Sequences of flat structs of primitives (point arrays) become
    numpy structured arrays in one ``frombuffer``; everything else becomes Python values."""

    def __init__(self, raw: bytes, fielddefs: dict, cdr: bool):
        self.raw = bytes(raw)
        self.defs = fielddefs
        self.cdr = cdr
        if cdr:
            if len(self.raw) < 4 or self.raw[1] not in (0, 1):
                raise ValueError("not a CDR message")
            if self.raw[1] == 0:
                raise ValueError("big-endian CDR is not supported")
        self.base = 4 if cdr else 0
        self.pos = self.base

    def align(self, n: int) -> None:
        if self.cdr and n > 1:
            self.pos += (-(self.pos - self.base)) % n

    def prim(self, t: str):
        dt = np.dtype(_PRIM[t])
        self.align(dt.itemsize)
        v = np.frombuffer(self.raw, dt, 1, self.pos)[0]
        self.pos += dt.itemsize
        return v

    def string(self) -> str:
        n = int(self.prim("uint32"))
        s = self.raw[self.pos : self.pos + n]
        self.pos += n
        return s.rstrip(b"\0").decode("utf-8", "replace")

    def prim_array(self, t: str, n: int) -> np.ndarray:
        dt = np.dtype(_PRIM[t])
        if n:
            self.align(dt.itemsize)
        a = np.frombuffer(self.raw, dt, n, self.pos)
        self.pos += n * dt.itemsize
        return a

    def flat_struct(self, name: str) -> tuple[np.dtype, int] | None:
        """(dtype with offsets, alignment of the first member) when ``name`` is a struct of primitives only."""
        fields = self.defs[name][1]
        names, formats, offsets = [], [], []
        off = 0
        max_al = 1
        for fname, (nt, det) in fields:
            if nt != 1 or det[0] not in _PRIM:
                return None
            dt = np.dtype(_PRIM[det[0]])
            if self.cdr:
                off += (-off) % dt.itemsize
                max_al = max(max_al, dt.itemsize)
            names.append(fname)
            formats.append(dt)
            offsets.append(off)
            off += dt.itemsize
        itemsize = off + ((-off) % max_al if self.cdr else 0)
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": itemsize}), max_al

    def message(self, name: str) -> dict:
        out = {}
        for fname, (nt, det) in self.defs[name][1]:
            out[fname] = self.field(nt, det)
        return out

    def field(self, nt: int, det):
        if nt == 1:  # BASE (type, maxlen)
            return self.string() if det[0] == "string" else self.prim(det[0])
        if nt == 2:  # NAME
            return self.message(det)
        (snt, sdet), count = det
        if nt == 4:  # SEQUENCE
            count = int(self.prim("uint32"))
        if snt == 1 and sdet[0] in _PRIM:
            return self.prim_array(sdet[0], count)
        if snt == 2:
            flat = self.flat_struct(sdet)
            if flat is not None and count:
                dt, al = flat
                self.align(al)
                if not self.cdr or (self.pos - self.base) % al == 0:
                    need = self.pos + count * dt.itemsize
                    buf = self.raw if need <= len(self.raw) else self.raw + bytes(need - len(self.raw))
                    arr = np.frombuffer(buf, dt, count, self.pos)
                    self.pos += (count - 1) * dt.itemsize + _packed_size(dt)
                    return arr
        return [self.field(snt, sdet) for _ in range(count)]


def _packed_size(dt: np.dtype) -> int:
    return max(off + dt.fields[n][0].itemsize for n, off in ((n, dt.fields[n][1]) for n in dt.names))


_PC2_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def decode_pointcloud2(msg: dict) -> tuple[np.ndarray, np.ndarray | None]:
    """A decoded PointCloud2 (dict with fields / point_step / row_step / data ...) -> (points (N,3) f32, intensity)."""
    fields = {f["name"]: f for f in msg["fields"]}
    for k in ("x", "y", "z"):
        if k not in fields:
            raise ValueError(f"PointCloud2 has no '{k}' field")
    endian = ">" if msg.get("is_bigendian") else "<"
    names, formats, offsets = [], [], []
    for nm in ("x", "y", "z", "intensity", "reflectivity"):
        f = fields.get(nm)
        if f is None or int(f["datatype"]) not in _PC2_TYPES:
            continue
        names.append(nm)
        formats.append(np.dtype(endian + _PC2_TYPES[int(f["datatype"])]))
        offsets.append(int(f["offset"]))
    step = int(msg["point_step"])
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    data = np.asarray(msg["data"], np.uint8)
    h, w = int(msg["height"]), int(msg["width"])
    row = int(msg["row_step"]) or w * step
    if h > 1 and row != w * step:
        data = data[: h * row].reshape(h, row)[:, : w * step].reshape(-1)
    arr = np.frombuffer(data.tobytes() if not data.flags.c_contiguous else data, dt, h * w)
    pts = np.column_stack([arr["x"], arr["y"], arr["z"]]).astype(np.float32)
    inten = next((arr[n].astype(np.float32) for n in ("intensity", "reflectivity") if n in names), None)
    ok = np.all(np.isfinite(pts), axis=1)
    return pts[ok], (inten[ok] if inten is not None else None)


def _stamp(msg: dict) -> float | None:
    st = msg.get("header", {}).get("stamp") if isinstance(msg.get("header"), dict) else None
    if not st:
        return None
    t = float(st["sec"]) + float(st["nanosec"]) * 1e-9
    return t if t > 0 else None


def bag_clouds(path: str | os.PathLike, topic: str | None = None, t0: float | None = None) -> Iterator[CloudFrame]:
    """Clouds from a ROS1/ROS2 bag. Times are the header stamps (bag receive time when zero) relative to ``t0``
    (default: the first cloud)."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    path = Path(path)
    if not path.exists():
        raise InputError(path, "bag not found")
    default = get_typestore(Stores.ROS2_HUMBLE)
    for pkg in ("livox_ros_driver", "livox_ros_driver2"):  # ROS2 bags without stored definitions
        default.register(get_types_from_msg(LIVOX_CUSTOM_POINT, f"{pkg}/msg/CustomPoint"))
        default.register(get_types_from_msg(LIVOX_CUSTOM_MSG.format(pkg=pkg), f"{pkg}/msg/CustomMsg"))
    paths = [path.parent] if path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").exists() else [path]
    try:
        reader = AnyReader(paths, default_typestore=default)
        reader.open()
    except (AnyReaderError, Exception) as e:  # noqa: BLE001 - rosbags raises several reader errors
        raise InputError(path, f"cannot open bag ({e.__class__.__name__}: {str(e)[:100]})") from None
    try:
        conns = [c for c in reader.connections if c.msgtype in LIVOX_TYPES + (PC2_TYPE,) and (topic is None or c.topic == topic)]
        if not conns:
            have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})) or "none"
            raise InputError(path, f"no Livox CustomMsg / PointCloud2 topic{' ' + topic if topic else ''} (topics: {have})")
        defs = reader.typestore.fielddefs
        cdr = bool(reader.is2)
        first = t0
        for conn, ts, raw in reader.messages(connections=conns):
            try:
                msg = _Walker(raw, defs, cdr).message(conn.msgtype)
                if conn.msgtype == PC2_TYPE:
                    pts, inten = decode_pointcloud2(msg)
                else:
                    p = msg["points"]
                    if isinstance(p, list):  # non-flat layout: rare, slow path
                        pts = np.array([[q["x"], q["y"], q["z"]] for q in p], np.float32).reshape(-1, 3)
                        inten = np.array([q.get("reflectivity", 0) for q in p], np.float32)
                    else:
                        pts = np.column_stack([p["x"], p["y"], p["z"]]).astype(np.float32)
                        inten = p["reflectivity"].astype(np.float32) if "reflectivity" in p.dtype.names else None
            except (ValueError, KeyError, IndexError, TypeError) as e:
                _warn(InputError(path, f"{conn.topic} @ {ts}: cannot decode {conn.msgtype} ({e})"))
                continue
            t = _stamp(msg) or ts * 1e-9
            if first is None:
                first = t
            yield CloudFrame(t - first, pts, inten, f"{conn.topic}@{ts}")
    finally:
        reader.close()


def open_clouds(spec: str, topic: str | None = None, hz: float = 10.0):
    """A cloud source from a folder, a bag, or a live Livox (``livox://IP``, ``livox1://``, ``livox2://``: a started
    :class:`radarcal.io.livox.LivoxSource`, polled)."""
    if spec.startswith(("livox://", "livox1://", "livox2://")):
        from radarcal.io.livox import open_livox

        return open_livox(spec)
    p = Path(spec)
    if p.is_dir() and not (p / "metadata.yaml").exists():
        return cloud_folder(p, hz)
    if p.exists():
        return bag_clouds(p, topic)
    raise InputError(spec, "cloud source not found (expected a folder of clouds, a ROS bag or livox://IP)")


# --- replay folder ---------------------------------------------------------------------------------------------------
@dataclass
class Replay:
    root: Path
    meta: dict
    frames: list[tuple[float, Path]]  # the images that exist
    clouds: list[tuple[float, Path]]
    detections: Path | None
    truth: Path | None
    bundle: Path | None
    timeline: list[tuple[float, str]] | None = None  # every camera frame (from detections.jsonl), images or not

    def camera_frames(self, need_pixels: bool = False) -> Iterator[CameraFrame]:
        """The camera frames. Driven by detections (``need_pixels=False``) every frame of ``detections.jsonl`` is
        yielded even when ``synth field --image-every K`` wrote only every K-th image; a detector needs the pixels
        and gets the frames that have an image."""
        if need_pixels or self.timeline is None:
            for i, (t, p) in enumerate(self.frames):
                yield CameraFrame(t, p.name, (lambda p=p: read_image(p)), i)
            return
        images = self.root / "images"
        for i, (t, name) in enumerate(self.timeline):
            p = images / name
            yield CameraFrame(t, name, (lambda p=p: read_image(p)), i)

    def cloud_frames(self) -> Iterator[CloudFrame]:
        return _read_clouds(self.clouds)

    def truth_by_frame(self) -> dict[str, dict]:
        out = {}
        if self.truth is None:
            return out
        with open(self.truth, encoding="utf-8") as f:
            for line in f:
                if line.strip():
                    d = json.loads(line)
                    out[str(d.get("frame", d.get("t")))] = d
        return out


def _timeline(det: Path) -> list[tuple[float, str]] | None:
    out = []
    with open(det, encoding="utf-8") as f:
        for i, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                d = json.loads(line)
                out.append((float(d["t"]), str(d["frame"])))
            except (ValueError, KeyError, TypeError):
                return None  # no usable frame names: the image list drives the replay (DetectionsFile reports errors)
    out.sort(key=lambda x: x[0])
    return out or None


def open_replay(folder: str | os.PathLike) -> Replay:
    """A replay folder as written by ``radarcal synth field`` (see docs): images/, clouds/, detections.jsonl ..."""
    root = Path(folder)
    if not root.is_dir():
        raise InputError(root, "replay folder not found")
    meta = {}
    if (root / "meta.json").is_file():
        try:
            meta = json.loads((root / "meta.json").read_text(encoding="utf-8"))
        except ValueError:
            raise InputError(root / "meta.json", "not valid JSON") from None
    fps = float(meta.get("fps", 30.0))
    hz = float(meta.get("lidar_hz", 10.0))
    frames = _timed_files(root / "images", IMAGE_SUFFIXES, fps, "image")
    clouds = _timed_files(root / "clouds", CLOUD_SUFFIXES, hz, "point-cloud") if (root / "clouds").is_dir() else []
    det = root / "detections.jsonl"
    truth = root / "truth.jsonl"
    bundle = next((root / n for n in ("calib.yaml", "bundle.yaml") if (root / n).is_file()), None)
    det = det if det.is_file() else None
    return Replay(root, meta, frames, clouds, det, truth if truth.is_file() else None, bundle, _timeline(det) if det else None)


def prefetch_frames(frames: Iterator[CameraFrame], depth: int = 3, latest_only: bool = False) -> Iterator[CameraFrame]:
    """Decode images in a background thread (JPEG decode and the detector then overlap). ``latest_only`` (live
    cameras): keep only the newest decoded frame, dropping older ones, so latency never builds up."""
    import queue

    q: queue.Queue = queue.Queue(maxsize=1 if latest_only else depth)
    done = object()
    stop = threading.Event()

    def work():
        try:
            for f in frames:
                if stop.is_set():
                    break
                try:
                    img = f.load()
                    g = CameraFrame(f.t, f.name, (lambda img=img: img), f.index)
                except InputError as e:
                    g = CameraFrame(f.t, f.name, (lambda e=e: (_ for _ in ()).throw(e)), f.index)
                if latest_only:
                    try:
                        q.get_nowait()  # drop the stale frame
                    except queue.Empty:
                        pass
                    q.put(g)
                else:
                    while not stop.is_set():
                        try:
                            q.put(g, timeout=0.1)
                            break
                        except queue.Full:
                            continue
        finally:
            q.put(done)

    th = threading.Thread(target=work, daemon=True, name="frame-prefetch")
    th.start()
    try:
        while True:
            g = q.get()
            if g is done:
                break
            yield g
    finally:
        stop.set()


# --- pairing ---------------------------------------------------------------------------------------------------------
def merge_by_time(frames: Iterator[CameraFrame], clouds, cloud_offset_s: float = 0.0) -> Iterator[tuple[CameraFrame, list[CloudFrame]]]:
    """Yield each camera frame with the clouds that arrived since the previous frame (cloud time + offset <= frame
    time). ``clouds`` is an iterator (files, bags: read ahead lazily) or a live source with a non-blocking ``poll()``."""
    if clouds is None:
        for f in frames:
            yield f, []
        return
    if hasattr(clouds, "poll"):
        for f in frames:
            yield f, clouds.poll()
        return
    it = iter(clouds)
    pending: CloudFrame | None = None
    done = False
    for f in frames:
        batch = []
        while not done:
            if pending is None:
                try:
                    pending = next(it)
                except StopIteration:
                    done = True
                    break
            if pending.t + cloud_offset_s <= f.t + 1e-9:
                pending.t = pending.t + cloud_offset_s
                batch.append(pending)
                pending = None
            else:
                break
        yield f, batch
