"""ROS bags without ROS: ROS1 ``.bag``, ROS2 bag directories / ``.mcap`` / ``.db3``, read with ``rosbags`` and decoded to
numpy from the message definitions stored in the bag (a small layout walker, no per-point Python objects).

Cloud messages: Livox ``CustomMsg`` (livox_ros_driver / livox_ros_driver2; ROS2 bags without stored definitions get
the driver's definition registered) and ``sensor_msgs/PointCloud2``. :class:`BagCloudSource` hands them out as
:class:`radarcal.io.clouds.Cloud` in header-stamp order, times absolute (header stamp, bag receive time when the stamp
is zero), as a :class:`radarcal.io.cloud_sources.CloudSource`.
"""

from __future__ import annotations

import heapq
import os
from pathlib import Path
from typing import Iterator

import numpy as np

from radarcal.errors import InputError
from radarcal.io.clouds import Cloud

__all__ = ["BagCloudSource", "decode_pointcloud2", "LIVOX_CUSTOM_MSG", "LIVOX_CUSTOM_POINT", "LIVOX_TYPES", "PC2_TYPE"]

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


def _livox_points(msg: dict) -> tuple[np.ndarray, np.ndarray | None]:
    p = msg["points"]
    if isinstance(p, list):  # non-flat layout: rare, slow path
        pts = np.array([[q["x"], q["y"], q["z"]] for q in p], np.float32).reshape(-1, 3)
        return pts, np.array([q.get("reflectivity", 0) for q in p], np.float32)
    pts = np.column_stack([p["x"], p["y"], p["z"]]).astype(np.float32)
    return pts, (p["reflectivity"].astype(np.float32) if "reflectivity" in p.dtype.names else None)


def _typestore():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    default = get_typestore(Stores.ROS2_HUMBLE)
    for pkg in ("livox_ros_driver", "livox_ros_driver2"):  # ROS2 bags without stored definitions
        default.register(get_types_from_msg(LIVOX_CUSTOM_POINT, f"{pkg}/msg/CustomPoint"))
        default.register(get_types_from_msg(LIVOX_CUSTOM_MSG.format(pkg=pkg), f"{pkg}/msg/CustomMsg"))
    return default


class BagCloudSource:
    """The clouds of a bag on ``topic`` (default: every Livox CustomMsg / PointCloud2 topic) in header-stamp order.

    Opening checks the bag and its topics (``InputError`` naming the bag); messages are decoded while iterating.
    Messages are written in receive order, so a reorder buffer of ``reorder`` messages puts them in stamp order; a
    message still older than one already handed out is skipped (reason ``out of time order``), as is one that does
    not decode (``undecodable message``)."""

    def __init__(self, path: str | os.PathLike, topic: str | None = None, sensor: str = "", reorder: int = 16, quiet: bool = False):
        from rosbags.highlevel import AnyReader

        from radarcal.io.cloud_sources import Skips

        self.path = Path(path)
        self.sensor = sensor
        self.reorder = max(int(reorder), 1)
        self.skipped = Skips(quiet=quiet)
        if not self.path.exists():
            raise InputError(self.path, "bag not found")
        p = self.path
        paths = [p.parent] if p.suffix in (".db3", ".mcap") and (p.parent / "metadata.yaml").exists() else [p]
        try:
            self._reader = AnyReader(paths, default_typestore=_typestore())
            self._reader.open()
        except Exception as e:  # noqa: BLE001 - rosbags raises several reader errors (and OSError, ValueError ...)
            raise InputError(self.path, f"cannot open bag ({e.__class__.__name__}: {str(e)[:100]})") from None
        self._conns = [c for c in self._reader.connections if c.msgtype in LIVOX_TYPES + (PC2_TYPE,) and (topic is None or c.topic == topic)]
        if not self._conns:
            have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in self._reader.connections})) or "none"
            self._reader.close()
            raise InputError(self.path, f"no Livox CustomMsg / PointCloud2 topic{' ' + topic if topic else ''} (topics: {have})")
        self.topics = sorted({c.topic for c in self._conns})

    def _decode(self, conn, ts: int, raw: bytes) -> Cloud | None:
        try:
            msg = _Walker(raw, self._reader.typestore.fielddefs, bool(self._reader.is2)).message(conn.msgtype)
            pts, inten = decode_pointcloud2(msg) if conn.msgtype == PC2_TYPE else _livox_points(msg)
        except (ValueError, KeyError, IndexError, TypeError) as e:
            self.skipped.add("undecodable message", InputError(self.path, f"{conn.topic} @ {ts}: cannot decode {conn.msgtype} ({e})"))
            return None
        return Cloud(pts, inten, t=_stamp(msg) or ts * 1e-9, sensor=self.sensor, name=f"{conn.topic}@{ts}")

    def __iter__(self) -> Iterator[Cloud]:
        heap: list[tuple[float, int, Cloud]] = []
        last = -np.inf

        def pop() -> Cloud | None:
            nonlocal last
            c = heapq.heappop(heap)[2]
            if c.t < last:
                self.skipped.add("out of time order", InputError(self.path, f"{c.name}: stamp {c.t:.6f} s is older than a cloud already read"))
                return None
            last = c.t
            return c

        for k, (conn, ts, raw) in enumerate(self._reader.messages(connections=self._conns)):
            c = self._decode(conn, ts, raw)
            if c is not None:
                heapq.heappush(heap, (c.t, k, c))
            if len(heap) > self.reorder and (c := pop()) is not None:
                yield c
        while heap:
            if (c := pop()) is not None:
                yield c

    def close(self) -> None:
        self._reader.close()
