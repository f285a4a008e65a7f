"""The real pyserial link over a pseudo-terminal pair: frames decode, CRCs check, rates hold, reconnect works."""

from __future__ import annotations

import os
import select
import struct
import time

import pytest

from radarcal.runtime import referee as rp
from radarcal.runtime.serial_link import RateLimiter, SerialLink, referee_limits


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_rate_limiter_frequency_and_byte_budget():
    clk = FakeClock()
    lim = RateLimiter({0x0305: 10.0}, bytes_per_s=100, clock=clk)
    assert lim.allow(0x0305, 33)
    lim.record(0x0305, 33)
    clk.t += 0.05
    assert not lim.allow(0x0305, 33)  # 20 Hz would exceed 10 Hz
    clk.t += 0.05
    assert lim.allow(0x0305, 33)
    lim.record(0x0305, 33)
    clk.t += 0.1
    lim.record(0x0305, 33)
    clk.t += 0.1
    assert not lim.allow(0x0305, 33)  # 99 bytes in the last second + 33 > 100
    clk.t += 0.81
    assert lim.allow(0x0305, 33)  # the first record left the window
    assert referee_limits(2026)[0x0305] == 5.0 and referee_limits(2024)[0x0301] == 10.0


class Pty:
    """A pseudo-terminal pair reachable through a stable symlink (like /dev/serial/by-id/...)."""

    def __init__(self, link):
        self.link = link
        self.master = None
        self.slave = None
        self.open()

    def open(self):
        self.master, self.slave = os.openpty()
        os.set_blocking(self.master, False)
        tmp = str(self.link) + ".tmp"
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, self.link)

    def close(self):
        for fd in (self.master, self.slave):
            if fd is not None:
                os.close(fd)
        self.master = self.slave = None
        if os.path.lexists(self.link):
            os.unlink(self.link)

    def read_frames(self, parser, seconds):
        out = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            r, _, _ = select.select([self.master], [], [], 0.01)
            if r:
                try:
                    out += parser.feed(os.read(self.master, 4096))
                except BlockingIOError:
                    pass
        return out


def wait_for(cond, timeout=3.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.01)
    return False


def test_pty_send_receive_rate_limit_and_reconnect(tmp_path):
    pytest.importorskip("serial")
    pty = Pty(tmp_path / "ttyREF")
    link = SerialLink(str(tmp_path / "ttyREF"), season=2024, reconnect_s=0.05, poll_s=0.002).start()
    try:
        assert wait_for(lambda: link.stats.connected)
        # --- radar -> referee: queue far faster than allowed; only the newest per key goes out, at <= 10 Hz
        parser = rp.FrameParser()
        got = []
        t0 = time.monotonic()
        i = 0
        while time.monotonic() - t0 < 1.0:
            link.send(rp.CMD_MAP, rp.map_payload(2024, {1: (i * 0.01, 7.5)})[0])
            link.send(rp.CMD_INTERACTION, rp.interaction_payload(0x0200, 9, 7, rp.sentry_guidance_content(3, 1.0, 2.0, 2.2)), key=0x0200)
            i += 1
            got += pty.read_frames(parser, 0.01)
        got += pty.read_frames(parser, 0.2)
        maps = [f for f in got if f.cmd_id == rp.CMD_MAP]
        inter = [f for f in got if f.cmd_id == rp.CMD_INTERACTION]
        assert parser.stats.bad_crc8 == parser.stats.bad_crc16 == 0 and parser.stats.skipped_bytes == 0
        assert 8 <= len(maps) <= 13, len(maps)  # ~10 Hz over ~1.2 s
        assert 8 <= len(inter) <= 13, len(inter)
        assert i > 50 and link.stats.replaced > 50  # the loop was never held up
        xs = [struct.unpack("<12H", f.data)[0] for f in maps]
        assert xs == sorted(xs) and xs[-1] >= (i - 40)  # newest positions, in order
        seqs = [f.seq for f in got]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # consecutive sequence numbers
        # --- referee -> radar: incoming frames update the state, garbage in between is skipped
        os.write(pty.master, b"\x00\xa5\x13" + rp.pack_frame(rp.CMD_ROBOT_STATUS, bytes([9, 1]) + bytes(10), 0) + b"junk" + rp.pack_frame(rp.CMD_GAME_STATUS, bytes([0x41, 10, 0]) + bytes(8), 1))
        assert wait_for(lambda: link.state.game is not None and link.state.team == "red")
        assert link.state.game.in_match and link.state.game.remaining_s == 10

        # --- the far end goes away: the link keeps accepting sends, then reconnects to the new port
        pty.close()
        t_close = time.monotonic()
        for _ in range(20):
            link.send(rp.CMD_MAP, rp.map_payload(2024, {2: (1.0, 1.0)})[0])
            time.sleep(0.01)
        assert wait_for(lambda: not link.stats.connected)
        assert time.monotonic() - t_close < 3.0
        pty.open()
        assert wait_for(lambda: link.stats.connected and link.stats.connects >= 2)
        link.send(rp.CMD_MAP, rp.map_payload(2024, {2: (4.0, 5.0)})[0])
        parser2 = rp.FrameParser()
        got2 = pty.read_frames(parser2, 0.5)
        assert any(struct.unpack("<12H", f.data)[2:4] == (400, 500) for f in got2 if f.cmd_id == rp.CMD_MAP)
        assert link.stats.disconnects >= 1
    finally:
        link.close()
        pty.close()


def test_missing_port_never_blocks(tmp_path):
    link = SerialLink(str(tmp_path / "nope"), reconnect_s=0.05).start()
    try:
        t0 = time.monotonic()
        for _ in range(1000):
            link.send(rp.CMD_MAP, bytes(24))
        assert time.monotonic() - t0 < 0.5
        time.sleep(0.2)
        assert not link.stats.connected and link.pending() == 1 and "nope" in link.stats.last_error
    finally:
        link.close()
