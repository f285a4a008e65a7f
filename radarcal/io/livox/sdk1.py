"""Livox SDK 1 (LiDAR communication protocol v1: Mid-40, Mid-70, Horizon, Avia, Tele): control frames and point
packets. Pure byte/array code, no sockets (those live in :mod:`radarcal.io.livox.source`).

Control frame (little-endian): ``sof 0xAA, version 1, length u16 (whole frame), cmd_type u8 (0 cmd, 1 ack, 2 msg),
seq u16, crc16 u16`` (MCRF4XX seed 0x4C49 over the 7 bytes before it), then ``cmd_set u8, cmd_id u8, payload``, then
``crc32 u32`` (seed 0x564F580A over everything before it). The sensor broadcasts ``(0, 0)`` (broadcast code[16],
device type u8, reserved u16) from its command port 65000 to host port 55000 about once a second until a host
handshakes ``(0, 1)`` (host IP u32, data port u16, command port u16, IMU port u16); the host then sends a heartbeat
``(0, 3)`` every ~0.8 s (the sensor stops streaming and broadcasts again after ~3 s without one), starts / stops
sampling with ``(0, 4)`` (u8 1 / 0), picks cartesian or spherical points with ``(0, 5)`` (u8 0 / 1) and says goodbye
with ``(0, 6)``.

Point packet: an 18-byte header (version, slot, id, reserved, status u32, timestamp type, data type, timestamp u64 ns)
then a fixed number of points of the data type (see :data:`POINT_TYPES`). Data type 6 (IMU) carries no points.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from radarcal.io.livox.crc import crc16_mcrf4xx, crc32

__all__ = [
    "ACK",
    "BROADCAST",
    "BROADCAST_PORT",
    "CMD",
    "COORDINATE",
    "DEVICE_TYPES",
    "DISCONNECT",
    "HANDSHAKE",
    "HEADER",
    "HEARTBEAT",
    "LIDAR_CMD_PORT",
    "MSG",
    "POINT_TYPES",
    "SAMPLE",
    "Frame",
    "decode_points",
    "encode_packets",
    "pack_frame",
    "packet_dtype",
    "parse_frame",
]  # fmt: skip

SOF = 0xAA
VERSION = 1
CMD, ACK, MSG = 0, 1, 2
BROADCAST, HANDSHAKE, DEVICE_INFO, HEARTBEAT, SAMPLE, COORDINATE, DISCONNECT = 0, 1, 2, 3, 4, 5, 6
BROADCAST_PORT = 55000  # host port the sensors broadcast to
LIDAR_CMD_PORT = 65000  # the sensor's command port
CRC16_SEED, CRC32_SEED = 0x4C49, 0x564F580A
DEVICE_TYPES = {0: "Hub", 1: "Mid-40", 2: "Tele", 3: "Horizon", 6: "Mid-70", 7: "Avia"}
_PRE = struct.Struct("<BBHBH")  # sof, version, length, cmd_type, seq


@dataclass
class Frame:
    cmd_type: int
    seq: int
    cmd_set: int
    cmd_id: int
    payload: bytes


def pack_frame(cmd_type: int, seq: int, cmd_set: int, cmd_id: int, payload: bytes = b"") -> bytes:
    length = 9 + 2 + len(payload) + 4
    pre = _PRE.pack(SOF, VERSION, length, cmd_type, seq & 0xFFFF)
    body = pre + struct.pack("<H", crc16_mcrf4xx(pre, CRC16_SEED)) + bytes((cmd_set, cmd_id)) + payload
    return body + struct.pack("<I", crc32(body, CRC32_SEED))


def parse_frame(buf: bytes) -> Frame | None:
    """One control frame, or None when it is not one (wrong start byte, length or either checksum)."""
    if len(buf) < 15 or buf[0] != SOF:
        return None
    _, _, length, cmd_type, seq = _PRE.unpack_from(buf)
    if length != len(buf) or crc16_mcrf4xx(buf[:9], CRC16_SEED) != 0:  # the preamble CRC of a good frame checks to 0
        return None
    if struct.unpack_from("<I", buf, length - 4)[0] != crc32(buf[: length - 4], CRC32_SEED):
        return None
    return Frame(cmd_type, seq, buf[9], buf[10], bytes(buf[11 : length - 4]))


# --- point packets ---------------------------------------------------------------------------------------------------
HEADER = [("version", "u1"), ("slot", "u1"), ("id", "u1"), ("rsvd", "u1"), ("status", "<u4"), ("ts_type", "u1"), ("data_type", "u1"), ("timestamp", "<u8")]
_XYZ = [("x", "<i4"), ("y", "<i4"), ("z", "<i4")]
# data type -> (point fields, points per packet, returns per point record, kind)
POINT_TYPES: dict[int, tuple[list, int, int, str]] = {
    0: (_XYZ + [("r", "u1")], 100, 1, "cart"),
    1: ([("depth", "<u4"), ("theta", "<u2"), ("phi", "<u2"), ("r", "u1")], 100, 1, "sph"),
    2: (_XYZ + [("r", "u1"), ("tag", "u1")], 96, 1, "cart"),
    3: ([("depth", "<u4"), ("theta", "<u2"), ("phi", "<u2"), ("r", "u1"), ("tag", "u1")], 96, 1, "sph"),
    4: (_XYZ + [("r", "u1"), ("tag", "u1")], 96, 1, "cart"),  # dual return: 48 slots x 2 consecutive extended points
    5: ([("theta", "<u2"), ("phi", "<u2"), ("depth", "<u4"), ("r", "u1"), ("tag", "u1"), ("depth2", "<u4"), ("r2", "u1"), ("tag2", "u1")], 48, 2, "sph2"),
    7: (_XYZ + [("r", "u1"), ("tag", "u1")], 90, 1, "cart"),  # triple return: 30 slots x 3 extended points
    8: ([("theta", "<u2"), ("phi", "<u2"), ("depth", "<u4"), ("r", "u1"), ("tag", "u1"), ("depth2", "<u4"), ("r2", "u1"), ("tag2", "u1"),
         ("depth3", "<u4"), ("r3", "u1"), ("tag3", "u1")], 30, 3, "sph3"),
}
IMU_TYPE = 6
HEADER_SIZE = np.dtype(HEADER).itemsize  # 18
POINT_INTERVAL_S = 1e-5  # Mid-40/70: 100 k points/s -> one point every 10 us


def packet_dtype(data_type: int) -> np.dtype:
    fields, n, _, _ = POINT_TYPES[data_type]
    return np.dtype(HEADER + [("pts", np.dtype(fields), (n,))])


def points_per_packet(data_type: int) -> int:
    _, n, k, _ = POINT_TYPES[data_type]
    return n * k


def _sph(depth, theta, phi) -> np.ndarray:
    d = depth.astype(np.float32) * np.float32(1e-3)
    th = np.radians(theta.astype(np.float32) * np.float32(0.01))
    ph = np.radians(phi.astype(np.float32) * np.float32(0.01))
    st = np.sin(th)
    return np.stack([d * st * np.cos(ph), d * st * np.sin(ph), d * np.cos(th)], axis=-1)


def decode_points(packets: np.ndarray, data_type: int) -> tuple[np.ndarray, np.ndarray]:
    """Packets of one data type (structured array from :func:`packet_dtype`) -> (points (N,3) float32 m, reflectivity
    (N,) float32, keep mask over the packets' point slots), every return of every packet in order; no-return points (all zero) removed."""
    kind = POINT_TYPES[data_type][3]
    p = packets["pts"].reshape(-1)
    if kind == "cart":
        xyz = np.stack([p["x"], p["y"], p["z"]], axis=-1).astype(np.float32) * np.float32(1e-3)
        r = p["r"]
    elif kind == "sph":
        xyz, r = _sph(p["depth"], p["theta"], p["phi"]), p["r"]
    else:  # multi-return spherical: returns of one slot share the angles
        suffixes = ["", "2", "3"][: POINT_TYPES[data_type][2]]
        xyz = np.stack([_sph(p["depth" + s], p["theta"], p["phi"]) for s in suffixes], axis=1).reshape(-1, 3)
        r = np.stack([p["r" + s] for s in suffixes], axis=1).reshape(-1)
    keep = np.any(xyz != 0, axis=1)
    return np.ascontiguousarray(xyz[keep]), r[keep].astype(np.float32), keep


def encode_packets(xyz_m: np.ndarray, reflectivity: np.ndarray, t0_ns: int, data_type: int = 2, lidar_id: int = 1) -> np.ndarray:
    """Points (N,3) m -> packets (structured array) of ``data_type`` 0 or 2 (cartesian), timestamps t0 + 10 us per
    point. N must be a multiple of the points per packet. For the simulator and the tests."""
    if data_type not in (0, 2):
        raise ValueError("the encoder writes cartesian data types 0 and 2")
    n = POINT_TYPES[data_type][1]
    k = len(xyz_m) // n
    out = np.zeros(k, packet_dtype(data_type))
    out["version"] = 5
    out["id"] = lidar_id
    out["data_type"] = data_type
    out["timestamp"] = t0_ns + (np.arange(k, dtype=np.uint64) * np.uint64(n * 10_000))
    mm = np.round(np.asarray(xyz_m[: k * n], np.float64) * 1000.0).astype(np.int32).reshape(k, n, 3)
    out["pts"]["x"], out["pts"]["y"], out["pts"]["z"] = mm[..., 0], mm[..., 1], mm[..., 2]
    out["pts"]["r"] = np.asarray(reflectivity[: k * n]).reshape(k, n).astype(np.uint8)
    return out
