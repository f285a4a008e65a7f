"""A Livox LiDAR simulator on loopback UDP, speaking SDK 1 (Mid-70 and kin) or SDK 2 (HAP, Mid-360), so radarcal's
sensor control and decoding can be tested (and a station checked) without the sensor.

SDK 1: broadcasts ``(0, 0)`` to the host discovery port every ``broadcast_s`` until a handshake arrives, acks the
handshake / sampling / coordinate / heartbeat / disconnect commands, streams extended-cartesian packets (96 points,
10 us apart) to the data port named in the handshake while sampling, and falls back to broadcasting after
``hb_timeout_s`` without a heartbeat. SDK 2: answers discovery on its discovery port, takes the point-data host
address, data type and work mode from ``0x0100`` parameter writes, streams cartesian packets (96 points) to that
address in work mode "normal" and pushes a state message once a second.

Faults on request: :meth:`LivoxSimulator.outage` (silent for S seconds: no answers, no data, then a fresh sensor that
must be started again), :meth:`inject` malformed or truncated packets. The scene is a walled room scanned with the
Livox rosette (default; 2 s of it, repeated) or the clouds of a replay folder (``radarcal synth field``), one cloud per 1/hz of sensor
time. Everything binds to the loopback address given (127.x.y.z) and sends only to the host address given.
"""

from __future__ import annotations

import selectors
import socket
import struct
import threading
import time
from pathlib import Path

import numpy as np

from radarcal.io.livox import sdk1, sdk2
from radarcal.synth.lidar_patterns import livox_rosette_dirs

__all__ = ["MODELS", "LivoxSimulator", "room_scene"]

# model -> (sdk, device type, points per second, sensor command port, sensor point port)
MODELS = {
    "mid70": (1, 6, 100_000.0, sdk1.LIDAR_CMD_PORT, None),
    "mid40": (1, 1, 100_000.0, sdk1.LIDAR_CMD_PORT, None),
    "avia": (1, 7, 240_000.0, sdk1.LIDAR_CMD_PORT, None),
    "hap": (2, 15, 452_000.0, 56000, 57000),
    "mid360": (2, 9, 200_000.0, 56100, 56300),
}


