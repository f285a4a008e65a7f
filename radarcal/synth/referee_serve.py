"""The referee simulator's I/O: a pseudo-terminal (or a serial device), the byte loop and the frame log.

:func:`open_pty` makes a raw pseudo-terminal and returns (master fd, slave path); the simulator keeps its own slave
fd open, so radarcal may open, close and reopen the path (a reconnect) without the master seeing a hang-up.
:func:`serve` runs :class:`~radarcal.synth.referee_sim.RefereeSim` over a byte port: it decodes what arrives with the
package's :class:`~radarcal.runtime.referee.FrameParser`, maps wall time to the match clock (match time 0 = the first
frame from radarcal, which sends its first frame right after processing the replay's first camera frame), sends the
referee's frames on their schedule and logs every frame both ways as JSON lines.
"""

from __future__ import annotations

import errno
import json
import os
import time
from dataclasses import dataclass
from typing import Callable

from radarcal.runtime import referee as rp
from radarcal.synth.referee_sim import RefereeSim

__all__ = ["open_pty", "PtyPort", "SerialPort", "serve", "serve_until_signal", "replay_truth", "ServeResult"]


def open_pty() -> tuple[int, int, str]:
    """A raw pseudo-terminal: (master fd, slave fd kept open by the caller, slave path). Master is non-blocking."""
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)  # no echo, no line discipline: bytes pass as they are
    os.set_blocking(master, False)
    return master, slave, os.ttyname(slave)


class PtyPort:
    """Non-blocking reads/writes on a pty master. A full buffer (nobody reading the slave yet) drops the frame."""

    def __init__(self, master: int, slave: int, path: str):
        self.master, self.slave, self.path = master, slave, path
        self.dropped_writes = 0

    def read(self) -> bytes:
        try:
            return os.read(self.master, 65536)
        except BlockingIOError:
            return b""
        except OSError as e:
            if e.errno == errno.EIO:  # no slave open at the moment
                return b""
            raise

    def write(self, data: bytes) -> None:
        try:
            n = os.write(self.master, data)
            if n != len(data):
                self.dropped_writes += 1
        except BlockingIOError:
            self.dropped_writes += 1

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


class SerialPort:
    """A real serial device (115200 8N1) through pyserial."""

    def __init__(self, device: str, baudrate: int = 115200):
        import serial

        self.path = device
        self.dropped_writes = 0
        self._ser = serial.Serial(device, baudrate, bytesize=8, parity="N", stopbits=1, timeout=0, write_timeout=0.2)

    def read(self) -> bytes:
        n = self._ser.in_waiting
        return self._ser.read(n) if n else b""

    def write(self, data: bytes) -> None:
        self._ser.write(data)

    def close(self) -> None:
        self._ser.close()


@dataclass
class ServeResult:
    summary: dict
    started: bool
    wall_s: float
    stopped_by: str


