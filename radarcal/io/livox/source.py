"""Live Livox LiDARs: radarcal starts the sensor itself (SDK 1 discovery / handshake / heartbeat / sampling, or SDK 2
discovery / parameter write / work mode), receives its point packets in a thread and hands out clouds with
:meth:`LivoxSource.poll` (never blocks). :class:`PacketDecoder` turns raw packets (live, or from a recording) into
clouds: packets are batched and decoded with numpy, clouds cut every ``frame_s`` of *sensor* time, each stamped with
the host receive time (:func:`radarcal.io.clock.now`) of its last packet, so that a replay of the recorded packets
gives the same clouds.
"""

from __future__ import annotations

import itertools
import selectors
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from radarcal.errors import InputError
from radarcal.io import clock
from radarcal.io.clouds import Cloud
from radarcal.io.livox import sdk1, sdk2

__all__ = ["LivoxHealth", "LivoxSource", "PacketDecoder", "local_ip_towards", "parse_livox_url"]


@dataclass
class LivoxHealth:
    """Counters of one LiDAR (read by the status line and the JSON summary)."""

    sensor: str = ""
    sdk: int | None = None
    device: str = ""
    state: str = "searching"  # searching | handshake | streaming | lost | closed
    packets: int = 0  # good point packets
    points: int = 0  # decoded points (no-return points excluded)
    raw_points: int = 0  # point slots in good packets (what the sensor sent)
    imu_packets: int = 0
    bad_packets: int = 0  # malformed (unknown type, bad header / length)
    truncated_packets: int = 0
    drops: int = 0  # packets missing from the sequence (SDK 2 udp counter, SDK 1 timestamp steps)
    reconnects: int = 0
    clouds: int = 0
    overflow_clouds: int = 0  # clouds discarded because nobody polled
    last_t: float | None = None  # clock.now() of the last good packet
    cpu_s: float = 0.0  # CPU time of the source's I/O thread (receive + decode)
    _rate: deque = field(default_factory=lambda: deque(maxlen=64), repr=False)

    def note_rate(self, t: float, n_points: int) -> None:
        self._rate.append((t, n_points))

    def rate(self) -> float:
        """Points per second over the last ~2 s of packets."""
        r = list(self._rate)
        if len(r) < 2:
            return 0.0
        t_end = r[-1][0]
        keep = [x for x in r if t_end - x[0] <= 2.0]
        dt = keep[-1][0] - keep[0][0]
        return sum(n for _, n in keep[1:]) / dt if dt > 0 else 0.0

    def snapshot(self, now: float | None = None) -> dict:
        now = clock.now() if now is None else now
        return {"sensor": self.sensor, "sdk": self.sdk, "device": self.device, "state": self.state, "packets": self.packets, "points": self.points,
                "raw_points": self.raw_points, "imu_packets": self.imu_packets, "bad_packets": self.bad_packets, "truncated_packets": self.truncated_packets,
                "drops": self.drops, "reconnects": self.reconnects, "clouds": self.clouds, "overflow_clouds": self.overflow_clouds,
                "rate_pts_s": round(self.rate(), 1), "cpu_s": round(self.cpu_s, 3), "last_seen_age_s": None if self.last_t is None else round(now - self.last_t, 3)}  # fmt: skip