def room_scene(n: int, rate: float, t0: float = 0.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` rosette returns (LiDAR frame, m) in a room: floor 1.2 m below, walls at x = 18 m and y = +-7 m, no
    ceiling (those rays return nothing: zero points, as a real Livox sends), walls 4.2 m high, two boxes. Reflectivity by surface."""
    rng = np.random.default_rng(seed)
    d = livox_rosette_dirs(t0 + np.arange(n) / rate)
    with np.errstate(divide="ignore", invalid="ignore"):
        planes = [(2, -1.2, 40.0), (0, 18.0, 120.0), (1, 7.0, 80.0), (1, -7.0, 80.0)]
        best = np.full(n, np.inf)
        refl = np.zeros(n)
        for axis, c, r in planes:
            t = c / d[:, axis]
            hit = (t > 0.1) & (t < best) & ((axis == 2) | (t * d[:, 2] < 3.0))  # walls are 4.2 m high
            best[hit], refl[hit] = t[hit], r
        for lo, hi, r in (((6.0, -1.5, -1.2), (7.0, -0.5, -0.2), 200.0), ((10.0, 1.0, -1.2), (11.0, 2.5, 0.3), 160.0)):
            lo_a, hi_a = np.array(lo), np.array(hi)
            t1, t2 = lo_a / d, hi_a / d
            tn = np.nanmax(np.minimum(t1, t2), axis=1)
            tf = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (tn <= tf) & (tn > 0.1) & (tn < best)
            best[hit], refl[hit] = tn[hit], r
    ok = np.isfinite(best) & (best < 60)
    xyz = np.zeros((n, 3))
    xyz[ok] = d[ok] * (best[ok] + rng.normal(0, 0.01, ok.sum()))[:, None]
    return xyz, np.where(ok, np.clip(refl + rng.normal(0, 2, n), 1, 255), 0)


class LivoxSimulator:
    """One simulated LiDAR. ``host`` is where it sends broadcasts (SDK 1) - the simulator never sends anywhere else
    than the addresses the host gives it. Counters: ``packets_sent``, ``points_sent`` (returns, zero points excluded),
    ``slots_sent``, ``bad_sent``, ``truncated_sent``, ``handshakes``, ``outages``."""

    def __init__(self, model: str = "mid70", ip: str = "127.0.0.1", host: str = "127.0.0.1", discovery_port: int | None = None, cmd_port: int | None = None,
                 rate: float | None = None, scene: str | Path | None = None, hz: float = 10.0, max_packets: int | None = None, broadcast_s: float = 0.2,
                 hb_timeout_s: float = 3.0, seed: int = 0, t0_ns: int = 5_000_000_000, discovery_bind: str | None = None,
                 T_sensor_scene: np.ndarray | None = None):  # fmt: skip
        if model not in MODELS:
            raise ValueError(f"unknown model {model!r} ({', '.join(MODELS)})")
        self.model = model
        self.sdk, self.dev_type, default_rate, default_cmd, self.point_port = MODELS[model]
        self.rate = float(rate or default_rate)
        self.ip, self.host = ip, host
        self.cmd_port = cmd_port or default_cmd
        self.discovery_port = discovery_port or (sdk1.BROADCAST_PORT if self.sdk == 1 else sdk2.DISCOVERY_PORT)
        self.npp = 96
        self.step_ns = self.npp * 1e9 / self.rate
        self.hz = hz
        self.max_packets = max_packets
        self.broadcast_s = broadcast_s
        self.hb_timeout_s = hb_timeout_s
        self.seed = seed
        self.t0_ns = t0_ns
        self.T_sensor_scene = None if T_sensor_scene is None else np.asarray(T_sensor_scene, float)  # scene points -> this sensor's frame
        self.scene_clouds = sorted(p for p in Path(scene, "clouds").iterdir() if p.suffix in (".pcd", ".npy", ".bin", ".ply")) if scene else None
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.packets_sent = self.points_sent = self.slots_sent = self.bad_sent = self.truncated_sent = 0
        self.handshakes = self.outages = 0
        self.streaming = False
        self._k = 0  # next packet index (sensor time t0 + k * step)
        self._stream_t0 = 0.0
        self._k_at_start = 0
        self._data_addr: tuple[str, int] | None = None
        self._state_addr: tuple[str, int] | None = None
        self._last_hb = 0.0
        self._mute_until = 0.0
        self._inject: list[str] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.data_type = 2 if self.sdk == 1 else 1
        self.sel = selectors.DefaultSelector()
        self.cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cmd.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.cmd.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
        self.cmd.bind((ip, self.cmd_port))
        self.cmd.setblocking(False)
        self.sel.register(self.cmd, selectors.EVENT_READ)
        self.disc = None
        if self.sdk == 2 and self.discovery_port != self.cmd_port:
            self.disc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.disc.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.disc.bind((discovery_bind or ip, self.discovery_port))  # "0.0.0.0": also hears broadcast discovery (isolated test networks)
            self.disc.setblocking(False)
            self.sel.register(self.disc, selectors.EVENT_READ)
        self.disc_tx = None
        if discovery_bind and self.disc is not None:  # answer from our own address (the host takes the source IP as the sensor's)
            self.disc_tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.disc_tx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.disc_tx.bind((ip, self.discovery_port))
            self.disc_tx.setblocking(False)
            self.sel.register(self.disc_tx, selectors.EVENT_READ)  # unicast discovery arrives here
        self.data = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.data.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
        self.data.bind((ip, self.point_port or 0))
        self._created = time.monotonic()
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"livox-sim-{model}")

    # --- control ------------------------------------------------------------------------------------------------------
    def start(self) -> LivoxSimulator:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)
        for s in (self.cmd, self.disc, self.disc_tx, self.data):
            if s is not None:
                s.close()

    def outage(self, seconds: float) -> None:
        """Go silent for ``seconds`` (no answers, no data, heartbeats ignored), then come back unconnected."""
        with self._lock:
            self._mute_until = time.monotonic() + seconds
            self.outages += 1

    def inject(self, kind: str, n: int = 1) -> None:
        """Send ``n`` bad packets among the next good ones: ``malformed`` (unknown data type / garbage) or ``truncated``."""
        if kind not in ("malformed", "truncated"):
            raise ValueError(kind)
        with self._lock:
            self._inject += [kind] * n

    def done(self) -> bool:
        return self.max_packets is not None and self.packets_sent >= self.max_packets

    # --- scene -------------------------------------------------------------------------------------------------------
    def _points(self, k0: int, k1: int) -> tuple[np.ndarray, np.ndarray]:
        """Points of packets k0..k1-1 (LiDAR frame, m) and their reflectivity."""
        n = (k1 - k0) * self.npp
        if self.scene_clouds is None:
            return room_scene(n, self.rate, t0=k0 * self.step_ns * 1e-9, seed=self.seed + k0)
        per = self.rate / self.hz
        idx = np.arange(k0 * self.npp, k1 * self.npp)
        ci = (idx // per).astype(int) % len(self.scene_clouds)
        xyz, refl = np.zeros((n, 3)), np.zeros(n)
        for c in np.unique(ci):
            pts, inten = self._cloud(int(c))
            sel = ci == c
            j = (idx[sel] - int(np.ceil(c * per))) % len(pts) if len(pts) else None
            if len(pts):
                xyz[sel], refl[sel] = pts[j], inten[j]
        return xyz, refl

    def _cloud(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        if i not in self._cache:
            from radarcal.io import read_cloud

            c = read_cloud(self.scene_clouds[i])
            self._cache = {i: (c.points.astype(np.float64), c.intensity if c.intensity is not None else np.full(len(c), 100.0))}
        return self._cache[i]

    def _encode(self, k0: int, k1: int) -> np.ndarray:
        """Packets k0..k1-1 with their sensor times and counters."""
        xyz, refl = self._points(k0, k1)
        if self.T_sensor_scene is not None:
            hit = np.any(xyz != 0, axis=1)
            xyz[hit] = xyz[hit] @ self.T_sensor_scene[:3, :3].T + self.T_sensor_scene[:3, 3]
        t0 = int(self.t0_ns + round(k0 * self.step_ns))
        if self.sdk == 1:
            pk = sdk1.encode_packets(xyz, refl, t0, self.data_type)
            pk["timestamp"] = self.t0_ns + np.round((k0 + np.arange(len(pk))) * self.step_ns).astype(np.uint64)
        else:
            pk = sdk2.encode_packets(xyz, refl, t0, udp_cnt0=k0, point_interval_ns=1e9 / self.rate, data_type=self.data_type, n=self.npp)
            pk["timestamp"] = self.t0_ns + np.round((k0 + np.arange(len(pk))) * self.step_ns).astype(np.uint64)
        return pk

    POOL_S = 2.0  # the room scene repeats every 2 s of packets (the rosette's points are computed once)

    def _packets(self, k0: int, k1: int) -> list[bytes]:
        if self.scene_clouds is None:  # static room: scan 2 s once, then resend it with new times and counters
            n_pool = max(1, int(round(self.POOL_S * self.rate / self.npp)))
            if getattr(self, "_pool", None) is None:
                self._pool = self._encode(0, n_pool)
            k = np.arange(k0, k1)
            pk = self._pool[k % n_pool]
            pk["timestamp"] = self.t0_ns + np.round(k * self.step_ns).astype(np.uint64)
            if self.sdk == 2:
                pk["udp_cnt"] = k & 0xFFFF
        else:
            pk = self._encode(k0, k1)
        slots = pk["pts"].reshape(len(pk), -1)
        nz = np.any(np.stack([slots["x"], slots["y"], slots["z"]], -1) != 0, axis=-1).sum(axis=1)
        raw = pk.tobytes()
        size = pk.dtype.itemsize
        self._nz = nz
        return [raw[i * size : (i + 1) * size] for i in range(len(pk))]

    # --- protocol -----------------------------------------------------------------------------------------------------
    def _reply1(self, f: sdk1.Frame, addr, payload: bytes) -> None:
        self.cmd.sendto(sdk1.pack_frame(sdk1.ACK, f.seq, f.cmd_set, f.cmd_id, payload), addr)

    def _on1(self, f: sdk1.Frame, addr) -> None:
        if f.cmd_set != 0 or f.cmd_type not in (sdk1.CMD, sdk1.ACK):
            return
        if f.cmd_id == sdk1.HANDSHAKE and len(f.payload) >= 10:
            data_port = struct.unpack_from("<H", f.payload, 4)[0]
            self._data_addr = (socket.inet_ntoa(f.payload[:4]), data_port)
            self._cmd_addr = addr
            self.handshakes += 1
            self._last_hb = time.monotonic()
            self._reply1(f, addr, b"\x00")
        elif self._data_addr is None:
            return
        elif f.cmd_id == sdk1.HEARTBEAT:
            self._last_hb = time.monotonic()
            self._reply1(f, addr, b"\x00\x01\x00" + b"\0" * 4)
        elif f.cmd_id == sdk1.SAMPLE:
            self._reply1(f, addr, b"\x00")
            self._set_streaming(f.payload[:1] == b"\x01")
        elif f.cmd_id == sdk1.COORDINATE:
            self.data_type = 2  # the simulator streams extended cartesian whatever is asked
            self._reply1(f, addr, b"\x00")
        elif f.cmd_id == sdk1.DISCONNECT:
            self._reply1(f, addr, b"\x00")
            self._reset()
        else:
            self._reply1(f, addr, b"\x00")

    def _on2(self, sock, f: sdk2.Frame, addr) -> None:
        if f.cmd_type != sdk2.REQ:
            return
        if f.cmd_id == sdk2.DISCOVERY:
            ack = bytes([0, self.dev_type]) + b"SIM" + str(self.seed).encode()[:13].ljust(13, b"\0") + socket.inet_aton(self.ip) + struct.pack("<H", self.cmd_port)
            (self.disc_tx or sock).sendto(sdk2.pack_frame(sdk2.ACK, f.seq, sdk2.DISCOVERY, ack, sender=1), addr)
        elif f.cmd_id == sdk2.GET_PARAMS and len(f.payload) >= 4:  # parameter query: key count u16, reserved u16, keys u16...
            n = struct.unpack_from("<H", f.payload)[0]
            keys = struct.unpack_from(f"<{n}H", f.payload, 4) if len(f.payload) >= 4 + 2 * n else ()
            vals = {0x8000: f"SIM{self.seed:013d}".encode()[:16], 0x8010: b"\x01", 0x8006: bytes([sdk2.WORK_NORMAL if self.streaming else sdk2.WORK_SLEEP])}
            items = b"".join(struct.pack("<HH", k, len(vals.get(k, b"\0"))) + vals.get(k, b"\0") for k in keys)
            sock.sendto(sdk2.pack_frame(sdk2.ACK, f.seq, f.cmd_id, b"\x00" + struct.pack("<H", len(keys)) + items, sender=1), addr)
        elif f.cmd_id == sdk2.SET_PARAMS:
            kv = sdk2.parse_params(f.payload)
            if kv is None:
                sock.sendto(sdk2.pack_frame(sdk2.ACK, f.seq, f.cmd_id, b"\x01\x00\x00", sender=1), addr)
                return
            if sdk2.KEY_POINT_HOST in kv:
                v = kv[sdk2.KEY_POINT_HOST]
                self._data_addr = (socket.inet_ntoa(v[:4]), struct.unpack_from("<H", v, 4)[0])
            if sdk2.KEY_STATE_HOST in kv:
                v = kv[sdk2.KEY_STATE_HOST]
                self._state_addr = (socket.inet_ntoa(v[:4]), struct.unpack_from("<H", v, 4)[0])
            if sdk2.KEY_DATA_TYPE in kv and kv[sdk2.KEY_DATA_TYPE][:1] in (b"\x01", b"\x02"):
                self.data_type = kv[sdk2.KEY_DATA_TYPE][0]
            sock.sendto(sdk2.pack_frame(sdk2.ACK, f.seq, f.cmd_id, b"\x00\x00\x00", sender=1), addr)
            if sdk2.KEY_WORK_MODE in kv and self._data_addr is not None:
                if kv[sdk2.KEY_WORK_MODE][:1] == bytes([sdk2.WORK_NORMAL]):
                    self.handshakes += 1
                self._set_streaming(kv[sdk2.KEY_WORK_MODE][:1] == bytes([sdk2.WORK_NORMAL]))

    def _set_streaming(self, on: bool) -> None:
        if on and not self.streaming:
            self._stream_t0 = time.monotonic()
            # sensor time runs with the wall clock since power-on: after an outage the timestamps jump
            self._k = max(self._k, int((self._stream_t0 - self._created) * 1e9 / self.step_ns))
            self._k_at_start = self._k
        self.streaming = on

    def _reset(self) -> None:
        self.streaming = False
        self._data_addr = self._state_addr = None

    # --- loop ---------------------------------------------------------------------------------------------------------
    def _run(self) -> None:
        last_bc = last_push = 0.0
        muted = False
        while not self._stop.is_set():
            for key, _ in self.sel.select(0.002):
                while True:
                    try:
                        buf, addr = key.fileobj.recvfrom(2048)
                    except (BlockingIOError, OSError):
                        break
                    if muted:
                        continue
                    if self.sdk == 1:
                        f = sdk1.parse_frame(buf)
                        if f is not None:
                            self._on1(f, addr)
                    else:
                        f = sdk2.parse_frame(buf)
                        if f is not None:
                            self._on2(key.fileobj, f, addr)
            now = time.monotonic()
            with self._lock:
                mute_until = self._mute_until
            if now < mute_until:
                if not muted:
                    muted = True
                    self._reset()
                continue
            if muted:  # back after the outage: a fresh sensor (not connected); its clock went on
                muted = False
            if self.sdk == 1 and self._data_addr is not None and now - self._last_hb > self.hb_timeout_s:
                self._reset()
            if self.sdk == 1 and self._data_addr is None and now - last_bc >= self.broadcast_s:
                last_bc = now
                code = f"SIM{self.model.upper()}{self.seed:04d}".encode()[:15].ljust(16, b"\0")
                self.cmd.sendto(sdk1.pack_frame(sdk1.MSG, 0, 0, sdk1.BROADCAST, code + bytes([self.dev_type]) + b"\0\0"), (self.host, self.discovery_port))
            if self.sdk == 2 and self.streaming and self._state_addr and now - last_push >= 1.0:
                last_push = now
                self.cmd.sendto(sdk2.pack_frame(sdk2.REQ, 0, sdk2.PUSH, struct.pack("<HH", 1, 0) + struct.pack("<HH", 0x8006, 1) + b"\x01", sender=1), self._state_addr)
            if self.streaming and self._data_addr is not None and not self.done():
                self._stream(now)

    def _stream(self, now: float) -> None:
        due = self._k_at_start + int((now - self._stream_t0) * 1e9 / self.step_ns) + 1
        if self.max_packets is not None:
            due = min(due, self.max_packets + (self._k - self.packets_sent))
        k0 = self._k
        if due <= k0:
            return
        k1 = min(due, k0 + 512)
        if due - k0 > 5 * 512:  # we fell far behind (outage, suspended): sensor time jumps, like a real sensor's clock
            self._k = k0 = due - 1
            self._k_at_start = self._k
            self._stream_t0 = now
            k1 = k0 + 1
        pkts = self._packets(k0, k1)
        nz = self._nz
        with self._lock:
            m = min(len(pkts), 4)
            bad, self._inject = self._inject[:m][::-1], self._inject[m:]
        for i, p in enumerate(pkts):
            self.data.sendto(p, self._data_addr)
            self.packets_sent += 1
            self.points_sent += int(nz[i])
            self.slots_sent += self.npp
            if bad:
                kind = bad.pop()
                if kind == "truncated":
                    self.data.sendto(p[: len(p) // 2], self._data_addr)
                    self.truncated_sent += 1
                else:
                    junk = bytearray(p)
                    junk[9 if self.sdk == 1 else 10] = 0x7E  # an unknown data type
                    self.data.sendto(bytes(junk), self._data_addr)
                    self.bad_sent += 1
        self._k = k1
