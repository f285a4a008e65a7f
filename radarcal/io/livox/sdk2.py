"""Livox SDK 2 (HAP, Mid-360): control frames and point packets. Pure byte/array code, no sockets.

Control frame (little-endian, 24-byte header): ``sof 0xAA, version 0, length u16 (whole frame), seq u32, cmd_id u16,
cmd_type u8 (0 request, 1 ack), sender_type u8 (0 host, 1 lidar), reserved[6], crc16 u16`` (CCITT-FALSE over the 18
bytes before it), ``crc32 u32`` (over the payload; 0 when empty), then the payload.

Commands used: discovery ``0x0000`` (empty request sent to the sensor's port 56000; the ack carries ret_code u8,
device type u8, serial[16], IP[4], command port u16), parameter write ``0x0100`` (key count u16, reserved u16, then
``key u16, length u16, value`` items: 0x0000 point data type, 0x0005 / 0x0006 / 0x0007 state / point / IMU host
address ``ip[4], host port u16, sensor port u16``, 0x001A work mode u8: 1 normal = streaming, 3 sleep; ack: ret_code
u8, error key u16), 0x0102 state push (the sensor's ~1 Hz "alive" message).

Point packet: a 36-byte header (version u8, length u16, time interval u16 [0.1 us], dot count u16, udp counter u16,
frame counter u8, data type u8, time type u8, reserved[12], crc32 u32, timestamp u64 ns) then the points: data type 1
cartesian high (int32 mm, reflectivity, tag: 14 bytes), 2 cartesian low (int16 cm: 8 bytes), 3 spherical (depth u32
mm, zenith theta u16 and azimuth phi u16 in 0.01 deg, reflectivity, tag: 10 bytes); data type 0 is IMU (ignored).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from radarcal.io.livox.crc import crc16_ccitt_false, crc32

__all__ = [
    "DEVICE_TYPES",
    "DISCOVERY",
    "DISCOVERY_PORT",
    "HEADER",
    "HEADER_SIZE",
    "KEY_DATA_TYPE",
    "KEY_IMU_HOST",
    "KEY_POINT_HOST",
    "KEY_STATE_HOST",
    "KEY_WORK_MODE",
    "POINT_TYPES",
    "PUSH",
    "SET_PARAMS",
    "Frame",
    "decode_points",
    "encode_packets",
    "pack_frame",
    "pack_params",
    "packet_dtype",
    "parse_frame",
    "parse_params",
]  # fmt: skip

SOF, VERSION = 0xAA, 0
REQ, ACK = 0, 1
DISCOVERY, SET_PARAMS, GET_PARAMS, PUSH = 0x0000, 0x0100, 0x0101, 0x0102
DISCOVERY_PORT = 56000
KEY_DATA_TYPE, KEY_STATE_HOST, KEY_POINT_HOST, KEY_IMU_HOST, KEY_WORK_MODE = 0x0000, 0x0005, 0x0006, 0x0007, 0x001A
WORK_NORMAL, WORK_SLEEP = 0x01, 0x03
DEVICE_TYPES = {9: "Mid-360", 10: "HAP (industrial)", 15: "HAP", 35: "Mid-360s", 40: "Avia2"}
_HDR = struct.Struct("<BBHIHBB6s")  # 18 bytes covered by crc16


@dataclass
class Frame:
    cmd_type: int
    seq: int
    cmd_id: int
    sender: int
    payload: bytes


def pack_frame(cmd_type: int, seq: int, cmd_id: int, payload: bytes = b"", sender: int = 0) -> bytes:
    head = _HDR.pack(SOF, VERSION, 24 + len(payload), seq & 0xFFFFFFFF, cmd_id, cmd_type, sender, b"\0" * 6)
    return head + struct.pack("<HI", crc16_ccitt_false(head), crc32(payload) if payload else 0) + payload


def parse_frame(buf: bytes) -> Frame | None:
    if len(buf) < 24 or buf[0] != SOF or buf[1] != VERSION:
        return None
    _, _, length, seq, cmd_id, cmd_type, sender, _ = _HDR.unpack_from(buf)
    c16, c32 = struct.unpack_from("<HI", buf, 18)
    if length != len(buf) or c16 != crc16_ccitt_false(buf[:18]):
        return None
    payload = bytes(buf[24:length])
    if c32 != (crc32(payload) if payload else 0):
        return None
    return Frame(cmd_type, seq, cmd_id, sender, payload)


def pack_params(items: list[tuple[int, bytes]]) -> bytes:
    return struct.pack("<HH", len(items), 0) + b"".join(struct.pack("<HH", k, len(v)) + v for k, v in items)


def parse_params(payload: bytes) -> dict[int, bytes] | None:
    if len(payload) < 4:
        return None
    n = struct.unpack_from("<H", payload)[0]
    out, pos = {}, 4
    for _ in range(n):
        if pos + 4 > len(payload):
            return None
        k, ln = struct.unpack_from("<HH", payload, pos)
        if pos + 4 + ln > len(payload):
            return None
        out[k] = payload[pos + 4 : pos + 4 + ln]
        pos += 4 + ln
    return out


def host_address(ip: str, host_port: int, lidar_port: int) -> bytes:
    return bytes(int(v) for v in ip.split(".")) + struct.pack("<HH", host_port, lidar_port)


# --- point packets ---------------------------------------------------------------------------------------------------
HEADER = [("version", "u1"), ("length", "<u2"), ("time_interval", "<u2"), ("dot_num", "<u2"), ("udp_cnt", "<u2"), ("frame_cnt", "u1"),
          ("data_type", "u1"), ("time_type", "u1"), ("rsvd", "u1", (12,)), ("crc32", "<u4"), ("timestamp", "<u8")]  # fmt: skip
HEADER_SIZE = np.dtype(HEADER).itemsize  # 36
POINT_TYPES: dict[int, tuple[list, str]] = {
    1: ([("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("r", "u1"), ("tag", "u1")], "cart_mm"),
    2: ([("x", "<i2"), ("y", "<i2"), ("z", "<i2"), ("r", "u1"), ("tag", "u1")], "cart_cm"),
    3: ([("depth", "<u4"), ("theta", "<u2"), ("phi", "<u2"), ("r", "u1"), ("tag", "u1")], "sph"),
}
IMU_TYPE = 0
POINTS_PER_PACKET = 96  # Mid-360 and HAP send 96 points per packet (the decoder reads dot_num, it does not assume it)


def point_size(data_type: int) -> int:
    return np.dtype(POINT_TYPES[data_type][0]).itemsize


def packet_dtype(data_type: int, n: int) -> np.dtype:
    return np.dtype(HEADER + [("pts", np.dtype(POINT_TYPES[data_type][0]), (n,))])


def decode_points(packets: np.ndarray, data_type: int) -> tuple[np.ndarray, np.ndarray]:
    """Packets of one data type and dot count -> (points (N,3) float32 m, reflectivity (N,) float32, keep mask over the point slots); zero points
    (no return) removed."""
    kind = POINT_TYPES[data_type][1]
    p = packets["pts"].reshape(-1)
    if kind == "sph":
        d = p["depth"].astype(np.float32) * np.float32(1e-3)
        th = np.radians(p["theta"].astype(np.float32) * np.float32(0.01))
        ph = np.radians(p["phi"].astype(np.float32) * np.float32(0.01))
        st = np.sin(th)
        xyz = np.stack([d * st * np.cos(ph), d * st * np.sin(ph), d * np.cos(th)], axis=-1)
    else:
        scale = np.float32(1e-3 if kind == "cart_mm" else 1e-2)
        xyz = np.stack([p["x"], p["y"], p["z"]], axis=-1).astype(np.float32) * scale
    keep = np.any(xyz != 0, axis=1)
    return np.ascontiguousarray(xyz[keep]), p["r"][keep].astype(np.float32), keep


def encode_packets(xyz_m: np.ndarray, reflectivity: np.ndarray, t0_ns: int, udp_cnt0: int = 0, point_interval_ns: float = 1e9 / 452_000,
                   data_type: int = 1, n: int = POINTS_PER_PACKET) -> np.ndarray:  # fmt: skip
    """Points (N,3) m -> SDK 2 packets (cartesian high / low), for the simulator and the tests. N a multiple of n."""
    k = len(xyz_m) // n
    out = np.zeros(k, packet_dtype(data_type, n))
    out["version"] = 0
    out["length"] = out.dtype.itemsize
    out["time_interval"] = round(n * point_interval_ns / 100.0)
    out["dot_num"] = n
    out["udp_cnt"] = (udp_cnt0 + np.arange(k)) & 0xFFFF
    out["data_type"] = data_type
    out["timestamp"] = np.uint64(t0_ns) + np.round(np.arange(k) * n * point_interval_ns).astype(np.uint64)
    scale = 1000.0 if data_type == 1 else 100.0
    v = np.round(np.asarray(xyz_m[: k * n], np.float64) * scale).astype(np.int32 if data_type == 1 else np.int16).reshape(k, n, 3)
    out["pts"]["x"], out["pts"]["y"], out["pts"]["z"] = v[..., 0], v[..., 1], v[..., 2]
    out["pts"]["r"] = np.asarray(reflectivity[: k * n]).reshape(k, n).astype(np.uint8)
    return out
