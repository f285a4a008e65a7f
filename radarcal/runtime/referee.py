"""RoboMaster referee-system serial protocol: CRCs, frame pack/parse, a resyncing stream parser, the radar's payloads.

Facts (see ``/work/shared/referee_protocol.md`` and the official 2020 appendix):

- frame = ``0xA5 | data_length u16 LE | seq u8 | CRC8(bytes 0..3) | cmd_id u16 LE | data | CRC16(bytes 0..6+n) LE``
- CRC8: polynomial 0x31 (x^8+x^5+x^4+1) reflected (0x8C), init 0xFF, no final XOR (check "123456789" -> 0x0B,
  *not* CRC-8/MAXIM which starts at 0x00).
- CRC16: polynomial 0x1021 reflected (0x8408), init 0xFFFF, no final XOR = CRC-16/MCRF4XX (check -> 0x6F91).
- Both tables are generated here from those parameters; the tests compare them with the appendix tables.

Payloads the radar sends: 0x0305 minimap (four season layouts: 14-byte float 2021-22, 10-byte float 2023,
24-byte uint16 cm 2024-25, 48-byte uint16 cm 2026) and 0x0301 student interaction (data_cmd_id, sender, receiver,
content <= 112 bytes). Payloads it reads: 0x0001 game status, 0x0003 robot HP, 0x0201 robot status (own id ->
team colour), 0x020C radar mark, 0x020E radar decision info.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from radarcal.runtime import referee_season as _season

__all__ = [
    "SOF",
    "HEADER_LEN",
    "OVERHEAD",
    "MAX_DATA_LEN",
    "CMD_GAME_STATUS",
    "CMD_ROBOT_HP",
    "CMD_ROBOT_STATUS",
    "CMD_RADAR_MARK",
    "CMD_RADAR_INFO",
    "CMD_INTERACTION",
    "CMD_MAP",
    "SERVER_ID",
    "crc8",
    "crc16",
    "CRC8_TABLE",
    "CRC16_TABLE",
    "Frame",
    "FrameError",
    "pack_frame",
    "parse_frame",
    "FrameParser",
    "map_payload",
    "map_layout",
    "interaction_payload",
    "radar_cmd_payload",
    "sentry_guidance_content",
    "hero_range_content",
    "GameStatus",
    "parse_game_status",
    "parse_robot_hp",
    "parse_radar_mark",
    "parse_radar_info",
    "RefereeState",
    "CMD_DART_INFO",
    "CMD_MAP_COMMAND",
    "SUB_RADAR_CMD",
    "parse_map_command",
    "parse_dart_info",
    "parse_interaction",
    "sentry_roster_content",
    "robot_id",
    "MAP_SLOTS",
]

SOF = 0xA5
HEADER_LEN = 5
OVERHEAD = 9  # header 5 + cmd_id 2 + CRC16 2
MAX_DATA_LEN = 512  # no referee command is near this; longer claims are treated as corruption

CMD_GAME_STATUS = 0x0001
CMD_ROBOT_HP = 0x0003
CMD_ROBOT_STATUS = 0x0201
CMD_RADAR_MARK = 0x020C
CMD_RADAR_INFO = 0x020E
CMD_INTERACTION = 0x0301
CMD_MAP = 0x0305
CMD_DART_INFO = 0x0105
CMD_MAP_COMMAND = 0x0303
SUB_RADAR_CMD = 0x0121  # 0x0301 sub-id of the radar's double-vulnerability request
SERVER_ID = 0x8080
INTERACTION_MAX_CONTENT = 112


# --- CRCs ------------------------------------------------------------------------------------------------------------
def _reflected_table(poly_reflected: int, width: int) -> np.ndarray:
    table = np.zeros(256, dtype=np.uint16 if width == 16 else np.uint8)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ poly_reflected if c & 1 else c >> 1
        table[i] = c
    return table


CRC8_TABLE = _reflected_table(0x8C, 8)  # 0x31 reflected
CRC16_TABLE = _reflected_table(0x8408, 16)  # 0x1021 reflected
_T8 = CRC8_TABLE.tolist()
_T16 = CRC16_TABLE.tolist()


def crc8(data: bytes, init: int = 0xFF) -> int:
    """Referee header CRC8 (poly 0x31 reflected, init 0xFF)."""
    c = init
    for b in data:
        c = _T8[c ^ b]
    return c


def crc16(data: bytes, init: int = 0xFFFF) -> int:
    """Referee frame CRC16 (CRC-16/MCRF4XX: poly 0x1021 reflected, init 0xFFFF)."""
    c = init
    for b in data:
        c = (c >> 8) ^ _T16[(c ^ b) & 0xFF]
    return c


# --- frames ----------------------------------------------------------------------------------------------------------
class FrameError(ValueError):
    """A byte string that is not one valid referee frame (the message says why)."""


@dataclass(frozen=True)
class Frame:
    cmd_id: int
    data: bytes
    seq: int = 0

    def pack(self) -> bytes:
        return pack_frame(self.cmd_id, self.data, self.seq)


def pack_frame(cmd_id: int, data: bytes, seq: int = 0) -> bytes:
    """Build one frame with both CRCs."""
    data = bytes(data)
    if len(data) > MAX_DATA_LEN:
        raise ValueError(f"data too long for a referee frame ({len(data)} > {MAX_DATA_LEN})")
    head = struct.pack("<BHB", SOF, len(data), seq & 0xFF)
    body = head + bytes([crc8(head)]) + struct.pack("<H", cmd_id & 0xFFFF) + data
    return body + struct.pack("<H", crc16(body))


def parse_frame(buf: bytes) -> Frame:
    """Parse exactly one frame; :class:`FrameError` on a bad SOF, CRC8, length or CRC16."""
    buf = bytes(buf)
    if len(buf) < OVERHEAD:
        raise FrameError(f"truncated: {len(buf)} bytes < {OVERHEAD}")
    if buf[0] != SOF:
        raise FrameError(f"bad SOF 0x{buf[0]:02X}")
    if crc8(buf[:4]) != buf[4]:
        raise FrameError("bad header CRC8")
    n = buf[1] | (buf[2] << 8)
    if n > MAX_DATA_LEN:
        raise FrameError(f"bad length {n}")
    if len(buf) != n + OVERHEAD:
        raise FrameError(f"length mismatch: header says {n} data bytes, frame has {len(buf) - OVERHEAD}")
    if crc16(buf[:-2]) != (buf[-2] | (buf[-1] << 8)):
        raise FrameError("bad frame CRC16")
    return Frame(buf[5] | (buf[6] << 8), buf[7:-2], buf[3])


@dataclass
class ParserStats:
    frames: int = 0
    bad_crc8: int = 0
    bad_crc16: int = 0
    bad_length: int = 0
    skipped_bytes: int = 0


class FrameParser:
    """Streaming parser: feed arbitrary chunks, get complete valid frames back. Resyncs on garbage.

    On a bad header CRC8, an impossible length or a bad CRC16 it drops only the SOF byte and searches again, so a
    valid frame hidden after garbage (or inside a corrupted frame's claimed length) is still found. The buffer is
    bounded (``max_buffer``) so random input can never grow memory.
    """

    def __init__(self, max_buffer: int = 4096):
        self._buf = bytearray()
        self.max_buffer = max_buffer
        self.stats = ParserStats()

    def feed(self, chunk: bytes) -> list[Frame]:
        self._buf += chunk
        out: list[Frame] = []
        buf = self._buf
        st = self.stats
        while True:
            i = buf.find(SOF)
            if i < 0:
                st.skipped_bytes += len(buf)
                buf.clear()
                break
            if i:
                st.skipped_bytes += i
                del buf[:i]
            if len(buf) < HEADER_LEN:
                break
            if crc8(buf[:4]) != buf[4]:
                st.bad_crc8 += 1
                st.skipped_bytes += 1
                del buf[:1]
                continue
            n = buf[1] | (buf[2] << 8)
            if n > MAX_DATA_LEN:
                st.bad_length += 1
                st.skipped_bytes += 1
                del buf[:1]
                continue
            total = n + OVERHEAD
            if len(buf) < total:
                break
            if crc16(buf[: total - 2]) != (buf[total - 2] | (buf[total - 1] << 8)):
                st.bad_crc16 += 1
                st.skipped_bytes += 1
                del buf[:1]
                continue
            out.append(Frame(buf[5] | (buf[6] << 8), bytes(buf[7 : total - 2]), buf[3]))
            st.frames += 1
            del buf[:total]
        if len(buf) > self.max_buffer:  # cannot happen with MAX_DATA_LEN < max_buffer, kept as a hard bound
            st.skipped_bytes += len(buf) - self.max_buffer
            del buf[: len(buf) - self.max_buffer]
        return out

    @property
    def pending(self) -> int:
        return len(self._buf)


# --- ids -------------------------------------------------------------------------------------------------------------
def robot_id(team: str, number: int) -> int:
    """Referee robot id: red n -> n, blue n -> 100 + n (radar = 9 / 109)."""
    if team not in ("red", "blue"):
        raise ValueError(f"team must be 'red' or 'blue', got {team!r}")
    return int(number) + (100 if team == "blue" else 0)


# --- 0x0305 minimap --------------------------------------------------------------------------------------------------
#: robot numbers in the slot order of the all-robots layouts (from the season table)
MAP_SLOTS = {2024: _season.MAP_LAYOUTS["all24"][0], 2026: _season.MAP_LAYOUTS["all48"][0]}


KNOWN_SEASONS = _season.KNOWN_SEASONS  # the seasons whose 0x0305 layout and rate limits are known


def map_layout(season: int) -> str:
    """``"single14"`` (<= 2022), ``"single10"`` (2023), ``"all24"`` (2024-2025), ``"all48"`` (>= 2026): read from
    :mod:`radarcal.runtime.referee_season` (seasons outside the table take the nearest known one)."""
    season = min(max(int(season), KNOWN_SEASONS[0]), KNOWN_SEASONS[-1])
    return _season.rules(season).map_layout.value


def _cm(xy) -> tuple[int, int]:
    x, y = (float(v) for v in xy)
    return tuple(int(min(max(round(v * 100.0), 0), 65535)) if np.isfinite(v) else 0 for v in (x, y))  # type: ignore[return-value]


def map_payload(season: int, enemy: dict[int, tuple[float, float]], ally: dict[int, tuple[float, float]] | None = None, enemy_team: str = "blue", angle: dict[int, float] | None = None,
                layout: str | None = None) -> list[bytes]:  # fmt: skip
    """0x0305 payload(s) for a season. ``enemy``/``ally`` map robot number (1 hero .. 7 sentry) -> field (x, y) m.

    All-robots layouts return one payload (missing robots are (0, 0) = "not sent"; metres -> cm, rounded, clamped
    to 0..65535). Single-target layouts return one payload per enemy robot (``enemy_team`` gives its referee id).
    ``layout`` overrides the season's (a season table with a changed layout).
    """
    layout = layout or map_layout(season)
    if layout.startswith("all"):
        slots = MAP_SLOTS[2024 if layout == "all24" else 2026]
        vals: list[int] = []
        for n in slots:
            vals += _cm(enemy[n]) if n in enemy else (0, 0)
        if layout == "all48":
            for n in slots:
                vals += _cm(ally[n]) if ally and n in ally else (0, 0)
        return [struct.pack(f"<{len(vals)}H", *vals)]
    out = []
    for n, (x, y) in sorted(enemy.items()):
        rid = robot_id(enemy_team, n)
        if layout == "single10":
            out.append(struct.pack("<Hff", rid, float(x), float(y)))
        else:
            out.append(struct.pack("<Hfff", rid, float(x), float(y), float((angle or {}).get(n, 0.0))))
    return out


# --- 0x0301 student interaction --------------------------------------------------------------------------------------
def interaction_payload(data_cmd_id: int, sender_id: int, receiver_id: int, content: bytes) -> bytes:
    """0x0301 data: data_cmd_id u16, sender u16, receiver u16, content (<= 112 bytes)."""
    content = bytes(content)
    if len(content) > INTERACTION_MAX_CONTENT:
        raise ValueError(f"0x0301 content too long ({len(content)} > {INTERACTION_MAX_CONTENT} bytes)")
    return struct.pack("<HHH", data_cmd_id & 0xFFFF, sender_id & 0xFFFF, receiver_id & 0xFFFF) + content


def radar_cmd_payload(season: int, radar_cmd: int, password_cmd: int = 0, key: str = "") -> bytes:
    """Content of sub-id 0x0121 (double-vulnerability request): 1 byte before 2026, 8 bytes from 2026."""
    if int(season) < 2026:
        return bytes([radar_cmd & 0xFF])
    k = key.encode("ascii")[:6].ljust(6, b"\0")
    return bytes([radar_cmd & 0xFF, password_cmd & 0xFF]) + k


def sentry_guidance_content(target_number: int, dx: float, dy: float, distance: float) -> bytes:
    """radarcal's robot-to-robot message to our sentry: u8 enemy robot number, u8 valid, float dx, dy, distance (m).

    (dx, dy) = enemy - sentry in the field frame. 14 bytes; valid = 0 means "no enemy located".
    """
    valid = 1 if target_number > 0 and np.isfinite(dx) and np.isfinite(dy) else 0
    if not valid:
        dx = dy = distance = 0.0
    return struct.pack("<BBfff", target_number & 0xFF, valid, float(dx), float(dy), float(distance))


def sentry_roster_content(guidance: bytes, slots: list[tuple[int, int, float, float]]) -> bytes:
    """The sentry message with the roster: ``guidance`` (:func:`sentry_guidance_content`, 14 bytes) then u8 count and,
    per enemy slot, u8 robot number, u8 state (1 seen, 2 predicted, 3 guess), u16 x cm, u16 y cm (6 bytes each)."""
    out = bytes(guidance) + bytes([len(slots) & 0xFF])
    for number, state, x, y in slots:
        cx, cy = _cm((x, y))
        out += struct.pack("<BBHH", number & 0xFF, state & 0xFF, cx, cy)
    if len(out) > INTERACTION_MAX_CONTENT:
        raise ValueError(f"sentry roster content too long ({len(out)} > {INTERACTION_MAX_CONTENT} bytes)")
    return out


def hero_range_content(distance_m: float, valid: bool = True) -> bytes:
    """radarcal's robot-to-robot message to our hero: u8 valid, float distance to the enemy outpost (m, offset applied)."""
    ok = bool(valid) and np.isfinite(distance_m)
    return struct.pack("<Bf", 1 if ok else 0, float(distance_m) if ok else 0.0)


# --- incoming ------------------------------------------------------------------------------------------------------
@dataclass
class GameStatus:
    game_type: int
    stage: int  # 0 not started, 1 preparation, 2 self-check, 3 countdown, 4 in match, 5 settlement
    remaining_s: int
    unix_time: int | None = None

    @property
    def in_match(self) -> bool:
        return self.stage == 4


def parse_game_status(data: bytes) -> GameStatus:
    """0x0001: 3 bytes (2020) or 11 bytes (2024+)."""
    if len(data) not in (3, 11):
        raise FrameError(f"0x0001 game status: expected 3 or 11 bytes, got {len(data)}")
    b0, remaining = data[0], data[1] | (data[2] << 8)
    unix = struct.unpack_from("<Q", data, 3)[0] if len(data) == 11 else None
    return GameStatus(b0 & 0x0F, b0 >> 4, remaining, unix)


_HP_NAMES_32 = [f"{team}_{n}" for team in ("red", "blue") for n in ("1", "2", "3", "4", "5", "7", "outpost", "base")]
_HP_NAMES_16 = [f"ally_{n}" for n in ("1", "2", "3", "4", "reserved", "7", "outpost", "base")]
_HP_NAMES_20 = ["ally_1", "ally_2", "ally_3", "ally_4", "damage_diff", "ally_7", "ally_outpost", "ally_base", "enemy_outpost", "enemy_base"]


def parse_robot_hp(data: bytes) -> dict[str, int]:
    """0x0003: 32 bytes (both teams, <= 2025), 16 bytes (2026 V1.1, own side), 20 bytes (2026 V2.0)."""
    names = {32: _HP_NAMES_32, 16: _HP_NAMES_16, 20: _HP_NAMES_20}.get(len(data))
    if names is None:
        raise FrameError(f"0x0003 robot HP: expected 16, 20 or 32 bytes, got {len(data)}")
    fmt = "<" + "".join("h" if nm == "damage_diff" else "H" for nm in names)
    return dict(zip(names, struct.unpack(fmt, data)))


def parse_radar_mark(data: bytes) -> dict:
    """0x020C: 6 x u8 mark progress (2024) or a u16 bitfield (2026)."""
    if len(data) == 6:
        return {"progress": dict(zip(("1", "2", "3", "4", "5", "7"), data))}
    if len(data) == 2:
        v = data[0] | (data[1] << 8)
        names = ["enemy_1_vulnerable", "enemy_2_vulnerable", "enemy_3_vulnerable", "enemy_4_vulnerable", "enemy_6_marked", "enemy_7_vulnerable",
                 "ally_1_marked", "ally_2_marked", "ally_3_marked", "ally_4_marked", "ally_6_marked", "ally_7_marked",
                 "enemy_6_laser_aimed", "enemy_6_countered", "ally_6_laser_aimed", "ally_6_countered"]  # fmt: skip
        return {"bits": v, **{nm: bool(v >> i & 1) for i, nm in enumerate(names)}}
    raise FrameError(f"0x020C radar mark: expected 2 or 6 bytes, got {len(data)}")


def parse_radar_info(data: bytes) -> dict:
    """0x020E (1 byte): double-vulnerability chances, opponent vulnerable now, encryption level, key changeable."""
    if len(data) != 1:
        raise FrameError(f"0x020E radar info: expected 1 byte, got {len(data)}")
    v = data[0]
    return {"chances": v & 3, "enemy_double_vulnerable": bool(v >> 2 & 1), "encryption_level": v >> 3 & 3, "key_changeable": bool(v >> 5 & 1)}


def parse_map_command(data: bytes) -> dict:
    """0x0303 (the aerial operator's map click, to the radar too): float x, y (m), u8 key, u8 target robot id, then
    the source id (u16 in the 2026 V2.0.0 text, u8 in some team headers: 11, 12 or 14 bytes accepted)."""
    if len(data) < 11:
        raise FrameError(f"0x0303 map command: expected at least 11 bytes, got {len(data)}")
    x, y, key, target = struct.unpack_from("<ffBB", data)
    source = data[10] | (data[11] << 8 if len(data) >= 12 else 0)
    return {"x": x, "y": y, "key": key, "target": target, "source": source}


def parse_dart_info(data: bytes, season: int = 2026) -> dict:
    """0x0105 (3 bytes): u8 dart launch remaining time (s), u16 dart info. 2026 (V2.0.0 表1-11): bits 0-2 the target our
    dart hit last (0 none, 1 outpost, 2 base fixed, 3 base random fixed, 4 base random moving, 5 base end moving),
    bits 3-5 hits on it, bits 6-8 the selected target. Before 2026 (UNCERTAIN): bits 0-1, 2-4, 5-6."""
    if len(data) != 3:
        raise FrameError(f"0x0105 dart info: expected 3 bytes, got {len(data)}")
    t, info = data[0], data[1] | (data[2] << 8)
    if int(season) >= 2026:
        return {"remaining_s": t, "hit_target": info & 7, "hits": info >> 3 & 7, "selected": info >> 6 & 7, "info": info}
    return {"remaining_s": t, "hit_target": info & 3, "hits": info >> 2 & 7, "selected": info >> 5 & 3, "info": info}


def parse_interaction(data: bytes) -> dict:
    """0x0301 received: data_cmd_id, sender, receiver, content."""
    if len(data) < 6:
        raise FrameError(f"0x0301 interaction: expected at least 6 bytes, got {len(data)}")
    sub, sender, receiver = struct.unpack_from("<HHH", data)
    return {"sub_id": sub, "sender": sender, "receiver": receiver, "content": bytes(data[6:])}


@dataclass
class RefereeState:
    """What the radar knows from incoming frames. ``team`` comes from 0x0201 (own robot id 9 -> red, 109 -> blue)."""

    team: str | None = None
    own_id: int | None = None
    game: GameStatus | None = None
    hp: dict[str, int] = field(default_factory=dict)
    mark: dict = field(default_factory=dict)
    radar_info: dict = field(default_factory=dict)
    frames: dict[int, int] = field(default_factory=dict)  # cmd_id -> count
    errors: int = 0
    map_command: dict = field(default_factory=dict)  # newest 0x0303 (frames[CMD_MAP_COMMAND] counts them)
    dart_raw: bytes = b""  # newest 0x0105 data (parse_dart_info with the season)
    interactions_from: dict[int, int] = field(default_factory=dict)  # 0x0301 sender id -> frames received

    def update(self, frame: Frame) -> None:
        self.frames[frame.cmd_id] = self.frames.get(frame.cmd_id, 0) + 1
        try:
            if frame.cmd_id == CMD_GAME_STATUS:
                self.game = parse_game_status(frame.data)
            elif frame.cmd_id == CMD_ROBOT_HP:
                self.hp = parse_robot_hp(frame.data)
            elif frame.cmd_id == CMD_RADAR_MARK:
                self.mark = parse_radar_mark(frame.data)
            elif frame.cmd_id == CMD_RADAR_INFO:
                self.radar_info = parse_radar_info(frame.data)
            elif frame.cmd_id == CMD_MAP_COMMAND:
                self.map_command = parse_map_command(frame.data)
            elif frame.cmd_id == CMD_DART_INFO:
                parse_dart_info(frame.data)
                self.dart_raw = bytes(frame.data)
            elif frame.cmd_id == CMD_INTERACTION:
                sender = parse_interaction(frame.data)["sender"]
                self.interactions_from[sender] = self.interactions_from.get(sender, 0) + 1
            elif frame.cmd_id == CMD_ROBOT_STATUS and len(frame.data) >= 1:
                rid = frame.data[0]
                if rid in range(1, 12) or rid in range(101, 112):
                    self.own_id = rid
                    self.team = "red" if rid < 100 else "blue"
        except FrameError:
            self.errors += 1