class PacketDecoder:
    """Raw point packets (one LiDAR, SDK 1 or 2) -> clouds of ``frame_s`` sensor time. :meth:`feed` only queues;
    :meth:`flush` decodes the queued packets in vectorised batches and returns the clouds completed so far."""

    OUTAGE_S = 0.5  # a sensor-time gap longer than this is an outage (reconnect), not dropped packets

    def __init__(self, sdk: int, frame_s: float = 0.1, sensor: str = "", health: LivoxHealth | None = None):
        if sdk not in (1, 2):
            raise ValueError("sdk must be 1 or 2")
        self.sdk = sdk
        self.frame_ns = round(frame_s * 1e9)
        self.sensor = sensor
        self.health = health or LivoxHealth(sensor=sensor, sdk=sdk)
        self._queue: list[tuple[bytes, float]] = []
        self._parts: list[tuple[np.ndarray, np.ndarray]] = []
        self._open: int | None = None  # frame index of the open cloud
        self._open_t = 0.0
        self._ts0: int | None = None
        self._last_ts: int | None = None
        self._last_cnt: int | None = None
        self._out: list[Cloud] = []

    def feed(self, buf: bytes, t: float) -> None:
        self._queue.append((buf, t))

    def pending(self) -> int:
        return len(self._queue)

    # --- classification -------------------------------------------------------------------------------------------
    def _key(self, buf: bytes) -> tuple | None:
        """(data type, packet size, points per packet) of a good point packet; None after counting a bad one, or an
        IMU packet."""
        h = self.health
        n = len(buf)
        if self.sdk == 1:
            if n < sdk1.HEADER_SIZE:
                h.truncated_packets += 1 if n > 0 else 0
                h.bad_packets += 1 if n == 0 else 0
                return None
            dt = buf[9]
            if dt == sdk1.IMU_TYPE:
                h.imu_packets += 1
                return None
            if dt not in sdk1.POINT_TYPES:
                h.bad_packets += 1
                return None
            size = sdk1.packet_dtype(dt).itemsize
            if n != size:
                if n < size:
                    h.truncated_packets += 1
                else:
                    h.bad_packets += 1
                return None
            return (dt, size, sdk1.points_per_packet(dt))
        if n < sdk2.HEADER_SIZE:
            h.truncated_packets += 1
            return None
        length, dot_num = struct.unpack_from("<H", buf, 1)[0], struct.unpack_from("<H", buf, 5)[0]
        dt = buf[10]
        if dt == sdk2.IMU_TYPE:
            h.imu_packets += 1
            return None
        if dt not in sdk2.POINT_TYPES or buf[0] != 0 or length != sdk2.HEADER_SIZE + dot_num * sdk2.point_size(dt) or dot_num == 0:
            h.bad_packets += 1
            return None
        if n != length:
            if n < length:
                h.truncated_packets += 1
            else:
                h.bad_packets += 1
            return None
        return (dt, length, dot_num)

    # --- decoding ---------------------------------------------------------------------------------------------------
    def flush(self) -> list[Cloud]:
        q, self._queue = self._queue, []
        run: list[tuple[bytes, float]] = []
        run_key = None
        for buf, t in q:
            k = self._key(buf)
            if k is None:
                continue
            if k != run_key and run:
                self._decode_run(run_key, run)
                run = []
            run_key = k
            run.append((buf, t))
        if run:
            self._decode_run(run_key, run)
        out, self._out = self._out, []
        return out

    def _decode_run(self, key: tuple, run: list[tuple[bytes, float]]) -> None:
        dt, _, npp = key
        if self.sdk == 1:
            pk = np.frombuffer(b"".join(b for b, _ in run), sdk1.packet_dtype(dt))
            xyz, refl, keep = sdk1.decode_points(pk, dt)
            step = npp * int(sdk1.POINT_INTERVAL_S * 1e9)
        else:
            pk = np.frombuffer(b"".join(b for b, _ in run), sdk2.packet_dtype(dt, npp))
            xyz, refl, keep = sdk2.decode_points(pk, dt)
            step = max(int(pk["time_interval"][0]) * 100, 1)
        ts = pk["timestamp"].astype(np.int64)
        t_recv = np.array([t for _, t in run])
        h = self.health
        h.packets += len(pk)
        h.raw_points += len(pk) * npp
        h.points += len(xyz)
        h.last_t = float(t_recv[-1])
        h.note_rate(float(t_recv[-1]), len(xyz))
        # drops: SDK 2 udp counter gaps; SDK 1 timestamp steps of more than one packet (not outages)
        prev_ts = self._last_ts if self._last_ts is not None else int(ts[0]) - step
        dts = np.diff(np.concatenate([[prev_ts], ts]))
        if self.sdk == 2:
            cnt = pk["udp_cnt"].astype(np.int64)
            prev = self._last_cnt if self._last_cnt is not None else int(cnt[0]) - 1
            gap = (np.diff(np.concatenate([[prev], cnt])) - 1) % 65536
            self._last_cnt = int(cnt[-1])
        else:
            gap = np.rint(dts / step).astype(np.int64) - 1
        ok = (dts >= 0) & (dts < self.OUTAGE_S * 1e9)
        h.drops += int(np.clip(gap[ok], 0, 1000).sum())
        self._last_ts = int(ts[-1])
        # frame index per packet; a reset (sensor time backwards, or an outage) restarts the frame grid
        cuts = set(np.flatnonzero(~ok).tolist())
        bounds = sorted({0, len(pk), *cuts})
        pidx = np.repeat(np.arange(len(pk)), npp)[keep]
        for a, b in itertools.pairwise(bounds):
            if self._ts0 is None or a in cuts:
                self._close()
                self._open = None
                self._ts0 = int(ts[a])
            fidx = (ts[a:b] - self._ts0) // self.frame_ns
            lo, hi = np.searchsorted(pidx, [a, b])
            self._assign(fidx, t_recv[a:b], xyz[lo:hi], refl[lo:hi], pidx[lo:hi] - a)

    def _assign(self, fidx: np.ndarray, t_recv: np.ndarray, xyz: np.ndarray, refl: np.ndarray, pidx: np.ndarray) -> None:
        """Append packets (frame index per packet) to the open cloud, closing it whenever the frame index grows."""
        change = np.flatnonzero(np.diff(fidx)) + 1
        starts = np.concatenate([[0], change])
        ends = np.concatenate([change, [len(fidx)]])
        for s, e in zip(starts, ends):
            f = int(fidx[s])
            if self._open is not None and f != self._open:
                self._close()
            self._open = f
            lo, hi = np.searchsorted(pidx, [s, e])
            self._parts.append((xyz[lo:hi], refl[lo:hi]))
            self._open_t = float(t_recv[e - 1])

    def _close(self) -> None:
        if self._parts:
            pts = np.concatenate([p for p, _ in self._parts]) if len(self._parts) > 1 else self._parts[0][0]
            inten = np.concatenate([r for _, r in self._parts]) if len(self._parts) > 1 else self._parts[0][1]
            if len(pts):
                self._out.append(Cloud(pts, inten, t=self._open_t, sensor=self.sensor, name=f"{self.sensor or 'livox'}@{self._open_t:.3f}"))
                self.health.clouds += 1
        self._parts = []

    def finish(self) -> list[Cloud]:
        """Flush and close the open cloud (end of a recording)."""
        out = self.flush()
        self._close()
        out += self._out
        self._out = []
        return out


