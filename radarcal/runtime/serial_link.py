"""Referee serial link: pyserial at 115200 8N1 in a background thread, so the main loop never blocks.

- :meth:`SerialLink.send` only puts the newest frame for a key (cmd_id, sub-id) into a mailbox and returns; an
  older unsent frame for the same key is replaced (a minimap position that is 200 ms old is worthless).
- The I/O thread sends what the :class:`RateLimiter` allows (per-command frequency caps plus a byte budget per
  second, the referee's limits), reads incoming bytes into a :class:`~radarcal.runtime.referee.FrameParser` and
  keeps a :class:`~radarcal.runtime.referee.RefereeState` up to date.
- When the port disappears (USB unplugged, far end closed) the thread closes it, counts a disconnect and retries
  opening every ``reconnect_s``; the main loop keeps running and frames queued meanwhile are sent after reconnection
  (only the newest per key).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from radarcal.runtime import referee as rp

__all__ = ["RateLimiter", "referee_limits", "LinkStats", "SerialLink"]


def referee_limits(season: int) -> dict[int, float]:
    """Max send frequency (Hz) per cmd_id from :mod:`radarcal.runtime.referee_season`: 0x0305 10 Hz (<= 2025) /
    5 Hz (2026); 0x0301 10 Hz / 30 Hz."""
    from radarcal.runtime.referee_season import KNOWN_SEASONS, rules

    r = rules(min(max(int(season), KNOWN_SEASONS[0]), KNOWN_SEASONS[-1]))
    return {rp.CMD_MAP: float(r.map_hz.value), rp.CMD_INTERACTION: float(r.interaction_hz.value)}


class RateLimiter:
    """Per-cmd_id minimum interval plus a bytes-per-second budget (sliding 1 s window). Clock injectable for tests."""

    def __init__(self, max_hz: dict[int, float], bytes_per_s: int = 5120, clock=time.monotonic):
        self.min_interval = {k: 1.0 / v for k, v in max_hz.items() if v > 0}
        self.bytes_per_s = int(bytes_per_s)
        self.clock = clock
        self._last: dict[int, float] = {}
        self._window: list[tuple[float, int]] = []

    def allow(self, cmd_id: int, nbytes: int) -> bool:
        now = self.clock()
        last = self._last.get(cmd_id)
        if last is not None and now - last < self.min_interval.get(cmd_id, 0.0) - 1e-9:
            return False
        self._window = [(t, n) for t, n in self._window if now - t < 1.0]
        if sum(n for _, n in self._window) + nbytes > self.bytes_per_s:
            return False
        return True

    def record(self, cmd_id: int, nbytes: int) -> None:
        now = self.clock()
        self._last[cmd_id] = now
        self._window.append((now, nbytes))


@dataclass
class LinkStats:
    sent_frames: int = 0
    sent_bytes: int = 0
    replaced: int = 0  # frames superseded by a newer one before they could be sent
    received_frames: int = 0
    disconnects: int = 0
    connects: int = 0
    write_errors: int = 0
    connected: bool = False
    last_error: str = ""
    sent_by_cmd: dict[int, int] = field(default_factory=dict)


class SerialLink:
    """Non-blocking referee link. ``start()`` spawns the I/O thread; ``close()`` stops it."""

    def __init__(self, port: str, baudrate: int = 115200, season: int = 2024, bytes_per_s: int = 5120, reconnect_s: float = 0.5, poll_s: float = 0.005, serial_factory=None):
        self.port = port
        self.baudrate = baudrate
        self.limiter = RateLimiter(referee_limits(season), bytes_per_s)
        self.reconnect_s = reconnect_s
        self.poll_s = poll_s
        self.state = rp.RefereeState()
        self.stats = LinkStats()
        self.received: list[rp.Frame] = []  # newest incoming frames (bounded), for callers that want raw frames
        self._parser = rp.FrameParser()
        self._mail: dict[tuple[int, int], tuple[int, bytes]] = {}
        self._order: list[tuple[int, int]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._ser = None
        self._seq = 0
        self._factory = serial_factory

    # --- public, called from the main loop (never blocks beyond a mutex) ---------------------------------------------
    def send(self, cmd_id: int, data: bytes, key: int = 0) -> None:
        """Queue ``data`` for ``cmd_id``; replaces an unsent frame with the same (cmd_id, key)."""
        k = (cmd_id, key)
        with self._lock:
            if k in self._mail:
                self.stats.replaced += 1
            else:
                self._order.append(k)
            self._mail[k] = (cmd_id, bytes(data))

    def pending(self) -> int:
        with self._lock:
            return len(self._mail)

    def start(self) -> "SerialLink":
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"referee-{self.port}", daemon=True)
        self._thread.start()
        return self

    def close(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._close_port()

    def __enter__(self) -> "SerialLink":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # --- I/O thread --------------------------------------------------------------------------------------------------
    def _open(self):
        if self._factory is not None:
            return self._factory(self.port, self.baudrate)
        import serial

        return serial.Serial(self.port, self.baudrate, bytesize=8, parity="N", stopbits=1, timeout=0, write_timeout=0.2, xonxoff=False, rtscts=False)

    def _close_port(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # noqa: BLE001 - closing a dead port may fail in many ways
                pass

    def _drop(self, err: Exception) -> None:
        self.stats.last_error = f"{err.__class__.__name__}: {err}"
        if self.stats.connected:
            self.stats.disconnects += 1
        self.stats.connected = False
        self._close_port()

    def _run(self) -> None:
        next_try = 0.0
        while not self._stop.is_set():
            if self._ser is None:
                now = time.monotonic()
                if now < next_try:
                    self._stop.wait(min(self.poll_s * 4, next_try - now))
                    continue
                try:
                    self._ser = self._open()
                    self._parser = rp.FrameParser()
                    self.stats.connected = True
                    self.stats.connects += 1
                except Exception as e:  # noqa: BLE001 - SerialException, OSError, FileNotFoundError ...
                    self.stats.last_error = f"{e.__class__.__name__}: {e}"
                    next_try = time.monotonic() + self.reconnect_s
                    continue
            try:
                self._read()
                self._write()
            except Exception as e:  # noqa: BLE001 - port vanished: reconnect later
                self._drop(e)
                next_try = time.monotonic() + self.reconnect_s
                continue
            self._stop.wait(self.poll_s)

    def _read(self) -> None:
        ser = self._ser
        n = ser.in_waiting
        if not n:
            return
        for f in self._parser.feed(ser.read(n)):
            self.stats.received_frames += 1
            with self._lock:
                self.state.update(f)
                self.received.append(f)
                if len(self.received) > 256:
                    del self.received[:128]

    def _write(self) -> None:
        with self._lock:
            order = list(self._order)
        for k in order:
            with self._lock:
                item = self._mail.get(k)
            if item is None:
                continue
            cmd_id, data = item
            nbytes = len(data) + rp.OVERHEAD
            if not self.limiter.allow(cmd_id, nbytes):
                continue
            frame = rp.pack_frame(cmd_id, data, self._seq)
            try:
                written = self._ser.write(frame)
                self._ser.flush()
            except Exception:
                self.stats.write_errors += 1
                raise
            if written is not None and written != len(frame):
                self.stats.write_errors += 1
                raise OSError(f"short write ({written} of {len(frame)} bytes)")
            self._seq = (self._seq + 1) & 0xFF
            self.limiter.record(cmd_id, nbytes)
            self.stats.sent_frames += 1
            self.stats.sent_bytes += nbytes
            self.stats.sent_by_cmd[cmd_id] = self.stats.sent_by_cmd.get(cmd_id, 0) + 1
            with self._lock:
                if self._mail.get(k) is item:  # not replaced meanwhile
                    del self._mail[k]
                    self._order.remove(k)

    def snapshot(self) -> dict:
        """Thread-safe copy of what the link knows (for the status line and JSON output)."""
        with self._lock:
            st = self.state
            return {
                "connected": self.stats.connected,
                "team": st.team,
                "stage": st.game.stage if st.game else None,
                "sent": self.stats.sent_frames,
                "received": self.stats.received_frames,
                "disconnects": self.stats.disconnects,
            }