def serve(sim: RefereeSim, port, log_path=None, idle_exit_s: float = 3.0, start_timeout_s: float = 120.0, end_margin_s: float = 1.0,
          poll_s: float = 0.005, clock: Callable[[], float] = time.monotonic, stop: Callable[[], bool] = lambda: False, speed: float = 1.0) -> ServeResult:  # fmt: skip
    """Play the referee on ``port`` until the replay's truth ends (+ ``end_margin_s``), radarcal has been silent for
    ``idle_exit_s`` after its first frame, no frame came within ``start_timeout_s``, or ``stop()`` is true.

    ``speed``: the match clock runs at this multiple of wall time (radarcal replaying at the same ``--speed``); rates
    and budgets stay on the wall clock, as the link's own limits do."""
    parser = rp.FrameParser()
    log = open(log_path, "w", encoding="utf-8") if log_path else None
    t0_wall = clock()
    first_rx = None
    last_rx = None
    seq = 0
    stopped_by = "end of truth"
    end_t = sim.truth.duration + end_margin_s * speed
    bad_before = 0

    def match_t(now: float) -> float:
        return 0.0 if first_rx is None else (now - first_rx) * speed

    def record(d: dict) -> None:
        if log is not None:
            log.write(json.dumps(d, separators=(",", ":")) + "\n")

    try:
        while True:
            now = clock()
            chunk = port.read()
            if chunk:
                if first_rx is None:
                    first_rx = now
                last_rx = now
                frames = parser.feed(chunk)
                st = parser.stats
                bad = st.bad_crc8 + st.bad_crc16 + st.bad_length
                if bad > bad_before or (st.skipped_bytes and not frames):
                    record({"t_wall": round(now - t0_wall, 4), "dir": "rx", "error": f"{bad - bad_before} bad frames, {st.skipped_bytes} skipped bytes so far"})
                    bad_before = bad
                t = match_t(now)
                sim.advance(t)
                for f in frames:
                    chk = sim.receive(t, f, t_wall=now)
                    record({"t_wall": round(now - t0_wall, 4), "t": round(t, 4), "dir": "rx", "seq": f.seq, "hex": f.pack().hex(), **chk.to_dict()})
            started = first_rx is not None
            t = match_t(now)
            if started:
                sim.advance(t)
            for cmd, data in sim.due_frames(now - t0_wall, started):
                frame = rp.pack_frame(cmd, data, seq)
                seq = (seq + 1) & 0xFF
                port.write(frame)
                record({"t_wall": round(now - t0_wall, 4), "t": round(t, 4), "dir": "tx", "seq": (seq - 1) & 0xFF, "cmd": f"0x{cmd:04X}", "hex": frame.hex()})
            if stop():
                stopped_by = "signal"
                break
            if started and t >= end_t:
                break
            if started and now - last_rx > idle_exit_s:
                stopped_by = f"radarcal silent for {idle_exit_s:g} s"
                break
            if not started and now - t0_wall > start_timeout_s:
                stopped_by = f"no frame from radarcal within {start_timeout_s:g} s"
                break
            time.sleep(poll_s)
        summary = sim.summary()
        st = parser.stats
        summary["link"].update({"bad_crc8": st.bad_crc8, "bad_crc16": st.bad_crc16, "bad_length": st.bad_length, "skipped_bytes": st.skipped_bytes,
                                "malformed_total": summary["link"]["malformed"] + st.bad_crc8 + st.bad_crc16 + st.bad_length,
                                "dropped_writes": port.dropped_writes})  # fmt: skip
        summary["stopped_by"] = stopped_by
        record({"summary": summary})
        return ServeResult(summary, first_rx is not None, clock() - t0_wall, stopped_by)
    finally:
        if log is not None:
            log.close()


def play_match(sim: RefereeSim, command: list[str], log_path=None, timeout_s: float = 600.0, env: dict | None = None, cwd=None, **serve_kw):
    """Run ``command + ["--serial", PTY]`` (e.g. ``radarcal run --replay DIR --speed 1``) against ``sim`` on a new
    pty; returns (:class:`ServeResult`, the command's ``subprocess.CompletedProcess``). The simulator stops shortly
    after the command exits (or at the end of the truth, or when the command goes silent)."""
    import subprocess
    import threading

    port = PtyPort(*open_pty())
    done = threading.Event()
    out: dict = {}

    def target():
        out["result"] = serve(sim, port, log_path, stop=done.is_set, **serve_kw)

    th = threading.Thread(target=target, name="referee-sim", daemon=True)
    th.start()
    try:
        proc = subprocess.run([*command, "--serial", port.path], capture_output=True, text=True, timeout=timeout_s, env=env, cwd=cwd)
    finally:
        time.sleep(0.3)  # the last frames are in the pty: one more read
        done.set()
        th.join(30.0)
        port.close()
    return out["result"], proc


def serve_until_signal(sim: RefereeSim, port, log_path=None, **kwargs) -> ServeResult:
    """:func:`serve`, stopping cleanly on SIGINT / SIGTERM (the previous handlers restored, ``port`` closed)."""
    import signal

    stop = {"now": False}

    def on_signal(signum, frame):  # noqa: ARG001
        stop["now"] = True

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return serve(sim, port, log_path, stop=lambda: stop["now"], **kwargs)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        port.close()


def replay_truth(replay):
    """The replay folder at ``replay`` and the :class:`~radarcal.synth.referee_sim.Truth` of its ``truth.jsonl``
    (``InputError`` when it has none or it is not one)."""
    from radarcal.errors import InputError
    from radarcal.io.replay import open_replay_folder
    from radarcal.synth.referee_sim import Truth

    rep = open_replay_folder(replay)
    if rep.truth is None:
        raise InputError(replay, "no truth.jsonl: the simulator scores marks against the replay's truth")
    try:
        truth = Truth.from_lines(rep.truth_by_frame().values())
    except (ValueError, KeyError, TypeError, IndexError) as e:
        raise InputError(rep.truth, f"not a truth file (JSON lines with t and robots[label, p_field]): {e}") from None
    if not len(truth.t):
        raise InputError(rep.truth, "empty: no frames")
    return rep, truth