# --- live sensors ----------------------------------------------------------------------------------------------------
def local_ip_towards(ip: str) -> str:
    """The host address the kernel would use to reach ``ip`` (a UDP connect: no packet is sent)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.connect((ip, 9))
        return s.getsockname()[0]
    except OSError:
        return "0.0.0.0"
    finally:
        s.close()


def parse_livox_url(spec: str) -> dict:
    """``livox://IP`` (SDK chosen by whichever protocol the sensor answers), ``livox1://IP``, ``livox2://IP``; options
    after ``?``: ``host=`` (our address, default: the one that reaches IP), ``frame=`` (s), ``discovery_port=``,
    ``cmd_port=`` (sensor side), ``name=``. ``livox://HOST:PORT`` with a port: listen only (SDK 1 packets on PORT,
    the handshake done by another tool; the old behaviour)."""
    scheme, _, rest = spec.partition("://")
    sdk = {"livox": None, "livox1": 1, "livox2": 2}.get(scheme)
    if sdk is None and scheme != "livox":
        raise InputError(spec, "expected livox://IP, livox1://IP or livox2://IP")
    addr, _, query = rest.partition("?")
    opts: dict = {"sdk": sdk, "listen_port": None}
    host, _, port = addr.rpartition(":") if ":" in addr else (addr, "", "")
    if port:
        if not port.isdigit():
            raise InputError(spec, "expected livox://HOST:PORT with a numeric port")
        opts["listen_port"] = int(port)
    opts["ip"] = host or "0.0.0.0"
    try:
        socket.inet_aton(opts["ip"])
    except OSError:
        raise InputError(spec, f"not an IPv4 address: {opts['ip']!r}") from None
    for kv in filter(None, query.split("&")):
        k, _, v = kv.partition("=")
        if k in ("host", "name"):
            opts[k] = v
        elif k in ("frame", "timeout"):
            opts[k] = float(v)
        elif k in ("discovery_port", "cmd_port", "data_type"):
            opts[k] = int(v)
        else:
            raise InputError(spec, f"unknown option {k!r} (host, name, frame, timeout, discovery_port, cmd_port, data_type)")
    return opts


def _big_receive_buffer(sock: socket.socket, size: int = 64 << 20) -> None:
    """A kernel receive buffer that rides out a stalled reader (64 MB ~ 10 s of HAP packets): SO_RCVBUFFORCE when
    allowed (root / CAP_NET_ADMIN), else SO_RCVBUF, which the kernel caps at net.core.rmem_max (raise it with
    ``sysctl -w net.core.rmem_max=67108864`` on the station)."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, getattr(socket, "SO_RCVBUFFORCE", 33), size)
    except OSError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)


class _Sdk1Discovery:
    """One socket per (address, port) receiving SDK 1 broadcasts, shared by every SDK 1 source of the process and
    dispatched by the sender's IP (several LiDARs broadcast to the same host port)."""

    _shared: ClassVar[dict[tuple[str, int], _Sdk1Discovery]] = {}
    _lock = threading.Lock()

    def __init__(self, bind: tuple[str, int]):
        self.bind = bind
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(bind)
        self.sock.settimeout(0.1)
        self.subs: dict[str, Callable] = {}
        self.users = 0
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True, name=f"livox1-discovery-{bind[1]}")
        self.thread.start()

    @classmethod
    def get(cls, bind: tuple[str, int]) -> _Sdk1Discovery:
        with cls._lock:
            d = cls._shared.get(bind)
            if d is None:
                d = cls._shared[bind] = cls(bind)
            d.users += 1
            return d

    def release(self) -> None:
        with self._lock:
            self.users -= 1
            if self.users <= 0:
                self._shared.pop(self.bind, None)
                self._stop.set()
                self.thread.join(1.0)
                self.sock.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                buf, addr = self.sock.recvfrom(2048)
            except TimeoutError:
                continue
            except OSError:
                break
            f = sdk1.parse_frame(buf)
            cb = self.subs.get(addr[0])
            if f is not None and f.cmd_set == 0 and f.cmd_id == sdk1.BROADCAST and cb is not None:
                cb(f, addr)


class LivoxSource:
    """One live Livox LiDAR. ``start()`` opens the sockets and the I/O thread; ``poll()`` returns the clouds completed
    since the last call (never blocks); ``close()`` stops sampling and closes. ``health`` holds the counters.

    ``packet_tap(sensor, kind, t, bytes)`` (optional) sees every raw datagram received (kind ``data`` / ``cmd``), for
    recordings. Ports default to the vendor's; tests and the simulator move them (``discovery_port``, ``cmd_port``)."""

    def __init__(self, ip: str, sdk: int | None = None, host: str | None = None, sensor: str = "", frame_s: float = 0.1, timeout_s: float = 2.0,
                 discovery_port: int | None = None, cmd_port: int | None = None, data_type: int | None = None, max_clouds: int = 50,
                 listen_port: int | None = None, packet_tap: Callable | None = None):  # fmt: skip
        self.ip = ip
        self.sdk = sdk
        self.host = host or (local_ip_towards(ip) if listen_port is None else ip)
        self.sensor = sensor
        self.frame_s = float(frame_s)
        self.timeout_s = float(timeout_s)
        self.discovery_port = discovery_port
        self.lidar_cmd_port = cmd_port
        self.data_type = data_type
        self.listen_port = listen_port
        self.tap = packet_tap
        self.health = LivoxHealth(sensor=sensor, sdk=sdk)
        self.clouds: deque[Cloud] = deque()
        self.max_clouds = max_clouds
        self._decoder: PacketDecoder | None = PacketDecoder(sdk, frame_s, sensor, self.health) if sdk else None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._seq = 0
        self._ever_streamed = False
        self._disc1: _Sdk1Discovery | None = None
        self._sdk1_addr: tuple[str, int] | None = None
        self._sdk2_cmd: tuple[str, int] | None = None
        self._last_alive = 0.0
        self._last_hb = 0.0
        self._last_try = 0.0
        self._inbox: deque = deque()
        self.sel = selectors.DefaultSelector()

    # --- public ----------------------------------------------------------------------------------------------------
    def start(self) -> LivoxSource:
        what = f"livox://{self.ip}"
        try:
            self.data_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            _big_receive_buffer(self.data_sock)
            if self.listen_port is not None:
                self.data_sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self.data_sock.bind((self.ip, self.listen_port))
                self.sdk = self.sdk or 1
                self._decoder = PacketDecoder(self.sdk, self.frame_s, self.sensor, self.health)
                self.health.sdk, self.health.state = self.sdk, "listening"
            else:
                self.data_sock.bind((self.host, 0))
                self.cmd_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                self.cmd_sock.bind((self.host, 0))
                self.cmd_sock.setblocking(False)
                self.sel.register(self.cmd_sock, selectors.EVENT_READ, "cmd")
                if self.sdk in (None, 1):
                    self._disc1 = _Sdk1Discovery.get((self.host if self.host != "0.0.0.0" else "", self.discovery_port or sdk1.BROADCAST_PORT))
                    self._disc1.subs[self.ip] = lambda f, addr: self._inbox.append((f, addr))
        except OSError as e:
            raise InputError(what, f"cannot open UDP sockets on {self.host} ({e.strerror})") from None
        self.data_sock.setblocking(False)
        self.sel.register(self.data_sock, selectors.EVENT_READ, "data")
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"livox-{self.sensor or self.ip}")
        self._thread.start()
        return self

    def poll(self) -> list[Cloud]:
        with self._lock:
            out = list(self.clouds)
            self.clouds.clear()
        return out

    def close(self) -> None:
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join(2.0)
        self._thread = None
        try:
            if self.health.state == "streaming":
                if self.sdk == 1 and self._sdk1_addr:
                    self._send1(sdk1.SAMPLE, b"\x00")
                    self._send1(sdk1.DISCONNECT)
                elif self.sdk == 2 and self._sdk2_cmd:
                    self._send2(sdk2.SET_PARAMS, sdk2.pack_params([(sdk2.KEY_WORK_MODE, bytes([sdk2.WORK_SLEEP]))]))
        except OSError:
            pass
        if self._disc1 is not None:
            self._disc1.subs.pop(self.ip, None)
            self._disc1.release()
            self._disc1 = None
        for s in (getattr(self, "cmd_sock", None), self.data_sock):
            if s is not None:
                s.close()
        self.health.state = "closed"

    def snapshot(self) -> dict:
        return self.health.snapshot()

    # --- control ------------------------------------------------------------------------------------------------------
    def _next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFFFF
        return self._seq

    def _send1(self, cmd_id: int, payload: bytes = b"", cmd_type: int = sdk1.CMD) -> None:
        self.cmd_sock.sendto(sdk1.pack_frame(cmd_type, self._next_seq(), 0, cmd_id, payload), self._sdk1_addr)

    def _send2(self, cmd_id: int, payload: bytes = b"", addr: tuple[str, int] | None = None) -> None:
        self.cmd_sock.sendto(sdk2.pack_frame(sdk2.REQ, self._next_seq(), cmd_id, payload), addr or self._sdk2_cmd)

    def _streaming(self) -> None:
        if self.health.state != "streaming":
            if self._ever_streamed:
                self.health.reconnects += 1
            self._ever_streamed = True
            self.health.state = "streaming"
        self._last_alive = time.monotonic()

    def _lost(self) -> None:
        self.health.state = "lost"
        self._sdk1_addr = None
        self._sdk2_cmd = None
        self._last_try = 0.0

    def _choose(self, sdk: int) -> None:
        if self.sdk is None or self._decoder is None:
            self.sdk = sdk
            self.health.sdk = sdk
            self._decoder = PacketDecoder(sdk, self.frame_s, self.sensor, self.health)
            if sdk == 2 and self._disc1 is not None:
                self._disc1.subs.pop(self.ip, None)
                self._disc1.release()
                self._disc1 = None

    def _on_sdk1(self, f: sdk1.Frame, addr: tuple[str, int]) -> None:
        if f.cmd_set != 0:
            return
        if f.cmd_id == sdk1.BROADCAST:
            if self.sdk == 2:
                return
            self._choose(1)
            if self.health.state == "streaming":  # a sensor that broadcasts has dropped us
                self._lost()
            self.health.device = sdk1.DEVICE_TYPES.get(f.payload[16] if len(f.payload) > 16 else -1, "unknown")
            self._sdk1_addr = (addr[0], self.lidar_cmd_port or addr[1])
            hs = socket.inet_aton(self.host) + struct.pack("<HHH", self.data_sock.getsockname()[1], self.cmd_sock.getsockname()[1], 0)
            self._send1(sdk1.HANDSHAKE, hs, cmd_type=sdk1.ACK)  # the vendor SDK sends the handshake with type 1
            self.health.state = "handshake"
        elif f.cmd_type == sdk1.ACK and f.cmd_id == sdk1.HANDSHAKE and f.payload[:1] == b"\x00":
            coord = b"\x00" if self.data_type not in (1, 3, 5) else b"\x01"
            self._send1(sdk1.COORDINATE, coord)
            self._send1(sdk1.SAMPLE, b"\x01")
            self._last_hb = 0.0
            self._streaming()
        elif f.cmd_type == sdk1.ACK and f.cmd_id == sdk1.HEARTBEAT and self.health.state == "streaming":
            self._last_alive = time.monotonic()

    def _on_sdk2(self, f: sdk2.Frame, addr: tuple[str, int]) -> None:
        if f.cmd_id == sdk2.DISCOVERY and f.cmd_type == sdk2.ACK and len(f.payload) >= 24 and f.payload[0] == 0:
            if self.sdk == 1:
                return
            self._choose(2)
            dev = f.payload[1]
            self.health.device = sdk2.DEVICE_TYPES.get(dev, f"type {dev}")
            cmd_port = self.lidar_cmd_port or struct.unpack_from("<H", f.payload, 22)[0]
            self._sdk2_cmd = (addr[0], cmd_port)
            lidar_point_port = 57000 if dev in (10, 15) else 56300
            my_cmd, my_data = self.cmd_sock.getsockname()[1], self.data_sock.getsockname()[1]
            items = [(sdk2.KEY_POINT_HOST, sdk2.host_address(self.host, my_data, lidar_point_port)),
                     (sdk2.KEY_STATE_HOST, sdk2.host_address(self.host, my_cmd, 56200)),
                     (sdk2.KEY_DATA_TYPE, bytes([self.data_type or 1])), (sdk2.KEY_WORK_MODE, bytes([sdk2.WORK_NORMAL]))]  # fmt: skip
            self._send2(sdk2.SET_PARAMS, sdk2.pack_params(items))
            self.health.state = "handshake"
        elif f.cmd_id == sdk2.SET_PARAMS and f.cmd_type == sdk2.ACK and f.payload[:1] == b"\x00" and self.health.state == "handshake":
            self._streaming()
        elif f.cmd_id == sdk2.PUSH and self.health.state == "streaming":
            self._last_alive = time.monotonic()

    def _tick(self, now: float) -> None:
        st = self.health.state
        if st == "listening":
            return
        if st == "streaming":
            # SDK 2 sensors prove they are alive by data or their 1 Hz state push: allow three pushes when idle
            limit = self.timeout_s if self.sdk == 1 else max(self.timeout_s, 3.0)
            if now - self._last_alive > limit:
                self._lost()
            elif self.sdk == 1 and now - self._last_hb >= 0.8 * min(1.0, self.timeout_s):
                self._last_hb = now
                self._send1(sdk1.HEARTBEAT)
            return
        if now - self._last_try < (1.5 if st == "handshake" else 0.5):  # an answer may be late on a busy host
            return
        self._last_try = now
        if self.sdk in (None, 2):  # SDK 2 discovery, unicast to the sensor (never a network broadcast)
            try:
                # discovery_port names the sensor's port for SDK 2, the host's broadcast port for SDK 1
                self._send2(sdk2.DISCOVERY, b"", (self.ip, self.discovery_port if self.sdk == 2 and self.discovery_port else sdk2.DISCOVERY_PORT))
            except OSError:
                pass
        if st == "handshake":
            self.health.state = "searching"  # no answer to the handshake / parameters: start over

    # --- I/O thread -----------------------------------------------------------------------------------------------
    def _run(self) -> None:
        last_flush = time.monotonic()
        while not self._stop.is_set():
            self.health.cpu_s = time.thread_time()
            events = self.sel.select(0.01)
            now = time.monotonic()
            for key, _ in events:
                sock = key.fileobj
                while True:
                    try:
                        buf, addr = sock.recvfrom(2048)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:
                        break
                    t = clock.now()
                    if key.data == "data":
                        if self.tap is not None:
                            self.tap(self.sensor, "data", t, buf)
                        if self._decoder is not None:
                            self._decoder.feed(buf, t)
                            if self.health.state == "streaming" and self.sdk == 2:
                                self._last_alive = now
                    else:
                        if self.tap is not None:
                            self.tap(self.sensor, "cmd", t, buf)
                        if buf[:1] == b"\xaa" and len(buf) >= 2 and buf[1] == sdk2.VERSION:
                            f2 = sdk2.parse_frame(buf)
                            if f2 is not None:
                                self._on_sdk2(f2, addr)
                        else:
                            f1 = sdk1.parse_frame(buf)
                            if f1 is not None:
                                self._on_sdk1(f1, addr)
            while self._inbox:
                f, addr = self._inbox.popleft()
                self._on_sdk1(f, addr)
            try:
                self._tick(now)
            except OSError:
                pass
            if self._decoder is not None and (now - last_flush > 0.02 or self._decoder.pending() > 512):
                last_flush = now
                clouds = self._decoder.flush()
                if clouds:
                    with self._lock:
                        self.clouds.extend(clouds)
                        while len(self.clouds) > self.max_clouds:
                            self.clouds.popleft()
                            self.health.overflow_clouds += 1
